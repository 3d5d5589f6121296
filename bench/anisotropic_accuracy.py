"""Analytic materials on a sphere (issue 20 item 2, and Xu 2013 Fig. 1's "one ASG within 0.5 % L2 of the reference"
on our renderer), under three environments and under one light of a sun's size: the SG renderer's image (lights by
f_s's mean over the light, `shading.light_mean`; the environment through the NDF's one warped ASG for the
anisotropic kinds, the warped SG for the isotropic ones) against the Monte Carlo reference (the exact BRDF),
per material × environment: relative L2 and PSNR over the sphere's pixels (those whose camera ray hits the mesh;
the background, the environment itself, is left out), the SG image's mean over the reference's at the rim
(cos θo < 0.35 on the unit sphere) and inside, the reference's own relative noise, and both render times.
Results: results.json, table.md.

    python -m bench.anisotropic_accuracy opencl --out bench/results/anisotropic-accuracy-cpu-2core
"""

import argparse
import os
import time
import warnings

import numpy as np

import warp_biscale as wb
from bench.common import HERE, Output, backend_names, markdown_table, run_meta

MATERIALS = {
    "anisotropic Ward 0.08 × 0.4": wb.AnisotropicWard(0.6, 0.08, 0.4, kd=0.2),
    "Ashikhmin–Shirley 20 × 400": wb.AshikhminShirley(rs=0.5, nu=20, nv=400, rd=0.3),
    "Ashikhmin–Shirley 100 × 1000 (10:1)": wb.AshikhminShirley(rs=0.6, nu=100, nv=1000, rd=0.2),
    "Cook–Torrance 0.2": wb.CookTorrance(0.6, 0.2, kd=0.2),
    "Ward 0.15": wb.Ward(0.5, 0.15, kd=0.2),
    "Blinn–Phong 64": wb.BlinnPhong(0.2, 64, kd=0.2),
}
RIM = 0.35  # cos θo below which a pixel is at the rim


def environments(height=64, width=128):
    """name → (environment, lights): three maps (the studio's and the sky's height × width texels), and one
    directional light of a sun's angular radius (2°) alone."""
    return {"constant": (wb.Environment.constant(1.0), []),
            "studio": (wb.Environment.studio(height=height, width=width), []),
            "sky (sun)": (wb.Environment.sky(height=height, width=width), []),
            "light 2°": (None, [wb.DirectionalLight((0.4, 0.8, 0.3), 3.0, 2.0)])}


def table(records, meta):
    rows = [[r["backend"], r["material"], r["environment"], f"{100 * r['relative_l2']:.2f} %", f"{r['psnr']:.2f}",
             f"{r['rim_ratio']:.3f}", f"{r['inner_ratio']:.3f}",
             f"{100 * r['reference_noise']:.2f} %", f"{r['sg_s']:.2f}", f"{r['mc_s']:.1f}"] for r in records]
    maps = meta.get("map_size", (64, 128))
    head = [f"# Analytic materials against the Monte Carlo reference ({meta['size'][0]} × {meta['size'][1]}, "
            f"{meta['samples']} samples a pixel, {maps[0]} × {maps[1]} maps; commit {meta.get('commit')})", ""]
    return "\n".join(head + markdown_table(["backend", "material", "environment", "relative L2", "PSNR dB",
                                            "SG/MC rim", "SG/MC inside", "reference noise", "SG render s",
                                            "MC render s"], rows)) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("backends", nargs="*", default=None)
    ap.add_argument("--samples", type=int, default=1024, help="Monte Carlo samples a pixel (default 1024)")
    ap.add_argument("--size", type=int, nargs=2, default=(48, 36), metavar=("W", "H"))
    ap.add_argument("--map-size", type=int, nargs=2, default=(64, 128), metavar=("H", "W"),
                    help="the studio's and the sky's texels (default 64 128)")
    ap.add_argument("--environments", nargs="+", default=None, help="a subset of the environments' names")
    ap.add_argument("--out", default=os.path.join(HERE, "out", "anisotropic-accuracy"))
    args = ap.parse_args(argv)
    out = Output(args.out, run_meta(samples=args.samples, size=list(args.size), map_size=list(args.map_size)))
    mesh = wb.Mesh.sphere(1.0, subdivisions=4)
    camera = wb.Camera(eye=(0.3, 0.5, 3.2), width=args.size[0], height=args.size[1], fov=45)
    eye, d = camera.rays()  # cos θo of each pixel on the unit sphere the icosphere approximates
    b = (eye * d).sum(1)
    t = -b - np.sqrt(np.maximum(b * b - (eye * eye).sum(1) + 1.0, 0.0))
    cos_o = (-(eye + t[:, None] * d) * d).sum(1).reshape(args.size[1], args.size[0])
    for name in backend_names(args.backends):
        backend = wb.get_backend(name)
        for ename, (env, lights) in environments(*args.map_size).items():
            if args.environments and ename not in args.environments:
                continue
            for mname, material in MATERIALS.items():
                scene = wb.Scene(mesh, [material], camera, env, lights)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", wb.EnergyWarning)
                    t0 = time.perf_counter()
                    sg_image = wb.render(scene, backend=backend, aa=1).image
                    t1 = time.perf_counter()
                    mc = wb.render(scene, method="mc", samples=args.samples, backend=backend)
                    t2 = time.perf_counter()
                hit = (backend.trace_primary(mesh, camera).face >= 0).reshape(mc.image.shape[:2])
                rim, inner = hit & (cos_o < RIM), hit & (cos_o >= RIM)
                ref = mc.image[hit]
                rms = float(np.sqrt((ref**2).mean()))
                rec = {"backend": backend.name, "material": mname, "environment": ename,
                       "relative_l2": float(np.linalg.norm(sg_image[hit] - ref) / np.linalg.norm(ref)),
                       "psnr": float(wb.compare_images(sg_image, mc.image, mask=hit)["psnr"]),
                       "rim_ratio": float(sg_image[rim].mean() / mc.image[rim].mean()),
                       "inner_ratio": float(sg_image[inner].mean() / mc.image[inner].mean()),
                       "reference_noise": float(mc.info["stderr_rms"]) / rms, "sg_s": t1 - t0, "mc_s": t2 - t1}
                out.records.append(rec)
                out.log(f"{backend.name} | {mname} | {ename}: relative L2 {100 * rec['relative_l2']:.2f} %, "
                        f"{rec['psnr']:.2f} dB, SG/MC rim {rec['rim_ratio']:.3f} inside {rec['inner_ratio']:.3f} "
                        f"(reference noise {100 * rec['reference_noise']:.2f} %)")
                out.save(table)
    out.finish(table)


if __name__ == "__main__":
    main()
