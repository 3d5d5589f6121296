"""Where a frame's time goes on Warp CUDA: each kernel's device time (Warp's CUDA activity timing,
`wp.timing_begin`) over queued frames of the render target scene (`bench_render.target_scene`: 16 shadow and 16
occlusion rays, 4×4 ray blocks, the image left on the device, `render.queue_frame`), a frame's sum and each
kernel's share of it, largest first. `--scenes asg-torus`: the same scene with its torus ASG-baked (render_asg's
material: the pyramid tile, coloured Blinn–Phong 256, J = 8). Device times only: what the host adds between
launches is in `bench_render`'s frames.

    python -m bench.profile_frame [--size 1920 1080] [--scenes target asg-torus] [--frames 20] > $OUT/frame.txt
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import warnings

import warp as wp

import warp_biscale as wb
from warp_biscale.render import queue_frame

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.bench_bake import families  # noqa: E402
from bench.bench_render import target_scene  # noqa: E402

SCENES = ("target", "asg-torus")
FRAME_OPTIONS = dict(shadow_samples=16, occlusion_samples=16, block_rays=4)


def scene_named(name, width, height, backend):
    scene = target_scene(width, height, backend=backend)
    if name == "asg-torus":
        tile = families()["pyramid"]
        small = wb.BlinnPhong((0.9, 0.7, 0.3), 256, kd=(0.25, 0.12, 0.05))
        scene.materials[0] = wb.bake(tile, [small] * tile.n_materials, method="asg", lobes=8, directions=12,
                                     facets=2**14, backend=backend)
    return scene


def kernel_times(scene, backend, frames):
    """{kernel name: (ms a frame, launches a frame)} over `frames` queued frames, after a render and 5 frames that
    compile and warm everything."""
    wb.render(scene, backend=backend, **FRAME_OPTIONS)
    for _ in range(5):
        queue_frame(scene, backend, **FRAME_OPTIONS)
    backend.synchronize()
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMCPY | wp.TIMING_MEMSET)
    for _ in range(frames):
        queue_frame(scene, backend, **FRAME_OPTIONS)
    results = wp.timing_end()
    total = collections.defaultdict(float)
    count = collections.Counter()
    for r in results:
        total[r.name] += r.elapsed
        count[r.name] += 1
    return {name: (ms / frames, count[name] / frames) for name, ms in total.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="warp:cuda", help="a Warp CUDA device (default warp:cuda)")
    ap.add_argument("--size", type=int, nargs=2, default=(1920, 1080), metavar=("W", "H"))
    ap.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    ap.add_argument("--frames", type=int, default=20, help="frames timed (default 20)")
    args = ap.parse_args(argv)
    if args.frames < 1:
        ap.error(f"--frames must be at least 1, got {args.frames}")
    warnings.simplefilter("ignore", wb.EnergyWarning)
    backend = wb.get_backend(args.backend)
    if not backend.name.startswith("warp:cuda"):
        ap.error(f"--backend {args.backend!r} is {backend.name}: Warp times kernels on CUDA devices only")
    for name in args.scenes:
        times = kernel_times(scene_named(name, *args.size, backend), backend, args.frames)
        frame = sum(ms for ms, _ in times.values())
        print(f"{name} {args.size[0]}x{args.size[1]} on {backend.device}: {frame:.3f} ms of device time a frame")
        for kernel, (ms, launches) in sorted(times.items(), key=lambda kv: -kv[1][0]):
            print(f"  {ms:8.4f} ms  {100 * ms / frame:5.1f} %  x{launches:g}  {kernel}")


if __name__ == "__main__":
    main()
