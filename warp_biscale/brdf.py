"""Small-scale BRDFs as plain parameter objects.

The isotropic models (Lambert, Blinn–Phong, Cook–Torrance, Ward) are written in the facet's local frame
and need only the facet normal n, the light direction ωi and the view direction ωo. The anisotropic
ones (AnisotropicWard, AshikhminShirley) also need a tangent t: the facet frame is (x, y, n) with
x = t − (t·n)n normalised and y = n × x (`tangent_frame`; docs/design.md §4.7). All colour parameters
are RGB (a scalar is broadcast). Kernels evaluate the *cosine-weighted* value f_r·(n·ωi)⁺(n·ωo)⁺, which
stays finite at grazing angles where f_r itself (Cook–Torrance, Ward, Ashikhmin–Shirley) divides by a
vanishing cosine.

Packed layout shared by the reference, the Warp and the OpenCL kernels, one row per material:
``kind`` (int: 0 Lambert, 1 Blinn–Phong, 2 Cook–Torrance, 3 Ward, 4 anisotropic Ward,
5 Ashikhmin–Shirley, 6 measured) and ``params`` = [kd_r, kd_g, kd_b, ks_r, ks_g, ks_b, p1, p2] (float32); the
anisotropic Ward's p1, p2 are αx, αy, Ashikhmin–Shirley's row is [Rd rgb, Rs rgb, nu, nv]. A measured BRDF's
row is [slot, mode, 0, …]: its table is slot `slot` of a table array the kernel takes beside `params`
(`measured_tables`), and mode 0 is trilinear interpolation, 1 nearest (`measured.MeasuredBRDF`).

Only the ground truth (which has each facet's tangent) and the renderers (the SG renderer and the Monte Carlo
reference, for a large-scale mesh's own material, in the frame of the mesh tangents) evaluate the anisotropic
models: every other consumer of materials (`as_material_list`, `pack_materials`: effective materials, the
bakes, lit spheres) refuses them in one line unless asked with ``anisotropic=True``. Likewise only the
ground truth and the matrix method's M pack measured BRDFs (``measured=True``); every other packing refuses
them in one line (`MeasuredBRDF.packed`).
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["Lambert", "BlinnPhong", "CookTorrance", "Ward", "AnisotropicWard", "AshikhminShirley", "Brdf",
           "pack_materials", "measured_tables", "as_material_list", "refuse_anisotropic", "tangent_frame", "parse_brdf",
           "EnergyWarning", "NORMALIZATIONS", "sg_lobes", "diffuse_albedo", "blinn_phong_normal_albedo",
           "cook_torrance_albedo", "SHARPNESS_MAX", "BLINN_PHONG_EXPONENT_MAX", "COOK_TORRANCE_ROUGHNESS_MIN",
           "WARD_ALPHA_MIN", "ANISOTROPIC_WARD_ALPHA_MIN", "ASHIKHMIN_SHIRLEY_EXPONENT_MAX", "P1_BOUNDS"]

LAMBERT, BLINN_PHONG, COOK_TORRANCE, WARD = 0, 1, 2, 3
ANISOTROPIC_WARD, ASHIKHMIN_SHIRLEY = 4, 5
ANISOTROPIC_KINDS = (ANISOTROPIC_WARD, ASHIKHMIN_SHIRLEY)  # the kinds whose packed row needs a tangent
MEASURED = 6  # a MERL table (measured.MeasuredBRDF): its packed row names a slot of the kernels' table array

# Where the facet's tangent is (almost) parallel to its normal, |t − (t·n)n|² below this (the tangent within
# 0.01 rad of the normal), the frame falls back on a tangent built from n alone (`tangent_frame`). The
# kernels use the same test and fallback.
TANGENT_DEGENERATE = 1e-4

# BlinnPhong.normalization: "iwasaki" the paper's lobe (its specular albedo exceeds ks), "energy" the same
# lobe scaled so that its specular albedo is ks at normal incidence and below ks everywhere else.
NORMALIZATIONS = ("iwasaki", "energy")


class EnergyWarning(UserWarning):
    """A material reflects more light than it receives (a directional albedo above 1: kd alone, or kd plus
    the specular lobe's albedo at some angle of view): allowed, but not physical."""


def _rgb(name, value) -> tuple:
    try:
        a = np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or an RGB triple, got {value!r}") from None
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,):
        raise ValueError(f"{name} must be a number or an RGB triple, got {value!r}")
    if not np.all(np.isfinite(a)) or (a < 0).any():
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return tuple(float(x) for x in a)


def warn_energy(name, rgb, stacklevel: int = 2) -> bool:
    """An `EnergyWarning` when a diffuse reflectance (an RGB triple: Lambert albedo, kd) has a channel > 1:
    a Lambertian term reflects its albedo of what it receives, so more than 1 creates light. → whether it warned."""
    a = np.asarray(rgb, np.float64).reshape(-1)
    if not (a > 1).any():
        return False
    if np.all(a == a[0]):
        shown = f"{a[0]:g} > 1"
    else:
        k = int(np.argmax(a))
        shown = f"({', '.join(f'{x:g}' for x in a)}): {'rgb'[k]} = {a[k]:g} > 1"
    warnings.warn(f"{name} {shown} reflects more light than it receives (an energy gain; keep it <= 1)",
                  EnergyWarning, stacklevel=stacklevel + 1)
    return True


def _positive(name, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return x


# How sharp a lobe may be. The SG closed forms hold up to sharpness SHARPNESS_MAX (sg.SHARPNESS_MAX is this one:
# sg imports this module), and the renderers and bakes cap every lobe there: a sharper BRDF lobe would be rendered as
# another, broader one (and past float32, fail late or render black). So each parameter is bounded where its lobe
# reaches SHARPNESS_MAX, through the mapping that turns it into an SG (`sg.specular_lobe`) or an ASG
# (`ndf_bandwidths`). An ASG exp(−λ(h·x)² − μ(h·y)²) is, along x, an SG of sharpness 2λ (λ(h·x)² = λ sin²θ ≈
# 2λ(1 − cos θ)), which is how the renderers and the bakes read it (asg_bake.BANDWIDTH_MAX = SHARPNESS_MAX/2,
# shading's η = 2√(λμ)): so its bandwidths are bounded by SHARPNESS_MAX/2, within the ASG forms' 1e6, and the
# anisotropic models' isotropic cases get their isotropic twins' bounds.
SHARPNESS_MAX = 1.0e6
# Blinn–Phong: η = exponent.
BLINN_PHONG_EXPONENT_MAX = SHARPNESS_MAX
# Cook–Torrance: exp(−θh²/m²) ≈ exp((2/m²)(cos θh − 1)), η = 2/m² ≤ SHARPNESS_MAX ⇔ m ≥ √(2/SHARPNESS_MAX) ≈ 1.414e−3.
COOK_TORRANCE_ROUGHNESS_MIN = math.sqrt(2.0 / SHARPNESS_MAX)
# Ward: exp(−tan²θh/α²) ≈ exp((2/α²)(cos θh − 1)), η = 2/α²: the same bound as Cook–Torrance's m.
WARD_ALPHA_MIN = math.sqrt(2.0 / SHARPNESS_MAX)
# Anisotropic Ward: λ = 1/αx², μ = 1/αy², each ≤ SHARPNESS_MAX/2 ⇔ α ≥ √(2/SHARPNESS_MAX) (Ward's, as αx = αy is Ward).
ANISOTROPIC_WARD_ALPHA_MIN = math.sqrt(2.0 / SHARPNESS_MAX)
# Ashikhmin–Shirley: λ = nu/2, μ = nv/2, each ≤ SHARPNESS_MAX/2 ⇔ nu, nv ≤ SHARPNESS_MAX (Blinn–Phong's, as nu = nv
# is the same (n·h)^n lobe).
ASHIKHMIN_SHIRLEY_EXPONENT_MAX = SHARPNESS_MAX


# The bounds of a packed row's p1 (name, least, most) for the kinds whose p1 a `svbrdf.Textured` parameter map scales.
P1_BOUNDS = {BLINN_PHONG: ("exponent", 0.0, BLINN_PHONG_EXPONENT_MAX),
             COOK_TORRANCE: ("roughness", COOK_TORRANCE_ROUGHNESS_MIN, math.inf),
             WARD: ("alpha", WARD_ALPHA_MIN, math.inf)}


def _lobe_parameter(name, value, least: float = 0.0, most: float = math.inf) -> float:
    """`value` as a finite float > 0 in [least, most]: a lobe parameter whose lobe is no sharper than the SG and
    ASG forms hold (SHARPNESS_MAX); a one-line ValueError naming `name` otherwise."""
    x = _positive(name, value)
    if x > most or x < least:
        bound = f"<= {most:g}" if x > most else f">= {least:.4g}"
        raise ValueError(f"{name} must be {bound}, got {value!r}: a sharper lobe than the SG and ASG forms hold "
                         f"(sharpness up to {SHARPNESS_MAX:g}, sg.SHARPNESS_MAX)")
    return x


# The stack level of a warning from a BRDF's __post_init__ that points at the line constructing it
# (warn_energy ← __post_init__ ← the dataclass __init__ ← the caller).
_CALLER = 3

# A directional albedo is warned of above 1 + this: kd + ks = 1 must not warn because of the rounding of
# a sum or of a scale factor folded into ks.
_ALBEDO_SLACK = 1e-9


def blinn_phong_normal_albedo(exponent) -> float:
    """The specular directional albedo at normal incidence of Iwasaki's Blinn–Phong lobe with ks = 1,
    ∫ (n+2)/(2π)(n·h)ⁿ cos θi dωi with ωo = n, in closed form: 4(n + 2^(−n/2))/(n + 4).

    With ωo on the normal, ωi = 2(n·h)h − n, so cos θi = 2c² − 1 (c = n·h) and dωi = 4c dω_h; the
    integral over c ∈ [1/√2, 1] is 4(n+2)∫c^(n+1)(2c² − 1)dc. It is the largest albedo over all angles
    of view (measured: tests/test_energy.py) and grows from 1 (n → 0) to 4 (n → ∞)."""
    n = float(exponent)
    return 4.0 * (n + 2.0 ** (-n / 2.0)) / (n + 4.0)


def _peak_text(name, total, cos_o) -> str:
    """'BlinnPhong directional albedo 3.85 > 1 at θo = 0° (cos θo = 1)', its largest channel named when
    the channels differ."""
    if np.all(total == total[0]):
        shown = f"{total[0]:.3g} > 1"
    else:
        k = int(np.argmax(total))
        shown = f"({', '.join(f'{x:.3g}' for x in total)}): {'rgb'[k]} = {total[k]:.3g} > 1"
    return f"{name} directional albedo {shown} at θo = {math.degrees(math.acos(cos_o)):.3g}° (cos θo = {cos_o:g})"


# Cook–Torrance's directional albedo (ks = 1) is linear in f0: f0·A1 + (1 − f0)·A5, with A1 the albedo of
# F = 1 and A5 that of F = (1 − h·ωi)⁵. Both are tabulated once, on first use, over the roughness m and
# cos θo, by Gauss–Legendre quadrature over the half vector; a material's largest albedo is read from them.
# Outside the table's m: below, the lobe is narrow and A ∝ m² (∫D dω_h ≈ πm²); above, D ≈ 1 (saturated).
_CT_COS = np.array([1e-3, 0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0])
_CT_ROUGHNESS = np.geomspace(0.02, 50.0, 42)  # 12 a decade: log-log interpolation within 0.015 of the albedo
_CT_NODES = 24


def _cook_torrance_albedos(roughness, cos_o, nodes: int = _CT_NODES):
    """(A1, A5), each (len(roughness), len(cos_o)): Cook–Torrance's specular directional albedo for ks = 1
    and F = 1, resp. F = (1 − h·ωi)⁵, by quadrature over the half vector h = (θh, φ) about the normal.

    ωi = 2(h·ωo)h − ωo, dωi = 4(h·ωo)dω_h. ωi is above the horizon for every φ while θh < π/4 − θo/2 and
    for |φ| < acos(−cot 2θh·cot θo) up to θh = π/4 + θo/2, so each of the two θh ranges gets its exact φ
    range (Gauss–Legendre in θh and φ); θh stops at 7m, past which D < e^−49."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    m = np.asarray(roughness, np.float64)[:, None, None]
    co = np.asarray(cos_o, np.float64)[None, :, None]
    so = np.sqrt(np.maximum(1.0 - co * co, 0.0))
    half = np.arccos(co) / 2
    full_end = np.minimum(np.pi / 4 - half, 7 * m)
    part_end = np.minimum(np.pi / 4 + half, 7 * m)
    a1 = a5 = 0.0
    for lo, hi, whole_circle in ((0.0 * full_end, full_end, True), (full_end, part_end, False)):
        th = lo + (hi - lo) * (x + 1) / 2
        w_th = (hi - lo) / 2 * w
        c, s = np.cos(th), np.sin(th)
        if whole_circle:
            phi_max = np.full_like(th, np.pi)
        else:
            phi_max = np.arccos(np.clip(-co * (2 * c * c - 1) / np.maximum(2 * s * c * so, 1e-300), -1.0, 1.0))
        phi = phi_max[..., None] * (x + 1) / 2
        w_phi = phi_max[..., None] / 2 * w
        c4, s4, co4, so4 = c[..., None], s[..., None], co[..., None], so[..., None]
        ho = s4 * np.cos(phi) * so4 + c4 * co4  # h·ωo = h·ωi
        ci = 2 * ho * c4 - co4
        ok = (ci > 0) & (ho > 0)
        hos = np.where(ok, ho, 1.0)
        g = np.minimum(1.0, np.minimum(2 * c4 * co4 / hos, 2 * c4 * ci / hos))
        d = np.exp(-((th[..., None] / m[..., None]) ** 2))
        # f_s·cos θi = F·G·D/(π cos θo); dωi = 4(h·ωo)·sin θh dθh dφ, φ over ±φmax (hence 2).
        term = np.where(ok, g * d / (np.pi * co4) * 4 * ho * s4, 0.0) * (2 * w_phi * w_th[..., None])
        a1 = a1 + term.sum((-1, -2))
        a5 = a5 + (term * (1.0 - np.clip(ho, 0.0, 1.0)) ** 5).sum((-1, -2))
    return a1, a5


@functools.cache
def _cook_torrance_table():
    a1, a5 = _cook_torrance_albedos(_CT_ROUGHNESS, _CT_COS)
    return np.log(a1), np.log(a5)


def cook_torrance_albedo(roughness, f0) -> tuple:
    """(cos θo (C,), A (C,)): Cook–Torrance's specular directional albedo for ks = 1 on a grid of cos θo
    from 1e−3 (grazing) to 1, read from a table computed once (within 0.015 of the quadrature)."""
    log1, log5 = _cook_torrance_table()
    lm = np.log(_CT_ROUGHNESS)
    m = float(roughness)
    at = float(np.clip(np.log(m), lm[0], lm[-1]))
    a1 = np.exp([np.interp(at, lm, log1[:, j]) for j in range(len(_CT_COS))])
    a5 = np.exp([np.interp(at, lm, log5[:, j]) for j in range(len(_CT_COS))])
    if m < _CT_ROUGHNESS[0]:
        a1, a5 = (a * (m / _CT_ROUGHNESS[0]) ** 2 for a in (a1, a5))
    return _CT_COS.copy(), f0 * a1 + (1.0 - f0) * a5


class Brdf:
    """Base of the small-scale BRDF parameter objects."""

    kind: int
    anisotropic = False  # True: f_r depends on the facet's tangent too (`eval` needs it)

    def packed(self) -> np.ndarray:
        raise NotImplementedError

    def eval(self, n, wi, wo, tangent=None) -> np.ndarray:
        """f_r(n, ωi, ωo) in float64, (N, 3) RGB; zero where ωi or ωo is below the facet. `tangent` (N, 3) or (3,):
        the facet's tangent (any vector off the normal; only its part across n counts), which an anisotropic
        BRDF needs and an isotropic one ignores."""
        n, wi, wo = (np.atleast_2d(np.asarray(x, np.float64)) for x in (n, wi, wo))
        n, wi, wo = np.broadcast_arrays(n, wi, wo)
        if self.anisotropic and tangent is None:
            raise ValueError(f"{type(self).__name__}.eval needs the facet's tangent (eval(n, wi, wo, tangent)): an "
                             "anisotropic BRDF depends on the direction across the normal")
        kinds, params = pack_materials([self], anisotropic=True)
        t = None if tangent is None else np.broadcast_to(np.asarray(tangent, np.float64), n.shape)
        fc = brdf_cosine_weighted(kinds, params, np.zeros(len(n), np.int32), n, wi, wo, t)
        ci = np.einsum("ij,ij->i", n, wi)
        co = np.einsum("ij,ij->i", n, wo)
        ok = (ci > 0) & (co > 0)
        out = np.zeros_like(fc)
        out[ok] = fc[ok] / (ci[ok] * co[ok])[:, None]
        return out


@dataclass(frozen=True)
class Lambert(Brdf):
    """Lambertian diffuse: f_r = albedo / π (so the albedo is the hemispherical reflectance)."""

    albedo: object = 0.5
    kind = LAMBERT

    def __post_init__(self):
        object.__setattr__(self, "albedo", _rgb("Lambert.albedo", self.albedo))
        warn_energy("Lambert albedo", self.albedo, stacklevel=_CALLER)

    def packed(self):
        return np.array([*self.albedo, 0, 0, 0, 0, 0], np.float64)


@dataclass(frozen=True)
class BlinnPhong(Brdf):
    """Blinn–Phong as Iwasaki §4.1: f_r = kd/π + s·ks·(n+2)/(2π)·(n·h)^n, h the half vector, s = 1 by default;
    0 < n ≤ BLINN_PHONG_EXPONENT_MAX = 1e6 (its SG sharpness n at most SHARPNESS_MAX).

    **What it does to energy.** (n+2)/(2π) normalises the *distribution* of h (∫(n+2)/(2π)(n·h)^n (n·h) dω_h
    = 1), not the BRDF, so the specular directional albedo A = ∫ f_s·cos θi dωi exceeds ks. Measured by
    float64 quadrature for ks = 1 (tests/test_energy.py):

        exponent n   cos θo = 1    0.9      0.5      0.1
        1            1.366         1.320    1.118    0.873
        10           2.866         2.441    1.147    0.403
        100          3.846         3.130    1.019    0.106
        1000         3.984         3.229    1.002    0.048
        10000        3.998         3.239    1.000    0.041

    It is largest at normal incidence, where it is 4(n + 2^(−n/2))/(n + 4) exactly (`blinn_phong_normal_albedo`;
    1 as n → 0, 4 as n → ∞), and tends to 4·cos²θo for sharp lobes. Under uniform light the surface reflects
    2(n + 2)/(n + 4) times ks of what it receives (the cosine-weighted mean of A over θo; → 2). So a
    material with kd + A·ks > 1 creates light, and constructing one gives an `EnergyWarning`.

    `normalization`: "iwasaki" (default) is the paper's lobe, s = 1. "energy" sets s = 1/A at normal
    incidence, (n + 4)/(4(n + 2^(−n/2))), folded into the ks that `packed()` returns (the kernels are
    unchanged): the specular albedo is then ks at normal incidence and less at every other angle (≈ ks·cos²θo
    for sharp lobes; ks·(n + 2)/(2(n + 2^(−n/2))) ≈ ks/2 under uniform light), so kd + ks ≤ 1 never creates
    light. A constant s cannot do better: the lobe loses light at oblique angles. Since s depends on the
    exponent, a `Textured` parameter map (which changes the exponent per texel) is refused with "energy".
    """

    ks: object = 1.0
    exponent: float = 64.0
    kd: object = 0.0
    normalization: str = "iwasaki"
    kind = BLINN_PHONG

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("BlinnPhong.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("BlinnPhong.kd", self.kd))
        kd_warned = warn_energy("BlinnPhong kd", self.kd, stacklevel=_CALLER)
        object.__setattr__(self, "exponent", _lobe_parameter("BlinnPhong.exponent", self.exponent,
                                                              most=BLINN_PHONG_EXPONENT_MAX))
        if not (isinstance(self.normalization, str) and self.normalization in NORMALIZATIONS):
            raise ValueError(f"BlinnPhong.normalization must be one of {', '.join(map(repr, NORMALIZATIONS))}, "
                             f"got {self.normalization!r}")
        if not kd_warned:  # (kd alone above 1 is said already)
            a = 1.0 if self.normalization == "energy" else blinn_phong_normal_albedo(self.exponent)
            total = np.asarray(self.kd) + np.asarray(self.ks) * a
            if (total > 1 + _ALBEDO_SLACK).any():
                advice = ("keep ks + kd <= 1" if self.normalization == "energy" else
                          'normalization="energy" makes that specular albedo ks')
                warnings.warn(f"{_peak_text('BlinnPhong', total, 1.0)}: ks × {a:.3g} + kd (the specular albedo of "
                              f"exponent {self.exponent:g} there, its largest) reflects more light "
                              f"than it receives (an energy gain); {advice}", EnergyWarning, stacklevel=_CALLER)

    def __repr__(self):  # the default normalization left out, so reprs (bench records) read as before
        extra = "" if self.normalization == "iwasaki" else f", normalization={self.normalization!r}"
        return f"BlinnPhong(ks={self.ks!r}, exponent={self.exponent!r}, kd={self.kd!r}{extra})"

    @property
    def ks_scale(self) -> float:
        """s: the factor `packed()` folds into ks (1 for "iwasaki")."""
        if self.normalization == "energy":
            return 1.0 / blinn_phong_normal_albedo(self.exponent)
        return 1.0

    def packed(self):
        if self.normalization == "iwasaki":
            return np.array([*self.kd, *self.ks, self.exponent, 0], np.float64)
        return np.array([*self.kd, *(np.asarray(self.ks) * self.ks_scale), self.exponent, 0], np.float64)


@dataclass(frozen=True)
class CookTorrance(Brdf):
    """Cook–Torrance as Wang 2009 Eq. 10, with Schlick's Fresnel:

    f_r = kd/π + ks·F(h·ωi)·G·D(h) / (π (n·ωi)(n·ωo)),  D = exp(−(θh/m)²),
    F = f0 + (1 − f0)(1 − h·ωi)⁵,  G = min(1, 2(n·h)(n·ωo)/(ωo·h), 2(n·h)(n·ωi)/(ωo·h)).
    `roughness` is m (radians of θh at which D falls to 1/e), at least COOK_TORRANCE_ROUGHNESS_MIN ≈ 1.414e−3 (its
    SG sharpness 2/m² at most SHARPNESS_MAX).

    **What it does to energy.** D is not normalised, so the specular directional albedo grows with m
    (≈ 4m²·F for a narrow lobe) and, for a rough lobe, towards grazing angles. Measured by float64
    quadrature for ks = 1 (tests/test_energy.py):

        m      f0     cos θo = 1   0.5     0.05
        0.2    1      0.156        0.150   0.152
        0.5    1      0.732        0.749   0.837
        1      1      1.221        1.696   2.145
        2      1      1.422        2.320   3.260
        0.5    0.04   0.029        0.046   0.252
        1      0.04   0.049        0.091   0.475

    With f0 = 1 it exceeds ks from m ≈ 0.55 (at grazing angles). A material whose kd + ks·A exceeds 1 at
    some angle gives an `EnergyWarning` (A read from a table over m and cos θo computed once,
    `cook_torrance_albedo`).
    """

    ks: object = 1.0
    roughness: float = 0.2
    f0: float = 0.04
    kd: object = 0.0
    kind = COOK_TORRANCE

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("CookTorrance.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("CookTorrance.kd", self.kd))
        kd_warned = warn_energy("CookTorrance kd", self.kd, stacklevel=_CALLER)
        object.__setattr__(self, "roughness", _lobe_parameter("CookTorrance.roughness", self.roughness,
                                                               least=COOK_TORRANCE_ROUGHNESS_MIN))
        try:
            f0 = float(self.f0)
        except (TypeError, ValueError):
            f0 = float("nan")
        if not (0.0 <= f0 <= 1.0):
            raise ValueError(f"CookTorrance.f0 must lie in [0, 1], got {self.f0!r}")
        object.__setattr__(self, "f0", f0)
        if not kd_warned and max(self.ks) > 0:
            cos_o, a = cook_torrance_albedo(self.roughness, f0)
            j = int(np.argmax(a))
            total = np.asarray(self.kd) + np.asarray(self.ks) * a[j]
            if (total > 1 + _ALBEDO_SLACK).any():
                warnings.warn(f"{_peak_text('CookTorrance', total, cos_o[j])}: ks × {a[j]:.3g} + kd (the specular "
                              f"albedo of roughness {self.roughness:g} and f0 {f0:g} there, its largest) reflects "
                              f"more light than it receives (an energy gain); lower ks, f0 or the roughness",
                              EnergyWarning, stacklevel=_CALLER)

    def packed(self):
        return np.array([*self.kd, *self.ks, self.roughness, self.f0], np.float64)


@dataclass(frozen=True)
class Ward(Brdf):
    """Isotropic Ward: f_r = kd/π + ks·exp(−tan²θh/α²) / (4π α² √(cosθi cosθo)); α ≥ WARD_ALPHA_MIN ≈ 1.414e−3 (its
    SG sharpness 2/α² at most SHARPNESS_MAX)."""

    ks: object = 1.0
    alpha: float = 0.2
    kd: object = 0.0
    kind = WARD

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("Ward.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("Ward.kd", self.kd))
        warn_energy("Ward kd", self.kd, stacklevel=_CALLER)
        object.__setattr__(self, "alpha", _lobe_parameter("Ward.alpha", self.alpha, least=WARD_ALPHA_MIN))

    def packed(self):
        return np.array([*self.kd, *self.ks, self.alpha, 0], np.float64)


def _unit_interval_rgb(name, value) -> tuple:
    rgb = _rgb(name, value)
    if max(rgb) > 1.0:
        raise ValueError(f"{name} must lie in [0, 1] (a reflectance at normal incidence), got {value!r}")
    return rgb


@dataclass(frozen=True)
class AnisotropicWard(Brdf):
    """Anisotropic Ward (Ward 1992 Eq. 5a; Wang 2009 §4.1), in the facet frame (x, y, n) of its tangent:

    f_r = kd/π + ks·exp(−tan²θh·(cos²φh/αx² + sin²φh/αy²)) / (4π αx αy √(cosθi cosθo)),

    θh, φh the half vector's polar angle and its azimuth from x; evaluated as
    exp(−((h·x/αx)² + (h·y/αy)²)/(h·n)²), which needs no trigonometry. `alpha_x` (αx) is the rms slope of the
    microfacets along the tangent x, `alpha_y` (αy) across it (along y = n × x): the highlight is wider along
    the direction of the larger α; each ≥ ANISOTROPIC_WARD_ALPHA_MIN ≈ 1.414e−3 (its ASG bandwidth 1/α² at most
    SHARPNESS_MAX/2). αx = αy = α is exactly the isotropic `Ward(alpha=α)`. (Xu 2013 §5.2 writes
    the exponent as 2((h·x/αx)² + (h·y/αy)²)/(1 + h·n), which agrees with tan² to second order in θh: his
    one-ASG fit, not this BRDF.)

    **What it does to energy.** Ward's 1/(4π αx αy) normalises the lobe only for small widths and away from
    grazing: the specular directional albedo A = ∫ f_s·cos θi dωi falls below ks for narrow lobes as θo grows
    and, through the 1/√(cosθi cosθo), diverges as 1/√cosθo at grazing. Measured by float64 quadrature over
    the half vector for ks = 1, kd = 0 (tests/test_anisotropic.py), at θo = 0°, 60°, 85°, 89° with ωo
    tilted along x | along y:

        αx     αy     0°      60°            85°            89°
        0.05   0.05   0.993   0.497          0.094          0.052
        0.2    0.2    0.895   0.459          0.182          0.242
        0.1    0.4    0.816   0.411 | 0.455  0.102 | 0.308  0.095 | 0.508
        0.05   0.5    0.761   0.381 | 0.447  0.073 | 0.350  0.041 | 0.605
        0.5    0.5    0.586   0.351          0.286          0.499
        0.3    1      0.453   0.247 | 0.337  0.147 | 0.380  0.231 | 0.721

    so kd + ks ≤ 1 keeps A ≤ 1 up to θo = 89°, but not beyond: 1.48 at θo = 89.9° for αx = αy = 0.5 (4.66 at
    89.99°), as the isotropic Ward. No EnergyWarning is given (as for `Ward`): every material has that
    grazing divergence.
    """

    ks: object = 1.0
    alpha_x: float = 0.1
    alpha_y: float = 0.4
    kd: object = 0.0
    kind = ANISOTROPIC_WARD
    anisotropic = True

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("AnisotropicWard.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("AnisotropicWard.kd", self.kd))
        warn_energy("AnisotropicWard kd", self.kd, stacklevel=_CALLER)
        for axis in ("alpha_x", "alpha_y"):
            object.__setattr__(self, axis, _lobe_parameter(f"AnisotropicWard.{axis}", getattr(self, axis),
                                                           least=ANISOTROPIC_WARD_ALPHA_MIN))

    def packed(self):
        return np.array([*self.kd, *self.ks, self.alpha_x, self.alpha_y], np.float64)

    @property
    def ndf_bandwidths(self) -> tuple:
        """(λ, μ) of the ASG that stands for its NDF in the renderer (`ndf_bandwidths`)."""
        return ndf_bandwidths(self.kind, self.alpha_x, self.alpha_y)

    @property
    def ndf_fit_error(self) -> float:
        """Relative L2 error of that ASG against the NDF itself (`ndf_asg_error`)."""
        return ndf_asg_error(self.kind, float(self.alpha_x), float(self.alpha_y))


@dataclass(frozen=True)
class AshikhminShirley(Brdf):
    """The anisotropic Phong BRDF of Ashikhmin & Shirley 2000 (as Xu 2013 §5.2 uses it), in the facet frame
    (u, v, n) of its tangent (u the tangent, v = n × u), k1 = ωi, k2 = ωo, h the half vector:

    f_r = ρs + ρd,
    ρs = √((nu + 1)(nv + 1))/(8π) · (n·h)^((nu (h·u)² + nv (h·v)²)/(1 − (n·h)²)) · F(h·k) / ((h·k) max(n·k1, n·k2)),
    F(c) = Rs + (1 − Rs)(1 − c)⁵  (Schlick),
    ρd = 28 Rd/(23π) · (1 − Rs) · (1 − (1 − n·k1/2)⁵) · (1 − (1 − n·k2/2)⁵).

    `nu`, `nv` (in (0, ASHIKHMIN_SHIRLEY_EXPONENT_MAX = 1e6]: ASG bandwidths nu/2, nv/2 at most SHARPNESS_MAX/2) are
    the Phong exponents of half vectors tilting towards u and towards v: the lobe is
    sharper along the direction of the larger exponent, so nu < nv stretches the highlight along u. `rs`
    (Rs, RGB in [0, 1]) is the specular reflectance at normal incidence, `rd` (Rd, RGB) the diffuse one;
    the diffuse term is not Lambertian: it gives way to the specular one at grazing angles, which is what
    keeps the sum from creating light. nu = nv is the isotropic Phong-like lobe of the paper. The power is
    evaluated as exp(e/2·log(1 − sin²θh)) with sin²θh = (h·u)² + (h·v)² — the same number for unit vectors,
    and exact in float32 for sharp lobes, where n·h rounds to within 6e−8 of 1.

    **What it does to energy.** The model is built so that rs + rd ≤ 1 (per channel) creates no light, and
    constructing one with rs + rd > 1 gives an `EnergyWarning`. The diffuse term alone has the albedo
    rd(1 − rs)(1 − (1 − cosθo/2)⁵) exactly (the 28/23 normalisation: 0.969·rd at normal incidence for rs = 0).
    The specular albedo with F = 1 (rs = 1), measured by float64 quadrature over the half vector
    (tests/test_anisotropic.py), at θo = 0°, 60°, 85°, 89° with ωo tilted along u | along v:

        nu      nv      0°       60°            85°            89°
        1       1       0.250    0.375          0.478          0.496
        10      10      0.696    0.613          0.520          0.504
        100     100     0.961    0.846          0.583          0.517
        8       800     0.809    0.652 | 0.791  0.526 | 0.638  0.505 | 0.530
        200     20000   0.990    0.898 | 0.983  0.620 | 0.930  0.525 | 0.716
        10⁴     10⁴     0.9996   0.986          0.909          0.664

    It stays below 1 and tends to 1 from below as the lobe sharpens (its 1/max(cosθi, cosθo) keeps it bounded
    at grazing, unlike Ward's); Schlick's F ≤ 1 only lowers it. Over (rs, rd) ∈ {(1, 0), (0, 1), (0.5, 0.5),
    (0.2, 0.8), (0.05, 0.95)}, (nu, nv) ∈ {(1, 1), (10, 100), (8, 800), (10⁴, 10⁴)} and θo up to 89° the largest
    total albedo measured is that 0.9996.
    """

    rs: object = 1.0
    nu: float = 10.0
    nv: float = 100.0
    rd: object = 0.0
    kind = ASHIKHMIN_SHIRLEY
    anisotropic = True

    def __post_init__(self):
        object.__setattr__(self, "rs", _unit_interval_rgb("AshikhminShirley.rs", self.rs))
        object.__setattr__(self, "rd", _rgb("AshikhminShirley.rd", self.rd))
        for axis in ("nu", "nv"):
            object.__setattr__(self, axis, _lobe_parameter(f"AshikhminShirley.{axis}", getattr(self, axis),
                                                           most=ASHIKHMIN_SHIRLEY_EXPONENT_MAX))
        total = np.asarray(self.rs) + np.asarray(self.rd)
        if (total > 1 + _ALBEDO_SLACK).any():
            k = int(np.argmax(total))
            where = "" if np.all(total == total[0]) else f" in {'rgb'[k]}"
            warnings.warn(f"AshikhminShirley rs + rd = {total[k]:.3g} > 1{where}: its albedo is bounded by 1 only "
                          "for rs + rd <= 1 (an energy gain)", EnergyWarning, stacklevel=_CALLER)

    # Rd and Rs under the names every other BRDF gives its diffuse and specular reflectance (and the packed row's
    # slots they fill), for code that reads those of any analytic BRDF.
    kd = property(lambda self: self.rd)
    ks = property(lambda self: self.rs)

    def packed(self):
        return np.array([*self.rd, *self.rs, self.nu, self.nv], np.float64)

    @property
    def ndf_bandwidths(self) -> tuple:
        """(λ, μ) of the ASG that stands for its NDF in the renderer (`ndf_bandwidths`)."""
        return ndf_bandwidths(self.kind, self.nu, self.nv)

    @property
    def ndf_fit_error(self) -> float:
        """Relative L2 error of that ASG against the NDF itself (`ndf_asg_error`)."""
        return ndf_asg_error(self.kind, float(self.nu), float(self.nv))


def ndf_bandwidths(kind, p1, p2) -> tuple:
    """(λ, μ): the bandwidths of the one ASG G(h) = exp(−λ(h·x)² − μ(h·y)²) (amplitude 1 at h = n) that stands
    for an anisotropic BRDF's NDF in the renderers (Xu 2013 §5.2), from its packed p1, p2. Anisotropic Ward:
    1/αx², 1/αy² (exp(−((h·x/αx)² + (h·y/αy)²)/(h·n)²) to second order in θh); Ashikhmin–Shirley: nu/2, nv/2
    ((n·h)^e = (1 − sin²θh)^(e/2) = exp(−e·sin²θh/2 + O(sin⁴θh)))."""
    if kind == ANISOTROPIC_WARD:
        return 1.0 / np.square(p1), 1.0 / np.square(p2)
    if kind == ASHIKHMIN_SHIRLEY:
        return np.asarray(p1) / 2.0, np.asarray(p2) / 2.0
    raise ValueError(f"ndf_bandwidths: kind {kind} is not an anisotropic BRDF's")


NDF_ERROR_NODES = 96  # Gauss–Legendre nodes per axis of `ndf_asg_error`'s disk rule (converged to < 1e−4 relative)


@functools.lru_cache(maxsize=256)
def ndf_asg_error(kind, p1: float, p2: float) -> float:
    """Relative L2 error, over the half vectors of the upper hemisphere, of the one ASG that stands for an
    anisotropic BRDF's NDF in the renderers and the ASG bake, (h·n)·exp(−λ(h·x)² − μ(h·y)²) (`ndf_bandwidths`),
    against the NDF itself with the same peak: anisotropic Ward's exp(−((h·x/αx)² + (h·y/αy)²)/(h·n)²),
    Ashikhmin–Shirley's (h·n)^((nu(h·x)² + nv(h·y)²)/(1 − (h·n)²)). The fit error the bakes report
    (`info["ndf_asg_error"]`). By Gauss–Legendre in the disk coordinates (a, b) = (h·x, h·y), dω = da db/(h·n),
    on a box of ±8 standard deviations of the ASG per axis (the whole disk where that is wider)."""
    lam, mu = ndf_bandwidths(kind, p1, p2)
    x, w = np.polynomial.legendre.leggauss(NDF_ERROR_NODES)
    half = np.minimum(1.0, 8.0 / np.sqrt(2.0 * np.array([lam, mu])))
    a, b = np.meshgrid(x * half[0], x * half[1], indexing="ij")
    wa = np.outer(w * half[0], w * half[1])
    r2 = a * a + b * b
    inside = r2 < 1.0
    t = np.sqrt(np.where(inside, 1.0 - r2, 1.0))
    fit = t * np.exp(-lam * a * a - mu * b * b)
    if kind == ANISOTROPIC_WARD:
        ndf = np.exp(-((a / p1) ** 2 + (b / p2) ** 2) / (t * t))
    elif kind == ASHIKHMIN_SHIRLEY:
        ndf = np.exp(np.where(r2 > 0, (p1 * a * a + p2 * b * b) / np.where(r2 > 0, r2, 1.0), 0.0) * np.log(t))
    else:
        raise ValueError(f"ndf_asg_error: kind {kind} is not an anisotropic BRDF's")
    weight = np.where(inside, wa / t, 0.0)
    return float(np.sqrt(np.sum(weight * (fit - ndf) ** 2) / np.sum(weight * ndf * ndf)))


_ANISOTROPIC_REFUSAL = ("it needs each facet's tangent, which only the ground truth (wb.ground_truth, "
                        "wb.effective_brdf_exact), the ASG bake (method='asg') and the renderers (as a large-scale "
                        "material) have; SG- and matrix-baked materials, lit spheres and textured (svbrdf.Textured) "
                        "materials do not take anisotropic BRDFs")


def refuse_anisotropic(materials, why: str = _ANISOTROPIC_REFUSAL) -> None:
    """A one-line ValueError naming the first anisotropic BRDF of `materials` (one BRDF or a list), and why
    the caller cannot take it."""
    for i, m in enumerate(as_material_list(materials, anisotropic=True)):
        if m.anisotropic:
            raise ValueError(f"materials[{i}] ({type(m).__name__}) is anisotropic: {why}")


def as_material_list(materials, anisotropic: bool = False) -> list:
    """One BRDF or a sequence of them (indexed by material id) → a list of `Brdf`. An anisotropic BRDF is refused
    (`refuse_anisotropic`) unless `anisotropic`: only a caller that supplies tangents may take one."""
    if isinstance(materials, str):  # (read as a list, it was one "BRDF" a character)
        raise ValueError(f"materials is the string {materials!r}: pass BRDF objects (e.g. Lambert(0.5)); "
                         "warp_biscale.brdf.parse_brdf reads the command line's spec strings")
    if isinstance(materials, Brdf):
        mats = [materials]
    else:
        try:
            mats = list(materials)
        except TypeError:
            raise ValueError(f"materials must be a BRDF or a list of BRDFs, got {materials!r}") from None
    if not mats:
        raise ValueError("materials is empty: give one BRDF per material id")
    for i, m in enumerate(mats):
        if not isinstance(m, Brdf):
            raise ValueError(f"materials[{i}] is not a BRDF (Lambert, BlinnPhong, CookTorrance, Ward, "
                             f"AnisotropicWard, AshikhminShirley): {m!r}")
    if not anisotropic:
        refuse_anisotropic(mats)
    return mats


def pack_materials(materials, n_required: int = 0, anisotropic: bool = False, measured: bool = False):
    """→ (kinds int32 (M,), params float64 (M, 8)). `n_required`: the tile's number of material ids.
    `anisotropic`: accept anisotropic BRDFs (the caller then passes the facets' tangents to the kernels).
    `measured`: accept measured BRDFs (the caller then passes `measured_tables(materials)` to the kernels);
    otherwise `MeasuredBRDF.packed` refuses one in one line."""
    mats = as_material_list(materials, anisotropic)
    if n_required > len(mats):
        raise ValueError(
            f"the tile uses material ids 0..{n_required - 1} but only {len(mats)} material(s) were given"
        )
    kinds = np.array([m.kind for m in mats], np.int32)
    if measured:
        slots = {id(t.data): s for s, t in enumerate(measured_tables(mats))}
        params = np.stack([m.kernel_row(slots[id(m.data)]) if m.kind == MEASURED else m.packed() for m in mats])
    else:
        params = np.stack([m.packed() for m in mats])
    return kinds, params.astype(np.float64)


def sg_lobes(brdf) -> tuple:
    """The analytic single-lobe BRDFs whose sum stands for `brdf` wherever its specular lobe is an SG (the SG
    and ASG bakes' f̄, the SG renderer's shading): (brdf,) itself, or for a measured one its SG fit's lobes
    (`MeasuredBRDF.sg_fit`: one or two Cook–Torrance lobes whose NDFs are read as SGs, the first carrying the
    fit's kd, the others kd = 0). The ground truth, the matrix method and the Monte Carlo reference evaluate
    the measured table itself."""
    return brdf.sg_fit().lobes if brdf.kind == MEASURED else (brdf,)


def diffuse_albedo(brdf) -> np.ndarray:
    """(3,) float64: the Lambertian albedo of `brdf`'s SG form (Lambert's albedo, any other model's kd; a
    measured one's fitted kd). Ashikhmin–Shirley's diffuse term is not Lambertian: its albedo at incidence θi is
    rd(1 − rs)g(cos θi), g(c) = 1 − (1 − c/2)⁵, whose cosine-weighted mean over θi is rd(1 − rs)·23/28 — the
    Lambertian albedo of the same energy, which an effective material's facets average it to."""
    if isinstance(brdf, AshikhminShirley):
        return np.asarray(brdf.rd, np.float64) * (1 - np.asarray(brdf.rs, np.float64)) * (23.0 / 28.0)
    return sum(np.asarray(b.albedo if isinstance(b, Lambert) else b.kd, np.float64) for b in sg_lobes(brdf))


def measured_tables(materials) -> list:
    """The measured BRDFs of `materials` (a list of `Brdf`) whose tables the kernels need, one per distinct
    table (two objects sharing one table, e.g. `with_interpolation`, share a slot), in order of first use:
    slot s of `pack_materials(..., measured=True)`'s rows is entry s, whose `kernel_table()` the backends
    upload (and cache by the table's identity)."""
    out, seen = [], set()
    for m in materials:
        if getattr(m, "kind", None) == MEASURED and id(m.data) not in seen:
            seen.add(id(m.data))
            out.append(m)
    return out


_BRDF_NAMES = {"lambert": Lambert, "blinnphong": BlinnPhong, "blinn-phong": BlinnPhong, "phong": BlinnPhong,
               "cooktorrance": CookTorrance, "cook-torrance": CookTorrance, "ct": CookTorrance, "ward": Ward,
               "anisotropicward": AnisotropicWard, "anisotropic-ward": AnisotropicWard,
               "ashikhminshirley": AshikhminShirley, "ashikhmin-shirley": AshikhminShirley, "as": AshikhminShirley}


def parse_brdf(text: str) -> Brdf:
    """Parse a command-line BRDF: ``name[:key=value,...]``, e.g. ``blinnphong:exponent=512,ks=0.8``.

    Names: lambert (albedo), blinnphong (ks, exponent, kd, normalization), cooktorrance (ks, roughness, f0,
    kd), ward (ks, alpha, kd), anisotropicward (ks, alpha_x, alpha_y, kd), ashikhminshirley or as (rs, nu,
    nv, rd). ``ward`` with alpha_x and alpha_y (both, instead of alpha) is the anisotropic Ward, e.g.
    ``ward:alpha_x=0.1,alpha_y=0.4``: αx the rms slope along the facet's tangent, αy across it. For
    Ashikhmin–Shirley, nu and nv are the Phong exponents towards the tangent and across it, rs the
    specular reflectance at normal incidence (in [0, 1]) and rd the diffuse one, e.g.
    ``as:nu=10,nv=1000,rs=0.8,rd=0.2``. Values are numbers or RGB triples written ``r/g/b``; the
    word-valued key, Blinn–Phong's normalization, takes ``iwasaki`` (the default: the paper's lobe, whose
    specular albedo is up to 4·ks) or ``energy`` (specular albedo ks at normal incidence, less elsewhere),
    e.g. ``blinnphong:exponent=128,normalization=energy``.
    """
    name, _, rest = text.partition(":")
    cls = _BRDF_NAMES.get(name.strip().lower())
    if cls is None:
        raise ValueError(f"unknown BRDF {name!r}; choose one of lambert, blinnphong (phong), cooktorrance (ct), "
                         "ward, anisotropicward, ashikhminshirley (as)")
    items = [s.strip() for s in rest.split(",")] if rest.strip() else []
    if "" in items:
        raise ValueError(f"BRDF spec {text!r} has an empty parameter (two commas in a row, or one at an end)")
    for item in items:
        if "=" not in item:
            raise ValueError(f"BRDF parameter {item!r} must be key=value")
    keys = {item.partition("=")[0].strip() for item in items}
    if cls is Ward and keys & {"alpha_x", "alpha_y"}:  # "ward" with αx, αy is the anisotropic Ward
        if "alpha" in keys:
            raise ValueError("ward takes alpha (isotropic) or alpha_x and alpha_y (anisotropic), not both")
        cls = AnisotropicWard
    # An anisotropic BRDF's two axes come together: one given alone would silently pair with the other's default.
    axes = {AnisotropicWard: ("the anisotropic ward", "alpha_x", "alpha_y"),
            AshikhminShirley: ("ashikhminshirley", "nu", "nv")}.get(cls)
    if axes is not None and len(keys & set(axes[1:])) == 1:
        raise ValueError(f"{axes[0]} needs both {axes[1]} and {axes[2]} (or neither, for the defaults), got only "
                         f"{(keys & set(axes[1:])).pop()}")
    names = [f.name for f in fields(cls)]
    words = {f.name for f in fields(cls) if isinstance(f.default, str)}  # keys whose value is a word
    kwargs = {}
    for item in items:
        key, eq, val = item.partition("=")
        if not eq:
            raise ValueError(f"BRDF parameter {item!r} must be key=value")
        key = key.strip()
        if key not in names:
            raise ValueError(f"{cls.__name__} has no parameter {key!r} (it has {', '.join(names)})")
        if key in kwargs:  # (a typo'd spec: silently keeping the last value would hide it)
            raise ValueError(f"BRDF parameter {key!r} is given twice in {text!r}")
        if key in words:
            kwargs[key] = val.strip()  # checked by the class, whose error names it
            continue
        try:
            parts = [float(p) for p in val.split("/")]
        except ValueError:
            raise ValueError(f"BRDF parameter {key}={val!r} is not a number or r/g/b triple") from None
        kwargs[key] = parts[0] if len(parts) == 1 else parts
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ValueError(f"bad parameter for {cls.__name__}: {exc}") from None


def tangent_frame(n, t):
    """(x, y), each (N, 3): the facet frame's unit tangent x = t − (t·n)n normalised, and y = n × x, for unit
    normals n and tangents t (N, 3). Where t is within 0.01 rad of ±n (|t − (t·n)n|² < TANGENT_DEGENERATE)
    x is instead built from n alone (Duff et al. 2017's branchless basis: for s = sign(n_z) (+1 at 0),
    a = −1/(s + n_z), x = (1 + s·n_x²·a, s·n_x·n_y·a, −s·n_x)), so the frame is defined for any input.
    Ward's and Ashikhmin–Shirley's lobes are even in x and in y, so the tangent's sign never matters."""
    n = np.asarray(n, np.float64)
    t = np.asarray(t, np.float64)
    x = t - np.einsum("ij,ij->i", t, n)[:, None] * n
    l2 = np.einsum("ij,ij->i", x, x)
    bad = l2 < TANGENT_DEGENERATE
    if bad.any():
        nb = n[bad]
        s = np.where(nb[:, 2] >= 0, 1.0, -1.0)
        a = -1.0 / (s + nb[:, 2])
        x[bad] = np.stack([1 + s * nb[:, 0] ** 2 * a, s * nb[:, 0] * nb[:, 1] * a, -s * nb[:, 0]], 1)
        l2[bad] = np.einsum("ij,ij->i", x[bad], x[bad])
    x = x / np.sqrt(l2)[:, None]
    return x, np.cross(n, x)


def brdf_cosine_weighted(kinds, params, material, n, wi, wo, tangent=None) -> np.ndarray:
    """(N, 3) f_r·(n·ωi)⁺(n·ωo)⁺ for facets with normals n (N,3) and material ids (N,). `tangent` (N, 3): the
    facets' tangents (`tangent_frame`), needed by the anisotropic kinds only (an error if one is present
    without it)."""
    n, wi, wo = (np.asarray(x, np.float64) for x in (n, wi, wo))
    n, wi, wo = np.broadcast_arrays(n, wi, wo)
    kind = np.asarray(kinds)[material]
    if np.isin(kind, ANISOTROPIC_KINDS).any():
        if tangent is None:
            raise ValueError("an anisotropic BRDF needs the facets' tangents (brdf_cosine_weighted(..., tangent))")
        tangent = np.broadcast_to(np.asarray(tangent, np.float64), n.shape)
    p = np.asarray(params, np.float64)[material]
    kd, ks, p1, p2 = p[:, 0:3], p[:, 3:6], p[:, 6], p[:, 7]
    ci = np.einsum("ij,ij->i", n, wi)
    co = np.einsum("ij,ij->i", n, wo)
    ok = (ci > 0) & (co > 0)
    ci, co = np.maximum(ci, 0.0), np.maximum(co, 0.0)
    h = wi + wo
    hl = np.linalg.norm(h, axis=1)
    h = h / np.maximum(hl, 1e-300)[:, None]
    nh = np.clip(np.einsum("ij,ij->i", n, h), -1.0, 1.0)
    nh_pos = np.maximum(nh, 0.0)
    hi = np.clip(np.einsum("ij,ij->i", h, wi), 0.0, 1.0)
    spec = np.zeros(len(n))  # scalar specular factor multiplying ks, already cosine-weighted
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        m = kind == BLINN_PHONG
        spec[m] = (p1[m] + 2) / (2 * np.pi) * nh_pos[m] ** p1[m] * ci[m] * co[m]
        m = kind == COOK_TORRANCE
        if m.any():
            theta_h = np.arccos(nh[m])
            d = np.exp(-((theta_h / p1[m]) ** 2))
            f = p2[m] + (1 - p2[m]) * (1 - hi[m]) ** 5
            ho = np.maximum(hi[m], 1e-300)  # h·ωo = h·ωi
            g = np.minimum(1.0, np.minimum(2 * nh_pos[m] * co[m] / ho, 2 * nh_pos[m] * ci[m] / ho))
            spec[m] = f * g * d / np.pi
        m = kind == WARD
        if m.any():
            cos2 = np.maximum(nh[m] ** 2, 1e-300)
            tan2 = (1 - cos2) / cos2
            a2 = p1[m] ** 2
            spec[m] = np.where(nh[m] > 0, np.exp(-tan2 / a2), 0.0) / (4 * np.pi * a2) * np.sqrt(ci[m] * co[m])
        m = kind == ANISOTROPIC_WARD
        if m.any():
            x, y = tangent_frame(n[m], tangent[m])
            hx, hy = np.einsum("ij,ij->i", h[m], x), np.einsum("ij,ij->i", h[m], y)
            e = (hx / p1[m]) ** 2 + (hy / p2[m]) ** 2  # tan²θh(cos²φh/αx² + sin²φh/αy²)·cos²θh
            spec[m] = (np.where(nh[m] > 0, np.exp(-e / np.maximum(nh[m] ** 2, 1e-300)), 0.0)
                       / (4 * np.pi * p1[m] * p2[m]) * np.sqrt(ci[m] * co[m]))
    # Lambert keeps its albedo in the kd slot and ks = 0, so one expression serves every model.
    out = kd / np.pi * (ci * co)[:, None] + ks * spec[:, None]
    m = (kind == ASHIKHMIN_SHIRLEY) & ok
    if m.any():
        out[m] = _ashikhmin_shirley(p[m], n[m], tangent[m], h[m], ci[m], co[m], hi[m])
    out[~ok] = 0.0
    return out


def _ashikhmin_shirley(p, n, tangent, h, ci, co, hk) -> np.ndarray:
    """(N, 3) Ashikhmin–Shirley's f_r·cosθi·cosθo (both cosines > 0) for packed rows p = [Rd, Rs, nu, nv]."""
    rd, rs, nu, nv = p[:, 0:3], p[:, 3:6], p[:, 6], p[:, 7]
    u, v = tangent_frame(n, tangent)
    hu, hv = np.einsum("ij,ij->i", h, u), np.einsum("ij,ij->i", h, v)
    s2 = hu * hu + hv * hv  # sin²θh: 1 − (n·h)² without its cancellation near h = n
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(s2 > 0, (nu * hu * hu + nv * hv * hv) / np.where(s2 > 0, s2, 1.0), 0.0)
        # (n·h)^e = exp(e/2·log(1 − sin²θh)); D = 1 at h = n (s2 = 0), 0 for h in the tangent plane
        d = np.where(s2 < 1, np.exp(0.5 * e * np.log1p(-np.minimum(s2, 1.0))), 0.0)
    fresnel = rs + (1 - rs) * ((1 - hk) ** 5)[:, None]
    # ρs·cosθi·cosθo: the 1/((h·k)·max(cosθi, cosθo)) of ρs times both cosines is min(cosθi, cosθo)/(h·k).
    spec = np.sqrt((nu + 1) * (nv + 1)) / (8 * np.pi) * d * np.minimum(ci, co) / np.maximum(hk, 1e-300)
    diffuse = (28 / (23 * np.pi)) * (1 - (1 - ci / 2) ** 5) * (1 - (1 - co / 2) ** 5) * ci * co
    return rd * (1 - rs) * diffuse[:, None] + fresnel * spec[:, None]
