"""The Monte Carlo reference renderer (docs/design.md §6): importance-sampled, exact visibility, exact f̄.

    result = montecarlo.render(scene, samples=256)   # or wb.render(scene, method="mc", ...)
    result.image               # (H, W, 3) float32 linear radiance, never NaN, inf or negative
    result.info["stderr"]      # (H, W, 3) float32 standard error of each pixel's estimate
    result.info["stderr_rms"], result.info["stderr_max"]   # over the hit pixels' RGB values

Every hit pixel of the G-buffer gets the estimate of

    L(x, ωo) = ∫ [L_env(ω) + Σ_l L_l(ω)] · V(x, ω) · F(ω, ωo) dω

- L_env(ω) = `Environment.lookup(ω)` (bilinear; black without an environment); L_l the light's SG
  emitter (`scene.light_sg`), the light model the SG renderer uses too.
- V exact: one `backend.trace_occluded` ray per sample, from where `trace_shadows` starts its rays
  (`trace.ray_starts`: the hit lifted off its flat face towards the smooth surface of the vertex
  normals, then moved `trace.SHADOW_OFFSET × mesh.scale` along the geometric normal turned to the
  viewer). Every direction above the shading normal's horizon is traced, also one below the face's
  own plane (it may hit the face itself), as `trace_shadows` treats a light there. Environment and
  directional lights are unbounded rays; a point light's term is
  occluded only by a hit before its centre (t_max = distance − offset, as `trace_shadows`), so a
  sample that hits something is traced again, up to each point light it sees.
- F: an analytic BRDF's f_r(n, ω, ωo)·(n·ω)⁺ (`Brdf.eval`), a `MeasuredBRDF`'s alike (its float64
  `eval`, the table lookup on the host); an effective BRDF's f̄(ω_local, ωo_local) from its ground truth
  (`GroundTruth.eval`, cos θi already in it), in the tile frame (t, b, n): the one passed in `truths`,
  else the one `truth.truth_of` computes from what the material records of how it was baked (its tile
  and small-scale BRDFs, on a K×K grid (`truth_directions`, the material's own K by default), `truth_facets`
  facets, `truth_bounces` bounces inside the tile), cached beside its material file and in memory. A
  material that records nothing (a format-1 file, one built by hand) is a ValueError, unless fallback="sg": then
  the material's own fit is used — `EffectiveBRDF.eval(method="sg-exact")` for an SG bake, its ASG lobes
  (`ASGBRDF.eval(method="asg")`) for an ASG bake — with a warning and a note in info["effective_brdf"] (not the
  exact f̄, so the reference is not exact for it).

Position, shading normal, tangent frame and ωo are built from the G-buffer exactly as
`shading.shade_reference` builds them (float32 vertex attributes, barycentric interpolation, the
tangent of `scene.vertex_tangents` orthonormalised, ωo·n clamped to MIN_COS_VIEW), so the two images
differ only by the method. The clamped ωo is used for analytic BRDFs too, so a silhouette pixel whose
interpolated normal faces away keeps its diffuse term, as in the SG renderer. Background pixels show
`Environment.lookup` along the camera ray.

Sampling: multiple importance sampling with the balance heuristic (Veach 1997 §9.2), per term of the
integrand. Strategies: (1) the environment, following its bilinear lookup (a cell between texel centres ∝
its corners' mean × solid angle, then bilinear inside it: L/p is nearly constant); (2) the cosine lobe
about n; (3) the BRDF: an analytic glossy BRDF's half vector from a von Mises–Fisher lobe about n of its
NDF's SG sharpness (`sg.specular_lobe`), reflected about ωo (a measured BRDF's: the sharpness fitted to
its table, `_measured_lobe`); an effective BRDF's warped NDF lobes (Wang Eq. 18–21) as a vMF mixture; (4)
each light's vMF emitter. The environment term L_env·V·F is estimated from the samples of (1), (2), (3);
light l's term from those of (4, l) and (3); each sample is weighted by 1/Σ_k n_k·p_k(ω) over the term's
strategies k, every pdf evaluated exactly. Cosine samples are kept off the lights' terms: an emitter is
sampled exactly by its own vMF, and a cosine sample hitting a small light is a rare event that skews the
estimate and makes its sample variance understate the error. Every term is covered wherever it is non-zero
(the environment strategy wherever the bilinear radiance is positive, a vMF everywhere), so the estimate
is unbiased. Strategies with nothing to contribute are left out (no environment: no environment or cosine
sampling; Lambert or a table without a lobe: no BRDF sampling).

The N samples of a pixel are shared out over its strategies (n_s each, at least 2) by weights that only
move variance, never the mean (`_plan`). Each strategy's main random choice u[0] (the environment cell,
the lobe of a mixture, the polar angle of a vMF or cosine sample) is stratified: n_s/STRATUM equal
strata with STRATUM independent samples each (e.g. the number of samples in a sun no longer varies
binomially), and the standard error is the stratified estimator's, Σ_h n_h·s_h²/N² over all strata h
with s_h² the sample variance inside stratum h (`_stratified_variance`): unbiased as a variance.
Measured on a sky + sun + two lights scene (sphere and floor, 256 spp): per-pixel errors 2.2× smaller
than i.i.d. sampling gives, and the error/σ ratio has RMS 1.06–1.16 (1.0–1.07 i.i.d.), with ~1 % of
pixels beyond 3σ (0.3 % for a normal law): where the variance sits in a few strata (a sun's highlight, a
penumbra) σ has few degrees of freedom, so read it per image (stderr_rms) rather than per pixel.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from . import sg
from .backend import get_backend
from .brdf import Brdf, Lambert, brdf_cosine_weighted, pack_materials
from .effective import EffectiveBRDF
from .measured import MeasuredBRDF, bin_centres
from .progress import Progress
from .scene import Rendering, Scene
from .scene import light_sg, vertex_tangents
from .shading import seen_from_behind, surface_frames
from .montecarlo_sampling import (_AsgGlossyStrategy, _basis, _CosineStrategy, _dot,  # noqa: F401
                                  _EnvironmentStrategy, _GlossyStrategy, _LightStrategy, _LobeMixtureStrategy,
                                  sample_vmf, vmf_pdf)
from .svbrdf import Textured
from .trace import offsets, ray_starts
from .truth import (BOUNCE_PATHS, MAX_FACETS, MAX_TRUTH_DIRECTIONS, TRUTH_FACETS, GroundTruth, _check_bounces,
                    _check_count, cached_truth)

__all__ = ["render", "missing_provenance", "DEFAULT_BATCH", "FALLBACKS", "sample_vmf", "vmf_pdf"]

DEFAULT_BATCH = 1 << 20  # samples (pixels × samples per pixel) a batch: ~0.4 GB of temporaries (measured)
STRATUM = 4  # samples per stratum of a strategy's u[0] (`_strata`): 3 degrees of freedom each for the variance
FALLBACKS = (None, "sg")  # what an effective material without a ground truth uses: none (an error) or its fit


# ---------------------------------------------------------------------------------------------------
# materials: F(ω, ωo) and the BRDF strategy
# ---------------------------------------------------------------------------------------------------


def _albedos(brdf: Brdf):
    """(diffuse, specular) mean reflectance proxies, mean kd and mean ks: they only share out the samples."""
    if isinstance(brdf, Lambert):
        return float(np.mean(brdf.albedo)), 0.0
    if isinstance(brdf, MeasuredBRDF):
        return _measured_lobe(brdf)[:2]
    return float(np.mean(brdf.kd)), float(np.mean(brdf.packed()[3:6]))  # ks as packed: a normalisation included


def _glossy_eta(brdf: Brdf):
    """The NDF's SG sharpness of an analytic BRDF with a specular term, else None (Lambert, ks = 0); a measured
    BRDF's fitted to its table (`_measured_lobe`)."""
    if isinstance(brdf, MeasuredBRDF):
        return _measured_lobe(brdf)[2]
    if isinstance(brdf, Lambert) or float(np.max(brdf.ks)) <= 0:
        return None
    z = np.array([[0.0, 0.0, 1.0]])
    return sg.specular_lobe(brdf, z, z)[0]


MEASURED_GLOSS = 1e-3  # a measured θh profile varying less than this share of its peak has no lobe to sample
MEASURED_ETA = (1.0, 1e5)  # the range of a measured BRDF's fitted half-vector sharpness


def _measured_lobe(brdf: MeasuredBRDF):
    """(kd, ks, η or None): a measured BRDF's diffuse and specular shares and its half-vector vMF sharpness,
    read off its table's θh profile next to the mirror configuration — f_r at the bin centres of θh, θd's
    first bin (0.5°), averaged over φd and RGB. Its minimum is the diffuse floor (kd = π·floor); the rest,
    s(θh), is the specular peak. η is the SG sharpness that falls to 1/e where s does (1 − cos θh = 1/η at
    s = s_max/e, linear between bins), as `sg.specular_lobe` matches an analytic NDF near its peak (a
    tabulated Cook–Torrance m = 0.2 gets 48.1 here, its analytic lobe 50), in MEASURED_ETA; None where s is
    under MEASURED_GLOSS of the peak (a tabulated Lambert: no BRDF strategy, as for Lambert). ks is s's albedo
    at normal view, ∫ s(θh) cos θi dωi with dωi = 4 cos θh dω_h, reading the profile as if it held there.
    These only choose a proposal and share out the samples: any value keeps the estimator unbiased."""
    th, td, pd = bin_centres()
    f = brdf.lookup(np.repeat(th, len(pd)), np.full(len(th) * len(pd), td[0]), np.tile(pd, len(th)))
    profile = f.mean(1).reshape(len(th), len(pd)).mean(1)
    floor = max(float(profile.min()), 0.0)
    spec = profile - floor
    peak = float(spec.max())
    if not np.isfinite(peak) or peak <= MEASURED_GLOSS * max(float(profile.max()), 1e-300):
        return np.pi * floor, 0.0, None
    top = int(np.argmax(spec))
    x = 1.0 - np.cos(th)  # 1 − cos θh, exact enough at these angles (θh ≥ 4.8e-5 rad: no cancellation below 1e-9)
    below = np.flatnonzero(spec[top:] <= peak / np.e)
    if len(below) == 0:  # never falls to 1/e: as broad as it gets
        eta = MEASURED_ETA[0]
    else:
        j = top + int(below[0])
        a, b = spec[j - 1], spec[j]
        xe = x[j - 1] + (x[j] - x[j - 1]) * (a - peak / np.e) / (a - b) if a > b else x[j]
        eta = 1.0 / max(xe - x[top], 1e-300)
    eta = float(np.clip(eta, *MEASURED_ETA))
    d_theta = (np.arange(len(th)) + 0.5) * np.pi / len(th) ** 2  # the bins' widths on MERL's square-root θh axis
    ks = float(np.sum(spec * 4 * np.cos(th) * np.maximum(np.cos(2 * th), 0.0) * np.sin(th) * d_theta) * 2 * np.pi)
    return np.pi * floor, ks, eta


class _AnalyticMaterial:
    """An analytic BRDF — or a `MeasuredBRDF`, whose `eval` (float64, on the host) is f_r as an analytic one's
    and whose BRDF strategy is the same half-vector vMF, fitted to its table (`_measured_lobe`)."""

    def __init__(self, brdf: Brdf):
        self.brdf = brdf
        if brdf.anisotropic:  # its NDF's ASG, in the pixel's tangent frame (Ashikhmin–Shirley's Fresnel reflects
            self.strategy = _AsgGlossyStrategy(*brdf.ndf_bandwidths)  # even where rs = 0)
        else:
            eta = _glossy_eta(brdf)
            self.strategy = None if eta is None else _GlossyStrategy(eta)
        self.albedos = _albedos(brdf)
        self.label = None

    def f(self, ctx, pix, w):
        """(K, 3) f_r(n, ω, ωo)·(n·ω)⁺ for samples w (K, 3) of pixels pix (K,) of the batch."""
        n, wo = ctx["n"][pix], ctx["wo"][pix]
        if self.brdf.anisotropic:  # in the frame the SG renderer shades it in
            f = self.brdf.eval(n, w, wo, tangent=ctx["t"][pix])
        else:
            f = self.brdf.eval(n, w, wo)
        return f * np.maximum(_dot(n, w), 0.0)[:, None]


class _TexturedMaterial(_AnalyticMaterial):
    """A `svbrdf.Textured` BRDF: its parameters at each sample's pixel UV (float64 lookups, `Textured.at`).
    The sampling strategy and sample shares are the untextured BRDF's — still unbiased (they only
    importance-sample), less efficient where a map sharpens the lobe."""

    def __init__(self, tex):
        super().__init__(tex.brdf)
        self.tex = tex

    def f(self, ctx, pix, w):

        n, wo = ctx["n"][pix], ctx["wo"][pix]
        kinds, _ = pack_materials([self.brdf])
        params = self.tex.at(ctx["uv"][pix])
        fc = brdf_cosine_weighted(np.full(len(params), kinds[0]), params, np.arange(len(params)), n, w, wo)
        co = _dot(n, wo)
        ok = (_dot(n, w) > 0) & (co > 0)
        out = np.zeros_like(fc)
        out[ok] = fc[ok] / co[ok][:, None]  # f_r·(n·ω)⁺ = (f_r·(n·ω)⁺(n·ωo)⁺)/(n·ωo), as Brdf.eval then ×cos
        return out


class _EffectiveMaterial:
    def __init__(self, mat: EffectiveBRDF, truth: GroundTruth | None):
        self.mat = mat
        speculars = [(m, _glossy_eta(s)) for m, s in enumerate(mat.materials)]
        speculars = [(m, e) for m, e in speculars if e is not None]
        self.strategy = _LobeMixtureStrategy(mat, speculars) if speculars else None
        self.albedos = tuple(np.max([_albedos(m) for m in mat.materials], 0))
        self.fit_method = self.fit_of(mat)
        self.use_truth(truth)

    @staticmethod
    def fit_of(mat) -> str:
        """The eval method of fallback="sg": an SG bake's SG lobes by Eq. 10 ("sg-exact"), another method's
        own lobes (an ASG bake's "asg")."""
        return "sg-exact" if mat.method in ("sg", "sg-exact") else mat.method

    def use_truth(self, truth: GroundTruth | None):
        self.truth = truth
        if truth is not None:
            bounces = f"{truth.bounces} bounces ({truth.paths} paths), " if truth.bounces > 1 else ""
            self.label = (f"ground truth (tile {truth.tile!r}, K={truth.directions}, {truth.facets} facets, "
                          f"{bounces}{truth.materials})")
        else:
            self.label = f"{fit_label(self.mat)}: fallback='sg', its fit, not the exact f̄"

    def f(self, ctx, pix, w):
        """(K, 3) f̄(ω_local, ωo_local), cos θi included, in the tile frame (t, b, n) of each pixel."""
        wl = np.stack([_dot(w, ctx["t"][pix]), _dot(w, ctx["b"][pix]), _dot(w, ctx["n"][pix])], 1)
        wo = ctx["wo_local"][pix]
        if self.truth is not None:
            return self.truth.eval(wl, wo)
        return self.mat.eval(wl, wo, method=self.fit_method)


def sampling_plan(mat: EffectiveBRDF) -> None:
    """Refuse, as `render` does for a material in view, a baked material whose glossy small-scale BRDFs' lobes
    cannot be sampled (the matrix method's: no lobes), without computing its ground truth."""
    strategy = _EffectiveMaterial(mat, None).strategy
    if strategy is not None:
        strategy.lobes()


def fit_label(mat) -> str:
    """How fallback="sg" evaluates `mat`: "EffectiveBRDF.eval(method='sg-exact')" (the SG fit), "ASGBRDF.eval(
    method='asg')" (its ASG lobes)."""
    return f"{type(mat).__name__}.eval(method={_EffectiveMaterial.fit_of(mat)!r})"


# ---------------------------------------------------------------------------------------------------
# the driver
# ---------------------------------------------------------------------------------------------------


class _Prefixed(Progress):
    """`progress` with every stage name prefixed: a ground truth's stages (facets, visibility, ...) say which
    material they are for in the middle of a render."""

    def __init__(self, inner: Progress, prefix: str):
        self.inner, self.prefix = inner, prefix

    def stage(self, name: str, total: int = 1):
        self.inner.stage(self.prefix + name, total)

    def advance(self, n: int = 1):
        self.inner.advance(n)

    def done(self):
        self.inner.done()


def _check_int(name, value, lo):
    try:
        ok = int(value) == value and int(value) >= lo
    except (TypeError, ValueError):
        ok = False
    if not ok or isinstance(value, bool):
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")
    return int(value)


def _check_truths(truths, materials) -> dict:
    """truths: None, {material index: GroundTruth}, or a sequence aligned with the materials (None entries)."""
    if truths is None:
        return {}
    if isinstance(truths, GroundTruth):
        raise ValueError("truths must map material indices to GroundTruth tables ({index: truth}), "
                         "not a single GroundTruth")
    items = truths.items() if isinstance(truths, dict) else enumerate(truths)
    out = {}
    for key, gt in items:
        if gt is None:
            continue
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not 0 <= int(key) < len(materials):
            raise ValueError(f"truths: material index {key!r} is not one of the scene's materials "
                             f"0..{len(materials) - 1}")
        if not isinstance(gt, GroundTruth):
            raise ValueError(f"truths[{key}] must be a GroundTruth (wb.ground_truth), got {type(gt).__name__}")
        if not isinstance(materials[int(key)], EffectiveBRDF):
            raise ValueError(f"truths[{key}] is given for material {key}, which is an analytic BRDF "
                             f"({materials[int(key)]!r}), not an EffectiveBRDF")
        out[int(key)] = gt
    return out


def _gbuffer_frame(scene, g):
    """Per hit pixel (P hits, back faces left out: black), the pixel indices and the shading inputs, built as
    shading.shade_reference does.

    → dict pix (P,) int, mat (P,) int, pos, n, t, b, wo (ωo with ωo·n clamped to MIN_COS_VIEW, world),
    wo_local (tile frame), origin (where the rays leave: trace.ray_starts), all (P, 3) float64; uv (P, 2) the
    interpolated texture coordinates (zeros without mesh UVs)."""
    mesh = scene.mesh
    eye = scene.camera.packed()[0:3].astype(np.float64)
    face = np.asarray(g.face)
    pix = np.flatnonzero(face >= 0)
    f = face[pix]
    bary = np.asarray(g.bary)[pix].astype(np.float64)
    host = mesh.device_cache.setdefault("host", {})
    if "tangents" not in host:  # the render driver's cache: the same float32 tangents the SG renderer reads
        host["tangents"] = vertex_tangents(mesh).astype(np.float32)
    # The float32 vertex data the kernels read, blended exactly as the SG reference blends it.
    sf = surface_frames(mesh.faces, mesh.vertices.astype(np.float32), mesh.normals.astype(np.float32),
                        host["tangents"], f, bary, eye)
    interp, pos, n, t, b, wo_local = sf["interp"], sf["pos"], sf["n"], sf["t"], sf["b"], sf["wo_local"]
    wo_clamped = wo_local[:, 0:1] * t + wo_local[:, 1:2] * b + wo_local[:, 2:3] * n
    # The rays leave where the SG renderer's shadow rays do (trace.ray_starts: lifted off the flat face
    # towards the smooth surface, then moved along the geometric normal turned to the viewer).
    start = ray_starts(mesh.vertices.astype(np.float32), mesh.normals.astype(np.float32), mesh.faces, f, bary, pos,
                       eye, offsets(mesh)[0])
    uv = interp(mesh.uvs.astype(np.float32)) if mesh.uvs is not None else np.zeros((len(pix), 2))  # texture lookups
    frame = {"pix": pix, "mat": mesh.face_material[f], "pos": pos, "n": n, "t": t, "b": b, "wo": wo_clamped,
             "wo_local": wo_local, "origin": start["origin"], "uv": uv}
    # Back faces stay black, unsampled: every ray would leave behind the face and meet it (the SG renderer's rule)
    front = ~seen_from_behind(mesh.vertices.astype(np.float32), mesh.faces, f, n, sf["wo"])
    return {k: v[front] for k, v in frame.items()}


def missing_provenance(scene, truths=None) -> list:
    """Indices of the scene's effective materials, on faces of its mesh and without a truth in `truths`, that
    do not record how they were baked (`EffectiveBRDF.provenance` None): those `render` cannot judge exactly."""
    given = _check_truths(truths, scene.materials)
    used = {int(i) for i in np.unique(scene.mesh.face_material)}
    return [i for i, m in enumerate(scene.materials)
            if isinstance(m, EffectiveBRDF) and i in used and i not in given and m.provenance is None]


def render(scene, backend="auto", samples: int = 256, seed: int = 0, truths=None, progress=None,
           batch: int = DEFAULT_BATCH, fallback=None, truth_facets: int = TRUTH_FACETS, truth_seed=None,
           truth_bounces: int = 1, truth_paths: int = BOUNCE_PATHS, truth_directions=None):
    """Render `scene` (a `render.Scene`) by Monte Carlo → `render.Rendering`.

    samples: samples per hit pixel, shared out over the pixel's sampling strategies (at least 2 each: a
        variance needs two; fewer is a ValueError).
    seed: the same seed (and batch) gives the same image.
    truths: {material index: GroundTruth} (or a list aligned with scene.materials): the exact f̄ of
        effective materials, given by hand.
    truth_facets, truth_seed: the ground truth of every other effective material in view is
        `truth.truth_of(material, truth_facets, truth_seed)` (truth_seed None: the bake's seed + 1), computed
        from what the material records of its bake and cached beside its material file (`<name>.truth.npz`)
        and in memory; a material that records nothing is a ValueError naming it.
    truth_bounces, truth_paths: `bounces` and `paths` of those ground truths (`wb.ground_truth`'s: B in [1, 16],
        1 the single-bounce truth; B > 1 adds B − 1 bounces of light inside the tiled surface, estimated with
        `truth_paths` paths per direction pair); part of the cache key when B > 1. A truth given in `truths`
        is used as it is.
    truth_directions: the K of those ground truths' K×K direction grids (None: each material's own K; up to
        64). The table is interpolated between its nodes, so a highlight narrower than the grid's spacing is
        blurred in the reference itself: for sharp small-scale BRDFs ask for a finer grid than the bake's
        (docs/design.md §3.4). The truth's cost grows as K⁴ × truth_facets.
    fallback: None, or "sg": materials without a truth given use their fit (an SG bake's
        `EffectiveBRDF.eval(method="sg-exact")`, an ASG bake's own lobes; not exact), with a warning; nothing is
        computed for them.
    batch: samples (pixels × samples) per batch, bounding memory (~400 bytes a sample).
    progress: a `progress.Progress`, or True/False/None (None: shown on a terminal); the ground truths
        computed report their stages there too.

    info: backend, device, method "mc", samples, seed, stderr (H, W, 3) float32 per-pixel standard error,
    stderr_rms / stderr_max over the hit pixels' RGB values, strategies {material: {name: samples per pixel}},
    effective_brdf {material: what f̄ was}, truth_source {material: "given", "computed", "memory" or the cache
    file read}, rays (shadow rays traced), clamped (samples whose contribution was non-finite or had a zero
    pdf, set to 0; 0 in a correct run), width, height, hit_pixels.
    timings (s): gbuffer, truth (ground truths computed or read), sample (directions and pdfs), shade
    (radiance and BRDF), visibility, total.
    """

    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a warp_biscale.render.Scene, got {type(scene).__name__}")
    samples = _check_int("samples", samples, 2)
    seed = _check_int("seed", seed, 0)
    batch = _check_int("batch", batch, 1)
    truth_of = _check_truths(truths, scene.materials)
    if not (fallback is None or (isinstance(fallback, str) and fallback in FALLBACKS[1:])):
        raise ValueError(f"fallback must be None or 'sg', got {fallback!r}")
    try:
        truth_facets = _check_count(truth_facets)
    except ValueError:
        raise ValueError(f"truth_facets must be an integer in [1, {MAX_FACETS}], got {truth_facets!r}") from None
    if truth_seed is not None:
        truth_seed = _check_int("truth_seed", truth_seed, 0)
    try:
        truth_bounces, truth_paths = _check_bounces(truth_bounces, truth_paths)
    except ValueError as exc:  # the library's message, with this function's argument names
        raise ValueError(f"truth_{exc}") from None
    if truth_directions is not None and (isinstance(truth_directions, bool) or not isinstance(
            truth_directions, (int, np.integer)) or not 2 <= truth_directions <= MAX_TRUTH_DIRECTIONS):
        raise ValueError(f"truth_directions must be an integer grid size K in [2, {MAX_TRUTH_DIRECTIONS}] or None "
                         f"(each material's own K), got {truth_directions!r}")
    if fallback is None:
        missing = missing_provenance(scene, truth_of)
        if missing:
            i = missing[0]
            raise ValueError(
                f"effective material {i} does not record how it was baked (a material file of format 1, or "
                f"built by hand), so its ground truth cannot be computed: pass it by hand (truths={{{i}: "
                f"wb.ground_truth(tile, materials, directions={scene.materials[i].directions})}}), re-bake it, "
                "or pass fallback='sg' to use its fit (not exact)")
    backend = get_backend(backend)
    progress = progress if isinstance(progress, Progress) else Progress(progress)
    timings = {"gbuffer": 0.0, "truth": 0.0, "sample": 0.0, "shade": 0.0, "visibility": 0.0}
    t_all = time.perf_counter()
    mesh, cam = scene.mesh, scene.camera
    h, w = cam.height, cam.width

    env = scene.environment
    env_strategy = _EnvironmentStrategy(env) if env is not None else None
    if env_strategy is not None and env_strategy.total <= 0:
        env_strategy = None  # a black map: nothing to sample (its lookups are 0; environment_is_sampled)
    lights = scene.lights_packed.astype(np.float64)
    materials, plans, labels = {}, {}, {}
    for i, m in enumerate(scene.materials):
        if isinstance(m, EffectiveBRDF):
            materials[i] = _EffectiveMaterial(m, truth_of.get(i))
            labels[i] = materials[i].label
        elif isinstance(m, Textured):
            materials[i] = _TexturedMaterial(m)
        else:
            materials[i] = _AnalyticMaterial(m)
        strategies, weights, terms = _plan(env_strategy, materials[i], len(lights))
        if samples < 2 * len(strategies):
            raise ValueError(f"samples={samples} is too few for material {i}'s {len(strategies)} sampling strategies "
                             f"({', '.join(st.name for st in strategies)}): give at least {2 * len(strategies)} "
                             "(2 each)")
        plans[i] = (strategies, _allocate(weights, samples) if strategies else [], terms)

    t0 = time.perf_counter()
    g = backend.trace_primary(mesh, cam)
    frame = _gbuffer_frame(scene, g)
    timings["gbuffer"] = time.perf_counter() - t0
    image = np.zeros((h * w, 3))
    stderr = np.zeros((h * w, 3))
    if env is not None:
        miss = np.flatnonzero(np.asarray(g.face) < 0)
        image[miss] = env.lookup(cam.rays()[1][miss])
    sources = {i: "given" for i in labels if i in truth_of}
    t0 = time.perf_counter()
    for i in labels:
        if i in truth_of:
            continue
        if not np.any(frame["mat"] == i):  # out of view: no truth is needed
            labels[i] = "not in view: no ground truth computed" if fallback is None else labels[i]
            continue
        if materials[i].strategy is not None:  # (a glossy material it cannot sample refuses before its truth)
            materials[i].strategy.lobes()
        if fallback == "sg":
            warnings.warn(f"Monte Carlo: no ground truth for effective material {i} (fallback='sg'); using "
                          f"{fit_label(scene.materials[i])} (its fit), so the reference is not exact for it",
                          stacklevel=2)
            continue
        gt, sources[i] = cached_truth(scene.materials[i], truth_facets, truth_seed, backend,
                                      _Prefixed(progress, f"truth of material {i}: "), truth_bounces, truth_paths,
                                      truth_directions)
        materials[i].use_truth(gt)
        labels[i] = materials[i].label
    timings["truth"] = time.perf_counter() - t0

    eps = offsets(mesh)[0]
    stats = {"rays": 0, "clamped": 0}
    n_hit = len(frame["pix"])
    progress.stage(f"monte carlo ({samples} spp)", max(n_hit, 1))
    per_batch = max(1, batch // samples)
    for mi in np.unique(frame["mat"]):
        mi = int(mi)
        strategies, counts, terms = plans[mi]
        sel = np.flatnonzero(frame["mat"] == mi)
        for bi, lo in enumerate(range(0, len(sel), per_batch)):
            rows = sel[lo:lo + per_batch]
            ctx = {k: v[rows] for k, v in frame.items()}
            rng = np.random.default_rng([seed, mi, bi])  # one stream per (material, batch): reproducible
            mean, err = _render_batch(ctx, materials[mi], strategies, counts, terms,
                                      env if env_strategy is not None else None, lights, eps, mesh, backend, rng,
                                      stats, timings)
            image[ctx["pix"]] = mean
            stderr[ctx["pix"]] = err
            progress.advance(len(rows))
    progress.done()

    if not (np.all(np.isfinite(image)) and (image >= 0).all()):  # every sample was checked: this is a bug
        raise FloatingPointError("Monte Carlo produced a non-finite or negative pixel")
    hit_err = stderr[frame["pix"]]
    timings["total"] = time.perf_counter() - t_all
    info = {
        "backend": backend.name, "device": backend.device, "method": "mc", "samples": samples, "seed": seed,
        "stderr": stderr.reshape(h, w, 3).astype(np.float32),
        "stderr_rms": float(np.sqrt(np.mean(hit_err**2))) if n_hit else 0.0,
        "stderr_max": float(hit_err.max()) if n_hit else 0.0,
        "strategies": {int(i): {st.name: c for st, c in zip(*plans[i][:2])} for i in np.unique(frame["mat"])},
        "effective_brdf": labels, "truth_source": sources, "rays": stats["rays"], "clamped": stats["clamped"],
        "lights": len(lights), "width": w, "height": h, "hit_pixels": n_hit,
    }
    return Rendering(image.reshape(h, w, 3).astype(np.float32), timings, info)


MIN_SHARE = 0.1  # every strategy keeps at least this weight (before normalising): MIS stays robust
LIGHT_SHARE = 0.25  # a light's weight: sampled exactly, it needs fewer samples (1 → 0.25: −28 % error on a bench scene)


def environment_is_sampled(env) -> bool:
    """Whether `render` samples environment `env` (None, or a black map, it does not): its two strategies."""
    return env is not None and _EnvironmentStrategy(env).total > 0


def _plan(env_strategy, mat, n_lights):
    """The strategies of one material, their weights (shares of the samples) and the terms each one serves.

    → (strategies, weights, terms); a term is (light index, or None for the environment; indices of its
    strategies). The environment term is sampled by the environment, the cosine lobe and the BRDF; light l's
    term by its emitter and the BRDF only: its emitter is a vMF sampled exactly, so cosine samples would add
    nothing but rare hits on a small light (a skewed estimate whose sample variance understates its error).

    Weights only move variance, never the mean: the environment by its distance from uniform (a constant map is
    sampled as well by the cosine lobe), the cosine lobe and the BRDF by the material's diffuse and specular
    shares (mean kd, mean ks), each light LIGHT_SHARE; every one at least MIN_SHARE."""
    strategies, weights, terms = [], [], []
    kd, ks = mat.albedos
    diffuse = kd / (kd + ks) if kd + ks > 0 else 0.5
    brdf = mat.strategy
    if env_strategy is not None:
        strategies += [env_strategy, _CosineStrategy()]
        weights += [env_strategy.peakedness, diffuse]
        if brdf is not None:
            strategies.append(brdf)
            weights.append(1 - diffuse)
        terms.append((None, list(range(len(strategies)))))
    elif brdf is not None and n_lights:
        strategies.append(brdf)
        weights.append(1 - diffuse)
    b_index = [strategies.index(brdf)] if brdf is not None and brdf in strategies else []
    for k in range(n_lights):
        strategies.append(_LightStrategy(k))
        weights.append(LIGHT_SHARE)
        terms.append((k, [len(strategies) - 1] + b_index))
    return strategies, np.maximum(np.asarray(weights, np.float64), MIN_SHARE), terms


def _allocate(weights, samples):
    """Integer sample counts ∝ weights summing to `samples`, each >= 2 (a variance needs two): 2 each, and the
    rest by largest remainder."""
    s = len(weights)
    share = weights / weights.sum() * (samples - 2 * s)
    counts = np.floor(share).astype(np.int64)
    counts[np.argsort(counts - share)[: samples - 2 * s - counts.sum()]] += 1
    return [int(c) + 2 for c in counts]


def _strata(count):
    """(stratum id (count,), stratum start (S,), stratum size (S,)) of count >= 2 samples of one strategy: strata
    of STRATUM samples, the last one also holding the remainder (one stratum if count < 2·STRATUM). Stratum h
    covers u[0] in [start_h, start_h + size_h)/count: widths ∝ sizes, so the plain mean stays unbiased."""
    h = np.minimum(np.arange(count) // STRATUM, max(count // STRATUM, 1) - 1)
    size = np.bincount(h)
    return h, np.concatenate([[0], np.cumsum(size)[:-1]]), size


def _stratified_uniforms(rng, npix, count, dims):
    """(dims, npix, count) uniforms in [0, 1), u[0] stratified (`_strata`), the rest independent. Several
    samples a stratum keep an unbiased variance estimate (`_stratified_variance`) while stratifying the
    strategy's main choice: e.g. how many environment samples land in the sun no longer varies binomially."""
    u = rng.random((dims, npix, count))
    h, start, size = _strata(count)
    u[0] = (start[h] + size[h] * u[0]) / count
    return u


def _stratified_variance(y):
    """Σ_h n_h·s_h² over the strata of one strategy's samples y (B, count, 3), s_h² the sample variance in
    stratum h: an unbiased estimate of count² × the variance of their mean."""
    h, start, size = _strata(y.shape[1])
    mean = np.add.reduceat(y, start, axis=1) / size[None, :, None]
    dev2 = np.add.reduceat((y - mean[:, h]) ** 2, start, axis=1)
    return (dev2 * (size / (size - 1))[None, :, None]).sum(1)


def _render_batch(ctx, mat, strategies, counts, terms, env, lights, eps, mesh, backend, rng, stats, timings):
    """The estimate and its standard error, (B, 3) each, for the B pixels of one batch (one material)."""
    npix = len(ctx["n"])
    if not strategies:  # no environment and no lights: nothing lights the surface
        return np.zeros((npix, 3)), np.zeros((npix, 3))
    t0 = time.perf_counter()
    if len(lights):
        axis, eta, amp, _ = light_sg(lights, ctx["pos"])
        ctx["light_axis"], ctx["light_eta"], ctx["light_amp"] = axis, eta, amp
        # A point light's shadow ray stops `eps` short of its centre, measured from the moved origin (trace_shadows).
        to_light = lights[None, :, 1:4] - ctx["origin"][:, None]
        ctx["light_tmax"] = np.where(lights[None, :, 0] == 1, np.linalg.norm(to_light, axis=-1) - eps, np.inf)
    if hasattr(mat.strategy, "setup") and mat.strategy in strategies:
        mat.strategy.setup(ctx)
    samples = sum(counts)
    sid = np.repeat(np.arange(len(strategies)), counts)  # the strategy of each sample column
    w = np.concatenate([st.sample(ctx, _stratified_uniforms(rng, npix, c, st.dims))
                        for st, c in zip(strategies, counts)], 1)  # (B, N, 3)
    pdfs = [st.pdf(ctx, w) for st in strategies]
    # Balance heuristic per term: a term's sample is weighted by 1 / Σ_{k in the term} n_k p_k(ω) (times N: the
    # plain mean below), and only the term's own strategies' samples count for it.
    p_term = [sum((counts[k] / samples) * pdfs[k] for k in members) for _, members in terms]
    in_term = [np.isin(sid, members) for _, members in terms]
    timings["sample"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    wf = w.reshape(-1, 3)
    pix = np.repeat(np.arange(npix), samples)
    col = np.tile(np.arange(samples), npix)
    # Only directions above the shading horizon contribute. One below the face's own plane is traced like any
    # other from the lifted origin, as the SG renderer's shadow rays are (it may hit the face itself).
    act = np.flatnonzero(_dot(wf, ctx["n"][pix]) > 0)
    wa, pa, ca = wf[act], pix[act], col[act]
    f = mat.f(ctx, pa, wa)  # (K, 3)
    unbounded = np.zeros((len(act), 3))  # environment and directional lights: occluded by any hit
    bounded = []  # (light index, weighted term (K, 3)) of point lights: occluded only before the light
    bad = np.zeros(len(act), bool)
    for (k, _), members, p in zip(terms, in_term, p_term):
        use = np.flatnonzero(members[ca])  # the active samples of this term's strategies
        wu, pu = wa[use], pa[use]
        if k is None:
            rad = env.lookup(wu)
        else:
            rad = ctx["light_amp"][pu, k] * sg.evaluate(wu, ctx["light_axis"][pu, k], ctx["light_eta"][pu, k])[:, None]
        g = rad * f[use]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            yu = g / p.reshape(-1)[act[use], None]
        # A positive integrand at zero pdf, or an overflow, would be a bug in a strategy: drop and count it.
        wrong = ~np.isfinite(yu).all(1) | (yu < 0).any(1)
        bad[use] |= wrong & (g.max(1) > 0)
        yu[wrong] = 0.0
        y = np.zeros((len(act), 3))
        y[use] = yu
        if k is None or lights[k, 0] == 0:
            unbounded += y
        else:
            bounded.append((k, y))
    stats["clamped"] += int(bad.sum())
    timings["shade"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    need = unbounded.max(1) > 0
    for _, c in bounded:
        need |= c.max(1) > 0
    occluded = np.zeros(len(act), bool)
    if need.any():
        occluded[need] = backend.trace_occluded(mesh, ctx["origin"][pa[need]], wa[need], np.inf)
    stats["rays"] += int(need.sum())
    y = np.where(occluded[:, None], 0.0, unbounded)
    # A sample that hit something may still see a point light in front of the hit: trace those again, one call.
    again = [(k, c, np.flatnonzero(occluded & (c.max(1) > 0))) for k, c in bounded]
    if any(len(r) for _, _, r in again):
        o = np.concatenate([ctx["origin"][pa[r]] for _, _, r in again])
        d = np.concatenate([wa[r] for _, _, r in again])
        tmax = np.concatenate([ctx["light_tmax"][pa[r], k] for k, _, r in again])
        hit = backend.trace_occluded(mesh, o, d, tmax)
        stats["rays"] += len(hit)
        start = 0
        for _, c, r in again:
            seen = r[~hit[start:start + len(r)]]
            y[seen] += c[seen]
            start += len(r)
    for _, c, _ in again:  # unoccluded samples see every point light
        y[~occluded] += c[~occluded]
    timings["visibility"] += time.perf_counter() - t0

    ys = np.zeros((npix * samples, 3))
    ys[act] = y
    ys = ys.reshape(npix, samples, 3)
    # Var(mean) = Σ over strategies and their strata of n_h·σ_h² / N²: strata are independent of each other.
    var = sum(_stratified_variance(ys[:, sid == k]) for k in range(len(counts)))
    return ys.mean(1), np.sqrt(var) / samples
