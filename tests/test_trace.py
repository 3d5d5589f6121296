"""Ray casting against the large-scale mesh (stage `trace`), on every backend present, against the
float64 brute-force reference (`reference.trace_closest`, `trace_occluded`, `trace_shadows`,
`trace_occlusion`).

Tolerances, and why:
- The kernels trace float32 rays against float32 vertices; the reference traces float64 camera
  rays (`Camera.rays`) against float64 vertices. Rounding a vertex moves a triangle's plane by
  δ ≈ 1e-7 × scale, which moves the hit along a ray meeting the plane at cos θ by δ / cos θ. So t
  and position are held to 1e-5 × scale where cos θ ≥ 0.1 and to 1e-6 × scale / cos θ everywhere
  (measured: at most 1e-7 × scale / cos θ). The position is a barycentric combination of the
  vertices, so its distance from the hit face's plane is held to 1e-6 × scale at any angle.
- Face ids: a ray within rounding of an edge can hit either neighbour, or miss past a silhouette.
  A mismatch is *explained* when the float64 ray also meets the other result's face inside a
  margin of BARY_TOL in barycentric units at a t within 1e-5 relative of the reference t (or, for
  a hit/miss disagreement, passes within BARY_TOL of the hit face's edge). Unexplained mismatches:
  none allowed; explained ones: at most 0.5 % of the pixels (measured: 0 on this scene).
- Any-hit, shadow and occlusion rays: the reference is evaluated with triangles grown and shrunk by BARY_TOL
  (`tol` = ±BARY_TOL); where the two agree a ray is unambiguous and the kernels must agree with
  it exactly; the ambiguous rays (grazing an edge within rounding) may go either way, and must be
  fewer than 1 %. BARY_TOL = 1e-3 is large next to float32 rounding of the barycentrics (~1e-4 at
  the most grazing hits here) and small enough that ambiguity stays rare.
"""

import dataclasses
import functools

import numpy as np
import pytest

import warp_biscale.trace as trace_module
from warp_biscale import reference as ref
from warp_biscale.model import GBuffer
from warp_biscale.scene import Camera, DirectionalLight, Mesh, PointLight
from warp_biscale.trace import SHADOW_OFFSET, T_MIN, offsets

BARY_TOL = 1e-3


def showcase_mesh(offset=(0.0, 0.0, 0.0)):
    """A sphere in a torus on a floor (~1500 triangles), plus a zero-area triangle (collinear
    vertices) that no ray may hit and that must not produce NaN."""
    sliver = Mesh(np.array([[-1.5, 1.0, -1.5], [-1.0, 1.0, -1.0], [-0.5, 1.0, -0.5]]), np.array([[0, 1, 2]]))
    parts = [Mesh.sphere(0.5, (0, 0.5, 0), subdivisions=2), Mesh.torus(1.0, 0.25, (0, 0.25, 0), segments=(32, 16)),
             Mesh.plane(4.0, 0.0, 8), sliver]
    m = Mesh.merge(parts)
    return Mesh(m.vertices + np.asarray(offset, float), m.faces, m.normals)


def showcase_camera(offset=(0.0, 0.0, 0.0), width=80, height=60):
    o = np.asarray(offset, float)
    # Looking down at the floor from above its edge, with sky above the horizon (misses).
    return Camera(eye=o + (2.5, 1.6, 3.0), target=o + (0, 0.3, 0), fov=50, width=width, height=height)


@pytest.fixture(scope="module", params=[(0.0, 0.0, 0.0), (100.0, -50.0, 20.0)], ids=["origin", "offset"])
def showcase(request):
    mesh, cam = showcase_mesh(request.param), showcase_camera(request.param)
    return mesh, cam, ref.trace_primary(mesh, cam)


def _cos_incidence(mesh, face, d):
    return np.abs(np.sum(mesh.face_normals[np.maximum(face, 0)] * d, axis=1))


def _explained(mesh, face, o, d, t_ref):
    """Where the float64 ray meets `face` inside BARY_TOL at a t within 1e-5 relative of t_ref."""
    u, v, t = ref.intersect_faces(mesh.vertices, mesh.faces, np.maximum(face, 0), o, d)
    with np.errstate(invalid="ignore"):
        inside = (u >= -BARY_TOL) & (v >= -BARY_TOL) & (u + v <= 1 + BARY_TOL)
        return (face >= 0) & inside & (np.abs(t - t_ref) <= 1e-5 * np.abs(t_ref))


def _near_edge(u, v):
    return np.minimum(np.minimum(u, v), 1 - u - v) <= BARY_TOL


def _face_mismatches(mesh, cam, g, r):
    """(unexplained, differ) masks over the pixels of kernel G-buffer g vs reference r (module notes)."""
    o, d = cam.rays()
    hit_ref, hit = r["face"] >= 0, g.face >= 0
    differ = g.face != r["face"]
    # Both hit, different faces: the kernel's face must be a near-tie of the reference hit.
    ok_both = _explained(mesh, g.face, o, d, r["t"])
    # Reference hits, kernel misses: the reference hit grazes an edge (a silhouette).
    ok_lost = _near_edge(r["bary"][:, 0], r["bary"][:, 1])
    # Kernel hits, reference misses: the kernel's face is hit by the float64 ray inside the margin.
    u, v, t = ref.intersect_faces(mesh.vertices, mesh.faces, np.maximum(g.face, 0), o, d)
    with np.errstate(invalid="ignore"):
        ok_gained = (u >= -BARY_TOL) & (v >= -BARY_TOL) & (u + v <= 1 + BARY_TOL) & (t > 0)
    unexplained = differ & np.where(hit & hit_ref, ~ok_both, np.where(hit_ref, ~ok_lost, ~ok_gained))
    return unexplained, differ


def test_primary_matches_reference(backend, showcase):
    mesh, cam, r = showcase
    g = backend.trace_primary(mesh, cam)
    n = cam.width * cam.height
    assert g.face.dtype == np.int32 and g.face.shape == (n,)
    assert g.bary.dtype == np.float32 and g.bary.shape == (n, 2)
    assert g.position.dtype == np.float32 and g.position.shape == (n, 3)
    assert g.t.dtype == np.float32 and g.t.shape == (n,)
    np.testing.assert_allclose(g.eye, cam.eye, rtol=1e-7)
    hit_ref, hit = r["face"] >= 0, g.face >= 0
    assert 0.3 * n < hit_ref.sum() < n  # the scene fills part of the frame, sky the rest

    o, d = cam.rays()
    unexplained, differ = _face_mismatches(mesh, cam, g, r)
    assert not unexplained.any(), f"{unexplained.sum()} unexplained face mismatches of {n} pixels"
    assert differ.sum() <= 0.005 * n, f"{differ.sum()} face mismatches of {n} pixels"

    same = ~differ & hit
    scale = mesh.scale
    cos = _cos_incidence(mesh, r["face"], d)[same]
    err_t = np.abs(g.t[same].astype(np.float64) - r["t"][same])
    err_x = np.linalg.norm(g.position[same] - r["position"][same], axis=1)
    for err in (err_t, err_x):
        assert (err[cos >= 0.1] <= 1e-5 * scale).all(), err[cos >= 0.1].max() / scale
        assert (err * cos <= 1e-6 * scale).all(), (err * cos).max() / scale
    # The position is on its face (the barycentric combination), at any angle.
    tri = mesh.vertices[mesh.faces[g.face[hit]]]
    off_plane = np.abs(np.sum((g.position[hit] - tri[:, 0]) * mesh.face_normals[g.face[hit]], axis=1))
    assert off_plane.max() <= 1e-6 * scale
    bu, bv = g.bary[hit, 0], g.bary[hit, 1]
    assert (bu >= -1e-6).all() and (bv >= -1e-6).all() and (bu + bv <= 1 + 1e-6).all()
    pos = ((1 - bu - bv)[:, None] * tri[:, 0] + bu[:, None] * tri[:, 1] + bv[:, None] * tri[:, 2])
    np.testing.assert_allclose(g.position[hit], pos, atol=1e-6 * scale)
    # Misses: face −1, t inf, zeros; never NaN anywhere.
    assert np.isinf(g.t[~hit]).all() and (g.t[hit] > 0).all()
    assert not g.bary[~hit].any() and not g.position[~hit].any()
    assert np.isfinite(g.bary).all() and np.isfinite(g.position).all()
    assert not (g.face == len(mesh.faces) - 1).any()  # the zero-area triangle


def test_primary_all_miss(backend):
    mesh = showcase_mesh()
    cam = Camera(eye=(0, 1, 5), target=(0, 1, 10), fov=60, width=32, height=24)  # looking away
    g = backend.trace_primary(mesh, cam)
    assert (g.face == -1).all() and np.isinf(g.t).all()
    assert not g.position.any() and not g.bary.any()
    assert (ref.trace_primary(mesh, cam)["face"] == -1).all()


def test_primary_non_square_and_pixel_order(backend):
    """Row-major from the top-left, y down: a floor seen from above fills the lower rows only."""
    mesh = Mesh.plane(4.0, 0.0, 4)
    cam = Camera(eye=(0, 1, 3), target=(0, 1, 0), fov=60, width=40, height=16)  # horizon across the middle
    g = backend.trace_primary(mesh, cam)
    hit = (g.face >= 0).reshape(16, 40)
    assert not hit[:8].any() and hit[8:].any()
    # Pixel centres of this symmetric view land exactly on the floor's grid lines: ties, explained.
    unexplained, _ = _face_mismatches(mesh, cam, g, ref.trace_primary(mesh, cam))
    assert not unexplained.any()


def test_device_cache(backend):
    mesh, cam = showcase_mesh(), showcase_camera(width=40, height=30)
    assert backend.trace_primary(mesh, cam, to_host=False) is None
    entry = mesh.device_cache[backend.name]
    for key in ("points", "faces", "normals", "face_normals", "gbuffer_face", "gbuffer_bary", "gbuffer_position",
                "gbuffer_t", "gbuffer_eye"):
        assert key in entry, key
    points = entry["points"]
    g = backend.trace_primary(mesh, cam)
    assert mesh.device_cache[backend.name]["points"] is points  # not re-uploaded for a second frame
    lights = np.stack([PointLight((1, 3, 1)).packed()])
    # The device G-buffer (gbuffer=None) and the host one give the same shadows.
    assert backend.trace_shadows(mesh, None, lights, to_host=False) is None
    assert "gbuffer_light_vis" in mesh.device_cache[backend.name]
    np.testing.assert_array_equal(backend.trace_shadows(mesh, None, lights), backend.trace_shadows(mesh, g, lights))
    # Replaced geometry is re-uploaded: the scene moved down by 0.5 is traced where it now is.
    mesh.vertices = mesh.vertices - [0.0, 0.5, 0.0]
    g2 = backend.trace_primary(mesh, cam)
    assert mesh.device_cache[backend.name]["points"] is not points
    assert (g2.face == ref.trace_primary(mesh, cam)["face"]).mean() > 0.99
    np.testing.assert_allclose(g2.position[g2.face >= 0, 1].min(), -0.5, atol=1e-5)


def _random_rays(mesh, n, seed):
    """Random rays through the scene's box, a third with t_max = inf."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    o = rng.uniform(lo - 0.3, hi + 0.3, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_max = rng.uniform(0.0, 1.5 * np.ptp(mesh.vertices, axis=0).max(), n)
    t_max[::3] = np.inf
    return o, d, t_max


def _grazing_rays(mesh, n, seed):
    """Nearly horizontal rays just above the floor (y = 0): parallel to a big flat part, and some
    dipping into it far away."""
    rng = np.random.default_rng(seed)
    eps = SHADOW_OFFSET * mesh.scale
    o = np.stack([rng.uniform(-2, 2, n), np.full(n, eps), rng.uniform(-2, 2, n)], 1)
    phi = rng.uniform(0, 2 * np.pi, n)
    dip = rng.choice([0.0, 1e-4, -1e-4, -1e-2], n)
    d = np.stack([np.cos(phi), dip, np.sin(phi)], 1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d, np.full(n, np.inf)


def _surface_rays(mesh, n, seed):
    """Rays leaving random surface points, moved off the surface by the caller's offset along the
    face normal on the side of the ray (as shadow and SSDF rays are): concave spots (torus inside,
    floor beside the torus) are hit, convex ones are not."""
    rng = np.random.default_rng(seed)
    real = np.flatnonzero(np.linalg.norm(mesh.face_normals, axis=1) > 0)
    f = rng.choice(real, n)
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    tri = mesh.vertices[mesh.faces[f]]
    x = tri[:, 0] + a[:, None] * (tri[:, 1] - tri[:, 0]) + b[:, None] * (tri[:, 2] - tri[:, 0])
    nrm = mesh.face_normals[f]
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    side = np.sign(np.sum(d * nrm, axis=1))[:, None]
    o = x + SHADOW_OFFSET * mesh.scale * side * nrm
    return o, d, np.full(n, np.inf)


def _check_occluded(mesh, got, o, d, t_max, what):
    t_min = T_MIN * mesh.scale
    grown = ref.trace_occluded(mesh.vertices, mesh.faces, o, d, t_min, t_max, tol=BARY_TOL)
    shrunk = ref.trace_occluded(mesh.vertices, mesh.faces, o, d, t_min, t_max, tol=-BARY_TOL)
    exact = ref.trace_occluded(mesh.vertices, mesh.faces, o, d, t_min, t_max)
    clear = grown == shrunk
    assert got.dtype == bool and got.shape == (len(o),)
    bad = clear & (got != exact)
    assert not bad.any(), f"{what}: {bad.sum()} of {clear.sum()} unambiguous rays disagree"
    assert (~clear).sum() <= 0.01 * len(o), f"{what}: {(~clear).sum()} ambiguous rays"
    return exact


@pytest.fixture(scope="module")
def mesh():
    return showcase_mesh()


@pytest.mark.parametrize("kind", ["random", "grazing", "surface"])
def test_occluded_matches_reference(backend, mesh, kind):
    o, d, t_max = {"random": _random_rays, "grazing": _grazing_rays, "surface": _surface_rays}[kind](mesh, 3000, 5)
    got = backend.trace_occluded(mesh, o, d, t_max)
    exact = _check_occluded(mesh, got, o, d, t_max, f"{backend.name} {kind}")
    assert 0.05 < exact.mean() < 0.95  # both outcomes are exercised


def test_occluded_limits(backend, mesh):
    # Straight down onto the floor from y = 1, beside the torus and off every edge of the floor's grid.
    o = np.array([[1.8, 1.0, 1.65]] * 4)
    d = np.array([[0.0, -1.0, 0.0]] * 4)
    # The floor is at t = 1: (t_min, t_max] includes it for t_max >= 1 only.
    got = backend.trace_occluded(mesh, o, d, np.array([0.999, 1.001, np.inf, 0.0]))
    np.testing.assert_array_equal(got, [False, True, True, False])
    # A scalar t_max applies to every ray; an empty batch is fine.
    np.testing.assert_array_equal(backend.trace_occluded(mesh, o, d, np.inf), [True] * 4)
    assert backend.trace_occluded(mesh, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)).shape == (0,)
    # Upwards from the same point: nothing above.
    assert not backend.trace_occluded(mesh, o, -d, np.inf).any()


def test_occluded_chunks(backend, mesh, monkeypatch):
    """Any number of rays: a batch is cut into launches of CHUNK_RAYS (made small here)."""
    o, d, t_max = _random_rays(mesh, 2500, 9)
    whole = backend.trace_occluded(mesh, o, d, t_max)
    monkeypatch.setattr(trace_module, "CHUNK_RAYS", 1000)
    np.testing.assert_array_equal(backend.trace_occluded(mesh, o, d, t_max), whole)


def test_occluded_million_rays(backend):
    """2^20 rays in one call (SSDF-sized), a sample of them checked against the reference."""
    m = Mesh.merge([Mesh.sphere(0.5, (0, 0.5, 0), subdivisions=1), Mesh.plane(4.0, 0.0, 2)])
    o, d, t_max = _random_rays(m, 1 << 20, 3)
    got = backend.trace_occluded(m, o, d, t_max)
    pick = np.random.default_rng(0).choice(len(o), 4000, replace=False)
    _check_occluded(m, got[pick], o[pick], d[pick], t_max[pick], f"{backend.name} 2^20")
    assert 0.05 < got.mean() < 0.95


def _shadow_scene():
    """A sphere hovering over a floor, seen from above; a point light and a directional light above
    it (each casts a shadow on the floor), and a light from below (below every seen horizon)."""
    mesh = Mesh.merge([Mesh.sphere(0.5, (0, 0.8, 0), subdivisions=3), Mesh.plane(4.0, 0.0, 16)])
    cam = Camera(eye=(0.0, 3.5, 3.0), target=(0, 0.2, 0), fov=55, width=72, height=56)
    lights = np.stack([PointLight((0.3, 3.0, 0.2)).packed(), DirectionalLight((-0.5, 1.0, 0.3)).packed(),
                       DirectionalLight((0.1, -1.0, 0.2)).packed()])
    return mesh, cam, lights


def test_shadows_match_reference(backend):
    mesh, cam, lights = _shadow_scene()
    g = backend.trace_primary(mesh, cam)
    vis = backend.trace_shadows(mesh, g, lights)
    n = len(g.face)
    assert vis.dtype == np.uint8 and vis.shape == (n, 3) and set(np.unique(vis)) <= {0, 255}
    eps, t_min = offsets(mesh)
    args = (mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, lights, eps, t_min)
    exact = ref.trace_shadows(*args)
    clear = ref.trace_shadows(*args, tol=BARY_TOL) == ref.trace_shadows(*args, tol=-BARY_TOL)
    bad = clear & (vis != exact)
    assert not bad.any(), f"{bad.sum()} unambiguous shadow rays disagree"
    assert (~clear).sum() <= 0.01 * vis.size
    # The sphere shadows the floor: floor pixels facing the light but occluded, for both lights above.
    floor = g.face >= len(Mesh.sphere(0.5, subdivisions=3).faces)
    for k in (0, 1):
        dark = floor & (vis[:, k] == 0)
        assert dark.sum() > 20, f"light {k}: no shadow on the floor"
        assert (floor & (vis[:, k] == 255)).sum() > dark.sum()  # most of the floor is lit
    # Misses see no light; a light from below is below the horizon of everything seen from above.
    assert not vis[g.face < 0].any()
    assert not vis[floor, 2].any()
    # The same from the reference G-buffer: lit fractions agree closely.
    r = ref.trace_primary(mesh, cam)
    lit_ref = ref.trace_shadows(mesh.vertices, mesh.normals, mesh.faces, r["face"], r["bary"], r["position"], r["eye"],
                                lights, eps, t_min)
    np.testing.assert_allclose(vis.mean(0) / 255, lit_ref.mean(0) / 255, atol=0.005)


def test_soft_shadows_match_reference(backend):
    """16 rays per light over its disc (large lights, so the floor has wide penumbrae): the visible share
    in 255ths against the float64 reference's same rays. A ray within rounding of an edge may go either
    way, so an entry may differ by a step or two (255/16 each) at a few pixels; the means agree closely."""
    mesh, cam, _ = _shadow_scene()
    lights = np.stack([PointLight((0.3, 3.0, 0.2), radius=0.4).packed(),
                       DirectionalLight((-0.5, 1.0, 0.3), angular_radius=8.0).packed()])
    g = backend.trace_primary(mesh, cam)
    vis = backend.trace_shadows(mesh, g, lights, samples=16).astype(np.int64)
    eps, t_min = offsets(mesh)
    exact = ref.trace_shadows(mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, lights,
                              eps, t_min, samples=16).astype(np.int64)
    step = 255 / 16
    assert (np.abs(vis - exact) > 2 * step).sum() == 0
    assert (vis != exact).mean() < 0.02
    np.testing.assert_allclose(vis.mean(0), exact.mean(0), atol=0.5)
    floor = g.face >= len(Mesh.sphere(0.5, subdivisions=3).faces)
    for k in range(2):  # a penumbra: floor pixels partly lit
        assert ((vis[floor, k] > 0) & (vis[floor, k] < 255)).sum() > 30
    # One sample is the hard shadow, ray for ray.
    np.testing.assert_array_equal(backend.trace_shadows(mesh, g, lights, samples=1),
                                  backend.trace_shadows(mesh, g, lights))


@pytest.mark.parametrize("bad", [0, 1025, 2.5, "8"])
def test_bad_shadow_samples_are_one_line(backend, bad):
    mesh, cam, lights = _shadow_scene()
    g = backend.trace_primary(mesh, cam)
    with pytest.raises(ValueError, match="shadow samples must be an integer"):
        backend.trace_shadows(mesh, g, lights, samples=bad)


@pytest.fixture(scope="module")
def occlusion_reference():
    """The shadow scene's float64 G-buffer, every second hit pixel of it (a GBuffer by hand: its own pixel
    indices), and the reference's 16-ray masks there: exact, and with triangles grown and shrunk by
    BARY_TOL. Made once for every backend."""
    mesh, cam, _ = _shadow_scene()
    r = ref.trace_primary(mesh, cam)
    pick = np.flatnonzero(r["face"] >= 0)[::2]
    g = GBuffer(face=r["face"][pick].astype(np.int32), bary=r["bary"][pick], position=r["position"][pick],
                eye=r["eye"])
    eps, t_min = offsets(mesh)
    args = (mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, eps, t_min, 16)
    masks = [ref.trace_occlusion(*args, tol=tol) for tol in (0.0, BARY_TOL, -BARY_TOL)]
    return mesh, g, masks


def _bits(mask, samples=16):
    return ((np.asarray(mask)[:, None].astype(np.uint64) >> np.arange(samples, dtype=np.uint64))
            & np.uint64(1)).astype(bool)


def test_occlusion_matches_reference(backend, occlusion_reference):
    """16 environment-occlusion rays a pixel (unbounded, cosine-distributed about the oriented geometric
    normal) against the float64 reference's same rays from the same points, bit for bit where a ray is
    unambiguous; ambiguous rays (grazing an edge within rounding) fewer than 1 %. Floor pixels by the
    sphere are partly blocked and the far floor's rays escape."""
    mesh, g, (exact, grown, shrunk) = occlusion_reference
    mask = backend.trace_occlusion(mesh, g, 16)
    assert mask.dtype == np.uint32 and mask.shape == g.face.shape
    clear = _bits(grown) == _bits(shrunk)
    got = _bits(mask)
    bad = clear & (got != _bits(exact))
    assert not bad.any(), f"{bad.sum()} clear rays disagree"
    assert (~clear).mean() < 0.01
    floor = g.face >= len(Mesh.sphere(0.5, subdivisions=3).faces)
    blocked = got.sum(1)
    assert ((blocked > 0) & (blocked < 16) & floor).sum() > 15  # partly occluded floor by the sphere
    assert (floor & (blocked == 0)).sum() > floor.sum() / 3  # the far floor sees the whole sky
    assert not backend.trace_occlusion(mesh, g, 0).any()  # no rays, no bits


LOBES = np.array([[0.6, 0.64, 0.48, 40.0], [-0.48, 0.8, 0.36, 400.0]], np.float32)  # a wide and a narrow sun


def test_lobe_rays_match_reference(backend, occlusion_reference):
    """8 rays over each of two sharp lobes' caps against the float64 reference's same rays, bit for bit where
    a ray is unambiguous; the sphere's shadow on the floor blocks some, not all; a lobe from below is behind
    the floor seen from above (nothing traced, no bits)."""
    mesh, g, _ = occlusion_reference
    eps, t_min = offsets(mesh)
    args = (mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, eps, t_min, LOBES)
    exact, grown, shrunk = (_bits(ref.trace_lobe_rays(*args, tol=tol), 32) for tol in (0.0, BARY_TOL, -BARY_TOL))
    got = _bits(backend.trace_lobe_rays(mesh, g, LOBES), 32)
    clear = grown == shrunk
    assert not (clear & (got != exact)).any(), f"{(clear & (got != exact)).sum()} clear rays disagree"
    assert (~clear).mean() < 0.01
    assert not got[:, 16:].any()  # bits past two lobes' 16
    floor = g.face >= len(Mesh.sphere(0.5, subdivisions=3).faces)
    for k in range(2):
        blocked = got[floor, 8 * k:8 * (k + 1)].sum(1)
        assert (blocked > 0).sum() > 10 and (blocked == 0).sum() > floor.sum() / 2, k  # a shadow on the floor
    below = LOBES.copy()
    below[:, 1] *= -1
    assert not backend.trace_lobe_rays(mesh, g, below)[floor].any()
    with pytest.raises(ValueError, match="lobes: at most"):
        backend.trace_lobe_rays(mesh, g, np.tile(LOBES, (3, 1)))


def test_occlusion_from_the_device_gbuffer(backend):
    """The render path: the masks of the G-buffer trace_primary left on the device equal those of its host
    copy; a miss has no bits."""
    mesh, cam, _ = _shadow_scene()
    g = backend.trace_primary(mesh, cam)
    host = backend.trace_occlusion(mesh, g, 8)
    backend.trace_occlusion(mesh, None, 8, to_host=False)
    np.testing.assert_array_equal(backend.trace_occlusion(mesh, None, 8), host)
    assert host[g.face >= 0].any() and not host[g.face < 0].any()


def test_ray_part_covers_each_set_once():
    """The parts of n anti-aliasing samples cover every ray of a set exactly once where n ≤ the set, and every
    sample gets one ray, in turn, past it; the kernels' (first, stride) are these."""
    for samples in (1, 8, 16):
        for count in (1, 2, 3, 4, 16, 40):
            cast = np.array([trace_module.part_rays(samples, (k, count)) for k in range(count)])
            assert cast.any(1).all()  # no sample traces nothing
            if count <= samples:
                np.testing.assert_array_equal(cast.sum(0), 1)
            else:
                assert cast.sum(1).max() == 1 and cast.any(0).all()
    assert trace_module.ray_part(16, (0, 1)) == (0, 1)


@pytest.mark.parametrize("part", [(1, 4), (2, 3)])
def test_a_part_of_each_ray_set_matches_reference(backend, occlusion_reference, part):
    """An anti-aliasing sample's part of the occlusion, lobe and shadow rays against the float64 reference's
    same part (bit for bit where a ray is unambiguous; the shadow shares to a step of the part's own rays);
    bits outside the part stay clear, and the parts of all samples together make the whole set's masks."""
    mesh, g, (exact, grown, shrunk) = occlusion_reference
    eps, t_min = offsets(mesh)
    args = (mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, eps, t_min)
    index, count = part
    union = np.zeros(len(g.face), np.uint32)
    for k in range(count):
        got = backend.trace_occlusion(mesh, g, 16, part=(k, count))
        assert not (_bits(got) & ~trace_module.part_rays(16, (k, count))[None]).any()
        want = [ref.trace_occlusion(*args, 16, tol=tol, part=(k, count)) for tol in (0.0, BARY_TOL, -BARY_TOL)]
        clear = _bits(want[1]) == _bits(want[2])
        assert not (clear & (_bits(got) != _bits(want[0]))).any()
        union |= got
    clear = _bits(grown) == _bits(shrunk)
    assert not (clear & (_bits(union) != _bits(exact))).any()
    lobes = [ref.trace_lobe_rays(*args, LOBES, tol=tol, part=part) for tol in (0.0, BARY_TOL, -BARY_TOL)]
    got = _bits(backend.trace_lobe_rays(mesh, g, LOBES, part=part), 32)
    clear = _bits(lobes[1], 32) == _bits(lobes[2], 32)
    assert not (clear & (got != _bits(lobes[0], 32))).any()
    assert not (got[:, :16] & ~np.tile(trace_module.part_rays(8, part), 2)[None]).any()
    lights = np.stack([PointLight((0.3, 3.0, 0.2), radius=0.4).packed(),
                       DirectionalLight((-0.5, 1.0, 0.3), angular_radius=8.0).packed()])
    vis = backend.trace_shadows(mesh, g, lights, samples=16, part=part).astype(np.int64)
    want = ref.trace_shadows(mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, lights,
                             eps, t_min, samples=16, part=part).astype(np.int64)
    step = 255 / trace_module.part_rays(16, part).sum()
    assert (np.abs(vis - want) > step + 1).sum() == 0 and (vis != want).mean() < 0.02


@pytest.fixture(scope="module")
def block_frame():
    """The shadow scene's whole float64 G-buffer (a GBuffer by hand, rows of the camera's width), and for each block
    side (2, 4) the float64 lenders of each pixel's block (trace.share_block) and the pixels whose lenders stay the
    same with both bounds moved by 1e-4 either way (the kernels decide them in float32)."""
    mesh, cam, lights = _shadow_scene()
    r = ref.trace_primary(mesh, cam)
    g = GBuffer(face=r["face"].astype(np.int32), bary=r["bary"], position=r["position"], eye=r["eye"])
    normals = trace_module._unit_face_normals(mesh.vertices[mesh.faces])
    args = (g.face, g.position, normals, g.eye, cam.width)
    sides = {}
    for side in (2, 4):
        lenders = trace_module.share_block(*args, side=side)
        moved = [trace_module.share_block(*args, side=side, normal_cos=trace_module.SHARE_NORMAL_COS + s * 1e-4,
                                          plane=trace_module.SHARE_PLANE - s * 1e-4) for s in (1, -1)]
        sides[side] = lenders, (moved[0] == moved[1]).all(1)
    return mesh, cam, lights, g, sides


def test_block_lenders_nest():
    """A pixel's 2×2 block lies inside its 4×4 block, and a pixel lends to another by their hits alone: the 2×2
    lenders taken from the 4×4 ones (trace.block_sub_lenders) are share_block's own for side 2, on an odd-sized
    frame whose last blocks are cut by its edges."""
    mesh, _, _ = _shadow_scene()
    cam = Camera(eye=(0.0, 2.0, 3.0), target=(0.0, 0.3, 0.0), width=45, height=31)
    r = ref.trace_primary(mesh, cam)
    normals = trace_module._unit_face_normals(mesh.vertices[mesh.faces])
    args = (r["face"], r["position"], normals, r["eye"], cam.width)
    two = trace_module.share_block(*args, side=2)
    four = trace_module.share_block(*args, side=4)
    assert four.shape == (45 * 31, 16) and 0 < (~four[r["face"] >= 0]).sum()
    np.testing.assert_array_equal(trace_module.block_sub_lenders(four, cam.width, 2), two)
    assert trace_module.block_side(16, (0, 1, 45, 4)) == 4 and trace_module.block_side(15, (0, 1, 45, 4)) == 2
    assert trace_module.block_side(16, (0, 2, 45, 4)) == 2 and trace_module.block_side(32, (1, 2, 45, 4)) == 4
    assert trace_module.block_side(3, (0, 1, 45, 4)) == 1 and trace_module.block_side(16, (0, 1, 0, 4)) == 1
    with pytest.raises(ValueError, match="block side"):
        trace_module.check_ray_part((0, 1, 45, 3))


def _lent_rays(samples, part, lenders, width):
    """(P,) the rays of a set of `samples` that each pixel's lenders traced in all (reference.share_block_shadows'
    denominator; at least 1), `lenders` those of the part's side."""
    side = trace_module.block_side(samples, part)
    p = np.arange(len(lenders))
    if side == 1:
        return np.maximum(trace_module.part_rays(samples, part, p).sum(1), 1)
    lent = trace_module.block_sub_lenders(lenders, width, side)
    total = np.zeros(len(p), np.int64)
    for q in range(side * side):
        b = np.where(lent[:, q], trace_module.block_pixel(p, width, q, side), p)
        total += np.where(lent[:, q], trace_module.part_rays(samples, part, b).sum(1), 0)
    return np.maximum(total, 1)


@pytest.mark.parametrize("side", [2, 4])
@pytest.mark.parametrize("part", [(0, 1), (1, 4)])
def test_rays_shared_in_blocks_match_reference(backend, block_frame, part, side):
    """A part with the frame's width as its block width: each pixel traces its slot's share of each set of four
    or more rays (trace.pixel_parts: a quarter in 2×2 blocks, a sixteenth in 4×4 ones where the set holds 16 rays a
    pixel and sample, else 2×2) and takes the rays of its block's lenders (trace.share_block). The occlusion and
    lobe masks, the bits each pixel was lent (ray_known) and the shadow shares against the float64 reference's
    traces of the same parts, shared by reference.share_block_masks / share_block_shadows: where the lenders are
    sure (block_frame) the lent bits equal, and the masks bit for bit where a ray is unambiguous (triangles grown
    and shrunk by BARY_TOL); the shadow shares exactly on 98 %, the others to one of a pixel's own rays (255/4 in
    2×2 blocks; in 4×4 blocks a pixel traces one ray of 16, so one ambiguous ray may move a share that few lenders
    hold by up to 255). A pixel of the open floor whose block lends it every slot knows the whole set; no bit
    outside the known ones. A set of fewer than four rays (one shadow ray) is each pixel's own; and lights of
    different counts in one call (trace.light_samples) are each shared by their own count's side."""
    mesh, cam, lights, g, sides = block_frame
    lenders, sure = sides[side]
    part = (*part, cam.width, side)
    eps, t_min = offsets(mesh)
    args = (mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, eps, t_min)
    whole = lenders.all(1) & sure
    # (4×4 blocks: fewer pixels whose every slot lends, and more whose lenders the bounds' rounding could move)
    assert whole.sum() > (1000 if side == 2 else 500) and sure[g.face >= 0].mean() > (0.97 if side == 2 else 0.95)
    assert (~lenders.all(1) & sure).sum() > 50
    # (6 occlusion rays: a set whose slots' parts wrap around its stride, some slots tracing more rays than others)
    for samples, lobes in ((16, False), (6, False), (8, True)):
        trace = (functools.partial(ref.trace_lobe_rays, *args, LOBES) if lobes
                 else functools.partial(ref.trace_occlusion, *args, samples))
        set_sure = sides[trace_module.block_side(samples, part)][1] if trace_module.block_side(samples, part) > 1 \
            else sure
        bits = 32 if lobes else 16
        got = (backend.trace_lobe_rays(mesh, g, LOBES, part=part) if lobes
               else backend.trace_occlusion(mesh, g, samples, part=part))
        known = backend.ray_known(mesh)[int(lobes)]
        want = [ref.share_block_masks(trace(tol=tol, part=part), lenders, samples, part)
                for tol in (0.0, BARY_TOL, -BARY_TOL)]
        np.testing.assert_array_equal(known[set_sure], want[0][1][set_sure])
        clear = _bits(want[1][0], bits) == _bits(want[2][0], bits)
        bad = clear & (_bits(got, bits) != _bits(want[0][0], bits)) & set_sure[:, None]
        assert not bad.any(), f"{bad.sum()} clear rays disagree"
        lent = _bits(known, samples)
        if lobes:
            lent = np.tile(lent, 2)
        assert not (_bits(got, bits)[:, :lent.shape[1]] & ~lent).any()
        if part[1] == 1:
            set_whole = sides[max(trace_module.block_side(samples, part), 2)][0].all(1) & set_sure
            assert (known[set_whole & whole] == (1 << samples) - 1).all()
    soft = np.stack([PointLight((0.3, 3.0, 0.2), radius=0.4).packed(),
                     DirectionalLight((-0.5, 1.0, 0.3), angular_radius=8.0).packed()])
    for samples in (16, 1, (16, 3), (8, 16), 6):
        vis = backend.trace_shadows(mesh, g, soft, samples=samples, part=part).astype(np.int64)
        own = ref.trace_shadows(mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, soft,
                                eps, t_min, samples=samples, part=part)
        want = ref.share_block_shadows(own, lenders, samples, part).astype(np.int64)
        # One ambiguous ray moves a share by 255 / (the rays its lenders traced): a 2×2 block's pixel traced
        # four of its light's 16, a 4×4 block's one of 16, so there the bound is 255 / its lenders; the lenders of
        # a 6-ray light in 2×2 blocks may hold fewer than four rays in all, and their own count bounds it then.
        step = np.stack([np.maximum(255 / 4 + 1, 255 / _lent_rays(n, part, lenders, cam.width) + 1)
                         if trace_module.block_side(n, part) < 4 else 255 / np.maximum(lenders.sum(1), 1) + 1
                         for n in trace_module.light_samples(samples, 2)], 1)
        on = sure & sides[2][1]
        off = np.abs(vis - want)[on]
        assert (off > step[on]).sum() == 0 and (off != 0).mean() < 0.02, (off.max(), (off != 0).mean())


@pytest.mark.parametrize("part", [(0, 1, 45, 4), (1, 4, 45, 4), (0, 1, 45, 2), (3, 4, 45, 2)])
def test_block_share_kernels_match_reference_exactly(backend, part):
    """share_block_masks and share_block_shadows alone (through the backends' own upload and launch methods, with an
    empty cache entry: no trace feeds them), fed random lenders, masks and visible shares on a 45×31 frame whose last
    blocks its edges cut (a fifth of the pixels misses, each hit lends to itself, no slot past the
    frame lends): bit for bit and 255th for 255th the float64 reference's, for sets whose slots' parts wrap around
    their stride (6 rays in parts of 4), whose slots trace unequal counts (6 rays over 4 slots), of 4×4 and 2×2 blocks
    and not shared (3 rays)."""
    width, height = 45, 31
    n, side = width * height, part[3]
    rng = np.random.default_rng(7)
    p = np.arange(n)
    face = np.where(rng.random(n) < 0.2, -1, rng.integers(0, 100, n)).astype(np.int32)
    lenders = rng.random((n, side * side)) < 0.6
    for q in range(side * side):
        inside = (p % width) - (p % width) % side + q % side < width
        b = trace_module.block_pixel(p, width, q, side)
        lenders[:, q] &= inside & (b < n) & (face[np.minimum(b, n - 1)] >= 0)
        lenders[:, q] |= b == p
    lenders[face < 0] = False
    packed = (lenders.astype(np.int64) << np.arange(side * side)).sum(1).astype(np.int32)
    m = {}
    on_device = backend._to_device(packed, "i32"), backend._to_device(face, "i32")
    for samples in (16, 6, 8, 3):
        own = rng.integers(0, 1 << samples, n, dtype=np.int64).astype(np.uint32)
        shared, known = backend._new(n, "u32"), backend._new(n, "u32")
        backend._launch_share_block_masks(m, *on_device, samples, part, n, backend._to_device(own, "u32"), shared,
                                          known)
        want = ref.share_block_masks(own, lenders, samples, part)
        np.testing.assert_array_equal(backend._to_host(shared, n, "u32"), want[0], err_msg=f"{samples} rays")
        np.testing.assert_array_equal(backend._to_host(known, n, "u32"), want[1], err_msg=f"{samples} rays")
    counts = np.array([16, 6, 3, 8], np.int32)
    visible = rng.integers(0, 256, (n, len(counts))).astype(np.uint8)
    out = backend._new((n, len(counts)), "u8")
    backend._launch_share_block_shadows(m, *on_device, counts, part, n, len(counts),
                                        backend._to_device(visible, "u8"), out)
    want = ref.share_block_shadows(visible, lenders, counts, part)
    assert (want != visible).mean() > 0.3
    np.testing.assert_array_equal(backend._to_host(out, (n, len(counts)), "u8"), want)


def test_block_lenders_follow_the_gbuffer(backend):
    """The lenders a frame's sets share are found once a G-buffer and block side and kept on the device
    (device._frame_lenders): a new camera's G-buffer, a host GBuffer in between, the own G-buffer again and a
    change of side each get their own, on a 45×31 frame whose last 4×4 blocks the frame's edges cut. The lent
    bits against the float64 reference where the lenders are sure (as block_frame's)."""
    mesh = Mesh.merge([Mesh.sphere(0.5, (0, 0.8, 0), subdivisions=3), Mesh.plane(4.0, 0.0, 16)])
    normals = trace_module._unit_face_normals(mesh.vertices[mesh.faces])
    eps, t_min = offsets(mesh)
    cams = [Camera(eye=(0.0, 3.5, 3.0), target=(0, 0.2, 0), fov=55, width=45, height=31),
            Camera(eye=(1.0, 2.0, 3.0), target=(0, 0.4, 0), fov=50, width=45, height=31)]
    light = PointLight((0.3, 3.0, 0.2), radius=0.4).packed()[None]

    def check(g, side):
        part = (0, 1, 45, side)
        args = (g.face, g.position, normals, g.eye, 45)
        lenders = trace_module.share_block(*args, side=side)
        moved = [trace_module.share_block(*args, side=side, normal_cos=trace_module.SHARE_NORMAL_COS + s * 1e-4,
                                          plane=trace_module.SHARE_PLANE - s * 1e-4) for s in (1, -1)]
        sure = (moved[0] == moved[1]).all(1)
        own = ref.trace_occlusion(mesh.vertices, mesh.normals, mesh.faces, g.face, g.bary, g.position, g.eye, eps,
                                  t_min, 16, part=part)
        want = ref.share_block_masks(own, lenders, 16, part)[1]
        got = backend.ray_known(mesh)[0]
        assert sure.mean() > 0.95 and (lenders.sum(1)[sure] < side * side).sum() > 20
        np.testing.assert_array_equal(got[sure], want[sure])

    for side in (4, 2):
        part = (0, 1, 45, side)
        g1 = backend.trace_primary(mesh, cams[0])
        backend.trace_shadows(mesh, None, light, samples=16, part=part)  # finds camera 0's lenders
        g2 = backend.trace_primary(mesh, cams[1])
        backend.trace_occlusion(mesh, None, 16, part=part)
        check(g2, side)
        host = GBuffer(face=g1.face.copy(), bary=g1.bary.copy(), position=g1.position.copy(), eye=g1.eye.copy())
        backend.trace_occlusion(mesh, host, 16, part=part)
        check(host, side)
        backend.trace_occlusion(mesh, None, 16, part=part)
        check(g2, side)
    backend.trace_occlusion(mesh, None, 16, part=(0, 1, 45, 4))
    backend.trace_occlusion(mesh, None, 16, part=(0, 1, 45, 2))
    check(g2, 2)


@pytest.mark.parametrize("part", [(0, 1), (1, 4), "blocks", "blocks 1/4", "4x4 blocks"])
def test_each_light_traces_its_own_count(backend, block_frame, part):
    """Lights of different counts in one call (trace.light_samples): each light's column is, bit for bit, what a
    call with its count for every light gives, each pixel its own rays or shared in blocks (a light of fewer
    than four rays then keeps its own; asked for 4×4 blocks, a light of fewer than 16 rays a sample 2×2)."""
    mesh, cam, lights, g, sides = block_frame
    part = {"blocks": (0, 1, cam.width), "blocks 1/4": (1, 4, cam.width),
            "4x4 blocks": (0, 1, cam.width, 4)}.get(part, part)
    soft = np.stack([PointLight((0.3, 3.0, 0.2), radius=0.4).packed(),
                     DirectionalLight((-0.5, 1.0, 0.3), angular_radius=8.0).packed()])
    for counts in ((16, 3), (8, 16)):
        mixed = backend.trace_shadows(mesh, g, soft, samples=counts, part=part)
        for k, n in enumerate(counts):
            alone = backend.trace_shadows(mesh, g, soft, samples=n, part=part)
            np.testing.assert_array_equal(mixed[:, k], alone[:, k])
        assert (mixed[:, 0] != mixed[:, 1]).any()


@pytest.mark.parametrize("bad, match", [((16, 8, 4), "one count a light, got 3 for 2 lights"),
                                        ((16, 0), "shadow samples"), ((16, 2.5), "shadow samples")])
def test_bad_per_light_samples_is_one_line(backend, bad, match):
    mesh, cam, lights = _shadow_scene()
    soft = np.stack([PointLight((0.3, 3.0, 0.2), radius=0.4).packed(),
                     DirectionalLight((-0.5, 1.0, 0.3), angular_radius=8.0).packed()])
    g = backend.trace_primary(mesh, cam)
    with pytest.raises(ValueError, match=match):
        backend.trace_shadows(mesh, g, soft, samples=bad)


@pytest.mark.parametrize("bad", [(4, 4), (-1, 2), (0, 0), "x", (0.5, 2)])
def test_bad_ray_part_is_one_line(backend, bad):
    mesh, cam, lights = _shadow_scene()
    g = backend.trace_primary(mesh, cam)
    with pytest.raises(ValueError, match="ray part"):
        backend.trace_occlusion(mesh, g, 8, part=bad)
    with pytest.raises(ValueError, match="ray part"):
        backend.trace_shadows(mesh, g, lights, samples=4, part=bad)


@pytest.mark.parametrize("bad", [-1, 33, 2.5, "8"])
def test_bad_occlusion_samples_are_one_line(backend, bad):
    mesh, cam, _ = _shadow_scene()
    g = backend.trace_primary(mesh, cam)
    with pytest.raises(ValueError, match="occlusion samples must be an integer"):
        backend.trace_occlusion(mesh, g, bad)


def test_shadows_offset_and_orientation(backend):
    """A single floor seen from below: the oriented normal points down, so a light above is behind
    it (0) and a light below is visible (1); no self-shadowing at any light elevation down to 2°."""
    mesh = Mesh.plane(4.0, 0.0, 8)
    cam = Camera(eye=(0.0, -2.0, 0.5), target=(0, 0, 0), fov=40, width=24, height=24)
    g = backend.trace_primary(mesh, cam)
    assert (g.face >= 0).all()
    elevations = np.radians([90, 30, 10, 2])
    below = np.stack([DirectionalLight((np.cos(e), -np.sin(e), 0)).packed() for e in elevations])
    above = np.stack([DirectionalLight((0, 1, 0)).packed(), PointLight((0, 2, 0)).packed()])
    assert backend.trace_shadows(mesh, g, below).all()
    assert not backend.trace_shadows(mesh, g, above).any()
    assert backend.trace_shadows(mesh, g, np.zeros((0, 8))).shape == (len(g.face), 0)


def test_bad_inputs(backend, mesh):
    o, d, t_max = _random_rays(mesh, 10, 1)
    with pytest.raises(ValueError, match="origins"):
        backend.trace_occluded(mesh, o[:, :2], d, t_max)
    nan_o = o.copy()
    nan_o[3, 1] = np.nan
    with pytest.raises(ValueError, match="origins"):
        backend.trace_occluded(mesh, nan_o, d, t_max)
    with pytest.raises(ValueError, match="directions"):
        backend.trace_occluded(mesh, o, d[:5], t_max)
    with pytest.raises(ValueError, match="directions"):
        backend.trace_occluded(mesh, o, 2 * d, t_max)
    with pytest.raises(ValueError, match="t_max"):
        backend.trace_occluded(mesh, o, d, t_max[:5])
    with pytest.raises(ValueError, match="t_max"):
        backend.trace_occluded(mesh, o, d, np.full(10, np.nan))
    with pytest.raises(ValueError, match="mesh"):
        backend.trace_occluded(mesh.vertices, o, d, t_max)
    cam = showcase_camera(width=8, height=6)
    with pytest.raises(ValueError, match="camera"):
        backend.trace_primary(mesh, cam.packed())
    with pytest.raises(ValueError, match="mesh"):
        backend.trace_primary(None, cam)
    g = backend.trace_primary(mesh, cam)
    good = PointLight().packed()
    with pytest.raises(ValueError, match="lights_packed"):
        backend.trace_shadows(mesh, g, np.zeros((2, 7)))
    with pytest.raises(ValueError, match="lights_packed"):
        backend.trace_shadows(mesh, g, np.where(np.arange(8) == 2, np.nan, good)[None])
    with pytest.raises(ValueError, match="lights_packed"):
        backend.trace_shadows(mesh, g, np.where(np.arange(8) == 0, 2.0, good)[None])
    with pytest.raises(ValueError, match="gbuffer"):
        backend.trace_shadows(mesh, {"face": g.face}, good)
    with pytest.raises(ValueError, match="gbuffer"):
        backend.trace_shadows(mesh, dataclasses.replace(g, face=g.face + len(mesh.faces)), good)
    with pytest.raises(ValueError, match="gbuffer"):
        backend.trace_shadows(showcase_mesh(), None, good)  # no trace_primary on this mesh yet


def test_a_gbuffer_by_hand_needs_what_the_rays_start_from(backend, occlusion_reference):
    """Shadow, occlusion and lobe rays start from the hit lifted by its face's vertex normals (trace.ray_starts),
    so a GBuffer built by hand must carry bary too; what is missing or malformed is named in one line, before
    any ray is traced."""
    mesh, g, _ = occlusion_reference
    lights = _shadow_scene()[2]
    cases = ((GBuffer(face=g.face, position=g.position, eye=g.eye), "gbuffer has no bary"),
             (GBuffer(face=g.face, bary=g.bary[:-1], position=g.position, eye=g.eye), "gbuffer.bary must be"),
             (GBuffer(face=g.face, bary=np.where(g.face[:, None] >= 0, np.nan, g.bary), position=g.position,
                      eye=g.eye), "gbuffer.bary contains NaN"))
    for bad, message in cases:
        for trace in (lambda b: backend.trace_shadows(mesh, b, lights), lambda b: backend.trace_occlusion(mesh, b, 8),
                      lambda b: backend.trace_lobe_rays(mesh, b, LOBES)):
            with pytest.raises(ValueError, match=message) as err:
                trace(bad)
            assert "\n" not in str(err.value)


def test_disk_radii_are_the_occlusion_rays_radii_and_lifts():
    """The shade kernels' per-ray table (trace.disk_radii, S's rows from S(S − 1)/2) against the float64 rays
    themselves: each row's radius is |disk_sample|, its lift the ray's cosine to the normal
    (occlusion_directions), the third 1/lift; float32 rounding (2e-7 relative)."""
    table = trace_module.DISK_RADII
    assert table.shape == (trace_module.OCCLUSION_SAMPLES_MAX * (trace_module.OCCLUSION_SAMPLES_MAX + 1) // 2, 3)
    for samples in (1, 2, 7, 16, 32):
        rows = table[samples * (samples - 1) // 2:][:samples].astype(np.float64)
        q = trace_module.disk_sample(np.arange(samples), samples, 12345)
        d = trace_module.occlusion_directions(np.array([0.0, 0.0, 1.0]), samples, 12345).reshape(samples, 3)
        np.testing.assert_allclose(rows[:, 0], np.hypot(q[:, 0], q[:, 1]), rtol=2e-7, atol=1e-12)
        np.testing.assert_allclose(rows[:, 1], d[:, 2], rtol=2e-7)
        np.testing.assert_allclose(rows[:, 2], 1.0 / d[:, 2], rtol=2e-7)
