"""Latency of the bake's NDF fit on one device, piece by piece (one call at a time, synchronised).

    python bench/probe_ndf_fit.py warp:cuda 65536 8
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402


def latency(fn, sync, runs=15):
    fn()
    sync()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return f"{np.median(times) * 1e3:.3f} ms (min {np.min(times) * 1e3:.3f})"


def main(backend, facets, j):
    be = wb.get_backend(backend)
    tile = heightfield_tile()
    fac = be.sample_facets(tile, facets, 0)
    vis = be.visibility(tile, fac, wb.directions.grid(12))
    weight = be.visible_weights(fac, vis)
    start = lobes_mod.initial_lobes(fac.normal, weight, j)
    sync = be.synchronize
    print("visible_weights:", latency(lambda: be.visible_weights(fac, vis), sync))
    print("initial_lobes (facet normals, host):", latency(lambda: lobes_mod.initial_lobes(fac.normal, weight, j), sync))
    for cap in (1, 30):
        print(f"ndf_em cap {cap}, weighted:",
              latency(lambda: be.ndf_em(fac, start.axes, start.sharpness, start.weight, cap, weight), sync))
    print("ndf_em cap 30, area:", latency(lambda: be.ndf_em(fac, start.axes, start.sharpness, start.weight, 30), sync))
    steps = be.ndf_em(fac, start.axes, start.sharpness, start.weight, 30, weight)[3]
    print(f"(steps taken: {steps})")
    if hasattr(be, "_em_graphs") and be._em_graphs:
        import warp as wp

        graph = next(reversed(be._em_graphs.values()))
        print("graph replay alone:", latency(lambda: wp.capture_launch(graph["graph"]), sync))
        prog = graph["prog"]
        print("result read-back alone:", latency(lambda: prog["result"].numpy(), sync))
        rows = wb.backend.em_start_rows(start)
        print("start upload alone:", latency(lambda: prog["start"].assign(rows), sync))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
