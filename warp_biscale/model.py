"""Data passed between stages: facets and visibility (numpy arrays, validated on construction).

Backends may keep device copies of these arrays (in `device_cache`) so that one bake's stages do
not re-upload them. What a backend made on its device (`Facets.deferred`, `Visibility.deferred`) is
read back to the host only when host code asks for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import directions as dirs

__all__ = ["Facets", "Visibility", "run_ends"]

# {"get": backend.get_backend}, filled in by warp_biscale.backend when it loads (the package's __init__ imports it):
# the modules that the backends themselves import (a measured BRDF's SG fit, the lit sphere's texels) find a
# backend named by the user through it, without importing the backends.
BACKENDS: dict = {}


class Facets:
    """Ns area-weighted facets of a tile (Wu §3.2), float32 as the kernels use them.

    position (Ns,3), normal (Ns,3) unit shading normal, face (Ns,) source triangle,
    area (Ns,) ΔA_s, material (Ns,) id, color (Ns,3) RGB weight; `seed` made them.

    Facets that a backend sampled stay on its device (`deferred`): a host array is read back the
    first time it is asked for, so a bake whose stages all run on the device copies none of them.
    """

    FIELDS = ("position", "normal", "face", "area", "material", "color")
    _SHAPES = {"position": (3,), "normal": (3,), "face": (), "area": (), "material": (), "color": (3,)}

    def __init__(self, position, normal, face, area, material, color, seed: int = 0):
        self._count = len(position)
        self._host = dict(zip(self.FIELDS, (position, normal, face, area, material, color)))
        self._load = None
        self.seed = int(seed)
        self.device_cache = {}
        for name in self.FIELDS:
            self._check(name, self._host[name])
        if self._count == 0:
            raise ValueError("Facets needs at least one facet")

    @classmethod
    def deferred(cls, count: int, load, seed: int = 0, **known) -> Facets:
        """Facets whose arrays are made on first use by `load(name, facets)` (a backend's read-back;
        given the facets rather than holding them, so no reference cycle keeps device arrays alive);
        `known` arrays (by name) are given now."""
        self = cls.__new__(cls)
        self._count = int(count)
        if self._count < 1:
            raise ValueError("Facets needs at least one facet")
        self._host = {}
        self._load = load
        self.seed = int(seed)
        self.device_cache = {}
        for name, value in known.items():
            self._check(name, value)
            self._host[name] = value
        return self

    def _check(self, name, value):
        shape = (self._count, *self._SHAPES[name])
        if getattr(value, "shape", None) != shape:
            raise ValueError(f"Facets.{name} must have shape {shape}, got {getattr(value, 'shape', None)}")

    def _get(self, name):
        value = self._host.get(name)
        if value is None:
            value = self._load(name, self)
            self._check(name, value)
            self._host[name] = value
        return value

    position = property(lambda self: self._get("position"))
    normal = property(lambda self: self._get("normal"))
    face = property(lambda self: self._get("face"))
    area = property(lambda self: self._get("area"))
    material = property(lambda self: self._get("material"))
    color = property(lambda self: self._get("color"))

    def __len__(self):
        return self._count

    def __repr__(self):
        return f"Facets({self._count}, seed={self.seed})"

    def as_dict(self) -> dict:
        """The arrays as float64, in the form `warp_biscale.reference` takes."""
        return {
            "position": self.position.astype(np.float64),
            "normal": self.normal.astype(np.float64),
            "face": self.face,
            "area": self.area.astype(np.float64),
            "material": self.material,
            "color": self.color.astype(np.float64),
        }


class Visibility:
    """V_s(ω_k) for D directions and Ns facets, one bit each.

    bits (D, ceil(Ns/32)) uint32: bit (s mod 32) of word s // 32 in row k is V_s(ω_k). Rows are
    per direction so that a kernel tracing one direction for many neighbouring facets writes whole
    words, and the ground truth ANDs the rows of ωi and ωo a word at a time. A backend's result
    stays on its device (`deferred`) until host code reads `bits`.
    """

    def __init__(self, directions, bits, n_facets: int):
        self.directions = directions
        self.n_facets = int(n_facets)
        self.device_cache = {}
        self._load = None
        self._bits = self._check(bits)

    @classmethod
    def deferred(cls, directions, n_facets: int, load) -> Visibility:
        """Bits made on first use by `load()` (a backend's read-back)."""
        self = cls.__new__(cls)
        self.directions = directions
        self.n_facets = int(n_facets)
        self.device_cache = {}
        self._load = load
        self._bits = None
        return self

    @property
    def words(self) -> int:
        """Words per direction row: ceil(Ns/32)."""
        return (self.n_facets + 31) // 32

    def _check(self, bits):
        if bits.shape != (len(self.directions), self.words) or bits.dtype != np.uint32:
            raise ValueError(
                f"Visibility.bits must be uint32 of shape ({len(self.directions)}, {self.words}), "
                f"got {bits.dtype} {bits.shape}"
            )
        return bits

    @property
    def bits(self) -> np.ndarray:
        if self._bits is None:
            self._bits = self._check(self._load())
        return self._bits

    def __repr__(self):
        return f"Visibility({len(self.directions)} directions, {self.n_facets} facets)"

    def as_bool(self) -> np.ndarray:
        """(D, Ns) bool."""
        unpacked = np.unpackbits(self.bits.view(np.uint8), axis=1, bitorder="little")
        return unpacked[:, : self.n_facets].astype(bool)

    @staticmethod
    def pack(vis: np.ndarray) -> np.ndarray:
        """(D, Ns) bool → (D, ceil(Ns/32)) uint32, the layout of `bits`."""
        d, n = vis.shape
        padded = np.zeros((d, (n + 31) // 32 * 32), np.uint8)
        padded[:, :n] = vis
        return np.packbits(padded, axis=1, bitorder="little").view(np.uint32)

    @property
    def nbytes(self) -> int:
        return self.bits.nbytes


def run_ends(normal, weight) -> np.ndarray:
    """(Ns,) int32: for each facet, the index one past the run of consecutive facets that share its
    normal and weight, cut at the end of its 32-facet word (the kernels' `facet_runs` is this).
    Facets come ordered by face, and every facet of a flat face has the face's normal and weight, so
    a face's facets form one run; the lobe-moment kernels then count a run's visible facets in a
    32-facet word with one popcount instead of adding them one by one."""
    normal = np.asarray(normal)
    weight = np.asarray(weight)
    n = len(weight)
    if n == 0:
        return np.zeros(0, np.int32)
    change = np.ones(n, bool)
    change[1:] = (normal[1:] != normal[:-1]).any(axis=1) | (weight[1:] != weight[:-1])
    starts = np.flatnonzero(change)
    ends = np.append(starts[1:], n)
    word_end = np.minimum((np.arange(n) // 32 + 1) * 32, n)
    return np.minimum(np.repeat(ends, ends - starts), word_end).astype(np.int32)


def radical_inverse(s: np.ndarray) -> np.ndarray:
    """Van der Corput φ2(s) on the top 24 bits (exact in float32), for uint32 s."""
    s = np.asarray(s, np.uint64) & np.uint64(0xFFFFFFFF)
    r = np.zeros_like(s)
    for b in range(32):
        r |= ((s >> np.uint64(b)) & np.uint64(1)) << np.uint64(31 - b)
    return (r >> np.uint64(8)).astype(np.float64) / float(1 << 24)


def facet_shift(seed: int) -> tuple[float, float]:
    """The Cranley–Patterson shift (ξ1, ξ2) of a seed; shared by every backend."""
    rng = np.random.default_rng(int(seed))
    xi = rng.random(2)
    return float(xi[0]), float(xi[1])


@dataclass(eq=False)
class Bvndf:
    """The binned BVNDF of one bake (Iwasaki §5): cube-map bins at `resolution` (6×R×R).

    bins (L,) the non-empty bin ids, normal (L, 3) each bin's area-weighted mean facet normal,
    area (L,) Γ: the tile area whose normal falls in the bin (the NDF), solid_angle (L,) of each bin,
    a_v (K²,) the visible projected area of each grid direction, and histogram (U, L) N over the
    unordered direction pairs i ≤ o (`pair_index`) when it was computed (route "histogram" or
    ``bake(..., bvndf=True)``), else None.
    """

    resolution: int
    bins: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    a_v: np.ndarray
    histogram: np.ndarray | None = None

    @property
    def solid_angle(self) -> np.ndarray:
        r = self.resolution
        rem = self.bins % (r * r)
        row, col = rem // r, rem % r
        edge = np.linspace(-1.0, 1.0, r + 1)

        def f(u, v):
            return np.arctan2(u * v, np.sqrt(u * u + v * v + 1.0))

        u0, u1, v0, v1 = edge[col], edge[col + 1], edge[row], edge[row + 1]
        return f(u1, v1) - f(u0, v1) - f(u1, v0) + f(u0, v0)

    @property
    def ndf(self) -> np.ndarray:
        """Γ per steradian in each non-empty bin."""
        return self.area / self.solid_angle

    def pair_index(self, i, o):
        """Row of `histogram` for the direction pair (i, o) (either order)."""
        return dirs.unordered_index(i, o, len(self.a_v))

    def arrays(self) -> dict:
        out = {"bins": self.bins, "normal": self.normal, "area": self.area, "a_v": self.a_v}
        if self.histogram is not None:
            out["histogram"] = self.histogram
        return out

    @classmethod
    def from_arrays(cls, resolution, arrays) -> Bvndf:
        return cls(int(resolution), arrays["bins"], arrays["normal"], arrays["area"], arrays["a_v"],
                   arrays.get("histogram"))


@dataclass(eq=False)
class GBuffer:
    """A frame's G-buffer on the host (P = W·H pixels, row y·W + x): what `Backend.trace_primary` returns
    and what trace_shadows and shade take instead of the device's own copy. face (P,) int32, −1 = miss;
    bary (P, 2) float32 (u, v) weights of the face's vertices 1 and 2; position (P, 3) float32 hit point
    (0 on a miss); t (P,) float32 ray distance (inf on a miss); eye (3,) float32; light_vis (P, L) uint8,
    the share of light l visible from pixel p in 255ths (trace_shadows' result, which shade reads);
    occlusion (P,) uint32, bit i set where environment-occlusion ray i of occlusion_samples is blocked
    (trace_occlusion's result; occlusion_samples 0: none traced, the SSDF alone shadows the environment);
    lobe_occlusion (P,) uint32, bit k·trace.LOBE_RAYS + i set where ray i towards the inputs' sharp
    environment lobe k is blocked (trace_lobe_rays' result, read where occlusion_samples > 0); ray_part
    (index, count[, block_width[, block_side]]): which anti-aliasing sample of how many the light_vis, occlusion and
    lobe_occlusion rays were traced for (trace.pixel_parts: those rays of each set alone), (0, 1) for all of
    them; with a block width W > 0 the rays were shared in pixel blocks (trace.share_block), light_vis,
    occlusion and lobe_occlusion are the shared results, and occlusion_known and lobe_known (P,) uint32 hold
    the bits of the occlusion and lobe rays each pixel was lent (`Backend.ray_known`)."""
    face: np.ndarray
    bary: np.ndarray | None = None
    position: np.ndarray | None = None
    t: np.ndarray | None = None
    eye: np.ndarray | None = None
    light_vis: np.ndarray | None = None
    occlusion: np.ndarray | None = None
    occlusion_samples: int = 0
    lobe_occlusion: np.ndarray | None = None
    ray_part: tuple = (0, 1)
    occlusion_known: np.ndarray | None = None
    lobe_known: np.ndarray | None = None


@dataclass(eq=False)
class ShadeInputs:
    """What the shade stage reads that does not change with the camera (`render.static_inputs`), packed
    as the kernels take it: the large-scale mesh (faces (F, 3), positions, normals, tangents (V, 3),
    uvs (V, 2), face_material (F,)), the environment (env_sgs (K, 7) SG lobes, env_residual (H, W, 3) the
    exact irradiance less the lobes' (an equirect map over normals), env_maps and env_levels the
    prefiltered maps, n_sharp_lobes: how many of env_sgs' first rows get lobe rays,
    `shading.sharp_lobes_first`, axis_lobes: the row of the six shadow lobes whose occlusion-ray shares the
    kernels find in one walk, or −1, `shading.axis_lobe_start`), the SSDF (has_ssdf, ssdf_res, ssdf_basis
    (R + 1, res²), ssdf_coeffs (V, R),
    env_theta (V, K) its θd towards each environment lobe's axis at each vertex, `ssdf.ssdf_at_axes`), the SG
    lighting table, and the packed materials (mat_info … tex_data, `shading.pack_materials`).
    Backends keep their device copies in `device`, by backend name."""
    faces: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    face_material: np.ndarray
    uvs: np.ndarray
    env_sgs: np.ndarray
    env_residual: np.ndarray
    env_maps: np.ndarray
    env_levels: np.ndarray
    has_ssdf: bool
    ssdf_res: int
    ssdf_basis: np.ndarray
    ssdf_coeffs: np.ndarray
    env_theta: np.ndarray
    table: np.ndarray
    mat_info: np.ndarray
    analytic: np.ndarray
    eff_info: np.ndarray
    eff_lobes: np.ndarray
    eff_sub: np.ndarray
    eff_tables: np.ndarray
    eff_diffuse: np.ndarray
    tex_info: np.ndarray
    tex_data: np.ndarray
    n_sharp_lobes: int = 0
    axis_lobes: int = -1
    device: dict = field(default_factory=dict, repr=False)

    def sharp_lobes(self) -> np.ndarray:
        """(M, 4) float32 [axis, η] of the sharp environment lobes (env_sgs' first n_sharp_lobes rows): what
        `backend.trace_lobe_rays` takes."""
        return np.ascontiguousarray(np.asarray(self.env_sgs, np.float32)[:int(self.n_sharp_lobes), :4])


@dataclass(eq=False)
class Frame:
    """One frame for the shade stage (`render.pack_frame`): its inputs, its G-buffer on the host (with
    light_vis), the camera (Camera.packed(), (16,)) and the lights ((L, 8), Light.packed())."""
    inputs: ShadeInputs
    gbuffer: GBuffer
    camera: np.ndarray
    lights: np.ndarray


class DeviceArray:
    """A float32 array a backend left on its device, read back only when host code asks for it: `shape`, `ndim`,
    `size`, `nbytes`, len(); numpy reads it through `__array__` (np.asarray, arithmetic, concatenation), a pickle
    or copy holds the host array. `owner`: the backend whose `device` it is (its flat view, for a kernel's flat
    argument); `reshape` and `ravel` are views of the same device array."""

    def __init__(self, owner, device, flat, shape, read):
        self.owner, self.device, self.flat, self.shape = owner, device, flat, tuple(int(s) for s in shape)
        self.dtype = np.dtype(np.float32)
        self._read, self._host = read, None

    def host(self) -> np.ndarray:
        if self._host is None:
            self._host = self._read()
        return self._host

    ndim = property(lambda self: len(self.shape))
    size = property(lambda self: int(np.prod(self.shape)))
    nbytes = property(lambda self: self.size * self.dtype.itemsize)

    def __len__(self):
        return self.shape[0]

    def __array__(self, dtype=None, copy=None):
        a = self.host()
        return a if dtype is None else a.astype(dtype, copy=False)

    def __reduce__(self):
        return np.asarray, (self.host(),)

    def reshape(self, *shape):
        shape = shape[0] if len(shape) == 1 and isinstance(shape[0], (tuple, list)) else shape
        new = np.empty(self.shape, bool).reshape(shape).shape  # (numpy's rules, -1 included)
        return DeviceArray(self.owner, self.device, self.flat, new, lambda: self.host().reshape(new))

    def ravel(self):
        return self.reshape(-1)
