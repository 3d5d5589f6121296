"""The SG renderer against the Monte Carlo reference on the two example scenes (examples/glossy.toml,
examples/bi-scale.toml), speed against error: PSNR and relative RMSE over the object pixels (the
background is the environment itself in both), with and without the environment-occlusion rays, and the
whole `wb.render` time beside each; `--block-rays`: also (or only) with the rays shared in 2×2 pixel blocks.
`--truth-directions`: the K of the reference's ground truths for baked
materials (a finer grid than the bake's keeps sharp highlights sharp in the reference; docs/design.md §3.4).
One anti-aliasing sample (the reference samples pixel centres too);
the scene files' own settings otherwise. One JSON line a render.

    python -m bench.fidelity_examples --backends warp:cuda opencl:nvidia --size 512x384 --samples 4096 > out.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import warnings

import numpy as np

import warp_biscale as wb
from bench import common

EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "examples")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=["auto"])
    ap.add_argument("--scenes", nargs="+", default=["glossy", "bi-scale"])
    ap.add_argument("--size", default="256x192", help="WxH (the scene files' own: 512x384)")
    ap.add_argument("--samples", type=int, default=1024, help="Monte Carlo samples a pixel")
    ap.add_argument("--occlusion-samples", type=int, nargs="+", default=[0, 16, 32])
    ap.add_argument("--truth-directions", type=int, nargs="+", default=[None],
                    help="K of the reference's ground truths (default: each material's own K); several: one "
                         "reference each, the SG renders judged against every one")
    ap.add_argument("--truth-facets", type=int, default=1 << 18)
    ap.add_argument("--block-rays", choices=["off", "on", "both"], default="off",
                    help="the SG renders with the rays shared in 2x2 pixel blocks (wb.render's block_rays), without, "
                         "or both")
    args = ap.parse_args(argv)
    blocks = {"off": (False,), "on": (True,), "both": (False, True)}[args.block_rays]
    w, h = (int(x) for x in args.size.lower().split("x"))
    warnings.simplefilter("ignore", wb.EnergyWarning)
    for backend in args.backends:
        be = wb.get_backend(backend)
        for name in args.scenes:
            sf = wb.load_scene(os.path.join(EXAMPLES, f"{name}.toml"), backend=be)
            sf.resize(w, h)
            mask = (be.trace_primary(sf.scene.mesh, sf.scene.camera).face >= 0).reshape(h, w)
            refs = {k: sf.render(method="mc", backend=be, samples=args.samples, truth_directions=k,
                                 truth_facets=args.truth_facets) for k in args.truth_directions}
            for occlusion, block in [(n, b) for n in args.occlusion_samples for b in blocks]:
                options = {"occlusion_samples": occlusion, **common.block_rays_option(block)}
                sf.render(method="sg", backend=be, **options)  # compiles, precomputes
                runs = [sf.render(method="sg", backend=be, **options) for _ in range(3)]
                image = runs[-1].image
                for k, ref in refs.items():
                    err = wb.compare_images(image, ref.image, mask=mask)
                    rel = float(np.sqrt(np.mean((image[mask] - ref.image[mask]) ** 2)) / np.mean(ref.image[mask]))
                    print(json.dumps({"scene": name, "backend": be.name, "device": be.device, "width": w,
                                      "height": h, "occlusion_samples": occlusion, "block_rays": block,
                                      "ssdf": runs[-1].info["ssdf"],
                                      "psnr": err["psnr"], "relative_rmse": rel, "mc_samples": args.samples,
                                      "mc_stderr_rms": ref.info.get("stderr_rms"), "truth_directions": k,
                                      "truth_facets": args.truth_facets, "mc_truths": ref.info["effective_brdf"],
                                      "mc_truth_s": ref.timings["truth"],
                                      "render_ms": 1e3 * float(np.median([r.timings["total"] for r in runs]))}),
                          flush=True)


if __name__ == "__main__":
    main()
