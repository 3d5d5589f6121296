"""The BVNDF (Iwasaki §5, Wu Eq. 11): cube-map normal bins and the histogram N over direction pairs.

Twin of ``cl/bvndf.cl``; the mathematics is ``warp_biscale.reference.cube_bin`` and
``reference.bvndf_histogram``; the bins' sums, ``reference.normal_bin_sums``. The histogram is a parallel reduction without atomics: the facets
are ordered by bin once (the driver sorts the bin ids), so bin l owns the contiguous range
[bin_start[l], bin_start[l+1]) and one thread per (pair, bin) sums it.
"""

import warp as wp

from .common import cube_bin


@wp.kernel
def normal_bins(normal: wp.array(dtype=wp.vec3), resolution: int, offset: int, bins: wp.array(dtype=wp.int32)):
    s = wp.tid() + offset
    bins[s] = cube_bin(normal[s], resolution)


@wp.kernel
def normal_bin_sums(normal: wp.array(dtype=wp.vec3), area: wp.array(dtype=wp.float32),
                    weight: wp.array(dtype=wp.float32), resolution: int, slot: wp.array(dtype=wp.int32),
                    scale: wp.float64, offset: int, sums: wp.array2d(dtype=wp.int64)):
    """One thread per facet: the row of its normal bin (`slot`, −1: none) [ΣΔA, ΣΔA·n, Σw] += its own, in fixed
    point round(x·scale) (sums zeroed first): integer sums do not depend on their order, so the bins are the
    same from run to run (reference.normal_bin_sums). Launched whole on the CPU, where atomic_add is a plain add."""
    s = wp.tid() + offset
    n = normal[s]
    k = slot[cube_bin(n, resolution)]
    if k < 0:
        return
    a = wp.float64(area[s]) * scale
    wp.atomic_add(sums, k, 0, wp.int64(wp.round(a)))
    wp.atomic_add(sums, k, 1, wp.int64(wp.round(a * wp.float64(n[0]))))
    wp.atomic_add(sums, k, 2, wp.int64(wp.round(a * wp.float64(n[1]))))
    wp.atomic_add(sums, k, 3, wp.int64(wp.round(a * wp.float64(n[2]))))
    wp.atomic_add(sums, k, 4, wp.int64(wp.round(wp.float64(weight[s]) * scale)))


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
