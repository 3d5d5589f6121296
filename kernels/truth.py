"""a_v(ω) and the ground-truth effective BRDF (docs/design.md §4), exact small-scale BRDFs.

Twin of ``cl/truth.cl``; the mathematics is ``warp_biscale.reference.visible_area`` and
``reference.effective_brdf``. Both sums over facets are split into chunks of 32-facet words: one
thread per (chunk, pair) writes a partial sum, and a second kernel adds the chunks. Threads of one
chunk and neighbouring pairs read the same facets, so those reads are shared through the cache;
no float atomics are needed (OpenCL devices lack them).

Summation: a float32 running sum of n similar terms loses up to ~n·ε/2 (measured: 0.3 % at 2¹⁸
facets on one CPU thread, 3e-5 with 2048-facet float32 blocks), so each thread sums one 32-facet
word in float32 and adds it into a float64 accumulator; chunk sums are added in float64 too. That
is one float64 add per word of up to 32 BRDF evaluations.
"""

import warp as wp

from .common import ANISOTROPIC_WARD, brdf_cosine_weighted, brdf_cosine_weighted_tangent, lowest_bit


@wp.kernel
def visible_area_partial(
    directions: wp.array(dtype=wp.vec3),
    bits: wp.array2d(dtype=wp.uint32),
    normal: wp.array(dtype=wp.vec3),
    area: wp.array(dtype=wp.float32),
    words_per_chunk: int,
    offset: int,
    partial: wp.array2d(dtype=wp.float32),
):
    c, k_local = wp.tid()
    k = k_local + offset
    d = directions[k]
    n_words = bits.shape[1]
    acc = wp.float64(0.0)
    w_start = c * words_per_chunk
    w_end = wp.min(w_start + words_per_chunk, n_words)
    for w in range(w_start, w_end):
        m = bits[k, w]
        block = float(0.0)
        while m != wp.uint32(0):
            b = lowest_bit(m)
            m = m & (m - wp.uint32(1))
            s = w * 32 + b
            block += wp.max(wp.dot(normal[s], d), 0.0) * area[s]
        acc += wp.float64(block)
    partial[c, k] = float(acc)


@wp.kernel
def sum_chunks_area(partial: wp.array2d(dtype=wp.float32), a_v: wp.array(dtype=wp.float32)):
    k = wp.tid()
    acc = wp.float64(0.0)
    for c in range(partial.shape[0]):
        acc += wp.float64(partial[c, k])
    a_v[k] = float(acc)


@wp.kernel
def effective_brdf_partial(
    directions: wp.array(dtype=wp.vec3),
    pair_i: wp.array(dtype=wp.int32),
    pair_o: wp.array(dtype=wp.int32),
    bits: wp.array2d(dtype=wp.uint32),
    normal: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=wp.vec3),
    material: wp.array(dtype=wp.int32),
    kinds: wp.array(dtype=wp.int32),
    params: wp.array2d(dtype=wp.float32),
    face: wp.array(dtype=wp.int32),
    tangent: wp.array(dtype=wp.vec3),
    words_per_chunk: int,
    offset: int,
    partial: wp.array2d(dtype=wp.vec3),
):
    # face, tangent: each facet's face and the tile's per-face tangents, read only for the anisotropic kinds
    # (kind >= ANISOTROPIC_WARD), so an isotropic material costs one comparison more per facet.
    c, p_local = wp.tid()
    p = p_local + offset
    i = pair_i[p]
    o = pair_o[p]
    wi = directions[i]
    wo = directions[o]
    n_words = bits.shape[1]
    acc = wp.vec3d(0.0)
    w_start = c * words_per_chunk
    w_end = wp.min(w_start + words_per_chunk, n_words)
    for w in range(w_start, w_end):
        m = bits[i, w] & bits[o, w]
        block = wp.vec3(0.0)
        while m != wp.uint32(0):
            b = lowest_bit(m)
            m = m & (m - wp.uint32(1))
            s = w * 32 + b
            mat = material[s]
            kind = kinds[mat]
            f = wp.vec3(0.0)
            if kind >= ANISOTROPIC_WARD:
                f = brdf_cosine_weighted_tangent(kind, params, mat, normal[s], tangent[face[s]], wi, wo)
            else:
                f = brdf_cosine_weighted(kind, params, mat, normal[s], wi, wo)
            block += wp.cw_mul(f, weight[s])
        acc += wp.vec3d(block)
    partial[c, p] = wp.vec3(acc)


@wp.kernel
def sum_chunks_brdf(
    partial: wp.array2d(dtype=wp.vec3),
    pair_o: wp.array(dtype=wp.int32),
    a_v: wp.array(dtype=wp.float32),
    out: wp.array(dtype=wp.vec3),
):
    p = wp.tid()
    acc = wp.vec3d(0.0)
    for c in range(partial.shape[0]):
        acc += wp.vec3d(partial[c, p])
    area = a_v[pair_o[p]]
    if area > 0.0:
        out[p] = wp.vec3(acc / wp.float64(area))
    else:
        out[p] = wp.vec3(0.0)
