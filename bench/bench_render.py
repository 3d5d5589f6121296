"""Rendering benchmark (issue 5): frame time against resolution, J, lights and PCA terms, per backend,
and the SG renderer's error against the Monte Carlo reference.

Parts (records go to --out/results.json; table.md and plots follow):
- ``frames``: the target scene — a torus with a baked effective BRDF (pyramid tile, K = 12, J = 8),
  a sphere and a floor with analytic glossy BRDFs, the sky environment (9 SG lobes + prefiltered
  maps), SSDF shadows (16 PCA terms) and one point light with shadow rays — one frame = G-buffer +
  shadow rays + shading, device-resident (no host copy; the read-back is timed apart). Swept over
  resolution (512² … 1920×1080), J, number of lights and PCA terms.
- ``pareto``: at a small resolution, the SG image against a Monte Carlo reference (PSNR, RMSE over the
  object pixels; the background is the environment in both) for J, against its frame time.

Times are medians over --runs repetitions of a loop of --frames frames after a warm-up frame
(compilation, uploads, SSDF and lighting precomputation are reported apart), device-synchronised.

    python bench/bench_render.py --out bench/results/render-cpu-2core --quick
    python bench/bench_render.py --backends warp:cuda opencl:nvidia --out $OUT
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

import warp_biscale as wb
from warp_biscale.render import Scene, _static_inputs

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_foundation import git_commit  # noqa: E402

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
    return Scene(wb.Mesh.merge([torus, sphere, floor]), mats, cam, wb.Environment.sky(),
                 all_lights[:lights], ssdf_terms=terms)


def time_frames(scene, backend, frames, runs):
    """(median s per frame, precompute s, first-frame extra s, readback s)."""
    be = wb.get_backend(backend)
    t0 = time.perf_counter()
    static = _static_inputs(scene, be, None, {})
    be.synchronize()
    precompute = time.perf_counter() - t0
    lights = scene.lights_packed
    cam = scene.camera.packed()

    def frame():
        be.trace_primary(scene.mesh, scene.camera, to_host=False)
        if len(lights):
            be.trace_shadows(scene.mesh, None, lights, to_host=False)
        be.shade(scene.mesh, static, cam, lights, to_host=False)

    t0 = time.perf_counter()
    frame()
    be.synchronize()
    first = time.perf_counter() - t0
    per = []
    for _ in range(runs):
        t0 = time.perf_counter()
        for _ in range(frames):
            frame()
        be.synchronize()
        per.append((time.perf_counter() - t0) / frames)
    t0 = time.perf_counter()
    be.shade(scene.mesh, static, cam, lights, to_host=True)
    readback = time.perf_counter() - t0 - float(np.median(per))
    return float(np.median(per)), precompute, max(first - float(np.median(per)), 0.0), max(readback, 0.0)


def part_frames(backends, sizes, lobe_list, light_list, term_list, frames, runs, records, log):
    base = dict(lobes=8, lights=1, terms=16)
    sweeps = [("size", s) for s in sizes] + [("lobes", j) for j in lobe_list] + \
             [("lights", n) for n in light_list] + [("terms", t) for t in term_list]
    for backend in backends:
        be = wb.get_backend(backend)
        for what, value in sweeps:
            kw = dict(base)
            w, h = sizes[0] if what != "size" else value
            if what != "size":
                kw[what] = value
            scene = target_scene(w, h, backend=backend, **kw)
            t, pre, first, back = time_frames(scene, be, frames, runs)
            rec = {"part": "frames", "sweep": what, "backend": be.name, "device": be.device, "width": w, "height": h,
                   **kw, "frame_s": t, "fps": 1.0 / t, "precompute_s": pre, "first_call_extra_s": first,
                   "readback_s": back}
            records.append(rec)
            log(f"{be.name:<28} {what:<6} {w}x{h} J={kw['lobes']} lights={kw['lights']} terms={kw['terms']}: "
                f"{t * 1e3:9.3f} ms/frame ({1 / t:8.1f} fps), precompute {pre:6.2f} s, readback {back * 1e3:7.2f} ms")


def part_pareto(backends, size, lobe_list, samples, runs, records, log):
    w, h = size
    for backend in backends:
        be = wb.get_backend(backend)
        ref_scene = target_scene(w, h, lobes=8, backend=backend)
        t0 = time.perf_counter()
        ref = wb.render(ref_scene, method="mc", backend=be, samples=samples)
        t_mc = time.perf_counter() - t0
        log(f"{be.name}: MC reference {w}x{h} {samples} spp in {t_mc:.1f} s, stderr rms {ref.info.get('stderr_rms')}")
        for j in lobe_list:
            scene = target_scene(w, h, lobes=j, backend=backend)
            t, pre, first, back = time_frames(scene, be, 3, runs)
            img = wb.render(scene, backend=be)
            # Over the object pixels only: the background is the environment itself in both images.
            mask = (be.trace_primary(scene.mesh, scene.camera)["face"] >= 0).reshape(h, w)
            err = wb.compare_images(img.image, ref.image, mask=mask)
            records.append({"part": "pareto", "backend": be.name, "device": be.device, "width": w, "height": h,
                            "lobes": j, "frame_s": t, "psnr": err["psnr"], "rmse": err["rmse"],
                            "mc_samples": samples, "mc_s": t_mc, "mc_stderr_rms": ref.info.get("stderr_rms")})
            log(f"{be.name:<28} J={j:<3} {t * 1e3:8.3f} ms  PSNR {err['psnr']:6.2f} dB vs MC")
            if j == lobe_list[-1]:
                from warp_biscale.images import write_png

                tag = be.name.replace(':', '_').replace(' ', '_')
                write_png(os.path.join(OUT_DIR[0], f"sg-J{j}-{tag}.png"), img.image)
                write_png(os.path.join(OUT_DIR[0], f"mc-{be.name.replace(':', '_').replace(' ', '_')}.png"), ref.image)


OUT_DIR = ["."]


def write_table(records, meta, path):
    lines = [f"# Rendering benchmark ({meta['device_kind']})", "", f"commit {meta['commit']}, {meta['date']}", "",
             "| backend | sweep | size | J | lights | PCA terms | ms/frame | fps | precompute s | readback ms |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        if r["part"] == "frames":
            lines.append(f"| {r['backend']} | {r['sweep']} | {r['width']}×{r['height']} | {r['lobes']} | "
                         f"{r['lights']} | {r['terms']} | {r['frame_s'] * 1e3:.3f} | {r['fps']:.1f} | "
                         f"{r['precompute_s']:.2f} | {r['readback_s'] * 1e3:.2f} |")
    pareto = [r for r in records if r["part"] == "pareto"]
    if pareto:
        lines += ["", "| backend | size | J | ms/frame | PSNR vs MC (dB) | RMSE | MC spp | MC stderr rms |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in pareto:
            lines.append(f"| {r['backend']} | {r['width']}×{r['height']} | {r['lobes']} | {r['frame_s'] * 1e3:.3f} | "
                         f"{r['psnr']:.2f} | {r['rmse']:.4g} | {r['mc_samples']} | {r['mc_stderr_rms']:.3g} |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def plot(records, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for be in sorted({r["backend"] for r in records if r["part"] == "frames"}):
        rs = [r for r in records if r["part"] == "frames" and r["backend"] == be and r["sweep"] == "size"]
        if rs:
            axes[0].plot([r["width"] * r["height"] / 1e6 for r in rs], [r["frame_s"] * 1e3 for r in rs], "o-", label=be)
        ps = [r for r in records if r["part"] == "pareto" and r["backend"] == be]
        if ps:
            axes[1].plot([r["frame_s"] * 1e3 for r in ps], [r["psnr"] for r in ps], "o-", label=be)
            for r in ps:
                axes[1].annotate(f"J={r['lobes']}", (r["frame_s"] * 1e3, r["psnr"]))
    axes[0].set(xlabel="megapixels", ylabel="ms / frame", title="frame time vs resolution", xscale="log", yscale="log")
    axes[1].set(xlabel="ms / frame", ylabel="PSNR vs Monte Carlo (dB)", title="speed against error", xscale="log")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "render.png"), dpi=120)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--parts", nargs="+", default=["frames", "pareto"])
    ap.add_argument("--quick", action="store_true", help="CPU sizes: 256², 512² and short sweeps")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--samples", type=int, default=1024)
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    OUT_DIR[0] = args.out
    backends = args.backends or [b["name"] for b in wb.backends() if not b.get("error") and b["device"]]
    if args.quick:
        sizes, pareto_size = [(512, 512), (256, 256)], (96, 72)
        lobes, lights, terms = [1, 4, 8, 16], [0, 1, 4], [4, 16, 48]
    else:
        sizes = [(1920, 1080), (512, 512), (1024, 1024), (1280, 720)]
        lobes, lights, terms, pareto_size = [1, 4, 8, 16], [0, 1, 4], [4, 16, 48], (320, 240)
    records: list = []
    log_lines: list = []

    def log(msg):
        print(msg, flush=True)
        log_lines.append(msg)

    meta = {"commit": git_commit(), "date": time.strftime("%Y-%m-%d %H:%M"), "host": platform.node(),
            "device_kind": ", ".join(sorted({wb.get_backend(b).device for b in backends})), "argv": sys.argv[1:]}

    def save():
        with open(os.path.join(args.out, "results.json"), "w") as f:
            json.dump({"meta": meta, "records": records}, f, indent=1)
        write_table(records, meta, os.path.join(args.out, "table.md"))
        with open(os.path.join(args.out, "log.txt"), "w") as f:
            f.write("\n".join(log_lines) + "\n")

    if "frames" in args.parts:
        part_frames(backends, sizes, lobes, lights, terms, args.frames if not args.quick else 3, args.runs, records,
                    log)
        save()
    if "pareto" in args.parts:
        part_pareto(backends, pareto_size, lobes, args.samples, args.runs, records, log)
        save()
    plot(records, args.out)


if __name__ == "__main__":
    main()
