"""Mitsuba 3 export of a baked effective BRDF (warp_biscale.mitsuba_export, docs/mitsuba.md): the plugin's f̄
against EffectiveBRDF.eval, its sampling against its own density, a Mitsuba 3 render of a sphere against our
Monte Carlo reference, the exported files and the CLI.

Mitsuba 3 is an optional test dependency (the `test` extra). Without it the tests that need it skip with that
reason, and so they do where its LLVM backend cannot compile (Dr.Jit 1.5 aborts on Debian 12's LLVM 14/15:
probed in a subprocess, since the abort would take pytest down); writing the files and the CLI need no Mitsuba.

Tolerances, and why:
- eval: the plugin computes in float32, the reference in float64: |Δ| ≤ 2e-4 × max(f̄, 1 % of the peak)
  (measured ≤ 4.4e-6 here; 5e-5 on a four-sided Cook–Torrance pyramid, its Fresnel and 1/cos²θd in float32).
- sampling: every sample's weight is the plugin's own f/p and its pdf its own density (1e-5, float32); the mean
  weight, an estimate of ∫f̄ dω, and the share of samples above the horizon, ∫p dω over the hemisphere, agree with
  float64 uniform-hemisphere estimates within 4 standard errors of the difference.
- render: the plugin evaluates the SG fit, so the Monte Carlo reference is given the same f̄ (a bake with method
  "sg-exact" and fallback="sg", which evaluates EffectiveBRDF.eval(method="sg-exact")). Over the pixels whose
  3 × 3 neighbourhood sees the sphere (the silhouette is left out: Mitsuba averages a pixel's area, our reference
  takes its centre and clamps ωo·n there), per pixel z = Δ/√(σ_mc² + σ_mi²) has RMS ≤ 1.5 (measured 1.11: the
  reference's σ runs ~10 % low, its docstring says, and the pixel's area against its centre adds a little) and
  fewer than 0.5 % of pixels beyond 5σ; the mean over those pixels agrees within 4 standard errors. σ_mi is the
  spread of 8 Mitsuba passes with different seeds.
"""

import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import mitsuba_export

VARIANT = "llvm_ad_rgb"
PROBE = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import drjit as dr; "
         "print(dr.minimum(mi.Float([1.0, 2.0]), 1.5))")


@pytest.fixture(scope="module")
def mi():
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (an optional test dependency: "
                                               "pip install 'warp_biscale[test]')")
    probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300)
    if probe.returncode != 0:
        lines = [line.strip() for line in (probe.stderr + probe.stdout).splitlines() if line.strip()]
        why = [line for line in lines if "ERROR" in line or "Error" in line] or lines or [f"exit {probe.returncode}"]
        pytest.skip(f"Mitsuba's {VARIANT} variant cannot run here ({why[0]}): Dr.Jit 1.5 needs a newer LLVM than "
                    "Debian 12's 14/15 (apt-get install libllvm19)")
    mi.set_variant(VARIANT)
    mitsuba_export.register()
    return mi


def _tile():
    """A turned three-sided pyramid (material 0) on a ground of material 1, coloured: two small-scale BRDFs and
    an effective BRDF with no mirror symmetry, so a tile frame turned or mirrored on the surface would show (a
    render with u flipped, or u and v swapped, is 15σ RMS off our reference)."""
    return wb.geometry.pyramid(height=0.4, base_fraction=0.8, sides=3, rotation=0.3, base_material=1,
                               color=(0.9, 0.7, 0.4), base_color=(0.6, 0.7, 0.9))


BRDFS = {"blinnphong+lambert": [wb.BlinnPhong(0.5, 60, kd=(0.3, 0.25, 0.2), normalization="energy"),
                                wb.Lambert(0.5)],
         "cooktorrance+ward": [wb.CookTorrance(ks=0.6, roughness=0.25, kd=0.2), wb.Ward(ks=0.3, alpha=0.3, kd=0.3)]}


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """{(brdfs, method): (material, its exported folder)}, small bakes (4096 facets, K = 8, 6 lobes) made once."""
    out = {}
    for name, brdfs in BRDFS.items():
        for method in ("sg", "sg-exact"):
            mat = wb.bake(_tile(), brdfs, method=method, lobes=6, facets=4096, directions=8)
            folder = tmp_path_factory.mktemp(f"{name}-{method}")
            out[name, method] = mat, mitsuba_export.export(mat, folder)
    return out


def _bsdf(mi, files, **props):
    return mi.load_dict({"type": mitsuba_export.PLUGIN, "filename": files["material"], **props})


def _floats(mi, a):
    """A Mitsuba Float of float32 values, from 64-byte aligned memory: Dr.Jit reads a numpy array in place and
    compiles its kernel for the array's alignment, so aligned inputs keep one kernel, compiled once (and cached)."""
    buf = np.empty(a.size + 16, np.float32)
    start = (-buf.ctypes.data % 64) // 4
    buf[start:start + a.size] = np.ravel(a)
    return mi.Float(buf[start:start + a.size])


def _vectors(mi, v):
    return mi.Vector3f(*[_floats(mi, v[:, k]) for k in range(3)])


def _interaction(mi, wo):
    """A surface interaction seen from unit directions wo (N, 3) in the shading frame (Mitsuba's si.wi)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(wo))
    si.wi = _vectors(mi, wo)
    return si


def _plugin_eval(mi, bsdf, wi, wo):
    """(N, 3) the plugin's value at ωi (towards the light: Mitsuba's wo) and ωo (towards the viewer: its si.wi)."""
    return np.array(bsdf.eval(mi.BSDFContext(), _interaction(mi, wo), _vectors(mi, wi)), np.float64).T


def _directions(rng, n, lower=0.0):
    """n unit directions, uniform on the sphere; a share `lower` of them left below the horizon."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2]) * np.where(rng.random(n) < lower, -1, 1)
    return v


# (brdfs, bake method, the plugin's "method" property or None: the bake's)
EVAL_CASES = [("blinnphong+lambert", "sg", None), ("cooktorrance+ward", "sg-exact", None),
              ("blinnphong+lambert", "sg", "sg-exact")]


@pytest.mark.parametrize("name, method, override", EVAL_CASES)
def test_plugin_eval_matches_effective_brdf_eval(mi, baked, name, method, override):
    mat, files = baked[name, method]
    bsdf = _bsdf(mi, files, **({"method": override} if override else {}))
    rng = np.random.default_rng(1)
    wi, wo = _directions(rng, 20000, lower=0.1), _directions(rng, 20000, lower=0.1)
    # hard cases: the pole, the horizon, grazing, ωi = ωo, the mirror direction
    grazing = np.array([np.cos(0.3), np.sin(0.3), 1e-6])
    hard_i = np.array([[0, 0, 1], [1, 0, 0], grazing, [0.6, 0, 0.8], [-0.6, 0, 0.8], [0, 0, 1]], float)
    hard_o = np.array([[0, 0, 1], [0, 0, 1], [0.3, 0.2, 0.9], [0.6, 0, 0.8], [0.6, 0, 0.8], grazing], float)
    hard_o /= np.linalg.norm(hard_o, axis=1, keepdims=True)
    wi, wo = np.concatenate([wi, hard_i]), np.concatenate([wo, hard_o])
    ref = mat.eval(wi, wo, override)
    got = _plugin_eval(mi, bsdf, wi, wo)
    assert np.all(np.isfinite(got)) and (got >= 0).all()
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert below.sum() > 3000 and np.all(got[below] == 0)
    peak = ref.max()
    np.testing.assert_array_less(np.abs(got - ref), 2e-4 * np.maximum(ref, 0.01 * peak) + 1e-30)


def test_plugin_sampling_is_consistent_with_its_density(mi, baked):
    mat, files = baked["blinnphong+lambert", "sg"]
    bsdf = _bsdf(mi, files)
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(2)
    n, n_uniform = 1 << 17, 1 << 16
    for theta, phi in ((0, 0), (40, 20), (75, -110)):
        t, p = np.radians(theta), np.radians(phi)
        wo = np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
        si = _interaction(mi, np.tile(wo, (n, 1)))
        u = rng.random((3, n))
        bs, weight = bsdf.sample(ctx, si, _floats(mi, u[0]), mi.Point2f(_floats(mi, u[1]), _floats(mi, u[2])))
        weight, pdf, wi = np.array(weight, np.float64).T, np.array(bs.pdf, np.float64), np.array(bs.wo, np.float64).T
        assert np.all(np.isfinite(weight)) and (weight >= 0).all() and np.all(np.isfinite(pdf)) and (pdf >= 0).all()
        valid = pdf > 0
        assert np.all(weight[~valid] == 0) and np.all(wi[valid, 2] > 0)
        value = np.array(bsdf.eval(ctx, si, bs.wo), np.float64).T
        density = np.array(bsdf.pdf(ctx, si, bs.wo), np.float64)
        np.testing.assert_allclose(density, pdf, rtol=1e-5)
        np.testing.assert_allclose(weight[valid], value[valid] / pdf[valid, None], rtol=1e-5)
        _, both = bsdf.eval_pdf(ctx, si, bs.wo)
        np.testing.assert_allclose(np.array(both), pdf, rtol=1e-5)

        # ∫f̄ dω and ∫p dω over the hemisphere by uniform samples (float64 f̄)
        z, a = rng.random(n_uniform), 2 * np.pi * rng.random(n_uniform)
        w = np.stack([np.sqrt(1 - z * z) * np.cos(a), np.sqrt(1 - z * z) * np.sin(a), z], 1)
        f = mat.eval(w, np.tile(wo, (n_uniform, 1))) * 2 * np.pi
        mass = np.array(bsdf.pdf(ctx, _interaction(mi, np.tile(wo, (n_uniform, 1))), _vectors(mi, w))) * 2 * np.pi
        se = np.sqrt(weight.var(0) / n + f.var(0) / n_uniform)
        assert np.all(np.abs(weight.mean(0) - f.mean(0)) < 4 * se), (theta, weight.mean(0), f.mean(0), se)
        share = valid.mean()
        se = np.sqrt(share * (1 - share) / n + mass.var() / n_uniform)
        assert abs(share - mass.mean()) < 4 * se, (theta, share, mass.mean(), se)
        assert share > 0.5  # most samples land where f̄ lives

    # the ends of the unit square (u = 0 reaches a vMF's antipode) and of the choice of lobe
    ends = np.array([0.0, 0.5, 1 - 2.0**-24])
    u = np.stack(np.meshgrid(ends, ends, ends), 0).reshape(3, -1)
    wo = _directions(rng, u.shape[1])
    wo[:2] = [[0, 0, 1], [1e-6, 0, 1]]
    bs, weight = bsdf.sample(ctx, _interaction(mi, wo), _floats(mi, u[0]), mi.Point2f(_floats(mi, u[1]),
                                                                                        _floats(mi, u[2])))
    weight, pdf = np.array(weight), np.array(bs.pdf)
    assert np.all(np.isfinite(weight)) and (weight >= 0).all() and np.all(np.isfinite(pdf)) and (pdf >= 0).all()


def _mitsuba_mesh(mi, mesh, bsdf):
    """Our Mesh as a Mitsuba mesh: the same triangles, vertex normals and UVs (so the shading frame's s axis,
    Mitsuba's ∂p/∂u, is our tile frame's tangent)."""
    props = mi.Properties()
    props["mesh_bsdf"] = bsdf
    out = mi.Mesh("sphere", len(mesh.vertices), len(mesh.faces), props=props, has_vertex_normals=True,
                  has_vertex_texcoords=True)
    params = mi.traverse(out)
    params["vertex_positions"] = mi.Float(mesh.vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(mesh.faces.astype(np.uint32).ravel())
    params["vertex_normals"] = mi.Float(mesh.normals.astype(np.float32).ravel())
    params["vertex_texcoords"] = mi.Float(mesh.uvs.astype(np.float32).ravel())
    params.update()
    return out


def _mitsuba_scene(mi, scene: wb.Scene, bsdf, spp):
    """Our camera (vertical fov, look-at with up), mesh, constant environment and directional lights in Mitsuba:
    one bounce (max_depth 2) as our reference, which has no interreflection on a lone convex object anyway."""
    cam, env = scene.camera, scene.environment
    radiance = env.radiance.reshape(-1, 3)
    assert np.all(radiance == radiance[0]), "a constant environment is what this helper converts"
    lights = {f"light{i}": {"type": "directional", "direction": (-light.direction).tolist(),
                            "irradiance": {"type": "rgb", "value": light.irradiance.tolist()}}
              for i, light in enumerate(scene.lights)}
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 2},
        "sensor": {"type": "perspective", "fov_axis": "y", "fov": cam.fov,
                   "to_world": mi.ScalarTransform4f().look_at(origin=cam.eye.tolist(), target=cam.target.tolist(),
                                                              up=cam.up.tolist()),
                   "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sphere": _mitsuba_mesh(mi, scene.mesh, bsdf),
        "environment": {"type": "constant", "radiance": {"type": "rgb", "value": radiance[0].tolist()}},
        **lights})


def _neighbourhood_all(mask):
    """True where the pixel and its 8 neighbours are all True (False on the image border)."""
    out = np.zeros_like(mask)
    inner = np.ones_like(mask[1:-1, 1:-1])
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            inner &= mask[1 + dy:mask.shape[0] - 1 + dy, 1 + dx:mask.shape[1] - 1 + dx]
    out[1:-1, 1:-1] = inner
    return out


def test_mitsuba_renders_the_sphere_as_our_monte_carlo_reference(mi, baked):
    mat, files = baked["blinnphong+lambert", "sg-exact"]
    width, height, passes, spp = 64, 48, 8, 128
    # Off centre, the camera tilted and the light from the upper left: a flipped or mirrored image, a wrong fov
    # axis or a tile frame turned the wrong way would show.
    camera = wb.Camera(eye=(0.2, 0.4, 4.5), target=(0.3, 0.2, 0.0), fov=35, width=width, height=height)
    light = wb.DirectionalLight((-0.5, 0.6, 0.6), irradiance=(2.0, 1.8, 1.5), angular_radius=0.1)
    env = wb.Environment.constant((0.3, 0.35, 0.4))
    scene = wb.Scene(wb.Mesh.sphere(1.0, center=(0.5, 0.25, 0.0), subdivisions=5), [mat], camera, env, [light])

    t0 = time.perf_counter()
    with pytest.warns(UserWarning, match="fallback='sg'"):
        ref = wb.render(scene, method="mc", samples=256, fallback="sg")
    t_mc = time.perf_counter() - t0
    assert "sg-exact" in ref.info["effective_brdf"][0]
    t0 = time.perf_counter()
    mscene = _mitsuba_scene(mi, scene, _bsdf(mi, files), spp)
    images = np.array([np.array(mi.render(mscene, seed=s, spp=spp), np.float64) for s in range(passes)])
    t_mi = time.perf_counter() - t0
    ours, sigma_ours = ref.image.astype(np.float64), ref.info["stderr"].astype(np.float64)
    theirs, sigma_theirs = images.mean(0), images.std(0, ddof=1) / np.sqrt(passes)
    assert theirs.shape == ours.shape and np.all(np.isfinite(images)) and (images >= 0).all()

    hit = (wb.get_backend().trace_primary(scene.mesh, camera).face >= 0).reshape(height, width)
    inside, outside = _neighbourhood_all(hit), _neighbourhood_all(~hit)
    assert inside.sum() > 600 and outside.sum() > 1000
    # Where only the environment is seen, both show it exactly: the sphere is where we put it in both images.
    # (Mitsuba's float32 average of its samples rounds: 1e-5)
    np.testing.assert_allclose(theirs[outside], np.broadcast_to(env.radiance[0, 0], (outside.sum(), 3)), rtol=1e-5)
    np.testing.assert_allclose(ours[outside], np.broadcast_to(env.radiance[0, 0], (outside.sum(), 3)), rtol=1e-6)

    z = (theirs - ours)[inside] / np.sqrt(sigma_ours**2 + sigma_theirs**2)[inside]
    rms = float(np.sqrt(np.mean(z**2)))
    diff = theirs[inside].mean(0) - ours[inside].mean(0)
    se = np.sqrt((sigma_ours[inside] ** 2 + sigma_theirs[inside] ** 2).sum(0)) / inside.sum()
    print(f"\n{inside.sum()} pixels: z RMS {rms:.3f}, beyond 5σ {np.mean(np.abs(z) > 5):.4f}; mean Mitsuba "
          f"{theirs[inside].mean(0)}, ours {ours[inside].mean(0)}, relative {diff / ours[inside].mean(0)}, "
          f"{diff / se} standard errors; Monte Carlo {t_mc:.1f} s, Mitsuba {t_mi:.1f} s ({passes} × {spp} spp)")
    assert rms < 1.5, rms
    assert np.mean(np.abs(z) > 5) < 0.005
    assert np.all(np.abs(diff) < 4 * se), (diff, se)


def test_exported_script_renders_the_exported_scene(mi, baked, tmp_path):
    """render.py as a user runs it, from another working directory: it registers the plugin, loads scene.xml,
    which finds material.wbm beside it, and writes the image."""
    _, files = baked["cooktorrance+ward", "sg"]
    out = tmp_path / "render.exr"
    r = subprocess.run([sys.executable, files["script"], "--spp", "8", "-o", str(out)], capture_output=True,
                       text=True, cwd=tmp_path, timeout=600)
    assert r.returncode == 0, r.stderr
    image = wb.read_image(out).astype(np.float64)
    assert image.shape == (288, 384, 3) and np.all(np.isfinite(image)) and (image >= 0).all()
    np.testing.assert_allclose(image[0, 0], 0.4, rtol=1e-5)  # the constant environment in a corner
    centre = image[104:184, 152:232]  # the sphere's middle, lit by the environment and the light
    assert np.all(np.abs(centre - 0.4).max(-1) > 1e-3) and centre.mean() > 0.05


def test_register_refuses_a_scalar_variant(mi):
    mi.set_variant("scalar_rgb")
    try:
        with pytest.raises(ValueError, match="RGB JIT variant.*'scalar_rgb'"):
            mitsuba_export.register()
    finally:
        mi.set_variant(VARIANT)


def test_plugin_bad_properties_are_named(mi, baked, tmp_path):
    # (Mitsuba reports a plugin's exception as a RuntimeError ending in the plugin's message)
    with pytest.raises(RuntimeError, match='needs a string property "filename"'):
        mi.load_dict({"type": mitsuba_export.PLUGIN})
    with pytest.raises(RuntimeError, match="no such file: .*missing.wbm"):
        mi.load_dict({"type": mitsuba_export.PLUGIN, "filename": str(tmp_path / "missing.wbm")})
    _, files = baked["blinnphong+lambert", "sg"]
    with pytest.raises(RuntimeError, match="method must be one of .* got 'bogus'"):
        _bsdf(mi, files, method="bogus")


# ------------------------------------------------------------------------------------- no Mitsuba needed


def test_export_writes_the_files_atomically_and_leaves_the_material_alone(baked, tmp_path):
    mat, _ = baked["blinnphong+lambert", "sg"]
    mat.save(tmp_path / "m.wbm")
    files = mat.export_mitsuba(tmp_path / "out")
    assert mat.path == str(tmp_path / "m.wbm")  # the export saved a copy: the material still names its own file
    assert sorted(os.listdir(tmp_path / "out")) == sorted(mitsuba_export.FILES.values())  # no temporary left
    copy = wb.load(files["material"])
    np.testing.assert_array_equal(copy.amplitudes, mat.amplitudes)
    assert copy.materials == mat.materials and copy.method == mat.method
    xml = open(files["scene"]).read()
    assert f'type="{mitsuba_export.PLUGIN}"' in xml and 'value="material.wbm"' in xml
    assert "register()" in open(files["script"]).read()
    again = mat.export_mitsuba(tmp_path / "out")  # an existing folder: the files are replaced
    assert again == files
    # a user's own file of one of those names is not replaced, and nothing else is written
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "render.py").write_text("print('my own renderer')\n")
    with pytest.raises(ValueError, match=r"^Mitsuba export: '.*mine/render.py' exists and was not written by an "
                                         r"export; give another folder or move the file$"):
        mat.export_mitsuba(tmp_path / "mine")
    assert os.listdir(tmp_path / "mine") == ["render.py"]
    assert (tmp_path / "mine" / "render.py").read_text() == "print('my own renderer')\n"
    (tmp_path / "mine" / "render.py").unlink()
    (tmp_path / "mine" / "material.wbm").write_text("notes")
    with pytest.raises(ValueError, match="material.wbm' exists and was not written by an export"):
        mat.export_mitsuba(tmp_path / "mine")


def _full_disk_on(monkeypatch, name):
    """Writing the export's file `name` fails as on a full disk (the write's OSError(ENOSPC), naming no file),
    inside io.atomic_path, which handles it; the files before it are written."""
    import contextlib
    import errno

    from warp_biscale import io

    @contextlib.contextmanager
    def atomic_path(path):
        with io.atomic_path(path) as tmp:
            yield tmp
            if os.path.basename(path) == name:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(mitsuba_export, "atomic_path", atomic_path)


def test_a_failed_export_names_the_file_and_leaves_no_folder_it_made(baked, tmp_path, monkeypatch, capsys):
    mat, _ = baked["blinnphong+lambert", "sg"]
    mat.save(tmp_path / "m.wbm")
    _full_disk_on(monkeypatch, "scene.xml")  # (material.wbm, written before it, is in the folder by then)
    out = tmp_path / "full" / "exp"
    with pytest.raises(OSError) as info:
        mat.export_mitsuba(out)
    assert str(info.value) == f"{out / 'scene.xml'} could not be written: No space left on device"
    assert os.listdir(tmp_path) == ["m.wbm"]  # the folders the export made, and the material in them, are gone
    from warp_biscale import cli

    assert cli.main(["export", str(tmp_path / "m.wbm"), "--to", "mitsuba", "-o", str(out)]) == 1
    assert capsys.readouterr().err == f"error: {out / 'scene.xml'} could not be written: No space left on device\n"
    assert os.listdir(tmp_path) == ["m.wbm"]
    # a folder that was there (an earlier export's) stays, with the files the failed export did not replace
    monkeypatch.undo()
    files = mat.export_mitsuba(tmp_path / "earlier")
    script = open(files["script"]).read()
    _full_disk_on(monkeypatch, "render.py")
    with pytest.raises(OSError, match="render.py could not be written: No space left on device"):
        mat.export_mitsuba(tmp_path / "earlier")
    assert sorted(os.listdir(tmp_path / "earlier")) == sorted(mitsuba_export.FILES.values())
    assert open(files["script"]).read() == script


def test_export_bad_input_is_one_line_naming_it(baked, tmp_path):
    mat, _ = baked["blinnphong+lambert", "sg"]
    with pytest.raises(ValueError, match="must be an EffectiveBRDF .* got Lambert"):
        mitsuba_export.export(wb.Lambert(0.5), tmp_path / "x")
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ValueError, match="afile' is a file, not a folder"):
        mat.export_mitsuba(tmp_path / "afile")
    with pytest.raises(ValueError, match="afile' is a file, not a directory"):
        mat.export_mitsuba(tmp_path / "afile" / "out")


def _run_cli(*args):
    """The installed console script, from a scratch directory (as tests/test_cli.py runs it)."""
    import shutil

    exe = shutil.which("warp-biscale", path=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    assert exe, "the warp-biscale console script is not installed next to this Python"
    with tempfile.TemporaryDirectory() as scratch:
        return subprocess.run([exe, *args], capture_output=True, text=True, cwd=scratch, timeout=600)


def test_cli_export_writes_the_folder(baked, tmp_path):
    mat, _ = baked["cooktorrance+ward", "sg-exact"]
    mat.save(tmp_path / "m.wbm")
    r = _run_cli("export", str(tmp_path / "m.wbm"), "--to", "mitsuba", "-o", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "render.py" in r.stdout and "pip install mitsuba" in r.stdout
    for name in mitsuba_export.FILES.values():
        assert (tmp_path / "out" / name).is_file()
    np.testing.assert_array_equal(wb.load(tmp_path / "out" / "material.wbm").amplitudes, mat.amplitudes)


def _unwritable_dir(tmp_path):
    """A folder in which this user can create no file (for root, whom permissions do not stop: /proc)."""
    if os.geteuid() == 0:
        return "/proc"
    d = tmp_path / "locked"
    d.mkdir()
    d.chmod(0o500)
    return str(d)


@pytest.mark.parametrize("case", ["not a material", "missing", "folder is a file", "unwritable folder"])
def test_cli_export_bad_input_is_one_line(baked, tmp_path, case):
    mat, _ = baked["blinnphong+lambert", "sg"]
    mat.save(tmp_path / "m.wbm")
    (tmp_path / "notes.wbm").write_text("not a material")
    (tmp_path / "afile").write_text("x")
    material, out, named = {
        "not a material": (tmp_path / "notes.wbm", tmp_path / "out", tmp_path / "notes.wbm"),
        "missing": (tmp_path / "nothing.wbm", tmp_path / "out", tmp_path / "nothing.wbm"),
        "folder is a file": (tmp_path / "m.wbm", tmp_path / "afile", tmp_path / "afile"),
        "unwritable folder": (tmp_path / "m.wbm", os.path.join(_unwritable_dir(tmp_path), "sub"), "sub"),
    }[case]
    r = _run_cli("export", str(material), "--to", "mitsuba", "-o", str(out))
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("error: ") and str(named) in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert r.stdout == "" and not (tmp_path / "out").exists()


def test_cli_export_needs_a_known_target(tmp_path):
    r = _run_cli("export", str(tmp_path / "m.wbm"), "--to", "blender")
    assert r.returncode == 2 and "invalid choice: 'blender'" in r.stderr
    r = _run_cli("export", "--help")
    assert r.returncode == 0 and "--to {mitsuba}" in r.stdout


def test_warp_biscale_imports_without_mitsuba():
    """Mitsuba stays optional: importing warp_biscale (and writing an export) loads no Mitsuba module."""
    code = ("import sys, warp_biscale, warp_biscale.mitsuba_export, warp_biscale.cli; "
            "print(any(m == 'mitsuba' or m.startswith('mitsuba.') for m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr
