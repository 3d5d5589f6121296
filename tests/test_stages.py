"""Every stage kernel against the float64 reference, on every backend present.

Tolerances, and why:
- facet positions 2e-6 (tile size 1): float32 rounding of a barycentric combination of float32
  vertices (~3 ulp of 1.0); face indices identical (both search the float64 cumulative area).
- visibility bits: the kernels trace in float32, the reference in float64, so a ray grazing an
  occluder's edge within float32 rounding may differ (measured: 1 bit in 590 000 on a
  1152-triangle height field); we allow 1 in 20 000.
- a_v and f̄ are compared with the reference *given the kernel's own bits*, so the comparison
  measures the summation and BRDF arithmetic alone: relative 2e-4 (float32 BRDF evaluation, e.g.
  (n·h)^512 amplifies a 6e-8 rounding of n·h by 512, plus blocked float32 partial sums).
"""

import numpy as np
import pytest
from conftest import random_heightfield, vgroove_tile

import warp_biscale as wb
from warp_biscale import reference as ref
from warp_biscale.brdf import pack_materials

MATERIALS = [
    wb.Lambert((0.2, 0.5, 0.8)),
    wb.BlinnPhong(ks=(1.0, 0.8, 0.6), exponent=512, kd=0.1),
    wb.CookTorrance(ks=0.9, roughness=0.2, f0=0.04, kd=(0.1, 0.2, 0.3)),
    wb.Ward(ks=0.7, alpha=0.15, kd=0.05),
]


def _ref_facets(fac):
    return fac.as_dict()


def test_facets_match_reference(backend, heightfield):
    fac = backend.sample_facets(heightfield, 3000, seed=7)
    r = ref.sample_facets(heightfield, 3000, seed=7)
    np.testing.assert_array_equal(fac.face, r["face"])
    np.testing.assert_allclose(fac.position, r["position"], atol=2e-6)
    np.testing.assert_allclose(fac.normal, r["normal"], atol=2e-6)
    np.testing.assert_allclose(fac.area.sum(), heightfield.area, rtol=1e-6)
    np.testing.assert_array_equal(fac.material, heightfield.material_ids[r["face"]])


def test_facets_deterministic_and_seeded(backend, heightfield):
    a = backend.sample_facets(heightfield, 1000, seed=3)
    b = backend.sample_facets(heightfield, 1000, seed=3)
    c = backend.sample_facets(heightfield, 1000, seed=4)
    np.testing.assert_array_equal(a.position, b.position)
    assert np.abs(a.position - c.position).max() > 1e-3


def test_facets_interpolate_vertex_normals(backend):
    # A curved cap: vertex normals point radially, so facet normals vary inside each face.
    tile = random_heightfield(n=4, seed=5)
    vn = tile.vertices - np.array([0.5, 0.5, -1.0])
    tile = wb.SmallScale(tile.vertices, tile.faces, vertex_normals=vn)
    fac = backend.sample_facets(tile, 2000, seed=1)
    r = ref.sample_facets(tile, 2000, seed=1)
    np.testing.assert_allclose(fac.normal, r["normal"], atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(fac.normal, axis=1), 1.0, atol=1e-6)
    # Not face normals: the interpolation really happened.
    assert np.abs(fac.normal - tile.face_normals[fac.face]).max() > 1e-2


def _bits_agree(a, b, what):
    mism = int((a != b).sum())
    assert mism <= max(2, a.size // 20000), f"{what}: {mism} of {a.size} visibility bits differ"
    return mism


@pytest.mark.parametrize("brute_force", [False, True], ids=["bvh", "brute"])
def test_visibility_matches_reference(backend, heightfield, brute_force):
    fac = backend.sample_facets(heightfield, 1500, seed=2)
    dirs = wb.directions.grid(8)
    vis = backend.visibility(heightfield, fac, dirs, brute_force=brute_force)
    vr = ref.visibility(heightfield, _ref_facets(fac), dirs)
    _bits_agree(vis.as_bool(), vr, f"{backend.name} {'brute' if brute_force else 'bvh'}")
    # The test is not vacuous: this tile shadows a real fraction of the rays.
    assert 0.05 < 1 - vr.mean() < 0.95


def test_bvh_traversal_agrees_with_brute_force(backend):
    tile = random_heightfield(n=24, amplitude=0.6, seed=11)  # 1152 triangles: a real BVH
    fac = backend.sample_facets(tile, 4096, seed=0)
    dirs = wb.directions.grid(12)
    bvh = backend.visibility(tile, fac, dirs).as_bool()
    brute = backend.visibility(tile, fac, dirs, brute_force=True).as_bool()
    _bits_agree(bvh, brute, backend.name)


def test_visibility_grazing_many_wraps(backend):
    # Tall, narrow tile: a ray 2° above the horizon crosses ~50 periods before leaving.
    tile = random_heightfield(n=4, amplitude=2.0, seed=3)
    fac = backend.sample_facets(tile, 256, seed=0)
    el = np.radians([2.0, 5.0, 10.0])
    dirs = np.stack([np.cos(el) * np.cos(0.3), np.cos(el) * np.sin(0.3), np.sin(el)], 1)
    vis = backend.visibility(tile, fac, dirs).as_bool()
    vr = ref.visibility(tile, _ref_facets(fac), dirs)
    _bits_agree(vis, vr, "grazing")


def test_visibility_flat_tile_sees_everything(backend, flat):
    fac = backend.sample_facets(flat, 500, seed=0)
    dirs = wb.directions.grid(12)
    assert backend.visibility(flat, fac, dirs).as_bool().all()
    assert backend.visibility(flat, fac, dirs, brute_force=True).as_bool().all()
    # Below the horizon nothing is visible.
    down = np.array([[0.3, 0.1, -0.9], [1.0, 0.0, 0.0]])
    down /= np.linalg.norm(down, axis=1, keepdims=True)
    assert not backend.visibility(flat, fac, down).as_bool().any()


def test_visibility_fully_shadowed_direction(backend):
    # Deep V-groove (depth 4, width 1): at 60° across the groove only the rims see the light.
    tile = vgroove_tile(depth=4.0)
    fac = backend.sample_facets(tile, 2000, seed=0)
    t = np.radians(60)
    dirs = np.array([[np.sin(t), 0.0, np.cos(t)], [0.0, np.sin(t), np.cos(t)]])
    vis = backend.visibility(tile, fac, dirs).as_bool()
    vr = ref.visibility(tile, _ref_facets(fac), dirs)
    _bits_agree(vis, vr, "deep groove")
    assert vis[0].mean() < 0.15  # mostly shadowed across the groove
    # Along the groove a wall point sees the sky iff the direction is above its own plane.
    assert vis[1].mean() > 0.99


def test_visible_area_matches_reference(backend, heightfield):
    fac = backend.sample_facets(heightfield, 4000, seed=1)
    dirs = wb.directions.grid(6)
    vis = backend.visibility(heightfield, fac, dirs)
    a_v = backend.visible_area(fac, vis)
    expected = ref.visible_area(_ref_facets(fac), vis.as_bool(), dirs)
    np.testing.assert_allclose(a_v, expected, rtol=2e-4)
    # A height field's visible projected area is its footprint times cos θ (up to sampling error).
    np.testing.assert_allclose(a_v, heightfield.footprint * dirs[:, 2], rtol=0.02)


@pytest.mark.parametrize("mat", MATERIALS, ids=lambda m: type(m).__name__)
def test_effective_brdf_matches_reference(backend, heightfield, mat):
    fac = backend.sample_facets(heightfield, 2048, seed=5)
    dirs = wb.directions.grid(5)
    vis = backend.visibility(heightfield, fac, dirs)
    a_v = backend.visible_area(fac, vis)
    kinds, params = pack_materials([mat])
    nd = len(dirs)
    pi, po = wb.directions.all_pairs(nd)
    f = backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v)
    expected = ref.effective_brdf(_ref_facets(fac), vis.as_bool(), dirs, kinds, params, pi, po)
    np.testing.assert_allclose(f, expected, rtol=2e-4, atol=2e-4 * expected.max())
    assert expected.max() > 0


def test_effective_brdf_several_materials_and_colours(backend):
    tile = random_heightfield(n=8, seed=9, materials=3)
    fac = backend.sample_facets(tile, 3000, seed=2)
    dirs = wb.directions.grid(4)
    vis = backend.visibility(tile, fac, dirs)
    a_v = backend.visible_area(fac, vis)
    kinds, params = pack_materials(MATERIALS[:3], tile.n_materials)
    nd = len(dirs)
    pi, po = wb.directions.all_pairs(nd)
    f = backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v)
    expected = ref.effective_brdf(_ref_facets(fac), vis.as_bool(), dirs, kinds, params, pi, po)
    np.testing.assert_allclose(f, expected, rtol=2e-4, atol=2e-4 * expected.max())


def test_brdf_kernel_matches_reference_at_hard_angles(backend):
    """Every BRDF at grazing, normal and back-facing configurations, through the kernel path."""
    tile = vgroove_tile(depth=0.01)  # almost flat: nearly every facet visible, two normals
    fac = backend.sample_facets(tile, 256, seed=0)
    el = np.radians([0.5, 1, 5, 30, 60, 89.5])
    az = np.radians([0, 90, 180, 270])
    e, a = np.meshgrid(el, az)
    dirs = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    vis = backend.visibility(tile, fac, dirs)
    a_v = backend.visible_area(fac, vis)
    nd = len(dirs)
    pi, po = wb.directions.all_pairs(nd)
    for mat in MATERIALS:
        kinds, params = pack_materials([mat])
        f = backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v)
        assert np.all(np.isfinite(f)) and (f >= 0).all()
        expected = ref.effective_brdf(_ref_facets(fac), vis.as_bool(), dirs, kinds, params, pi, po)
        np.testing.assert_allclose(f, expected, rtol=2e-4, atol=2e-4 * expected.max(), err_msg=repr(mat))


def test_tile_far_from_origin(backend):
    """A tile modelled at (1000, -1000, 100): float32 world coordinates would round by ~6e-5, more
    than the ray offset; the backends trace in the tile's local frame and must still agree."""
    base = random_heightfield(n=8, seed=6)
    shift = np.array([1000.0, -1000.0, 100.0])
    tile = wb.SmallScale(base.vertices + shift, base.faces)
    fac = backend.sample_facets(tile, 3000, seed=1)
    r = ref.sample_facets(tile, 3000, seed=1)
    np.testing.assert_allclose(fac.position, r["position"], atol=1e-4)  # float32 of values ~1000
    dirs = wb.directions.grid(8)
    vis = backend.visibility(tile, fac, dirs).as_bool()
    vr = ref.visibility(tile, r, dirs)
    _bits_agree(vis, vr, "far tile")
    # And the same bits as the tile at the origin (same local geometry, same facets).
    near = backend.visibility(base, backend.sample_facets(base, 3000, seed=1), dirs).as_bool()
    _bits_agree(vis, near, "far vs near")
