"""Measured isotropic BRDFs in the MERL format (Matusik et al. 2003), read, written, tabulated and evaluated.

    m = wb.MeasuredBRDF.load("blue-metallic-paint.binary")    # a file of the MERL data set
    m.eval(n, wi, wo)                                          # (N, 3) float64 f_r, like the analytic BRDFs
    t = wb.MeasuredBRDF.from_brdf(wb.CookTorrance(1.0, 0.2))   # any of our BRDFs, tabulated
    t.save("ct.binary")

**The file** (the data set's own reader, ``BRDFRead.cpp``): three little-endian int32 (90, 90, 180), the
table's dimensions over (θh, θd, φd); then 3·90·90·180 little-endian float64, channel-planar (all of red,
then green, then blue), each channel in C order over (θh, θd, φd), i.e. sample (i, j, k) of channel c at
``c·1458000 + (i·90 + j)·180 + k``. A stored number times its channel's scale (1/1500, 1.15/1500, 1.66/1500
for red, green, blue) is f_r in sr⁻¹: the reader does ``red = brdf[ind] * RED_SCALE``. A negative number
marks a sample that was not measured (in the data set: geometry below the horizon).

**The coordinates** are Rusinkiewicz's half/difference angles in the facet's frame (z = n): the half vector
h = (ωi + ωo)/|ωi + ωo| at (θh, φh), and the difference vector d, ωi rotated by −φh about n and then by −θh
about the binormal (so that h comes onto n), at (θd, φd). Isotropy drops φh; reciprocity (swapping ωi and ωo
turns d into (−dx, −dy, dz), φd into φd + π) folds φd into [0, π). The index axes, as ``BRDFRead.cpp``:

    θh: i = ⌊√(θh/(π/2))·90⌋   (a square-root axis: bins of 0.011° at the specular peak, 2° at grazing)
    θd: j = ⌊θd/(π/2)·90⌋       φd: k = ⌊φd/π·180⌋  (φd < 0 first raised by π)

each clamped into the table. Sample (i, j, k) is taken to stand for its bin's centre, i + ½ on each index
axis (so MERL's floor lookup returns the nearest centre); `from_brdf` tabulates there, and trilinear
interpolation puts its nodes there.

**On the device**, the ground truth (`wb.ground_truth`, `wb.effective_brdf_exact`, its interreflection
bounces too) and the matrix method's M (`wb.bake(method="matrix")`, `matrix.brdf_rows` with a backend) look
a MeasuredBRDF up in float32 exactly as `eval` does (kernels/common.py's `measured_cosine_weighted`, its twin
in cl/common.cl): the same tangent frame, angles by atan2, φd fold, index axes, clamping and interpolation,
on `kernel_table()` — the filled table times the channel scales, in float32 — which a backend uploads once
per table (17.5 MB) and keeps by identity. The packed row (`brdf.pack_materials(..., measured=True)`, kind
`brdf.MEASURED`) holds the table's slot among the call's tables (`brdf.measured_tables`) and the
interpolation. Measured (tests/test_measured_kernels.py): within 3.1e-5 of the peak of `eval` (trilinear;
1e-6 nearest). The SG and ASG bakes and the SG renderer use the table's SG fit instead (`sg_fit`, `fit_sg`:
one or two microfacet lobes whose NDFs are SGs, Wang §4.1–4.2; `brdf.sg_lobes`; its sums in the `sgfit` kernels). The
lit-sphere texel kernels (lit spheres read the table on the host instead) and the Mitsuba export refuse one in
one line (`packed`). The Monte Carlo reference (`montecarlo.render`) calls `eval` on the host, in float64.
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

from .brdf import COOK_TORRANCE_ROUGHNESS_MIN, MEASURED, Brdf, CookTorrance, EnergyWarning, Lambert, parse_brdf
from .io import atomic_path, check_output
from .model import BACKENDS

__all__ = ["MeasuredBRDF", "SGFit", "fit_sg", "paint_like", "small_scale_brdf", "half_diff_angles", "merl_indices",
           "RES_THETA_H", "RES_THETA_D", "RES_PHI_D", "SCALES", "INTERPOLATIONS"]

RES_THETA_H, RES_THETA_D, RES_PHI_D = 90, 90, 180  # the header: φd over [0, π) (BRDFRead.cpp's 360/2)
SHAPE = (3, RES_THETA_H, RES_THETA_D, RES_PHI_D)
SAMPLES = RES_THETA_H * RES_THETA_D * RES_PHI_D  # per channel: 1 458 000
HEADER_BYTES = 3 * 4
FILE_BYTES = HEADER_BYTES + 3 * SAMPLES * 8  # 34 992 012
SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])  # stored × scale = f_r (red, green, blue)
INTERPOLATIONS = ("trilinear", "nearest")
VALUE_MAX = 1e12  # a file's largest value (f_r times ~1500): above any measured peak, below overflow in its fits
INVALID = -1.0  # what `from_brdf` stores where a bin's centre is below the horizon (any negative marks it)
KERNEL_MODES = {"trilinear": 0, "nearest": 1}  # the interpolation's code in the kernels' packed row

_HALF_PI = np.pi / 2


def half_diff_angles(wi, wo):
    """(θh, θd, φd), each (N,), of unit directions (N, 3) in the facet's frame (z = n), as BRDFRead.cpp's
    ``std_coords_to_half_diff_coords``; φd in (−π, π] (not yet folded). The angles are taken with atan2
    of a sine and a cosine rather than acos, which loses digits next to the specular peak (θh → 0) and
    gives the same angle otherwise. Where h lies on the normal (θh = 0), φh is 0, as atan2(0, 0) in C."""
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    hx, hy, hz = h[..., 0], h[..., 1], h[..., 2]
    s = np.hypot(hx, hy)  # sin θh
    theta_h = np.arctan2(s, hz)
    safe = s > 0
    cos_phi = np.where(safe, hx / np.where(safe, s, 1.0), 1.0)
    sin_phi = np.where(safe, hy / np.where(safe, s, 1.0), 0.0)
    # d = R_y(−θh) R_z(−φh) ωi: its axes, seen in the facet's frame, are h's ∂/∂θh, ∂/∂φh directions and h.
    x, y, z = wi[..., 0], wi[..., 1], wi[..., 2]
    dx = hz * (x * cos_phi + y * sin_phi) - s * z
    dy = y * cos_phi - x * sin_phi
    dz = x * hx + y * hy + z * hz
    theta_d = np.arctan2(np.hypot(dx, dy), dz)
    phi_d = np.arctan2(dy, dx)
    return theta_h, theta_d, phi_d


def _fold_phi(phi_d):
    """φd into [0, π] by reciprocity (f at φd equals f at φd + π), as BRDFRead.cpp: φd < 0 is raised by π."""
    return np.where(phi_d < 0.0, phi_d + np.pi, phi_d)


def _continuous_indices(theta_h, theta_d, phi_d):
    """The three index-axis coordinates before truncation (BRDFRead.cpp's expressions, φd folded)."""
    ch = np.sqrt(np.maximum(theta_h, 0.0) / _HALF_PI) * RES_THETA_H
    cd = theta_d / _HALF_PI * RES_THETA_D
    cp = _fold_phi(phi_d) / np.pi * RES_PHI_D
    return ch, cd, cp


def merl_indices(theta_h, theta_d, phi_d):
    """(i, j, k) int64: MERL's nearest-sample lookup of BRDFRead.cpp (``theta_half_index``,
    ``theta_diff_index``, ``phi_diff_index``): the continuous index truncated, then clamped into the table."""
    ch, cd, cp = _continuous_indices(theta_h, theta_d, phi_d)
    i = np.clip(np.floor(ch), 0, RES_THETA_H - 1).astype(np.int64)
    j = np.clip(np.floor(cd), 0, RES_THETA_D - 1).astype(np.int64)
    k = np.clip(np.floor(cp), 0, RES_PHI_D - 1).astype(np.int64)
    return i, j, k


def bin_centres():
    """(θh (90,), θd (90,), φd (180,)): the angles at which sample (i, j, k) is taken to stand, the centre
    of its bin on each index axis: θh = ((i + ½)/90)²·π/2, θd = (j + ½)/90·π/2, φd = (k + ½)/180·π."""
    theta_h = ((np.arange(RES_THETA_H) + 0.5) / RES_THETA_H) ** 2 * _HALF_PI
    theta_d = (np.arange(RES_THETA_D) + 0.5) / RES_THETA_D * _HALF_PI
    phi_d = (np.arange(RES_PHI_D) + 0.5) / RES_PHI_D * np.pi
    return theta_h, theta_d, phi_d


def directions_of(theta_h, theta_d, phi_d):
    """(ωi, ωo), each (..., 3), in the facet's frame, of half/difference angles (broadcast together), φh = 0:
    the inverse of `half_diff_angles`. ωi = R_y(θh)·d, d = (sin θd cos φd, sin θd sin φd, cos θd); ωo is ωi
    mirrored about h, i.e. R_y(θh)·(−dx, −dy, dz)."""
    theta_h, theta_d, phi_d = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (theta_h, theta_d, phi_d)))
    ch, sh = np.cos(theta_h), np.sin(theta_h)
    dx = np.sin(theta_d) * np.cos(phi_d)
    dy = np.sin(theta_d) * np.sin(phi_d)
    dz = np.cos(theta_d)
    wi = np.stack([dx * ch + dz * sh, dy, dz * ch - dx * sh], axis=-1)
    wo = np.stack([-dx * ch + dz * sh, -dy, dz * ch + dx * sh], axis=-1)
    return wi, wo


def _tangent_frames(n):
    """(t, b), each (N, 3): a right-handed orthonormal tangent frame per unit normal (Duff et al. 2017,
    branchless, no singularity). A MERL BRDF is isotropic, so which tangent is chosen does not matter:
    φh is dropped, and a right-handed frame keeps φd's sign."""
    nx, ny, nz = n[:, 0], n[:, 1], n[:, 2]
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t = np.stack([1.0 + sign * nx * nx * a, sign * b, -sign * nx], axis=1)
    bt = np.stack([b, sign + ny * ny * a, -ny], axis=1)
    return t, bt


# Why a table none of whose samples is valid is refused: filling it (`_fill_invalid`) would make it 0 everywhere, a
# black material in every result.
_ALL_INVALID = "every sample has a negative channel, the data set's mark of a sample not measured: it would be black"


def _all_invalid(table) -> bool:
    """Whether every sample of a (3, 90, 90, 180) table is invalid (some channel negative)."""
    return bool((table < 0).any(axis=0).all())


def _fill_invalid(raw):
    """The table with its invalid (negative) samples replaced, for evaluation; `raw` itself is kept as read.

    A sample is invalid when any of its channels is negative (the data set marks a sample not measured in
    all three). It takes the values of the nearest valid sample of its (θh, φd) column along θd: the data
    set's invalid samples are the bins whose geometry dips below the horizon, at the large-θd end of such a
    column, so this continues the last measured grazing value up to the horizon — a bin's centre can lie
    below the horizon while part of the bin lies above it, and lookups there (and trilinear weights that
    reach across) get a measured neighbour rather than the marker or a black 0 that would darken every
    grazing highlight. A column with no valid sample takes the nearest valid column along θh (a table with none
    at all is refused when it is made, `_all_invalid`)."""
    invalid = (raw < 0).any(axis=0)  # (90, 90, 180)
    if not invalid.any():
        return raw
    out = raw.copy()
    for axis in (1, 0):  # θd within each column first, then θh for whole columns left empty
        valid = ~invalid
        size = valid.shape[axis]
        shape = [1, 1, 1]
        shape[axis] = size
        idx = np.arange(size).reshape(shape)
        before = np.maximum.accumulate(np.where(valid, idx, -1), axis=axis)  # last valid at or before
        after = np.flip(np.minimum.accumulate(np.flip(np.where(valid, idx, size), axis=axis), axis=axis), axis=axis)
        has_before, has_after = before >= 0, after < size
        use_before = has_before & (~has_after | (idx - before <= after - idx))
        src = np.where(use_before, before, np.where(has_after, after, idx))
        fillable = invalid & (has_before | has_after)
        gathered = np.take_along_axis(out, np.broadcast_to(src, invalid.shape)[None].repeat(3, axis=0), axis=axis + 1)
        out = np.where(fillable[None], gathered, out)
        invalid = invalid & ~fillable
        if not invalid.any():
            return out
    out[:, invalid] = 0.0
    return out


class MeasuredBRDF(Brdf):
    """An isotropic BRDF tabulated on the MERL grid (see the module's docstring), a `Brdf` like the analytic
    ones: ``eval(n, wi, wo)`` → (N, 3) float64 f_r, zero where ωi or ωo is below the facet.

    `data`: (3, 90, 90, 180) in the file's units (f_r divided by the channel's scale; negative = not
    measured), kept as given, in float64, so that `load` → `save` writes back the same bytes. Construct
    with `load`, `from_brdf` or `paint_like` rather than by hand.

    `interpolation`: "trilinear" (the default) or "nearest". "nearest" is MERL's own lookup (``BRDFRead.cpp``:
    the bin holding the query), piecewise constant, so its error is first order in the bin width — steps of
    up to a bin's change across a highlight, seen as banding in smooth reflections. "trilinear" blends the
    eight bin centres around the query on the index axes (periodic in φd, clamped at the ends of θh and θd):
    continuous, second-order error. Measured against analytic BRDFs tabulated by `from_brdf`
    (tests/test_measured.py, directions within 80° of the normal, half about the mirror direction), the
    largest error relative to the largest value is, trilinear against nearest: Blinn–Phong (exponent 64)
    0.052 % against 2.5 %, Cook–Torrance (m = 0.2) 1.3 % against 11 % (at 80°, where F/cos²θd curves
    steeply over the 1° θd bins; 0.005 % against 0.11 % within 60°). So trilinear is the default; "nearest"
    stays for comparisons with MERL's own code.

    Invalid samples are filled from measured neighbours for evaluation (see `_fill_invalid`); MERL's reader
    would return the negative marker there (and print "Below horizon.").
    """

    kind = MEASURED

    def __init__(self, data, *, interpolation: str = "trilinear", source: str | None = None):
        a = np.array(data, dtype=np.float64)  # a copy: the object owns its table
        if a.shape != SHAPE:
            raise ValueError(f"MeasuredBRDF data must have shape {SHAPE} (channel, θh, θd, φd), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"MeasuredBRDF data holds {int((~np.isfinite(a)).sum())} non-finite value(s)")
        if _all_invalid(a):
            raise ValueError(f"MeasuredBRDF data holds no valid measured sample ({_ALL_INVALID})")
        a.setflags(write=False)
        self._data = a
        self._lut = None  # the filled table, made on the first eval
        self._sg_fit = None  # the SG form, fitted on first use (`sg_fit`)
        self._sg_fit_lobes = None  # the `lobes` it was fitted with (`fit_sg`; what a material file records)
        self.source = source
        self.interpolation = _check_interpolation(interpolation)

    # -- construction -------------------------------------------------------------------------------------

    @classmethod
    def from_brdf(cls, brdf, *, interpolation: str = "trilinear") -> MeasuredBRDF:
        """Tabulate a `Brdf` (Lambert, BlinnPhong, CookTorrance, Ward, a MeasuredBRDF) — or the sum of a
        sequence of them, a layered mixture — at the MERL bin centres (`bin_centres`), in the facet's frame.

        A bin whose centre puts ωi or ωo below the horizon is stored as invalid (−1), as the data set
        marks the geometry it could not measure; every other bin holds f_r / scale. The BRDF is evaluated
        in slices of θh (bounded memory), about a second for the 1.46 M bins."""
        try:
            parts = [brdf] if isinstance(brdf, Brdf) else list(brdf)
        except TypeError:
            parts = []
        if not parts or not all(isinstance(p, Brdf) for p in parts):
            raise ValueError(f"from_brdf needs a BRDF or a non-empty list of BRDFs, got {brdf!r}")
        th, td, pd = bin_centres()
        wi, wo = directions_of(th[:, None, None], td[None, :, None], pd[None, None, :])  # (90, 90, 180, 3)
        valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        data = np.full(SHAPE, INVALID)
        step = 10  # θh rows a slice: 162 000 directions
        for i0 in range(0, RES_THETA_H, step):
            sl = slice(i0, i0 + step)
            ok = valid[sl]
            a, b = wi[sl][ok], wo[sl][ok]
            n = np.broadcast_to(np.array([0.0, 0.0, 1.0]), a.shape)
            f = sum(p.eval(n, a, b) for p in parts)
            if not np.isfinite(f).all():
                raise ValueError(f"{brdf!r} gives non-finite values at some MERL bin centres; it cannot be tabulated")
            block = data[:, sl]
            block[:, ok] = (f / SCALES).T
        names = " + ".join(repr(p) for p in parts)
        return cls(data, interpolation=interpolation, source=f"tabulated {names}")

    @classmethod
    def load(cls, path, *, interpolation: str = "trilinear") -> MeasuredBRDF:
        """Read a MERL binary file. One-line errors naming the file: FileNotFoundError if it is missing;
        ValueError if it is a directory, truncated (shorter than its header or than the table the header
        announces), has a wrong header (not 90, 90, 180 as little-endian int32; a big-endian file is named
        as such), a wrong size (bytes after the table), non-finite values or no valid (measured) sample."""
        path = os.fspath(path)
        what = f"MERL BRDF file {path}"
        if not os.path.exists(path):
            raise FileNotFoundError(f"no such MERL BRDF file: {path}")
        if os.path.isdir(path):
            raise ValueError(f"{what} is a directory, not a file")
        size = os.path.getsize(path)
        if size < HEADER_BYTES:
            raise ValueError(f"{what} is truncated: {size} bytes, shorter than its 12-byte header")
        with open(path, "rb") as fh:
            head = np.frombuffer(fh.read(HEADER_BYTES), "<i4")
            dims = tuple(int(x) for x in head)
            if dims != (RES_THETA_H, RES_THETA_D, RES_PHI_D):
                swapped = tuple(int(x) for x in head.byteswap())
                hint = " (a big-endian file; MERL files are little-endian)" if swapped == (90, 90, 180) else ""
                raise ValueError(f"{what} has a wrong header: dimensions {dims}, expected (90, 90, 180) "
                                 f"(θh, θd, φd as little-endian int32){hint}")
            if size < FILE_BYTES:
                raise ValueError(f"{what} is truncated: {size} bytes, its header announces {FILE_BYTES} "
                                 f"(12 + 3·90·90·180 float64)")
            if size > FILE_BYTES:
                raise ValueError(f"{what} has a wrong size: {size} bytes, {size - FILE_BYTES} more than the "
                                 f"{FILE_BYTES} of a 90·90·180 MERL table")
            data = np.frombuffer(fh.read(FILE_BYTES - HEADER_BYTES), "<f8")
        if len(data) != 3 * SAMPLES:  # the file shrank while it was read
            raise ValueError(f"{what} is truncated: read {len(data)} of {3 * SAMPLES} values")
        bad = ~np.isfinite(data)
        if bad.any():
            c, i, j, k = np.unravel_index(int(np.argmax(bad)), SHAPE)
            raise ValueError(f"{what} holds {int(bad.sum())} non-finite value(s), the first {data[np.argmax(bad)]} "
                             f"at channel {'rgb'[c]}, θh index {i}, θd index {j}, φd index {k}")
        if data.max() > VALUE_MAX:  # (its fits overflowed to inf far from here, in the bake's BRDF checks)
            c, i, j, k = np.unravel_index(int(np.argmax(data)), SHAPE)
            raise ValueError(f"{what} holds values up to {data.max():.3g} (channel {'rgb'[c]}, θh index {i}, θd "
                             f"index {j}, φd index {k}): at most {VALUE_MAX:g} in the file's units")
        if _all_invalid(data.reshape(SHAPE)):
            raise ValueError(f"{what} holds no valid measured sample ({_ALL_INVALID})")
        return cls(data.reshape(SHAPE), interpolation=interpolation, source=path)

    def save(self, path) -> None:
        """Write the table as a MERL binary file (the header, then the table exactly as held: little-endian
        int32 and float64 whatever this machine's byte order), atomically: a reader never sees half a file
        and a failed write leaves an old one untouched."""
        check_output(path, what="MERL BRDF file")
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(np.array([RES_THETA_H, RES_THETA_D, RES_PHI_D], "<i4").tobytes())
                fh.write(self._data.astype("<f8", copy=False).tobytes())

    def with_interpolation(self, interpolation: str) -> MeasuredBRDF:
        """The same table (shared, not copied) evaluated with another interpolation."""
        other = object.__new__(MeasuredBRDF)
        other.__dict__.update(self.__dict__)
        other.interpolation = _check_interpolation(interpolation)
        return other

    # -- the table ----------------------------------------------------------------------------------------

    @property
    def data(self) -> np.ndarray:
        """(3, 90, 90, 180) float64, read-only: the table in the file's units (f_r / scale; negative =
        not measured)."""
        return self._data

    def values(self) -> np.ndarray:
        """(3, 90, 90, 180) float64 f_r (sr⁻¹): the table times its channel scales, invalid samples NaN."""
        out = self._data * SCALES[:, None, None, None]
        out[:, (self._data < 0).any(axis=0)] = np.nan
        return out

    @property
    def invalid_fraction(self) -> float:
        """The share of the 90·90·180 samples marked invalid (any channel negative)."""
        return float((self._data < 0).any(axis=0).mean())

    @property
    def nbytes(self) -> int:
        """Bytes held: the table, plus its filled copy once evaluated if the table has invalid samples."""
        extra = self._lut.nbytes if self._lut is not None and not np.shares_memory(self._lut, self._data) else 0
        return self._data.nbytes + extra

    def _table(self) -> np.ndarray:
        if self._lut is None:
            self._lut = _fill_invalid(self._data).reshape(3, -1)
        return self._lut

    # -- evaluation ---------------------------------------------------------------------------------------

    def lookup(self, theta_h, theta_d, phi_d, interpolation: str | None = None) -> np.ndarray:
        """(N, 3) f_r at half/difference angles (φd unfolded, any real), by `interpolation` (default: the
        object's)."""
        mode = self.interpolation if interpolation is None else _check_interpolation(interpolation)
        table = self._table()
        if mode == "nearest":
            i, j, k = merl_indices(theta_h, theta_d, phi_d)
            vals = table[:, (i * RES_THETA_D + j) * RES_PHI_D + k]
        else:
            ch, cd, cp = _continuous_indices(theta_h, theta_d, phi_d)
            (i0, i1, wh), (j0, j1, wd) = (_clamped_nodes(c - 0.5, res) for c, res in
                                          ((ch, RES_THETA_H), (cd, RES_THETA_D)))
            u = cp - 0.5
            k0 = np.floor(u)
            wp = u - k0
            k0 = k0.astype(np.int64) % RES_PHI_D
            k1 = (k0 + 1) % RES_PHI_D
            vals = 0.0
            for i, fi in ((i0, 1 - wh), (i1, wh)):
                for j, fj in ((j0, 1 - wd), (j1, wd)):
                    row = (i * RES_THETA_D + j) * RES_PHI_D
                    vals = vals + (fi * fj) * ((1 - wp) * table[:, row + k0] + wp * table[:, row + k1])
        return (np.asarray(vals) * SCALES[:, None]).T

    def eval(self, n, wi, wo, interpolation: str | None = None) -> np.ndarray:
        """f_r(n, ωi, ωo) in float64, (N, 3) RGB; zero where ωi or ωo is below the facet (n·ω ≤ 0).

        n, ωi, ωo are (N, 3) or (3,), broadcast together, and normalised here (as BRDFRead.cpp does ωi and
        ωo). Each facet gets a tangent frame about its n (`_tangent_frames`), in which the half/difference
        angles are taken; the result does not depend on that choice (isotropy)."""
        n, wi, wo = (np.atleast_2d(np.asarray(x, np.float64)) for x in (n, wi, wo))
        n, wi, wo = (np.array(x) for x in np.broadcast_arrays(n, wi, wo))
        with np.errstate(invalid="ignore", divide="ignore"):
            n, wi, wo = (x / np.linalg.norm(x, axis=1, keepdims=True) for x in (n, wi, wo))
        ci = np.einsum("ij,ij->i", n, wi)
        co = np.einsum("ij,ij->i", n, wo)
        ok = (ci > 0) & (co > 0)  # False for NaN: a zero-length vector gives 0, not NaN
        out = np.zeros((len(n), 3))
        if ok.any():
            nn, a, b = n[ok], wi[ok], wo[ok]
            t, bt = _tangent_frames(nn)
            local = [np.stack([np.einsum("ij,ij->i", w, t), np.einsum("ij,ij->i", w, bt), c[ok]], axis=1)
                     for w, c in ((a, ci), (b, co))]
            out[ok] = self.lookup(*half_diff_angles(*local), interpolation=interpolation)
        return out

    def packed(self):
        raise ValueError("a MeasuredBRDF's table is read by the ground-truth and matrix kernels only (wb.ground_truth, "
                         "wb.bake(method='matrix')), and the SG and ASG bakes and the SG renderer use its SG fit "
                         "(.sg_fit()); the lit-sphere texel kernels and the Mitsuba export know Lambert, BlinnPhong, "
                         "CookTorrance and Ward only; evaluate it on the CPU with .eval(n, wi, wo)")

    def to_file(self, key: str) -> tuple[dict, dict]:
        """(header dict, arrays) as a material file holds this BRDF: the table as array `key`, the
        interpolation, source and SG fit in the header (`from_file` reads them back; the fit is made here
        if it was not yet, so that a loaded material is not fitted again)."""
        return ({"type": "MeasuredBRDF", "table": key, "interpolation": self.interpolation, "source": self.source,
                 "sg_fit": self.sg_fit().to_dict(), "sg_fit_lobes": self._sg_fit_lobes}, {key: self._data})

    @classmethod
    def from_file(cls, head: dict, arrays: dict) -> MeasuredBRDF:
        """The BRDF `to_file` wrote: a one-line error if its table is missing or malformed."""
        key = head.get("table")
        if key not in arrays:
            raise ValueError(f"the measured BRDF's table {key!r} is missing from the material file")
        out = cls(arrays[key], interpolation=head.get("interpolation", "trilinear"), source=head.get("source"))
        if head.get("sg_fit") is not None:
            out._sg_fit = SGFit.from_dict(head["sg_fit"])
            out._sg_fit_lobes = head.get("sg_fit_lobes", 1)  # a file from before two-lobe fits: fitted with one
        return out

    def sg_fit(self, backend=None) -> SGFit:
        """The SG form of this table (`fit_sg` with lobes="auto": one or two microfacet lobes with SG NDFs, Wang
        §4.1–4.2), fitted on the first call (its sums in `backend`'s kernels, or on the host in float64 without
        one: the bakes and the SG renderer pass theirs) and kept (a `with_interpolation` copy made after it
        shares it; `with_sg_fit` makes a copy with another). `sg_fit().lobes` is what the SG and ASG bakes and
        the SG renderer use for this material (`brdf.sg_lobes`); the ground truth, the matrix method and the
        Monte Carlo reference use the table itself."""
        if self._sg_fit is None:
            self._sg_fit = fit_sg(self, backend)
            self._sg_fit_lobes = "auto"
        return self._sg_fit

    def with_sg_fit(self, lobes, backend=None) -> MeasuredBRDF:
        """The same table (shared, not copied) with its SG form fitted with `lobes` (1, 2 or "auto", `fit_sg`):
        e.g. `with_sg_fit(1)` shades and bakes with one lobe where "auto" kept two. A new object, so that what
        was packed or baked with this one keeps its fit."""
        other = self.with_interpolation(self.interpolation)
        other._sg_fit = fit_sg(self, backend, lobes)
        other._sg_fit_lobes = lobes
        return other

    def kernel_row(self, slot: int) -> np.ndarray:
        """The packed row (8,) the ground-truth and matrix kernels read (`brdf.pack_materials(...,
        measured=True)`): [slot of its table in the kernels' table array, interpolation code
        (`KERNEL_MODES`), 0, …]."""
        return np.array([int(slot), KERNEL_MODES[self.interpolation], 0, 0, 0, 0, 0, 0], np.float64)

    def kernel_table(self) -> np.ndarray:
        """(90·90·180·3,) float32: the table the kernels look up, `_table()` (invalid samples filled) times
        the channel scales, i.e. f_r in sr⁻¹, interleaved by sample: channel c of sample (i, j, k) at
        ``((i·90 + j)·180 + k)·3 + c``, so that one lookup reads three neighbouring floats rather than
        three 5.8 MB apart. Scaling before the interpolation rather than after is the same linear map
        (float32 rounding apart). Made on demand (17.5 MB): a backend uploads it once per table."""
        return np.ascontiguousarray((self._table() * SCALES[:, None]).T, np.float32).reshape(-1)

    def __repr__(self):
        src = f"{self.source!r}" if self.source is not None else "<table>"
        return f"MeasuredBRDF({src}, interpolation={self.interpolation!r})"


def _check_interpolation(mode) -> str:
    if mode not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {', '.join(map(repr, INTERPOLATIONS))}, got {mode!r}")
    return mode


def _clamped_nodes(u, res):
    """(i0, i1, w): the two nodes around continuous node coordinate u on an axis of `res` nodes at 0..res−1,
    and the weight of i1; u is clamped into [0, res − 1] (the value is held constant past the end nodes)."""
    u = np.clip(u, 0.0, res - 1.0)
    i0 = np.minimum(np.floor(u), res - 2).astype(np.int64)
    return i0, i0 + 1, u - i0


def small_scale_brdf(spec: str, base: str | None = None) -> Brdf:
    """A small-scale BRDF from text (a `--brdf` argument, a scene file's brdf entry): a MERL table, a path ending
    in .binary (relative to folder `base` if given: a scene file's own), or a `brdf.parse_brdf` spec such as
    cooktorrance:roughness=0.2. One-line errors name a missing or unreadable file."""
    if str(spec).lower().endswith(".binary"):
        path = os.path.join(base, spec) if base is not None and not os.path.isabs(spec) else spec
        return MeasuredBRDF.load(path)
    return parse_brdf(spec)


def paint_like(base=(0.55, 0.08, 0.05), sheen=(0.12, 0.05, 0.04), coat=0.06, *, sheen_roughness=0.35,
               coat_roughness=0.06, f0=0.05, interpolation: str = "trilinear") -> MeasuredBRDF:
    """A synthetic measured "paint": a coloured Lambertian base, a broad coloured Cook–Torrance lobe (the
    pigment's sheen) and a sharp, uncoloured one (the clear coat), tabulated on the MERL grid by
    `from_brdf` — the kind of table the data set's paints give, written by the tests themselves."""
    lobes = [Lambert(base),
             CookTorrance(ks=sheen, roughness=sheen_roughness, f0=f0),
             CookTorrance(ks=coat, roughness=coat_roughness, f0=f0)]
    return MeasuredBRDF.from_brdf(lobes, interpolation=interpolation)


# ---------------------------------------------------------------------------------------------------------
# The SG fit (Wang 2009 §4.1–4.2): what stands for a measured BRDF wherever SG lobes are convolved
# ---------------------------------------------------------------------------------------------------------

# The fit's samples: every θh bin (MERL's square-root axis is dense at the specular peak, where a sharp
# lobe's width is decided), every FIT_STEP_TD-th θd bin and every FIT_STEP_PD-th φd bin: 90·45·45 bin centres.
FIT_STEP_TD, FIT_STEP_PD = 2, 4
FIT_ROUGHNESS = np.geomspace(0.005, 2.0, 24)  # the start's grid of m (SG sharpness η = 2/m², 0.5 to 8e4)
FIT_F0 = (0.02, 0.1, 0.5, 1.0)  # the start's grid of Schlick's f0
TWO_LOBE_GAIN = 0.75  # lobes="auto" keeps a second lobe that brings the relative error to this share or less
# lobes="auto" refines no second lobe whose best start on the grid leaves more than this share of one lobe's error:
# a table of one microfacet lobe (or of none) gives the grid nothing to use (its best start keeps the error to
# 3 digits), a table of two lobes at least a few percent.
TWO_LOBE_START = 0.99


class SGFit:
    """A measured BRDF's SG form (`MeasuredBRDF.sg_fit`): `lobes`, one or two `CookTorrance` lobes (ks RGB, m,
    f0; the first carries the fit's kd, the others kd = 0) whose NDFs are read as SG lobes G(h; n, 2/m², 1)
    (Wang Eq. 12) and whose sum is the form the SG and ASG bakes and the SG renderer convolve (`brdf.sg_lobes`);
    `error`, the relative L2 error of the fitted model's cosine-weighted values f·cosθi·cosθo against the
    table's over all direction pairs (the four-dimensional integral, by the fit's bin-centre quadrature);
    `one_lobe_error`, that of the best one-lobe fit (the same as `error` when one lobe was kept); `seconds`, the
    fit's time; `backend`, where its sums ran ("host": float64)."""

    def __init__(self, lobes, error: float, seconds: float, samples: int, backend: str = "host",
                 one_lobe_error: float | None = None):
        self.lobes = tuple(lobes)
        self.error = float(error)
        self.one_lobe_error = float(error if one_lobe_error is None else one_lobe_error)
        self.seconds = float(seconds)
        self.samples = int(samples)
        self.backend = str(backend)

    @property
    def brdf(self) -> CookTorrance:
        """The fitted BRDF of a one-lobe fit (a two-lobe fit is the sum of `lobes`; this refuses it in one line)."""
        if len(self.lobes) != 1:
            raise ValueError(f"this SG fit has {len(self.lobes)} lobes: its BRDF is the sum of SGFit.lobes")
        return self.lobes[0]

    def to_dict(self) -> dict:
        """The fit as a material file's JSON header holds it (`from_dict` reads it back)."""
        return {"lobes": [{"kd": list(b.kd), "ks": list(b.ks), "roughness": b.roughness, "f0": b.f0}
                          for b in self.lobes],
                "error": self.error, "one_lobe_error": self.one_lobe_error, "seconds": self.seconds,
                "samples": self.samples, "backend": self.backend}

    @classmethod
    def from_dict(cls, d: dict) -> SGFit:
        lobes = d.get("lobes", [d])  # a one-lobe fit written before two-lobe fits held its lobe's fields itself
        return cls([_fitted_brdf(x["kd"], x["ks"], x["roughness"], x["f0"]) for x in lobes], d["error"],
                   d["seconds"], d["samples"], d.get("backend", "host"), d.get("one_lobe_error"))

    def __repr__(self):
        kd = tuple(round(x, 4) for x in self.lobes[0].kd)
        parts = ", ".join(f"(ks={tuple(round(x, 4) for x in b.ks)}, roughness={b.roughness:.4g}, f0={b.f0:.3g})"
                          for b in self.lobes)
        return f"SGFit(kd={kd}, lobes=[{parts}], error={self.error:.3g})"


def _fitted_brdf(kd, ks, roughness, f0) -> CookTorrance:
    """The fit's Cook–Torrance, without an EnergyWarning: a table that reflects more than it receives is the
    table's own doing, and its fit says what the table does. Its roughness is held at COOK_TORRANCE_ROUGHNESS_MIN
    or above (`fit_sg` searches there only; a fit read from a file made before that bound may lie below it), the
    sharpest lobe the SG forms hold, which the renderers capped a sharper fit's lobe to anyway."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EnergyWarning)
        return CookTorrance(ks=tuple(ks), roughness=max(float(roughness), COOK_TORRANCE_ROUGHNESS_MIN), f0=float(f0),
                            kd=tuple(kd))


def fit_samples(table):
    """The fit's bin centres with both directions above the horizon, as the `sgfit` kernels read them: (basis
    (N, 4) [d = cosθi·cosθo/π, 1 − cos θh, (1 − h·ωi)^5, G/π] with G Cook–Torrance's shadowing-masking, target
    (N, 3) f·cosθi·cosθo, weight (N,)), float64. The weight of a bin is its measure dωi dωo = 4 cosθd sinθh sinθd
    dθh dθd dφd dφh (Rusinkiewicz's half/difference Jacobian; dθh is the square-root axis' bin width), φh and
    the constant factors dropped."""
    th, td, pd = bin_centres()
    sel_td, sel_pd = np.arange(0, RES_THETA_D, FIT_STEP_TD), np.arange(0, RES_PHI_D, FIT_STEP_PD)
    d_th = (2 * np.arange(RES_THETA_H) + 1) / RES_THETA_H**2 * _HALF_PI
    wi, wo = directions_of(th[:, None, None], td[sel_td][None, :, None], pd[sel_pd][None, None, :])
    ci, co = wi[..., 2], wo[..., 2]
    weight = np.broadcast_to((d_th * np.sin(th))[:, None, None] * (np.cos(td) * np.sin(td))[sel_td][None, :, None],
                             ci.shape)
    ok = (ci > 0) & (co > 0)
    vals = table.reshape(SHAPE)[:, :, sel_td][:, :, :, sel_pd] * SCALES[:, None, None, None]
    ci, co = ci[ok], co[ok]
    theta_h = np.broadcast_to(th[:, None, None], ok.shape)[ok]
    cos_d = np.broadcast_to(np.cos(td[sel_td])[None, :, None], ok.shape)[ok]  # h·ωi
    nh = np.cos(theta_h)
    g = np.minimum(1.0, np.minimum(2 * nh * co / cos_d, 2 * nh * ci / cos_d))
    basis = np.stack([ci * co / np.pi, 2.0 * np.sin(theta_h / 2) ** 2, (1.0 - cos_d) ** 5, g / np.pi], 1)
    return basis, vals[:, ok].T * (ci * co)[:, None], np.ascontiguousarray(weight[ok])


def _lobe_basis(basis, eta, f0) -> np.ndarray:
    """The specular basis b = (f0 + (1 − f0)(1 − h·ωi)^5)(G/π)e^{−η(1 − cos θh)} of one lobe; 0 where η ≤ 0 (absent)."""
    if eta <= 0:
        return np.zeros(len(basis))
    return (f0 + (1.0 - f0) * basis[:, 2]) * basis[:, 3] * np.exp(-eta * basis[:, 1])


def fit_sums(basis, target, weight, candidates, coef=None) -> np.ndarray:
    """The float64 reference of the `sgfit` kernels (kernels/sgfit.py): for candidates (C, 4) [η1, f0_1, η2, f0_2]
    (a second lobe absent where η2 ≤ 0), the (C, 15) normal-equation sums [Σwd², Σwdb1, Σwdb2, Σwb1², Σwb1b2,
    Σwb2², Σwd·t (3), Σwb1·t (3), Σwb2·t (3)], or with coef (C, 9) [kd RGB, ks1 RGB, ks2 RGB] the (C,) weighted
    squared residuals Σ w Σ_c (t_c − kd_c d − ks1_c b1 − ks2_c b2)², each b the lobe's `_lobe_basis`."""
    basis, target, weight = (np.asarray(x, np.float64) for x in (basis, target, weight))
    cand = np.asarray(candidates, np.float64)
    if cand.ndim != 2 or cand.shape[1] != 4:
        raise ValueError(f"fit_sums: candidates must be (C, 4) [η1, f0_1, η2, f0_2], got shape {cand.shape}")
    d = basis[:, 0]
    out = []
    for i, (eta1, f01, eta2, f02) in enumerate(cand):
        b1, b2 = _lobe_basis(basis, eta1, f01), _lobe_basis(basis, eta2, f02)
        if coef is None:
            wd, w1, w2 = weight * d, weight * b1, weight * b2
            out.append(np.concatenate([[wd @ d, wd @ b1, wd @ b2, w1 @ b1, w1 @ b2, w2 @ b2],
                                       wd @ target, w1 @ target, w2 @ target]))
        else:
            c = np.asarray(coef, np.float64).reshape(-1, 9)[i]
            r = target - d[:, None] * c[None, :3] - b1[:, None] * c[None, 3:6] - b2[:, None] * c[None, 6:]
            out.append(weight @ np.einsum("nc,nc->n", r, r))
    return np.array(out, np.float64).reshape(len(cand), 15) if coef is None else np.array(out, np.float64)


# The supports of the non-negative solve's three coefficients (kd, ks1, ks2): every non-empty subset.
_SUPPORTS = ((0,), (1,), (2,), (0, 1), (0, 2), (1, 2), (0, 1, 2))


def _nonnegative_coefficients(sums) -> np.ndarray:
    """(C, 9) [kd RGB, ks1 RGB, ks2 RGB] ≥ 0 minimising Σ w (t − kd·d − ks1·b1 − ks2·b2)² per channel, from
    `fit_sums`' (C, 15) normal-equation sums. The minimum of a convex quadratic over the non-negative octant is
    the unconstrained minimum on the face of its support, so it is the cheapest of the feasible unconstrained
    solutions over the seven supports (zero if none is feasible); a support whose Gram matrix is singular (an
    absent lobe, b ≡ 0) is skipped."""
    s = np.asarray(sums, np.float64).reshape(-1, 15)
    c = len(s)
    gram = np.empty((c, 3, 3))
    for (i, j), col in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)), range(6)):
        gram[:, i, j] = gram[:, j, i] = s[:, col]
    rhs = s[:, 6:15].reshape(c, 3, 3)  # (C, basis, channel)
    best = np.zeros((c, 3, 3))  # (C, basis, channel)
    best_cost = np.zeros((c, 3))
    for sup in _SUPPORTS:
        idx = np.array(sup)
        g = gram[:, idx[:, None], idx[None, :]]  # (C, k, k)
        r = rhs[:, idx, :]  # (C, k, 3)
        det = np.linalg.det(g)
        scale = np.prod(np.diagonal(g, axis1=1, axis2=2), axis=1)
        ok = det > 1e-12 * np.maximum(scale, 1e-300)
        x = np.zeros_like(r)
        if ok.any():
            x[ok] = np.linalg.solve(g[ok], r[ok])
        cost = -np.einsum("ckh,ckh->ch", x, r)  # at the support's minimum x'Gx − 2r'x = −r'x
        take = ok[:, None] & (x >= 0).all(1) & (cost < best_cost)
        full = np.zeros((c, 3, 3))
        full[:, idx, :] = x
        best = np.where(take[:, None, :], full, best)
        best_cost = np.where(take, cost, best_cost)
    return best.reshape(c, 9)


def _log_roughness(log_m):
    """The fit's search variable log m held at log COOK_TORRANCE_ROUGHNESS_MIN or above: a lobe sharper than the SG
    forms hold (a mirror-like table) is fitted with the sharpest they do, and the objective sees that lobe."""
    return np.maximum(log_m, np.log(COOK_TORRANCE_ROUGHNESS_MIN))


def fit_sg(measured: MeasuredBRDF, backend=None, lobes="auto") -> SGFit:
    """The SG fit of a measured BRDF, Wang §4.1–4.2: kd/π + Σ_l ks_l·F_l(h·ωi)·G·D_l(h)/(π cosθi cosθo) over one
    or two lobes l, with D_l = exp((2/m_l²)(n·h − 1)) the NDF's SG, Schlick's F(f0_l) and Cook–Torrance's
    V-cavity G (as `CookTorrance`), in the weighted least squares of f·cosθi·cosθo over the table's bin centres
    (`fit_samples`). kd and the ks_l enter linearly, so for each (m_l, f0_l) they are solved exactly (non-
    negative, per channel, from the normal equations) and the objective is the residual itself. One lobe: (m,
    f0) start at the best of a grid (one batch) and are refined by Nelder–Mead in (log m, f0). Two lobes: the
    second starts at the best of the same grid beside the one-lobe fit, then all four are refined together.

    `lobes`: 1, 2 or "auto" — two where they lower the relative error to TWO_LOBE_GAIN of one lobe's or
    less (a second lobe doubles the specular work of every consumer), else one; "auto" does not refine a
    second lobe whose best grid start leaves more than TWO_LOBE_START of one lobe's error (nothing for it to
    hold). With a `backend` the sums run in its `sgfit` kernels (float32 partial sums added in float64), else
    on the host in float64 (`fit_sums`, their reference). Deterministic; seconds."""
    from scipy.optimize import minimize  # (scipy on first use: importing it costs more than the fit's setup)

    if lobes not in (1, 2, "auto"):
        raise ValueError(f"lobes must be 1, 2 or 'auto', got {lobes!r}")
    t0 = time.perf_counter()
    basis, target, weight = fit_samples(measured._table())
    if backend is None:
        def sums(cand, coef=None):
            return fit_sums(basis, target, weight, cand, coef)
        where = "host"
    else:
        be = BACKENDS["get"](backend)  # (backend.get_backend: the backends import this module)
        data = be.sg_fit_data(basis, target, weight)

        def sums(cand, coef=None):
            return be.sg_fit_sums(data, cand, coef)
        where = be.name

    def solve(params):
        """params (C, 2) [log m, f0] or (C, 4) [log m1, f0_1, log m2, f0_2] → (coefficients (C, 9), residuals (C,))."""
        p = np.atleast_2d(np.asarray(params, np.float64))
        cand = np.zeros((len(p), 4))  # a one-lobe candidate's second lobe: η2 = 0, absent
        cand[:, 0] = 2.0 / np.exp(2 * _log_roughness(p[:, 0]))
        cand[:, 1] = np.clip(p[:, 1], 0.0, 1.0)
        if p.shape[1] == 4:
            cand[:, 2] = 2.0 / np.exp(2 * _log_roughness(p[:, 2]))
            cand[:, 3] = np.clip(p[:, 3], 0.0, 1.0)
        coef = _nonnegative_coefficients(sums(cand))
        return coef, sums(cand, coef)

    def refine(start, maxiter):
        """Nelder–Mead from `start`, f0s held in [0, 1]; the start itself where it stays better."""
        def objective(p):
            return solve(p)[1][0] + (1e30 if not all(0 <= f <= 1 for f in p[1::2]) else 0.0)
        best = minimize(objective, start, method="Nelder-Mead",
                        options={"xatol": 1e-4, "fatol": 1e-12, "maxiter": maxiter})
        return best.x if best.fun <= solve(start)[1][0] else start

    norm = float(weight @ np.einsum("nc,nc->n", target, target))

    def relative_error(residual):
        return float(np.sqrt(max(residual, 0.0) / norm)) if norm > 0 else 0.0

    grid = np.array([(np.log(m), f0) for m in FIT_ROUGHNESS for f0 in FIT_F0])
    one = refine(grid[int(np.argmin(solve(grid)[1]))], 400)
    coef, residual = solve(one)
    params, one_error = one, relative_error(residual[0])
    error = one_error
    if lobes != 1:
        pairs = np.concatenate([np.broadcast_to(one, grid.shape), grid], 1)
        starts = solve(pairs)[1]
        best = int(np.argmin(starts))
        if lobes == 2 or relative_error(starts[best]) <= TWO_LOBE_START * one_error:
            two = refine(pairs[best], 800)
            coef2, residual2 = solve(two)
            error2 = relative_error(residual2[0])
            if lobes == 2 or error2 <= TWO_LOBE_GAIN * one_error:
                params, coef, error = two, coef2, error2
    # (ks, m, f0) per lobe; a lobe the solve gave nothing is dropped (one is kept: a Lambertian table's); the
    # broader lobe comes first and carries kd.
    found = [(coef[0, 3 * lobe + 3:3 * lobe + 6], np.exp(_log_roughness(params[2 * lobe])),
              np.clip(params[2 * lobe + 1], 0, 1))
             for lobe in range(len(params) // 2)]
    found = [x for x in found if x[0].max() > 0] or found[:1]
    found.sort(key=lambda x: -x[1])
    fitted = [_fitted_brdf(coef[0, :3] if i == 0 else np.zeros(3), *x) for i, x in enumerate(found)]
    return SGFit(fitted, error, time.perf_counter() - t0, len(weight), where, one_error)
