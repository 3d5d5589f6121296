"""The OpenCL backend: kernels in ``warp_biscale.cl``, on any OpenCL device (PoCL on the CPU, a
vendor's GPU driver).

Each stage mirrors ``WarpBackend`` method by method and returns the same data model. The kernels
are the Warp kernels' twins (same mathematics, same thread decomposition, float32 with float64
facet search); the BVH that Warp gets from ``wp.Mesh`` is built on the host
(``warp_biscale.bvh``) and walked by ``cl/visibility.cl``.

Device memory layout: no ``float3`` in buffers (its 16-byte alignment differs between host and
device); every (N, 3) array travels as a contiguous float32 array of stride 3, which the kernels
read and write with the ``load3``/``store3`` helpers of ``cl/common.cl``. Programs are built once
per device (cached by stem) with explicit options:
``-cl-std=CL1.2``, plus ``-cl-fp32-correctly-rounded-divide-sqrt`` where the device supports it
(PoCL does), so that float32 ``/`` and ``sqrt`` round as on the host and in Warp's CPU kernels.
The facet search and the truth sums need ``cl_khr_fp64``; a device without it is refused at
construction. Launches use a fixed work-group size along dimension 0 (8 on a CPU, 64 on a GPU)
with the global size rounded up to it, since PoCL compiles a kernel once per work-group size.

The SG bake stages (``cl/bvndf.cl``, ``cl/em.cl``, ``cl/amplitudes.cl``) reduce without atomics
as their Warp twins do (float64 across words, chunks and bins). The lobe table G_j(n) has rows of
8⌈J/8⌉ floats, zero past J, read as float8 (PoCL turns them into AVX2 vector adds), so the moment
and solve kernels take at most 16 lobes, their private arrays' size.

Selection: ``OpenCLBackend(None)`` takes the first device, GPUs before other kinds;
``OpenCLBackend("sub")`` the first device whose platform or device name contains "sub"
(case-insensitive); a trailing ``#N`` picks the N-th such device (0-based), which ``name`` uses
only to tell apart devices of the same name.
"""

from __future__ import annotations

import re
import weakref
from importlib import resources

import numpy as np

from . import cl as cl_sources
from . import sg
from .asg import ASG
from .device import (ASG_EM_BLOCK, KINDS, PROBE_VALUES, SCRATCH_BYTES, SHADE_MAX_REGISTERS, DeviceBackend,
                     DeviceStart, UploadCache, check_kernel_lobes, chunking, device_copy, one_line, padded_lobe_values,
                     probe_mismatch, start_scale)
from .bvh import build_bvh
from .environment import SUPPORT, equirect_tables
from .lobes import KERNEL_LOBES, START_RES
from .progress import compile_notice
from .smallscale import ray_offset
from .trace import DISK_RADII, LOBE_RAYS

__all__ = ["OpenCLBackend", "list_devices"]


# One context, queue and program cache per device, shared by every backend object on it, so that
# buffers cached on data-model objects under the backend's name stay valid for all of them.
_DEVICE_STATE: dict = {}
_PROBES: dict = {}  # device int_ptr → None (usable) or why not, in one line


def _pyopencl():
    # pyopencl is imported when OpenCL is first asked for, so that a broken or missing install shows as
    # an unusable backend in `backends()` instead of failing `import warp_biscale`.
    try:
        import pyopencl
        import pyopencl.cltypes  # noqa: F401  (the vector types some kernels take by value)
    except ImportError as exc:
        raise RuntimeError(
            f"the OpenCL backend needs pyopencl ({exc}); install it with `pip install \"pyopencl[pocl]\"`"
        ) from None
    return pyopencl


def _ordered_devices():
    """Every OpenCL device as (platform, device), GPUs first, then the others, in platform order.
    Raises RuntimeError with an explanation if pyopencl or every OpenCL platform is missing."""
    cl = _pyopencl()
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # PLATFORM_NOT_FOUND_KHR with no ICD installed
        raise RuntimeError(
            "no OpenCL platform found (pyopencl: "
            f"{exc}). Install an OpenCL driver, e.g. the CPU one with `pip install \"pyopencl[pocl]\"`, "
            "or a GPU vendor's ICD"
        ) from None
    found = []
    for p in platforms:
        try:
            found.extend((p, d) for d in p.get_devices())
        except cl.Error:  # a platform with no devices raises DEVICE_NOT_FOUND
            continue
    if not found:
        raise RuntimeError("OpenCL platforms exist but hold no device")
    gpus = [pd for pd in found if pd[1].type & cl.device_type.GPU]
    return gpus + [pd for pd in found if not pd[1].type & cl.device_type.GPU]


DEVICE_TYPES = ("cpu", "gpu")  # selectors that pick by the device's type, as backends() lists it


def _matches(selector: str, platform, device) -> bool:
    sel = selector.lower()
    return any(sel in text.strip().lower() for text in (device.name, platform.name, platform.vendor))


def _first_usable(devices, what: str):
    reasons = []
    for p, d in devices:
        reason = probe(p, d)
        if reason is None:
            return p, d
        reasons.append(f"{_name(p, d, devices)}: {reason}")
    raise ValueError(f"no usable OpenCL {what}: " + "; ".join(reasons))


def _listing(devices) -> str:
    return "; ".join(f"{_name(p, d, devices)} ({d.name.strip()} on {p.name.strip()})" for p, d in devices)


def _select(selector, devices):
    """→ (platform, device) for a selector: None takes the first usable device; 'cpu' or 'gpu' the first
    usable device of that type; 'substring' the first usable device whose name, platform or vendor holds it;
    'cpu#N' or 'substring#N' the match at index N (from 0). A selector whose devices are all unusable is a
    ValueError saying why."""
    if selector is None or not selector.strip():
        return _first_usable(devices, "device")
    sel, index = selector.strip(), None
    m = re.fullmatch(r"(.*?)#(\d+)", sel)
    if m and m.group(1).strip():
        sel, index = m.group(1).strip(), int(m.group(2))
    if sel.lower() in DEVICE_TYPES:
        kind = getattr(_pyopencl().device_type, sel.upper())
        hits, what = [pd for pd in devices if pd[1].type & kind], f"{sel.upper()} device"
    else:
        hits, what = [pd for pd in devices if _matches(sel, *pd)], f"device matching {sel!r}"
    if index is None and hits:
        if len(hits) == 1:  # (its own name: the reason alone)
            index = 0
        else:
            return _first_usable(hits, what)
    if index is not None and index < len(hits):
        p, d = hits[index]
        reason = probe(p, d)
        if reason is not None:
            raise ValueError(f"OpenCL device {_name(p, d, devices)!r} is unusable: {reason}")
        return p, d
    if sel.lower() in DEVICE_TYPES and index is None:
        raise ValueError(f"no OpenCL {what} here; available: {_listing(devices)}")
    raise ValueError(f"no OpenCL device matches {selector!r}; available: {_listing(devices)}")


def _name(platform, device, devices) -> str:
    """The selection name that resolves back to this device."""
    base = device.name.strip()
    hits = [pd for pd in devices if _matches(base, *pd)]
    index = next(i for i, pd in enumerate(hits) if pd[1] == device)
    return f"opencl:{base}" + (f"#{index}" if index else "")


def _version(platform) -> str:
    """The platform's version up to its build details, e.g. "OpenCL 3.0 PoCL 3.0-rc2 Linux"."""
    return " ".join(platform.version.split(",")[0].split())


def _description(platform, device) -> str:
    """The device in words, with its platform's version (two PoCLs side by side differ only there)."""
    return f"{device.name.strip()} ({platform.name.strip()}, {_version(platform)})"


def list_devices() -> list[dict]:
    """Every OpenCL device as a backends() entry {name, kind, device, type, usable, reason}, each
    probed; with no OpenCL platform at all, one unusable entry "opencl" that says why. Never raises."""
    try:
        devices = _ordered_devices()
    except Exception as exc:
        return [{"name": "opencl", "kind": "opencl", "device": None, "type": None, "usable": False,
                 "reason": one_line(exc)}]
    cl = _pyopencl()
    found = []
    for p, d in devices:
        reason = probe(p, d)
        found.append({"name": _name(p, d, devices), "kind": "opencl", "device": _description(p, d),
                      "type": "gpu" if d.type & cl.device_type.GPU else "cpu", "usable": reason is None,
                      "reason": reason or ""})
    return found


def _device_state(device):
    cl = _pyopencl()
    state = _DEVICE_STATE.get(device.int_ptr)
    if state is None:
        ctx = cl.Context([device])
        state = {"ctx": ctx, "queue": cl.CommandQueue(ctx, device), "programs": {}, "kernels": {}}
        _DEVICE_STATE[device.int_ptr] = state
    return state


def build_options(device) -> list[str]:
    """The options every program is built with on `device` (the module docstring says why)."""
    cl = _pyopencl()
    options = ["-cl-std=CL1.2"]
    if device.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT:
        options.append("-cl-fp32-correctly-rounded-divide-sqrt")
    return options


# Stages built with fast math, as their Warp modules are (wp.set_module_options fast_math): shading
# bound by its arithmetic, whose float32 results are read against a float64 oracle with tolerances far
# above fast math's ~1e-5 relative error. (It assumes finite values: their output guard tests bits.)
FAST_MATH = {"litsphere", "shade"}
QUEUED_UPLOAD_BYTES = 1 << 20  # shade inputs this large are copied to a GPU without blocking (_shade_buffer)


def stage_options(options: list[str], stem: str, asg_em_group: int = ASG_EM_BLOCK,
                  nvidia_options: bool = False) -> list[str]:
    """`options` (build_options) for cl/<stem>.cl: fast math instead of exact rounding for FAST_MATH; the ASG EM's
    work-group size for asgfit (device.ASG_EM_BLOCK, the one definition both backends read, or less where the
    device's work-groups are smaller); on a device that takes NVIDIA's compiler options (`nvidia_options`), the
    shade kernel's register cap (device.SHADE_MAX_REGISTERS, which the Warp kernel is given too)."""
    if stem == "asgfit":
        options = [*options, f"-DASGFIT_GROUP={int(asg_em_group)}"]
    if stem == "shade" and nvidia_options:
        options = [*options, f"-cl-nv-maxrregcount={SHADE_MAX_REGISTERS}"]
    if stem not in FAST_MATH:
        return options
    return [o for o in options if o != "-cl-fp32-correctly-rounded-divide-sqrt"] + ["-cl-fast-relaxed-math"]


def build_failure(platform, device, log) -> str:
    """Why a program did not build on `device`, in one line, with the fix where one is known."""
    text = str(log)
    if "unknown target CPU" in text:
        return (f"{_version(platform)} is too old for this CPU (its LLVM cannot name it: \"unknown "
                "target CPU\"); install the system PoCL (`apt-get install pocl-opencl-icd` on Debian/Ubuntu), "
                "which warp_biscale then finds with no other step")
    if ("ld" in text.split() or "linker" in text) and "portable computing" in platform.name.lower():
        return ("PoCL links kernels with the system linker, which failed (is `ld` from binutils on PATH?): "
                + one_line(text))
    return f"kernels do not build: {one_line(text)}"


# Stage files whose functions a stage calls, built into its program ahead of it (after common.cl), in order:
# cl/shade.cl calls cl/asg.cl's convolution, warp and integrals (ASG materials), and cl/litsphere.cl calls
# camera_ray and prefiltered of cl/shade.cl, as the kernels/ twins import them.
USES = {"shade": ("asg",), "litsphere": ("asg", "shade"), "amplitudes": ("asg",), "asgfit": ("asg",)}


def program_source(stem: str) -> str:
    """common.cl, the stage files `stem` uses (USES), then cl/<stem>.cl."""
    if stem not in USES:
        return cl_sources.source(stem)
    files = resources.files(cl_sources)
    stems = (*USES[stem][1:], stem)
    return cl_sources.source(USES[stem][0]) + "".join("\n" + files.joinpath(f"{s}.cl").read_text() for s in stems)


def build_program(ctx, stem: str, options):
    """Build cl/<stem>.cl (with common.cl and program_source's others) in `ctx`; raises pyopencl's
    error with the build log."""

    cl = _pyopencl()
    with compile_notice():
        return cl.Program(ctx, program_source(stem)).build(options=options)


def probe(platform, device) -> str | None:
    """None if `device` builds cl/probe.cl (with the shared helpers of common.cl, under the options of
    every build) and runs it right, else why not, in one line. Once per device and process."""
    key = device.int_ptr
    if key not in _PROBES:
        _PROBES[key] = _run_probe(platform, device)
    return _PROBES[key]


def _run_probe(platform, device) -> str | None:
    cl = _pyopencl()
    if not device.double_fp_config and "cl_khr_fp64" not in device.extensions:
        return ("no double precision (cl_khr_fp64), which facet sampling needs (a float64 cumulative-area "
                "search): choose another device")
    try:
        state = _device_state(device)
    except Exception as exc:
        return f"cannot open the device: {one_line(exc)}"
    try:
        program = build_program(state["ctx"], "probe", build_options(device))
    except Exception as exc:
        return build_failure(platform, device, exc)
    try:
        mf = cl.mem_flags
        values = cl.Buffer(state["ctx"], mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=PROBE_VALUES)
        out = np.zeros_like(PROBE_VALUES)
        out_buf = cl.Buffer(state["ctx"], mf.WRITE_ONLY, size=out.nbytes)
        program.probe(state["queue"], (len(out),), None, values, out_buf, np.int32(len(out)))
        cl.enqueue_copy(state["queue"], out, out_buf)
    except Exception as exc:
        return f"the probe kernel built but did not run: {one_line(exc)}"
    return probe_mismatch(out)


class OpenCLBackend(DeviceBackend):
    """OpenCL on one device. `selector`: None (first device, GPUs first) or a substring of a
    platform or device name (case-insensitive), optionally ending in ``#N`` for the N-th match."""

    def __init__(self, selector: str | None = None):
        cl = _pyopencl()
        devices = _ordered_devices()
        platform, device = _select(selector, devices)
        self._cl = cl
        self._device = device
        self._platform = platform
        self.name = _name(platform, device, devices)
        self.device = f"{device.name.strip()} ({platform.name.strip()})"
        state = _device_state(device)
        self._ctx, self._queue = state["ctx"], state["queue"]
        self._programs, self._kernels = state["programs"], state["kernels"]
        self.build_options = build_options(device)
        self._nvidia_options = "cl_nv_compiler_options" in device.extensions.split()
        # Work-items worth launching per reduction: a few per core on a CPU, enough to fill a GPU.
        is_cpu = bool(device.type & cl.device_type.CPU)
        self.is_gpu = bool(device.type & cl.device_type.GPU)
        self._threads = max(1, device.max_compute_units) * 4 if is_cpu else 1 << 18
        # A fixed work-group size along dimension 0 (the global size is rounded up to it): PoCL
        # compiles a kernel once per work-group size, and would otherwise recompile for every new
        # facet or pair count. Small on a CPU (a group runs on one core), a few warps on a GPU.
        self._group = max(1, min(8 if is_cpu else 64, device.max_work_group_size))
        # The ASG EM's M-step: a work-group a lobe, ASG_EM_BLOCK work-items or the largest power of two the device
        # takes (cl/asgfit.cl's group sums halve it).
        self._asg_em_group = min(ASG_EM_BLOCK, 1 << (max(1, device.max_work_group_size).bit_length() - 1))
        self._tiles = weakref.WeakKeyDictionary()
        self._uploads = UploadCache()
        self._held_visible_area = None  # (host, device) of the last visible_area
        self._scratch_buffers = {}  # role → device buffer, see _scratch
        self._queued_uploads = {}  # role → the event of its last queued upload, see _shade_buffer
        self._em_programs = {}  # (Ns, J, steps, weighted) → an EM's buffers and launches: see _em_program
        self._em_buffers = {}
        self._asg_em_programs = {}  # (padded bins, J, steps, constants, group) → an ASG EM's buffers and launches

    def __repr__(self):
        return f"OpenCLBackend({self.name!r})"

    def synchronize(self):
        self._queue.finish()

    # ------------------------------------------------------------------ programs
    def _kernel(self, stem: str, name: str):
        key = (stem, name)
        kernel = self._kernels.get(key)
        if kernel is None:
            program = self._programs.get(stem)
            if program is None:
                program = self._build(stem)
                self._programs[stem] = program
            kernel = self._cl.Kernel(program, name)
            self._kernels[key] = kernel
        return kernel

    def _build(self, stem: str):
        try:
            return build_program(self._ctx, stem, stage_options(self.build_options, stem, self._asg_em_group,
                                                                  self._nvidia_options))
        except self._cl.Error as exc:
            raise RuntimeError(f"building cl/{stem}.cl for {self.device} failed: "
                               f"{build_failure(self._platform, self._device, exc)}\n{exc}") from None

    def _prepared(self, stem, name, shape, *args, group=None):
        """A callable that enqueues kernel `name` over `shape` (as _launch) with `args` set once: for a
        loop that enqueues the same launch many times (on NVIDIA's OpenCL setting the arguments at every
        launch cost the EM about half again its time). `group`: a work-group size other than the backend's."""
        cl = self._cl
        self._kernel(stem, name)  # builds the program once
        kernel = cl.Kernel(self._programs[stem], name)  # its own instance: its arguments stay set
        kernel.set_args(*args)
        g = group or self._group
        global_size = (-(-shape[0] // g) * g, *shape[1:])
        local_size = (g,) + (1,) * (len(shape) - 1)
        # The closure keeps `args` alive: a set argument holds no reference to its buffer.
        return lambda held=args: cl.enqueue_nd_range_kernel(self._queue, kernel, global_size, local_size)

    def _launch(self, stem, name, shape, *args):
        """Run kernel `name` over `shape` work-items, dimension 0 rounded up to whole work-groups
        (the kernels return early past their real size)."""
        g = self._group
        global_size = (-(-shape[0] // g) * g, *shape[1:])
        local_size = (g,) + (1,) * (len(shape) - 1)
        self._kernel(stem, name)(self._queue, global_size, local_size, *args)

    # ------------------------------------------------------------------ device copies
    def _buffer(self, array, dtype):
        """A read-only device copy of a host array (a one-element dummy for an empty one)."""
        cl = self._cl
        host = np.ascontiguousarray(array, dtype=dtype)
        if host.size == 0:
            host = np.zeros(1, dtype)
        return cl.Buffer(self._ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=host)

    def _shade_buffer(self, role, array, dtype):
        """A read-only device copy of shade input `role`: on a GPU, for a large array, a buffer whose copy is
        queued without blocking (faster than a COPY_HOST_PTR buffer on NVIDIA's OpenCL: bench/README.md), its
        event kept until the role's next upload, so that the host array the event holds stays alive until
        copied; else `_buffer`'s."""
        host = np.ascontiguousarray(array, dtype=dtype)
        if not self.is_gpu or host.nbytes < QUEUED_UPLOAD_BYTES:
            return self._buffer(host, dtype)
        buf = self._cl.Buffer(self._ctx, self._cl.mem_flags.READ_ONLY, size=host.nbytes)
        self._queued_uploads[role] = self._cl.enqueue_copy(self._queue, buf, host, is_blocking=False)
        return buf

    def _empty(self, n_items, dtype):
        return self._cl.Buffer(self._ctx, self._cl.mem_flags.READ_WRITE,
                               size=max(1, int(n_items)) * np.dtype(dtype).itemsize)

    def _scratch(self, role, n_items, dtype):
        """A device buffer that no caller keeps (a kernel's intermediate), reused from call to call while
        it is large enough. Why: a buffer released while queued kernels still use it made NVIDIA's
        OpenCL wait for them (the visibility call returned only when the rays were done, its ray buffer
        released at the call's end), so intermediates outlive their call. The
        in-order queue keeps reuse safe. Buffers over SCRATCH_BYTES are not kept."""
        nbytes = max(1, int(n_items)) * np.dtype(dtype).itemsize
        held = self._scratch_buffers.get(role)
        if held is not None and held.size >= nbytes:
            return held
        if nbytes > SCRATCH_BYTES:
            self._scratch_buffers.pop(role, None)
            return self._empty(n_items, dtype)
        buf = self._scratch_buffers[role] = self._empty(n_items, dtype)
        return buf

    def _read_later(self, buf, shape, dtype):
        """→ a function returning a host copy of `buf` as it is now: the copy is queued at once (not
        blocking), so the function waits for `buf`'s work alone, not for what is queued after it."""
        out = np.empty(shape, dtype)
        copied = self._cl.enqueue_copy(self._queue, out, buf, is_blocking=False) if out.size else None
        return lambda: (copied and copied.wait(), out)[1]

    def _queued_read(self, array, shape, kind):
        return self._read_later(array, self._host_shape(shape, kind), KINDS[kind][0])

    def _read(self, buf, shape, dtype, out=None):
        out = np.empty(shape, dtype) if out is None else out.reshape(shape)
        if out.size:
            self._cl.enqueue_copy(self._queue, out, buf)
        return out

    def _tile(self, tile, need_bvh=False):
        entry = self._tiles.get(tile)
        if entry is None:
            vn = tile.vertex_normals if tile.vertex_normals is not None else np.zeros((1, 3))
            areas = tile.face_areas
            entry = {
                "points": self._buffer(tile.to_local(tile.vertices), np.float32),
                "faces": self._buffer(tile.faces, np.int32),
                "vertex_normals": self._buffer(vn, np.float32),
                "face_normals": self._buffer(tile.face_normals, np.float32),
                "cumulative_area": self._buffer(np.cumsum(areas), np.float64),
                "face_area": self._buffer(areas, np.float64),
            }
            self._tiles[tile] = entry
        if need_bvh and "nodes" not in entry:

            local = tile.to_local(tile.vertices).astype(np.float64)
            bvh = build_bvh(local, tile.faces)
            entry["bvh"] = bvh
            entry["nodes"] = self._buffer(bvh.packed(), np.float32)
            entry["tris"] = self._buffer(bvh.triangle_table(local, tile.faces), np.float32)
        return entry

    # ------------------------------------------------------------------ stages
    def _launch_sample_facets(self, tile, count, xi1, xi2, pos, nrm, face):
        t = self._tile(tile)
        self._launch("facets", "sample_facets", (count,),
                     t["points"], t["faces"], t["vertex_normals"], np.int32(tile.vertex_normals is not None),
                     t["face_normals"], t["cumulative_area"], t["face_area"], np.int32(len(tile.faces)),
                     np.int32(count), np.float64(xi1), np.float32(xi2), pos, nrm, face)

    def _launch_facet_weights(self, face, per_face, area, count, weight):
        self._launch("facets", "facet_weights", (count,), face, per_face, area, np.int32(count), weight)

    def _launch_visibility(self, tile, facets, dirs, n_dirs, words, brute_force, bits):
        t = self._tile(tile, need_bvh=True)
        position = self._facet_positions(facets, tile)
        f = self._facets(facets)
        n = len(facets)
        z_lo, z_hi = tile.z_range
        visible = self._scratch("visible", n_dirs * n, np.uint8)  # (packed into bits at once)
        # (Work-groups of 32, like the Warp twin's blocks, were no faster on NVIDIA's OpenCL than the
        # device's 64.)
        self._launch("visibility", "visibility_rays", (n, n_dirs),
                     t["nodes"], t["tris"], np.int32(len(tile.faces)), t["face_normals"],
                     np.int32(brute_force), position, f["face"], np.int32(n), dirs,
                     np.float32(0.0), np.float32(0.0), np.float32(tile.period[0]),
                     np.float32(tile.period[1]), np.float32(0.0), np.float32(z_hi - z_lo),
                     np.float32(ray_offset(tile)), visible)
        self._launch("visibility", "pack_bits", (words, n_dirs), visible, np.int32(n), np.int32(words), bits)

    def _launch_visible_area(self, f, v, n_words, n_dirs, chunks, per, a_v):
        partial = self._scratch("visible_area_partial", chunks * n_dirs, np.float32)
        self._launch("truth", "visible_area_partial", (n_dirs, chunks),
                     v["directions"], v["bits"], np.int32(n_words), f["normal"], f["area"], np.int32(per),
                     np.int32(n_dirs), partial)
        self._launch("truth", "sum_chunks_area", (n_dirs,), partial, np.int32(chunks), np.int32(n_dirs), a_v)

    def _launch_effective_brdf(self, f, v, kinds, params, pair_i, pair_o, a_v, face, tangent, tables, n_words,
                               n_pairs, chunks, per, out):
        partial = self._empty(chunks * n_pairs * 3, np.float32)
        self._launch("truth", "effective_brdf_partial", (n_pairs, chunks),
                     v["directions"], pair_i, pair_o, v["bits"], np.int32(n_words), f["normal"], f["weight"],
                     f["material"], kinds, params, face, tangent, tables, np.int32(per), np.int32(n_pairs), partial)
        self._launch("truth", "sum_chunks_brdf", (n_pairs,), partial, np.int32(chunks), np.int32(n_pairs), pair_o,
                     a_v, out)

    # --- small-scale interreflection (DeviceBackend.interreflection): one block ---
    def _launch_interreflection(self, tile, f, position, v, kinds, params, pair_i, pair_o, a_v, face_material,
                                face_color, tangent, tables, aniso, n_facets, n_words, paths, chunks, per, bounces,
                                seed, n_pairs, out):
        t = self._tile(tile, need_bvh=True)
        if "tri_index" not in t:
            t["tri_index"] = self._buffer(t["bvh"].tri_index, np.int32)
        z_lo, z_hi = tile.z_range
        partial = self._empty(chunks * n_pairs * 3, np.float32)
        self._launch("truth", "interreflection_partial", (n_pairs, chunks),
                     t["nodes"], t["tris"], t["tri_index"], t["face_normals"], face_material, face_color,
                     v["directions"], pair_i, pair_o, v["bits"], np.int32(n_words), position, f["normal"],
                     f["weight"], f["material"], f["face"], kinds, params, tangent, tables, np.int32(aniso),
                     np.int32(n_facets), np.int32(paths), np.int32(per), np.int32(bounces), np.int32(seed),
                     np.float32(0.0), np.float32(0.0), np.float32(tile.period[0]), np.float32(tile.period[1]),
                     np.float32(0.0), np.float32(z_hi - z_lo), np.float32(ray_offset(tile)), np.int32(n_pairs),
                     partial)
        self._launch("truth", "sum_chunks_brdf", (n_pairs,), partial, np.int32(chunks), np.int32(n_pairs), pair_o,
                     a_v, out)

    # ------------------------------------------------------------------ SG bake stages
    def _launch_normal_bins(self, f, n, resolution, bins):
        self._launch("bvndf", "normal_bins", (n,), f["normal"], np.int32(resolution), np.int32(n), bins)

    def _launch_bvndf_histogram(self, v, n_words, pair_i, pair_o, order, bin_start, weight, n_pairs, n_bins, hist):
        self._launch("bvndf", "bvndf_histogram", (n_bins, n_pairs), pair_i, pair_o, v["bits"], np.int32(n_words),
                     order, bin_start, weight, np.int32(n_bins), np.int32(n_pairs), hist)

    def _launch_visible_weights(self, f, v, n_dirs, n_words, n, weight):
        self._launch("em", "visible_weights", (n,), v["directions"], v["bits"], np.int32(n_dirs), np.int32(n_words),
                     f["normal"], f["area"], np.int32(n), weight)

    def em_start(self, facets, facet_weight, count):
        f = self._facets(facets)
        n, j = len(facets), int(count)
        weight = f["area"] if facet_weight is None else self._facet_weight(f, facet_weight)
        scale = start_scale(facets, facet_weight)
        n_bins = 6 * START_RES * START_RES
        sums = self._scratch("start_sums", 4 * n_bins, np.int64)
        self._cl.enqueue_fill_buffer(self._queue, sums, np.int64(0), 0, 32 * n_bins)
        scratch = [self._scratch("start_bins", 4 * n_bins, np.float64), self._scratch("start_dist", n_bins, np.float64),
                   self._scratch("start_owner", n_bins, np.int32), self._scratch("start_chosen", j, np.int32)]
        rows = self._empty(6 * j, np.float64)
        self._launch("em", "start_bin_sums", (n,), f["normal"], weight, np.float64(scale), np.int32(n), sums)
        group = 256  # (START_GROUP of cl/em.cl: one work-group)
        self._kernel("em", "start_pick")(self._queue, (group,), (group,), sums, np.int32(n_bins), np.float64(scale),
                                         np.int32(j), *scratch, rows)
        return DeviceStart(rows, j, lambda: self._read(rows, (j, 6), np.float64))  # (read only if asked)

    def _em_launches(self, normal, mass, n, n_lobes, axes, sharpness, log_weight, state, resp):
        """One E-step's four kernels as prepared launches over `n` facets (`normal`, weighing `mass`,
        scratch `resp` (Ns, J)) → (launches, the (J, 4) float64 statistics buffer)."""
        j = n_lobes
        # Short serial chains for a GPU: chunks of 64 facets, then two sums over ~√chunks chunks each.
        chunks, per = chunking(-(-n // 64), j, self._threads)
        per *= 64
        group = int(np.ceil(np.sqrt(chunks)))
        groups = -(-chunks // group)
        partial, partial2 = self._empty(chunks * j * 4, np.float64), self._empty(groups * j * 4, np.float64)
        out = self._empty(j * 4, np.float64)
        launches = [
            self._prepared("em", "ndf_responsibilities", (n,), normal, mass, axes, sharpness, log_weight,
                           np.int32(j), np.int32(n), state, resp),
            self._prepared("em", "ndf_sums_partial", (j, chunks), normal, resp, np.int32(j), np.int32(n),
                           np.int32(per), state, partial),
            self._prepared("em", "sum_chunks_stats", (j, groups), partial, np.int32(chunks), np.int32(group),
                           np.int32(j), state, partial2),
            self._prepared("em", "sum_chunks_stats", (j, 1), partial2, np.int32(groups), np.int32(groups),
                           np.int32(j), state, out)]
        return launches, out

    def ndf_statistics(self, facets, axes, sharpness, log_weight):
        n, j = len(facets), len(axes)
        if n == 0 or j == 0:
            return np.zeros((j, 4))
        f = self._facets(facets)
        launches, out = self._em_launches(f["normal"], f["area"], n, j, self._buffer(axes, np.float32),
                                          self._buffer(sharpness, np.float32), self._buffer(log_weight, np.float32),
                                          self._buffer(np.zeros(2), np.int32), self._empty(n * j, np.float32))
        for launch in launches:
            launch()
        return self._read(out, (j, 4), np.float64)

    def _em_program(self, n, j, iterations, weighted):
        """The buffers and prepared launches of an EM of one shape (Ns, J, step cap, weighted or not),
        made once and kept (the facets are copied into its buffers): made at every call, they cost a
        one-step ndf_em several times what Warp's captured graph does. → dict: `normal`, `mass`,
        `start` / `result` (J, 6) float64 (em_start_rows / em_result_rows), `state`, and the launches
        `load`, `steps` (one EM step), `unload`."""
        key = (n, j, int(iterations), bool(weighted))
        prog = self._em_programs.pop(key, None)
        if prog is None:
            shared = self._em_buffers
            if shared.get("n") != n or shared["lobes"] < j:
                # The facet buffers, shared by every J up to resp's room (at least KERNEL_LOBES): the
                # programs made over the old ones go with them.

                self._em_programs.clear()
                shared.clear()
                room = max(j, KERNEL_LOBES)
                shared.update(n=n, lobes=room, normal=self._empty(3 * n, np.float32), mass=self._empty(n, np.float32),
                              resp=self._empty(n * room, np.float32))
            prog = {"normal": shared["normal"], "mass": shared["mass"],
                    "state": self._empty(2, np.int32), "moved": self._empty(j, np.int32),
                    "start": self._empty(6 * j, np.float64), "result": self._empty(6 * j, np.float64)}
            lobes32 = [self._empty(m, np.float32) for m in (3 * j, j, j)]
            prog["axes32"], prog["sharp32"] = lobes32[:2]  # (what DeviceLobes hands to lobe_moments)
            lobes64 = [self._empty(m, np.float64) for m in (3 * j, j, j)]
            steps, stats = self._em_launches(prog["normal"], prog["mass"], n, j, *lobes32, prog["state"],
                                             shared["resp"])
            steps += [self._prepared("em", "em_m_step", (j,), stats, np.int32(j), prog["state"], *lobes64, *lobes32,
                                     prog["moved"]),
                      self._prepared("em", "em_finish", (1,), prog["moved"], np.int32(j), np.int32(iterations),
                                     prog["state"])]
            prog["steps"] = steps
            prog["load"] = self._prepared("em", "em_load", (j,), prog["start"], np.int32(j), *lobes64, *lobes32,
                                          prog["state"])
            prog["unload"] = self._prepared("em", "em_result", (j,), *lobes64, prog["state"], np.int32(j),
                                            prog["result"])
        return self._keep_recent(self._em_programs, key, prog)

    def _run_em(self, f, mass, start_rows, n, j, iterations, weighted, meanwhile=None):
        prog = self._em_program(n, j, iterations, weighted)
        cl = self._cl
        cl.enqueue_copy(self._queue, prog["normal"], f["normal"], byte_count=12 * n)
        cl.enqueue_copy(self._queue, prog["mass"], mass, byte_count=4 * n)
        if isinstance(start_rows, np.ndarray):
            cl.enqueue_copy(self._queue, prog["start"], start_rows)
        else:
            cl.enqueue_copy(self._queue, prog["start"], start_rows, byte_count=48 * j)
        if meanwhile is not None:
            # Here, behind the rays and the EM's start: NVIDIA's OpenCL bake was slower with the host's work
            # between the EM's steps and its first look, flushed or not (bench/results/bake-h100).
            meanwhile()
        self._step_em(prog, iterations, lambda: bool(self._read(prog["state"], 2, np.int32)[0]))
        return prog

    def _lobe_values(self, normal_buf, n, axes, sharpness, role="lobe_values"):
        """(n, 8⌈J/8⌉) float32 device table G_j(n_s) of unit-amplitude lobes, zero past J (read as float8);
        `axes` host axes, or a DeviceLobes (sharpness None)."""
        j, axes_buf, sharpness_buf = self._lobes_on_device(axes, sharpness)
        stride = -(-j // 8) * 8
        values = self._scratch(role, n * stride, np.float32)
        if n:
            self._launch("amplitudes", "lobe_values", (n,), normal_buf, axes_buf, sharpness_buf,
                         np.int32(j), np.int32(stride), np.int32(n), values)
        return values

    def lobe_moments(self, facets, vis, weight, axes, sharpness, pair_i, pair_o, to_host=True, lobe_values=None):
        f = self._facets(facets)
        v = self._vis(vis)
        n, n_pairs = len(facets), len(pair_i)
        asgs = lobe_values if isinstance(lobe_values, ASG) else None  # (values made on the device)
        if lobe_values is None:
            j = len(axes)  # (len of a DeviceLobes: its count)
        else:
            j = len(asgs.lam) if asgs is not None else lobe_values.shape[1]
        check_kernel_lobes(j)  # (private per-lobe arrays of cl/amplitudes.cl)
        if n_pairs == 0:
            return np.zeros((0, j + 1), np.float32)
        if lobe_values is None:
            values = self._lobe_values(f["normal"], n, axes, sharpness)
        elif asgs is not None:
            stride = -(-j // 8) * 8
            values = self._scratch("lobe_values", n * stride, np.float32)
            self._launch("amplitudes", "asg_lobe_values", (n,), f["normal"],
                         self._recurring(self._asg_rows(asgs, asgs.shape), "f32"), np.int32(j), np.int32(stride),
                         np.int32(n), values)
        else:
            values = self._buffer(padded_lobe_values(lobe_values, -(-j // 8) * 8), np.float32)
        runs = f.get("area_runs") if weight is None else None  # the area's runs depend on the facets alone
        weight = f["area"] if weight is None else device_copy(
            weight, None, lambda host: self._buffer(np.asarray(host, np.float32), np.float32))
        n_words = vis.words
        if runs is None:
            if weight is f["area"]:  # kept with the facets
                runs = f["area_runs"] = (self._empty(n_words, np.uint32), self._empty(n, np.int32))
            else:
                runs = (self._scratch("runs_bits", n_words, np.uint32), self._scratch("runs_end", n, np.int32))
            self._launch("amplitudes", "facet_runs", (n_words,), f["normal"], weight, np.int32(n), *runs)
        channel_bits, run_end = runs
        chunks, per = chunking(n_words, n_pairs, self._threads)
        shape = chunks * n_pairs * (j + 1)  # (with one chunk the partial sums are the result: not scratch)
        partial = self._scratch("moments_partial", shape, np.float32) if chunks > 1 else self._empty(shape, np.float32)
        self._launch("amplitudes", "lobe_moments_partial", (n_pairs, chunks),
                     v["directions"], self._recurring(pair_i, "i32"), self._recurring(pair_o, "i32"),
                     v["bits"], np.int32(n_words), channel_bits, weight, f["normal"], values, run_end,
                     np.int32(j), np.int32(per),
                     np.int32(n_pairs), partial)
        out = partial
        if chunks > 1:
            out = self._empty(n_pairs * (j + 1), np.float32)
            self._launch("amplitudes", "sum_chunks_moments", (n_pairs,),
                         partial, np.int32(chunks), np.int32(n_pairs), np.int32(j + 1), out)
        return self._read(out, (n_pairs, j + 1), np.float32) if to_host else out

    def _launch_asg_value_sums(self, f, weight, rows, n_rows, n, per, chunks, partial):
        self._launch("amplitudes", "asg_value_sums", (chunks,), f["normal"], weight, rows, np.int32(n_rows),
                     np.int32(n), np.int32(per), np.int32(chunks), partial)

    def histogram_moments(self, hist, bin_normal, directions, axes, sharpness, pair_i, pair_o):
        bin_normal = np.asarray(bin_normal, np.float32)
        n_bins, j, n_pairs = len(bin_normal), len(axes), len(pair_i)
        check_kernel_lobes(j)  # (private per-lobe arrays of cl/amplitudes.cl)
        if n_pairs == 0:
            return np.zeros((0, j + 1), np.float32)
        bn = self._buffer(bin_normal, np.float32)
        bin_values = self._lobe_values(bn, n_bins, axes, sharpness, role="bin_lobe_values")
        out = self._empty(n_pairs * (j + 1), np.float32)
        self._launch("amplitudes", "histogram_moments", (n_pairs,),
                     self._buffer(directions, np.float32), self._buffer(pair_i, np.int32),
                     self._buffer(pair_o, np.int32), self._buffer(hist, np.float32), np.int32(n_bins), bn,
                     bin_values, np.int32(j), np.int32(n_pairs), out)
        return self._read(out, (n_pairs, j + 1), np.float32)

    def solve_amplitudes(self, moments, a_v, rows, integrals, pair_i, pair_o, n_dirs, to_host=True):
        j, n_pairs = len(integrals), len(pair_i)
        check_kernel_lobes(j)  # (private per-lobe arrays of cl/amplitudes.cl)
        if n_pairs == 0:
            return np.zeros((0, j), np.float32)
        mu = self._empty(n_pairs * j, np.float32)
        self._launch("amplitudes", "solve_amplitudes", (n_pairs,),
                     self._recurring(pair_i, "i32"), self._recurring(pair_o, "i32"), np.int32(n_dirs),
                     self._visible_area_device(a_v),
                     moments if isinstance(moments, self._cl.Buffer) else self._buffer(moments, np.float32),
                     self._recurring(rows, "f64"), self._recurring(integrals, "f64"), np.int32(j),
                     np.int32(n_pairs), mu)
        return self._read(mu, (n_pairs, j), np.float32) if to_host else mu

    def _launch_amplitude_tables(self, mu, integ, rgb, accumulate, material, n_pairs, j, amps, energy):
        self._launch("amplitudes", "amplitude_tables", (n_pairs,), mu, integ, *(np.float32(c) for c in rgb),
                     np.int32(accumulate), np.int32(material), np.int32(j), np.int32(n_pairs), amps, energy)

    def _launch_energy_levels(self, energy, weights, n_mat, n_levels, k2, levels):
        self._launch("amplitudes", "energy_levels", (k2 * k2, n_levels, n_mat), energy, weights, np.int32(n_levels),
                     np.int32(k2), levels)

    # ------------------------------------------------------------------ SSDF (stage `ssdf`, warp_biscale.ssdf)
    def _launch_ssdf_distance(self, g, blocks, visible, classes, n_v, n, theta):
        n_blocks, n_members = blocks
        self._launch("ssdf", "ssdf_distance", (n, n_v), visible, g["directions"], g["half_angle"], g["members"],
                     g["axis"], g["cos"], g["sin"], classes, np.int32(n), np.int32(n_v), np.int32(n_blocks),
                     np.int32(n_members), theta)

    # ------------------------------------------------------------------ device primitives (DeviceBackend)
    def _to_device(self, host, kind):
        return self._buffer(host, KINDS[kind][0])

    def _new(self, shape, kind):
        np_dtype, width = KINDS[kind]
        return self._empty(int(np.prod(shape)) * width, np_dtype)

    def _zeros(self, shape, kind):
        np_dtype, width = KINDS[kind]
        buf = self._empty(int(np.prod(shape)) * width, np_dtype)
        self._cl.enqueue_fill_buffer(self._queue, buf, np.zeros(1, np_dtype), 0, buf.size)
        return buf

    def _flat(self, array):
        return array

    def _to_device_mutable(self, host, kind):
        """As `_to_device`, a copy that kernels may also write (a `_to_device` buffer is read-only)."""
        cl = self._cl
        data = np.ascontiguousarray(host, KINDS[kind][0])
        return cl.Buffer(self._ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=data if data.size else np.zeros(1, data.dtype))

    def _asg_em_program(self, n_bins, n_lobes, iterations, dead_mass, log_range, converged) -> dict:
        """The ASG EM's buffers for `n_bins` bins and J lobes and its three launches, prepared once (made at every
        call, the three kernels' arguments cost NVIDIA's OpenCL more host time than its whole EM on the device)."""
        a = {"normal": self._empty(3 * n_bins, np.float64), "weight": self._empty(n_bins, np.float64),
             "lobes": self._empty(12 * n_lobes, np.float64), "alpha": self._empty(n_lobes, np.float64),
             "state": self._empty(2, np.int32), "resp_weight": self._new((n_bins, n_lobes), "f64"),
             "seen_weight": self._new(n_bins, "f64"), "new_lobes": self._new((n_lobes, 12), "f64"),
             "mass": self._new(n_lobes, "f64"), "moved": self._new(n_lobes, "f64")}
        j = np.int32(n_lobes)
        a["steps"] = [
            self._prepared("asgfit", "asg_em_responsibilities", (n_bins,), a["normal"], a["weight"], a["lobes"],
                           a["alpha"], a["state"], j, np.int32(n_bins), a["resp_weight"], a["seen_weight"]),
            self._prepared("asgfit", "asg_em_m_step", (n_lobes * self._asg_em_group,), a["normal"], a["seen_weight"],
                           a["resp_weight"], a["lobes"], np.float64(dead_mass), np.float64(log_range[0]),
                           np.float64(log_range[1]), a["state"], j, np.int32(n_bins), a["new_lobes"], a["mass"],
                           a["moved"], group=self._asg_em_group),  # (a work-group a lobe)
            self._prepared("asgfit", "asg_em_finish", (1,), a["new_lobes"], a["mass"], a["moved"],
                           np.float64(converged), j, a["lobes"], a["alpha"], a["state"])]
        return a

    def _run_asg_em(self, normal, weight, rows, alpha, iterations, dead_mass, log_range, converged):
        n_bins, n_lobes = len(normal), len(alpha)
        key = (n_bins, n_lobes, iterations, dead_mass, log_range, converged, self._asg_em_group)
        prog = self._asg_em_programs.pop(key, None)
        if prog is None:
            prog = self._asg_em_program(n_bins, n_lobes, iterations, dead_mass, log_range, converged)
        self._keep_asg_em(key, prog, n_bins, n_lobes)
        cl = self._cl
        # (pyopencl's event of a non-blocking copy waits for it when dropped: the events, and with them the host
        # arrays, are held until the reads below, which wait for the whole queue)
        uploads = [cl.enqueue_copy(self._queue, prog[name], np.ascontiguousarray(host, np.float64), is_blocking=False)
                   for name, host in (("normal", normal), ("weight", weight), ("lobes", rows), ("alpha", alpha))]
        cl.enqueue_fill_buffer(self._queue, prog["state"], np.int32(0), 0, 8)
        for _ in range(iterations):
            for step in prog["steps"]:
                step()
        # (the three copies queued together, then one wait: one round trip, not three)
        reads = [self._read_later(prog["lobes"], (n_lobes, 12), np.float64),
                 self._read_later(prog["alpha"], n_lobes, np.float64), self._read_later(prog["state"], 2, np.int32)]
        lobes, alpha, state = (read() for read in reads)
        del uploads
        return lobes, alpha, int(state[1])

    def frame_buffer(self, width: int, height: int) -> np.ndarray:
        """On a GPU, a host array mapped from a buffer the driver allocates in pinned host memory
        (ALLOC_HOST_PTR, mapped once and left mapped: no kernel reads it): a read-back into it needs no
        staging copy."""
        if not self.is_gpu:
            return super().frame_buffer(width, height)
        cl = self._cl
        shape = (int(height), int(width), 3)
        buf = cl.Buffer(self._ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.ALLOC_HOST_PTR, int(np.prod(shape)))
        mapped, _ = cl.enqueue_map_buffer(self._queue, buf, cl.map_flags.READ | cl.map_flags.WRITE, 0, shape,
                                          np.uint8, is_blocking=True)
        return mapped  # (its base holds the mapping, and the mapping the buffer)

    def _to_host(self, array, shape, kind, out=None):
        return self._read(array, self._host_shape(shape, kind), KINDS[kind][0], out)

    def _context(self):
        return self._ctx

    def _upload_trace_mesh(self, mesh):
        bvh = build_bvh(mesh.vertices, mesh.faces)
        return {"points": self._to_device(mesh.vertices, "vec3"), "faces": self._to_device(mesh.faces, "i32"),
                "normals": self._to_device(mesh.normals, "vec3"),
                "face_normals": self._to_device(mesh.face_normals, "vec3"),
                "bvh": bvh, "nodes": self._buffer(bvh.packed(), np.float32),
                "tris": self._buffer(bvh.triangle_table(mesh.vertices, mesh.faces), np.float32),
                "tri_index": self._buffer(bvh.tri_index, np.int32)}

    # ------------------------------------------------------------------ trace and shade launches
    def _launch_trace_primary(self, m, camera, face, bary, position, t):
        cltypes = self._cl.cltypes
        c = camera.packed()
        eye, forward, right, up = (cltypes.make_float4(*c[k:k + 3], 0.0) for k in (0, 3, 6, 9))
        self._launch("trace", "trace_primary", (camera.width * camera.height,), m["nodes"], m["tris"], m["tri_index"],
                     eye, forward, right, up, np.int32(camera.width), np.int32(camera.height), face, bary, position, t)

    def _launch_trace_occluded(self, m, origins, directions, t_min, t_max, n, occluded):
        self._launch("trace", "trace_occluded", (n,), m["nodes"], m["tris"], origins, directions, np.float32(t_min),
                     t_max, np.int32(n), occluded)

    def _launch_trace_shadows(self, m, face, bary, position, eye, lights, samples, eps, t_min, part, changed, n,
                              vis):
        self._launch("trace", "trace_shadows", (n, len(lights)), m["nodes"], m["tris"], *self._ray_mesh(m), face,
                     bary, position, *(np.float32(e) for e in eye), self._small_upload(m, "lights", lights),
                     self._small_upload(m, "light_samples", samples, "i32"), np.float32(eps), np.float32(t_min),
                     *map(np.int32, part),
                     changed[0], np.int32(changed[1]), np.int32(n), np.int32(len(lights)), vis)

    def _upload_shade_static(self, static, levels, basis, coeffs):
        """Empty arrays become one-element dummies the kernel never reads."""
        has_ssdf = int(static.has_ssdf)
        table = np.asarray(static.table, np.float32)

        def buf(key, dtype, host=None):
            return self._shade_input(key, getattr(static, key) if host is None else host,
                                     lambda a: self._shade_buffer(key, a, dtype))

        return {
            **{key: buf(key, np.int32) for key in ("faces", "face_material", "mat_info", "eff_info", "tex_info")},
            **{key: buf(key, np.float32) for key in (
                "positions", "normals", "tangents", "env_sgs", "env_residual", "env_maps", "analytic", "eff_lobes",
                "eff_sub", "eff_tables", "eff_diffuse", "uvs", "tex_data")},
            "env_levels": buf("env_levels", np.float32, levels),
            "ssdf_basis": buf("ssdf_basis", np.float32, basis.T),  # texel-major (res², terms + 1)
            "ssdf_coeffs": buf("ssdf_coeffs", np.float32, coeffs), "env_theta": buf("env_theta", np.float32),
            "table": buf("table", np.float32, table),
            "disk_radii": buf("disk_radii", np.float32, DISK_RADII),
            # Counts and shapes that the kernel takes by value.
            "n_env": np.int32(len(static.env_sgs)), "axis_lobes": np.int32(static.axis_lobes),
            "n_levels": np.int32(len(levels)),
            "residual_shape": tuple(np.int32(x) for x in np.shape(static.env_residual)[:2]),
            "ssdf_args": (np.int32(has_ssdf), np.int32(static.ssdf_res), np.int32(basis.shape[0]),
                          np.int32(coeffs.shape[1] if has_ssdf else 0)),
            "table_args": (np.int32(table.shape[1]), np.int32(table.shape[2]),
                           np.float32(sg.TABLE_LOG10_ETA[0]), np.float32(sg.TABLE_LOG10_ETA[1]),
                           np.float32(sg.SHARPNESS_MAX)),
        }

    def _launch_trace_occlusion(self, m, face, bary, position, eye, eps, t_min, samples, part, changed, n, mask):
        self._launch("trace", "trace_occlusion", (n,), m["nodes"], m["tris"], *self._ray_mesh(m), face, bary,
                     position,
                     *(np.float32(e) for e in eye), np.float32(eps), np.float32(t_min), np.int32(samples),
                     *map(np.int32, part), changed[0], np.int32(changed[1]), np.int32(n), mask)

    def _launch_trace_lobe_rays(self, m, face, bary, position, eye, lobes, eps, t_min, part, changed, n, mask):
        self._launch("trace", "trace_lobe_rays", (n,), m["nodes"], m["tris"], *self._ray_mesh(m), face, bary,
                     position,
                     *(np.float32(e) for e in eye), self._small_upload(m, "lobe_ray_lobes", lobes),
                     np.int32(len(lobes)), np.int32(LOBE_RAYS), np.float32(eps), np.float32(t_min),
                     *map(np.int32, part), changed[0], np.int32(changed[1]), np.int32(n), mask)

    def _launch_mark_changed(self, m, n, changed):
        self._launch("trace", "mark_changed", (n,), m["gbuffer_face"], m["gbuffer_position"], m["reference_face"],
                     m["reference_position"], self._ray_mesh(m)[3], m["face_material"],
                     *(np.float32(e) for e in m["gbuffer_eye"]), np.int32(n), changed)

    def _launch_block_lenders(self, m, face, position, eye, part, n, lenders):
        self._launch("trace", "frame_block_lenders", (n,), face, position, self._ray_mesh(m)[3],
                     *(np.float32(e) for e in eye), *map(np.int32, (part[2], part[3], n)), lenders)

    def _launch_share_block_masks(self, m, lenders, face, samples, part, n, traced, shared, known):
        self._launch("trace", "share_block_masks", (n,), lenders, face,
                     *map(np.int32, (part[2], part[3], n, samples, part[0], part[1])), traced, shared, known)

    def _launch_share_block_shadows(self, m, lenders, face, samples, part, n, n_lights, traced, shared):
        self._launch("trace", "share_block_shadows", (n,), lenders, face,
                     *map(np.int32, (part[2], part[3], n, part[0], part[1], n_lights)),
                     self._small_upload(m, "light_samples", samples, "i32"), traced, shared)

    def _launch_shade(self, dev, m, face, bary, vis, occ, occ_samples, lobe_occ, n_sharp, part, known, lights, camera,
                      n, only_material, changed, kept_mode, kept_amount, kept_scale, out):
        cltypes = self._cl.cltypes
        light_buf = self._small_upload(m, "shade_lights", lights if len(lights) else np.zeros((1, 8), np.float32))
        eye, forward, right, up = (cltypes.make_float4(*camera[k:k + 3], 0.0) for k in (0, 3, 6, 9))
        self._launch("shade", "shade_pixels", (n,),
                     face, bary, vis, occ, np.int32(occ_samples), lobe_occ, np.int32(n_sharp), *map(np.int32, part),
                     *known, dev["faces"],
                     dev["positions"], dev["normals"], dev["tangents"],
                     dev["face_material"], eye, forward, right, up, np.float32(camera[12]), np.float32(camera[13]),
                     np.int32(len(lights)), light_buf, dev["n_env"], dev["env_sgs"], dev["axis_lobes"],
                     dev["env_residual"],
                     *dev["residual_shape"], dev["env_maps"],
                     dev["n_levels"], dev["env_levels"], *dev["ssdf_args"], dev["ssdf_basis"],
                     dev["ssdf_coeffs"], dev["env_theta"], dev["disk_radii"], dev["table"], *dev["table_args"],
                     dev["mat_info"], dev["analytic"],
                     dev["eff_info"], dev["eff_lobes"], dev["eff_sub"], dev["eff_tables"], dev["eff_diffuse"],
                     dev["uvs"], dev["tex_info"], dev["tex_data"], np.int32(n), np.int32(only_material),
                     changed[0], changed[1], np.int32(changed[2]), np.int32(kept_mode), kept_amount, kept_scale, out)

    def _upload_spheres(self, spheres):
        return {"of_material": self._buffer(spheres.sphere_of_material, np.int32),
                **{key: self._buffer(getattr(spheres, key), np.int32) for key in ("sphere_info", "level_info")},
                **{key: self._buffer(getattr(spheres, key), np.float32) for key in ("angles", "texels")}}

    def _launch_shade_litsphere(self, dev, m, face, bary, vis, lights, camera, view_mode, shrink, env_maps, env_levels,
                                n, out):
        light_buf = self._small_upload(m, "shade_lights", lights if len(lights) else np.zeros((1, 8), np.float32))
        eye, forward, right, up = (self._cl.cltypes.make_float4(*camera[k:k + 3], 0.0) for k in (0, 3, 6, 9))
        self._launch("litsphere", "shade_litsphere", (n,), face, bary, vis, m["faces"], m["points"], m["normals"],
                     m["face_material"], eye, forward, right, up, np.float32(camera[12]), np.float32(camera[13]),
                     np.int32(len(lights)), light_buf, np.int32(view_mode), np.float32(shrink), env_maps,
                     np.int32(env_levels.size // 16), env_levels,  # (L, 4) float32: 16 bytes a level
                     dev["of_material"], dev["sphere_info"], dev["angles"], dev["level_info"], dev["texels"],
                     np.int32(n), out)

    def _launch_tonemap(self, radiance, scale, operator, n, out):
        self._launch("tonemap", "tonemap_pixels", (n,), radiance, np.float32(scale), np.int32(operator), np.int32(n),
                     out)

    def _launch_accumulate(self, radiance, weight, first, n, total):
        self._launch("tonemap", "accumulate_frame", (n,), radiance, np.float32(weight), np.int32(bool(first)),
                     np.int32(n), total)

    def _launch_litsphere_texels(self, resolution, effective, lights, kinds, params, info, lobes, amplitudes, n, out):
        self._launch("litsphere", "sphere_texels", (n,), np.int32(resolution), lights, np.int32(effective), kinds,
                     params, info, lobes, amplitudes, np.int32(n), out)

    # ------------------------------------------------------------------ envmap (prefiltered environment)
    def prefilter_level(self, radiance, sharpness, height, width):

        radiance = np.ascontiguousarray(radiance, np.float32)
        height, width, eta = int(height), int(width), float(sharpness)
        h_in, w_in = radiance.shape[:2]
        in_rows, in_cols = equirect_tables(h_in, w_in)
        out_rows, out_cols = equirect_tables(height, width)
        n = height * width
        out = self._empty(3 * n, np.float32)
        self._launch("envmap", "prefilter_level", (n,),
                     self._buffer(radiance, np.float32), self._buffer(in_rows, np.float32), np.int32(h_in),
                     self._buffer(in_cols, np.float32), np.int32(w_in), self._buffer(out_rows, np.float32),
                     self._buffer(out_cols, np.float32), np.int32(width), np.float32(eta),
                     np.float32(1.0 - SUPPORT / eta), np.int32(n), out)
        return self._read(out, (height, width, 3), np.float32)

    # ------------------------------------------------------------------ matrix (Wu's M, warp_biscale.matrix)
    def _launch_brdf_matrix(self, normals, wi, wo, kinds, params, tables, m, color, n_rows, n_pairs, out):
        self._launch("matrix", "brdf_matrix", (n_pairs, n_rows), normals, wi, wo, kinds, params, tables, np.int32(m),
                     *(np.float32(c) for c in color), np.int32(n_rows), np.int32(n_pairs), out)

    # ------------------------------------------------------------------ sgfit (a measured BRDF's SG fit)
    def _launch_sgfit_gram(self, data, candidates, n, chunk, n_candidates, n_chunks, out):
        self._launch("sgfit", "fit_gram", (n_chunks, n_candidates), data["basis"], data["target"], data["weight"],
                     candidates, np.int32(n), np.int32(chunk), np.int32(n_chunks), np.int32(n_candidates), out)

    def _launch_sgfit_residual(self, data, candidates, n, chunk, n_candidates, n_chunks, coef, out):
        self._launch("sgfit", "fit_residual", (n_chunks, n_candidates), data["basis"], data["target"],
                     data["weight"], candidates, coef, np.int32(n), np.int32(chunk), np.int32(n_chunks),
                     np.int32(n_candidates), out)

    # ------------------------------------------------------------------ asg (Xu 2013's operators, warp_biscale.asg)
    def _launch_asg(self, kernel, n, inputs, out):
        args = (np.int32(a) if isinstance(a, int) else a for a in inputs)
        self._launch("asg", kernel, (n,), *args, np.int32(n), out)
