"""SG bake benchmark: speed against error of the SG bake, per backend.

Parts (each writes records into --out/results.json; table.md and plots follow):
- ``targets``: the whole bake (facets → visibility → BVNDF → EM → amplitudes → tables) at
  K = 12, R = 128, J = 8 and --facets facets on the timing tile, per stage; and a material-only edit.
- ``pareto``: for each procedural tile family and small-scale BRDF (Blinn–Phong n = 512,
  Cook–Torrance m = 0.2): bake time against PSNR / RMSE / max relative error versus a ground truth
  with --gt-facets facets, over J × facets × route, with method "sg" (Eq. 15) and "sg-exact" (Eq. 10);
  and the ground truth itself at fewer facets as a third method.
- ``reference``: the float64 numpy reference bake (`warp_biscale.reference`) against each backend on
  the same small case, for the "≥ 20× faster than the reference" target.

Times are medians over >= --runs runs after a warm-up call (compilation and uploads are reported
apart as `first_call_extra_s`) and --warmup-s seconds of warm bakes, device-synchronised; each run
is a whole bake (a facet seed of its own). The targets record every run (`runs_s`).

    python -m bench.bench_bake --parts targets reference --facets 16384 --out /tmp/bake    # a CPU
    python -m bench.bench_bake --backends warp:cuda opencl:nvidia --parts targets --runs 9 --out $OUT
    python -m bench.bench_bake --backends warp:cuda opencl:nvidia --parts pareto --gt-facets 1048576 --out $OUT
    python -m bench.bench_bake --quick --out /tmp/bake-quick                              # a smoke test
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import os
import sys
import time

import numpy as np

import warp_biscale as wb
from warp_biscale import directions as dirs
from warp_biscale import lobes as lobes_mod
from warp_biscale import reference as ref

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

# The module, for its EM step cap (`wb.bake` is the function of the same name).
bake_module = importlib.import_module("warp_biscale.bake")


def families():
    xs = np.linspace(0.0, 1.0, 33)[:-1]
    bumps = 0.08 * np.sin(2 * np.pi * xs)[None, :] * np.cos(2 * np.pi * xs)[:, None]
    return {
        "pyramid": wb.geometry.pyramid(),
        "vgroove": wb.geometry.grooves(profile="v"),
        "ugroove": wb.geometry.grooves(profile="u"),
        "rods": wb.geometry.rods(),
        "woven": wb.geometry.woven(),
        "heightfield": wb.geometry.heightfield(bumps),
    }


BRDFS = {"blinnphong512": wb.BlinnPhong(1.0, 512), "cooktorrance0.2": wb.CookTorrance(1.0, 0.2)}


def timed_bake(backend, runs, warmup_s=0.0, **kw) -> common.Timed:
    """The whole bake timed (common.timed, keep_all: each run's material and its stage `timings`). The warm-up
    bake is seed 0, the material returned as `first`; every later bake gets a seed of its own, because the
    bake keeps what depends on the geometry per (tile, facets, seed, ...): a second bake of one seed would
    redo the tables alone (the material edit below times that on purpose)."""
    be = wb.get_backend(backend)
    seeds = itertools.count()
    return common.timed(lambda: wb.bake(backend=be, seed=next(seeds), **kw), runs, be, warmup_s=warmup_s,
                        keep_all=True)


def stage_medians(t: common.Timed) -> dict:
    stages = [m.timings for m in t.results]
    return {k: float(np.median([s.get(k, 0.0) for s in stages])) for k in stages[0]}


def part_targets(backend, tile, facets, runs, warmup_s, out):
    mat_a, mat_b = wb.BlinnPhong(1.0, 512), wb.CookTorrance((0.9, 0.6, 0.2), 0.3)
    for route in ("facets", "histogram"):
        try:
            t = timed_bake(backend, runs, warmup_s, tile=tile, materials=mat_a, lobes=8, directions=12,
                           normal_res=128, facets=facets, route=route)
        except ValueError as exc:  # the histogram may be refused as too large
            out.log(f"  {backend} bake route={route}: skipped ({exc})")
            continue
        stages, mat = stage_medians(t), t.first
        out.records.append({"part": "targets", "what": "whole bake", "backend": backend, "route": route,
                            "facets": facets, "K": 12, "R": 128, "J": 8, "tile": tile.name, "time_s": t.median_s,
                            "stages_s": stages, "first_call_extra_s": t.first_call_extra_s, "runs_s": t.runs_s,
                            "warmup_s": warmup_s, "lobes": mat.info["lobes"],
                            "nonempty_bins": mat.info["nonempty_bins"]})
        out.log(f"  {backend} whole bake route={route} {facets} facets: {t.median_s * 1e3:.1f} ms "
                f"(runs {min(t.runs_s) * 1e3:.1f}–{max(t.runs_s) * 1e3:.1f})  "
                + "  ".join(f"{k} {v * 1e3:.1f}" for k, v in stages.items()))
    # Material-only edit: one seed's geometry is kept after its first bake, so only the tables are rebuilt.
    be = wb.get_backend(backend)
    turn = itertools.count()
    t = common.timed(lambda: wb.bake(tile, mat_b if next(turn) % 2 == 0 else mat_a, lobes=8, directions=12,
                                     facets=facets, backend=be), max(runs, 5), be)
    out.records.append({"part": "targets", "what": "material edit", "backend": backend, "facets": facets, "K": 12,
                        "J": 8, "tile": tile.name, "time_s": t.median_s, "runs_s": t.runs_s})
    out.log(f"  {backend} material-only edit: {t.median_s * 1e3:.2f} ms")


def part_pareto(backends, gt_backend, fams, gt_facets, facet_list, lobe_list, runs, out, save):
    for tname, tile in fams.items():
        for bname, brdf in BRDFS.items():
            mats = [brdf] * tile.n_materials
            gt = wb.ground_truth(tile, mats, facets=gt_facets, directions=12, backend=gt_backend, seed=99)
            out.log(f"  {tname}/{bname}: ground truth {gt_facets} facets on {gt_backend} "
                    f"({sum(gt.timings.values()):.2f} s)")
            for backend in backends:
                for facets in facet_list:
                    for j in lobe_list:
                        for route in ("facets", "histogram"):
                            if route == "histogram" and (j != 8 or facets != facet_list[-1]):
                                continue
                            try:
                                t = timed_bake(backend, runs, tile=tile, materials=mats, lobes=j, directions=12,
                                               facets=facets, route=route)
                            except ValueError as exc:
                                out.log(f"    skip {route}: {exc}")
                                continue
                            mat, psnr = t.first, {}
                            for method in ("sg", "sg-exact"):
                                c = wb.compare(mat, gt, method)
                                psnr[method] = c["psnr"]
                                out.records.append({"part": "pareto", "method": method, "backend": backend,
                                                    "tile": tname, "brdf": bname, "facets": facets, "J": j,
                                                    "lobes": mat.info["lobes"], "route": route,
                                                    "time_s": t.median_s, "stages_s": stage_medians(t),
                                                    "ndf_error": mat.info["ndf_error"], **c})
                            out.log(f"    {backend} Ns={facets} J={j}->{mat.info['lobes']} {route}: "
                                    f"{t.median_s * 1e3:.1f} ms PSNR {psnr['sg']:.1f} "
                                    f"(exact {psnr['sg-exact']:.1f}) dB")
                # The ground truth at fewer facets, as a method of its own.
                be = wb.get_backend(backend)
                for facets in facet_list:
                    t0 = time.perf_counter()
                    small = wb.ground_truth(tile, mats, facets=facets, directions=12, backend=be)
                    be.synchronize()
                    t = time.perf_counter() - t0
                    c = wb.compare(small, gt)
                    out.records.append({"part": "pareto", "method": "ground truth", "backend": backend,
                                        "tile": tname, "brdf": bname, "facets": facets, "time_s": t, **c})
                    out.log(f"    {backend} ground truth Ns={facets}: {t * 1e3:.1f} ms PSNR {c['psnr']:.1f} dB")
            save()


def reference_bake(tile, brdf, facets, k, j):
    """The whole bake in float64 numpy, from `warp_biscale.reference` (the oracle, timed)."""
    fd = ref.sample_facets(tile, facets, 0)
    grid = dirs.grid(k)
    vb = ref.visibility(tile, fd, grid)
    a_v = ref.visible_area(fd, vb, grid)
    bins = ref.cube_bin(fd["normal"], 128)
    _, inv = np.unique(bins, return_inverse=True)
    area = np.bincount(inv, weights=fd["area"])
    mean = np.stack([np.bincount(inv, weights=fd["area"] * fd["normal"][:, c]) for c in range(3)], 1)
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    start = lobes_mod.initial_lobes(mean, area, j)
    axes, sharp, weight, _ = ref.ndf_em(fd["normal"], fd["area"], start.axes, start.sharpness, start.weight,
                                        bake_module.EM_ITERATIONS)
    lob = lobes_mod.LobeSet(axes, sharp, weight).alive()
    rows, integrals, _, _ = lobes_mod.amplitude_system(lob, mean, area)
    iu, ou = np.triu_indices(len(grid))
    mom = ref.lobe_moments(fd, vb, grid, fd["area"], lob.axes, lob.sharpness, iu, ou)
    pi, po = dirs.all_pairs(len(grid))
    lo, hi = np.minimum(pi, po), np.maximum(pi, po)
    return ref.solve_amplitudes(mom[lo * len(grid) - lo * (lo - 1) // 2 + hi - lo], a_v, po, rows, integrals)


def part_reference(backends, facets, k, runs, out):
    tile = wb.geometry.pyramid()
    brdf = wb.BlinnPhong(1.0, 512)
    t0 = time.perf_counter()
    reference_bake(tile, brdf, facets, k, 8)
    t_ref = time.perf_counter() - t0
    out.records.append({"part": "reference", "backend": "reference (float64 numpy)", "facets": facets, "K": k,
                        "tile": tile.name, "time_s": t_ref})
    out.log(f"  float64 reference bake, pyramid, {facets} facets, K={k}: {t_ref:.2f} s")
    for backend in backends:
        t = timed_bake(backend, runs, tile=tile, materials=brdf, lobes=8, directions=k, facets=facets)
        out.records.append({"part": "reference", "backend": backend, "facets": facets, "K": k, "tile": tile.name,
                            "time_s": t.median_s, "runs_s": t.runs_s, "speedup_vs_reference": t_ref / t.median_s})
        out.log(f"  {backend}: {t.median_s * 1e3:.1f} ms, {t_ref / t.median_s:.0f}x faster than the reference")


def table(records, meta):
    lines = [f"# SG bake benchmark ({meta['device_note']})", "", common.commit_line(meta), ""]
    tg = [r for r in records if r["part"] == "targets"]
    if tg:
        lines += ["## Targets", ""] + common.markdown_table(
            ["what", "backend", "route", "facets", "time (ms)", "stages (ms)"],
            [[r["what"], r["backend"], r.get("route", ""), r["facets"], f"{r['time_s'] * 1e3:.2f}",
              ", ".join(f"{k} {v * 1e3:.1f}" for k, v in r.get("stages_s", {}).items())] for r in tg]) + [""]
    rf = [r for r in records if r["part"] == "reference"]
    if rf:
        lines += ["## Against the float64 reference", ""] + common.markdown_table(
            ["backend", "time (ms)", "speed-up"],
            [[r["backend"], f"{r['time_s'] * 1e3:.1f}", f"{r.get('speedup_vs_reference', 1):.0f}×"] for r in rf]) + [""]
    pa = [r for r in records if r["part"] == "pareto"]
    if pa:
        lines += ["## Speed against error (PSNR of f̄ against the ground truth, K = 12)", ""] + common.markdown_table(
            ["tile", "BRDF", "backend", "method", "route", "facets", "J (fitted)", "time (ms)", "PSNR (dB)",
             "max rel. err"],
            [[r["tile"], r["brdf"], r["backend"], r["method"], r.get("route", ""), r["facets"],
              f"{r['J']} ({r['lobes']})" if "J" in r else "", f"{r['time_s'] * 1e3:.1f}", f"{r['psnr']:.1f}",
              f"{r['max_rel_error']:.3g}"] for r in pa])
    return "\n".join(lines) + "\n"


def plot(records, folder):
    plt = common.pyplot()
    pa = [r for r in records if r["part"] == "pareto"]
    if not pa:
        return
    pairs = sorted({(r["tile"], r["brdf"]) for r in pa})
    cols = 4
    rows = -(-len(pairs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax, (t, b) in zip(axes.flat, pairs):
        sub = [r for r in pa if r["tile"] == t and r["brdf"] == b]
        keys = sorted({(r["backend"], r["method"], r.get("J", 0)) for r in sub}, key=str)
        for be, method, j in keys:
            pts = sorted((r["time_s"] * 1e3, r["psnr"]) for r in sub if r["backend"] == be and r["method"] == method
                         and r.get("J", 0) == j and r.get("route", "facets") == "facets")
            if pts:
                label = f"{be} {method}" + (f" J={j}" if j else "")
                ax.plot(*zip(*pts), "o-" if method != "ground truth" else "s--", ms=3, label=label)
        ax.set_xscale("log")
        ax.set_title(f"{t} / {b}", fontsize=9)
        ax.set_xlabel("ms")
        ax.set_ylabel("PSNR (dB)")
        ax.axhline(35, color="k", lw=0.5, ls=":")
    for ax in list(axes.flat)[len(pairs):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(os.path.join(folder, "pareto.png"), dpi=90)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="*", help="backend names (default: every usable backend here)")
    ap.add_argument("--parts", nargs="*", default=["targets", "reference", "pareto"])
    ap.add_argument("--facets", type=int, default=1 << 16, help="facets of the targets part")
    ap.add_argument("--gt-facets", type=int, default=1 << 18)
    ap.add_argument("--pareto-facets", type=int, nargs="*", default=[1 << 12, 1 << 14, 1 << 16])
    ap.add_argument("--lobes", type=int, nargs="*", default=[1, 2, 4, 8, 16])
    ap.add_argument("--tiles", nargs="*", help="families for the pareto part (default all)")
    ap.add_argument("--reference-facets", type=int, default=1 << 14)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--warmup-s", type=float, default=0.0,
                    help="seconds of warm bakes after the first call, before the timed runs of the targets")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke test in about a minute: 2^12 facets, 3 runs, the pareto part on the pyramid "
                         "at J = 4 against a 2^14-facet ground truth")
    ap.add_argument("--device-note", default="")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    if args.quick:
        args.facets = args.reference_facets = 1 << 12
        args.gt_facets, args.pareto_facets, args.lobes, args.runs = 1 << 14, [1 << 12], [4], 3
        args.tiles = args.tiles or ["pyramid"]
    names = common.backend_names(args.backends)
    out = common.Output(args.out, common.run_meta(
        backends=names, device_note=args.device_note or ", ".join(wb.get_backend(n).device for n in names)))

    def save():
        out.save(table)

    if "targets" in args.parts:
        tile = common.heightfield_tile()
        out.log(f"targets: timing tile {tile.name} ({len(tile.faces)} triangles)")
        for b in names:
            part_targets(b, tile, args.facets, args.runs, args.warmup_s, out)
            save()
    if "reference" in args.parts:
        part_reference(names, args.reference_facets, 12, args.runs, out)
        save()
    if "pareto" in args.parts:
        fams = families()
        if args.tiles:
            fams = {k: v for k, v in fams.items() if k in args.tiles}
        part_pareto(names, names[0], fams, args.gt_facets, args.pareto_facets, args.lobes, args.runs, out, save)
    out.finish(table)
    plot(out.records, args.out)
    out.log(f"wrote {args.out}/results.json, table.md, pareto.png")


if __name__ == "__main__":
    main()
