/* Gram amplitudes (Iwasaki §4, docs/design.md §5): the lobe moments b, c of every direction pair and the solve.
 *
 * Twin of kernels/amplitudes.py; the mathematics is warp_biscale.reference.lobe_values,
 * lobe_moments, histogram_moments and solve_amplitudes. Needs cl_khr_fp64.
 *
 * Facet route: b_kj·a_v(ωo) = Σ_s P_si P_so w_s G_j(n_s) with P_sk = V_s(ω_k)(n_s·ω_k)⁺. It is
 * symmetric in (i, o), so only the unordered pairs i ≤ o are summed: one work-item per (unordered
 * pair, chunk of facet words) walks the set bits of V(ωi) ∧ V(ωo) ∧ channel and keeps J + 1
 * accumulators (J lobes and the plain sum c) in registers; G_j(n_s) is tabulated once per facet
 * (lobe_values). Summation as in the ground truth: float32 within a 32-facet word, float64 across
 * words and chunks.
 *
 * Histogram route: the same sums over the L non-empty normal bins, each taken at its mean normal.
 *
 * ASG lobes (the ASG bake): asg_lobe_values tabulates G_j(n_s) of ASG rows in lobe_values' place, and
 * asg_value_sums gives Σ_s w_s G_j(n_s); both call cl/asg.cl's asg_eval (opencl_backend.USES).
 *
 * Lobe layout: the table G_j(n) has a row of 8·⌈J/8⌉ floats, zero past J, read as one or two float8
 * (values past J are 0 and are never written out), so the hot loops add whole vectors — per lane the
 * same float32 (facet route) or float64 (histogram route) operations as the Warp twin's vec16, and
 * on PoCL (AVX2) about 1.3–1.5× faster than a loop over j (J = 8 and 16, 2^14 facets, 144
 * directions). Vectors are converted lane by lane rather than with convert_/vstore builtins, which
 * PoCL calls out of line (with the double8 ones the program lost its kernels: INVALID_KERNEL_NAME).
 *
 * Solve: one work-item per ordered pair (i, o) reads the unordered pair's moments, divides by
 * a_v(ωo), applies the J×J solve rows (float64: A⁻¹ of close lobes has large entries of both signs),
 * clamps negative amplitudes and rescales to the exact energy c, as the reference does.
 *
 * Tables: one work-item per ordered pair adds a channel's amplitudes times its colour into its
 * material's (P, J, 3) table and their energy Σ_j μ_j ∫G_j into (P, 3), on the device (the same numpy
 * on the host cost more than the read-back: bench/README.md); then one per (pair, level, material)
 * prefilters the energy over ωi for the renderer's broad environment lobes (energy_levels).
 *
 * At most MAX_LOBES lobes (private arrays). NDRanges as in cl/truth.cl: (outputs, chunks), dimension
 * 0 varying fastest as the last dimension of Warp's (chunks, outputs) launch, rounded up to a whole
 * work-group; the surplus work-items return. 3-vectors are float arrays of stride 3.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#define MAX_LOBES 16

/* A macro, not a function: PoCL warns that a double8 return value changes the ABI without AVX-512. */
#define TO_DOUBLE8(v) \
    ((double8)((double)(v).s0, (double)(v).s1, (double)(v).s2, (double)(v).s3, (double)(v).s4, (double)(v).s5, \
               (double)(v).s6, (double)(v).s7))

/* values[s, j] = exp(−η_j/2·‖ξ_j − n_s‖²) (1 − ξ·n written as ‖ξ − n‖²/2: exact near ξ = n), rows of
 * `stride` floats, zero past J. */
__kernel void lobe_values(
    __global const float *normal,     /* (Ns, 3) */
    __global const float *axes,       /* (J, 3) */
    __global const float *sharpness,  /* (J,) */
    const int n_lobes,
    const int stride,
    const int n_facets,
    __global float *values)           /* (Ns, stride), zero past J */
{
    int s = get_global_id(0);
    if (s >= n_facets)
        return;
    float3 n = load3(normal, s);
    for (int j = 0; j < n_lobes; ++j) {
        float3 a = load3(axes, j);
        float3 d = (float3)(a.x - n.x, a.y - n.y, a.z - n.z);
        float e = exp(-sharpness[j] * 0.5f * dot3(d, d));
        values[(size_t)s * stride + j] = e < 1.0e-30f ? 0.0f : e; /* no denormals: ~3x slower on a CPU */
    }
    for (int j = n_lobes; j < stride; ++j)
        values[(size_t)s * stride + j] = 0.0f;
}

/* The ASG bake's lobes in lobe_values' place: values[s, j] = G_j(n_s) of ASG rows (J, 12) (cl/asg.cl, which
 * opencl_backend.USES puts before this file), rows of `stride` floats, zero past J. */
__kernel void asg_lobe_values(
    __global const float *normal,     /* (Ns, 3) */
    __global const float *rows,       /* (J, 12) */
    const int n_lobes,
    const int stride,
    const int n_facets,
    __global float *values)           /* (Ns, stride), zero past J */
{
    int s = get_global_id(0);
    if (s >= n_facets)
        return;
    float3 n = load3(normal, s);
    for (int j = 0; j < n_lobes; ++j) {
        float e = asg_eval(asg_load(rows, j), n);
        values[(size_t)s * stride + j] = e < 1.0e-30f ? 0.0f : e;
    }
    for (int j = n_lobes; j < stride; ++j)
        values[(size_t)s * stride + j] = 0.0f;
}

/* partial[c, j] = Σ_s w_s G_j(n_s) over chunk c's facets [c·per, (c + 1)·per), in double (the ASG bake's
 * calibration sums; the host adds the chunks). */
__kernel void asg_value_sums(
    __global const float *normal,     /* (Ns, 3) */
    __global const float *weight,     /* (Ns,) */
    __global const float *rows,       /* (J, 12) */
    const int n_lobes,
    const int n_facets,
    const int facets_per_chunk,
    const int n_chunks,
    __global double *partial)         /* (chunks, J) */
{
    int c = get_global_id(0);
    if (c >= n_chunks)
        return;
    int start = c * facets_per_chunk;
    int stop = min(start + facets_per_chunk, n_facets);
    for (int j = 0; j < n_lobes; ++j) {
        Asg g = asg_load(rows, j);
        double acc = 0.0;
        for (int s = start; s < stop; ++s)
            acc += (double)(weight[s] * asg_eval(g, load3(normal, s)));
        partial[(size_t)c * n_lobes + j] = acc;
    }
}

__kernel void lobe_moments_partial(
    __global const float *directions,    /* (D, 3) */
    __global const int *pair_i,          /* (U,) */
    __global const int *pair_o,          /* (U,) */
    __global const uint *bits,           /* (D, words) */
    const int n_words,
    __global const uint *channel_bits,   /* (words,) weight > 0 */
    __global const float *weight,        /* (Ns,) */
    __global const float *normal,        /* (Ns, 3) */
    __global const float8 *values,       /* (Ns, groups) groups = ⌈J/8⌉, zero past J */
    __global const int *run_end,         /* (Ns,) one past the run of facets sharing s's normal and weight */
    const int n_lobes,
    const int words_per_chunk,
    const int n_pairs,
    __global float *partial)             /* (chunks, U, J + 1) */
{
    int u = get_global_id(0);
    int c = get_global_id(1);
    if (u >= n_pairs)
        return;
    int i = pair_i[u];
    int o = pair_o[u];
    int groups = (n_lobes + 7) >> 3;
    float3 wi = load3(directions, i);
    float3 wo = load3(directions, o);
    __global const uint *bi = bits + (size_t)i * n_words;
    __global const uint *bo = bits + (size_t)o * n_words;
    double8 a0 = (double8)(0.0), a1 = (double8)(0.0);
    double acc_c = 0.0;
    int w_start = c * words_per_chunk;
    int w_end = w_start + words_per_chunk < n_words ? w_start + words_per_chunk : n_words;
    for (int w = w_start; w < w_end; ++w) {
        uint m = bi[w] & bo[w] & channel_bits[w];
        if (m == 0u)
            continue;
        float8 b0 = (float8)(0.0f), b1 = (float8)(0.0f);
        float block_c = 0.0f;
        while (m != 0u) {
            int b = lowest_bit(m);
            int s = w * 32 + b;
            /* The visible facets of s's run in this word (same normal, weight, lobe values): one count. */
            int end = run_end[s] - w * 32;
            uint seg = end < 32 ? m & ((1u << end) - 1u) : m;
            m = m & ~seg;
            float3 n = load3(normal, s);
            float p = maxf(dot3(n, wi), 0.0f) * maxf(dot3(n, wo), 0.0f) * weight[s] * (float)bit_count(seg);
            block_c += p;
            __global const float8 *g = values + (size_t)s * groups;
            b0 += p * g[0];
            if (groups > 1)
                b1 += p * g[1];
        }
        acc_c += (double)block_c;
        a0 += TO_DOUBLE8(b0);
        if (groups > 1)
            a1 += TO_DOUBLE8(b1);
    }
    double acc[MAX_LOBES] = {a0.s0, a0.s1, a0.s2, a0.s3, a0.s4, a0.s5, a0.s6, a0.s7,
                      a1.s0, a1.s1, a1.s2, a1.s3, a1.s4, a1.s5, a1.s6, a1.s7};
    __global float *out = partial + ((size_t)c * n_pairs + u) * (n_lobes + 1);
    for (int j = 0; j < n_lobes; ++j)
        out[j] = (float)acc[j];
    out[n_lobes] = (float)acc_c;
}

/* One work-item per 32-facet word (model.run_ends): bit b of channel_bits[w] is weight > 0, and
 * run_end[s] is one past the run of facets sharing s's normal and weight, cut at the word's end (all
 * the moment kernels need), found walking the word backwards. */
__kernel void facet_runs(__global const float *normal,   /* (Ns, 3) */
                         __global const float *weight,   /* (Ns,) */
                         const int n,
                         __global uint *channel_bits,    /* (⌈Ns/32⌉,) */
                         __global int *run_end)          /* (Ns,) */
{
    int w = get_global_id(0);
    int start = w * 32;
    if (start >= n)
        return;
    int stop = min(start + 32, n);
    int end = stop;
    uint mask = 0u;
    for (int s = stop - 1; s >= start; --s) {
        if (s + 1 < stop && (normal[3 * s] != normal[3 * s + 3] || normal[3 * s + 1] != normal[3 * s + 4] ||
                             normal[3 * s + 2] != normal[3 * s + 5] || weight[s] != weight[s + 1]))
            end = s + 1;
        run_end[s] = end;
        if (weight[s] > 0.0f)
            mask |= 1u << (s - start);
    }
    channel_bits[w] = mask;
}

__kernel void sum_chunks_moments(__global const float *partial,  /* (chunks, U, J + 1) */
                                 const int chunks, const int n_pairs, const int width,
                                 __global float *out)            /* (U, J + 1) */
{
    int u = get_global_id(0);
    if (u >= n_pairs)
        return;
    for (int j = 0; j < width; ++j) {
        double acc = 0.0;
        for (int c = 0; c < chunks; ++c)
            acc += (double)partial[((size_t)c * n_pairs + u) * width + j];
        out[(size_t)u * width + j] = (float)acc;
    }
}

__kernel void histogram_moments(
    __global const float *directions,   /* (D, 3) */
    __global const int *pair_i,         /* (P,) */
    __global const int *pair_o,         /* (P,) */
    __global const float *hist,         /* (P, L) */
    const int n_bins,
    __global const float *bin_normal,   /* (L, 3) */
    __global const float8 *bin_values,  /* (L, groups) groups = ⌈J/8⌉, zero past J */
    const int n_lobes,
    const int n_pairs,
    __global float *out)                /* (P, J + 1) */
{
    int u = get_global_id(0);
    if (u >= n_pairs)
        return;
    int groups = (n_lobes + 7) >> 3;
    float3 wi = load3(directions, pair_i[u]);
    float3 wo = load3(directions, pair_o[u]);
    double8 a0 = (double8)(0.0), a1 = (double8)(0.0);
    double acc_c = 0.0;
    __global const float *row = hist + (size_t)u * n_bins;
    for (int l = 0; l < n_bins; ++l) {
        float h = row[l];
        if (h == 0.0f)
            continue;
        float3 n = load3(bin_normal, l);
        double p = (double)(maxf(dot3(n, wi), 0.0f) * maxf(dot3(n, wo), 0.0f) * h);
        acc_c += p;
        __global const float8 *g = bin_values + (size_t)l * groups;
        a0 += p * TO_DOUBLE8(g[0]);
        if (groups > 1)
            a1 += p * TO_DOUBLE8(g[1]);
    }
    double acc[MAX_LOBES] = {a0.s0, a0.s1, a0.s2, a0.s3, a0.s4, a0.s5, a0.s6, a0.s7,
                      a1.s0, a1.s1, a1.s2, a1.s3, a1.s4, a1.s5, a1.s6, a1.s7};
    __global float *o = out + (size_t)u * (n_lobes + 1);
    for (int j = 0; j < n_lobes; ++j)
        o[j] = (float)acc[j];
    o[n_lobes] = (float)acc_c;
}

__kernel void solve_amplitudes(
    __global const int *pair_i,        /* (P,) ordered pairs */
    __global const int *pair_o,        /* (P,) */
    const int n_dirs,
    __global const float *a_v,         /* (D,) */
    __global const float *moments,     /* (U, J + 1) unordered pairs lo <= hi, row-major */
    __global const double *rows,       /* (J, J) */
    __global const double *integrals,  /* (J,) */
    const int n_lobes,
    const int n_pairs,
    __global float *mu)                /* (P, J) */
{
    int p = get_global_id(0);
    if (p >= n_pairs)
        return;
    int i = pair_i[p];
    int o = pair_o[p];
    int lo = i < o ? i : o;
    int hi = i < o ? o : i;
    int u = lo * n_dirs - lo * (lo - 1) / 2 + (hi - lo);  /* index of (lo, hi) among the pairs lo <= hi */
    __global const float *m = moments + (size_t)u * (n_lobes + 1);
    __global float *out = mu + (size_t)p * n_lobes;
    double area = (double)a_v[o];
    double c = (double)m[n_lobes];
    if (area <= 0.0 || c <= 0.0) {
        for (int j = 0; j < n_lobes; ++j)
            out[j] = 0.0f;
        return;
    }
    c = c / area;
    double sol[MAX_LOBES];
    double total = 0.0;
    for (int j = 0; j < n_lobes; ++j) {
        __global const double *r = rows + (size_t)j * n_lobes;
        double x = 0.0;
        for (int k = 0; k < n_lobes; ++k)
            x += r[k] * (double)m[k];
        x = x / area;
        x = x > 0.0 ? x : 0.0;
        sol[j] = x;
        total += x * integrals[j];
    }
    if (total > 0.0) {
        for (int j = 0; j < n_lobes; ++j)
            out[j] = (float)(sol[j] * (c / total));
    } else { /* every amplitude clamped: all of ∫γ̃ goes to the lobe with the largest b_j */
        int best = 0;
        for (int j = 1; j < n_lobes; ++j)
            if (m[j] > m[best])
                best = j;
        for (int j = 0; j < n_lobes; ++j)
            out[j] = 0.0f;
        out[best] = (float)(c / integrals[best]);
    }
}

/* reference.amplitude_tables for one channel of `material`: amps[m, p, j, :] (+)= max(μ_pj, 0)·color and
 * energy[m, p, :] (+)= Σ_j max(μ_pj, 0) ∫G_j · color (added when `accumulate`, else written). A non-finite
 * μ makes the pair's energy NaN, which the host checks. */
__kernel void amplitude_tables(
    __global const float *mu,          /* (P, J) */
    __global const double *integrals,  /* (J,) */
    const float red, const float green, const float blue,
    const int accumulate,
    const int material,
    const int n_lobes,
    const int n_pairs,
    __global float *amps,              /* (M, P, J, 3) */
    __global float *energy)            /* (M, P, 3) */
{
    int p = get_global_id(0);
    if (p >= n_pairs)
        return;
    float color[3] = {red, green, blue};
    double total = 0.0;
    int finite = 1;
    __global float *mine = amps + (size_t)material * n_pairs * n_lobes * 3;
    __global float *e_out = energy + ((size_t)material * n_pairs + p) * 3;
    for (int j = 0; j < n_lobes; ++j) {
        float m = mu[(size_t)p * n_lobes + j];
        if (!isfinite(m))
            finite = 0;
        m = m > 0.0f ? m : 0.0f;
        total += (double)m * integrals[j];
        __global float *a = mine + ((size_t)p * n_lobes + j) * 3;
        for (int c = 0; c < 3; ++c)
            a[c] = (accumulate ? a[c] : 0.0f) + m * color[c];
    }
    float e = (float)total;
    for (int c = 0; c < 3; ++c) {
        float v = (accumulate ? e_out[c] : 0.0f) + e * color[c];
        e_out[c] = finite ? v : NAN;
    }
}

/* reference.energy_levels: levels[m, 0] = energy[m] and, for l >= 1, levels[m, l, (ξ, o)] =
 * Σ_g weights[(l − 1)·K² + ξ, g]·energy[m, (g, o)] over the K² grid directions (pairs ωi-major), in
 * float32 as the Warp twin. NDRange (pairs, levels, materials). */
__kernel void energy_levels(
    __global const float *energy,   /* (M, P, 3), P = K²·K² */
    __global const float *weights,  /* ((L − 1)·K², K²) */
    const int n_levels,
    const int k2,
    __global float *levels)         /* (M, L, P, 3) */
{
    int p = get_global_id(0);
    int level = get_global_id(1);
    int m = get_global_id(2);
    int n_pairs = k2 * k2;
    if (p >= n_pairs)
        return;
    __global const float *e = energy + (size_t)m * n_pairs * 3;
    __global float *out = levels + (((size_t)m * n_levels + level) * n_pairs + p) * 3;
    if (level == 0) {
        for (int c = 0; c < 3; ++c)
            out[c] = e[(size_t)p * 3 + c];
        return;
    }
    int xi = p / k2, o = p - xi * k2;
    __global const float *row = weights + ((size_t)(level - 1) * k2 + xi) * k2;
    float r = 0.0f, g_ = 0.0f, b = 0.0f;
    for (int g = 0; g < k2; ++g) {
        __global const float *v = e + ((size_t)g * k2 + o) * 3;
        r += row[g] * v[0];
        g_ += row[g] * v[1];
        b += row[g] * v[2];
    }
    out[0] = r;
    out[1] = g_;
    out[2] = b;
}
