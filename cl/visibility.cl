/* Visibility of the infinitely tiled surface (Wu §3.3, DESIGN §4): bits V_s(w_k).
 *
 * Twin of kernels/visibility.py; the mathematics is warp_biscale.reference.trace_periodic. One
 * work-item per ray (facet s, direction k) writes a byte, and pack_bits folds 32 bytes into a word
 * (no atomics). The NDRange is (Ns, D): OpenCL's dimension 0 varies fastest, so neighbouring
 * work-items trace neighbouring facets (ordered by face) along the same direction, as Warp's
 * (D, Ns) launch does; dimension 0 is rounded up to a whole work-group and the surplus work-items
 * return. Rays are any-hit. A ray leaving the tile through its xy boundary re-enters on the opposite side
 * until it passes above the tile's highest point.
 *
 * One difference from the Warp twin, by design: Warp's BVH query (wp.mesh_query_ray_anyhit) uses
 * its own watertight triangle test over t in [0, max_t) from the origin moved back by `back`;
 * here the BVH walk ends in the very Möller–Trumbore test of the brute force, over the same
 * (-back, t_exit + eps] from the unmoved origin, so BVH and brute force agree bit for bit unless a
 * box test wrongly prunes (which the host-side padding rules out; tests/test_bvh.py checks).
 *
 * Triangles: `tris` (F, 9) floats [a, b - a, c - a] in BVH slot order (warp_biscale.bvh), the
 * edges computed in float32 on the host exactly as Warp's hit_any_triangle computes them.
 * BVH nodes: `nodes` (N, 8) floats, [min xyz, max xyz, child0, child1] with the two child words
 * int32 bit patterns: inner (left, right), leaf (first slot, -count).
 */

#define BVH_STACK 64 /* = warp_biscale.bvh.STACK_SIZE; the builder guarantees depth <= this */

/* Möller–Trumbore, double-sided, exactly the acceptance test of Warp's hit_any_triangle:
 * det != 0, u >= 0, v >= 0, u + v <= 1, t_lo < t <= t_hi, every quantity computed with the same
 * operations in the same order (p = d × e2, det = p·e1, tv = o − a, q = tv × e1, ...). The early
 * out on u outside [0, 1] never changes the outcome: u + v <= 1 with v >= 0 implies u <= 1 in
 * rounded arithmetic too. */
CL_INLINE int hit_triangle(__global const float *tri, float3 o, float3 d, float t_lo, float t_hi)
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
    return (v >= 0.0f && u + v <= 1.0f && t > t_lo && t <= t_hi) ? 1 : 0;
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

/* 1 if the ray leaves the tile's height range unblocked (see reference.trace_periodic). Each
 * cell's segment is tested over t in (-back, t_exit + eps]: back = 0 for the first segment (it
 * starts on the facet), eps afterwards so that rounding at a wrap cannot open a gap. */
CL_INLINE int trace_periodic(__global const float *nodes, __global const float *tris, int n_tris, int brute_force,
                             float3 start, float3 d, float x0, float y0, float px, float py, float z_lo,
                             float z_hi, float eps)
{
    if (d.z <= 0.0f)
        return 0;
    float3 o = start;
    float z_top = z_hi + eps;
    float back = 0.0f;
    int steps = 4 + (int)ceil((z_hi - z_lo + 2.0f * eps) / d.z * (absf(d.x) / px + absf(d.y) / py));
    for (int step = 0; step < steps + 1; ++step) {
        float t_top = (z_top - o.z) / d.z;
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
        float t_side = minf(t_x, t_y);
        float t_exit = minf(t_top, t_side);
        int hit;
        if (brute_force != 0)
            hit = hit_any_triangle(tris, n_tris, o, d, -back, t_exit + eps);
        else
            hit = bvh_any_hit(nodes, tris, o, d, -back, t_exit + eps);
        if (hit != 0)
            return 0;
        if (t_top <= t_side)
            return 1;
        o = (float3)(o.x + t_exit * d.x, o.y + t_exit * d.y, o.z + t_exit * d.z);
        if (t_x <= t_exit)
            o.x = o.x - (d.x < 0.0f ? -1.0f : 1.0f) * px;
        if (t_y <= t_exit)
            o.y = o.y - (d.y < 0.0f ? -1.0f : 1.0f) * py;
        back = eps;
    }
    return 1;
}

__kernel void visibility_rays(
    __global const float *nodes,         /* (N, 8) BVH records */
    __global const float *tris,          /* (F, 9) [a, b - a, c - a], BVH slot order */
    const int n_tris,
    __global const float *face_normals,  /* (F, 3), original face order */
    const int brute_force,
    __global const float *position,      /* (Ns, 3) */
    __global const int *facet_face,      /* (Ns,) */
    const int n_facets,
    __global const float *directions,    /* (D, 3) */
    const float x0, const float y0, const float px, const float py,
    const float z_lo, const float z_hi, const float eps,
    __global uchar *visible)             /* (D, Ns) */
{
    int s = get_global_id(0);
    int k = get_global_id(1);
    if (s >= n_facets) /* dimension 0 is rounded up to a whole work-group */
        return;
    float3 d = load3(directions, k);
    float3 ng = load3(face_normals, facet_face[s]);
    uchar v = 0;
    /* Below the facet's own plane the ray would enter the surface: not visible. */
    if (dot3(ng, d) > 0.0f) {
        float3 p = load3(position, s);
        float3 o = (float3)(p.x + eps * ng.x, p.y + eps * ng.y, p.z + eps * ng.z);
        if (trace_periodic(nodes, tris, n_tris, brute_force, o, d, x0, y0, px, py, z_lo, z_hi, eps) != 0)
            v = 1;
    }
    visible[(long)k * n_facets + s] = v;
}

/* Pack one byte per ray into words of 32 facets: bit (s mod 32) of word s / 32. */
__kernel void pack_bits(__global const uchar *visible, const int n_facets, const int words,
                        __global uint *bits)
{
    int w = get_global_id(0);
    int k = get_global_id(1);
    if (w >= words)
        return;
    uint word = 0u;
    for (int b = 0; b < 32; ++b) {
        int s = w * 32 + b;
        if (s < n_facets && visible[(long)k * n_facets + s] != 0)
            word |= 1u << b;
    }
    bits[k * words + w] = word;
}
