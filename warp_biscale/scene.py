"""The large-scale side of rendering: a mesh, a camera and local lights (Wang 2009 §6–7).

World space is right-handed with +y up (trimesh's and most asset formats' convention). All
arrays are numpy; backends keep device copies in each object's `device_cache`.

Lights are small spherical emitters represented *exactly* as one spherical Gaussian each (Wang
Eq. 32–33). Their radiance, seen from a point x, is L(ω) = G(ω; l̂, η, μ) with the SG's
equivalent solid angle 2π/η equal to the solid angle Ω the emitter subtends, and ∫G = the
irradiance it delivers at normal incidence. The SG renderer and the Monte Carlo reference both
use this emitter, so their images differ only by the rendering method, not by the light model.

- `DirectionalLight(direction, irradiance, angular_radius)`: l̂ = direction (towards the light),
  Ω = π·α² (α in radians), ∫G = irradiance.
- `PointLight(position, intensity, radius)`: l̂ = (p − x)/d, Ω = π·r²/d², ∫G = intensity / d².
  A point light's sphere must stay clear of the mesh (a `Scene` refuses one with a face within
  `radius` of its centre): its SG and its shadow rays, aimed over its disc, see it from outside.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .brdf import Brdf
from .effective import EffectiveBRDF
from .environment import Environment
from .images import write_image
from .io import check_output
from .litsphere import LitSphere
from .lobes import KERNEL_LOBES
from .smallscale import TILE_SCALE_MAX, _finite_array, mesh_read_reason
from .svbrdf import Textured

__all__ = ["Mesh", "Camera", "PointLight", "DirectionalLight", "light_sg"]

MIN_LIGHT_SOLID_ANGLE = 1e-6  # sr: caps a light's SG sharpness at 2π·1e6 (the SG closed forms hold to 1e6)


def _vec3(name, v) -> np.ndarray:
    try:
        a = np.asarray(v, np.float64).reshape(3)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be three numbers, got {v!r}") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf: {v!r}")
    return a


def _unit(name, v) -> np.ndarray:
    a = _vec3(name, v)
    n = np.linalg.norm(a)
    if n == 0:
        raise ValueError(f"{name} must be a non-zero vector, got {v!r}")
    return a / n


def _number(name, v, what: str = "a finite number") -> float:
    """A finite real number (a bool is not one), else a ValueError naming `name`."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        x = None
    if x is None or isinstance(v, (bool, np.bool_)) or not np.isfinite(x):
        raise ValueError(f"{name} must be {what}, got {v!r}")
    return x


def _positive(name, v) -> float:
    x = _number(name, v, "a finite number > 0")
    if not x > 0:
        raise ValueError(f"{name} must be > 0, got {v!r}")
    return x


MESH_QUADS_MAX = 2048 * 2048  # a built-in mesh's cells (two faces each): past this its arrays fill the memory


def _integer(name, v, lo: int, hi: int | None = None, note: str = "") -> int:
    """An integer (an integral float is accepted) in lo..hi (hi None: >= lo), else a ValueError naming
    `name` (and `note`, what the range is)."""
    try:
        ok = not isinstance(v, (bool, np.bool_)) and int(v) == v and lo <= int(v) and (hi is None or int(v) <= hi)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        what = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise ValueError(f"{name} must be an integer {what}{note}, got {v!r}")
    return int(v)


def _rgb(name, v) -> np.ndarray:
    try:
        a = np.asarray(v, np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number >= 0 or an RGB triple of them, got {v!r}") from None
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or (a < 0).any():
        raise ValueError(f"{name} must be a number >= 0 or an RGB triple of them, got {v!r}")
    return a


LIGHT_POWER_MAX = 1e20  # a light's SG amplitude is its power over its solid angle, times a BRDF's peak: float32 room


def _light_power(name, v) -> np.ndarray:
    a = _rgb(name, v)
    if a.max() > LIGHT_POWER_MAX:
        raise ValueError(f"{name} must be at most {LIGHT_POWER_MAX:g} (the renderers' float32 range, with room for a "
                         f"small light's sharp lobe), got {v!r}")
    return a


_ICOSAHEDRON_FACES = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                               [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                               [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """(unit vertices (V, 3) float64, faces (F, 3), counter-clockwise seen from outside): the icosahedron with
    each triangle split into four at its edges' midpoints `subdivisions` times, each new vertex put on the unit
    sphere (trimesh.creation.icosphere's construction, without importing trimesh)."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], np.float64) / np.sqrt(1.0 + t * t)
    f = _ICOSAHEDRON_FACES
    for _ in range(subdivisions):
        edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)  # each face's edges 01, 12, 20
        _, first, inverse = np.unique(edges[:, 0] * len(v) + edges[:, 1], return_index=True, return_inverse=True)
        mid = v[edges[first]].sum(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(-1, 3) + len(v)  # the midpoints of edges 01, 12, 20
        f = np.stack([np.stack([f[:, 0], m[:, 0], m[:, 2]], 1), np.stack([m[:, 0], f[:, 1], m[:, 1]], 1),
                      np.stack([m[:, 2], m[:, 1], f[:, 2]], 1), m], 1).reshape(-1, 3)
        v = np.vstack([v, mid])
    return v, f


@dataclass(eq=False)
class Mesh:
    """A triangle mesh with per-vertex normals (smooth shading), optional UVs and a material id per face.

    vertices (V, 3) float64, faces (F, 3) int32, normals (V, 3) unit, uvs (V, 2) or None,
    face_material (F,) int32 indices into the scene's material list.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    face_material: np.ndarray | None = None
    device_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        self.vertices = _finite_array("Mesh.vertices", self.vertices, (3,), np.float64)
        if len(self.vertices) and np.abs(self.vertices).max() > TILE_SCALE_MAX:
            raise ValueError(f"Mesh.vertices reach {np.abs(self.vertices).max():.3g}: the float32 renderers take "
                             f"coordinates up to {TILE_SCALE_MAX:g} (rescale the scene)")
        faces = np.asarray(self.faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"Mesh.faces must be a non-empty (F, 3) integer array, got shape {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(self.vertices):
            raise ValueError(f"Mesh.faces must index vertices 0..{len(self.vertices) - 1}, "
                             f"found {faces.min()}..{faces.max()}")
        self.faces = faces.astype(np.int32)
        if self.normals is None:
            self.normals = self._smooth_normals()
        else:
            n = _finite_array("Mesh.normals", self.normals, (3,), np.float64)
            if len(n) != len(self.vertices):
                raise ValueError(f"Mesh.normals has {len(n)} rows for {len(self.vertices)} vertices")
            length = np.linalg.norm(n, axis=1, keepdims=True)
            self.normals = np.where(length > 0, n / np.where(length > 0, length, 1.0), self._smooth_normals())
        if self.uvs is not None:
            self.uvs = _finite_array("Mesh.uvs", self.uvs, (2,), np.float64)
            if len(self.uvs) != len(self.vertices):
                raise ValueError(f"Mesh.uvs has {len(self.uvs)} rows for {len(self.vertices)} vertices")
        if self.face_material is None:
            self.face_material = np.zeros(len(self.faces), np.int32)
        self.face_material = np.asarray(self.face_material, np.int32).reshape(-1)
        if len(self.face_material) != len(self.faces) or (self.face_material < 0).any():
            raise ValueError("Mesh.face_material must hold one id >= 0 per face")

    def _smooth_normals(self) -> np.ndarray:
        tri = self.vertices[self.faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 × area: area-weighted
        n = np.zeros_like(self.vertices)
        for k in range(3):
            np.add.at(n, self.faces[:, k], fn)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 0, n / np.where(length > 0, length, 1.0), np.array([0.0, 1.0, 0.0]))

    @property
    def face_normals(self) -> np.ndarray:
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)

    def distance_to(self, point, within: float = np.inf) -> float:
        """The distance from `point` to the nearest face (float64); faces whose bounding box lies
        farther than `within` are skipped (inf when all are)."""
        p = _vec3("point", point)
        near = np.ones(len(self.faces), bool)
        for axis in range(3):  # (one axis at a time: a big mesh's faces as (F, 3, 3) would take GBs)
            x = self.vertices[:, axis][self.faces]
            near &= (x.min(1) <= p[axis] + within) & (x.max(1) >= p[axis] - within)
        a, b, c = (self.vertices[self.faces[near, k]] for k in range(3))
        if not len(a):
            return np.inf

        def segment(u, v):
            e = v - u
            t = np.clip(np.einsum("ij,ij->i", p - u, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
            return np.linalg.norm(p - (u + t[:, None] * e), axis=1)

        d = np.minimum(np.minimum(segment(a, b), segment(b, c)), segment(c, a))
        n = np.cross(b - a, c - a)
        nn = np.einsum("ij,ij->i", n, n)
        ok = nn > 0  # the point's projection inside the triangle: the plane's distance
        w = p - a
        s1 = np.einsum("ij,ij->i", np.cross(w, c - a), n)  # barycentric weights ×|n|² of b and c
        s2 = np.einsum("ij,ij->i", np.cross(b - a, w), n)
        inside = ok & (s1 >= 0) & (s2 >= 0) & (s1 + s2 <= nn)
        plane = np.abs(np.einsum("ij,ij->i", w, n)) / np.sqrt(np.where(ok, nn, 1.0))
        d = np.where(inside, np.minimum(d, plane), d)
        return float(d.min())

    @property
    def bounds(self) -> np.ndarray:
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    @property
    def scale(self) -> float:
        """The larger of the extent and the largest coordinate magnitude (sets ray offsets)."""
        return float(max(np.ptp(self.vertices, axis=0).max(), np.abs(self.vertices).max(), 1e-30))

    def __len__(self):
        return len(self.faces)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_trimesh(cls, tm, material: int = 0) -> Mesh:
        material = _integer("Mesh.from_trimesh material", material, 0)
        uv = getattr(getattr(tm, "visual", None), "uv", None)
        uvs = None if uv is None or len(uv) != len(tm.vertices) else np.asarray(uv, np.float64)
        normals = np.asarray(tm.vertex_normals, np.float64) if len(tm.vertices) else None
        return cls(np.asarray(tm.vertices, np.float64), np.asarray(tm.faces), normals, uvs,
                   np.full(len(tm.faces), material, np.int32))

    @classmethod
    def load(cls, path, material: int = 0) -> Mesh:
        """Any mesh trimesh reads (OBJ, PLY, STL, GLB, ...); a scene is flattened into one mesh."""
        import trimesh  # (on first use: importing it takes a second of every process's start, a batch worker's too)

        material = _integer("Mesh.load material", material, 0)
        try:
            tm = trimesh.load(str(path), force="mesh", process=False)
        except Exception as exc:
            raise ValueError(f"cannot read mesh {path}: {mesh_read_reason(exc)}") from None
        if not isinstance(tm, trimesh.Trimesh) or len(tm.faces) == 0:
            raise ValueError(f"{path} holds no triangles")
        try:
            return cls.from_trimesh(tm, material)
        except IndexError as exc:  # (a PLY's bad face index surfaces only here, in its normals)
            raise ValueError(f"cannot read mesh {path}: {mesh_read_reason(exc)}") from None

    @classmethod
    def sphere(cls, radius=1.0, center=(0.0, 0.0, 0.0), subdivisions=4, material: int = 0) -> Mesh:
        """An icosphere with exact normals and equirectangular UVs."""
        radius = _positive("Mesh.sphere radius", radius)
        center = _vec3("Mesh.sphere center", center)
        subdivisions = _integer("Mesh.sphere subdivisions", subdivisions, 0, 8, " (8: 1.3 M faces)")
        material = _integer("Mesh.sphere material", material, 0)
        n, faces = icosphere(subdivisions)
        uvs = np.stack([0.5 + np.arctan2(n[:, 0], n[:, 2]) / (2 * np.pi),
                        np.arccos(np.clip(n[:, 1], -1, 1)) / np.pi], 1)
        return cls(n * radius + center, faces, n, uvs, np.full(len(faces), material, np.int32))

    @classmethod
    def torus(cls, major=1.0, minor=0.35, center=(0.0, 0.0, 0.0), segments=(96, 48), material: int = 0) -> Mesh:
        """A torus around +y with exact normals and (u, v) = (around, across) UVs."""
        major = _positive("Mesh.torus major", major)
        minor = _positive("Mesh.torus minor", minor)
        center = _vec3("Mesh.torus center", center)
        material = _integer("Mesh.torus material", material, 0)
        try:
            nu, nv = segments
        except (TypeError, ValueError):
            raise ValueError(f"Mesh.torus segments must be two integers >= 3 (around, across), "
                             f"got {segments!r}") from None
        nu = _integer("Mesh.torus segments[0] (around)", nu, 3, 4096)
        nv = _integer("Mesh.torus segments[1] (across)", nv, 3, 4096)
        if nu * nv > MESH_QUADS_MAX:
            raise ValueError(f"Mesh.torus segments {nu} x {nv} make {2 * nu * nv:,} faces: at most "
                             f"{2 * MESH_QUADS_MAX:,}")
        u = np.arange(nu) * 2 * np.pi / nu
        v = np.arange(nv) * 2 * np.pi / nv
        uu, vv = np.meshgrid(u, v, indexing="ij")
        ring = np.stack([np.cos(uu), np.zeros_like(uu), np.sin(uu)], -1)
        normal = ring * np.cos(vv)[..., None] + np.array([0.0, 1.0, 0.0]) * np.sin(vv)[..., None]
        pos = ring * major + normal * minor
        a = np.arange(nu)[:, None] * nv + np.arange(nv)[None, :]
        b = ((np.arange(nu)[:, None] + 1) % nu) * nv + np.arange(nv)[None, :]
        c = ((np.arange(nu)[:, None] + 1) % nu) * nv + (np.arange(nv)[None, :] + 1) % nv
        d = np.arange(nu)[:, None] * nv + (np.arange(nv)[None, :] + 1) % nv
        faces = np.concatenate([np.stack([a, d, b], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
        uvs = np.stack([uu / (2 * np.pi), vv / (2 * np.pi)], -1).reshape(-1, 2)
        return cls(pos.reshape(-1, 3) + center, faces, normal.reshape(-1, 3), uvs,
                   np.full(len(faces), material, np.int32))

    @classmethod
    def plane(cls, size=4.0, height=0.0, divisions=32, material: int = 0) -> Mesh:
        """A square floor at y = height, facing +y, divided into divisions² quads (SSDF vertices)."""
        size = _positive("Mesh.plane size", size)
        height = _number("Mesh.plane height", height)
        divisions = _integer("Mesh.plane divisions", divisions, 1, 2048, " (2048: 8.4 M faces)")
        material = _integer("Mesh.plane material", material, 0)
        t = np.linspace(-size / 2, size / 2, divisions + 1)
        xx, zz = np.meshgrid(t, t, indexing="ij")
        pos = np.stack([xx, np.full_like(xx, height), zz], -1).reshape(-1, 3)
        n1 = divisions + 1
        i, j = np.meshgrid(np.arange(divisions), np.arange(divisions), indexing="ij")
        a = (i * n1 + j).ravel()
        faces = np.concatenate([np.stack([a, a + 1, a + n1 + 1], 1), np.stack([a, a + n1 + 1, a + n1], 1)])
        uvs = np.stack([(xx + size / 2) / size, (zz + size / 2) / size], -1).reshape(-1, 2)
        return cls(pos, faces, np.tile([0.0, 1.0, 0.0], (len(pos), 1)), uvs, np.full(len(faces), material, np.int32))

    @staticmethod
    def merge(meshes) -> Mesh:
        """One mesh from several (the kernels trace one BVH); each keeps its faces' material ids."""
        meshes = list(meshes)
        if not meshes:
            raise ValueError("no meshes to merge")
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        any_uv = any(m.uvs is not None for m in meshes)
        uvs = (np.concatenate([m.uvs if m.uvs is not None else np.zeros((len(m.vertices), 2)) for m in meshes])
               if any_uv else None)
        return Mesh(np.concatenate([m.vertices for m in meshes]),
                    np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]),
                    np.concatenate([m.normals for m in meshes]), uvs,
                    np.concatenate([m.face_material for m in meshes]))


@dataclass(eq=False)
class Camera:
    """A pinhole camera. Pixel (x, y), y down, is the ray through its centre, or through the point
    `jitter` = (jx, jy) ∈ [−½, ½]² pixels from it (the anti-aliased renderer's sub-pixel samples):
    d ∝ forward + (2(x + ½ + jx)/W − 1)·tan(fov/2)·(W/H)·right + (1 − 2(y + ½ + jy)/H)·tan(fov/2)·up."""

    eye: object = (0.0, 0.0, 4.0)
    target: object = (0.0, 0.0, 0.0)
    up: object = (0.0, 1.0, 0.0)
    fov: float = 40.0  # vertical field of view, degrees
    width: int = 512
    height: int = 512
    jitter: tuple = (0.0, 0.0)

    def __post_init__(self):
        self.eye = _vec3("Camera.eye", self.eye)
        self.target = _vec3("Camera.target", self.target)
        self.up = _unit("Camera.up", self.up)
        if np.linalg.norm(self.target - self.eye) == 0:
            raise ValueError("Camera.eye and Camera.target coincide")
        fov = _number("Camera.fov", self.fov)
        if not (0 < fov < 180):
            raise ValueError(f"Camera.fov must lie in (0, 180) degrees, got {self.fov!r}")
        self.fov = fov
        for name in ("width", "height"):
            setattr(self, name, _integer(f"Camera.{name}", getattr(self, name), 1, 16384))
        if abs(np.dot(self.basis()[0], self.up)) > 1 - 1e-9:
            raise ValueError("Camera.up is parallel to the viewing direction")
        jitter = np.asarray(self.jitter, np.float64)
        if jitter.shape != (2,) or not np.all(np.abs(jitter) <= 0.5):
            raise ValueError(f"Camera.jitter must be two offsets in [-0.5, 0.5] pixels, got {self.jitter!r}")
        self.jitter = (float(jitter[0]), float(jitter[1]))

    def basis(self):
        """(forward, right, up) unit vectors, and tan(fov/2)."""
        f = self.target - self.eye
        f = f / np.linalg.norm(f)
        r = np.cross(f, self.up)
        r = r / max(np.linalg.norm(r), 1e-300)
        u = np.cross(r, f)
        return f, r, u, float(np.tan(np.radians(self.fov) / 2))

    def packed(self) -> np.ndarray:
        """(16,) float32, read-only: eye, forward, right·tan·aspect, up·tan, width, height, 0, 0 (what the kernels
        read). A jitter moves `forward` by that many pixels (kernels normalise the ray), so the kernels, which
        aim at pixel centres, need not know of it. Kept until a field changes: a frame asks for it several
        times (the G-buffer's key, the launches), and making it costs a GPU host about 0.1 ms each time."""
        key = (*(np.asarray(v, np.float64).tobytes() for v in (self.eye, self.target, self.up, self.jitter)),
               float(self.fov), int(self.width), int(self.height))
        held = self.__dict__.get("_packed")
        if held is not None and held[0] == key:
            return held[1]
        packed = self._packed_now()
        packed.flags.writeable = False
        self._packed = (key, packed)
        return packed

    def _packed_now(self) -> np.ndarray:
        f, r, u, t = self.basis()
        aspect = self.width / self.height
        right, up = r * t * aspect, u * t
        f = f + (2 * self.jitter[0] / self.width) * right - (2 * self.jitter[1] / self.height) * up
        return np.concatenate([self.eye, f, right, up, [self.width, self.height, 0, 0]]).astype(np.float32)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(H·W, 3) origins and unit directions in float64, row-major from the top-left pixel."""
        f, r, u, t = self.basis()
        x = (2 * (np.arange(self.width) + 0.5 + self.jitter[0]) / self.width - 1) * t * self.width / self.height
        y = (1 - 2 * (np.arange(self.height) + 0.5 + self.jitter[1]) / self.height) * t
        d = f[None, None] + x[None, :, None] * r + y[:, None, None] * u
        d = d.reshape(-1, 3)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.eye, d.shape).copy(), d


@dataclass(eq=False)
class DirectionalLight:
    """A distant disk emitter: `direction` points towards it; `irradiance` (RGB): its radiance integrated over
    its disc, ∫L dω, the irradiance it gives at normal incidence while it is small (a wide one gives ∫L cos θ dω
    there, less: its SG gives 0.985 of it at a 10° radius, 0.863 at 30°); `angular_radius` in degrees (the sun
    is 0.27°)."""

    direction: object = (0.0, 1.0, 0.0)
    irradiance: object = 1.0
    angular_radius: float = 2.0

    def __post_init__(self):
        self.direction = _unit("DirectionalLight.direction", self.direction)
        self.irradiance = _light_power("DirectionalLight.irradiance", self.irradiance)
        a = _number("DirectionalLight.angular_radius", self.angular_radius)
        if not (0 < a < 90):
            raise ValueError(f"DirectionalLight.angular_radius must lie in (0, 90) degrees, "
                             f"got {self.angular_radius!r}")
        self.angular_radius = a

    def packed(self) -> np.ndarray:
        """(8,) [0 (directional), direction, irradiance, solid angle]."""
        omega = np.pi * np.radians(self.angular_radius) ** 2
        return np.array([0, *self.direction, *self.irradiance, omega], np.float32)


@dataclass(eq=False)
class PointLight:
    """A small spherical emitter at `position` with `intensity` (RGB, W/sr) and `radius`."""

    position: object = (0.0, 4.0, 0.0)
    intensity: object = 10.0
    radius: float = 0.05

    def __post_init__(self):
        self.position = _vec3("PointLight.position", self.position)
        self.intensity = _light_power("PointLight.intensity", self.intensity)
        self.radius = _positive("PointLight.radius", self.radius)

    def packed(self) -> np.ndarray:
        """(8,) [1 (point), position, intensity, radius]."""
        return np.array([1, *self.position, *self.intensity, self.radius], np.float32)


def light_sg(packed: np.ndarray, x: np.ndarray):
    """The SG emitters of packed lights (L, 8) seen from points x (N, 3), in float64.

    → axis (N, L, 3), sharpness (N, L), amplitude (N, L, 3), distance (N, L) (inf for directional).
    η = 2π/Ω (Ω capped below at MIN_LIGHT_SOLID_ANGLE) and μ = E·η / (2π(1 − e^(−2η))) so ∫G = E.
    """
    packed = np.asarray(packed, np.float64).reshape(-1, 8)
    x = np.asarray(x, np.float64).reshape(-1, 3)
    n, n_l = len(x), len(packed)
    axis = np.zeros((n, n_l, 3))
    omega = np.zeros((n, n_l))
    power = np.zeros((n, n_l, 3))
    dist = np.full((n, n_l), np.inf)
    for k, row in enumerate(packed):
        if row[0] == 0:
            axis[:, k] = row[1:4]
            omega[:, k] = row[7]
            power[:, k] = row[4:7]
        else:
            d = row[1:4][None] - x
            dk = np.maximum(np.linalg.norm(d, axis=1), 1e-30)
            axis[:, k] = d / dk[:, None]
            omega[:, k] = np.pi * row[7] ** 2 / dk**2
            power[:, k] = row[4:7][None] / dk[:, None] ** 2
            dist[:, k] = dk
    eta = 2 * np.pi / np.maximum(omega, MIN_LIGHT_SOLID_ANGLE)
    amp = power * (eta / (2 * np.pi * -np.expm1(-2 * eta)))[..., None]
    return axis, eta, amp, dist


def vertex_tangents(mesh: Mesh) -> np.ndarray:
    """(V, 3) unit tangents ⟂ the vertex normals: the direction of increasing u of the UVs (Lengyel's
    per-face dP/du accumulated over each vertex's faces, faces across a UV seam excluded), which orients
    an anisotropic effective BRDF's tile x-axis on the surface. Where there are no UVs, or they are
    degenerate around a vertex, the tangent is the normal's projection of a fixed world axis (x, or z where
    the normal is along x)."""
    n = mesh.normals
    acc = np.zeros_like(mesh.vertices)
    if mesh.uvs is not None:
        p = mesh.vertices[mesh.faces]
        uv = mesh.uvs[mesh.faces]
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
        # Faces across a UV seam (a wrapped u or v jumps by most of the unit range, as on a closed torus or
        # sphere) have a meaningless dP/du: they are left out, their vertices take the other faces' tangents.
        span = np.ptp(uv, axis=1).max(axis=1)
        ok = (np.abs(det) > 1e-20) & (span < 0.5)
        t = np.where(ok[:, None], (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / np.where(ok, det, 1.0)[:, None], 0.0)
        t *= np.linalg.norm(np.cross(e1, e2), axis=1)[:, None] / np.maximum(np.linalg.norm(t, axis=1), 1e-300)[:, None]
        for k in range(3):
            np.add.at(acc, mesh.faces[:, k], t)
    acc -= n * np.einsum("ij,ij->i", acc, n)[:, None]
    length = np.linalg.norm(acc, axis=1)
    ref = np.where((np.abs(n[:, 0]) < 0.9)[:, None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    fallback = ref - n * np.einsum("ij,ij->i", ref, n)[:, None]
    fallback /= np.linalg.norm(fallback, axis=1, keepdims=True)
    big = length > 1e-8 * max(length.max(initial=0.0), 1e-300)
    return np.where(big[:, None], acc / np.where(big, length, 1.0)[:, None], fallback)


SSDF_RESOLUTIONS = (2, 128)  # the SSDF's octahedral grid, resolution² directions: at least one per quadrant


SETTINGS_UNITS = {"env_lobes": " (the SG lighting kernels' lobe count)",
                  "ssdf_resolution": " (SSDF directions per side)", "ssdf_terms": " (at most ssdf_resolution²)"}


SSDF_TERMS = 16  # the SSDF's PCA terms by default (Wang §5.7)


def settings_ranges(ssdf_resolution=32) -> dict:
    """The valid (lo, hi) of Scene's env_lobes, ssdf_resolution and ssdf_terms (at most the texel count
    ssdf_resolution², computed from the given resolution when it is an in-range integer): checked by Scene
    and, with the file's line, by scene files' [render]."""

    try:
        s = int(ssdf_resolution)
        s = s if s == ssdf_resolution and SSDF_RESOLUTIONS[0] <= s <= SSDF_RESOLUTIONS[1] else SSDF_RESOLUTIONS[1]
    except (TypeError, ValueError, OverflowError):
        s = SSDF_RESOLUTIONS[1]
    return {"env_lobes": (1, KERNEL_LOBES), "ssdf_resolution": SSDF_RESOLUTIONS, "ssdf_terms": (1, s * s)}


@dataclass(eq=False)
class Scene:
    """What to render: one mesh (merge several with `Mesh.merge`; each face's `face_material` indexes
    `materials`), analytic `Brdf`s or baked `EffectiveBRDF`s, a camera, an environment (None: black)
    and point/directional lights. `env_lobes` SG lobes fit the environment for the diffuse term (9 as
    Iwasaki §5); the SSDF has `ssdf_resolution`² directions and `ssdf_terms` PCA terms (by default 16, or
    ssdf_resolution² where that is fewer)."""

    mesh: Mesh
    materials: list
    camera: Camera = field(default_factory=Camera)
    environment: Environment | None = None
    lights: list = field(default_factory=list)
    env_lobes: int = 9
    ssdf_resolution: int = 32
    ssdf_terms: int | None = None  # None: SSDF_TERMS, or ssdf_resolution² where that is fewer
    cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):

        if not isinstance(self.mesh, Mesh):
            raise ValueError(f"Scene.mesh must be a Mesh, got {type(self.mesh).__name__}")
        if isinstance(self.materials, (Brdf, EffectiveBRDF, Textured, LitSphere)):
            self.materials = [self.materials]
        self.materials = list(self.materials)
        for i, m in enumerate(self.materials):
            if not isinstance(m, (Brdf, EffectiveBRDF, Textured, LitSphere)):
                raise ValueError(f"Scene.materials[{i}] must be a BRDF, a Textured BRDF, an EffectiveBRDF or a "
                                 f"LitSphere, got {m!r}")
        used = int(self.mesh.face_material.max()) + 1
        if used > len(self.materials):
            raise ValueError(f"the mesh uses material ids 0..{used - 1} but the scene has {len(self.materials)} "
                             "material(s)")
        if self.mesh.uvs is None:  # a texture lookup needs the surface's (u, v)
            for i in np.unique(self.mesh.face_material):
                if isinstance(self.materials[i], Textured):
                    raise ValueError(f"Scene.materials[{i}] ({self.materials[i]!r}) is textured but the mesh has no "
                                     "UVs (Mesh.uvs is None): give the mesh texture coordinates")
        if not isinstance(self.camera, Camera):
            raise ValueError(f"Scene.camera must be a Camera, got {type(self.camera).__name__}")
        if self.environment is not None and not isinstance(self.environment, Environment):
            raise ValueError(f"Scene.environment must be an Environment or None, got {type(self.environment).__name__}")
        self.lights = list(self.lights)
        for i, light in enumerate(self.lights):
            if not isinstance(light, (PointLight, DirectionalLight)):
                raise ValueError(f"Scene.lights[{i}] must be a PointLight or DirectionalLight, got {light!r}")
            if isinstance(light, PointLight):  # its SG and its shadow rays see it from outside its sphere
                d = self.mesh.distance_to(light.position, within=light.radius)
                if d < light.radius:
                    raise ValueError(f"Scene.lights[{i}]: the PointLight of radius {light.radius:g} at "
                                     f"{tuple(float(x) for x in light.position)} reaches into the mesh (a face "
                                     f"{d:.3g} from its centre): a light must lie outside the objects")
        if self.ssdf_terms is None:  # (a coarse SSDF alone must not be refused over a default it cannot hold)
            res = self.ssdf_resolution
            fits = isinstance(res, (int, np.integer)) and not isinstance(res, bool) and res >= 1
            self.ssdf_terms = min(SSDF_TERMS, int(res) ** 2) if fits else SSDF_TERMS
        for name, (lo, hi) in settings_ranges(self.ssdf_resolution).items():
            setattr(self, name, _integer(f"Scene.{name}", getattr(self, name), lo, hi, SETTINGS_UNITS[name]))

    @property
    def lights_packed(self) -> np.ndarray:
        return (np.stack([light.packed() for light in self.lights]) if self.lights
                else np.zeros((0, 8), np.float32))


@dataclass(eq=False)
class Rendering:
    """A rendered image: `image` (H, W, 3) float32 linear radiance, `timings` (s per stage), `info`."""

    image: np.ndarray
    timings: dict
    info: dict

    def save(self, path, exposure: float = 0.0) -> None:
        """Write .exr / .hdr (linear float) or .png (tone-mapped), atomically."""
        check_output(path, (".exr", ".hdr", ".pic", ".png"), "image file")
        write_image(path, self.image, exposure=exposure)


def _black_environment() -> Environment:
    return Environment(np.zeros((2, 4, 3), np.float32), name="black")
