/* Spherical EM (Han 2007, as Iwasaki §4): E-step responsibilities, their sufficient statistics, and the M-step.
 *
 * Twin of kernels/em.py; the mathematics is warp_biscale.reference.ndf_statistics / ndf_em. One
 * work-item per facet writes its J responsibilities (times ΔA, float32); then one work-item per
 * (lobe, chunk of 64 facets on a GPU) sums [r ΔA, r ΔA n] in float64 and sum_chunks_stats adds
 * groups of chunks in order, twice, so no atomics are needed and no work-item runs a long serial
 * chain. float64 sums matter here: the sharpness comes from 1 − r̄, r̄ = ‖Σ r ΔA n‖ / Σ r ΔA, which
 * is ~1e−5 for a sharp lobe. em_m_step (one work-item per lobe) and em_finish (one work-item) are
 * warp_biscale.lobes.m_step and converged in float64, so the whole EM loop is enqueued without a
 * host round trip per step. state = [done, steps]: once done is set, every kernel of the later
 * steps returns at once. Needs cl_khr_fp64.
 *
 * No limit on J here (nothing is held per lobe in private memory). NDRanges: (facets,), then
 * (lobes, chunks), dimension 0 varying fastest as the last dimension of Warp's (chunks, lobes)
 * launch. The statistics travel as double arrays of stride 4 ([r, r·nx, r·ny, r·nz]).
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

/* −η/2·‖ξ − n‖² + log α (= log α − η(1 − ξ·n), exact near ξ = n), in Warp's operation order. */
CL_INLINE float lobe_log(__global const float *axes, __global const float *sharpness,
                         __global const float *log_weight, int j, float3 n)
{
    float3 a = load3(axes, j);
    float3 d = (float3)(a.x - n.x, a.y - n.y, a.z - n.z);
    return log_weight[j] - sharpness[j] * 0.5f * dot3(d, d);
}

__kernel void ndf_responsibilities(
    __global const float *normal,      /* (Ns, 3) */
    __global const float *area,        /* (Ns,) */
    __global const float *axes,        /* (J, 3) */
    __global const float *sharpness,   /* (J,) */
    __global const float *log_weight,  /* (J,) */
    const int n_lobes,
    const int n_facets,
    __global const int *state,         /* (2,) [done, steps] */
    __global float *resp)              /* (Ns, J) */
{
    int s = get_global_id(0);
    if (s >= n_facets || state[0] != 0)
        return;
    float3 n = load3(normal, s);
    __global float *r = resp + (size_t)s * n_lobes;
    float top = -1.0e30f;
    for (int j = 0; j < n_lobes; ++j)
        top = maxf(top, lobe_log(axes, sharpness, log_weight, j, n));
    float total = 0.0f;
    for (int j = 0; j < n_lobes; ++j) {
        float e = exp(lobe_log(axes, sharpness, log_weight, j, n) - top);
        r[j] = e;
        total += e;
    }
    float scale = area[s] / total;
    for (int j = 0; j < n_lobes; ++j)
        r[j] = r[j] * scale;
}

__kernel void ndf_sums_partial(
    __global const float *normal,  /* (Ns, 3) */
    __global const float *resp,    /* (Ns, J) */
    const int n_lobes,
    const int n_facets,
    const int facets_per_chunk,
    __global const int *state,     /* (2,) */
    __global double *partial)      /* (chunks, J, 4) */
{
    int j = get_global_id(0);
    int c = get_global_id(1);
    if (j >= n_lobes || state[0] != 0)
        return;
    int start = c * facets_per_chunk;
    int stop = start + facets_per_chunk < n_facets ? start + facets_per_chunk : n_facets;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    for (int s = start; s < stop; ++s) {
        double r = (double)resp[(size_t)s * n_lobes + j];
        float3 n = load3(normal, s);
        a0 += r;
        a1 += r * (double)n.x;
        a2 += r * (double)n.y;
        a3 += r * (double)n.z;
    }
    __global double *out = partial + 4 * ((size_t)c * n_lobes + j);
    out[0] = a0;
    out[1] = a1;
    out[2] = a2;
    out[3] = a3;
}

/* out[g, j] = Σ partial[c, j] over the chunks c of group g, in order. NDRange (lobes, groups). */
__kernel void sum_chunks_stats(__global const double *partial, const int chunks, const int chunks_per_group,
                               const int n_lobes, __global const int *state, __global double *out)
{
    int j = get_global_id(0);
    int g = get_global_id(1);
    if (j >= n_lobes || state[0] != 0)
        return;
    int start = g * chunks_per_group;
    int stop = start + chunks_per_group < chunks ? start + chunks_per_group : chunks;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    for (int c = start; c < stop; ++c) {
        __global const double *x = partial + 4 * ((size_t)c * n_lobes + j);
        a0 += x[0];
        a1 += x[1];
        a2 += x[2];
        a3 += x[3];
    }
    __global double *o = out + 4 * ((size_t)g * n_lobes + j);
    o[0] = a0;
    o[1] = a1;
    o[2] = a2;
    o[3] = a3;
}

/* EM weight of a facet: ΔA_s · mean_k V_s(ω_k)(n_s·ω_k)⁺, its projected area over the direction grid
 * (reference.visible_weights): a facet no grid direction sees weighs nothing. Summed in Warp's order. */
__kernel void visible_weights(
    __global const float *directions,  /* (D, 3) */
    __global const uint *bits,         /* (D, words) */
    const int n_dirs,
    const int n_words,
    __global const float *normal,      /* (Ns, 3) */
    __global const float *area,        /* (Ns,) */
    const int n_facets,
    __global float *weight)            /* (Ns,) */
{
    int s = get_global_id(0);
    if (s >= n_facets)
        return;
    float3 n = load3(normal, s);
    int word = s / 32;
    uint bit = (uint)(s % 32);
    float acc = 0.0f;
    for (int k = 0; k < n_dirs; ++k)
        if ((bits[(size_t)k * n_words + word] >> bit) & 1u)
            acc += maxf(dot3(n, load3(directions, k)), 0.0f);
    weight[s] = area[s] * acc / (float)n_dirs;
}

#define DEAD_MASS 1.0e-9         /* lobes.DEAD_MASS */
#define EM_TOL 1.0e-4            /* lobes.CONVERGENCE_TOL */
#define SHARP_MIN 1.0e-3         /* sg.SHARPNESS_MIN */
#define SHARP_MAX 1.0e6          /* sg.SHARPNESS_MAX */
#define DEAD_LOG_WEIGHT -1.0e30f /* a dead lobe's E-step constant: exp(−1e30 − top) = 0 */

/* lobes._mean_resultant_to_sharpness: 20 Newton steps on coth κ − 1/κ = r̄ from Banerjee's start
 * (stopping once a step leaves κ unchanged: the later ones would too). */
CL_INLINE double sharpness_from_mean_resultant(double rbar)
{
    double r = rbar < 1.0e-9 ? 1.0e-9 : (rbar > 1.0 ? 1.0 : rbar);
    double k = SHARP_MAX;
    if (r < 1.0 - 1.0e-12) {
        k = r * (3.0 - r * r) / (1.0 - r * r);
        for (int it = 0; it < 20; ++it) {
            double coth = 1.0, csch2 = 0.0;
            if (k <= 20.0) {  /* coth κ = 1 to double precision beyond */
                coth = 1.0 / tanh(k);
                double sh = sinh(k);
                csch2 = 1.0 / (sh * sh);
            }
            double f = coth - 1.0 / k - r;
            double df = 1.0 / (k * k) - csch2;
            if (df <= 0.0)
                df = 1.0;
            double k_new = k - f / df;
            if (k_new < 1.0e-9)
                k_new = 1.0e-9;
            if (k_new == k)
                break;
            k = k_new;
        }
    }
    return k < SHARP_MIN ? SHARP_MIN : (k > SHARP_MAX ? SHARP_MAX : k);
}

/* One work-item per lobe: lobes.m_step on the float64 lobes from the E-step sums stats (J, 4), the
 * float32 copies the E-step reads (log_weight as LobeSet.log_weight), and moved[j] = 1 where
 * lobes.converged fails for lobe j (it moved, or died in this step), −1 when no lobe holds area
 * (m_step then keeps the lobes and EM stops). */
__kernel void em_m_step(
    __global const double *stats,  /* (J, 4) */
    const int n_lobes,
    __global const int *state,     /* (2,) [done, steps] */
    __global double *axes64,       /* (J, 3) */
    __global double *sharpness64,  /* (J,) */
    __global double *weight64,     /* (J,) */
    __global float *axes,          /* (J, 3) */
    __global float *sharpness,     /* (J,) */
    __global float *log_weight,    /* (J,) */
    __global int *moved)           /* (J,) */
{
    int j = get_global_id(0);
    if (j >= n_lobes || state[0] != 0)
        return;
    double total = 0.0, kept = 0.0;
    for (int i = 0; i < n_lobes; ++i)
        total += stats[4 * i];
    for (int i = 0; i < n_lobes; ++i)
        if (stats[4 * i] > DEAD_MASS * total)
            kept += stats[4 * i];
    if (kept <= 0.0) {
        moved[j] = -1;
        return;
    }
    double m = stats[4 * j];
    double ox = axes64[3 * j], oy = axes64[3 * j + 1], oz = axes64[3 * j + 2];
    double old_sharp = sharpness64[j], old_weight = weight64[j];
    double ax = ox, ay = oy, az = oz, k = old_sharp, w = 0.0;
    int flag = 0;
    if (m > DEAD_MASS * total) {
        double rx = stats[4 * j + 1], ry = stats[4 * j + 2], rz = stats[4 * j + 3];
        double length = sqrt(rx * rx + ry * ry + rz * rz);
        if (length > 0.0) {
            ax = rx / length;
            ay = ry / length;
            az = rz / length;
        }
        k = sharpness_from_mean_resultant(length / m);
        w = m / kept;
        double dx = ax - ox, dy = ay - oy, dz = az - oz;
        if (0.5 * (dx * dx + dy * dy + dz * dz) >= 0.5 * EM_TOL * EM_TOL)
            flag = 1;
        if (fabs(log(k / old_sharp)) >= 10.0 * EM_TOL)
            flag = 1;
        if (fabs(w - old_weight) >= EM_TOL)
            flag = 1;
    } else if (old_weight > 0.0) {  /* died in this step */
        flag = 1;
    }
    moved[j] = flag;
    axes64[3 * j] = ax;
    axes64[3 * j + 1] = ay;
    axes64[3 * j + 2] = az;
    sharpness64[j] = k;
    weight64[j] = w;
    axes[3 * j] = (float)ax;
    axes[3 * j + 1] = (float)ay;
    axes[3 * j + 2] = (float)az;
    sharpness[j] = (float)k;
    log_weight[j] = w > 0.0 ? (float)(log(w) + log(k) - log(6.283185307179586) - log(1.0 - exp(-2.0 * k)))
                            : DEAD_LOG_WEIGHT;
}

/* One work-item: count the step and stop EM when no lobe moved (lobes.converged) or at max_steps. */
__kernel void em_finish(__global const int *moved, const int n_lobes, const int max_steps, __global int *state)
{
    if (get_global_id(0) != 0 || state[0] != 0)
        return;
    int any_moved = 0;
    for (int j = 0; j < n_lobes; ++j) {
        if (moved[j] < 0) {  /* no lobe held area: the step did nothing, and EM stops */
            state[0] = 1;
            return;
        }
        if (moved[j] != 0)
            any_moved = 1;
    }
    state[1] += 1;
    if (!any_moved || state[1] >= max_steps)
        state[0] = 1;
}

/* One work-item per lobe: the starting lobes from one packed upload, start[j] = [ξ (3), η, α,
 * log_weight] (LobeSet.log_weight, ≥ −1e30), into the float64 state and its float32 copies; EM's
 * `state` is reset. (One upload instead of seven: a host copy costs more than this launch.) */
__kernel void em_load(__global const double *start,  /* (J, 6) */
                      const int n_lobes,
                      __global double *axes64, __global double *sharpness64, __global double *weight64,
                      __global float *axes, __global float *sharpness, __global float *log_weight,
                      __global int *state)
{
    int j = get_global_id(0);
    if (j >= n_lobes)
        return;
    __global const double *s = start + 6 * j;
    for (int c = 0; c < 3; ++c) {
        axes64[3 * j + c] = s[c];
        axes[3 * j + c] = (float)s[c];
    }
    sharpness64[j] = s[3];
    weight64[j] = s[4];
    sharpness[j] = (float)s[3];
    log_weight[j] = (float)s[5];
    if (j == 0) {
        state[0] = 0;
        state[1] = 0;
    }
}

/* One work-item per lobe: the fitted lobes and the steps taken packed for one read-back,
 * out[j] = [ξ (3), η, α, steps]. */
__kernel void em_result(__global const double *axes64, __global const double *sharpness64,
                        __global const double *weight64, __global const int *state, const int n_lobes,
                        __global double *out)  /* (J, 6) */
{
    int j = get_global_id(0);
    if (j >= n_lobes)
        return;
    __global double *o = out + 6 * j;
    for (int c = 0; c < 3; ++c)
        o[c] = axes64[3 * j + c];
    o[3] = sharpness64[j];
    o[4] = weight64[j];
    o[5] = (double)state[1];
}

/* ---- EM's start on the device: lobes.initial_lobes over the facets (each at its normal, weighing its EM
 * weight, in its cube-map bin at 16), so that EM can be enqueued behind the rays without the host reading
 * the weights first; kernels/em.py's start_bin_sums and start_pick. The bins' sums are fixed point
 * (round(x·scale) as long, scale = 2^52 / a bound on Σw) added by integer atomics: integer sums do not
 * depend on their order, so the start is the same from run to run without the host sorting the facets.
 * The pick runs in one work-group of START_GROUP, its argmax and sums work-group reductions. */
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#define START_RES 16
#define START_GROUP 256
#define BIG_INDEX 2147483647

/* One work-item per facet: its coarse bin's [Σw, Σw n] (stride 4) += its own, in fixed point. */
__kernel void start_bin_sums(__global const float *normal, __global const float *weight, const double scale,
                             const int n_facets, __global long *sums)
{
    int s = get_global_id(0);
    if (s >= n_facets)
        return;
    double w = (double)weight[s];
    if (w == 0.0)
        return;
    float3 n = load3(normal, s);
    __global long *b = sums + 4 * cube_bin(n, START_RES);
    double q = w * scale;
    atom_add((volatile __global long *)b, (long)round(q));
    atom_add((volatile __global long *)(b + 1), (long)round(q * (double)n.x));
    atom_add((volatile __global long *)(b + 2), (long)round(q * (double)n.y));
    atom_add((volatile __global long *)(b + 3), (long)round(q * (double)n.z));
}

/* Work-group reductions over START_GROUP work-items: every work-item calls them and gets the result
 * (the fences also make each work-item's global writes before the call visible to the others). */
CL_INLINE double group_sum(double x, __local double *scratch)
{
    int l = get_local_id(0);
    scratch[l] = x;
    barrier(CLK_LOCAL_MEM_FENCE | CLK_GLOBAL_MEM_FENCE);
    for (int stride = START_GROUP / 2; stride > 0; stride >>= 1) {
        if (l < stride)
            scratch[l] += scratch[l + stride];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    double r = scratch[0];
    barrier(CLK_LOCAL_MEM_FENCE);
    return r;
}

/* The first index m of the largest x over the work-group (each work-item offers its own first largest);
 * every work-item gets it, and the largest x in *top. */
CL_INLINE int group_first_max(double x, int m, __local double *xs, __local int *ms, double *top)
{
    int l = get_local_id(0);
    xs[l] = x;
    ms[l] = m;
    barrier(CLK_LOCAL_MEM_FENCE | CLK_GLOBAL_MEM_FENCE);
    for (int stride = START_GROUP / 2; stride > 0; stride >>= 1) {
        if (l < stride && (xs[l + stride] > xs[l] || (xs[l + stride] == xs[l] && ms[l + stride] < ms[l]))) {
            xs[l] = xs[l + stride];
            ms[l] = ms[l + stride];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    int r = ms[0];
    *top = xs[0];
    barrier(CLK_LOCAL_MEM_FENCE);
    return r;
}

/* One work-group of START_GROUP: lobes.initial_lobes from the bins' sums → start (J, 6) rows [ξ (3), η, α,
 * log_weight] (backend.em_start_rows), slots past the distinct bins dead (α = 0, log_weight = −1e30).
 * Each work-item takes the bins lane, lane + START_GROUP, …; bins (stride 4: weight, unit mean normal),
 * dist, owner: scratch per bin, chosen (J): the picked bins. */
__kernel __attribute__((reqd_work_group_size(START_GROUP, 1, 1)))
void start_pick(__global const long *sums, const int n_bins, const double scale, const int n_lobes,
                __global double *bins, __global double *dist, __global int *owner, __global int *chosen,
                __global double *start)
{
    __local double dscratch[START_GROUP];
    __local int iscratch[START_GROUP];
    int lane = get_local_id(0);
    double inv = 1.0 / scale;
    double part = 0.0, top_w = -1.0;
    int top_m = BIG_INDEX;
    for (int m = lane; m < n_bins; m += START_GROUP) {
        double w = (double)sums[4 * m] * inv;
        double vx = (double)sums[4 * m + 1] * inv, vy = (double)sums[4 * m + 2] * inv, vz = (double)sums[4 * m + 3] * inv;
        double length = sqrt(vx * vx + vy * vy + vz * vz);
        if (length > 0.0) {
            vx /= length;
            vy /= length;
            vz /= length;
        }
        bins[4 * m] = w;
        bins[4 * m + 1] = vx;
        bins[4 * m + 2] = vy;
        bins[4 * m + 3] = vz;
        dist[m] = 1.0e300;
        part += w;
        if (w > top_w) {
            top_w = w;
            top_m = m;
        }
    }
    double total = group_sum(part, dscratch);
    double heaviest_w;
    int pick = group_first_max(top_w, top_m, dscratch, iscratch, &heaviest_w);
    /* Then repeatedly the bin of largest w·(1 − n·ξ) to its nearest chosen axis ξ (numpy's first argmax). */
    double threshold = 1.0e-12 * total;
    int picked = 0;
    for (;;) {
        chosen[picked] = pick;  /* (every work-item writes the same) */
        ++picked;
        double ax = bins[4 * pick + 1], ay = bins[4 * pick + 2], az = bins[4 * pick + 3];
        double best_s = -1.0;
        int best_m = BIG_INDEX;
        for (int m = lane; m < n_bins; m += START_GROUP) {
            double dx = bins[4 * m + 1] - ax, dy = bins[4 * m + 2] - ay, dz = bins[4 * m + 3] - az;
            double e = fmin(dist[m], 0.5 * (dx * dx + dy * dy + dz * dz));
            dist[m] = e;
            double score = bins[4 * m] * e;
            if (score > best_s) {
                best_s = score;
                best_m = m;
            }
        }
        double top;
        pick = group_first_max(best_s, best_m, dscratch, iscratch, &top);
        if (picked == n_lobes || top <= threshold)
            break;
    }
    /* Each bin to its nearest chosen axis; then each lobe's weight and mean resultant, one group sum a lobe. */
    for (int m = lane; m < n_bins; m += START_GROUP) {
        double nx = bins[4 * m + 1], ny = bins[4 * m + 2], nz = bins[4 * m + 3];
        int o = 0;
        double top_cos = -2.0;
        for (int j = 0; j < picked; ++j) {
            int c = chosen[j];
            double cs = bins[4 * c + 1] * nx + bins[4 * c + 2] * ny + bins[4 * c + 3] * nz;
            if (cs > top_cos) {
                top_cos = cs;
                o = j;
            }
        }
        owner[m] = o;
    }
    for (int j = 0; j < n_lobes; ++j) {
        double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
        if (j < picked) {
            for (int m = lane; m < n_bins; m += START_GROUP) {
                if (owner[m] == j) {
                    double w = bins[4 * m];
                    a0 += w;
                    a1 += w * bins[4 * m + 1];
                    a2 += w * bins[4 * m + 2];
                    a3 += w * bins[4 * m + 3];
                }
            }
        }
        a0 = group_sum(a0, dscratch);
        a1 = group_sum(a1, dscratch);
        a2 = group_sum(a2, dscratch);
        a3 = group_sum(a3, dscratch);
        if (lane != 0)
            continue;
        __global double *s = start + 6 * j;
        if (j < picked && total > 0.0) {
            int c = chosen[j];
            double r = sqrt(a1 * a1 + a2 * a2 + a3 * a3) / fmax(a0, 1.0e-300);
            r = fmin(fmax(r, 0.0), 1.0 - 1.0e-12);
            /* Banerjee's κ ≈ r̄(3 − r̄²)/(1 − r̄²): enough for a start (lobes.initial_lobes). */
            double k = fmin(fmax(r * (3.0 - r * r) / (1.0 - r * r), 1.0), 1.0e4);
            double alpha = a0 / total;
            s[0] = bins[4 * c + 1];
            s[1] = bins[4 * c + 2];
            s[2] = bins[4 * c + 3];
            s[3] = k;
            s[4] = alpha;
            s[5] = alpha > 0.0 ? log(alpha) + log(k) - log(6.283185307179586) - log(1.0 - exp(-2.0 * k))
                               : DEAD_LOG_WEIGHT;
        } else {  /* a dead slot: no distinct bin left for it (or no weight at all) */
            s[0] = 0.0;
            s[1] = 0.0;
            s[2] = 1.0;
            s[3] = 1.0;
            s[4] = 0.0;
            s[5] = DEAD_LOG_WEIGHT;
        }
    }
}
