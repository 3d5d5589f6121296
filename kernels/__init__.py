"""Warp kernels, one module per stage (installed as ``warp_biscale.kernels``).

Each module here has an OpenCL twin with the same stem in ``warp_biscale.cl``; both are tested
against ``warp_biscale.reference``.
"""
