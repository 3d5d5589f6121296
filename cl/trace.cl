/* Ray casting against the large-scale mesh: camera rays (the G-buffer), any-hit rays (SSDF
 * visibility, shadows, the Monte Carlo reference) and per-light shadow rays.
 *
 * Twin of kernels/trace.py (conventions stated there); the mathematics is
 * warp_biscale.reference (trace_closest, trace_occluded, trace_shadows). The BVH is built on the
 * host (warp_biscale.bvh) and walked by bvh_closest_hit / bvh_any_hit of cl/common.cl, the walk
 * the small-scale visibility stage uses; a BVH slot maps back to its face through `tri_index`.
 * Every kernel is one work-item per ray along dimension 0, which the backend rounds up to a whole
 * work-group; the surplus work-items return. 3-vectors travel as float arrays of stride 3.
 */

/* Camera ray of pixel i (row-major, y down): normalize(forward + sx·right + sy·up), with right and up
 * already scaled by tan(fov/2)·aspect and tan(fov/2) (Camera.packed). The camera travels as four
 * float4 (w unused) rather than one float16, whose by-value ABI PoCL warns about without AVX-512. */
CL_INLINE float3 camera_ray(float4 forward, float4 right, float4 up, int i, int width, int height)
{
    int x = i % width;
    int y = i / width;
    float sx = 2.0f * ((float)x + 0.5f) / (float)width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)height;
    float3 d = (float3)(forward.x + sx * right.x + sy * up.x, forward.y + sx * right.y + sy * up.y,
                        forward.z + sx * right.z + sy * up.z);
    return normalize3(d);
}

/* The geometric normal n of a hit at x turned to the side the eye sees: shadow, occlusion and lobe rays
 * leave along it, so the moved origin lies in front of the face whichever way it is wound. */
CL_INLINE float3 seen_side(float3 n, float3 x, float3 eye)
{
    if (dot3(n, (float3)(eye.x - x.x, eye.y - x.y, eye.z - x.z)) < 0.0f)
        return (float3)(-n.x, -n.y, -n.z);
    return n;
}

/* Where the rays of hit x on face f leave from (kernels/trace.py's ray_start; trace.ray_starts, float64):
 * *ng the face's normal turned to the eye (seen_side), *ns the interpolated vertex normal turned with it,
 * and the origin x lifted onto the curved surface of the vertex normals (Hanika's shadow-terminator offset),
 * then eps along ng: so a light the shading normal sees past the face's own plane is reached over the
 * neighbouring faces. */
CL_INLINE float3 ray_start(__global const float *points, __global const float *normals, __global const int *faces,
                           __global const float *face_normals, int f, __global const float *bary, int p,
                           __global const float *position, float3 eye, float eps, float3 *ng, float3 *ns)
{
    float3 x = load3(position, p);
    float3 fn = load3(face_normals, f);
    float3 g = seen_side(fn, x, eye);
    float w1 = bary[2 * p], w2 = bary[2 * p + 1];
    float w[3] = {1.0f - w1 - w2, w1, w2};
    /* the vertex normals turned to the eye's side of the face with their blend (not with the winding, which a
     * mesh may have the other way round: its lights were then tested against the inside's horizon) */
    float3 blend = (float3)(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 3; ++k)
        blend += w[k] * load3(normals, faces[3 * f + k]);
    float side = dot3(g, blend) < 0.0f ? -1.0f : 1.0f;
    float3 lift = (float3)(0.0f, 0.0f, 0.0f), sum = (float3)(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 3; ++k) {
        int i = faces[3 * f + k];
        float3 n = side * load3(normals, i);
        float3 pk = load3(points, i);
        float d = fmin(dot3((float3)(x.x - pk.x, x.y - pk.y, x.z - pk.z), n), 0.0f);
        lift += (w[k] * d) * n;
        sum += w[k] * n;
    }
    *ng = g;
    *ns = normalize3(sum);
    return (float3)(x.x - lift.x + eps * g.x, x.y - lift.y + eps * g.y, x.z - lift.z + eps * g.z);
}

__kernel void trace_primary(
    __global const float *nodes,     /* (N, 8) BVH records */
    __global const float *tris,      /* (F, 9) [a, b - a, c - a], BVH slot order */
    __global const int *tri_index,   /* (F,) slot -> face */
    const float4 eye, const float4 forward, const float4 right, const float4 up, /* Camera.packed() */
    const int width, const int height,
    __global int *face_out,          /* (P,) face or -1 */
    __global float *bary_out,        /* (P, 2) weights of vertices 1 and 2 */
    __global float *position_out,    /* (P, 3) */
    __global float *t_out)           /* (P,) inf on a miss */
{
    int i = get_global_id(0);
    if (i >= width * height)
        return;
    float3 o = (float3)(eye.x, eye.y, eye.z);
    float3 d = camera_ray(forward, right, up, i, width, height);
    float t, u, v;
    int slot = bvh_closest_hit(nodes, tris, o, d, 0.0f, INFINITY, &t, &u, &v);
    if (slot >= 0) {
        /* On the triangle by construction: a + u(b - a) + v(c - a) from the same float32 edges
         * the Warp twin computes. */
        __global const float *tri = tris + 9 * slot;
        face_out[i] = tri_index[slot];
        bary_out[2 * i] = u;
        bary_out[2 * i + 1] = v;
        store3(position_out, i,
               (float3)(tri[0] + u * tri[3] + v * tri[6], tri[1] + u * tri[4] + v * tri[7],
                        tri[2] + u * tri[5] + v * tri[8]));
        t_out[i] = t;
    } else {
        face_out[i] = -1;
        bary_out[2 * i] = 0.0f;
        bary_out[2 * i + 1] = 0.0f;
        store3(position_out, i, (float3)(0.0f, 0.0f, 0.0f));
        t_out[i] = INFINITY;
    }
}

/* Any hit with t in (t_min, t_max[i]]; the caller has moved the origins off their surfaces. */
__kernel void trace_occluded(
    __global const float *nodes,
    __global const float *tris,
    __global const float *origins,     /* (R, 3) */
    __global const float *directions,  /* (R, 3) unit */
    const float t_min,
    __global const float *t_max,       /* (R,) inf allowed */
    const int n_rays,
    __global uchar *occluded)          /* (R,) */
{
    int i = get_global_id(0);
    if (i >= n_rays)
        return;
    float t_hi = t_max[i];
    occluded[i] = (t_hi > t_min && bvh_any_hit(nodes, tris, load3(origins, i), load3(directions, i), t_min, t_hi))
                      ? 1 : 0;
}

/* Shadow rays of each hit pixel towards each light (NDRange (P, L)). The origin is the hit point
 * moved eps along the geometric normal turned to the camera's side, the side the surface is
 * seen from; a light below that normal's horizon, or a missed pixel, gets 0. A point light's
 * ray stops eps short of its centre; a directional light's never stops. */
__kernel void trace_shadows(
    __global const float *nodes,
    __global const float *tris,
    __global const float *points,        /* (V, 3) */
    __global const float *normals,       /* (V, 3) unit vertex normals */
    __global const int *faces,           /* (F, 3), original face order */
    __global const float *face_normals,  /* (F, 3) unit, original face order */
    __global const int *face,            /* (P,) */
    __global const float *bary,          /* (P, 2) */
    __global const float *position,      /* (P, 3) */
    const float eye_x, const float eye_y, const float eye_z,
    __global const float *lights,        /* (L, 8) Light.packed() rows */
    __global const int *light_samples,   /* (L,) rays a pixel for each light (trace.light_samples) */
    const float eps, const float t_min,
    const int part_index, const int part_count, /* the anti-aliasing sample's rays of the set (ray_part) */
    const int block_width,               /* > 0: shared in the pixel blocks of frame rows this wide (pixel_part) ... */
    const int block_side,                /* ... of this side at most (2 or 4; set_block_side) */
    __global const uchar *changed,       /* only_changed: the pixels flagged here alone (mark_changed: anti- */
    const int only_changed,              /* aliasing shaded once a pixel; the others keep their rays) */
    const int n_pixels, const int n_lights,
    __global uchar *visible)             /* (P, L) visible share in 255ths */
{
    int p = get_global_id(0);
    int k = get_global_id(1);
    if (p >= n_pixels)
        return;
    int f = face[p];
    if (only_changed != 0 && changed[p] == 0)
        return;
    int hits = 0;
    int samples = light_samples[k];
    int3 part = pixel_part(samples, part_index, part_count, block_width, block_side, p);
    int traced = (samples - part.x + part.y - 1) / part.y;
    if (f >= 0) {
        float3 ng, n;
        float3 o = ray_start(points, normals, faces, face_normals, f, bary, p, position,
                             (float3)(eye_x, eye_y, eye_z), eps, &ng, &n);
        __global const float *light = lights + 8 * k;
        float3 c = (float3)(light[1], light[2], light[3]);
        float3 w = normalize3(c);
        float spread = tan(sqrt(light[7] / 3.14159265358979f)); /* directional: tan of the angular radius */
        float apparent = spread;                                /* the disc's radius over its distance */
        if (light[0] != 0.0f) {
            float3 to_light = c - o;
            w = normalize3(to_light);
            spread = light[7]; /* point: the radius */
            apparent = spread / sqrt(dot3(to_light, to_light));
        }
        /* the rays aim at the part of the disc above the shading normal's horizon, q.x > -chord */
        float3 a, b;
        float chord = horizon_frame(w, n, apparent, &a, &b);
        for (int i = part.x; i < samples; i += part.y) {
            float2 q = disk_sample(i, samples, part.z);
            if (chord < 1.0f)
                q = above_horizon(q, chord);
            float3 on_disc = spread * (q.x * a + q.y * b);
            float3 d = w + on_disc;
            float t_hi = INFINITY;
            if (light[0] != 0.0f) { /* a point light: towards a point of its disc, stopping eps short of it */
                d = c + on_disc - o;
                t_hi = sqrt(dot3(d, d)) - eps;
            }
            d = normalize3(d);
            /* Below the shading normal's horizon the light adds nothing; above it, a ray that dips below the
             * face's plane is traced from the lifted origin (it may still hit the face itself). */
            if (dot3(n, d) > 0.0f && !(t_hi > t_min && bvh_any_hit(nodes, tris, o, d, t_min, t_hi)))
                hits += 1;
        }
    }
    visible[(long)p * n_lights + k] = (uchar)((hits * 255 + traced / 2) / traced);
}

/* One work-item per pixel: of `samples` unbounded any-hit rays, cosine-distributed over the hemisphere of
 * the geometric normal on the camera's side (occlusion_direction), the pixel's of anti-aliasing sample
 * part_index of part_count (pixel_part); bit i of the pixel's mask is set where ray i is blocked
 * (trace.occlusion_directions, reference.trace_occlusion). */
__kernel void trace_occlusion(
    __global const float *nodes,
    __global const float *tris,
    __global const float *points,        /* (V, 3) */
    __global const float *normals,       /* (V, 3) unit vertex normals */
    __global const int *faces,           /* (F, 3), original face order */
    __global const float *face_normals,  /* (F, 3) unit, original face order */
    __global const int *face,            /* (P,) */
    __global const float *bary,          /* (P, 2) */
    __global const float *position,      /* (P, 3) */
    const float eye_x, const float eye_y, const float eye_z,
    const float eps, const float t_min, const int samples,
    const int part_index, const int part_count, const int block_width, const int block_side,
    __global const uchar *changed, const int only_changed, /* as trace_shadows' */
    const int n_pixels,
    __global uint *mask)                 /* (P,) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    int f = face[p];
    if (only_changed != 0 && changed[p] == 0)
        return;
    uint bits = 0u;
    if (f >= 0) {
        float3 n, ns;
        float3 o = ray_start(points, normals, faces, face_normals, f, bary, p, position,
                             (float3)(eye_x, eye_y, eye_z), eps, &n, &ns);
        float3 a, b;
        disk_basis(n, &a, &b);
        int3 part = pixel_part(samples, part_index, part_count, block_width, block_side, p);
        for (int i = part.x; i < samples; i += part.y) {
            float3 d = occlusion_direction(a, b, n, i, samples, part.z);
            if (bvh_any_hit(nodes, tris, o, d, t_min, INFINITY))
                bits |= 1u << i;
        }
    }
    mask[p] = bits;
}

/* One work-item per pixel: of LOBE_RAYS unbounded any-hit rays over each sharp lobe's cap (lobe_ray_direction),
 * the pixel's of anti-aliasing sample part_index of part_count (pixel_part); bit k·LOBE_RAYS + i set where ray i of
 * lobe k is blocked; a ray below the shading normal's horizon is not traced (reference.trace_lobe_rays). */
__kernel void trace_lobe_rays(
    __global const float *nodes,
    __global const float *tris,
    __global const float *points,        /* (V, 3) */
    __global const float *normals,       /* (V, 3) unit vertex normals */
    __global const int *faces,           /* (F, 3), original face order */
    __global const float *face_normals,  /* (F, 3) unit, original face order */
    __global const int *face,            /* (P,) */
    __global const float *bary,          /* (P, 2) */
    __global const float *position,      /* (P, 3) */
    const float eye_x, const float eye_y, const float eye_z,
    __global const float *lobes,         /* (M, 4) [axis, η] */
    const int n_lobes, const int rays,   /* LOBE_RAYS, passed in as the Warp twin takes it */
    const float eps, const float t_min,
    const int part_index, const int part_count, const int block_width, const int block_side,
    __global const uchar *changed, const int only_changed, /* as trace_shadows' */
    const int n_pixels,
    __global uint *mask)                 /* (P,) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    int f = face[p];
    if (only_changed != 0 && changed[p] == 0)
        return;
    uint bits = 0u;
    if (f >= 0) {
        float3 ng, n;
        float3 o = ray_start(points, normals, faces, face_normals, f, bary, p, position,
                             (float3)(eye_x, eye_y, eye_z), eps, &ng, &n);
        int3 part = pixel_part(rays, part_index, part_count, block_width, block_side, p);
        for (int k = 0; k < n_lobes; ++k) {
            float3 w = (float3)(lobes[4 * k], lobes[4 * k + 1], lobes[4 * k + 2]);
            float3 a, b;
            disk_basis(w, &a, &b);
            for (int i = part.x; i < rays; i += part.y) {
                float3 d = lobe_ray_direction(a, b, w, lobes[4 * k + 3], i, part.z);
                if (dot3(n, d) > 0.0f && bvh_any_hit(nodes, tris, o, d, t_min, INFINITY))
                    bits |= 1u << (k * LOBE_RAYS + i);
            }
        }
    }
    mask[p] = bits;
}

#define SHARE_NORMAL_COS 0.9f /* = trace.SHARE_NORMAL_COS */
#define SHARE_PLANE 0.1f      /* = trace.SHARE_PLANE */

CL_INLINE float3 seen_normal(__global const float *face_normals, int f, float3 x, float3 eye)
{
    float3 n = load3(face_normals, f);
    return dot3(n, eye - x) < 0.0f ? -n : n;
}

/* (the first pixel of pixel p's side x side block, its column): found once a pixel, so that the loops over a
 * block's slots (q = r side + c: the pixel origin + r width + c) find each slot's pixel without an integer division,
 * which on a GPU costs more than the slot's memory reads. */
CL_INLINE int2 block_origin(int p, int width, int side)
{
    int x = p % width, y = p / width;
    int x0 = x - x % side, y0 = y - y % side;
    return (int2)(y0 * width + x0, x0);
}

/* Whether a hit xq with geometric normal nb (turned to the eye) lies on the surface of the hit xp with normal ng
 * (trace.same_surface): normals within SHARE_NORMAL_COS, and xq near xp's tangent plane seen from xp. */
CL_INLINE int same_surface(float3 ng, float3 xp, float3 nb, float3 xq)
{
    float3 d = xq - xp;
    return dot3(ng, nb) >= SHARE_NORMAL_COS && fabs(dot3(ng, d)) <= SHARE_PLANE * sqrt(dot3(d, d));
}

/* Bit q set where the pixel in slot q of hit pixel p's side x side block lends p its rays (trace.share_block): p
 * itself, or a hit neighbour in the frame whose geometric normal is within SHARE_NORMAL_COS of p's and which lies
 * near p's tangent plane (SHARE_PLANE), so that a depth or crease edge keeps each side's rays apart. */
CL_INLINE int block_lenders(__global const int *face, __global const float *position,
                            __global const float *face_normals, float3 eye, int width, int n_pixels, int p, int side)
{
    float3 xp = load3(position, p);
    float3 ng = seen_normal(face_normals, face[p], xp, eye);
    int2 origin = block_origin(p, width, side);
    int lenders = 0;
    for (int r = 0; r < side; ++r) {
        for (int c = 0; c < side; ++c) {
            int b = origin.x + r * width + c;
            if (origin.y + c < width && b < n_pixels) {
                if (b == p) {
                    lenders |= 1 << (r * side + c);
                } else if (face[b] >= 0) {
                    float3 xq = load3(position, b);
                    if (same_surface(ng, xp, seen_normal(face_normals, face[b], xq, eye), xq))
                        lenders |= 1 << (r * side + c);
                }
            }
        }
    }
    return lenders;
}

/* One work-item per pixel: its lenders in its side x side block (block_lenders; 0 for a miss), found once a
 * G-buffer for every set of rays its frame shares (trace.share_block). */
__kernel void frame_block_lenders(
    __global const int *face,            /* (P,) */
    __global const float *position,      /* (P, 3) */
    __global const float *face_normals,  /* (F, 3) unit, original face order */
    const float eye_x, const float eye_y, const float eye_z,
    const int width, const int side, const int n_pixels,
    __global int *lenders)               /* (P,) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    lenders[p] = face[p] >= 0 ? block_lenders(face, position, face_normals, (float3)(eye_x, eye_y, eye_z), width,
                                              n_pixels, p, side) : 0;
}

/* The lenders of pixel p's side x side block taken from `lenders`, those of its lenders_side block
 * (trace.block_sub_lenders): the blocks nest, and a pixel lends to another by their hits alone. */
CL_INLINE int sub_lenders(int lenders, int p, int width, int lenders_side, int side)
{
    if (side == lenders_side)
        return lenders;
    int x = p % width, y = p / width;
    int ox = x % lenders_side - x % side, oy = y % lenders_side - y % side;
    int out = 0;
    for (int r = 0; r < side; ++r) /* (slot q = r side + c, by row and column: no division a slot, as block_origin) */
        for (int c = 0; c < side; ++c)
            if ((lenders >> ((ox + c) + lenders_side * (oy + r))) & 1)
                out |= 1 << (r * side + c);
    return out;
}

/* One work-item per pixel (reference.share_block_masks): the union of the ray masks (occlusion or lobe rays, a
 * set of `samples`) that the pixels of its block (set_block_side) lend it (`lenders`, frame_block_lenders' of the
 * part's block_side), and of the rays they traced (the part of their slot in the block): what the shade stage
 * weighs. A set of fewer than BLOCK_SLOTS rays is not shared: the pixel's own. 0 for a miss. */
__kernel void share_block_masks(
    __global const int *lenders,         /* (P,) */
    __global const int *face,            /* (P,) */
    const int width, const int block_side, const int n_pixels, const int samples, const int part_index,
    const int part_count,
    __global const uint *mask,           /* (P,) each pixel's own rays */
    __global uint *shared,               /* (P,) */
    __global uint *known)                /* (P,) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    uint bits = 0u, traced = 0u;
    if (face[p] >= 0) {
        int side = set_block_side(samples, part_count, width, block_side);
        if (side == 1) {
            int3 part = pixel_part(samples, part_index, part_count, width, block_side, p);
            bits = mask[p];
            traced = part_bits(part.x, part.y, samples);
        } else {
            int slots = side * side;
            int lent = sub_lenders(lenders[p], p, width, block_side, side);
            int2 origin = block_origin(p, width, side);
            /* slot q's part of the set is ray_part(samples, q + slots part_index, slots part_count): one stride for
             * every slot, and a first ray that steps by one from slot to slot, wrapping at the stride */
            int stride = max(1, min(slots * part_count, samples));
            int first = (slots * part_index) % stride;
            for (int r = 0; r < side; ++r) {
                for (int c = 0; c < side; ++c) {
                    if ((lent >> (r * side + c)) & 1) {
                        bits |= mask[origin.x + r * width + c];
                        traced |= part_bits(first, stride, samples);
                    }
                    if (++first == stride)
                        first = 0;
                }
            }
        }
    }
    shared[p] = bits;
    known[p] = traced;
}

/* One work-item per pixel (reference.share_block_shadows): each light's visible share over the shadow rays that
 * the pixels of its block (set_block_side for the light's rays) lend it (`lenders`, as share_block_masks'),
 * sum(traced * share) / sum(traced) in 255ths, rounded; the pixel's own share for a light of fewer than
 * BLOCK_SLOTS rays, and for a miss. */
__kernel void share_block_shadows(
    __global const int *lenders,         /* (P,) */
    __global const int *face,            /* (P,) */
    const int width, const int block_side, const int n_pixels, const int part_index, const int part_count,
    const int n_lights,
    __global const int *light_samples,   /* (L,) rays a pixel for each light (trace.light_samples) */
    __global const uchar *visible,       /* (P, L) each pixel's own rays */
    __global uchar *shared)              /* (P, L) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    int hit = face[p] >= 0;
    for (int l = 0; l < n_lights; ++l) {
        int value = visible[(long)p * n_lights + l];
        int samples = light_samples[l];
        int side = set_block_side(samples, part_count, width, block_side);
        if (hit && side > 1) {
            int slots = side * side;
            int lent = sub_lenders(lenders[p], p, width, block_side, side);
            int2 origin = block_origin(p, width, side);
            /* slot q's rays, as in share_block_masks: the first steps by one a slot, the stride is the same, so a
             * slot traces samples / stride rays, one more where its first is below samples % stride */
            int stride = max(1, min(slots * part_count, samples));
            int first = (slots * part_index) % stride;
            int fewest = samples / stride, longer = samples % stride;
            int num = 0, den = 0;
            for (int r = 0; r < side; ++r) {
                for (int c = 0; c < side; ++c) {
                    if ((lent >> (r * side + c)) & 1) {
                        int traced = fewest + (first < longer ? 1 : 0);
                        num += traced * (int)visible[(long)(origin.x + r * width + c) * n_lights + l];
                        den += traced;
                    }
                    if (++first == stride)
                        first = 0;
                }
            }
            value = (num + den / 2) / den;
        }
        shared[(long)p * n_lights + l] = (uchar)value;
    }
}

/* One work-item per pixel (trace.changed_pixels): 0 where the pixel's hit lies on the reference G-buffer's
 * surface at that pixel (the same face, both misses, or the same material with same_surface), else 1: which
 * pixels an anti-aliasing sample shaded once a pixel traces and shades itself. */
__kernel void mark_changed(
    __global const int *face,               /* (P,) */
    __global const float *position,         /* (P, 3) */
    __global const int *reference_face,     /* (P,) */
    __global const float *reference_position, /* (P, 3) */
    __global const float *face_normals,     /* (F, 3) unit, original face order */
    __global const int *face_material,      /* (F,) */
    const float eye_x, const float eye_y, const float eye_z,
    const int n_pixels,
    __global uchar *changed)                /* (P,) */
{
    int p = get_global_id(0);
    if (p >= n_pixels)
        return;
    int f = face[p], f0 = reference_face[p];
    uchar flag = 1;
    if (f == f0) {
        flag = 0;
    } else if (f >= 0 && f0 >= 0 && face_material[f] == face_material[f0]) {
        float3 eye = (float3)(eye_x, eye_y, eye_z);
        float3 x = load3(position, p), x0 = load3(reference_position, p);
        if (same_surface(seen_normal(face_normals, f0, x0, eye), x0, seen_normal(face_normals, f, x, eye), x))
            flag = 0;
    }
    changed[p] = flag;
}
