/* a_v(w) and the ground-truth effective BRDF (docs/design.md §4), exact small-scale BRDFs.
 *
 * Twin of kernels/truth.py; the mathematics is warp_biscale.reference.visible_area and
 * reference.effective_brdf. Both sums over facets are split into chunks of 32-facet words: one
 * work-item per (chunk c, output) writes partial[c, output], and a second kernel adds the chunks
 * in order.
 *
 * Summation as in the Warp twin: each 32-facet word is summed in float32 and added into a float64
 * accumulator (a float32 running sum of n similar terms loses up to ~n·eps/2), the partial is
 * stored as float32, and the chunks are added in float64. Needs cl_khr_fp64.
 *
 * No atomics (OpenCL has no float atomics). NDRanges are (outputs, chunks): dimension 0 varies
 * fastest, matching the linear order of Warp's (chunks, outputs) launch; it is rounded up to a
 * whole work-group and the surplus work-items return. 3-vectors are float arrays of stride 3.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

__kernel void visible_area_partial(
    __global const float *directions,  /* (D, 3) */
    __global const uint *bits,         /* (D, words) */
    const int n_words,
    __global const float *normal,      /* (Ns, 3) */
    __global const float *area,        /* (Ns,) */
    const int words_per_chunk,
    const int n_dirs,
    __global float *partial)           /* (chunks, D) */
{
    int k = get_global_id(0);
    int c = get_global_id(1);
    if (k >= n_dirs)
        return;
    float3 d = load3(directions, k);
    double acc = 0.0;
    int w_start = c * words_per_chunk;
    int w_end = w_start + words_per_chunk < n_words ? w_start + words_per_chunk : n_words;
    for (int w = w_start; w < w_end; ++w) {
        uint m = bits[k * n_words + w];
        float block = 0.0f;
        while (m != 0u) {
            int b = lowest_bit(m);
            m = m & (m - 1u);
            int s = w * 32 + b;
            block += maxf(dot3(load3(normal, s), d), 0.0f) * area[s];
        }
        acc += (double)block;
    }
    partial[c * n_dirs + k] = (float)acc;
}

__kernel void sum_chunks_area(__global const float *partial, const int chunks, const int n_dirs, __global float *a_v)
{
    int k = get_global_id(0);
    if (k >= n_dirs)
        return;
    double acc = 0.0;
    for (int c = 0; c < chunks; ++c)
        acc += (double)partial[c * n_dirs + k];
    a_v[k] = (float)acc;
}

__kernel void effective_brdf_partial(
    __global const float *directions,  /* (D, 3) */
    __global const int *pair_i,        /* (P,) */
    __global const int *pair_o,        /* (P,) */
    __global const uint *bits,         /* (D, words) */
    const int n_words,
    __global const float *normal,      /* (Ns, 3) */
    __global const float *weight,      /* (Ns, 3) colour × area */
    __global const int *material,      /* (Ns,) */
    __global const int *kinds,         /* (M,) */
    __global const float *params,      /* (M, 8) */
    __global const int *face,          /* (Ns,) each facet's face: read for the anisotropic kinds only */
    __global const float *tangent,     /* (F, 3) the tile's face tangents: likewise */
    __global const float *tables,      /* the measured BRDFs' tables: read for the measured kind only */
    const int words_per_chunk,
    const int n_pairs,
    __global float *partial)           /* (chunks, P, 3) */
{
    int p = get_global_id(0);
    int c = get_global_id(1);
    if (p >= n_pairs)
        return;
    int i = pair_i[p];
    int o = pair_o[p];
    float3 wi = load3(directions, i);
    float3 wo = load3(directions, o);
    double ax = 0.0, ay = 0.0, az = 0.0;
    int w_start = c * words_per_chunk;
    int w_end = w_start + words_per_chunk < n_words ? w_start + words_per_chunk : n_words;
    for (int w = w_start; w < w_end; ++w) {
        uint m = bits[i * n_words + w] & bits[o * n_words + w];
        float3 block = (float3)(0.0f, 0.0f, 0.0f);
        while (m != 0u) {
            int b = lowest_bit(m);
            m = m & (m - 1u);
            int s = w * 32 + b;
            int mat = material[s];
            int kind = kinds[mat];
            float3 n = load3(normal, s);
            float3 tg = (kind == ANISOTROPIC_WARD || kind == ASHIKHMIN_SHIRLEY) ? load3(tangent, face[s])
                                                                                : (float3)(1.0f, 0.0f, 0.0f);
            float3 f = material_cosine_weighted(kind, params, mat, n, tg, wi, wo, tables);
            float3 wt = load3(weight, s);
            block = (float3)(block.x + f.x * wt.x, block.y + f.y * wt.y, block.z + f.z * wt.z);
        }
        ax += (double)block.x;
        ay += (double)block.y;
        az += (double)block.z;
    }
    store3(partial, c * n_pairs + p, (float3)((float)ax, (float)ay, (float)az));
}

__kernel void sum_chunks_brdf(
    __global const float *partial,     /* (chunks, P, 3) */
    const int chunks,
    const int n_pairs,
    __global const int *pair_o,        /* (P,) */
    __global const float *a_v,         /* (D,) */
    __global float *out)               /* (P, 3) */
{
    int p = get_global_id(0);
    if (p >= n_pairs)
        return;
    double ax = 0.0, ay = 0.0, az = 0.0;
    for (int c = 0; c < chunks; ++c) {
        float3 x = load3(partial, c * n_pairs + p);
        ax += (double)x.x;
        ay += (double)x.y;
        az += (double)x.z;
    }
    float area = a_v[pair_o[p]];
    if (area > 0.0f)
        store3(out, p, (float3)((float)(ax / (double)area), (float)(ay / (double)area), (float)(az / (double)area)));
    else
        store3(out, p, (float3)(0.0f, 0.0f, 0.0f));
}

/* ------------------------------------------------------------------------------------------------
 * Small-scale interreflection (docs/design.md §4.6): the bounces 2..B of wb.ground_truth(bounces=B).
 * Twin of kernels/truth.py's interreflection_partial; the estimator and its float64 oracle are
 * warp_biscale.reference.interreflection (the same random numbers).
 * ------------------------------------------------------------------------------------------------ */

#define IR_ESCAPED (-1) /* trace_periodic_closest: the ray left above the tile */
#define IR_LOST (-2)    /* ... below it, or ran out of cells */
#define IR_MAX_CELLS 64 /* = reference.INTERREFLECTION_MAX_CELLS */

/* PCG-RXS-M-XS (Jarzynski & Olano 2020), in uint32 (reference.pcg_hash). */
CL_INLINE uint pcg_hash(uint v)
{
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

/* A uniform number in [0, 1) with 24 bits, a hash of (seed, path, wo, dimension). */
CL_INLINE float path_uniform(int seed, int path, int o, int dim)
{
    uint h = pcg_hash((uint)seed);
    h = pcg_hash(h + (uint)path);
    h = pcg_hash(h + (uint)o);
    h = pcg_hash(h + (uint)dim);
    return (float)(h >> 8u) * (1.0f / 16777216.0f);
}

CL_INLINE float3 cosine_direction(float3 n, float u1, float u2)
{
    float3 ref = absf(n.x) < 0.9f ? (float3)(1.0f, 0.0f, 0.0f) : (float3)(0.0f, 1.0f, 0.0f);
    float3 a = normalize3(cross3(n, ref));
    float3 b = cross3(n, a);
    float r = sqrt(u1);
    float phi = 2.0f * M_PI_F * u2;
    float ca = r * cos(phi), sb = r * sin(phi), cz = sqrt(maxf(1.0f - u1, 0.0f));
    return normalize3((float3)(ca * a.x + sb * b.x + cz * n.x, ca * a.y + sb * b.y + cz * n.y,
                               ca * a.z + sb * b.z + cz * n.z));
}

/* The first hit through the infinitely tiled surface: its face (and position in the base cell), or
 * IR_ESCAPED / IR_LOST. Cell by cell as trace_periodic of cl/visibility.cl, also downward. */
CL_INLINE int trace_periodic_closest(__global const float *nodes, __global const float *tris,
                                     __global const int *tri_index, float3 start, float3 d, float x0, float y0,
                                     float px, float py, float z_lo, float z_hi, float eps, float3 *hit)
{
    float3 o = start;
    float back = 0.0f;
    for (int step = 0; step < IR_MAX_CELLS; ++step) {
        float t_z = 1.0e30f;
        if (d.z > 0.0f)
            t_z = (z_hi + eps - o.z) / d.z;
        else if (d.z < 0.0f)
            t_z = (z_lo - eps - o.z) / d.z;
        float2 exits = cell_exits(o, d, x0, y0, px, py);
        float t_side = minf(exits.x, exits.y);
        float t_exit = minf(t_z, t_side);
        float t, u, v;
        int slot = bvh_closest_hit(nodes, tris, o, d, -back, t_exit + eps, &t, &u, &v);
        if (slot >= 0) {
            *hit = (float3)(o.x + t * d.x, o.y + t * d.y, o.z + t * d.z);
            return tri_index[slot];
        }
        if (t_z <= t_side)
            return d.z > 0.0f ? IR_ESCAPED : IR_LOST;
        o = next_cell(o, d, t_exit, exits, px, py);
        back = eps;
    }
    return IR_LOST;
}

CL_INLINE float3 mul3(float3 a, float3 b) { return (float3)(a.x * b.x, a.y * b.y, a.z * b.z); }

__kernel void interreflection_partial(
    __global const float *nodes,         /* (N, 8) BVH records */
    __global const float *tris,          /* (F, 9) BVH slot order */
    __global const int *tri_index,       /* (F,) slot -> face */
    __global const float *face_normals,  /* (F, 3) */
    __global const int *face_material,   /* (F,) */
    __global const float *face_color,    /* (F, 3) */
    __global const float *directions,    /* (D, 3) */
    __global const int *pair_i,          /* (P,) */
    __global const int *pair_o,          /* (P,) */
    __global const uint *bits,           /* (D, words) */
    const int n_words,
    __global const float *position,      /* (Ns, 3) tile-local */
    __global const float *normal,        /* (Ns, 3) */
    __global const float *weight,        /* (Ns, 3) colour × area */
    __global const int *material,        /* (Ns,) */
    __global const int *face,            /* (Ns,) */
    __global const int *kinds,           /* (M,) */
    __global const float *params,        /* (M, 8) */
    __global const float *tangent,       /* (F, 3), read where anisotropic */
    __global const float *tables,        /* the measured BRDFs' tables, read for the measured kind */
    const int anisotropic,
    const int n_facets,
    const int paths,
    const int paths_per_chunk,
    const int bounces,
    const int seed,
    const float x0, const float y0, const float px, const float py,
    const float z_lo, const float z_hi, const float eps,
    const int n_pairs,
    __global float *partial)             /* (chunks, P, 3) */
{
    int p = get_global_id(0);
    int c = get_global_id(1);
    if (p >= n_pairs)
        return;
    int i = pair_i[p];
    int o = pair_o[p];
    float3 wi = load3(directions, i);
    float3 wo = load3(directions, o);
    double ax = 0.0, ay = 0.0, az = 0.0;
    int j_start = c * paths_per_chunk;
    int j_end = j_start + paths_per_chunk < paths ? j_start + paths_per_chunk : paths;
    for (int j = j_start; j < j_end; ++j) {
        int s = (int)(((float)j + 0.5f) * (float)n_facets / (float)paths);
        s = s < n_facets - 1 ? s : n_facets - 1;
        if (((bits[o * n_words + (s >> 5)] >> (uint)(s & 31)) & 1u) == 0u)
            continue;
        float3 x = load3(position, s);
        int f_s = face[s];
        float3 n = load3(normal, s);
        float3 ng = load3(face_normals, f_s);
        int m = material[s];
        float3 tg = anisotropic ? load3(tangent, f_s) : (float3)(1.0f, 0.0f, 0.0f);
        float3 w_out = wo;
        float3 thr = load3(weight, s) * maxf(dot3(n, wo), 0.0f);
        float3 block = (float3)(0.0f, 0.0f, 0.0f);
        for (int b = 0; b < bounces - 1; ++b) {
            float3 d = cosine_direction(n, path_uniform(seed, j, o, 2 * b), path_uniform(seed, j, o, 2 * b + 1));
            float cd = dot3(n, d);
            float cw = dot3(n, w_out);
            if (dot3(ng, d) <= 0.0f || cd <= 0.0f || cw <= 0.0f)
                break;
            thr = mul3(thr, material_cosine_weighted(kinds[m], params, m, n, tg, d, w_out, tables)) * (M_PI_F / (cd * cw));
            float3 y;
            int fh = trace_periodic_closest(nodes, tris, tri_index, (float3)(x.x + eps * ng.x, x.y + eps * ng.y,
                                            x.z + eps * ng.z), d, x0, y0, px, py, z_lo, z_hi, eps, &y);
            if (fh < 0)
                break;
            float3 ny = load3(face_normals, fh);
            if (dot3(ny, d) >= 0.0f)
                break; /* a face's back: black, as in the single-bounce truth */
            x = y;
            n = ny;
            ng = ny;
            m = face_material[fh];
            if (anisotropic)
                tg = load3(tangent, fh);
            w_out = (float3)(-d.x, -d.y, -d.z);
            thr = mul3(thr, load3(face_color, fh));
            float ci = dot3(n, wi);
            if (ci > 0.0f) {
                float3 unused;
                int light = trace_periodic_closest(nodes, tris, tri_index, (float3)(x.x + eps * n.x,
                                                   x.y + eps * n.y, x.z + eps * n.z), wi, x0, y0, px, py, z_lo,
                                                   z_hi, eps, &unused);
                if (light == IR_ESCAPED) {
                    float3 fo = material_cosine_weighted(kinds[m], params, m, n, tg, wi, w_out, tables);
                    block += mul3(thr, fo) / maxf(dot3(n, w_out), 1.0e-30f);
                }
            }
        }
        ax += (double)block.x;
        ay += (double)block.y;
        az += (double)block.z;
    }
    store3(partial, c * n_pairs + p, (float3)((float)ax, (float)ay, (float)az));
}
