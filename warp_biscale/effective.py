"""The baked effective BRDF (Iwasaki §4.1): SG lobes of the NDF, amplitude tables, and the closed forms.

f̄(ωi, ωo) = Σ_m [ kd_m/π · Σ_j μ_mj(ωi, ωo)·∫G_j                                   (Eq. 9)
              + M_m(ωi, ωo) · Σ_j μ_mj(ωi, ωo)·S(h; ξ_j, η_j, η_s,m) ]                (Eq. 15 / Eq. 10)

with μ_mj (RGB) the amplitudes of lobe j for material m, tabulated on the K×K × K×K direction grid,
M_m, η_s,m the small-scale specular BRDF as an SG in the facet normal (`sg.specular_lobe`; a measured BRDF's
SG fit of two lobes is the sum of two such terms, `sg.specular_lobes`), h the
half vector and S either the SG-convolution closure (method "sg", Iwasaki Eq. 14–15) or the exact
SG inner product (method "sg-exact", Eq. 10). The amplitudes do not depend on the small-scale BRDFs,
so `with_materials` edits a material without re-baking anything.

A material made by `wb.bake` also records how it was made (`Provenance`: the tile and the bake's facet
seed; the small-scale BRDFs are `materials`), so that its exact ground truth can be rebuilt from it (the
Monte Carlo reference does, `truth.truth_of`). Material files of format 2 carry it; a format-1 file, or
a material built by hand, has none.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
import warnings

import numpy as np

from . import brdf as brdf_mod
from . import directions as dirs
from . import sg
from .model import Bvndf, DeviceArray
from .io import check_output, read_npz, save_npz
from .lobes import LobeSet
from .measured import MeasuredBRDF
from .smallscale import SmallScale, TileWarning

__all__ = ["EffectiveBRDF", "Provenance", "compare", "METHODS", "AMPLITUDE_MAX", "check_amplitudes"]

METHODS = ("sg", "sg-exact")
# The lobe types of `shade_lobes` (the shade stage's eff_info[:, 7]): SG lobes [axis, η] (Iwasaki), or ASG
# lobes [z, 0, x, λ, μ] (Xu 2013, `asg_bake.ASGBRDF`).
SG_LOBES, ASG_LOBES = 0, 1
EFF_LOBE_WIDTH = 9  # a lobe row of the shade kernels (`shading.pack_materials`' eff_lobes)
# Writers of a baked material for other renderers, by name, each (material, path) → what it wrote. The
# interface modules that write them fill this in when warp_biscale loads (mitsuba_export), so that this
# data-model module imports none of them.
EXPORTERS: dict = {}

# The environment's diffuse term reads f̄d prefiltered over ωi by its lobe (`energy_levels`, weighed by each
# small-scale material's kd/π in the shade stage): level 0 is f̄d itself (a sharp lobe: its axis), level
# l ≥ 1 the mean of f̄d/cos θ under a lobe of sharpness DIFFUSE_LEVEL_ETAS[l] (a lobe reads the level nearest
# its η in log, `diffuse_level`: a lobe of η ≥ 64/√8 ≈ 23 its axis, one of η ≤ 1/(8√8) ≈ 0.044 the broadest).
DIFFUSE_LEVEL_ETAS = (np.inf, 8.0, 1.0, 0.125, 0.015625)
DIFFUSE_LEVEL_SHARP = 64.0  # η at level coordinate 0: the sharpest lobe that reads f̄d at its axis
DIFFUSE_LEVEL_STEP = 8.0  # the ratio of neighbouring levels' η


# The largest amplitude μ_mj a material may hold (a file's is checked when it is read). In a bake μ_mj·∫G_j is the
# share of the view that lobe j's facets fill (≤ 1: 0.9994 the most measured over flat, pyramid, groove and rod
# tiles), so μ_mj ≤ 1/∫G_j ≤ sg.SHARPNESS_MAX/(2π) ≈ 1.6e5 (1.59e5 measured: a flat facet's lobe); this bound leaves
# 600 times that. Every amplitude of lobes.MAX_LOBES = 128 broad lobes (η = sg.SHARPNESS_MIN) at this bound, under the
# brightest light a scene takes (scene.LIGHT_POWER_MAX = 1e20) and an environment of environment.RADIANCE_MAX, gave at
# most 1.5e36 in the SG renderer (the largest small-scale factor tried: CookTorrance(ks=1, roughness=3, f0=1, kd=1),
# whose M = ks·F/(π cos²θd) peaks at grazing view; the Monte Carlo reference reads the exact ground truth instead),
# under float32's 3.4e38 with 200 times to spare. (A forged file's 3e38 rendered black in the SG renderer, its
# overflow cleared, and 1e38 elsewhere.)
AMPLITUDE_MAX = 1e8


def check_amplitudes(amplitudes, name: str = "amplitudes") -> None:
    """A one-line ValueError unless every value of an amplitude table is finite, >= 0 and at most AMPLITUDE_MAX."""
    a = np.asarray(amplitudes)
    if not a.size:
        return
    if not (a.min() >= 0 and np.isfinite(a.max())):  # (a NaN fails min() >= 0)
        raise ValueError(f"{name} must be finite and >= 0")
    if a.max() > AMPLITUDE_MAX:
        raise ValueError(f"{name} hold values up to {float(a.max()):.3g}: at most {AMPLITUDE_MAX:g} (a bake's reach "
                         f"about 1.6e5; more would overflow the renderers' float32)")


def diffuse_level(eta):
    """The level a lobe of sharpness η reads in the shade stage: the nearest in log η, round(u) of
    u = log_STEP(DIFFUSE_LEVEL_SHARP/η) clamped to [0, len(DIFFUSE_LEVEL_ETAS) − 1] (η = DIFFUSE_LEVEL_ETAS[l] at
    u = l). One level, not two blended: an environment lobe's η is the same at every pixel, so the choice
    makes no seam, and one table lookup a lobe keeps the diffuse term's cost what it was."""
    eta = np.maximum(np.asarray(eta, np.float64), 1e-30)
    u = np.clip(np.log(DIFFUSE_LEVEL_SHARP / eta) / np.log(DIFFUSE_LEVEL_STEP), 0.0, len(DIFFUSE_LEVEL_ETAS) - 1.0)
    return np.floor(u + 0.5).astype(int)


@functools.lru_cache(maxsize=8)
def level_weights(k: int) -> np.ndarray:
    """((L − 1)·K², K²) float32, read-only: row (l, ξ) holds G(ω_g; ξ, η_l)·cos θξ / Σ_g G(ω_g; ξ, η_l)·cos θ_g
    over ω_g (`broad_levels`' product; the bake's table kernels apply it on the device)."""
    g = dirs.grid(k)
    cos = g[:, 2]
    w = np.stack([np.exp(eta * (g @ g.T - 1.0)) for eta in DIFFUSE_LEVEL_ETAS[1:]])  # (L − 1, ξ, ω)
    w *= (cos / (w @ cos))[..., None]
    out = w.reshape(-1, len(g)).astype(np.float32)
    out.flags.writeable = False  # (one object per K: a backend's upload cache knows it without hashing)
    return out


def device_levels(backend, k: int):
    """`level_weights(k)` where a bake's table kernels should prefilter its energy into levels beside the tables
    (Backend.material_tables), or None where the host's float32 product (`broad_levels`, made when a renderer
    first asks) is the cheaper: on a CPU device, whose kernels run the product far slower than the host's BLAS
    (K = 12, two materials, this 2-core CPU: 71 ms on Warp CPU and 30 ms on PoCL against 2.5 ms in numpy;
    bench/README.md). A GPU makes them in microseconds and keeps them for the shade stage."""
    return level_weights(k) if backend.is_gpu else None


def broad_levels(table, k: int) -> np.ndarray:
    """(L − 1, M, K², K², 3) float32 of (M, K², K², 3) tables of f̄ values (cosine θi included) on the K×K
    grid: per level l ≥ 1 (η = DIFFUSE_LEVEL_ETAS[l]) P(ξ, ωo)·cos θξ, where P(ξ, ωo) =
    Σ_g G(ω_g; ξ, η)·f̄(ω_g, ωo) / Σ_g G(ω_g; ξ, η)·cos θ_g over the grid's equal-area cells: the mean of f̄/cos θ
    under the lobe, which times ∫G(n·ω)⁺ is ∫G·f̄ — what an environment lobe of that width sees, where the
    value at its axis is what a sharp one sees. (Stored times cos θξ so the shade stage's lookup, which divides
    by the grid's cos θ, reads P.) Linear in the table: a bake prefilters its energy once, an edit only
    re-weighs it."""
    t = np.asarray(table, np.float32)
    m, k2 = t.shape[0], k * k
    out = level_weights(k) @ t.reshape(m, k2, -1)  # (M, (L − 1)·K², K²·3)
    return out.reshape(m, len(DIFFUSE_LEVEL_ETAS) - 1, k2, k2, 3).transpose(1, 0, 2, 3, 4)


def _brdf_to_dict(b) -> dict:
    return {"type": type(b).__name__, **{f.name: getattr(b, f.name) for f in dataclasses.fields(b)}}


def materials_to_file(materials) -> tuple[list, dict]:
    """The small-scale BRDFs as a material file holds them: (JSON dicts for its header, arrays): an analytic
    BRDF's parameters, a measured one's table as array "measured_<i>" (`MeasuredBRDF.to_file`)."""
    dicts, arrays = [], {}
    for i, b in enumerate(materials):
        if b.kind == brdf_mod.MEASURED:
            head, table = b.to_file(f"measured_{i}")
            dicts.append(head)
            arrays.update(table)
        else:
            dicts.append(_brdf_to_dict(b))
    return dicts, arrays


def materials_from_file(dicts, arrays) -> list:
    """The BRDFs `materials_to_file` wrote. Their EnergyWarning (a BRDF reflecting more than it receives) is not
    given again: it was given when the material was built, and a warning at each load would point at this
    module, not at the caller, about a material the user did not just build."""
    if not isinstance(dicts, list) or not all(isinstance(d, dict) for d in dicts):
        raise ValueError(f"its materials must be a list of BRDF tables, got {str(dicts)[:80]}")
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", brdf_mod.EnergyWarning)
        for i, d in enumerate(dicts):
            try:
                out.append(MeasuredBRDF.from_file(d, arrays) if d.get("type") == "MeasuredBRDF" else _brdf_from_dict(d))
            except (TypeError, ValueError) as exc:  # (which of the file's materials, the loader names the file)
                raise ValueError(f"material {i}: {exc}") from None
    return out


def _brdf_from_dict(d: dict):
    """An analytic BRDF from its table (`_brdf_to_dict`): a one-line ValueError for an unknown type or a key that is
    not one of its parameters (the class's own TypeError named neither the table nor the parameters it takes)."""
    cls = getattr(brdf_mod, d.get("type", ""), None)
    if not (isinstance(cls, type) and issubclass(cls, brdf_mod.Brdf) and dataclasses.is_dataclass(cls)):
        raise ValueError(f"unknown BRDF type {d.get('type')!r} in material file")
    names = [f.name for f in dataclasses.fields(cls)]
    for key in d:
        if key != "type" and key not in names:
            raise ValueError(f"{cls.__name__} has no parameter {key!r}; its parameters: {', '.join(names)}")
    return cls(**{k: v for k, v in d.items() if k != "type"})


@dataclasses.dataclass(frozen=True, eq=False)
class Provenance:
    """How a baked material was made, enough to compute its exact ground truth: the tile (its arrays are
    kept exactly, so a tile rebuilt from a file is the same tile), the bake's facet count and seed. The
    small-scale BRDFs are the material's own `materials` (a material-only edit changes them, not this)."""

    tile: SmallScale
    seed: int = 0
    facets: int = 0

    def __post_init__(self):
        if not isinstance(self.tile, SmallScale):
            raise ValueError(f"Provenance.tile must be a SmallScale, got {type(self.tile).__name__}")

    def arrays(self) -> dict:
        """The tile as the npz arrays of a material file (`tile_*`)."""
        t = self.tile
        out = {"tile_vertices": t.vertices, "tile_faces": t.faces, "tile_material_ids": t.material_ids,
               "tile_colors": t.colors, "tile_period": np.asarray(t.period, np.float64), "tile_origin": t.origin}
        if t.vertex_normals is not None:
            out["tile_vertex_normals"] = t.vertex_normals
        # (the face tangents, such as the woven tile's along its threads, which an anisotropic BRDF's truth and bake
        # follow: kept exactly, as a generator's own may differ from the default by an ulp, 24 bytes a face; a file
        # written before them reloads with the default)
        out["tile_face_tangents"] = t.face_tangents
        return out

    def header(self) -> dict:
        return {"tile": self.tile.name, "seed": self.seed, "facets": self.facets}

    @classmethod
    def from_file(cls, head: dict, arrays: dict) -> Provenance:
        """Rebuild from `header()` and `arrays()`, bit for bit: the stored tile is already clean (no duplicate
        vertex, no degenerate face), so building it again changes no vertex, face, id or colour. A TileWarning it
        gave at bake time (seams) is not repeated on every load."""
        normals = arrays.get("tile_vertex_normals")
        tangents = arrays.get("tile_face_tangents")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TileWarning)
            tile = SmallScale(arrays["tile_vertices"], arrays["tile_faces"], arrays["tile_material_ids"],
                              arrays["tile_colors"], tuple(arrays["tile_period"]), normals,
                              str(head.get("tile", "tile")), arrays["tile_origin"], tangents)
        # SmallScale normalises the normals and tangents again, which moves about a third of unit vectors by an
        # ulp: the stored ones go back before anything sees the tile, so its truth is that of the tile baked.
        for name, stored in (("vertex_normals", normals), ("face_tangents", tangents)):
            if stored is not None:
                stored = np.array(stored, np.float64)
                stored.flags.writeable = False
                setattr(tile, name, stored)
        return cls(tile, int(head.get("seed", 0)), int(head.get("facets", 0)))


def interpolated_amplitudes(amplitudes, grid, directions: int, wi, wo) -> np.ndarray:
    """(M, N, J, 3) μ at (ωi, ωo) from a bake's (M, K², K², J, 3) table on its K×K `grid`, bilinear in the
    square domain of each direction; μ/cos θi is what is interpolated (the cos θi of γ̃ then comes out exact,
    as in `GroundTruth.eval`). Any lobe kind's amplitudes (SG, ASG) are interpolated alike."""
    ii, wi_w = dirs.bilinear_corners(wi, directions)
    oo, wo_w = dirs.bilinear_corners(wo, directions)
    per_cos = amplitudes / grid[:, 2][None, :, None, None, None]
    out = np.zeros((len(amplitudes), len(wi), amplitudes.shape[3], 3))
    for a in range(4):
        for b in range(4):
            out += (wi_w[:, a] * wo_w[:, b])[None, :, None, None] * per_cos[:, ii[:, a], oo[:, b]]
    return out * np.maximum(wi[:, 2], 0.0)[None, :, None, None]


def grid_amplitudes(amplitudes) -> np.ndarray:
    """(M, K⁴, J, 3) float64 μ at every pair of a bake's own K×K grid, in `directions.all_pairs` order: the tables
    themselves, which `interpolated_amplitudes` gives there up to its bilinear weights' rounding (~1e-15), without
    its sixteen gathers (most of a K = 12 table's time: `table`)."""
    a = np.asarray(amplitudes, np.float64)
    return a.reshape(a.shape[0], a.shape[1] * a.shape[2], *a.shape[3:])


class EffectiveBRDF:
    """A baked material. Build it with `wb.bake`; read it back with `wb.load`.

    Attributes: `lobes` (LobeSet: axes, sharpness, weight), `amplitudes` (M, K², K², J, 3) float32
    μ tables, `diffuse` (K², K², 3) the f̄d table of Eq. 9, `materials` (the small-scale BRDFs),
    `directions` K, `method`, `timings` (seconds per stage, device-synchronised), `info` (facets,
    seed, backend, NDF fit error, Gram condition number, ...), `provenance` (how it was baked: a
    `Provenance`, or None for a format-1 file or a material built by hand), `path` (the material file it
    was read from or last saved to, absolute; None if neither: where the Monte Carlo reference caches its
    ground truth).
    """

    VERSION = 2  # 2: the provenance (tile arrays, bake seed and facet count); version 1 files are still read
    VERSIONS = (1, 2)

    def __init__(self, lobes: LobeSet, amplitudes, materials, directions: int, method: str = "sg", timings=None,
                 info=None, bvndf=None, provenance: Provenance | None = None, path=None, _energy=None,
                 _energy_levels=None):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.lobes = lobes
        sharp = np.asarray(lobes.sharpness)
        if sharp.min() < sg.SHARPNESS_MIN or sharp.max() > sg.SHARPNESS_MAX:
            # (a bake's EM keeps them there; the shade stage's float32 made a forged 1e300 inf, and the lobe black)
            raise ValueError(f"lobe sharpness must lie in [{sg.SHARPNESS_MIN:g}, {sg.SHARPNESS_MAX:g}], the SG forms' "
                             f"range, got {sharp.min():.3g} to {sharp.max():.3g}")
        # (a bake's tables may stay on its device, a DeviceArray: `amplitudes` reads them when first asked for)
        self._amplitudes = amplitudes if isinstance(amplitudes, DeviceArray) else np.asarray(amplitudes, np.float32)
        self.directions = int(directions)
        nd = self.directions**2
        j = len(lobes)
        shape = self._amplitudes.shape
        if len(shape) != 5 or shape[1:] != (nd, nd, j, 3):
            raise ValueError(f"amplitudes must have shape (M, {nd}, {nd}, {j}, 3), got {shape}")
        if _energy is None:  # (checked once, where _energy was made: a bake's or an edit's tables are not again)
            check_amplitudes(self.amplitudes)
        self.materials = brdf_mod.as_material_list(materials)
        if len(self.materials) != shape[0]:
            raise ValueError(f"{shape[0]} amplitude table(s) but {len(self.materials)} material(s)")
        self.method = method
        self.timings = dict(timings or {})
        self.info = dict(info or {})
        self.bvndf = bvndf
        if provenance is not None and not isinstance(provenance, Provenance):
            raise ValueError(f"provenance must be an effective.Provenance or None, got {type(provenance).__name__}")
        if provenance is not None and provenance.tile.n_materials > len(self.materials):
            raise ValueError(f"provenance: the tile has {provenance.tile.n_materials} material ids but the material "
                             f"has {len(self.materials)} BRDF(s)")
        self.provenance = provenance
        self.path = None if path is None else os.path.abspath(os.fspath(path))
        self._integrals = sg.integral(self.lobes.sharpness)
        # Σ_j μ_mj ∫G_j = ∫γ̃ per material: independent of the BRDFs, so a material edit reuses it.
        self._energy = (np.einsum("miojc,j->mioc", self.amplitudes, self._integrals.astype(np.float32))
                        if _energy is None else _energy)
        # `energy_levels`: the bake's (made on the device with the tables), else made on first use; kept by edits
        if _energy_levels is not None and np.shape(_energy_levels) != (len(self.materials), len(DIFFUSE_LEVEL_ETAS),
                                                                        nd, nd, 3):
            raise ValueError(f"energy levels of shape {np.shape(_energy_levels)} do not fit the tables")
        self._energy_levels = _energy_levels
        self._diffuse = None  # `diffuse`, made on first use (the renderer reads `energy_levels` instead)

    @property
    def amplitudes(self) -> np.ndarray:
        """(M, K², K², J, 3) float32 μ tables (read back from the device the first time, where the bake left
        them there)."""
        if isinstance(self._amplitudes, DeviceArray):
            self._amplitudes = np.asarray(self._amplitudes)
        return self._amplitudes

    @amplitudes.setter
    def amplitudes(self, value):
        self._amplitudes = value

    def shade_tables(self) -> tuple:
        """(the μ tables, the energy levels) as the shade stage takes them (`shading.pack_materials`): where the
        bake left them on its device, those device arrays (a backend's DeviceArray; no read-back, no upload
        again), else host arrays."""
        levels = self._energy_levels if isinstance(self._energy_levels, DeviceArray) else self.energy_levels
        return self._amplitudes, levels

    def __repr__(self):
        return (f"EffectiveBRDF(K={self.directions}, lobes={len(self.lobes)}, materials={self.materials}, "
                f"method={self.method!r})")

    # ------------------------------------------------------------------ tables
    @property
    def diffuse(self) -> np.ndarray:
        """(K², K², 3) float32 f̄d on the grid (Eq. 9): Σ_m kd_m/π Σ_j μ_mj ∫G_j."""
        if self._diffuse is None:
            self._diffuse = self._diffuse_table()
        return self._diffuse

    def _diffuse_table(self) -> np.ndarray:
        kd = np.stack([brdf_mod.diffuse_albedo(mat).astype(np.float32) for mat in self.materials]) / np.float32(np.pi)
        return np.einsum("mioc,mc->ioc", self._energy, kd).astype(np.float32, copy=False)  # (one pass: an edit's cost)

    def shade_lobes(self) -> tuple[int, np.ndarray]:
        """What the SG renderer's shade stage reads of the lobes (`shading.pack_materials`): the lobe type
        (SG_LOBES) and rows (J, EFF_LOBE_WIDTH) float32 [axis (3), η, 0 …] in the tile frame."""
        rows = np.zeros((len(self.lobes), EFF_LOBE_WIDTH), np.float32)
        rows[:, 0:3], rows[:, 3] = self.lobes.axes, self.lobes.sharpness
        return SG_LOBES, rows

    def sampling_lobes(self) -> tuple[np.ndarray, np.ndarray]:
        """(axes (J, 3), sharpness (J,)) in the tile frame: the lobes the Monte Carlo reference's BRDF sampling
        warps (`montecarlo_sampling._LobeMixtureStrategy`)."""
        return self.lobes.axes, self.lobes.sharpness

    @property
    def energy_levels(self) -> np.ndarray:
        """(M, L, K², K², 3) float32, read-only: per small-scale material m its energy Σ_j μ_mj∫G_j on the grid
        (level 0) and its `broad_levels` (levels 1 …, prefiltered by DIFFUSE_LEVEL_ETAS): what the SG renderer's
        diffuse term reads, weighing level lookups by each material's kd/π (so f̄d = Σ_m kd_m/π·level 0). It does
        not depend on the small-scale BRDFs: made once per bake, kept by `with_materials`, so a material edit
        uploads nothing new for it."""
        if isinstance(self._energy_levels, DeviceArray):
            self._energy_levels = np.asarray(self._energy_levels)
            self._energy_levels.setflags(write=False)
        if self._energy_levels is None:
            broad = broad_levels(self._energy, self.directions)  # (L − 1, M, K², K², 3)
            levels = np.ascontiguousarray(np.concatenate([np.asarray(self._energy, np.float32)[None], broad])
                                          .transpose(1, 0, 2, 3, 4))
            levels.setflags(write=False)
            self._energy_levels = levels
        return self._energy_levels

    @property
    def nbytes_per_material(self) -> int:
        """Bytes of the μ table of one material (what a renderer uploads per material)."""
        return int(self._amplitudes.nbytes // self._amplitudes.shape[0])

    @property
    def grid(self) -> np.ndarray:
        return dirs.grid(self.directions)

    def with_materials(self, materials) -> EffectiveBRDF:
        """The same baked geometry with other small-scale BRDFs (a material-only edit: no re-bake). The
        provenance (the tile) and `path` carry over: the new BRDFs are the recorded ones, so the Monte Carlo
        reference computes the edited material's ground truth, and caches it beside the same file."""
        t0 = time.perf_counter()
        # (a method="auto" choice was made for the old BRDFs: not carried over)
        out = EffectiveBRDF(self.lobes, self._amplitudes, materials, self.directions, self.method,
                            info={k: v for k, v in self.info.items() if k != "method_choice"}, bvndf=self.bvndf,
                            provenance=self.provenance, path=self.path, _energy=self._energy)
        out._energy_levels = self._energy_levels
        out.timings = {"tables": time.perf_counter() - t0}
        return out

    # ------------------------------------------------------------------ evaluation
    def _interpolated_amplitudes(self, wi, wo) -> np.ndarray:
        """(M, N, J, 3) μ at (ωi, ωo): `interpolated_amplitudes` of this bake's tables."""
        return interpolated_amplitudes(self.amplitudes, self.grid, self.directions, wi, wo)

    def eval(self, wi, wo, method: str | None = None, *, _on_grid: bool = False) -> np.ndarray:
        """(N, 3) f̄(ωi, ωo) (cosine θi included, docs/design.md §4) at arbitrary directions; 0 below the horizon.

        method: "sg" (Eq. 15, the SG closure) or "sg-exact" (Eq. 10); default the bake's. (`_on_grid`: `table`'s
        call, (ωi, ωo) every pair of the bake's grid: the tables are read as they are, `grid_amplitudes`.)
        """
        method = self.method if method is None else method
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        wi = dirs.check_directions("wi", wi)
        wo = dirs.check_directions("wo", wo)
        if len(wi) != len(wo):
            raise ValueError(f"wi and wo must have the same length, got {len(wi)} and {len(wo)}")
        mu = grid_amplitudes(self.amplitudes) if _on_grid else self._interpolated_amplitudes(wi, wo)  # (M, N, J, 3)
        ax, eta = self.lobes.axes, self.lobes.sharpness
        out = np.zeros((len(wi), 3))
        for m, mat in enumerate(self.materials):
            kd = brdf_mod.diffuse_albedo(mat) / np.pi
            out += np.einsum("njc,j->nc", mu[m], self._integrals) * kd
            for eta_s, scale, h in sg.specular_lobes(mat, wi, wo):  # one, or a measured BRDF's fit's two
                if eta_s is None or not scale.any():
                    continue  # no specular path for a Lambertian or ks = 0 material
                if method == "sg":
                    eta_c, amp_c = sg.convolve(eta, 1.0, eta_s, 1.0)
                    s = sg.evaluate(h[:, None, :], ax[None], eta_c[None], amp_c[None])  # (N, J)
                else:
                    s = sg.inner_product(h[:, None, :], eta_s, 1.0, ax[None], eta[None], 1.0)
                out += scale * np.einsum("njc,nj->nc", mu[m], s)
        out[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] = 0.0
        return np.maximum(out, 0.0)

    def table(self, method: str | None = None) -> np.ndarray:
        """(K², K², 3) f̄ on the bake's own grid: table[i, o] at ωi = grid[i], ωo = grid[o]."""
        g = self.grid
        pi, po = dirs.all_pairs(len(g))
        return self.eval(g[pi], g[po], method, _on_grid=True).reshape(len(g), len(g), 3)

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write atomically as a versioned npz (`wb.load` reads it back); `path` then names this file."""
        check_output(path, what="material file")
        arrays = {"axes": self.lobes.axes, "sharpness": self.lobes.sharpness, "weight": self.lobes.weight,
                  "amplitudes": self.amplitudes}
        if self.bvndf is not None:
            arrays.update({f"bvndf_{k}": v for k, v in self.bvndf.arrays().items()})
        if self.provenance is not None:
            arrays.update(self.provenance.arrays())
        materials, tables = materials_to_file(self.materials)
        arrays.update(tables)
        save_npz(path, "effective_brdf", self.VERSION,
                 {"directions": self.directions, "method": self.method,
                  "materials": materials, "info": self.info,
                  "timings": self.timings, "bvndf_resolution": None if self.bvndf is None else self.bvndf.resolution,
                  "provenance": None if self.provenance is None else self.provenance.header()},
                 arrays)
        self.path = os.path.abspath(os.fspath(path))

    def export_mitsuba(self, path) -> dict:
        """Write what Mitsuba 3 needs to render this material into folder `path`: a copy of it (material.wbm),
        scene.xml (a sphere of it) and render.py (registers the plugin, renders the scene) → {"material",
        "scene", "script": their paths}. docs/mitsuba.md; `warp_biscale.mitsuba_export`."""
        return EXPORTERS["mitsuba"](self, path)

    @classmethod
    def load(cls, path) -> EffectiveBRDF:

        head, arrays = read_npz(path, "effective_brdf", versions=cls.VERSIONS)
        try:
            lobes = LobeSet(arrays["axes"], arrays["sharpness"], arrays["weight"])
            mats = materials_from_file(head["materials"], arrays)
            bv = None
            if head.get("bvndf_resolution") is not None:
                bv = Bvndf.from_arrays(head["bvndf_resolution"], {k[6:]: v for k, v in arrays.items()
                                                                  if k.startswith("bvndf_")})
            prov = Provenance.from_file(head["provenance"], arrays) if head.get("provenance") is not None else None
            return cls(lobes, arrays["amplitudes"], mats, head["directions"], head.get("method", "sg"),
                       head.get("timings"), head.get("info"), bv, prov, path)
        except KeyError as exc:
            raise ValueError(f"{path} is missing {exc} (corrupt material file)") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path} is not a valid material file: {exc}") from None


def _truth_like(obj) -> bool:
    """Whether `obj` holds a ground truth's data: a `directions` count and a `table` array (a GroundTruth's
    table is an attribute; an EffectiveBRDF's is a method)."""
    table = getattr(obj, "table", None)
    return table is not None and not callable(table) and getattr(obj, "directions", None) is not None


def compare(mat, gt, method: str | None = None) -> dict:
    """Error of an effective BRDF (an `EffectiveBRDF`, or another `GroundTruth`, e.g. one with fewer
    facets) against a ground truth (`wb.ground_truth`), on the truth's grid.

    Metric of Wu Table 4: the cosine-weighted BRDF f̄ (our tables include cos θi) over all K²×K²
    pairs and RGB. Returns rmse, psnr = 20·log10(peak / rmse) with peak the truth's maximum, and
    max_rel_error = max |f̄ − f̄_gt| / f̄_gt over the entries where f̄_gt ≥ 1 % of the peak. Analytic
    small-scale BRDFs that differ between the two (a bake judged against another material's truth) are
    warned about.
    """
    # The arguments are checked by shape rather than class so that a table-holding stand-in (an object with
    # `directions` and a `table` array, as tests and scripts build) still compares; swapped or missing
    # arguments otherwise fail deep inside with messages about methods and floats.
    if not _truth_like(gt):
        raise ValueError(f"gt must be a GroundTruth (wb.ground_truth), got {type(gt).__name__}")
    if not (isinstance(mat, EffectiveBRDF) or _truth_like(mat)):
        raise ValueError(f"mat must be an EffectiveBRDF (wb.bake, wb.load) or a GroundTruth, got {type(mat).__name__}")
    # A ground truth names its small-scale BRDFs by repr; analytic ones are their exact parameters (a measured
    # table's repr names its file alone, so it is not compared).
    mine = [m if isinstance(m, str) else repr(m) for m in getattr(mat, "materials", None) or []]
    theirs = [str(m) for m in getattr(gt, "materials", None) or []]
    n = min(len(mine), len(theirs))  # (materials past a tile's ids reflect nothing: one side may list more)
    mine, theirs = mine[:n], theirs[:n]
    # (a warning, not an error: two spellings of one BRDF, AnisotropicWard(a, a) and Ward(a), judge each other)
    if mine != theirs and not any(m.startswith("MeasuredBRDF(") for m in mine + theirs):
        warnings.warn(f"compare: the material's small-scale BRDFs {mine} are not the ground truth's {theirs}: a "
                      "material is judged against the truth of its own tile and small-scale materials", stacklevel=2)
    ref = np.asarray(gt.table, np.float64)
    same_grid = getattr(mat, "directions", None) == gt.directions
    if same_grid and callable(getattr(mat, "table", None)):
        est = mat.table(method)
    elif same_grid:  # a GroundTruth: its table is an array
        est = np.asarray(mat.table, np.float64)
    else:
        g = dirs.grid(gt.directions)
        pi, po = dirs.all_pairs(len(g))
        args = (method,) if isinstance(mat, EffectiveBRDF) else ()
        est = mat.eval(g[pi], g[po], *args).reshape(ref.shape)
    diff = est - ref
    rmse = float(np.sqrt(np.mean(diff**2)))
    peak = float(ref.max())
    big = ref >= 0.01 * peak
    rel = float(np.max(np.abs(diff[big]) / ref[big])) if big.any() else 0.0
    psnr = float("inf") if rmse == 0 else float(20 * np.log10(peak / rmse)) if peak > 0 else float("-inf")
    return {"rmse": rmse, "psnr": psnr, "max_rel_error": rel, "peak": peak}


class HostOnlyBRDF(EffectiveBRDF):
    """An effective BRDF with no SG lobes (the ASG and matrix methods' materials): what reads SG lobes — the
    SG renderer, the Monte Carlo reference's sampling, the Mitsuba export — gets `no_sg_lobes` as a one-line
    ValueError, and the lit-sphere renderer evaluates it on the host (`host_texels`: no texel kernel reads
    its tables). A subclass sets `no_sg_lobes` and its own eval, files and tables."""

    host_texels = True
    no_sg_lobes = "this material has no SG lobes"

    @property
    def lobes(self):
        raise ValueError(self.no_sg_lobes)

    def shade_lobes(self):
        raise ValueError(self.no_sg_lobes)

    def sampling_lobes(self):
        raise ValueError(self.no_sg_lobes)

    @property
    def diffuse(self):
        raise ValueError(self.no_sg_lobes)

    def _interpolated_amplitudes(self, wi, wo):
        raise ValueError(self.no_sg_lobes)

    def export_mitsuba(self, path) -> dict:
        """Refused before anything is written: the Mitsuba plugin evaluates and samples SG lobes."""
        raise ValueError(self.no_sg_lobes)
