"""Batch job files: a TOML file naming tiles, small-scale materials, bake settings, scenes and what to
compute; their cross product (or the combinations it lists) becomes one `Task` per material.
`warp_biscale.batch` runs the tasks; this module only reads and checks the file, before any work::

    output = "results"           # optional: the results folder (relative to this file; -o overrides it)

    [bake]                       # wb.bake's settings; a list (or a range table) is a sweep axis
    method = "sg"                # "sg" | "sg-exact" | "asg" (Xu 2013; it also takes anisotropic BRDFs) | "auto"
                                 #   (sg or asg, whichever is nearer the exact f̄ of the bake's facets)
    lobes = 4                    # J, or "auto"
    facets = 4096
    directions = 6               # K
    # normal_res = 128, route = "facets", seed = 0, backend = "auto", zip = false

    [compute]                    # besides the bake, every task can compute:
    truth = false                # the ground truth (wb.ground_truth), saved as truth.npz
    compare = false              # PSNR / RMSE of the bake against that truth (implies truth)
    render = true                # render every [[scene]] (default: true when there is one)

    [truth]                      # the ground truth's settings
    facets = 262144              # default 2^18; directions: the bake's K; seed = 0

    [[tile]]
    family = "pyramid"           # a built-in family: pyramid, pentagon, grooves, vgroove, ugroove, rods,
    height = [0.2, 0.4, 0.6]     #   woven, flat; its generator's parameters (wb.geometry.pyramid, ...)
    [[tile]]
    mesh = "tile.obj"            # or a mesh file (relative to this file); period = [px, py]
    [[tile]]
    heightfield = ["bumps.png", "dents.png"]   # or a height-field image; scale, size, material, color
    scale = { from = 0.05, to = 0.2, steps = 4 }
    name = "bumps"               # optional: what [[material]] tiles = [...] refers to

    [[material]]
    brdf = "blinnphong:exponent=128"          # the CLI's --brdf syntax: one for every material id of the tile,
    [[material]]                              #   or a list of strings, one per material id
    type = "cooktorrance"                     # or a BRDF type and its parameters, swept like a tile's
    roughness = [0.1, 0.2, 0.4]
    f0 = 0.04
    tiles = ["bumps"]                         # optional: only with these [[tile]] names (default: every tile)

    [[scene]]                    # scenes each material is rendered in
    path = "bi-scale.toml"       # a scene file (relative to this file)
    slot = "demo_tile"           # the [material.NAME] of that file the baked material replaces
    width = 128                  # optional: size, aa, shadow_samples, exposure, block_rays (true/false or a
    height = 96                  #   block side 1, 2, 4); each unset: the scene file's [render] setting, else aa 1
                                 #   and the renderer's defaults (block_rays: 2x2 blocks from 320x240, 4x4 from
                                 #   1920x1080); the file's occlusion_samples too

A sweep value is a list (``height = [0.2, 0.4]``), a range table (``{ from = 0.1, to = 0.5, steps = 5 }``,
``steps`` values evenly spaced, ``log = true`` for a geometric series; or ``step = 0.1``: from, from + step,
... up to to) or ``{ values = [...] }``. A key that takes a vector (``color``, ``orientation``, ``ks`` ...)
takes a list of numbers as its one value: sweep it with a list of lists or ``{ values = [...] }``. Within
a table the axes are crossed; ``zip = true`` pairs them instead (all of one length). Every [[tile]]
value is crossed with every [[material]] value (or those naming it in ``tiles``) and every [bake]
value: one task each.

Every mistake is a one-line `SceneError` naming the file and line, before any work: TOML syntax, unknown
tables and keys, wrong types, empty ranges, bad parameter values (each tile and BRDF is built once here),
missing files, a scene file that is itself bad, has no [material.SLOT] or uses it on no object, and an
output folder that cannot be written.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import itertools
import json
import math
import os
import re

import numpy as np

from . import brdf as brdf_mod
from . import geometry
from .bake import ROUTES
from .bake import _check_lobes
from .effective import METHODS, _brdf_to_dict
from .geometry import BUILTIN_TILES
from .io import check_output
from .scenefile import _BRDF_KEYS, _MAPS, SceneError, _brdfs
from .smallscale import SmallScale
from .tomlschema import _article, _build, _Ctx, _located_warnings, _read, _show
from .truth import TRUTH_FACETS, _check_count

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

# What a job's [bake] method may be: the bakes whose materials every task step takes (the ground truth's compare,
# the SG renderer); the matrix method's cannot be rendered by it.
BAKE_METHODS = (*METHODS, "asg", "auto")

__all__ = ["Jobs", "Task", "load_jobs", "loads_jobs", "jobs_from_dict", "FAMILIES", "MAX_TASKS", "FORMAT"]

FORMAT = 1  # part of every task's input hash: bump it when a task's outputs change for the same inputs
MAX_TASKS = 100_000
TOP_LEVEL = ("output", "bake", "compute", "truth", "tile", "material", "scene")
# Built-in families: the names `warp-biscale bake` takes, and the generators' own names.
FAMILIES = {**BUILTIN_TILES, **{name: (name, {}) for name in ("flat", "pyramid", "grooves", "rods", "woven")}}
BAKE_DEFAULTS = {"method": "sg", "lobes": 8, "facets": 1 << 16, "directions": 12, "normal_res": 128,
                 "route": "facets", "seed": 0, "backend": "auto"}
SCENE_KEYS = ("path", "slot", "name", "width", "height", "aa", "shadow_samples", "exposure", "block_rays")
_RANGE_KEYS = ("from", "to", "steps", "step", "log", "values")


@dataclasses.dataclass(eq=False)
class Task:
    """One material to bake (and judge and render): plain data, sent as is to a worker process.

    `hash` names its results folder (a digest of every input: tile, its file's bytes, BRDFs, settings,
    scene files); `tile_key` is the same for every task of one tile (they prefer one worker)."""

    hash: str
    label: str
    tile: dict          # kind ("family" | "mesh" | "heightfield"), family/fn or path + sha256, params, label
    tile_key: str
    materials: list     # the small-scale BRDFs (_material_dict: analytic parameters, a MERL file's path and hash)
    material: dict      # label, name, params (the swept or given ones, for the table)
    bake: dict          # wb.bake's settings (BAKE_DEFAULTS' keys)
    truth: dict | None  # facets, directions, seed; None: no ground truth
    compare: bool
    scenes: list        # name, path, sha256, slot, width, height, aa, shadow_samples, exposure, block_rays

    def payload(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(eq=False)
class Jobs:
    """A checked job file: its `tasks`, `scenes`, the `output` folder it names (absolute; None if none)."""

    path: str | None
    text: str | None  # the file's text (None for a job given as a dict)
    tasks: list
    scenes: list
    output: str | None = None

    def __len__(self):
        return len(self.tasks)


def digest(obj) -> str:
    """16 hex digits of SHA-256 over the canonical JSON of `obj`."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_jsonable)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, tuple):
        return list(v)
    raise TypeError(f"{type(v).__name__} is not JSON")


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# ------------------------------------------------------------------------------------------------
# reading


def load_jobs(path) -> Jobs:
    """Read and check a job file (see the module docstring) → Jobs; paths in it are relative to it."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise FileNotFoundError(f"no such job file: {path}") from None
    except IsADirectoryError:
        raise SceneError(f"{path} is a directory, not a job file", path) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{os.path.basename(path)}: not UTF-8 text ({exc})", path) from None
    return loads_jobs(text, path=path)


def loads_jobs(text: str, path: str | None = None, base_dir: str | None = None) -> Jobs:
    """`load_jobs` on TOML text; `path` names it in messages, `base_dir` (default: the path's folder, else
    the working directory) anchors its relative paths."""
    if base_dir is None:
        base_dir = os.path.dirname(os.path.abspath(path)) if path else os.getcwd()
    ctx = _Ctx(text, path, base_dir)
    if not path:
        ctx.name = "<jobs>"
    return _from_doc(ctx, _parse_toml(ctx, text), text)


def jobs_from_dict(doc: dict, base_dir: str | None = None) -> Jobs:
    """A job given as Python data, as the TOML file would be (``{"bake": {...}, "tile": [{...}], ...}``),
    checked the same way (its errors name the table and key; there are no lines); relative paths are
    against `base_dir` (default: the working directory)."""
    if not isinstance(doc, dict):
        raise ValueError(f"a job must be a dict of tables, got {type(doc).__name__}")
    ctx = _Ctx("", None, base_dir or os.getcwd())
    ctx.name = "<jobs>"
    return _from_doc(ctx, doc, None)


def _from_doc(ctx, doc, text) -> Jobs:
    path = ctx.path
    for key in doc:
        if key not in TOP_LEVEL:
            raise ctx.error((), key, f"unknown table or key {key!r} (allowed: {', '.join(TOP_LEVEL)})")
    for key in ("tile", "material", "scene"):
        if isinstance(doc.get(key), dict):
            raise ctx.error((key,), None, f"must be written [[{key}]] (an array of tables), not [{key}]")
    output = None
    if "output" in doc:
        if not isinstance(doc["output"], str) or not doc["output"].strip():
            raise ctx.error((), "output", f"output must be a folder name, got {_show(doc['output'])}")
        output = ctx.resolve(doc["output"])
        check_output_folder(output, lambda msg: ctx.error((), "output", msg))
    bakes = _bake_settings(ctx, doc.get("bake", {}))
    compute = _read(ctx, ("compute",), doc.get("compute", {}), {k: _BOOL for k in ("truth", "compare", "render")})
    scenes = _scenes(ctx, doc.get("scene", []))
    render = compute.get("render", bool(scenes))
    if render and not scenes:
        raise ctx.error(("compute",), "render", "render = true needs a [[scene]] to render the materials in")
    if not render:
        scenes = []
    truth = None
    if compute.get("truth") or compute.get("compare"):
        truth = _read(ctx, ("truth",), doc.get("truth", {}), {"facets": _INT, "directions": _INT, "seed": _INT})
        _check_settings(ctx, ("truth",), truth)
        truth = {"facets": truth.get("facets", TRUTH_FACETS), "directions": truth.get("directions"),
                 "seed": truth.get("seed", 0)}
    elif "truth" in doc:
        _read(ctx, ("truth",), doc["truth"], {"facets": _INT, "directions": _INT, "seed": _INT})
    tiles = _tiles(ctx, doc.get("tile", []))
    materials = _materials(ctx, doc.get("material", []), tiles)
    tasks = _cross(ctx, tiles, materials, bakes, truth, bool(compute.get("compare")), scenes)
    return Jobs(path=os.path.abspath(path) if path else None, text=text, tasks=tasks, scenes=scenes, output=output)


def check_output_folder(folder, error=None) -> None:
    """Refuse a results folder that cannot be written (a file on its way, no permission, a read-only file
    system) in one line; `error(message)` builds the exception (default ValueError)."""
    try:
        if os.path.exists(folder) and not os.path.isdir(folder):
            raise ValueError(f"output folder {folder!r} is a file, not a folder")
        check_output(os.path.join(folder, "results.csv"), (".csv",), "output folder")
    except ValueError as exc:
        msg = str(exc).replace(os.path.join(folder, "results.csv"), folder)
        raise (error(msg) if error else ValueError(msg)) from None


def _parse_toml(ctx, text):
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        if m:
            line, where, msg = int(m.group(1)), f"{ctx.name}:{m.group(1)}:{m.group(2)}:", msg[:m.start()].strip()
        else:  # "(at end of document)": the last line
            line = max(1, len(text.splitlines()))
            where = f"{ctx.name}:{line}:"
            msg = msg.replace("(at end of document)", "at the end of the file").strip()
        raise SceneError(f"{where} invalid TOML: {msg}", ctx.path, line) from None


def _check_bool(v):
    return (v, None) if isinstance(v, bool) else (None, "true or false")


def _check_block_rays(v):
    """true/false, or a side 1, 2, 4: 1 and 2 read as false and true (the same renders, so the same task hashes)."""
    if isinstance(v, bool):
        return v, None
    if isinstance(v, int) and v in (1, 2, 4):
        return {1: False, 2: True}.get(v, v), None
    return None, "true, false or a block side 1, 2 or 4"


def _check_int(v):
    return (v, None) if isinstance(v, int) and not isinstance(v, bool) else (None, "an integer")


def _any(v):
    return v, None


_BOOL, _INT = _check_bool, _check_int


# ------------------------------------------------------------------------------------------------
# sweep axes


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _axis(ctx, table, key, value, vector=False) -> list:
    """The values of one key: a list, a range table or { values = [...] } is a sweep axis; anything else is
    one value. For a vector key a flat list of numbers is one value."""
    if isinstance(value, dict):
        return _range(ctx, table, key, value)
    if isinstance(value, list):
        if vector and value and all(_is_num(x) for x in value):
            return [value]
        if not value:
            raise ctx.error(table, key, f"{key} is an empty list: a sweep axis needs at least one value")
        return list(value)
    return [value]


def _range(ctx, table, key, r) -> list:
    for k in r:
        if k not in _RANGE_KEYS:
            raise ctx.error(table, (key, k), f"{key}: unknown range key {k!r} (a range is {{ from, to, steps "
                                             "}} or {{ from, to, step }}, log = true for a geometric series; or "
                                             "{{ values = [...] }})")
    if "values" in r:
        if set(r) != {"values"}:
            raise ctx.error(table, key, f"{key}: give either values = [...] or from/to/steps, not both")
        if not isinstance(r["values"], list) or not r["values"]:
            raise ctx.error(table, (key, "values"), f"{key}: values must be a non-empty list, got {_show(r['values'])}")
        return list(r["values"])
    for k in ("from", "to"):
        if k not in r:
            raise ctx.error(table, key, f"{key}: a range needs from and to (and steps or step)")
        if not _is_num(r[k]) or not math.isfinite(r[k]):
            raise ctx.error(table, (key, k), f"{key}: {k} must be a finite number, got {_show(r[k])}")
    lo, hi, log = r["from"], r["to"], r.get("log", False)
    if not isinstance(log, bool):
        raise ctx.error(table, (key, "log"), f"{key}: log must be true or false, got {_show(log)}")
    if ("steps" in r) == ("step" in r):
        raise ctx.error(table, key, f"{key}: a range needs one of steps (how many values) or step (their spacing)")
    if "steps" in r:
        n = r["steps"]
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise ctx.error(table, (key, "steps"), f"{key}: steps must be an integer >= 1 (an empty range gives no "
                                                   f"task), got {_show(n)}")
        if n > MAX_TASKS:  # (before the values are made: 1e12 of them asked for 7 TiB)
            raise ctx.error(table, (key, "steps"), f"{key}: the range makes {n} values (more than {MAX_TASKS})")
        if log:
            if lo <= 0 or hi <= 0:
                raise ctx.error(table, key, f"{key}: a log range needs from and to > 0, got {lo:g} and {hi:g}")
            vals = np.geomspace(lo, hi, n) if n > 1 else np.array([lo], float)
        else:
            vals = np.linspace(lo, hi, n) if n > 1 else np.array([lo], float)
    else:
        step = r["step"]
        if not _is_num(step) or not math.isfinite(step) or step == 0 or log:
            raise ctx.error(table, (key, "step"), f"{key}: step must be a finite non-zero number (and no log), got "
                                                  f"{_show(step)}")
        count = math.floor((hi - lo) / step + 1e-9) + 1
        if count < 1:
            raise ctx.error(table, key, f"{key}: the range from {lo:g} to {hi:g} in steps of {step:g} is empty")
        if count > MAX_TASKS:
            raise ctx.error(table, key, f"{key}: the range makes {count} values (more than {MAX_TASKS})")
        vals = lo + step * np.arange(count)
    ints = all(isinstance(x, int) for x in (lo, hi, r.get("step", 0))) and np.allclose(vals, np.round(vals))
    return [int(round(v)) for v in vals] if ints else [round(float(v), 12) for v in vals]


def _expand(ctx, table, axes: dict, zipped: bool) -> list:
    """Dicts of one value per key: the product of the axes, or (zipped) their i-th values together."""
    if not axes:
        return [{}]
    if zipped:
        lengths = {k: len(v) for k, v in axes.items() if len(v) > 1}
        if len(set(lengths.values())) > 1:
            shown = ", ".join(f"{k} {n}" for k, n in lengths.items())
            raise ctx.error(table, "zip", f"zip = true needs sweep axes of one length, got {shown}")
        n = max(lengths.values(), default=1)
        return [{k: v[i] if len(v) > 1 else v[0] for k, v in axes.items()} for i in range(n)]
    count = math.prod(len(v) for v in axes.values())
    if count > MAX_TASKS:
        raise ctx.error(table, None, f"makes {count} combinations (more than {MAX_TASKS})")
    return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]


def _zip_flag(ctx, table, data) -> bool:
    z = data.get("zip", False)
    if not isinstance(z, bool):
        raise ctx.error(table, "zip", f"zip must be true or false, got {_show(z)}")
    return z


# ------------------------------------------------------------------------------------------------
# sections


def _bake_settings(ctx, data) -> list:
    table = ("bake",)
    if not isinstance(data, dict):
        raise ctx.error(table, None, f"must be a table, got {_show(data)}")
    _read(ctx, table, data, {**{k: _any for k in BAKE_DEFAULTS}, "zip": _BOOL})
    axes = {k: _axis(ctx, table, k, v) for k, v in data.items() if k != "zip"}
    out = []
    for combo in _expand(ctx, table, axes, _zip_flag(ctx, table, data)):
        s = {**BAKE_DEFAULTS, **combo}
        _check_settings(ctx, table, s, bake=True)
        out.append((s, {k: combo[k] for k in combo if len(axes[k]) > 1}))
    return out


def _check_settings(ctx, table, s, bake=False):
    def need(key, ok, what):
        if key in s and s[key] is not None and not ok(s[key]):
            raise ctx.error(table, key, f"{key} must be {what}, got {_show(s[key])}")

    integer = lambda v: isinstance(v, int) and not isinstance(v, bool)
    need("facets", lambda v: integer(v) and _ok(_check_count, v), "an integer in [1, 2^30]")
    need("directions", lambda v: integer(v) and 2 <= v <= 32, "an integer grid size K in [2, 32]")
    need("seed", lambda v: integer(v) and v >= 0, "an integer >= 0")
    if bake:
        need("lobes", lambda v: not isinstance(v, (bool, float)) and _ok(_check_lobes, v), "an integer in [1, 128] "
             'or "auto"')
        need("normal_res", lambda v: integer(v) and 1 <= v <= 1024, "an integer in [1, 1024]")
        need("method", lambda v: v in BAKE_METHODS, f"one of {', '.join(map(repr, BAKE_METHODS))}")
        need("route", lambda v: v in ROUTES, f"one of {', '.join(map(repr, ROUTES))}")
        need("backend", lambda v: isinstance(v, str) and re.fullmatch(r"(auto|warp|opencl)(:.+)?", v) is not None,
             "auto, warp, warp:cpu, warp:cuda, opencl, opencl:cpu, opencl:gpu or opencl:<name>")


def _ok(check, v) -> bool:
    try:
        check(v)
        return True
    except (TypeError, ValueError):
        return False


def _family_params(fn_name):
    sig = inspect.signature(getattr(geometry, fn_name))
    return {n: p.default for n, p in sig.parameters.items() if p.kind == p.KEYWORD_ONLY}


def _is_vector(name, default) -> bool:
    return isinstance(default, (tuple, list)) or name.endswith("color")


def _tiles(ctx, data) -> list:
    """→ list of (entry name or None, table, [(tile spec, SmallScale), ...])."""
    if not data:
        raise SceneError(f"{ctx.name}: the job has no [[tile]]: add at least one", ctx.path)
    out, names = [], set()
    for i, item in enumerate(data):
        table = ("tile", i)
        if not isinstance(item, dict):
            raise ctx.error(table, None, f"must be a table, got {_show(item)}")
        kinds = [k for k in ("family", "mesh", "heightfield") if k in item]
        if len(kinds) != 1:
            raise ctx.error(table, kinds[1] if kinds else None, "needs exactly one of family = \"pyramid\" (a built-in "
                            f"family: {', '.join(FAMILIES)}), mesh = \"file.obj\" or heightfield = \"image.png\"")
        kind = kinds[0]
        name = item.get("name")
        if name is not None and (not isinstance(name, str) or not name):
            raise ctx.error(table, "name", f"name must be a non-empty string, got {_show(name)}")
        if name is not None and name in names:
            raise ctx.error(table, "name", f"tile name {name!r} is used by an earlier [[tile]]")
        names.add(name)
        if kind == "family":
            family = item["family"]
            if not isinstance(family, str) or family not in FAMILIES:
                raise ctx.error(table, "family", f"unknown tile family {_show(family)}; choose one of "
                                                 f"{', '.join(FAMILIES)} (or mesh = / heightfield = a file)")
            fn, fixed = FAMILIES[family]
            params = _family_params(fn)
        elif kind == "mesh":
            fn, fixed, params = None, {}, {"period": ()}  # (a vector key; default: the mesh's extent)
        else:
            fn, fixed = "heightfield_from_image", {}
            params = {k: v for k, v in _family_params(fn).items()}
        allowed = {kind: _any, "name": _any, "zip": _BOOL, **{k: _any for k in params}}
        _read(ctx, table, item, allowed, where=f" for a {item[kind] if kind == 'family' else kind} tile")
        axes = {kind: _axis(ctx, table, kind, item[kind])}
        axes.update({k: _axis(ctx, table, k, v, _is_vector(k, params[k])) for k, v in item.items()
                     if k in params})
        variants = []
        for combo in _expand(ctx, table, axes, _zip_flag(ctx, table, item)):
            given = {k: v for k, v in combo.items() if k != kind}
            variants.append(_build_tile(ctx, table, kind, combo[kind], fn, fixed, given,
                                        {k for k in axes if len(axes[k]) > 1 and k != kind}))
        out.append((name, table, variants))
    return out


def _build_tile(ctx, table, kind, what, fn, fixed, given, swept):
    if kind == "family":
        if not isinstance(what, str) or what not in FAMILIES:
            raise ctx.error(table, kind, f"unknown tile family {_show(what)}; choose one of {', '.join(FAMILIES)}")
        tile = _build(ctx, table, {**fixed, **given}, getattr(geometry, fn))
        shown = ", ".join(f"{k}={_fmt(v)}" for k, v in given.items())
        spec = {"kind": "family", "family": what, "fn": fn, "params": {**fixed, **given},
                "label": f"{what}({shown})" if shown else what}
    else:
        if not isinstance(what, str):
            raise ctx.error(table, kind, f"{kind} must be a file name, got {_show(what)}")
        full = ctx.resolve(what)
        if not os.path.isfile(full):
            raise ctx.error(table, kind, f"no such {'mesh' if kind == 'mesh' else 'image'} file: {what} "
                                         f"(looked for {full})")
        try:
            with _located_warnings(ctx, table, given, kind):
                if kind == "mesh":
                    period = given.get("period")
                    tile = SmallScale.load(full, period=None if period is None else tuple(period))
                else:
                    tile = geometry.heightfield_from_image(full, **given)
        except (ValueError, TypeError) as exc:
            key = next((k for k in given if re.search(rf"\b{re.escape(k)}\b", str(exc))), kind)
            raise ctx.error(table, key, f"{kind} {what!r}: {exc}") from None
        shown = ", ".join(f"{k}={_fmt(v)}" for k, v in given.items() if k in swept)
        base = os.path.basename(what)
        spec = {"kind": kind, "path": full, "sha256": file_sha256(full), "params": given,
                "label": f"{base}({shown})" if shown else base}
    spec["swept"] = sorted(swept)
    spec["n_materials"] = int(tile.n_materials)
    return spec, tile


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (list, tuple)):
        return "/".join(_fmt(x) for x in v)
    return str(v)


def _materials(ctx, data, tiles) -> list:
    """→ list of (table, tile names or None, [(brdfs, material info), ...])."""
    if not data:
        raise SceneError(f"{ctx.name}: the job has no [[material]]: add at least one (brdf = \"lambert:albedo=0.5\")",
                         ctx.path)
    names = {n for n, _, _ in tiles if n is not None}
    out = []
    for i, item in enumerate(data):
        table = ("material", i)
        if not isinstance(item, dict):
            raise ctx.error(table, None, f"must be a table, got {_show(item)}")
        only = item.get("tiles")
        if only is not None:
            if isinstance(only, str):
                only = [only]
            if not isinstance(only, list) or not only or not all(isinstance(x, str) for x in only):
                raise ctx.error(table, "tiles", f"tiles must be a list of [[tile]] names, got {_show(item['tiles'])}")
            for n in only:
                if n not in names:
                    raise ctx.error(table, "tiles", f"no [[tile]] has name = {n!r} (named tiles: "
                                                    f"{', '.join(map(repr, sorted(names))) or 'none'})")
        common = {"tiles": _any, "name": _any}
        if "brdf" in item and "type" in item:
            raise ctx.error(table, "type", "give either brdf = \"name:key=value,...\" or type = \"...\" with its "
                                           "parameters, not both")
        if "brdf" in item:
            _read(ctx, table, item, {"brdf": _any, **common})
            specs = item["brdf"]
            if isinstance(specs, str):
                specs = [specs]
            if not isinstance(specs, list) or not specs or not all(isinstance(s, str) for s in specs):
                raise ctx.error(table, "brdf", "brdf must be a BRDF string (\"blinnphong:exponent=128\") or a non-empty"
                                               f" list of them, one per material id, got {_show(item['brdf'])}")
            brdfs = _brdfs(ctx, table, specs)
            variants = [(brdfs, {"label": " | ".join(specs), "params": {}})]
        elif "type" in item:
            kind = item["type"]
            if not isinstance(kind, str) or kind.lower() not in _BRDF_KEYS:
                raise ctx.error(table, "type", f"unknown BRDF type {_show(kind)}; choose one of "
                                               f"{', '.join(map(repr, _BRDF_KEYS))}")
            kind = kind.lower()
            keys = {k: v for k, v in _BRDF_KEYS[kind].items() if k not in _MAPS}
            _read(ctx, table, item, {"type": _any, "zip": _BOOL, **common, **{k: _any for k in keys}},
                  where=f" for {_article(kind)} {kind} material")
            axes = {k: _axis(ctx, table, k, v, vector=k in ("ks", "kd", "albedo")) for k, v in item.items()
                    if k in keys}
            cls = brdf_mod._BRDF_NAMES[kind]
            variants = []
            for combo in _expand(ctx, table, axes, _zip_flag(ctx, table, item)):
                b = _build(ctx, table, combo, cls)
                shown = ",".join(f"{k}={_fmt(v)}" for k, v in combo.items())
                variants.append(([b], {"label": f"{kind}:{shown}" if shown else kind,
                                       "params": {k: combo[k] for k in combo if len(axes[k]) > 1}}))
        else:
            raise ctx.error(table, None, "needs brdf = \"name:key=value,...\" (the --brdf syntax) or type = "
                                         f"one of {', '.join(map(repr, _BRDF_KEYS))} with its parameters")
        if item.get("name") is not None and not isinstance(item["name"], str):
            raise ctx.error(table, "name", f"name must be a string, got {_show(item['name'])}")
        for _, info in variants:
            info["name"] = item.get("name")
            if info["name"]:
                info["label"] = f"{info['name']}: {info['label']}"
        out.append((table, only, variants))
    return out


def _scenes(ctx, data) -> list:
    """Each [[scene]]: its file checked (every table and key, as `warp-biscale render` reads it, with bake
    materials checked, not baked) and its slot found → list of scene specs."""
    out, seen = [], set()
    for i, item in enumerate(data):
        table = ("scene", i)
        schema = {"path": _check_str, "slot": _check_str, "name": _check_str, "width": _INT, "height": _INT,
                  "aa": _INT, "shadow_samples": _INT, "exposure": _check_num,
                  "block_rays": _check_block_rays}
        v = _read(ctx, table, item, schema, required=("path", "slot"))
        full = ctx.resolve(v["path"])
        if not os.path.isfile(full):
            raise ctx.error(table, "path", f"no such scene file: {v['path']} (looked for {full})")
        name = v.get("name") or os.path.splitext(os.path.basename(v["path"]))[0]
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
            raise ctx.error(table, "name" if "name" in v else "path",
                            f"scene name {name!r} must be letters, digits, '.', '_' or '-' (it names image files)")
        if name in seen:
            raise ctx.error(table, "name" if "name" in v else "path",
                            f"a second scene named {name!r}: give each [[scene]] its own name = \"...\"")
        seen.add(name)
        for key, lo, hi in (("width", 1, 16384), ("height", 1, 16384), ("aa", 1, 256), ("shadow_samples", 1, 256)):
            if key in v and not lo <= v[key] <= hi:
                raise ctx.error(table, key, f"{key} must be an integer in {lo}..{hi}, got {v[key]}")
        try:
            sf = open_scene(full, v["slot"], None, dry=True)
        except (ValueError, OSError) as exc:
            raise scene_error(ctx, table, v, exc) from None
        exposure = v.get("exposure", sf.exposure)
        out.append({"name": name, "path": full, "sha256": file_sha256(full), "slot": v["slot"],
                    "width": v.get("width", sf.width), "height": v.get("height", sf.height),
                    # the rays: the [[scene]]'s, else the scene file's [render] (aa: else 1)
                    "aa": v.get("aa", sf.aa or 1), "shadow_samples": v.get("shadow_samples", sf.shadow_samples),
                    "exposure": exposure, "block_rays": v.get("block_rays", sf.block_rays),
                    "occlusion_samples": sf.occlusion_samples})
    return out


def _check_str(v):
    return (v, None) if isinstance(v, str) and v else (None, "a non-empty string")


def _check_num(v):
    return (float(v), None) if _is_num(v) and math.isfinite(v) else (None, "a finite number")


def _material_dict(b, sums: dict) -> dict:
    """A task's record of one small-scale BRDF: an analytic one's type and parameters; a MERL table's file, as a
    mesh tile's (its path, which the worker reads, and SHA-256, so that an edited file is another task; `sums`
    keeps each file's digest for the job)."""
    if b.kind == brdf_mod.MEASURED:
        path = os.path.abspath(b.source)
        if path not in sums:
            sums[path] = file_sha256(path)
        return {"type": "MeasuredBRDF", "path": path, "sha256": sums[path], "interpolation": b.interpolation}
    return _brdf_to_dict(b)


def _cross(ctx, tiles, materials, bakes, truth, compare, scenes) -> list:
    tasks, seen, sums = [], {}, {}
    for tile_name, _, tile_variants in tiles:
        for mat_table, only, mat_variants in materials:
            if only is not None and tile_name not in only:
                continue
            for (spec, tile), (brdfs, minfo) in itertools.product(tile_variants, mat_variants):
                if len(brdfs) > 1 and len(brdfs) < tile.n_materials:
                    raise ctx.error(mat_table, "brdf", f"tile {spec['label']} uses material ids "
                                    f"0..{tile.n_materials - 1}: give {tile.n_materials} BRDF strings (or one for "
                                    f"all), got {len(brdfs)}")
                mats = brdfs * tile.n_materials if len(brdfs) == 1 else brdfs
                mat_dicts = [_material_dict(b, sums) for b in mats]
                for settings, swept in bakes:
                    t = _task(spec, mat_dicts, minfo, settings, swept, truth, compare, scenes)
                    if t.hash in seen:  # the same inputs twice (two entries listing one combination): one task
                        continue
                    seen[t.hash] = t
                    tasks.append(t)
                    if len(tasks) > MAX_TASKS:
                        raise ctx.error((), None, f"the job makes more than {MAX_TASKS} tasks")
    if not tasks:
        raise SceneError(f"{ctx.name}: the job makes no task (every [[material]] names tiles = [...] that no [[tile]] "
                         "matches)", ctx.path)
    return tasks


def _task(spec, mat_dicts, minfo, settings, swept, truth, compare, scenes) -> Task:
    truth_s = None if truth is None else {**truth, "directions": truth["directions"] or settings["directions"]}
    tile_spec = {k: v for k, v in spec.items() if k != "label"}
    tile_key = digest({k: tile_spec[k] for k in ("kind", "family", "fn", "path", "sha256", "params") if k in tile_spec})
    # block_rays and occlusion_samples only where set: the hashes of the tasks that do not stay what they were
    scene_in = [{k: s[k] for k in ("name", "sha256", "slot", "width", "height", "aa", "shadow_samples", "exposure")}
                | {k: s[k] for k in ("block_rays", "occlusion_samples") if s.get(k) is not None} for s in scenes]
    h = digest({"format": FORMAT, "tile": tile_key, "materials": mat_dicts, "bake": settings, "truth": truth_s,
                "compare": compare, "scenes": scene_in})
    bake_label = ", ".join(f"{k}={_fmt(v)}" for k, v in swept.items())
    label = f"{spec['label']} × {minfo['label']}" + (f" [{bake_label}]" if bake_label else "")
    return Task(hash=h, label=label, tile=dict(spec), tile_key=tile_key, materials=mat_dicts, material=dict(minfo),
                bake=dict(settings), truth=truth_s, compare=bool(compare), scenes=[dict(s) for s in scenes])


class SlotError(SceneError):
    """A scene file without the material slot a job names (said at the job's slot key)."""


def open_scene(path, slot, material, dry=False, backend=None):
    """Read a scene file as `warp-biscale render` does, its [material.SLOT] replaced by `material` (never
    built: a bake material there is not baked) → scenefile.SceneFile. `dry`: check every table and key (bake
    materials checked, not baked) and build no Scene. A file with no [material.SLOT], or none of whose
    objects uses it, is a `SlotError`; every other mistake the scene file's own located SceneError."""
    from . import scenefile as sfm
    from .progress import as_progress
    from .scene import Mesh, Scene

    with open(path, "rb") as f:
        data = f.read()
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{os.path.basename(path)}: not UTF-8 text ({exc})", path) from None
    ctx = _Ctx(text, path, os.path.dirname(os.path.abspath(path)))
    doc = _parse_toml(ctx, text)
    for key in doc:
        if key not in sfm.TOP_LEVEL:
            raise ctx.error((), key, f"unknown table or key {key!r} (allowed: {', '.join(sfm.TOP_LEVEL)})")
    sf = sfm.SceneFile(scene=None, path=path)
    scene_opts = sfm._render_settings(ctx, doc.get("render", {}), sf)
    if backend is not None:
        sf.backend = backend
    cam = _read(ctx, ("camera",), doc.get("camera", {}), sfm.CAMERA_KEYS)
    defs = sfm._material_defs(ctx, doc.get("material", {}))
    if slot not in defs:
        raise SlotError(f"{ctx.name} has no [material.{slot}] for the baked material to replace (its materials: "
                        f"{', '.join(map(repr, defs)) or 'none'})", path)
    meshes, used = sfm._objects(ctx, doc.get("object", []), defs)
    if slot not in used:
        raise SlotError(f"no [[object]] of {ctx.name} uses material {slot!r}: the baked material would not be seen",
                        path)
    env = sfm._environment(ctx, doc.get("environment"))
    lights = sfm._lights(ctx, doc.get("light", []))
    camera = sfm._camera(ctx, cam, meshes, sf)
    prog = as_progress(False)
    for name, (kind, values) in defs.items():
        if name == slot:
            sf.materials[name] = material
            continue
        sf.materials[name] = sfm._material(ctx, ("material", name), kind, values, sf, name,
                                           name in used and not dry, prog)
    sf.material_names = list(used)
    if dry:
        return sf
    mesh = Mesh.merge(meshes) if len(meshes) > 1 else meshes[0]
    sf.scene = Scene(mesh, [sf.materials[n] for n in used], camera, env, lights, **scene_opts)
    return sf


def scene_error(ctx, table, v, exc) -> SceneError:
    """A scene file's error at the job's [[scene]] entry: a missing slot at its slot key, anything else at
    its path key with the scene file's own file:line after it."""
    if isinstance(exc, SlotError):
        return ctx.error(table, "slot", f"slot {v['slot']!r}: {exc}")
    msg = str(exc) if isinstance(exc, ValueError) else f"cannot be read: {exc}"
    return ctx.error(table, "path", f"scene file {v['path']}: {msg}")
