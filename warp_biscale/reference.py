"""Float64 numpy reference: slow, obvious, the oracle every kernel is tested against.

Nothing here is fast. Each function spells out the mathematics of docs/design.md §4 the way a reader would
check it by hand; the kernels in `kernels/` and `cl/` reproduce the same numbers in float32.
"""

from __future__ import annotations

import numpy as np

from . import lobes

# The float64 conventions and helpers that production code needs too live there; they are named
# here as well, so that a test reads every oracle from one module.
from .brdf import (ANISOTROPIC_WARD, ASHIKHMIN_SHIRLEY, BLINN_PHONG, COOK_TORRANCE, WARD,  # noqa: F401
                   brdf_cosine_weighted, tangent_frame)
from .directions import cube_bin  # noqa: F401
from .directions import grid as direction_grid
from .environment import (
    environment_irradiance,  # noqa: F401
    equirect_directions,
    equirect_row_solid_angles,
)
from .lighting import prefiltered_lookup, sg_irradiance  # noqa: F401
from .model import facet_shift, radical_inverse  # noqa: F401
from .trace import (LOBE_RAYS, above_horizon, block_pixel, block_side, block_sub_lenders, check_ray_part, disk_basis,
                    disk_sample, light_samples, lobe_ray_directions, occlusion_directions, part_rays, pixel_parts,
                    horizon_frame, ray_starts)
from .sg import one_minus_cos
from .smallscale import (
    SmallScale,
    default_face_tangents,
    ray_offset,  # noqa: F401
)
from .ssdf import ssdf_eval  # noqa: F401

__all__ = [
    "radical_inverse",
    "sample_facets",
    "ray_offset",
    "trace_periodic",
    "visibility",
    "brdf_cosine_weighted",
    "visible_area",
    "effective_brdf",
    "interreflection",
    "trace_periodic_closest",
    "vgroove_tile",
    "vgroove_effective_brdf",
    "cube_bin",
    "bvndf_histogram",
    "ndf_statistics",
    "ndf_em",
    "visible_weights",
    "lobe_values",
    "lobe_moments",
    "histogram_moments",
    "solve_amplitudes",
    "amplitude_tables",
    "energy_levels",
]

# ----------------------------------------------------------------------------------------------
# Facet sampling (Wu §3.2, made stratified)
#
# Facet s takes the 2-D point (u1, u2) = ((s + ξ1)/Ns, frac(φ2(s) + ξ2)) of a Hammersley set with a
# Cranley–Patterson shift (ξ1, ξ2) drawn from the seed. u1 walks the cumulative area of the faces,
# so facet counts per face are proportional to area to within one, and every facet carries the same
# area ΔA = A/Ns; the remainder of u1 inside its face and u2 place the point by the area-preserving
# square→triangle map. The estimator Σ_s g(x_s) ΔA of ∫g dA is unbiased for any shift and, being a
# low-discrepancy rule, its error falls faster than the 1/√Ns of independent sampling.
# ----------------------------------------------------------------------------------------------


def sample_facets(tile, count: int, seed: int = 0) -> dict:
    """Reference facet set: dict of position, normal, face, area, material, color (float64)."""
    count = int(count)
    areas = tile.face_areas
    cum = np.cumsum(areas)
    total = cum[-1]
    xi1, xi2 = facet_shift(seed)
    s = np.arange(count)
    target = (s + xi1) / count * total
    face = np.minimum(np.searchsorted(cum, target, side="right"), len(areas) - 1)
    start = cum[face] - areas[face]
    u = np.clip((target - start) / areas[face], 0.0, 1.0)
    v = np.mod(radical_inverse(s) + xi2, 1.0)
    su = np.sqrt(u)
    b0, b1, b2 = 1.0 - su, su * (1.0 - v), su * v
    tri = tile.triangles[face]
    pos = b0[:, None] * tri[:, 0] + b1[:, None] * tri[:, 1] + b2[:, None] * tri[:, 2]
    if tile.vertex_normals is not None:
        vn = tile.vertex_normals[tile.faces[face]]
        nrm = b0[:, None] * vn[:, 0] + b1[:, None] * vn[:, 1] + b2[:, None] * vn[:, 2]
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    else:
        nrm = tile.face_normals[face]
    return {
        "position": pos,
        "normal": nrm,
        "face": face.astype(np.int32),
        "area": np.full(count, total / count),
        "material": tile.material_ids[face],
        "color": tile.colors[face],
    }


# ----------------------------------------------------------------------------------------------
# Visibility of the infinitely tiled surface (Wu §3.3, docs/design.md §4)
# ----------------------------------------------------------------------------------------------


def _ray_hits_any(o, d, t_lo, t_hi, tri):
    """Möller–Trumbore, double-sided: (R,) bool, any triangle hit with t in (t_lo, t_hi]."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = b - a, c - a  # (F,3)
    p = np.cross(d[:, None, :], e2[None])  # (R,F,3)
    det = np.einsum("rfk,fk->rf", p, e1)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = o[:, None, :] - a[None]
    u = np.einsum("rfk,rfk->rf", tv, p) * inv
    q = np.cross(tv, e1[None])
    v = np.einsum("rk,rfk->rf", d, q) * inv
    t = np.einsum("fk,rfk->rf", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > t_lo[:, None]) & (t <= t_hi[:, None])
    return hit.any(axis=1)


def trace_periodic(tile, origins, direction) -> np.ndarray:
    """(R,) bool: True where the ray from `origins` along the unit `direction` (z > 0) leaves the
    tile's height range unblocked, the tile repeated infinitely in x and y.

    A ray crossing the tile's xy boundary re-enters from the opposite side, one cell at a time,
    until it passes above the highest point. Each cell's segment is extended back by the ray
    offset (not the first one, which starts on the facet) so that float rounding at a wrap cannot
    open a gap.
    """
    d = np.asarray(direction, np.float64)
    o = np.array(origins, np.float64)
    r = len(o)
    if d[2] <= 0:
        return np.zeros(r, bool)
    eps = ray_offset(tile)
    x0, y0 = tile.origin
    px, py = tile.period
    zlo, zhi = tile.z_range
    z_top = zhi + eps
    tri = tile.triangles
    visible = np.zeros(r, bool)
    active = np.ones(r, bool)
    back = np.zeros(r)
    max_steps = 4 + int(np.ceil((zhi - zlo + 2 * eps) / d[2] * (abs(d[0]) / px + abs(d[1]) / py)))
    for _ in range(max_steps + 1):
        if not active.any():
            break
        idx = np.nonzero(active)[0]
        oa = o[idx]
        t_top = (z_top - oa[:, 2]) / d[2]
        with np.errstate(divide="ignore"):
            t_x = np.where(d[0] > 0, (x0 + px - oa[:, 0]) / d[0], np.where(d[0] < 0, (x0 - oa[:, 0]) / d[0], np.inf))
            t_y = np.where(d[1] > 0, (y0 + py - oa[:, 1]) / d[1], np.where(d[1] < 0, (y0 - oa[:, 1]) / d[1], np.inf))
        t_x, t_y = np.maximum(t_x, 0.0), np.maximum(t_y, 0.0)
        t_exit = np.minimum(t_top, np.minimum(t_x, t_y))
        hit = _ray_hits_any(oa, np.broadcast_to(d, oa.shape), -back[idx], t_exit + eps, tri)
        escaped = ~hit & (t_top <= np.minimum(t_x, t_y))
        visible[idx[escaped]] = True
        done = hit | escaped
        active[idx[done]] = False
        # Move the rest to the exit point and wrap into the cell on the other side.
        go = idx[~done]
        if len(go) == 0:
            break
        te = t_exit[~done]
        o[go] = oa[~done] + te[:, None] * d
        wx = t_x[~done] <= te
        wy = t_y[~done] <= te
        o[go[wx], 0] -= np.sign(d[0]) * px
        o[go[wy], 1] -= np.sign(d[1]) * py
        back[go] = eps
    return visible


def visibility(tile, facets: dict, directions: np.ndarray) -> np.ndarray:
    """(D, Ns) bool: V_s(ω_k), exact float64 periodic ray casting against every triangle.

    V is 0 where ω lies below the facet's own face plane (the ray would enter the surface).
    """
    fn = tile.face_normals[facets["face"]]
    origins = facets["position"] + ray_offset(tile) * fn
    out = np.zeros((len(directions), len(origins)), bool)
    for k, w in enumerate(np.asarray(directions, np.float64)):
        up = fn @ w > 0
        if up.any():
            out[k, up] = trace_periodic(tile, origins[up], w)
    return out


# ----------------------------------------------------------------------------------------------
# Small-scale BRDFs, cosine-weighted: f_r(n, ωi, ωo)·(n·ωi)⁺·(n·ωo)⁺ (see warp_biscale.brdf)
# ----------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------
# a_v and the ground-truth effective BRDF (docs/design.md §4)
# ----------------------------------------------------------------------------------------------


def visible_area(facets: dict, vis: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(D,) a_v(ω) = Σ_s V_s(ω)(n_s·ω)⁺ΔA_s."""
    cos = np.maximum(np.asarray(directions, np.float64) @ facets["normal"].T, 0.0)  # (D, Ns)
    return (vis * cos) @ facets["area"]


def effective_brdf(facets: dict, vis: np.ndarray, directions, kinds, params, pair_i, pair_o,
                   tangents=None) -> np.ndarray:
    """(P, 3) f̄(ωi, ωo) = Σ_s c_s f_r(n_s,ωi,ωo)(n_s·ωi)⁺(n_s·ωo)⁺ V_s(ωi)V_s(ωo)ΔA_s / a_v(ωo).

    ωi = directions[pair_i], ωo = directions[pair_o]; c_s the facet's RGB colour weight. Zero
    where a_v(ωo) = 0 (nothing of the tile is visible from ωo). `tangents` (F, 3): the tile's face
    tangents (`SmallScale.face_tangents`); facet s takes its face's, made perpendicular to n_s
    (`brdf.tangent_frame`). Needed only for the anisotropic BRDFs.
    """
    directions = np.asarray(directions, np.float64)
    a_v = visible_area(facets, vis, directions)
    out = np.zeros((len(pair_i), 3))
    n = facets["normal"]
    t = None if tangents is None else np.asarray(tangents, np.float64)[facets["face"]]
    w = facets["area"][:, None] * facets["color"]
    for p, (i, o) in enumerate(zip(pair_i, pair_o)):
        both = vis[i] & vis[o]
        if not both.any() or a_v[o] <= 0:
            continue
        fc = brdf_cosine_weighted(kinds, params, facets["material"][both], n[both], directions[i], directions[o],
                                  None if t is None else t[both])
        out[p] = (fc * w[both]).sum(axis=0) / a_v[o]
    return out


# ----------------------------------------------------------------------------------------------
# Small-scale interreflection (docs/design.md §4.6): the bounces 2..B of ground_truth(bounces=B)
# ----------------------------------------------------------------------------------------------

INTERREFLECTION_MAX_CELLS = 64  # tile cells one ray may cross before it counts as absorbed
_U32 = np.uint64(0xFFFFFFFF)


def pcg_hash(v) -> np.ndarray:
    """PCG-RXS-M-XS (Jarzynski & Olano 2020) of uint32 values, computed in uint64 and wrapped."""
    st = (np.asarray(v, np.uint64) * np.uint64(747796405) + np.uint64(2891336453)) & _U32
    word = (((st >> ((st >> np.uint64(28)) + np.uint64(4))) ^ st) * np.uint64(277803737)) & _U32
    return ((word >> np.uint64(22)) ^ word) & _U32


def path_uniform(seed, path, o, dim) -> np.ndarray:
    """The kernels' random number of (seed, path j, ωo index, dimension): 24 hash bits / 2²⁴ (exact)."""
    h = pcg_hash(np.uint64(int(seed) & 0xFFFFFFFF))
    for k in (path, o, dim):
        h = pcg_hash((h + np.asarray(k, np.uint64)) & _U32)
    return (h >> np.uint64(8)).astype(np.float64) / 16777216.0


def cosine_direction(n, u1, u2) -> np.ndarray:
    """(R, 3) cosine-distributed about unit n (R, 3): frame a = normalize(n × x̂) (n × ŷ where |n_x| ≥ 0.9),
    b = n × a; d = √u1 cos(2πu2) a + √u1 sin(2πu2) b + √(1 − u1) n."""
    a, b = disk_basis(n)
    r, phi = np.sqrt(u1)[:, None], 2 * np.pi * np.asarray(u2)[:, None]
    d = r * np.cos(phi) * a + r * np.sin(phi) * b + np.sqrt(np.maximum(1 - u1, 0.0))[:, None] * n
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _closest_in(o, d, t_lo, t_hi, tri):
    """(R,) nearest face hit with t in (t_lo, t_hi] (−1: none) and its t; double-sided Möller–Trumbore."""
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None, :], e2[None])
    det = np.einsum("rfk,fk->rf", p, e1)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = o[:, None, :] - a[None]
    u = np.einsum("rfk,rfk->rf", tv, p) * inv
    q = np.cross(tv, e1[None])
    v = np.einsum("rk,rfk->rf", d, q) * inv
    t = np.einsum("fk,rfk->rf", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > t_lo[:, None]) & (t <= t_hi[:, None])
    t = np.where(hit, t, np.inf)
    face = np.argmin(t, axis=1)
    best = t[np.arange(len(o)), face]
    return np.where(np.isfinite(best), face, -1), best


def trace_periodic_closest(tile, origins, directions):
    """(face (R,), position (R, 3)): the first hit of each ray through the infinitely tiled surface (any
    direction), the position wrapped into the tile's base cell; face −1 where the ray leaves above the
    tile, −2 where it leaves below or crosses more than INTERREFLECTION_MAX_CELLS cells. Cell by cell as
    `trace_periodic`, each cell's segment tested over (−back, t_exit + eps]."""
    o = np.array(origins, np.float64)
    d = np.asarray(directions, np.float64)
    r = len(o)
    eps = ray_offset(tile)
    x0, y0 = tile.origin
    px, py = tile.period
    zlo, zhi = tile.z_range
    tri = tile.triangles
    face = np.full(r, -2)
    pos = np.zeros((r, 3))
    back = np.zeros(r)
    active = np.ones(r, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(INTERREFLECTION_MAX_CELLS):
            idx = np.nonzero(active)[0]
            if len(idx) == 0:
                break
            oa, da = o[idx], d[idx]
            t_z = np.where(da[:, 2] > 0, (zhi + eps - oa[:, 2]) / da[:, 2],
                           np.where(da[:, 2] < 0, (zlo - eps - oa[:, 2]) / da[:, 2], np.inf))
            t_x = np.where(da[:, 0] > 0, (x0 + px - oa[:, 0]) / da[:, 0],
                           np.where(da[:, 0] < 0, (x0 - oa[:, 0]) / da[:, 0], np.inf))
            t_y = np.where(da[:, 1] > 0, (y0 + py - oa[:, 1]) / da[:, 1],
                           np.where(da[:, 1] < 0, (y0 - oa[:, 1]) / da[:, 1], np.inf))
            t_x, t_y = np.maximum(t_x, 0.0), np.maximum(t_y, 0.0)
            t_side = np.minimum(t_x, t_y)
            t_exit = np.minimum(t_z, t_side)
            f, t = _closest_in(oa, da, -back[idx], t_exit + eps, tri)
            hit = f >= 0
            face[idx[hit]] = f[hit]
            pos[idx[hit]] = oa[hit] + t[hit, None] * da[hit]
            out = ~hit & (t_z <= t_side)
            face[idx[out]] = np.where(da[out, 2] > 0, -1, -2)
            active[idx[hit | out]] = False
            go = ~(hit | out)
            g = idx[go]
            te = t_exit[go]
            o[g] = oa[go] + te[:, None] * da[go]
            wx, wy = t_x[go] <= te, t_y[go] <= te
            o[g[wx], 0] -= np.sign(da[go][wx, 0]) * px
            o[g[wy], 1] -= np.sign(da[go][wy, 1]) * py
            back[g] = eps
    return face, pos


def interreflection_facets(n_facets: int, paths: int) -> np.ndarray:
    """(paths,) the facet of each path: ⌊(j + ½)·Ns/paths⌋ in float32, as the kernels compute it."""
    j = np.arange(paths, dtype=np.float32)
    s = ((j + np.float32(0.5)) * np.float32(n_facets)) / np.float32(paths)
    return np.minimum(s.astype(np.int64), n_facets - 1)


def interreflection(tile, facets: dict, vis: np.ndarray, directions, kinds, params, pair_i, pair_o, bounces: int,
                    paths: int, seed: int = 0, tangents=None) -> np.ndarray:
    """(P, 3) the bounces 2..B of f̄(ωi, ωo), the estimator of ground_truth(bounces=B) in float64.

    f̄_B = f̄_1 + (1/a_v(ωo)) Σ_s c_s ΔA_s (n_s·ωo)⁺ V_s(ωo) L_s, with L_s the radiance leaving facet s towards
    ωo after 1..B−1 reflections of unit irradiance from ωi inside the tiled surface. Path j starts at facet
    s(j) = ⌊(j + ½)Ns/P⌋ (if seen from ωo), stands for Ns/P facets, and at bounce b draws a cosine-distributed
    direction about its normal (random numbers path_uniform(seed, j, o, 2b), (…, 2b + 1)), multiplying its
    throughput by π f_r(x, d, ω_out); the ray is traced to its first hit y through the tiled surface
    (escaping: the light is a delta, nothing more to collect; a face's back, leaving below, or crossing more
    than INTERREFLECTION_MAX_CELLS cells: absorbed); at y the throughput takes y's colour, and next-event
    estimation adds throughput · f_r(y, ωi, −d)(n_y·ωi) where y sees ωi (`trace_periodic_closest` escapes).
    Hit points use their face's geometric normal and the face's material, colour and tangent. Unbiased for the
    B-bounce radiance (up to the absorbed cases); the same random numbers as the kernels."""
    directions = np.asarray(directions, np.float64)
    pair_i, pair_o = np.asarray(pair_i), np.asarray(pair_o)
    a_v = visible_area(facets, vis, directions)
    n_facets = len(facets["normal"])
    out = np.zeros((len(pair_i), 3))
    if bounces <= 1 or len(pair_i) == 0:
        return out
    eps = ray_offset(tile)
    face_t = None if tangents is None else np.asarray(tangents, np.float64)
    jj = np.arange(paths)
    s_of = interreflection_facets(n_facets, paths)
    pp, jv = np.repeat(np.arange(len(pair_i)), paths), np.tile(jj, len(pair_i))
    s = s_of[jv]
    o_idx = pair_o[pp]
    keep = vis[o_idx, s]
    pp, jv, s, o_idx = pp[keep], jv[keep], s[keep], o_idx[keep]
    wi, wo = directions[pair_i[pp]], directions[o_idx]
    x = facets["position"][s].copy()
    n = facets["normal"][s].copy()
    ng = tile.face_normals[facets["face"][s]].copy()
    m = facets["material"][s].copy()
    tg = None if face_t is None else face_t[facets["face"][s]].copy()
    w_out = wo.copy()
    thr = (facets["area"][s, None] * facets["color"][s]) * np.maximum(np.einsum("ij,ij->i", n, wo), 0.0)[:, None]
    acc = np.zeros((len(pp), 3))
    alive = np.ones(len(pp), bool)
    for b in range(bounces - 1):
        a = np.nonzero(alive)[0]
        if len(a) == 0:
            break
        d = cosine_direction(n[a], path_uniform(seed, jv[a], o_idx[a], 2 * b), path_uniform(seed, jv[a], o_idx[a],
                                                                                             2 * b + 1))
        cd, cw = np.einsum("ij,ij->i", n[a], d), np.einsum("ij,ij->i", n[a], w_out[a])
        ok = (np.einsum("ij,ij->i", ng[a], d) > 0) & (cd > 0) & (cw > 0)
        alive[a[~ok]] = False
        a, d, cd, cw = a[ok], d[ok], cd[ok], cw[ok]
        fc = brdf_cosine_weighted(kinds, params, m[a], n[a], d, w_out[a], None if tg is None else tg[a])
        thr[a] *= fc * (np.pi / (cd * cw))[:, None]
        fh, y = trace_periodic_closest(tile, x[a] + eps * ng[a], d)
        ok = fh >= 0
        ny = tile.face_normals[np.maximum(fh, 0)]
        ok &= np.einsum("ij,ij->i", ny, d) < 0
        alive[a[~ok]] = False
        a, d, fh, y, ny = a[ok], d[ok], fh[ok], y[ok], ny[ok]
        x[a], n[a], ng[a], m[a], w_out[a] = y, ny, ny, tile.material_ids[fh], -d
        if tg is not None:
            tg[a] = face_t[fh]
        thr[a] *= tile.colors[fh]
        ci = np.einsum("ij,ij->i", ny, wi[a])
        lit = ci > 0
        if lit.any():
            c = a[lit]
            lf, _ = trace_periodic_closest(tile, x[c] + eps * n[c], wi[c])
            c = c[lf == -1]
            if len(c):
                fo = brdf_cosine_weighted(kinds, params, m[c], n[c], wi[c], w_out[c], None if tg is None else tg[c])
                acc[c] += thr[c] * fo / np.maximum(np.einsum("ij,ij->i", n[c], w_out[c]), 1e-300)[:, None]
    np.add.at(out, pp, acc)
    ok = a_v[pair_o] > 0
    out[ok] *= (n_facets / paths) / a_v[pair_o][ok, None]
    out[~ok] = 0.0
    return out


# ----------------------------------------------------------------------------------------------
# Closed form: the symmetric V-groove (two planes, shadowing and masking by the opposite wall)
# ----------------------------------------------------------------------------------------------


def vgroove_tile(depth=0.5, width=1.0):
    """The tile `vgroove_effective_brdf` describes: one V-groove along y, walls from z = 0 at x = 0
    and x = w down to z = −depth at x = w/2, period w × w."""

    v = np.array([[0, 0, 0], [width / 2, 0, -depth], [width, 0, 0],
                  [0, width, 0], [width / 2, width, -depth], [width, width, 0]], float)
    f = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    return SmallScale(v, f, name="vgroove")


def vgroove_effective_brdf(depth, width, kinds, params, wi, wo, material=0, color=(1.0, 1.0, 1.0), tangents=None):
    """(N, 3) exact f̄ of a V-groove running along y: walls from z = 0 at x = 0 and x = w down to
    z = −depth at x = w/2, tiled with period w in x (any period in y).

    Derivation. The inside of one groove is a convex triangle in the xz-plane, so a ray from a
    wall point into it leaves either through the open top (unblocked: nothing of the tiling rises
    above z = 0) or through the opposite wall (blocked). With t = ωx/ωz, a point of the left wall
    at depth fraction s ∈ [0, 1] (position (s·w/2, −s·d)) reaches z = 0 at x = s(w/2 + d·t), so it
    is visible iff s ≤ w/(w/2 + d·t): the visible fraction of the left wall is
    v_L(ω) = min(1, w/(w/2 + d·t)) where n_L·ω > 0, and by symmetry v_R(ω) = min(1, w/(w/2 − d·t)).
    Visibility is monotone in s, so the fraction seen from both ωi and ωo is min(v(ωi), v(ωo)).
    Each wall is planar with one material, so f_r(n)(n·ωi)(n·ωo) is constant on it:
    f̄ = Σ_walls f_r·(n·ωi)⁺(n·ωo)⁺·A·min(v(ωi), v(ωo)) / Σ_walls (n·ωo)⁺·A·v(ωo),
    and the denominator equals w·ℓ·cos θo (a height field's projected area), which the tests check.
    `tangents`: the walls' tangents (left wall, right wall) for the anisotropic BRDFs; default the tile's
    default (`smallscale.default_face_tangents`: +x projected onto each wall, across the groove).
    """
    wi, wo = np.atleast_2d(np.asarray(wi, np.float64)), np.atleast_2d(np.asarray(wo, np.float64))
    d, w = float(depth), float(width)
    half = w / 2
    length = np.hypot(d, half)
    normals = [np.array([d, 0.0, half]) / length, np.array([-d, 0.0, half]) / length]
    signs = [1.0, -1.0]

    def frac(n, sign, om):
        t = om[:, 0] / om[:, 2]
        with np.errstate(divide="ignore"):
            v = np.minimum(1.0, w / (half + sign * d * t))
        return np.where((om @ n > 0) & (om[:, 2] > 0), v, 0.0)

    if tangents is None:
        tangents = default_face_tangents(np.array(normals))
    num = np.zeros((len(wi), 3))
    den = np.zeros(len(wi))
    mat = np.full(len(wi), material, np.int32)
    for n, sign, t in zip(normals, signs, tangents):
        vi, vo = frac(n, sign, wi), frac(n, sign, wo)
        fc = brdf_cosine_weighted(kinds, params, mat, np.broadcast_to(n, wi.shape), wi, wo,
                                  np.broadcast_to(np.asarray(t, np.float64), wi.shape))
        num += fc * np.asarray(color) * np.minimum(vi, vo)[:, None] * length
        den += np.maximum(wo @ n, 0.0) * vo * length
    out = np.zeros_like(num)
    ok = den > 0
    out[ok] = num[ok] / den[ok, None]
    return out


# ----------------------------------------------------------------------------------------------
# The SG bake (Iwasaki §4–5): normal bins, BVNDF histogram, spherical EM statistics, amplitudes
# ----------------------------------------------------------------------------------------------


def bvndf_histogram(facets: dict, vis: np.ndarray, bins: np.ndarray, weight: np.ndarray, pair_i, pair_o):
    """(P, L) N[p, l] = Σ_{s in bin l} V_s(ωi)V_s(ωo)·weight_s (Iwasaki §5; Wu Eq. 11).

    `bins` (Ns,) is each facet's index into the L non-empty bins; `weight` (Ns,) is ΔA_s times the
    facet's colour channel (zero for facets of other materials). No cosines: this is γ itself.
    """
    n_bins = int(bins.max()) + 1
    out = np.zeros((len(pair_i), n_bins))
    for p, (i, o) in enumerate(zip(pair_i, pair_o)):
        both = vis[i] & vis[o]
        out[p] = np.bincount(bins[both], weights=weight[both], minlength=n_bins)
    return out


def ndf_statistics(normal: np.ndarray, area: np.ndarray, axes, sharpness, log_weight) -> np.ndarray:
    """One spherical-EM E-step's sufficient statistics (Han 2007; Banerjee 2005), (J, 4):

    [Σ_s r_sj ΔA_s, Σ_s r_sj ΔA_s n_s] with responsibilities r_sj ∝ exp(log_weight_j − η_j(1 − ξ_j·n_s))
    (log_weight_j = log α_j + log of the von Mises–Fisher normalisation η_j / (2π(1 − e^{−2η_j}))).
    """

    normal = np.asarray(normal, np.float64)
    logp = np.asarray(log_weight, np.float64)[None, :] - np.asarray(sharpness, np.float64)[None, :] * one_minus_cos(
        normal[:, None, :], np.asarray(axes, np.float64)[None, :, :])
    logp -= logp.max(axis=1, keepdims=True)
    r = np.exp(logp)
    r /= r.sum(axis=1, keepdims=True)
    r *= np.asarray(area, np.float64)[:, None]
    return np.concatenate([r.sum(axis=0)[:, None], r.T @ normal], axis=1)


def visible_weights(facets: dict, vis: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(Ns,) the EM weight of each facet: ΔA_s · mean_k V_s(ω_k)(n_s·ω_k)⁺, its projected area averaged
    over the direction grid. The bake fits its lobes to the NDF weighted so (what some grid
    direction sees of it) rather than to the bare NDF: lobes spent on normals that no direction
    sees (the closed undersides of woven threads: 45 % of the woven tile's area at K = 12) are wasted."""
    cos = np.maximum(np.asarray(directions, np.float64) @ facets["normal"].T, 0.0)  # (D, Ns)
    return facets["area"] * (vis * cos).mean(axis=0)


def ndf_em(normal: np.ndarray, area: np.ndarray, axes, sharpness, weight, iterations: int):
    """Spherical EM in float64 (Backend.ndf_em): from lobes (axes, sharpness, weight), at most
    `iterations` steps of `ndf_statistics` + `lobes.m_step`, stopping after the first step that
    `lobes.converged`. → (axes (J, 3), sharpness (J,), weight (J,), steps); dead lobes keep weight 0."""

    lob = lobes.LobeSet(axes, sharpness, weight)
    for _ in range(int(iterations)):
        new = lobes.m_step(ndf_statistics(normal, area, lob.axes, lob.sharpness, lob.log_weight), lob)
        done = lobes.converged(new, lob)
        lob = new
        if done:
            break
    return lob.axes, lob.sharpness, lob.weight, lob.iterations


def lobe_values(normal, axes, sharpness) -> np.ndarray:
    """(Ns, J) G_j(n_s) = exp(−η_j(1 − ξ_j·n_s)), unit amplitude."""

    return np.exp(-np.asarray(sharpness, np.float64)[None, :] * one_minus_cos(
        np.asarray(normal, np.float64)[:, None, :], np.asarray(axes, np.float64)[None, :, :]))


def lobe_moments(facets: dict, vis: np.ndarray, directions, weight, axes, sharpness, pair_i, pair_o) -> np.ndarray:
    """(P, J + 1) the exact facet sums of docs/design.md §5, before the division by a_v(ωo):

    [Σ_s P_si P_so w_s G_j(n_s) for each lobe j,  Σ_s P_si P_so w_s],  P_sk = V_s(ω_k)(n_s·ω_k)⁺,
    w_s = `weight` (ΔA_s times a colour channel). Symmetric in (i, o). Divided by a_v(ωo) they are
    b_kj = ∫γ̃ G_j and c_k = ∫γ̃ for the pair k.
    """
    directions = np.asarray(directions, np.float64)
    n = facets["normal"]
    proj = vis * np.maximum(directions @ n.T, 0.0)  # (D, Ns)
    g = lobe_values(n, axes, sharpness) * np.asarray(weight, np.float64)[:, None]
    g = np.concatenate([g, np.asarray(weight, np.float64)[:, None]], axis=1)
    return np.stack([(proj[i] * proj[o]) @ g for i, o in zip(pair_i, pair_o)])


def histogram_moments(hist: np.ndarray, bin_normal, directions, axes, sharpness, pair_i, pair_o) -> np.ndarray:
    """(P, J + 1) the same sums as `lobe_moments` from the binned histogram (the histogram route):

    every facet of bin l is taken at the bin's mean normal n_l: Σ_l N[p, l](n_l·ωi)⁺(n_l·ωo)⁺[G_j(n_l), 1].
    `hist` (P, L) is `bvndf_histogram` for the same pairs.
    """
    directions = np.asarray(directions, np.float64)
    bn = np.asarray(bin_normal, np.float64)
    cos = np.maximum(directions @ bn.T, 0.0)  # (D, L)
    g = np.concatenate([lobe_values(bn, axes, sharpness), np.ones((len(bn), 1))], axis=1)
    return np.stack([(np.asarray(hist[p], np.float64) * cos[i] * cos[o]) @ g
                     for p, (i, o) in enumerate(zip(pair_i, pair_o))])


def solve_amplitudes(moments: np.ndarray, a_v: np.ndarray, pair_o, solve_rows: np.ndarray, integrals: np.ndarray):
    """(P, J) amplitudes μ ≥ 0 for each (ordered) pair; `moments` (P, J + 1) from `lobe_moments`.

    With b = moments[:J]/a_v(ωo) and c = moments[J]/a_v(ωo) (= ∫γ̃): μ = `solve_rows` @ b, Iwasaki's
    least-squares amplitudes (`lobes.amplitude_system` builds the rows: A⁻¹, calibrated per lobe);
    negative amplitudes are set to 0, and μ is scaled so that Σ_j μ_j ∫G_j = ∫γ̃ = c exactly, which
    keeps the diffuse part of f̄ (Eq. 9) exact and f̄ never negative. If every amplitude is 0 but
    c > 0, the lobe with the largest b_j takes all of c.
    """
    solve_rows = np.asarray(solve_rows, np.float64)
    integrals = np.asarray(integrals, np.float64)
    j = len(integrals)
    out = np.zeros((len(moments), j))
    for p, (m, o) in enumerate(zip(np.asarray(moments, np.float64), pair_o)):
        if a_v[o] <= 0 or m[j] <= 0:
            continue
        b, c = m[:j] / a_v[o], m[j] / a_v[o]
        mu = np.maximum(solve_rows @ b, 0.0)
        total = mu @ integrals
        if total > 0:
            mu *= c / total
        else:
            best = int(np.argmax(b))
            mu[best] = c / integrals[best]
        out[p] = mu
    return out


def amplitude_tables(channels, integrals):
    """A material's tables from its channels [(μ (P, J), rgb (3,))]: → (amps (P, J, 3), energy (P, 3)),
    amps = Σ_channels max(μ, 0)·rgb and energy = Σ_channels (max(μ, 0) @ ∫G)·rgb, in float64. A pair
    with a non-finite μ gets a NaN energy (its amps are then unspecified)."""
    integrals = np.asarray(integrals, np.float64)
    amps, energy = 0.0, 0.0
    for mu, rgb in channels:
        mu = np.asarray(mu, np.float64)
        rgb = np.asarray(rgb, np.float64)
        bad = ~np.isfinite(mu).all(axis=1)
        mu = np.maximum(np.where(bad[:, None], 0.0, mu), 0.0)
        amps = amps + mu[..., None] * rgb
        energy = energy + np.where(bad, np.nan, mu @ integrals)[:, None] * rgb
    return amps, energy

def energy_levels(energy, k: int, etas) -> np.ndarray:
    """Materials' energies (M, K², K², 3) prefiltered over ωi for broad environment lobes → (M, L, K², K², 3),
    L = len(etas): level 0 the energy itself, level l ≥ 1 (η = etas[l]) at (ξ, ωo) the mean of E/cos θ
    under the SG G(·; ξ, η) over the K×K grid's equal-area cells, times cos θξ:
    Σ_g G(ω_g; ξ, η)·E(ω_g, ωo) / Σ_g G(ω_g; ξ, η)·cos θ_g · cos θξ, in float64
    (effective.EffectiveBRDF.energy_levels)."""
    g = direction_grid(k)
    energy = np.asarray(energy, np.float64)
    m, k2 = energy.shape[0], len(g)
    out = [energy]
    for eta in etas[1:]:
        w = np.exp(eta * (g @ g.T - 1.0))  # (ξ, ω_g)
        w = w * (g[:, 2] / (w @ g[:, 2]))[:, None]
        out.append(np.einsum("xg,mgoc->mxoc", w, energy.reshape(m, k2, k2, 3)))
    return np.stack(out, axis=1)


# ==============================================================================================
# SSDF visibility of the large-scale mesh (Wang 2009 §5; warp_biscale.ssdf).
#
# θd over an octahedral S×S grid of world directions: the exact angle to the nearest texel
# direction of the opposite class, less half the texel's nearest-neighbour angle, signed by the
# texel's class (+ visible, − occluded); ±π when every texel has one class. Evaluated at arbitrary
# directions by bilinear lookup of each PCA basis image (edge mirroring ignored, see ssdf).
# ==============================================================================================


def ssdf_distance(visible, directions, half_angle) -> np.ndarray:
    """(V, N) float64 θd (rad) of (V, N) bool visibility over N unit `directions` (N, 3), with
    `half_angle` (N,) h_k: θd = ±(min angle to an opposite-class direction − h_k), ±π if none.
    Brute force over all N² direction pairs; angles by atan2(|a×b|, a·b) (accurate near 0)."""
    visible = np.asarray(visible, bool)
    d = np.asarray(directions, np.float64)
    h = np.asarray(half_angle, np.float64)
    angle = np.arctan2(np.linalg.norm(np.cross(d[:, None, :], d[None, :, :]), axis=-1), d @ d.T)  # (N, N)
    out = np.empty(visible.shape)
    for v, row in enumerate(visible):
        opposite = row[:, None] != row[None, :]
        a = np.where(opposite, angle, np.inf).min(axis=1)
        sign = np.where(row, 1.0, -1.0)
        out[v] = np.where(np.isinf(a), sign * np.pi, sign * (a - h))
    return out


# ==============================================================================================
# Ray casting against the large-scale mesh (stage `trace`: kernels/trace.py, cl/trace.cl)
#
# Brute force over every triangle, float64 Möller–Trumbore, double-sided. Barycentric (u, v) are
# the weights of a face's vertices 1 and 2 (vertex 0 gets 1 − u − v); a hit position is the
# barycentric combination of the vertices. Rays are processed in chunks so that a chunk's
# (rays × triangles) arrays stay near 2^18 entries: 10^5 rays × 10^3 triangles take seconds.
# `tol` > 0 grows every triangle by tol in barycentric units (tol < 0 shrinks it): the tests use
# the pair ±tol to tell rays that graze an edge within float32 rounding from clear hits and misses.
# ==============================================================================================

__all__ += ["intersect_faces", "trace_closest", "trace_occluded", "trace_shadows", "trace_primary",
            "trace_occlusion", "trace_lobe_rays"]

_TRACE_BLOCK = 1 << 18  # rays × triangles per chunk (2^18: fastest here, the blocks stay in cache)


def _ray_triangle(o, d, a, e1, e2):
    """Möller–Trumbore on broadcast operands (xyz in the last axis): → (u, v, t, ok), ok where det ≠ 0.
    Written per component: on (rays, triangles) blocks it is 3× faster than np.cross and einsum."""
    ox, oy, oz = (o[..., k] for k in range(3))
    dx, dy, dz = (d[..., k] for k in range(3))
    e1x, e1y, e1z = (e1[..., k] for k in range(3))
    e2x, e2y, e2z = (e2[..., k] for k in range(3))
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = px * e1x + py * e1y + pz * e1z
    ok = det != 0
    inv = 1.0 / np.where(ok, det, 1.0)
    tx, ty, tz = ox - a[..., 0], oy - a[..., 1], oz - a[..., 2]
    u = (tx * px + ty * py + tz * pz) * inv
    qx, qy, qz = ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return u, v, t, ok


def _triangles(vertices, faces):
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    a = v[f[:, 0]]
    return a, v[f[:, 1]] - a, v[f[:, 2]] - a


def _chunks(n_rays, n_tris):
    step = max(1, _TRACE_BLOCK // max(n_tris, 1))
    for lo in range(0, n_rays, step):
        yield slice(lo, min(lo + step, n_rays))


def intersect_faces(vertices, faces, face, origins, directions):
    """Ray i against face[i] only (its plane, no inside test): → (u, v, t) float64 (R,), NaN where
    the ray is parallel to the face. For judging one particular hit (e.g. a kernel's)."""
    a, e1, e2 = _triangles(vertices, faces)
    face = np.asarray(face, np.int64)
    u, v, t, ok = _ray_triangle(np.asarray(origins, np.float64), np.asarray(directions, np.float64),
                                a[face], e1[face], e2[face])
    return np.where(ok, u, np.nan), np.where(ok, v, np.nan), np.where(ok, t, np.nan)


def _inside(u, v, t, ok, t_lo, t_hi, tol):
    return ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t > t_lo) & (t <= t_hi)


def trace_closest(vertices, faces, origins, directions, t_min=0.0, t_max=np.inf, tol=0.0):
    """Closest hit with t in (t_min, t_max]: → face (R,) int32 (−1 = miss), u, v, t (R,) float64
    (t = inf on a miss). Equal t (a ray through a shared edge) resolves to the lower face index."""
    a, e1, e2 = _triangles(vertices, faces)
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    r = len(o)
    t_lo = np.broadcast_to(np.asarray(t_min, np.float64), (r,))
    t_hi = np.broadcast_to(np.asarray(t_max, np.float64), (r,))
    face = np.full(r, -1, np.int32)
    uu, vv, tt = np.zeros(r), np.zeros(r), np.full(r, np.inf)
    for s in _chunks(r, len(a)):
        u, v, t, ok = _ray_triangle(o[s, None], d[s, None], a[None], e1[None], e2[None])
        hit = _inside(u, v, t, ok, t_lo[s, None], t_hi[s, None], tol)
        t = np.where(hit, t, np.inf)
        best = np.argmin(t, axis=1)
        rows = np.arange(len(best))
        found = np.isfinite(t[rows, best])
        face[s] = np.where(found, best, -1)
        uu[s] = np.where(found, u[rows, best], 0.0)
        vv[s] = np.where(found, v[rows, best], 0.0)
        tt[s] = t[rows, best]
    return face, uu, vv, tt


def trace_occluded(vertices, faces, origins, directions, t_min, t_max, tol=0.0) -> np.ndarray:
    """(R,) bool: any triangle hit with t in (t_min, t_max] (t_min, t_max scalars or (R,); inf allowed).
    The caller moves origins off their surfaces."""
    a, e1, e2 = _triangles(vertices, faces)
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    r = len(o)
    t_lo = np.broadcast_to(np.asarray(t_min, np.float64), (r,))
    t_hi = np.broadcast_to(np.asarray(t_max, np.float64), (r,))
    out = np.zeros(r, bool)
    for s in _chunks(r, len(a)):
        u, v, t, ok = _ray_triangle(o[s, None], d[s, None], a[None], e1[None], e2[None])
        out[s] = _inside(u, v, t, ok, t_lo[s, None], t_hi[s, None], tol).any(axis=1)
    return out


def trace_primary(mesh, camera) -> dict:
    """The G-buffer of `camera` (Camera.rays, float64): face, bary (u, v), position, t, as the
    backends' trace_primary returns them (misses: face −1, bary and position 0, t inf)."""
    o, d = camera.rays()
    face, u, v, t = trace_closest(mesh.vertices, mesh.faces, o, d)
    tri = mesh.vertices[mesh.faces[np.maximum(face, 0)]]
    pos = (1 - u - v)[:, None] * tri[:, 0] + u[:, None] * tri[:, 1] + v[:, None] * tri[:, 2]
    pos[face < 0] = 0.0
    return {"face": face, "bary": np.stack([u, v], 1), "position": pos, "t": t, "eye": camera.eye.copy()}


def trace_shadows(vertices, normals, faces, face, bary, position, eye, lights_packed, eps, t_min, tol=0.0,
                  samples=1, part=(0, 1)) -> np.ndarray:
    """(P, L) uint8, the share of light k visible from hit pixel p in 255ths (trace.VISIBLE = 255: all).

    `samples`: S rays a pixel for every light, or one count a light (trace.light_samples). Each shadow ray
    starts at trace.ray_starts' origin (the hit lifted towards the smooth surface of the vertex `normals`,
    then eps along the geometric normal turned to the side of `eye`). Ray i of light k's S aims at disc point
    q = trace.above_horizon(trace.disk_sample(i, S, p), d) in the frame (a, b, d) = trace.horizon_frame(w, ns, ·): the
    part of the disc above the horizon of the shading normal ns.
    Directional light (row[0] = 0): w = row[1:4] normalised, direction w + tan(α)(q_x a + q_y b),
    α = √(row[7]/π) its angular radius, unbounded. Point light (row[0] = 1): w towards the centre c = row[1:4]
    from the origin, ray towards c + r(q_x a + q_y b) (r = row[7]) up to eps short of it. A ray counts if it
    is above the horizon of the shading normal (ray_starts' ns, which may see a light the face's plane hides)
    and hits no triangle with t in (t_min, t_max]; the entry is (count·255 + ⌊S'/2⌋) // S', S' the rays cast.
    0 for a missed pixel (face −1). With `part` (index, count[, block_width]) only the rays i of
    trace.pixel_parts(S, part, p) are cast, turned by its turn pixel, and S' is their number.
    """
    face = np.asarray(face, np.int64)
    lights = np.asarray(lights_packed, np.float64).reshape(-1, 8)
    counts_per_light = light_samples(samples, len(lights))
    out = np.zeros((len(face), len(lights)), np.uint8)
    hit = np.flatnonzero(face >= 0)
    if len(hit) == 0 or len(lights) == 0:
        return out
    start = ray_starts(vertices, normals, faces, face[hit], np.asarray(bary, np.float64).reshape(-1, 2)[hit],
                       np.asarray(position, np.float64).reshape(-1, 3)[hit], eye, eps)
    for k, n in enumerate(counts_per_light):
        counts = np.zeros(len(hit), np.int64)
        cast = part_rays(n, part, hit)  # (H, S)
        turn = pixel_parts(n, part, hit)[2]
        for i in np.flatnonzero(cast.any(0)):
            counts += _shadow_rays(vertices, faces, start, lights[k:k + 1], eps, t_min, tol, turn, i, n)[:, 0] \
                & cast[:, i]
        traced = cast.sum(1)
        out[hit, k] = ((counts * 255 + traced // 2) // traced).astype(np.uint8)
    return out


def trace_occlusion(vertices, normals, faces, face, bary, position, eye, eps, t_min, samples: int,
                    tol=0.0, part=(0, 1)) -> np.ndarray:
    """(P,) uint32 environment-occlusion masks: bit i set where ray i of `samples` from hit pixel p hits a
    triangle with t in (t_min, inf). The rays start at trace.ray_starts' origin and go along
    trace.occlusion_directions(ng, samples, p), ng its geometric normal turned to the eye. 0 for a missed
    pixel (face −1) and for samples = 0. With `part` (index, count[, block_width]) only the rays of
    trace.pixel_parts are cast, turned by the pixel's turn pixel; the others' bits stay clear."""
    face = np.asarray(face, np.int64)
    out = np.zeros(len(face), np.uint32)
    hit = np.flatnonzero(face >= 0)
    if len(hit) == 0 or samples == 0:
        return out
    start = ray_starts(vertices, normals, faces, face[hit], np.asarray(bary, np.float64).reshape(-1, 2)[hit],
                       np.asarray(position, np.float64).reshape(-1, 3)[hit], eye, eps)
    d = occlusion_directions(start["ng"], samples, pixel_parts(samples, part, hit)[2])  # (H, S, 3)
    cast = part_rays(samples, part, hit)
    rows, cols = np.nonzero(cast)
    blocked = np.zeros(cast.shape, bool)
    blocked[rows, cols] = trace_occluded(vertices, faces, start["origin"][rows], d[rows, cols], t_min, np.inf, tol)
    out[hit] = (blocked.astype(np.uint64) << np.arange(samples, dtype=np.uint64)).sum(1).astype(np.uint32)
    return out


def trace_lobe_rays(vertices, normals, faces, face, bary, position, eye, eps, t_min, lobes, tol=0.0,
                    part=(0, 1)) -> np.ndarray:
    """(P,) uint32 lobe masks: bit k·LOBE_RAYS + i set where ray i towards sharp lobe k of `lobes` (M, 4)
    [axis, η] (trace.lobe_ray_directions) from hit pixel p hits a triangle with t in (t_min, inf). The rays
    start as trace_occlusion's; one below the shading normal's horizon (ray_starts' ns) is not traced (bit
    clear), nor one outside trace.pixel_parts(LOBE_RAYS, part, p). 0 for a missed pixel and for no lobes."""
    face = np.asarray(face, np.int64)
    out = np.zeros(len(face), np.uint32)
    lobes = np.asarray(lobes, np.float64).reshape(-1, 4)
    hit = np.flatnonzero(face >= 0)
    if len(hit) == 0 or len(lobes) == 0:
        return out
    start = ray_starts(vertices, normals, faces, face[hit], np.asarray(bary, np.float64).reshape(-1, 2)[hit],
                       np.asarray(position, np.float64).reshape(-1, 3)[hit], eye, eps)
    o, n = start["origin"], start["ns"]
    bits = np.zeros(len(hit), np.uint64)
    for k, lobe in enumerate(lobes):
        d, _ = lobe_ray_directions(np.broadcast_to(lobe[:3], (len(hit), 3)), np.full(len(hit), lobe[3]),
                                   pixel_parts(LOBE_RAYS, part, hit)[2])
        up = (np.einsum("prk,pk->pr", d, n) > 0) & part_rays(LOBE_RAYS, part, hit)
        blocked = np.zeros(up.shape, bool)
        rows, cols = np.nonzero(up)
        blocked[rows, cols] = trace_occluded(vertices, faces, o[rows], d[rows, cols], t_min, np.inf, tol)
        shift = np.arange(k * LOBE_RAYS, (k + 1) * LOBE_RAYS, dtype=np.uint64)
        bits |= (blocked.astype(np.uint64) << shift).sum(1).astype(np.uint64)
    out[hit] = bits.astype(np.uint32)
    return out


def _shadow_rays(v, f, start, lights, eps, t_min, tol, turn, i, samples) -> np.ndarray:
    """(len(turn), L) bool: ray i of `samples` of trace_shadows unoccluded, per hit pixel and light, from the
    ray starts `start` (trace.ray_starts of the hit pixels), turned by pixels `turn` (trace.pixel_parts)."""
    o, n = start["origin"], start["ns"]
    out = np.zeros((len(turn), len(lights)), bool)
    q0 = disk_sample(i, samples, turn)
    for k, row in enumerate(lights):
        if row[0] == 0:
            w = np.broadcast_to(row[1:4] / np.linalg.norm(row[1:4]), o.shape)
            spread = np.tan(np.sqrt(row[7] / np.pi))
            a, b, chord = horizon_frame(w, n, spread)
            q = above_horizon(q0, chord)
            d = w + spread * (q[:, :1] * a + q[:, 1:] * b)
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
            t_max = np.full(len(o), np.inf)
        else:
            w = row[1:4][None] - o
            dist = np.maximum(np.linalg.norm(w, axis=1), 1e-300)
            w = w / dist[:, None]
            a, b, chord = horizon_frame(w, n, row[7] / dist)
            q = above_horizon(q0, chord)
            d = row[1:4][None] + row[7] * (q[:, :1] * a + q[:, 1:] * b) - o
            dist = np.linalg.norm(d, axis=1)
            d = d / np.maximum(dist, 1e-300)[:, None]
            t_max = dist - eps
        up = np.sum(n * d, axis=1) > 0
        vis = up.copy()
        if up.any():
            vis[up] = ~trace_occluded(v, f, o[up], d[up], t_min, t_max[up], tol)
        out[:, k] = vis
    return out


def share_block_masks(mask, lenders, samples: int, part) -> tuple[np.ndarray, np.ndarray]:
    """(shared, known), each (P,) uint32 (the kernels' share_block_masks): per hit pixel p, the union of the ray
    masks `mask` (P,) (occlusion or lobe rays, a set of `samples`) of the pixels of its block (trace.block_side's
    side for this set) that lend it their rays (`lenders` (P, s²) of the part's side s, trace.share_block), and the
    bits of the rays they traced (trace.pixel_parts). A set of fewer than trace.BLOCK_SLOTS rays is not shared: the
    pixel's own; a 4×4 part shares a set of fewer than 16·count rays in 2×2 blocks. 0 for a miss (a row of
    `lenders` all False)."""
    width = check_ray_part(part)[2]
    side = block_side(samples, part)
    mask = np.asarray(mask, np.uint32)
    p = np.arange(len(mask))
    bit = np.uint64(1) << np.arange(samples, dtype=np.uint64)
    if side == 1:
        hit = lenders.any(1)
        bits = (part_rays(samples, part, p).astype(np.uint64) * bit).sum(1, dtype=np.uint64)
        return np.where(hit, mask, 0).astype(np.uint32), np.where(hit, bits, 0).astype(np.uint32)
    lenders = block_sub_lenders(lenders, width, side)
    shared = np.zeros(len(mask), np.uint64)
    known = np.zeros(len(mask), np.uint64)
    for q in range(side * side):
        take = lenders[:, q]
        b = np.where(take, block_pixel(p, width, q, side), p)
        bits = (part_rays(samples, part, b).astype(np.uint64) * bit).sum(1, dtype=np.uint64)
        shared |= np.where(take, mask[b], 0).astype(np.uint64)
        known |= np.where(take, bits, np.uint64(0))
    return shared.astype(np.uint32), known.astype(np.uint32)


def share_block_shadows(visible, lenders, samples, part) -> np.ndarray:
    """(P, L) uint8 (the kernels' share_block_shadows): per hit pixel, each light's visible share `visible`
    (P, L) over the shadow rays its block's lenders traced (the light's block side, trace.block_side; `lenders`
    (P, s²) of the part's side s, trace.share_block), (Σ traced·v + ⌊Σ traced/2⌋) // Σ traced in 255ths; the
    pixel's own for a light of fewer than trace.BLOCK_SLOTS rays (`samples`: one count for every light, or one a
    light) and for a miss."""
    visible = np.asarray(visible, np.uint8)
    width = check_ray_part(part)[2]
    p = np.arange(len(visible))
    out = visible.copy()
    for k, n in enumerate(light_samples(samples, visible.shape[1])):
        side = block_side(int(n), part)
        if side == 1:
            continue
        light_lenders = block_sub_lenders(lenders, width, side)
        num = np.zeros(len(p), np.int64)
        den = np.zeros(len(p), np.int64)
        for q in range(side * side):
            b = np.where(light_lenders[:, q], block_pixel(p, width, q, side), p)
            traced = np.where(light_lenders[:, q], part_rays(n, part, b).sum(1), 0)
            num += traced * visible[b, k].astype(np.int64)
            den += traced
        on = den > 0
        out[on, k] = ((num[on] + den[on] // 2) // den[on]).astype(np.uint8)
    return out


# ----------------------------------------------------------------------------------------------
# Environment lighting (stage `envmap`; warp_biscale/lighting.py): the prefiltered
# environment Λ(p, η) of Wang Eq. 34–35, its packed-level lookup, and irradiance of an equirect
# map and of an SG mixture (the measures the diffuse SG fit is judged by).
# ----------------------------------------------------------------------------------------------

__all__ += ["lobe_average", "prefilter_level", "prefiltered_lookup", "environment_irradiance", "sg_irradiance"]


def lobe_average(radiance, p, sharpness) -> np.ndarray:
    """(N, 3) Λ(p, η) = Σ_t G(ω_t; p, η) L_t Ω_t / Σ_t G(ω_t; p, η) Ω_t for unit directions p (N, 3), by
    brute force over every texel t of the equirect map `radiance` (h, w, 3).

    G(ω; p, η) = exp(−η(1 − ω·p)); ω_t and Ω_t are the texel centres and exact solid angles of the
    environment.py convention. Σ_t G Ω_t estimates ∫G = 2π(1 − e^{−2η})/η; dividing by it rather than
    by the closed form makes a constant map exact and cancels most of the quadrature error of lobes
    a few texels wide.
    """

    rad = np.asarray(radiance, np.float64)
    d_in = equirect_directions(*rad.shape[:2]).reshape(-1, 3)
    omega = np.repeat(equirect_row_solid_angles(*rad.shape[:2]), rad.shape[1])
    flat = rad.reshape(-1, 3)
    p = np.asarray(p, np.float64).reshape(-1, 3)
    out = np.empty((len(p), 3))
    chunk = max(1, (1 << 22) // len(d_in))
    for a in range(0, len(p), chunk):
        u = one_minus_cos(p[a:a + chunk, None, :], d_in[None])
        # The ratio is unchanged by a common factor exp(η·min u): with it the nearest texel weighs 1, so
        # no lobe is too sharp (the limit η → ∞ is the nearest texel's radiance, ties averaged).
        g = np.exp(-float(sharpness) * (u - u.min(1, keepdims=True))) * omega[None]
        out[a:a + chunk] = (g @ flat) / g.sum(1)[:, None]
    return out


def prefilter_level(radiance, sharpness: float, height: int, width: int) -> np.ndarray:
    """(height, width, 3) `lobe_average` of `radiance` (h, w, 3) at the texel centres of a height×width
    equirect map: one level of the prefiltered environment (the envmap kernel's oracle; the kernel
    also drops texels with G < 1e−7, which this keeps)."""

    return lobe_average(radiance, equirect_directions(height, width).reshape(-1, 3), sharpness).reshape(
        height, width, 3)


