"""Matrix-method benchmark (Wu 2011): M's precomputation per material, and the matrix bake against the SG bake —
speed, PSNR against the ground truth and memory — on the procedural tile families with Cook–Torrance m = 0.2.

Parts (records go to --out/results.json; table.md and matrix.png follow):
- ``precompute``: per small-scale BRDF (Wu Table 3's analytic rows: Lambertian, Ward α = 0.3, Cook–Torrance
  m = 0.5 and 0.2), the factors of M from scratch (no cache) with M tabulated by each backend's kernels and
  by numpy: Wu's sampling-rate search (the octahedral R of M's rows; the K his 2 % threshold asks for), M's
  size in float64 (as Wu's "size of M"), the factors' bytes (his "final size"), the rank kept for 98 % of the
  power, and the time per step (search, colour direction, M, SVD).
- ``families``: per tile family, Cook–Torrance m = 0.2: a ground truth (`--gt-facets`), then per backend the
  SG bake (J = 8), the ASG bake (J = 8; its fit on the host) and the matrix bake (M's factors already
  precomputed: cached, as after one `precompute`) timed whole (median over `--runs`, a new facet seed each run
  so that the geometry is made again), their PSNR against the truth (Wu Table 4's metric, `wb.compare`), their
  memory (SG and ASG: the amplitude table of the material; matrix: N's factors and M's factors), and a
  material-only edit (`with_materials`, the new material's factors cached: Eq. 12 alone for the matrix method).

    python -m bench.bench_matrix --quick --out bench/results/matrix-cpu-2core          # a CPU
    python -m bench.bench_matrix --backends warp:cuda opencl:nvidia --out $OUT           # a GPU
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
import time
import warnings

import numpy as np

import warp_biscale as wb
from warp_biscale import matrix as mx

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402
from bench.bench_bake import families  # noqa: E402  (the tile families every bake benchmark uses)

warnings.simplefilter("ignore", wb.EnergyWarning)

CT02 = wb.CookTorrance(1.0, 0.2)
# Wu Table 3's analytic materials (his α is our roughness / alpha).
PRECOMPUTE_BRDFS = {"lambert": wb.Lambert(0.8), "ward0.3": wb.Ward(1.0, 0.3),
                    "cooktorrance0.5": wb.CookTorrance(1.0, 0.5), "cooktorrance0.2": CT02}
EDIT_BRDF = wb.Ward(0.8, 0.3, kd=0.1)  # what the material-only edit switches to


def part_precompute(backends, k, brdfs, out):
    g = wb.directions.grid(2)
    for backend in backends:  # build the `matrix` kernels first: a program's build is not M's time
        wb.get_backend(backend).brdf_matrix(*wb.brdf.pack_materials([CT02]), 0, g[:1], g, g, np.ones(3))
    for name, brdf in brdfs.items():
        for source in [*backends, "numpy"]:
            be = None if source == "numpy" else wb.get_backend(source)
            mx._MEMORY.clear()
            t0 = time.perf_counter()
            f = mx.material_factors(brdf, directions=k, cache_dir=False, backend=be)
            total = time.perf_counter() - t0
            rates = f.rates
            rec = {"part": "precompute", "brdf": name, "m_by": source, "K": k, "normal_res": f.normal_res,
                   "rows": f.info["rows"], "columns": f.info["columns"], "matrix_bytes": f.info["matrix_bytes"],
                   "factor_bytes": f.nbytes, "rank": f.rank, "power_kept": f.factors.power_kept,
                   "color_residual": f.color_residual, "streamed": f.info["streamed"],
                   "directions_advised": rates.directions, "direction_met": rates.direction_met,
                   "normal_error": rates.normal_error, "direction_error": rates.direction_error,
                   "stages_s": f.info["timings"], "time_s": total}
            out.records.append(rec)
            out.log(f"{name:<16} M by {source:<28} R={f.normal_res:<4} {rec['rows']}x{rec['columns']} "
                    f"({rec['matrix_bytes'] / 2**20:.1f} MiB) -> rank {f.rank}, {f.nbytes / 2**20:.2f} MiB; "
                    f"K advised {rates.directions}{'' if rates.direction_met else ' (2 % not met)'}; "
                    f"{total:.2f} s ({', '.join(f'{a} {b:.2f}' for a, b in f.info['timings'].items())})")


def timed_bake(be, runs, **kw) -> common.Timed:
    """The whole bake timed (common.timed, keep_all), a new facet seed each run: the bake keeps what depends
    on the geometry per (tile, facets, seed, ...), so one seed twice would time the tables alone."""
    seeds = itertools.count()
    return common.timed(lambda: wb.bake(backend=be, seed=next(seeds), **kw), runs, be, keep_all=True)


def stage_medians(t: common.Timed) -> dict:
    stages = [m.timings for m in t.results]
    return {s: float(np.median([st.get(s, 0.0) for st in stages])) for s in stages[0]}


def part_families(backends, fams, k, facets, gt_facets, runs, out, save):
    for tname, tile in fams.items():
        mats = [CT02] * tile.n_materials
        edit = [EDIT_BRDF] * tile.n_materials
        t0 = time.perf_counter()
        gt = wb.ground_truth(tile, mats, facets=gt_facets, directions=k, backend=backends[0], seed=99)
        out.log(f"{tname}: ground truth {gt_facets} facets, K = {k} on {backends[0]} "
                f"({time.perf_counter() - t0:.1f} s)")
        for backend in backends:
            be = wb.get_backend(backend)
            # M's factors once (precompute once, edit forever): the timed matrix bakes read them from the cache.
            for b in (CT02, EDIT_BRDF):
                mx.material_factors(b, directions=k, backend=be)
            for method in ("sg", "asg", "matrix"):
                t = timed_bake(be, runs, tile=tile, materials=mats, method=method, directions=k, facets=facets)
                mat = t.first
                c = wb.compare(mat, gt)
                te = common.timed(lambda: mat.with_materials(edit), runs)
                if method == "matrix":
                    fb = mat.factor_bytes
                    memory = {"n_factor_bytes": fb["n"], "m_factor_bytes": int(sum(fb["m"].values())),
                              "bytes": fb["n"] + int(sum(fb["m"].values())),
                              "table_bytes": int(mat.tables.nbytes), "n_ranks": mat.info["n_ranks"],
                              "m_rank": mat.factors[0].rank, "bins": mat.info["nonempty_bins"]}
                else:  # (SG and ASG: the material's amplitude table, J lobes)
                    memory = {"bytes": int(mat.amplitudes.nbytes), "lobes": int(mat.info["lobes"])}
                rec = {"part": "families", "tile": tname, "brdf": "cooktorrance0.2", "method": method,
                       "backend": be.name, "device": be.device, "K": k, "facets": facets, "gt_facets": gt_facets,
                       "time_s": t.median_s, "runs_s": t.runs_s, "first_call_extra_s": t.first_call_extra_s,
                       "stages_s": stage_medians(t), "edit_s": te.median_s, **memory, **c}
                out.records.append(rec)
                out.log(f"  {be.name:<28} {method:<6}: bake {t.median_s * 1e3:8.1f} ms, PSNR {c['psnr']:5.1f} dB, "
                        f"{rec['bytes'] / 2**10:8.1f} KiB, edit {te.median_s * 1e3:7.2f} ms "
                        f"({', '.join(f'{a} {b * 1e3:.1f}' for a, b in rec['stages_s'].items())} ms)")
        save()


def table(records, meta):
    lines = [f"# Matrix-method benchmark ({meta['device_kind']})", "", common.commit_line(meta),
             f"load average at start {meta.get('loadavg_start')}, at end {meta.get('loadavg_end')}; "
             f"OPENBLAS_NUM_THREADS={meta.get('openblas_threads')}", ""]
    pre = [r for r in records if r["part"] == "precompute"]
    if pre:
        lines += [f"M's precomputation from scratch (K = {pre[0]['K']}: {pre[0]['columns']} unordered direction "
                  "pairs; rows: R² octahedral normals, R by Wu's search at 1 % of the power; 98 % of M's power "
                  "kept; M's size in float64, as Wu Table 3)", ""]
        lines += common.markdown_table(
            ["BRDF", "M by", "R", "M rows x cols", "M MiB", "rank", "factors MiB", "compression", "K advised (2 %)",
             "search s", "M s", "SVD s", "total s"],
            [[r["brdf"], r["m_by"], r["normal_res"], f"{r['rows']} x {r['columns']}",
              f"{r['matrix_bytes'] / 2**20:.1f}", r["rank"], f"{r['factor_bytes'] / 2**20:.2f}",
              f"{r['matrix_bytes'] / r['factor_bytes']:.0f}:1",
              f"{r['directions_advised']}{'' if r['direction_met'] else ' (not met)'}",
              f"{r['stages_s'].get('search', 0):.2f}",
              f"{r['stages_s'].get('color', 0) + r['stages_s'].get('matrix', 0):.2f}",
              f"{r['stages_s'].get('svd', 0):.2f}", f"{r['time_s']:.2f}"] for r in pre])
    fam = [r for r in records if r["part"] == "families"]
    if fam:
        r0 = fam[0]
        lines += ["", f"Cook–Torrance m = 0.2, K = {r0['K']}, {r0['facets']} facets, against a {r0['gt_facets']}-facet "
                  "ground truth (PSNR of the cosine-weighted f̄ over every pair, Wu Table 4's metric; his: 17.4–22.7 "
                  "dB). Bake: median of whole bakes, a new facet seed each (the matrix bake with M's factors "
                  "precomputed; ASG: J = 8 ASG lobes, fitted on the host); memory: SG and ASG the material's "
                  "amplitude table, matrix N's + M's factors; edit: "
                  "`with_materials` to Ward α = 0.3 (factors cached)", ""]
        rows = []
        for tile in dict.fromkeys(r["tile"] for r in fam):
            for backend in dict.fromkeys(r["backend"] for r in fam):
                by = {r["method"]: r for r in fam if r["tile"] == tile and r["backend"] == backend}
                if "sg" not in by or "matrix" not in by:
                    continue
                s, m, a = by["sg"], by["matrix"], by.get("asg")

                def of_asg(fmt, key, scale=1.0):
                    return "—" if a is None else fmt.format(a[key] * scale)
                rows.append([tile, backend, f"{s['psnr']:.1f}", of_asg("{:.1f}", "psnr"), f"{m['psnr']:.1f}",
                             f"{s['time_s'] * 1e3:.0f}", of_asg("{:.0f}", "time_s", 1e3), f"{m['time_s'] * 1e3:.0f}",
                             f"{s['bytes'] / 2**10:.0f}", of_asg("{:.0f}", "bytes", 2**-10),
                             f"{m['n_factor_bytes'] / 2**10:.0f} + {m['m_factor_bytes'] / 2**10:.0f}",
                             f"{m['bins']} / {m['n_ranks']} / {m['m_rank']}",
                             f"{s['edit_s'] * 1e3:.2f}", of_asg("{:.2f}", "edit_s", 1e3), f"{m['edit_s'] * 1e3:.2f}"])
        lines += common.markdown_table(["tile", "backend", "SG dB", "ASG dB", "matrix dB", "SG bake ms",
                                        "ASG bake ms", "matrix bake ms", "SG KiB", "ASG KiB", "matrix KiB (N + M)",
                                        "bins / N ranks / M rank", "SG edit ms", "ASG edit ms", "matrix edit ms"],
                                       rows)
    return "\n".join(lines) + "\n"


def plot(records, folder):
    fam = [r for r in records if r["part"] == "families"]
    if not fam:
        return
    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for method, marker in (("sg", "o"), ("asg", "^"), ("matrix", "s")):
        rs = [r for r in fam if r["method"] == method]
        ax.scatter([r["time_s"] * 1e3 for r in rs], [r["psnr"] for r in rs], marker=marker, label=method)
        for r in rs:
            ax.annotate(f"{r['tile']} ({r['backend'].split(':')[0]})", (r["time_s"] * 1e3, r["psnr"]), fontsize=6)
    ax.axhline(17.36, color="grey", lw=0.8, label="Wu Table 4's lowest PSNR")
    ax.set_xscale("log")
    ax.set_xlabel("bake time (ms, median)")
    ax.set_ylabel("PSNR against the ground truth (dB)")
    ax.set_title("Matrix method vs SG and ASG bakes, Cook–Torrance m = 0.2")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "matrix.png"), dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=None, help="backend names (default: every usable backend here)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--parts", nargs="+", default=["precompute", "families"])
    ap.add_argument("--quick", action="store_true", help="a CPU: K = 8, 2^14 facets, a 2^16-facet truth, 3 runs")
    ap.add_argument("--directions", type=int, default=None, help="K (default 12; 8 with --quick)")
    ap.add_argument("--facets", type=int, default=None, help="bake facets (default 2^16; 2^14 with --quick)")
    ap.add_argument("--gt-facets", type=int, default=None, help="ground-truth facets (default 2^18; 2^16 with --quick)")
    ap.add_argument("--tiles", nargs="*", help="families (default all)")
    ap.add_argument("--brdfs", nargs="*", help=f"precompute BRDFs (default all: {list(PRECOMPUTE_BRDFS)})")
    ap.add_argument("--runs", type=int, default=None, help="timed runs (default 5; 3 with --quick)")
    args = ap.parse_args(argv)
    k = args.directions or (8 if args.quick else 12)
    facets = args.facets or (2**14 if args.quick else 2**16)
    gt_facets = args.gt_facets or (2**16 if args.quick else 2**18)
    runs = args.runs or (3 if args.quick else 5)
    backends = common.backend_names(args.backends)
    # M's factors go to a cache of this run's own, so that "precompute" and the timed bakes never read a
    # user's cache (the bakes read what this run computed); removed at the end.
    cache = tempfile.TemporaryDirectory(prefix="bench-matrix-factors-")
    os.environ["WARP_BISCALE_MATRIX_CACHE"] = cache.name
    out = common.Output(args.out, common.run_meta(
        backends=backends, device_kind=", ".join(sorted({wb.get_backend(b).device for b in backends})),
        openblas_threads=os.environ.get("OPENBLAS_NUM_THREADS"), K=k, facets=facets, gt_facets=gt_facets, runs=runs))
    if "precompute" in args.parts:
        brdfs = {n: PRECOMPUTE_BRDFS[n] for n in (args.brdfs or PRECOMPUTE_BRDFS)}
        part_precompute(backends, k, brdfs, out)
        out.save(table)
    if "families" in args.parts:
        fams = families()
        if args.tiles:
            fams = {n: fams[n] for n in args.tiles}
        part_families(backends, fams, k, facets, gt_facets, runs, out, lambda: out.save(table))
    out.finish(table)
    plot(out.records, args.out)
    cache.cleanup()
    out.log(f"wrote {args.out}/results.json, table.md, matrix.png")


if __name__ == "__main__":
    main()
