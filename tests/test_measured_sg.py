"""Measured BRDFs through their SG fit (Wang 2009 §4.1–4.2, `measured.fit_sg`): the fit against the parameters
that made a table, the SG and ASG bakes and the SG renderer of a measured material on every backend present,
material files that carry the table, and what the fit cannot hold.

The outside truth is the generating BRDF: a table tabulated from a Cook–Torrance (`MeasuredBRDF.from_brdf`)
must give back its kd, ks, m and f0. The fit reads the NDF as the SG exp((2/m²)(n·h − 1)) while the table
holds exp(−θh²/m²) (Wang Eq. 12's approximation), so the parameters come back close, not exact: measured
(numpy 2, this machine) m 0.1497 for 0.15 and 0.1994 for 0.2, ks within 0.11 %, kd within 0.004 %, f0
within 0.03 %, relative L2 errors 1.0e-4 and 1.2e-3. PARAM_TOL (1 %) and FIT_TOL (5e-3) leave headroom.
"""

import os

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import measured as ms
from warp_biscale.measured import MeasuredBRDF

PARAM_TOL = 0.01  # relative, on kd, ks, m, f0 of a tabulated Cook–Torrance (see the docstring)
FIT_TOL = 5e-3  # the fit's relative L2 error on such a table
GLOSSY = wb.CookTorrance(ks=(0.5, 0.4, 0.3), roughness=0.15, f0=0.2, kd=(0.3, 0.2, 0.1))


@pytest.fixture(scope="module")
def glossy():
    return MeasuredBRDF.from_brdf(GLOSSY)


@pytest.fixture(scope="module")
def paint():
    return ms.paint_like()


@pytest.mark.parametrize("brdf", [GLOSSY, wb.CookTorrance(1.0, 0.2)], ids=["coloured-m0.15", "ks1-m0.2"])
def test_fit_recovers_the_cook_torrance_that_made_the_table(brdf):
    fit = MeasuredBRDF.from_brdf(brdf).sg_fit()
    got = fit.brdf
    assert got.roughness == pytest.approx(brdf.roughness, rel=PARAM_TOL)
    assert got.f0 == pytest.approx(brdf.f0, rel=PARAM_TOL)
    np.testing.assert_allclose(got.ks, brdf.ks, rtol=PARAM_TOL)
    np.testing.assert_allclose(got.kd, brdf.kd, rtol=PARAM_TOL, atol=1e-6)
    assert 0 < fit.error < FIT_TOL and fit.samples > 100_000


def test_fit_of_a_paint_reports_its_error(paint):
    """The synthetic paint (a Lambertian base, a broad sheen lobe and a sharp coat) held by one lobe: the
    base comes back (measured kd within 0.04 %), the two lobes merge into one (measured m 0.319 between the
    sheen's 0.35 and the coat's 0.06), and the error says what that costs (measured 2.7e-3)."""
    fit = paint.sg_fit()
    np.testing.assert_allclose(fit.brdf.kd, (0.55, 0.08, 0.05), rtol=0.01)
    assert 0.06 < fit.brdf.roughness < 0.35
    assert 0 < fit.error < 0.02
    assert paint.sg_fit() is fit  # kept: a second use does not fit again


def test_fit_error_shows_what_one_microfacet_lobe_cannot_hold():
    """A tabulated Blinn–Phong is not a microfacet BRDF (no F·G/(cosθi cosθo)): the fit's error says so
    (measured 0.48) rather than passing it off as a match."""
    fit = MeasuredBRDF.from_brdf(wb.BlinnPhong(0.5, 128, kd=0.3, normalization="energy")).sg_fit()
    assert fit.error > 0.1


def test_fit_kernels_against_the_float64_sums(backend, paint):
    """The `sgfit` kernels' sums (normal equations and residuals) against `measured.fit_sums` (float64) on the
    paint's samples, for candidates from a delta-like lobe to a broad one. Tolerance: float32 samples and
    chunk sums of 1024 terms, added in float64: measured relative errors 1.9e-7 on the normal equations and
    7.5e-7 on the residuals (Warp CPU and PoCL alike; a residual subtracts nearly equal terms where the
    candidate fits) → 1e-5 and 1e-4."""
    basis, target, weight = ms.fit_samples(paint._table())
    cand = np.array([[2 / 0.01**2, 0.02], [2 / 0.06**2, 0.5], [2 / 0.32**2, 0.05], [2 / 2.0**2, 1.0]])
    data = backend.sg_fit_data(basis, target, weight)
    ref = ms.fit_sums(basis, target, weight, cand)
    got = backend.sg_fit_sums(data, cand)
    gram_err = np.abs(got - ref).max(0) / np.abs(ref).max(0)
    coef = ms._nonnegative_coefficients(ref)
    ref_res = ms.fit_sums(basis, target, weight, cand, coef)
    res_err = np.abs(backend.sg_fit_sums(data, cand, coef) - ref_res) / ref_res
    print(f"{backend.name}: normal equations {gram_err.max():.1e}, residuals {res_err.max():.1e}")
    assert gram_err.max() < 1e-5 and res_err.max() < 1e-4


def test_nonnegative_coefficients_against_nnls():
    """The fit's two-coefficient non-negative solve from the normal equations against scipy's NNLS on the
    design matrix itself, for random problems whose unconstrained solutions fall in every quadrant."""
    from scipy.optimize import nnls

    rng = np.random.default_rng(5)
    for _ in range(200):
        a = rng.normal(size=(40, 2)) * rng.uniform(0.1, 3, 2)
        t = a @ rng.normal(size=(2, 3)) + 0.3 * rng.normal(size=(40, 3))
        sums = np.concatenate([[a[:, 0] @ a[:, 0], a[:, 0] @ a[:, 1], a[:, 1] @ a[:, 1]], a[:, 0] @ t, a[:, 1] @ t])
        got = ms._nonnegative_coefficients(sums[None])[0].reshape(2, 3)
        for c in range(3):
            np.testing.assert_allclose(got[:, c], nnls(a, t[:, c])[0], atol=1e-9)


@pytest.fixture(scope="module")
def host_fits():
    """The float64 host fit of each table, made once for every backend's comparison."""
    return {}


@pytest.mark.parametrize("table", ["glossy", "paint"])
def test_fit_in_the_kernels_matches_the_host_fit(backend, table, request, host_fits):
    """`fit_sg(table, backend)` (the sums in the kernels) against the float64 host fit: the same lobe. Measured
    (Warp CPU, PoCL), relative: roughness within 2.1e-4, f0 7.3e-5, kd 3.9e-6, ks 1.3e-4, the error 6.1e-6
    (Nelder–Mead stops at another point of the float32 objective's flat minimum) → 2e-3, 2e-3 and 1e-3."""
    m = request.getfixturevalue(table)
    host = host_fits[table] = host_fits.get(table) or ms.fit_sg(m)
    dev = ms.fit_sg(m, backend)
    print(f"{backend.name} {table}: host {host}, device {dev}")
    assert dev.backend == backend.name and host.backend == "host"
    for a, b in ((dev.brdf.roughness, host.brdf.roughness), (dev.brdf.f0, host.brdf.f0)):
        assert a == pytest.approx(b, rel=2e-3, abs=1e-6)
    np.testing.assert_allclose(dev.brdf.kd, host.brdf.kd, rtol=2e-3, atol=1e-6)
    np.testing.assert_allclose(dev.brdf.ks, host.brdf.ks, rtol=2e-3, atol=1e-6)
    assert dev.error == pytest.approx(host.error, rel=1e-3)


def test_sg_bake_of_a_table_is_the_bake_of_its_fit_and_judged_by_the_table(backend, glossy):
    """The SG bake convolves with the fit (its f̄ equals the bake of the fitted Cook–Torrance on the same
    facets), records the fit in info, and is judged against the table's own ground truth (the truth kernels
    read the table): measured 60.4 dB against 61.1 dB for the analytic material against its truth (warp:cpu)."""
    tile = wb.geometry.pyramid(height=0.5)
    kw = dict(lobes=8, directions=6, facets=1 << 12, backend=backend)
    got = wb.bake(tile, glossy, **kw)
    want = wb.bake(tile, glossy.sg_fit().brdf, **kw)
    np.testing.assert_array_equal(got.table(), want.table())
    assert got.info["sg_fit"]["0"]["error"] == glossy.sg_fit().error and "sg_fit" in got.timings
    truth = wb.ground_truth(tile, glossy, directions=6, facets=1 << 14, backend=backend)
    truth_analytic = wb.ground_truth(tile, GLOSSY, directions=6, facets=1 << 14, backend=backend)
    psnr = wb.compare(got, truth)["psnr"]
    assert psnr > wb.compare(wb.bake(tile, GLOSSY, **kw), truth_analytic)["psnr"] - 2.0 and psnr > 40


def test_asg_bake_takes_a_table(backend, paint):
    tile = wb.geometry.grooves()
    mat = wb.bake(tile, paint, method="asg", lobes=4, directions=5, facets=1 << 12, backend=backend)
    f = mat.table()
    assert np.isfinite(f).all() and f.min() >= 0 and f.max() > 0 and "sg_fit" in mat.info


def test_sg_renderer_shades_a_table_by_its_fit(backend, glossy):
    """A measured material on a large-scale object, and a baked one, render as their fits do, pixel for
    pixel, with no NaN or negative radiance (a lone sphere under a sky and a light: no SSDF to build)."""
    mesh = wb.Mesh.sphere(1.0)
    cam = wb.Camera(eye=(0, 0.5, 3.5), width=48, height=36)
    lights = [wb.DirectionalLight()]
    sky = wb.Environment.sky(height=32, width=64)  # one object: its lighting is prepared once

    def image(material):
        return wb.render(wb.Scene(mesh, [material], cam, sky, lights), backend=backend, aa=1).image

    got = image(glossy)
    np.testing.assert_array_equal(got, image(glossy.sg_fit().brdf))
    assert np.isfinite(got).all() and got.min() >= 0 and got.max() > 0
    baked = wb.bake(wb.geometry.pyramid(), glossy, lobes=4, directions=4, facets=1 << 10, backend=backend)
    np.testing.assert_array_equal(image(baked), image(baked.with_materials([glossy.sg_fit().brdf])))


def test_material_files_carry_the_table_and_its_fit(tmp_path, glossy):
    """A baked material of a measured BRDF saves its table (the exact truth is rebuilt from it) and its fit
    (a loaded material is not fitted again), for the SG and the matrix method."""
    tile = wb.geometry.pyramid()
    for method, kw in (("sg", dict(lobes=4)), ("matrix", dict(matrix={"normal_res": 9, "cache_dir": str(tmp_path)}))):
        mat = wb.bake(tile, glossy, method=method, directions=4, facets=1 << 10, backend="warp:cpu", **kw)
        path = os.path.join(tmp_path, f"{method}.wbm")
        mat.save(path)
        back = wb.load(path)
        m = back.materials[0]
        assert isinstance(m, MeasuredBRDF) and np.array_equal(m.data, glossy.data)
        assert m._sg_fit is not None and m.sg_fit().error == glossy.sg_fit().error
        np.testing.assert_array_equal(back.table(), mat.table())
