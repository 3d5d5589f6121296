"""The SG bake (Iwasaki 2012 §4–5): the one driver for facets → visibility → BVNDF → EM → amplitudes → tables.

The driver calls backend primitives only and never asks which backend it holds. What depends on
the geometry alone (facets, visibility, BVNDF, lobes, amplitudes) is kept per tile, so baking the
same tile again with other small-scale BRDFs recomputes only the tables (`timings` then holds
only "tables"); `EffectiveBRDF.with_materials` does the same on a material in hand.
"""

from __future__ import annotations

import collections
import functools
import math
import time
import warnings
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from . import directions as dirs
from . import lobes as lobes_mod
from . import matrix as matrix_mod
from . import sg
from .backend import get_backend
from .device import OnDevice, once
from .brdf import MEASURED, Lambert, refuse_anisotropic
from .effective import METHODS, EffectiveBRDF, Provenance, compare, device_levels
from .progress import as_progress
from .truth import _check_count, _prepare, _Timer, check_seed, ground_truth
from .model import Bvndf, Facets

__all__ = ["bake", "Bvndf", "ROUTES"]

ROUTES = ("facets", "histogram")
# The cap on EM steps: well-separated lobes settle in 2–5. On a smooth NDF (height field, woven) EM
# creeps on, and against the 2^18-facet ground truths (PoCL, 2^16 facets, J = 8 and 16, Blinn–Phong
# n = 512 and Cook–Torrance m = 0.2) steps 9–16 moved the PSNR by −0.7 to +0.4 dB, mean +0.01 dB
# (steps past 16: −0.3 to +0.7, mean −0.02), while each step costs a chain of dependent launches (bench/README.md).
EM_ITERATIONS = 8
# The J that lobes="auto" tries, in order: every J up to the kernels' 16, then a few steps to 128 (a
# woven tile's NDF error at the probe sharpness of Blinn–Phong n = 512 is 0.35 at J = 16, 0.26 at 32,
# 0.040 at 64 and 0.037 at 128, for 22.9, 25.4, 34.9 and 35.6 dB against its 2^18-facet truth).
AUTO_LOBES = (*range(1, 17), 24, 32, 48, 64, 96, 128)
HISTOGRAM_BYTES = 1 << 30  # the dense histogram N (pairs × non-empty bins) is refused beyond this
# A flat tile's bins are summed over its faces (`_face_bins`) when it has at most one face per this many facets
# (a height field's 8192 faces at 2^16 facets were faster facet by facet).
FACETS_PER_FACE = 32
# Bakes of other methods by name, each (tile, materials, lobes, directions, normal_res, facets, backend, seed,
# bvndf, progress) → material: their modules register them when warp_biscale loads ("asg": asg_bake), so that
# this driver imports none of them.
METHOD_BAKES: dict = {}


def _one_channel(tile) -> bool:
    """Whether all the tile's faces have one material and one colour (see `_channels`)."""
    ids, colors = tile.material_ids, tile.colors
    return bool(len(ids) and (ids == ids[0]).all() and (colors == colors[0]).all())


_CHANNEL_FACES = weakref.WeakKeyDictionary()  # tile → its `_channel_faces` (a tile's faces do not change)


def _channel_faces(tile) -> list:
    """The colour channels a face at a time: → list of (material, rgb multiplier, its value a face (F,) float64,
    or None), made once per tile (`_CHANNEL_FACES`).

    A tile whose faces all have one material and one colour is one channel whose value is None: its weight is
    the facets' area (the backends then use the area they hold: no per-facet work). Otherwise a material whose
    faces all have one colour is one channel, 1 on its faces and 0 elsewhere, the colour applied afterwards
    (one sum instead of three); a material with several colours gets three channels, its faces' R, G and B. A
    material with no area has no channel (no facet lands on it).
    """
    kept = _CHANNEL_FACES.get(tile)
    if kept is None:
        kept = _CHANNEL_FACES[tile] = _split_faces(tile)
    return kept


def _split_faces(tile) -> list:
    if _one_channel(tile):
        return [(int(tile.material_ids[0]), tile.colors[0].astype(np.float64), None)]
    ids, colors = tile.material_ids, tile.colors
    area = np.bincount(ids, weights=tile.face_areas, minlength=tile.n_materials)
    out = []
    for m in np.flatnonzero(area > 0):
        mine = ids == m
        face_colors = colors[mine]
        if (face_colors == face_colors[0]).all():  # one colour: applied after one sum
            out.append((int(m), face_colors[0].astype(np.float64), mine.astype(np.float64)))
        else:
            for c in range(3):
                out.append((int(m), np.eye(3)[c], np.where(mine, colors[:, c], 0.0)))
    return out


def _facet_weigher(tile, facets):
    """→ weight(per_face): a face value (F,) made a facet weight per_face[face_s]·ΔA_s (Ns,) float64 on the host.
    Sampled facets run face by face, so a face's value is repeated over its run (`_face_runs`) rather than
    gathered facet by facet (per-facet tests of the colours cost a GPU host milliseconds an edit; the gathers
    most of a millisecond)."""
    runs, equal = _face_runs(facets.face, len(tile.faces)), _equal_area(facets)
    if runs is None:
        area = facets.area.astype(np.float64)
        return lambda per_face: per_face[facets.face] * area
    if equal is None:
        area = facets.area.astype(np.float64)
        return lambda per_face: np.repeat(per_face, runs) * area
    return lambda per_face: np.repeat(per_face * equal, runs)  # (ΔA times a face's value: one pass over the facets)


def host_weight(weight):
    """A channel's facet weight (`_Queued.channels`) as a host array: an OnDevice's host copy, else itself."""
    return weight.host() if isinstance(weight, OnDevice) else weight


def _channels(tile, facets):
    """Split the facets' weights into scalar channels (`_channel_faces`): → list of (material, rgb multiplier,
    weight (Ns,) float64 ΔA times the face's value, or None: the area), for the materials some facet lies on (a
    bake's device channels, `_sample_facets`, also keep one of area but no facet: its weights are 0)."""
    channels = _channel_faces(tile)
    if channels[0][2] is None:
        return channels
    runs = _face_runs(facets.face, len(tile.faces))
    ids = tile.material_ids
    present = (np.bincount(ids[facets.face], minlength=tile.n_materials) if runs is None
               else np.bincount(ids, weights=runs, minlength=tile.n_materials)) > 0
    weight = _facet_weigher(tile, facets)
    return [(m, mult, weight(per_face)) for m, mult, per_face in channels if present[m]]


def _face_runs(face, n_faces: int):
    """The number of facets of each face (n_faces,) when the facets run face by face (face ids not decreasing,
    as `sample_facets` makes them: its points walk the faces' cumulative area), else None."""
    face = np.asarray(face)
    if len(face) > 1 and not (face[1:] >= face[:-1]).all():
        return None
    return np.diff(np.searchsorted(face, np.arange(n_faces + 1)))


def _fit_lobes(be, fac, facet_weight, bin_normal, bin_weight, count, tolerance, probe_sharpness, coarse_bins=None,
               queue=None):
    """EM for `count` lobes, or the smallest J meeting `tolerance` when count == "auto", on the NDF
    weighted by `facet_weight` (binned: `bin_weight` at `bin_normal`, in the coarse bins `coarse_bins`
    of `lobes.initial_lobes` when known) → (lobes, NDF error or None, queued). With a fixed count,
    `queue(em)` is called with the EM's DeviceLobes before the host waits for them (work on the fitted
    lobes queued behind the EM), and `queued` is what it returned; else None. (With a fixed J the bake
    picks the start on the device instead, `Backend.em_start`; this serves lobes="auto" and a tile that
    no grid direction sees.)"""

    def fit(j, then=None):
        start = lobes_mod.initial_lobes(bin_normal, bin_weight, j, coarse_bins=coarse_bins)
        em = be.ndf_em(fac, start.axes, start.sharpness, start.weight, EM_ITERATIONS, facet_weight, to_host=False)
        queued = then(em) if then is not None else None
        return lobes_mod.from_em(start, em.host()), queued

    if count != "auto":  # the NDF error is what "auto" needs; with a fixed J it is not worth its time
        lob, queued = fit(count, queue)
        return lob, None, queued
    best = None
    for j in AUTO_LOBES:
        lob = fit(j)[0]
        err = lobes_mod.ndf_error(lob, bin_normal, bin_weight, probe_sharpness)
        if best is None or err < best[1]:
            best = (lob, err, None)
        if err <= tolerance or len(lob) < j:  # met, or fewer distinct normals than lobes asked for
            break
    return best


def probe_sharpness(mats) -> float:
    """The sharpest small-scale lobe's SG sharpness (64 with no specular lobe): what lobes="auto" fits the NDF
    for (`lobes.ndf_error`)."""
    # (an anisotropic BRDF's NDF by its narrower axis's sharpness, 2·max(λ, μ))
    spec = [2.0 * float(max(m.ndf_bandwidths)) for m in mats if m.anisotropic]
    spec += [lobe[0] for m in mats if not m.anisotropic for lobe in sg.specular_lobes(m, [[0, 0, 1.0]], [[0, 0, 1.0]])]
    return max([s for s in spec if s is not None], default=64.0)


def _coarse_bins(fine, resolution, coarse=16):
    """The bins of `lobes.initial_lobes` (cube map at `coarse`) holding the fine cube-map bins `fine`
    (at `resolution`), by integer arithmetic when `coarse` divides `resolution` (a fine bin's mean
    normal lies in its bin, so in the coarse bin around it), else None (initial_lobes bins the normals)."""
    if resolution % coarse:
        return None
    f = resolution // coarse
    face, rem = np.divmod(np.asarray(fine, np.int64), resolution * resolution)
    row, col = np.divmod(rem, resolution)
    return face * coarse * coarse + (row // f) * coarse + col // f


def _grouped_moments(sums, data, lob):
    """The moments (U, J + 1) of all of `lob`'s lobes from `sums(data, axes, sharpness)`, which takes
    at most lobes.KERNEL_LOBES lobes a call: one call for few lobes (its result as it comes, possibly
    on the device), else one per group, stitched on the host (each group's last column is the same
    plain sum c)."""
    k = lobes_mod.KERNEL_LOBES
    if len(lob) <= k:
        return sums(data, lob.axes, lob.sharpness)
    parts = [np.asarray(sums(data, lob.axes[a:a + k], lob.sharpness[a:a + k])) for a in range(0, len(lob), k)]
    return np.concatenate([p[:, :-1] for p in parts] + [parts[0][:, -1:]], axis=1)


_GEOMETRY = weakref.WeakKeyDictionary()  # tile → OrderedDict(key → geometry result), most recent last
_GEOMETRY_PER_TILE = 4


def _check_lobes(lobes):
    if isinstance(lobes, str):
        if lobes != "auto":
            raise ValueError(f"lobes must be an integer in [1, {lobes_mod.MAX_LOBES}] or 'auto', got {lobes!r}")
        return lobes
    try:
        j = int(lobes)
    except (TypeError, ValueError):
        j = None
    # True == 1 in Python: without this lobes=True would bake one lobe rather than be refused as the slip it is
    if isinstance(lobes, (bool, np.bool_)) or j is None or j != lobes or not (1 <= j <= lobes_mod.MAX_LOBES):
        raise ValueError(f"lobes must be an integer in [1, {lobes_mod.MAX_LOBES}] or 'auto', got {lobes!r}")
    return j


def bake(tile, materials, method: str = "sg", lobes=8, directions: int = 12, normal_res: int = 128,
         facets: int = 1 << 16, backend="auto", seed: int = 0, route: str = "facets", tolerance: float = 0.02,
         bvndf: bool = False, progress=None, matrix: dict | None = None) -> EffectiveBRDF:
    """Bake a tile and its small-scale BRDFs into an SG effective BRDF (Iwasaki 2012), or with
    method="matrix" by Wu 2011's matrix method (`matrix.MatrixBRDF`; `_bake_matrix`).

    Parameters
    ----------
    tile : SmallScale
    materials : Brdf or list of Brdf, indexed by the tile's material ids (more BRDFs than ids: a
        `TileWarning`; the extra ones reflect nothing).
    method : "sg" (Eq. 15, the SG closure, for rendering) or "sg-exact" (Eq. 10) for `eval`; "matrix": Wu's
        matrix method (the histogram N over `normal_res`'s bins times each material's precomputed M, both
        factored, Eq. 12; lobes, route and tolerance are the SG method's and unused), options in `matrix`;
        "asg": J anisotropic spherical Gaussians (Xu 2013) fitted from the SG EM's lobes (`asg_bake.ASGBRDF`);
        "auto": the SG or the ASG bake, whichever is nearer the exact f̄ of the bake's own facets (`_bake_auto`:
        both bakes, that ground truth and both materials' f̄ tables evaluated on the host: 63–91 ms on an H200 at
        the defaults, where one bake takes 3.4–9.3 ms; 16.5 s against 1.4 s on a 2-core CPU for a height field, the
        truth most of it; `info["method_choice"]` says which and why).
    lobes : J, the number of SG lobes of the NDF (1–128), or "auto": the first J of `AUTO_LOBES` (1–16,
        then 24, 32, 48, 64, 96, 128) whose NDF fit error (`lobes.ndf_error`, seen at the sharpest
        small-scale lobe, on the NDF weighted by what the direction grid sees, as the lobes are fitted)
        is ≤ `tolerance`, else the J of the least error (one EM per J tried); for method="asg" the same
        with the ASG mixture's error (`asg_bake.ndf_error`), one SG EM and ASG fit per J tried. Past 16
        lobes the moment kernels run once per group of 16 and the amplitudes are solved on the host
        (float64), so the bake costs up to about J/16 times the J = 16 bake; a tile whose NDF has sharp
        curved ridges (woven threads) needs ~128 lobes for 35 dB (bench/README.md).
    directions : K, the K×K direction grid (docs/design.md §4); tables are K²×K².
    normal_res : R, the cube map of normal bins (6×R×R).
    facets : Ns; seed : facet-sampling seed.
    route : how the amplitudes' right-hand sides are summed: "facets" (exact facet sums, default)
        or "histogram" (from the binned BVNDF, each bin at its mean normal).
    bvndf : also keep the histogram N in the result (`mat.bvndf.histogram`) for inspection.
    matrix : method="matrix" only: a dict updating `matrix.FACTOR_SETTINGS` (M's octahedral normal_res,
        "auto" by Wu's search or an odd integer; power of M and n_power of N kept; the SVD's oversample,
        power_iterations and seed; cache_dir of M's factors; search; memory_budget).

    Returns an `EffectiveBRDF` that records its `provenance` (the tile, facets, seed: what its ground truth
    is rebuilt from), with per-stage `timings` (seconds, device-synchronised; the host bins the normals
    while the device traces the visibility rays and sums a_v and the EM's facet weights behind them, and
    "visibility" times all of it together, until the weights are back; with a fixed J the EM's start, the
    EM and the moment sums are queued behind the rays too, and the device time they take shows in the
    stage that next waits for the device).
    """
    if method not in (*METHODS, "matrix", *METHOD_BAKES, "auto"):  # (first: a typo is not an anisotropy problem)
        raise ValueError(f"method must be one of {(*METHODS, 'matrix', *METHOD_BAKES, 'auto')}, got {method!r}")
    seed = check_seed(seed)
    if method == "auto":
        return _bake_auto(tile, materials, lobes, directions, normal_res, facets, backend, seed, route, tolerance,
                          bvndf, progress, matrix)
    # Anisotropic small-scale BRDFs: the ASG bake convolves their NDF's ASG, turned by each lobe's facet tangents,
    # with its lobes. The others refuse rather than fit an isotropic average: one isotropic SG per specular lobe
    # cannot hold an anisotropic one, so the result would be wrong by the anisotropy itself.
    if method != "asg":
        refuse_anisotropic(materials, f"method={method!r} cannot hold it (the SG bake fits each specular lobe as "
                                      "one isotropic SG, the matrix method's bins carry no tangent): bake it with "
                                      "method='asg'; wb.ground_truth evaluates it exactly")
    # A measured BRDF: the matrix method's M looks its table up; the SG and ASG bakes convolve with its SG
    # fit (`brdf.sg_lobes`), fitted here so that its time and error are the bake's (`_fit_measured`).
    mats, _, _ = _prepare(tile, materials, anisotropic=method == "asg", measured=True)
    if method == "matrix":
        return _bake_matrix(tile, mats, directions, normal_res, facets, backend, seed, bvndf, progress, matrix)
    if method in METHOD_BAKES:  # "asg": asg_bake.bake_asg (Xu 2013; its lobes fitted from the SG EM's)
        if matrix is not None or route != "facets":
            raise ValueError(f"method={method!r} sums its amplitudes over the facets and takes no matrix= options")
        fits = _fit_measured(mats, get_backend(backend))
        mat = METHOD_BAKES[method](tile, mats, lobes, directions, normal_res, facets, backend, seed, bvndf, progress,
                                   tolerance=tolerance)
        return _record_tolerance(_record_fits(mat, fits), tolerance)
    if matrix is not None:
        raise ValueError(f"matrix= holds the options of method='matrix', not of method={method!r}")
    if route not in ROUTES:
        raise ValueError(f"route must be one of {ROUTES}, got {route!r}")
    count = _check_count(facets)
    j_req = _check_lobes(lobes)
    k = int(directions)
    if k != directions or not (2 <= k <= 32):
        raise ValueError(f"directions must be an integer grid size K in [2, 32], got {directions!r}")
    r = int(normal_res)
    if r != normal_res or not (1 <= r <= 1024):
        raise ValueError(f"normal_res must be an integer in [1, 1024], got {normal_res!r}")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be a number > 0, got {tolerance!r}")
    be = get_backend(backend)
    fits = _fit_measured(mats, be)
    probe = probe_sharpness(mats) if j_req == "auto" else None
    key = (count, int(seed), k, r, j_req, route, float(tolerance) if j_req == "auto" else None, probe, bool(bvndf),
           be.name)
    cache = _GEOMETRY.setdefault(tile, collections.OrderedDict())
    geo = cache.get(key)
    timer = _Timer(be)
    prog = as_progress(progress)
    if geo is None:
        geo = _bake_geometry(tile, be, count, seed, k, r, j_req, route, tolerance, probe, bvndf, timer, prog)
        cache[key] = geo
        while len(cache) > _GEOMETRY_PER_TILE:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    prog.stage("tables", 1)
    t0 = time.perf_counter()
    amps, energy, levels = geo["amplitudes"], geo["energy"], geo["levels"]
    if len(mats) > len(amps):  # materials beyond the tile's ids reflect nothing
        extra = len(mats) - len(amps)
        amps, energy, levels = (None if a is None else np.concatenate([a, np.zeros((extra,) + a.shape[1:], a.dtype)])
                                for a in (amps, energy, levels))
    # The provenance lets the Monte Carlo reference rebuild this material's exact ground truth (truth.truth_of).
    mat = EffectiveBRDF(geo["lobes"], amps, mats, k, method,
                        info={**geo["info"], "backend": be.name, "tile": tile.name}, bvndf=geo["bvndf"],
                        provenance=Provenance(tile, int(seed), count), _energy=energy, _energy_levels=levels)
    timer.timings["tables"] = time.perf_counter() - t0
    mat.timings = dict(timer.timings)
    prog.done()
    return _record_tolerance(_record_fits(mat, fits), tolerance)


# method="auto" keeps the ASG bake only where it is nearer the facets' exact f̄ by more than this: where the two are
# equal to the printed digit (a tile of flat facets, whose lobes are round either way) the SG material, which every
# renderer and the Mitsuba export take, is kept.
AUTO_MARGIN_DB = 0.01


def _bake_auto(tile, materials, lobes, directions, normal_res, facets, backend, seed, route, tolerance, bvndf,
               progress, matrix):
    """method="auto": the SG and the ASG bake of the same facets (same count and seed), each compared with the exact
    f̄ of those facets (`wb.ground_truth` with the bake's facets, seed and grid: what the two lobe families differ
    in, without the facet sampling's error, which they share); the ASG material where its PSNR passes the SG one's
    by AUTO_MARGIN_DB, else the SG one. On the six procedural families under Blinn–Phong 512 and Cook–Torrance 0.2,
    in every case measured the bake nearer that truth was the one nearer an independent 4×-facet truth, or the two
    were within AUTO_MARGIN_DB (bench/README.md). The chosen material's `info["method_choice"]` holds both PSNRs and
    its `timings["method_choice"]` the seconds of the other bake, the truth and the two comparisons. A tile with an
    anisotropic small-scale BRDF takes the ASG bake alone (the SG bake refuses it), and one of Lambertian BRDFs only
    the SG bake alone (the two give the same f̄): its `method_choice` says so and holds no PSNR."""
    if matrix is not None or route != "facets":
        raise ValueError("method='auto' chooses between the SG and ASG bakes, which sum their amplitudes over the "
                         "facets and take no matrix= or route= options")
    kw = dict(lobes=lobes, directions=directions, normal_res=normal_res, facets=facets, backend=backend, seed=seed,
              tolerance=tolerance, bvndf=bvndf, progress=progress)
    t0 = time.perf_counter()
    said, both = [], False
    try:
        # (each bake and the truth check the materials: their warnings are said once, at the caller's line, not
        # three times; also when a step raises)
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            mats, _, _ = _prepare(tile, materials, anisotropic=True, measured=True)
            if any(m.anisotropic for m in mats):
                mat = bake(tile, materials, method="asg", **kw)
                mat.info["method_choice"] = {"chosen": "asg", "why": "an anisotropic small-scale BRDF, which only "
                                                                     "the ASG method holds"}
                return mat
            if all(type(m) is Lambert for m in mats):
                # (both bakes solve the diffuse term's amplitudes exactly: their f̄ agree to float32 rounding, measured
                # within 6e-8 of the peak on the six procedural families, so nothing is there to choose between)
                mat = bake(tile, materials, method="sg", **kw)
                mat.info["method_choice"] = {"chosen": "sg", "why": "Lambertian small-scale BRDFs only, whose f̄ "
                                                                    "both bakes give alike"}
                return mat
            both = True
            baked = {name: bake(tile, materials, method=name, **kw) for name in ("sg", "asg")}
            truth = ground_truth(tile, materials, facets=facets, directions=directions, backend=backend, seed=seed,
                                 progress=progress)
            psnr = {name: float(compare(m, truth)["psnr"]) for name, m in baked.items()}
    finally:
        for warning in {(w.category, str(w.message)): w for w in said}.values():
            if not (both and str(warning.message).startswith(AUTO_LOBES_SAID)):  # (said below for the one kept)
                warnings.warn(warning.message, stacklevel=3)
    chosen = "asg" if psnr["asg"] > psnr["sg"] + AUTO_MARGIN_DB else "sg"
    mat = baked[chosen]
    if _tolerance_missed(mat):
        warnings.warn(_tolerance_missed(mat), stacklevel=3)
    mat.info["method_choice"] = {
        "chosen": chosen, "psnr_sg": psnr["sg"], "psnr_asg": psnr["asg"],
        "why": f"PSNR of f̄ against the exact f̄ of the bake's {_check_count(facets)} facets: SG {psnr['sg']:.2f} dB, "
               f"ASG {psnr['asg']:.2f} dB"}
    mat.timings["method_choice"] = time.perf_counter() - t0 - sum(mat.timings.values())
    return mat


def _fit_measured(mats, backend) -> tuple[dict, float]:
    """The SG fits of the measured BRDFs among `mats` (`MeasuredBRDF.sg_fit` in `backend`'s kernels, kept by each
    table), by material index, and the seconds this call spent fitting (0 where every table had its fit
    already)."""
    t0 = time.perf_counter()
    fits = {i: m.sg_fit(backend) for i, m in enumerate(mats) if getattr(m, "kind", None) == MEASURED}
    return fits, time.perf_counter() - t0


AUTO_LOBES_SAID = "lobes='auto' found no J"  # (the start of _tolerance_missed's message)


def _record_tolerance(mat, tolerance: float):
    """lobes="auto": whether its J met the NDF fit tolerance, in `info["ndf_tolerance_met"]` beside the tolerance;
    where no J of AUTO_LOBES did (the bake keeps the J of the least error), a warning says so at the caller's line."""
    err = mat.info.get("ndf_error")
    if mat.info.get("lobes_requested") != "auto" or err is None:
        return mat
    mat.info["ndf_tolerance"], mat.info["ndf_tolerance_met"] = float(tolerance), bool(err <= tolerance)
    if _tolerance_missed(mat):
        warnings.warn(_tolerance_missed(mat), stacklevel=3)
    return mat


def _tolerance_missed(mat) -> str | None:
    """The warning of a lobes="auto" bake whose J met no tolerance (`_record_tolerance`), else None."""
    if mat.info.get("ndf_tolerance_met", True):
        return None
    return (f"{AUTO_LOBES_SAID} (of bake.AUTO_LOBES, up to as many as the tile has distinct normals) whose NDF fit "
            f"error meets the tolerance {mat.info['ndf_tolerance']:g}: kept {mat.info['lobes']} lobes, of the least "
            f"error ({mat.info['ndf_error']:.3g} at sharpness {mat.info['ndf_probe_sharpness']:g}); give a larger "
            "tolerance or a fixed J")


def _record_fits(mat, fitted: tuple[dict, float]):
    """The bake's result with its measured materials' SG fits in `info["sg_fit"]` (per material index: the
    fit's relative L2 error and its lobes' parameters, `SGFit.to_dict`) and the time the bake spent fitting in
    `timings["sg_fit"]`."""
    fits, seconds = fitted
    if fits:
        mat.info["sg_fit"] = {str(i): f.to_dict() for i, f in fits.items()}
        mat.timings["sg_fit"] = seconds
    return mat


@dataclass(eq=False)
class _Queued:
    """What the bake has queued on the device after the rays (results stay there until read): the
    facets, their visibility over the direction `grid`, a_v, the EM's facet weights, the facets' colour
    channels, the unordered direction pairs (iu, ou) the moments are summed over and, with a fixed J, the
    EM's start, its lobes and the moment sums queued behind it. Kept here until the bake returns, so that
    nothing the device has queued is released mid-bake."""
    fac: Facets
    bins: np.ndarray
    normal: np.ndarray
    grid: np.ndarray
    vis: object = None
    a_v: object = None
    em_weight: object = None
    channels: list = field(default_factory=list)  # (material, rgb multiplier, facet weight: see _sample_facets)
    weights: list = field(default_factory=list)  # the channels' weights on the device (None: the area)
    face_bins: tuple = None  # `_face_bins`: the bins of a flat tile's faces, or None
    iu: np.ndarray = None
    ou: np.ndarray = None
    em_start: object = None
    em: object = None
    queued: tuple = None


def _bake_geometry(tile, be, count, seed, k, r, j_req, route, tolerance, probe, keep_hist, timer, prog):
    """The geometry part of a bake, stage by stage. The device is kept busy by queueing: the rays, then
    a_v and the EM's facet weights behind them, and (fixed J) the EM and the moment sums behind those,
    while the host bins the normals; the host waits only where it needs a result. "visibility" times
    all that queueing and binning, until the facet weights are back (Warp's CPU device runs each call
    before it returns)."""
    q = _sample_facets(tile, be, count, seed, dirs.frozen_grid(k), r, timer, prog)
    t0 = time.perf_counter()
    _queue_visibility(tile, be, q, prog)
    bv, facet_bin = _queue_em_and_bin(be, q, r, j_req, route)
    weight_host = q.em_weight.host()  # (waits for the rays and the weights, not for what is queued behind them)
    timer.timings["visibility"] = timer.timings.get("visibility", 0.0) + time.perf_counter() - t0
    hists = _histograms(be, q, bv, facet_bin, route, keep_hist, timer, prog)
    lob, ndf_err, queued, seen_normal, seen_weight = _fit_ndf(be, q, bv, facet_bin, weight_host, r, j_req,
                                                             route, tolerance, probe, timer, prog)
    amps, energy, levels, cond = _amplitudes(tile, be, q, bv, hists, lob, queued, seen_normal, seen_weight, route,
                                             timer, prog)
    info = {"facets": count, "seed": int(seed), "normal_res": r, "route": route, "lobes": len(lob),
            "lobes_requested": j_req, "ndf_error": ndf_err, "ndf_probe_sharpness": probe,
            "em_iterations": lob.iterations, "gram_condition": cond, "nonempty_bins": int(len(bv.bins)),
            "channels": len(q.channels)}
    return {"lobes": lob, "amplitudes": amps, "energy": energy, "levels": levels, "bvndf": bv, "info": info}


def _sample_facets(tile, be, count, seed, grid, r, timer, prog, weights_on_device=True) -> _Queued:
    """Facets, each one's normal bin and the colour channels. What the host needs of the facets is read back now,
    before the rays queue behind them (read later, it would wait for the rays, and the host's work would not
    overlap them): a tile whose bins are summed over its faces (`_face_bins`) reads the facets' faces, any other
    their normals. With `weights_on_device` the channels' facet weights are made on the device now
    (`facet_weight_by_face`, `q.weights`, their face values uploaded ahead of the rays: an upload waits for the
    work queued before it, bench/README.md) and `q.channels` holds them as OnDevice (`host_weight`); else
    `q.channels` holds host arrays (`_channels`)."""
    prog.stage(f"facets ({count})", 1)
    fac = timer("facets", be.sample_facets, tile, count, seed)
    bins = timer("bvndf", be.normal_bins, fac, r)
    q = _Queued(fac, bins, None, grid)
    q.face_bins = _face_bins(tile, fac, bins)
    if q.face_bins is None:  # the bins are summed facet by facet: the facets' normals, read now
        q.normal = fac.normal
    if weights_on_device:
        # Each channel's facet weights made on the device from its face values (facet_weight_by_face): its
        # host array (the histogram route, J past the kernels) only when host code asks for it.
        channels = _channel_faces(tile)
        weigher = functools.cache(lambda: _facet_weigher(tile, fac))
        q.weights = [None if per_face is None else
                     be.facet_weight_by_face(fac, per_face, lambda per_face=per_face: weigher()(per_face))
                     for _, _, per_face in channels]
        q.channels = [(m, mult, w) for (m, mult, _), w in zip(channels, q.weights)]
    else:
        q.channels = _channels(tile, fac)
    return q


def _queue_visibility(tile, be, q: _Queued, prog) -> None:
    """Queue the rays, a_v and the EM's facet weights (all left on the device).

    The lobes fit the NDF as the direction grid sees it: each facet weighs its projected area averaged
    over the grid (reference.visible_weights), so no lobe is spent on normals that no direction sees
    (against 2^18-facet ground truths the woven tile gains 2–3 dB at J = 16; the other families move by
    at most 0.2 dB: bench/README.md)."""
    prog.stage(f"visibility ({len(q.grid)} dirs)", 1)
    q.vis = be.visibility(tile, q.fac, q.grid)
    q.a_v = be.visible_area(q.fac, q.vis, to_host=False)
    q.em_weight = be.visible_weights(q.fac, q.vis, to_host=False)  # float32 OnDevice, what EM weighs
    q.iu, q.ou = dirs.unordered_pairs(len(q.grid))


def _face_bins(tile, facets, bins):
    """For a tile whose facets take their face's normal (no vertex normals), run face by face, share one area
    and are at least FACETS_PER_FACE a face on average: (the normal bin of each face that has facets, those
    faces' facet counts, their first facets, their normals as the facets have them), each face's facets all in
    its bin (checked); else None. The bins' sums then run over the faces, not the facets (`_occupied_bins`,
    `_bin_normals`, `_fit_ndf`), and the facets' normals are not read back."""
    if (tile.vertex_normals is not None or len(tile.faces) * FACETS_PER_FACE > len(bins)
            or _equal_area(facets) is None):
        return None
    runs = _face_runs(facets.face, len(tile.faces))
    if runs is None:
        return None
    counts = runs[runs > 0]
    starts = np.cumsum(counts) - counts
    face_bin = bins[starts]
    if not np.array_equal(np.repeat(face_bin, counts), bins):
        return None
    # (a facet of a face without vertex normals takes the face's normal as the kernels hold it, in float32)
    return face_bin, counts, starts, tile.face_normals[runs > 0].astype(np.float32)


def _occupied_bins(q: _Queued, r) -> tuple:
    """(the facets' area in each non-empty fine normal bin, those bins (ascending)): what the EM's start needs
    to know before it is queued, the cheap part of `_bin_normals`."""
    area = _equal_area(q.fac)
    if q.face_bins is not None:  # a flat tile: counted over its faces
        face_bin, counts = q.face_bins[:2]
        occupied, slot = np.unique(face_bin, return_inverse=True)
        return np.bincount(slot, weights=counts) * area, occupied
    if area is None:
        mass = np.bincount(q.bins, weights=q.fac.area.astype(np.float64), minlength=6 * r * r)
    else:  # sampled facets share one ΔA: a count (no weights to convert and read) times it
        mass = np.bincount(q.bins, minlength=6 * r * r) * area
    occupied = np.flatnonzero(mass > 0)
    return mass[occupied], occupied


def _equal_area(facets):
    """ΔA when every facet has the same area (as sampled facets do: `device.equal_areas`), else None."""
    area = facets.area
    if not len(area) or not (area == area[0]).all():
        return None
    return float(area[0])


def _bin_normals(q: _Queued, r, mass=None, occupied=None) -> tuple:
    """→ (the Bvndf's non-empty bins with their area Γ and area-weighted mean normal, each facet's slot
    among them), from `_occupied_bins` (given, or made here). By counting, no sort; what the host needs
    after the rays that does not depend on them."""
    if mass is None:
        mass, occupied = _occupied_bins(q, r)
    equal = _equal_area(q.fac)
    if q.face_bins is not None:  # a flat tile: each face's facets have its normal, Σ over the faces
        face_bin, counts, _, face_normal = q.face_bins
        face_slot = np.searchsorted(occupied, face_bin).astype(np.int32)
        facet_bin = np.repeat(face_slot, counts)
        normal = np.asarray(face_normal, np.float64) * counts[:, None]
        mean = np.stack([np.bincount(face_slot, weights=normal[:, c], minlength=len(occupied)) for c in range(3)]).T
        mean = np.ascontiguousarray(mean / np.maximum(np.sqrt((mean * mean).sum(1)), 1e-300)[:, None])
        return Bvndf(r, occupied.astype(np.int32), mean, mass, None), facet_bin
    slot = np.full(6 * r * r, -1, np.int32)
    slot[occupied] = np.arange(len(occupied))
    facet_bin = slot[q.bins]
    if equal is not None and equal > 0:
        # Every facet's bin is occupied: the per-bin sums as one sparse (L, Ns) × (Ns, 3) product in float64,
        # a third of the time of three weighted bincounts, the same sums; equal areas weigh nothing (the mean
        # is normalised below).
        n = len(facet_bin)
        member = scipy.sparse.csc_matrix((np.ones(n), facet_bin, np.arange(n + 1)), shape=(len(occupied), n))
        mean = member @ np.asarray(q.normal, np.float64)  # (L, 3)
    else:  # (3, L): numpy's loops run along the bins (3 innermost: ~4× slower)
        area = q.fac.area.astype(np.float64)
        mean = np.stack([np.bincount(facet_bin, weights=area * q.normal[:, c], minlength=len(occupied))
                         for c in range(3)]).T
    mean = np.ascontiguousarray(mean / np.maximum(np.sqrt((mean * mean).sum(1)), 1e-300)[:, None])
    return Bvndf(r, occupied.astype(np.int32), mean, mass, None), facet_bin


def _queue_moments(be, q: _Queued, em, route):
    """With the facet route and a J the kernels hold, the moment sums are queued behind the EM from the
    lobes it left on the device: the host then waits for the EM alone, and sets up the Gram system while
    the device sums. → (J, per-channel device moments), or None."""
    if route != "facets" or em.count > lobes_mod.KERNEL_LOBES:
        return None
    return em.count, [be.lobe_moments(q.fac, q.vis, w, em, None, q.iu, q.ou, to_host=False) for w in q.weights]


def _queue_em_and_bin(be, q: _Queued, r, j_req, route) -> tuple:
    """`_bin_normals`, and with a fixed J the EM and its moment sums queued behind the rays first
    (`_queue_fixed_j_em`), the binning done while the device works through them. → _bin_normals'."""
    if j_req == "auto":
        return _bin_normals(q, r)
    mass, occupied = _occupied_bins(q, r)
    binned = []
    _queue_fixed_j_em(be, q, occupied, r, j_req, route,
                      meanwhile=lambda: binned.append(_bin_normals(q, r, mass, occupied)))
    return binned[0]


def _queue_fixed_j_em(be, q: _Queued, occupied, r, j_req, route, meanwhile=None) -> None:
    """With a fixed J the EM's start (lobes.initial_lobes over the facets, in their coarse bins) is picked on
    the device, so the EM and the moment sums are queued behind the rays before the host has read anything:
    the device goes from the rays to the EM without waiting for the host. `meanwhile()` (host work: the
    binning) runs before the host first waits on the device (an EM that looks at its stop flag waits for
    the rays), else once the moments are queued. No more lobes than the facets' coarse bins (the pyramid's 5 at
    J = 8): a slot the start leaves dead would cost EM its E-step and the moments a second sum for the live
    lobes (`occupied`: the non-empty fine bins). Sets q.em_start, q.em (the EM's DeviceLobes) and q.queued
    (the moments)."""
    coarse = _coarse_bins(occupied, r)
    j_dev = j_req if coarse is None else min(j_req, int(np.count_nonzero(np.bincount(coarse))))
    q.em_start = be.em_start(q.fac, q.em_weight, j_dev)
    meanwhile = once(meanwhile or (lambda: None))
    q.em = be.ndf_em(q.fac, q.em_start, None, None, EM_ITERATIONS, q.em_weight, to_host=False, meanwhile=meanwhile)
    q.queued = _queue_moments(be, q, q.em, route)
    meanwhile()


def _histograms(be, q: _Queued, bv, facet_bin, route, keep_hist, timer, prog):
    """The BVNDF histogram N per channel for the histogram route (and the plain one for `bvndf=True`),
    else None."""
    prog.stage(f"BVNDF ({6 * bv.resolution ** 2} normal bins)", 1)
    if not (route == "histogram" or keep_hist):
        return None
    area = q.fac.area.astype(np.float64)
    nbytes = len(q.iu) * len(bv.bins) * 4 * (len(q.channels) + 1)
    if nbytes > HISTOGRAM_BYTES:
        raise ValueError(
            f"the BVNDF histogram would take {nbytes / 2**30:.1f} GiB ({len(q.iu)} direction pairs × "
            f"{len(bv.bins)} non-empty normal bins); use route='facets', fewer directions or a smaller normal_res")
    order = np.argsort(facet_bin, kind="stable").astype(np.int32)
    start = np.searchsorted(facet_bin[order], np.arange(len(bv.bins) + 1)).astype(np.int32)
    hists = [timer("bvndf", be.bvndf_histogram, q.fac, q.vis, order, start,
                   (area if w is None else host_weight(w)).astype(np.float32), q.iu, q.ou)
             for _, _, w in q.channels]
    if keep_hist:
        bv.histogram = timer("bvndf", be.bvndf_histogram, q.fac, q.vis, order, start, area.astype(np.float32),
                             q.iu, q.ou)
    return hists


def _fit_ndf(be, q: _Queued, bv, facet_bin, weight_host, r, j_req, route, tolerance, probe, timer, prog):
    """The lobes: the fixed-J EM already queued (`q.em`), or an EM per J tried ("auto"), on the NDF as
    the grid sees it (the bins keep their area-weighted mean normals: within a bin at R = 128 the
    weighting barely moves them). "ndf_fit" ends when the lobes are on the host (the queueing of the
    sums counts in it; not synchronised further, so that the device sums while the host goes on).
    → (lobes, NDF fit error or None, queued moments or None, the seen bins' normals and weights)."""
    prog.stage("NDF fit (spherical EM)", 1)
    t0 = time.perf_counter()
    em_weight, fixed_j = q.em_weight, q.em is not None
    if q.face_bins is not None:  # a flat tile: summed over each face's run of facets, then per bin
        starts = q.face_bins[2]
        per_face = np.add.reduceat(np.asarray(weight_host, np.float64), starts)
        bin_weight = np.bincount(facet_bin[starts], weights=per_face, minlength=len(bv.bins))
    else:
        bin_weight = np.bincount(facet_bin, weights=weight_host, minlength=len(bv.bins))  # (summed in float64)
    if not bin_weight.any():  # no grid direction sees the tile at all: fall back on the bare NDF
        bin_weight, em_weight, fixed_j = bv.area, None, False
    seen = bin_weight > 0
    if seen.all():  # (as a rule: no gathers then)
        seen_normal, seen_weight = bv.normal, bin_weight
    else:
        seen_normal, seen_weight = bv.normal[seen], bin_weight[seen]
    if fixed_j:
        lob, ndf_err, queued = lobes_mod.from_em(q.em_start, q.em.host()), None, q.queued
    else:
        lob, ndf_err, queued = _fit_lobes(be, q.fac, em_weight, seen_normal, seen_weight, j_req, tolerance, probe,
                                          _coarse_bins(bv.bins[seen], r),
                                          lambda em: _queue_moments(be, q, em, route))
    timer.timings["ndf_fit"] = timer.timings.get("ndf_fit", 0.0) + time.perf_counter() - t0
    return lob, ndf_err, queued, seen_normal, seen_weight


def _amplitudes(tile, be, q: _Queued, bv, hists, lob, queued, seen_normal, seen_weight, route, timer, prog):
    """Per material, the (K², K², J, 3) amplitude table and (K², K², 3) energies, and the Gram system's
    condition number. "amplitudes" times the whole
    stage: the moment sums are queued first, and the host solves for the Gram system's rows while the
    device sums; then the solves and the tables (μ stays on the device for them)."""
    prog.stage(f"amplitudes ({len(lob)} lobes, {len(q.channels)} channel(s))", len(q.channels))
    t0 = time.perf_counter()
    nd = len(q.grid)
    few = len(lob) <= lobes_mod.KERNEL_LOBES  # else the lobes go through the kernels in groups
    if queued is not None and queued[0] == len(lob):  # (else a lobe died in EM: sum for the live ones)
        moments = queued[1]
    elif route == "facets":  # with few lobes the moments stay on the device for the solve
        def sums(w, ax, eta):
            return be.lobe_moments(q.fac, q.vis, w, ax, eta, q.iu, q.ou, to_host=not few)
        moments = [_grouped_moments(sums, w, lob) for w in q.weights]
    else:
        def sums(hist, ax, eta):
            return be.histogram_moments(hist, bv.normal, q.grid, ax, eta, q.iu, q.ou)
        moments = [_grouped_moments(sums, hist, lob) for hist in hists]
    rows, integrals, _, cond = lobes_mod.amplitude_system(lob, seen_normal, seen_weight)
    pi, po = dirs.all_pairs(nd)
    solved = []
    for (m, mult, _), mom in zip(q.channels, moments):
        if few:
            mu = be.solve_amplitudes(mom, q.a_v, rows, integrals, pi, po, nd, to_host=False)
        else:  # past the solve kernel's registers: float64 on the host
            mu = lobes_mod.solve_amplitudes(mom, q.a_v.host(), pi, po, nd, rows, integrals)
        solved.append((m, mult, mu))
        prog.advance()
    # Per material, on the device: the channels' amplitudes times their colours (BRDF-independent), their
    # energies Σ_j μ_j ∫G_j (from μ: the tables need not be summed again) and the energies prefiltered for the
    # renderer's broad environment lobes (`device_levels`).
    n_mat, n_pairs = tile.n_materials, nd * nd
    amps, energy, levels = be.material_tables([[(mu, mult) for mm, mult, mu in solved if mm == m]
                                               for m in range(n_mat)], integrals, n_pairs,
                                              device_levels(be, math.isqrt(nd)))
    if not np.isfinite(energy).all():  # (one pass: a reduction over the last axis of 3 took ~0.3 ms)
        bad = int((~np.isfinite(energy).all(axis=-1)).sum())
        raise FloatingPointError(f"the amplitude solve gave non-finite values in {bad} direction pairs")
    bv.a_v = np.asarray(q.a_v.host(), np.float64)
    be.synchronize()
    timer.timings["amplitudes"] = timer.timings.get("amplitudes", 0.0) + time.perf_counter() - t0
    return (amps.reshape(n_mat, nd, nd, len(lob), 3), energy.reshape(n_mat, nd, nd, 3),
            None if levels is None else levels.reshape(n_mat, -1, nd, nd, 3), cond)


# ---------------------------------------------------------------------------------------------------
# method="matrix": Wu 2011 (warp_biscale.matrix)
# ---------------------------------------------------------------------------------------------------


def _check_grid(directions, normal_res) -> tuple[int, int]:
    k = int(directions) if isinstance(directions, (int, np.integer)) and not isinstance(directions, bool) else None
    if k is None or not (2 <= k <= 32):
        raise ValueError(f"directions must be an integer grid size K in [2, 32], got {directions!r}")
    r = int(normal_res) if isinstance(normal_res, (int, np.integer)) and not isinstance(normal_res, bool) else None
    if r is None or not (1 <= r <= 1024):
        raise ValueError(f"normal_res must be an integer in [1, 1024], got {normal_res!r}")
    return k, r


def _bake_matrix(tile, mats, directions, normal_res, facets, backend, seed, keep_hist, progress, options):
    """Wu's matrix method through the bake's own stages: facets and their bins, visibility and a_v, the
    histogram N per colour channel (the `bvndf` kernels), N's factors (random-projection SVD in float64,
    N_POWER of its power); then per material M's factors (`matrix.material_factors`: cached on disk, else M
    by the `matrix` kernels and its SVD) and f̄ by Eq. 12 (`matrix.matrix_tables`). The geometry part (up to
    N's factors) is cached per tile as the SG bake's is, so baking the tile again with other BRDFs costs M's
    factors (cached) and Eq. 12 alone (`timings` then holds only "m_factors" and "tables")."""
    count = _check_count(facets)
    k, r = _check_grid(directions, normal_res)
    settings = matrix_mod.check_factor_settings(options)
    be = get_backend(backend)
    svd = (settings["n_power"], settings["oversample"], settings["power_iterations"], settings["seed"])
    key = ("matrix", count, int(seed), k, r, svd, bool(keep_hist), be.name)
    cache = _GEOMETRY.setdefault(tile, collections.OrderedDict())
    geo = cache.get(key)
    timer = _Timer(be)
    prog = as_progress(progress)
    if geo is None:
        geo = _matrix_geometry(tile, be, count, int(seed), k, r, settings, keep_hist, timer, prog)
        cache[key] = geo
        while len(cache) > _GEOMETRY_PER_TILE:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    used = {m for m, _, _ in geo["channels"]}
    prog.stage(f"M factors ({len(used)} material(s))", 1)
    t0 = time.perf_counter()
    factors = matrix_mod.factors_for(mats, used, k, settings, be)
    timer.timings["m_factors"] = time.perf_counter() - t0
    prog.stage("tables (Eq. 12)", 1)
    t0 = time.perf_counter()
    bv = geo["bvndf"]
    tables = matrix_mod.matrix_tables(geo["channels"], bv.normal, factors, bv.a_v, n_materials=len(mats))
    timer.timings["tables"] = time.perf_counter() - t0
    prog.done()
    info = {**geo["info"], "backend": be.name, "tile": tile.name}
    return matrix_mod.MatrixBRDF.from_bake(tables, mats, k, bv, geo["channels"], factors, settings,
                                           dict(timer.timings), info, Provenance(tile, int(seed), count), be)


def _matrix_geometry(tile, be, count, seed, k, r, settings, keep_hist, timer, prog) -> dict:
    """The part of a matrix bake that depends on the geometry alone: → {"bvndf", "channels" [(material,
    rgb multiplier, N's MatrixFactors)], "info"}; stages "facets", "visibility", "bvndf", "n_factors"."""
    q = _sample_facets(tile, be, count, seed, dirs.frozen_grid(k), r, timer, prog, weights_on_device=False)
    prog.stage(f"visibility ({len(q.grid)} dirs)", 1)
    t0 = time.perf_counter()
    q.vis = be.visibility(tile, q.fac, q.grid)
    q.a_v = be.visible_area(q.fac, q.vis, to_host=False)
    q.iu, q.ou = dirs.unordered_pairs(len(q.grid))
    bv, facet_bin = _bin_normals(q, r)
    bv.a_v = np.asarray(q.a_v.host(), np.float64)
    timer.timings["visibility"] = timer.timings.get("visibility", 0.0) + time.perf_counter() - t0
    nbytes = len(q.iu) * len(bv.bins) * 4 * (len(q.channels) + 1)  # (as _histograms counts it)
    if nbytes > HISTOGRAM_BYTES:
        raise ValueError(f"the matrix method's histogram N would take {nbytes / 2**30:.1f} GiB ({len(q.iu)} direction "
                         f"pairs × {len(bv.bins)} non-empty normal bins): use fewer directions or a smaller normal_res")
    hists = _histograms(be, q, bv, facet_bin, "histogram", keep_hist, timer, prog)
    prog.stage(f"N factors ({len(hists)} channel(s))", 1)
    t0 = time.perf_counter()
    omega = bv.solid_angle
    n_factors = [matrix_mod.bvndf_factors(h, omega, power=settings["n_power"], oversample=settings["oversample"],
                                          power_iterations=settings["power_iterations"], seed=settings["seed"])
                 for h in hists]
    timer.timings["n_factors"] = time.perf_counter() - t0
    channels = [(m, mult, nf) for (m, mult, _), nf in zip(q.channels, n_factors)]
    info = {"facets": count, "seed": seed, "normal_res": r, "nonempty_bins": int(len(bv.bins)),
            "channels": len(channels), "pairs": int(len(q.iu)),
            "n_ranks": [nf.rank for nf in n_factors], "n_power_kept": [float(nf.power_kept) for nf in n_factors],
            "geometry_timings": dict(timer.timings)}
    return {"bvndf": bv, "channels": channels, "info": info}
