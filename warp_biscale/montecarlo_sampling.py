"""Sampling for the Monte Carlo reference renderer (`montecarlo`): von Mises–Fisher sampling and its
density, and the importance-sampling strategies that `montecarlo.render` weighs by multiple importance
sampling (the environment map, the cosine lobe, each light, an analytic BRDF's glossy lobe, an effective
BRDF's lobe mixture). Each strategy draws directions from uniforms and gives their density; the
renderer's docstring states the estimator."""

from __future__ import annotations

import numpy as np
from scipy.special import erf

from . import asg as asg_mod
from . import sg
from .asg import truncated_gaussian
from .effective import EffectiveBRDF
from .shading import MIN_COS_VIEW

__all__ = ["sample_vmf", "vmf_pdf", "LOBE_FLOOR"]

LOBE_FLOOR = 0.05  # share of an effective BRDF's lobe mixture spread evenly over its lobes (robust proposal)


# ---------------------------------------------------------------------------------------------------
# small vector helpers (float64, broadcasting over leading axes)
# ---------------------------------------------------------------------------------------------------


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _normalize(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def _basis(axis):
    """Two unit vectors (t1, t2) completing unit `axis` (..., 3) to an orthonormal frame (Duff et al. 2017:
    branchless, no singularity)."""
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], -1)
    t2 = np.stack([b, sign + y * y * a, -y], -1)
    return t1, t2


def sample_vmf(axis, eta, u1, u2):
    """Directions (..., 3) from the von Mises–Fisher density p(ω) = exp(η(ω·ξ − 1)) / ∫G about unit
    axes ξ (..., 3) of sharpness η (...) > 0, from uniforms u1, u2 in [0, 1) (...).

    Inverting the CDF of cos θ, cos θ = 1 + log(u + (1 − u)e^{−2η})/η with u = 1 − u1 ∈ (0, 1]; written
    1 − cos θ = −log1p(u·expm1(−2η))/η it is exact for η → 0 (uniform) and for η up to 1e6 and beyond
    (no 1 − cos cancellation, no overflow)."""
    eta = np.asarray(eta, np.float64)
    with np.errstate(divide="ignore"):  # u1 = 0 with η ≥ 19 gives log(0) = −inf: the antipode, clipped below
        one_minus = -np.log1p((1.0 - np.asarray(u1)) * np.expm1(-2.0 * eta)) / eta
    one_minus = np.clip(one_minus, 0.0, 2.0)
    cos_t = 1.0 - one_minus
    sin_t = np.sqrt(one_minus * (2.0 - one_minus))
    phi = 2.0 * np.pi * np.asarray(u2)
    t1, t2 = _basis(axis)
    w = cos_t[..., None] * axis + (sin_t * np.cos(phi))[..., None] * t1 + (sin_t * np.sin(phi))[..., None] * t2
    return _normalize(w)


def vmf_pdf(w, axis, eta):
    """(...) the vMF density about unit `axis` of sharpness η at unit directions w (per steradian):
    exp(−η(1 − w·ξ)) / ∫G, with 1 − w·ξ = ‖w − ξ‖²/2 (exact for sharp lobes)."""
    eta = np.asarray(eta, np.float64)
    return np.exp(-eta * sg.one_minus_cos(w, axis)) / sg.integral(eta)


# ---------------------------------------------------------------------------------------------------
# sampling strategies: sample(ctx, u) maps uniforms u (dims, B, count) to directions (B, count, 3); u[0] is the
# stratified one (`_stratified_uniforms`), so each strategy puts its main choice there. pdf(ctx, w (B, N, 3)) → (B, N)
# ---------------------------------------------------------------------------------------------------


def _sample_linear(p0, p1, u):
    """x in [0, 1] with density ∝ (1 − x)·p0 + x·p1 (p0, p1 >= 0, not both 0) from a uniform u: the inverse CDF
    x = u(p0 + p1) / (p0 + sqrt((1 − u)p0² + u·p1²)), which has no cancellation (and is u where p0 = p1)."""
    den = p0 + np.sqrt((1 - u) * p0 * p0 + u * p1 * p1)
    return np.clip(np.where(den > 0, u * (p0 + p1) / np.where(den > 0, den, 1.0), u), 0.0, 1.0)


class _EnvironmentStrategy:
    """The environment by its radiance, following `Environment.lookup`'s bilinear interpolation: the (H + 1) × W
    cells between texel centres (polar caps: the half rows at the poles, where the lookup clamps θ) are picked
    with probability ∝ the mean of their 4 corner texels' mean RGB × their solid angle; inside a cell, with
    (t, s) its fractions in (cos θ, φ), the density is bilinear in (t, s) through the same 4 corners. So
    p(ω) = bil(t, s) / Σ_cells(mean·Ω), and L/p ≈ Σ(mean·Ω) is nearly constant (the lookup is bilinear in θ, the
    density in cos θ: within 2× in the first band off a pole, ≈ 1 elsewhere). Picking per texel instead, a
    bright texel's bilinear halo would fall in its dim neighbours' texels: fireflies. p = 0 only where L = 0."""

    name = "environment"
    dims = 3  # u[0] picks the cell (stratified: e.g. a sun gets a near-fixed number of samples)

    def __init__(self, env):
        h, w = env.height, env.width
        self.h, self.w = h, w
        lum = env.radiance.astype(np.float64).mean(-1)  # (H, W)
        band = np.arange(h + 1)
        r0, r1 = np.clip(band - 1, 0, h - 1), np.clip(band, 0, h - 1)
        c0, c1 = np.arange(w), (np.arange(w) + 1) % w
        # Corner values of each cell: [θ low (row r0), θ high (row r1)] × [φ low (column c0), φ high (c1)].
        self.corners = np.stack([lum[r0][:, c0], lum[r0][:, c1], lum[r1][:, c0], lum[r1][:, c1]], -1)  # (H+1, W, 4)
        theta = np.clip(np.pi * (np.arange(h + 2) - 0.5) / h, 0.0, np.pi)
        self.edges = np.cos(theta)  # cos θ of the band edges, decreasing: band k spans edges[k]..edges[k + 1]
        self.omega = np.broadcast_to(((self.edges[:-1] - self.edges[1:]) * 2 * np.pi / w)[:, None], (h + 1, w))
        weight = self.corners.mean(-1) * self.omega
        self.total = float(weight.sum())
        self.prob = weight / max(self.total, 1e-300)
        self.cdf = np.cumsum(self.prob.ravel())
        self.cdf /= self.cdf[-1] if self.total > 0 else 1.0
        # Total-variation distance from the uniform density: 0 for a constant map (its samples are no better
        # than uniform ones), → 1 for a sun; sets this strategy's share of the samples (`_plan`).
        self.peakedness = 0.5 * float(np.abs(self.prob - self.omega / (4 * np.pi)).sum())

    def sample(self, ctx, u):
        cell = np.minimum(np.searchsorted(self.cdf, u[0], side="right"), (self.h + 1) * self.w - 1)
        band, col = np.divmod(cell, self.w)
        a, b, c, d = np.moveaxis(self.corners[band, col], -1, 0)
        t = _sample_linear(a + b, c + d, u[1])  # the marginal in t is linear
        s = _sample_linear((1 - t) * a + t * c, (1 - t) * b + t * d, u[2])  # and so is s given t
        c0, c1 = self.edges[band], self.edges[band + 1]
        cos_t = c0 + (c1 - c0) * t
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        phi = 2.0 * np.pi * (col + 0.5 + s) / self.w
        return np.stack([sin_t * np.cos(phi), cos_t, sin_t * np.sin(phi)], -1)

    def pdf(self, ctx, w):
        cos_t = np.clip(w[..., 1], -1.0, 1.0)
        theta = np.arccos(cos_t)
        x = np.mod(np.arctan2(w[..., 2], w[..., 0]), 2 * np.pi) * self.w / (2 * np.pi) - 0.5
        band = np.clip(np.floor(theta * self.h / np.pi + 0.5).astype(np.int64), 0, self.h)
        col = np.floor(x).astype(np.int64)
        s = np.clip(x - col, 0.0, 1.0)
        col = np.mod(col, self.w)
        c0, c1 = self.edges[band], self.edges[band + 1]
        t = np.clip((c0 - cos_t) / (c0 - c1), 0.0, 1.0)
        a, b, c, d = np.moveaxis(self.corners[band, col], -1, 0)
        bil = (1 - t) * ((1 - s) * a + s * b) + t * ((1 - s) * c + s * d)
        return bil / max(self.total, 1e-300)


class _CosineStrategy:
    """p(ω) = (n·ω)⁺/π (Malley's method): the diffuse part of the environment term, where the environment's
    own proposal (radiance alone) ignores the cosine."""

    name = "cosine"

    dims = 2  # u[0] = sin²θ

    def sample(self, ctx, u):
        r = np.sqrt(u[0])
        phi = 2.0 * np.pi * u[1]
        z = np.sqrt(np.maximum(1.0 - u[0], 0.0))
        return ((r * np.cos(phi))[..., None] * ctx["t"][:, None] + (r * np.sin(phi))[..., None] * ctx["b"][:, None]
                + z[..., None] * ctx["n"][:, None])

    def pdf(self, ctx, w):
        return np.maximum(_dot(w, ctx["n"][:, None]), 0.0) / np.pi


class _LightStrategy:
    """Light l's SG emitter as a vMF density (axis, sharpness per pixel): exact importance sampling of it."""

    def __init__(self, index):
        self.index = index
        self.name = f"light {index}"

    dims = 2  # u[0]: the polar angle about the emitter's axis

    def sample(self, ctx, u):
        axis, eta = ctx["light_axis"][:, self.index], ctx["light_eta"][:, self.index]
        shape = u.shape[1:]
        return sample_vmf(np.broadcast_to(axis[:, None], shape + (3,)), np.broadcast_to(eta[:, None], shape),
                          u[0], u[1])

    def pdf(self, ctx, w):
        return vmf_pdf(w, ctx["light_axis"][:, None, self.index], ctx["light_eta"][:, None, self.index])


class _GlossyStrategy:
    """Analytic glossy BRDF: half vector h ~ vMF(n, η_s) (the NDF's SG, `sg.specular_lobe`), ω = 2(ωo·h)h − ωo.
    h and −h give the same ω, so p(ω) = [vMF(h) + vMF(−h)] / (4|ωo·h|), h = (ω + ωo)/‖ω + ωo‖."""

    name = "brdf"

    def __init__(self, eta_s):
        self.eta = float(eta_s)

    dims = 2  # u[0]: the half vector's polar angle about n

    def sample(self, ctx, u):
        n, wo = ctx["n"], ctx["wo"]
        h = sample_vmf(np.broadcast_to(n[:, None], u.shape[1:] + (3,)), np.full(u.shape[1:], self.eta), u[0], u[1])
        return _normalize(2.0 * _dot(wo[:, None], h)[..., None] * h - wo[:, None])

    def pdf(self, ctx, w):
        n, wo = ctx["n"][:, None], ctx["wo"][:, None]
        h = _normalize(w + wo)
        norm = sg.integral(self.eta)
        d = np.exp(-self.eta * sg.one_minus_cos(h, n)) + np.exp(-self.eta * sg.one_minus_cos(-h, n))
        with np.errstate(divide="ignore", over="ignore"):  # ω = −ωo: a null set, its pdf is capped
            return np.minimum(d / (norm * 4.0 * np.abs(_dot(wo, h))), 1e300)


def _gaussian_mass(beta, r):
    """∫_{−r}^{r} exp(−βx²) dx = √(π/β)·erf(√β·r), by its series 2r(1 − βr²/3 + β²r⁴/10) where βr² < 1e−4 (β → 0)."""
    x2 = beta * r * r
    with np.errstate(divide="ignore", invalid="ignore"):
        full = np.sqrt(np.pi / beta) * erf(np.sqrt(x2))
    return np.where(x2 < 1e-4, 2.0 * r * (1.0 - x2 / 3.0 + x2 * x2 / 10.0), full)


def sample_asg(x, y, z, lam, mu, u1, u2):
    """Directions (..., 3) from the density ∝ exp(−λ(ω·x)² − μ(ω·y)²)(ω·z)⁺ of ASGs with frames x, y, z (..., 3)
    and bandwidths λ, μ ≥ 0 (...), from uniforms u1, u2 in [0, 1) (...). In the disk coordinates (a, c) =
    (ω·x, ω·y): a from exp(−λa²) on [−1, 1], then c from exp(−μc²) on the chord |c| < √(1 − a²), each by its
    inverse CDF (`asg.truncated_gaussian`) — exact, with no rejection (unlike `asg.sample`), so stratified
    uniforms stay stratified. The density is not the ASG's own (c's chord is normalised per a) but is exact:
    `asg_pdf`."""
    a = truncated_gaussian(2.0 * np.asarray(u1) - 1.0, lam)
    r = np.sqrt(np.maximum(1.0 - a * a, 0.0))
    c = r * truncated_gaussian(2.0 * np.asarray(u2) - 1.0, mu * r * r)
    up = np.sqrt(np.maximum(1.0 - a * a - c * c, 0.0))
    return a[..., None] * x + c[..., None] * y + up[..., None] * z


def asg_pdf(x, y, z, lam, mu, w):
    """The density of `sample_asg` per unit solid angle at directions w (..., 3): p(a)·p(c|a)·(ω·z) (dω =
    da dc/(ω·z)), 0 at or below the lobe's horizon ω·z = 0."""
    a, c, up = _dot(w, x), _dot(w, y), _dot(w, z)
    r = np.sqrt(np.maximum(1.0 - a * a, 0.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_a = np.exp(-lam * a * a) / _gaussian_mass(lam, 1.0)
        p_c = np.where(r > 0, np.exp(-mu * c * c) / _gaussian_mass(mu, r), 0.0)
        return np.where(up > 0, np.minimum(p_a * p_c * up, 1e300), 0.0)


class _AsgGlossyStrategy:
    """Analytic anisotropic BRDF: the half vector h from its NDF's ASG exp(−λ(h·t)² − μ(h·b)²)(h·n)⁺ in the
    pixel's tangent frame (`brdf.ndf_bandwidths`; Xu 2013's "importance sampling of an ASG", his future work) by
    `sample_asg`, ω = 2(ωo·h)h − ωo, and p(ω) = p_h(±h)/(4|ωo·h|) with ±h the half vector on n's side."""

    name = "brdf"
    dims = 2

    def __init__(self, lam, mu):
        self.lam, self.mu = float(lam), float(mu)

    def sample(self, ctx, u):
        t, b, n, wo = (ctx[k][:, None] for k in ("t", "b", "n", "wo"))
        h = sample_asg(t, b, n, self.lam, self.mu, u[0], u[1])
        return _normalize(2.0 * _dot(wo, h)[..., None] * h - wo)

    def pdf(self, ctx, w):
        t, b, n, wo = (ctx[k][:, None] for k in ("t", "b", "n", "wo"))
        h = _normalize(w + wo)
        h = np.where((_dot(h, n) < 0)[..., None], -h, h)  # the half vector the sampler draws (on n's side)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.minimum(asg_pdf(t, b, n, self.lam, self.mu, h) / (4.0 * np.abs(_dot(wo, h))), 1e300)


class _LobeMixtureStrategy:
    """Effective BRDF: a vMF mixture (an ASG material's: an ASG mixture, `sample_asg`) over its warped lobes q =
    (small-scale material m, NDF lobe j), per pixel
    axis ξ'_j = 2(ωo·ξ_j)ξ_j − ωo, sharpness η_jη_s/((η_j + η_s)·4 ωo·ξ_j) (Iwasaki Eq. 14 + Wang Eq. 18–21),
    weight ∝ the lobe's SG energy M_m·μ_mj(ξ'_j, ωo)·2π/(η_j + η_s)·∫G' (what the SG renderer gives it),
    plus LOBE_FLOOR spread evenly over the lobes facing the viewer, so a lobe the tables underrate is still
    found. Any weights give an unbiased estimator: the pdf below is the mixture's exact density."""

    name = "brdf"

    def __init__(self, mat: EffectiveBRDF, speculars):
        self.mat = mat
        self.speculars = speculars  # [(sub-material index m, η_s)]
        self._lobes = None

    def lobes(self):
        """The material's sampling lobes (`sampling_lobes`), asked once: a material with none (the matrix method's)
        refuses here, which the reference asks of each material in view before computing its ground truth."""
        if self._lobes is None:
            self._lobes = self.mat.sampling_lobes()
        return self._lobes

    def setup(self, ctx):
        mat = self.mat
        t, b, n, wo, wo_local = ctx["t"], ctx["b"], ctx["n"], ctx["wo"], ctx["wo_local"]
        npix = len(n)
        ax, eta = self.lobes()
        nj = len(eta)
        xi = ax[None, :, 0:1] * t[:, None] + ax[None, :, 1:2] * b[:, None] + ax[None, :, 2:3] * n[:, None]  # (B, J, 3)
        c = _dot(xi, wo[:, None])  # (B, J)
        axis = _normalize(2.0 * c[..., None] * xi - wo[:, None])
        facing = c > 0
        local = np.stack([_dot(axis, t[:, None]), _dot(axis, b[:, None]), np.maximum(_dot(axis, n[:, None]), 1e-6)],
                         -1)
        mu = mat._interpolated_amplitudes(_normalize(local).reshape(-1, 3), np.repeat(wo_local, nj, axis=0))
        mu = mu[:, np.arange(npix * nj), np.tile(np.arange(nj), npix)].mean(-1).reshape(-1, npix, nj)  # (M, B, J)
        # An ASG material's lobes (Xu 2013): each G_j ⊛ SG_s warped to the light directions, sampled as the ASG it
        # is (`sample_asg`) rather than by its isotropic stand-in; the weights are the stand-ins' energies.
        asgs = getattr(mat, "asgs", None)
        if asgs is not None:
            def world(v):
                return v[None, :, 0:1] * t[:, None] + v[None, :, 1:2] * b[:, None] + v[None, :, 2:3] * n[:, None]

            lobes = asg_mod.ASG(world(asgs.x), world(asgs.y), world(asgs.z), asgs.lam[None], asgs.mu[None])
            warped = [asg_mod.warp(asg_mod.convolve_sg(lobes, eta_s), wo[:, None]) for _, eta_s in self.speculars]
            self.asg = tuple(np.concatenate([getattr(g, k) for g in warped], 1) for k in ("x", "y", "z", "lam", "mu"))
        else:
            self.asg = None
        axes, sharp, weight = [], [], []
        for m, eta_s in self.speculars:
            eta_c = 1.0 / (1.0 / eta + 1.0 / eta_s)
            eta_w = np.minimum(eta_c[None] / (4.0 * np.maximum(c, MIN_COS_VIEW)), sg.SHARPNESS_MAX)
            scale = sum(lobe[1] for lobe in sg.specular_lobes(mat.materials[m], axis.reshape(-1, 3),
                                                              np.repeat(wo, nj, axis=0)))
            energy = scale.mean(-1).reshape(npix, nj) * mu[m] * (2 * np.pi / (eta + eta_s))[None] * sg.integral(eta_w)
            axes.append(axis)
            sharp.append(eta_w)
            weight.append(np.where(facing, energy, 0.0))
        self.axis = np.concatenate(axes, 1)  # (B, Q, 3)
        self.eta = np.concatenate(sharp, 1)  # (B, Q)
        w = np.concatenate(weight, 1)
        valid = np.concatenate([facing] * len(self.speculars), 1).astype(np.float64)
        n_valid = valid.sum(1, keepdims=True)
        even = np.where(n_valid > 0, valid / np.maximum(n_valid, 1.0), 1.0 / valid.shape[1])
        total = w.sum(1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(total > 0, (1 - LOBE_FLOOR) * w / total + LOBE_FLOOR * even, even)
        self.weight = w
        self.cdf = np.cumsum(w, 1)

    dims = 3  # u[0] picks the lobe

    def sample(self, ctx, u):
        nq = self.weight.shape[1]
        q = np.minimum((u[0][..., None] * self.cdf[:, None, -1:] >= self.cdf[:, None, :]).sum(-1), nq - 1)
        if self.asg is not None:
            x, y, z = (np.take_along_axis(v, q[..., None], 1) for v in self.asg[:3])
            lam, mu = (np.take_along_axis(v, q, 1) for v in self.asg[3:])
            return _normalize(sample_asg(x, y, z, lam, mu, u[1], u[2]))
        axis = np.take_along_axis(self.axis, q[..., None], 1)
        eta = np.take_along_axis(self.eta, q, 1)
        return sample_vmf(axis, eta, u[1], u[2])

    def pdf(self, ctx, w):
        out = np.zeros(w.shape[:-1])
        for q in range(self.weight.shape[1]):
            if self.asg is not None:
                x, y, z, lam, mu = (v[:, q, None] for v in self.asg)
                out += self.weight[:, q, None] * asg_pdf(x, y, z, lam, mu, w)
            else:
                out += self.weight[:, q, None] * vmf_pdf(w, self.axis[:, None, q], self.eta[:, q, None])
        return out
