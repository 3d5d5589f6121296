"""Where the time of one whole bake goes (host Python vs device stages): cProfile of a warm bake.

    python bench/profile_bake.py warp:cuda 65536
"""

import cProfile
import os
import pstats
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402

bake_module = sys.modules["warp_biscale.bake"]


def main(backend, facets, top=30):
    tile = heightfield_tile()
    be = wb.get_backend(backend)
    kw = dict(tile=tile, materials=wb.BlinnPhong(1.0, 512), lobes=8, directions=12, normal_res=128,
              facets=facets, backend=be)
    wb.bake(**kw)
    totals = []
    for _ in range(5):
        bake_module._GEOMETRY.clear()
        t0 = time.perf_counter()
        mat = wb.bake(**kw)
        be.synchronize()
        totals.append(time.perf_counter() - t0)
    print(f"{backend} {facets} facets: whole bake median {np.median(totals) * 1e3:.1f} ms, stages (ms):",
          {k: round(v * 1e3, 2) for k, v in mat.timings.items()}, f"sum {sum(mat.timings.values()) * 1e3:.1f}")
    bake_module._GEOMETRY.clear()
    prof = cProfile.Profile()
    prof.enable()
    wb.bake(**kw)
    be.synchronize()
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(top)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1 << 16)
