"""The Monte Carlo reference renderer against closed forms, on every backend present.

Statistical checks use the renderer's own per-pixel standard error σ (the stratified sample variance)
and fixed seeds, so every test is deterministic; each also passed with five other seeds. "Within 4.5σ"
per pixel on smooth integrands; where σ has few degrees of freedom (its variance in a few strata: a sun's
highlight at low sample counts, the tail of an exactly sampled light) the check is the RMS of error/σ
or a relative bound instead, as said at each.
"""

import re

import numpy as np
import pytest
from conftest import flat_tile, vgroove_tile

import warp_biscale as wb
from warp_biscale import montecarlo as mc
from warp_biscale import sg
from warp_biscale.environment import Environment
from warp_biscale.scene import Scene
from warp_biscale.render import render as render_driver
from warp_biscale.scene import Camera, DirectionalLight, Mesh, PointLight, light_sg
from warp_biscale.shading import MIN_COS_VIEW


def _hit_normals(scene, backend):
    """(hit (P,) bool, n (P, 3), position (P, 3)) of every pixel: interpolated shading normals and positions
    (float32 vertex attributes, as the renderers read them), written out here independently of the renderer."""
    g = backend.trace_primary(scene.mesh, scene.camera)
    face = g.face
    hit = face >= 0
    bary = g.bary.astype(np.float64)
    wts = np.stack([1 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], 1)
    tri = scene.mesh.faces[np.maximum(face, 0)]
    n = np.einsum("pk,pkc->pc", wts, scene.mesh.normals.astype(np.float32)[tri].astype(np.float64))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    pos = np.einsum("pk,pkc->pc", wts, scene.mesh.vertices.astype(np.float32)[tri].astype(np.float64))
    return hit, n, pos


def _z(image, expected, stderr):
    return (image - expected) / np.maximum(stderr, 1e-30)


# ---------------------------------------------------------------------------------------------------
# sampling primitives (no backend)
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("eta", [1e-3, 0.5, 30.0, 1e4, 1e6])
def test_vmf_sampling_is_stable_and_matches_its_moments(eta):
    """Sampled 1 − cos θ has mean 1/η − 2e^{−2η}/(1 − e^{−2η}) (= E of the vMF); finite and unit for η up to 1e6."""
    rng = np.random.default_rng(1)
    axis = np.array([0.36, -0.48, 0.8])
    n = 200_000
    w = mc.sample_vmf(np.broadcast_to(axis, (n, 3)), np.full(n, eta), rng.random(n), rng.random(n))
    assert np.isfinite(w).all()
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    one_minus = sg.one_minus_cos(w, axis)
    mean = 1 / eta - 2 * np.exp(-2 * eta) / -np.expm1(-2 * eta) if eta > 1e-2 else 1.0  # uniform: E = 1
    se = one_minus.std() / np.sqrt(n)
    assert abs(one_minus.mean() - mean) < 4 * se + 1e-12 * mean, (one_minus.mean(), mean)
    # Azimuth about the axis is uniform: the mean tangential component vanishes.
    t = w - np.outer(w @ axis, axis)
    assert np.abs(t.mean(0)).max() < 4 * np.sqrt(np.maximum(one_minus.mean() * 2, 1e-300) / n) + 1e-12
    # pdf: its own samples give E[g/p] = ∫g = 1 for g the vMF of twice the sharpness (g/p bounded).
    ratio = mc.vmf_pdf(w, axis, 2 * eta) / mc.vmf_pdf(w, axis, eta)
    assert abs(ratio.mean() - 1) < 4 * ratio.std() / np.sqrt(n) + 1e-9


def _ctx(n_pix=2, seed=3):
    """A few shading points with random frames and view directions above their horizon."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(n_pix, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t1, t2 = mc._basis(n)
    a = rng.random(n_pix)[:, None] * 2 * np.pi
    elevation = np.linspace(0.9, 0.2, n_pix)[:, None]  # cos θo from near-normal to grazing
    wo = elevation * n + np.sqrt(1 - elevation**2) * (np.cos(a) * t1 + np.sin(a) * t2)
    cos_o = np.maximum(np.einsum("ij,ij->i", wo, n), MIN_COS_VIEW)
    wo_local = np.stack([np.einsum("ij,ij->i", wo, t1), np.einsum("ij,ij->i", wo, t2), cos_o], 1)
    return {"n": n, "t": t1, "b": t2, "wo": wo, "wo_local": wo_local / np.linalg.norm(wo_local, axis=1)[:, None],
            "pos": np.zeros((n_pix, 3))}


def _check_strategy(strategy, ctx, g, integral, samples=100_000, seed=0):
    """E_{ω~p}[g(ω)/p(ω)] = ∫g for each pixel: p is the exact density of the strategy's samples (where g > 0)."""
    rng = np.random.default_rng(seed)
    w = strategy.sample(ctx, rng.random((strategy.dims, len(ctx["n"]), samples)))  # i.i.d.: w ~ p exactly
    assert np.isfinite(w).all()
    np.testing.assert_allclose(np.linalg.norm(w, axis=-1), 1.0, atol=1e-9)
    y = g(w) / strategy.pdf(ctx, w)
    mean, se = y.mean(1), y.std(1) / np.sqrt(samples)
    integral = np.broadcast_to(integral, mean.shape)
    assert np.all(np.abs(mean - integral) < 4 * se + 1e-9 * integral), (mean, integral, se)
    assert np.all(np.abs(mean - integral) < 0.02 * integral), (mean, integral)


def test_environment_strategy_pdf_is_its_density():
    """A sky with a sun: p > 0 everywhere, so E[1/p] = 4π; and E[L/p] = ∫L_bilinear (by a fine grid)."""
    env = Environment.sky(height=16, width=32)
    s = mc._EnvironmentStrategy(env)
    ctx = _ctx(1)
    _check_strategy(s, ctx, lambda w: np.ones(w.shape[:-1]), 4 * np.pi)
    # ∫ of the bilinear lookup by the midpoint rule in (cos θ, φ) on a grid far finer than the texels.
    cos_t = 1 - 2 * (np.arange(512) + 0.5) / 512
    phi = 2 * np.pi * (np.arange(1024) + 0.5) / 1024
    st = np.sqrt(1 - cos_t**2)[:, None]
    d = np.stack(np.broadcast_arrays(st * np.cos(phi), cos_t[:, None], st * np.sin(phi)), -1)
    total = env.lookup(d).mean(-1).mean() * 4 * np.pi
    _check_strategy(s, ctx, lambda w: env.lookup(w).mean(-1), total)
    # L/p is bounded (the point of sampling the bilinear cells): at most 4x the cell's mean over its total.
    w = s.sample(ctx, np.random.default_rng(5).random((s.dims, 1, 50_000)))
    assert (env.lookup(w).mean(-1) / s.pdf(ctx, w)).max() <= 4 * s.total * (1 + 1e-9)


def test_cosine_and_light_strategies_pdf_is_their_density():
    ctx = _ctx(2)
    n = ctx["n"]
    _check_strategy(mc._CosineStrategy(), ctx, lambda w: np.maximum(np.einsum("bnc,bc->bn", w, n), 0) ** 2,
                    2 * np.pi / 3)
    lights = np.array([DirectionalLight((0.2, 1, 0.3), 1.0, 5.0).packed(), PointLight((1, 2, 0), 3.0, 0.2).packed()])
    axis, eta, _, _ = light_sg(lights, ctx["pos"])
    ctx.update(light_axis=axis, light_eta=eta)
    for k in range(2):
        ax, et = axis[:, k], eta[:, k]
        _check_strategy(mc._LightStrategy(k), ctx, lambda w, ax=ax, et=et: mc.vmf_pdf(w, ax[:, None], 2 * et[:, None]),
                        1.0)


@pytest.mark.parametrize("brdf", [wb.BlinnPhong(1.0, 2.0), wb.BlinnPhong(1.0, 200.0), wb.CookTorrance(1.0, 0.3),
                                  wb.Ward(1.0, 0.05)], ids=lambda b: f"{type(b).__name__}")
def test_glossy_strategy_pdf_is_its_density(brdf):
    """Half-vector vMF reflected about ωo, pdf with the 1/(4 ωo·h) Jacobian and both ±h (which matter for a
    broad lobe: Blinn–Phong exponent 2). g: a unit vMF about the mirror direction, sharp enough that g/p is
    bounded (sharper than the reflected lobe)."""
    ctx = _ctx(2)
    eta_s = mc._glossy_eta(brdf)
    s = mc._GlossyStrategy(eta_s)
    n, wo = ctx["n"], ctx["wo"]
    cos_o = np.einsum("ij,ij->i", wo, n)
    r = 2 * cos_o[:, None] * n - wo
    kappa = max(eta_s, 1.0) / cos_o**2  # sharper than the reflected lobe in every direction, even at grazing ωo
    _check_strategy(s, ctx, lambda w: mc.vmf_pdf(w, r[:, None], kappa[:, None]), 1.0)


@pytest.mark.parametrize("brdf", [wb.AnisotropicWard(1.0, 0.08, 0.4), wb.AshikhminShirley(nu=20, nv=400),
                                  wb.AshikhminShirley(nu=1, nv=3)], ids=["ward", "ashikhmin-shirley", "broad"])
def test_asg_glossy_strategy_pdf_is_its_density(brdf):
    """An anisotropic BRDF's half vector from its NDF's ASG in the pixel's tangent frame, reflected about ωo:
    E[g/p] = ∫g for g a unit vMF about the mirror direction sharper than the reflected lobe along both axes
    (g/p bounded); and the pdf is 0 nowhere the BRDF's lobe is."""
    ctx = _ctx(2)
    s = mc._AnalyticMaterial(brdf).strategy
    assert isinstance(s, mc._AsgGlossyStrategy) and (s.lam, s.mu) == brdf.ndf_bandwidths
    n, wo = ctx["n"], ctx["wo"]
    cos_o = np.einsum("ij,ij->i", wo, n)
    r = 2 * cos_o[:, None] * n - wo
    kappa = 2 * max(s.lam, s.mu, 1.0) / cos_o**2
    _check_strategy(s, ctx, lambda w: mc.vmf_pdf(w, r[:, None], kappa[:, None]), 1.0)
    assert (s.pdf(ctx, r[:, None]) > 0).all()


def test_lobe_mixture_strategy_pdf_is_its_density():
    """An effective BRDF with a specular sub-material: its warped-lobe vMF mixture samples what its pdf says."""
    mat = wb.bake(vgroove_tile(), [wb.BlinnPhong(1.0, 64.0, kd=0.1)], lobes=2, directions=6, facets=1 << 10)
    ctx = _ctx(2)
    s = mc._LobeMixtureStrategy(mat, [(0, mc._glossy_eta(mat.materials[0]))])
    s.setup(ctx)
    assert s.axis.shape == (2, 2, 3) and np.allclose(s.weight.sum(1), 1.0)

    def g(w):  # the mixture with every lobe twice as sharp: ∫ = 1 and g/p bounded
        return sum(s.weight[:, q, None] * mc.vmf_pdf(w, s.axis[:, None, q], 2 * s.eta[:, q, None])
                   for q in range(s.weight.shape[1]))

    _check_strategy(s, ctx, g, 1.0)


def test_asg_lobe_mixture_strategy_pdf_is_its_density():
    """An ASG material (Xu 2013): its warped lobes G_j ⊛ SG_s sampled as ASGs (`sample_asg`), the mixture's pdf
    the density of its samples; g: a unit vMF about each lobe's axis sharper than the lobe along both axes."""
    tile = wb.geometry.grooves(profile="u")
    mat = wb.bake(tile, [wb.CookTorrance(0.7, 0.15, kd=0.2)] * tile.n_materials, method="asg", lobes=2,
                  directions=4, facets=1 << 10, backend="warp:cpu")
    ctx = _ctx(2)
    s = mc._LobeMixtureStrategy(mat, [(0, mc._glossy_eta(mat.materials[0]))])
    s.setup(ctx)
    x, y, z, lam, mu = s.asg
    assert z.shape == (2, 2, 3) and np.allclose(s.weight.sum(1), 1.0)
    assert (np.maximum(lam, mu) > 4 * np.minimum(lam, mu)).any()  # anisotropic lobes

    def g(w):
        return sum(s.weight[:, q, None] * mc.vmf_pdf(w, z[:, None, q], 4 * np.maximum(lam, mu)[:, q, None] + 1.0)
                   for q in range(s.weight.shape[1]))

    _check_strategy(s, ctx, g, 1.0)


# ---------------------------------------------------------------------------------------------------
# whole images against closed forms (every backend)
# ---------------------------------------------------------------------------------------------------


def test_furnace_lambertian_sphere_is_albedo_times_radiance(backend):
    """Constant environment L = 1, a lone Lambertian sphere: every hit pixel is albedo·L = 0.5, within 4σ and 1 %
    (the only bias: directions between the shading and the geometric normal's horizons, ≤ δ²/4 ≈ 5e-4 relative for
    the icosphere's δ ≲ 2.5°). Background pixels are the environment along the camera ray."""
    mesh = Mesh.sphere(1.0, subdivisions=4)
    cam = Camera(eye=(0, 0, 4), fov=34, width=12, height=12)
    scene = Scene(mesh, [wb.Lambert(0.5)], cam, Environment(np.full((16, 32, 3), 1.0, np.float32)))
    r = mc.render(scene, backend=backend, samples=8192, seed=2)
    hit = r.info["stderr"].max(-1) > 0
    assert hit.sum() == r.info["hit_pixels"] >= 60
    assert r.info["stderr_max"] < 0.00125  # so that 1 % is more than 4σ
    assert list(r.info["strategies"][0]) == ["environment", "cosine"] and r.info["clamped"] == 0
    z = _z(r.image[hit], 0.5, r.info["stderr"][hit])
    assert np.abs(z).max() < 4, np.abs(z).max()
    assert np.abs(r.image[hit] - 0.5).max() < 0.005
    np.testing.assert_array_equal(r.image[~hit], 1.0)


def _frames(scene, backend):
    """Per hit pixel: n, t, b, ωo (world), ωo in (t, b, n), and the viewer-side geometric normal, built as the
    spec says (shading.shade_reference): float32 vertex attributes interpolated, tangent orthonormalised."""
    from warp_biscale.scene import vertex_tangents

    mesh = scene.mesh
    g = backend.trace_primary(mesh, scene.camera)
    hit = np.flatnonzero(g.face >= 0)
    f = g.face[hit]
    bary = g.bary[hit].astype(np.float64)
    wts = np.stack([1 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], 1)

    def interp(a):
        return np.einsum("pk,pkc->pc", wts, a.astype(np.float32)[mesh.faces[f]].astype(np.float64))

    pos, n, t = interp(mesh.vertices), interp(mesh.normals), interp(vertex_tangents(mesh))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t -= n * np.einsum("pc,pc->p", t, n)[:, None]
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    wo = scene.camera.packed()[0:3].astype(np.float64) - pos
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    ng = mesh.face_normals[f]
    ng *= np.sign(np.einsum("pc,pc->p", ng, wo))[:, None]
    wo_local = np.stack([np.einsum("pc,pc->p", wo, x) for x in (t, b, n)], 1)
    assert wo_local[:, 2].min() > MIN_COS_VIEW  # no clamping in these scenes: ωo is the true view direction
    return hit, n, t, b, wo, wo_local, ng


def _furnace_quadrature(frames, fbar, k=96):
    """∫ F(ω)·[ng·ω > 0] dω over the hemisphere of n per pixel by the midpoint rule in (cos θ, φ) (k × 2k cells):
    what a sphere under a unit constant environment reflects. fbar(p, ω_local (M, 3), ω (M, 3)) → (M, 3)."""
    hit, n, t, b, wo, wo_local, ng = frames
    cos_t = (np.arange(k) + 0.5) / k
    phi = np.pi * (np.arange(2 * k) + 0.5) / k
    st = np.sqrt(1 - cos_t**2)[:, None]
    local = np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), cos_t[:, None]), -1).reshape(-1, 3)
    d_omega = 2 * np.pi / (2 * k * k)
    out = np.zeros((len(hit), 3))
    for p in range(len(hit)):
        w = local @ np.stack([t[p], b[p], n[p]])
        vis = (w @ ng[p] > 0)[:, None]
        out[p] = (fbar(p, local, w) * vis).sum(0) * d_omega
    return out


def test_furnace_glossy_sphere_matches_quadrature(backend):
    """A Blinn–Phong sphere (kd and a lobe of exponent 32) in a unit constant environment: each pixel is
    ∫ f·cos·[ng·ω > 0] dω, by quadrature. Exercises the half-vector strategy and its MIS with the others."""
    brdf = wb.BlinnPhong(0.6, 32.0, kd=(0.3, 0.2, 0.1))
    cam = Camera(eye=(0, 0, 4), fov=34, width=8, height=8)
    scene = Scene(Mesh.sphere(1.0, subdivisions=4), [brdf], cam, Environment(np.ones((8, 16, 3), np.float32)))
    r = mc.render(scene, backend=backend, samples=2048, seed=5)
    assert list(r.info["strategies"][0]) == ["environment", "cosine", "brdf"] and r.info["clamped"] == 0
    frames = _frames(scene, backend)
    n, wo = frames[1], frames[4]
    expected = _furnace_quadrature(frames, lambda p, wl, w: brdf.eval(np.broadcast_to(n[p], w.shape), w,
                                                                        np.broadcast_to(wo[p], w.shape)) * wl[:, 2:3])
    img, err = r.image.reshape(-1, 3)[frames[0]], r.info["stderr"].reshape(-1, 3)[frames[0]]
    assert np.abs(_z(img, expected, err)).max() < 4.5
    np.testing.assert_allclose(img, expected, rtol=0.08)  # a sanity bound: σ is ~1 % per pixel at 2048 spp


def test_furnace_glossy_effective_material_matches_quadrature(backend):
    """A baked glossy V-groove (anisotropic: the tangent frame matters) with its ground truth in a unit constant
    environment: each pixel is ∫ f̄(ω_local, ωo_local)·[ng·ω > 0] dω, by quadrature of the same truth.
    Exercises the warped-lobe mixture strategy and the tile frame."""
    tile = vgroove_tile()
    mats = [wb.BlinnPhong(0.8, 32.0, kd=0.2)]
    mat = wb.bake(tile, mats, lobes=2, directions=6, facets=1 << 12, backend=backend)
    gt = wb.ground_truth(tile, mats, facets=1 << 12, directions=6, backend=backend)
    cam = Camera(eye=(0, 0, 4), fov=34, width=8, height=8)
    scene = Scene(Mesh.sphere(1.0, subdivisions=4), [mat], cam, Environment(np.ones((8, 16, 3), np.float32)))
    r = mc.render(scene, backend=backend, samples=2048, seed=6, truths={0: gt})
    assert list(r.info["strategies"][0]) == ["environment", "cosine", "brdf"] and r.info["clamped"] == 0
    frames = _frames(scene, backend)
    wo_local = frames[5]
    expected = _furnace_quadrature(frames, lambda p, wl, w: gt.eval(wl, np.broadcast_to(wo_local[p], wl.shape)),
                                   k=64)
    img, err = r.image.reshape(-1, 3)[frames[0]], r.info["stderr"].reshape(-1, 3)[frames[0]]
    assert np.abs(_z(img, expected, err)).max() < 4.5
    # A sanity bound: the V-groove's f̄ is multi-modal (two walls, masking), σ ~1.5 % per pixel at 2048 spp.
    np.testing.assert_allclose(img, expected, rtol=0.1)


def test_directional_light_on_lambertian_sphere_matches_closed_form(backend):
    """kd/π·E·cosine_fraction(n·l, η) per pixel (the SG emitter's exact cosine integral), n the interpolated
    normal. Pixels within ~12° of the terminator are left out: there the geometric normal's horizon (V = 0
    below it, as for the SG renderer's shadow ray) cuts the emitter's lobe, which the closed form does not."""
    mesh = Mesh.sphere(1.0, subdivisions=4)
    light = DirectionalLight((0.5, 0.7, 0.5), irradiance=(2.0, 1.0, 0.5), angular_radius=3.0)
    kd = np.array([0.7, 0.5, 0.3])
    scene = Scene(mesh, [wb.Lambert(kd)], Camera(eye=(0, 0, 4), fov=32, width=24, height=24), None, [light])
    r = mc.render(scene, backend=backend, samples=128, seed=4)
    hit, n, pos = _hit_normals(scene, backend)
    hit = hit.reshape(24, 24)
    assert r.info["strategies"] == {0: {"light 0": 128}}
    np.testing.assert_array_equal(r.image[~hit], 0.0)  # no environment: black background
    axis, eta, amp, _ = light_sg(scene.lights_packed, pos)
    c = np.einsum("pc,pc->p", n, axis[:, 0])
    irradiance = sg.integral(eta[:, 0], 1.0) * sg.cosine_fraction(c, eta[:, 0])
    expected = ((kd / np.pi)[None] * irradiance[:, None] * amp[:, 0]).reshape(24, 24, 3)
    lit = hit & (c.reshape(24, 24) > 0.2)
    assert lit.sum() > 100
    z = _z(r.image[lit], expected[lit], r.info["stderr"][lit])
    assert np.abs(z).max() < 4.5, np.abs(z).max()
    np.testing.assert_allclose(r.image[lit], expected[lit], rtol=0.05)  # near n·l = 0.2 a 3° light spans ±25 % in cos
    dark = hit & (c.reshape(24, 24) < -0.2)
    assert dark.any() and r.image[dark].max() < 1e-12  # the emitter's tail there is e^(-580) or less


def test_shadow_of_a_sphere_on_a_plane(backend):
    """A light from straight above: plane pixels under the sphere get nothing (within 0.6 of the axis the sphere
    covers 12° or more around the emitter, whose radiance there is < 1e-16 of its peak); plane pixels far from it
    get the unshadowed closed form kd/π·E·cosine_fraction(1, η)."""
    sphere = Mesh.sphere(1.0, center=(0, 1.5, 0), subdivisions=3)
    plane = Mesh.plane(8.0, height=0.0, divisions=4, material=1)
    mesh = Mesh.merge([sphere, plane])
    light = DirectionalLight((0, 1, 0), irradiance=3.0, angular_radius=2.0)
    cam = Camera(eye=(0, 1.0, 6), target=(0, 0, -0.5), fov=40, width=24, height=24)  # low: sees under the sphere
    scene = Scene(mesh, [wb.Lambert(0.8), wb.Lambert(0.6)], cam, None, [light])
    r = mc.render(scene, backend=backend, samples=64, seed=1)
    g = backend.trace_primary(mesh, cam)
    on_plane = (g.face >= len(sphere.faces)).reshape(24, 24)
    radial = np.hypot(g.position[:, 0], g.position[:, 2]).reshape(24, 24)
    _, eta, _, _ = light_sg(scene.lights_packed, np.zeros((1, 3)))
    open_sky = 0.6 / np.pi * 3.0 * float(sg.cosine_fraction(1.0, eta[0, 0]))
    under = on_plane & (radial < 0.6)
    far = on_plane & (radial > 2.0)
    assert under.sum() >= 4 and far.sum() >= 100
    assert r.image[under].max() < 1e-6 * open_sky
    # The emitter is sampled exactly and its polar angle stratified: the only noise is cos θ across a 2° lobe,
    # ~1e-5 relative. (σ is not used here: at that level it sits in the one stratum holding the lobe's tail, so
    # its estimate has few degrees of freedom.)
    np.testing.assert_allclose(r.image[far], open_sky, rtol=1e-4)


def test_point_light_is_not_shadowed_by_geometry_behind_it(backend):
    """A point light between a plane and a big sphere above it: rays towards the light hit the sphere beyond the
    light, which must not shadow it (its shadow ray stops at the light, as trace_shadows'). Closed form per pixel
    from `light_sg` at the pixel's position: kd/π·∫G·cosine_fraction(n·l̂, η)."""
    sphere = Mesh.sphere(1.5, center=(0, 3.0, 0), subdivisions=3)
    plane = Mesh.plane(6.0, height=0.0, divisions=4, material=1)
    mesh = Mesh.merge([sphere, plane])
    light = PointLight((0.0, 1.0, 0.0), intensity=2.0, radius=0.05)
    cam = Camera(eye=(0, 1.2, 4), target=(0, 0, 0), fov=50, width=24, height=24)
    scene = Scene(mesh, [wb.Lambert(0.5), wb.Lambert(0.5)], cam, None, [light])
    r = mc.render(scene, backend=backend, samples=64, seed=3)
    hit, n, pos = _hit_normals(scene, backend)
    g = backend.trace_primary(mesh, cam)
    on_plane = g.face >= len(sphere.faces)
    axis, eta, amp, _ = light_sg(scene.lights_packed, pos)
    c = np.einsum("pc,pc->p", n, axis[:, 0])
    expected = 0.5 / np.pi * (sg.integral(eta[:, 0]) * sg.cosine_fraction(c, eta[:, 0]))[:, None] * amp[:, 0]
    sel = on_plane & (c > 0.2)
    assert sel.sum() > 100
    img, err = r.image.reshape(-1, 3)[sel], r.info["stderr"].reshape(-1, 3)[sel]
    assert np.abs(_z(img, expected[sel], err)).max() < 4.5
    np.testing.assert_allclose(img, expected[sel], rtol=0.05)


def test_effective_flat_lambert_renders_like_lambert(backend):
    """A flat Lambertian tile's f̄ is kd/π·cos θi: with its ground truth, the effective material renders like
    Lambert(0.5) (same strategies and seed, so the same samples: equal to rounding). With fallback="sg" and no
    truth the renderer warns, says so in info, and uses the SG fit (exact for this tile too)."""
    tile = flat_tile()
    mat = wb.bake(tile, wb.Lambert(0.5), lobes=1, directions=6, facets=1 << 10, backend=backend)
    gt = wb.ground_truth(tile, [wb.Lambert(0.5)], facets=1 << 10, directions=6, backend=backend)
    mesh = Mesh.sphere(1.0, subdivisions=3)
    env = Environment.sky(height=16, width=32)
    lights = [DirectionalLight((0.3, 0.5, 0.8), 1.5, 4.0)]
    cam = Camera(eye=(0, 0.5, 4), fov=34, width=24, height=24)
    ref = mc.render(Scene(mesh, [wb.Lambert(0.5)], cam, env, lights), backend=backend, samples=48)
    r = mc.render(Scene(mesh, [mat], cam, env, lights), backend=backend, samples=48, truths={0: gt})
    assert "ground truth" in r.info["effective_brdf"][0]
    assert r.info["strategies"] == ref.info["strategies"]
    assert list(r.info["strategies"][0]) == ["environment", "cosine", "light 0"]
    np.testing.assert_allclose(r.image, ref.image, rtol=1e-5, atol=1e-7)
    with pytest.warns(UserWarning, match="no ground truth"):
        r2 = mc.render(Scene(mesh, [mat], cam, env, lights), backend=backend, samples=48, fallback="sg")
    assert "sg-exact" in r2.info["effective_brdf"][0]
    np.testing.assert_allclose(r2.image, ref.image, rtol=1e-5, atol=1e-7)
    # Background pixels: the environment along the camera ray.
    miss = r.info["stderr"].max(-1) == 0
    np.testing.assert_allclose(r.image[miss], env.lookup(cam.rays()[1]).reshape(24, 24, 3)[miss], rtol=1e-6)


def test_glossy_effective_material_renders_finite_with_its_brdf_strategy(backend):
    """A baked V-groove with a glossy sub-material: the warped-lobe strategy is used, nothing is clamped, the
    image is finite and >= 0, and with the ground truth it is close to the image of the SG fit (sg-exact,
    fallback="sg"): the two f̄ differ by the bake's error, a few per cent here."""
    tile = vgroove_tile()
    mats = [wb.BlinnPhong(0.8, 32.0, kd=0.2)]
    mat = wb.bake(tile, mats, lobes=2, directions=6, facets=1 << 12, backend=backend)
    gt = wb.ground_truth(tile, mats, facets=1 << 12, directions=6, backend=backend)
    scene = Scene(Mesh.sphere(1.0, subdivisions=3), [mat], Camera(eye=(0, 0, 4), fov=34, width=16, height=16),
                  Environment.sky(height=16, width=32), [PointLight((2, 2, 3), 10.0, 0.1)])
    r = mc.render(scene, backend=backend, samples=32, truths=[gt])
    assert list(r.info["strategies"][0]) == ["environment", "cosine", "brdf", "light 0"]
    assert r.info["clamped"] == 0 and np.isfinite(r.image).all() and (r.image >= 0).all()
    with pytest.warns(UserWarning):
        r2 = mc.render(scene, backend=backend, samples=32, fallback="sg")
    hit = r.info["stderr"].max(-1) > 0
    assert abs(r.image[hit].mean() / r2.image[hit].mean() - 1) < 0.3


def test_stderr_shrinks_with_samples_and_seed_is_deterministic(backend):
    mesh = Mesh.sphere(1.0, subdivisions=3)
    scene = Scene(mesh, [wb.BlinnPhong(0.5, 64.0, kd=0.3)], Camera(eye=(0, 0, 4), fov=34, width=16, height=16),
                  Environment.sky(height=16, width=32))
    a = mc.render(scene, backend=backend, samples=32, seed=7)
    b = mc.render(scene, backend=backend, samples=512, seed=7)
    # 16× the samples: σ falls at least as 1/√N (4×); stratification makes it fall faster on smooth integrands
    # (here ~6×), never faster than 1/N.
    ratio = a.info["stderr_rms"] / b.info["stderr_rms"]
    assert 3.2 < ratio < 16, ratio
    hit = a.info["stderr"].max(-1) > 0
    z = _z(a.image[hit], b.image[hit], np.hypot(a.info["stderr"][hit], b.info["stderr"][hit]))
    assert np.sqrt(np.mean(z**2)) < 1.5  # RMS, not max: at 32 spp the sun's highlight makes a heavy tail
    again = render_driver(scene, method="mc", backend=backend, samples=32, seed=7)  # the driver delegates here
    np.testing.assert_array_equal(again.image, a.image)
    assert again.info["method"] == "mc" and again.info["samples"] == 32
    other = mc.render(scene, backend=backend, samples=32, seed=8)
    assert not np.array_equal(other.image, a.image)
    # Batching changes which pixels share a random stream (so the image), not the statistics.
    small = mc.render(scene, backend=backend, samples=32, seed=7, batch=100)
    assert not np.array_equal(small.image, a.image)
    z = _z(small.image[hit], b.image[hit], np.hypot(small.info["stderr"][hit], b.info["stderr"][hit]))
    assert np.sqrt(np.mean(z**2)) < 1.5  # RMS, not max: at 32 spp the sun's highlight makes a heavy tail


def test_bad_options_are_named():
    mesh = Mesh.sphere(1.0, subdivisions=1)
    mat = wb.bake(flat_tile(), wb.Lambert(0.5), lobes=1, directions=4, facets=256)
    gt = wb.ground_truth(flat_tile(), [wb.Lambert(0.5)], facets=256, directions=4)
    scene = Scene(mesh, [wb.Lambert(0.5), mat], Camera(width=4, height=4))
    for bad in (0, 1, -3, 2.5, "many"):
        with pytest.raises(ValueError, match="samples"):
            mc.render(scene, samples=bad)
    with pytest.raises(ValueError, match="seed"):
        mc.render(scene, seed=-1)
    with pytest.raises(ValueError, match="batch"):
        mc.render(scene, batch=0)
    with pytest.raises(ValueError, match="material index 5"):
        mc.render(scene, truths={5: gt})
    with pytest.raises(ValueError, match=r"truths\[0\].*analytic"):
        mc.render(scene, truths={0: gt})
    with pytest.raises(ValueError, match=r"truths\[1\] must be a GroundTruth"):
        mc.render(scene, truths={1: "table.npz"})
    with pytest.raises(ValueError, match="scene"):
        mc.render(mesh)
    # Too few samples for a material's sampling strategies: the message says how many are needed.
    lit = Scene(mesh, [wb.Lambert(0.5)], Camera(width=4, height=4), wb.Environment.sky(height=8, width=16),
                [wb.PointLight((2, 3, 2), 20.0)])
    with pytest.raises(ValueError, match=r"^samples=3 is too few for material 0's (\d) sampling strategies "
                                         r"\([\w ]+(, [\w ]+)+\): give at least (\d+) \(2 each\)$") as err:
        mc.render(lit, samples=3)
    n, need = re.search(r"'s (\d) sampling.*least (\d+)", str(err.value)).groups()
    assert int(need) == 2 * int(n)
    with pytest.raises(ValueError, match="method"):
        render_driver(scene, method="path")
