"""The backend probe: a tiny kernel that a backend must build and run right before it is offered.

Twin of ``cl/probe.cl``; the reference is ``warp_biscale.backend.probe_expected``. It uses float64,
as facet sampling does, so a device that cannot run the stages fails here, not in the middle of a bake.
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.kernel
def probe(values: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    x = values[i]
    out[i] = x * x + wp.float64(0.5) * x + wp.float64(1.0)
