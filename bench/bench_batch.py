"""Batch throughput (`wb.batch.run`): one sweep of 12 small tasks (bake, ground truth + compare, one render
each) run on a Dask LocalCluster of 1 and of 2 worker processes (one Dask thread each), in tasks per second.

Settings, measured in rounds, each setting once a round (other work on the machine — logged as the CPU cores
it kept busy during each run — then falls on every setting alike), until each has `--runs` quiet runs (other
work below `--quiet-cores`) or `--budget` is spent; the median over the quiet runs (all runs where there are
none) and the best run are reported:
- here: the tasks run in this process one at a time, no Dask (`workers=0`; this process warmed first);
- cold: `run(jobs, workers=N)` from the call to its return, as `warp-biscale batch --workers N` runs it:
  the cluster's start, each fresh worker's first task (importing Warp, the renderer's per-process tables
  and the scene's lighting) and the cluster's shutdown included;
- warm: the same job submitted (`scheduler=`) to a cluster whose workers have each run a warm-up job first
  (other tiles, so nothing of the measured job is cached): what workers that live across tasks give; each
  worker splits its CPU work over every core, as `run(workers=N)` leaves it;
- warm-pinned (N > 1): warm, each worker kept on its own core(s) (`pin=N`, `--pin`), splitting over those;
- warm-share (N > 1): warm, each worker splitting its CPU work over cores / N threads
  ($WARP_BISCALE_CPU_THREADS in the workers' environment), unpinned.
Every run writes a fresh results folder (no resume).

    python -m bench.bench_batch --out bench/results/batch-cpu --runs 3    # 15-30 min on a 2-core CPU
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

from warp_biscale import batch
from warp_biscale.batch_jobs import loads_jobs
from warp_biscale.device import CPU_THREADS_VARIABLE, usable_cores

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

SCENE = """\
[render]
width = 128
height = 96
ssdf_resolution = 16
ssdf_terms = 8

[camera]
eye = [0.0, 1.2, 3.5]
target = [0.0, -0.2, 0.0]
fov = 40.0

[environment]
type = "sky"
height = 32
width = 64

[[light]]
type = "point"
position = [2.0, 3.0, 2.0]
intensity = 15.0
radius = 0.1

[[object]]
mesh = "sphere"
subdivisions = 3
material = "tile"

[[object]]
mesh = "plane"
size = 6.0
height = -1.0
divisions = 4
material = "floor"

[material.tile]
type = "lambert"

[material.floor]
type = "lambert"
albedo = 0.4
"""

# 12 tasks: 6 tiles x 2 materials, each a bake at 2^14 facets, K = 8, J = 8, its 2^15-facet ground truth
# and PSNR, and a 128 x 96 render (aa 2)
JOB = """\
[bake]
lobes = 8
facets = 16384
directions = 8
normal_res = 64

[compute]
compare = true

[truth]
facets = 32768

[[tile]]
family = "pyramid"
height = {heights}

[[tile]]
family = "grooves"
depth = {depths}

[[tile]]
family = "rods"
length = {lengths}

[[material]]
brdf = "blinnphong:exponent=128,ks=0.6,kd=0.2,normalization=energy"

[[material]]
brdf = "cooktorrance:roughness=0.25,f0=0.04,kd=0.3"

[[scene]]
path = "scene.toml"
slot = "tile"
aa = 2
shadow_samples = 4
"""

MEASURED = {"heights": "[0.3, 0.6]", "depths": "[0.3, 0.6]", "lengths": "[0.3, 0.6]"}
WARMUP = {"heights": "[0.45]", "depths": "[0.45]", "lengths": "0.45"}  # other tiles: 6 tasks, both workers busy


def _jobs(folder, values):
    return loads_jobs(JOB.format(**values), path=os.path.join(folder, "jobs.toml"))


def _busy_seconds() -> float | None:
    """CPU seconds all processes of the machine have used since boot (/proc/stat; None elsewhere)."""
    try:
        with open("/proc/stat") as fh:
            f = [int(x) for x in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    return (sum(f[:8]) - f[3] - f[4]) / os.sysconf("SC_CLK_TCK")  # all but idle and iowait


def _own_seconds() -> float:
    """CPU seconds used by this process and its descendants, live (psutil) and ended (os.times)."""
    import psutil

    me = psutil.Process()
    live = sum(sum(p.cpu_times()[:2]) for p in [me, *me.children(recursive=True)] if p.is_running())
    t = os.times()
    return live + t.children_user + t.children_system


def _timed_run(jobs, out, **kw):
    shutil.rmtree(out, ignore_errors=True)
    busy0, own0 = _busy_seconds(), _own_seconds()
    t0 = time.perf_counter()
    res = batch.run(jobs, out, progress=False, dashboard=False, **kw)
    wall = time.perf_counter() - t0
    busy1, own1 = _busy_seconds(), _own_seconds()
    # other work on the machine during the run, in CPU cores (0: the machine was ours)
    others = None if busy0 is None else max(0.0, ((busy1 - busy0) - (own1 - own0)) / wall)
    if res.failed:
        raise RuntimeError(f"{res.failed} task(s) failed: "
                           + "; ".join(r["error"] for r in res.records.values() if r["status"] == "failed"))
    task_s = [r["timings"]["total"] for r in res.records.values()]
    return {"wall_s": wall, "tasks": len(res.tasks), "other_cores": others, "own_cores": (own1 - own0) / wall,
            "tasks_per_s": len(res.tasks) / wall,
            "task_s_median": statistics.median(task_s), "task_s_sum": sum(task_s),
            "workers_seen": len({(r["worker"]["address"] or r["worker"]["pid"]) for r in res.records.values()})}


SETTINGS = ("here", "cold", "warm", "warm-pinned", "warm-share")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(common.HERE, "results", "batch-cpu"))
    ap.add_argument("--runs", type=int, default=3,
                    help="quiet runs wanted of each setting (medians reported); rounds go on until every setting has "
                         "them or --budget is spent")
    ap.add_argument("--quiet-cores", type=float, default=0.25,
                    help="a run is quiet when other work kept fewer CPU cores busy than this (default 0.25)")
    ap.add_argument("--budget", type=float, default=1800, help="seconds of rounds at most (default 1800)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args(argv)
    import distributed

    warnings.simplefilter("ignore")
    work = tempfile.mkdtemp(prefix="bench-batch-")
    with open(os.path.join(work, "scene.toml"), "w") as fh:
        fh.write(SCENE)
    jobs, warm = _jobs(work, MEASURED), _jobs(work, WARMUP)
    meta = common.run_meta(tasks=len(jobs.tasks), job=JOB.format(**MEASURED), scene=SCENE, runs=args.runs,
                           quiet_cores=args.quiet_cores)
    out = common.Output(args.out, meta)
    out.log(common.commit_line(meta))
    out.log(f"{len(jobs.tasks)} tasks: bake 2^14 facets, K = 8, J = 8; ground truth 2^15 facets + compare; one "
            "128x96 render (aa 2) each")

    runs = {}

    def quiet(rs):
        return [r for r in rs if r["other_cores"] is not None and r["other_cores"] < args.quiet_cores]

    def measure(mode, workers, i):
        folder = os.path.join(work, f"{mode}{workers}-{i}")
        if mode == "here":  # this process keeps its tiles and ground truths across runs: not across these
            batch._TILES.clear()
            batch._TRUTHS.clear()
            r = _timed_run(jobs, folder)
        elif mode == "cold":
            r = _timed_run(jobs, folder, workers=workers)
        else:
            kw = {"pin": workers if mode == "warm-pinned" else 0}
            env = {CPU_THREADS_VARIABLE: str(max(1, usable_cores() // workers))} if mode == "warm-share" else {}
            with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                          dashboard_address=None, silence_logs=logging.CRITICAL, env=env) as lc:
                _timed_run(warm, folder + "-warmup", scheduler=lc.scheduler_address, **kw)
                r = _timed_run(jobs, folder, scheduler=lc.scheduler_address, **kw)
        runs.setdefault((mode, workers), []).append(r)
        out.log(f"round {i + 1}: {mode:>14} workers={workers}: {r['tasks_per_s']:.3f} tasks/s, wall "
                f"{r['wall_s']:.1f} s, median task {r['task_s_median']:.2f} s, CPU cores busy: ours "
                f"{r['own_cores']:.2f}, others {r['other_cores']:.2f}")

    settings = [("here", 0)] + [(m, n) for n in args.workers for m in SETTINGS[1:] if n > 1 or m in ("cold", "warm")]
    _timed_run(warm, os.path.join(work, "warmup-here"))  # the baseline's process warmed first
    # round after round, every setting in turn, so that other work on the machine (logged: the CPU cores it kept
    # busy) falls on every setting alike; a setting stops once it has its quiet runs
    t_end, i = time.perf_counter() + args.budget, 0
    while time.perf_counter() < t_end:
        todo = [s for s in settings if len(quiet(runs.get(s, []))) < args.runs]
        if not todo:
            break
        for mode, n in todo:
            measure(mode, n, i)
        i += 1
    for (mode, n), rs in runs.items():
        q = quiet(rs)
        use = q or rs
        rec = {"mode": mode, "workers": n, "tasks": len(jobs.tasks), "runs": rs, "quiet_runs": len(q),
               "best_tasks_per_s": max(r["tasks_per_s"] for r in rs)}
        for key in ("wall_s", "tasks_per_s", "task_s_median", "task_s_sum", "other_cores", "own_cores"):
            rec[key] = statistics.median(r[key] for r in use)  # over the quiet runs where there are any
        out.records.append(rec)
    by = {(r["mode"], r["workers"]): r for r in out.records}
    for key in ("tasks_per_s", "best_tasks_per_s"):  # 2 workers against 1 (warm-* against warm)
        out.meta[f"speedup_2_over_1_{key}"] = {
            m: by[(m, 2)][key] / by[(m.split("-")[0], 1)][key]
            for m in SETTINGS[1:] if (m, 2) in by and (m.split("-")[0], 1) in by}
    out.meta["speedup_2_over_1_vs_here"] = {m: by[(m, 2)]["tasks_per_s"] / by[("here", 0)]["tasks_per_s"]
                                            for m in SETTINGS[1:] if (m, 2) in by and ("here", 0) in by}
    for r in out.records:
        out.log(f"{r['mode']:>14} workers={r['workers']}: {r['tasks_per_s']:.3f} tasks/s (median of {r['quiet_runs']} "
                f"quiet runs of {len(r['runs'])}; best {r['best_tasks_per_s']:.3f}), wall {r['wall_s']:.1f} s")
    for mode, s in out.meta["speedup_2_over_1_tasks_per_s"].items():
        out.log(f"{mode}: 2 workers give {s:.2f}x the tasks/s of 1 (best runs "
                f"{out.meta['speedup_2_over_1_best_tasks_per_s'][mode]:.2f}x)")
    out.finish(_table)
    shutil.rmtree(work, ignore_errors=True)
    return out.records


def _table(records, meta) -> str:
    rows = [(r["mode"], r["workers"], r["tasks"], f"{r['quiet_runs']}/{len(r['runs'])}", f"{r['wall_s']:.1f}",
             f"{r['tasks_per_s']:.3f}",
             f"{r['best_tasks_per_s']:.3f}", f"{r['task_s_median']:.2f}", f"{r['own_cores']:.2f}",
             f"{r['other_cores']:.2f}",
             " / ".join(f"{x['wall_s']:.1f}" for x in r["runs"])) for r in records]
    lines = [common.commit_line(meta), ""] + common.markdown_table(
        ["mode", "workers", "tasks", "quiet runs", "wall s (median)", "tasks/s (median)", "tasks/s (best)",
         "median task s",
         "cores ours", "cores others", "runs' wall s"], rows)
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
