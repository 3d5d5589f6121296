"""Lit-sphere benchmark (seed 004): the shader's error against the exact render, the light angles a
tolerance needs, texture memory, and frame time.

Parts (records go to --out/results.json; table.md and litsphere.png follow):
- ``accuracy``: PSNR over object pixels of a lit-sphere render against the exact direct lighting of the
  same material (`shading.direct_reference`: the material's own BRDF at each pixel centre, the same
  shadow rays), one directional light, per object (sphere, torus) × material × light-angle count ×
  view ("pixel": each pixel's own view direction; "camera": the paper's distant viewer), with the
  textures' memory — error against memory, the method's trade.
- ``tolerance``: the angle count `LitSphere.from_material(..., tolerance=…)` picks, per material and
  tolerance (Cook–Torrance m = 0.1 and a baked pyramid among them).
- ``frames``: a 1080p frame with 8 directional lights (a sphere, a torus and a floor, each a lit
  sphere): G-buffer + one shadow ray a light + shading, device-resident; the paper's frame (no shadow
  rays); and the shading alone.
- ``texels``: `LitSphere.from_material` per material, the host's float64 images against each backend's
  texel kernels (`backend=`): time and the largest difference.

    python -m bench.bench_litsphere --quick --out /tmp/litsphere                       # a CPU
    python -m bench.bench_litsphere --parts frames texels --backends warp:cuda opencl:nvidia --out $OUT   # a GPU
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

import numpy as np

import warp_biscale as wb
from warp_biscale import litsphere as L
from warp_biscale import shading
from warp_biscale.render import VIEWS, scene_spheres

if __package__ in (None, ""):  # run as a file: `bench` importable from the checkout, after site-packages
    sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

warnings.simplefilter("ignore", wb.EnergyWarning)


def materials(backend="auto") -> dict:
    baked = wb.bake(wb.geometry.pyramid(), [wb.BlinnPhong((0.9, 0.7, 0.3), 128, kd=(0.25, 0.12, 0.05),
                                                          normalization="energy")],
                    lobes=8, directions=12, facets=2**14, backend=backend)
    return {"lambert": wb.Lambert((0.8, 0.5, 0.3)),
            "blinnphong n=10": wb.BlinnPhong(0.5, 10, kd=0.4, normalization="energy"),
            "blinnphong n=50": wb.BlinnPhong(0.5, 50, kd=0.4, normalization="energy"),
            "cooktorrance m=0.1": wb.CookTorrance(0.6, 0.1, kd=0.3),
            "baked pyramid": baked}


def objects() -> dict:
    return {"sphere": wb.Mesh.sphere(1.0, subdivisions=5), "torus": wb.Mesh.torus(1.0, 0.4)}


def psnr(a, b, mask) -> float:
    return float(wb.compare_images(a.reshape(-1, 3)[mask][None], b.reshape(-1, 3)[mask][None])["psnr"])


def part_accuracy(backend, size, counts, resolution, out):
    be = wb.get_backend(backend)
    mats = materials(backend)
    light = [wb.DirectionalLight((0.5, 1.0, 0.6), 2.0, 0.25)]
    for obj_name, mesh in objects().items():
        for mat_name, mat in mats.items():
            scene = wb.Scene(mesh, [mat], wb.Camera(eye=(0, 1.5, 4.5), width=size[0], height=size[1]), None, light)
            g = be.trace_primary(mesh, scene.camera)
            vis = be.trace_shadows(mesh, g, scene.lights_packed)
            exact = shading.direct_reference(scene, g.face, g.bary, vis)
            mask = g.face >= 0
            for count in counts:
                angles = L.even_angles(count)
                sphere = scene_spheres(scene, angles, resolution)[0]
                for view in VIEWS:
                    img = wb.render(scene, method="litsphere", backend=be, resolution=resolution, angles=angles,
                                    shadow_samples=1, view=view).image
                    rec = {"part": "accuracy", "backend": be.name, "object": obj_name, "material": mat_name,
                           "angles": count, "resolution": resolution, "view": view, "width": size[0],
                           "height": size[1], "psnr_exact": psnr(img, exact, mask),
                           "texture_bytes": sphere.nbytes, "interpolation_error": sphere.interpolation_error()}
                    out.records.append(rec)
                    out.log(f"{obj_name:<7} {mat_name:<19} {count:>2} angles {view:<6}: {rec['psnr_exact']:6.2f} dB, "
                            f"{rec['texture_bytes'] / 2**20:6.1f} MiB, sphere error {rec['interpolation_error']:.4f}")


def part_tolerance(backend, resolution, tolerances, out):
    mats = materials(backend)
    for mat_name, mat in mats.items():
        for tol in tolerances:
            try:
                sphere = L.LitSphere.from_material(mat, resolution=resolution, tolerance=tol)
                count, err = len(sphere.angles), sphere.chosen["error"]
            except ValueError:
                count, err = None, None
            out.records.append({"part": "tolerance", "material": mat_name, "tolerance": tol, "angles": count,
                                "error": err, "resolution": resolution})
            out.log(f"{mat_name:<19} tolerance {tol:<5}: {count} angles (error {err})")


def frame_scene(width, height, resolution, backend):
    mats = materials(backend)
    torus = wb.Mesh.torus(0.8, 0.3, center=(0.0, 0.5, 0.0), segments=(96, 48), material=0)
    sphere = wb.Mesh.sphere(0.45, center=(1.5, 0.45, 0.6), subdivisions=4, material=1)
    floor = wb.Mesh.plane(6.0, 0.0, divisions=48, material=2)
    spheres = [L.LitSphere.from_material(m, resolution=resolution)
               for m in (mats["baked pyramid"], mats["cooktorrance m=0.1"], mats["lambert"])]
    rng = np.random.default_rng(0)
    lights = [wb.DirectionalLight(d, 0.4, 1.0) for d in rng.normal(size=(8, 3)) * [1, 0, 1] + [0, 1.5, 0]]
    cam = wb.Camera(eye=(0.5, 2.2, 4.2), target=(0.3, 0.4, 0.0), fov=45, width=width, height=height)
    return wb.Scene(wb.Mesh.merge([torus, sphere, floor]), spheres, cam, None, lights)


def part_frames(backends, size, resolution, frames, runs, out):
    for backend in backends:
        be = wb.get_backend(backend)
        scene = frame_scene(*size, resolution, backend)
        first = wb.render(scene, method="litsphere", backend=be, shadow_samples=1)
        pack = next(v for k, v in scene.cache.items() if k[0] == "litsphere_pack")
        lights, cam = scene.lights_packed, scene.camera.packed()
        black = (np.zeros((1, 3), np.float32), np.array([[0, 0, 1, 1]], np.float32))

        def shade(shadowed=True):
            be.shade_litsphere(scene.mesh, pack, cam, lights, *black, shadowed=shadowed, to_host=False)

        def frame():
            be.trace_primary(scene.mesh, scene.camera, to_host=False)
            be.trace_shadows(scene.mesh, None, lights, to_host=False, samples=1)
            shade()

        def unshadowed():  # the paper's frame: every light seen whole
            be.trace_primary(scene.mesh, scene.camera, to_host=False)
            shade(False)

        def loop(step):
            for _ in range(frames):
                step()

        t_frame = common.timed(lambda: loop(frame), runs, be).median_s / frames
        t_open = common.timed(lambda: loop(unshadowed), runs, be).median_s / frames
        t_shade = common.timed(lambda: loop(shade), runs, be).median_s / frames
        rec = {"part": "frames", "backend": be.name, "device": be.device, "width": size[0], "height": size[1],
               "lights": len(lights), "resolution": resolution, "frame_s": t_frame, "fps": 1 / t_frame,
               "unshadowed_s": t_open, "unshadowed_fps": 1 / t_open,
               "shade_s": t_shade, "shade_fps": 1 / t_shade, "texture_bytes": first.info["texture_bytes"]}
        out.records.append(rec)
        out.log(f"{be.name:<28} {size[0]}x{size[1]} 8 lights: frame {t_frame * 1e3:8.3f} ms ({1 / t_frame:8.1f} fps), "
                f"unshadowed {t_open * 1e3:8.3f} ms ({1 / t_open:8.1f} fps), shading alone {t_shade * 1e3:8.3f} ms "
                f"({1 / t_shade:8.1f} fps), textures {rec['texture_bytes'] / 2**20:.1f} MiB")


def part_texels(backends, resolution, runs, out):
    """LitSphere.from_material at the paper's 4 angles: the host's float64 images against each backend's
    texel kernels (the call whole: inputs up, images down, mip levels not yet built), and how far apart."""
    mats = materials(backends[0])
    for name, material in mats.items():
        host = wb.LitSphere.from_material(material, resolution=resolution)
        t_host = common.timed(lambda: wb.LitSphere.from_material(material, resolution=resolution), 1).median_s
        for backend in backends:
            be = wb.get_backend(backend)
            got = wb.LitSphere.from_material(material, resolution=resolution, backend=be)
            t = common.timed(lambda: wb.LitSphere.from_material(material, resolution=resolution, backend=be),
                             runs, be).median_s
            diff = float(np.max(np.abs(got.images - host.images)) / host.images.max())
            out.records.append({"part": "texels", "backend": be.name, "device": be.device, "material": name,
                                "resolution": resolution, "angles": len(host.angles), "host_s": t_host,
                                "device_s": t, "max_diff_rel": diff})
            out.log(f"{be.name:<28} {name:<19} from_material {resolution}²: host {t_host * 1e3:9.1f} ms, "
                    f"backend {t * 1e3:8.2f} ms, largest difference {diff:.1e} of the largest texel")


def table(records, meta):
    lines = [f"# Lit-sphere benchmark ({meta['device_kind']})", "", common.commit_line(meta), ""]
    acc = [r for r in records if r["part"] == "accuracy"]
    if acc:
        lines += ["PSNR (dB) over object pixels against the exact direct lighting, one directional light, "
                  f"{acc[0]['width']}×{acc[0]['height']}, {acc[0]['resolution']}² textures; pixel view / the "
                  "paper's camera view; texture memory per material", ""]
        counts = sorted({r["angles"] for r in acc})
        rows = []
        for obj in sorted({r["object"] for r in acc}):
            for mat in dict.fromkeys(r["material"] for r in acc):
                cells = []
                for c in counts:
                    by = {r["view"]: r for r in acc if r["object"] == obj and r["material"] == mat and r["angles"] == c}
                    cells.append(f"{by['pixel']['psnr_exact']:.1f} / {by['camera']['psnr_exact']:.1f}"
                                 if by else "")
                mem = [r for r in acc if r["material"] == mat and r["angles"] == 4]
                rows.append([obj, mat, *cells, f"{mem[0]['texture_bytes'] / 2**20:.1f}" if mem else ""])
        lines += common.markdown_table(["object", "material", *[f"{c} angles" for c in counts], "MiB at 4 angles"],
                                       rows)
    tol = [r for r in records if r["part"] == "tolerance"]
    if tol:
        lines += ["", "Angle count chosen by `from_material(tolerance=…)` (relative RMS error of the sphere)", ""]
        lines += common.markdown_table(["material", "tolerance", "angles", "error"],
                                       [[r["material"], r["tolerance"], r["angles"],
                                         f"{r['error']:.4f}" if r["error"] is not None else "none meets it"]
                                        for r in tol])
    fr = [r for r in records if r["part"] == "frames"]
    if fr:
        lines += ["", "Frame: G-buffer + 1 shadow ray a light + shading; unshadowed: G-buffer + shading (the "
                  "paper's frame); device-resident medians", ""]
        lines += common.markdown_table(["backend", "device", "size", "lights", "frame ms (fps)", "unshadowed ms (fps)",
                                        "shading ms (fps)", "textures MiB"],
                                       [[r["backend"], r["device"], f"{r['width']}x{r['height']}", r["lights"],
                                         f"{r['frame_s'] * 1e3:.3f} ({r['fps']:.0f})",
                                         f"{r['unshadowed_s'] * 1e3:.3f} ({r['unshadowed_fps']:.0f})",
                                         f"{r['shade_s'] * 1e3:.3f} ({r['shade_fps']:.0f})",
                                         f"{r['texture_bytes'] / 2**20:.1f}"] for r in fr])
    tx = [r for r in records if r["part"] == "texels"]
    if tx:
        lines += ["", f"`LitSphere.from_material` ({tx[0]['angles']} angles, {tx[0]['resolution']}², both parts): the "
                  "host's float64 images against the backend's texel kernels (median, call whole)", ""]
        lines += common.markdown_table(["backend", "material", "host ms", "backend ms", "speed-up",
                                        "largest difference / largest texel"],
                                       [[r["backend"], r["material"], f"{r['host_s'] * 1e3:.1f}",
                                         f"{r['device_s'] * 1e3:.2f}", f"{r['host_s'] / r['device_s']:.0f}x",
                                         f"{r['max_diff_rel']:.1e}"] for r in tx])
    return "\n".join(lines) + "\n"


def plot(records, folder):
    acc = [r for r in records if r["part"] == "accuracy" and r["object"] == "sphere"]
    if not acc:
        return
    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for mat in dict.fromkeys(r["material"] for r in acc):
        for view, style in (("pixel", "-o"), ("camera", ":x")):
            rs = sorted((r for r in acc if r["material"] == mat and r["view"] == view), key=lambda r: r["angles"])
            ax.plot([r["texture_bytes"] / 2**20 for r in rs], [r["psnr_exact"] for r in rs], style,
                    label=f"{mat} ({view})")
    ax.axhline(35, color="grey", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("texture memory (MiB; points: 2, 3, 4, 6, 8 … angles)")
    ax.set_ylabel("PSNR against the exact render (dB)")
    ax.set_title("Lit sphere: error against memory (sphere, one light)")
    ax.legend(fontsize=6.5, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "litsphere.png"), dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=None, help="backend names (default: every usable backend here)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--parts", nargs="+", default=["accuracy", "tolerance", "frames", "texels"])
    ap.add_argument("--quick", action="store_true", help="a CPU: 256² accuracy images, a 512² frame")
    ap.add_argument("--counts", type=int, nargs="+", default=[2, 3, 4, 6, 8], help="light-angle counts")
    ap.add_argument("--resolution", type=int, default=512, help="lit-sphere image resolution")
    ap.add_argument("--tolerances", type=float, nargs="+", default=[0.1, 0.05, 0.02])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, default=10)
    args = ap.parse_args(argv)
    backends = common.backend_names(args.backends)
    acc_size, frame_size = ((256, 256), (512, 512)) if args.quick else ((512, 512), (1920, 1080))
    out = common.Output(args.out, common.run_meta(
        backends=backends, device_kind=", ".join(sorted({wb.get_backend(b).device for b in backends}))))
    if "accuracy" in args.parts:
        part_accuracy(backends[0], acc_size, args.counts, args.resolution, out)
        out.save(table)
    if "tolerance" in args.parts:
        part_tolerance(backends[0], 256, args.tolerances, out)
        out.save(table)
    if "frames" in args.parts:
        part_frames(backends, frame_size, args.resolution, 3 if args.quick else args.frames, args.runs, out)
        out.save(table)
    if "texels" in args.parts:
        part_texels(backends, args.resolution, args.runs, out)
    out.finish(table)
    plot(out.records, args.out)
    out.log(f"wrote {args.out}/results.json, table.md, litsphere.png")


if __name__ == "__main__":
    main()
