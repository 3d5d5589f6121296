"""Host cost of a pinned host allocation against a reused one (CUDA): what `WarpBackend._read_later` keeps
one buffer per shape for.

    python bench/probe_pinned.py [N]
"""
import sys
import time

import numpy as np
import warp as wp

n = int(sys.argv[1]) if len(sys.argv) > 1 else 1 << 16
wp.init()
dev = wp.get_device("cuda:0")
a = wp.zeros(n, dtype=wp.float32, device=dev)
held = wp.empty(n, dtype=wp.float32, device="cpu", pinned=True)
for label, make in (("wp.empty pinned", lambda: wp.empty(n, dtype=wp.float32, device="cpu", pinned=True)),
                    ("reused pinned", lambda: held)):
    times = []
    for _ in range(50):
        t0 = time.perf_counter()
        host = make()
        wp.copy(host, a)
        wp.synchronize_device(dev)
        times.append(time.perf_counter() - t0)
    print(f"{label}: allocation + copy of {n} float32 {np.median(times) * 1e6:.1f} µs (median of 50)")
