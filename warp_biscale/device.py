"""What the two backends share on the host: `DeviceBackend`, the base class that does every stage's
checks, caching and bookkeeping once; results left on the device (OnDevice, DeviceLobes, DeviceStart);
the device-side facet and upload caches; the EM's stopping schedule; chunking of reductions; and the
probe every backend must pass before it is offered (`backend.backends`).

Nothing here knows a device kind: `warp_backend` and `opencl_backend` subclass DeviceBackend with
their allocations, copies and launches, and `backend` (the protocol and selection by name) sits
above them.
"""

from __future__ import annotations

import collections
import functools
import hashlib
import os
import weakref

import numpy as np

from .asg import ASG, unit_integral
from .brdf import ANISOTROPIC_KINDS, MEASURED
from .lobes import DEAD_MASS, KERNEL_LOBES, LobeSet
from .model import DeviceArray, Facets, GBuffer, ShadeInputs, Visibility, facet_shift
from .trace import (BLOCK_SLOTS, CHUNK_RAYS, LOBE_RAYS, check_camera, check_gbuffer, check_lights, check_mesh,
                    check_occlusion, check_lobes, check_occlusion_samples, check_ray_part, light_samples,
                    offsets)

# Shade inputs up to this size are compared by value to the last upload of their role (`_shade_input`),
# larger ones by their memory.
SHADE_INPUT_COMPARE_BYTES = 1 << 20
SCRATCH_BYTES = 64 << 20  # the largest scratch array a backend keeps between calls (see their _scratch)
# Threads a lobe in the ASG EM's M-step (kernels/asgfit.py's blocks; cl/asgfit.cl's ASGFIT_GROUP, which the
# OpenCL build is given from here): they share its sums over a few hundred to a few thousand normal bins and the
# Newton's 48 disk nodes.
ASG_EM_BLOCK = 128
# The largest (bins, J) float64 responsibilities an ASG EM program kept for the next call may hold (`_keep_asg_em`):
# `lobes="auto"` at fine bins tries many J, and eight kept programs of 128 MiB each would stay on the device.
ASG_EM_KEEP_BYTES = 16 << 20
# The shade kernel's register cap on NVIDIA GPUs (kernels/shade.py's cuda_max_registers; the OpenCL build's
# -cl-nv-maxrregcount where the device takes NVIDIA's compiler options): the rest spills to local memory, which the
# cache holds, and more resident warps hide the gathers' latency better than registers save spills. Timed on both
# backends (bench/results/shade-regcap-h200-0853f26, opencl-regcap-h200-d6d1287).
SHADE_MAX_REGISTERS = 64


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


def run_em_steps(iterations: int, enqueue_step, done, meanwhile=None) -> None:
    """Enqueue up to `iterations` EM steps (`enqueue_step()`), looking at the device's stop flag
    (`done()`, a host round trip) only after steps 2, 4, 8, 16, …: a few looks per EM instead of one
    per step, and a converged EM does not queue the rest of its steps (each would return at once,
    but on a CPU even an empty sliced launch costs a fraction of a millisecond, and the pyramid
    tile's EM stops after 2). `meanwhile()`, if given, is called once before the first look: host work
    that then runs while the device works through what is queued."""
    check = 2
    for step in range(1, int(iterations) + 1):
        enqueue_step()
        if step == check and step < iterations:
            if meanwhile is not None:
                meanwhile()
                meanwhile = None
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


def padded_lobe_values(values, width: int) -> np.ndarray:
    """(Ns, width) float32 of (Ns, J) lobe values G_j(n_s), zero past J: the table the moment kernels read
    (`lobe_moments(..., lobe_values=)`)."""
    values = np.asarray(values, np.float32)
    out = np.zeros((len(values), int(width)), np.float32)
    out[:, :values.shape[1]] = values
    return out


def once(f):
    """`f` as a function that runs it on its first call only."""
    pending = [f]

    def call():
        if pending:
            pending.pop()()
    return call


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


CPU_THREADS_VARIABLE = "WARP_BISCALE_CPU_THREADS"


CPU_THREADS_MAX = 1024


def cpu_threads() -> int:
    """The threads a CPU backend splits its work over: $WARP_BISCALE_CPU_THREADS if set, else the cores this
    process may run on (its affinity: `taskset`, a container's CPU set, a pinned batch worker), else
    os.cpu_count(). A backend reads it once, when made (`get_backend` keeps one per name and process)."""
    text = os.environ.get(CPU_THREADS_VARIABLE, "").strip()
    if text:
        if not (text.isascii() and text.isdigit()) or not 1 <= int(text) <= CPU_THREADS_MAX:
            raise ValueError(f"{CPU_THREADS_VARIABLE} must be an integer from 1 to {CPU_THREADS_MAX} (threads), "
                             f"got {text!r}")
        return int(text)
    return usable_cores()


def usable_cores() -> int:
    """The cores this process may run on: its affinity (`taskset`, a container's CPU set), else os.cpu_count()."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def one_line(text) -> str:
    """The first non-empty line of an error's text (a build log or a native message may span many)."""
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    return lines[0] if lines else type(text).__name__


# Element kinds of device arrays: numpy dtype and components per element. Warp holds a vec kind as an
# array of wp.vec2/wp.vec3, OpenCL as a flat float buffer of stride 2/3 (no float3 in buffers).
# The element kind of each facet array a DeviceFacets uploads (facet_host_array's keys).
FACET_KINDS = {"normal": "vec3", "face": "i32", "area": "f32", "material": "i32", "weight": "vec3"}
KINDS = {"i32": (np.int32, 1), "i64": (np.int64, 1), "u8": (np.uint8, 1), "u32": (np.uint32, 1),
         "f32": (np.float32, 1), "f64": (np.float64, 1), "vec2": (np.float32, 2), "vec3": (np.float32, 3),
         "vec4d": (np.float64, 4), "vec3d": (np.float64, 3)}


_NO_FACE = np.zeros(1, np.int32)  # effective_brdf's face and tangent arguments when no material is anisotropic
_NO_TANGENT = np.zeros((1, 3), np.float32)
_NO_TABLE = np.zeros(1, np.float32)  # the measured-table argument when no material is measured
for _a in (_NO_FACE, _NO_TANGENT, _NO_TABLE):
    _a.flags.writeable = False
MEASURED_TABLE_SETS = 2  # sets of measured tables a backend keeps on its device (17.5 MB a table)


def _shape(shape) -> tuple:
    return tuple(int(s) for s in shape) if isinstance(shape, (tuple, list)) else (int(shape),)


class DeviceBackend:
    """The host side of a backend, written once: checks, caches kept on data-model objects, the
    bookkeeping of the facet, visibility, ground-truth, BVNDF, EM, SSDF, ray-casting and shading stages
    (G-buffer choice included). A subclass supplies the
    device itself — `_to_device`, `_new`, `_to_host`, `_queued_read` (arrays of the element kinds in
    KINDS), `_context` (what device arrays cached on data objects belong to) — and one
    `_launch_<stage>` (or `_run_em`, `_upload_*`) per kernel launch, which only passes arguments in its
    toolkit's convention. The stages whose device work differs past argument passing (em_start,
    ndf_statistics, lobe_moments, histogram_moments, solve_amplitudes, prefilter_level) stay in the
    subclasses."""

    name: str
    device: str

    # --- device primitives (subclass) ---
    def _to_device(self, host, kind: str):
        """A device copy of a host array as `kind` (leading shape kept where the toolkit has one)."""
        raise NotImplementedError

    def _new(self, shape, kind: str):
        """An uninitialised device array of `shape` elements of `kind`."""
        raise NotImplementedError

    def _zeros(self, shape, kind: str):
        """A device array of `shape` elements of `kind`, zero."""
        raise NotImplementedError

    def _flat(self, array):
        """`array` as the one-dimensional array of its elements that a kernel's flat argument takes (a view)."""
        raise NotImplementedError

    def _to_host(self, array, shape, kind: str, out=None) -> np.ndarray:
        """A host copy of `array`, `shape` elements of `kind` (a vec kind adds its components as a last
        axis), once the work queued on it is done; in `out` (a C-contiguous host array of that size and
        type) if given."""
        raise NotImplementedError

    def _context(self):
        """What a device array cached on a data object belongs to (None: any array of this backend)."""
        return None

    def _queued_read(self, array, shape, kind: str):
        """→ a function returning a host copy of `array` as it is now: the copy is queued at once, so the
        function later waits for `array`'s work alone, not for what was queued after it."""
        raise NotImplementedError

    # --- shared host logic ---
    def _recurring(self, host, kind: str):
        """A read-only device copy of an input that recurs between calls (pair lists, the direction grid,
        equal facet areas), found again by content (UploadCache). No kernel may write into it."""
        return self._uploads.get(host, KINDS[kind][0], lambda h: self._to_device(h, kind), tag=kind)

    def _small_upload(self, entry: dict, key: str, host, kind: str = "f32"):
        """entry[key], a device copy of a small array (the camera, the lights, their ray counts) as `kind`, made
        again only when its values change: a frame that moves nothing allocates and copies nothing (a new OpenCL
        buffer, or a blocking copy into one, each frame cost a GPU host's frame its time)."""
        host = np.ascontiguousarray(host, KINDS[kind][0])
        held = entry.get(key + "/host")
        if held is None or held.dtype != host.dtype or held.shape != host.shape or not np.array_equal(held, host):
            entry[key] = self._to_device(host, kind)
            entry[key + "/host"] = host.copy()
        return entry[key]

    def _facets(self, facets: Facets) -> DeviceFacets:
        """facets.device_cache[self.name]: the facets' device arrays, each uploaded when first asked for."""
        entry = facets.device_cache.get(self.name)
        if entry is None or entry.get("context") is not self._context():
            entry = facets.device_cache[self.name] = DeviceFacets(self._upload_facet_array, facets,
                                                                  {"context": self._context()})
        return entry

    def _upload_facet_array(self, key, host):
        return self._to_device(host, FACET_KINDS[key])

    def _facet_positions(self, facets: Facets, tile):
        """Facet positions on the device in `tile`'s local frame (see `SmallScale.to_local`)."""
        entry = self._facets(facets)
        if entry.get("position_tile") is not tile:
            entry["position"] = self._to_device(tile.to_local(facets.position), "vec3")
            entry["position_tile"] = tile
        return entry["position"]

    def _vis(self, vis: Visibility) -> dict:
        """vis.device_cache[self.name]: the visibility bits (D, words) and directions on the device."""
        entry = vis.device_cache.get(self.name)
        if entry is None or entry.get("context") is not self._context():
            entry = vis.device_cache[self.name] = {"context": self._context(),
                                                   "bits": self._to_device(vis.bits, "u32"),
                                                   "directions": self._to_device(vis.directions, "vec3")}
        return entry

    def sample_facets(self, tile, count, seed):
        count = int(count)
        if count < 1:
            raise ValueError(f"facet count must be >= 1, got {count}")
        pos, nrm, face = self._new(count, "vec3"), self._new(count, "vec3"), self._new(count, "i32")
        xi1, xi2 = facet_shift(seed)
        self._launch_sample_facets(tile, count, xi1, xi2, pos, nrm, face)
        area = equal_areas(count, float(np.float32(tile.area / count)))
        # The facets stay on the device: the host reads back only what host code asks for.
        host = {"position": lambda f: tile.from_local(self._to_host(pos, count, "vec3")),
                "normal": lambda f: self._to_host(nrm, count, "vec3"),
                "face": lambda f: self._to_host(face, count, "i32"),
                "material": lambda f: tile.material_ids[f.face],
                "color": lambda f: tile.colors[f.face].astype(np.float32)}
        facets = Facets.deferred(count, lambda name, f: host[name](f), seed=int(seed), area=area)
        facets.device_cache[self.name] = DeviceFacets(self._upload_facet_array, facets, {
            "context": self._context(), "position": pos, "position_tile": tile, "normal": nrm, "face": face,
            "area": self._recurring(area, "f32")})  # read-only: shared by bakes of this count
        return facets

    def visibility(self, tile, facets, directions, brute_force=False):
        directions = np.asarray(directions, np.float64)
        n, n_dirs = len(facets), len(directions)
        words = (n + 31) // 32
        bits = self._new((n_dirs, words), "u32")
        dirs = self._recurring(directions, "vec3")
        if n_dirs:
            self._launch_visibility(tile, facets, dirs, n_dirs, words, bool(brute_force), bits)
        vis = Visibility.deferred(directions, n, lambda: self._to_host(bits, (n_dirs, words), "u32"))
        vis.device_cache[self.name] = {"context": self._context(), "bits": bits, "directions": dirs}
        return vis

    def visible_area(self, facets, vis, to_host=True):
        n_dirs = len(vis.directions)
        if n_dirs == 0:
            none = np.zeros(0, np.float32)
            return none if to_host else OnDevice(self._new(1, "f32"), lambda: none)
        chunks, per = chunking(vis.words, n_dirs, self._threads)
        a_v = self._new(n_dirs, "f32")
        self._launch_visible_area(self._facets(facets), self._vis(vis), vis.words, n_dirs, chunks, per, a_v)
        if not to_host:
            return OnDevice(a_v, self._queued_read(a_v, n_dirs, "f32"))  # (queued now: no wait when read)
        host = self._to_host(a_v, n_dirs, "f32")
        host.flags.writeable = False  # (so that the device copy stays what it holds)
        self._held_visible_area = (host, a_v)  # solve_amplitudes given `host` itself uses the device copy
        return host

    def facet_weight(self, weight):
        return OnDevice(self._to_device(np.asarray(weight, np.float32), "f32"), lambda: weight)

    def facet_weight_by_face(self, facets, per_face, host_weight=None):
        per_face = np.asarray(per_face, np.float64).reshape(-1)
        n = len(facets)
        weight = self._new(n, "f32")
        f = self._facets(facets)
        # (the face values recur from bake to bake of a tile: uploaded once, found again by content)
        self._launch_facet_weights(f["face"], self._recurring(per_face.astype(np.float32), "f32"), f["area"], n,
                                   weight)
        return OnDevice(weight, host_weight or (lambda: per_face[facets.face] * facets.area.astype(np.float64)))

    def material_tables(self, materials, integrals, n_pairs, level_weights=None):

        integrals = np.asarray(integrals, np.float64)
        j, n_mat = len(integrals), len(materials)
        shapes = [(n_mat, n_pairs, j, 3), (n_mat, n_pairs, 3)]
        if level_weights is not None:
            weights = np.asarray(level_weights, np.float32)
            k2 = weights.shape[1] if weights.ndim == 2 else 0
            if k2 == 0 or len(weights) % k2 or n_pairs != k2 * k2:
                raise ValueError(f"level_weights must have shape ((L - 1)·K², K²) for {n_pairs} = K⁴ direction "
                                 f"pairs, got {weights.shape}")
            n_levels = len(weights) // k2 + 1
            shapes.append((n_mat, n_levels, n_pairs, 3))
        if not (n_mat and j):
            return (*(np.zeros(s, np.float32) for s in shapes), *([None] if level_weights is None else []))
        amps, energy = self._zeros(shapes[0], "f32"), self._zeros(shapes[1], "f32")  # (a material may have no channel)
        integ = self._recurring(integrals, "f64")
        for m, channels in enumerate(materials):
            for k, (mu, rgb) in enumerate(channels):
                if isinstance(mu, (np.ndarray, list, tuple)):  # a host μ (else solve_amplitudes' device copy)
                    mu = self._to_device(np.asarray(mu, np.float32).reshape(n_pairs, j), "f32")
                self._launch_amplitude_tables(mu, integ, [float(c) for c in rgb], k > 0, m, n_pairs, j, amps, energy)
        arrays = [amps, energy]
        if level_weights is not None:
            arrays.append(self._new(shapes[2], "f32"))
            self._launch_energy_levels(energy, self._recurring(weights, "f32"), n_mat, n_levels, k2, arrays[2])
        # The tables and levels stay on the device: the shade stage takes them as they are (`_shade_input`), and a
        # host copy is read only where host code asks for one. The energies come back now (the bake checks them).
        out = [DeviceArray(self, a, self._flat(a), s, lambda a=a, s=s: self._to_host(a, s, "f32"))
               for a, s in zip(arrays, shapes)]
        out[1] = out[1].host()
        return tuple(out) if level_weights is not None else (out[0], out[1], None)

    def _visible_area_device(self, a_v):
        """The device copy of a_v (see device_copy): on a GPU host an upload costs more than the solve."""
        return device_copy(a_v, self._held_visible_area, lambda host: self._to_device(host, "f32"))

    def _measured_tables(self, kinds, measured):
        """The kernels' measured-table argument: the `kernel_table()`s of `measured` (the MeasuredBRDFs in slot
        order, `brdf.measured_tables`) concatenated, uploaded once per set of table objects and kept by
        their identity (the last MEASURED_TABLE_SETS sets); a one-float stand-in where no kind is measured."""
        if not np.isin(np.asarray(kinds), MEASURED).any():
            return self._recurring(_NO_TABLE, "f32")
        measured = list(measured or ())
        if not measured:
            raise ValueError("a measured material needs its table: pass measured=brdf.measured_tables(materials)")
        cache = self.__dict__.setdefault("_measured_uploads", {})
        key = tuple(id(m.data) for m in measured)
        hit = cache.get(key)
        if hit is not None and hit["context"] is self._context() and all(
                a is m.data for a, m in zip(hit["data"], measured)):
            return self._keep_recent(cache, key, hit, MEASURED_TABLE_SETS)["array"]
        host = np.concatenate([m.kernel_table() for m in measured])
        if host.size >= 1 << 31:
            raise ValueError(f"{len(measured)} measured tables exceed the kernels' int32 indexing: give fewer")
        entry = {"context": self._context(), "data": [m.data for m in measured], "array": self._to_device(host, "f32")}
        return self._keep_recent(cache, key, entry, MEASURED_TABLE_SETS)["array"]

    def effective_brdf(self, facets, vis, kinds, params, pair_i, pair_o, a_v, tangents=None, measured=None):
        """`tangents`: (F, 3) the per-face tangents of the tile the facets were sampled from
        (`SmallScale.face_tangents`, indexed by the facets' face), needed when a kind is anisotropic.
        `measured`: the MeasuredBRDFs whose tables the packed rows' slots name (`brdf.measured_tables`),
        needed when a kind is measured."""
        n_pairs = len(pair_i)
        if n_pairs == 0:
            return np.zeros((0, 3), np.float32)
        f = self._facets(facets)
        if tangents is None:
            if np.isin(np.asarray(kinds), ANISOTROPIC_KINDS).any():
                raise ValueError("an anisotropic material needs the tile's face tangents: "
                                 "effective_brdf(..., tangents=tile.face_tangents)")
            # Never read by the kernels without an anisotropic kind: one-element stand-ins, uploaded once.
            face, tangent = self._recurring(_NO_FACE, "i32"), self._recurring(_NO_TANGENT, "vec3")
        else:
            tangents = np.asarray(tangents)
            if tangents.ndim != 2 or tangents.shape[1] != 3 or len(tangents) == 0:
                raise ValueError(f"tangents must have shape (F, 3), got {tangents.shape}")
            face, tangent = f["face"], self._recurring(tangents, "vec3")
        tables = self._measured_tables(kinds, measured)
        chunks, per = chunking(vis.words, n_pairs, self._threads)
        out = self._new(n_pairs, "vec3")
        self._launch_effective_brdf(f, self._vis(vis), self._to_device(kinds, "i32"),
                                    self._to_device(np.asarray(params, np.float32).reshape(-1, 8), "f32"),
                                    self._to_device(pair_i, "i32"), self._to_device(pair_o, "i32"),
                                    self._to_device(a_v, "f32"), face, tangent, tables, vis.words, n_pairs, chunks,
                                    per, out)
        return self._to_host(out, n_pairs, "vec3")

    # --- small-scale interreflection (ground_truth(bounces=B), docs/design.md §4.6): one block ---
    def interreflection(self, tile, facets, vis, kinds, params, pair_i, pair_o, a_v, bounces, paths, seed,
                        tangents=None, measured=None):
        """(P, 3) float32: the bounces 2..`bounces` of f̄ at the pairs, by `paths` cosine-sampled paths per
        pair from the facets seen from ωo, with next-event estimation towards ωi at every hit
        (reference.interreflection, the same random numbers). `facets` and `vis` as effective_brdf's, from
        `tile`; `tangents` (F, 3) where a kind is anisotropic; `measured` (effective_brdf's) where one is measured."""
        n_pairs, bounces, paths = len(pair_i), int(bounces), int(paths)
        if n_pairs == 0 or bounces <= 1:
            return np.zeros((n_pairs, 3), np.float32)
        f = self._facets(facets)
        aniso = tangents is not None
        tangent = self._recurring(np.asarray(tangents, np.float32) if aniso else _NO_TANGENT, "vec3")
        tables = self._measured_tables(kinds, measured)
        chunks, per = chunking(paths, n_pairs, self._threads)
        out = self._new(n_pairs, "vec3")
        self._launch_interreflection(
            tile, f, self._facet_positions(facets, tile), self._vis(vis), self._to_device(kinds, "i32"),
            self._to_device(np.asarray(params, np.float32).reshape(-1, 8), "f32"), self._to_device(pair_i, "i32"),
            self._to_device(pair_o, "i32"), self._to_device(a_v, "f32"),
            self._recurring(np.ascontiguousarray(tile.material_ids, np.int32), "i32"),
            self._recurring(np.ascontiguousarray(tile.colors, np.float32), "vec3"), tangent, tables, aniso, len(facets),
            vis.words, paths, chunks, per, bounces, int(seed) % (1 << 31), n_pairs, out)
        # each path stands for Ns/paths facets of area ΔA (the facets' weight)
        return (self._to_host(out, n_pairs, "vec3") * (len(facets) / paths)).astype(np.float32)

    def normal_bins(self, facets, resolution):
        n = len(facets)
        bins = self._new(n, "i32")
        if n:
            self._launch_normal_bins(self._facets(facets), n, int(resolution), bins)
        return self._to_host(bins, n, "i32")

    def bvndf_histogram(self, facets, vis, order, bin_start, weight, pair_i, pair_o):
        n_bins, n_pairs = max(len(bin_start) - 1, 0), len(pair_i)
        hist = self._new((n_pairs, n_bins), "f32")
        if n_pairs and n_bins:
            self._launch_bvndf_histogram(self._vis(vis), vis.words, self._to_device(pair_i, "i32"),
                                         self._to_device(pair_o, "i32"), self._to_device(order, "i32"),
                                         self._to_device(bin_start, "i32"), self._to_device(weight, "f32"),
                                         n_pairs, n_bins, hist)
        return self._to_host(hist, (n_pairs, n_bins), "f32")

    def visible_weights(self, facets, vis, to_host=True):
        f = self._facets(facets)
        n = len(facets)
        weight = self._new(n, "f32")
        self._launch_visible_weights(f, self._vis(vis), len(vis.directions), vis.words, n, weight)
        if not to_host:
            return OnDevice(weight, self._queued_read(weight, n, "f32"))
        host = self._to_host(weight, n, "f32")
        f["visible_weight"] = (host, weight)  # ndf_em given `host` itself uses the device copy
        return host

    def _reuse(self, entry: dict, key: str, shape, kind: str):
        """entry[key] if it is a device array of this shape and kind, else a new one: frames and calls of
        one size reuse their buffers instead of allocating."""
        spec = (_shape(shape), kind)
        if entry.get(key + "/spec") != spec or key not in entry:
            entry[key] = self._new(spec[0], kind)
            entry[key + "/spec"] = spec
        return entry[key]

    def _host_shape(self, shape, kind):
        width = KINDS[kind][1]
        return _shape(shape) + ((width,) if width > 1 else ())

    def _trace_mesh(self, mesh) -> dict:
        """mesh.device_cache[self.name]: the mesh's device arrays and BVH (`_upload_trace_mesh`), built once
        per mesh and rebuilt when mesh.vertices or mesh.faces is replaced."""
        entry = mesh.device_cache.setdefault(self.name, {})
        if (entry.get("vertices_host") is not mesh.vertices or entry.get("faces_host") is not mesh.faces
                or entry.get("context") is not self._context()):
            entry.clear()  # the geometry (or the device) changed: everything derived from it is stale
            entry.update(self._upload_trace_mesh(mesh), vertices_host=mesh.vertices, faces_host=mesh.faces,
                         context=self._context())
        return entry

    def _upload_trace_mesh(self, mesh) -> dict:
        """The device arrays of a large-scale mesh and its BVH, as the trace and shade launches want them."""
        raise NotImplementedError

    def trace_primary(self, mesh, camera, to_host=True, if_changed=False, keep=False):
        """The G-buffer of `camera` on `mesh`, left on the device (and a host GBuffer with to_host). With
        if_changed (and to_host False), nothing is traced when the device already holds this camera's
        G-buffer of this mesh: an editor's frames that move no camera. keep: first keep the G-buffer on the
        device (of the same size) and its last shade as the reference frame of the rays' and shade's
        only_changed, which then trace and shade only the pixels whose hit is not on the reference's surface
        there (`trace.changed_pixels`): an anti-aliased frame's first sample, when the others are shaded once a
        pixel (`render`'s aa_shading="pixel")."""
        check_mesh(mesh)
        check_camera(camera)
        m = self._trace_mesh(mesh)
        key = camera.packed().tobytes()
        if if_changed and not to_host and m.get("gbuffer_key") == key:
            return None
        n = camera.width * camera.height
        if keep:
            if m.get("gbuffer_face/spec") != ((n,), "i32") or m.get("radiance/spec") != ((n,), "vec3"):
                raise ValueError(f"keep: no shaded frame of {n} pixels on the device to keep")
            # Two buffers each, swapped: the G-buffer's faces and hits and the last shade become the reference, and
            # the next trace and shade fill the others.
            for name, kind, reference in (("gbuffer_face", "i32", "reference_face"),
                                          ("gbuffer_position", "vec3", "reference_position"),
                                          ("radiance", "vec3", "reference_radiance")):
                spare = m[reference] if m.get(reference + "/spec") == ((n,), kind) else self._new((n,), kind)
                m[reference], m[name], m[reference + "/spec"] = m[name], spare, ((n,), kind)
            m["reference_eye"] = m["gbuffer_eye"]  # (anti-aliasing's jitter moves the rays, not the eye)
        m["changed_for"], m["occlusion_known/key"], m["lobe_known/key"] = None, None, None
        m["block_lenders_key"] = None  # (found again from the new hits)
        g = {"face": self._reuse(m, "gbuffer_face", n, "i32"), "bary": self._reuse(m, "gbuffer_bary", n, "vec2"),
             "position": self._reuse(m, "gbuffer_position", n, "vec3"), "t": self._reuse(m, "gbuffer_t", n, "f32")}
        self._launch_trace_primary(m, camera, g["face"], g["bary"], g["position"], g["t"])
        eye = camera.packed()[0:3].copy()
        m["gbuffer_eye"], m["gbuffer_size"], m["gbuffer_host"], m["gbuffer_width"] = eye, n, None, camera.width
        m["gbuffer_key"], m["light_vis_key"], m["occlusion_key"], m["occlusion_samples"] = key, None, None, 0
        m["lobe_rays_key"], m["lobe_rays"] = None, None
        if not to_host:
            return None
        host = GBuffer(**{key: self._to_host(g[key], n, kind) for key, kind in (
            ("face", "i32"), ("bary", "vec2"), ("position", "vec3"), ("t", "f32"))}, eye=eye.copy())
        m["gbuffer_host"] = host
        return host

    def trace_occluded(self, mesh, origins, directions, t_max, t_min=None):
        o, d, t_lo, t_hi = check_occlusion(mesh, origins, directions, t_max, t_min)
        out = np.zeros(len(o), bool)
        if len(o) == 0:
            return out
        m = self._trace_mesh(mesh)
        for lo in range(0, len(o), CHUNK_RAYS):
            hi = min(len(o), lo + CHUNK_RAYS)
            occluded = self._new(hi - lo, "u8")
            self._launch_trace_occluded(m, self._to_device(o[lo:hi], "vec3"), self._to_device(d[lo:hi], "vec3"),
                                        t_lo, self._to_device(t_hi[lo:hi], "f32"), hi - lo, occluded)
            out[lo:hi] = self._to_host(occluded, hi - lo, "u8") != 0
        return out

    @staticmethod
    def _rays_key(m, gbuffer, *what):
        """The key of rays traced from the device's own G-buffer (gbuffer None, or the host copy trace_primary
        returned) for `what`; None for rays from another GBuffer (never reused)."""
        return (m.get("gbuffer_key"), *what) if gbuffer is None or gbuffer is m.get("gbuffer_host") else None

    @staticmethod
    def _check_block_width(m, gbuffer, n, part):
        """A ray part's block width must be the frame's: the device G-buffer's camera width, or one that divides a
        host G-buffer's pixel count."""
        width = part[2]
        if not width:
            return
        own = gbuffer is None or gbuffer is m.get("gbuffer_host")
        if own and width != m.get("gbuffer_width"):
            raise ValueError(f"ray part block width {width} is not the frame's width {m.get('gbuffer_width')}")
        if not own and n % width:
            raise ValueError(f"ray part block width {width} does not divide the G-buffer's {n} pixels into rows")

    def _frame_lenders(self, m, gbuffer, face, position, eye, n, part):
        """(P,) int32 on the device: each pixel's lenders in its blocks of part's side (trace.share_block), found
        once for the device's G-buffer and that side and kept for its other sets of rays (a host GBuffer's each
        call)."""
        key = self._rays_key(m, gbuffer, "lenders", part[2], part[3])
        lenders = self._reuse(m, "block_lenders", n, "i32")
        if key is None or m.get("block_lenders_key") != key:
            self._launch_block_lenders(m, face, position, eye, part, n, lenders)
            m["block_lenders_key"] = key
        return lenders

    def _ray_starts(self, mesh, m, gbuffer):
        """(face, bary, position, eye, P) that shadow, occlusion and lobe rays leave from: the device's own
        G-buffer (gbuffer None or the host copy trace_primary returned), or a host GBuffer uploaded."""
        if gbuffer is None or gbuffer is m.get("gbuffer_host"):
            if "gbuffer_face" not in m:
                raise ValueError("gbuffer is None, but trace_primary has not run on this mesh with this backend")
            return m["gbuffer_face"], m["gbuffer_bary"], m["gbuffer_position"], m["gbuffer_eye"], m["gbuffer_size"]
        f, b, p, eye = check_gbuffer(gbuffer, len(mesh.faces))
        return self._to_device(f, "i32"), self._to_device(b, "vec2"), self._to_device(p, "vec3"), eye, len(f)

    def _changed(self, mesh, m, gbuffer, n, only_changed):
        """(changed flags, flag) that the trace and shade kernels take: with only_changed, the pixels of the device's
        own G-buffer whose hit is not on the kept reference frame's surface there (mark_changed, once a G-buffer);
        else a dummy (never read)."""
        if not only_changed:
            return self._reuse(m, "no_changed", 1, "u8"), 0
        if gbuffer is not None or m.get("reference_face/spec") != ((n,), "i32") \
                or not np.array_equal(m.get("reference_eye"), m["gbuffer_eye"]):
            raise ValueError("only_changed needs the device's own G-buffer (gbuffer None) and a frame of its size "
                             "and eye kept by trace_primary(..., keep=True)")
        if m.get("changed_for") is None:
            if m.get("face_material_host") is not mesh.face_material:
                m["face_material"] = self._to_device(np.asarray(mesh.face_material, np.int32), "i32")
                m["face_material_host"] = mesh.face_material
            changed = self._reuse(m, "changed", n, "u8")
            self._launch_mark_changed(m, n, changed)
            m["changed_for"] = True
        return m["changed"], 1

    def _changed_radiance(self, mesh, m, gbuffer, n, only_changed):
        """(changed flags, reference radiance, flag) that the shade kernels take (`_changed`)."""
        changed, flag = self._changed(mesh, m, gbuffer, n, only_changed)
        radiance = m["reference_radiance"] if flag else self._reuse(m, "no_reference_radiance", 1, "vec3")
        return changed, radiance, flag

    @staticmethod
    def _ray_mesh(m):
        """The mesh arrays the shadow, occlusion and lobe rays' starts read (the trace kernels' ray_start), in
        their launch order; `_upload_trace_mesh` puts them in the mesh's device cache."""
        return m["points"], m["normals"], m["faces"], m["face_normals"]

    @staticmethod
    def _offsets(mesh, m):
        """(eps, t_min) of the mesh (trace.offsets), once per mesh and only for rays that need them: it scans
        every vertex."""
        if "offsets" not in m:
            m["offsets"] = offsets(mesh)
        return m["offsets"]

    def trace_shadows(self, mesh, gbuffer, lights_packed, to_host=True, samples=1, if_changed=False, part=(0, 1),
                      only_changed=False):
        """`samples` shadow rays per light and pixel of the G-buffer (None: the one on the device), or one count a
        light (trace.light_samples); the visible shares left on the device. With if_changed (and to_host False),
        nothing is traced when the device already holds them for this G-buffer, these lights and samples. `part`
        (index, count): only the rays that anti-aliasing sample index of count traces of the set (trace.ray_part),
        their share; (index, count, W[, side]): shared in the pixel blocks of a frame of width W (trace.pixel_parts)
        for a light of BLOCK_SLOTS rays or more. only_changed: the pixels not on the kept frame's surface alone
        (`trace_primary`'s keep); the others keep the shares they have."""
        check_mesh(mesh)
        lights = check_lights(lights_packed)
        samples = light_samples(samples, len(lights))
        part = check_ray_part(part)
        m = self._trace_mesh(mesh)
        key = self._rays_key(m, gbuffer, lights.tobytes(), samples.tobytes(), part, bool(only_changed))
        if if_changed and not to_host and key is not None and m.get("light_vis_key") == key:
            return None
        face, bary, position, eye, n = self._ray_starts(mesh, m, gbuffer)
        self._check_block_width(m, gbuffer, n, part)
        vis = self._reuse(m, "gbuffer_light_vis", (n, len(lights)), "u8")
        if n and len(lights):
            shared = part[2] > 0 and samples.max() >= BLOCK_SLOTS
            traced = self._reuse(m, "block_light_vis", (n, len(lights)), "u8") if shared else vis
            self._launch_trace_shadows(m, face, bary, position, eye, lights, samples, *self._offsets(mesh, m), part,
                                       self._changed(mesh, m, gbuffer, n, only_changed), n, traced)
            if shared:
                lenders = self._frame_lenders(m, gbuffer, face, position, eye, n, part)
                self._launch_share_block_shadows(m, lenders, face, samples, part, n, len(lights), traced, vis)
        m["light_vis_key"] = key
        return self._to_host(vis, (n, len(lights)), "u8") if to_host else None

    def trace_occlusion(self, mesh, gbuffer, samples, to_host=True, if_changed=False, part=(0, 1),
                        only_changed=False):
        """`samples` environment-occlusion rays per pixel of the G-buffer (None: the one on the device), their
        (P,) uint32 masks left on the device for shade (reference.trace_occlusion); 0 samples: none, and shade
        shadows the environment by the SSDF alone. With if_changed (and to_host False), nothing is traced
        when the device already holds them for this G-buffer and samples. `part` (index, count): only the
        rays that anti-aliasing sample index of count traces (trace.ray_part), shade then reads those; (index,
        count, W): shared in pixel blocks, as trace_shadows'. only_changed: as trace_shadows'."""
        check_mesh(mesh)
        samples = check_occlusion_samples(samples)
        part = check_ray_part(part)
        m = self._trace_mesh(mesh)
        key = self._rays_key(m, gbuffer, samples, part, bool(only_changed))
        if if_changed and not to_host and key is not None and m.get("occlusion_key") == key:
            return None
        face, bary, position, eye, n = self._ray_starts(mesh, m, gbuffer)
        self._check_block_width(m, gbuffer, n, part)
        mask = self._reuse(m, "gbuffer_occlusion", n, "u32")
        if n and samples:
            traced = self._reuse(m, "block_occlusion", n, "u32") if part[2] else mask
            self._launch_trace_occlusion(m, face, bary, position, eye, *self._offsets(mesh, m), samples, part,
                                         self._changed(mesh, m, gbuffer, n, only_changed), n, traced)
            if part[2]:
                self._launch_share_block_masks(m, self._frame_lenders(m, gbuffer, face, position, eye, n, part), face,
                                               samples, part, n, traced, mask,
                                               self._reuse(m, "occlusion_known", n, "u32"))
            m["occlusion_known/key"] = part
        m["occlusion_key"], m["occlusion_samples"], m["occlusion_part"] = key, samples, part
        if not to_host:
            return None
        return self._to_host(mask, n, "u32") if samples else np.zeros(n, np.uint32)

    def trace_lobe_rays(self, mesh, gbuffer, lobes, to_host=True, if_changed=False, part=(0, 1),
                        only_changed=False):
        """trace.LOBE_RAYS rays per pixel of the G-buffer (None: the one on the device) towards each sharp
        environment lobe of `lobes` (M ≤ trace.LOBE_RAY_LOBES rows [axis, η]), their (P,) uint32 masks left on
        the device for shade (reference.trace_lobe_rays). With if_changed (and to_host False), nothing is
        traced when the device already holds them for this G-buffer and lobes. `part`: as trace_occlusion's,
        and the same as the occlusion rays' for shade. only_changed: as trace_shadows'."""
        check_mesh(mesh)
        lobes = check_lobes(lobes)
        part = check_ray_part(part)
        m = self._trace_mesh(mesh)
        key = self._rays_key(m, gbuffer, lobes.tobytes(), part, bool(only_changed))
        if if_changed and not to_host and key is not None and m.get("lobe_rays_key") == key:
            return None
        face, bary, position, eye, n = self._ray_starts(mesh, m, gbuffer)
        self._check_block_width(m, gbuffer, n, part)
        mask = self._reuse(m, "gbuffer_lobe_occlusion", n, "u32")
        if n and len(lobes):
            traced = self._reuse(m, "block_lobe_occlusion", n, "u32") if part[2] else mask
            self._launch_trace_lobe_rays(m, face, bary, position, eye, lobes, *self._offsets(mesh, m), part,
                                         self._changed(mesh, m, gbuffer, n, only_changed), n, traced)
            if part[2]:
                self._launch_share_block_masks(m, self._frame_lenders(m, gbuffer, face, position, eye, n, part), face,
                                               LOBE_RAYS, part, n, traced, mask,
                                               self._reuse(m, "lobe_known", n, "u32"))
            m["lobe_known/key"] = part
        m["lobe_rays_key"], m["lobe_rays"], m["lobe_part"] = key, lobes.tobytes(), part
        if not to_host:
            return None
        return self._to_host(mask, n, "u32") if len(lobes) else np.zeros(n, np.uint32)

    def ray_known(self, mesh) -> tuple:
        """(occlusion, lobe), each (P,) uint32 read back, or None where none was traced: the occlusion and lobe
        rays each pixel was lent by its pixel block (trace.share_block) in the device's last trace_occlusion and
        trace_lobe_rays with a block width in their part: what a host GBuffer's occlusion_known and lobe_known
        hold for shade."""
        m = self._trace_mesh(mesh)
        out = []
        for name, part in (("occlusion_known", m.get("occlusion_part")), ("lobe_known", m.get("lobe_part"))):
            spec = m.get(name + "/spec")
            shared = part is not None and part[2] and spec is not None and m.get(name + "/key") == part
            out.append(self._to_host(m[name], spec[0][0], "u32") if shared else None)
        return out[0], out[1]

    def shade(self, mesh, static, camera_packed, lights_packed, gbuffer=None, to_host=True, only_material=None,
              keep_visibility=False, only_changed=False):
        dev = self._shade_static(static)
        m = self._trace_mesh(mesh)
        if only_changed and (only_material is not None or keep_visibility):
            raise ValueError("only_changed shades part of an anti-aliased frame: not with only_material or "
                             "keep_visibility")
        if only_material is not None:
            if gbuffer is not None:
                raise ValueError("only_material shades over the device's last frame: pass gbuffer=None")
            if not (isinstance(only_material, (int, np.integer)) and 0 <= only_material < len(static.mat_info)):
                raise ValueError(f"only_material must be a material index in [0, {len(static.mat_info)}), "
                                 f"got {only_material!r}")
            if m.get("radiance/spec") != ((m.get("gbuffer_size"),), "vec3"):
                raise ValueError("only_material needs the last whole frame of this G-buffer on the device: "
                                 "shade it whole first")
        lights = np.asarray(lights_packed, np.float32).reshape(-1, 8)
        n_lights = len(lights)
        if gbuffer is None:
            if "gbuffer_face" not in m:
                raise ValueError("no G-buffer on the device for this mesh: call trace_primary first")
            face, bary, n = m["gbuffer_face"], m["gbuffer_bary"], m["gbuffer_size"]
            vis = m.get("gbuffer_light_vis") if n_lights else None
            if n_lights and m.get("gbuffer_light_vis/spec") != ((n, n_lights), "u8"):
                raise ValueError("no shadow rays on the device for these lights: call trace_shadows first")
            occ_samples = m.get("occlusion_samples", 0)
            occ = m["gbuffer_occlusion"] if occ_samples else None
            part = m.get("occlusion_part", (0, 1, 0, 2)) if occ_samples else (0, 1, 0, 2)
            lobe_occ = None
            if occ_samples and static.n_sharp_lobes:
                if m.get("lobe_rays") != static.sharp_lobes().tobytes():
                    raise ValueError("no lobe rays on the device for this environment's sharp lobes: call "
                                     "trace_lobe_rays after trace_occlusion")
                if m.get("lobe_part") != part:
                    raise ValueError(f"the lobe rays on the device are part {m.get('lobe_part')} of their set and the "
                                     f"occlusion rays part {part}: trace both for the same anti-aliasing sample")
                lobe_occ = m["gbuffer_lobe_occlusion"]
            known = (m.get("occlusion_known"), m.get("lobe_known") if lobe_occ is not None else None)
        else:
            if not isinstance(gbuffer, GBuffer):
                raise ValueError(f"gbuffer must be a GBuffer (or None), got {type(gbuffer).__name__}")
            f = np.asarray(gbuffer.face, np.int32).reshape(-1)
            n = len(f)
            bary_h = np.asarray(gbuffer.bary, np.float32)
            if bary_h.shape != (n, 2):
                raise ValueError(f"gbuffer.bary must have shape ({n}, 2), got {bary_h.shape}")
            if n and int(f.max()) >= len(mesh.faces):
                raise ValueError(f"gbuffer.face holds face {int(f.max())} of a mesh with {len(mesh.faces)}")
            face, bary, vis = self._to_device(f, "i32"), self._to_device(bary_h, "vec2"), None
            if n_lights:
                vis_h = np.asarray(gbuffer.light_vis, np.uint8)
                if vis_h.shape != (n, n_lights):
                    raise ValueError(f"gbuffer.light_vis must have shape ({n}, {n_lights}), got {vis_h.shape}")
                vis = self._to_device(vis_h, "u8")
            occ_samples, occ = check_occlusion_samples(gbuffer.occlusion_samples), None
            part = check_ray_part(gbuffer.ray_part)
            if occ_samples:
                occ_h = np.asarray(gbuffer.occlusion, np.uint32) if gbuffer.occlusion is not None else None
                if occ_h is None or occ_h.shape != (n,):
                    raise ValueError(f"gbuffer.occlusion must have shape ({n},) with occlusion_samples "
                                     f"{occ_samples}, got {None if occ_h is None else occ_h.shape}")
                occ = self._to_device(occ_h, "u32")
            lobe_occ = None
            if occ_samples and static.n_sharp_lobes:
                lobe_h = np.asarray(gbuffer.lobe_occlusion, np.uint32) if gbuffer.lobe_occlusion is not None else None
                if lobe_h is None or lobe_h.shape != (n,):
                    raise ValueError(f"gbuffer.lobe_occlusion must have shape ({n},) where the inputs have sharp "
                                     f"lobes and occlusion_samples > 0, got {None if lobe_h is None else lobe_h.shape}")
                lobe_occ = self._to_device(lobe_h, "u32")
            known = [None, None]
            if occ_samples and part[2]:  # rays shared in pixel blocks: the bits each pixel was lent
                for i, (name, on) in enumerate((("occlusion_known", True), ("lobe_known", lobe_occ is not None))):
                    bits = getattr(gbuffer, name)
                    if on:
                        if bits is None or np.shape(bits) != (n,):
                            raise ValueError(f"gbuffer.{name} must have shape ({n},) where ray_part has a block "
                                             f"width, got {None if bits is None else np.shape(bits)}")
                        known[i] = self._to_device(np.asarray(bits, np.uint32), "u32")
        if vis is None:
            vis = self._reuse(m, "no_light_vis", (1, 1), "u8")  # never read: no light
        if occ is None:
            occ = self._reuse(m, "no_occlusion", 1, "u32")  # never read: no occlusion rays
        n_sharp = int(static.n_sharp_lobes) if lobe_occ is not None else 0
        if lobe_occ is None:
            lobe_occ = occ  # never read: no lobe rays
        if not (occ_samples and part[2]):
            known = (occ, occ)  # never read: each pixel's own part
        known = tuple(occ if k is None else k for k in known)
        out = self._reuse(m, "radiance", n, "vec3")
        camera = np.asarray(camera_packed, np.float32).reshape(16)
        kept_mode, kept, key = self._kept_visibility(m, dev, static, camera, gbuffer, occ_samples, part, n_sharp, n,
                                                     only_material, keep_visibility)
        if kept_mode == 1:
            m["visibility_key"] = None  # (until the launch that writes them is queued)
        if n:
            self._launch_shade(dev, m, face, bary, vis, occ, occ_samples, lobe_occ, n_sharp, part, known, lights,
                               camera, n, -1 if only_material is None else int(only_material),
                               self._changed_radiance(mesh, m, gbuffer, n, only_changed), kept_mode, *kept, out)
        if kept_mode == 1:
            m["visibility_key"] = key
        m["visibility_read"] = kept_mode == 2
        return self._to_host(out, n, "vec3") if to_host else None

    def _kept_visibility(self, m, dev, static, camera, gbuffer, occ_samples, part, n_sharp, n, only_material,
                         keep) -> tuple:
        """(kept_mode, (amounts, scales), key) of a shade: each environment lobe's shadowed amount and the irradiance
        scale at every pixel, which depend on the G-buffer, the rays and the environment but not on the materials.
        A whole frame with keep_visibility keeps them (mode 1); a later only_material shade, or whole frame with
        keep_visibility, whose inputs they still fit reads them back (mode 2) instead of casting the environment's
        visibility again; else mode 0."""
        n_env = int(dev["n_env"])
        key = None
        # (the kernels index the kept amounts with 32-bit integers)
        if gbuffer is None and n_env and n and n * n_env < 2**31 \
                and (occ_samples == 0 or m.get("occlusion_key") is not None) \
                and (n_sharp == 0 or m.get("lobe_rays_key") is not None):
            # The eye turns the occlusion rays' frame to the camera's side. The device arrays themselves are
            # compared by identity: held in the key, none can pass its id on.
            key = (m.get("gbuffer_key"), camera[:3].tobytes(), m.get("occlusion_key") if occ_samples else None,
                   m.get("lobe_rays_key") if n_sharp else None, tuple(part), int(occ_samples), int(n_sharp),
                   *(dev[name] for name in ("env_sgs", "env_residual", "ssdf_basis", "ssdf_coeffs", "table", "faces",
                                            "positions", "normals", "tangents")),
                   bool(static.has_ssdf), int(static.ssdf_res), tuple(np.shape(static.env_residual)))
        held = m.get("visibility_key")
        mode = 0
        # Read back by a design-only shade, and by a whole frame that would keep them (the lights, which they do
        # not hold, changed: an editor's light edit), where they still fit.
        if key is not None and (only_material is not None or keep) and held is not None and len(held) == len(key) \
                and all(a is b or (isinstance(a, (bytes, tuple, int)) and a == b) for a, b in zip(held, key)):
            mode = 2
        elif key is not None and only_material is None and keep:
            mode = 1
        if mode == 0:
            return 0, (self._reuse(m, "no_kept_amount", 1, "f32"), self._reuse(m, "no_kept_scale", 1, "vec3")), None
        return mode, (self._reuse(m, "kept_amount", n * n_env, "f32"), self._reuse(m, "kept_scale", n, "vec3")), key

    def shade_litsphere(self, mesh, spheres, camera_packed, lights_packed, env_maps, env_levels, view_mode=0,
                        shrink=1.0, shadowed=True, to_host=True):
        """(P, 3) float32 lit-sphere radiance of every pixel of the G-buffer the last trace_primary /
        trace_shadows left on the device for `mesh` (shading.litsphere_reference): `spheres` a
        litsphere.SpherePack (its device copies kept in spheres.device[self.name]), view_mode 0 the
        pixel's view direction, 1 the camera's axis (the paper's distant viewer); `shrink` scales the
        turned normal before the lookup (litsphere.SHRINK, the paper's 0.995, or 1); misses get the
        environment (env_maps, env_levels: lighting.PrefilteredEnvironment) along the camera ray. With
        shadowed=False every light is seen whole (no shadow rays needed: the paper's frame)."""
        m = self._trace_mesh(mesh)
        lights = np.asarray(lights_packed, np.float32).reshape(-1, 8)
        if "gbuffer_face" not in m:
            raise ValueError("no G-buffer on the device for this mesh: call trace_primary first")
        face, bary, n = m["gbuffer_face"], m["gbuffer_bary"], m["gbuffer_size"]
        if shadowed and len(lights) and m.get("gbuffer_light_vis/spec") != ((n, len(lights)), "u8"):
            raise ValueError("no shadow rays on the device for these lights: call trace_shadows first")
        if int(np.max(mesh.face_material, initial=0)) >= len(spheres.sphere_of_material):
            raise ValueError(f"the mesh uses material {int(mesh.face_material.max())} of "
                             f"{len(spheres.sphere_of_material)} lit sphere(s)")
        if m.get("face_material_host") is not mesh.face_material:
            m["face_material_host"], m["face_material"] = mesh.face_material, self._to_device(mesh.face_material, "i32")
        dev = spheres.device.get(self.name)
        if dev is None or dev.get("context") is not self._context():
            dev = spheres.device[self.name] = {**self._upload_spheres(spheres), "context": self._context()}
        env = (np.asarray(env_maps, np.float32).reshape(-1, 3), np.asarray(env_levels, np.float32).reshape(-1, 4))
        if m.get("litsphere_env_host") is None or any(a.shape != b.shape or not np.array_equal(a, b)
                                                     for a, b in zip(m["litsphere_env_host"], env)):
            m["litsphere_env_host"] = env
            m["litsphere_env"] = (self._to_device(env[0], "vec3"), self._to_device(env[1], "f32"))
        if not len(lights):
            vis = self._reuse(m, "no_light_vis", (1, 1), "u8")
        elif shadowed:
            vis = m["gbuffer_light_vis"]
        else:
            if m.get("all_visible/spec") != ((n, len(lights)), "u8"):
                m["all_visible"] = self._to_device(np.full((n, len(lights)), 255, np.uint8), "u8")
                m["all_visible/spec"] = ((n, len(lights)), "u8")
            vis = m["all_visible"]
        out = self._reuse(m, "radiance", n, "vec3")
        if n:
            self._launch_shade_litsphere(dev, m, face, bary, vis, lights, np.asarray(camera_packed, np.float32),
                                         int(view_mode), float(shrink), *m["litsphere_env"], n, out)
        return self._to_host(out, n, "vec3") if to_host else None

    def frame_buffer(self, width: int, height: int) -> np.ndarray:
        """A new (H, W, 3) uint8 host array for `frame_u8(..., out=)` in the memory this backend reads back
        into fastest (a display loop keeps a few and reuses them): plain memory here."""
        return np.empty((int(height), int(width), 3), np.uint8)

    def frame_radiance(self, mesh, width: int, height: int) -> np.ndarray:
        """(H, W, 3) float32: the radiance the last shade or shade_litsphere left on the device for `mesh`."""
        return self._to_host(self._frame(mesh, width, height), width * height, "vec3").reshape(height, width, 3)

    def frame_u8(self, mesh, width: int, height: int, exposure: float = 0.0, operator: str = "aces",
                 out: np.ndarray | None = None) -> np.ndarray:
        """(H, W, 3) uint8 sRGB of that radiance, tone-mapped on the device (images.tonemap: `exposure` in
        stops, `operator` one of images.TONEMAP_OPERATORS): a frame for display, read back at a quarter of
        the float32 frame's bytes; into `out`, an (H, W, 3) C-contiguous uint8 host array, if given (a display
        loop that reuses its buffers: a new 6 MB array costs the host its page faults every frame)."""
        from .images import TONEMAP_OPERATORS, check_exposure

        if operator not in TONEMAP_OPERATORS:
            raise ValueError(f"unknown tone-map operator {operator!r}; choose one of {TONEMAP_OPERATORS}")
        if out is not None and not (isinstance(out, np.ndarray) and out.shape == (height, width, 3)
                                    and out.dtype == np.uint8 and out.flags.c_contiguous and out.flags.writeable):
            raise ValueError(f"out must be a writeable C-contiguous ({height}, {width}, 3) uint8 array")
        scale = 2.0 ** check_exposure(exposure)
        radiance = self._frame(mesh, width, height)
        n = width * height
        frame = self._reuse(self._trace_mesh(mesh), "frame_u8", 3 * n, "u8")
        self._launch_tonemap(radiance, float(scale), TONEMAP_OPERATORS.index(operator), n, frame)
        host = self._to_host(frame, 3 * n, "u8", out)
        return out if out is not None else host.reshape(height, width, 3)

    def accumulate_frame(self, mesh, width: int, height: int, weight: float, first: bool) -> None:
        """Add `weight` times the frame last shaded (`shade(..., to_host=False)`) to the mesh's frame sum on the
        device (`first`: the sum starts here): anti-aliasing samples averaged where they are made."""
        radiance = self._frame(mesh, width, height)
        n = int(width) * int(height)
        total = self._reuse(self._trace_mesh(mesh), "radiance_sum", n, "vec3")
        self._launch_accumulate(radiance, float(weight), bool(first), n, total)

    def accumulated_frame(self, mesh, width: int, height: int, to_host: bool = True):
        """The frame sum of `accumulate_frame` becomes the mesh's frame (what `frame_u8` tone-maps); → its (P, 3)
        float32 host copy, or None with to_host=False."""
        m = self._trace_mesh(mesh)
        n = int(width) * int(height)
        self._frame(mesh, width, height)  # (checks that a frame of that size is there)
        if m.get("radiance_sum/spec") != m.get("radiance/spec"):
            raise ValueError(f"no {width}x{height} frame sum of this mesh on the device: accumulate_frame first")
        m["radiance"], m["radiance_sum"] = m["radiance_sum"], m["radiance"]
        return self._to_host(m["radiance"], n, "vec3") if to_host else None

    def _launch_accumulate(self, radiance, weight, first, n, total):
        raise NotImplementedError

    def _frame(self, mesh, width, height):
        m = self._trace_mesh(mesh)
        if m.get("radiance/spec") != ((int(width) * int(height),), "vec3"):
            raise ValueError(f"no {width}x{height} frame of this mesh on the device: shade one first")
        return m["radiance"]

    def litsphere_texels(self, inputs: dict, lights, resolution: int) -> np.ndarray:
        """(A, R, R, 3) float32 images of the unit sphere seen from +Z far away, lit by unit irradiance
        from each of `lights` (A, 3) unit directions (litsphere.sphere_image): the material's response
        f(n, l, v)(n·l)⁺ at every texel of litsphere.texel_normals(resolution). `inputs`:
        litsphere.texel_inputs(material)."""
        lights = np.ascontiguousarray(lights, np.float32).reshape(-1, 3)
        resolution = int(resolution)
        n = len(lights) * resolution * resolution
        arrays = [self._to_device(lights, "vec3"), self._to_device(inputs["kinds"], "i32"),
                  self._to_device(inputs["params"], "f32"), self._to_device(inputs["info"], "i32"),
                  self._to_device(inputs["lobes"], "f32"), self._to_device(inputs["amplitudes"], "f32")]
        out = self._new(n, "vec3")
        if n:
            self._launch_litsphere_texels(resolution, int(inputs["effective"]), *arrays, n, out)
        return self._to_host(out, n, "vec3").reshape(len(lights), resolution, resolution, 3)

    def _shade_input(self, role: str, host, upload):
        """The device copy of shade input `role` (a ShadeInputs field) made by `upload(host)`, or the one
        made last for that role when `host` is the same memory as then (a large array that an edit kept:
        the mesh, the environment's maps, a bake's μ tables; the array is held here, so that its memory
        cannot pass to another array) or, if small, holds the same values. So the new ShadeInputs of an
        edit copies only what the edit changed: on a GPU host each upload costs 0.1–0.3 ms of host time.
        Shade inputs are not changed in place (render.static_inputs makes new arrays)."""
        if isinstance(host, DeviceArray) and host.owner is self:  # a bake's table, left here by material_tables
            return host.flat
        host = np.asarray(host)
        held = self.__dict__.setdefault("_shade_inputs_held", {}).get(role)
        if held is not None and held[0].shape == host.shape and held[0].dtype == host.dtype:
            given, kept, device = held
            if given is host and not host.flags.writeable:  # the very array, frozen: no compare
                return device
            if host.nbytes <= SHADE_INPUT_COMPARE_BYTES:
                if kept == host.tobytes():  # the same bits (a bytes compare: a tenth of np.array_equal's time)
                    self._shade_inputs_held[role] = (host, kept, device)
                    return device
            elif kept.__array_interface__ == host.__array_interface__:
                return device
        device = upload(host)
        kept = host.tobytes() if host.nbytes <= SHADE_INPUT_COMPARE_BYTES else host
        self._shade_inputs_held[role] = (host, kept, device)
        return device

    def _shade_static(self, static: ShadeInputs) -> dict:
        """Device copies of a scene's shade inputs (`_upload_shade_static`), checked and made once, kept
        with them (static.device[self.name])."""
        dev = static.device.get(self.name)
        if dev is None or dev.get("context") is not self._context():
            basis = np.asarray(static.ssdf_basis, np.float32)
            coeffs = np.asarray(static.ssdf_coeffs, np.float32)
            levels = np.asarray(static.env_levels, np.float32).reshape(-1, 4)
            if len(levels) == 0:
                raise ValueError("static.env_levels is empty: the prefiltered environment needs >= 1 level")
            residual_shape = np.shape(static.env_residual)
            if len(residual_shape) != 3 or residual_shape[2] != 3 or min(residual_shape[:2]) < 1:
                raise ValueError(f"static.env_residual must be an (H, W, 3) map, got shape {residual_shape}")
            if static.has_ssdf and (coeffs.shape[1] != basis.shape[0] - 1 or basis.shape[1] != static.ssdf_res ** 2):
                raise ValueError(f"static.ssdf_basis {basis.shape} and .ssdf_coeffs {coeffs.shape} do not fit "
                                 f"ssdf_res {static.ssdf_res} (want (R + 1, res²) and (V, R))")
            if static.has_ssdf and len(static.env_sgs) and np.shape(static.env_theta) != (len(coeffs),
                                                                                        len(static.env_sgs)):
                raise ValueError(f"static.env_theta {np.shape(static.env_theta)} does not fit {len(coeffs)} vertices "
                                 f"and {len(static.env_sgs)} environment lobes (want (V, K), ssdf.ssdf_at_axes)")
            dev = static.device[self.name] = {**self._upload_shade_static(static, levels, basis, coeffs),
                                              "context": self._context()}
        return dev

    def _ssdf_grid(self, grid) -> dict:
        """grid.device_cache[self.name]: an ssdf.SsdfGrid's directions and pruning blocks on the device."""
        entry = grid.device_cache.get(self.name)
        if entry is None or entry.get("context") is not self._context():
            entry = grid.device_cache[self.name] = {
                "context": self._context(),
                "directions": self._to_device(grid.directions, "vec3"),
                "half_angle": self._to_device(grid.half_angle, "f32"),
                "members": self._to_device(grid.block_members, "i32"),
                "axis": self._to_device(grid.block_axis, "vec3"),
                "cos": self._to_device(np.cos(grid.block_radius), "f32"),
                "sin": self._to_device(np.sin(grid.block_radius), "f32"),
            }
        return entry

    def ssdf_distance(self, grid, visible):
        visible = np.asarray(visible, bool)
        n_v, n = visible.shape
        if n != len(grid.directions):
            raise ValueError(f"visible has {n} columns for a grid of {len(grid.directions)} directions")
        if n_v == 0:
            return np.zeros((0, n), np.float32)
        theta = self._new((n_v, n), "f32")
        self._launch_ssdf_distance(self._ssdf_grid(grid), grid.block_members.shape, self._to_device(visible, "u8"),
                                   self._to_device(grid.block_classes(visible), "u8"), n_v, n, theta)
        return self._to_host(theta, (n_v, n), "f32")

    def _facet_weight(self, f, facet_weight):
        """The device copy of a facet weight (see device_copy): visible_weights' own output when given it."""
        return device_copy(facet_weight, f.get("visible_weight"), lambda host: self._to_device(host, "f32"))

    def ndf_em(self, facets, axes, sharpness, weight, iterations, facet_weight=None, to_host=True, meanwhile=None):
        on_device = isinstance(axes, DeviceStart)  # (em_start's rows: copied on the device)
        start = None if on_device else LobeSet(axes, sharpness, weight)
        j = axes.count if on_device else len(start)
        if int(iterations) <= 0:
            start = axes.host() if on_device else start
            result = (start.axes, start.sharpness, start.weight, 0)
            if to_host:
                return result
            return DeviceLobes((self._to_device(start.axes, "vec3"), self._to_device(start.sharpness, "f32")), j,
                               lambda: result)
        f = self._facets(facets)
        mass = f["area"] if facet_weight is None else self._facet_weight(f, facet_weight)
        prog = self._run_em(f, mass, axes.device if on_device else em_start_rows(start), len(facets), j,
                            int(iterations), facet_weight is not None, meanwhile)
        if not to_host:
            # The result's copy is queued behind the EM: reading it back waits for the EM, not for what
            # the caller queues after it.
            read = self._queued_read(prog["result"], (j, 6), "f64")
            return DeviceLobes((prog["axes32"], prog["sharp32"]), j, lambda: em_result_rows(read()))
        return em_result_rows(self._to_host(prog["result"], (j, 6), "f64"))

    def _run_em(self, f, mass, start_rows, n, j, iterations, weighted, meanwhile=None) -> dict:
        """Queue at most `iterations` EM steps over the `n` facets (device arrays `f`, weights `mass`) from
        `start_rows` (em_start's device rows, or em_start_rows of a LobeSet, a host array), calling
        `meanwhile` (ndf_em's) before the host first waits on the device (`_step_em`) → the EM's
        arrays: "result" (J, 6) float64 rows (em_result_rows), "axes32" and "sharp32" (the lobes as
        lobe_moments reads them)."""
        raise NotImplementedError

    def _lobes_on_device(self, axes, sharpness) -> tuple:
        """→ (J, axes, sharpness) on the device: a DeviceLobes' own arrays (the lobes an EM left there: no
        upload), or host axes (J, 3) and sharpness (J,) uploaded as float32."""
        if isinstance(axes, DeviceLobes):
            return (axes.count, *axes.device)
        return len(axes), self._to_device(axes, "vec3"), self._to_device(sharpness, "f32")

    @staticmethod
    def _keep_recent(cache: dict, key, value, size: int = 32):
        """cache[key] = value, most recent last, holding at most `size` entries (EM programs per facet
        count, J, step count and weighting: a session that edits a few materials reuses them)."""
        cache.pop(key, None)
        cache[key] = value
        while len(cache) > size:
            cache.pop(next(iter(cache)))
        return value

    def _keep_asg_em(self, key, program, n_bins: int, n_lobes: int) -> None:
        """Keep an ASG EM program (its buffers and launches) for the next call of its shape, the eight most recent,
        unless its (bins, J) float64 responsibilities pass ASG_EM_KEEP_BYTES (then it is made again when asked)."""
        if n_bins * n_lobes * 8 <= ASG_EM_KEEP_BYTES:
            self._keep_recent(self._asg_em_programs, key, program, size=8)

    @staticmethod
    def _step_em(prog: dict, iterations: int, stopped, meanwhile=None) -> None:
        """Load the start, queue the EM's steps (run_em_steps: looking at the device's stop flag,
        `stopped()`, only now and then) and unpack the result, through `prog`'s launches."""
        prog["load"]()

        def enqueue_step():
            for launch in prog["steps"]:
                launch()

        run_em_steps(iterations, enqueue_step, stopped, meanwhile)
        prog["unload"]()

    # --- the matrix method's M (stage `matrix`, Wu 2011 §3.5; oracle matrix.brdf_matrix) ---
    def brdf_matrix(self, kinds, params, material: int, normals, wi, wo, color, measured=None) -> np.ndarray:
        """(L, P) float32 M[l, k] = color·f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺ for material row `material`
        of the packed table (kinds (M,), params (M, 8): brdf.pack_materials), normals (L, 3), direction pairs
        wi, wo (P, 3 each) and a colour direction (3,) (Wu §3.7); `measured` as effective_brdf's. The oracle is
        `matrix.brdf_matrix` (float64).
        The pairs recur from block to block of one M (UploadCache), the normals are a new block each call."""
        normals = np.asarray(normals, np.float32).reshape(-1, 3)
        wi = np.asarray(wi, np.float32).reshape(-1, 3)
        wo = np.asarray(wo, np.float32).reshape(-1, 3)
        if wi.shape != wo.shape:
            raise ValueError(f"wi and wo must have the same shape, got {wi.shape} and {wo.shape}")
        kinds = np.asarray(kinds, np.int32).reshape(-1)
        params = np.asarray(params, np.float32).reshape(-1, 8)
        m = int(material)
        if not (0 <= m < len(kinds) == len(params)):
            raise ValueError(f"material {material} is not a row of the packed table ({len(kinds)} kinds, "
                             f"{len(params)} parameter rows)")
        color = np.asarray(color, np.float64).reshape(3)
        n_rows, n_pairs = len(normals), len(wi)
        out = self._new((n_rows, n_pairs), "f32")
        if n_rows and n_pairs:
            self._launch_brdf_matrix(self._to_device(normals, "vec3"), self._recurring(wi, "vec3"),
                                     self._recurring(wo, "vec3"), self._to_device(kinds, "i32"),
                                     self._to_device(params, "f32"), self._measured_tables(kinds[m:m + 1], measured),
                                     m, color, n_rows, n_pairs, out)
        return self._to_host(out, (n_rows, n_pairs), "f32")

    def _launch_brdf_matrix(self, normals, wi, wo, kinds, params, tables, m, color, n_rows, n_pairs, out):
        raise NotImplementedError

    # --- the SG fit of a measured BRDF (stage `sgfit`, Wang 2009 §4.1–4.2; oracle measured.fit_sums) ---
    SGFIT_CHUNK = 1024  # samples a thread sums in float32 (its partial sums are added on the host in float64)

    def sg_fit_data(self, basis, target, weight) -> dict:
        """The fit's samples (`measured.fit_samples`: basis (N, 4), target (N, 3), weight (N,)) on the device,
        uploaded once for all of a fit's `sg_fit_sums` calls."""
        basis = np.asarray(basis, np.float32).reshape(-1, 4)
        target = np.asarray(target, np.float32).reshape(-1, 3)
        weight = np.asarray(weight, np.float32).reshape(-1)
        if not (len(basis) == len(target) == len(weight)):
            raise ValueError(f"sg_fit_data: {len(basis)} basis rows, {len(target)} targets, {len(weight)} weights")
        return {"basis": self._to_device(basis, "f32"), "target": self._to_device(target, "f32"),
                "weight": self._to_device(weight, "f32"), "n": len(basis), "context": self._context()}

    def sg_fit_sums(self, data: dict, candidates, coef=None) -> np.ndarray:
        """For candidates (C, 4) [η1, f0_1, η2, f0_2] (one lobe: η2 = 0) over `sg_fit_data`'s samples: without
        `coef`, the (C, 15) normal-equation sums [Σwd², Σwdb1, Σwdb2, Σwb1², Σwb1b2, Σwb2², Σwd·t (3), Σwb1·t (3),
        Σwb2·t (3)]; with `coef` (C, 9) [kd RGB, ks1 RGB, ks2 RGB], the (C,) weighted squared residuals
        (kernels/sgfit.py says what they are). float64, each the sum of float32 partial sums over SGFIT_CHUNK
        samples."""
        cand = np.ascontiguousarray(candidates, np.float32)
        if cand.ndim != 2 or cand.shape[1] != 4:
            raise ValueError(f"sg_fit_sums: candidates must be (C, 4) [η1, f0_1, η2, f0_2], got shape {cand.shape}")
        c, n = len(cand), int(data["n"])
        chunks = max(1, -(-n // self.SGFIT_CHUNK))
        args = (data, self._to_device(cand, "f32"), n, self.SGFIT_CHUNK, c, chunks)
        if coef is None:
            out = self._new((c, chunks, 15), "f32")
            if c and n:
                self._launch_sgfit_gram(*args, out)
            return self._to_host(out, (c, chunks, 15), "f32").astype(np.float64).sum(1)
        coef = np.ascontiguousarray(coef, np.float32)
        if coef.shape != (c, 9):
            raise ValueError(f"sg_fit_sums: coef must be ({c}, 9) [kd, ks1, ks2 RGB], got shape {coef.shape}")
        out = self._new((c, chunks), "f32")
        if c and n:
            self._launch_sgfit_residual(*args, self._to_device(coef, "f32"), out)
        return self._to_host(out, (c, chunks), "f32").astype(np.float64).sum(1)

    def _launch_sgfit_gram(self, data, candidates, n, chunk, n_candidates, n_chunks, out):
        raise NotImplementedError

    def _launch_sgfit_residual(self, data, candidates, n, chunk, n_candidates, n_chunks, coef, out):
        raise NotImplementedError

    def asg_value_sums(self, facets, weight, asgs: ASG, to_host=True):
        """(J,) float64 Σ_s w_s G_j(n_s) over the facets, `weight` (Ns,) w_s (a host array, or visible_weights'
        OnDevice for these very facets: its device copy, no upload, its length not checked), for an ASG batch
        (J,) (the ASG bake's calibration sums, asg_bake.calibrated_rows; float32 terms, float64 sums).
        to_host=False: an OnDevice whose host() waits for these sums alone (their copy is queued with them), so
        the host goes on meanwhile."""
        n = len(facets)
        if not isinstance(weight, OnDevice):
            weight = np.asarray(weight, np.float32).reshape(-1)
            if weight.shape != (n,):
                raise ValueError(f"asg_value_sums: weight must have {n} entries (one a facet), got {weight.shape}")
        rows = self._asg_rows(asgs, asgs.shape).reshape(-1, 12)
        if n == 0 or len(rows) == 0:
            zeros = np.zeros(len(rows))
            return zeros if to_host else OnDevice(None, lambda: zeros)
        f = self._facets(facets)
        # Whole 32-facet words a chunk, as many chunks as the moment sums' one output would get.
        chunks, words = chunking(-(-n // 32), 1, self._threads)
        per = 32 * words
        chunks = -(-n // per)
        partial = self._new((chunks, len(rows)), "f64")
        # (the rows by the upload cache: the moment sums that follow, one call a channel, find them there instead of
        # uploading them again, an upload that would wait for the kernels queued before it)
        self._launch_asg_value_sums(f, self._facet_weight(f, weight), self._recurring(rows, "f32"), len(rows), n, per,
                                    chunks, partial)
        read = self._queued_read(partial, (chunks, len(rows)), "f64")
        return read().sum(0) if to_host else OnDevice(partial, lambda: read().sum(0))

    def _launch_asg_value_sums(self, f, weight, rows, n_rows, n, per, chunks, partial):
        """(chunks, J) float64 partial sums of asg_value_sums into `partial`, chunk c over facets
        [c·per, (c + 1)·per)."""
        raise NotImplementedError

    def asg_em(self, bin_normal, bin_weight, start: ASG, alpha, iterations: int, bandwidth_range, converged: float):
        """asg_bake.fit_asg's EM on the device (stage `asgfit`: kernels/asgfit.py, cl/asgfit.cl) over the normal
        bins (L, 3) weighing (L,), from the ASG batch `start` (J,) with weights `alpha` (J,): at most
        `iterations` steps, every one queued at once, stopping after the first whose lobes and weights all
        moved less than `converged`; bandwidths within `bandwidth_range` (lo, hi). → (ASG batch (J,), alpha (J,)
        float64, steps taken), dead lobes (alpha 0) included."""
        normal = np.asarray(bin_normal, np.float64).reshape(-1, 3)
        normal = normal / np.linalg.norm(normal, axis=1, keepdims=True)
        weight = np.asarray(bin_weight, np.float64).reshape(-1)
        alpha = np.asarray(alpha, np.float64).reshape(-1)
        n_bins, j = len(normal), len(alpha)
        if weight.shape != (n_bins,) or start.lam.shape != (j,):
            raise ValueError(f"asg_em: {n_bins} bin normals, {len(weight)} weights, {start.lam.size} lobes and "
                             f"{j} lobe weights do not match")
        if int(iterations) <= 0 or n_bins == 0 or j == 0:
            return start, alpha, 0
        rows = np.concatenate([start.x, start.y, start.z, start.lam[:, None], start.mu[:, None],
                               np.log(unit_integral(start.lam, start.mu))[:, None]], axis=1)
        log_range = (float(np.log(bandwidth_range[0])), float(np.log(bandwidth_range[1])))
        # The bins padded to a power of two (at least 256) that weigh 0 and so add exact zeros: a backend keeps one
        # program (buffers and launches) per padded size, J and step cap, reused by the next bake.
        size = max(256, 1 << (n_bins - 1).bit_length())
        padded_normal = np.zeros((size, 3))
        padded_normal[:, 2] = 1.0
        padded_normal[:n_bins] = normal
        padded_weight = np.zeros(size)
        padded_weight[:n_bins] = weight
        rows, alpha, steps = self._run_asg_em(padded_normal, padded_weight, rows, alpha, int(iterations), DEAD_MASS,
                                              log_range, float(converged))
        rows = np.asarray(rows, np.float64).reshape(j, 12)
        return ASG(rows[:, 0:3], rows[:, 3:6], rows[:, 6:9], rows[:, 9], rows[:, 10], 1.0), alpha, steps

    def _run_asg_em(self, normal, weight, rows, alpha, iterations, dead_mass, log_range, converged) -> tuple:
        """asg_em's steps on the device from host float64 bins (L, 3), weights (L,) (L a power of two, the padding
        bins weighing 0), lobe rows (J, 12) [x, y, z, λ, μ, log ∫G] and weights (J,): each step kernels/asgfit.py's
        asg_em_responsibilities (L threads), asg_em_m_step (J) and asg_em_finish (1), all queued before the reads.
        → (rows (J, 12), alpha (J,), steps) on the host."""
        raise NotImplementedError

    # --- ASG operators (stage `asg`, Xu 2013; oracle warp_biscale.asg, docs/design.md §9) ---
    # Each runs one device function of kernels/asg.py / cl/asg.cl over a batch, one thread a row: the
    # functions the ASG bake and shading will call, exercised here against their float64 oracle. ASGs travel
    # as (N, 12) float32 rows [x, y, z, λ, μ, c]; results come back as asg.ASG (float64 copies of the rows).
    ASG_INTEGRAL_METHODS = ("exact", "eq10", "eq11")  # asg_integral_values' method codes 0, 1, 2

    @staticmethod
    def _asg_rows(g: ASG, shape) -> np.ndarray:
        """(N, 12) float32 rows of ASG batch `g` broadcast to `shape` (N = its size)."""
        parts = [np.broadcast_to(getattr(g, k), shape + (3,)).reshape(-1, 3) for k in ("x", "y", "z")]
        parts += [np.broadcast_to(getattr(g, k), shape).reshape(-1, 1) for k in ("lam", "mu", "amplitude")]
        return np.ascontiguousarray(np.concatenate(parts, axis=1), np.float32)

    @staticmethod
    def _asg_of_rows(rows, shape) -> ASG:
        rows = np.asarray(rows, np.float64).reshape(shape + (12,))
        return ASG(rows[..., 0:3], rows[..., 3:6], rows[..., 6:9], rows[..., 9], rows[..., 10], rows[..., 11])

    def _asg_scalars(self, name, n, inputs) -> np.ndarray:
        out = self._new(n, "f32")
        if n:
            self._launch_asg(name, n, inputs, out)
        return self._to_host(out, n, "f32")

    def _asg_batch(self, name, shape, inputs) -> ASG:
        n = int(np.prod(shape, dtype=np.int64))
        out = self._new((n, 12), "f32")
        if n:
            self._launch_asg(name, n, inputs, out)
        return self._asg_of_rows(self._to_host(out, (n, 12), "f32"), shape)

    def bessel_i0e(self, x) -> np.ndarray:
        """float32 e^{−|x|}I0(x) (oracle scipy.special.i0e) of the kernels' Cephes expansions, at any shape."""
        x = np.asarray(x, np.float32)
        if not np.all(np.isfinite(x)):
            raise ValueError("bessel_i0e: x must be finite")
        return self._asg_scalars("bessel_i0e_values", x.size, [self._to_device(x.reshape(-1), "f32")]).reshape(
            x.shape)

    def asg_evaluate(self, g: ASG, v) -> np.ndarray:
        """float32 G(v) (oracle asg.evaluate); directions v (..., 3) broadcast with the batch."""
        v = np.asarray(v, np.float32)
        if v.ndim == 0 or v.shape[-1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"asg_evaluate: v must be finite directions (..., 3), got shape {v.shape}")
        shape = np.broadcast_shapes(g.shape, v.shape[:-1])
        v = np.broadcast_to(v, shape + (3,)).reshape(-1, 3)
        return self._asg_scalars("asg_evaluate_rows", len(v), [self._to_device(self._asg_rows(g, shape), "f32"),
                                                               self._to_device(v, "vec3")]).reshape(shape)

    def asg_unit_integral(self, lam, mu, method: str = "exact") -> np.ndarray:
        """float32 ∫ max(v·z, 0)·exp(−λ(v·x)² − μ(v·y)²) dv (oracle asg.unit_integral): "exact" (the 1-D form
        by a 56-node rule, float32-exact for λ, μ ≤ 1e6), "eq10" (Xu Eq. 10) or "eq11" (π/√(λμ))."""
        if method not in self.ASG_INTEGRAL_METHODS:
            raise ValueError(f"asg_unit_integral: method must be one of {self.ASG_INTEGRAL_METHODS} (got {method!r})")
        lam, mu = np.broadcast_arrays(np.asarray(lam, np.float32), np.asarray(mu, np.float32))
        if np.any(~np.isfinite(lam) | ~np.isfinite(mu) | (lam < 0) | (mu < 0)):
            raise ValueError("asg_unit_integral: bandwidths must be finite and >= 0")
        inputs = [self._to_device(lam.reshape(-1), "f32"), self._to_device(mu.reshape(-1), "f32"),
                  self.ASG_INTEGRAL_METHODS.index(method)]
        return self._asg_scalars("asg_integral_values", lam.size, inputs).reshape(lam.shape)

    def asg_convolve_sg(self, g: ASG, sharpness, amplitude=1.0) -> ASG:
        """Xu Eq. 18 with our SG a·exp(η(v·p − 1)), ν = η/2 (oracle asg.convolve_sg)."""
        eta = np.asarray(sharpness, np.float32)
        if np.any(~(eta >= 0)) or not np.all(np.isfinite(eta)):
            raise ValueError("asg_convolve_sg: sharpness must be finite and >= 0")
        shape = np.broadcast_shapes(g.shape, eta.shape, np.shape(amplitude))
        flat = lambda a: self._to_device(np.broadcast_to(np.asarray(a, np.float32), shape).reshape(-1), "f32")  # noqa: E731
        return self._asg_batch("asg_convolve_rows", shape,
                               [self._to_device(self._asg_rows(g, shape), "f32"), flat(eta), flat(amplitude)])

    def asg_convolve_asg(self, g: ASG, lam_s, mu_s, order=(0.0, 0.0)) -> ASG:
        """G convolved with an anisotropic small-scale NDF (oracle asg.convolve_asg)."""
        lam_s, mu_s = np.asarray(lam_s, np.float32), np.asarray(mu_s, np.float32)
        order = np.asarray(order, np.float32)
        if (np.any(~(lam_s > 0)) or np.any(~(mu_s > 0)) or not np.all(np.isfinite(lam_s) & np.isfinite(mu_s))
                or order.shape[-1:] != (2,) or not np.all(np.isfinite(order))):
            raise ValueError("asg_convolve_asg: the kernel's bandwidths must be finite and > 0, order (..., 2) finite")
        shape = np.broadcast_shapes(g.shape, lam_s.shape, mu_s.shape, order.shape[:-1])
        kernel = np.stack([np.broadcast_to(lam_s, shape), np.broadcast_to(mu_s, shape),
                           np.broadcast_to(order[..., 0], shape), np.broadcast_to(order[..., 1], shape)], -1)
        return self._asg_batch("asg_convolve_asg_rows", shape,
                               [self._to_device(self._asg_rows(g, shape), "f32"),
                                self._to_device(np.ascontiguousarray(kernel.reshape(-1, 4), np.float32), "f32")])

    def asg_product(self, g1: ASG, g2: ASG) -> ASG:
        """Xu Eq. 13, G1·G2 as one ASG (oracle asg.product; float64 on the device)."""
        shape = np.broadcast_shapes(g1.shape, g2.shape)
        return self._asg_batch("asg_product_rows", shape, [self._to_device(self._asg_rows(g1, shape), "f32"),
                                                           self._to_device(self._asg_rows(g2, shape), "f32")])

    def asg_warp(self, g: ASG, wo) -> ASG:
        """Xu Eq. 23–26: the NDF lobe g as an ASG in the light direction for views wo (..., 3), broadcast
        with the batch (oracle asg.warp)."""
        wo = np.asarray(wo, np.float32)
        if wo.ndim == 0 or wo.shape[-1] != 3 or not np.all(np.isfinite(wo)):
            raise ValueError(f"asg_warp: wo must be finite directions (..., 3), got shape {wo.shape}")
        shape = np.broadcast_shapes(g.shape, wo.shape[:-1])
        wo = np.broadcast_to(wo, shape + (3,)).reshape(-1, 3)
        return self._asg_batch("asg_warp_rows", shape, [self._to_device(self._asg_rows(g, shape), "f32"),
                                                        self._to_device(wo, "vec3")])

    def asg_from_sg(self, axis, sharpness, amplitude=1.0) -> ASG:
        """Xu Eq. 3: our SG a·exp(η(v·ξ − 1)) as the isotropic ASG λ = μ = η/2 (oracle asg.from_sg)."""
        axis = np.asarray(axis, np.float32)
        eta = np.asarray(sharpness, np.float32)
        if axis.ndim == 0 or axis.shape[-1] != 3 or np.any(~(eta >= 0)) or not np.all(np.isfinite(eta)):
            raise ValueError("asg_from_sg: axis must be (..., 3) and sharpness finite and >= 0")
        shape = np.broadcast_shapes(axis.shape[:-1], eta.shape, np.shape(amplitude))
        flat = lambda a: self._to_device(np.broadcast_to(np.asarray(a, np.float32), shape).reshape(-1), "f32")  # noqa: E731
        return self._asg_batch("asg_from_sg_rows", shape,
                               [self._to_device(np.broadcast_to(axis, shape + (3,)).reshape(-1, 3), "vec3"),
                                flat(eta), flat(amplitude)])

    def asg_effective_sharpness(self, g: ASG) -> np.ndarray:
        """float32 2√(λμ), the SSDF visibility's SG sharpness for an ASG (oracle asg.effective_sharpness)."""
        return self._asg_scalars("asg_sharpness_rows", int(np.prod(g.shape, dtype=np.int64)),
                                 [self._to_device(self._asg_rows(g, g.shape), "f32")]).reshape(g.shape)

    def _launch_asg(self, kernel: str, n: int, inputs: list, out):
        """Kernel `kernel` of the asg stage over n rows: `inputs` device arrays and Python ints, then `out`."""
        raise NotImplementedError
