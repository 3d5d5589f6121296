"""The bi-scale editor driven headless (wb.Editor): every control at both ends of its range bakes and
renders finite radiance; geometry changes re-bake and change the frame, BRDF changes do not re-bake;
painting touches the height field only under the brush; save → load gives the same frame; bad values
leave the editor as it was; undo/redo; coarse edits and their refinement."""

import math
import re
import warnings

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import editor as E

warnings.filterwarnings("ignore", category=wb.EnergyWarning)

SIZE = dict(width=48, height=36)
FAST = {"quality.facets_log2": 10, "quality.directions": 4, "quality.lobes": 2}


def _editor(target, backend="warp:cpu"):
    ed = E.Editor(target, backend=backend, **SIZE)
    for name, value in FAST.items():
        ed.set(name, value)
    return ed


@pytest.fixture(scope="module")
def pyramid():
    return _editor("pyramid")


@pytest.mark.parametrize("family", list(E.FAMILIES))
def test_every_control_at_both_ends_bakes_and_renders(family):
    """Every tile and material control at its low end together, then at its high end together (the
    ends' combinations are the hard cases: a tall thin wide tile), each choice in turn: finite, >= 0."""
    ed = _editor(family)
    params = [p for p in ed.parameters() if p.name not in FAST and p.group != "quality"]
    ends = {"lo": {}, "hi": {}}
    for p in params:
        if p.kind in ("real", "int"):
            ends["lo"][p.name], ends["hi"][p.name] = p.lo, p.hi
        elif p.kind == "rgb":
            ends["lo"][p.name], ends["hi"][p.name] = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    original = {p.name: p.value for p in params}
    for end in ("lo", "hi"):
        assert ed.set_many(ends[end]) == "bake"
        assert all(ed.get(name) == value for name, value in ends[end].items())
        frame = ed.frame()
        assert np.isfinite(frame).all() and frame.min() >= 0, end
    for p in params:
        if p.kind == "choice":
            for v in p.choices:
                if v in E.ANISOTROPIC_KINDS:  # (only under the ASG bake: test_anisotropic_materials_need_the_asg_bake)
                    with pytest.raises(ValueError, match="only the ASG bake takes it"):
                        ed.set(p.name, v)
                    continue
                ed.set(p.name, v)
                assert np.isfinite(ed.frame()).all() and ed.frame().min() >= 0, (p.name, v)
    ed.set_many(original)
    assert {p.name: p.value for p in ed.parameters() if p.name in original} == original


def test_quality_ends_and_the_litsphere_renderer(pyramid):
    ed = _editor("grooves")
    for name in FAST:
        p = next(q for q in ed.parameters() if q.name == name)
        for v in (p.lo, min(p.hi, {"quality.facets_log2": 13, "quality.directions": 8, "quality.lobes": 12}[name])):
            ed.set(name, v)
            assert np.isfinite(ed.frame()).all()
    ed.set("quality.method", "litsphere")
    assert ed.timings["redone"] == "render" and np.isfinite(ed.frame()).all() and ed.frame().max() > 0
    # the matrix method's bake, drawn by the lit-sphere renderer whatever quality.method says; the ASG bake by
    # the SG renderer
    for method, kind in (("matrix", wb.MatrixBRDF), ("asg", wb.ASGBRDF)):
        ed.set_many({"quality.method": "sg", "quality.bake": method})
        assert isinstance(ed.effective, kind) and ed.timings["redone"] == "bake"
        assert np.isfinite(ed.frame()).all() and ed.frame().max() > 0


def test_geometry_rebakes_and_materials_do_not(pyramid):
    ed = pyramid
    before, baked = ed.frame(), ed.effective
    assert ed.set("tile.height", 1.2) == "bake"
    assert ed.effective is not baked and ed.timings["redone"] == "bake" and "bake" in ed.timings
    assert np.abs(ed.frame() - before).max() > 1e-3
    baked, amplitudes = ed.effective, ed.effective.amplitudes.copy()
    assert ed.set("material0.exponent", 30.0) == "materials"
    assert ed.effective.lobes is baked.lobes and np.array_equal(ed.effective.amplitudes, amplitudes)
    assert ed.effective.materials[0].exponent == 30.0
    before = ed.frame()
    assert ed.set("light.elevation", 20.0) == "render" and ed.effective is not None
    assert np.abs(ed.frame() - before).max() > 1e-3
    assert ed.set("light.elevation", 20.0) == "none"  # nothing changed: nothing redone


def test_design_edits_shade_only_the_design_and_give_the_whole_frame(backend):
    """A geometry or material edit with the light unchanged shades only the design's pixels over the frame on
    the device; what is shown is the whole frame's tone map (host and device tone maps agree within one
    8-bit step, tests/test_tonemap.py). A light edit shades the whole frame."""
    ed = E.Editor("pyramid", backend=backend, **SIZE)
    for name, value in FAST.items():
        ed.set(name, value)
    for name, value in (("material0.exponent", 40.0), ("tile.height", 0.9), ("light.elevation", 35.0)):
        ed.set(name, value)
        assert ed.timings["shaded"] == ("frame" if name.startswith("light") else "design")
        shown, whole = ed.image8().astype(int), wb.images.tonemap(ed.frame()).astype(int)
        assert np.abs(shown - whole).max() <= 1, name


def test_the_frame_is_the_shown_frame_at_qvga(backend):
    """From 320×240 up the renderer's default shares rays in 2×2 blocks; the editor's window traces each pixel's
    own, and `frame()` (screenshots, image8 at another exposure) must give the frame the window shows: within one
    8-bit step after a light edit, which shades the whole frame."""
    ed = E.Editor("pyramid", backend=backend, width=320, height=240)
    for name, value in FAST.items():
        ed.set(name, value)
    ed.set("light.elevation", 35.0)
    shown, whole = ed.image8().astype(int), wb.images.tonemap(ed.frame()).astype(int)
    assert np.abs(shown - whole).max() <= 1


def test_a_material_kind_brings_its_own_controls(pyramid):
    ed = pyramid
    ed.set("material0.kind", "cooktorrance")
    names = {p.name for p in ed.parameters()}
    assert {"material0.roughness", "material0.f0"} <= names and "material0.exponent" not in names
    assert isinstance(ed.materials[0], wb.CookTorrance)
    ed.set("material0.roughness", 0.5)
    assert ed.effective.materials[0].roughness == 0.5
    ed.set("material0.kind", "blinnphong")


def test_anisotropic_materials_need_the_asg_bake(tmp_path):
    """Anisotropic Ward and Ashikhmin–Shirley (in the tile's face tangents) under the ASG bake: a kind or parameter
    edit is a material edit (no re-bake) that changes the frame; the SG bake refuses them in one line and leaves
    the editor as it was; save → load keeps the kind and the frame."""
    ed = _editor("pyramid")
    assert ed.set("quality.bake", "asg") == "bake"
    assert ed.set("material0.kind", "anisotropicward") == "materials"
    assert isinstance(ed.effective, wb.ASGBRDF) and isinstance(ed.materials[0], wb.AnisotropicWard)
    first = ed.frame().copy()
    assert ed.set("material0.alpha_x", 0.5) == "materials"
    assert np.isfinite(ed.frame()).all() and ed.frame().min() >= 0 and not np.allclose(ed.frame(), first)
    assert ed.set_many({"material0.kind": "ashikhminshirley", "material0.nu": 5.0}) == "materials"
    assert isinstance(ed.materials[0], wb.AshikhminShirley) and ed.materials[0].nu == 5.0
    state, frame = {p.name: p.value for p in ed.parameters()}, ed.frame()
    with pytest.raises(ValueError, match=r"^material0.kind 'ashikhminshirley' is anisotropic: only the ASG bake "
                                         r"takes it, not quality.bake 'sg': set quality.bake to 'asg', or "
                                         r"material0.kind to an isotropic kind$"):
        ed.set("quality.bake", "sg")
    assert {p.name: p.value for p in ed.parameters()} == state and np.array_equal(ed.frame(), frame)
    ed.save(tmp_path / "design.toml")
    again = E.Editor.load(tmp_path / "design.toml", backend="warp:cpu")
    assert again.get("material0.kind") == "ashikhminshirley" and again.get("quality.bake") == "asg"
    assert np.allclose(again.frame(), frame, rtol=1e-3, atol=1e-3 * frame.max())


@pytest.mark.parametrize("bad", [("tile.height", 99.0), ("tile.height", float("nan")), ("tile.height", "tall"),
                                 ("tile.sides", 4.5), ("material0.kd", (2, 0, 0)), ("material0.kind", "glass"),
                                 ("quality.lobes", 0), ("light.environment", "moon"), ("tile.colour", 1.0),
                                 ("tile.height", True)])
def test_bad_values_leave_the_editor_as_it_was(pyramid, bad):
    ed = pyramid
    name, value = bad
    before, state = ed.frame(), {p.name: p.value for p in ed.parameters()}
    with pytest.raises(ValueError) as info:
        ed.set(name, value)
    message = str(info.value)
    assert "\n" not in message and (name in message or name.split(".")[1] in message), message
    assert np.array_equal(ed.frame(), before)
    assert {p.name: p.value for p in ed.parameters()} == state


def test_undo_and_redo(pyramid):
    ed = pyramid
    first = ed.get("tile.sides")
    frame = ed.frame()
    ed.set("tile.sides", 6)
    changed = ed.frame()
    assert ed.undo() and ed.get("tile.sides") == first
    assert np.allclose(ed.frame(), frame, atol=1e-6)
    assert ed.redo() and ed.get("tile.sides") == 6
    assert np.allclose(ed.frame(), changed, atol=1e-6)
    ed.set("tile.sides", first)
    assert not ed.redo()


def test_a_step_of_many_changes_is_one_undo(pyramid):
    ed = pyramid
    before = ed.get("tile.height")
    ed.begin_step()
    for h in (0.3, 0.35, 0.4):
        ed.set("tile.height", h, coarse=True)
    ed.end_step()
    ed.refine()
    assert ed.undo() and ed.get("tile.height") == before
    assert ed.redo() and ed.get("tile.height") == 0.4
    ed.set("tile.height", before)


def test_coarse_edits_then_refine(pyramid):
    ed = pyramid
    ed.set("quality.facets_log2", 13)
    ed.set("tile.height", 0.7, coarse=True)
    assert ed.effective.info["facets"] <= 1 << E.COARSE["facets_log2"]
    assert ed.refine() and not ed.refine()
    assert ed.effective.info["facets"] == 1 << 13
    ed.set("quality.facets_log2", FAST["quality.facets_log2"])


def test_painting_changes_the_field_only_under_the_brush():
    ed = _editor("heightfield")
    h0 = ed.heights
    frame = ed.frame()
    assert ed.paint(0.25, 0.75, 0.1, 0.5) == "bake"
    d = ed.heights - h0
    n = len(h0)
    y, x = np.mgrid[0:n, 0:n] / n
    dist = np.hypot(np.minimum(abs(x - 0.25), 1 - abs(x - 0.25)), np.minimum(abs(y - 0.75), 1 - abs(y - 0.75)))
    assert np.all(d[dist >= 0.1] == 0) and d[dist < 0.05].min() > 0
    assert abs(d.max() - 0.5) < 0.05 and np.abs(ed.frame() - frame).max() > 0
    ed.paint(0.9, 0.05, 0.2, -0.3)  # lowers, wrapping across the tile's corner
    assert (ed.heights - h0)[0, 0] < 0
    before = ed.heights
    ed.smooth(0.25, 0.75, 0.15, 1.0)
    s = ed.heights - before
    assert np.all(s[dist >= 0.15] == 0) and np.abs(s).max() > 0
    assert ed.undo() and np.array_equal(ed.heights, before)
    with pytest.raises(ValueError, match="radius"):
        ed.paint(0.5, 0.5, 0.0, 0.1)
    with pytest.raises(ValueError, match="only a height field"):
        _editor("pyramid").paint(0.5, 0.5, 0.1, 0.1)


@pytest.mark.parametrize("family", ["pyramid", "rods", "heightfield"])
def test_save_then_load_gives_the_same_frame(tmp_path, family):
    """A saved design opened again is the same design: its controls (a painted field's amplitude and smoothing
    too, kept in the file's editor line, the field before smoothing beside it) and its frame; and the file is a
    scene `warp-biscale render` reads without a warning (a BRDF for each of the tile's material ids alone), whose
    height field is the one drawn (the smoothed one)."""
    ed = _editor(family)
    if family == "heightfield":
        ed.paint(0.5, 0.5, 0.2, 0.4)
        ed.set_many({"tile.amplitude": 0.3, "tile.smoothing": 2.0})
    else:
        ed.set("tile.color", (0.3, 0.9, 0.2))
    ed.set("material0.kind", "ward")
    ed.set("light.azimuth", 120.0)
    path = tmp_path / "design.toml"
    ed.save(path)
    again = E.Editor.load(path, backend="warp:cpu")
    assert again.family == family and again.get("material0.kind") == "ward"
    assert math.isclose(again.get("light.azimuth"), 120.0, abs_tol=1e-6)
    if family == "heightfield":
        assert (again.get("tile.amplitude"), again.get("tile.smoothing")) == (0.3, 2.0)
        assert again.set("tile.amplitude", 0.3) == "none"  # (in the control's range, and unchanged)
        # 16-bit heights: within a step of 1/65535 of the painted field's range
        np.testing.assert_allclose(again._state["heights"], ed._state["heights"], rtol=0,
                                   atol=np.ptp(ed._state["heights"]) / 65535)
    assert np.allclose(again.frame(), ed.frame(), rtol=1e-3, atol=1e-3 * ed.frame().max())
    # the file is a scene `warp-biscale render` reads: the same design baked by the scene loader
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = wb.load_scene(path)
    assert isinstance(scene.scene.materials[0], wb.EffectiveBRDF)
    assert len(scene.scene.materials[0].materials) == ed.tile.n_materials
    if family == "heightfield":
        drawn = E._blur(ed._state["heights"], 2.0)
        np.testing.assert_allclose(np.ptp(scene.tiles["design"].vertices[:, 2]), 0.3 * np.ptp(drawn), rtol=1e-6)
    # and it renders what the editor showed (with the editor's preview settings): the same tile, bit for bit (a
    # height field's 16-bit image is what the editor baked too), so the same lobes and the same pixels
    np.testing.assert_array_equal(scene.tiles["design"].vertices, ed.tile.vertices)
    shown = wb.render(scene.scene, backend="warp:cpu", aa=1, shadow_samples=1, block_rays=False).image
    np.testing.assert_array_equal(shown, ed.frame())


def test_loading_a_bad_design_names_the_file_and_the_key(tmp_path):
    """Editor.load checks a design as its controls check values: a misspelt tile key, a value outside its control's
    range, a width that is not an integer and a height field's missing image are one-line errors naming the file
    (render refuses the same files), not a default silently put in their place."""
    path = tmp_path / "design.toml"
    _editor("pyramid").save(path)
    text = path.read_text()
    assert "height = 0.5" in text and "width = 48" in text
    for edit, words in ((("height = 0.5", "hieght = 0.5"), "the pyramid tile has no control 'hieght'"),
                        (("height = 0.5", "height = 9.0"), "tile.height must lie in"),
                        (("width = 48", 'width = "wide"'), "[render] width must be an integer, got 'wide'"),
                        (("exponent=", "exponnt="), "brdf 0: BlinnPhong has no parameter 'exponnt'")):
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace(*edit, 1))
        with pytest.raises(ValueError, match=f"^design {re.escape(str(bad))}: .*{re.escape(words)}") as err:
            E.Editor.load(bad, backend="warp:cpu")
        assert "\n" not in str(err.value)
    field = _editor("heightfield")
    field.set("tile.smoothing", 1.0)
    field.save(tmp_path / "field.toml")
    text = (tmp_path / "field.toml").read_text()
    (tmp_path / "bad.toml").write_text(text.replace('"smoothing": 1.0', '"smoothing": "x"'))
    with pytest.raises(ValueError, match=r"bad.toml: its # editor: line is malformed"):
        E.Editor.load(tmp_path / "bad.toml", backend="warp:cpu")
    # a hand-edited scale: the scene's own field is what is edited (the editor line no longer describes it)
    scale = re.search(r"scale = ([0-9.e-]+)", text).group(1)
    (tmp_path / "edited.toml").write_text(text.replace(f"scale = {scale}", "scale = 0.1"))
    edited = E.Editor.load(tmp_path / "edited.toml", backend="warp:cpu")
    assert (edited.get("tile.amplitude"), edited.get("tile.smoothing")) == (0.1, 0.0)
    for name, what in (("field_painted.png", "painted height image"), ("field_heights.png", "height image")):
        (tmp_path / name).unlink()
        with pytest.raises(ValueError, match=f"field.toml: its {what} .*{name} is missing"):
            E.Editor.load(tmp_path / "field.toml", backend="warp:cpu")


def test_screenshot_and_bad_targets(tmp_path, pyramid):
    pyramid.screenshot(tmp_path / "frame.png")
    img = wb.images.read_image(tmp_path / "frame.png")
    assert img.shape[:2] == (SIZE["height"], SIZE["width"]) and img.max() > 0
    assert pyramid.image8().dtype == np.uint8
    with pytest.raises(ValueError, match="neither a tile family"):
        E.Editor("no-such-tile", backend="warp:cpu", **SIZE)
    with pytest.raises(ValueError, match="width"):
        E.Editor("pyramid", backend="warp:cpu", width=0, height=10)
    (tmp_path / "plain.toml").write_text("[render]\nwidth = 64\n")  # a scene file is opened by Editor.load
    with pytest.raises(ValueError, match=r"^Editor target .*plain.toml is a scene file: open a saved design with "
                                         r"Editor.load\('.*plain.toml'\)$"):
        E.Editor(str(tmp_path / "plain.toml"), backend="warp:cpu", **SIZE)
    with pytest.raises(ValueError, match="no parameter"):
        pyramid.set("tile.nope", 1.0)
