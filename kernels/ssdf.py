"""SSDF distance transform (Wang 2009 Eq. 23) over an octahedral grid of world directions.

Twin of ``cl/ssdf.cl``; the mathematics is ``warp_biscale.reference.ssdf_distance``. One thread per
(vertex v, texel k), no atomics: it finds the texel direction t of the opposite class nearest to
d_k and writes θd = ±(angle(d_k, t) − h_k) (+ visible, − occluded), or ±π if the vertex has no
texel of the opposite class.

Exact, but not by scanning all N = S² texels: texels come in blocks of neighbours, each bounded
by a cone (axis, radius r) that the host widens by 1e-3 rad so float32 rounding never prunes a
block holding the nearest texel. Pass 1 over the cones of the blocks that hold the opposite class
finds the nearest one (angle(d, axis) − r) and the smallest far bound (angle(d, axis) + r); pass 2
scans that block first, then only blocks whose near bound beats both the far bound and the best
found so far. Bounds are compared as cosines (cos(a ∓ r) = cos a·cos r ± sin a·sin r), so no
acos per block. The nearest texel is the largest float32 dot product; its angle is then
atan2(|d×t|, d·t), accurate near 0.
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.func
def cone_near_cos(ca: float, cos_r: float, sin_r: float) -> float:
    """cos of the smallest angle from d to a cone of radius r whose axis has cos ca with d (1 if inside)."""
    if ca >= cos_r:
        return 1.0
    sa = wp.sqrt(wp.max(1.0 - ca * ca, 0.0))
    return ca * cos_r + sa * sin_r


@wp.func
def cone_far_cos(ca: float, cos_r: float, sin_r: float) -> float:
    """cos of the largest angle from d to the cone (−1 if the cone reaches −d)."""
    if ca <= -cos_r:
        return -1.0
    sa = wp.sqrt(wp.max(1.0 - ca * ca, 0.0))
    return ca * cos_r - sa * sin_r


@wp.kernel
def ssdf_distance(
    visible: wp.array2d(dtype=wp.uint8),  # (V, N) 1 = visible
    directions: wp.array(dtype=wp.vec3),  # (N,) unit texel directions
    half_angle: wp.array(dtype=wp.float32),  # (N,) h_k, rad
    block_members: wp.array2d(dtype=wp.int32),  # (B, M) texel indices, −1 pads
    block_axis: wp.array(dtype=wp.vec3),  # (B,) unit cone axes
    block_cos: wp.array(dtype=wp.float32),  # (B,) cos of the cone radius
    block_sin: wp.array(dtype=wp.float32),  # (B,) sin of the cone radius
    block_classes: wp.array2d(dtype=wp.uint8),  # (V, B) bit 0: a visible member, bit 1: an occluded one
    offset: int,
    theta: wp.array2d(dtype=wp.float32),  # (V, N) θd, rad
):
    v, k_local = wp.tid()
    k = k_local + offset
    mine = visible[v, k]
    want = wp.uint8(1)  # the block bit of the opposite class: visible texel → look for occluded ones
    sign = float(-1.0)
    if mine != wp.uint8(0):
        want = wp.uint8(2)
        sign = 1.0
    d = directions[k]
    n_blocks = block_axis.shape[0]
    n_members = block_members.shape[1]
    # Pass 1 (cones only): the block nearest to d that holds the opposite class, and the best far
    # bound (some opposite texel lies at least this close). All in cosines: larger = nearer.
    first = int(-1)
    first_cos = float(-3.0)
    bound = float(-2.0)
    for b in range(n_blocks):
        if (block_classes[v, b] & want) != wp.uint8(0):
            ca = wp.dot(d, block_axis[b])
            near = cone_near_cos(ca, block_cos[b], block_sin[b])
            if near > first_cos:
                first_cos = near
                first = b
            bound = wp.max(bound, cone_far_cos(ca, block_cos[b], block_sin[b]))
    # Pass 2: scan that nearest block first (its best texel is usually the answer, a tight bound),
    # then every other block whose near bound still beats the best found.
    best_dot = float(-2.0)
    best = int(-1)
    for i in range(n_blocks + 1):
        b = first
        if i > 0:
            b = i - 1
        scan = first >= 0
        if i > 0:
            scan = b != first and (block_classes[v, b] & want) != wp.uint8(0)
            if scan:
                near = cone_near_cos(wp.dot(d, block_axis[b]), block_cos[b], block_sin[b])
                scan = near >= wp.max(best_dot, bound)
        if scan:
            for m in range(n_members):
                t = block_members[b, m]
                if t >= 0:
                    if visible[v, t] != mine:
                        c = wp.dot(d, directions[t])
                        if c > best_dot:
                            best_dot = c
                            best = t
    out = sign * 3.14159265358979
    if best >= 0:
        t_dir = directions[best]
        angle = wp.atan2(wp.length(wp.cross(d, t_dir)), wp.dot(d, t_dir))
        out = sign * (angle - half_angle[k])
    theta[v, k] = out
