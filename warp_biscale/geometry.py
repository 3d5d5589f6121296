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

The generators live in `geometry_relief` (height-field surfaces: flat, pyramid, grooves, sampled
heights) and `geometry_tubes` (rods and woven threads, which overhang), on the parameter checks of
`geometry_params` and the mesh assembly of `geometry_mesh`; this module is their public face.
"""

from __future__ import annotations

import os

from .geometry_relief import (flat, grooves, heightfield, heightfield_from_image, pyramid, read_height_image,
                              relief, relief_heights)
from .geometry_tubes import rods, woven
from .smallscale import SmallScale

__all__ = ["flat", "pyramid", "grooves", "rods", "woven", "heightfield", "heightfield_from_image", "read_height_image",
           "relief", "relief_heights"]

# Tile names accepted by the command line and scene files: generator (an attribute of this module)
# and its keyword arguments.
BUILTIN_TILES = {
    "pyramid": ("pyramid", {}),
    "pentagon": ("pyramid", {"sides": 5}),
    "grooves": ("grooves", {}),
    "vgroove": ("grooves", {"profile": "v"}),
    "ugroove": ("grooves", {"profile": "u"}),
    "rods": ("rods", {}),
    "woven": ("woven", {}),
    "flat": ("flat", {}),
    "heightfield": ("relief", {}),
}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".gif", ".webp")  # a height field's image


def load_tile(spec: str):
    """A mesh file path, a greyscale image (a height field, `heightfield_from_image`), or the name of a
    built-in procedural tile (BUILTIN_TILES)."""

    if os.path.exists(spec):
        return heightfield_from_image(spec) if spec.lower().endswith(IMAGE_SUFFIXES) else SmallScale.load(spec)
    if spec in BUILTIN_TILES:
        fn, kwargs = BUILTIN_TILES[spec]
        return globals()[fn](**kwargs)
    if os.path.islink(spec):
        raise FileNotFoundError(f"tile {spec!r} is a broken link (to {os.readlink(spec)!r})")
    if os.path.splitext(spec)[1] or os.sep in spec:  # (a path, not a misspelt name)
        raise FileNotFoundError(f"no such tile file: {spec}")
    raise ValueError(f"tile {spec!r} is neither a mesh file, a height-field image nor a built-in tile "
                     f"({', '.join(BUILTIN_TILES)})")
