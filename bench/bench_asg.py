"""ASG bake benchmark (issue 20 item 3): the ASG bi-scale bake against the SG bake at the same J, PSNR of f̄
against the ground truth on the procedural tile families with Blinn–Phong n = 512 and Cook–Torrance m = 0.2.

Per tile family and BRDF: a ground truth (`--gt-facets`, seed 99); the SG bake and the ASG bake (J lobes, the
same facets and seed), each timed whole (median over `--runs`, a new facet seed each run so that the geometry
is made again); their PSNR against the truth (`wb.compare`) for every seed baked, and its mean; for the ASG
bake also with Xu's Eq. 18 shape (eval method "asg-eq18"), the fitted bandwidths and the stage times. Records
go to --out/results.json, the table to table.md. `--anisotropic`: anisotropic small-scale BRDFs, which only the
ASG bake takes (ASG × ASG), with the same lobes' PSNR without their tangent orders beside it.

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_asg --quick --out bench/results/asg-cpu-2core     # a CPU
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
import warnings

import numpy as np

import warp_biscale as wb

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402
from bench.bench_bake import BRDFS, families  # noqa: E402  (the tile families and BRDFs every bake bench uses)

warnings.simplefilter("ignore", wb.EnergyWarning)

ANISOTROPIC_BRDFS = {"anisoward0.08x0.4": wb.AnisotropicWard(1.0, 0.08, 0.4),
                     "ashikhminshirley100x1000": wb.AshikhminShirley(1.0, 100, 1000)}


def timed_bake(be, runs, **kw) -> common.Timed:
    """The whole bake timed, a new facet seed each run (the bake caches its geometry per seed)."""
    seeds = itertools.count(1)
    return common.timed(lambda: wb.bake(backend=be, seed=next(seeds), **kw), runs, be, keep_all=True)


def stage_medians(t: common.Timed) -> dict:
    stages = [m.timings for m in t.results]
    return {s: float(np.median([st.get(s, 0.0) for st in stages])) for s in stages[0]}


def part_families(backend, fams, brdfs, k, lobes, facet_counts, gt_facets, runs, out, save):
    be = wb.get_backend(backend)
    for tname, tile in fams.items():
        for bname, brdf in brdfs.items():
            mats = [brdf] * tile.n_materials
            t0 = time.perf_counter()
            gt = wb.ground_truth(tile, mats, facets=gt_facets, directions=k, backend=be, seed=99)
            out.log(f"{tname} / {bname}: ground truth {gt_facets} facets, K = {k} ({time.perf_counter() - t0:.1f} s)")
            for j, facets in itertools.product(lobes, facet_counts):
                out.records.append(compare_methods(be, tile, tname, mats, bname, gt, k, j, facets, gt_facets, runs,
                                                   out))
                save()


def compare_methods(be, tile, tname, mats, bname, gt, k, j, facets, gt_facets, runs, out) -> dict:
    """The SG and the ASG bake of one tile at J lobes and `facets` facets against the truth `gt`: a record."""
    rec = {"part": "families", "tile": tname, "brdf": bname, "backend": be.name, "device": be.device,
           "K": k, "J": j, "facets": facets, "gt_facets": gt_facets, "runs": runs}
    anisotropic = any(m.anisotropic for m in mats)  # (the SG bake refuses those: the ASG bake alone)
    for method in ("asg",) if anisotropic else ("sg", "asg"):
        t = timed_bake(be, runs, tile=tile, materials=mats, method=method, lobes=j, directions=k, facets=facets)
        baked = [t.first, *t.results]  # facet seeds 1 … runs + 1: the PSNR per seed
        mat = t.first
        rec[method] = {"psnr_seeds": [wb.compare(m, gt)["psnr"] for m in baked],
                       "seeds": list(range(1, len(baked) + 1)),
                       "time_s": t.median_s, "runs_s": t.runs_s, "stages_s": stage_medians(t),
                       "lobes": len(mat.weight if method == "asg" else mat.lobes)}
        rec[method]["psnr"] = float(np.mean(rec[method]["psnr_seeds"]))
        if method == "asg":
            rec["asg"]["psnr_eq18"] = float(np.mean([wb.compare(m, gt, "asg-eq18")["psnr"] for m in baked]))
            rec["asg"]["lam"] = mat.asgs.lam.tolist()
            rec["asg"]["mu"] = mat.asgs.mu.tolist()
            rec["asg"]["em_iterations"] = mat.info["asg_em_iterations"]
            if anisotropic:  # the same lobes with no tangent order: what turning the small-scale NDF is worth
                rec["asg"]["psnr_unordered"] = float(np.mean([wb.compare(wb.ASGBRDF(
                    m.asgs, m.weight, m.amplitudes, m.materials, m.directions), gt)["psnr"] for m in baked]))
    rec["sg"] = rec.get("sg")
    rec["diff_seeds"] = ([a - b for a, b in zip(rec["asg"]["psnr_seeds"], rec["sg"]["psnr_seeds"])]
                         if rec["sg"] else None)
    s, a = rec["sg"], rec["asg"]
    sg_part = f"SG {s['psnr']:6.2f} dB ({s['time_s'] * 1e3:7.1f} ms)" if s else "SG refuses it"
    unordered = f"; no tangent order {a['psnr_unordered']:6.2f} dB" if "psnr_unordered" in a else ""
    out.log(f"  J = {j}, {facets} facets: {sg_part} | "
            f"ASG {a['psnr']:6.2f} dB "
            f"(Eq. 18 shape {a['psnr_eq18']:6.2f}{unordered}; {a['time_s'] * 1e3:7.1f} ms: "
            f"{', '.join(f'{n} {v * 1e3:.0f}' for n, v in a['stages_s'].items())} ms) "
            f"anisotropy λ/μ {np.round(np.maximum(a['lam'], a['mu']) / np.minimum(a['lam'], a['mu']), 1)}")
    return rec


def table(records, meta):
    lines = [f"# ASG bake benchmark ({meta['device_kind']})", "", common.commit_line(meta),
             f"load average at start {meta.get('loadavg_start')}, at end {meta.get('loadavg_end')}; "
             f"OPENBLAS_NUM_THREADS={meta.get('openblas_threads')}", ""]
    fam = [r for r in records if r["part"] == "families"]
    if fam:
        r0 = fam[0]
        lines += [f"K = {r0['K']}, against a {r0['gt_facets']}-facet "
                  "ground truth (PSNR of the cosine-weighted f̄ over every pair, `wb.compare`), the mean over the "
                  "bakes' "
                  f"{r0['runs'] + 1} facet seeds (1 … {r0['runs'] + 1}; per seed the two methods see the same facets). "
                  "ASG: the default eval "
                  "(Eq. 18's bandwidths and amplitude, `asg.convolve_sg_at`'s shape); \"Eq. 18\": Xu's shape "
                  "literally. Times: median of whole bakes, a new facet seed each, "
                  f"backend {r0['backend']}. pareto.png: PSNR against bake time, every row."
                  + (" Anisotropic small-scale BRDFs (ASG × ASG): the SG bake refuses them, and the Eq. 18 column "
                     "holds the same lobes' PSNR with no tangent order instead." if any(not r["sg"] for r in fam)
                     else ""), ""]
        rows = []
        for r in fam:
            s, a = r["sg"], r["asg"]
            ratio = np.maximum(a["lam"], a["mu"]) / np.minimum(a["lam"], a["mu"])
            d = r["diff_seeds"]
            # an anisotropic small-scale BRDF: no SG bake; the "Eq. 18" column holds the lobes with no tangent order
            rows.append([r["tile"], r["brdf"], r["J"], r["facets"], f"{s['psnr']:.2f}" if s else "refused",
                         f"{a['psnr']:.2f}",
                         f"{a['psnr'] - s['psnr']:+.2f} ({min(d):+.2f} … {max(d):+.2f})" if s else "—",
                         f"{a['psnr_eq18']:.2f}" if s else f"no order: {a['psnr_unordered']:.2f}",
                         f"{s['time_s'] * 1e3:.1f}" if s else "—", f"{a['time_s'] * 1e3:.1f}",
                         f"{a['lobes']}", f"{np.median(ratio):.1f} / {ratio.max():.0f}"])
        lines += common.markdown_table(["tile", "BRDF", "J", "facets", "SG dB", "ASG dB",
                                        "ASG − SG (per seed: min … max)", "ASG (Eq. 18) dB",
                                        "SG bake ms", "ASG bake ms", "ASG lobes", "λ/μ median / max"], rows)
    return "\n".join(lines) + "\n"


def plot_pareto(records, path):
    """PSNR against bake time for every (tile, J, facets) row, one panel per BRDF: SG hollow, ASG filled, a colour
    per tile; each pair of a row joined by a line (speed against error, SG vs ASG)."""
    plt = common.pyplot()
    fam = [r for r in records if r["part"] == "families"]
    brdfs = sorted({r["brdf"] for r in fam})
    tiles = sorted({r["tile"] for r in fam})
    colours = dict(zip(tiles, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    fig, axes = plt.subplots(1, len(brdfs), figsize=(6.5 * len(brdfs), 4.8), squeeze=False)
    for ax, brdf in zip(axes[0], brdfs):
        for r in (r for r in fam if r["brdf"] == brdf):
            c = colours[r["tile"]]
            xs = [r["sg"]["time_s"] * 1e3 if r["sg"] else None, r["asg"]["time_s"] * 1e3]
            ys = [r["sg"]["psnr"] if r["sg"] else None, r["asg"]["psnr"]]
            if r["sg"]:
                ax.plot(xs, ys, "-", color=c, alpha=0.35, lw=0.8)
                ax.plot(xs[0], ys[0], "o", mfc="none", color=c)
            ax.plot(xs[1], ys[1], "o", color=c)
            ax.annotate(f"{r['J']}", (xs[1], ys[1]), fontsize=6, xytext=(3, 2), textcoords="offset points")
        for t in tiles:
            ax.plot([], [], "o", color=colours[t], label=t)
        ax.plot([], [], "o", mfc="none", color="k", label="SG")
        ax.plot([], [], "o", color="k", label="ASG (label: J)")
        ax.set(xscale="log", xlabel="bake time (ms)", ylabel="PSNR of f̄ (dB)", title=brdf)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    common.save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", default="warp:cpu")
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true", help="a CPU: K = 8, 2^14 facets, a 2^16-facet truth, 2 runs")
    ap.add_argument("--directions", type=int, default=None, help="K (default 12; 8 with --quick)")
    ap.add_argument("--lobes", type=int, nargs="+", default=[8], help="J, one or more (default 8)")
    ap.add_argument("--facets", type=int, nargs="+", default=None,
                    help="bake facets, one or more (default 2^16; 2^14 with --quick)")
    ap.add_argument("--gt-facets", type=int, default=None, help="ground-truth facets (default 2^18; 2^16 with --quick)")
    ap.add_argument("--tiles", nargs="*", help="families (default all)")
    ap.add_argument("--runs", type=int, default=None, help="timed runs (default 5; 2 with --quick)")
    ap.add_argument("--anisotropic", action="store_true",
                    help="anisotropic small-scale BRDFs (ASG x ASG; the SG bake refuses them): anisotropic Ward "
                         "(0.08, 0.4) and Ashikhmin-Shirley (100, 1000) instead of Blinn-Phong and Cook-Torrance")
    args = ap.parse_args(argv)
    k = args.directions or (8 if args.quick else 12)
    facets = args.facets or [2**14 if args.quick else 2**16]
    gt_facets = args.gt_facets or (2**16 if args.quick else 2**18)
    runs = args.runs or (2 if args.quick else 5)
    out = common.Output(args.out, common.run_meta(
        backend=args.backend, device_kind=wb.get_backend(args.backend).device,
        openblas_threads=os.environ.get("OPENBLAS_NUM_THREADS"), K=k, J=args.lobes, facets=facets,
        gt_facets=gt_facets, runs=runs))
    fams = families()
    if args.tiles:
        fams = {n: fams[n] for n in args.tiles}
    brdfs = ANISOTROPIC_BRDFS if args.anisotropic else BRDFS
    part_families(args.backend, fams, brdfs, k, args.lobes, facets, gt_facets, runs, out, lambda: out.save(table))
    out.finish(table)
    plot_pareto(out.records, out.path("pareto.png"))
    out.log(f"wrote {args.out}/results.json, table.md, pareto.png")


if __name__ == "__main__":
    main()
