"""OpenCL C sources, one file per stage (installed as ``warp_biscale.cl``), twins of
``warp_biscale.kernels``. ``source(stem)`` returns a file's text with ``common.cl`` prepended."""

from importlib import resources


def source(stem: str) -> str:
    here = resources.files(__name__)
    return here.joinpath("common.cl").read_text() + "\n" + here.joinpath(f"{stem}.cl").read_text()
