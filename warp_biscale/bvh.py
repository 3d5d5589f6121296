"""A bounding volume hierarchy built on the host in numpy, for the OpenCL visibility kernel.

Warp brings its own BVH (``wp.Mesh``); OpenCL has none, so ``cl/visibility.cl`` walks this one.

Build: top-down, level by level (every node of one tree level is split in one vectorised pass, so
the cost is a few numpy passes over all triangles per level, not a Python call per node). Each
node with more than `leaf_size` (≤ 4) triangles is split by a binned surface-area heuristic
(16 bins per axis over the node's centroid bounds, all three axes). The triangles of a node are
kept sorted by centroid along each axis in three permutations, so a bin is a contiguous run and
its bounds are one ``reduceat``; splitting is a stable partition of each permutation. A node whose
centroids all coincide, and every node below level `MEDIAN_BELOW_LEVEL`, is split at its object
median instead, which bounds the depth by ``MEDIAN_BELOW_LEVEL + log2(F)`` (the kernel's
traversal stack holds `STACK_SIZE` entries).

Layout (what the kernel reads), nodes in breadth-first order, node 0 the root:

- ``bounds`` (N, 6) float32: min x, y, z, max x, y, z. Computed in float64 from the float32
  vertices the kernel tests, padded outward by `PAD` × the scene size (largest extent or
  coordinate magnitude) and rounded outward to float32, so no float32 rounding in the kernel's
  slab test can drop a triangle lying on a box face (a flat tile has zero-thickness boxes).
- ``child`` (N, 2) int32: an inner node holds (left, right) child indices (right = left + 1,
  both > 0); a leaf holds (first, -count): triangles ``first … first + count − 1`` of the
  reordered triangle list. ``child[:, 1] < 0`` is the leaf flag.
- ``tri_index`` (F,) int32: the original face index of each slot of the reordered list; every
  leaf covers a contiguous range of it.

``packed()`` gives the device form: one 32-byte record per node, (N, 8) float32 of the six bounds
followed by the two int32 child words (bit-cast); ``triangle_table(vertices, faces)`` the (F, 9)
float32 [a, b − a, c − a] per reordered slot (the edge vectors computed in float32, exactly as
the kernels' Möller–Trumbore test would compute them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Bvh", "build_bvh", "STACK_SIZE"]

LEAF_SIZE = 4
BINS = 16
PAD = 1e-6
MEDIAN_BELOW_LEVEL = 32
SAH_MIN_COUNT = 32  # smaller nodes split at the object median of their longest axis
STACK_SIZE = 64  # must match BVH_STACK in cl/visibility.cl


@dataclass(eq=False)
class Bvh:
    bounds: np.ndarray  # (N, 6) float32
    child: np.ndarray  # (N, 2) int32
    tri_index: np.ndarray  # (F,) int32
    depth: int  # number of levels (a lone leaf: 1)
    pad: float  # the absolute outward padding applied to every box

    @property
    def n_nodes(self) -> int:
        return len(self.bounds)

    @property
    def is_leaf(self) -> np.ndarray:
        return self.child[:, 1] < 0

    def packed(self) -> np.ndarray:
        """(N, 8) float32: bounds then the two child words, bit-cast (one 32-byte record per node)."""
        out = np.empty((self.n_nodes, 8), np.float32)
        out[:, :6] = self.bounds
        out[:, 6:] = self.child.astype(np.int32).view(np.float32)
        return out

    def triangle_table(self, vertices, faces) -> np.ndarray:
        """(F, 9) float32 rows [a, b − a, c − a] in leaf order, a b c the float32 vertices of a face."""
        v = np.asarray(vertices, np.float32)
        f = np.asarray(faces)[self.tri_index]
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        return np.ascontiguousarray(np.concatenate([a, b - a, c - a], axis=1), np.float32)


def _stable_partition(perm, pos, t, go_right, sid, first, seg_start, n_left):
    """perm with the items at positions pos (= t = perm[pos], grouped by segment sid, segment j
    occupying pos[first[j]:...] and perm[seg_start[j]:...]) reordered so that, within each segment,
    items with go_right False come first, both groups keeping their order."""
    left = ~go_right
    cl = np.cumsum(left, dtype=np.int64)
    pl = cl[first] - left[first]  # lefts before each segment
    k = np.arange(len(pos), dtype=np.int64)
    seg_pl = pl[sid]
    n_l_incl = cl - seg_pl  # lefts in the segment up to and including this item
    n_r_incl = (k - first[sid] + 1) - n_l_incl
    new = seg_start[sid] + np.where(go_right, n_left[sid] + n_r_incl - 1, n_l_incl - 1)
    out = perm.copy()
    out[new] = t
    return out


def _area(lo, hi):
    e = np.maximum(hi - lo, 0.0)
    return 2.0 * (e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0])


def build_bvh(vertices, faces, leaf_size: int = LEAF_SIZE) -> Bvh:
    """Build the BVH of a triangle mesh ((V, 3) vertices, (F, 3) faces); see the module notes."""
    if not 1 <= leaf_size <= LEAF_SIZE:
        raise ValueError(f"leaf_size must be in 1..{LEAF_SIZE}, got {leaf_size}")
    v32 = np.asarray(vertices, np.float32).astype(np.float64)  # what the kernel tests
    faces = np.asarray(faces, np.int64)
    n_tri = len(faces)
    if n_tri == 0:
        raise ValueError("build_bvh needs at least one triangle")
    tri = v32[faces]  # (F, 3, 3)
    tmin = tri.min(axis=1)
    tmax = tri.max(axis=1)
    cen = 0.5 * (tmin + tmax)

    # Three permutations, each sorted by centroid along one axis; every active node is the same
    # contiguous range in all three.
    perms = [np.argsort(cen[:, a], kind="stable") for a in range(3)]

    # Node records, appended level by level (breadth-first).
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
        s_start = cur_start[inner]
        s_count = cur_count[inner]
        m = len(s_start)
        first = np.r_[0, np.cumsum(s_count)[:-1]]  # offset of each segment in pos
        last = first + s_count - 1
        n_items = int(s_count.sum())
        sid = np.repeat(np.arange(m), s_count)
        pos = np.arange(n_items, dtype=np.int64) + np.repeat(s_start - first, s_count)
        t_ax = [perms[a][pos] for a in range(3)]
        c_ax = [cen[t_ax[a], a] for a in range(3)]
        ext = np.stack([c_ax[a][last] - c_ax[a][first] for a in range(3)], axis=1)

        go_right = np.zeros(n_tri, bool)  # by triangle id, for the nodes of this level
        split_axis = np.argmax(ext, axis=1)  # median split along the longest centroid extent
        use_median = np.ones(m, bool)
        sah = (s_count > SAH_MIN_COUNT) & (level < MEDIAN_BELOW_LEVEL) & (ext.max(axis=1) > 0)
        if sah.any():
            nodes = np.flatnonzero(sah)
            ms = len(nodes)
            items = np.flatnonzero(sah[sid]) if ms < m else slice(None)
            rid = (np.cumsum(sah) - 1)[sid[items]]
            cnt_s = s_count[nodes]
            first_s = np.r_[0, np.cumsum(cnt_s)[:-1]]
            best_cost = np.full(ms, np.inf)
            best_axis = np.zeros(ms, np.int64)
            best_bin = np.zeros(ms, np.int64)
            bins_of = []
            for a in range(3):
                t = t_ax[a][items]
                c = c_ax[a][items]
                e = ext[nodes, a]
                cmin = c[first_s]
                with np.errstate(divide="ignore"):
                    scale = np.where(e > 0, BINS / np.where(e > 0, e, 1.0), 0.0)
                b = np.minimum(((c - cmin[rid]) * scale[rid]).astype(np.int64), BINS - 1)
                bins_of.append(b)
                key = rid * BINS + b  # non-decreasing along the items (sorted by c within a node)
                brk = np.r_[0, np.flatnonzero(key[1:] != key[:-1]) + 1]
                gkey = key[brk]
                lo = np.full((ms * BINS, 3), np.inf)
                hi = np.full((ms * BINS, 3), -np.inf)
                cnt = np.zeros(ms * BINS, np.int64)
                lo[gkey] = np.minimum.reduceat(tmin[t], brk, axis=0)
                hi[gkey] = np.maximum.reduceat(tmax[t], brk, axis=0)
                cnt[gkey] = np.diff(np.r_[brk, len(key)])
                lo, hi, cnt = lo.reshape(ms, BINS, 3), hi.reshape(ms, BINS, 3), cnt.reshape(ms, BINS)
                # Split j: left = bins 0..j, right = bins j+1..BINS-1, j = 0..BINS-2.
                l_n = np.cumsum(cnt, axis=1)[:, :-1]
                r_n = cnt_s[:, None] - l_n
                l_a = _area(np.minimum.accumulate(lo, axis=1)[:, :-1], np.maximum.accumulate(hi, axis=1)[:, :-1])
                r_a = _area(np.minimum.accumulate(lo[:, ::-1], axis=1)[:, -2::-1],
                            np.maximum.accumulate(hi[:, ::-1], axis=1)[:, -2::-1])
                with np.errstate(invalid="ignore"):
                    cost = np.where((l_n > 0) & (r_n > 0), l_a * l_n + r_a * r_n, np.inf)
                j = np.argmin(cost, axis=1)
                cj = cost[np.arange(ms), j]
                better = cj < best_cost
                best_cost[better] = cj[better]
                best_axis[better] = a
                best_bin[better] = j[better]
            ok = np.isfinite(best_cost)
            use_median[nodes[ok]] = False
            split_axis[nodes] = best_axis
            item_ok = ok[rid]
            for a in range(3):
                sel = item_ok & (best_axis[rid] == a)
                if sel.any():
                    go_right[t_ax[a][items][sel]] = bins_of[a][sel] > best_bin[rid[sel]]
        if use_median.any():
            rank = np.arange(n_items) - first[sid]
            med = use_median[sid]
            for a in range(3):
                sel = med & (split_axis[sid] == a)
                if sel.any():
                    go_right[t_ax[a][sel]] = rank[sel] >= (s_count // 2)[sid[sel]]
        gr0 = go_right[t_ax[0]]
        n_right = np.bincount(sid, weights=gr0, minlength=m).astype(np.int64)
        n_left = s_count - n_right
        assert (n_left > 0).all() and (n_right > 0).all()
        perms[0] = _stable_partition(perms[0], pos, t_ax[0], gr0, sid, first, s_start, n_left)
        for a in (1, 2):
            perms[a] = _stable_partition(perms[a], pos, t_ax[a], go_right[t_ax[a]], sid, first, s_start, n_left)

        # Children: left = n_nodes + 2i, right = left + 1, for the i-th inner node of this level.
        kids = n_nodes + 2 * np.arange(m)
        child[inner, 0] = kids
        child[inner, 1] = kids + 1
        cur_start = np.stack([s_start, s_start + n_left], axis=1).reshape(-1)
        cur_count = np.stack([n_left, n_right], axis=1).reshape(-1)
        starts.append(cur_start)
        counts.append(cur_count)
        level_start.append(n_nodes)
        n_nodes += 2 * m
        level += 1

    child = np.concatenate(childs).astype(np.int64)
    start = np.concatenate(starts)
    count = np.concatenate(counts)
    order = perms[0]
    depth = len(childs)

    # Bounds: leaves from their triangles (reduceat over leaf ranges), inner nodes bottom-up.
    lo = np.empty((n_nodes, 3))
    hi = np.empty((n_nodes, 3))
    leaf = child[:, 1] < 0
    lid = np.flatnonzero(leaf)
    lid = lid[np.argsort(start[lid])]
    lo[lid] = np.minimum.reduceat(tmin[order], start[lid], axis=0)
    hi[lid] = np.maximum.reduceat(tmax[order], start[lid], axis=0)
    level_start.append(n_nodes)
    for lev in range(depth - 1, -1, -1):
        ids = np.arange(level_start[lev], level_start[lev + 1])
        ids = ids[~leaf[ids]]
        if len(ids):
            lo[ids] = np.minimum(lo[child[ids, 0]], lo[child[ids, 1]])
            hi[ids] = np.maximum(hi[child[ids, 0]], hi[child[ids, 1]])
    scale = max(float(np.max(v32.max(axis=0) - v32.min(axis=0))), float(np.abs(v32).max()), 1e-30)
    pad = PAD * scale
    lo32 = (lo - pad).astype(np.float32)
    hi32 = (hi + pad).astype(np.float32)
    lo32 = np.where(lo32.astype(np.float64) > lo - pad, np.nextafter(lo32, np.float32(-np.inf)), lo32)
    hi32 = np.where(hi32.astype(np.float64) < hi + pad, np.nextafter(hi32, np.float32(np.inf)), hi32)
    bounds = np.concatenate([lo32, hi32], axis=1).astype(np.float32)
    if depth > STACK_SIZE:
        raise RuntimeError(f"BVH depth {depth} exceeds the traversal stack ({STACK_SIZE})")
    return Bvh(bounds=bounds, child=child.astype(np.int32), tri_index=order.astype(np.int32), depth=depth, pad=pad)
