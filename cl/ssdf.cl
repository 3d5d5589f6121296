/* SSDF distance transform (Wang 2009 Eq. 23) over an octahedral grid of world directions.
 *
 * Twin of kernels/ssdf.py; the mathematics is warp_biscale.reference.ssdf_distance. One work-item
 * per (texel k, vertex v), NDRange (N, V): dimension 0 varies fastest, so neighbouring work-items
 * take neighbouring texels of one vertex, as Warp's (V, N) launch does; dimension 0 is rounded up
 * to a whole work-group and the surplus work-items return. No atomics.
 *
 * θd = ±(angle(d_k, t) − h_k) for the nearest texel direction t of the opposite class (+ visible,
 * − occluded), ±π if the vertex has none. Exact, with pruning by blocks of neighbouring texels,
 * each bounded by a cone (axis, radius r widened on the host by 1e-3 rad against float32
 * rounding): pass 1 over the cones of blocks holding the opposite class finds the nearest one
 * (angle − r) and the smallest far bound (angle + r); pass 2 scans that block first, then only
 * blocks whose near bound beats both the far bound and the best found so far. Bounds are compared
 * as cosines (cos(a ∓ r) = cos a cos r ± sin a sin r): no acos per block. The nearest texel is the
 * largest float32 dot product; its angle is then atan2(|d×t|, d·t), accurate near 0.
 *
 * Buffers: visible (V, N) uchar; directions (N, 3) float; half_angle (N,) float; block_members
 * (B, M) int, −1 pads; block_axis (B, 3) float; block_cos, block_sin (B,) float, of each cone's
 * radius; block_classes (V, B) uchar (bit 0: a visible member, bit 1: an occluded one);
 * theta (V, N) float, rad.
 */

/* cos of the smallest angle from d to a cone of radius r whose axis has cos ca with d (1 if inside). */
CL_INLINE float cone_near_cos(float ca, float cos_r, float sin_r)
{
    if (ca >= cos_r)
        return 1.0f;
    float sa = sqrt(maxf(1.0f - ca * ca, 0.0f));
    return ca * cos_r + sa * sin_r;
}

/* cos of the largest angle from d to the cone (-1 if the cone reaches -d). */
CL_INLINE float cone_far_cos(float ca, float cos_r, float sin_r)
{
    if (ca <= -cos_r)
        return -1.0f;
    float sa = sqrt(maxf(1.0f - ca * ca, 0.0f));
    return ca * cos_r - sa * sin_r;
}

__kernel void ssdf_distance(__global const uchar *visible, __global const float *directions,
                            __global const float *half_angle, __global const int *block_members,
                            __global const float *block_axis, __global const float *block_cos,
                            __global const float *block_sin, __global const uchar *block_classes, int n_texels,
                            int n_vertices, int n_blocks, int n_members, __global float *theta)
{
    int k = get_global_id(0);
    int v = get_global_id(1);
    if (k >= n_texels || v >= n_vertices)
        return;
    __global const uchar *row = visible + (size_t)v * n_texels;
    __global const uchar *classes = block_classes + (size_t)v * n_blocks;
    uchar mine = row[k];
    uchar want = mine ? 2 : 1; /* the block bit of the opposite class */
    float sign = mine ? 1.0f : -1.0f;
    float3 d = load3(directions, k);
    /* Pass 1 (cones only): the block nearest to d that holds the opposite class, and the best far
     * bound (some opposite texel lies at least this close). All in cosines: larger = nearer. */
    int first = -1;
    float first_cos = -3.0f;
    float bound = -2.0f;
    for (int b = 0; b < n_blocks; ++b) {
        if (classes[b] & want) {
            float ca = dot3(d, load3(block_axis, b));
            float near = cone_near_cos(ca, block_cos[b], block_sin[b]);
            if (near > first_cos) {
                first_cos = near;
                first = b;
            }
            bound = maxf(bound, cone_far_cos(ca, block_cos[b], block_sin[b]));
        }
    }
    /* Pass 2: scan that nearest block first (its best texel is usually the answer, a tight bound),
     * then every other block whose near bound still beats the best found. */
    float best_dot = -2.0f;
    int best = -1;
    for (int i = 0; i <= n_blocks; ++i) {
        int b = i > 0 ? i - 1 : first;
        int scan = first >= 0;
        if (i > 0) {
            scan = b != first && (classes[b] & want);
            if (scan)
                scan = cone_near_cos(dot3(d, load3(block_axis, b)), block_cos[b], block_sin[b]) >=
                       maxf(best_dot, bound);
        }
        if (!scan)
            continue;
        __global const int *members = block_members + (size_t)b * n_members;
        for (int m = 0; m < n_members; ++m) {
            int t = members[m];
            if (t >= 0 && row[t] != mine) {
                float c = dot3(d, load3(directions, t));
                if (c > best_dot) {
                    best_dot = c;
                    best = t;
                }
            }
        }
    }
    float out = sign * 3.14159265358979f;
    if (best >= 0) {
        float3 t = load3(directions, best);
        float cx = d.y * t.z - d.z * t.y, cy = d.z * t.x - d.x * t.z, cz = d.x * t.y - d.y * t.x;
        float angle = atan2(sqrt(cx * cx + cy * cy + cz * cz), dot3(d, t));
        out = sign * (angle - half_angle[k]);
    }
    theta[(size_t)v * n_texels + k] = out;
}
