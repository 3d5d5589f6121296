"""Measured-BRDF benchmark (issue 21 item 2): what a MERL table costs on the host and in the ground truth.

Host steps (median of `--runs` after a warm-up call): `MeasuredBRDF.save` and `MeasuredBRDF.load` of a
34 992 012-byte MERL file in a temporary folder (the read includes the header and finiteness checks; the OS's
page cache is warm after the write, so this is the parse, not the disk), `MeasuredBRDF.from_brdf`
(tabulating Cook–Torrance m = 0.2 at the 1.46 M bin centres) and `eval` of 1e6 direction pairs (random
directions on the upper hemisphere about random normals; float64, trilinear).

Ground truth, on each backend: `wb.ground_truth` of a procedural tile (`--tile`, one of bench_bake.families)
with the analytic Cook–Torrance m = 0.2 (ks = 1, its default Fresnel) and with its table, on the same facets
(same seed and count) and K: the median time of each (the table's first call also uploads its 17.5 MB:
`first_call_extra_s`), and the PSNR of the tabulated truth against the analytic one (`wb.compare`, Wu
Table 4's metric): the tabulation's own error, since everything else is shared.

    python -m bench.bench_measured --out bench/results/measured-cpu-2core          # a CPU
    python -m bench.bench_measured --backends warp:cuda opencl:nvidia --out $OUT     # a GPU
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import warnings

import numpy as np

import warp_biscale as wb

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402
from bench.bench_bake import families  # noqa: E402  (the tile families every bake benchmark uses)

ANALYTIC = wb.CookTorrance(1.0, 0.2)  # the bake benches' Cook–Torrance m = 0.2
PAIRS = 1_000_000


def _hemisphere(rng, n, normal):
    """n unit directions uniform on the hemisphere about each row of `normal` (n, 3)."""
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    return np.where((np.einsum("ij,ij->i", w, normal) < 0)[:, None], -w, w)


def host(out, runs):
    """The host steps: save, load, from_brdf, eval."""
    table = wb.MeasuredBRDF.from_brdf(ANALYTIC)
    with tempfile.TemporaryDirectory() as scratch:
        path = os.path.join(scratch, "ct.binary")
        t = common.timed(lambda: table.save(path), runs)
        size = os.path.getsize(path)
        _record(out, "save", t, bytes=size)
        t = common.timed(lambda: wb.MeasuredBRDF.load(path), runs)
        assert np.array_equal(t.last.data, table.data)  # the round trip is exact
        _record(out, "load", t, bytes=size)
    t = common.timed(lambda: wb.MeasuredBRDF.from_brdf(ANALYTIC), runs)
    _record(out, "from_brdf", t, bins=90 * 90 * 180)
    rng = np.random.default_rng(0)
    n = rng.normal(size=(PAIRS, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wi, wo = _hemisphere(rng, PAIRS, n), _hemisphere(rng, PAIRS, n)
    table.eval(n[:10], wi[:10], wo[:10])  # the filled table is made once, on the first eval: not timed here
    t = common.timed(lambda: table.eval(n, wi, wo), runs)
    _record(out, "eval", t, pairs=PAIRS)
    return table


def _record(out, step, t, backend="host", **extra):
    rec = {"step": step, "backend": backend, "median_s": t.median_s, "runs_s": t.runs_s,
           "first_call_extra_s": t.first_call_extra_s, **extra}
    out.records.append(rec)
    what = ", ".join(f"{k} {v}" for k, v in extra.items())
    out.log(f"{backend:>26} {step:>24}: {t.median_s:.4f} s median of {len(t.runs_s)} ({what}; first call "
            f"+{t.first_call_extra_s:.3f} s)")
    return rec


def truth(out, backends, table, tile_name, k, facets, runs):
    tile = families()[tile_name]
    for be_name in backends:
        be = wb.get_backend(be_name)
        gts = {}
        for name, brdf in (("analytic", ANALYTIC), ("tabulated", table)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # TileWarning of a family with one material id: none expected
                t = common.timed(lambda brdf=brdf: wb.ground_truth(tile, [brdf] * tile.n_materials, facets=facets,
                                                                   directions=k, backend=be), runs, be)
            gts[name] = t.last
            _record(out, f"ground_truth {name}", t, backend=be_name, tile=tile_name, K=k, facets=facets)
        c = wb.compare(gts["tabulated"], gts["analytic"])
        out.records[-1].update(psnr_db=c["psnr"], rmse=c["rmse"], max_rel_error=c["max_rel_error"])
        out.log(f"{be_name:>26} tabulated vs analytic truth: PSNR {c['psnr']:.1f} dB, RMSE {c['rmse']:.3g}, "
                f"max relative error {c['max_rel_error']:.3g} (entries >= 1 % of the peak {c['peak']:.3g})")


def table_md(records, meta) -> str:
    lines = [common.commit_line(meta), "",
             f"Median of {meta['runs']} runs after a warm-up call (device synchronised). Host: a "
             "MERL file of 34 992 012 bytes in a temporary folder; `eval` of 1e6 pairs. Ground truth: tile "
             f"{meta['tile']}, K = {meta['K']}, {meta['facets']} facets, Cook–Torrance m = 0.2 analytic and "
             "tabulated (`MeasuredBRDF.from_brdf`); PSNR of the tabulated truth against the analytic one.", ""]
    body = []
    for r in records:
        extra = ""
        if "psnr_db" in r:
            extra = f"PSNR {r['psnr_db']:.1f} dB, max rel. error {r['max_rel_error']:.2g}"
        elif "bytes" in r:
            extra = f"{r['bytes'] / r['median_s'] / 2**20:.0f} MiB/s"
        elif "pairs" in r:
            extra = f"{r['pairs'] / r['median_s'] / 1e6:.2f} M pairs/s"
        elif "bins" in r:
            extra = f"{r['bins'] / r['median_s'] / 1e6:.2f} M bins/s"
        body.append([r["backend"], r["step"], f"{r['median_s']:.3f}", f"{r['first_call_extra_s']:.3f}", extra])
    lines += common.markdown_table(["backend", "step", "median (s)", "first call extra (s)", "note"], body)
    return "\n".join(lines) + "\n"


def plot(records, folder):
    """Bars: each step's median time (log scale), host steps and each backend's two ground truths."""
    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.2))
    labels = [f"{r['step']}\n{r['backend']}" if r["backend"] != "host" else r["step"] for r in records]
    colors = ["tab:gray" if r["backend"] == "host" else "tab:orange" if "tabulated" in r["step"] else "tab:blue"
              for r in records]
    ax.bar(range(len(records)), [r["median_s"] for r in records], color=colors)
    ax.set_xticks(range(len(records)), labels, rotation=60, ha="right", fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("median time (s)")
    ax.set_title("MeasuredBRDF: host steps (grey); ground truth analytic (blue) vs tabulated (orange)")
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "measured.png"), dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="*", help="default: every usable backend")
    ap.add_argument("--tile", default="pyramid", help="tile family of the ground truths (default pyramid)")
    ap.add_argument("--directions", type=int, default=8, help="K of the ground truths' grid (default 8)")
    ap.add_argument("--facets", type=int, default=1 << 16, help="facets of the ground truths (default 2^16)")
    ap.add_argument("--runs", type=int, default=5, help="timed runs per step (default 5)")
    ap.add_argument("--out", default=os.path.join(common.HERE, "results", "measured"))
    args = ap.parse_args(argv)
    backends = common.backend_names(args.backends)
    meta = common.run_meta(K=args.directions, facets=args.facets, tile=args.tile, runs=args.runs, backends=backends)
    out = common.Output(args.out, meta)
    out.log(common.commit_line(meta))
    table = host(out, args.runs)
    out.save(table_md)
    truth(out, backends, table, args.tile, args.directions, args.facets, args.runs)
    out.finish(table_md)
    plot(out.records, args.out)


if __name__ == "__main__":
    main()
