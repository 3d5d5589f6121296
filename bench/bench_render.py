"""Rendering benchmark: frame time against resolution, J, lights and PCA terms, per backend,
and the SG renderer's error against the Monte Carlo reference.

Parts (records go to --out/results.json; table.md and plots follow):
- ``frames``: the target scene — a torus with a baked effective BRDF (pyramid tile, K = 12, J = 8),
  a sphere and a floor with analytic glossy BRDFs, the sky environment (9 SG lobes + prefiltered
  maps), SSDF shadows (16 PCA terms) with 16 environment-occlusion rays a pixel (and 8 a sharp lobe for the
  sun's lobes), and one point light with
  shadow rays — one frame = G-buffer + shadow rays + occlusion rays + shading, device-resident (no host
  copy; the read-back is timed apart). Swept over resolution (512² … 1920×1080), J, number of lights, PCA
  terms, shadow rays and occlusion rays; with --aa N, N anti-aliasing samples a pixel (--aa-shading: each
  sample shaded, or once a pixel), summed on the device.
- ``stages``: each stage of one frame of the target scene apart, at the first size: the G-buffer, the
  shadow rays (1 and the default count a light), the occlusion and sun-lobe rays, the shading, and the
  read-backs of the float and the 8-bit frame (not in the default parts); with --block-rays 2 / 4, the ray
  stages and the shade with the rays shared in those blocks too.
- ``blocks``: at the first size, what sharing the rays in pixel blocks costs the image (each pixel's own rays and
  the --block-rays settings; with the default "off", 2 and 4): each setting's frame time and PSNR over the object
  pixels against the same renderer with 64 shadow and 32 occlusion rays of each pixel's own (not in the default
  parts).
- ``pareto``: at a small resolution, the SG image against a Monte Carlo reference (PSNR, RMSE over the
  object pixels; the background is the environment in both) for J, against its frame time; and at the
  largest J without occlusion rays (the SSDF alone).

Times are medians over --runs repetitions of a loop of --frames frames after a warm-up frame
(compilation, uploads, SSDF and lighting precomputation are reported apart), device-synchronised.

    python -m bench.bench_render --quick --out /tmp/render                          # a CPU
    python -m bench.bench_render --backends warp:cuda opencl:nvidia --out $OUT      # on a GPU machine
    python -m bench.bench_render --sizes 64x48 --lobes 8 --lights 1 --terms 16 --pareto-size 32x24 \\
        --samples 16 --runs 1 --frames 1 --out /tmp/render-smoke                     # a smoke test
"""

from __future__ import annotations

import argparse
import os
import re
import sys

import numpy as np

import warp_biscale as wb
from warp_biscale.render import OCCLUSION_SAMPLES, SHADOW_SAMPLES, pack_frame, queue_frame

try:  # the renderer's lights: the scene's and its environment's compact sources (an older tree: the scene's)
    from warp_biscale.render import frame_lights
except ImportError:
    def frame_lights(scene):
        return scene.lights_packed
try:  # the shadow rays of each of those lights (an older tree: one count for all)
    from warp_biscale.render import frame_shadow_samples
except ImportError:
    def frame_shadow_samples(scene, samples, block_side=1):
        return samples

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

_MATERIALS: dict = {}


def baked(lobes: int, backend="auto"):
    """The pyramid tile baked with a coloured Blinn–Phong at K = 12 and `lobes` lobes (cached)."""
    if lobes not in _MATERIALS:
        tile = wb.geometry.pyramid()
        _MATERIALS[lobes] = wb.bake(tile, [wb.BlinnPhong((0.9, 0.7, 0.3), 256, kd=(0.25, 0.12, 0.05))],
                                    lobes=lobes, directions=12, facets=2**14, backend=backend)
    return _MATERIALS[lobes]


def target_scene(width, height, lobes=8, lights=1, terms=16, backend="auto"):
    torus = wb.Mesh.torus(0.8, 0.3, center=(0.0, 0.5, 0.0), segments=(96, 48), material=0)
    sphere = wb.Mesh.sphere(0.45, center=(1.5, 0.45, 0.6), subdivisions=4, material=1)
    floor = wb.Mesh.plane(6.0, 0.0, divisions=48, material=2)
    mats = [baked(lobes, backend), wb.CookTorrance(0.7, 0.15, kd=(0.1, 0.2, 0.5)), wb.BlinnPhong(0.1, 30, kd=0.5)]
    all_lights = [wb.PointLight((2.0, 3.5, 2.0), 25.0, 0.15), wb.PointLight((-2.5, 3.0, 1.0), 15.0, 0.2),
                  wb.DirectionalLight((0.3, 1.0, -0.4), 1.0, 1.0), wb.PointLight((0.0, 4.0, -2.5), 10.0, 0.3)]
    cam = wb.Camera(eye=(0.5, 2.2, 4.2), target=(0.3, 0.4, 0.0), fov=45, width=width, height=height)
    return wb.Scene(wb.Mesh.merge([torus, sphere, floor]), mats, cam, wb.Environment.sky(),
                    all_lights[:lights], ssdf_terms=terms)


PRECOMPUTE = ("lighting", "ssdf", "materials")  # Rendering.timings' stages of a scene's first frame only


def time_frames(scene, backend, frames, runs, shadow_samples=SHADOW_SAMPLES, occlusion_samples=OCCLUSION_SAMPLES,
                block_rays=False, aa=1, aa_shading="sample"):
    """(median s per frame, precompute s, first-frame extra s, read-back s). A frame is the G-buffer, the
    shadow rays and the shading of each of `aa` anti-aliasing samples (`wb.render`'s options: block_rays, the
    rays shared in pixel blocks; aa_shading), its image left on the device (what an interactive viewer
    draws from): `render.queue_frame`, the stages of `wb.render` without its read-back and per-stage waits.
    The read-back is timed apart: for aa 1 a shade with its read-back less a frame, for aa > 1
    `accumulated_frame` (the average's read-back)."""
    be = wb.get_backend(backend)
    options = dict(shadow_samples=shadow_samples, occlusion_samples=occlusion_samples, aa=aa,
                   **common.block_rays_option(block_rays),
                   **({"aa_shading": aa_shading} if aa_shading != "sample" else {}))
    first = wb.render(scene, backend=be, **options)  # compiles, and computes what does not depend on the camera
    precompute = sum(first.timings.get(k, 0.0) for k in PRECOMPUTE)

    def loop():
        for _ in range(frames):
            queue_frame(scene, be, **options)

    t = common.timed(loop, runs, be)
    per_frame = t.median_s / frames
    if aa == 1:
        inputs = pack_frame(scene, be).inputs  # the shade stage's inputs, cached on the scene by the render above
        lights, cam = frame_lights(scene), scene.camera.packed()
        back = common.timed(lambda: be.shade(scene.mesh, inputs, cam, lights, to_host=True), 3, be).median_s
        back -= per_frame
    else:  # the device's average of the samples
        back = common.timed(lambda: be.accumulated_frame(scene.mesh, scene.camera.width, scene.camera.height), 3,
                            be).median_s
    # The first render's time past its precompute and one warm frame: compilation and uploads.
    first_extra = first.timings["total"] - precompute - per_frame
    return per_frame, precompute, max(first_extra, 0.0), max(back, 0.0)


def part_frames(backends, sizes, lobe_list, light_list, term_list, frames, runs, out, shadow_list=(),
                occlusion_list=(), block_modes=(False,), aa_modes=((1, "sample"),)):
    base = dict(lobes=8, lights=1, terms=16, shadows=SHADOW_SAMPLES, occlusion=OCCLUSION_SAMPLES)
    sweeps = [("size", s) for s in sizes] + [("lobes", j) for j in lobe_list] + \
             [("lights", n) for n in light_list] + [("terms", t) for t in term_list] + \
             [("shadows", n) for n in shadow_list] + [("occlusion", n) for n in occlusion_list]
    for backend in backends:
        be = wb.get_backend(backend)
        for what, value in sweeps:
            kw = dict(base)
            w, h = sizes[0] if what != "size" else value
            if what != "size":
                kw[what] = value
            shadows, occlusion = kw.pop("shadows"), kw.pop("occlusion")
            scene = target_scene(w, h, backend=backend, **kw)
            kw["shadows"], kw["occlusion"] = shadows, occlusion
            for block in block_modes:
                for aa, aa_shading in aa_modes:
                    t, pre, first, back = time_frames(scene, be, frames, runs, shadows, occlusion, block_rays=block,
                                                      aa=aa, aa_shading=aa_shading)
                    out.records.append({"part": "frames", "sweep": what, "backend": be.name, "device": be.device,
                                        "width": w, "height": h, **kw, "block_rays": block, "aa": aa,
                                        "aa_shading": aa_shading, "frame_s": t, "fps": 1.0 / t,
                                        "precompute_s": pre, "first_call_extra_s": first, "readback_s": back})
                    out.log(f"{be.name:<28} {what:<7} {w}x{h} J={kw['lobes']} lights={kw['lights']} "
                            f"terms={kw['terms']} shadow rays={kw['shadows']} occlusion rays={kw['occlusion']} "
                            f"blocks={common.block_side(block)} aa={aa} ({aa_shading}): {t * 1e3:9.3f} ms/frame "
                            f"({1 / t:8.1f} fps), "
                            f"precompute {pre:6.2f} s, readback {back * 1e3:7.2f} ms")


def part_stages(backends, size, runs, out, repeat=10, block_modes=(False,)):
    """Each stage of a frame of the target scene apart (J = 8, one light, 16 terms), device-synchronised
    medians of `runs` loops of `repeat` calls: the G-buffer, the shadow rays at 1 a light and at the frame's 16 (an
    environment's sources at most lighting.SOURCE_SHADOW_SAMPLES), the
    occlusion rays, the sun lobes' rays, the shading (image left on the device), and the read-backs of the
    float frame and of the 8-bit display frame."""
    w, h = size
    for backend in backends:
        be = wb.get_backend(backend)
        scene = target_scene(w, h, backend=backend)
        wb.render(scene, backend=be)  # compiles, precomputes, leaves this camera's G-buffer and rays on the device
        inputs = pack_frame(scene, be).inputs
        lights, cam, mesh = frame_lights(scene), scene.camera.packed(), scene.mesh
        shadow_rays = frame_shadow_samples(scene, SHADOW_SAMPLES)  # the frame's: an environment's sun may get fewer
        fewer = sorted({int(n) for n in np.atleast_1d(shadow_rays)} - {SHADOW_SAMPLES})
        rays = f"{SHADOW_SAMPLES} rays" + "".join(f", {n} a source" for n in fewer)
        stages = {
            "trace_primary": lambda: be.trace_primary(mesh, scene.camera, to_host=False),
            "trace_shadows (1 ray)": lambda: be.trace_shadows(mesh, None, lights, to_host=False, samples=1),
            f"trace_shadows ({rays})": lambda: be.trace_shadows(mesh, None, lights, to_host=False,
                                                                samples=shadow_rays),
            f"trace_occlusion ({OCCLUSION_SAMPLES} rays)": lambda: be.trace_occlusion(mesh, None, OCCLUSION_SAMPLES,
                                                                                      to_host=False),
            "trace_lobe_rays": lambda: be.trace_lobe_rays(mesh, None, inputs.sharp_lobes(), to_host=False),
            "shade": lambda: be.shade(mesh, inputs, cam, lights, to_host=False),
            "shade + float read-back": lambda: be.shade(mesh, inputs, cam, lights, to_host=True),
            "frame_u8 (tone map + 8-bit read-back)": lambda: be.frame_u8(mesh, w, h),
        }
        for side in sorted({common.block_side(b) for b in block_modes} - {1}):
            # each set shared in side x side blocks (the shade then reads the lent rays)
            blocks, tag = (0, 1, w, side), f"{side}x{side} blocks"
            try:  # (an older tree: one count whatever the blocks)
                side_rays = frame_shadow_samples(scene, SHADOW_SAMPLES, side)
            except TypeError:
                side_rays = shadow_rays
            fewer = sorted({int(n) for n in np.atleast_1d(side_rays)} - {SHADOW_SAMPLES})
            side_tag = f"{SHADOW_SAMPLES} rays" + "".join(f", {n} a source" for n in fewer)
            stages.update({
                f"trace_shadows ({side_tag}, {tag})": lambda blocks=blocks, side_rays=side_rays: be.trace_shadows(
                    mesh, None, lights, to_host=False, samples=side_rays, part=blocks),
                f"trace_occlusion ({OCCLUSION_SAMPLES} rays, {tag})": lambda blocks=blocks: be.trace_occlusion(
                    mesh, None, OCCLUSION_SAMPLES, to_host=False, part=blocks),
                f"trace_lobe_rays ({tag})": lambda blocks=blocks: be.trace_lobe_rays(
                    mesh, None, inputs.sharp_lobes(), to_host=False, part=blocks),
                # (the rays just traced: this side's, as the shade after each set's trace reads them)
                f"shade ({tag})": lambda: be.shade(mesh, inputs, cam, lights, to_host=False)})
        for name, call in stages.items():
            def loop(call=call):
                for _ in range(repeat):
                    call()
            t = common.timed(loop, runs, be).median_s / repeat
            out.records.append({"part": "stages", "backend": be.name, "device": be.device, "width": w, "height": h,
                                "stage": name, "stage_s": t, "sharp_lobes": int(inputs.n_sharp_lobes)})
            out.log(f"{be.name:<28} {w}x{h} {name:<40} {t * 1e3:8.3f} ms")


def part_pareto(backends, size, lobe_list, samples, runs, out, block_modes=(False,)):
    w, h = size
    for backend in backends:
        be = wb.get_backend(backend)
        tag = re.sub(r"[^A-Za-z0-9.-]+", "_", be.name)
        ref_scene = target_scene(w, h, lobes=8, backend=backend)
        ref = wb.render(ref_scene, method="mc", backend=be, samples=samples)
        t_mc = ref.timings["total"]
        out.log(f"{be.name}: MC reference {w}x{h} {samples} spp in {t_mc:.1f} s, "
                f"stderr rms {ref.info.get('stderr_rms')}")
        rows = [(j, OCCLUSION_SAMPLES, False) for j in lobe_list] + [(lobe_list[-1], 0, False)]
        rows += [(j, OCCLUSION_SAMPLES, b) for b in block_modes if b is not False for j in lobe_list]
        for j, occlusion, block in rows:
            scene = target_scene(w, h, lobes=j, backend=backend)
            t, pre, first, back = time_frames(scene, be, 3, runs, occlusion_samples=occlusion, block_rays=block)
            img = wb.render(scene, backend=be, occlusion_samples=occlusion, **common.block_rays_option(block))
            # Over the object pixels only: the background is the environment itself in both images.
            mask = (be.trace_primary(scene.mesh, scene.camera).face >= 0).reshape(h, w)
            err = wb.compare_images(img.image, ref.image, mask=mask)
            out.records.append({"part": "pareto", "backend": be.name, "device": be.device, "width": w, "height": h,
                                "lobes": j, "occlusion": occlusion, "block_rays": block, "frame_s": t,
                                "psnr": err["psnr"],
                                "rmse": err["rmse"],
                                "mc_samples": samples, "mc_s": t_mc, "mc_stderr_rms": ref.info.get("stderr_rms")})
            out.log(f"{be.name:<28} J={j:<3} occlusion rays={occlusion:<3} blocks={common.block_side(block)} "
                    f"{t * 1e3:8.3f} ms  PSNR {err['psnr']:6.2f} dB vs MC")
            if j == lobe_list[-1] and occlusion and not block:
                img.save(out.path(f"sg-J{j}-{tag}.png"))
                ref.save(out.path(f"mc-{tag}.png"))


def part_blocks(backends, size, runs, out, block_modes=(False, 2, 4), rays=(64, 32)):
    """What sharing the rays in pixel blocks costs the image, apart from the SG method's own error: the target
    scene's frame with each block_rays of `block_modes` at the default rays (16 shadow rays a light, 16 occlusion
    rays), its time (time_frames) and its PSNR over the object pixels against the same renderer with each pixel
    tracing `rays` (shadow, occlusion) of its own (the rays' noise all but gone)."""
    w, h = size
    for backend in backends:
        be = wb.get_backend(backend)
        scene = target_scene(w, h, backend=backend)
        many = wb.render(scene, backend=be, shadow_samples=rays[0], occlusion_samples=rays[1], block_rays=False)
        mask = (be.trace_primary(scene.mesh, scene.camera).face >= 0).reshape(h, w)
        for block in block_modes:
            t, pre, first, back = time_frames(scene, be, 10, runs, block_rays=block)
            img = wb.render(scene, backend=be, **common.block_rays_option(block))
            err = wb.compare_images(img.image, many.image, mask=mask)
            out.records.append({"part": "blocks", "backend": be.name, "device": be.device, "width": w, "height": h,
                                "block_rays": block, "frame_s": t, "psnr": err["psnr"], "rmse": err["rmse"],
                                "reference_rays": list(rays)})
            out.log(f"{be.name:<28} {w}x{h} blocks={common.block_side(block)} {t * 1e3:8.3f} ms  PSNR "
                    f"{err['psnr']:6.2f} dB against {rays[0]} shadow and {rays[1]} occlusion rays a pixel")


def _blocks_cell(r) -> str:
    side = common.block_side(r.get("block_rays", False))
    return f"{side}×{side}" if side > 1 else "no"


def table(records, meta):
    lines = [f"# Rendering benchmark ({meta['device_kind']})", "", common.commit_line(meta), ""]
    lines += common.markdown_table(
        ["backend", "sweep", "size", "J", "lights", "PCA terms", "shadow rays", "occlusion rays", "ray blocks",
         "aa (shading)", "ms/frame", "fps", "precompute s", "readback ms"],
        [[r["backend"], r["sweep"], f"{r['width']}×{r['height']}", r["lobes"], r["lights"], r["terms"],
          r.get("shadows", 1), r.get("occlusion", 0), _blocks_cell(r),
          f"{r.get('aa', 1)} ({r.get('aa_shading', 'sample')})",
          f"{r['frame_s'] * 1e3:.3f}", f"{r['fps']:.1f}", f"{r['precompute_s']:.2f}", f"{r['readback_s'] * 1e3:.2f}"]
         for r in records if r["part"] == "frames"])
    stages = [r for r in records if r["part"] == "stages"]
    if stages:
        lines += [""] + common.markdown_table(
            ["backend", "size", "stage", "ms"],
            [[r["backend"], f"{r['width']}×{r['height']}", r["stage"], f"{r['stage_s'] * 1e3:.3f}"] for r in stages])
    blocks = [r for r in records if r["part"] == "blocks"]
    if blocks:
        lines += [""] + common.markdown_table(
            ["backend", "size", "ray blocks", "ms/frame", "PSNR vs many own rays (dB)", "RMSE"],
            [[r["backend"], f"{r['width']}×{r['height']}", _blocks_cell(r), f"{r['frame_s'] * 1e3:.3f}",
              f"{r['psnr']:.2f}", f"{r['rmse']:.4g}"] for r in blocks])
    pareto = [r for r in records if r["part"] == "pareto"]
    if pareto:
        lines += [""] + common.markdown_table(
            ["backend", "size", "J", "occlusion rays", "ray blocks", "ms/frame", "PSNR vs MC (dB)", "RMSE", "MC spp",
             "MC stderr rms"],
            [[r["backend"], f"{r['width']}×{r['height']}", r["lobes"], r.get("occlusion", 0),
              _blocks_cell(r),
              f"{r['frame_s'] * 1e3:.3f}", f"{r['psnr']:.2f}", f"{r['rmse']:.4g}", r["mc_samples"],
              f"{r['mc_stderr_rms']:.3g}"] for r in pareto])
    return "\n".join(lines) + "\n"


def plot(records, folder):
    plt = common.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for be in sorted({r["backend"] for r in records if r["part"] == "frames"}):
        for side in (1, 2, 4):
            label = be + (f", {side}×{side} blocks" if side > 1 else "")
            rs = [r for r in records if r["part"] == "frames" and r["backend"] == be and r["sweep"] == "size"
                  and common.block_side(r.get("block_rays", False)) == side]
            if rs:
                axes[0].plot([r["width"] * r["height"] / 1e6 for r in rs], [r["frame_s"] * 1e3 for r in rs], "o-",
                             label=label)
            ps = [r for r in records if r["part"] == "pareto" and r["backend"] == be
                  and common.block_side(r.get("block_rays", False)) == side]
            if ps:
                axes[1].plot([r["frame_s"] * 1e3 for r in ps], [r["psnr"] for r in ps], "o-", label=label)
                for r in ps:
                    axes[1].annotate(f"J={r['lobes']}", (r["frame_s"] * 1e3, r["psnr"]))
    axes[0].set(xlabel="megapixels", ylabel="ms / frame", title="frame time vs resolution", xscale="log", yscale="log")
    axes[1].set(xlabel="ms / frame", ylabel="PSNR vs Monte Carlo (dB)", title="speed against error", xscale="log")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "render.png"), dpi=120)
    plt.close(fig)


def wxh(text: str) -> tuple:
    w, h = text.lower().split("x")
    return int(w), int(h)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=None, help="backend names (default: every usable backend here)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--parts", nargs="+", default=["frames", "pareto"])
    ap.add_argument("--quick", action="store_true", help="CPU sizes: 512², 256² and a 96×72 Pareto image")
    ap.add_argument("--sizes", nargs="+", help="frame sizes WxH, the first one that of the other sweeps (default "
                                                "1920x1080 512x512 1024x1024 1280x720; --quick 512x512 256x256)")
    ap.add_argument("--lobes", type=int, nargs="+", default=[1, 4, 8, 16], help="the J sweep")
    ap.add_argument("--lights", type=int, nargs="+", default=[0, 1, 4], help="the light-count sweep")
    ap.add_argument("--terms", type=int, nargs="+", default=[4, 16, 48], help="the SSDF PCA-term sweep")
    ap.add_argument("--shadow-samples", type=int, nargs="+", default=[1, 4, 16],
                    help=f"the shadow-ray sweep (rays per light and pixel; the others at {SHADOW_SAMPLES})")
    ap.add_argument("--occlusion-samples", type=int, nargs="+", default=[0, 8, 16, 32],
                    help=f"the occlusion-ray sweep (rays per pixel; the others at {OCCLUSION_SAMPLES})")
    ap.add_argument("--pareto-size", help="WxH of the Pareto images (default 320x240; --quick 96x72)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, default=10, help="frames a timed loop (3 with --quick)")
    ap.add_argument("--samples", type=int, default=1024, help="Monte Carlo samples a pixel of the reference")
    ap.add_argument("--block-rays", nargs="+", choices=list(common.BLOCK_MODES), default=["off"],
                    help="frames with the rays shared in pixel blocks (wb.render's block_rays: on = 2 = 2x2, 4 = 4x4), "
                         "without (off), or both (off and on); several: each")
    ap.add_argument("--aa", type=int, nargs="+", default=[1], help="anti-aliasing samples a pixel of the frames")
    ap.add_argument("--aa-shading", nargs="+", choices=["sample", "pixel"], default=["sample"],
                    help="wb.render's aa_shading of the anti-aliased frames (aa > 1)")
    args = ap.parse_args(argv)
    blocks = common.block_modes(args.block_rays)
    aa_modes = [(aa, shading) for aa in args.aa for shading in (args.aa_shading if aa > 1 else ["sample"])]
    backends = common.backend_names(args.backends)
    if args.quick:
        sizes, pareto_size, frames = [(512, 512), (256, 256)], (96, 72), 3
    else:
        sizes, pareto_size, frames = [(1920, 1080), (512, 512), (1024, 1024), (1280, 720)], (320, 240), args.frames
    sizes = [wxh(s) for s in args.sizes] if args.sizes else sizes
    pareto_size = wxh(args.pareto_size) if args.pareto_size else pareto_size
    out = common.Output(args.out, common.run_meta(
        backends=backends, device_kind=", ".join(sorted({wb.get_backend(b).device for b in backends}))))

    def save():
        out.save(table)

    if "frames" in args.parts:
        part_frames(backends, sizes, args.lobes, args.lights, args.terms, frames, args.runs, out, args.shadow_samples,
                    args.occlusion_samples, blocks, aa_modes)
        save()
    if "blocks" in args.parts:
        # (each pixel's own rays always, as the baseline; --block-rays off alone: 2x2 and 4x4 beside them)
        part_blocks(backends, sizes[0], args.runs, out, (False, 2, 4) if blocks == (False,) else
                    (False, *[b for b in blocks if b is not False]))
        save()
    if "stages" in args.parts:
        part_stages(backends, sizes[0], args.runs, out, block_modes=blocks)
        save()
    if "pareto" in args.parts:
        part_pareto(backends, pareto_size, args.lobes, args.samples, args.runs, out, blocks)
    out.finish(table)
    plot(out.records, args.out)
    out.log(f"wrote {args.out}/results.json, table.md, render.png")


if __name__ == "__main__":
    main()
