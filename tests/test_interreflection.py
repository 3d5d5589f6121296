"""Small-scale interreflection: wb.ground_truth(..., bounces=B) (docs/design.md §4.6), on every backend present.

The bounces 2..B are a Monte Carlo estimate whose random numbers are a hash of (seed, path, ωo, dimension),
the same in the kernels and in the float64 oracle `reference.interreflection`: the kernels are compared with
the oracle path for path, so their difference is float32 rounding, not sampling noise.
"""

import numpy as np
import pytest
from conftest import random_heightfield, vgroove_tile

import warp_biscale as wb
from warp_biscale import reference as ref
from warp_biscale.brdf import AnisotropicWard, pack_materials


def test_one_bounce_is_the_existing_truth(backend):
    """bounces=1 (the default) is today's ground truth bit for bit: the same code path, nothing added."""
    tile = random_heightfield(n=6, amplitude=0.5, seed=3, materials=2)
    mats = [wb.Lambert(0.8), wb.CookTorrance(0.6, 0.2, 0.1, kd=0.2)]
    plain = wb.ground_truth(tile, mats, facets=2048, directions=6, backend=backend)
    one = wb.ground_truth(tile, mats, facets=2048, directions=6, backend=backend, bounces=1, paths=7)
    np.testing.assert_array_equal(one.table, plain.table)
    np.testing.assert_array_equal(one.a_v, plain.a_v)
    assert one.bounces == 1 and one.paths == 0 and "interreflection" not in one.timings


def test_white_furnace_vgroove(backend):
    """A closed Lambertian V-groove of albedo 1 (walls at 45°, depth 0.5, width 1) absorbs nothing: all
    the light that enters leaves, so its directional albedo ∫f̄ dωi → 1 for every ωo as B → ∞.

    Single bounce, closed form: where ωo sees both walls whole (|ωx| ≤ ωz here), the albedo is the walls'
    view factor to the opening, w/(2ℓ) = 1/√2 = 0.7071 (Hottel's crossed strings; ℓ the wall's length).
    Measured at K = 6, 2^14 facets, 8192 paths, seed 0 (warp:cpu and opencl:cpu to 4 digits): albedo mean
    over the 36 ωo 0.746 (B = 1), 0.922 (B = 2), 0.994 (B = 4), 1.004 (B = 16); median 0.707, 0.905, 0.988,
    1.000. Tolerances: the spread over ωo at B = 16 (0.958..1.057) is Monte Carlo noise — it shrank about as
    1/√paths from 256 paths (0.94..1.19) to 8192 — and the grid's quadrature; the mean and median average
    it down to 0.4 %, so 2 % is their bound."""
    tile = vgroove_tile(depth=0.5)
    alb = {}
    for b in (1, 2, 4, 16):
        gt = wb.ground_truth(tile, wb.Lambert(1.0), facets=1 << 14, directions=6, backend=backend, bounces=b,
                             paths=8192)
        assert np.isfinite(gt.table).all() and (gt.table >= 0).all()
        alb[b] = gt.albedo()[:, 0]
    g = wb.directions.grid(6)
    whole = np.abs(g[:, 0]) <= g[:, 2]
    np.testing.assert_allclose(alb[1][whole], 1 / np.sqrt(2), rtol=2e-3)
    means = [alb[b].mean() for b in (1, 2, 4, 16)]
    assert means[0] < means[1] < means[2] <= means[3], means
    assert means[1] > 0.9 and abs(means[3] - 1.0) < 0.02, means
    assert abs(np.median(alb[16]) - 1.0) < 0.02
    assert np.all(alb[16] >= alb[1]) and alb[16].min() > 0.9


def _oracle_case(tile, mats, b, paths, k=3, count=256, seed=5):
    kinds, params = pack_materials(mats, tile.n_materials, True)
    tangents = tile.face_tangents if any(m.anisotropic for m in mats) else None
    grid = wb.directions.grid(k)
    pi, po = wb.directions.all_pairs(len(grid))
    r = ref.sample_facets(tile, count, seed)
    vis = ref.visibility(tile, r, grid)
    want = ref.interreflection(tile, r, vis, grid, kinds, params, pi, po, b, paths, seed=seed, tangents=tangents)
    return want, (kinds, params, tangents, grid, pi, po, vis)


@pytest.mark.parametrize("case", ["vgroove-lambert", "vgroove-ward-anisotropic", "heightfield-two-materials"])
def test_kernels_match_float64_reference(backend, case):
    """The same estimator, the same random numbers: the kernels against reference.interreflection path for
    path. Tolerance 1e-4 of the peak (measured: ≤ 6.1e-7 of it on both CPU backends): float32 rounding of a path's few
    vertices, plus headroom for a rare path whose float32 ray passes an edge on the other side of the float64
    one (that would move one path's share, ~1/paths of the value, and would show as a failure here)."""
    if case.startswith("vgroove"):
        tile = vgroove_tile(depth=0.7)
        mats = [wb.Lambert(0.9)] if case == "vgroove-lambert" else [AnisotropicWard(0.5, 0.15, 0.4, kd=0.3)]
    else:
        tile = random_heightfield(n=4, amplitude=0.6, seed=4, materials=2)
        mats = [wb.Lambert([0.9, 0.7, 0.5]), wb.BlinnPhong(0.2, 20, kd=0.3)]
    b, paths, seed = 4, 64, 5
    want, (kinds, params, tangents, grid, pi, po, vis) = _oracle_case(tile, mats, b, paths, seed=seed)
    fac = backend.sample_facets(tile, 256, seed)
    v = backend.visibility(tile, fac, grid)
    a_v = backend.visible_area(fac, v)
    got = backend.interreflection(tile, fac, v, kinds, params, pi, po, a_v, b, paths, seed, tangents=tangents)
    assert want.max() > 0.01  # not vacuous
    err = np.abs(got - want)
    assert err.max() <= 1e-4 * want.max(), f"max error {err.max():.3g} vs peak {want.max():.3g}"


def test_driver_adds_the_bounces_to_the_one_bounce_table(backend):
    """ground_truth(bounces=B) = ground_truth() + the backend's interreflection term, and the oracle agrees."""
    tile = vgroove_tile(depth=0.7)
    mat = wb.Lambert(0.9)
    one = wb.ground_truth(tile, mat, facets=256, directions=3, backend=backend, seed=5)
    three = wb.ground_truth(tile, mat, facets=256, directions=3, backend=backend, seed=5, bounces=3, paths=64)
    want, _ = _oracle_case(tile, [mat], 3, 64)
    np.testing.assert_allclose(three.table - one.table, want.reshape(three.table.shape), atol=1e-4 * want.max())
    assert three.bounces == 3 and three.paths == 64 and three.timings["interreflection"] >= 0


def test_more_bounces_never_lose_energy(backend):
    """With the same seed, bounce b reuses the random numbers of bounces < b, so the B-bounce table is the
    (B − 1)-bounce table plus non-negative terms: never smaller, entry by entry. Glossy and coloured facets;
    every entry finite and ≥ 0."""
    tile = random_heightfield(n=4, amplitude=0.6, seed=4, materials=2)
    mats = [wb.Lambert([0.9, 0.7, 0.5]), wb.CookTorrance(0.7, 0.15, 0.2, kd=0.2)]
    prev = None
    for b in (1, 2, 3, 5):
        gt = wb.ground_truth(tile, mats, facets=1024, directions=4, backend=backend, bounces=b, paths=128)
        assert np.isfinite(gt.table).all() and (gt.table >= 0).all()
        if prev is not None:
            assert (gt.table >= prev).all()
            assert gt.table.sum() > prev.sum()
        prev = gt.table


@pytest.mark.parametrize("bounces", [0, 17, -1, 2.5, "2", True, None])
def test_bad_bounces(bounces):
    with pytest.raises(ValueError, match=r"^bounces must be an integer in \[1, 16\], got") as e:
        wb.ground_truth(vgroove_tile(), wb.Lambert(0.5), facets=64, directions=2, backend="warp:cpu",
                        bounces=bounces)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("paths", [0, 1 << 21, 3.0])
def test_bad_paths(paths):
    with pytest.raises(ValueError, match=r"^paths must be an integer in \[1, 1048576\], got"):
        wb.ground_truth(vgroove_tile(), wb.Lambert(0.5), facets=64, directions=2, backend="warp:cpu", bounces=2,
                        paths=paths)


def test_save_load_keeps_bounces(tmp_path):
    gt = wb.ground_truth(vgroove_tile(), wb.Lambert(0.5), facets=256, directions=3, backend="warp:cpu", bounces=2,
                         paths=16)
    gt.save(tmp_path / "gt.npz")
    back = wb.GroundTruth.load(tmp_path / "gt.npz")
    assert (back.bounces, back.paths) == (2, 16) and "bounces=2" in repr(back)
    np.testing.assert_array_equal(back.table, gt.table)
