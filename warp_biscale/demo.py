"""The built-in demo (``warp-biscale demo``): bake a small-scale tile and render a scene with it.

A torus made of gold pyramids on a dark red ground (the built-in `pyramid` tile, glossy Blinn–Phong
n = 256 on every facet) stands tilted over a grey floor under a blue sky, lit by a sun (a directional
light) and a warm point light. The bake is small (2¹³ facets, a 10×10 direction grid, 6 lobes: about
a second on a 2-core CPU) and the scene is an ordinary TOML scene file (`scene_text`), so

    warp-biscale demo -o demo.png

does what ``warp-biscale render`` does with that file written out (`examples/bi-scale.toml` is
the same scene).
"""

from __future__ import annotations

from .scenefile import loads_scene

__all__ = ["scene_text", "demo_scene", "DEMO_FACETS", "WIDTH", "HEIGHT"]

DEMO_FACETS = 1 << 13
WIDTH, HEIGHT = 512, 384  # the demo's frame (`warp-biscale demo --size` checks its size against it before the bake)

_TEMPLATE = """\
# The warp-biscale demo scene: a torus of baked pyramids over a floor, sky + sun + one point light.
[render]
width = {width}
height = {height}
method = "sg"
exposure = 0.0
ssdf_resolution = 16         # soft sky occlusion: 16x16 directions (sun and lamp shadows are ray-traced)

[camera]
eye = [0.0, 2.7, 6.4]
target = [0.0, 1.05, 0.0]
fov = 35.0

[environment]
type = "sky"
sun_irradiance = 0.0         # the sun is the directional light below (sharp, ray-traced shadow)
ground = [0.3, 0.28, 0.25]
height = 64
width = 128

[[light]]
type = "directional"         # the sun
direction = [0.6, 0.7, 0.35]
irradiance = [3.0, 2.9, 2.6]
angular_radius = 1.0

[[light]]
type = "point"               # a warm lamp at the back left
position = [-2.5, 3.0, -1.5]
intensity = [10.0, 7.5, 4.5]
radius = 0.1

[[object]]
mesh = "torus"
major = 1.0
minor = 0.4
segments = [64, 32]
rotate = [60.0, 0.0, 0.0]
translate = [0.0, 1.3, 0.0]
material = "demo_tile"

[[object]]
mesh = "plane"
size = 12.0
divisions = 16
material = "floor"

# Gold pyramids on a dark red ground, a glossy Blinn-Phong on every facet: seen from above the
# ground shows, at grazing angles the pyramids' faces hide it, so the torus turns gold at its rims.
[material.demo_tile]
type = "bake"
tile = "pyramid"
tile_params = {{ height = 0.5, color = [1.0, 0.75, 0.3], base_color = [0.55, 0.1, 0.07] }}
brdf = ["blinnphong:exponent=256,ks=0.8,kd=0.2,normalization=energy"]
lobes = {lobes}
directions = {directions}
facets = {facets}
normal_res = 64

[material.floor]
type = "lambert"
albedo = 0.45
"""


def scene_text(size: int = WIDTH, facets: int = DEMO_FACETS, directions: int = 10, lobes: int = 6,
               aspect: float = HEIGHT / WIDTH) -> str:
    """The demo scene as TOML text: `size` pixels wide, size·aspect high, and the bake's settings."""
    width = int(size)
    if width != size or width < 1:
        raise ValueError(f"size must be an integer >= 1, got {size!r}")
    return _TEMPLATE.format(width=width, height=max(1, round(width * aspect)), facets=int(facets),
                            directions=int(directions), lobes=int(lobes))


def demo_scene(size: int = WIDTH, backend=None, progress=None, **bake):
    """Bake the demo tile and build the demo scene → `scenefile.SceneFile` (`.render()` renders it)."""

    return loads_scene(scene_text(size, **bake), path="demo.toml", base_dir=".", backend=backend,
                       progress=progress)
