"""Visibility of the infinitely tiled surface (Wu §3.3, docs/design.md §4): bits V_s(ω_k).

Twin of ``cl/visibility.cl``; the mathematics is ``warp_biscale.reference.trace_periodic``.
One thread per ray (direction, facet) writes a byte, and `pack_bits` folds 32 bytes into a word (no
atomics). Neighbouring threads trace neighbouring facets (facets are ordered by face) along the same
direction, so the BVH walks of a warp stay coherent. On a GPU one thread per ray ran about 1.6× as
fast as one thread per 32-ray word, and an SAH-built BVH with 2 triangles a leaf about twice as fast
again as Warp's CUDA default (LBVH with 4), bits identical (bench/README.md). Rays are any-hit
(occluded or not is all we need). A ray leaving the tile through its xy boundary re-enters on the
opposite side until it passes above the tile's highest point.
"""

import warp as wp

from .common import cell_exits, next_cell

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.func
def hit_any_triangle(vertices: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32),
                     o: wp.vec3, d: wp.vec3, t_lo: float, t_hi: float) -> int:
    """Brute force: 1 if any triangle is hit with t in (t_lo, t_hi] (Möller–Trumbore, double-sided)."""
    for f in range(faces.shape[0]):
        a = vertices[faces[f, 0]]
        e1 = vertices[faces[f, 1]] - a
        e2 = vertices[faces[f, 2]] - a
        p = wp.cross(d, e2)
        det = wp.dot(p, e1)
        if det != 0.0:
            inv = 1.0 / det
            tv = o - a
            u = wp.dot(tv, p) * inv
            q = wp.cross(tv, e1)
            v = wp.dot(d, q) * inv
            t = wp.dot(e2, q) * inv
            if u >= 0.0 and v >= 0.0 and u + v <= 1.0 and t > t_lo and t <= t_hi:
                return 1
    return 0


@wp.func
def trace_periodic(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32),
                   brute_force: int, start: wp.vec3, d: wp.vec3,
                   x0: float, y0: float, px: float, py: float, z_lo: float, z_hi: float, eps: float) -> int:
    """1 if the ray leaves the tile's height range unblocked (see reference.trace_periodic)."""
    if d[2] <= 0.0:
        return 0
    o = start
    z_top = z_hi + eps
    back = float(0.0)  # the first segment starts on the facet; later ones reach back by eps
    steps = 4 + int(wp.ceil((z_hi - z_lo + 2.0 * eps) / d[2] * (wp.abs(d[0]) / px + wp.abs(d[1]) / py)))
    for _step in range(steps + 1):
        t_top = (z_top - o[2]) / d[2]
        exits = cell_exits(o, d, x0, y0, px, py)
        t_side = wp.min(exits[0], exits[1])
        t_exit = wp.min(t_top, t_side)
        hit = int(0)
        if brute_force != 0:
            hit = hit_any_triangle(vertices, faces, o, d, -back, t_exit + eps)
        elif wp.mesh_query_ray_anyhit(mesh, o - back * d, d, t_exit + eps + back):
            hit = 1
        if hit != 0:
            return 0
        if t_top <= t_side:
            return 1
        o = next_cell(o, d, t_exit, exits, px, py)
        back = eps
    return 1


@wp.kernel
def visibility_rays(
    mesh: wp.uint64,
    vertices: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    face_normals: wp.array(dtype=wp.vec3),
    brute_force: int,
    position: wp.array(dtype=wp.vec3),
    facet_face: wp.array(dtype=wp.int32),
    directions: wp.array(dtype=wp.vec3),
    x0: float, y0: float, px: float, py: float, z_lo: float, z_hi: float, eps: float,
    offset: int,
    visible: wp.array2d(dtype=wp.uint8),
):
    k, s_local = wp.tid()
    s = s_local + offset
    d = directions[k]
    ng = face_normals[facet_face[s]]
    v = wp.uint8(0)
    if wp.dot(ng, d) > 0.0:
        o = position[s] + eps * ng
        if trace_periodic(mesh, vertices, faces, brute_force, o, d, x0, y0, px, py, z_lo, z_hi, eps) != 0:
            v = wp.uint8(1)
    visible[k, s] = v


@wp.kernel
def pack_bits(visible: wp.array2d(dtype=wp.uint8), offset: int, bits: wp.array2d(dtype=wp.uint32)):
    """Pack one byte per ray into words of 32 facets."""
    k, w_local = wp.tid()
    w = w_local + offset
    n = visible.shape[1]
    word = wp.uint32(0)
    for b in range(32):
        s = w * 32 + b
        if s < n:
            if visible[k, s] != wp.uint8(0):
                word = word | (wp.uint32(1) << wp.uint32(b))
    bits[k, w] = word
