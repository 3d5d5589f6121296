"""The bi-scale editor's state, headless: a tile's parameters (or a painted height field), its small-scale
materials, the bake's quality and the light, and the large-scale frame they give (Wu 2011 §4, Iwasaki
2012 §6). `editor_gui` draws a window around it; scripts and tests drive it directly:

    ed = wb.Editor("pyramid", backend="auto", width=640, height=480)
    ed.parameters()                    # names, ranges, current values
    ed.set("tile.height", 0.8)         # re-bakes the geometry, re-renders -> "bake"
    ed.set("material0.exponent", 300)  # new small-scale BRDFs on the same bake -> "materials"
    ed.set("light.elevation", 30)      # a new frame only -> "render"
    ed.frame()                         # (H, W, 3) float32 radiance; ed.image8() for display
    ed.undo(); ed.save("design.toml")  # a scene file `warp-biscale render` reads

Every change is checked before anything is replaced: a bad value raises a one-line ValueError naming the
parameter and leaves the editor as it was. A geometry change may be `coarse` (fewer facets, directions and
lobes: what a dragged slider shows); `refine()` then bakes at full quality.
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from . import geometry, images
from .bake import bake
from .brdf import AnisotropicWard, AshikhminShirley, BlinnPhong, CookTorrance, Lambert, Ward
from .device import one_line
from .io import atomic_path, check_output
from .render import OCCLUSION_SAMPLES, frame_lights, render, static_inputs
from .scene import Camera, DirectionalLight, Mesh, Scene
from .environment import Environment
from .smallscale import SmallScale

__all__ = ["Editor", "Parameter", "FAMILIES"]


@dataclass
class Parameter:
    """One control: `kind` "real" | "int" | "choice" | "rgb" | "bool"; `lo`/`hi` for numbers, `choices` for a
    choice; `rebake`: changing it bakes the geometry again."""

    name: str
    group: str
    kind: str
    value: object
    lo: float | None = None
    hi: float | None = None
    choices: tuple | None = None
    rebake: bool = False
    help: str = ""


N_MATERIALS = 2  # small-scale materials a design has: every family can put either on each of its parts
HEIGHTS = 64  # a painted height field's grid (its vertices: HEIGHTS² per period)

# Each family's controls: (name, kind, lo, hi or choices, default, help). Ranges are what every value in
# them bakes to a valid tile with (tests/test_editor.py sets each to both ends).
_MAT = ("int", 0, N_MATERIALS - 1)
HEIGHTFIELD_AMPLITUDE_MAX = 0.5  # the painted field's amplitude control's range is [0, this]
FAMILIES = {
    "pyramid": [
        ("height", "real", 0.05, 2.0, 0.5, "apex height (base side 1)"),
        ("sides", "int", 3, 8, 4, "lateral faces"),
        ("rotation", "real", 0.0, math.pi / 2, 0.0, "base rotation about z, radians"),
        ("base_fraction", "real", 0.2, 1.0, 1.0, "base circumradius / half the tile side"),
        ("material", *_MAT, 0, "small-scale material of the faces"),
        ("base_material", *_MAT, 1, "small-scale material of the ground around the base"),
        ("color", "rgb", None, None, (1.0, 0.75, 0.3), "colour weight of the faces"),
        ("base_color", "rgb", None, None, (0.55, 0.1, 0.07), "colour weight of the ground"),
    ],
    "grooves": [
        ("depth", "real", 0.05, 2.0, 0.5, "groove depth (period 1)"),
        ("profile", "choice", None, ("v", "u"), "v", "V walls or a half ellipse"),
        ("flat_fraction", "real", 0.0, 0.9, 0.0, "share of the period that is flat land"),
        ("axis", "choice", None, ("x", "y"), "x", "direction the grooves run in"),
        ("material", *_MAT, 0, "small-scale material of the land"),
        ("wall_material", *_MAT, 1, "small-scale material of the walls"),
        ("color", "rgb", None, None, (1.0, 1.0, 1.0), "colour weight of the land"),
        ("wall_color", "rgb", None, None, (0.8, 0.5, 0.3), "colour weight of the walls"),
    ],
    "rods": [
        ("radius", "real", 0.02, 0.2, 0.1, "rod radius (spacing 0.5)"),
        ("length", "real", 0.1, 1.5, 0.5, "rod length along its axis"),
        ("count", "int", 1, 4, 2, "rods per tile side"),
        ("lean", "real", 0.0, 1.0, 0.0, "mean axis' tilt, as a share of the largest that keeps a rod in its cell"),
        ("azimuth", "real", 0.0, 2 * math.pi, 0.0, "mean axis' azimuth, radians"),
        ("spread", "real", 0.0, 0.5, 0.0, "largest random deviation of an axis, radians"),
        ("material", *_MAT, 0, "small-scale material of the rods"),
        ("ground_material", *_MAT, 1, "small-scale material of the ground"),
        ("color", "rgb", None, None, (0.9, 0.2, 0.25), "colour weight of the rods"),
        ("ground_color", "rgb", None, None, (0.2, 0.05, 0.05), "colour weight of the ground"),
    ],
    "woven": [
        ("warp_width", "real", 0.2, 0.95, 0.8, "warp thread width (spacing 1)"),
        ("weft_width", "real", 0.2, 0.95, 0.8, "weft thread width"),
        ("warp_height", "real", 0.05, 0.6, 0.2, "warp thread thickness"),
        ("weft_height", "real", 0.05, 0.6, 0.2, "weft thread thickness"),
        ("warp_material", *_MAT, 0, "small-scale material of the warp"),
        ("weft_material", *_MAT, 1, "small-scale material of the weft"),
        ("warp_color", "rgb", None, None, (0.9, 0.25, 0.2), "colour weight of the warp"),
        ("weft_color", "rgb", None, None, (0.2, 0.35, 0.9), "colour weight of the weft"),
    ],
    "heightfield": [
        ("amplitude", "real", 0.0, HEIGHTFIELD_AMPLITUDE_MAX, 0.15, "height of the painted field's unit (tile side 1)"),
        ("smoothing", "real", 0.0, 4.0, 0.0, "Gaussian blur of the field, in grid cells"),
        ("material", *_MAT, 0, "small-scale material of the field"),
        ("color", "rgb", None, None, (1.0, 1.0, 1.0), "colour weight of the field"),
    ],
}
# The command line's and scene files' tile names that are a family with fixed settings.
ALIASES = {"pentagon": ("pyramid", {"sides": 5}), "vgroove": ("grooves", {"profile": "v"}),
           "ugroove": ("grooves", {"profile": "u"})}

# (The anisotropic two, in the frame of the tile's face tangents, only through the ASG bake: `_check_design`.)
BRDF_KINDS = ("lambert", "blinnphong", "cooktorrance", "ward", "anisotropicward", "ashikhminshirley")
ANISOTROPIC_KINDS = ("anisotropicward", "ashikhminshirley")
# A small-scale material's controls by kind: (name, kind, lo, hi, help); kd/ks are RGB.
BRDF_PARAMS = {
    "lambert": [("kd", "rgb", None, None, "albedo")],
    "blinnphong": [("kd", "rgb", None, None, "diffuse albedo"), ("ks", "rgb", None, None, "specular colour"),
                   ("exponent", "real", 1.0, 2000.0, "Blinn-Phong exponent")],
    "cooktorrance": [("kd", "rgb", None, None, "diffuse albedo"), ("ks", "rgb", None, None, "specular colour"),
                     ("roughness", "real", 0.03, 1.0, "Beckmann roughness m"), ("f0", "real", 0.0, 1.0, "Fresnel F0")],
    "ward": [("kd", "rgb", None, None, "diffuse albedo"), ("ks", "rgb", None, None, "specular colour"),
             ("alpha", "real", 0.03, 1.0, "Ward roughness")],
    "anisotropicward": [("kd", "rgb", None, None, "diffuse albedo"), ("ks", "rgb", None, None, "specular colour"),
                        ("alpha_x", "real", 0.03, 1.0, "Ward roughness along the facets' tangents"),
                        ("alpha_y", "real", 0.03, 1.0, "Ward roughness across them")],
    "ashikhminshirley": [("kd", "rgb", None, None, "diffuse reflectance Rd"),
                         ("ks", "rgb", None, None, "specular reflectance Rs at normal incidence"),
                         ("nu", "real", 1.0, 10000.0, "Phong exponent towards the facets' tangents"),
                         ("nv", "real", 1.0, 10000.0, "Phong exponent across them")],
}
DEFAULT_MATERIALS = [
    {"kind": "blinnphong", "kd": (0.2, 0.2, 0.2), "ks": (0.8, 0.8, 0.8), "exponent": 256.0, "roughness": 0.2,
     "f0": 0.9, "alpha": 0.2, "alpha_x": 0.1, "alpha_y": 0.4, "nu": 20.0, "nv": 400.0},
    {"kind": "lambert", "kd": (0.6, 0.6, 0.6), "ks": (0.5, 0.5, 0.5), "exponent": 64.0, "roughness": 0.3,
     "f0": 0.05, "alpha": 0.3, "alpha_x": 0.1, "alpha_y": 0.4, "nu": 20.0, "nv": 400.0},
]
QUALITY = [
    ("lobes", "int", 1, 32, 8, True, "J: SG lobes of the normal distribution"),
    ("facets_log2", "int", 10, 20, 16, True, "log2 of the facets sampled on the tile"),
    ("directions", "int", 4, 16, 12, True, "K: the K x K direction grid of the tables"),
    ("bake", "choice", None, ("sg", "asg", "matrix"), "sg", True,
     "bake method: SG lobes (Iwasaki), ASG lobes (Xu) or the matrix method (Wu); the last drawn by the "
     "lit-sphere renderer"),
    ("method", "choice", None, ("sg", "litsphere"), "sg", False, "large-scale renderer of an SG or ASG bake"),
]
COARSE = {"lobes": 4, "facets_log2": 12, "directions": 6}  # a dragged slider's bake: each at most this
COARSE_SCALE = 4  # ... and, on a CPU, its frame: rendered at 1/4 of the width and height, shown enlarged (on a
# GPU the whole frame costs less than a G-buffer traced anew at another size: a coarse edit keeps it)
# The full bake's defaults on a CPU: a 2^16-facet, K = 12 bake takes ~2.6 s on 2 cores, past an
# interactive editor's "full quality within a couple of seconds"; 2^14 facets and K = 8 take ~0.5 s.
CPU_QUALITY = {"facets_log2": 14, "directions": 8}
LITSPHERE_RESOLUTION = 256  # the lit-sphere renderer's images of the design: an editor's frame, not a print
LIGHT = [
    ("elevation", "real", 5.0, 90.0, 45.0, "sun elevation, degrees"),
    ("azimuth", "real", 0.0, 360.0, 35.0, "sun azimuth, degrees"),
    ("intensity", "real", 0.0, 10.0, 3.0, "sun irradiance"),
    ("environment", "choice", None, ("sky", "studio", "constant", "none"), "sky", "what lights the rest"),
]


def _rgb(name, value):
    try:
        v = np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an RGB triple of numbers, got {value!r}") from None
    if v.size == 1:
        v = np.repeat(v, 3)
    if v.size != 3 or not np.all(np.isfinite(v)) or v.min() < 0 or v.max() > 1:
        raise ValueError(f"{name} must be an RGB triple in [0, 1], got {value!r}")
    return tuple(float(x) for x in v)


def _checked(name, kind, lo, hi, value):
    """`value` as the control's type, or a one-line ValueError naming the control."""
    if kind == "rgb":
        return _rgb(name, value)
    if kind == "choice":
        if value not in hi:
            raise ValueError(f"{name} must be one of {', '.join(map(str, hi))}, got {value!r}")
        return value
    if kind == "bool":
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False, got {value!r}")
        return bool(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if kind == "int":
        if v != round(v):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        v = int(round(v))
    if not (lo <= v <= hi):
        raise ValueError(f"{name} must lie in [{lo:g}, {hi:g}], got {value!r}")
    return v


ROD_SPACING = 0.5


def rod_tilt(p: dict) -> float:
    """The rods' mean tilt (radians) for a `lean` in [0, 1]: lean × the largest tilt whose top stays
    clear of the cell's edge with a margin, L·sin θ + r ≤ 0.45·spacing (what geometry.rods needs, and
    then some), at most 1.2 rad (its cap well off the ground)."""
    room = (0.45 * ROD_SPACING - p["radius"]) / p["length"]
    return p["lean"] * min(math.asin(min(max(room, 0.0), 1.0)), 1.2)


def _brdf(m: dict):
    """The Brdf a material's controls describe."""
    if m["kind"] == "lambert":
        return Lambert(m["kd"])
    if m["kind"] == "blinnphong":
        return BlinnPhong(m["ks"], m["exponent"], kd=m["kd"], normalization="energy")
    if m["kind"] == "cooktorrance":
        return CookTorrance(m["ks"], m["roughness"], kd=m["kd"], f0=m["f0"])
    if m["kind"] == "anisotropicward":
        return AnisotropicWard(m["ks"], m["alpha_x"], m["alpha_y"], kd=m["kd"])
    if m["kind"] == "ashikhminshirley":
        return AshikhminShirley(rs=m["ks"], nu=m["nu"], nv=m["nv"], rd=m["kd"])
    return Ward(m["ks"], m["alpha"], kd=m["kd"])


def _check_design(state) -> None:
    """A one-line error for what no bake can make: an anisotropic small-scale BRDF (each facet in its own tangent
    frame) is convolved per lobe by the ASG bake alone."""
    if state["quality"]["bake"] != "asg":
        for i, m in enumerate(state["materials"]):
            if m["kind"] in ANISOTROPIC_KINDS:
                raise ValueError(f"material{i}.kind {m['kind']!r} is anisotropic: only the ASG bake takes it, not "
                                 f"quality.bake {state['quality']['bake']!r}: set quality.bake to 'asg', or "
                                 f"material{i}.kind to an isotropic kind")


def brdf_spec(m: dict) -> str:
    """The command line's --brdf text of a material's controls (`brdf.parse_brdf` reads it back)."""
    def rgb(v):
        return "/".join(f"{x:.6g}" for x in v)
    if m["kind"] == "lambert":
        return f"lambert:albedo={rgb(m['kd'])}"
    if m["kind"] == "blinnphong":
        return f"blinnphong:ks={rgb(m['ks'])},exponent={m['exponent']:.6g},kd={rgb(m['kd'])},normalization=energy"
    if m["kind"] == "cooktorrance":
        return f"cooktorrance:ks={rgb(m['ks'])},roughness={m['roughness']:.6g},f0={m['f0']:.6g},kd={rgb(m['kd'])}"
    if m["kind"] == "anisotropicward":
        return f"ward:ks={rgb(m['ks'])},alpha_x={m['alpha_x']:.6g},alpha_y={m['alpha_y']:.6g},kd={rgb(m['kd'])}"
    if m["kind"] == "ashikhminshirley":
        return f"as:rs={rgb(m['ks'])},nu={m['nu']:.6g},nv={m['nv']:.6g},rd={rgb(m['kd'])}"
    return f"ward:ks={rgb(m['ks'])},alpha={m['alpha']:.6g},kd={rgb(m['kd'])}"


def _blur(h: np.ndarray, sigma: float) -> np.ndarray:
    """Periodic Gaussian blur of a height field (sigma in grid cells), by FFT."""
    if sigma <= 0:
        return h
    n, m = h.shape
    ky = np.fft.fftfreq(n)[:, None]
    kx = np.fft.fftfreq(m)[None, :]
    return np.real(np.fft.ifft2(np.fft.fft2(h) * np.exp(-2 * (np.pi * sigma) ** 2 * (kx**2 + ky**2))))


def _brush(n: int, x: float, y: float, radius: float) -> np.ndarray:
    """(n, n) weights of a round brush at (x, y) in tile coordinates [0, 1]² (row i is y = i/n), radius in
    tile units, wrapping across the period; (1 − (d/r)²)², exactly 0 at and past the radius."""
    c = np.arange(n) / n
    dx = np.abs(c[None, :] - x)
    dy = np.abs(c[:, None] - y)
    dx, dy = np.minimum(dx, 1 - dx), np.minimum(dy, 1 - dy)
    q = (dx**2 + dy**2) / radius**2
    return np.where(q < 1, (1 - q) ** 2, 0.0)


_BALL: dict = {}
# (backend name, id of the mesh) → the key (renderer, frame size, light) of the last frame shaded on that mesh's
# device copy. An editor shades only its design's pixels over a frame of the same key: every other pixel is
# then what it would shade itself (the ball mesh, its floor and camera are shared by every editor).
_SHADED: dict = {}


def default_scene(width: int, height: int) -> tuple[Mesh, Camera]:
    """A material ball: a sphere in the design (material 0) on a floor (material 1). The mesh is made once
    a process: its sky-visibility field (SSDF) and BVH are cached on it, so a second editor starts at once."""
    if "mesh" not in _BALL:
        _BALL["mesh"] = Mesh.merge([Mesh.sphere(1.0, (0.0, 1.0, 0.0), subdivisions=4, material=0),
                                    Mesh.plane(12.0, 0.0, 16, material=1)])
    return _BALL["mesh"], Camera(eye=(0.0, 2.4, 4.6), target=(0.0, 0.9, 0.0), fov=35.0, width=width, height=height)


class Editor:
    """A bi-scale design and its frame (module docstring). `target`: a family of FAMILIES or an alias
    (pentagon, vgroove, ugroove), "heightfield", a greyscale image (a height field to paint on), or a
    mesh file (its geometry fixed: materials, quality and light only). `backend`: where bakes and
    renders run."""

    def __init__(self, target="pyramid", *, backend="auto", width: int = 640, height: int = 480):
        from .backend import get_backend  # the editor holds one backend for its whole session

        if isinstance(width, bool) or not isinstance(width, int) or not (16 <= width <= 8192):
            raise ValueError(f"width must be an integer in [16, 8192], got {width!r}")
        if isinstance(height, bool) or not isinstance(height, int) or not (16 <= height <= 8192):
            raise ValueError(f"height must be an integer in [16, 8192], got {height!r}")
        self.backend = get_backend(backend)
        self.width, self.height = width, height
        self.mesh_tile = None
        state = {"family": None, "tile": {}, "heights": None,
                 "materials": copy.deepcopy(DEFAULT_MATERIALS),
                 "quality": {name: default for name, _, _, _, default, _, _ in QUALITY},
                 "light": {name: default for name, _, _, _, default, _ in LIGHT}}
        spec = check_target(target)
        if spec.lower().endswith(".toml"):
            raise ValueError(f"Editor target {spec} is a scene file: open a saved design with Editor.load({spec!r})")
        family, fixed = ALIASES.get(spec, (spec, {}))
        if family in FAMILIES:
            state["family"] = family
            state["tile"] = {name: default for name, _, _, _, default, _ in FAMILIES[family]}
            state["tile"].update(fixed)
            if family == "heightfield":
                state["heights"] = geometry.relief_heights(HEIGHTS)
        elif os.path.isfile(spec) and spec.lower().endswith(geometry.IMAGE_SUFFIXES):
            state["family"] = "heightfield"
            state["tile"] = {name: default for name, _, _, _, default, _ in FAMILIES["heightfield"]}
            state["heights"] = geometry.read_height_image(spec)  # its checks and one-line errors
        else:
            self.mesh_tile = SmallScale.load(spec)
            self.mesh_path = os.path.abspath(spec)
        if not getattr(self.backend, "is_gpu", False):
            state["quality"].update(CPU_QUALITY)
        self._state = state
        self._undo: list = []
        self._step = None  # the undo depth where begin_step was called
        self._redo: list = []
        self.timings: dict = {}
        self._coarse = False  # the bake is a coarse one (refine bakes it fully)
        self._coarse_frame = False  # the frame was rendered at 1/COARSE_SCALE size (refine renders it fully)
        self._frame_buffers = {}  # (height, width) → the host frames read back into, in turn
        self._floor = Lambert(0.45)
        self.tile = self.effective = self._image = self._shown = self.scene = None
        self.mesh, self.camera = default_scene(width, height)
        self._build(state, "bake", coarse=False)

    # ------------------------------------------------------------------ what can be changed
    @property
    def family(self):
        return self._state["family"]

    @property
    def heights(self):
        h = self._state["heights"]
        return None if h is None else h.copy()

    @property
    def materials(self) -> list:
        return [_brdf(m) for m in self._state["materials"]]

    def _controls(self, state) -> dict:
        """name → (group, kind, lo, hi-or-choices, rebake, help, getter path)."""
        out = {}
        if state["family"] is not None:
            for name, kind, lo, hi, _, hlp in FAMILIES[state["family"]]:
                out[f"tile.{name}"] = ("tile", kind, lo, hi, True, hlp, ("tile", name))
        for i, m in enumerate(state["materials"]):
            out[f"material{i}.kind"] = (f"material {i}", "choice", None, BRDF_KINDS, False,
                                        "small-scale BRDF", ("materials", i, "kind"))
            for name, kind, lo, hi, hlp in BRDF_PARAMS[m["kind"]]:
                out[f"material{i}.{name}"] = (f"material {i}", kind, lo, hi, False, hlp, ("materials", i, name))
        for name, kind, lo, hi, _, rebake, hlp in QUALITY:
            out[f"quality.{name}"] = ("quality", kind, lo, hi, rebake, hlp, ("quality", name))
        for name, kind, lo, hi, _, hlp in LIGHT:
            out[f"light.{name}"] = ("light", kind, lo, hi, False, hlp, ("light", name))
        return out

    def parameters(self) -> list:
        """Every control of the current design, with its range and value."""
        out = []
        for name, (group, kind, lo, hi, rebake, hlp, path) in self._controls(self._state).items():
            choices = hi if kind == "choice" else None
            number = kind in ("real", "int")
            out.append(Parameter(name, group, kind, self._lookup(self._state, path), lo if number else None,
                                 hi if number else None, choices, rebake, hlp))
        return out

    @staticmethod
    def _lookup(state, path):
        v = state
        for p in path:
            v = v[p]
        return v

    def get(self, name: str):
        controls = self._controls(self._state)
        if name not in controls:
            raise ValueError(f"no parameter {name!r}; the design has {', '.join(controls)}")
        return self._lookup(self._state, controls[name][-1])

    # ------------------------------------------------------------------ changes
    def set(self, name: str, value, coarse: bool = False) -> str:
        """Set one control; → what was redone: "bake" (the geometry), "materials" (new small-scale BRDFs on
        the same bake), "render" (the frame only) or "none". `coarse`: a geometry change bakes at COARSE
        quality (`refine` bakes it fully). A bad name or value: ValueError, nothing changed."""
        return self.set_many({name: value}, coarse)

    def set_many(self, values: dict, coarse: bool = False) -> str:
        """Set several controls at once (one bake and one frame), in order (a material's kind first makes
        its controls exist); → as `set`. Every value is checked before anything changes."""
        state = copy.deepcopy(self._state)
        redo = "none"
        rank = {"none": 0, "render": 1, "materials": 2, "bake": 3}
        for name, value in values.items():
            controls = self._controls(state)
            if name not in controls:
                raise ValueError(f"no parameter {name!r}; the design has {', '.join(controls)}")
            group, kind, lo, hi, rebake, _, path = controls[name]
            value = _checked(name, kind, lo, hi, value)
            target = state
            for p in path[:-1]:
                target = target[p]
            if target[path[-1]] == value:
                continue
            target[path[-1]] = value
            this = "bake" if rebake else "materials" if group.startswith("material") else "render"
            redo = max(redo, this, key=rank.get)
        if redo == "none":
            return "none"
        return self._apply(state, redo, coarse)

    def refine(self) -> bool:
        """After coarse edits, the full-quality bake and frame; False when the bake already is."""
        if self._coarse:
            self._build(self._state, "bake", coarse=False)
        elif self._coarse_frame:
            self._build(self._state, "render", coarse=False)
        else:
            return False
        return True

    def paint(self, x: float, y: float, radius: float, strength: float, coarse: bool = False) -> str:
        """Raise (strength > 0) or lower (< 0) the painted height field round (x, y) ∈ [0, 1]² (tile
        coordinates, wrapping), brush `radius` in tile units (0, 0.5]; heights beyond the radius are
        unchanged. Then re-bake."""
        h = self._painted("paint", x, y, radius, strength, (-1.0, 1.0))
        w = _brush(len(h), x, y, radius)
        state = copy.deepcopy(self._state)
        state["heights"] = h + strength * w
        return self._apply(state, "bake", coarse)

    def smooth(self, x: float, y: float, radius: float, strength: float, coarse: bool = False) -> str:
        """Blend the height field round (x, y) towards its blur (strength ∈ [0, 1]), as `paint`."""
        h = self._painted("smooth", x, y, radius, strength, (0.0, 1.0))
        w = strength * _brush(len(h), x, y, radius)
        state = copy.deepcopy(self._state)
        state["heights"] = (1 - w) * h + w * _blur(h, max(1.0, radius * len(h) / 2))
        return self._apply(state, "bake", coarse)

    def _painted(self, what, x, y, radius, strength, strength_range):
        if self._state["heights"] is None:
            raise ValueError(f"{what}: only a height field can be painted; this design is "
                             f"{self.family or 'a mesh file'}")
        _checked(f"{what} x", "real", 0.0, 1.0, x)
        _checked(f"{what} y", "real", 0.0, 1.0, y)
        if _checked(f"{what} radius", "real", 0.0, 0.5, radius) <= 0:
            raise ValueError(f"{what} radius must be > 0, got {radius!r}")
        _checked(f"{what} strength", "real", *strength_range, strength)
        return self._state["heights"]

    def _apply(self, state, redo, coarse) -> str:
        previous = self._state
        self._build(state, redo, coarse)  # raises before anything is replaced
        self._undo.append(previous)
        self._redo.clear()
        return redo

    def begin_step(self) -> None:
        """Every change until `end_step` becomes one undo step (a dragged slider's coarse edits, a brush
        stroke's dabs). Nested calls count as the outermost."""
        if self._step is None:
            self._step = len(self._undo)

    def end_step(self) -> None:
        depth, self._step = self._step, None
        if depth is not None and len(self._undo) > depth + 1:
            del self._undo[depth + 1:]  # each change pushed the state before it; the first is the step's start

    @property
    def in_step(self) -> bool:
        return self._step is not None

    def undo(self) -> bool:
        if not self._undo:
            return False
        state = self._undo.pop()
        self._redo.append(self._state)
        self._build(state, "bake", coarse=False)
        return True

    def redo(self) -> bool:
        if not self._redo:
            return False
        state = self._redo.pop()
        self._undo.append(self._state)
        self._build(state, "bake", coarse=False)
        return True

    # ------------------------------------------------------------------ building
    def _tile(self, state) -> SmallScale:
        if state["family"] is None:
            return self.mesh_tile
        p = dict(state["tile"])
        fam = state["family"]
        if fam == "heightfield":
            # The tile of the 16-bit image a save writes, so that the saved design renders what the editor shows:
            # the lobe fit can move by a few per cent when one facet crosses a bin (a float64 field differed
            # from its PNG by 1.6e-6 of a height, and the two bakes by 6 % of f̄'s peak).
            drawn = _blur(state["heights"], p["smoothing"])
            return geometry.heightfield(_height_levels(drawn)[::-1] / 65535.0, scale=_height_scale(p, drawn),
                                        material=p["material"], color=p["color"])
        if fam == "rods":
            return geometry.rods(radius=p["radius"], spacing=ROD_SPACING, length=p["length"], count=p["count"],
                                 perturbation=p["spread"], orientation=(rod_tilt(p), p["azimuth"]),
                                 material=p["material"], ground_material=p["ground_material"], color=p["color"],
                                 ground_color=p["ground_color"])
        return getattr(geometry, fam)(**p)

    def _quality(self, state, coarse):
        q = dict(state["quality"])
        if coarse:
            q = {k: min(v, COARSE[k]) if k in COARSE else v for k, v in q.items()}
        return q

    def _light_scene(self, state, effective, coarse=False) -> Scene:
        li = state["light"]
        el, az = math.radians(li["elevation"]), math.radians(li["azimuth"])
        direction = (math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az))
        lights = [DirectionalLight(direction, li["intensity"], 1.0)] if li["intensity"] > 0 else []
        env = _environment(li["environment"])
        camera = self.camera
        if self._coarse_frames(coarse):
            camera = Camera(camera.eye, camera.target, camera.up, camera.fov, max(8, self.width // COARSE_SCALE),
                            max(8, self.height // COARSE_SCALE))
        return Scene(self.mesh, [effective, self._floor], camera, env, lights, ssdf_resolution=16)

    def _build(self, state, redo, coarse):
        """Make what `redo` needs from `state`, render, and only then replace the editor's state."""
        _check_design(state)
        t_all = time.perf_counter()
        timings = {"redone": redo}
        tile, effective = self.tile, self.effective
        if redo == "bake" or effective is None:
            t0 = time.perf_counter()
            tile = self._tile(state)
            timings["tile"] = time.perf_counter() - t0
            q = self._quality(state, coarse)
            t0 = time.perf_counter()
            mats = [_brdf(m) for m in state["materials"]][:max(tile.n_materials, 1)]
            effective = bake(tile, mats, method=q["bake"], lobes=q["lobes"], directions=q["directions"],
                             facets=1 << q["facets_log2"], backend=self.backend)
            timings["bake"] = time.perf_counter() - t0
        elif redo == "materials":
            t0 = time.perf_counter()
            effective = effective.with_materials([_brdf(m) for m in state["materials"]][:len(effective.materials)])
            timings["bake"] = time.perf_counter() - t0
        scene = self._light_scene(state, effective, coarse)
        if self.scene is not None and self.scene.materials[0] is effective:
            scene.cache = self.scene.cache  # the same materials, mesh and environment: the static inputs stand
        t0 = time.perf_counter()
        # A geometry or material edit changes the design's pixels only: with the same camera, light and
        # environment as the frame on the device, only those are shaded again.
        key = (_renderer(state), self._coarse_frames(coarse), self.width, self.height,
               tuple(sorted(state["light"].items())))
        shaded = (self.backend.name, id(scene.mesh))
        only = 0 if redo in ("bake", "materials") and _SHADED.pop(shaded, None) == key else None
        timings["shaded"] = "design" if only is not None else "frame"
        shown, image = self._render(scene, _renderer(state), timings, only)
        _SHADED[shaded] = key  # (only once the frame is whole: a failed render leaves no key)
        if self._coarse_frames(coarse):
            shown = _enlarged(shown, self.width, self.height)
        timings["render"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_all
        self._state, self.tile, self.effective, self.scene = state, tile, effective, scene
        self._shown, self._image = shown, image
        if redo == "bake":
            self._coarse = coarse
        self._coarse_frame = self._coarse_frames(coarse)
        self.timings = timings

    def _coarse_frames(self, coarse) -> bool:
        """Whether a coarse edit renders a 1/COARSE_SCALE frame: on a CPU only."""
        return bool(coarse) and not self.backend.is_gpu

    def _render(self, scene, method, timings, only_material=None) -> tuple:
        """→ (the frame for display, (H, W, 3) uint8; its radiance, float32, or None: read when asked). The
        SG frame is shaded and tone-mapped on the device and only its bytes come back; the camera's G-buffer
        and the shadow rays are traced again only when the camera, the lights or the mesh changed."""
        if method == "litsphere":
            image = render(scene, method="litsphere", backend=self.backend, shadow_samples=1,
                           resolution=LITSPHERE_RESOLUTION).image
            return images.tonemap(image), image
        be, cam, lights = self.backend, scene.camera, frame_lights(scene)
        static = static_inputs(scene, be, timings)
        be.trace_primary(scene.mesh, cam, to_host=False, if_changed=True)
        if len(lights):
            be.trace_shadows(scene.mesh, None, lights, to_host=False, samples=1, if_changed=True)
        if static.has_ssdf:  # traced again only when the camera or the mesh moved, as the G-buffer
            be.trace_occlusion(scene.mesh, None, OCCLUSION_SAMPLES, to_host=False, if_changed=True)
            be.trace_lobe_rays(scene.mesh, None, static.sharp_lobes(), to_host=False, if_changed=True)
        # A whole frame keeps each pixel's environment visibility: the design-only shades of later material and
        # geometry edits read it back instead of casting it again.
        be.shade(scene.mesh, static, cam.packed(), lights, to_host=False, only_material=only_material,
                 keep_visibility=True)
        # Two host frames in turn: the one shown stays whole while the next is read back into the other.
        pair = self._frame_buffers.setdefault((cam.height, cam.width), [])
        if len(pair) < 2:
            pair.append(be.frame_buffer(cam.width, cam.height))
        buffer = pair[1] if pair[0] is self._shown else pair[0]
        return be.frame_u8(scene.mesh, cam.width, cam.height, out=buffer), None

    # ------------------------------------------------------------------ output
    def frame(self) -> np.ndarray:
        """(H, W, 3) float32 linear radiance of the current design on the large-scale scene (what `image8`
        shows, before tone mapping)."""
        if self._image is None:  # rendered again: the device's frame may since belong to another editor
            # each pixel its own rays, as the window's frame traces them (_render)
            image = render(self.scene, backend=self.backend, shadow_samples=1, block_rays=False).image
            self._image = _enlarged(image, self.width, self.height) if self._coarse_frame else image
        return self._image.copy()

    def image8(self, exposure: float = 0.0) -> np.ndarray:
        """The frame as the window shows it: (H, W, 3) uint8 sRGB (`images.tonemap`, ACES, `exposure` stops)."""
        if exposure == 0.0:
            return self._shown.copy()
        return images.tonemap(self.frame(), exposure)

    def screenshot(self, path) -> None:
        """The frame as an image file (PNG tone-mapped; EXR/HDR the radiance), written atomically."""
        images.write_image(path, self.frame())

    def save(self, path) -> None:
        """The design as a scene file (`warp-biscale render PATH`, `wb.load_scene`): the tile family and its
        parameters (a painted height field as a 16-bit PNG beside it; a mesh file by its path), the
        small-scale BRDFs, the bake's quality, the light and environment. Written atomically."""
        path = os.fspath(path)
        if not path.lower().endswith(".toml"):
            raise ValueError(f"a design is saved as a scene file: {path} must end in .toml")
        check_output(path)
        stem = os.path.splitext(os.path.basename(path))[0]
        text = _design_toml(self._state, self.width, self.height,
                            None if self.mesh_tile is None else self.mesh_path, f"{stem}_heights.png",
                            self.tile.n_materials)
        folder = os.path.dirname(os.path.abspath(path))
        if self._state["heights"] is not None:
            # the field drawn (smoothed), which `render` reads; with smoothing, the painted one too, for `load`
            smoothing = self._state["tile"]["smoothing"]
            _write_heights(os.path.join(folder, f"{stem}_heights.png"), _blur(self._state["heights"], smoothing))
            if smoothing > 0:
                _write_heights(os.path.join(folder, f"{stem}_painted.png"), self._state["heights"])
        with atomic_path(path) as tmp:
            with open(tmp, "w") as f:
                f.write(text)

    @classmethod
    def load(cls, path, *, backend="auto") -> Editor:
        """An editor on a design `save` wrote (or any scene file whose first bake material is a tile family
        or a mesh file)."""
        from .scenefile import tomllib  # (tomli before Python 3.11)

        path = os.fspath(path)
        try:
            with open(path, "rb") as f:
                text = f.read().decode("utf-8-sig")
            data = tomllib.loads(text)
        except OSError as exc:
            raise ValueError(f"cannot read design {path}: {exc.strerror or exc}") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"design {path} is not valid TOML: {exc}") from None
        mats = data.get("material", {})
        design = next((m for m in mats.values() if isinstance(m, dict) and m.get("type") == "bake"), None)
        if design is None:
            raise ValueError(f"design {path} has no material of type \"bake\" to edit")
        render_ = data.get("render", {})
        size = {"width": render_.get("width", 640), "height": render_.get("height", 480)}
        for key, value in size.items():
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"design {path}: [render] {key} must be an integer, got {value!r}")
        folder = os.path.dirname(os.path.abspath(path))
        tile_spec = design.get("tile", "pyramid")
        params = dict(design.get("tile_params", {}))
        if tile_spec == "heightfield":
            image = os.path.join(folder, params.pop("image"))
            if not os.path.isfile(image):
                raise ValueError(f"design {path}: its height image {image} is missing")
            ed = cls(image, backend=backend, **size)
            scale = float(params.get("scale", 1.0))
            meta = _editor_line(path, text, os.path.basename(image), scale)
            if meta is not None:  # the editor's own: the painted field (before smoothing) and its controls
                smoothing = meta["smoothing"]
                painted = image[:-len("_heights.png")] + "_painted.png" if smoothing > 0 else image
                if not os.path.isfile(painted):
                    raise ValueError(f"design {path}: its painted height image {painted} is missing")
                heights = geometry.read_height_image(painted) * meta["painted_range"]
                amplitude = meta["amplitude"]
            else:  # another scene file's height field: its image at its scale, the amplitude within the control's
                smoothing, amplitude = 0.0, min(scale, HEIGHTFIELD_AMPLITUDE_MAX)
                heights = geometry.read_height_image(image) * (scale / amplitude if amplitude > 0 else 1.0)
            ed._state["heights"] = heights
            params = {"amplitude": amplitude, "smoothing": smoothing, "material": params.get("material", 0),
                      "color": params.get("color", (1, 1, 1))}
        else:
            spec = tile_spec if tile_spec in FAMILIES or tile_spec in ALIASES else os.path.join(folder, tile_spec)
            ed = cls(spec, backend=backend, **size)
        state = copy.deepcopy(ed._state)
        if state["family"] is not None:
            if state["family"] == "rods" and "orientation" in params:
                tilt, params["azimuth"] = params.pop("orientation")
                params["spread"] = params.pop("perturbation", 0.0)
                params.pop("spacing", None)
                largest = rod_tilt({**state["tile"], **params, "lean": 1.0})
                params["lean"] = min(tilt / largest, 1.0) if largest > 0 else 0.0
            controls = ed._controls(state)
            for k, v in params.items():  # each checked as its control checks it: a typo or a bad value is said
                if f"tile.{k}" not in controls:
                    raise ValueError(f"design {path}: the {state['family']} tile has no control {k!r} (tile_params "
                                     f"may hold {', '.join(state['tile'])})")
                _, kind, lo, hi, *_ = controls[f"tile.{k}"]
                try:
                    state["tile"][k] = _checked(f"tile.{k}", kind, lo, hi, tuple(v) if isinstance(v, list) else v)
                except ValueError as exc:
                    raise ValueError(f"design {path}: {exc}") from None
        for i, text in enumerate(design.get("brdf", [])[:N_MATERIALS]):
            try:
                state["materials"][i].update(_material_controls(text))
            except ValueError as exc:
                raise ValueError(f"design {path}: brdf {i}: {exc}") from None
        for key, name in (("lobes", "lobes"), ("directions", "directions")):
            if key in design:
                state["quality"][name] = int(design[key])
        if "facets" in design:
            state["quality"]["facets_log2"] = int(round(math.log2(int(design["facets"]))))
        state["quality"]["bake"] = design.get("method") if design.get("method") in ("asg", "matrix") else "sg"
        state["quality"]["method"] = render_.get("method", "sg") if state["quality"]["bake"] == "sg" else "sg"
        env = data.get("environment")
        state["light"]["environment"] = "none" if env is None else env.get("type", "sky")
        if state["light"]["environment"] not in ("sky", "studio", "constant", "none"):
            state["light"]["environment"] = "sky"
        sun = next((li for li in data.get("light", []) if li.get("type") == "directional"), None)
        if sun is None:
            state["light"]["intensity"] = 0.0
        else:
            d = np.asarray(sun["direction"], np.float64)
            d = d / np.linalg.norm(d)
            state["light"]["elevation"] = float(np.clip(np.degrees(np.arcsin(d[1])), 5.0, 90.0))
            state["light"]["azimuth"] = float(np.degrees(np.arctan2(d[2], d[0])) % 360.0)
            state["light"]["intensity"] = float(np.clip(np.mean(np.atleast_1d(sun.get("irradiance", 1.0))), 0, 10))
        ed._build(state, "bake", coarse=False)
        return ed


def check_target(target) -> str:
    """An editor's target as a string: a tile family (or an alias) or an existing file (an image, a mesh, a saved
    design), else a one-line ValueError; what `Editor` and `edit` check before any bake or window."""
    spec = os.fspath(target) if isinstance(target, os.PathLike) else target
    if not isinstance(spec, str):
        raise ValueError(f"Editor target must be a tile family, an image or a mesh file, got {target!r}")
    if ALIASES.get(spec, (spec, {}))[0] in FAMILIES or os.path.isfile(spec):
        return spec
    if spec.lower().endswith(".toml"):
        raise ValueError(f"cannot read design {spec}: no such file")
    raise ValueError(f"Editor target {spec!r} is neither a tile family ({', '.join([*FAMILIES, *ALIASES])}), "
                     "an image nor an existing mesh file")


def _editor_line(path, text, image_name: str, scale: float):
    """The editor line of a saved height-field design → {amplitude, smoothing, painted_range}, or None where the
    file has none or its tile_params no longer name the image and scale it was written with (a hand edit: the
    scene's own field is then what is edited). A malformed line is a one-line error naming the design."""
    line = next((ln for ln in text.splitlines() if ln.startswith(EDITOR_LINE)), None)
    if line is None:
        return None
    try:
        meta = json.loads(line[len(EDITOR_LINE):])
        out = {k: float(meta[k]) for k in ("amplitude", "smoothing", "painted_range", "scale")}
        written = str(meta["image"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"design {path}: its {EDITOR_LINE.strip()} line is malformed ({one_line(exc)})") from None
    if written != image_name or not math.isclose(out["scale"], scale, rel_tol=1e-12, abs_tol=0.0):
        return None
    return out


def _renderer(state) -> str:
    """The large-scale renderer of a design: the SG renderer reads SG and ASG bakes, not the matrix method's."""
    return "litsphere" if state["quality"]["bake"] == "matrix" else state["quality"]["method"]


def _enlarged(image, width, height) -> np.ndarray:
    """A coarse frame brought to the window's size (bilinear): uint8 RGB at once, float32 per channel."""
    from PIL import Image

    if image.dtype == np.uint8:
        return np.asarray(Image.fromarray(image).resize((width, height), Image.BILINEAR))
    return np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(image[..., c], np.float32))
                                .resize((width, height), Image.BILINEAR)) for c in range(3)], -1).astype(np.float32)


_ENVIRONMENTS: dict = {}


def _environment(kind):
    """The light's environment of this kind, made once a process: its SG fit and prefiltered maps (seconds
    on a CPU) are cached on it, for every editor."""
    if kind not in _ENVIRONMENTS:
        _ENVIRONMENTS[kind] = _make_environment(kind)
    return _ENVIRONMENTS[kind]


def _make_environment(kind):
    if kind == "none":
        return None
    if kind == "constant":
        return Environment.constant(0.5, 16, 32)
    if kind == "studio":
        return Environment.studio(height=64, width=128)
    return Environment.sky(sun_irradiance=0.0, ground=(0.3, 0.28, 0.25), height=64, width=128)


def _height_levels(h) -> np.ndarray:
    """A height field's 16-bit levels as its image stores them: the full range, the top row (y = 1) first."""
    lo, hi = float(h.min()), float(h.max())
    return np.ascontiguousarray(np.round((h - lo) / max(hi - lo, 1e-12) * 65535).astype(np.uint16)[::-1])


def _height_scale(p: dict, drawn) -> float:
    """The tile's height scale of a field stored at the full range (the scene file's tile_params scale)."""
    return p["amplitude"] * float(drawn.max() - drawn.min())


def _write_heights(path, h):
    """A height field as a 16-bit greyscale PNG (`_height_levels`; the scale goes into the scene file's
    tile_params, the painted field's range into its editor line)."""
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(_height_levels(h)).save(tmp, format="PNG")  # uint16: a 16-bit greyscale PNG


def _material_controls(text) -> dict:
    from .brdf import parse_brdf

    b = parse_brdf(text)
    out = {"kind": {Lambert: "lambert", BlinnPhong: "blinnphong", CookTorrance: "cooktorrance", Ward: "ward",
                    AnisotropicWard: "anisotropicward", AshikhminShirley: "ashikhminshirley"}[type(b)]}
    if isinstance(b, Lambert):
        out["kd"] = tuple(float(x) for x in b.albedo)
        return out
    out["kd"] = tuple(float(x) for x in b.kd)
    out["ks"] = tuple(float(x) for x in b.ks)
    for name in ("exponent", "roughness", "f0", "alpha", "alpha_x", "alpha_y", "nu", "nv"):
        if hasattr(b, name):
            out[name] = float(getattr(b, name))
    return out


def _toml_value(v):
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (tuple, list, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))


# A saved height-field design's controls that the scene file cannot hold (the field's amplitude and smoothing, the
# painted field's range): a comment `Editor.load` reads back, which `render` skips.
EDITOR_LINE = "# editor: "


def _design_toml(state, width, height, mesh_path, heights_name, n_brdfs: int = N_MATERIALS) -> str:
    q, li = state["quality"], state["light"]
    fam = state["family"]
    editor_line = []
    if fam is None:
        tile, params = mesh_path, {}
    elif fam == "heightfield":
        p, painted = state["tile"], state["heights"]
        drawn = _blur(painted, p["smoothing"])
        tile = "heightfield"
        params = {"image": heights_name, "scale": _height_scale(p, drawn),
                  "material": p["material"], "color": p["color"]}
        editor_line = [EDITOR_LINE + json.dumps({"amplitude": p["amplitude"], "smoothing": p["smoothing"],
                                                 "painted_range": float(painted.max() - painted.min()),
                                                 "image": heights_name, "scale": params["scale"]})]
    elif fam == "rods":
        p = state["tile"]
        tile = "rods"
        params = {"radius": p["radius"], "spacing": ROD_SPACING, "length": p["length"], "count": p["count"],
                  "perturbation": p["spread"], "orientation": (rod_tilt(p), p["azimuth"]), "material": p["material"],
                  "ground_material": p["ground_material"], "color": p["color"], "ground_color": p["ground_color"]}
    else:
        tile, params = fam, state["tile"]
    el, az = math.radians(li["elevation"]), math.radians(li["azimuth"])
    direction = (math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az))
    lines = ["# A bi-scale design saved by warp_biscale's editor: `warp-biscale render` draws it,",
             "# `warp-biscale edit` opens it again.", *editor_line, "[render]", f"width = {width}",
             f"height = {height}",
             f'method = "{_renderer(state)}"', "ssdf_resolution = 16", "", "[camera]", "eye = [0.0, 2.4, 4.6]",
             "target = [0.0, 0.9, 0.0]", "fov = 35.0", ""]
    env = li["environment"]
    if env == "sky":
        lines += ["[environment]", 'type = "sky"', "sun_irradiance = 0.0", "ground = [0.3, 0.28, 0.25]",
                  "height = 64", "width = 128", ""]
    elif env == "studio":
        lines += ["[environment]", 'type = "studio"', "height = 64", "width = 128", ""]
    elif env == "constant":
        lines += ["[environment]", 'type = "constant"', "radiance = 0.5", "height = 16", "width = 32", ""]
    if li["intensity"] > 0:
        lines += ["[[light]]", 'type = "directional"', f"direction = {_toml_value(direction)}",
                  f"irradiance = {_toml_value(float(li['intensity']))}", "angular_radius = 1.0", ""]
    lines += ["[[object]]", 'mesh = "sphere"', "radius = 1.0", "center = [0.0, 1.0, 0.0]", "subdivisions = 4",
              'material = "design"', "", "[[object]]", 'mesh = "plane"', "size = 12.0", "divisions = 16",
              'material = "floor"', "", "[material.design]", 'type = "bake"', f"tile = {_toml_value(tile)}"]
    if params:
        lines.append("tile_params = { " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in params.items()) + " }")
    lines += ["brdf = [" + ", ".join(f'"{brdf_spec(m)}"' for m in state["materials"][:max(n_brdfs, 1)]) + "]",
              f"lobes = {q['lobes']}", f"directions = {q['directions']}", f"facets = {1 << q['facets_log2']}",
              *([f'method = "{q["bake"]}"'] if q["bake"] != "sg" else []), "",
              "[material.floor]", 'type = "lambert"', "albedo = 0.45", ""]
    return "\n".join(lines)
