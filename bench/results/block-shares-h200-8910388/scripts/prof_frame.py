"""Each CUDA kernel's device time in the 1080p target frame (4x4 blocks, 16 shadow + 16 occlusion rays), Warp CUDA,
over 20 queued frames (wp.timing_begin): the target scene, and with its torus ASG-baked (render_asg's material).
PB: the backend (default warp:cuda); PS: the size (default 1920x1080); PF_SCENES: which scenes."""
import collections
import os
import sys
import warnings

import warp as wp

import warp_biscale as wb
from warp_biscale.render import queue_frame

sys.path.insert(0, sys.argv[1])
from bench.bench_bake import families  # noqa: E402
from bench.bench_render import target_scene  # noqa: E402

warnings.simplefilter("ignore")
be = wb.get_backend(os.environ.get("PB", "warp:cuda"))
W, H = (int(x) for x in os.environ.get("PS", "1920x1080").split("x"))
opts = dict(shadow_samples=16, occlusion_samples=16, block_rays=4)
for label in os.environ.get("PF_SCENES", "target asg-torus").split():
    scene = target_scene(W, H, backend=be)
    if label == "asg-torus":
        tile = families()["pyramid"]
        small = wb.BlinnPhong((0.9, 0.7, 0.3), 256, kd=(0.25, 0.12, 0.05))
        scene.materials[0] = wb.bake(tile, [small] * tile.n_materials, method="asg", lobes=8, directions=12,
                                     facets=2**14, backend=be)
    wb.render(scene, backend=be, **opts)
    for _ in range(5):
        queue_frame(scene, be, **opts)
    be.synchronize()
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMCPY | wp.TIMING_MEMSET)
    for _ in range(20):
        queue_frame(scene, be, **opts)
    res = wp.timing_end()
    tot = collections.defaultdict(float)
    cnt = collections.Counter()
    for r in res:
        tot[r.name] += r.elapsed
        cnt[r.name] += 1
    print(label, "sum of device times a frame: %.3f ms" % (sum(tot.values()) / 20))
    for k, v in sorted(tot.items(), key=lambda kv: -kv[1]):
        print(f"  {v / 20:8.4f} ms  x{cnt[k] / 20:.0f}  {k}")
