"""ASG materials (Xu 2013, `wb.bake(..., method="asg")`) in the SG renderer and the Monte Carlo reference, on
every backend present. The shade kernels against their float64 reference are in tests/test_shade.py
("occluded-asg"); here the outside truths:

- Under lights, the renderer takes an ASG material's specular at each light's direction from the material's
  own f̄ (`ASGBRDF.eval`), so a lit sphere must match `shading.direct_reference` (the exact direct lighting of
  the scene's own materials at the same G-buffer). What differs is float32, the light SG's cosine integral
  against the ideal light's cosine, and the bilinear lookups. Measured (Warp CPU, U-grooves, Cook–Torrance
  m = 0.15, one directional light of radius 0.5°): mean relative error 7.5e-5, largest 8.4e-3 of the peak
  (Warp CPU and PoCL alike). Bounds: 1e-3 and 2e-2.
- The Monte Carlo reference renders the same scene from the material's exact ground truth (its provenance),
  sampling isotropic stand-ins of the ASG lobes: it judges the bake, so the two differ by the ASG bake's
  error. Measured (32×24, 64 samples, a 2^14-facet truth): 50.1 dB, mean relative difference 1.1 %. Bounds:
  40 dB, 3 %.
"""

import warnings

import numpy as np
import pytest

import warp_biscale as wb
from conftest import flat_tile
from warp_biscale.render import pack_frame
from warp_biscale.shading import direct_reference


@pytest.fixture(scope="module")
def grooves_asg():
    tile = wb.geometry.grooves(profile="u")
    return wb.bake(tile, [wb.CookTorrance(0.7, 0.15, kd=0.2)] * tile.n_materials, method="asg", lobes=4,
                   directions=8, facets=2**12, backend="warp:cpu")


SPHERE = wb.Mesh.sphere(1.0, subdivisions=4)  # one mesh object: its BVH is built once for every scene here


def _lit_sphere(material, width=48, height=36):
    cam = wb.Camera(eye=(0.3, 0.5, 3.2), width=width, height=height, fov=45)
    return wb.Scene(SPHERE, [material], cam, None,
                    [wb.DirectionalLight((0.3, 1.0, 0.6), 2.0, 0.5)])


def test_lights_shade_the_materials_own_brdf(backend, grooves_asg):
    assert (grooves_asg.asgs.lam / grooves_asg.asgs.mu).min() > 100  # lobes stretched along the grooves
    scene = _lit_sphere(grooves_asg)
    frame = pack_frame(scene, backend)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
    ref = direct_reference(scene, frame.gbuffer.face, frame.gbuffer.bary, frame.gbuffer.light_vis, frame.lights)
    hit = frame.gbuffer.face >= 0
    err = np.abs(out - ref)[hit]
    msg = f"mean relative {err.mean() / ref[hit].mean():.3g}, largest {err.max() / ref.max():.3g} of the peak"
    assert err.mean() < 1e-3 * ref[hit].mean(), msg
    assert err.max() < 2e-2 * ref.max(), msg


def test_sg_renderer_against_the_monte_carlo_reference(backend, grooves_asg):
    scene = _lit_sphere(grooves_asg, 32, 24)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = wb.render(scene, backend=backend, aa=1).image
        b = wb.render(scene, method="mc", samples=64, backend=backend, truth_facets=2**14).image
    assert np.isfinite(a).all() and a.min() >= 0 and a.max() > 0
    c = wb.compare_images(a, b)
    assert c["psnr"] > 40 and c["mean_rel"] < 0.03, c


def test_with_an_environment_and_occluders(backend, grooves_asg):
    """A whole frame: the ASG material on a floor under a sphere, sky and a point light, SSDF shadows —
    finite, non-negative, and darker where the sphere occludes the floor's sky."""
    mesh = wb.Mesh.merge([wb.Mesh.sphere(0.6, (0, 0.6, 0), material=0), wb.Mesh.plane(4.0, 0.0, 12, material=1)])
    cam = wb.Camera(eye=(0.0, 2.2, 3.5), target=(0.0, 0.3, 0.0), width=40, height=30, fov=50)
    scene = wb.Scene(mesh, [wb.Lambert(0.5), grooves_asg], cam, wb.Environment.sky(height=32, width=64),
                     [wb.PointLight((1.5, 3.0, 1.0), 10.0, 0.2)])
    img = wb.render(scene, backend=backend, aa=1).image
    assert np.isfinite(img).all() and img.min() >= 0
    frame = pack_frame(scene, backend)
    floor = (frame.gbuffer.face >= 0) & (mesh.face_material[np.maximum(frame.gbuffer.face, 0)] == 1)
    lum = img.reshape(-1, 3).mean(1)
    assert floor.sum() > 100 and lum[floor].min() < 0.5 * np.median(lum[floor])


FLAT_ANISOTROPIC = [wb.AnisotropicWard(0.7, 0.1, 0.3, kd=0.2), wb.AshikhminShirley(0.5, 40, 300, rd=0.3)]


@pytest.mark.parametrize("brdf", FLAT_ANISOTROPIC, ids=["ward", "ashikhmin-shirley"])
def test_flat_tile_of_an_anisotropic_brdf_renders_as_the_brdf(backend, brdf):
    """A flat tile's effective BRDF is its small-scale BRDF: the ASG bake of an anisotropic one (one delta lobe
    whose facets' tangents all lie along the tile's x: tangent order (1, 0)) must render, under a light, as that
    BRDF on the sphere itself (the analytic path, f_s exact, in the frame of the mesh's tangents). This checks the
    orientation chain tile x → lobe frame → convolved ASG → mesh tangent. What differs is the NDF's ASG against
    f_s's own shape and the K = 8 tables. Measured (PoCL, 48×36): Ward (0.1, 0.3) 53.2 dB, Ashikhmin–Shirley
    (40, 300) 56.5 dB; the same BRDF turned by 90° is 24.0 and 26.4 dB away. Bound 48 dB; the turned one < 40."""
    mat = wb.bake(flat_tile(), brdf, method="asg", lobes=1, directions=8, facets=2**10, backend=backend)
    np.testing.assert_allclose(mat.tangent_order, [[[1.0, 0.0]]], atol=1e-6)  # (material, lobe, 2)
    effective = wb.render(_lit_sphere(mat), backend=backend, aa=1).image
    analytic = wb.render(_lit_sphere(brdf), backend=backend, aa=1).image
    db = wb.compare_images(effective, analytic)["psnr"]
    turned = brdf.__class__(*(getattr(brdf, f) for f in (("ks", "alpha_y", "alpha_x", "kd")
                                                         if isinstance(brdf, wb.AnisotropicWard)
                                                         else ("rs", "nv", "nu", "rd"))))
    db_turned = wb.compare_images(effective, wb.render(_lit_sphere(turned), backend=backend, aa=1).image)["psnr"]
    print(f"\n{backend.name} {type(brdf).__name__}: {db:.2f} dB; turned by 90 degrees {db_turned:.2f} dB", end="")
    assert db > 48 and db_turned < 40, (db, db_turned)
