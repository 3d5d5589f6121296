"""Lit-sphere image-based materials (seed 004): a material as a few images of a lit unit sphere.

    ls = wb.LitSphere.from_material(wb.BlinnPhong(0.5, 40, kd=0.4))          # angles 0°, 45°, 90°, 135°
    ls = wb.LitSphere.from_material(baked, tolerance=0.02)                    # the fewest angles meeting 2 %
    wb.render(wb.Scene(mesh, [ls], camera, lights=[...]), method="litsphere")
    ls.save("gold.litsphere"); wb.LitSphere.load("gold.litsphere")

**The representation.** Image a of a material is the unit sphere seen along −Z by a distant viewer
(the view direction v = +Z at every point) lit by one ideal directional light of unit irradiance from
l(φa) = (sin φa, 0, cos φa) — in the plane Y = 0 at polar angle φa from the view axis. Texel (row, col)
of an R×R image is the sphere point with x = 2(col + ½)/R − 1, y = 1 − 2(row + ½)/R (row 0 at the top)
and holds the outgoing radiance f(n, l, v)(n·l)⁺ there. The texels are the material's own float64
evaluation (`Brdf.eval`, `EffectiveBRDF.eval`), exact, so that what a lit-sphere render loses is the
method's alone. Texels outside the disc hold the rim's value (the normal clamped just inside it), so a
filtered lookup near the silhouette never blends in black — the artefact the paper shrinks the normal
by 0.995 against. That shrink moves every lookup inwards (on a 256² diffuse sphere 0.5 % of the albedo
on average and 4 % near the rim, against 0.01 % and 0.6 % without), so here the normal is used as it is
(render option shrink=1) and the paper's SHRINK is an option.

**The shader** (seed 004 Eq. 1–4, `reference_shade`, kernels/litsphere.py, cl/litsphere.cl). An isotropic
BRDF depends on n, l and v only through their relative geometry, so each light is brought into the
images' frame: z = v (the paper: the camera axis; here by default the pixel's own view direction,
`view="pixel"`, which removes the distant-viewer error of a perspective camera; `view="camera"` is the
paper's), x along l's part across z (the rotation by −γ about the view axis), y = z × x. Then
φ = ∠(l, v); the images at φ1 ≤ φ ≤ φ2 bracket it, t = (φ − φ1)/(φ2 − φ1), and the normal n' in that
frame is turned about y by k·(φi − φ) before the lookup in image i (a turn by φi − φ keeps n·l, exact for
a diffuse surface; by half of it the half vector lands on image i's half vector, right for a highlight),
with k = ½ + sin(αh)/2 and αh the angle between the half vector and n' projected on the XZ plane
(Eq. 3). A sphere made from a material keeps its diffuse term's share apart and turns it by k = 1, so
a diffuse term is exact up to texture resolution; where the turned normal leaves the visible half, the
diffuse share is read at the rim point with the same n·l (`rim_point`), exact for a Lambertian term.
Past the last image (or before the first) only that image is read, with k = ¾. The lookup is
trilinear: a mip pyramid (2×2 box averages) and a level from the normal's change to the neighbouring
pixels. A light below the surface's horizon (n·l ≤ 0), or a normal facing away from the viewer (n·v ≤ 0,
an interpolated normal at a silhouette), adds nothing, as the BRDF itself says — guards the paper lacks
(its turned or projected normal can land in the lit half of an image).

**Lights.** Each point or directional light adds E·s·image(…) with E its irradiance at the point and s
its visible share from the shadow rays (`backend.trace_shadows`, as the SG renderer). The environment is
`render.environment_lights(environment, count)`: `count` directional lights over a Fibonacci sphere, each carrying the
radiance of its cell (the prefiltered map of the map without its compact sources, at the cell's width) times the
cell's solid angle, then those sources (a sun) as lights of their own, all shadowed by rays as any light.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field

import numpy as np

from . import images as images_mod
from . import sg
from .brdf import Brdf, Lambert, pack_materials
from .effective import EffectiveBRDF
from .io import write_error
from .measured import MeasuredBRDF
from .model import BACKENDS
from .svbrdf import Textured

__all__ = ["LitSphere", "PAPER_ANGLES", "METAL_ANGLES", "reference_shade", "pack_spheres"]

PAPER_ANGLES = (0.0, 45.0, 90.0, 135.0)  # the paper's set for plastics
METAL_ANGLES = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0)  # its set for metals and colour-shifting materials
RESOLUTION = 512  # the paper's "suitable for general use"; it suggests 1024 for high definition
RESOLUTION_MAX = 4096
SHRINK = 0.995  # the paper's normal shrink against filtering across the silhouette (render option shrink)
RIM = 0.9995  # texels at or past this radius hold the value here (the rim, filled outward)
K_OUTSIDE = 0.75  # the rotation coefficient past the last image (paper §3)
ENV_LIGHTS = 64  # directional lights standing for the environment
MIN_LEVEL_RES = 4  # the smallest mip level
TEST_ANGLES = tuple(np.arange(5.0, 180.0, 10.0))  # the lights interpolation_error judges a sphere under
ERROR_RESOLUTION = 256  # its default grid: texel-level error shows at any grid off the texel centres
# Light-angle counts tried by from_material(tolerance=…): n angles spread evenly over [0°, 180°).
TOLERANCE_COUNTS = (2, 3, 4, 6, 8, 12, 16, 24)
FORMAT = "warp_biscale.litsphere"
VERSION = 1
HEADER = "litsphere.json"  # a saved folder's header; its images are named as _IMAGE_NAME matches
_IMAGE_NAME = re.compile(r"(phi|diffuse)_\d{3}\.\d{5}\.exr")


# ---------------------------------------------------------------------------------------------
# Texel geometry and the material's exact response


def texel_normals(resolution: int) -> np.ndarray:
    """(R, R, 3) float64 unit normals of the texel centres (row 0 at the top, y up, x right, v = +Z);
    texels at or past radius RIM hold the normal at that radius in their direction."""
    c = 2 * (np.arange(resolution) + 0.5) / resolution - 1
    x, y = np.meshgrid(c, -c)
    r = np.hypot(x, y)
    scale = np.where(r > RIM, RIM / np.maximum(r, 1e-300), 1.0)
    x, y = x * scale, y * scale
    z = np.sqrt(np.maximum(1 - x * x - y * y, 0.0))
    return np.stack([x, y, z], -1)


def sphere_tangents(n: np.ndarray) -> np.ndarray:
    """Unit tangents of the sphere at normals n: the direction of increasing longitude about +Y, as
    `Mesh.sphere`'s UVs give (so a baked anisotropic tile lies on the lit sphere as on a rendered
    sphere); +X at the poles."""
    t = np.stack([n[..., 2], np.zeros_like(n[..., 0]), -n[..., 0]], -1)
    length = np.linalg.norm(t, axis=-1, keepdims=True)
    return np.where(length > 1e-9, t / np.maximum(length, 1e-300), np.array([1.0, 0.0, 0.0]))


def material_response(material, n: np.ndarray, light: np.ndarray, view: np.ndarray, tangent=None) -> np.ndarray:
    """(N, 3) float64 radiance f(n, l, v)(n·l)⁺ of `material` under unit irradiance from `light`, seen
    from `view` (unit vectors, (N, 3) each): an analytic `Brdf` by its eval, an `EffectiveBRDF` by its
    eval in the frame of `tangent` (unit, ⟂ n; default the sphere's, `sphere_tangents`) — its tables hold
    the cosine already."""
    n, light, view = (np.asarray(a, np.float64).reshape(-1, 3) for a in (n, light, view))
    cos_l = np.einsum("ij,ij->i", n, light)
    if isinstance(material, EffectiveBRDF):
        t = sphere_tangents(n) if tangent is None else np.asarray(tangent, np.float64).reshape(-1, 3)
        b = np.cross(n, t)

        def local(d):
            return np.stack([np.einsum("ij,ij->i", d, t), np.einsum("ij,ij->i", d, b),
                             np.einsum("ij,ij->i", d, n)], 1)

        wi, wo = local(light), local(view)
        out = np.zeros((len(n), 3))
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        if ok.any():
            out[ok] = material.eval(wi[ok], wo[ok])
        return np.maximum(out, 0.0)
    if isinstance(material, Brdf):
        if material.anisotropic:
            if tangent is None:  # a lit sphere holds one value per normal, for any tangent a mesh has there
                raise ValueError(f"{type(material).__name__} is anisotropic: a lit sphere, one value per normal, "
                                 "cannot hold it (render it with method='sg' or 'mc')")
            tangent = np.asarray(tangent, np.float64).reshape(-1, 3)
            return np.maximum(material.eval(n, light, view, tangent=tangent) * np.maximum(cos_l, 0.0)[:, None], 0.0)
        return np.maximum(material.eval(n, light, view) * np.maximum(cos_l, 0.0)[:, None], 0.0)
    raise ValueError(f"a lit sphere is made from an analytic Brdf or an EffectiveBRDF, got {material!r}")


def check_holdable(material, name: str = "", remedy: str = "render it with method='sg' or 'mc'") -> None:
    """Refuse, in one line and before any texel is made, a material a lit sphere cannot hold: a `Textured` one
    (its maps vary over the surface; a lit sphere is one response for the whole material) and an analytic
    anisotropic BRDF (its value depends on the tangent; a lit sphere holds one value per normal). A baked
    anisotropic tile is held: its bake is evaluated in the sphere's own tangent frame (`sphere_tangents`).
    `name` (e.g. "materials[0]") is put before the material's type in the message, `remedy` after it."""
    label = f"{name} ({type(material).__name__})" if name else type(material).__name__
    if isinstance(material, Textured):
        raise ValueError(f"{label} is textured: a lit sphere, one BRDF's response for the whole material, cannot "
                         f"hold its texture maps; {remedy}")
    if isinstance(material, Brdf) and material.anisotropic:
        raise ValueError(f"{label} is anisotropic: a lit sphere, one value per normal, cannot hold it; {remedy}")


def diffuse_part(material):
    """The material's diffuse term alone, as a material (Lambert(kd); an EffectiveBRDF with its
    small-scale BRDFs replaced by their diffuse terms), or None where it has none (a Lambert is all
    diffuse: itself)."""
    if isinstance(material, Lambert):
        return material
    if isinstance(material, EffectiveBRDF):
        return material.with_materials([diffuse_part(m) or Lambert(0.0) for m in material.materials])
    kd = getattr(material, "kd", None)
    if kd is None or not np.any(np.asarray(kd) > 0):
        return None
    return Lambert(kd)


def light_direction(phi_degrees: float) -> np.ndarray:
    p = np.radians(phi_degrees)
    return np.array([np.sin(p), 0.0, np.cos(p)])


def sphere_image(material, phi_degrees: float, resolution: int) -> np.ndarray:
    """(R, R, 3) float32: the unit sphere of `material` lit from polar angle φ (degrees) in the plane
    Y = 0, seen along −Z from afar (the module's convention)."""
    n = texel_normals(resolution).reshape(-1, 3)
    light = np.broadcast_to(light_direction(phi_degrees), n.shape)
    view = np.broadcast_to(np.array([0.0, 0.0, 1.0]), n.shape)
    return material_response(material, n, light, view).reshape(resolution, resolution, 3).astype(np.float32)


def texel_inputs(material) -> dict:
    """What the texel kernels (kernels/litsphere.py sphere_texels) read for `material`: an analytic BRDF
    as its packed row (brdf.pack_materials), an EffectiveBRDF as its lobes, its amplitude table (the lookup
    divides by the grid's cos θi, as EffectiveBRDF.eval interpolates μ/cos θi) and its small-scale BRDFs' rows."""
    if isinstance(material, EffectiveBRDF):
        kinds, params = pack_materials(material.materials)
        lobes = material.lobes
        return {"effective": 1, "kinds": kinds, "params": params.astype(np.float32),
                "info": np.array([material.directions, len(lobes.sharpness), len(material.materials),
                                  int(material.method == "sg-exact")], np.int32),
                "lobes": np.column_stack([lobes.axes, lobes.sharpness,
                                          sg.integral(lobes.sharpness)]).astype(np.float32),
                "amplitudes": material.amplitudes.ravel()}
    kinds, params = pack_materials([material])
    return {"effective": 0, "kinds": kinds, "params": params.astype(np.float32), "info": np.zeros(4, np.int32),
            "lobes": np.zeros((1, 5), np.float32), "amplitudes": np.zeros(1, np.float32)}


def sphere_images(material, angles, resolution: int, backend=None) -> np.ndarray:
    """(A, R, R, 3) float32: `sphere_image` at each of `angles` (degrees); on `backend` (a name or a
    Backend) by its texel kernels in float32, else (None) on the host in float64. A MeasuredBRDF's table
    is read on the host either way (the texel kernels have no measured lookup yet), and so is a baked material
    over one (its f̄ takes the table's SG fit, one or two lobes, where the kernels read one row a material) and a
    material whose tables no texel kernel reads (`host_texels`: a matrix-method MatrixBRDF)."""
    on_host = (isinstance(material, MeasuredBRDF) or getattr(material, "host_texels", False)
               or any(isinstance(m, MeasuredBRDF) for m in getattr(material, "materials", ())))
    if backend is None or on_host:
        return np.stack([sphere_image(material, phi, resolution) for phi in angles])
    lights = np.stack([light_direction(phi) for phi in angles])
    return BACKENDS["get"](backend).litsphere_texels(texel_inputs(material), lights, resolution)


# ---------------------------------------------------------------------------------------------
# Checks


def check_angles(angles) -> np.ndarray:
    try:
        a = np.asarray(angles, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"LitSphere angles must be numbers in degrees, got {angles!r}") from None
    if len(a) == 0:
        raise ValueError("LitSphere angles must hold at least one light angle, got none")
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 180:
        raise ValueError(f"LitSphere angles must lie in [0, 180] degrees, got {[round(float(x), 6) for x in a]}")
    if np.any(np.diff(a) <= 0):
        raise ValueError(f"LitSphere angles must be strictly increasing, got {[round(float(x), 6) for x in a]}")
    return a


def check_resolution(resolution) -> int:
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise ValueError(f"LitSphere resolution must be an integer number of texels, got {resolution!r}")
    if not (MIN_LEVEL_RES <= int(resolution) <= RESOLUTION_MAX):
        raise ValueError(f"LitSphere resolution must lie in [{MIN_LEVEL_RES}, {RESOLUTION_MAX}], got {resolution}")
    return int(resolution)


def mip_levels(image: np.ndarray) -> list:
    """[level 0 = image, then 2×2 box averages] down to MIN_LEVEL_RES (an odd size drops its last row and
    column before averaging)."""
    levels = [np.asarray(image, np.float32)]
    while levels[-1].shape[0] // 2 >= MIN_LEVEL_RES:
        a = levels[-1]
        h = a.shape[0] // 2 * 2
        a = a[:h, :h].astype(np.float64)
        levels.append(((a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]) / 4).astype(np.float32))
    return levels


# ---------------------------------------------------------------------------------------------
# The representation


@dataclass(eq=False)
class LitSphere:
    """A material as images of a lit unit sphere (module docstring): `images` (A, R, R, 3) float32
    radiance per unit irradiance, `angles` (A,) the lights' polar angles in degrees, strictly increasing
    in [0, 180]. `diffuse` (A, R, R, 3) or None: the diffuse term's share of `images`, where it is known
    (a lit sphere made from a material; not the paper's measured spheres). The shader turns that share
    by the exact diffuse rotation (k = 1) and only the rest by Eq. 3's k, so a diffuse term is exact up
    to texture resolution however glossy the rest. `source` is the material they were made from (None
    for a loaded one), `name` a label."""

    images: np.ndarray
    angles: object = PAPER_ANGLES
    diffuse: object = None
    source: object = None
    name: str = ""
    device: dict = field(default_factory=dict, repr=False)  # backends' device copies, by backend name

    def __post_init__(self):
        self.angles = check_angles(self.angles)
        a = np.asarray(self.images)
        if a.ndim != 4 or a.shape[3] != 3 or a.shape[1] != a.shape[2]:
            raise ValueError(f"LitSphere images must have shape (angles, R, R, 3), got {a.shape}")
        if a.shape[0] != len(self.angles):
            raise ValueError(f"LitSphere has {a.shape[0]} image(s) for {len(self.angles)} angle(s)")
        check_resolution(a.shape[1])
        a = np.ascontiguousarray(a, np.float32)
        if not np.all(np.isfinite(a)) or a.min() < 0:
            raise ValueError("LitSphere images must be finite and non-negative")
        self.images = a
        if self.diffuse is not None:
            d = np.ascontiguousarray(self.diffuse, np.float32)
            if d.shape != a.shape:
                raise ValueError(f"LitSphere diffuse images have shape {d.shape}; the images {a.shape}")
            if not np.all(np.isfinite(d)) or d.min() < 0:
                raise ValueError("LitSphere diffuse images must be finite and non-negative")
            self.diffuse = d
        self._levels = None

    def __repr__(self):
        label = f"{self.name!r}, " if self.name else ""
        return (f"LitSphere({label}angles={[float(x) for x in self.angles]}, resolution={self.resolution}, "
                f"{self.nbytes / 2**20:.1f} MiB)")

    @property
    def resolution(self) -> int:
        return int(self.images.shape[1])

    @property
    def parts(self) -> list:
        """[(images, k-rule)]: what the shader reads, each part's images turned by Eq. 3's k ("k") or by the
        exact diffuse rotation ("diffuse"): the images alone, or their diffuse share and the rest."""
        if self.diffuse is None:
            return [(self.images, "k")]
        return [(self.diffuse, "diffuse"), (np.maximum(self.images - self.diffuse, 0.0), "k")]

    @property
    def nbytes(self) -> int:
        """Bytes of the textures as the shader holds them (float32 RGB, every mip level of every part)."""
        return int(sum(level.nbytes for part in self.levels for pyramid in part for level in pyramid))

    @property
    def levels(self) -> list:
        """levels[part][a] = the mip pyramid (`mip_levels`) of image a of `parts`[part], built once."""
        if self._levels is None:
            self._levels = [[mip_levels(img) for img in images] for images, _ in self.parts]
        return self._levels

    @classmethod
    def from_material(cls, material, angles=PAPER_ANGLES, resolution: int = RESOLUTION, tolerance=None,
                      name: str = "", backend=None) -> LitSphere:
        """The lit sphere of an analytic isotropic `Brdf` (a `MeasuredBRDF` too) or a baked `EffectiveBRDF` (an
        anisotropic tile's too), its texels the material's exact response (module docstring): computed on the host
        in float64 (backend None), or by the texel kernels on `backend` (a name such as "warp:cuda" or "opencl", or
        a Backend) in float32 — the same values to ~1e-5 (tests/test_litsphere.py), in milliseconds on a GPU where
        the host takes seconds for a baked material. With `tolerance` (a relative RMS error, e.g. 0.02) the angles
        and the resolution are chosen, `angles` ignored and `resolution` the largest allowed: the fewest n of
        TOLERANCE_COUNTS (n angles evenly over [0°, 180°)) whose `interpolation_error` at `resolution` is at most
        `tolerance`, then the smallest resolution (halving, down to 32) whose error still is, each judged on the
        same grid (`resolution`, at most ERROR_RESOLUTION); ValueError if no count meets it. The choice is in the
        result's `chosen` dict (tolerance, error, resolution, what was tried). A `Textured` material and an analytic
        anisotropic BRDF (AnisotropicWard, AshikhminShirley) cannot be held: a one-line ValueError
        (`check_holdable`)."""
        check_holdable(material)
        resolution = check_resolution(resolution)
        if not isinstance(material, (Brdf, EffectiveBRDF)) or isinstance(material, LitSphere):
            raise ValueError(f"LitSphere.from_material takes an analytic Brdf or an EffectiveBRDF, got {material!r}")
        if tolerance is not None:
            tol = float(tolerance)
            if not (np.isfinite(tol) and tol > 0):
                raise ValueError(f"tolerance must be a positive relative error, got {tolerance!r}")
            tried = []
            grid = min(resolution, ERROR_RESOLUTION)  # every candidate judged on the same grid
            for count in TOLERANCE_COUNTS:
                sphere = cls.from_material(material, even_angles(count), resolution, name=name, backend=backend)
                err = sphere.interpolation_error(resolution=grid)
                tried.append(f"{count} angles at {resolution}: {err:.4f}")
                if err <= tol:
                    break
            else:
                raise ValueError(f"no light-angle count up to {TOLERANCE_COUNTS[-1]} meets tolerance {tol} for "
                                 f"{material!r} at resolution {resolution} ({', '.join(tried)})")
            res = resolution // 2
            while res >= 32:
                smaller = cls.from_material(material, sphere.angles, res, name=name, backend=backend)
                err_small = smaller.interpolation_error(resolution=grid)
                tried.append(f"{len(sphere.angles)} angles at {res}: {err_small:.4f}")
                if err_small > tol:
                    break
                sphere, err, res = smaller, err_small, res // 2
            sphere.chosen = {"tolerance": tol, "error": err, "resolution": sphere.resolution, "tried": tried}
            return sphere
        angles = check_angles(angles)
        imgs = sphere_images(material, angles, resolution, backend)
        diffuse = diffuse_part(material)
        diffuse_imgs = (None if diffuse is None else imgs if diffuse is material else
                        np.minimum(sphere_images(diffuse, angles, resolution, backend), imgs))
        return cls(imgs, angles, diffuse=diffuse_imgs, source=material, name=name)

    def interpolation_error(self, test_angles=None, resolution: int | None = None) -> float:
        """The relative RMS error, pooled over the disc and the test angles, of the shader's sphere against
        the exact sphere (`sphere_image` of `source`) under lights at `test_angles` (default TEST_ANGLES: a
        fixed set, so that spheres with different angles are judged alike — the error then falls as
        angles are added), on the texel grid of `resolution` (default the images' own, at most
        ERROR_RESOLUTION), seen along −Z from afar: the method's own error, perspective aside. Needs
        `source`."""
        if self.source is None:
            raise ValueError("this LitSphere has no source material (it was loaded): its error cannot be measured")
        test_angles = TEST_ANGLES if test_angles is None else test_angles
        res = min(self.resolution, ERROR_RESOLUTION) if resolution is None else check_resolution(resolution)
        n = texel_normals(res).reshape(-1, 3)
        inside = (np.hypot(n[:, 0], n[:, 1]) < RIM * 0.999)
        n = n[inside]
        v = np.broadcast_to([0.0, 0.0, 1.0], n.shape)
        num = den = 0.0
        for phi in test_angles:
            light = np.broadcast_to(light_direction(phi), n.shape)
            exact = material_response(self.source, n, light, v)
            got = reference_shade(self, n, v, light, lod=np.zeros(len(n)))
            num += float(((got - exact) ** 2).sum())
            den += float((exact**2).sum())
        return float(np.sqrt(num / max(den, 1e-300)))

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write a folder `path` (by convention *.litsphere): `litsphere.json` (format, version, angles,
        resolution, name, files, diffuse_files, source) and one float32 EXR per angle, `phi_<degrees>.exr`, and
        where the material has a diffuse part apart (`diffuse`), one more per angle, `diffuse_<degrees>.exr`. Atomic:
        the folder is built beside `path` and moved into place; an old one is replaced only once the new is whole.
        An existing folder is replaced only where it is empty or an earlier save's (`_not_saved_here`): one
        holding anything else is refused, in one line, before anything is written. A failed write (a full
        disk, a read-only folder) is an OSError naming `path` and leaves the old folder as it was."""
        path = os.fspath(path)
        if os.path.exists(path) and not os.path.isdir(path):
            raise ValueError(f"LitSphere output {path!r} is a file; a lit sphere is saved as a folder")
        if os.path.isdir(path):
            foreign = _not_saved_here(path)
            if foreign:
                shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
                raise ValueError(f"LitSphere output {path!r} holds files LitSphere.save did not write ({shown}); "
                                 "give another folder")
        parent = os.path.dirname(os.path.abspath(path))
        tmp = None
        try:
            os.makedirs(parent, exist_ok=True)
            tmp = tempfile.mkdtemp(prefix=".tmp-litsphere-", dir=parent)
            files, diffuse_files = [], []
            for a, phi in enumerate(self.angles):
                files.append(_image_name("phi", phi))
                images_mod.write_exr(os.path.join(tmp, files[-1]), self.images[a])
                if self.diffuse is not None:
                    diffuse_files.append(_image_name("diffuse", phi))
                    images_mod.write_exr(os.path.join(tmp, diffuse_files[-1]), self.diffuse[a])
            head = {"format": FORMAT, "version": VERSION, "angles": [float(x) for x in self.angles],
                    "resolution": self.resolution, "name": self.name, "files": files,
                    "diffuse_files": diffuse_files or None,
                    "source": repr(self.source) if self.source is not None else None}
            with open(os.path.join(tmp, HEADER), "w") as fh:
                json.dump(head, fh, indent=1)
            os.chmod(tmp, 0o777 & ~_umask())
            old = None
            if os.path.isdir(path):
                old = tempfile.mkdtemp(prefix=".tmp-old-litsphere-", dir=parent)
                os.rmdir(old)
                os.replace(path, old)
            try:
                os.replace(tmp, path)
            except OSError:
                if old is not None:  # (the old folder back where it was: a failed save loses nothing)
                    os.replace(old, path)
                raise
            tmp = None
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        except OSError as exc:
            # (the system's text names no file, or the temporary folder the user never asked for)
            raise write_error(path, exc) from exc
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)

    @classmethod
    def load(cls, path) -> LitSphere:
        """Read a folder `save` wrote; one-line errors name the folder and what is wrong."""
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"no such lit sphere: {path}")
        head_path = os.path.join(path, HEADER)
        if not os.path.isdir(path) or not os.path.isfile(head_path):
            raise ValueError(f"{path} is not a lit-sphere folder (no litsphere.json in it)")
        try:
            with open(head_path) as fh:
                head = json.load(fh)
        except (OSError, ValueError) as exc:
            raise ValueError(f"{head_path} is not a readable lit-sphere header: {exc}") from None
        if not isinstance(head, dict) or head.get("format") != FORMAT:
            raise ValueError(f"{head_path} is not a lit-sphere header (format {head.get('format')!r})"
                             if isinstance(head, dict) else f"{head_path} is not a lit-sphere header")
        if head.get("version") != VERSION:
            raise ValueError(f"{head_path} has version {head.get('version')!r}; this warp_biscale reads {VERSION}")
        try:
            files, angles, res = list(head["files"]), head["angles"], int(head["resolution"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{head_path} lacks or garbles a field: {exc}") from None
        if len(files) != len(angles):
            raise ValueError(f"{head_path} lists {len(files)} image(s) for {len(angles)} angle(s)")
        diffuse_files = head.get("diffuse_files")
        if diffuse_files is not None and (not isinstance(diffuse_files, list) or len(diffuse_files) != len(files)):
            raise ValueError(f"{head_path} lists diffuse images that do not match its {len(files)} image(s)")

        def read(names):
            out = []
            for name in names:
                if not isinstance(name, str) or os.path.basename(name) != name:
                    raise ValueError(f"{head_path} names an image outside its folder: {name!r}")
                img = images_mod.read_exr(os.path.join(path, name))
                if img.shape != (res, res, 3):
                    raise ValueError(f"{os.path.join(path, name)} is {img.shape[1]}×{img.shape[0]}; the header "
                                     f"says {res}×{res}")
                out.append(img)
            return np.stack(out)

        imgs = read(files)
        diffuse = read(diffuse_files) if diffuse_files else None
        try:
            return cls(imgs, angles, diffuse=diffuse, name=str(head.get("name", "")))
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None


def _image_name(kind: str, phi: float) -> str:
    return f"{kind}_{phi:09.5f}.exr"


def _not_saved_here(folder) -> list:
    """The entries of an existing folder that LitSphere.save did not write, sorted: none where it is empty or holds
    a lit-sphere header (litsphere.json of this FORMAT, any version) and images named as save names them; every
    entry where it has no such header (what is in it then is not known to be a save's). The files a save wrote
    are replaced with the folder; anything else in it would be lost."""
    names = sorted(os.listdir(folder))
    try:
        with open(os.path.join(folder, HEADER)) as fh:
            head = json.load(fh)
    except (OSError, ValueError):
        return names
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        return names
    return [n for n in names if n != HEADER and not (_IMAGE_NAME.fullmatch(n)
                                                     and os.path.isfile(os.path.join(folder, n)))]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def even_angles(count: int) -> np.ndarray:
    """`count` angles evenly over [0°, 180°): 4 → the paper's 0, 45, 90, 135; 6 → 0, 30, …, 150."""
    return np.arange(int(count)) * (180.0 / int(count))


# ---------------------------------------------------------------------------------------------
# The shader in float64 (what the kernels compute)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) bilinear lookup of an (R, R, 3) image at texture coordinates u (x), v (y) ∈ [0, 1], v up;
    clamped at the edges."""
    res = img.shape[0]
    fx = np.clip(u * res - 0.5, 0.0, res - 1.0)
    fy = np.clip((1.0 - v) * res - 0.5, 0.0, res - 1.0)
    x0 = np.minimum(np.floor(fx).astype(int), res - 2) if res > 1 else np.zeros(len(u), int)
    y0 = np.minimum(np.floor(fy).astype(int), res - 2) if res > 1 else np.zeros(len(u), int)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    a = img.astype(np.float64)
    return ((1 - ay) * ((1 - ax) * a[y0, x0] + ax * a[y0, x0 + 1])
            + ay * ((1 - ax) * a[y0 + 1, x0] + ax * a[y0 + 1, x0 + 1]))


def _trilinear(levels: list, u, v, lod) -> np.ndarray:
    lod = np.clip(lod, 0.0, len(levels) - 1.0)
    lo = np.floor(lod).astype(int)
    out = np.zeros((len(u), 3))
    for level in np.unique(lo):
        sel = lo == level
        f = (lod[sel] - level)[:, None]
        a = _bilinear(levels[level], u[sel], v[sel])
        b = _bilinear(levels[min(level + 1, len(levels) - 1)], u[sel], v[sel])
        out[sel] = (1 - f) * a + f * b
    return out


def view_frame(view: np.ndarray, light: np.ndarray):
    """(x, y, z) of the images' frame for unit view and light directions (N, 3): z = v, x along l's part
    across v (any perpendicular when l ∥ v), y = z × x."""
    z = view
    x = light - np.einsum("ij,ij->i", light, z)[:, None] * z
    length = np.linalg.norm(x, axis=1)
    # l along ±v: the light's azimuth is undefined and any x serves (the images are symmetric about it)
    ref = np.where((np.abs(z[:, 0]) < 0.9)[:, None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    alt = ref - np.einsum("ij,ij->i", ref, z)[:, None] * z
    x = np.where((length > 1e-6)[:, None], x, alt)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return x, np.cross(z, x), z


def rim_point(rx, ry, rz, phi_i):
    """Where a diffuse share is read for a turned normal r = (rx, ry, rz) in image i's frame (its light
    l_i = (sin φi, 0, cos φi)): r itself, or where r faces away (rz < 0, a point the image does not
    show) the rim point of the circle {m : m·l_i = r·l_i} on r's side — a diffuse term there is the same,
    and the rim is in the image. Arrays; → (x, y) of the point read."""
    c = rx * np.sin(phi_i) + rz * np.cos(phi_i)
    s = np.sqrt(np.maximum(1 - c * c, 0.0))
    across = s * np.sin(phi_i)
    sin_b = np.clip(-c * np.cos(phi_i) / np.where(across > 1e-6, across, 1.0), -1.0, 1.0)
    cos_b = np.copysign(np.sqrt(1 - sin_b * sin_b), ry)
    behind = (rz < 0) & (across > 1e-6)
    return (np.where(behind, c * np.sin(phi_i) - s * sin_b * np.cos(phi_i), rx), np.where(behind, s * cos_b, ry))


def reference_shade(sphere: LitSphere, n, view, light, lod=None, shrink: float = 1.0) -> np.ndarray:
    """(N, 3) float64 radiance per unit irradiance of normals n seen from `view`, lit from `light` (unit
    (N, 3) each, world space), by seed 004's Eq. 1–4 (module docstring): what the kernels compute for
    one light, before its irradiance and visible share. `lod` (N,) the mip level (default 0); `shrink`
    scales the turned normal before the lookup (1, or the paper's SHRINK)."""
    n, view, light = (np.asarray(a, np.float64).reshape(-1, 3) for a in (n, view, light))
    lod = np.zeros(len(n)) if lod is None else np.asarray(lod, np.float64).reshape(-1)
    x, y, z = view_frame(view, light)
    # (atan2 of the across and along parts: exact where l is near ±v, where acos loses float32 digits)
    across = np.linalg.norm(light - np.einsum("ij,ij->i", light, z)[:, None] * z, axis=1)
    phi = np.degrees(np.arctan2(across, np.einsum("ij,ij->i", light, z)))
    nx, ny, nz = (np.einsum("ij,ij->i", n, axis) for axis in (x, y, z))
    # half vector of l' = (sin φ, 0, cos φ) and v' = +Z: (sin φ/2, 0, cos φ/2)
    hx, hz = np.sin(np.radians(phi) / 2), np.cos(np.radians(phi) / 2)
    proj = np.hypot(nx, nz)
    cos_ah = np.where(proj > 1e-12, (hx * nx + hz * nz) / np.maximum(proj, 1e-300), 0.0)
    alpha_h = np.clip(np.arccos(np.clip(cos_ah, -1.0, 1.0)), 0.0, np.pi / 2)
    k_inside = 0.5 + np.sin(alpha_h) / 2
    angles = sphere.angles
    count = len(angles)
    i2 = np.searchsorted(angles, phi, side="left")  # angles[i2 - 1] < φ ≤ angles[i2]
    single = (i2 == 0) | (i2 >= count)
    i1 = np.clip(i2 - 1, 0, count - 1)
    i2 = np.clip(i2, 0, count - 1)
    i1 = np.where(single, np.where(phi <= angles[0], 0, count - 1), i1)
    i2 = np.where(single, i1, i2)
    phi1, phi2 = angles[i1], angles[i2]
    span = np.where(single, 1.0, phi2 - phi1)
    t = np.where(single, 0.0, (phi - phi1) / span)
    k_glossy = np.where(single, K_OUTSIDE, k_inside)
    out = np.zeros((len(n), 3))
    for levels, (_, rule) in zip(sphere.levels, sphere.parts):
        k = 1.0 if rule == "diffuse" else k_glossy
        for idx, phi_i, weight in ((i1, phi1, 1 - t), (i2, phi2, t)):
            turn = np.radians(k * (phi_i - phi))
            rx = nx * np.cos(turn) + nz * np.sin(turn)
            ry = ny
            if rule == "diffuse":
                rx, ry = rim_point(rx, ny, -nx * np.sin(turn) + nz * np.cos(turn), np.radians(phi_i))
            u, v = shrink * rx / 2 + 0.5, shrink * ry / 2 + 0.5
            for a in np.unique(idx):
                sel = (idx == a) & (weight > 0)
                if sel.any():
                    out[sel] += weight[sel, None] * _trilinear(levels[a], u[sel], v[sel], lod[sel])
    lit = (np.einsum("ij,ij->i", n, light) > 0) & (np.einsum("ij,ij->i", n, view) > 0)
    return np.where(lit[:, None], np.maximum(out, 0.0), 0.0)


# ---------------------------------------------------------------------------------------------
# Packing for the kernels


@dataclass(eq=False)
class SpherePack:
    """The lit spheres of a scene as the kernels read them. ``sphere_of_material`` (Mat,) int32 the sphere
    of each material; ``sphere_info`` (S, 8) int32 [first angle, angle count A, first level row, level
    count Lv, part count P (2: a diffuse part turned exactly, then the rest turned by k; 1: the images,
    turned by k), 0, 0, 0]; ``angles`` (ΣA, 3) float32 [φ (radians), cos φ, sin φ]; ``level_info``
    (Σ P·A·Lv, 2) int32 [texel offset, size], part p's image a at level l in row first level row
    + (p·A + a)·Lv + l; ``texels`` (T, 3) float32, each level row-major, row 0 at the top."""

    sphere_of_material: np.ndarray
    sphere_info: np.ndarray
    angles: np.ndarray
    level_info: np.ndarray
    texels: np.ndarray
    device: dict = field(default_factory=dict, repr=False)


def pack_spheres(spheres: list) -> SpherePack:
    """Pack one LitSphere per material (the same object may serve several) → SpherePack."""
    unique, of_material = [], []
    for s in spheres:
        if not isinstance(s, LitSphere):
            raise ValueError(f"pack_spheres takes LitSpheres, got {s!r}")
        found = [i for i, u in enumerate(unique) if u is s]
        of_material.append(found[0] if found else len(unique))
        if not found:
            unique.append(s)
    info, angles, level_rows, chunks = [], [], [], []
    offset = 0
    for s in unique:
        n_levels = len(s.levels[0][0])
        info.append([len(angles), len(s.angles), len(level_rows), n_levels, len(s.parts), 0, 0, 0])
        angles.extend(np.stack([np.radians(s.angles), np.cos(np.radians(s.angles)), np.sin(np.radians(s.angles))], 1))
        for part in s.levels:
            for pyramid in part:
                for level in pyramid:
                    level_rows.append([offset, level.shape[0]])
                    chunks.append(level.reshape(-1, 3))
                    offset += level.shape[0] * level.shape[1]
    return SpherePack(np.asarray(of_material, np.int32), np.asarray(info, np.int32).reshape(-1, 8),
                      np.asarray(angles, np.float32).reshape(-1, 3), np.asarray(level_rows, np.int32).reshape(-1, 2),
                      np.ascontiguousarray(np.concatenate(chunks), np.float32))
