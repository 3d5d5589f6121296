"""Visibility of the large-scale mesh as spherical signed distance functions (Wang 2009 §5).

Every vertex x gets its binary visibility V_x(ω) over the FULL sphere of world directions, sampled
on an octahedral S×S grid (default S = 32), and turned into an SSDF (Wang Eq. 23): θd(ω) is the
angle from ω to the nearest direction of the opposite class, positive where ω is visible, negative
where it is occluded. One common world frame for all vertices (not Wang's per-vertex tangent
frame) means the SSDFs of a triangle's vertices interpolate with no tangent-frame seams and the PCA
basis (Wang Eq. 24) is shared. Directions below the vertex's tangent plane (ω·n_x < 0) count as
occluded, so each SSDF holds the horizon plus whatever geometry blocks above it.

Pipeline (`build`): rays from every vertex in every grid direction above its horizon, any-hit
against the whole mesh (`backend.trace_occluded`) → (V, S²) visibility → distance transform on the
device (`backend.ssdf_distance`, exact, O(V·S²·scanned texels)) → PCA on the host in float64 →
`SsdfField` (mean + NV eigenvectors, coefficients per vertex), cached on the mesh.

The octahedral map (world axes, folded along z):
    encode d → p = d/(|dx|+|dy|+|dz|); if p.z < 0: (p.x, p.y) ← ((1−|p.y|)·sgn p.x, (1−|p.x|)·sgn p.y)
    with sgn 0 = +1; (u, v) = ((p.x+1)/2, (p.y+1)/2) ∈ [0, 1]².
Texel (i, j) (i along u, j along v) is centred at ((i+½)/S, (j+½)/S) and has flat index j·S + i.

Grid rule for θd (one rule everywhere, the kernels' and the reference's): with a the exact angle
from texel k's direction to the nearest texel direction of the opposite class, and h_k half the
angle from texel k to its nearest neighbouring texel direction,
    θd_k = +(a − h_k) if k is visible,  −(a − h_k) if k is occluded,  ±π if no texel is of the other class.
So the zero crossing sits half way between two texels of opposite class (the sampled boundary),
and since a ≥ 2·h_k the sign of θd is always the texel's class and |θd| ≥ h_k.

Evaluation (the shade kernel's contract, `ssdf_eval` below): at a point with per-point
coefficients c (barycentric blend of the vertices' coefficients), θd(ω) = Σ_r c_r·basis_r(ω) with
c_0 = 1, each basis image looked up bilinearly at continuous texel coordinates
x = u·S − ½, y = v·S − ½ clamped to [0, S−1]. The octahedral map's edge mirroring is ignored: in
the half-texel band along the square's border the lookup extrapolates the border texels flat
instead of blending with the mirrored texel across the edge (error measured in tests/test_ssdf.py).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .backend import get_backend
from .io import cache_folder, read_npz, save_npz
from .progress import as_progress
from .scene import SSDF_RESOLUTIONS
from .trace import offsets

__all__ = [
    "SsdfField",
    "SsdfGrid",
    "build",
    "compress",
    "distance_field",
    "grid",
    "octahedral_decode",
    "octahedral_encode",
    "octahedral_grid",
    "ssdf_at_axes",
    "texel_solid_angles",
    "vertex_visibility",
]

DEFAULT_RESOLUTION = 32
DEFAULT_TERMS = 16
MAX_AUTO_TERMS = 48  # Wang §5.2 uses NV = 48
RAYS_PER_CALL = 1 << 20  # rays handed to trace_occluded at once (bounds host memory, moves the progress bar)
BLOCK_MARGIN = 1e-3  # rad added to each block's cone radius so float32 rounding never prunes a block wrongly


# ------------------------------------------------------------------------------ octahedral map
def _sgn(x):
    """sign with sgn(0) = +1 (the octahedral fold's convention)."""
    return np.where(x >= 0, 1.0, -1.0)


def octahedral_encode(d) -> np.ndarray:
    """(..., 3) directions (any length > 0) → (..., 2) float64 (u, v) in [0, 1]²."""
    d = np.asarray(d, np.float64)
    p = d / np.abs(d).sum(axis=-1, keepdims=True)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    low = z < 0
    fx = np.where(low, (1 - np.abs(y)) * _sgn(x), x)
    fy = np.where(low, (1 - np.abs(x)) * _sgn(y), y)
    return np.stack([(fx + 1) / 2, (fy + 1) / 2], axis=-1)


def octahedral_decode(uv) -> np.ndarray:
    """(..., 2) (u, v) in [0, 1]² → (..., 3) float64 unit directions (inverse of octahedral_encode)."""
    uv = np.asarray(uv, np.float64)
    x, y = 2 * uv[..., 0] - 1, 2 * uv[..., 1] - 1
    z = 1 - np.abs(x) - np.abs(y)
    low = z < 0
    fx = np.where(low, (1 - np.abs(y)) * _sgn(x), x)
    fy = np.where(low, (1 - np.abs(x)) * _sgn(y), y)
    d = np.stack([fx, fy, z], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)




def _check_resolution(resolution) -> int:
    s = int(resolution)
    if s != resolution or not SSDF_RESOLUTIONS[0] <= s <= SSDF_RESOLUTIONS[1]:
        lo, hi = SSDF_RESOLUTIONS
        raise ValueError(f"SSDF resolution must be an integer in {lo}..{hi}, got {resolution!r}")
    return s


def octahedral_grid(resolution: int) -> np.ndarray:
    """(S·S, 3) float64 unit directions of the texel centres, index j·S + i."""
    s = _check_resolution(resolution)
    c = (np.arange(s) + 0.5) / s
    u, v = np.meshgrid(c, c, indexing="xy")  # u[j, i] = c[i], v[j, i] = c[j]: row-major index j·S + i
    return octahedral_decode(np.stack([u.ravel(), v.ravel()], axis=-1))


def texel_solid_angles(resolution: int, subdivisions: int = 8) -> np.ndarray:
    """(S·S,) float64 solid angle of each texel (sr), measured: each texel is cut into
    subdivisions² cells, each cell into two spherical triangles of its decoded corners (the
    Van Oosterom–Strackee formula). The triangles tile the sphere, so the sum is 4π up to rounding;
    the per-texel values converge as the cells shrink."""
    s = _check_resolution(resolution)
    m = int(subdivisions)
    n = s * m
    t = np.arange(n + 1) / n
    corners = octahedral_decode(np.stack(np.meshgrid(t, t, indexing="xy"), axis=-1))  # [row j, col i]
    a, b = corners[:-1, :-1], corners[:-1, 1:]
    c, d = corners[1:, 1:], corners[1:, :-1]

    def tri(p, q, r):
        num = np.einsum("...k,...k->...", p, np.cross(q, r))
        den = 1 + (p * q).sum(-1) + (q * r).sum(-1) + (r * p).sum(-1)
        return 2 * np.arctan2(num, den)

    cell = tri(a, b, c) + tri(a, c, d)  # (n, n) [row, col]; counter-clockwise in (u, v) → positive
    return cell.reshape(s, m, s, m).sum(axis=(1, 3)).ravel()


@dataclass(eq=False)
class SsdfGrid:
    """The direction grid of one resolution and what the distance transform needs about it.

    directions (N, 3) float64 texel centres (N = S²); half_angle (N,) h_k, half the angle (rad) to the
    nearest other texel direction; blocks of b×b neighbouring texels for pruning: block_members
    (B, M) int32 texel indices (−1 pads a block cut by the grid's edge), block_axis (B, 3) unit,
    block_radius (B,) rad, a cone around the axis that holds every member (plus BLOCK_MARGIN).
    """

    resolution: int
    directions: np.ndarray
    half_angle: np.ndarray
    block_members: np.ndarray
    block_axis: np.ndarray
    block_radius: np.ndarray
    device_cache: dict = field(default_factory=dict, repr=False)

    def block_classes(self, visible: np.ndarray) -> np.ndarray:
        """(V, B) uint8 per vertex and block: bit 0 set if a member is visible, bit 1 if one is occluded."""
        members = self.block_members
        valid = members >= 0
        vis = np.asarray(visible, bool)[:, np.where(valid, members, 0)]  # (V, B, M)
        has_vis = (vis & valid).any(axis=2)
        has_occ = (~vis & valid).any(axis=2)
        return (has_vis.astype(np.uint8) | (has_occ.astype(np.uint8) << 1))


def _block_size(s: int) -> int:
    # Work per thread ≈ 2 cone tests per block + the texels scanned. At S = 32 (a sphere over a plane,
    # counted in numpy) blocks of side 2, 3, 4, 6, 8 cost about 524, 272, 187, 195, 259 such steps
    # (brute force: 1024); on warp:cpu (1000 horizon-plus-cap vertices) side 4 took about half the time of
    # side 2 and two thirds that of side 8.
    return max(1, min(s, int(round(np.sqrt(s) * 0.75))))


@functools.lru_cache(maxsize=8)
def grid(resolution: int = DEFAULT_RESOLUTION, block: int | None = None) -> SsdfGrid:
    """The (cached) SsdfGrid of resolution S; `block` texels a block side (default ≈ 0.75·√S)."""
    s = _check_resolution(resolution)
    b = _block_size(s) if block is None else max(1, min(s, int(block)))
    dirs = octahedral_grid(s)
    n = len(dirs)
    nearest = np.empty(n)
    step = max(1, (1 << 22) // n)  # rows of the N×N cosine matrix at a time (N = 16384 at S = 128)
    for a in range(0, n, step):
        cos = dirs[a:a + step] @ dirs.T
        cos[np.arange(len(cos)), np.arange(a, a + len(cos))] = -2.0  # not itself
        nearest[a:a + step] = cos.max(axis=1)
    half = 0.5 * np.arccos(np.clip(nearest, -1.0, 1.0))
    nb = -(-s // b)
    members = np.full((nb * nb, b * b), -1, np.int32)
    for bj in range(nb):
        for bi in range(nb):
            jj, ii = np.meshgrid(np.arange(bj * b, min(s, bj * b + b)), np.arange(bi * b, min(s, bi * b + b)),
                                 indexing="ij")
            idx = (jj * s + ii).ravel()
            members[bj * nb + bi, :len(idx)] = idx
    axis = np.zeros((len(members), 3))
    radius = np.zeros(len(members))
    for k, row in enumerate(members):
        d = dirs[row[row >= 0]]
        a = d.sum(0)
        a /= np.linalg.norm(a)  # a block is small and compact on the sphere: its mean is never 0
        axis[k] = a
        radius[k] = np.arccos(np.clip(d @ a, -1.0, 1.0)).max() + BLOCK_MARGIN
    return SsdfGrid(s, dirs, half, members, axis, radius)


# ------------------------------------------------------------------------------ visibility
def vertex_visibility(mesh, backend, resolution: int = DEFAULT_RESOLUTION, progress=None) -> np.ndarray:
    """(V, S²) bool: V_x(ω_k) for every vertex x and grid direction ω_k (world frame).

    Directions with ω·n_x < 0 are occluded by definition (the horizon); the others are traced as
    any-hit rays (`backend.trace_occluded`, no distance limit) from x + eps·n_x against the whole
    mesh, eps = trace.SHADOW_OFFSET × mesh.scale = 1e-4 × scale, the shadow rays' offset (clears
    float32 rounding of positions, far below any modelled feature).
    """

    backend = get_backend(backend)
    g = grid(resolution)
    prog = as_progress(progress)
    above = mesh.normals @ g.directions.T >= 0  # (V, N)
    v_idx, k_idx = np.nonzero(above)
    eps = offsets(mesh)[0]
    occluded = np.zeros(len(v_idx), bool)
    prog.stage(f"SSDF rays ({len(v_idx)})", max(1, -(-len(v_idx) // RAYS_PER_CALL)))
    for a in range(0, len(v_idx), RAYS_PER_CALL):
        vi, ki = v_idx[a:a + RAYS_PER_CALL], k_idx[a:a + RAYS_PER_CALL]
        origins = mesh.vertices[vi] + eps * mesh.normals[vi]
        occluded[a:a + RAYS_PER_CALL] = backend.trace_occluded(mesh, origins, g.directions[ki], np.inf)
        prog.advance()
    visible = np.zeros(above.shape, bool)
    visible[v_idx, k_idx] = ~occluded
    return visible


# ------------------------------------------------------------------------------ SSDF and PCA
def distance_field(visible: np.ndarray, backend, resolution: int | None = None) -> np.ndarray:
    """(V, S²) float32 θd (radians) of (V, S²) visibility, on the backend (rule: module docstring)."""
    visible = np.asarray(visible)
    if visible.ndim != 2:
        raise ValueError(f"visible must be a (V, S²) array, got shape {visible.shape}")
    s = int(round(np.sqrt(visible.shape[1]))) if resolution is None else _check_resolution(resolution)
    if s * s != visible.shape[1]:
        raise ValueError(f"visible has {visible.shape[1]} columns, not S² for an S×S grid")

    return get_backend(backend).ssdf_distance(grid(s), visible.astype(bool))


def _check_terms(terms, n: int):
    if isinstance(terms, str):
        if terms != "auto":
            raise ValueError(f"terms must be an integer >= 1 or 'auto', got {terms!r}")
        return
    try:
        ok = int(terms) == terms and 1 <= int(terms) <= n
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"terms must be an integer in 1..{n} (the texel count) or 'auto', got {terms!r}")


def compress(theta: np.ndarray, terms=DEFAULT_TERMS, tolerance: float | None = None):
    """PCA of per-vertex SSDFs (Wang Eq. 24) in float64 on the host.

    theta (V, N) radians. terms: an int NV ≥ 1 (padded with zero eigenvectors past the data's rank, so
    the shapes are always what was asked), or "auto": the smallest NV ≥ 1 (at most MAX_AUTO_TERMS)
    whose reconstruction RMS error is below `tolerance` rad (default: a quarter of the mean texel
    angle, √(4π/N)/4, below the grid's own quantisation of the boundary).
    → (mean (N,), eigenvectors (NV, N), coefficients (V, NV), rms_by_terms) all float64, where
    rms_by_terms[k] is the exact RMS residual (rad) keeping k = 0..K terms, K = max(NV, MAX_AUTO_TERMS)
    or the rank bound min(V, N) if smaller.

    Only the leading K eigenpairs are computed (scipy's subset eigh), of the smaller of the V×V Gram
    matrix and the N×N covariance: the residual of k terms is the total energy less the k largest
    eigenvalues, so no full spectrum is needed.
    """
    x = np.asarray(theta, np.float64)
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
        raise ValueError(f"theta must be a non-empty (V, N) array, got shape {x.shape}")
    n_v, n = x.shape
    _check_terms(terms, n)
    auto = terms == "auto"
    want = MAX_AUTO_TERMS if auto else max(int(terms), MAX_AUTO_TERMS)
    mean = x.mean(axis=0)
    xc = x - mean
    k = min(want, n_v, n)
    if n_v <= n:  # few vertices: eigenvectors u of the Gram matrix give principal axes xcᵀu/√λ
        energy, u = scipy.linalg.eigh(xc @ xc.T, subset_by_index=[n_v - k, n_v - 1])
        energy, u = np.maximum(energy[::-1], 0.0), u[:, ::-1]
        keep = energy > 1e-12 * max(energy[0], 1e-300)  # (numerically) zero ones are not directions
        vectors = np.zeros((k, n))
        vectors[keep] = (xc.T @ u[:, keep] / np.sqrt(energy[keep])).T
    else:
        energy, e = scipy.linalg.eigh(xc.T @ xc, subset_by_index=[n - k, n - 1])
        energy, vectors = np.maximum(energy[::-1], 0.0), e[:, ::-1].T
    total = float((xc**2).sum())
    residual = np.maximum(total - np.concatenate([[0.0], np.cumsum(energy)]), 0.0)
    rms_by_terms = np.sqrt(residual / x.size)
    if auto:
        tol = np.sqrt(4 * np.pi / n) / 4 if tolerance is None else float(tolerance)
        if not tol > 0:
            raise ValueError(f"tolerance must be > 0 rad, got {tolerance!r}")
        ok = np.nonzero(rms_by_terms[1:] < tol)[0]
        nv = int(ok[0]) + 1 if len(ok) else min(MAX_AUTO_TERMS, n)
    else:
        nv = int(terms)
    basis = np.zeros((nv, n))
    basis[:min(nv, k)] = vectors[:min(nv, k)]
    # A deterministic sign per eigenvector (eigh may flip them): its largest entry positive.
    flip = np.where(basis[np.arange(nv), np.abs(basis).argmax(axis=1)] < 0, -1.0, 1.0)
    basis *= flip[:, None]
    coeffs = xc @ basis.T
    return mean, basis, coeffs, rms_by_terms


@dataclass(eq=False)
class SsdfField:
    """PCA-compressed SSDFs of a mesh's vertices (the shade kernel's input).

    resolution S (octahedral S×S grid); basis (NV+1, S·S) float32, row 0 the mean SSDF, rows 1.. the
    eigenvectors (rad); coeffs (V, NV) float32 per vertex; rms_error (rad) the measured RMS of
    reconstruction − exact grid SSDF over all vertices and texels, in float32 as stored;
    occluded False when no vertex ray hit geometry above its horizon (then θd = asin(ω·n) serves);
    rms_by_terms the exact float64 RMS residual keeping k = 0..rank terms; timings (s) per step.
    At a point with coefficients c (V's coeffs blended by barycentrics), θd(ω) = basis_0(ω) +
    Σ_r c_r·basis_r(ω), each basis row looked up bilinearly (module docstring; ssdf_eval).
    """

    resolution: int
    basis: np.ndarray
    coeffs: np.ndarray
    rms_error: float
    occluded: bool
    rms_by_terms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    timings: dict = field(default_factory=dict)

    @property
    def terms(self) -> int:
        return self.basis.shape[0] - 1

    def vertex_ssdf(self) -> np.ndarray:
        """(V, S²) float64 reconstructed SSDF of every vertex at the texel centres."""
        return self.basis[0].astype(np.float64) + self.coeffs.astype(np.float64) @ self.basis[1:].astype(np.float64)

    def eval(self, coeffs, directions) -> np.ndarray:
        """θd (rad) at directions (P, 3) or (P, K, 3) for per-point coefficients (P, NV) (float64)."""
        return ssdf_eval(self.basis, coeffs, self.resolution, directions)


def _fingerprint(mesh) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in (mesh.vertices, mesh.faces, mesh.normals):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


DISK_CACHE_ENTRIES = 32  # SSDFs kept on disk (the least recently used go first); ~0.7 MB for 10 000 vertices


@functools.lru_cache(maxsize=1)
def _code_digest() -> str | None:
    """A digest of the package's source (host code, Warp kernels, OpenCL kernels) as the process first reads it,
    with numpy's version: an SSDF kept on disk by one version of the code is never read by another. None where no
    source can be read (a frozen install): then nothing is kept on disk."""
    h = hashlib.blake2b(np.__version__.encode(), digest_size=16)
    read = 0
    # The package's folders: its own, and in a source checkout the root that holds kernels/ and cl/ (__init__.py)
    roots = list(dict.fromkeys(os.path.abspath(r) for r in sys.modules[__package__].__path__))
    for root in roots:
        for sub in ("", "kernels", "cl"):
            folder = os.path.join(root, sub)
            if not os.path.isdir(folder):
                continue
            for name in sorted(os.listdir(folder)):
                if name.endswith((".py", ".cl")):
                    with open(os.path.join(folder, name), "rb") as fh:
                        h.update(name.encode() + fh.read())
                    read += 1
    return h.hexdigest() if read else None


def disk_cache_path(mesh, backend_name: str, resolution: int, terms, tolerance, skip_unoccluded: bool) -> str | None:
    """The file `build` keeps this SSDF in between processes (`io.cache_folder()`/ssdf): named by a digest of the
    geometry, the settings, the backend that traced it and the code (`_code_digest`); None where the code's digest
    cannot be made (an unreadable source file, a frozen install): the SSDF is then built and not kept."""
    try:
        code = _code_digest()
    except OSError:
        return None
    if code is None:
        return None
    key = repr(("ssdf", 1, _fingerprint(mesh), backend_name, int(resolution), terms, tolerance,
                bool(skip_unoccluded), code))
    name = hashlib.blake2b(key.encode(), digest_size=16).hexdigest()
    return os.path.join(cache_folder(), "ssdf", f"{name}.npz")


def _read_disk(path, resolution: int, n_vertices: int) -> SsdfField | None:
    """The SSDF kept at `path`, or None where there is none or it is unreadable or not this mesh's shape."""
    try:
        head, arrays = read_npz(path, "ssdf_cache")
        basis, coeffs = arrays["basis"], arrays["coeffs"]
        if (basis.dtype != np.float32 or coeffs.dtype != np.float32 or basis.ndim != 2 or coeffs.ndim != 2
                or basis.shape[1] != resolution * resolution or coeffs.shape != (n_vertices, basis.shape[0] - 1)
                or not (np.isfinite(basis).all() and np.isfinite(coeffs).all())):
            return None
        with contextlib.suppress(OSError):  # recently used: the last to go (a read-only folder: still read)
            os.utime(path)
        return SsdfField(resolution, basis, coeffs, float(head["rms_error"]), bool(head["occluded"]),
                         arrays["rms_by_terms"], {})
    except Exception:  # noqa: BLE001 - whatever is wrong with a kept file, the SSDF is built again
        return None


def _write_disk(path, field_: SsdfField) -> None:
    """Keep `field_` at `path` (atomically), then drop the least recently used beyond DISK_CACHE_ENTRIES; a folder
    that takes no file costs the next process the build, nothing more."""
    try:
        save_npz(path, "ssdf_cache", 1, {"rms_error": float(field_.rms_error), "occluded": bool(field_.occluded)},
                 {"basis": field_.basis, "coeffs": field_.coeffs,
                  "rms_by_terms": np.asarray(field_.rms_by_terms, np.float64)})
        folder = os.path.dirname(path)
        kept = sorted((os.path.getmtime(os.path.join(folder, f)), f) for f in os.listdir(folder)
                      if f.endswith(".npz") and not f.startswith("."))  # (not another process's file being written)
        for _, name in kept[:max(0, len(kept) - DISK_CACHE_ENTRIES)]:
            os.remove(os.path.join(folder, name))
    except OSError:
        pass


def build(mesh, backend="auto", resolution: int = DEFAULT_RESOLUTION, terms=DEFAULT_TERMS, progress=None,
          tolerance: float | None = None, skip_unoccluded: bool = False, disk_cache: bool = True) -> SsdfField:
    """SSDF visibility of `mesh` (Wang §5), compressed with `terms` PCA terms (int or "auto", see
    `compress`). Cached on the mesh (`mesh.device_cache`, keyed by resolution, terms, tolerance and
    a hash of the geometry), so rendering the same mesh again costs nothing; and, with `disk_cache`, on disk
    between processes (`disk_cache_path`: the geometry, settings, backend and code; the DISK_CACHE_ENTRIES most
    recently used kept), so a new process rendering a mesh it rendered before skips the build (timings then
    {"disk": s, "total": s}).

    skip_unoccluded: when no vertex ray hits anything (`occluded` False, the renderer then uses the
    horizon asin(ω·n)), skip the distance transform and the PCA: the field's basis is then one zero
    row, its coeffs (V, 0) and rms_error NaN — placeholders, not an SSDF.
    timings: "trace" (rays), "distance" (distance transform), "pca", "total" — seconds, device
    synchronised.
    """

    s = _check_resolution(resolution)
    _check_terms(terms, s * s)
    key = ("ssdf", s, terms, tolerance, _fingerprint(mesh))
    cached = mesh.device_cache.get(key) or (mesh.device_cache.get(key + ("skip",)) if skip_unoccluded else None)
    if cached is not None:
        return cached
    be = get_backend(backend)
    t0 = time.perf_counter()
    path = disk_cache_path(mesh, be.name, s, terms, tolerance, skip_unoccluded) if disk_cache else None
    kept = _read_disk(path, s, len(mesh.vertices)) if path else None
    if kept is not None:
        elapsed = time.perf_counter() - t0
        kept.timings = {"disk": elapsed, "total": elapsed}
        mesh.device_cache[key + (("skip",) if skip_unoccluded and not kept.occluded else ())] = kept
        return kept
    prog = as_progress(progress)
    timings = {}
    visible = vertex_visibility(mesh, be, s, prog)
    be.synchronize()
    t1 = time.perf_counter()
    timings["trace"] = t1 - t0
    above = mesh.normals @ grid(s).directions.T >= 0
    occluded = bool((above & ~visible).any())
    if skip_unoccluded and not occluded:
        timings["total"] = timings["trace"]
        prog.done()
        result = SsdfField(s, np.zeros((1, s * s), np.float32), np.zeros((len(visible), 0), np.float32),
                           float("nan"), False, np.zeros(0), timings)
        mesh.device_cache[key + ("skip",)] = result
        if path:
            _write_disk(path, result)
        return result
    prog.stage(f"SSDF distance ({len(visible)}x{s * s})", 1)
    theta = distance_field(visible, be, s)
    be.synchronize()
    t2 = time.perf_counter()
    timings["distance"] = t2 - t1
    prog.stage("SSDF PCA", 1)
    mean, vectors, coeffs, rms_by_terms = compress(theta, terms, tolerance)
    basis32 = np.concatenate([mean[None], vectors]).astype(np.float32)
    coeffs32 = coeffs.astype(np.float32)
    recon = basis32[0].astype(np.float64) + coeffs32.astype(np.float64) @ basis32[1:].astype(np.float64)
    rms = float(np.sqrt(np.mean((recon - theta) ** 2)))
    t3 = time.perf_counter()
    timings["pca"] = t3 - t2
    timings["total"] = t3 - t0
    prog.done()
    result = SsdfField(s, basis32, coeffs32, rms, occluded, rms_by_terms, timings)
    mesh.device_cache[key] = result
    if path:
        _write_disk(path, result)
    return result


def ssdf_eval(field_basis, coeffs_per_point, resolution: int, dirs) -> np.ndarray:
    """θd (rad, float64) of a PCA-compressed SSDF at directions `dirs` (P, 3) or (P, K, 3).

    field_basis (R+1, S²): row 0 the mean, rows 1.. eigenvectors; coeffs_per_point (P, R);
    θd = basis_0(ω) + Σ_r c_r·basis_r(ω), each basis image looked up bilinearly at texel
    coordinates x = u·S − ½, y = v·S − ½ (u, v = ssdf.octahedral_encode(ω)), clamped to
    [0, S − 1], texel (i, j) at flat index j·S + i. → (P,) or (P, K).
    """
    basis, c = _basis_and_coeffs(field_basis, coeffs_per_point, resolution, "coeffs_per_point")
    d = np.asarray(dirs, np.float64)
    single = d.ndim == 2
    if single:
        d = d[:, None, :]
    images = _basis_at(basis, int(resolution), d)  # (R + 1, P, K)
    theta = images[0] + np.einsum("pr,rpk->pk", c, images[1:])
    return theta[:, 0] if single else theta


def ssdf_at_axes(field_basis, coeffs, resolution: int, axes) -> np.ndarray:
    """θd (rad, float64) of every point of `coeffs` (V, R) at a few fixed directions `axes` (K, 3): (V, K),
    ssdf_eval's at each point and axis. θd is linear in the coefficients, so a barycentric blend of three
    vertices' rows is θd at the blend's point: the renderer's environment lobes take theirs that way."""
    basis, c = _basis_and_coeffs(field_basis, coeffs, resolution, "coeffs")
    images = _basis_at(basis, int(resolution), np.asarray(axes, np.float64).reshape(1, -1, 3))[:, 0]  # (R + 1, K)
    return images[0] + c @ images[1:]


def _basis_and_coeffs(field_basis, coeffs, resolution: int, name: str):
    """(R + 1, S²) basis and (P, R) coefficients as float64, their term counts checked against each other."""
    basis = np.asarray(field_basis, np.float64).reshape(-1, int(resolution) ** 2)
    c = np.atleast_2d(np.asarray(coeffs, np.float64))
    if c.shape[1] != basis.shape[0] - 1:
        raise ValueError(f"{name} has {c.shape[1]} terms for a basis of {basis.shape[0] - 1}")
    return basis, c


def _basis_at(basis, s: int, d) -> np.ndarray:
    """(R + 1, ...) every basis image (rows of `basis` (R + 1, s²)) looked up bilinearly at directions d (..., 3)."""
    uv = octahedral_encode(d)
    x = np.clip(uv[..., 0] * s - 0.5, 0.0, s - 1.0)
    y = np.clip(uv[..., 1] * s - 0.5, 0.0, s - 1.0)
    i0 = np.minimum(np.floor(x), s - 2).astype(np.int64)
    j0 = np.minimum(np.floor(y), s - 2).astype(np.int64)
    fx, fy = x - i0, y - j0
    return (basis[:, j0 * s + i0] * ((1 - fx) * (1 - fy)) + basis[:, j0 * s + i0 + 1] * (fx * (1 - fy))
            + basis[:, (j0 + 1) * s + i0] * ((1 - fx) * fy) + basis[:, (j0 + 1) * s + i0 + 1] * (fx * fy))
