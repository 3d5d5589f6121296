"""SG lobes of the NDF (Iwasaki §4): the spherical EM's host side, and the amplitude system.

The whole EM loop runs on the device (`Backend.ndf_em`: E-step sums and M-step, no host round trip
per step). This module holds the deterministic initialisation, `m_step` and `converged` (the
float64 definition that the device M-step mirrors; `reference.ndf_em` is the host loop), `fit`
(the driver's entry), the J×J Gram matrix A of the lobes and its (regularised, energy-constrained)
solve rows, and the NDF fit error that `lobes="auto"` uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import sg
from .directions import cube_bin, unordered_index

__all__ = ["LobeSet", "initial_lobes", "m_step", "converged", "fit", "from_em", "amplitude_system", "solve_amplitudes",
           "ndf_error", "MAX_LOBES", "KERNEL_LOBES"]

MAX_LOBES = 128  # lobes of a LobeSet (the bake's J)
# The amplitude kernels keep one accumulator per lobe in registers: the bake passes more lobes through
# them in groups of this many (and solves for J > KERNEL_LOBES amplitudes on the host, `solve_amplitudes`).
KERNEL_LOBES = 16
RIDGE = 1e-6  # Tikhonov term on the unit-diagonal Gram matrix: bounds its condition number by ~1e6
CONVERGENCE_TOL = 1e-4  # see `converged`
START_RES = 16  # initial_lobes' coarse cube map: the device start (Backend.em_start) bins at it too
DEAD_MASS = 1e-9  # a lobe holding less than this fraction of the area after an E-step is dead (weight 0)


@dataclass(eq=False)
class LobeSet:
    """J SG lobes fitted to the NDF: axes (J, 3) unit, sharpness (J,), weight (J,) the fraction
    α_j of the tile's area each lobe holds. As an NDF, Γ(n) ≈ Σ_j A·α_j·vMF_j(n) with A the area.
    During EM a lobe that lost all its area keeps weight 0 (dead: it takes no responsibility);
    `alive()` drops such lobes."""

    axes: np.ndarray
    sharpness: np.ndarray
    weight: np.ndarray
    iterations: int = 0

    def __post_init__(self):
        self.axes = np.asarray(self.axes, np.float64).reshape(-1, 3)
        self.sharpness = np.asarray(self.sharpness, np.float64).reshape(-1)
        self.weight = np.asarray(self.weight, np.float64).reshape(-1)
        j = len(self.axes)
        if not (1 <= j <= MAX_LOBES) or self.sharpness.shape != (j,) or self.weight.shape != (j,):
            raise ValueError(f"a LobeSet needs 1..{MAX_LOBES} lobes with one sharpness and weight each")
        if not (np.all(np.isfinite(self.axes)) and np.all(self.sharpness > 0) and np.all(np.isfinite(self.sharpness))):
            raise ValueError("lobe axes must be finite and sharpness finite and > 0")
        length = np.linalg.norm(self.axes, axis=1, keepdims=True)
        if not np.all(length > 1e-12):
            raise ValueError(f"lobe axes must be non-zero directions (lobe {int(np.argmin(length))} is 0)")
        self.axes = self.axes / length

    def __len__(self):
        return len(self.axes)

    @property
    def log_weight(self) -> np.ndarray:
        """log α_j + log of the vMF normalisation η/(2π(1 − e^{−2η})): the E-step's per-lobe constant
        (−inf for a dead lobe, so that it takes no responsibility)."""
        eta = self.sharpness
        with np.errstate(divide="ignore"):
            log_alpha = np.where(self.weight > 0, np.log(np.where(self.weight > 0, self.weight, 1.0)), -np.inf)
        return log_alpha + np.log(eta) - np.log(2 * np.pi) - np.log(-np.expm1(-2 * eta))

    def alive(self) -> LobeSet:
        """The lobes of weight > 0."""
        live = self.weight > 0
        if live.all():
            return self
        return LobeSet(self.axes[live], self.sharpness[live], self.weight[live], self.iterations)

    def ndf(self, n, area: float = 1.0) -> np.ndarray:
        """Γ(n) ≈ Σ_j area·α_j·vMF_j(n), per steradian."""
        amp = area * self.weight * self.sharpness / (2 * np.pi * -np.expm1(-2 * self.sharpness))
        return sg.evaluate(np.asarray(n, np.float64)[..., None, :], self.axes, self.sharpness, amp).sum(-1)


def _mean_resultant_to_sharpness(rbar):
    """Solve coth κ − 1/κ = r̄ (the 3-D vMF's mean resultant length) for κ, by Newton's method
    from Banerjee's approximation κ ≈ r̄(3 − r̄²)/(1 − r̄²); r̄ → 1 (a delta) gives `SHARPNESS_MAX`."""
    rbar = np.clip(np.asarray(rbar, np.float64), 1e-9, 1.0)
    kappa = np.full_like(rbar, sg.SHARPNESS_MAX)
    live = rbar < 1.0 - 1e-12
    r = rbar[live]
    k = r * (3 - r * r) / (1 - r * r)
    for _ in range(20):
        big = k > 20  # coth κ = 1 to double precision
        coth = np.where(big, 1.0, 1.0 / np.tanh(np.where(big, 1.0, k)))
        f = coth - 1.0 / k - r
        df = 1.0 / k**2 - np.where(big, 0.0, 1.0 / np.sinh(np.where(big, 1.0, k)) ** 2)
        k_new = np.maximum(k - f / np.where(df > 0, df, 1.0), 1e-9)
        # Converged: Newton's next step would move κ by ~(1e−12)², below float64 (waiting for an exact
        # fixed point instead ran all 20 steps, as some κ oscillate in their last bit).
        settled = np.all(np.abs(k_new - k) <= 1e-12 * k)
        k = k_new
        if settled:
            break
    kappa[live] = k
    return np.clip(kappa, sg.SHARPNESS_MIN, sg.SHARPNESS_MAX)


def initial_lobes(normal, area, count: int, resolution: int = START_RES, coarse_bins=None) -> LobeSet:
    """Deterministic start for EM: the facets' normals binned on a coarse cube map, the heaviest bin
    first, then repeatedly the bin farthest (weighted by its area) from every axis chosen so far.
    Stops early when every bin sits on a chosen axis (fewer distinct normals than `count`).
    `coarse_bins`: each normal's coarse bin (`directions.cube_bin` at `resolution`) when the caller
    knows it already (the bake derives it from the normals' fine bins)."""

    normal = np.asarray(normal, np.float64)
    area = np.asarray(area, np.float64)
    bins = cube_bin(normal, resolution) if coarse_bins is None else np.asarray(coarse_bins, np.int64)
    used = np.zeros(6 * resolution * resolution, np.int64)  # the non-empty coarse bins, by counting
    used[bins] = 1
    inv = (np.cumsum(used) - 1)[bins]
    w = np.bincount(inv, weights=area)
    # The bins' mean normals as (3, M), components along the rows: numpy then loops along the bins (with
    # the 3 components innermost, ~4× slower per operation; this runs between the device's stages).
    mean = np.stack([np.bincount(inv, weights=area * normal[:, c]) for c in range(3)])
    norm = np.sqrt((mean * mean).sum(0))
    mean = mean / np.where(norm > 0, norm, 1.0)

    def one_minus_cos(b):  # 1 − n·n_b for every bin, as ‖n − n_b‖²/2 (sg.one_minus_cos)
        d = mean - mean[:, b:b + 1]
        return 0.5 * (d * d).sum(0)

    chosen = [int(np.argmax(w))]
    dist = one_minus_cos(chosen[0])
    threshold = 1e-12 * w.sum()
    while len(chosen) < count:
        score = w * dist
        best = int(np.argmax(score))
        if score[best] <= threshold:
            break
        chosen.append(best)
        dist = np.minimum(dist, one_minus_cos(best))
    axes = mean[:, chosen].T
    # Hard-assign bins to the nearest axis for the starting weight and sharpness.
    owner = np.argmax(axes @ mean, axis=0)
    weight = np.bincount(owner, weights=w, minlength=len(axes))
    resultant = np.sqrt(sum(np.bincount(owner, weights=w * mean[c], minlength=len(axes)) ** 2 for c in range(3)))
    # Banerjee's κ ≈ r̄(3 − r̄²)/(1 − r̄²), within a few per cent of the vMF's exact κ: enough for a start.
    rbar = np.clip(resultant / np.maximum(weight, 1e-300), 0.0, 1.0 - 1e-12)
    sharp = np.clip(rbar * (3 - rbar * rbar) / (1 - rbar * rbar), 1.0, 1e4)
    return LobeSet(axes, sharp, weight / weight.sum())


def m_step(stats, previous: LobeSet) -> LobeSet:
    """The M-step from E-step sums `stats` (J, 4) = [Σ r ΔA, Σ r ΔA n]. A lobe holding at most
    `DEAD_MASS` of the area dies: weight 0, axis and sharpness kept (the device M-step, kernels/em.py
    `em_m_step`, is this function in float64)."""
    stats = np.asarray(stats, np.float64)
    mass = stats[:, 0]
    keep = mass > DEAD_MASS * mass.sum()
    if not keep.any():
        return previous
    length = np.linalg.norm(stats[:, 1:], axis=1)
    live = keep & (length > 0)
    axes = previous.axes.copy()
    axes[live] = stats[live, 1:] / length[live, None]
    sharp = previous.sharpness.copy()
    sharp[keep] = _mean_resultant_to_sharpness(length[keep] / mass[keep])
    weight = np.where(keep, mass, 0.0) / mass[keep].sum()
    return LobeSet(axes, sharp, weight, previous.iterations + 1)


def converged(a: LobeSet, b: LobeSet, tol: float = CONVERGENCE_TOL) -> bool:
    """EM has settled from `b` to `a`: no lobe died, and each live lobe's axis moved less than `tol`
    rad, its sharpness by less than 10·`tol` relative, its weight by less than `tol`. (Tighter than
    the NDF's own sampling noise at 2¹⁶ facets, ~1e−3.)"""
    if len(a) != len(b):
        return False
    live = a.weight > 0
    if np.any((b.weight > 0) & ~live):
        return False
    return bool(np.all(sg.one_minus_cos(a.axes[live], b.axes[live]) < 0.5 * tol * tol)
                and np.all(np.abs(np.log(a.sharpness[live] / b.sharpness[live])) < 10 * tol)
                and np.all(np.abs(a.weight[live] - b.weight[live]) < tol))


def fit(backend, facets, start: LobeSet, iterations: int, facet_weight=None) -> LobeSet:
    """Spherical EM from `start` on the device: at most `iterations` steps, stopping after the first
    step that `converged`; dead lobes dropped. Each facet weighs its area, or `facet_weight` (Ns,).
    `iterations` of the result counts the steps taken."""
    return from_em(start, backend.ndf_em(facets, start.axes, start.sharpness, start.weight, int(iterations),
                                         facet_weight))


def from_em(start, result) -> LobeSet:
    """The live lobes of an EM from `start` (a LobeSet, or `Backend.em_start`'s DeviceStart: no steps
    before), given what `Backend.ndf_em` returned (axes, sharpness, weight, steps)."""
    axes, sharpness, weight, steps = result
    before = start.iterations if isinstance(start, LobeSet) else 0
    return LobeSet(axes, sharpness, weight, before + int(steps)).alive()


def amplitude_system(lobes: LobeSet, bin_normal=None, bin_area=None):
    """→ (solve_rows (J, J), integrals (J,), gram (J, J), condition number).

    Iwasaki's amplitudes solve A μ = b per direction pair, A_ij = ∫G_iG_j (unit amplitudes), the
    same matrix for every pair: it is inverted once here (regularised on its unit diagonal, ridge
    `RIDGE`, so near-duplicate lobes cannot blow the amplitudes up).

    Calibration (our addition): least squares against data sharper than its lobe over-weights the
    lobe, up to twice for a delta (a flat facet, capped sharpness): ⟨δ, G⟩/⟨G, G⟩ = η/π where η/2π
    keeps ∫. With the NDF the lobes were fitted to (bins `bin_normal`, `bin_area`: in the bake the
    facets weighted by `reference.visible_weights`, no pair's visibility or cosines) the
    right amplitude of lobe j is known, A·α_j·η_j/(2π(1 − e^{−2η_j})) from EM, so each row is scaled
    by (that) / (A⁻¹b_NDF)_j, which is 1/2 for a delta lobe and ~1 for a lobe that matches its data.
    The solve kernel then keeps the energy of γ̃ exact (see `reference.solve_amplitudes`).
    """
    ax, eta = lobes.axes, lobes.sharpness
    gram = sg.inner_product(ax[:, None, :], eta[:, None], 1.0, ax[None, :, :], eta[None, :], 1.0)
    integrals = sg.integral(eta)
    d = np.sqrt(np.diag(gram))
    unit = gram / np.outer(d, d) + RIDGE * np.eye(len(eta))
    inv = np.linalg.inv(unit) / np.outer(d, d)
    if bin_normal is not None:
        area = np.asarray(bin_area, np.float64)
        # G_j at every bin as exp(η_j(n·ξ_j − 1)) by one matrix product: 1 − n·ξ loses ~1e−16 near
        # n = ξ (sg.one_minus_cos is exact there), a relative 1e−10 at the largest η, 10⁶. Laid out (J, L),
        # lobes along the rows: with J innermost numpy loops over rows of 8 (about 1.4× slower on a
        # height field's bins at J = 8).
        # (In place, one (J, L) array: fresh temporaries of this size cost page faults, several times
        # the line's own time; bench/README.md.)
        x = ax @ np.asarray(bin_normal, np.float64).T
        x -= 1.0
        x *= eta[:, None]
        b_ndf = np.exp(x, out=x) @ area
        lsq = inv @ b_ndf
        target = area.sum() * lobes.weight * eta / (2 * np.pi * -np.expm1(-2 * eta))
        scale = np.where(lsq > 1e-12 * target.max(), target / np.where(lsq > 0, lsq, 1.0), 1.0)
        inv = inv * scale[:, None]
    return inv, integrals, gram, float(np.linalg.cond(unit))


def solve_amplitudes(moments, a_v, pair_i, pair_o, n_dirs: int, rows, integrals) -> np.ndarray:
    """(P, J) float32 amplitudes for the ordered pairs, on the host in float64: `reference.solve_amplitudes`
    vectorised over the pairs (the bake's solve when J > KERNEL_LOBES, beyond the solve kernel's registers).
    `moments` (U, J + 1) over the unordered pairs i ≤ o (`directions.unordered_pairs` order)."""
    moments = np.asarray(moments, np.float64)
    rows = np.asarray(rows, np.float64)
    integrals = np.asarray(integrals, np.float64)
    j = len(integrals)

    pi, po = np.asarray(pair_i, np.int64), np.asarray(pair_o, np.int64)
    m = moments[unordered_index(pi, po, n_dirs)]
    area = np.asarray(a_v, np.float64)[po]
    live = (area > 0) & (m[:, j] > 0)
    safe = np.where(live, area, 1.0)
    b, c = m[:, :j] / safe[:, None], m[:, j] / safe
    mu = np.maximum(b @ rows.T, 0.0)
    total = mu @ integrals
    mu *= np.where(total > 0, c / np.where(total > 0, total, 1.0), 0.0)[:, None]
    # Every amplitude clamped: all of ∫γ̃ goes to the lobe with the largest b_j.
    none = live & ~(total > 0)
    best = np.argmax(m[:, :j], axis=1)
    mu[none, best[none]] = c[none] / integrals[best[none]]
    mu[~live] = 0.0
    return mu.astype(np.float32)

def ndf_error(lobes: LobeSet, bin_normal, bin_area, probe_sharpness: float) -> float:
    """Relative RMS error of the fitted NDF seen through probe SGs of sharpness `probe_sharpness`.

    The probes sit on the non-empty normal bins (`bin_normal`, area `bin_area`); for each, the data
    gives Σ_l Γ_l G_q(n_l) and the lobes give Σ_j A α_j ⟨vMF_j, G_q⟩ (closed form). This is the NDF
    error a small-scale lobe of that sharpness sees (Iwasaki Eq. 10 without the pair's visibility;
    the bake passes the NDF weighted by `reference.visible_weights`, the one its lobes fit), and it
    is finite for a delta NDF, unlike a pointwise comparison.
    """
    bn = np.asarray(bin_normal, np.float64)
    ba = np.asarray(bin_area, np.float64)
    total = ba.sum()
    if len(bn) > 2048:  # the heaviest bins carry the error that matters; keep the probe count bounded
        bn_q = bn[np.argsort(-ba)[:2048]]
    else:
        bn_q = bn
    data = sg.evaluate(bn[None, :, :], bn_q[:, None, :], probe_sharpness) @ ba
    amp = total * lobes.weight * lobes.sharpness / (2 * np.pi * -np.expm1(-2 * lobes.sharpness))
    model = sg.inner_product(bn_q[:, None, :], probe_sharpness, 1.0, lobes.axes[None], lobes.sharpness[None],
                             amp).sum(1)
    return float(np.sqrt(np.sum((data - model) ** 2) / max(np.sum(data**2), 1e-300)))
