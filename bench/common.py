"""What the benchmarks share: the commit measured, the backends to run, median-of-runs timing with the
device synchronised, the timing tile, and an output folder (results.json, table.md, log.txt, plots)."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field

import numpy as np

import warp_biscale as wb

HERE = os.path.dirname(os.path.abspath(__file__))


def git_commit() -> str | None:
    """The commit measured: $WARP_BISCALE_COMMIT when set (a copy of the tree on another machine may carry
    no .git, or a stale one), else git's HEAD here (None when neither is known)."""
    if os.environ.get("WARP_BISCALE_COMMIT"):
        return os.environ["WARP_BISCALE_COMMIT"]
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE,
                              timeout=10).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def library_changed() -> bool | None:
    """Whether the library's files differ from the commit (uncommitted edits under warp_biscale/, kernels/,
    cl/): a figure measured on such a tree is not the commit's. None where git cannot tell, and None when
    $WARP_BISCALE_COMMIT names the commit (the caller vouches for the tree)."""
    if os.environ.get("WARP_BISCALE_COMMIT"):
        return None
    try:
        out = subprocess.run(["git", "status", "--porcelain", "--", "warp_biscale", "kernels", "cl"],
                             capture_output=True, text=True, cwd=os.path.dirname(HERE), timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return bool(out.stdout.strip()) if out.returncode == 0 else None


def commit_line(meta: dict) -> str:
    """A table's first line: the commit, date and machine of its run."""
    edits = " with uncommitted library edits" if meta.get("library_changed") else ""
    return f"commit {meta.get('commit')}{edits}, {meta.get('date')}, {meta.get('cpu')}"


def host_device() -> str:
    """The host CPU in words (its model name where /proc/cpuinfo gives one) and its CPU count."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            model = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{model} ({os.cpu_count()} CPUs)"


def load_average() -> list | None:
    """The 1, 5 and 15-minute load averages (None where the OS gives none): other work on the machine."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def run_meta(**extra) -> dict:
    """What a results.json says about its run: commit, date, machine, command line, load."""
    return {"commit": git_commit(), "library_changed": library_changed(), "date": time.strftime("%Y-%m-%d %H:%M"),
            "host": platform.node(), "cpu": host_device(), "machine": platform.machine(),
            "python": sys.version.split()[0], "cpu_count": os.cpu_count(), "argv": sys.argv[1:],
            "loadavg_start": load_average(), **extra}


def backend_names(requested=None) -> list[str]:
    """The backends to measure: those named, else every usable one found here (`wb.backends()`)."""
    if requested:
        return list(requested)
    return [b["name"] for b in wb.backends() if b["usable"]]


@dataclass
class Timed:
    median_s: float
    runs_s: list = field(default_factory=list)  # every timed run, in order
    first_call_extra_s: float = 0.0  # the warm-up call's time over the median: compilation, uploads, caches
    first: object = None  # the warm-up call's result
    results: list = field(default_factory=list)  # the timed runs' results (keep_all) or the last one

    @property
    def last(self):
        return self.results[-1] if self.results else self.first


def timed(fn, runs: int, sync=None, *, make_input=None, budget_s: float | None = None, warmup_s: float = 0.0,
          keep_all: bool = False) -> Timed:
    """fn() once as a warm-up, then for `warmup_s` more seconds untimed (a GPU's clocks and the host's caches
    settle), then `runs` timed calls; each clock stops after `sync` (a backend, or a function) has drained the
    device's queue. `make_input()`, outside the clock, gives each call its argument (fn(input)). With
    `budget_s`, the timed calls stop once they took more than budget_s × runs in all (at least one runs)."""
    sync = getattr(sync, "synchronize", sync)

    def once():
        arg = (make_input(),) if make_input is not None else ()
        t0 = time.perf_counter()
        out = fn(*arg)
        if sync is not None:
            sync()
        return time.perf_counter() - t0, out

    first_s, first = once()
    until = time.perf_counter() + warmup_s
    while time.perf_counter() < until:
        once()
    times, results = [], []
    for _ in range(runs):
        t, out = once()
        times.append(t)
        if keep_all:
            results.append(out)
        else:
            results = [out]
        if budget_s is not None and sum(times) > budget_s * runs:
            break
    med = float(np.median(times))
    return Timed(med, times, max(first_s - med, 0.0), first, results)


BLOCK_MODES = {"off": (False,), "on": (True,), "2": (2,), "4": (4,), "both": (False, True)}


def block_modes(names) -> tuple:
    """The block_rays values a bench's --block-rays names (off, on = 2×2, 2, 4, both = off and on), in order."""
    out = []
    for name in [names] if isinstance(names, str) else names:
        out += [m for m in BLOCK_MODES[name] if m not in out]
    return tuple(out)


def block_side(block) -> int:
    """The side of the pixel blocks a block_rays value asks for: False 1, True 2, else the value."""
    return (2 if block else 1) if isinstance(block, bool) else int(block)


def block_rays_option(block) -> dict:
    """wb.render's keyword for the rays shared in pixel blocks or not, said outright (False, True: 2×2, or a side
    2 / 4): its default ("auto") shares them from 320×240 up. An older tree (A/B runs) without the option gets none
    for False, and refuses anything else."""
    import inspect

    if block or "block_rays" in inspect.signature(wb.render).parameters:
        return {"block_rays": block if isinstance(block, int) and not isinstance(block, bool) else bool(block)}
    return {}


def heightfield_tile(n: int = 64, amplitude: float = 0.25, seed: int = 0):
    """The timing tile: a periodic random height field of n×n cells (2n² triangles; n = 64: 8192 triangles)."""
    rng = np.random.default_rng(seed)
    # A few sinusoids of random wave vectors keep it periodic and non-trivial to trace.
    x = np.arange(n) / n
    gx, gy = np.meshgrid(x, x, indexing="ij")
    h = np.zeros((n, n))
    for _ in range(6):
        kx, ky = rng.integers(1, 5, 2)
        h += rng.random() * np.sin(2 * np.pi * (kx * gx + ky * gy) + rng.random() * 6.28)
    h = (h - h.min()) / np.ptp(h) * amplitude
    return wb.geometry.heightfield(h, size=1.0)


def log2(n) -> int:
    return int(np.log2(n))


class Output:
    """A run's output folder: records and meta saved as results.json (after each step, so that a time limit
    keeps what is done), a markdown table, and every logged line printed and kept in log.txt."""

    def __init__(self, folder: str, meta: dict):
        os.makedirs(folder, exist_ok=True)
        self.folder, self.meta, self.records = folder, meta, []
        self._log = open(self.path("log.txt"), "w")

    def path(self, name: str) -> str:
        return os.path.join(self.folder, name)

    def log(self, msg: str = "") -> None:
        print(msg, flush=True)
        self._log.write(msg + "\n")
        self._log.flush()

    def save(self, table=None) -> None:
        """results.json, and table.md from table(records, meta) → markdown when given."""
        write_json(self.path("results.json"), {"meta": self.meta, "records": self.records})
        if table is not None:
            with open(self.path("table.md"), "w") as fh:
                fh.write(table(self.records, self.meta))

    def finish(self, table=None) -> None:
        """The last save, with the load average at the end (other work on the machine shows there)."""
        self.meta["loadavg_end"] = load_average()
        self.save(table)


def write_json(path: str, data) -> None:
    """JSON written whole or not at all (a run cut short never leaves half a file)."""
    tmp = path + ".part"
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=1)
    os.replace(tmp, path)


def markdown_table(header, rows) -> list[str]:
    """Lines of a markdown table."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + \
           ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def save_figure(fig, path: str, dpi: int = 110) -> None:
    """A matplotlib figure written whole or not at all (as write_json), then closed."""
    root, ext = os.path.splitext(path)
    tmp = f"{root}.part{ext}"
    fig.tight_layout()
    fig.savefig(tmp, dpi=dpi)
    os.replace(tmp, path)
    pyplot().close(fig)


def pyplot():
    """matplotlib.pyplot drawing to files only (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
