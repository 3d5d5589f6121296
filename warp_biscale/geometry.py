"""Procedural small-scale tiles (Wu et al. 2011 §4.2): pyramids, grooves, rods, woven threads, height fields.

Every generator returns a `SmallScale`: one period of a surface tiled infinitely in x and y, z up,
occupying x in [0, Px], y in [0, Py]. Triangles are wound counter-clockwise seen from the open side
(from above for height-field-like tiles, from outside for closed tubes), so the right-hand face
normal points away from the material.

Lengths are in arbitrary tile units: the effective BRDF of a tile does not change when the whole tile
is scaled, so only ratios (height : base, depth : width, radius : spacing, ...) matter. Angles are in
radians. Material ids index the list of small-scale BRDFs given to the pipeline; colours are RGB
weights (Wu §3.7).

Construction guarantees what `SmallScale` checks for: no duplicate vertices, no degenerate
triangles, and opposite tile edges carrying the same boundary vertices, so no `TileWarning` is
emitted for valid parameters. Parameters that would need sliver triangles (aspect ratio below 1e-7,
e.g. a pyramid 10^5 times taller than its base edge) raise a `ValueError` instead.
"""

from __future__ import annotations

import math
import os
from numbers import Integral, Real

import numpy as np
from PIL import Image
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .smallscale import SmallScale

__all__ = ["flat", "pyramid", "grooves", "rods", "woven", "heightfield", "heightfield_from_image"]

_WHITE = (1.0, 1.0, 1.0)

# ================================================================================================
# Parameter validation
# ================================================================================================


def _real(fn, name, value, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
    """A finite real in the given range, or a ValueError naming the parameter and its value."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{fn}: {name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{fn}: {name} must be finite, got {value!r}")
    bad_lo = lo is not None and (v < lo or (lo_open and v == lo))
    bad_hi = hi is not None and (v > hi or (hi_open and v == hi))
    if bad_lo or bad_hi:
        left = "-inf" if lo is None else f"{lo:g}"
        right = "inf" if hi is None else f"{hi:g}"
        interval = (
            f"{'(' if lo_open or lo is None else '['}{left}, {right}{')' if hi_open or hi is None else ']'}"
        )
        raise ValueError(f"{fn}: {name} must be in {interval}, got {value!r}")
    return v


def _int(fn, name, value, lo=None, hi=None) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f"{fn}: {name} must be an integer, got {value!r}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError(f"{fn}: {name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


def _material(fn, name, value, default=None) -> int:
    if value is None and default is not None:
        return default
    if isinstance(value, bool) or not isinstance(value, Integral) or int(value) < 0:
        raise ValueError(f"{fn}: {name} must be a material id (an integer >= 0), got {value!r}")
    return int(value)


def _color(fn, name, value, default=None) -> np.ndarray:
    if value is None and default is not None:
        return default
    try:
        c = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        c = None
    if c is None or c.shape != (3,) or not np.all(np.isfinite(c)) or (c < 0).any():
        raise ValueError(f"{fn}: {name} must be three finite RGB weights >= 0, got {value!r}")
    return c


def _choice(fn, name, value, options) -> str:
    v = value.lower() if isinstance(value, str) else value
    if v not in options:
        raise ValueError(f"{fn}: {name} must be one of {', '.join(repr(o) for o in options)}, got {value!r}")
    return v


# ================================================================================================
# Mesh assembly
# ================================================================================================


class _Soup:
    """Triangles collected as corner coordinates, each group with a material id and a colour."""

    def __init__(self):
        self.tris, self.mats, self.cols = [], [], []

    def add(self, tris, material, color):
        tris = np.asarray(tris, np.float64).reshape(-1, 3, 3)
        if len(tris):
            self.tris.append(tris)
            self.mats.append(np.full(len(tris), material, np.int32))
            self.cols.append(np.broadcast_to(color, (len(tris), 3)))

    def build(self, fn, period, name, params) -> SmallScale:
        tris = np.concatenate(self.tris)
        vertices, faces = _weld(tris.reshape(-1, 3))
        _check_faces(fn, vertices, faces, params)
        # Every generated tile occupies [0, Px] × [0, Py], whether or not its geometry reaches
        # the boundary (rods without ground do not).
        return SmallScale(vertices, faces, material_ids=np.concatenate(self.mats),
                          colors=np.concatenate(self.cols), period=period, name=name, origin=(0.0, 0.0))


def _weld(points: np.ndarray):
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
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        ncomp, labels = connected_components(graph, directed=False)
        keep = np.zeros(ncomp, np.int64)
        keep[labels[::-1]] = np.arange(n)[::-1]  # lowest member index of each group
        uniq, inverse = uniq[keep], labels[inverse]
    return uniq, inverse.reshape(-1, 3)


def _check_faces(fn, v, f, params):
    """Refuse parameters that need sliver triangles, which SmallScale would drop with a warning.

    Same criterion as SmallScale (twice the area over the longest edge squared), with a 2x margin
    so coordinate rounding in file round trips cannot push a face over the line.
    """
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest2 = np.max([((b - a) ** 2).sum(1), ((c - b) ** 2).sum(1), ((a - c) ** 2).sum(1)], axis=0)
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    bad = repeated | ~(area2 > 2e-7 * longest2)
    if bad.any():
        raise ValueError(
            f"{fn}: {params} would need {int(bad.sum())} sliver triangle(s) (thinner than 2e-7 of "
            "their length); bring the parameters' proportions closer together"
        )


def _tri3(xy, z=0.0) -> np.ndarray:
    """(T, 3, 2) xy triangles lifted to (T, 3, 3) at height z."""
    xy = np.asarray(xy, np.float64).reshape(-1, 3, 2)
    return np.concatenate([xy, np.full(xy.shape[:2] + (1,), z)], axis=2)


def _fmt(**kw) -> str:
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v!r}" for k, v in kw.items())


# ================================================================================================
# Ground triangulation: square cells with star-shaped holes (pyramid bases, rod feet)
# ================================================================================================


def _ground(n: int, cell: float, holes: dict) -> np.ndarray:
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


def _dedupe(poly, tol) -> np.ndarray:
    """Drop consecutive (cyclically) repeated points of a polygon."""
    keep = np.linalg.norm(poly - np.roll(poly, -1, axis=0), axis=1) > tol
    return poly[keep] if keep.any() else poly[:1]


def _shoelace(poly) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _fan(poly) -> np.ndarray:
    """Fan a convex CCW polygon from its vertex mean (robust to collinear runs of border points)."""
    g = poly.mean(axis=0)
    nxt = np.roll(poly, -1, axis=0)
    return np.stack([np.broadcast_to(g, poly.shape), poly, nxt], axis=1)


# ================================================================================================
# Generators
# ================================================================================================


def flat(*, size=1.0, material=0, color=_WHITE) -> SmallScale:
    """A flat square tile at z = 0 (two triangles): the reference surface whose effective BRDF is the
    small-scale BRDF itself.

    Parameters
    ----------
    size : float > 0
        Side of the square tile (tile units); the period is (size, size).
    material : int >= 0
        Material id of both faces.
    color : 3 floats >= 0
        RGB colour weight of both faces.
    """
    fn = "flat"
    size = _real(fn, "size", size, lo=0, lo_open=True)
    material = _material(fn, "material", material)
    color = _color(fn, "color", color)
    v = np.array([[0, 0, 0], [size, 0, 0], [size, size, 0], [0, size, 0]], np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return SmallScale(
        v,
        f,
        material_ids=[material] * 2,
        colors=np.tile(color, (2, 1)),
        period=(size, size),
        name=f"flat(size={size:g})",
    )


def pyramid(
    *,
    height=0.5,
    base_fraction=1.0,
    sides=4,
    rotation=0.0,
    size=1.0,
    material=0,
    base_material=None,
    color=_WHITE,
    base_color=None,
) -> SmallScale:
    """A regular n-gon pyramid centred in a square tile, on flat ground (Wu Fig. 5).

    The base polygon lies at z = 0 with its vertices at angles rotation + 2πk/sides around the tile
    centre and circumradius base_fraction·size/2; the apex is at height `height` above the centre.
    Ground not covered by the base is triangulated around it at z = 0.

    Parameters
    ----------
    height : float > 0
        Apex height (tile units). Raising it makes the reflection more anisotropic (Wu Fig. 5-b).
    base_fraction : float > 0
        Base circumradius as a fraction of half the tile side. Any value <= 1 fits; the largest
        value that keeps the base inside the tile depends on `sides` and `rotation` (sqrt(2) for a
        square base rotated by π/4, whose base then fills the tile: the classic full pyramid with
        no ground). Base vertices closer than 1e-4·size to the tile edge are moved onto it.
    sides : int in [3, 1024]
        Number of lateral faces (5 gives Wu's 5-way anisotropy, Fig. 5-d).
    rotation : float
        Rotation of the base about the vertical axis, radians. rotation=0 puts a vertex on +x; for
        sides=4, rotation=π/4 aligns the base edges with the tile edges.
    size : float > 0
        Side of the square tile (tile units).
    material, color
        Material id and RGB weight of the lateral faces.
    base_material, base_color
        Material id and RGB weight of the ground around the base (default: same as the pyramid).
    """
    fn = "pyramid"
    height = _real(fn, "height", height, lo=0, lo_open=True)
    base_fraction = _real(fn, "base_fraction", base_fraction, lo=0, lo_open=True)
    sides = _int(fn, "sides", sides, 3, 1024)
    rotation = _real(fn, "rotation", rotation)
    size = _real(fn, "size", size, lo=0, lo_open=True)
    material = _material(fn, "material", material)
    base_material = _material(fn, "base_material", base_material, default=material)
    color = _color(fn, "color", color)
    base_color = _color(fn, "base_color", base_color, default=color)

    angles = rotation + 2 * np.pi * np.arange(sides) / sides
    u = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    max_fraction = 1.0 / np.abs(u).max()
    if base_fraction > max_fraction * (1 + 1e-9):
        raise ValueError(
            f"{fn}: base_fraction={base_fraction!r} puts the base outside the tile; with sides={sides} and "
            f"rotation={rotation:g} rad the base fits for base_fraction <= {max_fraction:.9g}"
        )
    half = 0.5 * size
    p = half + min(base_fraction, max_fraction) * half * u
    # Snap near-touching vertices onto the edge: a base a hair inside the edge would leave ground
    # pieces too thin to triangulate without slivers.
    snap = 1e-4 * size
    p = np.where(p < snap, 0.0, np.where(p > size - snap, size, p))
    # Reject proportions whose faces are needles (clearer than the generic sliver error).
    edge = float(np.linalg.norm(p[1] - p[0]))
    apothem = base_fraction * half * math.cos(math.pi / sides)
    slant = math.hypot(height, apothem)
    if edge < 1e-5 * max(slant, size):
        raise ValueError(
            f"{fn}: base edges of {edge:.3g} are too short for height={height:g} and size={size:g} "
            f"(faces would be slivers); increase base_fraction or decrease sides={sides}"
        )

    soup = _Soup()
    apex = np.array([half, half, height])
    base3 = np.concatenate([p, np.zeros((sides, 1))], axis=1)
    lateral = np.stack([base3, np.roll(base3, -1, axis=0), np.broadcast_to(apex, base3.shape)], axis=1)
    soup.add(lateral, material, color)
    soup.add(_tri3(_ground(1, size, {(0, 0): p})), base_material, base_color)
    params = _fmt(height=height, base_fraction=base_fraction, sides=sides, rotation=rotation, size=size)
    return soup.build(
        fn,
        (size, size),
        f"pyramid(sides={sides}, height={height:g}, base_fraction={base_fraction:g})",
        params,
    )


def grooves(
    *,
    depth=0.5,
    width=1.0,
    profile="v",
    flat_fraction=0.0,
    axis="x",
    segments=16,
    material=0,
    wall_material=None,
    color=_WHITE,
    wall_color=None,
) -> SmallScale:
    """Parallel grooves, one per period, running along `axis` (Wu Fig. 4, the grooved cup).

    The tile is width × width. Across the groove (the other axis) the profile is: flat land at
    z = depth for flat_fraction·width/2, the groove down to z = 0 and back, and land again for
    flat_fraction·width/2. Along the groove the surface is straight.

    Parameters
    ----------
    depth : float in (0, 1e4·width]
        Groove depth (tile units): land at z = depth, groove bottom at z = 0.
    width : float > 0
        Period across the groove, and the tile's length along it (tile units).
    profile : "v" or "u"
        "v": two planar walls meeting at the bottom. "u": a half ellipse (semi-axes
        groove-width/2 and depth) sampled with `segments` straight pieces at equal angles; with
        an odd number of pieces the polygon has a flat bottom a little above z = 0.
    flat_fraction : float in [0, 0.999]
        Fraction of the period that is flat land between grooves, split half on each side
        (values below 2e-6 count as 0).
    axis : "x" or "y"
        Direction the grooves run in.
    segments : int in [2, 4096]
        Number of straight pieces of the "u" profile (ignored for "v").
    material, color
        Material id and RGB weight of the flat land.
    wall_material, wall_color
        Material id and RGB weight of the groove walls (default: same as the land); a different
        colour gives Wu's bi-colour cup (Fig. 4-b).
    """
    fn = "grooves"
    width = _real(fn, "width", width, lo=0, lo_open=True)
    depth = _real(fn, "depth", depth, lo=0, lo_open=True, hi=1e4 * width)
    profile = _choice(fn, "profile", profile, ("v", "u"))
    flat_fraction = _real(fn, "flat_fraction", flat_fraction, lo=0.0, hi=0.999)
    axis = _choice(fn, "axis", axis, ("x", "y"))
    segments = _int(fn, "segments", segments, 2, 4096)
    material = _material(fn, "material", material)
    wall_material = _material(fn, "wall_material", wall_material, default=material)
    color = _color(fn, "color", color)
    wall_color = _color(fn, "wall_color", wall_color, default=color)

    land = 0.5 * flat_fraction * width
    if land < 1e-6 * width:
        land = 0.0  # a strip of land this narrow could only be meshed with slivers
    g = width - 2 * land  # groove opening
    if profile == "v":
        groove = np.array([[land, depth], [0.5 * width, 0.0], [width - land, depth]])
    else:
        phi = np.pi * np.arange(segments + 1) / segments
        groove = np.stack([0.5 * width - 0.5 * g * np.cos(phi), depth - depth * np.sin(phi)], axis=1)
        groove[0], groove[-1] = (land, depth), (width - land, depth)  # exact rims
        groove = _thin_polyline(groove, 1e-6 * width)
    walls = np.stack([groove[:-1], groove[1:]], axis=1)  # (S, 2 ends, (t, z))
    lands = (
        [np.array([[(0.0, depth), (land, depth)], [(width - land, depth), (width, depth)]])]
        if land > 0
        else []
    )

    def extrude(segs):
        # Each profile piece (t0,z0)-(t1,z1) swept over s in [0, width] along the groove: a quad
        # (0,t0)-(w,t0)-(w,t1)-(0,t1), counter-clockwise from above because t1 > t0.
        (t0, z0), (t1, z1) = segs[:, 0].T, segs[:, 1].T
        zero, w = np.zeros_like(t0), np.full_like(t0, width)
        a = np.stack([zero, t0, z0], 1)
        b = np.stack([w, t0, z0], 1)
        c = np.stack([w, t1, z1], 1)
        d = np.stack([zero, t1, z1], 1)
        tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        if axis == "y":  # swapping x and y mirrors the tile, so the winding flips too
            tris = tris[:, ::-1][..., [1, 0, 2]]
        return tris

    soup = _Soup()
    for segs in lands:
        soup.add(extrude(segs), material, color)
    soup.add(extrude(walls), wall_material, wall_color)
    params = _fmt(depth=depth, width=width, profile=profile, flat_fraction=flat_fraction, segments=segments)
    name = (
        f"grooves({profile}, depth={depth:g}, width={width:g}, flat_fraction={flat_fraction:g}, axis={axis})"
    )
    return soup.build(fn, (width, width), name, params)


def _thin_polyline(pts, tol) -> np.ndarray:
    """Drop interior points closer than tol to the previously kept one (keeping both ends), so no
    profile piece is short enough to make a sliver quad."""
    kept = [pts[0]]
    for p in pts[1:-1]:
        if np.linalg.norm(p - kept[-1]) >= tol:
            kept.append(p)
    if len(kept) > 1 and np.linalg.norm(pts[-1] - kept[-1]) < tol:
        kept.pop()
    kept.append(pts[-1])
    return np.array(kept)


def rods(
    *,
    radius=0.1,
    spacing=0.5,
    length=0.5,
    count=None,
    perturbation=0.0,
    seed=0,
    orientation=(0.0, 0.0),
    segments=12,
    ground=True,
    material=0,
    ground_material=None,
    color=_WHITE,
    ground_color=None,
) -> SmallScale:
    """Short cylinders standing on a ground plane, one per grid cell (Wu Fig. 6, velvet).

    The tile is count × count square cells of side `spacing`, period count·spacing in x and y. In
    each cell a rod of `radius` stands with its foot at the cell centre; its axis has unit direction
    given by `orientation` plus a random tilt. The rod is the cylinder of that axis, cut by the
    ground plane z = 0 at the bottom (so it sits flush on the ground, which has a matching hole)
    and capped by a disc perpendicular to the axis at `length` along the axis from the foot.

    Each rod stays strictly inside its own cell (1e-3·spacing clear of the border), so rods touch
    nothing but the ground and the tile edges carry ground only. A rod whose random tilt would take
    it out of its cell (or its cap below a tenth of its length off the ground) is tilted back
    toward the mean axis, along the same great circle, just far enough to fit.

    Parameters
    ----------
    radius : float in (0, 0.499·spacing)
        Rod radius (tile units).
    spacing : float > 0
        Distance between neighbouring rod feet = cell side (tile units).
    length : float > 0
        Rod length along its axis, from the foot to the centre of the top cap (tile units).
    count : int in [1, 64] or None
        Rods per tile side. None: 1 when perturbation == 0 (every rod is the same, one cell is a
        period), else 4 (16 independently tilted rods per tile).
    perturbation : float in [0, π/2]
        Largest random deviation of a rod axis from the mean axis, radians. Axes are drawn
        uniformly (by solid angle) in the cone of this half-angle around the mean axis.
    seed : int
        Seed of the random tilts; the same seed gives the same tile.
    orientation : (tilt, azimuth)
        Mean rod axis: polar angle from +z (tilt in [0, π/2)) and azimuth from +x, radians.
        The mean rod must fit in its cell (ValueError otherwise).
    segments : int in [3, 256]
        Number of sides of each rod's polygonal cross-section.
    ground : bool
        Include the ground plane (with holes under the rods). Without it the rods have a flat
        bottom cap in z = 0 and the tile is open between them.
    material, color
        Material id and RGB weight of the rods.
    ground_material, ground_color
        Material id and RGB weight of the ground (default: same as the rods).
    """
    fn = "rods"
    spacing = _real(fn, "spacing", spacing, lo=0, lo_open=True)
    radius = _real(fn, "radius", radius, lo=0, lo_open=True)
    if radius >= 0.499 * spacing:
        raise ValueError(
            f"{fn}: radius={radius!r} does not fit a cell of spacing={spacing!r}; "
            f"radius must be < 0.499*spacing = {0.499 * spacing:g}"
        )
    length = _real(fn, "length", length, lo=0, lo_open=True)
    perturbation = _real(fn, "perturbation", perturbation, lo=0.0, hi=np.pi / 2)
    if count is None:
        count = 1 if perturbation == 0 else 4
    count = _int(fn, "count", count, 1, 64)
    if isinstance(seed, bool) or not isinstance(seed, Integral):
        raise ValueError(f"{fn}: seed must be an integer, got {seed!r}")
    try:
        tilt, azimuth = orientation
    except (TypeError, ValueError):
        raise ValueError(
            f"{fn}: orientation must be (tilt, azimuth) in radians, got {orientation!r}"
        ) from None
    tilt = _real(fn, "orientation[0] (tilt)", tilt, lo=0.0, hi=np.pi / 2, hi_open=True)
    azimuth = _real(fn, "orientation[1] (azimuth)", azimuth)
    segments = _int(fn, "segments", segments, 3, 256)
    if not isinstance(ground, (bool, np.bool_)):
        raise ValueError(f"{fn}: ground must be True or False, got {ground!r}")
    material = _material(fn, "material", material)
    ground_material = _material(fn, "ground_material", ground_material, default=material)
    color = _color(fn, "color", color)
    ground_color = _color(fn, "ground_color", ground_color, default=color)

    shape = _RodShape(radius, length, spacing, segments)
    mean = np.array(
        [[math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)]]
    )
    if not shape.fits(mean)[0]:
        raise ValueError(
            f"{fn}: a rod of length={length:g} and radius={radius:g} tilted by orientation[0]={tilt:g} rad "
            f"leaves its spacing={spacing:g} cell (or its cap nears the ground); reduce length, radius or "
            "the tilt, or increase spacing"
        )
    n_rods = count * count
    # Draw before deciding whether to use the draws, so a seed means the same thing at any perturbation.
    rng = np.random.default_rng(int(seed))
    u, v = rng.random((2, n_rods))
    delta = np.arccos(1.0 - u * (1.0 - math.cos(perturbation)))  # uniform by solid angle in the cone
    psi = 2 * np.pi * v
    b1, b2 = _perpendicular_frame(mean)
    off = np.cos(psi)[:, None] * b1 + np.sin(psi)[:, None] * b2

    def axes_at(lam):
        d = (lam * delta)[:, None]
        return np.cos(d) * mean + np.sin(d) * off

    # Largest fraction of each rod's random tilt that fits (bisection; fraction 0 is the mean rod).
    lam_ok = np.where(shape.fits(axes_at(np.ones(n_rods))), 1.0, 0.0)
    lo, hi = lam_ok.copy(), np.ones(n_rods)
    todo = lam_ok < 1
    for _ in range(40 if todo.any() else 0):
        mid = 0.5 * (lo + hi)
        ok = shape.fits(axes_at(mid))
        lo = np.where(todo & ok, mid, lo)
        hi = np.where(todo & ~ok, mid, hi)
    axes = axes_at(lo)

    jj, ii = np.meshgrid(np.arange(count), np.arange(count), indexing="ij")
    feet = np.stack([(ii.ravel() + 0.5) * spacing, (jj.ravel() + 0.5) * spacing, np.zeros(n_rods)], axis=1)
    bottom, top = shape.rings(feet, axes)  # (R, M, 3) each
    top_centre = feet + length * axes
    nxt = np.roll(np.arange(segments), -1)
    soup = _Soup()
    sides = np.concatenate(
        [
            np.stack([bottom, bottom[:, nxt], top[:, nxt]], axis=2),
            np.stack([bottom, top[:, nxt], top], axis=2),
        ],
        axis=1,
    )
    soup.add(sides, material, color)
    soup.add(
        np.stack([np.broadcast_to(top_centre[:, None], top.shape), top, top[:, nxt]], axis=2), material, color
    )
    if ground:
        cells = zip(ii.ravel().tolist(), jj.ravel().tolist(), strict=True)
        holes = {cell: bottom[k, :, :2] for k, cell in enumerate(cells)}
        soup.add(_tri3(_ground(count, spacing, holes)), ground_material, ground_color)
    else:
        soup.add(
            np.stack([np.broadcast_to(feet[:, None], bottom.shape), bottom[:, nxt], bottom], axis=2),
            material,
            color,
        )
    period = count * spacing
    params = _fmt(radius=radius, spacing=spacing, length=length, segments=segments)
    name = (
        f"rods({count}x{count}, radius={radius:g}, length={length:g}, perturbation={perturbation:g}, "
        f"seed={int(seed)}{'' if ground else ', no ground'})"
    )
    return soup.build(fn, (period, period), name, params)


def _perpendicular_frame(axes):
    """Unit e1 (horizontal) and e2 = a × e1 perpendicular to each unit axis a, so (e1, e2, a) is
    right-handed; e1 = +x for a vertical axis."""
    h = np.hypot(axes[:, 0], axes[:, 1])
    tilted = h > 1e-12
    e1 = np.where(
        tilted[:, None],
        np.stack([-axes[:, 1], axes[:, 0], np.zeros(len(axes))], axis=1) / np.where(tilted, h, 1.0)[:, None],
        np.array([1.0, 0.0, 0.0]),
    )
    return e1, np.cross(axes, e1)


class _RodShape:
    """Rings of a cylinder cut by z = 0 at its foot and capped at `length` along its axis."""

    def __init__(self, radius, length, spacing, segments):
        self.r, self.length, self.spacing = radius, length, spacing
        beta = 2 * np.pi * np.arange(segments) / segments
        self.cos, self.sin = np.cos(beta), np.sin(beta)

    def offsets(self, axes):
        e1, e2 = _perpendicular_frame(axes)
        return self.r * (self.cos[None, :, None] * e1[:, None] + self.sin[None, :, None] * e2[:, None])

    def rings(self, feet, axes):
        """(R, M, 3) bottom ring in z = 0 and top ring, counter-clockwise seen from +axis."""
        o = self.offsets(axes)
        s = -o[..., 2] / axes[:, None, 2]  # slide along the axis down/up to the ground plane
        bottom = feet[:, None] + o + s[..., None] * axes[:, None]
        bottom[..., 2] = 0.0
        top = feet[:, None] + o + self.length * axes[:, None]
        return bottom, top

    def fits(self, axes) -> np.ndarray:
        """(R,) bool: the rod with each axis (foot at the cell centre) stays in its cell, clear of the
        border by 1e-3·spacing, and its top cap stays at least length/10 along the axis from the
        ground cut (so the side quads are not slivers)."""
        up = axes[:, 2] > 1e-9
        safe = np.where(up[:, None], axes, np.array([0.0, 0.0, 1.0]))
        o = self.offsets(safe)
        s = -o[..., 2] / safe[:, None, 2]
        bottom_xy = o[..., :2] + s[..., None] * safe[:, None, :2]
        top_xy = o[..., :2] + self.length * safe[:, None, :2]
        reach = np.maximum(np.abs(bottom_xy).max(axis=(1, 2)), np.abs(top_xy).max(axis=(1, 2)))
        inside = reach <= 0.5 * self.spacing * (1 - 2e-3)
        tall = self.length - s.max(axis=1) >= 0.1 * self.length
        return up & inside & tall


def woven(
    *,
    warp_width=0.8,
    weft_width=0.8,
    warp_height=0.2,
    weft_height=0.2,
    spacing=1.0,
    segments=16,
    warp_material=0,
    weft_material=1,
    warp_color=_WHITE,
    weft_color=_WHITE,
) -> SmallScale:
    """A plain weave of closed tubular threads (Wu Fig. 7, two-hue shot silk).

    Warp threads run along x at y = spacing/2 and 3·spacing/2; weft threads run along y at
    x = spacing/2 and 3·spacing/2. Each thread alternates over and under the threads it crosses,
    so one period is 2 × 2 crossings: 2·spacing in x and y. A thread's cross-section (in the
    vertical plane across the thread) is an ellipse of the given width and height, sampled as a
    polygon with `segments` sides, whose centre follows z = ±A·cos(π(t - spacing/2)/spacing)
    along the thread. The undulation amplitude A is computed, not given: the smallest for which
    the over thread clears the under thread at every crossing by 0.5% of the mean thread
    height, sampling included. Wide threads (width near spacing) need a large A: the threads' round
    flanks must pass each other (A ≈ 0.57·height for widths 0.8·spacing, ≈ 20·height at
    0.9998·spacing).
    Threads leave the tile as open tubes whose cross-sections match on opposite tile edges.

    Parameters
    ----------
    warp_width, weft_width : float in (0, 0.9998·spacing]
        Thread widths (tile units); threads of one direction do not touch each other.
    warp_height, weft_height : float in [1e-4·spacing, 100·spacing]
        Thread thicknesses (tile units).
    spacing : float > 0
        Distance between neighbouring parallel threads (tile units).
    segments : int in [3, 256]
        Sides of the cross-section polygon. Along a thread, 4·max(8, ceil(segments/2)) samples
        per period.
    warp_material, weft_material : int >= 0
        Material ids of warp and weft threads.
    warp_color, weft_color : 3 floats >= 0
        RGB weights of warp and weft threads (different colours give the two-hue look).
    """
    fn = "woven"
    spacing = _real(fn, "spacing", spacing, lo=0, lo_open=True)
    widths, heights = {}, {}
    for name, value in (("warp_width", warp_width), ("weft_width", weft_width)):
        widths[name] = _real(fn, name, value, lo=0, lo_open=True)
        if widths[name] > 0.9998 * spacing:
            raise ValueError(
                f"{fn}: {name}={value!r} leaves no gap between threads; it must be <= 0.9998*spacing "
                f"= {0.9998 * spacing:g}"
            )
    for name, value in (("warp_height", warp_height), ("weft_height", weft_height)):
        heights[name] = _real(fn, name, value, lo=0, lo_open=True)
        if not 1e-4 * spacing <= heights[name] <= 100 * spacing:
            raise ValueError(
                f"{fn}: {name}={value!r} must be in [1e-4*spacing, 100*spacing] = "
                f"[{1e-4 * spacing:g}, {100 * spacing:g}]"
            )
    segments = _int(fn, "segments", segments, 3, 256)
    warp_material = _material(fn, "warp_material", warp_material)
    weft_material = _material(fn, "weft_material", weft_material)
    warp_color = _color(fn, "warp_color", warp_color)
    weft_color = _color(fn, "weft_color", weft_color)

    aw, af = 0.5 * widths["warp_width"], 0.5 * widths["weft_width"]
    bw, bf = 0.5 * heights["warp_height"], 0.5 * heights["weft_height"]
    n_along = 4 * max(8, math.ceil(segments / 2))  # multiple of 4: crossings fall on samples
    amp = _weave_amplitude(aw, bw, af, bf, spacing, n_along)
    period = 2 * spacing
    t = np.linspace(0.0, period, n_along + 1)
    t[-1] = period
    wave = np.cos(np.pi * (t - 0.5 * spacing) / spacing)
    alpha = 2 * np.pi * np.arange(segments) / segments
    soup = _Soup()
    # Warp j rises over weft j and dips under the other; weft i does the opposite at its crossings.
    for j, sign in ((0, 1.0), (1, -1.0)):
        soup.add(
            _tube_along_x(t, (j + 0.5) * spacing, sign * amp * wave, aw, bw, alpha), warp_material, warp_color
        )
    for i, sign in ((0, -1.0), (1, 1.0)):
        tube = _tube_along_x(t, (i + 0.5) * spacing, sign * amp * wave, af, bf, alpha)
        soup.add(
            tube[:, ::-1][..., [1, 0, 2]], weft_material, weft_color
        )  # swap x, y: mirror, so flip winding
    params = _fmt(
        warp_width=2 * aw,
        weft_width=2 * af,
        warp_height=2 * bw,
        weft_height=2 * bf,
        spacing=spacing,
        segments=segments,
    )
    name = f"woven(warp {2 * aw:g}x{2 * bw:g}, weft {2 * af:g}x{2 * bf:g}, spacing={spacing:g})"
    return soup.build(fn, (period, period), name, params)


def _tube_along_x(x, y0, zc, a, b, alpha) -> np.ndarray:
    """(T, 3, 3) open tube along x: elliptical cross-sections (half-width a in y, half-height b in z)
    in the planes x = const, centred at (y0, zc[k]); outward normals."""
    k, m = len(x), len(alpha)
    ring = np.empty((k, m, 3))
    ring[..., 0] = x[:, None]
    ring[..., 1] = y0 + a * np.cos(alpha)[None, :]
    ring[..., 2] = zc[:, None] + b * np.sin(alpha)[None, :]
    p00, p01 = ring[:-1], np.roll(ring[:-1], -1, axis=1)
    p10, p11 = ring[1:], np.roll(ring[1:], -1, axis=1)
    # Around the ring alpha turns counter-clockwise seen from +x, so (p00, p01, p11) faces outward.
    return np.concatenate([np.stack([p00, p01, p11], axis=2), np.stack([p00, p11, p10], axis=2)]).reshape(
        -1, 3, 3
    )


def _weave_amplitude(aw, bw, af, bf, s, n_along) -> float:
    """Smallest undulation amplitude A at which crossing threads clear each other.

    At a crossing, offsets u across the weft and v across the warp, the over (warp) thread's lower
    surface is A·cos(πu/s) - bw·sqrt(1-(v/aw)²) and the under (weft) thread's upper surface is
    -A·cos(πv/s) + bf·sqrt(1-(u/af)²). The gap separates into a u part and a v part, so it is
    non-negative everywhere iff min_u[A·cos(πu/s) - bf·√(1-(u/af)²)] + min_v[...] >= 0. Polygonal
    cross-sections lie inside the ellipse (they only help); linear interpolation between the
    n_along samples moves each centre line by at most eps·A·|cos| with eps = π²/(2·n_along²)
    (second derivative bound over one sample step), which we absorb by solving with A·(1 - 2·eps).
    The margin is 1% of the mean half-height (0.5% of the mean thread height). H(A) is increasing
    (cos > 0 for |u| < s/2).
    """
    t = np.linspace(0.0, 1.0, 4097)
    cu, ru = np.cos(np.pi * af * t / s), np.sqrt(np.maximum(1 - t * t, 0.0))
    cv, rv = np.cos(np.pi * aw * t / s), ru

    def clearance(a):
        return (a * cu - bf * ru).min() + (a * cv - bw * rv).min()

    margin = 0.01 * 0.5 * (bw + bf)
    lo, hi = 0.0, bw + bf
    while clearance(hi) < margin:
        hi *= 2
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if clearance(mid) < margin else (lo, mid)
    eps = np.pi**2 / (2 * n_along**2)
    return hi / (1 - 2 * eps)


def heightfield(heights, *, size=1.0, scale=1.0, material=0, color=_WHITE) -> SmallScale:
    """A periodic height field: z = scale·heights[i, j] at x = j·size/W, y = i·size/H.

    The (H, W) grid is one period: the tile has W × H cells and the vertices on x = size and
    y = size repeat column 0 and row 0, so the tiled surface is continuous. Each cell is split
    into two triangles along its (i, j)-(i+1, j+1) diagonal.

    Parameters
    ----------
    heights : (H, W) array of finite reals, H, W >= 2
        Heights (tile units before `scale`). Row i is y, column j is x.
    size : float > 0
        Side of the square tile (tile units); cells are size/W by size/H.
    scale : float
        Multiplies every height (0 gives a flat tile; negative inverts the relief).
    material, color
        Material id and RGB weight of every face.
    """
    fn = "heightfield"
    try:
        h = np.array(heights, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"{fn}: heights must be a 2-D array of real numbers, got {type(heights).__name__}"
        ) from None
    if h.ndim != 2 or h.shape[0] < 2 or h.shape[1] < 2:
        raise ValueError(f"{fn}: heights must be a 2-D array of at least 2x2, got shape {h.shape}")
    bad = ~np.isfinite(h)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise ValueError(
            f"{fn}: heights contains NaN or inf ({int(bad.sum())} value(s); first at row {i}, column {j})"
        )
    size = _real(fn, "size", size, lo=0, lo_open=True)
    scale = _real(fn, "scale", scale)
    material = _material(fn, "material", material)
    color = _color(fn, "color", color)

    rows, cols = h.shape
    z = np.pad(scale * h, ((0, 1), (0, 1)), mode="wrap")  # periodic: last row/column = first
    xs, ys = size * np.arange(cols + 1) / cols, size * np.arange(rows + 1) / rows
    xs[-1] = ys[-1] = size  # exactly on the tile edge
    gx, gy = np.meshgrid(xs, ys)
    v = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
    idx = np.arange((rows + 1) * (cols + 1)).reshape(rows + 1, cols + 1)
    v00, v10, v01, v11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    f = np.concatenate(
        [np.stack([v00, v10, v11], -1).reshape(-1, 3), np.stack([v00, v11, v01], -1).reshape(-1, 3)]
    )
    _check_faces(fn, v, f, _fmt(shape=h.shape, size=size, scale=scale) + " (slopes too steep for the grid)")
    nf = len(f)
    return SmallScale(
        v,
        f,
        material_ids=np.full(nf, material),
        colors=np.tile(color, (nf, 1)),
        period=(size, size),
        name=f"heightfield({rows}x{cols}, scale={scale:g})",
    )


def heightfield_from_image(path, *, size=1.0, scale=1.0, material=0, color=_WHITE) -> SmallScale:
    """A periodic height field from a greyscale image (Wu's painted height fields), values in [0, 1].

    8-bit images (and colour ones, converted to luminance "L" by PIL; alpha is ignored) give
    pixel/255; 16-bit images pixel/65535; 32-bit integer images are read as 16-bit data; float
    ("F") images are used as stored. The image is seen from above: its top row lies at y = size,
    its left column at x = 0. See `heightfield` for size, scale, material and color.

    Raises FileNotFoundError for a missing file and ValueError for one PIL cannot read.
    """
    fn = "heightfield_from_image"
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{fn}: image file not found: {path}")
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode == "F":
                arr = np.asarray(im, np.float64)
            elif im.mode.startswith("I"):
                arr = np.asarray(im, np.float64) / 65535.0
            else:
                arr = np.asarray(im.convert("L"), np.float64) / 255.0
    except (OSError, ValueError, SyntaxError) as exc:  # PIL signals unreadable files with any of these
        raise ValueError(f"{fn}: could not read {path!r} as an image: {exc}") from exc
    if arr.ndim != 2:
        raise ValueError(f"{fn}: {path!r} did not decode to a 2-D greyscale image (shape {arr.shape})")
    tile = heightfield(arr[::-1], size=size, scale=scale, material=material, color=color)
    tile.name = f"heightfield({os.path.basename(path)}, scale={scale:g})"
    return tile


BUILTIN_TILES = {
    "pyramid": ("pyramid", {}),
    "pentagon": ("pyramid", {"sides": 5}),
    "vgroove": ("grooves", {"profile": "v"}),
    "ugroove": ("grooves", {"profile": "u"}),
    "rods": ("rods", {}),
    "woven": ("woven", {}),
    "flat": ("flat", {}),
}


def load_tile(spec: str):
    """A mesh file path, or the name of a built-in procedural tile."""

    if os.path.exists(spec):
        return SmallScale.load(spec)
    if spec in BUILTIN_TILES:
        fn, kwargs = BUILTIN_TILES[spec]
        return globals()[fn](**kwargs)
    raise ValueError(f"tile {spec!r} is neither a mesh file nor a built-in tile ({', '.join(BUILTIN_TILES)})")
