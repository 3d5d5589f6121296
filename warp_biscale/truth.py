"""The ground-truth effective BRDF (docs/design.md §4, §6): the one driver for facets → visibility → f̄.

f̄(ωi, ωo) = Σ_s c_s f_r(n_s, ωi, ωo)(n_s·ωi)⁺(n_s·ωo)⁺ V_s(ωi) V_s(ωo) ΔA_s / a_v(ωo)

with every small-scale BRDF evaluated exactly (no SG fit) and exact ray-cast visibility of the
infinitely tiled surface. The driver calls backend primitives only; it never asks which backend.

`truth_of(mat)` is the ground truth of a baked material, from what it records of how it was made
(`EffectiveBRDF.provenance`), cached on disk beside its material file and in memory.
"""

from __future__ import annotations

import collections
import hashlib
import os
import time
import warnings

import numpy as np

from . import directions as dirs
from .backend import get_backend
from .brdf import MEASURED, as_material_list, measured_tables, pack_materials
from .effective import EffectiveBRDF
from .io import check_output, read_npz, save_npz
from .progress import as_progress
from .smallscale import SmallScale, TileWarning

__all__ = ["effective_brdf_exact", "ground_truth", "GroundTruth", "MAX_FACETS", "TRUTH_FACETS", "truth_of",
           "truth_key", "truth_cache_path"]

MAX_FACETS = 1 << 26  # 67 M facets: 1.3 GB of facet data; beyond this, ask for fewer
# Facets of a baked material's ground truth (`truth_of`): what the bench's ground truths use
# (bench_bake --gt-facets), four times a bake's default.
TRUTH_FACETS = 1 << 18
# Part of every cache key: bump it when the ground truth's numbers change (a kernel fix), so that no
# table cached before is used again.
TRUTH_KEY_VERSION = 1
MAX_TRUTH_DIRECTIONS = 64  # ground_truth's largest K: a 4096² × 3 float32 table, 200 MB
MAX_BOUNCES = 16  # ground_truth(bounces=B): B in [1, MAX_BOUNCES]
BOUNCE_PATHS = 4096  # ground_truth's default paths per direction pair for the bounces 2..B
MAX_PATHS = 1 << 20
TRUTH_MEMORY = 8  # ground truths `truth_of` keeps per process (a K = 12 table is 0.25 MB)
_MEMORY = collections.OrderedDict()  # cache key → GroundTruth, most recent last


def _check_count(facets) -> int:
    try:
        n = int(facets)
    except (TypeError, ValueError):
        raise ValueError(f"facets must be a positive integer, got {facets!r}") from None
    if n != facets or n < 1 or n > MAX_FACETS:
        raise ValueError(f"facets must be an integer in [1, {MAX_FACETS}], got {facets!r}")
    return n


def check_seed(seed) -> int:
    """A facet-sampling seed: an integer in 0 .. 2**63 − 1 (numpy's SeedSequence takes no negative one)."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(f"seed must be an integer in 0 .. 2**63 - 1, got {seed!r}")
    return int(seed)


def _prepare(tile, materials, anisotropic: bool = False, measured: bool = False):
    """The tile checked and its materials normalised (one BRDF or a list, indexed by the tile's material ids):
    → (list of Brdf, kinds, params). Fewer BRDFs than the tile's ids is an error; more (than one) is a
    `TileWarning`, since the extra ones are never used. Shared by `ground_truth`, `effective_brdf_exact`
    and `bake.bake`; the warning points at their caller. `anisotropic`: accept anisotropic BRDFs (the
    ground truth, which passes the tile's face tangents to the kernels); `measured`: accept measured ones
    (the ground truth and the matrix bake, whose kernels take their tables: `brdf.measured_tables`)."""

    if not isinstance(tile, SmallScale):
        raise ValueError(f"tile must be a SmallScale (wb.SmallScale.load(...) or wb.geometry.*), got {tile!r}")
    mats = as_material_list(materials, anisotropic)
    kinds, params = pack_materials(mats, tile.n_materials, anisotropic, measured)
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
    materials : Brdf or list of Brdf, indexed by the tile's material ids. Anisotropic BRDFs
        (AnisotropicWard, AshikhminShirley) use the tile's face tangents (`SmallScale.face_tangents`).
    wi, wo : (N, 3) directions in the tile frame (z up); normalised here. Pairs with either
        direction at or below the horizon give 0.
    facets : number of facets Ns (the estimator's error falls faster than 1/√Ns).
    backend : a backend name (see `wb.backends()`) or object.
    seed : facet-sampling seed; the same seed gives the same result.

    Returns (N, 3) float64 RGB f̄, including cos θi (docs/design.md §4). Only the distinct directions of
    wi and wo are traced.
    """
    mats, kinds, params = _prepare(tile, materials, anisotropic=True, measured=True)
    tangents = _tangents(tile, mats)
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
    fac = be.sample_facets(tile, count, check_seed(seed))
    prog.stage(f"visibility ({len(unique)} dirs)", 1)
    vis = be.visibility(tile, fac, unique)
    prog.stage("effective BRDF", 1)
    a_v = be.visible_area(fac, vis)
    f = be.effective_brdf(fac, vis, kinds, params, pair_i, pair_o, a_v, tangents=tangents,
                          measured=measured_tables(mats))
    prog.done()
    return _sanitise(f).astype(np.float64)


def _tangents(tile, mats):
    """The tile's face tangents where a material is anisotropic, else None (the kernels then read none)."""
    return tile.face_tangents if any(m.anisotropic for m in mats) else None


def _sanitise(f: np.ndarray) -> np.ndarray:
    """No NaN, inf or negative value leaves the driver: a kernel that produced one is a bug."""
    bad = ~np.isfinite(f)
    if bad.any():
        raise FloatingPointError(f"a kernel produced {int(bad.sum())} non-finite effective-BRDF values")
    return np.maximum(f, 0.0)


def _check_bounces(bounces, paths) -> tuple[int, int]:
    if isinstance(bounces, bool) or not isinstance(bounces, (int, np.integer)) or not 1 <= bounces <= MAX_BOUNCES:
        raise ValueError(f"bounces must be an integer in [1, {MAX_BOUNCES}], got {bounces!r}")
    if isinstance(paths, bool) or not isinstance(paths, (int, np.integer)) or not 1 <= paths <= MAX_PATHS:
        raise ValueError(f"paths must be an integer in [1, {MAX_PATHS}], got {paths!r}")
    return int(bounces), int(paths)


def ground_truth(tile, materials, facets: int = 1 << 20, directions: int = 12, backend="auto", seed: int = 0,
                 progress=None, bounces: int = 1, paths: int = BOUNCE_PATHS) -> GroundTruth:
    """Ground-truth f̄ on the K×K direction grid (K = `directions`): all K²×K² pairs. Every small-scale BRDF is
    exact, the anisotropic ones (AnisotropicWard, AshikhminShirley) in the frame of the tile's face tangents
    (`SmallScale.face_tangents`, made perpendicular to each facet's normal), a MeasuredBRDF by its table's
    lookup in float32, as its `eval` (the kernels' `measured_cosine_weighted`).

    bounces : B in [1, 16]. 1 (the default) is the single-bounce truth above, unchanged. B > 1 adds the
        light that reaches a facet after 1..B−1 reflections inside the infinitely tiled surface (docs/design.md
        §4.6): a Monte Carlo estimate with `paths` paths per direction pair, each from a facet seen from ωo
        (facet ⌊(j + ½)·facets/paths⌋ for path j), continued by cosine-sampled directions traced through the
        periodic tile (closest hit), with next-event estimation towards ωi at every hit; its random numbers
        are a hash of (seed, path, ωo, dimension), so the same arguments give the same table. Faces' backs,
        rays leaving below the tile and rays crossing more than 64 cells are absorbed, so the estimate only
        loses energy. Hit points use their face's geometric normal. Cost ∝ K⁴ · paths · (B − 1) · 2 rays.
    paths : paths per direction pair for the bounces 2..B (ignored for B = 1).

    Returns a `GroundTruth` table with `eval(wi, wo)`, `save(path)`, and per-stage `timings`
    (seconds, device-synchronised).
    """
    mats, kinds, params = _prepare(tile, materials, anisotropic=True, measured=True)
    tangents = _tangents(tile, mats)
    measured = measured_tables(mats)  # (their tables go to the device once, kept there by identity)
    count = _check_count(facets)
    seed = check_seed(seed)
    bounces, paths = _check_bounces(bounces, paths)
    k = int(directions)
    if k != directions or not (2 <= k <= MAX_TRUTH_DIRECTIONS):
        raise ValueError(f"directions must be an integer grid size K in [2, {MAX_TRUTH_DIRECTIONS}], "
                         f"got {directions!r}")
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
        f = timer("effective_brdf", be.effective_brdf, fac, vis, kinds, params, pair_i[batch], pair_o[batch], a_v,
                  tangents=tangents, measured=measured)
        table[start:stop] = f.reshape(stop - start, nd, 3)
        prog.advance(stop - start)
    if bounces > 1:  # the bounces 2..B, added to the single-bounce table above
        rows = max(1, min(nd, (1 << 24) // (nd * paths * (bounces - 1))))
        prog.stage(f"interreflection ({bounces} bounces, {paths} paths)", nd)
        for start in range(0, nd, rows):
            stop = min(nd, start + rows)
            batch = slice(start * nd, stop * nd)
            f = timer("interreflection", be.interreflection, tile, fac, vis, kinds, params, pair_i[batch],
                      pair_o[batch], a_v, bounces, paths, seed, tangents=tangents, measured=measured)
            table[start:stop] += _sanitise(f).reshape(stop - start, nd, 3)
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
        bounces=bounces,
        paths=paths if bounces > 1 else 0,
    )


class GroundTruth:
    """f̄ tabulated on the K×K grid of docs/design.md §4: ``table[i, o]`` for ωi = grid[i], ωo = grid[o].

    `eval` interpolates bilinearly in the square domain of ωi and of ωo. It interpolates
    f̄ / cos θi and multiplies the query's cos θi back, so the known cosine factor is exact (a flat
    Lambertian tile evaluates to kd/π·cos θi everywhere, not only at grid directions).
    """

    VERSION = 1

    def __init__(self, table, a_v, directions, facets, seed=0, tile="tile", footprint=1.0, materials=(),
                 backend="", timings=None, key="", bounces=1, paths=0):
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
        self.key = str(key)  # `truth_key` of the material it was made for by `truth_of`, else ""
        self.bounces, self.paths = int(bounces), int(paths)  # ground_truth(bounces=, paths=); 1, 0: single bounce

    def __repr__(self):
        bounces = f", bounces={self.bounces}, paths={self.paths}" if self.bounces > 1 else ""
        return (f"GroundTruth(tile={self.tile!r}, K={self.directions}, facets={self.facets}, "
                f"materials={self.materials}, backend={self.backend!r}{bounces})")

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
        flat Lambertian tile gives kd. Energy conservation of the tile bounds the true albedo by the largest
        small-scale albedo (≤ kd for a Lambertian tile); this cell rule meets that bound only where f̄ is
        smooth over a cell: a lobe narrower than the grid's spacing, sampled at a node, is spread over the
        node's whole cell (a flat tile under Blinn–Phong 5000, energy-normalised, gives up to 17 at K = 8 and
        4.4 at K = 16), and with bounces > 1 each entry carries the paths' Monte Carlo noise (a white
        Lambertian tile's entries scatter about kd, docs/design.md §4.6).
        """
        weight = dirs.cell_cosine_integrals(self.directions) / self.grid[:, 2]
        return np.einsum("i,ioc->oc", weight, self.table.astype(np.float64))

    def save(self, path) -> None:
        """Write atomically as a versioned npz (`wb.load` reads it back)."""
        check_output(path, what="ground-truth file")
        save_npz(path, "ground_truth", self.VERSION,
                 {"directions": self.directions, "facets": self.facets, "seed": self.seed, "tile": self.tile,
                  "footprint": self.footprint, "materials": self.materials, "backend": self.backend,
                  "timings": self.timings, "key": self.key, "bounces": self.bounces, "paths": self.paths},
                 {"table": self.table, "a_v": self.a_v})

    @classmethod
    def load(cls, path) -> GroundTruth:
        head, arrays = read_npz(path, "ground_truth", versions=(cls.VERSION,))
        try:
            return cls(arrays["table"], arrays["a_v"], head["directions"], head["facets"], head.get("seed", 0),
                       head.get("tile", "tile"), head.get("footprint", 1.0), head.get("materials", ()),
                       head.get("backend", ""), head.get("timings"), head.get("key", ""), head.get("bounces", 1),
                       head.get("paths", 0))
        except KeyError as exc:
            raise ValueError(f"{path} is missing {exc} (corrupt ground-truth file)") from None



# ---------------------------------------------------------------------------------------------------
# the ground truth of a baked material, cached
# ---------------------------------------------------------------------------------------------------


def _truth_settings(mat, facets, seed, bounces=1, paths=BOUNCE_PATHS, directions=None):
    """Checked (facets, seed, bounces, paths, K) of `truth_of`; seed None is the bake's seed + 1, so the truth's
    facets are not the bake's own (as `warp-biscale bake --truth` does); directions None is the material's K."""
    if not isinstance(mat, EffectiveBRDF):
        raise ValueError(f"truth_of takes an EffectiveBRDF (wb.bake, wb.load), got {type(mat).__name__}")
    if mat.provenance is None:
        raise ValueError(f"{mat!r} does not record how it was baked (a material file of format 1, or built by "
                         "hand): compute its ground truth with wb.ground_truth(tile, materials, "
                         f"directions={mat.directions})")
    count = _check_count(facets)
    if seed is None:
        seed = mat.provenance.seed + 1
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"truth seed must be an integer >= 0 or None, got {seed!r}")
    bounces, paths = _check_bounces(bounces, paths)
    if directions is None:
        directions = mat.directions
    elif (isinstance(directions, bool) or not isinstance(directions, (int, np.integer))
          or not 2 <= directions <= MAX_TRUTH_DIRECTIONS):
        raise ValueError(f"truth directions must be an integer grid size K in [2, {MAX_TRUTH_DIRECTIONS}] or None "
                         f"(the material's K = {mat.directions}), got {directions!r}")
    return count, int(seed), bounces, paths, int(directions)


def truth_key(mat, facets: int = TRUTH_FACETS, seed=None, bounces: int = 1, paths: int = BOUNCE_PATHS,
              directions=None) -> str:
    """The hex SHA-256 of everything `truth_of(mat, facets, seed, bounces=, paths=, directions=)`'s table
    depends on: the
    tile's arrays (vertices, faces, material ids, colours, vertex normals, period, origin; the face tangents
    where a BRDF is anisotropic), the small-scale BRDFs of its material ids (type and packed parameters; a
    measured one's table and interpolation), K, the facet count and seed, the bounces and paths when B > 1,
    and TRUTH_KEY_VERSION. Not the tile's name, nor the backend: backends agree to float32 rounding
    (docs/design.md §3.3)."""
    count, seed, bounces, paths, k = _truth_settings(mat, facets, seed, bounces, paths, directions)
    tile = mat.provenance.tile
    # B = 1 adds nothing to the key (ground_truth ignores paths there), so the single-bounce tables cached
    # before bounces existed stay valid.
    multi = f"; bounces={bounces}; paths={paths}" if bounces > 1 else ""
    h = hashlib.sha256(f"warp_biscale ground truth v{TRUTH_KEY_VERSION}; K={k}; facets={count}; "
                       f"seed={seed}{multi}".encode())
    parts = {"vertices": tile.vertices, "faces": tile.faces, "material_ids": tile.material_ids,
             "colors": tile.colors, "vertex_normals": tile.vertex_normals,
             "period": np.asarray(tile.period, np.float64), "origin": tile.origin}
    if any(m.anisotropic for m in mat.materials[:tile.n_materials]):
        # (only then: the tangents change nothing else, and older keys stay valid)
        parts["face_tangents"] = tile.face_tangents
    for name, arr in parts.items():
        h.update(f"; {name}".encode())
        if arr is not None:  # dtype and shape too: the same bytes in another layout are another tile
            arr = np.ascontiguousarray(arr)
            h.update(f" {arr.dtype.str}{arr.shape}".encode())
            h.update(arr.tobytes())
    for m in mat.materials[:tile.n_materials]:
        h.update(f"; {type(m).__name__}".encode())
        if m.kind == MEASURED:  # its table and interpolation (its packed row is only a slot)
            h.update(f"{m.interpolation};".encode() + hashlib.sha256(np.ascontiguousarray(m.data).tobytes()).digest())
        else:
            h.update(np.asarray(m.packed(), np.float64).tobytes())
    return h.hexdigest()


def truth_cache_path(mat):
    """Where `truth_of` caches a material's ground truth: `<name>.truth.npz` beside its material file
    (`EffectiveBRDF.path`), or None for a material that has no file."""
    if getattr(mat, "path", None) is None:
        return None
    return os.path.splitext(mat.path)[0] + ".truth.npz"


def truth_of(mat, facets: int = TRUTH_FACETS, seed=None, backend="auto", progress=None, bounces: int = 1,
             paths: int = BOUNCE_PATHS, directions=None) -> GroundTruth:
    """The ground truth of a baked material (`wb.ground_truth` on its recorded tile and its current
    small-scale BRDFs), with `facets` facets drawn with `seed` (None: the bake's seed + 1) and `bounces` B of
    light inside the tiled surface (`ground_truth`'s; B > 1 adds the interreflection estimated with `paths`
    paths per direction pair, which B = 1 ignores), on a K×K grid of `directions` (None: the material's own K;
    at most MAX_TRUTH_DIRECTIONS).

    Between its nodes the table is interpolated (`GroundTruth.eval`), so a highlight narrower than the grid's
    spacing is blurred in it: a finer grid than the bake's makes a closer reference (docs/design.md §3.4).
    The cost grows as K⁴ × facets.

    Cached by `truth_key`, so a table is never used for another tile, BRDF or setting: on disk as
    `<name>.truth.npz` beside the material's file (`truth_cache_path`; one table a file, replaced when the key
    differs; a folder that takes no file leaves it in memory, with a warning), and in memory (the last
    TRUTH_MEMORY). A material without a provenance is a ValueError."""
    return cached_truth(mat, facets, seed, backend, progress, bounces, paths, directions)[0]


def cached_truth(mat, facets: int = TRUTH_FACETS, seed=None, backend="auto", progress=None, bounces: int = 1,
                 paths: int = BOUNCE_PATHS, directions=None):
    """`truth_of` → (GroundTruth, where it came from: "computed", "memory" or the cache file read)."""
    count, seed, bounces, paths, k = _truth_settings(mat, facets, seed, bounces, paths, directions)
    key = truth_key(mat, count, seed, bounces, paths, k)
    path = truth_cache_path(mat)
    if path is not None and os.path.exists(path):
        try:
            disk = GroundTruth.load(path)
        except (ValueError, OSError):  # unreadable: computed again and replaced below
            disk = None
        if disk is not None and disk.key == key:
            _remember(key, disk)
            return disk, path
    gt, source = _MEMORY.get(key), "memory"
    if gt is None:
        tile = mat.provenance.tile
        gt = ground_truth(tile, mat.materials[:tile.n_materials], facets=count, directions=k,
                          backend=backend, seed=seed, progress=progress, bounces=bounces, paths=paths)
        gt.key, source = key, "computed"
    _remember(key, gt)
    if path is not None:
        # A cache path that cannot be written only warns; any other ValueError of the save is a defect and goes on.
        try:
            check_output(path, what="ground-truth cache")
        except ValueError as exc:
            warnings.warn(f"could not write the ground-truth cache: {exc}; kept in memory only", stacklevel=3)
        else:
            try:
                gt.save(path)
            except OSError as exc:
                warnings.warn(f"could not write the ground-truth cache {path} ({exc.strerror or exc}): kept in "
                              "memory only", stacklevel=3)
    return gt, source


def _remember(key, gt):
    _MEMORY[key] = gt
    _MEMORY.move_to_end(key)
    while len(_MEMORY) > TRUTH_MEMORY:
        _MEMORY.popitem(last=False)
