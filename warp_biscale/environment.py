"""Distant environment lighting as an equirectangular radiance map (Wang 2009 §6).

Convention (world +y up): texel (row i, column j) of an H×W map is centred on
θ = π(i + ½)/H (polar angle from +y) and φ = 2π(j + ½)/W, with direction
d = (sin θ cos φ, cos θ, sin θ sin φ). Row 0 is the zenith side. `lookup` is bilinear in (θ, φ),
wrapping in φ and clamping in θ.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Environment", "equirect_directions", "direction_to_equirect"]


def equirect_directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) float64 unit directions of the texel centres."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    st = np.sin(theta)[:, None]
    return np.stack([st * np.cos(phi)[None], np.broadcast_to(np.cos(theta)[:, None], (height, width)),
                     st * np.sin(phi)[None]], -1)


def direction_to_equirect(d: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous texel coordinates (row, column) of unit directions d (..., 3): texel centres at
    integers, so row = θH/π − ½, column = φW/(2π) − ½ with φ in [0, 2π)."""
    d = np.asarray(d, np.float64)
    theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
    phi = np.mod(np.arctan2(d[..., 2], d[..., 0]), 2 * np.pi)
    return theta * height / np.pi - 0.5, phi * width / (2 * np.pi) - 0.5


@dataclass(eq=False)
class Environment:
    """An equirectangular radiance map, (H, W, 3) float32, finite and >= 0."""

    radiance: np.ndarray
    name: str = "environment"
    device_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        r = np.asarray(self.radiance, np.float32)
        if r.ndim != 3 or r.shape[2] != 3 or r.shape[0] < 2 or r.shape[1] < 2:
            raise ValueError(f"Environment.radiance must be an (H, W, 3) array with H, W >= 2, got {r.shape}")
        if not np.all(np.isfinite(r)):
            raise ValueError(f"Environment {self.name!r} holds NaN or inf radiance")
        if (r < 0).any():
            raise ValueError(f"Environment {self.name!r} holds negative radiance (min {float(r.min())})")
        self.radiance = np.ascontiguousarray(r)

    @property
    def height(self) -> int:
        return self.radiance.shape[0]

    @property
    def width(self) -> int:
        return self.radiance.shape[1]

    def directions(self) -> np.ndarray:
        return equirect_directions(self.height, self.width)

    def solid_angles(self) -> np.ndarray:
        """(H, W) float64 exact solid angle of each texel: (cos θ0 − cos θ1)·2π/W."""
        edges = np.cos(np.pi * np.arange(self.height + 1) / self.height)
        return np.broadcast_to(((edges[:-1] - edges[1:]) * 2 * np.pi / self.width)[:, None],
                               (self.height, self.width)).copy()

    def lookup(self, d) -> np.ndarray:
        """(..., 3) float64 bilinear radiance in unit directions d (..., 3)."""
        row, col = direction_to_equirect(d, self.height, self.width)
        r0 = np.floor(row)
        c0 = np.floor(col)
        fr = row - r0
        fc = col - c0
        r0 = r0.astype(np.int64)
        c0 = c0.astype(np.int64)
        rad = self.radiance.astype(np.float64)
        out = 0.0
        for dr, wr in ((0, 1 - fr), (1, fr)):
            rr = np.clip(r0 + dr, 0, self.height - 1)
            for dc, wc in ((0, 1 - fc), (1, fc)):
                cc = np.mod(c0 + dc, self.width)
                out = out + (wr * wc)[..., None] * rad[rr, cc]
        return out

    def power(self) -> np.ndarray:
        """∫L dω (RGB), exact for the texel-constant map."""
        return np.einsum("hw,hwc->c", self.solid_angles(), self.radiance.astype(np.float64))
