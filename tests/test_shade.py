"""The shade stage (kernels/shade.py, cl/shade.cl) against its float64 reference `shading.shade_reference`,
on every backend present, over frames that exercise every path: analytic diffuse + glossy materials of
each kind, an effective (bi-scale) material, environment lobes with and without the SSDF (and its
per-pixel occlusion rays), point and
directional lights with shadows, background pixels, and silhouettes (normals facing away)."""

import functools

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale.render import OCCLUSION_SAMPLES, SHADOW_SAMPLES, frame_shadow_samples, pack_frame
from warp_biscale.scene import Scene
from warp_biscale.environment import Environment
from warp_biscale.scene import Camera, DirectionalLight, Mesh, PointLight
from warp_biscale.shading import axis_lobe_start, shade_reference


def _frame_rays(scene):
    """The shadow rays a pixel of each of the frame's lights, as pack_frame traces them."""
    return frame_shadow_samples(scene, SHADOW_SAMPLES)


@functools.cache
def _sg_environment(h=32, w=64):
    """A sky-like environment: a broad bright zenith lobe, a sharp warm "sun" (its fitted lobes 28 % of the power:
    the strongest gets rays of its own) and a constant ambient."""
    d = Environment(np.zeros((h, w, 3), np.float32)).directions()
    sky = 0.3 + 0.8 * np.exp(3.0 * (d[..., 1:2] - 1.0)) * np.array([0.6, 0.8, 1.0])
    sun_axis = np.array([0.5, 0.7, 0.5]) / np.linalg.norm([0.5, 0.7, 0.5])
    sun = 30.0 * np.exp(80.0 * (d @ sun_axis - 1.0))[..., None] * np.array([1.0, 0.9, 0.7])
    return Environment((sky + sun).astype(np.float32), name="test-sky")


@pytest.fixture(scope="module")
def effective_material():
    tile = wb.reference.vgroove_tile(0.5, 1.0)
    return wb.bake(tile, [wb.BlinnPhong(0.6, 200, kd=0.2)], lobes=4, directions=8, facets=2**12, backend="warp:cpu")


@functools.cache
def _meshes():
    """One object per mesh for every scene here (as one environment object): their BVH, SSDF and lighting are
    prepared once."""
    sphere = Mesh.sphere(radius=0.6, center=(0.0, 0.6, 0.0), subdivisions=3, material=0)
    torus = Mesh.torus(0.5, 0.18, center=(1.1, 0.2, 0.0), segments=(32, 16), material=1)
    floor = Mesh.plane(size=4.0, height=0.0, divisions=12, material=2)
    return Mesh.sphere(radius=1.0, subdivisions=3), Mesh.merge([sphere, torus, floor])


def _scenes(effective):
    env = _sg_environment()
    lone_mesh, occluded_mesh = _meshes()
    lone = Scene(
        lone_mesh,
        [wb.BlinnPhong(0.5, 150, kd=(0.5, 0.3, 0.2))],
        Camera(eye=(0.3, 0.4, 3.2), width=40, height=32, fov=45),
        env, [DirectionalLight((0.2, 1.0, 0.4), 2.0, 3.0), PointLight((2.0, 2.0, 2.0), 8.0, 0.1)])
    occluded = Scene(
        occluded_mesh,
        [wb.CookTorrance(0.6, 0.25, kd=0.3), wb.Ward(0.4, 0.15, kd=(0.2, 0.4, 0.3)), effective],
        Camera(eye=(0.0, 2.2, 3.5), target=(0.2, 0.3, 0.0), width=40, height=32, fov=50),
        env, [PointLight((1.5, 3.0, 1.0), 10.0, 0.2)], ssdf_resolution=16, ssdf_terms=8)
    return {"lone": lone, "occluded": occluded}


@pytest.fixture(scope="module")
def many_lobe_material():
    """More lobes (past the bake kernels' 16) than the shading has seen elsewhere: the woven tile."""
    tile = wb.geometry.woven()
    return wb.bake(tile, [wb.BlinnPhong(0.6, 200, kd=0.2)] * tile.n_materials, lobes=24, directions=4,
                   facets=2**12, backend="warp:cpu")


@pytest.fixture(scope="module")
def asg_material():
    """ASG lobes (Xu 2013) on U-grooves, whose NDF spreads along a great circle: anisotropic lobes."""
    tile = wb.geometry.grooves(profile="u")
    return wb.bake(tile, [wb.CookTorrance(0.7, 0.15, kd=0.2)] * tile.n_materials, method="asg", lobes=4,
                   directions=8, facets=2**12, backend="warp:cpu")


def _anisotropic(scene):
    """`scene` with its sphere in anisotropic Ward and its torus in Ashikhmin–Shirley (in the frames of the
    meshes' tangents, along their u directions)."""
    materials = [wb.AnisotropicWard(0.5, 0.08, 0.35, kd=0.3), wb.AshikhminShirley(rs=0.4, nu=20, nv=400, rd=0.4),
                 *scene.materials[2:]]
    return Scene(scene.mesh, materials, scene.camera, scene.environment, scene.lights, ssdf_resolution=16,
                 ssdf_terms=8)


def _anisotropic_small_scale(asg_material):
    """The ASG-baked grooves with anisotropic small-scale BRDFs (a material edit: the lobes' tangent orders are
    the bake's): Ashikhmin–Shirley on the first material id, anisotropic Ward on any other."""
    n = len(asg_material.materials)
    return asg_material.with_materials([wb.AshikhminShirley(rs=0.5, nu=40, nv=300, rd=0.3)]
                                       + [wb.AnisotropicWard(0.7, 0.1, 0.3, kd=0.2)] * (n - 1))


@functools.cache
def _woven_anisotropic():
    """The woven tile's ASG bake in anisotropic Ward (warp) and Ashikhmin–Shirley (weft): two materials whose
    tangents cross, each lobe turned each material's way (per-material tangent orders after the lobe rows)."""
    tile = wb.geometry.woven()
    return wb.bake(tile, [wb.AnisotropicWard(0.7, 0.08, 0.3, kd=0.2), wb.AshikhminShirley(rs=0.5, nu=30, nv=300,
                                                                                           rd=0.3)],
                   method="asg", lobes=4, directions=4, facets=2**12, backend="warp:cpu")


@pytest.mark.parametrize("which", ["lone", "occluded", "occluded-24-lobes", "occluded-asg", "occluded-anisotropic",
                                   "occluded-asg-anisotropic", "occluded-woven-anisotropic"])
def test_shade_kernel_matches_reference(backend, which, effective_material, many_lobe_material, asg_material):
    if which == "occluded-woven-anisotropic":
        woven = _woven_anisotropic()
        order = woven.tangent_order
        # the threads cross: their doubled-angle orders point apart (opposite: perpendicular lines)
        assert np.einsum("jc,jc->j", order[0], order[1]).min() < -0.5
        scene = _scenes(woven)["occluded"]
    elif which == "occluded-asg-anisotropic":
        assert np.hypot(*asg_material.tangent_order.T).max() > 0.9  # the grooves' tangents lie on one line
        scene = _scenes(_anisotropic_small_scale(asg_material))["occluded"]
    elif which == "occluded-anisotropic":
        scene = _anisotropic(_scenes(effective_material)["occluded"])
    elif which == "occluded-24-lobes":
        assert len(many_lobe_material.lobes) > 16
        scene = _scenes(many_lobe_material)["occluded"]
    elif which == "occluded-asg":
        assert (asg_material.asgs.lam / asg_material.asgs.mu).max() > 2  # anisotropic lobes
        scene = _scenes(asg_material)["occluded"]
    else:
        scene = _scenes(effective_material)[which]
    frame = pack_frame(scene, backend)
    assert bool(frame.inputs.has_ssdf) == (which != "lone")  # the lone convex sphere needs no SSDF
    # ... nor occlusion rays; the occluded scene's broad lobes are shadowed through them, some rays blocked
    assert frame.gbuffer.occlusion_samples == (0 if which == "lone" else OCCLUSION_SAMPLES)
    assert which == "lone" or frame.gbuffer.occlusion.any()
    # ... and its sharp lobe (the sky's sun) gets rays of its own, some blocked
    assert (frame.inputs.n_sharp_lobes == 0) == (which == "lone")
    assert which == "lone" or frame.gbuffer.lobe_occlusion.any()
    # ... and its six shadow lobes along the axes are shadowed by the rays alone, in the kernels in one walk
    assert frame.inputs.axis_lobes == axis_lobe_start(frame.inputs.env_sgs) == (
        -1 if which == "lone" else frame.inputs.n_sharp_lobes)
    ref = shade_reference(frame)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights,
                        gbuffer=frame.gbuffer)
    assert out.shape == ref.shape and out.dtype == np.float32
    assert np.isfinite(out).all() and (out >= 0).all()
    peak = ref.max()
    err = np.abs(out - ref)
    # float32 kernel vs float64 reference: the same formulas, so agreement to float32 rounding amplified by
    # the sharp lobes' exponentials (η up to ~1e3 here: relative 1e-4) and by the bilinear lookups' floor()
    # flipping at a cell edge on a few pixels. Measured: see the assertion message.
    msg = f"max err {err.max():.3g}, peak {peak:.3g}, p99.9 {np.quantile(err, 0.999):.3g}"
    assert np.quantile(err / (np.abs(ref) + 1e-3 * peak), 0.999) < 2e-3, msg
    assert err.max() < 2e-2 * peak, msg


def test_axis_lobe_start_finds_the_six_shadow_lobes():
    """shading.axis_lobe_start: the row where lighting.shadow_lobes' six lobes (±y, ±x, ±z, one sharpness) begin,
    after any sharp lobes; −1 for a set without them, in another order, of mixed sharpness or too sharp for the walk."""
    from warp_biscale.lighting import SHADOW_LOBE_AXES

    six = np.concatenate([SHADOW_LOBE_AXES, np.full((6, 1), 2.0), np.ones((6, 3))], 1)
    sun = np.array([[0.0, 0.8, 0.6, 900.0, 5.0, 5.0, 5.0]])
    assert axis_lobe_start(six.astype(np.float32)) == 0
    assert axis_lobe_start(np.concatenate([sun, six, sun])) == 1
    assert axis_lobe_start(sun) == -1 and axis_lobe_start(np.zeros((0, 7))) == -1
    assert axis_lobe_start(six[[1, 0, 2, 3, 4, 5]]) == -1
    mixed = six.copy()
    mixed[5, 3] = 3.0
    assert axis_lobe_start(mixed) == -1
    sharp = six.copy()
    sharp[:, 3] = 90.0  # past the one walk's float32 range (exp(±η ω))
    assert axis_lobe_start(sharp) == -1


def _assert_matches_reference(out, ref):
    """A float32 shade against its float64 reference, to test_shade_kernel_matches_reference's tolerances."""
    peak = ref.max()
    err = np.abs(out - ref)
    msg = f"max err {err.max():.3g}, peak {peak:.3g}, p99.9 {np.quantile(err, 0.999):.3g}"
    assert np.quantile(err / (np.abs(ref) + 1e-3 * peak), 0.999) < 2e-3, msg
    assert err.max() < 2e-2 * peak, msg


@pytest.mark.parametrize("samples", [1, 5, 8, 32])
def test_shade_with_other_occlusion_ray_counts(backend, effective_material, samples):
    """The occluded scene with 1, 5, 8 (the viewer's) and 32 occlusion rays a pixel (each count's rows of
    trace.DISK_RADII in the kernels; the other tests take the default 16) against the float64 reference, tolerances
    as test_shade_kernel_matches_reference's. At 5 and 8 the six shadow lobes blend the rays' shares (from their one
    walk, axis_ray_shares) with the SSDF's; at 1 the SSDF alone shadows them; at 32 the rays alone."""
    scene = _scenes(effective_material)["occluded"]
    frame = pack_frame(scene, backend, occlusion_samples=samples)
    assert frame.gbuffer.occlusion_samples == samples and frame.gbuffer.occlusion.any()
    _assert_matches_reference(backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights,
                                            gbuffer=frame.gbuffer), shade_reference(frame))


def test_shade_without_occlusion_rays_reads_every_lobes_ssdf_angle(backend, effective_material):
    """No occlusion rays: every environment lobe, the sun's sharp ones moved to the front (n_sharp_lobes) among
    them, is shadowed by the SSDF alone, its angle read from the per-vertex table (ShadeInputs.env_theta, in
    env_sgs' order), against the float64 reference's lookup at the blended coefficients (tolerances as
    test_shade_kernel_matches_reference's)."""
    scene = _scenes(effective_material)["occluded"]
    frame = pack_frame(scene, backend, occlusion_samples=0)
    static = frame.inputs
    assert static.has_ssdf and static.n_sharp_lobes > 0 and frame.gbuffer.occlusion_samples == 0
    assert static.env_theta.shape == (len(static.positions), len(static.env_sgs))
    _assert_matches_reference(backend.shade(scene.mesh, static, frame.camera, frame.lights, gbuffer=frame.gbuffer),
                              shade_reference(frame))


@pytest.mark.parametrize("part", [(1, 4), (2, 3), "2x2 blocks", "4x4 blocks"])
def test_shade_of_an_anti_aliasing_samples_part_of_the_rays(backend, effective_material, part):
    """A G-buffer whose occlusion, lobe and shadow rays are one anti-aliasing sample's part of each set
    (`trace.ray_part`), or shared in 2×2 or 4×4 pixel blocks (`trace.pixel_parts`: the rays each pixel was lent,
    turned by its block's first pixel): the kernel weighs those rays alone, as the float64 reference does
    (tolerances as test_shade_kernel_matches_reference's); and from the device's own copies it shades the same."""
    scene = _scenes(effective_material)["occluded"]
    width = scene.camera.width
    part = {"2x2 blocks": (0, 1, width), "4x4 blocks": (0, 1, width, 4)}.get(part, part)
    frame = pack_frame(scene, backend, part=part)
    assert frame.gbuffer.occlusion.any() and frame.gbuffer.lobe_occlusion.any()
    ref = shade_reference(frame)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
    peak = ref.max()
    _assert_matches_reference(out, ref)
    whole = shade_reference(pack_frame(scene, backend))
    assert np.abs(ref - whole).max() > 1e-3 * peak  # a part is not the whole set
    backend.trace_primary(scene.mesh, scene.camera, to_host=False)
    backend.trace_shadows(scene.mesh, None, frame.lights, to_host=False, samples=_frame_rays(scene), part=part)
    backend.trace_occlusion(scene.mesh, None, OCCLUSION_SAMPLES, to_host=False, part=part)
    backend.trace_lobe_rays(scene.mesh, None, frame.inputs.sharp_lobes(), to_host=False, part=part)
    np.testing.assert_array_equal(backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights), out)
    backend.trace_lobe_rays(scene.mesh, None, frame.inputs.sharp_lobes(), to_host=False)  # the whole set's
    with pytest.raises(ValueError, match="same anti-aliasing sample"):
        backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights)


def test_shade_uses_device_gbuffer(backend, effective_material):
    """The render path: G-buffer, shadows and occlusion masks left on the device by trace_primary,
    trace_shadows and trace_occlusion."""
    scene = _scenes(effective_material)["occluded"]
    frame = pack_frame(scene, backend)
    host = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights,
                         gbuffer=frame.gbuffer)
    backend.trace_primary(scene.mesh, scene.camera, to_host=False)
    backend.trace_shadows(scene.mesh, None, frame.lights, to_host=False, samples=_frame_rays(scene))  # as pack_frame
    backend.trace_occlusion(scene.mesh, None, OCCLUSION_SAMPLES, to_host=False)
    backend.trace_lobe_rays(scene.mesh, None, frame.inputs.sharp_lobes(), to_host=False)
    dev = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights)
    np.testing.assert_array_equal(dev, host)


def test_shade_only_one_material_over_the_last_frame(backend, effective_material):
    """only_material m: the pixels of material m shaded again, the rest kept from the last frame (bit for bit
    each as a whole shade of its own inputs gives them: here materials 0 and 1 changed, only 1 is shaded);
    misused, a one-line error."""
    scene = _scenes(effective_material)["occluded"]
    frame = pack_frame(scene, backend)
    backend.trace_primary(scene.mesh, scene.camera, to_host=False)
    backend.trace_shadows(scene.mesh, None, frame.lights, to_host=False, samples=_frame_rays(scene))
    backend.trace_occlusion(scene.mesh, None, OCCLUSION_SAMPLES, to_host=False)
    backend.trace_lobe_rays(scene.mesh, None, frame.inputs.sharp_lobes(), to_host=False)
    before = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights)
    edited = Scene(scene.mesh, [wb.Lambert(0.9), wb.Ward(0.2, 0.3, kd=(0.6, 0.1, 0.1)), scene.materials[2]],
                   scene.camera, scene.environment, scene.lights, ssdf_resolution=16, ssdf_terms=8)
    inputs = pack_frame(edited, backend).inputs
    backend.trace_primary(scene.mesh, scene.camera, to_host=False)
    backend.trace_shadows(scene.mesh, None, frame.lights, to_host=False, samples=_frame_rays(scene))
    backend.trace_occlusion(scene.mesh, None, OCCLUSION_SAMPLES, to_host=False)
    backend.trace_lobe_rays(scene.mesh, None, frame.inputs.sharp_lobes(), to_host=False)
    backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, to_host=False)
    masked = backend.shade(scene.mesh, inputs, frame.camera, frame.lights, only_material=1)
    whole = backend.shade(scene.mesh, inputs, frame.camera, frame.lights)
    face = frame.gbuffer.face
    torus = (face >= 0) & (scene.mesh.face_material[np.maximum(face, 0)] == 1)
    sphere = (face >= 0) & (scene.mesh.face_material[np.maximum(face, 0)] == 0)
    assert torus.sum() > 20 and sphere.sum() > 20  # both edited materials are in view
    assert not np.array_equal(whole[sphere], before[sphere]) and not np.array_equal(whole[torus], before[torus])
    np.testing.assert_array_equal(masked[torus], whole[torus])
    np.testing.assert_array_equal(masked[~torus], before[~torus])
    with pytest.raises(ValueError, match="gbuffer=None"):
        backend.shade(scene.mesh, inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer, only_material=1)
    with pytest.raises(ValueError, match="material index"):
        backend.shade(scene.mesh, inputs, frame.camera, frame.lights, only_material=3)


def _trace_on_device(backend, scene, frame):
    backend.trace_primary(scene.mesh, scene.camera, to_host=False)
    backend.trace_shadows(scene.mesh, None, frame.lights, to_host=False, samples=_frame_rays(scene))
    backend.trace_occlusion(scene.mesh, None, OCCLUSION_SAMPLES, to_host=False)
    backend.trace_lobe_rays(scene.mesh, None, frame.inputs.sharp_lobes(), to_host=False)


def test_shade_only_one_material_reads_the_kept_visibility(backend, effective_material):
    """A whole frame shaded with keep_visibility keeps each pixel's shadowed environment amounts; an only_material
    shade after a material edit reads them back and gives, bit for bit, what a whole shade of the edited inputs
    gives, and agrees with the float64 `shade_reference` as test_shade_kernel_matches_reference's frames do; so
    does a whole frame after the lights changed. Another eye or environment is not shaded from them."""
    scene = _scenes(effective_material)["occluded"]
    frame = pack_frame(scene, backend)
    _trace_on_device(backend, scene, frame)
    backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, to_host=False, keep_visibility=True)
    m = scene.mesh.device_cache[backend.name]
    assert m["visibility_read"] is False
    edited = Scene(scene.mesh, [scene.materials[0], wb.Ward(0.2, 0.3, kd=(0.6, 0.1, 0.1)), scene.materials[2]],
                   scene.camera, scene.environment, scene.lights, ssdf_resolution=16, ssdf_terms=8)
    edited_frame = pack_frame(edited, backend)
    _trace_on_device(backend, scene, frame)  # (if_changed not set: the same rays again, the same keys)
    masked = backend.shade(scene.mesh, edited_frame.inputs, frame.camera, frame.lights, only_material=1)
    assert m["visibility_read"] is True
    whole = backend.shade(scene.mesh, edited_frame.inputs, frame.camera, frame.lights)
    np.testing.assert_array_equal(masked, whole)
    face = frame.gbuffer.face
    torus = (face >= 0) & (scene.mesh.face_material[np.maximum(face, 0)] == 1)
    assert torus.sum() > 20
    ref = shade_reference(edited_frame)
    peak = ref.max()
    err = np.abs(masked - ref)[torus]
    msg = f"max err {err.max():.3g}, peak {peak:.3g}"
    assert np.quantile(err / (np.abs(ref[torus]) + 1e-3 * peak), 0.999) < 2e-3, msg
    assert err.max() < 2e-2 * peak, msg
    # New lights (other shadow rays): a whole frame that keeps the visibility reads it back, the same bit for bit.
    lit = Scene(scene.mesh, edited.materials, scene.camera, scene.environment,
                [PointLight((-1.0, 2.5, 1.5), 6.0, 0.3), DirectionalLight((0.3, 1.0, -0.2), 1.5, 2.0)],
                ssdf_resolution=16, ssdf_terms=8)
    lit_frame = pack_frame(lit, backend)
    _trace_on_device(backend, lit, lit_frame)
    relit = backend.shade(scene.mesh, lit_frame.inputs, frame.camera, lit_frame.lights, keep_visibility=True)
    assert m["visibility_read"] is True
    np.testing.assert_array_equal(relit, backend.shade(scene.mesh, lit_frame.inputs, frame.camera, lit_frame.lights))
    _trace_on_device(backend, scene, frame)
    # Another eye than the G-buffer's: it turns the occlusion rays' frame, so the kept amounts are not read.
    moved = frame.camera.copy()
    moved[0] += 0.3
    backend.shade(scene.mesh, edited_frame.inputs, moved, frame.lights, to_host=False, only_material=1)
    assert m["visibility_read"] is False
    # Another environment: the kept amounts are not its own, and are not read.
    other = Scene(scene.mesh, edited.materials, scene.camera, Environment.constant(0.7, 16, 32), scene.lights,
                  ssdf_resolution=16, ssdf_terms=8)
    other_frame = pack_frame(other, backend)
    _trace_on_device(backend, other, other_frame)
    backend.shade(scene.mesh, other_frame.inputs, frame.camera, other_frame.lights, to_host=False)
    again = backend.shade(scene.mesh, other_frame.inputs, frame.camera, other_frame.lights, only_material=1)
    assert m["visibility_read"] is False
    np.testing.assert_array_equal(again, backend.shade(scene.mesh, other_frame.inputs, frame.camera,
                                                       other_frame.lights))


def test_back_faces_are_black(backend):
    """A face seen from behind (the eye beyond its plane, on the side its normal turns from) is black in the kernels,
    their float64 reference and the Monte Carlo reference alike: surfaces are one-sided, and the reference's rays
    leave behind such a face and meet it. Before, the SG renderer lit a plane's underside (0.5 under a constant
    map, where the reference gave 0) and a baked material there made fireflies. Seen here: a floor's underside, a
    sphere below it seen from outside (lit), and the inside of a sphere."""
    floor = Mesh.plane(size=2.0, height=0.0, divisions=4, material=0)
    ball = Mesh.sphere(radius=0.5, center=(1.6, -0.6, 0.0), subdivisions=2, material=1)
    scene = Scene(Mesh.merge([floor, ball]), [wb.Lambert(0.5), wb.BlinnPhong(0.4, 60, kd=0.3, normalization="energy")],
                  Camera(eye=(0.0, -2.0, 3.0), target=(0.5, 0.0, 0.0), width=32, height=24),
                  _sg_environment(), [PointLight((1.0, -2.0, 1.0), 5.0, 0.1)])
    frame = pack_frame(scene, backend)
    face = np.asarray(frame.gbuffer.face)
    underside = (face >= 0) & (scene.mesh.face_material[np.maximum(face, 0)] == 0)
    outside = (face >= 0) & (scene.mesh.face_material[np.maximum(face, 0)] == 1)
    assert underside.sum() > 100 and outside.sum() > 20
    ref = shade_reference(frame)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
    assert np.all(out[underside] == 0) and np.all(ref[underside] == 0)
    assert ref[outside].min() > 0  # (a front face keeps its light)
    # the rest as test_shade_kernel_matches_reference checks it
    np.testing.assert_allclose(out, ref, rtol=2e-3, atol=1e-4 * ref.max())
    mc = wb.render(scene, method="mc", samples=8, backend=backend).image.reshape(-1, 3)
    assert np.all(mc[underside] == 0) and mc[outside].min() > 0
    # the inside of a closed sphere, which needs no SSDF (convex) and so casts no ray
    inside = Scene(Mesh.sphere(1.0), [wb.Lambert(0.5)], Camera(eye=(0, 0, 0.2), target=(0, 0, -1), width=16,
                                                                 height=12), Environment.studio(), [])
    assert wb.render(inside, backend=backend).image.max() == 0
