/* Per-pixel SG shading (Wang 2009 §7, Iwasaki 2012 §5): the shade stage.
 *
 * Twin of kernels/shade.py, function for function and in the same operation order; the
 * mathematics and the packed inputs are warp_biscale.shading (shade_reference is the float64
 * oracle). One work-item per pixel along dimension 0 (rounded up to a whole work-group; the
 * surplus returns): it rebuilds the surface point from the G-buffer (face, barycentrics), sums
 * the environment's SG lobes and each light's SG emitter against the diffuse part, then the
 * warped specular lobes against the prefiltered environment and the lights, each lobe shadowed
 * by the SSDF (environment) or the light's shadow ray.
 *
 * Layouts (no float3 in global memory): positions, normals, tangents, env_maps and the output are
 * float arrays of stride 3; bary stride 2; light_vis (P, L) uchar; table (2, rows, cols);
 * env_levels (n_levels, 4) [log2 η, texel offset, H, W]; ssdf_basis texel-major (res², n_basis) (the transpose of static['ssdf_basis']);
 * ssdf_coeffs (V, n_coeffs); env_theta (V, n_env) with an SSDF (ssdf.ssdf_at_axes); the material arrays as
 * warp_biscale.shading.pack_materials.
 * The two one-cell bilinear helpers that Warp calls twice (grid_corners, grid_weights) are one
 * function here (grid_bilinear): the same values, one concentric map instead of two. The specular loop
 * runs lobe by lobe with an SG lobe's SSDF angle and table cell found once for all its material sub-rows
 * (Warp's runs sub-row by sub-row): the same values summed in another order, measured faster on NVIDIA's
 * OpenCL and slower under Warp (bench/README.md).
 */

#define SHADE_PI 3.14159265358979f
#define MIN_COS_VIEW 1.0e-4f /* = shading.MIN_COS_VIEW */
#define ASG_LOBES 1 /* = effective.ASG_LOBES: eff_info[7] of a material with ASG lobes */
#define ASG_EQ10_MIN 5.0f /* = asg.EQ10_MIN_BANDWIDTH */
#define EFF_LOBE_WIDTH 9 /* eff_lobes' row: [axis or z (3), η, x (3), λ, μ]; an ASG material's tangent orders
                             after its lobes, [o_c, o_s, 0 …] per sub-row and lobe */
#define RAYS_ONLY 0.125f /* = shading.RAYS_ONLY */
#define SSDF_ONLY 0.5f /* = shading.SSDF_ONLY */
#define SHARP_LOBE_ETA 8.0f /* = shading.SHARP_LOBE_ETA */
#define DIFFUSE_LEVELS 5 /* = len(effective.DIFFUSE_LEVEL_ETAS): f̄d and its prefiltered levels */
#define DIFFUSE_LEVEL_SHARP 64.0f /* = effective.DIFFUSE_LEVEL_SHARP */
#define DIFFUSE_LEVEL_STEP 8.0f /* = effective.DIFFUSE_LEVEL_STEP */
#define AS_UNIFORM_COS 0.58292645536f /* = shading.AS_UNIFORM_COS */
#define ASG_TAPS 12 /* = shading.ASG_TAPS */
#define ASG_TAP_SHARE 0.05f /* = shading.ASG_TAP_SHARE */
#define LIGHT_BLUR_EXP_MAX 4.0f /* = shading.LIGHT_BLUR_EXP_MAX */
#define MOMENT_VAR_MIN 5.0e-7f /* = shading.MOMENT_VAR_MIN */
#define MOMENT_P1_STEPS 4.0f /* = shading.MOMENT_P1_STEPS */
#define BACKGROUND_LOG2 1.0e30f /* = lighting.BACKGROUND_LOG2 */
#define BACKGROUND_ETA 1.0e29f /* = lighting.BACKGROUND_ETA */
#define TAP_SPAN 2.75f /* = shading.TAP_SPAN */
#define TAP_GAP 1.5f /* = shading.TAP_GAP */
#define ROUND_SPREAD 0.25f /* = shading.ROUND_SPREAD */
/* shading._HERMITE_NODES, _HERMITE_WEIGHTS, _HERMITE_GAPS: the Gauss–Hermite rules of 2–5 nodes (in spreads) one
 * after another, their weights summing to 1, and each rule's widest gap */
__constant float HERMITE_NODES[14] = {-1.0f, 1.0f, -1.73205078f, 0.0f, 1.73205078f, -2.33441424f, -0.741963804f,
                                      0.741963804f, 2.33441424f, -2.85697007f, -1.35562623f, 0.0f, 1.35562623f,
                                      2.85697007f};
__constant float HERMITE_WEIGHTS[14] = {0.5f, 0.5f, 0.166666672f, 0.666666687f, 0.166666672f, 0.0458758548f,
                                        0.454124153f, 0.454124153f, 0.0458758548f, 0.011257411f, 0.222075924f,
                                        0.533333361f, 0.222075924f, 0.011257411f};
__constant float HERMITE_GAPS[4] = {2.0f, 1.73205078f, 1.59245038f, 1.50134385f};

/* floor(x) as an int for x >= 0 (every caller clamps x to a non-negative range first): truncation,
 * the same integer, without PoCL's out-of-line floor call. */
CL_INLINE int ifloor_pos(float x) { return (int)x; }

/* ∫G = 2π(1 − e^{−2η})/η, with its series below η = 1e-3 (no cancellation). */
CL_INLINE float sg_integral(float eta)
{
    if (eta < 1.0e-3f)
        return 2.0f * SHADE_PI * (2.0f - 2.0f * eta + 1.3333333f * eta * eta);
    return 2.0f * SHADE_PI * (1.0f - exp(-2.0f * eta)) / eta;
}

/* The lighting table (2, rows, cols) over (log10 η, c) and its η range (sg.TABLE_LOG10_ETA). */
typedef struct {
    __global const float *p;
    int rows, cols;
    float lo, hi;
} Table;

/* A table row position for one η: lookups that share η (a lobe's cosine integral and its SSDF
 * fractions) share it, so log(η) is taken once; the arithmetic is sg.table_lookup's, split in two. */
typedef struct {
    int r0;
    float fr;
} EtaRow;

CL_INLINE EtaRow eta_row(Table t, float eta)
{
    float le = clampf(log(maxf(eta, 1.0e-30f)) * 0.4342944819f, t.lo, t.hi);
    float tr = (le - t.lo) / (t.hi - t.lo) * (float)(t.rows - 1);
    EtaRow r;
    r.r0 = min(ifloor_pos(tr), t.rows - 2);
    r.fr = tr - (float)r.r0;
    return r;
}

/* Bilinear in (log10 η, c): sg.table_lookup of table `which` at c and a row from eta_row. */
CL_INLINE float lookup(Table t, int which, EtaRow r, float c)
{
    float tc = (clampf(c, -1.0f, 1.0f) + 1.0f) * 0.5f * (float)(t.cols - 1);
    int c0 = min(ifloor_pos(tc), t.cols - 2);
    float fc = tc - (float)c0;
    __global const float *t0 = t.p + (which * t.rows + r.r0) * t.cols + c0;
    __global const float *t1 = t0 + t.cols;
    float top = (1.0f - fc) * t0[0] + fc * t0[1];
    float bottom = (1.0f - fc) * t1[0] + fc * t1[1];
    return (1.0f - r.fr) * top + r.fr * bottom;
}

/* ∫ G(ω; axis, η, 1)(n·ω)⁺ dω, η given with its table row. */
CL_INLINE float cosine_integral(Table t, float3 axis, float eta, EtaRow r, float3 n)
{
    return sg_integral(eta) * lookup(t, 0, r, dot3(axis, n));
}

/* Bilinear lookup of one equirect level at polar angle theta and azimuth phi in [0, 2π]
 * (environment.py's convention: wrap φ, clamp θ). φ's column lies in [-1, w - 1], so the wrap is a compare, not an
 * integer remainder (which a GPU computes in tens of instructions); the clamp keeps any other φ inside the map. */
CL_INLINE float3 equirect_bilinear(__global const float *maps, int offset, int h, int w, float theta, float phi)
{
    float row = theta * (float)h / SHADE_PI - 0.5f;
    float col = phi * (float)w / (2.0f * SHADE_PI) - 0.5f;
    float r0f = floor(row);
    float c0f = floor(col);
    float fr = row - r0f;
    float fc = col - c0f;
    int r0 = clamp((int)r0f, 0, h - 1);
    int r1 = clamp((int)r0f + 1, 0, h - 1);
    int c0 = (int)c0f;
    if (c0 < 0)
        c0 += w;
    c0 = clamp(c0, 0, w - 1);
    int c1 = c0 + 1 == w ? 0 : c0 + 1;
    float3 a = load3(maps, offset + r0 * w + c0) * (1.0f - fc) + load3(maps, offset + r0 * w + c1) * fc;
    float3 b = load3(maps, offset + r1 * w + c0) * (1.0f - fc) + load3(maps, offset + r1 * w + c1) * fc;
    return a * (1.0f - fr) + b * fr;
}

/* A bilinear lookup of one equirect map in direction d (Warp's equirect_bilinear). */
CL_INLINE float3 equirect_bilinear_dir(__global const float *maps, int offset, int h, int w, float3 d)
{
    float phi = atan2(d.z, d.x);
    if (phi < 0.0f)
        phi = phi + 2.0f * SHADE_PI;
    return equirect_bilinear(maps, offset, h, w, acos(clampf(d.y, -1.0f, 1.0f)), phi);
}

/* The two prefiltered levels a sharpness η reads (prefiltered_levels): each one's (texel offset, H, W), and the
 * second's weight. */
typedef struct {
    int3 a, b;
    float f;
} LevelPair;

/* Prefiltered level l's (texel offset, H, W), from its row of `levels`. */
CL_INLINE int3 level_at(__global const float *levels, int l)
{
    __global const float *row = levels + 4 * l;
    return (int3)((int)row[1], (int)row[2], (int)row[3]);
}

/* The levels of Λ(·, η) and their weights: linear in log2 η between the two nearest (lighting.prefiltered_lookup);
 * a last row marked BACKGROUND_LOG2 is read by η >= BACKGROUND_ETA alone (the camera's rays), by no lobe. Found
 * once for all the taps of one sharpness (asg_prefiltered). */
CL_INLINE LevelPair prefiltered_levels(__global const float *levels, int n, float eta)
{
    LevelPair out;
    if (n > 1 && levels[4 * (n - 1)] >= BACKGROUND_LOG2) {
        if (eta >= BACKGROUND_ETA) {
            out.a = level_at(levels, n - 1);
            out.b = out.a;
            out.f = 0.0f;
            return out;
        }
        n = n - 1;
    }
    float t = clampf(log2(maxf(eta, 1.0e-30f)) - levels[0], 0.0f, (float)(n - 1));
    int l0 = max(min(ifloor_pos(t), n - 2), 0);
    out.a = level_at(levels, l0);
    out.b = level_at(levels, min(l0 + 1, n - 1));
    out.f = clampf(t - (float)l0, 0.0f, 1.0f);
    return out;
}

/* Λ(d, η) from η's levels, each read only where it weighs (an end of the range, the background). The direction's
 * angles are computed once for both levels, as Warp's prefiltered_at does: atan2 is one of the costliest calls in
 * PoCL. */
CL_INLINE float3 prefiltered_at(__global const float *maps, LevelPair lv, float3 d)
{
    float theta = acos(clampf(d.y, -1.0f, 1.0f));
    float phi = atan2(d.z, d.x);
    if (phi < 0.0f)
        phi = phi + 2.0f * SHADE_PI;
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    if (lv.f < 1.0f)
        out = equirect_bilinear(maps, lv.a.x, lv.a.y, lv.a.z, theta, phi) * (1.0f - lv.f);
    if (lv.f > 0.0f)
        out = out + equirect_bilinear(maps, lv.b.x, lv.b.y, lv.b.z, theta, phi) * lv.f;
    return out;
}

/* Λ(d, η) (lighting.prefiltered_lookup). */
CL_INLINE float3 prefiltered(__global const float *maps, __global const float *levels, int n, float3 d, float eta)
{
    return prefiltered_at(maps, prefiltered_levels(levels, n, eta), d);
}

/* The SSDF of a pixel: basis, the three vertices' coefficient rows and their barycentric weights. */
typedef struct {
    __global const float *basis;
    __global const float *c0, *c1, *c2;
    float w0, w1, w2;
    int n_basis, res;
} Ssdf;

/* θd(d) from the PCA basis and the barycentric blend of three vertices' coefficients
 * (octahedral map, fold along z, bilinear clamped: reference.ssdf_eval). */
CL_INLINE float ssdf_theta(Ssdf s, float3 d)
{
    float sum = absf(d.x) + absf(d.y) + absf(d.z);
    float px = d.x / sum;
    float py = d.y / sum;
    if (d.z < 0.0f) {
        float sx = px < 0.0f ? -1.0f : 1.0f;
        float sy = py < 0.0f ? -1.0f : 1.0f;
        float qx = (1.0f - absf(py)) * sx;
        float qy = (1.0f - absf(px)) * sy;
        px = qx;
        py = qy;
    }
    int res = s.res;
    float x = clampf((px + 1.0f) * 0.5f * (float)res - 0.5f, 0.0f, (float)(res - 1));
    float y = clampf((py + 1.0f) * 0.5f * (float)res - 0.5f, 0.0f, (float)(res - 1));
    int x0 = min(ifloor_pos(x), res - 1);
    int y0 = min(ifloor_pos(y), res - 1);
    int x1 = min(x0 + 1, res - 1);
    int y1 = min(y0 + 1, res - 1);
    float fx = x - (float)x0;
    float fy = y - (float)y0;
    int k00 = y0 * res + x0;
    int k10 = y0 * res + x1;
    int k01 = y1 * res + x0;
    int k11 = y1 * res + x1;
    /* The basis is texel-major (res², n_basis): each corner's terms are one contiguous run. */
    int nb = s.n_basis;
    __global const float *b00 = s.basis + k00 * nb;
    __global const float *b10 = s.basis + k10 * nb;
    __global const float *b01 = s.basis + k01 * nb;
    __global const float *b11 = s.basis + k11 * nb;
    float w00 = (1.0f - fx) * (1.0f - fy), w10 = fx * (1.0f - fy), w01 = (1.0f - fx) * fy, w11 = fx * fy;
    float theta = 0.0f;
    for (int r = 0; r < nb; ++r) {
        float c = 1.0f;
        if (r > 0)
            c = s.w0 * s.c0[r - 1] + s.w1 * s.c1[r - 1] + s.w2 * s.c2[r - 1];
        float v = w00 * b00[r] + w10 * b10[r] + w01 * b01[r] + w11 * b11[r];
        theta = theta + c * v;
    }
    return theta;
}

/* The share of a lobe's horizon-clipped integral left visible by the SSDF's θd at its axis:
 * visible_fraction(sin θd, η) / visible_fraction(axis·n, η), clamped to [0, 1]. */
CL_INLINE float ssdf_visible_at(Table t, float theta, float3 axis, EtaRow r, float3 n)
{
    float c = sin(clampf(theta, -0.5f * SHADE_PI, 0.5f * SHADE_PI));
    float vis = lookup(t, 1, r, c) / maxf(lookup(t, 1, r, dot3(axis, n)), 1.0e-6f);
    return clampf(vis, 0.0f, 1.0f);
}

/* directions.hemisphere_to_square (z clamped to [0, 1]). */
CL_INLINE float2 concentric_uv(float3 w)
{
    float z = clampf(w.z, 0.0f, 1.0f);
    float r = sqrt(1.0f - z);
    float phi = atan2(w.y, w.x);
    if (phi < -0.25f * SHADE_PI)
        phi = phi + 2.0f * SHADE_PI;
    float q = 0.25f * SHADE_PI;
    float a, b;
    if (phi < q) {
        a = r;
        b = phi * a / q;
    } else if (phi < 3.0f * q) {
        b = r;
        a = -(phi - 0.5f * SHADE_PI) * b / q;
    } else if (phi < 5.0f * q) {
        a = -r;
        b = (phi - SHADE_PI) * a / q;
    } else {
        b = -r;
        a = -(phi - 1.5f * SHADE_PI) * b / q;
    }
    return (float2)((a + 1.0f) * 0.5f, (b + 1.0f) * 0.5f);
}

/* The four K×K grid indices around w, their weights (directions.bilinear_corners' order) and their directions'
 * cos θ (directions.grid: 1 − r², r the cell centre's concentric radius), from their column and row with no
 * integer division by K: kernels/shade.py's grid_bilinear (and grid_corners, grid_weights in one). */
CL_INLINE void grid_bilinear(float3 w, int k, int *idx, float *wgt, float *cosv)
{
    float2 uv = concentric_uv(w);
    float x = clampf(uv.x * (float)k - 0.5f, 0.0f, (float)(k - 1));
    float y = clampf(uv.y * (float)k - 0.5f, 0.0f, (float)(k - 1));
    int x0 = min(ifloor_pos(x), k - 1);
    int y0 = min(ifloor_pos(y), k - 1);
    int x1 = min(x0 + 1, k - 1);
    int y1 = min(y0 + 1, k - 1);
    float tx = x - (float)x0;
    float ty = y - (float)y0;
    idx[0] = y0 * k + x0;
    idx[1] = y0 * k + x1;
    idx[2] = y1 * k + x0;
    idx[3] = y1 * k + x1;
    wgt[0] = (1.0f - tx) * (1.0f - ty);
    wgt[1] = tx * (1.0f - ty);
    wgt[2] = (1.0f - tx) * ty;
    wgt[3] = tx * ty;
    float ax0 = fabs(2.0f * ((float)x0 + 0.5f) / (float)k - 1.0f);
    float ax1 = fabs(2.0f * ((float)x1 + 0.5f) / (float)k - 1.0f);
    float by0 = fabs(2.0f * ((float)y0 + 0.5f) / (float)k - 1.0f);
    float by1 = fabs(2.0f * ((float)y1 + 0.5f) / (float)k - 1.0f);
    float r00 = fmax(ax0, by0), r10 = fmax(ax1, by0), r01 = fmax(ax0, by1), r11 = fmax(ax1, by1);
    cosv[0] = 1.0f - r00 * r00;
    cosv[1] = 1.0f - r10 * r10;
    cosv[2] = 1.0f - r01 * r01;
    cosv[3] = 1.0f - r11 * r11;
}

/* Bilinear (ωi) × bilinear (ωo) lookup of value/cos θi in a (K², K², J, 3) table of values at lobe j; oo,
 * ow: ωo's corners. The division by each ωi corner's cos θi is done here, so that a bake's tables are read
 * as they are (no host copy per edit). */
CL_INLINE float3 table_rgb_cell(__global const float *table, int base, int k2, int j_count, int j, const int *ii,
                                const float *iw, const float *ic, const int *oo, const float *ow)
{
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    for (int a = 0; a < 4; ++a) {
        float wa = iw[a] / ic[a];
        for (int b = 0; b < 4; ++b) {
            int i = base + ((ii[a] * k2 + oo[b]) * j_count + j) * 3;
            float wgt = wa * ow[b];
            out = out + wgt * (float3)(table[i], table[i + 1], table[i + 2]);
        }
    }
    return out;
}

/* table_rgb_cell at wi_local's grid cell (ii, iw, ic: grid_bilinear's), for a caller that reads one table there. */
CL_INLINE float3 table_rgb(__global const float *table, int base, int k2, int j_count, int j, float3 wi_local, int k,
                           const int *oo, const float *ow)
{
    int ii[4];
    float iw[4], ic[4];
    grid_bilinear(wi_local, k, ii, iw, ic);
    return table_rgb_cell(table, base, k2, j_count, j, ii, iw, ic, oo, ow);
}

/* The level of an effective material's energy that a lobe of sharpness η reads: the nearest in log η,
 * round(log8(64/η)) in [0, L − 1] (effective.diffuse_level). */
CL_INLINE int diffuse_level(float eta)
{
    float u = clamp(log(DIFFUSE_LEVEL_SHARP / maxf(eta, 1.0e-30f)) / log(DIFFUSE_LEVEL_STEP), 0.0f,
                    (float)(DIFFUSE_LEVELS - 1));
    return (int)(u + 0.5f);
}

/* An effective material's f̄d/cos θ as a lobe of sharpness η sees it: Σ_m kd_m/π ⊙ material m's energy at the
 * lobe's level (diffuse_level). */
CL_INLINE float3 effective_diffuse(__global const int *ei, __global const float *eff_sub,
                                   __global const float *eff_diffuse, int k2, float eta, float3 wi_local, int k,
                                   const int *oo, const float *ow)
{
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    int level = diffuse_level(eta);
    int ii[4];
    float iw[4], ic[4];
    grid_bilinear(wi_local, k, ii, iw, ic);  /* (one ωi for every material's table) */
    for (int sub_i = 0; sub_i < ei[2]; ++sub_i) {
        __global const float *sub = eff_sub + 9 * (ei[4] + sub_i);
        float3 kd = (float3)(sub[1], sub[2], sub[3]) / SHADE_PI;
        int base = ei[6] + (sub_i * DIFFUSE_LEVELS + level) * k2 * k2 * 3;
        out = out + kd * table_rgb_cell(eff_diffuse, base, k2, 1, 0, ii, iw, ic, oo, ow);
    }
    return out;
}

/* M of an analytic BRDF's values at cos θd (shading.specular_scale). Values, not a row pointer: a
 * textured material's ks and p1 differ per pixel. */
CL_INLINE float3 specular_scale(int kind, float3 ks, float p1, float p2, float cos_d_in)
{
    float cos_d = clampf(cos_d_in, MIN_COS_VIEW, 1.0f);
    if (kind == BLINN_PHONG)
        return ks * ((p1 + 2.0f) / (2.0f * SHADE_PI));
    if (kind == COOK_TORRANCE) {
        float e = 1.0f - cos_d;
        float fres = p2 + (1.0f - p2) * e * e * e * e * e;
        return ks * (fres / (SHADE_PI * cos_d * cos_d));
    }
    if (kind == WARD)
        return ks / (4.0f * SHADE_PI * p1 * p1 * cos_d);
    if (kind == ANISOTROPIC_WARD)
        return ks / (4.0f * SHADE_PI * p1 * p2 * cos_d);
    if (kind == ASHIKHMIN_SHIRLEY) {
        float e = 1.0f - cos_d;
        float f5 = e * e * e * e * e;
        return (ks + ((float3)(1.0f, 1.0f, 1.0f) - ks) * f5) * (sqrt((p1 + 1.0f) * (p2 + 1.0f))
                                                                / (8.0f * SHADE_PI * cos_d * cos_d));
    }
    return (float3)(0.0f, 0.0f, 0.0f);
}

CL_INLINE float ndf_sharpness(int kind, float p1)
{
    if (kind == BLINN_PHONG)
        return p1;
    return 2.0f / (p1 * p1);
}

/* Bilinear, repeat-wrapped lookup of texture `slot` (svbrdf.sample: texel (i, j) centred at
 * ((j + ½)/W, (i + ½)/H), row 0 at v = 0). tex_info (T, 4) [texel offset, H, W, 0]; tex_data RGB texels. */
CL_INLINE float3 texture_bilinear(__global const int *tex_info, __global const float *tex_data, int slot, float2 uv)
{
    int off = tex_info[4 * slot];
    int h = tex_info[4 * slot + 1];
    int w = tex_info[4 * slot + 2];
    float x = uv.x * (float)w - 0.5f;
    float y = uv.y * (float)h - 0.5f;
    float x0f = floor(x);
    float y0f = floor(y);
    float fx = x - x0f;
    float fy = y - y0f;
    int j0 = (((int)x0f % w) + w) % w;
    int i0 = (((int)y0f % h) + h) % h;
    int j1 = (j0 + 1) % w;
    int i1 = (i0 + 1) % h;
    float3 top = load3(tex_data, off + i0 * w + j0) * (1.0f - fx) + load3(tex_data, off + i0 * w + j1) * fx;
    float3 bottom = load3(tex_data, off + i1 * w + j0) * (1.0f - fx) + load3(tex_data, off + i1 * w + j1) * fx;
    return top * (1.0f - fy) + bottom * fy;
}

/* An analytic row's environment-lobe scale c(ωo) (shading.specular_correction), its texture read at
 * shading.correction_uv: φo folded into [0, π/2] (an isotropic row's columns: its parameter map's p1_factor, from
 * the first factor its moment table at slot + 1 keeps), cos θo, each clamped to the texel centres. */
CL_INLINE float3 specular_correction(__global const int *tex_info, __global const float *tex_data, int slot,
                                     float3 wo_local, int kind, float p1_factor)
{
    float h = (float)tex_info[4 * slot + 1];
    float w = (float)tex_info[4 * slot + 2];
    float u = atan2(fabs(wo_local.y), fabs(wo_local.x)) / (0.5f * M_PI_F);
    if (w > 1.0f && kind != ANISOTROPIC_WARD && kind != ASHIKHMIN_SHIRLEY) {
        float first = tex_data[3 * (tex_info[4 * (slot + 1)] + tex_info[4 * (slot + 1) + 2] / 2) + 2];
        u = (clamp(MOMENT_P1_STEPS * (log2(maxf(p1_factor, 1.0e-30f)) - first), 0.0f, w - 1.0f) + 0.5f) / w;
    }
    u = clamp(u, 0.5f / w, 1.0f - 0.5f / w);
    float v = clamp(wo_local.z, 0.5f / h, 1.0f - 0.5f / h);
    return texture_bilinear(tex_info, tex_data, slot, (float2)(u, v));
}

/* A light's SG emitter seen from pos (scene.light_sg): axis, η = 2π/Ω, μ with ∫G = the irradiance
 * at normal incidence. Rows: [type 0 directional | 1 point, xyz, rgb, solid angle | radius]. */
CL_INLINE float3 light_axis(__global const float *row, float3 pos)
{
    float3 v = (float3)(row[1], row[2], row[3]);
    if (row[0] == 0.0f)
        return v;
    return normalize3(v - pos);
}

CL_INLINE float light_sharpness(__global const float *row, float3 pos)
{
    float omega = row[7];
    if (row[0] != 0.0f) {
        float3 v = (float3)(row[1], row[2], row[3]) - pos;
        float d = sqrt(dot3(v, v));
        omega = SHADE_PI * row[7] * row[7] / maxf(d * d, 1.0e-30f);
    }
    return 2.0f * SHADE_PI / maxf(omega, 1.0e-6f);
}

CL_INLINE float3 light_amplitude(__global const float *row, float3 pos, float eta)
{
    float3 power = (float3)(row[4], row[5], row[6]);
    if (row[0] != 0.0f) {
        float3 v = (float3)(row[1], row[2], row[3]) - pos;
        float d = sqrt(dot3(v, v));
        power = power / maxf(d * d, 1.0e-30f);
    }
    return power / sg_integral(eta);
}

/* A light's irradiance at a point of normal n, its cosine included (the light SG's cosine integral), times the
 * share of its shadow rays that reached it (vis, in 255ths; the rays aim at the part of the light above the
 * horizon, as the cosine integral counts it: trace_shadows); axis and eta: light_axis, light_sharpness. */
CL_INLINE float3 light_irradiance(Table tab, __global const float *row, float3 pos, float3 n, float3 axis, float eta,
                                  uchar vis)
{
    return light_amplitude(row, pos, eta) * (cosine_integral(tab, axis, eta, eta_row(tab, eta), n) * (float)vis / 255.0f);
}

/* ∫ G(a1, e1)·G(a2, e2)·(n·ω)⁺: the product SG (sg.product) against the clamped cosine. */
CL_INLINE float product_integral(Table t, float3 a1, float e1, float3 a2, float e2, float3 n)
{
    float3 v = e1 * a1 + e2 * a2;
    float3 s = a1 + a2;
    float d = sqrt(maxf((e1 - e2) * (e1 - e2) + e1 * e2 * dot3(s, s), 0.0f));
    float3 diff = a1 - a2;
    float gap = e1 * e2 * dot3(diff, diff) / (e1 + e2 + d);
    float3 axis = (float3)(0.0f, 0.0f, 1.0f);
    if (sqrt(dot3(v, v)) > 0.0f)
        axis = normalize3(v);
    return exp(-gap) * cosine_integral(t, axis, d, eta_row(t, d), n);
}

/* A pixel's surface point rebuilt from the G-buffer: position, shading frame (t, b, n) and the
 * face's vertices with their barycentric weights (for the per-vertex SSDF). */
typedef struct {
    float3 pos, n, t, b;
    int i0, i1, i2;
    float w0, w1, w2;
} SurfacePoint;

/* The direction through pixel p's centre (Camera.packed). */
CL_INLINE float3 camera_ray(float4 forward, float4 right, float4 up, float cam_w, float cam_h, int p)
{
    int width = (int)cam_w;
    float x = (float)(p % width);
    float y = (float)(p / width);
    return normalize3((float3)(forward.x, forward.y, forward.z)
                      + (2.0f * (x + 0.5f) / cam_w - 1.0f) * (float3)(right.x, right.y, right.z)
                      + (1.0f - 2.0f * (y + 0.5f) / cam_h) * (float3)(up.x, up.y, up.z));
}

/* The interpolated position and normal, and the tangent made orthogonal to the normal (any
 * perpendicular where the mesh's tangent is parallel to it or zero). */
/* The viewer lies behind triangle abc's plane, on the side its shading normal n turns from: a back face. */
CL_INLINE int seen_from_behind(float3 a, float3 b, float3 c, float3 n, float3 wo)
{
    float3 ng = cross3(b - a, c - a);
    return dot3(ng, n) * dot3(ng, wo) < 0.0f;
}

CL_INLINE SurfacePoint surface_point(__global const int *faces, __global const float *positions,
                                     __global const float *normals, __global const float *tangents, int f,
                                     float w1, float w2)
{
    SurfacePoint s;
    s.i0 = faces[3 * f];
    s.i1 = faces[3 * f + 1];
    s.i2 = faces[3 * f + 2];
    s.w1 = w1;
    s.w2 = w2;
    s.w0 = 1.0f - w1 - w2;
    s.pos = s.w0 * load3(positions, s.i0) + s.w1 * load3(positions, s.i1) + s.w2 * load3(positions, s.i2);
    float3 n = normalize3(s.w0 * load3(normals, s.i0) + s.w1 * load3(normals, s.i1) + s.w2 * load3(normals, s.i2));
    float3 t = s.w0 * load3(tangents, s.i0) + s.w1 * load3(tangents, s.i1) + s.w2 * load3(tangents, s.i2);
    t = t - dot3(t, n) * n;
    if (sqrt(dot3(t, t)) < 1.0e-12f) {
        float3 ref = absf(n.x) < 0.9f ? (float3)(1.0f, 0.0f, 0.0f) : (float3)(0.0f, 0.0f, 1.0f);
        t = ref - dot3(ref, n) * n;
    }
    t = normalize3(t);
    s.n = n;
    s.t = t;
    s.b = cross3(n, t);
    return s;
}

CL_INLINE float3 to_local(SurfacePoint s, float3 d) { return (float3)(dot3(d, s.t), dot3(d, s.b), dot3(d, s.n)); }

/* A pixel's occlusion rays: their mask (bit i: ray i blocked), the set's count, the rays of it traced (bit i:
 * ray i, by the pixel or a block neighbour that lends it its rays), the frame (a, b, n) about the geometric
 * normal on the camera's side that they were traced in, the cosine and sine of the pixel's hash angle that turns
 * them, and each ray's radius, lift and 1/lift (trace.disk_radii: rows (r, lift, 1/lift), S's from S(S − 1)/2). */
typedef struct {
    uint mask;
    int samples;
    uint known;
    float3 a, b, n;
    float turn_c, turn_s;
    __global const float *disk;
} Occlusion;

/* The occlusion rays' weight against the SSDF's for a lobe of sharpness η (shading.ray_weight). */
CL_INLINE float ray_weight(float eta, int samples)
{
    if (samples == 0)
        return 0.0f;
    float lo = RAYS_ONLY * (float)samples;
    float hi = SSDF_ONLY * (float)samples;
    if (eta <= lo) /* exactly 1 and 0 at the ends, whatever fast math makes of the logarithms' ratio there */
        return 1.0f;
    if (eta >= hi)
        return 0.0f;
    return clampf(log(hi / maxf(eta, 1.0e-30f)) / log(hi / lo), 0.0f, 1.0f);
}

/* The lobe's share that the pixel's occlusion rays see unblocked (shading.ray_share): the rays of occ.known,
 * their directions made again, each weighted by G(ω)(n·ω)⁺/(ng·ω). The spiral's angle steps by the golden
 * angle, so its cosine and sine are turned by a fixed rotation from one ray to the next rather than computed
 * per ray. */
CL_INLINE float ray_share(float3 axis, float eta, float3 n, Occlusion occ)
{
    float total = 0.0f, seen = 0.0f;
    float c = occ.turn_c, s = occ.turn_s;
    __global const float *ray = occ.disk + 3 * (occ.samples * (occ.samples - 1) / 2);
    /* the axis and the shading normal in the rays' frame */
    float ax = dot3(occ.a, axis), ay = dot3(occ.b, axis), az = dot3(occ.n, axis);
    float nx = dot3(occ.a, n), ny = dot3(occ.b, n), nz = dot3(occ.n, n);
    for (int i = 0; i < occ.samples; ++i) {
        if ((occ.known >> i) & 1u) {
            float x = ray[3 * i] * c, y = ray[3 * i] * s, lift = ray[3 * i + 1];
            float w = exp(eta * (x * ax + y * ay + lift * az - 1.0f)) * maxf(x * nx + y * ny + lift * nz, 0.0f)
                      * ray[3 * i + 2];
            total = total + w;
            if (((occ.mask >> i) & 1u) == 0u)
                seen = seen + w;
        }
        float c_next = c * GOLDEN_COS - s * GOLDEN_SIN;
        s = s * GOLDEN_COS + c * GOLDEN_SIN;
        c = c_next;
    }
    return total > 1.0e-30f ? seen / total : 1.0f;
}

/* ray_share for the six lobes of sharpness η along +y, −y, +x, −x, +z, −z (shading.axis_lobe_start) in one walk of
 * the rays, into share[6]: a ray's weight towards ±x is exp(−η)·exp(±η ω_x) times its lobe-free factor, so three
 * exponentials and their reciprocals serve all six. */
CL_INLINE void axis_ray_shares(float eta, float3 n, Occlusion occ, float share[6])
{
    float total[6] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    float seen[6] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    float c = occ.turn_c, s = occ.turn_s;
    __global const float *ray = occ.disk + 3 * (occ.samples * (occ.samples - 1) / 2);
    float nx = dot3(occ.a, n), ny = dot3(occ.b, n), nz = dot3(occ.n, n);
    float fall = exp(-eta); /* G's exp(−η), kept so that the 1e-30 floor on the total means what it does in ray_share */
    for (int i = 0; i < occ.samples; ++i) {
        if ((occ.known >> i) & 1u) {
            float x = ray[3 * i] * c, y = ray[3 * i] * s, lift = ray[3 * i + 1];
            float base = fall * maxf(x * nx + y * ny + lift * nz, 0.0f) * ray[3 * i + 2];
            float3 d = x * occ.a + y * occ.b + lift * occ.n;
            float ex = exp(eta * d.x), ey = exp(eta * d.y), ez = exp(eta * d.z);
            float w[6] = {base * ey, base / ey, base * ex, base / ex, base * ez, base / ez};
            int open = ((occ.mask >> i) & 1u) == 0u;
            for (int k = 0; k < 6; ++k) {
                total[k] += w[k];
                if (open)
                    seen[k] += w[k];
            }
        }
        float c_next = c * GOLDEN_COS - s * GOLDEN_SIN;
        s = s * GOLDEN_COS + c * GOLDEN_SIN;
        c = c_next;
    }
    for (int k = 0; k < 6; ++k)
        share[k] = total[k] > 1.0e-30f ? seen[k] / total[k] : 1.0f;
}

/* The share of a lobe (axis, η) that sharp lobe k's rays (about ray_axis, ray_eta) see unblocked
 * (shading.lobe_ray_share): the rays of `known` (bit i: ray i traced), made again (lobe_ray_direction, turned by
 * pixel `turn`), each weighted by G(ω)(n·ω)⁺ and its solid-angle weight cos³ (its cosine to ray_axis, cubed); a
 * ray below the geometric horizon, not traced, has its bit clear. */
CL_INLINE float lobe_ray_share(float3 ray_axis, float ray_eta, float3 axis, float eta, float3 n, uint mask, int k,
                               uint known, int turn)
{
    float3 a, b;
    disk_basis(ray_axis, &a, &b);
    float total = 0.0f, seen = 0.0f;
    for (int i = 0; i < LOBE_RAYS; ++i) {
        if ((known >> i) & 1u) {
            float3 d = lobe_ray_direction(a, b, ray_axis, ray_eta, i, turn);
            float c = dot3(d, ray_axis);
            float w = exp(eta * (dot3(d, axis) - 1.0f)) * maxf(dot3(d, n), 0.0f) * c * c * c;
            total = total + w;
            if (((mask >> (k * LOBE_RAYS + i)) & 1u) == 0u)
                seen = seen + w;
        }
    }
    return total > 1.0e-30f ? seen / total : 1.0f;
}

/* The ray lobe environment lobe e is shadowed through (shading.nearest_ray_lobe): itself if it is one
 * (e < n_sharp), else, for a lobe of η ≥ SHARP_LOBE_ETA, the ray lobe nearest its axis if the axis lies in that
 * lobe's cap; -1: none (the SSDF then). */
CL_INLINE int nearest_ray_lobe(__global const float *env_sgs, int n_sharp, int e, float3 axis, float eta)
{
    if (e < n_sharp)
        return e;
    int best = -1;
    if (eta >= SHARP_LOBE_ETA) {
        float best_c = -2.0f;
        for (int k = 0; k < n_sharp; ++k) {
            float c = env_sgs[7 * k] * axis.x + env_sgs[7 * k + 1] * axis.y + env_sgs[7 * k + 2] * axis.z;
            if (c > best_c) {
                best_c = c;
                best = k;
            }
        }
        if (best >= 0 && best_c < maxf(1.0f - 2.0f / env_sgs[7 * best + 3], LOBE_COS_MIN))
            best = -1;
    }
    return best;
}

/* The share of ∫ G(ω; axis, η, 1)(n·ω)⁺ dω left unoccluded (1 without an SSDF): the SSDF's, blended for
 * broad lobes with the occlusion rays' (ray_weight; a mask with no bit set sees it all). rays_given ≥ 0: the
 * rays' share, found already (axis_ray_shares); < 0: found here. */
CL_INLINE float environment_share_at(Table tab, float theta, float3 axis, float eta, EtaRow row, SurfacePoint s,
                                     Occlusion occ, float rays_given)
{
    float share = ssdf_visible_at(tab, theta, axis, row, s.n);
    float weight = ray_weight(eta, occ.samples);
    if (weight > 0.0f) {
        float rays = rays_given >= 0.0f ? rays_given : occ.mask != 0u ? ray_share(axis, eta, s.n, occ) : 1.0f;
        share = weight * rays + (1.0f - weight) * share;
    }
    return share;
}

/* The share of a lobe that the occlusion rays alone shadow (ray_weight 1): environment_share_at's, with no SSDF
 * lookup (the SSDF's share would weigh 0). */
CL_INLINE float rays_alone_share(float3 axis, float eta, float3 n, Occlusion occ)
{
    return occ.mask != 0u ? ray_share(axis, eta, n, occ) : 1.0f;
}

/* environment_share_at for environment lobe e (1 without an SSDF), its θd at the pixel the blend of its three
 * vertices' (env_theta (V, n_env), ssdf.ssdf_at_axes: θd is linear in the coefficients). Warp's takes e = −1 for
 * a specular lobe's lookup; the specular loop here calls environment_share_at with its cached θd instead. */
CL_INLINE float environment_share(Table tab, __global const float *env_theta, int n_env, int e, float3 axis,
                                  float eta, EtaRow row, SurfacePoint s, int has_ssdf, Occlusion occ, float rays_given)
{
    if (has_ssdf == 0)
        return 1.0f;
    if (ray_weight(eta, occ.samples) >= 1.0f)
        return rays_given >= 0.0f ? rays_given : rays_alone_share(axis, eta, s.n, occ);
    __global const float *theta = env_theta + e;
    return environment_share_at(tab, s.w0 * theta[s.i0 * n_env] + s.w1 * theta[s.i1 * n_env]
                                + s.w2 * theta[s.i2 * n_env], axis, eta, row, s, occ, rays_given);
}

/* Per channel, the exact irradiance E = lobes + residual over the environment lobes' own irradiance:
 * the diffuse term keeps the lobes' shadows and takes E's magnitude. Where the lobes hold under a
 * thousandth of E the ratio stops at 1000, so the term never passes kd·E. */
CL_INLINE float irradiance_scale1(float lobes, float residual)
{
    float e = maxf(lobes + residual, 0.0f);
    return e / maxf(maxf(lobes, 1.0e-3f * e), 1.0e-30f);
}

CL_INLINE float3 irradiance_scale(float3 lobes, float3 residual)
{
    return (float3)(irradiance_scale1(lobes.x, residual.x), irradiance_scale1(lobes.y, residual.y),
                    irradiance_scale1(lobes.z, residual.z));
}

/* Σ over the lights whose shadow ray reached them of ∫ G(axis, η)·light SG·(n·ω)⁺. */
CL_INLINE float3 lobe_from_lights(Table tab, float3 axis, float eta, SurfacePoint s, int n_lights,
                                  __global const float *lights, __global const uchar *vis)
{
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    for (int l = 0; l < n_lights; ++l) {
        if (vis[l] == 0)
            continue;
        __global const float *row = lights + 8 * l;
        float3 la = light_axis(row, s.pos);
        float le = light_sharpness(row, s.pos);
        out = out + light_amplitude(row, s.pos, le) * (product_integral(tab, axis, eta, la, le, s.n) * (float)vis[l] / 255.0f);
    }
    return out;
}

/* (λ, μ) of an anisotropic BRDF's NDF as one ASG (brdf.ndf_bandwidths). */
CL_INLINE float2 ndf_bandwidths(int kind, float p1, float p2)
{
    if (kind == ANISOTROPIC_WARD)
        return (float2)(1.0f / (p1 * p1), 1.0f / (p2 * p2));
    return (float2)(0.5f * p1, 0.5f * p2);
}

/* An anisotropic BRDF's NDF as one ASG about the shading normal, in the frame of the mesh tangent, amplitude 1. */
CL_INLINE Asg ndf_asg(int kind, float p1, float p2, SurfacePoint s)
{
    float2 bw = ndf_bandwidths(kind, p1, p2);
    Asg g;
    g.x = s.t;
    g.y = s.b;
    g.z = s.n;
    g.c = 1.0f;
    g.lam = bw.x;
    g.mu = bw.y;
    return g;
}

/* ndf_asg warped to the light directions (Xu Eq. 23–26), its bandwidths at least 1e−6. */
CL_INLINE Asg warped_ndf(int kind, float p1, float p2, SurfacePoint s, float3 wo)
{
    Asg w = asg_warp(ndf_asg(kind, p1, p2, s), wo);
    w.lam = maxf(w.lam, 1.0e-6f);
    w.mu = maxf(w.mu, 1.0e-6f);
    return w;
}

/* An effective material's ASG lobe convolved with its small-scale BRDF's NDF: an anisotropic one's ASG turned by
 * the lobe's tangent order (oc, os) (asg.convolve_asg), else its SG (Xu Eq. 18). */
CL_INLINE Asg small_scale_convolved(Asg g, int kind, float p1, float p2, float eta_s, float oc, float os)
{
    if (kind == ANISOTROPIC_WARD || kind == ASHIKHMIN_SHIRLEY) {
        float2 bw = ndf_bandwidths(kind, p1, p2);
        return asg_convolve_asg(g, bw.x, bw.y, oc, os);
    }
    return asg_convolve_sg(g, eta_s, 1.0f);
}

/* The cosine at which Ashikhmin–Shirley's ρd is read for a light lobe (shading.lobe_cosine). */
CL_INLINE float lobe_cosine(float c, float eta)
{
    float r = eta / 3.0f - eta * eta * eta / 45.0f;
    if (eta >= 1.0e-2f) {
        float e2 = exp(-2.0f * eta);
        r = (1.0f + e2) / (1.0f - e2) - 1.0f / eta;
    }
    return r * maxf(c, 0.0f) + (1.0f - r) * AS_UNIFORM_COS;
}

/* f_d of an analytic material towards a light lobe: kd/π, or Ashikhmin–Shirley's ρd (kd = Rd/π here) at the
 * lobe's cosine. */
CL_INLINE float3 analytic_diffuse(int kind, float3 kd, float3 ks, float3 axis, float eta, SurfacePoint s, float cos_o)
{
    if (kind == ASHIKHMIN_SHIRLEY)
        return ashikhmin_shirley_diffuse(kd * SHADE_PI, ks, lobe_cosine(dot3(axis, s.n), eta), cos_o);
    return kd;
}

/* Unit axis across unit direction la (shading.light_axes): the hint with its part along la removed, or Duff et
 * al.'s basis vector where the hint lies along la. */
CL_INLINE float3 light_across(float3 la, float3 hint)
{
    float3 x = hint - dot3(hint, la) * la;
    float l2 = dot3(x, x);
    if (l2 > 1.0e-6f)
        return x / sqrt(l2);
    float sgn = la.z < 0.0f ? -1.0f : 1.0f;
    float a = -1.0f / (sgn + la.z);
    return (float3)(1.0f + sgn * la.x * la.x * a, sgn * la.x * la.y * a, -sgn * la.x);
}

/* f_s·(n·ωi)⁺ towards d (made unit here). */
CL_INLINE float3 specular_cos(int kind, float3 ks, float p1, float p2, SurfacePoint s, float3 d, float3 wo)
{
    float3 wi = normalize3(d);
    return analytic_specular(kind, ks, p1, p2, s.t, s.b, s.n, wi, wo) * maxf(dot3(s.n, wi), 0.0f);
}

CL_INLINE float specular_cos_sum(int kind, float3 ks, float p1, float p2, SurfacePoint s, float3 d, float3 wo)
{
    float3 f = specular_cos(kind, ks, p1, p2, s, d, wo);
    return f.x + f.y + f.z;
}

/* f_s·(n·ωi)⁺'s mean over a light, a Gaussian of variance var_l per axis about la (shading.light_mean): read where
 * the light's and the lobe's Gaussians overlap most (`lobe`: its centre z, axis x turned across the light
 * (light_across), variances 1/(2λ), 1/(2μ)) and at ± their product's σ along two axes, its logarithm taken as a
 * quadratic there and integrated against the light in closed form. */
CL_INLINE float3 light_mean(int kind, float3 ks, float p1, float p2, SurfacePoint s, float3 wo, float3 la, Asg lobe,
                            float var_l)
{
    float3 ax = light_across(la, lobe.x);
    float3 axes[2] = {ax, cross3(la, ax)};
    float var_k[2] = {0.5f / lobe.lam, 0.5f / lobe.mu};
    float xk[2], sk[2];
    float3 point = la;
    for (int k = 0; k < 2; ++k) {
        float d = dot3(lobe.z - la, axes[k]);
        xk[k] = d * var_l / (var_l + var_k[k]);
        sk[k] = sqrt(var_l * var_k[k] / (var_l + var_k[k]));
        point = point + xk[k] * axes[k];
    }
    float3 f0 = specular_cos(kind, ks, p1, p2, s, point, wo);
    float c0 = f0.x + f0.y + f0.z;
    if (c0 <= 0.0f) /* (where any of the five is 0, f_s·(n·ωi)⁺ at the light's centre) */
        return specular_cos(kind, ks, p1, p2, s, la, wo);
    float l0 = log(c0);
    float expo = 0.0f;
    float scale = 1.0f;
    for (int k = 0; k < 2; ++k) {
        float lo = specular_cos_sum(kind, ks, p1, p2, s, point - sk[k] * axes[k], wo);
        float hi = specular_cos_sum(kind, ks, p1, p2, s, point + sk[k] * axes[k], wo);
        if (lo <= 0.0f || hi <= 0.0f)
            return specular_cos(kind, ks, p1, p2, s, la, wo);
        float log_lo = log(lo);
        float log_hi = log(hi);
        float g = (log_hi - log_lo) / (2.0f * sk[k]);
        float c = minf((log_hi + log_lo - 2.0f * l0) / (sk[k] * sk[k]), 0.0f);
        float big_a = 1.0f / var_l - c;
        float big_b = g - c * xk[k];
        expo += -g * xk[k] + 0.5f * c * xk[k] * xk[k] + big_b * big_b / (2.0f * big_a);
        scale /= sqrt(var_l * big_a);
    }
    return f0 * (scale * exp(minf(expo, LIGHT_BLUR_EXP_MAX)));
}

/* The scale of a row's moment table (shading.moment_sharpness): the NDF's sharpness, or 2·√(λμ) of its ASG. */
CL_INLINE float moment_sharpness(int kind, float p1, float p2)
{
    if (kind == ANISOTROPIC_WARD || kind == ASHIKHMIN_SHIRLEY) {
        float2 bw = ndf_bandwidths(kind, p1, p2);
        return 2.0f * sqrt(bw.x * bw.y);
    }
    return ndf_sharpness(kind, p1);
}

/* The ASG of an analytic row's f_s·(n·ωi)⁺ moments, read from its moment table (shading.moment_table) at texture
 * `slot` for its moment_sharpness eta (shading.tabulated_moments): linear in √cos θo and across the columns — an
 * isotropic row's p1 factors (its parameter map's p1_factor here; the first's log2 in texel (0, W)'s third
 * channel), else φo folded into [0, π/2], a view in another quadrant of the tangent frame mirroring the out-of-plane
 * angle and the correlation. */
CL_INLINE Asg tabulated_moments(__global const int *tex_info, __global const float *tex_data, int slot,
                                SurfacePoint s, float3 wo, int kind, float eta, float p1_factor)
{
    int off = tex_info[4 * slot];
    int rows = tex_info[4 * slot + 1];
    int width = tex_info[4 * slot + 2] / 2;
    float cos_o = clamp(dot3(wo, s.n), 0.0f, 1.0f);
    float3 side = wo - cos_o * s.n;
    float length = sqrt(dot3(side, side));
    side = length > 1.0e-6f ? side / length : s.t;
    float3 across = cross3(s.n, side);
    float wx = dot3(wo, s.t);
    float wy = dot3(wo, s.b);
    float pos = sqrt(cos_o) * (float)(rows - 1);
    int i0 = min((int)pos, rows - 2);
    float fi = pos - (float)i0;
    int j0 = 0, j1 = 0;
    float fj = 0.0f;
    float mirror = 1.0f;
    if (width > 1) {
        float col;
        if (kind == ANISOTROPIC_WARD || kind == ASHIKHMIN_SHIRLEY) {
            col = atan2(fabs(wy), fabs(wx)) / (0.5f * SHADE_PI) * (float)(width - 1);
            if ((wx < 0.0f) != (wy < 0.0f))
                mirror = -1.0f;
        } else {
            col = clamp(MOMENT_P1_STEPS * (log2(maxf(p1_factor, 1.0e-30f)) - tex_data[3 * (off + width) + 2]), 0.0f,
                        (float)(width - 1));
        }
        j0 = min((int)col, width - 2);
        j1 = j0 + 1;
        fj = col - (float)j0;
    }
    int row0 = off + i0 * 2 * width;
    int row1 = row0 + 2 * width;
    float3 first = (load3(tex_data, row0 + j0) * (1.0f - fj) + load3(tex_data, row0 + j1) * fj) * (1.0f - fi)
                   + (load3(tex_data, row1 + j0) * (1.0f - fj) + load3(tex_data, row1 + j1) * fj) * fi;
    float3 second = (load3(tex_data, row0 + width + j0) * (1.0f - fj) + load3(tex_data, row0 + width + j1) * fj)
                        * (1.0f - fi)
                    + (load3(tex_data, row1 + width + j0) * (1.0f - fj) + load3(tex_data, row1 + width + j1) * fj)
                        * fi;
    float scale = sqrt(eta);
    float theta = clamp(atan2(length, cos_o) + first.x / scale, 0.0f, 0.5f * SHADE_PI);
    float beta = mirror * second.x / scale;
    float c = cos(theta);
    float sn = sin(theta);
    float3 z = cos(beta) * (c * s.n - sn * side) + sin(beta) * across;
    float3 u = -(c * side + sn * s.n);
    u = normalize3(u - dot3(u, z) * z);
    float3 v = cross3(z, u);
    float var_u = exp(first.y) / eta;
    float var_v = exp(first.z) / eta;
    float cov = mirror * second.y * sqrt(var_u * var_v);
    float angle = 0.5f * atan2(2.0f * cov, var_u - var_v);
    float ca = cos(angle);
    float sa = sin(angle);
    Asg g;
    g.z = z;
    g.x = ca * u + sa * v;
    g.y = cross3(z, g.x);
    g.c = 1.0f;
    g.lam = 0.5f / maxf(var_u * ca * ca + 2.0f * cov * ca * sa + var_v * sa * sa, MOMENT_VAR_MIN);
    g.mu = 0.5f / maxf(var_u * sa * sa - 2.0f * cov * ca * sa + var_v * ca * ca, MOMENT_VAR_MIN);
    return g;
}

/* An analytic BRDF's specular radiance from the lights: f_s·(n·ωi)⁺'s mean over each light's SG (light_mean; `lobe`
 * the warped lobe's shape) times the light's irradiance at normal incidence and its visible share. */
CL_INLINE float3 analytic_from_lights(int kind, float3 ks, float p1, float p2, SurfacePoint s, float3 wo, Asg lobe,
                                      int n_lights, __global const float *lights, __global const uchar *vis)
{
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    for (int l = 0; l < n_lights; ++l) {
        if (vis[l] == 0)
            continue;
        __global const float *row = lights + 8 * l;
        float3 la = light_axis(row, s.pos);
        float le = light_sharpness(row, s.pos);
        float3 f = light_mean(kind, ks, p1, p2, s, wo, la, lobe, 1.0f / le);
        out = out + f * light_amplitude(row, s.pos, le) * (sg_integral(le) * (float)vis[l] / 255.0f);
    }
    return out;
}

/* ASG lobe row `lobe` of an effective material ([z, 0, x, λ, μ] in the tile frame) in the world, unit amplitude. */
CL_INLINE Asg lobe_asg(__global const float *lobe, SurfacePoint s)
{
    Asg g;
    g.z = lobe[0] * s.t + lobe[1] * s.b + lobe[2] * s.n;
    g.x = lobe[4] * s.t + lobe[5] * s.b + lobe[6] * s.n;
    g.y = cross3(g.z, g.x);
    g.lam = lobe[7];
    g.mu = lobe[8];
    g.c = 1.0f;
    return g;
}

/* (G ⊛ SG_η)(h) of a unit-amplitude ASG (asg.convolve_sg_local: Xu Eq. 18's bandwidths and amplitude, a
 * shape exact for a delta lobe too). */
CL_INLINE float asg_convolved_at(Asg g, float eta, float3 h)
{
    float nu = 0.5f * eta;
    float lam_c = harmonic(g.lam, nu);
    float mu_c = harmonic(g.mu, nu);
    float a = dot3(h, g.x);
    float b = dot3(h, g.y);
    float t = dot3(h, g.z);
    if (t <= 0.0f)
        return 0.0f;
    float sx = g.lam > 0.0f ? clamp(lam_c / g.lam, 0.0f, 1.0f) : 1.0f;
    float sy = g.mu > 0.0f ? clamp(mu_c / g.mu, 0.0f, 1.0f) : 1.0f;
    float r2 = a * a + b * b;
    float w = r2 > 0.0f ? (sx * a * a + sy * b * b) / r2 : 0.5f * (sx + sy);
    float k = 2.0f / (1.0f + minf(t, 1.0f));
    float expo = lam_c * a * a * pow(k, 1.0f - sx) + mu_c * b * b * pow(k, 1.0f - sy);
    return SHADE_PI / sqrt((g.lam + nu) * (g.mu + nu)) * pow(t, w) * exp(-expo);
}

/* The environment's mean radiance under a warped ASG lobe: prefiltered lookups along its broad axis, as many as
 * shading.tap_plan asks (shading.asg_prefiltered). */
CL_INLINE float3 asg_prefiltered(__global const float *maps, __global const float *levels, int n_levels, Asg g,
                                 float sharpness_max)
{
    float3 long_axis = g.lam > g.mu ? g.y : g.x;
    float var_long = 0.5f / minf(g.lam, g.mu);
    float var_tap = maxf(0.5f / maxf(g.lam, g.mu), ASG_TAP_SHARE * var_long);
    float spread = sqrt(maxf(var_long - var_tap, 0.0f));
    float ratio = spread / sqrt(var_tap);
    if (ratio <= ROUND_SPREAD)
        return prefiltered(maps, levels, n_levels, g.z, minf(2.0f * sqrt(g.lam * g.mu), sharpness_max));
    LevelPair tap_levels = prefiltered_levels(levels, n_levels, minf(1.0f / var_tap, sharpness_max));
    int count = 0;
    for (int k = 0; k < 4; ++k)
        if (count == 0 && HERMITE_GAPS[k] * ratio <= TAP_GAP)
            count = k + 2;
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    if (count > 0) {
        int first = (count - 2) * (count + 1) / 2;
        for (int k = 0; k < count; ++k) {
            float3 d = normalize3(g.z + (HERMITE_NODES[first + k] * spread) * long_axis);
            out = out + HERMITE_WEIGHTS[first + k] * prefiltered_at(maps, tap_levels, d);
        }
        return out;
    }
    count = min(ASG_TAPS, 1 + (int)ceil(2.0f * TAP_SPAN * ratio / TAP_GAP));
    float step = 2.0f * TAP_SPAN / (float)(count - 1);
    float total = 0.0f;
    for (int k = 0; k < count; ++k) {
        float node = -TAP_SPAN + step * (float)k;
        float weight = exp(-0.5f * node * node);
        total += weight;
        float3 d = normalize3(g.z + (node * spread) * long_axis);
        out = out + weight * prefiltered_at(maps, tap_levels, d);
    }
    return out / total;
}

/* ∫ of a unit ASG: Xu's Eq. 10 where both bandwidths pass ASG_EQ10_MIN, else the exact quadrature
 * (asg.shade_integral). */
CL_INLINE float asg_shade_integral(float lam, float mu)
{
    if (minf(lam, mu) > ASG_EQ10_MIN)
        return asg_integral_eq10(lam, mu);
    return asg_unit_integral(lam, mu);
}

/* An ASG lobe's specular radiance from the lights: the material's own f̄ at each light's direction
 * (M(h·l)·μ_j(l, ωo)/cos θi·(G_j ⊛ D_s)(h)) times the light's irradiance, cosine and visible share. `conv` is
 * G_j ⊛ D_s (small_scale_convolved), evaluated as it is for an anisotropic D_s; an SG's takes the shape that is
 * exact for a delta lobe too (asg_convolved_at). */
CL_INLINE float3 asg_from_lights(Asg g, Asg conv, float eta_s, int kind, float3 ks, float p1, float p2,
                                 __global const float *eff_tables, int base, int k2, int j_count, int j, int k,
                                 const int *oo, const float *ow, SurfacePoint s, float3 wo, Table tab, int n_lights,
                                 __global const float *lights, __global const uchar *vis)
{
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    for (int l = 0; l < n_lights; ++l) {
        if (vis[l] == 0)
            continue;
        __global const float *row = lights + 8 * l;
        float3 la = light_axis(row, s.pos);
        float le = light_sharpness(row, s.pos);
        float3 h = normalize3(la + wo);
        float shape = (kind == ANISOTROPIC_WARD || kind == ASHIKHMIN_SHIRLEY) ? asg_eval(conv, h)
                                                                              : asg_convolved_at(g, eta_s, h);
        if (shape <= 0.0f)
            continue;
        float3 scale = specular_scale(kind, ks, p1, p2, dot3(h, la));
        float3 mu = table_rgb(eff_tables, base, k2, j_count, j, to_local(s, la), k, oo, ow);
        float3 e = light_irradiance(tab, row, s.pos, s.n, la, le, vis[l]);
        out = out + scale * mu * e * shape;
    }
    return out;
}

/* Never NaN, inf or negative (a degenerate normal, say, must not poison the image). By the bits, so
   that a program built with -cl-fast-relaxed-math (which may assume finite values) keeps the guard:
   all exponent bits set is inf or NaN; the sign bit is a negative (or -0, which 0 replaces alike). */
CL_INLINE float finite_channel(float x)
{
    uint bits = as_uint(x);
    return ((bits & 0x7f800000u) == 0x7f800000u || (bits >> 31) != 0u || x >= 3.0e38f) ? 0.0f : x;
}

CL_INLINE float3 finite_radiance(float3 v)
{
    return (float3)(finite_channel(v.x), finite_channel(v.y), finite_channel(v.z));
}

__kernel void shade_pixels(
    __global const int *face,           /* (P,) G-buffer face, -1 = miss */
    __global const float *bary,         /* (P, 2) weights of vertices 1 and 2 */
    __global const uchar *light_vis,    /* (P, L) visible share in 255ths */
    __global const uint *occlusion,     /* (P,) occlusion-ray masks */
    const int occlusion_samples,
    __global const uint *lobe_occlusion, /* (P,) sharp lobes' ray masks */
    const int n_sharp,
    const int part_index, const int part_count, /* the anti-aliasing sample's rays of each set (ray_part) */
    const int block_width,              /* > 0: the rays shared in pixel blocks (pixel_part) ... */
    const int block_side,               /* ... of this side at most (2 or 4; set_block_side) ... */
    __global const uint *occlusion_known, /* ... (P,) the occlusion rays each pixel was lent */
    __global const uint *lobe_known,    /* (P,) and the lobe rays */
    __global const int *faces,          /* (F, 3) */
    __global const float *positions,    /* (V, 3) */
    __global const float *normals,      /* (V, 3) */
    __global const float *tangents,     /* (V, 3) */
    __global const int *face_material,  /* (F,) */
    const float4 eye, const float4 forward, const float4 right, const float4 up, /* Camera.packed() */
    const float cam_w, const float cam_h,
    const int n_lights, __global const float *lights,                 /* (L, 8) */
    const int n_env, __global const float *env_sgs,                   /* (K, 7) [axis, η, rgb] */
    const int axis_lobes,               /* the first row of the six shadow lobes along the axes, or -1 */
    __global const float *env_residual, const int residual_h, const int residual_w, /* (H, W, 3) */
    __global const float *env_maps, const int n_levels, __global const float *env_levels,
    const int has_ssdf, const int ssdf_res, const int n_basis, const int n_coeffs,
    __global const float *ssdf_basis, __global const float *ssdf_coeffs,
    __global const float *env_theta,    /* (V, n_env) θd towards each environment lobe at each vertex */
    __global const float *disk_radii,   /* (Σ_S S, 3) trace.disk_radii */
    __global const float *table, const int table_rows, const int table_cols, const float log_lo, const float log_hi,
    const float sharpness_max,
    __global const int *mat_info,       /* (Mat, 4) */
    __global const float *analytic,     /* (A, 9) */
    __global const int *eff_info,       /* (E, 8) */
    __global const float *eff_lobes,    /* (ΣJ, EFF_LOBE_WIDTH) */
    __global const float *eff_sub,      /* (Σn_sub, 9) */
    __global const float *eff_tables, __global const float *eff_diffuse,
    __global const float *uvs,          /* (V, 2) */
    __global const int *tex_info,       /* (T, 4) [texel offset, H, W, 0] */
    __global const float *tex_data,     /* (Σ H·W, 3) */
    const int n_pixels, const int only_material,
    __global const uchar *changed,      /* only_changed: a pixel not flagged here (mark_changed) takes ... */
    __global const float *reference_radiance, /* ... (P, 3) this radiance, of the reference frame */
    const int only_changed,
    const int kept_mode,                /* 1: keep each lobe's shadowed amount and the irradiance scale, 2: read them */
    __global float *kept_amount,        /* (P, K) */
    __global float *kept_scale,         /* (P, 3) */
    __global float *radiance)           /* (P, 3) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    int f = face[p];
    if (only_changed != 0 && changed[p] == 0) {
        store3(radiance, p, load3(reference_radiance, p));
        return;
    }
    /* only that material's pixels: the others keep the radiance they have */
    if (only_material >= 0 && (f < 0 || face_material[f] != only_material))
        return;
    if (f < 0) {
        float3 d = camera_ray(forward, right, up, cam_w, cam_h, p);
        store3(radiance, p, prefiltered(env_maps, env_levels, n_levels, d, 1.0e30f));
        return;
    }
    Table tab = {table, table_rows, table_cols, log_lo, log_hi};
    SurfacePoint s = surface_point(faces, positions, normals, tangents, f, bary[2 * p], bary[2 * p + 1]);
    float3 wo = normalize3((float3)(eye.x, eye.y, eye.z) - s.pos);
    /* A back face is black: surfaces are one-sided, as the Monte Carlo reference sees them (its rays leave on the
     * viewer's side, behind the face, and meet it), not lit from the hemisphere of a normal turned from the eye. */
    if (seen_from_behind(load3(positions, s.i0), load3(positions, s.i1), load3(positions, s.i2), s.n, wo)) {
        store3(radiance, p, (float3)(0.0f, 0.0f, 0.0f));
        return;
    }
    float cos_o = maxf(dot3(wo, s.n), MIN_COS_VIEW);
    float3 wo_local = normalize3((float3)(dot3(wo, s.t), dot3(wo, s.b), cos_o));
    /* The occlusion rays' mask and frame (about the geometric normal on the camera's side, as traced), and
     * which rays of the occlusion and lobe ray sets this anti-aliasing sample traced: the pixel's own part, or,
     * with block_width > 0, those its pixel block lent it (share_block_masks' known bits). */
    int3 occlusion_part = pixel_part(occlusion_samples, part_index, part_count, block_width, block_side, p);
    int3 lobe_part = pixel_part(LOBE_RAYS, part_index, part_count, block_width, block_side, p);
    Occlusion occ = {0u, occlusion_samples, part_bits(occlusion_part.x, occlusion_part.y, occlusion_samples),
                     (float3)(1.0f, 0.0f, 0.0f), (float3)(0.0f, 1.0f, 0.0f), (float3)(0.0f, 0.0f, 1.0f),
                     1.0f, 0.0f, disk_radii};
    uint lobe_rays = part_bits(lobe_part.x, lobe_part.y, LOBE_RAYS);
    if (occlusion_samples > 0) {
        float turn = disk_turn(occlusion_part.z);
        occ.turn_c = cos(turn);
        occ.turn_s = sin(turn);
        occ.mask = occlusion[p];
        if (block_width > 0) {
            occ.known = occlusion_known[p];
            if (n_sharp > 0)
                lobe_rays = lobe_known[p];
        }
        float3 p0 = load3(positions, s.i0);
        float3 ng = normalize3(cross3(load3(positions, s.i1) - p0, load3(positions, s.i2) - p0));
        if (dot3(ng, wo) < 0.0f)
            ng = -ng;
        occ.n = ng;
        disk_basis(ng, &occ.a, &occ.b);
    }

    Ssdf ssdf = {ssdf_basis, ssdf_coeffs + s.i0 * n_coeffs, ssdf_coeffs + s.i1 * n_coeffs,
                 ssdf_coeffs + s.i2 * n_coeffs, s.w0, s.w1, s.w2, n_basis, ssdf_res};
    __global const uchar *vis = light_vis + p * n_lights;

    int mat = face_material[f];
    int kind = mat_info[4 * mat];
    int idx = mat_info[4 * mat + 1];
    int has_spec = mat_info[4 * mat + 2];
    int k = 0, k2 = 0, j_count = 0;
    int oo[4] = {0, 0, 0, 0};
    float ow[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    float3 kd = (float3)(0.0f, 0.0f, 0.0f);
    __global const int *ei = eff_info + 8 * idx;
    /* An analytic material's rows (one per SG lobe of its SG form; the first carries kd): a textured one
     * (slot >= 0) scales kd, ks and p1 by its maps at the pixel's UV, read once here into per-pixel factors. */
    float3 t_ks = (float3)(1.0f, 1.0f, 1.0f);
    float t_p1 = 1.0f;
    int a_kind = 0;
    float3 a_ks = (float3)(0.0f, 0.0f, 0.0f);
    if (kind == 0) {
        __global const float *row = analytic + 9 * idx;
        a_kind = (int)row[0];
        a_ks = (float3)(row[4], row[5], row[6]);
        float3 a_kd = (float3)(row[1], row[2], row[3]);
        int slot = mat_info[4 * mat + 3];
        if (slot >= 0) {
            float2 uv = s.w0 * (float2)(uvs[2 * s.i0], uvs[2 * s.i0 + 1])
                        + s.w1 * (float2)(uvs[2 * s.i1], uvs[2 * s.i1 + 1])
                        + s.w2 * (float2)(uvs[2 * s.i2], uvs[2 * s.i2 + 1]);
            a_kd = a_kd * texture_bilinear(tex_info, tex_data, slot, uv);
            t_ks = texture_bilinear(tex_info, tex_data, slot + 1, uv);
            t_p1 = texture_bilinear(tex_info, tex_data, slot + 2, uv).x;
        }
        kd = a_kd / SHADE_PI;
    } else {
        k = ei[0];
        k2 = k * k;
        j_count = ei[1];
        float oc[4];  /* (ωo's cosines: unused) */
        grid_bilinear(wo_local, k, oo, ow, oc);
    }
    float3 out = (float3)(0.0f, 0.0f, 0.0f);

    /* Diffuse: environment lobes (SSDF-shadowed, scaled to the exact irradiance), then lights (shadow rays). */
    /* Each lobe's shadowed amount and the irradiance scale depend on the pixel, the environment and the rays, not
     * on the material: kept_mode 1 keeps them per pixel, 2 reads them back (a material edit's shade), 0 neither. */
    float3 lobes_irradiance = (float3)(0.0f, 0.0f, 0.0f);
    /* The six shadow lobes along the axes, where the occlusion rays weigh in their shadow (environment_share's
     * ray_weight > 0): the rays' shares from one walk of the rays (axis_ray_shares), which environment_share then
     * takes (alone, or blended with the SSDF's). */
    float axis_shares[6] = {1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f};
    int axis_end = -1;
    if (axis_lobes >= 0 && has_ssdf != 0 && kept_mode != 2) {
        float axis_eta = env_sgs[7 * axis_lobes + 3];
        if (ray_weight(axis_eta, occ.samples) > 0.0f) {
            axis_end = axis_lobes + 6;
            if (occ.mask != 0u)
                axis_ray_shares(axis_eta, s.n, occ, axis_shares);
        }
    }
    for (int e = 0; e < n_env; ++e) {
        __global const float *lobe = env_sgs + 7 * e;
        float3 axis = (float3)(lobe[0], lobe[1], lobe[2]);
        float3 radiance_e = (float3)(lobe[4], lobe[5], lobe[6]);
        float amount;
        if (kept_mode == 2) {
            amount = kept_amount[p * n_env + e];
        } else {
            EtaRow row = eta_row(tab, lobe[3]);
            amount = cosine_integral(tab, axis, lobe[3], row, s.n);
            lobes_irradiance = lobes_irradiance + radiance_e * amount;
            int ray_lobe = nearest_ray_lobe(env_sgs, n_sharp, e, axis, lobe[3]);
            if (ray_lobe >= 0) { /* a sharp lobe: through its own rays, or those of the ray lobe whose cap holds its axis */
                __global const float *r = env_sgs + 7 * ray_lobe;
                amount = amount * lobe_ray_share((float3)(r[0], r[1], r[2]), r[3], axis, lobe[3], s.n,
                                                 lobe_occlusion[p], ray_lobe, lobe_rays, lobe_part.z);
            } else
                amount = amount * environment_share(tab, env_theta, n_env, e, axis, lobe[3], row, s, has_ssdf, occ,
                                                    e >= axis_lobes && e < axis_end ? axis_shares[e - axis_lobes]
                                                                                    : -1.0f);
            if (kept_mode == 1)
                kept_amount[p * n_env + e] = amount;
        }
        float3 fd = analytic_diffuse(a_kind, kd, a_ks, axis, lobe[3], s, cos_o);
        if (kind != 0)
            fd = effective_diffuse(ei, eff_sub, eff_diffuse, k2, lobe[3], to_local(s, axis), k, oo, ow);
        out = out + fd * radiance_e * amount;
    }
    float3 scale;
    if (kept_mode == 2) {
        scale = load3(kept_scale, p);
    } else {
        scale = irradiance_scale(lobes_irradiance, equirect_bilinear_dir(env_residual, 0, residual_h, residual_w, s.n));
        if (kept_mode == 1)
            store3(kept_scale, p, scale);
    }
    out = out * scale;
    for (int l = 0; l < n_lights; ++l) {
        if (vis[l] == 0)
            continue;
        __global const float *row = lights + 8 * l;
        float3 axis = light_axis(row, s.pos);
        float eta = light_sharpness(row, s.pos);
        float3 fd = analytic_diffuse(a_kind, kd, a_ks, axis, eta, s, cos_o);
        if (kind != 0)
            fd = effective_diffuse(ei, eff_sub, eff_diffuse, k2, eta, to_local(s, axis), k, oo, ow);
        out = out + fd * light_irradiance(tab, row, s.pos, s.n, axis, eta, vis[l]);
    }

    /* Specular: each warped lobe against the prefiltered environment and each light. */
    if (has_spec != 0) {
        int n_sub = 1;
        int n_lobes = has_spec;  /* an analytic material's lobe rows */
        if (kind != 0) {
            n_sub = ei[2];
            n_lobes = j_count;
        }
        /* Lobe by lobe, then its material sub-rows: an effective material's SG lobe reflects about the same axis
         * for every sub-row, so its SSDF angle and table cell are found once (lobe_cached). (kernels/shade.py
         * keeps sub-row by sub-row: the same caching measured slower under Warp's CUDA code, faster here.) */
        for (int j = 0; j < n_lobes; ++j) {
            int lobe_cached = 0;
            float lobe_theta = 0.0f;
            int lobe_ii[4];
            float lobe_iw[4], lobe_ic[4];
            for (int sub_i = 0; sub_i < n_sub; ++sub_i) {
                float3 axis;
                float eta;
                float3 amp;
                int with_lights = 1;
                float cap = -1.0f; /* Ashikhmin–Shirley's cap on the cosine integral (shading.capped_cosine_integral) */
                Asg tap; /* an ASG lobe's warped shape, for the anisotropic lookup (asg_prefiltered) */
                int taps = 0;
                float3 env_scale = (float3)(1.0f); /* the environment term's scale: an analytic row's correction */
                if (kind == 0) {
                    __global const float *row = analytic + 9 * (idx + j);
                    int r_kind = (int)row[0];
                    env_scale = specular_correction(tex_info, tex_data, 1 + 2 * (idx + j), wo_local, r_kind, t_p1);
                    float3 r_ks = (float3)(row[4], row[5], row[6]) * t_ks;
                    float r_p1 = row[7] * t_p1;
                    amp = specular_scale(r_kind, r_ks, r_p1, row[8], cos_o);
                    /* The lights by f_s itself (Xu 2013 §5.2), averaged over each light's size. */
                    with_lights = 0;
                    Asg shape;
                    if (r_kind == ANISOTROPIC_WARD || r_kind == ASHIKHMIN_SHIRLEY) {
                        /* The environment's magnitude and occlusion through the NDF's warped ASG, as an effective
                         * material's ASG lobe below. */
                        Asg w = warped_ndf(r_kind, r_p1, row[8], s, wo);
                        eta = minf(2.0f * sqrt(w.lam * w.mu), sharpness_max);
                        axis = w.z;
                        amp = amp * (w.c * asg_shade_integral(w.lam, w.mu) / sg_integral(eta));
                        if (r_kind == ASHIKHMIN_SHIRLEY)
                            cap = cos_o;
                        shape = w;
                    } else {
                        axis = normalize3(2.0f * cos_o * s.n - wo);
                        eta = ndf_sharpness(r_kind, r_p1) / (4.0f * cos_o);
                        shape.z = axis;
                        shape.x = s.t;
                        shape.y = s.b;
                        shape.lam = 0.5f * minf(eta, sharpness_max);
                        shape.mu = shape.lam;
                        shape.c = 1.0f;
                    }
                    out = out + analytic_from_lights(r_kind, r_ks, r_p1, row[8], s, wo, shape, n_lights, lights, vis);
                    /* The environment where f_s·cos θi itself lies, not where the warp puts it; nothing for a view
                     * below the shading normal's horizon, where f_s is 0. */
                    if (dot3(wo, s.n) > 0.0f) {
                        tap = tabulated_moments(tex_info, tex_data, 2 + 2 * (idx + j), s, wo, r_kind,
                                                moment_sharpness(r_kind, r_p1, row[8]), t_p1);
                        taps = 1;
                    } else {
                        amp = (float3)(0.0f, 0.0f, 0.0f);
                    }
                } else {
                    __global const float *sub = eff_sub + 9 * (ei[4] + sub_i);
                    __global const float *lobe = eff_lobes + EFF_LOBE_WIDTH * (ei[3] + j);
                    float3 xi = lobe[0] * s.t + lobe[1] * s.b + lobe[2] * s.n;
                    float c_oj = dot3(wo, xi);
                    int s_kind = (int)sub[0];
                    float s_p1 = sub[7];
                    float3 s_ks = (float3)(sub[4], sub[5], sub[6]);
                    float eta_s = ndf_sharpness(s_kind, s_p1);
                    int base = ei[5] + sub_i * k2 * k2 * j_count * 3;
                    int asg_lobes = ei[7] == ASG_LOBES;
                    Asg g, conv;
                    if (asg_lobes) {
                        /* Xu 2013: the lights by the material's own f̄ at their directions, whichever way the
                         * lobe faces; the environment below through the warped lobe's equal-integral SG. */
                        g = lobe_asg(lobe, s);
                        __global const float *order = eff_lobes + EFF_LOBE_WIDTH * (ei[3] + j_count * (1 + sub_i) + j);
                        conv = small_scale_convolved(g, s_kind, s_p1, sub[8], eta_s, order[0], order[1]);
                        out = out + asg_from_lights(g, conv, eta_s, s_kind, s_ks, s_p1, sub[8], eff_tables, base, k2,
                                                    j_count, j, k, oo, ow, s, wo, tab, n_lights, lights, vis);
                    }
                    if (c_oj <= 0.0f)
                        continue;
                    float3 scale = specular_scale(s_kind, s_ks, s_p1, sub[8], c_oj);
                    if (scale.x + scale.y + scale.z <= 0.0f)
                        continue;
                    if (asg_lobes) {
                        Asg c = conv;
                        Asg w = asg_warp(c, wo);
                        float lam = maxf(w.lam, 1.0e-6f);
                        float mu_w = maxf(w.mu, 1.0e-6f);
                        eta = 2.0f * sqrt(lam * mu_w);
                        axis = w.z;
                        float3 mu = table_rgb(eff_tables, base, k2, j_count, j, to_local(s, axis), k, oo, ow);
                        eta = minf(eta, sharpness_max);
                        amp = scale * mu * (c.c * asg_shade_integral(lam, mu_w) / sg_integral(eta));
                        with_lights = 0;
                        tap = w;
                        tap.lam = lam;
                        tap.mu = mu_w;
                        taps = 1;
                    } else {
                        float eta_j = lobe[3];
                        axis = normalize3(2.0f * c_oj * xi - wo);
                        if (!lobe_cached) {
                            grid_bilinear(to_local(s, axis), k, lobe_ii, lobe_iw, lobe_ic);
                            if (has_ssdf != 0)
                                lobe_theta = ssdf_theta(ssdf, axis);
                            lobe_cached = 1;
                        }
                        float3 mu = table_rgb_cell(eff_tables, base, k2, j_count, j, lobe_ii, lobe_iw, lobe_ic, oo, ow);
                        amp = scale * mu * (2.0f * SHADE_PI / (eta_j + eta_s));
                        eta = 1.0f / (1.0f / eta_j + 1.0f / eta_s) / (4.0f * maxf(c_oj, MIN_COS_VIEW));
                    }
                }
                eta = minf(eta, sharpness_max);
                EtaRow er = eta_row(tab, eta);
                float amount = cosine_integral(tab, axis, eta, er, s.n);
                if (cap >= 0.0f) {
                    float spread = sqrt(maxf(1.0f - cap * cap, 0.0f) / (2.0f * SHADE_PI * eta));
                    amount = maxf(amount - spread * sg_integral(eta) * lookup(tab, 1, er, dot3(axis, s.n))
                                               / (1.0f + exp(-eta)), 0.0f);
                }
                if (has_ssdf != 0)
                    amount = amount * (ray_weight(eta, occ.samples) >= 1.0f
                                       ? rays_alone_share(axis, eta, s.n, occ)
                                       : environment_share_at(tab, lobe_cached ? lobe_theta : ssdf_theta(ssdf, axis),
                                                              axis, eta, er, s, occ, -1.0f));
                float3 light_part = (float3)(0.0f, 0.0f, 0.0f);
                if (with_lights != 0)
                    light_part = lobe_from_lights(tab, axis, eta, s, n_lights, lights, vis);
                float3 env_l = taps != 0 ? asg_prefiltered(env_maps, env_levels, n_levels, tap, sharpness_max)
                                         : prefiltered(env_maps, env_levels, n_levels, axis, eta);
                out = out + amp * (env_scale * env_l * amount + light_part);
            }
        }
    }
    store3(radiance, p, finite_radiance(out));
}
