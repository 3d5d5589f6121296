/* The prefiltered environment (Wang 2009 Eq. 34-35): one level Λ(p, η) of an equirect map.
 *
 * Twin of kernels/envmap.py (see there for the support bounds and the precision argument); the
 * mathematics is warp_biscale.reference.prefilter_level. One work-item per output texel p, no
 * atomics: Σ_t G(ω_t; p, η) L_t Ω_t / Σ_t G Ω_t over the input texels t inside the lobe's support
 * (ω·p ≥ cos_min = 1 − 16.118/η, i.e. G ≥ 1e-7), each row summed in float32, rows in double.
 * An empty support gives the nearest texel's radiance (the limit η → ∞).
 *
 * Layout: radiance (h_in·w_in, 3) floats row-major; in_rows / out_rows (h, 4) [cos θ, sin θ, θ, Ω];
 * in_cols / out_cols (w, 3) [cos φ, sin φ, φ]; out (h_out·w_out, 3). Needs cl_khr_fp64.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#define ENV_PI 3.141592653589793f
#define ENV_TWO_PI 6.283185307179586f

__kernel void prefilter_level(
    __global const float *radiance,
    __global const float *in_rows, const int h_in,
    __global const float *in_cols, const int w_in,
    __global const float *out_rows,
    __global const float *out_cols, const int w_out,
    const float sharpness,
    const float cos_min,
    const int n_out,
    __global float *out)
{
    int t = get_global_id(0);
    if (t >= n_out)
        return;
    int i = t / w_out;
    int j = t - i * w_out;
    __global const float *r = out_rows + 4 * i;
    __global const float *c = out_cols + 3 * j;
    float3 p = (float3)(r[1] * c[0], r[0], r[1] * c[1]);
    float reach = acos(maxf(cos_min, -1.0f));
    int i_lo = (int)floor((r[2] - reach) * (float)h_in / ENV_PI - 0.5f);
    int i_hi = (int)ceil((r[2] + reach) * (float)h_in / ENV_PI - 0.5f);
    i_lo = i_lo > 0 ? i_lo : 0;
    i_hi = i_hi < h_in - 1 ? i_hi : h_in - 1;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, total = 0.0;
    for (int ii = i_lo; ii <= i_hi; ++ii) {
        __global const float *q = in_rows + 4 * ii;
        float x = (cos_min - q[0] * r[0]) / (q[1] * r[1]);
        if (!(x <= 1.0f))
            continue;
        int j0 = 0;
        int count = w_in;
        if (x > -1.0f) {
            float dphi = acos(x);
            int a = (int)ceil((c[2] - dphi) * (float)w_in / ENV_TWO_PI - 0.5f);
            int b = (int)floor((c[2] + dphi) * (float)w_in / ENV_TWO_PI - 0.5f);
            if (b - a + 1 < w_in) {
                j0 = a % w_in;
                if (j0 < 0)
                    j0 += w_in;
                count = b - a + 1 > 0 ? b - a + 1 : 0;
            }
        }
        float s0 = 0.0f, s1 = 0.0f, s2 = 0.0f, sw = 0.0f;
        __global const float *row = radiance + (size_t)3 * ii * w_in;
        for (int k = 0; k < count; ++k) {
            int jj = j0 + k;
            if (jj >= w_in)
                jj -= w_in;
            __global const float *cc = in_cols + 3 * jj;
            float dx = q[1] * cc[0] - p.x;
            float dy = q[0] - p.y;
            float dz = q[1] * cc[1] - p.z;
            float g = exp(-sharpness * 0.5f * (dx * dx + dy * dy + dz * dz));
            s0 += g * row[3 * jj];
            s1 += g * row[3 * jj + 1];
            s2 += g * row[3 * jj + 2];
            sw += g;
        }
        double omega = (double)q[3];
        a0 += (double)s0 * omega;
        a1 += (double)s1 * omega;
        a2 += (double)s2 * omega;
        total += (double)sw * omega;
    }
    float3 v;
    if (total > 0.0) {
        v = (float3)((float)(a0 / total), (float)(a1 / total), (float)(a2 / total));
    } else {
        /* No texel centre within the support: the nearest texel's radiance (the limit η → ∞),
         * searched among the 3×3 texels around the one containing p. */
        int ic = (int)floor(r[2] * (float)h_in / ENV_PI);
        ic = ic < 0 ? 0 : (ic > h_in - 1 ? h_in - 1 : ic);
        int jc = (int)floor(c[2] * (float)w_in / ENV_TWO_PI);
        float best = -2.0f;
        int best_k = 0;
        int lo = ic - 1 > 0 ? ic - 1 : 0;
        int hi = ic + 1 < h_in - 1 ? ic + 1 : h_in - 1;
        for (int ii = lo; ii <= hi; ++ii) {
            __global const float *q = in_rows + 4 * ii;
            for (int dj = -1; dj <= 1; ++dj) {
                int jj = (jc + dj) % w_in;
                if (jj < 0)
                    jj += w_in;
                __global const float *cc = in_cols + 3 * jj;
                float cosine = q[1] * cc[0] * p.x + q[0] * p.y + q[1] * cc[1] * p.z;
                if (cosine > best) {
                    best = cosine;
                    best_k = ii * w_in + jj;
                }
            }
        }
        v = load3(radiance, best_k);
    }
    store3(out, t, v);
}
