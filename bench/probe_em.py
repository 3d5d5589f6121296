"""Per-kernel device time of one EM step (warp backend): which of the four kernels dominates.

    python bench/probe_em.py warp:cuda 65536 8
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402


def main(backend, facets, j):
    import warp as wp

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
    from warp_biscale.kernels import em as ke

    dev = be._device
    state = wp.zeros(2, dtype=wp.int32, device=dev)
    moved = wp.zeros(j, dtype=wp.int32, device=dev)
    a32 = be._array(start.axes.astype(np.float32), wp.vec3)
    s32 = be._array(start.sharpness.astype(np.float32), wp.float32)
    l32 = be._array(start.log_weight.astype(np.float32), wp.float32)
    a64, s64, w64 = (be._array(start.axes, wp.vec3d), be._array(start.sharpness, wp.float64),
                     be._array(start.weight, wp.float64))
    f = be._facets(fac)
    steps, stats = be._em_launches(f["normal"], f["area"], j, a32, s32, l32, state, be._resp(fac, j))  # warp only
    steps.append(be._recorded(ke.em_m_step, j, [stats, state, a64, s64, w64], [a32, s32, l32, moved], split=False))
    steps.append(be._recorded(ke.em_finish, 1, [moved, 1000000], [state], split=False))
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
