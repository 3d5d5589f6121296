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
#define ANISOTROPIC_WARD 4
#define ASHIKHMIN_SHIRLEY 5
#define MEASURED 6
#define INV_PI M_1_PI_F
#define TANGENT_DEGENERATE 1.0e-4f /* = warp_biscale.brdf.TANGENT_DEGENERATE */

CL_INLINE float dot3(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

CL_INLINE float3 cross3(float3 a, float3 b)
{
    return (float3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

/* (t_x, t_y): where the ray o + t·d leaves the tile's cell [x0, x0 + px] × [y0, y0 + py] across its x
 * and its y sides (1e30 when it runs parallel to them), for the periodic traces of the tile. */
CL_INLINE float2 cell_exits(float3 o, float3 d, float x0, float y0, float px, float py)
{
    float t_x = 1.0e30f;
    if (d.x > 0.0f)
        t_x = maxf((x0 + px - o.x) / d.x, 0.0f);
    else if (d.x < 0.0f)
        t_x = maxf((x0 - o.x) / d.x, 0.0f);
    float t_y = 1.0e30f;
    if (d.y > 0.0f)
        t_y = maxf((y0 + py - o.y) / d.y, 0.0f);
    else if (d.y < 0.0f)
        t_y = maxf((y0 - o.y) / d.y, 0.0f);
    return (float2)(t_x, t_y);
}

/* The ray's point at t_exit, brought back into the cell across the side(s) it left by (cell_exits). */
CL_INLINE float3 next_cell(float3 o, float3 d, float t_exit, float2 exits, float px, float py)
{
    float3 q = (float3)(o.x + t_exit * d.x, o.y + t_exit * d.y, o.z + t_exit * d.z);
    if (exits.x <= t_exit)
        q.x = q.x - (d.x < 0.0f ? -1.0f : 1.0f) * px;
    if (exits.y <= t_exit)
        q.y = q.y - (d.y < 0.0f ? -1.0f : 1.0f) * py;
    return q;
}

/* Warp's normalize: v / |v|, or zero for a zero vector. */
CL_INLINE float3 normalize3(float3 a)
{
    float l = sqrt(a.x * a.x + a.y * a.y + a.z * a.z);
    if (l > 0.0f)
        return (float3)(a.x / l, a.y / l, a.z / l);
    return (float3)(0.0f, 0.0f, 0.0f);
}

#define GOLDEN_ANGLE 2.39996322972865f /* = trace.GOLDEN_ANGLE: the disc samples of shadow and occlusion rays */
#define GOLDEN_COS -0.7373688780783197f /* cos and sin of GOLDEN_ANGLE */
#define GOLDEN_SIN 0.6754902942615238f

/* The pixel's hash angle that turns its disc samples (trace.disk_sample). */
CL_INLINE float disk_turn(int pixel)
{
    uint h = (uint)pixel * 2654435761u; /* Knuth's multiplicative hash */
    return (float)(int)(h >> 8) * (2.0f * 3.14159265358979f / 16777216.0f);
}

/* Sample i of `samples` on the unit disc: a Vogel spiral turned by a per-pixel angle (trace.disk_sample),
 * so that neighbouring pixels' penumbrae are noise rather than bands. The centre for one sample. */
CL_INLINE float2 disk_sample(int i, int samples, int pixel)
{
    if (samples == 1)
        return (float2)(0.0f, 0.0f);
    float turn = disk_turn(pixel);
    float r = sqrt(((float)i + 0.5f) / (float)samples);
    float a = (float)i * GOLDEN_ANGLE + turn;
    return (float2)(r * cos(a), r * sin(a));
}

/* (first, stride) of the rays anti-aliasing sample part_index of part_count traces of a set of `samples`
 * (trace.ray_part). */
CL_INLINE int2 ray_part(int samples, int part_index, int part_count)
{
    int stride = max(1, min(part_count, samples));
    return (int2)(part_index % stride, stride);
}

#define BLOCK_SLOTS 4 /* = trace.BLOCK_SLOTS: the pixels of a 2x2 block; a set of at least this many rays is shared */

/* The side of the pixel blocks that share a set of `samples` rays (trace.block_side): 1 (each pixel its own)
 * without a block width or for fewer than BLOCK_SLOTS rays, 4 where asked and samples >= 16 part_count, else 2. */
CL_INLINE int set_block_side(int samples, int part_count, int block_width, int block_side)
{
    if (block_width <= 0 || samples < BLOCK_SLOTS)
        return 1;
    return (block_side == 4 && samples >= 16 * part_count) ? 4 : 2;
}

/* (first, stride, turn pixel) of the rays pixel `pixel` traces of a set of `samples` (trace.pixel_parts): where
 * the set is shared in s x s blocks (s = set_block_side > 1), slot q = x mod s + s (y mod s) of its block takes
 * part q + s^2 part_index of s^2 part_count, its rays turned by the block's first pixel, so that the block's pixels
 * trace the sample's part between them; else the sample's part, turned by the pixel itself. */
CL_INLINE int3 pixel_part(int samples, int part_index, int part_count, int block_width, int block_side, int pixel)
{
    int side = set_block_side(samples, part_count, block_width, block_side);
    if (side > 1) {
        int x = pixel % block_width, y = pixel / block_width, slots = side * side;
        int2 part = ray_part(samples, x % side + side * (y % side) + slots * part_index, slots * part_count);
        return (int3)(part.x, part.y, pixel - x % side - (y % side) * block_width);
    }
    int2 part = ray_part(samples, part_index, part_count);
    return (int3)(part.x, part.y, pixel);
}

/* Bit i set for each ray i = first, first + stride, ... < samples (<= 32) of a part. */
CL_INLINE uint part_bits(int first, int stride, int samples)
{
    uint bits = 0u;
    for (int i = first; i < samples; i += stride)
        bits |= 1u << i;
    return bits;
}

/* a right-handed frame (a, b, w) (trace.disk_basis) */
CL_INLINE void disk_basis(float3 w, float3 *a, float3 *b)
{
    float3 ref = absf(w.x) < 0.9f ? (float3)(1.0f, 0.0f, 0.0f) : (float3)(0.0f, 1.0f, 0.0f);
    *a = normalize3(cross3(w, ref));
    *b = cross3(w, *a);
}

/* A light's disc frame (a, b) about w for shading normal n (trace.horizon_frame): where n's horizon cuts the
 * disc, a is n's part across it and the result d = (n.w)/(apparent |that part|) lies in (-1, 1); else
 * disk_basis(w) and 2. */
CL_INLINE float horizon_frame(float3 w, float3 n, float apparent, float3 *a, float3 *b)
{
    float wn = dot3(w, n);
    float3 across = n - wn * w;
    float length = sqrt(dot3(across, across));
    if (apparent * length > fabs(wn)) {
        *a = across / length;
        *b = cross3(w, *a);
        return wn / (apparent * length);
    }
    disk_basis(w, a, b);
    return 2.0f;
}

/* Disc point q moved into the disc's part q.x > -d above the horizon (trace.above_horizon), for |d| < 1. */
CL_INLINE float2 above_horizon(float2 q, float d)
{
    float s2 = -d + 0.5f * (q.x + 1.0f) * (1.0f + d);
    return (float2)(s2, q.y * sqrt(fmax(1.0f - s2 * s2, 0.0f) / fmax(1.0f - q.x * q.x, 1.0e-12f)));
}

/* Environment-occlusion ray i of `samples` (trace.occlusion_directions): disc sample i lifted to the
 * hemisphere of n, in the frame (a, b, n), cosine-distributed. */
CL_INLINE float3 occlusion_direction(float3 a, float3 b, float3 n, int i, int samples, int pixel)
{
    float2 q = disk_sample(i, samples, pixel);
    float lift = sqrt(maxf(1.0f - q.x * q.x - q.y * q.y, 0.0f));
    return (float3)(q.x * a.x + q.y * b.x + lift * n.x, q.x * a.y + q.y * b.y + lift * n.y,
                    q.x * a.z + q.y * b.z + lift * n.z);
}


#define LOBE_RAYS 8 /* = trace.LOBE_RAYS */
#define LOBE_COS_MIN 0.0872f /* = trace.LOBE_COS_MIN */

/* Ray i towards a sharp lobe (trace.lobe_ray_directions): disc sample i on the tangent plane at the lobe's
 * axis w (frame (a, b, w)), radius tan θ with 1 − cos θ = 2/η, normalised. */
CL_INLINE float3 lobe_ray_direction(float3 a, float3 b, float3 w, float eta, int i, int pixel)
{
    float c = maxf(1.0f - 2.0f / maxf(eta, 1.0e-30f), LOBE_COS_MIN);
    float spread = sqrt(1.0f - c * c) / c;
    float2 q = disk_sample(i, LOBE_RAYS, pixel);
    return normalize3((float3)(w.x + spread * (q.x * a.x + q.y * b.x), w.y + spread * (q.x * a.y + q.y * b.y),
                               w.z + spread * (q.x * a.z + q.y * b.z)));
}

/* Powers without the pow builtin, which costs about three times exp + log2 in PoCL:
 * x^5 by multiplication, and x^y = 2^(y log2 x) for x >= 0 and y > 0 (0 at x = 0, as pow). They
 * differ from a libm powf by rounding only: a few ulp, or about 1e-6 relative for results above
 * 2^-20 of the peak, far inside the backends' 1e-4 tolerance. */
CL_INLINE float pow5(float x)
{
    float x2 = x * x;
    return x2 * x2 * x;
}
CL_INLINE float pow_pos(float x, float y) { return x > 0.0f ? exp2(y * log2(x)) : 0.0f; }

/* The isotropic kinds' specular factor of ks, cosine-weighted (f_s·cos θi·cos θo / ks; 0 for the others), from
 * the cosines (ci, co > 0) and nh = n·h, hi = h·ωi; twin of kernels/common.py's isotropic_specular. */
CL_INLINE float isotropic_specular(int kind, float p1, float p2, float ci, float co, float nh, float hi)
{
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
    return spec;
}

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
    float spec = isotropic_specular(kind, p1, p2, ci, co, clampf(dot3(n, h), -1.0f, 1.0f), clampf(dot3(h, wi), 0.0f, 1.0f));
    float s = INV_PI * ci * co;
    return (float3)(kd.x * s + ks.x * spec, kd.y * s + ks.y * spec, kd.z * s + ks.z * spec);
}

/* The facet frame's unit x axis (warp_biscale.brdf.tangent_frame): t − (t·n)n normalised, or, where that is
 * shorter than sqrt(TANGENT_DEGENERATE) (t within 0.01 rad of ±n), Duff et al.'s basis vector built from n. */
CL_INLINE float3 facet_tangent(float3 n, float3 t)
{
    float tn = dot3(t, n);
    float3 x = (float3)(t.x - tn * n.x, t.y - tn * n.y, t.z - tn * n.z);
    float l2 = dot3(x, x);
    if (l2 < TANGENT_DEGENERATE) {
        float s = n.z < 0.0f ? -1.0f : 1.0f;
        float a = -1.0f / (s + n.z);
        x = (float3)(1.0f + s * n.x * n.x * a, s * n.x * n.y * a, -s * n.x);
        l2 = dot3(x, x);
    }
    float l = sqrt(l2);
    return (float3)(x.x / l, x.y / l, x.z / l);
}

/* log(1 + x) for x > -1, accurate for small |x| (Goldberg's rewrite), written out as the Warp twin has it
 * (Warp has no log1p), so the backends round alike. */
CL_INLINE float log1p_small(float x)
{
    float u = 1.0f + x;
    if (u == 1.0f)
        return x;
    return log(u) * x / (u - 1.0f);
}

/* f_s of an analytic kind, without the cosines, in the facet frame (x, y, n): the isotropic kinds as
 * brdf_cosine_weighted's specular term over cos θi cos θo; the anisotropic Ward (p1, p2 = αx, αy) and
 * Ashikhmin–Shirley (ks = Rs, p1, p2 = nu, nv); twin of kernels/common.py's analytic_specular. 0 where either
 * direction is at or below the horizon. */
CL_INLINE float3 analytic_specular(int kind, float3 ks, float p1, float p2, float3 x, float3 y, float3 n,
                                   float3 wi, float3 wo)
{
    float ci = dot3(n, wi);
    float co = dot3(n, wo);
    if (ci <= 0.0f || co <= 0.0f)
        return (float3)(0.0f, 0.0f, 0.0f);
    float3 h = normalize3((float3)(wi.x + wo.x, wi.y + wo.y, wi.z + wo.z));
    float nh = clampf(dot3(n, h), -1.0f, 1.0f);
    float hi = clampf(dot3(h, wi), 0.0f, 1.0f);
    if (kind == BLINN_PHONG || kind == COOK_TORRANCE || kind == WARD) {
        float spec = isotropic_specular(kind, p1, p2, ci, co, nh, hi) / (ci * co);
        return (float3)(ks.x * spec, ks.y * spec, ks.z * spec);
    }
    if (kind != ANISOTROPIC_WARD && kind != ASHIKHMIN_SHIRLEY) /* (Lambert: no specular term) */
        return (float3)(0.0f, 0.0f, 0.0f);
    float hx = dot3(h, x);
    float hy = dot3(h, y);
    if (kind == ANISOTROPIC_WARD) {
        if (nh <= 0.0f)
            return (float3)(0.0f, 0.0f, 0.0f);
        float e = (hx / p1) * (hx / p1) + (hy / p2) * (hy / p2);
        float spec = exp(-e / (nh * nh)) / (4.0f * M_PI_F * p1 * p2 * sqrt(ci * co));
        return (float3)(ks.x * spec, ks.y * spec, ks.z * spec);
    }
    /* Ashikhmin–Shirley: (n·h)^e as exp(e/2·log(1 − sin²θh)), sin²θh from the tangential components (n·h
     * rounds to within 6e-8 of 1 in float32, which an exponent of 10^4 would make a 6e-4 error). */
    float s2 = hx * hx + hy * hy;
    float d = 1.0f;
    if (s2 >= 1.0f)
        d = 0.0f;
    else if (s2 > 0.0f)
        d = exp(0.5f * ((p1 * hx * hx + p2 * hy * hy) / s2) * log1p_small(-s2));
    float hk = maxf(hi, 1.0e-30f);
    float spec = sqrt((p1 + 1.0f) * (p2 + 1.0f)) / (8.0f * M_PI_F) * d / (hk * maxf(ci, co));
    float f5 = pow5(1.0f - hi);
    return (float3)((ks.x + (1.0f - ks.x) * f5) * spec, (ks.y + (1.0f - ks.y) * f5) * spec,
                    (ks.z + (1.0f - ks.z) * f5) * spec);
}

/* Ashikhmin–Shirley's ρd = 28 Rd/(23π)·(1 − Rs)·(1 − (1 − cos θi/2)⁵)·(1 − (1 − cos θo/2)⁵), without the
 * cosines (kd = Rd, ks = Rs); twin of kernels/common.py's ashikhmin_shirley_diffuse. */
CL_INLINE float3 ashikhmin_shirley_diffuse(float3 kd, float3 ks, float ci, float co)
{
    float g = 28.0f / (23.0f * M_PI_F) * (1.0f - pow5(1.0f - 0.5f * ci)) * (1.0f - pow5(1.0f - 0.5f * co));
    return (float3)(kd.x * (1.0f - ks.x) * g, kd.y * (1.0f - ks.y) * g, kd.z * (1.0f - ks.z) * g);
}

/* brdf_cosine_weighted for the anisotropic kinds, in the facet frame of tangent t (any vector off n): the
 * anisotropic Ward (p1, p2 = alpha_x, alpha_y) and Ashikhmin–Shirley (row [Rd, Rs, nu, nv]); any other kind
 * is brdf_cosine_weighted itself. See warp_biscale.brdf and kernels/common.py. */
CL_INLINE float3 brdf_cosine_weighted_tangent(int kind, __global const float *params, int m, float3 n, float3 t,
                                              float3 wi, float3 wo)
{
    if (kind != ANISOTROPIC_WARD && kind != ASHIKHMIN_SHIRLEY)
        return brdf_cosine_weighted(kind, params, m, n, wi, wo);
    float ci = dot3(n, wi);
    float co = dot3(n, wo);
    if (ci <= 0.0f || co <= 0.0f)
        return (float3)(0.0f, 0.0f, 0.0f);
    __global const float *p = params + 8 * m;
    float3 kd = (float3)(p[0], p[1], p[2]);
    float3 ks = (float3)(p[3], p[4], p[5]);
    float3 x = facet_tangent(n, t);
    float3 spec = analytic_specular(kind, ks, p[6], p[7], x, cross3(n, x), n, wi, wo);
    float3 diffuse = (float3)(kd.x * INV_PI, kd.y * INV_PI, kd.z * INV_PI);
    if (kind == ASHIKHMIN_SHIRLEY)
        diffuse = ashikhmin_shirley_diffuse(kd, ks, ci, co);
    float c = ci * co;
    return (float3)((diffuse.x + spec.x) * c, (diffuse.y + spec.y) * c, (diffuse.z + spec.z) * c);
}

/* ---- Measured (MERL) BRDFs: twin of kernels/common.py's measured_cosine_weighted; the mathematics is
 * warp_biscale.measured.MeasuredBRDF.eval. A table (MeasuredBRDF.kernel_table) is 90 θh × 90 θd × 180 φd
 * samples of 3 floats (f_r RGB, channel scales applied), one table a slot of `tables`. */
#define MERL_RES_TH 90
#define MERL_RES_TD 90
#define MERL_RES_PD 180
#define MERL_TABLE_FLOATS 4374000 /* 3·90·90·180 */

CL_INLINE float3 merl_sample(__global const float *tables, int base, int i, int j, int k)
{
    int s = base + ((i * MERL_RES_TD + j) * MERL_RES_PD + k) * 3;
    return (float3)(tables[s], tables[s + 1], tables[s + 2]);
}

/* The lower node around continuous index c on an axis of `res` bin centres at i + ½, and (in *w) the weight
 * of the next, clamped at the ends (measured._clamped_nodes of c − ½). */
CL_INLINE int merl_nodes(float c, int res, float *w)
{
    float u = clampf(c - 0.5f, 0.0f, (float)(res - 1));
    int i0 = (int)floor(u);
    i0 = i0 < res - 2 ? i0 : res - 2;
    *w = u - (float)i0;
    return i0;
}

/* f_r(n, wi, wo)·(n·wi)⁺(n·wo)⁺ of the measured BRDF of row m ([slot, mode, ...]): Duff et al.'s tangent frame
 * about n, Rusinkiewicz's angles by atan2 of a sine and a cosine (acos loses the digits of θh next to the
 * specular peak), φd folded into [0, π) by reciprocity, BRDFRead.cpp's index axes (θh's a square root), then
 * the nearest bin (mode 1) or trilinear interpolation between bin centres (mode 0; periodic in φd, clamped
 * in θh and θd). */
CL_INLINE float3 measured_cosine_weighted(__global const float *params, int m, float3 n, float3 wi, float3 wo,
                                          __global const float *tables)
{
    float ci = dot3(n, wi);
    float co = dot3(n, wo);
    if (ci <= 0.0f || co <= 0.0f)
        return (float3)(0.0f, 0.0f, 0.0f);
    float sg = n.z < 0.0f ? -1.0f : 1.0f;
    float a = -1.0f / (sg + n.z);
    float b = n.x * n.y * a;
    float3 t = (float3)(1.0f + sg * n.x * n.x * a, sg * b, -sg * n.x);
    float3 bt = (float3)(b, sg + n.y * n.y * a, -n.y);
    float x = dot3(wi, t);
    float y = dot3(wi, bt);
    float z = ci;
    float3 h = normalize3((float3)(x + dot3(wo, t), y + dot3(wo, bt), z + co));
    float s = sqrt(h.x * h.x + h.y * h.y); /* sin θh */
    float theta_h = atan2(s, h.z);
    float cos_phi = 1.0f, sin_phi = 0.0f;
    if (s > 0.0f) {
        cos_phi = h.x / s;
        sin_phi = h.y / s;
    }
    float dx = h.z * (x * cos_phi + y * sin_phi) - s * z;
    float dy = y * cos_phi - x * sin_phi;
    float dz = x * h.x + y * h.y + z * h.z;
    float theta_d = atan2(sqrt(dx * dx + dy * dy), dz);
    float phi_d = atan2(dy, dx);
    if (phi_d < 0.0f)
        phi_d = phi_d + M_PI_F;
    float ch = sqrt(maxf(theta_h, 0.0f) / M_PI_2_F) * (float)MERL_RES_TH;
    float cd = theta_d / M_PI_2_F * (float)MERL_RES_TD;
    float cp = phi_d / M_PI_F * (float)MERL_RES_PD;
    __global const float *p = params + 8 * m;
    int base = (int)p[0] * MERL_TABLE_FLOATS;
    float3 f = (float3)(0.0f, 0.0f, 0.0f);
    if (p[1] != 0.0f) { /* nearest: the bin holding the query (BRDFRead.cpp) */
        int i = clamp((int)floor(ch), 0, MERL_RES_TH - 1);
        int j = clamp((int)floor(cd), 0, MERL_RES_TD - 1);
        int k = clamp((int)floor(cp), 0, MERL_RES_PD - 1);
        f = merl_sample(tables, base, i, j, k);
    } else {
        float wh, wd;
        int i0 = merl_nodes(ch, MERL_RES_TH, &wh);
        int j0 = merl_nodes(cd, MERL_RES_TD, &wd);
        float u = cp - 0.5f;
        float kf = floor(u);
        float wpd = u - kf;
        int k0 = (int)kf;
        if (k0 < 0)
            k0 += MERL_RES_PD;
        if (k0 >= MERL_RES_PD)
            k0 -= MERL_RES_PD;
        int k1 = k0 + 1 < MERL_RES_PD ? k0 + 1 : 0;
        for (int di = 0; di < 2; ++di) {
            float fi = di ? wh : 1.0f - wh;
            for (int dj = 0; dj < 2; ++dj) {
                float fij = fi * (dj ? wd : 1.0f - wd);
                float3 lo = merl_sample(tables, base, i0 + di, j0 + dj, k0);
                float3 hi = merl_sample(tables, base, i0 + di, j0 + dj, k1);
                float wl = 1.0f - wpd;
                f = (float3)(f.x + fij * (wl * lo.x + wpd * hi.x), f.y + fij * (wl * lo.y + wpd * hi.y),
                             f.z + fij * (wl * lo.z + wpd * hi.z));
            }
        }
    }
    float cc = ci * co;
    return (float3)(f.x * cc, f.y * cc, f.z * cc);
}

/* f_r·(n·wi)⁺(n·wo)⁺ of material row m, any kind: the measured lookup, the anisotropic kinds in the frame of
 * tangent t (read by those only), the isotropic ones. The dispatcher of the stages that take measured BRDFs
 * (the ground truth, its interreflection, the matrix method's M). */
CL_INLINE float3 material_cosine_weighted(int kind, __global const float *params, int m, float3 n, float3 t,
                                          float3 wi, float3 wo, __global const float *tables)
{
    if (kind == MEASURED)
        return measured_cosine_weighted(params, m, n, wi, wo, tables);
    if (kind == ANISOTROPIC_WARD || kind == ASHIKHMIN_SHIRLEY)
        return brdf_cosine_weighted_tangent(kind, params, m, n, t, wi, wo);
    return brdf_cosine_weighted(kind, params, m, n, wi, wo);
}

/* Index of the lowest set bit of a non-zero word. OpenCL 1.2 has no ctz, and its popcount, the
 * obvious route (popcount((m & -m) - 1)), is a library call in PoCL; the de Bruijn
 * multiply-and-look-up below gives the same index for every word several times faster. */
__constant int DE_BRUIJN_32[32] = {0,  1,  28, 2,  29, 14, 24, 3, 30, 22, 20, 15, 25, 17, 4,  8,
                                   31, 27, 13, 23, 21, 19, 16, 7, 26, 12, 18, 6,  11, 5,  10, 9};
CL_INLINE int lowest_bit(uint m) { return DE_BRUIJN_32[((m & (0u - m)) * 0x077CB531u) >> 27]; }

/* Set bits of a word, by SWAR arithmetic (OpenCL's popcount is a library call in PoCL, see above). */
CL_INLINE int bit_count(uint x)
{
    x = x - ((x >> 1) & 0x55555555u);
    x = (x & 0x33333333u) + ((x >> 2) & 0x33333333u);
    x = (x + (x >> 4)) & 0x0F0F0F0Fu;
    return (int)((x * 0x01010101u) >> 24);
}

/* ============================================================================================
 * Ray casting against a triangle mesh through a BVH: shared by cl/visibility.cl (any-hit on the
 * small-scale tile) and cl/trace.cl (closest and any hit on the large-scale mesh), so both walk
 * one traversal.
 *
 * Triangles: `tris` (F, 9) floats [a, b - a, c - a] in BVH slot order (warp_biscale.bvh), the
 * edges computed in float32 on the host exactly as kernels/visibility.py's hit_any_triangle
 * computes them. BVH nodes: `nodes` (N, 8) floats, [min xyz, max xyz, child0, child1] with the
 * two child words int32 bit patterns: inner (left, right), leaf (first slot, -count). A slot maps
 * back to its original face through Bvh.tri_index (uploaded by the backend where needed).
 * ============================================================================================ */

#define BVH_STACK 64 /* = warp_biscale.bvh.STACK_SIZE; the builder guarantees depth <= this */

/* Möller–Trumbore, double-sided, exactly the acceptance test of kernels/visibility.py's hit_any_triangle:
 * det != 0, u >= 0, v >= 0, u + v <= 1, t_lo < t <= t_hi, every quantity computed with the same
 * operations in the same order (p = d × e2, det = p·e1, tv = o − a, q = tv × e1, ...). The early
 * out on u outside [0, 1] never changes the outcome: u + v <= 1 with v >= 0 implies u <= 1 in
 * rounded arithmetic too. A hit also returns t and the barycentric weights u (of vertex b) and
 * v (of vertex c); vertex a gets 1 - u - v. */
CL_INLINE int intersect_triangle(__global const float *tri, float3 o, float3 d, float t_lo, float t_hi,
                                 float *t_out, float *u_out, float *v_out)
{
    float ax = tri[0], ay = tri[1], az = tri[2];
    float e1x = tri[3], e1y = tri[4], e1z = tri[5];
    float e2x = tri[6], e2y = tri[7], e2z = tri[8];
    float px = d.y * e2z - d.z * e2y, py = d.z * e2x - d.x * e2z, pz = d.x * e2y - d.y * e2x;
    float det = px * e1x + py * e1y + pz * e1z;
    if (det == 0.0f)
        return 0;
    float inv = 1.0f / det;
    float tx = o.x - ax, ty = o.y - ay, tz = o.z - az;
    float u = (tx * px + ty * py + tz * pz) * inv;
    if (u < 0.0f || u > 1.0f)
        return 0;
    float qx = ty * e1z - tz * e1y, qy = tz * e1x - tx * e1z, qz = tx * e1y - ty * e1x;
    float v = (d.x * qx + d.y * qy + d.z * qz) * inv;
    float t = (e2x * qx + e2y * qy + e2z * qz) * inv;
    if (!(v >= 0.0f && u + v <= 1.0f && t > t_lo && t <= t_hi))
        return 0;
    *t_out = t;
    *u_out = u;
    *v_out = v;
    return 1;
}

/* Any hit with t in (t_lo, t_hi]: intersect_triangle without its outputs (inlined, they cost nothing). */
CL_INLINE int hit_triangle(__global const float *tri, float3 o, float3 d, float t_lo, float t_hi)
{
    float t, u, v;
    return intersect_triangle(tri, o, d, t_lo, t_hi, &t, &u, &v);
}

/* Brute force: 1 if any triangle is hit with t in (t_lo, t_hi]. */
CL_INLINE int hit_any_triangle(__global const float *tris, int n_tris, float3 o, float3 d, float t_lo, float t_hi)
{
    for (int f = 0; f < n_tris; ++f)
        if (hit_triangle(tris + 9 * f, o, d, t_lo, t_hi))
            return 1;
    return 0;
}

/* Slab test against a node's box over [t_lo, t_hi]; inv = 1/d with |d| >= 1e-20 per axis (see
 * safe_inverse), so no 0·inf appears. Boxes are padded on the host, so inclusive comparisons and
 * float32 rounding here can only admit a box, never lose one that holds an accepted hit. */
CL_INLINE int hit_box(__global const float *node, float3 o, float3 inv, float t_lo, float t_hi, float *t_enter)
{
    float tx0 = (node[0] - o.x) * inv.x, tx1 = (node[3] - o.x) * inv.x;
    float ty0 = (node[1] - o.y) * inv.y, ty1 = (node[4] - o.y) * inv.y;
    float tz0 = (node[2] - o.z) * inv.z, tz1 = (node[5] - o.z) * inv.z;
    float tmin = maxf(maxf(minf(tx0, tx1), minf(ty0, ty1)), maxf(minf(tz0, tz1), t_lo));
    float tmax = minf(minf(maxf(tx0, tx1), maxf(ty0, ty1)), minf(maxf(tz0, tz1), t_hi));
    *t_enter = tmin;
    return tmin <= tmax;
}

/* 1/x with x pushed away from zero to ±1e-20 (as Warp's mesh queries do for a zero component). */
CL_INLINE float safe_inverse(float x)
{
    return 1.0f / (x >= 0.0f ? maxf(x, 1.0e-20f) : minf(x, -1.0e-20f));
}

/* BVH any-hit: 1 if any triangle is hit with t in (t_lo, t_hi], the same test as the brute force.
 * Both children's boxes are tested at an inner node; the nearer hit one is walked first and the
 * other pushed on a small stack. */
CL_INLINE int bvh_any_hit(__global const float *nodes, __global const float *tris, float3 o, float3 d,
                          float t_lo, float t_hi)
{
    float3 inv = (float3)(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z));
    float t0, t1;
    if (!hit_box(nodes, o, inv, t_lo, t_hi, &t0))
        return 0;
    int stack[BVH_STACK];
    int sp = 0;
    int cur = 0;
    while (1) {
        __global const float *node = nodes + 8 * cur;
        int a = as_int(node[6]);
        int b = as_int(node[7]);
        if (b < 0) {
            for (int i = a; i < a - b; ++i)
                if (hit_triangle(tris + 9 * i, o, d, t_lo, t_hi))
                    return 1;
            if (sp == 0)
                return 0;
            cur = stack[--sp];
            continue;
        }
        int h0 = hit_box(nodes + 8 * a, o, inv, t_lo, t_hi, &t0);
        int h1 = hit_box(nodes + 8 * b, o, inv, t_lo, t_hi, &t1);
        if (h0 && h1) {
            if (t1 < t0) {
                stack[sp++] = a;
                cur = b;
            } else {
                stack[sp++] = b;
                cur = a;
            }
        } else if (h0) {
            cur = a;
        } else if (h1) {
            cur = b;
        } else {
            if (sp == 0)
                return 0;
            cur = stack[--sp];
        }
    }
}


/* BVH closest hit: the slot of the nearest triangle hit with t in (t_lo, t_hi], or -1, with its t
 * and barycentric (u, v). The walk of bvh_any_hit, except that the far bound shrinks to the
 * nearest hit so far: boxes entered beyond it are skipped, also when popped (the stack keeps each
 * node's entry distance, since the bound may have shrunk since it was pushed). A ray through an
 * edge shared by two triangles hits both at one t; the first found is kept. */
CL_INLINE int bvh_closest_hit(__global const float *nodes, __global const float *tris, float3 o, float3 d,
                              float t_lo, float t_hi, float *t_hit, float *u_hit, float *v_hit)
{
    float3 inv = (float3)(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z));
    float best = t_hi, best_u = 0.0f, best_v = 0.0f;
    int slot = -1;
    float t0, t1;
    if (!hit_box(nodes, o, inv, t_lo, best, &t0))
        return -1;
    int stack[BVH_STACK];
    float stack_t[BVH_STACK];
    int sp = 0;
    int cur = 0;
    while (1) {
        __global const float *node = nodes + 8 * cur;
        int a = as_int(node[6]);
        int b = as_int(node[7]);
        int descend = 0;
        if (b < 0) {
            for (int i = a; i < a - b; ++i) {
                float t, u, v;
                if (intersect_triangle(tris + 9 * i, o, d, t_lo, best, &t, &u, &v) && (slot < 0 || t < best)) {
                    best = t;
                    best_u = u;
                    best_v = v;
                    slot = i;
                }
            }
        } else {
            int h0 = hit_box(nodes + 8 * a, o, inv, t_lo, best, &t0);
            int h1 = hit_box(nodes + 8 * b, o, inv, t_lo, best, &t1);
            if (h0 && h1) {
                if (t1 < t0) {
                    stack_t[sp] = t0;
                    stack[sp++] = a;
                    cur = b;
                } else {
                    stack_t[sp] = t1;
                    stack[sp++] = b;
                    cur = a;
                }
                descend = 1;
            } else if (h0 || h1) {
                cur = h0 ? a : b;
                descend = 1;
            }
        }
        if (!descend) {
            /* Pop the next node still in front of the nearest hit. */
            while (sp > 0 && stack_t[sp - 1] > best)
                --sp;
            if (sp == 0)
                break;
            cur = stack[--sp];
        }
    }
    *t_hit = best;
    *u_hit = best_u;
    *v_hit = best_v;
    return slot;
}

/* The cube-map bin of unit normal n at `resolution` (reference.cube_bin): face·R² + row·R + col. */
CL_INLINE int cube_bin(float3 n, int resolution)
{
    float ax = absf(n.x);
    float ay = absf(n.y);
    float az = absf(n.z);
    int face;
    float major, u, v;
    if (ax >= ay && ax >= az) {
        face = n.x >= 0.0f ? 0 : 1;
        major = ax;
        u = n.y;
        v = n.z;
    } else if (ay >= az) {
        face = n.y >= 0.0f ? 2 : 3;
        major = ay;
        u = n.x;
        v = n.z;
    } else {
        face = n.z >= 0.0f ? 4 : 5;
        major = az;
        u = n.x;
        v = n.y;
    }
    if (major <= 0.0f)
        major = 1.0f;
    float r = (float)resolution;
    int col = (int)floor((u / major + 1.0f) * 0.5f * r);
    int row = (int)floor((v / major + 1.0f) * 0.5f * r);
    col = col < 0 ? 0 : (col > resolution - 1 ? resolution - 1 : col);
    row = row < 0 ? 0 : (row > resolution - 1 ? resolution - 1 : row);
    return face * resolution * resolution + row * resolution + col;
}
