"""Data passed between stages: plain dataclasses of numpy arrays, validated on construction.

Backends may keep device copies of these arrays (in `device_cache`) so that one bake's stages do
not re-upload them; the numpy arrays are always the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Facets", "Visibility", "run_ends"]


@dataclass(eq=False)
class Facets:
    """Ns area-weighted facets of a tile (Wu §3.2), float32 as the kernels use them.

    position (Ns,3), normal (Ns,3) unit shading normal, face (Ns,) source triangle,
    area (Ns,) ΔA_s, material (Ns,) id, color (Ns,3) RGB weight; `seed` made them.
    """

    position: np.ndarray
    normal: np.ndarray
    face: np.ndarray
    area: np.ndarray
    material: np.ndarray
    color: np.ndarray
    seed: int = 0
    device_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        n = len(self.position)
        for name, shape in (("position", (n, 3)), ("normal", (n, 3)), ("face", (n,)), ("area", (n,)),
                            ("material", (n,)), ("color", (n, 3))):
            if getattr(self, name).shape != shape:
                raise ValueError(f"Facets.{name} must have shape {shape}, got {getattr(self, name).shape}")
        if n == 0:
            raise ValueError("Facets needs at least one facet")

    def __len__(self):
        return len(self.position)

    def as_dict(self) -> dict:
        """The arrays as float64, in the form `warp_biscale.reference` takes."""
        return {
            "position": self.position.astype(np.float64),
            "normal": self.normal.astype(np.float64),
            "face": self.face,
            "area": self.area.astype(np.float64),
            "material": self.material,
            "color": self.color.astype(np.float64),
        }


@dataclass(eq=False)
class Visibility:
    """V_s(ω_k) for D directions and Ns facets, one bit each.

    bits (D, ceil(Ns/32)) uint32: bit (s mod 32) of word s // 32 in row k is V_s(ω_k). Rows are
    per direction so that a kernel tracing one direction for many neighbouring facets writes whole
    words, and the ground truth ANDs the rows of ωi and ωo a word at a time.
    """

    directions: np.ndarray
    bits: np.ndarray
    n_facets: int
    device_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        words = (self.n_facets + 31) // 32
        if self.bits.shape != (len(self.directions), words) or self.bits.dtype != np.uint32:
            raise ValueError(
                f"Visibility.bits must be uint32 of shape ({len(self.directions)}, {words}), "
                f"got {self.bits.dtype} {self.bits.shape}"
            )

    def as_bool(self) -> np.ndarray:
        """(D, Ns) bool."""
        unpacked = np.unpackbits(self.bits.view(np.uint8), axis=1, bitorder="little")
        return unpacked[:, : self.n_facets].astype(bool)

    @staticmethod
    def pack(vis: np.ndarray) -> np.ndarray:
        """(D, Ns) bool → (D, ceil(Ns/32)) uint32, the layout of `bits`."""
        d, n = vis.shape
        padded = np.zeros((d, (n + 31) // 32 * 32), np.uint8)
        padded[:, :n] = vis
        return np.packbits(padded, axis=1, bitorder="little").view(np.uint32)

    @property
    def nbytes(self) -> int:
        return self.bits.nbytes


def run_ends(normal, weight) -> np.ndarray:
    """(Ns,) int32: for each facet, the index one past the run of consecutive facets that share its
    normal and weight. Facets come ordered by face, and every facet of a flat face has the face's
    normal and weight, so a face's facets form one run; the lobe-moment kernels then count a run's
    visible facets in a 32-facet word with one popcount instead of adding them one by one."""
    normal = np.asarray(normal)
    weight = np.asarray(weight)
    n = len(weight)
    if n == 0:
        return np.zeros(0, np.int32)
    change = np.ones(n, bool)
    change[1:] = (normal[1:] != normal[:-1]).any(axis=1) | (weight[1:] != weight[:-1])
    starts = np.flatnonzero(change)
    ends = np.append(starts[1:], n)
    return np.repeat(ends, ends - starts).astype(np.int32)
