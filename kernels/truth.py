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

from .common import ANISOTROPIC_WARD, ASHIKHMIN_SHIRLEY, cell_exits, lowest_bit, material_cosine_weighted, next_cell

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


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
    tables: wp.array(dtype=wp.float32),
    words_per_chunk: int,
    offset: int,
    partial: wp.array2d(dtype=wp.vec3),
):
    # face, tangent: each facet's face and the tile's per-face tangents, read only for the anisotropic kinds,
    # so an isotropic material costs two comparisons more per facet. tables: the measured BRDFs' tables
    # (MeasuredBRDF.kernel_table, one a slot), read only for the measured kind.
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
            tg = wp.vec3(1.0, 0.0, 0.0)
            if kind == ANISOTROPIC_WARD or kind == ASHIKHMIN_SHIRLEY:
                tg = tangent[face[s]]
            f = material_cosine_weighted(kind, params, mat, normal[s], tg, wi, wo, tables)
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


# ---------------------------------------------------------------------------------------------------
# Small-scale interreflection (docs/design.md §4.6): the bounces 2..B of wb.ground_truth(bounces=B).
# Mathematics and estimator: warp_biscale.reference.interreflection (float64, the same random numbers).
# ---------------------------------------------------------------------------------------------------

PI = wp.constant(3.14159265358979)
ESCAPED = wp.constant(-1)  # trace_periodic_closest: the ray left above the tile
LOST = wp.constant(-2)  # ... below it, or ran out of cells (absorbed: the estimator only loses energy)
MAX_CELLS = wp.constant(64)  # tile cells one ray may cross (reference.INTERREFLECTION_MAX_CELLS)


PCG_INCREMENT = wp.constant(wp.uint32(2891336453))


@wp.func
def pcg_hash(v: wp.uint32) -> wp.uint32:
    """PCG-RXS-M-XS (Jarzynski & Olano 2020), in uint32 (reference.pcg_hash)."""
    state = v * wp.uint32(747796405) + PCG_INCREMENT
    word = ((state >> ((state >> wp.uint32(28)) + wp.uint32(4))) ^ state) * wp.uint32(277803737)
    return (word >> wp.uint32(22)) ^ word


@wp.func
def path_uniform(seed: int, path: int, o: int, dim: int) -> float:
    """A uniform number in [0, 1) with 24 bits, a hash of (seed, path, ωo, dimension): exact in float32,
    the same in cl/truth.cl and reference.path_uniform."""
    h = pcg_hash(wp.uint32(seed))
    h = pcg_hash(h + wp.uint32(path))
    h = pcg_hash(h + wp.uint32(o))
    h = pcg_hash(h + wp.uint32(dim))
    return float(int(h >> wp.uint32(8))) * (1.0 / 16777216.0)


@wp.func
def cosine_direction(n: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """A cosine-distributed direction about unit n (frame of reference.cosine_direction)."""
    ref = wp.vec3(0.0, 1.0, 0.0)
    if wp.abs(n[0]) < 0.9:
        ref = wp.vec3(1.0, 0.0, 0.0)
    a = wp.normalize(wp.cross(n, ref))
    b = wp.cross(n, a)
    r = wp.sqrt(u1)
    phi = 2.0 * PI * u2
    return wp.normalize(r * wp.cos(phi) * a + r * wp.sin(phi) * b + wp.sqrt(wp.max(1.0 - u1, 0.0)) * n)


@wp.func
def trace_periodic_closest(mesh: wp.uint64, start: wp.vec3, d: wp.vec3,
                           x0: float, y0: float, px: float, py: float, z_lo: float, z_hi: float,
                           eps: float) -> wp.vec4:
    """The first hit of the ray through the infinitely tiled surface: (x, y, z, face) with the position in
    the tile's base cell, or face ESCAPED / LOST. Cell by cell as trace_periodic (kernels/visibility.py),
    also downward; each cell's segment is tested over (-back, t_exit + eps]."""
    o = start
    back = float(0.0)
    for _step in range(MAX_CELLS):
        t_z = float(1.0e30)
        if d[2] > 0.0:
            t_z = (z_hi + eps - o[2]) / d[2]
        elif d[2] < 0.0:
            t_z = (z_lo - eps - o[2]) / d[2]
        exits = cell_exits(o, d, x0, y0, px, py)
        t_side = wp.min(exits[0], exits[1])
        t_exit = wp.min(t_z, t_side)
        q = wp.mesh_query_ray(mesh, o - back * d, d, t_exit + eps + back)
        if q.result:
            p = o + (q.t - back) * d
            return wp.vec4(p[0], p[1], p[2], float(q.face))
        if t_z <= t_side:
            if d[2] > 0.0:
                return wp.vec4(0.0, 0.0, 0.0, float(ESCAPED))
            return wp.vec4(0.0, 0.0, 0.0, float(LOST))
        o = next_cell(o, d, t_exit, exits, px, py)
        back = eps
    return wp.vec4(0.0, 0.0, 0.0, float(LOST))


@wp.kernel
def interreflection_partial(
    mesh: wp.uint64,
    face_normals: wp.array(dtype=wp.vec3),
    face_material: wp.array(dtype=wp.int32),
    face_color: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    pair_i: wp.array(dtype=wp.int32),
    pair_o: wp.array(dtype=wp.int32),
    bits: wp.array2d(dtype=wp.uint32),
    position: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=wp.vec3),
    material: wp.array(dtype=wp.int32),
    face: wp.array(dtype=wp.int32),
    kinds: wp.array(dtype=wp.int32),
    params: wp.array2d(dtype=wp.float32),
    tangent: wp.array(dtype=wp.vec3),
    tables: wp.array(dtype=wp.float32),
    anisotropic: int,
    n_facets: int,
    paths: int,
    paths_per_chunk: int,
    bounces: int,
    seed: int,
    x0: float, y0: float, px: float, py: float, z_lo: float, z_hi: float, eps: float,
    offset: int,
    partial: wp.array2d(dtype=wp.vec3),
):
    """Σ over the chunk's paths j of the bounces 2..`bounces` reaching facet s(j) = ⌊(j + ½)Ns/paths⌋ from ωi
    and leaving it towards ωo (reference.interreflection), unnormalised (sum_chunks_brdf divides by a_v and
    the driver by paths/Ns). `tangent` is per face, read only where `anisotropic`; `tables` the measured
    BRDFs' tables, read only for the measured kind."""
    c, p_local = wp.tid()
    p = p_local + offset
    i = pair_i[p]
    o = pair_o[p]
    wi = directions[i]
    wo = directions[o]
    acc = wp.vec3d(0.0)
    j_start = c * paths_per_chunk
    j_end = wp.min(j_start + paths_per_chunk, paths)
    for j in range(j_start, j_end):
        s = int((float(j) + 0.5) * float(n_facets) / float(paths))
        s = wp.min(s, n_facets - 1)
        if ((bits[o, s >> 5] >> wp.uint32(s & 31)) & wp.uint32(1)) != wp.uint32(0):
            x = position[s]
            f_s = face[s]
            n = normal[s]
            ng = face_normals[f_s]
            m = material[s]
            tg = wp.vec3(1.0, 0.0, 0.0)
            if anisotropic != 0:
                tg = tangent[f_s]
            w_out = wo
            thr = weight[s] * wp.max(wp.dot(n, wo), 0.0)
            block = wp.vec3(0.0)
            for b in range(bounces - 1):
                d = cosine_direction(n, path_uniform(seed, j, o, 2 * b), path_uniform(seed, j, o, 2 * b + 1))
                cd = wp.dot(n, d)
                cw = wp.dot(n, w_out)
                if wp.dot(ng, d) <= 0.0 or cd <= 0.0 or cw <= 0.0:
                    break
                # cosine sampling: f(x, d, w_out)(n·d)/pdf = π f, and f = brdf_cosine_weighted/((n·d)(n·w_out))
                f_d = material_cosine_weighted(kinds[m], params, m, n, tg, d, w_out, tables)
                thr = wp.cw_mul(thr, f_d) * (PI / (cd * cw))
                hit = trace_periodic_closest(mesh, x + eps * ng, d, x0, y0, px, py, z_lo, z_hi, eps)
                fh = int(hit[3])
                if fh < 0:
                    break
                ny = face_normals[fh]
                if wp.dot(ny, d) >= 0.0:
                    break  # a face's back: black, as in the single-bounce truth
                x = wp.vec3(hit[0], hit[1], hit[2])
                n = ny
                ng = ny
                m = face_material[fh]
                if anisotropic != 0:
                    tg = tangent[fh]
                w_out = -d
                thr = wp.cw_mul(thr, face_color[fh])
                # next-event estimation towards the (directional) light ωi
                ci = wp.dot(n, wi)
                if ci > 0.0:
                    light = trace_periodic_closest(mesh, x + eps * n, wi, x0, y0, px, py, z_lo, z_hi, eps)
                    if int(light[3]) == ESCAPED:
                        fo = material_cosine_weighted(kinds[m], params, m, n, tg, wi, w_out, tables)
                        block += wp.cw_mul(thr, fo) / wp.max(wp.dot(n, w_out), 1.0e-30)
            acc += wp.vec3d(block)
    partial[c, p] = wp.vec3(acc)
