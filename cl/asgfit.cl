/* The ASG bake's EM on the device (issue 20; Xu 2013 §4 on Iwasaki's bins): J anisotropic spherical Gaussians
 * fitted to the NDF's non-empty normal bins.
 *
 * Twin of kernels/asgfit.py, in the same operation order (its docstring gives the layout and the precision);
 * the float64 reference is warp_biscale.asg_bake.fit_asg. Needs cl_khr_fp64; takes asg_unit_integral from
 * cl/asg.cl (opencl_backend.USES). One EM step is three launches: asg_em_responsibilities (one work-item per
 * bin), asg_em_m_step (one work-group per lobe), asg_em_finish (one). state = [done, steps]: once done is set, every later
 * launch returns. Lobe rows (J, 12) double: [x (3), y (3), z (3), λ, μ, log ∫G]; bin normals (L, 3) double.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#define ASGFIT_NEG (-1.0e300)        /* log density of a lobe that does not see the normal */
#define ASGFIT_TINY 1.0e-300
#define ASGFIT_CHORD_TERMS 24        /* = asg_bake.CHORD_TERMS */
#define ASGFIT_CHORD_DONE 1.0e-17    /* = asg_bake.CHORD_DONE */
#define ASGFIT_NEWTON_STEPS 60       /* = bandwidths_from_moments' iterations */
#define ASGFIT_NEWTON_DONE 1.0e-7    /* a step below this in log λ and log μ ends the Newton, as on the host */

/* 48-point Gauss–Legendre on [−1, 1] (numpy.polynomial.legendre.leggauss(48)), as asg_bake._disk_moments. */
__constant double GL48_X[48] = {
    -0.9987710072524261, -0.9935301722663508, -0.9841245837228269, -0.9705915925462473, -0.9529877031604308,
    -0.9313866907065543, -0.9058791367155696, -0.8765720202742479, -0.8435882616243935, -0.8070662040294426,
    -0.7671590325157404, -0.7240341309238146, -0.6778723796326639, -0.6288673967765136, -0.5772247260839727,
    -0.523160974722233, -0.4669029047509584, -0.4086864819907167, -0.3487558862921607, -0.28736248735545555,
    -0.22476379039468905, -0.1612223560688917, -0.0970046992094627, -0.03238017096286937, 0.03238017096286937,
    0.0970046992094627, 0.1612223560688917, 0.22476379039468905, 0.28736248735545555, 0.3487558862921607,
    0.4086864819907167, 0.4669029047509584, 0.523160974722233, 0.5772247260839727, 0.6288673967765136,
    0.6778723796326639, 0.7240341309238146, 0.7671590325157404, 0.8070662040294426, 0.8435882616243935,
    0.8765720202742479, 0.9058791367155696, 0.9313866907065543, 0.9529877031604308, 0.9705915925462473,
    0.9841245837228269, 0.9935301722663508, 0.9987710072524261};
__constant double GL48_W[48] = {
    0.0031533460523098414, 0.007327553901276135, 0.011477234579234614, 0.015579315722943226, 0.019616160457356056,
    0.023570760839324047, 0.027426509708357034, 0.031167227832798097, 0.034777222564770394, 0.0382413510658305,
    0.04154508294346455, 0.04467456085669423, 0.04761665849249024, 0.0503590355538542, 0.05289018948519344,
    0.05519950369998403, 0.057277292100402916, 0.059114839698395344, 0.0607044391658936, 0.06203942315989242,
    0.06311419228625373, 0.06392423858464787, 0.06446616443594982, 0.06473769681268365, 0.06473769681268365,
    0.06446616443594982, 0.06392423858464787, 0.06311419228625373, 0.06203942315989242, 0.0607044391658936,
    0.059114839698395344, 0.057277292100402916, 0.05519950369998403, 0.05289018948519344, 0.0503590355538542,
    0.04761665849249024, 0.04467456085669423, 0.04154508294346455, 0.0382413510658305, 0.034777222564770394,
    0.031167227832798097, 0.027426509708357034, 0.023570760839324047, 0.019616160457356056, 0.015579315722943226,
    0.011477234579234614, 0.007327553901276135, 0.0031533460523098414};

/* 1/(2n + 1) and 1/(m + 1): the chord series' divisions as products. */
__constant double ASGFIT_INV_ODD[26] = {
    1.0, 0.3333333333333333, 0.2, 0.14285714285714285, 0.1111111111111111, 0.09090909090909091,
    0.07692307692307693, 0.06666666666666667, 0.058823529411764705, 0.05263157894736842, 0.047619047619047616,
    0.043478260869565216, 0.04, 0.037037037037037035, 0.034482758620689655, 0.03225806451612903,
    0.030303030303030304, 0.02857142857142857, 0.02702702702702703, 0.02564102564102564, 0.024390243902439025,
    0.023255813953488372, 0.022222222222222223, 0.02127659574468085, 0.02040816326530612, 0.0196078431372549};
__constant double ASGFIT_INV_NEXT[24] = {
    1.0, 0.5, 0.3333333333333333, 0.25, 0.2, 0.16666666666666666, 0.14285714285714285, 0.125, 0.1111111111111111,
    0.1, 0.09090909090909091, 0.08333333333333333, 0.07692307692307693, 0.07142857142857142, 0.06666666666666667,
    0.0625, 0.058823529411764705, 0.05555555555555555, 0.05263157894736842, 0.05, 0.047619047619047616,
    0.045454545454545456, 0.043478260869565216, 0.041666666666666664};

CL_INLINE double3 asgfit_vec(__global const double *lobes, int j, int k)
{
    return (double3)(lobes[12 * j + k], lobes[12 * j + k + 1], lobes[12 * j + k + 2]);
}

CL_INLINE double asgfit_dot(double3 a, double3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

CL_INLINE double3 asgfit_cross(double3 a, double3 b)
{
    return (double3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

/* Duff et al. 2017's frame (asg.tangent_frame), double. */
CL_INLINE double3 asgfit_frame_x(double3 z)
{
    double s = z.z < 0.0 ? -1.0 : 1.0;
    double a = -1.0 / (s + z.z);
    return (double3)(1.0 + s * z.x * z.x * a, s * z.x * z.y * a, -s * z.x);
}

CL_INLINE double3 asgfit_frame_y(double3 z)
{
    double s = z.z < 0.0 ? -1.0 : 1.0;
    double a = -1.0 / (s + z.z);
    return (double3)(z.x * z.y * a, s + z.y * z.y * a, -z.y);
}

/* log(α_j G_j(n)/∫G_j) (asg_bake._log_pdf plus log α), ASGFIT_NEG where α_j = 0 or n is below the horizon. */
CL_INLINE double asgfit_log_density(__global const double *lobes, __global const double *alpha, int j, double3 n)
{
    double t = asgfit_dot(n, asgfit_vec(lobes, j, 6));
    if (alpha[j] <= 0.0 || t <= 0.0)
        return ASGFIT_NEG;
    double a = asgfit_dot(n, asgfit_vec(lobes, j, 0));
    double b = asgfit_dot(n, asgfit_vec(lobes, j, 3));
    return log(t) - lobes[12 * j + 9] * a * a - lobes[12 * j + 10] * b * b - lobes[12 * j + 11] + log(alpha[j]);
}

/* asg_bake._chord_moments: (S0, S2, S4) = ∫_{−B}^{B} b^{2k} e^{−μb²} db, B = half, by erf and parts, or by the
 * series where μB² < 1. */
CL_INLINE double3 asgfit_chord_moments(double mu, double half_width)
{
    double x = mu * half_width * half_width;
    if (x < 1.0) {
        double h2 = half_width * half_width, term = 2.0 * half_width;
        double s0 = 0.0, s2 = 0.0, s4 = 0.0;
        for (int m = 0; m < ASGFIT_CHORD_TERMS; ++m) {
            s0 += term * ASGFIT_INV_ODD[m];
            s2 += term * h2 * ASGFIT_INV_ODD[m + 1];
            s4 += term * h2 * h2 * ASGFIT_INV_ODD[m + 2];
            term = term * (-x) * ASGFIT_INV_NEXT[m];
            if (fabs(term) < ASGFIT_CHORD_DONE * s0)
                break;
        }
        return (double3)(s0, s2, s4);
    }
    double e = exp(-x);
    double c0 = sqrt(M_PI / mu) * erf(sqrt(x));
    double c2 = (c0 - 2.0 * half_width * e) / (2.0 * mu);
    double c4 = (3.0 * c2 - 2.0 * half_width * half_width * half_width * e) / (2.0 * mu);
    return (double3)(c0, c2, c4);
}

#ifndef ASGFIT_GROUP  /* work-items a lobe in asg_em_m_step: device.ASG_EM_BLOCK, given by opencl_backend's build */
#error "cl/asgfit.cl is built with -DASGFIT_GROUP=<device.ASG_EM_BLOCK> (opencl_backend.stage_options)"
#endif

/* The work-group's sum of each work-item's x, returned to every work-item (the barrier after the read lets the
 * scratch be used again). */
CL_INLINE double4 asgfit_group_sum(double4 x, __local double4 *scratch)
{
    int l = get_local_id(0);
    scratch[l] = x;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int stride = ASGFIT_GROUP / 2; stride > 0; stride >>= 1) {
        if (l < stride)
            scratch[l] += scratch[l + stride];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    double4 r = scratch[0];
    barrier(CLK_LOCAL_MEM_FENCE);
    return r;
}

/* (E[a²], E[b²], E[a⁴], E[b⁴], E[a²b²]) of exp(−λa² − μb²) on the unit disk (asg_bake._disk_moments), the 48
 * nodes shared by the work-group (node i by work-item i mod ASGFIT_GROUP), every work-item getting the sums. */
CL_INLINE void asgfit_disk_moments(double lam, double mu, double *m, __local double4 *scratch)
{
    double amax = fmin(1.0, 6.0 / sqrt(2.0 * lam));
    double bcap = 6.0 / sqrt(2.0 * mu);
    double z = 0.0, sa2 = 0.0, sb2 = 0.0, sa4 = 0.0, sb4 = 0.0, sab = 0.0;
    for (int i = get_local_id(0); i < 48; i += ASGFIT_GROUP) {
        double a = amax * GL48_X[i];
        double a2 = a * a;
        double wa = amax * GL48_W[i] * exp(-lam * a2);
        double3 chord = asgfit_chord_moments(mu, fmin(sqrt(fmax(1.0 - a2, 0.0)), bcap));
        z += wa * chord.x;
        sa2 += wa * a2 * chord.x;
        sa4 += wa * a2 * a2 * chord.x;
        sb2 += wa * chord.y;
        sb4 += wa * chord.z;
        sab += wa * a2 * chord.y;
    }
    double4 first = asgfit_group_sum((double4)(z, sa2, sb2, sa4), scratch);
    double4 second = asgfit_group_sum((double4)(sb4, sab, 0.0, 0.0), scratch);
    z = first.x;
    sa2 = first.y;
    sb2 = first.z;
    sa4 = first.w;
    sb4 = second.x;
    sab = second.y;
    m[0] = sa2 / z;
    m[1] = sb2 / z;
    m[2] = sa4 / z;
    m[3] = sb4 / z;
    m[4] = sab / z;
}

/* asg_bake.bandwidths_from_moments with start = (prev_lam, prev_mu), log bandwidths clipped to [lo, hi]; called by
 * every work-item of a group alike (its disk moments are group sums). */
CL_INLINE double2 asgfit_bandwidths(double ma, double mb, double prev_lam, double prev_mu, double lo, double hi,
                                    __local double4 *scratch)
{
    double t0 = clamp(log(0.5 / fmax(ma, ASGFIT_TINY)), lo, hi);
    double t1 = clamp(log(0.5 / fmax(mb, ASGFIT_TINY)), lo, hi);
    if (18.0 / exp(t0) + 18.0 / exp(t1) > 1.0) { /* not inside the disk: warm start */
        t0 = clamp(log(prev_lam), lo, hi);
        t1 = clamp(log(prev_mu), lo, hi);
    }
    for (int it = 0; it < ASGFIT_NEWTON_STEPS; ++it) {
        double lam = exp(t0), mu = exp(t1);
        double m[5];
        asgfit_disk_moments(lam, mu, m, scratch);
        double f0 = m[0] - ma, f1 = m[1] - mb;
        double j00 = -lam * (m[2] - m[0] * m[0]);
        double j01 = -mu * (m[4] - m[0] * m[1]);
        double j10 = -lam * (m[4] - m[0] * m[1]);
        double j11 = -mu * (m[3] - m[1] * m[1]);
        double det = j00 * j11 - j01 * j10;
        double s0 = 0.0, s1 = 0.0;
        if (fabs(det) > ASGFIT_TINY) {
            s0 = clamp((j11 * f0 - j01 * f1) / det, -2.0, 2.0);
            s1 = clamp((j00 * f1 - j10 * f0) / det, -2.0, 2.0);
        }
        double n0 = clamp(t0 - s0, lo, hi), n1 = clamp(t1 - s1, lo, hi);
        int done = fabs(n0 - t0) < ASGFIT_NEWTON_DONE && fabs(n1 - t1) < ASGFIT_NEWTON_DONE;
        t0 = n0;
        t1 = n1;
        if (done)
            break;
    }
    return (double2)(exp(t0), exp(t1));
}

/* resp_weight[l, j] = r_lj·w_l; seen_weight[l] = w_l, or 0 where the normal is below every live lobe's horizon. */
__kernel void asg_em_responsibilities(__global const double *bin_normal, __global const double *bin_weight,
                                      __global const double *lobes, __global const double *alpha,
                                      __global const int *state, const int n_lobes, const int n_bins,
                                      __global double *resp_weight, __global double *seen_weight)
{
    int l = get_global_id(0);
    if (l >= n_bins || state[0] != 0)
        return;
    double3 n = (double3)(bin_normal[3 * l], bin_normal[3 * l + 1], bin_normal[3 * l + 2]);
    double top = ASGFIT_NEG;
    for (int j = 0; j < n_lobes; ++j)
        top = fmax(top, asgfit_log_density(lobes, alpha, j, n));
    __global double *row = resp_weight + (size_t)l * n_lobes;
    if (top <= ASGFIT_NEG) {
        for (int j = 0; j < n_lobes; ++j)
            row[j] = 0.0;
        seen_weight[l] = 0.0;
        return;
    }
    double total = 0.0;
    for (int j = 0; j < n_lobes; ++j) {
        double lp = asgfit_log_density(lobes, alpha, j, n);
        double e = lp > ASGFIT_NEG ? exp(lp - top) : 0.0;
        row[j] = e;
        total += e;
    }
    double scale = bin_weight[l] / total;
    for (int j = 0; j < n_lobes; ++j)
        row[j] = row[j] * scale;
    seen_weight[l] = bin_weight[l];
}

/* asg_bake._m_step for lobe j, one work-group a lobe: its new row, its mass (0 if it died) and how far it moved.
 * The work-items take the bins lane, lane + ASGFIT_GROUP, … and the group sums their shares; every work-item then
 * solves the lobe's frame and bandwidths alike (the Newton's disk moments shared node by node), and lane 0 writes
 * them. */
__kernel __attribute__((reqd_work_group_size(ASGFIT_GROUP, 1, 1)))
void asg_em_m_step(__global const double *bin_normal, __global const double *seen_weight,
                   __global const double *resp_weight, __global const double *lobes, const double dead_mass,
                   const double log_min, const double log_max, __global const int *state, const int n_lobes,
                   const int n_bins, __global double *new_lobes, __global double *mass, __global double *moved)
{
    __local double4 scratch[ASGFIT_GROUP];
    int j = get_group_id(0), lane = get_local_id(0);
    if (j >= n_lobes || state[0] != 0)
        return;
    double4 part = (double4)(0.0, 0.0, 0.0, 0.0); /* [Σ r, Σ r·n] */
    double part_total = 0.0;
    for (int l = lane; l < n_bins; l += ASGFIT_GROUP) {
        double r = resp_weight[(size_t)l * n_lobes + j];
        part += (double4)(r, r * bin_normal[3 * l], r * bin_normal[3 * l + 1], r * bin_normal[3 * l + 2]);
        part_total += seen_weight[l];
    }
    double4 sums = asgfit_group_sum(part, scratch);
    double total = asgfit_group_sum((double4)(part_total, 0.0, 0.0, 0.0), scratch).x;
    double m_j = sums.x;
    double3 mean = (double3)(sums.y, sums.z, sums.w);
    double3 prev_x = asgfit_vec(lobes, j, 0), prev_z = asgfit_vec(lobes, j, 6);
    double prev_lam = lobes[12 * j + 9], prev_mu = lobes[12 * j + 10];
    double norm = sqrt(asgfit_dot(mean, mean));
    int live = m_j > dead_mass * total && norm > 0.0;
    double3 z = live ? mean / norm : prev_z;
    double3 x0 = asgfit_frame_x(z), y0 = asgfit_frame_y(z);
    part = (double4)(0.0, 0.0, 0.0, 0.0); /* [Σ r, Σ r·a², Σ r·b², Σ r·ab] over the bins in z's hemisphere */
    for (int l = lane; l < n_bins; l += ASGFIT_GROUP) {
        double3 n = (double3)(bin_normal[3 * l], bin_normal[3 * l + 1], bin_normal[3 * l + 2]);
        if (asgfit_dot(n, z) > 0.0) {
            double r = resp_weight[(size_t)l * n_lobes + j];
            double a = asgfit_dot(n, x0), b = asgfit_dot(n, y0);
            part += (double4)(r, r * a * a, r * b * b, r * a * b);
        }
    }
    double4 second = asgfit_group_sum(part, scratch);
    double m2 = second.x;
    double mm = fmax(m2, ASGFIT_TINY);
    double caa = second.y / mm, cbb = second.z / mm, cab = second.w / mm;
    /* The 2×2 covariance's smaller eigenvalue e0 (its eigenvector → x, the larger λ) and the larger e1. */
    double mid = 0.5 * (caa + cbb);
    double d = sqrt(0.25 * (caa - cbb) * (caa - cbb) + cab * cab);
    double e0 = mid - d, e1 = mid + d;
    double2 u = (double2)(cab, e0 - caa); /* (A − e0 I)u = 0 from either row: the longer of the two */
    double2 v = (double2)(cbb - e0, -cab);
    if (v.x * v.x + v.y * v.y > u.x * u.x + u.y * u.y)
        u = v;
    double uu = u.x * u.x + u.y * u.y;
    u = uu > 0.0 ? u / sqrt(uu) : (double2)(1.0, 0.0);
    double2 bw = asgfit_bandwidths(fmax(e0, 0.0), fmax(e1, 0.0), prev_lam, prev_mu, log_min, log_max, scratch);
    int keep = live && m2 > ASGFIT_TINY;
    double3 x = prev_x;
    double lam = prev_lam, mu = prev_mu, log_norm = lobes[12 * j + 11];
    if (keep) {
        x = u.x * x0 + u.y * y0;
        lam = bw.x;
        mu = bw.y;
        log_norm = (double)log(asg_unit_integral((float)lam, (float)mu));
    } else {
        z = prev_z;
    }
    double3 y = asgfit_cross(z, x);
    if (lane != 0)
        return;
    __global double *out = new_lobes + 12 * j;
    out[0] = x.x; out[1] = x.y; out[2] = x.z;
    out[3] = y.x; out[4] = y.y; out[5] = y.z;
    out[6] = z.x; out[7] = z.y; out[8] = z.z;
    out[9] = lam;
    out[10] = mu;
    out[11] = log_norm;
    mass[j] = keep ? m_j : 0.0;
    double3 dz = z - prev_z;
    moved[j] = fmax(0.5 * asgfit_dot(dz, dz), fmax(fabs(log(lam / prev_lam)), fabs(log(mu / prev_mu))));
}

/* One work-item: the step counted; with no mass left the EM stops where it was, else the new lobes and weights
 * replace the old, and the EM is done once nothing moved by `converged`. */
__kernel void asg_em_finish(__global const double *new_lobes, __global const double *mass,
                            __global const double *moved, const double converged, const int n_lobes,
                            __global double *lobes, __global double *alpha, __global int *state)
{
    if (get_global_id(0) != 0 || state[0] != 0)
        return;
    state[1] = state[1] + 1;
    double total = 0.0;
    for (int j = 0; j < n_lobes; ++j)
        total += mass[j];
    if (!(total > 0.0)) {
        state[0] = 1;
        return;
    }
    double worst = 0.0;
    for (int j = 0; j < n_lobes; ++j) {
        double a = mass[j] / total;
        worst = fmax(worst, fmax(moved[j], fabs(a - alpha[j])));
        alpha[j] = a;
        for (int k = 0; k < 12; ++k)
            lobes[12 * j + k] = new_lobes[12 * j + k];
    }
    if (worst < converged)
        state[0] = 1;
}
