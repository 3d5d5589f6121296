"""Host timeline of one warm 2^16-facet bake: when each backend call and host step starts and ends
(no added synchronisation, ~1 µs of overhead a call), so the gaps between them are visible.

    python bench/timeline_bake.py warp:cuda
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


def traced(owner, name, label=None):
    fn = getattr(owner, name)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            EVENTS.append((label or name, t0, time.perf_counter()))

    setattr(owner, name, wrapper)


def main(backend, facets=1 << 16, runs=5):
    be = wb.get_backend(backend)
    for name in ("sample_facets", "normal_bins", "visibility", "visible_area", "visible_weights", "ndf_em",
                 "lobe_moments", "solve_amplitudes", "amplitude_tables", "synchronize"):
        traced(be, name)
    for name in ("initial_lobes", "amplitude_system"):
        traced(lobes_mod, name)
    traced(bake_module, "_channels")
    traced(bake_module, "EffectiveBRDF")
    kw = dict(tile=heightfield_tile(), materials=wb.BlinnPhong(1.0, 512), lobes=8, directions=12, normal_res=128,
              facets=facets, backend=be)
    wb.bake(**kw)
    rows = []
    for _ in range(runs):
        bake_module._GEOMETRY.clear()
        EVENTS.clear()
        t0 = time.perf_counter()
        wb.bake(**kw)
        be.synchronize()
        total = time.perf_counter() - t0
        rows.append((total, [(n, a - t0, b - t0) for n, a, b in EVENTS]))
    total, events = sorted(rows, key=lambda r: r[0])[len(rows) // 2]
    print(f"{backend}: median whole bake {total * 1e3:.2f} ms (of {[round(r[0] * 1e3, 1) for r in rows]})")
    last = 0.0
    for name, a, b in sorted(events, key=lambda e: e[1]):
        gap = a - last
        print(f"  {a * 1e3:7.2f} → {b * 1e3:7.2f} ms  {(b - a) * 1e3:6.2f} ms  {name}"
              + (f"   (gap before: {gap * 1e3:.2f} ms)" if gap > 1e-4 else ""))
        last = max(last, b)
    print(f"  end {total * 1e3:.2f} ms (after the last call: {(total - last) * 1e3:.2f} ms)")
    return np.median([r[0] for r in rows])


if __name__ == "__main__":
    main(sys.argv[1])
