"""How many taps an ASG lookup takes (`shading.asg_prefiltered`, `shading.tap_plan`): for 400 random lobes (axes
anywhere, narrow deviation 2–25° over the aspect, aspect 1–2.5) under the studio and the sky, the relative L1 error of
the mean radiance read from the prefiltered maps against a dense quadrature of the map itself (every texel), for the
taps `tap_plan` asks and for 12 even taps over ±TAP_SPAN spreads (the rule before it), per aspect band, with the
mean tap count. Float64 host code; writes a JSON and prints a table.

    python -m bench.study_asg_taps bench/results/asg-taps-cpu-<commit>.json
"""

import json
import sys

import numpy as np

import warp_biscale as wb
from warp_biscale import lighting, sg, shading
from warp_biscale.lighting import prefiltered_lookup

BANDS = ((1.0, 1.1), (1.1, 1.2), (1.2, 1.35), (1.35, 1.5), (1.5, 2.0), (2.0, 2.5))


def even_taps(maps, levels, x, y, z, lam, mu, count=12):
    """The lookup with `count` even taps over ±TAP_SPAN spreads whatever the aspect (one where round)."""
    long = np.where((lam <= mu)[:, None], x, y)
    var_long = 0.5 / np.minimum(lam, mu)
    var_tap = np.maximum(0.5 / np.maximum(lam, mu), shading.ASG_TAP_SHARE * var_long)
    spread = np.sqrt(np.maximum(var_long - var_tap, 0.0))
    nodes = np.linspace(-shading.TAP_SPAN, shading.TAP_SPAN, count)
    weights = np.exp(-nodes**2 / 2) / np.exp(-nodes**2 / 2).sum()
    out = np.zeros((len(z), 3))
    for node, weight in zip(nodes, weights):
        d = z + (node * spread)[:, None] * long
        out += weight * prefiltered_lookup(maps, levels, d / np.linalg.norm(d, axis=1, keepdims=True),
                                           np.minimum(1.0 / var_tap, sg.SHARPNESS_MAX))
    return out


def study(env, m=400, seed=1):
    pre = lighting.prefilter(env)
    texels = env.directions().reshape(-1, 3)
    solid = env.solid_angles().reshape(-1)
    radiance = env.radiance.reshape(-1, 3).astype(np.float64)
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(m, 3))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    a = rng.normal(size=(m, 3))
    x = a - (a * z).sum(1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    aspect = np.exp(rng.uniform(0, np.log(2.5), m))
    narrow = np.radians(rng.uniform(2, 25, m)) / aspect
    lam, mu = 0.5 / narrow**2, 0.5 / (narrow * aspect) ** 2
    exact = np.zeros((m, 3))
    for i in range(m):
        g = texels @ z[i]
        g = np.where(g > 0, g * np.exp(-lam[i] * (texels @ x[i]) ** 2 - mu[i] * (texels @ y[i]) ** 2), 0.0) * solid
        exact[i] = g @ radiance / g.sum()
    var_long = 0.5 / np.minimum(lam, mu)
    var_tap = np.maximum(0.5 / np.maximum(lam, mu), shading.ASG_TAP_SHARE * var_long)
    count, _ = shading.tap_plan(np.sqrt(np.maximum(var_long - var_tap, 0.0) / var_tap))

    def error(out):
        return np.abs(out - exact).sum(1) / exact.sum(1)

    planned = error(shading.asg_prefiltered(pre.maps, pre.levels, x, y, z, lam, mu))
    even = error(even_taps(pre.maps, pre.levels, x, y, z, lam, mu))
    rows = []
    for lo, hi in BANDS:
        sel = (aspect >= lo) & (aspect < hi)
        rows.append({"aspect": [lo, hi], "lobes": int(sel.sum()), "planned_error": float(planned[sel].mean()),
                     "even12_error": float(even[sel].mean()), "planned_taps": float(count[sel].mean())})
    return {"environment": env.name, "lobes": m, "planned_error": float(planned.mean()),
            "planned_error_p95": float(np.percentile(planned, 95)), "even12_error": float(even.mean()),
            "even12_error_p95": float(np.percentile(even, 95)), "planned_taps": float(count.mean()), "bands": rows}


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else None
    results = [study(wb.Environment.studio()), study(wb.Environment.sky())]
    for r in results:
        print(f"{r['environment']}: planned {100 * r['planned_error']:.2f} % (p95 {100 * r['planned_error_p95']:.2f}) "
              f"at {r['planned_taps']:.2f} taps; 12 even {100 * r['even12_error']:.2f} % "
              f"(p95 {100 * r['even12_error_p95']:.2f})")
        print("| aspect | lobes | planned | taps | 12 even |\n| --- | --- | --- | --- | --- |")
        for b in r["bands"]:
            print(f"| {b['aspect'][0]}–{b['aspect'][1]} | {b['lobes']} | {100 * b['planned_error']:.2f} % | "
                  f"{b['planned_taps']:.1f} | {100 * b['even12_error']:.2f} % |")
    if out:
        with open(out, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
