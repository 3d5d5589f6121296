"""Spherical EM's E-step (Han 2007, as Iwasaki §4): responsibilities and their sufficient statistics.

Twin of ``cl/em.cl``; the mathematics is ``warp_biscale.reference.ndf_statistics``. One thread per
facet writes its J responsibilities (times ΔA); then one thread per (chunk of facets, lobe) sums
[r ΔA, r ΔA n] in float64 and a last kernel adds the chunks, so no atomics are needed. float64 sums
matter here: the sharpness comes from 1 − r̄, r̄ = ‖Σ r ΔA n‖ / Σ r ΔA, which is ~1e−5 for a sharp lobe.
The M-step (a handful of numbers) runs on the host (``warp_biscale.lobes.m_step``).
"""

import warp as wp


@wp.kernel
def ndf_responsibilities(
    normal: wp.array(dtype=wp.vec3),
    area: wp.array(dtype=wp.float32),
    axes: wp.array(dtype=wp.vec3),
    sharpness: wp.array(dtype=wp.float32),
    log_weight: wp.array(dtype=wp.float32),
    offset: int,
    resp: wp.array2d(dtype=wp.float32),
):
    s = wp.tid() + offset
    n = normal[s]
    n_lobes = axes.shape[0]
    top = float(-1.0e30)
    for j in range(n_lobes):
        d = axes[j] - n
        top = wp.max(top, log_weight[j] - sharpness[j] * 0.5 * wp.dot(d, d))
    total = float(0.0)
    for j in range(n_lobes):
        d = axes[j] - n
        e = wp.exp(log_weight[j] - sharpness[j] * 0.5 * wp.dot(d, d) - top)
        resp[s, j] = e
        total += e
    scale = area[s] / total
    for j in range(n_lobes):
        resp[s, j] = resp[s, j] * scale


@wp.kernel
def ndf_sums_partial(
    normal: wp.array(dtype=wp.vec3),
    resp: wp.array2d(dtype=wp.float32),
    facets_per_chunk: int,
    offset: int,
    partial: wp.array2d(dtype=wp.vec4d),
):
    c, j_local = wp.tid()
    j = j_local + offset
    n_facets = normal.shape[0]
    start = c * facets_per_chunk
    stop = wp.min(start + facets_per_chunk, n_facets)
    acc = wp.vec4d(wp.float64(0.0))
    for s in range(start, stop):
        r = wp.float64(resp[s, j])
        n = wp.vec3d(normal[s])
        acc += wp.vec4d(r, r * n[0], r * n[1], r * n[2])
    partial[c, j] = acc


@wp.kernel
def sum_chunks_stats(partial: wp.array2d(dtype=wp.vec4d), out: wp.array(dtype=wp.vec4d)):
    j = wp.tid()
    acc = wp.vec4d(wp.float64(0.0))
    for c in range(partial.shape[0]):
        acc += partial[c, j]
    out[j] = acc
