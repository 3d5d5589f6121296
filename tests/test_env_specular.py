"""The environment's specular magnitude of analytic materials (`shading.specular_correction`): each analytic row's
environment lobe is scaled by its exact specular albedo over what the lobe alone gives under a constant
environment, so that a constant environment is rendered exactly whatever the lobe's shape (but at the most
grazing views, where the correction is clipped).

- `shading.specular_albedo` (over the half vector, in slope coordinates scaled by the NDF's widths) against a plain
  product rule over ωi itself (an independent parametrisation: no half vector, no Jacobian), for lobes of every
  kind: within 1e−3; for narrow, elongated lobes against importance sampling of the NDF's ASG: 4 standard errors
  + 0.2 %.
- The outside truth: a sphere under a constant environment against the Monte Carlo reference (the exact BRDF),
  on every backend. Measured (32 × 24, 256 samples a pixel, seed 1, Warp CPU and PoCL alike), the SG image's
  mean over the reference's, at the rim (cos θo < 0.35, 36 pixels) / inside: anisotropic Ward 1.004 / 0.999,
  Ashikhmin–Shirley 1.006 / 0.999, Cook–Torrance 0.997 / 0.995, Ward 0.997 / 0.999, Blinn–Phong 0.999 / 0.999,
  and the relative L2 over the sphere 0.99–1.09× the reference's own noise. Before the correction: 0.980 /
  1.052, 1.407 / 1.069, 1.056 / 0.995, 0.965 / 1.014, 0.931 / 1.009, and 1.16–11.9× the noise (PoCL). Bounds: 2 % at
  the rim and 1 % inside (the means' own noise is ~0.5 % and ~0.2 %), relative L2 1.25× the noise + 0.2 %.
"""

import warnings

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import brdf as brdf_mod
from warp_biscale import sg, shading

MATERIALS = {
    "anisotropic-ward": wb.AnisotropicWard(0.6, 0.08, 0.4, kd=0.2),
    "ashikhmin-shirley": wb.AshikhminShirley(rs=0.5, nu=20, nv=400, rd=0.3),
    "cook-torrance": wb.CookTorrance(0.6, 0.2, kd=0.2),
    "ward": wb.Ward(0.5, 0.15, kd=0.2),
    "blinn-phong": wb.BlinnPhong(0.2, 64, kd=0.2),
}
SPHERE = wb.Mesh.sphere(1.0, subdivisions=4)  # one mesh object: its BVH is built once for every scene here
CONSTANT = wb.Environment.constant(1.0)  # one environment object: its lighting is prepared once


def _row(material):
    return shading._analytic_rows(material, anisotropic=True)[0].astype(np.float64)


def _albedo_over_wi(row, wo, nodes=400):
    """∫ f_s (n·ωi)⁺ dωi by a product rule over ωi: Gauss–Legendre in cos θi, the trapezoid rule in φi."""
    c, wc = np.polynomial.legendre.leggauss(nodes)
    c, wc = (c + 1) / 2, wc / 2
    phi = (np.arange(2 * nodes) + 0.5) * np.pi / nodes
    cc, pp = np.meshgrid(c, phi, indexing="ij")
    s = np.sqrt(1 - cc**2)
    wi = np.stack([s * np.cos(pp), s * np.sin(pp), cc], -1).reshape(-1, 3)
    weight = np.outer(wc, np.full(len(phi), np.pi / nodes)).ravel()
    params = row[1:9].copy()
    params[0:3] = 0.0
    z = np.broadcast_to([0.0, 0.0, 1.0], wi.shape)
    x = np.broadcast_to([1.0, 0.0, 0.0], wi.shape)
    fc = wb.brdf.brdf_cosine_weighted(np.array([int(row[0])]), params[None], np.zeros(len(wi), np.int64), z, wi,
                                      np.broadcast_to(wo, wi.shape), x)
    return (fc * weight[:, None]).sum(0) / wo[2]


def _albedo_by_sampling(row, wo, count=1 << 18):
    """The same integral by importance sampling h from the NDF's ASG (`montecarlo_sampling.sample_asg`, exact pdf),
    stratified: (mean, standard error) per channel. For narrow, elongated lobes a fixed rule over ωi cannot
    resolve."""
    from warp_biscale.montecarlo_sampling import asg_pdf, sample_asg

    lam, mu = wb.brdf.ndf_bandwidths(int(row[0]), row[7], row[8])
    side = int(np.sqrt(count))
    rng = np.random.default_rng(3)
    u1, u2 = ((np.indices((side, side)).reshape(2, -1) + rng.random((2, side * side))) / side)
    x, y, z = (np.broadcast_to(v, (side * side, 3)) for v in np.eye(3))
    h = sample_asg(x, y, z, lam, mu, u1, u2)
    pdf = asg_pdf(x, y, z, lam, mu, h)
    ho = h @ wo
    wi = 2 * ho[:, None] * h - wo
    params = row[1:9].copy()
    params[0:3] = 0.0
    fc = wb.brdf.brdf_cosine_weighted(np.array([int(row[0])]), params[None], np.zeros(len(h), np.int64), z, wi,
                                      np.broadcast_to(wo, h.shape), x)
    ok = (ho > 0) & (wi[:, 2] > 0) & (pdf > 0)
    g = np.where(ok[:, None], fc * (4 * ho / np.where(ok, pdf, 1.0))[:, None], 0.0) / wo[2]
    return g.mean(0), g.std(0) / np.sqrt(len(g))


@pytest.mark.parametrize("material", [wb.AnisotropicWard(0.6, 0.02, 0.5), wb.AshikhminShirley(rs=0.6, nu=10, nv=10000)],
                         ids=lambda m: type(m).__name__)
def test_specular_albedo_of_narrow_elongated_lobes_against_importance_sampling(material):
    """Lobes 25 and 1000 times longer than wide: the rule follows the NDF's two widths (an earlier rule in θh,
    placed by the broad width, was 15–30 % low on these, against this sampling)."""
    row = _row(material)
    for theta, phi in ((0.1, 0.0), (0.9, 0.7), (1.3, 1.3)):
        wo = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        got = shading.specular_albedo(row, wo[None])[0]
        want, err = _albedo_by_sampling(row, wo)
        assert np.all(np.abs(got - want) < 4 * err + 2e-3 * want), (theta, phi, got, want, err)


@pytest.mark.parametrize("material", [wb.CookTorrance(0.6, 0.3, f0=0.1), wb.Ward(0.5, 0.25), wb.BlinnPhong(0.25, 24),
                                      wb.AnisotropicWard(0.6, 0.2, 0.4), wb.AshikhminShirley(rs=0.5, nu=10, nv=60)],
                         ids=lambda m: type(m).__name__)
def test_specular_albedo_against_a_quadrature_over_the_light_directions(material):
    row = _row(material)
    for theta, phi in ((0.1, 0.0), (0.9, 0.7), (1.4, 1.3)):
        wo = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        got = shading.specular_albedo(row, wo[None])[0]
        want = _albedo_over_wi(row, wo)
        np.testing.assert_allclose(got, want, rtol=1e-3, err_msg=f"θo {theta}, φo {phi}")


def test_the_correction_tables():
    """Their shape (φo only for the anisotropic kinds), 1 for a row without a specular lobe, finite, within
    [0, CORRECTION_MAX], the same object for the same row (kept), and where the packed rows find them."""
    iso = shading.specular_correction(_row(MATERIALS["cook-torrance"]))
    aniso = shading.specular_correction(_row(MATERIALS["ashikhmin-shirley"]))
    assert iso.shape == (shading.CORRECTION_COS, 1, 3) and aniso.shape == (shading.CORRECTION_COS,
                                                                            shading.CORRECTION_PHI, 3)
    for table in (iso, aniso):
        assert np.isfinite(table).all() and table.min() >= 0 and table.max() <= shading.CORRECTION_MAX
    assert shading.specular_correction(_row(MATERIALS["cook-torrance"])) is iso
    np.testing.assert_array_equal(shading.specular_correction(_row(wb.Lambert(0.5))), np.ones((1, 1, 3)))
    packed = shading.pack_materials([wb.Lambert(0.5), MATERIALS["ashikhmin-shirley"], MATERIALS["cook-torrance"]])
    for slot, want in ((3, aniso), (5, iso), (6, shading.moment_table(_row(MATERIALS["cook-torrance"])))):
        off, h, w, _ = packed["tex_info"][slot]  # (row r's correction at slot 1 + 2r, its moment table at 2 + 2r)
        np.testing.assert_array_equal(packed["tex_data"][3 * off:3 * (off + h * w)].reshape(h, w, 3), want)


# A parameter map's rows have their correction c in a column per p1 step too, read at the pixel's factor as the
# moment table is (from the first factor the moment table keeps). Measured (map 0.5–2, Cook–Torrance 0.3 and
# Blinn–Phong 64, 40 views): within 0.49 % of a plain material's c at p1 times the factor, between the columns; the
# one table at the map's mean p1 that the columns replaced was up to 124 % off (at grazing views). Bound: 1.5 %.
def test_parameter_map_corrections_follow_p1():
    from warp_biscale.svbrdf import Textured

    cos_o = np.linspace(0.05, 0.99, 40)
    wo = np.stack([np.sqrt(1 - cos_o**2), 0 * cos_o, cos_o], 1)
    worst_mean = 0.0
    kinds = ((lambda p: wb.CookTorrance(0.6, p, kd=0.2), 0.3), (lambda p: wb.BlinnPhong(0.2, p, kd=0.2), 64.0))
    for make, base in kinds:
        mapped = np.array([[0.5, 2.0], [1.0, 1.0]])
        packed = shading.pack_materials([Textured(make(base), parameter_map=mapped)])
        assert packed["tex_info"][1][2] == shading.moment_p1_steps(mapped)[1] == 9
        mean = shading.pack_materials([make(base * float(mapped.mean()))])
        for factor in (0.5, 0.61, 0.8, 1.3, 1.77, 2.0):
            got = shading.correction_at(packed["tex_info"], packed["tex_data"], 1, wo, np.full(len(wo), factor))
            plain = shading.pack_materials([make(base * factor)])
            want = shading.correction_at(plain["tex_info"], plain["tex_data"], 1, wo)
            np.testing.assert_allclose(got, want, rtol=0.015, err_msg=f"factor {factor}")
            at_mean = shading.correction_at(mean["tex_info"], mean["tex_data"], 1, wo)
            worst_mean = max(worst_mean, float(np.abs(at_mean / want - 1).max()))
    assert worst_mean > 0.1  # (the columns matter)


def _sphere_against_reference(backend, material, environment, samples):
    """The unit sphere of `material` under `environment` (32 × 24), the SG image against the Monte Carlo reference
    (`samples` a pixel, seed 1) over the sphere's pixels: ([rim, inside] means' ratios (cos θo < 0.35 / ≥ 0.35 on
    the unit sphere the icosphere approximates), relative L2, the reference's relative noise)."""
    cam = wb.Camera(eye=(0.3, 0.5, 3.2), width=32, height=24, fov=45)
    scene = wb.Scene(SPHERE, [material], cam, environment, [])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = wb.render(scene, backend=backend, aa=1).image
        ref = wb.render(scene, method="mc", samples=samples, backend=backend, seed=1)
    want = ref.image
    assert np.isfinite(got).all() and got.min() >= 0
    hit = (backend.trace_primary(SPHERE, cam).face >= 0).reshape(want.shape[:2])
    eye, d = cam.rays()
    b = (eye * d).sum(1)
    t = -b - np.sqrt(np.maximum(b * b - (eye * eye).sum(1) + 1.0, 0.0))
    cos_o = (-(eye + t[:, None] * d) * d).sum(1).reshape(want.shape[:2])
    rim, inner = hit & (cos_o < 0.35), hit & (cos_o >= 0.35)
    ratios = [got[s].mean() / want[s].mean() for s in (rim, inner)]
    noise = ref.info["stderr_rms"] / np.sqrt((want[hit] ** 2).mean())
    return ratios, np.linalg.norm(got[hit] - want[hit]) / np.linalg.norm(want[hit]), noise


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_constant_environment_against_the_monte_carlo_reference(backend, name):
    ratios, rel, noise = _sphere_against_reference(backend, MATERIALS[name], CONSTANT, 256)
    msg = f"rim {ratios[0]:.4f}, inner {ratios[1]:.4f}, relative L2 {rel:.4f} (noise {noise:.4f})"
    assert abs(ratios[0] - 1) < 0.02 and abs(ratios[1] - 1) < 0.01, msg
    assert rel < 1.25 * noise + 0.002, msg


def _dense_moments(row, wo, nz=768, nphi=1536):
    """The mean direction of f_s·(n·ωi)⁺ about n = z, tangent x, at the view wo (3,), and its second moments, by the
    midpoint rule in (cos θi, φi) over the hemisphere."""
    zz, pp = np.meshgrid((np.arange(nz) + 0.5) / nz, (np.arange(nphi) + 0.5) / nphi * 2 * np.pi, indexing="ij")
    r = np.sqrt(1 - zz * zz)
    wi = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    m = len(wi)
    g = shading._analytic_specular(np.broadcast_to(row[None], (m, 9)), np.broadcast_to([[0.0, 0, 1]], (m, 3)),
                                   np.broadcast_to([[1.0, 0, 0]], (m, 3)), wi, np.broadcast_to(wo, (m, 3)))
    g = g.sum(1) * wi[:, 2]
    mean = (g[:, None] * wi).sum(0)
    return mean / np.linalg.norm(mean), (g[:, None, None] * wi[:, :, None] * wi[:, None, :]).sum(0) / g.sum()


# Where an analytic row reads the environment: the mean direction and covariance of f_s·(n·ωi)⁺, tabulated once a
# row (`shading.moment_table`) and read per pixel (`tabulated_moments`), against the dense quadrature above
# (768 × 1536) at views between the table's rows and columns, grazing ones included; the tangent frame turned about
# the normal (the view turned with it: nothing may change) and, for the anisotropic kinds, views in the other
# quadrants (read from the first's, mirrored). Measured (the frame unturned): the mean within 0.037 of the narrow
# σ, the variances along the returned axes 0.938–1.005 of the exact ones (the lowest Cook–Torrance 0.2's at
# cos θo = 0.05) and the exact covariance across them within 0.025 of their geometric mean; at cos θo = 0.05 the
# 5 × 5 Gauss–Hermite rule per pixel that the table replaced had 0.10–0.24 of the exact variance across the plane
# of incidence. Bounds: 0.1 σ, 0.9–1.05 and 0.05.
TABLE_MATERIALS = {
    "blinn-phong": wb.BlinnPhong(0.2, 64, kd=0.2),
    "broad-blinn-phong": wb.BlinnPhong(0.1, 30, kd=0.5),
    "ward": wb.Ward(0.5, 0.15, kd=0.2),
    "cook-torrance": wb.CookTorrance(0.6, 0.2, kd=0.2),
    "ashikhmin-shirley-10-1": wb.AshikhminShirley(rs=0.6, nu=100, nv=1000, rd=0.2),
    "anisotropic-ward": wb.AnisotropicWard(0.6, 0.08, 0.4, kd=0.2),
}
TABLE_VIEWS = {"isotropic": [(c, 0.0) for c in (0.05, 0.12, 0.3, 0.55, 0.97)],
               "anisotropic": [(0.12, 0.4), (0.3, 2.5), (0.55, -1.1), (0.8, 0.9)]}


@pytest.mark.parametrize("name, cos_o, phi_o", [
    (name, c, p) for name, m in TABLE_MATERIALS.items()
    for c, p in TABLE_VIEWS["anisotropic" if m.kind in brdf_mod.ANISOTROPIC_KINDS else "isotropic"]])
def test_tabulated_moments_against_a_dense_quadrature(name, cos_o, phi_o):
    row = _row(TABLE_MATERIALS[name])
    wo = np.array([np.sqrt(1 - cos_o**2) * np.cos(phi_o), np.sqrt(1 - cos_o**2) * np.sin(phi_o), cos_o])
    mean, second = _dense_moments(row, wo)
    turn = 0.7  # the tangent frame turned about the normal, the view turned with it
    rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1.0]])
    x, y, z, lam, mu = shading.tabulated_moments(shading.moment_table(row), shading.moment_sharpness(row[None]),
                                                 np.array([[0.0, 0, 1]]), rot[:, :1].T, (rot @ wo)[None])
    x, y, z = rot.T @ x[0], rot.T @ y[0], rot.T @ z[0]
    sigma_min = np.sqrt(0.5 / max(lam[0], mu[0]))
    assert np.arccos(min(float(mean @ z), 1.0)) < 0.1 * sigma_min, (mean, z, sigma_min)
    exact_x, exact_y = x @ second @ x, y @ second @ y
    assert 0.9 < (0.5 / lam[0]) / exact_x < 1.05 and 0.9 < (0.5 / mu[0]) / exact_y < 1.05, (
        0.5 / lam[0], exact_x, 0.5 / mu[0], exact_y)
    assert abs(x @ second @ y) < 0.05 * np.sqrt(exact_x * exact_y)


# A `Textured` material's parameter map changes p1, and with it the shape of the moments, pixel by pixel: its rows'
# tables have a column every quarter octave of the map's factor from its least (`moment_p1_steps`; one for a
# constant map). Read at factors between the
# columns they must give the moments of a table made at the pixel's own p1. Measured (map 0.5–2, Cook–Torrance 0.3,
# Blinn–Phong 64, Ward 0.15; cos θo 0.1 / 0.4 / 0.95): the mean within 0.013 of the narrow σ, the bandwidths within
# 0.8 %; one table at the row's p1 rescaled by η (what the columns replaced, made at the map's mean) was up to 2.62×
# off in bandwidth. Bounds: 0.05 σ, 3 %.
def test_parameter_map_rows_tabulate_their_p1():
    steps = shading.moment_p1_steps(np.array([[0.5, 2.0], [1.0, 1.2]]))
    assert steps == (-1.0, 9) and shading.moment_p1_steps(np.full((2, 2), 0.7))[1] == 1
    n, t = np.array([[0.0, 0, 1]]), np.array([[1.0, 0, 0]])
    worst_single = 0.0
    for material in (wb.CookTorrance(0.6, 0.3), wb.BlinnPhong(0.2, 64), wb.Ward(0.5, 0.15)):
        base = _row(material)
        table = shading.moment_table(base, steps)
        assert table.shape == (shading.MOMENT_TABLE_COS, 2 * steps[1], 3) and np.isfinite(table).all()
        for factor in (0.5, 0.61, 1.3, 1.77, 2.0):
            row = base.copy()
            row[7] *= factor
            eta = shading.moment_sharpness(row[None])
            for cos_o in (0.1, 0.4, 0.95):
                wo = np.array([[np.sqrt(1 - cos_o**2), 0.0, cos_o]])
                got = shading.tabulated_moments(table, eta, n, t, wo, np.array([factor]))
                want = shading.tabulated_moments(shading.moment_table(row), eta, n, t, wo)
                sigma = np.sqrt(0.5 / max(want[3][0], want[4][0]))
                assert np.arccos(min(float(got[2][0] @ want[2][0]), 1.0)) < 0.05 * sigma
                for k in (3, 4):
                    assert got[k][0] == pytest.approx(want[k][0], rel=0.03), (material, factor, cos_o, k)
                single = shading.tabulated_moments(shading.moment_table(base), eta, n, t, wo)
                worst_single = max(worst_single, *(abs(single[k][0] / want[k][0] - 1) for k in (3, 4)))
    assert worst_single > 0.3  # (the columns matter: the mean-p1 table rescaled is far off somewhere)


def test_a_colour_edit_makes_no_table_again():
    """Neither table changes with a scale of f_s: a row whose ks (or kd) alone differs takes the very tables
    already made, but for Ashikhmin–Shirley, whose ks is its Fresnel term's (its shape). The shared tables are
    those the new colour would make: the correction against a fresh build at that ks (the cache bypassed)."""
    for material, edited in ((wb.AnisotropicWard(0.6, 0.08, 0.4, kd=0.2), wb.AnisotropicWard((0.2, 0.3, 0.9), 0.08,
                                                                                              0.4, kd=0.5)),
                             (wb.CookTorrance(0.6, 0.2, kd=0.2), wb.CookTorrance(0.3, 0.2, kd=(0.1, 0.4, 0.2)))):
        a, b = _row(material), _row(edited)
        assert shading.moment_table(a) is shading.moment_table(b)
        assert shading.specular_correction(a) is shading.specular_correction(b)
    row = _row(wb.CookTorrance((0.3, 0.5, 0.9), 0.2, kd=0.2))  # the shared table is this colour's own ratio
    wo = shading.correction_directions(False).reshape(-1, 3)
    own = shading.specular_albedo(row, wo) / shading.lobe_energy(row, wo, sg.lighting_table())
    np.testing.assert_allclose(shading.specular_correction(row).reshape(-1, 3), own, rtol=1e-5)
    rs_low, rs_high = _row(wb.AshikhminShirley(rs=0.1, nu=20, nv=400)), _row(wb.AshikhminShirley(rs=0.9, nu=20, nv=400))
    assert not np.array_equal(shading.moment_table(rs_low), shading.moment_table(rs_high))


def test_a_row_without_specular_tabulates_its_shape():
    """ks = 0 (a diffuse Cook–Torrance): f_s is 0, its table is that of f_s's shape (ks = 1), finite."""
    diffuse = _row(wb.CookTorrance(0.0, 0.3, kd=0.5))
    glossy = _row(wb.CookTorrance(1.0, 0.3, kd=0.5))
    np.testing.assert_array_equal(shading.moment_table(diffuse), shading.moment_table(glossy))
    packed = shading.pack_materials([wb.CookTorrance(0.0, 0.3, kd=0.5), wb.AnisotropicWard(0.0, 0.1, 0.3, kd=0.5)])
    assert np.isfinite(packed["tex_data"]).all()


# The same against the Monte Carlo reference under the studio, whose softboxes a glossy sphere's rim reflects
# (32 × 24, 4096 samples a pixel, seed 1): the SG image's mean over the reference's at the rim (cos θo < 0.35) /
# inside, and the relative L2 over the sphere. Measured (PoCL and Warp CPU alike), with the moments tabulated
# (`moment_table`) → the 5 × 5 rule per pixel (002b5ed) → the lookup where the warp put it (6664c2f): Cook–Torrance
# 0.2 1.011 / 0.999, 1.48 % → 1.007 / 0.998, 1.63 % → 1.049 / 0.998, 4.05 %; Ward 0.15 1.026 / 0.997, 2.61 % → 1.024
# / 0.997, 2.73 % → 1.210 / 0.985, 9.70 %; Blinn–Phong 64 1.015 / 1.001, 3.20 % → 1.010 / 0.999, 3.61 % → 1.152 /
# 0.970, 11.27 %; Ashikhmin–Shirley 20 × 400 1.176 / 1.013, 11.99 % → 1.028 / 1.009, 13.09 % → 2.001 / 0.976,
# 14.09 %; anisotropic Ward 0.08 × 0.4 1.059 / 1.005, 11.99 % → 1.123 / 1.006, 15.46 % → 1.690 / 1.056, 31.62 % (the
# reference's noise 1.0–2.0 %). The table's converged moments put more light on the Ashikhmin–Shirley 20 × 400 rim
# than the rule did (why is not known) while the whole sphere comes closer. Bounds: the rim within 6 % (20 % for
# Ashikhmin–Shirley 20 × 400, 10 % for the anisotropic Ward), inside 1.5 %, and the relative L2 below the
# per-material bound (each of the rule's figures above it).
STUDIO = wb.Environment.studio(height=64, width=128)
STUDIO_L2 = {"cook-torrance": 0.016, "ward": 0.027, "blinn-phong": 0.035, "ashikhmin-shirley": 0.127,
             "anisotropic-ward": 0.14}
STUDIO_RIM = {"ashikhmin-shirley": 0.2, "anisotropic-ward": 0.1}


@pytest.mark.parametrize("name", sorted(STUDIO_L2))
def test_studio_against_the_monte_carlo_reference(backend, name):
    ratios, rel, _ = _sphere_against_reference(backend, MATERIALS[name], STUDIO, 4096)
    msg = f"rim {ratios[0]:.4f}, inner {ratios[1]:.4f}, relative L2 {rel:.4f}"
    assert abs(ratios[0] - 1) < STUDIO_RIM.get(name, 0.06) and abs(ratios[1] - 1) < 0.015, msg
    assert rel < STUDIO_L2[name], msg
