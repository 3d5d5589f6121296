"""A study, not a stage: how many shadow rays an environment's compact source (the sky's 2° sun, a light of the
frame: `lighting.environment_sources`) needs. The SG image of a torus, a sphere and a floor under the sky and one
point light (the point light at 64 rays throughout), with the sources' cap `lighting.SOURCE_SHADOW_SAMPLES` at
each count asked for, against the same image with the sun at 64 rays: relative RMS and PSNR over the hit pixels,
each pixel its own rays and rays shared in 2×2 blocks (against blocks at 64).

    python -m bench.study_source_rays --out bench/out/source-rays
"""

import argparse
import os

import numpy as np

import warp_biscale as wb
from bench.common import HERE, Output, markdown_table, run_meta
from warp_biscale import lighting

REFERENCE_RAYS = 64


def scene(width, height):
    torus = wb.Mesh.torus(0.8, 0.3, center=(0.0, 0.5, 0.0), segments=(96, 48), material=0)
    sphere = wb.Mesh.sphere(0.45, center=(1.5, 0.45, 0.6), subdivisions=4, material=1)
    floor = wb.Mesh.plane(6.0, 0.0, divisions=48, material=2)
    mats = [wb.CookTorrance(0.5, 0.3, kd=(0.5, 0.4, 0.3)), wb.CookTorrance(0.7, 0.15, kd=(0.1, 0.2, 0.5)),
            wb.BlinnPhong(0.1, 30, kd=0.5)]
    cam = wb.Camera(eye=(0.5, 2.2, 4.2), target=(0.3, 0.4, 0.0), fov=45, width=width, height=height)
    return wb.Scene(wb.Mesh.merge([torus, sphere, floor]), mats, cam, wb.Environment.sky(),
                    [wb.PointLight((2.0, 3.5, 2.0), 25.0, 0.15)], ssdf_terms=16)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="opencl")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--rays", type=int, nargs="+", default=[16, 8, 4])
    ap.add_argument("--out", default=os.path.join(HERE, "out", "source-rays"))
    args = ap.parse_args(argv)
    w, h = map(int, args.size.split("x"))
    out = Output(args.out, run_meta(size=args.size, backend=args.backend))
    backend = wb.get_backend(args.backend)
    s = scene(w, h)
    cap = lighting.SOURCE_SHADOW_SAMPLES

    def table(records, meta):
        rows = [[("2×2 blocks" if r["blocks"] else "own rays"), r["rays"], f"{100 * r['relative_rms']:.3f} %",
                 f"{r['psnr_db']:.2f} dB"] for r in records]
        return "\n".join([f"# The sun's shadow rays against {REFERENCE_RAYS} (commit {meta.get('commit')}, "
                          f"{meta.get('backend')}, {meta.get('size')})", ""] + markdown_table(
            ["shadow rays", "sun's rays a pixel", "relative RMS", "PSNR"], rows)) + "\n"

    try:
        for blocks in (False, True):
            images = {}
            for n in (REFERENCE_RAYS, *args.rays):
                lighting.SOURCE_SHADOW_SAMPLES = n
                images[n] = wb.render(s, backend=backend, shadow_samples=REFERENCE_RAYS, block_rays=blocks).image
            ref = images[REFERENCE_RAYS]
            hit = (backend.trace_primary(s.mesh, s.camera).face >= 0).reshape(h, w)  # the scene's pixels, no sky
            for n in args.rays:
                d = images[n][hit] - ref[hit]
                rec = {"blocks": blocks, "rays": n,
                       "relative_rms": float(np.sqrt((d ** 2).mean() / (ref[hit] ** 2).mean())),
                       "psnr_db": float(10 * np.log10(ref[hit].max() ** 2 / (d ** 2).mean()))}
                out.records.append(rec)
                out.log(f"blocks={blocks} sun rays {n}: {100 * rec['relative_rms']:.3f} %, {rec['psnr_db']:.2f} dB")
                out.save(table)
    finally:
        lighting.SOURCE_SHADOW_SAMPLES = cap
    out.finish(table)


if __name__ == "__main__":
    main()
