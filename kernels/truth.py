"""a_v(ω) and the ground-truth effective BRDF (DESIGN §4), exact small-scale BRDFs.

Twin of ``cl/truth.cl``; the mathematics is ``warp_biscale.reference.visible_area`` and
``reference.effective_brdf``. Both sums over facets are split into chunks of 32-facet words: one
thread per (chunk, pair) writes a partial sum, and a second kernel adds the chunks. Threads of one
chunk and neighbouring pairs read the same facets, so those reads are shared through the cache;
no float atomics are needed (OpenCL devices lack them).
"""

import warp as wp

from .common import brdf_cosine_weighted, lowest_bit


@wp.kernel
def visible_area_partial(
    directions: wp.array(dtype=wp.vec3),
    bits: wp.array2d(dtype=wp.uint32),
    normal: wp.array(dtype=wp.vec3),
    area: wp.array(dtype=wp.float32),
    words_per_chunk: int,
    partial: wp.array2d(dtype=wp.float32),
):
    c, k = wp.tid()
    d = directions[k]
    n_words = bits.shape[1]
    acc = float(0.0)
    w_end = wp.min((c + 1) * words_per_chunk, n_words)
    for w in range(c * words_per_chunk, w_end):
        m = bits[k, w]
        while m != wp.uint32(0):
            b = lowest_bit(m)
            m = m & (m - wp.uint32(1))
            s = w * 32 + b
            acc += wp.max(wp.dot(normal[s], d), 0.0) * area[s]
    partial[c, k] = acc


@wp.kernel
def sum_chunks_area(partial: wp.array2d(dtype=wp.float32), a_v: wp.array(dtype=wp.float32)):
    k = wp.tid()
    acc = float(0.0)
    for c in range(partial.shape[0]):
        acc += partial[c, k]
    a_v[k] = acc


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
    words_per_chunk: int,
    partial: wp.array2d(dtype=wp.vec3),
):
    c, p = wp.tid()
    i = pair_i[p]
    o = pair_o[p]
    wi = directions[i]
    wo = directions[o]
    n_words = bits.shape[1]
    acc = wp.vec3(0.0)
    w_end = wp.min((c + 1) * words_per_chunk, n_words)
    for w in range(c * words_per_chunk, w_end):
        m = bits[i, w] & bits[o, w]
        while m != wp.uint32(0):
            b = lowest_bit(m)
            m = m & (m - wp.uint32(1))
            s = w * 32 + b
            mat = material[s]
            f = brdf_cosine_weighted(kinds[mat], params, mat, normal[s], wi, wo)
            acc += wp.cw_mul(f, weight[s])
    partial[c, p] = acc


@wp.kernel
def sum_chunks_brdf(
    partial: wp.array2d(dtype=wp.vec3),
    pair_o: wp.array(dtype=wp.int32),
    a_v: wp.array(dtype=wp.float32),
    out: wp.array(dtype=wp.vec3),
):
    p = wp.tid()
    acc = wp.vec3(0.0)
    for c in range(partial.shape[0]):
        acc += partial[c, p]
    area = a_v[pair_o[p]]
    if area > 0.0:
        out[p] = acc / area
    else:
        out[p] = wp.vec3(0.0)
