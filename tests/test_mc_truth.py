"""The Monte Carlo reference judges a baked material by its exact ground truth, rebuilt from what the material
records of how it was baked (`EffectiveBRDF.provenance`), cached beside its material file and in memory.

Tolerances: none. The ground-truth kernels are deterministic (fixed summation order, no float atomics,
docs/design.md §4.8), so a truth computed from the recorded tile is bit-identical to one computed by hand from
the original tile with the same settings, and Monte Carlo with the same seed, samples and batch draws the same
samples: the images are compared for equality. Sizes are tiny (K = 4, 2^10 facets, 10×10 pixels, 16 samples):
what is checked is which f̄ is used, not how well it converges.
"""

import json

import numpy as np
import pytest
from conftest import random_heightfield, vgroove_tile
from test_cli import TINY_SCENE, run_cli_in_process

import warp_biscale as wb
from warp_biscale import montecarlo as mc
from warp_biscale import truth as truth_mod
from warp_biscale.effective import EffectiveBRDF
from warp_biscale.scene import Camera, Mesh, PointLight, Scene

K, BAKE_FACETS, TRUTH_FACETS, SAMPLES = 4, 512, 1024, 16
GLOSSY = [wb.BlinnPhong(0.2, 32.0, kd=0.2)]  # (directional albedo < 1: no EnergyWarning)


@pytest.fixture(autouse=True)
def empty_truth_memory():
    """Each test starts with no ground truth remembered in this process, so what it sees reused came from disk."""
    truth_mod._MEMORY.clear()
    yield
    truth_mod._MEMORY.clear()


def _bake(mats=GLOSSY, backend="warp:cpu", tile=None):
    return wb.bake(tile or vgroove_tile(), mats, lobes=2, directions=K, facets=BAKE_FACETS, normal_res=16,
                   backend=backend)


def _scene(*materials):
    """A sphere (material 0) in front of a plane (the last material), in a sky with one light."""
    sphere = Mesh.sphere(1.0, subdivisions=2, material=0)
    floor = Mesh.plane(6.0, -1.0, divisions=2, material=len(materials) - 1)
    return Scene(Mesh.merge([sphere, floor]), list(materials),
                 Camera(eye=(0, 0.5, 4), fov=40, width=10, height=10),
                 wb.Environment.sky(height=8, width=16), [PointLight((2, 2, 3), 10.0, 0.1)])


def _mc(scene, backend="warp:cpu", **kw):
    return mc.render(scene, backend=backend, samples=SAMPLES, seed=5, truth_facets=TRUTH_FACETS, **kw)


class _CountingGroundTruth:
    """Stands in for truth.ground_truth: counts the calls and, when `refuse` is set, fails instead of computing."""

    def __init__(self):
        self.calls, self.refuse, self._real = 0, False, truth_mod.ground_truth

    def __call__(self, *args, **kwargs):
        if self.refuse:
            raise AssertionError("ground_truth was computed again where a cached one should have been used")
        self.calls += 1
        return self._real(*args, **kwargs)


@pytest.fixture
def counting(monkeypatch):
    spy = _CountingGroundTruth()
    monkeypatch.setattr(truth_mod, "ground_truth", spy)
    return spy


def _v1_file(mat, path):
    """`mat` written as a format-1 material file: what warp_biscale wrote before the provenance, i.e. a format-2
    file without its tile arrays and provenance header."""
    mat.save(path)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if not k.startswith("tile_")}
    head = json.loads(str(arrays["header"]))
    assert head["version"] == 2 and head["provenance"] is not None
    del head["provenance"]
    head["version"] = 1
    arrays["header"] = np.array(json.dumps(head))
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


# ---------------------------------------------------------------------------------------------------
# the reference uses the exact ground truth of what it judges
# ---------------------------------------------------------------------------------------------------


def test_mc_of_a_baked_material_equals_mc_with_its_truth_passed_by_hand(backend):
    tile = vgroove_tile()
    mat = _bake(backend=backend, tile=tile)
    assert mat.provenance.tile is tile and mat.provenance.seed == 0 and mat.provenance.facets == BAKE_FACETS
    scene = _scene(mat, wb.Lambert(0.5))
    auto = _mc(scene, backend)
    # By hand: the tile and BRDFs it was baked from, on its grid; the truth's seed is the bake's + 1.
    gt = wb.ground_truth(tile, GLOSSY, facets=TRUTH_FACETS, directions=K, backend=backend, seed=1)
    by_hand = _mc(scene, backend, truths={0: gt})
    assert auto.info["truth_source"] == {0: "computed"} and by_hand.info["truth_source"] == {0: "given"}
    assert auto.info["effective_brdf"][0].startswith("ground truth (tile 'vgroove', K=4, 1024 facets")
    np.testing.assert_array_equal(auto.image, by_hand.image)
    np.testing.assert_array_equal(auto.info["stderr"], by_hand.info["stderr"])
    # Which f̄ is used shows in the image: the SG fit gives another one.
    with pytest.warns(UserWarning, match="fallback='sg'"):
        fit = _mc(scene, backend, fallback="sg")
    assert not np.array_equal(fit.image, auto.image)
    # A second render in this process reuses the table (no file: the material was never saved).
    again = _mc(scene, backend)
    assert again.info["truth_source"] == {0: "memory"}
    np.testing.assert_array_equal(again.image, auto.image)


def test_render_driver_forwards_the_truth_options():
    mat = _bake()
    scene = _scene(mat, wb.Lambert(0.5))
    r = wb.render(scene, method="mc", backend="warp:cpu", samples=SAMPLES, truth_facets=256, truth_seed=3)
    assert r.info["effective_brdf"][0].startswith("ground truth (tile 'vgroove', K=4, 256 facets")
    gt = wb.ground_truth(vgroove_tile(), GLOSSY, facets=256, directions=K, backend="warp:cpu", seed=3)
    np.testing.assert_array_equal(truth_mod.truth_of(mat, 256, 3).table, gt.table)
    # A finer grid than the bake's: the truth on that grid, under its own cache key.
    fine = wb.render(scene, method="mc", backend="warp:cpu", samples=SAMPLES, truth_facets=256, truth_seed=3,
                     truth_directions=6)
    assert fine.info["effective_brdf"][0].startswith("ground truth (tile 'vgroove', K=6, 256 facets")
    gt6 = wb.ground_truth(vgroove_tile(), GLOSSY, facets=256, directions=6, backend="warp:cpu", seed=3)
    np.testing.assert_array_equal(truth_mod.truth_of(mat, 256, 3, directions=6).table, gt6.table)
    assert truth_mod.truth_key(mat, 256, 3, directions=6) != truth_mod.truth_key(mat, 256, 3)
    assert truth_mod.truth_key(mat, 256, 3, directions=K) == truth_mod.truth_key(mat, 256, 3)  # None: its own K
    for bad in (1, 65, 6.0, True, "fine"):
        with pytest.raises(ValueError, match=r"^truth_directions must be an integer grid size K in \[2, 64\]"):
            mc.render(scene, truth_directions=bad)
        with pytest.raises(ValueError, match=r"^truth directions must be an integer grid size K in \[2, 64\]"):
            truth_mod.truth_of(mat, 256, directions=bad)


def test_a_finer_truth_grid_keeps_a_highlight_the_materials_grid_blurs():
    """The reference reads f̄ from its table by interpolation, so a highlight narrower than the grid's spacing is
    blurred there (docs/design.md §3.4): between the nodes of the material's K = 4 grid, truths on finer grids
    come closer to the exact f̄ (`effective_brdf_exact` at the very pairs, the same facets). A flat Blinn–Phong
    n = 64 tile: its f̄ is the BRDF itself, a lobe about 10° wide against the K = 4 grid's ~30° spacing."""
    tile = wb.geometry.load_tile("flat")
    brdf = [wb.BlinnPhong(0.5, 64.0, kd=0.1, normalization="energy")]
    mat = wb.bake(tile, brdf, lobes=1, directions=K, facets=256, normal_res=16, backend="warp:cpu")
    rng = np.random.default_rng(7)
    theta_o, phi_o = rng.uniform(0.1, 1.1, 64), rng.uniform(0, 2 * np.pi, 64)
    wo = np.stack([np.sin(theta_o) * np.cos(phi_o), np.sin(theta_o) * np.sin(phi_o), np.cos(theta_o)], 1)
    wi = wo * [-1, -1, 1] + rng.normal(0, 0.05, (64, 3))  # near the mirror direction: on the highlight
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    exact = truth_mod.effective_brdf_exact(tile, brdf, wi, wo, facets=256, backend="warp:cpu", seed=1)
    err = {k: np.sqrt(np.mean((truth_mod.truth_of(mat, 256, directions=k).eval(wi, wo) - exact) ** 2))
           for k in (K, 16, 32)}
    scale = np.sqrt(np.mean(exact ** 2))
    # Bilinear interpolation's error falls as the spacing squared once the grid resolves the lobe: a doubled K
    # should cut it by about 4; the bounds ask for 2, and for the K = 4 grid to be far off (a third of f̄).
    assert err[K] > 0.3 * scale and err[16] < 0.5 * err[K] and err[32] < 0.5 * err[16] and err[32] < 0.08 * scale


def test_the_cache_beside_a_saved_material_is_reused_and_never_stale(tmp_path, counting):
    mat = _bake()
    path = tmp_path / "groove.wbm"
    mat.save(path)
    loaded = wb.load(path)
    assert loaded.path == str(path) and mat.path == str(path)
    # The file rebuilds the very tile: the same arrays, so the same cache key as the material baked in memory.
    for name in ("vertices", "faces", "material_ids", "colors", "origin"):
        np.testing.assert_array_equal(getattr(loaded.provenance.tile, name), getattr(mat.provenance.tile, name))
    assert loaded.provenance.tile.period == mat.provenance.tile.period
    assert truth_mod.truth_key(loaded, TRUTH_FACETS) == truth_mod.truth_key(mat, TRUTH_FACETS)

    cache = tmp_path / "groove.truth.npz"
    first = _mc(_scene(loaded, wb.Lambert(0.5)))
    assert counting.calls == 1 and cache.exists() and first.info["truth_source"] == {0: "computed"}
    assert wb.load(cache).key == truth_mod.truth_key(loaded, TRUTH_FACETS)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp")]  # written atomically, nothing left

    # Another process would find only the file: forget the memory, and computing again would fail.
    truth_mod._MEMORY.clear()
    counting.refuse = True
    again = _mc(_scene(wb.load(path), wb.Lambert(0.5)))
    assert again.info["truth_source"] == {0: str(cache)}
    np.testing.assert_array_equal(again.image, first.image)

    # A material-only edit: the recorded BRDFs follow it, so the cached table (of the old BRDFs) is not used...
    other = [wb.Ward(0.6, 0.3, kd=0.3)]
    edited = loaded.with_materials(other)
    assert edited.provenance is loaded.provenance and edited.path == loaded.path
    assert truth_mod.truth_key(edited, TRUTH_FACETS) != truth_mod.truth_key(loaded, TRUTH_FACETS)
    with pytest.raises(AssertionError, match="computed again"):
        _mc(_scene(edited, wb.Lambert(0.5)))
    # ...its own truth is computed and replaces it, and is the truth of the edited BRDFs.
    counting.refuse = False
    new = _mc(_scene(edited, wb.Lambert(0.5)))
    assert counting.calls == 2 and new.info["truth_source"] == {0: "computed"}
    assert wb.load(cache).key == truth_mod.truth_key(edited, TRUTH_FACETS)
    gt = wb.ground_truth(vgroove_tile(), other, facets=TRUTH_FACETS, directions=K, backend="warp:cpu", seed=1)
    np.testing.assert_array_equal(new.image, _mc(_scene(edited, wb.Lambert(0.5)), truths={0: gt}).image)
    # Other truth settings are another key too.
    _mc(_scene(edited, wb.Lambert(0.5)), truth_seed=7)
    assert counting.calls == 3


def test_a_corrupt_or_unwritable_cache_costs_a_recomputation_not_the_render(tmp_path, counting):
    mat = _bake()
    mat.save(tmp_path / "m.wbm")
    (tmp_path / "m.truth.npz").write_bytes(b"not a zip")
    r = _mc(_scene(wb.load(tmp_path / "m.wbm"), wb.Lambert(0.5)))
    assert r.info["truth_source"] == {0: "computed"} and counting.calls == 1
    assert wb.load(tmp_path / "m.truth.npz").key == truth_mod.truth_key(mat, TRUTH_FACETS)  # replaced
    # A cache path that is a directory cannot be written: a warning, the table kept in memory.
    truth_mod._MEMORY.clear()
    (tmp_path / "m.truth.npz").unlink()
    (tmp_path / "m.truth.npz").mkdir()
    with pytest.warns(UserWarning, match="could not write the ground-truth cache"):
        r2 = _mc(_scene(wb.load(tmp_path / "m.wbm"), wb.Lambert(0.5)))
    np.testing.assert_array_equal(r2.image, r.image)
    assert counting.calls == 2


def test_a_saved_tile_comes_back_bit_for_bit(tmp_path):
    """Vertex normals, colours and several material ids included: the loaded material has the cache key of the
    one baked, so a truth cached for one is the truth of the other."""
    base = random_heightfield(4, materials=2)
    normals = base.vertices * [0.3, -0.2, 0.0] + [0.01, 0.02, 1.0]  # tilted, not unit: SmallScale normalises them
    tile = wb.SmallScale(base.vertices, base.faces, base.material_ids, base.colors, vertex_normals=normals,
                         name="bumps")
    mat = wb.bake(tile, [wb.Lambert(0.5), wb.BlinnPhong(0.25, 16.0)], lobes=2, directions=K, facets=BAKE_FACETS,
                  normal_res=16, backend="warp:cpu")
    mat.save(tmp_path / "m.wbm")
    back = wb.load(tmp_path / "m.wbm").provenance
    assert back.tile.name == "bumps" and (back.seed, back.facets) == (0, BAKE_FACETS)
    for name in ("vertices", "faces", "material_ids", "colors", "vertex_normals", "origin"):
        a, b = getattr(back.tile, name), getattr(tile, name)
        assert a.dtype == b.dtype and not a.flags.writeable
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert back.tile.period == tile.period
    assert truth_mod.truth_key(wb.load(tmp_path / "m.wbm"), TRUTH_FACETS) == truth_mod.truth_key(mat, TRUTH_FACETS)


def test_a_saved_tile_keeps_its_own_face_tangents(tmp_path):
    """A tile's own tangents (the woven tile's run along its threads) are what an anisotropic BRDF's truth follows:
    they come back bit for bit (not the default, +x on each face), so the loaded material has the truth key, and
    so the truth, of the one baked; so do a built-in pyramid's, an ulp from the default."""
    base = random_heightfield(4)
    rng = np.random.default_rng(3)
    tile = wb.SmallScale(base.vertices, base.faces, face_tangents=rng.normal(size=(len(base.faces), 3)),
                         name="turned")
    aniso = [wb.AnisotropicWard(0.3, 0.1, 0.4, kd=0.2)]
    mat = wb.bake(tile, aniso, method="asg", lobes=2, directions=K, facets=BAKE_FACETS, normal_res=16,
                  backend="warp:cpu")
    mat.save(tmp_path / "m.wbm")
    back = wb.load(tmp_path / "m.wbm")
    tangents = back.provenance.tile.face_tangents
    assert tangents.dtype == np.float64 and not tangents.flags.writeable
    np.testing.assert_array_equal(tangents, tile.face_tangents)
    assert truth_mod.truth_key(back, TRUTH_FACETS) == truth_mod.truth_key(mat, TRUTH_FACETS)
    pyramid = wb.bake(wb.geometry.pyramid(), aniso, method="asg", lobes=2, directions=K, facets=BAKE_FACETS,
                      normal_res=16, backend="warp:cpu")
    pyramid.save(tmp_path / "p.wbm")
    np.testing.assert_array_equal(wb.load(tmp_path / "p.wbm").provenance.tile.face_tangents,
                                  pyramid.provenance.tile.face_tangents)


def test_truth_key_covers_what_the_truth_depends_on():
    tile = random_heightfield(4, materials=2)
    mats = [wb.Lambert(0.5), wb.BlinnPhong(0.25, 16.0)]
    mat = wb.bake(tile, mats, lobes=2, directions=K, facets=BAKE_FACETS, normal_res=16, backend="warp:cpu")
    key = truth_mod.truth_key(mat, TRUTH_FACETS)
    recolored = wb.SmallScale(tile.vertices, tile.faces, tile.material_ids, tile.colors * 0.5, name=tile.name)
    renamed = wb.SmallScale(tile.vertices, tile.faces, tile.material_ids, tile.colors, name="another name")

    def with_tile(t):
        return EffectiveBRDF(mat.lobes, mat.amplitudes, mats, K, provenance=type(mat.provenance)(t, 0, BAKE_FACETS))
    assert truth_mod.truth_key(with_tile(renamed), TRUTH_FACETS) == key  # a name changes no number
    assert truth_mod.truth_key(with_tile(recolored), TRUTH_FACETS) != key
    assert truth_mod.truth_key(mat.with_materials([mats[0], wb.BlinnPhong(0.25, 17.0)]), TRUTH_FACETS) != key
    assert truth_mod.truth_key(mat, TRUTH_FACETS + 1) != key
    assert truth_mod.truth_key(mat, TRUTH_FACETS, seed=2) != key
    assert truth_mod.truth_key(mat, TRUTH_FACETS, seed=1) == key  # None is the bake's seed + 1


# ---------------------------------------------------------------------------------------------------
# a material that cannot say how it was made; the old fallback, only when asked
# ---------------------------------------------------------------------------------------------------


def _by_hand(mat):
    """The same tables with no provenance: what a material built by hand (or a format-1 file) is."""
    return EffectiveBRDF(mat.lobes, mat.amplitudes, mat.materials, mat.directions, mat.method)


def test_a_material_without_provenance_is_a_one_line_error_before_any_work(monkeypatch):
    mat = _by_hand(_bake())
    scene = _scene(wb.Lambert(0.5), mat)  # the plane's material, index 1

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the inputs were checked")

    monkeypatch.setattr(mc, "get_backend", no_work)
    with pytest.raises(ValueError) as exc:
        mc.render(scene)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith("effective material 1 does not record how it was baked")
    assert "truths={1: wb.ground_truth(tile, materials, directions=4)}" in msg and "fallback='sg'" in msg
    # A material on no face of the mesh needs no truth.
    monkeypatch.undo()
    unused = Scene(Mesh.sphere(1.0, subdivisions=1), [wb.Lambert(0.5), mat], Camera(width=4, height=4))
    assert mc.render(unused, backend="warp:cpu", samples=4).info["truth_source"] == {}
    for bad in ("SG", "exact", 1):
        with pytest.raises(ValueError, match="fallback must be None or 'sg'"):
            mc.render(scene, fallback=bad)
    for bad in (0, 2.5, "many"):
        with pytest.raises(ValueError, match="truth_facets"):
            mc.render(scene, truth_facets=bad)
    with pytest.raises(ValueError, match="truth_seed"):
        mc.render(scene, truth_seed=-1)
    with pytest.raises(ValueError, match="does not record how it was baked"):
        truth_mod.truth_of(mat)


def test_fallback_sg_is_the_old_behaviour(monkeypatch, counting):
    """fallback="sg": no truth is computed, f̄ is EffectiveBRDF.eval(method="sg-exact") with a warning and a note
    in info, whether or not the material records its bake; a truth given by hand is still used."""
    baked = _bake()
    counting.refuse = True
    methods = []
    real_eval = EffectiveBRDF.eval

    def spy(self, wi, wo, method=None):
        methods.append(method)
        return real_eval(self, wi, wo, method)

    monkeypatch.setattr(EffectiveBRDF, "eval", spy)
    with pytest.warns(UserWarning, match="no ground truth for effective material 0 .fallback='sg'.; using "
                                         r"EffectiveBRDF.eval\(method='sg-exact'\)"):
        a = _mc(_scene(baked, wb.Lambert(0.5)), fallback="sg")
    assert methods and set(methods) == {"sg-exact"}
    assert "sg-exact" in a.info["effective_brdf"][0] and a.info["truth_source"] == {}
    with pytest.warns(UserWarning, match="fallback='sg'"):
        b = _mc(_scene(_by_hand(baked), wb.Lambert(0.5)), fallback="sg")
    np.testing.assert_array_equal(a.image, b.image)
    counting.refuse = False
    gt = truth_mod.truth_of(baked, TRUTH_FACETS)
    counting.refuse = True
    methods.clear()
    c = _mc(_scene(_by_hand(baked), wb.Lambert(0.5)), fallback="sg", truths={0: gt})
    assert c.info["truth_source"] == {0: "given"} and not methods


def test_fallback_sg_evaluates_an_asg_material_by_its_own_lobes(monkeypatch, counting):
    """An ASG bake has no SG fit: fallback="sg" judges it by its own ASG lobes (ASGBRDF.eval's default), said in
    the warning and in info, instead of failing on eval(method='sg-exact')."""
    asg_mat = wb.bake(vgroove_tile(), GLOSSY, method="asg", lobes=2, directions=K, facets=BAKE_FACETS, normal_res=16,
                      backend="warp:cpu")
    counting.refuse = True
    methods = []
    real_eval = wb.ASGBRDF.eval

    def spy(self, wi, wo, method=None, **kw):
        methods.append(method)
        return real_eval(self, wi, wo, method, **kw)

    monkeypatch.setattr(wb.ASGBRDF, "eval", spy)
    with pytest.warns(UserWarning, match=r"using ASGBRDF.eval\(method='asg'\) \(its fit\)"):
        out = _mc(_scene(asg_mat, wb.Lambert(0.5)), fallback="sg")
    assert methods and set(methods) == {"asg"}
    assert "ASGBRDF.eval(method='asg')" in out.info["effective_brdf"][0]
    assert np.isfinite(out.image).all() and out.image.min() >= 0 and out.image.max() > 0


def test_an_old_format_material_file_still_loads(tmp_path):
    mat = _bake()
    path = tmp_path / "old.wbm"
    _v1_file(mat, path)
    old = wb.load(path)
    assert isinstance(old, EffectiveBRDF) and old.provenance is None and old.path == str(path)
    np.testing.assert_array_equal(old.table(), mat.table())
    assert old.materials == mat.materials
    with pytest.raises(ValueError, match="effective material 0 does not record how it was baked"):
        _mc(_scene(old, wb.Lambert(0.5)))
    with pytest.warns(UserWarning, match="fallback='sg'"):
        _mc(_scene(old, wb.Lambert(0.5)), fallback="sg")
    # Saving it again writes format 2, still without a provenance.
    old.save(tmp_path / "again.wbm")
    assert wb.load(tmp_path / "again.wbm").provenance is None


# ---------------------------------------------------------------------------------------------------
# the command line
# ---------------------------------------------------------------------------------------------------


def _file_scene(tmp_path, material_file):
    text = TINY_SCENE.replace('[material.shiny]\ntype = "blinnphong"\nkd = [0.5, 0.2, 0.1]\nks = 0.5\n'
                              'exponent = 100.0',
                              f'[material.shiny]\ntype = "file"\npath = "{material_file}"')
    assert 'type = "file"' in text
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return p


def test_cli_render_mc_uses_and_caches_the_ground_truth(tmp_path, capsys):
    _bake().save(tmp_path / "groove.wbm")
    scene = _file_scene(tmp_path, "groove.wbm")
    args = ["render", str(scene), "--method", "mc", "--samples", "8", "--size", "8", "6", "--truth-facets", "256"]
    r = run_cli_in_process(capsys, *args, "-o", str(tmp_path / "a.exr"))
    assert r.returncode == 0, r.stderr
    cache = tmp_path / "groove.truth.npz"
    assert cache.exists()
    assert "ground truth of material 'shiny': computed (ground truth (tile 'vgroove', K=4, 256 facets" in r.stdout
    r = run_cli_in_process(capsys, *args, "-o", str(tmp_path / "b.exr"))
    assert r.returncode == 0, r.stderr
    assert f"ground truth of material 'shiny': read from {cache}" in r.stdout
    from warp_biscale.images import read_exr

    np.testing.assert_array_equal(read_exr(tmp_path / "a.exr"), read_exr(tmp_path / "b.exr"))
    # --truth-directions: a truth on a finer grid than the bake's, cached in place of the K = 4 one.
    from warp_biscale import cli

    assert cli.main([*args, "--truth-directions", "6", "-o", str(tmp_path / "c.exr")]) == 0
    assert "ground truth of material 'shiny': computed (ground truth (tile 'vgroove', K=6, 256 facets" in \
        capsys.readouterr().out
    assert wb.load(cache).directions == 6
    for bad in ("1", "65"):
        assert cli.main([*args, "--truth-directions", bad, "-o", str(tmp_path / "d.exr")]) == 2
        errors = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning:")]
        assert errors == [f"error: --truth-directions must be a grid size K in [2, 64], got {bad}"]
    for bad in ("0", str(truth_mod.MAX_FACETS + 1)):  # (named as the flag, before the scene loads)
        assert cli.main([*args[:-2], "--truth-facets", bad, "-o", str(tmp_path / "d.exr")]) == 2
        errors = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning:")]
        assert errors == [f"error: --truth-facets must be an integer in [1, {truth_mod.MAX_FACETS}], got {bad}"]
    assert not (tmp_path / "d.exr").exists()


def test_cli_render_mc_of_an_old_material_file(tmp_path, capsys):
    _v1_file(_bake(), tmp_path / "old.wbm")
    scene = _file_scene(tmp_path, "old.wbm")
    out = tmp_path / "x.png"
    args = ["render", str(scene), "--method", "mc", "--samples", "8", "--size", "8", "6", "-o", str(out)]
    r = run_cli_in_process(capsys, *args)
    assert r.returncode == 2
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and r.stderr.rstrip().endswith(errors[0]) and "Traceback" not in r.stderr
    assert errors[0].startswith(f"error: material 'shiny' ({tmp_path / 'old.wbm'}) does not record how it was baked")
    assert "--mc-fallback sg" in errors[0]
    assert not out.exists()
    r = run_cli_in_process(capsys, *args, "--mc-fallback", "sg", "-q")
    assert r.returncode == 0, r.stderr
    assert "fallback='sg'" in r.stderr and out.exists()
    r = run_cli_in_process(capsys, "render", scene, "--mc-fallback", "sg", "-o", out)  # the file's method: sg
    assert r.returncode == 2 and "--mc-fallback is for --method mc" in r.stderr


# ---------------------------------------------------------------------------------------------------
# interreflection inside the tile (bounces > 1) in a baked material's truth
# ---------------------------------------------------------------------------------------------------

PATHS = 16  # paths per direction pair: what is checked is which table is used, not its convergence


def test_truth_of_with_bounces_is_the_ground_truth_with_bounces_and_cached_under_its_own_key(tmp_path, counting):
    """truth_of(bounces=B, paths=P) is wb.ground_truth(..., bounces=B, paths=P) on the recorded tile, bit for bit
    (deterministic kernels, hashed random numbers); B and P are in its cache key, B = 1's key is the one it
    always was (paths ignored there), and the table read back from beside the file says B and P."""
    tile = vgroove_tile()
    mat = _bake(tile=tile)
    mat.save(tmp_path / "g.wbm")
    loaded = wb.load(tmp_path / "g.wbm")
    key1 = truth_mod.truth_key(loaded, TRUTH_FACETS)
    assert truth_mod.truth_key(loaded, TRUTH_FACETS, bounces=1, paths=7) == key1
    key2 = truth_mod.truth_key(loaded, TRUTH_FACETS, bounces=2, paths=PATHS)
    assert len({key1, key2, truth_mod.truth_key(loaded, TRUTH_FACETS, bounces=3, paths=PATHS),
                truth_mod.truth_key(loaded, TRUTH_FACETS, bounces=2, paths=PATHS + 1)}) == 4
    gt2 = truth_mod.truth_of(loaded, TRUTH_FACETS, bounces=2, paths=PATHS)
    assert (gt2.bounces, gt2.paths, gt2.key) == (2, PATHS, key2) and counting.calls == 1
    by_hand = wb.ground_truth(tile, GLOSSY, facets=TRUTH_FACETS, directions=K, backend="warp:cpu", seed=1,
                              bounces=2, paths=PATHS)
    np.testing.assert_array_equal(gt2.table, by_hand.table)
    # Interreflection only adds light: the B = 2 table is the single-bounce one plus a non-negative term.
    gt1 = truth_mod.truth_of(loaded, TRUTH_FACETS)
    assert counting.calls == 2 and gt1.bounces == 1 and gt1.key == key1
    assert (gt2.table >= gt1.table).all() and gt2.table.sum() > gt1.table.sum()
    # One table a file: the last one computed (B = 1) is on disk; B = 2 comes back from memory, then from
    # the file once it is written again and the memory forgotten.
    assert wb.load(tmp_path / "g.truth.npz").key == key1
    truth_mod._MEMORY.pop(key1)
    counting.refuse = True
    with pytest.raises(AssertionError, match="computed again"):
        truth_mod.truth_of(loaded, TRUTH_FACETS, bounces=2, paths=PATHS + 1)
    assert truth_mod.cached_truth(loaded, TRUTH_FACETS, bounces=2, paths=PATHS)[1] == "memory"
    truth_mod._MEMORY.clear()
    again, source = truth_mod.cached_truth(loaded, TRUTH_FACETS, bounces=2, paths=PATHS)
    assert source == str(tmp_path / "g.truth.npz") and (again.bounces, again.paths) == (2, PATHS)
    np.testing.assert_array_equal(again.table, gt2.table)
    for bad in ({"bounces": 0}, {"bounces": 17}, {"bounces": 2.0}, {"bounces": 2, "paths": 0}):
        with pytest.raises(ValueError, match="bounces|paths"):
            truth_mod.truth_of(loaded, TRUTH_FACETS, **bad)


def test_mc_uses_the_truth_with_bounces():
    """montecarlo.render(truth_bounces=, truth_paths=) renders with the B-bounce truth: the very image of that
    truth passed by hand, said so in info; bad values are named before any work."""
    mat = _bake()
    scene = _scene(mat, wb.Lambert(0.5))
    auto = _mc(scene, truth_bounces=2, truth_paths=PATHS)
    gt = wb.ground_truth(vgroove_tile(), GLOSSY, facets=TRUTH_FACETS, directions=K, backend="warp:cpu", seed=1,
                         bounces=2, paths=PATHS)
    np.testing.assert_array_equal(auto.image, _mc(scene, truths={0: gt}).image)
    assert f"2 bounces ({PATHS} paths)" in auto.info["effective_brdf"][0]
    assert not np.array_equal(auto.image, _mc(scene).image)  # the single-bounce truth is another f̄
    for bad, name in (({"truth_bounces": 0}, "truth_bounces"),
                      ({"truth_bounces": 2, "truth_paths": -1}, "truth_paths")):
        with pytest.raises(ValueError, match=f"^{name} must be an integer"):
            _mc(scene, **bad)


def test_cli_truth_and_render_take_bounces_and_paths(tmp_path, capsys):
    """`truth --bounces B --paths P` saves the B-bounce table (equal to the library's); `render --method mc
    --truth-bounces B --truth-paths P` judges a baked material with it; bad values are one-line errors naming
    the flag, before any work."""
    npz = tmp_path / "gt.npz"
    r = run_cli_in_process(capsys, "truth", "vgroove", "--facets", "1024", "--directions", "4", "--backend",
                           "warp:cpu", "--bounces", "2", "--paths", str(PATHS), "--save", str(npz), "-o",
                           str(tmp_path / "p.png"))
    assert r.returncode == 0, r.stderr
    assert f"2 bounces ({PATHS} paths)" in r.stdout
    gt = wb.load(npz)
    assert (gt.bounces, gt.paths) == (2, PATHS)
    ref = wb.ground_truth(wb.geometry.load_tile("vgroove"), [wb.Lambert(0.5)], facets=1024, directions=4,
                          backend="warp:cpu", bounces=2, paths=PATHS)
    np.testing.assert_array_equal(gt.table, ref.table)

    _bake().save(tmp_path / "groove.wbm")
    scene = _file_scene(tmp_path, "groove.wbm")
    r = run_cli_in_process(capsys, "render", str(scene), "--method", "mc", "--samples", "8", "--size", "8", "6",
                           "--truth-facets", "256", "--truth-bounces", "2", "--truth-paths", str(PATHS), "-o",
                           str(tmp_path / "a.exr"))
    assert r.returncode == 0, r.stderr
    assert f"256 facets, 2 bounces ({PATHS} paths)" in r.stdout
    assert wb.load(tmp_path / "groove.truth.npz").bounces == 2

    for args, message in ((["truth", "flat", "--bounces", "0"], "--bounces must be an integer in [1, 16], got 0"),
                          (["truth", "flat", "--bounces", "2", "--paths", "0"], "--paths must be an integer in [1, "),
                          (["truth", "flat", "--paths", "64"], "--paths is for --bounces above 1"),
                          (["bake", "flat", "--truth-bounces", "2"], "--truth-bounces is for the ground truth of "
                                                                     "--truth FACETS"),
                          (["render", str(scene), "--method", "mc", "--truth-bounces", "17"],
                           "--truth-bounces must be an integer in [1, 16], got 17")):
        out = tmp_path / ("x.wbm" if args[0] == "bake" else "x.png")
        r = run_cli_in_process(capsys, *args, "-o", str(out))
        errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
        assert r.returncode == 2 and len(errors) == 1 and message in errors[0], r.stderr
        assert not out.exists()
