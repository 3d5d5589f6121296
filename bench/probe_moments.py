"""Lobe-moment kernel time with facet runs (model.run_ends: one popcount per run and word) against runs
of one facet (weights made all different), on the bench's tiles.

    python bench/probe_moments.py warp:cuda 65536
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import directions as dirs  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402
from warp_biscale.model import run_ends  # noqa: E402


def main(backend, facets):
    be = wb.get_backend(backend)
    grid = dirs.grid(12)
    iu, ou = (a.astype(np.int32) for a in np.triu_indices(len(grid)))
    for tile in (heightfield_tile(), wb.geometry.pyramid(), wb.geometry.woven()):
        fac = be.sample_facets(tile, facets, 0)
        vis = be.visibility(tile, fac, grid)
        lob = lobes_mod.initial_lobes(fac.normal, fac.area, 8)
        runs = fac.area.astype(np.float32)
        single = runs * (1 + 1e-6 * np.arange(len(runs), dtype=np.float32))  # every weight differs
        for name, w in (("runs", runs), ("runs of one", single)):
            ends = run_ends(fac.normal, w)
            be.lobe_moments(fac, vis, w, lob.axes, lob.sharpness, iu, ou)
            be.synchronize()
            ts = []
            for _ in range(7):
                t0 = time.perf_counter()
                be.lobe_moments(fac, vis, w, lob.axes, lob.sharpness, iu, ou)
                be.synchronize()
                ts.append(time.perf_counter() - t0)
            print(f"{tile.name[:24]:24s} {name:12s} mean run {len(ends) / len(np.unique(ends)):7.1f} facets: "
                  f"{np.median(ts) * 1e3:7.2f} ms", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1 << 16)
