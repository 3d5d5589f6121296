"""warp_biscale: bi-scale material design on NVIDIA Warp and OpenCL.

    import warp_biscale as wb
    tile = wb.geometry.pyramid(height=0.5)            # or wb.SmallScale.load("tile.obj")
    f = wb.effective_brdf_exact(tile, wb.Lambert(0.5), wi, wo, facets=2**16)
    gt = wb.ground_truth(tile, [wb.BlinnPhong(1.0, 64)], facets=2**18, directions=12)
    gt.eval(wi, wo); gt.save("t.npz"); wb.load("t.npz")
    mat = wb.bake(tile, [wb.BlinnPhong(1.0, 512)], lobes=8, directions=12, facets=2**16)
    mat.eval(wi, wo); mat.save("m.wbm"); mat.timings; wb.compare(mat, gt)

    scene = wb.Scene(wb.Mesh.sphere(), [mat], wb.Camera(eye=(0, 0, 4)), wb.Environment.sky(),
                     [wb.PointLight((2, 3, 2), 20.0)])
    img = wb.render(scene, method="sg"); img.save("out.png"); img.timings
    ref = wb.render(scene, method="mc", samples=1024); wb.compare_images(img.image, ref.image)
"""

import os as _os

__version__ = "0.1.0"  # before the imports: warp_biscale.cli reads it while the package is importing

# An install puts kernels/ and cl/ inside the package (warp_biscale.kernels, warp_biscale.cl); in a source
# checkout they sit beside it. Look there too, so that the checkout runs as it is (`python -m warp_biscale`
# or `python -m pytest` from its root import this folder, not the install).
if not _os.path.isdir(_os.path.join(__path__[0], "kernels")):
    __path__.append(_os.path.dirname(_os.path.abspath(__path__[0])))

from . import asg, batch, directions, geometry, lobes, matrix, sg
from .backend import Backend, backends, get_backend
from .bake import bake
from .model import Bvndf
from .brdf import AnisotropicWard, AshikhminShirley, BlinnPhong, CookTorrance, EnergyWarning, Lambert, Ward
from .effective import EffectiveBRDF, compare
from .environment import Environment
from .images import compare_images, read_image, write_image
from .litsphere import LitSphere
from .matrix import MatrixBRDF
from .asg_bake import ASGBRDF
from .loading import load
from .measured import MeasuredBRDF
from .model import Facets, Visibility
from .render import queue_frame, render
from .scene import Rendering, Scene
from .scene import Camera, DirectionalLight, Mesh, PointLight
from .scenefile import load_scene
from . import mitsuba_export  # noqa: F401, E402 (registers EffectiveBRDF.export_mitsuba's writer)
from .editor import Editor
from .smallscale import SmallScale, TileWarning
from .svbrdf import Textured
from .truth import GroundTruth, effective_brdf_exact, ground_truth, truth_of

__all__ = [
    "AnisotropicWard", "AshikhminShirley", "ASGBRDF", "Backend", "BlinnPhong", "asg", "batch", "Bvndf", "Camera",
    "CookTorrance", "DirectionalLight",
    "EffectiveBRDF",
    "Editor", "EnergyWarning",
    "Environment",
    "Facets", "GroundTruth", "Lambert", "LitSphere", "MatrixBRDF", "MeasuredBRDF",
    "Mesh", "PointLight", "Rendering", "Scene", "SmallScale", "Textured",
    "TileWarning",
    "Visibility", "Ward", "backends", "bake", "compare", "compare_images", "directions", "effective_brdf_exact",
    "geometry", "get_backend", "ground_truth", "truth_of", "load", "load_scene", "lobes", "matrix", "read_image",
    "queue_frame", "render", "sg",
    "write_image",
]

