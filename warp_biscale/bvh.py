"""A bounding volume hierarchy built on the host in numpy, for the OpenCL visibility kernel.

Warp brings its own BVH (``wp.Mesh``); OpenCL has none, so ``cl/visibility.cl`` walks this one.

Build
-----
A linear BVH: triangles are sorted once by the 63-bit Morton code of their box centroid, with one
cube-shaped quantisation grid over the centroid bounds (so a thin axis, such as the z of a height
field, spends no bits and never gets split before it matters). Every node is then a contiguous
range of that order, and the tree is built top-down, one level at a time with every node of the
level split in one vectorised pass: a node splits at its first triangle whose code has the node's
highest differing bit set (a spatial median split on the octree grid of the centroids: halves of
the longest quantised axis first), or at half its count when all its codes are equal. Nothing is
moved after the sort, so a level costs O(nodes) numpy work plus one ``searchsorted`` (build
times: bench/README.md, `bench_precompute.py`). Leaves hold at most `LEAF_SIZE` = 4 triangles.
Below level `HALF_BELOW_LEVEL` every node splits at half its count, which bounds the depth by
``HALF_BELOW_LEVEL + log2(F)``, inside the kernel's traversal stack (`STACK_SIZE` = 64).

(A binned surface-area heuristic over cut candidates in Morton order was tried and did not lower
the SAH cost or the kernel's time on height fields, spheres, tori or rods-on-a-plane tiles.)

Layout (what the kernel reads), nodes in breadth-first order, node 0 the root
-------------------------------------------------------------------------------
- ``bounds`` (N, 6) float32: min x, y, z, max x, y, z. Computed in float64 from the float32
  vertices the kernel tests, padded outward by `PAD` = 1e-6 × the scene size (the larger of the
  vertices' largest extent and largest coordinate magnitude) and rounded outward to float32, so
  no float32 rounding in the kernel's slab test drops a triangle lying on a box face (a flat tile
  has zero-thickness boxes; its rays start on their faces).
- ``child`` (N, 2) int32: an inner node holds (left, right) child indices (right = left + 1,
  both > 0); a leaf holds (first, −count): slots first … first + count − 1 of the reordered
  triangle list. ``child[:, 1] < 0`` is the leaf flag.
- ``tri_index`` (F,) int32: the original face index in each slot of the reordered list; each leaf
  covers a contiguous range of it, and every face is in exactly one leaf.

``packed()`` gives the device form, one 32-byte record per node: (N, 8) float32, the six bounds
then the two child words bit-cast. ``triangle_table(vertices, faces)`` gives (F, 9) float32 rows
[a, b − a, c − a] per slot, the edges computed in float32 exactly as Möller–Trumbore would.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Bvh", "build_bvh", "STACK_SIZE", "LEAF_SIZE"]

LEAF_SIZE = 4
STACK_SIZE = 64  # the traversal stack of cl/visibility.cl (BVH_STACK there)
PAD = 1e-6
HALF_BELOW_LEVEL = 40


@dataclass(eq=False)
class Bvh:
    bounds: np.ndarray  # (N, 6) float32
    child: np.ndarray  # (N, 2) int32
    tri_index: np.ndarray  # (F,) int32
    depth: int  # number of levels (a single leaf: 1)
    pad: float  # the absolute outward padding of every box

    @property
    def n_nodes(self) -> int:
        return len(self.bounds)

    @property
    def is_leaf(self) -> np.ndarray:
        return self.child[:, 1] < 0

    def packed(self) -> np.ndarray:
        """(N, 8) float32: bounds, then the two int32 child words bit-cast (32 bytes a node)."""
        out = np.empty((self.n_nodes, 8), np.float32)
        out[:, :6] = self.bounds
        out[:, 6:] = np.ascontiguousarray(self.child, np.int32).view(np.float32)
        return out

    def triangle_table(self, vertices, faces) -> np.ndarray:
        """(F, 9) float32 rows [a, b − a, c − a] in slot order (a, b, c the float32 face vertices)."""
        v = np.asarray(vertices, np.float32)
        f = np.asarray(faces)[self.tri_index]
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        return np.ascontiguousarray(np.concatenate([a, b - a, c - a], axis=1), np.float32)

    def sah_cost(self) -> float:
        """Surface-area-heuristic cost relative to the root (1 per node visit, 1 per triangle test)."""
        lo, hi = self.bounds[:, :3].astype(np.float64), self.bounds[:, 3:].astype(np.float64)
        e = hi - lo
        area = 2 * (e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0])
        leaf = self.is_leaf
        return float((area[~leaf].sum() + (area[leaf] * -self.child[leaf, 1]).sum()) / area[0])


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """21-bit integers → 63-bit with two zero bits between consecutive bits."""
    x = x.astype(np.uint64) & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


def _highest_bit(x: np.ndarray) -> np.ndarray:
    """Index of the highest set bit of non-zero uint64 values (vectorised binary search)."""
    x = x.astype(np.uint64)
    r = np.zeros(len(x), np.int64)
    for s in (32, 16, 8, 4, 2, 1):
        big = (x >> np.uint64(s)) != 0
        r += np.where(big, s, 0)
        x = np.where(big, x >> np.uint64(s), x)
    return r


def build_bvh(vertices, faces, leaf_size: int = LEAF_SIZE) -> Bvh:
    """Build the BVH of a triangle mesh ((V, 3) vertices, (F, 3) faces); see the module notes."""
    if not 1 <= leaf_size <= LEAF_SIZE:
        raise ValueError(f"leaf_size must be in 1..{LEAF_SIZE}, got {leaf_size}")
    v32 = np.asarray(vertices, np.float32).astype(np.float64)  # exactly what the kernel tests
    faces = np.asarray(faces, np.int64)
    n_tri = len(faces)
    if n_tri == 0:
        raise ValueError("build_bvh needs at least one triangle")
    tri = v32[faces]  # (F, 3, 3)
    tmin = tri.min(axis=1)
    tmax = tri.max(axis=1)
    cen = 0.5 * (tmin + tmax)
    c_lo = cen.min(axis=0)
    size = float((cen.max(axis=0) - c_lo).max())
    q = np.zeros_like(cen, dtype=np.int64)
    if size > 0:
        q = np.clip(((cen - c_lo) * ((1 << 21) - 1) / size).astype(np.int64), 0, (1 << 21) - 1)
    code = ((_spread_bits(q[:, 0]) << np.uint64(2)) | (_spread_bits(q[:, 1]) << np.uint64(1))
            | _spread_bits(q[:, 2]))
    order = np.argsort(code, kind="stable")
    code = code[order]
    lo_s = tmin[order]
    hi_s = tmax[order]

    starts = [np.array([0], np.int64)]
    counts = [np.array([n_tri], np.int64)]
    childs = []  # per level: (n, 2) int64
    level_start = [0]
    n_nodes = 1
    cur_start, cur_count = starts[0], counts[0]
    level = 0
    while True:
        child = np.empty((len(cur_start), 2), np.int64)
        inner = cur_count > leaf_size
        child[~inner, 0] = cur_start[~inner]
        child[~inner, 1] = -cur_count[~inner]
        childs.append(child)
        if not inner.any():
            break
        s = cur_start[inner]
        e = s + cur_count[inner]
        m = len(s)
        # Morton split: first slot whose code has the node's highest differing bit set.
        diff = code[s] ^ code[e - 1]
        same = diff == 0
        mid = (s + e) // 2
        if (~same).any():
            b = _highest_bit(diff[~same]).astype(np.uint64)
            target = ((code[s[~same]] >> b) | np.uint64(1)) << b
            mid[~same] = np.searchsorted(code, target)
        split = (s + e) // 2 if level >= HALF_BELOW_LEVEL else mid
        bad = (split <= s) | (split >= e)
        split[bad] = ((s + e) // 2)[bad]

        kids = n_nodes + 2 * np.arange(m)
        child[inner, 0] = kids
        child[inner, 1] = kids + 1
        cur_start = np.stack([s, split], axis=1).reshape(-1)
        cur_count = np.stack([split - s, e - split], axis=1).reshape(-1)
        starts.append(cur_start)
        counts.append(cur_count)
        level_start.append(n_nodes)
        n_nodes += 2 * m
        level += 1

    child = np.concatenate(childs)
    start = np.concatenate(starts)
    depth = len(childs)
    if depth > STACK_SIZE:
        raise RuntimeError(f"BVH depth {depth} exceeds the traversal stack ({STACK_SIZE})")

    # Bounds: leaves over their slot ranges, inner nodes as the union of their children, bottom-up.
    lo = np.empty((n_nodes, 3))
    hi = np.empty((n_nodes, 3))
    leaf = child[:, 1] < 0
    lid = np.flatnonzero(leaf)
    lid = lid[np.argsort(start[lid])]
    lo[lid] = np.minimum.reduceat(lo_s, start[lid], axis=0)
    hi[lid] = np.maximum.reduceat(hi_s, start[lid], axis=0)
    level_start.append(n_nodes)
    for lev in range(depth - 1, -1, -1):
        ids = np.arange(level_start[lev], level_start[lev + 1])
        ids = ids[~leaf[ids]]
        if len(ids):
            lo[ids] = np.minimum(lo[child[ids, 0]], lo[child[ids, 1]])
            hi[ids] = np.maximum(hi[child[ids, 0]], hi[child[ids, 1]])
    scale = max(float((v32.max(axis=0) - v32.min(axis=0)).max()), float(np.abs(v32).max()), 1e-30)
    pad = PAD * scale
    lo64, hi64 = lo - pad, hi + pad
    lo32, hi32 = lo64.astype(np.float32), hi64.astype(np.float32)
    lo32 = np.where(lo32.astype(np.float64) > lo64, np.nextafter(lo32, np.float32(-np.inf)), lo32)
    hi32 = np.where(hi32.astype(np.float64) < hi64, np.nextafter(hi32, np.float32(np.inf)), hi32)
    bounds = np.concatenate([lo32, hi32], axis=1).astype(np.float32)
    return Bvh(bounds=bounds, child=child.astype(np.int32), tri_index=order.astype(np.int32), depth=depth,
               pad=pad)
