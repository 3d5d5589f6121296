"""A/B of two library trees in one sitting: the whole bake (2^16 facets, K = 12, R = 128, J = 8, the
8192-triangle timing tile, Blinn–Phong n = 512) and a 1920×1080 frame of the render target scene, on
one backend, through the public API. Run it once per tree and backend, alternating the trees, each in
its own process (a process's speed varies on a GPU host): a refactor is judged by the spread of both.

    PYTHONPATH=<tree A's install> python -P bench/ab_trees.py A warp:cuda $OUT/ab.jsonl
    PYTHONPATH=<tree B's install> python -P bench/ab_trees.py B warp:cuda $OUT/ab.jsonl   # and again

Appends one JSON line per run: label, backend, device, every bake's and frame's seconds, their medians,
and the frame's mean radiance (equal between trees that render the same image)."""

import json
import sys

import numpy as np

import warp_biscale as wb
from warp_biscale.render import pack_frame

try:  # the renderer's lights: the scene's and its environment's compact sources (an older tree: the scene's)
    from warp_biscale.render import frame_lights
except ImportError:
    def frame_lights(scene):
        return scene.lights_packed

try:
    from bench.common import heightfield_tile, timed
except ImportError:  # run as a file: bench/ is this file's folder
    from common import heightfield_tile, timed


def target_scene(backend):
    """The render benchmark's target scene at 1920×1080 with one light (bench_render.target_scene)."""
    baked = wb.bake(wb.geometry.pyramid(), [wb.BlinnPhong(1.0, 512)], lobes=8, directions=12, facets=2**14,
                    backend=backend)
    torus = wb.Mesh.torus(0.8, 0.3, center=(0.0, 0.5, 0.0), segments=(96, 48), material=0)
    sphere = wb.Mesh.sphere(0.45, center=(1.5, 0.45, 0.6), subdivisions=4, material=1)
    floor = wb.Mesh.plane(6.0, 0.0, divisions=48, material=2)
    mats = [baked, wb.CookTorrance(0.7, 0.15, kd=(0.1, 0.2, 0.5)), wb.BlinnPhong(0.1, 30, kd=0.5)]
    cam = wb.Camera(eye=(0.5, 2.2, 4.2), target=(0.3, 0.4, 0.0), fov=45, width=1920, height=1080)
    return wb.Scene(wb.Mesh.merge([torus, sphere, floor]), mats, cam, wb.Environment.sky(),
                    [wb.PointLight((2.0, 3.5, 2.0), 25.0, 0.15)], ssdf_terms=16)


def main():
    label, backend, out_path = sys.argv[1:4]
    be = wb.get_backend(backend)
    tile, mat = heightfield_tile(), wb.BlinnPhong(1.0, 512)
    seeds = iter(range(1, 1 << 30))  # a new seed each bake: the geometry cache misses, as a new tile would
    bakes = timed(lambda seed: wb.bake(tile, mat, lobes=8, directions=12, normal_res=128, facets=1 << 16,
                                       backend=be, seed=seed), 9, be, make_input=lambda: next(seeds), warmup_s=2.0)
    scene = target_scene(be)
    frame = pack_frame(scene, be)  # the static inputs, uploaded once; the G-buffer stays on the device below
    inputs = getattr(frame, "inputs", frame)  # (a tree from before the typed contracts returns the inputs' dict)
    lights, camera = frame_lights(scene), scene.camera.packed()

    def draw():
        be.trace_primary(scene.mesh, scene.camera, to_host=False)
        be.trace_shadows(scene.mesh, None, lights, to_host=False)
        be.shade(scene.mesh, inputs, camera, lights, to_host=False)

    frames = timed(lambda: [draw() for _ in range(20)], 7, be)
    image = be.shade(scene.mesh, inputs, camera, lights, to_host=True)
    record = {"label": label, "backend": be.name, "device": be.device, "bake_s": bakes.runs_s,
              "bake_median_ms": 1e3 * bakes.median_s, "frame_s": [t / 20 for t in frames.runs_s],
              "frame_median_ms": 1e3 * frames.median_s / 20, "image_mean": float(np.mean(image))}
    print(json.dumps({k: v for k, v in record.items() if not k.endswith("_s")}), flush=True)
    with open(out_path, "a") as fh:
        fh.write(json.dumps(record) + "\n")


if __name__ == "__main__":
    main()
