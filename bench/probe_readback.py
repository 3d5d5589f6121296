"""Latency of reading a bake-sized table (K = 12, J = 8: 20736 × 8 × 3 float32, 2 MB) back from a
Warp CUDA array: `.numpy()` (pageable), and through a pinned staging buffer kept between calls (D2H
into it, then a host copy into a fresh owned array).

    python bench/probe_readback.py
"""
import time

import numpy as np
import warp as wp


def latency(fn, runs=20):
    fn()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return f"{np.median(times) * 1e3:.3f} ms (min {min(times) * 1e3:.3f})"


def main():
    wp.init()
    for shape in [(20736, 8, 3), (20736, 8)]:
        dev = wp.array(np.random.rand(*shape).astype(np.float32), device="cuda:0")
        staging = wp.empty(shape, dtype=wp.float32, device="cpu", pinned=True)

        def pinned():
            wp.copy(staging, dev)
            wp.synchronize_device("cuda:0")
            return np.array(staging.numpy())

        print(shape, "numpy():", latency(lambda: dev.numpy()), " pinned staging + copy:", latency(pinned))


if __name__ == "__main__":
    main()
