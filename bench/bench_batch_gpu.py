"""Batch throughput on GPUs (`wb.batch.run(..., gpus=N)`, issue 24's multi-GPU target): a sweep of bake+render
tasks (2^16 facets, K = 12, J = 8, one 512x512 render each) on a local Dask cluster of one worker per GPU,
for each N of --gpus, and on --cpu-workers CPU worker processes (fewer tasks: a CPU bake is ~100x slower).

Each GPU setting runs the whole job cold, as `warp-biscale batch --gpus N` does (the cluster's start, each
worker's first task included) after one warm-up job has filled the kernel caches on disk; and warm: submitted
(`scheduler=`) to a `batch.gpu_cluster(N)` whose workers have run the warm-up job (what a standing cluster
gives). Reported: tasks/s
(tasks over the wall time), the median task's own time (its record's total, in the worker), and the
scheduler's overhead per task: (wall x workers - the tasks' own times) / tasks, as a share of the mean task
time (it holds the cluster's start and each worker's first-task imports, spread over the tasks).

    python -m bench.bench_batch_gpu --gpus 1 2 --cpu-workers 16 --out $OUT      # a 2-GPU host

Cold runs start every process afresh: where PYTHONDONTWRITEBYTECODE is set and the packages carry no bytecode,
each worker, nanny and the scheduler compiles every module it imports from source, which an install (pip
compiles at install) does not. Compile it first (`python -m compileall` on the packages, the variable unset) to
time what an install gives (results/batch-gpu-h100x2-bytecode-c05e3dc: 1.71x without, 2.07x with, one run each).
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import statistics
import sys
import tempfile
import time
import warnings

import numpy as np

from warp_biscale import batch
from warp_biscale.batch_jobs import load_jobs

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

SCENE = """\
[render]
width = 512
height = 512
ssdf_resolution = 16
[camera]
eye = [0.0, 1.6, 3.6]
target = [0.0, 0.2, 0.0]
fov = 40.0
[environment]
type = "constant"
radiance = 0.4
height = 16
width = 32
[[light]]
type = "point"
position = [2.0, 3.0, 2.0]
intensity = 15.0
radius = 0.1
[[object]]
mesh = "sphere"
subdivisions = 4
material = "tile"
[[object]]
mesh = "plane"
size = 8.0
height = -1.0
divisions = 4
material = "floor"
[material.tile]
type = "lambert"
[material.floor]
type = "lambert"
albedo = 0.4
"""


def job_text(heights, exponents, backend, facets=1 << 16):
    return f"""\
[bake]
lobes = 8
facets = {facets}
directions = 12
backend = "{backend}"
[[tile]]
family = "pyramid"
height = {list(heights)}
[[material]]
type = "blinnphong"
exponent = {list(exponents)}
ks = 0.5
kd = 0.2
normalization = "energy"
[[scene]]
path = "scene.toml"
slot = "tile"
name = "ball"
shadow_samples = 1
"""


def write_job(folder, heights, exponents, backend, facets=1 << 16):
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "scene.toml"), "w") as fh:
        fh.write(SCENE)
    path = os.path.join(folder, "jobs.toml")
    with open(path, "w") as fh:
        fh.write(job_text(heights, exponents, backend, facets))
    return load_jobs(path)


def timed_run(jobs, out, **kw):
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    res = batch.run(jobs, out, progress=False, dashboard=False, resume=False, **kw)
    wall = time.perf_counter() - t0
    own = [r["timings"]["total"] for r in res.records.values() if r.get("status") == "done"]
    return res, wall, own


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--gpus", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--tasks", type=int, default=500, help="GPU tasks (pyramid heights x Blinn-Phong exponents)")
    ap.add_argument("--backend", default="warp:cuda", help="each GPU worker's backend (its own GPU)")
    ap.add_argument("--cpu-workers", type=int, nargs="*", default=[], help="CPU worker counts to run too")
    ap.add_argument("--cpu-tasks", type=int, default=32)
    ap.add_argument("--cold-only", action="store_true", help="no warm (standing cluster) runs")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    work = tempfile.mkdtemp(prefix="bench-batch-gpu-")
    out = common.Output(args.out, common.run_meta(gpus=args.gpus, tasks=args.tasks, backend=args.backend))
    n_e = 20
    n_h = -(-args.tasks // n_e)
    heights = [round(float(h), 4) for h in np.linspace(0.1, 1.0, n_h)]
    exponents = [round(float(e), 2) for e in np.geomspace(8, 1024, n_e)]
    jobs = write_job(os.path.join(work, "gpu"), heights, exponents, args.backend)
    warm = write_job(os.path.join(work, "warm"), [0.33, 0.66], [50.0], args.backend)
    out.log(f"{len(jobs.tasks)} tasks; warm-up job of {len(warm.tasks)} tasks (fills the kernel caches)")
    timed_run(warm, os.path.join(work, "warm-out"), gpus=max(args.gpus))
    settings = [("gpus", n, jobs) for n in args.gpus]
    if not args.cold_only:
        settings += [("warm-gpus", n, jobs) for n in args.gpus]
    if args.cpu_workers:
        n_c = max(1, args.cpu_tasks // 4)
        cpu_jobs = write_job(os.path.join(work, "cpu"), [round(float(h), 4) for h in np.linspace(0.1, 1.0, n_c)],
                             [16.0, 64.0, 256.0, 1024.0], "warp:cpu")
        settings += [("workers", n, cpu_jobs) for n in args.cpu_workers]
    for kind, n, jb in settings:
        if kind == "warm-gpus":
            with batch.gpu_cluster(n) as cluster:
                timed_run(warm, os.path.join(work, f"warm-{n}"), scheduler=cluster.scheduler_address)
                res, wall, own = timed_run(jb, os.path.join(work, f"{kind}-{n}"), scheduler=cluster.scheduler_address)
        else:
            res, wall, own = timed_run(jb, os.path.join(work, f"{kind}-{n}"), **{kind: n})
        mean = statistics.fmean(own) if own else float("nan")
        overhead = (wall * n - sum(own)) / max(len(own), 1)
        rec = {"part": "throughput", "kind": kind, "workers": n, "tasks": len(jb.tasks), "done": res.done,
               "failed": res.failed, "wall_s": wall, "tasks_per_s": res.done / wall,
               "median_task_s": statistics.median(own) if own else None, "mean_task_s": mean,
               "overhead_per_task_s": overhead, "overhead_share": overhead / mean if own else None,
               "backends": sorted({str(r["worker"].get("backend")) for r in res.records.values()
                                   if r.get("status") == "done"}),
               "gpus_seen": sorted({str(r["worker"].get("gpus")) for r in res.records.values()
                                    if r.get("status") == "done"})}
        out.records.append(rec)
        out.log(f"{kind}={n}: {res.done}/{len(jb.tasks)} done in {wall:.1f} s = {rec['tasks_per_s']:.2f} tasks/s; "
                f"task {rec['median_task_s']:.3f} s (median); overhead {overhead * 1e3:.1f} ms a task "
                f"({100 * rec['overhead_share']:.1f} % of the mean task); backends {rec['backends']}, "
                f"GPUs {rec['gpus_seen']}")
    for kind in ("gpus", "warm-gpus"):
        base = next((r for r in out.records if r["kind"] == kind and r["workers"] == 1), None)
        for r in out.records:
            if base and r["kind"] == kind:
                r["speedup_vs_1_gpu"] = r["tasks_per_s"] / base["tasks_per_s"]
    out.finish(table)
    shutil.rmtree(work, ignore_errors=True)


def table(records, meta):
    lines = ["# Batch throughput on GPUs", "", common.commit_line(meta), "",
             "One job, cold (`batch.run(..., gpus=N)` / `workers=N`, the cluster's start included) or warm (submitted "
             "to a standing `batch.gpu_cluster(N)`); tasks: bake (2^16 facets, K = 12, J = 8) + one 512x512 render "
             "each", ""]
    rows = [[r["kind"], r["workers"], r["tasks"], r["done"], f"{r['wall_s']:.1f}", f"{r['tasks_per_s']:.2f}",
             f"{r.get('speedup_vs_1_gpu', float('nan')):.2f}" if "gpus" in r["kind"] else "",
             f"{r['median_task_s'] * 1e3:.0f}", f"{r['overhead_per_task_s'] * 1e3:.1f}",
             f"{100 * r['overhead_share']:.1f}", ", ".join(r["backends"]), ", ".join(r["gpus_seen"])]
            for r in records]
    lines += common.markdown_table(["workers of", "N", "tasks", "done", "wall s", "tasks/s", "x 1 GPU",
                                    "median task ms", "overhead ms/task", "overhead %", "backends", "GPUs"], rows)
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
