"""The tonemap stage (a frame tone-mapped for display on the device, `backend.frame_u8`) against
`images.tonemap`, the float64 reference, on every backend."""

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import images


@pytest.fixture(scope="module")
def scene():
    mesh = wb.Mesh.merge([wb.Mesh.sphere(1.0, (0, 1, 0), subdivisions=3, material=0),
                          wb.Mesh.plane(6.0, 0.0, 4, material=1)])
    return wb.Scene(mesh, [wb.BlinnPhong(0.6, 80, kd=0.3, normalization="energy"), wb.Lambert(0.5)],
                    wb.Camera(eye=(0, 2.2, 5), target=(0, 0.8, 0), width=40, height=30),
                    wb.Environment.constant(0.6, 8, 16), [wb.DirectionalLight((0.3, 1, 0.4), 3.0, 1.0)])


@pytest.mark.parametrize("operator", images.TONEMAP_OPERATORS)
def test_frame_u8_matches_the_host_tone_mapping(backend, scene, operator):
    """Against images.tonemap of the same float frame read back: at most one 8-bit step apart (float32
    against float64 at a rounding boundary; the device rounds halves up, numpy to even), and on almost
    every channel equal. Exposures from -8 to +8 stops reach the operators' flat ends."""
    be = wb.get_backend(backend)
    wb.render(scene, backend=be, shadow_samples=1)  # leaves the frame's radiance on the device
    cam = scene.camera
    radiance = be.frame_radiance(scene.mesh, cam.width, cam.height)
    assert radiance.max() > 0
    for exposure in (-8.0, -1.0, 0.0, 2.5, 8.0):
        got = be.frame_u8(scene.mesh, cam.width, cam.height, exposure, operator)
        want = images.tonemap(radiance, exposure, operator)
        assert got.shape == want.shape == (cam.height, cam.width, 3) and got.dtype == np.uint8
        diff = np.abs(got.astype(int) - want.astype(int))
        assert diff.max() <= 1 and (diff == 0).mean() > 0.99, (exposure, diff.max(), (diff == 0).mean())
        # read back into a buffer of the caller's, plain or the backend's own (pinned on a GPU)
        for out in (np.full((cam.height, cam.width, 3), 7, np.uint8), be.frame_buffer(cam.width, cam.height)):
            out[...] = 7
            assert be.frame_u8(scene.mesh, cam.width, cam.height, exposure, operator, out=out) is out
            np.testing.assert_array_equal(out, got)


def test_frame_u8_bad_inputs(scene):
    be = wb.get_backend("warp:cpu")
    wb.render(scene, backend=be, shadow_samples=1)
    with pytest.raises(ValueError, match="operator"):
        be.frame_u8(scene.mesh, 40, 30, 0.0, "filmic")
    with pytest.raises(ValueError, match="exposure"):
        be.frame_u8(scene.mesh, 40, 30, float("nan"))
    with pytest.raises(ValueError, match="no 41x30 frame"):
        be.frame_u8(scene.mesh, 41, 30)
    for out in (np.zeros((30, 40, 3), np.float32), np.zeros((40, 30, 3), np.uint8), np.zeros((30, 40, 4), np.uint8)):
        with pytest.raises(ValueError, match="out must be"):
            be.frame_u8(scene.mesh, 40, 30, out=out)
