"""Command line: ``warp-biscale demo`` (bake a tile and render a scene with it), ``render`` (a TOML scene
file to PNG / EXR / HDR), ``view`` (the interactive viewer), ``edit`` (the bi-scale editor), ``bake`` (the
effective BRDF of a tile: SG, ASG or matrix), ``truth`` (its ground truth), ``ball`` (a material thumbnail),
``batch`` (a job file of bakes and renders, on a Dask cluster), ``export`` (a baked material for Mitsuba 3) and
``backends``."""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

from . import __version__, batch, demo
from .backend import backends, get_backend
from .bake import bake
from .brdf import Lambert, parse_brdf
from .device import one_line
from .effective import EffectiveBRDF, compare
from .geometry import BUILTIN_TILES, load_tile
from .images import check_exposure
from .io import atomic_path, check_output
from .tomlschema import _Ctx
from .litsphere import LitSphere, check_angles, check_holdable, check_resolution
from .loading import load
from .lighting import SOURCE_SHADOW_SAMPLES
from .measured import MeasuredBRDF, small_scale_brdf
from .montecarlo import missing_provenance
from .progress import as_progress, set_quiet
from .render import METHODS, OCCLUSION_SAMPLES, SHADOW_SAMPLES, check_aa, material_ball
from .scene import _integer
from .trace import OCCLUSION_SAMPLES_MAX, check_occlusion_samples, check_shadow_samples
from .scenefile import _MAPS as TEXTURE_MAPS  # (a material table's texture keys)
from .scenefile import _environment as scenefile_environment
from .scenefile import load_scene, tomllib  # (tomllib, or tomli before Python 3.11)
from .truth import (BOUNCE_PATHS, MAX_BOUNCES, MAX_PATHS, MAX_TRUTH_DIRECTIONS, _check_bounces, _check_count,
                    ground_truth)
from .viewer import view


def _materials(specs, tile):

    if not specs:
        return [Lambert(0.5)] * tile.n_materials
    mats = [small_scale_brdf(s) for s in specs]
    if len(mats) == 1 and tile.n_materials > 1:
        mats = mats * tile.n_materials  # one BRDF for every material id
    return mats


def _incidence_slices(gt, thetas_i, n_out=61):
    """f̄ in the plane of incidence: ωi at θi (φ = 0), ωo from −85° to 85° (negative = φ 180°)."""
    theta_o = np.radians(np.linspace(-85, 85, n_out))
    rows = []
    for ti in np.radians(thetas_i):
        wi = np.tile([np.sin(ti), 0.0, np.cos(ti)], (n_out, 1))
        wo = np.stack([np.sin(theta_o), np.zeros(n_out), np.cos(theta_o)], 1)
        rows.append(gt.eval(wi, wo))
    return np.degrees(theta_o), np.array(rows)


def _print_table(gt, thetas_i, file=None):
    file = sys.stdout if file is None else file  # (at call time: sys.stdout may have been redirected since import)
    cols = [-60, -30, 0, 30, 60]
    bounces = f", {gt.bounces} bounces ({gt.paths} paths)" if gt.bounces > 1 else ""
    print(f"\nf̄(ωi, ωo) (mean of RGB, cos θi included) in the plane of incidence, tile {gt.tile!r}, "
          f"{gt.facets} facets, K={gt.directions}{bounces}, backend {gt.backend}", file=file)
    print("θi \\ θo " + "".join(f"{c:>10d}°" for c in cols), file=file)
    for ti in thetas_i:
        t = np.radians(ti)
        wi = np.tile([np.sin(t), 0, np.cos(t)], (len(cols), 1))
        to = np.radians(cols)
        wo = np.stack([np.sin(to), np.zeros(len(cols)), np.cos(to)], 1)
        f = gt.eval(wi, wo).mean(axis=1)
        print(f"{ti:>6.0f}° " + "".join(f"{x:>11.5f}" for x in f), file=file)
    alb = gt.albedo().mean(axis=1)
    # Energy conservation bounds the albedo by the small-scale BRDFs' own; what can still put a value above it:
    # with bounces, mostly the noise of the Monte Carlo paths (docs/design.md §4.6: the per-ωo spread is Monte
    # Carlo noise; a finer grid does not lower it), else the quadrature of a lobe narrower than the grid's spacing.
    why = (f"the bounces 2..{gt.bounces} are a Monte Carlo estimate from {gt.paths} paths a direction pair, whose "
           "noise can put a value above the small-scale BRDFs' own albedo (more --paths narrows it); a lobe "
           "narrower than the grid's spacing is also over- or under-counted here" if gt.bounces > 1 else
           "a lobe narrower than the grid's spacing is over- or under-counted here: a value above the small-scale "
           "BRDFs' own albedo is quadrature error, not an energy gain")
    print(f"directional albedo by {gt.directions}×{gt.directions} grid quadrature: min {alb.min():.4f}, max "
          f"{alb.max():.4f} ({why})", file=file)
    print("stage times (s): " + ", ".join(f"{k} {v:.3f}" for k, v in gt.timings.items()), file=file)


def _plot(gt, path, thetas_i):
    # matplotlib is imported only to draw this plot: it costs a few tenths of a second at every start.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    theta_o, slices = _incidence_slices(gt, thetas_i)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ti, f in zip(thetas_i, slices):
        axes[0].plot(theta_o, f.mean(axis=1), label=f"θi = {ti:g}°")
    axes[0].set_xlabel("θo in the plane of incidence (°; negative: back side)")
    axes[0].set_ylabel("f̄ (cos θi included), mean RGB")
    axes[0].set_title(f"{gt.tile}: effective BRDF slices")
    axes[0].legend()
    axes[0].grid(alpha=0.3)
    im = axes[1].imshow(gt.table.mean(axis=2), origin="lower", cmap="magma", aspect="auto")
    axes[1].set_xlabel("ωo grid index")
    axes[1].set_ylabel("ωi grid index")
    axes[1].set_title(f"f̄ on the {gt.directions}²×{gt.directions}² grid ({gt.facets} facets)")
    fig.colorbar(im, ax=axes[1])
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _bounce_args(bounces, paths, prefix=""):
    """(B, P) of --{prefix}bounces and --{prefix}paths (None: the library's defaults), checked as
    wb.ground_truth checks them before any work, the error naming the flag."""
    try:
        checked = _check_bounces(1 if bounces is None else bounces, BOUNCE_PATHS if paths is None else paths)
    except ValueError as exc:
        raise ValueError(f"--{prefix}{exc}") from None
    if paths is not None and checked[0] == 1:  # (a single bounce traces no paths: the option would do nothing)
        raise ValueError(f"--{prefix}paths is for --{prefix}bounces above 1 (interreflection's paths a facet)")
    return checked


def cmd_truth(args):
    check_output(args.output, (".png",), "--output")
    if args.save:
        check_output(args.save, (".npz",), "--save")
    bounces, paths = _bounce_args(args.bounces, args.paths)
    seed = _seed(args.seed)
    tile = load_tile(args.tile)
    mats = _materials(args.brdf, tile)
    _check_backend(args.backend)
    gt = ground_truth(tile, mats, facets=args.facets, directions=args.directions, backend=args.backend,
                         seed=seed, progress=not args.quiet, bounces=bounces, paths=paths)
    thetas = [0, 30, 60, 75]
    if not args.quiet:
        _print_table(gt, thetas)
    if args.output:
        _plot(gt, args.output, thetas)
        _say(args, f"wrote {args.output}")
    if args.save:
        gt.save(args.save)
        _say(args, f"wrote {args.save}")
    return 0


def cmd_bake(args):
    if args.truth is not None:  # (0 ran no truth and said nothing: refused as the truth's own count check does)
        try:
            _check_count(args.truth)
        except ValueError as exc:
            raise ValueError(f"--truth {exc}") from None
    check_output(args.output, (".wbm", ".npz"), "--output")
    for flag, value in (("--truth-bounces", args.truth_bounces), ("--truth-paths", args.truth_paths)):
        if value is not None and not args.truth:
            raise ValueError(f"{flag} is for the ground truth of --truth FACETS")
    bounces, paths = _bounce_args(args.truth_bounces, args.truth_paths, "truth-")
    seed = _seed(args.seed)
    tile = load_tile(args.tile)
    mats = _materials(args.brdf, tile)
    _check_backend(args.backend)
    lobes = args.lobes if args.lobes == "auto" else _int_arg("--lobes", args.lobes)
    if args.method == "matrix" and (args.lobes != "8" or args.route != "facets"):
        raise ValueError("--method matrix takes no --lobes or --route (Wu's factors keep ranks by power)")
    mat = bake(tile, mats, method=args.method, lobes=lobes, directions=args.directions, normal_res=args.normal_res,
                  facets=args.facets, backend=args.backend, seed=seed, route=args.route,
                  progress=not args.quiet)
    if not args.quiet:
        info = mat.info
        fit = (f" (NDF fit error {info['ndf_error']:.2%} at sharpness {info['ndf_probe_sharpness']:g})"
               if info.get("ndf_error") is not None else "")
        lobes_said = _lobes_said(mat, fit)
        if "method_choice" in info:
            print(f"method auto: {info['method_choice']['chosen'].upper()} ({info['method_choice']['why']})")
        print(f"{tile.name}: {lobes_said}{info['nonempty_bins']} non-empty normal bins, "
              f"{mat.nbytes_per_material / 2**20:.2f} MiB per material")
        print("  ".join(f"{k} {v * 1e3:.1f} ms" for k, v in mat.timings.items()))
    if args.truth:
        gt = ground_truth(tile, mats, facets=args.truth, directions=args.directions, backend=args.backend,
                             seed=seed + 1, progress=not args.quiet, bounces=bounces, paths=paths)
        c = compare(mat, gt)
        what = f"{args.truth} facets" + (f", {bounces} bounces ({paths} paths)" if bounces > 1 else "")
        _say(args, f"against the ground truth ({what}): PSNR {c['psnr']:.1f} dB, RMSE {c['rmse']:.3g}, "
                   f"max relative error {c['max_rel_error']:.3g}")
    mat.save(args.output)
    _say(args, f"wrote {args.output}")
    return 0


def _say(args, text):
    """A result line: on stdout unless -q."""
    if not args.quiet:
        print(text)


def _seed(seed):
    """--seed, checked here: numpy's own refusal of a negative seed ("expected non-negative integer") names no
    option."""
    return _integer("--seed", seed, 0)


def _check_backend(name):
    """--backend, resolved before the work but after the cheap input checks (starting a toolkit takes a second or
    two, which a refused tile or option should not wait for; None: the scene file's, checked as it loads): an
    unknown name is said naming the option, not, as a scene file's bake would, the file's material that uses it."""
    if name is None:
        return
    try:
        get_backend(name)
    except ValueError as exc:
        raise ValueError(f"--backend: {exc}") from None


def _int_arg(name, text):
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{name} must be an integer or 'auto', got {text!r}") from None


BACKEND_KINDS = ("warp", "opencl")  # backends()' kinds, and the device types each may have
BACKEND_TYPES = ("cpu", "gpu")


def cmd_backends(args):
    for r in args.require or ():  # a kind no backend has is a typo, not a missing backend: before the probes
        kind, _, kind_type = r.partition(":")
        if kind not in BACKEND_KINDS or kind_type not in ("", *BACKEND_TYPES):
            raise ValueError(f"--require {r!r}: the kinds are {' and '.join(BACKEND_KINDS)}, each optionally with "
                             f":{' or :'.join(BACKEND_TYPES)} (e.g. opencl:cpu, warp:gpu)")
    entries = backends()
    if not args.quiet:
        for b in entries:
            state = "usable" if b["usable"] else f"unusable: {b['reason']}"
            print(f"{b['name']:<28} {b['device'] or '-':<48} {state}")
    usable = [b for b in entries if b["usable"]]
    _say(args, f"auto picks {get_backend('auto').name}" if usable else "no usable backend here")
    missing = [r for r in args.require or ()
               if not any(b["kind"] == r.partition(":")[0] and r.partition(":")[2] in ("", b["type"]) for b in usable)]
    for r in missing:
        print(f"error: no usable {r} backend here", file=sys.stderr)
    return 1 if missing or not usable else 0


# ------------------------------------------------------------------------------------------------ rendering

IMAGE_EXTENSIONS = (".png", ".exr", ".hdr", ".pic")


def _check_output(path, what="output"):
    check_output(path, IMAGE_EXTENSIONS, what, "PNG is tone-mapped; EXR and HDR keep the linear radiance")


def _size(values, width, height):
    """--size W [H] → (width, height): one number sets the width and keeps the aspect of (width, height)."""
    if values is None:
        return width, height
    if len(values) > 2:
        raise ValueError(f"--size takes a width and an optional height, got {len(values)} numbers")
    for v in values:
        if not 1 <= v <= 16384:
            raise ValueError(f"--size values must be integers in 1..16384, got {v}")
    if len(values) == 2:
        return values[0], values[1]
    return values[0], max(1, round(values[0] * height / width))


def _lobes_said(mat, fit: str = "") -> str:
    """'8 lobes, ' (SG), '8 ASG lobes, ' or '' (the matrix method keeps ranks, not lobes), from the bake's info:
    `lobes` itself is SG lobes only, which an ASG or matrix material refuses."""
    if "lobes" not in mat.info:
        return ""
    return f"{mat.info['lobes']} {'ASG ' if getattr(mat, 'method', None) == 'asg' else ''}lobes{fit}, "


def _print_bakes(sf):
    for key, seconds in sf.timings.items():
        if key.startswith("bake "):
            name = key[5:]
            mat = sf.materials[name]
            print(f"baked material {name!r}: tile {sf.tiles[name].name}, {mat.info.get('facets')} facets, "
                  f"{_lobes_said(mat)}K={mat.directions}, in {seconds:.2f} s")


def _print_rendering(result, path, exposure=0.0, names=None):
    h, w = result.image.shape[:2]
    print("stage times: " + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in result.timings.items()))
    info = result.info
    for i, source in info.get("truth_source", {}).items():
        name = repr(names[i]) if names else str(i)
        how = {"computed": "computed", "memory": "reused", "given": "given"}.get(source, f"read from {source}")
        print(f"ground truth of material {name}: {how} ({info['effective_brdf'][i]})")
    if "stderr_rms" in info:  # (the Monte Carlo reference's noise, as its Python result holds it)
        print(f"Monte Carlo: {info.get('samples')} samples a pixel, standard error (RMS over the hit pixels) "
              f"{info['stderr_rms']:.3g}")
    print(f"wrote {path} ({w}×{h} pixels, method {info.get('method')}, backend {info.get('backend')}"
          + (f", exposure {exposure:+g}" if exposure and path.lower().endswith(".png") else "") + ")")


def cmd_render(args):

    _check_output(args.output)
    if args.exposure is not None:
        check_exposure(args.exposure)
        if args.exposure != 0 and not args.output.lower().endswith(".png"):  # (EXR and HDR hold the radiance)
            raise ValueError(f"--exposure scales a PNG's tone mapping; {args.output} (EXR/HDR) keeps the radiance "
                             "itself: leave --exposure out, or write a .png")
    if args.aa is not None:
        check_aa(args.aa)
    if args.shadow_samples is not None:
        check_shadow_samples(args.shadow_samples)
    if args.occlusion_samples is not None:
        check_occlusion_samples(args.occlusion_samples)
    if args.method == "mc":
        _refuse_sg_options(args)
    if args.truth_bounces is not None or args.truth_paths is not None:
        _bounce_args(args.truth_bounces, args.truth_paths, "truth-")  # before the scene's bakes
    if args.truth_facets is not None:  # (before the scene's bakes, as the truth checks it, named as the flag)
        try:
            _check_count(args.truth_facets)
        except ValueError as exc:
            raise ValueError(f"--truth-{exc}") from None
    if args.truth_directions is not None and not 2 <= args.truth_directions <= MAX_TRUTH_DIRECTIONS:
        raise ValueError(f"--truth-directions must be a grid size K in [2, {MAX_TRUTH_DIRECTIONS}], "
                         f"got {args.truth_directions}")
    if args.size is not None:
        _size(args.size, 1, 1)  # (its checks; the aspect kept is the file's, known once it loads)
    _check_scene_options(args)
    _check_backend(args.backend)
    prog = as_progress(not args.quiet)
    sf = load_scene(args.scene, backend=args.backend, progress=prog, method=args.method)
    if args.size is not None:
        sf.resize(*_size(args.size, sf.width, sf.height))
    method = args.method or sf.method
    options = sf.render_options(method)
    for _, key, value in _mc_options(args):  # (given for another method: refused by _check_scene_options)
        if value is not None:
            options[key] = value
    if method == "mc":
        _refuse_sg_options(args)
    else:
        options["aa"] = options.get("aa", FILE_AA) if args.aa is None else args.aa  # flag, then the file's [render]
        if args.shadow_samples is not None:
            options["shadow_samples"] = args.shadow_samples
        if args.occlusion_samples is not None:
            options["occlusion_samples"] = args.occlusion_samples
        if args.every_ray_per_sample:
            options["split_rays"] = False
        side = args.block_rays if args.block_side is None else args.block_side  # (at most one is given)
        if side is not None:
            options["block_rays"] = side
        if args.aa_shading is not None:
            options["aa_shading"] = args.aa_shading
    if method == "mc" and args.mc_fallback is None:
        # Before the render starts: a material file of format 1 records no tile to compute the truth from.
        for i in missing_provenance(sf.scene):
            mat = sf.scene.materials[i]
            where = f" ({mat.path})" if mat.path else ""
            raise ValueError(f"material {sf.material_names[i]!r}{where} does not record how it was baked (a material "
                             "file of format 1), so the Monte Carlo reference cannot compute its ground truth: "
                             "re-bake it (warp-biscale bake), or pass --mc-fallback sg to judge with its fit "
                             "(not exact)")
    exposure = sf.exposure if args.exposure is None else args.exposure
    if not args.quiet:
        _print_bakes(sf)
    result = sf.render(method=method, progress=prog, **options)
    prog.done()
    result.save(args.output, exposure=exposure)
    if not args.quiet:
        _print_rendering(result, args.output, exposure, sf.material_names)
    return 0


def _mc_options(args):
    """(flag, render option, value) of render's options for the Monte Carlo reference."""
    return (("--samples", "samples", args.samples), ("--mc-fallback", "fallback", args.mc_fallback),
            ("--truth-facets", "truth_facets", args.truth_facets),
            ("--truth-directions", "truth_directions", args.truth_directions),
            ("--truth-bounces", "truth_bounces", args.truth_bounces),
            ("--truth-paths", "truth_paths", args.truth_paths))


def _table(doc, key, kind=dict):
    value = doc.get(key)
    return value if isinstance(value, kind) else kind()


def _check_mc_floor(ctx, doc, said: str, samples: int) -> None:
    """The Monte Carlo reference's floor that the file alone shows, before its bakes: 2 samples for each light
    and for each of a lit environment's two strategies (the map and the cosine lobe; a glossy material adds its
    BRDF's, which the reference checks once its materials are made). The environment is made as the file says
    (milliseconds; a black one is not sampled); one the file cannot make is left to load_scene to say."""
    from .montecarlo import environment_is_sampled

    try:
        lit = environment_is_sampled(scenefile_environment(ctx, doc.get("environment")))
    except (ValueError, OSError):
        lit = False
    lights = sum(isinstance(x, dict) for x in _table(doc, "light", list))
    floor = 2 * (2 * lit + lights)
    if samples < floor:
        what = " and ".join([*(["its environment's 2"] if lit else []),
                             *([f"its {lights} light{'s' * (lights != 1)}"] if lights else [])])
        raise ValueError(f"{said} is too few for the Monte Carlo reference of this scene: at least "
                         f"{floor}, 2 for each sampling strategy ({what}; a glossy material's BRDF adds 2)")


def _check_scene_options(args):
    """What render's options need of the scene, checked on the scene file's TOML before load_scene bakes its
    materials (seconds to minutes) rather than when the render starts. A file that cannot be read, or a
    malformed table, is left to load_scene, whose errors name the file's line."""
    try:
        with open(args.scene, "rb") as f:
            text = f.read().decode("utf-8")
        doc = tomllib.loads(text)
    except (OSError, ValueError):  # (tomllib.TOMLDecodeError and UnicodeDecodeError are ValueErrors)
        return
    settings = _table(doc, "render")
    method = args.method or settings.get("method", "sg")
    if method not in METHODS:  # (a bad [render] method: load_scene's to say)
        return
    for flag, _, value in _mc_options(args):
        if value is not None and method != "mc":
            renderer = {"sg": "the SG renderer", "litsphere": "the lit-sphere shader"}[method]
            raise ValueError(f"{flag} is for --method mc ({renderer} has no such option)")
    samples = args.samples if args.samples is not None else settings.get("samples")
    if method == "mc" and isinstance(samples, int) and not isinstance(samples, bool) and samples < 2:
        # (the reference's floor, 2 a sampling strategy: a scene's own count is known once its materials are
        # made, and the reference says it then; a malformed value is load_scene's to say)
        why = f"must be at least 2 for the Monte Carlo reference (2 a sampling strategy), got {samples}"
        if args.samples is not None:
            raise ValueError(f"--samples {why}")
        raise _Ctx(text, args.scene, os.path.dirname(os.path.abspath(args.scene))).error(("render",), "samples",
                                                                                        f"samples {why}")
    if method == "mc" and isinstance(samples, int) and not isinstance(samples, bool):
        said = f"--samples {samples}" if args.samples is not None else f"[render] samples = {samples}"
        _check_mc_floor(_Ctx(text, args.scene, os.path.dirname(os.path.abspath(args.scene))), doc, said, samples)
    if method == "litsphere":
        for flag, value, why in (
                ("--occlusion-samples", args.occlusion_samples, "traces no occlusion rays"),
                ("--block-rays", args.block_rays if args.block_rays == 2 else None, "shares no rays between pixels"),
                ("--block-side", args.block_side if args.block_side not in (None, 1) else None,
                 "shares no rays between pixels"),
                ("--aa-shading", args.aa_shading if args.aa_shading == "pixel" else None, "shades each sample")):
            if value is not None:
                raise ValueError(f"{flag} is for the SG renderer (--method sg); the lit-sphere shader {why}")
        materials = _table(doc, "material")
        names = dict.fromkeys(o.get("material") for o in _table(doc, "object", list) if isinstance(o, dict))
        for name, table in ((n, materials.get(n)) for n in names if isinstance(n, str)):  # the objects' materials
            maps = [k for k in TEXTURE_MAPS if isinstance(table, dict) and k in table]
            if maps:
                raise ValueError(f"the lit-sphere method (--method litsphere) cannot shade textured materials: "
                                 f"material {name!r} has {' and '.join(maps)} (a lit sphere is one BRDF's response "
                                 "for the whole material); render it with --method sg or mc")


def _refuse_sg_options(args):
    for flag, value in (("--aa", args.aa), ("--shadow-samples", args.shadow_samples),
                        ("--occlusion-samples", args.occlusion_samples),
                        ("--every-ray-per-sample", args.every_ray_per_sample or None),
                        ("--block-rays", args.block_rays if args.block_rays == 2 else None),
                        ("--block-side", args.block_side if args.block_side not in (None, 1) else None),
                        ("--aa-shading", args.aa_shading)):
        if value is not None:
            raise ValueError(f"{flag} is for the SG renderer (--method sg); the Monte Carlo reference samples "
                             "pixel centres and lights as emitters")


def cmd_demo(args):

    _check_output(args.output)
    check_aa(args.aa)
    size = _size(args.size, demo.WIDTH, demo.HEIGHT)  # checked before the bake, as the backend is
    _check_backend(args.backend)
    t0 = time.perf_counter()
    prog = as_progress(not args.quiet)
    sf = demo.demo_scene(backend=args.backend, progress=prog)
    if args.size is not None:
        sf.resize(*size)
    if not args.quiet:
        _print_bakes(sf)
    result = sf.render(progress=prog, aa=args.aa)
    prog.done()
    result.save(args.output, exposure=sf.exposure)
    if not args.quiet:
        _print_rendering(result, args.output)
        print(f"demo done in {time.perf_counter() - t0:.1f} s: open {os.path.abspath(args.output)} (the scene of "
              "examples/bi-scale.toml in the source tree; `warp-biscale view` shows a scene interactively)")
    return 0


def load_material(spec: str):
    """A material from the command line: a lit-sphere folder, a MERL .binary file, a baked material file
    (.wbm / .npz), or a --brdf spec such as blinnphong:exponent=50,ks=0.5,kd=0.3."""
    if os.path.isdir(spec):
        return LitSphere.load(spec)
    if spec.lower().endswith(".binary"):
        return MeasuredBRDF.load(spec)
    if os.path.splitext(spec)[1].lower() in (".wbm", ".npz"):
        material = load(spec)
        if not isinstance(material, EffectiveBRDF):
            raise ValueError(f"{spec} holds a {type(material).__name__}, not a baked material")
        return material
    if os.path.isfile(spec):
        raise ValueError(f"{spec} is not a material file: give a baked material (.wbm/.npz), a MERL table (.binary), "
                         "a saved lit-sphere folder or a BRDF spec (e.g. blinnphong:exponent=50)")
    if ":" not in spec and not spec.isalpha():
        raise ValueError(f"material {spec!r} is neither a file nor a BRDF spec (e.g. blinnphong:exponent=50)")
    return parse_brdf(spec)


def cmd_export(args):
    material = load(args.material)
    if not isinstance(material, EffectiveBRDF):
        raise ValueError(f"{args.material} holds a {type(material).__name__}, not a baked material")
    out = args.output or os.path.splitext(os.path.basename(args.material))[0] + "-mitsuba"
    written = material.export_mitsuba(out)
    _say(args, f"wrote {', '.join(written.values())}; render with: python {written['script']} "
               "(needs Mitsuba 3: pip install mitsuba)")
    return 0


BALL_RESOLUTION, BALL_ANGLES = 512, (0.0, 45.0, 90.0, 135.0)  # a material made into a lit sphere for `ball`


def cmd_ball(args):
    _check_output(args.output)

    angles = check_angles(BALL_ANGLES if args.angles is None else args.angles)
    resolution = check_resolution(BALL_RESOLUTION if args.resolution is None else args.resolution)
    size = _integer("--size", args.size, 8, 8192)  # material_ball's range, checked before loading the material
    material = load_material(args.material)
    given = [flag for flag, value in (("--resolution", args.resolution), ("--angles", args.angles))
             if value is not None]
    if isinstance(material, LitSphere) and given:  # (drawn as saved: the images are what the folder holds)
        raise ValueError(f"{' and '.join(given)}: {args.material} is a saved lit sphere, drawn at its own resolution "
                         f"({material.resolution}) and angles ({', '.join(f'{a:g}' for a in material.angles)})")
    check_holdable(material, remedy="show it on a scene's object with `warp-biscale render` (its SG renderer or "
                                    "--method mc) instead")
    _check_backend(args.backend)
    result = material_ball(material, size=size, backend=args.backend, resolution=resolution, angles=angles)
    result.save(args.output, exposure=args.exposure)
    _say(args, f"wrote {args.output}: {material!r} as a lit-sphere ball ({result.timings['total']:.2f} s, "
               f"{result.info['texture_bytes'] / 2**20:.1f} MiB of textures)")
    return 0


def cmd_view(args):

    if args.screenshot:
        if not args.screenshot.lower().endswith(".png"):
            raise ValueError(f"--screenshot {args.screenshot!r} must be a .png")
        _check_output(args.screenshot, "--screenshot")
    size = _size(args.size, 1200, 600)
    if not 0 < args.render_scale <= 1:
        raise ValueError(f"--render-scale must be in (0, 1], got {args.render_scale:g}")
    _check_backend(args.backend)
    try:
        view(args.scene, screenshot=args.screenshot, size=size, backend=args.backend,
             progress=as_progress(not args.quiet), render_scale=args.render_scale)
    except RuntimeError as exc:  # no display, no OpenGL: say so, no traceback
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if args.screenshot:
        _say(args, f"wrote {args.screenshot}")
    return 0


def _frame_size(values):
    """--size of `edit` → (width, height): W [H] as the other commands take it (a width alone keeps 640x480's
    aspect), or the WxH this command took first."""
    if values is None:
        return 640, 480
    given = values
    if len(values) == 1 and "x" in values[0].lower():
        values = values[0].lower().split("x", 1)
    try:
        size = _size([int(v) for v in values], 640, 480)
    except ValueError:
        size = (0, 0)
    if min(size) < 16 or max(size) > 8192:  # (the editor's frame sizes)
        raise ValueError(f"--size must be WIDTH [HEIGHT] (or WIDTHxHEIGHT), each in 16..8192 pixels, e.g. 640 480, "
                         f"got {' '.join(given)!r}")
    return size


def _edit_target(args):
    """`edit --size 640x480 pyramid` (the --size before TARGET, as the command took it when --size was one WxH):
    --size's list takes TARGET too, so it is taken back from there."""
    if args.target is None and args.size and not args.size[-1].lower().replace("x", "").isdigit():
        args.target = args.size.pop()
    if args.target is None:
        raise ValueError("edit needs a TARGET: a tile family, a greyscale image, a mesh file or a saved design")
    return args.target


def cmd_edit(args):
    from .editor_gui import edit  # (pyvista and VTK load only for this command)

    target = _edit_target(args)
    size = _frame_size(args.size)
    if args.output is not None:  # (before the window opens: the design is written there when the user saves)
        if not args.output.lower().endswith(".toml"):
            raise ValueError(f"-o {args.output!r}: a design is saved as a scene file, which must end in .toml")
        check_output(args.output)
    if args.screenshot:
        if not args.screenshot.lower().endswith(".png"):
            raise ValueError(f"--screenshot {args.screenshot!r} must be a .png")
        check_output(args.screenshot, what="--screenshot")
    _check_backend(args.backend)
    try:
        edit(target, output=args.output, backend=args.backend, size=size, screenshot=args.screenshot,
             inside=args.inside)
    except RuntimeError as exc:  # no display, no OpenGL: say so, no traceback
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if args.screenshot:
        _say(args, f"wrote {args.screenshot}")
    return 0


def _add_edit_command(sub):
    e = sub.add_parser("edit", help="interactive bi-scale editor: tile, materials, brush -> the large-scale look "
                                    "(pyvista)",
                       description="Edit a small-scale design and see the large-scale object it makes: the frame, "
                                   "the tile (3 x 3 periods, coloured by material), sliders for the tile family's "
                                   "parameters, each small-scale material, the bake's quality and the light; on a "
                                   "height field, raise/lower/smooth brushes; 'looking inside' shows the normal "
                                   "distribution, the fitted lobes and a slice of the effective BRDF against the "
                                   "ground truth. Keys: u undo, r redo, s save (-o), p screenshot, i inside, g next "
                                   "tab, m brush. docs/editor.md.")
    e.add_argument("target", nargs="?",
                   help="a tile family (pyramid, pentagon, grooves, vgroove, ugroove, rods, woven, heightfield), a "
                        "greyscale image (a height field to paint), a mesh file, or a design saved by the editor "
                        "(.toml)")
    e.add_argument("-o", "--output", metavar="TOML", help="where 's' saves the design (a scene file `render` reads)")
    e.add_argument("--backend", default="auto", help=BACKEND_HELP)
    e.add_argument("--size", nargs="+", metavar="N",
                   help=SIZE_HELP + " of the frame, or WIDTHxHEIGHT (default 640 480; a design file's own size wins)")
    e.add_argument("--screenshot", metavar="PNG", help="draw the window offscreen, write this PNG and exit")
    e.add_argument("--inside", action="store_true",
                   help="with --screenshot: show the 'looking inside' views (waits for the ground truth)")
    e.add_argument("-q", "--quiet", action="store_true", help="no summary")
    e.set_defaults(func=cmd_edit)


SIZE_HELP = "WIDTH [HEIGHT] in pixels (a width alone keeps the aspect)"
BACKEND_HELP = "auto, warp, warp:cpu, warp:cuda, opencl, opencl:cpu, opencl:gpu, opencl:<name>"
FILE_AA = 4  # samples a pixel for an image written to a file (the interactive viewer takes 1)


def _add_render_commands(sub):
    r = sub.add_parser("render", help="render a TOML scene file to PNG / EXR / HDR",
                       description="Render a TOML scene file (schema: `python -m pydoc warp_biscale.scenefile`; "
                                   "examples/*.toml). Baked materials are baked first.")
    r.add_argument("scene", help="the scene file (.toml)")
    r.add_argument("-o", "--output", default="render.png",
                   help="image to write: .png (tone-mapped sRGB), .exr or .hdr (linear radiance); default render.png")
    r.add_argument("--method", choices=["sg", "mc", "litsphere"],
                   help="sg: per-pixel SG shading; mc: Monte Carlo reference; litsphere: the lit-sphere shader "
                        "(seed 004) (default: the file's [render] method, else sg)")
    r.add_argument("--samples", type=int, help="samples per pixel for --method mc: at least 2 for each sampling "
                   "strategy (the environment map and the cosine lobe, each light, and the BRDF of a glossy "
                   "material: 8 for a glossy object under an environment and one light; default: the file's, else "
                   "256)")
    r.add_argument("--truth-facets", type=int, metavar="N",
                   help="--method mc: facets of the ground truth computed for each baked material in view "
                        "(default 2^18; cached beside a material file as NAME.truth.npz)")
    r.add_argument("--truth-directions", type=int, metavar="K",
                   help="--method mc: the K of those ground truths' KxK direction grids, 2..64 (default: each "
                        "material's own K). A finer grid than the bake's keeps sharp highlights sharp in the "
                        "reference; the cost grows as K^4 x facets")
    r.add_argument("--truth-bounces", type=int, metavar="B",
                   help=f"--method mc: bounces of light inside the tile in those ground truths, 1..{MAX_BOUNCES} "
                        "(default 1, single bounce; B > 1 adds B-1 interreflection bounces, as `truth --bounces`)")
    r.add_argument("--truth-paths", type=int, metavar="P",
                   help=f"--method mc: paths per direction pair for those truths' bounces 2..B, 1..{MAX_PATHS} "
                        f"(default {BOUNCE_PATHS})")
    r.add_argument("--aa", type=int, metavar="N",
                   help=f"anti-aliasing: N jittered samples a pixel for the SG renderer (default: the scene file's "
                        f"[render] aa, else {FILE_AA}; 1: pixel centres only)")
    r.add_argument("--shadow-samples", type=int, metavar="N",
                   help=f"shadow rays per light and pixel over the light's disc (default: the file's [render] "
                        f"shadow_samples, else {SHADOW_SAMPLES}; 1: a hard "
                        f"shadow; an environment's sun at most {SOURCE_SHADOW_SAMPLES}, 16 in 4x4 ray blocks)")
    r.add_argument("--occlusion-samples", type=int, metavar="N",
                   help=f"environment-occlusion rays a pixel, 0..{OCCLUSION_SAMPLES_MAX}, that shadow the broad "
                        f"environment lobes where the scene occludes itself (default: the file's [render] "
                        f"occlusion_samples, else {OCCLUSION_SAMPLES}; 0: the SSDF alone)")
    r.add_argument("--every-ray-per-sample", action="store_true",
                   help="every anti-aliasing sample traces every shadow and occlusion ray (--aa times the rays, less "
                        "noise); by default the samples of a pixel share each set of rays between them")
    blocks = r.add_mutually_exclusive_group()
    blocks.add_argument("--block-rays", dest="block_rays", action="store_const", const=2, default=None,
                   help="the pixels of each 2x2 block share their shadow and occlusion rays, each tracing a quarter "
                        "of them (about a quarter of the ray cost; visibility averaged over two pixels, so a contact "
                        "shadow comes out lighter at low resolutions): --block-side 2")
    blocks.add_argument("--no-block-rays", dest="block_rays", action="store_const", const=1,
                   help="each pixel traces its own rays: --block-side 1")
    blocks.add_argument("--block-side", dest="block_side", type=int, choices=[1, 2, 4],
                   help="the side of the pixel blocks that share each set of rays: 1 (each pixel its own), 2, or 4 "
                        "(a sixteenth of the rays of a set of 16 a pixel and anti-aliasing sample; 2 for smaller "
                        "sets); default: the file's "
                        "[render] block_rays, else 4 from 1920x1080 pixels up, 2 from 320x240, else 1")
    r.add_argument("--aa-shading", choices=["sample", "pixel"],
                   help="sample (default): shade every anti-aliasing sample; pixel: shade a pixel once where its "
                        "samples hit one surface (one material, no depth or crease edge), as multisampling does: edges "
                        "anti-aliased at about one sample's cost, a highlight smaller than a pixel not")
    r.add_argument("--mc-fallback", choices=["sg"],
                   help="--method mc: judge every baked material with its fit (an SG bake's SG lobes, an ASG "
                        "bake's ASG lobes; not exact; with a warning) "
                        "instead of its exact ground truth, e.g. for a material file of format 1, which records "
                        "no tile to compute the truth from")
    r.add_argument("--backend", help=BACKEND_HELP + " (default: the file's)")
    r.add_argument("--size", type=int, nargs="+", metavar="N", help=SIZE_HELP + " (default: the file's)")
    r.add_argument("--exposure", type=float, help="PNG exposure in stops: 0 leaves the radiance, -1 halves it, "
                                                  "+1 doubles it (default: the file's, else 0)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress, no bake summary")
    r.set_defaults(func=cmd_render)
    d = sub.add_parser("demo", help="bake a built-in tile and render a scene with it (a few seconds on a CPU)")
    d.add_argument("-o", "--output", default="demo.png", help="image to write (default demo.png)")
    d.add_argument("--size", type=int, nargs="+", metavar="N", help=SIZE_HELP + " (default 512 384)")
    d.add_argument("--aa", type=int, metavar="N", default=FILE_AA,
                   help=f"anti-aliasing: N jittered samples a pixel (default {FILE_AA}; 1: pixel centres only)")
    d.add_argument("--backend", help=BACKEND_HELP + " (default auto)")
    d.add_argument("-q", "--quiet", action="store_true", help="no progress, no bake summary")
    d.set_defaults(func=cmd_demo)
    a = sub.add_parser("ball", help="a material-ball thumbnail of any material (lit-sphere shader)",
                       description="Render a sphere of MATERIAL under a key, a fill and a rim light with the "
                                   "lit-sphere shader (seed 004), as a material library shows its entries.")
    a.add_argument("material", help="a --brdf spec (e.g. blinnphong:exponent=50,ks=0.5,kd=0.3), a baked material "
                                    "(.wbm), a MERL file (.binary) or a lit-sphere folder")
    a.add_argument("-o", "--output", default="ball.png", help="image to write: .png, .exr or .hdr (default ball.png)")
    a.add_argument("--size", type=int, default=256, help="image width and height in pixels (default 256)")
    a.add_argument("--resolution", type=int, help=f"lit-sphere image resolution (default {BALL_RESOLUTION}; "
                                                   "a saved lit-sphere folder keeps its own)")
    a.add_argument("--angles", type=float, nargs="+",
                   help=f"light polar angles of the lit-sphere images, degrees (default "
                        f"{' '.join(f'{x:g}' for x in BALL_ANGLES)}; a saved lit-sphere folder keeps its own)")
    a.add_argument("--exposure", type=float, default=0.0, help="PNG exposure in stops (default 0)")
    a.add_argument("--backend", default="auto", help=BACKEND_HELP)
    a.add_argument("-q", "--quiet", action="store_true", help="no summary")
    a.set_defaults(func=cmd_ball)
    v = sub.add_parser("view", help="interactive viewer: our rendering + the small-scale tile (pyvista)",
                       description="Left: the scene rendered by warp_biscale from the viewer's camera (re-rendered "
                                   "when you release the mouse), sliders for a light's azimuth/elevation and the "
                                   "first material's main parameter; right: the first baked material's tile.")
    v.add_argument("scene", help="the scene file (.toml)")
    v.add_argument("--screenshot", metavar="PNG", help="render offscreen, write this PNG and exit (no window); "
                                                       "the viewer's frame: one sample a pixel and its own ray counts, "
                                                       "whatever the file's [render] asks (`render` writes those)")
    v.add_argument("--size", type=int, nargs="+", metavar="N", help=SIZE_HELP + " of the window (default 1200 600)")
    v.add_argument("--backend", help=BACKEND_HELP + " (default: the file's)")
    v.add_argument("--render-scale", type=float, default=1.0, metavar="S",
                   help="render at S x the viewport's resolution, 0 < S <= 1 (e.g. 0.5 for quicker frames on a CPU; "
                        "default 1)")
    v.add_argument("-q", "--quiet", action="store_true", help="no progress")
    v.set_defaults(func=cmd_view)
    _add_edit_command(sub)


def main(argv=None):
    parser = argparse.ArgumentParser(prog="warp-biscale", description=__doc__)
    parser.add_argument("--version", action="version", version=f"warp-biscale {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_render_commands(sub)
    p = sub.add_parser("truth", help="ground-truth effective BRDF of a tile: table + PNG plot of slices")
    p.add_argument("tile", nargs="?", default="pyramid",
                   help=f"mesh file (OBJ/PLY/STL/GLB), greyscale image (a height field, heights 0..1 in tile units) "
                        f"or built-in tile: {', '.join(BUILTIN_TILES)} "
                        "(default: pyramid)")
    p.add_argument("--brdf", action="append",
                   help="small-scale BRDF, once per material id, e.g. lambert:albedo=0.5, "
                        "blinnphong:exponent=512,ks=1 (add normalization=energy for a specular albedo of at most "
                        "ks; the default iwasaki lobe reflects up to 4·ks), cooktorrance:roughness=0.2,f0=0.04, "
                        "ward:alpha=0.2; anisotropic (bake with --method asg or auto): ward:alpha_x=0.1,alpha_y=0.4, "
                        "as:nu=10,nv=1000 (Ashikhmin–Shirley); RGB as r/g/b; or a MERL table file (.binary) "
                        "(default lambert:albedo=0.5)")
    p.add_argument("--facets", type=int, default=1 << 16,
                   help="number of facets Ns (default 2^16; raise it for a more accurate table)")
    p.add_argument("--directions", type=int, default=12, help="direction grid size K (K² directions, default 12)")
    p.add_argument("--backend", default="auto", help=BACKEND_HELP)
    p.add_argument("--seed", type=int, default=0, help="facet-sampling seed (default 0)")
    p.add_argument("--bounces", type=int, default=1, metavar="B",
                   help=f"bounces of light inside the infinitely tiled surface, 1..{MAX_BOUNCES} (default 1: the "
                        "single-bounce truth; B > 1 adds B-1 bounces of interreflection by Monte Carlo)")
    p.add_argument("--paths", type=int, metavar="P",
                   help=f"paths per direction pair for the bounces 2..B, 1..{MAX_PATHS} (default {BOUNCE_PATHS}; "
                        "cost ∝ K⁴·P·(B-1))")
    p.add_argument("-o", "--output", default="truth.png", help="PNG plot of BRDF slices (default truth.png)")
    p.add_argument("--save", help="also save the table as .npz (read back with wb.load)")
    p.add_argument("-q", "--quiet", action="store_true", help="no table, no progress")
    p.set_defaults(func=cmd_truth)
    k = sub.add_parser("bake", help="bake a tile's effective BRDF (SG, ASG or matrix method) into a material file")
    k.add_argument("tile", nargs="?", default="pyramid",
                   help=f"mesh file (OBJ/PLY/STL/GLB), greyscale image (a height field, heights 0..1 in tile units) "
                        f"or built-in tile: {', '.join(BUILTIN_TILES)} (default: pyramid)")
    k.add_argument("--brdf", action="append", help="small-scale BRDF, once per material id (as for `truth`)")
    k.add_argument("--lobes", default="8", help="SG lobes J: 1-128 (past 16 a bake costs up to about J/16 "
                   "times more; a woven tile needs ~128 for 35 dB) or 'auto' (the smallest J meeting the NDF "
                   "tolerance, up to 128); default 8")
    k.add_argument("--facets", type=int, default=1 << 16, help="number of facets Ns (default 2^16)")
    k.add_argument("--directions", type=int, default=12, help="direction grid size K (default 12)")
    k.add_argument("--normal-res", type=int, default=128, help="normal cube-map resolution R (default 128)")
    k.add_argument("--method", default="sg", choices=["sg", "sg-exact", "asg", "matrix", "auto"],
                   help="sg = SG lobes, the specular term by the SG closure, Eq. 15 (default); sg-exact = Eq. 10; "
                        "asg = anisotropic SG lobes (Xu 2013); matrix = Wu 2011's factored matrices (it takes "
                        "no --lobes or --route); auto = sg or asg, whichever is nearer the exact f̄ of the bake's "
                        "facets (both bakes, that truth and both f̄ tables on the host: 63-91 ms on an H200 at the "
                        "defaults, where one bake takes 3.4-9.3 ms; on a 2-core CPU 16.5 s against 1.4 s for a "
                        "height field)")
    k.add_argument("--route", default="facets", choices=["facets", "histogram"],
                   help="amplitude right-hand sides from exact facet sums (default) or the BVNDF histogram")
    k.add_argument("--backend", default="auto", help=BACKEND_HELP)
    k.add_argument("--seed", type=int, default=0, help="facet-sampling seed (default 0)")
    k.add_argument("--truth", type=int, metavar="FACETS",
                   help="also compute the ground truth with this many facets and print the error against it")
    k.add_argument("--truth-bounces", type=int, metavar="B",
                   help=f"with --truth: bounces of light inside the tile in that truth, 1..{MAX_BOUNCES} (default 1; "
                        "as `truth --bounces`: what the single-bounce bake misses shows in the error)")
    k.add_argument("--truth-paths", type=int, metavar="P",
                   help=f"with --truth: paths per direction pair for its bounces 2..B (default {BOUNCE_PATHS})")
    k.add_argument("-o", "--output", default="material.wbm", help="material file to write (default material.wbm)")
    k.add_argument("-q", "--quiet", action="store_true", help="no summary, no progress")
    k.set_defaults(func=cmd_bake)
    batch.add_parser(sub)
    e = sub.add_parser("export", help="export a baked material to another renderer (Mitsuba 3)",
                       description="Write what Mitsuba 3 needs to render a baked material in its path tracer into "
                                   "a folder: a copy of the material, scene.xml (a sphere of it through warp_biscale's "
                                   "BSDF plugin) and render.py, which registers the plugin and renders the scene "
                                   "(docs/mitsuba.md).")
    e.add_argument("material", help="the baked material file (.wbm)")
    e.add_argument("--to", required=True, choices=["mitsuba"], help="the renderer: mitsuba (Mitsuba 3)")
    e.add_argument("-o", "--output", help="folder to write (made if missing; default NAME-mitsuba in the current "
                                          "directory, NAME the material file's name)")
    e.add_argument("-q", "--quiet", action="store_true", help="no summary")
    e.set_defaults(func=cmd_export)
    b = sub.add_parser("backends", help="list the compute backends found here, usable or not, and why")
    b.add_argument("--require", action="append", metavar="KIND[:TYPE]",
                   help="exit 1 unless a backend of this kind is usable: warp or opencl, optionally :cpu or :gpu, "
                        "e.g. opencl:cpu, warp:gpu, opencl")
    b.add_argument("-q", "--quiet", action="store_true", help="no listing (with --require: only the exit code)")
    b.set_defaults(func=cmd_backends)
    args = parser.parse_args(argv)
    set_quiet(args.quiet)
    # A warning reads as one line, as the errors do: what the library says, not where in it.
    warnings.formatwarning = lambda message, category, *_, **__: f"warning: {message}\n"
    # Exit codes: 2 for a usage or input error (argparse's own too), 1 for a failure on the way.
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as exc:
        print(f"error: {one_line(exc) if isinstance(exc, OSError) else exc}", file=sys.stderr)
        return 2
    except (RuntimeError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
