/* The BVNDF (Iwasaki §5, Wu Eq. 11): cube-map normal bins and the histogram N over direction pairs.
 *
 * Twin of kernels/bvndf.py; the mathematics is warp_biscale.reference.cube_bin and
 * reference.bvndf_histogram. The histogram is a parallel reduction without atomics: the facets are
 * ordered by bin once (the driver sorts the bin ids), so bin l owns the contiguous range
 * [bin_start[l], bin_start[l+1]) of `order` and one work-item per (bin, pair) sums it in float64.
 *
 * NDRanges: (facets,) for the bins; (bins, pairs) for the histogram, dimension 0 varying fastest as
 * the last dimension of Warp's (pairs, bins) launch. Rounded up to a whole work-group; the surplus
 * work-items return. 3-vectors are float arrays of stride 3.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

__kernel void normal_bins(
    __global const float *normal,  /* (Ns, 3) */
    const int resolution,
    const int n_facets,
    __global int *bins)            /* (Ns,) */
{
    int s = get_global_id(0);
    if (s >= n_facets)
        return;
    bins[s] = cube_bin(load3(normal, s), resolution);
}

__kernel void bvndf_histogram(
    __global const int *pair_i,     /* (P,) */
    __global const int *pair_o,     /* (P,) */
    __global const uint *bits,      /* (D, words) */
    const int n_words,
    __global const int *order,      /* (Ns,) facets sorted by bin */
    __global const int *bin_start,  /* (L + 1,) */
    __global const float *weight,   /* (Ns,) */
    const int n_bins,
    const int n_pairs,
    __global float *hist)           /* (P, L) */
{
    int l = get_global_id(0);
    int p = get_global_id(1);
    if (l >= n_bins || p >= n_pairs)
        return;
    __global const uint *bi = bits + (size_t)pair_i[p] * n_words;
    __global const uint *bo = bits + (size_t)pair_o[p] * n_words;
    double acc = 0.0;
    int stop = bin_start[l + 1];
    for (int k = bin_start[l]; k < stop; ++k) {
        int s = order[k];
        if (((bi[s >> 5] & bo[s >> 5]) >> (uint)(s & 31)) & 1u)
            acc += (double)weight[s];
    }
    hist[(size_t)p * n_bins + l] = (float)acc;
}
