"""Gram amplitudes (Iwasaki §4, docs/design.md §5): the lobe moments b, c of every direction pair and the solve.

Twin of ``cl/amplitudes.cl``; the mathematics is ``warp_biscale.reference.lobe_values``,
``lobe_moments``, ``histogram_moments`` and ``solve_amplitudes``.

Facet route: b_kj·a_v(ωo) = Σ_s P_si P_so w_s G_j(n_s) with P_sk = V_s(ω_k)(n_s·ω_k)⁺ is the J weighted
Gram products PᵀW_jP. It is symmetric in (i, o), so only the unordered pairs i ≤ o are summed: one
thread per (chunk of facet words, unordered pair) walks the set bits of V(ωi) ∧ V(ωo) ∧ channel and
keeps J + 1 accumulators (J lobes and the plain sum c) in registers; G_j(n_s) is tabulated once per
facet (`lobe_values`) as an 8- or 16-vector, zero beyond J, so the hot loop adds whole vectors. Summation
as in the ground truth: float32 within a 32-facet word, float64 across words and chunks.

Histogram route: the same sums over the L non-empty normal bins, each taken at its mean normal.

ASG lobes (the ASG bake): ``asg_lobe_values`` tabulates G_j(n_s) of ASG rows in ``lobe_values``' place, and
``asg_value_sums`` gives Σ_s w_s G_j(n_s); both call kernels/asg.py's ``asg_eval``.

Solve: one thread per ordered pair (i, o) reads the unordered pair's moments, divides by a_v(ωo),
applies the J×J solve rows (float64: A⁻¹ of close lobes has large entries of both signs), clamps
negative amplitudes and rescales to the exact energy c, as the reference does.

Tables: one thread per ordered pair adds a channel's amplitudes times its colour into its material's
(P, J, 3) table and their energy Σ_j μ_j ∫G_j into (P, 3), on the device: the same numpy on the host
cost more than the read-back (strided writes into the RGB-last table; bench/README.md). Then one thread
per (material, level, pair) prefilters the energy over ωi for the renderer's broad environment lobes
(`effective.broad_levels`' product, on the device beside the energy it reads).
"""

import warp as wp

from .asg import asg_eval, asg_load
from .common import lowest_bit

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

MAX_LOBES = 16
vec16 = wp.types.vector(length=MAX_LOBES, dtype=wp.float32)
vec16d = wp.types.vector(length=MAX_LOBES, dtype=wp.float64)


@wp.kernel
def facet_runs(
    normal: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=wp.float32),
    offset: int,
    channel_bits: wp.array(dtype=wp.uint32),
    run_end: wp.array(dtype=wp.int32),
):
    """One thread per 32-facet word (model.run_ends): bit b of channel_bits[w] is weight > 0, and
    run_end[s] is one past the run of facets sharing s's normal and weight, cut at the word's end
    (all the moment kernels need), found walking the word backwards."""
    w = wp.tid() + offset
    n = normal.shape[0]
    start = w * 32
    stop = wp.min(start + 32, n)
    end = stop
    mask = wp.uint32(0)
    for i in range(stop - start):
        s = stop - 1 - i
        if s + 1 < stop:
            a = normal[s]
            b = normal[s + 1]
            if a[0] != b[0] or a[1] != b[1] or a[2] != b[2] or weight[s] != weight[s + 1]:
                end = s + 1
        run_end[s] = end
        if weight[s] > 0.0:
            mask = mask | (wp.uint32(1) << wp.uint32(s - start))
    channel_bits[w] = mask


def _facet_kernels(lanes: int):
    """`lobe_values` and `lobe_moments_partial` on `lanes`-vectors (8 for J ≤ 8, else 16; the OpenCL
    twin reads float8 blocks likewise): the hot loop adds whole vectors, and at J ≤ 8 half the lanes
    halve its loads and adds (pyramid, 2^14 facets, K = 12, J = 5, Warp CPU: see bench/README.md)."""
    vec = wp.types.vector(length=lanes, dtype=wp.float32)
    vecd = wp.types.vector(length=lanes, dtype=wp.float64)

    @wp.kernel(module="unique")
    def lobe_values(
        normal: wp.array(dtype=wp.vec3),
        axes: wp.array(dtype=wp.vec3),
        sharpness: wp.array(dtype=wp.float32),
        offset: int,
        values: wp.array(dtype=vec),
    ):
        s = wp.tid() + offset
        n = normal[s]
        v = vec()  # lobes beyond J stay 0
        for j in range(axes.shape[0]):
            d = axes[j] - n
            e = wp.exp(-sharpness[j] * 0.5 * wp.dot(d, d))  # 1 − ξ·n as ‖ξ − n‖²/2: exact near ξ = n
            v[j] = wp.where(e < 1.0e-30, 0.0, e)  # no denormals: their products cost ~3x on a CPU
        values[s] = v

    @wp.kernel(module="unique")
    def asg_lobe_values(
        normal: wp.array(dtype=wp.vec3),
        rows: wp.array2d(dtype=wp.float32),
        offset: int,
        values: wp.array(dtype=vec),
    ):
        """The ASG bake's lobes in lobe_values' place: G_j(n_s) of ASG rows (J, 12) (kernels/asg.py)."""
        s = wp.tid() + offset
        n = normal[s]
        v = vec()
        for j in range(rows.shape[0]):
            e = asg_eval(asg_load(rows, j), n)
            v[j] = wp.where(e < 1.0e-30, 0.0, e)
        values[s] = v

    @wp.kernel(module="unique")
    def lobe_moments_partial(
        directions: wp.array(dtype=wp.vec3),
        pair_i: wp.array(dtype=wp.int32),
        pair_o: wp.array(dtype=wp.int32),
        bits: wp.array2d(dtype=wp.uint32),
        channel_bits: wp.array(dtype=wp.uint32),
        weight: wp.array(dtype=wp.float32),
        normal: wp.array(dtype=wp.vec3),
        values: wp.array(dtype=vec),
        run_end: wp.array(dtype=wp.int32),
        n_lobes: int,
        words_per_chunk: int,
        offset: int,
        partial: wp.array3d(dtype=wp.float32),
    ):
        c, u_local = wp.tid()
        u = u_local + offset
        i = pair_i[u]
        o = pair_o[u]
        wi = directions[i]
        wo = directions[o]
        n_words = bits.shape[1]
        acc = vecd()
        acc_c = wp.float64(0.0)
        w_start = c * words_per_chunk
        w_end = wp.min(w_start + words_per_chunk, n_words)
        for w in range(w_start, w_end):
            m = bits[i, w] & bits[o, w] & channel_bits[w]
            if m == wp.uint32(0):
                continue
            block = vec()
            block_c = float(0.0)
            while m != wp.uint32(0):
                b = lowest_bit(m)
                s = w * 32 + b
                # The visible facets of s's run in this word (same normal, weight, lobe values): one count.
                end = run_end[s] - w * 32
                seg = m
                if end < 32:
                    seg = m & ((wp.uint32(1) << wp.uint32(end)) - wp.uint32(1))
                m = m & ~seg
                n = normal[s]
                p = wp.max(wp.dot(n, wi), 0.0) * wp.max(wp.dot(n, wo), 0.0) * weight[s] * float(wp.bit_count(seg))
                block_c += p
                block += p * values[s]  # all lanes at once: no per-lobe indexing in the hot loop
            acc_c += wp.float64(block_c)
            acc += vecd(block)
        for j in range(n_lobes):
            partial[c, u, j] = float(acc[j])
        partial[c, u, n_lobes] = float(acc_c)

    return vec, lobe_values, lobe_moments_partial, asg_lobe_values


# lanes → (vec, lobe_values, moments, asg_lobe_values)
FACET_KERNELS = {lanes: _facet_kernels(lanes) for lanes in (8, MAX_LOBES)}
lobe_values = FACET_KERNELS[MAX_LOBES][1]  # histogram route: bin values as 16-vectors


def facet_kernels(n_lobes: int):
    """(vec type, lobe_values, lobe_moments_partial, asg_lobe_values) with the fewest lanes holding `n_lobes`."""
    return FACET_KERNELS[8 if n_lobes <= 8 else MAX_LOBES]


@wp.kernel
def asg_value_sums(
    normal: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=wp.float32),
    rows: wp.array2d(dtype=wp.float32),
    facets_per_chunk: int,
    offset: int,
    partial: wp.array2d(dtype=wp.float64),
):
    """partial[c, j] = Σ_s w_s G_j(n_s) over chunk c's facets, float64 (the ASG bake's calibration sums;
    the host adds the chunks)."""
    c = wp.tid() + offset
    start = c * facets_per_chunk
    stop = wp.min(start + facets_per_chunk, normal.shape[0])
    for j in range(rows.shape[0]):
        g = asg_load(rows, j)
        acc = wp.float64(0.0)
        for s in range(start, stop):
            acc += wp.float64(weight[s] * asg_eval(g, normal[s]))
        partial[c, j] = acc


@wp.kernel
def sum_chunks_moments(partial: wp.array3d(dtype=wp.float32), offset: int, out: wp.array2d(dtype=wp.float32)):
    u = wp.tid() + offset
    for j in range(partial.shape[2]):
        acc = wp.float64(0.0)
        for c in range(partial.shape[0]):
            acc += wp.float64(partial[c, u, j])
        out[u, j] = float(acc)


@wp.kernel
def histogram_moments(
    directions: wp.array(dtype=wp.vec3),
    pair_i: wp.array(dtype=wp.int32),
    pair_o: wp.array(dtype=wp.int32),
    hist: wp.array2d(dtype=wp.float32),
    bin_normal: wp.array(dtype=wp.vec3),
    bin_values: wp.array(dtype=vec16),
    n_lobes: int,
    offset: int,
    out: wp.array2d(dtype=wp.float32),
):
    u = wp.tid() + offset
    wi = directions[pair_i[u]]
    wo = directions[pair_o[u]]
    acc = vec16d()
    acc_c = wp.float64(0.0)
    for l in range(hist.shape[1]):
        h = hist[u, l]
        if h == 0.0:
            continue
        n = bin_normal[l]
        p = wp.float64(wp.max(wp.dot(n, wi), 0.0) * wp.max(wp.dot(n, wo), 0.0) * h)
        acc_c += p
        acc += p * vec16d(bin_values[l])
    for j in range(n_lobes):
        out[u, j] = float(acc[j])
    out[u, n_lobes] = float(acc_c)


@wp.kernel
def solve_amplitudes(
    pair_i: wp.array(dtype=wp.int32),
    pair_o: wp.array(dtype=wp.int32),
    n_dirs: int,
    a_v: wp.array(dtype=wp.float32),
    moments: wp.array2d(dtype=wp.float32),
    rows: wp.array2d(dtype=wp.float64),
    integrals: wp.array(dtype=wp.float64),
    offset: int,
    mu: wp.array2d(dtype=wp.float32),
):
    p = wp.tid() + offset
    i = pair_i[p]
    o = pair_o[p]
    lo = wp.min(i, o)
    hi = wp.max(i, o)
    u = lo * n_dirs - lo * (lo - 1) / 2 + (hi - lo)  # index of (lo, hi) among the pairs lo <= hi, row-major
    n_lobes = rows.shape[0]
    area = wp.float64(a_v[o])
    c = wp.float64(moments[u, n_lobes])
    if area <= wp.float64(0.0) or c <= wp.float64(0.0):
        for j in range(n_lobes):
            mu[p, j] = 0.0
        return
    c = c / area
    sol = vec16d()
    total = wp.float64(0.0)
    for j in range(n_lobes):
        x = wp.float64(0.0)
        for k in range(n_lobes):
            x += rows[j, k] * wp.float64(moments[u, k])
        x = wp.max(x / area, wp.float64(0.0))
        sol[j] = x
        total += x * integrals[j]
    if total > wp.float64(0.0):
        for j in range(n_lobes):
            mu[p, j] = float(sol[j] * (c / total))
    else:  # every amplitude clamped: all of ∫γ̃ goes to the lobe with the largest b_j
        best = int(0)
        for j in range(1, n_lobes):
            if moments[u, j] > moments[u, best]:
                best = j
        for j in range(n_lobes):
            mu[p, j] = 0.0
        mu[p, best] = float(c / integrals[best])


@wp.kernel
def amplitude_tables(
    mu: wp.array2d(dtype=wp.float32),
    integrals: wp.array(dtype=wp.float64),
    color: wp.vec3,
    accumulate: int,
    material: int,
    offset: int,
    amps: wp.array4d(dtype=wp.float32),
    energy: wp.array3d(dtype=wp.float32),
):
    """reference.amplitude_tables for one channel of `material`: amps[m, p, j, :] (+)= max(μ_pj, 0)·color
    and energy[m, p, :] (+)= Σ_j max(μ_pj, 0) ∫G_j · color (added when `accumulate`, else written). A
    non-finite μ (NaN is not clamped away) makes the pair's energy NaN, which the host checks."""
    p = wp.tid() + offset
    total = wp.float64(0.0)
    finite = int(1)
    for j in range(mu.shape[1]):
        m = mu[p, j]
        if not wp.isfinite(m):
            finite = 0
        m = wp.max(m, 0.0)
        total += wp.float64(m) * integrals[j]
        for c in range(3):
            a = m * color[c]
            if accumulate != 0:
                a += amps[material, p, j, c]
            amps[material, p, j, c] = a
    e = float(total)
    for c in range(3):
        v = e * color[c]
        if accumulate != 0:
            v += energy[material, p, c]
        if finite == 0:
            v = wp.nan
        energy[material, p, c] = v


@wp.kernel
def energy_levels(
    energy: wp.array3d(dtype=wp.float32),
    weights: wp.array2d(dtype=wp.float32),
    offset: int,
    levels: wp.array4d(dtype=wp.float32),
):
    """reference.energy_levels: levels[m, 0] = energy[m] and, for l ≥ 1, levels[m, l, (ξ, o)] =
    Σ_g weights[(l − 1)·K² + ξ, g]·energy[m, (g, o)] over the K² grid directions ω_g (pairs ωi-major),
    summed in float32 as the host's float32 product was."""
    m, level, p0 = wp.tid()
    p = p0 + offset
    k2 = weights.shape[1]
    if level == 0:
        for c in range(3):
            levels[m, 0, p, c] = energy[m, p, c]
        return
    xi = p // k2
    o = p - xi * k2
    row = (level - 1) * k2 + xi
    total = wp.vec3(0.0)
    for g in range(k2):
        q = g * k2 + o
        total += weights[row, g] * wp.vec3(energy[m, q, 0], energy[m, q, 1], energy[m, q, 2])
    for c in range(3):
        levels[m, level, p, c] = total[c]
