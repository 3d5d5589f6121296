"""The SG renderer end to end (wb.render): physical closed forms, the Monte Carlo reference, and what the
driver skips or re-uses. Every backend present runs them (the `backend` fixture)."""

import subprocess
import sys

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import sg, shading
from warp_biscale.render import SHADOW_SAMPLES, pack_frame
from warp_biscale.scene import Scene
from warp_biscale.trace import above_horizon, disk_sample, horizon_frame


def _hit_normals(frame, mesh):
    """The interpolated unit normals of the hit pixels (as the shading builds them) and the hit mask."""
    hit = frame.gbuffer.face >= 0
    tri = mesh.faces[frame.gbuffer.face[hit]]
    u, v = frame.gbuffer.bary[hit, 0].astype(np.float64), frame.gbuffer.bary[hit, 1].astype(np.float64)
    n = (1 - u - v)[:, None] * mesh.normals[tri[:, 0]] + u[:, None] * mesh.normals[tri[:, 1]] \
        + v[:, None] * mesh.normals[tri[:, 2]]
    return n / np.linalg.norm(n, axis=1, keepdims=True), hit


def test_furnace_lambert_sphere_returns_its_albedo(backend):
    """A Lambertian sphere, no occluder, constant environment L = 1: every pixel is the albedo (the SG fit of a
    constant map is exact to 1e-3 and the cosine table to 5e-4), the background is L."""
    scene = Scene(wb.Mesh.sphere(1.0, subdivisions=4), [wb.Lambert((0.6, 0.4, 0.2))],
                  wb.Camera(eye=(0, 0, 3.5), width=48, height=40), wb.Environment.constant(1.0))
    out = wb.render(scene, backend=backend)
    img = out.image.reshape(-1, 3)
    hit = pack_frame(scene, backend).gbuffer.face >= 0
    assert hit.sum() > 500 and (~hit).sum() > 100
    np.testing.assert_allclose(img[hit], np.tile([0.6, 0.4, 0.2], (hit.sum(), 1)), rtol=5e-3)
    np.testing.assert_allclose(img[~hit], 1.0, rtol=1e-6)
    assert out.info["ssdf"] is False  # a lone convex object needs no SSDF


def test_directional_light_on_lambert_sphere_closed_form(backend):
    """One directional light (an SG emitter of irradiance E), no environment: L = kd/π · E · cosine_fraction(n·l, η)
    per pixel, exact in our light model; the table's error is 5e-4 of E."""
    light = wb.DirectionalLight((0.3, 0.8, 0.5), irradiance=(2.0, 1.5, 1.0), angular_radius=5.0)
    scene = Scene(wb.Mesh.sphere(1.0, subdivisions=4), [wb.Lambert(0.5)], wb.Camera(eye=(0, 0, 3.5), width=48,
                  height=40), None, [light])
    out = wb.render(scene, backend=backend).image.reshape(-1, 3)
    frame = pack_frame(scene, backend)
    n, hit = _hit_normals(frame, scene.mesh)
    _, eta, _, _ = wb.scene.light_sg(light.packed()[None], np.zeros((1, 3)))
    cos_part = sg.cosine_fraction(n @ light.direction, eta[0, 0])
    expected = 0.5 / np.pi * np.asarray(light.irradiance)[None] * cos_part[:, None]
    # Near the terminator the light's disc is partly below the shading normal's horizon: the shadow rays aim at
    # the part above (trace.above_horizon), which is what the cosine integral counts, and one that still falls
    # below counts as blocked (trace_shadows). On a lone convex sphere nothing else blocks them (they leave from the
    # hit lifted towards the smooth surface, so not even a ray that dips below its face's plane): the rays' share is
    # computed here in float64 from their directions (trace.disk_sample, horizon_frame, above_horizon), 1 wherever part
    # of the disc is above; pixels with a ray within 1e-5 of the horizon may round either way in float32 and are
    # left out.
    w = np.asarray(light.direction, np.float64) / np.linalg.norm(light.direction)
    q = disk_sample(np.arange(SHADOW_SAMPLES)[None], SHADOW_SAMPLES, np.flatnonzero(hit)[:, None])  # (P, S, 2)
    spread = np.tan(np.radians(light.angular_radius))
    a, b, chord = horizon_frame(np.broadcast_to(w, n.shape), n, spread)
    q = above_horizon(q, chord[:, None])
    d = w + spread * (q[..., :1] * a[:, None] + q[..., 1:] * b[:, None])
    above = np.einsum("pc,psc->ps", n, d / np.linalg.norm(d, axis=-1, keepdims=True))
    share = ((above > 0).sum(1) * 255 + SHADOW_SAMPLES // 2) // SHADOW_SAMPLES
    clear = np.abs(above).min(1) > 1e-5
    expected *= share[:, None] / 255.0
    assert clear.mean() > 0.99
    np.testing.assert_allclose(out[hit][clear], expected[clear], atol=1e-3 * 2.0, rtol=2e-3)
    lit = n @ light.direction > 0
    assert lit.sum() > 100 and (~lit).sum() > 100
    # a soft terminator, all of whose pixels see their rays (before, the part of the disc below the horizon took
    # its rays' share away again: half the light at the terminator's middle)
    terminator = np.abs(n @ w) < spread * np.sqrt(1 - (n @ w) ** 2)
    assert terminator.sum() > 10 and np.all(share[terminator & clear & (n @ w > -0.9 * spread)] == 255)
    assert np.all(out[~hit] == 0)  # no environment: black background


def _glossy_scene(size=48):
    env = wb.Environment.from_sgs([[0.3, 0.8, 0.5], [0, 1, 0], [-0.7, 0.3, -0.6]], [40.0, 2.0, 10.0],
                                  [[6.0, 5.5, 5.0], [0.6, 0.7, 0.9], [1.0, 0.8, 0.6]], constant=0.15, height=64,
                                  width=128)
    sphere = wb.Mesh.sphere(0.7, center=(0, 0.7, 0), subdivisions=4, material=0)
    floor = wb.Mesh.plane(5.0, 0.0, divisions=24, material=1)
    return Scene(wb.Mesh.merge([sphere, floor]), [wb.BlinnPhong(0.6, 120, kd=(0.4, 0.25, 0.15)), wb.Lambert(0.5)],
                 wb.Camera(eye=(0, 1.8, 3.2), target=(0, 0.5, 0), fov=45, width=size, height=size), env,
                 [wb.PointLight((1.5, 3.0, 1.5), 6.0, 0.15)], ssdf_terms=16)


def test_glossy_scene_sg_against_monte_carlo(backend):
    """A glossy Blinn–Phong sphere on a floor (SSDF shadows), an environment of three SG lobes + ambient, and a
    point light: the SG image against the converged Monte Carlo reference, over the object pixels. Measured on
    Warp CPU: 48.2 dB before the diffuse term took the exact irradiance, 48.7 dB after (mean relative error
    5.0 → 4.3 %; the reference's own noise, stderr rms 0.030 against an RMSE of 0.048, is much of what is
    left). The MC noise is checked too, so the PSNR is the method's error, not the reference's."""
    scene = _glossy_scene()
    sg_img = wb.render(scene, backend=backend)
    mc = wb.render(scene, method="mc", backend=backend, samples=512, seed=3)
    assert sg_img.info["ssdf"] is True
    mask = (pack_frame(scene, backend).gbuffer.face >= 0).reshape(scene.camera.height, scene.camera.width)
    err = wb.compare_images(sg_img.image, mc.image, mask=mask)
    peak = mc.image[mask].max()
    assert mc.info["stderr_rms"] < 0.2 * err["rmse"] + 0.01 * peak  # the reference is converged enough to judge
    assert err["psnr"] >= 46.0, err
    assert np.isfinite(sg_img.image).all() and (sg_img.image >= 0).all()


def test_driver_reuses_static_work_and_skips_what_is_not_needed(backend):
    scene = _glossy_scene(24)
    first = wb.render(scene, backend=backend)
    assert {"lighting", "ssdf", "gbuffer", "shadows", "shade"} <= set(first.timings)
    scene.camera = wb.Camera(eye=(0.5, 1.5, 3.0), target=(0, 0.5, 0), width=24, height=24)  # only the camera moved
    second = wb.render(scene, backend=backend)
    assert "lighting" not in second.timings and "ssdf" not in second.timings
    assert not np.array_equal(first.image, second.image)
    lambert_only = Scene(scene.mesh, [wb.Lambert(0.5), wb.BlinnPhong(0.0, 50, kd=0.3)], scene.camera, None, [])
    frame = pack_frame(lambert_only, backend)
    assert frame.inputs.mat_info[:, 2].tolist() == [0, 0]  # ks = 0: no specular path
    out = wb.render(lambert_only, backend=backend)
    assert "shadows" not in out.timings and "ssdf" not in out.timings  # no lights, no environment


def test_a_scene_without_an_environment_makes_no_environment_tables(backend):
    """No environment, no specular environment term: the analytic rows' correction and moment tables (about a second
    for an anisotropic row on a 2-core CPU) are not made; the image is the one with the black map and its tables."""
    sphere = wb.Mesh.sphere(1.0, subdivisions=2)
    cam = wb.Camera(eye=(0.3, 0.5, 3.2), width=24, height=18, fov=45)
    lights = [wb.DirectionalLight((0.3, 0.5, 1.0), 2.0, 2.0)]
    material = wb.AnisotropicWard(0.6, 0.1, 0.3, kd=0.2)
    without = Scene(sphere, [material], cam, None, lights)
    frame = pack_frame(without, backend)
    assert [list(r[1:3]) for r in frame.inputs.tex_info[1:3]] == [[1, 1], [2, 2]]
    black = Scene(sphere, [material], cam, wb.Environment(np.zeros((2, 4, 3), np.float32), name="black"), lights)
    assert pack_frame(black, backend).inputs.tex_info[2][2] == 2 * shading.MOMENT_TABLE_PHI
    np.testing.assert_allclose(wb.render(without, backend=backend).image, wb.render(black, backend=backend).image,
                               rtol=1e-6, atol=1e-7)


def test_material_edit_uploads_only_what_changed(backend):
    """A material edit (EffectiveBRDF.with_materials: a new ShadeInputs with the same mesh, environment and
    μ tables) keeps the device copies of what it did not change, and its frame is the one a backend that
    uploads everything afresh renders, bit for bit; a new bake's tables are uploaded again."""
    tile = wb.geometry.pyramid(height=0.5)
    baked = wb.bake(tile, [wb.BlinnPhong(0.5, 60, kd=0.2)], lobes=2, directions=4, facets=1 << 11, backend=backend)
    scene = _glossy_scene(24)
    first = Scene(scene.mesh, [baked, wb.Lambert(0.5)], scene.camera, scene.environment, scene.lights)
    wb.render(first, backend=backend)
    edited = baked.with_materials([wb.BlinnPhong(0.3, 200, kd=(0.5, 0.2, 0.1))])
    second = Scene(scene.mesh, [edited, wb.Lambert(0.5)], scene.camera, scene.environment, scene.lights)
    image = wb.render(second, backend=backend).image
    dev1, dev2 = ([v for k, v in s.cache.items() if k[0] == "static"][0].device[backend.name] for s in (first, second))
    assert dev2["eff_tables"] is dev1["eff_tables"] and dev2["positions"] is dev1["positions"]
    assert dev2["eff_diffuse"] is dev1["eff_diffuse"]  # the energy levels: kd is weighed in the kernel
    assert dev2["env_maps"] is dev1["env_maps"] and dev2["ssdf_coeffs"] is dev1["ssdf_coeffs"]
    assert dev2["env_theta"] is dev1["env_theta"]  # (the per-vertex angles: same coefficients, same lobes)
    assert dev2["eff_sub"] is not dev1["eff_sub"]  # the new small-scale BRDF's row
    backend._shade_inputs_held.clear()  # what a backend that never saw the first scene holds
    cold = Scene(scene.mesh, [edited, wb.Lambert(0.5)], scene.camera, scene.environment, scene.lights)
    np.testing.assert_array_equal(wb.render(cold, backend=backend).image, image)
    dev_cold = [v for k, v in cold.cache.items() if k[0] == "static"][0].device[backend.name]
    rebaked = wb.bake(wb.geometry.pyramid(height=0.3), [wb.BlinnPhong(0.5, 60, kd=0.2)], lobes=2, directions=4,
                      facets=1 << 11, backend=backend)
    third = Scene(scene.mesh, [rebaked, wb.Lambert(0.5)], scene.camera, scene.environment, scene.lights)
    wb.render(third, backend=backend)
    dev3 = [v for k, v in third.cache.items() if k[0] == "static"][0].device[backend.name]
    assert dev3["eff_tables"] is not dev_cold["eff_tables"] and dev3["positions"] is dev_cold["positions"]
    assert dev3["eff_diffuse"] is not dev_cold["eff_diffuse"]


def test_frames_upload_the_lights_only_when_they_change(backend):
    """The lights, their ray counts and the sharp environment lobes live on the device from frame to frame
    (`_small_upload`): a second frame of the same ones makes no new device copy; a moved light is uploaded again,
    and its frame is the one a mesh the backend never saw renders, bit for bit."""
    scene = _glossy_scene(24)
    wb.render(scene, backend=backend)
    entry = scene.mesh.device_cache[backend.name]
    held = {k: entry[k] for k in ("lights", "light_samples", "shade_lights", "lobe_ray_lobes")}  # (its sharp lobe)
    wb.render(scene, backend=backend)
    assert all(entry[k] is v for k, v in held.items())
    moved = Scene(scene.mesh, scene.materials, scene.camera, scene.environment,
                  [wb.PointLight((-1.5, 2.5, 1.0), 6.0, 0.15)], ssdf_terms=16)
    image = wb.render(moved, backend=backend).image
    assert entry["lights"] is not held["lights"] and entry["shade_lights"] is not held["shade_lights"]
    assert entry["light_samples"] is held["light_samples"] and entry["lobe_ray_lobes"] is held["lobe_ray_lobes"]
    new = _glossy_scene(24)  # a mesh of its own, with nothing on the device
    assert new.mesh is not scene.mesh and backend.name not in new.mesh.device_cache
    fresh = Scene(new.mesh, scene.materials, scene.camera, scene.environment, moved.lights, ssdf_terms=16)
    np.testing.assert_array_equal(wb.render(fresh, backend=backend).image, image)


def test_degenerate_mesh_never_yields_nan(backend):
    """A zero-area face and opposite vertex normals that cancel on a face: finite, non-negative radiance."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 2]])  # the last face is degenerate (collinear)
    normals = np.array([[0, 0, 1], [0, 0, 1], [0, 0, -1], [0, 0, 1], [0, 0, 1]], float)
    scene = Scene(wb.Mesh(v, f, normals), [wb.CookTorrance(0.8, 0.1, kd=0.2)],
                  wb.Camera(eye=(0, 0, 3), width=24, height=24), wb.Environment.constant(1.0),
                  [wb.PointLight((0, 0, 2), 5.0, 0.1)])
    img = wb.render(scene, backend=backend).image
    assert np.isfinite(img).all() and (img >= 0).all()


def test_bad_scene_inputs_are_named():
    mesh = wb.Mesh.sphere(subdivisions=1)
    with pytest.raises(ValueError, match="material"):
        Scene(wb.Mesh.merge([mesh, wb.Mesh.plane(material=1)]), [wb.Lambert(0.5)])
    with pytest.raises(ValueError, match="lights"):
        Scene(mesh, [wb.Lambert(0.5)], lights=["sun"])
    with pytest.raises(ValueError, match="method"):
        wb.render(Scene(mesh, [wb.Lambert(0.5)]), method="path")
    with pytest.raises(ValueError, match="Camera.fov"):
        wb.Camera(fov=0)


def test_camera_packed_follows_its_fields():
    """Camera.packed() is kept between calls, but any field changed since (in place or replaced) gives the row
    made afresh; the kept row is read-only, so that no caller can change what another gets."""
    cam = wb.Camera(eye=(0, 1, 4), target=(0, 0, 0), width=64, height=48)
    first = cam.packed()
    assert cam.packed() is first and not first.flags.writeable
    for change in (lambda c: c.eye.__setitem__(0, 0.5), lambda c: setattr(c, "width", 80),
                   lambda c: setattr(c, "fov", 30.0), lambda c: setattr(c, "jitter", (0.25, -0.25)),
                   lambda c: setattr(c, "target", np.array([0.0, 0.2, 0.0])),
                   lambda c: setattr(c, "eye", (0.5, 1.0, 4.0)), lambda c: setattr(c, "jitter", np.array([0.1, 0.2]))):
        change(cam)
        np.testing.assert_array_equal(cam.packed(), cam._packed_now())
    assert not np.array_equal(cam.packed(), first)


@pytest.mark.parametrize("subdivisions", [0, 1, 3])
def test_icosphere_is_trimeshs(subdivisions):
    """`scene.icosphere` (Mesh.sphere's, made without importing trimesh) against trimesh.creation.icosphere: the
    same vertices (to 1e−12; the order may differ) and the same triangles with the same winding (outward)."""
    import trimesh

    from warp_biscale.scene import icosphere

    v, f = icosphere(subdivisions)
    tm = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    tv, tf = np.asarray(tm.vertices), np.asarray(tm.faces)
    assert v.shape == tv.shape and f.shape == tf.shape
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-15)
    match = np.argmin(np.linalg.norm(v[:, None, :] - tv[None, :, :], axis=2), axis=1)  # our vertex → trimesh's
    np.testing.assert_allclose(v, tv[match], atol=1e-12)
    assert len(set(match)) == len(v)

    def cycles(faces):  # each triangle as its rotation starting at its smallest index (winding kept)
        k = np.argmin(faces, axis=1)[:, None]
        return {tuple(r) for r in np.take_along_axis(faces, (k + np.arange(3)) % 3, axis=1)}

    assert cycles(match[f]) == cycles(tf)


def test_import_leaves_trimesh_for_when_a_mesh_file_is_read(tmp_path):
    """Importing the package, or making a sphere, does not import trimesh (a second of every process's start,
    a batch worker's too, where networkx is installed); writing a mesh file does."""
    code = ("import sys, warp_biscale as wb; wb.Mesh.sphere(1.0); assert 'trimesh' not in sys.modules, 'imported'; "
            "wb.geometry.pyramid().save(sys.argv[1]); assert 'trimesh' in sys.modules")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "tile.ply")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]


def test_readme_scenes_have_light():
    """Every `wb.Scene(...)` in the README's and docs' snippets gives an environment or lights (the fourth and
    fifth arguments, or by keyword): a scene with neither renders black, as the README's ASG line once did."""
    import os
    import re

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    docs = [os.path.join(root, "README.md")] + [os.path.join(root, "docs", f) for f in
                                                 sorted(os.listdir(os.path.join(root, "docs"))) if f.endswith(".md")]
    found = 0
    for path in docs:
        text = open(path, encoding="utf-8").read()
        for match in re.finditer(r"wb\.Scene\(", text):
            depth, args, i = 1, [""], match.end()
            while depth:  # the call's top-level arguments
                c = text[i]
                depth += (c in "([{") - (c in ")]}")
                if depth == 1 and c == ",":
                    args.append("")
                elif depth:
                    args[-1] += c
                i += 1
            args = [a.split("#")[0].strip() for a in args]  # (a comment after an argument is not one)
            given = [a for a in args if a]
            lit = len([a for a in given if "=" not in a.split("(")[0]]) >= 4 or any(
                re.match(r"(environment|lights)\s*=", a) for a in given)
            assert lit, f"{os.path.basename(path)}: {text[match.start():i]!r} has no environment or lights"
            found += 1
    assert found >= 2
    black = wb.render(wb.Scene(wb.Mesh.sphere(subdivisions=1), [wb.Lambert(0.5)],
                               wb.Camera(eye=(0, 0, 4), width=8, height=6)), backend="warp:cpu").image
    assert black.max() == 0  # (why the snippets must give one)
