"""Environment lighting for the SG renderer (Wang 2009 §6, Iwasaki 2012 §5).

Two representations of one `Environment`, built once by `prepare` and cached on it:

- `EnvironmentSGs` (`fit_sgs`), for the diffuse term: K SG lobes (default 9, as Iwasaki §5 after
  Wang §6). Only the environment's low frequencies matter there, but its energy must be kept and
  its irradiance E(n) = ∫L(ω)(ω·n)⁺dω on every normal is what the diffuse term consumes. So: an
  ambient lobe (η = 1e−3, nearly constant) takes the map's per-channel minimum (a constant map is
  then fitted exactly, to the lobe's 0.1 % variation); spherical EM (the bake's E-step kernel,
  `Backend.ndf_statistics`, on texel directions weighted by luminance × solid angle) places K − 1
  lobes on the rest and gives each the RGB power its responsibilities hold (power exact per
  channel); then the amplitudes are re-solved per channel by non-negative least squares against
  the map's irradiance on 256 normals with the power held exactly (`_refine_amplitudes`: EM is
  driven by luminance, so on the sky it gave the blue zenith the horizon's white, 12.8 % irradiance
  error; refined: 3.2 %). Measured at K = 9, 128×256, max |E_fit − E| over 400 normals / mean E:
  constant 0.07 %, sky (2° sun) 3.2 %, sky (0.5° sun) 3.3 %, studio 0.8 %, from_sgs 0.16 %, one hot
  texel 0.9 %; power error ≤ 1e−15 relative.
- `PrefilteredEnvironment` (`prefilter`), for the specular lobes: Λ(p, η) = ∫G(ω; p, η, 1)L(ω)dω / ∫G,
  the SG-weighted average radiance (Wang Eq. 34–35 divided by ∫G, so that it interpolates well in
  log η), tabulated on levels η_l = 2^(l0 + l), l0 = −3, each an equirect map (environment.py's
  convention) at its own resolution, computed by the envmap stage (`Backend.prefilter_level`).

Packed for the shade kernels (the contract with the renderer): ``maps`` float32 (Σ h_l·w_l, 3), the
levels' texels concatenated row-major, and ``levels`` float32 (n, 4) rows [log2 η_l, offset (index of
the level's first texel), h_l, w_l]; `prefiltered_lookup` (below) is the lookup's semantics.

Level resolution (`level_plan`). A lobe's angular scale is σ = 1/√η (G ≈ exp(−θ²/(2σ²))); level l
has h_l = ⌈s·π·√η_l⌉ rows (row spacing σ/s, s = `TEXELS_PER_SIGMA` = 3), at least `MIN_HEIGHT` = 8,
and columns in the base map's aspect, and is summed from the base map area-averaged (power
preserving, `downsample`) to `INPUT_FACTOR` = 2 times its rows, so every level sees its lobe through
the same number of input texels and costs (its texels) × (a fixed support). Measured on 128×256 maps
(sky with a 2° and a 0.5° sun, studio, one hot texel, noise; lookup vs the float64 Λ of the base map
at 1000 directions, error / max Λ, at the levels' own η, levels below the base rows): s = 2 → ≤ 7 %
away from the poles, ≤ 14 % within 22° of one (the lookup clamps θ above the first row's centre,
an error of first order, ≈ 0.3/s of the peak); s = 3 → ≤ 4.2 % and ≤ 9.3 %; s = 4 → ≤ 2.5 % and
≤ 7 %. Between levels the interpolation linear in log η adds its own ≈ 5 % (a factor 2 in η: for a
point light Λ's peak ∝ η, 1.5 against √2), so s = 3 is where the grid stops being the larger error
(s = 4 costs 1.8× the texels of those levels). `INPUT_FACTOR` 1 / 2 / 3: ≤ 12 / 8.5 / 7 % at
s = 3 for the hot texel, the others alike.

Where the levels stop. Once a level needs the base map's rows it is computed *at* the base
resolution (from the base map itself), and levels continue until a lobe's σ is below half a row
(`STOP_TEXELS_PER_SIGMA` = 0.5); then the base map itself (Λ = L) is the last level, with the nominal
sharpness 2^(l0 + n − 1). Why not stop at the first level that needs the base rows: the base map
resolves features down to its texel (a sun), far sharper than that level's η, so interpolating
towards it over the last octave put the sun's raw radiance into lobes of η ≈ 360 (128 rows): 2× the
true peak of Λ for the 2° sun, 12–24× for a 0.5° sun or a one-texel light (energy is still right,
the shape is not). Continuing to σ = ½ row brings that octave to ≤ 0.37 × (0.5° sun), ≤ 0.13 × for
the others, at 7.4× the base map's texels instead of 2.4× (128×256: 17 levels, η up to 2^12, base
nominal 2^13). Level 0 is always prefiltered, so n ≥ 2 even for a 2×4 map. Offsets are float32 in
`levels`, exact to 2^24 texels: for a map so large that the full plan passes that, the sharpest
base-resolution levels are left out (down to the plain stop rule) rather than failing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

from . import lobes as lobes_mod
from . import sg
from .backend import get_backend
from .environment import (Environment, environment_irradiance, equirect_bilinear, equirect_directions,
                          equirect_row_solid_angles)
from .model import Facets
from .environment import equirect_tables

__all__ = ["EnvironmentSGs", "PrefilteredEnvironment", "EnvironmentLighting", "EnvironmentSources", "fit_sgs",
           "prefilter", "prepare", "environment_sources",
           "downsample", "level_plan", "equirect_tables", "irradiance_map",
           "irradiance_residual"]

LOG2_ETA0 = -3  # the broadest level, η = 1/8: σ ≈ 160°, nearly the whole-sphere average
TEXELS_PER_SIGMA = 3.0  # rows per lobe σ (see the module docstring and tests/test_lighting.py)
STOP_TEXELS_PER_SIGMA = 0.5  # levels at the base resolution continue until σ < ½ row
MIN_HEIGHT = 8  # the broadest levels' rows
INPUT_FACTOR = 2  # a level's input has this many times its rows (capped at the base map's)


MAX_TEXELS = 1 << 24  # `levels` holds texel offsets in float32: exact up to 2^24
# The mark of a last row of `levels` that the background alone reads (η ≥ BACKGROUND_ETA: the camera's rays): the
# map itself where the levels are made from the map without its compact sources, so that no lobe reads a source
# that is also a light (`prepare`, `prefiltered_lookup`).
BACKGROUND_LOG2 = 1.0e30
BACKGROUND_ETA = 1.0e29
AMBIENT_SHARPNESS = sg.SHARPNESS_MIN  # 1e−3: G varies by 0.2 % over the sphere
FIT_HEIGHT = 128  # the SG fit works on the map area-averaged to at most this many rows
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709: the EM weights' scalar radiance


# ----------------------------------------------------------------------------------------------
# Equirect helpers (environment.py's convention)
# ----------------------------------------------------------------------------------------------


def _resample_axis(values, fine_edges, coarse_edges, axis):
    """Integrals of a piecewise-constant function over coarse cells: `values` (…) are the function's
    integrals over the fine cells along `axis` (fine_edges increasing, in the cells' measure); the
    running integral is linear inside each fine cell, so it is interpolated exactly at coarse edges."""
    values = np.moveaxis(values, axis, 0)
    running = np.concatenate([np.zeros((1, *values.shape[1:])), np.cumsum(values, 0)], 0)
    k = np.clip(np.searchsorted(fine_edges, coarse_edges, side="right") - 1, 0, len(fine_edges) - 2)
    frac = (coarse_edges - fine_edges[k]) / (fine_edges[k + 1] - fine_edges[k])
    frac = frac.reshape(-1, *([1] * (values.ndim - 1)))
    at_edges = running[k] + frac * (running[k + 1] - running[k])
    return np.moveaxis(np.diff(at_edges, axis=0), 0, axis)


def downsample(radiance, height: int, width: int) -> np.ndarray:
    """(height, width, 3) float64 area-weighted average of an equirect map (h, w, 3) over each coarse
    texel (any sizes, not only integer factors; partly covered fine texels count by the covered
    solid angle). Power preserving: Σ L Ω over the coarse map equals the fine map's (to rounding)."""
    rad = np.asarray(radiance, np.float64)
    h, w = rad.shape[:2]
    if (height, width) == (h, w):
        return rad.copy()
    # θ: the measure of a row is 1 − cos θ; φ: the measure is φ itself (fractions of the full turn).
    u_fine = 1.0 - np.cos(np.pi * np.arange(h + 1) / h)
    u_coarse = 1.0 - np.cos(np.pi * np.arange(height + 1) / height)
    u_coarse[-1] = u_fine[-1] = 2.0
    rows = _resample_axis(rad * np.diff(u_fine)[:, None, None], u_fine, u_coarse, 0)
    p_fine = np.arange(w + 1) / w
    p_coarse = np.arange(width + 1) / width
    cells = _resample_axis(rows / w, p_fine, p_coarse, 1)
    return cells / (np.diff(u_coarse)[:, None, None] / width)


# ----------------------------------------------------------------------------------------------
# The prefiltered environment (specular lobes)
# ----------------------------------------------------------------------------------------------


def level_plan(height: int, width: int, texels_per_sigma: float = TEXELS_PER_SIGMA,
               min_height: int = MIN_HEIGHT, input_factor: int = INPUT_FACTOR,
               stop_texels_per_sigma: float = STOP_TEXELS_PER_SIGMA) -> list[dict]:
    """The levels of a height×width base map (module docstring): a list of {log2_eta, height, width,
    in_height, in_width}; the last entry is the base map itself (in_height = in_width = 0: nothing to
    compute). stop_texels_per_sigma = texels_per_sigma gives the plain rule (stop at the first level
    that needs the base rows). Levels beyond that rule are dropped while the base map's offset would
    pass `MAX_TEXELS`."""
    plan = _plan(height, width, texels_per_sigma, min_height, input_factor, stop_texels_per_sigma)
    plain = len(_plan(height, width, texels_per_sigma, min_height, input_factor, texels_per_sigma))
    while len(plan) > plain and sum(p["height"] * p["width"] for p in plan[:-1]) > MAX_TEXELS:
        plan = plan[:-2] + [dict(plan[-1], log2_eta=plan[-2]["log2_eta"])]
    return plan


def _plan(height, width, texels_per_sigma, min_height, input_factor, stop):
    plan = []
    l2 = LOG2_ETA0
    while True:
        rows = max(int(min_height), int(np.ceil(texels_per_sigma * np.pi * np.sqrt(2.0**l2))))
        if np.ceil(stop * np.pi * np.sqrt(2.0**l2)) >= height and plan:
            plan.append({"log2_eta": l2, "height": height, "width": width, "in_height": 0, "in_width": 0})
            return plan
        rows = min(rows, height)
        cols = max(2, min(width, int(round(rows * width / height))))
        in_rows = min(height, input_factor * rows)
        in_cols = width if in_rows == height else max(2, min(width, int(round(in_rows * width / height))))
        plan.append({"log2_eta": l2, "height": rows, "width": cols, "in_height": in_rows, "in_width": in_cols})
        l2 += 1


@dataclass(eq=False)
class PrefilteredEnvironment:
    """Λ(p, η) tabulated on n ≥ 2 levels (see the module docstring for the layout).

    maps (Σ h_l·w_l, 3) float32 ≥ 0, levels (n, 4) float32 [log2 η_l, offset, h_l, w_l]; `timings` holds
    each computed level's seconds (backend synchronised)."""

    maps: np.ndarray
    levels: np.ndarray
    timings: list = field(default_factory=list, repr=False)

    def __post_init__(self):
        self.maps = np.ascontiguousarray(self.maps, np.float32)
        self.levels = np.ascontiguousarray(self.levels, np.float32)
        if self.maps.ndim != 2 or self.maps.shape[1] != 3:
            raise ValueError(f"PrefilteredEnvironment.maps must be (N, 3), got {self.maps.shape}")
        if self.levels.ndim != 2 or self.levels.shape[1] != 4 or len(self.levels) < 2:
            raise ValueError(f"PrefilteredEnvironment.levels must be (n >= 2, 4), got {self.levels.shape}")
        sizes = self.levels[:, 2].astype(np.int64) * self.levels[:, 3].astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        lobes = self.levels[:-1] if self.has_background else self.levels
        if (not np.array_equal(self.levels[:, 1].astype(np.int64), offsets) or sizes.sum() != len(self.maps)
                or not np.array_equal(np.diff(lobes[:, 0]), np.ones(len(lobes) - 1)) or len(lobes) < 2):
            raise ValueError("PrefilteredEnvironment.levels must list consecutive log2 η (then, at most, the "
                             "background's marked row) and contiguous offsets that cover maps")
        if not (np.all(np.isfinite(self.maps)) and (self.maps >= 0).all()):
            raise ValueError("PrefilteredEnvironment.maps holds NaN, inf or negative radiance")

    def __len__(self):
        return len(self.levels)

    @property
    def has_background(self) -> bool:
        """Whether the last row is the background's alone (log2 η = BACKGROUND_LOG2: the map itself, where the
        levels are of the map without its sources; `prefiltered_lookup`)."""
        return bool(self.levels[-1, 0] >= BACKGROUND_LOG2)

    @property
    def sharpness(self) -> np.ndarray:
        """(n,) η_l (the last level's, the base map's, is nominal; the background's row, if any, is inf)."""
        with np.errstate(over="ignore"):
            return 2.0 ** self.levels[:, 0].astype(np.float64)

    def level(self, l: int) -> np.ndarray:
        """Level l as an (h_l, w_l, 3) float32 image."""
        _, off, h, w = (int(x) for x in self.levels[l])
        return self.maps[off:off + h * w].reshape(h, w, 3)

    def lookup(self, p, eta) -> np.ndarray:
        """(..., 3) float64 Λ(p, η) for unit p (..., 3) and η (...) (`prefiltered_lookup`)."""
        return prefiltered_lookup(self.maps, self.levels, p, eta)


def prefilter(env: Environment, backend="auto", texels_per_sigma: float = TEXELS_PER_SIGMA,
              min_height: int = MIN_HEIGHT, stop_texels_per_sigma: float = STOP_TEXELS_PER_SIGMA
              ) -> PrefilteredEnvironment:
    """The prefiltered levels of `env` (`level_plan`), each computed by `backend.prefilter_level`."""

    be = get_backend(backend)
    plan = level_plan(env.height, env.width, texels_per_sigma, min_height, INPUT_FACTOR, stop_texels_per_sigma)
    last = sum(p["height"] * p["width"] for p in plan[:-1])
    if last > MAX_TEXELS:
        raise ValueError(f"environment {env.name!r} ({env.height}x{env.width}) is too large: its base map would "
                         f"start at texel {last} of the packed levels, past the {MAX_TEXELS} a float32 offset "
                         "addresses exactly; use env.resized(...) first")
    maps, levels, timings, offset = [], [], [], 0
    inputs = {}  # (in_height, in_width) → downsampled map: two levels share each input
    for p in plan:
        if p["in_height"] == 0:
            level = env.radiance
        else:
            key = (p["in_height"], p["in_width"])
            if key not in inputs:
                inputs[key] = (env.radiance if key == (env.height, env.width)
                               else downsample(env.radiance, *key).astype(np.float32))
            t0 = time.perf_counter()
            level = be.prefilter_level(inputs[key], 2.0 ** p["log2_eta"], p["height"], p["width"])
            be.synchronize()
            timings.append(time.perf_counter() - t0)
        maps.append(level.reshape(-1, 3))
        levels.append([p["log2_eta"], offset, p["height"], p["width"]])
        offset += p["height"] * p["width"]
    return PrefilteredEnvironment(np.concatenate(maps), np.asarray(levels, np.float32), timings)


# ----------------------------------------------------------------------------------------------
# The SG fit (diffuse term)
# ----------------------------------------------------------------------------------------------


@dataclass(eq=False)
class EnvironmentSGs:
    """K SG lobes L(ω) ≈ Σ_k μ_k exp(η_k(ω·ξ_k − 1)): axes ξ (K, 3) unit, sharpness η (K,) > 0,
    amplitude μ (K, 3) RGB radiance ≥ 0. K ≥ 1 (a black map gives one zero-amplitude lobe)."""

    axes: np.ndarray
    sharpness: np.ndarray
    amplitude: np.ndarray
    iterations: int = 0

    def __post_init__(self):
        self.axes = np.asarray(self.axes, np.float64).reshape(-1, 3)
        self.sharpness = np.asarray(self.sharpness, np.float64).reshape(-1)
        self.amplitude = np.asarray(self.amplitude, np.float64).reshape(-1, 3)
        k = len(self.axes)
        if k < 1 or self.sharpness.shape != (k,) or self.amplitude.shape != (k, 3):
            raise ValueError(f"EnvironmentSGs needs K >= 1 lobes with axes (K, 3), sharpness (K,), amplitude "
                             f"(K, 3); got {self.axes.shape}, {self.sharpness.shape}, {self.amplitude.shape}")
        if not (np.all(np.isfinite(self.axes)) and np.all(np.isfinite(self.amplitude))
                and np.all(np.isfinite(self.sharpness)) and (self.sharpness > 0).all() and (self.amplitude >= 0).all()):
            raise ValueError("EnvironmentSGs: axes and amplitudes must be finite, amplitudes >= 0, sharpness > 0")
        self.axes = self.axes / np.linalg.norm(self.axes, axis=1, keepdims=True)

    def __len__(self):
        return len(self.sharpness)

    def packed(self) -> np.ndarray:
        """(K, 7) float32 rows [ξx, ξy, ξz, η, μr, μg, μb] (what the shade kernels read)."""
        return np.concatenate([self.axes, self.sharpness[:, None], self.amplitude], 1).astype(np.float32)

    def evaluate(self, d) -> np.ndarray:
        """(..., 3) float64 radiance of the fit in unit directions d (..., 3)."""
        d = np.asarray(d, np.float64)
        g = sg.evaluate(d[..., None, :], self.axes, self.sharpness)  # (..., K)
        return g @ self.amplitude

    def power(self) -> np.ndarray:
        """(3,) ∫ fit dω = Σ_k μ_k ∫G_k (closed form)."""
        return sg.integral(self.sharpness) @ self.amplitude

    def irradiance(self, normals) -> np.ndarray:
        """(N, 3) ∫ fit(ω) max(ω·n, 0) dω for unit normals (N, 3) (`sg_irradiance`)."""
        return sg_irradiance(self.axes, self.sharpness, self.amplitude, normals)


def _texel_facets(directions, weight):
    """Texel directions as `Facets` (unit normals with areas) for the bake's EM kernel."""

    n = len(directions)
    return Facets(np.zeros((n, 3), np.float32), directions.astype(np.float32), np.zeros(n, np.int32),
                  weight.astype(np.float32), np.zeros(n, np.int32), np.ones((n, 3), np.float32))


def fit_sgs(env: Environment, lobes: int = 9, backend="auto", ambient: bool = True,
            iterations: int = 30, refine: bool = True) -> EnvironmentSGs:
    """K ≤ `lobes` SG lobes for the diffuse term (see the module docstring). Deterministic.

    `lobes` in [1, 16] counts the ambient lobe (present when `ambient` and lobes ≥ 2; always first);
    EM may return fewer lobes than asked when the map has fewer distinct bright regions (a black map
    gives the ambient lobe alone, amplitude 0). The map is first area-averaged to at most
    `FIT_HEIGHT` rows (power kept). EM runs at most `iterations` steps (`lobes.converged` stops it
    earlier). Sharpness: EM sees each texel as a point, so a lobe's sharpness is widened by its
    texel's own spread (1/η ← 1/η + Ω/12, a square texel of solid angle Ω), which caps a one-texel sun
    at the map's resolution instead of η = 10⁶. `refine`: re-solve the amplitudes for irradiance
    (`_refine_amplitudes`); without it they are EM's responsibility-weighted powers over ∫G.
    """

    try:
        k = int(lobes)
    except (TypeError, ValueError):
        k = None
    if k is None or k != lobes or not 1 <= k <= lobes_mod.KERNEL_LOBES:
        raise ValueError(f"lobes must be an integer in [1, {lobes_mod.KERNEL_LOBES}], got {lobes!r}")
    be = get_backend(backend)
    if env.height > FIT_HEIGHT:
        rows = FIT_HEIGHT
        cols = max(2, int(round(rows * env.width / env.height)))
        rad = downsample(env.radiance, rows, cols)
        small = Environment(rad.astype(np.float32), name=env.name)
    else:
        small = env
    rad = small.radiance.astype(np.float64).reshape(-1, 3)
    omega = small.solid_angles().reshape(-1)
    dirs = small.directions().reshape(-1, 3)
    with_ambient = bool(ambient) and k >= 2
    floor = rad.min(axis=0) if with_ambient else np.zeros(3)
    rest = np.maximum(rad - floor, 0.0)
    weight = (rest @ LUMINANCE) * omega
    keep = weight > 0  # every texel with any power left has luminance > 0
    axes, sharp, amp = [], [], []
    if with_ambient:
        axes.append([0.0, 1.0, 0.0])
        sharp.append(AMBIENT_SHARPNESS)
        amp.append(floor * 4 * np.pi / sg.integral(AMBIENT_SHARPNESS))
    steps = 0
    if keep.any():
        scale = weight[keep].sum()
        d = dirs[keep]
        facets = _texel_facets(d, weight[keep] / scale)
        lob = lobes_mod.fit(be, facets, lobes_mod.initial_lobes(d, weight[keep] / scale, k - int(with_ambient)),
                            int(iterations))
        steps = lob.iterations
        # Each lobe's RGB power: the texels' power split by the final lobes' responsibilities (the same
        # E-step kernel with the channel's power as the facet area; responsibilities sum to 1 per texel).
        power = np.stack([be.ndf_statistics(_texel_facets(d, rest[keep, c] * omega[keep] / scale), lob.axes,
                                            lob.sharpness, lob.log_weight)[:, 0] for c in range(3)], 1) * scale
        texel = omega[np.argmax(lob.axes @ dirs.T, axis=1)]  # the solid angle of the texel under each axis
        eta = 1.0 / (1.0 / lob.sharpness + texel / 12.0)
        for j in range(len(lob)):
            axes.append(lob.axes[j])
            sharp.append(eta[j])
            amp.append(np.maximum(power[j], 0.0) / sg.integral(eta[j]))
    if not axes:  # black map, no ambient lobe asked for: one lobe of zero amplitude
        axes, sharp, amp = [[0.0, 1.0, 0.0]], [1.0], [np.zeros(3)]
    axes, sharp, amp = np.asarray(axes, np.float64), np.asarray(sharp, np.float64), np.asarray(amp, np.float64)
    if refine and len(axes) > 1:
        amp = _refine_amplitudes(small, axes, sharp, amp)
    return EnvironmentSGs(axes, sharp, amp, iterations=steps)


def fibonacci_directions(n: int) -> np.ndarray:
    """(n, 3) float64 unit directions spread evenly over the sphere (the Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    y = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - y * y, 0.0))
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], 1)


REFINE_NORMALS = 256


def _refine_amplitudes(env, axes, sharp, amp):
    """Amplitudes re-solved per channel for the irradiance the diffuse term sees: non-negative least
    squares of Σ_k μ_k E_k(n) against the map's E(n) on `REFINE_NORMALS` normals, with the power
    Σ_k μ_k ∫G_k = ∫L held (a heavily weighted row, then an exact rescale)."""

    normals = fibonacci_directions(REFINE_NORMALS)
    target = environment_irradiance(env.radiance, normals)  # (N, 3)
    basis = np.stack([sg_irradiance(a[None], [e], [[1.0, 1.0, 1.0]], normals)[:, 0]
                      for a, e in zip(axes, sharp)], 1)  # (N, K)
    integrals = sg.integral(sharp)
    power = env.power()
    out = amp.copy()
    for c in range(3):
        if power[c] <= 0:
            out[:, c] = 0.0
            continue
        scale = target[:, c].mean()
        rows = np.vstack([basis / scale, 1e3 * integrals[None] / power[c]])
        rhs = np.concatenate([target[:, c] / scale, [1e3]])
        mu = nnls(rows, rhs, maxiter=50 * len(axes))[0]
        total = mu @ integrals
        out[:, c] = mu * (power[c] / total) if total > 0 else amp[:, c]
    return out


# ----------------------------------------------------------------------------------------------
# The exact irradiance (diffuse lighting's scale)
# ----------------------------------------------------------------------------------------------

IRRADIANCE_SHAPE = (32, 64)  # E(n) is smooth: bilinear over 5.6° texels errs by ~0.1 % of E
IRRADIANCE_COARSE = (64, 128)  # the map's smooth remainder is summed at this resolution
IRRADIANCE_BRIGHT = 4096  # the map's most powerful texels are summed one by one, at their own place


def irradiance_map(env: Environment, shape=IRRADIANCE_SHAPE, coarse=IRRADIANCE_COARSE,
                   bright: int = IRRADIANCE_BRIGHT) -> np.ndarray:
    """(H, W, 3) float32 E(n) = ∫L(ω)(ω·n)⁺dω at the texel centres of an equirect grid of normals
    (environment.py's convention): the diffuse term's exact irradiance, which the SG lobes only
    approximate (`shading`). The texel-centre rule of `environment_irradiance` over the whole map,
    made cheap without moving a sun: the `bright` texels of most power are summed where they are,
    the rest of the map area-averaged (power kept) to `coarse` first. Texels of the remainder move by
    at most half a coarse texel, and only smooth light is left there."""
    rad = np.asarray(env.radiance, np.float64)
    h, w = rad.shape[:2]
    normals = equirect_directions(*shape).reshape(-1, 3)
    if h * w <= coarse[0] * coarse[1] + bright:
        return environment_irradiance(rad, normals).reshape(*shape, 3).astype(np.float32)
    flat = rad.reshape(-1, 3)
    omega = np.repeat(equirect_row_solid_angles(h, w), w)
    top = np.argpartition((flat @ LUMINANCE) * omega, -bright)[-bright:]
    rest = flat.copy()
    rest[top] = 0.0
    out = environment_irradiance(downsample(rest.reshape(h, w, 3), *coarse), normals)
    d = equirect_directions(h, w).reshape(-1, 3)[top]
    out += np.maximum(normals @ d.T, 0.0) @ (flat[top] * omega[top, None])
    return np.maximum(out, 0.0).reshape(*shape, 3).astype(np.float32)


SHADOW_LOBE_AXES = np.array([[0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]], np.float64)
SHADOW_LOBE_SHARPNESS = 2.0  # six lobes this broad sum to within ±5 % of a constant


def shadow_lobes(sgs: EnvironmentSGs) -> EnvironmentSGs:
    """The lobes the shade stage shadows: `sgs` with each near-constant (ambient) lobe split into six
    broad lobes along ±x, ±y, ±z of the same power. The SSDF shadows a lobe by the visibility around
    its axis (Wang §5.3), so one lobe for the whole sphere would be shadowed by whatever hides its
    axis; six see six directions. Their sum is not flat, but the shade stage scales the diffuse term
    to the exact irradiance (`irradiance_residual`), so only their shadows count."""
    broad = sgs.sharpness <= 10 * AMBIENT_SHARPNESS
    if not broad.any():
        return sgs
    keep = ~broad
    power = (sg.integral(sgs.sharpness[broad])[:, None] * sgs.amplitude[broad]).sum(0)
    k = len(SHADOW_LOBE_AXES)
    amp = np.tile(power / (k * sg.integral(SHADOW_LOBE_SHARPNESS)), (k, 1))
    return EnvironmentSGs(np.concatenate([SHADOW_LOBE_AXES, sgs.axes[keep]]),
                          np.concatenate([np.full(k, SHADOW_LOBE_SHARPNESS), sgs.sharpness[keep]]),
                          np.concatenate([amp, sgs.amplitude[keep]]), iterations=sgs.iterations)


def irradiance_residual(env: Environment, sgs: EnvironmentSGs, shape=IRRADIANCE_SHAPE, exact=None) -> np.ndarray:
    """(H, W, 3) float32 E(n) − E_sg(n) on `irradiance_map`'s grid of normals: the exact irradiance
    less the SG lobes' (`EnvironmentSGs.irradiance`). The shade stage adds it, bilinearly, to the
    lobes' irradiance at the pixel's normal. A residual rather than E itself because E has a kink
    wherever a small bright source sets (n·ω = 0 at a sun), which bilinear interpolation over 5.6°
    texels blurs by up to 3–4 % of the mean E; the sun's own lobe carries that kink analytically, and
    what is left is smooth (tests/test_env_fidelity.py measures it). `exact`: irradiance_map(env, shape),
    when already computed."""
    normals = equirect_directions(*shape).reshape(-1, 3)
    exact = irradiance_map(env, shape) if exact is None else exact
    exact = np.asarray(exact, np.float64).reshape(-1, 3)
    return (exact - sgs.irradiance(normals)).reshape(*shape, 3).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# Compact bright sources (a sun) as lights
# ----------------------------------------------------------------------------------------------

# A sun reflected in a glossy material is where the environment's specular term erred most: its lobe, warped to the
# light directions and read from the prefiltered maps, is round where the BRDF's image of a small source is not
# (docs/design.md §5.7, "Compact bright sources leave the map as lights"). So texels brighter than SOURCE_CONTRAST
# times the map's mean radiance, in connected groups (with the texels next to them) that a disc of at most
# SOURCE_MAX_RADIUS degrees holds and that carry at least SOURCE_SHARE of its power (the SOURCE_COUNT strongest:
# each light costs its shadow rays in every frame), leave the map and become directional lights, which the renderer
# shades by f_s's mean over the light (`shading.light_mean`) and shadows by rays to its disc. The map without them
# is what the SG fit, the irradiance and the prefiltered maps see; the map itself follows the levels in a row that
# the background alone reads (BACKGROUND_LOG2), so the camera still sees the sun and no lobe reflects it twice.
SOURCE_CONTRAST = 100.0
SOURCE_MAX_RADIUS = 5.0  # degrees
SOURCE_SHARE = 0.05  # of the map's power, at least
SOURCE_COUNT = 2  # at most, the most powerful
# Shadow rays a pixel for a source, at most (the frame's count if fewer): a disc of at most SOURCE_MAX_RADIUS casts a
# narrow penumbra, which this many rays step finely enough (bench/README.md, "An environment's sources with fewer
# shadow rays"), and each ray costs every frame.
SOURCE_SHADOW_SAMPLES = 8


@dataclass(eq=False)
class EnvironmentSources:
    """An environment's compact bright sources (`environment_sources`): `lights` (DirectionalLight each),
    `packed` (K, 8) float32 their Light.packed() rows, and `residual`, the environment without them (the
    environment itself where there are none)."""

    lights: list
    packed: np.ndarray
    residual: Environment


def _label_wrapped(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected components (8-neighbour) of an equirect mask, joined across the φ seam."""
    from scipy import ndimage

    labels, count = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if count:
        parent = np.arange(count + 1)

        def root(a):
            while parent[a] != a:
                a = parent[a]
            return a
        h = mask.shape[0]
        for i in range(h):
            for di in (-1, 0, 1):
                j = i + di
                if 0 <= j < h and labels[i, -1] and labels[j, 0]:
                    a, b = root(labels[i, -1]), root(labels[j, 0])
                    parent[max(a, b)] = min(a, b)
        roots = np.array([root(a) for a in range(count + 1)])
        labels = roots[labels]
        _, labels = np.unique(labels, return_inverse=True)
        labels = labels.reshape(mask.shape)
        count = int(labels.max())
    return labels, count


def _window_directions(height: int, width: int, rows: slice) -> np.ndarray:
    """(r, W, 3) the texel directions of rows `rows` of an H×W equirect map (`equirect_directions`' rows)."""
    theta = np.pi * (np.arange(rows.start, rows.stop) + 0.5) / height
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    st = np.sin(theta)[:, None]
    return np.stack([st * np.cos(phi)[None], np.broadcast_to(np.cos(theta)[:, None], (len(theta), width)),
                     st * np.sin(phi)[None]], -1)


def environment_sources(env: Environment) -> EnvironmentSources:
    """The environment's compact bright sources as directional lights, and the map without them (see
    SOURCE_CONTRAST above); cached on the environment. Each source's radiance above its surroundings' (the median
    of a two-texel ring around it, per channel) leaves the map: its integral is the light's irradiance at normal
    incidence, its luminance-weighted mean direction the light's direction, and its second moment, less a
    texel's own spread, the disc's radius (a uniform disc of radius r has E[γ²] = r²/2), but no less than the
    spread of the texel at its centre (a smaller source could lie anywhere in its texel). Only the SOURCE_COUNT
    most powerful sources that hold at least SOURCE_SHARE of the map's power each become lights (each costs its
    shadow rays in every frame); smaller specks stay in the map."""
    cached = env.device_cache.get("sources")
    if cached is not None:
        return cached
    from scipy import ndimage

    from .scene import DirectionalLight

    rad = np.asarray(env.radiance, np.float64)
    h, w = rad.shape[:2]
    omega = np.broadcast_to(equirect_row_solid_angles(h, w)[:, None], (h, w))
    lum = rad @ LUMINANCE
    power = float((lum * omega).sum())
    theta = np.pi * (np.arange(h) + 0.5) / h
    texel_var = ((np.pi / h) ** 2 + (2 * np.pi / w * np.sin(theta)) ** 2) / 12  # a texel's own spread (rad²)
    labels, count = _label_wrapped(lum > SOURCE_CONTRAST * power / (4 * np.pi)) if power > 0 else (None, 0)
    lights, residual = [], rad.copy()
    if count:
        # Only groups whose whole power could pass SOURCE_SHARE are looked at, the most powerful first; each texel
        # goes to one source (the first to claim it), so that the map never goes below its surroundings.
        held = np.bincount(labels.ravel(), weights=(lum * omega).ravel(), minlength=count + 1)
        boxes = ndimage.find_objects(labels)
        claimed = np.zeros((h, w), bool)

        def grown(mask, by):
            return ndimage.binary_dilation(np.pad(mask, ((0, 0), (by, by)), mode="wrap"), iterations=by)[:, by:-by]
        for k in np.argsort(-held[1:])[:count] + 1:
            if held[k] < SOURCE_SHARE * power or len(lights) == SOURCE_COUNT:
                break
            rows = slice(max(boxes[k - 1][0].start - 3, 0), min(boxes[k - 1][0].stop + 3, h))  # with edge and ring
            own = labels[rows]
            # with its edge: the texels next to it that a soft or sub-texel disc covers in part
            inside = grown(own == k, 1) & ((own == 0) | (own == k)) & ~claimed[rows]
            ring = grown(inside, 2) & ~inside & (own == 0)
            local = rad[rows]
            background = np.median(local[ring], axis=0) if ring.any() else np.zeros(3)
            excess = np.maximum(local[inside] - background, 0.0)
            solid = omega[rows][inside]
            weight = (excess @ LUMINANCE) * solid
            if weight.sum() < SOURCE_SHARE * power:
                continue
            d = _window_directions(h, w, rows)[inside]
            centre = (weight[:, None] * d).sum(0)
            centre /= np.linalg.norm(centre)
            spread = np.arccos(np.clip(d @ centre, -1.0, 1.0)) ** 2 - np.broadcast_to(texel_var[rows, None],
                                                                                     inside.shape)[inside]
            second = max(float((weight * spread).sum() / weight.sum()), 0.0)
            row = min(int(np.arccos(np.clip(centre[1], -1.0, 1.0)) / np.pi * h), h - 1)
            radius = np.degrees(max(np.sqrt(2 * second), np.sqrt(texel_var[row])))
            if radius > SOURCE_MAX_RADIUS:
                continue
            lights.append(DirectionalLight(centre, (excess * solid[:, None]).sum(0), radius))
            part = residual[rows]
            part[inside] -= excess
            residual[rows] = part
            window = claimed[rows]
            window[inside] = True
            claimed[rows] = window
    packed = np.array([lt.packed() for lt in lights], np.float32).reshape(-1, 8)
    packed.flags.writeable = False
    out = EnvironmentSources(lights, packed, Environment(residual.astype(np.float32), name=env.name)
                             if lights else env)
    env.device_cache["sources"] = out
    return out


# ----------------------------------------------------------------------------------------------
# All three, cached per environment
# ----------------------------------------------------------------------------------------------


@dataclass(eq=False)
class EnvironmentLighting:
    """What the renderer needs of an environment: `sgs` (the fit), `shadow_sgs` (`shadow_lobes`: the
    diffuse term's lobes where the SSDF shadows them), the residuals (`irradiance_residual`: what each
    lobe set's irradiance lacks of the exact one) and `prefiltered` (specular); `timings` seconds of the
    fit, the irradiance and the prefilter."""

    sgs: EnvironmentSGs
    shadow_sgs: EnvironmentSGs
    prefiltered: PrefilteredEnvironment
    irradiance_residual: np.ndarray  # for shadow_sgs
    open_residual: np.ndarray  # for sgs
    timings: dict = field(default_factory=dict)
    # The environment's compact bright sources as lights (environment_sources: (K, 8) Light.packed() rows), which
    # the four above leave out; the renderer adds them to the scene's lights.
    sources: np.ndarray = field(default_factory=lambda: np.zeros((0, 8), np.float32))
    # The shade's order of the diffuse lobes (render._static_inputs), made once per `shadowed`: a material edit
    # keeps the environment, and its ShadeInputs then hold the very same frozen array.
    shade_order: dict = field(default_factory=dict)

    def diffuse_lobes(self, shadowed: bool) -> tuple:
        """(lobes, residual) for the diffuse term: the six-way split ambient lobe only where the SSDF
        shadows the lobes (an unshadowed scene needs one ambient lobe, and the residual makes both exact)."""
        return (self.shadow_sgs, self.irradiance_residual) if shadowed else (self.sgs, self.open_residual)


def prepare(env: Environment, backend="auto", lobes: int = 9) -> EnvironmentLighting:
    """`environment_sources`, then `fit_sgs` + `prefilter` of the map without them on `backend`, cached in
    env.device_cache per backend name and lobe count, so re-rendering under the same environment costs nothing.
    An Environment is treated as immutable: a changed map is a new Environment."""

    be = get_backend(backend)
    key = ("lighting", be.name, int(lobes))
    cached = env.device_cache.get(key)
    if cached is not None:
        return cached
    t0 = time.perf_counter()
    sources = environment_sources(env)
    rest = sources.residual
    t1 = time.perf_counter()
    sgs = fit_sgs(rest, lobes, be)
    t2 = time.perf_counter()
    shading = shadow_lobes(sgs)
    exact = irradiance_map(rest)
    residuals = [irradiance_residual(rest, lobes, exact=exact) for lobes in (shading, sgs)]
    t3 = time.perf_counter()
    pre = prefilter(rest, be)
    if rest is not env:
        # The map itself after the levels, in a row marked for the background alone (BACKGROUND_LOG2): the camera
        # still sees the sources, and no lobe reads them. (Where its offset would pass what float32 holds exactly,
        # the background shows the map without them.)
        top = pre.levels[-1]
        start = int(top[1]) + int(top[2]) * int(top[3])
        if start <= MAX_TEXELS:
            pre = PrefilteredEnvironment(np.concatenate([pre.maps, env.radiance.reshape(-1, 3)]),
                                         np.concatenate([pre.levels, [[BACKGROUND_LOG2, start, env.height,
                                                                       env.width]]]).astype(np.float32), pre.timings)
    t4 = time.perf_counter()
    out = EnvironmentLighting(sgs, shading, pre, *residuals,
                              {"sources": t1 - t0, "fit": t2 - t1, "irradiance": t3 - t2, "prefilter": t4 - t3},
                              sources=sources.packed)
    env.device_cache[key] = out
    return out


def prefiltered_lookup(maps, levels, p, eta) -> np.ndarray:
    """(..., 3) Λ(p, η) from the packed levels (lighting.PrefilteredEnvironment): the oracle of the
    shade kernels' lookup.

    `maps` (Σ h_l·w_l, 3), `levels` (n, 4) rows [log2 η_l, offset, h_l, w_l] with log2 η_l
    consecutive integers, then at most a row marked BACKGROUND_LOG2, which η ≥ BACKGROUND_ETA alone reads (bilinear)
    and the others ignore. t = clamp(log2 max(η, 1e−30) − log2 η_0, 0, n − 1), l = max(min(⌊t⌋, n − 2), 0),
    f = t − l: (1 − f)·bilinear(level l) + f·bilinear(level min(l + 1, n − 1)), each level an equirect
    map (environment.py convention: φ wraps, θ clamps). p (..., 3) unit, η (...) broadcast together.
    (lighting.prefilter always makes n ≥ 2; n = 1 is that one level, as in the shade kernels.)
    """

    maps = np.asarray(maps, np.float64)
    levels = np.asarray(levels, np.float64)
    n = len(levels)
    if n < 1:
        raise ValueError("prefiltered_lookup needs at least one level")
    p = np.asarray(p, np.float64)
    eta = np.asarray(eta, np.float64)
    shape = np.broadcast_shapes(p.shape[:-1], eta.shape)
    p = np.broadcast_to(p, (*shape, 3)).reshape(-1, 3)
    eta = np.broadcast_to(eta, shape).reshape(-1)
    if n > 1 and levels[-1, 0] >= BACKGROUND_LOG2:  # the background's own row: η ≥ BACKGROUND_ETA alone reads it
        off, h, w = levels[-1, 1:].astype(np.int64)
        out = prefiltered_lookup(maps, levels[:-1], p, np.minimum(eta, BACKGROUND_ETA))
        far = eta >= BACKGROUND_ETA
        out[far] = equirect_bilinear(maps[off:off + h * w].reshape(h, w, 3), p[far])
        return out.reshape(*shape, 3)
    t = np.clip(np.log2(np.maximum(eta, 1e-30)) - levels[0, 0], 0.0, n - 1.0)
    lev = np.maximum(np.minimum(np.floor(t), n - 2), 0).astype(np.int64)
    f = np.clip(t - lev, 0.0, 1.0)
    images = []
    for off, h, w in levels[:, 1:].astype(np.int64):
        images.append(maps[off:off + h * w].reshape(h, w, 3))
    out = np.zeros((len(p), 3))
    for l in np.unique(lev):
        m = lev == l
        out[m] = ((1 - f[m])[:, None] * equirect_bilinear(images[l], p[m])
                  + f[m][:, None] * equirect_bilinear(images[min(l + 1, n - 1)], p[m]))
    return out.reshape(*shape, 3)


def _clamped_cosine_ring(u, cos_a):
    """∫_0^{2π} max(a + b cos φ, 0) dφ with a = (1 − u)cos α, b = √(u(2 − u))·sin α: the clamped cosine
    about a normal at angle α from the lobe axis, integrated over the ring 1 − ω·ξ = u."""
    sin_a = np.sqrt(np.maximum(1.0 - cos_a * cos_a, 0.0))
    a = (1.0 - u) * cos_a
    b = np.sqrt(np.maximum(u * (2.0 - u), 0.0)) * sin_a
    safe_b = np.where(b > 0, b, 1.0)
    ratio = np.clip(-a / safe_b, -1.0, 1.0)
    partial = 2.0 * (a * np.arccos(ratio) + np.sqrt(np.maximum(b * b - a * a, 0.0)))
    return np.where(a >= b, 2.0 * np.pi * a, np.where(a <= -b, 0.0, partial))


def sg_irradiance(axes, sharpness, amplitude, normals, nodes: int = 32) -> np.ndarray:
    """(N, 3) E(n) = Σ_k ∫ G(ω; ξ_k, η_k, μ_k) max(ω·n, 0) dω for K lobes, axes (K, 3), sharpness (K,),
    amplitude (K, 3), unit normals (N, 3).

    With u = 1 − ω·ξ, dω = du dφ and the φ integral in closed form (`_clamped_cosine_ring`), each
    term is ∫_0^2 e^{−ηu} ring(u) du over u ∈ [0, min(2, 50/η)] (e^{−50} is nothing). The ring has kinks
    at u = 1 ∓ sin α (α: the normal's angle from ξ), so the range is cut there and each piece taken by
    Gauss–Legendre of `nodes` points under the smoothstep u = lo + (hi − lo)·t²(3 − 2t), which gathers
    the nodes at the pieces' ends, where the kinks are. Error per lobe against adaptive quadrature, for
    η = 1e−3 … 1e6 and normals at every angle, the horizon included: ≤ 1e−8·∫G at 32 nodes
    (tests/test_lighting.py), in 3·32 evaluations a normal.
    """
    axes = np.asarray(axes, np.float64).reshape(-1, 3)
    sharpness = np.asarray(sharpness, np.float64).reshape(-1)
    amplitude = np.asarray(amplitude, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    x, wq = np.polynomial.legendre.leggauss(nodes)
    t = (x + 1.0) / 2.0
    step = t * t * (3.0 - 2.0 * t)
    step_weight = 3.0 * t * (1.0 - t) * wq  # d(step)/dx · the Gauss weight
    out = np.zeros((len(normals), 3))
    for xi, eta, mu in zip(axes, sharpness, amplitude):
        top = min(2.0, 50.0 / eta)
        cos_a = np.clip(normals @ xi, -1.0, 1.0)
        sin_a = np.sqrt(np.maximum(1.0 - cos_a * cos_a, 0.0))
        cuts = np.sort(np.clip(np.stack([np.zeros_like(sin_a), 1.0 - sin_a, 1.0 + sin_a,
                                         np.full_like(sin_a, top)], 1), 0.0, top), axis=1)
        e = np.zeros(len(normals))
        for k in range(3):
            lo, hi = cuts[:, k:k + 1], cuts[:, k + 1:k + 2]
            u = lo + (hi - lo) * step[None]
            w = (hi - lo) * step_weight[None] * np.exp(-eta * u)
            e += np.sum(_clamped_cosine_ring(u, cos_a[:, None]) * w, axis=1)
        out += e[:, None] * mu[None, :]
    return out
