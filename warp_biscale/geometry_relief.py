"""Procedural tiles whose surface is a height field z = f(x, y): flat, pyramid, grooves, sampled heights.

Each surface is single-valued over the tile: no overhangs, every triangle wound counter-clockwise
seen from above. Tiles with overhangs (rods, woven threads) are built from tubes in `geometry_tubes`.
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np
from PIL import Image

from .geometry_mesh import TriangleSoup, check_faces, following, lift, triangulate_ground
from .geometry_params import WHITE, format_params, integer, material_id, one_of, real, rgb
from .images import check_image_size
from .smallscale import SmallScale

__all__ = ["flat", "pyramid", "grooves", "heightfield", "heightfield_from_image", "relief", "relief_heights"]


def flat(*, size=1.0, material=0, color=WHITE) -> SmallScale:
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
    size = real(fn, "size", size, lo=0, lo_open=True)
    material = material_id(fn, "material", material)
    color = rgb(fn, "color", color)
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
    color=WHITE,
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
    height = real(fn, "height", height, lo=0, lo_open=True)
    base_fraction = real(fn, "base_fraction", base_fraction, lo=0, lo_open=True)
    sides = integer(fn, "sides", sides, 3, 1024)
    rotation = real(fn, "rotation", rotation)
    size = real(fn, "size", size, lo=0, lo_open=True)
    material = material_id(fn, "material", material)
    base_material = material_id(fn, "base_material", base_material, default=material)
    color = rgb(fn, "color", color)
    base_color = rgb(fn, "base_color", base_color, default=color)

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

    soup = TriangleSoup()
    apex = np.array([half, half, height])
    base3 = np.concatenate([p, np.zeros((sides, 1))], axis=1)
    lateral = np.stack([base3, following(base3), np.broadcast_to(apex, base3.shape)], axis=1)
    soup.add(lateral, material, color)
    soup.add(lift(triangulate_ground(1, size, {(0, 0): p})), base_material, base_color)
    params = format_params(height=height, base_fraction=base_fraction, sides=sides, rotation=rotation, size=size)
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
    color=WHITE,
    wall_color=None,
) -> SmallScale:
    """Parallel grooves, one per period, running along `axis` (Wu Fig. 4, the grooved cup). Every face's
    tangent (`SmallScale.face_tangents`) runs along the grooves.

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
    width = real(fn, "width", width, lo=0, lo_open=True)
    depth = real(fn, "depth", depth, lo=0, lo_open=True, hi=1e4 * width)
    profile = one_of(fn, "profile", profile, ("v", "u"))
    flat_fraction = real(fn, "flat_fraction", flat_fraction, lo=0.0, hi=0.999)
    axis = one_of(fn, "axis", axis, ("x", "y"))
    segments = integer(fn, "segments", segments, 2, 4096)
    material = material_id(fn, "material", material)
    wall_material = material_id(fn, "wall_material", wall_material, default=material)
    color = rgb(fn, "color", color)
    wall_color = rgb(fn, "wall_color", wall_color, default=color)

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

    # Face tangents along the grooves (every face holds that direction): an anisotropic BRDF's x axis
    # then follows the grooves, as a brushed or turned finish would.
    along = (1.0, 0.0, 0.0) if axis == "x" else (0.0, 1.0, 0.0)
    soup = TriangleSoup()
    for segs in lands:
        soup.add(extrude(segs), material, color, tangents=along)
    soup.add(extrude(walls), wall_material, wall_color, tangents=along)
    params = format_params(depth=depth, width=width, profile=profile, flat_fraction=flat_fraction, segments=segments)
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


def heightfield(heights, *, size=1.0, scale=1.0, material=0, color=WHITE) -> SmallScale:
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
    size = real(fn, "size", size, lo=0, lo_open=True)
    scale = real(fn, "scale", scale)
    material = material_id(fn, "material", material)
    color = rgb(fn, "color", color)

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
    check_faces(fn, v, f, format_params(shape=h.shape, size=size, scale=scale) + " (slopes too steep for the grid)")
    nf = len(f)
    return SmallScale(
        v,
        f,
        material_ids=np.full(nf, material),
        colors=np.tile(color, (nf, 1)),
        period=(size, size),
        name=f"heightfield({rows}x{cols}, scale={scale:g})",
    )


HEIGHT_PIXELS_MAX = 2048 * 2048  # a height image's cells, two faces each: past this a small PNG could fill the memory
RELIEF_GRID = 64  # the default relief's grid: RELIEF_GRID² heights a period


def relief_heights(n: int = RELIEF_GRID, seed: int = 0) -> np.ndarray:
    """(n, n) heights in [0, 1]: a gentle periodic relief of six random low-frequency waves (the editor's
    starting height field, and the tile named "heightfield" on the command line and in scene files)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    h = np.zeros((n, n))
    for _ in range(6):
        fx, fy = rng.integers(1, 4, 2)
        h += np.cos(2 * np.pi * (fx * x + fy * y) + rng.uniform(0, 2 * np.pi))
    return (h - h.min()) / (h.max() - h.min())


def relief(amplitude=0.15, seed=0, *, material=0, color=WHITE) -> SmallScale:
    """The default height field: `relief_heights(seed=seed)` raised to `amplitude` (the tile side is 1)."""
    seed = integer("relief", "seed", seed, 0)
    amplitude = real("relief", "amplitude", amplitude)
    try:
        tile = heightfield(relief_heights(seed=seed), scale=amplitude, material=material, color=color)
    except ValueError as exc:  # (heightfield's check of the grid: said as relief's, whose amplitude is its scale)
        raise ValueError(f"relief(amplitude={amplitude:g}): {exc}") from None
    tile.name = f"relief(amplitude={amplitude:g}, seed={seed})"
    return tile


def heightfield_from_image(path, *, size=1.0, scale=1.0, material=0, color=WHITE) -> SmallScale:
    """A periodic height field from a greyscale image (Wu's painted height fields), values in [0, 1].

    8-bit images (and colour ones, converted to luminance "L" by PIL; alpha is ignored) give
    pixel/255; 16-bit images pixel/65535; 32-bit integer images are read as 16-bit data; float
    ("F") images are used as stored. The image is seen from above: its top row lies at y = size,
    its left column at x = 0. See `heightfield` for size, scale, material and color.

    Raises FileNotFoundError for a missing file and ValueError for one PIL cannot read.
    """
    arr = read_height_image(path, "heightfield_from_image")
    try:
        tile = heightfield(arr, size=size, scale=scale, material=material, color=color)
    except ValueError as exc:  # (a 1-pixel or NaN image, too steep: the file named)
        raise ValueError(f"height image {os.fspath(path)}: {exc}") from None
    tile.name = f"heightfield({os.path.basename(path)}, scale={scale:g})"
    return tile


def read_height_image(path, fn="read_height_image") -> np.ndarray:
    """(H, W) float64 heights in [0, 1] of a greyscale image, row i at y = i/H (the image's bottom row
    first: it is seen from above), as `heightfield_from_image` reads it."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{fn}: image file not found: {path}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # (its size is checked here)
            im = Image.open(path)
        with im:
            check_image_size(path, im.size, HEIGHT_PIXELS_MAX)
            im.load()
            if im.mode == "F":
                arr = np.asarray(im, np.float64)
            elif im.mode.startswith("I"):
                arr = np.asarray(im, np.float64) / 65535.0
            else:
                arr = np.asarray(im.convert("L"), np.float64) / 255.0
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:  # PIL's signals of bad files
        raise ValueError(f"{fn}: could not read {path!r} as an image: {exc}") from exc
    if arr.ndim != 2:
        raise ValueError(f"{fn}: {path!r} did not decode to a 2-D greyscale image (shape {arr.shape})")
    return arr[::-1].copy()
