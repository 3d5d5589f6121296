"""Anti-aliasing: the SG renderer's jittered supersampling against the box-filtered analytic coverage of
an edge, and the camera's sub-pixel jitter against its own float64 rays."""

import numpy as np
import pytest

import warp_biscale as wb
import warp_biscale.trace as trace_module
from warp_biscale import cli
from warp_biscale.render import aa_offsets


def _edge_scene():
    """A lit square seen from straight above with the image axes turned 20° from its edges: its edge
    crosses the pixels at a slope, and every covered pixel has the same radiance."""
    a = np.radians(20)
    cam = wb.Camera(eye=(2.0, 3.0, 0.0), target=(2.0, 0.0, 0.0), up=(np.sin(a), 0, -np.cos(a)), fov=30,
                    width=48, height=32)
    plane = wb.Mesh.plane(4.0, 0.0, 2, material=0)
    return wb.Scene(plane, [wb.Lambert(0.5)], cam, None, [wb.DirectionalLight((0, 1, 0), 3.0, 1.0)])


def _coverage(cam, n=32):
    """The share of each pixel's square that sees the square |x|, |z| ≤ 2 at y = 0, by an n × n grid of
    exact ray–plane intersections per pixel (±1/(2n) per pixel)."""
    f, r, u, t = cam.basis()
    off = (np.arange(n) + 0.5) / n
    total = np.zeros((cam.height, cam.width))
    for ox in off:
        for oy in off:
            x = (2 * (np.arange(cam.width) + ox) / cam.width - 1) * t * cam.width / cam.height
            y = (1 - 2 * (np.arange(cam.height) + oy) / cam.height) * t
            d = f[None, None] + x[None, :, None] * r + y[:, None, None] * u
            p = cam.eye + (-cam.eye[1] / d[..., 1])[..., None] * d
            total += (np.abs(p[..., 0]) <= 2.0) & (np.abs(p[..., 2]) <= 2.0)
    return total / (n * n)


@pytest.fixture(scope="module")
def edge():
    scene = _edge_scene()
    cov = _coverage(scene.camera)
    return scene, cov, (cov > 0) & (cov < 1)


@pytest.mark.parametrize("aa_shading", ["sample", "pixel"])
def test_aa_matches_the_box_filtered_coverage_of_an_edge(backend, edge, aa_shading):
    """16 multi-jittered samples: per edge pixel the error is a sum of a few cells' Bernoulli draws,
    std ≈ 0.06 of the radiance (measured on Warp CPU: mean 0.053, max 0.116); one sample per pixel is
    0.21 / 0.46. Unbiased: the signed errors cancel over the edge. Shaded once a pixel (aa_shading="pixel"),
    the coverage is the same."""
    scene, cov, on_edge = edge
    assert on_edge.sum() >= 30
    img = wb.render(scene, backend=backend, aa=16, aa_shading=aa_shading).image[..., 0]
    radiance = img[cov == 1].mean()
    err = (img - radiance * cov)[on_edge] / radiance
    assert np.abs(err).mean() < 0.08 and np.abs(err).max() < 0.2
    assert abs(err.mean()) < 0.03
    assert np.abs(img - radiance * cov)[~on_edge].max() < 1e-4 * radiance  # inside and outside: unchanged
    single = wb.render(scene, backend=backend).image[..., 0]
    assert np.abs(single - radiance * cov)[on_edge].mean() / radiance > 0.15  # the test sees aliasing


@pytest.mark.parametrize("method", ["sg", "litsphere"])
def test_device_average_is_the_mean_of_the_samples(backend, edge, method):
    """aa = N averages its samples on the device (`accumulate_frame`): the result against the float64 mean of N
    one-sample renders with the same jitters, read back one by one. Tolerance: the device sums weight·x in
    float32 (measured, Warp CPU and PoCL alike: 1.6e-8 of the largest pixel (SG), 1.2e-7 (lit-sphere))
    → 1e-6; the frame it leaves is the average (what `frame_u8` tone-maps)."""
    import dataclasses

    scene = edge[0]
    n = 5
    got = wb.render(scene, method=method, backend=backend, aa=n).image
    mean = np.zeros(got.shape)
    for jx, jy in aa_offsets(n):
        cam = dataclasses.replace(scene.camera, jitter=(jx, jy))
        one = wb.Scene(scene.mesh, scene.materials, cam, scene.environment, scene.lights)
        mean += wb.render(one, method=method, backend=backend).image / n
    err = np.abs(got - mean).max() / mean.max()
    print(f"{backend.name} {method}: {err:.1e} of the largest pixel")
    assert err < 1e-6
    wb.render(scene, method=method, backend=backend, aa=n)
    frame = backend.frame_u8(scene.mesh, scene.camera.width, scene.camera.height)
    np.testing.assert_allclose(frame, wb.images.tonemap(got), atol=1)


def test_aa_offsets_are_stratified():
    for n in (2, 4, 5, 16, 64):
        o = aa_offsets(n)
        assert o.shape == (n, 2) and np.all(o >= -0.5) and np.all(o < 0.5)
        k = int(np.ceil(np.sqrt(n)))
        cells = np.floor((o + 0.5) * k).astype(int)
        assert len({tuple(c) for c in cells}) == n  # at most one sample per coarse cell
        for axis in range(2):  # one per fine row and column
            assert len(np.unique(np.floor((o[:, axis] + 0.5) * k * k))) == n
    np.testing.assert_array_equal(aa_offsets(1), [[0.0, 0.0]])
    np.testing.assert_array_equal(aa_offsets(9), aa_offsets(9))


def test_jittered_camera_rays_match_packed():
    """The kernels aim at pixel centres; a jitter moves the packed `forward`: the ray through the packed
    camera's pixel centre must be the float64 jittered ray (float32 packing: 1e-6)."""
    cam = wb.Camera(eye=(0.3, 1.0, 4.0), target=(0, 0.5, 0), width=7, height=5, jitter=(0.3, -0.45))
    _, d = cam.rays()
    c = cam.packed().astype(np.float64)
    x, y = np.meshgrid(np.arange(7), np.arange(5))
    sx = (2 * (x + 0.5) / 7 - 1).reshape(-1, 1)
    sy = (1 - 2 * (y + 0.5) / 5).reshape(-1, 1)
    k = c[3:6] + sx * c[6:9] + sy * c[9:12]
    np.testing.assert_allclose(k / np.linalg.norm(k, axis=1, keepdims=True), d, atol=1e-6)


@pytest.mark.parametrize("bad", [0, -1, 1.5, "4", True, 257])
def test_bad_aa_is_one_line(bad):
    with pytest.raises(ValueError, match="aa must be an integer"):
        wb.render(_edge_scene(), backend="warp:cpu", aa=bad)


def test_bad_jitter_is_one_line():
    with pytest.raises(ValueError, match="Camera.jitter"):
        wb.Camera(jitter=(0.7, 0.0))


def test_cli_render_anti_aliases_by_default(tmp_path, capsys):
    """`warp-biscale render` writes an anti-aliased image by default (4 samples) and `--aa 1` the pixel
    centres; both read back: an edge pixel of the sphere differs between them. Bad values are refused
    before any work, with exit code 2."""
    from test_cli import TINY_SCENE

    scene = tmp_path / "tiny.toml"
    scene.write_text(TINY_SCENE)
    outs = {}
    # (in-process, `cli.main`: test_cli runs the console script's render itself)
    for flag in ([], ["--aa", "1"], ["--shadow-samples", "1"], ["--every-ray-per-sample"], ["--block-rays"],
                 ["--aa-shading", "pixel"]):
        out = tmp_path / f"img{len(outs)}.exr"
        assert cli.main(["render", str(scene), "-o", str(out), "-q", *flag]) == 0
        outs[tuple(flag)] = wb.images.read_image(str(out))
    aa4, aa1 = outs[()], outs[("--aa", "1")]
    assert aa4.shape == aa1.shape == (24, 32, 3)
    assert np.abs(aa4 - aa1).max() > 0.01  # silhouettes changed
    every = outs[("--every-ray-per-sample",)]  # 4x the shadow rays: the same image but for their noise
    assert np.abs(every - aa4).mean() < 0.05 * aa4.mean() and np.abs(every - aa4).max() > 0
    block = outs[("--block-rays",)]  # a quarter of the rays a pixel: the same image but for noise and a blur
    assert np.abs(block - aa4).mean() < 0.05 * aa4.mean() and np.abs(block - aa4).max() > 0
    # At 320×240 the default shares the rays in blocks: as --block-rays, bit for bit, and not as --no-block-rays
    # (the flags before the scene's path, as a script may put them).
    big = {}
    for flag in ([], ["--block-rays"], ["--no-block-rays"]):
        out = tmp_path / f"big{len(big)}.exr"
        assert cli.main(["render", *flag, str(scene), "-o", str(out), "-q", "--aa", "1", "--size", "320", "240"]) == 0
        big[tuple(flag)] = wb.images.read_image(str(out))
    assert np.array_equal(big[()], big[("--block-rays",)])
    assert np.abs(big[()] - big[("--no-block-rays",)]).max() > 0.01
    out = tmp_path / "big-side-4.exr"  # --block-side 4: 4x4 blocks, not the default's 2x2
    assert cli.main(["render", "--block-side", "4", str(scene), "-o", str(out), "-q", "--aa", "1", "--size", "320",
                     "240"]) == 0
    assert np.abs(wb.images.read_image(str(out)) - big[()]).max() > 0.01
    # Shaded once a pixel: the edges anti-aliased alike, shading within a surface from one sample (the shiny
    # sphere's highlight is the pixel that differs most: 3.5 times the image mean, measured). The median
    # |once − aa4| measured 0.93 % of the mean while the sky's sun lit through its lobe, 1.11 % with the sun a
    # light of the map's 16 × 32 texel size (a wider penumbra, its rays split four ways in both images).
    once = outs[("--aa-shading", "pixel")]
    assert np.median(np.abs(once - aa4)) < 0.015 * aa4.mean() and np.abs(once - aa1).max() > 0.01
    # At the silhouettes (a pixel beside one of another material, or the sky) once is nearer aa4 than one sample is
    # (measured on its 102 such pixels: mean |once − aa4| 0.0183 against |aa1 − aa4| 0.0382; the rest is the rays'
    # noise, drawn differently, and shading across a pixel); its first sample alone would be as far as aa1.
    sf = wb.load_scene(str(scene))
    g = wb.get_backend("warp:cpu").trace_primary(sf.scene.mesh, sf.scene.camera)
    material = np.where(g.face >= 0, sf.scene.mesh.face_material[np.maximum(g.face, 0)], -1).reshape(aa4.shape[:2])
    edge = np.zeros(material.shape, bool)
    for axis in (0, 1):
        step = np.diff(material, axis=axis) != 0
        edge[(slice(1, None), slice(None))[::1 - 2 * axis]] |= step
        edge[(slice(None, -1), slice(None))[::1 - 2 * axis]] |= step
    assert edge.sum() > 20 and np.abs(once - aa4)[edge].mean() < 0.75 * np.abs(aa1 - aa4)[edge].mean()
    for bad, what in ((["--aa", "0"], "aa must be"), (["--shadow-samples", "0"], "shadow samples must be"),
                      (["--occlusion-samples", "33"], "occlusion samples must be"),
                      (["--method", "mc", "--aa", "4"], "--aa is for the SG renderer"),
                      (["--method", "mc", "--occlusion-samples", "8"], "--occlusion-samples is for the SG renderer"),
                      (["--method", "mc", "--every-ray-per-sample"], "--every-ray-per-sample is for the SG"),
                      (["--method", "mc", "--block-rays"], "--block-rays is for the SG"),
                      (["--method", "mc", "--block-side", "4"], "--block-side is for the SG"),
                      (["--method", "mc", "--block-side", "2"], "--block-side is for the SG"),
                      (["--method", "mc", "--aa-shading", "pixel"], "--aa-shading is for the SG")):
        assert cli.main(["render", str(scene), "-o", str(tmp_path / "bad.png"), *bad]) == 2
        err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning:")]
        assert len(err) == 1 and what in err[0], err  # (the tiny scene's EnergyWarning aside)
        assert not (tmp_path / "bad.png").exists()


@pytest.mark.parametrize("block_rays", [False, True])
def test_aa_shaded_once_a_pixel(backend, block_rays):
    """aa_shading="pixel": the first sample traces every ray of each set (shared in 2×2 blocks with block_rays) and
    is shaded whole; a later sample k adds its own shade (its part (k, n) of each set, never shared) where its hit
    is off the first sample's surface at that pixel (trace.changed_pixels, the float64 twin of mark_changed), and
    the first sample's radiance elsewhere. Against the shade of each jittered G-buffer with those rays
    (pack_frame), where the float64 decision holds with the bounds moved by 1e-4 either way: to the device sum's
    float32 rounding (measured 5.0e-8 Warp CPU, 5.6e-8 PoCL → 1e-6 of the peak); a later sample changes a few
    pixels, not most (3.8 % here, where the same face alone would have changed 32 %). Bad values, and the option
    with another method, are refused in one line."""
    import dataclasses

    from warp_biscale.render import pack_frame

    scene = _contact_scene()
    mesh, n = scene.mesh, 4
    got = wb.render(scene, backend=backend, aa=n, aa_shading="pixel", block_rays=block_rays)
    assert got.info["aa_shading"] == "pixel"
    image = got.image.reshape(-1, 3)
    frames, images = [], []
    for k, (jx, jy) in enumerate(aa_offsets(n)):
        cam = dataclasses.replace(scene.camera, jitter=(jx, jy))
        one = wb.Scene(scene.mesh, scene.materials, cam, scene.environment, scene.lights)
        first_part = (0, 1, cam.width) if block_rays else (0, 1)
        frame = pack_frame(one, backend, part=first_part if k == 0 else (k, n))
        images.append(backend.shade(mesh, frame.inputs, frame.camera, frame.lights, gbuffer=frame.gbuffer)
                      .astype(np.float64))
        frames.append(frame.gbuffer)
    first, sure = frames[0], np.ones(len(image), bool)
    want = images[0] / n
    for k in range(1, n):
        g = frames[k]
        args = (g.face, g.position, first.face, first.position, mesh.face_normals, mesh.face_material, g.eye)
        changed = trace_module.changed_pixels(*args)
        loose, tight = (trace_module.changed_pixels(*args, normal_cos=trace_module.SHARE_NORMAL_COS + s * 1e-4,
                                                    plane=trace_module.SHARE_PLANE - s * 1e-4) for s in (1, -1))
        sure &= loose == tight
        assert 0 < changed.mean() < 0.1, changed.mean()
        want = want + np.where(changed[:, None], images[k], images[0]) / n
    assert sure.mean() > 0.99
    assert np.abs(image - want)[sure].max() < 1e-6 * want.max()
    # The viewer's and the benchmarks' frame (queued with no waits, left on the device) is the same image.
    wb.queue_frame(scene, backend, aa=n, aa_shading="pixel", block_rays=block_rays)
    queued = backend.accumulated_frame(mesh, scene.camera.width, scene.camera.height).reshape(-1, 3)
    assert np.abs(queued - image).max() <= 1e-6 * want.max()
    for bad, message in (({"split_rays": "yes"}, "split_rays must be True or False"),
                         ({"block_rays": 3}, "block_rays must be True, False, 'auto' or a block side"),
                         ({"occlusion_samples": 99}, "occlusion samples"), ({"aa": 0}, "aa"),
                         ({"aa_shading": "msaa"}, "aa_shading must be one of")):
        with pytest.raises(ValueError, match=message):
            wb.queue_frame(scene, backend, **bad)
    with pytest.raises(ValueError, match="aa_shading must be one of"):
        wb.render(scene, backend=backend, aa=n, aa_shading="msaa")
    with pytest.raises(ValueError, match="options of the SG renderer"):
        wb.render(scene, method="litsphere", backend=backend, aa=n, aa_shading="pixel")
    # Ray options of the SG renderer, given to a method that traces no such rays: refused, not silently dropped
    # (before any work: no backend is made).
    for method, options in (("mc", {"shadow_samples": 1}), ("mc", {"occlusion_samples": 0}),
                            ("mc", {"split_rays": False}), ("litsphere", {"occlusion_samples": 4})):
        with pytest.raises(ValueError, match=rf"^{next(iter(options))}: option\(s\) of the SG renderer "
                                             rf"\(method='sg'\), not of method='{method}'"):
            wb.render(scene, method=method, backend="no such backend", **options)


def _contact_scene(width=40, height=30):
    """A sphere on a floor under a constant sky and a point light with a radius: occlusion rays, lobe-free, and
    a soft shadow, all of them split between anti-aliasing samples."""
    mesh = wb.Mesh.merge([wb.Mesh.sphere(1.0, (0, 1, 0), material=0), wb.Mesh.plane(8.0, 0.0, 8, material=1)])
    return wb.Scene(mesh, [wb.Lambert(0.8), wb.Lambert(0.5)],
                    wb.Camera(eye=(0, 2.2, 5), target=(0, 0.8, 0), width=width, height=height),
                    wb.Environment.constant(1.0), [wb.PointLight((2, 3, 2), 10.0, 0.4)])


@pytest.mark.parametrize("block_rays", [True, False])
def test_anti_aliasing_samples_share_the_ray_sets(backend, block_rays):
    """aa = 4 (split_rays, the default): sample k traces part (k, 4) of each set of rays, shared in 2×2 pixel
    blocks with block_rays (part (k, 4, W)). Against the float64 reference of that frame, the mean
    over k of shade_reference of the jittered G-buffer with that part's rays (tolerances of test_shade: the same
    float32-against-float64 agreement, now averaged over four samples); against every sample and pixel tracing
    every ray (split_rays=False, block_rays=False), the same image up to the rays' noise: 16 rays a set per pixel
    instead of 64 (4 of its own with blocks), unbiased (measured on Warp CPU and PoCL without blocks: mean |Δ|
    0.76 % of the mean pixel, the means 0.07 % apart; with blocks, whose rays also leave from points up to two
    pixels apart, on Warp CPU: 2.44 %, 0.045 % apart)."""
    import dataclasses

    from warp_biscale.render import pack_frame
    from warp_biscale.shading import shade_reference

    scene = _contact_scene()
    n = 4
    got = wb.render(scene, backend=backend, aa=n, block_rays=block_rays)
    assert got.info["split_rays"] is True and got.info["block_rays"] == (2 if block_rays else 1)
    want = 0.0
    for k, (jx, jy) in enumerate(aa_offsets(n)):
        cam = dataclasses.replace(scene.camera, jitter=(jx, jy))
        one = wb.Scene(scene.mesh, scene.materials, cam, scene.environment, scene.lights)
        frame = pack_frame(one, backend, part=(k, n, cam.width) if block_rays else (k, n))
        want = want + shade_reference(frame).reshape(got.image.shape) / n
    peak = want.max()
    err = np.abs(got.image - want)
    assert np.quantile(err / (np.abs(want) + 1e-3 * peak), 0.999) < 2e-3 and err.max() < 2e-2 * peak, err.max()
    every = wb.render(scene, backend=backend, aa=n, split_rays=False, block_rays=False).image
    print(f"{backend.name} block_rays={block_rays}: mean |Δ| {np.abs(got.image - every).mean() / every.mean():.4f}, "
          f"means {abs(got.image.mean() - every.mean()) / every.mean():.5f} apart")
    assert np.abs(got.image - every).mean() < (0.03 if block_rays else 0.02) * every.mean()
    assert abs(got.image.mean() - every.mean()) < 0.005 * every.mean()
    with pytest.raises(ValueError, match="split_rays must be True or False"):
        wb.render(scene, backend=backend, aa=n, split_rays=1)
    with pytest.raises(ValueError, match="block_rays must be True, False, 'auto' or a block side 1, 2 or 4"):
        wb.render(scene, backend=backend, block_rays="yes")


def test_block_rays_auto_shares_rays_from_qvga_up(backend):
    """block_rays="auto" (the default) shares the rays in 2×2 blocks (block_rays=True or 2) from
    render.BLOCK_RAYS_MIN_PIXELS (320×240) pixels up and not below (False or 1): the same images, bit for bit (the
    same rays), and info["block_rays"] says which side. The contact scene at 320×240 and at 318×240 (the last even
    width below), each against both explicit settings, which differ."""
    from warp_biscale.render import BLOCK_RAYS_MIN_PIXELS

    assert BLOCK_RAYS_MIN_PIXELS == 320 * 240
    for width, side in ((320, 2), (318, 1)):
        scene = _contact_scene(width, 240)
        auto = wb.render(scene, backend=backend)
        assert auto.info["block_rays"] == side
        on = wb.render(scene, backend=backend, block_rays=True).image
        off = wb.render(scene, backend=backend, block_rays=False).image
        assert np.abs(on - off).max() > 0.01  # the setting shows in the image
        assert np.array_equal(auto.image, on if side == 2 else off)
        assert np.array_equal(wb.render(scene, backend=backend, block_rays=side).image, auto.image)
        wb.queue_frame(scene, backend)  # the viewer's frame takes the same default
        queued = backend.frame_radiance(scene.mesh, width, 240).reshape(auto.image.shape)
        assert np.array_equal(queued, auto.image)
    from warp_biscale.render import frame_block_rays

    with pytest.raises(ValueError, match="block_rays must be True, False, 'auto' or a block side"):
        frame_block_rays("off", _contact_scene().camera)


def test_block_sides_say_which_side_each_set_of_rays_got(backend):
    """info["block_sides"] is the side each set of rays was shared in, which a 4 asked of the frame need not give:
    with aa = 4 splitting the default 16 rays a set, a sample holds 4 rays of each, too few for a 4×4 block, so
    every set goes 2×2 and the image is the 2×2 one bit for bit; with aa_shading "pixel" the first sample traces
    every ray, the sets go 4×4, and the image differs from the 2×2 one."""
    scene = _contact_scene(64, 48)
    for aa_shading, side in (("sample", 2), ("pixel", 4)):
        four = wb.render(scene, backend=backend, aa=4, block_rays=4, aa_shading=aa_shading)
        two = wb.render(scene, backend=backend, aa=4, block_rays=2, aa_shading=aa_shading)
        assert four.info["block_rays"] == 4 and two.info["block_rays"] == 2
        assert four.info["block_sides"] == {"shadow": [side], "occlusion": side, "lobe_rays": None}
        assert two.info["block_sides"] == {"shadow": [2], "occlusion": 2, "lobe_rays": None}
        assert np.array_equal(four.image, two.image) == (side == 2)
    one = wb.render(scene, backend=backend, block_rays=False).info
    assert one["block_rays"] == 1 and one["block_sides"] == {"shadow": [1], "occlusion": 1, "lobe_rays": None}


def test_block_rays_auto_takes_4x4_blocks_from_1080p_up(backend):
    """From render.BLOCK_RAYS_4_MIN_PIXELS (1920×1080) pixels up "auto" shares each set of 16 rays in 4×4 blocks
    (block_rays=4), bit for bit, and says so; below it (1918×1080) 2×2. A 4×4 frame differs from the 2×2 one (a
    pixel traces one ray of each set, not four) by shadow noise and blur alone: their mean radiance within 1 %
    (measured 0.005 % apart on Warp CPU and PoCL)."""
    from warp_biscale.render import BLOCK_RAYS_4_MIN_PIXELS, frame_block_rays

    assert BLOCK_RAYS_4_MIN_PIXELS == 1920 * 1080
    assert frame_block_rays("auto", _contact_scene(1918, 1080).camera) == 2
    scene = _contact_scene(1920, 1080)
    auto = wb.render(scene, backend=backend)
    assert auto.info["block_rays"] == 4
    four = wb.render(scene, backend=backend, block_rays=4).image
    two = wb.render(scene, backend=backend, block_rays=2).image
    assert np.array_equal(auto.image, four)
    assert np.abs(four - two).max() > 0.01
    print(f"{backend.name}: 4x4 mean {four.mean():.5f}, 2x2 mean {two.mean():.5f}")
    assert abs(four.mean() - two.mean()) < 0.01 * two.mean(), (four.mean(), two.mean())
