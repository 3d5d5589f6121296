"""Whole `wb.render` calls, read-back included, of the render target scene (bench_render.target_scene) at
1920×1080: aa 1 and 4 samples a pixel, hard (1) and soft (16) shadow rays, and where the library has it
4 samples with every ray per sample (split_rays=False; the default splits each set between the samples), and 1
and 4 with the rays shared in 2×2 pixel blocks (block_rays=True), and 4 shaded once a pixel (aa_shading="pixel");
medians of 5 after 2 warm calls, one JSON line each.

    python -m bench.render_calls warp:cuda opencl:nvidia > $OUT/render_calls.jsonl
"""

import inspect
import json
import sys
import time

import numpy as np

import warp_biscale as wb
from bench import common
from bench.bench_render import target_scene


def main(backends):
    for backend in backends:
        be = wb.get_backend(backend)
        scene = target_scene(1920, 1080, backend=be)
        own = common.block_rays_option(False)  # each pixel its own rays, whatever the default
        rows = [(1, 1, own), (1, 16, own), (4, 1, own), (4, 16, own)]
        if "split_rays" in inspect.signature(wb.render).parameters:
            rows += [(4, 1, {"split_rays": False, **own}), (4, 16, {"split_rays": False, **own})]
        if "block_rays" in inspect.signature(wb.render).parameters:
            rows += [(1, 16, {"block_rays": True}), (4, 16, {"block_rays": True})]
        if "aa_shading" in inspect.signature(wb.render).parameters:
            rows += [(4, 16, {"aa_shading": "pixel", **own}), (4, 16, {"aa_shading": "pixel", "block_rays": True})]
        for aa, shadows, extra in rows:
            for _ in range(2):
                result = wb.render(scene, backend=be, aa=aa, shadow_samples=shadows, **extra)
            times = []
            for _ in range(5):
                t0 = time.perf_counter()
                result = wb.render(scene, backend=be, aa=aa, shadow_samples=shadows, **extra)
                times.append(time.perf_counter() - t0)
            print(json.dumps({"backend": be.name, "device": be.device, "aa": aa, "shadow_samples": shadows,
                              "split_rays": result.info.get("split_rays"),
                              "block_rays": result.info.get("block_rays", False),
                              "aa_shading": result.info.get("aa_shading", "sample"),
                              "render_ms": 1e3 * float(np.median(times)),
                              "timings_ms": {k: round(1e3 * v, 2) for k, v in result.timings.items()}}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["auto"])
