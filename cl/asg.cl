/* Anisotropic spherical Gaussians (Xu et al. 2013) on the device: the asg stage.
 *
 * Twin of kernels/asg.py, in the same operation order; the float64 reference is warp_biscale.asg and
 * kernels/asg.py's docstring gives the numerics (Cephes i0f for i0e, the 56-node integral, the product in
 * double, the warp's closed-form 2x2 eigenpairs). G(v) = c·max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) (Xu Eq. 1);
 * our SG of sharpness η is Xu's ν = η/2. Layouts: ASG rows (N, 12) float [x, y, z, λ, μ, c]; 3-vectors
 * (N, 3) float; scalars (N,) float. The product needs cl_khr_fp64: it is built only where the device has it,
 * so that the shade stage, which takes this file's other functions (opencl_backend.USES), builds everywhere.
 */
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

#define ASG_PI 3.14159265358979f
#define ASG_FLOAT_MAX 3.4028234e38f
#define ASG_INTEGRAL_PANELS 6            /* geometric panels of asg_unit_integral between t0 and 1 */
#define ASG_DEGENERATE 1.0e-12           /* asg.product's tie tolerance, relative to max(w2, 1) */
#define ASG_JACOBI_DONE 1.0e-34          /* off-diagonal² / ‖A‖² below this: eigenvalues to ~1e-17‖A‖ */

/* Cephes i0f.c: Chebyshev coefficients of e^{-x}I0(x) on [0, 8] (argument x/2 − 2) and of
 * √x·e^{-x}I0(x) on (8, ∞) (argument 32/x − 2), highest order first. */
__constant float I0E_A[18] = {
    -1.30002500998624804212e-8f, 6.04699502254191894932e-8f, -2.67079385394061173391e-7f, 1.11738753912010371815e-6f,
    -4.41673835845875056359e-6f, 1.64484480707288970893e-5f, -5.75419501008210370398e-5f, 1.88502885095841655729e-4f,
    -5.76375574538582365885e-4f, 1.63947561694133579842e-3f, -4.32430999505057594430e-3f, 1.05464603945949983183e-2f,
    -2.37374148058994688156e-2f, 4.93052842396707084878e-2f, -9.49010970480476444210e-2f, 1.71620901522208775349e-1f,
    -3.04682672343198398683e-1f, 6.76795274409476084995e-1f};
__constant float I0E_B[7] = {
    3.39623202570838634515e-9f, 2.26666899049817806459e-8f, 2.04891858946906374183e-7f, 2.89137052083475648297e-6f,
    6.88975834691682398426e-5f, 3.36911647825569408990e-3f, 8.04490411014108831608e-1f};

/* 8-point Gauss–Legendre nodes and weights on [−1, 1]. */
__constant float GL_X[8] = {-0.9602898564975363f, -0.7966664774136267f, -0.5255324099163290f, -0.1834346424956498f,
                            0.1834346424956498f,  0.5255324099163290f,  0.7966664774136267f,  0.9602898564975363f};
__constant float GL_W[8] = {0.1012285362903763f, 0.2223810344533745f, 0.3137066458778873f, 0.3626837833783620f,
                            0.3626837833783620f, 0.3137066458778873f, 0.2223810344533745f, 0.1012285362903763f};

/* One ASG: frame x, y, z, bandwidths lam, mu (Xu's λ, μ ≥ 0) and amplitude c. */
typedef struct {
    float3 x, y, z;
    float lam, mu, c;
} Asg;

CL_INLINE Asg asg_load(__global const float *rows, int i)
{
    __global const float *r = rows + 12 * i;
    Asg g;
    g.x = (float3)(r[0], r[1], r[2]);
    g.y = (float3)(r[3], r[4], r[5]);
    g.z = (float3)(r[6], r[7], r[8]);
    g.lam = r[9];
    g.mu = r[10];
    g.c = r[11];
    return g;
}

CL_INLINE void asg_store(__global float *rows, int i, Asg g)
{
    __global float *r = rows + 12 * i;
    r[0] = g.x.x; r[1] = g.x.y; r[2] = g.x.z;
    r[3] = g.y.x; r[4] = g.y.y; r[5] = g.y.z;
    r[6] = g.z.x; r[7] = g.z.y; r[8] = g.z.z;
    r[9] = g.lam;
    r[10] = g.mu;
    r[11] = g.c;
}

/* G(v) = c·max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) (Xu Eq. 1): every exponent ≤ 0, no overflow. */
CL_INLINE float asg_eval(Asg g, float3 v)
{
    float t = dot3(v, g.z);
    if (t <= 0.0f)
        return 0.0f;
    float a = dot3(v, g.x);
    float b = dot3(v, g.y);
    return g.c * t * exp(-g.lam * a * a - g.mu * b * b);
}

/* Duff et al. 2017's frame (x, y, z = x × y) for unit z (asg.tangent_frame): exact at the poles. */
CL_INLINE float3 tangent_frame_x(float3 z)
{
    float s = z.z < 0.0f ? -1.0f : 1.0f;
    float a = -1.0f / (s + z.z);
    return (float3)(1.0f + s * z.x * z.x * a, s * z.x * z.y * a, -s * z.x);
}

CL_INLINE float3 tangent_frame_y(float3 z)
{
    float s = z.z < 0.0f ? -1.0f : 1.0f;
    float a = -1.0f / (s + z.z);
    return (float3)(z.x * z.y * a, s + z.y * z.y * a, -z.y);
}

/* Xu Eq. 3: our SG a·exp(η(v·ξ − 1)) as the isotropic ASG λ = μ = η/2, c = a (asg.from_sg). */
CL_INLINE Asg asg_from_sg(float3 axis, float eta, float amplitude)
{
    Asg g;
    g.z = normalize3(axis);
    g.x = tangent_frame_x(g.z);
    g.y = tangent_frame_y(g.z);
    g.lam = 0.5f * eta;
    g.mu = 0.5f * eta;
    g.c = amplitude;
    return g;
}

/* ------------------------------------------------------------------ the scaled Bessel function, the integral */

/* Cephes chbevl (Clenshaw's recurrence) over n coefficients. */
CL_INLINE float chbevl(float x, __constant const float *c, int n)
{
    float b0 = c[0], b1 = 0.0f, b2 = 0.0f;
    for (int k = 1; k < n; ++k) {
        b2 = b1;
        b1 = b0;
        b0 = x * b1 - b2 + c[k];
    }
    return 0.5f * (b0 - b2);
}

/* e^{-|x|}I0(x) (scipy.special.i0e) by Cephes i0f's expansions. */
CL_INLINE float bessel_i0e(float x)
{
    float ax = absf(x);
    if (ax <= 8.0f)
        return chbevl(0.5f * ax - 2.0f, I0E_A, 18);
    return chbevl(32.0f / ax - 2.0f, I0E_B, 7) / sqrt(ax);
}

/* e^x − 1 without cancellation for |x| < 0.5 (Taylor to x⁹), exp(x) − 1 beyond (the Warp twin has no
 * expm1, so both write it out). */
CL_INLINE float expm1_small(float x)
{
    if (absf(x) < 0.5f)
        return x * (1.0f + x / 2.0f * (1.0f + x / 3.0f * (1.0f + x / 4.0f * (1.0f + x / 5.0f * (
            1.0f + x / 6.0f * (1.0f + x / 7.0f * (1.0f + x / 8.0f * (1.0f + x / 9.0f))))))));
    return exp(x) - 1.0f;
}

/* i0e(x) − 1 for x ≥ 0 without cancellation at small x (asg._i0e_minus_one). */
CL_INLINE float bessel_i0e_minus_one(float x)
{
    if (x < 0.5f) {
        float q = 0.25f * x * x;
        float series = q * (1.0f + q / 4.0f * (1.0f + q / 9.0f * (1.0f + q / 16.0f * (1.0f + q / 25.0f))));
        return exp(-x) * series + expm1_small(-x);
    }
    return bessel_i0e(x) - 1.0f;
}

/* Xu Eq. 10 in the reference's rearrangement (asg._integral_eq10); +∞ on a band. */
CL_INLINE float asg_integral_eq10(float lam, float mu)
{
    float hi = fmax(lam, mu);
    float lo = fmin(lam, mu);
    if (hi <= 0.0f)
        return ASG_PI;
    if (lo <= 0.0f)
        return INFINITY;
    float nu = hi - lo;
    float band = 0.0f;
    if (nu > 0.0f) {
        float ratio = nu / lo;
        band = ratio * bessel_i0e(0.5f * (nu + ratio));
    }
    float e = exp(-lo);
    float bracket = nu / (sqrt(hi * lo) + lo) - expm1_small(-lo) - e * bessel_i0e_minus_one(0.5f * nu) - e * band;
    float value = ASG_PI / hi * bracket;
    if (!(value <= ASG_FLOAT_MAX)) /* overflow (μ' ≪ 1) or inf·0: the limit is +∞ */
        return INFINITY;
    return value;
}

/* Xu Eq. 11, π/√(λμ); +∞ on a band. */
CL_INLINE float asg_integral_eq11(float lam, float mu)
{
    float p = lam * mu;
    if (p <= 0.0f)
        return INFINITY;
    return ASG_PI / sqrt(p);
}

/* ∫ max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) dv for any λ, μ ≥ 0 (asg.unit_integral "exact"): π∫₀¹e^{−sμ'}
 * i0e(s(λ' − μ')/2)ds by 8-node Gauss–Legendre in t = √s on [0, t0] and six geometric panels t0 … 1. */
CL_INLINE float asg_unit_integral(float lam, float mu)
{
    float hi = fmax(lam, mu);
    float lo = fmin(lam, mu);
    float semi = 0.5f * (hi - lo);
    float log_t0 = -0.5f * log(1.0f + hi);
    float total = 0.0f;
    float left = 0.0f;
    for (int p = 0; p < ASG_INTEGRAL_PANELS + 1; ++p) {
        /* panel p ends at t0^(1 − p/6): t0 for the first, exactly 1 for the last */
        float right = exp((1.0f - (float)p / (float)ASG_INTEGRAL_PANELS) * log_t0);
        float mid = 0.5f * (right + left);
        float width = 0.5f * (right - left);
        for (int k = 0; k < 8; ++k) {
            float t = mid + width * GL_X[k];
            float s = t * t;
            total = total + width * GL_W[k] * (2.0f * t * exp(-s * lo) * bessel_i0e(s * semi));
        }
        left = right;
    }
    return ASG_PI * total;
}

CL_INLINE float asg_integral(Asg g) { return g.c * asg_unit_integral(g.lam, g.mu); }

/* ------------------------------------------------------------------ convolution with an SG, the SSDF bandwidth */

/* ab/(a + b), 0 when either is 0 (asg._harmonic). */
CL_INLINE float harmonic(float a, float b)
{
    if (a > 0.0f && b > 0.0f)
        return 1.0f / (1.0f / a + 1.0f / b);
    return 0.0f;
}

/* Xu Eq. 18 with ν = η/2 (asg.convolve_sg). */
CL_INLINE Asg asg_convolve_sg(Asg g, float eta, float amplitude)
{
    float nu = 0.5f * eta;
    Asg r;
    r.x = g.x;
    r.y = g.y;
    r.z = g.z;
    r.lam = harmonic(g.lam, nu);
    r.mu = harmonic(g.mu, nu);
    r.c = g.c * amplitude * ASG_PI / sqrt((g.lam + nu) * (g.mu + nu));
    return r;
}

/* G convolved with an anisotropic small-scale NDF (λ_s, μ_s) whose facets' doubled tangent angles in G's frame
   have the mean (oc, os): covariances added in G's tangent plane (asg.convolve_asg, its stable forms). */
CL_INLINE Asg asg_convolve_asg(Asg g, float lam_s, float mu_s, float oc, float os)
{
    float sx = 0.5f / lam_s, sy = 0.5f / mu_s;
    float mean = 0.5f * (sx + sy), spread = 0.5f * (sx - sy); /* (`half` is an OpenCL type) */
    float s00 = mean + spread * oc, s01 = spread * os, s11 = mean - spread * oc;
    float det_s = sx * sy + spread * spread * fmax(1.0f - oc * oc - os * os, 0.0f);
    float det = 1.0f + 2.0f * s00 * g.lam + 2.0f * s11 * g.mu + 4.0f * g.lam * g.mu * det_s;
    float c00 = g.lam * (1.0f + 2.0f * s11 * g.mu) / det;
    float c11 = g.mu * (1.0f + 2.0f * s00 * g.lam) / det;
    float c01 = -2.0f * g.lam * g.mu * s01 / det;
    float big = 0.5f * (c00 + c11) + sqrt(0.25f * (c00 - c11) * (c00 - c11) + c01 * c01);
    float small = big > 0.0f ? fmin(g.lam * g.mu / det / big, big) : 0.0f;
    float psi = 0.5f * atan2(2.0f * c01, c00 - c11);
    float cp = cos(psi), sp = sin(psi);
    Asg r;
    r.x = cp * g.x + sp * g.y;
    r.y = cp * g.y - sp * g.x;
    r.z = g.z;
    r.lam = big;
    r.mu = small;
    r.c = g.c * ASG_PI / sqrt(det * lam_s * mu_s);
    return r;
}

/* Our SG sharpness of the SSDF's stand-in circle, 2√(λμ) (asg.effective_sharpness). */
CL_INLINE float asg_effective_sharpness(Asg g) { return 2.0f * sqrt(g.lam * g.mu); }

/* ------------------------------------------------------------------ product (Xu Eq. 13), in double */
#ifdef cl_khr_fp64

/* a + w·uuᵀ (row-major 3×3 doubles). */
CL_INLINE void add_form(double *a, float w, float3 u)
{
    double wd = (double)w;
    double ud[3] = {(double)u.x, (double)u.y, (double)u.z};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            a[3 * i + j] = a[3 * i + j] + wd * (ud[i] * ud[j]);
}

/* One Jacobi rotation zeroing a[p][q] (Numerical Recipes §11.1); v's columns are the eigenvectors. */
CL_INLINE void jacobi_rotate(double *a, double *v, int p, int q)
{
    double apq = a[3 * p + q];
    if (apq == 0.0)
        return;
    int r = 3 - p - q;
    double theta = (a[3 * q + q] - a[3 * p + p]) / (2.0 * apq);
    double t = 1.0 / (fabs(theta) + sqrt(theta * theta + 1.0));
    if (fabs(theta) > 1.0e150) /* θ² would overflow: t → 1/(2θ) */
        t = 0.5 / fabs(theta);
    if (theta < 0.0)
        t = -t;
    double c = 1.0 / sqrt(t * t + 1.0);
    double s = t * c;
    double app = a[3 * p + p] - t * apq;
    double aqq = a[3 * q + q] + t * apq;
    double arp = c * a[3 * r + p] - s * a[3 * r + q];
    double arq = s * a[3 * r + p] + c * a[3 * r + q];
    a[3 * p + p] = app;
    a[3 * q + q] = aqq;
    a[3 * p + q] = 0.0;
    a[3 * q + p] = 0.0;
    a[3 * r + p] = arp;
    a[3 * p + r] = arp;
    a[3 * r + q] = arq;
    a[3 * q + r] = arq;
    for (int k = 0; k < 3; ++k) {
        double vkp = v[3 * k + p];
        double vkq = v[3 * k + q];
        v[3 * k + p] = c * vkp - s * vkq;
        v[3 * k + q] = s * vkp + c * vkq;
    }
}

CL_INLINE double dotd(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* Xu Eq. 13 (asg.product), A3 formed and diagonalised in double; ties as the reference. */
CL_INLINE Asg asg_product(Asg g1, Asg g2)
{
    double a3[9] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    add_form(a3, g1.lam, g1.x);
    add_form(a3, g1.mu, g1.y);
    add_form(a3, g2.lam, g2.x);
    add_form(a3, g2.mu, g2.y);
    double a[9], v[9] = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
    double scale = 0.0;
    for (int k = 0; k < 9; ++k) {
        a[k] = a3[k];
        scale = scale + a3[k] * a3[k];
    }
    for (int sweep = 0; sweep < 12; ++sweep) { /* cyclic Jacobi: ~4–5 sweeps for a 3×3 */
        double off = a[1] * a[1] + a[2] * a[2] + a[5] * a[5];
        if (off > ASG_JACOBI_DONE * scale) {
            jacobi_rotate(a, v, 0, 1);
            jacobi_rotate(a, v, 0, 2);
            jacobi_rotate(a, v, 1, 2);
        }
    }
    int i0 = 0, i2 = 0;
    for (int k = 1; k < 3; ++k) {
        if (a[4 * k] < a[4 * i0])
            i0 = k;
        if (a[4 * k] > a[4 * i2])
            i2 = k;
    }
    if (i0 == i2) { /* all three equal */
        i2 = 2;
        i0 = 0;
    }
    int i1 = 3 - i0 - i2;
    double w0 = a[4 * i0], w1 = a[4 * i1], w2 = a[4 * i2];
    double q0[3] = {v[i0], v[3 + i0], v[6 + i0]};
    double q1[3] = {v[i1], v[3 + i1], v[6 + i1]};
    double q2[3] = {v[i2], v[3 + i2], v[6 + i2]};
    double z1[3] = {(double)g1.z.x, (double)g1.z.y, (double)g1.z.z};
    double z2[3] = {(double)g2.z.x, (double)g2.z.y, (double)g2.z.z};
    double zsum[3] = {z1[0] + z2[0], z1[1] + z2[1], z1[2] + z2[2]};
    double tol = ASG_DEGENERATE * fmax(w2, 1.0);
    int deg1 = (w1 - w0) <= tol;
    int deg2 = (w2 - w0) <= tol;
    double proj[3] = {q0[0], q0[1], q0[2]};
    if (deg1) {
        double s0 = dotd(zsum, q0), s1 = dotd(zsum, q1);
        for (int k = 0; k < 3; ++k)
            proj[k] = s0 * q0[k] + s1 * q1[k];
    }
    if (deg2)
        for (int k = 0; k < 3; ++k)
            proj[k] = zsum[k];
    double pn = sqrt(dotd(proj, proj));
    double z3[3] = {q0[0], q0[1], q0[2]};
    if (pn > 1.0e-12) /* asg.product: a zero projection keeps q0 */
        for (int k = 0; k < 3; ++k)
            z3[k] = proj[k] / pn;
    if (dotd(z3, zsum) < 0.0)
        for (int k = 0; k < 3; ++k)
            z3[k] = -z3[k];
    double x3[3] = {q2[0], q2[1], q2[2]};
    if (deg2) { /* Duff's tangent of z3, in double */
        double s = z3[2] < 0.0 ? -1.0 : 1.0;
        double da = -1.0 / (s + z3[2]);
        x3[0] = 1.0 + s * z3[0] * z3[0] * da;
        x3[1] = s * z3[0] * z3[1] * da;
        x3[2] = -s * z3[0];
    }
    double xz = dotd(x3, z3);
    for (int k = 0; k < 3; ++k)
        x3[k] = x3[k] - xz * z3[k];
    double xn = sqrt(dotd(x3, x3));
    if (xn > 0.0)
        for (int k = 0; k < 3; ++k)
            x3[k] = x3[k] / xn;
    double y3[3] = {z3[1] * x3[2] - z3[2] * x3[1], z3[2] * x3[0] - z3[0] * x3[2], z3[0] * x3[1] - z3[1] * x3[0]};
    double ax[3], ay[3];
    for (int i = 0; i < 3; ++i) {
        ax[i] = a3[3 * i] * x3[0] + a3[3 * i + 1] * x3[1] + a3[3 * i + 2] * x3[2];
        ay[i] = a3[3 * i] * y3[0] + a3[3 * i + 1] * y3[1] + a3[3 * i + 2] * y3[2];
    }
    Asg r;
    r.x = (float3)((float)x3[0], (float)x3[1], (float)x3[2]);
    r.y = (float3)((float)y3[0], (float)y3[1], (float)y3[2]);
    r.z = (float3)((float)z3[0], (float)z3[1], (float)z3[2]);
    r.lam = (float)fmax(dotd(x3, ax) - w0, 0.0);
    r.mu = (float)fmax(dotd(y3, ay) - w0, 0.0);
    double smooth = fmax(dotd(z3, z1), 0.0) * fmax(dotd(z3, z2), 0.0);
    r.c = (float)((double)g1.c * (double)g2.c * smooth * exp(-fmax(w0, 0.0)));
    return r;
}
#endif

/* ------------------------------------------------------------------ spherical warp (Xu Eq. 23–26) */

/* The NDF lobe G_h(h) as an ASG in the light direction (asg.warp); see kernels/asg.py's asg_warp. */
CL_INLINE Asg asg_warp(Asg g, float3 wo)
{
    float3 o = normalize3(wo);
    float cos_d = dot3(o, g.z);
    float3 zi = normalize3((float3)(2.0f * cos_d * g.z.x - o.x, 2.0f * cos_d * g.z.y - o.y,
                                    2.0f * cos_d * g.z.z - o.z));
    float3 t1 = tangent_frame_x(zi);
    float3 cr = cross3(o, g.z);
    if (sqrt(dot3(cr, cr)) > 1.0e-4f)
        t1 = normalize3(cr);
    float t1z = dot3(t1, zi);
    t1 = normalize3((float3)(t1.x - t1z * zi.x, t1.y - t1z * zi.y, t1.z - t1z * zi.z));
    float3 t2 = cross3(zi, t1);
    float j00 = dot3(g.x, t1);
    float j01 = dot3(g.x, t2);
    float j10 = dot3(g.y, t1);
    float j11 = dot3(g.y, t2);
    float qa = g.lam * j00 * j00 + g.mu * j10 * j10;
    float qb = g.lam * j00 * j01 + g.mu * j10 * j11;
    float qd = g.lam * j01 * j01 + g.mu * j11 * j11;
    float det_j = j00 * j11 - j01 * j10;
    float semi = 0.5f * (qa - qd);
    float big = 0.5f * (qa + qd) + sqrt(semi * semi + qb * qb);
    float small = 0.0f;
    if (big > 0.0f)
        small = fmax(g.lam * g.mu * det_j * det_j / big, 0.0f);
    float e0 = qb, e1 = big - qa;
    float f0 = big - qd, f1 = qb;
    if (f0 * f0 + f1 * f1 > e0 * e0 + e1 * e1) {
        e0 = f0;
        e1 = f1;
    }
    float el2 = e0 * e0 + e1 * e1;
    if (el2 > 0.0f) {
        float el = sqrt(el2);
        e0 = e0 / el;
        e1 = e1 / el;
    } else {
        e0 = 1.0f;
        e1 = 0.0f;
    }
    float3 e_big = (float3)(e0 * t1.x + e1 * t2.x, e0 * t1.y + e1 * t2.y, e0 * t1.z + e1 * t2.z);
    float3 e_small = (float3)(-e1 * t1.x + e0 * t2.x, -e1 * t1.y + e0 * t2.y, -e1 * t1.z + e0 * t2.z);
    float c = fmax(cos_d, 1.0e-12f);
    float scale = 1.0f / (4.0f * c * c);
    Asg r;
    r.z = zi;
    if (absf(dot3(e_small, g.x)) >= absf(dot3(e_big, g.x))) {
        r.x = e_small;
        r.y = e_big;
        r.lam = small * scale;
        r.mu = big * scale;
    } else {
        r.x = e_big;
        r.y = e_small;
        r.lam = big * scale;
        r.mu = small * scale;
    }
    if (dot3(r.x, g.x) < 0.0f)
        r.x = -r.x;
    if (dot3(r.y, g.y) < 0.0f)
        r.y = -r.y;
    r.c = cos_d > 0.0f ? g.c : 0.0f;
    return r;
}

/* ------------------------------------------------------------------ kernels: one work-item per row */

__kernel void asg_evaluate_rows(__global const float *rows, __global const float *v, const int n,
                                __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    out[i] = asg_eval(asg_load(rows, i), load3(v, i));
}

__kernel void bessel_i0e_values(__global const float *x, const int n, __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    out[i] = bessel_i0e(x[i]);
}

/* method: 0 exact (asg_unit_integral), 1 Xu Eq. 10, 2 Xu Eq. 11 (DeviceBackend.ASG_INTEGRAL_METHODS). */
__kernel void asg_integral_values(__global const float *lam, __global const float *mu, const int method,
                                  const int n, __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    if (method == 0)
        out[i] = asg_unit_integral(lam[i], mu[i]);
    else if (method == 1)
        out[i] = asg_integral_eq10(lam[i], mu[i]);
    else
        out[i] = asg_integral_eq11(lam[i], mu[i]);
}

__kernel void asg_convolve_rows(__global const float *rows, __global const float *sharpness,
                                __global const float *amplitude, const int n, __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    asg_store(out, i, asg_convolve_sg(asg_load(rows, i), sharpness[i], amplitude[i]));
}

/* kernel rows: [λ_s, μ_s, o_c, o_s]. */
__kernel void asg_convolve_asg_rows(__global const float *rows, __global const float *kernel_rows, const int n,
                                    __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    __global const float *k = kernel_rows + 4 * i;
    asg_store(out, i, asg_convolve_asg(asg_load(rows, i), k[0], k[1], k[2], k[3]));
}

#ifdef cl_khr_fp64
__kernel void asg_product_rows(__global const float *rows1, __global const float *rows2, const int n,
                               __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    asg_store(out, i, asg_product(asg_load(rows1, i), asg_load(rows2, i)));
}
#endif

__kernel void asg_warp_rows(__global const float *rows, __global const float *wo, const int n, __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    asg_store(out, i, asg_warp(asg_load(rows, i), load3(wo, i)));
}

__kernel void asg_from_sg_rows(__global const float *axis, __global const float *sharpness,
                               __global const float *amplitude, const int n, __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    asg_store(out, i, asg_from_sg(load3(axis, i), sharpness[i], amplitude[i]));
}

__kernel void asg_sharpness_rows(__global const float *rows, const int n, __global float *out)
{
    int i = get_global_id(0);
    if (i >= n)
        return;
    out[i] = asg_effective_sharpness(asg_load(rows, i));
}
