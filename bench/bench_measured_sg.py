"""Measured BRDFs in the SG bake (issue 21 item 2): the SG fit's time and error per table, then the SG bake of
each table on every tile family, its time against its error.

Tables (`MeasuredBRDF.from_brdf`, written by the benchmark itself: nothing is downloaded): a tabulated coloured
Cook–Torrance (m = 0.2), the synthetic paint (`measured.paint_like`: Lambertian base, broad sheen, sharp coat)
and a tabulated Blinn–Phong n = 128 (energy normalisation; not a microfacet BRDF, so one microfacet lobe holds
it badly). Per table: `fit_sg`'s seconds (one fit; deterministic) and its relative L2 error, with one lobe and with
lobes="auto" (two where they bring the error to TWO_LOBE_GAIN of one lobe's), its sums on the host (float64) and
in each backend's `sgfit` kernels (`--fits-only`: these alone).

Per table × family (bench_bake.families) × backend: `wb.bake(tile, table, lobes=J, directions=K,
facets=2^f)` — the fit is made once, before, so the bake's time is the bake's — and its PSNR (`wb.compare`,
Wu's metric) against the table's own ground truth (`wb.ground_truth` of the table: the truth kernels look
it up; 2^g facets); beside it the PSNR of the same bake against the ground truth of the fitted lobes (the sum
of each lobe's truth on the same facets: the truth is linear in the BRDF), i.e. the bake's own error without
the fit's, so that the difference is what the fit costs. A table whose "auto" fit has two lobes is baked
with its one-lobe fit too (the same bake, `with_materials`), so that the second lobe's gain shows.

    python -m bench.bench_measured_sg --out bench/results/measured-sg-cpu-2core
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
import warnings

import warp_biscale as wb
from warp_biscale import measured as ms

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402
from bench.bench_bake import families  # noqa: E402


def tables():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wb.EnergyWarning)
        cook = wb.CookTorrance((0.6, 0.5, 0.4), 0.2, kd=(0.2, 0.1, 0.05))
        return {"cooktorrance0.2": wb.MeasuredBRDF.from_brdf(cook),
                "paint": ms.paint_like(),
                "blinnphong128": wb.MeasuredBRDF.from_brdf(wb.BlinnPhong(0.6, 128, kd=0.2, normalization="energy"))}


def fits(out, named, backends):
    """Each table's fits (one lobe, then lobes="auto") on the host (float64 sums) and with their sums in each
    backend's `sgfit` kernels (after an untimed fit that compiles and loads them); the host's fits are the ones
    the bakes then use: → {table name: {1: one-lobe fit, "auto": the auto fit}}."""
    kept = {}
    for where in [None, *backends]:
        be = None if where is None else wb.get_backend(where)
        if be is not None:
            ms.fit_sg(next(iter(named.values())), be, lobes=1)  # (warm-up: kernels compiled and loaded)
        for name, table in named.items():
            for lobes in (1, "auto"):
                fit = ms.fit_sg(table, be, lobes=lobes)
                if be is None:
                    kept.setdefault(name, {})[lobes] = fit
                out.records.append({"kind": "fit", "table": name, "where": fit.backend, "lobes_asked": lobes,
                                    "seconds": fit.seconds, "error": fit.error, "one_lobe_error": fit.one_lobe_error,
                                    "samples": fit.samples, "lobes": fit.to_dict()["lobes"]})
                out.log(f"fit {name:>16} ({fit.backend}, lobes={lobes}): {fit.seconds:.2f} s, relative L2 error "
                        f"{fit.error:.3g} ({fit!r})")
    return kept


def with_fit(table, fit):
    """A copy of `table` (the same array) whose SG form is `fit`."""
    out = table.with_interpolation(table.interpolation)
    out._sg_fit, out._sg_fit_lobes = fit, len(fit.lobes)
    return out


class _SummedTruth:
    """What `wb.compare` reads of a ground truth (its table and grid), for the sum of the fitted lobes' truths."""

    def __init__(self, truths):
        self.table = sum(t.table for t in truths)
        self.directions = truths[0].directions


def bakes(out, named, kept, backends, lobes, k, facets, truth_facets):
    # A bake keeps its tile's geometry per facet seed: every timed bake gets a seed of its own, so that it
    # makes the geometry again rather than only the tables of a material edit.
    seeds = itertools.count(1)
    for be_name in backends:
        be = wb.get_backend(be_name)
        for tile_name, tile in families().items():
            for name, table in named.items():
                auto = with_fit(table, kept[name]["auto"])
                mats = [auto] * tile.n_materials
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    wb.bake(tile, mats, lobes=lobes, directions=k, facets=facets, backend=be, seed=next(seeds))
                    t0 = time.perf_counter()  # (after a warm-up bake: compiled kernels, uploaded buffers)
                    mat = wb.bake(tile, mats, lobes=lobes, directions=k, facets=facets, backend=be, seed=next(seeds))
                    bake_s = time.perf_counter() - t0
                    truth = wb.ground_truth(tile, mats, directions=k, facets=truth_facets, backend=be)
                    variants = [(len(kept[name]["auto"].lobes), mat)]
                    if len(kept[name]["auto"].lobes) > 1:
                        variants.append((1, mat.with_materials([with_fit(table, kept[name][1])] * tile.n_materials)))
                    for n_lobes, baked in variants:
                        fit = kept[name]["auto" if n_lobes > 1 else 1]
                        truth_fit = _SummedTruth([wb.ground_truth(tile, [lobe] * tile.n_materials, directions=k,
                                                                  facets=truth_facets, backend=be)
                                                  for lobe in fit.lobes])
                        psnr = wb.compare(baked, truth)["psnr"]
                        psnr_fit = wb.compare(baked, truth_fit)["psnr"]
                        out.records.append({"kind": "bake", "backend": be_name, "tile": tile_name, "table": name,
                                            "fit_lobes": n_lobes, "bake_s": bake_s, "psnr_table_db": psnr,
                                            "psnr_fit_db": psnr_fit, "J": lobes, "K": k, "facets": facets,
                                            "truth_facets": truth_facets})
                        out.log(f"{be_name:>24} {tile_name:>12} {name:>16} ({n_lobes} lobe fit): bake "
                                f"{bake_s * 1e3:7.1f} ms, PSNR against the table's truth {psnr:5.1f} dB, against "
                                f"the fit's {psnr_fit:5.1f} dB")
                out.save(table_md)


def table_md(records, meta) -> str:
    bakes_run = any(r["kind"] == "bake" for r in records)
    lines = [common.commit_line(meta), "",
             "SG fits of tabulated BRDFs (one fit each, its sums on the host in float64 or in a backend's kernels)"
             + (f", then SG bakes (J = {meta['J']}, K = {meta['K']}, {meta['facets']} facets, the bake's own time "
                f"after a warm-up bake of another seed) judged against the table's ground truth and the fitted "
                f"BRDF's ({meta['truth_facets']} facets)." if bakes_run else "."), ""]
    def rgb(x):
        return "/".join(f"{v:.3g}" for v in x)

    fit_rows = [[r["table"], r.get("where", "host"), str(r["lobes_asked"]), str(len(r["lobes"])),
                 f"{r['seconds']:.2f}", f"{r['error']:.3g}", "; ".join(f"{b['roughness']:.4g}" for b in r["lobes"]),
                 "; ".join(f"{b['f0']:.3g}" for b in r["lobes"]), rgb(r["lobes"][0]["kd"]),
                 "; ".join(rgb(b["ks"]) for b in r["lobes"])] for r in records if r["kind"] == "fit"]
    lines += common.markdown_table(["table", "sums on", "lobes asked", "lobes", "fit (s)", "relative L2 error", "m",
                                    "f0", "kd", "ks"], fit_rows) + [""]
    bake_rows = [[r["backend"], r["tile"], r["table"], str(r["fit_lobes"]), f"{r['bake_s'] * 1e3:.1f}",
                  f"{r['psnr_table_db']:.1f}", f"{r['psnr_fit_db']:.1f}"] for r in records if r["kind"] == "bake"]
    if bake_rows:
        lines += common.markdown_table(["backend", "tile", "table", "fit lobes", "bake (ms)",
                                        "PSNR vs table truth (dB)", "PSNR vs fit truth (dB)"], bake_rows)
    return "\n".join(lines) + "\n"


def plot(records, folder):
    """Bake time against PSNR (vs the table's truth), one marker per table, one point per family and backend."""
    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    bakes_ = [r for r in records if r["kind"] == "bake"]
    for (name, n_lobes), marker in zip(sorted({(r["table"], r["fit_lobes"]) for r in bakes_}), "os^vDP"):
        rs = [r for r in bakes_ if (r["table"], r["fit_lobes"]) == (name, n_lobes)]
        ax.scatter([r["bake_s"] * 1e3 for r in rs], [r["psnr_table_db"] for r in rs], marker=marker,
                   label=f"{name} ({n_lobes}-lobe fit)")
        for r in rs:
            ax.annotate(r["tile"], (r["bake_s"] * 1e3, r["psnr_table_db"]), fontsize=6)
    ax.set_xlabel("bake (ms)")
    ax.set_ylabel("PSNR against the table's ground truth (dB)")
    ax.set_title("Measured BRDFs through their SG fit: SG bake time against error")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "measured_sg.png"), dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="*", help="default: every usable backend")
    ap.add_argument("--lobes", type=int, default=8)
    ap.add_argument("--directions", type=int, default=8)
    ap.add_argument("--facets", type=int, default=1 << 14)
    ap.add_argument("--truth-facets", type=int, default=1 << 16)
    ap.add_argument("--out", default=os.path.join(common.HERE, "results", "measured-sg"))
    ap.add_argument("--fits-only", action="store_true", help="the fits alone, no bakes")
    args = ap.parse_args(argv)
    backends = common.backend_names(args.backends)
    meta = common.run_meta(J=args.lobes, K=args.directions, facets=args.facets, truth_facets=args.truth_facets,
                           backends=backends)
    out = common.Output(args.out, meta)
    out.log(common.commit_line(meta))
    named = tables()
    kept = fits(out, named, backends)
    out.save(table_md)
    if not args.fits_only:
        bakes(out, named, kept, backends, args.lobes, args.directions, args.facets, args.truth_facets)
    out.finish(table_md)
    if not args.fits_only:
        plot(out.records, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
