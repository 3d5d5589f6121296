"""The ground-truth effective BRDF (docs/design.md §4, §6): the one driver for facets → visibility → f̄.

f̄(ωi, ωo) = Σ_s c_s f_r(n_s, ωi, ωo)(n_s·ωi)⁺(n_s·ωo)⁺ V_s(ωi) V_s(ωo) ΔA_s / a_v(ωo)

with every small-scale BRDF evaluated exactly (no SG fit) and exact ray-cast visibility of the
infinitely tiled surface. The driver calls backend primitives only; it never asks which backend.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from . import directions as dirs
from .backend import get_backend
from .brdf import as_material_list, pack_materials
from .io import read_npz, save_npz
from .progress import as_progress
from .smallscale import SmallScale, TileWarning

__all__ = ["effective_brdf_exact", "ground_truth", "GroundTruth", "MAX_FACETS"]

MAX_FACETS = 1 << 26  # 67 M facets: 1.3 GB of facet data; beyond this, ask for fewer


def _check_count(facets) -> int:
    try:
        n = int(facets)
    except (TypeError, ValueError):
        raise ValueError(f"facets must be a positive integer, got {facets!r}") from None
    if n != facets or n < 1 or n > MAX_FACETS:
        raise ValueError(f"facets must be an integer in [1, {MAX_FACETS}], got {facets!r}")
    return n


def _prepare(tile, materials):
    """The tile checked and its materials normalised (one BRDF or a list, indexed by the tile's material ids):
    → (list of Brdf, kinds, params). Fewer BRDFs than the tile's ids is an error; more (than one) is a
    `TileWarning`, since the extra ones are never used. Shared by `ground_truth`, `effective_brdf_exact`
    and `bake.bake`; the warning points at their caller."""

    if not isinstance(tile, SmallScale):
        raise ValueError(f"tile must be a SmallScale (wb.SmallScale.load(...) or wb.geometry.*), got {tile!r}")
    mats = as_material_list(materials)
    kinds, params = pack_materials(mats, tile.n_materials)
    n = tile.n_materials
    if len(mats) > n:
        unused = f"BRDF {n} is" if len(mats) == n + 1 else f"BRDFs {n}..{len(mats) - 1} are"
        ids = "1 material id" if n == 1 else f"{n} material ids"
        warnings.warn(f"{len(mats)} BRDFs given for a tile with {ids}: {unused} unused", TileWarning, stacklevel=3)
    return mats, kinds, params


class _Timer:
    def __init__(self, backend):
        self.backend = backend
        self.timings = {}

    def __call__(self, name, fn, *args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        self.backend.synchronize()
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0
        return out


def effective_brdf_exact(tile, materials, wi, wo, facets: int = 1 << 20, backend="auto", seed: int = 0,
                         progress=None) -> np.ndarray:
    """Ground-truth f̄ at arbitrary direction pairs.

    Parameters
    ----------
    tile : SmallScale
    materials : Brdf or list of Brdf, indexed by the tile's material ids.
    wi, wo : (N, 3) directions in the tile frame (z up); normalised here. Pairs with either
        direction at or below the horizon give 0.
    facets : number of facets Ns (the estimator's error falls faster than 1/√Ns).
    backend : a backend name (see `wb.backends()`) or object.
    seed : facet-sampling seed; the same seed gives the same result.

    Returns (N, 3) float64 RGB f̄, including cos θi (docs/design.md §4). Only the distinct directions of
    wi and wo are traced.
    """
    _, kinds, params = _prepare(tile, materials)
    wi = dirs.check_directions("wi", wi)
    wo = dirs.check_directions("wo", wo)
    if len(wi) != len(wo):
        raise ValueError(f"wi and wo must have the same length, got {len(wi)} and {len(wo)}")
    count = _check_count(facets)
    be = get_backend(backend)
    prog = as_progress(progress)
    unique, inverse = np.unique(np.concatenate([wi, wo]), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    pair_i, pair_o = inverse[: len(wi)], inverse[len(wi):]
    prog.stage("facets", 1)
    fac = be.sample_facets(tile, count, seed)
    prog.stage(f"visibility ({len(unique)} dirs)", 1)
    vis = be.visibility(tile, fac, unique)
    prog.stage("effective BRDF", 1)
    a_v = be.visible_area(fac, vis)
    f = be.effective_brdf(fac, vis, kinds, params, pair_i, pair_o, a_v)
    prog.done()
    return _sanitise(f).astype(np.float64)


def _sanitise(f: np.ndarray) -> np.ndarray:
    """No NaN, inf or negative value leaves the driver: a kernel that produced one is a bug."""
    bad = ~np.isfinite(f)
    if bad.any():
        raise FloatingPointError(f"a kernel produced {int(bad.sum())} non-finite effective-BRDF values")
    return np.maximum(f, 0.0)


def ground_truth(tile, materials, facets: int = 1 << 20, directions: int = 12, backend="auto", seed: int = 0,
                 progress=None) -> GroundTruth:
    """Ground-truth f̄ on the K×K direction grid (K = `directions`): all K²×K² pairs.

    Returns a `GroundTruth` table with `eval(wi, wo)`, `save(path)`, and per-stage `timings`
    (seconds, device-synchronised).
    """
    mats, kinds, params = _prepare(tile, materials)
    count = _check_count(facets)
    k = int(directions)
    if k != directions or not (2 <= k <= 64):
        raise ValueError(f"directions must be an integer grid size K in [2, 64], got {directions!r}")
    be = get_backend(backend)
    prog = as_progress(progress)
    timer = _Timer(be)
    grid = dirs.grid(k)
    nd = len(grid)
    prog.stage(f"facets ({count})", 1)
    fac = timer("facets", be.sample_facets, tile, count, seed)
    prog.stage(f"visibility ({nd} dirs)", 1)
    vis = timer("visibility", be.visibility, tile, fac, grid)
    a_v = timer("visible_area", be.visible_area, fac, vis)
    # All pairs, a few ωi rows per launch (at most ~2^28 facet-pair terms) so that the progress display
    # moves on long runs; a launch that large still fills a GPU.
    table = np.zeros((nd, nd, 3), np.float32)
    rows = max(1, min(nd, (1 << 28) // (nd * count)))
    pair_i, pair_o = dirs.all_pairs(nd)
    prog.stage(f"effective BRDF ({nd}x{nd})", nd)
    for start in range(0, nd, rows):
        stop = min(nd, start + rows)
        batch = slice(start * nd, stop * nd)
        f = timer("effective_brdf", be.effective_brdf, fac, vis, kinds, params, pair_i[batch], pair_o[batch], a_v)
        table[start:stop] = f.reshape(stop - start, nd, 3)
        prog.advance(stop - start)
    prog.done()
    return GroundTruth(
        table=_sanitise(table),
        a_v=np.asarray(a_v, np.float64),
        directions=k,
        facets=count,
        seed=int(seed),
        tile=tile.name,
        footprint=tile.footprint,
        materials=[repr(m) for m in mats],
        backend=be.name,
        timings=timer.timings,
    )


class GroundTruth:
    """f̄ tabulated on the K×K grid of docs/design.md §4: ``table[i, o]`` for ωi = grid[i], ωo = grid[o].

    `eval` interpolates bilinearly in the square domain of ωi and of ωo. It interpolates
    f̄ / cos θi and multiplies the query's cos θi back, so the known cosine factor is exact (a flat
    Lambertian tile evaluates to kd/π·cos θi everywhere, not only at grid directions).
    """

    VERSION = 1

    def __init__(self, table, a_v, directions, facets, seed=0, tile="tile", footprint=1.0, materials=(),
                 backend="", timings=None):
        self.table = np.asarray(table, np.float32)
        self.a_v = np.asarray(a_v, np.float64)
        self.directions = int(directions)
        nd = self.directions**2
        if self.table.shape != (nd, nd, 3):
            raise ValueError(f"table must have shape ({nd}, {nd}, 3) for K={self.directions}, got {self.table.shape}")
        if not np.all(np.isfinite(self.table)) or (self.table < 0).any():
            raise ValueError("table must be finite and >= 0")
        self.facets, self.seed, self.tile, self.footprint = int(facets), int(seed), str(tile), float(footprint)
        self.materials = list(materials)
        self.backend = backend
        self.timings = dict(timings or {})

    def __repr__(self):
        return (f"GroundTruth(tile={self.tile!r}, K={self.directions}, facets={self.facets}, "
                f"materials={self.materials}, backend={self.backend!r})")

    @property
    def grid(self) -> np.ndarray:
        """(K², 3) the grid directions."""
        return dirs.grid(self.directions)

    def _corners(self, w):
        return dirs.bilinear_corners(w, self.directions)

    def eval(self, wi, wo) -> np.ndarray:
        """(N, 3) f̄ at arbitrary (ωi, ωo) by interpolation; 0 where either is below the horizon."""
        wi = dirs.check_directions("wi", wi)
        wo = dirs.check_directions("wo", wo)
        if len(wi) != len(wo):
            raise ValueError(f"wi and wo must have the same length, got {len(wi)} and {len(wo)}")
        grid_cos = self.grid[:, 2]
        per_cos = self.table / grid_cos[:, None, None]
        ii, wi_w = self._corners(wi)
        oo, wo_w = self._corners(wo)
        out = np.zeros((len(wi), 3))
        for a in range(4):
            for b in range(4):
                out += (wi_w[:, a] * wo_w[:, b])[:, None] * per_cos[ii[:, a], oo[:, b]]
        out *= np.maximum(wi[:, 2], 0.0)[:, None]
        out[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] = 0.0
        return out

    def albedo(self) -> np.ndarray:
        """(K², 3) directional albedo ∫f̄(ωi, ωo)dωi for each ωo on the grid.

        Integrates f̄/cos θi (the smooth part) against the exact ∫cos θ dω of each grid cell, so a
        flat Lambertian tile gives kd. Energy conservation of the tile bounds it by the largest
        small-scale albedo (≤ kd for a Lambertian tile).
        """
        weight = dirs.cell_cosine_integrals(self.directions) / self.grid[:, 2]
        return np.einsum("i,ioc->oc", weight, self.table.astype(np.float64))

    def save(self, path) -> None:
        """Write atomically as a versioned npz (`wb.load` reads it back)."""
        save_npz(path, "ground_truth", self.VERSION,
                 {"directions": self.directions, "facets": self.facets, "seed": self.seed, "tile": self.tile,
                  "footprint": self.footprint, "materials": self.materials, "backend": self.backend,
                  "timings": self.timings},
                 {"table": self.table, "a_v": self.a_v})

    @classmethod
    def load(cls, path) -> GroundTruth:
        head, arrays = read_npz(path, "ground_truth", versions=(cls.VERSION,))
        try:
            return cls(arrays["table"], arrays["a_v"], head["directions"], head["facets"], head.get("seed", 0),
                       head.get("tile", "tile"), head.get("footprint", 1.0), head.get("materials", ()),
                       head.get("backend", ""), head.get("timings"))
        except KeyError as exc:
            raise ValueError(f"{path} is missing {exc} (corrupt ground-truth file)") from None

