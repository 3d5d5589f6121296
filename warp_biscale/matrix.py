"""The matrix method (Wu, Dorsey, Rushmeier 2011 §3.1–§3.7): f̄ = N·M with both matrices factored by
random-projection SVD. Host-side numpy, float64 where Wu computes in double precision.

Wu Eq. 8/12, in our layout (docs/design.md §4.4–§4.6):

    f̄(ωi_k, ωo_k) = (1/a_v(ωo_k)) Σ_l N[k, l] M[l, k]

- **N** (U × L): the BVNDF histogram of the bake (`bake(..., bvndf=True)`, `Bvndf.histogram`), rows over the
  U = K²(K²+1)/2 unordered direction pairs of the K×K grid, columns over the L non-empty cube-map normal bins,
  N[k, l] = Σ_{s in bin l} V_s(ωi)V_s(ωo)ΔA_s (times a colour channel; Wu Eq. 11).
- **M** (rows over normals × U): the pre-rotated, cosine-weighted small-scale BRDF,
  M[l, k] = f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺ (Wu Eq. 4, 9), evaluated exactly as the ground truth
  weighs a facet (`brdf.brdf_cosine_weighted`: the truth is this sum over facets instead of bins). Every BRDF
  here is reciprocal (M[l, (i, o)] = M[l, (o, i)]), so M needs the unordered pairs only (Wu §3.7), and the
  ordered table follows by dividing by a_v of each pair's ωo.

**Precompute once, edit forever** (Wu §3.5). M does not depend on the geometry if its rows are fixed normals:
the texel centres of an octahedral map of the whole sphere at an odd resolution R (`octahedral_normals`;
odd, so that the pole +z — every flat part of a tile — is a texel centre, where interpolation is exact). The
rows a bake needs, at its bins' mean normals, are interpolated bilinearly from the texels' rows (Wu §3.7:
"linear interpolation is applied to N and M"); since M ≈ L_M R_Mᵀ, interpolating M's rows is interpolating
the rows of L_M, so a bake touches only the factors. R is found by Wu's binary search (`sampling_rates`).

**Factors** (`randomized_svd`, `MatrixFactors`): Halko–Martinsson–Tropp's randomized range finder — the
modern form of Wu Table 2 — with oversampling, power iterations and re-orthonormalisation, in float64, over
row blocks generated on the fly (M need not fit in memory: Wu's 83 GB case). Before the SVD the matrix is
weighted (Wu §3.7: "scale N and M with proper weights ... and scale the results back"): M's rows by √Ω of
their texel's solid angle, N's columns by 1/√Ω of their bin's, so that the SVD minimises the L² error over the
sphere of M(n) and of the BVNDF density N/Ω rather than favouring where the maps sample densely; and the
mean row is subtracted (standard PCA, Wu §3.7). The rank kept holds a fraction of the power (the sum of
squared singular values of the centred, weighted matrix): 99.5 % for N, 98 % for M (Wu §6). The stored
factors are A ≈ diag(1/w_r)(1 μᵀ + U diag(S) Vᵀ)diag(1/w_c), i.e. A ≈ `left() @ right().T`.

**Eq. 12** (`pair_sums`, `effective_from_factors`): with N ≈ L_N R_Nᵀ and M ≈ L_M R_Mᵀ (M's rows at N's bins),
Σ_l N[k, l]M[l, k] = Σ_a L_N[k, a] (R_M (R_Nᵀ L_M)ᵀ)[k, a]: an (r_N+1)×(r_M+1) product and one dot of
length r_N + 1 per pair.

**Colour** (Wu §3.7): M is scalar. Each material's RGB BRDF is projected on its first principal direction
d (the top eigenvector of the 3×3 Gram matrix of its RGB tabulation over M's entries): M = d·M_rgb, and
f̄_rgb = d·f̄. Exact when the BRDF's colour is one direction (kd ∥ ks, or either zero); otherwise
`color_residual` is the fraction of the RGB power lost. The facets' colour weights are the N channels
(bake._channels): f̄_rgb = Σ_channels mult ⊙ d_m · f̄_channel.

**Cache** (`material_factors`): the factors of one material on one grid, as a versioned npz written
atomically, named by a SHA-256 of the BRDF's type and parameters, K, the normal resolution (or the search
settings that choose it), the SVD settings and FACTORS_KEY_VERSION.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import json
import os
import time
import warnings

import numpy as np

from . import directions as dirs
from .brdf import BLINN_PHONG, COOK_TORRANCE, LAMBERT, MEASURED, WARD, as_material_list, pack_materials
from .effective import HostOnlyBRDF, Provenance, check_amplitudes, materials_from_file, materials_to_file
from .io import cache_folder, check_output, read_npz, save_npz
from .model import Bvndf

__all__ = [
    "N_POWER", "M_POWER", "NORMAL_THRESHOLD", "DIRECTION_THRESHOLD", "MatrixFactors", "MaterialFactors",
    "SamplingRates", "brdf_matrix", "brdf_rows", "color_direction", "randomized_svd", "pair_sums",
    "direct_pair_sums", "effective_table", "effective_from_factors", "binary_search_rate", "normal_domain_error",
    "direction_domain_error", "sampling_rates", "material_factors", "factors_key", "factors_cache_dir",
    "bvndf_factors", "matrix_tables", "octahedral_encode", "octahedral_decode", "octahedral_normals",
    "octahedral_solid_angles", "octahedral_corners", "MatrixBRDF", "FACTOR_SETTINGS",
]

N_POWER = 0.995  # power of N kept (Wu §6: "at least 99.5 % of the power of N")
M_POWER = 0.98  # power of M kept (Wu §6: "at least 98 % of the power of M")
NORMAL_THRESHOLD = 0.01  # Wu §6: the sampling rate's error threshold, 1 % of the power for the normal domain
DIRECTION_THRESHOLD = 0.02  # ... and 2 % for the bidirectional one
NORMAL_RANGE = (3, 255)  # odd octahedral resolutions searched (9 to 65 025 rows)
DIRECTION_RANGE = (2, 32)  # K of the direction grid searched (the bake's range)
FACTORS_VERSION = 1  # the cache file's format
FACTORS_KEY_VERSION = 1  # part of every cache key: bump when the factors' numbers change
MEMORY_BUDGET = 1 << 29  # M is built in memory up to this many bytes (float64), else streamed in row blocks
BLOCK_ENTRIES = 1 << 20  # entries of M per generated block (each temporary is 8 MiB)
# Entries per block made by the kernels (64 MiB float32 on the device, 128 MiB as float64 on the host): a
# GPU wants large launches, and each block is one upload of normals and one read-back.
KERNEL_BLOCK_ENTRIES = 1 << 24
_MEMORY = collections.OrderedDict()  # cache key → MaterialFactors, most recent last
_MEMORY_ENTRIES = 8


# ---------------------------------------------------------------------------------------------------
# The normal domain of M: an octahedral map of the whole sphere
# ---------------------------------------------------------------------------------------------------


def octahedral_encode(n) -> np.ndarray:
    """(N, 3) unit vectors → (N, 2) points p of [−1, 1]² (the octahedral map; the upper hemisphere inside
    |p_x| + |p_y| ≤ 1, the lower one folded outside it)."""
    n = np.asarray(n, np.float64)
    p = n[:, :2] / np.maximum(np.abs(n).sum(axis=1), 1e-300)[:, None]
    low = n[:, 2] < 0
    sx = np.where(p[:, 0] >= 0, 1.0, -1.0)
    sy = np.where(p[:, 1] >= 0, 1.0, -1.0)
    folded = np.stack([(1 - np.abs(p[:, 1])) * sx, (1 - np.abs(p[:, 0])) * sy], axis=1)
    return np.where(low[:, None], folded, p)


def octahedral_decode(p, normalize: bool = True) -> np.ndarray:
    """(N, 2) points of [−1, 1]² → (N, 3) unit vectors (or, `normalize` False, the octahedron's point
    q, |q_x| + |q_y| + |q_z| = 1)."""
    p = np.asarray(p, np.float64)
    u, v = p[:, 0], p[:, 1]
    z = 1 - np.abs(u) - np.abs(v)
    low = z < 0
    x = np.where(low, (1 - np.abs(v)) * np.where(u >= 0, 1.0, -1.0), u)
    y = np.where(low, (1 - np.abs(u)) * np.where(v >= 0, 1.0, -1.0), v)
    q = np.stack([x, y, z], axis=1)
    return q / np.linalg.norm(q, axis=1)[:, None] if normalize else q


def _check_res(resolution) -> int:
    r = int(resolution)
    if r != resolution or r < 1:
        raise ValueError(f"normal_res must be an integer >= 1, got {resolution!r}")
    return r


def octahedral_normals(resolution: int) -> np.ndarray:
    """(R², 3) the texel centres of the R×R octahedral map, index row·R + col, p = ((col + ½)/R·2 − 1,
    (row + ½)/R·2 − 1). With R odd the centre texel is the pole +z."""
    r = _check_res(resolution)
    c = (np.arange(r) + 0.5) / r * 2 - 1
    u, v = np.meshgrid(c, c)
    return octahedral_decode(np.stack([u.ravel(), v.ravel()], axis=1))


def octahedral_solid_angles(resolution: int, sub: int = 8) -> np.ndarray:
    """(R²,) the solid angle of each texel (they sum to 4π). The octahedral map has dω = du dv/|q|³ with q the
    octahedron's point (a central projection of the octahedron's faces; the lower half's fold is
    area-preserving in xy), integrated by a sub×sub midpoint rule per texel and scaled to 4π."""
    r = _check_res(resolution)
    t = (np.arange(r * sub) + 0.5) / (r * sub) * 2 - 1
    u, v = np.meshgrid(t, t)
    q = octahedral_decode(np.stack([u.ravel(), v.ravel()], axis=1), normalize=False)
    dens = np.linalg.norm(q, axis=1) ** -3.0
    per = dens.reshape(r, sub, r, sub).sum(axis=(1, 3)).ravel()
    return per * (4 * np.pi / per.sum())


def octahedral_corners(n, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation on the R×R octahedral map: (N, 4) texel indices and (N, 4) weights for unit
    vectors n (N, 3). A corner beyond the square's edge is folded back as the map is: the edge is mirrored
    onto itself (texel −1 of row j is texel 0 of row R − 1 − j; likewise on every side)."""
    r = _check_res(resolution)
    p = octahedral_encode(n)
    x = (p + 1) * 0.5 * r - 0.5
    x0 = np.floor(x).astype(np.int64)
    t = x - x0
    idx, wts = [], []
    for dy in (0, 1):
        for dx in (0, 1):
            col, row = x0[:, 0] + dx, x0[:, 1] + dy
            out = col < 0
            col, row = np.where(out, -1 - col, col), np.where(out, r - 1 - row, row)
            out = col >= r
            col, row = np.where(out, 2 * r - 1 - col, col), np.where(out, r - 1 - row, row)
            out = row < 0
            row, col = np.where(out, -1 - row, row), np.where(out, r - 1 - col, col)
            out = row >= r
            row, col = np.where(out, 2 * r - 1 - row, row), np.where(out, r - 1 - col, col)
            idx.append(row * r + col)
            wts.append((t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1]))
    return np.stack(idx, 1), np.stack(wts, 1)


# ---------------------------------------------------------------------------------------------------
# M: the pre-rotated, cosine-weighted BRDF (Wu §3.5)
# ---------------------------------------------------------------------------------------------------


def _analytic(brdf):
    """(kind, kd (3,), ks (3,), p1, p2) of a BRDF the kernels know (its packed row), else None (a measured
    BRDF: evaluated through its own `eval`)."""
    kind = getattr(brdf, "kind", None)
    if kind not in (LAMBERT, BLINN_PHONG, COOK_TORRANCE, WARD):
        return None
    p = np.asarray(brdf.packed(), np.float64)
    return int(kind), p[0:3], p[3:6], float(p[6]), float(p[7])


def _kernel_measured(brdf, backend):
    """(kinds (1,), params (1, 8), [brdf]): the packed row and table list of a measured BRDF whose M the
    backend's kernels tabulate (their lookup is MeasuredBRDF.eval's in float32), else None (no backend, or
    not a measured BRDF)."""
    if backend is None or getattr(brdf, "kind", None) != MEASURED:
        return None
    kinds, params = pack_materials([brdf], measured=True)
    return kinds, params, [brdf]


def _parts(kind, p1, p2, normals, wi, wo):
    """(D, S), each (L, P): M's diffuse part for kd = 1 and its specular part for ks = 1 at normals (L, 3)
    and direction pairs wi, wo (P, 3), so that M_rgb = kd ⊗ D + ks ⊗ S. Formula for formula
    `brdf.brdf_cosine_weighted` (the ground truth's), with the cosines as matrix products."""
    ci = normals @ wi.T
    co = normals @ wo.T
    ok = (ci > 0) & (co > 0)
    ci, co = np.maximum(ci, 0.0), np.maximum(co, 0.0)
    d = ci * co / np.pi
    spec = None
    if kind != LAMBERT:
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=1), 1e-300)[:, None]
        nh = np.clip(normals @ h.T, -1.0, 1.0)
        nh_pos = np.maximum(nh, 0.0)
        hi = np.clip(np.einsum("ij,ij->i", h, wi), 0.0, 1.0)[None, :]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
            if kind == BLINN_PHONG:
                spec = (p1 + 2) / (2 * np.pi) * nh_pos**p1 * ci * co
            elif kind == COOK_TORRANCE:
                dd = np.exp(-((np.arccos(nh) / p1) ** 2))
                f = p2 + (1 - p2) * (1 - hi) ** 5
                ho = np.maximum(hi, 1e-300)
                g = np.minimum(1.0, np.minimum(2 * nh_pos * co / ho, 2 * nh_pos * ci / ho))
                spec = f * g * dd / np.pi
            else:  # Ward
                cos2 = np.maximum(nh**2, 1e-300)
                a2 = p1 * p1
                spec = np.where(nh > 0, np.exp(-((1 - cos2) / cos2) / a2), 0.0) / (4 * np.pi * a2) * np.sqrt(ci * co)
        spec = np.where(ok, spec, 0.0)
    return np.where(ok, d, 0.0), spec


def _generic_rgb(brdf, normals, wi, wo):
    """(L, P, 3) f_r(n, ωi, ωo)(n·ωi)⁺(n·ωo)⁺ through the BRDF's own `eval` (any `Brdf`, e.g. measured)."""
    nl, np_ = len(normals), len(wi)
    n = np.repeat(normals, np_, axis=0)
    a, b = np.tile(wi, (nl, 1)), np.tile(wo, (nl, 1))
    ci = np.maximum(np.einsum("ij,ij->i", n, a), 0.0)
    co = np.maximum(np.einsum("ij,ij->i", n, b), 0.0)
    return (np.asarray(brdf.eval(n, a, b), np.float64) * (ci * co)[:, None]).reshape(nl, np_, 3)


def _pair_dirs(directions, pairs):
    g = np.asarray(directions, np.float64)
    if pairs is None:
        pairs = dirs.unordered_pairs(len(g))
    pi, po = (np.asarray(x, np.int64) for x in pairs)
    return g[pi], g[po]


def brdf_matrix(brdf, bin_normals, directions, pairs=None, color=None) -> np.ndarray:
    """M of one small-scale BRDF: M[l, k] = f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺, float64.

    bin_normals (L, 3) unit normals (rows); directions (D, 3) and pairs = (pair_i, pair_o) indices into them
    (default `directions.unordered_pairs(D)`: the reciprocal BRDF needs no more). color None → (L, P, 3) RGB;
    a 3-vector d (Wu §3.7, `color_direction`) → (L, P) the projection d·M_rgb. For a large M use `brdf_rows`.
    """
    normals = np.asarray(bin_normals, np.float64).reshape(-1, 3)
    wi, wo = _pair_dirs(directions, pairs)
    an = _analytic(brdf)
    if an is None:
        rgb = _generic_rgb(brdf, normals, wi, wo)
        return rgb if color is None else rgb @ np.asarray(color, np.float64)
    kind, kd, ks, p1, p2 = an
    d, s = _parts(kind, p1, p2, normals, wi, wo)
    if color is None:
        out = d[..., None] * kd
        return out if s is None else out + s[..., None] * ks
    c = np.asarray(color, np.float64)
    out = float(c @ kd) * d
    return out if s is None else out + float(c @ ks) * s


def color_direction(brdf, normals, directions, pairs=None, rows_per_block=None,
                    backend=None) -> tuple[np.ndarray, float]:
    """Wu §3.7's colour direction: (d (3,), residual). d is the first principal direction of the BRDF's RGB
    tabulated over M's entries (the top eigenvector of Σ f fᵀ over every (normal, pair)), made ≥ 0; residual
    = 1 − λ1/trace, the fraction of the RGB power the projection loses (0 when the colour is one direction:
    kd ∥ ks, or either zero — then d is found without tabulating). backend: a Backend whose `brdf_matrix`
    kernels tabulate an analytic BRDF's diffuse and specular parts, or a measured BRDF's three channels
    (`_check_backend`), else None (numpy)."""
    an = _analytic(brdf)
    if an is not None:
        _, kd, ks, _, _ = an
        nk, ns = np.linalg.norm(kd), np.linalg.norm(ks)
        if an[0] == LAMBERT or ns == 0 or nk == 0 or np.linalg.norm(np.cross(kd, ks)) <= 1e-12 * nk * ns:
            c = kd if nk >= ns else ks
            nc = np.linalg.norm(c)
            return (c / nc if nc > 0 else np.full(3, 1 / np.sqrt(3))), 0.0
    gram = np.zeros((3, 3))
    sums = np.zeros(3)  # ΣD², ΣDS, ΣS² for an analytic BRDF
    normals = np.asarray(normals, np.float64)
    wi, wo = _pair_dirs(directions, pairs)
    backend = _check_backend(backend)
    kernels = backend is not None and an is not None  # D and S by the kernels: M's own rows, two passes
    measured = _kernel_measured(brdf, backend)  # a measured BRDF's R, G, B by the kernels: three passes
    step = rows_per_block or max(1, (KERNEL_BLOCK_ENTRIES if kernels or measured else BLOCK_ENTRIES)
                                 // max(len(wi), 1))
    for a in range(0, len(normals), step):
        nb = normals[a:a + step]
        if measured is not None:
            kinds, params, tables = measured
            f = np.stack([np.asarray(backend.brdf_matrix(kinds, params, 0, nb, wi, wo, e, measured=tables),
                                     np.float64).reshape(-1) for e in np.eye(3)], axis=1)
            gram += f.T @ f
        elif kernels:
            d, s = (np.asarray(backend.brdf_matrix(*row, 0, nb, wi, wo, (1.0, 0.0, 0.0)), np.float64)
                    for row in _kernel_parts(an))
            sums += [np.vdot(d, d), np.vdot(d, s), np.vdot(s, s)]
        elif an is None:
            f = _generic_rgb(brdf, nb, wi, wo).reshape(-1, 3)
            gram += f.T @ f
        else:
            d, s = _parts(an[0], an[3], an[4], nb, wi, wo)
            sums += [np.vdot(d, d), np.vdot(d, s), np.vdot(s, s)]
    if an is not None:
        kd, ks = an[1], an[2]
        gram = np.outer(kd, kd) * sums[0] + (np.outer(kd, ks) + np.outer(ks, kd)) * sums[1] + np.outer(ks, ks) * sums[2]
    lam, vec = np.linalg.eigh(gram)
    d = vec[:, -1] * (1.0 if vec[:, -1].sum() >= 0 else -1.0)
    trace = float(np.trace(gram))
    return d, (float(1 - lam[-1] / trace) if trace > 0 else 0.0)


class _Rows:
    """A matrix given by row blocks made on demand: `shape`, `blocks()` → (start, (b, n) float64) in order."""

    def __init__(self, shape, make, rows_per_block):
        self.shape = (int(shape[0]), int(shape[1]))
        self._make = make
        self.rows_per_block = max(1, int(rows_per_block))

    def blocks(self):
        for a in range(0, self.shape[0], self.rows_per_block):
            b = min(self.shape[0], a + self.rows_per_block)
            yield a, self._make(a, b)

    def dense(self) -> np.ndarray:
        out = np.empty(self.shape)
        for a, blk in self.blocks():
            out[a:a + len(blk)] = blk
        return out


def brdf_rows(brdf, normals, directions, pairs=None, color=None, rows_per_block=None, backend=None) -> _Rows:
    """`brdf_matrix(brdf, normals, directions, pairs, color)` (scalar: `color` is required, default Wu's
    `color_direction`) as row blocks generated on demand, for `randomized_svd` of an M too large to hold.
    backend: a Backend (`_check_backend`) whose `brdf_matrix` kernels (kernels/matrix.py, cl/matrix.cl) make
    the blocks of an analytic or a measured BRDF in float32 (then widened to float64 for the SVD); None, or a
    BRDF the kernels do not know, → numpy in float64."""
    normals = np.asarray(normals, np.float64)
    backend = _check_backend(backend)
    if color is None:
        color = color_direction(brdf, normals, directions, pairs, backend=backend)[0]
    wi, wo = _pair_dirs(directions, pairs)
    an = _analytic(brdf)
    measured = _kernel_measured(brdf, backend)
    if backend is None or (an is None and measured is None):
        step = rows_per_block or max(1, BLOCK_ENTRIES // max(len(wi), 1))
        return _Rows((len(normals), len(wi)),
                     lambda a, b: brdf_matrix(brdf, normals[a:b], directions, pairs, color), step)
    color = np.asarray(color, np.float64)
    step = rows_per_block or max(1, KERNEL_BLOCK_ENTRIES // max(len(wi), 1))
    if measured is not None:
        kinds, params, tables = measured
        return _Rows((len(normals), len(wi)),
                     lambda a, b: np.asarray(backend.brdf_matrix(kinds, params, 0, normals[a:b], wi, wo, color,
                                                                 measured=tables), np.float64), step)
    kinds, params = _packed_row(an)
    return _Rows((len(normals), len(wi)),
                 lambda a, b: np.asarray(backend.brdf_matrix(kinds, params, 0, normals[a:b], wi, wo, color),
                                         np.float64), step)


def _check_backend(backend):
    """A Backend object with the `brdf_matrix` stage, or None (numpy). The mathematics layer takes the
    object, not a name: resolving a name is the stages layer's (`wb.get_backend`; `bake` does it)."""
    if backend is None:
        return None
    if isinstance(backend, str) or not callable(getattr(backend, "brdf_matrix", None)):
        raise ValueError(f"backend must be a Backend object (wb.get_backend({backend!r})) or None for numpy, "
                         f"got {backend!r}")
    return backend


def _packed_row(an):
    """(kinds (1,), params (1, 8)) of `_analytic`'s (kind, kd, ks, p1, p2): the kernels' packed layout."""
    kind, kd, ks, p1, p2 = an
    return np.array([kind], np.int32), np.concatenate([kd, ks, [p1, p2]])[None, :]


def _kernel_parts(an):
    """The packed rows of an analytic BRDF's diffuse part (kd = 1, ks = 0) and specular part (kd = 0, ks = 1),
    whose kernel tabulations (colour (1, 0, 0)) are `_parts`' D and S."""
    kind, _, _, p1, p2 = an
    one, zero = np.ones(3), np.zeros(3)
    return [_packed_row((kind, one, zero, p1, p2)), _packed_row((kind, zero, one, p1, p2))]


# ---------------------------------------------------------------------------------------------------
# Random-projection SVD (Wu Table 2; Halko, Martinsson, Tropp 2011)
# ---------------------------------------------------------------------------------------------------


@dataclasses.dataclass(eq=False)
class MatrixFactors:
    """A ≈ diag(1/row_scale)·(1 meanᵀ + U diag(S) Vᵀ)·diag(1/col_scale) for an m×n matrix A.

    U (m, r), S (r,), V (n, r), mean (n,) the mean row that was subtracted (zeros if none), row_scale (m,)
    and col_scale (n,) the weights applied before the SVD; total_power the sum of squared singular values of
    the centred, weighted matrix (all of them), power_kept the fraction the r kept hold. `left() @
    right().T` is A's approximation."""

    U: np.ndarray
    S: np.ndarray
    V: np.ndarray
    mean: np.ndarray
    row_scale: np.ndarray
    col_scale: np.ndarray
    total_power: float = 0.0
    power_kept: float = 1.0
    centered: bool = True

    @property
    def rank(self) -> int:
        return int(len(self.S))

    @property
    def shape(self) -> tuple:
        return (len(self.U), len(self.V))

    @property
    def nbytes(self) -> int:
        """Bytes of the stored arrays (what a renderer or an edit holds for this matrix)."""
        return int(sum(a.nbytes for a in (self.U, self.S, self.V, self.mean, self.row_scale, self.col_scale)))

    def left(self) -> np.ndarray:
        """(m, r [+ 1]) float64: diag(1/row_scale)[1 | U S] (the column of ones only when centred)."""
        us = self.U.astype(np.float64) * self.S.astype(np.float64)
        if self.centered:
            us = np.concatenate([np.ones((len(us), 1)), us], axis=1)
        return us / self.row_scale.astype(np.float64)[:, None]

    def right(self) -> np.ndarray:
        """(n, r [+ 1]) float64: diag(1/col_scale)[mean | V]."""
        v = self.V.astype(np.float64)
        if self.centered:
            v = np.concatenate([self.mean.astype(np.float64)[:, None], v], axis=1)
        return v / self.col_scale.astype(np.float64)[:, None]

    def reconstruct(self) -> np.ndarray:
        return self.left() @ self.right().T

    def truncated(self, rank: int) -> MatrixFactors:
        """The same factors keeping the first `rank` singular triplets."""
        r = max(0, min(int(rank), self.rank))
        s2 = self.S.astype(np.float64) ** 2
        kept = float(s2[:r].sum() / self.total_power) if self.total_power > 0 else 1.0
        return dataclasses.replace(self, U=self.U[:, :r], S=self.S[:r], V=self.V[:, :r], power_kept=kept)

    def astype(self, dtype) -> MatrixFactors:
        return dataclasses.replace(self, **{f: getattr(self, f).astype(dtype)
                                            for f in ("U", "S", "V", "mean", "row_scale", "col_scale")})

    def arrays(self, prefix: str = "") -> dict:
        return {prefix + f: getattr(self, f) for f in ("U", "S", "V", "mean", "row_scale", "col_scale")}

    @classmethod
    def from_arrays(cls, arrays: dict, header: dict, prefix: str = "") -> MatrixFactors:
        return cls(*(arrays[prefix + f] for f in ("U", "S", "V", "mean", "row_scale", "col_scale")),
                   total_power=float(header["total_power"]), power_kept=float(header["power_kept"]),
                   centered=bool(header["centered"]))

    def header(self) -> dict:
        return {"total_power": self.total_power, "power_kept": self.power_kept, "centered": self.centered,
                "rank": self.rank}


class _Weighted:
    """diag(rw)·A·diag(cw) by row blocks, over a dense array or a `_Rows` generator."""

    def __init__(self, a, rw, cw):
        self.a, self.rw, self.cw = a, rw, cw
        self.shape = a.shape

    def blocks(self):
        if isinstance(self.a, np.ndarray):
            step = max(1, (BLOCK_ENTRIES * 8) // max(self.shape[1], 1))
            src = ((s, self.a[s:s + step]) for s in range(0, self.shape[0], step))
        else:
            src = self.a.blocks()
        for s, blk in src:
            blk = np.asarray(blk, np.float64)
            if self.rw is not None:
                blk = blk * self.rw[s:s + len(blk), None]
            if self.cw is not None:
                blk = blk * self.cw[None, :]
            yield s, blk


def _orth(y):
    return np.linalg.qr(y)[0]


def _sketch_svd(op, m, n, l, q, seed, center):
    """One randomized SVD with l columns in the sketch and q power iterations: → (U (m, l), S (l,), V (n, l),
    mean (n,), total power). Passes over the rows: 2 + 2q (the first also sums the mean and the power)."""
    rng = np.random.default_rng(seed)
    omega = rng.standard_normal((n, l))
    y = np.empty((m, l))
    col_sum = np.zeros(n)
    sq = 0.0
    for s, blk in op.blocks():
        y[s:s + len(blk)] = blk @ omega
        col_sum += blk.sum(axis=0)
        sq += float(np.vdot(blk, blk))
    mean = col_sum / m if center else np.zeros(n)
    if center:
        y -= (mean @ omega)[None, :]
    total = max(sq - m * float(mean @ mean), 0.0)
    q_mat = _orth(y)
    for _ in range(q):
        z = np.zeros((n, l))
        for s, blk in op.blocks():
            z += blk.T @ q_mat[s:s + len(blk)]
        if center:
            z -= np.outer(mean, q_mat.sum(axis=0))
        z = _orth(z)
        for s, blk in op.blocks():
            y[s:s + len(blk)] = blk @ z
        if center:
            y -= (mean @ z)[None, :]
        q_mat = _orth(y)
    b = np.zeros((q_mat.shape[1], n))
    for s, blk in op.blocks():
        b += q_mat[s:s + len(blk)].T @ blk
    if center:
        b -= np.outer(q_mat.sum(axis=0), mean)
    ub, sv, vt = np.linalg.svd(b, full_matrices=False)
    return q_mat @ ub, sv, vt.T, mean, total


def _exact_svd(op, m, n, center):
    """The plain SVD (LAPACK, float64) of the whole centred, weighted matrix: where a sketch would need
    min(m, n) columns, randomisation saves nothing."""
    a = np.empty((m, n))
    for s, blk in op.blocks():
        a[s:s + len(blk)] = blk
    mean = a.mean(axis=0) if center else np.zeros(n)
    a -= mean[None, :]
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    return u, sv, vt.T, mean, float(np.vdot(a, a))


def _rank_for(s, total, power):
    """The fewest leading singular values whose squares hold `power` of `total`, or None if all of s do not."""
    if total <= 0:
        return 0
    c = np.cumsum(s.astype(np.float64) ** 2)
    hit = np.flatnonzero(c >= power * total * (1 - 1e-12))
    return int(hit[0]) + 1 if len(hit) else None


def randomized_svd(a, rank=None, power=None, oversample: int = 10, power_iterations: int = 2, seed: int = 0,
                   center: bool = False, row_weights=None, col_weights=None, dtype=np.float64,
                   initial_rank: int = 16, exact_when_full: bool = True) -> MatrixFactors:
    """Random-projection SVD of an m×n matrix `a` (a numpy array, or `brdf_rows`' block generator for a
    matrix too large to hold), in float64 (Wu Table 2 in Halko–Martinsson–Tropp's form: a Gaussian sketch of
    rank + `oversample` columns, `power_iterations` steps of (AAᵀ) with re-orthonormalisation, seeded: the
    same seed gives the same R every time, Wu §3.7).

    rank: keep exactly this many; power: keep the fewest whose squared singular values hold this fraction of
    the (centred, weighted) matrix's total power (computed exactly in the first pass); power ≥ 1 or rank
    "full" keeps min(m, n). With `power` the sketch starts at `initial_rank` + oversample and doubles until
    the kept rank fits below its top `oversample` columns (or covers min(m, n), where the sketch is exact).
    center: subtract the mean row first (PCA, Wu §3.7). row_weights (m,), col_weights (n,): positive weights
    applied before the SVD and divided out of the factors (`MatrixFactors`). dtype: of the stored factors.
    exact_when_full: where the sketch would need min(m, n) columns and `a` is an array, take LAPACK's SVD
    instead (exact, and faster than a full-width sketch with its QRs); False keeps the sketch (for testing it).
    """
    m, n = (int(x) for x in a.shape)
    full = min(m, n)
    rw = None if row_weights is None else np.asarray(row_weights, np.float64)
    cw = None if col_weights is None else np.asarray(col_weights, np.float64)
    for name, w, size in (("row_weights", rw, m), ("col_weights", cw, n)):
        if w is not None and (w.shape != (size,) or not np.all(np.isfinite(w)) or (w <= 0).any()):
            raise ValueError(f"{name} must be {size} finite numbers > 0")
    if (rank is None) == (power is None):
        raise ValueError("give exactly one of rank (an integer or 'full') and power (a fraction in (0, 1])")
    op = _Weighted(a, rw, cw)
    q = int(power_iterations)
    p = int(oversample)
    dense = isinstance(a, np.ndarray)

    def svd(l):
        if l >= full and dense and exact_when_full:
            return _exact_svd(op, m, n, center)
        return _sketch_svd(op, m, n, max(l, 1), q, seed, center)

    if rank is not None:
        r = full if rank == "full" else int(rank)
        if r < 0:
            raise ValueError(f"rank must be >= 0, got {rank!r}")
        r = min(r, full)
        u, s, v, mean, total = svd(min(full, r + p))
    else:
        power = float(power)
        if not (0 < power):
            raise ValueError(f"power must be a fraction in (0, 1], got {power!r}")
        l = full if power >= 1 else min(full, int(initial_rank) + p)
        while True:
            u, s, v, mean, total = svd(l)
            r = full if power >= 1 else _rank_for(s, total, power)
            if l >= full:
                r = min(full, len(s)) if r is None else r
                break
            if r is not None and r <= l - p:
                break
            l = min(full, 2 * l)
    r = min(r, len(s))
    s2 = s.astype(np.float64) ** 2
    kept = float(s2[:r].sum() / total) if total > 0 else 1.0
    one = np.ones
    return MatrixFactors(u[:, :r].astype(dtype), s[:r].astype(dtype), v[:, :r].astype(dtype), mean.astype(dtype),
                         (one(m) if rw is None else rw).astype(dtype), (one(n) if cw is None else cw).astype(dtype),
                         total_power=float(total), power_kept=min(kept, 1.0), centered=bool(center))


# ---------------------------------------------------------------------------------------------------
# Wu Eq. 8 / Eq. 12
# ---------------------------------------------------------------------------------------------------


def _low_rank(f):
    if isinstance(f, MatrixFactors):
        return f.left(), f.right()
    left, right = f
    return np.asarray(left, np.float64), np.asarray(right, np.float64)


def direct_pair_sums(n_matrix, m_matrix) -> np.ndarray:
    """(U,) Σ_l N[k, l] M[l, k] from the full matrices (Wu Eq. 8 before the 1/a_v): N (U, L), M (L, U)."""
    return np.einsum("kl,lk->k", np.asarray(n_matrix, np.float64), np.asarray(m_matrix, np.float64))


def pair_sums(n_factors, m_factors) -> np.ndarray:
    """(U,) Σ_l N[k, l] M[l, k] from the factors (Wu Eq. 12): N ≈ L_N R_Nᵀ (U × L) and M ≈ L_M R_Mᵀ (L × U),
    each a `MatrixFactors` or a (left, right) pair (M's rows already at N's columns: `MaterialFactors.rows_at`).
    Σ_a L_N[k, a]·(R_M (R_Nᵀ L_M)ᵀ)[k, a]: the cost is U·(r_N + 1)·(r_M + 1), independent of L."""
    ln, rn = _low_rank(n_factors)
    lm, rm = _low_rank(m_factors)
    if rn.shape[0] != lm.shape[0] or ln.shape[0] != rm.shape[0]:
        raise ValueError(f"N is {ln.shape[0]}×{rn.shape[0]} but M is {lm.shape[0]}×{rm.shape[0]}: M must be "
                         "(N's columns) × (N's rows)")
    w = rm @ (rn.T @ lm).T  # (U, r_N + 1)
    return np.einsum("ka,ka->k", ln, w)


def effective_table(sums, a_v) -> np.ndarray:
    """(K², K²) f̄[i, o] = sums[pair (i, o)] / a_v[o] from per-unordered-pair sums (U,) and a_v (K²,); 0 where
    a_v(ωo) = 0 (nothing of the tile is seen from ωo) and clamped at 0 (a truncated factorisation may dip
    below)."""
    a_v = np.asarray(a_v, np.float64)
    nd = len(a_v)
    sums = np.asarray(sums, np.float64)
    if sums.shape != (nd * (nd + 1) // 2,):
        raise ValueError(f"sums must have one value per unordered pair of {nd} directions, got {sums.shape}")
    pi, po = dirs.all_pairs(nd)
    u = dirs.unordered_index(pi.astype(np.int64), po.astype(np.int64), nd)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(a_v[po] > 0, sums[u] / a_v[po], 0.0)
    return np.maximum(f, 0.0).reshape(nd, nd)


def effective_from_factors(n_factors, m_factors, a_v) -> np.ndarray:
    """(K², K²) scalar f̄ by Wu Eq. 12: `effective_table(pair_sums(n_factors, m_factors), a_v)`. With every
    singular value kept (rank "full") it equals `effective_table(direct_pair_sums(N, M), a_v)` to rounding."""
    return effective_table(pair_sums(n_factors, m_factors), a_v)


# ---------------------------------------------------------------------------------------------------
# Wu §3.7: the sampling rates of M, by binary search
# ---------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class SamplingRates:
    """What `sampling_rates` found: normal_res (odd R of the octahedral map of M's rows) and directions (K of
    the direction grid of its columns), each the smallest rate in its range whose relative error power
    (`normal_domain_error`, `direction_domain_error`) is within its threshold (met False: not even the
    largest rate was, which is then returned); the errors at them; trials [(rate, error)] in the order tried."""

    normal_res: int
    directions: int
    normal_error: float
    direction_error: float
    normal_met: bool
    direction_met: bool
    normal_trials: list
    direction_trials: list
    normal_threshold: float = NORMAL_THRESHOLD
    direction_threshold: float = DIRECTION_THRESHOLD

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def binary_search_rate(error, lo: int, hi: int, threshold: float):
    """Wu §3.7's search: start with [lo, hi]; halve it by whether the midpoint's `error(rate)` is ≤
    `threshold`; stop at one number. → (rate, its error, met, trials [(rate, error)]). Assumes the error falls
    with the rate; if even `hi` misses the threshold, returns hi with met False."""
    lo, hi = int(lo), int(hi)
    if lo > hi:
        raise ValueError(f"empty search range [{lo}, {hi}]")
    trials = {}

    def err(r):
        if r not in trials:
            trials[r] = float(error(r))
        return trials[r]

    a, b = lo, hi
    while a < b:
        mid = (a + b) // 2
        if err(mid) <= threshold:
            b = mid
        else:
            a = mid + 1
    e = err(a)
    return a, e, e <= threshold, list(trials.items())


def _probe_pairs(count, rng):
    """(count, 3) ωi and ωo uniform over the hemisphere (uniform in the square of the equal-area map)."""
    return (dirs.square_to_hemisphere(rng.random((count, 2))), dirs.square_to_hemisphere(rng.random((count, 2))))


def _sphere(count, rng):
    v = rng.standard_normal((count, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def _scalar_values(brdf, color, normals, wi, wo):
    """(L, P) d·M_rgb at normals × pairs (wi[k], wo[k])."""
    g = np.concatenate([wi, wo])
    p = np.arange(len(wi))
    return brdf_matrix(brdf, normals, g, (p, p + len(wi)), color)


def normal_domain_error(brdf, resolution: int, normals=None, wi=None, wo=None, color=None, seed: int = 0,
                        n_normals: int = 2048, n_pairs: int = 512) -> float:
    """Relative error power of M's rows interpolated from an R×R octahedral map (`octahedral_corners`) against
    M evaluated exactly, over probe normals (default `n_normals` uniform on the sphere) × probe pairs (default
    `n_pairs` uniform on the hemisphere): Σ(M̂ − M)²/ΣM²."""
    rng = np.random.default_rng(seed)
    if normals is None:
        normals = _sphere(n_normals, rng)
    if wi is None:
        wi, wo = _probe_pairs(n_pairs, rng)
    if color is None:
        color = color_direction(brdf, normals, np.concatenate([wi, wo]),
                                (np.arange(len(wi)), np.arange(len(wi)) + len(wi)))[0]
    exact = _scalar_values(brdf, color, normals, wi, wo)
    idx, w = octahedral_corners(normals, resolution)
    used, inv = np.unique(idx, return_inverse=True)
    texel = _scalar_values(brdf, color, octahedral_normals(resolution)[used], wi, wo)
    approx = np.einsum("nc,ncp->np", w, texel[inv.reshape(idx.shape)])
    power = float(np.vdot(exact, exact))
    return float(np.vdot(approx - exact, approx - exact) / power) if power > 0 else 0.0


def direction_domain_error(brdf, k: int, normals=None, wi=None, wo=None, color=None, seed: int = 1,
                           n_normals: int = 256, n_pairs: int = 1024) -> float:
    """Relative error power of M's columns interpolated bilinearly from the K×K direction grid (in the square
    domain of ωi and of ωo: 16 grid pairs, `directions.bilinear_corners`, as `EffectiveBRDF.eval`
    interpolates) against M evaluated exactly, over probe normals × probe pairs: Σ(M̂ − M)²/ΣM²."""
    rng = np.random.default_rng(seed)
    if normals is None:
        normals = _sphere(n_normals, rng)
    if wi is None:
        wi, wo = _probe_pairs(n_pairs, rng)
    if color is None:
        color = color_direction(brdf, normals, np.concatenate([wi, wo]),
                                (np.arange(len(wi)), np.arange(len(wi)) + len(wi)))[0]
    exact = _scalar_values(brdf, color, normals, wi, wo)
    nd = k * k
    ci, wci = dirs.bilinear_corners(wi, k)
    co, wco = dirs.bilinear_corners(wo, k)
    pair = (ci[:, :, None] * nd + co[:, None, :]).reshape(len(wi), 16)
    weight = (wci[:, :, None] * wco[:, None, :]).reshape(len(wi), 16)
    used, inv = np.unique(pair, return_inverse=True)
    g = dirs.grid(k)
    vals = brdf_matrix(brdf, normals, g, (used // nd, used % nd), color)  # (L, distinct pairs)
    approx = np.einsum("pc,lpc->lp", weight, vals[:, inv.reshape(pair.shape)])
    power = float(np.vdot(exact, exact))
    return float(np.vdot(approx - exact, approx - exact) / power) if power > 0 else 0.0


def sampling_rates(brdf, normal_threshold: float = NORMAL_THRESHOLD, direction_threshold: float = DIRECTION_THRESHOLD,
                   normal_range=NORMAL_RANGE, direction_range=DIRECTION_RANGE, seed: int = 0,
                   n_normals: int = 2048, n_pairs: int = 512, n_direction_normals: int = 256,
                   n_direction_pairs: int = 1024) -> SamplingRates:
    """Wu §3.7: the sampling rates of M for one BRDF by binary search, each domain on its own —
    the normal domain (R, odd, of the octahedral map of M's rows: the error of its interpolated rows at
    `n_normals` probe normals × `n_pairs` probe pairs within `normal_threshold` of the power, Wu's 1 %) and
    the bidirectional domain (K of the direction grid of M's columns: the error of bilinear interpolation
    over the grid at `n_direction_normals` × `n_direction_pairs` probes within `direction_threshold`, Wu's
    2 %). The probes are fixed by `seed`, so the search is deterministic. → `SamplingRates`."""
    for name, rng_ in (("normal_range", normal_range), ("direction_range", direction_range)):
        if len(rng_) != 2 or int(rng_[0]) < 1 or int(rng_[1]) < int(rng_[0]):
            raise ValueError(f"{name} must be (lo, hi) with 1 <= lo <= hi, got {rng_!r}")
    rng = np.random.default_rng(seed)
    nn = _sphere(n_normals, rng)
    wi, wo = _probe_pairs(n_pairs, rng)
    color = color_direction(brdf, nn, np.concatenate([wi, wo]), (np.arange(len(wi)), np.arange(len(wi)) + len(wi)))[0]
    lo, hi = int(normal_range[0]) // 2, (int(normal_range[1]) - 1) // 2  # the odd R = 2j + 1 in the range
    j, ne, nmet, ntr = binary_search_rate(
        lambda j: normal_domain_error(brdf, 2 * j + 1, nn, wi, wo, color), max(lo, 0), max(hi, 0), normal_threshold)
    dn = _sphere(n_direction_normals, rng)
    dwi, dwo = _probe_pairs(n_direction_pairs, rng)
    k, de, dmet, dtr = binary_search_rate(
        lambda k: direction_domain_error(brdf, k, dn, dwi, dwo, color), int(direction_range[0]),
        int(direction_range[1]), direction_threshold)
    return SamplingRates(2 * j + 1, k, ne, de, nmet, dmet, [(2 * a + 1, e) for a, e in ntr], dtr,
                         float(normal_threshold), float(direction_threshold))


# ---------------------------------------------------------------------------------------------------
# Per-material factors, cached on disk
# ---------------------------------------------------------------------------------------------------


@dataclasses.dataclass(eq=False)
class MaterialFactors:
    """The precomputed M of one small-scale BRDF on one direction grid (Wu §3.5): M (R² octahedral texels ×
    U unordered pairs of the K×K grid) ≈ `factors`, scalar after Wu's colour projection on `color` (d);
    `color_residual` the RGB power it loses; `rates` the `SamplingRates` when R was searched; `info` (ranks,
    power kept, timings, ...); `key` the cache key; `source` "computed", "memory" or the file read."""

    brdf: object
    directions: int
    normal_res: int
    color: np.ndarray
    color_residual: float
    factors: MatrixFactors
    rates: SamplingRates | None = None
    info: dict = dataclasses.field(default_factory=dict)
    key: str = ""
    source: str = "computed"

    @property
    def nbytes(self) -> int:
        """Bytes of the factors held for this material (Wu Table 3's "final size")."""
        return self.factors.nbytes + int(self.color.nbytes)

    @property
    def rank(self) -> int:
        return self.factors.rank

    def rows_at(self, normals) -> tuple[np.ndarray, np.ndarray]:
        """M's factors with rows at arbitrary unit normals (L, 3) (a bake's bin normals): (left (L, r + 1)
        interpolated bilinearly over the octahedral texels, right (U, r + 1)), for `pair_sums`."""
        idx, w = octahedral_corners(np.asarray(normals, np.float64).reshape(-1, 3), self.normal_res)
        left = self.factors.left()
        return np.einsum("lc,lca->la", w, left[idx]), self.factors.right()

    def header(self) -> dict:
        return {"key": self.key, "brdf": repr(self.brdf), "brdf_type": type(self.brdf).__name__,
                "directions": self.directions, "normal_res": self.normal_res,
                "color_residual": self.color_residual, "factors": self.factors.header(),
                "rates": None if self.rates is None else self.rates.as_dict(), "info": self.info}

    def save(self, path) -> None:
        """Write atomically as a versioned npz (`MaterialFactors.load` reads it back)."""
        save_npz(path, "matrix_factors", FACTORS_VERSION, self.header(),
                 {"color": self.color, **self.factors.arrays("m_")})

    @classmethod
    def load(cls, path, brdf=None) -> MaterialFactors:
        head, arrays = read_npz(path, "matrix_factors", versions=(FACTORS_VERSION,))
        try:
            f = MatrixFactors.from_arrays(arrays, head["factors"], "m_")
            rates = None if head.get("rates") is None else SamplingRates(**head["rates"])
            return cls(brdf if brdf is not None else head["brdf"], int(head["directions"]), int(head["normal_res"]),
                       arrays["color"], float(head["color_residual"]), f, rates, dict(head.get("info") or {}),
                       str(head.get("key", "")), os.fspath(path))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{path} is missing {exc} (corrupt matrix-factors file)") from None


def _brdf_identity(brdf) -> bytes:
    """The bytes that identify a BRDF's values: its type and packed parameters (analytic), or its table
    (measured: its `data` array and interpolation mode)."""
    name = type(brdf).__name__.encode()
    if _analytic(brdf) is not None:
        return name + b";" + np.asarray(brdf.packed(), np.float64).tobytes()
    data = getattr(brdf, "data", None)
    if data is None:
        raise ValueError(f"the matrix method needs an analytic BRDF or a tabulated one, got {brdf!r}")
    arr = np.ascontiguousarray(data)
    return (name + f";{arr.dtype.str}{arr.shape};{getattr(brdf, 'interpolation', '')};".encode()
            + hashlib.sha256(arr.tobytes()).digest())


def factors_key(brdf, directions: int, normal_res, power: float = M_POWER, oversample: int = 10,
                power_iterations: int = 2, seed: int = 0, dtype=np.float32, search=None) -> str:
    """The hex SHA-256 of everything `material_factors`' result depends on: the BRDF (type and parameters),
    the grid K, the normal resolution (or, for "auto", the search settings), the SVD settings, the stored
    dtype and FACTORS_KEY_VERSION."""
    auto = isinstance(normal_res, str) and normal_res == "auto"
    settings = {"v": FACTORS_KEY_VERSION, "K": int(directions), "R": "auto" if auto else int(normal_res),
                "power": float(power), "oversample": int(oversample), "q": int(power_iterations), "seed": int(seed),
                "dtype": np.dtype(dtype).str, "search": dict(search or {}) if auto else None}
    h = hashlib.sha256(b"warp_biscale matrix factors;")
    h.update(json.dumps(settings, sort_keys=True, default=str).encode())
    h.update(_brdf_identity(brdf))
    return h.hexdigest()


def factors_cache_dir():
    """Where `material_factors` caches by default: $WARP_BISCALE_MATRIX_CACHE, else the library's cache
    folder's `matrix` (`io.cache_folder`: ~/.cache/warp_biscale/matrix unless moved)."""
    return os.environ.get("WARP_BISCALE_MATRIX_CACHE") or os.path.join(cache_folder(), "matrix")


def material_factors(brdf, directions: int = 12, normal_res="auto", power: float = M_POWER, oversample: int = 10,
                     power_iterations: int = 2, seed: int = 0, dtype=np.float32, cache_dir=None,
                     memory_budget: int = MEMORY_BUDGET, search: dict | None = None, backend=None) -> MaterialFactors:
    """The factors of M for one small-scale BRDF on the K×K grid (K = `directions`): precomputed once, then
    read from the cache (Wu §3.5: "precompute once, edit forever").

    normal_res: odd R of the octahedral map of M's rows, or "auto": Wu's binary search (`sampling_rates`, with
    `search` its keyword arguments; its bidirectional rate is recorded as info["directions_advised"]: a bake
    whose K is below it interpolates M coarser than Wu's 2 % threshold). power: the fraction of M's power kept
    (Wu's 98 %). The SVD is float64 (Wu §6), the stored factors `dtype` (Wu stores single precision). M is
    built in memory when it takes at most `memory_budget` bytes, else generated in row blocks on every pass.
    cache_dir: a folder (default `factors_cache_dir()`), or False for no disk cache. The last few results are
    also kept in memory. An unreadable cache file is computed again and replaced; an unwritable folder gives a
    warning and the result stays in memory.
    backend: a Backend object whose kernels tabulate M (stage `matrix`, float32; info["m_source"] names it),
    or None for numpy (float64). The cache key leaves it out, as `truth.truth_key` leaves out the backend:
    the kernels agree with numpy to ~2e-5 of M's peak (tests/test_matrix_bake.py), far below the 2 % of M's
    power the truncation drops, and the factors are stored in float32 either way.
    """
    backend = _check_backend(backend)
    k = int(directions)
    if k != directions or not (2 <= k <= 64):
        raise ValueError(f"directions must be an integer grid size K in [2, 64], got {directions!r}")
    if normal_res != "auto":
        r = _check_res(normal_res)
        if r % 2 == 0:
            raise ValueError(f"normal_res must be odd (the pole +z on a texel centre), got {normal_res!r}")
    if not (0 < float(power) <= 1):
        raise ValueError(f"power must be a fraction in (0, 1], got {power!r}")
    search = dict(search or {})
    key = factors_key(brdf, k, normal_res, power, oversample, power_iterations, seed, dtype, search)
    hit = _MEMORY.get(key)
    if hit is not None:
        _MEMORY.move_to_end(key)
        return dataclasses.replace(hit, source="memory")
    folder = factors_cache_dir() if cache_dir is None else cache_dir
    path = None
    if folder is not False:
        path = os.path.join(os.fspath(folder), f"{type(brdf).__name__.lower()}-{key[:24]}.npz")
        if os.path.exists(path):
            try:
                got = MaterialFactors.load(path, brdf)
            except (ValueError, OSError):
                got = None
            if got is not None and got.key == key:
                _remember(key, got)
                return got
    out = _compute_factors(brdf, k, normal_res, power, oversample, power_iterations, seed, dtype, memory_budget, search,
                           backend)
    out.key = key
    _remember(key, out)
    if path is not None:
        try:
            out.save(path)
        except OSError as exc:
            warnings.warn(f"could not write the matrix-factors cache {path} ({exc.strerror or exc}): kept in memory "
                          "only", stacklevel=2)
    return out


def _remember(key, value):
    _MEMORY[key] = value
    _MEMORY.move_to_end(key)
    while len(_MEMORY) > _MEMORY_ENTRIES:
        _MEMORY.popitem(last=False)


def _compute_factors(brdf, k, normal_res, power, oversample, power_iterations, seed, dtype, budget, search,
                     backend=None):
    timings = {}
    t0 = time.perf_counter()
    rates = None
    if normal_res == "auto":
        rates = sampling_rates(brdf, **search)
        normal_res = rates.normal_res
        timings["search"] = time.perf_counter() - t0
    r = int(normal_res)
    normals = octahedral_normals(r)
    omega = octahedral_solid_angles(r)
    grid = dirs.grid(k)
    pairs = dirs.unordered_pairs(len(grid))
    t1 = time.perf_counter()
    d, residual = color_direction(brdf, normals, grid, pairs, backend=backend)
    timings["color"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    shape = (len(normals), len(pairs[0]))
    # (made a block of rows at a time: bounded temporaries; by the kernels for an analytic BRDF)
    m = brdf_rows(brdf, normals, grid, pairs, d, backend=backend)
    if shape[0] * shape[1] * 8 <= budget:
        m = m.dense()
        timings["matrix"] = time.perf_counter() - t1
        t1 = time.perf_counter()
    f = randomized_svd(m, power=power, oversample=oversample, power_iterations=power_iterations, seed=seed,
                       center=True, row_weights=np.sqrt(omega), dtype=dtype)
    timings["svd"] = time.perf_counter() - t1
    info = {"rows": shape[0], "columns": shape[1], "matrix_bytes": shape[0] * shape[1] * 8, "rank": f.rank,
            "power_kept": f.power_kept, "power_target": float(power), "streamed": not isinstance(m, np.ndarray),
            "timings": timings,
            "m_source": (backend.name if backend is not None and (_analytic(brdf) is not None
                                                                   or _kernel_measured(brdf, backend) is not None)
                         else "numpy")}
    if rates is not None:
        info["directions_advised"] = rates.directions
    return MaterialFactors(brdf, k, r, d.astype(np.float64), residual, f, rates, info)


# ---------------------------------------------------------------------------------------------------
# N, and the effective BRDF of a bake from N's and M's factors
# ---------------------------------------------------------------------------------------------------


def bvndf_factors(histogram, solid_angle=None, power: float = N_POWER, oversample: int = 10,
                  power_iterations: int = 2, seed: int = 0, dtype=np.float32) -> MatrixFactors:
    """N's factors (Wu §3.4): the histogram (U pairs × L bins, `Bvndf.histogram` or a bake channel's),
    its columns weighted by 1/√Ω of their bins (`Bvndf.solid_angle`: the SVD then sees the BVNDF's density
    N/Ω), the mean row subtracted, the fewest ranks holding `power` of it kept (Wu's 99.5 %), in float64."""
    n = np.asarray(histogram, np.float64)
    cw = None if solid_angle is None else 1.0 / np.sqrt(np.asarray(solid_angle, np.float64))
    return randomized_svd(n, power=power, oversample=oversample, power_iterations=power_iterations, seed=seed,
                          center=True, col_weights=cw, dtype=dtype)


def matrix_tables(channels, bin_normals, material_factors_list, a_v, n_materials=None) -> np.ndarray:
    """(M, K², K², 3) float64 RGB f̄ per material from N's factors and the materials' M factors (Wu Eq. 12).

    channels: [(material id, rgb multiplier (3,), N factors)] as the bake splits the facets (bake._channels:
    one per material some facet lies on, or per such material and colour component), each N (U × L) over the
    bake's bins;
    bin_normals (L, 3) those bins' normals (`Bvndf.normal`), where each material's M rows are interpolated;
    material_factors_list: a `MaterialFactors` per material id, on the bake's grid; a_v (K²,).
    f̄_m = Σ_{channels of m} mult ⊙ d_m · f̄_channel, clamped at 0."""
    a_v = np.asarray(a_v, np.float64)
    nd = len(a_v)
    k = int(round(np.sqrt(nd)))
    n_mat = len(material_factors_list) if n_materials is None else int(n_materials)
    out = np.zeros((n_mat, nd, nd, 3))
    rows = {}
    for m, mult, nf in channels:
        mf = material_factors_list[m]
        if mf.directions != k:
            raise ValueError(f"material {m}'s factors are for K = {mf.directions}, the bake's grid is K = {k}")
        if m not in rows:
            rows[m] = mf.rows_at(bin_normals)
        table = effective_from_factors(nf, rows[m], a_v)
        out[m] += table[..., None] * (np.asarray(mult, np.float64) * mf.color)[None, None, :]
    return np.maximum(out, 0.0)


# ---------------------------------------------------------------------------------------------------
# The baked material (wb.bake(..., method="matrix"))
# ---------------------------------------------------------------------------------------------------

# What `material_factors` is called with for every material of a matrix bake (bake's `matrix=` options):
# M's octahedral resolution ("auto": Wu's search) and power, the SVD's settings (shared by N and M), N's
# power, the cache folder (None: `factors_cache_dir()`; False: none), the search's keyword arguments and
# the in-memory budget of M.
FACTOR_SETTINGS = {"normal_res": "auto", "power": M_POWER, "n_power": N_POWER, "oversample": 10,
                   "power_iterations": 2, "seed": 0, "cache_dir": None, "search": None,
                   "memory_budget": MEMORY_BUDGET}
_RUNTIME_SETTINGS = ("cache_dir", "memory_budget")  # where and how, not what: not written to a material file

# One line for whatever reads SG lobes off a material (the SG renderer's packing, the Monte Carlo reference's
# BRDF sampling, the SG texel kernels, the Mitsuba export): a matrix-method material has none.
NO_LOBES = ("a material baked by the matrix method (Wu 2011) holds f-bar tables from N's and M's factors, not "
            "the SG lobes and amplitudes that the SG renderer, the Monte Carlo reference's sampling and the "
            "Mitsuba export read: render it with method='litsphere', or bake the tile with method='sg'")


def check_factor_settings(options) -> dict:
    """`FACTOR_SETTINGS` updated by `options` (a dict or None), checked; one-line errors name the key."""
    if options is None:
        options = {}
    if not isinstance(options, dict):
        raise ValueError(f"matrix options must be a dict (keys {sorted(FACTOR_SETTINGS)}), got {options!r}")
    unknown = sorted(set(options) - set(FACTOR_SETTINGS))
    if unknown:
        raise ValueError(f"unknown matrix option(s) {unknown}; known: {sorted(FACTOR_SETTINGS)}")
    out = {**FACTOR_SETTINGS, **options}
    r = out["normal_res"]
    if not (isinstance(r, str) and r == "auto"):
        if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 1 or r % 2 == 0:
            raise ValueError(f"matrix normal_res must be 'auto' or an odd integer >= 1 (M's octahedral map, the "
                             f"pole +z on a texel centre), got {r!r}")
        out["normal_res"] = int(r)
    for name in ("power", "n_power"):
        v = out[name]
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not (0 < float(v) <= 1):
            raise ValueError(f"matrix {name} must be a fraction of the power in (0, 1], got {v!r}")
        out[name] = float(v)
    for name, lo in (("oversample", 0), ("power_iterations", 0), ("seed", 0), ("memory_budget", 0)):
        v = out[name]
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"matrix {name} must be an integer >= {lo}, got {v!r}")
        out[name] = int(v)
    if out["search"] is not None and not isinstance(out["search"], dict):
        raise ValueError(f"matrix search must be a dict of sampling_rates' keyword arguments, got {out['search']!r}")
    if out["cache_dir"] not in (None, False) and not isinstance(out["cache_dir"], (str, os.PathLike)):
        raise ValueError(f"matrix cache_dir must be a folder, None (the default) or False, got {out['cache_dir']!r}")
    return out


def factors_for(materials, used, directions: int, settings: dict, backend=None) -> list:
    """[MaterialFactors or None] per material: `material_factors` (cached) for the material ids in `used`,
    None for the others (ids the tile does not hold reflect nothing)."""
    out = [None] * len(materials)
    for m in sorted(used):
        out[m] = material_factors(materials[m], directions=directions, normal_res=settings["normal_res"],
                                  power=settings["power"], oversample=settings["oversample"],
                                  power_iterations=settings["power_iterations"], seed=settings["seed"],
                                  cache_dir=settings["cache_dir"], memory_budget=settings["memory_budget"],
                                  search=settings["search"], backend=backend)
    return out


def _factor_info(mf) -> dict:
    """What a bake reports of one material's M factors (Wu Table 3's columns, ours)."""
    return {"normal_res": mf.normal_res, "rows": mf.factors.shape[0], "columns": mf.factors.shape[1],
            "rank": mf.rank, "power_kept": mf.factors.power_kept, "bytes": mf.nbytes,
            "matrix_bytes": mf.factors.shape[0] * mf.factors.shape[1] * 8, "color": [float(c) for c in mf.color],
            "color_residual": mf.color_residual, "source": "computed" if mf.source == "computed" else "cache",
            "m_source": mf.info.get("m_source", "numpy"), "directions_advised": mf.info.get("directions_advised"),
            "precompute_s": float(sum(mf.info.get("timings", {}).values())) if mf.source == "computed" else 0.0,
            "key": mf.key}


class MatrixBRDF(HostOnlyBRDF):
    """A material baked by Wu's matrix method (`wb.bake(tile, materials, method="matrix")`): f̄ on the K×K
    grid from the factors of the bake's BVNDF histogram N (per colour channel) and of each small-scale
    BRDF's pre-rotated, cosine-weighted matrix M (precomputed once per material and cached on disk), by
    Eq. 12, colour as Wu §3.7 (`matrix_tables`).

    The interface of `EffectiveBRDF`: `eval(wi, wo)` (cosine θi included, bilinear in f̄/cos θi as §4.4),
    `table()`, `wb.compare`, `save` / `wb.load` (format "matrix_brdf"), `with_materials` (new small-scale
    BRDFs: their M factors, from the cache or computed, and Eq. 12 — N is not re-baked), `provenance`,
    `path`, `timings`, `info`. Attributes: `tables` (M, K², K², 3) float32 f̄ per material, `bvndf` (the
    bins' mean normals, where M's rows are interpolated, their areas, a_v; the histogram itself only with
    `bake(..., bvndf=True)`), `channels` [(material id, rgb multiplier, N's MatrixFactors)], `factors`
    [MaterialFactors or None per material] (None after `load` until an edit fetches them), `settings`
    (FACTOR_SETTINGS), `factor_bytes` (the memory of the factors). It has no SG lobes: the SG renderer and
    the Monte Carlo reference's sampling refuse it in one line (`NO_LOBES`); the lit-sphere renderer
    evaluates it on the host (`host_texels`)."""

    VERSION = 1
    VERSIONS = (1,)
    FORMAT = "matrix_brdf"
    no_sg_lobes = NO_LOBES

    def __init__(self, tables, materials, directions: int, bvndf: Bvndf, channels, factors=None, settings=None,
                 timings=None, info=None, provenance: Provenance | None = None, path=None, backend=None):
        self.directions = int(directions)
        nd = self.directions**2
        self.tables = np.asarray(tables, np.float32)
        if self.tables.ndim != 4 or self.tables.shape[1:] != (nd, nd, 3):
            raise ValueError(f"tables must have shape (M, {nd}, {nd}, 3), got {self.tables.shape}")
        check_amplitudes(self.tables, "tables")
        self.materials = as_material_list(materials)
        if len(self.materials) != len(self.tables):
            raise ValueError(f"{len(self.tables)} table(s) but {len(self.materials)} material(s)")
        if not isinstance(bvndf, Bvndf) or np.shape(bvndf.a_v) != (nd,):
            raise ValueError(f"bvndf must be a Bvndf with a_v of {nd} directions")
        self.bvndf = bvndf
        self.channels = [(int(m), np.asarray(mult, np.float64).reshape(3), f) for m, mult, f in channels]
        for m, _, f in self.channels:
            if not (0 <= m < len(self.materials)) or not isinstance(f, MatrixFactors):
                raise ValueError(f"channel of material {m}: want a material id below {len(self.materials)} and "
                                 "N's MatrixFactors")
            if f.shape != (nd * (nd + 1) // 2, len(bvndf.normal)):
                raise ValueError(f"N's factors are {f.shape}, want (pairs, bins) = "
                                 f"({nd * (nd + 1) // 2}, {len(bvndf.normal)})")
        self.factors = list(factors) if factors is not None else [None] * len(self.materials)
        if len(self.factors) != len(self.materials):
            raise ValueError(f"{len(self.factors)} factor set(s) for {len(self.materials)} material(s)")
        self.settings = check_factor_settings({k: v for k, v in (settings or {}).items() if k in FACTOR_SETTINGS})
        self.method = "matrix"
        self.timings = dict(timings or {})
        self.info = dict(info or {})
        if provenance is not None and not isinstance(provenance, Provenance):
            raise ValueError(f"provenance must be an effective.Provenance or None, got {type(provenance).__name__}")
        if provenance is not None and provenance.tile.n_materials > len(self.materials):
            raise ValueError(f"provenance: the tile has {provenance.tile.n_materials} material ids but the material "
                             f"has {len(self.materials)} BRDF(s)")
        self.provenance = provenance
        self.path = None if path is None else os.path.abspath(os.fspath(path))
        self._backend = backend  # what computes M for an edit's new materials (None: numpy)
        self._table = self.tables.sum(axis=0, dtype=np.float64)

    def __getstate__(self):
        """Pickled (a batch task's result) without the backend an edit would use: it holds device state."""
        return {**self.__dict__, "_backend": None}

    def __repr__(self):
        ranks = [f.rank for f in self.factors if f is not None]
        n_ranks = [f.rank for *_, f in self.channels]
        return (f"MatrixBRDF(K={self.directions}, materials={self.materials}, N ranks={n_ranks}, "
                f"M ranks={ranks or 'not loaded'})")

    # ------------------------------------------------------------------ what the SG form has and this has not
    @property
    def amplitudes(self):  # (HostOnlyBRDF refuses the lobes, the diffuse table and the Mitsuba export)
        raise ValueError(NO_LOBES)

    # ------------------------------------------------------------------ tables and memory
    @property
    def nbytes_per_material(self) -> int:
        """Bytes of one material's f̄ table (what a renderer would upload per material)."""
        return int(self.tables[0].nbytes)

    @property
    def factor_bytes(self) -> dict:
        """The memory of the factors (Wu Table 3's "final size"): {"n": N's factors over every channel,
        "m": {material id: its M factors}} in bytes; M's from `info` for a loaded material."""
        m = {i: f.nbytes for i, f in enumerate(self.factors) if f is not None}
        if not m:
            m = {int(i): int(v["bytes"]) for i, v in (self.info.get("m_factors") or {}).items()}
        return {"n": int(sum(f.nbytes for *_, f in self.channels)), "m": m}

    def table(self, method: str | None = None) -> np.ndarray:
        """(K², K², 3) f̄ on the bake's own grid (every material summed): table[i, o] at ωi = grid[i], ωo = grid[o]."""
        self._check_method(method)
        return self._table.copy()

    @staticmethod
    def _check_method(method):
        if method not in (None, "matrix"):
            raise ValueError(f"a matrix-method material evaluates its own tables (method 'matrix' or None), not "
                             f"{method!r}")

    def eval(self, wi, wo, method: str | None = None) -> np.ndarray:
        """(N, 3) f̄(ωi, ωo) (cosine θi included, docs/design.md §4) at arbitrary directions; 0 below the
        horizon. f̄/cos θi is interpolated bilinearly in the square domain of each direction (§4.4), so a
        flat Lambertian tile gives (kd/π)cos θi everywhere."""
        self._check_method(method)
        wi = dirs.check_directions("wi", wi)
        wo = dirs.check_directions("wo", wo)
        if len(wi) != len(wo):
            raise ValueError(f"wi and wo must have the same length, got {len(wi)} and {len(wo)}")
        k = self.directions
        per_cos = self._table / dirs.grid(k)[:, 2][:, None, None]
        ii, wi_w = dirs.bilinear_corners(wi, k)
        oo, wo_w = dirs.bilinear_corners(wo, k)
        out = np.zeros((len(wi), 3))
        for a in range(4):
            for b in range(4):
                out += (wi_w[:, a] * wo_w[:, b])[:, None] * per_cos[ii[:, a], oo[:, b]]
        out *= np.maximum(wi[:, 2], 0.0)[:, None]
        out[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] = 0.0
        return np.maximum(out, 0.0)

    # ------------------------------------------------------------------ edits
    def with_materials(self, materials, backend=None, cache_dir=None) -> MatrixBRDF:
        """The same N with other small-scale BRDFs (a material-only edit, Wu §3.6): each new material's M
        factors (`material_factors` with this bake's `settings`: from the cache when precomputed, else
        computed — by `backend`'s kernels, default the bake's, or numpy after `load`), then Eq. 12. Nothing
        of the geometry is recomputed. `timings`: "m_factors" and "tables". Provenance and `path` carry over,
        as EffectiveBRDF.with_materials."""
        mats = as_material_list(materials)
        used = {m for m, _, _ in self.channels}
        if used and len(mats) <= max(used):
            raise ValueError(f"the bake's N holds material ids up to {max(used)}, but {len(mats)} BRDF(s) were "
                             "given")
        be = _check_backend(backend) if backend is not None else self._backend
        settings = dict(self.settings)
        if cache_dir is not None:
            settings["cache_dir"] = cache_dir
        t0 = time.perf_counter()
        factors = factors_for(mats, used, self.directions, settings, be)
        t1 = time.perf_counter()
        tables = matrix_tables(self.channels, self.bvndf.normal, factors, self.bvndf.a_v, n_materials=len(mats))
        t2 = time.perf_counter()
        info = {**self.info, "m_factors": {str(i): _factor_info(f) for i, f in enumerate(factors) if f is not None}}
        out = MatrixBRDF(tables, mats, self.directions, self.bvndf, self.channels, factors, settings,
                         {"m_factors": t1 - t0, "tables": t2 - t1}, info, self.provenance, self.path, be)
        out.info["factor_bytes"] = out._factor_bytes_json()
        return out

    def _factor_bytes_json(self) -> dict:
        """`factor_bytes` as `info` holds it (material ids as strings, as a material file's JSON header has them)."""
        fb = self.factor_bytes
        return {"n": fb["n"], "m": {str(i): v for i, v in fb["m"].items()}}

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write atomically as a versioned npz (format "matrix_brdf", `wb.load` reads it back): the f̄
        tables, N's factors per channel, the bins and a_v, the materials, settings, provenance, info and
        timings. M's factors are not in the file: they are the materials' own, in the factor cache (an edit
        after `load` fetches them there, or computes them)."""
        check_output(path, what="material file")
        arrays = {"tables": self.tables, **{f"bvndf_{k}": v for k, v in self.bvndf.arrays().items()},
                  "channel_material": np.array([m for m, _, _ in self.channels], np.int32),
                  "channel_mult": np.array([mult for _, mult, _ in self.channels], np.float64).reshape(-1, 3)}
        for c, (_, _, f) in enumerate(self.channels):
            arrays.update(f.arrays(f"n{c}_"))
        if self.provenance is not None:
            arrays.update(self.provenance.arrays())
        materials, tables = materials_to_file(self.materials)
        arrays.update(tables)
        settings = {k: v for k, v in self.settings.items() if k not in _RUNTIME_SETTINGS}
        save_npz(path, self.FORMAT, self.VERSION,
                 {"directions": self.directions, "method": "matrix",
                  "materials": materials, "settings": settings,
                  "channels": [f.header() for *_, f in self.channels], "info": self.info, "timings": self.timings,
                  "bvndf_resolution": self.bvndf.resolution,
                  "provenance": None if self.provenance is None else self.provenance.header()},
                 arrays)
        self.path = os.path.abspath(os.fspath(path))

    @classmethod
    def load(cls, path) -> MatrixBRDF:
        head, arrays = read_npz(path, cls.FORMAT, versions=cls.VERSIONS)
        try:
            mats = materials_from_file(head["materials"], arrays)
            bv = Bvndf.from_arrays(head["bvndf_resolution"], {k[6:]: v for k, v in arrays.items()
                                                              if k.startswith("bvndf_")})
            channels = [(int(m), mult, MatrixFactors.from_arrays(arrays, h, f"n{c}_"))
                        for c, (m, mult, h) in enumerate(zip(arrays["channel_material"], arrays["channel_mult"],
                                                             head["channels"]))]
            prov = Provenance.from_file(head["provenance"], arrays) if head.get("provenance") is not None else None
            return cls(arrays["tables"], mats, head["directions"], bv, channels, None, head.get("settings"),
                       head.get("timings"), head.get("info"), prov, path)
        except KeyError as exc:
            raise ValueError(f"{path} is missing {exc} (corrupt matrix-method material file)") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path} is not a valid matrix-method material file: {exc}") from None

    @classmethod
    def from_bake(cls, tables, materials, directions, bvndf, channels, factors, settings, timings, info,
                  provenance, backend) -> MatrixBRDF:
        """The bake's result, with every material's M factors reported in `info` ("m_factors", and
        "factor_bytes": the memory of N's and M's factors)."""
        info = {**info, "m_factors": {str(i): _factor_info(f) for i, f in enumerate(factors) if f is not None}}
        out = cls(tables, materials, directions, bvndf, channels, factors, settings, timings, info, provenance,
                  None, backend)
        out.info["factor_bytes"] = out._factor_bytes_json()
        return out
