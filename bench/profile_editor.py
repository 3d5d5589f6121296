"""Where an editor edit's time goes (issue 23): cProfile of repeated `Editor.set` calls per kind of edit,
the functions sorted by their own time, so that host work (uploads, launches, numpy) and device waits
(synchronisation, read-backs) show apart.

    python -m bench.profile_editor --backends warp:cuda opencl:nvidia --size 1920x1080 --edits 10
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
import warnings

import warp_biscale as wb
from warp_biscale.editor import Editor

warnings.filterwarnings("ignore", category=wb.EnergyWarning)

EDITS = {"geometry": ("tile.height", (0.45, 0.55)), "brdf": ("material0.exponent", (200.0, 300.0)),
         "light": ("light.elevation", (40.0, 50.0))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="+", default=["auto"])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--edits", type=int, default=10)
    ap.add_argument("--kinds", nargs="+", default=list(EDITS))
    ap.add_argument("--top", type=int, default=25)
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    for backend in a.backends:
        be = wb.get_backend(backend)
        ed = Editor("pyramid", backend=be, width=w, height=h)
        for kind in a.kinds:
            name, values = EDITS[kind]
            for v in (values[1], values[0], values[1]):  # warm
                ed.set(name, v)
            walls = []
            prof = cProfile.Profile()
            for i in range(a.edits):
                t0 = time.perf_counter()
                prof.enable()
                ed.set(name, values[i % 2])
                prof.disable()
                walls.append(time.perf_counter() - t0)
            walls.sort()
            parts = {k: round(v * 1e3, 2) for k, v in ed.timings.items() if isinstance(v, float)}
            stages = {k: round(v * 1e3, 2) for k, v in (ed.effective.timings or {}).items()}
            print(f"== {be.name} {kind}: median {walls[len(walls) // 2] * 1e3:.2f} ms; last {parts}; "
                  f"bake stages {stages}")
            s = io.StringIO()
            pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(a.top)
            print("\n".join(line for line in s.getvalue().splitlines()[6:] if line.strip()))


if __name__ == "__main__":
    main()
