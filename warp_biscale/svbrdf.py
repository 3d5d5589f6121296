"""Spatially varying analytic BRDFs (Wang 2009 §4.1/§6: "texturing over the surface the parameters ks,
kd and the model parameter").

    mat = wb.Textured(wb.BlinnPhong(0.5, 200, kd=0.8), kd_map="albedo.png", parameter_map=rough)

`Textured` wraps an analytic `Brdf` (Lambert, BlinnPhong, CookTorrance, Ward) with up to three maps,
each a multiplier of the wrapped BRDF's own values at a surface point with texture coordinates (u, v)
(the mesh's `uvs`, interpolated with the pixel's barycentrics):

    kd ← kd ⊙ kd_map(u, v),   ks ← ks ⊙ ks_map(u, v),   p1 ← p1 · parameter_map(u, v)

where p1 is the Blinn–Phong exponent, the Cook–Torrance roughness m or the Ward alpha (Cook–Torrance's f0
is not textured). Maps are linear floats: (H, W, 3) for kd and ks, (H, W) for the parameter, or a path
read with `images.read_image` (8-bit sRGB images are decoded to linear; the parameter map takes channel
0). Values must be finite and >= 0, the parameter map's > 0, and the parameter it scales must stay within the
BRDF's own bounds (`brdf.P1_BOUNDS`: no lobe sharper than the SG forms hold).

Lookup convention (the kernels and `sample` agree): bilinear, wrapping (repeat) in u and v; texel (i, j)
(row i, column j) is centred at (u, v) = ((j + ½)/W, (i + ½)/H), so row 0 sits at v = 0 — an image read
from a file is therefore applied with its top row at v = 0 (flip it vertically for the OpenGL habit of
v = 0 at the bottom).

The effective (bi-scale) materials are not textured: their small-scale BRDFs are baked into tables.
"""

from __future__ import annotations

import os

import numpy as np

from . import brdf as brdf_mod
from .images import read_image

__all__ = ["Textured", "sample"]

MAP_NAMES = ("kd_map", "ks_map", "parameter_map")


def sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, repeat-wrapped float64 lookup of an (H, W, C) image at uv (N, 2) → (N, C): the module's
    convention (texel (i, j) centred at ((j + ½)/W, (i + ½)/H))."""
    image = np.asarray(image, np.float64)
    h, w = image.shape[:2]
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    j0, i0 = np.mod(x0.astype(np.int64), w), np.mod(y0.astype(np.int64), h)
    j1, i1 = (j0 + 1) % w, (i0 + 1) % h
    top = image[i0, j0] * (1 - fx) + image[i0, j1] * fx
    bottom = image[i1, j0] * (1 - fx) + image[i1, j1] * fx
    return top * (1 - fy) + bottom * fy


def _load_map(name, value, rgb: bool) -> np.ndarray | None:
    if value is None:
        return None
    if isinstance(value, (str, os.PathLike)):

        try:
            a = read_image(value)
        except (OSError, ValueError) as exc:
            raise ValueError(f"Textured.{name}: cannot read {os.fspath(value)!r}: {exc}") from None
        if not rgb:
            a = a[..., 0]
    else:
        try:
            a = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"Textured.{name} must be an array or an image path, got {type(value).__name__}") from None
    want = "(H, W, 3)" if rgb else "(H, W)"
    if a.ndim != (3 if rgb else 2) or (rgb and a.shape[2] != 3) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"Textured.{name} must have shape {want}, got {a.shape}")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise ValueError(f"Textured.{name} has non-finite values (NaN or inf)")
    if rgb and (a < 0).any():
        raise ValueError(f"Textured.{name} must be >= 0 everywhere, its minimum is {a.min():.6g}")
    if not rgb and (a <= 0).any():
        raise ValueError(f"Textured.{name} must be > 0 everywhere (it multiplies the model parameter), "
                         f"its minimum is {a.min():.6g}")
    return np.ascontiguousarray(a, np.float32)


def _check_scaled_parameter(brdf, parameter_map) -> None:
    """Refuse a parameter map that scales the BRDF's p1 past the sharpest lobe the SG forms hold (`brdf.P1_BOUNDS`),
    in one line naming the map's extreme value. The kernels interpolate the map bilinearly, so p1 · map lies between
    p1 times the map's smallest and largest texels (the float32 texels the kernels read, as checked here)."""
    bounds = brdf_mod.P1_BOUNDS.get(brdf.kind)
    if bounds is None:
        return
    name, least, most = bounds
    p1 = float(getattr(brdf, name))
    lo, hi = float(parameter_map.min()), float(parameter_map.max())
    for factor, bad, limit in ((hi, p1 * hi > most, f"<= {most:g}"), (lo, p1 * lo < least, f">= {least:.4g}")):
        if bad:
            raise ValueError(f"Textured.parameter_map reaches {factor:.6g}: it scales {type(brdf).__name__}.{name} "
                             f"{p1:g} to {p1 * factor:.6g}, which must be {limit} (a sharper lobe than the SG forms "
                             f"hold, sg.SHARPNESS_MAX)")


class Textured:
    """An analytic `Brdf` whose kd, ks and model parameter p1 are scaled by texture maps (module docstring)."""

    def __init__(self, brdf, kd_map=None, ks_map=None, parameter_map=None):
        if not isinstance(brdf, brdf_mod.Brdf):
            raise ValueError(f"Textured.brdf must be an analytic BRDF (Lambert, BlinnPhong, CookTorrance, Ward), "
                             f"got {brdf!r}")
        if isinstance(brdf, brdf_mod.Lambert) and (ks_map is not None or parameter_map is not None):
            raise ValueError("Textured: a Lambert BRDF has no ks or model parameter: give only kd_map")
        if parameter_map is not None and getattr(brdf, "normalization", "iwasaki") != "iwasaki":
            # Its factor is a function of the exponent folded into ks; the kernels scale the exponent per texel
            # and would keep the untextured exponent's factor, so the lobe would no longer be what it says.
            raise ValueError(f"Textured: parameter_map cannot vary the exponent of a BlinnPhong with "
                             f"normalization={brdf.normalization!r} (its energy factor depends on the exponent)")
        self.brdf = brdf
        self.kd_map = _load_map("kd_map", kd_map, True)
        self.ks_map = _load_map("ks_map", ks_map, True)
        self.parameter_map = _load_map("parameter_map", parameter_map, False)
        if self.parameter_map is not None:
            _check_scaled_parameter(brdf, self.parameter_map)
        if self.kd_map is not None:  # the diffuse reflectance kd ⊙ kd_map where the map is brightest
            lambert = isinstance(brdf, brdf_mod.Lambert)
            kd = np.asarray(brdf.albedo if lambert else brdf.kd, np.float64)
            peak = kd * self.kd_map.reshape(-1, 3).max(axis=0).astype(np.float64)
            if not (kd > 1).any():  # (a kd above 1 was warned of by the BRDF itself)
                name = f"Textured {type(brdf).__name__} {'albedo' if lambert else 'kd'} × kd_map (at its brightest)"
                brdf_mod.warn_energy(name, peak, stacklevel=2)

    @property
    def maps(self) -> tuple:
        """(kd_map, ks_map, parameter_map), None where absent."""
        return self.kd_map, self.ks_map, self.parameter_map

    def __repr__(self):
        maps = ", ".join(f"{n}={m.shape[0]}x{m.shape[1]}" for n, m in zip(MAP_NAMES, self.maps) if m is not None)
        return f"Textured({self.brdf!r}{', ' + maps if maps else ''})"

    def at(self, uv) -> list:
        """(N, 8) float64 parameter rows at uv (N, 2) in brdf.pack_materials' layout [kd, ks, p1, p2], the
        maps applied (float64 lookups): what the material is at each point."""
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        kinds, params = brdf_mod.pack_materials([self.brdf])
        rows = np.tile(params[0].astype(np.float64), (len(uv), 1))
        if self.kd_map is not None:
            rows[:, 0:3] *= sample(self.kd_map, uv)
        if self.ks_map is not None:
            rows[:, 3:6] *= sample(self.ks_map, uv)
        if self.parameter_map is not None:
            rows[:, 6] *= sample(self.parameter_map[..., None], uv)[:, 0]
        return rows
