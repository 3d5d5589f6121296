"""Ray casting against the large-scale mesh: camera rays (the G-buffer), any-hit rays (SSDF
visibility, shadows, the Monte Carlo reference) and per-light shadow rays.

Twin of ``cl/trace.cl``; the mathematics is ``warp_biscale.reference`` (``trace_closest``,
``trace_occluded``, ``trace_shadows``). Warp walks its own BVH (``wp.Mesh``, SAH with 2 triangles a
leaf, built once per mesh and kept in the mesh's device cache).

Conventions shared with the OpenCL twin and the reference:
- pixel (x, y), y down, is thread y·W + x; its ray is normalize(forward + sx·R + sy·U) with
  sx = 2(x + ½)/W − 1, sy = 1 − 2(y + ½)/H (`Camera.packed`), generated here, not on the host;
- barycentric (u, v) are the weights of the face's vertices 1 and 2 (vertex 0 gets 1 − u − v),
  and the hit position is a + u(b − a) + v(c − a), on the triangle, not o + t·d;
- any-hit rays count a triangle hit with t in (t_min, t_max]. Warp's query tests [0, max_t), so
  the ray starts at o + t_min·d with max_t = t_max − t_min: the two agree except for a hit
  within float32 rounding of either end.
"""

import warp as wp

from warp_biscale import trace as _trace

from .common import (LOBE_RAYS, above_horizon, disk_basis, disk_sample, horizon_frame, lobe_ray_direction,
                     occlusion_direction, part_bits, pixel_part, set_block_side)

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

SHARE_NORMAL_COS = wp.constant(_trace.SHARE_NORMAL_COS)
SHARE_PLANE = wp.constant(_trace.SHARE_PLANE)


@wp.func
def surface_point(points: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32), f: int,
                  u: float, v: float) -> wp.vec3:
    """a + u(b − a) + v(c − a) for face f: the same operations as cl/trace.cl, whose triangle table
    holds exactly these float32 edges."""
    a = points[faces[f, 0]]
    return a + u * (points[faces[f, 1]] - a) + v * (points[faces[f, 2]] - a)


@wp.func
def seen_side(n: wp.vec3, x: wp.vec3, eye: wp.vec3) -> wp.vec3:
    """The geometric normal n of a hit at x turned to the side the eye sees: shadow, occlusion and lobe rays
    leave along it, so the moved origin lies in front of the face whichever way it is wound."""
    if wp.dot(n, eye - x) < 0.0:
        return -n
    return n


@wp.func
def ray_start(points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32),
              face_normal: wp.vec3, f: int, bary: wp.vec2, x: wp.vec3, eye: wp.vec3, eps: float):
    """(origin, ng, ns) of the rays leaving hit x of face f (trace.ray_starts, the float64 twin): ng the face's
    normal turned to the eye (seen_side), ns the interpolated vertex normal turned to ng's side, and the origin x
    lifted onto the curved surface of the vertex normals (Hanika's shadow-terminator offset), then eps along
    ng: so a light the shading normal sees past the face's own plane is reached over the neighbouring faces."""
    ng = seen_side(face_normal, x, eye)
    w1 = bary[0]
    w2 = bary[1]
    w0 = 1.0 - w1 - w2
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    # the vertex normals turned to the eye's side of the face with their blend (not with the winding, which a
    # mesh may have the other way round: its lights were then tested against the inside's horizon)
    side = wp.where(wp.dot(ng, w0 * normals[i0] + w1 * normals[i1] + w2 * normals[i2]) < 0.0, -1.0, 1.0)
    n0 = side * normals[i0]
    n1 = side * normals[i1]
    n2 = side * normals[i2]
    d0 = wp.min(wp.dot(x - points[i0], n0), 0.0)
    d1 = wp.min(wp.dot(x - points[i1], n1), 0.0)
    d2 = wp.min(wp.dot(x - points[i2], n2), 0.0)
    lifted = x - (w0 * d0 * n0 + w1 * d1 * n1 + w2 * d2 * n2)
    ns = wp.normalize(w0 * n0 + w1 * n1 + w2 * n2)
    return lifted + eps * ng, ng, ns


@wp.kernel
def trace_primary(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    eye: wp.vec3,
    forward: wp.vec3,
    right: wp.vec3,  # right·tan(fov/2)·aspect
    up: wp.vec3,  # up·tan(fov/2)
    width: int,
    height: int,
    offset: int,
    face_out: wp.array(dtype=wp.int32),
    bary_out: wp.array(dtype=wp.vec2),
    position_out: wp.array(dtype=wp.vec3),
    t_out: wp.array(dtype=wp.float32),
):
    i = wp.tid() + offset
    x = i % width
    y = i // width
    sx = 2.0 * (float(x) + 0.5) / float(width) - 1.0
    sy = 1.0 - 2.0 * (float(y) + 0.5) / float(height)
    d = wp.normalize(forward + sx * right + sy * up)
    q = wp.mesh_query_ray(mesh, eye, d, wp.inf)
    if q.result:
        # Warp's (u, v) weigh vertices 0 and 1; ours weigh vertices 1 and 2.
        u = q.v
        v = 1.0 - q.u - q.v
        face_out[i] = q.face
        bary_out[i] = wp.vec2(u, v)
        position_out[i] = surface_point(points, faces, q.face, u, v)
        t_out[i] = q.t
    else:
        face_out[i] = -1
        bary_out[i] = wp.vec2(0.0, 0.0)
        position_out[i] = wp.vec3(0.0, 0.0, 0.0)
        t_out[i] = wp.inf


@wp.kernel
def trace_occluded(
    mesh: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    t_min: float,
    t_max: wp.array(dtype=wp.float32),
    offset: int,
    occluded: wp.array(dtype=wp.uint8),
):
    i = wp.tid() + offset
    d = directions[i]
    reach = t_max[i] - t_min
    hit = wp.uint8(0)
    if reach > 0.0:
        if wp.mesh_query_ray_anyhit(mesh, origins[i] + t_min * d, d, reach):
            hit = wp.uint8(1)
    occluded[i] = hit


@wp.kernel
def trace_shadows(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    face_normals: wp.array(dtype=wp.vec3),
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    position: wp.array(dtype=wp.vec3),
    eye: wp.vec3,
    lights: wp.array2d(dtype=wp.float32),  # (L, 8) Light.packed() rows
    light_samples: wp.array(dtype=wp.int32),  # (L,) rays a pixel for each light (trace.light_samples)
    eps: float,
    t_min: float,
    part_index: int,
    part_count: int,
    block_width: int,
    block_side: int,
    changed: wp.array(dtype=wp.uint8),  # only_changed: the pixels flagged here alone (mark_changed: anti-aliasing
    only_changed: int,  # shaded once a pixel; the others keep their rays)
    offset: int,
    visible: wp.array2d(dtype=wp.uint8),  # (N, L)
):
    """One thread per (light, pixel); neighbouring threads take neighbouring pixels towards one
    light, so their BVH walks stay coherent. The pixel's rays of anti-aliasing sample part_index of part_count
    (pixel_part, its block's share where block_width > 0) among the light's light_samples[k] go to points
    spread over the light's disc (a point light's sphere seen from the pixel; a directional light's cone); the result
    is their visible share in 255ths, rounded."""
    k, p_local = wp.tid()
    p = p_local + offset
    f = face[p]
    if only_changed != 0 and changed[p] == wp.uint8(0):
        return
    hits = int(0)
    samples = light_samples[k]
    part = pixel_part(samples, part_index, part_count, block_width, block_side, p)
    first = part[0]
    stride = part[1]
    traced = (samples - first + stride - 1) // stride
    if f >= 0:
        o, ng, n = ray_start(points, normals, faces, face_normals[f], f, bary[p], position[p], eye, eps)
        c = wp.vec3(lights[k, 1], lights[k, 2], lights[k, 3])
        w = wp.normalize(c)
        spread = wp.tan(wp.sqrt(lights[k, 7] / 3.14159265358979))  # directional: tan of the angular radius
        apparent = spread  # the disc's radius over its distance
        if lights[k, 0] != 0.0:
            w = wp.normalize(c - o)
            spread = lights[k, 7]  # point: the radius
            apparent = spread / wp.length(c - o)
        # the rays aim at the part of the disc above the shading normal's horizon, q_x > −chord
        frame = horizon_frame(w, n, apparent)
        chord = frame[2, 0]
        for i in range(first, samples, stride):
            q = disk_sample(i, samples, part[2])
            if chord < 1.0:
                q = above_horizon(q, chord)
            offset_on_disc = spread * (q[0] * frame[0] + q[1] * frame[1])
            d = w + offset_on_disc
            t_hi = float(wp.inf)
            if lights[k, 0] != 0.0:  # a point light: towards a point of its disc, stopping eps short of it
                d = c + offset_on_disc - o
                t_hi = wp.length(d) - eps
            d = wp.normalize(d)
            # Below the shading normal's horizon the light adds nothing; above it, a ray that dips below the
            # face's plane is traced from the lifted origin (it may still hit the face itself).
            if wp.dot(n, d) > 0.0:
                reach = t_hi - t_min
                if reach > 0.0:
                    if not wp.mesh_query_ray_anyhit(mesh, o + t_min * d, d, reach):
                        hits = hits + 1
                else:
                    hits = hits + 1
    visible[p, k] = wp.uint8((hits * 255 + traced // 2) // traced)


@wp.kernel
def trace_occlusion(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    face_normals: wp.array(dtype=wp.vec3),
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    position: wp.array(dtype=wp.vec3),
    eye: wp.vec3,
    eps: float,
    t_min: float,
    samples: int,
    part_index: int,
    part_count: int,
    block_width: int,
    block_side: int,
    changed: wp.array(dtype=wp.uint8),  # only_changed: the pixels flagged here alone (mark_changed: anti-aliasing
    only_changed: int,  # shaded once a pixel; the others keep their rays)
    offset: int,
    mask: wp.array(dtype=wp.uint32),
):
    """One thread per pixel: of `samples` unbounded any-hit rays, cosine-distributed over the hemisphere of
    the geometric normal on the camera's side (occlusion_direction), the pixel's of anti-aliasing sample
    part_index of part_count (pixel_part); bit i of the pixel's mask is set where ray i is blocked."""
    p = wp.tid() + offset
    f = face[p]
    if only_changed != 0 and changed[p] == wp.uint8(0):
        return
    bits = wp.uint32(0)
    if f >= 0:
        o, n, ns = ray_start(points, normals, faces, face_normals[f], f, bary[p], position[p], eye, eps)
        frame = disk_basis(n)
        part = pixel_part(samples, part_index, part_count, block_width, block_side, p)
        for i in range(part[0], samples, part[1]):
            d = occlusion_direction(frame, i, samples, part[2])
            if wp.mesh_query_ray_anyhit(mesh, o + t_min * d, d, wp.inf):
                bits = bits | (wp.uint32(1) << wp.uint32(i))
    mask[p] = bits


@wp.kernel
def trace_lobe_rays(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    face_normals: wp.array(dtype=wp.vec3),
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    position: wp.array(dtype=wp.vec3),
    eye: wp.vec3,
    lobes: wp.array2d(dtype=wp.float32),  # (M, 4) [axis, η]
    n_lobes: int,
    rays: int,  # LOBE_RAYS, passed in (as to the OpenCL twin): Warp unrolls a loop over a constant, BVH walk and all
    eps: float,
    t_min: float,
    part_index: int,
    part_count: int,
    block_width: int,
    block_side: int,
    changed: wp.array(dtype=wp.uint8),  # only_changed: the pixels flagged here alone (mark_changed: anti-aliasing
    only_changed: int,  # shaded once a pixel; the others keep their rays)
    offset: int,
    mask: wp.array(dtype=wp.uint32),
):
    """One thread per pixel: of LOBE_RAYS unbounded any-hit rays over each sharp lobe's cap (lobe_ray_direction),
    the pixel's of anti-aliasing sample part_index of part_count (pixel_part); bit k·LOBE_RAYS + i set where ray i of
    lobe k is blocked. A ray below the shading normal's horizon is not traced."""
    p = wp.tid() + offset
    f = face[p]
    if only_changed != 0 and changed[p] == wp.uint8(0):
        return
    bits = wp.uint32(0)
    if f >= 0:
        o, ng, n = ray_start(points, normals, faces, face_normals[f], f, bary[p], position[p], eye, eps)
        part = pixel_part(rays, part_index, part_count, block_width, block_side, p)
        for k in range(n_lobes):
            axis = wp.vec3(lobes[k, 0], lobes[k, 1], lobes[k, 2])
            frame = disk_basis(axis)
            for i in range(part[0], rays, part[1]):
                d = lobe_ray_direction(frame, lobes[k, 3], i, part[2])
                if wp.dot(n, d) > 0.0:
                    if wp.mesh_query_ray_anyhit(mesh, o + t_min * d, d, wp.inf):
                        bits = bits | (wp.uint32(1) << wp.uint32(k * LOBE_RAYS + i))
    mask[p] = bits


@wp.func
def same_surface(ng: wp.vec3, xp: wp.vec3, nb: wp.vec3, xq: wp.vec3) -> bool:
    """Whether a hit xq with geometric normal nb (turned to the eye) lies on the surface of the hit xp with normal
    ng (trace.same_surface): normals within SHARE_NORMAL_COS, and xq near xp's tangent plane seen from xp."""
    d = xq - xp
    return wp.dot(ng, nb) >= SHARE_NORMAL_COS and wp.abs(wp.dot(ng, d)) <= SHARE_PLANE * wp.length(d)


@wp.func
def block_origin(p: int, width: int, side: int) -> wp.vec2i:
    """(the first pixel of pixel p's side x side block, its column): found once a pixel, so that the loops
    over a block's slots (q = r·side + c: the pixel origin + r·width + c) find each slot's pixel without an integer
    division, which on a GPU costs more than the slot's memory reads."""
    x = p % width
    y = p // width
    x0 = x - x % side
    y0 = y - y % side
    return wp.vec2i(y0 * width + x0, x0)


@wp.func
def block_lenders(face: wp.array(dtype=wp.int32), position: wp.array(dtype=wp.vec3),
                  face_normals: wp.array(dtype=wp.vec3), eye: wp.vec3, width: int, n_pixels: int, p: int,
                  side: int) -> int:
    """Bit q set where the pixel in slot q of hit pixel p's side x side block lends p its rays (trace.share_block):
    p itself, or a hit neighbour in the frame whose geometric normal is within SHARE_NORMAL_COS of p's and which
    lies near p's tangent plane (SHARE_PLANE), so that a depth or crease edge keeps each side's rays apart."""
    xp = position[p]
    ng = seen_side(face_normals[face[p]], xp, eye)
    origin = block_origin(p, width, side)
    lenders = int(0)
    for r in range(side):
        for c in range(side):
            b = origin[0] + r * width + c
            if origin[1] + c < width and b < n_pixels:
                if b == p:
                    lenders = lenders | (1 << (r * side + c))
                elif face[b] >= 0:
                    xq = position[b]
                    if same_surface(ng, xp, seen_side(face_normals[face[b]], xq, eye), xq):
                        lenders = lenders | (1 << (r * side + c))
    return lenders


@wp.kernel
def frame_block_lenders(
    face: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    face_normals: wp.array(dtype=wp.vec3),
    eye: wp.vec3,
    width: int,
    side: int,
    n_pixels: int,
    offset: int,
    lenders: wp.array(dtype=wp.int32),
):
    """One thread per pixel: its lenders in its side x side block (block_lenders; 0 for a miss), found once a
    G-buffer for every set of rays its frame shares (trace.share_block)."""
    p = wp.tid() + offset
    out = int(0)
    if face[p] >= 0:
        out = block_lenders(face, position, face_normals, eye, width, n_pixels, p, side)
    lenders[p] = out


@wp.func
def sub_lenders(lenders: int, p: int, width: int, lenders_side: int, side: int) -> int:
    """The lenders of pixel p's side x side block taken from `lenders`, those of its lenders_side block
    (trace.block_sub_lenders): the blocks nest, and a pixel lends to another by their hits alone."""
    if side == lenders_side:
        return lenders
    x = p % width
    y = p // width
    ox = x % lenders_side - x % side
    oy = y % lenders_side - y % side
    out = int(0)
    for r in range(side):  # (slot q = r·side + c, by row and column: no division a slot, as block_origin)
        for c in range(side):
            if (lenders >> ((ox + c) + lenders_side * (oy + r))) & 1 != 0:
                out = out | (1 << (r * side + c))
    return out


@wp.kernel
def share_block_masks(
    lenders: wp.array(dtype=wp.int32),
    face: wp.array(dtype=wp.int32),
    width: int,
    block_side: int,
    samples: int,
    part_index: int,
    part_count: int,
    mask: wp.array(dtype=wp.uint32),
    offset: int,
    shared: wp.array(dtype=wp.uint32),
    known: wp.array(dtype=wp.uint32),
):
    """One thread per pixel (reference.share_block_masks): the union of the ray masks (occlusion or lobe rays, a
    set of `samples`) that the pixels of its block (set_block_side) lend it (`lenders`, frame_block_lenders' of the
    part's block_side), and of the rays they traced (the part of their slot in the block): what the shade stage
    weighs. A set of fewer than BLOCK_SLOTS rays is not shared: the pixel's own. 0 for a miss."""
    p = wp.tid() + offset
    bits = wp.uint32(0)
    traced = wp.uint32(0)
    if face[p] >= 0:
        side = set_block_side(samples, part_count, width, block_side)
        if side == 1:
            part = pixel_part(samples, part_index, part_count, width, block_side, p)
            bits = mask[p]
            traced = part_bits(part[0], part[1], samples)
        else:
            slots = side * side
            lent = sub_lenders(lenders[p], p, width, block_side, side)
            origin = block_origin(p, width, side)
            # slot q's part of the set is ray_part(samples, q + slots·part_index, slots·part_count): one stride
            # for every slot, and a first ray that steps by one from slot to slot, wrapping at the stride
            stride = wp.max(1, wp.min(slots * part_count, samples))
            first = (slots * part_index) % stride
            for r in range(side):
                for c in range(side):
                    if (lent >> (r * side + c)) & 1 != 0:
                        bits = bits | mask[origin[0] + r * width + c]
                        traced = traced | part_bits(first, stride, samples)
                    first = first + 1
                    if first == stride:
                        first = 0
    shared[p] = bits
    known[p] = traced


@wp.kernel
def share_block_shadows(
    lenders: wp.array(dtype=wp.int32),
    face: wp.array(dtype=wp.int32),
    width: int,
    block_side: int,
    part_index: int,
    part_count: int,
    n_lights: int,
    light_samples: wp.array(dtype=wp.int32),  # (L,) rays a pixel for each light (trace.light_samples)
    visible: wp.array2d(dtype=wp.uint8),
    offset: int,
    shared: wp.array2d(dtype=wp.uint8),
):
    """One thread per pixel (reference.share_block_shadows): each light's visible share over the shadow rays
    that the pixels of its block (set_block_side for the light's rays) lend it (`lenders`, as share_block_masks'),
    Σ traced·share / Σ traced in 255ths, rounded; the pixel's own share for a light of fewer than BLOCK_SLOTS
    rays, and for a miss."""
    p = wp.tid() + offset
    hit = face[p] >= 0
    for l in range(n_lights):
        value = int(visible[p, l])
        samples = light_samples[l]
        side = set_block_side(samples, part_count, width, block_side)
        if hit and side > 1:
            slots = side * side
            lent = sub_lenders(lenders[p], p, width, block_side, side)
            origin = block_origin(p, width, side)
            # slot q's rays, as in share_block_masks: the first steps by one a slot, the stride is the same, so a
            # slot traces samples // stride rays, one more where its first is below samples % stride
            stride = wp.max(1, wp.min(slots * part_count, samples))
            first = (slots * part_index) % stride
            fewest = samples // stride
            longer = samples % stride
            num = int(0)
            den = int(0)
            for r in range(side):
                for c in range(side):
                    if (lent >> (r * side + c)) & 1 != 0:
                        traced = fewest
                        if first < longer:
                            traced = traced + 1
                        num = num + traced * int(visible[origin[0] + r * width + c, l])
                        den = den + traced
                    first = first + 1
                    if first == stride:
                        first = 0
            value = (num + den // 2) // den
        shared[p, l] = wp.uint8(value)


@wp.kernel
def mark_changed(
    face: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    reference_face: wp.array(dtype=wp.int32),
    reference_position: wp.array(dtype=wp.vec3),
    face_normals: wp.array(dtype=wp.vec3),
    face_material: wp.array(dtype=wp.int32),
    eye: wp.vec3,
    offset: int,
    changed: wp.array(dtype=wp.uint8),
):
    """One thread per pixel (trace.changed_pixels): 0 where the pixel's hit lies on the reference G-buffer's surface
    at that pixel (the same face, both misses, or the same material with same_surface), else 1: which pixels an
    anti-aliasing sample shaded once a pixel traces and shades itself."""
    p = wp.tid() + offset
    f = face[p]
    f0 = reference_face[p]
    flag = wp.uint8(1)
    if f == f0:
        flag = wp.uint8(0)
    elif f >= 0 and f0 >= 0:
        if face_material[f] == face_material[f0]:
            x = position[p]
            x0 = reference_position[p]
            if same_surface(seen_side(face_normals[f0], x0, eye), x0, seen_side(face_normals[f], x, eye), x):
                flag = wp.uint8(0)
    changed[p] = flag
