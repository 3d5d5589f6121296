"""SmallScale validation: clear errors naming the bad input, repairs with warnings, file loading."""

import warnings

import numpy as np
import pytest
import trimesh
from conftest import random_heightfield

import warp_biscale as wb

QUAD_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])


def test_nan_and_inf_rejected_with_row():
    v = QUAD_V.copy()
    v[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"vertices contains NaN or inf \(first at row 2"):
        wb.SmallScale(v, QUAD_F)
    v[2, 1] = np.inf
    with pytest.raises(ValueError, match="vertices contains NaN or inf"):
        wb.SmallScale(v, QUAD_F)
    with pytest.raises(ValueError, match="colors contains NaN"):
        wb.SmallScale(QUAD_V, QUAD_F, colors=np.array([[1, 1, 1], [np.nan, 1, 1]]))
    with pytest.raises(ValueError, match="vertex_normals contains NaN"):
        wb.SmallScale(QUAD_V, QUAD_F, vertex_normals=np.full((4, 3), np.nan))


@pytest.mark.parametrize("kwargs, match", [
    (dict(faces=np.zeros((0, 3), int)), "has no faces"),
    (dict(faces=np.array([[0, 1, 7]])), "out of range"),
    (dict(material_ids=np.array([0, -1])), "material_ids must be >= 0"),
    (dict(material_ids=np.array([0, 1, 2])), "one per face"),
    (dict(colors=np.array([[1, 1, -1], [1, 1, 1]])), "colors must be >= 0"),
    (dict(period=(1.0, 0.0)), "period must be > 0"),
    (dict(period=(1.0,)), "period must be two"),
    (dict(vertices=np.zeros((4, 2))), r"vertices must have shape \(N, 3\)"),
])
def test_bad_inputs_named(kwargs, match):
    args = dict(vertices=QUAD_V, faces=QUAD_F)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        wb.SmallScale(**args)


def test_degenerate_triangles_dropped_with_warning():
    v = np.vstack([QUAD_V, [[0.5, 0.5, 0.0]]])
    faces = np.vstack([QUAD_F, [[0, 1, 1]], [[0, 4, 2]], [[0, 1, 0]]])  # repeated index, collinear, repeated
    with pytest.warns(wb.TileWarning, match="dropped 3 zero-area or degenerate"):
        tile = wb.SmallScale(v, faces, material_ids=np.array([0, 1, 2, 3, 4]))
    assert len(tile.faces) == 2
    np.testing.assert_array_equal(tile.material_ids, [0, 1])  # per-face data follows the faces kept
    np.testing.assert_allclose(tile.area, 1.0)


def test_all_degenerate_is_an_error():
    with pytest.raises(ValueError, match="no faces with non-zero area"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wb.SmallScale(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), np.array([[0, 1, 2]]), period=(1, 1))


def test_duplicate_vertices_merged_with_warning():
    # Two triangles that do not share vertex indices (a "triangle soup").
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    with pytest.warns(wb.TileWarning, match="merged 2 duplicate"):
        tile = wb.SmallScale(v, np.array([[0, 1, 2], [3, 4, 5]]))
    assert len(tile.vertices) == 4 and len(tile.faces) == 2


def test_clean_tile_emits_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tile = random_heightfield(n=5)
    assert tile.period == (1.0, 1.0)
    np.testing.assert_allclose(tile.origin, [0, 0])


def test_period_defaults_to_xy_extent_and_can_be_given():
    tile = wb.SmallScale(QUAD_V * [2, 3, 1], QUAD_F)
    assert tile.period == (2.0, 3.0)
    with pytest.warns(wb.TileWarning):  # a 1×1 quad in a 2×2 period has unmatched edges
        big = wb.SmallScale(QUAD_V, QUAD_F, period=(2.0, 2.0))
    assert big.period == (2.0, 2.0) and big.footprint == 4.0


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "glb"])
def test_load_formats(tmp_path, ext):
    tile = random_heightfield(n=4, seed=3)
    mesh = trimesh.Trimesh(tile.vertices, tile.faces, process=False)
    path = tmp_path / f"tile.{ext}"
    mesh.export(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wb.TileWarning)  # STL stores a triangle soup: merged
        back = wb.SmallScale.load(path)
    np.testing.assert_allclose(back.area, tile.area, rtol=1e-6)
    np.testing.assert_allclose(back.z_range, tile.z_range, rtol=1e-6, atol=1e-7)
    assert back.period == pytest.approx(tile.period)
    assert back.name == "tile"


def test_load_uses_file_vertex_normals(tmp_path):
    tile = random_heightfield(n=4, seed=3)
    vn = tile.vertices - [0.5, 0.5, -2.0]
    vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    path = tmp_path / "curved.obj"
    mesh = trimesh.Trimesh(tile.vertices, tile.faces, vertex_normals=vn, process=False)
    path.write_text(trimesh.exchange.obj.export_obj(mesh, include_normals=True))
    back = wb.SmallScale.load(path)
    assert back.vertex_normals is not None
    np.testing.assert_allclose(np.abs(back.vertex_normals).sum(), np.abs(vn).sum(), rtol=1e-4)
    # A file without normals gives face normals.
    plain = tmp_path / "plain.obj"
    plain.write_text(trimesh.exchange.obj.export_obj(mesh, include_normals=False))
    assert wb.SmallScale.load(plain).vertex_normals is None


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="tile file not found"):
        wb.SmallScale.load(tmp_path / "nope.obj")
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="bad.obj"):
        wb.SmallScale.load(bad)
    # a face naming a vertex the file lacks: said in those words (numpy's IndexError beneath), for a tile and a mesh
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    for load in (wb.SmallScale.load, wb.Mesh.load):
        with pytest.raises(ValueError, match="bad.obj.*a face refers to a vertex the file does not have"):
            load(bad)
    ply = tmp_path / "bad.ply"  # (a PLY's bad index surfaces later, in the mesh's normals: said alike)
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(ValueError, match="bad.ply.*a face refers to a vertex the file does not have"):
        wb.Mesh.load(ply)
    with pytest.raises(ValueError, match="bad.ply"):
        wb.SmallScale.load(ply)


def test_save_round_trip(tmp_path):
    tile = random_heightfield(n=3, seed=2)
    tile.save(tmp_path / "t.ply")
    back = wb.SmallScale.load(tmp_path / "t.ply")
    np.testing.assert_allclose(back.area, tile.area, rtol=1e-6)


def test_a_ply_keeps_material_ids_and_colours_other_formats_warn(tmp_path):
    """A .ply keeps each face's material id and colour weight (face properties, as its tangents): a two-material
    woven tile comes back as two materials in their colours, not one white one. A format with no place for them
    warns when the tile has several ids or colours; a one-material white tile saves there silently."""
    tile = wb.geometry.woven(warp_color=(0.9, 0.25, 0.2), weft_color=(0.2, 0.35, 0.9))
    assert tile.n_materials == 2 and not np.all(tile.colors == 1.0)
    tile.save(tmp_path / "w.ply")
    back = wb.SmallScale.load(tmp_path / "w.ply")
    np.testing.assert_array_equal(back.material_ids, tile.material_ids)
    np.testing.assert_array_equal(back.colors, tile.colors)
    with pytest.warns(wb.TileWarning, match="saved as .obj: its 2 material id.s. and colour weights are not kept"):
        tile.save(tmp_path / "w.obj")
    assert wb.SmallScale.load(tmp_path / "w.obj").n_materials == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wb.geometry.grooves(profile="v").save(tmp_path / "g.obj")


def test_origin_for_geometry_inside_its_cell():
    tri = np.array([[0.2, 0.2, 0.0], [0.4, 0.2, 0.0], [0.3, 0.4, 0.1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tile = wb.SmallScale(tri, np.array([[0, 1, 2]]), period=(1, 1), origin=(0, 0))
    np.testing.assert_allclose(tile.origin, [0, 0])
    with pytest.raises(ValueError, match="outside the tile cell"):
        wb.SmallScale(tri, np.array([[0, 1, 2]]), period=(0.1, 1), origin=(0, 0))
    with pytest.raises(ValueError, match="origin must be two finite"):
        wb.SmallScale(tri, np.array([[0, 1, 2]]), period=(1, 1), origin=(np.nan, 0))


def test_tile_is_immutable():
    tile = random_heightfield(n=3)
    with pytest.raises(ValueError, match="read-only"):
        tile.vertices[0, 2] = 5.0
    with pytest.raises(ValueError, match="read-only"):
        tile.material_ids[0] = 3


def test_a_tile_with_no_face_looking_up_warns():
    """A tile given upside down (or wound the other way round) shows only backs from above, and bakes to an
    all-zero material: that used to happen in silence."""
    tile = wb.geometry.pyramid()
    with pytest.warns(wb.TileWarning, match="no face looks up"):
        wb.SmallScale(tile.vertices, tile.faces[:, ::-1].copy())
    # faces wound to look up but the file's vertex normals all down: the facets, shaded by them, face down too
    down = np.tile([0.0, 0.0, -1.0], (len(tile.vertices), 1))
    with pytest.warns(wb.TileWarning, match=r"no vertex normal looks up \(\+z\).*negate the normals"):
        wb.SmallScale(tile.vertices, tile.faces, vertex_normals=down)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wb.SmallScale(tile.vertices, tile.faces, vertex_normals=-down)
