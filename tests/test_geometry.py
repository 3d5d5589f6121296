"""Procedural tiles (warp_biscale.geometry): validity, seamless tiling, closed-form areas, materials."""

import math
import os
import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from warp_biscale.geometry import flat, grooves, heightfield, heightfield_from_image, pyramid, relief, rods, woven
from warp_biscale.smallscale import SmallScale, TileWarning

FAST = settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much]
)


def make(fn, *args, **kw) -> SmallScale:
    """Build a tile with every TileWarning turned into an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", TileWarning)
        tile = fn(*args, **kw)
    assert isinstance(tile, SmallScale)
    return tile


def check_tile(tile, prefix):
    """Invariants every generated tile has."""
    assert tile.name.startswith(prefix)
    assert len(tile.faces) and (tile.face_areas > 0).all()
    assert tile.material_ids.shape == (len(tile.faces),) and tile.colors.shape == (len(tile.faces), 3)
    px, py = tile.period
    xy = tile.vertices[:, :2]
    assert (
        (xy >= -1e-12 * px).all()
        and (xy[:, 0] <= px * (1 + 1e-12)).all()
        and (xy[:, 1] <= py * (1 + 1e-12)).all()
    )
    assert_edges_match(tile)


def assert_edges_match(tile):
    """Opposite tile edges carry exactly the same boundary vertices (other coordinate, z)."""
    v, tol = tile.vertices, 1e-9 * max(tile.period)
    for axis, other in ((0, 1), (1, 0)):
        lo = v[np.abs(v[:, axis]) < tol][:, [other, 2]]
        hi = v[np.abs(v[:, axis] - tile.period[axis]) < tol][:, [other, 2]]
        assert len(lo) == len(hi)
        lo, hi = lo[np.lexsort(lo.T[::-1])], hi[np.lexsort(hi.T[::-1])]
        np.testing.assert_allclose(lo, hi, rtol=0, atol=1e-9 * max(tile.period))


def check_height_field_like(tile):
    """Every face looks up, and the faces project onto the footprint exactly once."""
    n = tile.face_normals
    assert (n[:, 2] > 0).all()
    projected = float((tile.face_areas * np.abs(n[:, 2])).sum())
    assert projected == pytest.approx(tile.period[0] * tile.period[1], rel=1e-9)


def projected_signed(tile):
    return float((tile.face_areas * tile.face_normals[:, 2]).sum())


def volume(tile, mask=None):
    """∫ z n_z dA: the enclosed volume for surfaces closed up to vertical walls."""
    m = slice(None) if mask is None else mask
    zbar = tile.triangles[m][:, :, 2].mean(axis=1)
    return float((tile.face_areas[m] * tile.face_normals[m][:, 2] * zbar).sum())


# ------------------------------------------------------------------------------------------------- defaults

DEFAULTS = [
    ("flat", lambda: make(flat), True),
    ("pyramid", lambda: make(pyramid), True),
    ("pyramid", lambda: make(pyramid, sides=4, rotation=math.pi / 4, base_fraction=math.sqrt(2)), True),
    ("pyramid", lambda: make(pyramid, sides=5, base_fraction=1.0, rotation=0.3), True),
    ("pyramid", lambda: make(pyramid, sides=3, base_fraction=1.0), True),
    ("grooves", lambda: make(grooves), True),
    ("grooves", lambda: make(grooves, profile="u", flat_fraction=0.3, axis="y"), True),
    ("rods", lambda: make(rods), False),
    ("rods", lambda: make(rods, perturbation=0.6, seed=3), False),
    ("rods", lambda: make(rods, ground=False, perturbation=0.3), False),
    ("woven", lambda: make(woven), False),
    ("heightfield", lambda: make(heightfield, np.random.default_rng(0).random((5, 7))), True),
]


@pytest.mark.parametrize("prefix, build, height_field_like", DEFAULTS)
def test_defaults_are_valid_tiles(prefix, build, height_field_like):
    tile = build()
    check_tile(tile, prefix)
    if height_field_like:
        check_height_field_like(tile)


# ----------------------------------------------------------------------------------------------------- flat


@FAST
@given(size=st.floats(1e-3, 1e3), material=st.integers(0, 7), color=st.tuples(*[st.floats(0, 4)] * 3))
def test_flat(size, material, color):
    tile = make(flat, size=size, material=material, color=color)
    check_tile(tile, "flat")
    check_height_field_like(tile)
    assert tile.area == pytest.approx(size * size, rel=1e-12)
    assert tile.period == (size, size) and tile.z_range == (0.0, 0.0)
    assert (tile.material_ids == material).all()
    np.testing.assert_array_equal(tile.colors, np.tile(color, (2, 1)))


# -------------------------------------------------------------------------------------------------- pyramid


def max_fraction(sides, rotation):
    a = rotation + 2 * np.pi * np.arange(sides) / sides
    return 1.0 / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a))).max()


def pyramid_lateral(height, base_fraction, sides, size):
    r = base_fraction * size / 2
    edge = 2 * r * math.sin(math.pi / sides)
    slant = math.hypot(height, r * math.cos(math.pi / sides))
    return sides * 0.5 * edge * slant, sides / 2 * r * r * math.sin(2 * math.pi / sides)


@FAST
@given(
    height=st.floats(0.01, 5),
    sides=st.integers(3, 12),
    rotation=st.floats(-math.pi, math.pi),
    size=st.floats(0.1, 10),
    rel=st.one_of(st.just(1.0), st.floats(0.05, 1.0)),
)
def test_pyramid_valid_and_seamless(height, sides, rotation, size, rel):
    base_fraction = rel * max_fraction(sides, rotation)
    try:
        tile = make(
            pyramid,
            height=height * size,
            base_fraction=base_fraction,
            sides=sides,
            rotation=rotation,
            size=size,
            base_material=1,
            color=(1, 0, 0),
            base_color=(0, 1, 0),
        )
    except ValueError as exc:
        # A base corner a hair off the tile edge (e.g. rotation 2e-7) would need a sliver triangle: the
        # generator refuses such proportions by design, with this message; any other error is a failure.
        assert "sliver" in str(exc)
        assume(False)
    check_tile(tile, "pyramid")
    check_height_field_like(tile)
    lateral = tile.material_ids == 0
    assert lateral.sum() == sides
    # Colours follow materials; the ground is exactly flat at z = 0.
    np.testing.assert_array_equal(tile.colors[lateral], np.tile((1, 0, 0), (sides, 1)))
    np.testing.assert_array_equal(tile.colors[~lateral], np.tile((0, 1, 0), ((~lateral).sum(), 1)))
    assert (tile.triangles[~lateral][..., 2] == 0).all()
    if rel < 0.99:  # away from the edge-snapping tolerance the closed form is exact
        lat, base = pyramid_lateral(height * size, base_fraction, sides, size)
        assert tile.face_areas[lateral].sum() == pytest.approx(lat, rel=1e-9)
        assert tile.face_areas[~lateral].sum() == pytest.approx(size * size - base, rel=1e-9)


@pytest.mark.parametrize(
    "sides, rotation, fraction",
    [(4, 0.0, 0.5), (4, 0.0, 1.0), (5, 0.2, 0.8), (3, 1.0, 0.3), (8, 0.1, 0.9), (64, 0.0, 1.0)],
)
def test_pyramid_closed_form_area(sides, rotation, fraction):
    h, size = 0.7, 2.0
    tile = make(pyramid, height=h, base_fraction=fraction, sides=sides, rotation=rotation, size=size)
    lat, base = pyramid_lateral(h, fraction, sides, size)
    assert tile.area == pytest.approx(lat + size * size - base, rel=1e-12)
    assert tile.z_range == (0.0, h)


def test_full_pyramid_has_no_ground():
    h, size = 0.5, 1.0
    tile = make(pyramid, height=h, sides=4, rotation=math.pi / 4, base_fraction=math.sqrt(2), size=size)
    assert len(tile.faces) == 4 and len(tile.vertices) == 5
    assert tile.area == pytest.approx(4 * 0.5 * size * math.hypot(h, size / 2), rel=1e-12)
    check_height_field_like(tile)


# -------------------------------------------------------------------------------------------------- grooves


@FAST
@given(
    depth=st.floats(0.01, 10),
    width=st.floats(0.1, 10),
    profile=st.sampled_from(["v", "u"]),
    flat_fraction=st.one_of(st.just(0.0), st.floats(0, 0.999)),
    axis=st.sampled_from(["x", "y"]),
    segments=st.integers(2, 64),
)
def test_grooves_valid_and_seamless(depth, width, profile, flat_fraction, axis, segments):
    tile = make(
        grooves,
        depth=depth * width,
        width=width,
        profile=profile,
        flat_fraction=flat_fraction,
        axis=axis,
        segments=segments,
        wall_material=2,
        wall_color=(1, 1, 0),
    )
    check_tile(tile, "grooves")
    check_height_field_like(tile)
    lowest = (
        0.0
        if profile == "v" or segments % 2 == 0
        else depth * width * (1 - math.cos(math.pi / (2 * segments)))
    )
    assert tile.z_range == pytest.approx((lowest, depth * width), rel=1e-12, abs=1e-12 * depth * width)
    land = tile.material_ids == 0
    # Land is flat at the top; walls are everything else.
    assert (tile.face_normals[land][:, 2] == 1).all() and (
        tile.triangles[land][..., 2] == depth * width
    ).all()
    level = tile.face_normals[:, 2] == 1
    # Only an odd "u" has a flat bottom.
    np.testing.assert_allclose(
        tile.triangles[~land & level][..., 2], lowest, rtol=0, atol=1e-12 * depth * width
    )
    np.testing.assert_array_equal(tile.colors[~land], np.tile((1, 1, 0), ((~land).sum(), 1)))
    flat_fraction = flat_fraction if flat_fraction >= 2e-6 else 0.0
    assert tile.face_areas[land].sum() == pytest.approx(flat_fraction * width * width, rel=1e-9, abs=1e-12)
    if profile == "v":
        g = (1 - flat_fraction) * width
        wall = 2 * math.hypot(depth * width, g / 2) * width
        assert tile.face_areas[~land].sum() == pytest.approx(wall, rel=1e-9)


def test_v_groove_wall_area():
    d, w = 0.3, 2.0
    tile = make(grooves, depth=d, width=w, profile="v", flat_fraction=0.0)
    assert tile.area == pytest.approx(2 * math.sqrt(d * d + (w / 2) ** 2) * w, rel=1e-12)


def test_u_groove_approaches_half_ellipse():
    d, w = 0.4, 1.0
    tile = make(grooves, depth=d, width=w, profile="u", segments=2048)
    a, b = w / 2, d
    h = ((a - b) / (a + b)) ** 2  # Ramanujan's perimeter of an ellipse
    half_perimeter = 0.5 * math.pi * (a + b) * (1 + 3 * h / (10 + math.sqrt(4 - 3 * h)))
    assert tile.area == pytest.approx(half_perimeter * w, rel=1e-5)


def test_grooves_axis_y_is_axis_x_mirrored():
    tx = make(grooves, profile="u", flat_fraction=0.2, axis="x")
    ty = make(grooves, profile="u", flat_fraction=0.2, axis="y")
    a = tx.vertices[np.lexsort(tx.vertices.T)]
    b = ty.vertices[:, [1, 0, 2]]
    np.testing.assert_allclose(a, b[np.lexsort(b.T)])
    assert ty.area == pytest.approx(tx.area, rel=1e-12)


# ----------------------------------------------------------------------------------------------------- rods


def rod_cells(tile, spacing):
    """Cell index of each rod face (from its centroid) and whether the face belongs to a rod."""
    tri = tile.triangles
    on_ground = (tri[..., 2] == 0).all(axis=1) & (tile.face_normals[:, 2] == 1)
    return np.floor(tri.mean(axis=1)[:, :2] / spacing).astype(int), ~on_ground


@FAST
@given(
    spacing=st.floats(0.1, 5),
    radius=st.floats(0.02, 0.45),
    length=st.floats(0.1, 2),
    tilt=st.floats(0, 0.6),
    azimuth=st.floats(-math.pi, math.pi),
    perturbation=st.floats(0, math.pi / 2),
    count=st.one_of(st.none(), st.integers(1, 4)),
    segments=st.integers(3, 24),
    ground=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_rods_valid_and_seamless(
    spacing, radius, length, tilt, azimuth, perturbation, count, segments, ground, seed
):
    kw = dict(
        radius=radius * spacing,
        spacing=spacing,
        length=length * spacing,
        orientation=(tilt, azimuth),
        perturbation=perturbation,
        count=count,
        segments=segments,
        ground=ground,
        seed=seed,
        ground_material=3,
        ground_color=(0.5, 0.5, 0.5),
    )
    try:
        tile = make(rods, **kw)
    except ValueError as exc:
        assume("leaves its" not in str(exc))  # the documented rejection of a mean rod that does not fit
        raise
    n = count if count is not None else (1 if perturbation == 0 else 4)
    assert tile.period == pytest.approx((n * spacing, n * spacing))
    if ground:
        check_tile(tile, "rods")
        # The ground with its holes plus the rods' caps covers the footprint once (signed).
        assert projected_signed(tile) == pytest.approx(n * n * spacing * spacing, rel=1e-9)
        assert set(np.unique(tile.material_ids)) == {0, 3}
        ground_faces = tile.material_ids == 3
        assert (tile.face_normals[ground_faces][:, 2] == 1).all()
    else:
        # Closed rods: the outward normals integrate to zero and the volume is positive.
        np.testing.assert_allclose(
            (tile.face_areas[:, None] * tile.face_normals).sum(0), 0, atol=1e-9 * spacing**2
        )
        assert volume(tile) > 0
    # Every rod stays strictly inside its own cell, clear of the border.
    cell, is_rod = rod_cells(tile, spacing)
    tri = tile.triangles
    for k in np.flatnonzero(is_rod):
        lo = cell[k] * spacing
        assert (tri[k][:, :2] > lo + 1e-4 * spacing).all() and (
            tri[k][:, :2] < lo + spacing * (1 - 1e-4)
        ).all()
    assert tile.z_range[0] == 0.0


def test_upright_rods_closed_form():
    r, s, length, m, n = 0.1, 0.5, 0.4, 12, 2
    tile = make(rods, radius=r, spacing=s, length=length, segments=m, count=n, ground_material=1)
    cap = m / 2 * r * r * math.sin(2 * math.pi / m)
    side = m * 2 * r * math.sin(math.pi / m) * length
    rod = tile.material_ids == 0
    assert tile.face_areas[rod].sum() == pytest.approx(n * n * (cap + side), rel=1e-12)
    assert tile.face_areas[~rod].sum() == pytest.approx(n * n * (s * s - cap), rel=1e-12)
    assert tile.z_range == pytest.approx((0.0, length))


def test_rods_deterministic_per_seed():
    a = make(rods, perturbation=0.5, seed=7)
    b = make(rods, perturbation=0.5, seed=7)
    c = make(rods, perturbation=0.5, seed=8)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)


def test_rods_orientation_tilts_the_rods():
    tilt, azimuth, length = 0.3, 1.0, 0.5
    tile = make(rods, radius=0.05, spacing=1.0, length=length, orientation=(tilt, azimuth))
    top = tile.vertices[np.argmax(tile.vertices[:, 2])]
    centre = tile.vertices[tile.vertices[:, 2] > 0].mean(axis=0)
    d = centre[:2] - 0.5
    assert math.atan2(d[1], d[0]) == pytest.approx(azimuth, abs=1e-9)
    assert top[2] <= length * math.cos(tilt) + 0.05 * math.sin(tilt) + 1e-12


# ---------------------------------------------------------------------------------------------------- woven


def upward_crossings(points, tris):
    """How many triangles the upward vertical ray from each point crosses (odd: inside a closed tube)."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-300
    det = np.where(ok, det, 1.0)
    out = np.zeros(len(points), int)
    for s in range(0, len(points), 256):
        p = points[s : s + 256, None, :]
        dx, dy = p[..., 0] - a[:, 0], p[..., 1] - a[:, 1]
        l1 = (dx * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * dy) / det
        l2 = ((b[:, 0] - a[:, 0]) * dy - dx * (b[:, 1] - a[:, 1])) / det
        z = a[:, 2] + l1 * (b[:, 2] - a[:, 2]) + l2 * (c[:, 2] - a[:, 2])
        hit = ok & (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1) & (z > p[..., 2])
        out[s : s + 256] = hit.sum(axis=1)
    return out


def assert_threads_apart(tile, warp_material=0, weft_material=1, seed=0, points=2000):
    """Random points on each thread set lie outside the other set's tubes."""
    rng = np.random.default_rng(seed)
    for mine, other in ((warp_material, weft_material), (weft_material, warp_material)):
        tri = tile.triangles[tile.material_ids == mine]
        tri = tri[rng.choice(len(tri), min(len(tri), points), replace=False)]
        u, v = rng.random((2, len(tri)))
        su = np.sqrt(u)
        pts = (
            (1 - su)[:, None] * tri[:, 0]
            + (su * (1 - v))[:, None] * tri[:, 1]
            + (su * v)[:, None] * tri[:, 2]
        )
        crossings = upward_crossings(pts, tile.triangles[tile.material_ids == other])
        assert (crossings % 2 == 0).all(), f"{int((crossings % 2).sum())} points inside the other threads"


@FAST
@given(
    spacing=st.floats(0.1, 10),
    warp_width=st.floats(0.05, 0.9998),
    weft_width=st.floats(0.05, 0.9998),
    warp_height=st.floats(1e-3, 2),
    weft_height=st.floats(1e-3, 2),
    segments=st.integers(3, 32),
)
def test_woven_valid_and_seamless(spacing, warp_width, weft_width, warp_height, weft_height, segments):
    s = spacing
    tile = make(
        woven,
        spacing=s,
        warp_width=warp_width * s,
        weft_width=weft_width * s,
        warp_height=warp_height * s,
        weft_height=weft_height * s,
        segments=segments,
        warp_material=4,
        weft_material=2,
        warp_color=(1, 0, 0),
        weft_color=(0, 0, 1),
    )
    check_tile(tile, "woven")
    assert tile.period == pytest.approx((2 * s, 2 * s))
    warp = tile.material_ids == 4
    assert set(np.unique(tile.material_ids)) == {2, 4}
    assert (tile.colors[warp] == (1, 0, 0)).all() and (tile.colors[~warp] == (0, 0, 1)).all()
    # Warp threads follow x and weft threads y, each filling the whole period along its direction.
    assert np.ptp(tile.vertices[tile.faces[warp]][..., 0]) == pytest.approx(2 * s)
    assert np.ptp(tile.vertices[tile.faces[~warp]][..., 1]) == pytest.approx(2 * s)
    # Closed tubes with outward normals: ∫ z n_z dA is the volume, 2 threads × length × polygon area.
    for mask, width, height in ((warp, warp_width, warp_height), (~warp, weft_width, weft_height)):
        poly = segments / 2 * (width * s / 2) * (height * s / 2) * math.sin(2 * math.pi / segments)
        assert volume(tile, mask) == pytest.approx(2 * 2 * s * poly, rel=1e-9)
    assert projected_signed(tile) == pytest.approx(0, abs=1e-9 * s * s)
    assert_threads_apart(tile, 4, 2, points=300)


def test_woven_half_area_each_when_threads_equal():
    tile = make(woven, warp_width=0.7, weft_width=0.7, warp_height=0.25, weft_height=0.25)
    warp = tile.material_ids == 0
    assert tile.face_areas[warp].sum() == pytest.approx(0.5 * tile.area, rel=1e-12)
    assert_threads_apart(tile)


@pytest.mark.parametrize("width", [0.5, 0.8, 0.95, 0.9998])
def test_woven_threads_do_not_interpenetrate(width):
    tile = make(woven, warp_width=width, weft_width=width, warp_height=0.3, weft_height=0.1, segments=24)
    assert_threads_apart(tile, seed=1)


def test_inside_test_sees_inside():
    tile = make(woven)
    warp = tile.triangles[tile.material_ids == 0]
    # Generic positions (off every grid line, where a vertical ray would graze shared edges).
    centres = np.array(
        [[x, 0.5137, z] for x, z in ((0.0123, 0.0), (0.5071, tile.z_range[1] - 0.1), (1.7, -0.05))]
    )
    assert (upward_crossings(centres, warp) % 2 == 1).all()


# ---------------------------------------------------------------------------------------------- heightfield


@FAST
@given(
    heights=st.tuples(st.integers(2, 10), st.integers(2, 10)).flatmap(
        lambda shape: arrays(np.float64, shape, elements=st.floats(-1, 1))
    ),
    size=st.floats(0.1, 10),
    scale=st.floats(-3, 3),
)
def test_heightfield_valid_and_seamless(heights, size, scale):
    tile = make(heightfield, heights, size=size, scale=scale, material=2, color=(0.2, 0.3, 0.4))
    check_tile(tile, "heightfield")
    check_height_field_like(tile)
    rows, cols = heights.shape
    assert len(tile.faces) == 2 * rows * cols
    assert (tile.material_ids == 2).all() and (tile.colors == (0.2, 0.3, 0.4)).all()
    # Every grid height appears at its grid point (row i -> y, column j -> x).
    v = tile.vertices
    i, j = (
        np.round(v[:, 1] / size * rows).astype(int) % rows,
        np.round(v[:, 0] / size * cols).astype(int) % cols,
    )
    np.testing.assert_allclose(v[:, 2], scale * heights[i, j], rtol=0, atol=1e-12)


@pytest.mark.parametrize("value", [0.0, 0.37, -2.0])
def test_constant_heightfield_is_flat(value):
    tile = make(heightfield, np.full((4, 6), value), size=3.0, scale=2.0)
    assert tile.area == pytest.approx(9.0, rel=1e-12)
    assert tile.z_range == (2 * value, 2 * value)
    assert (tile.face_normals[:, 2] == 1).all()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_heightfield_rejects_non_finite(bad):
    h = np.zeros((3, 3))
    h[1, 2] = bad
    with pytest.raises(ValueError, match="heights"):
        heightfield(h)


@pytest.mark.parametrize("bits", [8, 16])
def test_heightfield_from_image_round_trip(tmp_path, bits):
    rng = np.random.default_rng(bits)
    top = 255 if bits == 8 else 65535
    img = rng.integers(0, top + 1, size=(6, 9)).astype(np.uint8 if bits == 8 else np.uint16)
    path = tmp_path / f"h{bits}.png"
    Image.fromarray(img).save(path)
    tile = make(heightfield_from_image, path, size=2.0, scale=0.5)
    want = heightfield(
        img[::-1] / top, size=2.0, scale=0.5
    )  # the image is seen from above: top row at y = size
    np.testing.assert_allclose(tile.vertices, want.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(tile.faces, want.faces)
    assert tile.name.startswith("heightfield") and path.name in tile.name
    assert tile.z_range[1] <= 0.5


def test_heightfield_from_colour_image(tmp_path):
    path = tmp_path / "rgb.png"
    Image.fromarray(np.full((4, 4, 3), 255, np.uint8)).save(path)
    tile = make(heightfield_from_image, path, scale=0.25)
    assert tile.z_range == pytest.approx((0.25, 0.25))


def test_heightfield_from_image_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.png"):
        heightfield_from_image(tmp_path / "missing.png")
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"this is not an image")
    with pytest.raises(ValueError, match="junk.png"):
        heightfield_from_image(junk)
    tiny = tmp_path / "tiny.png"
    Image.fromarray(np.zeros((1, 5), np.uint8)).save(tiny)
    with pytest.raises(ValueError, match=r"^height image .*tiny.png: heightfield: heights must be a 2-D array"):
        heightfield_from_image(tiny)  # (the file named: the message came without it)
    holed = tmp_path / "holed.tiff"
    Image.fromarray(np.array([[0.0, np.nan], [0.5, 1.0]], np.float32), mode="F").save(holed)
    with pytest.raises(ValueError, match=r"^height image .*holed.tiff: .*NaN"):
        heightfield_from_image(holed)


# --------------------------------------------------------------------------------------- invalid parameters

INVALID = [
    (flat, dict(size=0), "size"),
    (flat, dict(size=float("nan")), "size"),
    (flat, dict(size="1"), "size"),
    (flat, dict(material=-1), "material"),
    (flat, dict(material=1.5), "material"),
    (flat, dict(color=(1, 1)), "color"),
    (flat, dict(color=(1, -1, 1)), "color"),
    (pyramid, dict(height=0), "height"),
    (pyramid, dict(height=-1.0), "height"),
    (pyramid, dict(sides=2), "sides"),
    (pyramid, dict(sides=4.0), "sides"),
    (pyramid, dict(base_fraction=0), "base_fraction"),
    (pyramid, dict(base_fraction=1.5), "base_fraction"),
    (pyramid, dict(base_fraction=1.2, sides=3), "base_fraction"),
    (pyramid, dict(rotation=float("inf")), "rotation"),
    (pyramid, dict(size=-1), "size"),
    (pyramid, dict(base_material=-2), "base_material"),
    (pyramid, dict(base_color="red"), "base_color"),
    (pyramid, dict(height=1e6, base_fraction=0.01, sides=64), "base edges"),
    (grooves, dict(depth=0), "depth"),
    (grooves, dict(width=-1), "width"),
    (grooves, dict(profile="w"), "profile"),
    (grooves, dict(flat_fraction=1.0), "flat_fraction"),
    (grooves, dict(flat_fraction=-0.1), "flat_fraction"),
    (grooves, dict(axis="z"), "axis"),
    (grooves, dict(segments=1), "segments"),
    (grooves, dict(wall_material=1.5), "wall_material"),
    (grooves, dict(wall_color=(1, 1, float("nan"))), "wall_color"),
    (rods, dict(radius=0.3, spacing=0.5), "radius"),
    (rods, dict(radius=0), "radius"),
    (rods, dict(spacing=0), "spacing"),
    (rods, dict(length=0), "length"),
    (rods, dict(count=0), "count"),
    (rods, dict(count=2.0), "count"),
    (rods, dict(perturbation=-0.1), "perturbation"),
    (rods, dict(perturbation=2.0), "perturbation"),
    (rods, dict(orientation=(1.6, 0.0)), "orientation"),
    (rods, dict(orientation=(1.2, 0.0)), "orientation"),
    (rods, dict(orientation=1.0), "orientation"),
    (rods, dict(seed=1.5), "seed"),
    (rods, dict(seed=-1), "seed"),
    (relief, dict(seed=-1), "seed"),
    (relief, dict(amplitude=float("nan")), "relief: amplitude"),
    (relief, dict(amplitude=1e9), "relief(amplitude=1e+09): heightfield: shape=(64, 64)"),
    (rods, dict(segments=2), "segments"),
    (rods, dict(ground="yes"), "ground"),
    (rods, dict(ground_material=-1), "ground_material"),
    (woven, dict(warp_width=1.0), "warp_width"),
    (woven, dict(weft_width=0), "weft_width"),
    (woven, dict(warp_height=0), "warp_height"),
    (woven, dict(weft_height=1e-6), "weft_height"),
    (woven, dict(spacing=-1), "spacing"),
    (woven, dict(segments=2), "segments"),
    (woven, dict(weft_material=-1), "weft_material"),
    (woven, dict(warp_color=(0, 0)), "warp_color"),
]


@pytest.mark.parametrize(
    "fn, kw, name", INVALID, ids=[f"{f.__name__}-{n}-{i}" for i, (f, _, n) in enumerate(INVALID)]
)
def test_invalid_parameters_raise_naming_them(fn, kw, name):
    with pytest.raises(ValueError) as info:
        fn(**kw)
    msg = str(info.value)
    assert name in msg
    value = kw.get(name)
    if isinstance(value, str):
        assert repr(value) in msg
    elif isinstance(value, (int, float)) and math.isfinite(value):
        assert repr(value) in msg or f"{value:g}" in msg


@pytest.mark.parametrize(
    "heights, what",
    [
        (np.zeros((1, 5)), "2x2"),
        (np.zeros(4), "2x2"),
        (np.zeros((2, 2, 2)), "2x2"),
        ("abc", "heights"),
        ([[0, 1], [2, float("nan")]], "NaN"),
    ],
)
def test_heightfield_rejects_bad_arrays(heights, what):
    with pytest.raises(ValueError, match="heights") as info:
        heightfield(heights)
    assert what in str(info.value)


def test_heightfield_rejects_bad_scalars():
    with pytest.raises(ValueError, match="size"):
        heightfield(np.zeros((2, 2)), size=0)
    with pytest.raises(ValueError, match="scale"):
        heightfield(np.zeros((2, 2)), scale=float("nan"))


def test_parameters_are_keyword_only():
    with pytest.raises(TypeError):
        pyramid(0.5)


# ------------------------------------------------------------------------------------------ file round trip

TILES = st.one_of(
    st.builds(lambda h, n: pyramid(height=h, sides=n), st.floats(0.05, 2), st.integers(3, 8)),
    st.builds(
        lambda d, p, f: grooves(depth=d, profile=p, flat_fraction=f),
        st.floats(0.05, 2),
        st.sampled_from(["v", "u"]),
        st.floats(0, 0.9),
    ),
    st.builds(
        lambda p, seed, g: rods(perturbation=p, seed=seed, ground=g, count=2),
        st.floats(0, 1),
        st.integers(0, 100),
        st.booleans(),
    ),
    st.builds(
        lambda w, h: woven(warp_width=w, warp_height=h, segments=8),
        st.floats(0.2, 0.95),
        st.floats(0.05, 0.5),
    ),
    st.builds(lambda a: heightfield(a), arrays(np.float64, (4, 5), elements=st.floats(-1, 1))),
)


@FAST
@given(tile=TILES, fmt=st.sampled_from(["obj", "ply", "stl"]))
def test_load_round_trip(tmp_path_factory, tile, fmt):
    path = tmp_path_factory.mktemp("rt") / f"tile.{fmt}"
    trimesh.Trimesh(tile.vertices, tile.faces, process=False).export(path)
    with warnings.catch_warnings():
        warnings.simplefilter(
            "ignore", TileWarning
        )  # STL stores every corner: SmallScale merges them, saying so
        back = SmallScale.load(path, period=tile.period)
    assert back.area == pytest.approx(tile.area, rel=1e-6)
    scale = float(np.ptp(tile.vertices, axis=0).max())
    np.testing.assert_allclose(back.vertices.min(0), tile.vertices.min(0), rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose(back.vertices.max(0), tile.vertices.max(0), rtol=0, atol=1e-6 * scale)
    assert len(back.faces) == len(tile.faces)
    assert back.period == tile.period


def test_weld_components_as_scipy():
    """The union-find that joins a few near-coincident corners labels the components as scipy's connected_components
    (numbered by their lowest vertex), on random graphs below and above its pair count."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from warp_biscale.geometry_mesh import _components

    rng = np.random.default_rng(7)
    for n, p in [(2, 1), (5, 3), (40, 25), (60, 80), (3000, 250)]:  # (up to 256 pairs: the union-find)
        pairs = rng.integers(0, n, (p, 2))
        pairs = pairs[pairs[:, 0] != pairs[:, 1]]
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        np.testing.assert_array_equal(_components(n, pairs), connected_components(graph, directed=False)[1])


def test_merge_duplicates_as_numpy_unique():
    """SmallScale's duplicate merge (rows sorted by lexsort) keeps the same vertices in the same order and maps the
    faces as np.unique(axis=0, return_index=True, return_inverse=True) does."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        v = rng.integers(-2, 3, (int(rng.integers(4, 40)), 3)).astype(float) * 0.5
        f = rng.integers(0, len(v), (12, 3))
        key = np.round(v / (np.ptp(v, axis=0).max() * 1e-9)).astype(np.int64)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TileWarning)
            v2, f2, _ = SmallScale._merge_duplicates(v, f, None)
        np.testing.assert_array_equal(v2, v[first] if len(first) < len(v) else v)
        np.testing.assert_array_equal(f2, inverse.reshape(-1)[f] if len(first) < len(v) else f)


def test_tile_names_of_the_command_line_and_scene_files(tmp_path):
    """`load_tile` (the command line's and scene files' TILE) takes every family name the README and the
    editor use — grooves and heightfield too — and a greyscale image as a height field; anything else is a
    one-line error naming what it takes."""
    from warp_biscale import editor, geometry

    for name, (fn, kwargs) in geometry.BUILTIN_TILES.items():
        tile = geometry.load_tile(name)
        want = getattr(geometry, fn)(**kwargs)
        np.testing.assert_array_equal(tile.vertices, want.vertices)
    relief = geometry.load_tile("heightfield")
    np.testing.assert_array_equal(relief.vertices, heightfield(geometry.relief_heights(), scale=0.15).vertices)
    # the editor starts from the same relief
    np.testing.assert_array_equal(editor.Editor("heightfield", backend="warp:cpu", width=16, height=16).heights,
                                  geometry.relief_heights(editor.HEIGHTS))
    path = tmp_path / "bumps.png"
    Image.fromarray((np.random.default_rng(0).random((8, 8)) * 255).astype(np.uint8)).save(path)
    np.testing.assert_array_equal(geometry.load_tile(str(path)).vertices, heightfield_from_image(path).vertices)
    with pytest.raises(ValueError, match="neither a mesh file, a height-field image nor a built-in tile .*grooves"):
        geometry.load_tile("groove")
    # a path is a missing file, not a misspelt tile name; a GIF is an image like the others
    with pytest.raises(FileNotFoundError, match=r"^no such tile file: .*missing.obj$"):
        geometry.load_tile(str(tmp_path / "missing.obj"))
    os.symlink(tmp_path / "gone.obj", tmp_path / "link.obj")
    with pytest.raises(FileNotFoundError, match=r"link.obj' is a broken link \(to '.*gone.obj'\)$"):
        geometry.load_tile(str(tmp_path / "link.obj"))
    Image.open(path).save(tmp_path / "bumps.gif")
    np.testing.assert_array_equal(geometry.load_tile(str(tmp_path / "bumps.gif")).vertices,
                                  heightfield_from_image(path).vertices)
