/* a_v(w) and the ground-truth effective BRDF (DESIGN §4), exact small-scale BRDFs.
 *
 * Twin of kernels/truth.py; the mathematics is warp_biscale.reference.visible_area and
 * reference.effective_brdf. Both sums over facets are split into chunks of 32-facet words: one
 * work-item per (chunk c, output) writes partial[c, output], and a second kernel adds the chunks
 * in order. No atomics (OpenCL has no float atomics). NDRanges are (outputs, chunks): dimension 0
 * varies fastest, matching the linear order of Warp's (chunks, outputs) launch. 3-vectors are
 * float arrays of stride 3.
 */

__kernel void visible_area_partial(
    __global const float *directions,  /* (D, 3) */
    __global const uint *bits,         /* (D, words) */
    const int n_words,
    __global const float *normal,      /* (Ns, 3) */
    __global const float *area,        /* (Ns,) */
    const int words_per_chunk,
    __global float *partial)           /* (chunks, D) */
{
    int k = get_global_id(0);
    int c = get_global_id(1);
    int n_dirs = get_global_size(0);
    float3 d = vload3(k, directions);
    float acc = 0.0f;
    int w_end = min((c + 1) * words_per_chunk, n_words);
    for (int w = c * words_per_chunk; w < w_end; ++w) {
        uint m = bits[k * n_words + w];
        while (m != 0u) {
            int b = lowest_bit(m);
            m = m & (m - 1u);
            int s = w * 32 + b;
            acc += fmax(dot3(vload3(s, normal), d), 0.0f) * area[s];
        }
    }
    partial[c * n_dirs + k] = acc;
}

__kernel void sum_chunks_area(__global const float *partial, const int chunks, __global float *a_v)
{
    int k = get_global_id(0);
    int n_dirs = get_global_size(0);
    float acc = 0.0f;
    for (int c = 0; c < chunks; ++c)
        acc += partial[c * n_dirs + k];
    a_v[k] = acc;
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
    const int words_per_chunk,
    __global float *partial)           /* (chunks, P, 3) */
{
    int p = get_global_id(0);
    int c = get_global_id(1);
    int n_pairs = get_global_size(0);
    int i = pair_i[p];
    int o = pair_o[p];
    float3 wi = vload3(i, directions);
    float3 wo = vload3(o, directions);
    float3 acc = (float3)(0.0f, 0.0f, 0.0f);
    int w_end = min((c + 1) * words_per_chunk, n_words);
    for (int w = c * words_per_chunk; w < w_end; ++w) {
        uint m = bits[i * n_words + w] & bits[o * n_words + w];
        while (m != 0u) {
            int b = lowest_bit(m);
            m = m & (m - 1u);
            int s = w * 32 + b;
            int mat = material[s];
            float3 f = brdf_cosine_weighted(kinds[mat], params, mat, vload3(s, normal), wi, wo);
            float3 wt = vload3(s, weight);
            acc = (float3)(acc.x + f.x * wt.x, acc.y + f.y * wt.y, acc.z + f.z * wt.z);
        }
    }
    vstore3(acc, c * n_pairs + p, partial);
}

__kernel void sum_chunks_brdf(
    __global const float *partial,     /* (chunks, P, 3) */
    const int chunks,
    __global const int *pair_o,        /* (P,) */
    __global const float *a_v,         /* (D,) */
    __global float *out)               /* (P, 3) */
{
    int p = get_global_id(0);
    int n_pairs = get_global_size(0);
    float3 acc = (float3)(0.0f, 0.0f, 0.0f);
    for (int c = 0; c < chunks; ++c) {
        float3 x = vload3(c * n_pairs + p, partial);
        acc = (float3)(acc.x + x.x, acc.y + x.y, acc.z + x.z);
    }
    float area = a_v[pair_o[p]];
    if (area > 0.0f)
        vstore3((float3)(acc.x / area, acc.y / area, acc.z / area), p, out);
    else
        vstore3((float3)(0.0f, 0.0f, 0.0f), p, out);
}
