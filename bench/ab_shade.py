"""A/B of two library trees' shade stage alone, in one sitting: the render target scene (`ab_trees.target_scene`)
at W × H, packed once (G-buffer, rays, left on the device), then `backend.shade` of the device's G-buffer N times, the
image left on the device (after one warm-up call; the kernel's time, not the transfers'); one JSON line a run:
label, backend, size, the median and fastest call, and the image's mean radiance (which tells the trees apart
where they are meant to render differently). A sixth argument sets the occlusion rays a pixel (default the
renderer's). Alternate the trees, each in its own process:

    PYTHONPATH=<tree A's install> python -P bench/ab_shade.py A opencl 512 512 15 >> $OUT/ab.jsonl
    PYTHONPATH=<tree B's install> python -P bench/ab_shade.py B opencl 512 512 15 >> $OUT/ab.jsonl   # and again
"""

import json
import os
import sys
import time
import warnings

import numpy as np

import warp_biscale as wb
from warp_biscale.render import OCCLUSION_SAMPLES, pack_frame

try:
    from bench.ab_trees import target_scene
except ImportError:  # run as a file (with -P, its folder is not on the path)
    sys.path.append(os.path.dirname(os.path.abspath(__file__)))
    from ab_trees import target_scene


def main():
    label, name, w, h, n = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
    occlusion = int(sys.argv[6]) if len(sys.argv) > 6 else OCCLUSION_SAMPLES  # occlusion rays a pixel
    warnings.simplefilter("ignore", wb.EnergyWarning)
    backend = wb.get_backend(name)
    scene = target_scene(backend)
    scene.camera.width, scene.camera.height = w, h
    # (its G-buffer and rays also stay on the device, where the shade reads them)
    frame = pack_frame(scene, backend, occlusion_samples=occlusion)
    seconds = []
    for _ in range(n + 1):  # the shade kernel alone: no G-buffer upload, the image left on the device
        t0 = time.perf_counter()
        backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, to_host=False)
        backend.synchronize()
        seconds.append(time.perf_counter() - t0)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights)
    assert np.array_equal(out, backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights,
                                             gbuffer=frame.gbuffer)), "the device's G-buffer is not the frame's"
    print(json.dumps({"label": label, "backend": backend.name, "size": [w, h],
                      "median_ms": 1e3 * float(np.median(seconds[1:])), "min_ms": 1e3 * min(seconds[1:]),
                      "mean_radiance": float(np.mean(out))}))


if __name__ == "__main__":
    main()
