"""Small-scale BRDFs as plain parameter objects.

Every model is isotropic and is written in the facet's local frame, so it needs only the facet
normal n, the light direction ωi and the view direction ωo. All parameters are RGB (a scalar is
broadcast). Kernels evaluate the *cosine-weighted* value f_r·(n·ωi)⁺(n·ωo)⁺, which stays finite at
grazing angles where f_r itself (Cook–Torrance, Ward) divides by a vanishing cosine.

Packed layout shared by the reference, the Warp and the OpenCL kernels, one row per material:
``kind`` (int: 0 Lambert, 1 Blinn–Phong, 2 Cook–Torrance, 3 Ward) and
``params`` = [kd_r, kd_g, kd_b, ks_r, ks_g, ks_b, p1, p2] (float32).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["Lambert", "BlinnPhong", "CookTorrance", "Ward", "Brdf", "pack_materials", "as_material_list",
           "parse_brdf", "EnergyWarning"]

LAMBERT, BLINN_PHONG, COOK_TORRANCE, WARD = 0, 1, 2, 3


class EnergyWarning(UserWarning):
    """A material reflects more light than it receives (a diffuse albedo above 1): allowed, but not physical."""


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


def warn_energy(name, rgb, stacklevel: int = 2) -> None:
    """An `EnergyWarning` when a diffuse reflectance (an RGB triple: Lambert albedo, kd) has a channel > 1:
    a Lambertian term reflects its albedo of what it receives, so more than 1 creates light."""
    a = np.asarray(rgb, np.float64).reshape(-1)
    if not (a > 1).any():
        return
    if np.all(a == a[0]):
        shown = f"{a[0]:g} > 1"
    else:
        k = int(np.argmax(a))
        shown = f"({', '.join(f'{x:g}' for x in a)}): {'rgb'[k]} = {a[k]:g} > 1"
    warnings.warn(f"{name} {shown} reflects more light than it receives (an energy gain; keep it <= 1)",
                  EnergyWarning, stacklevel=stacklevel + 1)


def _positive(name, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return x


# The stack level of a warning from a BRDF's __post_init__ that points at the line constructing it
# (warn_energy ← __post_init__ ← the dataclass __init__ ← the caller).
_CALLER = 3


class Brdf:
    """Base of the small-scale BRDF parameter objects."""

    kind: int

    def packed(self) -> np.ndarray:
        raise NotImplementedError

    def eval(self, n, wi, wo) -> np.ndarray:
        """f_r(n, ωi, ωo) in float64, (N, 3) RGB; zero where ωi or ωo is below the facet."""
        n, wi, wo = (np.atleast_2d(np.asarray(x, np.float64)) for x in (n, wi, wo))
        kinds, params = pack_materials([self])
        fc = brdf_cosine_weighted(kinds, params, np.zeros(len(n), np.int32), n, wi, wo)
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
    """Normalised Blinn–Phong as Iwasaki §4.1: f_r = kd/π + ks·(n+2)/(2π)·(n·h)^n, h the half vector."""

    ks: object = 1.0
    exponent: float = 64.0
    kd: object = 0.0
    kind = BLINN_PHONG

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("BlinnPhong.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("BlinnPhong.kd", self.kd))
        warn_energy("BlinnPhong kd", self.kd, stacklevel=_CALLER)
        object.__setattr__(self, "exponent", _positive("BlinnPhong.exponent", self.exponent))

    def packed(self):
        return np.array([*self.kd, *self.ks, self.exponent, 0], np.float64)


@dataclass(frozen=True)
class CookTorrance(Brdf):
    """Cook–Torrance as Wang 2009 Eq. 10, with Schlick's Fresnel:

    f_r = kd/π + ks·F(h·ωi)·G·D(h) / (π (n·ωi)(n·ωo)),  D = exp(−(θh/m)²),
    F = f0 + (1 − f0)(1 − h·ωi)⁵,  G = min(1, 2(n·h)(n·ωo)/(ωo·h), 2(n·h)(n·ωi)/(ωo·h)).
    `roughness` is m (radians of θh at which D falls to 1/e).
    """

    ks: object = 1.0
    roughness: float = 0.2
    f0: float = 0.04
    kd: object = 0.0
    kind = COOK_TORRANCE

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("CookTorrance.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("CookTorrance.kd", self.kd))
        warn_energy("CookTorrance kd", self.kd, stacklevel=_CALLER)
        object.__setattr__(self, "roughness", _positive("CookTorrance.roughness", self.roughness))
        try:
            f0 = float(self.f0)
        except (TypeError, ValueError):
            f0 = float("nan")
        if not (0.0 <= f0 <= 1.0):
            raise ValueError(f"CookTorrance.f0 must lie in [0, 1], got {self.f0!r}")
        object.__setattr__(self, "f0", f0)

    def packed(self):
        return np.array([*self.kd, *self.ks, self.roughness, self.f0], np.float64)


@dataclass(frozen=True)
class Ward(Brdf):
    """Isotropic Ward: f_r = kd/π + ks·exp(−tan²θh/α²) / (4π α² √(cosθi cosθo))."""

    ks: object = 1.0
    alpha: float = 0.2
    kd: object = 0.0
    kind = WARD

    def __post_init__(self):
        object.__setattr__(self, "ks", _rgb("Ward.ks", self.ks))
        object.__setattr__(self, "kd", _rgb("Ward.kd", self.kd))
        warn_energy("Ward kd", self.kd, stacklevel=_CALLER)
        object.__setattr__(self, "alpha", _positive("Ward.alpha", self.alpha))

    def packed(self):
        return np.array([*self.kd, *self.ks, self.alpha, 0], np.float64)


def as_material_list(materials) -> list:
    """One BRDF or a sequence of them (indexed by material id) → a list of `Brdf`."""
    if isinstance(materials, Brdf):
        return [materials]
    try:
        mats = list(materials)
    except TypeError:
        raise ValueError(f"materials must be a BRDF or a list of BRDFs, got {materials!r}") from None
    if not mats:
        raise ValueError("materials is empty: give one BRDF per material id")
    for i, m in enumerate(mats):
        if not isinstance(m, Brdf):
            raise ValueError(f"materials[{i}] is not a BRDF (Lambert, BlinnPhong, CookTorrance, Ward): {m!r}")
    return mats


def pack_materials(materials, n_required: int = 0):
    """→ (kinds int32 (M,), params float64 (M, 8)). `n_required`: the tile's number of material ids."""
    mats = as_material_list(materials)
    if n_required > len(mats):
        raise ValueError(
            f"the tile uses material ids 0..{n_required - 1} but only {len(mats)} material(s) were given"
        )
    kinds = np.array([m.kind for m in mats], np.int32)
    params = np.stack([m.packed() for m in mats]).astype(np.float64)
    return kinds, params


_BRDF_NAMES = {"lambert": Lambert, "blinnphong": BlinnPhong, "blinn-phong": BlinnPhong, "phong": BlinnPhong,
               "cooktorrance": CookTorrance, "cook-torrance": CookTorrance, "ct": CookTorrance, "ward": Ward}


def parse_brdf(text: str) -> Brdf:
    """Parse a command-line BRDF: ``name[:key=value,...]``, e.g. ``blinnphong:exponent=512,ks=0.8``.

    Values are numbers or RGB triples written ``r/g/b``.
    """
    name, _, rest = text.partition(":")
    cls = _BRDF_NAMES.get(name.strip().lower())
    if cls is None:
        raise ValueError(f"unknown BRDF {name!r}; choose one of lambert, blinnphong, cooktorrance, ward")
    kwargs = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise ValueError(f"BRDF parameter {item!r} must be key=value")
        try:
            parts = [float(p) for p in val.split("/")]
        except ValueError:
            raise ValueError(f"BRDF parameter {key}={val!r} is not a number or r/g/b triple") from None
        kwargs[key.strip()] = parts[0] if len(parts) == 1 else parts
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ValueError(f"bad parameter for {cls.__name__}: {exc}") from None


def brdf_cosine_weighted(kinds, params, material, n, wi, wo) -> np.ndarray:
    """(N, 3) f_r·(n·ωi)⁺(n·ωo)⁺ for facets with normals n (N,3) and material ids (N,)."""
    n, wi, wo = (np.asarray(x, np.float64) for x in (n, wi, wo))
    n, wi, wo = np.broadcast_arrays(n, wi, wo)
    kind = np.asarray(kinds)[material]
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
    # Lambert keeps its albedo in the kd slot and ks = 0, so one expression serves every model.
    out = kd / np.pi * (ci * co)[:, None] + ks * spec[:, None]
    out[~ok] = 0.0
    return out
