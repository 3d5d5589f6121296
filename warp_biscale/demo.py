"""The built-in demo (``warp-biscale demo``): bake a small-scale tile and render a scene with it.

A torus made of gold-tinted pyramids (the built-in `pyramid` tile, glossy Blinn–Phong n = 256 on
the facets, a white ground between them) stands tilted over a grey floor under a blue sky with a
sun and one warm point light. The bake is small (2¹³ facets, a 10×10 direction grid, 6 lobes: about
a second on a 2-core CPU) and the scene is an ordinary TOML scene file (`scene_text`), so

    warp-biscale demo -o demo.png

does what ``warp-biscale render`` does with that file written out (`examples/bi-scale.toml` is
the same scene).
"""

from __future__ import annotations

__all__ = ["scene_text", "demo_scene", "DEMO_FACETS"]

DEMO_FACETS = 1 << 13

_TEMPLATE = """\
# The warp-biscale demo scene: a torus of baked gold pyramids over a floor, sky + sun + one point light.
[render]
width = {width}
height = {height}
method = "sg"
exposure = 0.0

[camera]
eye = [0.0, 2.4, 5.2]
target = [0.0, 0.9, 0.0]
fov = 35.0

[environment]
type = "sky"
sun_direction = [0.6, 0.7, 0.35]
sun_angular_radius = 2.0
height = 64
width = 128

[[light]]
type = "point"
position = [-2.5, 3.5, 2.5]
intensity = [14.0, 12.0, 9.0]
radius = 0.1

[[object]]
mesh = "torus"
major = 1.0
minor = 0.4
rotate = [60.0, 0.0, 0.0]
translate = [0.0, 1.3, 0.0]
material = "demo_tile"

[[object]]
mesh = "plane"
size = 8.0
divisions = 16
material = "floor"

[material.demo_tile]
type = "bake"
tile = "pyramid"
tile_params = {{ height = 0.5, color = [1.0, 0.78, 0.38], base_color = [0.85, 0.85, 0.85] }}
brdf = ["blinnphong:exponent=256,ks=0.9,kd=0.05"]
lobes = {lobes}
directions = {directions}
facets = {facets}
normal_res = 64

[material.floor]
type = "lambert"
albedo = 0.45
"""


def scene_text(size: int = 512, facets: int = DEMO_FACETS, directions: int = 10, lobes: int = 6,
               aspect: float = 0.75) -> str:
    """The demo scene as TOML text: `size` pixels wide, size·aspect high, and the bake's settings."""
    width = int(size)
    if width != size or width < 1:
        raise ValueError(f"size must be an integer >= 1, got {size!r}")
    return _TEMPLATE.format(width=width, height=max(1, round(width * aspect)), facets=int(facets),
                            directions=int(directions), lobes=int(lobes))


def demo_scene(size: int = 512, backend=None, progress=None, **bake):
    """Bake the demo tile and build the demo scene → `scenefile.SceneFile` (`.render()` renders it)."""
    from .scenefile import loads_scene

    return loads_scene(scene_text(size, **bake), path="demo.toml", base_dir=".", backend=backend,
                       progress=progress)
