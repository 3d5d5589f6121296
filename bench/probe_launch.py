"""Host cost of the Warp calls a bake makes, one at a time, on one device (no kernel work to speak of):
wp.launch of a small kernel with the argument count of the bake's, the same launch recorded
(`record_cmd=True`, re-issued by `Launch.launch()`), wp.empty, wp.copy, array.assign and
array.numpy() of a small array, each a median over many calls.

    python bench/probe_launch.py [cuda:0|cpu]
"""

import sys
import time

import numpy as np
import warp as wp


@wp.kernel
def six_args(a: wp.array(dtype=wp.float32), b: wp.array(dtype=wp.vec3), c: wp.array2d(dtype=wp.float32),
             n: int, x: float, offset: int, out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = a[i] + x


def per_call(fn, n=400, sync=None):
    for _ in range(20):
        fn()
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        times.append((time.perf_counter() - t0) / n)
        if sync is not None:
            sync()
    return float(np.median(times)) * 1e6


def main(device):
    wp.init()
    dev = wp.get_device(device)
    a = wp.zeros(64, dtype=wp.float32, device=dev)
    b = wp.zeros(64, dtype=wp.vec3, device=dev)
    c = wp.zeros((8, 8), dtype=wp.float32, device=dev)
    out = wp.zeros(64, dtype=wp.float32, device=dev)
    args = dict(dim=64, inputs=[a, b, c, 3, 1.0, 0], outputs=[out], device=dev)
    wp.launch(six_args, **args)
    wp.synchronize_device(dev)

    def sync():
        wp.synchronize_device(dev)

    rec = wp.launch(six_args, record_cmd=True, **args)
    host = np.ones(64, np.float32)
    rows = {
        "wp.launch (7 arguments)": per_call(lambda: wp.launch(six_args, **args), sync=sync),
        "recorded Launch.launch()": per_call(rec.launch, sync=sync),
        "recorded, one argument set + launch": per_call(lambda: (rec.set_param_at_index(0, a), rec.launch()),
                                                        sync=sync),
        "wp.empty(64)": per_call(lambda: wp.empty(64, dtype=wp.float32, device=dev), sync=sync),
        "wp.copy(64 floats, device to device)": per_call(lambda: wp.copy(out, a), sync=sync),
        "array.assign(64 floats from the host)": per_call(lambda: a.assign(host), sync=sync),
        "array.numpy() (64 floats)": per_call(lambda: out.numpy(), n=200),
        "synchronize_device (idle)": per_call(sync, n=200),
    }
    print(f"host µs a call on {dev} ({dev.name})")
    for name, us in rows.items():
        print(f"  {us:8.1f} µs  {name}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "cuda:0")
