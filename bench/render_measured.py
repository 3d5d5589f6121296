"""The 1080p frame of the render target scene (bench_render.target_scene) with the synthetic paint
(`measured.paint_like`, a MERL-grid table) as its torus material, shaded by its SG fit of one lobe and of two
(lobes="auto" keeps two for the paint): directly on the torus, and baked on the pyramid tile (SG bake, K = 12,
J = 8, 2^14 facets). Per frame the G-buffer, one shadow ray a light and the shading, left on the device
(bench_render.time_frames); one JSON line each, with the fit's relative error (issue 21: what the second lobe
costs a frame, against what it gains in error).

    python -m bench.render_measured warp:cuda opencl:nvidia > $OUT/render_measured.jsonl
"""

import json
import sys
import warnings

import warp_biscale as wb
from warp_biscale import measured
from bench.bench_render import target_scene, time_frames


def main(backends):
    warnings.simplefilter("ignore", wb.EnergyWarning)
    paint = measured.paint_like()
    for backend in backends:
        be = wb.get_backend(backend)
        tile = wb.geometry.pyramid()
        for lobes in (1, "auto"):
            table = paint.with_sg_fit(lobes, be)
            fit = table.sg_fit()
            for where in ("object", "baked"):
                scene = target_scene(1920, 1080, backend=be)
                scene.materials[0] = (table if where == "object" else
                                      wb.bake(tile, [table], lobes=8, directions=12, facets=2**14, backend=be))
                per_frame, _, _, _ = time_frames(scene, be, frames=10, runs=5, shadow_samples=1)
                print(json.dumps({"backend": be.name, "device": be.device, "fit_lobes": len(fit.lobes),
                                  "fit_error": fit.error, "fit_s": fit.seconds, "material": where,
                                  "frame_ms": 1e3 * per_frame, "fps": 1.0 / per_frame}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["auto"])
