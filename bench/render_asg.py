"""The 1080p frame of the render target scene (bench_render.target_scene) with its baked torus material made by the
SG bake and by the ASG bake (the pyramid tile, coloured Blinn–Phong n = 256, K = 12, J = 8): per frame the
G-buffer, the shadow rays and the shading, left on the device (bench_render.time_frames), hard (1) and soft (16)
shadow rays; one JSON line each (issue 20's "1080p with ASG materials ≥ 400 fps").

    python -m bench.render_asg warp:cuda opencl:nvidia > $OUT/render_asg.jsonl
"""

import json
import sys
import warnings

import warp_biscale as wb
from bench.bench_render import target_scene, time_frames


def main(backends):
    warnings.simplefilter("ignore", wb.EnergyWarning)
    for backend in backends:
        be = wb.get_backend(backend)
        tile = wb.geometry.pyramid()
        brdf = [wb.BlinnPhong((0.9, 0.7, 0.3), 256, kd=(0.25, 0.12, 0.05))]
        for method in ("sg", "asg"):
            scene = target_scene(1920, 1080, backend=be)
            scene.materials[0] = wb.bake(tile, brdf, method=method, lobes=8, directions=12, facets=2**14, backend=be)
            for shadows in (1, 16):
                per_frame, _, _, _ = time_frames(scene, be, frames=10, runs=5, shadow_samples=shadows)
                print(json.dumps({"backend": be.name, "device": be.device, "material": method,
                                  "shadow_samples": shadows, "frame_ms": 1e3 * per_frame, "fps": 1.0 / per_frame}),
                      flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["auto"])
