"""Warp functions shared by several stages: the small-scale BRDFs (cosine-weighted) and bit tricks.

Mirrors ``cl/common.cl`` and ``warp_biscale.reference.brdf_cosine_weighted``; the measured (MERL) lookup
mirrors ``warp_biscale.measured.MeasuredBRDF.eval``.
"""

import warp as wp

from warp_biscale import trace as _trace

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

LAMBERT = wp.constant(0)
BLINN_PHONG = wp.constant(1)
COOK_TORRANCE = wp.constant(2)
WARD = wp.constant(3)
ANISOTROPIC_WARD = wp.constant(4)
ASHIKHMIN_SHIRLEY = wp.constant(5)
MEASURED = wp.constant(6)
INV_PI = wp.constant(0.31830988618379067)
TANGENT_DEGENERATE = wp.constant(1.0e-4)  # = brdf.TANGENT_DEGENERATE


@wp.func
def isotropic_specular(kind: int, p1: float, p2: float, ci: float, co: float, nh: float, hi: float) -> float:
    """The isotropic kinds' specular factor of ks, cosine-weighted (f_s·cos θi·cos θo / ks; 0 for the others), from
    the cosines (ci, co > 0) and nh = n·h, hi = h·ωi (see warp_biscale.brdf)."""
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
    return spec


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
    spec = isotropic_specular(kind, p1, p2, ci, co, nh, wp.clamp(wp.dot(h, wi), 0.0, 1.0))
    return kd * (INV_PI * ci * co) + ks * spec


@wp.func
def facet_tangent(n: wp.vec3, t: wp.vec3) -> wp.vec3:
    """The facet frame's unit x axis (brdf.tangent_frame): t − (t·n)n normalised, or, where that is shorter
    than √TANGENT_DEGENERATE (t within 0.01 rad of ±n), Duff et al.'s basis vector built from n alone."""
    x = t - wp.dot(t, n) * n
    l2 = wp.dot(x, x)
    if l2 < TANGENT_DEGENERATE:
        s = float(1.0)
        if n[2] < 0.0:
            s = -1.0
        a = -1.0 / (s + n[2])
        x = wp.vec3(1.0 + s * n[0] * n[0] * a, s * n[0] * n[1] * a, -s * n[0])
        l2 = wp.dot(x, x)
    return x / wp.sqrt(l2)


@wp.func
def log1p_small(x: float) -> float:
    """log(1 + x) for x > −1, accurate for small |x| in float32 (Goldberg's rewrite: u = 1 + x rounded, then
    log(u)·x/(u − 1), whose rounding errors cancel); Warp has no log1p."""
    u = 1.0 + x
    if u == 1.0:
        return x
    return wp.log(u) * x / (u - 1.0)


@wp.func
def analytic_specular(kind: int, ks: wp.vec3, p1: float, p2: float, x: wp.vec3, y: wp.vec3, n: wp.vec3,
                      wi: wp.vec3, wo: wp.vec3) -> wp.vec3:
    """f_s of an analytic kind, without the cosines, in the facet frame (x, y, n); see warp_biscale.brdf. The
    isotropic kinds as brdf_cosine_weighted's specular term over cos θi cos θo; the anisotropic Ward (p1, p2 =
    αx, αy: ks·D/(4π αx αy √(cos θi cos θo))) and Ashikhmin–Shirley (ks = Rs, p1, p2 = nu, nv:
    F(h·ωi)·√((nu+1)(nv+1))/(8π)·D/((h·ωi) max(cos θi, cos θo))). 0 where either direction is at or below the
    horizon."""
    ci = wp.dot(n, wi)
    co = wp.dot(n, wo)
    if ci <= 0.0 or co <= 0.0:
        return wp.vec3(0.0)
    h = wp.normalize(wi + wo)
    nh = wp.clamp(wp.dot(n, h), -1.0, 1.0)
    hi = wp.clamp(wp.dot(h, wi), 0.0, 1.0)
    if kind == BLINN_PHONG or kind == COOK_TORRANCE or kind == WARD:
        return ks * (isotropic_specular(kind, p1, p2, ci, co, nh, hi) / (ci * co))
    if kind != ANISOTROPIC_WARD and kind != ASHIKHMIN_SHIRLEY:  # (Lambert: no specular term)
        return wp.vec3(0.0)
    hx = wp.dot(h, x)
    hy = wp.dot(h, y)
    if kind == ANISOTROPIC_WARD:
        if nh <= 0.0:
            return wp.vec3(0.0)
        ew = (hx / p1) * (hx / p1) + (hy / p2) * (hy / p2)
        return ks * (wp.exp(-ew / (nh * nh)) / (4.0 * 3.14159265358979 * p1 * p2 * wp.sqrt(ci * co)))
    # Ashikhmin–Shirley: (n·h)^e as exp(e/2·log(1 − sin²θh)) with sin²θh from the tangential components: n·h
    # rounds to within 6e-8 of 1 in float32, which an exponent of 10^4 would turn into a 6e-4 error.
    s2 = hx * hx + hy * hy
    d = float(1.0)
    if s2 >= 1.0:
        d = 0.0
    elif s2 > 0.0:
        e = (p1 * hx * hx + p2 * hy * hy) / s2
        d = wp.exp(0.5 * e * log1p_small(-s2))
    hk = wp.max(hi, 1.0e-30)
    one = wp.vec3(1.0)
    fresnel = ks + (one - ks) * wp.pow(1.0 - hi, 5.0)
    return fresnel * (wp.sqrt((p1 + 1.0) * (p2 + 1.0)) / (8.0 * 3.14159265358979) * d / (hk * wp.max(ci, co)))


@wp.func
def ashikhmin_shirley_diffuse(kd: wp.vec3, ks: wp.vec3, ci: float, co: float) -> wp.vec3:
    """Ashikhmin–Shirley's ρd = 28 Rd/(23π)·(1 − Rs)·(1 − (1 − cos θi/2)⁵)·(1 − (1 − cos θo/2)⁵), without the
    cosines (kd = Rd, ks = Rs)."""
    gi = 1.0 - wp.pow(1.0 - 0.5 * ci, 5.0)
    go = 1.0 - wp.pow(1.0 - 0.5 * co, 5.0)
    return wp.cw_mul(kd, wp.vec3(1.0) - ks) * (28.0 / (23.0 * 3.14159265358979) * gi * go)


@wp.func
def brdf_cosine_weighted_tangent(kind: int, params: wp.array2d(dtype=wp.float32), m: int,
                                 n: wp.vec3, t: wp.vec3, wi: wp.vec3, wo: wp.vec3) -> wp.vec3:
    """brdf_cosine_weighted for the anisotropic kinds, in the facet frame of tangent t (any vector off n):
    the anisotropic Ward (p1, p2 = αx, αy) and Ashikhmin–Shirley (row [Rd, Rs, nu, nv]); see
    warp_biscale.brdf. Any other kind is brdf_cosine_weighted itself."""
    if kind != ANISOTROPIC_WARD and kind != ASHIKHMIN_SHIRLEY:
        return brdf_cosine_weighted(kind, params, m, n, wi, wo)
    ci = wp.dot(n, wi)
    co = wp.dot(n, wo)
    if ci <= 0.0 or co <= 0.0:
        return wp.vec3(0.0)
    kd = wp.vec3(params[m, 0], params[m, 1], params[m, 2])
    ks = wp.vec3(params[m, 3], params[m, 4], params[m, 5])
    x = facet_tangent(n, t)
    spec = analytic_specular(kind, ks, params[m, 6], params[m, 7], x, wp.cross(n, x), n, wi, wo)
    diffuse = kd * INV_PI
    if kind == ASHIKHMIN_SHIRLEY:
        diffuse = ashikhmin_shirley_diffuse(kd, ks, ci, co)
    return (diffuse + spec) * (ci * co)


# The MERL grid (warp_biscale.measured): 90 θh × 90 θd × 180 φd samples of 3 floats, one table a slot.
MERL_RES_TH = wp.constant(90)
MERL_RES_TD = wp.constant(90)
MERL_RES_PD = wp.constant(180)
MERL_TABLE_FLOATS = wp.constant(4374000)  # 3·90·90·180
HALF_PI = wp.constant(1.5707963267948966)
PI_F = wp.constant(3.141592653589793)


@wp.func
def merl_sample(tables: wp.array(dtype=wp.float32), base: int, i: int, j: int, k: int) -> wp.vec3:
    """f_r (RGB, scaled) of sample (i, j, k) of the table at `base` (MeasuredBRDF.kernel_table's layout)."""
    s = base + ((i * MERL_RES_TD + j) * MERL_RES_PD + k) * 3
    return wp.vec3(tables[s], tables[s + 1], tables[s + 2])


@wp.func
def merl_nodes(c: float, res: int) -> wp.vec2:
    """(i0, w): the lower node around continuous index c on an axis of `res` bin centres at i + ½, and the
    weight of i0 + 1, clamped at the ends (measured._clamped_nodes of c − ½)."""
    u = wp.clamp(c - 0.5, 0.0, float(res - 1))
    i0 = wp.min(int(wp.floor(u)), res - 2)
    return wp.vec2(float(i0), u - float(i0))


@wp.func
def measured_cosine_weighted(params: wp.array2d(dtype=wp.float32), m: int, n: wp.vec3, wi: wp.vec3,
                             wo: wp.vec3, tables: wp.array(dtype=wp.float32)) -> wp.vec3:
    """f_r(n, ωi, ωo)·(n·ωi)⁺(n·ωo)⁺ of the measured BRDF of row m ([slot, mode, ...]), as MeasuredBRDF.eval:
    Duff et al.'s tangent frame about n, Rusinkiewicz's angles by atan2 of a sine and a cosine (acos loses
    the digits of θh next to the specular peak), φd folded into [0, π) by reciprocity, BRDFRead.cpp's index
    axes (θh's a square root), then the nearest bin (mode 1) or trilinear interpolation between bin centres
    (mode 0; periodic in φd, clamped in θh and θd) of `tables` (MeasuredBRDF.kernel_table)."""
    ci = wp.dot(n, wi)
    co = wp.dot(n, wo)
    if ci <= 0.0 or co <= 0.0:
        return wp.vec3(0.0)
    sg = float(1.0)
    if n[2] < 0.0:
        sg = -1.0
    a = -1.0 / (sg + n[2])
    b = n[0] * n[1] * a
    t = wp.vec3(1.0 + sg * n[0] * n[0] * a, sg * b, -sg * n[0])
    bt = wp.vec3(b, sg + n[1] * n[1] * a, -n[1])
    x = wp.dot(wi, t)
    y = wp.dot(wi, bt)
    z = ci
    h = wp.normalize(wp.vec3(x + wp.dot(wo, t), y + wp.dot(wo, bt), z + co))
    s = wp.sqrt(h[0] * h[0] + h[1] * h[1])  # sin θh
    theta_h = wp.atan2(s, h[2])
    cos_phi = float(1.0)
    sin_phi = float(0.0)
    if s > 0.0:
        cos_phi = h[0] / s
        sin_phi = h[1] / s
    dx = h[2] * (x * cos_phi + y * sin_phi) - s * z
    dy = y * cos_phi - x * sin_phi
    dz = x * h[0] + y * h[1] + z * h[2]
    theta_d = wp.atan2(wp.sqrt(dx * dx + dy * dy), dz)
    phi_d = wp.atan2(dy, dx)
    if phi_d < 0.0:
        phi_d = phi_d + PI_F
    ch = wp.sqrt(wp.max(theta_h, 0.0) / HALF_PI) * float(MERL_RES_TH)
    cd = theta_d / HALF_PI * float(MERL_RES_TD)
    cp = phi_d / PI_F * float(MERL_RES_PD)
    base = int(params[m, 0]) * MERL_TABLE_FLOATS
    f = wp.vec3(0.0)
    if params[m, 1] != 0.0:  # nearest: the bin holding the query (BRDFRead.cpp)
        i = wp.clamp(int(wp.floor(ch)), 0, MERL_RES_TH - 1)
        j = wp.clamp(int(wp.floor(cd)), 0, MERL_RES_TD - 1)
        k = wp.clamp(int(wp.floor(cp)), 0, MERL_RES_PD - 1)
        f = merl_sample(tables, base, i, j, k)
    else:
        nh = merl_nodes(ch, MERL_RES_TH)
        nd = merl_nodes(cd, MERL_RES_TD)
        i0 = int(nh[0])
        j0 = int(nd[0])
        wh = nh[1]
        wd = nd[1]
        u = cp - 0.5
        kf = wp.floor(u)
        wpd = u - kf
        k0 = int(kf)
        if k0 < 0:
            k0 = k0 + MERL_RES_PD
        if k0 >= MERL_RES_PD:
            k0 = k0 - MERL_RES_PD
        k1 = k0 + 1
        if k1 >= MERL_RES_PD:
            k1 = 0
        for di in range(2):
            fi = 1.0 - wh
            if di == 1:
                fi = wh
            for dj in range(2):
                fj = 1.0 - wd
                if dj == 1:
                    fj = wd
                lo = merl_sample(tables, base, i0 + di, j0 + dj, k0)
                hi = merl_sample(tables, base, i0 + di, j0 + dj, k1)
                f = f + (fi * fj) * ((1.0 - wpd) * lo + wpd * hi)
    return f * (ci * co)


@wp.func
def material_cosine_weighted(kind: int, params: wp.array2d(dtype=wp.float32), m: int, n: wp.vec3, t: wp.vec3,
                             wi: wp.vec3, wo: wp.vec3, tables: wp.array(dtype=wp.float32)) -> wp.vec3:
    """f_r·(n·ωi)⁺(n·ωo)⁺ of material row m, any kind: the measured lookup, the anisotropic kinds in the
    frame of tangent t (read by those only), the isotropic ones (brdf_cosine_weighted). The dispatcher of
    the stages that take measured BRDFs (the ground truth, its interreflection, the matrix method's M)."""
    if kind == MEASURED:
        return measured_cosine_weighted(params, m, n, wi, wo, tables)
    if kind == ANISOTROPIC_WARD or kind == ASHIKHMIN_SHIRLEY:
        return brdf_cosine_weighted_tangent(kind, params, m, n, t, wi, wo)
    return brdf_cosine_weighted(kind, params, m, n, wi, wo)


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


@wp.func
def cell_exits(o: wp.vec3, d: wp.vec3, x0: float, y0: float, px: float, py: float) -> wp.vec2:
    """(t_x, t_y): where the ray o + t·d leaves the tile's cell [x0, x0 + px] × [y0, y0 + py] across its
    x and its y sides (1e30 when it runs parallel to them), for the periodic traces of the tile."""
    t_x = float(1.0e30)
    if d[0] > 0.0:
        t_x = wp.max((x0 + px - o[0]) / d[0], 0.0)
    elif d[0] < 0.0:
        t_x = wp.max((x0 - o[0]) / d[0], 0.0)
    t_y = float(1.0e30)
    if d[1] > 0.0:
        t_y = wp.max((y0 + py - o[1]) / d[1], 0.0)
    elif d[1] < 0.0:
        t_y = wp.max((y0 - o[1]) / d[1], 0.0)
    return wp.vec2(t_x, t_y)


@wp.func
def next_cell(o: wp.vec3, d: wp.vec3, t_exit: float, exits: wp.vec2, px: float, py: float) -> wp.vec3:
    """The ray's point at t_exit, brought back into the cell across the side(s) it left by (cell_exits)."""
    q = o + t_exit * d
    if exits[0] <= t_exit:
        q = wp.vec3(q[0] - wp.sign(d[0]) * px, q[1], q[2])
    if exits[1] <= t_exit:
        q = wp.vec3(q[0], q[1] - wp.sign(d[1]) * py, q[2])
    return q


GOLDEN_ANGLE = wp.constant(2.39996322972865)  # = trace.GOLDEN_ANGLE: the disc samples of shadow and occlusion rays
HASH_MULTIPLIER = wp.constant(wp.uint32(2654435761))  # Knuth's multiplicative hash of the pixel index


@wp.func
def disk_turn(pixel: int) -> float:
    """The pixel's hash angle that turns its disc samples (trace.disk_sample)."""
    h = wp.uint32(pixel) * HASH_MULTIPLIER
    return float(int(h >> wp.uint32(8))) * (2.0 * 3.14159265358979 / 16777216.0)


@wp.func
def disk_sample(i: int, samples: int, pixel: int) -> wp.vec2:
    """Sample i of `samples` on the unit disc: a Vogel spiral turned by a per-pixel angle (trace.disk_sample),
    so that neighbouring pixels' penumbrae are noise rather than bands. The centre for one sample."""
    if samples == 1:
        return wp.vec2(0.0, 0.0)
    turn = disk_turn(pixel)
    r = wp.sqrt((float(i) + 0.5) / float(samples))
    a = float(i) * GOLDEN_ANGLE + turn
    return wp.vec2(r * wp.cos(a), r * wp.sin(a))


@wp.func
def ray_part(samples: int, part_index: int, part_count: int) -> wp.vec2i:
    """(first, stride) of the rays anti-aliasing sample part_index of part_count traces of a set of `samples`
    (trace.ray_part)."""
    stride = wp.max(1, wp.min(part_count, samples))
    return wp.vec2i(part_index % stride, stride)


BLOCK_SLOTS = wp.constant(_trace.BLOCK_SLOTS)


@wp.func
def set_block_side(samples: int, part_count: int, block_width: int, block_side: int) -> int:
    """The side of the pixel blocks that share a set of `samples` rays (trace.block_side): 1 (each pixel its own)
    without a block width or for fewer than BLOCK_SLOTS rays, 4 where asked and samples >= 16 part_count, else 2."""
    if block_width <= 0 or samples < BLOCK_SLOTS:
        return 1
    if block_side == 4 and samples >= 16 * part_count:
        return 4
    return 2


@wp.func
def pixel_part(samples: int, part_index: int, part_count: int, block_width: int, block_side: int,
               pixel: int) -> wp.vec3i:
    """(first, stride, turn pixel) of the rays pixel `pixel` traces of a set of `samples` (trace.pixel_parts):
    where the set is shared in s x s blocks (s = set_block_side > 1), slot q = x mod s + s (y mod s) of its block
    takes part q + s^2 part_index of s^2 part_count, its rays turned by the block's first pixel, so that the block's
    pixels trace the sample's part between them; else the sample's part, turned by the pixel itself."""
    side = set_block_side(samples, part_count, block_width, block_side)
    if side > 1:
        x = pixel % block_width
        y = pixel // block_width
        slots = side * side
        part = ray_part(samples, x % side + side * (y % side) + slots * part_index, slots * part_count)
        return wp.vec3i(part[0], part[1], pixel - x % side - (y % side) * block_width)
    part = ray_part(samples, part_index, part_count)
    return wp.vec3i(part[0], part[1], pixel)


@wp.func
def part_bits(first: int, stride: int, samples: int) -> wp.uint32:
    """Bit i set for each ray i = first, first + stride, … < samples (≤ 32) of a part."""
    bits = wp.uint32(0)
    for i in range(first, samples, stride):
        bits = bits | (wp.uint32(1) << wp.uint32(i))
    return bits


@wp.func
def disk_basis(w: wp.vec3) -> wp.mat33:
    """Rows a, b, w: a right-handed frame whose third row is w (trace.disk_basis)."""
    ref = wp.vec3(0.0, 1.0, 0.0)
    if wp.abs(w[0]) < 0.9:
        ref = wp.vec3(1.0, 0.0, 0.0)
    a = wp.normalize(wp.cross(w, ref))
    return wp.matrix_from_rows(a, wp.cross(w, a), w)


@wp.func
def horizon_frame(w: wp.vec3, n: wp.vec3, apparent: float) -> wp.mat33:
    """Rows a, b and (d, 0, 0): a light's disc frame about w for shading normal n (trace.horizon_frame): where n's
    horizon cuts the disc, a is n's part across it and d = (n·w)/(apparent·|that part|) in (−1, 1), else
    disk_basis(w) and d = 2."""
    wn = wp.dot(w, n)
    across = n - wn * w
    length = wp.length(across)
    if apparent * length > wp.abs(wn):
        a = across / length
        return wp.matrix_from_rows(a, wp.cross(w, a), wp.vec3(wn / (apparent * length), 0.0, 0.0))
    basis = disk_basis(w)
    return wp.matrix_from_rows(basis[0], basis[1], wp.vec3(2.0, 0.0, 0.0))


@wp.func
def above_horizon(q: wp.vec2, d: float) -> wp.vec2:
    """Disc point q moved into the disc's part q_x > −d above the horizon (trace.above_horizon), for |d| < 1."""
    s2 = -d + 0.5 * (q[0] + 1.0) * (1.0 + d)
    return wp.vec2(s2, q[1] * wp.sqrt(wp.max(1.0 - s2 * s2, 0.0) / wp.max(1.0 - q[0] * q[0], 1.0e-12)))


@wp.func
def occlusion_direction(frame: wp.mat33, i: int, samples: int, pixel: int) -> wp.vec3:
    """Environment-occlusion ray i of `samples` (trace.occlusion_directions): disc sample i lifted to the
    hemisphere of frame's third row, cosine-distributed."""
    q = disk_sample(i, samples, pixel)
    lift = wp.sqrt(wp.max(1.0 - q[0] * q[0] - q[1] * q[1], 0.0))
    return q[0] * frame[0] + q[1] * frame[1] + lift * frame[2]


LOBE_COS_MIN = wp.constant(_trace.LOBE_COS_MIN)
LOBE_RAYS = wp.constant(_trace.LOBE_RAYS)


@wp.func
def lobe_ray_direction(frame: wp.mat33, eta: float, i: int, pixel: int) -> wp.vec3:
    """Ray i towards a sharp lobe (trace.lobe_ray_directions): disc sample i on the tangent plane at the
    lobe's axis (frame's third row), radius tan θ with 1 − cos θ = 2/η, normalised."""
    c = wp.max(1.0 - 2.0 / wp.max(eta, 1.0e-30), LOBE_COS_MIN)
    spread = wp.sqrt(1.0 - c * c) / c
    q = disk_sample(i, LOBE_RAYS, pixel)
    return wp.normalize(frame[2] + spread * (q[0] * frame[0] + q[1] * frame[1]))
