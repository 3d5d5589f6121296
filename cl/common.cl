/* Shared by every OpenCL stage (cl/__init__.source prepends it): small vector helpers, the
 * small-scale BRDFs (cosine-weighted) and bit tricks. Twin of kernels/common.py; the mathematics
 * is warp_biscale.reference.brdf_cosine_weighted.
 *
 * Memory layout: no float3 in global memory (its 16-byte padding differs between host and
 * device); every 3-vector array is a plain float array of stride 3 (load3/store3 below).
 * Arithmetic is written out component by component in the order Warp's vec3 operators use, and
 * FP_CONTRACT is off, so no compiler fuses a*b+c into an fma and float32 results match Warp's
 * CPU kernels operation for operation (built with -cl-fp32-correctly-rounded-divide-sqrt, so /
 * and sqrt are correctly rounded as on the host).
 */
#pragma OPENCL FP_CONTRACT OFF

/* Every helper is forced inline: PoCL (3.0, CPU) otherwise emits a call for each helper and
 * each builtin such as min or vload3, which tripled the cost of the visibility kernel. For the
 * same reason the hot paths use the plain-operator helpers below instead of builtins (no NaN
 * reaches them, so they equal Warp's fmin/fmax-based min, max and clamp). */
#define CL_INLINE static inline __attribute__((always_inline))

CL_INLINE float minf(float a, float b) { return a < b ? a : b; }
CL_INLINE float maxf(float a, float b) { return a > b ? a : b; }
CL_INLINE float clampf(float x, float lo, float hi) { return minf(maxf(lo, x), hi); }
CL_INLINE float absf(float x) { return as_float(as_uint(x) & 0x7FFFFFFFu); }

/* Element i of a float array of stride 3. */
CL_INLINE float3 load3(__global const float *p, int i) { return (float3)(p[3 * i], p[3 * i + 1], p[3 * i + 2]); }
CL_INLINE void store3(__global float *p, int i, float3 v)
{
    p[3 * i] = v.x;
    p[3 * i + 1] = v.y;
    p[3 * i + 2] = v.z;
}

#define LAMBERT 0
#define BLINN_PHONG 1
#define COOK_TORRANCE 2
#define WARD 3
#define INV_PI M_1_PI_F

CL_INLINE float dot3(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

CL_INLINE float3 cross3(float3 a, float3 b)
{
    return (float3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

/* Warp's normalize: v / |v|, or zero for a zero vector. */
CL_INLINE float3 normalize3(float3 a)
{
    float l = sqrt(a.x * a.x + a.y * a.y + a.z * a.z);
    if (l > 0.0f)
        return (float3)(a.x / l, a.y / l, a.z / l);
    return (float3)(0.0f, 0.0f, 0.0f);
}

/* Powers without the pow builtin, which costs about 120 ns a call in PoCL (exp + log2 cost 40):
 * x^5 by multiplication, and x^y = 2^(y log2 x) for x >= 0 and y > 0 (0 at x = 0, as pow). They
 * differ from a libm powf by rounding only: a few ulp, or about 1e-6 relative for results above
 * 2^-20 of the peak, far inside the backends' 1e-4 tolerance. */
CL_INLINE float pow5(float x)
{
    float x2 = x * x;
    return x2 * x2 * x;
}
CL_INLINE float pow_pos(float x, float y) { return x > 0.0f ? exp2(y * log2(x)) : 0.0f; }

/* f_r(n, wi, wo)·(n·wi)⁺(n·wo)⁺ for material row m of the packed table: params has stride 8,
 * [kd_r, kd_g, kd_b, ks_r, ks_g, ks_b, p1, p2] (see warp_biscale.brdf). */
CL_INLINE float3 brdf_cosine_weighted(int kind, __global const float *params, int m, float3 n, float3 wi, float3 wo)
{
    float ci = dot3(n, wi);
    float co = dot3(n, wo);
    if (ci <= 0.0f || co <= 0.0f)
        return (float3)(0.0f, 0.0f, 0.0f);
    __global const float *p = params + 8 * m;
    float3 kd = (float3)(p[0], p[1], p[2]);
    float3 ks = (float3)(p[3], p[4], p[5]);
    float p1 = p[6];
    float p2 = p[7];
    float3 h = normalize3((float3)(wi.x + wo.x, wi.y + wo.y, wi.z + wo.z));
    float nh = clampf(dot3(n, h), -1.0f, 1.0f);
    float hi = clampf(dot3(h, wi), 0.0f, 1.0f);
    float spec = 0.0f;
    if (kind == BLINN_PHONG) {
        spec = (p1 + 2.0f) * 0.5f * INV_PI * pow_pos(maxf(nh, 0.0f), p1) * ci * co;
    } else if (kind == COOK_TORRANCE) {
        float theta_h = acos(nh);
        float d = exp(-(theta_h / p1) * (theta_h / p1));
        float f = p2 + (1.0f - p2) * pow5(1.0f - hi);
        float ho = maxf(hi, 1.0e-30f);
        float g = minf(1.0f, minf(2.0f * maxf(nh, 0.0f) * co / ho, 2.0f * maxf(nh, 0.0f) * ci / ho));
        spec = f * g * d * INV_PI;
    } else if (kind == WARD) {
        if (nh > 0.0f) {
            float cos2 = nh * nh;
            float tan2 = (1.0f - cos2) / cos2;
            float a2 = p1 * p1;
            spec = exp(-tan2 / a2) / (4.0f * M_PI_F * a2) * sqrt(ci * co);
        }
    }
    float s = INV_PI * ci * co;
    return (float3)(kd.x * s + ks.x * spec, kd.y * s + ks.y * spec, kd.z * s + ks.z * spec);
}

/* Index of the lowest set bit of a non-zero word. OpenCL 1.2 has no ctz, and its popcount, the
 * obvious route (popcount((m & -m) - 1)), is a 6 ns library call in PoCL; the de Bruijn
 * multiply-and-look-up below gives the same index for every word in about 1 ns. */
__constant int DE_BRUIJN_32[32] = {0,  1,  28, 2,  29, 14, 24, 3, 30, 22, 20, 15, 25, 17, 4,  8,
                                   31, 27, 13, 23, 21, 19, 16, 7, 26, 12, 18, 6,  11, 5,  10, 9};
CL_INLINE int lowest_bit(uint m) { return DE_BRUIJN_32[((m & (0u - m)) * 0x077CB531u) >> 27]; }
