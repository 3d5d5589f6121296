"""SSDF visibility of the large-scale mesh (warp_biscale.ssdf, stage `ssdf`), on every backend present.

Tolerances, and why:
- distance transform vs reference.ssdf_distance: the class (sign) exactly; θd to 1e-5 rad. The
  kernels pick the nearest texel by float32 dot products (a near-tie may pick another texel at
  the same angle to ~1e-7) and take its angle by float32 atan2(|d×t|, d·t) (~1e-7 rad).
- octahedral round trip 1e-12 (float64 arithmetic); texel solid angles sum to 4π to 1e-9.
- a lone sphere's SSDF against the analytic horizon asin(ω·n): one texel angle (the largest angle
  between neighbouring texel centres), the grid's own quantisation of the boundary.
- sign agreement with exact ray-cast visibility, "away from boundaries": a sample direction ω
  counts only if ω and 8 directions one mean texel angle (√(4π/S²)) around it all have the same
  exact visibility; there the sign must agree for ≥ 97% of samples.
"""

import os

import numpy as np
import pytest

from warp_biscale import reference as ref
from warp_biscale import ssdf
from warp_biscale.scene import Mesh


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_dirs(n, seed):
    return _unit(np.random.default_rng(seed).normal(size=(n, 3)))


def _raw_field(mesh, backend, s):
    """(visible (V, S²) bool, θd (V, S²) float32) before compression."""
    vis = ssdf.vertex_visibility(mesh, backend, s)
    return vis, ssdf.distance_field(vis, backend, s)


def _eval_raw(theta_rows, s, dirs):
    """θd of each row (one vertex's raw SSDF) at its directions (P, K, 3), as the shader would (NV = 0)."""
    return np.stack([ref.ssdf_eval(row[None], np.zeros((1, 0)), s, d[None])[0] for row, d in zip(theta_rows, dirs)])


def _exact_visible(mesh, points, normals, dirs):
    """Exact visibility (float64 ray casting) of dirs (P, K, 3) from points (P, 3) with normals (P, 3):
    below the tangent plane is occluded, as in the SSDF."""
    p, k = dirs.shape[:2]
    eps = 1e-4 * mesh.scale
    o = np.repeat(points + eps * normals, k, axis=0)
    d = dirs.reshape(-1, 3)
    hit = ref.trace_occluded(mesh.vertices, mesh.faces, o, d, 1e-6 * mesh.scale, np.inf)
    above = np.einsum("pkc,pc->pk", dirs, normals) >= 0
    return above & ~hit.reshape(p, k)


def _ring(dirs, angle, count=8):
    """(..., count, 3) directions at `angle` around each of dirs (..., 3)."""
    helper = np.where(np.abs(dirs[..., :1]) < 0.9, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    t1 = _unit(np.cross(dirs, helper))
    t2 = np.cross(dirs, t1)
    phi = 2 * np.pi * np.arange(count) / count
    ring = (np.cos(angle) * dirs[..., None, :] + np.sin(angle) * (np.cos(phi)[:, None] * t1[..., None, :]
                                                                  + np.sin(phi)[:, None] * t2[..., None, :]))
    return _unit(ring)


def _away_from_boundary(mesh, points, normals, dirs, angle):
    """(exact visibility (P, K), mask (P, K) of samples whose ring at `angle` agrees with them)."""
    p, k = dirs.shape[:2]
    vis = _exact_visible(mesh, points, normals, dirs)
    ring = _ring(dirs, angle).reshape(p, k * 8, 3)
    ring_vis = _exact_visible(mesh, points, normals, ring).reshape(p, k, 8)
    return vis, (ring_vis == vis[..., None]).all(axis=2)


def _towards_sphere(points, seed, k=48, centre=(0.0, 0.7, 0.0), radius=0.5):
    """(P, k, 3) sample directions: a third uniform over the sphere of directions, two thirds in a cone
    1.5× the occluding sphere's angular radius around the direction to its centre (where the shadow is)."""
    rng = np.random.default_rng(seed)
    p = len(points)
    out = _random_dirs(p * k, seed).reshape(p, k, 3)
    to = np.asarray(centre) - points
    dist = np.linalg.norm(to, axis=1)
    axis = to / dist[:, None]
    half = 1.5 * np.arcsin(np.minimum(radius / dist, 1.0))
    m = 2 * k // 3
    cos_t = 1 - rng.random((p, m)) * (1 - np.cos(half))[:, None]  # uniform over the cone's solid angle
    ring = _ring(axis, 1.0, count=m)  # only its tangent plane matters: directions at angle 1 around axis
    tangent = _unit(ring - np.cos(1.0) * axis[:, None, :])
    phi = rng.random((p, m)) * 2 * np.pi
    t2 = np.cross(axis[:, None, :], tangent)
    sin_t = np.sqrt(1 - cos_t**2)
    out[:, :m] = _unit(cos_t[..., None] * axis[:, None, :] + sin_t[..., None] * (
        np.cos(phi)[..., None] * tangent + np.sin(phi)[..., None] * t2))
    return out


def sphere_over_plane(level=2, divisions=8):
    return Mesh.merge([Mesh.sphere(0.5, (0.0, 0.7, 0.0), subdivisions=level), Mesh.plane(4.0, 0.0, divisions)])


def box(lo=-1.0, hi=1.0):
    c = np.array([[x, y, z] for x in (lo, hi) for y in (lo, hi) for z in (lo, hi)], float)
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return Mesh(c, np.array(faces))


# ------------------------------------------------------------------------------ octahedral map
def test_octahedral_round_trip():
    d = np.concatenate([_random_dirs(20000, 0), np.eye(3), -np.eye(3),
                        _unit([[1, 1, 0], [1, -1, 0], [-1, 0, -1], [0, 1, -1], [1, 1, -1], [-1, -1, -1]])])
    uv = ssdf.octahedral_encode(d)
    assert uv.min() >= 0 and uv.max() <= 1
    np.testing.assert_allclose(ssdf.octahedral_decode(uv), d, atol=1e-12)
    # Inside the square (away from its mirrored border) encode inverts decode too.
    uv = np.random.default_rng(1).uniform(0.01, 0.99, size=(20000, 2))
    np.testing.assert_allclose(ssdf.octahedral_encode(ssdf.octahedral_decode(uv)), uv, atol=1e-12)
    # The fold: the upper hemisphere is the inner diamond, the lower the four corners.
    assert np.allclose(ssdf.octahedral_encode([0, 0, 1]), [0.5, 0.5])
    assert np.allclose(ssdf.octahedral_encode([0, 0, -1]), [1.0, 1.0])  # sgn(0) = +1: the (1, 1) corner


def test_grid_layout():
    s = 8
    g = ssdf.octahedral_grid(s)
    assert g.shape == (s * s, 3)
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1, atol=1e-15)
    i, j = 5, 2
    np.testing.assert_allclose(g[j * s + i], ssdf.octahedral_decode([(i + 0.5) / s, (j + 0.5) / s]))
    np.testing.assert_allclose(ssdf.octahedral_encode(g).reshape(s, s, 2)[j, i], [(i + 0.5) / s, (j + 0.5) / s])


@pytest.mark.parametrize("s", [8, 32])
def test_grid_covers_the_sphere(s):
    sa = ssdf.texel_solid_angles(s)
    assert (sa > 0).all()
    np.testing.assert_allclose(sa.sum(), 4 * np.pi, rtol=1e-9)
    # Converged per texel (cells halved: same to 1e-4), and the map's area distortion as measured.
    np.testing.assert_allclose(ssdf.texel_solid_angles(s, 16), sa, rtol=2e-4)
    assert 2.5 < sa.max() / sa.min() < 5.3  # octahedral map: up to 3√3 = 5.2 as S → ∞
    # Independent check: uniform random directions fall into texels in proportion to solid angle.
    n = 400000
    uv = ssdf.octahedral_encode(_random_dirs(n, 2))
    idx = np.minimum((uv[:, 1] * s).astype(int), s - 1) * s + np.minimum((uv[:, 0] * s).astype(int), s - 1)
    counts = np.bincount(idx, minlength=s * s)
    expected = n * sa / (4 * np.pi)
    assert (np.abs(counts - expected) <= 5 * np.sqrt(expected) + 1).all()


def test_grid_half_angles_and_blocks():
    g = ssdf.grid(16)
    d = g.directions
    cos = d @ d.T
    np.fill_diagonal(cos, -2)
    np.testing.assert_allclose(g.half_angle, 0.5 * np.arccos(cos.max(1)))
    # Every texel in exactly one block, inside its cone.
    members = g.block_members[g.block_members >= 0]
    np.testing.assert_array_equal(np.sort(members), np.arange(16 * 16))
    for row, axis, r in zip(g.block_members, g.block_axis, g.block_radius):
        ang = np.arccos(np.clip(d[row[row >= 0]] @ axis, -1, 1))
        assert ang.max() <= r - 0.9 * ssdf.BLOCK_MARGIN


# ------------------------------------------------------------------------------ distance transform
def _patterns(s, n_vertices, seed):
    """Visibility of random vertices: horizon, random caps and random holes (many small islands),
    plus an all-occluded row (enclosed vertex) and an all-visible one (±π)."""
    rng = np.random.default_rng(seed)
    g = ssdf.grid(s)
    n = _random_dirs(n_vertices, seed)
    caps = _random_dirs(n_vertices, seed + 1)
    vis = (n @ g.directions.T >= 0) & (np.einsum("vc,kc->vk", caps, g.directions) < rng.uniform(0.3, 0.95,
                                                                                                 (n_vertices, 1)))
    vis[: n_vertices // 3] &= rng.random((n_vertices // 3, s * s)) > 0.15
    vis[-1] = False
    vis[-2] = True
    return g, vis


@pytest.mark.parametrize("s, block", [(16, None), (32, None), (16, 1), (16, 16), (12, 5)])
def test_distance_matches_reference(backend, s, block):
    _, vis = _patterns(s, 24 if s <= 16 else 8, seed=s)
    g = ssdf.grid(s, block)
    theta = backend.ssdf_distance(g, vis)
    want = ref.ssdf_distance(vis, g.directions, g.half_angle)
    assert theta.dtype == np.float32 and theta.shape == vis.shape
    np.testing.assert_array_equal(theta > 0, vis)  # exact class
    np.testing.assert_allclose(theta, want, atol=1e-5, rtol=0)
    assert np.all(theta[-1] == np.float32(-np.pi)) and np.all(theta[-2] == np.float32(np.pi))
    # |θd| ≥ h_k wherever there is a boundary (the rule keeps the sign).
    assert (np.abs(theta[:-2]) >= g.half_angle.astype(np.float32) - 1e-6).all()


def test_distance_empty_and_bad_input(backend):
    g = ssdf.grid(8)
    assert backend.ssdf_distance(g, np.zeros((0, 64), bool)).shape == (0, 64)
    with pytest.raises(ValueError, match="columns"):
        backend.ssdf_distance(g, np.zeros((3, 60), bool))
    with pytest.raises(ValueError, match="S²"):
        ssdf.distance_field(np.zeros((3, 60), bool), backend)


# ------------------------------------------------------------------------------ meshes
def test_lone_sphere_is_the_horizon(backend):
    s = 16
    mesh = Mesh.sphere(1.0, subdivisions=2)
    field = ssdf.build(mesh, backend, resolution=s, terms=16)
    assert field.occluded is False
    vis, theta = _raw_field(mesh, backend, s)
    g = ssdf.grid(s)
    horizon = np.arcsin(np.clip(mesh.normals @ g.directions.T, -1, 1))
    np.testing.assert_array_equal(vis, horizon >= 0)
    texel = 2 * g.half_angle.max()
    err = np.abs(theta - horizon)
    assert err.max() <= texel, (err.max(), texel)
    # The compressed field is close to the raw one (rms measured over every vertex and texel).
    assert field.rms_error < 0.05
    np.testing.assert_allclose(np.sqrt(np.mean((field.vertex_ssdf() - theta) ** 2)), field.rms_error, rtol=1e-6)


def _eval_mirrored(theta_rows, s, dirs):
    """Like _eval_raw but with the octahedral edge mirroring the shader ignores: a bilinear tap one
    texel past the square's edge reads the texel that holds the same direction, (i, −1) ≡ (S−1−i, 0),
    (i, S) ≡ (S−1−i, S−1), (−1, j) ≡ (0, S−1−j), (S, j) ≡ (S−1, S−1−j) (rows folded first)."""
    uv = ssdf.octahedral_encode(dirs)
    x, y = uv[..., 0] * s - 0.5, uv[..., 1] * s - 0.5
    i0, j0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - i0, y - j0

    def tap(i, j):
        low, high = j < 0, j >= s
        i = np.where(low | high, s - 1 - i, i)
        j = np.where(low, 0, np.where(high, s - 1, j))
        low, high = i < 0, i >= s
        j = np.where(low | high, s - 1 - j, j)
        i = np.where(low, 0, np.where(high, s - 1, i))
        return np.take_along_axis(theta_rows, (j * s + i).reshape(len(theta_rows), -1), axis=1).reshape(i.shape)

    return ((1 - fx) * (1 - fy) * tap(i0, j0) + fx * (1 - fy) * tap(i0 + 1, j0)
            + (1 - fx) * fy * tap(i0, j0 + 1) + fx * fy * tap(i0 + 1, j0 + 1))


@pytest.mark.parametrize("s", [16, 32])
def test_border_band_lookup_error(backend, s):
    """The shader's bilinear lookup clamps at the square's border instead of following the octahedral
    map's edge mirroring. Measured on the raw SSDFs of a lone sphere's vertices (the horizon
    asin(ω·n) up to the grid rule) at random directions: in the half-texel band along the border
    (where clamping acts) the clamped and the mirrored lookups are compared with each other and
    with the horizon; elsewhere they are identical."""
    mesh = Mesh.sphere(1.0, subdivisions=1)
    _, theta = _raw_field(mesh, backend, s)
    theta = theta.astype(np.float64)
    dirs = _random_dirs(len(mesh.vertices) * 400, 5).reshape(len(mesh.vertices), 400, 3)
    clamped = _eval_raw(theta, s, dirs)
    mirrored = _eval_mirrored(theta, s, dirs)
    horizon = np.arcsin(np.clip(np.einsum("pkc,pc->pk", dirs, mesh.normals), -1, 1))
    uv = ssdf.octahedral_encode(dirs)
    band = ((uv < 0.5 / s) | (uv > 1 - 0.5 / s)).any(axis=-1)
    np.testing.assert_allclose(clamped[~band], mirrored[~band], atol=1e-12)
    texel = 2 * ssdf.grid(s).half_angle.max()
    e_in, e_clamp, e_mirror = np.abs(clamped - horizon)[~band], np.abs(clamped - horizon)[band], \
        np.abs(mirrored - horizon)[band]
    diff = np.abs(clamped - mirrored)[band]

    def rms(e):
        return np.sqrt(np.mean(e**2))

    measured = (f"lookup vs horizon, S={s} (texel angle {texel:.4f} rad): interior rms {rms(e_in):.4f} max "
                f"{e_in.max():.4f}; border band ({band.mean():.1%} of directions) clamped rms {rms(e_clamp):.4f} max "
                f"{e_clamp.max():.4f}, mirrored rms {rms(e_mirror):.4f} max {e_mirror.max():.4f}; clamped − mirrored "
                f"rms {rms(diff):.4f} max {diff.max():.4f} rad")
    assert e_in.max() <= texel and e_mirror.max() <= texel, measured
    assert e_clamp.max() <= 1.5 * texel, measured


def test_sphere_over_plane(backend):
    s = 32
    mesh = sphere_over_plane(level=2, divisions=8)
    n_sphere = 162
    vis, theta = _raw_field(mesh, backend, s)
    field = ssdf.build(mesh, backend, resolution=s, terms=16)
    assert field.occluded is True
    assert field.basis.shape == (17, s * s) and field.coeffs.shape == (len(mesh.vertices), 16)
    assert field.basis.dtype == np.float32 and field.coeffs.dtype == np.float32
    g = ssdf.grid(s)
    above = mesh.normals @ g.directions.T >= 0
    blocked = (above & ~vis).sum(1) / above.sum(1)  # fraction of the upper hemisphere's texels blocked
    plane = np.arange(n_sphere, len(mesh.vertices))
    p = mesh.vertices[plane]
    under = plane[(np.abs(p[:, 0]) <= 0.5) & (np.abs(p[:, 2]) <= 0.5)]
    centre = plane[np.argmin(np.linalg.norm(p, axis=1))]
    assert blocked[centre] > 0.2 and (blocked[under] > 0.1).all()  # the sphere subtends 30% of the centre's sky
    assert blocked[under].min() > blocked[plane].mean()

    # Sign vs exact ray-cast visibility at random directions, for the plane vertices near the sphere.
    near = plane[np.linalg.norm(p[:, [0, 2]], axis=1) <= 1.25]
    dirs = _towards_sphere(mesh.vertices[near], seed=3)
    exact, away = _away_from_boundary(mesh, mesh.vertices[near], mesh.normals[near], dirs, np.sqrt(4 * np.pi) / s)
    raw_sign = _eval_raw(theta[near], s, dirs) > 0
    pca_sign = field.eval(field.coeffs[near], dirs) > 0
    raw_ok = (raw_sign == exact)[away].mean()
    pca_ok = (pca_sign == exact)[away].mean()
    measured = (f"sphere over plane, S={s}: {away.mean():.1%} of {away.size} samples away from boundaries; sign "
                f"agreement raw {raw_ok:.2%}, PCA NV=16 {pca_ok:.2%}; occluded share {(~exact[away]).mean():.1%}; "
                "rms(NV) = " + ", ".join(f"{nv}: {field.rms_by_terms[nv]:.4f}" for nv in (1, 2, 4, 8, 16, 32, 48)))
    assert 0.1 < (~exact[away]).mean() < 0.9, measured  # not vacuous
    assert raw_ok >= 0.97, measured
    assert pca_ok >= 0.97, measured


def test_interpolated_coefficients_inside_triangles(backend):
    """What the shader does: coefficients blended with barycentrics at points inside plane triangles
    near the sphere, θd's sign against exact visibility from those points (same boundary rule)."""
    s = 32
    mesh = sphere_over_plane(level=2, divisions=8)
    field = ssdf.build(mesh, backend, resolution=s, terms=16)
    rng = np.random.default_rng(4)
    faces = mesh.faces[320:]  # icosphere level 2 has 320 faces; the plane's follow
    centre = mesh.vertices[faces].mean(1)
    faces = faces[np.linalg.norm(centre[:, [0, 2]], axis=1) <= 1.0]
    bary = rng.dirichlet([1, 1, 1], size=len(faces))
    points = np.einsum("fk,fkc->fc", bary, mesh.vertices[faces])
    normals = np.tile([0.0, 1.0, 0.0], (len(faces), 1))
    coeffs = np.einsum("fk,fkr->fr", bary, field.coeffs[faces].astype(np.float64))
    dirs = _towards_sphere(points, seed=6)
    exact, away = _away_from_boundary(mesh, points, normals, dirs, np.sqrt(4 * np.pi) / s)
    ok = ((field.eval(coeffs, dirs) > 0) == exact)[away].mean()
    assert ok >= 0.9, (f"interpolated inside {len(faces)} plane triangles: sign agreement {ok:.2%} "
                       f"of {away.sum()} samples")


def test_single_triangle(backend):
    mesh = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))
    field = ssdf.build(mesh, backend, resolution=8, terms=4)
    assert field.occluded is False
    assert field.coeffs.shape == (3, 4) and field.basis.shape == (5, 64)
    assert np.all(field.basis[3:] == 0)  # rank ≤ 2 (three identical rows: rank 0): padded with zeros
    g = ssdf.grid(8)
    horizon = np.arcsin(np.clip(mesh.normals @ g.directions.T, -1, 1))
    assert np.abs(field.vertex_ssdf() - horizon).max() <= 2 * g.half_angle.max()
    assert np.isfinite(field.basis).all() and field.rms_error < 1e-5


def test_enclosed_vertex_sees_nothing(backend):
    inner = Mesh(np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0.1]], float), np.array([[0, 1, 2]]))
    mesh = Mesh.merge([box(), inner])
    vis, theta = _raw_field(mesh, backend, 16)
    assert not vis[8:].any()
    assert np.all(theta[8:] == np.float32(-np.pi))
    field = ssdf.build(mesh, backend, resolution=16, terms=4)
    assert field.occluded is True
    np.testing.assert_allclose(field.vertex_ssdf()[8:], -np.pi, atol=10 * field.rms_error + 1e-5)


def test_degenerate_faces_change_nothing(backend):
    base = sphere_over_plane(level=1, divisions=4)
    v = base.vertices
    extra = np.array([[0, 0, 1], [5, 5, 6], [0, 1, 2]])  # two zero-area faces: repeated vertex, and ...
    line = np.array([[0.3, 0.2, 0.0], [0.6, 0.2, 0.0], [0.9, 0.2, 0.0]])  # ... three collinear points
    mesh = Mesh(np.concatenate([v, line]), np.concatenate([base.faces, extra[:2], [[len(v), len(v) + 1, len(v) + 2]]]),
                np.concatenate([base.normals, np.tile([0.0, 1.0, 0.0], (3, 1))]))
    _, t0 = _raw_field(base, backend, 16)
    _, t1 = _raw_field(mesh, backend, 16)
    np.testing.assert_array_equal(t1[: len(v)], t0)
    field = ssdf.build(mesh, backend, resolution=16, terms=8)
    assert np.isfinite(field.basis).all() and np.isfinite(field.coeffs).all()


# ------------------------------------------------------------------------------ PCA, eval, cache
def test_pca_exact_residuals_and_auto():
    rng = np.random.default_rng(7)
    theta = (rng.normal(size=(40, 5)) @ rng.normal(size=(5, 64)) + 0.01 * rng.normal(size=(40, 64))).astype(np.float32)
    for rows in (theta, np.tile(theta, (40, 1))):  # the Gram route (V ≤ N) and the covariance route
        mean, vec, coeffs, rms = ssdf.compress(rows, 8)
        np.testing.assert_allclose(vec @ vec.T, np.eye(8), atol=1e-10)
        for nv in (1, 3, 5, 8):
            recon = mean + coeffs[:, :nv] @ vec[:nv]
            np.testing.assert_allclose(np.sqrt(np.mean((recon - rows) ** 2)), rms[nv], rtol=1e-6)
        _, vec, _, _ = ssdf.compress(rows, "auto", tolerance=0.02)
        assert len(vec) == 5  # 5 true components; the noise is 0.01
    with pytest.raises(ValueError, match="terms"):
        ssdf.compress(theta, 0)
    with pytest.raises(ValueError, match="terms"):
        ssdf.compress(theta, "many")


def test_eval_reference_at_texel_centres():
    rng = np.random.default_rng(8)
    s, nv = 8, 3
    basis = rng.normal(size=(nv + 1, s * s))
    coeffs = rng.normal(size=(5, nv))
    g = ssdf.octahedral_grid(s)
    got = ref.ssdf_eval(basis, coeffs, s, np.broadcast_to(g, (5, s * s, 3)))
    np.testing.assert_allclose(got, basis[0] + coeffs @ basis[1:], atol=1e-12)
    # Half way between two texel centres along u: the average of the two.
    d = ssdf.octahedral_decode([[3.0 / s, 2.5 / s]])
    np.testing.assert_allclose(ref.ssdf_eval(basis[:1], np.zeros((1, 0)), s, d),
                               0.5 * (basis[0, 2 * s + 2] + basis[0, 2 * s + 3]))


def test_build_caches_and_validates(backend):
    """The in-memory cache and the checks (the disk's left out: test_build_keeps_ssdfs_on_disk_between_processes)."""
    mesh = sphere_over_plane(level=1, divisions=4)
    a = ssdf.build(mesh, backend, resolution=8, terms=4, disk_cache=False)
    assert set(a.timings) == {"trace", "distance", "pca", "total"}
    assert ssdf.build(mesh, backend, resolution=8, terms=4) is a
    b = ssdf.build(mesh, backend, resolution=8, terms="auto", disk_cache=False)
    assert b is not a and 1 <= b.terms <= ssdf.MAX_AUTO_TERMS
    assert b.rms_error < np.sqrt(4 * np.pi / 64) / 4 + 1e-6 or b.terms == min(ssdf.MAX_AUTO_TERMS, 64)
    # An unoccluded mesh with skip_unoccluded: rays only, placeholders; an occluded one: the full field.
    lone = Mesh.sphere(1.0, subdivisions=1)
    skipped = ssdf.build(lone, backend, resolution=8, terms=4, skip_unoccluded=True, disk_cache=False)
    assert skipped.occluded is False and skipped.coeffs.shape == (len(lone.vertices), 0)
    assert set(skipped.timings) == {"trace", "total"} and np.isnan(skipped.rms_error)
    assert ssdf.build(lone, backend, resolution=8, terms=4, disk_cache=False).coeffs.shape == (len(lone.vertices), 4)
    assert ssdf.build(mesh, backend, resolution=8, terms=4, skip_unoccluded=True) is a
    for bad in (1, 2.5, 129):
        with pytest.raises(ValueError, match="resolution"):
            ssdf.build(mesh, backend, resolution=bad)
    for bad in (0, 65, 1.5, None, "all"):
        with pytest.raises(ValueError, match="terms"):
            ssdf.build(mesh, backend, resolution=8, terms=bad)


def test_build_keeps_ssdfs_on_disk_between_processes(backend, tmp_path, monkeypatch):
    """ssdf.build keeps each SSDF in io.cache_folder()/ssdf: a mesh of the same geometry with nothing in memory (a new
    process's) reads it back, bit for bit and without tracing; another resolution, another geometry or disk_cache
    False builds; a damaged file is built again and replaced; an unoccluded mesh's placeholder is kept apart from its
    full field; at most DISK_CACHE_ENTRIES files stay, the most recently used."""
    monkeypatch.setenv("WARP_BISCALE_CACHE", str(tmp_path))
    mesh = sphere_over_plane(level=1, divisions=4)
    built = ssdf.build(mesh, backend, resolution=8, terms=4)
    assert "trace" in built.timings
    path = ssdf.disk_cache_path(mesh, backend.name, 8, 4, None, False)
    assert os.path.isfile(path) and os.listdir(tmp_path / "ssdf") == [os.path.basename(path)]
    again = sphere_over_plane(level=1, divisions=4)  # the same geometry, nothing in memory
    read = ssdf.build(again, backend, resolution=8, terms=4)
    assert set(read.timings) == {"disk", "total"}
    np.testing.assert_array_equal(read.basis, built.basis)
    np.testing.assert_array_equal(read.coeffs, built.coeffs)
    assert read.rms_error == built.rms_error and read.occluded == built.occluded
    assert ssdf.build(again, backend, resolution=8, terms=4) is read  # then kept in memory
    assert "trace" in ssdf.build(sphere_over_plane(level=1, divisions=4), backend, resolution=16, terms=4).timings
    moved = sphere_over_plane(level=1, divisions=4)
    moved.vertices = moved.vertices + np.array([0.0, 0.01, 0.0])
    assert "trace" in ssdf.build(moved, backend, resolution=8, terms=4).timings
    assert "trace" in ssdf.build(sphere_over_plane(level=1, divisions=4), backend, resolution=8, terms=4,
                                 disk_cache=False).timings
    with open(path, "wb") as fh:
        fh.write(b"PK not an archive")
    rebuilt = ssdf.build(sphere_over_plane(level=1, divisions=4), backend, resolution=8, terms=4)
    assert "trace" in rebuilt.timings
    np.testing.assert_array_equal(rebuilt.coeffs, built.coeffs)
    assert "disk" in ssdf.build(sphere_over_plane(level=1, divisions=4), backend, resolution=8, terms=4).timings
    # An unoccluded mesh's placeholder (skip_unoccluded) is kept under its own name: read back as a placeholder,
    # never handed to a caller that asks for the full field.
    lone = Mesh.sphere(1.0, subdivisions=1)
    assert ssdf.build(lone, backend, resolution=8, terms=4, skip_unoccluded=True).coeffs.shape[1] == 0
    placeholder = ssdf.build(Mesh.sphere(1.0, subdivisions=1), backend, resolution=8, terms=4, skip_unoccluded=True)
    assert set(placeholder.timings) == {"disk", "total"} and placeholder.occluded is False
    assert placeholder.coeffs.shape == (len(lone.vertices), 0) and np.isnan(placeholder.rms_error)
    full = ssdf.build(Mesh.sphere(1.0, subdivisions=1), backend, resolution=8, terms=4)
    assert "trace" in full.timings and full.coeffs.shape == (len(lone.vertices), 4)
    # The least recently used go first: the file just read stays.
    monkeypatch.setattr(ssdf, "DISK_CACHE_ENTRIES", 2)
    os.utime(path, (0, 0))  # the oldest of all ...
    assert "disk" in ssdf.build(sphere_over_plane(level=1, divisions=4), backend, resolution=8, terms=4).timings
    ssdf.build(sphere_over_plane(level=1, divisions=3), backend, resolution=8, terms=4)  # ... until read again
    assert len(os.listdir(tmp_path / "ssdf")) == 2 and os.path.isfile(path)


def test_ssdf_at_axes_is_ssdf_eval_at_each_point_and_axis():
    """The renderer's per-vertex θd towards its environment lobes (ssdf.ssdf_at_axes) equals ssdf_eval at every point
    and axis (float64: both are the same lookups, summed in another order), and a barycentric blend of three rows
    is ssdf_eval at the blended coefficients (θd is linear in them: what the shade kernels rely on)."""
    rng = np.random.default_rng(5)
    res, terms = 8, 5
    basis = rng.normal(size=(terms + 1, res * res))
    coeffs = rng.normal(size=(7, terms))
    axes = rng.normal(size=(4, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    axes[0] = (0.0, 0.0, -1.0)  # the fold and the map's border
    at_axes = ssdf.ssdf_at_axes(basis, coeffs, res, axes)
    assert at_axes.shape == (7, 4)
    expect = ssdf.ssdf_eval(basis, coeffs, res, np.broadcast_to(axes, (7, 4, 3)))
    np.testing.assert_allclose(at_axes, expect, rtol=1e-12, atol=1e-12)
    w = np.array([0.2, 0.5, 0.3])
    blended = ssdf.ssdf_eval(basis, np.tile(w @ coeffs[:3], (4, 1)), res, axes)  # (one point per axis)
    np.testing.assert_allclose(w @ at_axes[:3], blended, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="coeffs has 4 terms"):
        ssdf.ssdf_at_axes(basis, coeffs[:, :4], res, axes)
