"""Per-pixel SG shading (Wang 2009 §7, Iwasaki 2012 §5): material packing and the float64 reference.

The shade stage (`kernels/shade.py`, `cl/shade.cl`) computes, for every pixel of the G-buffer, the
outgoing radiance L(x, ωo) = ∫ L(ω) V(x, ω) f(ω, ωo) (n·ω)⁺ dω — for an effective BRDF f̄, whose
tables already hold the cosine (docs/design.md §4), the same integral with f̄/cos θi — with every factor an
SG or tabulated against one:

- **Lighting.** Diffuse: the environment's K SG lobes (`lighting.EnvironmentSGs`, Iwasaki §5, Wang §6)
  and each light's SG emitter (`scene.light_sg`). Specular: the prefiltered environment
  Λ(p, η) (the SG-weighted average radiance, `lighting.PrefilteredEnvironment`, Wang Eq. 35) at
  the warped BRDF lobe, and the SG product with each light's emitter.
- **BRDF lobes.** An analytic BRDF's NDF is one SG about n (`sg.specular_lobe`: Blinn–Phong
  η = exponent, Cook–Torrance and Ward η = 2/m²; a measured BRDF's SG fit is one or two such lobes, each
  shaded as one, `brdf.sg_lobes`); an effective BRDF's specular part is Iwasaki's
  Eq. 15: per NDF lobe j and small-scale material m an SG in h of sharpness ηjηs/(ηj + ηs) and
  amplitude 2π·M·μj/(ηj + ηs). Both are warped to ωi (Wang Eq. 18–21): axis ξ' = 2(ωo·ξ)ξ − ωo,
  sharpness η/(4 ωo·ξ); the smooth factors (M, μj) are taken at the warped axis (Wang Eq. 22). An analytic
  row's environment lobe is then scaled by c(ωo), its exact specular albedo over the lobe's own under a
  constant environment (`specular_correction`), so that a constant environment is exact (but where c is clipped,
  at the most grazing views).
- **Cosine and horizon.** ∫ G(ω; ξ, η)(n·ω)⁺ dω = ∫G · cosine_fraction(ξ·n, η), exact and tabulated
  (`sg.lighting_table`), rather than Wang's one-lobe cosine fit (Eq. 40), whose 17 % error at normal
  incidence would dominate our error budget.
- **Visibility.** Environment lobes are shadowed through the SSDF (Wang §5): θd = SSDF(ξ') at the
  lobe axis, interpolated per pixel from PCA coefficients at the vertices, and the lobe keeps the
  fraction visible_fraction(sin θd, η)/visible_fraction(ξ'·n, η) (Wang's lune, `sg.visible_fraction`)
  — the occlusion beyond the horizon, since the cosine fraction already clips at the horizon (our
  SSDF includes it). Without occluders (a lone convex object) the SSDF is skipped and that factor
  is 1. Lights are shadowed by rays to points of the emitter's disc (`backend.trace_shadows`, one
  ray: its centre), each light scaled by its visible share (light_vis / 255).
- **Broad lobes' visibility per pixel.** The SSDF is a per-vertex summary: for a broad lobe (the
  ambient of a constant map, a sky's wide lobes, a rough material's) it sees too little of the
  visibility near a contact, and its vertex interpolation blurs over a coarse receiver. With S
  occlusion rays per pixel (`backend.trace_occlusion`: cosine-distributed over the geometric normal's
  hemisphere, one bit each) a lobe of sharpness η keeps, instead, the ratio estimate
  Σ G(ωi)(n·ωi)⁺/(ng·ωi)·Vi / Σ G(ωi)(n·ωi)⁺/(ng·ωi) (`ray_share`): exactly 1 on an unoccluded surface,
  and for a uniform lobe the pixel's ambient occlusion. Rays alone shadow η ≤ S/8; the SSDF alone
  η ≥ S/2, which the rays sample too sparsely; between, the two blend in log η (`ray_weight`).
- **Sharp environment lobes' visibility per pixel.** Up to trace.LOBE_RAY_LOBES of the sharp, powerful
  environment lobes (a sun, a softbox: η ≥ SHARP_LOBE_ETA and SHARP_LOBE_SHARE of the power or more,
  `sharp_lobes_first`) get, in the
  diffuse term, trace.LOBE_RAYS rays each over their own cap (`backend.trace_lobe_rays` of
  `ShadeInputs.sharp_lobes()`), weighed as the occlusion rays are but with the cap's solid-angle weight
  (`lobe_ray_share`): a penumbra per pixel, not interpolated from the receiver's vertices. Another lobe of
  η ≥ SHARP_LOBE_ETA whose axis lies in a ray lobe's cap (the fit often splits a sun into several lobes)
  is weighed through that lobe's rays (`nearest_ray_lobe`). Traced with the occlusion rays (none when S = 0).
- **Diffuse magnitude.** The environment lobes' diffuse sum is scaled per channel by the exact
  irradiance over the lobes' own (`irradiance_scale`; the exact one is the lobes' plus the residual
  map `lighting.irradiance_residual` at n): the lobes shape the shadows, the map gives the magnitude.

Material packing (what the kernels read; `pack_materials`):
``mat_info`` (Mat, 4) int32 [type (0 analytic, 1 effective), index, specular, texture slot]: an analytic
material's rows are ``analytic[index : index + R]``, one per SG lobe of its SG form (`brdf.sg_lobes`: R = 2 for
a measured BRDF's two-lobe fit, whose second row has kd = 0), and specular is R, or 0 where no row has a
specular term (an effective material's: 1 or 0); the slot
is −1, or for a `svbrdf.Textured` analytic material the first of its three ``tex_info`` rows (kd, ks,
parameter map; an absent map is a shared 1×1 texture of ones); ``tex_info`` row 1 + 2r is analytic row r's
specular correction (`specular_correction`: (24, W) texels, W = 6 values of φo for an anisotropic row, else 1;
a Lambert row's the 1×1 texture of ones; a Textured material's rows under a parameter map a column per p1 step of
its moment table instead),
row 2 + 2r its moment table (`moment_table`: (33, 2W) texels, a Lambert row's 2×2 zeros);
``tex_info`` (T, 4) int32 [texel offset into tex_data, H, W, 0]; ``tex_data``
float32 (Σ H·W·3), row-major RGB texels (a parameter map is stored in all three channels; the kernels read
channel 0). The kernels read each analytic row into per-pixel values, scale them by the maps at the pixel's UV
(``uvs`` (V, 2), bilinear, repeat: `svbrdf.sample`) and use only those values afterwards;
``analytic`` (A, 9) float32 [brdf kind, kd rgb, ks rgb, p1, p2] (brdf.pack_materials' row with the kind first);
``eff_info`` (E, 8) int32 [K, J, n_sub, lobe_offset, sub_offset, table_offset, diffuse_offset, lobe type
(`effective.SG_LOBES` 0, `effective.ASG_LOBES` 1)];
``eff_lobes`` (ΣJ + Σn_sub·J of the ASG materials, EFF_LOBE_WIDTH = 9) float32 in the tile frame
(`EffectiveBRDF.shade_lobes`): an SG lobe [axis, η, 0 …], an ASG lobe [z, 0, x, λ, μ] (y = z × x), and after an
ASG material's J lobes its tangent orders, row J·(1 + s) + j for sub-row s and lobe j [o_c, o_s, 0 …]
(`ASGBRDF.tangent_rows`, read for anisotropic small-scale BRDFs); ``eff_sub`` (Σn_sub, 9) like ``analytic``,
n_sub rows per effective material: one per SG lobe of each small-scale material, each row with its material's
tables below;
``eff_tables`` float32, per effective material and sub-row m the (K², K², J, 3) table of
μ (index table_offset + (((m·K² + i)·K² + o)·J + j)·3 + c), the bake's own array where every small-scale
material has one row (a view, no copy: a material edit keeps it, and the backends then keep its device copy),
else its rows per sub-row, made once and kept (`_tables_per_row`: the same arrays again at the next pack);
``eff_diffuse`` float32 (n_sub, L, K², K², 3) per effective material: each sub-row's small-scale material's
energy Σ_j μ_mj∫G_j and its levels prefiltered for broad environment lobes (`EffectiveBRDF.energy_levels`,
also kept by a material edit); the diffuse term is Σ_m kd_m/π times the level a lobe of sharpness η reads
(`effective.diffuse_level(η)`). The
lookups divide each ωi corner by its cos θi (μ/cos θi is what is interpolated, as `EffectiveBRDF.eval` does).
An effective material's tile frame is (tangent, bitangent, normal)
with the tangent along the mesh's u direction (`scene.vertex_tangents`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import brdf as brdf_mod
from . import directions as dirs
from . import asg as asg_mod
from . import litsphere, sg, svbrdf
from .effective import ASG_LOBES, DIFFUSE_LEVEL_ETAS, EFF_LOBE_WIDTH, EffectiveBRDF, diffuse_level
from .model import Frame
from .lighting import SHADOW_LOBE_AXES, prefiltered_lookup
from .scene import light_sg, vertex_tangents
from .environment import equirect_bilinear
from .ssdf import ssdf_eval
from .trace import (LOBE_COS_MIN, LOBE_RAY_LOBES, LOBE_RAYS, VISIBLE, check_ray_part, lobe_ray_directions,
                    occlusion_directions, oriented_face_normals, part_rays, pixel_parts)
from .svbrdf import Textured

__all__ = ["pack_materials", "shade_reference", "surface_frames", "MIN_COS_VIEW", "ray_share", "ray_weight",
           "RAYS_ONLY", "SSDF_ONLY", "SHARP_LOBE_ETA", "sharp_lobes_first", "nearest_ray_lobe", "lobe_ray_share"]

SHARP_LOBE_ETA = 8.0  # environment lobes at least this sharp may get lobe rays (SSDF_ONLY × the default 16 rays)
SHARP_LOBE_SHARE = 0.1  # ... if they carry at least this share of the environment's power (a sun, not a sky's gradient)
RAYS_ONLY = 1 / 8  # × occlusion samples: lobes this broad or broader are shadowed by the rays alone
SSDF_ONLY = 1 / 2  # × occlusion samples: lobes this sharp or sharper by the SSDF alone


def ray_weight(eta, samples: int):
    """The occlusion rays' weight against the SSDF's for a lobe of sharpness `eta` (1: rays alone): 1 at
    η ≤ RAYS_ONLY·S, 0 at η ≥ SSDF_ONLY·S, linear in log η between; 0 without rays (S = 0)."""
    eta = np.asarray(eta, np.float64)
    if samples == 0:
        return np.zeros_like(eta)
    lo, hi = RAYS_ONLY * samples, SSDF_ONLY * samples
    return np.clip(np.log(hi / np.maximum(eta, 1e-30)) / np.log(hi / lo), 0.0, 1.0)


def sharp_lobes_first(env_sgs) -> tuple[np.ndarray, int]:
    """(env_sgs reordered, M): the (K, 7) [axis, η, rgb] lobes with, first, the M ≤ trace.LOBE_RAY_LOBES of
    η ≥ SHARP_LOBE_ETA and at least SHARP_LOBE_SHARE of all the lobes' power (mean radiance × ∫G) with the most
    power, most powerful first, then the rest in their order. Those M get lobe rays."""
    env_sgs = np.asarray(env_sgs)
    if len(env_sgs) == 0:
        return env_sgs, 0
    eta = env_sgs[:, 3].astype(np.float64)
    power = env_sgs[:, 4:7].astype(np.float64).mean(1) * sg.integral(eta)
    sharp = np.flatnonzero((eta >= SHARP_LOBE_ETA) & (power > 0) & (power >= SHARP_LOBE_SHARE * power.sum()))
    first = sharp[np.argsort(-power[sharp], kind="stable")][:LOBE_RAY_LOBES]
    rest = np.setdiff1d(np.arange(len(env_sgs)), first)
    return np.ascontiguousarray(env_sgs[np.concatenate([first, rest])]), len(first)


def nearest_ray_lobe(env_sgs, n_sharp: int, index: int) -> int:
    """The ray lobe (one of env_sgs' first n_sharp rows) that environment lobe `index` is shadowed through:
    itself if it is one; else, for a lobe of η ≥ SHARP_LOBE_ETA (a sun the fit split into several lobes, say),
    the ray lobe nearest its axis if the axis lies in that lobe's cap (1 − cos θ = 2/η); −1: none (the SSDF)."""
    if index < n_sharp:
        return index
    lobe = np.asarray(env_sgs[index], np.float64)
    if n_sharp == 0 or lobe[3] < SHARP_LOBE_ETA:
        return -1
    rays = np.asarray(env_sgs[:n_sharp], np.float64)
    c = rays[:, :3] @ lobe[:3]
    best = int(np.argmax(c))
    return best if c[best] >= max(1.0 - 2.0 / rays[best, 3], LOBE_COS_MIN) else -1


def lobe_ray_share(axis, eta, n, directions, solid, blocked, known=None):
    """(R,) the share of a lobe's ∫ G(ω; axis, η)(n·ω)⁺ dω that its lobe rays `directions` (R, L, 3)
    (solid-angle weights `solid` (R, L)) see unblocked: Σ wi·(1 − blocked_i) / Σ wi over the rays of `known`
    (R, L) bool (None: all), wi = G(ωi)(n·ωi)⁺·solid_i (a ray below the geometric horizon was not traced: its
    bit is clear); 1 where every weight is below 1e-30."""
    c = np.einsum("rlk,rk->rl", directions, axis)
    w = np.exp(np.asarray(eta, np.float64)[:, None] * (c - 1.0)) * np.maximum(
        np.einsum("rlk,rk->rl", directions, n), 0.0) * solid * (1.0 if known is None else known)
    total = w.sum(1)
    return np.where(total > 1e-30, (w * ~blocked).sum(1) / np.maximum(total, 1e-300), 1.0)


def ray_share(axis, eta, n, n_geo, directions, blocked, known=None):
    """(R,) the share of a lobe's ∫ G(ω; axis, η)(n·ω)⁺ dω that the occlusion rays see unblocked: per pixel
    (R rows) the ratio Σ wi·(1 − blocked_i) / Σ wi over those of its S rays `directions` (R, S, 3)
    (cosine-distributed about n_geo) that `known` (R, S) bool marks traced (None: all), wi = G(ωi)·(n·ωi)⁺/(n_geo·ωi);
    1 where every weight is below 1e-30."""
    c = np.einsum("rsk,rk->rs", directions, axis)
    w = (np.exp(np.asarray(eta, np.float64)[:, None] * (c - 1.0))
         * np.maximum(np.einsum("rsk,rk->rs", directions, n), 0.0)
         / np.maximum(np.einsum("rsk,rk->rs", directions, n_geo), 1e-6)) * (1.0 if known is None else known)
    total = w.sum(1)
    seen = (w * ~blocked).sum(1)
    return np.where(total > 1e-30, seen / np.maximum(total, 1e-300), 1.0)


# The six axis lobes' one walk (axis_lobe_start) takes exp(−η)·exp(±η ω) for exp(η(±ω − 1)): exact in float32 while
# neither factor leaves its range (η up to about 85); six lobes sharper than this are walked one by one.
AXIS_WALK_ETA_MAX = 16.0


def axis_lobe_start(env_sgs) -> int:
    """The row of env_sgs (K, ≥4) where `lighting.shadow_lobes`' six lobes along ±y, ±x, ±z (its
    SHADOW_LOBE_AXES, in that order, one sharpness η ≤ AXIS_WALK_ETA_MAX) begin, or −1. The shade kernels weigh
    the occlusion rays for these six in one walk of the rays (a ray's three exponentials exp(η ω_x), exp(η ω_y),
    exp(η ω_z) and their reciprocals give all six weights), not six: the same shares as `ray_share`'s, to float32
    rounding."""
    rows = np.asarray(env_sgs, np.float64)
    axes = SHADOW_LOBE_AXES
    if rows.ndim != 2 or rows.shape[1] < 4:
        return -1
    for start in range(len(rows) - len(axes) + 1):
        block = rows[start:start + len(axes)]
        if (np.array_equal(block[:, :3], axes) and np.all(block[:, 3] == block[0, 3])
                and 0.0 < block[0, 3] <= AXIS_WALK_ETA_MAX):
            return start
    return -1


IRRADIANCE_RATIO_MAX = 1e3  # the diffuse term's E/E_sg stops here: it then never passes kd·E
MIN_COS_VIEW = 1e-4  # ωo·n is clamped here: silhouette pixels whose interpolated normal faces away


def _analytic_rows(m, anisotropic: bool = False) -> np.ndarray:
    """(R, 9) float32: the shade kernels' rows of a BRDF, one per SG lobe of its SG form (`brdf.sg_lobes`: the
    BRDF itself, or a measured one's SG fit of one or two lobes, the first carrying kd). `anisotropic`: take an
    anisotropic BRDF (a large-scale material, in the frame of the mesh's tangents), else refuse it."""
    kinds, params = brdf_mod.pack_materials(list(brdf_mod.sg_lobes(m)), anisotropic=anisotropic)
    return np.concatenate([kinds[:, None], params], 1).astype(np.float32)


def _sub_rows(m) -> np.ndarray:
    """An effective material's small-scale BRDF as the shade kernels' rows (`_analytic_rows`), its diffuse slot
    holding the Lambertian albedo its facets average to (`brdf.diffuse_albedo`: Ashikhmin–Shirley's is not kd).
    Anisotropic ones only reach here from a bake that convolves their NDF per lobe (the ASG bake's)."""
    rows = _analytic_rows(m, anisotropic=True)
    if isinstance(m, brdf_mod.AshikhminShirley):
        rows[0, 1:4] = brdf_mod.diffuse_albedo(m)
    return rows


def _specular_rows(m) -> int:
    """How many of `_analytic_rows(m)` the specular loop reads: all of them, or 0 where none has a specular
    term (Lambert, ks = 0)."""
    if isinstance(m, Textured):  # the maps only scale ks: no specular term appears where ks = 0
        m = m.brdf
    lobes = brdf_mod.sg_lobes(m)
    # (Ashikhmin–Shirley's Fresnel term reflects at grazing angles even where Rs = 0.)
    spec = any(isinstance(b, brdf_mod.AshikhminShirley)
               or not isinstance(b, brdf_mod.Lambert) and float(np.max(b.ks)) > 0 for b in lobes)
    return len(lobes) if spec else 0


# The environment's specular term of an analytic row (Wang 2009's warped SG lobe; Xu 2013 §5.2's warped ASG for
# the anisotropic kinds) takes its magnitude from M at the mirror direction times the lobe's cosine-weighted
# integral. That is right near normal incidence only: towards grazing the BRDF's lobe leaves the mirror direction
# and the horizon clips the SG where it does not clip the BRDF, so a sphere's rim under a constant environment was
# far off the reference (bench/anisotropic_accuracy.py). Each row's environment lobe is therefore scaled by
# c(ωo) = A_s(ωo)/E(ωo): the row's exact specular albedo ∫ f_s (n·ωi)⁺ dωi over what its lobe gives under a
# constant unit environment (`specular_correction`). Exact under a constant environment (but where c is clipped);
# the lobe still shapes everything else (docs/design.md §5.7 "The environment's specular magnitude of an analytic row").
CORRECTION_COS = 24  # table rows: cos θo = (i + ½)/24, i = 0 … 23
CORRECTION_PHI = 6  # an anisotropic row's columns: φo = (j + ½)/6 · π/2 (both kinds are even in x and in y)
CORRECTION_MAX = 10.0  # c stops here: at grazing a lobe's clipped integral tends to 0
ALBEDO_REACH, ALBEDO_CORE, ALBEDO_TAIL, ALBEDO_PHI = 8.0, 48, 24, 192  # `_half_vector_rule`'s reach and nodes


def _ndf_widths(row) -> tuple[float, float]:
    """The widths (in slope, tan θh) of a row's NDF along the tangent and the bitangent: 1/√η each for its SG,
    1/√(2λ), 1/√(2μ) for its ASG exp(−λ(h·x)² − μ(h·y)²)."""
    kind = int(row[0])
    if kind in brdf_mod.ANISOTROPIC_KINDS:
        lam, mu = brdf_mod.ndf_bandwidths(kind, float(row[7]), float(row[8]))
        return float(1.0 / np.sqrt(2.0 * max(lam, 1e-12))), float(1.0 / np.sqrt(2.0 * max(mu, 1e-12)))
    _, eta = specular_scale(row, np.ones(1))
    w = float(1.0 / np.sqrt(max(float(eta), 1e-12)))
    return w, w


def _half_vector_rule(wx: float, wy: float) -> tuple[np.ndarray, np.ndarray]:
    """(h (N, 3), weights (N,)): a rule for ∫ g(h) dωh over the upper hemisphere that follows an NDF of widths
    (wx, wy): in slope space (p, q) = (wx·r cos φ, wy·r sin φ), h = (p, q, 1)/√(1 + p² + q²),
    dωh = wx·wy·r dr dφ/(1 + p² + q²)^{3/2}; Gauss–Legendre in r on [0, ALBEDO_REACH] and in 1/r beyond (the tail
    to the horizon), φ evenly (the trapezoid rule: periodic). An elongated lobe is as round here as an isotropic
    one, so its narrow axis is resolved as well as its broad one."""
    x, w = np.polynomial.legendre.leggauss(ALBEDO_CORE)
    r_core, w_core = ALBEDO_REACH * (x + 1) / 2, w * ALBEDO_REACH / 2
    x, w = np.polynomial.legendre.leggauss(ALBEDO_TAIL)
    u, wu = (x + 1) / 2, w / 2
    r_tail, w_tail = ALBEDO_REACH / u, wu * ALBEDO_REACH / (u * u)
    r, wr = np.concatenate([r_core, r_tail]), np.concatenate([w_core, w_tail])
    phi = (np.arange(ALBEDO_PHI) + 0.5) * (2 * np.pi / ALBEDO_PHI)
    rr, pp = np.meshgrid(r, phi, indexing="ij")
    p, q = wx * rr * np.cos(pp), wy * rr * np.sin(pp)
    norm = np.sqrt(1 + p * p + q * q)
    h = np.stack([p / norm, q / norm, 1 / norm], -1).reshape(-1, 3)
    weight = (wx * wy * rr * wr[:, None] * (2 * np.pi / ALBEDO_PHI) / norm**3).ravel()
    return h, weight


def specular_albedo(row, wo_local) -> np.ndarray:
    """(N, 3) a packed row's exact specular albedo ∫ f_s(ωi, ωo)(n·ωi)⁺ dωi (its kd left out) for each ωo (N, 3)
    in the surface frame (n = z, tangent = x), over the half vector (dωi = 4(h·ωo) dωh) by `_half_vector_rule`
    at the NDF's widths (tests/test_env_specular.py checks it against a rule over ωi and, for narrow elongated
    lobes, against importance sampling)."""
    row = np.asarray(row, np.float64)
    h, dh = _half_vector_rule(*_ndf_widths(row))
    params = row[1:9].copy()
    params[0:3] = 0.0  # (the specular term alone)
    kinds = np.array([int(row[0])])
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), h.shape)
    x = np.broadcast_to(np.array([1.0, 0.0, 0.0]), h.shape)
    wo_local = np.asarray(wo_local, np.float64).reshape(-1, 3)
    out = np.zeros((len(wo_local), 3))
    for k, o in enumerate(wo_local):
        ho = h @ o
        wi = 2 * ho[:, None] * h - o
        ok = (ho > 0) & (wi[:, 2] > 0)
        fc = brdf_mod.brdf_cosine_weighted(kinds, params[None], np.zeros(len(h), np.int64), z, wi,
                                           np.broadcast_to(o, h.shape), x)  # f_s cos θi cos θo
        out[k] = (fc * np.where(ok, 4 * ho * dh, 0.0)[:, None]).sum(0) / max(o[2], 1e-300)
    return out


def lobe_energy(row, wo_local, table) -> np.ndarray:
    """(N, 3) what a row's environment lobe gives under a constant unit environment with nothing in the way, as
    `shade_reference` and the kernels form it (M, the warped lobe, its cosine integral, Ashikhmin–Shirley's cap),
    for each ωo (N, 3) in the surface frame."""
    wo_local = np.asarray(wo_local, np.float64).reshape(-1, 3)
    m = len(wo_local)
    n = np.broadcast_to(np.array([0.0, 0.0, 1.0]), wo_local.shape)
    t = np.broadcast_to(np.array([1.0, 0.0, 0.0]), wo_local.shape)
    rows = np.tile(np.asarray(row, np.float64), (m, 1))
    cos_o = np.maximum(wo_local[:, 2], MIN_COS_VIEW)
    cap = None
    if int(row[0]) in brdf_mod.ANISOTROPIC_KINDS:
        axis, eta, amp, _, cap, _ = _anisotropic_environment_lobe(rows, n, t, wo_local, cos_o)
    else:
        amp, eta_s = specular_scale(rows, cos_o)
        axis, eta = _normalize(2 * cos_o[:, None] * n - wo_local), eta_s / (4 * cos_o)
    eta = np.minimum(eta, sg.SHARPNESS_MAX)
    e = sg.integral(eta) * sg.table_lookup(table, 0, _dot(axis, n), eta)
    if cap is not None:
        e = capped_cosine_integral(e, cap, axis, n, eta, table)
    return amp * e[:, None]


def correction_directions(anisotropic: bool) -> np.ndarray:
    """(CORRECTION_COS, W, 3) the ωo of `specular_correction`'s texels (W = CORRECTION_PHI, or 1 for an isotropic
    row, whose φo does not matter)."""
    c = (np.arange(CORRECTION_COS) + 0.5) / CORRECTION_COS
    phi = (np.arange(CORRECTION_PHI) + 0.5) * (np.pi / 2 / CORRECTION_PHI) if anisotropic else np.zeros(1)
    s = np.sqrt(1 - c * c)
    return np.stack(np.broadcast_arrays(s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), c[:, None]), -1)


_CORRECTIONS: dict = {}  # a row's bytes → its table (rows recur across frames and scenes)
_TABLES_KEPT = 256  # per table kind: the correction, the moments


def _kept(cache: dict, key, make) -> np.ndarray:
    """cache[key], made by make() the first time and frozen (one table for every scene that packs the row); the
    oldest entry leaves once the cache holds _TABLES_KEPT."""
    hit = cache.get(key)
    if hit is None:
        hit = make()
        hit.setflags(write=False)
        if len(cache) >= _TABLES_KEPT:
            cache.pop(next(iter(cache)))
        cache[key] = hit
    return hit


def _table_row(row) -> np.ndarray:
    """A packed row as its correction and moment tables are made and kept: kd set to 0, and ks to 1 where ks only
    scales f_s (every kind but Ashikhmin–Shirley, whose Fresnel term is ks's: its shape), since neither table
    changes with a scale of f_s. So a colour edit makes no table again (an anisotropic row's takes a second)."""
    row = np.array(row, np.float32)
    row[1:4] = 0.0
    if int(row[0]) != brdf_mod.ASHIKHMIN_SHIRLEY and row[4:7].any():
        row[4:7] = 1.0
    return row


def specular_correction(row, p1_steps=None) -> np.ndarray:
    """(CORRECTION_COS, W, 3) float32 c(ωo) = A_s/E of a packed row (`specular_albedo` over `lobe_energy`,
    clipped to [0, CORRECTION_MAX]; 1 where the lobe gives nothing) at `correction_directions`: a texture the
    kernels read bilinearly at (u, v) = (φo folded into [0, π/2] over π/2, cos θo), clamped to the texel centres
    (`correction_uv`). An isotropic row under a parameter map has a column per `moment_p1_steps` step instead, c at
    p1 times each factor (read at the pixel's factor, as its moment table is). A row without a specular lobe
    (Lambert) is the 1×1 texture of ones."""
    row = _table_row(row)

    def correction(row):
        kind = int(row[0])
        if kind == brdf_mod.LAMBERT:
            return np.ones((1, 1, 3), np.float32)
        wo = correction_directions(kind in brdf_mod.ANISOTROPIC_KINDS)
        flat = wo.reshape(-1, 3)
        exact = specular_albedo(row, flat)
        model = lobe_energy(row, flat, sg.lighting_table())
        ok = model > 1e-12 * max(float(model.max()), 1e-300)
        c = np.where(ok, exact / np.where(ok, model, 1.0), 1.0)
        c = np.where(np.isfinite(c), c, 1.0)  # (a degenerate row's NaN must not reach an image)
        return np.clip(c, 0.0, CORRECTION_MAX).reshape(wo.shape).astype(np.float32)

    def make():
        if not p1_steps or int(row[0]) in brdf_mod.ANISOTROPIC_KINDS or int(row[0]) == brdf_mod.LAMBERT:
            return correction(row)
        columns = []
        for j in range(p1_steps[1]):
            scaled = row.copy()
            scaled[7] = np.float32(float(row[7]) * 2.0 ** (p1_steps[0] + j / MOMENT_P1_STEPS))
            columns.append(correction(scaled))
        return np.concatenate(columns, 1)

    return _kept(_CORRECTIONS, (row.tobytes(), p1_steps), make)


def correction_at(tex_info, tex_data, slot: int, wo_local, p1_factor=None) -> np.ndarray:
    """(N, 3) the packed correction texture `slot` (`pack_materials`) at each ωo (N, 3) in the surface frame, as
    the kernels read it (`correction_uv`, `svbrdf.sample`); an isotropic row's columns at its parameter map's
    `p1_factor` (N,), from the first factor that its moment table (slot + 1) keeps."""
    off, h, w = (int(x) for x in tex_info[slot][:3])
    image = np.asarray(tex_data[3 * off:3 * (off + h * w)], np.float64).reshape(h, w, 3)
    column = None
    if w > 1 and p1_factor is not None:
        moff, _, mw = (int(x) for x in tex_info[slot + 1][:3])
        first = float(tex_data[3 * (moff + mw // 2) + 2])
        column = np.clip(MOMENT_P1_STEPS * (np.log2(np.maximum(p1_factor, 1e-30)) - first), 0.0, w - 1)
    return svbrdf.sample(image, correction_uv(wo_local, w, column))


def correction_uv(wo_local, width: int, column=None) -> np.ndarray:
    """(N, 2) where `specular_correction`'s texture of `width` columns is read for each ωo (N, 3) in the surface
    frame: u = φo folded into [0, π/2] over π/2 (or, where the columns are p1's, the centre of fractional `column`
    (N,)), v = cos θo, each clamped to its first and last texel centres (the texture lookup wraps; the table must
    not)."""
    wo_local = np.asarray(wo_local, np.float64)
    if column is None:
        u = np.arctan2(np.abs(wo_local[:, 1]), np.abs(wo_local[:, 0])) / (np.pi / 2)
    else:
        u = (np.asarray(column, np.float64) + 0.5) / width
    u = np.clip(u, 0.5 / width, 1 - 0.5 / width)
    v = np.clip(wo_local[:, 2], 0.5 / CORRECTION_COS, 1 - 0.5 / CORRECTION_COS)
    return np.stack([u, v], 1)


_PER_ROW: dict = {}  # (id(table), id(levels), owner) → (table, levels, their rows per sub-row): `_tables_per_row`
_PER_ROW_KEPT = 8


def _tables_per_row(table, levels, owner):
    """A bake's amplitude table and energy levels (M, …) once per sub-row (`owner` (R,): each row's small-scale
    material), made once per bake's arrays and kept (frozen), so that packing the same material again gives the
    same arrays, whose device copies the backends keep by identity. The entry holds the source arrays too, so
    their ids stay theirs while it is kept."""
    key = (id(table), id(levels), owner.tobytes())
    hit = _PER_ROW.get(key)
    if hit is None:
        if len(_PER_ROW) >= _PER_ROW_KEPT:
            _PER_ROW.pop(next(iter(_PER_ROW)))
        rows = np.ascontiguousarray(table[owner]), np.ascontiguousarray(levels[owner])
        for a in rows:
            a.setflags(write=False)
        hit = _PER_ROW[key] = (table, levels, *rows)
    return hit[2], hit[3]


def pack_materials(materials, environment: bool = True) -> dict:
    """Pack a scene's materials (analytic `Brdf`s, `svbrdf.Textured` ones and `EffectiveBRDF`s) for the shade stage.
    `environment` False (a scene without one, whose specular environment term is 0): the analytic rows' correction
    and moment tables are not made (a 1×1 texture of ones and a 2×2 one of zeros stand in)."""

    info, analytic, eff_info, eff_lobes, eff_sub, eff_tables, eff_diffuse = [], [], [], [], [], [], []
    n_lobes = n_sub = n_table = n_diffuse = 0
    # Textures: entry 0 is the shared 1×1 texture of ones that stands in for an absent map; entries 1 … A are the
    # analytic rows' specular corrections (`specular_correction`, row r's at 1 + 2r) and moment tables
    # (`moment_table`, row r's at 2 + 2r); the materials' maps follow.
    maps = []  # (the maps in order; a Textured material's slot is counted among them, then moved past the A rows)
    textured = []
    table_steps = []  # per analytic row, its tables' p1 columns (`moment_p1_steps`) or None
    for idx, m in enumerate(materials):
        if isinstance(m, Textured):
            textured.append(len(info))
            info.append([0, len(analytic), _specular_rows(m), len(maps)])
            rows = _analytic_rows(m.brdf)
            analytic.extend(rows)
            maps.extend(m.maps)
            steps = None if m.parameter_map is None else moment_p1_steps(m.parameter_map)
            table_steps.extend([steps] * len(rows))
        elif isinstance(m, brdf_mod.Brdf):
            info.append([0, len(analytic), _specular_rows(m), -1])
            analytic.extend(_analytic_rows(m, anisotropic=True))
            table_steps.extend([None] * (len(analytic) - len(table_steps)))
        elif isinstance(m, EffectiveBRDF):
            k2 = m.directions**2
            lobe_type, rows = m.shade_lobes()  # a matrix-method material has none: a one-line refusal
            j = len(rows)
            # One sub-row per SG lobe of each small-scale material (two for a measured BRDF's two-lobe fit), each
            # with its material's tables: the amplitudes do not depend on the BRDF, so its lobes share them.
            sub_rows = [_sub_rows(s) for s in m.materials]
            owner = np.repeat(np.arange(len(sub_rows)), [len(r) for r in sub_rows])
            subs = np.concatenate(sub_rows)
            if lobe_type == ASG_LOBES:  # then each sub-row's tangent orders per lobe (`ASGBRDF.tangent_rows`)
                rows = np.concatenate([rows, m.tangent_rows(owner)])
            info.append([1, len(eff_info), int(any(_specular_rows(s) for s in m.materials)), -1])
            eff_info.append([m.directions, j, len(subs), n_lobes, n_sub, n_table, n_diffuse, lobe_type])
            eff_lobes.append(rows)
            eff_sub.extend(subs)
            # float32, contiguous (ravel() is a view), the levels kept by material edits; where the bake left them
            # on its device, those device arrays (the backend takes them without an upload)
            table, diffuse = m.shade_tables()
            if len(subs) != len(m.materials):  # a material of several lobes: its tables once per lobe
                table, diffuse = _tables_per_row(np.asarray(table), np.asarray(diffuse), owner)
            eff_tables.append(table.ravel())
            eff_diffuse.append(diffuse.ravel())
            n_lobes += len(rows)
            n_sub += len(subs)
            n_table += table.size
            n_diffuse += diffuse.size
            assert k2 * k2 * j * 3 * len(subs) == table.size
        else:
            raise ValueError(f"material {idx} is neither a BRDF, a Textured BRDF nor an EffectiveBRDF: {m!r}")

    def stack(rows, width, dtype):
        return np.asarray(rows, dtype).reshape(-1, width) if rows else np.zeros((0, width), dtype)

    tex_info, tex_data, n_texels = [[0, 1, 1, 0]], [np.ones(3, np.float32)], 1
    if environment:
        tables = [t for row, steps in zip(analytic, table_steps) for t in (specular_correction(row, steps),
                                                                           moment_table(row, steps))]
    else:
        tables = [np.ones((1, 1, 3), np.float32), np.zeros((2, 2, 3), np.float32)] * len(analytic)
    for tex in tables + maps:
        if tex is None:
            tex_info.append([0, 1, 1, 0])
            continue
        if tex.ndim == 2:  # the parameter map: its value in all three channels
            tex = np.repeat(tex[..., None], 3, axis=2)
        tex_info.append([n_texels, tex.shape[0], tex.shape[1], 0])
        tex_data.append(np.ascontiguousarray(tex, np.float32).ravel())
        n_texels += tex.shape[0] * tex.shape[1]
    for i in textured:
        info[i][3] += 1 + 2 * len(analytic)

    return {
        "mat_info": stack(info, 4, np.int32),
        "analytic": stack(analytic, 9, np.float32),
        "eff_info": stack(eff_info, 8, np.int32),
        "eff_lobes": np.concatenate(eff_lobes) if eff_lobes else np.zeros((0, EFF_LOBE_WIDTH), np.float32),
        "eff_sub": stack(eff_sub, 9, np.float32),
        "eff_tables": (eff_tables[0] if len(eff_tables) == 1 else
                       np.concatenate(eff_tables) if eff_tables else np.zeros(0, np.float32)),
        "eff_diffuse": (eff_diffuse[0] if len(eff_diffuse) == 1 else  # one material's levels as they are (kept)
                        np.concatenate(eff_diffuse) if eff_diffuse else np.zeros(0, np.float32)),
        "tex_info": np.asarray(tex_info, np.int32).reshape(-1, 4),
        "tex_data": np.concatenate(tex_data).astype(np.float32),
    }


# ---------------------------------------------------------------------------------------------------
# The float64 reference (the oracle of kernels/shade.py and cl/shade.cl)
# ---------------------------------------------------------------------------------------------------


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _normalize(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-30)


def specular_scale(row, cos_d):
    """(N, 3) M of an analytic BRDF row at cos θd (sg.specular_lobe at the lobe centre) and its NDF
    sharpness η_s. `row` is one packed row (9,) or one per point (N, 9) (a textured material's values at
    each pixel); η_s is then a scalar or (N,). Rows without a specular term give M = 0."""
    row = np.asarray(row, np.float64)
    kind = int(row[..., 0].flat[0])
    ks = row[..., 4:7]
    p1, p2 = row[..., 7], row[..., 8]
    cos_d = np.clip(np.asarray(cos_d, np.float64), MIN_COS_VIEW, 1.0)
    shape = (len(cos_d), 3)
    if kind == brdf_mod.BLINN_PHONG:
        return np.broadcast_to(ks * ((p1 + 2) / (2 * np.pi))[..., None], shape).copy(), p1
    if kind == brdf_mod.COOK_TORRANCE:
        fres = p2 + (1 - p2) * (1 - cos_d) ** 5
        return ks * (fres / (np.pi * cos_d**2))[:, None], 2 / p1**2
    if kind == brdf_mod.WARD:
        return ks / (4 * np.pi * p1**2 * cos_d)[:, None], 2 / p1**2
    # The anisotropic kinds: f_s at the mirror direction (h = n, cos θi = cos θo = cos θd) over their NDF's ASG,
    # which is 1 there; η_s is that ASG's effective SG sharpness 2√(λμ) (Xu §5.3).
    if kind == brdf_mod.ANISOTROPIC_WARD:
        return ks / (4 * np.pi * p1 * p2 * cos_d)[:, None], 2 / (p1 * p2)
    if kind == brdf_mod.ASHIKHMIN_SHIRLEY:
        fres = ks + (1 - ks) * ((1 - cos_d) ** 5)[:, None]
        return fres * (np.sqrt((p1 + 1) * (p2 + 1)) / (8 * np.pi * cos_d**2))[:, None], np.sqrt(p1 * p2)
    return np.zeros(shape), 1.0


def _table_interp(table_flat, base, k, j_count, j, wi_local, wo_local):
    """Bilinear (in ωi) × bilinear (in ωo) lookup of value/cos θi in a (K², K², J, 3) table → (N, 3)."""
    ii, iw = dirs.bilinear_corners(wi_local, k)
    oo, ow = dirs.bilinear_corners(wo_local, k)
    iw = iw / dirs.grid(k)[:, 2][ii]
    k2 = k * k
    out = np.zeros((len(wi_local), 3))
    for a in range(4):
        for b in range(4):
            idx = base + ((ii[:, a] * k2 + oo[:, b]) * j_count + j) * 3
            vals = np.stack([table_flat[idx + c] for c in range(3)], 1).astype(np.float64)
            out += (iw[:, a] * ow[:, b])[:, None] * vals
    return out


def _small_scale_convolved(g, sub, eta_s, order):
    """G_j ⊛ D_s: an effective material's ASG lobes g (world frame) convolved with its small-scale BRDF's NDF, an
    anisotropic one's ASG turned by the lobe's tangent order (`asg.convolve_asg`), else its SG (Xu Eq. 18)."""
    kind = int(sub[0])
    if kind in brdf_mod.ANISOTROPIC_KINDS:
        lam_s, mu_s = brdf_mod.ndf_bandwidths(kind, sub[7], sub[8])
        return asg_mod.convolve_asg(g, lam_s, mu_s, order)
    return asg_mod.convolve_sg(g, eta_s)


def _asg_environment_lobe(c, scale, wo, c_oj, t, b, n, wo_local, tables, base, k, j_count, j):
    """An ASG lobe of an effective material (Xu 2013) against the environment, as the SG lobes are: the lobe
    G_j convolved with the small-scale NDF (`c`, world frame: `_small_scale_convolved`), warped to the light
    directions (Eq. 23–26), then replaced by the SG of the same axis, of Xu's effective bandwidth
    (η = 2√(λ_i μ_i), §5.3) and of the same integral — so the prefiltered maps, the cosine and the SSDF take it
    as an SG lobe. → (axis, η, amplitude (m, 3) that multiplies the SG's ∫G·cos·visibility·L̄)."""
    w = asg_mod.warp(c, wo)
    lam, mu = np.maximum(w.lam, 1e-6), np.maximum(w.mu, 1e-6)
    eta = np.minimum(2.0 * np.sqrt(lam) * np.sqrt(mu), sg.SHARPNESS_MAX)  # (λμ itself can overflow)
    integral = asg_mod.shade_integral(lam, mu)
    axis = w.z
    wl = np.stack([_dot(axis, t), _dot(axis, b), _dot(axis, n)], 1)
    mu_tab = _table_interp(tables, base, k, j_count, j, wl, wo_local)
    amp = scale * mu_tab * (c.amplitude * np.where(c_oj > 0, integral / sg.integral(eta), 0.0))[:, None]
    return axis, eta, amp, False, None, (w.x, w.y, lam, mu)


# Ashikhmin–Shirley's ρd varies with cos θi as g(c) = 1 − (1 − c/2)⁵, whose cosine-weighted mean over the
# hemisphere is 23/28 (the model's normalisation): g takes it at this cosine, 2(1 − (5/28)^(1/5)) = 0.5829.
AS_UNIFORM_COS = 2.0 * (1.0 - (5.0 / 28.0) ** 0.2)


def lobe_cosine(c, eta):
    """The cosine at which Ashikhmin–Shirley's ρd is read for a light lobe of sharpness η whose axis has cosine c:
    c itself for a sharp lobe, AS_UNIFORM_COS (exact for a uniform one) for a broad one, blended by the lobe's mean
    resultant length R = coth η − 1/η (η/3 below 1e-2)."""
    eta = np.asarray(eta, np.float64)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        r = np.where(eta < 1e-2, eta / 3 - eta**3 / 45, 1 / np.tanh(np.maximum(eta, 1e-2)) - 1 / np.maximum(eta, 1e-2))
    return r * np.maximum(c, 0.0) + (1 - r) * AS_UNIFORM_COS


def _ashikhmin_shirley_diffuse(row, cos_i, cos_o):
    """(m, 3) Ashikhmin–Shirley's ρd (no cosines) of packed rows (m, 9) [kind, Rd, Rs, nu, nv]."""
    g = (1 - (1 - cos_i / 2) ** 5) * (1 - (1 - cos_o / 2) ** 5) * 28 / (23 * np.pi)
    return row[:, 1:4] * (1 - row[:, 4:7]) * g[:, None]


def _analytic_specular(row, n, t, wi, wo):
    """(m, 3) f_s (no cosines) of an analytic BRDF's packed rows (m, 9), in the frame of tangents t for the
    anisotropic kinds: its cosine-weighted specular term (`brdf.brdf_cosine_weighted` with no diffuse) over
    cos θi cos θo."""
    params = row[:, 1:9].copy()
    params[:, 0:3] = 0.0
    fc = brdf_mod.brdf_cosine_weighted(row[:, 0].astype(np.int32), params, np.arange(len(row)), n, wi, wo, t)
    c = np.maximum(_dot(n, wi), 0.0) * np.maximum(_dot(n, wo), 0.0)
    return np.where((c > 0)[:, None], fc / np.where(c > 0, c, 1.0)[:, None], 0.0)


def _anisotropic_environment_lobe(row, n, t, wo, cos_o):
    """An anisotropic BRDF's specular lobe against the environment (Xu 2013 §5.2): its NDF as one ASG about n in
    the frame of the tangents (`brdf.ndf_bandwidths`), warped to the light directions (Eq. 23–26), then the SG of
    the warped axis, of the effective bandwidth 2√(λ_iμ_i) and of the same integral, as an effective material's
    ASG lobe (`_asg_environment_lobe`); its amplitude is f_s at the mirror direction (`specular_scale`)."""
    x, y = brdf_mod.tangent_frame(n, t)
    lam, mu = brdf_mod.ndf_bandwidths(int(row[0, 0]), row[:, 7], row[:, 8])
    w = asg_mod.warp(asg_mod.ASG(x, y, n, lam, mu), wo)
    lam, mu = np.maximum(w.lam, 1e-6), np.maximum(w.mu, 1e-6)
    eta = np.minimum(2.0 * np.sqrt(lam) * np.sqrt(mu), sg.SHARPNESS_MAX)
    scale, _ = specular_scale(row, cos_o)
    amp = scale * (w.amplitude * asg_mod.shade_integral(lam, mu) / sg.integral(eta))[:, None]
    return w.z, eta, amp, False, cos_o if int(row[0, 0]) == brdf_mod.ASHIKHMIN_SHIRLEY else None, (w.x, w.y, lam, mu)


# The anisotropic lookup of an ASG lobe in the prefiltered maps (`asg_prefiltered`): taps along its broad axis,
# each as sharp as its narrow axis allows — but at most as narrow as ASG_TAP_SHARE of the broad axis's variance, so
# that neighbouring taps overlap and a sharp light (a sun) is a streak, not a row of spots — spread so that together
# they have the broad axis's variance. As few taps as keep neighbours at most TAP_GAP tap deviations apart: one
# lookup where the spread is under ROUND_SPREAD of a tap's deviation; else the first Gauss–Hermite rule of 2–5
# nodes whose widest gap passes (its variance is exact with few nodes); else up to ASG_TAPS taps evenly spaced over
# ±TAP_SPAN spreads with a Gaussian's weights (Gauss–Hermite rules of more nodes spend their outer taps on weights
# below 1e−3). Against a dense quadrature of the studio and the sky (bench/README.md, "How many taps an ASG lookup
# takes") this has the 12 even taps' error at 5.4 taps on average.
ASG_TAPS = 12
ASG_TAP_SHARE = 0.05
TAP_SPAN = 2.75
TAP_GAP = 1.5
ROUND_SPREAD = 0.25
HERMITE_TAPS = (2, 3, 4, 5)
# the rules' nodes and weights, one after another (the rule of n nodes from (n − 2)(n + 1)/2), and widest gaps
_HERMITE = [np.polynomial.hermite_e.hermegauss(n) for n in HERMITE_TAPS]
_HERMITE_NODES = np.concatenate([x for x, _ in _HERMITE])
_HERMITE_WEIGHTS = np.concatenate([w / w.sum() for _, w in _HERMITE])
_HERMITE_GAPS = np.array([np.diff(x).max() for x, _ in _HERMITE])


def tap_plan(spread_ratio) -> tuple:
    """(count, even) per lobe of spread over tap deviation `spread_ratio` (m,): how many taps `asg_prefiltered`
    takes, and whether they are the even comb (else a Gauss–Hermite rule, or one lookup where count is 1)."""
    r = np.asarray(spread_ratio, np.float64)
    count = np.minimum(ASG_TAPS, 1 + np.ceil(2.0 * TAP_SPAN * r / TAP_GAP)).astype(np.int64)
    even = np.ones(r.shape, bool)
    for n, gap in zip(HERMITE_TAPS[::-1], _HERMITE_GAPS[::-1]):
        fits = gap * r <= TAP_GAP
        count = np.where(fits, n, count)
        even &= ~fits
    count = np.where(r <= ROUND_SPREAD, 1, count)
    return count, even & (r > ROUND_SPREAD)


def tap_rule(count: int, even: bool) -> tuple:
    """(nodes in spreads, weights) of `tap_plan`'s taps."""
    if even:
        nodes = np.linspace(-TAP_SPAN, TAP_SPAN, count)
        weights = np.exp(-nodes**2 / 2)
        return nodes, weights / weights.sum()
    if count == 1:
        return np.zeros(1), np.ones(1)
    first = (count - 2) * (count + 1) // 2
    return _HERMITE_NODES[first:first + count], _HERMITE_WEIGHTS[first:first + count]


def asg_prefiltered(maps, levels, x, y, z, lam, mu):
    """(m, 3) the environment's mean radiance under warped ASG lobes (frames x, y, z (m, 3), bandwidths λ, μ (m,)):
    the weighted average of `tap_plan`'s prefiltered lookups spread along the broad axis (variance
    1/(2·min(λ, μ)) in all), each tap an SG of the narrow axis's variance 1/(2·max(λ, μ)) or of ASG_TAP_SHARE of the
    broad one's, whichever is broader; a lobe near round (one tap) is read once at η = 2·√(λμ), the SG lobes' own
    lookup."""
    long = np.where((lam <= mu)[:, None], x, y)
    var_long = 0.5 / np.minimum(lam, mu)
    var_tap = np.maximum(0.5 / np.maximum(lam, mu), ASG_TAP_SHARE * var_long)
    spread = np.sqrt(np.maximum(var_long - var_tap, 0.0))
    count, even = tap_plan(spread / np.sqrt(var_tap))
    out = prefiltered_lookup(maps, levels, z, np.minimum(2.0 * np.sqrt(lam) * np.sqrt(mu), sg.SHARPNESS_MAX))
    eta_tap = np.minimum(1.0 / var_tap, sg.SHARPNESS_MAX)
    for n, ev in sorted(set(zip(count[count > 1].tolist(), even[count > 1].tolist()))):
        sel = (count == n) & (even == ev)
        nodes, weights = tap_rule(n, ev)
        taps = np.zeros((int(sel.sum()), 3))
        for node, weight in zip(nodes, weights):
            d = _normalize(z[sel] + (node * spread[sel])[:, None] * long[sel])
            taps += weight * prefiltered_lookup(maps, levels, d, eta_tap[sel])
        out[sel] = taps
    return out


# Where an analytic row reads the environment, tabulated. The moments of f_s·(n·ωi)⁺ depend on the view alone (in the
# row's tangent frame), so they are made once a row, when the materials are packed (`moment_table`), and the frame
# reads them (`tabulated_moments`) instead of evaluating f_s about the warped lobe. Made on the host, the table can
# afford to converge where a per-pixel rule did not: a 5 × 5 Gauss–Hermite rule on the warped lobe missed most at
# grazing views, where the horizon cuts f_s·cos θi (Cook–Torrance 0.15 at cos θo = 0.1: its mean 4.1° from the
# mirror direction against 6.3°; Blinn–Phong 30 at 0.05: a tenth of the variance across the plane of incidence;
# anisotropic Ward 0.08 × 0.4 up to 7.6° off its mean). The table takes MOMENT_TABLE_PASSES midpoint grids of
# MOMENT_TABLE_GRID² points over ±MOMENT_TABLE_WIDTH deviations of the previous pass's Gaussian (the first about the
# warped lobe). Its rows are at cos θo = (i/(N − 1))², denser towards grazing, where the moments change fastest; an
# anisotropic row's columns at φo = j/(W − 1)·π/2 (both anisotropic kinds are even in x and in y: a view in another
# quadrant reads the first's, mirrored); an isotropic row under a parameter map (a `Textured` one's p1 map) has a
# column every quarter octave of the map's factor instead, over the map's range, since its moments' shape changes
# with p1 (a table at the map's mean rescaled by η put Cook–Torrance 0.3 at twice its p1 2.6× off in variance).
# Each texel holds, in the frame of the plane of incidence (the mirror side along −side, `across` = n × side), the
# mean's angle from the mirror direction in that plane and its angle out of it, times √η, the logarithms of the
# variances along u (in the plane) and v = z × u on the mean's tangent plane, times η, and their correlation (which
# stays in (−1, 1) between texels, as a covariance need not) (η: `moment_sharpness`).
MOMENT_TABLE_COS = 33
MOMENT_TABLE_PHI = 17
MOMENT_TABLE_GRID = 31
MOMENT_TABLE_PASSES = 3
MOMENT_TABLE_WIDTH = 5.0
MOMENT_TABLE_COS_MIN = (0.5 / (MOMENT_TABLE_COS - 1)) ** 2  # (the first row's view: at cos θo = 0 f_s has no lobe)
MOMENT_P1_STEPS = 4  # an isotropic row under a parameter map: a column every quarter octave of p1 …
MOMENT_P1_COLUMNS = 33  # … at most this many
MOMENT_VAR_MIN = 0.5 / sg.SHARPNESS_MAX  # (a lobe narrower than a lookup resolves: as sharp as a lookup goes)


def moment_sharpness(row) -> np.ndarray:
    """(m,) the scale of packed rows' (m, 9) moment tables: the NDF's sharpness η (isotropic kinds), or 2·√(λμ) of
    its ASG (anisotropic ones, `brdf.ndf_bandwidths`)."""
    row = np.asarray(row, np.float64)
    if int(row[0, 0]) in brdf_mod.ANISOTROPIC_KINDS:
        lam, mu = brdf_mod.ndf_bandwidths(int(row[0, 0]), row[:, 7], row[:, 8])
        return 2.0 * np.sqrt(lam * mu)
    return specular_scale(row, np.ones(len(row)))[1]


def _incidence_frame(n, x, wo):
    """(cos θo, side, across): the view's cosine to n, the unit direction of its part across n (the tangent x where it
    lies along n, as the kernels take it) and n × side."""
    cos_o = np.clip(_dot(wo, n), 0.0, 1.0)
    side = wo - cos_o[:, None] * n
    length = np.linalg.norm(side, axis=1)
    side = np.where((length > 1e-6)[:, None], side / np.maximum(length, 1e-30)[:, None], x)
    return cos_o, side, np.cross(n, side)


def _covariance_axes(z, hint, second):
    """(x, y, var_x, var_y): the principal axes and variances of second moments `second` (m, 3, 3) (Σ g·d dᵀ / Σ g)
    on the tangent planes of mean directions z (m, 3) (`light_axes` of z and `hint` first)."""
    u, v = light_axes(z, hint)
    cuu = np.einsum("mi,mij,mj->m", u, second, u)
    cvv = np.einsum("mi,mij,mj->m", v, second, v)
    cuv = np.einsum("mi,mij,mj->m", u, second, v)
    angle = 0.5 * np.arctan2(2.0 * cuv, cuu - cvv)
    c, s = np.cos(angle), np.sin(angle)
    x = c[:, None] * u + s[:, None] * v
    return (x, np.cross(z, x), cuu * c * c + 2.0 * cuv * c * s + cvv * s * s,
            cuu * s * s - 2.0 * cuv * c * s + cvv * c * c)


def _grid_moments(row, n, t, wo, z, x, y, half_x, half_y):
    """One pass of `moment_table`: f_s·(n·ωi)⁺ on a midpoint grid of MOMENT_TABLE_GRID² points over ±half_x, ±half_y
    on the tangent plane at z (axes x, y), each weighted by its solid angle; (ok, z, x, y, var_x, var_y) of the
    result, ok false where the grid held nothing."""
    k = MOMENT_TABLE_GRID
    steps = (np.arange(k) + 0.5) / k * 2.0 - 1.0
    a, b = (v.ravel() for v in np.meshgrid(steps, steps, indexing="ij"))
    m = len(n)
    d = (z[:, None, :] + (a[None, :] * half_x[:, None])[..., None] * x[:, None, :]
         + (b[None, :] * half_y[:, None])[..., None] * y[:, None, :])  # (m, k², 3)
    length = np.linalg.norm(d, axis=2)
    d = d / length[..., None]

    def each(v):  # one row of v (m, ·) per grid point
        return np.repeat(v, k * k, axis=0)

    flat = d.reshape(-1, 3)
    g = _analytic_specular(each(row), each(n), each(t), flat, each(wo)).sum(1) * np.maximum(
        _dot(each(n), flat), 0.0)
    g = g.reshape(m, k * k) * length ** -3.0
    total = g.sum(1)
    first = np.einsum("mp,mpi->mi", g, d)
    ok = (total > 0) & (np.linalg.norm(first, axis=1) > 0)
    second = np.einsum("mp,mpi,mpj->mij", g, d, d) / np.where(ok, total, 1.0)[:, None, None]
    mean = _normalize(np.where(ok[:, None], first, z))
    return (ok, mean, *_covariance_axes(mean, x, second))


_MOMENT_TABLES: dict = {}  # (a row's bytes, its p1 steps) → its table (as _CORRECTIONS)


def moment_p1_steps(parameter_map) -> tuple:
    """(log2 f0, count): the p1 factors f0·2^(j/MOMENT_P1_STEPS), j = 0 … count − 1, over which an isotropic row under
    a parameter map tabulates its moments, from the map's least value f0 to its greatest (at most
    MOMENT_P1_COLUMNS; one for a constant map)."""
    values = np.asarray(parameter_map, np.float64)
    lo = np.log2(max(float(values.min()), 1e-30))
    span = np.log2(max(float(values.max()), 1e-30)) - lo
    return float(lo), int(min(np.ceil(MOMENT_P1_STEPS * span - 1e-9), MOMENT_P1_COLUMNS - 1)) + 1


def moment_table(row, p1_steps=None) -> np.ndarray:
    """(MOMENT_TABLE_COS, 2W, 3) float32 texture of a packed row's moments (see above). Its W columns: an
    anisotropic row's MOMENT_TABLE_PHI at φo = j/(W − 1)·π/2; an isotropic row's `p1_steps` (log2 f0, count), p1
    times f0·2^(j/MOMENT_P1_STEPS) (a row under a parameter map), else 1. Texel (i, j), at cos θo = max((i/(N −
    1))², MOMENT_TABLE_COS_MIN), holds [(θ_mean − θ_mirror)·√η, ln(var_u·η), ln(var_v·η)], texel (i, W + j)
    [β·√η, ρ_uv, log2 f0] (β the mean's angle out of the plane of incidence, ρ the correlation across u and v; f0
    1 but under a parameter map). A row without a specular lobe is a 2×2 texture of zeros; a row whose ks is 0 is
    tabulated as if it were 1 (its moments are of f_s's shape)."""
    row = _table_row(row)

    def make():
        kind = int(row[0])
        if kind == brdf_mod.LAMBERT:  # (never read: a lookup's bilinear reads would still stay inside it)
            return np.zeros((2, 2, 3), np.float32)
        shape = row.copy()
        if not shape[4:7].any():
            shape[4:7] = 1.0
        anisotropic = kind in brdf_mod.ANISOTROPIC_KINDS
        v = np.arange(MOMENT_TABLE_COS) / (MOMENT_TABLE_COS - 1)
        width = MOMENT_TABLE_PHI if anisotropic else (p1_steps[1] if p1_steps else 1)
        phi = np.arange(width) / (width - 1) * (0.5 * np.pi) if anisotropic else np.zeros(1)
        log_first = p1_steps[0] if p1_steps and not anisotropic else 0.0
        factor = 2.0 ** (log_first + np.arange(width if p1_steps and not anisotropic else 1) / MOMENT_P1_STEPS)
        cos_o, phi, factor = (a.ravel() for a in np.meshgrid(np.maximum(v * v, MOMENT_TABLE_COS_MIN), phi,
                                                             factor, indexing="ij")[:3])
        m = len(cos_o)
        sin_o = np.sqrt(1.0 - cos_o * cos_o)
        wo = np.stack([sin_o * np.cos(phi), sin_o * np.sin(phi), cos_o], 1)
        rows = np.tile(shape.astype(np.float64), (m, 1))
        rows[:, 7] *= factor
        n = np.tile([0.0, 0.0, 1.0], (m, 1))
        t = np.tile([1.0, 0.0, 0.0], (m, 1))
        eta = moment_sharpness(rows)
        if anisotropic:
            lam, mu = brdf_mod.ndf_bandwidths(kind, rows[:, 7], rows[:, 8])
        else:
            lam = mu = 0.5 * eta
        w = asg_mod.warp(asg_mod.ASG(t, np.cross(n, t), n, lam, mu), wo)
        z, x, y = w.z, w.x, w.y
        var_x, var_y = 0.5 / np.maximum(w.lam, 1e-6), 0.5 / np.maximum(w.mu, 1e-6)
        for _ in range(MOMENT_TABLE_PASSES):
            # (a tangent-plane half-width past ~80° would fold the grid over the far side)
            ok, *new = _grid_moments(rows, n, t, wo, z, x, y, np.minimum(MOMENT_TABLE_WIDTH * np.sqrt(var_x), 6.0),
                                     np.minimum(MOMENT_TABLE_WIDTH * np.sqrt(var_y), 6.0))
            # (where a pass's grid held nothing, the previous pass's Gaussian stays)
            z, x, y = (np.where(ok[:, None], a, b) for a, b in zip(new[:3], (z, x, y)))
            var_x = np.where(ok, np.maximum(new[3], MOMENT_VAR_MIN), var_x)
            var_y = np.where(ok, np.maximum(new[4], MOMENT_VAR_MIN), var_y)
        # (the plane of incidence from φo, which at normal incidence still names the column's frame)
        side = np.stack([np.cos(phi), np.sin(phi), np.zeros(m)], 1)
        across = np.cross(n, side)
        theta_m = np.arctan2(-_dot(z, side), _dot(z, n))
        beta = np.arcsin(np.clip(_dot(z, across), -1.0, 1.0))
        u = -(np.cos(theta_m)[:, None] * side + np.sin(theta_m)[:, None] * n)
        u = _normalize(u - _dot(u, z)[:, None] * z)  # (u ⊥ z exactly, whatever β)
        vv = np.cross(z, u)

        def moment(a, b):  # aᵀ C b of the covariance whose principal axes and variances the passes gave
            return var_x * _dot(a, x) * _dot(b, x) + var_y * _dot(a, y) * _dot(b, y)

        var_u, var_v = np.maximum(moment(u, u), MOMENT_VAR_MIN), np.maximum(moment(vv, vv), MOMENT_VAR_MIN)
        first = np.stack([(theta_m - np.arccos(cos_o)) * np.sqrt(eta), np.log(var_u * eta),
                          np.log(var_v * eta)], 1)
        second = np.stack([beta * np.sqrt(eta), np.clip(moment(u, vv) / np.sqrt(var_u * var_v), -1.0, 1.0),
                           np.full(m, log_first)], 1)
        table = np.concatenate([first.reshape(MOMENT_TABLE_COS, width, 3),
                                second.reshape(MOMENT_TABLE_COS, width, 3)], 1).astype(np.float32)
        if not np.isfinite(table).all():
            raise ValueError(f"moment_table: row {row.tolist()} gives non-finite moments")
        return table

    return _kept(_MOMENT_TABLES, (row.tobytes(), p1_steps), make)


def tabulated_moments(table, eta, n, t, wo, p1_factor=None) -> tuple:
    """(x, y, z, λ, μ), `asg_prefiltered`'s arguments: the ASG of f_s·(n·ωi)⁺'s moments read from a row's
    `moment_table` (N, 2W, 3) for its `moment_sharpness` η (m,), unit normals n, tangents t and views wo (m, 3)
    above the horizon, as the kernels read it: linear in √cos θo and across the columns, clamped to the table. The
    columns: an isotropic row's p1 factors (`p1_factor` (m,), the row's parameter map at the pixels; the first
    column's log2 in texel (0, W)'s third channel), else φo folded into [0, π/2] (a view in another quadrant of the
    tangent frame mirrors the out-of-plane angle and the correlation)."""
    table = np.asarray(table, np.float64)
    rows, width = table.shape[0], table.shape[1] // 2
    x_t, y_t = brdf_mod.tangent_frame(n, t)
    cos_o, side, across = _incidence_frame(n, x_t, wo)
    wx, wy = _dot(wo, x_t), _dot(wo, y_t)
    pos = np.sqrt(cos_o) * (rows - 1)
    i0 = np.minimum(pos.astype(np.int64), rows - 2)
    fi = (pos - i0)[:, None]
    mirror = np.ones(len(n))
    if width == 1:
        col = np.zeros(len(n))
    elif p1_factor is not None:
        col = np.clip(MOMENT_P1_STEPS * (np.log2(np.maximum(p1_factor, 1e-30)) - table[0, width, 2]), 0.0,
                      width - 1)
    else:
        col = np.arctan2(np.abs(wy), np.abs(wx)) / (0.5 * np.pi) * (width - 1)
        mirror = np.where((wx < 0) != (wy < 0), -1.0, 1.0)
    j0 = np.minimum(col.astype(np.int64), max(width - 2, 0))
    j1 = np.minimum(j0 + 1, width - 1)
    fj = (col - j0)[:, None]

    def read(offset):
        top = (1.0 - fj) * table[i0, offset + j0] + fj * table[i0, offset + j1]
        bottom = (1.0 - fj) * table[i0 + 1, offset + j0] + fj * table[i0 + 1, offset + j1]
        return (1.0 - fi) * top + fi * bottom

    first, second = read(0), read(width)
    scale = np.sqrt(eta)
    theta_m = np.clip(np.arccos(cos_o) + first[:, 0] / scale, 0.0, 0.5 * np.pi)
    beta = mirror * second[:, 0] / scale
    in_plane = np.cos(theta_m)[:, None] * n - np.sin(theta_m)[:, None] * side
    z = np.cos(beta)[:, None] * in_plane + np.sin(beta)[:, None] * across
    u = -(np.cos(theta_m)[:, None] * side + np.sin(theta_m)[:, None] * n)
    u = _normalize(u - _dot(u, z)[:, None] * z)
    v = np.cross(z, u)
    var_u, var_v = np.exp(first[:, 1]) / eta, np.exp(first[:, 2]) / eta
    cov = mirror * second[:, 1] * np.sqrt(var_u * var_v)
    angle = 0.5 * np.arctan2(2.0 * cov, var_u - var_v)
    c, s = np.cos(angle), np.sin(angle)
    x = c[:, None] * u + s[:, None] * v
    var_x = np.maximum(var_u * c * c + 2.0 * cov * c * s + var_v * s * s, MOMENT_VAR_MIN)
    var_y = np.maximum(var_u * s * s - 2.0 * cov * c * s + var_v * c * c, MOMENT_VAR_MIN)
    return x, np.cross(z, x), z, 0.5 / var_x, 0.5 / var_y


def capped_cosine_integral(e, cap, axis, n, eta, table):
    """Ashikhmin–Shirley's 1/max(cos θi, cos θo) over a lobe whose M is taken at cos θi = cos θo = `cap`: its
    f_s·cos θi is M·D·min(cos θi, cos θo), so the lobe's cosine integral e = ∫G·(n·ω)⁺ loses ∫G·(cos θi − cos θo)⁺.
    Across a lobe of sharpness η about an axis of sine s = √(1 − cap²), cos θi − cos θo is ≈ Gaussian of spread
    s/√η, whose positive part has the mean s/√(2πη); ∫G is taken over the lobe's visible part (the visible
    fraction of its own hemisphere, whose share of ∫G is 1/(1 + e^−η)); docs/design.md §9 gives its effect."""
    visible = sg.integral(eta) * sg.table_lookup(table, 1, _dot(axis, n), eta) / (1 + np.exp(-eta))
    spread = np.sqrt(np.maximum(1 - cap * cap, 0.0) / (2 * np.pi * eta))
    return np.maximum(e - spread * visible, 0.0)


# A light's size blurs f_s over it (`light_mean`): f_s·cos θi is read where the light and the lobe overlap most (the
# mean of the product of the light's Gaussian and the lobe's) and at ± the product's σ along two axes across the
# light, its logarithm taken as a quadratic there, whose integral against the light (its SG emitter, the one the
# Monte Carlo reference samples too: a Gaussian of variance 1/η) is closed. Read there rather than at the light's
# centre, a lobe narrower than the light still has its peak in the quadratic. The exponent of the result stops at
# LIGHT_BLUR_EXP_MAX (e^4 ≈ 55): where the lobe's centre (the warped lobe's, an estimate) is off, the quadratic's
# slope would otherwise multiply a value that f_s's own tail need not follow.
LIGHT_BLUR_EXP_MAX = 4.0


def light_mean(f_at, light, axes, var_l, centre, var_lobe):
    """(m, 3) a lobe's mean over a light: f_at(d) → (m, 3) its values at unit directions d (f_s·(n·ωi)⁺ for the
    renderer), the light a Gaussian of variance var_l (m,) per axis about unit directions `light` (m, 3) (its SG
    emitter exp(η(ω·l − 1)), `scene.light_sg`: 1/η), `axes` two unit axes across it, the lobe about `centre` (m, 3)
    with variances var_lobe (2, m) along them. Along each axis k the two Gaussians put their product's mass at
    x_k = d_k·var_l/(var_l + v_k) (d_k the lobe centre's offset), of spread s_k² = var_l·v_k/(var_l + v_k); with
    log f ≈ l0 + g·u + c·u²/2 about there (g, c from f at the point and at ±s_k; c ≤ 0), ∫N(x; 0, var_l)·f =
    f(point)·Π exp(−g x_k + c x_k²/2 + B_k²/(2A_k))/√(var_l·A_k), A_k = 1/var_l − c, B_k = g − c·x_k: exact for a
    Gaussian lobe. f at the light's centre where f is 0 at any of the five (the light at a lobe's or the horizon's
    edge)."""
    offsets = [_dot(centre - light, a) for a in axes]
    x = [o * var_l / (var_l + v) for o, v in zip(offsets, var_lobe)]
    spread = [np.sqrt(var_l * v / (var_l + v)) for v in var_lobe]
    point = light + x[0][:, None] * axes[0] + x[1][:, None] * axes[1]
    f0 = f_at(_normalize(point))
    c0 = f0.sum(1)
    ok = c0 > 0
    l0 = np.log(np.where(ok, c0, 1.0))
    expo = np.zeros(len(c0))
    scale = np.ones(len(c0))
    for a, xk, sk in zip(axes, x, spread):
        lo = f_at(_normalize(point - sk[:, None] * a)).sum(1)
        hi = f_at(_normalize(point + sk[:, None] * a)).sum(1)
        ok &= (lo > 0) & (hi > 0)
        log_lo, log_hi = np.log(np.where(ok, lo, 1.0)), np.log(np.where(ok, hi, 1.0))
        g = (log_hi - log_lo) / (2 * sk)
        c = np.minimum((log_hi + log_lo - 2 * l0) / (sk * sk), 0.0)
        big_a = 1 / var_l - c
        big_b = g - c * xk
        expo += -g * xk + 0.5 * c * xk * xk + big_b * big_b / (2 * big_a)
        scale /= np.sqrt(var_l * big_a)
    factor = scale * np.exp(np.minimum(expo, LIGHT_BLUR_EXP_MAX))
    return np.where(ok[:, None], f0 * factor[:, None], f_at(light))


def _analytic_lights(row, n, t, wo, table, l_axis, l_eta, l_amp, l_vis, lobe):
    """(m, 3) an analytic BRDF's specular radiance from the lights: f_s·(n·ωi)⁺'s mean over each light's SG
    (`light_mean`; `lobe` = (centre, x, λ, μ): the warped lobe's centre, its x axis (turned across each light:
    `light_axes`) and bandwidths, variances 1/(2λ), 1/(2μ)) times the light's irradiance at normal incidence and
    its visible share."""
    centre, hint, lam, mu = lobe
    out = np.zeros((len(wo), 3))
    for li in range(l_axis.shape[1]):
        light = l_axis[:, li]
        f = light_mean(lambda d: _analytic_specular(row, n, t, d, wo) * np.maximum(_dot(n, d), 0.0)[:, None], light,
                       light_axes(light, hint), 1.0 / l_eta[:, li], centre, (0.5 / lam, 0.5 / mu))
        out += f * l_amp[:, li] * (sg.integral(l_eta[:, li]) * l_vis[:, li])[:, None]
    return out


def light_axes(light, hint):
    """Two unit axes across unit directions `light` (m, 3): `hint` with its part along the light removed, or,
    where the hint lies along the light, Duff et al.'s basis vector of the light; and light × that one."""
    x = hint - _dot(hint, light)[:, None] * light
    norm = np.linalg.norm(x, axis=1)
    sgn = np.where(light[:, 2] < 0, -1.0, 1.0)
    a = -1.0 / (sgn + light[:, 2])
    duff = np.stack([1 + sgn * light[:, 0] ** 2 * a, sgn * light[:, 0] * light[:, 1] * a, -sgn * light[:, 0]], 1)
    x = np.where((norm > 1e-3)[:, None], x / np.maximum(norm, 1e-30)[:, None], duff)
    return x, np.cross(light, x)


def _asg_lights(g, conv, sub, eta_s, wo, t, b, n, wo_local, tables, base, k, j_count, j, table, l_axis, l_eta, l_amp,
                l_vis):
    """(m, 3) an ASG lobe's specular radiance from the lights: the material's own f̄ at each light's
    direction (`ASGBRDF.eval`'s specular term: M(h·l)·μ_j(l, ωo)/cos θi·(G_j ⊛ D_s)(h); `conv` = G_j ⊛ D_s as it
    is for an anisotropic D_s, else `asg.convolve_sg_at`'s shape) times the light's irradiance with its cosine
    and visible share, as the diffuse term takes it."""
    out = np.zeros((len(wo), 3))
    anisotropic = int(sub[0]) in brdf_mod.ANISOTROPIC_KINDS
    for li in range(l_axis.shape[1]):
        light = l_axis[:, li]
        h = _normalize(light + wo)
        if anisotropic:
            shape = asg_mod.evaluate(conv, h)
        else:
            shape = asg_mod.convolve_sg_local(g.lam, g.mu, eta_s, _dot(h, g.x), _dot(h, g.y), _dot(h, g.z))
        scale, _ = specular_scale(sub, _dot(h, light))
        wl = np.stack([_dot(light, t), _dot(light, b), _dot(light, n)], 1)
        mu_tab = _table_interp(tables, base, k, j_count, j, wl, wo_local)
        e = sg.integral(l_eta[:, li]) * sg.table_lookup(table, 0, _dot(light, n), l_eta[:, li])
        out += scale * mu_tab * l_amp[:, li] * (shape * e * l_vis[:, li])[:, None]
    return out


def surface_frames(faces, positions, normals, tangents, face, bary, eye) -> dict:
    """The shading frame of hit pixels, exactly as the shade kernels build it (the SG reference and the Monte
    Carlo reference share it, so their images differ only by the method).

    faces (F, 3), positions / normals / tangents (V, 3) as the kernels read them (float32), face (P,) the hit
    faces, bary (P, 2) the weights of their vertices 1 and 2, eye (3,). → dict of float64 arrays: `interp`
    (a function blending a per-vertex (V, C) attribute), pos, n (unit interpolated normal), t, b (tangent,
    bitangent; t ⟂ n from the interpolated tangent, or a fixed axis where that vanishes), wo (unit, to the
    eye), cos_o = max(ωo·n, MIN_COS_VIEW), wo_local (ωo in (t, b, n) with that clamp), all (P, 3) / (P,).
    """
    tri = np.asarray(faces)[face]
    u, v = np.asarray(bary[:, 0], np.float64), np.asarray(bary[:, 1], np.float64)
    wts = np.stack([1 - u - v, u, v], 1)

    def interp(attr):
        return np.einsum("nk,nkc->nc", wts, np.asarray(attr)[tri].astype(np.float64))

    pos = interp(positions)
    n = _normalize(interp(normals))
    t = interp(tangents)
    t = t - n * _dot(t, n)[:, None]
    bad = np.linalg.norm(t, axis=1) < 1e-12
    ref = np.where((np.abs(n[:, 0]) < 0.9)[:, None], np.array([1.0, 0, 0]), np.array([0, 0, 1.0]))
    t = np.where(bad[:, None], ref - n * _dot(ref, n)[:, None], t)
    t = _normalize(t)
    b = np.cross(n, t)
    wo = _normalize(np.asarray(eye, np.float64)[None] - pos)
    cos_o = np.maximum(_dot(wo, n), MIN_COS_VIEW)
    wo_local = _normalize(np.stack([_dot(wo, t), _dot(wo, b), cos_o], 1))
    return {"interp": interp, "pos": pos, "n": n, "t": t, "b": b, "wo": wo, "cos_o": cos_o, "wo_local": wo_local}


def irradiance_scale(lobes, residual):
    """(..., 3) the exact irradiance E = lobes + residual over the environment lobes' own irradiance,
    per channel, for the diffuse term (E/lobes, at most IRRADIANCE_RATIO_MAX): the lobes give the
    shadows' shape, E the magnitude."""
    e = np.maximum(np.asarray(lobes) + residual, 0.0)
    return e / np.maximum(np.maximum(lobes, e / IRRADIANCE_RATIO_MAX), 1e-30)


def shade_reference(frame: Frame) -> np.ndarray:
    """(N, 3) float64 radiance of every pixel of a packed frame (`render.pack_frame`)."""
    static = frame.inputs
    if not isinstance(static.eff_tables, np.ndarray) or not isinstance(static.eff_diffuse, np.ndarray):
        # (a bake's tables left on its device: this reference reads them on the host)
        static = dataclasses.replace(static, eff_tables=np.asarray(static.eff_tables),
                                     eff_diffuse=np.asarray(static.eff_diffuse))

    table = static.table
    face = frame.gbuffer.face
    n_pix = len(face)
    out = np.zeros((n_pix, 3))
    cam = frame.camera.astype(np.float64)
    eye = cam[0:3]
    hit = face >= 0
    # Background: the environment itself along the camera ray (its sharpest level).
    if (~hit).any():
        w, h = int(cam[12]), int(cam[13])
        pix = np.flatnonzero(~hit)
        x, y = pix % w, pix // w
        d = (cam[3:6][None] + ((2 * (x + 0.5) / w - 1))[:, None] * cam[6:9][None]
             + ((1 - 2 * (y + 0.5) / h))[:, None] * cam[9:12][None])
        d = _normalize(d)
        out[pix] = prefiltered_lookup(static.env_maps, static.env_levels, d, 1e30)
    pix = np.flatnonzero(hit)
    if len(pix) == 0:
        return out
    f = face[pix]
    sf = surface_frames(static.faces, static.positions, static.normals, static.tangents, f,
                        frame.gbuffer.bary[pix], eye)
    interp, pos, n, t, b = sf["interp"], sf["pos"], sf["n"], sf["t"], sf["b"]
    wo, cos_o, wo_local = sf["wo"], sf["cos_o"], sf["wo_local"]

    has_ssdf = bool(static.has_ssdf)
    coeffs = interp(static.ssdf_coeffs) if has_ssdf else None

    samples = int(frame.gbuffer.occlusion_samples) if has_ssdf else 0
    # The rays of each set that the G-buffer's anti-aliasing sample traced (all of them by default).
    # With a block width, the rays the pixel's block lent it (the G-buffer's known bits, trace.share_block).
    part = check_ray_part(frame.gbuffer.ray_part)
    shared = part[2] > 0
    if shared and samples:
        for name in ("occlusion_known", "lobe_known")[:1 + bool(static.n_sharp_lobes)]:
            if getattr(frame.gbuffer, name) is None:
                raise ValueError(f"gbuffer.{name} is None, but its ray_part {part} shares rays in pixel blocks: "
                                 "fill it from Backend.ray_known (render.pack_frame does)")

    def bits_of(values, count):
        values = np.asarray(values, np.uint32)[pix].astype(np.uint64)
        return ((values[:, None] >> np.arange(count, dtype=np.uint64)[None]) & np.uint64(1)).astype(bool)

    if samples:
        n_geo = oriented_face_normals(static.positions, static.faces, f, pos, eye)
        ray_dirs = occlusion_directions(n_geo, samples, pixel_parts(samples, part, pix)[2])
        blocked = bits_of(frame.gbuffer.occlusion, samples)
        cast = bits_of(frame.gbuffer.occlusion_known, samples) if shared else part_rays(samples, part, pix)
    n_sharp = int(static.n_sharp_lobes) if samples else 0
    if n_sharp:
        lobe_turn = pixel_parts(LOBE_RAYS, part, pix)[2]
        lobe_bits = bits_of(frame.gbuffer.lobe_occlusion, 32)
        lobe_cast = bits_of(frame.gbuffer.lobe_known, LOBE_RAYS) if shared else part_rays(LOBE_RAYS, part, pix)

    def occlusion(axis, eta, sel):
        """The fraction of a lobe's horizon-clipped integral left visible: by the SSDF, blended with the
        occlusion rays' estimate for broad lobes (`ray_weight`); 1 without an SSDF."""
        if not has_ssdf:
            return np.ones(len(axis))
        theta_d = ssdf_eval(static.ssdf_basis, coeffs[sel], int(static.ssdf_res), axis)
        c = np.sin(np.clip(theta_d, -np.pi / 2, np.pi / 2))
        vis = sg.table_lookup(table, 1, c, eta)  # visible_fraction
        horizon = sg.table_lookup(table, 1, _dot(axis, n[sel]), eta)
        share = np.clip(vis / np.maximum(horizon, 1e-6), 0.0, 1.0)
        weight = ray_weight(eta, samples)
        if not weight.any():
            return share
        rays = ray_share(axis, eta, n[sel], n_geo[sel], ray_dirs[sel], blocked[sel], cast[sel])
        return weight * rays + (1 - weight) * share

    def lobe_occlusion(ray_lobe, axis, eta, sel):
        """A lobe's visible share through the rays of sharp lobe `ray_lobe` (`nearest_ray_lobe`)."""
        row = env[ray_lobe]
        d, solid = lobe_ray_directions(np.tile(row[0:3], (len(sel), 1)), np.full(len(sel), row[3]), lobe_turn[sel])
        bits = lobe_bits[sel][:, ray_lobe * LOBE_RAYS:(ray_lobe + 1) * LOBE_RAYS]
        return lobe_ray_share(axis, eta, n[sel], d, solid, bits, lobe_cast[sel])

    rad = np.zeros((len(pix), 3))
    env = static.env_sgs.astype(np.float64)
    light_axis, light_eta, light_amp, _ = light_sg(frame.lights, pos)
    light_vis = (frame.gbuffer.light_vis[pix].astype(np.float64) / VISIBLE if len(frame.lights)
                 else np.zeros((len(pix), 0)))

    for mat in np.unique(static.face_material[f]):
        sel = np.flatnonzero(static.face_material[f] == mat)
        kind, idx, has_spec = (int(x) for x in static.mat_info[mat][:3])  # has_spec: an analytic one's lobe rows
        ns, ts_, bs = n[sel], t[sel], b[sel]
        wo_s, wol_s, cos_os = wo[sel], wo_local[sel], cos_o[sel]
        m = len(sel)

        if kind == 0:
            # The analytic rows (one per SG lobe) as per-pixel values, scaled by the material's maps at each
            # pixel's UV; the first row carries kd.
            rows = [np.tile(static.analytic[idx + r].astype(np.float64), (m, 1)) for r in range(max(has_spec, 1))]
            slot = int(static.mat_info[mat][3])
            if slot >= 0:
                uv = interp(static.uvs)[sel]
                for which, cols in ((0, slice(1, 4)), (1, slice(4, 7)), (2, slice(7, 8))):
                    off, th, tw = (int(x) for x in static.tex_info[slot + which][:3])
                    image = static.tex_data[3 * off:3 * (off + th * tw)].reshape(th, tw, 3)
                    factor = svbrdf.sample(image, uv)[:, :cols.stop - cols.start]
                    for row in rows:
                        row[:, cols] *= factor

            def diffuse_over_cos(axis_world, eta, row=rows[0], ns=ns, cos_os=cos_os):
                if int(row[0, 0]) == brdf_mod.ASHIKHMIN_SHIRLEY:  # ρd of the lobe's cosine (`lobe_cosine`) and cos θo
                    return _ashikhmin_shirley_diffuse(row, lobe_cosine(_dot(axis_world, ns), eta), cos_os)
                return row[:, 1:4] / np.pi
        else:
            ei = static.eff_info[idx]
            k = int(ei[0])

            def diffuse_over_cos(axis_world, eta, ei=ei, k=k, ts_=ts_, bs=bs, ns=ns, wol_s=wol_s):
                """f̄d/cos θ as a lobe of sharpness η sees it: Σ_m kd_m/π times material m's energy
                (`EffectiveBRDF.energy_levels`) at the lobe's level (`effective.diffuse_level`)."""
                wl = np.stack([_dot(axis_world, ts_), _dot(axis_world, bs), _dot(axis_world, ns)], 1)
                level = diffuse_level(eta)
                n_levels = len(DIFFUSE_LEVEL_ETAS)
                out = np.zeros((len(wl), 3))
                for si in range(int(ei[2])):
                    kd = static.eff_sub[int(ei[4]) + si, 1:4].astype(np.float64) / np.pi
                    for lv in np.unique(level):
                        on = level == lv
                        base = int(ei[6]) + (si * n_levels + int(lv)) * k**4 * 3
                        out[on] += kd * _table_interp(static.eff_diffuse, base, k, 1, 0, wl[on], wol_s[on])
                return out

        # Diffuse: environment lobes (shadowed), scaled per channel to the exact irradiance, then lights.
        lobes_irradiance = np.zeros((m, 3))
        env_diffuse = np.zeros((m, 3))
        for index, lobe in enumerate(env):
            axis = np.tile(lobe[0:3], (m, 1))
            eta = np.full(m, lobe[3])
            e = sg.integral(eta) * sg.table_lookup(table, 0, _dot(axis, ns), eta)
            lobes_irradiance += lobe[4:7][None] * e[:, None]
            ray_lobe = nearest_ray_lobe(env, n_sharp, index)
            occ = lobe_occlusion(ray_lobe, axis, eta, sel) if ray_lobe >= 0 else occlusion(axis, eta, sel)
            env_diffuse += diffuse_over_cos(axis, eta) * (lobe[4:7][None] * (e * occ)[:, None])
        rad[sel] += env_diffuse * irradiance_scale(lobes_irradiance, equirect_bilinear(static.env_residual, ns))
        for li in range(light_axis.shape[1]):
            axis, eta, amp = light_axis[sel, li], light_eta[sel, li], light_amp[sel, li]
            e = sg.integral(eta) * sg.table_lookup(table, 0, _dot(axis, ns), eta)
            rad[sel] += diffuse_over_cos(axis, eta) * amp * (e * light_vis[sel, li])[:, None]

        if not has_spec:
            continue
        # Specular lobes: (axis ξ', sharpness η', amplitude A (m, 3)) after the warp; an ASG material's lobes
        # meet the environment here and the lights in `asg_lights`.
        lobes, env_scales = [], []  # (and per lobe its environment term's scale: an analytic row's correction)
        if kind == 0:
            for r, row in enumerate(rows):
                factor = None  # (an isotropic row's p1 at the pixels over its packed one: its parameter map)
                if int(row[0, 0]) not in brdf_mod.ANISOTROPIC_KINDS:
                    factor = row[:, 7] / float(static.analytic[idx + r, 7])
                env_scales.append(correction_at(static.tex_info, static.tex_data, 1 + 2 * (idx + r), wol_s, factor))
                # The lights by f_s itself (Xu 2013 §5.2), blurred by their size through the lobe's shape.
                if int(row[0, 0]) in brdf_mod.ANISOTROPIC_KINDS:
                    lobes.append(_anisotropic_environment_lobe(row, ns, ts_, wo_s, cos_os))
                    x, _, lam, mu = lobes[-1][-1]  # the warped lobe's shape
                    shape = (lobes[-1][0], x, lam, mu)
                else:
                    scale, eta_s = specular_scale(row, cos_os)
                    axis = _normalize(2 * cos_os[:, None] * ns - wo_s)
                    lobes.append((axis, eta_s / (4 * cos_os), scale, False))
                    half = 0.5 * np.minimum(lobes[-1][1], sg.SHARPNESS_MAX)
                    shape = (axis, ts_, half, half)
                rad[sel] += _analytic_lights(row, ns, ts_, wo_s, table, light_axis[sel], light_eta[sel],
                                             light_amp[sel], light_vis[sel], shape)
        else:
            j_count = int(ei[1])
            for si in range(int(ei[2])):
                sub = static.eff_sub[int(ei[4]) + si].astype(np.float64)
                base = int(ei[5]) + si * (k * k) ** 2 * j_count * 3
                for j in range(j_count):
                    lobe = static.eff_lobes[int(ei[3]) + j].astype(np.float64)
                    xi = lobe[0] * ts_ + lobe[1] * bs + lobe[2] * ns
                    c_oj = _dot(wo_s, xi)
                    scale, eta_s = specular_scale(sub, c_oj)
                    if not scale.any():
                        continue
                    if int(ei[7]) == ASG_LOBES:
                        x_w = lobe[4] * ts_ + lobe[5] * bs + lobe[6] * ns
                        g = asg_mod.ASG(x_w, np.cross(xi, x_w), xi, lobe[7], lobe[8])
                        order = static.eff_lobes[int(ei[3]) + j_count * (1 + si) + j, 0:2].astype(np.float64)
                        conv = _small_scale_convolved(g, sub, eta_s, order)
                        lobes.append(_asg_environment_lobe(conv, scale, wo_s, c_oj, ts_, bs, ns, wol_s,
                                                           static.eff_tables, base, k, j_count, j))
                        rad[sel] += _asg_lights(g, conv, sub, eta_s, wo_s, ts_, bs, ns, wol_s, static.eff_tables, base,
                                                k, j_count, j, table, light_axis[sel], light_eta[sel], light_amp[sel],
                                                light_vis[sel])
                        continue
                    eta_c = 1.0 / (1.0 / lobe[3] + 1.0 / eta_s)
                    axis = _normalize(2 * c_oj[:, None] * xi - wo_s)
                    wl = np.stack([_dot(axis, ts_), _dot(axis, bs), _dot(axis, ns)], 1)
                    mu = _table_interp(static.eff_tables, base, k, j_count, j, wl, wol_s)
                    amp = scale * mu * (2 * np.pi / (lobe[3] + eta_s))
                    amp *= (c_oj > 0)[:, None]  # a lobe facing away from the viewer reflects nothing
                    lobes.append((axis, eta_c / (4 * np.maximum(c_oj, MIN_COS_VIEW)), amp, True))
        env_scales += [1.0] * (len(lobes) - len(env_scales))
        for lobe_index, ((axis, eta, amp, with_lights, *extra), env_scale) in enumerate(zip(lobes, env_scales)):
            cap, asg_lobe = (extra + [None, None])[:2]
            eta = np.minimum(eta, sg.SHARPNESS_MAX)
            e = sg.integral(eta) * sg.table_lookup(table, 0, _dot(axis, ns), eta)
            if cap is not None:
                e = capped_cosine_integral(e, cap, axis, ns, eta, table)
            occ = occlusion(axis, eta, sel)
            if kind == 0:  # an analytic row: where f_s·cos θi itself lies (`moment_table`); nothing for a view
                # below the shading normal's horizon, where f_s is 0
                row = rows[lobe_index]
                off, th, tw = (int(v) for v in static.tex_info[2 + 2 * (idx + lobe_index)][:3])
                image = static.tex_data[3 * off:3 * (off + th * tw)].reshape(th, tw, 3)
                factor = None  # (an isotropic row's p1 at the pixels over its packed one: its parameter map)
                if int(row[0, 0]) not in brdf_mod.ANISOTROPIC_KINDS:
                    factor = row[:, 7] / float(static.analytic[idx + lobe_index, 7])
                env_avg = asg_prefiltered(static.env_maps, static.env_levels, *tabulated_moments(
                    image, moment_sharpness(row), ns, ts_, wo_s, factor))
                env_avg *= (_dot(ns, wo_s) > 0)[:, None]
            elif asg_lobe is None:
                env_avg = prefiltered_lookup(static.env_maps, static.env_levels, axis, eta)
            else:
                env_avg = asg_prefiltered(static.env_maps, static.env_levels, asg_lobe[0], asg_lobe[1], axis,
                                          *asg_lobe[2:])
            rad[sel] += amp * env_scale * env_avg * (e * occ)[:, None]
            for li in range(light_axis.shape[1] if with_lights else 0):
                p_axis, p_eta, p_amp = sg.product(axis, eta, 1.0, light_axis[sel, li], light_eta[sel, li], 1.0)
                e = sg.integral(p_eta) * sg.table_lookup(table, 0, _dot(p_axis, ns), p_eta)
                rad[sel] += amp * light_amp[sel, li] * (p_amp * e * light_vis[sel, li])[:, None]
    out[pix] = np.maximum(np.nan_to_num(rad, nan=0.0, posinf=0.0), 0.0)
    out[pix[seen_from_behind(static.positions, static.faces, f, n, wo)]] = 0.0  # back faces: one-sided, black
    return out


def seen_from_behind(positions, faces, face, n, wo) -> np.ndarray:
    """(R,) bool: the viewer (along wo, (R, 3)) lies behind face `face`'s plane, on the side its shading normal
    n (R, 3) turns from: a back face, which the renderers show black (surfaces are one-sided, as the Monte Carlo
    reference sees them: its rays leave on the viewer's side, behind the face, and meet it)."""
    tri = np.asarray(positions, np.float64)[np.asarray(faces, np.int64)[np.asarray(face, np.int64)]]
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return _dot(ng, n) * _dot(ng, wo) < 0


# ---------------------------------------------------------------------------------------------
# The lit-sphere stage's float64 oracle, and the exact direct lighting it approximates


def litsphere_reference(mesh, spheres: list, face, bary, light_vis, camera_packed, lights_packed, view_mode: int = 0,
                     env_maps=None, env_levels=None, shrink: float = 1.0) -> np.ndarray:
    """(P, 3) float64 what the litsphere kernels compute (kernels/litsphere.py) for a G-buffer (face (P,), bary (P, 2),
    light_vis (P, L) uint8 visible shares in 255ths): `spheres` one LitSphere per material; misses get the
    environment's sharpest level along the camera ray (black without maps)."""
    face = np.asarray(face).reshape(-1)
    cam = np.asarray(camera_packed, np.float64)
    lights = np.asarray(lights_packed, np.float64).reshape(-1, 8)
    width = int(cam[12])
    out = np.zeros((len(face), 3))
    hit = face >= 0
    if (~hit).any() and env_maps is not None:
        pix = np.flatnonzero(~hit)
        x, y = pix % width, pix // width
        d = (cam[3:6][None] + (2 * (x + 0.5) / width - 1)[:, None] * cam[6:9][None]
             + (1 - 2 * (y + 0.5) / cam[13])[:, None] * cam[9:12][None])
        out[pix] = prefiltered_lookup(env_maps, env_levels, d / np.linalg.norm(d, axis=1, keepdims=True), 1e30)
    normals = np.zeros((len(face), 3))
    pos = np.zeros((len(face), 3))
    if hit.any():
        vertices, vertex_normals = mesh.vertices.astype(np.float32), mesh.normals.astype(np.float32)  # as the kernels
        sf = surface_frames(mesh.faces, vertices, vertex_normals, vertex_normals, face[hit],
                            np.asarray(bary, np.float64)[hit], cam[0:3])
        normals[hit], pos[hit] = sf["n"], sf["pos"]
    step = np.zeros(len(face))
    idx = np.arange(len(face))
    for q, ok in ((idx + 1, idx % width + 1 < width), (idx + width, idx + width < len(face))):
        q = np.where(ok, q, idx)
        d = np.linalg.norm(normals[q] - normals, axis=1)
        valid = ok & hit & (face[q] >= 0) & (d <= 0.5)
        step = np.maximum(step, np.where(valid, d, 0.0))
    for mat in np.unique(mesh.face_material[face[hit]]):
        sel = np.flatnonzero(hit & (mesh.face_material[np.maximum(face, 0)] == mat))
        sphere = spheres[mat]
        n, p = normals[sel], pos[sel]
        view = (np.broadcast_to(-cam[3:6] / np.linalg.norm(cam[3:6]), n.shape) if view_mode == 1 else
                (cam[0:3][None] - p) / np.linalg.norm(cam[0:3][None] - p, axis=1, keepdims=True))
        lod = np.log2(np.maximum(step[sel] * 0.5 * shrink * sphere.resolution, 1.0))
        for li, row in enumerate(lights):
            share = np.asarray(light_vis, np.float64).reshape(len(face), -1)[sel, li] / 255.0
            if row[0] == 0:
                light = np.broadcast_to(row[1:4], n.shape)
                e = np.broadcast_to(row[4:7], n.shape)
            else:
                d = row[1:4][None] - p
                r2 = np.maximum((d * d).sum(1), 1e-30)
                light = d / np.sqrt(r2)[:, None]
                e = row[4:7][None] / r2[:, None]
            on = share > 0
            if on.any():
                c = litsphere.reference_shade(sphere, n[on], view[on], light[on], lod[on], shrink)
                out[sel[on]] += share[on, None] * e[on] * c
    return np.maximum(np.nan_to_num(out, nan=0.0, posinf=0.0), 0.0)


def direct_reference(scene, face, bary, light_vis, lights_packed=None) -> np.ndarray:
    """(P, 3) float64 the exact direct lighting of `scene`'s own materials (analytic or baked; not
    LitSpheres) for a G-buffer: Σ over lights of E·s·f(n, l, v)(n·l)⁺, each light an ideal one at its
    disc's centre with its visible share s (light_vis / 255) — what a lit-sphere render of lights alone
    approximates, so that the difference is the method's. Misses are 0."""
    face = np.asarray(face).reshape(-1)
    lights = np.asarray(scene.lights_packed if lights_packed is None else lights_packed, np.float64).reshape(-1, 8)
    out = np.zeros((len(face), 3))
    hit = np.flatnonzero(face >= 0)
    if len(hit) == 0:
        return out
    mesh = scene.mesh
    sf = surface_frames(mesh.faces, mesh.vertices, mesh.normals, vertex_tangents(mesh), face[hit],
                        np.asarray(bary, np.float64)[hit], scene.camera.eye)
    vis = np.asarray(light_vis, np.float64).reshape(len(face), -1)[hit] / 255.0
    mats = mesh.face_material[face[hit]]
    for mat in np.unique(mats):
        sel = np.flatnonzero(mats == mat)
        n, p, wo, t = sf["n"][sel], sf["pos"][sel], sf["wo"][sel], sf["t"][sel]
        for li, row in enumerate(lights):
            if row[0] == 0:
                light, e = np.broadcast_to(row[1:4], n.shape), np.broadcast_to(row[4:7], n.shape)
            else:
                d = row[1:4][None] - p
                r2 = np.maximum((d * d).sum(1), 1e-30)
                light, e = d / np.sqrt(r2)[:, None], row[4:7][None] / r2[:, None]
            f = litsphere.material_response(scene.materials[mat], n, light, wo, tangent=t)
            out[hit[sel]] += vis[sel, li][:, None] * e * f
    return out
