"""A/B of the shade stage (README.txt): on one backend, device-synchronised medians (ms) of the editor's shade
of its design's pixels and of its whole frame (1920x1080, pyramid, 2 materials, J = 8, K = 12), the
editor's BRDF edit (Editor.set, alternating two exponents), and the shade of bench_render's target scene's
frame (1920x1080). Run from the repository root: python3 abshade.py BACKEND LABEL."""

import os
import sys
import time
import warnings

sys.path.append(os.getcwd())
warnings.filterwarnings("ignore")
import warp_biscale as wb  # noqa: E402
from warp_biscale.editor import Editor  # noqa: E402
from warp_biscale.render import pack_frame, static_inputs  # noqa: E402
from bench.bench_render import target_scene  # noqa: E402


def med(f, be, n=30, sync=True):
    f()
    ts = []
    for _ in range(n):
        if sync:
            be.synchronize()
        t = time.perf_counter()
        f()
        if sync:
            be.synchronize()
        ts.append(time.perf_counter() - t)
    return round(sorted(ts)[n // 2] * 1e3, 3)


be = wb.get_backend(sys.argv[1])
ed = Editor("pyramid", backend=be, width=1920, height=1080)
es = ed.scene
st = static_inputs(es, be)
ts = target_scene(1920, 1080, backend=be)
wb.render(ts, backend=be)
t_inputs = pack_frame(ts, be).inputs
r = {}
values = iter([200.0, 300.0] * 100)
r["brdf edit"] = med(lambda: ed.set("material0.exponent", next(values)), be, sync=False)
r["editor design"] = med(lambda: be.shade(es.mesh, st, es.camera.packed(), es.lights_packed, to_host=False,
                                          only_material=0), be)
r["editor frame"] = med(lambda: be.shade(es.mesh, st, es.camera.packed(), es.lights_packed, to_host=False), be)
wb.render(ts, backend=be)
r["target frame"] = med(lambda: be.shade(ts.mesh, t_inputs, ts.camera.packed(), ts.lights_packed, to_host=False), be)
print(sys.argv[2], be.name, r, flush=True)
