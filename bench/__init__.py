"""The benchmarks behind the figures of bench/README.md, as a package that imports warp_biscale the public way.

Run a script from the checkout's root as a module or as a file (warp_biscale must be installed:
`pip install .` maps kernels/ and cl/ into it):

    python -m bench.bench_foundation --help
    python -P bench/bench_foundation.py --help
"""

import os
import sys

# `python -m bench.<name>` puts the checkout's root first on sys.path, where `warp_biscale` is the source
# tree without the kernels/ and cl/ subpackages that installing maps into it. Moving the root last keeps
# `bench` importable and lets the installed package win.
_ROOT = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))
_AT_ROOT = [p for p in sys.path if os.path.realpath(p or os.curdir) == _ROOT]
if _AT_ROOT and "warp_biscale" not in sys.modules:
    sys.path[:] = [p for p in sys.path if p not in _AT_ROOT] + [_ROOT]
