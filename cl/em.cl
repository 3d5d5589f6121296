/* Spherical EM's E-step (Han 2007, as Iwasaki §4): responsibilities and their sufficient statistics.
 *
 * Twin of kernels/em.py; the mathematics is warp_biscale.reference.ndf_statistics. One work-item per
 * facet writes its J responsibilities (times ΔA, float32); then one work-item per (lobe, chunk of
 * facets) sums [r ΔA, r ΔA n] in float64 and a last kernel adds the chunks in order, so no atomics
 * are needed. float64 sums matter here: the sharpness comes from 1 − r̄, r̄ = ‖Σ r ΔA n‖ / Σ r ΔA,
 * which is ~1e−5 for a sharp lobe. Needs cl_khr_fp64.
 *
 * No limit on J here (nothing is held per lobe in private memory). NDRanges: (facets,), then
 * (lobes, chunks), dimension 0 varying fastest as the last dimension of Warp's (chunks, lobes)
 * launch. The statistics travel as double arrays of stride 4 ([r, r·nx, r·ny, r·nz]).
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

/* −η/2·‖ξ − n‖² + log α (= log α − η(1 − ξ·n), exact near ξ = n), in Warp's operation order. */
CL_INLINE float lobe_log(__global const float *axes, __global const float *sharpness,
                         __global const float *log_weight, int j, float3 n)
{
    float3 a = load3(axes, j);
    float3 d = (float3)(a.x - n.x, a.y - n.y, a.z - n.z);
    return log_weight[j] - sharpness[j] * 0.5f * dot3(d, d);
}

__kernel void ndf_responsibilities(
    __global const float *normal,      /* (Ns, 3) */
    __global const float *area,        /* (Ns,) */
    __global const float *axes,        /* (J, 3) */
    __global const float *sharpness,   /* (J,) */
    __global const float *log_weight,  /* (J,) */
    const int n_lobes,
    const int n_facets,
    __global float *resp)              /* (Ns, J) */
{
    int s = get_global_id(0);
    if (s >= n_facets)
        return;
    float3 n = load3(normal, s);
    __global float *r = resp + (size_t)s * n_lobes;
    float top = -1.0e30f;
    for (int j = 0; j < n_lobes; ++j)
        top = maxf(top, lobe_log(axes, sharpness, log_weight, j, n));
    float total = 0.0f;
    for (int j = 0; j < n_lobes; ++j) {
        float e = exp(lobe_log(axes, sharpness, log_weight, j, n) - top);
        r[j] = e;
        total += e;
    }
    float scale = area[s] / total;
    for (int j = 0; j < n_lobes; ++j)
        r[j] = r[j] * scale;
}

__kernel void ndf_sums_partial(
    __global const float *normal,  /* (Ns, 3) */
    __global const float *resp,    /* (Ns, J) */
    const int n_lobes,
    const int n_facets,
    const int facets_per_chunk,
    __global double *partial)      /* (chunks, J, 4) */
{
    int j = get_global_id(0);
    int c = get_global_id(1);
    if (j >= n_lobes)
        return;
    int start = c * facets_per_chunk;
    int stop = start + facets_per_chunk < n_facets ? start + facets_per_chunk : n_facets;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    for (int s = start; s < stop; ++s) {
        double r = (double)resp[(size_t)s * n_lobes + j];
        float3 n = load3(normal, s);
        a0 += r;
        a1 += r * (double)n.x;
        a2 += r * (double)n.y;
        a3 += r * (double)n.z;
    }
    __global double *out = partial + 4 * ((size_t)c * n_lobes + j);
    out[0] = a0;
    out[1] = a1;
    out[2] = a2;
    out[3] = a3;
}

__kernel void sum_chunks_stats(__global const double *partial, const int chunks, const int n_lobes,
                               __global double *out)  /* (J, 4) */
{
    int j = get_global_id(0);
    if (j >= n_lobes)
        return;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    for (int c = 0; c < chunks; ++c) {
        __global const double *x = partial + 4 * ((size_t)c * n_lobes + j);
        a0 += x[0];
        a1 += x[1];
        a2 += x[2];
        a3 += x[3];
    }
    out[4 * j] = a0;
    out[4 * j + 1] = a1;
    out[4 * j + 2] = a2;
    out[4 * j + 3] = a3;
}
