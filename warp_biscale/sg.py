"""Spherical Gaussians: the stable closed forms of docs/design.md §5, in float64 numpy.

G(v; ξ, η, μ) = μ·exp(η(v·ξ − 1)), η > 0 (Iwasaki Eq. 3, Wang Eq. 2). Every function broadcasts
over leading axes: axes ξ (..., 3), sharpness η (...), amplitude μ (...). They are the formulas the
bake and the renderer use on the host, and the ones the kernels mirror.

Why these forms and not the textbook ones: the textbook inner product 4πμ1μ2·sinh(d)/(d·e^{η1+η2})
overflows at η ≈ 700 and loses everything to cancellation when d → 0; here every exponent is ≤ 0
and d → 0 is a finite limit, so sharpness up to 10⁶ and antipodal lobes are exact.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from .brdf import SHARPNESS_MAX, BlinnPhong, CookTorrance, Ward, sg_lobes
from .io import atomic_path, cache_folder

__all__ = ["evaluate", "integral", "inner_product", "product", "convolve", "one_minus_cos", "SHARPNESS_MAX",
           "SHARPNESS_MIN", "specular_lobe", "specular_lobes"]

# SHARPNESS_MAX (1e6, defined in brdf, whose BRDF parameters it bounds): a delta NDF (a flat facet) is capped
# there; see `convolve` for why that is harmless
SHARPNESS_MIN = 1.0e-3


def one_minus_cos(a, b):
    """1 − a·b for unit vectors, as ‖a − b‖²/2: exact to the last bit near a = b, where 1 − a·b is not."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return 0.5 * np.einsum("...i,...i->...", d, d)


def evaluate(v, axis, sharpness, amplitude=1.0):
    """G(v) = μ·exp(−η(1 − v·ξ))."""
    return np.asarray(amplitude, np.float64) * np.exp(-np.asarray(sharpness, np.float64) * one_minus_cos(v, axis))


def _one_minus_exp_over(x):
    """(1 − e^{−2x})/x, with its limit 2 at x → 0."""
    x = np.asarray(x, np.float64)
    safe = np.where(x > 1e-12, x, 1.0)
    return np.where(x > 1e-12, -np.expm1(-2.0 * safe) / safe, 2.0 - 2.0 * x)


def integral(sharpness, amplitude=1.0):
    """∫_S² G = 2πμ·(1 − e^{−2η})/η."""
    return 2.0 * np.pi * np.asarray(amplitude, np.float64) * _one_minus_exp_over(sharpness)


def _resultant(axis1, sharpness1, axis2, sharpness2):
    """d = ‖η1ξ1 + η2ξ2‖, computed as sqrt((η1 − η2)² + 2η1η2(1 + ξ1·ξ2)) so antipodal lobes lose nothing."""
    e1 = np.asarray(sharpness1, np.float64)
    e2 = np.asarray(sharpness2, np.float64)
    s = np.asarray(axis1, np.float64) + np.asarray(axis2, np.float64)
    one_plus = 0.5 * np.einsum("...i,...i->...", s, s)  # 1 + ξ1·ξ2, exact near ξ1 = −ξ2
    return np.sqrt(np.maximum((e1 - e2) ** 2 + 2.0 * e1 * e2 * one_plus, 0.0))


def inner_product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2):
    """∫_S² G1·G2 = 2πμ1μ2·exp(d − η1 − η2)·(1 − e^{−2d})/d, d = ‖η1ξ1 + η2ξ2‖ (Iwasaki Eq. 4/11).

    The exponent d − η1 − η2 ≤ 0 is evaluated as −2η1η2(1 − ξ1·ξ2)/(η1 + η2 + d), which follows from
    (η1 + η2)² − d² = 2η1η2(1 − ξ1·ξ2) and has no cancellation when the lobes are sharp and close.
    """
    e1 = np.asarray(sharpness1, np.float64)
    e2 = np.asarray(sharpness2, np.float64)
    d = _resultant(axis1, e1, axis2, e2)
    gap = 2.0 * e1 * e2 * one_minus_cos(axis1, axis2) / (e1 + e2 + d)  # η1 + η2 − d ≥ 0, no cancellation
    return (2.0 * np.pi * np.asarray(amplitude1, np.float64) * np.asarray(amplitude2, np.float64)
            * np.exp(-gap) * _one_minus_exp_over(d))


def product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2):
    """G1·G2 as one SG (Wang Eq. 5): → (axis, sharpness, amplitude).

    axis (η1ξ1 + η2ξ2)/d, sharpness d, amplitude μ1μ2·exp(d − η1 − η2). For exactly antipodal lobes
    of equal sharpness d = 0 and the product is the constant μ1μ2·e^{−2η}; the axis is then +z.
    """
    e1 = np.asarray(sharpness1, np.float64)
    e2 = np.asarray(sharpness2, np.float64)
    d = _resultant(axis1, e1, axis2, e2)
    v = e1[..., None] * np.asarray(axis1, np.float64) + e2[..., None] * np.asarray(axis2, np.float64)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    axis = np.where(norm > 0, v / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 1.0]))
    gap = 2.0 * e1 * e2 * one_minus_cos(axis1, axis2) / (e1 + e2 + d)
    return axis, d, np.asarray(amplitude1, np.float64) * np.asarray(amplitude2, np.float64) * np.exp(-gap)


def convolve(sharpness1, amplitude1, sharpness2, amplitude2):
    """Iwasaki Eq. 14: ∫G(ω; ξ1, η1, μ1)G(ω; ξ2, η2, μ2)dω ≈ G(ξ1; ξ2, η, μ) as one SG in ξ1.

    → (sharpness η = 1/(1/η1 + 1/η2), amplitude μ = 2πμ1μ2/(η1 + η2)). The harmonic form keeps an
    infinite (capped) sharpness harmless: a perfectly flat facet's lobe reduces to the other lobe.
    Its largest absolute error (μ1 = μ2 = 1) is ≈ 1.45/(η1 + η2)² for sharp pairs (3.6e−5 at (100, 100),
    1.2e−6 at (100, 1000)); at small sharpness it grows: 1.3e−2 at (1, 10), 0.070 at (1, 4) (Iwasaki
    Fig. 5 and §4.2) and 0.55 at (1, 1) — tests/test_sg.py measures these.
    """
    e1 = np.asarray(sharpness1, np.float64)
    e2 = np.asarray(sharpness2, np.float64)
    eta = 1.0 / (1.0 / e1 + 1.0 / e2)
    return eta, 2.0 * np.pi * np.asarray(amplitude1, np.float64) * np.asarray(amplitude2, np.float64) / (e1 + e2)


def specular_lobe(brdf, wi, wo):
    """A small-scale BRDF's specular term as an SG over the facet normal n, centred on h:

    ks·f_s(n, ωi, ωo) ≈ M(ωi, ωo)·G(n; h, η_s, 1) → (η_s scalar, M (N, 3) RGB, h (N, 3)).

    Blinn–Phong (Iwasaki §4.1): (n+2)/(2π)(n·h)^n ≈ G(n; h, n, (n+2)/(2π)), so η_s = n, M = ks(n+2)/(2π).
    Cook–Torrance (Wang §4): D = exp(−θh²/m²) ≈ G(n; h, 2/m², 1); the rest, F·G/(π(n·ωi)(n·ωo)), is
    taken at n = h, where G = 1 and n·ωi = n·ωo = h·ωi = cos θd: M = ks·F(cos θd)/(π cos²θd).
    Ward: exp(−tan²θh/α²) ≈ G(n; h, 2/α², 1) (tan²θ ≈ 2(1 − cos θ) near θ = 0) and
    M = ks/(4πα² cos θd). A Lambertian BRDF has no specular term: η_s = None, M = 0. A measured BRDF's is
    its SG fit's lobe; one whose fit has two lobes is refused in one line (`specular_lobes` takes it).
    """
    lobes = sg_lobes(brdf)
    if len(lobes) != 1:
        raise ValueError(f"{brdf!r} has {len(lobes)} SG lobes (its SG fit's): take them by sg.specular_lobes")
    brdf = lobes[0]

    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    s = wi + wo
    norm = np.linalg.norm(s, axis=-1, keepdims=True)
    h = np.where(norm > 0, s / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 1.0]))
    cos_d = np.clip(np.einsum("ij,ij->i", h, wi), 1e-6, 1.0)
    ks = np.asarray(brdf.packed()[3:6], np.float64)  # ks as the kernels see it: BlinnPhong's normalization folded in
    if isinstance(brdf, BlinnPhong):
        n = brdf.exponent
        return n, np.tile(ks * (n + 2.0) / (2.0 * np.pi), (len(wi), 1)), h
    if isinstance(brdf, CookTorrance):
        fres = brdf.f0 + (1.0 - brdf.f0) * (1.0 - cos_d) ** 5
        return 2.0 / brdf.roughness**2, ks[None, :] * (fres / (np.pi * cos_d**2))[:, None], h
    if isinstance(brdf, Ward):
        return 2.0 / brdf.alpha**2, ks[None, :] / (4.0 * np.pi * brdf.alpha**2 * cos_d)[:, None], h
    return None, np.zeros((len(wi), 3)), h


def specular_lobes(brdf, wi, wo) -> list:
    """`specular_lobe` of each of `brdf`'s SG lobes (`brdf.sg_lobes`: the BRDF itself, or a measured one's SG
    fit of one or two lobes) → [(η_s, M (N, 3), h (N, 3)), …]; a small-scale BRDF's specular term is their sum."""
    return [specular_lobe(b, wi, wo) for b in sg_lobes(brdf)]


# ---------------------------------------------------------------------------------------------------
# Lighting integrals of one SG against a half-space, tabulated for the renderer (docs/design.md §5, Wang §5.3)
#
# With c = ξ·m for the lobe axis ξ and a unit vector m:
#   cosine_fraction(c, η)     = ∫ G(ω; ξ, η, 1)·max(ω·m, 0) dω / ∫G   (m the surface normal: the SG
#                               times the clamped cosine, exact where Wang's one-lobe fit Eq. 40 is not)
#   hemisphere_fraction(c, η) = ∫_{ω·m ≥ 0} G(ω; ξ, η, 1) dω / ∫G
#   visible_fraction(c, η)    = ∫_{ω·ξ ≥ 0, ω·m ≥ 0} G dω / ∫_{ω·ξ ≥ 0} G dω   (Wang's f_h(θd, λ)/f_h(π/2, λ),
#                               Eq. 30–31, with c = sin θd: m is the normal of the reconstructed
#                               visibility hemisphere, at angle π/2 − θd from the lobe axis, and the
#                               lobe is taken over its own hemisphere, as Wang integrates it)
# Both are exact 1-D integrals over the polar angle θ about ξ of a closed-form azimuthal measure; the
# renderer reads them from `lighting_table()` by bilinear interpolation in (log10 η, c).
# ---------------------------------------------------------------------------------------------------

TABLE_LOG10_ETA = (-4.0, 6.0)  # η from 1e-4 (a near-constant lobe: ambient light) to SHARPNESS_MAX
TABLE_ROWS = 161  # 16 per decade of η: the fractions are smooth in log η
TABLE_COLUMNS = 257  # over c in [-1, 1]; the step of a sharp lobe is smeared over 2/256 in c (0.45°)
_GL_NODES = 48


def _quadrature_setup(c, eta):
    """c, η broadcast and flattened (float64, c clipped to [−1, 1]), their shape, s = √(1 − c²),
    a = 1 − e^{−2η} and y(θ) = (1 − e^{−η(1−cos θ)})/a: the variable in which the SG weight is uniform."""
    c = np.clip(np.asarray(c, np.float64), -1.0, 1.0)
    eta = np.asarray(eta, np.float64)
    c, eta = np.broadcast_arrays(c, eta)
    shape = c.shape
    c, eta = c.reshape(-1), eta.reshape(-1)
    a = -np.expm1(-2.0 * eta)

    def y_of_theta(theta):
        return -np.expm1(-eta * (1.0 - np.cos(theta))) / a

    return c, eta, shape, np.sqrt(np.maximum(1.0 - c * c, 0.0)), a, y_of_theta


def _rings(c, eta, s, a, cuts):
    """Gauss–Legendre in y on each piece between consecutive `cuts` (N, P): yields per piece the
    weights w, and for each node's ring about ξ (1 − cos θ = x) the half-width φ0 of its arc with
    ω·m ≥ 0 (ξ·m = c, ω·m = A + B cos φ), with A and B."""
    nodes, weights = np.polynomial.legendre.leggauss(_GL_NODES)
    for k in range(cuts.shape[1] - 1):
        lo, hi = cuts[:, k:k + 1], cuts[:, k + 1:k + 2]
        y = lo + (hi - lo) * (nodes[None] + 1) / 2
        w = (hi - lo) / 2 * weights[None]
        q = np.maximum(1.0 - y, 0.0)
        # 1 − cos θ = −log(1 − a·y)/η with 1 − a·y written as e^{−2η} + a·(1 − y): no log(0) for sharp lobes
        x = np.minimum(-np.log(np.maximum(np.exp(-2.0 * eta)[:, None] + a[:, None] * q, 1e-300)) / eta[:, None], 2.0)
        big_a = c[:, None] * (1.0 - x)
        big_b = s[:, None] * np.sqrt(np.maximum(x * (2.0 - x), 0.0))
        ratio = np.where(big_b > 0, -big_a / np.where(big_b > 0, big_b, 1.0), np.where(big_a >= 0, -2.0, 2.0))
        yield w, np.arccos(np.clip(ratio, -1.0, 1.0)), big_a, big_b


def _half_space_fractions(c, eta):
    """(cosine_fraction, hemisphere_fraction) for arrays c, η of one shape, by Gauss–Legendre in
    y = (1 − e^{−η(1−cos θ)})/(1 − e^{−2η}), which makes the SG weight uniform, on the pieces between
    the kinks of the azimuthal measure (θ = |θd| and π − |θd|, θd = asin c)."""
    c, eta, shape, s, a, y_of_theta = _quadrature_setup(c, eta)
    td = np.abs(np.arcsin(c))
    cuts = np.stack([np.zeros_like(c), y_of_theta(td), y_of_theta(np.pi - td), np.ones_like(c)], 1)
    cuts = np.sort(np.clip(cuts, 0.0, 1.0), axis=1)
    cos_total = np.zeros_like(c)
    hemi_total = np.zeros_like(c)
    for w, phi0, big_a, big_b in _rings(c, eta, s, a, cuts):
        cos_total += np.sum(w * 2.0 * (big_a * phi0 + big_b * np.sin(phi0)), axis=1)
        hemi_total += np.sum(w * 2.0 * phi0, axis=1)
    return (np.maximum(cos_total / (2 * np.pi), 0.0).reshape(shape),
            np.clip(hemi_total / (2 * np.pi), 0.0, 1.0).reshape(shape))


def _lune_fraction(c, eta):
    """visible_fraction for arrays c, η of one shape: the same quadrature as `_half_space_fractions`,
    over the lobe's own hemisphere (θ ≤ π/2 about ξ, y ≤ y(π/2)) only, divided by that hemisphere's mass."""
    c, eta, shape, s, a, y_of_theta = _quadrature_setup(c, eta)
    y_half = y_of_theta(np.pi / 2)  # the own hemisphere's share of ∫G
    cuts = np.stack([np.zeros_like(c), np.minimum(y_of_theta(np.abs(np.arcsin(c))), y_half), y_half], 1)
    total = np.zeros_like(c)
    for w, phi0, _, _ in _rings(c, eta, s, a, cuts):
        total += np.sum(w * 2.0 * phi0, axis=1)
    return np.clip(total / (2 * np.pi * y_half), 0.0, 1.0).reshape(shape)


def visible_fraction(c, eta):
    """Wang §5.3's visibility of an SG lobe, c = sin θd: the share of the lobe's integral over its own
    hemisphere (ω·ξ ≥ 0) that also lies on the visible side ω·m ≥ 0 of the reconstructed visibility
    hemisphere, whose boundary passes at angle θd from the axis (f_h(θd, λ)/f_h(π/2, λ), Eq. 30–31).
    1 at c = 1; for a sharp lobe hemisphere_fraction(c, η); for a uniform one the lune's share
    (π/2 + θd)/π, so a broad lobe is shadowed too (the half-space alone leaves it 1/2 whatever θd)."""
    return _lune_fraction(c, eta)


def cosine_fraction(c, eta):
    """∫ G(ω; ξ, η, 1)·max(ω·n, 0) dω / ∫G with c = ξ·n (exact quadrature, float64)."""
    return _half_space_fractions(c, eta)[0]


def hemisphere_fraction(c, eta):
    """The fraction of an SG's integral on the side ω·m ≥ 0 of a great circle, c = ξ·m = sin θd
    (exact quadrature, float64). 0.5 at c = 0; hemisphere_fraction(−c) = 1 − hemisphere_fraction(c)."""
    return _half_space_fractions(c, eta)[1]


def table_axes():
    """(log10 η of the rows, c of the columns) of `lighting_table`."""
    return (np.linspace(*TABLE_LOG10_ETA, TABLE_ROWS), np.linspace(-1.0, 1.0, TABLE_COLUMNS))


_TABLE = None


def _computed_table() -> np.ndarray:
    log_eta, c = table_axes()
    cc, ee = np.meshgrid(c, 10.0**log_eta)
    return np.stack([_half_space_fractions(cc, ee)[0], _lune_fraction(cc, ee)]).astype(np.float32)


def table_cache_path() -> str:
    """The file `lighting_table` is kept in between processes: named by a digest of this module's source
    (every quadrature and constant the table depends on lives here) and numpy's version."""
    with open(__file__, "rb") as fh:
        digest = hashlib.sha256(fh.read()).hexdigest()[:16]
    return os.path.join(cache_folder(), f"lighting-table-{digest}-numpy{np.__version__}.npy")


def lighting_table() -> np.ndarray:
    """(2, TABLE_ROWS, TABLE_COLUMNS) float32: [0] cosine_fraction, [1] visible_fraction on the grid
    of `table_axes`. Its quadrature takes about a second, which every fresh process (a CLI render, a batch
    worker) would pay: it is read from `table_cache_path()` where a valid one is there, else computed
    and written there atomically (a folder that takes no file only costs the next process the
    second); then kept for the process."""
    global _TABLE
    if _TABLE is None:
        shape = (2, TABLE_ROWS, TABLE_COLUMNS)
        table = None
        try:
            path = table_cache_path()
            table = np.load(path, allow_pickle=False)
            if table.shape != shape or table.dtype != np.float32 or not np.isfinite(table).all():
                table = None
        except Exception:  # noqa: BLE001 - whatever is wrong with the cached file, the table is computed again
            table = None
        if table is None:
            table = _computed_table()
            try:
                with atomic_path(table_cache_path()) as tmp:
                    with open(tmp, "wb") as fh:
                        np.save(fh, table)
            except OSError:
                pass
        table.setflags(write=False)
        _TABLE = table
    return _TABLE


def table_lookup(table, which: int, c, eta):
    """Bilinear lookup of lighting_table()[which] at (c, η), float64: the semantics the shade kernels
    implement (η clamped to the table's range, c to [−1, 1])."""
    table = np.asarray(table, np.float64)[which]
    rows, cols = table.shape
    lo, hi = TABLE_LOG10_ETA
    le = np.clip(np.log10(np.maximum(np.asarray(eta, np.float64), 1e-30)), lo, hi)
    tr = (le - lo) / (hi - lo) * (rows - 1)
    tc = (np.clip(np.asarray(c, np.float64), -1.0, 1.0) + 1.0) / 2.0 * (cols - 1)
    r0 = np.minimum(np.floor(tr).astype(np.int64), rows - 2)
    c0 = np.minimum(np.floor(tc).astype(np.int64), cols - 2)
    fr = tr - r0
    fc = tc - c0
    return ((1 - fr) * ((1 - fc) * table[r0, c0] + fc * table[r0, c0 + 1])
            + fr * ((1 - fc) * table[r0 + 1, c0] + fc * table[r0 + 1, c0 + 1]))
