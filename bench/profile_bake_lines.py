"""Line-level host time of one warm 2^16-facet bake (needs `line_profiler`): where the time between
the device stages goes.

    python bench/profile_bake_lines.py warp:cuda [MIN_MS [RUNS]]

Lines of at least MIN_MS (default 0.2) per bake, averaged over RUNS bakes (default 1).
"""

import os
import sys

from line_profiler import LineProfiler

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_foundation import heightfield_tile  # noqa: E402
from warp_biscale import lobes as lobes_mod  # noqa: E402

bake_module = sys.modules["warp_biscale.bake"]


def main(backend, min_ms=0.2, runs=1, facets=1 << 16):
    be = wb.get_backend(backend)
    kw = dict(tile=heightfield_tile(), materials=wb.BlinnPhong(1.0, 512), lobes=8, directions=12, normal_res=128,
              facets=facets, backend=be)
    wb.bake(**kw)
    bake_module._GEOMETRY.clear()
    wb.bake(**kw)
    bake_module._GEOMETRY.clear()
    prof = LineProfiler(bake_module._bake_geometry, bake_module.bake, bake_module._fit_lobes, lobes_mod.fit,
                        lobes_mod.initial_lobes, lobes_mod.amplitude_system, be.sample_facets, be.visibility,
                        be.visible_area, be.visible_weights, be.normal_bins, be.ndf_em, be.lobe_moments,
                        be.solve_amplitudes, be.amplitude_tables, lobes_mod.from_em, wb.EffectiveBRDF.__init__,
                        *[getattr(be, name) for name in ("_read_later", "_launch") if hasattr(be, name)])
    for _ in range(runs):
        prof.runcall(wb.bake, **kw)
        be.synchronize()
        bake_module._GEOMETRY.clear()
    stats = prof.get_stats()
    for (fn, line0, name), timings in sorted(stats.timings.items(), key=lambda kv: kv[0][1]):
        total = sum(t for _, _, t in timings) * stats.unit * 1e3 / runs
        print(f"== {name} ({os.path.basename(fn)}:{line0}) {total:.2f} ms")
        lines = open(fn).read().splitlines()
        for lineno, _hits, t in timings:
            ms = t * stats.unit * 1e3 / runs
            if ms >= min_ms:
                print(f"  {lineno:5d} {ms:8.2f} ms  {lines[lineno - 1].strip()[:100]}")


if __name__ == "__main__":
    main(sys.argv[1], *(float(a) for a in sys.argv[2:3]), *(int(a) for a in sys.argv[3:4]))
