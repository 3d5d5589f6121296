"""Where an ASG bake's time goes (issue 20's ≤ 10 ms at 2^16 facets, K = 12, J = 8): each stage of the bake and
each backend call inside it timed apart, the device synchronised before and after every one, so a stage's time
is its own host work plus the device work it queued. The sum is therefore above an unsynchronised bake's time;
the bake's median is printed beside it.

    python -m bench.profile_asg_bake --backends warp:cuda opencl:nvidia [--tile woven] [--bakes 10]
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import sys
import time
import warnings

import numpy as np

import warp_biscale as wb
from warp_biscale import asg_bake

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.bench_bake import BRDFS, families  # noqa: E402

warnings.simplefilter("ignore", wb.EnergyWarning)
bake_module = sys.modules["warp_biscale.bake"]
BACKEND_CALLS = ("asg_em", "asg_value_sums", "lobe_moments", "solve_amplitudes", "material_tables")
MODULE_CALLS = ((asg_bake, "amplitude_system"), (asg_bake, "ASGBRDF"), (bake_module, "_sample_facets"),
                (bake_module, "_queue_visibility"), (bake_module, "_queue_em_and_bin"), (bake_module, "_fit_ndf"))


def timed(f, sync, into):
    @functools.wraps(f)
    def call(*args, **kwargs):
        sync()
        t0 = time.perf_counter()
        out = f(*args, **kwargs)
        sync()
        into.append(time.perf_counter() - t0)
        return out
    return call


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=["warp:cpu"])
    ap.add_argument("--tile", default="woven")
    ap.add_argument("--bakes", type=int, default=10)
    args = ap.parse_args(argv)
    tile = families()[args.tile]
    mats = [BRDFS["blinnphong512"]] * tile.n_materials
    kw = dict(method="asg", lobes=8, directions=12, facets=2**16)
    for name in args.backends:
        be = wb.get_backend(name)
        for seed in range(1, 4):  # kernels built, caches warm
            wb.bake(tile, mats, backend=be, seed=seed, **kw)
        plain = []
        for seed in range(100, 100 + args.bakes):
            be.synchronize()
            t0 = time.perf_counter()
            wb.bake(tile, mats, backend=be, seed=seed, **kw)
            plain.append(time.perf_counter() - t0)
        times = collections.defaultdict(list)
        saved = [(owner, attr, getattr(owner, attr)) for owner, attr in MODULE_CALLS]
        for owner, attr, f in saved:
            setattr(owner, attr, timed(f, be.synchronize, times[attr]))
        for attr in BACKEND_CALLS:
            setattr(be, attr, timed(getattr(be, attr), be.synchronize, times[attr]))
        try:
            for seed in range(200, 200 + args.bakes):
                wb.bake(tile, mats, backend=be, seed=seed, **kw)
        finally:
            for owner, attr, f in saved:
                setattr(owner, attr, f)
            for attr in BACKEND_CALLS:
                delattr(be, attr)
        print(f"{be.name} ({be.device}), {args.tile}, Blinn–Phong n = 512, 2^16 facets, K = 12, J = 8: "
              f"bake median {np.median(plain) * 1e3:.2f} ms; synchronised pieces, median ms per bake (calls a bake):")
        for attr, values in times.items():
            calls = len(values) // args.bakes
            print(f"  {attr:20s} {np.median(values) * 1e3 * calls:7.3f}  ({calls})")


if __name__ == "__main__":
    main()
