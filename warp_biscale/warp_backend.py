"""The NVIDIA Warp backend: kernels in ``warp_biscale.kernels``, on ``"cpu"`` or ``"cuda:N"``.

Warp's CPU device runs a launch on one thread. Its launches call native code through ctypes,
which releases the GIL, so on the CPU each stage's launch is split along its last dimension into
one slice per core, launched from a thread pool (measured here: 2.26× on 2 cores, bit-identical).
On CUDA a launch is one launch.
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import weakref
from concurrent.futures import ThreadPoolExecutor, wait

import numpy as np
import warp as wp

from .asg import ASG
from .effective import EFF_LOBE_WIDTH
from .device import (ASG_EM_BLOCK, KINDS, DeviceBackend, PROBE_VALUES, SCRATCH_BYTES, DeviceStart, UploadCache,
                     check_kernel_lobes, chunking, cpu_threads, device_copy, one_line, padded_lobe_values,
                     probe_mismatch, start_scale)
from .kernels import amplitudes as kamplitudes
from .kernels import asg as kasg
from .kernels import asgfit as kasgfit
from .kernels import bvndf as kbvndf
from .kernels import em as kem
from .kernels import envmap as kenvmap
from .kernels import facets as kfacets
from .kernels import litsphere as klitsphere
from .kernels import matrix as kmatrix
from .kernels import probe as kprobe
from .kernels import sgfit as ksgfit
from .kernels import shade as kshade
from .kernels import ssdf as kssdf
from .kernels import tonemap as ktonemap
from .kernels import trace as ktrace
from .kernels import truth as ktruth
from .kernels import visibility as kvisibility
from .environment import SUPPORT, equirect_tables
from .lobes import KERNEL_LOBES, START_RES
from .progress import compile_notice
from .smallscale import ray_offset
from .trace import DISK_RADII, LOBE_RAYS

_READY = False
_NO_CUDA_DRIVER = False  # Warp's native library found no CUDA driver (a CPU-only machine)
_PROBES: dict = {}  # device alias → None (usable) or why not, in one line
_CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


RAY_PIECES = 4  # slices per core of the visibility rays on the CPU (see _launch)
# Slices per core of a frame's per-pixel kernels (rays, shading) on the CPU: their cost follows the image (a sky pixel
# costs nothing), so a frame cut in one slice a core leaves cores idle (bench/README.md, "What was tried").
FRAME_PIECES = 8
LAUNCH_MIN_ITEMS = 1024  # items of a slice beyond the first a core: each launch costs the host tens of µs
LAUNCH_MAX_ITEMS = 1 << 22  # items of a slice at most: ~1 s of visibility rays on one core
PINNED_BYTES = 1 << 20  # read-backs from a GPU at least this large go through a pinned host buffer


def _stderr_of(call) -> str:
    """Run `call()` with file descriptor 2 sent to a temporary file, and return what was written there
    (a native library writes to the descriptor, past sys.stderr)."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            call()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        held.seek(0)
        return held.read().decode("utf-8", "replace")


def init_warp():
    global _READY, _NO_CUDA_DRIVER
    if not _READY:
        wp.config.log_level = wp.LOG_WARNING  # compile chatter would drown the progress display
        # Warp's native library warns on stderr when it finds no CUDA driver: on a CPU-only machine
        # that is every command. `backends()` says it once instead; any other message passes on.
        text = _stderr_of(wp.init)
        _NO_CUDA_DRIVER = _CUDA_DRIVER_WARNING in text
        rest = "".join(line for line in text.splitlines(True) if _CUDA_DRIVER_WARNING not in line)
        if rest:
            sys.stderr.write(rest)
            sys.stderr.flush()
        _READY = True
    return wp


def probe(device) -> str | None:
    """None if Warp builds and runs the probe kernel (kernels/probe.py) right on `device` (a Warp
    device), else why not, in one line. Once per device and process."""
    alias = device.alias
    if alias not in _PROBES:

        try:

            with compile_notice():
                wp.load_module(kprobe.probe.module, device=device)
            values = wp.array(PROBE_VALUES, dtype=wp.float64, device=device)
            out = wp.zeros(len(PROBE_VALUES), dtype=wp.float64, device=device)
            wp.launch(kprobe.probe, dim=len(PROBE_VALUES), inputs=[values], outputs=[out], device=device)
            _PROBES[alias] = probe_mismatch(out.numpy())
        except Exception as exc:
            _PROBES[alias] = f"Warp cannot build or run a kernel on {device.name}: {one_line(exc)}"
    return _PROBES[alias]


def list_devices() -> list[dict]:
    """Warp's devices as backends() entries (each probed); without CUDA an unusable "warp:cuda" entry
    that says why."""
    wp = init_warp()
    found = []
    for dev in wp.get_devices():
        reason = probe(dev)
        found.append({"name": f"warp:{dev.alias}", "kind": "warp", "device": dev.name,
                      "type": "cpu" if dev.is_cpu else "gpu", "usable": reason is None, "reason": reason or ""})
    if not wp.is_cuda_available():
        why = ("no NVIDIA CUDA driver found" if _NO_CUDA_DRIVER else "the CUDA driver reports no GPU")
        found.append({"name": "warp:cuda", "kind": "warp", "device": None, "type": "gpu", "usable": False,
                      "reason": f"{why}: no GPU here, Warp runs on the CPU"})
    return found


WARP_TYPES = {"i32": wp.int32, "i64": wp.int64, "u8": wp.uint8, "u32": wp.uint32, "f32": wp.float32,
              "f64": wp.float64, "vec2": wp.vec2, "vec3": wp.vec3, "vec4d": wp.vec4d, "vec3d": wp.vec3d}


class WarpBackend(DeviceBackend):
    """Warp on one device. `device`: None (CUDA if present, else CPU), "cpu", "cuda" or "cuda:N"."""

    def __init__(self, device: str | None = None):
        wp = init_warp()
        if device is None:
            device = "cuda:0" if wp.is_cuda_available() else "cpu"
        if device == "cuda" and wp.is_cuda_available():
            device = "cuda:0"
        if device.startswith("cuda") and not wp.is_cuda_available():
            raise ValueError(f"backend 'warp:{device}' asked for, but Warp finds no CUDA device here")
        try:
            self._device = wp.get_device(device)
        except Exception as exc:
            raise ValueError(f"Warp has no device {device!r}: {exc}") from None
        reason = probe(self._device)
        if reason:
            raise ValueError(f"backend 'warp:{self._device.alias}' is unusable here: {reason}")
        self.name = f"warp:{self._device.alias}"
        self.device = self._device.name
        self.is_gpu = not self._device.is_cpu
        # Launch slices: one per thread on the CPU (device.cpu_threads; each slice runs on one), one on a GPU.
        self._slices = cpu_threads() if self._device.is_cpu else 1
        self._pool = ThreadPoolExecutor(self._slices) if self._slices > 1 else None
        # Threads worth launching per reduction: one per slice on the CPU, enough to fill a GPU.
        self._threads = 1 if self._device.is_cpu else 1 << 18
        self._tiles = weakref.WeakKeyDictionary()
        self._loaded = set()  # (id of a Warp module, block_dim) loaded by _load
        self._uploads = UploadCache()
        self._held_visible_area = None  # (host, device) of the last visible_area
        self._scratch_arrays = {}  # role → device scratch array, see _scratch
        self._pinned = {}  # (shape, dtype) → pinned host buffer for large read-backs, see _trace_host
        self._em_graphs = {}  # (Ns, J, steps, weighted) → captured EM (CUDA): see _em_graph
        self._em_buffers = {}
        self._asg_em_programs = {}  # (bins rounded up, J, steps, constants) → an ASG EM's program: _run_asg_em
        self._pinned = {}  # (shape, dtype) → [(pinned host array, event)] free for _read_later
        self._frame_buffers = {}  # id of a frame_buffer view → (its pinned Warp array, the view)

    def __repr__(self):
        return f"WarpBackend({self._device.alias!r})"

    def synchronize(self):
        wp.synchronize_device(self._device)

    def _launch(self, kernel, dim, inputs, outputs, block_dim=256, pieces=1):
        """Launch `kernel` over `dim`; its last input is an offset into the last dimension.

        On the CPU the last dimension is cut into `pieces` slices per core, launched in parallel (a core
        that finishes its slice takes the next: for a kernel whose work varies along that dimension,
        such as the visibility rays, more pieces even out the cores). On a GPU `block_dim` threads make
        a block (Warp's default 256).
        """
        dim = tuple(dim) if isinstance(dim, (tuple, list)) else (int(dim),)
        n = dim[-1]
        parts = 1
        if self._slices > 1:  # one slice a core, and up to `pieces` a core of at least LAUNCH_MIN_ITEMS items
            parts = min(self._slices * pieces, max(self._slices, n // LAUNCH_MIN_ITEMS), n)
            # ... and slices of at most LAUNCH_MAX_ITEMS items: a Ctrl-C waits for the running ones (below)
            parts = min(max(parts, -(-int(np.prod(dim)) // LAUNCH_MAX_ITEMS)), n)
        # Compile/load before the threads race to do it (the kernel's own Warp module: kernels made
        # by a factory live in a module of their own).
        self._load(kernel, block_dim)
        if parts <= 1:
            wp.launch(kernel, dim=dim, inputs=[*inputs, 0], outputs=outputs, device=self._device,
                      block_dim=block_dim)
            return
        bounds = np.linspace(0, n, parts + 1).astype(int)
        futures = [self._pool.submit(wp.launch, kernel, dim=(*dim[:-1], int(b - a)), inputs=[*inputs, int(a)],
                                     outputs=outputs, device=self._device)
                   for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        try:
            for f in futures:
                f.result()
        except BaseException:  # (Ctrl-C): the slices still running must end before their arrays are freed
            for f in futures:
                f.cancel()
            wait(futures)
            raise

    def _load(self, kernel, block_dim=None):
        """Load `kernel`'s Warp module before its first launch: on a first run that compiles it, which
        compile_notice tells the user about when it takes a while."""
        key = (id(kernel.module), block_dim)
        if key not in self._loaded:
            with compile_notice():
                wp.load_module(kernel.module, device=self._device, block_dim=block_dim)
            self._loaded.add(key)

    # ------------------------------------------------------------------ device copies
    def _tile(self, tile):
        entry = self._tiles.get(tile)
        if entry is None:
            dev = self._device
            points = wp.array(tile.to_local(tile.vertices), dtype=wp.vec3, device=dev)
            faces = wp.array(tile.faces.astype(np.int32), dtype=wp.int32, device=dev)
            # SAH with 2 triangles a leaf: built on the host for CUDA too, but its rays ran about twice
            # as fast as on Warp's default GPU LBVH with 4 a leaf (bench/README.md).
            mesh = wp.Mesh(points=points, indices=faces.flatten(), bvh_constructor="sah", bvh_leaf_size=2)
            vn = tile.vertex_normals if tile.vertex_normals is not None else np.zeros((1, 3))
            areas = tile.face_areas
            entry = {
                "mesh": mesh,
                "points": points,
                "faces": faces,
                "vertex_normals": wp.array(vn.astype(np.float32), dtype=wp.vec3, device=dev),
                "face_normals": wp.array(tile.face_normals.astype(np.float32), dtype=wp.vec3, device=dev),
                "cumulative_area": wp.array(np.cumsum(areas), dtype=wp.float64, device=dev),
                "face_area": wp.array(areas, dtype=wp.float64, device=dev),
            }
            self._tiles[tile] = entry
        return entry

    # ------------------------------------------------------------------ stages
    def _launch_sample_facets(self, tile, count, xi1, xi2, pos, nrm, face):
        t = self._tile(tile)
        self._launch(kfacets.sample_facets, count,
                     [t["points"], t["faces"], t["vertex_normals"], int(tile.vertex_normals is not None),
                      t["face_normals"], t["cumulative_area"], t["face_area"], count, wp.float64(xi1), float(xi2)],
                     [pos, nrm, face])

    def _launch_facet_weights(self, face, per_face, area, count, weight):
        self._launch(kfacets.facet_weights, count, [face, per_face, area], [weight])

    def _launch_visibility(self, tile, facets, dirs, n_dirs, words, brute_force, bits):
        t = self._tile(tile)
        position = self._facet_positions(facets, tile)
        f = self._facets(facets)
        n = len(facets)
        visible = self._scratch("visible", (n_dirs, n), wp.uint8)  # (packed into bits at once)
        z_lo, z_hi = tile.z_range
        # Blocks of one warp: a ray's BVH walk varies in length, and small blocks free their slots as
        # soon as their rays end (on a GPU 32 threads a block beat Warp's default 256 by a quarter).
        self._launch(kvisibility.visibility_rays, (n_dirs, n),
                     [t["mesh"].id, t["points"], t["faces"], t["face_normals"], int(brute_force),
                      position, f["face"], dirs,
                      0.0, 0.0, float(tile.period[0]), float(tile.period[1]), 0.0, z_hi - z_lo, ray_offset(tile)],
                     [visible], block_dim=32, pieces=RAY_PIECES)
        self._launch(kvisibility.pack_bits, (n_dirs, words), [visible], [bits])

    def _launch_visible_area(self, f, v, n_words, n_dirs, chunks, per, a_v):
        partial = self._scratch("visible_area_partial", (chunks, n_dirs), wp.float32)
        self._launch(ktruth.visible_area_partial, (chunks, n_dirs),
                     [v["directions"], v["bits"], f["normal"], f["area"], per], [partial])
        self._load(ktruth.sum_chunks_area)
        wp.launch(ktruth.sum_chunks_area, dim=n_dirs, device=self._device, inputs=[partial], outputs=[a_v])

    def _launch_effective_brdf(self, f, v, kinds, params, pair_i, pair_o, a_v, face, tangent, tables, n_words,
                               n_pairs, chunks, per, out):
        partial = wp.empty((chunks, n_pairs), dtype=wp.vec3, device=self._device)
        self._launch(ktruth.effective_brdf_partial, (chunks, n_pairs),
                     [v["directions"], pair_i, pair_o, v["bits"], f["normal"], f["weight"], f["material"],
                      kinds, params, face, tangent, tables, per],
                     [partial])
        self._load(ktruth.sum_chunks_brdf)
        wp.launch(ktruth.sum_chunks_brdf, dim=n_pairs, device=self._device, inputs=[partial, pair_o, a_v],
                  outputs=[out])

    # --- small-scale interreflection (DeviceBackend.interreflection): one block ---
    def _launch_interreflection(self, tile, f, position, v, kinds, params, pair_i, pair_o, a_v, face_material,
                                face_color, tangent, tables, aniso, n_facets, n_words, paths, chunks, per, bounces,
                                seed, n_pairs, out):
        t = self._tile(tile)
        z_lo, z_hi = tile.z_range
        partial = wp.empty((chunks, n_pairs), dtype=wp.vec3, device=self._device)
        self._launch(ktruth.interreflection_partial, (chunks, n_pairs),
                     [t["mesh"].id, t["face_normals"], face_material, face_color, v["directions"], pair_i, pair_o,
                      v["bits"], position, f["normal"], f["weight"], f["material"], f["face"], kinds, params,
                      tangent, tables, int(aniso), n_facets, paths, per, bounces, seed, 0.0, 0.0, float(tile.period[0]),
                      float(tile.period[1]), 0.0, z_hi - z_lo, ray_offset(tile)],
                     [partial], block_dim=32, pieces=RAY_PIECES)
        self._load(ktruth.sum_chunks_brdf)
        wp.launch(ktruth.sum_chunks_brdf, dim=n_pairs, device=self._device, inputs=[partial, pair_o, a_v],
                  outputs=[out])

    # ------------------------------------------------------------------ SG bake stages
    def _array(self, data, dtype):
        return wp.array(np.ascontiguousarray(data), dtype=dtype, device=self._device)

    def _launch_normal_bins(self, f, n, resolution, bins):
        self._launch(kbvndf.normal_bins, n, [f["normal"], resolution], [bins])

    def _launch_bvndf_histogram(self, v, n_words, pair_i, pair_o, order, bin_start, weight, n_pairs, n_bins, hist):
        self._launch(kbvndf.bvndf_histogram, (n_pairs, n_bins),
                     [pair_i, pair_o, v["bits"], order, bin_start, weight], [hist])

    def _launch_visible_weights(self, f, v, n_dirs, n_words, n, weight):
        self._launch(kem.visible_weights, n, [v["directions"], v["bits"], f["normal"], f["area"]], [weight])

    def em_start(self, facets, facet_weight, count):

        f = self._facets(facets)
        j = int(count)
        weight = f["area"] if facet_weight is None else self._facet_weight(f, facet_weight)
        scale = start_scale(facets, facet_weight)
        n_bins = 6 * START_RES * START_RES
        sums = self._scratch("start_sums", (n_bins, 4), wp.int64)
        sums.zero_()
        scratch = [self._scratch("start_bins", n_bins, wp.vec4d), self._scratch("start_dist", n_bins, wp.float64),
                   self._scratch("start_owner", n_bins, wp.int32), self._scratch("start_chosen", j, wp.int32)]
        rows = wp.empty((j, 6), dtype=wp.float64, device=self._device)
        # (One launch, not sliced over the CPU's cores: there Warp's atomic_add is a plain add.)
        self._load(kem.start_bin_sums)
        self._load(kem.start_pick, 256)
        wp.launch(kem.start_bin_sums, dim=len(facets), inputs=[f["normal"], weight, scale, 0], outputs=[sums],
                  device=self._device)
        wp.launch_tiled(kem.start_pick, dim=[1], inputs=[sums, scale], outputs=[*scratch, rows], block_dim=256,
                        device=self._device)
        return DeviceStart(rows, j, lambda: self._trace_host(rows))  # (read only if asked: the bake never does)

    def _em_launches(self, normal, mass, n_lobes, axes, sharpness, log_weight, state, resp):
        """The E-step's kernels as callables (recorded launches on a GPU: re-issuing one skips Python's
        argument packing) over facets `normal` (vec3) weighing `mass` (float32), with `resp` (Ns, ≥ J)
        their scratch → (steps, stats (1, J) vec4d)."""

        dev = self._device
        n, j = normal.shape[0], n_lobes
        # Short serial chains for a GPU: chunks of 64 facets, then two sums over ~√chunks chunks each.
        chunks, per = chunking(-(-n // 64), j, self._threads)
        per *= 64
        group = int(np.ceil(np.sqrt(chunks)))
        groups = -(-chunks // group)
        partial = wp.empty((chunks, j), dtype=wp.vec4d, device=dev)
        partial2 = wp.empty((groups, j), dtype=wp.vec4d, device=dev)
        stats = wp.empty((1, j), dtype=wp.vec4d, device=dev)
        launches = [(kem.ndf_responsibilities, n, [normal, mass, axes, sharpness, log_weight, state], [resp]),
                    (kem.ndf_sums_partial, (chunks, j), [normal, resp, per, state], [partial]),
                    (kem.sum_chunks_stats, (groups, j), [partial, group, state], [partial2]),
                    (kem.sum_chunks_stats, (1, j), [partial2, groups, state], [stats])]
        steps = [self._recorded(*launch, split=k < 2) for k, launch in enumerate(launches)]
        # A recorded launch keeps its arguments only as a Warp internal: hold the scratch arrays here.
        steps.append(lambda held=(resp, partial, partial2): None)
        return steps, stats

    def _resp(self, f, n, n_lobes):
        """The E-step scratch (Ns, J) of the facets whose device arrays are `f`, kept with them."""
        key = ("resp", n_lobes)
        if key not in f:
            f[key] = wp.empty((n, n_lobes), dtype=wp.float32, device=self._device)
        return f[key]

    def _recorded(self, kernel, dim, inputs, outputs, split=True, block_dim=None):
        """A callable that re-issues this launch (see _launch): recorded (re-issued without Python's
        argument packing), or with `split` on the CPU sliced over the cores (a sliced launch costs
        ~200 µs there, so tiny kernels are not split). `block_dim`: a tiled launch of `dim` blocks of
        that many threads (wp.launch_tiled; on the CPU a block of one), not split."""
        if block_dim is not None:
            self._load(kernel, block_dim)
            return wp.launch_tiled(kernel, dim=[dim], inputs=[*inputs, 0], outputs=outputs, device=self._device,
                                   block_dim=block_dim, record_cmd=True).launch
        if split and self._slices > 1:
            return functools.partial(self._launch, kernel, dim, inputs, outputs)
        self._load(kernel)
        return wp.launch(kernel, dim=dim, inputs=[*inputs, 0], outputs=outputs, device=self._device,
                         record_cmd=True).launch

    def ndf_statistics(self, facets, axes, sharpness, log_weight):
        f = self._facets(facets)
        state = wp.zeros(2, dtype=wp.int32, device=self._device)
        steps, stats = self._em_launches(f["normal"], f["area"], len(axes),
                                         self._array(np.asarray(axes, np.float32), wp.vec3),
                                         self._array(np.asarray(sharpness, np.float32), wp.float32),
                                         self._array(np.asarray(log_weight, np.float32), wp.float32), state,
                                         self._resp(f, len(facets), len(axes)))
        for step in steps:
            step()
        return stats.numpy()[0].astype(np.float64)

    def _em_program(self, normal, mass, j, iterations, resp):
        """Buffers and launches of an EM of at most `iterations` steps for J lobes over these facet
        arrays → dict: `start` and `result` (J, 6) float64 (em_start_rows / em_result_rows), `state`,
        and the launches as callables: `load`, `steps` (one EM step) and `unload`."""

        dev = self._device
        prog = {name: wp.zeros(j, dtype=dtype, device=dev) for name, dtype in (
            ("moved", wp.int32), ("axes32", wp.vec3), ("sharp32", wp.float32), ("logw32", wp.float32),
            ("axes64", wp.vec3d), ("sharp64", wp.float64), ("weight64", wp.float64))}
        prog["state"] = wp.zeros(2, dtype=wp.int32, device=dev)
        prog["start"] = wp.zeros((j, 6), dtype=wp.float64, device=dev)
        prog["result"] = wp.zeros((j, 6), dtype=wp.float64, device=dev)
        lobes64 = [prog["axes64"], prog["sharp64"], prog["weight64"]]
        lobes32 = [prog["axes32"], prog["sharp32"], prog["logw32"]]
        steps, stats = self._em_launches(normal, mass, j, *lobes32, prog["state"], resp)
        steps.append(self._recorded(kem.em_m_step, j, [stats, prog["state"], *lobes64], [*lobes32, prog["moved"]],
                                    split=False))
        steps.append(self._recorded(kem.em_finish, 1, [prog["moved"], int(iterations)], [prog["state"]], split=False))
        prog["steps"] = steps
        prog["load"] = self._recorded(kem.em_load, j, [prog["start"]], [*lobes64, *lobes32, prog["state"]],
                                      split=False)
        prog["unload"] = self._recorded(kem.em_result, j, [*lobes64, prog["state"]], [prog["result"]], split=False)
        return prog

    def _em_graph(self, n, j, iterations, weighted):
        """On CUDA, the whole EM of one shape (Ns, J, step cap, weighted or not) as one captured CUDA
        graph over buffers of its own, captured once and replayed: queueing a step's six dependent launches
        from Python (and reading the stop flag) cost a GPU's host more than the whole replay
        (bench/README.md). Steps after convergence return at their first line."""
        key = (n, j, int(iterations), bool(weighted))
        graph = self._em_graphs.pop(key, None)
        if graph is None:
            dev = self._device
            shared = self._em_buffers
            if shared.get("n") != n or shared["resp"].shape[1] < j:
                # The facet buffers, shared by every J up to resp's columns (at least KERNEL_LOBES): the
                # graphs captured over the old ones go with them.

                self._em_graphs.clear()
                shared.clear()
                shared.update(n=n, normal=wp.empty(n, dtype=wp.vec3, device=dev),
                              mass=wp.empty(n, dtype=wp.float32, device=dev),
                              resp=wp.empty((n, max(j, KERNEL_LOBES)), dtype=wp.float32, device=dev))
            prog = self._em_program(shared["normal"], shared["mass"], j, iterations, shared["resp"])
            with wp.ScopedCapture(device=dev, force_module_load=False) as capture:
                prog["load"]()
                for _ in range(int(iterations)):
                    for step in prog["steps"]:
                        step()
                prog["unload"]()
            graph = {"prog": prog, "graph": capture.graph}
        return self._keep_recent(self._em_graphs, key, graph)

    def _run_em(self, f, mass, start_rows, n, j, iterations, weighted, meanwhile=None):
        def load_start(rows):
            if isinstance(start_rows, np.ndarray):
                rows.assign(start_rows)
            else:
                wp.copy(rows, start_rows)

        if self._device.is_cuda:
            graph = self._em_graph(n, j, iterations, weighted)
            prog = graph["prog"]
            wp.copy(self._em_buffers["normal"], f["normal"])
            wp.copy(self._em_buffers["mass"], mass)
            load_start(prog["start"])
            wp.capture_launch(graph["graph"])
            return prog
        prog = self._em_program(f["normal"], mass, j, iterations, self._resp(f, n, j))
        load_start(prog["start"])
        self._step_em(prog, iterations, lambda: bool(prog["state"].numpy()[0]), meanwhile)
        return prog

    def lobe_moments(self, facets, vis, weight, axes, sharpness, pair_i, pair_o, to_host=True, lobe_values=None):

        f = self._facets(facets)
        v = self._vis(vis)
        dev = self._device
        n, n_pairs = len(facets), len(pair_i)
        asgs = lobe_values if isinstance(lobe_values, ASG) else None  # (values made on the device)
        if lobe_values is None:
            j, axes_arr, sharpness_arr = self._lobes_on_device(axes, sharpness)
        else:
            j = len(asgs.lam) if asgs is not None else lobe_values.shape[1]
        check_kernel_lobes(j)
        vec, lobe_values_kernel, lobe_moments_partial, asg_lobe_values = kamplitudes.facet_kernels(j)
        if lobe_values is None:
            values = self._scratch("lobe_values", n, vec)
            self._launch(lobe_values_kernel, n, [f["normal"], axes_arr, sharpness_arr], [values])
        elif asgs is not None:
            values = self._scratch("lobe_values", n, vec)
            # (the ASG bake's rows, uploaded once by its asg_value_sums: found by content, no upload behind the queue)
            self._launch(asg_lobe_values, n, [f["normal"], self._recurring(self._asg_rows(asgs, asgs.shape), "f32")],
                         [values])
        else:
            values = wp.array(padded_lobe_values(lobe_values, vec._length_), dtype=vec, device=dev)
        runs = f.get("area_runs") if weight is None else None  # the area's runs depend on the facets alone
        weight = f["area"] if weight is None else device_copy(
            weight, None, lambda host: self._array(np.asarray(host, np.float32), wp.float32))
        if runs is None:
            runs = (wp.empty(vis.words, dtype=wp.uint32, device=dev), wp.empty(n, dtype=wp.int32, device=dev))
            self._launch(kamplitudes.facet_runs, vis.words, [f["normal"], weight], list(runs))
            if weight is f["area"]:
                f["area_runs"] = runs
        channel_bits, run_end = runs
        chunks, per = chunking(vis.words, n_pairs, self._threads)
        shape = (chunks, n_pairs, j + 1)
        if chunks > 1:
            partial = self._scratch("moments_partial", shape, wp.float32)
        else:  # the partial sums are the result: not scratch
            partial = wp.empty(shape, dtype=wp.float32, device=dev)
        self._launch(lobe_moments_partial, (chunks, n_pairs),
                     [v["directions"], self._recurring(pair_i, "i32"),
                      self._recurring(pair_o, "i32"), v["bits"],
                      channel_bits, weight, f["normal"], values, run_end, j, per],
                     [partial])
        if chunks == 1:
            out = partial.reshape((n_pairs, j + 1))
        else:
            out = wp.empty((n_pairs, j + 1), dtype=wp.float32, device=dev)
            self._launch(kamplitudes.sum_chunks_moments, n_pairs, [partial], [out])
        return self._trace_host(out) if to_host else out

    def _launch_asg_value_sums(self, f, weight, rows, n_rows, n, per, chunks, partial):
        self._launch(kamplitudes.asg_value_sums, chunks, [f["normal"], weight, rows, per], [partial])

    def histogram_moments(self, hist, bin_normal, directions, axes, sharpness, pair_i, pair_o):

        dev = self._device
        bin_normal = np.asarray(bin_normal, np.float32)
        j = len(axes)
        check_kernel_lobes(j)
        bn = self._array(bin_normal, wp.vec3)
        bin_values = wp.empty(len(bin_normal), dtype=kamplitudes.vec16, device=dev)
        self._launch(kamplitudes.lobe_values, len(bin_normal),
                     [bn, self._array(np.asarray(axes, np.float32), wp.vec3),
                      self._array(np.asarray(sharpness, np.float32), wp.float32)], [bin_values])
        out = wp.empty((len(pair_i), j + 1), dtype=wp.float32, device=dev)
        self._launch(kamplitudes.histogram_moments, len(pair_i),
                     [self._array(np.asarray(directions, np.float32), wp.vec3),
                      self._array(np.asarray(pair_i, np.int32), wp.int32),
                      self._array(np.asarray(pair_o, np.int32), wp.int32),
                      self._array(np.asarray(hist, np.float32), wp.float32), bn, bin_values, j], [out])
        return out.numpy()

    def solve_amplitudes(self, moments, a_v, rows, integrals, pair_i, pair_o, n_dirs, to_host=True):

        j = len(integrals)
        check_kernel_lobes(j)
        mu = wp.empty((len(pair_i), j), dtype=wp.float32, device=self._device)
        if not isinstance(moments, wp.array):  # a host array, not lobe_moments(..., to_host=False)
            moments = self._array(np.asarray(moments, np.float32), wp.float32)
        self._launch(kamplitudes.solve_amplitudes, len(pair_i),
                     [self._recurring(pair_i, "i32"), self._recurring(pair_o, "i32"),
                      int(n_dirs), self._visible_area_device(a_v), moments,
                      self._recurring(rows, "f64"),  # (integrals recur in material_tables)
                      self._recurring(integrals, "f64")], [mu])
        return self._trace_host(mu) if to_host else mu

    def _launch_amplitude_tables(self, mu, integ, rgb, accumulate, material, n_pairs, j, amps, energy):
        self._launch(kamplitudes.amplitude_tables, n_pairs, [mu, integ, wp.vec3(*rgb), int(accumulate), int(material)],
                     [amps, energy])

    def _launch_energy_levels(self, energy, weights, n_mat, n_levels, k2, levels):
        self._launch(kamplitudes.energy_levels, (n_mat, n_levels, k2 * k2), [energy, weights], [levels])

    # ------------------------------------------------------------------ SSDF (stage `ssdf`, warp_biscale.ssdf)
    def _launch_ssdf_distance(self, g, blocks, visible, classes, n_v, n, theta):
        self._launch(kssdf.ssdf_distance, (n_v, n),
                     [visible, g["directions"], g["half_angle"], g["members"], g["axis"], g["cos"], g["sin"], classes],
                     [theta])

    # ------------------------------------------------------------------ stage trace
    # Ray casting against the large-scale mesh; see Backend.trace_primary for the device-cache keys.
    def _queued_read(self, array, shape, kind):
        return self._read_later(array)

    def _read_later(self, a):
        """→ a function returning a host copy of device array `a` as it is now. On a GPU the copy is queued
        at once into pinned memory with an event behind it: the function then waits for `a`'s work alone,
        not for what is queued after it. The pinned buffers are pooled per shape: a buffer goes back to the
        pool once its copy is read out (into a host array of the caller's own), and one never read is left
        to Python. (A fresh pinned buffer each call cost a GPU's host far more inside a bake than in a
        loop alone: bench/README.md.)"""
        if not self._device.is_cuda:
            return lambda: self._trace_host(a)
        free = self._pinned.setdefault((a.shape, a.dtype), [])
        host, ready = free.pop() if free else (wp.empty(a.shape, dtype=a.dtype, device="cpu", pinned=True),
                                               wp.Event(self._device))
        wp.copy(host, a)
        wp.get_stream(self._device).record_event(ready)
        out = []

        def read():
            if not out:
                wp.synchronize_event(ready)
                out.append(host.numpy().copy())
                free.append((host, ready))
            return out[0]

        return read

    def _trace_host(self, a, out=None):
        """A host copy of a device array (on the CPU, .numpy() is a view that the next frame overwrites),
        in `out` (a host array of its size) if given. From a GPU, a large array (a frame) goes through a
        pinned host buffer kept per shape and type: a copy to pageable memory goes through the driver's
        staging buffer and ran several times slower."""
        held = self._frame_buffers.get(id(out)) if out is not None else None
        if held is not None and held[1]() is out and held[0].size == a.size and held[0].dtype == a.dtype:
            wp.copy(held[0], a)  # straight into the caller's pinned buffer (frame_buffer): no host copy
            wp.synchronize_device(self._device)
            return out
        if self._device.is_cpu or a.capacity < PINNED_BYTES:
            host = a.numpy()
        else:
            key = (a.shape, a.dtype)
            pinned = self._pinned.get(key)
            if pinned is None:
                pinned = self._pinned[key] = wp.empty(a.shape, dtype=a.dtype, device="cpu", pinned=True)
            wp.copy(pinned, a)
            wp.synchronize_device(self._device)
            host = pinned.numpy()
        if out is not None:
            np.copyto(out.reshape(host.shape), host)
            return out
        return host if (not self._device.is_cpu and a.capacity < PINNED_BYTES) else host.copy()

    # ------------------------------------------------------------------ device primitives (DeviceBackend)
    def _to_device(self, host, kind):
        np_dtype, width = KINDS[kind]
        a = np.ascontiguousarray(host, np_dtype)
        return wp.array(a.reshape(-1, width) if width > 1 else a, dtype=WARP_TYPES[kind], device=self._device)

    def _new(self, shape, kind):
        """(`kind` may also be a Warp dtype: the scratch arrays of some stages hold vectors of J floats.)"""
        return wp.empty(shape, dtype=WARP_TYPES.get(kind, kind), device=self._device)

    def _zeros(self, shape, kind):
        return wp.zeros(shape, dtype=WARP_TYPES[kind], device=self._device)

    def _flat(self, array):
        return array.flatten()

    def _asg_em_program(self, n_bins, j, iterations, dead_mass, log_range, converged) -> dict:
        """The ASG EM's buffers for `n_bins` bins and J lobes and its steps' launches, recorded."""
        shapes = {"normal": (n_bins, wp.vec3d), "weight": (n_bins, wp.float64), "lobes": ((j, 12), wp.float64),
                  "alpha": (j, wp.float64), "state": (2, wp.int32), "resp_weight": ((n_bins, j), wp.float64),
                  "seen_weight": (n_bins, wp.float64), "new_lobes": ((j, 12), wp.float64), "mass": (j, wp.float64),
                  "moved": (j, wp.float64)}
        a = {name: wp.zeros(shape, dtype=dtype, device=self._device) for name, (shape, dtype) in shapes.items()}
        a["step"] = [
            self._recorded(kasgfit.asg_em_responsibilities, n_bins, [a["normal"], a["weight"], a["lobes"], a["alpha"],
                                                                     a["state"]], [a["resp_weight"], a["seen_weight"]]),
            self._recorded(kasgfit.asg_em_m_step, j, [a["normal"], a["seen_weight"], a["resp_weight"], a["lobes"],
                                                      dead_mass, *log_range, a["state"]],
                           [a["new_lobes"], a["mass"], a["moved"]], block_dim=ASG_EM_BLOCK),
            self._recorded(kasgfit.asg_em_finish, 1, [a["new_lobes"], a["mass"], a["moved"], converged],
                           [a["lobes"], a["alpha"], a["state"]], split=False)]
        return a

    def _run_asg_em(self, normal, weight, rows, alpha, iterations, dead_mass, log_range, converged):
        # One program (buffers and recorded launches) per padded bin count, J and step cap, kept and reused; on CUDA
        # its steps are one graph, captured once and replayed, as the SG EM's (_em_graph): the replay of its 24
        # launches costs ~0.3 ms where every kernel returns at once (bench/results/asg-h100-860865a).
        size, j = len(normal), len(alpha)
        key = (size, j, iterations, dead_mass, log_range, converged)
        kept = self._asg_em_programs.pop(key, None)
        if kept is None:
            prog = self._asg_em_program(size, j, iterations, dead_mass, log_range, converged)
            kept = {"prog": prog, "graph": None}
            if self._device.is_cuda:
                with wp.ScopedCapture(device=self._device, force_module_load=False) as capture:
                    self._asg_em_steps(prog, iterations)
                kept["graph"] = capture.graph
        self._keep_asg_em(key, kept, size, j)
        prog = kept["prog"]
        prog["normal"].assign(normal)
        prog["weight"].assign(weight)
        prog["lobes"].assign(rows)
        prog["alpha"].assign(alpha)
        prog["state"].zero_()
        if kept["graph"] is not None:
            wp.capture_launch(kept["graph"])
        else:
            self._asg_em_steps(prog, iterations)
        # (the three copies queued together, then one wait: one round trip, not three)
        reads = [self._read_later(prog[name]) for name in ("lobes", "alpha", "state")]
        lobes, alpha, state = (read() for read in reads)
        return lobes, alpha, int(state[1])

    @staticmethod
    def _asg_em_steps(prog, iterations):
        for _ in range(iterations):
            for launch in prog["step"]:
                launch()

    def frame_buffer(self, width: int, height: int) -> np.ndarray:
        """On a GPU, pinned host memory: a frame is then copied into it from the device and nowhere else."""
        if self._device.is_cpu:
            return super().frame_buffer(width, height)
        n = int(width) * int(height) * 3
        pinned = wp.empty(n, dtype=wp.uint8, device="cpu", pinned=True)
        view = pinned.numpy().reshape(int(height), int(width), 3)
        # Known by the view's id and a weak reference to it (a recycled id cannot match); the pinned memory
        # goes when its view does.
        self._frame_buffers = {k: v for k, v in self._frame_buffers.items() if v[1]() is not None}
        self._frame_buffers[id(view)] = (pinned, weakref.ref(view))
        return view

    def _to_host(self, array, shape, kind, out=None):
        return self._trace_host(array, out).reshape(self._host_shape(shape, kind))

    def _upload_trace_mesh(self, mesh):
        points = self._to_device(mesh.vertices, "vec3")
        faces = self._to_device(mesh.faces, "i32")
        # SAH with 2 triangles a leaf, as _tile: its rays ran 2× faster than Warp's default LBVH.
        return {"points": points, "faces": faces, "normals": self._to_device(mesh.normals, "vec3"),
                "face_normals": self._to_device(mesh.face_normals, "vec3"),
                "mesh": wp.Mesh(points=points, indices=faces.flatten(), bvh_constructor="sah", bvh_leaf_size=2)}

    def _scratch(self, role, shape, dtype):
        """A device array that no caller keeps (a kernel's intermediate, or a table read back at once),
        reused from call to call while its shape and type match: each wp.empty costs a GPU host about
        0.1 ms, and a bake made a dozen. Launches on one stream, and read-backs that copy, keep reuse
        safe. Arrays over SCRATCH_BYTES are not kept."""
        shape = tuple(shape) if isinstance(shape, (tuple, list)) else (int(shape),)
        if int(np.prod(shape)) * wp.types.type_size_in_bytes(dtype) > SCRATCH_BYTES:
            self._scratch_arrays.pop(role, None)
            return wp.empty(shape, dtype=dtype, device=self._device)
        return self._reuse(self._scratch_arrays, role, shape, dtype)

    # ------------------------------------------------------------------ trace and shade launches
    def _launch_trace_primary(self, m, camera, face, bary, position, t):
        c = camera.packed()
        self._launch(ktrace.trace_primary, len(face),
                     [m["mesh"].id, m["points"], m["faces"], wp.vec3(*c[0:3]), wp.vec3(*c[3:6]), wp.vec3(*c[6:9]),
                      wp.vec3(*c[9:12]), camera.width, camera.height],
                     [face, bary, position, t], pieces=FRAME_PIECES)

    def _launch_trace_occluded(self, m, origins, directions, t_min, t_max, n, occluded):
        self._launch(ktrace.trace_occluded, n, [m["mesh"].id, origins, directions, t_min, t_max], [occluded])

    def _launch_trace_shadows(self, m, face, bary, position, eye, lights, samples, eps, t_min, part, changed, n,
                              vis):
        self._launch(ktrace.trace_shadows, (len(lights), n),
                     [m["mesh"].id, *self._ray_mesh(m), face, bary, position, wp.vec3(*eye),
                      self._small_upload(m, "lights", lights),
                      self._small_upload(m, "light_samples", samples, "i32"), eps, t_min, *part, *changed],
                     [vis], pieces=FRAME_PIECES)

    def _upload_shade_static(self, static, levels, basis, coeffs):
        def upload(dtype, width=None, shape=None):
            def make(a):
                if a.size == 0:  # Warp wants no empty arrays: a one-element dummy (the kernel never reads it)
                    a = np.zeros((1, width) if width else 1, a.dtype)
                a = np.ascontiguousarray(a)
                return wp.array(a if shape is None else a.reshape(shape), dtype=dtype, device=self._device)
            return make

        def arr(key, dtype, width=None, host=None, shape=None):
            return self._shade_input(key, getattr(static, key) if host is None else host, upload(dtype, width, shape))

        return {
            "faces": arr("faces", wp.int32, 3),
            "positions": arr("positions", wp.vec3), "normals": arr("normals", wp.vec3),
            "tangents": arr("tangents", wp.vec3), "face_material": arr("face_material", wp.int32),
            "env_sgs": arr("env_sgs", wp.float32, 7), "env_maps": arr("env_maps", wp.vec3),
            "env_residual": arr("env_residual", wp.vec3, host=np.asarray(static.env_residual, np.float32),
                                shape=(-1, 3)),
            "residual_shape": tuple(int(x) for x in np.shape(static.env_residual)[:2]),
            "env_levels": arr("env_levels", wp.float32, host=levels),
            # texel-major (res², terms + 1): a lookup reads each corner's terms contiguously
            "ssdf_basis": arr("ssdf_basis", wp.float32, host=basis.T),
            "ssdf_coeffs": arr("ssdf_coeffs", wp.float32, host=coeffs), "env_theta": arr("env_theta", wp.float32, 1),
            "disk_radii": arr("disk_radii", wp.vec3, host=DISK_RADII),
            "table": arr("table", wp.float32), "mat_info": arr("mat_info", wp.int32, 4),
            "analytic": arr("analytic", wp.float32, 9), "eff_info": arr("eff_info", wp.int32, 8),
            "eff_lobes": arr("eff_lobes", wp.float32, EFF_LOBE_WIDTH), "eff_sub": arr("eff_sub", wp.float32, 9),
            "eff_tables": arr("eff_tables", wp.float32), "eff_diffuse": arr("eff_diffuse", wp.float32),
            "uvs": arr("uvs", wp.vec2), "tex_info": arr("tex_info", wp.int32, 4),
            "tex_data": arr("tex_data", wp.vec3, host=np.asarray(static.tex_data, np.float32), shape=(-1, 3)),
            "n_env": len(static.env_sgs), "axis_lobes": int(static.axis_lobes),
            "has_ssdf": int(static.has_ssdf), "ssdf_res": int(static.ssdf_res),
        }

    def _launch_trace_occlusion(self, m, face, bary, position, eye, eps, t_min, samples, part, changed, n, mask):
        self._launch(ktrace.trace_occlusion, n, [m["mesh"].id, *self._ray_mesh(m), face, bary, position,
                                                 wp.vec3(*eye), eps, t_min, samples, *part, *changed], [mask],
                     pieces=FRAME_PIECES)

    def _launch_trace_lobe_rays(self, m, face, bary, position, eye, lobes, eps, t_min, part, changed, n, mask):
        self._launch(ktrace.trace_lobe_rays, n,
                     [m["mesh"].id, *self._ray_mesh(m), face, bary, position, wp.vec3(*eye),
                      self._small_upload(m, "lobe_ray_lobes", lobes), len(lobes), LOBE_RAYS, eps, t_min, *part,
                      *changed],
                     [mask], pieces=FRAME_PIECES)

    def _launch_mark_changed(self, m, n, changed):
        self._launch(ktrace.mark_changed, n, [m["gbuffer_face"], m["gbuffer_position"], m["reference_face"],
                                              m["reference_position"], m["face_normals"], m["face_material"],
                                              wp.vec3(*m["gbuffer_eye"])], [changed], pieces=FRAME_PIECES)

    def _launch_block_lenders(self, m, face, position, eye, part, n, lenders):
        self._launch(ktrace.frame_block_lenders, n, [face, position, m["face_normals"], wp.vec3(*eye), part[2], part[3],
                                                     n], [lenders], pieces=FRAME_PIECES)

    def _launch_share_block_masks(self, m, lenders, face, samples, part, n, traced, shared, known):
        self._launch(ktrace.share_block_masks, n, [lenders, face, part[2], part[3], samples, part[0], part[1], traced],
                     [shared, known], pieces=FRAME_PIECES)

    def _launch_share_block_shadows(self, m, lenders, face, samples, part, n, n_lights, traced, shared):
        self._launch(ktrace.share_block_shadows, n,
                     [lenders, face, part[2], part[3], part[0], part[1], n_lights,
                      self._small_upload(m, "light_samples", samples, "i32"), traced], [shared],
                     pieces=FRAME_PIECES)

    def _launch_shade(self, dev, m, face, bary, vis, occ, occ_samples, lobe_occ, n_sharp, part, known, lights, camera,
                      n, only_material, changed, kept_mode, kept_amount, kept_scale, out):
        light_arr = self._small_upload(m, "shade_lights", lights if len(lights) else np.zeros((1, 8), np.float32))
        # Blocks of 128: a frame's pixels differ in cost (the design's against the floor's and the sky's),
        # and smaller blocks free their slots sooner (bench/results/editor-h100: 128 beat Warp's 256).
        self._launch(kshade.shade_pixels, n,
                     [face, bary, vis, occ, int(occ_samples), lobe_occ, int(n_sharp), *part, *known, dev["faces"],
                      dev["positions"],
                      dev["normals"], dev["tangents"],
                      dev["face_material"], self._small_upload(m, "shade_camera", camera),
                      len(lights), light_arr, dev["n_env"], dev["env_sgs"], dev["axis_lobes"], dev["env_residual"],
                      *dev["residual_shape"], dev["env_maps"], dev["env_levels"],
                      dev["has_ssdf"], dev["ssdf_res"], dev["ssdf_basis"], dev["ssdf_coeffs"], dev["env_theta"],
                      dev["disk_radii"],
                      dev["table"], dev["mat_info"], dev["analytic"], dev["eff_info"], dev["eff_lobes"],
                      dev["eff_sub"], dev["eff_tables"], dev["eff_diffuse"], dev["uvs"], dev["tex_info"],
                      dev["tex_data"], kept_mode, kept_amount, kept_scale, n, only_material, *changed],
                     [out], block_dim=128, pieces=FRAME_PIECES)

    def _upload_spheres(self, spheres):
        return {"of_material": self._array(spheres.sphere_of_material, wp.int32),
                "info": wp.array(np.ascontiguousarray(spheres.sphere_info), dtype=wp.int32, device=self._device),
                "angles": self._array(spheres.angles, wp.vec3),
                "levels": wp.array(np.ascontiguousarray(spheres.level_info), dtype=wp.int32, device=self._device),
                "texels": self._array(spheres.texels, wp.vec3)}

    def _launch_shade_litsphere(self, dev, m, face, bary, vis, lights, camera, view_mode, shrink, env_maps, env_levels,
                                n, out):
        light_arr = self._small_upload(m, "shade_lights", lights if len(lights) else np.zeros((1, 8), np.float32))
        self._launch(klitsphere.shade_litsphere, n,
                     [face, bary, vis, m["faces"], m["points"], m["normals"], m["face_material"],
                      self._small_upload(m, "shade_camera", camera),
                      len(lights), light_arr, view_mode, shrink, env_maps, env_levels, dev["of_material"], dev["info"],
                      dev["angles"], dev["levels"], dev["texels"], n],
                     [out], pieces=FRAME_PIECES)

    def _launch_tonemap(self, radiance, scale, operator, n, out):
        self._launch(ktonemap.tonemap_pixels, n, [radiance, scale, operator, n], [out])

    def _launch_accumulate(self, radiance, weight, first, n, total):
        self._launch(ktonemap.accumulate_frame, n, [radiance, weight, int(first), n], [total])

    def _launch_litsphere_texels(self, resolution, effective, lights, kinds, params, info, lobes, amplitudes, n, out):
        self._launch(klitsphere.sphere_texels, n,
                     [resolution, lights, effective, kinds, params, info, lobes, amplitudes, n], [out])

    # ------------------------------------------------------------------ envmap (prefiltered environment)
    def prefilter_level(self, radiance, sharpness, height, width):

        radiance = np.ascontiguousarray(radiance, np.float32)
        height, width, eta = int(height), int(width), float(sharpness)
        in_rows, in_cols = equirect_tables(*radiance.shape[:2])
        out_rows, out_cols = equirect_tables(height, width)
        out = wp.empty(height * width, dtype=wp.vec3, device=self._device)
        self._launch(kenvmap.prefilter_level, height * width,
                     [self._array(radiance.reshape(-1, 3), wp.vec3), self._array(in_rows, wp.vec4),
                      self._array(in_cols, wp.vec3), self._array(out_rows, wp.vec4), self._array(out_cols, wp.vec3),
                      eta, 1.0 - SUPPORT / eta],
                     [out])
        return out.numpy().reshape(height, width, 3)

    # ------------------------------------------------------------------ matrix (Wu's M, warp_biscale.matrix)
    def _launch_brdf_matrix(self, normals, wi, wo, kinds, params, tables, m, color, n_rows, n_pairs, out):
        self._launch(kmatrix.brdf_matrix, (n_rows, n_pairs),
                     [normals, wi, wo, kinds, params, tables, int(m), wp.vec3(*(float(c) for c in color))], [out])

    # ------------------------------------------------------------------ sgfit (a measured BRDF's SG fit)
    def _launch_sgfit_gram(self, data, candidates, n, chunk, n_candidates, n_chunks, out):
        self._launch(ksgfit.fit_gram, (n_candidates, n_chunks),
                     [data["basis"], data["target"], data["weight"], candidates, n, chunk], [out])

    def _launch_sgfit_residual(self, data, candidates, n, chunk, n_candidates, n_chunks, coef, out):
        self._launch(ksgfit.fit_residual, (n_candidates, n_chunks),
                     [data["basis"], data["target"], data["weight"], candidates, coef, n, chunk], [out])

    # ------------------------------------------------------------------ asg (Xu 2013's operators, warp_biscale.asg)
    def _launch_asg(self, kernel, n, inputs, out):
        self._launch(getattr(kasg, kernel), n, inputs, [out])
