"""The ASG bake's EM on the device (issue 20; Xu 2013 §4 on Iwasaki's bins): J anisotropic spherical Gaussians
fitted to the NDF's non-empty normal bins.

Twin of ``cl/asgfit.cl``; the float64 reference is ``warp_biscale.asg_bake.fit_asg`` (its module notes give the
EM: E-step responsibilities of the normalised ASGs; M-step axis = the weighted mean normal, frame and bandwidths
from the second moments of the disk coordinates in its tangent plane, the bandwidths the exact maximum likelihood
of the truncated Gaussian on the unit disk, by Newton in log λ, log μ). One EM step is three launches, queued
for every step at once with no host round trip: `asg_em_responsibilities` (one thread per bin),
`asg_em_m_step` (one block per lobe: its threads share the sums over the bins, which one thread a lobe had
walked serially, latency-bound, for most of the EM's time on a GPU) and `asg_em_finish` (one thread: the
weights, the convergence test and the new lobes). `state` = [done, steps]: once done is set, every later launch returns.

Precision: float64 throughout, as the reference (a lobe at the bandwidth cap, λ = 5e5, has E[a²] = 1e−6, which
float32 normals would give to 1e−4); the disk moments are the reference's (48 Gauss–Legendre nodes across, each
chord in closed form), and the E-step's responsibilities and ∫G (kernels/asg.py's 56-node float32 rule, 2.7e−7)
are where the two differ (tests/test_asg_bake.py).

Lobe rows (J, 12) float64: [x (3), y (3), z (3), λ, μ, log ∫G] (∫G by kernels/asg.py's 56-node rule).
"""

import numpy as np
import warp as wp

from .asg import asg_unit_integral

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

# 48-point Gauss–Legendre on [−1, 1] (numpy.polynomial.legendre.leggauss(48)), as asg_bake._disk_moments.
_X, _W = np.polynomial.legendre.leggauss(48)
vec48 = wp.types.vector(length=48, dtype=wp.float64)
GL48_X = wp.constant(vec48(*_X))
GL48_W = wp.constant(vec48(*_W))
vec5d = wp.types.vector(length=5, dtype=wp.float64)
vec6d = wp.types.vector(length=6, dtype=wp.float64)

D0 = wp.constant(wp.float64(0.0))
D1 = wp.constant(wp.float64(1.0))
NEG = wp.constant(wp.float64(-1.0e300))  # log density of a lobe that does not see the normal
TINY = wp.constant(wp.float64(1.0e-300))
PI64 = wp.constant(wp.float64(3.141592653589793))
CHORD_TERMS = wp.constant(24)  # = asg_bake.CHORD_TERMS
CHORD_DONE = wp.constant(wp.float64(1.0e-17))  # = asg_bake.CHORD_DONE
vec26d = wp.types.vector(length=26, dtype=wp.float64)
vec24d = wp.types.vector(length=24, dtype=wp.float64)
INV_ODD = wp.constant(vec26d(*(1.0 / (2.0 * np.arange(26) + 1.0))))  # 1/(2n + 1): the series' divisions as products
INV_NEXT = wp.constant(vec24d(*(1.0 / (np.arange(24) + 1.0))))  # 1/(m + 1)
NEWTON_STEPS = wp.constant(60)  # = bandwidths_from_moments' iterations
NEWTON_DONE = wp.constant(wp.float64(1.0e-7))  # a step below this in log λ and log μ ends the Newton, as on the host


@wp.func
def frame_x(z: wp.vec3d) -> wp.vec3d:
    """Duff et al. 2017's x for unit z (asg.tangent_frame), float64."""
    s = D1
    if z[2] < D0:
        s = -D1
    a = -D1 / (s + z[2])
    return wp.vec3d(D1 + s * z[0] * z[0] * a, s * z[0] * z[1] * a, -s * z[0])


@wp.func
def frame_y(z: wp.vec3d) -> wp.vec3d:
    s = D1
    if z[2] < D0:
        s = -D1
    a = -D1 / (s + z[2])
    return wp.vec3d(z[0] * z[1] * a, s + z[1] * z[1] * a, -z[1])


@wp.func
def lobe_vec(lobes: wp.array2d(dtype=wp.float64), j: int, k: int) -> wp.vec3d:
    return wp.vec3d(lobes[j, k], lobes[j, k + 1], lobes[j, k + 2])


@wp.func
def log_density(lobes: wp.array2d(dtype=wp.float64), alpha: wp.array(dtype=wp.float64), j: int,
                n: wp.vec3d) -> wp.float64:
    """log(α_j G_j(n)/∫G_j) (asg_bake._log_pdf plus log α), NEG where α_j = 0 or n is below the lobe's horizon."""
    t = wp.dot(n, lobe_vec(lobes, j, 6))
    if alpha[j] <= D0 or t <= D0:
        return NEG
    a = wp.dot(n, lobe_vec(lobes, j, 0))
    b = wp.dot(n, lobe_vec(lobes, j, 3))
    return wp.log(t) - lobes[j, 9] * a * a - lobes[j, 10] * b * b - lobes[j, 11] + wp.log(alpha[j])


@wp.func
def chord_moments(mu: wp.float64, half: wp.float64) -> wp.vec3d:
    """asg_bake._chord_moments: (S0, S2, S4) = ∫_{−B}^{B} b^{2k} e^{−μb²} db, B = half, by erf and parts, or by the
    series where μB² < 1."""
    x = mu * half * half
    if x < D1:
        h2 = half * half
        term = wp.float64(2.0) * half
        s0 = D0
        s2 = D0
        s4 = D0
        for m in range(CHORD_TERMS):
            s0 += term * INV_ODD[m]
            s2 += term * h2 * INV_ODD[m + 1]
            s4 += term * h2 * h2 * INV_ODD[m + 2]
            term = term * (-x) * INV_NEXT[m]
            if wp.abs(term) < CHORD_DONE * s0:
                break
        return wp.vec3d(s0, s2, s4)
    e = wp.exp(-x)
    c0 = wp.sqrt(PI64 / mu) * wp.erf(wp.sqrt(x))
    c2 = (c0 - wp.float64(2.0) * half * e) / (wp.float64(2.0) * mu)
    c4 = (wp.float64(3.0) * c2 - wp.float64(2.0) * half * half * half * e) / (wp.float64(2.0) * mu)
    return wp.vec3d(c0, c2, c4)


@wp.func
def disk_moments(lam: wp.float64, mu: wp.float64, lane: int, width: int) -> vec5d:
    """(E[a²], E[b²], E[a⁴], E[b⁴], E[a²b²]) of exp(−λa² − μb²) on the unit disk (asg_bake._disk_moments), the
    48 nodes shared by the block (node i by lane i mod width), every thread getting the block's sums."""
    amax = wp.min(D1, wp.float64(6.0) / wp.sqrt(wp.float64(2.0) * lam))
    bcap = wp.float64(6.0) / wp.sqrt(wp.float64(2.0) * mu)
    part = vec6d(D0, D0, D0, D0, D0, D0)  # [z, Σa², Σb², Σa⁴, Σb⁴, Σa²b²] (weighted)
    for i in range(lane, 48, width):
        a = amax * GL48_X[i]
        a2 = a * a
        wa = amax * GL48_W[i] * wp.exp(-lam * a2)
        chord = chord_moments(mu, wp.min(wp.sqrt(wp.max(D1 - a2, D0)), bcap))
        part += vec6d(wa * chord[0], wa * a2 * chord[0], wa * chord[1], wa * a2 * a2 * chord[0], wa * chord[2],
                      wa * a2 * chord[1])
    s = wp.tile_sum(wp.tile(part, preserve_type=True))[0]
    z = s[0]
    return vec5d(s[1] / z, s[2] / z, s[3] / z, s[4] / z, s[5] / z)


@wp.func
def bandwidths(ma: wp.float64, mb: wp.float64, prev_lam: wp.float64, prev_mu: wp.float64, lo: wp.float64,
               hi: wp.float64, lane: int, width: int) -> wp.vec2d:
    """asg_bake.bandwidths_from_moments with start=(prev_lam, prev_mu), in log bandwidths clipped to [lo, hi];
    called by every thread of a block alike (its disk moments are block sums)."""
    t0 = wp.clamp(wp.log(wp.float64(0.5) / wp.max(ma, TINY)), lo, hi)
    t1 = wp.clamp(wp.log(wp.float64(0.5) / wp.max(mb, TINY)), lo, hi)
    if wp.float64(18.0) / wp.exp(t0) + wp.float64(18.0) / wp.exp(t1) > D1:  # not inside the disk: warm start
        t0 = wp.clamp(wp.log(prev_lam), lo, hi)
        t1 = wp.clamp(wp.log(prev_mu), lo, hi)
    for _ in range(NEWTON_STEPS):
        lam = wp.exp(t0)
        mu = wp.exp(t1)
        m = disk_moments(lam, mu, lane, width)
        f0 = m[0] - ma
        f1 = m[1] - mb
        j00 = -lam * (m[2] - m[0] * m[0])
        j01 = -mu * (m[4] - m[0] * m[1])
        j10 = -lam * (m[4] - m[0] * m[1])
        j11 = -mu * (m[3] - m[1] * m[1])
        det = j00 * j11 - j01 * j10
        s0 = D0
        s1 = D0
        if wp.abs(det) > TINY:
            s0 = wp.clamp((j11 * f0 - j01 * f1) / det, wp.float64(-2.0), wp.float64(2.0))
            s1 = wp.clamp((j00 * f1 - j10 * f0) / det, wp.float64(-2.0), wp.float64(2.0))
        n0 = wp.clamp(t0 - s0, lo, hi)
        n1 = wp.clamp(t1 - s1, lo, hi)
        done = wp.abs(n0 - t0) < NEWTON_DONE and wp.abs(n1 - t1) < NEWTON_DONE
        t0 = n0
        t1 = n1
        if done:
            break
    return wp.vec2d(wp.exp(t0), wp.exp(t1))


@wp.kernel
def asg_em_responsibilities(
    bin_normal: wp.array(dtype=wp.vec3d),
    bin_weight: wp.array(dtype=wp.float64),
    lobes: wp.array2d(dtype=wp.float64),
    alpha: wp.array(dtype=wp.float64),
    state: wp.array(dtype=wp.int32),
    offset: int,
    resp_weight: wp.array2d(dtype=wp.float64),
    seen_weight: wp.array(dtype=wp.float64),
):
    """resp_weight[l, j] = r_lj·w_l (the E-step's responsibilities times the bin's weight); seen_weight[l] = w_l,
    or 0 where the normal is below every live lobe's horizon (it takes no part)."""
    if state[0] != 0:
        return
    l = wp.tid() + offset
    n = bin_normal[l]
    n_lobes = lobes.shape[0]
    top = NEG
    for j in range(n_lobes):
        top = wp.max(top, log_density(lobes, alpha, j, n))
    if top <= NEG:
        for j in range(n_lobes):
            resp_weight[l, j] = D0
        seen_weight[l] = D0
        return
    total = D0
    for j in range(n_lobes):
        lp = log_density(lobes, alpha, j, n)
        e = D0
        if lp > NEG:
            e = wp.exp(lp - top)
        resp_weight[l, j] = e
        total += e
    scale = bin_weight[l] / total
    for j in range(n_lobes):
        resp_weight[l, j] = resp_weight[l, j] * scale
    seen_weight[l] = bin_weight[l]


@wp.kernel
def asg_em_m_step(
    bin_normal: wp.array(dtype=wp.vec3d),
    seen_weight: wp.array(dtype=wp.float64),
    resp_weight: wp.array2d(dtype=wp.float64),
    lobes: wp.array2d(dtype=wp.float64),
    dead_mass: wp.float64,
    log_min: wp.float64,
    log_max: wp.float64,
    state: wp.array(dtype=wp.int32),
    offset: int,
    new_lobes: wp.array2d(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    moved: wp.array(dtype=wp.float64),
):
    """asg_bake._m_step for lobe j, one block a lobe (launch_tiled, dim [J]; on the CPU a block of one): its new
    row, its mass (0 if it died) and how far it moved (the larger of 1 − cos between the axes and |Δ log λ|,
    |Δ log μ|). The block's threads take the bins lane, lane + block_dim, … and the block sums their shares; every
    thread then solves the lobe's frame and bandwidths alike (the Newton's disk moments shared node by node), and
    lane 0 writes them."""
    if state[0] != 0:
        return
    block, lane = wp.tid()
    j = block + offset
    width = wp.block_dim()
    n_bins = bin_normal.shape[0]
    part = wp.vec4d(D0, D0, D0, D0)  # [Σ r, Σ r·n]
    part_total = D0
    for l in range(lane, n_bins, width):
        r = resp_weight[l, j]
        n = bin_normal[l]
        part += wp.vec4d(r, r * n[0], r * n[1], r * n[2])
        part_total += seen_weight[l]
    sums = wp.tile_sum(wp.tile(part, preserve_type=True))[0]
    total = wp.tile_sum(wp.tile(part_total))[0]
    m_j = sums[0]
    mean = wp.vec3d(sums[1], sums[2], sums[3])
    prev_x = lobe_vec(lobes, j, 0)
    prev_z = lobe_vec(lobes, j, 6)
    prev_lam = lobes[j, 9]
    prev_mu = lobes[j, 10]
    norm = wp.length(mean)
    live = m_j > dead_mass * total and norm > D0
    z = prev_z
    if live:
        z = mean / norm
    x0 = frame_x(z)
    y0 = frame_y(z)
    part = wp.vec4d(D0, D0, D0, D0)  # [Σ r, Σ r·a², Σ r·b², Σ r·ab] over the bins in z's hemisphere
    for l in range(lane, n_bins, width):
        n = bin_normal[l]
        if wp.dot(n, z) > D0:
            r = resp_weight[l, j]
            a = wp.dot(n, x0)
            b = wp.dot(n, y0)
            part += wp.vec4d(r, r * a * a, r * b * b, r * a * b)
    second = wp.tile_sum(wp.tile(part, preserve_type=True))[0]
    m2 = second[0]
    mm = wp.max(m2, TINY)
    caa = second[1] / mm
    cbb = second[2] / mm
    cab = second[3] / mm
    # The 2×2 covariance's smaller eigenvalue e0 (its eigenvector → x, the larger λ) and the larger e1.
    mid = wp.float64(0.5) * (caa + cbb)
    d = wp.sqrt(wp.float64(0.25) * (caa - cbb) * (caa - cbb) + cab * cab)
    e0 = mid - d
    e1 = mid + d
    u = wp.vec2d(cab, e0 - caa)  # (A − e0 I)u = 0 from either row: the longer of the two
    v = wp.vec2d(cbb - e0, -cab)
    if wp.dot(v, v) > wp.dot(u, u):
        u = v
    if wp.dot(u, u) > D0:
        u = u / wp.length(u)
    else:
        u = wp.vec2d(D1, D0)
    bw = bandwidths(wp.max(e0, D0), wp.max(e1, D0), prev_lam, prev_mu, log_min, log_max, lane, width)
    keep = live and m2 > TINY
    x = prev_x
    lam = prev_lam
    mu = prev_mu
    log_norm = lobes[j, 11]
    if keep:
        x = u[0] * x0 + u[1] * y0
        lam = bw[0]
        mu = bw[1]
        log_norm = wp.float64(wp.log(asg_unit_integral(float(lam), float(mu))))
    else:
        z = prev_z
    y = wp.cross(z, x)
    if lane != 0:
        return
    for k in range(3):
        new_lobes[j, k] = x[k]
        new_lobes[j, 3 + k] = y[k]
        new_lobes[j, 6 + k] = z[k]
    new_lobes[j, 9] = lam
    new_lobes[j, 10] = mu
    new_lobes[j, 11] = log_norm
    mass[j] = wp.where(keep, m_j, D0)
    dz = z - prev_z
    moved[j] = wp.max(wp.float64(0.5) * wp.dot(dz, dz), wp.max(wp.abs(wp.log(lam / prev_lam)),
                                                                 wp.abs(wp.log(mu / prev_mu))))


@wp.kernel
def asg_em_finish(
    new_lobes: wp.array2d(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    moved: wp.array(dtype=wp.float64),
    converged: wp.float64,
    offset: int,
    lobes: wp.array2d(dtype=wp.float64),
    alpha: wp.array(dtype=wp.float64),
    state: wp.array(dtype=wp.int32),
):
    """One thread: the step counted; with no mass left the EM stops where it was, else the new lobes and weights
    α_j = mass_j/Σ mass replace the old, and the EM is done once nothing moved by `converged` (asg_bake.fit_asg)."""
    if state[0] != 0:
        return
    state[1] = state[1] + 1
    n_lobes = lobes.shape[0]
    total = D0
    for j in range(n_lobes):
        total += mass[j]
    if not (total > D0):
        state[0] = 1
        return
    worst = D0
    for j in range(n_lobes):
        a = mass[j] / total
        worst = wp.max(worst, wp.max(moved[j], wp.abs(a - alpha[j])))
        alpha[j] = a
        for k in range(12):
            lobes[j, k] = new_lobes[j, k]
    if worst < converged:
        state[0] = 1
