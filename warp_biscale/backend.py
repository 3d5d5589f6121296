"""One protocol for every compute backend, and selection by name.

A backend implements each stage primitive on its device and hands back the data model
(`Facets`, `Visibility`, numpy arrays). The pipeline calls only these methods and never asks which
kind of backend it holds. Names:

``"warp"`` (Warp, CUDA if present else CPU), ``"warp:cpu"``, ``"warp:cuda"`` / ``"warp:cuda:N"``,
``"opencl"`` (first OpenCL device, GPUs first), ``"opencl:<substring>"`` (first device whose
platform or device name contains the substring, case-insensitive), ``"auto"`` (Warp on CUDA if
present, else Warp CPU).
"""

from __future__ import annotations

import functools
from typing import Protocol, runtime_checkable

import numpy as np

from .device import DeviceLobes, DeviceStart, OnDevice, cpu_threads, one_line
from .model import BACKENDS, Facets, GBuffer, ShadeInputs, Visibility

__all__ = ["Backend", "get_backend", "backends"]

@runtime_checkable
class Backend(Protocol):
    name: str  # the selection name that reproduces this backend, e.g. "warp:cpu"
    device: str  # what it runs on, in words
    is_gpu: bool  # a GPU (else a CPU): what a sensible default quality or resolution depends on

    def synchronize(self) -> None:
        """Block until all queued work has finished (for timing)."""

    def sample_facets(self, tile, count: int, seed: int) -> Facets:
        """`count` area-weighted stratified facets of `tile` (reference.sample_facets)."""

    def visibility(self, tile, facets: Facets, directions: np.ndarray, brute_force: bool = False) -> Visibility:
        """V_s(ω) bits for (D, 3) unit directions (reference.visibility); brute_force tests every
        triangle instead of walking the BVH (for testing the BVH)."""

    def visible_area(self, facets: Facets, vis: Visibility, to_host: bool = True) -> np.ndarray:
        """(D,) float32 a_v(ω) (reference.visible_area); with to_host=False an OnDevice (for
        solve_amplitudes; `host()` reads it back)."""

    def effective_brdf(self, facets: Facets, vis: Visibility, kinds: np.ndarray, params: np.ndarray,
                       pair_i: np.ndarray, pair_o: np.ndarray, a_v: np.ndarray) -> np.ndarray:
        """(P, 3) float32 f̄ for direction index pairs into vis.directions (reference.effective_brdf)."""

    # --- SG bake (stages em, amplitudes: kernels/, cl/; warp_biscale.bake) ---
    def ndf_statistics(self, facets: Facets, axes, sharpness, log_weight) -> np.ndarray:
        """(J, 4) float64 one E-step's sums [Σ r ΔA, Σ r ΔA n] (reference.ndf_statistics)."""

    def visible_weights(self, facets: Facets, vis: Visibility, to_host: bool = True) -> np.ndarray | OnDevice:
        """(Ns,) float32 ΔA_s · mean_k V_s(ω_k)(n_s·ω_k)⁺ over vis.directions (reference.visible_weights);
        with to_host=False only queued: → OnDevice, which ndf_em takes as its `facet_weight`, its copy to
        the host queued with it (its host() then waits for the weights, not for work queued after them)."""

    def normal_bins(self, facets: Facets, resolution: int) -> np.ndarray:
        """(Ns,) int32 cube-map bin of each facet normal at `resolution` (directions.cube_bin)."""

    def bvndf_histogram(self, facets: Facets, vis: Visibility, order: np.ndarray, bin_start: np.ndarray,
                        weight: np.ndarray, pair_i: np.ndarray, pair_o: np.ndarray) -> np.ndarray:
        """(P, L) float32 BVNDF histogram N over the unordered pairs (reference.bvndf_histogram): the facets
        grouped by bin (`order` the facet indices sorted by bin, `bin_start` (L + 1,) each bin's first
        place in it), each weighing `weight` (Ns,)."""

    def histogram_moments(self, hist: np.ndarray, bin_normal: np.ndarray, directions: np.ndarray,
                          axes: np.ndarray, sharpness: np.ndarray, pair_i: np.ndarray,
                          pair_o: np.ndarray) -> np.ndarray:
        """(P, J + 1) float32 moments of lobe_moments from the histogram instead of the facets
        (reference.histogram_moments): each bin a facet at its mean normal."""

    def em_start(self, facets: Facets, facet_weight: np.ndarray | OnDevice | None, count: int) -> DeviceStart:
        """EM's start for `count` lobes picked on the device: lobes.initial_lobes(the facets' normals,
        `facet_weight`, count, their cube-map bins at lobes.START_RES), each bin's sums in fixed point
        (start_scale). `facet_weight` None (the areas), visible_weights(..., to_host=False)'s OnDevice
        or a host array (Ns,). Only queued: → DeviceStart, which ndf_em takes as its start before the
        host has it (so that EM can be queued behind the rays)."""

    def ndf_em(self, facets: Facets, axes: np.ndarray | DeviceStart, sharpness: np.ndarray | None,
               weight: np.ndarray | None, iterations: int, facet_weight: np.ndarray | OnDevice | None = None,
               to_host: bool = True, meanwhile=None) -> tuple | DeviceLobes:
        """Spherical EM on the device from lobes (axes (J, 3), sharpness, weight), or from em_start's
        DeviceStart as `axes` (sharpness and weight None): at most `iterations`
        steps, stopping after the first step that lobes.converged → (axes, sharpness, weight, steps),
        float64, dead lobes with weight 0 (reference.ndf_em). Facets weigh their area, or
        `facet_weight` (Ns,), or visible_weights(..., to_host=False)'s OnDevice. With to_host=False
        the EM is only queued: → DeviceLobes, whose lobes lobe_moments can sum over before the host
        has them. `meanwhile()`, if given, runs on the host before ndf_em first waits on the device (it may
        never wait: a caller with host work to hide runs it afterwards too, wrapped in `device.once`)."""

    def facet_weight(self, weight: np.ndarray):
        """A device copy of a facet weight (Ns,) as lobe_moments takes it (an OnDevice whose host() is `weight`),
        made now: an upload waits for the work queued before it, so a caller uploads while the device is idle."""

    def facet_weight_by_face(self, facets: Facets, per_face: np.ndarray, host_weight=None):
        """A facet weight per_face[face_s]·ΔA_s (Ns,) made on the device from a value a face (F,) (the float32
        product of the float32 values), as lobe_moments takes it: an OnDevice whose host() is that weight in float64
        (`host_weight()` if given, else gathered here). Queued, not waited for: the facets' faces stay on the
        device and only the F values are uploaded."""

    def lobe_moments(self, facets: Facets, vis: Visibility, weight: np.ndarray | None, axes: np.ndarray | DeviceLobes,
                     sharpness: np.ndarray | None, pair_i: np.ndarray, pair_o: np.ndarray,
                     to_host: bool = True, lobe_values=None):
        """(P, J + 1) float32 facet sums of docs/design.md §5 for the unordered pairs (reference.lobe_moments),
        each facet weighing `weight` (Ns,) (a host array, or what facet_weight or facet_weight_by_face returned), or
        its area ΔA when `weight` is None (a tile of one material and one colour: nothing uploaded); with
        to_host=False a device array for solve_amplitudes (no round trip through the host). `axes` may be the
        DeviceLobes of this backend's last ndf_em (`sharpness` None): its J lobes, dead ones included, as the device
        holds them (float32). With `lobe_values`, the facets' values of other lobes stand for the SG lobes' (axes
        and sharpness unused): a host (Ns, J) array, or an asg.ASG batch (J,) (the ASG bake's lobes, their
        amplitudes included), evaluated on the device."""

    def asg_em(self, bin_normal: np.ndarray, bin_weight: np.ndarray, start, alpha, iterations: int,
               bandwidth_range, converged: float) -> tuple:
        """The ASG bake's EM (asg_bake.fit_asg, stage `asgfit`) over normal bins (L, 3) weighing (L,) from the
        asg.ASG batch `start` (J,) with weights `alpha` (J,), every step queued at once → (asg.ASG (J,), alpha
        (J,), steps), dead lobes (alpha 0) included; float64 but for the E-step's ∫G (float32)."""

    def asg_value_sums(self, facets: Facets, weight, asgs, to_host: bool = True):
        """(J,) float64 Σ_s w_s G_j(n_s) over the facets for an asg.ASG batch (J,), `weight` (Ns,) w_s (a host
        array or visible_weights' OnDevice): the ASG bake's calibration sums (asg_bake.calibrated_rows). float32
        terms, float64 sums. to_host=False: an OnDevice to read when needed."""

    def solve_amplitudes(self, moments, a_v, rows, integrals, pair_i, pair_o, n_dirs: int, to_host: bool = True):
        """(P, J) float32 μ ≥ 0 for the ordered pairs (reference.solve_amplitudes); `moments` a host
        array or what lobe_moments(..., to_host=False) returned; `a_v` a host array or what
        visible_area(..., to_host=False) returned. With to_host=False μ stays on the device (for
        material_tables)."""

    def material_tables(self, materials, integrals, n_pairs: int, level_weights=None) -> tuple:
        """Per material m its channels materials[m] = [(μ, rgb)] (μ a host (P, J) array or what
        solve_amplitudes(..., to_host=False) returned; J = len(integrals)) → float32 host arrays: the (M, P, J, 3)
        amplitude tables and (M, P, 3) energies (reference.amplitude_tables per material; a material with no
        channel reflects nothing; a non-finite μ gives its pair a NaN energy), and with `level_weights`
        (effective.level_weights(K), P = K⁴) the (M, L, P, 3) energy levels (reference.energy_levels), else
        None. The tables and the levels stay on the device (model.DeviceArray, read back when host code asks for
        them): the shade stage takes them there (no upload)."""

    # --- SSDF visibility of the large-scale mesh (stage `ssdf`, warp_biscale.ssdf) ---
    def ssdf_distance(self, grid, visible: np.ndarray) -> np.ndarray:
        """(V, N) float32 θd (rad) of (V, N) bool per-vertex visibility over `grid` (an ssdf.SsdfGrid,
        N = S² directions): ±(angle to the nearest opposite-class direction − grid.half_angle), + visible,
        − occluded, ±π with no opposite class (reference.ssdf_distance). Exact; blocks pruned by cones."""

    # --- Ray casting against the large-scale mesh (stage `trace`: kernels/trace.py, cl/trace.cl) ---
    # The backend keeps the mesh on the device in mesh.device_cache[backend.name], a dict, built once
    # per mesh (rebuilt if mesh.vertices or mesh.faces is replaced). Keys, Warp | OpenCL:
    #   "points" (V,) wp.vec3 | V·3 float32 Buffer          vertex positions (float32)
    #   "faces" (F, 3) wp.int32 | F·3 int32                  vertex indices
    #   "normals" (V,) wp.vec3 | V·3 float32                 Mesh.normals (shading normals)
    #   "face_normals" (F,) wp.vec3 | F·3 float32            unit geometric normals (Mesh.face_normals)
    #   "mesh" wp.Mesh (SAH, 2 a leaf) | "bvh" Bvh, "nodes" N·8 float32, "tris" F·9 float32 (slot order),
    #          "tri_index" F int32 (slot → face)             the BVH
    # and, after trace_primary / trace_shadows, the G-buffer of the last frame (P = W·H pixels, row y·W + x):
    #   "gbuffer_face" (P,) wp.int32 | P int32               closest face, −1 = miss
    #   "gbuffer_bary" (P,) wp.vec2 | P·2 float32            (u, v) weights of the face's vertices 1 and 2
    #   "gbuffer_position" (P,) wp.vec3 | P·3 float32        hit point (0 on a miss)
    #   "gbuffer_t" (P,) wp.float32 | P float32              ray distance (inf on a miss)
    #   "gbuffer_eye" (3,) numpy float32, "gbuffer_size" int P
    #   "gbuffer_light_vis" (P, L) wp.uint8 | P·L uint8      light l's visible share from pixel p, in 255ths
    #   "gbuffer_occlusion" (P,) wp.uint32 | P uint32        environment-occlusion masks (bit i: ray i blocked),
    #   "occlusion_samples" int                              of this many rays (0: none since trace_primary)
    #   "gbuffer_lobe_occlusion" (P,) wp.uint32 | P uint32   the sharp environment lobes' ray masks
    # The G-buffer arrays are reused from frame to frame (same size): a new trace overwrites them.
    def trace_primary(self, mesh, camera, to_host: bool = True, keep: bool = False) -> GBuffer | None:
        """The G-buffer of `camera` on `mesh` (reference.trace_primary): camera rays generated in the
        kernel (Camera.packed), closest hit. Fills mesh.device_cache[self.name]["gbuffer_*"] (above)
        and, with to_host, returns the host GBuffer (face, bary, position — the barycentric combination of
        the vertices, on the surface —, t, eye); without, returns None (no copies to the host). keep: first keep
        the device's G-buffer (same size) and its last shade as the reference frame of the rays' and shade's
        only_changed ("reference_face", "reference_position", "reference_radiance")."""

    def trace_occluded(self, mesh, origins: np.ndarray, directions: np.ndarray, t_max,
                       t_min: float | None = None) -> np.ndarray:
        """(N,) bool: any triangle of `mesh` hit with t in (t_min, t_max] (reference.trace_occluded).
        origins, directions (N, 3) (unit), t_max (N,) or a number, inf allowed. The CALLER moves each
        origin off its surface (e.g. along the normal by trace.SHADOW_OFFSET × mesh.scale); t_min
        (default trace.T_MIN × mesh.scale) only guards against rounding. Any ray count (chunked)."""

    def trace_shadows(self, mesh, gbuffer: GBuffer | None, lights_packed, to_host: bool = True,
                      samples=1, part=(0, 1), only_changed: bool = False) -> np.ndarray | None:
        """(P, L) uint8, the visible share of each light in 255ths (reference.trace_shadows): from each hit pixel,
        `samples` rays a light (an int, or one count a light: trace.light_samples) from trace.ray_starts' origin (the
        hit lifted towards the smooth surface of the vertex normals, then moved trace.SHADOW_OFFSET × mesh.scale along
        the geometric normal turned to the eye's side), towards points of each light's disc (`lights_packed` (L, 8)
        Light.packed(); one sample: its centre); a point light's rays stop that offset short of it. Misses get 0, and
        rays below the shading normal's horizon count as blocked. `gbuffer`: None or the GBuffer trace_primary last
        returned (both use the device copy), or any GBuffer with face, bary, position and eye (uploaded). Fills
        "gbuffer_light_vis"; returns None unless to_host. `part` (index, count[, W[, side]]): only the rays each pixel
        traces for anti-aliasing sample index of count (trace.pixel_parts), with W > 0 shared in the pixel blocks
        (side 2 or 4, trace.block_side) of a frame of width W for a light of trace.BLOCK_SLOTS rays or more
        (trace.share_block;
        reference.share_block_shadows). only_changed: only the pixels whose hit is not on the kept reference frame's
        surface there (trace.changed_pixels; trace_primary's keep); the others keep theirs."""

    def trace_occlusion(self, mesh, gbuffer: GBuffer | None, samples: int, to_host: bool = True, part=(0, 1),
                        only_changed: bool = False) -> np.ndarray | None:
        """(P,) uint32 environment-occlusion masks (reference.trace_occlusion): from each hit pixel, `samples`
        (≤ trace.OCCLUSION_SAMPLES_MAX) unbounded rays from where the shadow rays start, along
        trace.occlusion_directions (cosine-distributed over the geometric normal's hemisphere); bit i set
        where ray i is blocked, 0 for a miss. `gbuffer`, `part` and only_changed as trace_shadows' (with a block
        width the masks are shared, reference.share_block_masks, and the rays each pixel was lent kept for
        shade: `ray_known`). Fills "gbuffer_occlusion" and "occlusion_samples", which shade reads; returns None
        unless to_host."""

    def trace_lobe_rays(self, mesh, gbuffer: GBuffer | None, lobes, to_host: bool = True, part=(0, 1),
                        only_changed: bool = False) -> np.ndarray | None:
        """(P,) uint32 masks of the sharp environment lobes' rays (reference.trace_lobe_rays): from each hit
        pixel, trace.LOBE_RAYS unbounded rays over the cap of each of `lobes` ((M, 4) [axis, η], M ≤
        trace.LOBE_RAY_LOBES: the shade inputs' `ShadeInputs.sharp_lobes()`), started as trace_occlusion's; bit
        k·LOBE_RAYS + i set where ray i of lobe k is blocked. Fills "gbuffer_lobe_occlusion", which shade
        reads for inputs with sharp lobes wherever occlusion rays were traced; returns None unless to_host.
        `part` and only_changed as trace_occlusion's."""

    def ray_known(self, mesh) -> tuple:
        """(occlusion, lobe) (P,) uint32 or None: the rays each pixel was lent by its pixel block in the device's
        last trace_occlusion / trace_lobe_rays with a block width (a host GBuffer's occlusion_known, lobe_known)."""

    # --- Per-pixel SG shading (stage `shade`: kernels/shade.py, cl/shade.cl; warp_biscale.shading) ---
    def shade(self, mesh, static: ShadeInputs, camera_packed: np.ndarray, lights_packed: np.ndarray,
              gbuffer: GBuffer | None = None, to_host: bool = True,
              only_material: int | None = None, keep_visibility: bool = False,
              only_changed: bool = False) -> np.ndarray | None:
        """(P, 3) float32 outgoing radiance of every pixel (shading.shade_reference; P = W·H, row-major),
        never NaN, inf or negative; background pixels get the environment along the camera ray.
        `static`: the scene's packed inputs (render._static_inputs), uploaded once and kept in
        static.device[self.name]. camera_packed: Camera.packed() (16,); lights_packed (L, 8).
        The G-buffer: gbuffer None → the one the last trace_primary / trace_shadows / trace_occlusion
        left on the device for `mesh` (the render path; ValueError if absent or traced for another light
        count), or a host GBuffer with face, bary, light_vis and occlusion (uploaded). The output buffer is kept
        in mesh.device_cache[self.name]["radiance"] and reused; returns None unless to_host.
        only_material m: shade only the pixels of faces of material m, and leave every other pixel as
        the last shade of this mesh's device G-buffer left it (gbuffer None only; ValueError if the
        kept radiance is for another frame size): after an edit of one material, with the camera,
        lights and environment unchanged, the same frame as a whole shade, for that material's share
        of the work. keep_visibility (a whole frame over the device's G-buffer): keep each pixel's shadowed
        amount of every environment lobe and its irradiance scale on the device, which a later only_material
        shade, or whole frame with keep_visibility (new lights), reads back, bit for bit the same, while the
        G-buffer, its rays, the environment and the mesh's arrays are those it was kept for (else it computes
        them again): the environment's visibility is most of a pixel's work, and neither a material nor a light
        changes it. only_changed (gbuffer None): only the pixels trace_shadows' only_changed traces; the others
        take the kept reference frame's radiance (an anti-aliased frame shaded once a pixel)."""

    # --- Prefiltered environment (stage `envmap`: kernels/envmap.py, cl/envmap.cl; warp_biscale.lighting) ---
    def prefilter_level(self, radiance: np.ndarray, sharpness: float, height: int, width: int) -> np.ndarray:
        """(height, width, 3) float32 Λ(p, η) = Σ_t G(ω_t; p, η) L_t Ω_t / Σ_t G Ω_t at the texel centres p of
        a height×width equirect map, from the equirect radiance (h, w, 3) (reference.prefilter_level);
        one thread per output texel over the input texels with G ≥ 1e−7 (environment.NEGLIGIBLE)."""


@functools.lru_cache(maxsize=None)
def _make(name: str) -> Backend:
    kind, _, rest = name.partition(":")
    # A backend module is imported when first asked for: importing it imports its toolkit (Warp
    # builds its kernel modules, pyopencl finds its platforms), which a command that never computes
    # (--help, a refused input) should not wait for.
    if kind == "warp":
        from .warp_backend import WarpBackend

        return WarpBackend(rest or None)
    if kind == "opencl":
        from .opencl_backend import OpenCLBackend

        return OpenCLBackend(rest or None)
    raise ValueError(f"unknown backend {name!r}; use 'auto', 'warp', 'warp:cpu', 'warp:cuda', 'opencl', 'opencl:cpu', "
                     "'opencl:gpu' or 'opencl:<platform, vendor or device substring>'")


_BACKEND_TYPES = set()  # types that passed isinstance(·, Backend)


def get_backend(backend="auto") -> Backend:
    """A backend by name (cached: the same name returns the same object), or pass one through. Only a
    device whose probe passed is used (see `backends`); "auto" is Warp (CUDA, else CPU), or the first
    usable OpenCL device where Warp is unusable."""
    if not isinstance(backend, str):
        # (isinstance against the runtime-checkable protocol looks up each of its ~30 members, at the
        # start of every bake and render: once a type)
        if type(backend) in _BACKEND_TYPES:
            return backend
        if isinstance(backend, Backend):
            _BACKEND_TYPES.add(type(backend))
            return backend
        raise ValueError(f"backend must be a name or a Backend, got {backend!r}")
    name = backend.strip().lower() or "auto"
    cpu_threads()  # a bad $WARP_BISCALE_CPU_THREADS is refused here, not taken by "auto" for an unusable Warp
    if name != "auto":
        return _make(name)
    try:
        return _make("warp")
    except (ValueError, RuntimeError) as warp_error:
        try:
            return _make("opencl")
        except (ValueError, RuntimeError) as opencl_error:
            raise ValueError(f"no usable backend here: {warp_error}; {opencl_error}") from None


def backends() -> list[dict]:
    """Every backend found here, usable or not: dicts {name, kind ("warp" | "opencl"), device (in words;
    None when nothing was found), type ("cpu" | "gpu" | None), usable, reason}. Each found device is
    probed once per process (a tiny float64 kernel built and run, its output checked against
    `device.probe_expected`); `reason` says in one line why an entry is unusable and what to do ("" when
    usable). Without a CUDA driver, an unusable "warp:cuda" entry says so (Warp then runs on the CPU)."""
    found = []
    try:  # (imported here as in _make; a Warp that cannot even import is reported, not fatal)
        from .warp_backend import list_devices as warp_devices

        found.extend(warp_devices())
    except Exception as exc:
        found.append({"name": "warp:cpu", "kind": "warp", "device": None, "type": "cpu", "usable": False,
                      "reason": f"Warp cannot start here: {one_line(exc)}"})
    try:
        from .opencl_backend import list_devices as opencl_devices

        found.extend(opencl_devices())
    except Exception as exc:
        found.append({"name": "opencl", "kind": "opencl", "device": None, "type": None, "usable": False,
                      "reason": f"OpenCL support cannot start here: {one_line(exc)}"})
    return found


BACKENDS["get"] = get_backend  # MeasuredBRDF.sg_fit("warp:cuda"), LitSphere.from_material(backend="warp:cuda")
