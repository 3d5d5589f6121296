"""Warp functions shared by several stages: the small-scale BRDFs (cosine-weighted) and bit tricks.

Mirrors ``cl/common.cl`` and ``warp_biscale.reference.brdf_cosine_weighted``.
"""

import warp as wp

LAMBERT = wp.constant(0)
BLINN_PHONG = wp.constant(1)
COOK_TORRANCE = wp.constant(2)
WARD = wp.constant(3)
INV_PI = wp.constant(0.31830988618379067)


@wp.func
def brdf_cosine_weighted(kind: int, params: wp.array2d(dtype=wp.float32), m: int,
                         n: wp.vec3, wi: wp.vec3, wo: wp.vec3) -> wp.vec3:
    """f_r(n, ωi, ωo)·(n·ωi)⁺(n·ωo)⁺ for material row m of the packed table (see warp_biscale.brdf)."""
    ci = wp.dot(n, wi)
    co = wp.dot(n, wo)
    if ci <= 0.0 or co <= 0.0:
        return wp.vec3(0.0)
    kd = wp.vec3(params[m, 0], params[m, 1], params[m, 2])
    ks = wp.vec3(params[m, 3], params[m, 4], params[m, 5])
    p1 = params[m, 6]
    p2 = params[m, 7]
    h = wp.normalize(wi + wo)
    nh = wp.clamp(wp.dot(n, h), -1.0, 1.0)
    hi = wp.clamp(wp.dot(h, wi), 0.0, 1.0)
    spec = float(0.0)
    if kind == BLINN_PHONG:
        spec = (p1 + 2.0) * 0.5 * INV_PI * wp.pow(wp.max(nh, 0.0), p1) * ci * co
    elif kind == COOK_TORRANCE:
        theta_h = wp.acos(nh)
        d = wp.exp(-(theta_h / p1) * (theta_h / p1))
        f = p2 + (1.0 - p2) * wp.pow(1.0 - hi, 5.0)
        ho = wp.max(hi, 1.0e-30)
        g = wp.min(1.0, wp.min(2.0 * wp.max(nh, 0.0) * co / ho, 2.0 * wp.max(nh, 0.0) * ci / ho))
        spec = f * g * d * INV_PI
    elif kind == WARD:
        if nh > 0.0:
            cos2 = nh * nh
            tan2 = (1.0 - cos2) / cos2
            a2 = p1 * p1
            spec = wp.exp(-tan2 / a2) / (4.0 * 3.14159265358979 * a2) * wp.sqrt(ci * co)
    return kd * (INV_PI * ci * co) + ks * spec


@wp.func
def lowest_bit(m: wp.uint32) -> int:
    """Index of the lowest set bit of a non-zero word."""
    return wp.bit_count((m & (~m + wp.uint32(1))) - wp.uint32(1))


@wp.func
def cube_bin(n: wp.vec3, resolution: int) -> int:
    """The cube-map bin of unit normal n at `resolution` (reference.cube_bin): face·R² + row·R + col."""
    ax = wp.abs(n[0])
    ay = wp.abs(n[1])
    az = wp.abs(n[2])
    face = int(0)
    major = float(0.0)
    u = float(0.0)
    v = float(0.0)
    if ax >= ay and ax >= az:
        face = wp.where(n[0] >= 0.0, 0, 1)
        major = ax
        u = n[1]
        v = n[2]
    elif ay >= az:
        face = wp.where(n[1] >= 0.0, 2, 3)
        major = ay
        u = n[0]
        v = n[2]
    else:
        face = wp.where(n[2] >= 0.0, 4, 5)
        major = az
        u = n[0]
        v = n[1]
    if major <= 0.0:
        major = 1.0
    r = float(resolution)
    col = wp.clamp(int(wp.floor((u / major + 1.0) * 0.5 * r)), 0, resolution - 1)
    row = wp.clamp(int(wp.floor((v / major + 1.0) * 0.5 * r)), 0, resolution - 1)
    return face * resolution * resolution + row * resolution + col
