"""Image files and image comparison: float EXR and Radiance HDR, tone-mapped PNG, error metrics.

Every image here is an (H, W, 3) array of linear RGB, row 0 at the top. Radiance images written to
disk must be finite and >= 0 (docs/design.md §7: no NaN or negative radiance reaches an output file), and
every write is atomic (`io.atomic_path`): a reader never sees a half-written file and a failed write
keeps the old one.

    img = read_image("studio.hdr")              # .exr .hdr .pic .png .jpg .jpeg .npy -> (H, W, 3) float32
    write_image("out.exr", img)                 # .exr .hdr .pic .png (exposure=, operator= shape the png)
    u8 = tonemap(img, exposure=1.0)             # (H, W, 3) uint8 sRGB
    compare_images(render, reference)           # {"rmse", "psnr", "max_abs", "mean_rel", "n_pixels"}
"""

from __future__ import annotations

import contextlib
import errno
import io
import math
import os
import sys
import warnings

import numpy as np
import OpenEXR
from PIL import Image, UnidentifiedImageError

from .io import atomic_path

__all__ = [
    "read_exr", "write_exr", "read_hdr", "write_hdr", "read_image", "write_image", "write_png",
    "tonemap", "srgb_to_linear", "linear_to_srgb", "compare_images",
]

TONEMAP_OPERATORS = ("aces", "reinhard", "clamp")


# ---------------------------------------------------------------------------------------------
# validation


def _as_rgb(image, what: str) -> np.ndarray:
    """(H, W, 3) or (H, W) (grey) → (H, W, 3) float32; anything else is a ValueError naming `what`."""
    a = np.asarray(image)
    if a.dtype.kind not in "fiub":
        raise ValueError(f"{what} must be a numeric array, got dtype {a.dtype}")
    a = a.astype(np.float32)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{what} must be an (H, W, 3) RGB image, got shape {np.shape(image)}")
    return a


def _check_radiance(a: np.ndarray, what: str) -> None:
    """Refuse NaN, inf and negative values: they must never be written to a file."""
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{what} holds {int(bad.sum())} NaN/inf value(s); refusing to write or tone-map it")
    if (a < 0).any():
        raise ValueError(f"{what} holds negative values (min {float(a.min())}); refusing to write or tone-map it")


# ---------------------------------------------------------------------------------------------
# OpenEXR (the `OpenEXR` package, 3.x API: OpenEXR.File(header, channels) / OpenEXR.File(path))


def write_exr(path, image) -> None:
    """Write an (H, W, 3) linear RGB image as a float32 (not half) ZIP-compressed scanline EXR."""
    a = _as_rgb(image, f"image for {os.fspath(path)}")
    _check_radiance(a, f"image for {os.fspath(path)}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        try:
            with OpenEXR.File(header, {"RGB": np.ascontiguousarray(a)}) as f:
                f.write(tmp)
        except RuntimeError as exc:  # (the binding's error for a failed write names the temporary)
            full = "No space" in str(exc)
            raise OSError(errno.ENOSPC if full else errno.EIO, os.strerror(errno.ENOSPC) if full else str(exc),
                          tmp) from None
        if os.path.getsize(tmp) == 0:  # a small image fails only when its buffer is flushed, unreported
            raise OSError(errno.ENOSPC, "nothing was written (is the disk full?)", tmp)


@contextlib.contextmanager
def _c_output_silenced():
    """Output to /dev/null for the block: OpenEXR prints its own lines for a corrupt file, before the
    error we raise says the same in one line."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            yield  # (the binding prints its warning through Python's sys.stdout, the C++ library to the descriptors)
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def read_exr(path) -> np.ndarray:
    """→ (H, W, 3) float32 from an EXR with R, G, B channels (half or float; a lone Y channel is grey)."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    try:
        with _c_output_silenced():
            with OpenEXR.File(path, separate_channels=True) as f:
                channels = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except (RuntimeError, ValueError, IndexError, OSError) as exc:
        # The binding raises RuntimeError for a file it cannot open, and for one whose pixel data is cut
        # it prints a warning, keeps no part, then fails on part 0 with a ValueError.
        raise ValueError(f"{path} is not a readable EXR file (truncated or corrupt?): {exc}") from None
    if all(c in channels for c in "RGB"):
        rgb = np.stack([channels["R"], channels["G"], channels["B"]], -1)
    elif "Y" in channels:
        rgb = np.repeat(channels["Y"][..., None], 3, axis=2)
    else:
        raise ValueError(f"{path} has channels {sorted(channels)}; expected R, G, B (or Y)")
    return np.ascontiguousarray(rgb, dtype=np.float32)


# ---------------------------------------------------------------------------------------------
# Radiance RGBE (.hdr / .pic)
#
# A file is a text header ("#?RADIANCE" or "#?RGBE", then VAR=value lines, then a blank line), a
# resolution line, then H scanlines of W pixels of 4 bytes (R, G, B mantissas and a shared exponent
# E). We read the standard orientation "-Y H +X W" only (row 0 at the top, x to the right); any other
# is refused rather than silently flipped. A scanline is stored flat, flat with old-style runs
# (a pixel 1,1,1,n repeats the previous pixel n << shift times), or new-style RLE (bytes 2, 2, W>>8,
# W&255, then each of the four byte planes run-length coded: a count c > 128 repeats the next byte
# c - 128 times, a count 1..128 is followed by c literal bytes).
#
# Decoding: value = m · 2^(E − 136), E = 0 → 0 (Walter's rgbe.c, stb_image, OpenCV). Radiance's own
# reader adds ½ to m; we don't, so that a zero channel reads as exactly zero, and our writer rounds to
# nearest so that its round trip is unbiased (error ≤ 2^−9 of the pixel's largest channel).


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBE → (..., 3) float32."""
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return (rgbe[..., :3].astype(np.float64) * scale[..., None]).astype(np.float32)


def _float_to_rgbe(a: np.ndarray) -> np.ndarray:
    """(..., 3) finite float >= 0 → (..., 4) uint8 RGBE, mantissas rounded to nearest."""
    a = np.asarray(a, np.float64)
    vmax = a.max(-1)
    _, e = np.frexp(vmax)  # vmax = f · 2^e, f in [0.5, 1)  →  largest mantissa in [128, 256)
    m = np.rint(a * np.ldexp(1.0, 8 - e)[..., None])
    over = (m > 255).any(-1)  # rounding 255.5+ up: move to the next exponent
    e = np.where(over, e + 1, e)
    m = np.rint(a * np.ldexp(1.0, 8 - e)[..., None])
    if (vmax > 0).any() and (e[vmax > 0] + 128 > 255).any():
        raise ValueError(f"radiance {float(vmax.max())} is too large for RGBE (max about 1.7e38)")
    out = np.zeros(a.shape[:-1] + (4,), np.uint8)
    keep = (vmax > 0) & (e + 128 >= 1)  # below 2^-128 the pixel is written as black
    out[..., :3] = np.where(keep[..., None], np.clip(m, 0, 255), 0).astype(np.uint8)
    out[..., 3] = np.where(keep, e + 128, 0).astype(np.uint8)
    return out


def _parse_hdr_header(data: bytes, path: str) -> tuple[int, int, int]:
    """→ (height, width, offset of the first scanline byte)."""
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE") or data.startswith(b"#?")):
        raise ValueError(f"{path} is not a Radiance HDR file (no '#?' signature)")
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise ValueError(f"{path}: truncated header (no blank line before the resolution)")
        line = data[pos:end].strip()
        pos = end + 1
        if not line:
            break
        if line.startswith(b"FORMAT="):
            fmt = line[7:].decode("ascii", "replace")
            if fmt != "32-bit_rle_rgbe":
                raise ValueError(f"{path}: FORMAT={fmt} is not supported (only 32-bit_rle_rgbe)")
    end = data.find(b"\n", pos)
    if end < 0:
        raise ValueError(f"{path}: truncated header (no resolution line)")
    res = data[pos:end].decode("ascii", "replace").split()
    if len(res) != 4 or res[0] != "-Y" or res[2] != "+X" or not (res[1].isdigit() and res[3].isdigit()):
        raise ValueError(f"{path}: resolution line {' '.join(res)!r} is not supported (only '-Y H +X W')")
    height, width = int(res[1]), int(res[3])
    if height < 1 or width < 1:
        raise ValueError(f"{path}: empty image ({height} x {width})")
    check_image_size(path, (width, height), IMAGE_PIXELS_MAX)
    # RLE packs a run of up to 127 equal bytes into 2: the data cannot be shorter than 4·H·W·2/128 bytes
    if len(data) - (end + 1) < height * width // 16:
        raise ValueError(f"{path}: truncated: {len(data) - end - 1} bytes of data for {height} x {width} pixels")
    return height, width, end + 1


def _read_rle_scanline(data: bytes, pos: int, width: int, path: str, row: int) -> tuple[np.ndarray, int]:
    """New-style RLE scanline starting after its 4-byte marker → ((W, 4) uint8, next offset)."""
    out = np.empty((4, width), np.uint8)
    n = len(data)
    for plane in range(4):
        x = 0
        while x < width:
            if pos >= n:
                raise ValueError(f"{path}: truncated at scanline {row}")
            count = data[pos]
            pos += 1
            if count > 128:  # a run of one byte
                count -= 128
                if x + count > width or pos >= n:
                    raise ValueError(f"{path}: corrupt run at scanline {row}" if pos < n
                                     else f"{path}: truncated at scanline {row}")
                out[plane, x:x + count] = data[pos]
                pos += 1
            else:  # literal bytes
                if count == 0 or x + count > width:
                    raise ValueError(f"{path}: corrupt literal block at scanline {row}")
                if pos + count > n:
                    raise ValueError(f"{path}: truncated at scanline {row}")
                out[plane, x:x + count] = np.frombuffer(data, np.uint8, count, pos)
                pos += count
            x += count
    return out.T, pos


def _read_flat_scanline(data: bytes, pos: int, width: int, path: str, row: int) -> tuple[np.ndarray, int]:
    """Flat scanline, with or without old-style runs → ((W, 4) uint8, next offset)."""
    if pos + 4 * width <= len(data):
        px = np.frombuffer(data, np.uint8, 4 * width, pos).reshape(width, 4)
        # A normalised pixel's largest mantissa is >= 128, so 1,1,1 only ever marks an old-style run.
        if not ((px[:, 0] == 1) & (px[:, 1] == 1) & (px[:, 2] == 1)).any():
            return px.copy(), pos + 4 * width
    out = np.empty((width, 4), np.uint8)
    x, shift = 0, 0
    while x < width:
        if pos + 4 > len(data):
            raise ValueError(f"{path}: truncated at scanline {row}")
        p = data[pos:pos + 4]
        pos += 4
        if p[0] == 1 and p[1] == 1 and p[2] == 1:
            count = p[3] << shift
            if x == 0 or x + count > width:
                raise ValueError(f"{path}: corrupt old-style run at scanline {row}")
            out[x:x + count] = out[x - 1]
            x += count
            shift += 8
        else:
            out[x] = np.frombuffer(p, np.uint8)
            x += 1
            shift = 0
    return out, pos


def read_hdr(path) -> np.ndarray:
    """→ (H, W, 3) float32 from a Radiance RGBE file (.hdr / .pic), flat or RLE scanlines.

    Only FORMAT=32-bit_rle_rgbe and orientation "-Y H +X W" are read; the EXPOSURE header is ignored
    (as stb_image, OpenCV and most renderers do). A truncated or corrupt file is a ValueError.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    with open(path, "rb") as fh:
        data = fh.read()
    height, width, pos = _parse_hdr_header(data, path)
    rgbe = np.empty((height, width, 4), np.uint8)
    for row in range(height):
        head = data[pos:pos + 4]
        # RLE is only defined for 8 <= W < 32768; its marker can't be a normalised pixel (b >= 128).
        if 8 <= width < 32768 and len(head) == 4 and head[0] == 2 and head[1] == 2 and head[2] < 128:
            if (head[2] << 8 | head[3]) != width:
                raise ValueError(f"{path}: scanline {row} says width {head[2] << 8 | head[3]}, header says {width}")
            rgbe[row], pos = _read_rle_scanline(data, pos + 4, width, path, row)
        else:
            rgbe[row], pos = _read_flat_scanline(data, pos, width, path, row)
    return _rgbe_to_float(rgbe)


def write_hdr(path, image) -> None:
    """Write an (H, W, 3) linear RGB image as a flat (uncompressed) Radiance RGBE file."""
    a = _as_rgb(image, f"image for {os.fspath(path)}")
    _check_radiance(a, f"image for {os.fspath(path)}")
    h, w = a.shape[:2]
    head = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode("ascii")
    body = _float_to_rgbe(a).tobytes()
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(head + body)


# ---------------------------------------------------------------------------------------------
# sRGB, tone mapping, PNG


def srgb_to_linear(v) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear (the sRGB EOTF, IEC 61966-2-1)."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v) -> np.ndarray:
    """Linear values in [0, 1] → sRGB-encoded (the sRGB OETF)."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(np.maximum(v, 0.0031308), 1 / 2.4) - 0.055)


EXPOSURE_LIMIT = 24.0  # stops: 2^±24 maps any radiance a scene has to all black or all white in 8 bits


def check_exposure(exposure) -> float:
    """A PNG exposure in stops (the image is scaled by 2^exposure: 0 leaves it, negative darkens), refused
    in one line when it is not a finite number within ±EXPOSURE_LIMIT, beyond which an 8-bit image of
    any radiance between 1e-7 and 1e7 is uniformly black or white."""
    try:
        value = float(exposure)
    except (TypeError, ValueError):
        raise ValueError(f"exposure must be a number of stops, got {exposure!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"exposure must be a finite number of stops, got {exposure!r}")
    if abs(value) > EXPOSURE_LIMIT:
        raise ValueError(f"exposure {value:g} stops would turn the whole image {'white' if value > 0 else 'black'}; "
                         f"use a value within ±{EXPOSURE_LIMIT:g} (0 leaves the radiance as it is)")
    return value


def tonemap(image, exposure: float = 0.0, operator: str = "aces") -> np.ndarray:
    """Linear (H, W, 3) radiance → (H, W, 3) uint8 sRGB for display.

    The image is scaled by 2^exposure (stops), mapped to [0, 1] per channel by `operator`, then sRGB
    encoded and rounded:
      "aces":     Narkowicz's fit of the ACES filmic curve, x(2.51x + 0.03)/(x(2.43x + 0.59) + 0.14),
                  clipped to [0, 1] (it reaches 1 at x ≈ 7.2; monotone on x >= 0);
      "reinhard": x/(1 + x);
      "clamp":    min(x, 1).
    All three map 0 to 0 and are non-decreasing. NaN, inf or negative input is a ValueError.
    """
    if operator not in TONEMAP_OPERATORS:
        raise ValueError(f"unknown tone-map operator {operator!r}; choose one of {TONEMAP_OPERATORS}")
    if not math.isfinite(exposure):
        raise ValueError(f"exposure must be finite, got {exposure}")
    a = _as_rgb(image, "image to tone-map")
    _check_radiance(a, "image to tone-map")
    x = a.astype(np.float64) * 2.0 ** exposure
    if operator == "aces":
        y = x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14)
    elif operator == "reinhard":
        y = x / (1.0 + x)
    else:
        y = x
    y = np.clip(y, 0.0, 1.0)
    return np.rint(linear_to_srgb(y) * 255.0).astype(np.uint8)


def write_png(path, image, exposure: float = 0.0, operator: str = "aces") -> None:
    """Tone-map a linear (H, W, 3) image (see `tonemap`) and write it as an 8-bit sRGB PNG."""
    u8 = tonemap(image, exposure=exposure, operator=operator)
    if not u8.any() and np.asarray(image).max() > 0:
        warnings.warn(f"{os.fspath(path)}: exposure {exposure:g} stops turns the whole image black "
                      f"(brightest radiance {float(np.asarray(image).max()):.3g}); raise it", stacklevel=2)
    with atomic_path(path) as tmp:
        Image.fromarray(u8, "RGB").save(tmp, format="PNG")


IMAGE_PIXELS_MAX = 8192 * 8192  # an image read whole, as float64 RGB: 1.6 GB at this size


def _read_pillow(path: str) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # (its size is checked here)
            im = Image.open(path)
        with im:
            check_image_size(path, im.size, IMAGE_PIXELS_MAX)
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):  # 16-bit grey PNG
                a = np.asarray(im, np.float64) / 65535.0
            else:
                a = np.asarray(im.convert("RGB"), np.float64) / 255.0
    except (UnidentifiedImageError, OSError, SyntaxError, Image.DecompressionBombError) as exc:
        raise ValueError(f"{path} is not a readable image (truncated or corrupt?): {exc}") from None
    return _as_rgb(srgb_to_linear(a), path)


def check_image_size(path, size, most: int) -> None:
    """Refuse, before decoding it, an image of more than `most` pixels (its header's `size`, (width, height)):
    a small compressed file can stand for one that fills the memory."""
    w, h = (int(x) for x in size)
    if w * h > most:
        raise ValueError(f"{os.fspath(path)} is {w}×{h} pixels: at most {most:,} are read (downsample it)")


def read_image(path) -> np.ndarray:
    """→ (H, W, 3) float32 linear RGB, by extension: .exr, .hdr/.pic (linear), .png/.jpg/.jpeg (8-bit
    sRGB decoded to linear), .npy ((H, W, 3) or (H, W) array, taken as linear)."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    if os.path.isdir(path):
        raise ValueError(f"{path} is a folder, not an image file")
    if ext == ".exr":
        return read_exr(path)
    if ext in (".hdr", ".pic"):
        return read_hdr(path)
    if ext in (".png", ".jpg", ".jpeg"):
        return _read_pillow(path)
    if ext == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise ValueError(f"{path} is not a readable .npy array: {exc}") from None
        return _as_rgb(a, path)
    raise ValueError(f"{path}: unknown image extension {ext!r} (use .exr, .hdr, .pic, .png, .jpg or .npy)")


def write_image(path, image, exposure: float = 0.0, operator: str = "aces") -> None:
    """Write by extension: .exr (float32), .hdr/.pic (RGBE), .png (tone-mapped by `write_png`).

    exposure and operator only shape the .png; the linear formats store the radiance unchanged (so one
    call can save a rendering in any format), but the operator name is checked for them too."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext == ".png":
        write_png(path, image, exposure=exposure, operator=operator)
        return
    if operator not in TONEMAP_OPERATORS:
        raise ValueError(f"unknown tone-map operator {operator!r}; choose one of {TONEMAP_OPERATORS}")
    if ext == ".exr":
        write_exr(path, image)
    elif ext in (".hdr", ".pic"):
        write_hdr(path, image)
    else:
        raise ValueError(f"{os.fspath(path)}: cannot write extension {ext!r} (use .exr, .hdr, .pic or .png)")


# ---------------------------------------------------------------------------------------------
# comparison


def compare_images(a, b, mask=None) -> dict:
    """Error of image `a` against the reference `b` (same shape, e.g. (H, W, 3)).

    mask: optional (H, W) bool selecting the pixels compared (all by default). Over the selected values:
      rmse      sqrt(mean (a − b)²);
      psnr      20·log10(peak / rmse) in dB with peak = max of b (inf when rmse = 0);
      max_abs   max |a − b|;
      mean_rel  mean |a − b| / b over the values where b >= 1% of peak (nan if there are none);
      n_pixels  number of pixels compared.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"compare_images: shapes differ, {a.shape} (image) vs {b.shape} (reference)")
    if a.ndim < 2 or a.size == 0:
        raise ValueError(f"compare_images: expected (H, W) or (H, W, C) images, got shape {a.shape}")
    for arr, what in ((a, "image"), (b, "reference")):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"compare_images: the {what} holds NaN or inf")
    if mask is None:
        mask = np.ones(a.shape[:2], bool)
    mask = np.asarray(mask)
    if mask.shape != a.shape[:2]:
        raise ValueError(f"compare_images: mask shape {mask.shape} does not match the images' {a.shape[:2]}")
    mask = mask.astype(bool)
    n = int(mask.sum())
    if n == 0:
        raise ValueError("compare_images: the mask selects no pixel")
    av, bv = a[mask], b[mask]  # (n, C) or (n,)
    diff = np.abs(av - bv)
    rmse = float(np.sqrt(np.mean(diff ** 2)))
    peak = float(bv.max())
    if rmse == 0:
        psnr = math.inf
    elif peak <= 0:
        psnr = -math.inf
    else:
        psnr = 20.0 * math.log10(peak / rmse)
    sel = bv >= 0.01 * peak if peak > 0 else np.zeros(bv.shape, bool)
    mean_rel = float(np.mean(diff[sel] / bv[sel])) if sel.any() else math.nan
    return {"rmse": rmse, "psnr": psnr, "max_abs": float(diff.max()), "mean_rel": mean_rel, "n_pixels": n}
