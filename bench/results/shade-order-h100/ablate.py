"""Shade-kernel ablation on NVIDIA OpenCL: cl/shade.cl with one function short-circuited per variant, the
shade stage timed (device-synchronised medians) over the editor's frame (design pixels only, and whole) and
the render target scene's frame. Not a test of correctness: a map of where the shade's time goes.
Run from the repository root: python3 ablate.py BACKEND WIDTH HEIGHT [VARIANT ...]. (Lines rewrapped for the
linter after the run.)"""
import os
import re
import sys
import time
import warnings

sys.path.append(os.getcwd())
warnings.filterwarnings("ignore")
import warp_biscale as wb  # noqa: E402
from warp_biscale import opencl_backend as ob  # noqa: E402
from warp_biscale.editor import Editor  # noqa: E402
from warp_biscale.render import static_inputs  # noqa: E402
from bench.bench_render import target_scene  # noqa: E402
from warp_biscale.render import pack_frame  # noqa: E402

ORIG = ob.program_source
VARIANTS = {
    "base": {},
    "ssdf": {"ssdf_theta": "return 3.0f;"},
    "rays": {"ray_share": "return 1.0f;"},
    "envshare": {"environment_share": "return 1.0f;"},
    "tables": {"table_rgb": "return (float3)(0.1f, 0.1f, 0.1f);"},
    "ediffuse": {"effective_diffuse": "return (float3)(0.1f, 0.1f, 0.1f);"},
    "prefiltered": {"prefiltered": "return (float3)(1.0f, 1.0f, 1.0f);"},
    "cosint": {"cosine_integral": "return 1.0f;"},
}


def patched(edits):
    def source(stem):
        text = ORIG(stem)
        if stem != "shade":
            return text
        for name, body in edits.items():
            i = re.search(rf"CL_INLINE\s+\w+\s+{name}\(", text).start()
            j = text.index("{", i)
            text = text[:j + 1] + body + text[j + 1:]
        return text
    return source


def med(f, be, n=20):
    f()
    ts = []
    for _ in range(n):
        be.synchronize()
        t = time.perf_counter()
        f()
        be.synchronize()
        ts.append(time.perf_counter() - t)
    return round(sorted(ts)[n // 2] * 1e3, 3)


be = wb.get_backend(sys.argv[1])
W, H = int(sys.argv[2]), int(sys.argv[3])
ONLY = sys.argv[4:] or list(VARIANTS)
ed = Editor("pyramid", backend=be, width=W, height=H)
es = ed.scene
e_static = static_inputs(es, be)
ts = target_scene(W, H, backend=be)
wb.render(ts, backend=be)
t_inputs = pack_frame(ts, be).inputs
for name in ONLY:
    edits = VARIANTS[name]
    ob.program_source = patched(edits)
    be._programs.pop("shade", None)
    for key in [k for k in be._kernels if k[0] == "shade"]:
        be._kernels.pop(key)
    r = {}
    ed.set("material0.exponent", 250.0)  # the editor's frame and G-buffer on the device
    r["editor design"] = med(lambda: be.shade(es.mesh, e_static, es.camera.packed(), es.lights_packed, to_host=False,
                                              only_material=0), be)
    r["editor frame"] = med(lambda: be.shade(es.mesh, e_static, es.camera.packed(), es.lights_packed,
                                             to_host=False), be)
    wb.render(ts, backend=be)
    r["target frame"] = med(lambda: be.shade(ts.mesh, t_inputs, ts.camera.packed(), ts.lights_packed,
                                             to_host=False), be)
    print(name, r, flush=True)
