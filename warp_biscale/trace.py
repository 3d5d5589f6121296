"""Host side of the ray-casting stage (`kernels/trace.py`, `cl/trace.cl`): the offsets both backends
and the reference use, and the input checks the backends share, so that every backend rejects the
same bad input with the same message.

Offsets, relative to `Mesh.scale` (the larger of the extent and the largest coordinate magnitude):

- `T_MIN` = 1e-6: an any-hit ray counts hits with t in (t_min, t_max], t_min = T_MIN × scale,
  about ten float32 roundings of a coordinate: a ray whose origin sits a rounding error off a
  surface does not hit that surface at t ≈ 0.
- `SHADOW_OFFSET` = 1e-4: a shadow ray starts this far (× scale) off the hit point along the
  oriented geometric normal, and a point light's ray stops this far short of the light's centre.
  Far above float32 rounding, far below any modelled feature.

Soft shadows: a light's shadow rays go to `samples` points of its disc (a point light's sphere as
seen from the pixel, a directional light's cone), `disk_sample` turned by a per-pixel angle so that a
penumbra is fine noise rather than bands; one sample is the centre, the hard shadow. The result is the
visible share in 255ths (`VISIBLE`), rounded: what the shade stage scales each light by.

Environment occlusion: `samples` rays (at most `OCCLUSION_SAMPLES_MAX`, one bit each) leave each hit
pixel over the hemisphere of its oriented geometric normal, cosine-distributed and stratified: the
same turned Vogel spiral lifted to the hemisphere (Malley's method, `occlusion_directions`). Bit i of
the pixel's mask is set where ray i hits the mesh (unbounded: the environment is at infinity); the
shade stage weighs the bits per lobe (`shading.ray_share`).

Sharp environment lobes' rays: for each of up to `LOBE_RAY_LOBES` sharp lobes (axis ξ, sharpness η) the
first of a frame's environment lobes (`shading.sharp_lobes_first`), `LOBE_RAYS` rays towards points of
the disc of tangent radius tan θ about ξ, 1 − cos θ = 2/η (`lobe_ray_directions`: the same turned
spiral); bit k·LOBE_RAYS + i of the pixel's lobe mask is set where ray i of lobe k is blocked. A ray
below the geometric horizon is not traced (its bit stays clear: the shading normal decides).
"""

from __future__ import annotations

import numpy as np

from .model import GBuffer
from .scene import Camera, Mesh, _integer

__all__ = ["T_MIN", "SHADOW_OFFSET", "CHUNK_RAYS", "offsets", "check_mesh", "check_camera", "check_rays",
           "check_lights", "check_gbuffer", "check_shadow_samples", "light_samples", "check_ray_part", "ray_part",
           "part_rays",
           "pixel_parts", "block_side", "block_pixel", "share_block", "block_sub_lenders", "BLOCK_SLOTS", "BLOCK_SIDES",
           "SHARE_NORMAL_COS", "SHARE_PLANE",
           "same_surface", "changed_pixels",
           "disk_sample", "disk_basis", "horizon_frame", "above_horizon", "VISIBLE",
           "SHADOW_SAMPLES_MAX", "OCCLUSION_SAMPLES_MAX", "check_occlusion_samples", "occlusion_directions",
           "oriented_face_normals", "ray_starts", "LOBE_RAYS", "LOBE_RAY_LOBES", "lobe_ray_directions", "check_lobes"]

T_MIN = 1e-6
SHADOW_OFFSET = 1e-4
CHUNK_RAYS = 1 << 22  # any-hit rays per launch: bounds device memory (~100 MB a chunk) for any ray count
VISIBLE = 255  # a light_vis entry of a fully visible light
BLOCK_SLOTS = 4  # the pixels of a 2×2 block: a set of at least this many rays is shared in blocks (pixel_parts)
BLOCK_SIDES = (2, 4)  # the sides of the square pixel blocks that may share a set of rays
SHADOW_SAMPLES_MAX = 1024
OCCLUSION_SAMPLES_MAX = 32  # one bit each of a pixel's uint32 mask
LOBE_RAYS = 8  # rays a sharp environment lobe and pixel ...
LOBE_RAY_LOBES = 2  # ... for at most this many lobes (LOBE_RAYS × this ≤ 32: one bit each of a uint32 mask)
LOBE_COS_MIN = 0.0872  # cos 85°: the widest disc a lobe's rays spread over (the tangent grows without bound)
GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def disk_sample(i, samples: int, pixel) -> np.ndarray:
    """(..., 2) float64 sample i of `samples` on the unit disc for pixel index `pixel` (arrays broadcast):
    a Vogel spiral, r = √((i + ½)/S), angle i·golden angle, turned by the pixel's hash angle
    2π·((pixel·2654435761 mod 2³²) >> 8)/2²⁴; the centre when samples = 1 (the kernels' twin)."""
    i, pixel = np.broadcast_arrays(np.asarray(i, np.int64), np.asarray(pixel, np.int64))
    if samples == 1:
        return np.zeros((*i.shape, 2))
    h = (pixel.astype(np.uint64) * np.uint64(2654435761)) & np.uint64(0xFFFFFFFF)
    turn = (h >> np.uint64(8)).astype(np.float64) * (2 * np.pi / 16777216.0)
    r = np.sqrt((i + 0.5) / samples)
    a = i * GOLDEN_ANGLE + turn
    return np.stack([r * np.cos(a), r * np.sin(a)], -1)


def disk_radii() -> np.ndarray:
    """(Σ_S S, 3) float32 rows (r, lift, 1/lift) of disk_sample's ray i of S — r = √((i + ½)/S), 0 for S = 1, and
    lift = √(1 − r²) its cosine to the normal (occlusion_directions) — for S = 1 … OCCLUSION_SAMPLES_MAX, the set
    of S from row S(S − 1)/2: the shade kernels read them rather than take two square roots and a division per ray
    and lobe."""
    rows = []
    for samples in range(1, OCCLUSION_SAMPLES_MAX + 1):
        r2 = np.zeros(1) if samples == 1 else (np.arange(samples) + 0.5) / samples
        lift = np.sqrt(1.0 - r2)
        rows.append(np.stack([np.sqrt(r2), lift, 1.0 / np.maximum(lift, 1e-6)], -1))
    out = np.concatenate(rows).astype(np.float32)
    out.flags.writeable = False  # one array for every shade upload (device._shade_input holds it by identity)
    return out


DISK_RADII = disk_radii()


def horizon_frame(w, n, apparent) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, d), (..., 3), (..., 3), (...,): the frame a light's shadow rays spread over its disc in (the kernels'
    `horizon_frame`), for disc axes w (..., 3) (unit, towards the light), shading normals n and the disc's
    radius over its distance `apparent` (tan of a directional light's angular radius). Where the horizon of n cuts
    the disc, a is n's part across the disc, normalised, b = w × a, and d = (n·w)/(apparent·|n − (n·w)w|) in
    (−1, 1): a ray to disc point q is above the horizon where q_x > −d. Elsewhere (a, b) = disk_basis(w) and d = 2."""
    w, n = np.asarray(w, np.float64), np.asarray(n, np.float64)
    apparent = np.asarray(apparent, np.float64)
    wn = np.sum(w * n, -1)
    across = n - wn[..., None] * w
    length = np.linalg.norm(across, axis=-1)
    cut = apparent * length > np.abs(wn)
    a0, b0 = disk_basis(w)
    a = np.where(cut[..., None], across / np.where(cut, length, 1.0)[..., None], a0)
    b = np.where(cut[..., None], np.cross(w, a), b0)
    return a, b, np.where(cut, wn / np.where(cut, apparent * length, 1.0), 2.0)


def above_horizon(q, d) -> np.ndarray:
    """Disc points q (..., 2) moved into the part of the disc above the horizon, q_x > −d (`horizon_frame`; the
    kernels' `above_horizon`): where |d| < 1 the coordinate q_x is squeezed linearly from [−1, 1] onto [−d, 1] and
    q_y scaled with the chord there. Every ray then aims at the part of the light that the cosine integral counts
    (rays over the whole disc, those below counted as blocked, counted the horizon twice). Elsewhere q is kept (a
    disc wholly below lights nothing)."""
    q, d = np.asarray(q, np.float64), np.asarray(d, np.float64)
    s, t = q[..., 0], q[..., 1]
    s2 = -d + 0.5 * (s + 1.0) * (1.0 + d)
    t2 = t * np.sqrt(np.maximum(1.0 - s2 * s2, 0.0) / np.maximum(1.0 - s * s, 1e-12))
    return np.where((np.abs(d) < 1)[..., None], np.stack([s2, t2], -1), q)


def disk_basis(w) -> tuple[np.ndarray, np.ndarray]:
    """(a, b), each (..., 3): with w (..., 3) unit, the right-handed frame (a, b, w) the kernels build
    (a = normalize(w × x̂), or w × ŷ where |w_x| ≥ 0.9; b = w × a)."""
    w = np.asarray(w, np.float64)
    ref = np.where((np.abs(w[..., 0]) < 0.9)[..., None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    a = np.cross(w, ref)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    return a, np.cross(w, a)


def occlusion_directions(normal, samples: int, pixel) -> np.ndarray:
    """(..., samples, 3) float64: the environment-occlusion ray directions of pixels `pixel` (...,) whose
    oriented geometric normals are `normal` (..., 3): disc sample q_i = disk_sample(i, samples, pixel)
    lifted to q_x·a + q_y·b + √(1 − |q|²)·n in disk_basis(n), cosine-distributed over n's hemisphere
    (the kernels' twin)."""
    n = np.asarray(normal, np.float64)
    a, b = disk_basis(n)
    q = disk_sample(np.arange(samples)[None], samples, np.asarray(pixel)[..., None])  # (..., S, 2)
    lift = np.sqrt(np.maximum(1.0 - np.sum(q * q, -1), 0.0))
    return q[..., :1] * a[..., None, :] + q[..., 1:] * b[..., None, :] + lift[..., None] * n[..., None, :]


def oriented_face_normals(vertices, faces, face, position, eye) -> np.ndarray:
    """(R, 3) float64 unit geometric normals of faces `face` (R,), each turned to the side of `eye` seen
    from its point `position` (R, 3): the normal shadow and occlusion rays leave along."""
    n = _unit_face_normals(np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)[np.asarray(face, np.int64)]])
    x = np.asarray(position, np.float64).reshape(-1, 3)
    return np.where((np.sum(n * (np.asarray(eye, np.float64) - x), axis=1) < 0)[:, None], -n, n)


def _unit_face_normals(tri) -> np.ndarray:
    """(R, 3) unit normals of triangles tri (R, 3 vertices, 3), by their winding; 0 for a degenerate one."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)


def ray_starts(vertices, normals, faces, face, bary, position, eye, eps) -> dict:
    """Where the shadow, occlusion and lobe rays of hit pixels leave from, float64 (the kernels' `ray_start`):
    face (R,), bary (R, 2) and position (R, 3) of the hits, eye (3,), eps the offset (`offsets`).

    → dict ng (R, 3): the unit geometric normal turned to the eye's side (`oriented_face_normals`); ns: the
    interpolated vertex normal, turned to ng's side; origin: the hit moved onto the curved surface that the vertex
    normals describe, then eps along ng.

    The move is Hanika's ("Hacking the shadow terminator", Ray Tracing Gems II, 2021): for each vertex k of
    the face, the hit's offset from it loses its part below k's tangent plane, d_k = min(0, (x − p_k)·n_k);
    the origin is x − Σ_k w_k d_k n_k (w_k the barycentric weights). On a convex patch that lifts x off the
    flat triangle towards the smooth surface, so a light that the shading normal sees but the face's plane
    hides is reached by a ray that clears the neighbouring faces instead of the face itself; where the
    surface is flat or concave it leaves x where it is."""
    v = np.asarray(vertices, np.float64)
    tri = np.asarray(faces, np.int64)[np.asarray(face, np.int64)]
    x = np.asarray(position, np.float64).reshape(-1, 3)
    ng = _unit_face_normals(v[tri])
    ng = np.where((np.sum(ng * (np.asarray(eye, np.float64) - x), axis=1) < 0)[:, None], -ng, ng)
    u, w = np.asarray(bary, np.float64)[:, 0], np.asarray(bary, np.float64)[:, 1]
    weights = np.stack([1.0 - u - w, u, w], 1)  # (R, 3)
    nk = np.asarray(normals, np.float64)[tri]  # (R, 3, 3)
    # turned to the eye's side of the face with their blend (not with the winding, which may be the other way)
    side = np.where(np.einsum("rk,rkc,rc->r", weights, nk, ng) < 0, -1.0, 1.0)
    nk = side[:, None, None] * nk
    d = np.minimum(np.einsum("rkc,rkc->rk", x[:, None] - v[tri], nk), 0.0)
    lifted = x - np.einsum("rk,rk,rkc->rc", weights, d, nk)
    ns = np.einsum("rk,rkc->rc", weights, nk)
    ns = ns / np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-300)
    return {"ng": ng, "ns": ns, "origin": lifted + eps * ng}


def lobe_ray_directions(axis, eta, pixel) -> tuple[np.ndarray, np.ndarray]:
    """(directions (..., LOBE_RAYS, 3), solid-angle weights (..., LOBE_RAYS)) float64 of the rays of pixels
    `pixel` (...,) towards a lobe of unit axis `axis` (..., 3) and sharpness `eta` (...,): disc sample q_i =
    disk_sample(i, LOBE_RAYS, pixel) on the tangent plane at the axis, radius tan θ (1 − cos θ = 2/η, θ at
    most 85°), direction normalize(ξ + tan θ·(q_x a + q_y b)) in disk_basis(ξ); the weight cos³ of its angle
    from the axis undoes the plane's crowding of directions towards the rim (the kernels' twin)."""
    axis = np.asarray(axis, np.float64)
    c = np.maximum(1.0 - 2.0 / np.maximum(np.asarray(eta, np.float64), 1e-30), LOBE_COS_MIN)
    spread = np.sqrt(1.0 - c * c) / c
    a, b = disk_basis(axis)
    q = disk_sample(np.arange(LOBE_RAYS)[None], LOBE_RAYS, np.asarray(pixel)[..., None])  # (..., R, 2)
    off = spread[..., None, None] * (q[..., :1] * a[..., None, :] + q[..., 1:] * b[..., None, :])
    d = axis[..., None, :] + off
    length = np.linalg.norm(d, axis=-1)
    return d / length[..., None], length ** -3.0


def check_lobes(lobes) -> np.ndarray:
    """→ (M, 4) float32 [unit axis, η] rows of sharp environment lobes for lobe rays, M ≤ LOBE_RAY_LOBES."""
    a = _array("lobes", lobes).reshape(-1, 4) if np.size(lobes) else np.zeros((0, 4))
    if len(a) > LOBE_RAY_LOBES:
        raise ValueError(f"lobes: at most {LOBE_RAY_LOBES} lobes get lobe rays, got {len(a)}")
    if not np.isfinite(a).all() or (a[:, 3] <= 0).any():
        raise ValueError("lobes must be finite [axis, sharpness > 0] rows")
    if len(a) and np.abs(np.linalg.norm(a[:, :3], axis=1) - 1).max() > 1e-3:
        raise ValueError("lobes' axes must be unit vectors")
    return np.ascontiguousarray(a, np.float32)


def check_occlusion_samples(samples) -> int:
    return _integer("occlusion samples", samples, 0, OCCLUSION_SAMPLES_MAX,
                    " (environment-occlusion rays per pixel; 0: the SSDF alone)")


def check_shadow_samples(samples) -> int:
    return _integer("shadow samples", samples, 1, SHADOW_SAMPLES_MAX, " (rays per light and pixel)")


def light_samples(samples, n_lights: int) -> np.ndarray:
    """→ (n_lights,) int32 shadow rays per pixel for each light: `samples` one count for every light, or a
    sequence of one count a light (each checked as check_shadow_samples)."""
    if np.ndim(samples) == 0:
        return np.full(n_lights, check_shadow_samples(samples), np.int32)
    counts = list(samples)
    if len(counts) != n_lights:
        raise ValueError(f"shadow samples: one count a light, got {len(counts)} for {n_lights} lights")
    return np.array([check_shadow_samples(c) for c in counts], np.int32).reshape(n_lights)


def check_ray_part(part) -> tuple[int, int, int, int]:
    """→ (index, count, block_width, block_side): which of `count` anti-aliasing samples a trace is for
    (`ray_part`), the width W of the frame whose pixel blocks share each set of rays (`pixel_parts`; 0, the default:
    each pixel traces the sample's part itself), and the side of those blocks, 2 (the default) or 4
    (BLOCK_SIDES; `block_side` says which side a set takes). (0, 1, 0, 2): all rays."""
    try:
        index, count, *rest = part
        if len(rest) > 2:
            raise ValueError
    except (TypeError, ValueError):
        raise ValueError(f"ray part must be (index, count), (index, count, block_width) or (index, count, "
                         f"block_width, block_side), got {part!r}") from None
    count = _integer("ray part count", count, 1, 1 << 16, " (anti-aliasing samples sharing the rays)")
    width = _integer("ray part block width", rest[0] if rest else 0, 0, 1 << 20,
                     " (the frame's width, whose pixel blocks share the rays; 0: none)")
    side = _integer("ray part block side", rest[1] if len(rest) > 1 else 2, 2, 4, " (2 or 4)")
    if side not in BLOCK_SIDES:
        raise ValueError(f"ray part block side must be one of {BLOCK_SIDES}, got {side}")
    return _integer("ray part index", index, 0, count - 1, f" (of {count})"), count, width, side


def ray_part(samples: int, part) -> tuple[int, int]:
    """(first, stride): the rays i = first, first + stride, … < `samples` of a pixel's set that anti-aliasing
    sample `part` = (index, count) traces, so that `count` samples trace the set once between them (each ray
    once where count divides the set; when count exceeds it, every sample one ray, in turn). (0, 1): all."""
    index, count = part[:2]
    stride = max(1, min(int(count), int(samples)))
    return int(index) % stride, stride


def block_side(samples: int, part) -> int:
    """The side of the square pixel blocks that share a set of `samples` rays for part (index, count, W, side)
    (`check_ray_part`; the kernels' set_block_side): 1 (each pixel its own rays) without a block width or for a
    set of fewer than BLOCK_SLOTS rays; 4 where the part asks for 4 and the set holds a ray for every pixel of a
    4×4 block and every anti-aliasing sample (samples ≥ 16·count); else 2."""
    index, count, width, side = check_ray_part(part)
    if width == 0 or samples < BLOCK_SLOTS:
        return 1
    return 4 if side == 4 and samples >= 16 * count else 2


def pixel_parts(samples: int, part, pixel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first, stride, turn) int64 arrays shaped as `pixel`: the rays first, first + stride, … < `samples` of a
    set that pixel `pixel` traces for part (index, count, block_width[, block_side]) (`check_ray_part`), and the
    pixel whose hash angle turns them (`disk_sample`). Where the set is shared in s×s blocks (s = `block_side`
    > 1), the pixel at (x, y) = (p mod W, p div W) is slot q = x mod s + s (y mod s) of its block and traces part
    q + s²·index of s²·count, turned by the block's first pixel: the block's pixels trace the sample's part
    between them in one spiral, which `share_block` then lends to each. Else each pixel traces the sample's own
    part, turned by itself (the kernels' pixel_part)."""
    index, count, width, _ = check_ray_part(part)
    side = block_side(samples, part)
    p = np.asarray(pixel, np.int64)
    if side > 1:
        x, y = p % width, p // width
        slots = side * side
        stride = max(1, min(slots * count, int(samples)))
        first = (x % side + side * (y % side) + slots * index) % stride
        return first, np.full(p.shape, stride, np.int64), p - x % side - (y % side) * width
    first, stride = ray_part(samples, part)
    return np.full(p.shape, first, np.int64), np.full(p.shape, stride, np.int64), p


def part_rays(samples: int, part, pixel=None) -> np.ndarray:
    """(samples,) bool: the rays `ray_part` traces; with `pixel` (...,), (..., samples): the rays each pixel
    traces (`pixel_parts`)."""
    if pixel is None:
        first, stride = ray_part(samples, part)
    else:
        first, stride, _ = pixel_parts(samples, part, pixel)
        first, stride = first[..., None], stride[..., None]
    i = np.arange(samples)
    return (i >= first) & ((i - first) % stride == 0)


SHARE_NORMAL_COS = 0.9  # a block neighbour whose geometric normal is within ~26° of the pixel's ...
SHARE_PLANE = 0.1  # ... and that lies within ~6° of the pixel's tangent plane seen from it lends its rays


def _seen_normals(face, position, face_normals, eye):
    """(normals (..., 3) of faces `face` turned to the eye's side of `position`, hit (...,) bool)."""
    n = np.asarray(face_normals, np.float64)[np.maximum(face, 0)]
    n = np.where((np.sum(n * (np.asarray(eye, np.float64) - position), -1) < 0)[..., None], -n, n)
    return n, face >= 0


def same_surface(ng, xp, nb, xq, normal_cos: float = SHARE_NORMAL_COS, plane: float = SHARE_PLANE) -> np.ndarray:
    """(...,) bool float64 twin of the kernels' same_surface: whether hits xq (normals nb, turned to the eye) lie on
    the surface of hits xp (normals ng): ng·nb ≥ normal_cos and |ng·(xq − xp)| ≤ plane·|xq − xp|."""
    d = xq - xp
    return (np.sum(ng * nb, -1) >= normal_cos) & (np.abs(np.sum(ng * d, -1)) <= plane * np.linalg.norm(d, axis=-1))


def changed_pixels(face, position, reference_face, reference_position, face_normals, face_material, eye,
                   normal_cos: float = SHARE_NORMAL_COS, plane: float = SHARE_PLANE) -> np.ndarray:
    """(P,) bool float64 twin of the kernels' mark_changed: False where a pixel's hit lies on the reference
    G-buffer's surface at that pixel (the same face, both misses, or faces of one material whose hits pass
    `same_surface`), True elsewhere: the pixels an anti-aliasing sample shaded once a pixel traces and shades."""
    face, reference_face = np.asarray(face, np.int64), np.asarray(reference_face, np.int64)
    x = np.asarray(position, np.float64).reshape(-1, 3)
    x0 = np.asarray(reference_position, np.float64).reshape(-1, 3)
    n, hit = _seen_normals(face, x, face_normals, eye)
    n0, hit0 = _seen_normals(reference_face, x0, face_normals, eye)
    material = np.asarray(face_material, np.int64)
    same = hit & hit0 & (material[np.maximum(face, 0)] == material[np.maximum(reference_face, 0)])
    return ~((face == reference_face) | (same & same_surface(n0, x0, n, x, normal_cos, plane)))


def block_pixel(p, width: int, q: int, side: int = 2):
    """The pixel in slot q (x0 + q mod s, y0 + q div s) of pixels p's s×s blocks (s = `side`) in a frame of width
    `width` (x0, y0: p's column and row rounded down to a multiple of s; the kernels walk slot q = r·s + c as
    block_origin + r·width + c). Past the frame's last column where s does not divide the width: check the
    column, x0 + q mod s < width."""
    x, y = p % width, p // width
    return (y - y % side + q // side) * width + x - x % side + q % side


def share_block(face, position, face_normals, eye, width: int, pixel=None, side: int = 2,
                normal_cos: float = SHARE_NORMAL_COS, plane: float = SHARE_PLANE) -> np.ndarray:
    """(P, side²) bool float64 twin of the kernels' block_lenders: for hit pixel p (row y·W + x of a frame of width
    W), whether the pixel in slot q (x0 + q mod s, y0 + q div s) of its s×s block (s = `side`; x0, y0 = x, y
    rounded down to a multiple of s) lends its rays to p — p itself, or a hit neighbour inside the frame whose
    geometric normal (turned to the eye) n' has n·n' ≥ SHARE_NORMAL_COS and whose hit x' has |n·(x' − x)| ≤
    SHARE_PLANE·|x' − x| (`same_surface`): a depth or crease edge keeps each side's rays to itself. Missed pixels:
    none. `face_normals` (F, 3) unit. (normal_cos and plane move the two bounds, for a test's margins.)"""
    face = np.asarray(face, np.int64)
    position = np.asarray(position, np.float64).reshape(-1, 3)
    n_all = len(face)
    p = np.arange(n_all) if pixel is None else np.asarray(pixel, np.int64)
    x = p % width
    n_p, hit = _seen_normals(face[p], position[p], face_normals, eye)
    out = np.zeros((len(p), side * side), bool)
    for q in range(side * side):
        b = block_pixel(p, width, q, side)
        inside = (x - x % side + q % side < width) & (b < n_all)
        b = np.where(inside, b, p)
        n_b, hit_b = _seen_normals(face[b], position[b], face_normals, eye)
        same = same_surface(n_p, position[p], n_b, position[b], normal_cos, plane)
        out[:, q] = hit & inside & ((b == p) | (hit_b & same))
    return out


def block_sub_lenders(lenders, width: int, side: int, pixel=None) -> np.ndarray:
    """(P, side²) bool: the lenders of each pixel's side×side block taken from `lenders` (P, S²) of its S×S block
    (`share_block`, S a multiple of side): the blocks nest, and a pixel lends to another by their hits alone."""
    lenders = np.asarray(lenders, bool)
    big = int(round(np.sqrt(lenders.shape[1])))
    if big * big != lenders.shape[1] or big % side:
        raise ValueError(f"lenders must have S² columns with S a multiple of side {side}, got {lenders.shape[1]}")
    if big == side:
        return lenders
    p = np.arange(len(lenders)) if pixel is None else np.asarray(pixel, np.int64)
    x, y = p % width, p // width
    ox, oy = x % big - x % side, y % big - y % side  # the small block's corner inside the big one
    q = np.arange(side * side)
    slots = (ox[:, None] + q % side) + big * (oy[:, None] + q // side)
    return np.take_along_axis(lenders, slots, 1)


def offsets(mesh) -> tuple[float, float]:
    """(eps, t_min) of `mesh`: the shadow-ray offset and the any-hit lower bound, absolute."""
    return SHADOW_OFFSET * mesh.scale, T_MIN * mesh.scale


def check_mesh(mesh):

    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a warp_biscale.scene.Mesh, got {type(mesh).__name__}")
    return mesh


def check_camera(camera):

    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a warp_biscale.scene.Camera, got {type(camera).__name__}")
    return camera


def _array(name, value, dtype=np.float64) -> np.ndarray:
    try:
        return np.asarray(value, dtype)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}") from None


def check_rays(origins, directions, t_max):
    """→ float32 (N, 3) origins, (N, 3) directions, (N,) t_max. Directions must be unit (to 1e-3):
    t is a distance. t_max may be a scalar (every ray) and may be inf, never NaN."""
    o = _array("origins", origins)
    d = _array("directions", directions)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins must be an (N, 3) array, got shape {o.shape}")
    if d.shape != o.shape:
        raise ValueError(f"directions must have the shape of origins {o.shape}, got {d.shape}")
    if not np.isfinite(o).all():
        raise ValueError("origins contains NaN or inf")
    if not np.isfinite(d).all():
        raise ValueError("directions contains NaN or inf")
    if len(d) and np.abs(np.linalg.norm(d, axis=1) - 1.0).max() > 1e-3:
        raise ValueError("directions must be unit vectors (|d| = 1 to within 1e-3)")
    t = _array("t_max", t_max)
    if t.ndim == 0:
        t = np.full(len(o), float(t))
    if t.shape != (len(o),):
        raise ValueError(f"t_max must be a number or an ({len(o)},) array, got shape {t.shape}")
    if np.isnan(t).any():
        raise ValueError("t_max contains NaN")
    return (np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32),
            np.ascontiguousarray(t, np.float32))


def check_occlusion(mesh, origins, directions, t_max, t_min):
    """The inputs of Backend.trace_occluded → (origins, directions, t_lo, t_max (N,)) as check_rays,
    t_lo = `t_min` or the mesh's any-hit lower bound (`offsets`)."""
    check_mesh(mesh)
    o, d, t_hi = check_rays(origins, directions, t_max)
    t_lo = offsets(mesh)[1] if t_min is None else float(t_min)
    if not np.isfinite(t_lo) or t_lo < 0:
        raise ValueError(f"t_min must be a finite number >= 0, got {t_min!r}")
    return o, d, t_lo, t_hi


def check_lights(lights) -> np.ndarray:
    """→ (L, 8) float32 packed light rows (`PointLight.packed()` / `DirectionalLight.packed()`), or a
    list of such rows or light objects."""
    if isinstance(lights, (list, tuple)):
        lights = [x.packed() if hasattr(x, "packed") else x for x in lights]
        lights = np.zeros((0, 8)) if not lights else lights
    a = _array("lights_packed", lights)
    if a.ndim == 1 and a.size == 8:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 8:
        raise ValueError(f"lights_packed must be an (L, 8) array of Light.packed() rows, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("lights_packed contains NaN or inf")
    if not np.isin(a[:, 0], (0, 1)).all():
        raise ValueError("lights_packed column 0 must be 0 (directional) or 1 (point)")
    dirs = a[a[:, 0] == 0, 1:4]
    if len(dirs) and (np.linalg.norm(dirs, axis=1) == 0).any():
        raise ValueError("lights_packed: a directional light has a zero direction")
    return np.ascontiguousarray(a, np.float32)


def check_gbuffer(gbuffer, n_faces):
    """→ (face int32 (N,), bary float32 (N, 2), position float32 (N, 3), eye float32 (3,)) of a GBuffer for
    shadow rays (what `trace_primary` returns, or one built by hand with face, bary, position and eye)."""
    if not isinstance(gbuffer, GBuffer):
        raise ValueError(f"gbuffer must be the GBuffer trace_primary returns (or None), got {type(gbuffer).__name__}")
    for key in ("bary", "position", "eye"):
        if getattr(gbuffer, key) is None:
            raise ValueError(f"gbuffer has no {key} (shadow rays need face, bary, position and eye)")
    face = _array("gbuffer.face", gbuffer.face, np.int64)
    bary = _array("gbuffer.bary", gbuffer.bary)
    pos = _array("gbuffer.position", gbuffer.position)
    eye = _array("gbuffer.eye", gbuffer.eye).reshape(-1)
    if face.ndim != 1:
        raise ValueError(f"gbuffer.face must be (N,), got shape {face.shape}")
    if bary.shape != (len(face), 2):
        raise ValueError(f"gbuffer.bary must be ({len(face)}, 2), got shape {bary.shape}")
    if pos.shape != (len(face), 3):
        raise ValueError(f"gbuffer.position must be ({len(face)}, 3), got shape {pos.shape}")
    if eye.shape != (3,) or not np.isfinite(eye).all():
        raise ValueError("gbuffer.eye must be three finite numbers")
    if len(face) and (face.min() < -1 or face.max() >= n_faces):
        raise ValueError(f"gbuffer.face must hold -1 (miss) or a face index 0..{n_faces - 1}")
    if not np.isfinite(pos[face >= 0]).all():
        raise ValueError("gbuffer.position contains NaN or inf at a hit pixel")
    if not np.isfinite(bary[face >= 0]).all():
        raise ValueError("gbuffer.bary contains NaN or inf at a hit pixel")
    return (np.ascontiguousarray(face, np.int32), np.ascontiguousarray(bary, np.float32),
            np.ascontiguousarray(pos, np.float32), np.ascontiguousarray(eye, np.float32))
