"""Mesh assembly shared by the procedural tile generators.

Generators emit triangles as corner coordinates (a `TriangleSoup`); `weld` turns them into shared
vertices, and `check_faces` refuses parameters whose triangles would be slivers, which is how every
generated tile meets what `SmallScale` checks for without a `TileWarning`. `triangulate_ground`
meshes flat ground around holes (pyramid bases, rod feet) with identical vertices on opposite tile
edges, so the tile repeats without cracks.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .smallscale import SmallScale, cross_rows, default_face_tangents, row_norms

__all__ = ["TriangleSoup", "weld", "check_faces", "lift", "triangulate_ground", "following"]


class TriangleSoup:
    """Triangles collected as corner coordinates, each group with a material id, a colour and optionally
    a tangent direction (the facet frame's x axis of anisotropic BRDFs, `SmallScale.face_tangents`)."""

    def __init__(self):
        self.tris, self.mats, self.cols, self.tangents = [], [], [], []

    def add(self, tris, material, color, tangents=None):
        """Append triangles (anything reshaping to (T, 3, 3)) with one material id and colour. `tangents`: one
        direction (3,) or one per triangle (T, 3), in the triangles' planes or not (SmallScale projects
        them); None: the default of `SmallScale.face_tangents`."""
        tris = np.asarray(tris, np.float64).reshape(-1, 3, 3)
        if len(tris):
            self.tris.append(tris)
            self.mats.append(np.full(len(tris), material, np.int32))
            self.cols.append(np.broadcast_to(color, (len(tris), 3)))
            if tangents is None:  # the default rule, on the triangles' own normals
                normals = cross_rows(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
                tangents = default_face_tangents(normals / row_norms(normals)[:, None])
            self.tangents.append(np.broadcast_to(np.asarray(tangents, np.float64), (len(tris), 3)))

    def build(self, fn, period, name, params) -> SmallScale:
        """The welded tile; `fn` and `params` name the call in the error for sliver triangles."""
        tris = np.concatenate(self.tris)
        vertices, faces = weld(tris.reshape(-1, 3))
        check_faces(fn, vertices, faces, params)
        # Every generated tile occupies [0, Px] × [0, Py], whether or not its geometry reaches
        # the boundary (rods without ground do not).
        return SmallScale(vertices, faces, material_ids=np.concatenate(self.mats),
                          colors=np.concatenate(self.cols), period=period, name=name, origin=(0.0, 0.0),
                          face_tangents=np.concatenate(self.tangents))


def weld(points: np.ndarray):
    """Merge coincident corners into shared vertices: (V, 3) vertices and (F, 3) faces.

    Corners meant to coincide are computed from the same numbers, so they are exactly equal; a
    KD-tree pass also merges any within 1e-8 of the tile size, which keeps the survivors far enough
    apart that SmallScale's own 1e-9 duplicate merge (and its TileWarning) never triggers.
    """
    # Exact duplicates: sort the rows and keep the first of each run (lexsort is several times
    # faster than np.unique(axis=0) on float rows, and treats -0.0 and 0.0 as equal).
    order = np.lexsort(points.T[::-1])
    srt = points[order]
    first = np.r_[True, (np.diff(srt, axis=0) != 0).any(axis=1)]
    uniq = srt[first]
    inverse = np.empty(len(points), np.int64)
    inverse[order] = np.cumsum(first) - 1
    scale = max(float(np.ptp(points, axis=0).max()), 1e-30)
    pairs = cKDTree(uniq).query_pairs(1e-8 * scale, output_type="ndarray")
    if len(pairs):
        n = len(uniq)
        labels = _components(n, pairs)
        keep = np.zeros(labels.max() + 1, np.int64)
        keep[labels[::-1]] = np.arange(n)[::-1]  # lowest member index of each group
        uniq, inverse = uniq[keep], labels[inverse]
    return uniq, inverse.reshape(-1, 3)


def _components(n, pairs) -> np.ndarray:
    """Connected-component labels of n nodes joined by (P, 2) `pairs`, numbered in the order of each component's
    lowest node (as scipy's connected_components). A few pairs (the usual near-coincident corners) are joined
    in Python with a union-find: a sparse graph costs far more than its search on a few dozen vertices."""
    if len(pairs) > 256:
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        return connected_components(graph, directed=False)[1]
    parent = {}

    def root(i):
        while parent.get(i, i) != i:
            i = parent[i]
        return i

    for i, j in pairs.tolist():
        ri, rj = root(i), root(j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)  # a component's root is its lowest node
    lowest = np.arange(n)
    for i in parent:
        lowest[i] = root(i)
    return np.unique(lowest, return_inverse=True)[1].reshape(-1)


def check_faces(fn, v, f, params):
    """Refuse parameters that need sliver triangles, which SmallScale would drop with a warning.

    Same criterion as SmallScale (twice the area over the longest edge squared), with a 2x margin
    so coordinate rounding in file round trips cannot push a face over the line.
    """
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area2 = row_norms(cross_rows(b - a, c - a))
    longest2 = np.max([((b - a) ** 2).sum(1), ((c - b) ** 2).sum(1), ((a - c) ** 2).sum(1)], axis=0)
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    bad = repeated | ~(area2 > 2e-7 * longest2)
    if bad.any():
        raise ValueError(
            f"{fn}: {params} would need {int(bad.sum())} sliver triangle(s) (thinner than 2e-7 of "
            "their length); bring the parameters' proportions closer together"
        )


def lift(xy, z=0.0) -> np.ndarray:
    """(T, 3, 2) xy triangles lifted to (T, 3, 3) at height z."""
    xy = np.asarray(xy, np.float64).reshape(-1, 3, 2)
    return np.concatenate([xy, np.full(xy.shape[:2] + (1,), z)], axis=2)


# ================================================================================================
# Ground triangulation: square cells with star-shaped holes (pyramid bases, rod feet)
# ================================================================================================


def triangulate_ground(n: int, cell: float, holes: dict) -> np.ndarray:
    """Triangulate an n×n grid of square cells minus one hole per cell: (T, 3, 2) CCW triangles.

    Cell (i, j) is [i·cell, (i+1)·cell] × [j·cell, (j+1)·cell]. holes[(i, j)] is a (K, 2) polygon,
    counter-clockwise, star-shaped about the cell centre (convex and containing it is enough); its
    vertices may lie on the cell border (a pyramid base touching the tile edge) but not outside.

    The ray from the cell centre through each hole vertex p_k meets the border at q_k; between
    consecutive rays the ground is the convex polygon p_k, q_k, (border points), q_{k+1}, p_{k+1},
    fanned from its vertex mean. Every q lies on a grid line shared with the neighbouring cell,
    and line n is line 0 (periodic), so each border point appears in both cells that touch it and
    on both opposite tile edges: no T-junctions inside, identical vertices on opposite edges.
    """
    edges = np.arange(n + 1) * cell  # every corner coordinate comes from this one array
    tol = 1e-7 * cell
    vlines = [[] for _ in range(n)]  # y values of border points on the line x = edges[i]
    hlines = [[] for _ in range(n)]  # x values of border points on the line y = edges[j]
    rays = {}
    for (i, j), p in holes.items():
        x0, x1, y0, y1 = edges[i], edges[i + 1], edges[j], edges[j + 1]
        c = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
        d = p - c
        ax, ay = np.abs(d[:, 0]), np.abs(d[:, 1])
        q = c + (0.5 * cell / np.maximum(ax, ay))[:, None] * d
        # Put the coordinate the ray leaves through exactly on the border (both at a corner).
        on_x, on_y = ax >= ay * (1 - 1e-12), ay >= ax * (1 - 1e-12)
        q[:, 0] = np.where(on_x, np.where(d[:, 0] > 0, x1, x0), q[:, 0])
        q[:, 1] = np.where(on_y, np.where(d[:, 1] > 0, y1, y0), q[:, 1])
        touching = (p[:, 0] == x0) | (p[:, 0] == x1) | (p[:, 1] == y0) | (p[:, 1] == y1)
        q[touching] = p[touching]
        for qx, qy in q:
            if qx == x0 or qx == x1:
                vlines[(i + (qx == x1)) % n].append(qy)
            if qy == y0 or qy == y1:
                hlines[(j + (qy == y1)) % n].append(qx)
        rays[(i, j)] = (p, q)

    vreps = [_merge_line(vals, edges, tol) for vals in vlines]
    hreps = [_merge_line(vals, edges, tol) for vals in hlines]
    out = []
    for i in range(n):
        for j in range(n):
            x0, x1, y0, y1 = edges[i], edges[i + 1], edges[j], edges[j + 1]
            # The cell border counter-clockwise from its lower-left corner, with every border point.
            loop = (
                [(x0, y0)]
                + [(x, y0) for x in _between(hreps[j], x0, x1)]
                + [(x1, y0)]
                + [(x1, y) for y in _between(vreps[(i + 1) % n], y0, y1)]
                + [(x1, y1)]
                + [(x, y1) for x in _between(hreps[(j + 1) % n], x0, x1)[::-1]]
                + [(x0, y1)]
                + [(x0, y) for y in _between(vreps[i], y0, y1)[::-1]]
            )
            loop = np.array(loop)
            if (i, j) not in rays:
                out.append(_fan(loop) if len(loop) > 4 else loop[[0, 1, 2, 0, 2, 3]].reshape(2, 3, 2))
                continue
            p, q = rays[(i, j)]
            idx = np.argmin(((loop[None] - q[:, None]) ** 2).sum(-1), axis=1)
            k_count, m = len(p), len(loop)
            for k in range(k_count):
                k1 = (k + 1) % k_count
                steps = (idx[k1] - idx[k]) % m
                chain = loop[(idx[k] + np.arange(steps + 1)) % m]
                piece = _dedupe(np.concatenate([p[k : k + 1], chain, p[k1 : k1 + 1]]), tol)
                if len(piece) >= 3 and _shoelace(piece) > 1e-12 * cell * cell:
                    out.append(piece[None] if len(piece) == 3 else _fan(piece))
    return np.concatenate(out) if out else np.zeros((0, 3, 2))


def _merge_line(values, anchors, tol) -> np.ndarray:
    """Sorted representatives of points on one grid line: values within tol of a cell corner become
    that corner, and values within tol of each other become one point (rounding in the ray
    intersections of two neighbouring cells must not leave two vertices a hair apart)."""
    reps = []
    for v in sorted(values):
        near = anchors[np.abs(anchors - v) <= tol]
        if len(near):
            continue  # corners are always in the loop
        if reps and v - reps[-1] <= tol:
            continue
        reps.append(v)
    return np.array(reps)


def _between(values, lo, hi) -> list:
    return [v for v in values if lo < v < hi]


def following(a) -> np.ndarray:
    """Each row's successor around a closed polygon (np.roll(a, -1, axis=0), which costs several times this on
    the few rows of a polygon)."""
    return np.concatenate([a[1:], a[:1]])


def _dedupe(poly, tol) -> np.ndarray:
    """Drop consecutive (cyclically) repeated points of a polygon."""
    keep = row_norms(poly - following(poly)) > tol
    return poly[keep] if keep.any() else poly[:1]


def _shoelace(poly) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, following(y)) - np.dot(following(x), y))


def _fan(poly) -> np.ndarray:
    """Fan a convex CCW polygon from its vertex mean (robust to collinear runs of border points)."""
    g = poly.mean(axis=0)
    nxt = following(poly)
    return np.stack([np.broadcast_to(g, poly.shape), poly, nxt], axis=1)
