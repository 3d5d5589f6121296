"""Facet sampling (Wu §3.2, stratified): one thread per facet.

Twin of ``cl/facets.cl``; the mathematics is ``warp_biscale.reference.sample_facets``: facet s
takes u1 = (s + ξ1)/Ns along the cumulative face area (float64, so a face is found exactly even
among 10⁶ faces) and u2 = frac(φ2(s) + ξ2), mapped into its face by the area-preserving
square→triangle map. Every facet carries ΔA = A/Ns.

`offset` (here and in every main kernel of a stage) is added to the last launch index, so that
the backend can split one launch into slices, one per CPU core: Warp's CPU device runs a launch
on one thread, and launches from several Python threads run in parallel. The OpenCL twins need no
slicing: PoCL spreads one launch over every core itself.
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.func
def radical_inverse_24(s: int) -> float:
    """Van der Corput φ2(s) on the top 24 bits, exact in float32."""
    x = wp.uint32(s)
    x = ((x >> wp.uint32(1)) & wp.uint32(0x55555555)) | ((x & wp.uint32(0x55555555)) << wp.uint32(1))
    x = ((x >> wp.uint32(2)) & wp.uint32(0x33333333)) | ((x & wp.uint32(0x33333333)) << wp.uint32(2))
    x = ((x >> wp.uint32(4)) & wp.uint32(0x0F0F0F0F)) | ((x & wp.uint32(0x0F0F0F0F)) << wp.uint32(4))
    x = ((x >> wp.uint32(8)) & wp.uint32(0x00FF00FF)) | ((x & wp.uint32(0x00FF00FF)) << wp.uint32(8))
    x = (x >> wp.uint32(16)) | (x << wp.uint32(16))
    return float(x >> wp.uint32(8)) * (1.0 / 16777216.0)


@wp.kernel
def sample_facets(
    vertices: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    vertex_normals: wp.array(dtype=wp.vec3),
    use_vertex_normals: int,
    face_normals: wp.array(dtype=wp.vec3),
    cumulative_area: wp.array(dtype=wp.float64),
    face_area: wp.array(dtype=wp.float64),
    count: int,
    xi1: wp.float64,
    xi2: float,
    offset: int,
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    face: wp.array(dtype=wp.int32),
):
    s = wp.tid() + offset
    n_faces = cumulative_area.shape[0]
    total = cumulative_area[n_faces - 1]
    target = (wp.float64(s) + xi1) / wp.float64(count) * total
    # First face whose cumulative area exceeds the target.
    lo = int(0)
    hi = n_faces - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cumulative_area[mid] > target:
            hi = mid
        else:
            lo = mid + 1
    f = lo
    start = cumulative_area[f] - face_area[f]
    u = float(wp.clamp((target - start) / face_area[f], wp.float64(0.0), wp.float64(1.0)))
    v = radical_inverse_24(s) + xi2
    if v >= 1.0:
        v = v - 1.0
    su = wp.sqrt(u)
    b0 = 1.0 - su
    b1 = su * (1.0 - v)
    b2 = su * v
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    position[s] = b0 * vertices[i0] + b1 * vertices[i1] + b2 * vertices[i2]
    if use_vertex_normals != 0:
        normal[s] = wp.normalize(b0 * vertex_normals[i0] + b1 * vertex_normals[i1] + b2 * vertex_normals[i2])
    else:
        normal[s] = face_normals[f]
    face[s] = f


@wp.kernel
def facet_weights(
    face: wp.array(dtype=wp.int32),
    per_face: wp.array(dtype=wp.float32),
    area: wp.array(dtype=wp.float32),
    offset: int,
    weight: wp.array(dtype=wp.float32),
):
    """A facet's weight from its face's value: per_face[face] · ΔA (bake._channel_faces' colour channels, made where
    the facets are, so the host neither reads their faces back nor uploads a weight a facet)."""
    s = wp.tid() + offset
    weight[s] = per_face[face[s]] * area[s]
