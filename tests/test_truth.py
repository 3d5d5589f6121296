"""The ground-truth driver against closed forms, bounds and hard cases, on every backend present."""

import numpy as np
import pytest
from conftest import flat_tile, random_heightfield, vgroove_tile

import warp_biscale as wb
from warp_biscale import reference as ref
from warp_biscale.brdf import pack_materials


def _pairs(grid):
    pi, po = wb.directions.all_pairs(len(grid))
    return grid[pi], grid[po]


def test_flat_lambertian_is_kd_over_pi_cos(backend):
    """The first test of every method: f̄ = (kd/π)·cos θi exactly (up to float32)."""
    kd = np.array([0.2, 0.5, 0.9])
    gt = wb.ground_truth(flat_tile(), wb.Lambert(kd), facets=2048, directions=8, backend=backend)
    g = gt.grid
    expected = kd[None, None, :] / np.pi * g[:, None, None, 2]
    np.testing.assert_allclose(gt.table, np.broadcast_to(expected, gt.table.shape), rtol=1e-5, atol=1e-7)
    # Interpolated anywhere, including off-grid and near the horizon.
    rng = np.random.default_rng(0)
    wi = wb.directions.square_to_hemisphere(rng.random((500, 2)))
    wo = wb.directions.square_to_hemisphere(rng.random((500, 2)))
    np.testing.assert_allclose(gt.eval(wi, wo), kd / np.pi * wi[:, 2:3], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(gt.albedo(), np.broadcast_to(kd, (64, 3)), rtol=1e-5)


@pytest.mark.parametrize("mat", [wb.Lambert(0.7), wb.BlinnPhong(1.0, 64, kd=0.1),
                                 wb.CookTorrance(1.0, 0.2, 0.1), wb.Ward(1.0, 0.25)],
                         ids=lambda m: type(m).__name__)
def test_vgroove_matches_closed_form(backend, mat):
    """Two planes with shadowing and masking by the opposite wall (reference.vgroove_effective_brdf).

    Tolerance: with 2^16 stratified facets the measured RMS error is ~1e-4 of the mean and the
    largest ~1e-3 of the peak (sampling error of the visibility boundary on each wall); 5e-3 of
    the peak leaves margin for float32 and for other backends' rounding.
    """
    depth = 0.5
    tile = vgroove_tile(depth=depth)
    gt = wb.ground_truth(tile, mat, facets=1 << 16, directions=8, backend=backend)
    wi, wo = _pairs(gt.grid)
    kinds, params = pack_materials([mat])
    cf = ref.vgroove_effective_brdf(depth, 1.0, kinds, params, wi, wo).reshape(gt.table.shape)
    err = np.abs(gt.table - cf)
    assert err.max() <= 5e-3 * cf.max(), f"max error {err.max():.3g} vs peak {cf.max():.3g}"
    assert np.sqrt((err**2).mean()) <= 1e-3 * cf.mean()
    # Shadowing matters here: the closed form without it would be far off.
    assert (cf == 0).sum() < cf.size


def test_vgroove_closed_form_a_v_is_footprint_cos():
    """The closed form's denominator equals the footprint's projected area (checks the derivation)."""
    grid = wb.directions.grid(12)
    kinds, params = pack_materials([wb.Lambert(1.0)])
    # With a Lambertian wall f̄ sums to cos θi-weighted visible fractions; a_v is checked via the
    # ratio of two evaluations that share ωo: f̄(ωi=ωo) · a_v / (cos² term) is tested by the driver.
    tile = vgroove_tile(depth=0.5)
    r = ref.sample_facets(tile, 20000, seed=0)
    vis = ref.visibility(tile, r, grid)
    a_v = ref.visible_area(r, vis, grid)
    np.testing.assert_allclose(a_v, tile.footprint * grid[:, 2], rtol=2e-3)
    f = ref.vgroove_effective_brdf(0.5, 1.0, kinds, params, grid, grid)
    assert np.all(np.isfinite(f)) and (f >= 0).all()


def test_bounds_nonnegative_and_energy(backend):
    tile = random_heightfield(n=8, amplitude=0.5, seed=2)
    kd = 0.8
    gt = wb.ground_truth(tile, wb.Lambert(kd), facets=1 << 13, directions=8, backend=backend)
    assert (gt.table >= 0).all() and np.isfinite(gt.table).all()
    # Shadowed Lambertian facets reflect at most kd of what reaches them (1 % quadrature margin).
    assert gt.albedo().max() <= kd * 1.01
    assert gt.albedo().min() > 0.2  # and the test is not vacuous


def test_effective_brdf_exact_matches_grid_table(backend):
    """A driver test, not a kernel test (the kernels are checked against the reference in
    test_stages): arbitrary pairs, deduplicated directions and their index bookkeeping must give
    exactly the grid table's numbers."""
    tile = random_heightfield(n=6, seed=4)
    mat = wb.BlinnPhong(1.0, 32, kd=0.2)
    gt = wb.ground_truth(tile, mat, facets=4096, directions=6, backend=backend, seed=3)
    wi, wo = _pairs(gt.grid)
    sel = np.arange(0, len(wi), 7)
    f = wb.effective_brdf_exact(tile, mat, wi[sel], wo[sel], facets=4096, backend=backend, seed=3)
    np.testing.assert_allclose(f, gt.table.reshape(-1, 3)[sel], rtol=1e-5, atol=1e-7)


def test_effective_brdf_exact_below_horizon_is_zero(backend, vgroove):
    wi = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, -0.5], [0.0, 0.3, 0.7]])
    wo = np.array([[0.5, 0.0, -0.5], [0.0, 0.0, 1.0], [0.0, -0.3, 0.7]])
    f = wb.effective_brdf_exact(vgroove, wb.Lambert(0.5), wi, wo, facets=1024, backend=backend)
    assert (f[:2] == 0).all() and (f[2] > 0).all()


def test_non_periodic_tile_warns_and_works(backend):
    # A ramp: z rises along x, so the edges x=0 and x=1 do not match.
    v = np.array([[0, 0, 0], [1, 0, 0.3], [1, 1, 0.3], [0, 1, 0]], float)
    with pytest.warns(wb.TileWarning, match="do not match"):
        tile = wb.SmallScale(v, np.array([[0, 1, 2], [0, 2, 3]]))
    gt = wb.ground_truth(tile, wb.Lambert(0.5), facets=1024, directions=6, backend=backend)
    assert np.isfinite(gt.table).all() and (gt.table >= 0).all() and gt.table.max() > 0


def test_save_load_round_trip(tmp_path, vgroove):
    gt = wb.ground_truth(vgroove, wb.Lambert(0.5), facets=1024, directions=4, backend="warp:cpu")
    path = tmp_path / "t.npz"
    gt.save(path)
    back = wb.load(path)
    np.testing.assert_array_equal(back.table, gt.table)
    assert back.directions == 4 and back.facets == 1024 and back.tile == "vgroove"
    w = wb.directions.grid(4)
    np.testing.assert_allclose(back.eval(w, w[::-1]), gt.eval(w, w[::-1]))


def test_load_rejects_bad_files(tmp_path, vgroove):
    gt = wb.ground_truth(vgroove, wb.Lambert(0.5), facets=256, directions=3, backend="warp:cpu")
    good = tmp_path / "good.npz"
    gt.save(good)
    data = good.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated or corrupt"):
        wb.load(tmp_path / "trunc.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError, match="truncated or corrupt"):
        wb.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "foreign.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a warp_biscale file"):
        wb.load(tmp_path / "foreign.npz")
    from warp_biscale.io import save_npz

    save_npz(tmp_path / "future.npz", "ground_truth", 99, {}, {"table": np.zeros(1)})
    with pytest.raises(ValueError, match="version 99"):
        wb.load(tmp_path / "future.npz")
    with pytest.raises(FileNotFoundError):
        wb.load(tmp_path / "missing.npz")


def test_failed_save_keeps_old_file(tmp_path, vgroove, monkeypatch):
    gt = wb.ground_truth(vgroove, wb.Lambert(0.5), facets=256, directions=3, backend="warp:cpu")
    path = tmp_path / "t.npz"
    gt.save(path)
    before = path.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError, match="disk full"):
        gt.save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.npz"]  # no temporary left behind


@pytest.mark.parametrize("bad, match", [
    (dict(facets=0), "facets"),
    (dict(facets=2.5), "facets"),
    (dict(directions=1), "directions"),
    (dict(backend="vulkan"), "unknown backend"),
    (dict(materials=[]), "materials is empty"),
    (dict(materials=["lambert"]), r"materials\[0\]"),
])
def test_ground_truth_rejects_bad_arguments(vgroove, bad, match):
    kwargs = dict(materials=wb.Lambert(0.5), facets=256, directions=4, backend="warp:cpu")
    kwargs.update(bad)
    with pytest.raises(ValueError, match=match):
        wb.ground_truth(vgroove, **kwargs)


def test_missing_material_for_id_is_named():
    tile = random_heightfield(n=4, materials=3, seed=1)
    with pytest.raises(ValueError, match="material ids 0..2 but only 1"):
        wb.ground_truth(tile, wb.Lambert(0.5), facets=256, directions=4, backend="warp:cpu")


def test_nan_directions_rejected(vgroove):
    wi = np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0]])
    with pytest.raises(ValueError, match="wi contains NaN"):
        wb.effective_brdf_exact(vgroove, wb.Lambert(0.5), wi, wi, facets=64, backend="warp:cpu")
    with pytest.raises(ValueError, match="same length"):
        wb.effective_brdf_exact(vgroove, wb.Lambert(0.5), wi[:1], wi[:1].repeat(2, 0), facets=64,
                                backend="warp:cpu")


def test_saved_files_get_ordinary_permissions(tmp_path, vgroove):
    import os
    import stat

    gt = wb.ground_truth(vgroove, wb.Lambert(0.5), facets=256, directions=3, backend="warp:cpu")
    gt.save(tmp_path / "t.npz")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(os.stat(tmp_path / "t.npz").st_mode) == 0o666 & ~umask
