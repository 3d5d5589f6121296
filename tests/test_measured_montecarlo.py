"""A MeasuredBRDF on a large-scale object in the Monte Carlo reference (`wb.render(..., "mc")`,
`montecarlo.render`): F = its float64
`eval` times the cosine, sampled with the analytic BRDFs' half-vector vMF fitted to its table
(`montecarlo._measured_lobe`), on every backend present (the backend traces; the table is read on the host).

Tolerances: per pixel within 4σ / 4.5σ of the renderer's own standard error, as tests/test_montecarlo.py's
furnace tests (fixed seeds; the same checks passed with five other seeds there), against closed forms or a
float64 quadrature of the same integrand. The tabulation's own error is measured here by quadrature of the
tabulated and the analytic BRDF in the same scene, not assumed.
"""

import numpy as np
import pytest
from test_montecarlo import _frames, _furnace_quadrature, _z

import warp_biscale as wb
from warp_biscale import montecarlo as mc
from warp_biscale.environment import Environment
from warp_biscale.scene import Camera, Mesh, Scene

GLOSSY = wb.CookTorrance(0.8, 0.2, f0=0.9, kd=0.05)  # a metal-like lobe: the BRDF strategy matters


@pytest.fixture(scope="module")
def tabulated():
    """The MERL tables of Lambert(0.5) and GLOSSY, made once (from_brdf: ~1 s each on 2 cores)."""
    return {"lambert": wb.MeasuredBRDF.from_brdf(wb.Lambert(0.5)), "glossy": wb.MeasuredBRDF.from_brdf(GLOSSY)}


def test_fitted_lobe_of_tabulated_brdfs(tabulated):
    """The fitted half-vector sharpness η of a tabulated BRDF is close to the analytic one's SG sharpness (both
    match the NDF near its peak; the table's profile carries F·G/(4 cos²θh) too, so 5 % apart at most: 48.1
    against 50 here), its diffuse floor is the analytic kd (the profile's minimum, exact to rounding); a
    tabulated Lambert has no lobe at all, so it gets no BRDF strategy, as Lambert does."""
    kd, ks, eta = mc._measured_lobe(tabulated["glossy"])
    assert abs(eta / mc._glossy_eta(GLOSSY) - 1) < 0.05, eta
    assert kd == pytest.approx(0.05, rel=1e-9) and ks > 0
    kd, ks, eta = mc._measured_lobe(tabulated["lambert"])
    assert eta is None and ks == 0 and kd == pytest.approx(0.5, rel=1e-9)
    sharp = wb.BlinnPhong(1.0, 400.0, normalization="energy")
    eta = mc._measured_lobe(wb.MeasuredBRDF.from_brdf(sharp))[2]
    assert abs(eta / mc._glossy_eta(sharp) - 1) < 0.05, eta  # 0.011° θh bins resolve a sharp peak too


def test_furnace_tabulated_lambert_sphere_is_its_albedo(backend, tabulated):
    """Constant environment L = 1, a sphere of the tabulated Lambert(0.5): every hit pixel is 0.5 within 4σ and
    1 % (σ ≤ 1.25e-3 here; the bias of the geometric horizon is ≤ 5e-4 relative, see test_montecarlo). It has
    the strategies of Lambert (no lobe to sample), so it draws the very samples the analytic Lambert draws with
    the same seed: its image equals that one to float32 rounding (the table holds 0.5/π to float64 rounding)."""
    cam = Camera(eye=(0, 0, 4), fov=34, width=8, height=8)
    env = Environment(np.full((16, 32, 3), 1.0, np.float32))
    sphere = Mesh.sphere(1.0, subdivisions=4)
    r = wb.render(Scene(sphere, [tabulated["lambert"]], cam, env), "mc", backend=backend, samples=4096, seed=2)
    hit = r.info["stderr"].max(-1) > 0
    assert hit.sum() == r.info["hit_pixels"] >= 20
    assert list(r.info["strategies"][0]) == ["environment", "cosine"] and r.info["clamped"] == 0
    assert r.info["stderr_max"] < 0.00125
    assert np.abs(_z(r.image[hit], 0.5, r.info["stderr"][hit])).max() < 4
    assert np.abs(r.image[hit] - 0.5).max() < 0.005
    ref = mc.render(Scene(sphere, [wb.Lambert(0.5)], cam, env), backend=backend, samples=4096, seed=2)
    np.testing.assert_allclose(r.image, ref.image, rtol=1e-6, atol=0)


def test_tabulated_glossy_sphere_agrees_with_the_analytic_one(backend, tabulated):
    """A sphere of GLOSSY and one of its table, in a sky with a sun (its highlight is in view), 2048 samples:
    each image is its own BRDF's ∫ L·F·[ng·ω > 0] dω by float64 quadrature within 4.5σ per pixel, and the two
    images agree within 4.5 σ_pair + the tabulation's error — which the two quadratures measure: 0.23 % of the
    pixel at most (3.4e-4 absolute; bounded at 0.5 % below), against a per-pixel σ of ~2 %. The two use
    different BRDF strategies (the analytic SG sharpness 50 and the fitted 48.1, other sample shares), so they
    share no samples: their agreement is the estimator's, not a shared random stream's."""
    env = Environment.sky(height=16, width=32)
    cam = Camera(eye=(0, 0, 4), fov=34, width=8, height=8)
    out = {}
    for name, brdf in (("analytic", GLOSSY), ("table", tabulated["glossy"])):
        scene = Scene(Mesh.sphere(1.0, subdivisions=4), [brdf], cam, env)
        r = mc.render(scene, backend=backend, samples=2048, seed=5)
        assert list(r.info["strategies"][0]) == ["environment", "cosine", "brdf"] and r.info["clamped"] == 0
        frames = _frames(scene, backend)
        n, wo = frames[1], frames[4]
        def radiance(p, wl, w, brdf=brdf, n=n, wo=wo):  # L·f_r·cos θ at pixel p's quadrature directions
            return env.lookup(w) * wl[:, 2:3] * brdf.eval(np.broadcast_to(n[p], w.shape), w,
                                                          np.broadcast_to(wo[p], w.shape))

        expected = _furnace_quadrature(frames, radiance)
        img, err = r.image.reshape(-1, 3)[frames[0]], r.info["stderr"].reshape(-1, 3)[frames[0]]
        assert np.abs(_z(img, expected, err)).max() < 4.5, name
        out[name] = img, err, expected
    (img_a, err_a, q_a), (img_t, err_t, q_t) = out["analytic"], out["table"]
    tab_error = np.abs(q_t - q_a)
    assert (tab_error / q_a).max() < 0.005  # measured 0.23 %
    assert np.all(np.abs(img_t - img_a) <= 4.5 * np.hypot(err_a, err_t) + tab_error)
