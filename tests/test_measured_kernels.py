"""Measured (MERL) BRDFs in the kernels (kernels/common.py's measured_cosine_weighted, cl/common.cl's twin), on
every backend present: the lookup against the float64 `MeasuredBRDF.eval`, the ground truth (single bounce and
interreflection) against float64 sums over the same facets, and the matrix method's M and bake.

Tolerances are relative to the peak of the float64 values compared. The kernels take the angles in float32
(about 1e-7 rad of error in each; more on θh's square-root axis next to the peak, and in φh where sin θh is
small) and hold the table in float32 (6e-8 relative); the interpolation weights turn an angle's error into a
value error of the table's change across a bin times the error in bins. Measured on warp:cpu and opencl:cpu
(the same to three digits): trilinear lookups within 3.1e-5 of the peak (the tabulated Cook–Torrance at
θd of 84°–88°, where its table is steepest; 1.3e-5 for the paint), nearest ones within 1.0e-6 away from bin
boundaries; the ground truth within 4.1e-7 of the float64 sum, the interreflection within 2.1e-7, M within
2.9e-7. LOOKUP_TOL, 1e-4 of the peak, is three times the largest.
"""

import math

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import matrix as mx
from warp_biscale import measured as ms
from warp_biscale import reference as ref
from warp_biscale.brdf import measured_tables, pack_materials
from warp_biscale.measured import MeasuredBRDF

COOK = wb.CookTorrance(ks=(1.0, 0.8, 0.6), roughness=0.2, f0=0.04, kd=(0.1, 0.2, 0.3))
BLINN = wb.BlinnPhong(ks=(0.6, 0.5, 0.4), exponent=64, kd=(0.1, 0.05, 0.02), normalization="energy")
LOOKUP_TOL = 1e-4  # of the peak: see the module's docstring


@pytest.fixture(scope="module")
def tables():
    """Tabulations (about a second each): Cook–Torrance, Blinn–Phong, the synthetic paint, and a table with
    invalid samples beyond those below the horizon — whole (θh, φd) columns (filled from θh neighbours) and
    the grazing end of others (filled along θd)."""
    cook = MeasuredBRDF.from_brdf(COOK)
    data = np.array(ms.paint_like().data)
    data[:, 30:33] = -1.0  # three θh rows: every column empty, filled from rows 29 and 33
    data[:, 50, 60:, 10:40] = -1.0  # the grazing end of some columns
    data[1, 70, 5, 100] = -1.0  # one channel marks the whole sample invalid
    holes = MeasuredBRDF(data)
    return {"cook": cook, "blinn": MeasuredBRDF.from_brdf(BLINN), "paint": ms.paint_like(), "holes": holes}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(n):
    t = _unit(np.cross(n, [0.3, 0.5, 0.7]))
    return t, np.cross(n, t)


def _triples(n, rng, count=1500):
    """(ωi, ωo) about unit normal n: uniform over the hemisphere, near-specular (θh from 1e-6 rad to a few
    degrees), grazing (both within 3° of the horizon) and one direction grazing."""
    local = []
    u = _unit(rng.normal(size=(2, count, 3)))
    u[..., 2] = np.abs(u[..., 2])
    local.append((u[0], u[1]))
    th = np.concatenate([10 ** rng.uniform(-6, -2, count // 2), np.abs(rng.normal(0, 0.05, count // 2))])
    a, b = ms.directions_of(th, rng.uniform(0, 1.5, count), rng.uniform(-np.pi, np.pi, count))
    local.append((a, b))
    for lo in (0.0, 0.9):
        z = np.stack([rng.uniform(0.0005, 0.05, count), rng.uniform(lo, 1.0, count)], 0)
        phi = rng.uniform(0, 2 * np.pi, (2, count))
        r = np.sqrt(1 - z ** 2)
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
        local.append((d[0], d[1]))
    a = np.concatenate([p[0] for p in local])
    b = np.concatenate([p[1] for p in local])
    ok = (a[:, 2] > 0) & (b[:, 2] > 0)
    a, b = a[ok], b[ok]
    t, bt = _frame(n)
    to_world = lambda v: v[:, :1] * t + v[:, 1:2] * bt + v[:, 2:] * n
    return to_world(a), to_world(b)


def _kernel_rgb(backend, brdf, n, wi, wo):
    """(P, 3) f_r·(n·ωi)⁺(n·ωo)⁺ of one measured BRDF by the matrix stage's kernel (one row, normal n)."""
    kinds, params = pack_materials([brdf], measured=True)
    return np.stack([backend.brdf_matrix(kinds, params, 0, n[None], wi, wo, e, measured=[brdf])[0]
                     for e in np.eye(3)], -1).astype(np.float64)


def _host_rgb(brdf, n, wi, wo):
    nn = np.broadcast_to(n, wi.shape)
    return brdf.eval(nn, wi, wo) * (np.maximum(wi @ n, 0) * np.maximum(wo @ n, 0))[:, None]


def _near_a_boundary(brdf, n, wi, wo, margin=1e-3):
    """Pairs whose float64 index on some axis lies within `margin` of a bin boundary, where float32 angles
    may pick the neighbouring bin in nearest mode (the ends of θh and θd are clamped, φd's wrap is one)."""
    t, bt = ms._tangent_frames(np.broadcast_to(n, wi.shape).copy())
    loc = [np.stack([np.einsum("ij,ij->i", w, t), np.einsum("ij,ij->i", w, bt), w @ n], 1) for w in (wi, wo)]
    ch, cd, cp = ms._continuous_indices(*ms.half_diff_angles(*loc))
    near = np.zeros(len(wi), bool)
    for c, res in ((ch, 90), (cd, 90)):
        k = np.round(c)
        near |= (np.abs(c - k) < margin) & (k >= 1) & (k <= res - 1)
    near |= np.abs(cp - np.round(cp)) < margin
    return near


@pytest.mark.parametrize("name", ["cook", "paint", "holes"])
def test_lookup_matches_eval(backend, tables, name):
    """The kernel's lookup (trilinear and nearest) against MeasuredBRDF.eval in float64 at normals +z, −z
    tilted and random, ωi and ωo uniform, near-specular and grazing. The inputs are rounded to float32 first
    (the kernels' inputs), so the difference is the kernels' arithmetic alone."""
    rng = np.random.default_rng(11)
    normals = np.concatenate([[[0, 0, 1.0]], _unit(np.array([[0.3, -0.2, -0.9], [0.9, 0.1, 0.05]])),
                              _unit(rng.normal(size=(2, 3)))])
    normals = normals.astype(np.float32).astype(np.float64)
    for mode in ("trilinear", "nearest"):
        brdf = tables[name].with_interpolation(mode)
        worst = 0.0
        for n in normals:
            wi, wo = (w.astype(np.float32).astype(np.float64) for w in _triples(n, rng))
            got = _kernel_rgb(backend, brdf, n, wi, wo)
            want = _host_rgb(brdf, n, wi, wo)
            peak = np.abs(want).max()
            assert peak > 0
            err = np.abs(got - want).max(axis=1)
            if mode == "nearest":
                err = err[~_near_a_boundary(brdf, n, wi, wo)]
            worst = max(worst, err.max() / peak)
        print(f"{name} {mode}: max error {worst:.3g} of the peak")
        assert worst <= LOOKUP_TOL, (name, mode, worst)


# ---- the ground truth ------------------------------------------------------------------------------------------

K, FACETS, SEED = 4, 1024, 3


def _float64_truth(tile, brdf):
    """(K², K², 3) f̄ of the single-bounce truth in float64 over the facets and visibility the kernels use (the
    reference's, the same seed), every f_r from `brdf.eval`: the oracle for a measured BRDF."""
    grid = wb.directions.grid(K)
    r = ref.sample_facets(tile, FACETS, SEED)
    vis = ref.visibility(tile, r, grid)
    a_v = ref.visible_area(r, vis, grid)
    n, w = r["normal"], r["area"][:, None] * r["color"]
    out = np.zeros((len(grid), len(grid), 3))
    for i in range(len(grid)):
        for o in range(len(grid)):
            both = vis[i] & vis[o]
            if both.any() and a_v[o] > 0:
                nb = n[both]
                wi, wo = np.broadcast_to(grid[i], nb.shape), np.broadcast_to(grid[o], nb.shape)
                f = brdf.eval(nb, wi, wo) * (np.maximum(nb @ grid[i], 0) * np.maximum(nb @ grid[o], 0))[:, None]
                out[i, o] = (f * w[both]).sum(0) / a_v[o]
    return out


@pytest.mark.parametrize("name,analytic", [("cook", COOK), ("blinn", BLINN)])
def test_ground_truth_of_a_tabulated_brdf(backend, tables, name, analytic):
    """wb.ground_truth of a tabulated BRDF against the float64 sum of its `eval` over the same facets, and
    against the ground truth of the analytic BRDF it tabulates, which it differs from by the tabulation's own
    error (measured by the same float64 sums for both BRDFs: 5.9e-4 of the peak for the Cook–Torrance, 3.7e-4
    for the Blinn–Phong; the kernels' tables differ by the same to three digits) and float32."""
    tile = wb.geometry.pyramid(height=0.5)
    m = tables[name]
    got = wb.ground_truth(tile, [m], facets=FACETS, directions=K, backend=backend, seed=SEED).table
    want = _float64_truth(tile, m)
    peak = want.max()
    err = np.abs(got - want).max() / peak
    analytic_table = wb.ground_truth(tile, [analytic], facets=FACETS, directions=K, backend=backend, seed=SEED).table
    tabulation = np.abs(_float64_truth(tile, analytic) - want)
    print(f"{name}: kernel vs float64 {err:.3g} of the peak; tabulation error {tabulation.max() / peak:.3g}; "
          f"kernel tables {np.abs(got - analytic_table).max() / peak:.3g}")
    assert err <= LOOKUP_TOL
    assert np.all(np.abs(got - analytic_table) <= tabulation + 2 * LOOKUP_TOL * peak)


def test_interreflection_of_a_tabulated_lambert(backend):
    """The bounces 2..B through the dispatcher: a tabulated Lambert (a constant table: the tabulation is exact
    to float32) beside an analytic Blinn–Phong, against reference.interreflection of the analytic pair, path
    for path (the same random numbers). Tolerance as tests/test_interreflection.py's, 1e-4 of the peak."""
    tile = wb.geometry.pyramid(height=0.7, base_material=1)
    lam = wb.Lambert((0.9, 0.7, 0.5))
    analytic = [lam, wb.BlinnPhong(0.2, 20, kd=0.3)]
    mats = [MeasuredBRDF.from_brdf(lam), analytic[1]]
    b, paths, k, count, seed = 3, 64, 3, 256, 5
    kinds, params = pack_materials(analytic, tile.n_materials)
    grid = wb.directions.grid(k)
    pi, po = wb.directions.all_pairs(len(grid))
    r = ref.sample_facets(tile, count, seed)
    want = ref.interreflection(tile, r, ref.visibility(tile, r, grid), grid, kinds, params, pi, po, b, paths,
                               seed=seed)
    mk, mp = pack_materials(mats, tile.n_materials, measured=True)
    fac = backend.sample_facets(tile, count, seed)
    v = backend.visibility(tile, fac, grid)
    a_v = backend.visible_area(fac, v)
    got = backend.interreflection(tile, fac, v, mk, mp, pi, po, a_v, b, paths, seed, measured=measured_tables(mats))
    assert want.max() > 0.01
    print(f"interreflection: max error {np.abs(got - want).max() / want.max():.3g} of the peak")
    assert np.abs(got - want).max() <= 1e-4 * want.max()
    gt = wb.ground_truth(tile, mats, facets=count, directions=k, backend=backend, seed=seed, bounces=b, paths=paths)
    assert np.isfinite(gt.table).all() and gt.bounces == b


# ---- the matrix method ---------------------------------------------------------------------------------------


def test_matrix_m_of_a_measured_brdf(backend, tables):
    """M's rows of a measured BRDF by the kernels (`brdf_rows` with a backend) against the float64 numpy M
    (`brdf_matrix`, through `eval`), and Wu's colour direction from the kernels' three channels."""
    m = tables["paint"]
    g = wb.directions.grid(4)
    pairs = wb.directions.unordered_pairs(len(g))
    normals = mx.octahedral_normals(9)
    dk, rk = mx.color_direction(m, normals, g, pairs, backend=backend)
    dh, rh = mx.color_direction(m, normals, g, pairs)
    assert np.abs(dk - dh).max() <= 1e-5 and abs(rk - rh) <= 1e-5
    got = mx.brdf_rows(m, normals, g, pairs, color=dh, rows_per_block=30, backend=backend).dense()
    want = mx.brdf_matrix(m, normals, g, pairs, color=dh)
    print(f"M: max error {np.abs(got - want).max() / np.abs(want).max():.3g} of the peak")
    np.testing.assert_allclose(got, want, rtol=0, atol=LOOKUP_TOL * np.abs(want).max())


def test_matrix_bake_of_a_tabulated_brdf(backend, tmp_path):
    """wb.bake(method="matrix") takes a MeasuredBRDF, its M made by the kernels, and agrees with the bake of the
    analytic BRDF it tabulates (a grey Cook–Torrance: one colour direction, no projection error) within M's
    tabulation error, every singular value kept. Measured: the tables differ by 6.9e-4 of the peak, M's
    tabulation error (float64, over its texels and pairs) is 1.2e-3 of M's peak."""
    ct = wb.CookTorrance(ks=0.8, roughness=0.3, kd=0.2)
    m = MeasuredBRDF.from_brdf(ct)
    tile = wb.geometry.pyramid(height=0.5)
    opts = {"normal_res": 9, "power": 1.0, "n_power": 1.0, "cache_dir": False}
    kw = dict(method="matrix", directions=4, facets=1 << 12, backend=backend, matrix=opts)
    got = wb.bake(tile, [m], **kw)
    want = wb.bake(tile, [ct], **kw)
    assert got.factors[0].info["m_source"] != "numpy"  # (the kernels': the first backend's, cached in memory)
    g = wb.directions.grid(4)
    normals = mx.octahedral_normals(9)
    m_an = mx.brdf_matrix(ct, normals, g, color=np.ones(3) / math.sqrt(3))
    m_tab = np.abs(mx.brdf_matrix(m, normals, g, color=np.ones(3) / math.sqrt(3)) - m_an).max() / m_an.max()
    a, b = got.table(), want.table()
    diff = np.abs(a - b).max() / b.max()
    print(f"matrix bake: tables differ by {diff:.3g} of the peak; M's tabulation error {m_tab:.3g} of its peak")
    assert diff <= 2 * m_tab + LOOKUP_TOL


# ---- what still refuses a measured BRDF ---------------------------------------------------------------------


def test_other_stages_refuse_in_one_line(tables):
    """The kernels' packing of analytic rows (the lit-sphere texel kernels') refuses a MeasuredBRDF in one line
    that names what cannot take it; the ground truth and the matrix bake take its table (above), the SG and ASG
    bakes and the SG renderer its SG fit (tests/test_measured_sg.py)."""
    m = tables["paint"]
    calls = [(lambda: pack_materials([wb.Lambert(0.5), m]), "lit-sphere texel kernels")]
    for call, words in calls:
        with pytest.raises(ValueError, match="MeasuredBRDF") as info:
            call()
        assert words in str(info.value) and "\n" not in str(info.value)
