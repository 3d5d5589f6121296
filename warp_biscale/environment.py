"""Distant environment lighting as an equirectangular radiance map (Wang 2009 §6).

Convention (world +y up): texel (row i, column j) of an H×W map is centred on
θ = π(i + ½)/H (polar angle from +y) and φ = 2π(j + ½)/W, with direction
d = (sin θ cos φ, cos θ, sin θ sin φ). Row 0 is the zenith side. `lookup` is bilinear in (θ, φ),
wrapping in φ and clamping in θ.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from .images import read_image, write_exr, write_hdr
from .io import check_output

__all__ = ["Environment", "Softbox", "equirect_directions", "direction_to_equirect", "equirect_bilinear",
           "equirect_row_solid_angles", "sun_profile", "sun_integrals"]


def equirect_directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) float64 unit directions of the texel centres."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    st = np.sin(theta)[:, None]
    return np.stack([st * np.cos(phi)[None], np.broadcast_to(np.cos(theta)[:, None], (height, width)),
                     st * np.sin(phi)[None]], -1)


def direction_to_equirect(d: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous texel coordinates (row, column) of unit directions d (..., 3): texel centres at
    integers, so row = θH/π − ½, column = φW/(2π) − ½ with φ in [0, 2π)."""
    d = np.asarray(d, np.float64)
    theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
    phi = np.mod(np.arctan2(d[..., 2], d[..., 0]), 2 * np.pi)
    return theta * height / np.pi - 0.5, phi * width / (2 * np.pi) - 0.5


def equirect_row_solid_angles(height: int, width: int) -> np.ndarray:
    """(height,) float64 exact solid angle of one texel of each row: (cos θ0 − cos θ1)·2π/W."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (edges[:-1] - edges[1:]) * 2 * np.pi / width


def equirect_bilinear(image, d) -> np.ndarray:
    """(..., 3) float64 bilinear samples of an (h, w, 3) equirect image in unit directions d (..., 3):
    texel centres at integer coordinates (`direction_to_equirect`), φ wraps, θ clamps."""
    image = np.asarray(image, np.float64)
    h, w = image.shape[:2]
    row, col = direction_to_equirect(d, h, w)
    r0 = np.floor(row)
    c0 = np.floor(col)
    fr = row - r0
    fc = col - c0
    r0 = r0.astype(np.int64)
    c0 = c0.astype(np.int64)
    out = 0.0
    for dr, wr in ((0, 1 - fr), (1, fr)):
        rr = np.clip(r0 + dr, 0, h - 1)
        for dc, wc in ((0, 1 - fc), (1, fc)):
            out = out + (wr * wc)[..., None] * image[rr, np.mod(c0 + dc, w)]
    return out


RADIANCE_MAX = 1e16  # a texel's radiance: times the solid angle of a source's few texels, a light under 1e20


def _softbox(i: int, box):
    """A studio light given as a Softbox, or as its fields (a tuple or a dict), named by its place when they are not
    a Softbox's."""
    if isinstance(box, Softbox):
        return box
    try:
        return Softbox(**box) if isinstance(box, dict) else Softbox(*box)
    except TypeError as exc:
        raise ValueError(f"Environment.studio light #{i + 1}: {exc} (a Softbox: direction, half_width, half_height, "
                         f"radiance)") from None


@dataclass(eq=False)
class Environment:
    """An equirectangular radiance map, (H, W, 3) float32, finite and >= 0."""

    radiance: np.ndarray
    name: str = "environment"
    device_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        r = np.asarray(self.radiance, np.float32)
        if r.ndim != 3 or r.shape[2] != 3 or r.shape[0] < 2 or r.shape[1] < 2:
            raise ValueError(f"Environment.radiance must be an (H, W, 3) array with H, W >= 2, got {r.shape}")
        if not np.all(np.isfinite(r)):
            raise ValueError(f"Environment {self.name!r} holds NaN or inf radiance")
        if (r < 0).any():
            raise ValueError(f"Environment {self.name!r} holds negative radiance (min {float(r.min())})")
        if r.max() > RADIANCE_MAX:  # (its sources become lights, of at most scene.LIGHT_POWER_MAX)
            raise ValueError(f"Environment {self.name!r} holds radiance up to {float(r.max()):.3g}: the renderers, in "
                             f"float32, take at most {RADIANCE_MAX:g} (scale the map down)")
        self.radiance = np.ascontiguousarray(r)

    def __repr__(self):  # (the map's size and range, not its every texel)
        return (f"Environment({self.name!r}, {self.height}×{self.width}, radiance {float(self.radiance.min()):.4g}"
                f"…{float(self.radiance.max()):.4g})")

    @property
    def height(self) -> int:
        return self.radiance.shape[0]

    @property
    def width(self) -> int:
        return self.radiance.shape[1]

    def directions(self) -> np.ndarray:
        return equirect_directions(self.height, self.width)

    def solid_angles(self) -> np.ndarray:
        """(H, W) float64 exact solid angle of each texel: (cos θ0 − cos θ1)·2π/W."""
        return np.broadcast_to(equirect_row_solid_angles(self.height, self.width)[:, None],
                               (self.height, self.width)).copy()

    def lookup(self, d) -> np.ndarray:
        """(..., 3) float64 bilinear radiance in unit directions d (..., 3)."""
        return equirect_bilinear(self.radiance, d)

    def power(self) -> np.ndarray:
        """∫L dω (RGB), exact for the texel-constant map."""
        return np.einsum("hw,hwc->c", self.solid_angles(), self.radiance.astype(np.float64))

    # -----------------------------------------------------------------------------------------
    # Files and procedural maps. Everything below is deterministic and needs no download.

    @classmethod
    def from_file(cls, path, name: str | None = None) -> Environment:
        """Load an equirectangular map (.exr, .hdr/.pic, .png/.jpg as sRGB, .npy) in this module's
        convention (row 0 = zenith, column j at φ = 2π(j + ½)/W). Non-finite or negative radiance is a
        ValueError naming the file."""

        path = os.fspath(path)
        img = read_image(path)
        bad = ~np.isfinite(img)
        if bad.any():
            raise ValueError(f"environment file {path} holds {int(bad.sum())} NaN/inf value(s)")
        if (img < 0).any():
            raise ValueError(f"environment file {path} holds negative radiance (min {float(img.min())})")
        if img.shape[0] < 2 or img.shape[1] < 2:
            raise ValueError(f"environment file {path} is {img.shape[0]} x {img.shape[1]}; need at least 2 x 2")
        if img.shape[1] != 2 * img.shape[0]:  # a cube-map cross or a mirror-ball probe read as latitude-longitude
            warnings.warn(f"environment file {path} is {img.shape[1]} x {img.shape[0]} pixels, not 2:1: it is read as "
                          "an equirectangular (latitude-longitude) map, so a cube map or light probe comes out "
                          "scrambled and other shapes stretched", stacklevel=2)
        return cls(img, name=name if name is not None else os.path.splitext(os.path.basename(path))[0])

    def save(self, path) -> None:
        """Write the radiance map as float32 EXR (.exr) or Radiance RGBE (.hdr/.pic), atomically."""

        ext = os.path.splitext(os.fspath(path))[1].lower()
        if ext not in (".exr", ".hdr", ".pic"):
            raise ValueError(f"Environment.save: {os.fspath(path)} must end in .exr, .hdr or .pic")
        check_output(path, what="Environment.save:")  # a folder, or a parent that is a file: one line, not OSError
        if ext == ".exr":
            write_exr(path, self.radiance)
        else:
            write_hdr(path, self.radiance)

    @classmethod
    def constant(cls, radiance=1.0, height: int = 32, width: int = 64, name: str = "constant") -> Environment:
        """Uniform radiance (scalar or RGB) in every direction; its power is 4π·radiance."""
        _check_size(height, width)
        rgb = _rgb(radiance, "Environment.constant radiance")
        return cls(np.broadcast_to(rgb, (height, width, 3)).astype(np.float32), name=name)

    @classmethod
    def sky(cls, sun_direction=(0.4, 0.8, 0.3), sun_angular_radius: float = 2.0, sun_radiance=None,
            sun_irradiance=None, sky_zenith=(0.08, 0.18, 0.45), sky_horizon=(0.55, 0.6, 0.65),
            ground=(0.06, 0.055, 0.05), height: int = 128, width: int = 256, *, sun_edge: float = 0.2,
            supersample: int = 4, name: str = "sky") -> Environment:
        """A simple analytic daylight: gradient sky, dim ground, and a sun disk with a soft edge.

        Sky (d_y > 0): L = zenith + (horizon − zenith)·(1 − d_y)³ — blue overhead, bright at the
        horizon. Ground (d_y <= 0): the constant `ground`. The sun is added on top of both (it is not
        occluded by the ground), radially symmetric about `sun_direction` with profile
        `sun_profile(γ, radius, sun_edge)`: 1 in the core, 0 outside, falling by a smoothstep over an
        angular band sun_edge·radius wide centred on `sun_angular_radius` (degrees; the half-intensity
        radius).

        The sun's brightness is given either as its disk radiance `sun_radiance` (RGB, the profile's
        peak) or — the default — as `sun_irradiance`: the irradiance E = ∫ L_sun cos γ dω it delivers
        to a surface facing it, default (3.0, 2.9, 2.6); the disk radiance is E / ∫ profile·cos γ dω, so
        E stays put when the radius changes. (For comparison, the default sky alone gives an upward-facing
        surface E = π·zenith + π(horizon − zenith)/10 ≈ (0.40, 0.70, 1.48).)

        Texels are averaged over supersample² equal-solid-angle sub-cells (anti-aliasing the horizon),
        and texels near the sun over as many as needed to put ~16 sub-samples across the sun's radius
        (up to 128²), then scaled so that they hold the sun's power exactly (a sun too small for those
        sub-samples to meet lies in the texel of its centre), so a sun smaller than a texel still has the
        right power at any resolution.
        All radiances are RGB (or scalars, meaning grey), in the caller's units.
        """
        _check_size(height, width)
        sun = _unit(sun_direction, "Environment.sky sun_direction")
        alpha = np.radians(float(sun_angular_radius))
        edge = float(sun_edge)
        if not (0.0 <= edge <= 1.0):
            raise ValueError(f"Environment.sky sun_edge must be in [0, 1], got {sun_edge}")
        if not (0.0 < alpha and alpha * (1 + edge / 2) <= np.radians(45.0)):
            raise ValueError(f"Environment.sky sun_angular_radius must be in (0°, ~40°], got {sun_angular_radius}")
        if sun_radiance is not None and sun_irradiance is not None:
            raise ValueError("Environment.sky: give sun_radiance or sun_irradiance, not both")
        if sun_radiance is not None:
            l_sun = _rgb(sun_radiance, "Environment.sky sun_radiance")
        else:
            e_sun = _rgb((3.0, 2.9, 2.6) if sun_irradiance is None else sun_irradiance,
                         "Environment.sky sun_irradiance")
            l_sun = e_sun / sun_integrals(alpha, edge)[1]
        zen = _rgb(sky_zenith, "Environment.sky sky_zenith")
        hor = _rgb(sky_horizon, "Environment.sky sky_horizon")
        gnd = _rgb(ground, "Environment.sky ground")
        n = _supersample(supersample)

        def sky_fn(d):
            y = d[..., 1:2]
            return np.where(y > 0, zen + (hor - zen) * (1.0 - np.clip(y, 0.0, 1.0)) ** 3, gnd)

        rad = _rasterize(sky_fn, height, width, n)
        if np.any(l_sun > 0):
            def sun_fn(d):
                gamma = np.arccos(np.clip(d @ sun, -1.0, 1.0))
                return sun_profile(gamma, alpha, edge)[..., None] * l_sun

            # Texels whose centre is within the sun's outer radius + one texel span (the largest angle
            # between two points of a texel is < π/H + 2π/W) are the only ones the sun can touch.
            span = np.pi / height + 2 * np.pi / width
            centre_angle = np.arccos(np.clip(equirect_directions(height, width) @ sun, -1.0, 1.0))
            near = centre_angle <= alpha * (1 + edge / 2) + span
            rows, cols = np.nonzero(near)
            n_sun = int(np.clip(np.ceil(16 * max(np.pi / height, 2 * np.pi / width) / alpha), n, 128))
            added = _texel_means(sun_fn, rows, cols, height, width, n_sun)
            # The texels then hold the sun's power ∫L dω exactly: 128² sub-samples a texel miss a sun
            # below ~1/100 of a texel (it vanished), and round a few-sample one up or down.
            omega = equirect_row_solid_angles(height, width)[rows]
            power = sun_integrals(alpha, edge)[0] * l_sun
            held = omega @ added
            if np.all(held > 0):
                added *= power / held
            else:  # no sub-sample met the sun: all of it in the texel it is centred in
                added[:] = 0.0
                row = min(int(np.arccos(np.clip(sun[1], -1.0, 1.0)) / np.pi * height), height - 1)
                col = int(np.floor(np.arctan2(sun[2], sun[0]) % (2 * np.pi) / (2 * np.pi) * width)) % width
                here = np.nonzero((rows == row) & (cols == col))[0]
                added[here[0]] = power / omega[here[0]]
            rad[rows, cols] += added
        return cls(rad.astype(np.float32), name=name)

    @classmethod
    def studio(cls, lights=None, background=0.02, height: int = 128, width: int = 256, *,
               supersample: int = 4, name: str = "studio") -> Environment:
        """A dark studio lit by rectangular softboxes: `background` radiance everywhere plus, added on
        top, each `Softbox` (see there). Default lights: a warm key (upper front right), a large dim
        fill (left), a narrow bright rim (behind). Texels are averaged over supersample² equal-area
        sub-cells so box edges are anti-aliased and each box's power is close to radiance × solid angle."""
        _check_size(height, width)
        boxes = DEFAULT_STUDIO_LIGHTS if lights is None else [_softbox(i, b) for i, b in enumerate(lights)]
        bg = _rgb(background, "Environment.studio background")
        n = _supersample(supersample)

        def fn(d):
            out = np.broadcast_to(bg, d.shape).copy()
            for box in boxes:
                out += box.mask(d)[..., None] * box.rgb
            return out

        return cls(_rasterize(fn, height, width, n).astype(np.float32), name=name)

    @classmethod
    def from_sgs(cls, axes, sharpness, amplitudes, constant=0.0, height: int = 128, width: int = 256,
                 name: str = "sg") -> Environment:
        """A sum of spherical Gaussians on a constant, evaluated at texel centres (no supersampling):
        L(d) = constant + Σ_k μ_k·exp(η_k(d·ξ_k − 1)).

        axes (K, 3) (normalised here), sharpness η (K,) > 0, amplitudes μ (K, 3) or (K,) >= 0,
        constant scalar or RGB >= 0."""
        _check_size(height, width)
        xi = np.atleast_2d(np.asarray(axes, np.float64))
        eta = np.atleast_1d(np.asarray(sharpness, np.float64))
        mu = np.asarray(amplitudes, np.float64)
        k = xi.shape[0]
        if xi.shape != (k, 3):
            raise ValueError(f"Environment.from_sgs axes must be (K, 3), got {np.shape(axes)}")
        if mu.ndim == 1:
            mu = np.repeat(mu[:, None], 3, axis=1)
        if eta.shape != (k,) or mu.shape != (k, 3):
            raise ValueError(f"Environment.from_sgs: {k} axes need sharpness (K,) and amplitudes (K,) or (K, 3), "
                             f"got {np.shape(sharpness)} and {np.shape(amplitudes)}")
        for arr, what in ((xi, "axes"), (eta, "sharpness"), (mu, "amplitudes")):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"Environment.from_sgs {what} hold NaN or inf")
        norms = np.linalg.norm(xi, axis=1)
        if (norms < 1e-12).any():
            raise ValueError("Environment.from_sgs axes include a zero vector")
        if (eta <= 0).any():
            raise ValueError(f"Environment.from_sgs sharpness must be > 0, got min {float(eta.min())}")
        if (mu < 0).any():
            raise ValueError(f"Environment.from_sgs amplitudes must be >= 0, got min {float(mu.min())}")
        c = _rgb(constant, "Environment.from_sgs constant")
        d = equirect_directions(height, width)
        xi = xi / norms[:, None]
        rad = np.broadcast_to(c, (height, width, 3)).copy()
        for j in range(k):  # one lobe at a time: (H, W) temporaries, not (H, W, K)
            rad += np.exp(eta[j] * (d @ xi[j] - 1.0))[..., None] * mu[j]  # exponent <= 0: no overflow
        return cls(rad.astype(np.float32), name=name)

    def resized(self, height: int, width: int) -> Environment:
        """This map at another resolution, each axis by an integer factor, preserving power exactly.

        Down: a coarse texel is the solid-angle-weighted mean of the fine texels it covers (its rows'
        edges are edges of the fine rows, so its solid angle is their sum). Up: each fine texel takes
        its coarse texel's value. Either way Σ L·Ω is unchanged (to float32 rounding)."""
        _check_size(height, width)
        h0, w0 = self.height, self.width
        for new, old, axis in ((height, h0, "height"), (width, w0, "width")):
            if not (old % new == 0 or new % old == 0):
                raise ValueError(f"Environment.resized: {axis} {old} -> {new} is not an integer factor")
        rad = self.radiance.astype(np.float64)
        if height < h0:  # rows: weight by each fine row's solid angle
            f = h0 // height
            omega = self.solid_angles()[:, 0]
            rad = (rad * omega[:, None, None]).reshape(height, f, w0, 3).sum(1) / \
                omega.reshape(height, f).sum(1)[:, None, None]
        elif height > h0:
            rad = np.repeat(rad, height // h0, axis=0)
        if width < w0:  # columns of one row all have the same solid angle: a plain mean
            rad = rad.reshape(height, width, w0 // width, 3).mean(2)
        elif width > w0:
            rad = np.repeat(rad, width // w0, axis=1)
        return Environment(rad.astype(np.float32), name=self.name)


@dataclass(frozen=True)
class Softbox:
    """A flat rectangular light seen from the centre: centred on `direction` (world, +y up), with
    angular half-width and half-height in degrees (the rectangle's half-sides are tan of them at unit
    distance; width runs horizontally, along normalize(y × direction), or x when direction is ±y),
    and `radiance` (scalar or RGB). Its solid angle is 4·arcsin(sin a·sin b)."""

    direction: tuple
    half_width: float
    half_height: float
    radiance: object = 1.0

    def __post_init__(self):
        c = _unit(self.direction, "Softbox direction")
        for v, what in ((self.half_width, "half_width"), (self.half_height, "half_height")):
            if not (0.0 < float(v) < 89.0):
                raise ValueError(f"Softbox {what} must be in (0°, 89°), got {v}")
        e1 = np.cross([0.0, 1.0, 0.0], c)
        e1 = e1 / np.linalg.norm(e1) if np.linalg.norm(e1) > 1e-9 else np.array([1.0, 0.0, 0.0])
        object.__setattr__(self, "_frame", (c, e1, np.cross(c, e1)))
        object.__setattr__(self, "rgb", _rgb(self.radiance, "Softbox radiance"))

    @property
    def solid_angle(self) -> float:
        return float(4 * np.arcsin(np.sin(np.radians(self.half_width)) * np.sin(np.radians(self.half_height))))

    def mask(self, d: np.ndarray) -> np.ndarray:
        """(...) float64: 1 where unit directions d (..., 3) see the rectangle, else 0."""
        c, e1, e2 = self._frame
        dc = d @ c
        inside = (dc > 0) & (np.abs(d @ e1) <= np.tan(np.radians(self.half_width)) * dc) & \
                 (np.abs(d @ e2) <= np.tan(np.radians(self.half_height)) * dc)
        return inside.astype(np.float64)


def sun_profile(gamma, radius: float, edge: float = 0.2) -> np.ndarray:
    """Relative sun radiance at angle gamma (radians) from the sun's centre: 1 for γ <= r(1 − e/2),
    0 for γ >= r(1 + e/2), a smoothstep between (r = radius in radians, e = edge as a fraction of r;
    e = 0 is a hard disk). Half intensity at γ = r."""
    gamma = np.asarray(gamma, np.float64)
    if edge <= 0:
        return (gamma <= radius).astype(np.float64)
    t = np.clip((gamma - radius * (1 - edge / 2)) / (radius * edge), 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def sun_integrals(radius: float, edge: float = 0.2) -> tuple[float, float]:
    """(∫ profile dω, ∫ profile·cos γ dω) over the sphere for `sun_profile` (radians, radius·(1 + e/2)
    < π/2): the sun's power and its normal-incidence irradiance per unit disk radiance. The flat
    core is in closed form, the smoothstep ring by 64-point Gauss–Legendre (exact to rounding:
    the integrand is a cubic times sin/cos on a short interval)."""
    a, b = radius * (1 - edge / 2), radius * (1 + edge / 2)
    power = 4 * np.pi * np.sin(a / 2) ** 2  # 2π(1 − cos a), without its cancellation for a tiny sun
    irr = np.pi * np.sin(a) ** 2
    if b > a:
        x, w = np.polynomial.legendre.leggauss(64)
        g = 0.5 * (b - a) * x + 0.5 * (a + b)
        s = sun_profile(g, radius, edge) * np.sin(g) * 0.5 * (b - a) * w
        power += 2 * np.pi * float(np.sum(s))
        irr += 2 * np.pi * float(np.sum(s * np.cos(g)))
    return float(power), float(irr)


# ---------------------------------------------------------------------------------------------
# helpers for the procedural maps


SIZE_MAX = (8192, 16384)  # a procedural map's largest height × width (1.6 GB of float32 radiance)


def _check_size(height, width) -> None:
    if int(height) != height or int(width) != width or height < 2 or width < 2:
        raise ValueError(f"environment size must be integers >= 2, got {height} x {width}")
    if height > SIZE_MAX[0] or width > SIZE_MAX[1]:
        raise ValueError(f"environment size {height} x {width} is past the largest, {SIZE_MAX[0]} x {SIZE_MAX[1]}")


def _rgb(value, what: str) -> np.ndarray:
    """Scalar or RGB → (3,) float64, finite and >= 0, else a ValueError naming `what`."""
    v = np.asarray(value, np.float64)
    if v.ndim == 0:
        v = np.full(3, float(v))
    if v.shape != (3,):
        raise ValueError(f"{what} must be a scalar or an RGB triple, got shape {v.shape}")
    if not np.all(np.isfinite(v)) or (v < 0).any():
        raise ValueError(f"{what} must be finite and >= 0, got {v.tolist()}")
    return v


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-12:
        raise ValueError(f"{what} must be a finite non-zero 3-vector, got {np.asarray(v).tolist()}")
    return v / np.linalg.norm(v)


def _supersample(n) -> int:
    if int(n) != n or not (1 <= n <= 64):
        raise ValueError(f"supersample must be an integer in [1, 64], got {n}")
    return int(n)


def _texel_means(fn, rows, cols, height: int, width: int, n: int) -> np.ndarray:
    """(T, 3) float64 mean of fn over texels (rows[t], cols[t]), each split into n×n sub-cells of equal
    solid angle (n equal steps of cos θ × n equal steps of φ) sampled at their centres in (cos θ, φ).

    fn maps unit directions (..., 3) float64 → radiance (..., 3). Equal-area cells make the plain mean
    an unbiased estimate of the texel's mean radiance, so Σ mean·Ω approximates the power."""
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    k = (np.arange(n) + 0.5) / n
    out = np.empty((len(rows), 3))
    step = max(1, (1 << 20) // (n * n))  # bound the (chunk, n, n, 3) temporaries to ~25 MB
    for s in range(0, len(rows), step):
        r, c = rows[s:s + step], cols[s:s + step]
        c0 = np.cos(np.pi * r / height)
        c1 = np.cos(np.pi * (r + 1) / height)
        cos_t = (c0[:, None] + (c1 - c0)[:, None] * k[None])[:, :, None]  # (T, n, 1)
        phi = (2 * np.pi * (c[:, None] + k[None]) / width)[:, None, :]     # (T, 1, n)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
        d = np.stack(np.broadcast_arrays(sin_t * np.cos(phi), cos_t, sin_t * np.sin(phi)), -1)
        out[s:s + step] = fn(d).mean(axis=(1, 2))
    return out


def _rasterize(fn, height: int, width: int, n: int) -> np.ndarray:
    """(H, W, 3) float64 texel means of fn over the whole map (see `_texel_means`)."""
    rows, cols = np.divmod(np.arange(height * width), width)
    return _texel_means(fn, rows, cols, height, width, n).reshape(height, width, 3)


# Built after the helpers Softbox validates with.
DEFAULT_STUDIO_LIGHTS = (
    Softbox((0.55, 0.55, 0.63), 18.0, 12.0, (5.0, 4.8, 4.4)),  # key: warm, upper front right
    Softbox((-0.85, 0.2, 0.5), 30.0, 20.0, 0.8),                # fill: large and dim, left
    Softbox((-0.1, 0.45, -0.9), 6.0, 25.0, 8.0),                # rim: narrow and bright, behind
)


def environment_irradiance(radiance, normals) -> np.ndarray:
    """(N, 3) E(n) = ∫ L(ω) max(ω·n, 0) dω of an (h, w, 3) equirect map for unit normals (N, 3),
    by the texel-centre rule Σ_t L_t Ω_t max(ω_t·n, 0)."""
    rad = np.asarray(radiance, np.float64)
    h, w = rad.shape[:2]
    weighted = (rad * equirect_row_solid_angles(h, w)[:, None, None]).reshape(-1, 3)
    d = equirect_directions(h, w).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    out = np.empty((len(normals), 3))
    chunk = max(1, (1 << 22) // len(d))
    for a in range(0, len(normals), chunk):
        out[a:a + chunk] = np.maximum(normals[a:a + chunk] @ d.T, 0.0) @ weighted
    return out


NEGLIGIBLE = 1e-7  # G below this is dropped from the prefilter sums
SUPPORT = float(-np.log(NEGLIGIBLE))  # η(1 − ω·p) beyond which G < NEGLIGIBLE (16.118)


def equirect_tables(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The envmap kernels' per-row and per-column tables of an equirect map, float32:
    rows (height, 4) [cos θ, sin θ, θ, Ω] (Ω the solid angle of one texel of the row, sr) and
    columns (width, 3) [cos φ, sin φ, φ], at the texel centres θ = π(i + ½)/H, φ = 2π(j + ½)/W."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    omega = equirect_row_solid_angles(height, width)
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    rows = np.stack([np.cos(theta), np.sin(theta), theta, omega], 1)
    cols = np.stack([np.cos(phi), np.sin(phi), phi], 1)
    return rows.astype(np.float32), cols.astype(np.float32)


