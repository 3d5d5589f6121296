"""The ASG bi-scale bake (issue 20 item 3; Xu 2013 §4–5 on Iwasaki 2012's pipeline): `wb.bake(tile, materials,
method="asg", lobes=J)` → `ASGBRDF`.

What it does, stage by stage (the geometry stages are the SG bake's own, `bake._sample_facets` …
`bake._fit_ndf`: facets, visibility, the visible weights, the SG EM on the device):

1. **The fit** (`fit_asg_on` on the device; `fit_asg`, host float64, its reference): J anisotropic spherical
   Gaussians fitted to the NDF's non-empty normal bins (the cube map of `normal_res`, each bin at its facets'
   area-weighted mean normal, weighing their visible weights summed: the NDF as the direction grid sees it, as
   the SG EM fits it; a bin's own spread, under a degree at R = 128, is what binning loses, and the facets would
   cost the fit their number per step: docs/design.md §9 has the comparison). The start
   is deterministic: the SG EM's lobes as isotropic ASGs (Xu's ν = η/2, `asg.from_sg`). Then EM steps on
   the mixture of normalised ASGs p_j(n) = G_j(n)/∫G_j: E-step responsibilities; M-step axis z = the
   responsibility-weighted mean normal, and in the tangent plane of z the weighted second moments of the
   disk coordinates (a, b) = (n·x, n·y): their eigenvectors give the frame, and λ, μ are the exact maximum
   likelihood of the truncated Gaussian on the unit disk for that frame (an ASG *is* that Gaussian in (a, b),
   asg.py's module notes; its sufficient statistics are a², b², so ML = matching E[a²], E[b²], solved by
   Newton in log λ, log μ with the moments by Gauss–Legendre across the disk, each chord in closed form).
   A facet whose normal lies below a lobe's horizon takes no responsibility from it.
2. **Amplitudes by the Gram route** (`amplitude_system`): A_ij = ∫G_iG_j by Xu's product (Eq. 13) and its integral
   (`gram`: Eq. 10 where it holds, else exact), regularised on its unit diagonal as the SG route (`lobes.RIDGE`) and
   calibrated per lobe by the fitted NDF (`lobes.amplitude_system`'s calibration: the amplitude of lobe j on the
   fitted NDF is A·α_j/∫G_j). b by the exact facet sums Σ_s P_si P_so w_s G_j(n_s) (`reference.lobe_moments`' sums),
   solved as `lobes.solve_amplitudes` (negative amplitudes 0, Σ_j μ_j ∫G_j = ∫γ̃ exactly, so the diffuse part is
   exact): for J ≤ lobes.KERNEL_LOBES by the SG bake's moment, solve and table kernels fed the ASGs' values at the
   facets, made on the device (`Backend.lobe_moments(..., lobe_values=asgs)`; the calibration's facet sums by
   `Backend.asg_value_sums`), past that on the host in float64 (P diag(w G_j) Pᵀ per lobe, `asg_moments`).
3. **f̄** (`ASGBRDF.eval`, float64): diffuse Σ_j μ_j kd/π ∫G_j; specular M(ωi, ωo)·Σ_j μ_j (G_j ⊛ SG_s)(h) with
   the small-scale BRDF's SG (`sg.specular_lobe`; a measured BRDF's fit of two lobes is two such terms,
   `sg.specular_lobes`) and Xu's Eq. 18 (`asg.convolve_sg`): its bandwidths and
   amplitude, with a shape that is exact for a delta NDF lobe too (`convolve_sg_at`; method "asg-eq18" is
   Eq. 18's own shape). An anisotropic small-scale BRDF (anisotropic Ward, Ashikhmin–Shirley) is instead its
   NDF's ASG (`brdf.ndf_bandwidths`) turned by each lobe's facets' tangents (`tangent_order`, recorded by the
   bake) and convolved with the lobe as Gaussians in its tangent plane (`asg.convolve_asg`: ASG × ASG).

The ASG fit (EM) runs on the device (`fit_asg_on`, stage asgfit; `fit_asg` is its float64 host reference); the
lobes' values, the moments and the solve run in the SG bake's kernels. The SG
renderer shades an `ASGBRDF` in its kernels (`shade_lobes`, `diffuse`; docs/design.md §9 "ASG rendering"),
the lit-sphere renderer evaluates it on the host (`host_texels`), the Monte Carlo reference samples it by
isotropic stand-ins of its lobes (`sampling_lobes`) and evaluates its exact ground truth; the Mitsuba export
reads SG lobes and refuses it in one line (`NO_SG_LOBES`).
"""

from __future__ import annotations

import collections
import math
import os
import time

import numpy as np
from scipy.special import erf

from . import asg as asg_mod
from . import bake as bake_mod
from . import directions as dirs
from . import lobes as lobes_mod
from . import sg
from .brdf import as_material_list, diffuse_albedo
from .effective import (ASG_LOBES, DIFFUSE_LEVEL_ETAS, EFF_LOBE_WIDTH, EffectiveBRDF, HostOnlyBRDF, Provenance,
                        check_amplitudes, device_levels, grid_amplitudes, interpolated_amplitudes, materials_from_file,
                        materials_to_file)
from .io import check_output, read_npz, save_npz
from .model import Bvndf, DeviceArray
from .progress import as_progress
from .smallscale import row_norms
from .truth import _check_count, _Timer

__all__ = ["ASGBRDF", "bake_asg", "fit_asg", "bandwidths_from_moments", "amplitude_system", "asg_moments",
           "calibrated_rows", "NO_SG_LOBES", "EM_ITERATIONS",
           "EVAL_METHODS", "fit_asg_on"]

EM_ITERATIONS = 8  # ASG EM steps after the SG start (0: the SG lobes as isotropic ASGs, λ = μ = η/2)
BANDWIDTH_MAX = sg.SHARPNESS_MAX / 2.0  # a delta direction (flat facets): the SG cap, in Xu's ν = η/2 units
BANDWIDTH_MIN = 1e-6
_CONVERGED = 1e-6  # relative change of the bandwidths and axis movement (rad²/2) that stops the EM
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)
CHORD_TERMS = 24  # series terms of _chord_moments where μB² < 1: the last below 1/24! ≈ 1.6e−24
CHORD_DONE = 1e-17  # ... or fewer, once a term is below this fraction of the sum

NO_SG_LOBES = ("a material baked by the ASG method (Xu 2013) holds anisotropic spherical Gaussians, not the SG "
               "lobes that the Mitsuba export reads: bake the tile with method='sg' to export it")


# ---------------------------------------------------------------------------------------------------
# The fit
# ---------------------------------------------------------------------------------------------------

def _chord_moments(mu, half):
    """(S0, S2, S4) = ∫_{−B}^{B} b^{2k} e^{−μb²} db for k = 0, 1, 2, B = `half`, in closed form: S0 = √(π/μ)·erf(B√μ)
    and, by parts, S2 = (S0 − 2B·e^{−μB²})/(2μ), S4 = (3·S2 − 2B³·e^{−μB²})/(2μ); where x = μB² < 1 those lose
    ~ε/x to cancellation, so there the series S_2k = 2Σ_m (−x)^m B^{2k+1}/(m!(2k + 2m + 1)) (terms below 1/m!:
    CHORD_TERMS of them are exact to float64, and it stops once a term is below CHORD_DONE of S0) takes over."""
    mu, half = np.broadcast_arrays(np.asarray(mu, np.float64), np.asarray(half, np.float64))
    x = mu * half * half
    small = x < 1.0
    rmu = np.where(small, 1.0, mu)  # (the closed form where x >= 1; the series below replaces the rest)
    e = np.exp(-np.where(small, 0.0, x))
    s0 = np.sqrt(np.pi / rmu) * erf(np.sqrt(np.where(small, 1.0, x)))
    s2 = (s0 - 2.0 * half * e) / (2.0 * rmu)
    s4 = (3.0 * s2 - 2.0 * half**3 * e) / (2.0 * rmu)
    if small.any():
        s0, s2, s4 = (np.array(v, np.float64) for v in (s0, s2, s4))  # (writable, scalars too)
        xs, hs = x[small], half[small]
        term, series = 2.0 * hs, [np.zeros_like(xs) for _ in range(3)]
        for m in range(CHORD_TERMS):
            for k in range(3):
                series[k] += term * hs ** (2 * k) / (2 * k + 2 * m + 1)
            term = term * -xs / (m + 1)
            if np.all(np.abs(term) < CHORD_DONE * series[0]):
                break
        for out, value in zip((s0, s2, s4), series):
            out[small] = value
    return s0, s2, s4


def _disk_moments(lam, mu):
    """For the density ∝ exp(−λa² − μb²) on the unit disk, per lobe: (E[a²], E[b²], E[a⁴], E[b⁴], E[a²b²]).
    Gauss–Legendre 48 in a ∈ [−A, A], A = min(1, 6/√(2λ)), and for each a the chord b ∈ [−B(a), B(a)],
    B = min(√(1 − a²), 6/√(2μ)), in closed form (`_chord_moments`): the Gaussian is below e^{−18} of its peak
    past those limits, so sharp lobes get their nodes where their mass is (bandwidths from 1e−6 to 5e5)."""
    lam, mu = np.asarray(lam, np.float64), np.asarray(mu, np.float64)
    amax = np.minimum(1.0, 6.0 / np.sqrt(2.0 * lam))[..., None]
    a2 = (amax * _GL_X) ** 2  # (J, na)
    wa = amax * _GL_W * np.exp(-lam[..., None] * a2)
    bmax = np.minimum(np.sqrt(np.maximum(1.0 - a2, 0.0)), 6.0 / np.sqrt(2.0 * mu)[..., None])  # (J, na)
    s0, s2, s4 = _chord_moments(mu[..., None], bmax)
    z = np.sum(wa * s0, -1)
    return (np.sum(wa * a2 * s0, -1) / z, np.sum(wa * s2, -1) / z, np.sum(wa * a2 * a2 * s0, -1) / z,
            np.sum(wa * s4, -1) / z, np.sum(wa * a2 * s2, -1) / z)


def bandwidths_from_moments(ma, mb, iterations: int = 60, start=None):
    """(λ, μ) whose truncated-disk Gaussian exp(−λa² − μb²) has E[a²] = ma, E[b²] = mb (the ML of an ASG for
    its frame): Newton in (log λ, log μ) from the untruncated 1/(2m), exact where a lobe's ±6σ box lies inside
    the disk, or elsewhere, given `start` (λ, μ) (the EM's previous bandwidths), from those; bandwidths clipped
    to [BANDWIDTH_MIN, BANDWIDTH_MAX] (a second moment at or above the disk's own leaves the bandwidth at its
    floor: an ASG cannot be broader than uniform in that direction). Stops when no step exceeds 1e−7 in log:
    Newton's error after it is of its square."""
    ma, mb = np.asarray(ma, np.float64), np.asarray(mb, np.float64)
    lo, hi = np.log(BANDWIDTH_MIN), np.log(BANDWIDTH_MAX)
    th = np.stack([np.log(np.clip(0.5 / np.maximum(ma, 1e-300), BANDWIDTH_MIN, BANDWIDTH_MAX)),
                   np.log(np.clip(0.5 / np.maximum(mb, 1e-300), BANDWIDTH_MIN, BANDWIDTH_MAX))], -1)
    target = np.stack([ma, mb], -1)
    if start is not None:
        # The untruncated start is exact (to the rule's e^{−18}) where its ±6σ box lies inside the disk; elsewhere
        # the EM's last bandwidths are closer once the EM settles.
        inside = np.sum(18.0 / np.exp(th), -1) <= 1.0
        warm = np.log(np.clip(np.stack(np.broadcast_arrays(*start), -1), BANDWIDTH_MIN, BANDWIDTH_MAX))
        th = np.where(inside[..., None], th, warm)
    for _ in range(iterations):
        lam, mu = np.exp(th[..., 0]), np.exp(th[..., 1])
        ea, eb, ea4, eb4, eab = _disk_moments(lam, mu)
        f = np.stack([ea, eb], -1) - target
        # d E[a²]/d log λ = −λ Var(a²), d E[a²]/d log μ = −μ Cov(a², b²), and likewise for b².
        jac = np.empty(f.shape + (2,))
        jac[..., 0, 0] = -lam * (ea4 - ea * ea)
        jac[..., 0, 1] = -mu * (eab - ea * eb)
        jac[..., 1, 0] = -lam * (eab - ea * eb)
        jac[..., 1, 1] = -mu * (eb4 - eb * eb)
        det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
        ok = np.abs(det) > 1e-300
        sdet = np.where(ok, det, 1.0)
        step = np.stack([(jac[..., 1, 1] * f[..., 0] - jac[..., 0, 1] * f[..., 1]) / sdet,
                         (jac[..., 0, 0] * f[..., 1] - jac[..., 1, 0] * f[..., 0]) / sdet], -1)
        step = np.where(ok[..., None], np.clip(step, -2.0, 2.0), 0.0)  # (damped: at most e² a step)
        new = np.clip(th - step, lo, hi)
        done = np.all(np.abs(new - th) < 1e-7)
        th = new
        if done:
            break
    return np.exp(th[..., 0]), np.exp(th[..., 1])


class _Lobes(collections.namedtuple("_Lobes", "x y z lam mu")):
    """The EM's ASGs between its steps: frames already orthonormal (the M-step builds them so), so not
    checked and re-orthonormalised at every step as an asg.ASG is; one is made at the end."""


def _log_pdf(asgs: _Lobes, log_norm, normal):
    """(Ns, J) log of the normalised ASG densities G_j(n)/∫G_j; −inf below each lobe's horizon."""
    a, b, t = normal @ asgs.x.T, normal @ asgs.y.T, normal @ asgs.z.T
    with np.errstate(divide="ignore"):
        return np.log(np.maximum(t, 0.0)) - asgs.lam * a * a - asgs.mu * b * b - log_norm


def _m_step(normal, weight, resp, previous: _Lobes):
    """Axes, frames and bandwidths from responsibilities `resp` (Ns, J) → (_Lobes, mass (J,))."""
    rw = resp * weight[:, None]
    mass = rw.sum(0)
    mean = rw.T @ normal  # (J, 3)
    norm = np.linalg.norm(mean, axis=1)
    live = (mass > lobes_mod.DEAD_MASS * mass.sum()) & (norm > 0)
    z = np.where(live[:, None], mean / np.where(norm > 0, norm, 1.0)[:, None], previous.z)
    x0, y0 = asg_mod.tangent_frame(z)
    a, b = normal @ x0.T, normal @ y0.T
    above = (normal @ z.T) > 0
    rw = np.where(above, rw, 0.0)
    m = np.maximum(rw.sum(0), 1e-300)
    caa, cbb, cab = (rw * a * a).sum(0) / m, (rw * b * b).sum(0) / m, (rw * a * b).sum(0) / m
    cov = np.stack([np.stack([caa, cab], -1), np.stack([cab, cbb], -1)], -2)
    evals, evecs = np.linalg.eigh(cov)  # ascending: column 0 the narrower direction → x, the larger λ
    ex, ey = evecs[..., :, 0], evecs[..., :, 1]
    x = ex[:, :1] * x0 + ex[:, 1:] * y0
    y = ey[:, :1] * x0 + ey[:, 1:] * y0
    lam, mu = bandwidths_from_moments(np.maximum(evals[:, 0], 0.0), np.maximum(evals[:, 1], 0.0),
                                      start=(previous.lam, previous.mu))
    keep = live & (m > 1e-300)
    x = np.where(keep[:, None], x, previous.x)
    y = np.where(keep[:, None], y, previous.y)
    z = np.where(keep[:, None], z, previous.z)
    lam = np.where(keep, lam, previous.lam)
    mu = np.where(keep, mu, previous.mu)
    y = np.cross(z, x)  # (a right-handed frame; the density does not depend on y's sign)
    return _Lobes(x, y, z, lam, mu), np.where(keep, mass, 0.0)


def _em_start(start: lobes_mod.LobeSet):
    """The EM's deterministic start: the SG lobes as isotropic ASGs (Xu's Eq. 3, λ = μ = η/2, within the
    bandwidth range) and their weights summing to 1 → (ASG batch (J,), α (J,))."""
    eta = np.clip(start.sharpness, 2 * BANDWIDTH_MIN, 2 * BANDWIDTH_MAX)
    alpha = np.asarray(start.weight, np.float64)
    return asg_mod.from_sg(start.axes, eta), alpha / alpha.sum()


def fit_asg_on(backend, normal, weight, start: lobes_mod.LobeSet, iterations: int = EM_ITERATIONS):
    """`fit_asg` on `backend`'s device (`Backend.asg_em`: the EM's steps queued at once), float64 as the host's
    but for the E-step's ∫G, the kernels' float32 56-node rule (kernels/asgfit.py). → as fit_asg."""
    first, alpha = _em_start(start)
    g, alpha, steps = backend.asg_em(normal, weight, first, alpha, iterations, (BANDWIDTH_MIN, BANDWIDTH_MAX),
                                     _CONVERGED)
    live = alpha > 0
    return g[live], alpha[live] / alpha[live].sum(), steps


def fit_asg(normal, weight, start: lobes_mod.LobeSet, iterations: int = EM_ITERATIONS):
    """EM for a mixture of J normalised ASGs on unit normals (Ns, 3) with weights (Ns,), from the SG lobes
    `start` (each as the isotropic ASG of Xu's Eq. 3, λ = μ = η/2, capped at BANDWIDTH_MAX).
    → (ASG batch (J',) of unit amplitude, weight α (J',) summing to 1, steps taken); dead lobes dropped."""
    normal = np.asarray(normal, np.float64)
    normal = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    weight = np.asarray(weight, np.float64)
    first, alpha = _em_start(start)
    g = _Lobes(*(getattr(first, k) for k in _Lobes._fields))
    steps = 0
    for _ in range(int(iterations)):
        log_norm = np.log(asg_mod.unit_integral(g.lam, g.mu))
        with np.errstate(divide="ignore"):
            lp = _log_pdf(g, log_norm, normal) + np.log(np.where(alpha > 0, alpha, 0.0))
        top = lp.max(1, keepdims=True)
        seen = np.isfinite(top[:, 0])  # a normal below every lobe's horizon takes no part
        resp = np.where(seen[:, None], np.exp(lp - np.where(seen[:, None], top, 0.0)), 0.0)
        resp /= np.where(seen, resp.sum(1), 1.0)[:, None]
        new, mass = _m_step(normal, weight, resp, g)
        steps += 1
        total = mass.sum()
        if not total > 0:
            break
        new_alpha = mass / total
        moved = (np.max(sg.one_minus_cos(new.z, g.z)) < _CONVERGED
                 and np.max(np.abs(np.log(new.lam / g.lam))) < _CONVERGED
                 and np.max(np.abs(np.log(new.mu / g.mu))) < _CONVERGED
                 and np.max(np.abs(new_alpha - alpha)) < _CONVERGED)
        g, alpha = new, new_alpha
        if moved:
            break
    live = alpha > 0
    return asg_mod.ASG(*g, 1.0)[live], alpha[live] / alpha[live].sum(), steps


def ndf_error(asgs: asg_mod.ASG, alpha, bin_normal, bin_weight, probe_sharpness: float) -> float:
    """`lobes.ndf_error` for an ASG mixture: the relative RMS error of the fitted NDF Σ_j W·α_j G_j/∫G_j (W the
    bins' total weight) seen through probe SGs of sharpness `probe_sharpness` on the heaviest 2048 non-empty
    normal bins: the data give Σ_l w_l G_q(n_l), the mixture Σ_j W α_j (G_j ⊛ SG_q)(q)/∫G_j
    (`asg.convolve_sg_at`, the convolution `ASGBRDF.eval` uses for the specular term). What lobes="auto"
    compares with its tolerance, as the SG bake compares `lobes.ndf_error`."""
    bn = np.asarray(bin_normal, np.float64)
    bw = np.asarray(bin_weight, np.float64)
    probes = bn[np.argsort(-bw)[:2048]] if len(bn) > 2048 else bn
    data = sg.evaluate(bn[None, :, :], probes[:, None, :], probe_sharpness) @ bw
    scale = bw.sum() * np.asarray(alpha, np.float64) / asg_mod.unit_integral(asgs.lam, asgs.mu)
    model = asg_mod.convolve_sg_at(asgs, probe_sharpness, probes) @ scale
    return float(np.sqrt(np.sum((data - model) ** 2) / max(np.sum(data**2), 1e-300)))


# ---------------------------------------------------------------------------------------------------
# Amplitudes
# ---------------------------------------------------------------------------------------------------

def _unit_rows(v) -> np.ndarray:
    """(N, 3) float64 rows scaled to unit length (the facets' float32 normals, made unit again in float64)."""
    v = np.asarray(v, np.float64)
    return v / row_norms(v)[:, None]


def _values(asgs: asg_mod.ASG, normal):
    """(Ns, J) G_j(n_s), unit amplitude."""
    normal = np.asarray(normal, np.float64)
    a, b, t = normal @ asgs.x.T, normal @ asgs.y.T, normal @ asgs.z.T
    return np.maximum(t, 0.0) * np.exp(-asgs.lam * a * a - asgs.mu * b * b)


TANGENT_SAMPLE = 8192  # facets read for the lobes' tangent orders (every k-th): plenty for a mean of cosines


def tangent_order(asgs: asg_mod.ASG, alpha, normal, tangent, weight, material, n_materials: int) -> np.ndarray:
    """(M, J, 2) each material's lobes' tangent orders: the mean (cos 2φ, sin 2φ) of the angles φ, in the lobe's
    frame, of the tangents of that material's facets (their direction across the lobe's tangent plane; doubled, as
    a tangent and its opposite are one line), each facet weighed by its weight and its responsibility
    α_jG_j(n)/Σ_k α_kG_k(n). What an anisotropic small-scale BRDF's NDF is convolved with (`asg.convolve_asg`):
    length 1 where all of a lobe's tangents lie on one line (grooves; each thread of a weave, whose warp and weft
    are two materials), 0 where they turn every way; (0, 0) for a lobe none of the material's facets reach. Per
    material because the amplitudes are: f̄ = Σ_m Σ_j μ_mj (G_j ⊛ D_m), so a lobe shared by two materials whose
    tangents cross (a weave) is turned each material's way. Read on the facets given (the bake gives every k-th,
    TANGENT_SAMPLE of them)."""
    material = np.asarray(material)
    return np.stack([_tangent_order_of(asgs, alpha, *(np.asarray(a, np.float64)[material == m]
                                                      for a in (normal, tangent, weight)))
                     for m in range(n_materials)])


def _tangent_order_of(asgs, alpha, n, t, w) -> np.ndarray:
    """(J, 2) `tangent_order` over the facets given."""
    resp = _values(asgs, n) * alpha
    total = resp.sum(1, keepdims=True)
    resp = np.where(total > 0, resp / np.where(total > 0, total, 1.0), 0.0) * w[:, None]
    c, d = t @ asgs.x.T, t @ asgs.y.T  # (Ns, J) the tangent across each lobe's plane
    r2 = c * c + d * d
    ok = r2 > 1e-12
    r2 = np.where(ok, r2, 1.0)
    cos2, sin2 = np.where(ok, (c * c - d * d) / r2, 0.0), np.where(ok, 2 * c * d / r2, 0.0)
    mass = (resp * ok).sum(0)
    order = np.stack([(resp * cos2).sum(0), (resp * sin2).sum(0)], 1)
    order = np.where(mass[:, None] > 0, order / np.where(mass > 0, mass, 1.0)[:, None], 0.0)
    length = np.hypot(order[:, 0], order[:, 1])
    return order / np.maximum(length, 1.0)[:, None]  # (rounding past 1)


class TangentSample:
    """What `tangent_order` reads, kept by a bake (and shared by the materials made from it: the geometry cache,
    material edits) so that the order is made once, and only when an anisotropic small-scale BRDF needs it
    (`ASGBRDF.tangent_order`: most materials never do, and it costs milliseconds on the host)."""

    def __init__(self, asgs, alpha, normal, face, weight, face_tangents, material_ids, n_materials):
        """normal (Ns, 3) the sampled facets' normals as the device holds them (made unit in float64 on first use),
        face (Ns,) their faces, weight (Ns,); the tile's face_tangents (F, 3) and material_ids (F,), looked up on
        first use too. (The tile's arrays, not the tile: the bake's geometry cache, which keeps this, is keyed by
        the tile weakly, and a value holding its key would keep every baked tile alive.)"""
        self.inputs = (asgs, alpha, normal, face, weight, face_tangents, material_ids, n_materials)
        self._order = None

    def order(self) -> np.ndarray:
        if self._order is None:
            asgs, alpha, normal, face, weight, face_tangents, material_ids, n_materials = self.inputs
            self._order = tangent_order(asgs, alpha, _unit_rows(normal), face_tangents[face], weight,
                                        material_ids[face], n_materials)
        return self._order


def gram(asgs: asg_mod.ASG):
    """(J, J) A_ij = ∫G_iG_j by Xu's product (Eq. 13) and its integral as the shade kernels take it
    (`asg.shade_integral`: Eq. 10 where both bandwidths exceed 5, within 0.026 % there and to rounding for the
    sharp products of a bake's lobes; the kernels' 56-node rule elsewhere), each pair i ≤ j once.

    `asg.product` in closed form where A1 + A2's smallest eigenvalue w0 is simple, as it is for two lobes of a
    fitted mixture: z3 is its eigenvector, λ3 = w2 − w0, μ3 = w1 − w0 and the amplitude
    c1c2(z3·z1)⁺(z3·z2)⁺e^{−w0} (equal to `product`'s to rounding, which forms λ3 and μ3 from x3ᵀA3x3); the pairs
    whose w0 is degenerate (a band, μ = 0, with itself or one along the same axis; λ = μ = 0 lobes) go through
    `product`. One batched eigendecomposition instead of `product`'s general path: the Gram matrix is on the
    bake's critical path."""
    lam, mu, x, y = asgs.lam, asgs.mu, asgs.x, asgs.y
    forms = lam[:, None, None] * x[:, :, None] * x[:, None, :] + mu[:, None, None] * y[:, :, None] * y[:, None, :]
    i, j = np.triu_indices(len(lam))
    w, q = np.linalg.eigh(forms[i] + forms[j])
    z1, z2 = asgs.z[i], asgs.z[j]
    zsum = z1 + z2
    z3 = q[:, :, 0]
    z3 = np.where((np.einsum("pi,pi->p", z3, zsum) < 0)[:, None], -z3, z3)
    tol = 1e-12 * np.maximum(w[:, 2], 1.0)  # (as `product`)
    simple = (w[:, 1] - w[:, 0]) > tol
    smooth = np.maximum(np.einsum("pi,pi->p", z3, z1), 0.0) * np.maximum(np.einsum("pi,pi->p", z3, z2), 0.0)
    amp = asgs.amplitude[i] * asgs.amplitude[j] * smooth * np.exp(-np.maximum(w[:, 0], 0.0))
    lam3, mu3 = np.maximum(w[:, 2] - w[:, 0], 0.0), np.maximum(w[:, 1] - w[:, 0], 0.0)
    if not simple.all():
        p = asg_mod.product(asgs[i[~simple]], asgs[j[~simple]])
        amp[~simple], lam3[~simple], mu3[~simple] = p.amplitude, p.lam, p.mu
    a = np.empty((len(lam),) * 2)
    a[i, j] = a[j, i] = amp * asg_mod.shade_integral(lam3, mu3)
    return a


def gram_by_products(asgs: asg_mod.ASG):
    """`gram` through `asg.product` for every pair (its oracle in the tests)."""
    i, j = np.triu_indices(len(asgs.lam))
    a = np.empty((len(asgs.lam),) * 2)
    p = asg_mod.product(asgs[i], asgs[j])
    a[i, j] = a[j, i] = p.amplitude * asg_mod.shade_integral(p.lam, p.mu)
    return a


def amplitude_system(asgs: asg_mod.ASG, alpha=None, value_sums=None, total_weight=None):
    """→ (solve rows (J, J), integrals (J,), gram (J, J), condition number): `lobes.amplitude_system` for ASGs.
    With the fitted NDF's sums the rows are calibrated (`calibrated_rows`), else not."""
    a = gram(asgs)
    integrals = asg_mod.unit_integral(asgs.lam, asgs.mu)
    d = np.sqrt(np.maximum(np.diag(a), 1e-300))
    unit = a / np.outer(d, d) + lobes_mod.RIDGE * np.eye(len(d))
    inv = np.linalg.inv(unit) / np.outer(d, d)
    if value_sums is not None:
        inv = calibrated_rows(inv, integrals, alpha, value_sums, total_weight)
    return inv, integrals, a, float(np.linalg.cond(unit))


def calibrated_rows(inv, integrals, alpha, value_sums, total_weight):
    """The solve rows scaled so that the fitted NDF's own least-squares amplitudes are its fitted ones,
    total·α_j/∫G_j: `value_sums` (J,) Σ_s w_s G_j(n_s) over the facets (`_values(...).T @ w` on the host,
    `Backend.asg_value_sums` on the device) and `total_weight` Σ_s w_s."""
    lsq = inv @ np.asarray(value_sums, np.float64)
    target = float(total_weight) * np.asarray(alpha, np.float64) / integrals
    scale = np.where(lsq > 1e-12 * target.max(), target / np.where(lsq > 0, lsq, 1.0), 1.0)
    return inv * scale[:, None]


def asg_moments(proj, values, weight, pair_i, pair_o):
    """(U, J + 1) [Σ_s P_si P_so w_s G_j(n_s), Σ_s P_si P_so w_s] for the unordered pairs (`reference.lobe_moments`'
    sums): proj (D, Ns) P_sk = V_s(ω_k)(n_s·ω_k)⁺, values (Ns, J) G_j(n_s), weight (Ns,) w_s. By one
    (D, Ns)·(Ns, D) product per lobe, float64."""
    g = np.concatenate([values * weight[:, None], weight[:, None]], axis=1)
    out = np.empty((len(pair_i), g.shape[1]))
    for j in range(g.shape[1]):
        out[:, j] = ((proj * g[:, j]) @ proj.T)[pair_i, pair_o]
    return out


# ---------------------------------------------------------------------------------------------------
# The bake
# ---------------------------------------------------------------------------------------------------

def bake_asg(tile, mats, lobes, directions, normal_res, facets, backend, seed, keep_hist, progress,
             tolerance: float = 0.02) -> ASGBRDF:
    """`wb.bake(..., method="asg")` (bake.py dispatches here): see the module notes. lobes="auto": the first J of
    `bake.AUTO_LOBES` whose ASG mixture's `ndf_error` at the sharpest small-scale lobe is ≤ `tolerance` (else
    the J of the least error), one SG EM and ASG fit per J tried. The geometry part (up to the amplitude
    tables) is cached per tile beside the SG bake's, so baking the tile again with other BRDFs costs the
    tables alone."""
    count = _check_count(facets)
    j_req = bake_mod._check_lobes(lobes)
    k, r = bake_mod._check_grid(directions, normal_res)
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be a number > 0, got {tolerance!r}")
    be = bake_mod.get_backend(backend)
    probe = bake_mod.probe_sharpness(mats) if j_req == "auto" else None
    key = ("asg", count, int(seed), k, r, j_req, int(EM_ITERATIONS), bool(keep_hist), be.name,
           (float(tolerance), probe) if j_req == "auto" else None)
    cache = bake_mod._GEOMETRY.setdefault(tile, collections.OrderedDict())
    geo = cache.get(key)
    timer = _Timer(be)
    prog = as_progress(progress)
    if geo is None:
        geo = _asg_geometry(tile, be, count, int(seed), k, r, j_req, keep_hist, timer, prog, tolerance, probe)
        cache[key] = geo
        while len(cache) > bake_mod._GEOMETRY_PER_TILE:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    prog.stage("tables", 1)
    t0 = time.perf_counter()
    amps, energy, levels = geo["amplitudes"], geo["energy"], geo["levels"]
    if len(mats) > len(amps):  # materials beyond the tile's ids reflect nothing
        amps, energy, levels = (None if a is None else np.concatenate([a, np.zeros((len(mats) - len(a),) + a.shape[1:],
                                                                                  a.dtype)])
                                for a in (amps, energy, levels))
    mat = ASGBRDF(geo["asgs"], geo["alpha"], amps, mats, k, info={**geo["info"], "backend": be.name,
                                                                  "tile": tile.name, **_ndf_fit_info(mats)},
                  bvndf=geo["bvndf"], provenance=Provenance(tile, int(seed), count), energy=energy,
                  tangent_order=geo["tangent_order"], energy_levels=levels, _integrals=geo["integrals"])
    timer.timings["tables"] = time.perf_counter() - t0
    mat.timings = dict(timer.timings)
    prog.done()
    return mat


def _ndf_fit_info(mats) -> dict:
    """{"ndf_asg_error": {material index: error}} for the anisotropic small-scale BRDFs among `mats`, whose NDF
    stands as one ASG (`brdf.ndf_asg_error`), else {}."""
    fit = {str(i): m.ndf_fit_error for i, m in enumerate(mats) if m.anisotropic}
    return {"ndf_asg_error": fit} if fit else {}


def _asg_geometry(tile, be, count, seed, k, r, j_req, keep_hist, timer, prog, tolerance=0.02, probe=None) -> dict:
    """Facets, visibility, weights and the SG EM by the SG bake's stages; then the ASG EM on the device (per J
    tried, for "auto"), the moments, the solve and the tables (in kernels up to lobes.KERNEL_LOBES lobes, else
    on the host). → {"asgs", "alpha", "integrals" (J,) ∫G_j, "amplitudes" (M, K², K², J, 3), "energy" (M, K², K², 3)
    Σ_j μ_j ∫G_j from the table kernels or None, "bvndf", "info"}."""
    q = bake_mod._sample_facets(tile, be, count, seed, dirs.frozen_grid(k), r, timer, prog)
    t0 = time.perf_counter()
    bake_mod._queue_visibility(tile, be, q, prog)
    bv, facet_bin = bake_mod._queue_em_and_bin(be, q, r, j_req, "histogram")  # ("histogram": no SG moment sums)
    weight_host = np.asarray(q.em_weight.host(), np.float64)
    timer.timings["visibility"] = timer.timings.get("visibility", 0.0) + time.perf_counter() - t0
    hists = bake_mod._histograms(be, q, bv, facet_bin, "facets", keep_hist, timer, prog)
    del hists  # (only bv.histogram, with keep_hist)
    # (no grid direction sees the tile: the bare NDF)
    em_w = weight_host if weight_host.any() else np.asarray(q.fac.area, np.float64)
    ndf_err = None
    for j in (bake_mod.AUTO_LOBES if j_req == "auto" else (j_req,)):
        # (With a fixed J the SG EM was queued behind the rays; "auto" runs one per J tried.)
        lob, _, _, seen_normal, seen_weight = bake_mod._fit_ndf(be, q, bv, facet_bin, weight_host, r, j,
                                                                "histogram", tolerance, None, timer, prog)
        prog.stage(f"ASG fit ({len(lob)} lobes)", 1)
        t0 = time.perf_counter()
        fitted = fit_asg_on(be, seen_normal, seen_weight, lob, EM_ITERATIONS)
        timer.timings["asg_fit"] = timer.timings.get("asg_fit", 0.0) + time.perf_counter() - t0
        if j_req != "auto":
            break
        err = ndf_error(fitted[0], fitted[1], seen_normal, seen_weight, probe)
        if ndf_err is None or err < ndf_err:
            best, ndf_err = (lob, fitted), err
        if err <= tolerance or len(lob) < j:  # met, or fewer distinct normals than lobes asked for
            break
    if j_req == "auto":
        lob, fitted = best
    asgs, alpha, steps = fitted
    prog.stage(f"amplitudes ({len(alpha)} ASG lobes, {len(q.channels)} channel(s))", 1)
    t0 = time.perf_counter()
    nd = len(q.grid)
    pi, po = dirs.all_pairs(nd)
    if len(alpha) <= lobes_mod.KERNEL_LOBES:
        # The SG bake's moment, solve and table kernels, with the ASGs' values at the facets (made on the device)
        # in place of the SG lobes': exact facet sums, float32, as the SG route.
        value_sums = be.asg_value_sums(q.fac, q.em_weight if em_w is weight_host else em_w, asgs, to_host=False)
        moments = [be.lobe_moments(q.fac, q.vis, w, None, None, q.iu, q.ou, to_host=False, lobe_values=asgs)
                   for w in q.weights]
        rows, integrals, _, cond = amplitude_system(asgs)  # (on the host while the device sums)
        rows = calibrated_rows(rows, integrals, alpha, value_sums.host(), em_w.sum())
        solved = [(m, mult, be.solve_amplitudes(b, q.a_v, rows, integrals, pi, po, nd, to_host=False))
                  for (m, mult, _), b in zip(q.channels, moments)]
        # (with the tables their Σ_j μ_j ∫G_j and its levels for the renderer, as the SG bake's)
        amps, energy, levels = be.material_tables([[(mu, mult) for mm, mult, mu in solved if mm == m]
                                                   for m in range(tile.n_materials)], integrals, nd * nd,
                                                  device_levels(be, math.isqrt(nd)))
        # (the tables and levels stay on the device, as the SG bake's: the shade stage takes them from there)
        energy = energy.reshape(tile.n_materials, nd, nd, 3)
        levels = None if levels is None else levels.reshape(tile.n_materials, -1, nd, nd, 3)
    else:  # past the kernels' lobes: float64 on the host (P diag(w G_j) Pᵀ per lobe)
        energy = levels = None
        normal = _unit_rows(q.fac.normal)
        area = np.asarray(q.fac.area, np.float64)
        values = _values(asgs, normal)
        rows, integrals, _, cond = amplitude_system(asgs, alpha, values.T @ em_w, em_w.sum())
        proj = q.vis.as_bool() * np.maximum(q.grid @ normal.T, 0.0)  # (D, Ns)
        a_v = np.asarray(q.a_v.host(), np.float64)
        amps = np.zeros((tile.n_materials, nd * nd, len(alpha), 3))
        for m, mult, w in q.channels:
            mom = asg_moments(proj, values, area if w is None else np.asarray(bake_mod.host_weight(w), np.float64),
                              q.iu, q.ou)
            mu = lobes_mod.solve_amplitudes(mom, a_v, pi, po, nd, rows, integrals)
            amps[m] += np.asarray(mu, np.float64)[..., None] * mult
    # (a NaN μ leaves its amplitude 0 in the table kernels' output but makes its pair's energy NaN: the energies
    # are checked, the tables only where the host made them)
    if (energy is None and not np.isfinite(amps).all()) or (energy is not None and not np.isfinite(energy).all()):
        raise FloatingPointError("the ASG amplitude solve gave non-finite values")
    bv.a_v = np.asarray(q.a_v.host(), np.float64)
    every = slice(None, None, max(1, len(q.fac) // TANGENT_SAMPLE))  # (a mean of cosines: a sample suffices)
    # (copies of the sample alone: a view would keep the whole arrays)
    order = TangentSample(asgs, alpha, np.asarray(q.fac.normal)[every].copy(), np.asarray(q.fac.face)[every].copy(),
                          em_w[every].copy(), tile.face_tangents, tile.material_ids, tile.n_materials)
    timer.timings["amplitudes"] = time.perf_counter() - t0
    info = {"facets": count, "seed": seed, "normal_res": r, "route": "facets", "lobes": int(len(alpha)),
            "lobes_requested": j_req, "ndf_error": ndf_err, "ndf_probe_sharpness": probe,
            "sg_em_iterations": lob.iterations, "asg_em_iterations": steps,
            "gram_condition": cond, "nonempty_bins": int(len(bv.bins)), "channels": len(q.channels)}
    return {"asgs": asgs, "alpha": alpha, "integrals": integrals,
            "amplitudes": amps.reshape(tile.n_materials, nd, nd, len(alpha), 3),
            "energy": energy, "levels": levels, "bvndf": bv, "info": info, "tangent_order": order}


# ---------------------------------------------------------------------------------------------------
# The result
# ---------------------------------------------------------------------------------------------------

EVAL_METHODS = ("asg", "asg-eq18")


class ASGBRDF(HostOnlyBRDF):
    """A material baked by the ASG method (`wb.bake(tile, materials, method="asg", lobes=J)`).

    The interface of `EffectiveBRDF`: `eval(wi, wo)` (cosine θi included; μ/cos θi bilinear on the grid as the
    SG form), `table()`, `wb.compare`, `save` / `wb.load` (format "asg_brdf", versioned), `with_materials`
    (new small-scale BRDFs, nothing re-baked), `provenance`, `path`, `timings`, `info`. Attributes: `asgs`
    (asg.ASG batch (J,), unit amplitude), `weight` (J,) α_j, `amplitudes` (M, K², K², J, 3) float32 μ tables
    (of the ASGs), `integrals` (J,) ∫G_j, `diffuse` the f̄d table, `tangent_order` (M, J, 2) per material and lobe
    its facets' mean (cos 2φ, sin 2φ) of their tangents' angles in the lobe's frame (`tangent_order`; what an
    anisotropic small-scale BRDF's NDF is turned by). It has no SG lobes: `lobes` and the
    Mitsuba export raise `NO_SG_LOBES`; the SG renderer reads its ASG lobes (`shade_lobes`), the Monte Carlo
    reference samples their isotropic stand-ins (`sampling_lobes`), the lit-sphere renderer evaluates it on
    the host."""

    VERSION = 1
    VERSIONS = (1,)
    FORMAT = "asg_brdf"
    no_sg_lobes = NO_SG_LOBES

    def __init__(self, asgs: asg_mod.ASG, weight, amplitudes, materials, directions: int, timings=None, info=None,
                 bvndf=None, provenance: Provenance | None = None, path=None, energy=None, tangent_order=None,
                 energy_levels=None, _integrals=None):
        if not isinstance(asgs, asg_mod.ASG) or asgs.lam.ndim != 1 or not (1 <= len(asgs.lam) <= lobes_mod.MAX_LOBES):
            raise ValueError(f"asgs must be an asg.ASG batch of 1..{lobes_mod.MAX_LOBES} lobes")
        unit = np.all(asgs.amplitude == 1.0)
        self.asgs = asgs if unit else asg_mod.ASG(asgs.x, asgs.y, asgs.z, asgs.lam, asgs.mu, 1.0)
        j = len(self.asgs.lam)
        self.weight = np.asarray(weight, np.float64).reshape(-1)
        if self.weight.shape != (j,):
            raise ValueError(f"weight must have {j} entries, got {self.weight.shape}")
        self.directions = int(directions)
        if not (2 <= self.directions <= 32):
            raise ValueError(f"directions must be in [2, 32], got {directions!r}")
        nd = self.directions**2
        # (a bake's tables stay on its device, a DeviceArray, as the SG bake's: `amplitudes` reads them back when
        # host code first asks. Checked once, where their energies are made: the bake checked those, an edit
        # passes them on, tables without them are checked here.)
        self._amplitudes = amplitudes if isinstance(amplitudes, DeviceArray) else np.asarray(amplitudes, np.float32)
        shape = self._amplitudes.shape
        if len(shape) != 5 or shape[1:] != (nd, nd, j, 3):
            raise ValueError(f"amplitudes must have shape (M, {nd}, {nd}, {j}, 3), got {shape}")
        if energy is None:
            check_amplitudes(self.amplitudes)
        # Anisotropic small-scale BRDFs too: each lobe's facets' tangent order says how to turn their NDF's ASG
        # before it is convolved with the lobe (`asg.convolve_asg`).
        self.materials = as_material_list(materials, anisotropic=True)
        # (a TangentSample: made on first use, `tangent_order`)
        self._tangent_order = np.zeros((shape[0], j, 2)) if tangent_order is None else tangent_order
        if not isinstance(tangent_order, TangentSample):
            self._tangent_order = self._checked_order(self._tangent_order)
        if len(self.materials) != shape[0]:
            raise ValueError(f"{shape[0]} amplitude table(s) but {len(self.materials)} material(s)")
        self.method = "asg"
        self.timings = dict(timings or {})
        self.info = dict(info or {})
        self.bvndf = bvndf
        if provenance is not None and not isinstance(provenance, Provenance):
            raise ValueError(f"provenance must be an effective.Provenance or None, got {type(provenance).__name__}")
        if provenance is not None and provenance.tile.n_materials > len(self.materials):
            raise ValueError(f"provenance: the tile has {provenance.tile.n_materials} material ids but the material "
                             f"has {len(self.materials)} BRDF(s)")
        self.provenance = provenance
        self.path = None if path is None else os.path.abspath(os.fspath(path))
        # (`_integrals`: the bake's or the edited material's own ∫G_j of these ASGs, not made again)
        self.integrals = (asg_mod.unit_integral(self.asgs.lam, self.asgs.mu) if _integrals is None
                          else np.asarray(_integrals, np.float64))
        # Σ_j μ_mj ∫G_j per material, independent of the BRDFs (EffectiveBRDF's; `energy_levels` reads it), or
        # `energy` (M, K², K², 3), the same sums as the bake's table kernels made them
        if energy is None:
            self._energy = np.einsum("miojc,j->mioc", self.amplitudes, self.integrals.astype(np.float32))
        else:
            self._energy = np.asarray(energy, np.float32)
            if self._energy.shape != shape[:3] + (3,):
                raise ValueError(f"energy must have shape {shape[:3] + (3,)}, got {self._energy.shape}")
            if self._energy.size and not (self._energy.min() >= 0 and np.isfinite(self._energy.max())):
                raise ValueError("energy must be finite and >= 0")
        # `energy_levels`: the bake's (made on the device with the tables), else made on first use
        if energy_levels is not None and np.shape(energy_levels) != (len(self.materials), len(DIFFUSE_LEVEL_ETAS),
                                                                      nd, nd, 3):
            raise ValueError(f"energy levels of shape {np.shape(energy_levels)} do not fit the tables")
        self._energy_levels = energy_levels
        self._diffuse = None  # made on first use (`diffuse`)

    def _checked_order(self, order) -> np.ndarray:
        order = np.asarray(order, np.float64)
        shape = (len(self._amplitudes), len(self.weight), 2)
        if len(order) < shape[0] and order.shape[1:] == shape[1:]:  # materials beyond the tile's ids: no facets
            order = np.concatenate([order, np.zeros((shape[0] - len(order),) + shape[1:])])
        if (order.shape != shape or not np.isfinite(order).all()
                or (order.size and np.hypot(order[..., 0], order[..., 1]).max() > 1 + 1e-6)):
            raise ValueError(f"tangent_order must be {shape} (materials, lobes, 2), finite, each of length <= 1")
        return order

    @property
    def tangent_order(self) -> np.ndarray:
        """(M, J, 2) each material's lobes' tangent orders (`tangent_order`), made from the bake's sample on first
        use."""
        if isinstance(self._tangent_order, TangentSample):
            return self._checked_order(self._tangent_order.order())
        return self._tangent_order

    def shade_lobes(self) -> tuple[int, np.ndarray]:
        """The SG renderer's lobe rows (`shading.pack_materials`): ASG_LOBES and (J, EFF_LOBE_WIDTH) float32
        [z (3), 0, x (3), λ, μ] in the tile frame (y = z × x: an ASG is even in x and y)."""
        g = self.asgs
        rows = np.zeros((len(self.weight), EFF_LOBE_WIDTH), np.float32)
        rows[:, 0:3], rows[:, 4:7], rows[:, 7], rows[:, 8] = g.z, g.x, g.lam, g.mu
        return ASG_LOBES, rows

    def tangent_rows(self, owner) -> np.ndarray:
        """(len(owner)·J, EFF_LOBE_WIDTH) float32: per shade sub-row s (of small-scale material owner[s]) and lobe j,
        [o_c, o_s, 0 …], that material's tangent order (`shading.pack_materials` puts them after the lobe rows);
        zero, and never made, where no material is anisotropic (the kernels read them for those alone)."""
        rows = np.zeros((len(owner) * len(self.weight), EFF_LOBE_WIDTH), np.float32)
        if any(m.anisotropic for m in self.materials):
            rows[:, 0:2] = self.tangent_order[np.asarray(owner)].reshape(-1, 2)
        return rows

    def sampling_lobes(self) -> tuple[np.ndarray, np.ndarray]:
        """The Monte Carlo reference's BRDF sampling (`EffectiveBRDF.sampling_lobes`): each ASG's axis with the SG
        sharpness of its equal-area circle, 2√(λμ) (`asg.effective_sharpness`), the isotropic stand-ins whose
        energies weigh the lobes; the lobes themselves are drawn as ASGs (`montecarlo_sampling.sample_asg`).
        Any lobes sample without bias (the estimator divides by their exact density)."""
        return self.asgs.z, asg_mod.effective_sharpness(self.asgs)

    def _interpolated_amplitudes(self, wi, wo):
        return self._mu(wi, wo)

    # f̄d on the grid from this bake's energy, as an SG bake's (HostOnlyBRDF refuses it for the matrix method)
    diffuse = EffectiveBRDF.diffuse

    def __repr__(self):
        return f"ASGBRDF(K={self.directions}, lobes={len(self.weight)}, materials={self.materials})"

    def export_mitsuba(self, path) -> dict:
        """Refused before anything is written (`NO_SG_LOBES`); with an anisotropic small-scale BRDF, which no SG
        bake holds, the refusal says that nothing exports it."""
        if any(m.anisotropic for m in self.materials):
            raise ValueError("a material baked by the ASG method (Xu 2013) over an anisotropic small-scale BRDF has no "
                             "form the Mitsuba export reads (it reads SG lobes, and the SG bake holds no anisotropic "
                             "BRDF): it cannot be exported")
        raise ValueError(self.no_sg_lobes)

    # ------------------------------------------------------------------ edits
    def with_materials(self, materials) -> ASGBRDF:
        """The same baked ASGs and amplitudes with other small-scale BRDFs (a material-only edit: no re-bake);
        provenance and `path` carry over, as EffectiveBRDF.with_materials."""
        t0 = time.perf_counter()
        # (the new BRDFs' fit errors instead; and a method="auto" choice was made for the old BRDFs)
        info = {k: v for k, v in self.info.items() if k not in ("ndf_asg_error", "method_choice")}
        out = ASGBRDF(self.asgs, self.weight, self._amplitudes, materials, self.directions, info=info,
                      bvndf=self.bvndf, provenance=self.provenance, path=self.path, energy=self._energy,
                      tangent_order=self._tangent_order, energy_levels=self._energy_levels, _integrals=self.integrals)
        out.info.update(_ndf_fit_info(out.materials))
        out.timings = {"tables": time.perf_counter() - t0}
        return out

    # ------------------------------------------------------------------ evaluation
    @staticmethod
    def _check_method(method):
        if method not in (None, *EVAL_METHODS):
            raise ValueError(f"an ASG-method material evaluates its own lobes (method one of {EVAL_METHODS} or None), "
                             f"not {method!r}")

    def _mu(self, wi, wo) -> np.ndarray:
        """(M, N, J, 3) μ at (ωi, ωo), interpolated as the SG form's (`effective.interpolated_amplitudes`)."""
        return interpolated_amplitudes(self.amplitudes, self.grid, self.directions, wi, wo)

    def eval(self, wi, wo, method: str | None = None, *, _on_grid: bool = False) -> np.ndarray:
        """(N, 3) f̄(ωi, ωo) (cosine θi included, docs/design.md §4); 0 below the horizon. Diffuse
        Σ_j μ_j kd/π ∫G_j, specular M·Σ_j μ_j (G_j ⊛ SG_s)(h), float64. method "asg" (default): the convolution
        by `convolve_sg_at` (Xu's Eq. 18 bandwidths and amplitude, a shape exact in both limits); "asg-eq18":
        Xu's Eq. 18 literally (`asg.convolve_sg`). (`_on_grid`: `table`'s call, as EffectiveBRDF.eval's.)"""
        self._check_method(method)
        literal = method == "asg-eq18"
        wi = dirs.check_directions("wi", wi)
        wo = dirs.check_directions("wo", wo)
        if len(wi) != len(wo):
            raise ValueError(f"wi and wo must have the same length, got {len(wi)} and {len(wo)}")
        mu = grid_amplitudes(self.amplitudes) if _on_grid else self._mu(wi, wo)
        out = np.zeros((len(wi), 3))
        for m, mat in enumerate(self.materials):
            kd = diffuse_albedo(mat) / np.pi
            out += np.einsum("njc,j->nc", mu[m], self.integrals) * kd
            if mat.anisotropic:
                out += self._anisotropic_specular(m, mat, mu[m], wi, wo)
                continue
            for eta_s, scale, h in sg.specular_lobes(mat, wi, wo):
                if eta_s is None or not scale.any():
                    continue
                if literal:
                    s = asg_mod.evaluate(asg_mod.convolve_sg(self.asgs, eta_s), h[:, None, :])  # (N, J)
                else:
                    s = asg_mod.convolve_sg_at(self.asgs, eta_s, h)
                out += scale * np.einsum("njc,nj->nc", mu[m], s)
        out[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] = 0.0
        return np.maximum(out, 0.0)

    def _anisotropic_specular(self, m, mat, mu, wi, wo) -> np.ndarray:
        """(N, 3) the specular term of material m, an anisotropic small-scale BRDF: M(cos θd)·Σ_j μ_j (G_j ⊛ D_s)(h),
        D_s its NDF's ASG turned by its tangent order for each lobe (`asg.convolve_asg`), M its f_s at the mirror
        direction over D_s (`shading.specular_scale`, which the renderers use)."""
        from .shading import _analytic_rows, specular_scale  # (shading imports this module's neighbours)

        h = wi + wo
        h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        scale, _ = specular_scale(_analytic_rows(mat, anisotropic=True)[0], np.einsum("ij,ij->i", h, wi))
        lam_s, mu_s = mat.ndf_bandwidths
        conv = asg_mod.convolve_asg(self.asgs, float(lam_s), float(mu_s), self.tangent_order[m])
        return scale * np.einsum("njc,nj->nc", mu, asg_mod.evaluate(conv, h[:, None, :]))

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write atomically as a versioned npz (format "asg_brdf"; `wb.load` reads it back)."""
        check_output(path, what="material file")
        g = self.asgs
        arrays = {"asg_x": g.x, "asg_y": g.y, "asg_z": g.z, "asg_lam": g.lam, "asg_mu": g.mu, "weight": self.weight,
                  "amplitudes": self.amplitudes, "tangent_order": self.tangent_order}
        if self.bvndf is not None:
            arrays.update({f"bvndf_{k}": v for k, v in self.bvndf.arrays().items()})
        if self.provenance is not None:
            arrays.update(self.provenance.arrays())
        materials, tables = materials_to_file(self.materials)
        arrays.update(tables)
        save_npz(path, self.FORMAT, self.VERSION,
                 {"directions": self.directions, "method": "asg",
                  "materials": materials, "info": self.info,
                  "timings": self.timings, "bvndf_resolution": None if self.bvndf is None else self.bvndf.resolution,
                  "provenance": None if self.provenance is None else self.provenance.header()},
                 arrays)
        self.path = os.path.abspath(os.fspath(path))

    @classmethod
    def load(cls, path) -> ASGBRDF:
        head, arrays = read_npz(path, cls.FORMAT, versions=cls.VERSIONS)
        try:
            g = asg_mod.ASG(arrays["asg_x"], arrays["asg_y"], arrays["asg_z"], arrays["asg_lam"], arrays["asg_mu"])
            mats = materials_from_file(head["materials"], arrays)
            bv = None
            if head.get("bvndf_resolution") is not None:
                bv = Bvndf.from_arrays(head["bvndf_resolution"], {k[6:]: v for k, v in arrays.items()
                                                                  if k.startswith("bvndf_")})
            prov = Provenance.from_file(head["provenance"], arrays) if head.get("provenance") is not None else None
            return cls(g, arrays["weight"], arrays["amplitudes"], mats, head["directions"], head.get("timings"),
                       head.get("info"), bv, prov, path, tangent_order=arrays.get("tangent_order"))
        except KeyError as exc:
            raise ValueError(f"{path} is missing {exc} (corrupt material file)") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path} is not a valid material file: {exc}") from None


bake_mod.METHOD_BAKES["asg"] = bake_asg
