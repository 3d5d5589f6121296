"""The BVNDF (Iwasaki §5, Wu Eq. 11): cube-map normal bins and the histogram N over direction pairs.

Twin of ``cl/bvndf.cl``; the mathematics is ``warp_biscale.reference.cube_bin`` and
``reference.bvndf_histogram``. The histogram is a parallel reduction without atomics: the facets
are ordered by bin once (the driver sorts the bin ids), so bin l owns the contiguous range
[bin_start[l], bin_start[l+1]) and one thread per (pair, bin) sums it.
"""

import warp as wp

from .common import cube_bin

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.kernel
def normal_bins(normal: wp.array(dtype=wp.vec3), resolution: int, offset: int, bins: wp.array(dtype=wp.int32)):
    s = wp.tid() + offset
    bins[s] = cube_bin(normal[s], resolution)


@wp.func
def bit(bits: wp.array2d(dtype=wp.uint32), k: int, s: int) -> wp.uint32:
    return (bits[k, s >> 5] >> wp.uint32(s & 31)) & wp.uint32(1)


@wp.kernel
def bvndf_histogram(
    pair_i: wp.array(dtype=wp.int32),
    pair_o: wp.array(dtype=wp.int32),
    bits: wp.array2d(dtype=wp.uint32),
    order: wp.array(dtype=wp.int32),
    bin_start: wp.array(dtype=wp.int32),
    weight: wp.array(dtype=wp.float32),
    offset: int,
    hist: wp.array2d(dtype=wp.float32),
):
    p, l_local = wp.tid()
    l = l_local + offset
    i = pair_i[p]
    o = pair_o[p]
    acc = wp.float64(0.0)
    for k in range(bin_start[l], bin_start[l + 1]):
        s = order[k]
        if (bit(bits, i, s) & bit(bits, o, s)) != wp.uint32(0):
            acc += wp.float64(weight[s])
    hist[p, l] = float(acc)
