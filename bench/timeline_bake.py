"""Host timeline of one warm 2^16-facet bake: when each backend call and host step starts and ends
(no added synchronisation, ~1 µs of overhead a call), so the gaps between them are visible.

    python bench/timeline_bake.py warp:cuda [--gpu] [--facets N] [--tile pyramid] [--runs 5]

With --gpu (Warp CUDA only) each call also records a CUDA event on the device's stream before and
after it (no synchronisation; a few µs a call): the timeline then shows, for each call, when the GPU
reached the work queued before it and when it finished what the call queued, so the time the GPU sits
idle waiting for the host is visible ("GPU idle before"). It then lists each kernel, copy and graph of
one more bake with its device time (Warp's activity timing, `wp.timing_begin`).
"""

import functools
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402

bake_module = sys.modules["warp_biscale.bake"]
EVENTS = []
GPU = {"device": None}  # the Warp CUDA device when GPU events are recorded


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


def main(backend, facets=1 << 16, runs=5, gpu=False, tile="heightfield"):
    be = wb.get_backend(backend)
    if gpu:
        GPU["device"] = be._device  # (Warp CUDA: the backend's device)
    for name in ("sample_facets", "normal_bins", "visibility", "visible_area", "visible_weights", "ndf_em",
                 "lobe_moments", "solve_amplitudes", "amplitude_tables", "synchronize", "em_start"):
        if hasattr(be, name):  # (em_start: since the EM's start is picked on the device)
            traced(be, name)
    for name in ("initial_lobes", "amplitude_system"):
        traced(lobes_mod, name)
    traced(bake_module, "_channels")
    traced(bake_module, "EffectiveBRDF")
    tile = heightfield_tile() if tile == "heightfield" else getattr(wb.geometry, tile)()
    kw = dict(tile=tile, materials=wb.BlinnPhong(1.0, 512), lobes=8, directions=12, normal_res=128,
              facets=facets, backend=be)
    wb.bake(**kw)
    rows = []
    for _ in range(runs):
        bake_module._GEOMETRY.clear()
        EVENTS.clear()
        be.synchronize()
        start = _mark()
        t0 = time.perf_counter()
        wb.bake(**kw)
        be.synchronize()
        total = time.perf_counter() - t0
        rows.append((total, [(n, a - t0, b - t0, _gpu_ms(start, e0), _gpu_ms(start, e1))
                             for n, a, b, e0, e1 in EVENTS]))
    total, events = sorted(rows, key=lambda r: r[0])[len(rows) // 2]
    print(f"{backend}: median whole bake {total * 1e3:.2f} ms (of {[round(r[0] * 1e3, 1) for r in rows]})")
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
        _device_activities(kw)
    return np.median([r[0] for r in rows])


def _device_activities(kw):
    """Device time of each kernel, copy and graph of one warm bake."""
    import warp as wp

    bake_module._GEOMETRY.clear()
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
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("backend")
    ap.add_argument("--gpu", action="store_true", help="CUDA events per call and device activities (Warp CUDA)")
    ap.add_argument("--facets", type=int, default=1 << 16)
    ap.add_argument("--tile", default="heightfield", help="heightfield (the targets' tile) or a geometry family")
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    main(a.backend, facets=a.facets, runs=a.runs, gpu=a.gpu, tile=a.tile)
