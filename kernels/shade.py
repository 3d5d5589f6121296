"""Per-pixel SG shading (Wang 2009 §7, Iwasaki 2012 §5): the shade stage.

Twin of ``cl/shade.cl``; the mathematics and the packed inputs are ``warp_biscale.shading``
(``shade_reference`` is the float64 oracle). One thread per pixel: it rebuilds the surface point
from the G-buffer (face, barycentrics), sums the environment's SG lobes and each light's SG
emitter against the diffuse part, then the warped specular lobes against the prefiltered
environment and the lights, each lobe shadowed by the SSDF (environment) or the light's shadow ray.
The specular loop runs material sub-row by sub-row here and lobe by lobe in the twin: the same values,
summed in another order, each order measured the faster on its own toolkit (bench/README.md).
"""

import math

import warp as wp

from warp_biscale import asg as _asg
from warp_biscale import device as _device
from warp_biscale import effective as _effective
from warp_biscale import lighting as _lighting
from warp_biscale import sg as _sg

from warp_biscale import shading as _shading

from .asg import (Asg, asg_convolve_asg, asg_convolve_sg, asg_eval, asg_integral_eq10, asg_unit_integral, asg_warp,
                  harmonic)
from .common import (ANISOTROPIC_WARD, ASHIKHMIN_SHIRLEY, GOLDEN_ANGLE, LOBE_COS_MIN, LOBE_RAYS, analytic_specular,
                     ashikhmin_shirley_diffuse, disk_basis, disk_turn, lobe_ray_direction, part_bits, pixel_part)

# Fast math on CUDA (approximate division, square root, exp and trigonometry): this shading is bound by its
# arithmetic, and its float32 results are read against the float64 oracle with tolerances far above fast
# math's error. cl/'s twin is built alike (opencl_backend.FAST_MATH).
# (enable_backward off: nothing here is differentiated, and backward kernels take most of the compile time)
wp.set_module_options({"fast_math": True, "enable_backward": False})

PI = wp.constant(3.14159265358979)
LOG_LO = wp.constant(_sg.TABLE_LOG10_ETA[0])
LOG_HI = wp.constant(_sg.TABLE_LOG10_ETA[1])
SHARPNESS_MAX = wp.constant(_sg.SHARPNESS_MAX)
BACKGROUND_LOG2 = wp.constant(_lighting.BACKGROUND_LOG2)
BACKGROUND_ETA = wp.constant(_lighting.BACKGROUND_ETA)
MIN_COS_VIEW = wp.constant(1.0e-4)  # = shading.MIN_COS_VIEW
ASG_LOBES = wp.constant(_effective.ASG_LOBES)  # i32_at2(eff_info, :, 7) of a material with ASG lobes
ASG_EQ10_MIN = wp.constant(_asg.EQ10_MIN_BANDWIDTH)
GOLDEN_COS = wp.constant(math.cos(GOLDEN_ANGLE))
GOLDEN_SIN = wp.constant(math.sin(GOLDEN_ANGLE))
RAYS_ONLY = wp.constant(_shading.RAYS_ONLY)
SHARP_LOBE_ETA = wp.constant(_shading.SHARP_LOBE_ETA)
SSDF_ONLY = wp.constant(_shading.SSDF_ONLY)
DIFFUSE_LEVELS = wp.constant(len(_effective.DIFFUSE_LEVEL_ETAS))  # f̄d and its prefiltered levels
DIFFUSE_LEVEL_SHARP = wp.constant(_effective.DIFFUSE_LEVEL_SHARP)
DIFFUSE_LEVEL_STEP = wp.constant(_effective.DIFFUSE_LEVEL_STEP)
AS_UNIFORM_COS = wp.constant(_shading.AS_UNIFORM_COS)
ASG_TAPS = wp.constant(_shading.ASG_TAPS)
ASG_TAP_SHARE = wp.constant(_shading.ASG_TAP_SHARE)
LIGHT_BLUR_EXP_MAX = wp.constant(_shading.LIGHT_BLUR_EXP_MAX)
MOMENT_VAR_MIN = wp.constant(_shading.MOMENT_VAR_MIN)
MOMENT_P1_STEPS = wp.constant(float(_shading.MOMENT_P1_STEPS))
TAP_SPAN = wp.constant(_shading.TAP_SPAN)
TAP_GAP = wp.constant(_shading.TAP_GAP)
ROUND_SPREAD = wp.constant(_shading.ROUND_SPREAD)
hermite_vec = wp.types.vector(length=len(_shading._HERMITE_NODES), dtype=wp.float32)
HERMITE_NODES = wp.constant(hermite_vec(*[float(x) for x in _shading._HERMITE_NODES]))
HERMITE_WEIGHTS = wp.constant(hermite_vec(*[float(x) for x in _shading._HERMITE_WEIGHTS]))
HERMITE_GAPS = wp.constant(wp.vec4(*[float(x) for x in _shading._HERMITE_GAPS]))

vec4i = wp.vec4i

# The helpers marked inline=False stay out of line (CUDA __noinline__): the shade kernel is large enough that
# fetching its instructions, not its arithmetic or memory, bounds it (half its warps' stall samples under Nsight
# Compute), and each of these bulky or hot helpers, most of them called from several sites, then exists once.
# Which helpers: the fastest set of those timed (bench/results/shade-noinline-h200-ccd6a6f); it also compiles in a
# third of the time. kernels/litsphere.py calls two of them (prefiltered, and table_rgb_cell through table_rgb).
# The OpenCL twin's helpers stay always_inline: marked noinline they were no faster on NVIDIA's OpenCL.


# Array reads with 32-bit index arithmetic, as cl/shade.cl's int indices: Warp's own indexing multiplies each
# index by its byte stride in size_t (64-bit), and this kernel gathers thousands of values a pixel; that address
# arithmetic, with work cl/ shares and Warp did not (one log per η's table row, prefiltered's angles once, one
# concentric map per grid cell: shared below too), made Warp's shade register-bound where cl/'s is not
# (bench/results/shade-h100). Same byte offsets (same strides, any layout) in int: every array here is far
# below 2 GiB.
@wp.func_native("return *(const float*)((const char*)a.data + i * a.strides[0]);")
def f32_at(a: wp.array(dtype=wp.float32), i: int) -> float: ...


@wp.func_native("return *(const float*)((const char*)a.data + (i * a.strides[0] + j * a.strides[1]));")
def f32_at2(a: wp.array2d(dtype=wp.float32), i: int, j: int) -> float: ...


@wp.func_native("return *(const float*)((const char*)a.data\n"
                "                        + (i * a.strides[0] + j * a.strides[1] + k * a.strides[2]));")
def f32_at3(a: wp.array3d(dtype=wp.float32), i: int, j: int, k: int) -> float: ...


@wp.func_native("return *(const wp::vec3*)((const char*)a.data + i * a.strides[0]);")
def vec3_at(a: wp.array(dtype=wp.vec3), i: int) -> wp.vec3: ...


@wp.func_native("return *(const int*)((const char*)a.data + (i * a.strides[0] + j * a.strides[1]));")
def i32_at2(a: wp.array2d(dtype=wp.int32), i: int, j: int) -> int: ...


@wp.func_native("return *(const unsigned char*)((const char*)a.data + (i * a.strides[0] + j * a.strides[1]));")
def u8_at2(a: wp.array2d(dtype=wp.uint8), i: int, j: int) -> wp.uint8: ...


@wp.func
def sg_integral(eta: float) -> float:
    """∫G = 2π(1 − e^{−2η})/η, with its series below η = 1e-3 (no cancellation)."""
    if eta < 1.0e-3:
        return 2.0 * PI * (2.0 - 2.0 * eta + 1.3333333 * eta * eta)
    return 2.0 * PI * (1.0 - wp.exp(-2.0 * eta)) / eta


@wp.func
def eta_row(table: wp.array3d(dtype=wp.float32), eta: float) -> float:
    """The table's fractional row at η (sg.table_lookup's first half): the lookups of one η (a lobe's cosine
    integral and its SSDF fractions) share its log, as cl/shade.cl's eta_row."""
    le = wp.clamp(wp.log(wp.max(eta, 1.0e-30)) * 0.4342944819, LOG_LO, LOG_HI)
    return (le - LOG_LO) / (LOG_HI - LOG_LO) * float(table.shape[1] - 1)


@wp.func(inline=False)
def table_lookup(table: wp.array3d(dtype=wp.float32), which: int, c: float, tr: float) -> float:
    """Bilinear in (log10 η, c), η's row tr from eta_row: sg.table_lookup."""
    rows = table.shape[1]
    cols = table.shape[2]
    tc = (wp.clamp(c, -1.0, 1.0) + 1.0) * 0.5 * float(cols - 1)
    r0 = wp.min(int(wp.floor(tr)), rows - 2)
    c0 = wp.min(int(wp.floor(tc)), cols - 2)
    fr = tr - float(r0)
    fc = tc - float(c0)
    top = (1.0 - fc) * f32_at3(table, which, r0, c0) + fc * f32_at3(table, which, r0, c0 + 1)
    bottom = (1.0 - fc) * f32_at3(table, which, r0 + 1, c0) + fc * f32_at3(table, which, r0 + 1, c0 + 1)
    return (1.0 - fr) * top + fr * bottom


@wp.func
def cosine_integral(table: wp.array3d(dtype=wp.float32), axis: wp.vec3, eta: float, tr: float,
                    n: wp.vec3) -> float:
    """∫ G(ω; axis, η, 1)(n·ω)⁺ dω, η's table row tr from eta_row."""
    return sg_integral(eta) * table_lookup(table, 0, wp.dot(axis, n), tr)


@wp.func
def beyond_horizon(table: wp.array3d(dtype=wp.float32), theta: float, axis: wp.vec3, tr: float, n: wp.vec3) -> float:
    """The share of a lobe's horizon-clipped integral left visible by the SSDF's θd at its axis:
    visible_fraction(sin θd, η) / visible_fraction(axis·n, η), clamped to [0, 1] (the horizon alone
    would give θd = asin(axis·n): the cosine integral has clipped that much already). tr: η's table row."""
    c = wp.sin(wp.clamp(theta, -0.5 * PI, 0.5 * PI))
    vis = table_lookup(table, 1, c, tr) / wp.max(table_lookup(table, 1, wp.dot(axis, n), tr), 1.0e-6)
    return wp.clamp(vis, 0.0, 1.0)


@wp.func
def direction_angles(d: wp.vec3) -> wp.vec2:
    """(θ, φ) of d, φ in [0, 2π] (environment.py's convention): prefiltered_at takes them once for both levels."""
    theta = wp.acos(wp.clamp(d[1], -1.0, 1.0))
    phi = wp.atan2(d[2], d[0])
    if phi < 0.0:
        phi = phi + 2.0 * PI
    return wp.vec2(theta, phi)


@wp.func(inline=False)
def equirect_bilinear(maps: wp.array(dtype=wp.vec3), offset: int, h: int, w: int, theta: float, phi: float) -> wp.vec3:
    """Bilinear lookup of one equirect level at polar angle θ and azimuth φ in [0, 2π] (environment.py's
    convention: wrap φ, clamp θ). φ's column lies in [−1, w − 1], so the wrap is a compare, not an integer
    remainder (which a GPU computes in tens of instructions); the clamp keeps any other φ inside the map."""
    row = theta * float(h) / PI - 0.5
    col = phi * float(w) / (2.0 * PI) - 0.5
    r0f = wp.floor(row)
    c0f = wp.floor(col)
    fr = row - r0f
    fc = col - c0f
    r0 = wp.clamp(int(r0f), 0, h - 1)
    r1 = wp.clamp(int(r0f) + 1, 0, h - 1)
    c0 = int(c0f)
    if c0 < 0:
        c0 = c0 + w
    c0 = wp.clamp(c0, 0, w - 1)
    c1 = c0 + 1
    if c1 == w:
        c1 = 0
    a = vec3_at(maps, offset + r0 * w + c0) * (1.0 - fc) + vec3_at(maps, offset + r0 * w + c1) * fc
    b = vec3_at(maps, offset + r1 * w + c0) * (1.0 - fc) + vec3_at(maps, offset + r1 * w + c1) * fc
    return a * (1.0 - fr) + b * fr


@wp.func
def equirect_bilinear_dir(maps: wp.array(dtype=wp.vec3), offset: int, h: int, w: int, d: wp.vec3) -> wp.vec3:
    """Bilinear lookup of one equirect level in direction d."""
    tp = direction_angles(d)
    return equirect_bilinear(maps, offset, h, w, tp[0], tp[1])


@wp.struct
class LevelPair:
    """The two prefiltered levels a sharpness η reads (prefiltered_levels): each one's (texel offset, H, W), and
    the second's weight."""
    a: wp.vec3i
    b: wp.vec3i
    f: float


@wp.func
def level_at(levels: wp.array2d(dtype=wp.float32), l: int) -> wp.vec3i:
    """Prefiltered level l's (texel offset, H, W), from its row of `levels`."""
    return wp.vec3i(int(f32_at2(levels, l, 1)), int(f32_at2(levels, l, 2)), int(f32_at2(levels, l, 3)))


@wp.func
def prefiltered_levels(levels: wp.array2d(dtype=wp.float32), eta: float) -> LevelPair:
    """The levels of Λ(·, η) and their weights: linear in log2 η between the two nearest (lighting.prefiltered_lookup);
    a last row marked BACKGROUND_LOG2 is read by η ≥ BACKGROUND_ETA alone (the camera's rays), and by no lobe. Found
    once for all the taps of one sharpness (asg_prefiltered)."""
    n = levels.shape[0]
    out = LevelPair()
    if n > 1 and f32_at2(levels, n - 1, 0) >= BACKGROUND_LOG2:
        if eta >= BACKGROUND_ETA:
            out.a = level_at(levels, n - 1)
            out.b = out.a
            out.f = 0.0
            return out
        n = n - 1
    t = wp.clamp(wp.log2(wp.max(eta, 1.0e-30)) - f32_at2(levels, 0, 0), 0.0, float(n - 1))
    l0 = wp.max(wp.min(int(wp.floor(t)), n - 2), 0)
    out.a = level_at(levels, l0)
    out.b = level_at(levels, wp.min(l0 + 1, n - 1))
    out.f = wp.clamp(t - float(l0), 0.0, 1.0)
    return out


@wp.func(inline=False)
def prefiltered_at(maps: wp.array(dtype=wp.vec3), lv: LevelPair, d: wp.vec3) -> wp.vec3:
    """Λ(d, η) from η's levels: each level read only where it weighs (an end of the range, the background)."""
    tp = direction_angles(d)
    out = wp.vec3(0.0)
    if lv.f < 1.0:
        out = equirect_bilinear(maps, lv.a[0], lv.a[1], lv.a[2], tp[0], tp[1]) * (1.0 - lv.f)
    if lv.f > 0.0:
        out = out + equirect_bilinear(maps, lv.b[0], lv.b[1], lv.b[2], tp[0], tp[1]) * lv.f
    return out


@wp.func
def prefiltered(maps: wp.array(dtype=wp.vec3), levels: wp.array2d(dtype=wp.float32), d: wp.vec3, eta: float) -> wp.vec3:
    """Λ(d, η) (lighting.prefiltered_lookup)."""
    return prefiltered_at(maps, prefiltered_levels(levels, eta), d)


@wp.func(inline=False)
def ssdf_theta(basis: wp.array2d(dtype=wp.float32), coeffs: wp.array2d(dtype=wp.float32), i0: int, i1: int, i2: int,
               w0: float, w1: float, w2: float, res: int, d: wp.vec3) -> float:
    """θd(d) from the PCA basis and the barycentric blend of three vertices' coefficients
    (octahedral map, fold along z, bilinear clamped: reference.ssdf_eval)."""
    s = wp.abs(d[0]) + wp.abs(d[1]) + wp.abs(d[2])
    px = d[0] / s
    py = d[1] / s
    if d[2] < 0.0:
        sx = 1.0
        if px < 0.0:
            sx = -1.0
        sy = 1.0
        if py < 0.0:
            sy = -1.0
        qx = (1.0 - wp.abs(py)) * sx
        qy = (1.0 - wp.abs(px)) * sy
        px = qx
        py = qy
    x = wp.clamp((px + 1.0) * 0.5 * float(res) - 0.5, 0.0, float(res - 1))
    y = wp.clamp((py + 1.0) * 0.5 * float(res) - 0.5, 0.0, float(res - 1))
    x0 = wp.min(int(wp.floor(x)), res - 1)
    y0 = wp.min(int(wp.floor(y)), res - 1)
    x1 = wp.min(x0 + 1, res - 1)
    y1 = wp.min(y0 + 1, res - 1)
    fx = x - float(x0)
    fy = y - float(y0)
    k00 = y0 * res + x0
    k10 = y0 * res + x1
    k01 = y1 * res + x0
    k11 = y1 * res + x1
    w00 = (1.0 - fx) * (1.0 - fy)
    w10 = fx * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w11 = fx * fy
    theta = float(0.0)
    for r in range(basis.shape[1]):  # basis is texel-major (res², terms + 1): contiguous per corner
        c = float(1.0)
        if r > 0:
            c = w0 * f32_at2(coeffs, i0, r - 1) + w1 * f32_at2(coeffs, i1, r - 1) + w2 * f32_at2(coeffs, i2, r - 1)
        theta = theta + c * (w00 * f32_at2(basis, k00, r) + w10 * f32_at2(basis, k10, r)
                             + w01 * f32_at2(basis, k01, r) + w11 * f32_at2(basis, k11, r))
    return theta


@wp.func(inline=False)
def concentric_uv(w: wp.vec3) -> wp.vec2:
    """directions.hemisphere_to_square (z clamped to [0, 1])."""
    z = wp.clamp(w[2], 0.0, 1.0)
    r = wp.sqrt(1.0 - z)
    phi = wp.atan2(w[1], w[0])
    if phi < -0.25 * PI:
        phi = phi + 2.0 * PI
    q = 0.25 * PI
    a = float(0.0)
    b = float(0.0)
    if phi < q:
        a = r
        b = phi * a / q
    elif phi < 3.0 * q:
        b = r
        a = -(phi - 0.5 * PI) * b / q
    elif phi < 5.0 * q:
        a = -r
        b = (phi - PI) * a / q
    else:
        b = -r
        a = -(phi - 1.5 * PI) * b / q
    return wp.vec2((a + 1.0) * 0.5, (b + 1.0) * 0.5)


@wp.struct
class GridCell:
    """The four K×K grid indices around a direction, their bilinear weights and their directions' cos θ."""
    idx: vec4i
    wgt: wp.vec4
    cos: wp.vec4


@wp.func
def grid_bilinear(w: wp.vec3, k: int) -> GridCell:
    """grid_corners and grid_weights from one concentric map (cl/shade.cl's grid_bilinear)."""
    uv = concentric_uv(w)
    x = wp.clamp(uv[0] * float(k) - 0.5, 0.0, float(k - 1))
    y = wp.clamp(uv[1] * float(k) - 0.5, 0.0, float(k - 1))
    x0 = wp.min(int(wp.floor(x)), k - 1)
    y0 = wp.min(int(wp.floor(y)), k - 1)
    x1 = wp.min(x0 + 1, k - 1)
    y1 = wp.min(y0 + 1, k - 1)
    tx = x - float(x0)
    ty = y - float(y0)
    g = GridCell()
    g.idx = vec4i(y0 * k + x0, y0 * k + x1, y1 * k + x0, y1 * k + x1)
    g.wgt = wp.vec4((1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty)
    # cos θ of the four cells (directions.grid: 1 − r², r the cell centre's concentric radius) from their
    # column and row, with no integer division by K.
    ax0 = wp.abs(2.0 * (float(x0) + 0.5) / float(k) - 1.0)
    ax1 = wp.abs(2.0 * (float(x1) + 0.5) / float(k) - 1.0)
    by0 = wp.abs(2.0 * (float(y0) + 0.5) / float(k) - 1.0)
    by1 = wp.abs(2.0 * (float(y1) + 0.5) / float(k) - 1.0)
    r00 = wp.max(ax0, by0)
    r10 = wp.max(ax1, by0)
    r01 = wp.max(ax0, by1)
    r11 = wp.max(ax1, by1)
    g.cos = wp.vec4(1.0 - r00 * r00, 1.0 - r10 * r10, 1.0 - r01 * r01, 1.0 - r11 * r11)
    return g


@wp.func
def grid_corners(w: wp.vec3, k: int) -> vec4i:
    """The four K×K grid indices around w (directions.bilinear_corners' order)."""
    return grid_bilinear(w, k).idx


@wp.func
def grid_weights(w: wp.vec3, k: int) -> wp.vec4:
    return grid_bilinear(w, k).wgt


@wp.func
def table_rgb(table: wp.array(dtype=wp.float32), base: int, k2: int, j_count: int, j: int, wi_local: wp.vec3, k: int,
              oo: vec4i, ow: wp.vec4) -> wp.vec3:
    """Bilinear (ωi) × bilinear (ωo) lookup of value/cos θi in a (K², K², J, 3) table of values at lobe j:
    the division by each ωi corner's cos θi is done here, so that a bake's tables are read as they are
    (no host copy per edit)."""
    g = grid_bilinear(wi_local, k)
    return table_rgb_cell(table, base, k2, j_count, j, g.idx, wp.cw_div(g.wgt, g.cos), oo, ow)


@wp.func(inline=False)
def table_rgb_cell(table: wp.array(dtype=wp.float32), base: int, k2: int, j_count: int, j: int, ii: vec4i,
                   iw_cos: wp.vec4, oo: vec4i, ow: wp.vec4) -> wp.vec3:
    """table_rgb at ωi's grid cell: its corners ii and their bilinear weights over their cos θ (grid_bilinear's
    idx and wgt / cos), for callers that read several tables at one ωi."""
    out = wp.vec3(0.0)
    for a in range(4):
        wa = iw_cos[a]
        for b in range(4):
            idx = base + ((ii[a] * k2 + oo[b]) * j_count + j) * 3
            wgt = wa * ow[b]
            out = out + wgt * wp.vec3(f32_at(table, idx), f32_at(table, idx + 1), f32_at(table, idx + 2))
    return out


@wp.func
def diffuse_level(eta: float) -> int:
    """The level of an effective material's energy that a lobe of sharpness η reads: the nearest in log η,
    round(log8(64/η)) in [0, L − 1] (effective.diffuse_level)."""
    u = wp.clamp(wp.log(DIFFUSE_LEVEL_SHARP / wp.max(eta, 1.0e-30)) / wp.log(DIFFUSE_LEVEL_STEP), 0.0,
                 float(DIFFUSE_LEVELS - 1))
    return int(u + 0.5)


@wp.func
def effective_diffuse(eff_info: wp.array2d(dtype=wp.int32), eff_sub: wp.array2d(dtype=wp.float32),
                      eff_diffuse: wp.array(dtype=wp.float32), idx: int, k2: int, eta: float, wi_local: wp.vec3, k: int,
                      oo: vec4i, ow: wp.vec4) -> wp.vec3:
    """An effective material's f̄d/cos θ as a lobe of sharpness η sees it: Σ_m kd_m/π ⊙ material m's energy at
    the lobe's level (diffuse_level)."""
    out = wp.vec3(0.0)
    level = diffuse_level(eta)
    g = grid_bilinear(wi_local, k)  # (one ωi for every material's table)
    iw_cos = wp.cw_div(g.wgt, g.cos)
    for sub_i in range(i32_at2(eff_info, idx, 2)):
        sub = i32_at2(eff_info, idx, 4) + sub_i
        kd = wp.vec3(f32_at2(eff_sub, sub, 1), f32_at2(eff_sub, sub, 2), f32_at2(eff_sub, sub, 3)) / PI
        base = i32_at2(eff_info, idx, 6) + (sub_i * DIFFUSE_LEVELS + level) * k2 * k2 * 3
        out = out + wp.cw_mul(kd, table_rgb_cell(eff_diffuse, base, k2, 1, 0, g.idx, iw_cos, oo, ow))
    return out


@wp.func
def specular_scale(kind: int, ks: wp.vec3, p1: float, p2: float, cos_d_in: float) -> wp.vec3:
    """M of an analytic BRDF's values at cos θd (shading.specular_scale). Values, not a row index: a
    textured material's ks and p1 differ per pixel."""
    cos_d = wp.clamp(cos_d_in, MIN_COS_VIEW, 1.0)
    if kind == 1:
        return ks * ((p1 + 2.0) / (2.0 * PI))
    if kind == 2:
        e = 1.0 - cos_d
        fres = p2 + (1.0 - p2) * e * e * e * e * e
        return ks * (fres / (PI * cos_d * cos_d))
    if kind == 3:
        return ks / (4.0 * PI * p1 * p1 * cos_d)
    if kind == ANISOTROPIC_WARD:
        return ks / (4.0 * PI * p1 * p2 * cos_d)
    if kind == ASHIKHMIN_SHIRLEY:
        e = 1.0 - cos_d
        f5 = e * e * e * e * e
        return (ks + (wp.vec3(1.0) - ks) * f5) * (wp.sqrt((p1 + 1.0) * (p2 + 1.0)) / (8.0 * PI * cos_d * cos_d))
    return wp.vec3(0.0)


@wp.func
def ndf_sharpness(kind: int, p1: float) -> float:
    if kind == 1:
        return p1
    return 2.0 / (p1 * p1)


@wp.func(inline=False)
def texture_bilinear(tex_info: wp.array2d(dtype=wp.int32), tex_data: wp.array(dtype=wp.vec3), slot: int,
                     uv: wp.vec2) -> wp.vec3:
    """Bilinear, repeat-wrapped lookup of texture `slot` (svbrdf.sample: texel (i, j) centred at
    ((j + ½)/W, (i + ½)/H), row 0 at v = 0)."""
    off = tex_info[slot, 0]
    h = tex_info[slot, 1]
    w = tex_info[slot, 2]
    x = uv[0] * float(w) - 0.5
    y = uv[1] * float(h) - 0.5
    x0f = wp.floor(x)
    y0f = wp.floor(y)
    fx = x - x0f
    fy = y - y0f
    j0 = ((int(x0f) % w) + w) % w
    i0 = ((int(y0f) % h) + h) % h
    j1 = (j0 + 1) % w
    i1 = (i0 + 1) % h
    top = tex_data[off + i0 * w + j0] * (1.0 - fx) + tex_data[off + i0 * w + j1] * fx
    bottom = tex_data[off + i1 * w + j0] * (1.0 - fx) + tex_data[off + i1 * w + j1] * fx
    return top * (1.0 - fy) + bottom * fy


@wp.func
def specular_correction(tex_info: wp.array2d(dtype=wp.int32), tex_data: wp.array(dtype=wp.vec3), slot: int,
                        wo_local: wp.vec3, kind: int, p1_factor: float) -> wp.vec3:
    """An analytic row's environment-lobe scale c(ωo) (shading.specular_correction), its texture read at
    shading.correction_uv: φo folded into [0, π/2] (an isotropic row's columns: its parameter map's p1_factor, from
    the first factor its moment table at slot + 1 keeps), cos θo, each clamped to the texel centres."""
    h = float(tex_info[slot, 1])
    w = float(tex_info[slot, 2])
    u = wp.atan2(wp.abs(wo_local[1]), wp.abs(wo_local[0])) / (0.5 * PI)
    if w > 1.0 and kind != ANISOTROPIC_WARD and kind != ASHIKHMIN_SHIRLEY:
        first = tex_data[tex_info[slot + 1, 0] + tex_info[slot + 1, 2] // 2][2]
        u = (wp.clamp(MOMENT_P1_STEPS * (wp.log2(wp.max(p1_factor, 1.0e-30)) - first), 0.0, w - 1.0) + 0.5) / w
    u = wp.clamp(u, 0.5 / w, 1.0 - 0.5 / w)
    v = wp.clamp(wo_local[2], 0.5 / h, 1.0 - 0.5 / h)
    return texture_bilinear(tex_info, tex_data, slot, wp.vec2(u, v))


@wp.func
def light_axis(lights: wp.array2d(dtype=wp.float32), l: int, pos: wp.vec3) -> wp.vec3:
    if f32_at2(lights, l, 0) == 0.0:
        return wp.vec3(f32_at2(lights, l, 1), f32_at2(lights, l, 2), f32_at2(lights, l, 3))
    return wp.normalize(wp.vec3(f32_at2(lights, l, 1), f32_at2(lights, l, 2), f32_at2(lights, l, 3)) - pos)


@wp.func
def light_sharpness(lights: wp.array2d(dtype=wp.float32), l: int, pos: wp.vec3) -> float:
    """η = 2π/Ω (scene.light_sg)."""
    omega = f32_at2(lights, l, 7)
    if f32_at2(lights, l, 0) != 0.0:
        d = wp.length(wp.vec3(f32_at2(lights, l, 1), f32_at2(lights, l, 2), f32_at2(lights, l, 3)) - pos)
        omega = PI * f32_at2(lights, l, 7) * f32_at2(lights, l, 7) / wp.max(d * d, 1.0e-30)
    return 2.0 * PI / wp.max(omega, 1.0e-6)


@wp.func
def light_amplitude(lights: wp.array2d(dtype=wp.float32), l: int, pos: wp.vec3, eta: float) -> wp.vec3:
    """μ with ∫G = the irradiance at normal incidence."""
    power = wp.vec3(f32_at2(lights, l, 4), f32_at2(lights, l, 5), f32_at2(lights, l, 6))
    if f32_at2(lights, l, 0) != 0.0:
        d = wp.length(wp.vec3(f32_at2(lights, l, 1), f32_at2(lights, l, 2), f32_at2(lights, l, 3)) - pos)
        power = power / wp.max(d * d, 1.0e-30)
    return power / sg_integral(eta)


@wp.func
def light_irradiance(table: wp.array3d(dtype=wp.float32), lights: wp.array2d(dtype=wp.float32), l: int,
                     pos: wp.vec3, n: wp.vec3, axis: wp.vec3, eta: float, vis: wp.uint8) -> wp.vec3:
    """Light l's irradiance at a point of normal n, its cosine included (the light SG's cosine integral), times
    the share of its shadow rays that reached it (vis, in 255ths; the rays aim at the part of the light above the
    horizon, as the cosine integral counts it: trace_shadows); axis and η: light_axis, light_sharpness."""
    return light_amplitude(lights, l, pos, eta) * (
        cosine_integral(table, axis, eta, eta_row(table, eta), n) * float(int(vis)) / 255.0)


@wp.func
def product_integral(table: wp.array3d(dtype=wp.float32), a1: wp.vec3, e1: float, a2: wp.vec3, e2: float,
                     n: wp.vec3) -> float:
    """∫ G(a1, e1)·G(a2, e2)·(n·ω)⁺: the product SG (sg.product) against the clamped cosine."""
    v = e1 * a1 + e2 * a2
    s = a1 + a2
    d = wp.sqrt(wp.max((e1 - e2) * (e1 - e2) + e1 * e2 * wp.dot(s, s), 0.0))
    diff = a1 - a2
    gap = e1 * e2 * wp.dot(diff, diff) / (e1 + e2 + d)
    axis = wp.vec3(0.0, 0.0, 1.0)
    if wp.length(v) > 0.0:
        axis = wp.normalize(v)
    return wp.exp(-gap) * cosine_integral(table, axis, d, eta_row(table, d), n)


@wp.struct
class SurfacePoint:
    """A pixel's surface point rebuilt from the G-buffer: position, shading frame (t, b, n) and the
    face's vertices with their barycentric weights (for the per-vertex SSDF)."""
    pos: wp.vec3
    n: wp.vec3
    t: wp.vec3
    b: wp.vec3
    i0: wp.int32
    i1: wp.int32
    i2: wp.int32
    w0: wp.float32
    w1: wp.float32
    w2: wp.float32


@wp.func
def camera_ray(camera: wp.array(dtype=wp.float32), p: int) -> wp.vec3:
    """The direction through pixel p's centre (Camera.packed: eye, forward, right, up, width, height)."""
    width = int(camera[12])
    x = float(p % width)
    y = float(p // width)
    return wp.normalize(wp.vec3(camera[3], camera[4], camera[5])
                        + (2.0 * (x + 0.5) / camera[12] - 1.0) * wp.vec3(camera[6], camera[7], camera[8])
                        + (1.0 - 2.0 * (y + 0.5) / camera[13]) * wp.vec3(camera[9], camera[10], camera[11]))


@wp.func
def surface_point(faces: wp.array2d(dtype=wp.int32), positions: wp.array(dtype=wp.vec3),
                  normals: wp.array(dtype=wp.vec3), tangents: wp.array(dtype=wp.vec3), f: int,
                  bary: wp.vec2) -> SurfacePoint:
    """The interpolated position and normal, and the tangent made orthogonal to the normal (any
    perpendicular where the mesh's tangent is parallel to it or zero)."""
    s = SurfacePoint()
    s.i0 = faces[f, 0]
    s.i1 = faces[f, 1]
    s.i2 = faces[f, 2]
    s.w1 = bary[0]
    s.w2 = bary[1]
    s.w0 = 1.0 - s.w1 - s.w2
    s.pos = s.w0 * positions[s.i0] + s.w1 * positions[s.i1] + s.w2 * positions[s.i2]
    n = wp.normalize(s.w0 * normals[s.i0] + s.w1 * normals[s.i1] + s.w2 * normals[s.i2])
    t = s.w0 * tangents[s.i0] + s.w1 * tangents[s.i1] + s.w2 * tangents[s.i2]
    t = t - wp.dot(t, n) * n
    if wp.length(t) < 1.0e-12:
        ref = wp.vec3(0.0, 0.0, 1.0)
        if wp.abs(n[0]) < 0.9:
            ref = wp.vec3(1.0, 0.0, 0.0)
        t = ref - wp.dot(ref, n) * n
    t = wp.normalize(t)
    s.n = n
    s.t = t
    s.b = wp.cross(n, t)
    return s


@wp.func
def seen_from_behind(a: wp.vec3, b: wp.vec3, c: wp.vec3, n: wp.vec3, wo: wp.vec3) -> bool:
    """The viewer lies behind triangle abc's plane, on the side its shading normal n turns from: a back face."""
    ng = wp.cross(b - a, c - a)
    return wp.dot(ng, n) * wp.dot(ng, wo) < 0.0


@wp.func
def to_local(s: SurfacePoint, d: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.dot(d, s.t), wp.dot(d, s.b), wp.dot(d, s.n))


@wp.func
def ndf_bandwidths(kind: int, p1: float, p2: float) -> wp.vec2:
    """(λ, μ) of an anisotropic BRDF's NDF as one ASG (brdf.ndf_bandwidths)."""
    if kind == ANISOTROPIC_WARD:
        return wp.vec2(1.0 / (p1 * p1), 1.0 / (p2 * p2))
    return wp.vec2(0.5 * p1, 0.5 * p2)


@wp.func
def ndf_asg(kind: int, p1: float, p2: float, s: SurfacePoint) -> Asg:
    """An anisotropic BRDF's NDF as one ASG about the shading normal, in the frame of the mesh tangent,
    amplitude 1."""
    bw = ndf_bandwidths(kind, p1, p2)
    g = Asg()
    g.x = s.t
    g.y = s.b
    g.z = s.n
    g.c = 1.0
    g.lam = bw[0]
    g.mu = bw[1]
    return g


@wp.func
def warped_ndf(kind: int, p1: float, p2: float, s: SurfacePoint, wo: wp.vec3) -> Asg:
    """ndf_asg warped to the light directions (Xu Eq. 23–26), its bandwidths at least 1e−6."""
    w = asg_warp(ndf_asg(kind, p1, p2, s), wo)
    w.lam = wp.max(w.lam, 1.0e-6)
    w.mu = wp.max(w.mu, 1.0e-6)
    return w


@wp.func
def small_scale_convolved(g: Asg, kind: int, p1: float, p2: float, eta_s: float, oc: float, os: float) -> Asg:
    """An effective material's ASG lobe convolved with its small-scale BRDF's NDF: an anisotropic one's ASG turned
    by the lobe's tangent order (oc, os) (asg.convolve_asg), else its SG (Xu Eq. 18)."""
    if kind == ANISOTROPIC_WARD or kind == ASHIKHMIN_SHIRLEY:
        bw = ndf_bandwidths(kind, p1, p2)
        return asg_convolve_asg(g, bw[0], bw[1], oc, os)
    return asg_convolve_sg(g, eta_s, 1.0)


@wp.func
def lobe_cosine(c: float, eta: float) -> float:
    """The cosine at which Ashikhmin–Shirley's ρd is read for a light lobe (shading.lobe_cosine)."""
    r = eta / 3.0 - eta * eta * eta / 45.0
    if eta >= 1.0e-2:
        e2 = wp.exp(-2.0 * eta)
        r = (1.0 + e2) / (1.0 - e2) - 1.0 / eta
    return r * wp.max(c, 0.0) + (1.0 - r) * AS_UNIFORM_COS


@wp.func
def analytic_diffuse(kind: int, kd: wp.vec3, ks: wp.vec3, axis: wp.vec3, eta: float, s: SurfacePoint,
                     cos_o: float) -> wp.vec3:
    """f_d of an analytic material towards a light lobe: kd/π, or Ashikhmin–Shirley's ρd (kd = Rd/π here) at the
    lobe's cosine."""
    if kind == ASHIKHMIN_SHIRLEY:
        return ashikhmin_shirley_diffuse(kd * PI, ks, lobe_cosine(wp.dot(axis, s.n), eta), cos_o)
    return kd


@wp.func
def ray_weight(eta: float, samples: int) -> float:
    """The occlusion rays' weight against the SSDF's for a lobe of sharpness η (shading.ray_weight): exactly 1 at
    η ≤ lo and 0 at η ≥ hi, whatever fast math makes of the logarithms' ratio there."""
    if samples == 0:
        return 0.0
    lo = RAYS_ONLY * float(samples)
    hi = SSDF_ONLY * float(samples)
    if eta <= lo:
        return 1.0
    if eta >= hi:
        return 0.0
    return wp.clamp(wp.log(hi / wp.max(eta, 1.0e-30)) / wp.log(hi / lo), 0.0, 1.0)


@wp.func(inline=False)
def ray_share(axis: wp.vec3, eta: float, n: wp.vec3, frame: wp.mat33, mask: wp.uint32, samples: int,
              known: wp.uint32, turn: wp.vec2, disk_radii: wp.array(dtype=wp.vec3)) -> float:
    """The lobe's share that the pixel's occlusion rays see unblocked (shading.ray_share): the rays of `known`
    (bit i: ray i was traced, by the pixel or a block neighbour that lends it its rays), their directions made
    again (occlusion_direction about frame's third row, the geometric normal, turned by the angle whose cosine
    and sine are `turn`), each weighted by G(ω)(n·ω)⁺/(ng·ω). The spiral's angle steps by the golden angle, so
    its cosine and sine are turned by a fixed rotation from one ray to the next; each ray's radius, lift and
    1/lift come from disk_radii (trace.disk_radii)."""
    total = float(0.0)
    seen = float(0.0)
    c = turn[0]
    s = turn[1]
    first = samples * (samples - 1) // 2
    ax = wp.dot(frame[0], axis)  # the axis and the shading normal in the rays' frame
    ay = wp.dot(frame[1], axis)
    az = wp.dot(frame[2], axis)
    nx = wp.dot(frame[0], n)
    ny = wp.dot(frame[1], n)
    nz = wp.dot(frame[2], n)
    for i in range(samples):
        if ((known >> wp.uint32(i)) & wp.uint32(1)) != wp.uint32(0):
            ray = disk_radii[first + i]
            x = ray[0] * c
            y = ray[0] * s
            lift = ray[1]
            w = wp.exp(eta * (x * ax + y * ay + lift * az - 1.0)) * wp.max(x * nx + y * ny + lift * nz, 0.0) * ray[2]
            total = total + w
            if ((mask >> wp.uint32(i)) & wp.uint32(1)) == wp.uint32(0):
                seen = seen + w
        c_next = c * GOLDEN_COS - s * GOLDEN_SIN
        s = s * GOLDEN_COS + c * GOLDEN_SIN
        c = c_next
    if total > 1.0e-30:
        return seen / total
    return 1.0


vec6 = wp.types.vector(length=6, dtype=wp.float32)


@wp.func(inline=False)
def axis_ray_shares(eta: float, n: wp.vec3, frame: wp.mat33, mask: wp.uint32, samples: int, known: wp.uint32,
                    turn: wp.vec2, disk_radii: wp.array(dtype=wp.vec3)) -> vec6:
    """ray_share for the six lobes of sharpness η along +y, −y, +x, −x, +z, −z (shading.axis_lobe_start) in one
    walk of the rays: a ray's weight towards ±x is exp(−η)·exp(±η ω_x) times its lobe-free factor, so three
    exponentials and their reciprocals serve all six."""
    total = vec6(0.0)
    seen = vec6(0.0)
    c = turn[0]
    s = turn[1]
    first = samples * (samples - 1) // 2
    nx = wp.dot(frame[0], n)
    ny = wp.dot(frame[1], n)
    nz = wp.dot(frame[2], n)
    fall = wp.exp(-eta)  # (G's exp(−η), kept so that the 1e-30 floor on the total means what it does in ray_share)
    for i in range(samples):
        if ((known >> wp.uint32(i)) & wp.uint32(1)) != wp.uint32(0):
            ray = disk_radii[first + i]
            x = ray[0] * c
            y = ray[0] * s
            lift = ray[1]
            base = fall * wp.max(x * nx + y * ny + lift * nz, 0.0) * ray[2]
            d = x * frame[0] + y * frame[1] + lift * frame[2]
            ex = wp.exp(eta * d[0])
            ey = wp.exp(eta * d[1])
            ez = wp.exp(eta * d[2])
            w = base * vec6(ey, 1.0 / ey, ex, 1.0 / ex, ez, 1.0 / ez)
            total = total + w
            if ((mask >> wp.uint32(i)) & wp.uint32(1)) == wp.uint32(0):
                seen = seen + w
        c_next = c * GOLDEN_COS - s * GOLDEN_SIN
        s = s * GOLDEN_COS + c * GOLDEN_SIN
        c = c_next
    out = vec6(1.0)
    for k in range(6):
        if total[k] > 1.0e-30:
            out[k] = seen[k] / total[k]
    return out


@wp.func
def lobe_ray_share(ray_axis: wp.vec3, ray_eta: float, axis: wp.vec3, eta: float, n: wp.vec3, mask: wp.uint32,
                   k: int, known: wp.uint32, turn: int) -> float:
    """The share of a lobe (axis, η) that sharp lobe k's rays (about ray_axis, ray_eta) see unblocked
    (shading.lobe_ray_share): the rays of `known` (bit i: ray i traced), made again (lobe_ray_direction, turned
    by pixel `turn`), each weighted by G(ω)(n·ω)⁺ and its solid-angle weight cos³ (its cosine to ray_axis,
    cubed); a ray below the geometric horizon, not traced, has its bit clear."""
    frame = disk_basis(ray_axis)
    total = float(0.0)
    seen = float(0.0)
    for i in range(LOBE_RAYS):
        if ((known >> wp.uint32(i)) & wp.uint32(1)) != wp.uint32(0):
            d = lobe_ray_direction(frame, ray_eta, i, turn)
            c = wp.dot(d, ray_axis)
            w = wp.exp(eta * (wp.dot(d, axis) - 1.0)) * wp.max(wp.dot(d, n), 0.0) * c * c * c
            total = total + w
            if ((mask >> wp.uint32(k * LOBE_RAYS + i)) & wp.uint32(1)) == wp.uint32(0):
                seen = seen + w
    if total > 1.0e-30:
        return seen / total
    return 1.0


@wp.func
def nearest_ray_lobe(env_sgs: wp.array2d(dtype=wp.float32), n_sharp: int, e: int, axis: wp.vec3, eta: float) -> int:
    """The ray lobe environment lobe e is shadowed through (shading.nearest_ray_lobe): itself if it is one (e <
    n_sharp), else, for a lobe of η ≥ SHARP_LOBE_ETA, the ray lobe nearest its axis if the axis lies in that
    lobe's cap; −1: none (the SSDF then)."""
    if e < n_sharp:
        return e
    best = int(-1)
    if eta >= SHARP_LOBE_ETA:
        best_c = float(-2.0)
        for k in range(n_sharp):
            c = f32_at2(env_sgs, k, 0) * axis[0] + f32_at2(env_sgs, k, 1) * axis[1] + f32_at2(env_sgs, k, 2) * axis[2]
            if c > best_c:
                best_c = c
                best = k
        if best >= 0:
            if best_c < wp.max(1.0 - 2.0 / f32_at2(env_sgs, best, 3), LOBE_COS_MIN):
                best = -1
    return best


@wp.func
def environment_share(table: wp.array3d(dtype=wp.float32), axis: wp.vec3, eta: float, tr: float, s: SurfacePoint,
                      has_ssdf: int, ssdf_res: int, ssdf_basis: wp.array2d(dtype=wp.float32),
                      ssdf_coeffs: wp.array2d(dtype=wp.float32), env_theta: wp.array2d(dtype=wp.float32), e: int,
                      mask: wp.uint32, samples: int, known: wp.uint32,
                      frame: wp.mat33, turn: wp.vec2, disk_radii: wp.array(dtype=wp.vec3), rays_given: float) -> float:
    """The share of ∫ G(ω; axis, η, 1)(n·ω)⁺ dω left unoccluded (1 without an SSDF): the SSDF's, blended
    for broad lobes with the occlusion rays' (ray_weight; a mask with no bit set sees it all); tr: η's
    table row. e ≥ 0: environment lobe e, whose θd at the vertices env_theta holds (ssdf.ssdf_at_axes), else
    θd looked up at the axis. rays_given ≥ 0: the rays' share, found already (axis_ray_shares); < 0: found here."""
    if has_ssdf == 0:
        return 1.0
    weight = ray_weight(eta, samples)
    if weight >= 1.0:  # a lobe the occlusion rays alone shadow: no SSDF lookup (its share would weigh 0)
        if rays_given >= 0.0:
            return rays_given
        if mask != wp.uint32(0):
            return ray_share(axis, eta, s.n, frame, mask, samples, known, turn, disk_radii)
        return 1.0
    theta = float(0.0)
    if e >= 0:
        theta = s.w0 * f32_at2(env_theta, s.i0, e) + s.w1 * f32_at2(env_theta, s.i1, e) + s.w2 * f32_at2(
            env_theta, s.i2, e)
    else:
        theta = ssdf_theta(ssdf_basis, ssdf_coeffs, s.i0, s.i1, s.i2, s.w0, s.w1, s.w2, ssdf_res, axis)
    share = beyond_horizon(table, theta, axis, tr, s.n)
    if weight > 0.0:
        rays = float(1.0)
        if rays_given >= 0.0:
            rays = rays_given
        elif mask != wp.uint32(0):
            rays = ray_share(axis, eta, s.n, frame, mask, samples, known, turn, disk_radii)
        share = weight * rays + (1.0 - weight) * share
    return share


@wp.func
def irradiance_scale(lobes: wp.vec3, residual: wp.vec3) -> wp.vec3:
    """Per channel, the exact irradiance E = lobes + residual over the environment lobes' own
    irradiance: the diffuse term keeps the lobes' shadows and takes E's magnitude. Where the lobes
    hold under a thousandth of E the ratio stops at 1000, so the term never passes kd·E."""
    out = wp.vec3(0.0)
    for c in range(3):
        e = wp.max(lobes[c] + residual[c], 0.0)
        out[c] = e / wp.max(wp.max(lobes[c], 1.0e-3 * e), 1.0e-30)
    return out


@wp.func
def lobe_from_lights(table: wp.array3d(dtype=wp.float32), axis: wp.vec3, eta: float, s: SurfacePoint,
                     n_lights: int, lights: wp.array2d(dtype=wp.float32), light_vis: wp.array2d(dtype=wp.uint8),
                     p: int) -> wp.vec3:
    """Σ over the lights whose shadow ray reached them of ∫ G(axis, η)·light SG·(n·ω)⁺."""
    out = wp.vec3(0.0)
    for l in range(n_lights):
        if u8_at2(light_vis, p, l) == wp.uint8(0):
            continue
        la = light_axis(lights, l, s.pos)
        le = light_sharpness(lights, l, s.pos)
        out = out + light_amplitude(lights, l, s.pos, le) * (
            product_integral(table, axis, eta, la, le, s.n) * float(int(u8_at2(light_vis, p, l))) / 255.0)
    return out


@wp.func
def lobe_asg(eff_lobes: wp.array2d(dtype=wp.float32), lobe: int, s: SurfacePoint) -> Asg:
    """ASG lobe `lobe` of an effective material ([z, 0, x, λ, μ] in the tile frame) in the world, unit amplitude."""
    g = Asg()
    g.z = f32_at2(eff_lobes, lobe, 0) * s.t + f32_at2(eff_lobes, lobe, 1) * s.b + f32_at2(eff_lobes, lobe, 2) * s.n
    g.x = f32_at2(eff_lobes, lobe, 4) * s.t + f32_at2(eff_lobes, lobe, 5) * s.b + f32_at2(eff_lobes, lobe, 6) * s.n
    g.y = wp.cross(g.z, g.x)
    g.lam = f32_at2(eff_lobes, lobe, 7)
    g.mu = f32_at2(eff_lobes, lobe, 8)
    g.c = 1.0
    return g


@wp.func
def asg_convolved_at(g: Asg, eta: float, h: wp.vec3) -> float:
    """(G ⊛ SG_η)(h) of a unit-amplitude ASG (asg.convolve_sg_local: Xu Eq. 18's bandwidths and amplitude, a
    shape exact for a delta lobe too)."""
    nu = 0.5 * eta
    lam_c = harmonic(g.lam, nu)
    mu_c = harmonic(g.mu, nu)
    a = wp.dot(h, g.x)
    b = wp.dot(h, g.y)
    t = wp.dot(h, g.z)
    if t <= 0.0:
        return 0.0
    sx = float(1.0)
    if g.lam > 0.0:
        sx = wp.clamp(lam_c / g.lam, 0.0, 1.0)
    sy = float(1.0)
    if g.mu > 0.0:
        sy = wp.clamp(mu_c / g.mu, 0.0, 1.0)
    r2 = a * a + b * b
    w = 0.5 * (sx + sy)
    if r2 > 0.0:
        w = (sx * a * a + sy * b * b) / r2
    k = 2.0 / (1.0 + wp.min(t, 1.0))
    expo = lam_c * a * a * wp.pow(k, 1.0 - sx) + mu_c * b * b * wp.pow(k, 1.0 - sy)
    return PI / wp.sqrt((g.lam + nu) * (g.mu + nu)) * wp.pow(t, w) * wp.exp(-expo)


@wp.func(inline=False)
def asg_prefiltered(maps: wp.array(dtype=wp.vec3), levels: wp.array2d(dtype=wp.float32), g: Asg) -> wp.vec3:
    """The environment's mean radiance under a warped ASG lobe: prefiltered lookups along its broad axis, as many as
    shading.tap_plan asks (shading.asg_prefiltered)."""
    long_axis = g.x
    if g.lam > g.mu:
        long_axis = g.y
    var_long = 0.5 / wp.min(g.lam, g.mu)
    var_tap = wp.max(0.5 / wp.max(g.lam, g.mu), ASG_TAP_SHARE * var_long)
    spread = wp.sqrt(wp.max(var_long - var_tap, 0.0))
    ratio = spread / wp.sqrt(var_tap)
    if ratio <= ROUND_SPREAD:
        return prefiltered(maps, levels, g.z, wp.min(2.0 * wp.sqrt(g.lam * g.mu), SHARPNESS_MAX))
    tap_levels = prefiltered_levels(levels, wp.min(1.0 / var_tap, SHARPNESS_MAX))
    count = int(0)
    for k in range(4):
        if count == 0 and HERMITE_GAPS[k] * ratio <= TAP_GAP:
            count = k + 2
    out = wp.vec3(0.0)
    if count > 0:
        first = (count - 2) * (count + 1) // 2
        for k in range(count):
            d = wp.normalize(g.z + (HERMITE_NODES[first + k] * spread) * long_axis)
            out = out + HERMITE_WEIGHTS[first + k] * prefiltered_at(maps, tap_levels, d)
        return out
    count = wp.min(ASG_TAPS, 1 + int(wp.ceil(2.0 * TAP_SPAN * ratio / TAP_GAP)))
    step = 2.0 * TAP_SPAN / float(count - 1)
    total = float(0.0)
    for k in range(count):
        node = -TAP_SPAN + step * float(k)
        weight = wp.exp(-0.5 * node * node)
        total = total + weight
        d = wp.normalize(g.z + (node * spread) * long_axis)
        out = out + weight * prefiltered_at(maps, tap_levels, d)
    return out / total


@wp.func
def asg_shade_integral(lam: float, mu: float) -> float:
    """∫ of a unit ASG: Xu's Eq. 10 where both bandwidths pass ASG_EQ10_MIN, else the exact quadrature
    (asg.shade_integral)."""
    if wp.min(lam, mu) > ASG_EQ10_MIN:
        return asg_integral_eq10(lam, mu)
    return asg_unit_integral(lam, mu)


@wp.func
def asg_from_lights(g: Asg, conv: Asg, eta_s: float, kind: int, ks: wp.vec3, p1: float, p2: float,
                    eff_tables: wp.array(dtype=wp.float32), base: int, k2: int, j_count: int, j: int, k: int,
                    oo: vec4i, ow: wp.vec4, s: SurfacePoint, wo: wp.vec3, table: wp.array3d(dtype=wp.float32),
                    n_lights: int, lights: wp.array2d(dtype=wp.float32), light_vis: wp.array2d(dtype=wp.uint8),
                    p: int) -> wp.vec3:
    """An ASG lobe's specular radiance from the lights: the material's own f̄ at each light's direction
    (M(h·l)·μ_j(l, ωo)/cos θi·(G_j ⊛ D_s)(h)) times the light's irradiance, cosine and visible share. `conv` is
    G_j ⊛ D_s (`small_scale_convolved`), evaluated as it is for an anisotropic D_s; an SG's takes the shape
    that is exact for a delta lobe too (asg_convolved_at)."""
    anisotropic = kind == ANISOTROPIC_WARD or kind == ASHIKHMIN_SHIRLEY
    out = wp.vec3(0.0)
    for l in range(n_lights):
        if u8_at2(light_vis, p, l) == wp.uint8(0):
            continue
        la = light_axis(lights, l, s.pos)
        le = light_sharpness(lights, l, s.pos)
        h = wp.normalize(la + wo)
        shape = float(0.0)
        if anisotropic:
            shape = asg_eval(conv, h)
        else:
            shape = asg_convolved_at(g, eta_s, h)
        if shape <= 0.0:
            continue
        scale = specular_scale(kind, ks, p1, p2, wp.dot(h, la))
        mu = table_rgb(eff_tables, base, k2, j_count, j, to_local(s, la), k, oo, ow)
        e = light_irradiance(table, lights, l, s.pos, s.n, la, le, u8_at2(light_vis, p, l))
        out = out + wp.cw_mul(wp.cw_mul(scale, mu), e) * shape
    return out


@wp.func
def finite_radiance(v: wp.vec3) -> wp.vec3:
    """Never NaN, inf or negative (a degenerate normal, say, must not poison the image)."""
    out = v
    for c in range(3):
        if not (v[c] >= 0.0 and v[c] < 3.0e38):
            out[c] = 0.0
    return out


@wp.func
def light_axes(la: wp.vec3, hint: wp.vec3) -> wp.mat33:
    """Rows: two unit axes across unit direction la (shading.light_axes: the hint with its part along la removed,
    or Duff et al.'s basis vector where the hint lies along la), then la × the first."""
    x = hint - wp.dot(hint, la) * la
    l2 = wp.dot(x, x)
    if l2 > 1.0e-6:
        x = x / wp.sqrt(l2)
    else:
        sgn = float(1.0)
        if la[2] < 0.0:
            sgn = -1.0
        a = -1.0 / (sgn + la[2])
        x = wp.vec3(1.0 + sgn * la[0] * la[0] * a, sgn * la[0] * la[1] * a, -sgn * la[0])
    return wp.matrix_from_rows(x, wp.cross(la, x), la)


@wp.func(inline=False)
def specular_cos(kind: int, ks: wp.vec3, p1: float, p2: float, s: SurfacePoint, d: wp.vec3, wo: wp.vec3) -> wp.vec3:
    """f_s·(n·ωi)⁺ towards d (made unit here)."""
    wi = wp.normalize(d)
    return analytic_specular(kind, ks, p1, p2, s.t, s.b, s.n, wi, wo) * wp.max(wp.dot(s.n, wi), 0.0)


@wp.func
def specular_cos_sum(kind: int, ks: wp.vec3, p1: float, p2: float, s: SurfacePoint, d: wp.vec3, wo: wp.vec3) -> float:
    f = specular_cos(kind, ks, p1, p2, s, d, wo)
    return f[0] + f[1] + f[2]


@wp.func
def light_mean(kind: int, ks: wp.vec3, p1: float, p2: float, s: SurfacePoint, wo: wp.vec3, la: wp.vec3, lobe: Asg,
               var_l: float) -> wp.vec3:
    """f_s·(n·ωi)⁺'s mean over a light, a Gaussian of variance var_l per axis about la (shading.light_mean): read
    where the light's and the lobe's Gaussians overlap most (`lobe`: its centre z, axis x turned across the light
    (light_axes), variances 1/(2λ), 1/(2μ)) and at ± their product's σ along two axes, its logarithm taken as a
    quadratic there and integrated against the light in closed form."""
    axes = light_axes(la, lobe.x)
    var_x = 0.5 / lobe.lam
    var_y = 0.5 / lobe.mu
    dx = wp.dot(lobe.z - la, axes[0])
    dy = wp.dot(lobe.z - la, axes[1])
    xk = wp.vec2(dx * var_l / (var_l + var_x), dy * var_l / (var_l + var_y))
    sk = wp.vec2(wp.sqrt(var_l * var_x / (var_l + var_x)), wp.sqrt(var_l * var_y / (var_l + var_y)))
    point = la + xk[0] * axes[0] + xk[1] * axes[1]
    f0 = specular_cos(kind, ks, p1, p2, s, point, wo)
    c0 = f0[0] + f0[1] + f0[2]
    if c0 <= 0.0:  # (where any of the five is 0, f_s·(n·ωi)⁺ at the light's centre)
        return specular_cos(kind, ks, p1, p2, s, la, wo)
    l0 = wp.log(c0)
    expo = float(0.0)
    scale = float(1.0)
    for k in range(2):
        lo = specular_cos_sum(kind, ks, p1, p2, s, point - sk[k] * axes[k], wo)
        hi = specular_cos_sum(kind, ks, p1, p2, s, point + sk[k] * axes[k], wo)
        if lo <= 0.0 or hi <= 0.0:
            return specular_cos(kind, ks, p1, p2, s, la, wo)
        log_lo = wp.log(lo)
        log_hi = wp.log(hi)
        g = (log_hi - log_lo) / (2.0 * sk[k])
        c = wp.min((log_hi + log_lo - 2.0 * l0) / (sk[k] * sk[k]), 0.0)
        big_a = 1.0 / var_l - c
        big_b = g - c * xk[k]
        expo = expo - g * xk[k] + 0.5 * c * xk[k] * xk[k] + big_b * big_b / (2.0 * big_a)
        scale = scale / wp.sqrt(var_l * big_a)
    return f0 * (scale * wp.exp(wp.min(expo, LIGHT_BLUR_EXP_MAX)))


@wp.func
def moment_sharpness(kind: int, p1: float, p2: float) -> float:
    """The scale of a row's moment table (shading.moment_sharpness): the NDF's sharpness, or 2·√(λμ) of its ASG."""
    if kind == ANISOTROPIC_WARD or kind == ASHIKHMIN_SHIRLEY:
        bw = ndf_bandwidths(kind, p1, p2)
        return 2.0 * wp.sqrt(bw[0] * bw[1])
    return ndf_sharpness(kind, p1)


@wp.func
def tabulated_moments(tex_info: wp.array2d(dtype=wp.int32), tex_data: wp.array(dtype=wp.vec3), slot: int,
                      s: SurfacePoint, wo: wp.vec3, kind: int, eta: float, p1_factor: float) -> Asg:
    """The ASG of an analytic row's f_s·(n·ωi)⁺ moments, read from its moment table (shading.moment_table) at
    texture `slot` for its moment_sharpness η (shading.tabulated_moments): linear in √cos θo and across the
    columns — an isotropic row's p1 factors (its parameter map's `p1_factor` here; the first's log2 in texel
    (0, W)'s third channel), else φo folded into [0, π/2], a view in another quadrant of the tangent frame mirroring
    the out-of-plane angle and the correlation."""
    off = i32_at2(tex_info, slot, 0)
    rows = i32_at2(tex_info, slot, 1)
    width = i32_at2(tex_info, slot, 2) // 2
    cos_o = wp.clamp(wp.dot(wo, s.n), 0.0, 1.0)
    side = wo - cos_o * s.n
    length = wp.length(side)
    if length > 1.0e-6:
        side = side / length
    else:
        side = s.t
    across = wp.cross(s.n, side)
    wx = wp.dot(wo, s.t)
    wy = wp.dot(wo, s.b)
    pos = wp.sqrt(cos_o) * float(rows - 1)
    i0 = wp.min(int(pos), rows - 2)
    fi = pos - float(i0)
    j0 = int(0)
    j1 = int(0)
    fj = float(0.0)
    mirror = float(1.0)
    if width > 1:
        col = float(0.0)
        if kind == ANISOTROPIC_WARD or kind == ASHIKHMIN_SHIRLEY:
            col = wp.atan2(wp.abs(wy), wp.abs(wx)) / (0.5 * PI) * float(width - 1)
            if (wx < 0.0) != (wy < 0.0):
                mirror = -1.0
        else:
            col = wp.clamp(MOMENT_P1_STEPS * (wp.log2(wp.max(p1_factor, 1.0e-30)) - tex_data[off + width][2]), 0.0,
                           float(width - 1))
        j0 = wp.min(int(col), width - 2)
        j1 = j0 + 1
        fj = col - float(j0)
    row0 = off + i0 * 2 * width
    row1 = row0 + 2 * width
    first = (tex_data[row0 + j0] * (1.0 - fj) + tex_data[row0 + j1] * fj) * (1.0 - fi) + (
        tex_data[row1 + j0] * (1.0 - fj) + tex_data[row1 + j1] * fj) * fi
    second = (tex_data[row0 + width + j0] * (1.0 - fj) + tex_data[row0 + width + j1] * fj) * (1.0 - fi) + (
        tex_data[row1 + width + j0] * (1.0 - fj) + tex_data[row1 + width + j1] * fj) * fi
    scale = wp.sqrt(eta)
    theta = wp.clamp(wp.atan2(length, cos_o) + first[0] / scale, 0.0, 0.5 * PI)
    beta = mirror * second[0] / scale
    c = wp.cos(theta)
    sn = wp.sin(theta)
    z = wp.cos(beta) * (c * s.n - sn * side) + wp.sin(beta) * across
    u = -(c * side + sn * s.n)
    u = wp.normalize(u - wp.dot(u, z) * z)
    v = wp.cross(z, u)
    var_u = wp.exp(first[1]) / eta
    var_v = wp.exp(first[2]) / eta
    cov = mirror * second[1] * wp.sqrt(var_u * var_v)
    angle = 0.5 * wp.atan2(2.0 * cov, var_u - var_v)
    ca = wp.cos(angle)
    sa = wp.sin(angle)
    g = Asg()
    g.z = z
    g.x = ca * u + sa * v
    g.y = wp.cross(z, g.x)
    g.c = 1.0
    g.lam = 0.5 / wp.max(var_u * ca * ca + 2.0 * cov * ca * sa + var_v * sa * sa, MOMENT_VAR_MIN)
    g.mu = 0.5 / wp.max(var_u * sa * sa - 2.0 * cov * ca * sa + var_v * ca * ca, MOMENT_VAR_MIN)
    return g


@wp.func
def analytic_from_lights(kind: int, ks: wp.vec3, p1: float, p2: float, s: SurfacePoint, wo: wp.vec3, lobe: Asg,
                         n_lights: int, lights: wp.array2d(dtype=wp.float32), light_vis: wp.array2d(dtype=wp.uint8),
                         p: int) -> wp.vec3:
    """An analytic BRDF's specular radiance from the lights: f_s·(n·ωi)⁺'s mean over each light's SG (light_mean;
    `lobe` the warped lobe's shape) times the light's irradiance at normal incidence and its visible share."""
    out = wp.vec3(0.0)
    for l in range(n_lights):
        if u8_at2(light_vis, p, l) == wp.uint8(0):
            continue
        la = light_axis(lights, l, s.pos)
        le = light_sharpness(lights, l, s.pos)
        f = light_mean(kind, ks, p1, p2, s, wo, la, lobe, 1.0 / le)
        power = light_amplitude(lights, l, s.pos, le) * (sg_integral(le) * float(u8_at2(light_vis, p, l)) / 255.0)
        out = out + wp.cw_mul(f, power)
    return out


# A register cap (device.SHADE_MAX_REGISTERS, the OpenCL build's too): the rarely taken ASG path would otherwise
# set the whole kernel's count.
@wp.kernel(cuda_max_registers=_device.SHADE_MAX_REGISTERS)
def shade_pixels(
    face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec2), light_vis: wp.array2d(dtype=wp.uint8),
    occlusion: wp.array(dtype=wp.uint32), occlusion_samples: int, lobe_occlusion: wp.array(dtype=wp.uint32),
    n_sharp: int, part_index: int, part_count: int, block_width: int, block_side: int,
    occlusion_known: wp.array(dtype=wp.uint32), lobe_known: wp.array(dtype=wp.uint32),
    faces: wp.array2d(dtype=wp.int32), positions: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
    tangents: wp.array(dtype=wp.vec3), face_material: wp.array(dtype=wp.int32),
    camera: wp.array(dtype=wp.float32),
    n_lights: int, lights: wp.array2d(dtype=wp.float32),
    n_env: int, env_sgs: wp.array2d(dtype=wp.float32), axis_lobes: int,
    env_residual: wp.array(dtype=wp.vec3), residual_h: int, residual_w: int,
    env_maps: wp.array(dtype=wp.vec3), env_levels: wp.array2d(dtype=wp.float32),
    has_ssdf: int, ssdf_res: int, ssdf_basis: wp.array2d(dtype=wp.float32), ssdf_coeffs: wp.array2d(dtype=wp.float32),
    env_theta: wp.array2d(dtype=wp.float32), disk_radii: wp.array(dtype=wp.vec3),
    table: wp.array3d(dtype=wp.float32),
    mat_info: wp.array2d(dtype=wp.int32), analytic: wp.array2d(dtype=wp.float32),
    eff_info: wp.array2d(dtype=wp.int32), eff_lobes: wp.array2d(dtype=wp.float32),
    eff_sub: wp.array2d(dtype=wp.float32), eff_tables: wp.array(dtype=wp.float32),
    eff_diffuse: wp.array(dtype=wp.float32),
    uvs: wp.array(dtype=wp.vec2), tex_info: wp.array2d(dtype=wp.int32), tex_data: wp.array(dtype=wp.vec3),
    kept_mode: int, kept_amount: wp.array(dtype=wp.float32), kept_scale: wp.array(dtype=wp.vec3),
    n_pixels: int, only_material: int, changed: wp.array(dtype=wp.uint8),
    reference_radiance: wp.array(dtype=wp.vec3), only_changed: int, offset: int,
    radiance: wp.array(dtype=wp.vec3),
):
    p = wp.tid() + offset
    if p >= n_pixels:
        return
    f = face[p]
    if only_changed != 0:  # a pixel not flagged changed (mark_changed) takes the reference frame's radiance
        if changed[p] == wp.uint8(0):
            radiance[p] = reference_radiance[p]
            return
    if only_material >= 0:  # only that material's pixels: the others keep the radiance they have
        if f < 0:
            return
        if face_material[f] != only_material:
            return
    if f < 0:
        radiance[p] = prefiltered(env_maps, env_levels, camera_ray(camera, p), 1.0e30)
        return
    s = surface_point(faces, positions, normals, tangents, f, bary[p])
    wo = wp.normalize(wp.vec3(camera[0], camera[1], camera[2]) - s.pos)
    # A back face is black: surfaces are one-sided, as the Monte Carlo reference sees them (its rays leave on the
    # viewer's side, behind the face, and meet it), not lit from the hemisphere of a normal turned from the eye.
    if seen_from_behind(positions[s.i0], positions[s.i1], positions[s.i2], s.n, wo):
        radiance[p] = wp.vec3(0.0)
        return
    cos_o = wp.max(wp.dot(wo, s.n), MIN_COS_VIEW)
    wo_local = wp.normalize(wp.vec3(wp.dot(wo, s.t), wp.dot(wo, s.b), cos_o))
    # The occlusion rays' mask and frame (about the geometric normal on the camera's side, as traced), and
    # which rays of the occlusion and lobe ray sets this anti-aliasing sample traced: the pixel's own part, or,
    # with block_width > 0, those its pixel block lent it (trace.share_block_masks' known bits).
    occlusion_part = pixel_part(occlusion_samples, part_index, part_count, block_width, block_side, p)
    lobe_part = pixel_part(LOBE_RAYS, part_index, part_count, block_width, block_side, p)
    occlusion_rays = part_bits(occlusion_part[0], occlusion_part[1], occlusion_samples)
    lobe_rays = part_bits(lobe_part[0], lobe_part[1], LOBE_RAYS)
    mask = wp.uint32(0)
    frame = wp.identity(3, dtype=float)
    turn = wp.vec2(1.0, 0.0)  # the cosine and sine of the angle that turns the pixel's occlusion rays (disk_turn)
    if occlusion_samples > 0:
        turn_angle = disk_turn(occlusion_part[2])
        turn = wp.vec2(wp.cos(turn_angle), wp.sin(turn_angle))
        mask = occlusion[p]
        if block_width > 0:
            occlusion_rays = occlusion_known[p]
            if n_sharp > 0:
                lobe_rays = lobe_known[p]
        ng = wp.normalize(wp.cross(positions[s.i1] - positions[s.i0], positions[s.i2] - positions[s.i0]))
        if wp.dot(ng, wo) < 0.0:
            ng = -ng
        frame = disk_basis(ng)

    mat = face_material[f]
    kind = i32_at2(mat_info, mat, 0)
    idx = i32_at2(mat_info, mat, 1)
    has_spec = i32_at2(mat_info, mat, 2)
    k = int(0)
    k2 = int(0)
    j_count = int(0)
    oo = vec4i(0, 0, 0, 0)
    ow = wp.vec4(0.0)
    kd = wp.vec3(0.0)
    # An analytic material's rows (one per SG lobe of its SG form; the first carries kd): a textured one
    # (slot >= 0) scales kd, ks and p1 by its maps at the pixel's UV, read once here into per-pixel factors.
    t_ks = wp.vec3(1.0)
    t_p1 = float(1.0)
    a_kind = int(0)
    a_ks = wp.vec3(0.0)
    if kind == 0:
        a_kind = int(analytic[idx, 0])
        a_ks = wp.vec3(analytic[idx, 4], analytic[idx, 5], analytic[idx, 6])
        a_kd = wp.vec3(analytic[idx, 1], analytic[idx, 2], analytic[idx, 3])
        slot = i32_at2(mat_info, mat, 3)
        if slot >= 0:
            uv = s.w0 * uvs[s.i0] + s.w1 * uvs[s.i1] + s.w2 * uvs[s.i2]
            a_kd = wp.cw_mul(a_kd, texture_bilinear(tex_info, tex_data, slot, uv))
            t_ks = texture_bilinear(tex_info, tex_data, slot + 1, uv)
            t_p1 = texture_bilinear(tex_info, tex_data, slot + 2, uv)[0]
        kd = a_kd / PI
    else:
        k = i32_at2(eff_info, idx, 0)
        k2 = k * k
        j_count = i32_at2(eff_info, idx, 1)
        go = grid_bilinear(wo_local, k)
        oo = go.idx
        ow = go.wgt
    out = wp.vec3(0.0)

    # Diffuse: environment lobes (SSDF-shadowed, scaled to the exact irradiance), then lights (shadow rays).
    # Each lobe's shadowed amount and the irradiance scale depend on the pixel, the environment and the rays, not
    # on the material: kept_mode 1 keeps them per pixel, 2 reads them back (a material edit's shade), 0 neither.
    lobes_irradiance = wp.vec3(0.0)
    # The six shadow lobes along the axes (axis_lobes: the first's row, or −1), where the occlusion rays weigh in
    # their shadow (environment_share's ray_weight > 0): the rays' shares from one walk of the rays
    # (axis_ray_shares), which environment_share then takes (alone, or blended with the SSDF's).
    axis_shares = vec6(1.0)
    axis_end = int(-1)
    if axis_lobes >= 0 and has_ssdf != 0 and kept_mode != 2:
        axis_eta = f32_at2(env_sgs, axis_lobes, 3)
        if ray_weight(axis_eta, occlusion_samples) > 0.0:
            axis_end = axis_lobes + 6
            if mask != wp.uint32(0):
                axis_shares = axis_ray_shares(axis_eta, s.n, frame, mask, occlusion_samples, occlusion_rays, turn,
                                              disk_radii)
    for e in range(n_env):
        axis = wp.vec3(f32_at2(env_sgs, e, 0), f32_at2(env_sgs, e, 1), f32_at2(env_sgs, e, 2))
        eta = f32_at2(env_sgs, e, 3)
        radiance_e = wp.vec3(f32_at2(env_sgs, e, 4), f32_at2(env_sgs, e, 5), f32_at2(env_sgs, e, 6))
        amount = float(0.0)
        if kept_mode == 2:
            amount = kept_amount[p * n_env + e]
        else:
            tr = eta_row(table, eta)
            amount = cosine_integral(table, axis, eta, tr, s.n)
            lobes_irradiance = lobes_irradiance + radiance_e * amount
            ray_lobe = nearest_ray_lobe(env_sgs, n_sharp, e, axis, eta)
            if ray_lobe >= 0:  # a sharp lobe: through its own rays, or those of the ray lobe whose cap holds its axis
                ray_axis = wp.vec3(f32_at2(env_sgs, ray_lobe, 0), f32_at2(env_sgs, ray_lobe, 1),
                                   f32_at2(env_sgs, ray_lobe, 2))
                amount = amount * lobe_ray_share(ray_axis, f32_at2(env_sgs, ray_lobe, 3), axis, eta, s.n,
                                                 lobe_occlusion[p], ray_lobe, lobe_rays, lobe_part[2])
            else:
                rays_given = float(-1.0)
                if e >= axis_lobes and e < axis_end:
                    rays_given = axis_shares[e - axis_lobes]
                amount = amount * environment_share(table, axis, eta, tr, s, has_ssdf, ssdf_res, ssdf_basis,
                                                    ssdf_coeffs, env_theta, e, mask, occlusion_samples,
                                                    occlusion_rays, frame, turn, disk_radii, rays_given)
            if kept_mode == 1:
                kept_amount[p * n_env + e] = amount
        fd = analytic_diffuse(a_kind, kd, a_ks, axis, eta, s, cos_o)
        if kind != 0:
            fd = effective_diffuse(eff_info, eff_sub, eff_diffuse, idx, k2, eta, to_local(s, axis), k, oo, ow)
        out = out + wp.cw_mul(fd, radiance_e) * amount
    scale = wp.vec3(0.0)
    if kept_mode == 2:
        scale = kept_scale[p]
    else:
        scale = irradiance_scale(lobes_irradiance, equirect_bilinear_dir(env_residual, 0, residual_h, residual_w, s.n))
        if kept_mode == 1:
            kept_scale[p] = scale
    out = wp.cw_mul(out, scale)
    for l in range(n_lights):
        if u8_at2(light_vis, p, l) == wp.uint8(0):
            continue
        axis = light_axis(lights, l, s.pos)
        eta = light_sharpness(lights, l, s.pos)
        fd = analytic_diffuse(a_kind, kd, a_ks, axis, eta, s, cos_o)
        if kind != 0:
            fd = effective_diffuse(eff_info, eff_sub, eff_diffuse, idx, k2, eta, to_local(s, axis), k, oo, ow)
        out = out + wp.cw_mul(fd, light_irradiance(table, lights, l, s.pos, s.n, axis, eta, u8_at2(light_vis, p, l)))

    # Specular: each warped lobe against the prefiltered environment and each light.
    if has_spec != 0:
        n_sub = 1
        n_lobes = has_spec  # an analytic material's lobe rows
        if kind != 0:
            n_sub = i32_at2(eff_info, idx, 2)
            n_lobes = j_count
        for sub_i in range(n_sub):
            for j in range(n_lobes):
                axis = wp.vec3(0.0)
                eta = float(0.0)
                amp = wp.vec3(0.0)
                with_lights = int(1)
                cap = float(-1.0)  # Ashikhmin–Shirley's cap on the cosine integral (shading.capped_cosine_integral)
                tap = Asg()  # an ASG lobe's warped shape, for the anisotropic lookup (asg_prefiltered)
                taps = int(0)
                env_scale = wp.vec3(1.0)  # the environment term's scale: an analytic row's correction
                if kind == 0:
                    row = idx + j
                    r_kind = int(analytic[row, 0])
                    env_scale = specular_correction(tex_info, tex_data, 1 + 2 * row, wo_local, r_kind, t_p1)
                    r_ks = wp.cw_mul(wp.vec3(analytic[row, 4], analytic[row, 5], analytic[row, 6]), t_ks)
                    r_p1 = analytic[row, 7] * t_p1
                    r_p2 = analytic[row, 8]
                    amp = specular_scale(r_kind, r_ks, r_p1, r_p2, cos_o)
                    # The lights by f_s itself (Xu 2013 §5.2), averaged over each light's size.
                    with_lights = 0
                    shape = Asg()
                    if r_kind == ANISOTROPIC_WARD or r_kind == ASHIKHMIN_SHIRLEY:
                        # The environment's magnitude and occlusion through the NDF's warped ASG, as an effective
                        # material's ASG lobe below.
                        w = warped_ndf(r_kind, r_p1, r_p2, s, wo)
                        eta = wp.min(2.0 * wp.sqrt(w.lam * w.mu), SHARPNESS_MAX)
                        axis = w.z
                        amp = amp * (w.c * asg_shade_integral(w.lam, w.mu) / sg_integral(eta))
                        if r_kind == ASHIKHMIN_SHIRLEY:
                            cap = cos_o
                        shape = w
                    else:
                        axis = wp.normalize(2.0 * cos_o * s.n - wo)
                        eta = ndf_sharpness(r_kind, r_p1) / (4.0 * cos_o)
                        shape.z = axis
                        shape.x = s.t
                        shape.lam = 0.5 * wp.min(eta, SHARPNESS_MAX)
                        shape.mu = shape.lam
                    out = out + analytic_from_lights(r_kind, r_ks, r_p1, r_p2, s, wo, shape, n_lights, lights,
                                                     light_vis, p)
                    # The environment where f_s·cos θi itself lies, not where the warp puts it; nothing for a view
                    # below the shading normal's horizon, where f_s is 0.
                    if wp.dot(wo, s.n) > 0.0:
                        tap = tabulated_moments(tex_info, tex_data, 2 + 2 * row, s, wo, r_kind,
                                                moment_sharpness(r_kind, r_p1, r_p2), t_p1)
                        taps = 1
                    else:
                        amp = wp.vec3(0.0)
                else:
                    sub = i32_at2(eff_info, idx, 4) + sub_i
                    lobe = i32_at2(eff_info, idx, 3) + j
                    xi = (f32_at2(eff_lobes, lobe, 0) * s.t + f32_at2(eff_lobes, lobe, 1) * s.b
                          + f32_at2(eff_lobes, lobe, 2) * s.n)
                    c_oj = wp.dot(wo, xi)
                    s_kind = int(f32_at2(eff_sub, sub, 0))
                    s_p1 = f32_at2(eff_sub, sub, 7)
                    s_ks = wp.vec3(f32_at2(eff_sub, sub, 4), f32_at2(eff_sub, sub, 5), f32_at2(eff_sub, sub, 6))
                    eta_s = ndf_sharpness(s_kind, s_p1)
                    base = i32_at2(eff_info, idx, 5) + sub_i * k2 * k2 * j_count * 3
                    asg_lobes = i32_at2(eff_info, idx, 7) == ASG_LOBES
                    g = Asg()
                    conv = Asg()
                    s_p2 = f32_at2(eff_sub, sub, 8)
                    if asg_lobes:
                        # Xu 2013: the lights by the material's own f̄ at their directions, whichever way the
                        # lobe faces; the environment below through the warped lobe's equal-integral SG.
                        g = lobe_asg(eff_lobes, lobe, s)
                        order = i32_at2(eff_info, idx, 3) + j_count * (1 + sub_i) + j  # (after the lobes' rows)
                        conv = small_scale_convolved(g, s_kind, s_p1, s_p2, eta_s, f32_at2(eff_lobes, order, 0),
                                                     f32_at2(eff_lobes, order, 1))
                        out = out + asg_from_lights(g, conv, eta_s, s_kind, s_ks, s_p1, s_p2, eff_tables,
                                                    base, k2, j_count, j, k, oo, ow, s, wo, table, n_lights, lights,
                                                    light_vis, p)
                    if c_oj <= 0.0:
                        continue
                    scale = specular_scale(s_kind, s_ks, s_p1, s_p2, c_oj)
                    if scale[0] + scale[1] + scale[2] <= 0.0:
                        continue
                    if asg_lobes:
                        c = conv
                        w = asg_warp(c, wo)
                        lam = wp.max(w.lam, 1.0e-6)
                        mu_w = wp.max(w.mu, 1.0e-6)
                        eta = 2.0 * wp.sqrt(lam * mu_w)
                        axis = w.z
                        mu = table_rgb(eff_tables, base, k2, j_count, j, to_local(s, axis), k, oo, ow)
                        eta = wp.min(eta, SHARPNESS_MAX)
                        amp = wp.cw_mul(scale, mu) * (c.c * asg_shade_integral(lam, mu_w) / sg_integral(eta))
                        with_lights = 0
                        tap = w
                        tap.lam = lam
                        tap.mu = mu_w
                        taps = 1
                    else:
                        eta_j = f32_at2(eff_lobes, lobe, 3)
                        axis = wp.normalize(2.0 * c_oj * xi - wo)
                        mu = table_rgb(eff_tables, base, k2, j_count, j, to_local(s, axis), k, oo, ow)
                        amp = wp.cw_mul(scale, mu) * (2.0 * PI / (eta_j + eta_s))
                        eta = 1.0 / (1.0 / eta_j + 1.0 / eta_s) / (4.0 * wp.max(c_oj, MIN_COS_VIEW))
                eta = wp.min(eta, SHARPNESS_MAX)
                tr = eta_row(table, eta)
                amount = cosine_integral(table, axis, eta, tr, s.n)
                if cap >= 0.0:
                    spread = wp.sqrt(wp.max(1.0 - cap * cap, 0.0) / (2.0 * PI * eta))
                    amount = wp.max(amount - spread * sg_integral(eta) * table_lookup(table, 1, wp.dot(axis, s.n), tr)
                                    / (1.0 + wp.exp(-eta)), 0.0)
                amount = amount * environment_share(
                    table, axis, eta, tr, s, has_ssdf, ssdf_res, ssdf_basis, ssdf_coeffs, env_theta, -1, mask,
                    occlusion_samples, occlusion_rays, frame, turn, disk_radii, -1.0)
                light_part = wp.vec3(0.0)
                if with_lights != 0:
                    light_part = lobe_from_lights(table, axis, eta, s, n_lights, lights, light_vis, p)
                env_l = wp.vec3(0.0)
                if taps != 0:
                    env_l = asg_prefiltered(env_maps, env_levels, tap)
                else:
                    env_l = prefiltered(env_maps, env_levels, axis, eta)
                out = out + wp.cw_mul(amp, wp.cw_mul(env_scale, env_l) * amount + light_part)
    radiance[p] = finite_radiance(out)
