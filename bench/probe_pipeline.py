"""What a device round trip, the visibility kernel and a captured EM cost on one GPU (warp backend).

    python bench/probe_pipeline.py warp:cuda 65536 8

Prints: a small read-back and a small upload on an idle queue; the visibility rays kernel alone;
30 EM steps queued from Python and the same steps replayed as one captured CUDA graph.
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402


def per_call(fn, runs=100, sync=None):
    fn()
    if sync:
        sync()
    t0 = time.perf_counter()
    for _ in range(runs):
        fn()
    if sync:
        sync()
    return (time.perf_counter() - t0) / runs * 1e3


def main(backend, facets, j):
    import warp as wp


    be = wb.get_backend(backend)
    dev = be._device
    tile = heightfield_tile()
    small = wp.zeros(8, dtype=wp.int32, device=dev)
    host8 = np.zeros(8, np.int32)
    print(f"small read-back (idle queue): {per_call(small.numpy):.3f} ms")
    print(f"small upload wp.array: {per_call(lambda: wp.array(host8, dtype=wp.int32, device=dev)):.3f} ms")
    print(f"small assign_ (host->device copy): {per_call(lambda: small.assign(host8)):.3f} ms")
    fac = be.sample_facets(tile, facets, 0)
    be.synchronize()
    print(f"sample_facets (stage): {per_call(lambda: be.sample_facets(tile, facets, 0), 20, be.synchronize):.3f} ms")
    grid = wb.directions.grid(12)
    be.visibility(tile, fac, grid)
    print(f"visibility (stage): {per_call(lambda: be.visibility(tile, fac, grid), 20, be.synchronize):.3f} ms")
    start = lobes_mod.initial_lobes(fac.normal, fac.area, j)

    f = be._facets(fac)
    # The bake's EM program (warp backend), with a step cap it never reaches: every step runs.
    prog = be._em_program(f["normal"], f["area"], j, 1000000, be._resp(fac, j))
    prog["start"].assign(wb.backend.em_start_rows(start))
    prog["load"]()
    steps, state = prog["steps"], prog["state"]

    def thirty():
        state.zero_()
        for _ in range(30):
            for step in steps:
                step()

    print(f"30 EM steps queued (never converging), host+device: {per_call(thirty, 10, be.synchronize):.3f} ms")
    if not be._device.is_cuda:
        return
    t0 = time.perf_counter()
    with wp.ScopedCapture(device=dev, force_module_load=False) as capture:
        thirty()
    print(f"capture of those 30 steps: {(time.perf_counter() - t0) * 1e3:.3f} ms")
    print(f"graph replays back to back (throughput, not latency): "
          f"{per_call(lambda: wp.capture_launch(capture.graph), 20, be.synchronize):.3f} ms")
    replay_read = per_call(lambda: (wp.capture_launch(capture.graph), state.numpy()), 20)
    print(f"graph replay + read state: {replay_read:.3f} ms")
    print(f"ndf_em (as the bake runs it): "
          f"{per_call(lambda: be.ndf_em(fac, start.axes, start.sharpness, start.weight, 30), 10):.3f} ms")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
