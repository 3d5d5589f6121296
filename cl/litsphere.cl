/* Lit-sphere shading (seed 004 Eq. 1–4): the litsphere stage.
 *
 * Twin of kernels/litsphere.py, function for function and in the same operation order; the
 * mathematics and the packed inputs are warp_biscale.litsphere (reference_shade is the float64
 * oracle of one light's lookup, SpherePack the layout). One work-item per pixel along dimension 0
 * (rounded up to a whole work-group; the surplus returns): the surface normal from the G-buffer, a
 * mip level from the normal's change to the next pixels, then per light the images' frame (z the
 * view direction, x towards the light), the two images bracketing the light's polar angle, each
 * read at the normal turned about y (trilinear), blended.
 *
 * Built after cl/shade.cl (OpenCLBackend's program sources), whose camera_ray, prefiltered,
 * finite_radiance and ifloor_pos it calls, as the Warp twin imports them from kernels/shade.py.
 *
 * Layouts (no float3 in global memory): positions, normals, texels, env_maps and the output are
 * float arrays of stride 3; bary stride 2; light_vis (P, L) uchar; lights (L, 8); faces (F, 3);
 * sphere_info (S, 8) int; angles (ΣA, 3) [φ, cos φ, sin φ]; level_info (rows, 2) int [texel offset, size]; env_levels (n_levels, 4).
 */

#define K_OUTSIDE 0.75f  /* = litsphere.K_OUTSIDE */
#define RIM 0.9995f      /* = litsphere.RIM */
#define EDGE 0.5f        /* a neighbour whose normal differs more is across an edge: no footprint from it */

CL_INLINE float3 pixel_normal(__global const int *faces, __global const float *normals, int f, float b0, float b1)
{
    float w0 = 1.0f - b0 - b1;
    return normalize3(w0 * load3(normals, faces[3 * f]) + b0 * load3(normals, faces[3 * f + 1])
                      + b1 * load3(normals, faces[3 * f + 2]));
}

/* |n(q) − n| for the neighbouring pixel q, 0 where q misses or lies across an edge. */
CL_INLINE float normal_step(__global const int *face, __global const float *bary, __global const int *faces,
                            __global const float *normals, int q, float3 n)
{
    int g = face[q];
    if (g < 0)
        return 0.0f;
    float3 e = pixel_normal(faces, normals, g, bary[2 * q], bary[2 * q + 1]) - n;
    float d = sqrt(dot3(e, e));
    if (d > EDGE)
        return 0.0f;
    return d;
}

/* Bilinear lookup at (u, v) ∈ [0, 1]², v up, of a size² level stored row-major from the top; clamped. */
CL_INLINE float3 bilinear(__global const float *texels, int offset, int size, float u, float v)
{
    float fs = (float)size;
    float fx = clampf(u * fs - 0.5f, 0.0f, fs - 1.0f);
    float fy = clampf((1.0f - v) * fs - 0.5f, 0.0f, fs - 1.0f);
    int x0 = min(ifloor_pos(fx), size - 2);
    int y0 = min(ifloor_pos(fy), size - 2);
    float ax = fx - (float)x0;
    float ay = fy - (float)y0;
    int r0 = offset + y0 * size + x0;
    int r1 = r0 + size;
    return ((1.0f - ay) * ((1.0f - ax) * load3(texels, r0) + ax * load3(texels, r0 + 1))
            + ay * ((1.0f - ax) * load3(texels, r1) + ax * load3(texels, r1 + 1)));
}

/* Image `row`'s pyramid (its level 0 at level_info[row]) read at mip level `lod`. */
CL_INLINE float3 trilinear(__global const float *texels, __global const int *level_info, int row, int n_levels,
                           float u, float v, float lod)
{
    float t = clampf(lod, 0.0f, (float)(n_levels - 1));
    int lo = ifloor_pos(t);
    float f = t - (float)lo;
    int hi = min(lo + 1, n_levels - 1);
    float3 a = bilinear(texels, level_info[2 * (row + lo)], level_info[2 * (row + lo) + 1], u, v);
    if (f <= 0.0f) /* a footprint within a texel (most pixels of a close object): one level read */
        return a;
    float3 b = bilinear(texels, level_info[2 * (row + hi)], level_info[2 * (row + hi) + 1], u, v);
    return (1.0f - f) * a + f * b;
}

/* litsphere.rim_point: (x, y) read for the turned normal r in image i's frame. */
CL_INLINE float2 rim_point(float rx, float ry, float rz, float phi_i)
{
    float c = rx * sin(phi_i) + rz * cos(phi_i);
    float s = sqrt(maxf(1.0f - c * c, 0.0f));
    float across = s * sin(phi_i);
    if (rz >= 0.0f || across <= 1.0e-6f)
        return (float2)(rx, ry);
    float sin_b = clampf(-c * cos(phi_i) / across, -1.0f, 1.0f);
    float cos_b = sqrt(1.0f - sin_b * sin_b);
    if (ry < 0.0f)
        cos_b = -cos_b;
    return (float2)(c * sin(phi_i) - s * sin_b * cos(phi_i), s * cos_b);
}

/* Radiance per unit irradiance of normal n seen from `view`, lit from `light`: litsphere.reference_shade.
 * The shading is bound by its arithmetic, so the half angle, sin αh and the diffuse share's turn come from
 * cos φ, sin φ and each image's (cos φi, sin φi) by identities instead of trigonometric calls. */
CL_INLINE float3 sphere_lookup(float3 n, float3 view, float3 light, float lod, float shrink, int s,
                               __global const int *sphere_info, __global const float *angles,
                               __global const int *level_info, __global const float *texels)
{
    float3 z = view;
    float3 x = light - dot3(light, z) * z;
    float cos_phi = dot3(light, z);
    float sin_phi = sqrt(dot3(x, x));
    /* (atan2 of the across and along parts: exact where l is near ±v, where acos loses float32 digits) */
    float phi = atan2(sin_phi, cos_phi);
    if (sin_phi <= 1.0e-6f) { /* the light along the view axis: any x (the images are symmetric about it) */
        float3 ref = (float3)(0.0f, 1.0f, 0.0f);
        if (absf(z.x) < 0.9f)
            ref = (float3)(1.0f, 0.0f, 0.0f);
        x = ref - dot3(ref, z) * z;
    }
    x = normalize3(x);
    float3 y = cross3(z, x);
    float nx = dot3(n, x);
    float ny = dot3(n, y);
    float nz = dot3(n, z);
    float hx = sqrt(maxf(0.5f * (1.0f - cos_phi), 0.0f)); /* sin φ/2 */
    float hz = sqrt(maxf(0.5f * (1.0f + cos_phi), 0.0f)); /* cos φ/2 */
    float proj = sqrt(nx * nx + nz * nz);
    float cos_ah = 0.0f;
    if (proj > 1.0e-12f)
        cos_ah = minf((hx * nx + hz * nz) / proj, 1.0f);
    float sin_ah = 1.0f; /* αh = min(∠, π/2): sin αh = 1 past a right angle */
    if (cos_ah > 0.0f)
        sin_ah = sqrt(1.0f - cos_ah * cos_ah);
    __global const int *info = sphere_info + 8 * s;
    int first = info[0];
    int count = info[1];
    int first_row = info[2];
    int n_levels = info[3];
    int n_parts = info[4];
    /* the bracket: angles[i2 − 1] < φ ≤ angles[i2]; outside the angles, the nearest image alone */
    int i2 = 0;
    while (i2 < count && angles[3 * (first + i2)] < phi)
        i2 += 1;
    int i1 = i2 - 1;
    float t = 0.0f;
    float k_glossy = 0.5f + 0.5f * sin_ah;
    if (i2 == 0 || i2 >= count) {
        i1 = i2 == 0 ? 0 : count - 1;
        i2 = i1;
        k_glossy = K_OUTSIDE;
    } else {
        t = (phi - angles[3 * (first + i1)]) / (angles[3 * (first + i2)] - angles[3 * (first + i1)]);
    }
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    for (int part = 0; part < n_parts; ++part) {
        int diffuse = n_parts == 2 && part == 0; /* the diffuse share: the exact rotation (k = 1) */
        for (int which = 0; which < 2; ++which) {
            int a = which == 1 ? i2 : i1;
            float w = which == 1 ? t : 1.0f - t;
            if (w > 0.0f) {
                __global const float *image = angles + 3 * (first + a); /* (φi, cos φi, sin φi) */
                float cos_turn = image[1] * cos_phi + image[2] * sin_phi; /* cos(φi − φ) */
                float sin_turn = image[2] * cos_phi - image[1] * sin_phi; /* sin(φi − φ) */
                if (!diffuse) {
                    float turn = k_glossy * (image[0] - phi);
                    cos_turn = cos(turn);
                    sin_turn = sin(turn);
                }
                float2 r = (float2)(nx * cos_turn + nz * sin_turn, ny);
                if (diffuse)
                    r = rim_point(r.x, ny, -nx * sin_turn + nz * cos_turn, image[0]);
                float u = shrink * r.x * 0.5f + 0.5f;
                float v = shrink * r.y * 0.5f + 0.5f;
                int row = first_row + (part * count + a) * n_levels;
                out = out + w * trilinear(texels, level_info, row, n_levels, u, v, lod);
            }
        }
    }
    return out;
}

__kernel void shade_litsphere(
    __global const int *face,             /* (P,) G-buffer face, -1 = miss */
    __global const float *bary,           /* (P, 2) weights of vertices 1 and 2 */
    __global const uchar *light_vis,      /* (P, L) visible share in 255ths */
    __global const int *faces,            /* (F, 3) */
    __global const float *positions,      /* (V, 3) */
    __global const float *normals,        /* (V, 3) */
    __global const int *face_material,    /* (F,) */
    const float4 eye, const float4 forward, const float4 right, const float4 up, /* Camera.packed() */
    const float cam_w, const float cam_h,
    const int n_lights, __global const float *lights,   /* (L, 8) */
    const int view_mode,                  /* 0 the pixel's view direction, 1 the camera's axis */
    const float shrink,                   /* the turned normal's scale before the lookup (1 or litsphere.SHRINK) */
    __global const float *env_maps, const int n_levels, __global const float *env_levels,
    __global const int *sphere_of_material, __global const int *sphere_info, /* (Mat,), (S, 8) */
    __global const float *angles, __global const int *level_info, __global const float *texels,
    const int n_pixels,
    __global float *radiance)             /* (P, 3) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    int f = face[p];
    if (f < 0) {
        store3(radiance, p, prefiltered(env_maps, env_levels, n_levels,
                                        camera_ray(forward, right, up, cam_w, cam_h, p), 1.0e30f));
        return;
    }
    float b0 = bary[2 * p];
    float b1 = bary[2 * p + 1];
    float3 n = pixel_normal(faces, normals, f, b0, b1);
    float w0 = 1.0f - b0 - b1;
    float3 pos = w0 * load3(positions, faces[3 * f]) + b0 * load3(positions, faces[3 * f + 1])
                 + b1 * load3(positions, faces[3 * f + 2]);
    float3 view = normalize3((float3)(eye.x, eye.y, eye.z) - pos);
    if (view_mode == 1) /* the paper's distant viewer: the camera's axis */
        view = -normalize3((float3)(forward.x, forward.y, forward.z));
    int width = (int)cam_w;
    int x = p % width;
    float step = 0.0f;
    if (x + 1 < width)
        step = normal_step(face, bary, faces, normals, p + 1, n);
    if (p + width < n_pixels)
        step = maxf(step, normal_step(face, bary, faces, normals, p + width, n));
    int s = sphere_of_material[face_material[f]];
    /* texels per pixel at level 0: the lookup point moves by shrink·|Δn|/2 of the image's width */
    float rho = step * 0.5f * shrink * (float)level_info[2 * sphere_info[8 * s + 2] + 1];
    float lod = log2(maxf(rho, 1.0f));
    float3 total = (float3)(0.0f, 0.0f, 0.0f);
    for (int l = 0; l < n_lights; ++l) {
        float share = (float)light_vis[p * n_lights + l] / 255.0f;
        if (share > 0.0f) {
            __global const float *row = lights + 8 * l;
            float3 light = (float3)(row[1], row[2], row[3]);
            float3 e = (float3)(row[4], row[5], row[6]);
            if (row[0] != 0.0f) { /* a point light: its direction and the inverse-square irradiance */
                float3 d = light - pos;
                float r2 = maxf(dot3(d, d), 1.0e-30f);
                light = d / sqrt(r2);
                e = e / r2;
            }
            if (dot3(n, light) > 0.0f && dot3(n, view) > 0.0f) {
                float3 c = sphere_lookup(n, view, light, lod, shrink, s, sphere_info, angles, level_info, texels);
                total = total + share * (e * c);
            }
        }
    }
    store3(radiance, p, finite_radiance(total));
}


/* ------------------------------------------------------------------------------------------------
 * The images themselves: the material's response on the texel grid (litsphere.material_response)
 * Layouts: lights (A, 3); kinds (M,) int; params (M, 8); info [K, J, M, exact]; lobes (J, 5) [axis,
 * sharpness, ∫G]; amplitudes (M, K², K², J, 3) μ/cos θi; texels (A·R², 3). */

/* litsphere.texel_normals: texel i (row-major from the top) of a resolution² image, rim-filled. */
CL_INLINE float3 texel_normal(int resolution, int i)
{
    float x = 2.0f * ((float)(i % resolution) + 0.5f) / (float)resolution - 1.0f;
    float y = 1.0f - 2.0f * ((float)(i / resolution) + 0.5f) / (float)resolution;
    float r = sqrt(x * x + y * y);
    if (r > RIM) {
        x = x * RIM / r;
        y = y * RIM / r;
    }
    return (float3)(x, y, sqrt(maxf(1.0f - x * x - y * y, 0.0f)));
}

/* EffectiveBRDF.eval(ωi, ωo) in the surface's frame (its tables hold the cosine). */
CL_INLINE float3 effective_response(__global const int *kinds, __global const float *params, __global const int *info,
                                    __global const float *lobes, __global const float *amplitudes, float3 wi, float3 wo)
{
    if (wi.z <= 0.0f || wo.z <= 0.0f)
        return (float3)(0.0f, 0.0f, 0.0f);
    int k = info[0];
    int j_count = info[1];
    int k2 = k * k;
    int oo[4];
    float ow[4], oc[4];  /* (ωo's cosines: unused) */
    grid_bilinear(wo, k, oo, ow, oc);
    float3 half_sum = wi + wo;
    float3 h = (float3)(0.0f, 0.0f, 1.0f);
    if (dot3(half_sum, half_sum) > 0.0f)
        h = normalize3(half_sum);
    float3 out = (float3)(0.0f, 0.0f, 0.0f);
    for (int m = 0; m < info[2]; ++m) {
        int base = m * k2 * k2 * j_count * 3;
        int kind = kinds[m];
        __global const float *row = params + 8 * m;
        float3 kd = (float3)(row[0], row[1], row[2]) / SHADE_PI;
        float3 scale = specular_scale(kind, (float3)(row[3], row[4], row[5]), row[6], row[7], dot3(h, wi));
        float eta_s = 1.0f;
        if (kind != 0)
            eta_s = ndf_sharpness(kind, row[6]);
        for (int j = 0; j < j_count; ++j) {
            float3 mu = table_rgb(amplitudes, base, k2, j_count, j, wi, k, oo, ow) * wi.z;
            out = out + kd * mu * lobes[5 * j + 4];
            if (kind != 0) {
                float3 axis = (float3)(lobes[5 * j], lobes[5 * j + 1], lobes[5 * j + 2]);
                float eta = lobes[5 * j + 3];
                float3 d = h - axis;
                float one_minus_cos = 0.5f * dot3(d, d); /* 1 − h·ξ without cancellation near the axis */
                float s;
                if (info[3] == 0) { /* Eq. 15: the convolved lobe at h (sg.convolve, sg.evaluate) */
                    s = 2.0f * SHADE_PI / (eta + eta_s) * exp(-one_minus_cos / (1.0f / eta + 1.0f / eta_s));
                } else { /* Eq. 10: the inner product (sg.inner_product) */
                    float3 resultant = eta_s * h + eta * axis;
                    float r = sqrt(dot3(resultant, resultant));
                    float gap = 2.0f * eta * eta_s * one_minus_cos / (eta + eta_s + r);
                    float over = 2.0f - 2.0f * r;
                    if (r > 1.0e-12f)
                        over = (1.0f - exp(-2.0f * r)) / r;
                    s = 2.0f * SHADE_PI * exp(-gap) * over;
                }
                out = out + scale * mu * s;
            }
        }
    }
    return (float3)(maxf(out.x, 0.0f), maxf(out.y, 0.0f), maxf(out.z, 0.0f));
}

/* Texel i of image a (i + a·R² = the work-item): f(n, l, v)(n·l)⁺ of an analytic BRDF (row 0 of
 * kinds/params) or of an effective BRDF (`effective` = 1, in the sphere's longitude frame), v = +Z. */
__kernel void sphere_texels(const int resolution, __global const float *lights, const int effective,
                            __global const int *kinds, __global const float *params, __global const int *info,
                            __global const float *lobes, __global const float *amplitudes, const int n_texels,
                            __global float *texels)
{
    int t = get_global_id(0);
    if (t >= n_texels)
        return;
    int per_image = resolution * resolution;
    float3 n = texel_normal(resolution, t % per_image);
    float3 light = load3(lights, t / per_image);
    float3 view = (float3)(0.0f, 0.0f, 1.0f);
    float3 out;
    if (effective == 0) {
        out = brdf_cosine_weighted(kinds[0], params, 0, n, light, view) / maxf(n.z, 1.0e-30f);
    } else {
        /* litsphere.sphere_tangents: increasing longitude about +Y, +X at the poles */
        float3 tangent = (float3)(1.0f, 0.0f, 0.0f);
        float3 across = (float3)(n.z, 0.0f, -n.x);
        if (dot3(across, across) > 1.0e-18f)
            tangent = normalize3(across);
        float3 bitangent = cross3(n, tangent);
        float3 wi = (float3)(dot3(light, tangent), dot3(light, bitangent), dot3(light, n));
        float3 wo = (float3)(dot3(view, tangent), dot3(view, bitangent), dot3(view, n));
        out = effective_response(kinds, params, info, lobes, amplitudes, wi, wo);
    }
    store3(texels, t, finite_radiance(out));
}
