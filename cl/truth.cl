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
            float3 f = kind >= ANISOTROPIC_WARD
                           ? brdf_cosine_weighted_tangent(kind, params, mat, n, load3(tangent, face[s]), wi, wo)
                           : brdf_cosine_weighted(kind, params, mat, n, wi, wo);
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
