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


# The fits of one-lobe tables run their sums in the Warp CPU kernels (seconds; lobes="auto" also tries a second
# lobe, which on the host in float64 takes several times longer): the host fit is the paint's, which
# test_fit_in_the_kernels_matches_the_host_fit compares with each backend's.
FIT_BACKEND = "warp:cpu"


@pytest.fixture(scope="module")
def glossy():
    table = MeasuredBRDF.from_brdf(GLOSSY)
    table.sg_fit(FIT_BACKEND)
    return table


@pytest.fixture(scope="module")
def paint():
    return ms.paint_like()


@pytest.mark.parametrize("brdf", [GLOSSY, wb.CookTorrance(1.0, 0.2)], ids=["coloured-m0.15", "ks1-m0.2"])
def test_fit_recovers_the_cook_torrance_that_made_the_table(brdf):
    """lobes="auto" keeps one lobe for a table of one Cook–Torrance lobe, and gives its parameters back."""
    fit = MeasuredBRDF.from_brdf(brdf).sg_fit(FIT_BACKEND)
    got = fit.brdf
    assert got.roughness == pytest.approx(brdf.roughness, rel=PARAM_TOL)
    assert got.f0 == pytest.approx(brdf.f0, rel=PARAM_TOL)
    np.testing.assert_allclose(got.ks, brdf.ks, rtol=PARAM_TOL)
    np.testing.assert_allclose(got.kd, brdf.kd, rtol=PARAM_TOL, atol=1e-6)
    assert 0 < fit.error < FIT_TOL and fit.samples > 100_000


PAINT_SHEEN = dict(ks=(0.12, 0.05, 0.04), roughness=0.35, f0=0.05)  # what `paint_like` tabulates by default
PAINT_COAT = dict(ks=(0.06, 0.06, 0.06), roughness=0.06, f0=0.05)
TWO_LOBE_TOL = 0.02  # relative, on the two lobes' ks, m and f0 (measured worst 0.86 %: the sheen's m 0.347)


def test_two_lobe_fit_of_a_paint_gives_back_its_sheen_and_coat(paint):
    """The synthetic paint (a Lambertian base, a broad sheen lobe and a sharp coat) is two lobes (Wang §4.2's
    "1 or 2 lobes"), and lobes="auto" keeps both: measured, the base's kd within 0.04 %, each lobe's ks, m and
    f0 within 0.9 %, relative error 4.8e-5 against one lobe's 2.7e-3 (that lobe, m 0.319, lies between the
    sheen's 0.35 and the coat's 0.06)."""
    fit = paint.sg_fit()
    assert len(fit.lobes) == 2 and fit.error < 1e-3 and fit.one_lobe_error > 10 * fit.error
    sheen, coat = fit.lobes  # the broader first, carrying kd
    np.testing.assert_allclose(sheen.kd, (0.55, 0.08, 0.05), rtol=0.01)
    np.testing.assert_array_equal(coat.kd, (0, 0, 0))
    for got, want in ((sheen, PAINT_SHEEN), (coat, PAINT_COAT)):
        np.testing.assert_allclose(got.ks, want["ks"], rtol=TWO_LOBE_TOL)
        assert got.roughness == pytest.approx(want["roughness"], rel=TWO_LOBE_TOL)
        assert got.f0 == pytest.approx(want["f0"], rel=TWO_LOBE_TOL)
    assert paint.sg_fit() is fit  # kept: a second use does not fit again
    with pytest.raises(ValueError, match="2 lobes"):
        fit.brdf  # noqa: B018 — a two-lobe fit has no one BRDF


def test_one_lobe_fit_of_a_paint_reports_what_it_misses(paint):
    """lobes=1 merges the sheen and the coat into one lobe between them, and its error says what that costs
    (measured 2.7e-3); `with_sg_fit` makes a copy that keeps it, sharing the table, and leaves the paint's."""
    table = paint.with_sg_fit(1)
    one = table.sg_fit()
    assert len(one.lobes) == 1 and 0.06 < one.brdf.roughness < 0.35 and 1e-3 < one.error < 0.02
    assert table.data is paint.data and len(paint.sg_fit().lobes) == 2
    with pytest.raises(ValueError, match="lobes must be"):
        ms.fit_sg(table, lobes=3)


def test_fit_error_shows_what_microfacet_lobes_cannot_hold():
    """A tabulated Blinn–Phong is not a microfacet BRDF (no F·G/(cosθi cosθo)): the fit's error says so
    (measured 0.48) rather than passing it off as a match, and a second lobe does not help (lobes="auto" keeps
    one)."""
    fit = MeasuredBRDF.from_brdf(wb.BlinnPhong(0.5, 128, kd=0.3, normalization="energy")).sg_fit(FIT_BACKEND)
    assert fit.error > 0.1 and len(fit.lobes) == 1


def test_fit_kernels_against_the_float64_sums(backend, paint):
    """The `sgfit` kernels' sums (normal equations and residuals) against `measured.fit_sums` (float64) on the
    paint's samples, for one-lobe candidates from a delta-like lobe to a broad one and for two-lobe ones.
    Tolerance: float32 samples and chunk sums of 1024 terms, added in float64: measured relative errors 7.7e-7
    on the normal equations and 7.5e-7 on the residuals (Warp CPU and PoCL alike; a residual subtracts nearly
    equal terms where the candidate fits) → 1e-5 and 1e-4."""
    basis, target, weight = ms.fit_samples(paint._table())
    cand = np.array([[2 / 0.01**2, 0.02, 0, 0], [2 / 0.06**2, 0.5, 0, 0], [2 / 0.32**2, 0.05, 0, 0],
                     [2 / 2.0**2, 1.0, 0, 0], [2 / 0.35**2, 0.05, 2 / 0.06**2, 0.05],
                     [2 / 2.0**2, 0.1, 2 / 0.01**2, 1.0]])
    data = backend.sg_fit_data(basis, target, weight)
    ref = ms.fit_sums(basis, target, weight, cand)
    got = backend.sg_fit_sums(data, cand)
    assert got.shape == (6, 15) and not ref[:4, [2, 4, 5, 12, 13, 14]].any()  # one lobe: no second lobe's sums
    gram_err = np.abs(got - ref).max(0) / np.maximum(np.abs(ref).max(0), 1e-300)
    coef = ms._nonnegative_coefficients(ref)
    ref_res = ms.fit_sums(basis, target, weight, cand, coef)
    res_err = np.abs(backend.sg_fit_sums(data, cand, coef) - ref_res) / ref_res
    print(f"{backend.name}: normal equations {gram_err.max():.1e}, residuals {res_err.max():.1e}")
    assert gram_err.max() < 1e-5 and res_err.max() < 1e-4


@pytest.mark.parametrize("columns", [3, 2])
def test_nonnegative_coefficients_against_nnls(columns):
    """The fit's non-negative solve of kd, ks1, ks2 from the normal equations against scipy's NNLS on the
    design matrix itself, for random problems whose unconstrained solutions fall in every octant; with two
    columns the second lobe is absent (b2 ≡ 0, as a one-lobe candidate's) and its coefficient must be 0."""
    from scipy.optimize import nnls

    rng = np.random.default_rng(5)
    for _ in range(200):
        a = rng.normal(size=(40, 3)) * rng.uniform(0.1, 3, 3)
        a[:, columns:] = 0.0
        t = a @ rng.normal(size=(3, 3)) + 0.3 * rng.normal(size=(40, 3))
        g = a.T @ a
        sums = np.concatenate([[g[0, 0], g[0, 1], g[0, 2], g[1, 1], g[1, 2], g[2, 2]], (a.T @ t).ravel()])
        got = ms._nonnegative_coefficients(sums[None])[0].reshape(3, 3)
        for c in range(3):
            want = np.zeros(3)
            want[:columns] = nnls(a[:, :columns], t[:, c])[0]
            np.testing.assert_allclose(got[:, c], want, atol=1e-9)


def test_fit_in_the_kernels_matches_the_host_fit(backend, paint):
    """`fit_sg(paint, backend)` (the sums in the kernels) against the float64 host fit: the same two lobes, and
    the same error of the one-lobe fit that "auto" starts from. Tolerances: Nelder–Mead stops at another point
    of the float32 objective's flat minimum; the fits are printed."""
    host = paint.sg_fit()
    dev = ms.fit_sg(paint, backend)
    print(f"{backend.name}: host {host}, device {dev}")
    assert dev.backend == backend.name and host.backend == "host"
    assert len(dev.lobes) == len(host.lobes) == 2
    assert dev.one_lobe_error == pytest.approx(host.one_lobe_error, rel=1e-3)
    for d, h in zip(dev.lobes, host.lobes):
        for a, b in ((d.roughness, h.roughness), (d.f0, h.f0)):
            assert a == pytest.approx(b, rel=2e-3, abs=1e-6)
        np.testing.assert_allclose(d.kd, h.kd, rtol=2e-3, atol=1e-6)
        np.testing.assert_allclose(d.ks, h.ks, rtol=2e-3, atol=1e-6)
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


def test_asg_bake_takes_a_table(backend, paint, paint_baked):
    """The ASG and SG bakes of the paint evaluate its two-lobe fit as the sum of its lobes: f̄ is linear in the
    small-scale BRDF, so the material equals the sum of its copies with each lobe alone (the first carries kd),
    to float64 rounding."""
    tile = wb.geometry.grooves()
    mat = wb.bake(tile, paint, method="asg", lobes=4, directions=5, facets=1 << 12, backend=backend)
    f = mat.table()
    assert np.isfinite(f).all() and f.min() >= 0 and f.max() > 0 and "sg_fit" in mat.info
    lobes = paint.sg_fit().lobes
    assert len(lobes) == 2
    for baked in (mat, paint_baked):
        n = len(baked.materials)
        split = sum(baked.with_materials([lobe] * n).table() for lobe in lobes)
        np.testing.assert_allclose(baked.table(), split, rtol=1e-12, atol=1e-14 * f.max())


def test_sg_renderer_shades_a_table_by_its_fit(backend, glossy):
    """A measured material on a large-scale object, and a baked one, render as their fits do, pixel for
    pixel, with no NaN or negative radiance (a lone sphere under a sky and a light: no SSDF to build); a table
    not fitted yet is fitted by the render in its backend's kernels."""
    mesh = wb.Mesh.sphere(1.0)
    cam = wb.Camera(eye=(0, 0.5, 3.5), width=48, height=36)
    lights = [wb.DirectionalLight()]
    sky = wb.Environment.sky(height=32, width=64)  # one object: its lighting is prepared once

    def image(material):
        return wb.render(wb.Scene(mesh, [material], cam, sky, lights), backend=backend, aa=1).image

    got = image(glossy)
    np.testing.assert_array_equal(got, image(glossy.sg_fit().brdf))
    fresh = MeasuredBRDF(glossy.data)
    image(fresh)
    assert fresh.sg_fit().backend == backend.name
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


def test_material_files_carry_a_two_lobe_fit(tmp_path, paint_baked):
    """A bake of the paint keeps both lobes of its fit through a file; a fit written before two-lobe fits (its
    lobe's fields at the top level of the header) reads back as one lobe."""
    path = os.path.join(tmp_path, "paint.wbm")
    paint_baked.save(path)
    back = wb.load(path)
    assert back.materials[0].sg_fit().to_dict()["lobes"] == paint_baked.materials[0].sg_fit().to_dict()["lobes"]
    np.testing.assert_array_equal(back.table(), paint_baked.table())
    old = {"kd": [0.2, 0.1, 0.0], "ks": [0.5, 0.5, 0.5], "roughness": 0.2, "f0": 0.04, "error": 1e-3, "seconds": 1.0,
           "samples": 10}
    fit = ms.SGFit.from_dict(old)
    assert len(fit.lobes) == 1 and fit.brdf.roughness == 0.2 and fit.one_lobe_error == fit.error


@pytest.fixture(scope="module")
def paint_asg(paint):
    """The paint baked by the ASG method on U-grooves: two sub-rows of ASG lobes in the shade stage."""
    tile = wb.geometry.grooves(profile="u")
    return wb.bake(tile, [paint] * tile.n_materials, method="asg", lobes=4, directions=6, facets=1 << 12,
                   backend="warp:cpu")


@pytest.fixture(scope="module")
def paint_baked(paint):
    """The paint (its two-lobe fit) baked on U-grooves: two sub-rows of one material in the shade stage."""
    tile = wb.geometry.grooves(profile="u")
    return wb.bake(tile, [paint] * tile.n_materials, lobes=4, directions=6, facets=1 << 12, backend="warp:cpu")


def test_shade_kernels_take_a_two_lobe_fit(backend, paint, paint_baked, paint_asg):
    """The shade kernels against their float64 reference (`shading.shade_reference`) on a scene whose
    materials have two-lobe SG forms: the paint on a sphere (two analytic rows), baked by the ASG method on a
    torus and by the SG method on the floor (two sub-rows sharing one table each); environment lobes through
    the SSDF, a point light with shadows. Tolerances as tests/test_shade.py's (float32 kernels against float64, the same
    formulas). And the kernels' sum over the rows is the sum of the lobes: the sphere shaded with the paint
    equals it shaded with each lobe alone, added (less the other materials' pixels, counted twice), to float32
    rounding."""
    from warp_biscale.render import pack_frame
    from warp_biscale.shading import pack_materials, shade_reference

    packed = pack_materials([paint, paint_asg, paint_baked])
    assert packed["mat_info"][:, 2].tolist() == [2, 1, 1] and len(packed["analytic"]) == 2
    assert len(packed["eff_sub"]) == 2 * (len(paint_asg.materials) + len(paint_baked.materials))
    # The per-row tables are made once, then kept: a second pack gives the same memory (the backends then keep
    # its device copy).
    first, again = pack_materials([paint_baked]), pack_materials([paint_baked])
    for role in ("eff_tables", "eff_diffuse"):
        assert first[role].__array_interface__ == again[role].__array_interface__
    mesh = wb.Mesh.merge([wb.Mesh.sphere(0.6, (0.0, 0.6, 0.0), subdivisions=3, material=0),
                          wb.Mesh.torus(0.5, 0.18, center=(1.1, 0.2, 0.0), segments=(32, 16), material=1),
                          wb.Mesh.plane(4.0, 0.0, 12, material=2)])
    sky = wb.Environment.sky(height=32, width=64)

    def shade(first, reference=False):
        scene = wb.Scene(mesh, [first, paint_asg, paint_baked],
                         wb.Camera(eye=(0.0, 2.2, 3.5), target=(0.2, 0.3, 0.0), width=40, height=32, fov=50),
                         sky, [wb.PointLight((1.5, 3.0, 1.0), 10.0, 0.2)], ssdf_resolution=16, ssdf_terms=8)
        frame = pack_frame(scene, backend)
        out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
        return (out, shade_reference(frame)) if reference else out

    out, ref = shade(paint, reference=True)
    assert np.isfinite(out).all() and (out >= 0).all()
    peak, err = ref.max(), np.abs(out - ref)
    msg = f"max err {err.max():.3g}, peak {peak:.3g}, p99.9 {np.quantile(err, 0.999):.3g}"
    sheen, coat = paint.sg_fit().lobes
    added = shade(sheen) + shade(coat) - shade(wb.Lambert(0.0))
    msg += f"; paint against its lobes added: max {np.abs(out - added).max():.3g}"
    print(f"{backend.name}: {msg}")
    assert np.quantile(err / (np.abs(ref) + 1e-3 * peak), 0.999) < 2e-3, msg
    assert err.max() < 2e-2 * peak, msg
    assert np.abs(shade(sheen) - out).max() > 1e-3 * peak  # the coat's lobe shows (measured: 3.0e-3 of 0.90)
    np.testing.assert_allclose(out, added, rtol=1e-5, atol=1e-6 * peak, err_msg=msg)


def test_two_lobe_fit_brings_the_sg_bake_closer_to_the_table(paint):
    """The SG bake of the paint with its two-lobe fit against the table's own ground truth, beside the bake of
    the one-lobe fit on the same facets (f̄ is linear in the small-scale BRDF's lobes: `with_materials` on a
    copy of the table fitted with one lobe). Measured (warp:cpu, pyramid, K = 6, 2^12 facets, truth 2^14):
    see the message; the two-lobe bake must be the closer."""
    tile = wb.geometry.pyramid(height=0.5)
    two = wb.bake(tile, paint, lobes=8, directions=6, facets=1 << 12, backend="warp:cpu")
    one = two.with_materials([paint.with_sg_fit(1, "warp:cpu")])
    assert len(two.info["sg_fit"]["0"]["lobes"]) == 2
    truth = wb.ground_truth(tile, paint, directions=6, facets=1 << 14, backend="warp:cpu")
    psnr_two, psnr_one = wb.compare(two, truth)["psnr"], wb.compare(one, truth)["psnr"]
    print(f"two lobes {psnr_two:.2f} dB, one lobe {psnr_one:.2f} dB")
    assert psnr_two > psnr_one


def test_a_lit_sphere_of_a_material_baked_over_a_table(backend, paint_baked):
    """An SG bake over a MERL table (its two-lobe fit: two rows of one material, where the texel kernels read one)
    makes its lit spheres on the host, from the bake's own f̄, whatever backend is asked: `LitSphere.from_material`
    with a backend equals the host's, instead of refusing the table's packed row."""
    on_backend = wb.LitSphere.from_material(paint_baked, angles=[0, 90], resolution=32, backend=backend)
    on_host = wb.LitSphere.from_material(paint_baked, angles=[0, 90], resolution=32)
    assert on_host.images.max() > 0
    np.testing.assert_array_equal(on_backend.images, on_host.images)
