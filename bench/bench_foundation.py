"""Foundation benchmark: facet sampling, visibility and the ground truth, speed against error.

For every usable backend here (or those named), Ns = 2^14 … 2^20 facets and K = 8, 12, 16:
- time of each stage: median over >= 5 runs after a warm-up call, device-synchronised; the
  first call's extra time (compilation, BVH build, uploads) is reported apart as `first_call_extra_s`;
- error of the ground truth against the exact V-groove closed form (reference.vgroove_effective_brdf),
  for the stratified facets the library uses and for independent (i.i.d.) area-weighted facets
  through the same kernels, so the gain of stratification is measured, not claimed.

Writes one JSON record per measurement (`results.json`), a markdown table (`table.md`), `log.txt` and
plots (`*.png`) into --out. A measurement predicted to exceed --budget seconds per run (from the
backend's measured rate) is skipped and recorded as skipped.

    python -m bench.bench_foundation --out /tmp/foundation                       # every usable backend
    python -m bench.bench_foundation --backends warp:cuda opencl:nvidia --out $OUT   # on a GPU machine
    python -m bench.bench_foundation --quick --out /tmp/foundation-quick         # seconds: a smoke test
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import warp_biscale as wb
from warp_biscale import reference as ref
from warp_biscale.brdf import pack_materials

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402
from bench.common import log2  # noqa: E402


def iid_facets(tile, count, seed):
    """Independent area-weighted facets (Wu's original sampling, without the kd-tree areas)."""
    rng = np.random.default_rng(seed)
    areas = tile.face_areas
    face = rng.choice(len(areas), size=count, p=areas / areas.sum())
    u, v = rng.random(count), rng.random(count)
    su = np.sqrt(u)
    tri = tile.triangles[face]
    pos = (1 - su)[:, None] * tri[:, 0] + (su * (1 - v))[:, None] * tri[:, 1] + (su * v)[:, None] * tri[:, 2]
    return wb.Facets(pos.astype(np.float32), tile.face_normals[face].astype(np.float32), face.astype(np.int32),
                     np.full(count, tile.area / count, np.float32), tile.material_ids[face],
                     tile.colors[face].astype(np.float32), seed=seed)


def ground_truth_table(backend, tile, fac, grid, kinds, params):
    vis = backend.visibility(tile, fac, grid)
    a_v = backend.visible_area(fac, vis)
    nd = len(grid)
    pi, po = wb.directions.all_pairs(nd)
    return backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v).reshape(nd, nd, 3)


def error_sweep(backend, exps, k, seeds, out):
    """RMS / max error of the ground truth on the V-groove against its closed form."""
    tile = ref.vgroove_tile(0.5, 1.0)
    mat = wb.BlinnPhong(1.0, 64, kd=0.1)
    kinds, params = pack_materials([mat])
    grid = wb.directions.grid(k)
    nd = len(grid)
    pi, po = wb.directions.all_pairs(nd)
    exact = ref.vgroove_effective_brdf(0.5, 1.0, kinds, params, grid[pi], grid[po]).reshape(nd, nd, 3)
    for e in exps:
        n = 1 << e
        for method in ("stratified", "iid"):
            rms, mx = [], []
            for seed in range(seeds):
                fac = backend.sample_facets(tile, n, seed) if method == "stratified" else iid_facets(tile, n, seed)
                err = ground_truth_table(backend, tile, fac, grid, kinds, params) - exact
                rms.append(float(np.sqrt((err**2).mean()) / exact.mean()))
                mx.append(float(np.abs(err).max() / exact.max()))
            rec = {"stage": "ground_truth_error", "method": method, "tile": "vgroove", "brdf": repr(mat),
                   "facets": n, "K": k, "seeds": seeds, "rel_rms_error": float(np.mean(rms)),
                   "rel_max_error": float(np.mean(mx)), "backend": backend.name, "device": backend.device}
            out.records.append(rec)
            out.log(f"error  {method:<10} Ns=2^{e:<2} K={k}: rel RMS {rec['rel_rms_error']:.2e}  "
                    f"rel max {rec['rel_max_error']:.2e}")


def speed_sweep(backend, tile, exps, ks, runs, budget, out):
    mat = wb.BlinnPhong(1.0, 64, kd=0.1)
    kinds, params = pack_materials([mat])
    rate = {}  # seconds per unit of work, to predict and skip what would blow the budget
    for k in ks:
        grid = wb.directions.grid(k)
        nd = len(grid)
        pi, po = wb.directions.all_pairs(nd)
        for e in exps:
            n = 1 << e
            base = {"backend": backend.name, "device": backend.device, "facets": n, "K": k,
                    "tile": tile.name, "triangles": int(len(tile.faces))}
            fac = backend.sample_facets(tile, n, 0)
            if k == ks[0]:
                t = common.timed(lambda: backend.sample_facets(tile, n, 0), runs, backend, budget_s=budget)
                out.records.append({**base, "stage": "facets", "median_s": t.median_s, "runs": len(t.runs_s),
                                    "first_call_extra_s": t.first_call_extra_s})
                out.log(f"{backend.name:<22} facets      Ns=2^{e:<2}        {t.median_s * 1e3:10.3f} ms")
            work = {"visibility": n * nd, "ground_truth": n * nd * nd}
            for stage in ("visibility", "ground_truth"):
                if stage in rate and rate[stage] * work[stage] > budget:
                    out.records.append({**base, "stage": stage, "skipped": True,
                                        "predicted_s": rate[stage] * work[stage]})
                    out.log(f"{backend.name:<22} {stage:<11} Ns=2^{e:<2} K={k:<2} skipped (predicted "
                            f"{rate[stage] * work[stage]:.1f} s > budget {budget} s)")
                    continue
                if stage == "visibility":
                    t = common.timed(lambda: backend.visibility(tile, fac, grid), runs, backend, budget_s=budget)
                    extra = {"rays": n * nd, "mrays_per_s": n * nd / t.median_s / 1e6,
                             "visible_fraction": float(t.last.as_bool().mean())}
                else:
                    vis = backend.visibility(tile, fac, grid)

                    def gt():
                        a_v = backend.visible_area(fac, vis)
                        return backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v)

                    t = common.timed(gt, runs, backend, budget_s=budget)
                    extra = {"pairs": nd * nd, "gfacet_pairs_per_s": n * nd * nd / t.median_s / 1e9}
                rate[stage] = max(rate.get(stage, 0.0), t.median_s / work[stage])
                out.records.append({**base, "stage": stage, "median_s": t.median_s, "runs": len(t.runs_s),
                                    "first_call_extra_s": t.first_call_extra_s, **extra})
                out.log(f"{backend.name:<22} {stage:<11} Ns=2^{e:<2} K={k:<2} {t.median_s * 1e3:10.3f} ms  "
                        f"({len(t.runs_s)} runs)")


def table(records, meta):
    head = [common.commit_line(meta), ""]
    rows = []
    for r in records:
        if r["stage"] == "ground_truth_error":
            continue
        size = [r["stage"], r["backend"], r["device"], f"2^{log2(r['facets'])}", r["K"]]
        if r.get("skipped"):
            rows.append(size + [f"skipped (~{r['predicted_s']:.0f} s)", "", "", ""])
            continue
        rate = ""
        if "mrays_per_s" in r:
            rate = f"{r['mrays_per_s']:.1f} Mrays/s"
        elif "gfacet_pairs_per_s" in r:
            rate = f"{r['gfacet_pairs_per_s']:.3f} G facet-pairs/s"
        rows.append(size + [f"{r['median_s'] * 1e3:.3f}", r["runs"], f"{r['first_call_extra_s'] * 1e3:.1f}", rate])
    lines = head + common.markdown_table(
        ["stage", "backend", "device", "Ns", "K", "median ms", "runs", "first-call extra ms", "rate"], rows)
    err = [r for r in records if r["stage"] == "ground_truth_error"]
    if err:
        lines += ["", "Ground-truth error on the V-groove (Blinn-Phong n=64, kd=0.1) against the closed form:", ""]
        lines += common.markdown_table(
            ["facets", "method", "backend", "K", "rel. RMS error", "rel. max error"],
            [[f"2^{log2(r['facets'])}", r["method"], r["backend"], r["K"], f"{r['rel_rms_error']:.2e}",
              f"{r['rel_max_error']:.2e}"] for r in err])
    return "\n".join(lines) + "\n"


def plot(records, folder):
    plt = common.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    for ax, stage in zip(axes[:2], ("visibility", "ground_truth")):
        keys = sorted({(r["backend"], r["K"]) for r in records if r["stage"] == stage and not r.get("skipped")})
        for be, k in keys:
            pts = sorted((r["facets"], r["median_s"]) for r in records
                         if r["stage"] == stage and r["backend"] == be and r["K"] == k and not r.get("skipped"))
            ax.loglog(*zip(*pts), "o-", label=f"{be} K={k}")
        ax.set_xlabel("facets Ns")
        ax.set_ylabel("median time (s)")
        ax.set_title(stage)
        ax.grid(alpha=0.3, which="both")
        if keys:
            ax.legend(fontsize=7)
    ax = axes[2]
    err = [r for r in records if r["stage"] == "ground_truth_error"]
    gt_time = {(r["backend"], r["facets"], r["K"]): r["median_s"] for r in records
               if r["stage"] == "ground_truth" and not r.get("skipped")}
    for method in ("stratified", "iid"):
        pts = sorted((r["facets"], r["rel_rms_error"]) for r in err if r["method"] == method)
        if pts:
            ax.loglog(*zip(*pts), "o-", label=f"{method} facets")
    ax.set_xlabel("facets Ns")
    ax.set_ylabel("relative RMS error vs closed form")
    ax.set_title("ground-truth error (V-groove)")
    ax.grid(alpha=0.3, which="both")
    if err:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "foundation.png"), dpi=100)
    plt.close(fig)
    # Speed against error: ground-truth time (timing tile) against the V-groove error at equal Ns.
    if err and gt_time:
        fig, ax = plt.subplots(figsize=(6, 4.5))
        for be, k in sorted({(b, kk) for (b, _, kk) in gt_time}):
            pts = sorted((gt_time[(be, r["facets"], k)] * 1e3, r["rel_rms_error"]) for r in err
                         if r["method"] == "stratified" and (be, r["facets"], k) in gt_time and r["K"] == k)
            if pts:
                ax.loglog(*zip(*pts), "o-", label=f"{be} K={k}")
        ax.set_xlabel("ground-truth time (ms)")
        ax.set_ylabel("relative RMS error")
        ax.set_title("ground truth: error against time")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:  # empty when no K of the error sweep was timed
            ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(folder, "pareto.png"), dpi=100)
        plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--backends", nargs="*", help="backend names (default: every usable backend here)")
    p.add_argument("--facets", nargs="*", type=int, default=list(range(14, 21, 2)), help="log2 facet counts")
    p.add_argument("--directions", nargs="*", type=int, default=[8, 12, 16], help="grid sizes K")
    p.add_argument("--runs", type=int, default=5, help="timed runs per measurement (median reported)")
    p.add_argument("--budget", type=float, default=20.0, help="skip measurements predicted above this many s/run")
    p.add_argument("--error-facets", nargs="*", type=int, default=[10, 12, 14, 16, 18],
                   help="log2 Ns for the error sweep")
    p.add_argument("--error-seeds", type=int, default=4, help="seeds averaged in the error sweep")
    p.add_argument("--tile-cells", type=int, default=128,
                   help="timing tile: n×n-cell height field, 2n² triangles (128: the tile of bench/README.md)")
    p.add_argument("--quick", action="store_true",
                   help="a smoke test in seconds: 2^10 and 2^12 facets, K = 8, a 16×16-cell tile, 2 error seeds")
    p.add_argument("--out", required=True, help="output folder")
    args = p.parse_args(argv)
    if args.quick:
        args.facets, args.directions, args.tile_cells = [10, 12], [8], 16
        args.error_facets, args.error_seeds = [10, 12], 2

    names = common.backend_names(args.backends)
    tile = common.heightfield_tile(args.tile_cells)
    out = common.Output(args.out, common.run_meta(backends=names, tile_triangles=int(len(tile.faces))))
    out.log(f"timing tile: {len(tile.faces)} triangles; backends: {', '.join(names)}")
    for name in names:
        backend = wb.get_backend(name)
        speed_sweep(backend, tile, args.facets, args.directions, args.runs, args.budget, out)
        error_sweep(backend, args.error_facets, 8, args.error_seeds, out)
        out.save(table)
    out.finish(table)
    plot(out.records, args.out)
    out.log(f"wrote {args.out}/results.json, table.md, foundation.png, pareto.png")


if __name__ == "__main__":
    main()
