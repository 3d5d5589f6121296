"""Probe: the visibility kernel on Warp's BVH builders (LBVH, SAH), and on n×n blocks of tile copies
(the ray then wraps by n periods: still exact, fewer BVH queries per ray). Bits are checked equal.

Measured on an H100, 2^16 facets × 144 directions, 32k-triangle height field (per-ray kernel):
LBVH 14.6 ms; SAH with 1 / 2 / 4 / 8 triangles a leaf 7.7 / 7.4 / 9.5 / 12.4 ms; SAH 3×3 block
9.6 ms, 5×5 block 9.7 ms: the queries per ray are not what costs, the BVH walk is (NVIDIA OpenCL
walking warp_biscale.bvh: 5.4 ms for the whole stage).
An earlier kernel with one thread per 32-ray word took 24.1 ms (LBVH) / 17.0 ms (SAH).

    python bench/probe_visibility.py --device cuda:0 --facets 16 --directions 12 --tile-cells 128

`--block-dims 64 128 256` times the per-ray kernel of the SAH leaf-2 BVH (the backend's) at those
thread-block sizes (Warp's default is 256).
"""

import argparse
import time

import numpy as np
import warp as wp
from bench_foundation import heightfield_tile

import warp_biscale as wb
from warp_biscale.kernels import visibility as kv
from warp_biscale.reference import ray_offset
from warp_biscale.warp_backend import init_warp


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--facets", type=int, default=16)
    p.add_argument("--directions", type=int, default=12)
    p.add_argument("--tile-cells", type=int, default=128)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--block-dims", type=int, nargs="*", default=[256])
    a = p.parse_args()
    init_warp()
    dev = wp.get_device(a.device)
    tile = heightfield_tile(a.tile_cells)
    be = wb.get_backend("warp:" + a.device)
    n = 1 << a.facets
    fac = be.sample_facets(tile, n, 0)
    grid = wb.directions.grid(a.directions)
    ref_bits = be.visibility(tile, fac, grid).bits
    nd, words = len(grid), (n + 31) // 32
    pts = wp.array(tile.to_local(tile.vertices), dtype=wp.vec3, device=dev)
    faces = wp.array(tile.faces, dtype=wp.int32, device=dev)
    fn = wp.array(tile.face_normals.astype(np.float32), dtype=wp.vec3, device=dev)
    pos = wp.array(tile.to_local(fac.position), dtype=wp.vec3, device=dev)
    ff = wp.array(fac.face, dtype=wp.int32, device=dev)
    dirs = wp.array(grid.astype(np.float32), dtype=wp.vec3, device=dev)
    z_lo, z_hi = tile.z_range
    geo = [0.0, 0.0, float(tile.period[0]), float(tile.period[1]), 0.0, z_hi - z_lo, ray_offset(tile)]
    local = tile.to_local(tile.vertices)
    px, py = tile.period
    for block, ctor, leaf in ((1, "lbvh", None), (1, "sah", 1), (1, "sah", 2), (1, "sah", 4), (1, "sah", 8),
                              (3, "sah", 4)):
        # An n×n block of copies centred on the tile; the ray wraps by n periods (still exact).
        shifts = [(i * px, j * py, 0.0) for i in range(-(block // 2), block // 2 + 1)
                  for j in range(-(block // 2), block // 2 + 1)]
        bverts = np.concatenate([local + np.float32(sh) for sh in shifts]).astype(np.float32)
        bfaces = np.concatenate([tile.faces + m * len(local) for m in range(len(shifts))]).astype(np.int32)
        pts = wp.array(bverts, dtype=wp.vec3, device=dev)
        faces = wp.array(bfaces, dtype=wp.int32, device=dev)
        lo = -(block // 2)
        geo = [lo * px, lo * py, block * px, block * py, 0.0, z_hi - z_lo, ray_offset(tile)]
        try:
            t0 = time.perf_counter()
            mesh = wp.Mesh(points=pts, indices=faces.flatten(), bvh_constructor=ctor,
                           bvh_leaf_size=leaf)
            wp.synchronize_device(dev)
            build = time.perf_counter() - t0
        except Exception as exc:
            print(ctor, "failed", exc)
            continue
        bits = wp.empty((nd, words), dtype=wp.uint32, device=dev)
        flags = wp.empty((nd, n), dtype=wp.uint8, device=dev)

        def per_ray(block_dim=256):
            wp.launch(kv.visibility_rays, dim=(nd, n), device=dev, block_dim=block_dim,
                      inputs=[mesh.id, pts, faces, fn, 0, pos, ff, dirs, *geo, 0], outputs=[flags])
            wp.launch(kv.pack_bits, dim=(nd, words), device=dev, inputs=[flags, 0], outputs=[bits])

        runs = [("per_ray", per_ray)]
        if (block, ctor, leaf) == (1, "sah", 2):
            runs += [(f"per_ray block_dim {b}", lambda b=b: per_ray(b)) for b in a.block_dims if b != 256]
        for name, fn_ in runs:
            fn_()
            wp.synchronize_device(dev)
            ts = []
            for _ in range(a.runs):
                t0 = time.perf_counter()
                fn_()
                wp.synchronize_device(dev)
                ts.append(time.perf_counter() - t0)
            same = np.array_equal(bits.numpy(), ref_bits)
            print(f"block {block} {ctor:6s} leaf {leaf} build {build * 1e3:7.2f} ms  {name:8s} "
                  f"{np.median(ts) * 1e3:8.3f} ms ({n * nd / np.median(ts) / 1e9:.2f} Grays/s) "
                  f"bits identical: {same}", flush=True)


if __name__ == "__main__":
    main()
