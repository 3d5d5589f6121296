"""Anisotropic spherical Gaussians (Xu et al. 2013): the float64 reference of their operators.

Conventions (docs/design.md §4, §9)
-------------------------------------------------------
    G(v; [x, y, z], [λ, μ], c) = c · max(v·z, 0) · exp(−λ(v·x)² − μ(v·y)²)          (Xu Eq. 1)

[x, y, z] orthonormal (either handedness), bandwidths λ, μ ≥ 0 (Xu asks > 0; 0 is allowed here: μ = 0 is
a band), amplitude c. Every array broadcasts over leading axes: x, y, z (..., 3); λ, μ, c (...).
Xu's bandwidth μ is *not* our SG amplitude μ: in code the bandwidths are `lam`, `mu`, the amplitude
`amplitude`. Our SG (sg.py) is a·exp(η(v·ξ − 1)); Xu's isotropic SG is exp(2ν(v·p − 1)), so an SG of
sharpness η is Xu's ν = η/2 — the trap every conversion below goes through (`from_sg`, `convolve_sg`,
`visible_fraction`).

The identity everything rests on: in the disk coordinates (a, b) = (v·x, v·y) of the hemisphere v·z > 0,
dω = da db / (v·z), so the smooth term cancels the Jacobian and

    G(v) dω = c · exp(−λa² − μb²) da db   on the unit disk a² + b² < 1.

An ASG is a 2-D Gaussian truncated to the unit disk. This gives the exact integral (`unit_integral`
"exact") and exact importance sampling (`sample`).

What each function computes, and how accurately (measured against brute-force float64 quadrature in
tests/test_asg.py; the quadrature itself is shown there to be accurate to < 1e−12 relative):

- `evaluate`, `rotate`, `ASG(...)`: exact. Every exponent is ≤ 0: no overflow at λ, μ = 1e6 or beyond.
- `from_sg(axis, η, a)`: Xu's Eq. 3 link λ = μ = η/2. *Not* the same function: with t = v·ξ the ASG is
  a·t⁺·e^{−ν(1−t²)} and the SG a·e^{−2ν(1−t)}, their ratio t·e^{ν(1−t)²}. The ASG is 0 below the
  horizon, its integral π(1 − e^{−ν})/ν against the SG's π(1 − e^{−4ν})/ν (relative difference
  ≈ −e^{−ν}: −0.67 % at η = 10, 2e−22 at η = 100), its peak curvature that of an SG of sharpness η + 1;
  measured, their relative L2 difference over S² is √2/(4η) (3.6 % at η = 10, 0.035 % at η = 1000;
  derived from the log-ratio −u + νu², u = 1 − t) and their largest pointwise difference ≈ 0.23·a/η
  (2.4 % of the peak at η = 10, 0.023 % at η = 1000).
- `unit_integral` / `integral`:
    "exact" (default): π∫₀¹ e^{−sμ'} i0e(s(λ' − μ')/2) ds (μ' = min, λ' = max), a 1-D integral of a
      smooth positive function (derived here: Xu Eq. 5 is (1 − e^{−k})/(2k) = ½∫₀¹e^{−sk}ds, and
      ∫₀^{2π} e^{−s(λcos²φ + μsin²φ)} dφ = 2π e^{−sμ'} i0e(s(λ'−μ')/2)), by Gauss–Legendre on graded panels
      in t = √s, ~400 nodes. Relative error < 1e−13 against brute force for λ, μ ∈ [0, 1e6] (bands, λ = μ,
      (0, 0) included) and against closed forms up to 1e12. Two closed forms bound it: λ = μ = k gives
      π(1 − e^{−k})/k, a band (μ = 0) π(i0e(λ/2) + i1e(λ/2)) (both to 2e−16 here).
    "eq10": Xu Eq. 10 with F(a) = 2π·i0e(a/2), rearranged without cancellation. Measured worst relative
      error 0.0259 % for λ, μ ≥ 5 (Xu: < 0.027 %), 5.13 % for λ, μ ≥ 1 (Xu: < 5.2 %), exact for λ = μ. It
      diverges as min(λ, μ) → 0 (its Gaussian fit of 1/(λcos²φ + μsin²φ), Eq. 8, loses the Lorentzian's
      mass): +35 % at (1, 0.1), ×4 at (10, 0.01); +∞ at μ = 0. Never use it for a band.
    "eq11": π/√(λμ): worst 0.678 % for λ, μ ≥ 5 (Xu: < 0.68 %), at λ = μ = 5; +58 % at (1, 1).

Error metrics below: relative L2 = ‖approx − truth‖₂/‖truth‖₂ over S². Xu's supplement, which defines his
L2 error, is not in our copy of the paper; his Fig. 5 caption ("inputs normalised to unit integral")
suggests an absolute L2 of normalised inputs, which tests/test_asg.py also reports ("Xu-style").

- `product` (Eq. 13): the exponents add exactly; the error is the smooth terms taken constant at the new
  peak. Relative L2, Xu Fig. 4's pairs: 2.0–2.9 % with the axes aligned (cos² against cos), 23–31 % at
  z1·z2 = 0.4, 60–80 % as z1·z2 → 0 (where the product vanishes); a sharp pair (100, 50)×(200, 80):
  0.2 % aligned, 4.8 % at z1·z2 = 0.4. Xu gives no number.
- `convolve_sg` (Eq. 18): Xu's "< 0.2 % for λ, μ > 3 whatever ν" is NOT reproduced. Relative L2:
  (5, 5, ν = 1) 35 %, (40, 1, 10) 3.9 %, (100, 10, 100) 0.46 % (Xu Fig. 6's examples), (3, 3, 10) 4.6 %,
  (100, 100, 1000) 0.056 %. Where the kernel is the broader (ν ≪ λ, μ) the true C is the SG kernel itself
  and the error is from_sg's shape difference at η = 2ν, √2/(8ν) (1.8 % at (1000, 1000, 10), as
  measured); it falls as the result sharpens and as the ASG dominates (ν ≫ λ, μ).
- `warp` (Eq. 23–26): the Hessian of the supplement (not in our copy) is derived in `warp_hessian` and
  checked by finite differences; isotropic lobes reduce to Wang's η/(4 o·ξ) as the geometric mean.
  Relative L2 against G_h(h(i)), normal view / θo = 30° / 60°: (1e4, 1e4) 0.01 / 0.06 / 0.6 %;
  (1000, 100) 0.4 / 5 / 11 %; (100, 10) 3 / 15 / 30 %; (1e4, 10) 3 / 78 / 93 % (a long streak bends
  on a small circle no ASG follows).
- `visible_fraction` / `occlude` (Xu §5.3, Eq. 27–28): sg.visible_fraction at the effective SG sharpness
  2√(λμ) (Xu writes √(λμ) in Wang's f_h, whose bandwidth is our η: by Xu's own Eq. 3 that is a factor 2
  too broad). Absolute error of the fraction, worst over θd and the boundary's orientation: λ = μ = 10:
  0.0045 (0.078 with √(λμ)); (40, 10): 0.083; (1000, 10): 0.25; a band: 0.35.
- `sample` / `pdf`: exact and unbiased (truncated-Gaussian inverse CDF per disk coordinate, rejection
  outside the unit disk; acceptance π/4 for the uniform cosine lobe, → 1 for sharp lobes); χ² tests pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf, erfinv, i0e

from . import sg
from .smallscale import cross_rows

__all__ = ["ASG", "evaluate", "rotate", "from_sg", "unit_integral", "integral", "product", "convolve_sg",
           "convolve_asg", "convolve_sg_at", "convolve_sg_local", "warp", "warp_hessian", "effective_sharpness",
           "visible_fraction", "occlude", "sample", "pdf", "tangent_frame"]

_ORTHO_TOL = 1e-6  # a frame further than this from orthonormal is an error, not rounding


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def tangent_frame(z):
    """Orthonormal (x, y) with (x, y, z) right-handed, continuous except across z_z = 0 (Duff et al. 2017:
    no division by a vanishing component, so it is exact for every unit z, poles included)."""
    z = np.asarray(z, np.float64)
    zx, zy, zz = z[..., 0], z[..., 1], z[..., 2]
    sign = np.where(zz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + zz)
    b = zx * zy * a
    x = np.stack([1.0 + sign * zx * zx * a, sign * b, -sign * zx], axis=-1)
    y = np.stack([b, sign + zy * zy * a, -zy], axis=-1)
    return x, y


def _check_finite(name, arr):
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"ASG: {name} must be finite (got {arr[~np.isfinite(arr)].ravel()[0]})")


@dataclass(frozen=True, eq=False)
class ASG:
    """A batch of ASGs G(v) = amplitude·max(v·z, 0)·exp(−lam(v·x)² − mu(v·y)²) (Xu Eq. 1).

    x, y, z: (..., 3) orthonormal frames (within 1e−6; re-orthonormalised here, z kept, y's handedness
    kept); lam, mu: (...) bandwidths ≥ 0; amplitude: (...) finite. All broadcast to one batch shape.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    lam: np.ndarray
    mu: np.ndarray
    amplitude: np.ndarray = 1.0

    def __post_init__(self):
        arrays = {}
        for name in ("x", "y", "z", "lam", "mu", "amplitude"):
            arr = np.asarray(getattr(self, name), np.float64)
            _check_finite(name, arr)
            arrays[name] = arr
        for name in ("x", "y", "z"):
            if arrays[name].ndim == 0 or arrays[name].shape[-1] != 3:
                raise ValueError(f"ASG: {name} must have shape (..., 3) (got {arrays[name].shape})")
        for name in ("lam", "mu"):
            if np.any(arrays[name] < 0):
                raise ValueError(f"ASG: {name} must be >= 0 (got {arrays[name].min()})")
        try:
            shape = np.broadcast_shapes(arrays["x"].shape[:-1], arrays["y"].shape[:-1], arrays["z"].shape[:-1],
                                        arrays["lam"].shape, arrays["mu"].shape, arrays["amplitude"].shape)
        except ValueError:
            raise ValueError("ASG: x, y, z (..., 3) and lam, mu, amplitude (...) do not broadcast to one shape"
                             ) from None
        x, y, z = (np.broadcast_to(arrays[n], shape + (3,)) for n in ("x", "y", "z"))
        gram = np.stack([_dot(x, x) - 1, _dot(y, y) - 1, _dot(z, z) - 1, _dot(x, y), _dot(y, z), _dot(z, x)])
        worst = float(np.max(np.abs(gram))) if gram.size else 0.0
        if worst > _ORTHO_TOL:
            raise ValueError(f"ASG: frame [x, y, z] is not orthonormal (largest Gram deviation {worst:.2e})")
        # Re-orthonormalise (z kept): the operators below (product's quadratic form, warp's Jacobian, sample's
        # v = a·x + b·y + t·z) assume an exact frame, and v = z then gives exactly the amplitude.
        z = _normalize(z)
        x = _normalize(x - _dot(x, z)[..., None] * z)
        zx = cross_rows(z, x)
        y = np.where((_dot(zx, y) >= 0)[..., None], zx, -zx)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "z", z)
        for n in ("lam", "mu", "amplitude"):
            object.__setattr__(self, n, np.broadcast_to(arrays[n], shape).copy())

    @property
    def shape(self):
        return self.lam.shape

    @classmethod
    def from_axis(cls, z, x_hint, lam, mu, amplitude=1.0):
        """An ASG with lobe axis z and tangent x along the part of x_hint perpendicular to z."""
        z = _normalize(np.asarray(z, np.float64))
        x = np.asarray(x_hint, np.float64)
        x = x - _dot(x, z)[..., None] * z
        n = np.linalg.norm(x, axis=-1, keepdims=True)
        if np.any(n < 1e-9):
            raise ValueError("ASG.from_axis: x_hint is parallel to z")
        x = x / n
        return cls(x, cross_rows(z, x), z, lam, mu, amplitude)

    def __getitem__(self, index):
        # A part of a checked batch: its frames are orthonormal and its arrays broadcast, so it is not checked
        # and re-orthonormalised again (what most of the ASG bake's Gram matrix time went to). The vectors are
        # indexed on their batch axes only, so `...` and every other index select whole lobes.
        part = object.__new__(ASG)
        on_batch = (index if isinstance(index, tuple) else (index,)) + (slice(None),)
        for name in ("x", "y", "z"):
            object.__setattr__(part, name, np.array(getattr(self, name)[on_batch]))
        for name in ("lam", "mu", "amplitude"):
            object.__setattr__(part, name, np.array(getattr(self, name)[index]))
        if part.x.ndim == 0 or part.x.shape[:-1] != part.lam.shape:
            raise IndexError(f"ASG: index {index!r} does not select whole lobes")
        return part


def evaluate(asg: ASG, v):
    """G(v) = c·max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²); v (..., 3) broadcasts with the batch shape."""
    v = np.asarray(v, np.float64)
    a, b, t = _dot(v, asg.x), _dot(v, asg.y), _dot(v, asg.z)
    return asg.amplitude * np.maximum(t, 0.0) * np.exp(-asg.lam * a * a - asg.mu * b * b)


def rotate(asg: ASG, rotation):
    """The ASG v ↦ G(Rᵀv) for an orthogonal R (..., 3, 3): its frame is turned by R."""
    r = np.asarray(rotation, np.float64)
    _check_finite("rotation", r)
    bad = r.ndim < 2 or r.shape[-2:] != (3, 3)
    if bad or np.max(np.abs(np.einsum("...ji,...jk->...ik", r, r) - np.eye(3))) > _ORTHO_TOL:
        raise ValueError("rotate: rotation must be an orthogonal (..., 3, 3) matrix")
    turn = lambda u: np.einsum("...ij,...j->...i", r, u)  # noqa: E731
    return ASG(turn(asg.x), turn(asg.y), turn(asg.z), asg.lam, asg.mu, asg.amplitude)


def from_sg(axis, sharpness, amplitude=1.0):
    """Xu Eq. 3: the SG a·exp(η(v·ξ − 1)) as the isotropic ASG with λ = μ = ν = η/2 and c = a.

    Approximate, not equal (see the module notes): same peak, same integral up to a relative e^{−η/2},
    the ASG 0 below the horizon; pointwise difference ≈ 0.23·a/η at most, relative L2 difference √2/(4η)."""
    axis = _normalize(np.asarray(axis, np.float64))
    eta = np.asarray(sharpness, np.float64)
    if np.any(eta < 0):
        raise ValueError("from_sg: sharpness must be >= 0")
    x, y = tangent_frame(axis)
    return ASG(x, y, axis, eta / 2.0, eta / 2.0, amplitude)


# ---------------------------------------------------------------------------------------------------
# Integral (Xu §4.1)
# ---------------------------------------------------------------------------------------------------

_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
_PANELS = 24


def _integral_exact(lam, mu):
    """π∫₀¹ e^{−s·lo} i0e(s(hi − lo)/2) ds by Gauss–Legendre in t = √s (ds = 2t dt, which removes the
    1/√s shape i0e takes for a large argument) on one panel [0, t0] and 24 geometric panels [t0, 1],
    t0 = 0.25/√(1 + hi): on [0, t0] the exponents are ≤ 1/16 (a near-polynomial), and beyond it the
    integrand's two scales 1/√lo and 1/√(hi − lo) each span several panels of 16 nodes."""
    lo, hi = np.minimum(lam, mu), np.maximum(lam, mu)
    t0 = 0.25 / np.sqrt(1.0 + hi)
    edges = t0[..., None] ** (1.0 - np.arange(_PANELS + 1) / _PANELS)  # t0 … 1, geometric
    edges = np.concatenate([np.zeros_like(t0)[..., None], edges], axis=-1)
    left, right = edges[..., :-1, None], edges[..., 1:, None]
    t = left + (right - left) * 0.5 * (_GL_X + 1.0)
    w = (right - left) * 0.5 * _GL_W
    s = t * t
    f = 2.0 * t * np.exp(-s * lo[..., None, None]) * i0e(s * (hi - lo)[..., None, None] / 2.0)
    return np.pi * np.sum(w * f, axis=(-2, -1))


def _i0e_minus_one(x):
    """e^{−x}I0(x) − 1 without cancellation at small x (series of I0 − 1 below 0.5)."""
    x = np.asarray(x, np.float64)
    q = (np.minimum(x, 0.5) / 2.0) ** 2
    term, series = np.ones_like(q), np.zeros_like(q)
    for k in range(1, 10):
        term = term * q / (k * k)
        series = series + term
    return np.where(x < 0.5, np.exp(-x) * series + np.expm1(-x), i0e(x) - 1.0)


def _integral_eq10(lam, mu):
    """Xu Eq. 10, λ ≥ μ, ν = λ − μ, F(a) = 2π·i0e(a/2):
        π/√(λμ) − e^{−μ}/(2λ)·(F(ν) + (ν/μ)F(ν + ν/μ))
    written as (π/λ)·[ν/(√(λμ) + μ) − expm1(−μ) − e^{−μ}(i0e(ν/2) − 1) − e^{−μ}(ν/μ)i0e((ν + ν/μ)/2)],
    using π/√(λμ) = (π/λ)(1 + ν/(√(λμ) + μ)): the two large terms' common π/λ cancels analytically, so
    λ = μ gives π(1 − e^{−μ})/μ to the last bit (Eq. 10 is exact there) and λ = μ → 0 gives π."""
    hi, lo = np.maximum(lam, mu), np.minimum(lam, mu)
    nu = hi - lo
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = np.where(nu > 0, nu / lo, 0.0)  # ν/μ, 0 when λ = μ (also λ = μ = 0)
        band = np.where(nu > 0, ratio * i0e(0.5 * (nu + ratio)), 0.0)
        bracket = (nu / (np.sqrt(hi * lo) + lo) - np.expm1(-lo) - np.exp(-lo) * _i0e_minus_one(nu / 2.0)
                   - np.exp(-lo) * band)
        value = np.where(hi > 0, np.pi / hi * bracket, np.pi)
    # min(λ, μ) = 0 < max: Eq. 10 diverges (its limit is +∞), and so does Eq. 11.
    return np.where((lo == 0) & (hi > 0), np.inf, np.where(np.isfinite(value), value, np.inf))


def unit_integral(lam, mu, method="exact"):
    """∫_S² max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) dv for bandwidth arrays λ, μ ≥ 0 (amplitude 1).

    method "exact" (default; the oracle, < 1e−13 relative), "eq10" (Xu Eq. 10) or "eq11" (π/√(λμ)).
    The module notes give each one's measured error; Eq. 10 and 11 are +∞ on a band (min(λ, μ) = 0)."""
    lam, mu = np.broadcast_arrays(np.asarray(lam, np.float64), np.asarray(mu, np.float64))
    if np.any(~np.isfinite(lam) | ~np.isfinite(mu) | (lam < 0) | (mu < 0)):
        raise ValueError("unit_integral: bandwidths must be finite and >= 0")
    if method == "exact":
        iso = lam == mu  # (an isotropic lobe's integral in closed form, π(1 − e^{−λ})/λ: an SG's, Xu's ν = η/2)
        if not iso.any():
            return _integral_exact(lam, mu)
        out = np.empty(lam.shape)
        k = lam[iso]
        out[iso] = np.where(k > 0, -np.pi * np.expm1(-k) / np.where(k > 0, k, 1.0), np.pi)
        if not iso.all():
            out[~iso] = _integral_exact(lam[~iso], mu[~iso])
        return out[()]  # (a scalar for scalar bandwidths, as the quadrature's)
    if method == "eq10":
        return _integral_eq10(lam, mu)
    if method == "eq11":
        with np.errstate(divide="ignore"):
            return np.pi / np.sqrt(lam * mu)
    raise ValueError(f"unit_integral: method must be 'exact', 'eq10' or 'eq11' (got {method!r})")


# Where both bandwidths exceed this, Xu's Eq. 10 is within 0.027 % of the integral (Xu; measured in the module
# notes) and costs a few exponentials against the kernels' 56-node rule: what the shade kernels use.
EQ10_MIN_BANDWIDTH = 5.0

_RULE_X, _RULE_W = np.polynomial.legendre.leggauss(8)
_RULE_PANELS = 6  # geometric panels between t0 and 1 (kernels/asg.py's INTEGRAL_PANELS)


def rule_integral(lam, mu):
    """The unit integral by the kernels' rule (kernels/asg.py `asg_unit_integral`) in float64: the exact form's
    integrand 2t·e^{−t²μ'}·i0e(t²(λ' − μ')/2) by 8-node Gauss–Legendre on [0, t0], t0 = 1/√(1 + λ'), and on six
    geometric panels t0 … 1; within 2.7e−7 of `unit_integral` for λ, μ ≤ 1e6 (tests/test_asg_kernels.py), at
    56 nodes against the exact quadrature's 400."""
    lam, mu = np.broadcast_arrays(np.asarray(lam, np.float64), np.asarray(mu, np.float64))
    lo, hi = np.minimum(lam, mu)[..., None, None], np.maximum(lam, mu)
    edges = np.exp((1.0 - np.arange(_RULE_PANELS + 1) / _RULE_PANELS) * (-0.5 * np.log1p(hi))[..., None])
    edges = np.concatenate([np.zeros(hi.shape + (1,)), edges], axis=-1)
    mid, width = 0.5 * (edges[..., 1:] + edges[..., :-1]), 0.5 * (edges[..., 1:] - edges[..., :-1])
    t = mid[..., None] + width[..., None] * _RULE_X
    s = t * t
    f = 2.0 * t * np.exp(-s * lo) * i0e(s * (0.5 * (hi[..., None, None] - lo)))
    return np.pi * np.sum(width[..., None] * _RULE_W * f, axis=(-2, -1))


def shade_integral(lam, mu):
    """The unit integral as the shade kernels take it: Eq. 10 where min(λ, μ) > EQ10_MIN_BANDWIDTH, else the
    kernels' rule (`rule_integral`)."""
    lam, mu = np.broadcast_arrays(np.asarray(lam, np.float64), np.asarray(mu, np.float64))
    big = np.minimum(lam, mu) > EQ10_MIN_BANDWIDTH
    out = np.empty(lam.shape)
    out[big] = unit_integral(lam[big], mu[big], "eq10")
    if not big.all():  # (the quadrature only where Eq. 10 does not hold)
        out[~big] = rule_integral(lam[~big], mu[~big])
    return out


def integral(asg: ASG, method="exact"):
    """∫_S² G(v) dv = c·unit_integral(λ, μ, method)."""
    return asg.amplitude * unit_integral(asg.lam, asg.mu, method)


# ---------------------------------------------------------------------------------------------------
# Product (Xu §4.2, Eq. 12–13)
# ---------------------------------------------------------------------------------------------------

def _quadratic_form(asg: ASG):
    """A = λxxᵀ + μyyᵀ (Xu Eq. 2 with the smallest eigenvalue 0): G = c·max(v·z, 0)·exp(−vᵀAv)."""
    return (asg.lam[..., None, None] * asg.x[..., :, None] * asg.x[..., None, :]
            + asg.mu[..., None, None] * asg.y[..., :, None] * asg.y[..., None, :])


def product(g1: ASG, g2: ASG) -> ASG:
    """Xu Eq. 13: G1·G2 ≈ S(z3; z1, z2)·e^{−w3}·G(v; [x3, y3, z3], [w1 − w3, w2 − w3]).

    A3 = A1 + A2 (exact: the exponents add) with eigenvalues w1 ≥ w2 ≥ w3 ≥ 0 and eigenvectors x3, y3, z3;
    the smooth terms max(v·z1, 0)·max(v·z2, 0)/max(v·z3, 0) are taken as constant, at v = z3. That is
    what the formula assumes: bandwidths ≫ 1 (the exponent changes much faster than the cosines) and z3
    inside both hemispheres; otherwise the product is small anyway (0 if z3 leaves one of them).

    z3's sign is chosen with z3·z1 + z3·z2 ≥ 0 (the eigenvector's sign is free; the peak is on the side of
    the axes). Where the smallest eigenvalue is numerically degenerate (e.g. two bands with one axis and
    μ = 0, or two λ = μ = 0 lobes), the exponent cannot choose z3, so the smooth term does: z3 is z1 + z2
    projected onto the degenerate eigenspace. Eigenvalues are known to ~eps·w1 absolutely (eigh is
    backward stable), so a bandwidth ≪ 1 next to one of 1e6 carries a ~1e−10 absolute error.

    Measured relative L2 error (tests/test_asg.py; Xu Fig. 4's pairs, z2 tilted about x or y): ex. 1
    (3, 3)×(100, 5) 2.9 % aligned, 23 % at z1·z2 = 0.4; ex. 2 (10, 1)×(100, 10) 2.1 %, 31 %; ex. 3
    (10, 1)×(1000, 10) 2.0 %, 31 %; a sharp pair (100, 50)×(200, 80) 0.20 %, 4.8 %.
    """
    a3 = _quadratic_form(g1) + _quadratic_form(g2)
    w, q = np.linalg.eigh(a3)  # ascending: w[..., 0] is the smallest
    z1, z2 = np.broadcast_arrays(g1.z, g2.z)
    zsum = z1 + z2
    tol = 1e-12 * np.maximum(w[..., 2], 1.0)  # eigh's absolute accuracy is ~eps·‖A‖: closer eigenvalues tie
    deg1 = (w[..., 1] - w[..., 0]) <= tol
    deg2 = (w[..., 2] - w[..., 0]) <= tol
    q0, q1, q2 = q[..., :, 0], q[..., :, 1], q[..., :, 2]
    # In a degenerate eigenspace, z3 is the projection of z1 + z2 on it (if that is not 0).
    proj = np.where(deg1[..., None], _dot(zsum, q0)[..., None] * q0 + _dot(zsum, q1)[..., None] * q1, q0)
    proj = np.where(deg2[..., None], zsum, proj)
    pn = np.linalg.norm(proj, axis=-1, keepdims=True)
    z3 = np.where(pn > 1e-12, proj / np.where(pn > 0, pn, 1.0), q0)
    z3 = np.where((_dot(z3, zsum) < 0)[..., None], -z3, z3)
    # x3 along the largest eigenvalue; y3 completes the frame (exactly q1 up to sign unless degenerate).
    x3 = np.where(deg2[..., None], tangent_frame(z3)[0], q2)
    x3 = _normalize(x3 - _dot(x3, z3)[..., None] * z3)
    y3 = cross_rows(z3, x3)
    lam3 = np.maximum(_dot(x3, np.einsum("...ij,...j->...i", a3, x3)) - w[..., 0], 0.0)
    mu3 = np.maximum(_dot(y3, np.einsum("...ij,...j->...i", a3, y3)) - w[..., 0], 0.0)
    smooth = np.maximum(_dot(z3, z1), 0.0) * np.maximum(_dot(z3, z2), 0.0)
    amp = g1.amplitude * g2.amplitude * smooth * np.exp(-np.maximum(w[..., 0], 0.0))
    return ASG(x3, y3, z3, lam3, mu3, amp)


# ---------------------------------------------------------------------------------------------------
# Convolution with an SG (Xu §4.3, Eq. 14–18)
# ---------------------------------------------------------------------------------------------------

def _harmonic(a, b):
    """ab/(a + b) = 1/(1/a + 1/b), 0 when either is 0 (no 0/0), the other when one is infinite."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((a > 0) & (b > 0), 1.0 / (1.0 / a + 1.0 / b), 0.0)


def convolve_sg(asg: ASG, sharpness, amplitude=1.0) -> ASG:
    """Xu Eq. 18: C(p) = ∫ G(v)·a·exp(η(v·p − 1)) dv ≈ G(p; [x, y, z], [λν/(λ + ν), μν/(μ + ν)],
    c·a·π/√((λ + ν)(μ + ν))) with ν = η/2 (Xu's SG bandwidth; our sharpness η). An ASG in p.

    Assumes (Eq. 14–15) the smooth term constant at p and v, p close to z (a tangent-plane Gaussian);
    the inner integral is taken as Eq. 11's planar π/√(...), as Xu does. Bandwidths are written in
    harmonic form, so as η → ∞ (a delta kernel) they tend to λ, μ (at η = ∞ itself the amplitude, c·a·π/√(...),
    is 0: a unit-amplitude SG's integral vanishes with its width; nothing caps η here), and a band (μ = 0)
    stays a band.

    Measured relative L2 error over p ∈ S² (tests/test_asg.py): Xu Fig. 6's examples (5, 5, ν = 1) 35 %,
    (40, 1, 10) 3.9 %, (100, 10, 100) 0.46 %; (3, 3, 1) 38 %, (3, 3, 10) 4.6 %, (1000, 1000, 10) 1.8 %,
    (100, 100, 1000) 0.056 %. Xu's "< 0.2 % for λ, μ > 3, whatever ν" is not reproduced (nor in an
    absolute L2 of normalised inputs). For ν ≪ λ, μ the true C is the SG kernel, nonzero below the horizon,
    and the ASG form carries from_sg's shape difference √2/(8ν).
    """
    nu = np.asarray(sharpness, np.float64) / 2.0
    if np.any(~(nu >= 0)):
        raise ValueError("convolve_sg: sharpness must be >= 0")
    lam, mu = asg.lam, asg.mu
    with np.errstate(divide="ignore", over="ignore"):
        amp = asg.amplitude * np.asarray(amplitude, np.float64) * np.pi / np.sqrt((lam + nu) * (mu + nu))
    return ASG(asg.x, asg.y, asg.z, _harmonic(lam, nu), _harmonic(mu, nu), amp)


def convolve_sg_at(asgs: ASG, sharpness, p):
    """(N, J) (G_j ⊛ SG)(p) for unit-amplitude ASGs G_j and the SG exp(η(v·p − 1)), at p (N, 3).

    Xu's Eq. 18 gives the bandwidths λ' = λν/(λ + ν), μ' = μν/(μ + ν) and the amplitude π/√((λ + ν)(μ + ν))
    (ν = η/2), with the ASG's shape t·exp(−λ'a² − μ'b²) ((a, b, t) = p's coordinates in the lobe's frame).
    That shape is right where the SG is the sharper (ν ≫ λ, μ: the result is G itself), but for a sharp NDF lobe
    (λ, μ ≫ ν; a delta in the limit) the result is the SG kernel, exp(2ν(t − 1)) = exp(−2ν(a² + b²)/(1 + t)),
    which Eq. 18's shape misses by from_sg's difference (√2/(8ν) relative L2: 0.2–0.5 dB on the V-grooves'
    delta lobes). Here (beyond Xu) each axis has its own s: s_x = λ'/λ, s_y = μ'/μ ∈ [0, 1] (ν/(λ + ν), ν/(μ + ν))
    and the shape is t^w·exp(−λ'a²k^{1−s_x} − μ'b²k^{1−s_y}) with k = 2/(1 + t) and w = (s_x a² + s_y b²)/(a² + b²):
    Eq. 18's shape where s = 1, the SG kernel exactly where s = 0 (a delta lobe), and in between the same peak
    value and axes as Eq. 18, its curvature at the peak raised by (1 − s)/2 along each axis."""
    p = np.asarray(p, np.float64)
    return convolve_sg_local(asgs.lam, asgs.mu, sharpness, p @ asgs.x.T, p @ asgs.y.T, p @ asgs.z.T)


def convolve_sg_local(lam, mu, sharpness, a, b, t):
    """`convolve_sg_at` elementwise (broadcast): the unit-amplitude ASG of bandwidths λ, μ convolved with the
    SG of `sharpness`, at the point whose coordinates in the lobe's frame are (a, b, t)."""
    lam, mu = np.asarray(lam, np.float64), np.asarray(mu, np.float64)
    nu = np.asarray(sharpness, np.float64) / 2.0
    lam_c, mu_c = _harmonic(lam, nu), _harmonic(mu, nu)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        amp = np.pi / np.sqrt((lam + nu) * (mu + nu))
        sx = np.clip(np.where(lam > 0, lam_c / lam, 1.0), 0.0, 1.0)
        sy = np.clip(np.where(mu > 0, mu_c / mu, 1.0), 0.0, 1.0)
        r2 = a * a + b * b
        s = np.where(r2 > 0, (sx * a * a + sy * b * b) / np.where(r2 > 0, r2, 1.0), 0.5 * (sx + sy))
        smooth = np.where(t > 0, np.maximum(t, 1e-300) ** s, 0.0)
        k = 2.0 / (1.0 + np.clip(t, 0.0, 1.0))
        expo = lam_c * a * a * k ** (1.0 - sx) + mu_c * b * b * k ** (1.0 - sy)
    return amp * smooth * np.exp(-expo)


def convolve_asg(asg: ASG, lam_s, mu_s, order=(0.0, 0.0)) -> ASG:
    """The lobe G (an ASG of the NDF) convolved with an anisotropic small-scale NDF, itself an ASG of
    bandwidths (λ_s, μ_s) about each facet's normal (`brdf.ndf_bandwidths`) whose x axis makes the angle φ with
    G's x axis, spread over the lobe's facets: `order` (..., 2) is their mean (cos 2φ, sin 2φ) (length 1: all
    facets' tangents along one line; 0: no preferred direction). Beyond Xu (whose Eq. 18 takes an isotropic
    kernel): in G's tangent plane both are Gaussians, so their convolution is the Gaussian whose covariance is the
    sum of G's, diag(1/2λ, 1/2μ), and the kernel's mean covariance over the facets,
    S = s̄·I + δ·[[o_c, o_s], [o_s, −o_c]] with s̄ = (1/2λ_s + 1/2μ_s)/2, δ = (1/2λ_s − 1/2μ_s)/2. With P = diag(λ, μ)
    the result's bandwidth matrix is C = P(I + 2SP)⁻¹ (finite for a band, λ or μ = 0, and for a delta kernel,
    S = 0: C = P) and its amplitude c·π/√(det(I + 2SP)·λ_sμ_s), which keeps the planar integral
    (π/√(λμ))·(π/√(λ_sμ_s)). The result's frame is C's eigenbasis about the same axis z. For λ_s = μ_s = η/2 it
    is `convolve_sg`'s Eq. 18 exactly."""
    lam_s, mu_s = np.asarray(lam_s, np.float64), np.asarray(mu_s, np.float64)
    if np.any(~(lam_s > 0)) or np.any(~(mu_s > 0)):
        raise ValueError("convolve_asg: the kernel's bandwidths must be > 0")
    order = np.asarray(order, np.float64)
    if order.shape[-1:] != (2,) or np.any(~np.isfinite(order)) or np.any(np.hypot(order[..., 0], order[..., 1])
                                                                        > 1 + 1e-9):
        raise ValueError("convolve_asg: order must be (..., 2), finite, of length <= 1")
    oc, os_ = order[..., 0], order[..., 1]
    sx, sy = 0.5 / lam_s, 0.5 / mu_s
    mean, half = 0.5 * (sx + sy), 0.5 * (sx - sy)
    s00, s01, s11 = mean + half * oc, half * os_, mean - half * oc
    det_s = sx * sy + half * half * np.maximum(1 - oc * oc - os_ * os_, 0.0)  # s00·s11 − s01², without cancelling
    lam, mu = asg.lam, asg.mu
    # M = I + 2SP, P = diag(λ, μ); C = P·M⁻¹ = P·adj(M)/det M, det M expanded so that no terms cancel.
    det = 1 + 2 * s00 * lam + 2 * s11 * mu + 4 * lam * mu * det_s
    c00, c11, c01 = lam * (1 + 2 * s11 * mu) / det, mu * (1 + 2 * s00 * lam) / det, -2 * lam * mu * s01 / det
    big = 0.5 * (c00 + c11) + np.hypot(0.5 * (c00 - c11), c01)
    with np.errstate(divide="ignore", invalid="ignore"):
        small = np.where(big > 0, lam * mu / det / np.where(big > 0, big, 1.0), 0.0)  # det C / λ', not a difference
    psi = 0.5 * np.arctan2(2 * c01, c00 - c11)
    cp, sp = np.cos(psi)[..., None], np.sin(psi)[..., None]
    x = cp * asg.x + sp * asg.y
    y = -sp * asg.x + cp * asg.y
    amp = asg.amplitude * np.pi / np.sqrt(det * lam_s * mu_s)
    return ASG(x, y, asg.z, big, np.minimum(small, big), amp)


# ---------------------------------------------------------------------------------------------------
# Spherical warp (Xu §5.2, Eq. 23–26; Wang 2009 §4)
# ---------------------------------------------------------------------------------------------------

def warp_hessian(asg: ASG, wo):
    """The data of the warp: (z_i, T, Q, cos θd) with z_i = 2(o·z_h)z_h − o the warped lobe axis, T (..., 3, 2)
    an orthonormal tangent basis at z_i, and Q (..., 2, 2) the quadratic form with
    g(i) = λ_h(h(i)·x_h)² + μ_h(h(i)·y_h)² ≈ sᵀQs for i ≈ z_i + T s (Xu Eq. 24–25; Q is ½ the Hessian).

    Derivation (the supplement's §6 is not in our copy of the paper): h(i) = (i + o)/|i + o|, so
    dh = (I − hhᵀ)di/|i + o|, and at i = z_i, h = z_h and |z_i + o| = 2(o·z_h). As x_h, y_h ⊥ z_h,
    d(h·x_h) = x_h·di/(2 o·z_h), and likewise for y_h. Since h·x_h = h·y_h = 0 at the lobe, g's Hessian
    has no second-derivative-of-h term: g ≈ sᵀJᵀΛJs, J = [x_h, y_h]ᵀT/(2 o·z_h), Λ = diag(λ_h, μ_h), Q = JᵀΛJ.
    Geometrically: a tangent step out of the plane of o and z_h moves h by 1/(2cos θd) of it, one in that
    plane by 1/2, so an isotropic λ_h becomes λ_h/(4cos²θd) and λ_h/4 (geometric mean λ_h/(4cos θd):
    Wang's η/(4 o·ξ)). Xu's Eq. 24 writes sᵀHs with H "the Hessian"; the Taylor term is ½sᵀHs, and the
    λ_i, μ_i that reproduce g are the eigenvalues of Q = H/2.
    """
    o = _normalize(np.asarray(wo, np.float64))
    zh = asg.z
    cos_d = _dot(o, zh)
    zi = _normalize(2.0 * cos_d[..., None] * zh - o)
    t1, t2 = tangent_frame(zi)
    # Xu's x'_i ⊥ o: any tangent basis gives the same Q up to rotation; use o × z_h where it is defined,
    # so that the frame follows the geometry, and the Duff frame at normal view (o ∥ z_h).
    cross = cross_rows(o, zh)
    cn = np.linalg.norm(cross, axis=-1, keepdims=True)
    use = cn > 1e-12
    t1 = np.where(use, cross / np.where(use, cn, 1.0), t1)
    t2 = np.where(use, cross_rows(zi, t1), t2)
    tb = np.stack([t1, t2], axis=-1)  # (..., 3, 2)
    c = np.maximum(cos_d, 1e-100)  # o·z_h ≤ 0 has no lobe (amplitude 0 in `warp`); keep Q finite
    jac = np.stack([np.einsum("...i,...ik->...k", asg.x, tb), np.einsum("...i,...ik->...k", asg.y, tb)],
                   axis=-2) / (2.0 * c[..., None, None])  # (..., 2, 2): rows h·x_h, h·y_h
    lam_diag = np.stack([asg.lam, asg.mu], axis=-1)
    q = np.einsum("...ki,...k,...kj->...ij", jac, lam_diag, jac)
    return zi, tb, q, cos_d


def warp(asg: ASG, wo) -> ASG:
    """Xu Eq. 23–26: the NDF lobe G_h(h) re-expressed in the light direction i, h = (i + o)/|i + o|:
    G_h(h(i)) ≈ G(i; [x_i, y_i, z_i], [λ_i, μ_i], c), with z_i the mirror direction of o about z_h and
    λ_i, μ_i, x_i, y_i the eigen-decomposition of the exponent's quadratic form Q (`warp_hessian`).
    The amplitude is kept (the smooth term max(h·z_h, 0) is 1 at the lobe); where o·z_h ≤ 0 the view
    cannot see the lobe and the amplitude is 0. x_i is the eigenvector closer to the image of x_h, so that
    λ_i follows λ_h. The 1/(4 i·h) Jacobian of the half-vector map belongs to the BRDF's smooth factor M,
    not here (as in Xu Eq. 22 and Wang).

    Measured relative L2 error of the warped lobe against G_h(h(i)) over i ∈ S² (tests/test_asg.py), worst
    over the view azimuth, θo = 0° / 30° / 60° / 75°: (10, 10) 4.5 / 4.4 / 18 / 44 %; (100, 10)
    3.1 / 15 / 30 / 49 %; (1000, 100) 0.4 / 5.1 / 11 / 20 %; (1e4, 1e4) 0.01 / 0.06 / 0.6 / 1.5 %;
    (1e4, 10) 2.9 / 78 / 93 / 106 %. A streak along y_h seen with o tilted toward x_h lands on a small
    circle of the light sphere, which no ASG follows (8 % at 30° when o tilts along the streak instead).
    """
    zi, tb, q, cos_d = warp_hessian(asg, wo)
    evals, evecs = np.linalg.eigh(q)  # (..., 2), (..., 2, 2): columns are the eigenvectors
    e0 = np.einsum("...ik,...k->...i", tb, evecs[..., :, 0])
    e1 = np.einsum("...ik,...k->...i", tb, evecs[..., :, 1])
    # Which eigenvector plays x: the one whose direction is nearer x_h (the two are ⊥ z_i, x_h ⊥ z_h).
    first = np.abs(_dot(e0, asg.x)) >= np.abs(_dot(e1, asg.x))
    xi = np.where(first[..., None], e0, e1)
    yi = np.where(first[..., None], e1, e0)
    lam_i = np.where(first, evals[..., 0], evals[..., 1])
    mu_i = np.where(first, evals[..., 1], evals[..., 0])
    xi = np.where((_dot(xi, asg.x) < 0)[..., None], -xi, xi)
    yi = np.where((_dot(yi, asg.y) < 0)[..., None], -yi, yi)
    amp = np.where(cos_d > 0, asg.amplitude, 0.0)
    return ASG(xi, yi, zi, np.maximum(lam_i, 0.0), np.maximum(mu_i, 0.0), amp)


# ---------------------------------------------------------------------------------------------------
# Visibility through the SSDF (Xu §5.3, Eq. 27–28)
# ---------------------------------------------------------------------------------------------------

def effective_sharpness(asg: ASG):
    """Our SG sharpness of the circle that stands in for the ASG's ellipse: η = 2√(λμ) (Xu's effective
    bandwidth √(λμ) is in his ν units, and ν = η/2)."""
    return 2.0 * np.sqrt(asg.lam * asg.mu)


def visible_fraction(asg: ASG, sin_theta_d):
    """Xu Eq. 27–28 in our terms: f_h(θd, ·)/f_h(π/2, ·) = sg.visible_fraction(sin θd, 2√(λμ)), the share of
    the lobe on the visible side of a great circle passing at angle θd from the lobe axis (θd > 0: the
    axis is visible). The ellipse is replaced by a circle of the same area, so the fraction does not
    depend on how the boundary is oriented in the lobe's frame, which the true fraction does.

    Measured (tests/test_asg.py), absolute error of the fraction against brute force, worst over the
    boundary's azimuth and θd: λ = μ = 1, 10, 100, 1e4: 0.046, 0.0045, 4e−4, 1e−6 (with Xu's literal
    √(λμ) as η: 0.093, 0.078, 0.080, 0.020); (40, 10): 0.083; (100, 1): 0.21; (1000, 10): 0.25; a band
    (μ = 0, a uniform stand-in): 0.35 — the orientation dependence the effective bandwidth cannot carry.
    """
    s = np.asarray(sin_theta_d, np.float64)
    inside = np.abs(s) <= 1.0 + 1e-9  # (NaN is outside; a rounding's overshoot is clipped)
    if not np.all(inside):
        raise ValueError(f"visible_fraction: sin_theta_d must lie in [-1, 1], got {s.reshape(-1)[np.argmin(inside)]}")
    return sg.visible_fraction(np.clip(s, -1.0, 1.0), np.maximum(effective_sharpness(asg), 1e-9))


def occlude(asg: ASG, sin_theta_d) -> ASG:
    """Xu Eq. 28: G·V ≈ visible_fraction·G, the same ASG with its amplitude attenuated."""
    return ASG(asg.x, asg.y, asg.z, asg.lam, asg.mu, asg.amplitude * visible_fraction(asg, sin_theta_d))


# ---------------------------------------------------------------------------------------------------
# Importance sampling (not in Xu; his §7 asks for it)
# ---------------------------------------------------------------------------------------------------

def truncated_gaussian(u, beta):
    """Inverse CDF of the density ∝ exp(−βa²) on [−1, 1] at u ∈ (−1, 1) (u = 2·CDF − 1):
    a = erfinv(u·erf(√β))/√β; uniform (a = u) at β = 0, and accurate for tiny β, where both erf and erfinv
    are linear."""
    rb = np.sqrt(beta)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = erfinv(u * erf(rb)) / rb
    return np.where(beta > 1e-300, a, u)


def sample(asg: ASG, n: int, rng):
    """n directions from the density G(v)/∫G (amplitude ignored) for each ASG of the batch, and that pdf
    (per unit solid angle): → (v (..., n, 3), pdf (..., n)).

    Exact and unbiased: in disk coordinates (a, b) = (v·x, v·y) the density is exp(−λa² − μb²) on the unit
    disk (module notes). a and b are drawn from exp(−λa²), exp(−μb²) on [−1, 1] by inverse CDF, pairs
    outside the disk are rejected (acceptance = the disk's share of the square's mass: π/4 for λ = μ = 0,
    the broadest lobe, → 1 for sharp ones), and v = a·x + b·y + √(1 − a² − b²)·z. Bandwidths up to 1e6 and beyond, bands
    (μ = 0) and the uniform cosine lobe (λ = μ = 0) are all exact. rng: a numpy Generator."""
    n = int(n)
    if n < 0:
        raise ValueError("sample: n must be >= 0")
    shape = asg.shape
    lam = asg.lam.reshape(-1)[:, None]
    mu = asg.mu.reshape(-1)[:, None]
    a = np.full((lam.shape[0], n), np.nan)
    b = np.full_like(a, np.nan)
    todo = np.ones(a.shape, bool)
    while todo.any():
        # Fresh draws for every slot, kept only where still empty: simple, and each round fills ≥ π/4 of
        # them (the acceptance's minimum over λ, μ ∈ {0} ∪ [1e−3, 1e6], at λ = μ = 0; tests/test_asg.py).
        ca = truncated_gaussian(rng.uniform(-1.0, 1.0, a.shape), lam)
        cb = truncated_gaussian(rng.uniform(-1.0, 1.0, a.shape), mu)
        ok = todo & (ca * ca + cb * cb < 1.0)
        a = np.where(ok, ca, a)
        b = np.where(ok, cb, b)
        todo &= ~ok
    a = a.reshape(shape + (n,))
    b = b.reshape(shape + (n,))
    t = np.sqrt(np.maximum(1.0 - a * a - b * b, 0.0))
    v = a[..., None] * asg.x[..., None, :] + b[..., None] * asg.y[..., None, :] + t[..., None] * asg.z[..., None, :]
    dens = t * np.exp(-asg.lam[..., None] * a * a - asg.mu[..., None] * b * b)
    return v, dens / unit_integral(asg.lam, asg.mu)[..., None]


def pdf(asg: ASG, v):
    """The density of `sample` at directions v (..., 3) (broadcast with the batch): G(v)/∫G, amplitude ignored."""
    unit = ASG(asg.x, asg.y, asg.z, asg.lam, asg.mu, 1.0)
    return evaluate(unit, v) / unit_integral(asg.lam, asg.mu)
