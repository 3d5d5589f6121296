"""Can the host bin the normals while the rays trace? One warm 2^16-facet visibility on Warp CUDA,
with the normal bins (a 13 µs kernel and two read-backs) queued behind it on the same stream, or on
a stream of their own (default or high priority) while the rays run on another.

    python bench/probe_streams.py

Prints, per layout, the median over 9 tries of: when the bins were on the host (after the rays were
queued), and when the rays were done.
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp as wp  # noqa: E402

import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import directions as dirs  # noqa: E402


def main(tries=9):
    be = wb.get_backend("warp:cuda")
    dev = be._device
    tile = heightfield_tile()
    grid = dirs.frozen_grid(12)
    default = wp.get_stream(dev)
    rays = wp.Stream(dev)
    high = wp.Stream(dev, priority=-1)
    layouts = {"one stream": (None, None), "rays on their own stream": (rays, None),
               "rays on their own stream, bins on a high-priority one": (rays, high)}
    for name, (ray_stream, bin_stream) in layouts.items():
        rows = []
        for _ in range(tries + 1):
            fac = be.sample_facets(tile, 1 << 16, 0)
            be.synchronize()
            t0 = time.perf_counter()
            if ray_stream is None:
                vis = be.visibility(tile, fac, grid)
            else:
                ray_stream.wait_stream(default)
                with wp.ScopedStream(ray_stream, sync_enter=False, sync_exit=False):
                    vis = be.visibility(tile, fac, grid)
                done = ray_stream.record_event()
            t1 = time.perf_counter()
            if bin_stream is None:
                bins = be.normal_bins(fac, 128)
                normal = fac.normal
            else:
                bin_stream.wait_stream(default)
                with wp.ScopedStream(bin_stream, sync_enter=False, sync_exit=False):
                    bins = be.normal_bins(fac, 128)
                    normal = fac.normal
            t2 = time.perf_counter()
            if ray_stream is not None:
                default.wait_event(done)
            be.synchronize()
            t3 = time.perf_counter()
            rows.append((t1 - t0, t2 - t0, t3 - t0))
            assert len(bins) == len(normal) == len(fac) and vis.words
        med = np.median(np.array(rows[1:]), axis=0) * 1e3
        print(f"{name:55s} rays queued {med[0]:.2f} ms, bins on the host {med[1]:.2f} ms, rays done {med[2]:.2f} ms")


if __name__ == "__main__":
    main()
