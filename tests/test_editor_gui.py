"""The editor's window (`warp_biscale.editor_gui`), offscreen (EGL): the real window, drawn and driven through
the callbacks its sliders, mouse and keys call; its screenshots have content and change with the design."""

import os

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # before VTK loads
pv = pytest.importorskip("pyvista")

from warp_biscale import cli  # noqa: E402
from warp_biscale.editor import Editor, Parameter  # noqa: E402
from warp_biscale.editor_gui import Control, controls_of, from_slider, open_editor, to_slider  # noqa: E402

pv.OFF_SCREEN = True
FRAME = {"width": 96, "height": 72}


@pytest.fixture(scope="module", autouse=True)
def offscreen_gl():
    """Skip (with the reason) where VTK cannot draw offscreen."""
    try:
        p = pv.Plotter(off_screen=True, window_size=(32, 32))
        p.add_mesh(pv.Sphere())
        img = p.screenshot(return_img=True)
        p.close()
    except Exception as exc:  # what VTK raises for a missing EGL / OpenGL varies
        pytest.skip(f"no offscreen OpenGL (EGL) here: {exc}")
    if img is None or img.std() == 0:
        pytest.skip("offscreen OpenGL draws nothing here")


def quick(target):
    """An editor whose full bake is small (the quality controls): a released slider re-bakes in a fraction of
    a second on a 2-core CPU, where the default 2^16 facets take seconds."""
    ed = Editor(target, **FRAME)
    for name, value in (("quality.facets_log2", 12), ("quality.directions", 6), ("quality.lobes", 4)):
        ed.set(name, value)
    return ed


# ------------------------------------------------------------------------------------------------ driving


def drag(w, key, *positions):
    """What a mouse drag on a slider does: start, one interaction a position, end (the release)."""
    widget = w.sliders[key]
    widget.InvokeEvent("StartInteractionEvent")
    for p in positions:
        widget.GetRepresentation().SetValue(p)
        widget.InvokeEvent("InteractionEvent")
    widget.InvokeEvent("EndInteractionEvent")


def press_key(w, sym, ctrl=False, shift=False):
    it = w.plotter.iren.interactor
    it.SetKeyEventInformation(int(ctrl), int(shift), sym if len(sym) == 1 else "\0", 0, sym)
    it.InvokeEvent("KeyPressEvent")
    it.InvokeEvent("CharEvent")


def mouse(w, *points):
    """Left button down at the first display point, moved through the others, up at the last."""
    it = w.plotter.iren.interactor
    it.SetEventInformation(*points[0], 0, 0)
    it.InvokeEvent("LeftButtonPressEvent")
    for p in points[1:]:
        it.SetEventInformation(*p, 0, 0)
        it.InvokeEvent("MouseMoveEvent")
    it.InvokeEvent("LeftButtonReleaseEvent")


def on_screen(w, renderer, point):
    """Display pixel (VTK's: from the bottom left) of a world point in a viewport."""
    ren = w.renderers[renderer]
    ren.SetWorldPoint(*point, 1.0)
    ren.WorldToDisplay()
    x, y, _ = ren.GetDisplayPoint()
    return int(round(x)), int(round(y))


def button(w, label_start):
    """Display pixel of the centre of a panel cell whose label starts so."""
    x0, y0, x1, y1 = w.renderers["panel"].GetViewport()
    W, H = w.plotter.render_window.GetSize()
    for label, _, (u0, v0, u1, v1) in w.buttons():
        if label.startswith(label_start):
            return int((x0 + (u0 + u1) / 2 * (x1 - x0)) * W), int((y0 + (v0 + v1) / 2 * (y1 - y0)) * H)
    raise AssertionError(f"no button {label_start!r} in {[b[0] for b in w.buttons()]}")


def part(img, w, renderer):
    """The pixels of one viewport in a screenshot (rows from the top)."""
    H, W = img.shape[:2]
    x0, y0, x1, y1 = w.renderers[renderer].GetViewport()
    return img[round((1 - y1) * H):round((1 - y0) * H), round(x0 * W):round(x1 * W)].astype(float)


def changed(a, b):
    return np.abs(a - b).mean()


# ------------------------------------------------------------------------------------------------ tests


def test_controls_map_parameters_to_sliders():
    params = [Parameter("tile.height", "tile", "real", 0.5, 0.05, 2.0), Parameter("tile.sides", "tile", "int", 4, 3, 8),
              Parameter("material0.exponent", "material 0", "real", 256.0, 1.0, 2000.0),
              Parameter("material0.kind", "material 0", "choice", "ward", choices=("lambert", "ward")),
              Parameter("tile.color", "tile", "rgb", (1.0, 0.75, 0.3))]
    groups = controls_of(params)
    assert list(groups) == ["tile", "material 0"]
    assert [c.key for c in groups["tile"]] == ["tile.height", "tile.sides", "tile.color:0", "tile.color:1",
                                                "tile.color:2"]
    exp, kind = groups["material 0"]
    assert exp.scale == "log" and (exp.lo, exp.hi) == (0.0, pytest.approx(np.log10(2000)))
    assert to_slider(exp, 100.0) == pytest.approx(2.0) and from_slider(exp, 2.0, None) == pytest.approx(100.0)
    assert from_slider(exp, exp.hi, None) <= 2000.0  # 10**log10(hi) stays in range
    assert to_slider(kind, "ward") == 1 and from_slider(kind, 0.6, None) == "ward"
    sides = groups["tile"][1]
    assert from_slider(sides, 4.4, None) == 4 and from_slider(sides, 9.7, None) == 8
    green = Control("tile.color:1", "color G", 0.0, 1.0, "real")
    assert from_slider(green, 0.2, (1.0, 0.75, 0.3)) == (1.0, 0.2, 0.3)


def test_sliders_keys_and_tabs_edit_the_design(tmp_path):
    ed = quick("pyramid")
    w = open_editor(ed, off_screen=True, truth=False)
    try:
        img0 = w.screenshot(tmp_path / "start.png")
        assert os.path.getsize(tmp_path / "start.png") > 0
        for name in ("frame", "panel", "tile"):
            assert part(img0, w, name).std() > 8, name  # each viewport has content, not a flat background
        # the frame viewport shows the editor's frame at its own size, upright (text overlays cover a little)
        frame = part(img0, w, "frame")
        assert frame.shape[:2] == (72, 96)
        assert np.abs(frame - ed.image8()).mean() < 25

        # a geometry slider: coarse bakes while it moves, the full bake when let go, one undo step for the drag
        assert list(w.sliders)[:3] == ["tile.height", "tile.sides", "tile.rotation"]
        widget = w.sliders["tile.height"]
        widget.InvokeEvent("StartInteractionEvent")
        for v in (0.8, 1.2):
            widget.GetRepresentation().SetValue(v)
            widget.InvokeEvent("InteractionEvent")
            assert ed.timings["redone"] == "bake"
        assert w._coarse and "coarse" in w.frame_text.GetText(2)
        widget.InvokeEvent("EndInteractionEvent")
        assert ed.get("tile.height") == pytest.approx(1.2) and not w._coarse
        assert not ed.refine()  # already refined by the release
        img1 = w.screenshot()
        assert changed(part(img1, w, "frame"), part(img0, w, "frame")) > 1
        assert changed(part(img1, w, "tile"), part(img0, w, "tile")) > 1
        press_key(w, "u")
        assert ed.get("tile.height") == pytest.approx(0.5)  # the whole drag undone at once
        assert widget.GetRepresentation().GetValue() == pytest.approx(0.5)  # and the slider follows
        press_key(w, "r")
        assert ed.get("tile.height") == pytest.approx(1.2)
        press_key(w, "z", ctrl=True)
        assert ed.get("tile.height") == pytest.approx(0.5)
        press_key(w, "y", ctrl=True)
        assert ed.get("tile.height") == pytest.approx(1.2)
        # an int slider snaps
        drag(w, "tile.sides", 5.4)
        assert ed.get("tile.sides") == 5 and w.sliders["tile.sides"].GetRepresentation().GetValue() == 5

        # a tab, clicked: the first material's sliders
        mouse(w, button(w, "material 0"))
        assert w.tab == "material 0" and set(w.sliders) >= {"material0.kind", "material0.exponent"}
        before = w.screenshot()
        widget = w.sliders["material0.exponent"]
        widget.GetRepresentation().SetValue(1.0)  # a log10 slider: exponent 10
        widget.InvokeEvent("InteractionEvent")
        assert ed.get("material0.exponent") == pytest.approx(10.0)
        assert ed.timings["redone"] == "materials"  # new small-scale BRDFs on the same bake
        widget.InvokeEvent("EndInteractionEvent")
        assert ed.timings["redone"] != "bake"
        assert changed(part(w.screenshot(), w, "frame"), part(before, w, "frame")) > 1
        # a choice applies when let go: another kind brings its own sliders
        widget = w.sliders["material0.kind"]
        widget.GetRepresentation().SetValue(2.0)
        widget.InvokeEvent("InteractionEvent")
        assert ed.get("material0.kind") == "blinnphong"
        widget.InvokeEvent("EndInteractionEvent")
        assert ed.get("material0.kind") == "cooktorrance" and "material0.roughness" in w.sliders

        # keys VTK has too do only ours: 'r' redoes (nothing here), it does not reset the tile's camera
        cam = w.renderers["tile"].camera
        cam.Azimuth(25)
        where = cam.GetPosition()
        press_key(w, "r")
        assert cam.GetPosition() == where and w.status == "nothing to redo"
        # save: not without -o; then to it; a screenshot of the window
        press_key(w, "s")
        assert w.status.startswith("no file to save to")
        w.output = str(tmp_path / "design.toml")
        press_key(w, "s")
        text = (tmp_path / "design.toml").read_text()
        assert 'type = "bake"' in text and "cooktorrance" in text
        press_key(w, "p")
        shot = tmp_path / "design-001.png"
        assert shot.exists() and w.status == f"wrote {shot}"
    finally:
        w.close()


def test_painting_the_height_field(tmp_path):
    ed = quick("heightfield")
    w = open_editor(ed, off_screen=True, truth=False)
    try:
        img0 = w.screenshot()
        n = len(ed.heights)
        centre = on_screen(w, "tile", (0.05, 0.05, float(np.mean(ed.tile.z_range))))
        cam = w.renderers["tile"].camera
        h0 = ed.heights
        # no brush: a drag on the tile turns the camera, it does not paint
        mouse(w, centre, (centre[0] + 30, centre[1]))
        assert np.array_equal(ed.heights, h0)
        assert w.brush["mode"] == "off"
        view = cam.GetPosition()

        press_key(w, "m")
        assert w.brush["mode"] == "raise"
        x, y = w.tile_coordinates(w.pick_tile(*centre))
        assert abs(x - 0.55) < 0.1 and abs(y - 0.55) < 0.1  # world (0.05, 0.05): tile point (0.55, 0.55)
        mouse(w, centre)
        assert cam.GetPosition() == view  # the stroke never reached the camera
        d = ed.heights - h0
        assert d.max() > 0.05 and d.min() >= 0
        # raised where painted only: nothing beyond the brush radius (wrapping over the period)
        c = np.arange(n) / n
        dx, dy = np.abs(c[None, :] - x), np.abs(c[:, None] - y)
        dist = np.hypot(np.minimum(dx, 1 - dx), np.minimum(dy, 1 - dy))
        assert np.all(d[dist > w.brush["radius"] + 1e-9] == 0)
        assert d[dist < w.brush["radius"] / 2].min() > 0
        img1 = w.screenshot()
        assert changed(part(img1, w, "tile"), part(img0, w, "tile")) > 0.2
        assert changed(part(img1, w, "frame"), part(img0, w, "frame")) > 0.05

        # a stroke of several dabs is one undo step
        h1 = ed.heights
        mouse(w, centre, (centre[0] + 25, centre[1]), (centre[0] + 50, centre[1] + 10))
        assert (ed.heights - h1).max() > 0 and not w._coarse
        press_key(w, "u")
        assert np.array_equal(ed.heights, h1)

        press_key(w, "m")
        assert w.brush["mode"] == "lower"
        mouse(w, centre)
        assert (ed.heights - h1).min() < -0.05 and (ed.heights - h1).max() <= 1e-12
        press_key(w, "m")
        assert w.brush["mode"] == "smooth"
        h2 = ed.heights
        near = dist < w.brush["radius"] / 2
        mouse(w, centre)
        assert ed.heights[near].std() < h2[near].std()  # smoother where brushed
        # the brush's settings are sliders of the "view" tab
        w.select_tab("view")
        drag(w, "view.brush_radius", 0.3)
        assert w.brush["radius"] == pytest.approx(0.3)
        w.screenshot(tmp_path / "painted.png")
    finally:
        w.close()


def test_looking_inside(tmp_path):
    ed = quick("pyramid")
    w = open_editor(ed, off_screen=True, truth=True)
    try:
        img0 = w.screenshot()
        press_key(w, "i")
        assert w.inside and w.renderers["ndf"].GetDraw() and w.renderers["polar"].GetDraw()
        assert w.wait_truth(180), "the ground truth did not arrive"
        img1 = w.screenshot(tmp_path / "inside.png")
        for name in ("ndf", "polar", "tile"):
            assert part(img1, w, name).std() > 5, name
        assert changed(part(img1, w, "ndf"), part(img0, w, "ndf")) > 5  # (what the tile showed there before)
        text = w.polar_text.GetText(2)
        assert "PSNR" in text and "dB" in text
        theta, ours, truth = w.slice()
        assert np.all(np.isfinite(ours)) and truth is not None and np.all(np.isfinite(truth))
        assert np.corrcoef(ours, truth)[0, 1] > 0.9  # the bake follows the truth's shape
        # the slice's incidence, on the "view" tab
        w.select_tab("view")
        drag(w, "view.theta_i", 60.0)
        assert w.theta_i == pytest.approx(60.0)
        _, ours60, _ = w.slice()
        assert not np.allclose(ours60, ours)
        img2 = w.screenshot()
        assert changed(part(img2, w, "polar"), part(img1, w, "polar")) > 0.2
        # another geometry: its own truth, in the background
        w.select_tab("tile")
        drag(w, "tile.height", 1.5)
        assert w.wait_truth(180)
        assert "PSNR" in w.polar_text.GetText(2)
        press_key(w, "i")
        assert not w.inside and not w.renderers["ndf"].GetDraw()
    finally:
        w.close()
    assert w.truth is None  # the worker process is gone with the window


def test_cli_edit(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["edit", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "--size N [N ...]" in out and "heightfield" in out and "undo" in out
    assert cli.main(["edit", "no-such-tile", "--screenshot", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: Editor target 'no-such-tile'") and err.count("\n") == 1
    assert cli.main(["edit", "pyramid", "--size", "8"]) == 2  # (W [H] as every command; WxH still taken)
    assert "--size must be WIDTH [HEIGHT]" in capsys.readouterr().err
    assert cli.main(["edit", "pyramid", "--screenshot", str(tmp_path / "x.jpg")]) == 2
    assert cli.main(["edit", "pyramid", "-o", str(tmp_path / "design.txt")]) == 2  # refused before the bake
    assert "design.txt" in capsys.readouterr().err
    path = tmp_path / "edit.png"
    assert cli.main(["edit", "pyramid", "--size", "96x72", "--screenshot", str(path), "-q"]) == 0
    from PIL import Image

    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (372, 1080, 3) and img.std() > 8
