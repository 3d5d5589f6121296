"""Image files and metrics: EXR and Radiance HDR round trips through real files, RLE scanlines
decoded from a file encoded by hand here, truncated/corrupt files refused, tone mapping, atomic
writes, and compare_images on arrays whose errors are known."""

import errno
import math
import os
import re

import numpy as np
import pytest

from warp_biscale import images


def hdr_image(h=6, w=11, seed=0):
    """Linear RGB with zeros, values far above 1 and a grey patch."""
    rng = np.random.default_rng(seed)
    img = (rng.random((h, w, 3)) ** 3 * 50).astype(np.float32)
    img[0, 0] = 0.0
    img[1, 2] = (1000.0, 0.0, 1e-3)
    img[2, 3:6] = 0.25
    return img


# ---------------------------------------------------------------------------------------------
# EXR


def test_exr_round_trip_is_exact(tmp_path):
    img = hdr_image()
    path = tmp_path / "a.exr"
    images.write_exr(path, img)
    back = images.read_exr(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    np.testing.assert_array_equal(back, img)  # float32 channels, lossless ZIP: bit-exact
    np.testing.assert_array_equal(images.read_image(path), img)


def test_exr_grey_input_becomes_rgb(tmp_path):
    grey = np.linspace(0, 2, 12, dtype=np.float32).reshape(3, 4)
    images.write_image(tmp_path / "g.exr", grey)
    np.testing.assert_array_equal(images.read_image(tmp_path / "g.exr"), np.repeat(grey[..., None], 3, 2))


@pytest.mark.parametrize("cut", [10, 200, -20, 0.5])
def test_exr_truncated_or_corrupt_is_valueerror(tmp_path, capfd, cut):
    good = tmp_path / "good.exr"
    images.write_exr(good, hdr_image(32, 32))
    data = good.read_bytes()
    bad = tmp_path / "bad.exr"
    bad.write_bytes(data[:int(cut * len(data)) if isinstance(cut, float) else cut])
    with pytest.raises(ValueError, match="bad.exr"):
        images.read_exr(bad)
    out, err = capfd.readouterr()  # OpenEXR's C++ lines for the cut file do not reach the terminal
    assert out == "" and err == "", (out, err)
    print("after")  # and the descriptors are back
    assert capfd.readouterr().out == "after\n"


def test_exr_garbage_is_valueerror(tmp_path):
    bad = tmp_path / "x.exr"
    bad.write_bytes(b"not an exr at all")
    with pytest.raises(ValueError, match="x.exr"):
        images.read_image(bad)


def test_writers_refuse_nan_inf_negative(tmp_path):
    for bad_value in (np.nan, np.inf, -1.0):
        img = hdr_image()
        img[2, 2, 1] = bad_value
        for ext in (".exr", ".hdr", ".png"):
            path = tmp_path / f"bad{ext}"
            with pytest.raises(ValueError, match="NaN|negative"):
                images.write_image(path, img)
            assert not path.exists()


# ---------------------------------------------------------------------------------------------
# Radiance HDR


def test_hdr_round_trip_within_rgbe_quantisation(tmp_path):
    img = hdr_image(9, 13)
    path = tmp_path / "a.hdr"
    images.write_hdr(path, img)
    back = images.read_hdr(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    # Each pixel shares one exponent: 8-bit mantissas rounded to nearest, so the error is at most half
    # a step, 2^-9 of the pixel's largest channel (≤ 2^-8 allowing for the exponent bump on rounding up).
    bound = img.max(-1, keepdims=True) * 2.0 ** -8
    assert np.all(np.abs(back - img) <= bound + 1e-30)
    assert back[0, 0].tolist() == [0, 0, 0] and back[1, 2, 1] == 0  # zeros stay exactly zero
    np.testing.assert_array_equal(images.read_image(path), back)


def test_hdr_exactly_representable_values_round_trip_exactly(tmp_path):
    img = np.array([[[1.0, 0.5, 0.25], [4.0, 4.0, 4.0]], [[0, 0, 0], [2.0 ** -20, 0, 2.0 ** -21]]], np.float32)
    images.write_hdr(tmp_path / "e.pic", img)
    np.testing.assert_array_equal(images.read_image(tmp_path / "e.pic"), img)


def rle_plane(plane: bytes) -> bytes:
    """Encode one byte plane the way Radiance does: runs of >= 3 as (128 + n, byte), else literal
    blocks of <= 128 bytes (count, bytes...)."""
    out, i, n = bytearray(), 0, len(plane)
    literal = bytearray()

    def flush():
        while literal:
            chunk = literal[:128]
            out.append(len(chunk))
            out.extend(chunk)
            del literal[:128]

    while i < n:
        run = 1
        while i + run < n and plane[i + run] == plane[i] and run < 127:
            run += 1
        if run >= 3:
            flush()
            out.extend((128 + run, plane[i]))
            i += run
        else:
            literal.extend(plane[i:i + run])
            i += run
    flush()
    return bytes(out)


def write_rle_hdr(path, rgbe: np.ndarray, flat_rows=()):
    """A Radiance file with new-style RLE scanlines (rows in flat_rows stored flat instead: a reader
    decides per scanline)."""
    h, w = rgbe.shape[:2]
    body = bytearray()
    for row in range(h):
        if row in flat_rows:
            body.extend(rgbe[row].tobytes())
            continue
        body.extend((2, 2, w >> 8, w & 255))
        for c in range(4):
            body.extend(rle_plane(rgbe[row, :, c].tobytes()))
    head = f"#?RADIANCE\n# written by hand in test_images\nEXPOSURE=1.0\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n"
    with open(path, "wb") as fh:
        fh.write(head.encode() + bytes(body))


def rle_test_image(h=7, w=300):
    """Long constant runs (left), a gradient (middle) and noise (right): runs and literals, with a
    width above 255 so the width's high byte is used."""
    rng = np.random.default_rng(3)
    a, b = w // 3, 2 * w // 3
    img = np.zeros((h, w, 3), np.float32)
    img[:, :a] = (0.5, 2.0, 7.0)
    img[:, a:b] = np.linspace(0.01, 3.0, b - a)[None, :, None]
    img[:, b:] = rng.random((h, w - b, 3)) * 20
    img[3] *= 10  # a different exponent on one row
    return img


def test_hdr_rle_scanlines_decode_like_flat(tmp_path):
    img = rle_test_image()
    rgbe = images._float_to_rgbe(img)
    write_rle_hdr(tmp_path / "rle.hdr", rgbe, flat_rows={4})
    flat = tmp_path / "flat.hdr"
    images.write_hdr(flat, img)
    rle_bytes = (tmp_path / "rle.hdr").stat().st_size
    assert rle_bytes < flat.stat().st_size  # the runs really were compressed
    np.testing.assert_array_equal(images.read_hdr(tmp_path / "rle.hdr"), images.read_hdr(flat))
    np.testing.assert_array_equal(images.read_hdr(flat), images._rgbe_to_float(rgbe))


def test_hdr_old_style_runs(tmp_path):
    # Pixel A, then (1,1,1,3): A three more times; then B, (1,1,1,2) and (1,1,1,1) → 2 + (1 << 8) more Bs.
    w = 1 + 3 + 1 + 2 + 256
    a, b = (200, 100, 50, 130), (128, 128, 128, 129)
    data = bytes(a) + bytes((1, 1, 1, 3)) + bytes(b) + bytes((1, 1, 1, 2)) + bytes((1, 1, 1, 1))
    path = tmp_path / "old.hdr"
    path.write_bytes(f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X {w}\n".encode() + data)
    got = images.read_hdr(path)[0]
    want = images._rgbe_to_float(np.array([a] * 4 + [b] * (w - 4), np.uint8))
    np.testing.assert_array_equal(got, want)


def test_hdr_truncated_and_corrupt_are_valueerrors(tmp_path):
    img = rle_test_image(4, 64)
    write_rle_hdr(tmp_path / "rle.hdr", images._float_to_rgbe(img))
    images.write_hdr(tmp_path / "flat.hdr", img)
    cases = {}  # file name → (bytes, what the message must say)
    for name in ("rle", "flat"):
        data = (tmp_path / f"{name}.hdr").read_bytes()
        cases[f"cut-{name}"] = data[:-7], "truncated at scanline 3"
        cases[f"header-only-{name}"] = data[:data.index(b"+X 64\n") + 6], "truncated: 0 bytes of data for 4 x 64"
        cases[f"no-resolution-{name}"] = data[:data.index(b"\n\n") + 2], "no resolution line"
    rle = (tmp_path / "rle.hdr").read_bytes()
    start = rle.index(b"+X 64\n") + 6
    zero_count = bytearray(rle)
    zero_count[start + 4] = 0  # a literal block of length 0 is invalid
    cases["zero-count"] = bytes(zero_count), "corrupt literal block"
    wrong_width = bytearray(rle)
    wrong_width[start + 3] = 63
    cases["wrong-width"] = bytes(wrong_width), "says width 63"
    cases["not-radiance"] = b"P6\n2 2\n255\n" + bytes(12), "not a Radiance"
    cases["xyze"] = b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n" + bytes(4), "xyze is not supported"
    cases["flipped"] = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n+Y 1 +X 1\n" + bytes(4), "only '-Y H \\+X W'"
    cases["empty"] = b"", "not a Radiance"
    # a header that promises more than the file could hold, refused before the pixels' memory is taken (a 55-byte
    # file said 99999 × 99999 and asked for 37 GiB)
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"
    cases["huge"] = head + b"-Y 99999 +X 99999\n" + bytes(16), "99999×99999 pixels: at most 67,108,864 are read"
    cases["short"] = head + b"-Y 2000 +X 2000\n" + bytes(16), "truncated: 16 bytes of data for 2000 x 2000"
    for name, (data, message) in cases.items():
        path = tmp_path / f"{name}.hdr"
        path.write_bytes(data)
        with pytest.raises(ValueError, match=f"{name}.hdr.*{message}"):
            images.read_hdr(path)


def test_missing_file_and_unknown_extension(tmp_path):
    with pytest.raises(FileNotFoundError):
        images.read_image(tmp_path / "nope.exr")
    (tmp_path / "x.tiff").write_bytes(b"II*\0")
    with pytest.raises(ValueError, match="extension"):
        images.read_image(tmp_path / "x.tiff")
    with pytest.raises(ValueError, match="extension"):
        images.write_image(tmp_path / "x.tiff", hdr_image())
    with pytest.raises(ValueError, match="operator"):
        images.write_image(tmp_path / "x.exr", hdr_image(), operator="filmic")
    assert sorted(os.listdir(tmp_path)) == ["x.tiff"]


def test_write_image_exposure_only_shapes_the_png(tmp_path):
    img = hdr_image()
    images.write_image(tmp_path / "a.exr", img, exposure=3.0)  # linear files: radiance unchanged
    np.testing.assert_array_equal(images.read_image(tmp_path / "a.exr"), img)


# ---------------------------------------------------------------------------------------------
# sRGB, tone mapping, PNG, npy


def test_srgb_curves_invert_each_other():
    v = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(images.linear_to_srgb(images.srgb_to_linear(v)), v, atol=1e-12)
    assert images.linear_to_srgb(0.0018) == pytest.approx(12.92 * 0.0018)  # linear toe
    assert images.linear_to_srgb(0.5) == pytest.approx(0.735356983, abs=1e-8)


@pytest.mark.parametrize("operator", images.TONEMAP_OPERATORS)
def test_tonemap_monotone_zero_and_white(operator):
    x = np.concatenate([[0.0], np.geomspace(1e-5, 1e4, 4000)]).astype(np.float32)
    u8 = images.tonemap(np.repeat(x[None, :, None], 3, 2), operator=operator)
    assert u8.dtype == np.uint8 and u8.shape == (1, len(x), 3)
    assert np.all(np.diff(u8[0, :, 0].astype(int)) >= 0)
    assert u8[0, 0].tolist() == [0, 0, 0]
    assert u8[0, -1].tolist() == [255, 255, 255]


def test_tonemap_exposure_is_stops_and_operators_differ():
    img = hdr_image()
    np.testing.assert_array_equal(images.tonemap(img, exposure=1.0), images.tonemap(2 * img))
    np.testing.assert_array_equal(images.tonemap(img, exposure=-2.0, operator="clamp"),
                                  images.tonemap(img / 4, operator="clamp"))
    mid = np.full((1, 1, 3), 0.5, np.float32)
    assert images.tonemap(mid, operator="clamp")[0, 0, 0] == round(255 * 0.735356983)
    assert images.tonemap(mid, operator="reinhard")[0, 0, 0] == round(255 * images.linear_to_srgb(1 / 3))
    aces = 0.5 * (2.51 * 0.5 + 0.03) / (0.5 * (2.43 * 0.5 + 0.59) + 0.14)
    assert images.tonemap(mid, operator="aces")[0, 0, 0] == round(255 * float(images.linear_to_srgb(aces)))


def test_tonemap_refuses_bad_input():
    for bad_value in (np.nan, np.inf, -0.5):
        img = hdr_image()
        img[0, 1, 2] = bad_value
        with pytest.raises(ValueError):
            images.tonemap(img)
    with pytest.raises(ValueError, match="operator"):
        images.tonemap(hdr_image(), operator="filmic")
    with pytest.raises(ValueError, match="exposure"):
        images.tonemap(hdr_image(), exposure=float("nan"))
    with pytest.raises(ValueError, match="shape"):
        images.tonemap(np.zeros((4, 4, 2)))


def test_png_written_is_the_tonemapped_image_and_reads_back_linear(tmp_path):
    from PIL import Image

    img = hdr_image() / 50
    path = tmp_path / "a.png"
    images.write_image(path, img, exposure=0.5, operator="reinhard")
    with Image.open(path) as im:
        assert im.mode == "RGB"
        u8 = np.asarray(im)
    np.testing.assert_array_equal(u8, images.tonemap(img, exposure=0.5, operator="reinhard"))
    # read_image decodes sRGB: a clamp-mapped image in [0, 1] comes back within 8-bit quantisation.
    lin = np.clip(img, 0, 1)
    images.write_png(path, lin, operator="clamp")
    back = images.read_image(path)
    assert back.dtype == np.float32
    np.testing.assert_allclose(back, lin, atol=0.01)


def test_jpg_and_npy_read(tmp_path):
    from PIL import Image

    Image.fromarray(np.full((4, 5, 3), 255, np.uint8)).save(tmp_path / "w.jpg")
    np.testing.assert_allclose(images.read_image(tmp_path / "w.jpg"), 1.0, atol=0.01)
    arr = hdr_image()
    np.save(tmp_path / "a.npy", arr)
    np.testing.assert_array_equal(images.read_image(tmp_path / "a.npy"), arr)
    np.save(tmp_path / "bad.npy", np.zeros((2, 3, 4)))
    with pytest.raises(ValueError, match="bad.npy"):
        images.read_image(tmp_path / "bad.npy")
    (tmp_path / "trunc.png").write_bytes(b"\x89PNG\r\n\x1a\n\0\0")
    with pytest.raises(ValueError, match="trunc.png"):
        images.read_image(tmp_path / "trunc.png")


# ---------------------------------------------------------------------------------------------
# atomic writes


def _only(tmp_path, name):
    """The folder holds just `name`: no temporary file was left behind."""
    assert sorted(os.listdir(tmp_path)) == [name]


def test_failed_exr_write_keeps_the_old_file(tmp_path, monkeypatch):
    import OpenEXR

    path = tmp_path / "keep.exr"
    old = hdr_image(seed=1)
    images.write_exr(path, old)

    def broken_write(self, filename):
        with open(filename, "wb") as fh:  # half a file, then the failure, as the binding words it
            fh.write(b"v/1\x01partial")
        raise RuntimeError(f'Failed to write pixel data to image file "{filename}". No space left on device.')

    def empty_write(self, filename):  # what OpenEXR does on a full disk for an image its buffer holds
        open(filename, "wb").close()

    for write, words in ((broken_write, "No space left on device"), (empty_write, r"nothing was written")):
        monkeypatch.setattr(OpenEXR.File, "write", write)
        with pytest.raises(OSError, match=rf"^{re.escape(str(path))} could not be written: {words}") as info:
            images.write_exr(path, hdr_image(seed=2))
        assert info.value.errno in (errno.ENOSPC, errno.EIO)
        monkeypatch.undo()
        np.testing.assert_array_equal(images.read_exr(path), old)
        _only(tmp_path, "keep.exr")


def test_failed_png_and_hdr_writes_keep_the_old_file(tmp_path, monkeypatch):
    from PIL import Image

    png, hdr = tmp_path / "keep.png", tmp_path / "keep.hdr"
    images.write_png(png, hdr_image())
    images.write_hdr(hdr, hdr_image())
    before = png.read_bytes(), hdr.read_bytes()

    def broken_save(self, fp, *a, **k):
        raise OSError("no space left on device")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OSError, match="no space"):
        images.write_png(png, hdr_image(seed=5))
    def broken_open(name, mode="r", *a, **k):
        fh = open(name, mode, *a, **k)
        fh.write(b"#?RADIANCE\n")  # half a file, then the failure
        fh.close()
        raise OSError("no space left on device")

    monkeypatch.setattr(images, "open", broken_open, raising=False)  # the module's own `open`
    with pytest.raises(OSError, match="no space"):
        images.write_hdr(hdr, hdr_image(seed=5))
    assert (png.read_bytes(), hdr.read_bytes()) == before
    assert sorted(os.listdir(tmp_path)) == ["keep.hdr", "keep.png"]


def test_overwrite_replaces(tmp_path):
    path = tmp_path / "a.exr"
    images.write_image(path, hdr_image(seed=1))
    images.write_image(path, hdr_image(seed=2))
    np.testing.assert_array_equal(images.read_image(path), hdr_image(seed=2))
    _only(tmp_path, "a.exr")


# ---------------------------------------------------------------------------------------------
# compare_images


def test_compare_images_known_errors():
    b = np.zeros((4, 5, 3))
    b[..., 0] = 2.0
    b[..., 1] = 1.0
    b[..., 2] = 0.01  # below 1% of the peak (2.0): left out of mean_rel
    a = b + 0.1
    m = images.compare_images(a, b)
    assert m["rmse"] == pytest.approx(0.1)
    assert m["psnr"] == pytest.approx(20 * math.log10(2.0 / 0.1))
    assert m["max_abs"] == pytest.approx(0.1)
    assert m["mean_rel"] == pytest.approx((0.1 / 2 + 0.1 / 1) / 2)
    assert m["n_pixels"] == 20


def test_compare_images_mask_identical_and_errors():
    rng = np.random.default_rng(0)
    b = rng.random((6, 7, 3))
    a = b.copy()
    a[0, 0] += 5.0  # one bad pixel, masked out
    mask = np.ones((6, 7), bool)
    mask[0, 0] = False
    m = images.compare_images(a, b, mask=mask)
    assert m["rmse"] == 0 and m["psnr"] == math.inf and m["max_abs"] == 0 and m["n_pixels"] == 41
    full = images.compare_images(a, b)
    assert full["max_abs"] == pytest.approx(5.0)
    assert full["rmse"] == pytest.approx(math.sqrt(3 * 25 / (42 * 3)))
    # Reference is b: swapping arguments changes peak and mean_rel.
    assert images.compare_images(b, a)["psnr"] > full["psnr"]
    with pytest.raises(ValueError, match="shape"):
        images.compare_images(a, b[:, :-1])
    with pytest.raises(ValueError, match="mask"):
        images.compare_images(a, b, mask=np.ones((6, 6), bool))
    with pytest.raises(ValueError, match="no pixel"):
        images.compare_images(a, b, mask=np.zeros((6, 7), bool))
    a[1, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        images.compare_images(a, b)
