"""Procedural tiles built from polygonal tubes: rods standing on a ground plane (velvet), woven threads.

Tubes overhang (a tilted rod, a thread passing over another), so these tiles are not height fields:
each tube is closed or leaves the tile open-ended, its triangles wound counter-clockwise seen from
outside.
"""

from __future__ import annotations

import math
from numbers import Integral

import numpy as np

from .geometry_mesh import TriangleSoup, lift, triangulate_ground
from .geometry_params import WHITE, format_params, integer, material_id, real, rgb
from .smallscale import SmallScale

__all__ = ["rods", "woven"]


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
    color=WHITE,
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
    spacing = real(fn, "spacing", spacing, lo=0, lo_open=True)
    radius = real(fn, "radius", radius, lo=0, lo_open=True)
    if radius >= 0.499 * spacing:
        raise ValueError(
            f"{fn}: radius={radius!r} does not fit a cell of spacing={spacing!r}; "
            f"radius must be < 0.499*spacing = {0.499 * spacing:g}"
        )
    length = real(fn, "length", length, lo=0, lo_open=True)
    perturbation = real(fn, "perturbation", perturbation, lo=0.0, hi=np.pi / 2)
    if count is None:
        count = 1 if perturbation == 0 else 4
    count = integer(fn, "count", count, 1, 64)
    if isinstance(seed, bool) or not isinstance(seed, Integral) or seed < 0:
        raise ValueError(f"{fn}: seed must be an integer >= 0, got {seed!r}")
    tilt, azimuth = _orientation(fn, orientation)
    segments = integer(fn, "segments", segments, 3, 256)
    if not isinstance(ground, (bool, np.bool_)):
        raise ValueError(f"{fn}: ground must be True or False, got {ground!r}")
    material = material_id(fn, "material", material)
    ground_material = material_id(fn, "ground_material", ground_material, default=material)
    color = rgb(fn, "color", color)
    ground_color = rgb(fn, "ground_color", ground_color, default=color)

    shape = _RodShape(radius, length, spacing, segments)
    mean = _unit_axis(tilt, azimuth)
    if not shape.fits(mean)[0]:
        raise ValueError(
            f"{fn}: a rod of length={length:g} and radius={radius:g} tilted by orientation[0]={tilt:g} rad "
            f"leaves its spacing={spacing:g} cell (or its cap nears the ground); reduce length, radius or "
            "the tilt, or increase spacing"
        )
    tilt_angles, tilt_directions = _random_tilts(mean, count * count, perturbation, int(seed))
    fraction = _fitting_fraction(shape, mean, tilt_angles, tilt_directions)
    axes = _tilt(mean, tilt_directions, fraction * tilt_angles)
    feet, cells = _rod_feet(count, spacing)
    bottom, top = shape.rings(feet, axes)  # (R, M, 3) each

    soup = TriangleSoup()
    soup.add(_rod_sides(bottom, top), material, color)
    soup.add(_cap(feet + length * axes, top, facing_axis=True), material, color)
    if ground:
        holes = {cell: bottom[k, :, :2] for k, cell in enumerate(cells)}
        soup.add(lift(triangulate_ground(count, spacing, holes)), ground_material, ground_color)
    else:
        soup.add(_cap(feet, bottom, facing_axis=False), material, color)
    period = count * spacing
    params = format_params(radius=radius, spacing=spacing, length=length, segments=segments)
    name = (
        f"rods({count}x{count}, radius={radius:g}, length={length:g}, perturbation={perturbation:g}, "
        f"seed={int(seed)}{'' if ground else ', no ground'})"
    )
    return soup.build(fn, (period, period), name, params)


def _orientation(fn, orientation) -> tuple[float, float]:
    """The mean rod axis as (tilt, azimuth), or a ValueError naming what was given."""
    try:
        tilt, azimuth = orientation
    except (TypeError, ValueError):
        raise ValueError(
            f"{fn}: orientation must be (tilt, azimuth) in radians, got {orientation!r}"
        ) from None
    tilt = real(fn, "orientation[0] (tilt)", tilt, lo=0.0, hi=np.pi / 2, hi_open=True)
    azimuth = real(fn, "orientation[1] (azimuth)", azimuth)
    return tilt, azimuth


def _unit_axis(tilt, azimuth) -> np.ndarray:
    """(1, 3) unit vector at polar angle `tilt` from +z and azimuth `azimuth` from +x."""
    return np.array(
        [[math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)]]
    )


def _random_tilts(mean, n_rods, perturbation, seed):
    """Angle (R,) and unit direction (R, 3), perpendicular to the mean axis, of each rod's random tilt.

    Axes tilted so are uniform by solid angle in the cone of half-angle `perturbation` around the
    mean axis. The draws are made whatever the perturbation, so a seed means the same thing at
    any perturbation.
    """
    rng = np.random.default_rng(seed)
    u, v = rng.random((2, n_rods))
    angles = np.arccos(1.0 - u * (1.0 - math.cos(perturbation)))
    psi = 2 * np.pi * v
    b1, b2 = _perpendicular_frame(mean)
    directions = np.cos(psi)[:, None] * b1 + np.sin(psi)[:, None] * b2
    return angles, directions


def _tilt(mean, directions, angles) -> np.ndarray:
    """(R, 3) unit axes turned from the mean axis by `angles` toward `directions`, along great circles."""
    a = angles[:, None]
    return np.cos(a) * mean + np.sin(a) * directions


def _fitting_fraction(shape, mean, angles, directions) -> np.ndarray:
    """(R,) largest fraction of each rod's tilt that keeps the rod in its cell, by bisection.

    Fraction 0 is the mean rod, which fits; a rod whose whole tilt fits keeps fraction 1.
    """
    n_rods = len(angles)
    whole = np.where(shape.fits(_tilt(mean, directions, angles)), 1.0, 0.0)
    lo, hi = whole.copy(), np.ones(n_rods)
    too_far = whole < 1
    for _ in range(40 if too_far.any() else 0):
        mid = 0.5 * (lo + hi)
        ok = shape.fits(_tilt(mean, directions, mid * angles))
        lo = np.where(too_far & ok, mid, lo)
        hi = np.where(too_far & ~ok, mid, hi)
    return lo


def _rod_feet(count, spacing):
    """(R, 3) rod feet at the centres of the count × count cells, and each rod's cell (i, j).

    Rod k stands in cell (k % count, k // count).
    """
    jj, ii = np.meshgrid(np.arange(count), np.arange(count), indexing="ij")
    feet = np.stack(
        [(ii.ravel() + 0.5) * spacing, (jj.ravel() + 0.5) * spacing, np.zeros(count * count)], axis=1
    )
    cells = list(zip(ii.ravel().tolist(), jj.ravel().tolist(), strict=True))
    return feet, cells


def _rod_sides(bottom, top) -> np.ndarray:
    """(R, 2M, 3, 3) outward-facing triangles joining each rod's bottom ring to its top ring."""
    nxt = np.roll(np.arange(bottom.shape[1]), -1)
    return np.concatenate(
        [
            np.stack([bottom, bottom[:, nxt], top[:, nxt]], axis=2),
            np.stack([bottom, top[:, nxt], top], axis=2),
        ],
        axis=1,
    )


def _cap(centres, rings, facing_axis) -> np.ndarray:
    """(R, M, 3, 3) fans closing each ring at its centre.

    Rings run counter-clockwise seen from +axis, so the fan faces along the axis as given (a top
    cap) and against it with the winding reversed (a bottom cap).
    """
    hub = np.broadcast_to(centres[:, None], rings.shape)
    nxt = np.roll(np.arange(rings.shape[1]), -1)
    corners = [hub, rings, rings[:, nxt]] if facing_axis else [hub, rings[:, nxt], rings]
    return np.stack(corners, axis=2)


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
        """(R, M, 3) ring corners relative to the axis, in the plane perpendicular to each axis."""
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
    warp_color=WHITE,
    weft_color=WHITE,
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
    Threads leave the tile as open tubes whose cross-sections match on opposite tile edges. Every face's
    tangent (`SmallScale.face_tangents`) runs along its thread.

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
    spacing = real(fn, "spacing", spacing, lo=0, lo_open=True)
    widths, heights = {}, {}
    for name, value in (("warp_width", warp_width), ("weft_width", weft_width)):
        widths[name] = real(fn, name, value, lo=0, lo_open=True)
        if widths[name] > 0.9998 * spacing:
            raise ValueError(
                f"{fn}: {name}={value!r} leaves no gap between threads; it must be <= 0.9998*spacing "
                f"= {0.9998 * spacing:g}"
            )
    for name, value in (("warp_height", warp_height), ("weft_height", weft_height)):
        heights[name] = real(fn, name, value, lo=0, lo_open=True)
        if not 1e-4 * spacing <= heights[name] <= 100 * spacing:
            raise ValueError(
                f"{fn}: {name}={value!r} must be in [1e-4*spacing, 100*spacing] = "
                f"[{1e-4 * spacing:g}, {100 * spacing:g}]"
            )
    segments = integer(fn, "segments", segments, 3, 256)
    warp_material = material_id(fn, "warp_material", warp_material)
    weft_material = material_id(fn, "weft_material", weft_material)
    warp_color = rgb(fn, "warp_color", warp_color)
    weft_color = rgb(fn, "weft_color", weft_color)

    aw, af = 0.5 * widths["warp_width"], 0.5 * widths["weft_width"]
    bw, bf = 0.5 * heights["warp_height"], 0.5 * heights["weft_height"]
    n_along = 4 * max(8, math.ceil(segments / 2))  # multiple of 4: crossings fall on samples
    amp = _weave_amplitude(aw, bw, af, bf, spacing, n_along)
    period = 2 * spacing
    t = np.linspace(0.0, period, n_along + 1)
    t[-1] = period
    wave = np.cos(np.pi * (t - 0.5 * spacing) / spacing)
    alpha = 2 * np.pi * np.arange(segments) / segments
    soup = TriangleSoup()
    # Warp j rises over weft j and dips under the other; weft i does the opposite at its crossings.
    # Face tangents along each thread (its centre line's chord over the face), the direction the fibres of
    # a yarn run: an anisotropic BRDF's x axis then follows the thread.
    for j, sign in ((0, 1.0), (1, -1.0)):
        soup.add(
            _tube_along_x(t, (j + 0.5) * spacing, sign * amp * wave, aw, bw, alpha), warp_material, warp_color,
            tangents=_tube_tangents(t, sign * amp * wave, segments),
        )
    for i, sign in ((0, -1.0), (1, 1.0)):
        tube = _tube_along_x(t, (i + 0.5) * spacing, sign * amp * wave, af, bf, alpha)
        soup.add(
            tube[:, ::-1][..., [1, 0, 2]], weft_material, weft_color,
            tangents=_tube_tangents(t, sign * amp * wave, segments)[:, [1, 0, 2]],
        )  # swap x, y: mirror, so flip winding
    params = format_params(
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


def _tube_tangents(x, zc, m) -> np.ndarray:
    """(T, 3) the tangents of `_tube_along_x(x, ..., zc, ...)`'s triangles, in its order (two triangles per ring
    segment k and side, all of segment k's first triangles, then all the second ones): the centre line's
    chord (x[k+1] − x[k], 0, zc[k+1] − zc[k]) normalised, which both triangles of a side's quad contain (the
    quad is a parallelogram: neighbouring rings are translates)."""
    chord = np.stack([np.diff(x), np.zeros(len(x) - 1), np.diff(zc)], 1)
    chord /= np.linalg.norm(chord, axis=1, keepdims=True)
    return np.tile(np.repeat(chord, m, axis=0), (2, 1))


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
