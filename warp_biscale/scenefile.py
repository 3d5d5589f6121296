"""TOML scene files: a whole render job — objects, materials (analytic, baked at load time, or read
from a ``.wbm`` file), lights, environment, camera and render settings — in one text file.

    sf = load_scene("examples/bi-scale.toml")       # → SceneFile (bakes what needs baking)
    sf.scene                                        # the render.Scene
    result = sf.render()                            # render with the file's [render] settings
    result.save("out.png", exposure=sf.exposure)
    sf.tiles["gold"]                                # the SmallScale tile each baked material came from

or ``warp-biscale render scene.toml -o out.png``. Every table and key is optional except where marked
*required*; defaults are those of the Python constructors they feed. A full example::

    [render]
    width = 640                  # image size in pixels (default 512 × 512)
    height = 480
    method = "sg"                # "sg" (per-pixel SG shading), "mc" (Monte Carlo reference) or "litsphere"
    samples = 64                 # mc only: samples per pixel (>= 2); seed = 0 too
    exposure = 0.0               # stops, applied when writing a PNG
    aa = 4                       # sg and litsphere: anti-aliasing samples a pixel (default: the CLI's 4, render()'s 1)
    shadow_samples = 16          # sg and litsphere: shadow rays a light and pixel (1: hard shadows)
    occlusion_samples = 16       # sg: environment-occlusion rays a pixel (0: the SSDF alone)
    block_rays = "auto"          # sg: true/false or a block side 1, 2, 4 (pixels sharing their rays; "auto": by size)
    env_lobes = 9                # SG lobes fitted to the environment (diffuse term), 1..16
    ssdf_resolution = 32         # SSDF directions per side (2..128); ssdf_terms: PCA terms (16, at most resolution²)
    backend = "auto"             # auto, warp, warp:cpu, warp:cuda, opencl, opencl:cpu, opencl:gpu, opencl:<name>

    [camera]                     # no [camera] / no eye: framed on the objects' bounding sphere
    eye = [0.0, 1.6, 4.2]
    target = [0.0, 0.3, 0.0]     # default: the centre of the objects' bounds
    up = [0.0, 1.0, 0.0]
    fov = 40.0                   # vertical, degrees

    [environment]                # type: "sky" | "studio" | "constant" | "file" | "sgs" | "none"
    type = "sky"                 # + Environment.sky's parameters:
    sun_direction = [0.5, 0.7, 0.4]
    sun_angular_radius = 2.0     # sun_irradiance / sun_radiance, sky_zenith, sky_horizon, ground,
    height = 64                  # height, width, sun_edge, supersample
    width = 128
    # type = "file": path = "studio.hdr" (relative to this file) ; every type: scale = 1.0 multiplies it
    # type = "constant": radiance ; type = "studio": background, lights = [{direction = [..],
    #   half_width = 20, half_height = 10, radiance = 5.0}, ...] ; type = "sgs": axes, sharpness,
    #   amplitudes, constant

    [[light]]                    # any number of them
    type = "point"               # "point": position, intensity (W/sr, RGB or scalar), radius
    position = [2.0, 4.0, 3.0]
    intensity = 20.0
    radius = 0.1
    [[light]]
    type = "directional"         # "directional": direction (towards the light), irradiance, angular_radius (deg)
    direction = [-0.3, 1.0, 0.2]
    irradiance = [1.0, 0.95, 0.9]

    [[object]]
    mesh = "torus"               # required: "sphere" | "torus" | "plane" | a mesh file (OBJ/PLY/STL/GLB,
    material = "gold"            #   relative to this file); material: required, a [material.NAME]
    major = 1.0                  # torus: major, minor, center, segments = [96, 48]
    minor = 0.4                  # sphere: radius, center, subdivisions ; plane: size, height, divisions
    translate = [0.0, 0.4, 0.0]  # every object: scale (number), rotate ([x, y, z] degrees, x first),
    rotate = [30.0, 0.0, 0.0]    #   translate, applied in that order
    [[object]]
    mesh = "plane"
    size = 8.0
    material = "floor"

    [material.floor]
    type = "lambert"             # "lambert": albedo ; "blinnphong": ks, exponent, kd, normalization
    albedo = [0.5, 0.5, 0.5]     #   ("iwasaki" | "energy") ; "cooktorrance": ks, roughness, f0, kd ;
                                 #   "ward": ks, alpha, kd ; "anisotropicward": ks, alpha_x, alpha_y, kd ;
                                 #   "ashikhminshirley": rs, nu, nv, rd (both in the frame of the mesh's
                                 #   tangents: the u direction of its UVs)
    kd_map = "floor.png"         # optional maps (svbrdf.Textured, images relative to this file): kd_map,
                                 #   and ks_map, parameter_map (multiplies exponent | roughness | alpha)

    [material.gold]
    type = "bake"                # baked at load time (in memory) by `wb.bake`: the SG bake, or the one `method` names
    tile = "pyramid"             # required: a built-in tile (as `warp-biscale bake` takes), a mesh file, a
                                 #   greyscale image, or "heightfield" (the default relief; with
                                 #   tile_params.image, that image, and scale)
    tile_params = { height = 0.4, color = [1.0, 0.8, 0.4] }   # keyword arguments of the tile's generator
    brdf = ["blinnphong:exponent=256,ks=0.9"]                 # one per tile material id (or one for all);
                                                              #   a MERL file ("paint.binary") is one too
    lobes = 6                    # J, or "auto" ; directions (K), facets, normal_res, method, route, seed
    method = "sg"                # "sg" (default), "sg-exact", "asg", "auto" (SG or ASG, the nearer its facets'
                                 #   exact f̄) or "matrix" (drawn by method = "litsphere"; the SG renderer
                                 #   refuses it)

    [material.steel]
    type = "file"                # a material file written by `warp-biscale bake` / EffectiveBRDF.save
    path = "steel.wbm"           # relative to this file; brdf = [...] optionally swaps its small-scale BRDFs

    [material.paint]
    type = "merl"                # a measured BRDF in MERL's binary format (wb.MeasuredBRDF: the SG renderer
    path = "paint.binary"        #   shades it by its SG fit); or type = "litsphere", path = a folder
                                 #   LitSphere.save wrote, which renders only by method = "litsphere" (which
                                 #   makes every other material a lit sphere)

Errors name the file, the line, the table and the key — ``scene.toml:12: [material.gold] exponent
must be a number, got 'high'`` — for TOML syntax errors, unknown tables and keys (a typo never passes
silently), wrong types, missing required keys, undefined materials, missing files and bad values (sizes
<= 0, nan, inf, settings out of range). The warnings of a material that reflects more light than it
receives (`brdf.EnergyWarning`) and of BRDFs beyond a tile's material ids (`TileWarning`) name them too.
"""

from __future__ import annotations

import inspect
import math
import os
import re
import time
from dataclasses import dataclass, field

import numpy as np

from . import brdf as brdf_mod
from . import geometry
from .backend import get_backend
from .bake import bake
from .brdf import Lambert, parse_brdf
from .geometry import BUILTIN_TILES
from .effective import EffectiveBRDF
from .environment import Environment, Softbox
from .images import check_exposure
from .device import one_line
from .litsphere import LitSphere
from .loading import load
from .measured import MeasuredBRDF, small_scale_brdf
from .progress import as_progress
from .render import METHODS, check_aa, check_block_rays, render
from .trace import check_occlusion_samples, check_shadow_samples
from .scene import SETTINGS_UNITS, Scene, settings_ranges
from .scene import Camera, DirectionalLight, Mesh, PointLight
from .smallscale import SmallScale
from .svbrdf import Textured
from .tomlschema import (INT, INT2, LIST, LOBES, NUM, RGB, STR, STRLIST, TABLE, VEC3, SceneError, _article, _build,
                         _Ctx, _located, _located_warnings, _read, _show)

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["SceneFile", "SceneError", "load_scene", "loads_scene", "MESH_BUILTINS", "MATERIAL_TYPES",
           "ENVIRONMENT_TYPES", "LIGHT_TYPES"]


# ------------------------------------------------------------------------------------------------
# schema

def _check_block_rays(v):
    try:
        check_block_rays(v)
    except ValueError:
        return None, 'true, false, "auto" or a block side 1, 2 or 4'
    return v, None


RENDER_KEYS = {"width": INT, "height": INT, "method": STR, "samples": INT, "seed": INT, "exposure": NUM,
               "env_lobes": INT, "ssdf_resolution": INT, "ssdf_terms": INT, "backend": STR,
               "aa": INT, "shadow_samples": INT, "occlusion_samples": INT, "block_rays": _check_block_rays}
# the [render] keys that are options of the SG renderer (aa and shadow_samples the lit-sphere shader's too)
RAY_KEYS = ("aa", "shadow_samples", "occlusion_samples", "block_rays")
CAMERA_KEYS = {"eye": VEC3, "target": VEC3, "up": VEC3, "fov": NUM}
_SIZE = {"height": INT, "width": INT}
ENVIRONMENT_TYPES = {
    "none": {},
    "constant": {"radiance": RGB, **_SIZE},
    "sky": {"sun_direction": VEC3, "sun_angular_radius": NUM, "sun_radiance": RGB, "sun_irradiance": RGB,
            "sky_zenith": RGB, "sky_horizon": RGB, "ground": RGB, "sun_edge": NUM, "supersample": INT, **_SIZE},
    "studio": {"lights": LIST, "background": RGB, "supersample": INT, **_SIZE},
    "file": {"path": STR},
    "sgs": {"axes": LIST, "sharpness": LIST, "amplitudes": LIST, "constant": RGB, **_SIZE},
}
SOFTBOX_KEYS = {"direction": VEC3, "half_width": NUM, "half_height": NUM, "radiance": RGB}
LIGHT_TYPES = {
    "point": {"position": VEC3, "intensity": RGB, "radius": NUM},
    "directional": {"direction": VEC3, "irradiance": RGB, "angular_radius": NUM},
}
_PLACE = {"scale": NUM, "rotate": VEC3, "translate": VEC3}
MESH_BUILTINS = {
    "sphere": {"radius": NUM, "center": VEC3, "subdivisions": INT},
    "torus": {"major": NUM, "minor": NUM, "center": VEC3, "segments": INT2},
    "plane": {"size": NUM, "height": NUM, "divisions": INT},
}
_MAPS = {"kd_map": STR, "ks_map": STR, "parameter_map": STR}  # svbrdf.Textured: image paths, relative to the file
_BRDF_KEYS = {
    "lambert": {"albedo": RGB, "kd_map": STR},
    "blinnphong": {"ks": RGB, "exponent": NUM, "kd": RGB, "normalization": STR, **_MAPS},
    "cooktorrance": {"ks": RGB, "roughness": NUM, "f0": NUM, "kd": RGB, **_MAPS},
    "ward": {"ks": RGB, "alpha": NUM, "kd": RGB, **_MAPS},
    # anisotropic: in the frame of the mesh's tangents (its UVs' u direction)
    "anisotropicward": {"ks": RGB, "alpha_x": NUM, "alpha_y": NUM, "kd": RGB},
    "ashikhminshirley": {"rs": RGB, "nu": NUM, "nv": NUM, "rd": RGB},
}
BAKE_KEYS = {"tile": STR, "tile_params": TABLE, "brdf": STRLIST, "lobes": LOBES, "directions": INT, "facets": INT,
             "normal_res": INT, "method": STR, "route": STR, "seed": INT}
MATERIAL_TYPES = {**_BRDF_KEYS, "bake": BAKE_KEYS, "file": {"path": STR, "brdf": STRLIST}, "litsphere": {"path": STR},
                  "merl": {"path": STR}}
TOP_LEVEL = ("render", "camera", "environment", "light", "object", "material")


# ------------------------------------------------------------------------------------------------
# the result


@dataclass(eq=False)
class SceneFile:
    """A loaded scene file: the `scene` (render.Scene) and the [render] settings.

    `material_names[i]` names `scene.materials[i]`; `materials` maps every name to its material (None
    for a bake material no object uses: it is checked, not baked); `tiles` maps each bake material's
    name to the SmallScale tile it was baked from; `timings` holds the load's seconds ("bake NAME" per
    baked material, "load" in all)."""

    scene: object
    path: str | None = None
    width: int = 512
    height: int = 512
    method: str = "sg"
    samples: int | None = None
    seed: int | None = None
    exposure: float = 0.0
    backend: str = "auto"
    aa: int | None = None  # (None: the renderer's default)
    shadow_samples: int | None = None
    occlusion_samples: int | None = None
    block_rays: object = None
    material_names: list = field(default_factory=list)
    materials: dict = field(default_factory=dict)
    tiles: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    def resize(self, width: int, height: int) -> None:
        """Render at another image size (the camera's view is kept; the vertical fov is what it fixes)."""

        c = self.scene.camera
        self.scene.camera = Camera(c.eye, c.target, c.up, c.fov, width, height)
        self.width, self.height = self.scene.camera.width, self.scene.camera.height

    def render_options(self, method: str | None = None) -> dict:
        """Keyword options for `render.render` beyond method and backend, those the file sets: mc: samples, seed;
        sg: aa, shadow_samples, occlusion_samples, block_rays; litsphere: aa, shadow_samples."""
        method = method or self.method
        keys = {"mc": ("samples", "seed"), "sg": RAY_KEYS, "litsphere": RAY_KEYS[:2]}.get(method, ())
        return {k: getattr(self, k) for k in keys if getattr(self, k) is not None}

    def render(self, method: str | None = None, backend=None, progress=None, **options):
        """Render with the file's settings (`method`, `backend` and options override them)."""

        method = method or self.method
        return render(self.scene, method=method, backend=backend or self.backend, progress=progress,
                      **{**self.render_options(method), **options})


def load_scene(path, backend=None, progress=None, method=None) -> SceneFile:
    """Read a TOML scene file (see the module docstring) → SceneFile. Paths in it are relative to the
    file. `backend` overrides [render] backend (also for baking); `progress` reports the bakes; `method` is the
    renderer the caller will use (default the file's [render] method): a bake it cannot shade (the matrix
    method's, by the SG renderer) is refused before any bake."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise FileNotFoundError(f"no such scene file: {path}") from None
    except IsADirectoryError:
        raise SceneError(f"{path} is a directory, not a scene file", path) from None
    try:
        text = data.decode("utf-8-sig")  # (a byte-order mark, as some editors write, is no TOML error)
    except UnicodeDecodeError as exc:
        raise SceneError(f"{os.path.basename(path)}: not UTF-8 text ({exc})", path) from None
    return loads_scene(text, path=path, backend=backend, progress=progress, method=method)


def loads_scene(text: str, path: str | None = None, base_dir: str | None = None, backend=None,
                progress=None, method=None) -> SceneFile:
    """`load_scene` on TOML text; `path` names it in messages, `base_dir` (default: path's folder, else
    the working directory) anchors its relative paths; `method` as `load_scene`'s."""
    t_load = time.perf_counter()
    if base_dir is None:
        base_dir = os.path.dirname(os.path.abspath(path)) if path else os.getcwd()
    ctx = _Ctx(text, path, base_dir)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        if m:
            line, where, msg = int(m.group(1)), f"{ctx.name}:{m.group(1)}:{m.group(2)}:", msg[:m.start()].strip()
        else:  # "(at end of document)": the last line
            line = max(1, len(text.splitlines()))
            where = f"{ctx.name}:{line}:"
            msg = msg.replace("(at end of document)", "at the end of the file").strip()
        raise SceneError(f"{where} invalid TOML: {msg}", path, line) from None
    for key in doc:
        if key not in TOP_LEVEL:
            raise ctx.error((), key, f"unknown table or key {key!r} (allowed: {', '.join(TOP_LEVEL)})")

    sf = SceneFile(scene=None, path=path)
    scene_opts = _render_settings(ctx, doc.get("render", {}), sf)
    if backend is not None:
        sf.backend = backend
    cam = _read(ctx, ("camera",), doc.get("camera", {}), CAMERA_KEYS)
    defs = _material_defs(ctx, doc.get("material", {}))
    meshes, used = _objects(ctx, doc.get("object", []), defs)
    env = _environment(ctx, doc.get("environment"))
    lights = _lights(ctx, doc.get("light", []))
    camera = _camera(ctx, cam, meshes, sf)


    renders_by = method or sf.method
    for name, (kind, values) in defs.items():  # what the renderer cannot draw, before any bake
        if kind != "bake" or name not in used or values.get("method") != "matrix":
            continue
        if renders_by == "sg":  # ('mc' named only where it can render it: a Lambertian bake's)
            also = "" if _glossy(values.get("brdf", [])) else " (or 'mc')"
            raise ctx.error(("material", name), "method",
                            "the SG renderer cannot shade a matrix bake (Wu's f̄ tables, not lobes): render "
                            f"this scene by method 'litsphere'{also}, or bake with method 'sg' or 'asg'")
        if renders_by == "mc" and _glossy(values.get("brdf", [])):
            raise ctx.error(("material", name), "method",
                            "the Monte Carlo reference samples a glossy small-scale BRDF by its bake's lobes, which "
                            "a matrix bake has not: render this scene by method 'litsphere', or bake with method "
                            "'sg' or 'asg'")
    prog = as_progress(progress)
    for name, (kind, values) in defs.items():
        table = ("material", name)
        t0 = time.perf_counter()
        sf.materials[name] = _material(ctx, table, kind, values, sf, name, name in used, prog)
        if kind == "bake" and name in used:
            sf.timings[f"bake {name}"] = time.perf_counter() - t0
    sf.material_names = list(used)
    mesh = Mesh.merge(meshes) if len(meshes) > 1 else meshes[0]
    try:
        sf.scene = Scene(mesh, [sf.materials[n] for n in used], camera, env, lights, **scene_opts)
    except ValueError as exc:
        raise _located(ctx, ("render",), scene_opts, exc) from None
    sf.timings["load"] = time.perf_counter() - t_load
    return sf


# ------------------------------------------------------------------------------------------------
# sections


def _render_settings(ctx, data, sf):

    table = ("render",)
    v = _read(ctx, table, data, RENDER_KEYS)
    for key in ("width", "height"):
        if key in v and not (1 <= v[key] <= 16384):
            raise ctx.error(table, key, f"{key} must be an integer in 1..16384, got {v[key]}")
        setattr(sf, key, v.get(key, getattr(sf, key)))
    if "method" in v and v["method"] not in METHODS:
        raise ctx.error(table, "method", f"method must be one of {', '.join(METHODS)}, got {v['method']!r}")
    if "samples" in v and v["samples"] < 2:
        raise ctx.error(table, "samples", f"samples must be >= 2, got {v['samples']}")
    # the ranges render.Scene checks (env_lobes up to the lighting kernels' lobes, the SSDF's grid sizes):
    # a bad value is named here with its line, not when the render starts
    for key, (lo, hi) in settings_ranges(v.get("ssdf_resolution", Scene.ssdf_resolution)).items():
        if key in v and not lo <= v[key] <= hi:
            raise ctx.error(table, key, f"{key} must be an integer in {lo}..{hi}{SETTINGS_UNITS[key]}, got {v[key]}")
    if "seed" in v and v["seed"] < 0:
        raise ctx.error(table, "seed", f"seed must be >= 0, got {v['seed']}")
    if "backend" in v:

        try:  # an unknown name fails here, with its line; a known one is only resolved at render time
            get_backend(v["backend"])
        except (ValueError, RuntimeError) as exc:
            raise ctx.error(table, "backend", str(exc)) from None
    sf.method = v.get("method", sf.method)
    sf.samples = v.get("samples")
    sf.seed = v.get("seed")
    if "exposure" in v:
        try:
            check_exposure(v["exposure"])
        except ValueError as exc:
            raise ctx.error(table, "exposure", str(exc)) from None
    sf.exposure = v.get("exposure", sf.exposure)
    sf.backend = v.get("backend", sf.backend)
    for key, check in (("aa", check_aa), ("shadow_samples", check_shadow_samples),
                       ("occlusion_samples", check_occlusion_samples)):
        if key in v:
            try:
                check(v[key])
            except ValueError as exc:
                raise ctx.error(table, key, str(exc)) from None
            setattr(sf, key, v[key])
    if "block_rays" in v:
        sf.block_rays = v["block_rays"]
    return {k: v[k] for k in ("env_lobes", "ssdf_resolution", "ssdf_terms") if k in v}


def _typed(ctx, table, data, types: dict, what: str):
    """The `type` key of a table and its type's keys → (type, values)."""
    if not isinstance(data, dict):
        raise ctx.error(table, None, f"must be a table, got {_show(data)}")
    kind = data.get("type")
    if kind is None:
        raise ctx.error(table, None, f"needs a type: one of {', '.join(map(repr, types))}")
    if not isinstance(kind, str) or kind.lower() not in types:
        raise ctx.error(table, "type", f"unknown {what} type {_show(kind)}; choose one of "
                                       f"{', '.join(map(repr, types))}")
    kind = kind.lower()
    rest = {k: v for k, v in data.items() if k != "type"}
    return kind, _read(ctx, table, rest, types[kind], where=f" for {_article(kind)} {kind} {what}")


def _environment(ctx, data):

    if data is None:
        return None
    table = ("environment",)
    types = {k: {**v, "scale": NUM} if k != "none" else v for k, v in ENVIRONMENT_TYPES.items()}
    kind, v = _typed(ctx, table, data, types, "environment")
    scale = v.pop("scale", None)
    if scale is not None and scale < 0:
        raise ctx.error(table, "scale", f"scale must be >= 0, got {scale:g}")
    if kind == "none":
        return None
    if kind == "constant":
        env = _build(ctx, table, v, Environment.constant)
    elif kind == "sky":
        env = _build(ctx, table, v, Environment.sky)
    elif kind == "studio":
        if "lights" in v:
            boxes = []
            for i, box in enumerate(v["lights"]):
                b = _read(ctx, table, box, SOFTBOX_KEYS, required=("direction", "half_width", "half_height"),
                          where=f" in studio light #{i + 1}")
                try:
                    boxes.append(Softbox(**b))
                except (ValueError, TypeError) as exc:
                    raise ctx.error(table, "lights", f"light #{i + 1}: {exc}") from None
            v["lights"] = boxes
        env = _build(ctx, table, v, Environment.studio)
    elif kind == "sgs":
        for key in ("axes", "sharpness", "amplitudes"):
            if key not in v:
                raise ctx.error(table, None, f"needs the key {key!r} for an sgs environment")
        env = _build(ctx, table, v, Environment.from_sgs)
    else:  # file
        if "path" not in v:
            raise ctx.error(table, None, "needs the key 'path' for a file environment")
        full = ctx.resolve(v["path"])
        if not os.path.isfile(full):
            raise ctx.error(table, "path", f"no such environment file: {v['path']} (looked for {full})")
        try:
            env = Environment.from_file(full)
        except (ValueError, OSError) as exc:
            raise ctx.error(table, "path", str(exc)) from None
    if scale is not None and scale != 1.0:
        env = Environment(env.radiance * np.float32(scale), name=env.name)
    return env


def _lights(ctx, data):

    if isinstance(data, dict):
        raise ctx.error(("light",), None, "must be written [[light]] (an array of tables), not [light]")
    out = []
    for i, item in enumerate(data):
        table = ("light", i)
        kind, v = _typed(ctx, table, item, LIGHT_TYPES, "light")
        out.append(_build(ctx, table, v, PointLight if kind == "point" else DirectionalLight))
    return out


def _material_defs(ctx, data) -> dict:
    """name → (type, checked values), in file order (built later, once we know which are used)."""
    if not isinstance(data, dict):
        raise ctx.error(("material",), None, "must be a table of [material.NAME] tables")
    out = {}
    for name, item in data.items():
        table = ("material", name)
        if not isinstance(item, dict):
            raise ctx.error(table, None, f"must be a table [material.{name}] with a type, got {_show(item)}")
        kind, v = _typed(ctx, table, item, MATERIAL_TYPES, "material")
        if kind in ("bake", "file"):
            need = "tile" if kind == "bake" else "path"
            if need not in v:
                raise ctx.error(table, None, f"needs the key {need!r} for a {kind} material")
        out[name] = (kind, v)
    return out


def _objects(ctx, data, defs):
    """→ (list of Mesh with material ids set, material names in order of first use)."""

    if isinstance(data, dict):
        raise ctx.error(("object",), None, "must be written [[object]] (an array of tables), not [object]")
    if not data:
        raise SceneError(f"{ctx.name}: the scene has no [[object]]: add at least one", ctx.path)
    used: list = []
    meshes = []
    for i, item in enumerate(data):
        table = ("object", i)
        if not isinstance(item, dict):
            raise ctx.error(table, None, f"must be a table, got {_show(item)}")
        base = {"mesh": STR, "material": STR, **_PLACE}
        if "mesh" not in item:
            raise ctx.error(table, None, f"needs the key 'mesh': {', '.join(map(repr, MESH_BUILTINS))} or a mesh file")
        if "material" not in item:
            raise ctx.error(table, None, "needs the key 'material' (the NAME of a [material.NAME])")
        mesh_kind = item["mesh"]
        if isinstance(mesh_kind, str) and mesh_kind not in MESH_BUILTINS and not os.path.isfile(ctx.resolve(mesh_kind)):
            # (before the keys: a typo'd built-in or a missing file is the error, not the keys of the shape meant)
            raise ctx.error(table, "mesh", f"mesh {mesh_kind!r} is neither a built-in ({', '.join(MESH_BUILTINS)}) "
                                           f"nor an existing mesh file (looked for {ctx.resolve(mesh_kind)})")
        schema = {**base, **MESH_BUILTINS.get(mesh_kind, {})} if isinstance(mesh_kind, str) else base
        v = _read(ctx, table, item, schema, where=f" for mesh {_show(mesh_kind)}")
        name = v.pop("material")
        if name not in defs:
            known = ", ".join(map(repr, defs)) or "none are defined"
            raise ctx.error(table, "material", f"material {name!r} is not defined by a [material.{name}] table "
                                               f"(materials: {known})")
        if name not in used:
            used.append(name)
        mid = used.index(name)
        spec = v.pop("mesh")
        place = {k: v.pop(k) for k in list(v) if k in _PLACE}
        if spec in MESH_BUILTINS:
            mesh = _build(ctx, table, v, getattr(Mesh, spec), material=mid)
        else:
            full = ctx.resolve(spec)
            try:
                mesh = Mesh.load(full, material=mid)
            except ValueError as exc:
                raise ctx.error(table, "mesh", str(exc)) from None
        meshes.append(_place(ctx, table, mesh, place))
    return meshes, used


def _rotation(deg) -> np.ndarray:
    rx, ry, rz = np.radians(deg)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return mz @ my @ mx  # x first, then y, then z


def _place(ctx, table, mesh, place):

    if not place:
        return mesh
    s = place.get("scale", 1.0)
    if not s > 0:
        raise ctx.error(table, "scale", f"scale must be > 0, got {s:g}")
    r = _rotation(place.get("rotate", (0.0, 0.0, 0.0)))
    t = np.asarray(place.get("translate", (0.0, 0.0, 0.0)))
    try:
        return Mesh(mesh.vertices @ (s * r).T + t, mesh.faces, mesh.normals @ r.T, mesh.uvs, mesh.face_material)
    except ValueError as exc:  # (coordinates past the renderers' range)
        raise ctx.error(table, None, f"placed by its {' and '.join(place)}: {exc}") from None


def _camera(ctx, v, meshes, sf):
    """The camera from the checked [camera] values; no eye: framed on the objects' bounding sphere."""

    table = ("camera",)
    lo = np.min([m.vertices.min(0) for m in meshes], axis=0)
    hi = np.max([m.vertices.max(0) for m in meshes], axis=0)
    if "target" not in v:
        v["target"] = ((lo + hi) / 2).tolist()
    if "eye" not in v:  # frame the bounding sphere from the front and a little above
        fov = v.get("fov", 40.0)
        if not 0 < fov < 180:
            raise ctx.error(table, "fov", f"fov must lie in (0, 180) degrees, got {fov:g}")
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
        dist = 1.1 * radius / math.sin(math.radians(min(fov, fov * sf.width / sf.height)) / 2)
        d = np.array([0.0, 0.35, 1.0]) / np.linalg.norm([0.0, 0.35, 1.0])
        v["eye"] = (np.asarray(v["target"]) + dist * d).tolist()
    return _build(ctx, table, v, Camera, width=sf.width, height=sf.height)


def _brdfs(ctx, table, specs):

    out = []
    for s in specs:
        try:
            with _located_warnings(ctx, table, (), "brdf"):
                out.append(small_scale_brdf(s, ctx.base_dir))
        except (ValueError, OSError) as exc:
            raise ctx.error(table, "brdf", f"brdf {s!r}: {one_line(exc)}") from None
    return out


def _material(ctx, table, kind, v, sf, name, used, prog):

    if kind in _BRDF_KEYS:
        cls = {"lambert": brdf_mod.Lambert, "blinnphong": brdf_mod.BlinnPhong,
               "cooktorrance": brdf_mod.CookTorrance, "ward": brdf_mod.Ward,
               "anisotropicward": brdf_mod.AnisotropicWard, "ashikhminshirley": brdf_mod.AshikhminShirley}[kind]
        v = dict(v)
        maps = {key: v.pop(key) for key in _MAPS if key in v}
        mat = _build(ctx, table, v, cls)
        if not maps:
            return mat

        for key, rel in maps.items():
            full = ctx.resolve(rel)
            if not os.path.isfile(full):
                raise ctx.error(table, key, f"{key} {rel!r}: no such image file (looked for {full})")
            maps[key] = full
        return _build(ctx, table, maps, Textured, mat)
    if kind == "file":

        full = ctx.resolve(v["path"])
        if not os.path.isfile(full):
            raise ctx.error(table, "path", f"no such material file: {v['path']} (looked for {full})")
        try:
            mat = load(full)
        except (ValueError, OSError, KeyError) as exc:
            raise ctx.error(table, "path", f"cannot read material file {v['path']}: {exc}") from None
        if not isinstance(mat, EffectiveBRDF):
            raise ctx.error(table, "path", f"{v['path']} holds a {type(mat).__name__}, not a baked material (.wbm)")
        if "brdf" in v:
            mats = _brdfs(ctx, table, v["brdf"])
            if len(mats) == 1 and len(mat.materials) > 1:
                mats = mats * len(mat.materials)
            try:
                mat = mat.with_materials(mats)
            except ValueError as exc:
                raise ctx.error(table, "brdf", str(exc)) from None
        return mat
    if kind in ("litsphere", "merl"):
        full = ctx.resolve(v["path"])
        if not os.path.exists(full):
            raise ctx.error(table, "path", f"no such {kind} material: {v['path']} (looked for {full})")
        try:
            return LitSphere.load(full) if kind == "litsphere" else MeasuredBRDF.load(full)
        except (ValueError, OSError) as exc:
            raise ctx.error(table, "path", f"cannot read {kind} material {v['path']}: {one_line(exc)}") from None
    return _bake(ctx, table, v, sf, name, used, prog)


def _glossy(specs) -> bool:
    """Whether a bake table's brdf specs hold a small-scale BRDF other than a Lambertian one (a MERL table is
    glossy); a spec that does not parse is left to the bake, which names it."""
    for spec in [specs] if isinstance(specs, str) else specs:
        if not isinstance(spec, str):
            continue
        if spec.lower().endswith(".binary"):
            return True
        try:
            if not isinstance(parse_brdf(spec), Lambert):
                return True
        except ValueError:
            continue
    return False


def _bake(ctx, table, v, sf, name, used, prog):

    spec = v["tile"]
    params = v.get("tile_params", {})
    try:
        if spec == "heightfield" and "image" in params:  # a painted height field (the editor saves one): its image
            rest = dict(params)
            image = rest.pop("image")
            if not isinstance(image, str):
                raise ctx.error(table, "tile_params", 'tile_params.image must be a greyscale image file')
            tile = geometry.heightfield_from_image(ctx.resolve(image), **rest)
        elif spec in BUILTIN_TILES:  # ("heightfield" without an image: the default relief, geometry.relief)
            fn, kwargs = BUILTIN_TILES[spec]
            for k in params:  # (a name that fixes a parameter, such as vgroove's profile, keeps it)
                if k in kwargs and params[k] != kwargs[k]:
                    raise ctx.error(table, ("tile_params", k), f"tile {spec!r} is {fn} with {k} = {kwargs[k]!r}, "
                                                               f"got {k} = {params[k]!r}: use tile = {fn!r} for that")
            generator = getattr(geometry, fn)
            taken = [k for k, p in inspect.signature(generator).parameters.items()
                     if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and k not in kwargs]
            for k in params:
                if k not in taken:
                    also = (" (a painted height field takes it, given tile_params.image)" if spec == "heightfield"
                            and k in inspect.signature(geometry.heightfield_from_image).parameters else "")
                    raise ctx.error(table, ("tile_params", k), f"tile {spec!r} has no parameter {k!r}{also}; its "
                                                               f"parameters: {', '.join(taken)}")
            tile = generator(**{**kwargs, **params})
        else:
            full = ctx.resolve(spec)
            if not os.path.isfile(full):
                raise ctx.error(table, "tile", f"tile {spec!r} is neither a built-in tile "
                                               f"({', '.join(BUILTIN_TILES)}) nor an existing mesh or image file "
                                               f"(looked for {full})")
            image = full.lower().endswith(geometry.IMAGE_SUFFIXES)  # a greyscale image: a height field
            tile = geometry.heightfield_from_image(full, **params) if image else SmallScale.load(full, **params)
    except SceneError:
        raise
    except (ValueError, TypeError, FileNotFoundError) as exc:  # the line of the parameter it names, else of tile_params
        msg = str(exc)
        named = [k for k in params if re.search(rf"(?<![A-Za-z0-9_]){re.escape(k)}(?![A-Za-z0-9_])", msg)]
        key = ("tile_params", named[0]) if named else ("tile_params" if params else "tile")
        raise ctx.error(table, key, f"tile {spec!r}: {msg}") from None
    sf.tiles[name] = tile

    mats = _brdfs(ctx, table, v["brdf"]) if "brdf" in v else [Lambert(0.5)]
    if len(mats) == 1 and tile.n_materials > 1:
        mats = mats * tile.n_materials
    if len(mats) < tile.n_materials:
        raise ctx.error(table, "brdf", f"the tile uses material ids 0..{tile.n_materials - 1}: give {tile.n_materials} "
                                       f"brdf strings (or one for all), got {len(mats)}")
    opts = {k: v[k] for k in ("lobes", "directions", "facets", "normal_res", "method", "route", "seed") if k in v}
    if not used:  # validated, not baked: nothing in the scene shows it
        return None
    return _build(ctx, table, opts, bake, tile, mats, warn_key="brdf", backend=sf.backend, progress=prog)
