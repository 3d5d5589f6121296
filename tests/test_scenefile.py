"""TOML scene files: the examples load, every kind of mistake is named with its key and line, relative
paths resolve against the file, and a bake material is baked at load time."""

import os
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import scenefile, tomlschema
from warp_biscale.scenefile import SceneError, load_scene, loads_scene

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

BASE = """\
[[object]]
mesh = "sphere"
subdivisions = 1
material = "m"

[material.m]
type = "lambert"
albedo = 0.5
"""


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def line_of(text, snippet, nth=1):
    """1-based line of the nth line containing `snippet`."""
    hits = [i for i, line in enumerate(textwrap.dedent(text).splitlines(), 1) if snippet in line]
    return hits[nth - 1]


def expect_error(tmp_path, text, snippet, *words, nth=1):
    p = write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(p, backend="warp:cpu")
    msg = str(info.value)
    line = line_of(text, snippet, nth)
    assert msg.startswith(f"scene.toml:{line}:"), msg
    assert info.value.line == line
    for w in words:
        assert w in msg, msg
    return info.value


# ------------------------------------------------------------------------------------------------ examples


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_each_example_scene_loads(name, monkeypatch):
    # a bake with the example's own settings is a second or two; shrink it for the suite
    real_bake = wb.bake

    def quick_bake(tile, mats, **kw):
        kw.update(facets=512, directions=4, lobes=2, normal_res=16)
        return real_bake(tile, mats, **kw)

    monkeypatch.setattr(sys.modules["warp_biscale.bake"], "bake", quick_bake)
    sf = load_scene(EXAMPLES / name, backend="warp:cpu")
    assert isinstance(sf.scene, wb.Scene)
    assert sf.material_names and len(sf.scene.materials) == len(sf.material_names)
    assert sf.scene.camera.width == sf.width and sf.scene.camera.height == sf.height
    assert int(sf.scene.mesh.face_material.max()) == len(sf.material_names) - 1
    for name_, mat in zip(sf.material_names, sf.scene.materials):
        assert sf.materials[name_] is mat
    for name_ in sf.tiles:
        assert isinstance(sf.tiles[name_], wb.SmallScale)
        assert isinstance(sf.materials[name_], wb.EffectiveBRDF)


def test_examples_are_present():
    names = {p.name for p in EXAMPLES.glob("*.toml")}
    assert {"glossy.toml", "bi-scale.toml"} <= names


def test_demo_scene_text_is_a_valid_scene_file():
    from warp_biscale import demo

    sf = loads_scene(demo.scene_text(size=16, facets=512, directions=4, lobes=2), path="demo.toml",
                     backend="warp:cpu")
    assert sf.width == 16 and "demo_tile" in sf.tiles


# ------------------------------------------------------------------------------------------------ contents


def test_full_scene_builds_every_part(tmp_path):
    text = """\
    [render]
    width = 24
    height = 16
    method = "mc"
    samples = 8
    seed = 3
    exposure = -1.5
    env_lobes = 5
    ssdf_resolution = 8
    ssdf_terms = 4
    backend = "warp:cpu"

    [camera]
    eye = [0.0, 1.0, 5.0]
    target = [0.0, 0.5, 0.0]
    up = [0.0, 1.0, 0.0]
    fov = 30

    [environment]
    type = "constant"
    radiance = [0.2, 0.3, 0.4]
    height = 8
    width = 16
    scale = 2.0

    [[light]]
    type = "point"
    position = [1, 3, 2]
    intensity = [5, 4, 3]
    radius = 0.2

    [[light]]
    type = "directional"
    direction = [0, 1, 0]
    irradiance = 2.0
    angular_radius = 1.5

    [[object]]
    mesh = "torus"
    major = 1.0
    minor = 0.25
    segments = [12, 8]
    rotate = [90, 0, 0]
    translate = [0, 1, 0]
    material = "b"

    [[object]]
    mesh = "plane"
    size = 4
    divisions = 2
    material = "a"

    [[object]]
    mesh = "sphere"
    radius = 0.3
    subdivisions = 1
    scale = 2.0
    material = "b"

    [material.a]
    type = "ward"
    ks = 0.3
    alpha = 0.25
    kd = [0.1, 0.2, 0.3]

    [material.b]
    type = "cooktorrance"
    roughness = 0.3
    f0 = 0.5

    [material.unused]
    type = "blinnphong"
    exponent = 10
    """
    sf = load_scene(write(tmp_path, text))
    s = sf.scene
    assert (sf.width, sf.height, sf.method, sf.samples, sf.seed, sf.exposure, sf.backend) == \
        (24, 16, "mc", 8, 3, -1.5, "warp:cpu")
    assert sf.render_options() == {"samples": 8, "seed": 3}
    assert sf.render_options("sg") == {}
    assert (s.env_lobes, s.ssdf_resolution, s.ssdf_terms) == (5, 8, 4)
    assert s.camera.fov == 30 and np.allclose(s.camera.eye, [0, 1, 5])
    np.testing.assert_allclose(s.environment.radiance[0, 0], [0.4, 0.6, 0.8], rtol=1e-6)
    assert isinstance(s.lights[0], wb.PointLight) and isinstance(s.lights[1], wb.DirectionalLight)
    np.testing.assert_allclose(s.lights[0].intensity, [5, 4, 3])
    # materials in order of first use; the unused one is built but not in the scene
    assert sf.material_names == ["b", "a"]
    assert isinstance(s.materials[0], wb.CookTorrance) and isinstance(s.materials[1], wb.Ward)
    assert isinstance(sf.materials["unused"], wb.BlinnPhong)
    torus_faces = 12 * 8 * 2
    fm = s.mesh.face_material
    assert (fm[:torus_faces] == 0).all() and (fm[torus_faces:torus_faces + 8] == 1).all()
    assert (fm[torus_faces + 8:] == 0).all()
    # the torus rotated 90° about x: its axis (+y) now points along +z, centre at y = 1
    torus = s.mesh.vertices[:12 * 8]
    np.testing.assert_allclose(torus.mean(0), [0, 1, 0], atol=1e-9)
    assert np.ptp(torus[:, 2]) == pytest.approx(0.5, abs=1e-9)
    # the sphere scaled 2x: radius 0.6; normals stay unit
    sphere = s.mesh.vertices[-42:]
    np.testing.assert_allclose(np.linalg.norm(sphere, axis=1), 0.6, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(s.mesh.normals, axis=1), 1.0, rtol=1e-9)


def test_defaults_and_camera_framing(tmp_path):
    sf = load_scene(write(tmp_path, BASE))
    cam = sf.scene.camera
    assert sf.method == "sg" and sf.exposure == 0.0 and sf.backend == "auto" and sf.scene.environment is None
    np.testing.assert_allclose(cam.target, 0.0, atol=1e-9)  # the bounds' centre
    # the unit sphere is in view: its angular radius from the eye is less than half the fov
    dist = np.linalg.norm(cam.eye - cam.target)
    assert np.degrees(np.arcsin(1.0 / dist)) < cam.fov / 2


@pytest.mark.parametrize("env, check", [
    ('type = "sky"\nsun_direction = [0, 1, 0]\nheight = 8\nwidth = 16\nsupersample = 1',
     lambda e: e.radiance.shape == (8, 16, 3) and e.radiance[0].mean() > e.radiance[-1].mean()),
    ('type = "studio"\nheight = 8\nwidth = 16\nsupersample = 1\n'
     'lights = [{direction = [0, 1, 0], half_width = 30, half_height = 30, radiance = 7.0}]',
     lambda e: e.radiance.max() == pytest.approx(7.02, rel=1e-3)),
    ('type = "sgs"\naxes = [[0, 1, 0]]\nsharpness = [10.0]\namplitudes = [2.0]\nheight = 8\nwidth = 16',
     lambda e: e.radiance.max() > 1.5),
    ('type = "none"', lambda e: e is None),
])
def test_environment_types(tmp_path, env, check):
    sf = load_scene(write(tmp_path, BASE + "\n[environment]\n" + env + "\n"))
    assert check(sf.scene.environment)


def test_relative_paths_resolve_against_the_scene_file(tmp_path, monkeypatch):
    import trimesh

    assets = tmp_path / "scenes" / "assets"
    assets.mkdir(parents=True)
    trimesh.creation.box(extents=(1, 1, 1)).export(assets / "box.obj")
    wb.Environment.constant(0.7, height=4, width=8).save(assets / "env.exr")
    tile = wb.geometry.grooves(depth=0.3)
    mat = wb.bake(tile, [wb.BlinnPhong(1.0, 32)], facets=256, directions=4, lobes=2, normal_res=8,
                  backend="warp:cpu")
    mat.save(assets / "grooves.wbm")
    text = """\
    [environment]
    type = "file"
    path = "assets/env.exr"

    [[object]]
    mesh = "assets/box.obj"
    material = "g"

    [material.g]
    type = "file"
    path = "assets/grooves.wbm"
    brdf = ["ward:alpha=0.3"]
    """
    p = write(tmp_path / "scenes", text)
    monkeypatch.chdir(tmp_path)  # not the scene's folder
    sf = load_scene(os.path.relpath(p, tmp_path))
    assert len(sf.scene.mesh.faces) == 12
    np.testing.assert_allclose(sf.scene.environment.radiance, 0.7)
    g = sf.scene.materials[0]
    assert isinstance(g, wb.EffectiveBRDF) and isinstance(g.materials[0], wb.Ward)
    assert g.lobes.axes.shape == mat.lobes.axes.shape


def test_bake_material_is_baked_at_load_with_its_tile(tmp_path):
    text = BASE.replace('material = "m"', 'material = "b"') + (
        '\n[material.b]\ntype = "bake"\ntile = "pyramid"\n'
        'tile_params = { height = 0.3, color = [1.0, 0.5, 0.25], base_material = 1 }\n'
        'brdf = ["blinnphong:exponent=64,ks=0.8", "lambert:albedo=0.4"]\n'
        'lobes = 2\ndirections = 4\nfacets = 512\nnormal_res = 16\nseed = 2\n')
    sf = load_scene(write(tmp_path, text), backend="warp:cpu")
    mat = sf.scene.materials[0]
    assert sf.material_names == ["b"]
    assert isinstance(mat, wb.EffectiveBRDF) and mat.directions == 4 and len(mat.materials) == 2
    assert isinstance(mat.materials[1], wb.Lambert)
    assert mat.info["facets"] == 512
    tile = sf.tiles["b"]
    assert tile.n_materials == 2 and np.allclose(tile.colors.max(0), [1.0, 0.5, 0.25])
    assert sf.timings["bake b"] > 0
    assert sf.materials["m"] is not None  # the unused lambert is still built


@pytest.mark.parametrize("tile, params", [('"heightfield"', ""), ('"heightfield"', "tile_params = { seed = 3 }\n"),
                                          ('"bumps.png"', ""),
                                          ('"heightfield"', 'tile_params = { image = "bumps.png" }\n')])
def test_bake_material_takes_the_tile_names_the_command_line_takes(tmp_path, tile, params):
    """A bake material's tile is what `warp-biscale bake` takes: "heightfield" alone the default relief
    (geometry.relief, tile_params its arguments), a greyscale image file as a height field, and the editor's
    "heightfield" with tile_params.image as before."""
    from PIL import Image

    Image.fromarray((np.random.default_rng(0).random((8, 8)) * 255).astype(np.uint8)).save(tmp_path / "bumps.png")
    text = BASE.replace('material = "m"', 'material = "b"') + (
        f'\n[material.b]\ntype = "bake"\ntile = {tile}\n{params}brdf = ["lambert:albedo=0.5"]\n'
        'lobes = 2\ndirections = 4\nfacets = 512\n')
    sf = load_scene(write(tmp_path, text), backend="warp:cpu")
    want = (wb.geometry.relief(**({"seed": 3} if "seed" in params else {})) if "bumps" not in tile + params
            else wb.geometry.heightfield_from_image(tmp_path / "bumps.png"))
    np.testing.assert_array_equal(sf.tiles["b"].vertices, want.vertices)


def test_bake_material_takes_a_merl_file(tmp_path):
    """A bake material's brdf entry may be a MERL table file, relative to the scene file; a missing one is an
    error naming the key."""
    wb.MeasuredBRDF.from_brdf(wb.CookTorrance(0.6, 0.2, kd=0.2)).save(tmp_path / "ct.binary")
    text = BASE.replace('material = "m"', 'material = "b"') + (
        '\n[material.b]\ntype = "bake"\ntile = "pyramid"\nbrdf = ["ct.binary"]\n'
        'lobes = 2\ndirections = 4\nfacets = 512\n')
    sf = load_scene(write(tmp_path, text), backend="warp:cpu")
    assert isinstance(sf.scene.materials[0].materials[0], wb.MeasuredBRDF)
    with pytest.raises(SceneError, match=r"brdf 'gone.binary': no such MERL BRDF file"):
        load_scene(write(tmp_path, text.replace("ct.binary", "gone.binary")), backend="warp:cpu")


def test_unused_bake_material_is_checked_not_baked(tmp_path, monkeypatch):
    def no_bake(*a, **k):
        raise AssertionError("baked a material nothing uses")

    monkeypatch.setattr(sys.modules["warp_biscale.bake"], "bake", no_bake)
    text = BASE + '\n[material.spare]\ntype = "bake"\ntile = "rods"\nfacets = 256\n'
    sf = load_scene(write(tmp_path, text))
    assert sf.materials["spare"] is None and "spare" in sf.tiles


def test_loads_scene_from_text_names_it_in_errors():
    with pytest.raises(SceneError, match=r"^inline\.toml:2: \[camera\] unknown key 'fvo'"):
        loads_scene("[camera]\nfvo = 3\n", path="inline.toml")


# ------------------------------------------------------------------------------------------------ errors


def test_toml_syntax_error_has_line_and_column(tmp_path):
    text = BASE + "\n[camera]\nfov 30\neye = [0, 1, 2]\n"
    with pytest.raises(SceneError, match=rf"^scene\.toml:{line_of(text, 'fov 30')}:\d+: invalid TOML: "):
        load_scene(write(tmp_path, text))
    text = BASE + "\n[camera]\neye = [0, 1, \n"  # tomllib says "at end of document": the last line
    with pytest.raises(SceneError, match=rf"^scene\.toml:{len(text.splitlines())}: invalid TOML: .*end of the file"):
        load_scene(write(tmp_path, text))
    text = BASE + '\n[material.m]\ntype = "ward"\n'  # a table defined twice
    with pytest.raises(SceneError, match=r"^scene\.toml:\d+:\d+: invalid TOML"):
        load_scene(write(tmp_path, text))


@pytest.mark.parametrize("extra, snippet, words", [
    # unknown keys and tables (typos)
    ('[camera]\nfvo = 30\n', "fvo", ["[camera]", "unknown key 'fvo'", "fov"]),
    ('[rendr]\nwidth = 3\n', "[rendr]", ["unknown table or key 'rendr'"]),
    ('[render]\nsampels = 3\n', "sampels", ["[render]", "unknown key 'sampels'"]),
    ('[[light]]\ntype = "point"\nposition = [0, 3, 0]\n[[light]]\ntype = "point"\nintensty = 3\n',
     "intensty", ["[[light]] #2", "unknown key 'intensty' for a point light"]),
    ('[material.g]\ntype = "blinnphong"\nexponant = 30\n', "exponant", ["[material.g]", "exponant"]),
    ('[material.g]\ntype = "bake"\ntile = "pyramid"\ntile_params = { hieght = 0.2 }\n', "hieght",
     ["[material.g]", "tile 'pyramid' has no parameter 'hieght'; its parameters: height, base_fraction"]),
    ('[material.g]\ntype = "bake"\ntile = "heightfield"\ntile_params = { scale = 2.0 }\n', "scale",
     ["tile 'heightfield' has no parameter 'scale' (a painted height field takes it, given tile_params.image); "
      "its parameters: amplitude, seed, material, color"]),
    # wrong types
    ('[material.g]\ntype = "blinnphong"\nexponent = "high"\n', "exponent", ["exponent must be a number", "'high'"]),
    ('[camera]\neye = [0, 1]\n', "eye =", ["[camera]", "eye must be three numbers"]),
    ('[render]\nwidth = 1.5\n', "width = 1.5", ["width must be an integer"]),
    ('[material.g]\ntype = "bake"\ntile = "pyramid"\nlobes = "many"\n', "lobes", ["lobes must be an integer or"]),
    # bad values (checked by the constructors, located by the key they name)
    ('[material.g]\ntype = "blinnphong"\nks = 1\nexponent = -3\n', "exponent = -3",
     ["[material.g]", "exponent must be a finite number > 0", "-3"]),
    ('[material.g]\ntype = "cooktorrance"\nf0 = 2\n', "f0 = 2", ["f0 must lie in [0, 1]"]),
    ('[camera]\nfov = 200\n', "fov = 200", ["fov must lie in (0, 180)"]),
    ('[render]\nmethod = "path"\n', "method", ["method must be one of sg, mc"]),
    ('[render]\nbackend = "metal"\n', "backend", ["unknown backend"]),
    ('[render]\naa = 0\n', "aa = 0", ["[render]", "aa must be"]),
    ('[render]\nshadow_samples = 0\n', "shadow_samples", ["shadow samples must be"]),
    ('[render]\nocclusion_samples = 99\n', "occlusion_samples", ["occlusion samples must be"]),
    ('[render]\nblock_rays = 3\n', "block_rays", ["block_rays must be true, false, \"auto\" or a block side"]),
    ('[render]\nblock_rays = "yes"\n', "block_rays", ["block_rays must be true, false"]),
    ('[environment]\ntype = "sky"\nsun_edge = 3\n', "sun_edge", ["sun_edge must be in [0, 1]"]),
    ('[[light]]\ntype = "point"\nradius = -1\n', "radius", ["[[light]] #1", "radius must be > 0"]),
    ('[material.g]\ntype = "bake"\ntile = "pyramid"\nbrdf = ["glass"]\n', "brdf", ["unknown BRDF 'glass'"]),
    ('[material.g]\ntype = "bake"\ntile = "pyramid"\nfacets = 0\n', "facets", ["facets"]),
    ('[material.g]\ntype = "bake"\ntile = "vgroove"\ntile_params = { profile = "u" }\n', "tile_params",
     ["tile 'vgroove' is grooves with profile = 'v', got profile = 'u'"]),
    # unknown type names
    ('[material.g]\ntype = "glass"\n', 'type = "glass"', ["unknown material type 'glass'", "'blinnphong'"]),
    ('[environment]\ntype = "hdri"\n', 'type = "hdri"', ["unknown environment type 'hdri'"]),
    # missing required keys
    ('[material.g]\ntype = "bake"\n', "[material.g]", ["needs the key 'tile'"]),
    ('[material.g]\nexponent = 3\n', "[material.g]", ["needs a type"]),
    ('[[light]]\nposition = [0, 1, 0]\n', "[[light]]", ["[[light]] #1 needs a type"]),
    # missing files
    ('[environment]\ntype = "file"\npath = "nowhere.hdr"\n', "nowhere", ["no such environment file: nowhere.hdr"]),
    ('[material.g]\ntype = "file"\npath = "gone.wbm"\n', "gone.wbm", ["no such material file"]),
    ('[material.g]\ntype = "bake"\ntile = "tiles/x.obj"\n', "tiles/x.obj",
     ["neither a built-in tile", "pyramid"]),
])
def test_errors_name_key_and_line(tmp_path, extra, snippet, words):
    base = BASE.replace('material = "m"', 'material = "g"') if "[material.g]" in extra else BASE
    text = base + "\n" + extra
    expect_error(tmp_path, text, snippet, *words)


def test_object_errors(tmp_path):
    obj = '[[object]]\nmesh = "sphere"\nmaterial = "m"\n'
    # an undefined material, in the second object
    expect_error(tmp_path, BASE + "\n" + obj.replace('"m"', '"gold"'), 'material = "gold"',
                 "[[object]] #2", "material 'gold' is not defined", "'m'")
    # a parameter of another mesh type
    expect_error(tmp_path, BASE + "\n" + obj + "major = 2\n", "major = 2", "[[object]] #2", "unknown key 'major'",
                 "radius")
    # a bad constructor value
    expect_error(tmp_path, BASE + "\n" + obj + "subdivisions = 2.5\n", "subdivisions = 2.5",
                 "subdivisions must be an integer")
    expect_error(tmp_path, BASE + "\n" + obj + "scale = -1\n", "scale = -1", "scale must be > 0")
    # no mesh, no material, a missing mesh file
    expect_error(tmp_path, BASE + '\n[[object]]\nmaterial = "m"\n', "[[object]]", "[[object]] #2 needs the key 'mesh'",
                 nth=2)
    expect_error(tmp_path, BASE + '\n[[object]]\nmesh = "sphere"\n', "[[object]]", "needs the key 'material'", nth=2)
    expect_error(tmp_path, BASE + '\n[[object]]\nmesh = "teapot.obj"\nmaterial = "m"\n', "teapot",
                 "neither a built-in", "teapot.obj")
    # a typo'd built-in keeping the keys of the shape meant: the mesh is the error, not its keys
    expect_error(tmp_path, BASE + '\n[[object]]\nmesh = "spehre"\nradius = 0.5\nsubdivisions = 2\nmaterial = "m"\n',
                 'mesh = "spehre"', "mesh 'spehre' is neither a built-in (sphere, torus, plane)")
    # placed past the renderers' coordinates: the object named, with what placed it (it came without file or line)
    expect_error(tmp_path, BASE + '\n[[object]]\nmesh = "sphere"\nmaterial = "m"\nscale = 1e30\n', "[[object]]",
                 "[[object]] #2 placed by its scale: Mesh.vertices reach 1e+30", nth=2)


def test_a_scene_without_objects_is_refused(tmp_path):
    with pytest.raises(SceneError, match="no \\[\\[object\\]\\]"):
        load_scene(write(tmp_path, '[material.m]\ntype = "lambert"\n'))


def test_tables_written_as_single_tables_are_refused(tmp_path):
    expect_error(tmp_path, BASE + '\n[light]\ntype = "point"\n', "[light]", "must be written [[light]]")


def test_missing_and_directory_paths(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such scene file"):
        load_scene(tmp_path / "nope.toml")
    with pytest.raises(SceneError, match="is a directory"):
        load_scene(tmp_path)


def test_locator_paths():
    text = textwrap.dedent("""\
        top = 1
        [a]
        x = 1
        "quoted key" = 2
        [[arr]]
        y = 3
        [[arr]]
        y = 4
        [arr.sub]
        z = 5
        [b.'c d']
        inline = { p = 1, q = { r = 2 } }
        s = \"\"\"
        not_a_key = 3
        \"\"\"
        after = 6
        """)
    loc = tomlschema._Locator(text)
    assert loc.line(("top",)) == 1
    assert loc.line(("a", "x")) == 3 and loc.line(("a", "quoted key")) == 4
    assert loc.line(("arr", 0, "y")) == 6 and loc.line(("arr", 1, "y")) == 8
    assert loc.line(("arr", 1, "sub", "z")) == 10
    assert loc.line(("b", "c d", "inline", "q")) == 12
    assert loc.line(("b", "c d", "not_a_key")) == 11  # inside a string: falls back to the table
    assert loc.line(("b", "c d", "after")) == 16
    assert loc.line(("a", "missing")) == 2 and loc.line(("nothing",)) is None


def test_bi_scale_example_is_the_demo_scene():
    from warp_biscale import demo

    tomllib = scenefile.tomllib  # tomli on Python 3.10

    with open(EXAMPLES / "bi-scale.toml", "rb") as f:
        example = tomllib.load(f)
    assert example == tomllib.loads(demo.scene_text(512))


def test_anisotropic_material_types():
    """The anisotropic BRDFs as large-scale materials (in the mesh's tangent frame); a wrong key is named."""
    text = BASE.replace('type = "lambert"\nalbedo = 0.5', 'type = "anisotropicward"\nks = 0.6\nalpha_x = 0.08\n'
                        'alpha_y = 0.4\nkd = 0.2')
    mat = loads_scene(text).scene.materials[0]
    assert mat == wb.AnisotropicWard(0.6, 0.08, 0.4, kd=0.2)
    text = BASE.replace('type = "lambert"\nalbedo = 0.5', 'type = "ashikhminshirley"\nrs = 0.5\nnu = 20\nnv = 400')
    assert loads_scene(text).scene.materials[0] == wb.AshikhminShirley(rs=0.5, nu=20, nv=400)
    with pytest.raises(SceneError, match="alpha"):
        loads_scene(BASE.replace('type = "lambert"\nalbedo = 0.5', 'type = "anisotropicward"\nalpha = 0.1'))


def test_render_table_sets_the_rays_of_the_sg_renderer(tmp_path, capsys):
    """[render] aa, shadow_samples, occlusion_samples and block_rays: render options of the SG renderer (aa and
    shadow_samples of the lit-sphere shader too), not of the Monte Carlo reference; SceneFile.render gives them, and
    the CLI takes each from the file unless its flag is given (aa: the file's, else the CLI's 4): the file's
    [render] aa = 1 renders as --aa 1, bit for bit."""
    from warp_biscale import cli

    text = BASE + '\n[render]\nwidth = 24\nheight = 16\naa = 1\nshadow_samples = 4\nocclusion_samples = 8\n' \
                  'block_rays = false\n\n[[light]]\ntype = "point"\nposition = [0, 3, 0]\nradius = 0.3\n'
    path = write(tmp_path, text)
    sf = load_scene(path, backend="warp:cpu")
    rays = {"aa": 1, "shadow_samples": 4, "occlusion_samples": 8, "block_rays": False}
    assert sf.render_options() == rays and sf.render_options("sg") == rays
    assert sf.render_options("litsphere") == {"aa": 1, "shadow_samples": 4}
    assert sf.render_options("mc") == {}
    got = sf.render(backend="warp:cpu")
    assert got.info["aa"] == 1 and got.info["shadow_samples"] == 4 and got.info["block_rays"] == 1
    assert got.info["occlusion_samples"] in (0, 8)  # (0 where nothing occludes: the rays would all escape)
    images = {}
    for flags in ([], ["--aa", "1"], ["--aa", "2"]):
        out = tmp_path / f"img{len(images)}.exr"
        assert cli.main(["render", str(path), "-o", str(out), "-q", "--backend", "warp:cpu", *flags]) == 0
        images[tuple(flags)] = wb.images.read_image(str(out))
    assert np.array_equal(images[()], images[("--aa", "1")])
    assert np.abs(images[()] - images[("--aa", "2")]).max() > 0  # the flag wins over the file
    plain = load_scene(write(tmp_path, BASE, "plain.toml"), backend="warp:cpu")
    assert plain.render_options("sg") == {} and plain.aa is None


def test_a_byte_order_mark_is_read_past(tmp_path):
    """Some Windows editors start a UTF-8 file with a byte-order mark, which TOML's parser refused as
    'Invalid statement' at 1:1; an error further down still gets its right line."""
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BASE.encode("utf-8"))
    assert load_scene(str(path)).scene.materials[0].albedo[0] == 0.5
    path.write_bytes(b"\xef\xbb\xbf" + (BASE + "\n[camera]\nfvo = 30\n").encode("utf-8"))
    with pytest.raises(SceneError, match=rf"^bom.toml:{BASE.count(chr(10)) + 3}: \[camera\] unknown key 'fvo'"):
        load_scene(str(path))
