"""Lit-sphere shading (seed 004 Eq. 1–4): the litsphere stage.

Twin of ``cl/litsphere.cl``; the mathematics and the packed inputs are ``warp_biscale.litsphere``
(``reference_shade`` is the float64 oracle of one light's lookup, ``SpherePack`` the layout). One
thread per pixel: the surface normal from the G-buffer, a mip level from the normal's change to the
next pixels, then per light the images' frame (z the view direction, x towards the light), the two
images bracketing the light's polar angle, each read at the normal turned about y (trilinear), blended.
"""

import warp as wp

from warp_biscale import litsphere as _ls

from .common import brdf_cosine_weighted
from .shade import (PI, camera_ray, finite_radiance, grid_corners, grid_weights, ndf_sharpness, prefiltered,
                    specular_scale, table_rgb)

# Fast math on CUDA (approximate division, square root and trigonometry, ~1e-5 relative against the
# float64 oracle, far inside the tests' tolerances): this shading is bound by its arithmetic. cl/'s twin
# is built alike (opencl_backend.FAST_MATH).
# (enable_backward off: nothing here is differentiated, and backward kernels take most of the compile time)
wp.set_module_options({"fast_math": True, "enable_backward": False})

K_OUTSIDE = wp.constant(_ls.K_OUTSIDE)
RIM = wp.constant(_ls.RIM)
EDGE = wp.constant(0.5)  # a neighbour whose normal differs more is across an edge: no footprint from it


@wp.func
def pixel_normal(faces: wp.array2d(dtype=wp.int32), normals: wp.array(dtype=wp.vec3), f: int,
                 bary: wp.vec2) -> wp.vec3:
    w0 = 1.0 - bary[0] - bary[1]
    return wp.normalize(w0 * normals[faces[f, 0]] + bary[0] * normals[faces[f, 1]] + bary[1] * normals[faces[f, 2]])


@wp.func
def normal_step(face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec2), faces: wp.array2d(dtype=wp.int32),
                normals: wp.array(dtype=wp.vec3), q: int, n: wp.vec3) -> float:
    """|n(q) − n| for the neighbouring pixel q, 0 where q misses or lies across an edge."""
    g = face[q]
    if g < 0:
        return 0.0
    d = wp.length(pixel_normal(faces, normals, g, bary[q]) - n)
    if d > EDGE:
        return 0.0
    return d


@wp.func
def bilinear(texels: wp.array(dtype=wp.vec3), offset: int, size: int, u: float, v: float) -> wp.vec3:
    """Bilinear lookup at (u, v) ∈ [0, 1]², v up, of a size² level stored row-major from the top; clamped."""
    fs = float(size)
    fx = wp.clamp(u * fs - 0.5, 0.0, fs - 1.0)
    fy = wp.clamp((1.0 - v) * fs - 0.5, 0.0, fs - 1.0)
    x0 = wp.min(int(wp.floor(fx)), size - 2)
    y0 = wp.min(int(wp.floor(fy)), size - 2)
    ax = fx - float(x0)
    ay = fy - float(y0)
    r0 = offset + y0 * size + x0
    r1 = r0 + size
    return ((1.0 - ay) * ((1.0 - ax) * texels[r0] + ax * texels[r0 + 1])
            + ay * ((1.0 - ax) * texels[r1] + ax * texels[r1 + 1]))


@wp.func
def trilinear(texels: wp.array(dtype=wp.vec3), level_info: wp.array2d(dtype=wp.int32), row: int, n_levels: int,
              u: float, v: float, lod: float) -> wp.vec3:
    """Image `row`'s pyramid (its level 0 at level_info[row]) read at mip level `lod`."""
    t = wp.clamp(lod, 0.0, float(n_levels - 1))
    lo = int(wp.floor(t))
    f = t - float(lo)
    hi = wp.min(lo + 1, n_levels - 1)
    a = bilinear(texels, level_info[row + lo, 0], level_info[row + lo, 1], u, v)
    if f <= 0.0:  # a footprint within a texel (most pixels of a close object): one level read
        return a
    b = bilinear(texels, level_info[row + hi, 0], level_info[row + hi, 1], u, v)
    return (1.0 - f) * a + f * b


@wp.func
def rim_point(rx: float, ry: float, rz: float, phi_i: float) -> wp.vec2:
    """litsphere.rim_point: (x, y) read for the turned normal r in image i's frame."""
    c = rx * wp.sin(phi_i) + rz * wp.cos(phi_i)
    s = wp.sqrt(wp.max(1.0 - c * c, 0.0))
    across = s * wp.sin(phi_i)
    if rz >= 0.0 or across <= 1.0e-6:
        return wp.vec2(rx, ry)
    sin_b = wp.clamp(-c * wp.cos(phi_i) / across, -1.0, 1.0)
    cos_b = wp.sqrt(1.0 - sin_b * sin_b)
    if ry < 0.0:
        cos_b = -cos_b
    return wp.vec2(c * wp.sin(phi_i) - s * sin_b * wp.cos(phi_i), s * cos_b)


@wp.func
def sphere_lookup(n: wp.vec3, view: wp.vec3, light: wp.vec3, lod: float, shrink: float, s: int,
                  sphere_info: wp.array2d(dtype=wp.int32), angles: wp.array(dtype=wp.vec3),
                  level_info: wp.array2d(dtype=wp.int32), texels: wp.array(dtype=wp.vec3)) -> wp.vec3:
    """Radiance per unit irradiance of normal n seen from `view`, lit from `light`: litsphere.reference_shade.
    The shading is bound by its arithmetic, so the half angle, sin αh and the diffuse share's turn come from
    cos φ, sin φ and each image's (cos φi, sin φi) by identities instead of trigonometric calls."""
    z = view
    x = light - wp.dot(light, z) * z
    cos_phi = wp.dot(light, z)
    sin_phi = wp.length(x)
    # (atan2 of the across and along parts: exact where l is near ±v, where acos loses float32 digits)
    phi = wp.atan2(sin_phi, cos_phi)
    if sin_phi <= 1.0e-6:  # the light along the view axis: any x (the images are symmetric about it)
        ref = wp.vec3(0.0, 1.0, 0.0)
        if wp.abs(z[0]) < 0.9:
            ref = wp.vec3(1.0, 0.0, 0.0)
        x = ref - wp.dot(ref, z) * z
    x = wp.normalize(x)
    y = wp.cross(z, x)
    nx = wp.dot(n, x)
    ny = wp.dot(n, y)
    nz = wp.dot(n, z)
    hx = wp.sqrt(wp.max(0.5 * (1.0 - cos_phi), 0.0))  # sin φ/2
    hz = wp.sqrt(wp.max(0.5 * (1.0 + cos_phi), 0.0))  # cos φ/2
    proj = wp.sqrt(nx * nx + nz * nz)
    cos_ah = 0.0
    if proj > 1.0e-12:
        cos_ah = wp.min((hx * nx + hz * nz) / proj, 1.0)
    sin_ah = 1.0  # αh = min(∠, π/2): sin αh = 1 past a right angle
    if cos_ah > 0.0:
        sin_ah = wp.sqrt(1.0 - cos_ah * cos_ah)
    first = sphere_info[s, 0]
    count = sphere_info[s, 1]
    first_row = sphere_info[s, 2]
    n_levels = sphere_info[s, 3]
    n_parts = sphere_info[s, 4]
    # the bracket: angles[i2 − 1] < φ ≤ angles[i2]; outside the angles, the nearest image alone
    i2 = int(0)
    while i2 < count and angles[first + i2][0] < phi:
        i2 += 1
    i1 = i2 - 1
    t = float(0.0)
    k_glossy = 0.5 + 0.5 * sin_ah
    if i2 == 0 or i2 >= count:
        if i2 == 0:
            i1 = 0
        else:
            i1 = count - 1
        i2 = i1
        k_glossy = K_OUTSIDE
    else:
        t = (phi - angles[first + i1][0]) / (angles[first + i2][0] - angles[first + i1][0])
    out = wp.vec3(0.0)
    for part in range(n_parts):
        diffuse = n_parts == 2 and part == 0  # the diffuse share: the exact rotation (k = 1)
        for which in range(2):
            a = i1
            w = 1.0 - t
            if which == 1:
                a = i2
                w = t
            if w > 0.0:
                image = angles[first + a]  # (φi, cos φi, sin φi)
                cos_turn = image[1] * cos_phi + image[2] * sin_phi  # cos(φi − φ)
                sin_turn = image[2] * cos_phi - image[1] * sin_phi  # sin(φi − φ)
                if not diffuse:
                    turn = k_glossy * (image[0] - phi)
                    cos_turn = wp.cos(turn)
                    sin_turn = wp.sin(turn)
                r = wp.vec2(nx * cos_turn + nz * sin_turn, ny)
                if diffuse:
                    r = rim_point(r[0], ny, -nx * sin_turn + nz * cos_turn, image[0])
                u = shrink * r[0] * 0.5 + 0.5
                v = shrink * r[1] * 0.5 + 0.5
                row = first_row + (part * count + a) * n_levels
                out = out + w * trilinear(texels, level_info, row, n_levels, u, v, lod)
    return out


@wp.kernel
def shade_litsphere(
    face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec2), light_vis: wp.array2d(dtype=wp.uint8),
    faces: wp.array2d(dtype=wp.int32), positions: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
    face_material: wp.array(dtype=wp.int32), camera: wp.array(dtype=wp.float32),
    n_lights: int, lights: wp.array2d(dtype=wp.float32), view_mode: int, shrink: float,
    env_maps: wp.array(dtype=wp.vec3), env_levels: wp.array2d(dtype=wp.float32),
    sphere_of_material: wp.array(dtype=wp.int32), sphere_info: wp.array2d(dtype=wp.int32),
    angles: wp.array(dtype=wp.vec3), level_info: wp.array2d(dtype=wp.int32), texels: wp.array(dtype=wp.vec3),
    n_pixels: int, offset: int,
    radiance: wp.array(dtype=wp.vec3),
):
    p = wp.tid() + offset
    if p >= n_pixels:
        return
    f = face[p]
    if f < 0:
        radiance[p] = prefiltered(env_maps, env_levels, camera_ray(camera, p), 1.0e30)
        return
    b = bary[p]
    n = pixel_normal(faces, normals, f, b)
    w0 = 1.0 - b[0] - b[1]
    pos = w0 * positions[faces[f, 0]] + b[0] * positions[faces[f, 1]] + b[1] * positions[faces[f, 2]]
    view = wp.normalize(wp.vec3(camera[0], camera[1], camera[2]) - pos)
    if view_mode == 1:  # the paper's distant viewer: the camera's axis
        view = -wp.normalize(wp.vec3(camera[3], camera[4], camera[5]))
    width = int(camera[12])
    x = p % width
    step = float(0.0)
    if x + 1 < width:
        step = normal_step(face, bary, faces, normals, p + 1, n)
    if p + width < n_pixels:
        step = wp.max(step, normal_step(face, bary, faces, normals, p + width, n))
    s = sphere_of_material[face_material[f]]
    # texels per pixel at level 0: the lookup point moves by shrink·|Δn|/2 of the image's width
    rho = step * 0.5 * shrink * float(level_info[sphere_info[s, 2], 1])
    lod = wp.log2(wp.max(rho, 1.0))
    total = wp.vec3(0.0)
    for l in range(n_lights):
        share = float(light_vis[p, l]) / 255.0
        if share > 0.0:
            light = wp.vec3(lights[l, 1], lights[l, 2], lights[l, 3])
            e = wp.vec3(lights[l, 4], lights[l, 5], lights[l, 6])
            if lights[l, 0] != 0.0:  # a point light: its direction and the inverse-square irradiance
                d = light - pos
                r2 = wp.max(wp.dot(d, d), 1.0e-30)
                light = d / wp.sqrt(r2)
                e = e / r2
            if wp.dot(n, light) > 0.0 and wp.dot(n, view) > 0.0:
                c = sphere_lookup(n, view, light, lod, shrink, s, sphere_info, angles, level_info, texels)
                total = total + share * wp.cw_mul(e, c)
    radiance[p] = finite_radiance(total)


# ---------------------------------------------------------------------------------------------
# The images themselves: the material's response on the texel grid (litsphere.material_response)


@wp.func
def texel_normal(resolution: int, i: int) -> wp.vec3:
    """litsphere.texel_normals: texel i (row-major from the top) of a resolution² image, rim-filled."""
    x = 2.0 * (float(i % resolution) + 0.5) / float(resolution) - 1.0
    y = 1.0 - 2.0 * (float(i / resolution) + 0.5) / float(resolution)
    r = wp.sqrt(x * x + y * y)
    if r > RIM:
        x = x * RIM / r
        y = y * RIM / r
    return wp.vec3(x, y, wp.sqrt(wp.max(1.0 - x * x - y * y, 0.0)))


@wp.func
def effective_response(kinds: wp.array(dtype=wp.int32), params: wp.array2d(dtype=wp.float32),
                       info: wp.array(dtype=wp.int32), lobes: wp.array2d(dtype=wp.float32),
                       amplitudes: wp.array(dtype=wp.float32), wi: wp.vec3, wo: wp.vec3) -> wp.vec3:
    """EffectiveBRDF.eval(ωi, ωo) in the surface's frame (its tables hold the cosine): `info` [K, J, M,
    exact], `lobes` (J, 5) the axis, sharpness and ∫G of each lobe, `amplitudes` the (M, K², K², J, 3)
    table of μ/cos θi at the grid, `kinds`/`params` the small-scale BRDFs (brdf.pack_materials)."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return wp.vec3(0.0)
    k = info[0]
    j_count = info[1]
    k2 = k * k
    oo = grid_corners(wo, k)
    ow = grid_weights(wo, k)
    half = wi + wo
    h = wp.vec3(0.0, 0.0, 1.0)
    if wp.length(half) > 0.0:
        h = wp.normalize(half)
    out = wp.vec3(0.0)
    for m in range(info[2]):
        base = m * k2 * k2 * j_count * 3
        kind = kinds[m]
        kd = wp.vec3(params[m, 0], params[m, 1], params[m, 2]) / PI
        scale = specular_scale(kind, wp.vec3(params[m, 3], params[m, 4], params[m, 5]), params[m, 6], params[m, 7],
                               wp.dot(h, wi))
        eta_s = float(1.0)
        if kind != 0:
            eta_s = ndf_sharpness(kind, params[m, 6])
        for j in range(j_count):
            mu = table_rgb(amplitudes, base, k2, j_count, j, wi, k, oo, ow) * wi[2]
            out = out + wp.cw_mul(kd, mu) * lobes[j, 4]
            if kind != 0:
                axis = wp.vec3(lobes[j, 0], lobes[j, 1], lobes[j, 2])
                eta = lobes[j, 3]
                d = h - axis
                one_minus_cos = 0.5 * wp.dot(d, d)  # 1 − h·ξ without cancellation near the axis
                s = float(0.0)
                if info[3] == 0:  # Eq. 15: the convolved lobe at h (sg.convolve, sg.evaluate)
                    s = 2.0 * PI / (eta + eta_s) * wp.exp(-one_minus_cos / (1.0 / eta + 1.0 / eta_s))
                else:  # Eq. 10: the inner product (sg.inner_product)
                    r = wp.length(eta_s * h + eta * axis)
                    gap = 2.0 * eta * eta_s * one_minus_cos / (eta + eta_s + r)
                    over = 2.0 - 2.0 * r
                    if r > 1.0e-12:
                        over = (1.0 - wp.exp(-2.0 * r)) / r
                    s = 2.0 * PI * wp.exp(-gap) * over
                out = out + wp.cw_mul(scale, mu) * s
    return wp.max(out, wp.vec3(0.0))


@wp.kernel
def sphere_texels(resolution: int, lights: wp.array(dtype=wp.vec3), effective: int,
                  kinds: wp.array(dtype=wp.int32), params: wp.array2d(dtype=wp.float32),
                  info: wp.array(dtype=wp.int32), lobes: wp.array2d(dtype=wp.float32),
                  amplitudes: wp.array(dtype=wp.float32), n_texels: int, offset: int,
                  texels: wp.array(dtype=wp.vec3)):
    """Texel i of image a (i + a·R² = the thread): f(n, l, v)(n·l)⁺ of an analytic BRDF (row 0 of
    kinds/params) or of an effective BRDF (`effective` = 1, in the sphere's longitude frame), v = +Z."""
    t = wp.tid() + offset
    if t >= n_texels:
        return
    per_image = resolution * resolution
    n = texel_normal(resolution, t % per_image)
    light = lights[t / per_image]
    view = wp.vec3(0.0, 0.0, 1.0)
    out = wp.vec3(0.0)
    if effective == 0:
        out = brdf_cosine_weighted(kinds[0], params, 0, n, light, view) / wp.max(n[2], 1.0e-30)
    else:
        # litsphere.sphere_tangents: increasing longitude about +Y, +X at the poles
        tangent = wp.vec3(1.0, 0.0, 0.0)
        across = wp.vec3(n[2], 0.0, -n[0])
        if wp.length(across) > 1.0e-9:
            tangent = wp.normalize(across)
        bitangent = wp.cross(n, tangent)
        wi = wp.vec3(wp.dot(light, tangent), wp.dot(light, bitangent), wp.dot(light, n))
        wo = wp.vec3(wp.dot(view, tangent), wp.dot(view, bitangent), wp.dot(view, n))
        out = effective_response(kinds, params, info, lobes, amplitudes, wi, wo)
    texels[t] = finite_radiance(out)
