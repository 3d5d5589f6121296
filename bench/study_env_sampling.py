"""A study, not a stage: how far the SG renderer's environment specular term of an analytic material is from the
Monte Carlo reference, against filtered importance sampling of the same term (Křivánek & Colbert 2008) done on the
host in float64: K stratified half vectors a pixel drawn from the NDF's ASG (`montecarlo_sampling.sample_asg`),
reflected about ωo, weighed by the exact f_s·cos θi over their density, each reading the prefiltered maps at the
sharpness 2π·K·pdf (the solid angle a sample stands for). The rest of the pixel (diffuse, lights) is
`shading.shade_reference`'s with its environment specular lookups returning 0. The spheres, environments and
reference of bench/anisotropic_accuracy.py (48 × 36, 1024 samples a pixel, over the sphere's pixels).

    python -m bench.study_env_sampling --samples 16 64 --environments studio "sky (sun)" --out bench/out/env-sampling
"""

import argparse
import importlib
import os
import warnings

import numpy as np

import warp_biscale as wb
from bench.anisotropic_accuracy import MATERIALS, environments
from bench.common import HERE, Output, markdown_table, run_meta
from warp_biscale import brdf as brdf_mod
from warp_biscale import lighting, shading
from warp_biscale.montecarlo_sampling import asg_pdf, sample_asg

render_mod = importlib.import_module("warp_biscale.render")


def sampled_environment(frame, material, maps, levels, k):
    """(P_hit, 3) the environment's specular term by filtered importance sampling with k stratified samples."""
    face = frame.gbuffer.face
    hit = face >= 0
    st = frame.inputs
    sf = shading.surface_frames(st.faces, st.positions, st.normals, st.tangents, face[hit], frame.gbuffer.bary[hit],
                                frame.camera[0:3].astype(np.float64))
    n, t, wo = sf["n"], sf["t"], sf["wo"]
    kinds, params = brdf_mod.pack_materials([material], anisotropic=True)
    kind, p = int(kinds[0]), params[0].astype(np.float64)
    x, y = brdf_mod.tangent_frame(n, t)
    if kind in brdf_mod.ANISOTROPIC_KINDS:
        lam, mu = brdf_mod.ndf_bandwidths(kind, p[6], p[7])
    else:
        eta = p[6] if kind == brdf_mod.BLINN_PHONG else 2 / p[6] ** 2
        lam = mu = eta / 2
    lam, mu = np.full(len(n), float(lam)), np.full(len(n), float(mu))
    spec = p.copy()
    spec[0:3] = 0.0
    cos_o = np.maximum((n * wo).sum(1), 1e-4)
    side = int(round(np.sqrt(k)))
    grid = (np.arange(side) + 0.5) / side
    out = np.zeros((len(n), 3))
    for u1, u2 in zip(*[a.ravel() for a in np.meshgrid(grid, grid)]):
        h = sample_asg(x, y, n, lam, mu, np.full(len(n), u1), np.full(len(n), u2))
        oh = (wo * h).sum(1)
        wi = 2 * oh[:, None] * h - wo
        pdf = asg_pdf(x, y, n, lam, mu, h) / (4 * np.maximum(np.abs(oh), 1e-9))
        ok = (oh > 0) & ((n * wi).sum(1) > 0) & (pdf > 0)
        fc = brdf_mod.brdf_cosine_weighted(np.array([kind]), spec[None], np.zeros(len(n), int), n, wi, wo, t)
        radiance = lighting.prefiltered_lookup(maps, levels, wi, np.maximum(2 * np.pi * side * side * pdf, 1e-3))
        out += np.where(ok[:, None], fc / cos_o[:, None] * radiance / np.where(ok, pdf, 1.0)[:, None], 0.0)
    return out / (side * side)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="opencl")
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64], help="K, square numbers")
    ap.add_argument("--environments", nargs="+", default=["studio", "sky (sun)"])
    ap.add_argument("--out", default=os.path.join(HERE, "out", "env-sampling"))
    args = ap.parse_args(argv)
    out = Output(args.out, run_meta(samples=args.samples))
    warnings.simplefilter("ignore", wb.EnergyWarning)
    backend = wb.get_backend(args.backend)
    mesh = wb.Mesh.sphere(1.0, subdivisions=4)
    camera = wb.Camera(eye=(0.3, 0.5, 3.2), width=48, height=36, fov=45)

    def table(records, meta):
        rows = [[r["environment"], r["material"], f"{100 * r['sg']:.2f} %"]
                + [f"{100 * r['sampled'][str(k)]:.2f} %" for k in args.samples]
                + [f"{100 * r['reference_noise']:.2f} %"] for r in records]
        return "\n".join([f"# The environment's specular term: SG renderer against filtered importance sampling "
                          f"(commit {meta.get('commit')})", ""] + markdown_table(
            ["environment", "material", "SG renderer"] + [f"sampled, K = {k}" for k in args.samples]
            + ["reference noise"], rows)) + "\n"

    for ename in args.environments:
        env, lights = environments()[ename]
        light = lighting.prepare(env, backend)
        for mname, material in MATERIALS.items():
            scene = wb.Scene(mesh, [material], camera, env, lights)
            frame = render_mod.pack_frame(scene, backend)
            mc = wb.render(scene, method="mc", samples=1024, backend=backend)
            ref = mc.image.reshape(-1, 3)
            hit = frame.gbuffer.face >= 0
            sg_image = shading.shade_reference(frame)
            lookups = shading.prefiltered_lookup, shading.asg_prefiltered
            shading.prefiltered_lookup = lambda maps, levels, p, eta: np.zeros((len(np.atleast_2d(p)), 3))
            shading.asg_prefiltered = lambda maps, levels, x, y, z, lam, mu: np.zeros((len(z), 3))
            try:
                base = shading.shade_reference(frame)
            finally:
                shading.prefiltered_lookup, shading.asg_prefiltered = lookups
            norm = np.linalg.norm(ref[hit])
            noise = float(mc.info["stderr_rms"]) / float(np.sqrt((ref[hit] ** 2).mean()))
            rec = {"environment": ename, "material": mname, "sampled": {}, "reference_noise": noise,
                   "sg": float(np.linalg.norm(sg_image[hit] - ref[hit]) / norm)}
            for k in args.samples:
                image = base.copy()
                image[hit] += sampled_environment(frame, material, light.prefiltered.maps, light.prefiltered.levels, k)
                rec["sampled"][str(k)] = float(np.linalg.norm(image[hit] - ref[hit]) / norm)
            out.records.append(rec)
            out.log(f"{ename} | {mname}: SG {100 * rec['sg']:.2f} %, sampled "
                    + ", ".join(f"K={k} {100 * v:.2f} %" for k, v in rec["sampled"].items()))
            out.save(table)
    out.finish(table)


if __name__ == "__main__":
    main()
