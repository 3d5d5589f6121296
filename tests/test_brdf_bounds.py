"""No small-scale BRDF lobe sharper than the SG and ASG forms hold (sg.SHARPNESS_MAX): each bound derived from it
through the parameter's own SG or ASG (`sg.specular_lobe`, `brdf.ndf_bandwidths`), refused in one line at
construction (and in a `Textured` parameter map that scales the parameter past it), and what a user meets at the
bound itself: finite, non-negative images from the SG renderer and the Monte Carlo reference that agree.

Before these bounds, BlinnPhong(exponent=1e18) rendered 157 in SG against 0.50 in Monte Carlo,
AshikhminShirley(nu=nv=1e20) rendered black (its diffuse too) and exponent 1e39 failed late with "a kernel
produced 768 non-finite effective-BRDF values"."""

import math

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import brdf as B
from warp_biscale import sg
from warp_biscale.svbrdf import Textured

Z = [[0.0, 0.0, 1.0]]


def test_each_bound_is_where_its_lobe_reaches_the_sharpness_max():
    """Through the mappings the bakes and renderers use: Blinn–Phong η = n, Cook–Torrance and Ward η = 2/m², 2/α²
    (`sg.specular_lobe`); the anisotropic models' ASG bandwidths (`ndf_bandwidths`) are read as SG sharpness 2λ,
    so they stop at SHARPNESS_MAX/2. Equal to the last bits of the square root's rounding (1e-12 relative)."""
    at = {B.BlinnPhong(0.2, B.BLINN_PHONG_EXPONENT_MAX): sg.SHARPNESS_MAX,
          B.CookTorrance(1.0, B.COOK_TORRANCE_ROUGHNESS_MIN): sg.SHARPNESS_MAX,
          B.Ward(1.0, B.WARD_ALPHA_MIN): sg.SHARPNESS_MAX}
    for brdf, eta in at.items():
        assert sg.specular_lobe(brdf, Z, Z)[0] == pytest.approx(eta, rel=1e-12)
    a = B.ANISOTROPIC_WARD_ALPHA_MIN
    n = B.ASHIKHMIN_SHIRLEY_EXPONENT_MAX
    for brdf in (B.AnisotropicWard(1.0, a, a), B.AshikhminShirley(1.0, n, n)):
        assert [2 * x for x in brdf.ndf_bandwidths] == pytest.approx([sg.SHARPNESS_MAX] * 2, rel=1e-12)
    # the isotropic cases of the anisotropic models get their isotropic twins' bounds
    assert B.ANISOTROPIC_WARD_ALPHA_MIN == B.WARD_ALPHA_MIN
    assert B.ASHIKHMIN_SHIRLEY_EXPONENT_MAX == B.BLINN_PHONG_EXPONENT_MAX


PAST = [  # the user's values, and a value just past each bound
    (lambda: B.BlinnPhong(0.5, 1e18), "BlinnPhong.exponent must be <= 1e+06, got 1e+18"),
    (lambda: B.BlinnPhong(0.5, 1e39), "BlinnPhong.exponent must be <= 1e+06"),
    (lambda: B.BlinnPhong(0.5, B.BLINN_PHONG_EXPONENT_MAX * 1.001), "BlinnPhong.exponent must be <= 1e+06"),
    (lambda: B.CookTorrance(0.5, 1e-10), "CookTorrance.roughness must be >= 0.001414, got 1e-10"),
    (lambda: B.CookTorrance(0.5, B.COOK_TORRANCE_ROUGHNESS_MIN * 0.999), "CookTorrance.roughness must be >= 0.001414"),
    (lambda: B.Ward(0.5, 1e-9), "Ward.alpha must be >= 0.001414, got 1e-09"),
    (lambda: B.Ward(0.5, 1e-11), "Ward.alpha must be >= 0.001414"),
    (lambda: B.AnisotropicWard(0.5, 1e-9, 0.2), "AnisotropicWard.alpha_x must be >= 0.001414, got 1e-09"),
    (lambda: B.AnisotropicWard(0.5, 0.2, B.ANISOTROPIC_WARD_ALPHA_MIN * 0.999), "AnisotropicWard.alpha_y must be >="),
    (lambda: B.AshikhminShirley(0.5, 1e20, 1e20), "AshikhminShirley.nu must be <= 1e+06, got 1e+20"),
    (lambda: B.AshikhminShirley(0.5, 100.0, 2e6), "AshikhminShirley.nv must be <= 1e+06, got 2000000.0"),
    (lambda: B.parse_brdf("blinnphong:exponent=1e7"), "BlinnPhong.exponent must be <= 1e+06"),
    (lambda: B.parse_brdf("as:nu=10,nv=1e9"), "AshikhminShirley.nv must be <= 1e+06"),
    (lambda: B.parse_brdf("ward:alpha_x=0.1,alpha_y=1e-5"), "AnisotropicWard.alpha_y must be >= 0.001414"),
    # the bounds come after the old checks: a non-positive or non-finite value is still said as before
    (lambda: B.BlinnPhong(0.5, math.inf), "BlinnPhong.exponent must be a finite number > 0, got inf"),
    (lambda: B.Ward(0.5, 0.0), "Ward.alpha must be a finite number > 0, got 0.0"),
]


@pytest.mark.parametrize("make, words", PAST, ids=[w for _, w in PAST])
def test_a_lobe_sharper_than_the_sg_forms_hold_is_refused_in_one_line(make, words):
    with pytest.raises(ValueError) as info:
        make()
    message = str(info.value)
    assert words in message and "\n" not in message
    if "must be <=" in message or "must be >=" in message:
        assert "sharper lobe than the SG and ASG forms hold" in message


def test_the_bounds_themselves_are_taken():
    a, n = B.WARD_ALPHA_MIN, B.BLINN_PHONG_EXPONENT_MAX
    assert B.BlinnPhong(0.2, n).exponent == n
    assert B.CookTorrance(0.5, B.COOK_TORRANCE_ROUGHNESS_MIN).roughness == B.COOK_TORRANCE_ROUGHNESS_MIN
    assert B.Ward(0.5, a).alpha == a
    assert B.AnisotropicWard(0.5, a, a).alpha_y == a
    assert B.AshikhminShirley(0.5, n, n).nv == n


@pytest.mark.parametrize("brdf, factor, words", [
    # a parameter map of 3e32 / 64 makes the user's exponent 3e32
    (B.BlinnPhong(0.2, 64.0), 3e32 / 64, "Textured.parameter_map reaches 4.6875e+30: it scales BlinnPhong.exponent 64"
                                         " to 3e+32, which must be <= 1e+06"),
    (B.BlinnPhong(0.2, 64.0), 1.001e6 / 64, "Textured.parameter_map reaches 15640.6"),
    (B.CookTorrance(0.5, 0.2), 1e-5, "Textured.parameter_map reaches 1e-05: it scales CookTorrance.roughness 0.2 to "
                                     "2e-06, which must be >= 0.001414"),
    (B.Ward(0.5, 0.3), 0.004, "Textured.parameter_map reaches 0.004: it scales Ward.alpha 0.3 to 0.0012"),
])
def test_a_parameter_map_past_the_bound_is_refused_naming_its_extreme(brdf, factor, words):
    """The kernels interpolate the map bilinearly, so the scaled parameter lies between the BRDF's times the map's
    extremes: those are checked (here beside a texel of 1)."""
    with pytest.raises(ValueError) as info:
        Textured(brdf, parameter_map=np.array([[1.0, factor], [1.0, 1.0]]))
    assert words in str(info.value) and "\n" not in str(info.value)


def test_a_parameter_map_up_to_the_bound_is_taken():
    Textured(B.BlinnPhong(0.2, 64.0), parameter_map=np.array([[0.5, 1e6 / 64]]))
    Textured(B.CookTorrance(0.5, 0.2), parameter_map=np.array([[B.COOK_TORRANCE_ROUGHNESS_MIN / 0.2 * 1.0001, 5.0]]))
    Textured(B.Lambert(0.5), kd_map=np.ones((2, 2, 3)))


AT_THE_BOUND = [
    B.BlinnPhong(0.15, B.BLINN_PHONG_EXPONENT_MAX, kd=0.3),  # (ks 0.15: Blinn–Phong's albedo is up to 4·ks)
    B.CookTorrance(0.5, B.COOK_TORRANCE_ROUGHNESS_MIN, f0=0.9, kd=0.3),
    B.Ward(0.5, B.WARD_ALPHA_MIN, kd=0.3),
    B.AnisotropicWard(0.5, B.ANISOTROPIC_WARD_ALPHA_MIN, B.ANISOTROPIC_WARD_ALPHA_MIN, kd=0.3),
    B.AshikhminShirley(0.5, B.ASHIKHMIN_SHIRLEY_EXPONENT_MAX, B.ASHIKHMIN_SHIRLEY_EXPONENT_MAX, rd=0.3),
    Textured(B.BlinnPhong(0.15, 1e4, kd=0.3), parameter_map=np.array([[1.0, 100.0], [50.0, 0.5]])),
]


@pytest.mark.parametrize("material", AT_THE_BOUND, ids=lambda m: repr(m)[:40])
def test_a_lobe_at_the_bound_renders_as_the_monte_carlo_reference(material):
    """A sphere of the sharpest lobe each model takes, under a constant environment: the SG renderer's image and the
    Monte Carlo reference's are finite, non-negative and never black on the sphere (AshikhminShirley at nu = nv =
    1e20 was black there, its diffuse too), and their means over the sphere agree within 3 %: the SG renderer's
    analytic rows are exact under a constant environment (`shading.specular_correction`); measured here (64 × 48,
    64 samples a pixel) they agree within 0.13 % for each untextured model and 1.4 % for the textured one: the
    reference's noise (0.02 % at 1024 samples a pixel)."""
    mesh = wb.Mesh.sphere(radius=0.6, subdivisions=3)
    scene = wb.Scene(mesh, [material], wb.Camera(eye=(0.0, 0.6, 2.2), target=(0.0, 0.0, 0.0), width=64, height=48,
                                                 fov=50), wb.Environment.constant(1.0))
    sg_image = wb.render(scene, method="sg", backend="warp:cpu").image
    mc_image = wb.render(scene, method="mc", samples=64, backend="warp:cpu", seed=1).image
    on_sphere = mc_image.sum(-1) != 1.0 * 3  # (the background shows the environment's constant 1)
    assert on_sphere.sum() > 500
    for image in (sg_image, mc_image):
        assert np.isfinite(image).all() and (image >= 0).all()
        assert (image[on_sphere].sum(-1) > 0).all()
    assert sg_image[on_sphere].mean() == pytest.approx(mc_image[on_sphere].mean(), rel=0.03)
