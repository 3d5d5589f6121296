"""Where an editor edit's time goes (issue 23): cProfile of repeated `Editor.set` calls per kind of edit,
the functions sorted by their own time, so that host work (uploads, launches, numpy) and device waits
(synchronisation, read-backs) show apart.

    python -m bench.profile_editor --backends warp:cuda opencl:nvidia --size 1920x1080 --edits 10
    python -m bench.profile_editor --backends warp:cuda --size 1920x1080 --activities   # device time per kernel

--activities (Warp CUDA) lists each kernel, copy and graph of one warm edit of each kind with its device time
(Warp's activity timing), beside the edit's wall time: what the GPU does and how long the host keeps it waiting.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
import warnings

import warp_biscale as wb
from warp_biscale.editor import Editor
from warp_biscale.scene import Scene

warnings.filterwarnings("ignore", category=wb.EnergyWarning)

EDITS = {"geometry": ("tile.height", (0.45, 0.55)), "brdf": ("material0.exponent", (200.0, 300.0)),
         "light": ("light.elevation", (40.0, 50.0))}


def edit_parts(ed, runs=20):
    """Device-synchronised times (ms, medians) of the pieces of an edit on the editor's current design: the
    frame's shade, its tone map and read-back, the static inputs of a material edit, and the bake's stages
    for the current tile (its visibility rays alone, the whole bake)."""
    from warp_biscale import directions as dirs
    from warp_biscale.render import frame_lights, static_inputs

    be, scene = ed.backend, ed.scene
    cam, lights = scene.camera, frame_lights(scene)

    def timed(f):
        out = []
        for _ in range(runs):
            be.synchronize()
            t0 = time.perf_counter()
            f()
            be.synchronize()
            out.append(time.perf_counter() - t0)
        return round(sorted(out)[len(out) // 2] * 1e3, 3)

    static = static_inputs(scene, be)
    res = {"shade": timed(lambda: be.shade(scene.mesh, static, cam.packed(), lights, to_host=False)),
           "frame_u8": timed(lambda: be.frame_u8(scene.mesh, cam.width, cam.height)),
           "shadows": timed(lambda: be.trace_shadows(scene.mesh, None, lights, to_host=False, samples=1))}
    mat = ed.effective

    def material_edit():
        s = Scene(scene.mesh, [mat.with_materials(list(mat.materials)), *scene.materials[1:]], cam,
                  scene.environment, scene.lights, ssdf_resolution=scene.ssdf_resolution)
        static_inputs(s, be)
    res["static (material edit)"] = timed(material_edit)
    tile = ed.tile
    fac = be.sample_facets(tile, 1 << 16, 0)
    grid = dirs.frozen_grid(12)
    res["visibility rays"] = timed(lambda: be.visibility(tile, fac, grid))
    res["pyramid tile build"] = timed(lambda: ed._tile(ed._state))
    return res


def edit_activities(ed, kinds):
    """Print each device activity of one warm edit of each kind (Warp CUDA's activity timing)."""
    import warp as wp

    for kind in kinds:
        name, values = EDITS[kind]
        for v in (values[1], values[0], values[1]):  # warm
            ed.set(name, v)
        ed.backend.synchronize()
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        t0 = time.perf_counter()
        ed.set(name, values[0])
        wall = time.perf_counter() - t0
        results = wp.timing_end()
        print(f"== {ed.backend.name} {kind}: {wall * 1e3:.2f} ms wall, {len(results)} device activities, "
              f"{sum(r.elapsed for r in results):.2f} ms of device time; timings "
              f"{ {k: round(v * 1e3, 2) for k, v in ed.timings.items() if isinstance(v, float)} }")
        for r in results:
            print(f"  {r.elapsed:7.3f} ms  {r.name}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="+", default=["auto"])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--edits", type=int, default=10)
    ap.add_argument("--kinds", nargs="+", default=list(EDITS))
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--sort", default="tottime", help="pstats order: tottime (own time) or cumulative")
    ap.add_argument("--parts", action="store_true", help="time the edit's pieces instead (device-synchronised)")
    ap.add_argument("--activities", action="store_true", help="each kernel and copy of one edit (Warp CUDA)")
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    for backend in a.backends:
        be = wb.get_backend(backend)
        ed = Editor("pyramid", backend=be, width=w, height=h)
        if a.parts:
            print(f"== {be.name} parts (ms): {edit_parts(ed)}")
            continue
        if a.activities:
            edit_activities(ed, a.kinds)
            continue
        for kind in a.kinds:
            name, values = EDITS[kind]
            for v in (values[1], values[0], values[1]):  # warm
                ed.set(name, v)
            walls = []
            prof = cProfile.Profile()
            for i in range(a.edits):
                t0 = time.perf_counter()
                prof.enable()
                ed.set(name, values[i % 2])
                prof.disable()
                walls.append(time.perf_counter() - t0)
            walls.sort()
            last = {k: round(v * 1e3, 2) for k, v in ed.timings.items() if isinstance(v, float)}
            stages = {k: round(v * 1e3, 2) for k, v in (ed.effective.timings or {}).items()}
            print(f"== {be.name} {kind}: median {walls[len(walls) // 2] * 1e3:.2f} ms; last {last}; "
                  f"bake stages {stages}")
            s = io.StringIO()
            pstats.Stats(prof, stream=s).sort_stats(a.sort).print_stats(a.top)
            print("\n".join(line for line in s.getvalue().splitlines()[6:] if line.strip()))


if __name__ == "__main__":
    main()
