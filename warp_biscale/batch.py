"""Batch jobs (``warp-biscale batch jobs.toml -o results/``, `wb.batch.run`): bake, judge and render a sweep
of tiles and small-scale materials, one task per material, in this process or on a Dask cluster.

    import warp_biscale as wb
    res = wb.batch.run("jobs.toml", "results", workers=2)   # or workers=0: here, one task at a time
    res.done, res.failed, res.skipped, res.csv, res.html

The job file is described in `warp_biscale.batch_jobs` (tiles with parameter sweeps, materials, bake
settings, scenes with the material's slot named, what to compute). What a run writes::

    results/
      results.csv             one row per task: parameters, method, bake time, PSNR, memory, image paths, error
      index.html              contact sheet: every render's thumbnail beside its parameters, sortable (no server)
      job.toml                the job file the results came from
      tasks/<hash>/           one folder per task, named by a digest of its inputs:
        material.wbm          the baked material (wb.load reads it)
        truth.npz             the ground truth, when asked
        render-<scene>.png    each scene rendered with the material; thumb-<scene>.png its thumbnail
        task.json             timings, metrics, memory, worker: written last, the task's done marker
        error.json            a task that failed twice: its error and traceback (no task.json)

**Where tasks run.** ``workers=N`` (``--workers N``) starts a Dask LocalCluster of N processes with one
Dask thread each, each splitting its CPU work over every core it may run on (``pin=True``, ``--pin``: each
kept on its own share of the cores, `pin_cores`, and splitting over those; ``$WARP_BISCALE_CPU_THREADS`` sets
the count);
``gpus=N`` (``--gpus N``) starts one worker process per GPU, each seeing only its own
(``CUDA_VISIBLE_DEVICES``: its backend's "cuda" or NVIDIA OpenCL device is that GPU; `gpu_cluster`);
``scheduler="tcp://host:8786"``
submits to a running cluster (its workers need warp_biscale and read the job's input files, tile meshes,
images and scene files, at the same paths; what they make comes back to this process, which writes it).
A worker process lives across tasks, so its compiled kernels, backend, tiles (the bake's geometry cache),
ground truths and scenes (lighting, SSDF) stay warm; tasks of one tile are sent to one worker where that
keeps the load even. ``workers=0``, or no Dask installed, runs the tasks here one at a time, with the same
outputs. Scenes are rendered with the job's [bake] backend (not the scene file's), with the SG renderer.

A task's input hash covers the tile (a mesh's or image's bytes), the BRDFs, the bake, truth and compare
settings and each scene file's text (not the files a scene file names in turn: edit those, and pass
``resume=False`` / ``--no-resume``).

**Faults.** A task that raises is run once more (Dask ``retries=1``); if it fails again its error is
recorded and the others go on. A worker that dies (killed, out of memory) has its tasks run elsewhere; a
task that kills its worker on every attempt (a crash in native code) is recorded as failed after three
deaths (Dask's KilledWorker), as may be a task queued on that worker beside it (a rerun tries them again).
Without Dask (``workers=0``) such a crash ends the whole run: ``workers=1`` keeps it to its worker.
Each task's files are written atomically, its task.json last; a rerun skips every task whose task.json
has the same input hash and whose outputs are all there as written (their SHA-256 in task.json), so an
interrupted run (Ctrl-C) resumes where it stopped and an output edited or cut since is made again.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import json
import os
import re
import socket
import sys
import tempfile
import time
import traceback
import uuid
import warnings

from .batch_jobs import (Jobs, Task, check_output_folder, digest, file_sha256, jobs_from_dict, load_jobs, loads_jobs,
                         open_scene)
from .batch_report import ProgressLine, write_report
from .device import cpu_threads
from .io import atomic_path

__all__ = ["run", "execute", "BatchResult", "load_jobs", "loads_jobs", "jobs_from_dict", "add_parser", "cmd_batch",
           "assign_workers"]

TASKS_DIR = "tasks"
RECORD = "task.json"
ERROR = "error.json"
THUMB_SIZE = 192  # pixels: the longer side of a contact-sheet thumbnail
RETRIES = 1


@dataclasses.dataclass
class BatchResult:
    """What `run` did: `ran` tasks this run (`done` + `failed`), `skipped` (done before, resumed), the
    records by task hash, and the report's paths."""

    output: str
    tasks: list
    records: dict
    ran: int = 0
    done: int = 0
    failed: int = 0
    skipped: int = 0
    elapsed: float = 0.0
    interrupted: bool = False
    csv: str = ""
    html: str = ""
    dashboard: str | None = None

    @property
    def rate(self) -> float:
        """Tasks finished per second of this run (done or failed)."""
        return self.ran / self.elapsed if self.elapsed > 0 else 0.0


# ------------------------------------------------------------------------------------------------
# one task, in a worker process (or here)

_TILES: collections.OrderedDict = collections.OrderedDict()   # tile_key → SmallScale (the bake caches per tile object)
_TRUTHS: collections.OrderedDict = collections.OrderedDict()  # truth key → GroundTruth
_SCENES: collections.OrderedDict = collections.OrderedDict()  # scene key → (SceneFile, slot index)
_MEASURED: collections.OrderedDict = collections.OrderedDict()  # (path, sha256, interpolation) → MeasuredBRDF
_STATE = {"tasks": 0}
CACHE_SIZES = {"tiles": 16, "truths": 8, "scenes": 4, "measured": 4}


def _cached(cache, key, size, make):
    if key in cache:
        cache.move_to_end(key)
        return cache[key], True
    value = make()
    cache[key] = value
    while len(cache) > size:
        cache.popitem(last=False)
    return value, False


def _task_brdf(d: dict):
    """A small-scale BRDF from its task record (`batch_jobs._material_dict`): a MERL table read from its file,
    which must be the one the job was read with."""
    from .effective import _brdf_from_dict
    from .measured import MeasuredBRDF

    if d.get("type") != "MeasuredBRDF":
        return _brdf_from_dict(d)

    def load():  # (once a worker: the table, 33 MB, and its SG fit, which the bakes keep by table, are reused)
        if file_sha256(d["path"]) != d["sha256"]:
            raise ValueError(f"the MERL file {d['path']} changed since the job was read (its SHA-256 differs)")
        return MeasuredBRDF.load(d["path"], interpolation=d["interpolation"])

    return _cached(_MEASURED, (d["path"], d["sha256"], d["interpolation"]), CACHE_SIZES["measured"], load)[0]


def _build_tile(spec):
    from . import geometry
    from .smallscale import SmallScale

    if spec["kind"] == "family":
        return getattr(geometry, spec["fn"])(**spec["params"])
    if spec["kind"] == "mesh":
        period = spec["params"].get("period")
        return SmallScale.load(spec["path"], period=None if period is None else tuple(period))
    return geometry.heightfield_from_image(spec["path"], **spec["params"])


def _memory() -> dict:
    """This process's resident memory now and at its peak so far, in MB (None where unknown)."""
    rss = peak = None
    try:
        with open("/proc/self/statm") as fh:
            rss = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (2**20 if sys.platform == "darwin" else 2**10)
    except (ImportError, OSError):
        pass
    return {"rss_mb": None if rss is None else round(rss, 1), "peak_rss_mb": None if peak is None else round(peak, 1)}


def _worker_name() -> str | None:
    if "distributed" not in sys.modules:
        return None
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError, AttributeError):
        return None


def pin_cores(n_workers: int):
    """In worker `i` (its Dask name, as LocalCluster numbers them) of a local cluster of `n_workers`: keep this
    process, every thread of it, on its own share of the cores (i·C/n … (i+1)·C/n − 1 of the C cores it may
    use; one core round-robin when there are more workers than cores), so that workers do not crowd each
    other's cores. Once per process; → the cores, or None where there is nothing to do (one worker, not in
    a numbered Dask worker, no sched_setaffinity)."""
    if "pinned" in _STATE:
        return _STATE["pinned"]
    _STATE["pinned"] = None
    if n_workers < 2 or not hasattr(os, "sched_setaffinity") or "distributed" not in sys.modules:
        return None
    try:
        from distributed import get_worker

        index = get_worker().name
    except (ImportError, ValueError, AttributeError):
        return None
    if not isinstance(index, int) or index < 0:
        return None
    cores = sorted(os.sched_getaffinity(0))
    c = len(cores)
    mine = cores[index * c // n_workers:(index + 1) * c // n_workers] if n_workers <= c else [cores[index % c]]
    try:
        for tid in os.listdir("/proc/self/task"):
            os.sched_setaffinity(int(tid), mine)
    except OSError:
        return None
    _STATE["pinned"] = mine
    return mine


def _thumbnail(src, dst):
    from PIL import Image

    with Image.open(src) as im:
        im.thumbnail((THUMB_SIZE, THUMB_SIZE))
        im.save(dst, format="PNG")


def execute(task: dict, hook=None, pin: int = 0) -> dict:
    """Run one task (a `Task.payload()`) here → {"record": what task.json holds, "files": name → bytes}.
    The files are made in a temporary folder and returned, not written: the caller writes them into the
    results folder (which a remote worker may not see). `pin`: the local cluster's worker count, for
    `pin_cores` (0: leave the process where it is). `hook(task)`, if given, runs first (tests use it to make
    a task fail or its worker die). Raises on failure."""
    from .bake import bake
    from .brdf import EnergyWarning, Lambert
    from .effective import compare
    from .render import SHADOW_SAMPLES, render
    from .smallscale import TileWarning
    from .truth import ground_truth

    if pin:
        pin_cores(pin)
    if hook is not None:
        hook(task)
    t_all = time.perf_counter()
    _STATE["tasks"] += 1
    b = task["bake"]
    backend = b["backend"]
    timings, metrics, outputs, caches = {}, {}, {"renders": {}, "thumbnails": {}}, {}
    with tempfile.TemporaryDirectory(prefix="wb-batch-") as tmp, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", EnergyWarning)  # said once, with its line, when the job file was read
        warnings.simplefilter("ignore", TileWarning)
        tile, caches["tile"] = _cached(_TILES, task["tile_key"], CACHE_SIZES["tiles"],
                                       lambda: _build_tile(task["tile"]))
        mats = [_task_brdf(d) for d in task["materials"]]
        t0 = time.perf_counter()
        mat = bake(tile, mats, method=b["method"], lobes=b["lobes"], directions=b["directions"],
                   normal_res=b["normal_res"], facets=b["facets"], backend=backend, seed=b["seed"], route=b["route"],
                   progress=False)
        timings["bake"] = time.perf_counter() - t0
        timings["bake_stages"] = dict(mat.timings)
        mat.save(os.path.join(tmp, "material.wbm"))
        outputs["material"] = "material.wbm"
        if task["truth"] is not None:
            tr = task["truth"]
            key = digest([task["tile_key"], task["materials"], tr, backend])
            t0 = time.perf_counter()
            gt, caches["truth"] = _cached(_TRUTHS, key, CACHE_SIZES["truths"], lambda: ground_truth(
                tile, mats, facets=tr["facets"], directions=tr["directions"], backend=backend, seed=tr["seed"],
                progress=False))
            timings["truth"] = time.perf_counter() - t0
            gt.save(os.path.join(tmp, "truth.npz"))
            outputs["truth"] = "truth.npz"
            if task["compare"]:
                t0 = time.perf_counter()
                metrics = compare(mat, gt)
                timings["compare"] = time.perf_counter() - t0
        timings["render"] = {}
        for sc in task["scenes"]:
            key = digest([sc, backend])

            def load(sc=sc):
                sf = open_scene(sc["path"], sc["slot"], Lambert(0.5), backend=backend)
                sf.resize(sc["width"], sc["height"])
                return sf, sf.material_names.index(sc["slot"])

            t0 = time.perf_counter()
            (sf, slot), caches[f"scene {sc['name']}"] = _cached(_SCENES, key, CACHE_SIZES["scenes"], load)
            materials = list(sf.scene.materials)
            materials[slot] = mat
            scene = dataclasses.replace(sf.scene, materials=materials, cache={})
            block_rays, occlusion = sc.get("block_rays"), sc.get("occlusion_samples")
            result = render(scene, method="sg", backend=backend, aa=sc["aa"],
                            shadow_samples=sc["shadow_samples"] or SHADOW_SAMPLES,
                            block_rays="auto" if block_rays is None else block_rays,
                            **({} if occlusion is None else {"occlusion_samples": occlusion}))
            image, thumb = f"render-{sc['name']}.png", f"thumb-{sc['name']}.png"
            result.save(os.path.join(tmp, image), exposure=sc["exposure"])
            _thumbnail(os.path.join(tmp, image), os.path.join(tmp, thumb))
            timings["render"][sc["name"]] = time.perf_counter() - t0
            outputs["renders"][sc["name"]], outputs["thumbnails"][sc["name"]] = image, thumb
        files = {}
        for name in sorted(os.listdir(tmp)):
            with open(os.path.join(tmp, name), "rb") as fh:
                files[name] = fh.read()
    timings["total"] = time.perf_counter() - t_all
    record = {
        "status": "done", "hash": task["hash"], "label": task["label"], "outputs": outputs, "timings": timings,
        "metrics": metrics, "caches": caches,
        "bake_info": {"lobes_live": len(mat.sampling_lobes()[1]), "backend": mat.info.get("backend"),
                      "ndf_error": mat.info.get("ndf_error"), "method": getattr(mat, "method", None)},
        "memory": {**_memory(), "wbm_bytes": len(files["material.wbm"]),
                   "table_bytes": int(mat.amplitudes.nbytes)},
        "worker": {"address": _worker_name(), "host": socket.gethostname(), "pid": os.getpid(),
                   "task_index": _STATE["tasks"], "cores": _STATE.get("pinned"),
                   "gpus": os.environ.get("CUDA_VISIBLE_DEVICES"), "backend": mat.info.get("backend"),
                   "cpu_threads": cpu_threads()},
        "warnings": sorted({f"{w.category.__name__}: {w.message}" for w in caught}),
    }
    return {"record": record, "files": files}


# ------------------------------------------------------------------------------------------------
# the results folder


REPORT_FILES = ("results.csv", "index.html", "job.toml")  # what a run writes beside tasks/ (and overwrites)
_TASK_NAME = re.compile(r"[0-9a-f]{16}")  # a task folder's name: batch_jobs.digest's 16 hex digits


def is_results_folder(folder) -> bool:
    """Whether `folder` holds an earlier batch's results: a tasks/ folder (a run makes it before it writes anything
    else) of task folders alone, each named by its task's hash; empty where a run stopped before its first task.
    Hidden entries are passed over (a file browser's .DS_Store in a results folder someone looked through)."""
    tasks = os.path.join(folder, TASKS_DIR)
    try:
        names = [n for n in os.listdir(tasks) if not n.startswith(".")]
    except OSError:  # (none, or not a folder)
        return False
    return all(_TASK_NAME.fullmatch(n) and os.path.isdir(os.path.join(tasks, n)) for n in names)


def check_results_folder(folder, error=None) -> None:
    """Refuse, in one line naming the folder and a file in it, a results folder that holds files and is not an
    earlier batch's (`is_results_folder`): a run writes results.csv, index.html and job.toml there and would
    replace the user's own. An earlier batch's is reused (a rerun resumes there); a missing or empty one is made
    or filled. `error(message)` builds the exception (default ValueError)."""
    try:
        names = sorted(os.listdir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return  # (missing: made; a file in the way: check_output_folder says so)
    if not names or is_results_folder(folder):
        return
    clash = [n for n in REPORT_FILES if n in names]  # name a file the run would replace, where there is one
    more = f" and {len(names) - 1} more" if len(names) > 1 else ""
    msg = (f"output folder {folder!r} holds {(clash or names)[0]!r}{more} and is not an earlier batch's results (no "
           f"{TASKS_DIR}/ folder of task folders); give a new or empty folder")
    raise error(msg) if error else ValueError(msg)


def task_dir(output, task_hash) -> str:
    return os.path.join(output, TASKS_DIR, task_hash)


def read_done(output, task: Task) -> dict | None:
    """The task's record if it finished before with these inputs and every output is still there as it was
    written (its SHA-256 in the record), else None."""
    folder = task_dir(output, task.hash)
    try:
        with open(os.path.join(folder, RECORD)) as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.get("status") != "done" or rec.get("hash") != task.hash:
        return None
    outs = rec.get("outputs", {})
    names = [outs.get("material"), outs.get("truth"), *outs.get("renders", {}).values(),
             *outs.get("thumbnails", {}).values()]
    if not all(os.path.isfile(os.path.join(folder, n)) for n in names if n):
        return None
    sums = rec.get("sha256")
    if not isinstance(sums, dict) or not all(n in sums for n in names if n):
        return None  # (a record of an older version, without the sums: the task runs again)
    if any(file_sha256(os.path.join(folder, n)) != h for n, h in sums.items()):
        return None  # an output edited, cut or replaced since
    return rec


def _write_json(path, obj):
    with atomic_path(path) as tmp:
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=1, sort_keys=True)


def _store(output, task: Task, result: dict, attempts) -> dict:
    """Write a finished task's files atomically, then its task.json (the done marker) → its record."""
    folder = task_dir(output, task.hash)
    os.makedirs(folder, exist_ok=True)
    for name, data in result["files"].items():
        with atomic_path(os.path.join(folder, name)) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(data)
    rec = {"format": "warp_biscale.batch_task", "version": 1, **result["record"], "attempts": attempts,
           "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), "task": task.payload(),
           "sha256": {name: hashlib.sha256(data).hexdigest() for name, data in result["files"].items()}}
    _write_json(os.path.join(folder, RECORD), rec)
    if os.path.exists(os.path.join(folder, ERROR)):
        os.remove(os.path.join(folder, ERROR))
    return rec


def _store_failure(output, task: Task, exc, tb: str, attempts) -> dict:
    folder = task_dir(output, task.hash)
    os.makedirs(folder, exist_ok=True)
    msg = " ".join(str(exc).split()) or type(exc).__name__
    rec = {"format": "warp_biscale.batch_task", "version": 1, "status": "failed", "hash": task.hash,
           "label": task.label, "error": f"{type(exc).__name__}: {msg}", "traceback": tb, "attempts": attempts,
           "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), "task": task.payload()}
    _write_json(os.path.join(folder, ERROR), rec)
    return rec


# ------------------------------------------------------------------------------------------------
# running


def assign_workers(tasks, workers) -> dict:
    """task hash → worker address: the tasks in tile order (`_order`) cut into one run of consecutive
    tasks per worker, of near-equal counts, so that a tile's tasks share a worker (its tile, geometry
    and ground truths stay warm there) except where a run ends inside a tile. Only a preference: Dask
    moves a task to another worker when its own is busy or gone (allow_other_workers)."""
    if not workers:
        return {}
    ordered = _order(tasks)
    n, w = len(ordered), len(workers)
    out, start = {}, 0
    for i, addr in enumerate(workers):
        end = start + n // w + (1 if i < n % w else 0)
        out.update({t.hash: addr for t in ordered[start:end]})
        start = end
    return out


def _order(tasks) -> list:
    """Tasks of one tile together (the bake then rebuilds only the tables), in the job's order otherwise."""
    first = {}
    for i, t in enumerate(tasks):
        first.setdefault(t.tile_key, i)
    return sorted(tasks, key=lambda t: first[t.tile_key])


def _have(module) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def run(jobs, output=None, *, workers: int = 0, scheduler: str | None = None, resume: bool = True, progress=None,
        hook=None, dashboard: bool = True, pin: bool | int = False, stream=None, gpus: int = 0) -> BatchResult:
    """Run a job (a job file's path, `Jobs` from `load_jobs` / `loads_jobs`, or a dict as `jobs_from_dict`
    takes) into the folder `output` (default
    the file's `output`, else "results") → BatchResult. `workers`: a Dask LocalCluster of that many
    processes (0: here, one task at a time); `gpus`: a local cluster of one worker per GPU instead
    (`gpu_cluster`); `scheduler`: the address of a running Dask scheduler instead.
    `resume`: skip tasks finished before with the same inputs. `progress`: a line on stderr (None: when it
    is a terminal). `pin`: keep each worker of the local cluster on its own share of the cores (`pin_cores`;
    off by default: on a machine that other work shares, a pinned worker cannot move off a busy core); an
    integer n does so for the workers numbered 0 … n − 1 of `scheduler` (a LocalCluster of the caller's).
    `hook(task dict)` runs before every attempt of every task, in the worker (for tests and benchmarks).
    `output` must be missing, empty or an earlier run's results (`check_results_folder`, before any task runs).
    Ctrl-C stops the run; what finished is kept, and the report is written before KeyboardInterrupt goes on."""
    if isinstance(jobs, dict):
        jobs = jobs_from_dict(jobs)
    elif not isinstance(jobs, Jobs):
        jobs = load_jobs(jobs)
    output = os.path.abspath(os.fspath(output or jobs.output or "results"))
    check_output_folder(output)
    check_results_folder(output)
    workers, gpus = int(workers or 0), int(gpus or 0)
    if workers < 0 or gpus < 0:
        raise ValueError(f"workers and gpus must be >= 0, got {workers} and {gpus}")
    if sum(map(bool, (scheduler, workers, gpus))) > 1:
        raise ValueError("give one of workers (a local cluster), gpus (one worker per GPU) or scheduler "
                         "(a running one)")
    use_dask = bool(scheduler) or workers > 0 or gpus > 0
    if use_dask and not _have("distributed"):
        if scheduler:
            raise ValueError("scheduler needs Dask: pip install 'dask[distributed]'")
        warnings.warn("Dask is not installed: the tasks run in this process, one at a time (pip install "
                      "'dask[distributed]' for workers)", RuntimeWarning, stacklevel=2)
        use_dask = False
    os.makedirs(os.path.join(output, TASKS_DIR), exist_ok=True)
    if jobs.text is not None:
        with atomic_path(os.path.join(output, "job.toml")) as tmp:
            with open(tmp, "w") as fh:
                fh.write(jobs.text)
    res = BatchResult(output=output, tasks=list(jobs.tasks), records={})
    before = {}
    if resume:
        for t in jobs.tasks:
            rec = read_done(output, t)
            if rec is not None:
                before[t.hash] = rec
    res.records.update(before)
    res.skipped = len(before)
    todo = _order([t for t in jobs.tasks if t.hash not in before])
    line = ProgressLine(len(todo), res.skipped, progress, stream)
    t0 = time.perf_counter()

    def done(task, result, attempts=None):
        res.records[task.hash] = _store(output, task, result, attempts)
        res.done += 1
        line.update(res.done, res.failed, task.label, res.records[task.hash]["timings"]["total"])

    def failed(task, exc, tb, attempts=RETRIES + 1):
        res.records[task.hash] = _store_failure(output, task, exc, tb, attempts)
        res.failed += 1
        line.update(res.done, res.failed, task.label, None, res.records[task.hash]["error"])

    not_started = False
    try:
        if not todo:
            pass
        elif use_dask:
            n_pin = pin if not isinstance(pin, bool) else workers if pin and not scheduler else 0
            _run_dask(todo, workers, scheduler, hook, dashboard, int(n_pin), done, failed, line, res, gpus)
        else:
            _run_here(todo, hook, done, failed)
    except KeyboardInterrupt:
        res.interrupted = True
        raise
    except Exception:
        not_started = res.done + res.failed == 0  # (no cluster reached: no task ran)
        raise
    finally:
        res.ran = res.done + res.failed
        res.elapsed = time.perf_counter() - t0
        line.finish(res)
        csv = os.path.join(output, "results.csv")
        if not (not_started and os.path.exists(csv)):  # (a run that never started leaves the last report alone)
            res.csv, res.html = write_report(output, jobs, res.records, TASKS_DIR)
    return res


def _run_here(todo, hook, done, failed):
    for task in todo:
        for attempt in range(1, RETRIES + 2):
            try:
                result = execute(task.payload(), hook)
            except Exception as exc:  # noqa: BLE001 - any failure of a task is recorded, the rest go on
                if attempt == RETRIES + 1:
                    failed(task, exc, traceback.format_exc(), attempt)
                continue
            done(task, result, attempt)
            break


def gpu_cluster(gpus: int, dashboard: bool = False):
    """A local Dask cluster of one worker process per GPU, worker i seeing GPU i alone
    (CUDA_VISIBLE_DEVICES=i, one thread): dask-cuda's LocalCUDACluster where it is installed, else the same
    made of distributed's own parts (a SpecCluster of nannies, each given its worker's environment)."""
    import logging

    try:
        from dask_cuda import LocalCUDACluster
    except ImportError:
        LocalCUDACluster = None
    address = ":8787" if dashboard else None
    if LocalCUDACluster is not None:
        return LocalCUDACluster(CUDA_VISIBLE_DEVICES=list(range(gpus)), threads_per_worker=1,
                                dashboard_address=address, silence_logs=logging.CRITICAL)
    from distributed import Nanny, Scheduler, SpecCluster

    scheduler = {"cls": Scheduler, "options": {"dashboard": bool(dashboard), "dashboard_address": address or ":0"}}
    workers = {i: {"cls": Nanny, "options": {"nthreads": 1, "name": i, "env": {"CUDA_VISIBLE_DEVICES": str(i)},
                                             "silence_logs": logging.CRITICAL}} for i in range(gpus)}
    return SpecCluster(workers=workers, scheduler=scheduler, silence_logs=logging.CRITICAL)


WATCH_S = 5.0  # seconds without a finished task before the batch looks for tasks stranded on a dead worker
RESULT_S = 32.0  # a finished task's result may take up to twice this to come back (its files: up to hundreds of MB)


def _collect(client, fut, task, done, failed) -> bool:
    """A finished or failed future's result or error, to `done` or `failed`; then released. False, and nothing
    said, where a finished task's result is held by no worker or did not come within RESULT_S: its worker died
    holding it, and it is computed again (`_resend_stranded` sends it elsewhere if it was sent to that worker)."""
    if fut.status == "finished":
        wait, result = 1.0, None
        while result is None:  # (waits that double: a worker that dies is seen in a second or two, a big result
            if fut.status != "finished" or not client.who_has([fut]).get(fut.key):  # gets up to a minute)
                return False
            try:
                result = fut.result(timeout=wait)
            except TimeoutError:
                if wait > RESULT_S:
                    return False
                wait *= 2
            except Exception as exc:  # noqa: BLE001 - lost on the way back: recorded as a failure
                failed(task, exc, traceback.format_exc())
                break
        if result is not None:
            done(task, result)
    else:
        try:
            exc, tb = fut.exception(), fut.traceback()
        except Exception as lost:  # noqa: BLE001 - cancelled (the scheduler or the cluster went away)
            exc, tb = lost, None
        failed(task, exc, "".join(traceback.format_exception(type(exc), exc, tb)))
    fut.release()
    return True


def _resend_stranded(client, futures, assignment, submit) -> None:
    """Send again, to any worker, the unfinished tasks sent to a worker that has left the cluster. Dask keeps a
    task whose worker restriction names a departed worker waiting for it ("no-worker") even where other workers
    are allowed, and a local cluster's nanny restarts a killed worker at a new address: the batch waited for
    ever once a task had killed its worker."""
    alive = set(client.scheduler_info()["workers"])
    for fut, task in list(futures.items()):
        where = assignment.get(task.hash)
        if where is None or where in alive or fut.done():
            continue
        client.cancel(fut)
        del futures[fut]
        del assignment[task.hash]
        futures[submit(task, None)] = task


def _run_dask(todo, workers, scheduler, hook, dashboard, pin, done, failed, line, res, gpus=0):
    import logging

    from distributed import Client, LocalCluster

    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        dashboard = dashboard and _have("bokeh")  # (Dask's dashboard needs bokeh)
        # Dask's own log lines stay quiet: a failed task is on the progress line and in its error.json
        cluster = (gpu_cluster(gpus, dashboard) if gpus else
                   LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                dashboard_address=":8787" if dashboard else None, silence_logs=logging.CRITICAL))
        client = Client(cluster)
    futures = {}
    try:
        res.dashboard = client.dashboard_link if dashboard else None
        line.say(f"Dask: {len(client.scheduler_info()['workers'])} worker(s)" +
                 (f", dashboard {res.dashboard}" if res.dashboard else ""))
        assignment = assign_workers(todo, sorted(client.scheduler_info()["workers"]))
        tag = uuid.uuid4().hex[:8]

        def submit(task, where):
            return client.submit(execute, task.payload(), hook, pin,
                                 key=f"warp-biscale-{task.hash}-{tag}{'' if where else '-anywhere'}",
                                 retries=RETRIES, pure=False,
                                 **({"workers": [where], "allow_other_workers": True} if where else {}))

        for task in todo:
            futures[submit(task, assignment.get(task.hash))] = task
        quiet = time.monotonic()
        while futures:  # (a future's state is local: polling it costs nothing beside tasks of seconds)
            finished = [fut for fut in futures if fut.done() and _collect(client, fut, futures[fut], done, failed)]
            for fut in finished:
                del futures[fut]
            if finished:
                quiet = time.monotonic()
            elif time.monotonic() - quiet > WATCH_S:  # a quiet spell: has a worker that tasks were sent to gone?
                _resend_stranded(client, futures, assignment, submit)
                quiet = time.monotonic()
            else:
                time.sleep(0.05)
    finally:
        if futures:
            client.cancel(list(futures))
        client.close()
        if cluster is not None:
            cluster.close()


# ------------------------------------------------------------------------------------------------
# command line


def add_parser(subparsers):
    """The `batch` sub-command, for cli.main's subparsers."""
    p = subparsers.add_parser(
        "batch", help="run a job file: bake, judge and render a sweep of tiles and materials",
        description="Run a TOML job file (schema: `python -m pydoc warp_biscale.batch_jobs`; "
                    "examples/jobs/sweep.toml): one task per material of the sweep, each writing its .wbm, "
                    "ground truth, renders and timings under OUTPUT/tasks/<hash>/, with OUTPUT/results.csv and "
                    "OUTPUT/index.html (a contact sheet) over all of them. A rerun skips the tasks already done.")
    p.add_argument("jobs", help="the job file (.toml)")
    p.add_argument("-o", "--output", help="results folder (default: the job file's `output`, else ./results)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="run on a local Dask cluster of N worker processes, one thread each (default 0: in this "
                        "process, one task at a time)")
    p.add_argument("--gpus", type=int, metavar="N",
                   help="run on a local Dask cluster of one worker per GPU (GPUs 0 .. N-1, each worker seeing its own)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="submit to a running Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--no-resume", action="store_true", help="run every task again, even those done before")
    p.add_argument("--no-dashboard", action="store_true", help="start the local cluster without its web dashboard")
    p.add_argument("--pin", action="store_true",
                   help="keep each local worker on its own share of the CPU cores (for a machine of its own)")
    p.add_argument("--dry-run", action="store_true", help="check the job file and list its tasks; run nothing")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress, no summary")
    p.set_defaults(func=cmd_batch)
    return p


def _cuda_device_count() -> int:
    """The GPUs the CUDA driver sees (0 without one), asked of the driver itself: no context is made in this
    process, which hands the GPUs to its workers."""
    import ctypes

    try:
        cuda = ctypes.CDLL("libcuda.so.1")
        count = ctypes.c_int(0)
        if cuda.cuInit(0) != 0 or cuda.cuDeviceGetCount(ctypes.byref(count)) != 0:
            return 0
        return int(count.value)
    except OSError:
        return 0


def cmd_batch(args):
    """`warp-biscale batch`: 0 when every task is done, 1 when some failed, 2 for a bad job file or argument
    (raised as ValueError, which cli.main reports in one line)."""
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers must be >= 0, got {args.workers}")
    if args.gpus is not None and args.gpus < 0:
        raise ValueError(f"--gpus must be >= 0, got {args.gpus}")
    if sum(map(bool, (args.scheduler, args.workers, args.gpus))) > 1:
        raise ValueError("give one of --workers N (a local cluster), --gpus N (one worker per GPU) or "
                         "--scheduler ADDRESS (a running one)")
    if args.scheduler and _have("distributed"):  # (its syntax before any work; whether one answers, on connecting)
        from distributed.comm import parse_address, parse_host_port

        try:
            parse_host_port(parse_address(args.scheduler)[1])
        except ValueError as exc:
            raise ValueError(f"--scheduler {args.scheduler!r}: {exc} (e.g. tcp://host:8786)") from None
    if args.gpus:
        found = _cuda_device_count()
        if found < args.gpus:
            warnings.warn(f"--gpus {args.gpus}, but {found or 'no'} CUDA GPU(s) are visible here: the workers beyond "
                          "them see none, and the job's backend runs on the CPU there", stacklevel=2)
    if args.output:
        check_output_folder(os.path.abspath(args.output), lambda msg: ValueError(f"-o: {msg}"))
        check_results_folder(os.path.abspath(args.output), lambda msg: ValueError(f"-o: {msg}"))
    jobs = load_jobs(args.jobs)
    if not (args.scheduler or args.gpus or args.workers or args.dry_run):  # (the tasks run here: its backends, now)
        from .backend import get_backend

        for name in sorted({t.bake["backend"] for t in jobs.tasks}):
            try:
                get_backend(name)
            except (ValueError, RuntimeError) as exc:
                raise ValueError(f"{args.jobs}: [bake] backend {name!r} cannot run here: {exc}") from None
    if args.dry_run:
        for t in jobs.tasks:
            print(f"{t.hash}  {t.label}")
        print(f"{len(jobs.tasks)} task(s)")
        return 0
    res = run(jobs, args.output, workers=args.workers or 0, scheduler=args.scheduler, resume=not args.no_resume,
              progress=not args.quiet, dashboard=not args.no_dashboard, pin=args.pin, gpus=args.gpus or 0)
    if not args.quiet:
        print(f"wrote {res.csv} and {res.html}")
    if res.failed:
        print(f"error: {res.failed} of {len(res.tasks)} task(s) failed (errors in {res.csv} and "
              f"{os.path.join(res.output, TASKS_DIR, '<hash>', ERROR)})", file=sys.stderr)
        return 1
    return 0
