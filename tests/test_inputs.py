"""Every bad input is refused before the work, in one line that names it: non-positive sizes, NaN and inf
in scene construction (and their file:line in a scene file), an energy gain in a BRDF (a warning), BRDFs
beyond a tile's material ids (a warning) and [render] settings beyond what the renderer takes."""

import re
import sys
import textwrap
import warnings

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import ssdf
from warp_biscale.brdf import EnergyWarning
from warp_biscale.lobes import KERNEL_LOBES
from warp_biscale.scene import SSDF_RESOLUTIONS
from warp_biscale.scenefile import SceneError, load_scene

NAN, INF = float("nan"), float("inf")


def _scene(**settings):
    return wb.Scene(wb.Mesh.sphere(subdivisions=0), wb.Lambert(0.5), **settings)


BAD = [
    # Mesh.sphere
    (lambda: wb.Mesh.sphere(radius=-0.8), "Mesh.sphere radius must be > 0, got -0.8"),
    (lambda: wb.Mesh.sphere(radius=0), "Mesh.sphere radius must be > 0"),
    (lambda: wb.Mesh.sphere(radius=NAN), "Mesh.sphere radius must be a finite number > 0, got nan"),
    (lambda: wb.Mesh.sphere(radius=INF), "Mesh.sphere radius"),
    (lambda: wb.Mesh.sphere(subdivisions=-1), "Mesh.sphere subdivisions must be an integer in 0..8"),
    (lambda: wb.Mesh.sphere(subdivisions=1.5), "Mesh.sphere subdivisions"),
    (lambda: wb.Mesh.sphere(center=(0, NAN, 0)), "Mesh.sphere center"),
    (lambda: wb.Mesh.sphere(material=-1), "Mesh.sphere material must be an integer >= 0"),
    # Mesh.torus
    (lambda: wb.Mesh.torus(major=-1.0), "Mesh.torus major must be > 0, got -1.0"),
    (lambda: wb.Mesh.torus(minor=0.0), "Mesh.torus minor must be > 0, got 0.0"),
    (lambda: wb.Mesh.torus(minor=NAN), "Mesh.torus minor"),
    (lambda: wb.Mesh.torus(segments=(2, 48)), "Mesh.torus segments[0] (around) must be an integer in 3..4096, got 2"),
    (lambda: wb.Mesh.torus(segments=(96, 0)), "Mesh.torus segments[1] (across)"),
    (lambda: wb.Mesh.torus(segments=5), "Mesh.torus segments must be two integers"),
    (lambda: wb.Mesh.torus(center=(INF, 0, 0)), "Mesh.torus center"),
    # Mesh.plane
    (lambda: wb.Mesh.plane(size=-4.0), "Mesh.plane size must be > 0, got -4.0"),
    (lambda: wb.Mesh.plane(size=0), "Mesh.plane size"),
    (lambda: wb.Mesh.plane(height=NAN), "Mesh.plane height must be a finite number"),
    (lambda: wb.Mesh.plane(divisions=0), "Mesh.plane divisions must be an integer in 1..2048"),
    # Camera
    (lambda: wb.Camera(fov=NAN), "Camera.fov"),
    (lambda: wb.Camera(fov="wide"), "Camera.fov"),
    (lambda: wb.Camera(width=NAN), "Camera.width must be an integer in 1..16384, got nan"),
    (lambda: wb.Camera(height=-2), "Camera.height"),
    # lights
    (lambda: wb.PointLight(intensity=-1.0), "PointLight.intensity"),
    (lambda: wb.PointLight(intensity=INF), "PointLight.intensity"),
    (lambda: wb.PointLight(intensity=(1.0, NAN, 1.0)), "PointLight.intensity"),
    (lambda: wb.PointLight(intensity="bright"), "PointLight.intensity"),
    (lambda: wb.PointLight(radius=-0.1), "PointLight.radius must be > 0, got -0.1"),
    (lambda: wb.PointLight(radius=NAN), "PointLight.radius"),
    (lambda: wb.PointLight(position=(0, INF, 0)), "PointLight.position"),
    (lambda: wb.DirectionalLight(irradiance=-2.0), "DirectionalLight.irradiance"),
    # built-in meshes past what fits in memory (a sphere of 12 subdivisions ran for minutes; 1e5 plane divisions
    # asked numpy for 75 GiB)
    (lambda: wb.Mesh.sphere(subdivisions=12), "Mesh.sphere subdivisions must be an integer in 0..8"),
    (lambda: wb.Mesh.torus(segments=(4000, 4000)), "Mesh.torus segments 4000 x 4000 make 32,000,000 faces"),
    (lambda: wb.Mesh.plane(divisions=100000), "Mesh.plane divisions must be an integer in 1..2048"),
    # a tile or mesh past the float32 kernels' range (a tile at 1e25 crashed the bake's kernels, at 1e-25 found no lobe)
    (lambda: wb.SmallScale(wb.geometry.pyramid().vertices * 1e25, wb.geometry.pyramid().faces),
     "spans 1e+25 with coordinates up to 1e+25: the kernels, in float32, take a period of at least 1e-12"),
    (lambda: wb.SmallScale(wb.geometry.pyramid().vertices * 1e-25, wb.geometry.pyramid().faces), "rescale it"),
    (lambda: wb.Mesh(np.array([[0, 0, 0], [1e30, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])),
     "Mesh.vertices reach 1e+30: the float32 renderers take coordinates up to 1e+12"),
    # an environment as bright: its sun would become such a light (an EXR texel of 3e38 was refused as an internal
    # light the user never wrote)
    (lambda: wb.Environment.constant(1e38), "Environment 'constant' holds radiance up to 1e+38: the renderers"),
    (lambda: wb.Environment.sky(height=100000, width=200000),  # (it asked numpy for 149 GiB)
     "environment size 100000 x 200000 is past the largest, 8192 x 16384"),
    (lambda: wb.Environment.studio(height=64, width=20000), "environment size 64 x 20000 is past the largest"),
    # past float32's room once a small light's sharp lobe scales it (1e38 rendered black, 1e39 failed unnamed)
    (lambda: wb.PointLight(intensity=1e38), "PointLight.intensity must be at most 1e+20"),
    (lambda: wb.DirectionalLight(irradiance=(1, 1, 1e21)), "DirectionalLight.irradiance must be at most 1e+20"),
    (lambda: wb.DirectionalLight(irradiance=NAN), "DirectionalLight.irradiance"),
    (lambda: wb.DirectionalLight(angular_radius=NAN), "DirectionalLight.angular_radius"),
    (lambda: wb.DirectionalLight(angular_radius="big"), "DirectionalLight.angular_radius"),
    # BRDFs
    (lambda: wb.Lambert(-0.5), "Lambert.albedo"),
    (lambda: wb.Lambert(NAN), "Lambert.albedo"),
    (lambda: wb.Lambert("grey"), "Lambert.albedo"),
    (lambda: wb.BlinnPhong(0.5, -10.0), "BlinnPhong.exponent must be a finite number > 0, got -10.0"),
    (lambda: wb.BlinnPhong(0.5, "sharp"), "BlinnPhong.exponent"),
    (lambda: wb.CookTorrance(0.5, 0.2, f0=NAN), "CookTorrance.f0"),
    (lambda: wb.CookTorrance(0.5, 0.2, f0="glass"), "CookTorrance.f0"),
    (lambda: wb.Ward(0.5, INF), "Ward.alpha"),
    # render settings: the ranges the renderer takes
    (lambda: _scene(env_lobes=KERNEL_LOBES + 1), f"Scene.env_lobes must be an integer in 1..{KERNEL_LOBES}"),
    (lambda: _scene(env_lobes=0), "Scene.env_lobes"),
    (lambda: _scene(env_lobes=NAN), "Scene.env_lobes"),
    (lambda: _scene(ssdf_resolution=1), "Scene.ssdf_resolution must be an integer in 2..128"),
    (lambda: _scene(ssdf_resolution=129), "Scene.ssdf_resolution"),
    (lambda: _scene(ssdf_resolution=8, ssdf_terms=65), "Scene.ssdf_terms must be an integer in 1..64"),
    (lambda: _scene(ssdf_terms=0), "Scene.ssdf_terms"),
    # a point light whose sphere reaches into the mesh (the unit sphere's icosahedron: faces ≥ 0.79 from 0)
    (lambda: _scene(lights=[wb.PointLight((0, 0, 0), 1.0, 100.0)]),
     r"Scene.lights[0]: the PointLight of radius 100 at (0.0, 0.0, 0.0) reaches into the mesh (a face 0.795 from "
     "its centre): a light must lie outside the objects"),
    (lambda: _scene(lights=[wb.PointLight((0, 0, 1.1), 1.0, 0.3)]), "Scene.lights[0]: the PointLight of radius 0.3"),
]


@pytest.mark.parametrize("make, names", BAD, ids=[names for _, names in BAD])
def test_bad_input_is_refused_in_one_line_naming_it(make, names):
    with pytest.raises(ValueError) as info:
        make()
    msg = str(info.value)
    assert names in msg, msg
    assert "\n" not in msg, msg


def test_good_sizes_still_build():
    assert len(wb.Mesh.sphere(radius=0.8, subdivisions=0).faces) == 20
    assert len(wb.Mesh.torus(0.5, 0.1, segments=(3, 3)).faces) == 18
    assert len(wb.Mesh.plane(size=1.0, divisions=1).faces) == 2
    np.testing.assert_allclose(np.linalg.norm(wb.Mesh.sphere(radius=np.float32(2.0)).vertices, axis=1), 2.0)
    s = _scene(env_lobes=KERNEL_LOBES, ssdf_resolution=8, ssdf_terms=64)
    assert (s.env_lobes, s.ssdf_resolution, s.ssdf_terms) == (KERNEL_LOBES, 8, 64)
    # the default 16 PCA terms, or as many as a coarse SSDF has directions (2² = 4: it was refused over a default
    # the user never wrote)
    assert [_scene(ssdf_resolution=r).ssdf_terms for r in (2, 3, 4, 32)] == [4, 9, 16, 16]


def test_ssdf_resolution_range_is_the_ssdf_modules():
    lo, hi = SSDF_RESOLUTIONS
    for ok in (lo, hi):
        ssdf._check_resolution(ok)
    for bad in (lo - 1, hi + 1):
        with pytest.raises(ValueError):
            ssdf._check_resolution(bad)


# ------------------------------------------------------------------------------------------------ energy


@pytest.mark.parametrize("make, match", [
    (lambda: wb.Lambert(1.2), r"Lambert albedo 1\.2 > 1 reflects more light than it receives"),
    (lambda: wb.Lambert((0.5, 1.3, 0.5)), r"Lambert albedo \(0\.5, 1\.3, 0\.5\): g = 1\.3 > 1"),
    (lambda: wb.BlinnPhong(0.5, 100, kd=1.5), r"BlinnPhong kd 1\.5 > 1 reflects more light"),
    (lambda: wb.CookTorrance(0.5, 0.2, kd=(1.1, 0.2, 0.2)), r"CookTorrance kd .*r = 1\.1 > 1"),
    (lambda: wb.Ward(0.5, 0.2, kd=2.0), r"Ward kd 2 > 1"),
    (lambda: wb.Textured(wb.Lambert(0.8), kd_map=np.full((2, 2, 3), 1.5)),
     r"Textured Lambert albedo × kd_map \(at its brightest\) 1\.2 > 1"),
])
def test_an_energy_gain_warns_naming_the_input(make, match):
    with pytest.warns(EnergyWarning, match=match) as record:
        make()
    assert all(w.filename == __file__ for w in record if issubclass(w.category, EnergyWarning))


def test_physical_brdfs_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", EnergyWarning)
        wb.Lambert(1.0)
        wb.BlinnPhong(0.5, 100, kd=0.5, normalization="energy")  # specular albedo ks at most: 0.5 + 0.5
        wb.Ward(0.9, 0.2, kd=(1.0, 0.5, 0.0))
        wb.Textured(wb.BlinnPhong(0.5, 100, kd=0.5, normalization="energy"),
                    kd_map=np.full((2, 2, 3), 2.0))  # 0.5 × 2 = 1


def test_energy_warning_is_a_user_warning():
    assert issubclass(EnergyWarning, UserWarning)


# ------------------------------------------------------------------------------------------------ unused BRDFs


@pytest.fixture
def two_id_tile():
    tile = wb.geometry.pyramid(height=0.3, base_material=1)
    assert tile.n_materials == 2
    return tile


class _NoWork(Exception):
    pass


def _no_work(*a, **k):
    raise _NoWork


@pytest.mark.parametrize("call", ["bake", "ground_truth", "effective_brdf_exact"])
def test_brdfs_beyond_the_tiles_ids_warn_before_the_work(two_id_tile, call, monkeypatch):
    for mod in ("warp_biscale.bake", "warp_biscale.truth"):  # (wb.bake is the function: the module by name)
        monkeypatch.setattr(sys.modules[mod], "get_backend", _no_work)
    fn = {"bake": lambda m: wb.bake(two_id_tile, m),
          "ground_truth": lambda m: wb.ground_truth(two_id_tile, m),
          "effective_brdf_exact": lambda m: wb.effective_brdf_exact(two_id_tile, m, [[0, 0, 1.0]], [[0, 0, 1.0]])}
    mats = [wb.Lambert(0.5), wb.Lambert(0.4), wb.Lambert(0.3), wb.Lambert(0.2)]
    with pytest.warns(wb.TileWarning, match=r"^3 BRDFs given for a tile with 2 material ids: BRDF 2 is unused$") as rec:
        with pytest.raises(_NoWork):
            fn[call](mats[:3])
    assert [w.filename for w in rec if issubclass(w.category, wb.TileWarning)] == [__file__]  # the caller's line
    with pytest.warns(wb.TileWarning, match=r"^4 BRDFs given for a tile with 2 material ids: BRDFs 2\.\.3 are unused$"):
        with pytest.raises(_NoWork):
            fn[call](mats)


def test_as_many_brdfs_as_ids_or_one_do_not_warn(two_id_tile, monkeypatch):
    monkeypatch.setattr(sys.modules["warp_biscale.truth"], "get_backend", _no_work)
    with warnings.catch_warnings():
        warnings.simplefilter("error", wb.TileWarning)
        for mats in ([wb.Lambert(0.5), wb.Lambert(0.4)], wb.Lambert(0.5)):
            with pytest.raises((_NoWork, ValueError)):  # one BRDF for two ids: refused by pack_materials
                wb.ground_truth(two_id_tile, mats)


def test_extra_brdfs_still_bake(two_id_tile):
    with pytest.warns(wb.TileWarning, match="BRDF 2 is unused"):
        mat = wb.bake(two_id_tile, [wb.Lambert(0.5), wb.Lambert(0.4), wb.Lambert(0.3)], lobes=2, directions=4,
                      facets=512, normal_res=16, backend="warp:cpu")
    assert len(mat.materials) == 3


# ------------------------------------------------------------------------------------------------ scene files

from test_scenefile import BASE  # noqa: E402  (the smallest scene file: one sphere, one Lambert material)


def _load_error(tmp_path, text):
    p = tmp_path / "scene.toml"
    p.write_text(textwrap.dedent(text))
    with pytest.raises(SceneError) as info:
        load_scene(p, backend="warp:cpu")
    assert "\n" not in str(info.value)
    return info.value


def _line(text, snippet):
    return next(i for i, line in enumerate(text.splitlines(), 1) if snippet in line)


@pytest.mark.parametrize("extra, snippet, words", [
    ("radius = -0.8\n", "radius = -0.8", ["[[object]] #1", "Mesh.sphere radius must be > 0, got -0.8"]),
    ("subdivisions = -2\n", "subdivisions = -2", ["Mesh.sphere subdivisions must be an integer in 0..8", "got -2"]),
    ("translate = [nan, 0, 0]\n", "translate", ["translate must be three finite numbers"]),
    ("rotate = [0, inf, 0]\n", "rotate", ["rotate must be three finite numbers"]),
    ("scale = 0\n", "scale = 0", ["scale must be > 0, got 0"]),
])
def test_scene_file_sphere_errors_have_file_and_line(tmp_path, extra, snippet, words):
    text = BASE.replace("subdivisions = 1\n", "subdivisions = 1\n" + extra) if "subdivisions" not in extra \
        else BASE.replace("subdivisions = 1\n", extra)
    err = _load_error(tmp_path, text)
    line = _line(text, snippet)
    assert str(err).startswith(f"scene.toml:{line}:"), str(err)
    assert err.line == line
    for w in words:
        assert w in str(err), str(err)


@pytest.mark.parametrize("mesh, extra, snippet, word", [
    ("torus", "minor = -0.1\n", "minor", "Mesh.torus minor must be > 0, got -0.1"),
    ("torus", "segments = [2, 48]\n", "segments", "Mesh.torus segments[0] (around) must be an integer in 3..4096"),
    ("plane", "size = 0.0\n", "size", "Mesh.plane size must be > 0, got 0.0"),
    ("plane", "divisions = 0\n", "divisions", "Mesh.plane divisions must be an integer in 1..2048"),
])
def test_scene_file_mesh_errors_have_file_and_line(tmp_path, mesh, extra, snippet, word):
    text = BASE.replace('mesh = "sphere"\nsubdivisions = 1\n', f'mesh = "{mesh}"\n{extra}')
    err = _load_error(tmp_path, text)
    assert str(err).startswith(f"scene.toml:{_line(text, snippet)}:"), str(err)
    assert word in str(err)


@pytest.mark.parametrize("render, snippet, word", [
    (f"env_lobes = {2 * KERNEL_LOBES}", "env_lobes",
     f"[render] env_lobes must be an integer in 1..{KERNEL_LOBES} (the SG lighting kernels' lobe count), "
     f"got {2 * KERNEL_LOBES}"),
    ("env_lobes = 0", "env_lobes", "env_lobes must be an integer in 1.."),
    ("ssdf_resolution = 1", "ssdf_resolution", "ssdf_resolution must be an integer in 2..128"),
    ("ssdf_resolution = 256", "ssdf_resolution", "ssdf_resolution must be an integer in 2..128"),
    ("ssdf_resolution = 8\nssdf_terms = 100", "ssdf_terms", "ssdf_terms must be an integer in 1..64"),
    ("ssdf_terms = 2000", "ssdf_terms", "ssdf_terms must be an integer in 1..1024"),  # the default 32²
    ("samples = 1", "samples", "samples must be >= 2"),
])
def test_scene_file_render_settings_are_checked_at_load(tmp_path, render, snippet, word):
    text = f"[render]\nwidth = 64\n{render}\n\n" + BASE
    err = _load_error(tmp_path, text)
    assert str(err).startswith(f"scene.toml:{_line(text, snippet)}:"), str(err)
    assert err.key == snippet
    assert word in str(err), str(err)


def test_scene_file_light_errors_have_file_and_line(tmp_path):
    text = BASE + '\n[[light]]\ntype = "point"\nposition = [0, 3, 0]\nintensity = -5.0\n'
    err = _load_error(tmp_path, text)
    assert str(err).startswith(f"scene.toml:{_line(text, 'intensity')}: [[light]] #1 PointLight.intensity")
    text = BASE + '\n[[light]]\ntype = "directional"\nirradiance = [1, nan, 1]\n'
    err = _load_error(tmp_path, text)
    assert str(err).startswith(f"scene.toml:{_line(text, 'irradiance')}: [[light]] #1 irradiance must be a finite")


def test_scene_file_energy_warning_has_file_and_line(tmp_path):
    text = BASE.replace("albedo = 0.5", "albedo = 1.2")
    p = tmp_path / "scene.toml"
    p.write_text(text)
    line = _line(text, "albedo")
    with pytest.warns(EnergyWarning, match=rf"^scene\.toml:{line}: \[material\.m\] Lambert albedo 1\.2 > 1"):
        sf = load_scene(p, backend="warp:cpu")
    assert sf.scene.materials[0].albedo == (1.2, 1.2, 1.2)  # a warning, not an error


def test_scene_file_unused_brdf_warning_has_file_and_line(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules["warp_biscale.bake"], "get_backend", _no_work)
    text = BASE.replace('material = "m"', 'material = "b"') + (
        '\n[material.b]\ntype = "bake"\ntile = "pyramid"\n'
        'tile_params = { height = 0.3, base_material = 1 }\n'
        'brdf = ["lambert:albedo=0.5", "lambert:albedo=0.4", "lambert:albedo=0.3"]\n')
    p = tmp_path / "scene.toml"
    p.write_text(text)
    with pytest.warns(wb.TileWarning, match=rf"^scene\.toml:{_line(text, 'brdf')}: \[material\.b\] 3 BRDFs given "
                                            r"for a tile with 2 material ids"):
        with pytest.raises(_NoWork):
            load_scene(p, backend="warp:cpu")


def test_load_and_compare_say_what_does_not_fit(tmp_path):
    """`wb.load` of an image says it is not a warp_biscale file (numpy's pickle message did not), of a lit-sphere
    folder loads it; `wb.compare` of a bake against the truth of other small-scale BRDFs warns (it returned a PSNR
    and said nothing; not an error, as AnisotropicWard(a, a) and Ward(a) judge each other)."""
    from PIL import Image

    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "demo.png")
    with pytest.raises(ValueError, match=r"demo.png is truncated or corrupt, or not a warp_biscale file"):
        wb.load(tmp_path / "demo.png")
    ls = wb.LitSphere.from_material(wb.Lambert(0.5), angles=(0.0, 90.0), resolution=16)
    ls.save(tmp_path / "ball")
    assert isinstance(wb.load(tmp_path / "ball"), wb.LitSphere)
    with pytest.raises(ValueError, match="not a lit-sphere folder"):
        wb.load(tmp_path)
    tile = wb.geometry.pyramid()
    kw = dict(directions=3, facets=1024, backend="warp:cpu")
    mat = wb.bake(tile, wb.Lambert(0.5), **kw)
    assert wb.compare(mat, wb.ground_truth(tile, wb.Lambert(0.5), **kw))["psnr"] > 20
    other = wb.ground_truth(tile, wb.BlinnPhong(0.5, 64, kd=0.2, normalization="energy"), **kw)
    with pytest.warns(UserWarning, match="compare: the material's small-scale BRDFs .* are not the ground truth's"):
        wb.compare(mat, other)
    with pytest.warns(wb.TileWarning):  # a truth listing more materials than the tile has ids (the editor's)
        more = wb.ground_truth(tile, [wb.Lambert(0.5), wb.Lambert(0.2)], **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wb.compare(mat, more)


def test_a_brdf_spec_string_is_refused_in_one_line_naming_parse_brdf():
    """A spec string (the command line's --brdf syntax) given as the materials: read as a list, it was one "BRDF" a
    character ('l'); the Python API takes BRDF objects and says where spec strings are read."""
    with pytest.raises(ValueError, match=r"materials is the string 'lambert:albedo=0.5': pass BRDF objects .*"
                                         r"parse_brdf"):
        wb.bake(wb.geometry.pyramid(), "lambert:albedo=0.5", directions=3, facets=256, backend="warp:cpu")
    assert wb.brdf.parse_brdf("lambert:albedo=0.5") == wb.Lambert(0.5)


# ------------------------------------------------------------------------------------------------ output paths


def test_every_save_refuses_a_bad_path_in_one_line_before_writing(tmp_path, monkeypatch):
    """Each object's `save` checks its path as `io.check_output` does (MeasuredBRDF.save's one line): an existing
    folder, a folder that is a file, and for a tile or an image a suffix it cannot write (trimesh's and the OS's
    own errors named a temporary file or said "object must be PointCloud"). Nothing is left behind."""
    monkeypatch.setenv("WARP_BISCALE_MATRIX_CACHE", str(tmp_path / "factors"))
    tile = wb.geometry.pyramid()
    kw = dict(directions=3, facets=256, backend="warp:cpu")
    lam = wb.Lambert(0.5)
    objects = {"EffectiveBRDF": wb.bake(tile, lam, **kw), "ASGBRDF": wb.bake(tile, lam, method="asg", **kw),
               "MatrixBRDF": wb.bake(tile, lam, method="matrix", matrix={"normal_res": 9}, **kw),
               "GroundTruth": wb.ground_truth(tile, lam, **kw), "SmallScale": tile,
               "Rendering": wb.Rendering(np.zeros((2, 2, 3), np.float32), {}, {})}
    out = tmp_path / "out"
    out.mkdir()
    (out / "folder").mkdir()
    (out / "a_file").write_text("")
    suffix = {"SmallScale": ".ply", "Rendering": ".png"}
    for name, obj in objects.items():
        good = suffix.get(name, ".wbm")
        cases = [(out / "folder", "is a directory"), (out / "a_file" / f"x{good}", "is a file, not a directory")]
        if name in suffix:
            cases.append((out / "x.xyz", "must end in " + (".obj, .ply, .stl, .off, .glb" if name == "SmallScale"
                                                           else ".exr, .hdr, .pic, .png")))
        for path, words in cases:
            with pytest.raises(ValueError, match=words) as err:
                obj.save(path)
            assert str(path) in str(err.value) and "\n" not in str(err.value) and ".tmp" not in str(err.value), name
        obj.save(out / f"{name}{good}")  # a good path still writes
    assert sorted(p.name for p in out.iterdir()) == sorted(["folder", "a_file"] + [
        f"{name}{suffix.get(name, '.wbm')}" for name in objects])
    assert not list((out / "folder").iterdir())


def test_loading_a_material_does_not_warn_again_about_its_energy(tmp_path):
    """A material file holding a BRDF that reflects more than it receives loads without an EnergyWarning (it was
    given when the BRDF was built; at load it pointed at effective.py, not the caller); building the BRDF still
    warns."""
    def gain():
        return wb.BlinnPhong(1.0, 512)  # Blinn–Phong's default normalisation: more out than in at grazing light

    with pytest.warns(EnergyWarning):
        brdf = gain()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EnergyWarning)
        mat = wb.bake(wb.geometry.pyramid(), brdf, directions=3, facets=256, backend="warp:cpu")
    mat.save(tmp_path / "m.wbm")
    with warnings.catch_warnings():
        warnings.simplefilter("error", EnergyWarning)
        back = wb.load(tmp_path / "m.wbm")
    assert back.materials == [brdf]
    with pytest.warns(EnergyWarning):
        gain()


@pytest.mark.parametrize("method", ["sg", "mc", "litsphere"])
def test_an_unknown_render_option_is_one_line_for_every_method(method, monkeypatch):
    """Each renderer refuses an option it does not take by name, as a ValueError, before any work (the Monte Carlo
    reference and the lit-sphere shader used to raise Python's TypeError from inside their call)."""
    render = sys.modules["warp_biscale.render"]  # (the module: the package's `render` is its function)

    def no_backend(*args, **kwargs):
        raise AssertionError("the renderer started before checking its options")

    monkeypatch.setattr(render, "get_backend", no_backend)
    with pytest.raises(ValueError, match=r"unknown option\(s\) for .*'bogus'"):
        wb.render(_scene(), method=method, bogus=1)


def test_images_too_large_to_read_are_refused_before_decoding(tmp_path):
    """A small compressed file can stand for an image that fills the memory (a 165 KB PNG of 12000 × 12000 took all
    24 GB as a height field): its header's size is checked first, one line naming the file and the limit."""
    from PIL import Image

    path = tmp_path / "flat.png"
    Image.new("L", (2049, 2048)).save(path)  # 2049·2048 cells: one column past the height field's 2048²
    assert path.stat().st_size < 100_000
    with pytest.raises(ValueError, match="flat.png is 2049×2048 pixels: at most 4,194,304 are read"):
        wb.geometry.heightfield_from_image(path)
    Image.new("RGB", (8193, 8192)).save(path)
    with pytest.raises(ValueError, match="flat.png is 8193×8192 pixels: at most 67,108,864 are read"):
        wb.Environment.from_file(path)


def test_a_material_file_with_a_malformed_material_list_or_zero_lobe_axes_is_refused(tmp_path):
    """A .wbm whose `materials` holds a string (not a BRDF table) failed with an AttributeError traceback; one whose
    lobe axes are zero loaded with a numpy warning and rendered without its specular term. Both now say the file
    is not a valid material file, in one line."""
    import json

    mat = wb.bake(wb.geometry.pyramid(), [wb.Lambert(0.5)], lobes=2, directions=4, facets=1024, normal_res=16,
                  backend="warp:cpu")
    good = tmp_path / "good.wbm"
    mat.save(good)
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    for name, edit in (("list", lambda h, a: h.update(materials=["phong:x=1"])),
                       ("axes", lambda h, a: a.__setitem__("axes", np.zeros_like(a["axes"])))):
        h, a = json.loads(json.dumps(header)), dict(arrays)
        edit(h, a)
        bad = tmp_path / f"{name}.wbm"
        with open(bad, "wb") as fh:  # (a path would get .npz added)
            np.savez_compressed(fh, header=np.array(json.dumps(h)), **a)
        with pytest.raises(ValueError, match=f"{name}.wbm is not a valid material file: "):
            wb.load(bad)


@pytest.mark.parametrize("seed", [-1, 1.5, "7", True])
def test_a_facet_sampling_seed_is_a_non_negative_integer(seed):
    """numpy's SeedSequence said "expected non-negative integer" naming no argument for -1, and 1.5 was taken."""
    tile = wb.geometry.pyramid()
    for call in (lambda: wb.bake(tile, [wb.Lambert(0.5)], lobes=2, directions=4, facets=1024, seed=seed),
                 lambda: wb.ground_truth(tile, [wb.Lambert(0.5)], directions=4, facets=1024, seed=seed)):
        with pytest.raises(ValueError, match=r"^seed must be an integer in 0 \.\. 2\*\*63 - 1, got"):
            call()


def test_render_studio_and_image_reading_name_a_wrong_argument(tmp_path):
    """wb.render(None) or of a path was an AttributeError; a studio light given as an incomplete table a bare
    TypeError from Softbox; a folder read as an environment map an "unknown image extension ''"."""
    for arg, words in ((None, "render takes a Scene, got NoneType"),
                       ("scene.toml", "got str (a scene file: wb.load_scene(path).scene)")):
        with pytest.raises(TypeError, match=re.escape(words)):
            wb.render(arg)
    with pytest.raises(ValueError, match=r"Environment.studio light #1: .*missing 3 required"):
        wb.Environment.studio(lights=[{}])
    box = {"direction": (0, 1, 0), "half_width": 10, "half_height": 10}  # (a table of a Softbox's fields works)
    assert wb.Environment.studio(lights=[box], height=16, width=32).radiance.max() > 0
    with pytest.raises(ValueError, match="is a folder, not an image file"):
        wb.Environment.from_file(tmp_path)


def test_mesh_distance_to_matches_dense_samples_and_a_light_outside_is_taken():
    mesh = wb.Mesh.merge([wb.Mesh.sphere(1.0, (0, 1, 0), subdivisions=1), wb.Mesh.plane(4.0, 0.0, 4)])
    tri = mesh.vertices[mesh.faces]
    rng = np.random.default_rng(3)
    u, v = rng.random((2, 400, 1))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    samples = tri[:, None, 0] + u * (tri[:, None, 1] - tri[:, None, 0]) + v * (tri[:, None, 2] - tri[:, None, 0])
    for p in rng.uniform(-3, 3, (12, 3)):
        dense = np.linalg.norm(samples - p, axis=2).min()
        d = mesh.distance_to(p)
        # the exact distance is below every sample's and within the samples' spacing (faces ≤ 1.1 across)
        assert d <= dense + 1e-12 and dense - d < 0.1, (p, d, dense)
    assert mesh.distance_to((0, 3, 0)) == pytest.approx(1.0, abs=0.02)  # above the sphere's top vertex
    assert mesh.distance_to((0, 3, 0), within=0.5) == np.inf
    wb.Scene(mesh, wb.Lambert(0.5), lights=[wb.PointLight((0, 2.3, 0), 1.0, 0.25)])  # 0.3 above the top: fine


def _forged_material(tmp_path, name, edit):
    """A small baked material saved, then its file rewritten with `edit(header, arrays)` applied."""
    import json

    path = tmp_path / "good.wbm"
    if not path.exists():
        wb.bake(wb.geometry.pyramid(), [wb.Lambert(0.5)], lobes=2, directions=4, facets=1024, normal_res=16,
                backend="warp:cpu").save(path)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    edit(header, arrays)
    bad = tmp_path / f"{name}.wbm"
    with open(bad, "wb") as fh:  # (a path would get .npz added)
        np.savez_compressed(fh, header=np.array(json.dumps(header)), **arrays)
    return bad


def test_a_material_file_with_amplitudes_past_float32s_room_is_refused(tmp_path):
    """A forged .wbm with amplitudes of 3e38 loaded and rendered black in the SG renderer (1e38 elsewhere). Amplitudes
    above effective.AMPLITUDE_MAX (1e8: 600 times the most a bake makes, SHARPNESS_MAX/(2π) ≈ 1.6e5, and low enough
    that the SG renderer's float32 cannot overflow under the brightest light a scene takes; its comment) are refused
    at load, one line naming the file and the largest value; the bound itself loads and renders finite."""
    from warp_biscale.effective import AMPLITUDE_MAX

    def fill(value):
        return lambda h, a: a.__setitem__("amplitudes", np.full_like(a["amplitudes"], value))

    for value, shown in ((3e38, "3e+38"), (AMPLITUDE_MAX * 1.01, "1.01e+08")):
        bad = _forged_material(tmp_path, "big", fill(value))
        with pytest.raises(ValueError) as info:
            wb.load(bad)
        message = str(info.value)
        assert f"{bad} is not a valid material file: amplitudes hold values up to {shown}: at most 1e+08" in message
        assert "\n" not in message
    mat = wb.load(_forged_material(tmp_path, "bound", fill(AMPLITUDE_MAX)))
    scene = wb.Scene(wb.Mesh.sphere(subdivisions=1), [mat], wb.Camera(eye=(0, 0.5, 3), width=16, height=12),
                     wb.Environment.constant(1.0), [wb.DirectionalLight((0.3, 1.0, 0.2), 1e20)])
    image = wb.render(scene, backend="warp:cpu").image
    assert np.isfinite(image).all() and (image >= 0).all() and image.max() > 1e20


def test_a_material_file_naming_a_parameter_its_brdf_lacks_says_which(tmp_path):
    """A BRDF table with an extra key failed with "Lambert.__init__() got an unexpected keyword argument 'bogus'"; it
    now names the material, the key and the parameters the BRDF has. A bad value names the material too."""
    def bogus(h, a):
        h["materials"][0]["bogus"] = 1

    bad = _forged_material(tmp_path, "bogus", bogus)
    with pytest.raises(ValueError) as info:
        wb.load(bad)
    assert str(info.value) == (f"{bad} is not a valid material file: material 0: Lambert has no parameter 'bogus'; "
                               "its parameters: albedo")

    def sharp(h, a):
        h["materials"][0] = {"type": "BlinnPhong", "ks": [0.2] * 3, "exponent": 1e18, "kd": [0.0] * 3}

    with pytest.raises(ValueError, match=r"sharp.wbm is not a valid material file: material 0: BlinnPhong.exponent "
                                         r"must be <= 1e\+06, got 1e\+18"):
        wb.load(_forged_material(tmp_path, "sharp", sharp))


def test_a_material_file_with_lobes_outside_the_sg_forms_range_is_refused(tmp_path):
    """A forged .wbm whose lobe sharpness was 1e300 loaded and rendered its sphere black in the SG renderer (float32
    made it inf). A bake's lobes keep to [sg.SHARPNESS_MIN, sg.SHARPNESS_MAX] (its EM clamps them there), so a file's
    must too: one line naming the file and the range found."""
    for value, shown in ((1e300, "1e+300 to 1e+300"), (1e-300, "1e-300 to 1e-300")):
        def edit(h, a, value=value):
            a["sharpness"] = np.full_like(a["sharpness"], value)

        bad = _forged_material(tmp_path, "sharpness", edit)
        with pytest.raises(ValueError) as info:
            wb.load(bad)
        assert str(info.value) == (f"{bad} is not a valid material file: lobe sharpness must lie in [0.001, 1e+06], "
                                   f"the SG forms' range, got {shown}")
