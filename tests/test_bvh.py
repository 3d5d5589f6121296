"""The host-built BVH of the OpenCL visibility kernel (warp_biscale.bvh).

Structure: every triangle in exactly one leaf, leaves small, child boxes inside their parents,
leaf boxes around their triangles with the promised padding, depth within the kernel's stack.
Traversal-free query check: with the kernel's float32 slab and Möller–Trumbore tests written in
numpy, every triangle a ray hits must sit in a leaf whose box and all of whose ancestors' boxes
the ray hits, so a walk that prunes on box misses can never lose it.
"""

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import reference
from warp_biscale.bvh import LEAF_SIZE, PAD, STACK_SIZE, build_bvh

f32 = np.float32


def height_field(n, amp=0.1, seed=0, flat=False):
    rng = np.random.default_rng(seed)
    h = np.zeros((n, n)) if flat else rng.random((n, n)) * amp
    xs = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    z = h[np.arange(n + 1) % n][:, np.arange(n + 1) % n]
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    idx = lambda i, j: i * (n + 1) + j
    f = np.concatenate([np.stack([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], 1),
                        np.stack([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)], 1)])
    return v, f


def vgroove():
    tile = reference.vgroove_tile(0.5, 1.0)
    return np.array(tile.vertices), np.array(tile.faces)


def soup(n, seed=1):
    rng = np.random.default_rng(seed)
    c = rng.random((n, 1, 3)) * 10
    return (c + 0.2 * rng.standard_normal((n, 3, 3))).reshape(-1, 3), np.arange(3 * n).reshape(-1, 3)


MESHES = {
    "one triangle": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])),
    "vgroove": vgroove(),
    "flat 8x8": height_field(8, flat=True),
    "height field 16x16": height_field(16),
    "soup 3000": soup(3000),
    # Many triangles with one centroid: all Morton codes equal, splits fall back to counts.
    "coincident": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float),
                   np.array([[0, 1, 2], [1, 3, 2]] * 20)),
    # Far from the origin: the padding must follow the coordinates' magnitude, not only the size.
    "offset": (height_field(8)[0] + [1000.0, -500.0, 20.0], height_field(8)[1]),
}


def parents(bvh):
    par = np.full(bvh.n_nodes, -1)
    inner = np.flatnonzero(~bvh.is_leaf)
    par[bvh.child[inner, 0]] = inner
    par[bvh.child[inner, 1]] = inner
    return par


@pytest.mark.parametrize("name", list(MESHES))
def test_structure(name):
    v, f = MESHES[name]
    bvh = build_bvh(v, f)
    n_tri = len(f)
    assert bvh.bounds.dtype == np.float32 and bvh.bounds.shape == (bvh.n_nodes, 6)
    assert bvh.child.dtype == np.int32 and bvh.child.shape == (bvh.n_nodes, 2)
    assert 1 <= bvh.depth <= STACK_SIZE
    leaf = bvh.is_leaf
    # Every triangle in exactly one leaf: tri_index is a permutation and the leaf ranges tile it.
    assert np.array_equal(np.sort(bvh.tri_index), np.arange(n_tri))
    first, count = bvh.child[leaf, 0], -bvh.child[leaf, 1]
    assert (count >= 1).all() and (count <= LEAF_SIZE).all()
    cover = np.zeros(n_tri, int)
    for a, c in zip(first, count, strict=True):
        cover[a:a + c] += 1
    assert (cover == 1).all()
    # Inner nodes: right = left + 1, children after their parent (breadth-first), each node one parent.
    inner = np.flatnonzero(~leaf)
    left, right = bvh.child[inner, 0], bvh.child[inner, 1]
    assert np.array_equal(right, left + 1) and (left > inner).all() and (right < bvh.n_nodes).all()
    kids = np.concatenate([left, right])
    assert len(np.unique(kids)) == len(kids) == bvh.n_nodes - 1 and 0 not in kids
    # Child boxes inside their parents.
    for side in (left, right):
        assert (bvh.bounds[side, :3] >= bvh.bounds[inner, :3]).all()
        assert (bvh.bounds[side, 3:] <= bvh.bounds[inner, 3:]).all()
    # Leaf boxes contain their triangles' float32 vertices with (almost all of) the padding to spare.
    v32 = np.asarray(v, np.float32).astype(np.float64)
    scale = max(float(np.ptp(v32, axis=0).max()), float(np.abs(v32).max()))
    assert bvh.pad == pytest.approx(PAD * scale)
    for node, a, c in zip(np.flatnonzero(leaf), first, count, strict=True):
        pts = v32[np.asarray(f)[bvh.tri_index[a:a + c]]].reshape(-1, 3)
        lo, hi = bvh.bounds[node, :3].astype(np.float64), bvh.bounds[node, 3:].astype(np.float64)
        assert (pts.min(0) - lo >= 0.99 * bvh.pad).all() and (hi - pts.max(0) >= 0.99 * bvh.pad).all()
    # The packed device record round-trips.
    packed = bvh.packed()
    assert packed.shape == (bvh.n_nodes, 8) and packed.dtype == np.float32
    assert np.array_equal(packed[:, :6], bvh.bounds)
    assert np.array_equal(packed[:, 6:].view(np.int32), bvh.child)
    table = bvh.triangle_table(v, f)
    tri = np.asarray(v, np.float32)[np.asarray(f)[bvh.tri_index]]
    assert np.array_equal(table[:, :3], tri[:, 0])
    assert np.array_equal(table[:, 3:6], tri[:, 1] - tri[:, 0])
    assert np.array_equal(table[:, 6:], tri[:, 2] - tri[:, 0])


def test_flat_tile_boxes_have_thickness():
    """All z equal: the boxes are padded to a non-zero z extent, so a ray starting on the plane is
    inside them, not on a face."""
    bvh = build_bvh(*height_field(8, flat=True))
    assert (bvh.bounds[:, 2] < 0).all() and (bvh.bounds[:, 5] > 0).all()


def test_rejects_bad_input():
    with pytest.raises(ValueError):
        build_bvh(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(ValueError):
        build_bvh(*vgroove(), leaf_size=LEAF_SIZE + 1)


# ------------------------------------------------------------------ traversal-free query check
def _safe_inverse(d):
    d = d.astype(f32)
    return (f32(1.0) / np.where(d >= 0, np.maximum(d, f32(1e-20)), np.minimum(d, f32(-1e-20)))).astype(f32)


def _box_hits(bounds, o, inv, t_lo, t_hi):
    """(R, N) the kernel's float32 slab test of every ray against every node box."""
    lo = bounds[None, :, :3]
    hi = bounds[None, :, 3:]
    t0 = (lo - o[:, None]) * inv[:, None]
    t1 = (hi - o[:, None]) * inv[:, None]
    tmin = np.maximum(np.minimum(t0, t1).max(axis=2), t_lo[:, None])
    tmax = np.minimum(np.maximum(t0, t1).min(axis=2), t_hi[:, None])
    return tmin <= tmax


def _tri_hits(table, o, d, t_lo, t_hi):
    """(R, F) the kernel's float32 Möller–Trumbore test (same operations, same order)."""
    a, e1, e2 = table[None, :, 0:3], table[None, :, 3:6], table[None, :, 6:9]
    dd = d[:, None, :]
    p = np.stack([dd[..., 1] * e2[..., 2] - dd[..., 2] * e2[..., 1],
                  dd[..., 2] * e2[..., 0] - dd[..., 0] * e2[..., 2],
                  dd[..., 0] * e2[..., 1] - dd[..., 1] * e2[..., 0]], -1)
    det = p[..., 0] * e1[..., 0] + p[..., 1] * e1[..., 1] + p[..., 2] * e1[..., 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = f32(1.0) / det
        tv = o[:, None, :] - a
        u = (tv[..., 0] * p[..., 0] + tv[..., 1] * p[..., 1] + tv[..., 2] * p[..., 2]) * inv
        q = np.stack([tv[..., 1] * e1[..., 2] - tv[..., 2] * e1[..., 1],
                      tv[..., 2] * e1[..., 0] - tv[..., 0] * e1[..., 2],
                      tv[..., 0] * e1[..., 1] - tv[..., 1] * e1[..., 0]], -1)
        v = (dd[..., 0] * q[..., 0] + dd[..., 1] * q[..., 1] + dd[..., 2] * q[..., 2]) * inv
        t = (e2[..., 0] * q[..., 0] + e2[..., 1] * q[..., 1] + e2[..., 2] * q[..., 2]) * inv
        return ((det != 0) & (u >= 0) & (u <= 1) & (v >= 0) & (u + v <= 1)
                & (t > t_lo[:, None]) & (t <= t_hi[:, None]))


def _rays(v, f, n, seed):
    """Rays that graze: origins on the triangles (as facet rays start) and on their edges and
    vertices, directions random, axis-aligned and in the triangles' planes."""
    rng = np.random.default_rng(seed)
    v = np.asarray(v, np.float64)
    tri = v[np.asarray(f)]
    pick = rng.integers(0, len(tri), n)
    bary = rng.dirichlet([1, 1, 1], n)
    bary[: n // 4] = np.eye(3)[rng.integers(0, 3, n // 4)]  # on vertices
    bary[n // 4: n // 2, rng.integers(0, 3)] = 0.0  # on edges
    bary /= bary.sum(1, keepdims=True)
    o = np.einsum("rk,rkj->rj", bary, tri[pick])
    d = rng.standard_normal((n, 3))
    axes = np.eye(3)[rng.integers(0, 3, n)] * rng.choice([-1.0, 1.0], (n, 1))
    d[::3] = axes[::3]  # axis-aligned: zero components
    inplane = tri[pick, 1] - tri[pick, 0]
    d[1::5] = inplane[1::5]  # in the triangle's plane
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_lo = np.where(rng.random(n) < 0.5, 0.0, -1e-3)
    t_hi = rng.random(n) * 2.0 * max(np.ptp(v, axis=0).max(), 1e-3)
    o = o + 1e-6 * rng.standard_normal((n, 3)) * (rng.random((n, 1)) < 0.3)
    return o.astype(f32), d.astype(f32), t_lo.astype(f32), t_hi.astype(f32)


@pytest.mark.parametrize("name", ["vgroove", "flat 8x8", "height field 16x16", "soup 3000", "offset"])
def test_every_hit_is_reachable(name):
    v, f = MESHES[name]
    bvh = build_bvh(v, f)
    table = bvh.triangle_table(v, f)
    o, d, t_lo, t_hi = _rays(v, f, 400, seed=len(name))
    if name == "offset":  # rays above the raised tile: origins far from zero
        o = o + f32(1e-4)
    tri_hit = _tri_hits(table, o, d, t_lo, t_hi)  # (R, F) in slot order
    box_hit = _box_hits(bvh.bounds, o, _safe_inverse(d), t_lo, t_hi)  # (R, N)
    # Reachable: the node's box and every ancestor's box are hit (parents precede children).
    par = parents(bvh)
    reach = box_hit.copy()
    for node in range(1, bvh.n_nodes):
        reach[:, node] &= reach[:, par[node]]
    leaf = np.flatnonzero(bvh.is_leaf)
    slot_leaf = np.empty(len(f), int)
    for node in leaf:
        a, c = bvh.child[node, 0], -bvh.child[node, 1]
        slot_leaf[a:a + c] = node
    lost = tri_hit & ~reach[:, slot_leaf]
    assert tri_hit.any(), "the rays should hit something"
    assert not lost.any(), f"{int(lost.sum())} hits in unreachable leaves"


def test_large_height_field_node_count():
    """A 128×128 height field (32 768 triangles): fewer than 2 nodes a triangle (a binary tree with leaves of
    up to LEAF_SIZE triangles). Its build time is measured in bench/bench_precompute.py, not here."""
    v, f = height_field(128)
    bvh = build_bvh(v, f)
    assert bvh.n_nodes < 2 * len(f), f"{bvh.n_nodes} nodes for {len(f)} triangles"


def test_opencl_bvh_matches_brute_force():
    """The kernel's BVH walk gives the same bits as its brute force over every triangle."""
    from warp_biscale import SmallScale, directions

    opencl = [b for b in wb.backends() if b["kind"] == "opencl"]
    if not any(b["usable"] for b in opencl):
        why = "; ".join(f"{b['name']}: {b['reason']}" for b in opencl) or "no OpenCL device found"
        pytest.skip(f"no usable OpenCL backend ({why})")
    be = wb.get_backend("opencl")
    dirs = directions.grid(5)  # odd K: the zenith (0, 0, 1) is among them
    for v, f in (vgroove(), height_field(8, amp=0.4, seed=2), height_field(6, flat=True)):
        tile = SmallScale(v, f)
        facets = be.sample_facets(tile, 700, 3)
        bits = be.visibility(tile, facets, dirs).bits
        brute = be.visibility(tile, facets, dirs, brute_force=True).bits
        assert np.array_equal(bits, brute)
