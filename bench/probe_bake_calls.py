"""Host time of each Warp call a warm 2^16-facet bake makes (wp.launch per kernel, wp.copy, wp.empty,
array.numpy, array.assign, wp.capture_launch), medians over bakes: what the backend's calls cost
beyond Python's own work.

    python bench/probe_bake_calls.py [warp:cuda] [BAKES]
"""

import collections
import functools
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp as wp  # noqa: E402

import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402

bake_module = sys.modules["warp_biscale.bake"]
CALLS = []


def timed(owner, name, label):
    fn = getattr(owner, name)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            key = label(args) if callable(label) else label
            CALLS.append((key, time.perf_counter() - t0))

    setattr(owner, name, wrapper)


def main(backend="warp:cuda", bakes=7):
    be = wb.get_backend(backend)
    timed(wp, "launch", lambda a: f"launch {a[0].key}")
    timed(wp, "copy", "wp.copy")
    timed(wp, "empty", "wp.empty")
    timed(wp, "capture_launch", "wp.capture_launch")
    timed(wp.array, "numpy", "array.numpy")
    timed(wp.array, "assign", "array.assign")
    kw = dict(tile=heightfield_tile(), materials=wb.BlinnPhong(1.0, 512), lobes=8, directions=12, normal_res=128,
              facets=1 << 16, backend=be)
    wb.bake(**kw)
    per_bake = []
    totals = []
    for _ in range(bakes):
        bake_module._GEOMETRY.clear()
        CALLS.clear()
        be.synchronize()
        t0 = time.perf_counter()
        wb.bake(**kw)
        be.synchronize()
        totals.append(time.perf_counter() - t0)
        sums = collections.defaultdict(lambda: [0, 0.0])
        for key, t in CALLS:
            sums[key][0] += 1
            sums[key][1] += t
        per_bake.append(sums)
    keys = sorted({k for s in per_bake for k in s}, key=lambda k: -np.median([s[k][1] for s in per_bake if k in s]))
    print(f"{backend}: whole bake median {np.median(totals) * 1e3:.2f} ms; host ms a bake in each Warp call (median):")
    total = 0.0
    for k in keys:
        ms = float(np.median([s[k][1] for s in per_bake if k in s])) * 1e3
        n = per_bake[-1][k][0] if k in per_bake[-1] else 0
        total += ms
        print(f"  {ms:7.3f} ms  {n:3d}×  {k}")
    print(f"  {total:7.3f} ms  in all")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "warp:cuda", int(sys.argv[2]) if len(sys.argv) > 2 else 7)
