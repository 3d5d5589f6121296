/* A shaded frame's last steps on the device: the tonemap stage.
 *
 * Twin of kernels/tonemap.py, in the same operation order. tonemap_pixels (images.tonemap on the device):
 * one work-item per pixel, the radiance scaled by 2^exposure, mapped to [0, 1] by the operator (0 ACES,
 * 1 Reinhard, 2 clamp), sRGB-encoded and rounded to 8 bits. accumulate_frame: an anti-aliasing sample's
 * radiance times its weight added to the frame's sum (the first sample sets it). Layouts: radiance and
 * total (P, 3) float; out (P, 3) uchar.
 */

#define TONEMAP_LARGE 1.0e4f /* past it every operator is 1 to within half an 8-bit step; ACES stays finite */

CL_INLINE uchar to_byte(float x, int curve)
{
    float v = x;
    if (!(v >= 0.0f)) /* NaN or negative: black (radiance reaching here is already finite and >= 0) */
        v = 0.0f;
    v = fmin(v, TONEMAP_LARGE);
    float y = v;
    if (curve == 0)
        y = v * (2.51f * v + 0.03f) / (v * (2.43f * v + 0.59f) + 0.14f);
    else if (curve == 1)
        y = v / (1.0f + v);
    y = clampf(y, 0.0f, 1.0f);
    float s = 12.92f * y;
    /* The power through the native base-2 functions: PoCL's pow (and its exact exp2 and log2) cost a CPU frame's
     * tone map four times their time, and an 8-bit step is far above the native pair's error (bench/README.md,
     * "What was tried"). */
    if (y > 0.0031308f)
        s = 1.055f * native_exp2(native_log2(y) * (1.0f / 2.4f)) - 0.055f;
    return (uchar)(int)floor(s * 255.0f + 0.5f);
}

__kernel void tonemap_pixels(__global const float *radiance, const float scale, const int curve,
                             const int n_pixels, __global uchar *out)
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    for (int k = 0; k < 3; ++k)
        out[3 * p + k] = to_byte(radiance[3 * p + k] * scale, curve);
}

__kernel void accumulate_frame(__global const float *radiance, const float weight, const int first,
                               const int n_pixels, __global float *total)
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    for (int k = 0; k < 3; ++k)
        total[3 * p + k] = (first ? 0.0f : total[3 * p + k]) + weight * radiance[3 * p + k];
}
