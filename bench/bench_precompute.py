"""Precompute benchmark: the one-off work before a frame is drawn, per backend.

Stages (each timed as a whole call, device-synchronised):
- ``bvh_build`` (backend "host": numpy on the host): `bvh.build_bvh` of the timing tile, a periodic
  128×128-cell height field of 32 768 triangles (`bench_foundation.heightfield_tile`), the BVH the
  OpenCL visibility kernel walks;
- ``env_fit_sgs``: `lighting.fit_sgs` of `wb.Environment.sky()` (128×256) with 9 lobes, the diffuse term;
- ``env_prefilter``: `lighting.prefilter` of the same sky, the specular term's levels;
- ``ssdf_build``: `ssdf.build` of an icosphere of level 4 (radius 0.5) over a 32×32-cell plane
  (3651 vertices) at resolution 32 with 16 PCA terms. `build` caches its field on the mesh, so every
  call gets a fresh copy of the mesh (made outside the timing); the time includes the mesh's upload.

Times are medians over >= --runs runs after a warm-up call (its extra time, compilation included, is
`first_call_extra_s`); every run is kept in `runs_s`. Writes one JSON record per measurement
(`results.json`: stage, backend, device, sizes, median seconds, git commit) and a markdown table
(`table.md`, also printed) into --out.

    python bench/bench_precompute.py --out bench/results/precompute-cpu-2core       # here
    python bench/bench_precompute.py --backends warp:cuda opencl:nvidia --out $OUT  # on a GPU machine
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
from warp_biscale import bvh, lighting, ssdf

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_foundation import git_commit, heightfield_tile  # noqa: E402

STAGES = ("bvh_build", "env_fit_sgs", "env_prefilter", "ssdf_build")
SG_LOBES = 9
SSDF_RESOLUTION, SSDF_TERMS = 32, 16


def timed(fn, runs, sync=None, make_input=None):
    """fn(input) timed: (median s, every run's s, first-call extra s, last output). `make_input()` (outside
    the timing) gives each call its input; `sync()` waits for the device before the clock stops."""
    times, out = [], None
    for _ in range(runs + 1):  # the first call is the warm-up
        arg = make_input() if make_input else None
        t0 = time.perf_counter()
        out = fn(arg)
        if sync:
            sync()
        times.append(time.perf_counter() - t0)
    med = float(np.median(times[1:]))
    return med, times[1:], max(times[0] - med, 0.0), out


def ssdf_scene():
    """The scene of the SSDF timing: an icosphere of level 4 over a 32×32-cell plane."""
    return wb.Mesh.merge([wb.Mesh.sphere(0.5, (0.0, 0.7, 0.0), subdivisions=4), wb.Mesh.plane(4.0, 0.0, 32)])


def bench_bvh(runs, base, log):
    tile = heightfield_tile(128)
    v, f = np.asarray(tile.vertices), np.asarray(tile.faces)
    med, all_s, extra, tree = timed(lambda _: bvh.build_bvh(v, f), runs)
    rec = {**base, "stage": "bvh_build", "backend": "host", "device": host_device(), "tile": tile.name,
           "triangles": int(len(f)), "leaf_size": bvh.LEAF_SIZE, "nodes": int(tree.n_nodes), "depth": int(tree.depth),
           "median_s": med, "runs": len(all_s), "runs_s": all_s, "first_call_extra_s": extra}
    log(f"{'host':<24} bvh_build      {len(f)} triangles: {med * 1e3:9.2f} ms")
    return [rec]


def bench_environment(backend, stages, runs, base, log):
    env = wb.Environment.sky()
    sizes = {"environment": env.name, "height": int(env.height), "width": int(env.width)}
    out = []
    if "env_fit_sgs" in stages:
        med, all_s, extra, fit = timed(lambda _: lighting.fit_sgs(env, SG_LOBES, backend=backend), runs,
                                       backend.synchronize)
        out.append({**base, **sizes, "stage": "env_fit_sgs", "lobes_asked": SG_LOBES, "lobes": len(fit),
                    "em_steps": int(fit.iterations), "median_s": med, "runs": len(all_s), "runs_s": all_s,
                    "first_call_extra_s": extra})
        log(f"{backend.name:<24} env_fit_sgs    {env.height}x{env.width}, {len(fit)} lobes: {med * 1e3:9.2f} ms")
    if "env_prefilter" in stages:
        levels = []

        def prefilter(_):
            pre = lighting.prefilter(env, backend)
            levels.append(pre.timings)
            return pre

        med, all_s, extra, pre = timed(prefilter, runs, backend.synchronize)
        # pre.timings: one per level made by the kernel, every level but the last (the base map itself)
        computed = pre.levels[:len(pre.timings)]
        out.append({**base, **sizes, "stage": "env_prefilter", "levels": len(pre), "texels": int(len(pre.maps)),
                    "level_eta": [float(2.0 ** lv) for lv in computed[:, 0]],
                    "level_size": [[int(h), int(w)] for h, w in computed[:, 2:4]],
                    "level_median_s": [float(x) for x in np.median(np.asarray(levels[1:]), axis=0)],
                    "median_s": med, "runs": len(all_s), "runs_s": all_s, "first_call_extra_s": extra})
        log(f"{backend.name:<24} env_prefilter  {env.height}x{env.width}, {len(pre)} levels: {med * 1e3:9.2f} ms")
    return out


def bench_ssdf(backend, runs, base, log):
    field_timings = []

    def build(mesh):
        field = ssdf.build(mesh, backend, resolution=SSDF_RESOLUTION, terms=SSDF_TERMS)
        field_timings.append(field.timings)
        return field

    med, all_s, extra, field = timed(build, runs, backend.synchronize, ssdf_scene)
    mesh = ssdf_scene()
    parts = {k: float(np.median([t[k] for t in field_timings[1:]])) for k in field_timings[-1]}
    rec = {**base, "stage": "ssdf_build", "vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces)),
           "resolution": SSDF_RESOLUTION, "terms": SSDF_TERMS, "occluded": bool(field.occluded),
           "rms_error": float(field.rms_error), "parts_median_s": parts, "median_s": med, "runs": len(all_s),
           "runs_s": all_s, "first_call_extra_s": extra}
    log(f"{backend.name:<24} ssdf_build     {len(mesh.vertices)} vertices, S={SSDF_RESOLUTION}: {med * 1e3:9.2f} ms")
    return [rec]


def host_device():
    """The host CPU in words (its model name where /proc/cpuinfo gives one) and its CPU count."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            model = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{model} ({os.cpu_count()} CPUs)"


def load_average():
    """The 1, 5 and 15-minute load averages (None where the OS gives none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def size_of(r):
    if r["stage"] == "bvh_build":
        return f"{r['triangles']} triangles, leaf {r['leaf_size']} ({r['nodes']} nodes)"
    if r["stage"] == "env_fit_sgs":
        return f"{r['height']}×{r['width']} {r['environment']}, {r['lobes']} lobes, {r['em_steps']} EM steps"
    if r["stage"] == "env_prefilter":
        return f"{r['height']}×{r['width']} {r['environment']}, {r['levels']} levels, {r['texels']} texels"
    parts = ", ".join(f"{k} {v * 1e3:.0f}" for k, v in r["parts_median_s"].items() if k != "total")
    return f"{r['vertices']} vertices, S = {r['resolution']}, NV = {r['terms']} (ms: {parts})"


def write_table(records, meta, path):
    rows = [f"commit {meta['commit']}, {meta['date']}, {meta['host']} ({meta['cpu_count']} CPUs); load average "
            f"{meta['loadavg_start']} at the start, {meta.get('loadavg_end')} at the end", "",
            "| stage | backend | device | size | median ms | runs | first-call extra ms |",
            "|---|---|---|---|---|---|---|"]
    for r in records:
        rows.append(f"| {r['stage']} | {r['backend']} | {r['device']} | {size_of(r)} | {r['median_s'] * 1e3:.2f} | "
                    f"{r['runs']} | {r['first_call_extra_s'] * 1e3:.1f} |")
    text = "\n".join(rows) + "\n"
    with open(path, "w") as fh:
        fh.write(text)
    return text


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--backends", nargs="*", help="backend names (default: every usable backend here)")
    p.add_argument("--stages", nargs="*", choices=STAGES, default=list(STAGES), help="stages to time")
    p.add_argument("--runs", type=int, default=5, help="timed runs after the warm-up (median reported; >= 5)")
    p.add_argument("--out", default="bench/out/precompute", help="output folder")
    args = p.parse_args(argv)
    if args.runs < 5:
        p.error("--runs must be >= 5")

    os.makedirs(args.out, exist_ok=True)
    names = args.backends or [b["name"] for b in wb.backends() if b["usable"]]
    meta = {"commit": git_commit(), "date": time.strftime("%Y-%m-%d %H:%M"), "host": platform.node(),
            "machine": platform.machine(), "python": sys.version.split()[0], "cpu_count": os.cpu_count(),
            "backends": names, "stages": args.stages, "runs": args.runs, "loadavg_start": load_average()}
    base = {"commit": meta["commit"]}
    records = []

    def log(msg):
        print(msg, flush=True)

    def save():  # after each step: keep partial work
        with open(os.path.join(args.out, "results.json"), "w") as fh:
            json.dump({"meta": meta, "records": records}, fh, indent=1)

    log(f"backends: {', '.join(names)}; stages: {', '.join(args.stages)}; {args.runs} runs after a warm-up")
    if "bvh_build" in args.stages:
        records += bench_bvh(args.runs, base, log)
        save()
    for name in names:
        backend = wb.get_backend(name)
        here = {**base, "backend": backend.name, "device": backend.device}
        records += bench_environment(backend, args.stages, args.runs, here, log)
        if "ssdf_build" in args.stages:
            records += bench_ssdf(backend, args.runs, here, log)
        save()
    meta["loadavg_end"] = load_average()  # other work on the machine shows here
    save()
    table = write_table(records, meta, os.path.join(args.out, "table.md"))
    log("")
    log(table)
    log(f"wrote {args.out}/results.json, table.md")


if __name__ == "__main__":
    main()
