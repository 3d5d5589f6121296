"""Precompute benchmark: the one-off work before a frame is drawn, per backend.

Stages (each timed as a whole call, device-synchronised):
- ``bvh_build`` (backend "host": numpy on the host): `bvh.build_bvh` of the timing tile, a periodic
  128×128-cell height field of 32 768 triangles (`common.heightfield_tile`), the BVH the
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

    python -m bench.bench_precompute --out /tmp/precompute                               # a CPU
    python -m bench.bench_precompute --backends warp:cuda opencl:nvidia --out $OUT       # on a GPU machine
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import warp_biscale as wb
from warp_biscale import bvh, lighting, ssdf

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

STAGES = ("bvh_build", "env_fit_sgs", "env_prefilter", "ssdf_build")
SG_LOBES = 9
SSDF_RESOLUTION, SSDF_TERMS = 32, 16


def timing(t: common.Timed) -> dict:
    return {"median_s": t.median_s, "runs": len(t.runs_s), "runs_s": t.runs_s,
            "first_call_extra_s": t.first_call_extra_s}


def ssdf_scene():
    """The scene of the SSDF timing: an icosphere of level 4 over a 32×32-cell plane."""
    return wb.Mesh.merge([wb.Mesh.sphere(0.5, (0.0, 0.7, 0.0), subdivisions=4), wb.Mesh.plane(4.0, 0.0, 32)])


def bench_bvh(runs, base, log):
    tile = common.heightfield_tile(128)
    v, f = np.asarray(tile.vertices), np.asarray(tile.faces)
    t = common.timed(lambda: bvh.build_bvh(v, f), runs)
    tree = t.last
    rec = {**base, "stage": "bvh_build", "backend": "host", "device": common.host_device(), "tile": tile.name,
           "triangles": int(len(f)), "leaf_size": bvh.LEAF_SIZE, "nodes": int(tree.n_nodes), "depth": int(tree.depth),
           **timing(t)}
    log(f"{'host':<24} bvh_build      {len(f)} triangles: {t.median_s * 1e3:9.2f} ms")
    return [rec]


def bench_environment(backend, stages, runs, base, log):
    env = wb.Environment.sky()
    sizes = {"environment": env.name, "height": int(env.height), "width": int(env.width)}
    out = []
    if "env_fit_sgs" in stages:
        t = common.timed(lambda: lighting.fit_sgs(env, SG_LOBES, backend=backend), runs, backend)
        fit = t.last
        out.append({**base, **sizes, "stage": "env_fit_sgs", "lobes_asked": SG_LOBES, "lobes": len(fit),
                    "em_steps": int(fit.iterations), **timing(t)})
        log(f"{backend.name:<24} env_fit_sgs    {env.height}x{env.width}, {len(fit)} lobes: "
            f"{t.median_s * 1e3:9.2f} ms")
    if "env_prefilter" in stages:
        levels = []

        def prefilter():
            pre = lighting.prefilter(env, backend)
            levels.append(pre.timings)
            return pre

        t = common.timed(prefilter, runs, backend)
        pre = t.last
        # pre.timings: one per level made by the kernel, every level but the last (the base map itself)
        computed = pre.levels[:len(pre.timings)]
        out.append({**base, **sizes, "stage": "env_prefilter", "levels": len(pre), "texels": int(len(pre.maps)),
                    "level_eta": [float(2.0 ** lv) for lv in computed[:, 0]],
                    "level_size": [[int(h), int(w)] for h, w in computed[:, 2:4]],
                    "level_median_s": [float(x) for x in np.median(np.asarray(levels[1:]), axis=0)], **timing(t)})
        log(f"{backend.name:<24} env_prefilter  {env.height}x{env.width}, {len(pre)} levels: "
            f"{t.median_s * 1e3:9.2f} ms")
    return out


def bench_ssdf(backend, runs, base, log, resolution=SSDF_RESOLUTION, terms=SSDF_TERMS):
    field_timings = []

    def build(mesh):
        field = ssdf.build(mesh, backend, resolution=resolution, terms=terms, disk_cache=False)  # the build itself
        field_timings.append(field.timings)
        return field

    t = common.timed(build, runs, backend, make_input=ssdf_scene)
    field, mesh = t.last, ssdf_scene()
    parts = {k: float(np.median([t[k] for t in field_timings[1:]])) for k in field_timings[-1]}
    rec = {**base, "stage": "ssdf_build", "vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces)),
           "resolution": resolution, "terms": terms, "occluded": bool(field.occluded),
           "rms_error": float(field.rms_error), "parts_median_s": parts, **timing(t)}
    log(f"{backend.name:<24} ssdf_build     {len(mesh.vertices)} vertices, S={resolution}: "
        f"{t.median_s * 1e3:9.2f} ms")
    return [rec]


def size_of(r):
    if r["stage"] == "bvh_build":
        return f"{r['triangles']} triangles, leaf {r['leaf_size']} ({r['nodes']} nodes)"
    if r["stage"] == "env_fit_sgs":
        return f"{r['height']}×{r['width']} {r['environment']}, {r['lobes']} lobes, {r['em_steps']} EM steps"
    if r["stage"] == "env_prefilter":
        return f"{r['height']}×{r['width']} {r['environment']}, {r['levels']} levels, {r['texels']} texels"
    parts = ", ".join(f"{k} {v * 1e3:.0f}" for k, v in r["parts_median_s"].items() if k != "total")
    return f"{r['vertices']} vertices, S = {r['resolution']}, NV = {r['terms']} (ms: {parts})"


def table(records, meta):
    rows = [f"{common.commit_line(meta)}; load average {meta['loadavg_start']} at the start, "
            f"{meta.get('loadavg_end')} at the end", ""]
    rows += common.markdown_table(
        ["stage", "backend", "device", "size", "median ms", "runs", "first-call extra ms"],
        [[r["stage"], r["backend"], r["device"], size_of(r), f"{r['median_s'] * 1e3:.2f}", r["runs"],
          f"{r['first_call_extra_s'] * 1e3:.1f}"] for r in records])
    return "\n".join(rows) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--backends", nargs="*", help="backend names (default: every usable backend here)")
    p.add_argument("--stages", nargs="*", choices=STAGES, default=list(STAGES), help="stages to time")
    p.add_argument("--runs", type=int, default=5, help="timed runs after the warm-up (median reported; >= 5)")
    p.add_argument("--quick", action="store_true",
                   help="a smoke test: one timed run each, the SSDF at S = 16 with 4 terms (not a figure)")
    p.add_argument("--out", required=True, help="output folder")
    args = p.parse_args(argv)
    ssdf_size = (SSDF_RESOLUTION, SSDF_TERMS)
    if args.quick:
        args.runs, ssdf_size = 1, (16, 4)
    elif args.runs < 5:
        p.error("--runs must be >= 5")

    names = common.backend_names(args.backends)
    out = common.Output(args.out, common.run_meta(backends=names, stages=args.stages, runs=args.runs))
    base = {"commit": out.meta["commit"]}
    out.log(f"backends: {', '.join(names)}; stages: {', '.join(args.stages)}; {args.runs} runs after a warm-up")
    if "bvh_build" in args.stages:
        out.records += bench_bvh(args.runs, base, out.log)
        out.save(table)
    for name in names:
        backend = wb.get_backend(name)
        here = {**base, "backend": backend.name, "device": backend.device}
        out.records += bench_environment(backend, args.stages, args.runs, here, out.log)
        if "ssdf_build" in args.stages:
            out.records += bench_ssdf(backend, args.runs, here, out.log, *ssdf_size)
        out.save(table)
    out.finish(table)
    out.log("")
    out.log(table(out.records, out.meta))
    out.log(f"wrote {args.out}/results.json, table.md")


if __name__ == "__main__":
    main()
