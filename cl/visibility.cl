/* Visibility of the infinitely tiled surface (Wu §3.3, docs/design.md §4): bits V_s(w_k).
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
 * The triangle test, the box test and the BVH walk (hit_triangle, hit_any_triangle, hit_box,
 * safe_inverse, bvh_any_hit) live in cl/common.cl, shared with cl/trace.cl; the layouts of
 * `nodes` and `tris` are described there.
 */

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
        float2 exits = cell_exits(o, d, x0, y0, px, py);
        float t_side = minf(exits.x, exits.y);
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
        o = next_cell(o, d, t_exit, exits, px, py);
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
