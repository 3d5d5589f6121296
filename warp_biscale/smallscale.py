"""Small-scale geometry: one period of a surface, tiled infinitely in x and y, z up.

`SmallScale` is the contract between the geometry front end (trimesh files, procedural generators)
and every stage after it. Construction validates and cleans the mesh once, so the kernels can
assume finite coordinates, non-degenerate triangles and in-range indices.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .io import atomic_path, check_output

__all__ = ["SmallScale", "TileWarning"]

# The suffixes `SmallScale.save` writes: the trimesh exporters that take a triangle mesh into one file that
# `SmallScale.load` reads back (.gltf writes its buffers as further files beside it, .3mf and .dae need
# optional packages, .xyz holds points only).
SAVE_FORMATS = (".obj", ".ply", ".stl", ".off", ".glb")


class TileWarning(UserWarning):
    """Something in a tile was repaired or looks suspicious (dropped triangles, unmatched edges)."""


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis of (..., 3) arrays (broadcast): np.cross's arithmetic (the same bits)
    without its axis handling, which costs several times the arithmetic on the few rows of a procedural tile or
    a bake's few ASG lobes."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def row_norms(a: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of an (N, 3) array (np.linalg.norm(a, axis=1)'s sum of squares)."""
    return np.sqrt((a * a).sum(axis=1))


def _finite_array(name: str, value, shape_tail: tuple, dtype) -> np.ndarray:
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim != 1 + len(shape_tail) or tuple(arr.shape[1:]) != shape_tail:
        want = "(N, " + ", ".join(str(s) for s in shape_tail) + ")" if shape_tail else "(N,)"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if np.issubdtype(arr.dtype, np.floating):
        bad = ~np.isfinite(arr)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ValueError(f"{name} contains NaN or inf (first at row {row}: {arr[row].tolist()})")
    return arr


def mesh_read_reason(exc: Exception) -> str:
    """Why trimesh could not read a mesh file, in a user's words where its own are numpy's (a face naming a
    vertex the file lacks surfaces as numpy's IndexError)."""
    if isinstance(exc, IndexError):
        return f"a face refers to a vertex the file does not have ({exc})"
    return str(exc)


TILE_SCALE_MIN, TILE_SCALE_MAX = 1e-12, 1e12  # float32 kernels: beyond, areas and squared lengths overflow or vanish


@dataclass(eq=False)
class SmallScale:
    """One period of a small-scale surface, tiled in x and y (z up). Immutable once built (its
    arrays are read-only): to edit a tile, build a new one.

    Parameters
    ----------
    vertices : (V, 3) float
        Vertex positions in the tile frame. Must be finite.
    faces : (F, 3) int
        Triangles as vertex indices. Zero-area and degenerate triangles are dropped with a
        `TileWarning`; duplicate vertices are merged with a `TileWarning`.
    material_ids : (F,) int, optional
        Material index per face (default 0). Indexes the list of small-scale BRDFs given to the
        pipeline; must be ≥ 0.
    colors : (F, 3) float, optional
        RGB colour weight per face (Wu §3.7), default (1, 1, 1). Must be finite and ≥ 0.
    period : (Px, Py), optional
        Tile period; default the xy extent of the vertices.
    origin : (x0, y0), optional
        Lower corner of the tile's cell, which occupies [origin, origin + period] in x and y;
        default the xy minimum of the vertices. Give it with `period` when the geometry does not
        reach the cell's boundary (rods standing free in their cell, say).
    vertex_normals : (V, 3) float, optional
        Per-vertex shading normals, interpolated across faces (Wu §3.2). If absent, facets use the
        face normal.
    name : str
        A label used in messages and plots.
    face_tangents : (F, 3) float, optional
        Per-face tangent direction, the x axis of the facet frame of anisotropic small-scale BRDFs
        (`brdf.AnisotropicWard`, `brdf.AshikhminShirley`; isotropic ones ignore it). Each row is
        projected onto its face's plane and normalised; a row (nearly) parallel to its face normal is
        an error. Default (`default_face_tangents`): the tile's +x axis projected onto each face's
        plane, or, where a face's normal lies within 0.01 rad of ±x (a wall facing x, whose plane
        holds no direction near x), +y projected instead. The procedural tiles set their own:
        along the grooves (`geometry.grooves`), along each thread (`geometry.woven`). Only the
        tangent's line matters (the BRDFs are even in it), not its sign. A facet's frame is this
        tangent made perpendicular to the facet's (possibly interpolated) normal (`brdf.tangent_frame`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    material_ids: np.ndarray | None = None
    colors: np.ndarray | None = None
    period: tuple | None = None
    vertex_normals: np.ndarray | None = None
    name: str = "tile"
    origin: np.ndarray | None = None
    face_tangents: np.ndarray | None = None

    def __post_init__(self):
        v = _finite_array("vertices", self.vertices, (3,), np.float64)
        f = np.asarray(self.faces)
        if f.size == 0:
            raise ValueError(f"tile {self.name!r} has no faces")
        if not np.issubdtype(f.dtype, np.integer):
            if not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
                raise ValueError("faces must hold integer vertex indices")
        f = _finite_array("faces", f.astype(np.int64), (3,), np.int64)
        if len(v) == 0:
            raise ValueError(f"tile {self.name!r} has no vertices")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"faces index vertices out of range [0, {len(v)}): min {f.min()}, max {f.max()}")
        nf = len(f)
        mat = np.zeros(nf, np.int32) if self.material_ids is None else np.asarray(self.material_ids)
        if mat.shape != (nf,):
            raise ValueError(f"material_ids must have shape ({nf},) (one per face), got {mat.shape}")
        if not np.issubdtype(mat.dtype, np.integer):
            if not np.all(np.isfinite(mat)) or np.any(mat != np.round(mat)):
                raise ValueError("material_ids must be integers")
        mat = mat.astype(np.int32)
        if mat.min() < 0:
            raise ValueError(f"material_ids must be >= 0, got {int(mat.min())}")
        col = np.ones((nf, 3)) if self.colors is None else np.asarray(self.colors, np.float64)
        if col.ndim == 1 and col.shape == (3,):
            col = np.broadcast_to(col, (nf, 3)).copy()
        col = _finite_array("colors", col, (3,), np.float64)
        if len(col) != nf:
            raise ValueError(f"colors must have one RGB row per face ({nf}), got {len(col)}")
        if (col < 0).any():
            raise ValueError("colors must be >= 0 (they are RGB weights)")
        vn = None
        if self.vertex_normals is not None:
            vn = _finite_array("vertex_normals", self.vertex_normals, (3,), np.float64)
            if len(vn) != len(v):
                raise ValueError(f"vertex_normals must have one row per vertex ({len(v)}), got {len(vn)}")
            ln = np.linalg.norm(vn, axis=1)
            if (ln < 1e-12).any():
                raise ValueError(f"vertex_normals has a zero-length normal at vertex {int(np.argmin(ln))}")
            vn = vn / ln[:, None]

        tan = None
        if self.face_tangents is not None:
            tan = _finite_array("face_tangents", self.face_tangents, (3,), np.float64)
            if len(tan) != nf:
                raise ValueError(f"face_tangents must have one row per face ({nf}), got {len(tan)}")

        v, f, vn = self._merge_duplicates(v, f, vn)
        keep = self._nondegenerate(v, f)
        if not keep.all():
            warnings.warn(
                f"tile {self.name!r}: dropped {int((~keep).sum())} zero-area or degenerate triangle(s)",
                TileWarning,
                stacklevel=3,
            )
            f, mat, col = f[keep], mat[keep], col[keep]
            tan = tan[keep] if tan is not None else None
            if len(f) == 0:
                raise ValueError(f"tile {self.name!r} has no faces with non-zero area")
        # Drop vertices no face uses, so bounds describe the surface.
        used = np.unique(f)
        remap = np.full(len(v), -1, np.int64)
        remap[used] = np.arange(len(used))
        v, f = v[used], remap[f]
        vn = vn[used] if vn is not None else None

        lo, hi = v.min(axis=0), v.max(axis=0)
        if self.period is None:
            period = hi[:2] - lo[:2]
        else:
            period = np.asarray(self.period, np.float64).reshape(-1)
            if period.shape != (2,) or not np.all(np.isfinite(period)):
                raise ValueError(f"period must be two finite numbers (Px, Py), got {self.period!r}")
        if (period <= 0).any():
            raise ValueError(
                f"tile period must be > 0 in x and y, got {tuple(period.tolist())}"
                " (a tile needs an xy extent; give period= explicitly for a degenerate footprint)"
            )
        reach = float(np.abs(v).max())
        if reach > TILE_SCALE_MAX or period.max() < TILE_SCALE_MIN:
            raise ValueError(  # (beyond, float32 kernels overflowed their areas and squared lengths or lost them)
                f"tile {self.name!r} spans {period.max():.3g} with coordinates up to {reach:.3g}: the kernels, in "
                f"float32, take a period of at least {TILE_SCALE_MIN:g} and coordinates up to {TILE_SCALE_MAX:g} "
                "(rescale it: a tile's size does not change its effective BRDF)"
            )
        self.vertices, self.faces = v, f.astype(np.int32)
        self.material_ids, self.colors, self.vertex_normals = mat, col, vn
        self.period = (float(period[0]), float(period[1]))
        if self.origin is None:
            self.origin = lo[:2].copy()
        else:
            origin = np.asarray(self.origin, np.float64).reshape(-1)
            if origin.shape != (2,) or not np.all(np.isfinite(origin)):
                raise ValueError(f"origin must be two finite numbers (x0, y0), got {self.origin!r}")
            self.origin = origin
        outside = (v[:, :2] < self.origin - 1e-9 * max(self.period)) | (
            v[:, :2] > self.origin + period + 1e-9 * max(self.period))
        if outside.any():
            row = int(np.argwhere(outside.any(axis=1))[0][0])
            raise ValueError(
                f"vertex {row} {v[row].tolist()} lies outside the tile cell [{self.origin.tolist()}, "
                f"{(self.origin + period).tolist()}] given by origin and period"
            )
        self._check_edges()
        # A tile is immutable once built: backends cache device copies (and a BVH) per tile object,
        # so an edited tile must be a new SmallScale. Face geometry is computed once here.
        t = self.vertices[self.faces]
        cross = cross_rows(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = row_norms(cross)
        self._face_areas = 0.5 * norm
        self._face_normals = cross / norm[:, None]
        if not (self._face_normals[:, 2] > 0).any():  # (a mesh wound the other way round, or given upside down)
            warnings.warn(f"tile {self.name!r}: no face looks up (+z): seen from above the surface shows only "
                          "backs, and its effective BRDF is 0 (turn it over or reverse its faces' winding)",
                          TileWarning, stacklevel=3)
        elif vn is not None and not (vn[self.faces].sum(1)[:, 2] > 0).any():  # (the file's normals flipped)
            warnings.warn(f"tile {self.name!r}: no vertex normal looks up (+z): the facets, shaded by them, face "
                          "down, and its effective BRDF is 0 (negate the normals, or drop them to shade by the "
                          "faces)", TileWarning, stacklevel=3)
        if tan is None:
            self.face_tangents = default_face_tangents(self._face_normals)
        else:
            self.face_tangents = _tangents_in_planes(tan, self._face_normals, np.flatnonzero(keep))
        for arr in (self.vertices, self.faces, self.material_ids, self.colors, self.vertex_normals, self.origin,
                    self._face_areas, self._face_normals, self.face_tangents):
            if arr is not None:
                arr.flags.writeable = False

    # ----------------------------------------------------------------------------- cleaning
    @staticmethod
    def _merge_duplicates(v, f, vn):
        scale = max(float(np.ptp(v, axis=0).max()), 1e-30)
        key = np.round(v / (scale * 1e-9)).astype(np.int64)
        if vn is not None:
            key = np.concatenate([key, np.round(vn * 1e6).astype(np.int64)], axis=1)
        # The rows sorted (lexsort: np.unique(axis=0)'s order, several times faster on int rows) and the first
        # of each run of equal rows kept, as np.unique(axis=0, return_index=True, return_inverse=True).
        order = np.lexsort(key.T[::-1])
        srt = key[order]
        new = np.r_[True, (srt[1:] != srt[:-1]).any(axis=1)]
        first = order[new]
        inverse = np.empty(len(v), np.int64)
        inverse[order] = np.cumsum(new) - 1
        if len(first) < len(v):
            warnings.warn(f"merged {len(v) - len(first)} duplicate vertex/vertices", TileWarning, stacklevel=4)
            v = v[first]
            vn = vn[first] if vn is not None else None
            f = inverse[f]
        return v, f, vn

    @staticmethod
    def _nondegenerate(v, f):
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        area2 = row_norms(cross_rows(b - a, c - a))
        longest = np.max([row_norms(b - a), row_norms(c - b), row_norms(a - c)], axis=0)
        repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
        # A sliver whose height is below 1e-7 of its longest edge has no trustworthy normal.
        return ~repeated & (area2 > 1e-7 * longest**2) & (area2 > 0)

    def _check_edges(self):
        """Warn if the profile on opposite tile edges differs (the tile then has seams)."""
        v = self.vertices
        tol = 1e-6 * max(self.period)
        for axis, other in ((0, 1), (1, 0)):
            lo = self.origin[axis]
            hi = lo + self.period[axis]
            left = v[np.abs(v[:, axis] - lo) < tol][:, [other, 2]]
            right = v[np.abs(v[:, axis] - hi) < tol][:, [other, 2]]
            if len(left) == 0 and len(right) == 0:
                continue
            if len(left) == 0 or len(right) == 0 or not (_covered(left, right, tol) and _covered(right, left, tol)):
                warnings.warn(
                    f"tile {self.name!r}: the edges at {'xy'[axis]}={lo:g} and {'xy'[axis]}={hi:g} do not match; "
                    "the tiled surface has seams (visibility still treats it as periodic)",
                    TileWarning,
                    stacklevel=4,
                )

    # ----------------------------------------------------------------------------- properties
    @property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) vertex positions of every face."""
        return self.vertices[self.faces]

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit geometric normals (right-handed winding)."""
        return self._face_normals

    @property
    def face_areas(self) -> np.ndarray:
        """(F,) triangle areas."""
        return self._face_areas

    @property
    def area(self) -> float:
        return float(self._face_areas.sum())

    @property
    def z_range(self) -> tuple[float, float]:
        return float(self.vertices[:, 2].min()), float(self.vertices[:, 2].max())

    @property
    def footprint(self) -> float:
        """Projected (xy) area of one period: the denominator of a flat tile's a_v."""
        return self.period[0] * self.period[1]

    @property
    def corner(self) -> np.ndarray:
        """(x0, y0, z_lo): the tile's lowest corner, origin of the frame the kernels trace in."""
        return np.array([self.origin[0], self.origin[1], self.z_range[0]])

    def to_local(self, points) -> np.ndarray:
        """float32 coordinates relative to `corner`, shifted in float64 before the cast.

        A tile modelled at (1000, −1000, 100) would otherwise lose ~6e-5 to float32 rounding, more
        than the ray offset (1e-5 of the tile size), and self-shadow at random. The backends trace
        in this frame: the tile's cell is [0, Px] × [0, Py] and its height range [0, z_hi − z_lo].
        """
        return (np.asarray(points, np.float64) - self.corner).astype(np.float32)

    def from_local(self, points) -> np.ndarray:
        """Inverse of `to_local` (float32 out, as the facets are)."""
        return (np.asarray(points, np.float64) + self.corner).astype(np.float32)

    @property
    def n_materials(self) -> int:
        return int(self.material_ids.max()) + 1

    def __repr__(self):
        return (
            f"SmallScale({self.name!r}, {len(self.vertices)} vertices, {len(self.faces)} faces, "
            f"period={self.period}, z={self.z_range}, materials={self.n_materials})"
        )

    # ----------------------------------------------------------------------------- I/O
    @classmethod
    def load(cls, path, period=None, material_ids=None, colors=None, name=None) -> SmallScale:
        """Load a triangle mesh (OBJ, PLY, STL, GLB, ...) through trimesh as one tile period.

        Vertex normals stored in the file are used (interpolated across faces); otherwise facets use
        face normals. Face tangents stored in a PLY file as the face properties tangent_x, tangent_y,
        tangent_z (what `save` writes) are used; otherwise the default (`default_face_tangents`); so are its
        material_id and color_r/g/b face properties, unless `material_ids` or `colors` is given. Scenes
        with several meshes are concatenated, each mesh getting the next material id unless
        `material_ids` is given.
        """
        import trimesh  # (on first use: importing it takes a second of every process's start)

        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"tile file not found: {path}")
        try:
            loaded = trimesh.load(path, process=False, maintain_order=True)
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ValueError(f"could not read tile mesh {path!r}: {mesh_read_reason(exc)}") from exc
        meshes = list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene) else [loaded]
        meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh) and len(m.faces)]
        if not meshes:
            raise ValueError(f"{path!r} holds no triangle mesh with faces")
        verts, faces, mats, normals = [], [], [], []
        offset = 0
        has_normals = all(_file_has_vertex_normals(m) for m in meshes)
        tangents = [_file_face_tangents(m) for m in meshes]
        colours = []
        for k, m in enumerate(meshes):
            verts.append(np.asarray(m.vertices, np.float64))
            faces.append(np.asarray(m.faces, np.int64) + offset)
            ids = _file_face_properties(m, (_MATERIAL_PROPERTY,))
            mats.append(np.full(len(m.faces), k, np.int32) if ids is None or len(meshes) > 1
                        else ids[:, 0].astype(np.int32))
            colours.append(_file_face_properties(m, _COLOR_PROPERTIES))
            if has_normals:
                normals.append(np.asarray(m.vertex_normals, np.float64))
            offset += len(m.vertices)
        try:
            return cls(
                np.concatenate(verts),
                np.concatenate(faces),
                material_ids=np.concatenate(mats) if material_ids is None else material_ids,
                colors=colors if colors is not None or any(c is None for c in colours) else np.concatenate(colours),
                period=period,
                vertex_normals=np.concatenate(normals) if has_normals else None,
                name=name or os.path.splitext(os.path.basename(path))[0],
                face_tangents=np.concatenate(tangents) if all(t is not None for t in tangents) else None,
            )
        except ValueError as exc:  # (the tile's own checks: say which file they were made on)
            raise ValueError(f"tile mesh {path!r}: {exc}") from None

    def save(self, path) -> None:
        """Write the tile as a mesh file (format from the extension), atomically. A .ply file also keeps each
        face's material id, colour weight and tangent (face properties material_id, color_r/g/b and
        tangent_x/y/z, which `load` reads back); other formats have no place for them: the tile reloads as one
        white material with the default tangents, and saving a tile that has several ids or colours there
        warns (TileWarning)."""
        # Checked before trimesh is imported: trimesh's own errors for a bad suffix or path are cryptic
        # ("object must be PointCloud", "exporter not available") or name the temporary file.
        check_output(path, SAVE_FORMATS, "tile mesh file")
        import trimesh

        fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower()
        if fmt != "ply" and (self.n_materials > 1 or not np.all(self.colors == 1.0)):
            warnings.warn(f"tile {self.name!r} saved as .{fmt}: its {self.n_materials} material id(s) and colour "
                          "weights are not kept (a .ply keeps them)", TileWarning, stacklevel=2)
        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        if self.vertex_normals is not None:
            mesh.vertex_normals = self.vertex_normals
        mesh.face_attributes[_MATERIAL_PROPERTY] = np.ascontiguousarray(self.material_ids, np.int32)
        for axis, name in enumerate(_COLOR_PROPERTIES):
            mesh.face_attributes[name] = np.ascontiguousarray(self.colors[:, axis], np.float64)
        for axis, name in enumerate(_TANGENT_PROPERTIES):
            mesh.face_attributes[name] = np.ascontiguousarray(self.face_tangents[:, axis])
        with atomic_path(path) as tmp:
            mesh.export(tmp, file_type=os.path.splitext(os.fspath(path))[1].lstrip(".").lower())


# A tangent whose part in its face's plane has squared length below this (relative: it lies within 0.01 rad of
# the normal) names no direction in the face; the same bound as brdf.TANGENT_DEGENERATE for a facet's frame.
TANGENT_DEGENERATE = 1e-4


def default_face_tangents(face_normals) -> np.ndarray:
    """(F, 3) unit tangents: the tile's +x axis projected onto each face's plane, or +y projected where the face
    normal lies within 0.01 rad of ±x (|x − (x·n)n|² < TANGENT_DEGENERATE: a wall facing ±x, whose plane holds
    no direction near x; +y then lies in it to within 0.01 rad). Well defined for every unit normal, and
    continuous except across that small cone about ±x."""
    n = np.asarray(face_normals, np.float64)
    t = np.zeros_like(n)
    t[:, 0] = 1.0
    t -= n[:, 0:1] * n
    bad = np.einsum("ij,ij->i", t, t) < TANGENT_DEGENERATE
    if bad.any():
        y = np.zeros((int(bad.sum()), 3))
        y[:, 1] = 1.0
        t[bad] = y - n[bad, 1:2] * n[bad]
    return t / row_norms(t)[:, None]


def _tangents_in_planes(tangents, face_normals, rows) -> np.ndarray:
    """Given tangents projected onto their faces' planes and normalised; `rows` maps each face back to the row
    of the caller's array (for the error)."""
    t = tangents - np.einsum("ij,ij->i", tangents, face_normals)[:, None] * face_normals
    l2 = np.einsum("ij,ij->i", t, t)
    bad = l2 <= TANGENT_DEGENERATE * np.einsum("ij,ij->i", tangents, tangents)  # (a zero row too)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"face_tangents row {int(rows[i])} {tangents[i].tolist()} is (nearly) parallel to its face's "
                         f"normal {face_normals[i].round(6).tolist()}: a tangent must lie across the normal")
    return t / np.sqrt(l2)[:, None]


def _covered(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Every 2-D point of `a` lies on the polyline through the points of `b` sorted by first coord.

    A heuristic: it accepts matching vertex sets at once, and otherwise lets the opposite edge
    be tessellated differently. Where an edge crosses several separate pieces (woven tubes), the
    sorted polyline joins unrelated points, so it errs towards no warning.
    """
    if len(a) * len(b) <= 4096:  # a few edge vertices: every distance, cheaper than building a KD-tree
        dist = np.sqrt(((a[:, None, :] - b[None]) ** 2).sum(-1)).min(axis=1)
    else:
        dist, _ = cKDTree(b).query(a)
    if np.all(dist < 10 * tol):  # the common case: the same boundary vertices on both edges
        return True
    b = b[np.lexsort((b[:, 1], b[:, 0]))]
    if len(b) == 1:
        return False
    p0, p1 = b[:-1], b[1:]
    d = p1 - p0
    dd = np.maximum((d * d).sum(1), 1e-300)
    for start in range(0, len(a), 256):  # chunks keep memory at 256 × len(b)
        ac = a[start:start + 256]
        t = np.clip(((ac[:, None, :] - p0[None]) * d[None]).sum(-1) / dd[None], 0.0, 1.0)
        near = p0[None] + t[..., None] * d[None]
        if not np.all(np.sqrt(((ac[:, None, :] - near) ** 2).sum(-1)).min(axis=1) < 10 * tol):
            return False
    return True


_TANGENT_PROPERTIES = ("tangent_x", "tangent_y", "tangent_z")  # the PLY face properties of the face tangents
_MATERIAL_PROPERTY = "material_id"  # ... of the faces' material ids
_COLOR_PROPERTIES = ("color_r", "color_g", "color_b")  # ... of their RGB colour weights


def _file_face_properties(mesh, names):
    """(F, len(names)) float64 face properties a PLY file carried, else None. trimesh hands a PLY file's extra
    properties back only in metadata["_ply_raw"] (its raw elements)."""
    try:
        data = mesh.metadata["_ply_raw"]["face"]["data"]
        if len(data) != len(mesh.faces):
            return None
        return np.stack([np.asarray(data[name], np.float64).reshape(-1) for name in names], 1)
    except (KeyError, TypeError, ValueError, IndexError):
        return None


def _file_face_tangents(mesh):
    """(F, 3) face tangents a PLY file carried as face properties tangent_x/y/z, else None."""
    return _file_face_properties(mesh, _TANGENT_PROPERTIES)


def _file_has_vertex_normals(mesh) -> bool:
    """trimesh computes vertex normals on demand; only trust ones the file carried."""
    cache = getattr(mesh, "_cache", None)
    try:
        return "vertex_normals" in cache.cache and cache.cache["vertex_normals"] is not None
    except Exception:
        return False


def ray_offset(tile) -> float:
    """Distance a ray origin is lifted off its facet along the face normal.

    1e-5 of the tile's largest dimension: far above float32 rounding of positions (~1e-7
    relative), far below any feature a designer builds. Derived from the tile, never a user knob.
    """
    zlo, zhi = tile.z_range
    return 1e-5 * max(tile.period[0], tile.period[1], zhi - zlo)
