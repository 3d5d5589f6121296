"""The matrix method (Wu 2011 §3.4–§3.7, `warp_biscale.matrix`): M, the random-projection SVD, Eq. 12, the
sampling-rate search, the factor cache, and the method end to end on closed-form and one-normal-per-bin tiles.

Tolerances, each measured here (numpy 2, float64) and given headroom:

- M against the BRDFs' own evaluation (`Brdf.eval` × the two cosines, `brdf_cosine_weighted`): the same
  formulas, the cosines as matrix products instead of row dots; measured ≤ 1e-14 of the largest entry
  (Blinn–Phong n = 64 amplifies a rounding of n·h 64-fold) → 1e-12.
- Reciprocity: M over (i, o) against (o, i): measured ≤ 3e-16 of the largest entry → 1e-13.
- Random-projection SVD against LAPACK (`numpy.linalg.svd`), rank 20, 10 oversampling columns, two power
  iterations: on a 300×200 matrix with singular values 0.8^i the top 20 singular values come to 6e-12 and the
  reconstruction error to 4e-12 above Eckart–Young's optimum (measured) → 1e-8; on a real M (CT m = 0.3,
  289 × 136), whose spectrum decays slowly past rank 10, the top 10 to 2.2e-6, all 20 to 5.2e-4 and the
  error to 1.4e-4 above the optimum → 1e-5, 2e-3, 1e-3 (SVD_TOLERANCES). With no power iteration (Wu Table 2
  as printed) the error is 5 % (spectrum) and 26 % (M) above the optimum: why the default takes two.
- Reconstruction error against rank: for an SVD, ‖A − A_r‖² = total power − Σ_{i≤r} s_i² exactly; the
  randomized SVD's is measured within 1e-10 of the total power → 1e-8, and non-increasing to 1e-12.
- Eq. 12 with every singular value kept against the direct product N·M: float64 rounding, measured
  ≤ 2e-15 of the largest value → 1e-12.
- The flat Lambertian tile: f̄ = (kd/π)cos θi. The bake's N (float32 sums) and the ground truth (float32
  kernels) agree to ~1e-7 of the peak; the octahedral map puts +z on a texel centre, so M's row there is
  exact; with all of M's power kept the matrix f̄ is within 4e-7 of the peak (measured) → 1e-5. Wu's 98 %
  of M's power is a real loss here (measured on both CPU backends: 27.2 dB, the largest error 18 % of the
  peak, at grazing ωo where f̄ divides M's error by a_v ∝ cos θo; 99.9 %: 32.6 dB, 12 %) → > 25 dB and
  < 25 %, falling as power is kept.
- The pyramid (every bin holds one normal): N·M with M at the bins' normals is the ground truth's sum over
  the same facets grouped by bin, measured within 5.1e-7 of the peak on both CPU backends (float32 kernels)
  → 1e-5; Eq. 12 from the full-rank factors (N's stored in float32) within 1.2e-7 of it → 1e-6.
"""

import os
import types

import numpy as np
import pytest
from conftest import flat_tile

import warp_biscale as wb
from warp_biscale import matrix as mx
from warp_biscale.brdf import Brdf, brdf_cosine_weighted, pack_materials

BRDFS = [wb.Lambert([0.2, 0.5, 0.9]), wb.BlinnPhong([0.2, 0.1, 0.04], 64, kd=[0.1, 0.2, 0.3]),
         wb.CookTorrance([1.0, 0.8, 0.6], 0.2, 0.3, kd=[0.1, 0.1, 0.2]), wb.Ward([0.5, 0.6, 0.7], 0.25, kd=0.1)]


def _sphere(count, seed):
    v = np.random.default_rng(seed).standard_normal((count, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def _direct(brdf, normals, grid, pi, po):
    """(L, P, 3) f_r(n, ωi, ωo)(n·ωi)⁺(n·ωo)⁺ through `Brdf.eval`, the slow obvious way."""
    n = np.repeat(normals, len(pi), axis=0)
    wi, wo = np.tile(grid[pi], (len(normals), 1)), np.tile(grid[po], (len(normals), 1))
    cos = np.maximum((n * wi).sum(1), 0) * np.maximum((n * wo).sum(1), 0)
    return (brdf.eval(n, wi, wo) * cos[:, None]).reshape(len(normals), len(pi), 3)


# ------------------------------------------------------------------------------------------------ M


@pytest.mark.parametrize("brdf", BRDFS, ids=lambda b: type(b).__name__)
def test_brdf_matrix_against_direct_evaluation(brdf):
    """M[l, k] = f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺ for normals over the whole sphere (those facing
    down reflect grazing light only) and every unordered pair of a K = 4 grid, RGB and projected."""
    g = wb.directions.grid(4)
    pi, po = wb.directions.unordered_pairs(len(g))
    normals = np.concatenate([_sphere(60, 3), [[0, 0, 1.0], [1.0, 0, 0]]])
    m = mx.brdf_matrix(brdf, normals, g)
    want = _direct(brdf, normals, g, pi, po)
    peak = np.abs(want).max()
    assert peak > 0
    np.testing.assert_allclose(m, want, rtol=0, atol=1e-12 * peak)
    # The ground truth's own formula (brdf_cosine_weighted) too, and the projection on a colour direction.
    kinds, params = pack_materials([brdf])
    n = np.repeat(normals, len(pi), axis=0)
    truth = brdf_cosine_weighted(kinds, params, np.zeros(len(n), np.int32), n, np.tile(g[pi], (len(normals), 1)),
                                 np.tile(g[po], (len(normals), 1)))
    np.testing.assert_allclose(m.reshape(-1, 3), truth, rtol=0, atol=1e-12 * peak)
    d = np.array([0.3, 0.5, 0.81])
    np.testing.assert_allclose(mx.brdf_matrix(brdf, normals, g, color=d), want @ d, rtol=0, atol=1e-12 * peak)


@pytest.mark.parametrize("brdf", BRDFS, ids=lambda b: type(b).__name__)
def test_brdf_matrix_is_reciprocal(brdf):
    """Why the unordered pairs suffice (Wu §3.7): M over (ωi, ωo) equals M over (ωo, ωi)."""
    g = wb.directions.grid(5)
    pi, po = wb.directions.all_pairs(len(g))
    normals = _sphere(40, 4)
    a = mx.brdf_matrix(brdf, normals, g, (pi, po))
    b = mx.brdf_matrix(brdf, normals, g, (po, pi))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * np.abs(a).max())


class _Opaque(Brdf):
    """A BRDF the kernels do not know (as a measured one): only `eval`."""

    def __init__(self, inner):
        self.inner = inner
        self.data = np.asarray(inner.packed())

    def eval(self, n, wi, wo):
        return self.inner.eval(n, wi, wo)


def test_brdf_matrix_of_a_brdf_known_only_by_eval():
    """A BRDF without a packed kind (e.g. `MeasuredBRDF`) goes through its `eval`: the same M, the same colour
    direction, and a cache key of its own."""
    inner = BRDFS[2]
    g = wb.directions.grid(4)
    normals = _sphere(30, 5)
    a = mx.brdf_matrix(inner, normals, g)
    b = mx.brdf_matrix(_Opaque(inner), normals, g)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * np.abs(a).max())
    da, ra = mx.color_direction(inner, normals, g)
    db, rb = mx.color_direction(_Opaque(inner), normals, g)
    np.testing.assert_allclose(db, da, atol=1e-10)
    assert abs(ra - rb) < 1e-10
    assert mx.factors_key(inner, 4, 9) != mx.factors_key(_Opaque(inner), 4, 9)


def test_color_direction_is_wus_principal_direction():
    """Wu §3.7: d is the top principal direction of the RGB tabulation (Σ f fᵀ over every entry of M), and
    the residual the RGB power the projection loses; a BRDF of one colour loses nothing."""
    g = wb.directions.grid(4)
    normals = _sphere(50, 6)
    for brdf in BRDFS[1:]:  # kd and ks of different colours
        f = mx.brdf_matrix(brdf, normals, g).reshape(-1, 3)
        lam, vec = np.linalg.eigh(f.T @ f)
        d, res = mx.color_direction(brdf, normals, g)
        np.testing.assert_allclose(d, vec[:, -1] * np.sign(vec[:, -1].sum()), atol=1e-10)
        assert abs(res - (1 - lam[-1] / lam.sum())) < 1e-10
        assert res > 1e-5 and (d > 0).all()
    one = wb.CookTorrance([0.9, 0.6, 0.3], 0.3, kd=[0.3, 0.2, 0.1])  # kd ∥ ks: one colour
    d, res = mx.color_direction(one, normals, g)
    assert res == 0.0
    f = mx.brdf_matrix(one, normals, g)
    np.testing.assert_allclose(mx.brdf_matrix(one, normals, g, color=d)[..., None] * d, f, rtol=0,
                               atol=1e-14 * np.abs(f).max())


# ------------------------------------------------------------------------------------------------ octahedral map


def test_octahedral_map():
    normals = _sphere(5000, 7)
    np.testing.assert_allclose(mx.octahedral_decode(mx.octahedral_encode(normals)), normals, atol=1e-14)
    for r in (1, 4, 9, 33):
        omega = mx.octahedral_solid_angles(r)
        assert abs(omega.sum() - 4 * np.pi) < 1e-12 and (omega > 0).all()
        # Texel centres interpolate to themselves.
        idx, w = mx.octahedral_corners(mx.octahedral_normals(r), r)
        np.testing.assert_allclose(np.take_along_axis(w, np.argmax(w, 1)[:, None], 1), 1.0, atol=1e-9)
        np.testing.assert_array_equal(idx[np.arange(r * r), np.argmax(w, 1)], np.arange(r * r))
    # An odd R puts the pole on the centre texel, with weight exactly 1.
    idx, w = mx.octahedral_corners([[0, 0, 1.0]], 9)
    assert w.max() == 1.0 and idx[0, np.argmax(w)] == 40
    np.testing.assert_array_equal(mx.octahedral_normals(9)[40], [0, 0, 1.0])
    # Folding across the square's edges: a smooth function interpolates with an error that falls with R
    # everywhere, the edges included (a wrong fold would leave an O(1) error there).
    f = lambda n: np.exp(n[:, 0]) * (1 + n[:, 2]) ** 2 + n[:, 1]
    errs = []
    for r in (17, 33, 65):
        idx, w = mx.octahedral_corners(normals, r)
        errs.append(np.abs((w * f(mx.octahedral_normals(r))[idx]).sum(1) - f(normals)).max())
    assert errs[0] > 1.8 * errs[1] > 3.2 * errs[2] and errs[2] < 0.1


# ------------------------------------------------------------------------------------------------ SVD


def _spectrum_matrix(m=300, n=200, decay=0.8, seed=1):
    rng = np.random.default_rng(seed)
    u = np.linalg.qr(rng.standard_normal((m, n)))[0]
    v = np.linalg.qr(rng.standard_normal((n, n)))[0]
    s = decay ** np.arange(n)
    return (u * s) @ v.T


def _m_small(brdf=None, r=17, k=4):
    brdf = brdf or wb.CookTorrance(1.0, 0.3)
    return mx.brdf_matrix(brdf, mx.octahedral_normals(r), wb.directions.grid(k), color=np.ones(3) / np.sqrt(3))


# (top-10 singular values, all 20, reconstruction error over Eckart–Young's optimum) − 1, measured with two
# power iterations: (3e-15, 6e-12, 4e-12) for the fast spectrum; (2.2e-6, 5.2e-4, 1.4e-4) for M, whose
# spectrum decays slowly past rank 10 (s_20/s_30 ≈ 1.3) and holds equal pairs (symmetric normals).
SVD_TOLERANCES = {"spectrum": (1e-10, 1e-8, 1e-8), "brdf": (1e-5, 2e-3, 1e-3)}


@pytest.mark.parametrize("which", ["spectrum", "brdf"])
def test_randomized_svd_against_numpy(which):
    a = _spectrum_matrix() if which == "spectrum" else _m_small(r=17, k=4)  # 300 × 200, 289 × 136
    top, rest, recon = SVD_TOLERANCES[which]
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    r = 20
    f = mx.randomized_svd(a, rank=r, oversample=10, power_iterations=2, seed=3, exact_when_full=False)
    np.testing.assert_allclose(f.S[:10], s[:10], rtol=top)
    np.testing.assert_allclose(f.S, s[:r], rtol=rest)
    best = np.linalg.norm(a - (u[:, :r] * s[:r]) @ vt[:r])
    assert np.linalg.norm(a - f.reconstruct()) <= best * (1 + recon)
    if which == "spectrum":  # singular vectors (up to sign) where the spectrum separates them
        sign = np.sign((f.U * u[:, :r]).sum(0))
        np.testing.assert_allclose(f.U[:, :10] * sign[:10], u[:, :10], atol=1e-8)
    # No power iteration (Wu Table 2 as printed) is much less accurate: why the default takes two.
    f0 = mx.randomized_svd(a, rank=r, oversample=10, power_iterations=0, seed=3, exact_when_full=False)
    assert np.linalg.norm(a - f0.reconstruct()) > best * (1 + 10 * recon)
    # Centred and weighted: the SVD of diag(w_r)·A·diag(w_c) less its mean row, scaled back.
    rng = np.random.default_rng(2)
    rw, cw = rng.random(a.shape[0]) + 0.5, rng.random(a.shape[1]) + 0.5
    aw = rw[:, None] * a * cw[None, :]
    s2 = np.linalg.svd(aw - aw.mean(0), compute_uv=False)
    f = mx.randomized_svd(a, rank=r, center=True, row_weights=rw, col_weights=cw, seed=4, exact_when_full=False)
    np.testing.assert_allclose(f.S[:10], s2[:10], rtol=top)
    np.testing.assert_allclose(f.S, s2[:r], rtol=rest)
    assert abs(f.total_power - (s2**2).sum()) <= 1e-10 * (s2**2).sum()
    for exact in (False, True):  # every singular value: A itself, by the sketch or by LAPACK
        full = mx.randomized_svd(a, rank="full", center=True, row_weights=rw, col_weights=cw, exact_when_full=exact)
        np.testing.assert_allclose(full.reconstruct(), a, rtol=0, atol=1e-10 * np.abs(a).max())


def test_randomized_svd_in_row_blocks_equals_in_memory():
    """M generated a block of rows at a time (for a matrix that does not fit) gives the same factors."""
    brdf = wb.CookTorrance(1.0, 0.3)
    normals, g = mx.octahedral_normals(15), wb.directions.grid(4)
    d = np.ones(3) / np.sqrt(3)
    dense = mx.brdf_matrix(brdf, normals, g, color=d)
    rows = mx.brdf_rows(brdf, normals, g, color=d, rows_per_block=37)
    np.testing.assert_array_equal(rows.dense(), dense)
    a = mx.randomized_svd(dense, power=0.98, center=True, seed=5)
    b = mx.randomized_svd(rows, power=0.98, center=True, seed=5)
    assert a.rank == b.rank
    np.testing.assert_allclose(b.S, a.S, rtol=1e-10)
    np.testing.assert_allclose(b.reconstruct(), a.reconstruct(), rtol=0, atol=1e-10 * np.abs(dense).max())


def test_reconstruction_error_falls_with_rank():
    """The Frobenius error of the rank-r factors falls with r and is exactly the power left out."""
    a = _m_small(wb.CookTorrance(1.0, 0.25), r=17, k=5)  # 289 × 325
    f = mx.randomized_svd(a, rank=60, center=True, seed=6)
    errs = []
    for r in range(0, 61, 3):
        t = f.truncated(r)
        e2 = float(((a - t.reconstruct()) ** 2).sum())
        errs.append(e2)
        assert abs(e2 - (1 - t.power_kept) * f.total_power) <= 1e-8 * f.total_power
    assert all(b <= a_ * (1 + 1e-12) for a_, b in zip(errs, errs[1:]))
    assert errs[-1] < 1e-2 * errs[0]


def test_rank_by_power_is_the_fewest_that_hold_it():
    a = _spectrum_matrix(decay=0.9)
    s = np.linalg.svd(a - a.mean(0), compute_uv=False)
    cum = np.cumsum(s**2) / (s**2).sum()
    for power in (0.5, 0.9, 0.98, 0.995):
        f = mx.randomized_svd(a, power=power, center=True, initial_rank=4)
        assert f.rank == int(np.searchsorted(cum, power)) + 1
        assert f.power_kept >= power
    assert mx.randomized_svd(a, power=1.0).rank == 200
    with pytest.raises(ValueError, match="exactly one"):
        mx.randomized_svd(a, rank=3, power=0.9)
    with pytest.raises(ValueError, match="row_weights"):
        mx.randomized_svd(a, rank=3, row_weights=np.zeros(300))


# ------------------------------------------------------------------------------------------------ Eq. 12


def test_eq12_with_full_rank_equals_the_direct_product():
    rng = np.random.default_rng(8)
    k = 4
    nd = k * k
    u = nd * (nd + 1) // 2
    n_mat = rng.random((u, 23)) * (rng.random((u, 23)) < 0.4)
    m_mat = rng.random((23, u))
    a_v = rng.random(nd) + 0.1
    a_v[3] = 0.0  # nothing seen from ω3: f̄ = 0 there
    nf = mx.randomized_svd(n_mat, rank="full", center=True, col_weights=rng.random(23) + 0.5)
    mf = mx.randomized_svd(m_mat, rank="full", center=True, row_weights=rng.random(23) + 0.5)
    direct = mx.direct_pair_sums(n_mat, m_mat)
    np.testing.assert_allclose(mx.pair_sums(nf, mf), direct, rtol=0, atol=1e-12 * np.abs(direct).max())
    table = mx.effective_from_factors(nf, mf, a_v)
    want = mx.effective_table(direct, a_v)
    np.testing.assert_allclose(table, want, rtol=0, atol=1e-12 * want.max())
    assert (table[:, 3] == 0).all()
    # The table: f̄[i, o] = Σ_l N[(i, o), l] M[l, (i, o)] / a_v[o], either order of the pair reading one row.
    i, o = 5, 2
    p = wb.directions.unordered_index(i, o, nd)
    assert np.isclose(want[i, o], (n_mat[p] * m_mat[:, p]).sum() / a_v[o])
    assert np.isclose(want[o, i], (n_mat[p] * m_mat[:, p]).sum() / a_v[i])
    # Truncated: the error falls as ranks are added.
    errs = [np.abs(mx.pair_sums(nf.truncated(r), mf.truncated(r)) - direct).max() for r in (2, 8, 23)]
    assert errs[0] > errs[1] > errs[2]
    with pytest.raises(ValueError, match="must be"):
        mx.pair_sums(nf, mx.randomized_svd(m_mat[:20], rank=3))


# ------------------------------------------------------------------------------------------------ sampling rates


def test_binary_search_rate():
    calls = []

    def err(r):
        calls.append(r)
        return 1.0 / r

    rate, e, met, trials = mx.binary_search_rate(err, 1, 100, 0.02)  # 1/r ≤ 0.02 from r = 50
    assert (rate, met) == (50, True) and e == 0.02
    assert len(calls) <= 8 and len(set(calls)) == len(calls) and dict(trials)[50] == 0.02
    rate, e, met, _ = mx.binary_search_rate(err, 1, 10, 0.02)
    assert (rate, met) == (10, False)
    assert mx.binary_search_rate(err, 3, 3, 1.0)[:3] == (3, 1 / 3, True)


def test_sampling_rates_follow_the_lobe():
    """A sharper lobe needs more normals and more directions; the chosen rates meet Wu's thresholds and the
    rate just below, where it was tried, does not."""
    kw = dict(n_normals=768, n_pairs=192, n_direction_normals=96, n_direction_pairs=384, normal_range=(3, 129))
    lam = mx.sampling_rates(wb.Lambert(0.5), **kw)
    ct = mx.sampling_rates(wb.CookTorrance(1.0, 0.3), **kw)
    assert lam.normal_res % 2 == 1 and ct.normal_res % 2 == 1
    assert ct.normal_res > lam.normal_res and ct.directions > lam.directions
    for rates in (lam, ct):
        assert rates.normal_met and rates.normal_error <= mx.NORMAL_THRESHOLD
        below = dict(rates.normal_trials).get(rates.normal_res - 2)
        assert below is None or below > mx.NORMAL_THRESHOLD
        if rates.direction_met:
            assert rates.direction_error <= mx.DIRECTION_THRESHOLD
            below = dict(rates.direction_trials).get(rates.directions - 1)
            assert below is None or below > mx.DIRECTION_THRESHOLD
    assert lam.direction_met


# ------------------------------------------------------------------------------------------------ cache


def test_material_factors_cache_round_trip(tmp_path):
    ct = wb.CookTorrance(1.0, 0.4)
    kw = dict(directions=4, normal_res=9, cache_dir=tmp_path)
    mx._MEMORY.clear()
    a = mx.material_factors(ct, **kw)
    assert a.source == "computed" and a.key == mx.factors_key(ct, 4, 9)
    files = os.listdir(tmp_path)
    assert len(files) == 1 and a.key[:24] in files[0]
    assert mx.material_factors(ct, **kw).source == "memory"
    mx._MEMORY.clear()
    b = mx.material_factors(ct, **kw)
    assert b.source == os.path.join(tmp_path, files[0])
    for name in ("U", "S", "V", "mean", "row_scale", "col_scale"):
        np.testing.assert_array_equal(getattr(b.factors, name), getattr(a.factors, name))
    np.testing.assert_array_equal(b.color, a.color)
    assert (b.rank, b.nbytes, b.normal_res, b.directions) == (a.rank, a.nbytes, 9, 4)
    assert a.nbytes == sum(x.nbytes for x in a.factors.arrays().values()) + a.color.nbytes
    # Another BRDF parameter, another grid or another resolution: another key, another file.
    keys = {a.key, mx.factors_key(wb.CookTorrance(1.0, 0.41), 4, 9), mx.factors_key(ct, 5, 9),
            mx.factors_key(ct, 4, 11), mx.factors_key(ct, 4, "auto"), mx.factors_key(ct, 4, 9, power=0.99)}
    assert len(keys) == 6
    # A corrupt file is computed again and replaced.
    path = os.path.join(tmp_path, files[0])
    with open(path, "wb") as fh:
        fh.write(b"not a zip")
    mx._MEMORY.clear()
    c = mx.material_factors(ct, **kw)
    assert c.source == "computed" and mx.MaterialFactors.load(path).key == a.key
    with pytest.raises(ValueError, match="odd"):
        mx.material_factors(ct, directions=4, normal_res=8, cache_dir=False)
    # A folder that takes no file: a warning, and the factors in memory.
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    mx._MEMORY.clear()
    with pytest.warns(UserWarning, match="kept in memory"):
        d = mx.material_factors(ct, directions=4, normal_res=9, cache_dir=blocker / "sub")
    assert d.source == "computed" and mx.material_factors(ct, directions=4, normal_res=9,
                                                          cache_dir=blocker / "sub").source == "memory"
    # Streamed in row blocks (M over the memory budget): the same factors.
    mx._MEMORY.clear()
    e = mx.material_factors(ct, directions=4, normal_res=9, cache_dir=False, memory_budget=0)
    assert e.info["streamed"] and not a.info["streamed"] and e.rank == a.rank
    np.testing.assert_allclose(e.factors.S, a.factors.S, rtol=1e-6)


def test_material_factors_auto_resolution_records_the_search(tmp_path):
    search = dict(n_normals=512, n_pairs=128, n_direction_normals=64, n_direction_pairs=256, normal_range=(3, 65))
    f = mx.material_factors(wb.Lambert(0.6), directions=4, normal_res="auto", cache_dir=tmp_path, search=search)
    assert f.rates is not None and f.normal_res == f.rates.normal_res
    assert f.info["directions_advised"] == f.rates.directions and f.factors.power_kept >= mx.M_POWER
    lam = wb.Lambert(0.6)
    assert f.key == mx.factors_key(lam, 4, "auto", search=search) != mx.factors_key(lam, 4, "auto")
    mx._MEMORY.clear()
    g = mx.material_factors(wb.Lambert(0.6), directions=4, normal_res="auto", cache_dir=tmp_path, search=search)
    assert g.source != "computed" and g.rates.normal_trials == [list(t) for t in f.rates.normal_trials]


# ------------------------------------------------------------------------------------------------ end to end


def _bake_n(tile, brdf, k, facets, backend, seed=0):
    mat = wb.bake(tile, brdf, directions=k, facets=facets, bvndf=True, backend=backend, seed=seed)
    return mat.bvndf


def test_flat_lambertian_through_the_matrix_method(backend):
    """The first test of every method: f̄ = (kd/π)cos θi, here from the bake's histogram N (Wu Eq. 11) and a
    precomputed M, by Eq. 12, and against the ground truth."""
    kd = np.array([0.2, 0.5, 0.8])
    color = np.array([1.0, 0.9, 0.7])
    tile = wb.SmallScale(flat_tile().vertices, flat_tile().faces, colors=np.tile(color, (2, 1)), name="flat")
    k = 6
    bv = _bake_n(tile, wb.Lambert(kd), k, 2048, backend)
    assert len(bv.bins) == 1
    want = (kd * color)[None, None, :] / np.pi * wb.directions.grid(k)[:, 2][:, None, None]
    want = np.broadcast_to(want, (k * k, k * k, 3))
    gt = wb.ground_truth(tile, wb.Lambert(kd), facets=2048, directions=k, backend=backend)
    nf = mx.bvndf_factors(bv.histogram, bv.solid_angle)
    errs = []
    for power in (1.0, 0.999, mx.M_POWER):
        mf = mx.material_factors(wb.Lambert(kd), directions=k, normal_res=9, power=power, cache_dir=False)
        tab = mx.matrix_tables([(0, color, nf)], bv.normal, [mf], bv.a_v)[0]
        errs.append(np.abs(tab - gt.table).max() / want.max())
        if power == 1.0:  # every singular value of M: exact but for float32 rounding
            np.testing.assert_allclose(tab, want, rtol=0, atol=1e-5 * want.max())
            np.testing.assert_allclose(tab, gt.table, rtol=0, atol=1e-5 * want.max())
        if power == mx.M_POWER:  # Wu's 98 %: the truncation's error, measured 27.2 dB, 18 % of the peak
            assert wb.compare(types.SimpleNamespace(directions=k, table=tab), gt)["psnr"] > 25
    assert errs[0] < errs[1] < errs[2] < 0.25


def test_one_normal_per_bin_is_exact(backend):
    """On the pyramid every bin holds one normal, so N·M with M at the bins' normals is the ground truth's sum
    over the same facets, grouped by bin (Wu Eq. 8 with no binning error); and Eq. 12 with M factored at
    those normals, every singular value kept, gives it too."""
    tile = wb.geometry.pyramid()
    ct = wb.CookTorrance([1.0, 0.8, 0.6], 0.2)
    k, facets = 5, 4096
    bv = _bake_n(tile, ct, k, facets, backend)
    gt = wb.ground_truth(tile, ct, facets=facets, directions=k, backend=backend)
    g = wb.directions.grid(k)
    d, res = mx.color_direction(ct, bv.normal, g)
    assert res == 0.0
    m_bins = mx.brdf_matrix(ct, bv.normal, g, color=d)
    n_mat = bv.histogram.astype(np.float64)
    direct = mx.effective_table(mx.direct_pair_sums(n_mat, m_bins), bv.a_v)[..., None] * d
    peak = gt.table.max()
    np.testing.assert_allclose(direct, gt.table, rtol=0, atol=1e-5 * peak)
    nf = mx.bvndf_factors(n_mat, bv.solid_angle, power=1.0)
    mf = mx.randomized_svd(m_bins, rank="full", center=True)
    factored = mx.effective_from_factors(nf, mf, bv.a_v)[..., None] * d
    np.testing.assert_allclose(factored, direct, rtol=0, atol=1e-6 * peak)
