"""Anisotropic spherical Gaussians (Xu et al. 2013) on the device: the asg stage.

Twin of ``cl/asg.cl``; the float64 reference is ``warp_biscale.asg`` (docs/design.md §9, "ASG device
functions"). An ASG is G(v) = c·max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) (Xu Eq. 1); our SG of sharpness η is
Xu's ν = η/2. The device functions (``wp.func``) are for the stages that will use ASGs (bake, shading);
the kernels at the end run each one over arrays of inputs, one thread per row, so that every function is
exercised on the device against its float64 oracle (tests/test_asg_kernels.py). Rows of ASGs travel as
(N, 12) float32: [x (3), y (3), z (3), λ, μ, c].

Numerics (measured in tests/test_asg_kernels.py, quoted in docs/design.md §9):
- i0e(x) = e^{−x}I0(x): Cephes' single-precision Chebyshev expansions (S. Moshier, i0f.c: 18 terms of
  e^{−x}I0(x) on [0, 8] in x/2 − 2, 7 terms of √x·e^{−x}I0(x) beyond in 32/x − 2): within 1.6e−8 relative
  of scipy's i0e as published, 1.4e−7 with the coefficients rounded to float32, 4.0e−7 evaluated in
  float32 (≈ 7 ulp: that rounding and Clenshaw's recurrence near the interval's ends).
- The integral: `asg_unit_integral` is the reference's exact 1-D form π∫₀¹e^{−sμ'}i0e(s(λ'−μ')/2)ds by a
  fixed 56-node Gauss–Legendre rule (t = √s; one panel [0, t0], six geometric panels t0 … 1,
  t0 = 1/√(1 + λ')), whose rule error is < 2.7e−7 relative for λ, μ ∈ [0, 1e6] (bands and λ = μ
  included; the kernel 6.2e−7 with float32 rounding) — float32-exact for every ASG, at ~56 exponentials.
  `asg_integral_eq10` (Xu Eq. 10, written without cancellation as the reference does; +∞ on a band) and
  `asg_integral_eq11` (π/√(λμ)) are the cheap forms, with Xu's errors.
- The product (Eq. 13) needs the smallest eigenvalue w0 of A3 = A1 + A2, whose e^{−w0} is the amplitude:
  float32 gives w0 only to ~ε·‖A3‖ (a float32 eigensolver on the test's pairs: up to 0.037, a 3.7 %
  amplitude error, where a bandwidth is ~1e6), so A3 is formed and diagonalised (cyclic Jacobi) in
  float64, as docs/design.md §4.8 asks where float32 loses the answer.
- The warp (Eq. 23–26) solves its 2×2 quadratic form in closed form: the large eigenvalue from the trace
  and discriminant (no cancellation), the small one as det/large with det = λμ·det(J)² exactly, so a
  streak (λ/μ = 1e4) keeps its small bandwidth to float32 precision.
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

PI = wp.constant(3.14159265358979)
FLOAT_MAX = wp.constant(3.4028234e38)

# Cephes i0f.c: Chebyshev coefficients of e^{−x}I0(x) on [0, 8] (argument x/2 − 2) and of √x·e^{−x}I0(x)
# on (8, ∞) (argument 32/x − 2), highest order first, as chbevl takes them (the float64 values here; the
# device holds them rounded to float32).
vec18 = wp.types.vector(length=18, dtype=wp.float32)
vec7 = wp.types.vector(length=7, dtype=wp.float32)
vec8 = wp.types.vector(length=8, dtype=wp.float32)
I0E_A_COEFFS = (
    -1.30002500998624804212e-8, 6.04699502254191894932e-8, -2.67079385394061173391e-7, 1.11738753912010371815e-6,
    -4.41673835845875056359e-6, 1.64484480707288970893e-5, -5.75419501008210370398e-5, 1.88502885095841655729e-4,
    -5.76375574538582365885e-4, 1.63947561694133579842e-3, -4.32430999505057594430e-3, 1.05464603945949983183e-2,
    -2.37374148058994688156e-2, 4.93052842396707084878e-2, -9.49010970480476444210e-2, 1.71620901522208775349e-1,
    -3.04682672343198398683e-1, 6.76795274409476084995e-1)
I0E_B_COEFFS = (
    3.39623202570838634515e-9, 2.26666899049817806459e-8, 2.04891858946906374183e-7, 2.89137052083475648297e-6,
    6.88975834691682398426e-5, 3.36911647825569408990e-3, 8.04490411014108831608e-1)
I0E_A = wp.constant(vec18(*I0E_A_COEFFS))  # rounded to float32: 1.4e−7 relative on [0, 8] (tests)
I0E_B = wp.constant(vec7(*I0E_B_COEFFS))

# 8-point Gauss–Legendre nodes and weights on [−1, 1] (numpy.polynomial.legendre.leggauss(8)).
GL_X = wp.constant(vec8(-0.9602898564975363, -0.7966664774136267, -0.5255324099163290, -0.1834346424956498,
                        0.1834346424956498, 0.5255324099163290, 0.7966664774136267, 0.9602898564975363))
GL_W = wp.constant(vec8(0.1012285362903763, 0.2223810344533745, 0.3137066458778873, 0.3626837833783620,
                        0.3626837833783620, 0.3137066458778873, 0.2223810344533745, 0.1012285362903763))
INTEGRAL_PANELS = wp.constant(6)  # geometric panels of asg_unit_integral between t0 and 1

# float64 constants of the product (Warp does not mix float32 literals into float64 arithmetic).
D0 = wp.constant(wp.float64(0.0))
D1 = wp.constant(wp.float64(1.0))
D2 = wp.constant(wp.float64(2.0))
DEGENERATE = wp.constant(wp.float64(1.0e-12))  # asg.product's tie tolerance, relative to max(w2, 1)
JACOBI_DONE = wp.constant(wp.float64(1.0e-34))  # off-diagonal² / ‖A‖² below this: eigenvalues to ~1e−17‖A‖


@wp.struct
class Asg:
    """One ASG: frame x, y, z, bandwidths lam, mu (Xu's λ, μ ≥ 0) and amplitude c."""
    x: wp.vec3
    y: wp.vec3
    z: wp.vec3
    lam: float
    mu: float
    c: float


@wp.func
def asg_load(rows: wp.array2d(dtype=wp.float32), i: int) -> Asg:
    g = Asg()
    g.x = wp.vec3(rows[i, 0], rows[i, 1], rows[i, 2])
    g.y = wp.vec3(rows[i, 3], rows[i, 4], rows[i, 5])
    g.z = wp.vec3(rows[i, 6], rows[i, 7], rows[i, 8])
    g.lam = rows[i, 9]
    g.mu = rows[i, 10]
    g.c = rows[i, 11]
    return g


@wp.func
def asg_store(rows: wp.array2d(dtype=wp.float32), i: int, g: Asg):
    for k in range(3):
        rows[i, k] = g.x[k]
        rows[i, 3 + k] = g.y[k]
        rows[i, 6 + k] = g.z[k]
    rows[i, 9] = g.lam
    rows[i, 10] = g.mu
    rows[i, 11] = g.c


@wp.func
def asg_eval(g: Asg, v: wp.vec3) -> float:
    """G(v) = c·max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) (Xu Eq. 1): every exponent ≤ 0, no overflow."""
    t = wp.dot(v, g.z)
    if t <= 0.0:
        return 0.0
    a = wp.dot(v, g.x)
    b = wp.dot(v, g.y)
    return g.c * t * wp.exp(-g.lam * a * a - g.mu * b * b)


@wp.func
def tangent_frame_x(z: wp.vec3) -> wp.vec3:
    """Duff et al. 2017's x of a frame (x, y, z) for unit z (asg.tangent_frame): exact at the poles."""
    s = float(1.0)
    if z[2] < 0.0:
        s = -1.0
    a = -1.0 / (s + z[2])
    return wp.vec3(1.0 + s * z[0] * z[0] * a, s * z[0] * z[1] * a, -s * z[0])


@wp.func
def tangent_frame_y(z: wp.vec3) -> wp.vec3:
    """Duff et al. 2017's y of that frame (right-handed: y = z × x)."""
    s = float(1.0)
    if z[2] < 0.0:
        s = -1.0
    a = -1.0 / (s + z[2])
    return wp.vec3(z[0] * z[1] * a, s + z[1] * z[1] * a, -z[1])


@wp.func
def asg_from_sg(axis: wp.vec3, eta: float, amplitude: float) -> Asg:
    """Xu Eq. 3: our SG a·exp(η(v·ξ − 1)) as the isotropic ASG λ = μ = η/2, c = a (asg.from_sg)."""
    g = Asg()
    g.z = wp.normalize(axis)
    g.x = tangent_frame_x(g.z)
    g.y = tangent_frame_y(g.z)
    g.lam = 0.5 * eta
    g.mu = 0.5 * eta
    g.c = amplitude
    return g


# ---------------------------------------------------------------------------------------------------
# The scaled Bessel function and the integral (Xu §4.1)
# ---------------------------------------------------------------------------------------------------

@wp.func
def chbevl_a(x: float) -> float:
    """Cephes chbevl over I0E_A (Clenshaw's recurrence)."""
    b0 = I0E_A[0]
    b1 = float(0.0)
    b2 = float(0.0)
    for k in range(1, 18):
        b2 = b1
        b1 = b0
        b0 = x * b1 - b2 + I0E_A[k]
    return 0.5 * (b0 - b2)


@wp.func
def chbevl_b(x: float) -> float:
    b0 = I0E_B[0]
    b1 = float(0.0)
    b2 = float(0.0)
    for k in range(1, 7):
        b2 = b1
        b1 = b0
        b0 = x * b1 - b2 + I0E_B[k]
    return 0.5 * (b0 - b2)


@wp.func
def bessel_i0e(x: float) -> float:
    """e^{−|x|}I0(x) (scipy.special.i0e) by Cephes i0f's expansions; → 1/√(2πx) for large x."""
    ax = wp.abs(x)
    if ax <= 8.0:
        return chbevl_a(0.5 * ax - 2.0)
    return chbevl_b(32.0 / ax - 2.0) / wp.sqrt(ax)


@wp.func
def expm1_small(x: float) -> float:
    """e^x − 1 without the cancellation of exp(x) − 1 for |x| < 0.5 (Taylor to x⁹, truncation < 3e−10
    relative; Warp has no expm1); exp(x) − 1 beyond, where it loses < 2 ulp."""
    if wp.abs(x) < 0.5:
        return x * (1.0 + x / 2.0 * (1.0 + x / 3.0 * (1.0 + x / 4.0 * (1.0 + x / 5.0 * (
            1.0 + x / 6.0 * (1.0 + x / 7.0 * (1.0 + x / 8.0 * (1.0 + x / 9.0))))))))
    return wp.exp(x) - 1.0


@wp.func
def bessel_i0e_minus_one(x: float) -> float:
    """i0e(x) − 1 for x ≥ 0 without cancellation at small x (asg._i0e_minus_one): below 0.5,
    e^{−x}(I0 − 1) + expm1(−x) with I0 − 1 = Σ_{k≥1}(x²/4)^k/k!² to k = 5 (truncation < 1e−10)."""
    if x < 0.5:
        q = 0.25 * x * x
        series = q * (1.0 + q / 4.0 * (1.0 + q / 9.0 * (1.0 + q / 16.0 * (1.0 + q / 25.0))))
        return wp.exp(-x) * series + expm1_small(-x)
    return bessel_i0e(x) - 1.0


@wp.func
def asg_integral_eq10(lam: float, mu: float) -> float:
    """Xu Eq. 10 for λ, μ ≥ 0, in the reference's rearrangement (asg._integral_eq10: ν = λ' − μ',
    (π/λ')·[ν/(√(λ'μ') + μ') − expm1(−μ') − e^{−μ'}(i0e(ν/2) − 1) − e^{−μ'}(ν/μ')i0e((ν + ν/μ')/2)]) so
    that λ = μ gives π(1 − e^{−μ})/μ to rounding. Xu's bounds: < 0.027 % relative for λ, μ > 5, 5.2 % for
    λ, μ > 1; it diverges as min(λ, μ) → 0 and is +∞ on a band (min = 0 < max), as the reference."""
    hi = wp.max(lam, mu)
    lo = wp.min(lam, mu)
    if hi <= 0.0:
        return PI
    if lo <= 0.0:
        return wp.inf
    nu = hi - lo
    band = float(0.0)
    if nu > 0.0:
        ratio = nu / lo
        band = ratio * bessel_i0e(0.5 * (nu + ratio))
    e = wp.exp(-lo)
    bracket = nu / (wp.sqrt(hi * lo) + lo) - expm1_small(-lo) - e * bessel_i0e_minus_one(0.5 * nu) - e * band
    value = PI / hi * bracket
    if not (value <= FLOAT_MAX):  # overflow (μ' ≪ 1: ν/μ' huge) or inf·0: the limit is +∞
        return wp.inf
    return value


@wp.func
def asg_integral_eq11(lam: float, mu: float) -> float:
    """Xu Eq. 11, π/√(λμ): < 0.68 % relative for λ, μ > 5 (worst at 5); +∞ on a band."""
    p = lam * mu
    if p <= 0.0:
        return wp.inf
    return PI / wp.sqrt(p)


@wp.func
def asg_unit_integral(lam: float, mu: float) -> float:
    """∫ max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) dv for any λ, μ ≥ 0 (asg.unit_integral "exact"): in disk
    coordinates it is π∫₀¹e^{−sμ'}i0e(s(λ' − μ')/2)ds (μ' = min, λ' = max; docs/design.md §9). In t = √s
    the integrand 2t·e^{−t²μ'}·i0e(t²(λ' − μ')/2) is smooth with scales 1/√μ' and 1/√(λ' − μ'); an
    8-node Gauss–Legendre rule on [0, t0] (t0 = 1/√(1 + λ'), where every exponent is ≤ 1) and on six
    geometric panels t0 … 1 resolves both to < 2.7e−7 relative for λ, μ ≤ 1e6 (1.4e−6 at 1e7)."""
    hi = wp.max(lam, mu)
    lo = wp.min(lam, mu)
    semi = 0.5 * (hi - lo)
    log_t0 = -0.5 * wp.log(1.0 + hi)
    total = float(0.0)
    left = float(0.0)
    for p in range(INTEGRAL_PANELS + 1):
        # Panel p ends at t0^(1 − p/6): t0 for the first, exactly 1 for the last (exp(0)).
        right = wp.exp((1.0 - float(p) / float(INTEGRAL_PANELS)) * log_t0)
        mid = 0.5 * (right + left)
        width = 0.5 * (right - left)
        for k in range(8):
            t = mid + width * GL_X[k]
            s = t * t
            total = total + width * GL_W[k] * (2.0 * t * wp.exp(-s * lo) * bessel_i0e(s * semi))
        left = right
    return PI * total


@wp.func
def asg_integral(g: Asg) -> float:
    """∫ G(v) dv = c·asg_unit_integral(λ, μ)."""
    return g.c * asg_unit_integral(g.lam, g.mu)


# ---------------------------------------------------------------------------------------------------
# Convolution with an SG (Xu §4.3, Eq. 18) and the SSDF's effective bandwidth (§5.3)
# ---------------------------------------------------------------------------------------------------

@wp.func
def harmonic(a: float, b: float) -> float:
    """ab/(a + b) = 1/(1/a + 1/b), 0 when either is 0 (asg._harmonic)."""
    if a > 0.0 and b > 0.0:
        return 1.0 / (1.0 / a + 1.0 / b)
    return 0.0


@wp.func
def asg_convolve_sg(g: Asg, eta: float, amplitude: float) -> Asg:
    """Xu Eq. 18: ∫ G(v)·a·exp(η(v·p − 1)) dv ≈ G(p; [x, y, z], [λν/(λ + ν), μν/(μ + ν)],
    c·a·π/√((λ + ν)(μ + ν))), ν = η/2 (asg.convolve_sg; harmonic bandwidths, so a band stays a band)."""
    nu = 0.5 * eta
    r = Asg()
    r.x = g.x
    r.y = g.y
    r.z = g.z
    r.lam = harmonic(g.lam, nu)
    r.mu = harmonic(g.mu, nu)
    r.c = g.c * amplitude * PI / wp.sqrt((g.lam + nu) * (g.mu + nu))
    return r


@wp.func
def asg_convolve_asg(g: Asg, lam_s: float, mu_s: float, oc: float, os: float) -> Asg:
    """G convolved with an anisotropic small-scale NDF of bandwidths (λ_s, μ_s) whose facets' doubled tangent
    angles in G's frame have the mean (oc, os): Gaussian covariances added in G's tangent plane
    (asg.convolve_asg, its stable forms)."""
    sx = 0.5 / lam_s
    sy = 0.5 / mu_s
    mean = 0.5 * (sx + sy)
    half = 0.5 * (sx - sy)
    s00 = mean + half * oc
    s01 = half * os
    s11 = mean - half * oc
    det_s = sx * sy + half * half * wp.max(1.0 - oc * oc - os * os, 0.0)
    det = 1.0 + 2.0 * s00 * g.lam + 2.0 * s11 * g.mu + 4.0 * g.lam * g.mu * det_s
    c00 = g.lam * (1.0 + 2.0 * s11 * g.mu) / det
    c11 = g.mu * (1.0 + 2.0 * s00 * g.lam) / det
    c01 = -2.0 * g.lam * g.mu * s01 / det
    big = 0.5 * (c00 + c11) + wp.sqrt(0.25 * (c00 - c11) * (c00 - c11) + c01 * c01)
    small = float(0.0)
    if big > 0.0:
        small = wp.min(g.lam * g.mu / det / big, big)
    psi = 0.5 * wp.atan2(2.0 * c01, c00 - c11)
    cp = wp.cos(psi)
    sp = wp.sin(psi)
    r = Asg()
    r.x = cp * g.x + sp * g.y
    r.y = cp * g.y - sp * g.x
    r.z = g.z
    r.lam = big
    r.mu = small
    r.c = g.c * PI / wp.sqrt(det * lam_s * mu_s)
    return r


@wp.func
def asg_effective_sharpness(g: Asg) -> float:
    """Our SG sharpness of the circle that stands in for the ASG's ellipse in the SSDF visibility
    (Xu §5.3): η = 2√(λμ), Xu's bandwidth √(λμ) read in his ν = η/2 units (asg.effective_sharpness)."""
    return 2.0 * wp.sqrt(g.lam * g.mu)


# ---------------------------------------------------------------------------------------------------
# Product (Xu §4.2, Eq. 13), in float64
# ---------------------------------------------------------------------------------------------------

@wp.func
def add_form(a: wp.mat33d, w: float, u: wp.vec3) -> wp.mat33d:
    """a + w·uuᵀ in float64 (an ASG's quadratic form λxxᵀ + μyyᵀ, one term)."""
    wd = wp.float64(w)
    ud = wp.vec3d(wp.float64(u[0]), wp.float64(u[1]), wp.float64(u[2]))
    return a + wd * wp.outer(ud, ud)


@wp.func
def jacobi_rotate(a: wp.mat33d, v: wp.mat33d, p: int, q: int):
    """One Jacobi rotation zeroing a[p, q] (Numerical Recipes §11.1); v accumulates the eigenvectors as
    columns."""
    apq = a[p, q]
    if apq != D0:
        r = 3 - p - q
        theta = (a[q, q] - a[p, p]) / (D2 * apq)
        t = D1 / (wp.abs(theta) + wp.sqrt(theta * theta + D1))
        if wp.abs(theta) > wp.float64(1.0e150):  # θ² would overflow: t → 1/(2θ)
            t = wp.float64(0.5) / wp.abs(theta)
        if theta < D0:
            t = -t
        c = D1 / wp.sqrt(t * t + D1)
        s = t * c
        app = a[p, p] - t * apq
        aqq = a[q, q] + t * apq
        arp = c * a[r, p] - s * a[r, q]
        arq = s * a[r, p] + c * a[r, q]
        a[p, p] = app
        a[q, q] = aqq
        a[p, q] = D0
        a[q, p] = D0
        a[r, p] = arp
        a[p, r] = arp
        a[r, q] = arq
        a[q, r] = arq
        for k in range(3):
            vkp = v[k, p]
            vkq = v[k, q]
            v[k, p] = c * vkp - s * vkq
            v[k, q] = s * vkp + c * vkq
    return a, v


@wp.func
def col(v: wp.mat33d, j: int) -> wp.vec3d:
    return wp.vec3d(v[0, j], v[1, j], v[2, j])


@wp.func
def asg_product(g1: Asg, g2: Asg) -> Asg:
    """Xu Eq. 13 (asg.product): G1·G2 ≈ S(z3; z1, z2)·e^{−w0}·G(v; [x3, y3, z3], [w2' − w0, w1' − w0]) with
    A3 = λ1x1x1ᵀ + μ1y1y1ᵀ + λ2x2x2ᵀ + μ2y2y2ᵀ, w0 ≤ w1 ≤ w2 its eigenvalues, z3 the eigenvector of w0
    turned to the side of z1 + z2, x3 that of w2; the smooth terms are taken at z3. Ties as the reference:
    where w1 − w0 (or w2 − w0) ≤ 1e−12·max(w2, 1), z3 is z1 + z2 projected on the tied eigenspace, and
    x3 is Duff's tangent of z3 if all three tie. Computed in float64 (module notes)."""
    a3 = wp.mat33d()
    a3 = add_form(a3, g1.lam, g1.x)
    a3 = add_form(a3, g1.mu, g1.y)
    a3 = add_form(a3, g2.lam, g2.x)
    a3 = add_form(a3, g2.mu, g2.y)
    a = a3
    v = wp.identity(n=3, dtype=wp.float64)
    scale = D0
    for i in range(3):
        for j in range(3):
            scale = scale + a3[i, j] * a3[i, j]
    for _sweep in range(12):  # cyclic Jacobi: a 3×3 converges quadratically, in ~4–5 sweeps
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        if off > JACOBI_DONE * scale:
            a, v = jacobi_rotate(a, v, 0, 1)
            a, v = jacobi_rotate(a, v, 0, 2)
            a, v = jacobi_rotate(a, v, 1, 2)
    # Sort the eigenvalues ascending: i0 the smallest, i2 the largest.
    i0 = 0
    i2 = 0
    for k in range(1, 3):
        if a[k, k] < a[i0, i0]:
            i0 = k
        if a[k, k] > a[i2, i2]:
            i2 = k
    if i0 == i2:  # all three equal
        i2 = 2
        i0 = 0
    i1 = 3 - i0 - i2
    w0 = a[i0, i0]
    w1 = a[i1, i1]
    w2 = a[i2, i2]
    q0 = col(v, i0)
    q1 = col(v, i1)
    q2 = col(v, i2)
    z1 = wp.vec3d(wp.float64(g1.z[0]), wp.float64(g1.z[1]), wp.float64(g1.z[2]))
    z2 = wp.vec3d(wp.float64(g2.z[0]), wp.float64(g2.z[1]), wp.float64(g2.z[2]))
    zsum = z1 + z2
    tol = DEGENERATE * wp.max(w2, D1)
    deg1 = (w1 - w0) <= tol
    deg2 = (w2 - w0) <= tol
    proj = q0
    if deg1:
        proj = wp.dot(zsum, q0) * q0 + wp.dot(zsum, q1) * q1
    if deg2:
        proj = zsum
    pn = wp.length(proj)
    z3 = q0
    if pn > wp.float64(1.0e-12):  # asg.product: a zero projection keeps q0
        z3 = proj / pn
    if wp.dot(z3, zsum) < D0:
        z3 = -z3
    x3 = q2
    if deg2:  # Duff's tangent of z3, in float64
        s = D1
        if z3[2] < D0:
            s = -D1
        da = -D1 / (s + z3[2])
        x3 = wp.vec3d(D1 + s * z3[0] * z3[0] * da, s * z3[0] * z3[1] * da, -s * z3[0])
    x3 = wp.normalize(x3 - wp.dot(x3, z3) * z3)
    y3 = wp.cross(z3, x3)
    r = Asg()
    r.x = wp.vec3(float(x3[0]), float(x3[1]), float(x3[2]))
    r.y = wp.vec3(float(y3[0]), float(y3[1]), float(y3[2]))
    r.z = wp.vec3(float(z3[0]), float(z3[1]), float(z3[2]))
    r.lam = float(wp.max(wp.dot(x3, a3 * x3) - w0, D0))
    r.mu = float(wp.max(wp.dot(y3, a3 * y3) - w0, D0))
    smooth = wp.max(wp.dot(z3, z1), D0) * wp.max(wp.dot(z3, z2), D0)
    r.c = float(wp.float64(g1.c) * wp.float64(g2.c) * smooth * wp.exp(-wp.max(w0, D0)))
    return r


# ---------------------------------------------------------------------------------------------------
# Spherical warp of an NDF lobe (Xu §5.2, Eq. 23–26)
# ---------------------------------------------------------------------------------------------------

@wp.func
def asg_warp(g: Asg, wo: wp.vec3) -> Asg:
    """The NDF lobe G_h(h) as an ASG in the light direction i, h = (i + o)/|i + o| (asg.warp): axis
    z_i = 2(o·z_h)z_h − o; with J = [x_h, y_h]ᵀT/(2 o·z_h) for a tangent basis T of z_i, the exponent is
    ≈ sᵀJᵀΛJs (asg.warp_hessian), whose eigenpairs are λ_i, μ_i and x_i, y_i; x_i is the one nearer x_h,
    signs follow x_h, y_h. Amplitude c, or 0 where o·z_h ≤ 0 (the view cannot see the lobe).

    The 2×2 form is solved on Q' = 4(o·z_h)²Q: its large eigenvalue from trace and discriminant, the
    small one as det(Q')/large with det(Q') = λμ·det(J')² (no cancellation for long streaks); o·z_h is
    held ≥ 1e−12 (the reference: 1e−100) so Q stays finite in float32 for a lobe at the view's horizon."""
    o = wp.normalize(wo)
    cos_d = wp.dot(o, g.z)
    zi = wp.normalize(2.0 * cos_d * g.z - o)
    # Xu's x'_i ⊥ o: o × z_h where defined (any tangent basis gives the same eigenpairs), Duff's frame at
    # normal view; made orthogonal to z_i again, as rounding leaves o × z_h off by ε/|o × z_h|.
    t1 = tangent_frame_x(zi)
    cross = wp.cross(o, g.z)
    if wp.length(cross) > 1.0e-4:
        t1 = wp.normalize(cross)
    t1 = wp.normalize(t1 - wp.dot(t1, zi) * zi)
    t2 = wp.cross(zi, t1)
    j00 = wp.dot(g.x, t1)
    j01 = wp.dot(g.x, t2)
    j10 = wp.dot(g.y, t1)
    j11 = wp.dot(g.y, t2)
    qa = g.lam * j00 * j00 + g.mu * j10 * j10
    qb = g.lam * j00 * j01 + g.mu * j10 * j11
    qd = g.lam * j01 * j01 + g.mu * j11 * j11
    det_j = j00 * j11 - j01 * j10
    semi = 0.5 * (qa - qd)
    big = 0.5 * (qa + qd) + wp.sqrt(semi * semi + qb * qb)
    small = float(0.0)
    if big > 0.0:
        small = wp.max(g.lam * g.mu * det_j * det_j / big, 0.0)
    # The eigenvector of `big`: (b, big − a) or (big − d, b), whichever is longer (both 0: Q' ∝ I).
    e = wp.vec2(qb, big - qa)
    e2 = wp.vec2(big - qd, qb)
    if wp.dot(e2, e2) > wp.dot(e, e):
        e = e2
    if wp.dot(e, e) > 0.0:
        e = wp.normalize(e)
    else:
        e = wp.vec2(1.0, 0.0)
    e_big = e[0] * t1 + e[1] * t2
    e_small = -e[1] * t1 + e[0] * t2
    c = wp.max(cos_d, 1.0e-12)
    scale = 1.0 / (4.0 * c * c)
    r = Asg()
    r.z = zi
    if wp.abs(wp.dot(e_small, g.x)) >= wp.abs(wp.dot(e_big, g.x)):
        r.x = e_small
        r.y = e_big
        r.lam = small * scale
        r.mu = big * scale
    else:
        r.x = e_big
        r.y = e_small
        r.lam = big * scale
        r.mu = small * scale
    if wp.dot(r.x, g.x) < 0.0:
        r.x = -r.x
    if wp.dot(r.y, g.y) < 0.0:
        r.y = -r.y
    r.c = 0.0
    if cos_d > 0.0:
        r.c = g.c
    return r


# ---------------------------------------------------------------------------------------------------
# Kernels: each operator over arrays of inputs, one thread per row (device.DeviceBackend.asg_*)
# ---------------------------------------------------------------------------------------------------

@wp.kernel
def asg_evaluate_rows(rows: wp.array2d(dtype=wp.float32), v: wp.array(dtype=wp.vec3), offset: int,
                      out: wp.array(dtype=wp.float32)):
    i = wp.tid() + offset
    out[i] = asg_eval(asg_load(rows, i), v[i])


@wp.kernel
def bessel_i0e_values(x: wp.array(dtype=wp.float32), offset: int, out: wp.array(dtype=wp.float32)):
    i = wp.tid() + offset
    out[i] = bessel_i0e(x[i])


@wp.kernel
def asg_integral_values(lam: wp.array(dtype=wp.float32), mu: wp.array(dtype=wp.float32), method: int,
                        offset: int, out: wp.array(dtype=wp.float32)):
    """method: 0 exact (asg_unit_integral), 1 Xu Eq. 10, 2 Xu Eq. 11 (DeviceBackend.ASG_INTEGRAL_METHODS)."""
    i = wp.tid() + offset
    if method == 0:
        out[i] = asg_unit_integral(lam[i], mu[i])
    elif method == 1:
        out[i] = asg_integral_eq10(lam[i], mu[i])
    else:
        out[i] = asg_integral_eq11(lam[i], mu[i])


@wp.kernel
def asg_convolve_rows(rows: wp.array2d(dtype=wp.float32), sharpness: wp.array(dtype=wp.float32),
                      amplitude: wp.array(dtype=wp.float32), offset: int, out: wp.array2d(dtype=wp.float32)):
    i = wp.tid() + offset
    asg_store(out, i, asg_convolve_sg(asg_load(rows, i), sharpness[i], amplitude[i]))


@wp.kernel
def asg_convolve_asg_rows(rows: wp.array2d(dtype=wp.float32), kernel: wp.array2d(dtype=wp.float32), offset: int,
                          out: wp.array2d(dtype=wp.float32)):
    """kernel rows: [λ_s, μ_s, o_c, o_s]."""
    i = wp.tid() + offset
    asg_store(out, i, asg_convolve_asg(asg_load(rows, i), kernel[i, 0], kernel[i, 1], kernel[i, 2], kernel[i, 3]))


@wp.kernel
def asg_product_rows(rows1: wp.array2d(dtype=wp.float32), rows2: wp.array2d(dtype=wp.float32), offset: int,
                     out: wp.array2d(dtype=wp.float32)):
    i = wp.tid() + offset
    asg_store(out, i, asg_product(asg_load(rows1, i), asg_load(rows2, i)))


@wp.kernel
def asg_warp_rows(rows: wp.array2d(dtype=wp.float32), wo: wp.array(dtype=wp.vec3), offset: int,
                  out: wp.array2d(dtype=wp.float32)):
    i = wp.tid() + offset
    asg_store(out, i, asg_warp(asg_load(rows, i), wo[i]))


@wp.kernel
def asg_from_sg_rows(axis: wp.array(dtype=wp.vec3), sharpness: wp.array(dtype=wp.float32),
                     amplitude: wp.array(dtype=wp.float32), offset: int, out: wp.array2d(dtype=wp.float32)):
    i = wp.tid() + offset
    asg_store(out, i, asg_from_sg(axis[i], sharpness[i], amplitude[i]))


@wp.kernel
def asg_sharpness_rows(rows: wp.array2d(dtype=wp.float32), offset: int, out: wp.array(dtype=wp.float32)):
    i = wp.tid() + offset
    out[i] = asg_effective_sharpness(asg_load(rows, i))
