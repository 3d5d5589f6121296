"""Spherical EM (Han 2007, as Iwasaki §4): E-step responsibilities, their sufficient statistics, and the M-step.

Twin of ``cl/em.cl``; the mathematics is ``warp_biscale.reference.ndf_statistics`` / ``ndf_em``. One
thread per facet writes its J responsibilities (times ΔA); then one thread per (chunk of facets,
lobe) sums [r ΔA, r ΔA n] in float64 over 64 facets (on a GPU; on the CPU one chunk, sliced over lobes) and
`sum_chunks_stats` adds groups of chunks, twice, so no atomics are needed and no thread runs a long
serial chain. float64 sums matter here: the sharpness comes from 1 − r̄, r̄ = ‖Σ r ΔA n‖ / Σ r ΔA,
which is ~1e−5 for a sharp lobe. `em_m_step` (one thread per lobe) and `em_finish` (one thread) are
``warp_biscale.lobes.m_step`` and ``converged`` in float64, so the whole EM loop is queued without a
host round trip per step: on a GPU a step with one M-step thread for all lobes and 256-facet chunks
ran several times faster than the E-step with its round trip to a numpy M-step on the host; this
layout: see bench/README.md.
`state` = [done, steps]: once done is set, every kernel of the later steps returns at once.
"""

import warp as wp

from .common import cube_bin

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.kernel
def ndf_responsibilities(
    normal: wp.array(dtype=wp.vec3),
    area: wp.array(dtype=wp.float32),
    axes: wp.array(dtype=wp.vec3),
    sharpness: wp.array(dtype=wp.float32),
    log_weight: wp.array(dtype=wp.float32),
    state: wp.array(dtype=wp.int32),
    offset: int,
    resp: wp.array2d(dtype=wp.float32),
):
    if state[0] != 0:
        return
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
    state: wp.array(dtype=wp.int32),
    offset: int,
    partial: wp.array2d(dtype=wp.vec4d),
):
    if state[0] != 0:
        return
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
def sum_chunks_stats(partial: wp.array2d(dtype=wp.vec4d), chunks_per_group: int, state: wp.array(dtype=wp.int32),
                     offset: int, out: wp.array2d(dtype=wp.vec4d)):
    """out[g, j] = Σ partial[c, j] over the chunks c of group g, in order."""
    if state[0] != 0:
        return
    g, j_local = wp.tid()
    j = j_local + offset
    start = g * chunks_per_group
    stop = wp.min(start + chunks_per_group, partial.shape[0])
    acc = wp.vec4d(wp.float64(0.0))
    for c in range(start, stop):
        acc += partial[c, j]
    out[g, j] = acc


@wp.kernel
def visible_weights(
    directions: wp.array(dtype=wp.vec3),
    bits: wp.array2d(dtype=wp.uint32),
    normal: wp.array(dtype=wp.vec3),
    area: wp.array(dtype=wp.float32),
    offset: int,
    weight: wp.array(dtype=wp.float32),
):
    """EM weight of a facet: ΔA_s · mean_k V_s(ω_k)(n_s·ω_k)⁺, its projected area over the direction
    grid (reference.visible_weights): a facet no grid direction sees weighs nothing."""
    s = wp.tid() + offset
    n = normal[s]
    word = s / 32
    bit = wp.uint32(s % 32)
    acc = float(0.0)
    for k in range(directions.shape[0]):
        if ((bits[k, word] >> bit) & wp.uint32(1)) != wp.uint32(0):
            acc += wp.max(wp.dot(n, directions[k]), 0.0)
    weight[s] = area[s] * acc / float(directions.shape[0])


DEAD_MASS = wp.constant(wp.float64(1.0e-9))  # lobes.DEAD_MASS
TOL = wp.constant(wp.float64(1.0e-4))  # lobes.CONVERGENCE_TOL
SHARPNESS_MIN = wp.constant(wp.float64(1.0e-3))  # sg.SHARPNESS_MIN
SHARPNESS_MAX = wp.constant(wp.float64(1.0e6))  # sg.SHARPNESS_MAX
DEAD_LOG_WEIGHT = wp.constant(-1.0e30)  # a dead lobe's E-step constant: exp(−1e30 − top) = 0


@wp.func
def sharpness_from_mean_resultant(rbar: wp.float64) -> wp.float64:
    """lobes._mean_resultant_to_sharpness: 20 Newton steps on coth κ − 1/κ = r̄ from Banerjee's start
    (stopping once a step leaves κ unchanged: the later ones would too)."""
    one = wp.float64(1.0)
    r = wp.clamp(rbar, wp.float64(1.0e-9), one)
    k = SHARPNESS_MAX
    if r < one - wp.float64(1.0e-12):
        k = r * (wp.float64(3.0) - r * r) / (one - r * r)
        for _it in range(20):
            coth = one
            csch2 = wp.float64(0.0)
            if k <= wp.float64(20.0):  # coth κ = 1 to double precision beyond
                coth = one / wp.tanh(k)
                sh = wp.sinh(k)
                csch2 = one / (sh * sh)
            f = coth - one / k - r
            df = one / (k * k) - csch2
            if df <= wp.float64(0.0):
                df = one
            k_new = wp.max(k - f / df, wp.float64(1.0e-9))
            if k_new == k:
                break
            k = k_new
    return wp.clamp(k, SHARPNESS_MIN, SHARPNESS_MAX)


@wp.kernel
def em_m_step(
    stats: wp.array2d(dtype=wp.vec4d),
    state: wp.array(dtype=wp.int32),
    axes64: wp.array(dtype=wp.vec3d),
    sharpness64: wp.array(dtype=wp.float64),
    weight64: wp.array(dtype=wp.float64),
    offset: int,
    axes: wp.array(dtype=wp.vec3),
    sharpness: wp.array(dtype=wp.float32),
    log_weight: wp.array(dtype=wp.float32),
    moved: wp.array(dtype=wp.int32),
):
    """One thread per lobe: lobes.m_step on the float64 lobes from the E-step sums stats[0, :], the
    float32 copies the E-step reads (log_weight as LobeSet.log_weight), and moved[j] = 1 where
    lobes.converged fails for lobe j (it moved, or died in this step), −1 when no lobe holds area
    (m_step then keeps the lobes and EM stops)."""
    if state[0] != 0:
        return
    j = wp.tid() + offset
    n_lobes = stats.shape[1]
    total = wp.float64(0.0)
    for i in range(n_lobes):
        total += stats[0, i][0]
    kept = wp.float64(0.0)
    for i in range(n_lobes):
        if stats[0, i][0] > DEAD_MASS * total:
            kept += stats[0, i][0]
    if kept <= wp.float64(0.0):
        moved[j] = -1
        return
    m = stats[0, j][0]
    old_axis = axes64[j]
    old_sharp = sharpness64[j]
    old_weight = weight64[j]
    ax = old_axis
    k = old_sharp
    w = wp.float64(0.0)
    flag = int(0)
    if m > DEAD_MASS * total:
        res = wp.vec3d(stats[0, j][1], stats[0, j][2], stats[0, j][3])
        length = wp.length(res)
        if length > wp.float64(0.0):
            ax = res / length
        k = sharpness_from_mean_resultant(length / m)
        w = m / kept
        d = ax - old_axis
        if wp.float64(0.5) * wp.dot(d, d) >= wp.float64(0.5) * TOL * TOL:
            flag = 1
        if wp.abs(wp.log(k / old_sharp)) >= wp.float64(10.0) * TOL:
            flag = 1
        if wp.abs(w - old_weight) >= TOL:
            flag = 1
    elif old_weight > wp.float64(0.0):  # died in this step
        flag = 1
    moved[j] = flag
    axes64[j] = ax
    sharpness64[j] = k
    weight64[j] = w
    axes[j] = wp.vec3(float(ax[0]), float(ax[1]), float(ax[2]))
    sharpness[j] = float(k)
    if w > wp.float64(0.0):
        two_pi = wp.float64(6.283185307179586)
        norm = wp.log(k) - wp.log(two_pi) - wp.log(wp.float64(1.0) - wp.exp(wp.float64(-2.0) * k))
        log_weight[j] = float(wp.log(w) + norm)
    else:
        log_weight[j] = DEAD_LOG_WEIGHT


@wp.kernel
def em_finish(moved: wp.array(dtype=wp.int32), max_steps: int, offset: int, state: wp.array(dtype=wp.int32)):
    """One thread: count the step and stop EM when no lobe moved (lobes.converged) or at `max_steps`."""
    if state[0] != 0:
        return
    any_moved = int(0)
    for j in range(moved.shape[0]):
        if moved[j] < 0:  # no lobe held area: the step did nothing, and EM stops
            state[0] = 1
            return
        if moved[j] != 0:
            any_moved = 1
    state[1] = state[1] + 1
    if any_moved == 0 or state[1] >= max_steps:
        state[0] = 1


@wp.kernel
def em_load(start: wp.array2d(dtype=wp.float64), offset: int,
            axes64: wp.array(dtype=wp.vec3d), sharpness64: wp.array(dtype=wp.float64),
            weight64: wp.array(dtype=wp.float64), axes: wp.array(dtype=wp.vec3),
            sharpness: wp.array(dtype=wp.float32), log_weight: wp.array(dtype=wp.float32),
            state: wp.array(dtype=wp.int32)):
    """One thread per lobe: the starting lobes from one packed upload, start[j] = [ξ (3), η, α,
    log_weight] (LobeSet.log_weight, ≥ −1e30), into the float64 state and its float32 copies; EM's
    `state` is reset. (One upload instead of seven: a host copy costs more than this launch.)"""
    j = wp.tid() + offset
    ax = wp.vec3d(start[j, 0], start[j, 1], start[j, 2])
    axes64[j] = ax
    sharpness64[j] = start[j, 3]
    weight64[j] = start[j, 4]
    axes[j] = wp.vec3(float(ax[0]), float(ax[1]), float(ax[2]))
    sharpness[j] = float(start[j, 3])
    log_weight[j] = float(start[j, 5])
    if j == 0:
        state[0] = 0
        state[1] = 0


@wp.kernel
def em_result(axes64: wp.array(dtype=wp.vec3d), sharpness64: wp.array(dtype=wp.float64),
              weight64: wp.array(dtype=wp.float64), state: wp.array(dtype=wp.int32), offset: int,
              out: wp.array2d(dtype=wp.float64)):
    """One thread per lobe: the fitted lobes and the steps taken packed for one read-back,
    out[j] = [ξ (3), η, α, steps]."""
    j = wp.tid() + offset
    ax = axes64[j]
    out[j, 0] = ax[0]
    out[j, 1] = ax[1]
    out[j, 2] = ax[2]
    out[j, 3] = sharpness64[j]
    out[j, 4] = weight64[j]
    out[j, 5] = wp.float64(state[1])


# ------------------------------------------------------------------ EM's start on the device
# lobes.initial_lobes over the facets (each at its normal, weighing its EM weight, in its cube-map bin at
# START_RES), so that EM can be queued behind the rays without the host reading the weights first. The
# bins' sums are fixed point (round(x·scale) as int64, scale = 2^52 / a bound on Σw) added by integer
# atomics: integer sums do not depend on their order, so the start is the same from run to run, without
# the host sorting the facets by bin. The pick runs in one block, its argmax and sums block reductions.

START_RES = wp.constant(16)  # lobes.initial_lobes' coarse cube map


@wp.kernel
def start_bin_sums(normal: wp.array(dtype=wp.vec3), weight: wp.array(dtype=wp.float32), scale: wp.float64,
                   offset: int, sums: wp.array2d(dtype=wp.int64)):
    """One thread per facet: its coarse bin's [Σw, Σw n] += its own, in fixed point (sums zeroed first)."""
    s = wp.tid() + offset
    w = wp.float64(weight[s])
    if w == wp.float64(0.0):
        return
    n = normal[s]
    b = cube_bin(n, START_RES)
    q = w * scale
    wp.atomic_add(sums, b, 0, wp.int64(wp.round(q)))
    wp.atomic_add(sums, b, 1, wp.int64(wp.round(q * wp.float64(n[0]))))
    wp.atomic_add(sums, b, 2, wp.int64(wp.round(q * wp.float64(n[1]))))
    wp.atomic_add(sums, b, 3, wp.int64(wp.round(q * wp.float64(n[2]))))


BIG_INDEX = wp.constant(2147483647)


@wp.kernel
def start_pick(sums: wp.array2d(dtype=wp.int64), scale: wp.float64, bins: wp.array(dtype=wp.vec4d),
               dist: wp.array(dtype=wp.float64), owner: wp.array(dtype=wp.int32), chosen: wp.array(dtype=wp.int32),
               start: wp.array2d(dtype=wp.float64)):
    """One block (launch_tiled, dim [1]; on the CPU a block of one): lobes.initial_lobes from the bins' sums
    → start (J, 6) rows [ξ (3), η, α, log_weight] (backend.em_start_rows), slots past the distinct bins
    dead (α = 0, log_weight = −1e30). Each thread takes the bins lane, lane + block_dim, …; bins (the
    weight and unit mean normal), dist, owner: scratch per bin, chosen: the picked bins."""
    _block, lane = wp.tid()
    width = wp.block_dim()
    n_bins = sums.shape[0]
    n_lobes = start.shape[0]
    inv = wp.float64(1.0) / scale
    # The bins' weights and unit mean normals; the total and the heaviest bin (the first of equals).
    part = wp.float64(0.0)
    top_w = wp.float64(-1.0)
    top_m = int(BIG_INDEX)
    for m in range(lane, n_bins, width):
        w = wp.float64(sums[m, 0]) * inv
        v = wp.vec3d(wp.float64(sums[m, 1]), wp.float64(sums[m, 2]), wp.float64(sums[m, 3])) * inv
        length = wp.length(v)
        if length > wp.float64(0.0):
            v = v / length
        bins[m] = wp.vec4d(w, v[0], v[1], v[2])
        dist[m] = wp.float64(1.0e300)
        part += w
        if w > top_w:
            top_w = w
            top_m = m
    total = wp.tile_sum(wp.tile(part))[0]
    heaviest_w = wp.tile_max(wp.tile(top_w))[0]
    cand = int(BIG_INDEX)
    if top_w == heaviest_w:
        cand = top_m
    pick = wp.tile_min(wp.tile(cand))[0]
    # Then repeatedly the bin of largest w·(1 − n·ξ) to its nearest chosen axis ξ (numpy's first argmax).
    threshold = wp.float64(1.0e-12) * total
    picked = int(0)
    done = int(0)
    while done == 0:
        chosen[picked] = pick  # (every thread writes the same)
        picked += 1
        a = bins[pick]
        axis = wp.vec3d(a[1], a[2], a[3])
        best_s = wp.float64(-1.0)
        best_m = int(BIG_INDEX)
        for m in range(lane, n_bins, width):
            b = bins[m]
            d = wp.vec3d(b[1], b[2], b[3]) - axis
            e = wp.min(dist[m], wp.float64(0.5) * wp.dot(d, d))
            dist[m] = e
            score = b[0] * e
            if score > best_s:
                best_s = score
                best_m = m
        top = wp.tile_max(wp.tile(best_s))[0]
        cand = int(BIG_INDEX)
        if best_s == top:
            cand = best_m
        pick = wp.tile_min(wp.tile(cand))[0]
        if picked == n_lobes or top <= threshold:
            done = 1
    # Each bin to its nearest chosen axis; then each lobe's weight and mean resultant, one block sum a lobe.
    for m in range(lane, n_bins, width):
        b = bins[m]
        n = wp.vec3d(b[1], b[2], b[3])
        o = int(0)
        top_cos = wp.float64(-2.0)
        for j in range(picked):
            c = bins[chosen[j]]
            cos = wp.dot(wp.vec3d(c[1], c[2], c[3]), n)
            if cos > top_cos:
                top_cos = cos
                o = j
        owner[m] = o
    one = wp.float64(1.0)
    for j in range(n_lobes):
        acc = wp.vec4d(wp.float64(0.0))
        if j < picked:
            for m in range(lane, n_bins, width):
                if owner[m] == j:
                    b = bins[m]
                    acc += wp.vec4d(b[0], b[0] * b[1], b[0] * b[2], b[0] * b[3])
        lobe = wp.tile_sum(wp.tile(acc, preserve_type=True))[0]
        if lane == 0:
            if j < picked and total > wp.float64(0.0):
                c = bins[chosen[j]]
                w = lobe[0]
                r = wp.length(wp.vec3d(lobe[1], lobe[2], lobe[3])) / wp.max(w, wp.float64(1.0e-300))
                r = wp.clamp(r, wp.float64(0.0), one - wp.float64(1.0e-12))
                # Banerjee's κ ≈ r̄(3 − r̄²)/(1 − r̄²): enough for a start (lobes.initial_lobes).
                k = wp.clamp(r * (wp.float64(3.0) - r * r) / (one - r * r), one, wp.float64(1.0e4))
                alpha = w / total
                start[j, 0] = c[1]
                start[j, 1] = c[2]
                start[j, 2] = c[3]
                start[j, 3] = k
                start[j, 4] = alpha
                if alpha > wp.float64(0.0):
                    start[j, 5] = wp.log(alpha) + wp.log(k) - wp.log(wp.float64(6.283185307179586)) - wp.log(
                        one - wp.exp(wp.float64(-2.0) * k))
                else:
                    start[j, 5] = wp.float64(DEAD_LOG_WEIGHT)
            else:  # a dead slot: no distinct bin left for it (or no weight at all)
                start[j, 0] = wp.float64(0.0)
                start[j, 1] = wp.float64(0.0)
                start[j, 2] = wp.float64(1.0)
                start[j, 3] = one
                start[j, 4] = wp.float64(0.0)
                start[j, 5] = wp.float64(DEAD_LOG_WEIGHT)
