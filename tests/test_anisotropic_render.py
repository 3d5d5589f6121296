"""Analytic anisotropic BRDFs (anisotropic Ward, Ashikhmin–Shirley) as large-scale materials, in the frame of the
mesh's tangents (issue 20 item 2), in the SG renderer and the Monte Carlo reference, on every backend present.
The shade kernels against their float64 reference are in tests/test_shade.py ("occluded-anisotropic"); here
the outside truths:

- Under lights the renderer evaluates f_s·cos θi itself, averaged over the light's SG (`shading.light_mean`), so a
  lit sphere must match `shading.direct_reference` (the exact direct lighting of an ideal light at the disc's
  centre, at the same G-buffer) up to the light's size and float32. Measured (Warp CPU and PoCL alike, one
  directional light of radius 0.5°): mean relative error 1.19e-3 (Ward) and 1.50e-3 (Ashikhmin–Shirley), largest
  1.9e-3 and 2.1e-3 of the peak; with f_s at the centre alone, before, 4.5e-5 and 3.8e-5. Bounds: 3e-3 and 2e-2
  (the light's size is judged against the Monte Carlo reference in tests/test_light_size.py).
- Under an environment the NDF is one ASG (Xu 2013 §5.2, `brdf.ndf_bandwidths`) warped to the light directions
  and taken by the prefiltered maps at its effective sharpness (isotropic blur), with f_s's smooth factor at
  the mirror direction (Ashikhmin–Shirley's 1/max(cos θi, cos θo) through `shading.capped_cosine_integral`, its
  ρd at `shading.lobe_cosine`), scaled by the row's exact specular albedo over the lobe's own
  (`shading.specular_correction`): exact under a constant environment. Against the Monte Carlo reference (the
  exact BRDF, its half vectors drawn from the NDF's ASG: `montecarlo_sampling._AsgGlossyStrategy`), the spheres
  below under a constant environment, 32 × 24, 256 samples a pixel, over the sphere's pixels, measured (Warp CPU
  and PoCL alike): anisotropic Ward 36.0 dB (mean relative 1.8 %), Ashikhmin–Shirley 39.9 dB (0.9 %), both at the
  reference's own noise; before the correction (the reference's seed 1) 26.4 dB (5.8 %) and 17.6 dB (11.9 %).
  Bounds 33 and 36 dB, 3 % and 2 %. With αx = αy the anisotropic Ward is the isotropic Ward's image.
"""

import warnings

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale.render import pack_frame
from warp_biscale.shading import direct_reference

MATERIALS = {"ward": wb.AnisotropicWard(0.6, 0.08, 0.4, kd=0.2),
             "ashikhmin-shirley": wb.AshikhminShirley(rs=0.5, nu=20, nv=400, rd=0.3)}


SPHERE = wb.Mesh.sphere(1.0, subdivisions=4)  # one mesh object: its BVH is built once for every scene here
CONSTANT = wb.Environment.constant(1.0)  # one environment object: its lighting is prepared once


def _sphere(material, environment=None, lights=(), width=48, height=36):
    cam = wb.Camera(eye=(0.3, 0.5, 3.2), width=width, height=height, fov=45)
    return wb.Scene(SPHERE, [material], cam, environment, list(lights))


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_lights_shade_the_exact_brdf(backend, name):
    scene = _sphere(MATERIALS[name], lights=[wb.DirectionalLight((0.3, 1.0, 0.6), 2.0, 0.5)])
    frame = pack_frame(scene, backend)
    out = backend.shade(scene.mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
    ref = direct_reference(scene, frame.gbuffer.face, frame.gbuffer.bary, frame.gbuffer.light_vis, frame.lights)
    hit = frame.gbuffer.face >= 0
    err = np.abs(out - ref)[hit]
    msg = f"mean relative {err.mean() / ref[hit].mean():.3g}, largest {err.max() / ref.max():.3g} of the peak"
    assert err.mean() < 3e-3 * ref[hit].mean(), msg
    assert err.max() < 2e-2 * ref.max(), msg
    # the highlight is stretched: turning the tangent frame (swapping αx, αy) changes the image
    swapped = wb.AnisotropicWard(0.6, 0.4, 0.08, kd=0.2) if name == "ward" else wb.AshikhminShirley(
        rs=0.5, nu=400, nv=20, rd=0.3)
    other = backend.shade(scene.mesh, pack_frame(_sphere(swapped, lights=scene.lights), backend).inputs,
                          frame.camera, frame.lights, gbuffer=frame.gbuffer)
    assert np.abs(other - out)[hit].max() > 0.2 * ref.max()


@pytest.mark.parametrize("name, psnr, mean_rel", [("ward", 33, 0.03), ("ashikhmin-shirley", 36, 0.02)])
def test_environment_against_the_monte_carlo_reference(backend, name, psnr, mean_rel):
    """A sphere under a constant environment against the Monte Carlo reference at 256 samples a pixel, over the
    sphere's pixels (bounds 3–4 dB and 1.7–2.1× from the module's measurements)."""
    env = CONSTANT
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = wb.render(_sphere(MATERIALS[name], env, width=32, height=24), backend=backend, aa=1).image
        b = wb.render(_sphere(MATERIALS[name], env, width=32, height=24), method="mc", samples=256,
                      backend=backend).image
    assert np.isfinite(a).all() and a.min() >= 0
    cam = _sphere(MATERIALS[name], env, width=32, height=24).camera
    hit = (backend.trace_primary(SPHERE, cam).face >= 0).reshape(b.shape[:2])
    c = wb.compare_images(a, b, mask=hit)
    assert c["psnr"] > psnr and c["mean_rel"] < mean_rel, c


def test_isotropic_limit_is_the_isotropic_ward(backend):
    """αx = αy: the ASG path (warp of an ASG, Eq. 10 integral) gives the isotropic Ward's SG path's image."""
    env = wb.Environment.sky(height=32, width=64)
    lights = [wb.PointLight((2.0, 2.0, 2.0), 8.0, 0.1)]
    iso = wb.render(_sphere(wb.AnisotropicWard(0.6, 0.2, 0.2, kd=0.2), env, lights, 32, 24), backend=backend,
                    aa=1).image
    ward = wb.render(_sphere(wb.Ward(0.6, 0.2, kd=0.2), env, lights, 32, 24), backend=backend, aa=1).image
    c = wb.compare_images(iso, ward)
    assert c["psnr"] > 40, c


def test_textured_anisotropic_material_is_refused():
    """The texture maps scale an isotropic BRDF's parameters only: an anisotropic one under maps is refused in
    one line, naming it."""
    from warp_biscale.svbrdf import Textured

    with pytest.raises(ValueError, match=r"\(AnisotropicWard\) is anisotropic: .*textured") as err:
        textured = Textured(MATERIALS["ward"], kd_map=np.ones((2, 2, 3)))
        wb.render(_sphere(textured, lights=[wb.DirectionalLight((0, 0, 1), 1.0)], width=8, height=8),
                  backend="warp:cpu")
    assert "\n" not in str(err.value)


def test_opencl_taps_are_the_references():
    """cl/shade.cl writes the anisotropic lookup's rules out (`shading.asg_prefiltered`; kernels/shade.py takes them
    from `shading`): the same nodes, weights and gaps, to float32, and the same constants."""
    import re
    from importlib import resources

    from warp_biscale import cl as cl_sources
    from warp_biscale import shading

    text = resources.files(cl_sources).joinpath("shade.cl").read_text()
    for name, want in (("HERMITE_NODES", shading._HERMITE_NODES), ("HERMITE_WEIGHTS", shading._HERMITE_WEIGHTS),
                       ("HERMITE_GAPS", shading._HERMITE_GAPS)):
        body = re.search(name + r"\[\d+\] = \{([^}]*)\}", text).group(1)
        got = np.array([float(v.strip().rstrip("f")) for v in body.split(",")])
        np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9)
    for name in ("ASG_TAPS", "ASG_TAP_SHARE", "TAP_SPAN", "TAP_GAP", "ROUND_SPREAD"):
        value = float(re.search(r"#define " + name + r" ([0-9.e+-]+)f? ", text).group(1))
        assert value == pytest.approx(getattr(shading, name), rel=1e-7), name


def test_tap_plan_keeps_taps_close_and_the_variance():
    """`shading.tap_plan`: neighbouring taps at most TAP_GAP tap deviations apart below ASG_TAPS, as few as that
    allows (one lookup only for a near-round lobe), and every rule's variance that of the spread it stands for
    (Gauss–Hermite: exactly; the even comb over ±TAP_SPAN: its truncation's, within 4 %)."""
    from warp_biscale import shading

    ratio = np.concatenate([np.linspace(0.0, 4.4, 441), [0.25, 1.0, 1.5013438]])
    count, even = shading.tap_plan(ratio)
    for r, n, ev in zip(ratio, count, even):
        nodes, weights = shading.tap_rule(int(n), bool(ev))
        assert len(nodes) == n and weights.sum() == pytest.approx(1.0, abs=1e-12)
        if n == 1:
            assert r <= shading.ROUND_SPREAD
            continue
        if n < shading.ASG_TAPS:  # (ASG_TAPS even taps span the longest lobes a little more thinly)
            assert np.diff(nodes).max() * r <= shading.TAP_GAP + 1e-12, (r, n, ev)
        variance = float((weights * nodes**2).sum())
        assert variance == pytest.approx(1.0, rel=1e-12 if not ev else 0.04), (r, n, ev)
        if ev and n < shading.ASG_TAPS:  # one fewer even tap would have left too wide a gap
            assert 2 * shading.TAP_SPAN / (n - 2) * r > shading.TAP_GAP
    assert count.max() == shading.ASG_TAPS and count[ratio > 0.25].min() == 2
