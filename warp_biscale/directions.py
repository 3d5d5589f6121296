"""The K×K direction grid of docs/design.md §4: cell centres of the unit square → Shirley–Chiu concentric
disk → hemisphere by the equal-area lift z = 1 − r², so every direction owns 2π/K² sr.

Direction index k = row·K + col for the cell centre (u, v) = ((col + ½)/K, (row + ½)/K).
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["grid", "frozen_grid", "all_pairs", "unordered_pairs", "unordered_index", "bilinear_corners",
           "square_to_hemisphere", "hemisphere_to_square", "check_directions", "cell_cosine_integrals"]


def square_to_hemisphere(uv: np.ndarray) -> np.ndarray:
    """(N, 2) points of [0,1]² → (N, 3) unit vectors, z ≥ 0 (float64)."""
    uv = np.asarray(uv, np.float64)
    a = 2.0 * uv[..., 0] - 1.0
    b = 2.0 * uv[..., 1] - 1.0
    big_a = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(big_a, a, b)
        phi = np.where(big_a, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    # r is signed: a negative r with phi covers the opposite half of the disk.
    x, y = r * np.cos(phi), r * np.sin(phi)
    r2 = x * x + y * y
    s = np.sqrt(np.maximum(2.0 - r2, 0.0))  # lift (x, y) by sqrt(1 - z²)/r = sqrt(2 - r²)
    return np.stack([x * s, y * s, 1.0 - r2], axis=-1)


def hemisphere_to_square(w: np.ndarray) -> np.ndarray:
    """Inverse of `square_to_hemisphere` for unit vectors with z ≥ 0 (z is clamped to [0, 1])."""
    w = np.asarray(w, np.float64)
    z = np.clip(w[..., 2], 0.0, 1.0)
    r = np.sqrt(1.0 - z)
    phi = np.arctan2(w[..., 1], w[..., 0])  # (-π, π]
    phi = np.where(phi < -np.pi / 4, phi + 2 * np.pi, phi)  # [-π/4, 7π/4)
    # Four wedges of the concentric map.
    a = np.empty_like(r)
    b = np.empty_like(r)
    m0 = phi < np.pi / 4
    m1 = (phi >= np.pi / 4) & (phi < 3 * np.pi / 4)
    m2 = (phi >= 3 * np.pi / 4) & (phi < 5 * np.pi / 4)
    m3 = phi >= 5 * np.pi / 4
    a[m0] = r[m0]
    b[m0] = phi[m0] * a[m0] / (np.pi / 4)
    b[m1] = r[m1]
    a[m1] = -(phi[m1] - np.pi / 2) * b[m1] / (np.pi / 4)
    a[m2] = -r[m2]
    b[m2] = (phi[m2] - np.pi) * a[m2] / (np.pi / 4)
    b[m3] = -r[m3]
    a[m3] = -(phi[m3] - 3 * np.pi / 2) * b[m3] / (np.pi / 4)
    return np.stack([(a + 1.0) / 2.0, (b + 1.0) / 2.0], axis=-1)


def grid(k: int = 12) -> np.ndarray:
    """(K², 3) float64 directions of the K×K grid, index row·K + col."""
    k = int(k)
    if k < 1:
        raise ValueError(f"directions must be a grid size K >= 1, got {k}")
    c = (np.arange(k) + 0.5) / k
    u, v = np.meshgrid(c, c)  # u varies along columns, v along rows
    return square_to_hemisphere(np.stack([u.ravel(), v.ravel()], axis=-1))


def _frozen(*arrays):
    out = tuple(np.array(a) for a in arrays)  # owned copies
    for a in out:
        a.flags.writeable = False
    return out


@functools.lru_cache(maxsize=8)
def frozen_grid(k: int = 12) -> np.ndarray:
    """`grid(k)`, made once per K and read-only (the bake's; a backend then knows it again without
    hashing it, `backend.UploadCache`; and a bake does not build it again)."""
    return _frozen(grid(k))[0]


@functools.lru_cache(maxsize=8)
def all_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(pair_i, pair_o): every (i, o) of n directions, ωi-major (pair p = i·n + o), int32, read-only
    (made once per n: a backend then knows them again without hashing them, `backend.UploadCache`).

    The layout of a K²×K² table flattened row by row: table[i, o] is pair i·n + o.
    """
    i, o = np.meshgrid(np.arange(n, dtype=np.int32), np.arange(n, dtype=np.int32), indexing="ij")
    return _frozen(i.ravel(), o.ravel())


@functools.lru_cache(maxsize=8)
def unordered_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(pair_i, pair_o): the unordered pairs i ≤ o of n directions (np.triu_indices order), int32,
    read-only, made once per n."""
    i, o = np.triu_indices(n)
    return _frozen(i.astype(np.int32), o.astype(np.int32))


def unordered_index(i, o, n: int):
    """Index of the direction pair (i, o), either order, among `unordered_pairs(n)`."""
    lo, hi = np.minimum(i, o), np.maximum(i, o)
    return lo * n - lo * (lo - 1) // 2 + (hi - lo)


def bilinear_corners(w, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation on the K×K grid in the square domain: (N, 4) grid indices, (N, 4) weights.

    Directions outside the outermost cell centres are clamped to the edge cells.
    """
    uv = hemisphere_to_square(w)
    x = np.clip(uv * k - 0.5, 0.0, k - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), k - 1)
    x1 = np.minimum(x0 + 1, k - 1)
    t = x - x0
    cols = [x0[:, 0], x1[:, 0], x0[:, 0], x1[:, 0]]
    rows = [x0[:, 1], x0[:, 1], x1[:, 1], x1[:, 1]]
    wts = [(1 - t[:, 0]) * (1 - t[:, 1]), t[:, 0] * (1 - t[:, 1]), (1 - t[:, 0]) * t[:, 1], t[:, 0] * t[:, 1]]
    return np.stack([r * k + c for r, c in zip(rows, cols)], 1), np.stack(wts, 1)


def check_directions(name: str, w) -> np.ndarray:
    """Validate an (N, 3) array of directions: finite, non-zero; returns unit float64 vectors."""
    w = np.asarray(w, np.float64)
    if w.ndim == 1 and w.shape == (3,):
        w = w[None]
    if w.ndim != 2 or w.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {w.shape}")
    if not np.all(np.isfinite(w)):
        row = int(np.argwhere(~np.isfinite(w))[0][0])
        raise ValueError(f"{name} contains NaN or inf (row {row})")
    n = np.linalg.norm(w, axis=1)
    if (n < 1e-12).any():
        raise ValueError(f"{name} has a zero vector at row {int(np.argmin(n))}")
    return w / n[:, None]


def cell_cosine_integrals(k: int = 12, sub: int = 4096) -> np.ndarray:
    """(K²,) ∫ cos θ dω over each grid cell, in index order row·K + col (they sum to π).

    The concentric map has a constant Jacobian (disk area π per unit square) and the lift doubles
    it (hemisphere 2π), so with a = 2u − 1, b = 2v − 1 (r² = max(a², b²) on the concentric map)
    ∫_cell cos θ dω = (π/2) ∫∫_cell (1 − max(a², b²)) da db. The inner integral over b is done in
    closed form, the outer one by a `sub`-point midpoint rule per cell (error ~1e-9 relative).
    """
    k = int(k)
    edges = np.linspace(-1.0, 1.0, k + 1)
    out = np.empty((k, k))
    for row in range(k):
        b0, b1 = edges[row], edges[row + 1]
        for col in range(k):
            a = edges[col] + (np.arange(sub) + 0.5) * (2.0 / k / sub)
            abs_a = np.abs(a)
            lo, hi = np.maximum(b0, -abs_a), np.minimum(b1, abs_a)
            inside = np.maximum(hi - lo, 0.0)  # measure of b with |b| <= |a|: there max = a²
            cubes = np.where(hi > lo, (hi**3 - lo**3) / 3.0, 0.0)
            max_sq = a * a * inside + (b1**3 - b0**3) / 3.0 - cubes
            out[row, col] = ((b1 - b0) - max_sq).mean() * (2.0 / k)
    return out.ravel() * (np.pi / 2.0)


def cube_bin(n, resolution: int) -> np.ndarray:
    """(N,) int cube-map bin of unit normals: face·R² + row·R + col (docs/design.md §4).

    Faces 0..5 are +x, −x, +y, −y, +z, −z, chosen by the largest |component| (ties go to the
    earlier axis); on face ±x (u, v) = (y, z)/|x|, on ±y (x, z)/|y|, on ±z (x, y)/|z|, and
    col = ⌊(u + 1)/2·R⌋, row = ⌊(v + 1)/2·R⌋, clamped to R − 1.
    """
    n = np.asarray(n, np.float64)
    a = np.abs(n)
    on_x = (a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2])
    on_y = ~on_x & (a[:, 1] >= a[:, 2])
    on_z = ~on_x & ~on_y
    face = np.where(on_x, np.where(n[:, 0] >= 0, 0, 1), np.where(on_y, np.where(n[:, 1] >= 0, 2, 3),
                                                                 np.where(n[:, 2] >= 0, 4, 5)))
    major = np.where(on_x, a[:, 0], np.where(on_y, a[:, 1], a[:, 2]))
    major = np.where(major > 0, major, 1.0)
    u = np.where(on_x, n[:, 1], n[:, 0]) / major
    v = np.where(on_z, n[:, 1], n[:, 2]) / major
    col = np.clip(np.floor((u + 1.0) * 0.5 * resolution), 0, resolution - 1).astype(np.int64)
    row = np.clip(np.floor((v + 1.0) * 0.5 * resolution), 0, resolution - 1).astype(np.int64)
    return face * resolution * resolution + row * resolution + col
