"""What a small-scale BRDF does to energy: its directional albedo A(θo) = ∫ f_r cos θi dωi, measured here
by float64 quadrature of the library's own `Brdf.eval`; the numbers the docstrings state; Blinn–Phong's
normalization="energy"; the EnergyWarning of a material whose albedo exceeds 1; and the option's way
through parse_brdf, scene files and material files.

Tolerances (each with its reason where it is used): the quadrature below agrees with the closed form of
Blinn–Phong's albedo at normal incidence to ~1e-15 and with an independent brute-force grid over ωi to
~1e-9, so 1e-6 covers it everywhere; docstring numbers are printed to 3 decimals (±5e-4); the
Cook–Torrance table is stated to be within 0.015 of the quadrature (log-log interpolation in roughness).
"""

import math
import textwrap
import warnings

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import brdf as B
from warp_biscale import sg, shading
from warp_biscale.brdf import EnergyWarning, parse_brdf
from warp_biscale.lobes import LobeSet
from warp_biscale.scenefile import SceneError, load_scene

QUAD = 1e-6  # quadrature error bound (module docstring)
PRINTED = 5e-4 + QUAD  # a number printed to 3 decimals
X, W = np.polynomial.legendre.leggauss(32)


def _gl(lo, hi):
    """Gauss–Legendre nodes and weights on [lo, hi]."""
    return lo + (hi - lo) * (X + 1) / 2, (hi - lo) / 2 * W


def _pieces(lo, hi, width):
    """[lo, hi] cut at lo + width·2^k, so that a lobe of that angular width gets nodes of its own scale."""
    cuts = [lo] + [lo + width * 2.0**k for k in range(-3, 12) if lo + width * 2.0**k < hi] + [hi]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def albedo(brdf, cos_o, width=None, cut=None, phi_pieces=1):
    """(3,) RGB directional albedo ∫ brdf.eval(n, ωi, ωo)·cos θi dωi for ωo at cos θo (float64).

    Over the half vector h = (θh, φ) about the normal: ωi = 2(h·ωo)h − ωo, dωi = 4(h·ωo) sin θh dθh dφ.
    ωi is above the horizon for every φ while θh < π/4 − θo/2, and for |φ| < acos(−cot 2θh · cot θo) up to
    θh = π/4 + θo/2 (beyond, for no φ), so each range is integrated with its exact φ limits and the integrand
    is smooth inside except where a min() in the BRDF switches (Cook–Torrance's G): `phi_pieces` then splits
    φ into equal pieces. `width`: the lobe's angular width, for the θh subdivision; `cut`: θh past which the
    lobe is negligible."""
    if width is None:
        width = _lobe_width(brdf)
    co = float(cos_o)
    so = math.sqrt(max(1.0 - co * co, 0.0))
    half = math.acos(co) / 2
    a1, a2 = math.pi / 4 - half, math.pi / 4 + half
    if cut is not None:
        a1, a2 = min(a1, cut), min(a2, cut)
    wo = np.array([so, 0.0, co])
    total = np.zeros(3)
    for lo, hi, whole in ((0.0, a1, True), (a1, a2, False)):
        for p, q in _pieces(lo, hi, width):
            th, wth = _gl(p, q)
            c, s = np.cos(th), np.sin(th)
            if whole or so == 0:
                pm = np.full_like(th, np.pi)
            else:
                pm = np.arccos(np.clip(-co * (2 * c * c - 1) / (2 * s * c * so), -1.0, 1.0))
            k = np.arange(phi_pieces)[:, None]
            xs, ws = ((k + (X + 1) / 2) / phi_pieces).ravel(), np.tile(W / 2 / phi_pieces, phi_pieces)
            phi, wphi = pm[:, None] * xs, pm[:, None] * ws
            h = np.stack([s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), np.broadcast_to(c[:, None], phi.shape)],
                         -1).reshape(-1, 3)
            ho = h @ wo
            wi = 2 * ho[:, None] * h - wo
            wi[:, 2] = np.maximum(wi[:, 2], 0.0)  # rounding at the φ limit: ωi on the horizon adds nothing
            n = np.tile([0.0, 0.0, 1.0], (len(h), 1))
            f = brdf.eval(n, wi, np.tile(wo, (len(h), 1)))
            weight = (2 * wphi * wth[:, None]).reshape(-1) * 4 * ho * np.repeat(s, phi.shape[1]) * wi[:, 2]
            total += weight @ f
    return total


def _lobe_width(brdf):
    if isinstance(brdf, wb.BlinnPhong):  # (n·h)^n ≈ exp(−n θh²/2)
        return min(1.0, math.sqrt(2.0 / brdf.exponent))
    if isinstance(brdf, wb.CookTorrance):
        return min(1.0, brdf.roughness)
    return 1.0


def _bp_cut(n):
    """θh past which (n·h)^n < e^−80 of its peak: the Blinn–Phong lobe is zero there in float64 terms."""
    return math.acos(math.exp(-80.0 / n)) if n > 80.0 / 745 else None


def bp(n, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EnergyWarning)  # (ks = 1 under "iwasaki" warns, on purpose)
        return wb.BlinnPhong(1.0, n, **kw)


def bp_albedo(n, cos_o, **kw):
    return albedo(bp(n, **kw), cos_o, cut=_bp_cut(n))[0]


# ------------------------------------------------------------------------------------------------ the quadrature


def test_quadrature_matches_a_brute_force_grid_over_wi():
    """The half-vector change of variables checked against a plain Gauss–Legendre grid over (θi, φi) for
    broad lobes, where that grid converges (1e-9: its own error at 200×200 nodes)."""
    xg, wg = np.polynomial.legendre.leggauss(200)
    ti, wti = (xg + 1) * np.pi / 4, wg * np.pi / 4
    ph, wph = (xg + 1) * np.pi / 2, wg * np.pi / 2  # φ over [0, π], doubled by symmetry
    tt, pp = np.meshgrid(ti, ph, indexing="ij")
    wi = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1).reshape(-1, 3)
    wts = (wti[:, None] * wph[None, :]).reshape(-1) * 2 * np.sin(tt).reshape(-1) * wi[:, 2]
    for n, co in ((1.0, 0.5), (10.0, 0.9), (10.0, 0.2)):
        wo = np.array([math.sqrt(1 - co * co), 0.0, co])
        m = bp(n)
        brute = wts @ m.eval(np.tile([0.0, 0.0, 1.0], (len(wi), 1)), wi, np.tile(wo, (len(wi), 1)))[:, 0]
        assert bp_albedo(n, co) == pytest.approx(brute, abs=1e-9), (n, co)


@pytest.mark.parametrize("n", [0.1, 1.0, 2.0, 10.0, 64.0, 100.0, 1000.0, 1e4])
def test_normal_incidence_albedo_has_the_closed_form(n):
    assert bp_albedo(n, 1.0) == pytest.approx(B.blinn_phong_normal_albedo(n), abs=QUAD)


# ------------------------------------------------------------------------------------------------ stated numbers

# BlinnPhong's docstring table (ks = 1): exponent → albedo at cos θo = 1, 0.9, 0.5, 0.1
BLINN_PHONG_TABLE = {1: (1.366, 1.320, 1.118, 0.873), 10: (2.866, 2.441, 1.147, 0.403),
                     100: (3.846, 3.130, 1.019, 0.106), 1000: (3.984, 3.229, 1.002, 0.048),
                     10000: (3.998, 3.239, 1.000, 0.041)}


def test_the_blinn_phong_docstring_states_the_table_measured_here():
    doc = " ".join(wb.BlinnPhong.__doc__.split())
    for n, row in BLINN_PHONG_TABLE.items():
        assert f"{n} {' '.join(f'{a:.3f}' for a in row)}" in doc, n
        for co, a in zip((1.0, 0.9, 0.5, 0.1), row):
            assert bp_albedo(float(n), co) == pytest.approx(a, abs=PRINTED), (n, co)


def test_the_issues_claims():
    """~3·ks at cos θo = 0.9 (3.13 at n = 100, 3.24 as n → ∞, i.e. 4·cos²θo), → 4·ks at normal incidence;
    ks = 0.6 reflects 1.94× at cos θo = 0.9 for a sharp lobe — a point's directional albedo, not what a whole
    sphere reflects under uniform light: that is 0.6·2(n + 2)/(n + 4) ≤ 1.2 (below)."""
    assert 2.9 < bp_albedo(100.0, 0.9) < 3.25
    assert bp_albedo(1e4, 0.9) == pytest.approx(4 * 0.81, rel=1e-3)
    assert B.blinn_phong_normal_albedo(1e6) == pytest.approx(4.0, rel=1e-5)
    assert 0.6 * bp_albedo(1e4, 0.9) == pytest.approx(1.94, abs=0.005)


@pytest.mark.parametrize("n", [1.0, 10.0, 100.0])
def test_uniform_light_reflects_two_n_plus_two_over_n_plus_four(n):
    """The docstring's 2(n + 2)/(n + 4): the cosine-weighted mean over θo of A, 2∫A(μ)μ dμ."""
    xg, wg = np.polynomial.legendre.leggauss(48)
    mu, wmu = (xg + 1) / 2, wg / 2
    mean = 2 * sum(w * m * bp_albedo(n, m) for m, w in zip(mu, wmu))
    assert mean == pytest.approx(2 * (n + 2) / (n + 4), abs=1e-6)  # 48 nodes in μ: error ~1e-9 measured


# Cook–Torrance's docstring table (ks = 1): (roughness, f0) → albedo at cos θo = 1, 0.5, 0.05
COOK_TORRANCE_TABLE = {(0.2, 1): (0.156, 0.150, 0.152), (0.5, 1): (0.732, 0.749, 0.837),
                       (1, 1): (1.221, 1.696, 2.145), (2, 1): (1.422, 2.320, 3.260),
                       (0.5, 0.04): (0.029, 0.046, 0.252), (1, 0.04): (0.049, 0.091, 0.475)}


def ct(m, f0, ks=1.0, kd=0.0):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EnergyWarning)
        return wb.CookTorrance(ks, m, f0, kd)


def ct_albedo(m, f0, cos_o):
    return albedo(ct(m, f0), cos_o, cut=7 * m, phi_pieces=16)[0]


def test_the_cook_torrance_docstring_states_the_table_measured_here():
    doc = " ".join(wb.CookTorrance.__doc__.split())
    for (m, f0), row in COOK_TORRANCE_TABLE.items():
        assert f"{m:g} {f0:g} {' '.join(f'{a:.3f}' for a in row)}" in doc, (m, f0)
        for co, a in zip((1.0, 0.5, 0.05), row):
            # G's min() puts kinks inside the domain: with φ in 16 pieces the quadrature moves by < 1e-5
            # when the pieces are doubled, and agrees with brdf._cook_torrance_albedos at 800 nodes to 1e-5
            assert ct_albedo(m, f0, co) == pytest.approx(a, abs=5e-4 + 3e-5), (m, f0, co)


def test_a_metal_exceeds_ks_from_roughness_0_55_at_grazing():
    """The docstrings' m ≈ 0.55 (f0 = 1): grazing is where the albedo peaks for such a lobe."""
    assert ct_albedo(0.53, 1.0, 1e-3) < 1.0 < ct_albedo(0.57, 1.0, 1e-3)
    assert ct_albedo(0.57, 1.0, 1.0) < 1.0


@pytest.mark.parametrize("m, f0", [(0.03, 1.0), (0.3, 0.04), (0.55, 1.0), (0.8, 0.5), (3.0, 1.0), (30.0, 0.04)])
def test_cook_torrance_albedo_table_is_within_its_stated_error(m, f0):
    cos_o, a = B.cook_torrance_albedo(m, f0)
    for co, value in zip(cos_o[[1, 4, 9, 15]], a[[1, 4, 9, 15]]):  # grazing to normal, off the table's m nodes
        assert value == pytest.approx(ct_albedo(m, f0, co), abs=0.015), (m, f0, co)


# ------------------------------------------------------------------------------------------------ "energy"

EXPONENTS = [1.0, 1.7, 3.0, 6.0, 10.0, 30.0, 100.0, 300.0, 1000.0, 3000.0, 1e4]
COSINES = [1.0, 0.99, 0.95, 0.9, 0.8, 0.6, 0.4, 0.2, 0.1, 0.03, 0.01, 0.001]


@pytest.mark.parametrize("n", EXPONENTS)
def test_energy_albedo_is_ks_at_normal_incidence_and_never_more(n):
    a = [bp_albedo(n, co, normalization="energy") for co in COSINES]
    assert a[0] == pytest.approx(1.0, abs=QUAD)
    assert max(a) <= 1.0 + QUAD
    # the constant factor's price: light lost at oblique angles (≈ cos²θo for a sharp lobe)
    assert a[-1] < 0.7


def test_energy_albedo_scales_with_ks_per_channel():
    m = wb.BlinnPhong((0.9, 0.5, 0.1), 200.0, normalization="energy")
    np.testing.assert_allclose(albedo(m, 1.0, cut=_bp_cut(200.0)), [0.9, 0.5, 0.1], atol=QUAD)


@pytest.mark.parametrize("n", [1.0, 64.0, 512.0])
def test_energy_is_the_iwasaki_lobe_times_a_constant_of_the_exponent(n):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(2, 64, 3))
    d[..., 2] = np.abs(d[..., 2])
    wi, wo = d / np.linalg.norm(d, axis=-1, keepdims=True)
    normal = np.tile([0.0, 0.0, 1.0], (64, 1))
    scale = (n + 4) / (4 * (n + 2 ** (-n / 2)))
    e, i = bp(n, normalization="energy"), bp(n)
    assert e.ks_scale == pytest.approx(scale, rel=1e-15) and i.ks_scale == 1.0
    # (atol: random directions far off a sharp lobe give subnormal values, which have fewer significant bits)
    np.testing.assert_allclose(e.eval(normal, wi, wo), scale * i.eval(normal, wi, wo), rtol=1e-14, atol=1e-300)
    np.testing.assert_allclose(e.packed()[3:6], scale, rtol=1e-15)
    # the SG fit (bake, effective BRDF, Monte Carlo strategy) sees the same ks; the renderer packs it
    _, me, _ = sg.specular_lobe(e, [[0, 0, 1.0]], [[0, 0, 1.0]])
    _, mi, _ = sg.specular_lobe(i, [[0, 0, 1.0]], [[0, 0, 1.0]])
    np.testing.assert_allclose(me, scale * mi, rtol=1e-14)
    row = shading.pack_materials([e])["analytic"][0]
    np.testing.assert_array_equal(row[4:7], np.float32(scale))


def test_iwasaki_packs_bit_for_bit_as_before():
    rng = np.random.default_rng(7)
    for _ in range(50):
        ks, kd = rng.uniform(0, 1, 3), rng.uniform(0, 0.3, 3)
        n = float(np.exp(rng.uniform(0, 10)))
        before = np.array([*kd, *ks, n, 0], np.float64)  # what packed() returned before the option
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", EnergyWarning)
            default, named = wb.BlinnPhong(ks, n, kd), wb.BlinnPhong(ks, n, kd, normalization="iwasaki")
        assert default.packed().tobytes() == before.tobytes() == named.packed().tobytes()
        assert default == named and repr(default) == repr(named) and "normalization" not in repr(default)


def test_unknown_normalization_is_a_one_line_error_naming_it():
    for bad in ("Energy", "physical", "", 1.0, None):
        with pytest.raises(ValueError) as info:
            wb.BlinnPhong(0.5, 10.0, normalization=bad)
        msg = str(info.value)
        assert "\n" not in msg and "normalization" in msg and repr(bad) in msg and "'energy'" in msg, msg


def test_a_textured_exponent_is_refused_with_energy():
    e = wb.BlinnPhong(0.5, 100.0, normalization="energy")
    with pytest.raises(ValueError, match="parameter_map cannot vary the exponent of a BlinnPhong with "
                                         "normalization='energy'"):
        wb.Textured(e, parameter_map=np.full((2, 2), 0.5))
    wb.Textured(e, kd_map=np.full((2, 2, 3), 0.5), ks_map=np.full((2, 2, 3), 0.5))  # (the maps that scale ks: fine)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EnergyWarning)
        wb.Textured(wb.BlinnPhong(0.5, 100.0), parameter_map=np.full((2, 2), 0.5))


# ------------------------------------------------------------------------------------------------ the warning


@pytest.mark.parametrize("make, match", [
    (lambda: wb.BlinnPhong(1.0, 64.0),
     r"^BlinnPhong directional albedo 3\.76 > 1 at θo = 0° \(cos θo = 1\): ks × 3\.76 \+ kd .*"
     r'normalization="energy" makes that specular albedo ks$'),
    (lambda: wb.BlinnPhong((0.6, 0.3, 0.1), 100.0, kd=0.1),
     r"^BlinnPhong directional albedo \(2\.41, 1\.25, 0\.485\): r = 2\.41 > 1 at θo = 0°"),
    (lambda: wb.BlinnPhong(0.6, 100.0, kd=0.6, normalization="energy"),
     r"^BlinnPhong directional albedo 1\.2 > 1 at θo = 0° .*keep ks \+ kd <= 1$"),
    (lambda: wb.CookTorrance(1.0, 1.0, f0=1.0),
     r"^CookTorrance directional albedo 2\.1\d > 1 at θo = 89\.9° \(cos θo = 0\.001\): .*roughness 1 and f0 1"),
    (lambda: wb.CookTorrance(1.0, 1.0, f0=0.04, kd=0.8), r"^CookTorrance directional albedo 1\.4\d > 1 at θo = 89\.9°"),
])
def test_an_albedo_above_one_warns_once_naming_class_albedo_and_angle(make, match):
    with pytest.warns(EnergyWarning, match=match) as record:
        make()
    assert len(record) == 1 and "\n" not in str(record[0].message)
    assert record[0].filename == __file__  # it points at the line that built the material


def test_a_kd_above_one_is_said_once_as_before():
    with pytest.warns(EnergyWarning) as record:
        wb.BlinnPhong(1.0, 64.0, kd=1.5)
    assert len(record) == 1 and str(record[0].message).startswith("BlinnPhong kd 1.5 > 1")


def test_materials_that_keep_their_albedo_at_most_one_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", EnergyWarning)
        wb.BlinnPhong(0.5, 100.0, kd=0.5, normalization="energy")  # exactly 1 at normal incidence
        wb.BlinnPhong((0.3, 0.6, 0.9), 1e4, kd=(0.7, 0.4, 0.1), normalization="energy")
        wb.BlinnPhong(0.2, 100.0, kd=0.2)  # 0.2 + 0.2·3.85 = 0.97
        wb.BlinnPhong(1 / 1.366, 1.0)  # n = 1: A = 1.3657 at most
        wb.BlinnPhong(0.0, 64.0, kd=1.0)
        wb.CookTorrance(0.9, 0.2, kd=0.1)  # the CLI's example: 0.1 + 0.9·0.07 at grazing
        wb.CookTorrance(1.0, 0.5, f0=1.0)  # a metal below m ≈ 0.55: 0.85 at most
        parse_brdf("blinnphong:exponent=128,normalization=energy,kd=0.3,ks=0.7")


def test_warning_follows_the_measured_albedo_across_the_threshold():
    """The warning's albedo is the measured one: a ks just under 1/A(n) is quiet, just over warns."""
    for n in (1.0, 30.0, 5000.0):
        a = bp_albedo(n, 1.0)
        with warnings.catch_warnings():
            warnings.simplefilter("error", EnergyWarning)
            wb.BlinnPhong(0.999 / a, n)
        with pytest.warns(EnergyWarning):
            wb.BlinnPhong(1.001 / a, n)


# ------------------------------------------------------------------------------------------------ parse, save, load


def test_parse_brdf_round_trip():
    e = parse_brdf("blinnphong:exponent=128,normalization=energy")
    assert e == wb.BlinnPhong(1.0, 128.0, normalization="energy")
    assert parse_brdf("phong:normalization = iwasaki , ks=0.2") == wb.BlinnPhong(0.2)
    assert parse_brdf(f"blinnphong:exponent={e.exponent:g},ks={'/'.join(f'{x:g}' for x in e.ks)},"
                      f"normalization={e.normalization}") == e


@pytest.mark.parametrize("text, words", [
    ("blinnphong:normalization=physical", ["BlinnPhong.normalization", "'physical'"]),
    ("blinnphong:normalisation=energy", ["BlinnPhong has no parameter 'normalisation'", "normalization"]),
    ("lambert:normalization=energy", ["Lambert has no parameter 'normalization'"]),
    ("blinnphong:exponent=energy", ["exponent='energy' is not a number"]),
])
def test_parse_brdf_errors_name_the_input(text, words):
    with pytest.raises(ValueError) as info:
        parse_brdf(text)
    assert "\n" not in str(info.value)
    for w in words:
        assert w in str(info.value), str(info.value)


def _material(mats, k=2):
    lobes = LobeSet(np.array([[0.0, 0.0, 1.0]]), np.array([50.0]), np.array([1.0]))
    return wb.EffectiveBRDF(lobes, np.full((len(mats), k * k, k * k, 1, 3), 0.1, np.float32), mats, k)


def test_material_file_keeps_the_normalization(tmp_path):
    mats = [wb.BlinnPhong(0.4, 300.0, kd=0.2, normalization="energy"), wb.BlinnPhong(0.1, 20.0)]
    _material(mats).save(tmp_path / "m.wbm")
    back = wb.load(tmp_path / "m.wbm")
    assert back.materials == mats
    assert [m.normalization for m in back.materials] == ["energy", "iwasaki"]
    np.testing.assert_array_equal(back.materials[0].packed(), mats[0].packed())


def test_a_material_written_before_the_option_reads_as_iwasaki():
    from warp_biscale.effective import _brdf_from_dict

    old = {"type": "BlinnPhong", "ks": [0.2, 0.2, 0.2], "exponent": 64.0, "kd": [0.1, 0.1, 0.1]}
    assert _brdf_from_dict(old) == wb.BlinnPhong(0.2, 64.0, 0.1)


SCENE = """\
[[object]]
mesh = "sphere"
subdivisions = 1
material = "m"

[[object]]
mesh = "plane"
material = "f"

[material.m]
type = "blinnphong"
ks = 0.5
exponent = 200.0
kd = 0.3
normalization = "energy"

[material.f]
type = "file"
path = "m.wbm"
brdf = ["blinnphong:exponent=50,ks=0.6,normalization=energy"]
"""


def test_scene_file_reads_the_normalization(tmp_path):
    _material([wb.BlinnPhong(0.2, 20.0)]).save(tmp_path / "m.wbm")
    (tmp_path / "scene.toml").write_text(SCENE)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EnergyWarning)  # both are physical with "energy"
        sf = load_scene(tmp_path / "scene.toml", backend="warp:cpu")
    assert sf.materials["m"] == wb.BlinnPhong(0.5, 200.0, 0.3, normalization="energy")
    assert sf.materials["f"].materials == [wb.BlinnPhong(0.6, 50.0, normalization="energy")]


def test_scene_file_energy_gain_is_located(tmp_path):
    text = SCENE.replace('normalization = "energy"\n', "")
    _material([wb.BlinnPhong(0.2, 20.0)]).save(tmp_path / "m.wbm")
    (tmp_path / "scene.toml").write_text(text)
    line = next(i for i, s in enumerate(text.splitlines(), 1) if s.startswith("ks = 0.5"))
    with pytest.warns(EnergyWarning, match=rf"^scene\.toml:{line}: \[material\.m\] BlinnPhong directional albedo"):
        load_scene(tmp_path / "scene.toml", backend="warp:cpu")


@pytest.mark.parametrize("where", ["analytic", "brdf string"])
def test_scene_file_unknown_normalization_is_located(tmp_path, where):
    if where == "analytic":
        text, snippet = SCENE.replace('normalization = "energy"', 'normalization = "physical"'), "physical"
    else:
        text, snippet = SCENE.replace("normalization=energy", "normalization=physical"), "physical"
    _material([wb.BlinnPhong(0.2, 20.0)]).save(tmp_path / "m.wbm")
    (tmp_path / "scene.toml").write_text(textwrap.dedent(text))
    with pytest.raises(SceneError) as info:
        load_scene(tmp_path / "scene.toml", backend="warp:cpu")
    line = next(i for i, s in enumerate(text.splitlines(), 1) if snippet in s)
    msg = str(info.value)
    assert msg.startswith(f"scene.toml:{line}:") and "'physical'" in msg and "\n" not in msg, msg
