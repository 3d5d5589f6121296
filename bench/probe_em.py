"""Per-kernel device time of one EM step (warp backend): which of the four kernels dominates.

    python bench/probe_em.py warp:cuda 65536 8
"""

import os
import sys
import time


sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402


def main(backend, facets, j):

    be = wb.get_backend(backend)
    fac = be.sample_facets(heightfield_tile(), facets, 0)
    start = lobes_mod.initial_lobes(fac.normal, fac.area, j)
    for iters in (1, 30):
        be.ndf_em(fac, start.axes, start.sharpness, start.weight, iters)
        be.synchronize()
        t0 = time.perf_counter()
        out = be.ndf_em(fac, start.axes, start.sharpness, start.weight, iters)
        print(f"ndf_em iterations={iters}: {(time.perf_counter() - t0) * 1e3:.2f} ms, steps {out[3]}")
    if not backend.startswith("warp"):
        return

    f = be._facets(fac)
    # The bake's EM program (warp backend), with a step cap it never reaches: every step runs.
    prog = be._em_program(f["normal"], f["area"], j, 1000000, be._resp(fac, j))
    prog["start"].assign(wb.backend.em_start_rows(start))
    prog["load"]()
    steps, state = prog["steps"], prog["state"]
    be.synchronize()
    t0 = time.perf_counter()
    for _ in range(200):
        state.zero_()
    be.synchronize()
    t_zero = (time.perf_counter() - t0) / 200
    names = ["responsibilities", "sums_partial", "sum_chunks 1", "sum_chunks 2", "(holds the scratch arrays)",
             "m_step", "finish"]
    for name, step in zip(names, steps):
        t0 = time.perf_counter()
        for _ in range(200):
            state.zero_()
            step()
        be.synchronize()
        print(f"  {name}: {((time.perf_counter() - t0) / 200 - t_zero) * 1e6:.1f} us (memset {t_zero * 1e6:.1f} us)")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
