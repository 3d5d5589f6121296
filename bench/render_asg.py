"""The 1080p frame of the render target scene (bench_render.target_scene) with its baked torus material made by the
SG bake and by the ASG bake (a tile, coloured Blinn–Phong n = 256, K = 12, J lobes): per frame the G-buffer, the
shadow rays and the shading, left on the device (bench_render.time_frames), hard (1) and soft (16) shadow rays;
one JSON line each (issue 20's "1080p with ASG materials ≥ 400 fps", and its render speed per material × J);
`--block-rays`: each also with the rays shared in 2×2 pixel blocks; `--block-rays 2 4`: with each of those block sides
(off, on = 2, 2, 4, both; the frames of each).
The default tile is the pyramid (at most 5 distinct normals, so at most 5 lobes whatever J); the height field
gives every J its lobes.

    python -m bench.render_asg warp:cuda opencl:nvidia > $OUT/render_asg.jsonl
    python -m bench.render_asg warp:cuda opencl:nvidia --tile heightfield --lobes 2 4 8 16 > $OUT/render_asg_j.jsonl

`--analytic`: instead, the torus in analytic materials: isotropic Ward, and the anisotropic Ward and
Ashikhmin–Shirley, which the renderer shades through one ASG each (the "material" key names them).
`--anisotropic`: the ASG bake alone, of the tile in anisotropic Ward (0.05, 0.3) (ASG × ASG: each lobe convolved
with the small-scale NDF's ASG in the shade kernels; "material": "asg-anisotropic-ward").
"""

import argparse
import json
import warnings

import warp_biscale as wb
from bench import common
from bench.bench_bake import families
from bench.bench_render import target_scene, time_frames


ANALYTIC = {"ward": wb.Ward((0.9, 0.7, 0.3), 0.15, kd=(0.25, 0.12, 0.05)),
            "anisotropic-ward": wb.AnisotropicWard((0.9, 0.7, 0.3), 0.05, 0.3, kd=(0.25, 0.12, 0.05)),
            "ashikhmin-shirley": wb.AshikhminShirley(rs=(0.9, 0.7, 0.3), nu=20, nv=400, rd=(0.1, 0.05, 0.02))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("backends", nargs="*", default=["auto"])
    ap.add_argument("--tile", default="pyramid", help="a family of bench_bake.families (default pyramid)")
    ap.add_argument("--lobes", type=int, nargs="+", default=[8], help="J, one or more (default 8)")
    ap.add_argument("--size", type=int, nargs=2, default=(1920, 1080), metavar=("W", "H"))
    ap.add_argument("--analytic", action="store_true", help="the torus in analytic (an)isotropic materials")
    ap.add_argument("--anisotropic", action="store_true",
                    help="the ASG bake of the tile in anisotropic Ward (the SG bake refuses it)")
    ap.add_argument("--block-rays", nargs="*", choices=list(common.BLOCK_MODES), default=None,
                    help="alone: each frame also with the rays shared in 2x2 pixel blocks (wb.render's block_rays); "
                         "with values (off, on = 2, 2, 4, both): each of those settings")
    args = ap.parse_args(argv)
    blocks = (False,) if args.block_rays is None else common.block_modes(args.block_rays or ["both"])
    warnings.simplefilter("ignore", wb.EnergyWarning)
    tile = families()[args.tile]
    for backend in args.backends:
        be = wb.get_backend(backend)
        if args.analytic:
            for name, mat in ANALYTIC.items():
                scene = target_scene(*args.size, backend=be)
                scene.materials[0] = mat
                for shadows, block in [(n, b) for n in (1, 16) for b in blocks]:
                    per_frame, _, _, _ = time_frames(scene, be, frames=10, runs=5, shadow_samples=shadows,
                                                     block_rays=block)
                    print(json.dumps({"backend": be.name, "device": be.device, "material": name,
                                      "size": list(args.size), "shadow_samples": shadows, "block_rays": block,
                                      "frame_ms": 1e3 * per_frame, "fps": 1.0 / per_frame}), flush=True)
            continue
        small = (ANALYTIC["anisotropic-ward"] if args.anisotropic
                 else wb.BlinnPhong((0.9, 0.7, 0.3), 256, kd=(0.25, 0.12, 0.05)))
        brdf = [small] * tile.n_materials
        for j in args.lobes:
            for method in ("asg",) if args.anisotropic else ("sg", "asg"):
                scene = target_scene(*args.size, backend=be)
                mat = wb.bake(tile, brdf, method=method, lobes=j, directions=12, facets=2**14, backend=be)
                scene.materials[0] = mat
                for shadows, block in [(n, b) for n in (1, 16) for b in blocks]:
                    per_frame, _, _, _ = time_frames(scene, be, frames=10, runs=5, shadow_samples=shadows,
                                                     block_rays=block)
                    print(json.dumps({"backend": be.name, "device": be.device, "tile": args.tile, "J": j,
                                      "lobes": len(mat.weight if method == "asg" else mat.lobes),
                                      "material": method + ("-anisotropic-ward" if args.anisotropic else ""),
                                      "size": list(args.size), "shadow_samples": shadows, "block_rays": block,
                                      "frame_ms": 1e3 * per_frame, "fps": 1.0 / per_frame}), flush=True)


if __name__ == "__main__":
    main()
