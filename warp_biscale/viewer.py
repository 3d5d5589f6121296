"""The interactive viewer (``warp-biscale view scene.toml``): a pyvista window with two viewports.

Left: the large-scale scene as *our* renderer shades it (the SG renderer, `render.render`), seen from
the pyvista camera: drag to orbit, wheel to zoom; while the mouse is down pyvista draws a quick grey
proxy of the mesh, and when it is released the frame is re-rendered with warp_biscale and shown as
the viewport's background. Sliders re-render too: the first light's azimuth and elevation (around
the scene's centre) and the main parameter of the first baked material's small-scale BRDF (else of
the first material): Blinn–Phong exponent (log10 slider), Cook–Torrance roughness, Ward alpha,
Lambert albedo. A baked material is edited with `EffectiveBRDF.with_materials` (no re-bake).

Right: the small-scale tile of the first baked material, 3×3 periods, each face in its material's
colour times its colour weight; with no baked material, a sphere in the first material rendered by
warp_biscale (a preview that follows the material slider).

    v = Viewer(load_scene("examples/bi-scale.toml"), size=(1200, 600), off_screen=True)
    v.screenshot("view.png")                 # what `view --screenshot view.png` does
    v.show()                                 # a window (needs a display)

Offscreen rendering uses EGL (no X server): `VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow` is set
before VTK loads when a screenshot is asked for.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
import warnings

import numpy as np

from . import brdf as B
from .effective import EffectiveBRDF
from .images import tonemap
from .io import atomic_path
from .litsphere import LitSphere
from .measured import MeasuredBRDF
from .render import render
from .scene import Scene
from .scene import Camera, DirectionalLight, Mesh, PointLight
from .scenefile import SceneFile, load_scene

__all__ = ["Viewer", "view", "camera_from_pyvista", "camera_to_pyvista", "main_parameter", "with_main_parameter",
           "light_angles", "with_light_angles", "tile_polydata", "material_color"]


# ------------------------------------------------------------------------------------------------ cameras


def camera_from_pyvista(pv_camera, width: int, height: int):
    """Our `Camera` seeing what a pyvista / VTK camera sees in a width × height viewport: VTK's
    position, focal point, view up and (vertical) view angle are our eye, target, up and fov."""

    if pv_camera.GetUseHorizontalViewAngle():
        t = math.tan(math.radians(pv_camera.GetViewAngle()) / 2) * height / width
        fov = math.degrees(2 * math.atan(t))
    else:
        fov = pv_camera.GetViewAngle()
    eye = np.array(pv_camera.GetPosition(), np.float64)
    target = np.array(pv_camera.GetFocalPoint(), np.float64)
    up = np.array(pv_camera.GetViewUp(), np.float64)
    f = target - eye
    up = up - f * (up @ f) / max(f @ f, 1e-300)  # VTK keeps it orthogonal; make sure
    return Camera(eye, target, up, fov, int(width), int(height))


def camera_to_pyvista(camera, pv_camera) -> None:
    """Point a pyvista / VTK camera like our `Camera` (vertical view angle = fov)."""
    pv_camera.SetUseHorizontalViewAngle(False)
    pv_camera.SetPosition(*camera.eye)
    pv_camera.SetFocalPoint(*camera.target)
    pv_camera.SetViewUp(*camera.up)
    pv_camera.SetViewAngle(camera.fov)
    if hasattr(pv_camera, "is_set"):  # pyvista resets an unset camera at the first show / screenshot
        pv_camera.is_set = True


# ------------------------------------------------------------------------------------------------ editing


def _brdf_main(b):
    """(field, label, value, slider lo, slider hi, log10 slider) of a small-scale BRDF's main parameter."""

    if isinstance(b, B.BlinnPhong):
        return "exponent", "log10 exponent", b.exponent, 0.0, 4.0, True
    if isinstance(b, B.CookTorrance):
        return "roughness", "roughness", b.roughness, 0.02, 1.0, False
    if isinstance(b, B.Ward):
        return "alpha", "alpha", b.alpha, 0.02, 1.0, False
    if isinstance(b, B.Lambert):
        return "albedo", "albedo", max(b.albedo), 0.0, 1.0, False
    return None


def main_parameter(material):
    """The slider a material gets: (label, slider value, lo, hi), or None. A baked material's is its
    first small-scale BRDF's."""

    b = material.materials[0] if isinstance(material, EffectiveBRDF) else material
    m = _brdf_main(b)
    if m is None:
        return None
    _, label, value, lo, hi, log = m
    v = math.log10(value) if log else value
    return label, float(np.clip(v, lo, hi)), lo, hi


# Interactive frames: 4 shadow rays a light (a grainier penumbra) and one sample a pixel, for speed; a file
# written from the viewer's scene with `warp-biscale render` gets the full defaults.
VIEWER_SHADOW_SAMPLES = 4
VIEWER_OCCLUSION_SAMPLES = 8  # and half the default occlusion rays (broad lobes half through the SSDF)


def _brdf_with(b, slider_value):
    field, _, _, _, _, log = _brdf_main(b)
    value = 10.0 ** slider_value if log else float(slider_value)
    if field == "albedo":
        rgb = np.asarray(b.albedo)
        value = tuple(rgb / max(rgb.max(), 1e-12) * value) if rgb.max() > 0 else (value,) * 3
    else:
        value = max(value, 1e-6)
    with warnings.catch_warnings():  # the loaded material warned once already; a slider must not repeat it
        warnings.simplefilter("ignore", B.EnergyWarning)
        return dataclasses.replace(b, **{field: value})


def with_main_parameter(material, slider_value):
    """The material with its main parameter set from a slider value (see `main_parameter`); a baked
    material gets every small-scale BRDF equal to its first one changed (`with_materials`: no re-bake)."""

    if isinstance(material, EffectiveBRDF):
        first = material.materials[0]
        new = _brdf_with(first, slider_value)
        return material.with_materials([new if m == first else m for m in material.materials])
    return _brdf_with(material, slider_value)


def light_angles(light, centre) -> tuple[float, float]:
    """(azimuth, elevation) in degrees of a light seen from `centre` (+y up; azimuth 0 along +z,
    90 along +x)."""

    d = (light.position - np.asarray(centre, np.float64)) if isinstance(light, PointLight) else light.direction
    d = d / max(np.linalg.norm(d), 1e-300)
    return math.degrees(math.atan2(d[0], d[2])), math.degrees(math.asin(float(np.clip(d[1], -1, 1))))


def with_light_angles(light, centre, azimuth=None, elevation=None):
    """The light moved to (azimuth, elevation) degrees around `centre` (a point light keeps its
    distance; a directional one its irradiance and size)."""

    az0, el0 = light_angles(light, centre)
    az = math.radians(az0 if azimuth is None else azimuth)
    el = math.radians(el0 if elevation is None else elevation)
    d = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    if isinstance(light, PointLight):
        r = float(np.linalg.norm(light.position - np.asarray(centre, np.float64)))
        return dataclasses.replace(light, position=np.asarray(centre, np.float64) + r * d)
    return dataclasses.replace(light, direction=d)


# ------------------------------------------------------------------------------------------------ the tile


def material_color(b) -> np.ndarray:
    """A display colour (RGB in [0, 1]) for a small-scale BRDF: the albedo, or kd + ks."""

    if isinstance(b, B.Lambert):
        c = np.asarray(b.albedo)
    else:
        c = np.asarray(b.kd) + np.asarray(b.ks)
    return np.clip(c, 0.0, 1.0)


def tile_polydata(tile, materials, repeat: int = 3):
    """A pyvista PolyData of `repeat`² periods of a SmallScale tile (centred on the origin, z up)
    with cell data "rgb" (uint8): each face's material colour × its colour weight."""
    import pyvista as pv  # (imported only to draw: VTK takes about a second to load)

    mats = list(materials)
    ids = np.clip(tile.material_ids, 0, len(mats) - 1)
    base = np.stack([material_color(m) for m in mats])[ids] * np.clip(tile.colors, 0.0, 1.0)
    px, py = tile.period
    verts, faces, colors = [], [], []
    n = len(tile.vertices)
    for i in range(repeat):
        for j in range(repeat):
            off = np.array([(i - (repeat - 1) / 2) * px, (j - (repeat - 1) / 2) * py, 0.0])
            verts.append(tile.vertices - tile.corner - [px / 2, py / 2, 0] + off)
            faces.append(tile.faces + n * (i * repeat + j))
            colors.append(base)
    poly = pv.PolyData.from_regular_faces(np.concatenate(verts), np.concatenate(faces))
    poly.cell_data["rgb"] = np.rint(np.concatenate(colors) * 255).astype(np.uint8)
    return poly


# ------------------------------------------------------------------------------------------------ the window


def _ensure_offscreen_gl():
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


class Viewer:
    """The two-viewport viewer of a `scenefile.SceneFile` (see the module docstring).

    size: window (width, height) in pixels; backend: overrides the scene's; off_screen: no window
    (for `screenshot`); render_scale: our image's resolution as a fraction of the viewport's."""

    def __init__(self, scenefile, size=(1200, 600), backend=None, off_screen=False, progress=None,
                 render_scale: float = 1.0):
        if off_screen:
            _ensure_offscreen_gl()
        import pyvista as pv  # (imported only to draw: VTK takes about a second to load)

        w, h = (int(x) for x in size)
        if w < 2 or h < 1:
            raise ValueError(f"window size must be at least 2 x 1 pixels, got {size}")
        check_render_scale(render_scale)
        self.sf = scenefile
        self.scene = scenefile.scene
        self.backend = backend or scenefile.backend
        # the scene file's shader when it is the lit sphere (SG for "mc": the reference is not interactive)
        self.method = "litsphere" if scenefile.method == "litsphere" else "sg"
        if scenefile.method == "mc":
            warnings.warn("the viewer draws this scene with the SG renderer: its [render] method 'mc', the Monte Carlo "
                          "reference, is for `warp-biscale render`", stacklevel=2)
        self.progress = progress
        self.render_scale = float(render_scale)
        self.timings: dict = {}
        self.frames = 0
        self.image = None
        self._preview = None
        self._rendered_view = None
        b = self.scene.mesh.bounds
        self.centre = (b[0] + b[1]) / 2
        # the material the slider edits: the first baked one, else the first
        names = scenefile.material_names
        baked = [n for n in names if n in scenefile.tiles]
        self.edit_name = baked[0] if baked else names[0]
        self.edit_index = names.index(self.edit_name)
        self.tile_name = baked[0] if baked else None

        self.plotter = pv.Plotter(shape=(1, 2), window_size=(w, h), off_screen=off_screen, border=False,
                                  title="warp_biscale viewer")
        self._setup_left(pv)
        self._setup_right(pv)
        self.plotter.subplot(0, 0)

    # ---------------------------------------------------------------- left: our rendering
    def _setup_left(self, pv):
        p = self.plotter
        p.subplot(0, 0)
        self.left = p.renderer
        self.left.set_background("black")
        mesh = self.scene.mesh
        proxy = pv.PolyData.from_regular_faces(mesh.vertices, mesh.faces)
        self.proxy = p.add_mesh(proxy, color="lightgrey", smooth_shading=True, name="proxy")
        self.proxy.SetVisibility(False)
        camera_to_pyvista(self.scene.camera, self.left.camera)
        self.left.ResetCameraClippingRange()
        self.status = p.add_text("", position="upper_left", font_size=9, color="white", shadow=True, name="status")
        self._updating = True  # the sliders call back once when added: not a user edit
        if self.scene.lights:
            az, el = light_angles(self.scene.lights[0], self.centre)
            p.add_slider_widget(lambda v: self._set_light(azimuth=v), [-180.0, 180.0], value=az,
                                title="light azimuth", pointa=(0.04, 0.09), pointb=(0.31, 0.09), style="modern",
                                title_height=0.025, fmt="%.0f")
            p.add_slider_widget(lambda v: self._set_light(elevation=v), [-10.0, 90.0], value=el,
                                title="light elevation", pointa=(0.36, 0.09), pointb=(0.63, 0.09),
                                style="modern", title_height=0.025, fmt="%.0f")
        param = main_parameter(self.scene.materials[self.edit_index])
        if param is not None:
            label, value, lo, hi = param
            p.add_slider_widget(self._set_material, [lo, hi], value=value, title=label,
                                pointa=(0.68, 0.09), pointb=(0.96, 0.09), style="modern", title_height=0.025,
                                fmt="%.2f")
        self._updating = False
        iren = p.iren
        if iren is not None:
            style = iren.interactor.GetInteractorStyle()
            if style is not None:
                style.AddObserver("StartInteractionEvent", self._start_interaction)
                style.AddObserver("EndInteractionEvent", self._end_interaction)
            p.add_key_event("u", lambda: self.update(force=True))

    def _viewport_pixels(self, renderer):
        w, h = renderer.GetSize()
        if w < 1 or h < 1:  # before the first render: from the viewport and window size
            vp = renderer.GetViewport()
            ws = self.plotter.window_size
            w, h = round((vp[2] - vp[0]) * ws[0]), round((vp[3] - vp[1]) * ws[1])
        s = self.render_scale
        return max(1, round(w * s)), max(1, round(h * s))

    def _view_state(self):
        c = self.left.camera
        return (c.GetPosition(), c.GetFocalPoint(), c.GetViewUp(), c.GetViewAngle(), self._viewport_pixels(self.left))

    def _start_interaction(self, style=None, _event=None):
        """Mouse down in the left viewport: pyvista's quick proxy follows the camera until release."""
        ren = style.GetCurrentRenderer() if style is not None else None
        if ren is None or ren is self.left:
            self.proxy.SetVisibility(True)
            self.left.SetTexturedBackground(False)

    def _end_interaction(self, *_):
        self.update()

    def update(self, force: bool = False):
        """Re-render the left viewport from its camera if the view changed (or `force`)."""
        state = self._view_state()
        if force or state != self._rendered_view:
            self.render_left()
        else:
            self.proxy.SetVisibility(False)
            self.left.SetTexturedBackground(True)

    def render_left(self):
        """Render the scene with warp_biscale from the left viewport's camera and show it."""

        w, h = self._viewport_pixels(self.left)
        self.scene.camera = camera_from_pyvista(self.left.camera, w, h)
        t0 = time.perf_counter()
        # (interactive: one sample a pixel and the viewer's rays, whatever the file's [render] asks of an image)
        rays = {"occlusion_samples": VIEWER_OCCLUSION_SAMPLES} if self.method == "sg" else {}  # (none in a lit sphere)
        result = self.sf.render(method=self.method, backend=self.backend, progress=self.progress, aa=1,
                                shadow_samples=VIEWER_SHADOW_SAMPLES, **rays)
        dt = time.perf_counter() - t0
        self.image = result.image
        self.timings = result.timings
        self.frames += 1
        self._show(self.left, tonemap(result.image, exposure=self.sf.exposure))
        self.proxy.SetVisibility(False)
        self._rendered_view = self._view_state()
        stages = ", ".join(f"{k} {v * 1e3:.0f}" for k, v in result.timings.items() if k != "total")
        self.status.SetText(2, f"warp_biscale {w}x{h}: {dt * 1e3:.0f} ms\n({stages} ms)")
        if self.tile_name is None:
            self._render_preview()

    @staticmethod
    def _show(renderer, u8):
        import pyvista as pv  # (imported only to draw: VTK takes about a second to load)

        tex = pv.Texture(np.ascontiguousarray(u8))
        tex.interpolate = True  # smooth when render_scale < 1
        renderer.SetBackgroundTexture(tex)
        renderer.SetTexturedBackground(True)

    def _set_light(self, azimuth=None, elevation=None):
        if self._updating:
            return
        self.scene.lights[0] = with_light_angles(self.scene.lights[0], self.centre, azimuth, elevation)
        self.render_left()

    def _set_material(self, value):
        if self._updating:
            return
        i = self.edit_index
        self.scene.materials[i] = with_main_parameter(self.scene.materials[i], value)
        self.sf.materials[self.edit_name] = self.scene.materials[i]
        self.render_left()

    # ---------------------------------------------------------------- right: the tile or a preview
    def _setup_right(self, pv):
        p = self.plotter
        p.subplot(0, 1)
        self.right = p.renderer
        if self.tile_name is not None:
            tile = self.sf.tiles[self.tile_name]
            mat = self.sf.materials[self.tile_name]
            self.right.set_background("#30343a", top="#8a9aab")
            p.add_mesh(tile_polydata(tile, mat.materials), scalars="rgb", rgb=True, smooth_shading=False,
                       name="tile", show_scalar_bar=False)
            p.add_text(f"small scale of {self.tile_name!r}: {tile.name}", position="upper_left", font_size=9,
                       color="white", shadow=True, name="tile_label")
            c = self.right.camera
            size = 3 * max(tile.period)
            c.SetFocalPoint(0.0, 0.0, float(np.mean(tile.z_range)))
            c.SetPosition(0.9 * size, -1.3 * size, 1.2 * size)
            c.SetViewUp(0.0, 0.0, 1.0)
            c.SetViewAngle(30.0)
            self.right.ResetCamera()
            self.right.camera.Zoom(1.05)
            self.right.camera.is_set = True  # keep this view at the first show
        else:
            self.right.set_background("black")
            p.add_text(f"material {self.edit_name!r} on a sphere", position="upper_left", font_size=9,
                       color="white", shadow=True, name="tile_label")

    def _render_preview(self):
        """A unit sphere in the edited material, rendered by warp_biscale under the scene's environment
        and directional lights (its point lights are placed for the scene, not for the sphere)."""

        w, h = self._viewport_pixels(self.right)
        cam = Camera((0.0, 0.0, 4.5), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, w, h)
        mat = self.scene.materials[self.edit_index]
        lights = [lt for lt in self.scene.lights if isinstance(lt, DirectionalLight)]
        if self._preview is None:
            self._preview = Scene(Mesh.sphere(1.0, subdivisions=4), [mat], cam, self.scene.environment, lights,
                                  env_lobes=self.scene.env_lobes)
        ps = self._preview
        ps.camera, ps.materials, ps.lights = cam, [mat], lights
        # a lit sphere or a measured BRDF has no other shader; under method litsphere the preview is the
        # material ball `warp-biscale ball` draws
        method = "litsphere" if isinstance(mat, (LitSphere, MeasuredBRDF)) else self.method
        result = render(ps, method=method, backend=self.backend)
        self._show(self.right, tonemap(result.image, exposure=self.sf.exposure))

    # ---------------------------------------------------------------- output
    def screenshot(self, path) -> np.ndarray:
        """Render ours from the current camera, draw both viewports and write a PNG → (H, W, 3) uint8."""
        self.plotter.render()  # lays the viewports out (sizes) first
        self.render_left()
        self.plotter.render()
        img = self.plotter.screenshot(None, return_img=True)
        from PIL import Image


        with atomic_path(path) as tmp:
            Image.fromarray(np.ascontiguousarray(img[..., :3]), "RGB").save(tmp, format="PNG")
        return img[..., :3]

    def show(self):
        """Open the window (blocks until it is closed)."""
        self.render_left()
        self.plotter.show()

    def close(self):
        self.plotter.close()


def _has_display() -> bool:
    if sys.platform != "linux":
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def check_render_scale(render_scale) -> None:
    if not 0 < render_scale <= 1:
        raise ValueError(f"render_scale must be in (0, 1], got {render_scale}")


def view(scene, screenshot=None, size=(1200, 600), backend=None, progress=None, render_scale=1.0):
    """Open the viewer on a scene file path (or a loaded SceneFile); with `screenshot`, render
    offscreen, write that PNG and return its pixels instead."""

    check_render_scale(render_scale)  # (bad arguments are said before a missing display)
    if not isinstance(scene, SceneFile) and not os.path.isfile(os.fspath(scene)):
        raise FileNotFoundError(f"no such scene file: {os.fspath(scene)}")
    if screenshot is None and not _has_display():
        raise RuntimeError("no display to open a window on (DISPLAY is not set): use --screenshot out.png to "
                           "render offscreen, or run under X (e.g. xvfb-run)")
    if screenshot is not None:
        _ensure_offscreen_gl()
    sf = scene if isinstance(scene, SceneFile) else load_scene(scene, backend=backend, progress=progress)
    v = Viewer(sf, size=size, backend=backend, off_screen=screenshot is not None, progress=progress,
               render_scale=render_scale)
    try:
        if screenshot is not None:
            return v.screenshot(screenshot)
        v.show()
        return None
    finally:
        v.close()
