"""Xu 2013's operator error plots, reproduced (issue 20 item 5): the ASG integral (Xu Fig. 3, and his bounds of
§4.1), the product of two ASGs (Eq. 13; Fig. 5 left, the second lobe's axis moved away from the first's) and the
convolution with an SG (Eq. 18; Fig. 5 right, against the kernel's bandwidth ν), each against brute-force
float64 quadrature on the sphere: tests/test_asg.py's oracle (a product Gauss–Legendre rule graded toward the
lobes, shown there to be accurate to < 1e−12 relative), imported from it so that the figures and the tests
measure with the same rule.

Error measures, as tests/test_asg.py defines them: the relative L2 over the sphere, and Xu's (the absolute L2
with both inputs normalised to unit integral, his Fig. 5 caption). Xu's three example pairs and kernels are
his Figs. 4 and 6 as tests/test_asg.py reads them. The device integrals (the kernels' float32 forms) are
compared with the float64 exact one on every usable backend. Records go to --out/results.json, the table to
table.md, the figures to operators.png.

    python -m bench.bench_asg_operators --out bench/results/asg-operators-cpu-2core      # about a minute
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

import warp_biscale as wb
from warp_biscale import asg

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
import test_asg as oracle  # noqa: E402  (the brute-force quadrature the tests validate)

INTEGRAL_MU = (1.0, 5.0, 20.0)  # Fig. 3's curves: one per μ, λ from μ up
PRODUCT_PAIRS = ((3.0, 3.0, 100.0, 5.0), (10.0, 1.0, 100.0, 10.0), (10.0, 1.0, 1000.0, 10.0))  # Xu Fig. 4
CONVOLUTION_ASGS = ((5.0, 5.0), (40.0, 1.0), (100.0, 10.0))  # Xu Fig. 6
CONVOLUTION_NU = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0)


def part_integral(out, backends):
    lam_grid = np.geomspace(1.0, 1e4, 41)
    for mu in INTEGRAL_MU:
        lam = lam_grid[lam_grid >= mu]
        exact = asg.unit_integral(lam, mu)
        for method in ("eq10", "eq11"):
            approx = asg.unit_integral(lam, np.full_like(lam, mu), method)
            rel = np.abs(approx / exact - 1.0)
            out.records.append({"part": "integral", "mu": mu, "method": method, "lam": lam.tolist(),
                                "exact": exact.tolist(), "approx": approx.tolist(), "rel_error": rel.tolist()})
    # Xu's bounds over the quadrant: λ, μ on a log grid above 1 and above 5.
    grid = np.geomspace(1.0, 1e4, 81)
    lam, mu = np.meshgrid(grid, grid, indexing="ij")
    keep = lam >= mu
    lam, mu = lam[keep], mu[keep]
    exact = asg.unit_integral(lam, mu)
    for method in ("eq10", "eq11"):
        rel = np.abs(asg.unit_integral(lam, mu, method) / exact - 1.0)
        for above in (1.0, 5.0):
            sel = (lam > above) & (mu > above)
            out.records.append({"part": "integral_bound", "method": method, "above": above,
                                "max_rel_error": float(rel[sel].max()), "points": int(sel.sum())})
    for name in backends:
        be = wb.get_backend(name)
        for method in ("exact", "eq10", "eq11"):
            got = np.asarray(be.asg_unit_integral(lam, mu, method), np.float64)
            want = exact if method == "exact" else asg.unit_integral(lam, mu, method)
            rel = np.abs(got / want - 1.0)
            out.records.append({"part": "integral_device", "backend": be.name, "device": be.device,
                                "method": method, "max_rel_error_vs_float64": float(rel.max()),
                                "points": int(len(lam))})


def part_product(out):
    for pair in PRODUCT_PAIRS:
        cosines = np.linspace(1.0, 0.1, 10)
        rel, xu = zip(*(oracle._product_errors(*pair, c, [1, 0, 0]) for c in cosines))
        out.records.append({"part": "product", "pair": list(pair), "cos12": cosines.tolist(), "rel_l2": list(rel),
                            "xu_l2": list(xu)})
        out.log(f"product {pair}: Xu-style L2 {min(xu):.4f} … {max(xu):.4f}, relative L2 {min(rel):.4f} … "
                f"{max(rel):.4f} over z1·z2 = 1 … 0.1")


def part_convolution(out):
    for lam, mu in CONVOLUTION_ASGS:
        rows = []
        for nu in CONVOLUTION_NU:
            t0 = time.perf_counter()
            rel, xu, peak = oracle._convolution_errors(lam, mu, nu)
            rows.append((rel, xu, float(peak), time.perf_counter() - t0))
        rel, xu, peak, secs = zip(*rows)
        out.records.append({"part": "convolution", "lam": lam, "mu": mu, "nu": list(CONVOLUTION_NU),
                            "rel_l2": list(rel), "xu_l2": list(xu), "peak_rel_error": list(peak)})
        out.log(f"convolution λ = {lam:g}, μ = {mu:g}: Xu-style L2 {min(xu):.4f} … {max(xu):.4f} over ν = "
                f"{CONVOLUTION_NU[0]:g} … {CONVOLUTION_NU[-1]:g} ({sum(secs):.0f} s of quadrature)")


def table(records, meta) -> str:
    lines = ["# Xu 2013's ASG operator errors, reproduced", "", common.commit_line(meta), "",
             "## The integral (Xu §4.1: Eq. 10 < 0.027 % and Eq. 11 < 0.68 % for λ, μ > 5; Eq. 10 < 5.2 % for "
             "λ, μ > 1)", ""]
    rows = [[r["method"], f"> {r['above']:g}", f"{100 * r['max_rel_error']:.4g} %", r["points"]]
            for r in records if r["part"] == "integral_bound"]
    lines += common.markdown_table(["form", "λ, μ", "largest relative error", "grid points"], rows)
    rows = [[r["backend"], r["method"], f"{r['max_rel_error_vs_float64']:.2e}"]
            for r in records if r["part"] == "integral_device"]
    if rows:
        lines += ["", "The device forms (float32 kernels) against the same forms in float64, over that grid:", ""]
        lines += common.markdown_table(["backend", "form", "largest relative difference"], rows)
    lines += ["", "## The product (Eq. 13; Xu Fig. 5 left): G2's axis tilted away from G1's", ""]
    rows = [[str(tuple(r["pair"])), f"{min(r['xu_l2']):.4f} … {max(r['xu_l2']):.4f}",
             f"{100 * min(r['rel_l2']):.2f} … {100 * max(r['rel_l2']):.2f} %"]
            for r in records if r["part"] == "product"]
    lines += common.markdown_table(["(λ1, μ1, λ2, μ2)", "Xu-style L2, z1·z2 = 1 … 0.1", "relative L2"], rows)
    lines += ["", "## The convolution with an SG (Eq. 18; Xu Fig. 5 right: < 0.2 % for λ, μ > 3 whatever ν)", ""]
    rows = []
    for r in records:
        if r["part"] == "convolution":
            rows += [[f"({r['lam']:g}, {r['mu']:g})", f"{nu:g}", f"{xu:.4f}", f"{100 * rel:.3f} %",
                      f"{100 * pk:+.3f} %"] for nu, xu, rel, pk in zip(r["nu"], r["xu_l2"], r["rel_l2"],
                                                                        r["peak_rel_error"])]
    lines += common.markdown_table(["(λ, μ)", "ν", "Xu-style L2", "relative L2", "at the peak"], rows)
    return "\n".join(lines) + "\n"


def plot(records, path):
    plt = common.pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    for r in records:
        if r["part"] == "integral":
            style = "-" if r["method"] == "eq10" else "--"
            ax[0].loglog(r["lam"], np.maximum(r["rel_error"], 1e-17), style,
                         label=f"{'Eq. 10' if r['method'] == 'eq10' else 'Eq. 11'}, μ = {r['mu']:g}")
        elif r["part"] == "product":
            ax[1].plot(r["cos12"], r["xu_l2"], "o-", label=f"({', '.join(f'{v:g}' for v in r['pair'])})")
        elif r["part"] == "convolution":
            ax[2].loglog(r["nu"], r["xu_l2"], "o-", label=f"λ = {r['lam']:g}, μ = {r['mu']:g}")
    ax[0].set(xlabel="λ", ylabel="relative error of the integral", title="Integral (Xu Fig. 3)")
    ax[1].set(xlabel="z1·z2", ylabel="L2 error, normalised inputs", title="Product, Eq. 13 (Xu Fig. 5 left)")
    ax[1].invert_xaxis()
    ax[2].set(xlabel="ν (SG kernel bandwidth)", ylabel="L2 error, normalised inputs",
              title="Convolution, Eq. 18 (Xu Fig. 5 right)")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7)
    common.save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--backends", nargs="*", help="device integrals on these backends (default: every usable one)")
    args = ap.parse_args(argv)
    out = common.Output(args.out, common.run_meta())
    part_integral(out, common.backend_names(args.backends))
    out.save(table)
    part_product(out)
    out.save(table)
    part_convolution(out)
    out.finish(table)
    plot(out.records, out.path("operators.png"))
    out.log(f"wrote {args.out}/results.json, table.md, operators.png")


if __name__ == "__main__":
    main()
