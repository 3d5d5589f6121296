"""warp_biscale: bi-scale material design on NVIDIA Warp and OpenCL."""

from . import directions, reference
from .backend import Backend, backends, get_backend
from .brdf import BlinnPhong, CookTorrance, Lambert, Ward
from .model import Facets, Visibility
from .smallscale import SmallScale, TileWarning

__version__ = "0.1.0"
