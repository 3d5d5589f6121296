"""Environment maps: the equirect convention, solid angles and power, the procedural maps against
their closed forms (sun and softbox power by analytic integrals), files, resizing, bad inputs."""

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import quad

from warp_biscale import images
from warp_biscale.environment import Environment, Softbox, equirect_directions, sun_profile


# ---------------------------------------------------------------------------------------------
# convention and measure


@pytest.mark.parametrize("i, j", [(0, 0), (3, 11), (7, 5), (15, 31)])
def test_single_bright_texel_is_found_at_its_direction(i, j):
    h, w = 16, 32
    rad = np.zeros((h, w, 3), np.float32)
    rad[i, j] = (5.0, 2.0, 1.0)
    env = Environment(rad)
    # The documented convention, written out here rather than taken from the module.
    theta, phi = math.pi * (i + 0.5) / h, 2 * math.pi * (j + 0.5) / w
    d = np.array([math.sin(theta) * math.cos(phi), math.cos(theta), math.sin(theta) * math.sin(phi)])
    np.testing.assert_allclose(env.directions()[i, j], d, atol=1e-12)
    np.testing.assert_allclose(env.lookup(d), [5.0, 2.0, 1.0], atol=1e-9)
    # Half a texel away (in φ) bilinear lookup gives half the value.
    phi2 = phi + math.pi / w
    d2 = np.array([math.sin(theta) * math.cos(phi2), math.cos(theta), math.sin(theta) * math.sin(phi2)])
    np.testing.assert_allclose(env.lookup(d2), [2.5, 1.0, 0.5], atol=1e-9)


@pytest.mark.parametrize("h, w", [(2, 2), (17, 31), (128, 256)])
def test_solid_angles_sum_to_4pi(h, w):
    env = Environment.constant(1.0, h, w)
    omega = env.solid_angles()
    assert omega.shape == (h, w) and (omega > 0).all()
    assert omega.sum() == pytest.approx(4 * math.pi, rel=1e-12)


def test_constant_power_is_4pi_radiance():
    env = Environment.constant((0.5, 1.0, 2.0), 24, 48)
    assert env.radiance.shape == (24, 48, 3) and env.radiance.dtype == np.float32
    np.testing.assert_allclose(env.power(), 4 * math.pi * np.array([0.5, 1.0, 2.0]), rtol=1e-12)
    np.testing.assert_allclose(env.lookup(np.array([[0, 1, 0], [0.6, 0, 0.8]])), [[0.5, 1, 2]] * 2, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# sky


def sun_analytic(radius_deg, edge=0.2):
    """(∫ profile dω, ∫ profile cos γ dω) by adaptive quadrature of the documented profile."""
    a = math.radians(radius_deg)
    kw = dict(points=[a * (1 - edge / 2), a * (1 + edge / 2)], epsabs=0, epsrel=1e-12, limit=200)
    power = 2 * math.pi * quad(lambda g: sun_profile(g, a, edge) * math.sin(g), 0, 2 * a, **kw)[0]
    irr = 2 * math.pi * quad(lambda g: sun_profile(g, a, edge) * math.sin(g) * math.cos(g), 0, 2 * a, **kw)[0]
    return power, irr


def sun_only(**kw):
    return Environment.sky(sky_zenith=0, sky_horizon=0, ground=0, **kw)


@pytest.mark.parametrize("radius, h, w, direction", [
    (2.0, 128, 256, (0.4, 0.8, 0.3)),   # the default: ~3 texels across
    (0.27, 64, 128, (0.4, 0.8, 0.3)),   # the real sun, a fifth of a texel
    (0.27, 128, 256, (-0.3, 0.2, -0.9)),
    (5.0, 32, 64, (0.0, 1.0, 0.0)),     # on the pole, where texels are thin wedges
    (1.0, 17, 31, (0.9, -0.1, 0.2)),    # odd sizes, below the horizon
    (20.0, 128, 256, (0.1, 0.3, 0.9)),
    (0.01, 128, 256, (0.4, 0.8, 0.3)),  # 1/140 of a texel: 128² sub-samples meet it a few times
    (0.001, 128, 256, (0.4, 0.8, 0.3)),  # none meets it (it vanished): its texel holds it
    (1e-4, 64, 128, (-0.3, -0.2, 0.9)),
])
def test_sky_sun_power_and_irradiance_match_the_analytic_disk(radius, h, w, direction):
    env = sun_only(sun_direction=direction, sun_angular_radius=radius, height=h, width=w)
    power, irr = sun_analytic(radius)
    e_sun = np.array([3.0, 2.9, 2.6])  # the documented default irradiance
    l_sun = e_sun / irr
    np.testing.assert_allclose(env.power(), l_sun * power, rtol=1e-5)  # scaled to it (float32 texels)
    # Irradiance on a surface facing the sun: the stated value.
    s = np.asarray(direction, float) / np.linalg.norm(direction)
    weight = env.solid_angles() * np.maximum(env.directions() @ s, 0)
    np.testing.assert_allclose(np.einsum("hw,hwc->c", weight, env.radiance.astype(float)), e_sun, rtol=0.02)


def test_sky_sun_radiance_hard_disk_and_irradiance_options():
    radius = 3.0
    env = sun_only(sun_angular_radius=radius, sun_radiance=(10.0, 5.0, 1.0), sun_edge=0.0, height=64, width=128)
    disk = 2 * math.pi * (1 - math.cos(math.radians(radius)))  # hard disk: a spherical cap
    np.testing.assert_allclose(env.power(), np.array([10.0, 5.0, 1.0]) * disk, rtol=0.02)
    env = sun_only(sun_irradiance=2.0, height=64, width=128)
    assert env.power()[0] == pytest.approx(env.power()[2], rel=1e-6)  # scalar = grey
    with pytest.raises(ValueError, match="not both"):
        Environment.sky(sun_radiance=1.0, sun_irradiance=1.0)
    assert Environment.sky(sun_irradiance=0).power()[0] < Environment.sky().power()[0]


def test_sky_default_looks_like_a_sky():
    env = Environment.sky()
    r = env.radiance
    assert r.shape == (128, 256, 3) and r.dtype == np.float32
    assert np.isfinite(r).all() and (r >= 0).all()
    zenith, horizon, ground = r[0].mean(0), r[63].mean(0), r[100].mean(0)
    assert zenith[2] > zenith[0]  # blue overhead
    assert horizon.sum() > zenith.sum() > ground.sum()  # bright horizon, dim ground
    # The brightest texel is where the sun is.
    i, j = np.unravel_index(np.argmax(r[..., 0]), r.shape[:2])
    s = np.array([0.4, 0.8, 0.3]) / np.linalg.norm([0.4, 0.8, 0.3])
    assert env.directions()[i, j] @ s > math.cos(math.radians(3))
    # Deterministic.
    np.testing.assert_array_equal(Environment.sky().radiance, r)


def test_sky_sky_part_matches_its_formula():
    zen, hor, gnd = np.array([0.1, 0.2, 0.5]), np.array([0.6, 0.6, 0.7]), np.array([0.05, 0.04, 0.03])
    env = Environment.sky(sun_irradiance=0, sky_zenith=zen, sky_horizon=hor, ground=gnd, height=64, width=8)
    # Power of the documented gradient: 2π ∫_0^1 (zen + (hor − zen)(1 − y)³) dy + 2π·ground.
    want = 2 * math.pi * (zen + (hor - zen) / 4) + 2 * math.pi * gnd
    np.testing.assert_allclose(env.power(), want, rtol=1e-3)


# ---------------------------------------------------------------------------------------------
# studio


def rect_solid_angle(half_w_deg, half_h_deg):
    """A rectangle of half-sides tan(a), tan(b) at unit distance (Van Oosterom–Strackee)."""
    a, b = math.tan(math.radians(half_w_deg)), math.tan(math.radians(half_h_deg))
    return 4 * math.atan(a * b / math.sqrt(1 + a * a + b * b))


def test_studio_finite_nonnegative_and_power():
    env = Environment.studio()
    r = env.radiance
    assert r.shape == (128, 256, 3) and np.isfinite(r).all() and (r >= 0).all()
    assert r.min() == pytest.approx(0.02)  # the dark background
    boxes = [Softbox((0.3, 0.5, 0.8), 15.0, 10.0, 4.0), Softbox((0, 1, 0), 25.0, 25.0, (1.0, 2.0, 3.0))]
    env = Environment.studio(boxes, background=0.01, height=64, width=128)
    want = 0.01 * 4 * math.pi + sum(np.asarray(b.rgb) * rect_solid_angle(b.half_width, b.half_height)
                                    for b in boxes)
    np.testing.assert_allclose(env.power(), want, rtol=0.02)
    assert boxes[0].solid_angle == pytest.approx(rect_solid_angle(15, 10), rel=1e-12)
    # The first box is seen at its centre direction, the background elsewhere.
    d = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    np.testing.assert_allclose(env.lookup(d), 4.01, rtol=1e-6)
    np.testing.assert_allclose(env.lookup(-d), 0.01, rtol=1e-6)


def test_studio_tuples_and_bad_softboxes():
    env = Environment.studio([((1, 0, 0), 10.0, 10.0, 2.0)], height=16, width=32)
    assert env.lookup(np.array([1.0, 0, 0]))[0] > 1.0
    with pytest.raises(ValueError, match="half_width"):
        Softbox((1, 0, 0), 95.0, 10.0)
    with pytest.raises(ValueError, match="Softbox direction"):
        Softbox((0, 0, 0), 10.0, 10.0)
    with pytest.raises(ValueError, match="Softbox radiance"):
        Softbox((1, 0, 0), 10.0, 10.0, -1.0)


# ---------------------------------------------------------------------------------------------
# spherical Gaussians


def test_from_sgs_is_the_formula_at_texel_centres_and_has_the_sg_power():
    axes = np.array([[0.0, 2.0, 0.0], [1.0, 0.2, -0.5]])
    eta = np.array([8.0, 60.0])
    mu = np.array([[1.0, 0.5, 0.25], [3.0, 3.0, 3.0]])
    env = Environment.from_sgs(axes, eta, mu, constant=0.1, height=64, width=128)
    d = equirect_directions(64, 128)
    xi = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    want = 0.1 + sum(np.exp(eta[k] * (d @ xi[k] - 1))[..., None] * mu[k] for k in range(2))
    np.testing.assert_allclose(env.radiance, want, rtol=1e-6)
    # ∫G = 2πμ(1 − e^{−2η})/η (docs/design.md §5); the map's midpoint rule is within 1% at these sharpnesses.
    sg_power = sum(2 * math.pi * mu[k] * -math.expm1(-2 * eta[k]) / eta[k] for k in range(2))
    np.testing.assert_allclose(env.power(), 0.4 * math.pi + sg_power, rtol=0.01)


def test_from_sgs_sharp_lobe_and_scalar_amplitude():
    env = Environment.from_sgs([[0, 0, 1]], [1e6], [2.0], height=16, width=32)  # exponent <= 0: no overflow
    assert np.isfinite(env.radiance).all() and env.radiance.max() <= 2.0


@pytest.mark.parametrize("kwargs, message", [
    (dict(axes=[[0, 0, 0]], sharpness=[1.0], amplitudes=[1.0]), "zero vector"),
    (dict(axes=[[0, 1, 0]], sharpness=[0.0], amplitudes=[1.0]), "sharpness must be > 0"),
    (dict(axes=[[0, 1, 0]], sharpness=[1.0], amplitudes=[-1.0]), "amplitudes must be >= 0"),
    (dict(axes=[[0, 1, 0]], sharpness=[np.nan], amplitudes=[1.0]), "sharpness hold NaN"),
    (dict(axes=[[0, 1]], sharpness=[1.0], amplitudes=[1.0]), "axes must be"),
    (dict(axes=[[0, 1, 0]], sharpness=[1.0, 2.0], amplitudes=[1.0]), "sharpness"),
    (dict(axes=[[0, 1, 0]], sharpness=[1.0], amplitudes=[1.0], constant=-1), "constant"),
])
def test_from_sgs_bad_inputs_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Environment.from_sgs(**kwargs)


# ---------------------------------------------------------------------------------------------
# files


def test_from_file_round_trips(tmp_path):
    env = Environment.sky(height=32, width=64)
    env.save(tmp_path / "sky.exr")
    back = Environment.from_file(tmp_path / "sky.exr")
    assert back.name == "sky"
    np.testing.assert_array_equal(back.radiance, env.radiance)
    env.save(tmp_path / "sky.hdr")
    back = Environment.from_file(tmp_path / "sky.hdr", name="daylight")
    assert back.name == "daylight"
    bound = env.radiance.max(-1, keepdims=True) * 2.0 ** -8  # RGBE quantisation
    assert np.all(np.abs(back.radiance - env.radiance) <= bound)
    # An 8-bit sRGB PNG loads as linear radiance.
    images.write_png(tmp_path / "lo.png", np.clip(env.radiance, 0, 1), operator="clamp")
    png = Environment.from_file(tmp_path / "lo.png")
    np.testing.assert_allclose(png.radiance, np.clip(env.radiance, 0, 1), atol=0.01)
    with pytest.raises(ValueError, match=r"\.exr, \.hdr or \.pic"):
        env.save(tmp_path / "sky.png")
    (tmp_path / "folder.exr").mkdir()
    with pytest.raises(ValueError, match=r"^Environment.save: '.*folder.exr' is a directory; give a file name$"):
        env.save(tmp_path / "folder.exr")
    with pytest.raises(ValueError, match=r"^Environment.save: '.*sky.exr/x.exr' cannot be written: .* is a file"):
        env.save(tmp_path / "sky.exr" / "x.exr")


def test_from_file_rejects_bad_radiance_naming_the_file(tmp_path):
    rad = np.ones((8, 16, 3), np.float32)
    rad[2, 3, 0] = np.nan
    np.save(tmp_path / "nan_map.npy", rad)
    with pytest.raises(ValueError, match="nan_map.npy.*NaN"):
        Environment.from_file(tmp_path / "nan_map.npy")
    rad[2, 3, 0] = -0.5
    np.save(tmp_path / "neg_map.npy", rad)
    with pytest.raises(ValueError, match="neg_map.npy.*negative"):
        Environment.from_file(tmp_path / "neg_map.npy")
    (tmp_path / "cut.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n" + bytes(20))
    with pytest.raises(ValueError, match="cut.hdr.*truncated"):
        Environment.from_file(tmp_path / "cut.hdr")
    with pytest.raises(FileNotFoundError):
        Environment.from_file(tmp_path / "missing.exr")


def test_from_file_warns_when_a_map_is_not_two_to_one(tmp_path):
    np.save(tmp_path / "cross.npy", np.ones((12, 16, 3), np.float32))  # a 4:3 cube-map cross's shape
    with pytest.warns(UserWarning, match=r"cross.npy is 16 x 12 pixels, not 2:1: .*equirectangular"):
        env = Environment.from_file(tmp_path / "cross.npy")
    assert env.radiance.shape == (12, 16, 3)  # still loaded: a warning, not a refusal
    np.save(tmp_path / "latlong.npy", np.ones((8, 16, 3), np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Environment.from_file(tmp_path / "latlong.npy")


# ---------------------------------------------------------------------------------------------
# resizing


@pytest.mark.parametrize("h, w", [(32, 64), (16, 16), (64, 128), (8, 512), (256, 512)])
def test_resized_keeps_power(h, w):
    env = Environment.sky(height=64, width=128)
    small = env.resized(h, w)
    assert small.radiance.shape == (h, w, 3)
    np.testing.assert_allclose(small.power(), env.power(), rtol=1e-6)


def test_resized_round_trip_and_bad_factors():
    env = Environment.studio(height=32, width=64)
    # Up then down by the same factor is the identity (each fine texel had the coarse value).
    np.testing.assert_allclose(env.resized(64, 128).resized(32, 64).radiance, env.radiance, rtol=1e-6)
    with pytest.raises(ValueError, match="height 32 -> 24"):
        env.resized(24, 64)
    with pytest.raises(ValueError, match="width"):
        env.resized(32, 48)


# ---------------------------------------------------------------------------------------------
# bad inputs


@pytest.mark.parametrize("make, message", [
    (lambda: Environment.constant(-1.0), "Environment.constant radiance"),
    (lambda: Environment.constant((1, 2)), "Environment.constant radiance"),
    (lambda: Environment.constant(1.0, 1, 8), "size"),
    (lambda: Environment.sky(sun_direction=(0, 0, 0)), "sun_direction"),
    (lambda: Environment.sky(sun_angular_radius=0), "sun_angular_radius"),
    (lambda: Environment.sky(sun_angular_radius=60), "sun_angular_radius"),
    (lambda: Environment.sky(sky_zenith=(np.nan, 0, 0)), "sky_zenith"),
    (lambda: Environment.sky(ground=-0.1), "ground"),
    (lambda: Environment.sky(sun_edge=2), "sun_edge"),
    (lambda: Environment.sky(supersample=0), "supersample"),
    (lambda: Environment.studio(background=-1), "background"),
    (lambda: Environment(np.full((4, 8, 3), np.inf), name="bad"), "'bad' holds NaN or inf"),
])
def test_bad_inputs_are_named(make, message):
    with pytest.raises(ValueError, match=message):
        make()
