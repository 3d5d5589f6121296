"""The matrix method as a bake (Wu 2011 §3.4–§3.7): M in kernels on every backend, `wb.bake(..., method="matrix")`
and its `MatrixBRDF` (eval, compare, save/load, with_materials, rendering).

Tolerances, each measured here (Warp CPU and PoCL, numpy 2) and given headroom:

- M by the kernels (kernels/matrix.py, cl/matrix.cl: float32, the ground truth's `brdf_cosine_weighted`)
  against `matrix.brdf_matrix` (float64): measured ≤ 5.4e-6 of M's peak for Blinn–Phong n = 64, Cook–Torrance
  m = 0.2 and Ward α = 0.25, and 2.1e-5 for Cook–Torrance m = 0.05, whose D = exp(−(θh/m)²) turns float32's
  rounding of acos near n·h = 1 into (2θh/m²)·δθ (both backends the same) → 1e-4 of the peak, as
  tests/test_stages.py's 2e-4 for the same BRDF code. Wu §3.7's colour direction from the kernels' diffuse and
  specular parts (two float32 passes) against numpy's: measured ≤ 7.4e-8, its residual ≤ 3.1e-8 → 1e-6.
- The flat Lambertian tile through the whole matrix bake, every singular value of M kept: f̄ = (kd/π)cos θi
  to 3.2e-7 of the peak in the table and 2.8e-7 in `eval` off the grid (float32 N and kernels; the
  octahedral map puts +z, the tile's one normal, on a texel centre) → 1e-5. With Wu's 98 % of M's power the
  truncation is a real error (18 % of the peak, as tests/test_matrix.py measures) → between 5 % and 25 %.
- The pyramid with Cook–Torrance m = 0.2 (K = 6, 2^12 facets, M at R = 25, 98 % of M's power) against a
  2^14-facet ground truth: measured 39.6 dB on both backends → above Wu Table 4's lowest, 17.36 dB (his
  target), and above 30 dB so that a regression of the method shows. A 6×6 height field with two materials
  and per-face colours (three N channels each, Wu §3.7's colour weights; Lambert and a Cook–Torrance whose kd
  and ks differ in colour; K = 5, 2^12 facets, R = 17, a 2^14-facet truth): 37.7 dB → above 30 dB.
- with_materials against a fresh bake of the same tile with the new materials (its geometry cache cleared, so
  N is made again from the facets): the same kernels, the same seeds and the same cached M factors, so the
  tables are identical; a save/load round trip keeps every array bit for bit.
- The lit-sphere render of the flat Lambertian matrix material against that of Lambert(kd) itself: measured
  2.4e-7 of the brightest pixel → 1e-5. The Monte Carlo reference renders a Lambertian matrix material by its
  ground truth (no BRDF sampling needed), the same samples as for Lambert(kd): 2.4e-7 → 1e-5.
"""

import os
import pickle
import re
import sys
import types

import numpy as np
import pytest
from conftest import flat_tile, random_heightfield

import warp_biscale as wb
from warp_biscale import matrix as mx
from warp_biscale.brdf import pack_materials

BRDFS = [wb.Lambert([0.2, 0.5, 0.9]), wb.BlinnPhong([0.2, 0.1, 0.04], 64, kd=[0.1, 0.2, 0.3]),
         wb.CookTorrance([1.0, 0.8, 0.6], 0.2, 0.3, kd=[0.1, 0.1, 0.2]), wb.Ward([0.5, 0.6, 0.7], 0.25, kd=0.1),
         wb.CookTorrance(1.0, 0.05)]
CT = wb.CookTorrance([1.0, 0.8, 0.6], 0.2)
bake_module = sys.modules["warp_biscale.bake"]  # (wb.bake is the function)


@pytest.fixture(autouse=True)
def factor_cache(tmp_path, monkeypatch):
    """Each test's M factors in a folder of its own (the default cache is the user's home)."""
    monkeypatch.setenv("WARP_BISCALE_MATRIX_CACHE", str(tmp_path / "factors"))
    return tmp_path / "factors"


def _sphere(count, seed):
    v = np.random.default_rng(seed).standard_normal((count, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


# ------------------------------------------------------------------------------------------------ M in kernels


def test_m_kernels_against_float64(backend):
    """M[l, k] = d·f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺ by the `matrix` stage against the float64
    `brdf_matrix`, over the octahedral texels (the rows a material's M has), random normals (those facing
    down reflect grazing light only) and the pole, for every unordered pair of a K = 5 grid."""
    g = wb.directions.grid(5)
    pi, po = wb.directions.unordered_pairs(len(g))
    normals = np.concatenate([mx.octahedral_normals(17), _sphere(50, 3), [[0, 0, 1.0]]])
    d = np.array([0.3, 0.5, 0.81])
    for brdf in BRDFS:
        kinds, params = pack_materials([brdf])
        got = backend.brdf_matrix(kinds, params, 0, normals, g[pi], g[po], d)
        assert got.dtype == np.float32 and got.shape == (len(normals), len(pi))
        want = mx.brdf_matrix(brdf, normals, g, color=d)
        peak = np.abs(want).max()
        assert peak > 0
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * peak, err_msg=repr(brdf))
        # Wu §3.7's colour direction, its diffuse and specular parts tabulated by the kernels.
        dk, rk = mx.color_direction(brdf, normals, g, backend=backend)
        dh, rh = mx.color_direction(brdf, normals, g)
        np.testing.assert_allclose(dk, dh, atol=1e-6)
        assert abs(rk - rh) <= 1e-6
    # Row blocks made by the kernels (the SVD's passes over an M too large to hold) are M's rows.
    rows = mx.brdf_rows(BRDFS[2], normals, g, color=d, rows_per_block=40, backend=backend)
    want = mx.brdf_matrix(BRDFS[2], normals, g, color=d)
    np.testing.assert_allclose(rows.dense(), want, rtol=0, atol=1e-4 * np.abs(want).max())
    assert backend.brdf_matrix(*pack_materials([CT]), 0, np.zeros((0, 3)), g[pi], g[po], d).shape == (0, len(pi))


def test_material_factors_by_kernels_match_numpy(backend):
    """The factors of M made from the kernels' float32 blocks (dense and streamed) hold the same rank and
    reconstruct the same M as numpy's float64 ones: the float32 tabulation is far below the 2 % of M's power
    the truncation drops."""
    ct = BRDFS[2]
    mx._MEMORY.clear()
    host = mx.material_factors(ct, directions=4, normal_res=9, cache_dir=False)
    mx._MEMORY.clear()
    dev = mx.material_factors(ct, directions=4, normal_res=9, cache_dir=False, backend=backend)
    mx._MEMORY.clear()
    streamed = mx.material_factors(ct, directions=4, normal_res=9, cache_dir=False, backend=backend, memory_budget=0)
    assert dev.info["m_source"] == backend.name and host.info["m_source"] == "numpy" and streamed.info["streamed"]
    a = host.factors.reconstruct()
    for f in (dev, streamed):
        assert f.rank == host.rank
        np.testing.assert_allclose(f.color, host.color, atol=1e-6)
        np.testing.assert_allclose(f.factors.reconstruct(), a, rtol=0, atol=1e-4 * np.abs(a).max())
    mx._MEMORY.clear()


# ------------------------------------------------------------------------------------------------ the bake


def test_flat_lambertian_through_the_matrix_bake(backend):
    """The first test of every method: f̄ = (kd/π)cos θi, on the grid and off it."""
    kd = np.array([0.2, 0.5, 0.8])
    color = np.array([1.0, 0.9, 0.7])
    tile = wb.SmallScale(flat_tile().vertices, flat_tile().faces, colors=np.tile(color, (2, 1)), name="flat")
    k = 6
    g = wb.directions.grid(k)
    want = np.broadcast_to((kd * color)[None, None, :] / np.pi * g[:, 2][:, None, None], (k * k, k * k, 3))
    mat = wb.bake(tile, wb.Lambert(kd), method="matrix", directions=k, facets=2048, backend=backend,
                  matrix={"normal_res": 9, "power": 1.0})
    assert isinstance(mat, wb.MatrixBRDF) and isinstance(mat, wb.EffectiveBRDF) and mat.method == "matrix"
    assert mat.info["nonempty_bins"] == 1 and mat.info["m_factors"]["0"]["normal_res"] == 9
    np.testing.assert_allclose(mat.table(), want, rtol=0, atol=1e-5 * want.max())
    rng = np.random.default_rng(1)
    wi = wb.directions.square_to_hemisphere(rng.random((400, 2)))
    wo = wb.directions.square_to_hemisphere(rng.random((400, 2)))
    np.testing.assert_allclose(mat.eval(wi, wo), (kd * color) / np.pi * wi[:, 2:3], rtol=0, atol=1e-5 * want.max())
    assert (mat.eval(wi * [1, 1, -1], wo) == 0).all()  # below the horizon
    # Wu's 98 % of M's power: the truncation's own error (at grazing ωo, where f̄ divides by a_v).
    wu = wb.bake(tile, wb.Lambert(kd), method="matrix", directions=k, facets=2048, backend=backend,
                 matrix={"normal_res": 9})
    err = np.abs(wu.table() - want).max() / want.max()
    assert 0.05 < err < 0.25
    assert set(wu.timings) == {"m_factors", "tables"}  # the tile's N was cached by the first bake


def test_pyramid_cook_torrance_against_the_ground_truth(backend):
    """Wu Table 4's metric (PSNR of the cosine-weighted f̄ over every pair, `wb.compare`) above his 17 dB,
    with his 98 % of M's power and 99.5 % of N's; the stages are timed and the factors' memory reported."""
    tile = wb.geometry.pyramid()
    k = 6
    mat = wb.bake(tile, CT, method="matrix", directions=k, facets=1 << 12, backend=backend,
                  matrix={"normal_res": 25})
    gt = wb.ground_truth(tile, CT, facets=1 << 14, directions=k, backend=backend)
    psnr = wb.compare(mat, gt)["psnr"]
    assert psnr > 30 > 17.36
    assert {"facets", "visibility", "bvndf", "n_factors", "m_factors", "tables"} <= set(mat.timings)
    m0 = mat.info["m_factors"]["0"]
    assert m0["power_kept"] >= mx.M_POWER and 0 < m0["rank"] < min(m0["rows"], m0["columns"])
    assert mat.factor_bytes["m"][0] == m0["bytes"] == mat.factors[0].nbytes < m0["matrix_bytes"]
    assert mat.factor_bytes["n"] == sum(f.nbytes for *_, f in mat.channels) > 0
    assert mat.info["factor_bytes"] == {"n": mat.factor_bytes["n"], "m": {"0": m0["bytes"]}}
    # compare on another grid: through eval
    coarse = wb.ground_truth(tile, CT, facets=1 << 12, directions=4, backend=backend)
    assert wb.compare(mat, coarse)["psnr"] > 17.36


def test_colour_weights_and_two_materials(backend):
    """Wu §3.7: per-face colours (N per colour channel), two materials, a BRDF whose kd and ks differ in
    colour (M projected on its principal colour direction), against the ground truth."""
    tile = random_heightfield(n=6, materials=2, seed=3)
    mats = [wb.Lambert([0.6, 0.5, 0.4]), wb.CookTorrance([1.0, 0.8, 0.6], 0.3, kd=[0.1, 0.1, 0.2])]
    mat = wb.bake(tile, mats, method="matrix", directions=5, facets=1 << 12, normal_res=16, backend=backend,
                  matrix={"normal_res": 17})
    assert mat.info["channels"] == 6  # three colour channels per material
    assert mat.info["m_factors"]["1"]["color_residual"] > 0 == mat.info["m_factors"]["0"]["color_residual"]
    gt = wb.ground_truth(tile, mats, facets=1 << 14, directions=5, backend=backend)
    assert wb.compare(mat, gt)["psnr"] > 30
    np.testing.assert_allclose(mat.tables.sum(0), mat.table(), rtol=1e-6, atol=1e-9)


def test_with_materials_equals_a_fresh_bake(backend):
    """A material-only edit (Eq. 12 from the cached N and the new materials' M factors) gives the tables a
    fresh bake with those materials gives, and costs no geometry."""
    tile = wb.geometry.pyramid()
    kw = dict(method="matrix", directions=4, facets=1 << 10, backend=backend, matrix={"normal_res": 9})
    mat = wb.bake(tile, CT, **kw)
    ward = wb.Ward([0.5, 0.6, 0.7], 0.25, kd=0.1)
    edit = mat.with_materials(ward)
    assert set(edit.timings) == {"m_factors", "tables"} and edit.provenance is mat.provenance
    assert edit.materials == [ward] and edit.channels is not mat.channels
    bake_module._GEOMETRY.pop(tile, None)  # N made again from the facets
    fresh = wb.bake(tile, ward, **kw)
    assert "visibility" in fresh.timings
    np.testing.assert_array_equal(edit.tables, fresh.tables)
    np.testing.assert_array_equal(edit.eval(wb.directions.grid(7), wb.directions.grid(7)[::-1]),
                                  fresh.eval(wb.directions.grid(7), wb.directions.grid(7)[::-1]))
    # Back to the first material: its factors come from the cache; the tables are the first bake's.
    back = edit.with_materials(CT)
    assert back.info["m_factors"]["0"]["source"] == "cache"
    np.testing.assert_array_equal(back.tables, mat.tables)


def test_save_load_round_trip(tmp_path):
    tile = random_heightfield(n=4, materials=2, seed=5)
    mats = [wb.Lambert([0.6, 0.5, 0.4]), wb.BlinnPhong(0.2, 32, kd=0.2)]
    mat = wb.bake(tile, mats, method="matrix", directions=4, facets=1 << 11, normal_res=16, backend="warp:cpu",
                  matrix={"normal_res": 9})
    path = tmp_path / "m.wbm"
    mat.save(path)
    assert mat.path == str(path)
    back = wb.load(path)
    assert isinstance(back, wb.MatrixBRDF) and back.path == str(path)
    np.testing.assert_array_equal(back.tables, mat.tables)
    np.testing.assert_array_equal(back.table(), mat.table())
    g = wb.directions.grid(5)
    np.testing.assert_array_equal(back.eval(g, g[::-1]), mat.eval(g, g[::-1]))
    assert back.materials == mat.materials and back.directions == mat.directions
    assert back.info == mat.info and back.timings == mat.timings
    assert back.factor_bytes == {"n": mat.factor_bytes["n"], "m": mat.factor_bytes["m"]}
    for (m1, c1, f1), (m2, c2, f2) in zip(mat.channels, back.channels):
        assert m1 == m2
        np.testing.assert_array_equal(c1, c2)
        np.testing.assert_array_equal(f1.reconstruct(), f2.reconstruct())
    for name, arr in mat.bvndf.arrays().items():
        np.testing.assert_array_equal(getattr(back.bvndf, name), arr)
    assert back.provenance.seed == mat.provenance.seed and back.provenance.facets == mat.provenance.facets
    np.testing.assert_array_equal(back.provenance.tile.vertices, tile.vertices)
    assert wb.truth.truth_key(back) == wb.truth.truth_key(mat)  # the same ground truth
    assert back.factors == [None, None]  # M's factors stay in their cache, fetched by an edit
    again = pickle.loads(pickle.dumps(mat))  # (a batch task's result; the backend is left behind)
    assert again._backend is None and again.factors[1].rank == mat.factors[1].rank
    np.testing.assert_array_equal(again.table(), mat.table())
    edit = wb.Ward(0.4, 0.3)
    np.testing.assert_array_equal(back.with_materials([mats[0], edit]).tables,
                                  mat.with_materials([mats[0], edit]).tables)
    # A corrupt or foreign file is a one-line error.
    bad = tmp_path / "bad.wbm"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="truncated or corrupt"):
        wb.load(bad)
    wb.bake(tile, mats, directions=4, facets=1 << 10, backend="warp:cpu").save(tmp_path / "sg.wbm")
    assert type(wb.load(tmp_path / "sg.wbm")) is wb.EffectiveBRDF  # wb.load tells the two apart
    with pytest.raises(ValueError, match="not a warp_biscale.matrix_brdf"):
        wb.MatrixBRDF.load(tmp_path / "sg.wbm")


# ------------------------------------------------------------------------------------------------ rendering


def test_rendered_by_the_lit_sphere_refused_by_sg_and_mc(backend):
    """render(method="litsphere") makes its lit sphere by `eval` on the host; the flat Lambertian one renders
    as Lambert(kd) itself, and so does the Monte Carlo reference (by its ground truth). The SG renderer, and
    the Monte Carlo reference's sampling of a glossy one, need SG lobes: one line naming the method to use."""
    kd = np.array([0.2, 0.5, 0.8])
    mat = wb.bake(flat_tile(), wb.Lambert(kd), method="matrix", directions=6, facets=2048, backend=backend,
                  matrix={"normal_res": 9, "power": 1.0})
    cam = wb.Camera(eye=(0, 0, 4), width=40, height=30)
    lights = [wb.PointLight((2, 3, 2), 20.0)]
    a = wb.render(wb.Scene(wb.Mesh.sphere(), [mat], cam, None, lights), method="litsphere", backend=backend,
                  resolution=64).image
    b = wb.render(wb.Scene(wb.Mesh.sphere(), [wb.Lambert(kd)], cam, None, lights), method="litsphere",
                  backend=backend, resolution=64).image
    assert b.max() > 0 and np.isfinite(a).all()
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5 * b.max())
    small = wb.Camera(eye=(0, 0, 4), width=16, height=12)
    a = wb.render(wb.Scene(wb.Mesh.sphere(), [mat], small, None, lights), method="mc", backend=backend, samples=16,
                  truth_facets=1024)
    b = wb.render(wb.Scene(wb.Mesh.sphere(), [wb.Lambert(kd)], small, None, lights), method="mc", backend=backend,
                  samples=16)
    assert "ground truth" in a.info["effective_brdf"][0]
    np.testing.assert_allclose(a.image, b.image, rtol=0, atol=1e-5 * b.image.max())
    glossy = mat.with_materials(wb.CookTorrance(1.0, 0.3))
    scene = wb.Scene(wb.Mesh.sphere(), [glossy], wb.Camera(eye=(0, 0, 4), width=8, height=6), None, lights)
    for method, options in (("sg", {}), ("mc", {"samples": 4, "truth_facets": 256})):
        with pytest.raises(ValueError, match="method='litsphere'") as info:
            wb.render(scene, method=method, backend=backend, **options)
        assert "\n" not in str(info.value)


def test_sg_renderer_refuses_before_any_setup(monkeypatch):
    """The SG renderer's refusal of a matrix material comes before the lighting fit and the SSDF (it came after
    them, 3 s into a render), with the material's own message."""
    mat = wb.bake(flat_tile(), wb.Lambert(0.5), method="matrix", directions=4, facets=256, backend="warp:cpu",
                  matrix={"normal_res": 9})
    render_module = sys.modules["warp_biscale.render"]

    def no_setup(*args, **kwargs):
        raise AssertionError("the render's setup ran before its materials were checked")

    monkeypatch.setattr(render_module, "_static_inputs", no_setup)
    monkeypatch.setattr(render_module.lighting, "prepare", no_setup)
    scene = wb.Scene(wb.Mesh.sphere(), [wb.Lambert(0.2), mat], wb.Camera(eye=(0, 0, 4), width=8, height=6),
                     wb.Environment.sky(height=8, width=16))
    with pytest.raises(ValueError, match="^" + re.escape(mx.NO_LOBES) + "$"):
        wb.render(scene, backend="warp:cpu")


def test_mc_and_the_lit_spheres_error_report_refuse_a_glossy_matrix_bake_before_any_work(monkeypatch):
    """The Monte Carlo reference cannot sample a glossy matrix bake's lobes (it has none): refused before its ground
    truth is computed. The lit-sphere render's report_error, whose references (SG, MC) cannot render it, refuses
    before the lit spheres are made; without report_error the lit-sphere render goes on."""
    from warp_biscale import truth as truth_mod

    glossy = wb.bake(flat_tile(), wb.CookTorrance(1.0, 0.3), method="matrix", directions=4, facets=256,
                     backend="warp:cpu", matrix={"normal_res": 9})
    scene = wb.Scene(wb.Mesh.sphere(), [glossy], wb.Camera(eye=(0, 0, 4), width=8, height=6), None,
                     [wb.PointLight((2, 3, 2), 20.0)])
    render_module = sys.modules["warp_biscale.render"]

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the materials were checked")

    with monkeypatch.context() as m:
        m.setattr(truth_mod, "ground_truth", no_work)
        m.setattr(render_module, "scene_spheres", no_work)
        with pytest.raises(ValueError, match="^" + re.escape(mx.NO_LOBES) + "$"):
            wb.render(scene, method="mc", backend="warp:cpu", samples=4, truth_facets=256)
        for refs, named in ((True, "sg, mc"), (["mc"], "mc")):
            with pytest.raises(ValueError, match=rf"^report_error: its references \({named}\) cannot render "
                                                 r"materials\[0\] \(MatrixBRDF, a matrix bake\): leave report_error "
                                                 "out"):
                wb.render(scene, method="litsphere", backend="warp:cpu", report_error=refs, samples=4)
    assert np.isfinite(wb.render(scene, method="litsphere", backend="warp:cpu", resolution=32).image).all()


# ------------------------------------------------------------------------------------------------ bad input


def test_bad_inputs_are_one_line_errors(tmp_path):
    tile = flat_tile()
    lam = wb.Lambert(0.5)
    cases = [
        (dict(matrix={"normal_res": 8}), "odd integer"),
        (dict(matrix={"normal_res": "big"}), "odd integer"),
        (dict(matrix={"power": 0}), "power must be"),
        (dict(matrix={"n_power": 1.5}), "n_power must be"),
        (dict(matrix={"rank": 3}), "unknown matrix option"),
        (dict(matrix=[("power", 0.9)]), "must be a dict"),
        (dict(matrix={"oversample": -1}), "oversample must be"),
        (dict(matrix={"search": 3}), "search must be"),
        (dict(matrix={"cache_dir": 3}), "cache_dir must be"),
        (dict(directions=40), "directions must be"),
        (dict(directions=4.5), "directions must be"),
        (dict(normal_res=0), "normal_res must be"),
        (dict(facets=0), "facets must be"),
    ]
    for kw, match in cases:
        with pytest.raises(ValueError, match=match) as info:
            wb.bake(tile, lam, **{"method": "matrix", "backend": "warp:cpu", **kw})
        assert "\n" not in str(info.value), kw
    with pytest.raises(ValueError, match="options of method='matrix'"):
        wb.bake(tile, lam, matrix={"power": 0.9}, backend="warp:cpu")
    with pytest.raises(ValueError, match="'matrix'"):
        wb.bake(tile, lam, method="matrx", backend="warp:cpu")
    with pytest.raises(ValueError, match="Backend object"):
        mx.material_factors(lam, directions=4, normal_res=9, cache_dir=False, backend="warp:cpu")
    mat = wb.bake(tile, lam, method="matrix", directions=4, facets=256, backend="warp:cpu", matrix={"normal_res": 9})
    g = wb.directions.grid(4)
    with pytest.raises(ValueError, match="method 'matrix'"):
        mat.eval(g, g, method="sg")
    with pytest.raises(ValueError, match="same length"):
        mat.eval(g, g[:3])
    with pytest.raises(ValueError, match="NaN"):
        mat.eval(g * np.nan, g)
    with pytest.raises(ValueError, match="not a BRDF"):
        mat.with_materials([lam, "gold"])
    two = wb.bake(random_heightfield(n=4, materials=2, seed=5), [lam, lam], method="matrix", directions=4,
                  facets=512, normal_res=8, backend="warp:cpu", matrix={"normal_res": 9})
    with pytest.raises(ValueError, match="material ids up to 1"):
        two.with_materials(lam)
    for attr in ("lobes", "amplitudes", "diffuse"):
        with pytest.raises(ValueError, match="method='litsphere'"):
            getattr(mat, attr)
    with pytest.raises(ValueError, match="method='litsphere'"):
        mat.export_mitsuba(tmp_path / "mitsuba")
    assert not os.path.exists(tmp_path / "mitsuba")
    assert wb.compare(mat, types.SimpleNamespace(directions=4, table=mat.table()))["psnr"] == float("inf")


def test_mc_renders_a_scene_that_lists_a_glossy_matrix_bake_no_object_uses():
    """The Monte Carlo reference asks its sampling lobes only of the materials in view: a glossy matrix bake that no
    object uses does not stop the render (it did not before the up-front refusal of those in view)."""
    glossy = wb.bake(flat_tile(), wb.CookTorrance(1.0, 0.3), method="matrix", directions=4, facets=256,
                     backend="warp:cpu", matrix={"normal_res": 9})
    scene = wb.Scene(wb.Mesh.sphere(), [wb.Lambert(0.5), glossy], wb.Camera(eye=(0, 0, 4), width=8, height=6), None,
                     [wb.PointLight((2, 3, 2), 20.0)])
    out = wb.render(scene, method="mc", backend="warp:cpu", samples=4)
    assert np.isfinite(out.image).all() and out.image.max() > 0
    lit = wb.render(scene, method="litsphere", backend="warp:cpu", resolution=32, report_error=["mc"], samples=4)
    assert "mc" in lit.info["error"]
