"""Anisotropic small-scale BRDFs (issue 20 item 2): `AnisotropicWard` and `AshikhminShirley` in float64, the tile's
face tangents, and the ground truth's kernels on every backend present; what refuses them, and why.

Tolerances, and why:
- float64 identities (αx = αy is the isotropic Ward, a tangent turned by 90° swaps the two widths, reciprocity,
  the tangent's sign): 1e-12 relative — equal expressions that round differently (Ward's tan²θh from 1 − (n·h)²
  against (h·x)² + (h·y)², both over (n·h)²).
- kernels against the float64 reference given the kernel's own visibility bits: 2e-4 relative plus 2e-4 of the
  largest value absolute, as tests/test_stages.py (float32 BRDF arithmetic; Ashikhmin–Shirley's power is taken
  from the tangential components, so exponents up to 10⁴ stay inside it).
- the same tile and facets with Ward(α) against AnisotropicWard(α, α), or with a tangent turned by 90° and the
  widths swapped, through the kernels: 2e-4 relative plus 2e-4 of the peak — the same mathematics in float32
  from different operations.
- the V-groove's closed form (reference.vgroove_effective_brdf) against the ground truth at 2^16 facets: 5e-3
  of the peak, as tests/test_truth.py for the isotropic BRDFs (the sampling error of each wall's visibility
  boundary).
- directional albedo by Gauss–Legendre quadrature over the half vector (geometric θh panels from a sixteenth of
  the lobe width, 180 φ nodes): against 720 φ nodes and 24-node panels it differs by < 3e-4; the A–S diffuse
  term alone is checked against its closed form 1 − (1 − cosθo/2)⁵ to 1e-4.
"""

import warnings

import numpy as np
import pytest
from conftest import flat_tile, random_heightfield, vgroove_tile

import warp_biscale as wb
from warp_biscale import reference as ref
from warp_biscale.brdf import (AnisotropicWard, AshikhminShirley, EnergyWarning, pack_materials, parse_brdf,
                               tangent_frame)
from warp_biscale.scene import Scene
from warp_biscale.smallscale import default_face_tangents

ANISOTROPIC = [
    AnisotropicWard(ks=(1.0, 0.8, 0.6), alpha_x=0.05, alpha_y=0.3, kd=0.1),
    AnisotropicWard(ks=0.7, alpha_x=0.6, alpha_y=0.2, kd=(0.1, 0.2, 0.3)),
    AshikhminShirley(rs=(0.9, 0.5, 0.1), nu=10, nv=1000, rd=(0.05, 0.3, 0.6)),
    AshikhminShirley(rs=0.04, nu=10000, nv=200, rd=0.5),
    AshikhminShirley(rs=0.5, nu=1, nv=1, rd=0.5),
]


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_configs(n, seed):
    """n unit normals near +z, directions above them, and tangents in random directions, at least 0.1 rad off the
    normal (closer, the frame's fallback would make the turned and the plain tangent different frames)."""
    rng = np.random.default_rng(seed)
    normal = _unit(rng.normal(size=(n, 3)) * [0.3, 0.3, 1.0] + [0, 0, 1.5])
    wi, wo = (_unit(normal * 1.2 + rng.normal(size=(n, 3))) for _ in range(2))
    tangent = rng.normal(size=(n, 3))
    across = np.linalg.norm(np.cross(_unit(tangent), normal), axis=1)
    tangent[across < 0.1] = np.cross(normal[across < 0.1], [1.0, 0, 0])
    return normal, wi, wo, tangent


def _eval_cos(brdf, n, wi, wo, t):
    kinds, params = pack_materials([brdf], anisotropic=True)
    return ref.brdf_cosine_weighted(kinds, params, np.zeros(len(n), np.int32), n, wi, wo, t)


# ------------------------------------------------------------------------------------------------ float64


def test_anisotropic_ward_with_equal_widths_is_ward():
    n, wi, wo, t = _random_configs(4000, 1)
    for alpha in (0.02, 0.2, 0.7):
        iso = _eval_cos(wb.Ward(ks=(1, 0.5, 0.2), alpha=alpha, kd=0.3), n, wi, wo, t)
        aniso = _eval_cos(AnisotropicWard(ks=(1, 0.5, 0.2), alpha_x=alpha, alpha_y=alpha, kd=0.3), n, wi, wo, t)
        assert (iso > 0).mean() > 0.5
        np.testing.assert_allclose(aniso, iso, rtol=1e-12, atol=1e-12 * iso.max())


@pytest.mark.parametrize("make", [lambda a, b: AnisotropicWard(ks=0.9, alpha_x=a, alpha_y=b, kd=0.1),
                                  lambda a, b: AshikhminShirley(rs=0.6, nu=1 / a**2, nv=1 / b**2, rd=0.3)],
                         ids=["ward", "ashikhmin-shirley"])
def test_tangent_turned_90_degrees_swaps_the_widths(make):
    """Turning the tangent by 90° about the normal (t → n × t) is the same BRDF with αx ↔ αy (nu ↔ nv); its sign
    changes nothing (both lobes are even in x and in y)."""
    n, wi, wo, t = _random_configs(4000, 2)
    a = _eval_cos(make(0.08, 0.4), n, wi, wo, t)
    turned = np.cross(n, t - np.einsum("ij,ij->i", t, n)[:, None] * n)
    b = _eval_cos(make(0.4, 0.08), n, wi, wo, turned)
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * a.max())
    np.testing.assert_allclose(_eval_cos(make(0.08, 0.4), n, wi, wo, -t), a, rtol=1e-12, atol=1e-12 * a.max())
    # and it is anisotropic: the swapped widths in the same frame differ
    assert np.abs(_eval_cos(make(0.4, 0.08), n, wi, wo, t) - a).max() > 0.1 * a.max()


@pytest.mark.parametrize("brdf", ANISOTROPIC, ids=repr)
def test_reciprocal(brdf):
    n, wi, wo, t = _random_configs(4000, 3)
    a = brdf.eval(n, wi, wo, t)
    np.testing.assert_allclose(brdf.eval(n, wo, wi, t), a, rtol=1e-12, atol=1e-13 * a.max())
    assert np.all(np.isfinite(a)) and (a >= 0).all()


def _albedo(brdf, wo, width, n_phi=180, nodes=12):
    """(3,) directional albedo ∫ f_r(ωi, ωo) cosθi dωi, normal +z, tangent +x, by Gauss–Legendre quadrature over
    the half vector (ωi = 2(h·ωo)h − ωo, dωi = 4(h·ωo)dω_h): θh in geometric panels from width/16 to π/2, so
    a lobe of angular `width` and the broad rest are both resolved."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    edges = [0.0]
    e = width / 16
    while e < np.pi / 2:
        edges.append(e)
        e *= 1.6
    edges.append(np.pi / 2)
    th = np.concatenate([a + (b - a) * (x + 1) / 2 for a, b in zip(edges[:-1], edges[1:])])
    w_th = np.concatenate([(b - a) / 2 * w for a, b in zip(edges[:-1], edges[1:])])
    xp, wp = np.polynomial.legendre.leggauss(n_phi)
    phi, w_phi = np.pi * (xp + 1), np.pi * wp
    tt, pp = np.meshgrid(th, phi, indexing="ij")
    weight = (np.outer(w_th, w_phi) * np.sin(tt)).reshape(-1)
    h = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1).reshape(-1, 3)
    ho = h @ wo
    wi = 2 * ho[:, None] * h - wo
    count = len(h)
    f = brdf.eval(np.tile([0.0, 0.0, 1.0], (count, 1)), wi, np.tile(wo, (count, 1)), np.tile([1.0, 0, 0], (count, 1)))
    return (f * (np.maximum(wi[:, 2], 0) * 4 * np.maximum(ho, 0) * weight)[:, None]).sum(0)


def _view(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def test_ashikhmin_shirley_diffuse_albedo_closed_form():
    """Its diffuse term alone (rd = 1 minus rd = 0, rs = 0) has the albedo 1 − (1 − cosθo/2)⁵ exactly (the 28/23
    normalisation): this checks the quadrature and the formula at once."""
    for theta in (0, 45, 80, 89):
        wo = _view(theta, 30)
        d = (_albedo(AshikhminShirley(rs=0.0, nu=10, nv=100, rd=1.0), wo, 0.1)
             - _albedo(AshikhminShirley(rs=0.0, nu=10, nv=100, rd=0.0), wo, 0.1))
        np.testing.assert_allclose(d, 1 - (1 - wo[2] / 2) ** 5, rtol=1e-4)


def test_ashikhmin_shirley_albedo_at_most_one_with_rs_plus_rd_at_most_one():
    """Measured (this quadrature; docs/design.md §4.7): the largest directional albedo over θo in {0, 60, 85, 89}°,
    φo along and across the tangent, is 0.9996: rs = 1 (F = 1), nu = nv = 10⁴, at normal incidence — the
    specular lobe's albedo tends to 1 from below as it sharpens; rs = 0, rd = 1 gives 0.969 there (the diffuse
    term's 31/32 plus a little of Schlick's grazing specular)."""
    largest = 0.0
    for rs, rd in ((1.0, 0.0), (0.0, 1.0), (0.5, 0.5)):
        for nu, nv in ((1, 1), (8, 800), (10000, 10000)):
            brdf = AshikhminShirley(rs=rs, nu=nu, nv=nv, rd=rd)
            width = 1 / np.sqrt(max(nu, nv))
            for theta in (0, 60, 85, 89):
                for phi in (0, 90):
                    a = _albedo(brdf, _view(theta, phi), width)
                    assert np.all(a <= 1.0), (brdf, theta, phi, a)
                    largest = max(largest, float(a.max()))
    assert 0.999 < largest <= 1.0


def test_anisotropic_ward_albedo_measured():
    """Measured by the same quadrature, ks = 1, kd = 0 (docs/design.md §4.7): the albedo is below 1 up to θo = 89°,
    largest at normal incidence for narrow lobes (0.993 for α = 0.05), and towards grazing it grows along the
    wider axis (0.605 at θo = 89° for αx = 0.05, αy = 0.5 looking across the tangent, 0.041 along it); Ward's
    1/√(cosθi cosθo) makes it diverge as 1/√cosθo at grazing (1.484 at 89.9° for α = 0.5)."""
    b = AnisotropicWard(ks=1.0, alpha_x=0.05, alpha_y=0.5)
    along, across = _albedo(b, _view(89, 0), 0.05)[0], _albedo(b, _view(89, 90), 0.05)[0]
    assert along == pytest.approx(0.041, abs=2e-3) and across == pytest.approx(0.605, abs=2e-3)
    assert _albedo(AnisotropicWard(ks=1.0, alpha_x=0.05, alpha_y=0.05), _view(0, 0), 0.05)[0] == \
        pytest.approx(0.993, abs=2e-3)
    assert _albedo(AnisotropicWard(ks=1.0, alpha_x=0.5, alpha_y=0.5), _view(89.9, 90), 0.5)[0] == \
        pytest.approx(1.484, abs=2e-3)


def test_tangent_frame_and_its_fallback():
    n, _, _, t = _random_configs(1000, 4)
    t[:10] = n[:10] * 3.0  # parallel: the fallback
    t[10:20] = -n[10:20] + 1e-4  # nearly anti-parallel: the fallback
    x, y = tangent_frame(n, t)
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", x, n), 0, atol=1e-12)
    np.testing.assert_allclose(np.cross(x, y), n, atol=1e-12)
    ok = slice(20, None)
    proj = t[ok] - np.einsum("ij,ij->i", t[ok], n[ok])[:, None] * n[ok]
    np.testing.assert_allclose(x[ok], _unit(proj), atol=1e-12)
    # the fallback for the poles too (Duff et al. at n = ±z)
    x, y = tangent_frame(np.array([[0, 0, 1.0], [0, 0, -1.0]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    np.testing.assert_allclose(np.abs(x @ [0, 0, 1.0]), 0, atol=1e-15)


def test_eval_needs_a_tangent():
    with pytest.raises(ValueError, match="needs the facet's tangent"):
        AnisotropicWard().eval([0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0])
    kinds, params = pack_materials([AshikhminShirley()], anisotropic=True)
    with pytest.raises(ValueError, match="tangents"):
        ref.brdf_cosine_weighted(kinds, params, np.zeros(1, np.int32), [[0, 0, 1.0]], [[0, 0, 1.0]], [[0, 0, 1.0]])
    # isotropic BRDFs ignore it
    np.testing.assert_array_equal(wb.Ward().eval([0, 0, 1.0], [0, 0.6, 0.8], [0, 0, 1.0], tangent=[1.0, 0, 0]),
                                  wb.Ward().eval([0, 0, 1.0], [0, 0.6, 0.8], [0, 0, 1.0]))


# ------------------------------------------------------------------------------------------------ parameters


def test_parse_brdf_anisotropic():
    b = parse_brdf("ward:alpha_x=0.1,alpha_y=0.4,ks=0.8,kd=0.1/0.2/0.3")
    assert b == AnisotropicWard(ks=0.8, alpha_x=0.1, alpha_y=0.4, kd=(0.1, 0.2, 0.3))
    assert parse_brdf("anisotropicward:alpha_x=0.2,alpha_y=0.1") == AnisotropicWard(alpha_x=0.2, alpha_y=0.1)
    assert parse_brdf("ward:alpha=0.3") == wb.Ward(alpha=0.3)  # still the isotropic one
    assert parse_brdf("as:nu=10,nv=1000,rs=0.8,rd=0.2") == AshikhminShirley(rs=0.8, nu=10, nv=1000, rd=0.2)
    assert parse_brdf("ashikhmin-shirley:nu=5,nv=5") == AshikhminShirley(nu=5, nv=5)


@pytest.mark.parametrize("text, match", [
    ("ward:alpha_x=0.1", "needs both alpha_x and alpha_y"),
    ("ward:alpha=0.2,alpha_x=0.1,alpha_y=0.3", "not both"),
    ("ward:alpha_x=0,alpha_y=0.3", "alpha_x must be a finite number > 0"),
    ("ward:alpha_x=0.1,alpha_y=-1", "alpha_y must be a finite number > 0"),
    ("ward:alpha_x=nan,alpha_y=0.3", "alpha_x must be a finite number > 0"),
    ("as:nu=0,nv=10", "nu must be a finite number > 0"),
    ("as:nu=10,nv=inf", "nv must be a finite number > 0"),
    ("as:rs=1.5", r"rs must lie in \[0, 1\]"),
    ("as:rd=-0.1", "rd must be finite and >= 0"),
    ("as:alpha=0.1", "has no parameter 'alpha'"),
    ("as:nu=ten,nv=10", "is not a number"),
    # one axis alone would silently pair with the other's default, under either name
    ("anisotropicward:alpha_x=0.1", "the anisotropic ward needs both alpha_x and alpha_y .* got only alpha_x"),
    ("as:nu=100", "ashikhminshirley needs both nu and nv .* got only nu"),
    ("as:nu=10,,nv=100", "has an empty parameter"),
    ("as:nu=10,nv=100,", "has an empty parameter"),
    ("as:nu,nv=10", "BRDF parameter 'nu' must be key=value"),
    ("glossy:nu=1", r"unknown BRDF 'glossy'; choose one of .* ashikhminshirley \(as\)"),
])
def test_parse_brdf_bad_values_are_one_line_errors(text, match):
    with pytest.raises(ValueError, match=match) as err:
        parse_brdf(text)
    assert "\n" not in str(err.value)


def test_ashikhmin_shirley_energy_warning():
    with pytest.warns(EnergyWarning, match="rs \\+ rd = 1.2 > 1"):
        AshikhminShirley(rs=0.5, rd=0.7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        AshikhminShirley(rs=(0.5, 0.2, 0.0), rd=(0.5, 0.8, 1.0))  # rs + rd = 1 exactly: no warning
    b = AshikhminShirley(rs=0.3, rd=0.6)
    assert b.kd == b.rd and b.ks == b.rs  # the diffuse and specular reflectance under the common names


# ------------------------------------------------------------------------------------------------ tiles


def test_default_face_tangents():
    n = _unit(np.array([[0, 0, 1.0], [1, 0, 0], [-1, 0, 1e-3], [1, 0, 1], [0.3, -0.4, 0.8], [0, 1, 0]]))
    t = default_face_tangents(n)
    np.testing.assert_allclose(np.einsum("ij,ij->i", t, n), 0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1, atol=1e-15)
    np.testing.assert_allclose(t[0], [1, 0, 0])
    np.testing.assert_allclose(t[1], [0, 1, 0])  # a wall facing +x: +y
    np.testing.assert_allclose(t[2], [0, 1, 0], atol=1e-15)  # within 0.01 rad of -x: +y
    np.testing.assert_allclose(t[3], _unit(np.array([1, 0, -1.0])))  # +x projected
    np.testing.assert_allclose(t[5], [1, 0, 0])
    tile = flat_tile()
    np.testing.assert_allclose(tile.face_tangents, [[1, 0, 0]] * 2)
    assert not tile.face_tangents.flags.writeable


def test_given_face_tangents_are_projected_checked_and_follow_dropped_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 2, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 0, 4]])  # the last is degenerate: dropped
    with pytest.warns(wb.TileWarning, match="dropped 1"):
        tile = wb.SmallScale(v, faces, face_tangents=[[1, 1, 5.0], [0, 2, 0], [1, 0, 0]], period=(1, 1))
    np.testing.assert_allclose(tile.face_tangents, [_unit(np.array([1, 1, 0.0])), [0, 1, 0]])
    quad = v[:4], faces[:2]
    with pytest.raises(ValueError, match="face_tangents row 1 .* parallel to its face's normal"):
        wb.SmallScale(*quad, face_tangents=[[1, 0, 0], [0, 0, -2.0]])
    with pytest.raises(ValueError, match="face_tangents row 0 .* parallel"):
        wb.SmallScale(*quad, face_tangents=[[0, 0, 0.0], [1, 0, 0]])
    with pytest.raises(ValueError, match="face_tangents contains NaN"):
        wb.SmallScale(*quad, face_tangents=[[np.nan, 0, 0], [1, 0, 0]])
    with pytest.raises(ValueError, match="one row per face"):
        wb.SmallScale(*quad, face_tangents=[[1, 0, 0]])


def test_face_tangents_survive_a_ply_file(tmp_path):
    tile = wb.geometry.grooves(axis="y", profile="u", segments=6)
    np.testing.assert_allclose(tile.face_tangents, np.tile([0, 1.0, 0], (len(tile.faces), 1)), atol=1e-15)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wb.TileWarning)  # a mesh file re-merges the welded boundary
        tile.save(tmp_path / "g.ply")
        back = wb.SmallScale.load(tmp_path / "g.ply", period=tile.period)
        tile.save(tmp_path / "g.obj")  # no place for them: the default comes back
        obj = wb.SmallScale.load(tmp_path / "g.obj", period=tile.period)
    np.testing.assert_allclose(back.face_tangents, tile.face_tangents, atol=1e-6)
    np.testing.assert_allclose(obj.face_tangents, default_face_tangents(obj.face_normals))


def test_procedural_tiles_set_tangents_along_grooves_and_threads():
    g = wb.geometry.grooves(axis="x", profile="v")
    np.testing.assert_allclose(g.face_tangents, np.tile([1.0, 0, 0], (len(g.faces), 1)), atol=1e-15)
    w = wb.geometry.woven(segments=8)
    t, n = w.face_tangents, w.face_normals
    np.testing.assert_allclose(np.einsum("ij,ij->i", t, n), 0, atol=1e-12)  # in each face's plane
    warp_faces, weft_faces = w.material_ids == 0, w.material_ids == 1
    np.testing.assert_allclose(t[warp_faces, 1], 0, atol=1e-12)  # warp threads run along x
    np.testing.assert_allclose(t[weft_faces, 0], 0, atol=1e-12)  # weft threads along y
    assert np.abs(t[warp_faces, 0]).min() > 0.5 and np.abs(t[weft_faces, 1]).min() > 0.5


# ------------------------------------------------------------------------------------------------ kernels


def _curved_tile(seed=5):
    """A height field with bent vertex normals (each facet's frame is made perpendicular to an interpolated
    normal) and random face tangents, two material ids."""
    base = random_heightfield(n=4, seed=seed, materials=2)
    vn = base.vertices - np.array([0.5, 0.5, -1.0])
    rng = np.random.default_rng(seed)
    return wb.SmallScale(base.vertices, base.faces, material_ids=base.material_ids, colors=base.colors,
                         vertex_normals=vn, face_tangents=rng.normal(size=(len(base.faces), 3)))


def _hard_directions():
    el = np.radians([0.5, 5, 30, 60, 89.5])
    az = np.radians([0, 40, 90, 200, 300])
    e, a = np.meshgrid(el, az)
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)


@pytest.mark.parametrize("brdf", ANISOTROPIC, ids=repr)
def test_kernel_matches_reference(backend, brdf):
    """Each anisotropic kernel path (with an isotropic material on the tile's other id, so both branches of the
    facet loop run) against the float64 reference, given the kernel's bits, at grazing and normal angles."""
    tile = _curved_tile()
    fac = backend.sample_facets(tile, 512, seed=0)
    dirs = _hard_directions()
    vis = backend.visibility(tile, fac, dirs)
    a_v = backend.visible_area(fac, vis)
    pi, po = wb.directions.all_pairs(len(dirs))
    mats = [brdf, wb.BlinnPhong(ks=0.2, exponent=64, kd=0.2)]
    kinds, params = pack_materials(mats, anisotropic=True)
    f = backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v, tangents=tile.face_tangents)
    assert np.all(np.isfinite(f)) and (f >= 0).all()
    expected = ref.effective_brdf(fac.as_dict(), vis.as_bool(), dirs, kinds, params, pi, po,
                                  tangents=tile.face_tangents)
    assert expected.max() > 0
    np.testing.assert_allclose(f, expected, rtol=2e-4, atol=2e-4 * expected.max())


def test_kernel_tangent_fallback_matches_reference(backend):
    """Facet normals bent onto their face's tangent (+x): the frame falls back on Duff et al.'s basis, alike on
    the device and in the reference."""
    tile = flat_tile()
    tile = wb.SmallScale(tile.vertices, tile.faces, vertex_normals=np.tile([1.0, 0, 0.002], (4, 1)))
    fac = backend.sample_facets(tile, 256, seed=0)
    dirs = _unit(np.array([[1, 0.2, 0.3], [1, -0.5, 0.5], [0.8, 0.6, 0.2], [1, 0, 1.0]]))
    vis = backend.visibility(tile, fac, dirs)
    a_v = backend.visible_area(fac, vis)
    pi, po = wb.directions.all_pairs(len(dirs))
    for brdf in ANISOTROPIC[:3]:
        kinds, params = pack_materials([brdf], anisotropic=True)
        f = backend.effective_brdf(fac, vis, kinds, params, pi, po, a_v, tangents=tile.face_tangents)
        expected = ref.effective_brdf(fac.as_dict(), vis.as_bool(), dirs, kinds, params, pi, po,
                                      tangents=tile.face_tangents)
        assert expected.max() > 0
        np.testing.assert_allclose(f, expected, rtol=2e-4, atol=2e-4 * expected.max())


def test_kernel_without_tangents_is_refused(backend, flat):
    fac = backend.sample_facets(flat, 64, seed=0)
    vis = backend.visibility(flat, fac, [[0, 0, 1.0]])
    kinds, params = pack_materials([AnisotropicWard()], anisotropic=True)
    with pytest.raises(ValueError, match="face tangents"):
        backend.effective_brdf(fac, vis, kinds, params, [0], [0], backend.visible_area(fac, vis))


def test_ground_truth_equal_widths_is_ward(backend):
    tile = wb.geometry.grooves(profile="u", axis="y", segments=8)
    iso = wb.ground_truth(tile, wb.Ward(ks=0.8, alpha=0.15, kd=0.1), facets=4096, directions=6, backend=backend)
    an = wb.ground_truth(tile, AnisotropicWard(ks=0.8, alpha_x=0.15, alpha_y=0.15, kd=0.1), facets=4096,
                         directions=6, backend=backend)
    np.testing.assert_allclose(an.table, iso.table, rtol=2e-4, atol=2e-4 * iso.table.max())


@pytest.mark.parametrize("widths", [("alpha_x", "alpha_y", 0.08, 0.4), ("nu", "nv", 20.0, 800.0)],
                         ids=["ward", "ashikhmin-shirley"])
def test_ground_truth_tangents_turned_90_degrees_swap_the_widths(backend, widths):
    """The same tile with every face tangent turned by 90° in its plane, and the two widths swapped, is the same
    ground truth (same facets: the tangents change nothing else)."""
    kx, ky, a, b = widths
    cls = AnisotropicWard if kx == "alpha_x" else AshikhminShirley
    tile = random_heightfield(n=6, seed=2)
    turned = wb.SmallScale(tile.vertices, tile.faces, colors=tile.colors,
                           face_tangents=np.cross(tile.face_normals, tile.face_tangents))
    one = wb.ground_truth(tile, cls(**{kx: a, ky: b}), facets=4096, directions=6, backend=backend)
    two = wb.ground_truth(turned, cls(**{kx: b, ky: a}), facets=4096, directions=6, backend=backend)
    np.testing.assert_allclose(two.table, one.table, rtol=2e-4, atol=2e-4 * one.table.max())
    swapped = wb.ground_truth(tile, cls(**{kx: b, ky: a}), facets=4096, directions=6, backend=backend)
    assert np.abs(swapped.table - one.table).max() > 0.05 * one.table.max()  # and the tangent does matter


@pytest.mark.parametrize("brdf", [ANISOTROPIC[0], ANISOTROPIC[2]], ids=repr)
def test_vgroove_matches_closed_form(backend, brdf):
    """The V-groove's closed form with the walls' default tangents (across the groove, down each wall)."""
    depth = 0.5
    tile = vgroove_tile(depth=depth)
    gt = wb.ground_truth(tile, brdf, facets=1 << 16, directions=6, backend=backend)
    pi, po = wb.directions.all_pairs(len(gt.grid))
    kinds, params = pack_materials([brdf], anisotropic=True)
    cf = ref.vgroove_effective_brdf(depth, 1.0, kinds, params, gt.grid[pi], gt.grid[po]).reshape(gt.table.shape)
    err = np.abs(gt.table - cf)
    assert err.max() <= 5e-3 * cf.max(), f"max error {err.max():.3g} vs peak {cf.max():.3g}"


def test_effective_brdf_exact_takes_anisotropic_materials(backend):
    tile = wb.geometry.grooves(profile="v", axis="x")
    rng = np.random.default_rng(0)
    wi = wb.directions.square_to_hemisphere(rng.random((40, 2)))
    wo = wb.directions.square_to_hemisphere(rng.random((40, 2)))
    f = wb.effective_brdf_exact(tile, AshikhminShirley(rs=0.7, nu=50, nv=500, rd=0.3), wi, wo, facets=2048,
                                backend=backend)
    assert f.shape == (40, 3) and np.all(np.isfinite(f)) and (f >= 0).all() and f.max() > 0


def test_isotropic_ground_truth_ignores_the_tangents(backend, heightfield):
    """Bit for bit: an isotropic material never reads the tangents, whatever they are."""
    turned = wb.SmallScale(heightfield.vertices, heightfield.faces, material_ids=heightfield.material_ids,
                           colors=heightfield.colors, face_tangents=np.cross(heightfield.face_normals, [0.3, 1, 0]))
    mats = [wb.CookTorrance(ks=0.9, roughness=0.2, kd=0.1)]
    a = wb.ground_truth(heightfield, mats, facets=2048, directions=5, backend=backend)
    b = wb.ground_truth(turned, mats, facets=2048, directions=5, backend=backend)
    np.testing.assert_array_equal(a.table, b.table)


# ------------------------------------------------------------------------------------------------ refusals


def test_sg_bake_refuses_anisotropic_materials(vgroove):
    with pytest.raises(ValueError, match=r"materials\[1\] \(AshikhminShirley\) is anisotropic: method='sg' .*"
                                         r"bake it with method='asg'") as err:
        wb.bake(vgroove, [wb.Lambert(0.5), AshikhminShirley()], facets=256, directions=4)
    assert "\n" not in str(err.value)
    for method in ("sg-exact", "matrix"):
        with pytest.raises(ValueError, match="method='asg'"):
            wb.bake(vgroove, AnisotropicWard(), facets=256, directions=4, method=method)


def test_effective_material_refuses_anisotropic_materials(flat):
    mat = wb.bake(flat, wb.Lambert(0.5), facets=256, directions=4, lobes=1, backend="warp:cpu")
    with pytest.raises(ValueError, match=r"materials\[0\] \(AnisotropicWard\) is anisotropic"):
        mat.with_materials([AnisotropicWard()])


def test_lit_sphere_refuses_anisotropic_materials():
    """A lit sphere holds one value per normal: an anisotropic material, which the SG renderer and the Monte
    Carlo reference shade in the mesh's tangent frame (tests/test_anisotropic_render.py), is refused in one line."""
    scene = Scene(wb.Mesh.sphere(1.0, subdivisions=1), [AshikhminShirley()], wb.Camera(eye=(0, 0, 3.5), width=8,
                  height=8), None, [wb.DirectionalLight((0, 0, 1), 1.0)])
    words = (r"^materials\[0\] \(AshikhminShirley\) is anisotropic: a lit sphere, one value per normal, cannot hold "
             r"it; render it with method='sg' or 'mc'$")
    with pytest.raises(ValueError, match=words) as err:
        wb.render(scene, method="litsphere", backend="warp:cpu")
    assert "\n" not in str(err.value)


# ------------------------------------------------------------------------------------------------ the NDF's ASG


@pytest.mark.parametrize("kind, p", [("as", 10.0), ("as", 100.0), ("ward", 0.05), ("ward", 0.3)])
def test_ndf_fit_error_against_a_one_dimensional_quadrature(kind, p):
    """`brdf.ndf_asg_error` (a 2-D rule in the disk coordinates) against scipy's adaptive quadrature over θ for the
    isotropic cases, where both functions depend on θ alone: Ashikhmin–Shirley nu = nv = n, cos^n θ against
    cos θ·e^{−n sin²θ/2}; Ward αx = αy = α, e^{−tan²θ/α²} against cos θ·e^{−sin²θ/α²}. To 1e−4 relative."""
    from scipy.integrate import quad

    if kind == "as":
        def truth(t):
            return np.cos(t) ** p

        def fit(t):
            return np.cos(t) * np.exp(-p * np.sin(t) ** 2 / 2)
        err = wb.brdf.ndf_asg_error(wb.brdf.ASHIKHMIN_SHIRLEY, p, p)
    else:
        def truth(t):
            return np.exp(-np.tan(t) ** 2 / p**2)

        def fit(t):
            return np.cos(t) * np.exp(-np.sin(t) ** 2 / p**2)
        err = wb.brdf.ndf_asg_error(wb.brdf.ANISOTROPIC_WARD, p, p)
    num = quad(lambda t: (fit(t) - truth(t)) ** 2 * np.sin(t), 0, np.pi / 2, limit=400, epsabs=0, epsrel=1e-12)[0]
    den = quad(lambda t: truth(t) ** 2 * np.sin(t), 0, np.pi / 2, limit=400, epsabs=0, epsrel=1e-12)[0]
    assert err == pytest.approx(np.sqrt(num / den), rel=1e-4)


def test_the_asg_bake_reports_the_ndf_fit_error(vgroove):
    """The ASG bake records each anisotropic material's NDF fit error (info["ndf_asg_error"], per material index);
    measured: anisotropic Ward (0.08, 0.4) 7.95 %, Ashikhmin–Shirley (100, 1000) 0.45 %, (20, 400) 2.1 %."""
    mats = [AnisotropicWard(1.0, 0.08, 0.4), AshikhminShirley(1.0, 100, 1000)][:vgroove.n_materials]
    mat = wb.bake(vgroove, mats, method="asg", lobes=2, directions=4, facets=1024, backend="warp:cpu")
    expected = {"0": 0.0795, "1": 0.0045}
    for i, e in mat.info["ndf_asg_error"].items():
        assert e == pytest.approx(expected[i], rel=0.01)
    assert AshikhminShirley(1.0, 20, 400).ndf_fit_error == pytest.approx(0.0214, rel=0.01)
    edited = mat.with_materials([AshikhminShirley(1.0, 20, 400)] * len(mats))  # an edit reports its own BRDFs'
    assert edited.info["ndf_asg_error"]["0"] == pytest.approx(0.0214, rel=0.01)
    assert "ndf_asg_error" not in mat.with_materials([wb.Lambert(0.5)] * len(mats)).info
