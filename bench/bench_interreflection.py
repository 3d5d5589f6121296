"""Small-scale interreflection benchmark: how much energy the single-bounce ground truth misses, per tile family.

For each procedural tile family (bench_bake.families: pyramid, V- and U-grooves, rods, woven, height field)
and small-scale BRDF (Lambert kd = 1 and 0.8; Cook–Torrance m = 0.2, ks = 1), `wb.ground_truth(..., bounces=B)` at
B = 1, 2, 4 (docs/design.md §4.6) on a K × K grid: the directional albedo ∫f̄ dωi averaged over the K² ωo
(`GroundTruth.albedo`), interreflection's share of it, (albedo_B − albedo_1)/albedo_B, and the time of the
interreflection stage (device-synchronised, one run: these are seconds-long Monte Carlo runs, not timings to
the millisecond).

    python -m bench.bench_interreflection --out bench/results/interreflection-cpu-2core    # a CPU
    python -m bench.bench_interreflection --backends warp:cuda --directions 12 --paths 4096 --out $OUT
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

import warp_biscale as wb

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402
from bench.bench_bake import families  # noqa: E402  (the tile families every bake benchmark uses)

# white Lambert: the furnace (a tile that absorbs nothing would return albedo 1 as B → ∞); the bake benches'
# Cook–Torrance m = 0.2 (ks = 1, its default Fresnel F0)
BRDFS = {"lambert1.0": wb.Lambert(1.0), "lambert0.8": wb.Lambert(0.8), "cooktorrance0.2": wb.CookTorrance(1.0, 0.2)}
BOUNCES = (1, 2, 4)


def run(backends, fams, brdfs, k, facets, paths, out, save):
    for be_name in backends:
        be = wb.get_backend(be_name)
        for tname, tile in fams.items():
            for bname, mat in brdfs.items():
                base = None
                for b in BOUNCES:
                    t0 = time.perf_counter()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        gt = wb.ground_truth(tile, [mat] * tile.n_materials, facets=facets, directions=k,
                                             backend=be, bounces=b, paths=paths)
                    total = time.perf_counter() - t0
                    alb = gt.albedo().mean(axis=1)  # (K²,) grey: the mean of RGB
                    base = alb if base is None else base
                    share = float(np.mean(alb) - np.mean(base)) / max(float(np.mean(alb)), 1e-30)
                    rec = {"backend": be_name, "tile": tname, "triangles": int(len(tile.faces)), "brdf": bname,
                           "bounces": b, "K": k, "facets": facets, "paths": paths if b > 1 else 0,
                           "albedo_mean": float(alb.mean()), "albedo_min": float(alb.min()),
                           "albedo_max": float(alb.max()), "share": share,
                           "interreflection_s": float(gt.timings.get("interreflection", 0.0)), "total_s": total,
                           "finite": bool(np.isfinite(gt.table).all()), "nonnegative": bool((gt.table >= 0).all())}
                    out.records.append(rec)
                    out.log(f"{be_name:>24} {tname:>11} {bname:>16} B={b}: albedo {alb.mean():.4f} "
                            f"[{alb.min():.3f}, {alb.max():.3f}], share {100 * share:5.1f} %, "
                            f"interreflection {rec['interreflection_s']:.2f} s, total {total:.2f} s")
                    save()


def table(records, meta) -> str:
    lines = [common.commit_line(meta), "",
             f"Mean directional albedo over the K² ωo (K = {meta['K']}, {meta['facets']} facets, {meta['paths']} "
             "paths per pair for B > 1) and interreflection's share of it, (albedo_B − albedo_1)/albedo_B; "
             "time: the interreflection stage, one run, on a loaded machine.", ""]
    header = ["backend", "tile", "triangles", "BRDF"] + [f"albedo B={b}" for b in BOUNCES] + \
             [f"share B={b}" for b in BOUNCES[1:]] + [f"time B={b} (s)" for b in BOUNCES[1:]]
    rows = {}
    for r in records:
        key = (r["backend"], r["tile"], r["brdf"])
        rows.setdefault(key, {"triangles": r["triangles"]})[r["bounces"]] = r
    body = []
    for (be, tile, brdf), row in rows.items():
        cells = [be, tile, row["triangles"], brdf]
        cells += [f"{row[b]['albedo_mean']:.4f}" if b in row else "" for b in BOUNCES]
        cells += [f"{100 * row[b]['share']:.1f} %" if b in row else "" for b in BOUNCES[1:]]
        cells += [f"{row[b]['interreflection_s']:.2f}" if b in row else "" for b in BOUNCES[1:]]
        body.append(cells)
    lines += common.markdown_table(header, body)
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="*", help="default: every usable backend")
    ap.add_argument("--tiles", nargs="*", help="families (default all)")
    ap.add_argument("--directions", type=int, default=8, help="K of the direction grid (default 8)")
    ap.add_argument("--facets", type=int, default=1 << 14)
    ap.add_argument("--paths", type=int, default=2048, help="paths per direction pair for B > 1")
    ap.add_argument("--out", default=os.path.join(common.HERE, "results", "interreflection"))
    args = ap.parse_args(argv)
    backends = common.backend_names(args.backends)
    fams = families()
    if args.tiles:
        fams = {t: fams[t] for t in args.tiles}
    meta = common.run_meta(K=args.directions, facets=args.facets, paths=args.paths, backends=backends,
                           bounces=list(BOUNCES))
    out = common.Output(args.out, meta)
    out.log(common.commit_line(meta))
    run(backends, fams, BRDFS, args.directions, args.facets, args.paths, out, lambda: out.save(table))
    out.finish(table)


if __name__ == "__main__":
    main()
