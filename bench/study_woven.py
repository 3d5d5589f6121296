"""Why the woven tile's SG bake is inaccurate: float64 oracle study (one ingredient replaced at a time).

Nothing runs on the device beyond facets + visibility (--backend, PoCL by default); the rest is float64
numpy on the same 2^16 facets, compared with a ground truth of 2^18 facets at K = 12 (cached under --cache).

    python -m bench.study_woven --part floor solve weights lobes local --family woven
    python -m bench.study_woven --facets 4096 --gt-facets 16384 --cache /tmp/wv-smoke     # a smoke test

Parts:
- floor:   exact visibility-weighted NDF (the facets themselves) with the SG small-scale BRDF
           (Σ_s γ̃_s M G(n_s; h, η_s)): the error no lobe set can remove.
- solve:   the bake's lobes, amplitudes by (a) the bake's calibrated solve + energy rescale,
           (b) plain least squares, (c) clamped, (d) clamped + energy rescale.
- weights: EM on the NDF weighted by area, area × any visibility, area × Σ_k P_sk (the bake's
           visibility weighting), area × Σ_i P_si Σ_o P_so / a_v(o); J = 8, 16.
- lobes:   J = 16, 32, 64, 128 isotropic lobes, fitted and solved in numpy.
- local:   per-pair weighted least squares, weight W_h(n) = exp(η_w(n·h − 1)) around the pair's half
           vector (per-pair J×J Gram of SG triple products); clamp, with / without the per-lobe
           calibration of `lobes.amplitude_system`, with / without the energy rescale.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import warp_biscale as wb
from warp_biscale import directions as dirs
from warp_biscale import lobes as L
from warp_biscale import reference as ref
from warp_biscale import sg

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.bench_bake import BRDFS, families  # noqa: E402


def setup(tile, K, F, backend, seed=0):
    grid = dirs.grid(K)
    be = wb.get_backend(backend)
    fac = be.sample_facets(tile, F, seed)
    vis = be.visibility(tile, fac, grid).as_bool()
    d = fac.as_dict()
    proj = vis * np.maximum(grid @ d["normal"].T, 0.0)
    a_v = proj @ d["area"]
    return dict(fac=fac, d=d, vis=vis, grid=grid, proj=proj, a_v=a_v, K=K, tile=tile)

def moments(S, g):
    """(nd, nd, C) Σ_s P_si P_so g_s[c] / a_v(o)."""
    proj = S["proj"]
    nd = len(proj)
    out = np.empty((nd, nd, g.shape[1]))
    for i in range(nd):
        out[i] = (proj * proj[i][None]) @ g
    return out / np.maximum(S["a_v"], 1e-300)[None, :, None]

def spec(S, brdf):
    g = S["grid"]
    nd = len(g)
    pi, po = dirs.all_pairs(nd)
    eta_s, scale, h = sg.specular_lobe(brdf, g[pi], g[po])
    return eta_s, scale[:, 0].reshape(nd, nd), h.reshape(nd, nd, 3)

def fbar_from_mu(S, brdf, lob, mu, method="sg"):
    """mu (nd, nd, J) → f̄ (nd, nd) scalar (ks=1 white)."""
    eta_s, scale, h = spec(S, brdf)
    ax, eta = lob.axes, lob.sharpness
    if method == "sg":
        eta_c, amp_c = sg.convolve(eta, 1.0, eta_s, 1.0)
        s = sg.evaluate(h[..., None, :], ax, eta_c, amp_c)
    else:
        s = sg.inner_product(h[..., None, :], eta_s, 1.0, ax, eta, 1.0)
    return scale * np.einsum("ioj,ioj->io", mu, s)

def fbar_exact_ndf(S, brdf):
    """Exact γ̃ (facets) with the SG small-scale BRDF: Σ_s γ̃_s M G(n_s; h, η_s)."""
    eta_s, scale, h = spec(S, brdf)
    proj, n, w = S["proj"], S["d"]["normal"], S["d"]["area"]
    nd = len(proj)
    out = np.empty((nd, nd))
    for i in range(nd):
        G = np.exp(-eta_s * (1 - h[i] @ n.T))  # (nd, Ns)
        out[i] = ((proj * proj[i][None] * w[None]) * G).sum(1)
    return out * scale / np.maximum(S["a_v"], 1e-300)[None, :]


def psnr(est, gt):
    ref_ = gt
    diff = est - ref_
    rmse = np.sqrt(np.mean(diff**2))
    peak = ref_.max()
    big = ref_ >= 0.01 * peak
    return 20 * np.log10(peak / rmse), np.max(np.abs(diff[big]) / ref_[big])

def fit_lobes_w(S, J, weight, iters=30, r=128, init_r=16):
    d = S["d"]
    bins = ref.cube_bin(d["normal"], r)
    u, inv = np.unique(bins, return_inverse=True)
    area = np.bincount(inv, weights=weight)
    mean = np.stack([np.bincount(inv, weights=d["area"] * d["normal"][:, c]) for c in range(3)], 1)
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    keep = area > 0
    mean, area = mean[keep], area[keep]
    start = L.initial_lobes(mean, area, J, init_r)
    axes, sharp, lobe_weight, _ = ref.ndf_em(d["normal"], weight, start.axes, start.sharpness, start.weight, iters)
    return L.LobeSet(axes, sharp, lobe_weight).alive(), mean, area

def solve_variants(S, lob, mean, area, weight=None):
    d = S["d"]
    J = len(lob)
    G = ref.lobe_values(d["normal"], lob.axes, lob.sharpness) * d["area"][:, None]
    g = np.concatenate([G, d["area"][:, None]], 1)
    m = moments(S, g)
    b, c = m[..., :J], m[..., J]
    ax, eta = lob.axes, lob.sharpness
    gram = sg.inner_product(ax[:, None, :], eta[:, None], 1.0, ax[None, :, :], eta[None, :], 1.0)
    integrals = sg.integral(eta)
    rows = L.amplitude_system(lob, mean, area)[0]
    out = {}
    dd = np.sqrt(np.diag(gram))
    inv_raw = np.linalg.inv(gram / np.outer(dd, dd) + 1e-6 * np.eye(J)) / np.outer(dd, dd)
    def energy(mu):
        mu = np.maximum(mu, 0)
        tot = mu @ integrals
        return np.where(tot[..., None] > 0, mu * (c / np.where(tot > 0, tot, 1))[..., None], 0)
    if rows is not None:
        out["calib+energy(bake)"] = energy(b @ rows.T)
    out["raw LS clamp"] = np.maximum(b @ inv_raw.T, 0)
    out["raw LS clamp+energy"] = energy(b @ inv_raw.T)
    return out

def local_system(S, lob, eta_w):
    """Per pair: A^h (nd, nd, J, J) = ∫G_i G_j W_h, b^h (nd, nd, J), c (nd, nd)."""
    g = S["grid"]
    nd = len(g)
    J = len(lob)
    ax, eta = lob.axes, lob.sharpness
    pi, po = dirs.all_pairs(nd)
    h = g[pi] + g[po]
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    h = h.reshape(nd, nd, 3)
    pax, pd, pamp = sg.product(ax[:, None, :], np.broadcast_to(eta[:, None], (J, J)), 1.0, ax[None, :, :],
                               np.broadcast_to(eta[None, :], (J, J)), 1.0)
    A = sg.inner_product(h[:, :, None, None, :], eta_w, 1.0, pax, pd, pamp)  # (nd, nd, J, J)
    proj, n, w = S["proj"], S["d"]["normal"], S["d"]["area"]
    G = ref.lobe_values(n, ax, eta) * w[:, None]
    b = np.empty((nd, nd, J))
    c = np.empty((nd, nd))
    for i in range(nd):
        PP = proj * proj[i][None]
        Wh = np.exp(-eta_w * (1 - h[i] @ n.T))
        b[i] = (PP * Wh) @ G
        c[i] = PP @ w
    b /= np.maximum(S["a_v"], 1e-300)[None, :, None]
    c /= np.maximum(S["a_v"], 1e-300)[None, :]
    return A, b, c

def local_solve(A, b, c, integrals, mode, ridge=1e-6):
    J = A.shape[-1]
    d = np.sqrt(np.einsum("...jj->...j", A))
    An = A / (d[..., :, None] * d[..., None, :]) + ridge * np.eye(J)
    bn = b / d
    if mode == "eq":  # min ||.||_A s.t. μ·I = c  (KKT)
        In = integrals / d
        K1 = np.concatenate([np.concatenate([An, In[..., :, None]], -1),
                             np.concatenate([In[..., None, :], np.zeros(In.shape[:-1] + (1, 1))], -1)], -2)
        rhs = np.concatenate([bn, c[..., None]], -1)
        y = np.linalg.solve(K1, rhs[..., None])[..., 0]
        mu = y[..., :J] / d
        return np.maximum(mu, 0)
    mu = np.linalg.solve(An, bn[..., None])[..., 0] / d
    if mode == "clamp":
        return np.maximum(mu, 0)
    mu = np.maximum(mu, 0)
    tot = mu @ integrals
    return np.where(tot[..., None] > 0, mu * (c / np.where(tot > 0, tot, 1))[..., None], 0)


def ground_truths(fam, tile, k, facets, cache, backend):
    os.makedirs(cache, exist_ok=True)
    out = {}
    for bn, brdf in BRDFS.items():
        path = os.path.join(cache, f"{fam}_{bn}_K{k}_{facets}.npz")
        if os.path.exists(path):
            gt = wb.load(path)
        else:
            gt = wb.ground_truth(tile, [brdf] * tile.n_materials, facets=facets, directions=k, backend=backend)
            gt.save(path)
        out[bn] = gt.table[..., 0].astype(np.float64)
    return out


def scores(S, lob, mu, gts):
    return " ".join(f"{bn[:5]} {psnr(fbar_from_mu(S, b, lob, mu), gts[bn])[0]:.2f}" for bn, b in BRDFS.items())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", nargs="+", default=["floor", "solve", "weights", "lobes", "local"])
    ap.add_argument("--family", default="woven")
    ap.add_argument("--directions", type=int, default=12)
    ap.add_argument("--facets", type=int, default=1 << 16)
    ap.add_argument("--gt-facets", type=int, default=1 << 18)
    ap.add_argument("--eta-w", type=float, nargs="+", default=[10.0, 30.0, 50.0])
    ap.add_argument("--cache", default="/tmp/wv/gt", help="folder of the cached ground truths")
    ap.add_argument("--backend", default="opencl", help="backend of the facets, visibility and ground truths")
    a = ap.parse_args()
    tile = families()[a.family]
    S = setup(tile, a.directions, a.facets, a.backend)
    gts = ground_truths(a.family, tile, a.directions, a.gt_facets, a.cache, a.backend)
    d, P = S["d"], S["proj"]
    if "floor" in a.part:
        for bn, brdf in BRDFS.items():
            print(f"floor {bn}: exact NDF + SG BRDF psnr {psnr(fbar_exact_ndf(S, brdf), gts[bn])[0]:.2f}", flush=True)
    if "solve" in a.part:
        for j in (8, 16):
            mat = wb.bake(tile, [BRDFS["blinnphong512"]] * tile.n_materials, lobes=j, directions=a.directions,
                          facets=a.facets, backend=a.backend)
            # Calibrated on the bins' bare areas (mat.bvndf.area), where the bake calibrates on the bins
            # weighted by what the grid sees: the "(bake)" row is the bake's solve on the bare NDF.
            for name, mu in solve_variants(S, mat.lobes, mat.bvndf.normal, mat.bvndf.area).items():
                print(f"solve J={j} {name:22s} {scores(S, mat.lobes, mu, gts)}", flush=True)
    if "weights" in a.part:
        a_v = S["a_v"]
        wts = {"area": d["area"], "visible-any": d["area"] * (P > 0).any(0), "sumP": d["area"] * P.sum(0),
               "sumP*sumP/av": d["area"] * P.sum(0) * (P / np.maximum(a_v, 1e-300)[:, None]).sum(0)}
        for wn, w in wts.items():
            for j in (8, 16):
                lob, mean, area = fit_lobes_w(S, j, w)
                for name, mu in solve_variants(S, lob, mean, area).items():
                    print(f"weights {wn:13s} J={j} {name:22s} {scores(S, lob, mu, gts)}", flush=True)
    if "lobes" in a.part:
        for j in (16, 32, 64, 128):
            lob, mean, area = fit_lobes_w(S, j, d["area"] * P.sum(0), init_r=32)
            for name, mu in solve_variants(S, lob, mean, area).items():
                print(f"lobes J={j} (sumP EM) {name:22s} {scores(S, lob, mu, gts)}", flush=True)
    if "local" in a.part:
        lob, mean, area = fit_lobes_w(S, 16, d["area"])
        integrals = sg.integral(lob.sharpness)
        rows, _, gram, _ = L.amplitude_system(lob, mean, area)
        dd = np.sqrt(np.diag(gram))
        inv = np.linalg.inv(gram / np.outer(dd, dd) + L.RIDGE * np.eye(len(lob))) / np.outer(dd, dd)
        scale = np.diag(rows @ np.linalg.inv(inv))  # rows = diag(scale) · A⁻¹
        for eta_w in a.eta_w:
            A, b, c = local_system(S, lob, eta_w)
            mu = local_solve(A, b, c, integrals, "clamp")
            for name, m in (("clamp", mu), ("clamp+cal", mu * scale)):
                tot = m @ integrals
                me = np.where(tot[..., None] > 0, m * (c / np.where(tot > 0, tot, 1))[..., None], 0)
                print(f"local eta_w={eta_w:g} {name:10s} {scores(S, lob, m, gts)} | +energy {scores(S, lob, me, gts)}",
                      flush=True)


if __name__ == "__main__":
    main()
