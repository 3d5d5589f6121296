"""Where a frame's time goes: each render stage alone in a loop (device-synchronised at the end), and the
kernels' own device time from Warp's CUDA activity timer. Usage: python bench/probe_render.py BACKEND [W H]."""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import warp_biscale as wb  # noqa: E402
from bench_render import target_scene  # noqa: E402
from warp_biscale.render import _static_inputs  # noqa: E402


def loop(fn, be, n=50):
    fn()
    be.synchronize()
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    be.synchronize()
    return (time.perf_counter() - t0) / n * 1e3


def main():
    name = sys.argv[1]
    w, h = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (1920, 1080)
    be = wb.get_backend(name)
    scene = target_scene(w, h, backend=name)
    static = _static_inputs(scene, be, None, {})
    lights = scene.lights_packed
    cam = scene.camera.packed()
    be.trace_primary(scene.mesh, scene.camera, to_host=False)
    be.trace_shadows(scene.mesh, None, lights, to_host=False)
    stages = {
        "trace_primary": lambda: be.trace_primary(scene.mesh, scene.camera, to_host=False),
        "trace_shadows": lambda: be.trace_shadows(scene.mesh, None, lights, to_host=False),
        "shade": lambda: be.shade(scene.mesh, static, cam, lights, to_host=False),
    }
    for k, fn in stages.items():
        print(f"{name} {w}x{h} {k:<14} {loop(fn, be):8.3f} ms/call (loop, synchronised at the end)")
    if name.startswith("warp:cuda"):
        import warp as wp

        for k, fn in stages.items():
            with wp.ScopedTimer(k, print=False, cuda_filter=wp.TIMING_KERNEL, synchronize=True) as t:
                for _ in range(10):
                    fn()
            kern = {}
            for r in t.timing_results:
                kern[r.name] = kern.get(r.name, 0.0) + r.elapsed / 10
            print(f"{name} {k:<14} device kernels: " + ", ".join(f"{a} {b:.3f} ms" for a, b in kern.items()))
        host = []
        for _ in range(20):
            t0 = time.perf_counter()
            be.shade(scene.mesh, static, cam, lights, to_host=False)
            host.append((time.perf_counter() - t0) * 1e3)
        print(f"{name} shade host-side call time (no sync): median {np.median(host):.3f} ms")


if __name__ == "__main__":
    main()
