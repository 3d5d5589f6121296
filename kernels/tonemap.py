"""A shaded frame's last steps on the device: the tonemap stage.

Twin of ``cl/tonemap.cl``. `tonemap_pixels` (the float64 reference is ``warp_biscale.images.tonemap``): one
thread per pixel, the radiance scaled by 2^exposure, mapped to [0, 1] by the operator (`curve`: 0 ACES,
1 Reinhard, 2 clamp, the order of images.TONEMAP_OPERATORS), sRGB-encoded and rounded to 8 bits — so a frame
crosses to the host as a quarter of its float32 bytes. `accumulate_frame`: an anti-aliasing sample's radiance
times its weight added to the frame's sum (the first sample sets it), so that only the average is read back.
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

# Past this the three operators are 1 to within half an 8-bit step (ACES reaches 1 at ~7.2), and ACES's
# products stay finite in float32.
LARGE = wp.constant(1.0e4)


@wp.func
def to_byte(x: float, curve: int) -> wp.uint8:
    v = x
    if not (v >= 0.0):  # NaN or negative: black (radiance reaching here is already finite and >= 0)
        v = 0.0
    v = wp.min(v, LARGE)
    y = v
    if curve == 0:
        y = v * (2.51 * v + 0.03) / (v * (2.43 * v + 0.59) + 0.14)
    elif curve == 1:
        y = v / (1.0 + v)
    y = wp.clamp(y, 0.0, 1.0)
    s = 12.92 * y
    if y > 0.0031308:
        s = 1.055 * wp.pow(y, 1.0 / 2.4) - 0.055
    return wp.uint8(int(wp.floor(s * 255.0 + 0.5)))


@wp.kernel
def tonemap_pixels(radiance: wp.array(dtype=wp.vec3), scale: float, curve: int, n_pixels: int, offset: int,
                   out: wp.array(dtype=wp.uint8)):
    p = wp.tid() + offset
    if p >= n_pixels:
        return
    c = radiance[p]
    for k in range(3):
        out[3 * p + k] = to_byte(c[k] * scale, curve)


@wp.kernel
def accumulate_frame(radiance: wp.array(dtype=wp.vec3), weight: float, first: int, n_pixels: int, offset: int,
                     total: wp.array(dtype=wp.vec3)):
    p = wp.tid() + offset
    if p >= n_pixels:
        return
    if first != 0:
        total[p] = weight * radiance[p]
    else:
        total[p] = total[p] + weight * radiance[p]
