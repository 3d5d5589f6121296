"""Spatially varying analytic BRDFs (`svbrdf.Textured`, Wang 2009 §4.1/§6): the shade kernels against the
float64 reference with textured materials, a constant map against the untextured material it equals,
where a map changes the image, the lookup convention, and the errors (no UVs, bad maps, TOML keys)."""

import functools

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale.render import pack_frame
from warp_biscale.scene import Scene
from warp_biscale.scene import Camera, Mesh, PointLight
from warp_biscale.shading import shade_reference
from warp_biscale.svbrdf import Textured, sample


def _checker(n=8, lo=0.2, hi=1.0, rgb=True):
    i, j = np.mgrid[0:n, 0:n]
    c = np.where((i + j) % 2 == 0, hi, lo)
    return np.repeat(c[..., None], 3, 2) * np.array([1.0, 0.8, 0.6]) if rgb else c


@functools.cache
def _env():
    """One environment object for every scene here: its prepared lighting is made once."""
    return wb.Environment.from_sgs([[0.3, 0.8, 0.5], [0, 1, 0]], [40.0, 2.0], [[6.0, 5.5, 5.0], [0.6, 0.7, 0.9]],
                                   constant=0.15, height=32, width=64)


@functools.cache
def _mesh():
    """One mesh object for every scene here: its SSDF and BVH are made once."""
    sphere = Mesh.sphere(radius=0.6, center=(0.0, 0.6, 0.0), subdivisions=3, material=0)
    floor = Mesh.plane(size=4.0, height=0.0, divisions=8, material=1)
    return Mesh.merge([sphere, floor])


def _scene(materials, lights=True, size=(40, 32)):
    return Scene(_mesh(), materials,
                 Camera(eye=(0.0, 2.0, 3.0), target=(0.0, 0.4, 0.0), width=size[0], height=size[1], fov=50),
                 _env(), [PointLight((1.5, 3.0, 1.0), 10.0, 0.2)] if lights else [], ssdf_resolution=16, ssdf_terms=8)


def _shade(backend, scene):
    frame = pack_frame(scene, backend)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights,
                        gbuffer=frame.gbuffer)
    return frame, out


@pytest.mark.parametrize("base", [wb.BlinnPhong(0.5, 120, kd=0.4), wb.CookTorrance(0.6, 0.3, kd=0.3),
                                  wb.Ward(0.4, 0.2, kd=(0.2, 0.4, 0.3))], ids=["blinnphong", "cooktorrance", "ward"])
def test_textured_kernel_matches_reference(backend, base):
    floor = Textured(base, kd_map=_checker(8), ks_map=_checker(4, 0.0, 1.0), parameter_map=_checker(6, 0.5, 2.0,
                                                                                                    rgb=False))
    sphere = Textured(wb.BlinnPhong(0.5, 150, kd=(0.5, 0.3, 0.2)), kd_map=_checker(16))
    scene = _scene([sphere, floor])
    frame, out = _shade(backend, scene)
    # slot 0 is the shared texture of ones, 1–4 the two analytic rows' specular corrections and moment tables
    assert frame.inputs.mat_info[:, 3].tolist() == [5, 8]
    ref = shade_reference(frame)
    assert np.isfinite(out).all() and (out >= 0).all()
    peak = ref.max()
    err = np.abs(out - ref)
    msg = f"max err {err.max():.3g}, peak {peak:.3g}, p99.9 {np.quantile(err, 0.999):.3g}"
    # The tolerances of tests/test_shade.py.
    assert np.quantile(err / (np.abs(ref) + 1e-3 * peak), 0.999) < 2e-3, msg
    assert err.max() < 2e-2 * peak, msg


@pytest.mark.parametrize("which", ["kd_map", "ks_map", "parameter_map"])
def test_constant_map_equals_scaled_material(backend, which):
    c = 0.7
    base = wb.CookTorrance(0.6, 0.3, f0=0.2, kd=(0.3, 0.2, 0.1))
    scaled = {"kd_map": wb.CookTorrance(0.6, 0.3, f0=0.2, kd=(0.3 * c, 0.2 * c, 0.1 * c)),
              "ks_map": wb.CookTorrance(0.6 * c, 0.3, f0=0.2, kd=(0.3, 0.2, 0.1)),
              "parameter_map": wb.CookTorrance(0.6, 0.3 * c, f0=0.2, kd=(0.3, 0.2, 0.1))}[which]
    shape = (3, 5) if which == "parameter_map" else (3, 5, 3)
    textured = Textured(base, **{which: np.full(shape, c)})
    plain = wb.Lambert(0.5)
    _, a = _shade(backend, _scene([plain, textured]))
    _, b = _shade(backend, _scene([plain, scaled]))
    # The same float32 operations up to the map's product (c·x rounded once either way).
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * b.max())


def test_black_kd_half_removes_the_diffuse(backend):
    """A kd map black for u < 0.5 on the floor (a Lambert): those floor pixels go black, the others keep
    the untextured radiance."""
    kd_map = np.ones((4, 8, 3))
    kd_map[:, :4] = 0.0
    floor = wb.Lambert(0.6)
    frame, plain = _shade(backend, _scene([wb.Lambert(0.5), floor], lights=False))
    _, tex = _shade(backend, _scene([wb.Lambert(0.5), Textured(floor, kd_map=kd_map)], lights=False))
    hit = frame.gbuffer.face >= 0
    on_floor = np.zeros(len(hit), bool)
    on_floor[hit] = frame.inputs.face_material[frame.gbuffer.face[hit]] == 1
    mesh = _scene([wb.Lambert(0.5), floor]).mesh
    tri = mesh.faces[frame.gbuffer.face[on_floor]]
    b = frame.gbuffer.bary[on_floor].astype(np.float64)
    uv = ((1 - b[:, 0] - b[:, 1])[:, None] * mesh.uvs[tri[:, 0]] + b[:, :1] * mesh.uvs[tri[:, 1]]
          + b[:, 1:] * mesh.uvs[tri[:, 2]])
    u = np.mod(uv[:, 0], 1.0)
    # Bilinear with repeat: black strictly inside columns 0-3's centres (u in [1/16, 7/16]), white in 4-7's.
    black, white = (u > 1.5 / 16) & (u < 6.5 / 16), (u > 9.5 / 16) & (u < 14.5 / 16)
    assert black.sum() > 50 and white.sum() > 50
    assert plain[on_floor][black].min() > 0
    np.testing.assert_array_equal(tex[on_floor][black], 0.0)
    np.testing.assert_allclose(tex[on_floor][white], plain[on_floor][white], rtol=1e-6)
    # Off the floor the image is unchanged (the sphere's material has no texture; no SSDF change).
    np.testing.assert_array_equal(tex[~on_floor], plain[~on_floor])


def test_sample_convention():
    img = np.arange(12, dtype=np.float64).reshape(3, 4, 1)
    # Texel centres return the texel; row 0 at v = 0; columns wrap.
    np.testing.assert_allclose(sample(img, [[0.5 / 4, 0.5 / 3], [3.5 / 4, 2.5 / 3]])[:, 0], [0, 11])
    np.testing.assert_allclose(sample(img, [[0.0, 0.5 / 3]])[:, 0], [(0 + 3) / 2])  # halfway between col 3 and 0
    np.testing.assert_allclose(sample(img, [[1.5 / 4 + 2.0, 1.5 / 3 - 1.0]]), sample(img, [[1.5 / 4, 1.5 / 3]]))


def test_mesh_without_uvs_is_refused():
    mesh = Mesh.sphere(1.0, subdivisions=2)
    mesh.uvs = None
    with pytest.raises(ValueError, match=r"materials\[0\].*Textured.*no UVs"):
        Scene(mesh, [Textured(wb.Lambert(0.5), kd_map=np.ones((2, 2, 3)))])
    Scene(mesh, [wb.Lambert(0.5)])  # untextured: fine


@pytest.mark.parametrize("which, bad, match", [
    ("kd_map", np.full((2, 2, 3), np.nan), "kd_map has non-finite"),
    ("ks_map", -np.ones((2, 2, 3)), "ks_map must be >= 0"),
    ("kd_map", np.ones((2, 2)), r"kd_map must have shape \(H, W, 3\)"),
    ("parameter_map", np.ones((2, 2, 3)), r"parameter_map must have shape \(H, W\)"),
    ("parameter_map", np.zeros((2, 2)), "parameter_map must be > 0"),
    ("parameter_map", np.full((2, 2), np.inf), "parameter_map has non-finite"),
    ("kd_map", "/nonexistent/albedo.png", "kd_map: cannot read"),
])
def test_bad_maps_are_named(which, bad, match):
    with pytest.raises(ValueError, match=match):
        Textured(wb.BlinnPhong(0.5, 50), **{which: bad})


def test_bad_wrapped_brdf():
    with pytest.raises(ValueError, match="analytic BRDF"):
        Textured("plastic")
    with pytest.raises(ValueError, match="Lambert"):
        Textured(wb.Lambert(0.5), ks_map=np.ones((1, 1, 3)))


def test_toml_kd_map_renders(backend, tmp_path):
    from PIL import Image

    img = np.zeros((4, 8, 3), np.uint8)
    img[:, 4:] = 255
    Image.fromarray(img).save(tmp_path / "albedo.png")
    (tmp_path / "scene.toml").write_text("""
[render]
width = 24
height = 16
[camera]
eye = [0.0, 3.0, 3.0]
target = [0.0, 0.0, 0.0]
[environment]
type = "constant"
radiance = 1.0
[[object]]
mesh = "plane"
size = 4.0
material = "floor"
[material.floor]
type = "blinnphong"
ks = 0.2
exponent = 50.0
kd = 0.8
kd_map = "albedo.png"
""")
    sf = wb.load_scene(tmp_path / "scene.toml")
    mat = sf.scene.materials[0]
    assert isinstance(mat, Textured) and mat.kd_map.shape == (4, 8, 3)
    np.testing.assert_allclose(mat.kd_map[:, 4:], 1.0)
    image = wb.render(sf.scene, backend=backend).image
    assert np.isfinite(image).all() and image.max() > 0


def test_toml_map_errors(tmp_path):
    base = """
[[object]]
mesh = "plane"
material = "floor"
[material.floor]
type = "%s"
%s
"""
    (tmp_path / "a.toml").write_text(base % ("ward", 'ks = 0.3\nalpha = 0.2\nkd_map = "missing.png"'))
    with pytest.raises(ValueError, match=r"a\.toml:\d+: \[material\.floor\] kd_map"):
        wb.load_scene(tmp_path / "a.toml")
    (tmp_path / "b.toml").write_text(base % ("ward", "ks = 0.3\nalpha = 0.2\nparameter_map = 3"))
    with pytest.raises(ValueError, match=r"b\.toml:\d+: \[material\.floor\] parameter_map"):
        wb.load_scene(tmp_path / "b.toml")


def test_monte_carlo_evaluates_the_maps(backend):
    """The Monte Carlo reference looks the maps up at each pixel's UV: maps of ones give the untextured image
    bit for bit (same strategies, same samples), and a constant kd map c on a Lambert scales it by c."""
    def mc(mat):
        scene = _scene([wb.Lambert(0.5), mat], lights=True, size=(16, 12))
        return wb.render(scene, method="mc", backend=backend, samples=8, seed=3).image

    base = wb.BlinnPhong(0.5, 80, kd=0.3)
    ones = Textured(base, kd_map=np.ones((2, 2, 3)), ks_map=np.ones((3, 1, 3)), parameter_map=np.ones((1, 2)))
    np.testing.assert_allclose(mc(ones), mc(base), rtol=1e-12, atol=0)
    lam = wb.Lambert(0.6)
    scaled = mc(Textured(lam, kd_map=np.full((2, 3, 3), 0.25)))
    plain = mc(lam)
    floor = np.abs(scaled - plain).max(axis=2) > 0
    assert floor.sum() > 20
    np.testing.assert_allclose(scaled[floor], 0.25 * plain[floor], rtol=1e-9)
