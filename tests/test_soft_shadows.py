"""Soft shadows: a light with a radius casts a penumbra, against the Monte Carlo reference, whose lights
are the same emitting discs."""

import numpy as np
import pytest

import warp_biscale as wb


@pytest.fixture(scope="module")
def penumbra():
    """A sphere hovering over a floor under a large point light (radius 0.5 at 2.2 above the floor: wide
    penumbrae), no environment, so every floor pixel is direct light times its visible share."""
    mesh = wb.Mesh.merge([wb.Mesh.sphere(0.5, (0, 0.8, 0), subdivisions=3), wb.Mesh.plane(4.0, 0.0, 16)])
    cam = wb.Camera(eye=(0.0, 3.5, 3.0), target=(0, 0.2, 0), fov=55, width=72, height=56)
    scene = wb.Scene(mesh, [wb.Lambert(0.6)], cam, None, [wb.PointLight((0.3, 2.2, 0.2), intensity=8.0, radius=0.5)])
    return scene, wb.render(scene, method="mc", samples=1024, backend="warp:cpu").image


def _psnr(image, reference):
    return 10 * np.log10(reference.max() ** 2 / np.mean((image - reference) ** 2))


def test_penumbra_matches_monte_carlo(backend, penumbra):
    """Measured on Warp CPU against 1024 MC samples: one shadow ray (the hard shadow) 36.9 dB, 16 rays
    46.2 dB, 64 rays 46.8 dB (the reference's own noise is then the larger part); 16 rays 48.2 dB since they aim
    at the part of the light above the horizon (trace.above_horizon)."""
    scene, reference = penumbra
    soft = wb.render(scene, backend=backend, shadow_samples=16).image
    hard = wb.render(scene, backend=backend, shadow_samples=1).image
    assert _psnr(soft, reference) > 44.0
    assert _psnr(soft, reference) > _psnr(hard, reference) + 6.0


def test_a_light_the_shading_normal_sees_past_the_faces_plane_lights_the_surface(backend):
    """The shadow terminator: on a coarse sphere (80 faces) lit from the side, pixels whose face's own plane
    hides the light but whose interpolated normal sees it must get the smooth surface's light, ρ/π·E·(n·l),
    not 0 (they were all 0 when every ray below the face's plane counted as blocked). The rays leave from the
    hit lifted towards the smooth surface (trace.ray_starts), so on a convex mesh nothing blocks them: 1 %
    per pixel (float32 shading; a grazing ray could still clip a neighbouring face, which would show as a
    step of 1/16). The Monte Carlo reference, whose rays leave from the same points, agrees to its noise."""
    direction = np.array([1.0, 0.3, 0.2]) / np.linalg.norm([1.0, 0.3, 0.2])
    mesh = wb.Mesh.sphere(1.0, subdivisions=1)
    cam = wb.Camera(eye=(0, 0, 4), target=(0, 0, 0), fov=35, width=48, height=48)
    scene = wb.Scene(mesh, [wb.Lambert(0.8)], cam, None,
                     [wb.DirectionalLight(tuple(direction), irradiance=3.0, angular_radius=0.5)])
    g = wb.get_backend(backend).trace_primary(mesh, cam)
    hit = g.face >= 0
    tri = mesh.faces[np.maximum(g.face, 0)]
    weights = np.stack([1 - g.bary[:, 0] - g.bary[:, 1], g.bary[:, 0], g.bary[:, 1]], 1)
    ns = np.einsum("pk,pkc->pc", weights, mesh.normals[tri].astype(np.float64))
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    past_plane = hit & (mesh.face_normals[np.maximum(g.face, 0)] @ direction < 0) & (ns @ direction > 0.02)
    assert past_plane.sum() > 30
    smooth = 0.8 / np.pi * 3.0 * (ns @ direction)[past_plane]
    image = wb.render(scene, backend=backend, shadow_samples=16).image.reshape(-1, 3)[past_plane, 0]
    np.testing.assert_allclose(image, smooth, rtol=0.01)
    mc = wb.render(scene, backend=backend, method="mc", samples=64).image.reshape(-1, 3)[past_plane, 0]
    np.testing.assert_allclose(mc.mean(), smooth.mean(), rtol=0.01)


def test_a_mesh_wound_the_other_way_keeps_its_lights(backend):
    """A mesh whose faces wind against its vertex normals (outward normals, inward winding): the rays leave with
    the vertex normals turned to the eye's side by their own blend, not by the winding, which had turned them
    inside, so that every light was below their horizon (SG 0.0002 against the reference's 0.0676). Now the image
    is the one of the same sphere wound the usual way, within the float32 kernels' rounding, and agrees with
    Monte Carlo (which samples about the shading normal) as that one does."""
    sphere = wb.Mesh.sphere(1.0, subdivisions=3)
    flipped = wb.Mesh(sphere.vertices, sphere.faces[:, ::-1].copy(), sphere.normals)
    camera = wb.Camera(eye=(0.0, 0.5, 3.5), width=40, height=30)
    light = [wb.DirectionalLight((0.5, 0.8, 0.3), 3.0, 5.0)]
    images = [wb.render(wb.Scene(m, [wb.Lambert(0.5)], camera, None, light), backend=backend, aa=1).image
              for m in (sphere, flipped)]
    assert images[0].mean() > 0.05
    np.testing.assert_allclose(images[1], images[0], atol=1e-4)
    mc = wb.render(wb.Scene(flipped, [wb.Lambert(0.5)], camera, None, light), method="mc", samples=64,
                   backend=backend).image
    assert abs(mc.mean() / images[1].mean() - 1) < 0.02
