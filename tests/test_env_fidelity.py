"""Environment lighting against outside truth: the diffuse term's exact irradiance (closed forms and the
map's own quadrature) and broad-lobe shadows at a contact (the Monte Carlo reference)."""

import warnings

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import lighting
from warp_biscale.environment import (environment_irradiance, equirect_bilinear, equirect_directions,
                                      equirect_row_solid_angles)
from warp_biscale.render import frame_lights, frame_shadow_samples, pack_frame
from warp_biscale.shading import shade_reference

ZENITH = np.array([0.08, 0.18, 0.45])  # Environment.sky's defaults
HORIZON = np.array([0.55, 0.6, 0.65])


@pytest.mark.parametrize("ground", [None, (0.3, 0.28, 0.25), (0.0, 0.0, 0.0), (1.5, 1.2, 0.9)])
def test_floor_under_sky_receives_the_upper_hemispheres_irradiance(backend, ground):
    """A Lambertian floor facing up under a sunless sky receives E = π·zenith + π(horizon − zenith)/10
    whatever the ground below it (Environment.sky's closed form). Within 1 %: measured on Warp CPU 0.17 %
    at most for the first three grounds and 0.67 % (red) under the bright one; before the exact irradiance
    the default ground was 8.1 % high in red and the demo's 30.1 % low in blue."""
    # (the default map for the default ground; a coarser one, the same closed form, for the others: 0.43 % at
    # most measured under the bright ground, the lighting prepared in half the time)
    kw = {} if ground is None else {"ground": ground, "height": 64, "width": 128}
    env = wb.Environment.sky(sun_irradiance=0, **kw)
    floor = wb.Mesh.plane(8.0, 0.0, 8, material=0)
    cam = wb.Camera(eye=(0, 3, 0.01), target=(0, 0, 0), width=16, height=16)
    image = wb.render(wb.Scene(floor, [wb.Lambert(0.45)], cam, env), backend=backend).image
    exact = 0.45 / np.pi * (np.pi * ZENITH + np.pi * (HORIZON - ZENITH) / 10)
    np.testing.assert_allclose(image[4:12, 4:12].reshape(-1, 3), np.broadcast_to(exact, (64, 3)), rtol=0.01)


def _loaded_map(tmp_path):
    """A map as a user loads one: smooth noise, a hot 1-texel light and a dark band, written as EXR and
    read back."""
    rng = np.random.default_rng(7)
    coarse = rng.random((6, 12, 3))
    image = np.kron(coarse, np.ones((16, 16, 1))) * 0.5 + 0.05
    image[20, 40] = [400.0, 380.0, 300.0]
    image[60:64] *= 0.1
    path = tmp_path / "noisy.exr"
    wb.Environment(image.astype(np.float32)).save(path)
    return wb.Environment.from_file(path)


@pytest.mark.parametrize("make", [lambda _: wb.Environment.sky(), lambda _: wb.Environment.sky(sun_angular_radius=0.5),
                                  lambda _: wb.Environment.studio(), lambda _: wb.Environment.constant(0.7),
                                  lambda _: wb.Environment.from_sgs([[0.3, 0.8, 0.5], [0, -1, 0]], [40.0, 3.0],
                                                                    [[6.0, 5.5, 5.0], [0.5, 0.4, 0.3]], constant=0.1),
                                  _loaded_map],
                         ids=["sky", "sky-small-sun", "studio", "constant", "from-sgs", "loaded-exr"])
def test_lobes_plus_residual_is_the_exact_irradiance(make, tmp_path):
    """What the shade stage adds up for an unoccluded normal, the shadow lobes' irradiance plus the
    residual map's bilinear value, against the irradiance by the texel rule at 400 normals of the map it
    lights with (the map without its compact sources, which are lights: `lighting.environment_sources`):
    within 0.5 % of the mean E (measured 0.05–0.25 %; the residual map alone is E's smooth part, where
    interpolating E itself over a sun's terminator errs by 3–4 %)."""
    env = make(tmp_path)
    light = lighting.prepare(env, "warp:cpu")
    normals = lighting.fibonacci_directions(400)
    exact = environment_irradiance(lighting.environment_sources(env).residual.radiance, normals)
    for shadowed in (True, False):  # the six-way split lobes (an SSDF scene) and the fit itself (none)
        lobes, residual = light.diffuse_lobes(shadowed)
        got = lobes.irradiance(normals) + equirect_bilinear(residual, normals)
        assert np.abs(got - exact).max() / exact.mean() < 5e-3, shadowed


@pytest.mark.parametrize("radius, size", [(2.0, (128, 256)), (2.0, (64, 128)), (0.5, (128, 256))])
def test_a_sun_leaves_the_map_as_a_light(radius, size):
    """The sky's sun, found in its texels alone, becomes one directional light: its direction within a fifth of a
    texel row (measured 0.22° for the 0.5° sun on rows of 1.4°), its irradiance within 1 % of the sky's
    `sun_irradiance` and its radius within 15 % (the edge's smoothstep and the texels blur it: measured 2.01°,
    1.90° and 0.46° for 2°, 2° at 64 rows and 0.5°); what is left of the map
    is the sunless sky (no texel brighter than its horizon or zenith), and power is kept exactly."""
    env = wb.Environment.sky(sun_angular_radius=radius, height=size[0], width=size[1])
    found = lighting.environment_sources(env)
    assert lighting.environment_sources(env) is found  # cached on the environment
    assert len(found.lights) == 1 and found.packed.shape == (1, 8)
    sun = found.lights[0]
    true = np.array([0.4, 0.8, 0.3]) / np.linalg.norm([0.4, 0.8, 0.3])
    assert np.degrees(np.arccos(min(float(sun.direction @ true), 1.0))) < 0.2 * 180 / size[0]
    np.testing.assert_allclose(sun.irradiance, [3.0, 2.9, 2.6], rtol=0.01)
    assert abs(sun.angular_radius / radius - 1) < 0.15, sun.angular_radius
    sunless = wb.Environment.sky(sun_irradiance=0, height=size[0], width=size[1])
    assert found.residual.radiance.max() <= sunless.radiance.max() * 1.01
    omega = equirect_row_solid_angles(*size)[:, None, None]
    power = (env.radiance.astype(np.float64) * omega).sum((0, 1))
    kept = (found.residual.radiance.astype(np.float64) * omega).sum((0, 1)) + sun.irradiance
    np.testing.assert_allclose(kept, power, rtol=1e-5)


@pytest.mark.parametrize("make", [lambda: wb.Environment.studio(), lambda: wb.Environment.constant(0.7),
                                  lambda: wb.Environment.sky(sun_irradiance=0),
                                  lambda: wb.Environment.from_sgs([[0.3, 0.8, 0.5]], [40.0], [[6.0, 5.5, 5.0]],
                                                                  constant=0.1)],
                         ids=["studio", "constant", "sunless-sky", "from-sgs"])
def test_broad_lights_stay_in_the_map(make):
    """Softboxes, smooth lobes and constant maps are no compact sources: the map lights as it is."""
    env = make()
    found = lighting.environment_sources(env)
    assert found.lights == [] and found.residual is env
    assert len(lighting.prepare(env, "warp:cpu").sources) == 0


def test_the_sun_is_seen_by_the_camera_alone(backend):
    """With the sun a light, the prefiltered maps keep the map itself in a row that the background alone reads
    (lighting.BACKGROUND_LOG2): a camera ray towards the sun sees it, a lobe as sharp as any (η = SHARPNESS_MAX)
    does not — else a near-mirror material would reflect the sun twice, once as a light. The kernels as their
    float64 reference: the background looking at the sun, and a near-mirror sphere (Blinn–Phong n = 10^5) under
    the sky, within 1e-3 of the peak."""
    env = wb.Environment.sky(height=64, width=128)
    pre = lighting.prepare(env, backend).prefiltered
    assert pre.has_background
    sun = lighting.environment_sources(env).lights[0].direction
    sunless = wb.Environment.sky(sun_irradiance=0, height=64, width=128).radiance.max()
    assert lighting.prefiltered_lookup(pre.maps, pre.levels, sun, wb.sg.SHARPNESS_MAX).max() <= sunless * 1.01
    assert lighting.prefiltered_lookup(pre.maps, pre.levels, sun, 1e30).max() > 100 * sunless
    eye = -3.0 * sun
    mesh = wb.Mesh.sphere(0.5, center=(0.0, -2.0, 0.0), subdivisions=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wb.EnergyWarning)
        mirror = wb.BlinnPhong(1.0, 1e5)
    scene = wb.Scene(mesh, [mirror], wb.Camera(eye=tuple(eye), target=(0.0, -1.2, 0.0), width=32, height=24, fov=70),
                     env)
    frame = pack_frame(scene, backend)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
    ref = shade_reference(frame)
    assert len(frame.lights) == 1  # the sun
    assert (frame.gbuffer.face >= 0).sum() > 20 and out[frame.gbuffer.face < 0].max() > 10 * sunless  # the sun
    np.testing.assert_allclose(out, ref, atol=1e-3 * ref.max(), rtol=2e-3)


def test_a_source_gets_fewer_shadow_rays_than_the_scenes_lights(monkeypatch):
    """A scene's own light gets the frame's shadow rays; the sky's sun, a light of the frame too, at most
    lighting.SOURCE_SHADOW_SAMPLES (its penumbra is narrow; the accuracy cost is measured in bench/README.md)."""
    mesh = wb.Mesh.plane(2.0, 0.0, 2, material=0)
    cam = wb.Camera(eye=(0, 3, 0.01), target=(0, 0, 0), width=8, height=8)
    light = wb.PointLight((0.0, 2.0, 0.0), 5.0, 0.1)
    sky = wb.Scene(mesh, [wb.Lambert(0.5)], cam, wb.Environment.sky(), [light])
    cap = lighting.SOURCE_SHADOW_SAMPLES
    assert len(frame_lights(sky)) == 2
    np.testing.assert_array_equal(frame_shadow_samples(sky, 16), [16, cap])
    np.testing.assert_array_equal(frame_shadow_samples(sky, 2), [2, 2])
    # in 4x4 blocks a source takes 16, one a pixel of the block (8 would fall back to 2x2 blocks: two a pixel),
    # unless anti-aliasing samples split the set: it then falls back to 2x2 whatever its count, and 8 cost less
    np.testing.assert_array_equal(frame_shadow_samples(sky, 16, 4), [16, 16])
    np.testing.assert_array_equal(frame_shadow_samples(sky, 32, 4), [32, 16])
    np.testing.assert_array_equal(frame_shadow_samples(sky, 16, 2), [16, cap])
    np.testing.assert_array_equal(frame_shadow_samples(sky, 16, 4, 2), [16, cap])
    studio = wb.Scene(mesh, [wb.Lambert(0.5)], cam, wb.Environment.studio(), [light])
    np.testing.assert_array_equal(frame_shadow_samples(studio, 16), [16])
    backend = wb.get_backend("warp:cpu")
    traced = []
    trace = backend.trace_shadows

    def spy(*args, **kwargs):  # what the renderer asks the device to trace
        traced.append(np.asarray(kwargs["samples"]).tolist())
        return trace(*args, **kwargs)

    monkeypatch.setattr(backend, "trace_shadows", spy)
    info = wb.render(sky, backend=backend, shadow_samples=16).info
    assert traced == [[16, cap]]
    assert info["shadow_samples"] == 16 and info["source_shadow_samples"] == cap
    traced.clear()
    info = wb.render(sky, backend=backend, shadow_samples=16, block_rays=4).info
    assert traced == [[16, 16]] and info["source_shadow_samples"] == 16 and info["block_rays"] == 4
    for options, cap_4x4 in (({"aa": 2}, cap), ({"aa": 2, "aa_shading": "pixel"}, 16),
                             ({"aa": 2, "split_rays": False}, 16)):
        traced.clear()
        info = wb.render(sky, backend=backend, shadow_samples=16, block_rays=4, **options).info
        assert traced == [[16, cap_4x4]] * 2 and info["source_shadow_samples"] == cap_4x4, (options, traced)


def test_at_most_two_sources_and_no_specks():
    """Five hot texels, each 12 % of the map's power: the two strongest become lights (each light costs its shadow
    rays in every frame), the others stay in the map; a hot texel of 0.4 % of the power stays too."""
    image = np.full((64, 128, 3), 0.2, np.float32)
    omega = equirect_row_solid_angles(64, 128)
    for k, (row, col) in enumerate([(10, 10), (20, 40), (30, 70), (40, 100), (25, 120)]):
        image[row, col] = (0.12 + 0.002 * k) * 0.2 * 4 * np.pi / omega[row] / 0.4  # the last ones a little stronger
    image[50, 64] = 0.01 * 0.2 * 4 * np.pi / omega[50]
    env = wb.Environment(image)
    found = lighting.environment_sources(env)
    assert len(found.lights) == 2
    kept = {tuple(np.round(lt.direction, 6)) for lt in found.lights}
    dirs = equirect_directions(64, 128)
    assert kept == {tuple(np.round(dirs[40, 100], 6)), tuple(np.round(dirs[25, 120], 6))}
    assert found.residual.radiance[10, 10, 0] == image[10, 10, 0] and found.residual.radiance[50, 64, 0] > 1


def test_irradiance_map_keeps_a_sun_in_place():
    """The map sums the brightest texels where they are: against the full texel rule at its own normals."""
    env = wb.Environment.sky(sun_angular_radius=0.5)
    normals = equirect_directions(*lighting.IRRADIANCE_SHAPE).reshape(-1, 3)
    exact = environment_irradiance(env.radiance, normals)
    got = lighting.irradiance_map(env).reshape(-1, 3)
    assert np.abs(got - exact).max() / exact.mean() < 2e-3


def test_unoccluded_scene_keeps_one_ambient_lobe():
    """A lone convex object needs no SSDF, so its diffuse term keeps the fit's lobes (no six-way split)."""
    scene = wb.Scene(wb.Mesh.sphere(1.0, subdivisions=2), [wb.Lambert(0.5)],
                     wb.Camera(eye=(0, 0, 3.5), width=16, height=16), wb.Environment.sky())
    frame = pack_frame(scene, "warp:cpu")
    light = lighting.prepare(scene.environment, "warp:cpu")
    assert not frame.inputs.has_ssdf
    assert len(frame.inputs.env_sgs) == len(light.sgs) < len(light.shadow_sgs)


def test_shadow_lobes_keep_the_power():
    sgs = lighting.fit_sgs(wb.Environment.sky(), 9, "warp:cpu")
    split = lighting.shadow_lobes(sgs)
    assert len(split) == len(sgs) - 1 + 6
    np.testing.assert_allclose(split.power(), sgs.power(), rtol=1e-12)


@pytest.fixture(scope="module")
def contact_scene():
    mesh = wb.Mesh.merge([wb.Mesh.sphere(1.0, (0, 1, 0), material=0), wb.Mesh.plane(8.0, 0.0, 32, material=1)])
    cam = wb.Camera(eye=(0, 2.2, 5), target=(0, 0.8, 0), width=80, height=60)
    scene = wb.Scene(mesh, [wb.Lambert(0.8), wb.Lambert(0.5)], cam, wb.Environment.constant(1.0))
    g = wb.get_backend("warp:cpu").trace_primary(mesh, cam)
    pos = g.position.reshape(60, 80, 3)
    face = g.face.reshape(60, 80)
    floor = (face >= 0) & (mesh.face_material[np.maximum(face, 0)] == 1)
    regions = {"contact": floor & (np.linalg.norm(pos, axis=-1) < 0.5),  # the floor within 0.5 of the contact
               "underside": (face >= 0) & ~floor & (pos[..., 1] < 0.3),
               "open floor": floor & (np.linalg.norm(pos, axis=-1) > 3.0)}
    return scene, wb.render(scene, method="mc", samples=1024, backend="warp:cpu").image, regions


@pytest.mark.parametrize("occlusion_samples", [16, 0])
def test_constant_environment_shadows_at_a_contact(backend, contact_scene, occlusion_samples):
    """A sphere resting on a floor under a constant sky, against the Monte Carlo reference (1024 samples):
    the floor by the contact is shadowed and the open floor is not. Measured on Warp CPU and PoCL alike
    (region means against the reference's):

    | occlusion rays | image | floor within 0.5 of the contact | sphere below y = 0.3 | open floor |
    | --- | --- | --- | --- | --- |
    | none (the SSDF alone) | 25.8 dB | +202 % | +264 % | −1.4 % |
    | 16 (the default) | 34.8 dB | −2.4 % | +4.0 % | +0.1 % |

    Before the broad lobes were shadowed at all, the contact was 0.50 (unshadowed) and the image 17.1 dB.
    Bounds: the contact within 5 % (the issue's), the underside within 10 % (14 pixels: the reference's own
    mean there moves by 8 % between 256 and 1024 samples), the open floor within 3 %. The SSDF alone is kept
    as a check that it is still too bright, so the rays are what mends it."""
    scene, reference, regions = contact_scene
    image = wb.render(scene, backend=backend, occlusion_samples=occlusion_samples).image
    psnr = 10 * np.log10(reference.max() ** 2 / np.mean((image - reference) ** 2))

    def rel(name):
        return image[regions[name]].mean() / reference[regions[name]].mean() - 1

    assert regions["contact"].sum() >= 20 and regions["underside"].sum() >= 10
    assert abs(rel("open floor")) < 0.03
    if occlusion_samples:
        assert psnr > 33.0
        assert abs(rel("contact")) < 0.05, rel("contact")
        assert abs(rel("underside")) < 0.10, rel("underside")
    else:
        assert psnr > 23.0
        assert rel("contact") > 1.0  # the SSDF's six axes see too little of the visibility near a contact


@pytest.fixture(scope="module")
def contact_scene_1080p():
    """The contact scene at 1920×1080, where block_rays="auto" shares each set of 16 rays in 4×4 blocks, with its
    floor within 0.5 of the contact and a Monte Carlo reference of 8 samples a pixel (over ~9600 floor pixels)."""
    mesh = wb.Mesh.merge([wb.Mesh.sphere(1.0, (0, 1, 0), material=0), wb.Mesh.plane(8.0, 0.0, 32, material=1)])
    cam = wb.Camera(eye=(0, 2.2, 5), target=(0, 0.8, 0), width=1920, height=1080)
    scene = wb.Scene(mesh, [wb.Lambert(0.8), wb.Lambert(0.5)], cam, wb.Environment.constant(1.0))
    g = wb.get_backend("warp:cpu").trace_primary(mesh, cam)
    face = g.face.reshape(1080, 1920)
    floor = (face >= 0) & (mesh.face_material[np.maximum(face, 0)] == 1)
    contact = floor & (np.linalg.norm(g.position.reshape(1080, 1920, 3), axis=-1) < 0.5)
    return scene, wb.render(scene, method="mc", samples=8, backend="warp:cpu").image, contact


def test_default_ray_blocks_keep_a_contact_shadow_at_1080p(backend, contact_scene_1080p):
    """At 1920×1080 the default shares the rays in 4×4 blocks, which average visibility over four pixels: the floor
    by the contact stays within the issue's 5 % of the Monte Carlo reference (measured +3.0 % on Warp CPU and PoCL;
    each pixel's own rays −0.9 %, 2×2 blocks −0.4 %; at 1280×720 4×4 blocks gave +4.9 %, so they start at 1080p)."""
    scene, reference, contact = contact_scene_1080p
    got = wb.render(scene, backend=backend)
    assert got.info["block_rays"] == 4 and contact.sum() > 5000
    rel = got.image[contact].mean() / reference[contact].mean() - 1
    print(f"{backend.name}: contact {100 * rel:+.1f} %")
    assert abs(rel) < 0.05, rel


SUN = dict(axes=[[0.5, 0.8, 0.3]], sharpness=[200.0], radiance=[[40.0, 38.0, 34.0]], constant=0.05)


@pytest.fixture(scope="module")
def sun_scenes():
    """A sphere over a floor of 4 × 4 and of 32 × 32 quads under a map's sun (an SG of η = 200, about 6°
    across), the Monte Carlo reference (512 samples) and the floor's pixels. The floor is flat, so one
    reference serves both tessellations (their floor pixels agree but for rounding at its edges)."""
    env = wb.Environment.from_sgs(SUN["axes"], SUN["sharpness"], SUN["radiance"], constant=SUN["constant"])
    cam = wb.Camera(eye=(0, 3.0, 4.0), target=(0, 0.3, 0), width=80, height=60)
    scenes = {d: wb.Scene(wb.Mesh.merge([wb.Mesh.sphere(0.6, (0, 0.9, 0), material=0),
                                         wb.Mesh.plane(8.0, 0.0, d, material=1)]),
                          [wb.Lambert(0.8), wb.Lambert(0.5)], cam, env, ssdf_resolution=16) for d in (4, 32)}
    floors = []
    for scene in scenes.values():
        face = wb.get_backend("warp:cpu").trace_primary(scene.mesh, cam).face.reshape(60, 80)
        floors.append((face >= 0) & (scene.mesh.face_material[np.maximum(face, 0)] == 1))
    assert (floors[0] ^ floors[1]).sum() <= 10  # the same floor pixels whatever the tessellation
    floor = floors[0] & floors[1]
    return scenes, wb.render(scenes[32], method="mc", samples=512, backend="warp:cpu").image, floor


def test_sun_penumbra_does_not_depend_on_the_receivers_tessellation(backend, sun_scenes):
    """The sun's shadow on a floor of 4 × 4 quads (2 units each) and of 64 × 64, against the reference over the
    floor's pixels. The fit splits the sun into several sharp lobes; the most powerful get rays of their own
    and the others are weighed through those rays. Measured here, Warp CPU and PoCL alike:

    | floor | SSDF alone | with the rays (the default) |
    | --- | --- | --- |
    | 4 × 4 | 17.55 dB | 33.56 dB |
    | 32 × 32 | 28.2 dB | 33.56 dB |

    Bounds: both tessellations above 31 dB and within 1 dB of each other with
    the rays; the coarse floor below 22 dB with the SSDF alone, so the rays are what mends it."""
    scenes, reference, floor = sun_scenes

    def floor_psnr(divisions, occlusion):
        image = wb.render(scenes[divisions], backend=backend, occlusion_samples=occlusion).image
        return 10 * np.log10(reference[floor].max() ** 2 / np.mean((image[floor] - reference[floor]) ** 2))

    coarse, fine = floor_psnr(4, 16), floor_psnr(32, 16)
    assert coarse > 31.0 and fine > 31.0, (coarse, fine)
    assert abs(coarse - fine) < 1.0, (coarse, fine)
    assert floor_psnr(4, 0) < 22.0


def _directional_albedo(material, wo_local, n_z=192, n_phi=384):
    """∫ f̄(ωi, ωo) dωi over the hemisphere (f̄ includes cos θi) by the midpoint rule in (cos θi, φi), where
    dω = d(cos θ) dφ: deterministic, and f̄d is smooth in ωi."""
    z = (np.arange(n_z) + 0.5) / n_z
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz * zz)
    wi = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    return np.array([material.eval(wi, np.broadcast_to(w, wi.shape)).sum(0) * (2 * np.pi / len(wi))
                     for w in wo_local])


@pytest.mark.parametrize("method", ["sg", "asg"])
def test_effective_material_under_a_constant_environment_reflects_its_albedo(backend, method):
    """A baked material (Lambertian facets: its diffuse term alone) on a lone sphere under a constant
    environment of radiance 1 reflects its directional albedo ∫f̄ dωi at each pixel's view. U-grooves, whose
    f̄d changes most with ωi. The environment's single ambient lobe reads f̄d prefiltered to its width
    (`EffectiveBRDF.energy_levels`); read at the lobe's axis, as before, pixels were 0.13–4.8× the albedo.
    Measured (K = 8, 2^12 facets, 31 pixels): −0.53 % … +0.80 % on Warp CPU and PoCL, SG and ASG alike.
    Bound 2 %."""
    from warp_biscale.scene import vertex_tangents
    from warp_biscale.shading import surface_frames

    tile = wb.geometry.grooves(profile="u")
    mat = wb.bake(tile, [wb.Lambert(0.6)] * tile.n_materials, method=method, lobes=4, directions=8, facets=2**12,
                  backend=backend)
    mesh = wb.Mesh.sphere(1.0, subdivisions=4)
    cam = wb.Camera(eye=(0.3, 0.5, 3.2), width=40, height=30, fov=45)
    scene = wb.Scene(mesh, [mat], cam, wb.Environment.constant(1.0))
    frame = pack_frame(scene, backend)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
    pix = np.flatnonzero(frame.gbuffer.face >= 0)[::37]
    sf = surface_frames(mesh.faces, mesh.vertices, mesh.normals, vertex_tangents(mesh), frame.gbuffer.face[pix],
                        frame.gbuffer.bary[pix].astype(np.float64), cam.eye)
    albedo = _directional_albedo(mat, sf["wo_local"])
    rel = out[pix] / albedo - 1
    assert np.abs(rel).max() < 0.02, f"relative error {rel.min():.4f} … {rel.max():.4f}"
