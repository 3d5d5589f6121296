"""Host timeline of one warm bake: when each backend call and host step starts and ends (no added
synchronisation, ~1 µs of overhead a call), so that the gaps between them show what the critical path is.

    python -m bench.timeline_bake warp:cuda [--gpu] [--facets N] [--tile pyramid|editor] [--runs 5] [--fresh-tiles]
    python -m bench.timeline_bake warp:cpu --facets 4096 --runs 2          # a smoke test
    python -m bench.timeline_bake warp:cuda --gpu --method asg --tile woven   # issue 20's ASG bake

With --gpu (Warp CUDA only) each call also records a CUDA event on the device's stream before and
after it (no synchronisation; a few µs a call): the timeline then shows, for each call, when the GPU
reached the work queued before it and when it finished what the call queued, so the time the GPU sits
idle waiting for the host is visible ("GPU idle before"). It then lists each kernel, copy and graph of
one more bake with its device time (Warp's activity timing, `wp.timing_begin`).

The timeline wraps what the bake calls in place (the backend's methods, the lobe functions of
`warp_biscale.lobes`, and two names inside `warp_biscale.bake`): it instruments the library's inner
steps on purpose, so it follows them when they are renamed; bench_bake.py's figures need none of it.

With --fresh-tiles every bake gets a tile object of its own (the editor's geometry edit: the height of the
editor's pyramid, or the family's default height, alternated), built before the timed bake, so the tile's
device copies and its BVH (`_tile`) are made within the bake as they are after an edit.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import itertools
import os
import sys
import time

import numpy as np

import warp_biscale as wb
from warp_biscale import lobes as lobes_mod

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

bake_module = importlib.import_module("warp_biscale.bake")  # (`wb.bake` is the function of the same name)
EVENTS = []
GPU = {"device": None}  # the Warp CUDA device when GPU events are recorded

# What a bake calls on its backend: each is traced where the backend has it.
BACKEND_CALLS = ("_tile", "sample_facets", "normal_bins", "facet_weight_by_face", "visibility", "visible_area",
                 "visible_weights", "em_start", "ndf_em", "lobe_moments", "solve_amplitudes", "material_tables",
                 "synchronize", "asg_em", "asg_value_sums")
# The host steps between them. `_channel_faces` is private: it splits the facet weights per material and colour
# (a value a face, which facet_weight_by_face makes the facets' weights on the device), host work before the rays
# that the timeline must show.
LOBE_STEPS = ("initial_lobes", "amplitude_system")
BAKE_STEPS = ("_channel_faces", "_occupied_bins", "_bin_normals", "_fit_ndf", "EffectiveBRDF")
# The ASG bake's host steps (method "asg").
ASG_STEPS = ("amplitude_system", "calibrated_rows", "fit_asg_on")


def _mark():
    if GPU["device"] is None:
        return None
    import warp as wp

    return wp.get_stream(GPU["device"]).record_event(wp.Event(GPU["device"], enable_timing=True))


def traced(owner, name, label=None):
    fn = getattr(owner, name)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        e0 = _mark()
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            t1 = time.perf_counter()
            EVENTS.append((label or name, t0, t1, e0, _mark()))

    setattr(owner, name, wrapper)


def main(backend, facets=1 << 16, runs=5, gpu=False, tile="heightfield", fresh_tiles=False, method="sg"):
    be = wb.get_backend(backend)
    if gpu:
        if not be.name.startswith("warp:cuda"):
            raise SystemExit(f"--gpu needs a Warp CUDA backend, not {be.name}")
        import warp as wp

        GPU["device"] = wp.get_device(be.name.split(":", 1)[1])  # "warp:cuda:0" → Warp's "cuda:0"
    for name in BACKEND_CALLS:
        if hasattr(be, name):
            traced(be, name)
    for name in LOBE_STEPS:
        traced(lobes_mod, name)
    for name in BAKE_STEPS:
        if hasattr(bake_module, name):
            traced(bake_module, name)
    if method == "asg":
        asg_bake = importlib.import_module("warp_biscale.asg_bake")
        for name in ASG_STEPS:
            traced(asg_bake, name, f"asg.{name}")
        traced(asg_bake.ASGBRDF, "__init__", "ASGBRDF")  # (the class itself stays a class: isinstance checks)
    materials = wb.BlinnPhong(1.0, 512)
    family = tile
    if family == "editor":  # the editor's first design: a pyramid and its ground, two materials and colours
        def make(height=0.5):
            return wb.geometry.pyramid(height=height, material=0, base_material=1, color=(1.0, 0.75, 0.3),
                                       base_color=(0.55, 0.1, 0.07))
        materials = [materials, wb.BlinnPhong(0.3, 64, kd=0.5)]
    elif family == "heightfield":
        def make(height=None):
            return common.heightfield_tile()
    else:
        def make(height=None):
            return getattr(wb.geometry, family)() if height is None else getattr(wb.geometry, family)(height=height)
    tile = make()
    if not isinstance(materials, list):
        materials = [materials] * tile.n_materials
    kw = dict(tile=tile, materials=materials, lobes=8, directions=12, normal_res=128, facets=facets, backend=be,
              method=method)
    heights = itertools.cycle((0.45, 0.55) if family in ("editor", "pyramid") else (None,))
    # A seed of its own for each bake: the bake keeps what depends on the geometry per seed, and a second
    # bake of one seed would redo the tables alone.
    seeds = itertools.count()
    wb.bake(seed=next(seeds), **kw)
    rows = []
    for _ in range(runs):
        seed = next(seeds)
        if fresh_tiles:
            kw["tile"] = make(next(heights))
        EVENTS.clear()
        be.synchronize()
        start = _mark()
        t0 = time.perf_counter()
        wb.bake(seed=seed, **kw)
        be.synchronize()
        total = time.perf_counter() - t0
        rows.append((total, [(n, a - t0, b - t0, _gpu_ms(start, e0), _gpu_ms(start, e1))
                             for n, a, b, e0, e1 in EVENTS]))
    total, events = sorted(rows, key=lambda r: r[0])[len(rows) // 2]
    print(f"{be.name}: median whole bake {total * 1e3:.2f} ms (of {[round(r[0] * 1e3, 1) for r in rows]}), "
          f"commit {common.git_commit()}")
    last = 0.0
    gpu_last = 0.0
    for name, a, b, g0, g1 in sorted(events, key=lambda e: e[1]):
        gap = a - last
        line = f"  {a * 1e3:7.2f} → {b * 1e3:7.2f} ms  {(b - a) * 1e3:6.2f} ms  {name:18s}"
        if g0 is not None:  # the GPU: reached the call's first work at g0 (or was there), done at g1
            line += f"  GPU {g0:7.2f} → {g1:7.2f} ms"
            if g0 - gpu_last > 0.01:
                line += f" (GPU idle before: {g0 - gpu_last:.2f} ms)"
            gpu_last = max(gpu_last, g1)
        print(line + (f"   (gap before: {gap * 1e3:.2f} ms)" if gap > 1e-4 else ""))
        last = max(last, b)
    print(f"  end {total * 1e3:.2f} ms (after the last call: {(total - last) * 1e3:.2f} ms)")
    if gpu:
        _device_activities(dict(kw, seed=next(seeds)))
    return float(np.median([r[0] for r in rows]))


def _device_activities(kw):
    """Device time of each kernel, copy and graph of one warm bake."""
    import warp as wp

    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    wb.bake(**kw)
    results = wp.timing_end()
    total = sum(r.elapsed for r in results)
    print(f"device activities of one bake: {len(results)}, {total:.2f} ms of device time")
    for r in results:
        print(f"  {r.elapsed:7.3f} ms  {r.name}")


def _gpu_ms(start, event):
    """ms from the `start` event to `event` on the GPU (None without GPU events)."""
    if event is None:
        return None
    import warp as wp

    return wp.get_event_elapsed_time(start, event, synchronize=False)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("backend")
    ap.add_argument("--gpu", action="store_true", help="CUDA events per call and device activities (Warp CUDA)")
    ap.add_argument("--facets", type=int, default=1 << 16)
    ap.add_argument("--tile", default="heightfield",
                    help="heightfield (the targets' tile), editor (the editor's first design) or a geometry family")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--fresh-tiles", action="store_true", help="a new tile object for every bake (an edit)")
    ap.add_argument("--method", default="sg", choices=("sg", "asg"))
    a = ap.parse_args()
    main(a.backend, facets=a.facets, runs=a.runs, gpu=a.gpu, tile=a.tile, fresh_tiles=a.fresh_tiles, method=a.method)
