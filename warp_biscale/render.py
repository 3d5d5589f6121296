"""The render driver: G-buffer → (SSDF, lighting) → per-pixel SG shading, on any backend.

    scene = wb.Scene(mesh, [wb.BlinnPhong(0.5, 200, kd=0.3), wb.load("m.wbm")], camera, environment, lights)
    result = wb.render(scene, method="sg", backend="auto")   # or method="mc" (the Monte Carlo reference)
    result.image        # (H, W, 3) float32 linear radiance, never NaN, inf or negative
    result.timings      # seconds per stage, device-synchronised
    result.save("out.png"); result.save("out.exr")

What is computed depends on what the scene needs, and what does not change is not recomputed:
- the environment's SG fit and prefiltered maps once per environment (cached on it);
- the SSDF once per mesh, and only when the scene has an environment and the mesh occludes itself
  (a lone convex object has no SSDF: its visibility is its horizon, exact in the shading);
- shadow rays only when there are lights; specular lobes only for materials with ks > 0;
- packed materials once per material list.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import time

import numpy as np

from . import lighting, litsphere, montecarlo, sg, trace
from .litsphere import LitSphere
from . import ssdf as ssdf_mod
from .backend import get_backend
from .bake import _fit_measured
from .effective import EffectiveBRDF
from .progress import Progress
from .model import Frame, ShadeInputs
from .scene import vertex_tangents
from .shading import axis_lobe_start, pack_materials, sharp_lobes_first
from .trace import check_occlusion_samples, check_ray_part, check_shadow_samples
from .images import compare_images
from .scene import Camera, DirectionalLight, Mesh, Rendering, Scene, _black_environment, _integer

__all__ = ["Scene", "Rendering", "render", "queue_frame", "pack_frame", "static_inputs", "frame_lights",
           "frame_shadow_samples", "METHODS",
           "environment_lights", "material_ball", "litsphere_errors"]

METHODS = ("sg", "mc", "litsphere")


def _environment_thetas(host: dict, has_ssdf: bool, basis, coeffs, res: int, env_sgs) -> np.ndarray:
    """(V, K) float32 θd of the SSDF at each vertex towards each environment lobe's axis (ssdf.ssdf_at_axes):
    the shade kernels blend a pixel's three rows instead of looking the basis up again per lobe and pixel. Kept
    in the mesh's host arrays while the coefficients and the lobes are the same arrays (a material edit makes
    neither anew). (1, 1) zeros without an SSDF or lobes (never read)."""
    if not has_ssdf or len(env_sgs) == 0:
        return np.zeros((1, 1), np.float32)
    held = host.get("env_theta")
    if held is not None and held[0] is coeffs and held[1] is env_sgs:
        return held[2]
    theta = np.ascontiguousarray(ssdf_mod.ssdf_at_axes(basis, coeffs, res, np.asarray(env_sgs)[:, :3]), np.float32)
    host["env_theta"] = (coeffs, env_sgs, theta)
    return theta


def _static_inputs(scene: Scene, backend, progress, timings) -> ShadeInputs:
    """Everything that does not depend on the camera: cached on the scene per backend."""
    key = ("static", backend.name, id(scene.environment), tuple(id(m) for m in scene.materials))
    cached = scene.cache.get(key)
    if cached is not None:
        return cached
    mesh = scene.mesh
    env = scene.environment if scene.environment is not None else _black_environment()
    t0 = time.perf_counter()
    light = lighting.prepare(env, backend, lobes=scene.env_lobes)
    backend.synchronize()
    timings["lighting"] = time.perf_counter() - t0
    has_ssdf = False
    basis = np.zeros((1, 1), np.float32)
    coeffs = np.zeros((len(mesh.vertices), 1), np.float32)
    res = 1
    if scene.environment is not None:
        t0 = time.perf_counter()
        # skip_unoccluded: a mesh that blocks none of its vertices' rays (a lone convex object) gets no
        # distance transform or PCA; its visibility is the horizon, which the shading has exactly.
        # Kept with the mesh's other host arrays (below), so that a new material list does not hash the
        # mesh again (ssdf.build's own cache key; 0.4-0.5 ms of a GPU host's time per edit); the mesh's arrays
        # are not changed in place, and a new array object is a new key.
        arrays = (mesh.vertices, mesh.faces, mesh.normals)
        host = mesh.device_cache.setdefault("host", {})
        held = host.get(("ssdf", scene.ssdf_resolution, scene.ssdf_terms))
        if held is not None and all(a is b for a, b in zip(held[0], arrays)):
            field_ = held[1]
        else:
            field_ = ssdf_mod.build(mesh, backend, resolution=scene.ssdf_resolution, terms=scene.ssdf_terms,
                                    progress=progress, skip_unoccluded=True)
            host[("ssdf", scene.ssdf_resolution, scene.ssdf_terms)] = (arrays, field_)
        timings["ssdf"] = time.perf_counter() - t0
        if field_.occluded:
            has_ssdf = True
            basis, coeffs, res = field_.basis, field_.coeffs, field_.resolution
            if coeffs.shape[1] == 0:  # the mean alone: keep one zero coefficient column for the kernels
                coeffs = np.zeros((len(mesh.vertices), 1), np.float32)
                basis = np.concatenate([basis, np.zeros((1, basis.shape[1]), np.float32)])
    t0 = time.perf_counter()
    # The mesh's arrays as the kernels read them, made once per mesh: the same arrays in every ShadeInputs
    # of the mesh, so that a material edit's new ShadeInputs uploads none of them again (Backend._shade_input).
    host = mesh.device_cache.setdefault("host", {})
    if "tangents" not in host:
        host["tangents"] = vertex_tangents(mesh).astype(np.float32)
    if "positions" not in host:
        host["positions"] = mesh.vertices.astype(np.float32)
        host["normals"] = mesh.normals.astype(np.float32)
        # texture coordinates for the textured materials' lookups (zeros when the mesh has none: no
        # textured material can then be rendered, Scene checks it)
        host["uvs"] = (mesh.uvs if mesh.uvs is not None else np.zeros((len(mesh.vertices), 2))).astype(np.float32)
        for name in ("tangents", "positions", "normals", "uvs"):  # ours alone: frozen, known by identity
            host[name].flags.writeable = False
    # A measured BRDF is shaded by its SG fit: fitted here (once per table) with its sums in this backend's
    # kernels rather than on the host, as a bake does.
    small = [s for m in scene.materials for s in getattr(m, "materials", [getattr(m, "brdf", m)])]
    fits, seconds = _fit_measured(small, backend)
    if fits:
        timings["sg_fit"] = seconds
    packed = pack_materials(scene.materials, environment=scene.environment is not None)
    timings["materials"] = time.perf_counter() - t0
    lobes, residual = light.diffuse_lobes(has_ssdf)
    if has_ssdf not in light.shade_order:
        # Where an SSDF shadows the lobes, the sharpest, most powerful ones come first: they get their own rays.
        order = sharp_lobes_first(lobes.packed()) if has_ssdf else (lobes.packed(), 0)
        order[0].flags.writeable = False
        light.shade_order[has_ssdf] = order
    env_sgs, n_sharp = light.shade_order[has_ssdf]
    # The cached environment, SSDF and SG table arrays are frozen: a backend then knows them by identity.
    basis, coeffs = np.ascontiguousarray(basis, np.float32), np.ascontiguousarray(coeffs, np.float32)
    env_theta = _environment_thetas(host, has_ssdf, basis, coeffs, res, env_sgs)
    for a in (light.prefiltered.maps, light.prefiltered.levels, basis, coeffs, env_theta, sg.lighting_table()):
        a.flags.writeable = False
    static = ShadeInputs(
        faces=mesh.faces, positions=host["positions"], normals=host["normals"],
        tangents=host["tangents"], face_material=mesh.face_material, uvs=host["uvs"],
        env_sgs=env_sgs, n_sharp_lobes=n_sharp, axis_lobes=axis_lobe_start(env_sgs), env_residual=residual,
        env_maps=light.prefiltered.maps,
        env_levels=light.prefiltered.levels, has_ssdf=bool(has_ssdf), ssdf_res=int(res), ssdf_basis=basis,
        ssdf_coeffs=coeffs, env_theta=env_theta, table=sg.lighting_table(), **packed)
    scene.cache.clear()  # one static set per scene: a changed material list or environment replaces it
    scene.cache[key] = static
    return static


def static_inputs(scene: Scene, backend, timings=None) -> ShadeInputs:
    """The shade stage's inputs that do not depend on the camera (`_static_inputs`), made once per scene,
    materials and environment; `timings` gets the seconds of what was made."""
    return _static_inputs(scene, get_backend(backend), Progress(None), {} if timings is None else timings)


def frame_lights(scene: Scene) -> np.ndarray:
    """(L, 8) float32 the SG renderer's lights: the scene's, then its environment's compact bright sources (a sun:
    `lighting.environment_sources`), which the renderer's environment lighting leaves out. (The Monte Carlo
    reference keeps them in the environment.)"""
    lights = np.asarray(scene.lights_packed, np.float32).reshape(-1, 8)
    if scene.environment is None:
        return lights
    sources = lighting.environment_sources(scene.environment).packed
    return np.concatenate([lights, sources]) if len(sources) else lights


def source_shadow_samples(samples: int, block_side: int = 1, part_count: int = 1) -> int:
    """The shadow rays a pixel of an environment's source: `samples`, at most lighting.SOURCE_SHADOW_SAMPLES, or
    at most 16, one a pixel of a 4×4 block, where the rays are shared in 4×4 blocks (`block_side` 4) and each
    pixel's anti-aliasing sample traces its set whole (`part_count` 1: trace.block_side's 16·count): there 8 rays
    would fall back to 2×2 blocks and cost each pixel two rays, 16 cost it one. With the set split between samples
    it falls back to 2×2 whatever its count, and 8 cost less."""
    shared_4x4 = int(block_side) == 4 and int(part_count) == 1
    return min(int(samples), 16 if shared_4x4 else lighting.SOURCE_SHADOW_SAMPLES)


def frame_shadow_samples(scene: Scene, samples: int, block_side: int = 1, part_count: int = 1) -> np.ndarray:
    """(L,) int32 the shadow rays a pixel of each of `frame_lights(scene)`: `samples` for the scene's lights,
    `source_shadow_samples` for its environment's sources (`block_side`: the frame's, `frame_block_rays`;
    `part_count`: the anti-aliasing samples that split each set, `frame_part_count`)."""
    n = check_shadow_samples(samples)
    counts = np.full(len(frame_lights(scene)), n, np.int32)
    counts[len(np.asarray(scene.lights_packed).reshape(-1, 8)):] = source_shadow_samples(n, block_side, part_count)
    return counts


def frame_part_count(n_aa: int, split_rays: bool, aa_shading: str) -> int:
    """Between how many anti-aliasing samples a frame's first sample splits each set of rays: n_aa with split_rays,
    else 1 (every sample traces every ray); 1 with aa_shading "pixel" (the first sample traces every ray)."""
    return n_aa if split_rays and aa_shading != "pixel" else 1


SHADOW_SAMPLES = 16  # shadow rays per light and pixel: a penumbra in 16 steps, noise turned per pixel
# environment-occlusion rays per pixel where an SSDF shadows the environment: lobes up to η = 2 by the rays
# alone (shading.RAYS_ONLY), so a constant map's six shadow lobes (lighting.shadow_lobes) are seen whole
OCCLUSION_SAMPLES = 16
# block_rays="auto" (the default) shares the rays in 2x2 blocks from this many pixels up: below it two pixels can be
# much of a contact shadow, above it the blocks cost the image little and a frame three quarters of its rays
# (docs/design.md, "Rays shared in pixel blocks", has the measurements) ...
BLOCK_RAYS_MIN_PIXELS = 320 * 240
# ... and in 4x4 blocks from this many up, where a set of 16 rays a pixel costs one ray a pixel: below it four
# pixels lighten a contact shadow towards the 5 % the contact scene allows (docs/design.md has the measurements).
BLOCK_RAYS_4_MIN_PIXELS = 1920 * 1080


def pack_frame(scene: Scene, backend="auto", progress=None, timings=None,
               shadow_samples: int = SHADOW_SAMPLES, occlusion_samples: int = OCCLUSION_SAMPLES,
               part=(0, 1)) -> Frame:
    """The shade stage's inputs for the scene's current camera and lights, its G-buffer on the host
    (light_vis included, `shadow_samples` rays per light; and the occlusion masks of `occlusion_samples`
    rays per pixel where the scene has an SSDF): what `shading.shade_reference` takes (and `backend.shade`,
    its inputs and G-buffer). `part`: those of anti-aliasing sample (index, count)'s rays alone (`trace.ray_part`),
    shared in the pixel blocks of a frame of width W with (index, count, W[, side]) (`trace.pixel_parts`; the
    G-buffer then holds the shared results and the rays each pixel was lent)."""
    backend = get_backend(backend)
    timings = {} if timings is None else timings
    n_occlusion = check_occlusion_samples(occlusion_samples)
    part = check_ray_part(part)
    if part[2] not in (0, scene.camera.width):
        raise ValueError(f"part's block width must be 0 or the camera's width {scene.camera.width}, got {part[2]}")
    static = _static_inputs(scene, backend, progress, timings)
    g = backend.trace_primary(scene.mesh, scene.camera)
    lights = frame_lights(scene)
    g.ray_part = part
    sources = frame_shadow_samples(scene, shadow_samples, part[3] if part[2] else 1, part[1])
    g.light_vis = (backend.trace_shadows(scene.mesh, g, lights, samples=sources,
                                         part=part) if len(lights) else np.zeros((len(g.face), 0), np.uint8))
    if static.has_ssdf and n_occlusion:
        g.occlusion = backend.trace_occlusion(scene.mesh, g, n_occlusion, part=part)
        g.occlusion_samples = n_occlusion
        g.lobe_occlusion = backend.trace_lobe_rays(scene.mesh, g, static.sharp_lobes(), part=part)
        if part[2]:
            g.occlusion_known, g.lobe_known = backend.ray_known(scene.mesh)
    return Frame(static, g, scene.camera.packed(), lights)


AA_MAX = 256
AA_SHADING = ("sample", "pixel")


def check_block_rays(block_rays):
    """`block_rays` as "auto" or the side of the pixel blocks that share the rays: 1 (False: each pixel its own),
    2 (True) or 4; anything else a one-line error."""
    if isinstance(block_rays, bool):
        return 2 if block_rays else 1
    if isinstance(block_rays, str) and block_rays == "auto":
        return block_rays
    if isinstance(block_rays, (int, np.integer)) and int(block_rays) in (1, 2, 4):
        return int(block_rays)
    raise ValueError(f"block_rays must be True, False, 'auto' or a block side 1, 2 or 4, got {block_rays!r}")


def frame_block_rays(block_rays, camera) -> int:
    """The side of the pixel blocks that share a frame's rays (1: each pixel its own): `block_rays` itself
    (`check_block_rays`), or for "auto" 4 from BLOCK_RAYS_4_MIN_PIXELS pixels up, 2 from BLOCK_RAYS_MIN_PIXELS,
    else 1."""
    side = check_block_rays(block_rays)
    if side == "auto":
        pixels = camera.width * camera.height
        return 4 if pixels >= BLOCK_RAYS_4_MIN_PIXELS else 2 if pixels >= BLOCK_RAYS_MIN_PIXELS else 1
    return side


def frame_block_sides(shadow_samples, occlusion_samples: int, n_sharp: int, part_count: int, width: int,
                      block_rays: int) -> dict:
    """The side of the pixel blocks each set of a frame's first sample is shared in (`trace.block_side`): what a
    frame's block_rays (`frame_block_rays`) gives each set, which may be less (a 4 asked of a set smaller than 16
    rays for each anti-aliasing sample that splits it goes 2×2). {"shadow": [a side per light of `frame_lights`],
    "occlusion": side or None (no occlusion rays), "lobe_rays": side or None (no sharp environment lobe)}."""
    part = (0, part_count, width, block_rays) if block_rays > 1 else (0, part_count)
    return {"shadow": [trace.block_side(int(n), part) for n in np.asarray(shadow_samples).reshape(-1)],
            "occlusion": trace.block_side(occlusion_samples, part) if occlusion_samples else None,
            "lobe_rays": trace.block_side(trace.LOBE_RAYS, part) if occlusion_samples and n_sharp else None}


def aa_offsets(samples: int, seed: int = 0) -> np.ndarray:
    """(samples, 2) sub-pixel offsets in [−½, ½)², multi-jittered (Chiu, Shirley and Wang 1994): one in
    each cell of a k × k grid (k² ≥ samples, cells taken in a shuffled order when samples < k²) and,
    within the grid, one per row and column of the fine samples × samples grid, so an edge of any
    slope is sampled at distinct places across the pixel. (0, 0), the pixel centre, for one sample.
    Deterministic."""
    if samples == 1:
        return np.zeros((1, 2))
    rng = np.random.default_rng(seed)
    k = int(np.ceil(np.sqrt(samples)))
    cells = rng.permutation(k * k)[:samples] if samples < k * k else np.arange(samples)
    cx, cy = cells % k, cells // k
    # fine positions: within cell (cx, cy), sub-cell (cy, cx) of a k × k sub-grid (canonical n-rooks)
    fx = (cx * k + cy + rng.random(samples)) / (k * k)
    fy = (cy * k + cx + rng.random(samples)) / (k * k)
    return np.stack([fx, fy], 1) - 0.5


def check_aa(aa) -> int:
    return _integer("aa", aa, 1, AA_MAX, " (samples per pixel)")


def render(scene: Scene, method: str = "sg", backend="auto", progress=None, aa: int = 1,
           shadow_samples: int | None = None, occlusion_samples: int | None = None, split_rays: bool | None = None,
           block_rays="auto", aa_shading: str = "sample", **options) -> Rendering:
    """Render `scene` → `Rendering`. method "sg": the per-pixel SG renderer (Wang 2009 / Iwasaki 2012 §5), with `aa`
    jittered samples per pixel (`aa_offsets`; 1: the pixel centre only) averaged with a box filter, `shadow_samples`
    (default SHADOW_SAMPLES) shadow rays per light spread over its disc (soft shadows; 1: one ray to its centre, a
    hard shadow), and, where the mesh occludes itself under an environment, `occlusion_samples` (default
    OCCLUSION_SAMPLES) environment-occlusion rays per pixel that
    shadow the broad lobes, and with them rays towards a sun's or a softbox's sharp lobes (shading's "Broad lobes'
    visibility per pixel" and "Sharp environment lobes' visibility per pixel"; 0: the SSDF alone). `split_rays`
    (default): the `aa` samples of a pixel share each set of rays, sample k of n tracing rays k, k + n, … of it
    (`trace.ray_part`), so an anti-aliased frame traces the rays of one frame and its average holds every ray of
    each set once; False: every sample traces every ray (n times the rays, less noise). `block_rays` True (or 2):
    the pixels of each 2×2 block share their rays too, each tracing a quarter of each set of at least four rays and
    weighing those of its neighbours on the same surface (`trace.pixel_parts`, `trace.share_block`: a depth or
    crease edge keeps each side's rays apart), so a frame traces a quarter of the rays, and visibility is averaged
    over two pixels: at low resolutions a contact shadow or a soft terminator comes out lighter (docs/design.md,
    "Rays shared in pixel blocks"); 4: 4×4 blocks for each set of at least 16·n rays, n the anti-aliasing samples
    that split it (a sixteenth of the rays, visibility averaged over four pixels; `trace.block_side`), 2×2 for
    smaller sets (so with aa > 1 and split_rays the default 16 rays go 2×2, but for aa_shading "pixel"'s first
    sample, which traces them all); False (or 1): every pixel
    traces its own; "auto" (default): 4 from BLOCK_RAYS_4_MIN_PIXELS (1920×1080) pixels up, 2 from
    BLOCK_RAYS_MIN_PIXELS (320×240), else 1 (`frame_block_rays`; info["block_rays"] says which side the frame
    asked, info["block_sides"] the side each set of the first sample's rays got, `frame_block_sides`).
    info["env_lobes"] is the number of environment lobes shaded: the fit's (at most `Scene.env_lobes`, fewer for a
    map that needs fewer), its ambient lobe split into six along the axes where an SSDF shadows them (so up to
    env_lobes + 5; docs/design.md §5.7).
    `aa_shading` "sample" (default): each anti-aliasing sample shaded; "pixel": a pixel shaded once where its samples
    hit the surface its first sample hits, as multisampling does: the first sample traces every ray of each set and
    is shaded whole; a later sample traces (its own part of each set) and shades only the pixels whose hit is not on
    the first sample's surface there (another material, a depth or crease edge: `trace.changed_pixels`), the
    others adding the first sample's radiance again. Edges are anti-aliased at about one frame's shading and rays;
    shading within a surface is not.
    "mc": the Monte
    Carlo reference (`montecarlo.render`, options `samples`, `seed`, `truths`, `fallback`, `truth_facets`,
    `truth_seed`, `truth_directions`; the ray options above are the SG renderer's and refused), whose lights are the
    same discs and which judges a baked material by its
    exact ground truth (`truth.truth_of`); "litsphere": the lit-sphere shader (seed 004, `warp_biscale.litsphere`),
    each material a `LitSphere` (any other made into one, options `angles`, `resolution`; a `Textured` material
    or an analytic anisotropic BRDF, which a lit sphere cannot hold, is refused: render those with "sg" or "mc"),
    options `view` ("pixel": each pixel's own view direction; "camera": the paper's distant viewer), `shrink` (the
    turned normal's scale before the lookup: 1, or the paper's litsphere.SHRINK), `env_lights` (directional lights
    standing for the environment), `shadows` (False: every light seen whole, no shadow rays — the paper's frame)
    and `report_error` (True, or references among "sg", "mc": info["error"] then holds `litsphere_errors`, the
    Monte Carlo one at `samples` a pixel), with `aa`, `shadow_samples` and `split_rays` as "sg"."""
    if not isinstance(scene, Scene):
        hint = (" (a scene file: wb.load_scene(path).scene)" if isinstance(scene, (str, os.PathLike)) else
                " (a loaded scene file: its .scene)" if isinstance(getattr(scene, "scene", None), Scene) else "")
        raise TypeError(f"render takes a Scene, got {type(scene).__name__}{hint}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    # The ray options given for a method that traces no such rays are refused, not silently dropped.
    given = [name for name, value in (("shadow_samples", shadow_samples), ("occlusion_samples", occlusion_samples),
                                      ("split_rays", split_rays)) if value is not None]
    unused = {"mc": given, "litsphere": [n for n in given if n == "occlusion_samples"]}.get(method, [])
    if unused:
        raise ValueError(f"{' and '.join(unused)}: option(s) of the SG renderer (method='sg'), not of "
                         f"method={method!r}" + ("; the Monte Carlo reference traces its own rays" if method == "mc"
                                                 else "; the lit-sphere shader traces no occlusion rays"))
    shadow_samples = SHADOW_SAMPLES if shadow_samples is None else shadow_samples
    occlusion_samples = OCCLUSION_SAMPLES if occlusion_samples is None else occlusion_samples
    split_rays = True if split_rays is None else split_rays
    if method == "sg":  # a material with no lobes to shade (the matrix method's) refuses now, not after the setup
        for m in scene.materials:
            if hasattr(m, "shade_lobes"):
                m.shade_lobes()
    n_aa, n_shadow, n_occlusion = check_frame_options(aa, shadow_samples, occlusion_samples, split_rays, block_rays,
                                                      aa_shading)
    if method != "sg" and (check_block_rays(block_rays) not in ("auto", 1) or aa_shading != "sample"):
        raise ValueError(f"block_rays and aa_shading are options of the SG renderer (method='sg'), not of "
                         f"method={method!r}")
    if method == "mc":
        if n_aa != 1:
            raise ValueError("aa is an option of the SG renderer; the Monte Carlo reference samples pixel centres")
        _check_options(method, montecarlo.render, options, ("scene", "backend", "progress"))
        check_no_litspheres(scene, method)
        return montecarlo.render(scene, backend=backend, progress=progress, **options)
    if method == "litsphere":
        _check_options(method, _render_litsphere, options, ("scene", "backend", "n_aa", "n_shadow", "split_rays"))
        return _render_litsphere(scene, get_backend(backend), n_aa, n_shadow, split_rays=split_rays, **options)
    if options:
        raise ValueError(f"unknown option(s) for the SG renderer: {sorted(options)}")
    check_no_litspheres(scene, method)
    block_rays = frame_block_rays(block_rays, scene.camera)
    backend = get_backend(backend)
    progress = progress or Progress(None)
    timings: dict = {"gbuffer": 0.0, "shade": 0.0}
    t_all = time.perf_counter()
    static = _static_inputs(scene, backend, progress, timings)
    lights = frame_lights(scene)
    n_occlusion = n_occlusion if static.has_ssdf else 0  # nothing occludes: the rays would all escape
    parts = frame_part_count(n_aa, split_rays, aa_shading)
    image = _accumulate(scene, backend, n_aa, frame_shadow_samples(scene, n_shadow, block_rays, parts), n_occlusion,
                        lights,
                        timings,
                        lambda cam, to_host, **kw: backend.shade(scene.mesh, static, cam.packed(), lights,
                                                                 to_host=to_host, **kw),
                        static.sharp_lobes(), split_rays, block_rays, aa_shading == "pixel")
    timings["total"] = time.perf_counter() - t_all
    cam = scene.camera
    info = {"backend": backend.name, "device": backend.device, "method": "sg", "ssdf": bool(static.has_ssdf),
            "env_lobes": len(static.env_sgs), "lights": len(lights),
            "environment_sources": len(lights) - len(scene.lights_packed), "width": cam.width, "height": cam.height,
            "aa": n_aa, "shadow_samples": n_shadow,
            "source_shadow_samples": source_shadow_samples(n_shadow, block_rays, parts) if len(lights) > len(
                scene.lights_packed) else None, "occlusion_samples": n_occlusion, "split_rays": split_rays,
            "block_rays": block_rays,
            "block_sides": frame_block_sides(frame_shadow_samples(scene, n_shadow, block_rays, parts), n_occlusion,
                                             len(static.sharp_lobes()), parts, cam.width, block_rays),
            "aa_shading": aa_shading}
    return Rendering(image, timings, info)


def check_frame_options(aa, shadow_samples, occlusion_samples, split_rays, block_rays, aa_shading) -> tuple:
    """(aa, shadow samples, occlusion samples) of a frame's options, each checked (one-line errors)."""
    n_aa = check_aa(aa)
    n_shadow = check_shadow_samples(shadow_samples)
    n_occlusion = check_occlusion_samples(occlusion_samples)
    if not isinstance(split_rays, bool):
        raise ValueError(f"split_rays must be True or False, got {split_rays!r}")
    check_block_rays(block_rays)
    if aa_shading not in AA_SHADING:
        raise ValueError(f"aa_shading must be one of {AA_SHADING}, got {aa_shading!r}")
    return n_aa, n_shadow, n_occlusion


def queue_frame(scene: Scene, backend="auto", aa: int = 1, shadow_samples: int = SHADOW_SAMPLES,
                occlusion_samples: int = OCCLUSION_SAMPLES, split_rays: bool = True, block_rays="auto",
                aa_shading: str = "sample") -> None:
    """Queue one SG frame of `scene` as `render` makes it (the same options, checked as `render` checks them),
    its stages back to back with no waits and its image left on the device: what an interactive viewer draws
    from, and the benchmarks' frame (`backend.accumulated_frame` reads an anti-aliased one back). The scene's
    precomputation (lighting, SSDF, materials) is `render`'s, cached on the scene."""
    n_aa, n_shadow, n_occlusion = check_frame_options(aa, shadow_samples, occlusion_samples, split_rays, block_rays,
                                                      aa_shading)
    check_no_litspheres(scene, "sg")
    block_rays = frame_block_rays(block_rays, scene.camera)
    backend = get_backend(backend)
    static = _static_inputs(scene, backend, Progress(None), {})
    lights = frame_lights(scene)
    n_occlusion = n_occlusion if static.has_ssdf else 0
    parts = frame_part_count(n_aa, split_rays, aa_shading)
    _accumulate(scene, backend, n_aa, frame_shadow_samples(scene, n_shadow, block_rays, parts), n_occlusion, lights,
                {"shade": 0.0},
                lambda cam, to_host, **kw: backend.shade(scene.mesh, static, cam.packed(), lights, to_host=to_host,
                                                         **kw),
                static.sharp_lobes(), split_rays, block_rays, aa_shading == "pixel", wait=False, to_host=False)


def check_no_litspheres(scene: Scene, method: str) -> None:
    """Refuse, in one line, a material `method` cannot shade: a LitSphere (only the lit-sphere shader reads
    one). A MeasuredBRDF the SG renderer shades by its SG fit (`brdf.sg_lobes`), the Monte Carlo reference
    and the lit-sphere shader by its table."""
    for i, m in enumerate(scene.materials):
        if isinstance(m, LitSphere):
            raise ValueError(f"Scene.materials[{i}] is a LitSphere, which only method='litsphere' renders "
                             f"(method={method!r} needs the material itself)")


def _accumulate(scene: Scene, backend, n_aa: int, n_shadow, n_occlusion: int, lights, timings: dict, shade,
                lobes=None, split_rays: bool = True, block_rays: int = 1, shade_once: bool = False,
                wait: bool = True, to_host: bool = True):
    """The (H, W, 3) image: per anti-aliasing sample (`aa_offsets`) the G-buffer, the shadow rays of
    `lights` (n_shadow a pixel for every light, or one count a light; none when 0), the environment-occlusion
    rays (n_occlusion a pixel; none when 0) and with them the rays of the sharp environment lobes `lobes`
    (`ShadeInputs.sharp_lobes`), then `shade(camera, to_host)` (→ (P, 3) with to_host), averaged with a box filter
    on the device (`accumulate_frame`: one read-back, of the average). With split_rays, sample i of n traces its part
    (i, n) of each set of rays (`trace.ray_part`), else all of them; with block_rays > 1, shared in pixel blocks
    of that side (`trace.pixel_parts`). shade_once (n > 1): the first sample traces every ray of each set (shared
    in blocks with block_rays) and is shaded whole; a later one traces its own part (k, n) of each set and shades
    only the pixels whose hit is off the first sample's surface (`only_changed`), the others adding the first
    sample's radiance again. wait: wait for each stage, to time it into `timings`; False: the stages queued back to
    back, as a viewer's frame. to_host False: the image left on the device (→ None)."""
    cam = scene.camera

    def timed(key, t0):
        if wait:
            backend.synchronize()
            timings[key] = timings.get(key, 0.0) + time.perf_counter() - t0

    image = None
    shade_once = shade_once and n_aa > 1
    for i, (jx, jy) in enumerate(aa_offsets(n_aa)):
        sample = dataclasses.replace(cam, jitter=(jx, jy)) if n_aa > 1 else cam
        part = (i, n_aa) if split_rays and not (shade_once and i == 0) else (0, 1)
        if block_rays > 1 and not (shade_once and i):  # (a changed pixel's block holds the first sample's rays)
            part = (*part, cam.width, block_rays)
        changed = {"only_changed": True} if shade_once and i else {}
        t0 = time.perf_counter()
        backend.trace_primary(scene.mesh, sample, to_host=False, keep=shade_once and i == 1)
        timed("gbuffer", t0)
        if len(lights) and np.min(n_shadow) > 0:
            t0 = time.perf_counter()
            backend.trace_shadows(scene.mesh, None, lights, to_host=False, samples=n_shadow, part=part, **changed)
            timed("shadows", t0)
        if n_occlusion:
            t0 = time.perf_counter()
            backend.trace_occlusion(scene.mesh, None, n_occlusion, to_host=False, part=part, **changed)
            if lobes is not None and len(lobes):
                backend.trace_lobe_rays(scene.mesh, None, lobes, to_host=False, part=part, **changed)
            timed("occlusion", t0)
        t0 = time.perf_counter()
        if n_aa == 1:
            image = shade(sample, to_host)
        else:  # (summed in float32: at most 256 samples of a non-negative value, relative error ~1e-5)
            shade(sample, False, **changed)
            backend.accumulate_frame(scene.mesh, cam.width, cam.height, 1.0 / n_aa, first=i == 0)
        timings["shade"] += time.perf_counter() - t0
    if not to_host:
        return None
    if n_aa > 1:
        t0 = time.perf_counter()
        image = backend.accumulated_frame(scene.mesh, cam.width, cam.height)
        timings["shade"] += time.perf_counter() - t0
    return image.reshape(cam.height, cam.width, 3)


VIEWS = {"pixel": 0, "camera": 1}


def scene_spheres(scene: Scene, angles=litsphere.PAPER_ANGLES, resolution: int = litsphere.RESOLUTION,
                  backend=None) -> list:
    """One LitSphere per scene material: a LitSphere as it is, any other material made into one
    (`LitSphere.from_material` at `angles`, `resolution`, its texels by `backend`'s kernels, or on the
    host for None), kept in scene.cache while the materials stay."""
    key = ("litspheres", tuple(id(m) for m in scene.materials), tuple(np.asarray(angles, float)), int(resolution))
    cached = scene.cache.get(key)
    if cached is None:
        cached = scene.cache[key] = [m if isinstance(m, LitSphere) else
                                     LitSphere.from_material(m, angles, resolution, backend=backend)
                                     for m in scene.materials]
    return cached


def _check_references(scene: Scene, references) -> None:
    """What `litsphere_errors` needs, checked before the lit spheres are made: known references, and materials they
    render (a LitSphere by its source; the SG renderer takes no matrix bake, the Monte Carlo reference samples
    the lobes of a baked material's glossy small-scale BRDFs)."""
    if not references:
        return
    for ref in references:
        if ref not in ("sg", "mc"):
            raise ValueError(f"references must be 'sg' and/or 'mc', got {ref!r}")
    used = set(np.unique(np.asarray(scene.mesh.face_material)).tolist())  # (mc asks only of the materials used)
    for i, m in enumerate(scene.materials):
        if isinstance(m, LitSphere):
            if m.source is None:
                raise ValueError(f"Scene.materials[{i}] is a loaded LitSphere (no source material): its error "
                                 "against an exact render cannot be measured")
            m = m.source
        try:
            if "sg" in references and hasattr(m, "shade_lobes"):
                m.shade_lobes()
            if "mc" in references and isinstance(m, EffectiveBRDF) and i in used:
                montecarlo.sampling_plan(m)
        except ValueError:  # (the material's own message advises another method: not what is wrong here)
            raise ValueError(f"report_error: its references ({', '.join(references)}) cannot render "
                             f"materials[{i}] ({type(m).__name__}, a {getattr(m, 'method', '?')} bake): leave "
                             "report_error out, or ask only references that render it") from None


def litsphere_errors(scene: Scene, image, backend="auto", references=("sg", "mc"), samples: int = 64) -> dict:
    """The error of a lit-sphere `image` of `scene` against the exact renders of the same materials, over the
    pixels that see the object: {reference: compare_images(...)} for "sg" (our SG renderer, 1 sample a
    pixel, hard shadows: what the lit sphere reproduces) and "mc" (the Monte Carlo reference, `samples` a
    pixel). A LitSphere material stands for its `source`; one without (a loaded one) cannot be judged."""
    _check_references(scene, references)
    materials = [m.source if isinstance(m, LitSphere) else m for m in scene.materials]
    exact_scene = dataclasses.replace(scene, materials=materials, cache={})
    backend = get_backend(backend)
    mask = backend.trace_primary(scene.mesh, scene.camera).face.reshape(scene.camera.height, scene.camera.width) >= 0
    out = {}
    for ref in references:
        if ref == "sg":
            exact = render(exact_scene, backend=backend, shadow_samples=1, block_rays=False).image
        else:
            exact = render(exact_scene, method="mc", backend=backend, samples=samples).image
        out[ref] = compare_images(np.asarray(image)[mask][None], exact[mask][None])
    return out


def _check_options(method: str, fn, options: dict, passed: tuple) -> None:
    """Refuse, in one line naming them and what the method takes, keyword options `fn` does not take (as the SG
    renderer's own check does) rather than Python's TypeError from inside the call."""
    takes = [name for name in inspect.signature(fn).parameters if name not in passed]
    unknown = sorted(set(options) - set(takes))
    if unknown:
        raise ValueError(f"unknown option(s) for method={method!r}: {unknown}; it takes {takes}")


def _render_litsphere(scene: Scene, backend, n_aa: int, n_shadow: int, view: str = "pixel",
                      env_lights: int = litsphere.ENV_LIGHTS, angles=litsphere.PAPER_ANGLES,
                      resolution: int = litsphere.RESOLUTION, shrink: float = 1.0, report_error=None,
                      samples: int = 64, shadows: bool = True, split_rays: bool = True) -> Rendering:
    if view not in VIEWS:
        raise ValueError(f"view must be one of {sorted(VIEWS)}, got {view!r}")
    if isinstance(shrink, bool) or not isinstance(shrink, (int, float)) or not (0.5 <= shrink <= 1):
        raise ValueError(f"shrink must be a number in [0.5, 1] (the paper's is {litsphere.SHRINK}), got {shrink!r}")
    if isinstance(env_lights, bool) or not isinstance(env_lights, int) or not (2 <= env_lights <= 4096):
        raise ValueError(f"env_lights must be an integer in [2, 4096], got {env_lights!r}")
    for i, m in enumerate(scene.materials):  # every material checked before any is made into a sphere
        if not isinstance(m, LitSphere):
            litsphere.check_holdable(m, f"materials[{i}]")
    refs = (("sg", "mc") if report_error is True else tuple(report_error)) if report_error else ()
    _check_references(scene, refs)
    timings: dict = {"gbuffer": 0.0, "shade": 0.0}
    t_all = time.perf_counter()
    t0 = time.perf_counter()
    spheres = scene_spheres(scene, angles, resolution, backend)
    key = ("litsphere_pack", tuple(id(s) for s in spheres))
    pack = scene.cache.get(key)
    if pack is None:
        pack = scene.cache[key] = litsphere.pack_spheres(spheres)
    timings["materials"] = time.perf_counter() - t0
    env = scene.environment
    t0 = time.perf_counter()
    # the background: the environment's prefiltered maps, or one black texel (nothing to fit or filter)
    maps, levels = ((lambda p: (p.maps, p.levels))(lighting.prepare(env, backend, lobes=scene.env_lobes).prefiltered)
                    if env is not None else (np.zeros((1, 3), np.float32), np.array([[0, 0, 1, 1]], np.float32)))
    lights = scene.lights_packed
    if env is not None:
        env_key = ("litsphere_lights", int(env_lights), backend.name)
        extra = env.device_cache.get(env_key)
        if extra is None:
            extra = env.device_cache[env_key] = np.array(
                [lt.packed() for lt in environment_lights(env, env_lights, backend)], np.float32).reshape(-1, 8)
        lights = np.concatenate([np.asarray(lights, np.float32).reshape(-1, 8), extra])
    timings["lighting"] = time.perf_counter() - t0
    if not isinstance(shadows, bool):
        raise ValueError(f"shadows must be True or False, got {shadows!r}")
    image = _accumulate(scene, backend, n_aa, n_shadow if shadows else 0, 0, lights, timings,
                        lambda cam, to_host: backend.shade_litsphere(scene.mesh, pack, cam.packed(), lights, maps,
                                                                     levels, VIEWS[view], shrink, shadowed=shadows,
                                                                     to_host=to_host), None, split_rays)
    timings["total"] = time.perf_counter() - t_all
    cam = scene.camera
    info = {"backend": backend.name, "device": backend.device, "method": "litsphere", "view": view, "shrink": shrink,
            "shadows": shadows,
            "lights": len(lights), "env_lights": len(lights) - len(scene.lights_packed), "width": cam.width,
            "height": cam.height, "aa": n_aa, "shadow_samples": n_shadow,
            "texture_bytes": int(sum(s.nbytes for s in {id(s): s for s in spheres}.values()))}
    if refs:
        info["error"] = litsphere_errors(scene, image, backend, refs, samples)
    return Rendering(image, timings, info)


def environment_lights(environment, count: int = litsphere.ENV_LIGHTS, backend="auto") -> list:
    """DirectionalLights standing for `environment`: `count` on a Fibonacci sphere, each carrying the radiance of
    the map without its compact sources averaged over its cell (the prefiltered map at a sharpness whose lobe spans
    the cell) times the cell's solid angle 4π/count, with the disc of that solid angle; then those sources
    themselves (a sun: `lighting.environment_sources`)."""
    count = int(count)
    if count < 2:
        raise ValueError(f"environment_lights count must be at least 2, got {count}")
    k = np.arange(count) + 0.5
    zc = 1 - 2 * k / count
    r = np.sqrt(np.maximum(1 - zc * zc, 0.0))
    ang = np.pi * (1 + 5**0.5) * k
    dirs = np.stack([r * np.cos(ang), zc, r * np.sin(ang)], 1)
    omega = 4 * np.pi / count
    # an SG of sharpness η holds most of its mass within a cap of solid angle ≈ 2π/η
    eta = 2 * np.pi / omega
    light = lighting.prepare(environment, backend)
    radiance = lighting.prefiltered_lookup(light.prefiltered.maps, light.prefiltered.levels, dirs, np.full(count, eta))
    radius = np.degrees(np.arccos(1 - omega / (2 * np.pi)))
    return [DirectionalLight(d, np.maximum(rad, 0.0) * omega, radius) for d, rad in zip(dirs, radiance)
            if np.max(rad) > 0] + list(lighting.environment_sources(environment).lights)


BALL_LIGHTS = (((-0.55, 0.65, 0.75), 2.4), ((0.85, 0.1, 0.5), 0.6), ((0.2, 0.6, -0.9), 1.2))  # key, fill, rim


def material_ball(material, size: int = 256, backend="auto", resolution: int = litsphere.RESOLUTION,
                  angles=litsphere.PAPER_ANGLES):
    """A sphere of `material` (any the lit sphere takes, or a LitSphere) under a key, a fill and a rim light,
    rendered by the lit-sphere shader, size × size pixels, 4 samples a pixel → Rendering."""
    size = _integer("ball size", size, 8, 8192)
    sphere = Mesh.sphere(1.0, subdivisions=5)
    camera = Camera(eye=(0.0, 0.0, 3.6), target=(0.0, 0.0, 0.0), fov=36.0, width=size, height=size)
    lights = [DirectionalLight(d, e, 1.0) for d, e in BALL_LIGHTS]
    return render(Scene(sphere, [material], camera, None, lights), method="litsphere", backend=backend, aa=4,
                  shadow_samples=1, resolution=resolution, angles=angles)
