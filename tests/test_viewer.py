"""The pyvista viewer, offscreen (EGL): our image lines up with pyvista's camera, the sliders' edits,
the tile's colours, and a screenshot with content in both viewports."""

import math
import os

import numpy as np
import pytest

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # before VTK loads
pv = pytest.importorskip("pyvista")

import warp_biscale as wb  # noqa: E402
from warp_biscale import viewer  # noqa: E402
from warp_biscale.scenefile import loads_scene  # noqa: E402

pv.OFF_SCREEN = True

SCENE = """\
[render]
width = 64
height = 64
backend = "warp:cpu"

[camera]
eye = [0.0, 1.2, 3.5]
target = [0.0, 0.4, 0.0]
fov = 40

[environment]
type = "sky"
height = 16
width = 32
supersample = 1

[[light]]
type = "point"
position = [2.0, 3.0, 2.0]
intensity = 8.0

[[object]]
mesh = "sphere"
radius = 0.6
center = [0.0, 0.6, 0.0]
subdivisions = 2
material = "tiles"

[[object]]
mesh = "plane"
size = 4.0
divisions = 4
material = "floor"

[material.floor]
type = "lambert"
albedo = 0.5
"""

BAKED = SCENE + """
[material.tiles]
type = "bake"
tile = "pyramid"
tile_params = { height = 0.5, color = [1.0, 0.7, 0.3], base_color = [0.2, 0.4, 1.0] }
brdf = ["blinnphong:exponent=64,ks=0.8,kd=0.1"]
lobes = 2
directions = 4
facets = 512
normal_res = 16
"""

ANALYTIC = SCENE + """
[material.tiles]
type = "cooktorrance"
ks = 0.8
roughness = 0.3
kd = [0.3, 0.1, 0.05]
"""


@pytest.fixture(scope="module")
def baked():
    return loads_scene(BAKED, path="baked.toml")


def test_our_camera_sees_what_pyvista_sees():
    """World points project to the same pixel in VTK's viewport and in our Camera's image."""
    plotter = pv.Plotter(shape=(1, 2), window_size=(160, 90), off_screen=True, border=False)
    plotter.subplot(0, 0)
    plotter.add_mesh(pv.Sphere())
    ren = plotter.renderer
    cam = ren.camera
    cam.position, cam.focal_point, cam.up = (1.5, 2.0, 4.0), (0.2, -0.1, 0.3), (0.1, 1.0, 0.0)
    cam.view_angle = 35.0
    plotter.render()
    w, h = ren.GetSize()
    assert (w, h) == (80, 90)
    ours = viewer.camera_from_pyvista(cam, w, h)
    f, r, u, t = ours.basis()
    pts = np.array([[0.2, -0.1, 0.3], [0.7, 0.3, -0.2], [-0.5, 0.4, 0.8], [0.9, -0.6, 0.1]])
    for p in pts:
        ren.SetWorldPoint(*p, 1.0)
        ren.WorldToDisplay()
        dx, dy, _ = ren.GetDisplayPoint()
        v = p - ours.eye
        x = ((v @ r) / (v @ f) / (t * w / h) + 1) / 2 * w       # our pixel coordinates (x right, y down)
        y = (1 - (v @ u) / (v @ f) / t) / 2 * h
        assert x == pytest.approx(dx, abs=0.02) and y == pytest.approx(h - dy, abs=0.02)
    # and back: our camera → pyvista → ours is the identity
    other = pv.Plotter(off_screen=True).renderer.camera
    viewer.camera_to_pyvista(ours, other)
    again = viewer.camera_from_pyvista(other, w, h)
    np.testing.assert_allclose([again.eye, again.target, again.up], [ours.eye, ours.target, ours.up], atol=1e-12)
    assert again.fov == pytest.approx(ours.fov)
    plotter.close()


def test_horizontal_view_angle_is_converted():
    c = pv.Plotter(off_screen=True).renderer.camera
    c.SetUseHorizontalViewAngle(True)
    c.SetViewAngle(60.0)
    ours = viewer.camera_from_pyvista(c, 200, 100)
    assert math.tan(math.radians(ours.fov) / 2) * 2 == pytest.approx(math.tan(math.radians(30)))


@pytest.mark.parametrize("brdf, field, slider, expect", [
    (wb.BlinnPhong(ks=0.5, exponent=100.0), "exponent", 3.0, 1000.0),
    (wb.CookTorrance(roughness=0.2), "roughness", 0.5, 0.5),
    (wb.Ward(alpha=0.2), "alpha", 0.1, 0.1),
    (wb.Lambert((0.4, 0.2, 0.1)), "albedo", 0.8, (0.8, 0.4, 0.2)),
])
def test_main_parameter_slider(brdf, field, slider, expect):
    label, value, lo, hi = viewer.main_parameter(brdf)
    assert lo <= value <= hi
    new = viewer.with_main_parameter(brdf, slider)
    assert np.allclose(getattr(new, field), expect)
    assert type(new) is type(brdf)


def test_main_parameter_of_a_baked_material_edits_without_rebaking(baked):
    mat = baked.materials["tiles"]
    label, value, _, _ = viewer.main_parameter(mat)
    assert label == "log10 exponent" and value == pytest.approx(math.log10(64))
    new = viewer.with_main_parameter(mat, 2.5)
    assert isinstance(new, wb.EffectiveBRDF) and new.materials[0].exponent == pytest.approx(10 ** 2.5)
    assert new.amplitudes is mat.amplitudes and set(new.timings) == {"tables"}


@pytest.mark.parametrize("light", [wb.PointLight((2.0, 3.0, 2.0), 8.0), wb.DirectionalLight((0.3, 0.8, -0.5))])
def test_light_angles_round_trip(light):
    centre = np.array([0.0, 0.5, 0.0])
    az, el = viewer.light_angles(light, centre)
    moved = viewer.with_light_angles(light, centre, azimuth=az + 90.0, elevation=20.0)
    az2, el2 = viewer.light_angles(moved, centre)
    assert (az2 - az - 90.0 + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-9) and el2 == pytest.approx(20.0)
    same = viewer.with_light_angles(light, centre)
    if isinstance(light, wb.PointLight):
        np.testing.assert_allclose(same.position, light.position, atol=1e-12)
        assert np.linalg.norm(moved.position - centre) == pytest.approx(np.linalg.norm(light.position - centre))
    else:
        np.testing.assert_allclose(same.direction, light.direction, atol=1e-12)


def test_tile_polydata_colours(baked):
    tile = baked.tiles["tiles"]
    poly = viewer.tile_polydata(tile, baked.materials["tiles"].materials, repeat=2)
    assert poly.n_cells == 4 * len(tile.faces)
    rgb = poly.cell_data["rgb"]
    # material colour kd + ks = 0.9, times the face colour weights
    expect = np.rint(np.clip(0.9 * tile.colors, 0, 1) * 255)
    np.testing.assert_array_equal(rgb[:len(tile.faces)], expect)
    assert np.allclose(poly.center[:2], 0.0, atol=1e-9)


def _check_screenshot(img, path):
    assert os.path.getsize(path) > 0
    from PIL import Image

    saved = np.asarray(Image.open(path).convert("RGB"))
    assert saved.shape == img.shape == (64, 128, 3)
    left, right = saved[:, :64].astype(float), saved[:, 64:].astype(float)
    assert len(np.unique(saved.reshape(-1, 3), axis=0)) > 20  # not a single colour
    for half in (left, right):
        assert half.std() > 8  # each viewport has content, not a flat background
    return left, right


def test_screenshot_of_a_baked_scene(tmp_path):
    baked = loads_scene(BAKED, path="baked.toml")  # its own: the sliders below edit it
    path = tmp_path / "view.png"
    v = viewer.Viewer(baked, size=(128, 64), off_screen=True)
    try:
        img = v.screenshot(path)
        assert v.frames == 1 and v.image.shape == (64, 64, 3)
        assert v.scene.camera.width == 64 and v.scene.camera.height == 64
        left, right = _check_screenshot(img, path)
        # pyvista did not reset our camera at the first screenshot: it still is the scene file's
        np.testing.assert_allclose(v.left.camera.GetPosition(), [0.0, 1.2, 3.5], atol=1e-9)
        # the left viewport shows our rendering (tone-mapped), not pyvista's proxy
        from warp_biscale.images import tonemap

        ours = tonemap(v.image, exposure=baked.exposure).astype(float)
        assert np.abs(left - ours).mean() < 40  # the slider and text overlays cover part of it
        # a slider edit re-renders with the new light
        before = v.image.copy()
        v._set_light(azimuth=-120.0)
        assert v.frames == 2 and not np.allclose(before, v.image)
        # re-rendering only when the view changed
        v.update()
        assert v.frames == 2
        v.left.camera.Azimuth(20)
        v.update()
        assert v.frames == 3
        # what a mouse drag in the left viewport does: proxy while dragging, our frame on release
        style = v.plotter.iren.interactor.GetInteractorStyle()
        style.SetCurrentRenderer(v.left)
        style.InvokeEvent("StartInteractionEvent")
        assert v.proxy.GetVisibility() and not v.left.GetTexturedBackground()
        v.left.camera.Elevation(10)
        style.InvokeEvent("EndInteractionEvent")
        assert v.frames == 4 and not v.proxy.GetVisibility() and v.left.GetTexturedBackground()
        # a drag in the right viewport leaves the left alone
        style.SetCurrentRenderer(v.right)
        style.InvokeEvent("StartInteractionEvent")
        style.InvokeEvent("EndInteractionEvent")
        assert v.frames == 4 and not v.proxy.GetVisibility()
        # the material slider edits the baked material without re-baking and re-renders
        v._set_material(1.0)
        assert v.frames == 5 and v.scene.materials[0].materials[0].exponent == pytest.approx(10.0)
        assert baked.materials["tiles"] is v.scene.materials[0]
    finally:
        v.close()


def test_screenshot_without_a_baked_material_shows_a_sphere_preview(tmp_path):
    sf = loads_scene(ANALYTIC, path="analytic.toml")
    img = viewer.view(sf, screenshot=tmp_path / "v.png", size=(128, 64))
    _check_screenshot(img, tmp_path / "v.png")


def test_screenshot_of_a_measured_material_by_the_lit_sphere(tmp_path):
    """A scene file whose render method is the lit sphere, with a MERL material (written here): both
    viewports are drawn by the lit-sphere shader (the SG renderer cannot shade a measured BRDF)."""
    from warp_biscale.measured import paint_like

    wb.MeasuredBRDF.from_brdf(paint_like()).save(tmp_path / "paint.binary")
    analytic = 'type = "cooktorrance"\nks = 0.8\nroughness = 0.3\nkd = [0.3, 0.1, 0.05]'
    text = ANALYTIC.replace('backend = "warp:cpu"', 'backend = "warp:cpu"\nmethod = "litsphere"').replace(
        analytic, 'type = "merl"\npath = "paint.binary"')
    sf = loads_scene(text, path=str(tmp_path / "measured.toml"))
    assert isinstance(sf.scene.materials[0], wb.MeasuredBRDF)
    v = viewer.Viewer(sf, size=(128, 64), off_screen=True)
    try:
        img = v.screenshot(tmp_path / "v.png")
        left, right = _check_screenshot(img, tmp_path / "v.png")
        assert v.method == "litsphere"
        centre = right[24:40, 24:40]  # the preview sphere: the paint's red, not grey
        assert centre[..., 0].mean() > 1.5 * centre[..., 2].mean()
    finally:
        v.close()
