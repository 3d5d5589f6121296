"""What the two backends share on the host: results left on the device (OnDevice, DeviceLobes,
DeviceStart), the device-side facet and upload caches, the EM's stopping schedule, chunking of
reductions, and the probe every backend must pass before it is offered (`backend.backends`).

Nothing here knows a device kind; `warp_backend` and `opencl_backend` build on it, and
`backend` (the protocol and selection by name) on them.
"""

from __future__ import annotations

import collections
import functools
import hashlib
import weakref

import numpy as np

from .lobes import KERNEL_LOBES, LobeSet

SCRATCH_BYTES = 64 << 20  # the largest scratch array a backend keeps between calls (see their _scratch)


class OnDevice:
    """A result left on the device, so that the host need not wait for it: `device` is the backend's own
    array (or arrays) for its next calls, `host()` the host copy, read back when first asked for (the
    copy may have been queued with the result: then it waits for that result alone, not for work
    queued after it). `device` None: a host copy alone, which a backend given it uploads."""

    def __init__(self, device, read):
        self.device = device
        self._read = read
        self._host = None

    def host(self):
        if self._host is None:
            self._host = self._read()
        return self._host


def device_copy(value, held, upload):
    """The device copy of an input that a backend call may have left on the device (a facet weight from
    visible_weights, a_v from visible_area): `value.device` for an OnDevice (one with a host copy alone
    is uploaded), or `held[1]` when `value` is the very host array `held[0]` that the call returned and
    kept on the device as `held[1]`, else `upload(value)`."""
    if isinstance(value, OnDevice):
        if value.device is not None:
            return value.device
        value = value.host()
    if held is not None and held[0] is value:
        return held[1]
    return upload(value)


class _LobesOnDevice(OnDevice):
    """J lobes left on the device: `count` J, also its len()."""

    def __init__(self, device, count, read):
        super().__init__(device, read)
        self.count = int(count)

    def __len__(self):
        return self.count


class DeviceLobes(_LobesOnDevice):
    """The lobes of `Backend.ndf_em(..., to_host=False)`: `device` the backend's own float32 (axes,
    sharpness) arrays, which `lobe_moments` takes in place of host axes until the backend's next
    ndf_em; `count` J; `host()` → (axes, sharpness, weight, steps) as ndf_em returns them."""


class DeviceStart(_LobesOnDevice):
    """EM's start picked on the device by `Backend.em_start`: `device` the backend's (J, 6) float64 rows
    [ξ (3), η, α, log_weight] (em_start_rows), which ndf_em takes in place of host lobes; `count` J;
    `host()` → the LobeSet of all J slots (a slot past the distinct normals has weight 0)."""

    def __init__(self, device, count, read):
        super().__init__(device, count, lambda: start_lobes(read()))


def start_scale(facets, facet_weight) -> float:
    """The fixed point of em_start's bin sums: round(x · scale) as int64, scale = 2^52 over a bound on
    Σ|w| (the facets' area for None or visible weights, which are at most the area), so no sum passes
    2^63 and each is exact to 2^-52 of that bound per facet."""
    if facet_weight is None or isinstance(facet_weight, OnDevice):
        bound = float(np.sum(facets.area, dtype=np.float64))
    else:
        bound = float(np.sum(np.abs(np.asarray(facet_weight, np.float64))))
    return 2.0**52 / bound if bound > 0 else 1.0


def start_lobes(rows):
    """The LobeSet of (J, 6) start rows [ξ (3), η, α, log_weight] (em_start_rows' layout)."""

    rows = np.asarray(rows, np.float64)
    return LobeSet(rows[:, :3], rows[:, 3], rows[:, 4])


class UploadCache:
    """Device copies of small host arrays that recur from call to call (direction pairs, grids, equal
    facet areas), by content: an upload is a synchronous copy that also waits for the kernels queued
    before it, and a bake made a dozen. Holds `size` arrays, most recent last; a hit compares the
    bytes, not only their hash. The very array object seen before, if it owns its data and is
    read-only (`directions.all_pairs` / `unordered_pairs`), is a hit without hashing its bytes."""

    def __init__(self, size: int = 32):
        self._size = size
        self._entries = collections.OrderedDict()
        self._by_object = {}  # (id, dtype, tag) → (weakref to the host array, key in _entries)

    def get(self, array, dtype, upload, tag=None):
        """The device copy of `array` as `dtype`, from `upload(contiguous host array)` on a miss; `tag`
        tells apart device copies of one host array (e.g. Warp's wp.vec3 and wp.float32 views)."""
        frozen = isinstance(array, np.ndarray) and not array.flags.writeable and array.base is None
        if frozen:
            seen = self._by_object.get((id(array), np.dtype(dtype).str, tag))
            if seen is not None and seen[0]() is array and seen[1] in self._entries:
                self._entries.move_to_end(seen[1])
                return self._entries[seen[1]][1]
        host = np.ascontiguousarray(array, dtype=dtype)
        data = host.tobytes()
        key = (host.dtype.str, host.shape, tag, hashlib.blake2b(data, digest_size=16).digest())
        hit = self._entries.get(key)
        if hit is not None and hit[0] == data:
            self._entries.move_to_end(key)
            device = hit[1]
        else:
            device = upload(host)
            self._entries[key] = (data, device)
            while len(self._entries) > self._size:
                self._entries.popitem(last=False)
        if frozen:
            self._by_object = {k: v for k, v in self._by_object.items() if v[0]() is not None}
            self._by_object[(id(array), np.dtype(dtype).str, tag)] = (weakref.ref(array), key)
        return device


def run_em_steps(iterations: int, enqueue_step, done) -> None:
    """Enqueue up to `iterations` EM steps (`enqueue_step()`), looking at the device's stop flag
    (`done()`, a host round trip) only after steps 2, 4, 8, 16, …: a few looks per EM instead of one
    per step, and a converged EM does not queue the rest of its steps (each would return at once,
    but on a CPU even an empty sliced launch costs ~0.2 ms: 14 ms of 30 no-op steps measured on the
    pyramid tile, whose EM stops after 2)."""
    check = 2
    for step in range(1, int(iterations) + 1):
        enqueue_step()
        if step == check and step < iterations:
            if done():
                return
            check *= 2


def facet_host_array(facets, key: str) -> np.ndarray | None:
    """The host array behind a facet device array: normal, face, area, material, or weight (ΔA·colour,
    (Ns, 3)); None for another key."""
    if key == "weight":
        return facets.color * facets.area[:, None]
    return getattr(facets, key) if key in ("normal", "face", "area", "material") else None


class DeviceFacets(dict):
    """A Facets' device arrays by name (facets.device_cache[backend.name]): the sampling kernel's own
    outputs are given at once; any other (`facet_host_array`) is uploaded by `upload(key, host)` when
    first asked for. Holds the facets weakly, so they and their device arrays go together."""

    def __init__(self, upload, facets, given=None):
        super().__init__(given or {})
        self._upload = upload
        self._facets = weakref.ref(facets)

    def __missing__(self, key):
        host = facet_host_array(self._facets(), key)
        if host is None:
            raise KeyError(key)
        value = self[key] = self._upload(key, host)
        return value


@functools.lru_cache(maxsize=8)
def equal_areas(count: int, value: float) -> np.ndarray:
    """(count,) float32 ΔA = `value` for every facet, read-only and made once per (count, value): the
    sampled facets' areas, which a backend then finds in its UploadCache without hashing them."""
    area = np.full(int(count), value, np.float32)
    area.flags.writeable = False
    return area


def em_start_rows(start) -> np.ndarray:
    """(J, 6) float64 rows [ξ (3), η, α, log_weight ≥ −1e30] of a LobeSet: the one upload that the
    device EM's `em_load` kernel unpacks."""
    return np.ascontiguousarray(np.column_stack([start.axes, start.sharpness, start.weight,
                                                 np.maximum(start.log_weight, -1e30)]), np.float64)


def em_result_rows(rows) -> tuple:
    """The (J, 6) rows `em_result` packs → (axes, sharpness, weight, steps)."""
    rows = np.asarray(rows, np.float64)
    return rows[:, :3].copy(), rows[:, 3].copy(), rows[:, 4].copy(), int(rows[0, 5])


def check_kernel_lobes(n_lobes: int) -> None:
    """The amplitude kernels (moments, solve) hold one accumulator per lobe in registers: 1 to
    lobes.KERNEL_LOBES lobes a call (the bake passes more in groups)."""

    if not 1 <= n_lobes <= KERNEL_LOBES:
        raise ValueError(f"the amplitude kernels take 1 to {KERNEL_LOBES} lobes a call, got {n_lobes}")


def chunking(n_words: int, n_outputs: int, threads: int) -> tuple[int, int]:
    """Split n_words facet words into chunks so that n_outputs × chunks ≈ threads.

    → (chunks, words_per_chunk). A serial device wants one chunk; a GPU wants enough threads to fill.
    """
    chunks = int(np.clip(-(-threads // max(n_outputs, 1)), 1, max(n_words, 1)))
    words = -(-n_words // chunks)
    chunks = max(1, -(-n_words // words))
    return chunks, words


# The probe's input: zero, one, small, large, negative and non-dyadic values.
PROBE_VALUES = np.array([0.0, 1.0, -2.5, 3.0e-3, 1.0e10, -7.0 / 3.0, 12345.678, 0.1], np.float64)


def probe_expected(values) -> np.ndarray:
    """What the probe kernels (kernels/probe.py, cl/probe.cl) return for `values`: x² + x/2 + 1."""
    values = np.asarray(values, np.float64)
    return values * values + 0.5 * values + 1.0


def probe_mismatch(out) -> str | None:
    """None if the probe's output is right, else what was wrong, in one line. Tolerance 1e-12 relative:
    the kernels compute in float64, and a fused multiply-add may round once less than numpy."""
    want = probe_expected(PROBE_VALUES)
    out = np.asarray(out, np.float64)
    if out.shape != want.shape or not np.allclose(out, want, rtol=1e-12, atol=0.0):
        return f"its probe kernel ran but returned wrong values ({out.tolist()}, expected {want.tolist()})"
    return None


def one_line(text) -> str:
    """The first non-empty line of an error's text (a build log or a native message may span many)."""
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    return lines[0] if lines else type(text).__name__
