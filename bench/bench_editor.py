"""Editor benchmark (issue 23): how long a moved control takes to give a new frame (`wb.Editor.set`: the
tile rebuilt, the bake, the render, the frame on the host), per kind of edit.

Edits, each timed whole (the call to `set`, medians over --edits calls that alternate two values):
- ``geometry``: a tile parameter (the pyramid's height) at the editor's full quality (on a GPU 2^16
  facets, K = 12, J = 8; on a CPU its defaults, 2^14 facets, K = 8, J = 8) — re-bakes;
- ``coarse``: the same while a control is dragged (`coarse=True`: a COARSE bake, a 1/4-size frame enlarged);
- ``brdf``: a small-scale BRDF parameter (Blinn–Phong exponent) — new tables from the same bake;
- ``light``: the sun's elevation — the frame only.
Beside each: the bake's and the render's share (`Editor.timings`; the frame is tone-mapped on the device and
read back as 8-bit sRGB within the render's share), the bake's stages, and `Editor.image8` (the frame for
display, already on the host) timed apart.

    python -m bench.bench_editor --out /tmp/editor                                         # this CPU, 640x480
    python -m bench.bench_editor --backends warp:cuda opencl:nvidia --size 1920x1080 --out $OUT   # a GPU
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

import warp_biscale as wb
from warp_biscale.editor import Editor

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import common  # noqa: E402

warnings.filterwarnings("ignore", category=wb.EnergyWarning)

EDITS = {  # edit → (control, the two values it alternates between, coarse)
    "geometry": ("tile.height", (0.45, 0.55), False),
    "coarse": ("tile.height", (0.35, 0.65), True),
    "brdf": ("material0.exponent", (200.0, 300.0), False),
    "light": ("light.elevation", (40.0, 50.0), False),
}


def part_edits(backends, size, edits, out):
    for backend in backends:
        be = wb.get_backend(backend)
        t0 = time.perf_counter()
        ed = Editor("pyramid", backend=be, width=size[0], height=size[1])
        t_open = time.perf_counter() - t0
        quality = {k: ed.get(f"quality.{k}") for k in ("facets_log2", "directions", "lobes")}
        out.log(f"{be.name}: editor open in {t_open:.2f} s (first compile, SSDF and bake); quality {quality}")
        for kind, (name, values, coarse) in EDITS.items():
            ed.set(name, values[1], coarse=coarse)  # warm: this kind of edit's kernels and buffers
            walls, parts = [], []
            for i in range(edits):
                t0 = time.perf_counter()
                ed.set(name, values[i % 2], coarse=coarse)
                walls.append(time.perf_counter() - t0)
                parts.append({**ed.timings, "bake_stages": dict(ed.effective.timings or {})})
            ed.refine()
            t_display = common.timed(ed.image8, 5).median_s
            k = int(np.argsort(walls)[len(walls) // 2])
            rec = {"part": "edits", "backend": be.name, "device": be.device, "width": size[0], "height": size[1],
                   "edit": kind, "control": name, "coarse": coarse, **{f"quality_{q}": v for q, v in quality.items()},
                   "edit_s": float(np.median(walls)), "edit_min_s": float(min(walls)), "edits": edits,
                   "bake_s": parts[k].get("bake", 0.0), "render_s": parts[k].get("render", 0.0),
                   "display_s": t_display, "open_s": t_open,
                   "bake_stages_s": parts[k]["bake_stages"] if kind in ("geometry", "coarse") else {}}
            out.records.append(rec)
            stages = ", ".join(f"{name} {t * 1e3:.2f}" for name, t in rec["bake_stages_s"].items())
            out.log(f"{be.name:<28} {kind:<9} {rec['edit_s'] * 1e3:9.2f} ms (min {rec['edit_min_s'] * 1e3:.2f}; "
                    f"bake {rec['bake_s'] * 1e3:.2f}, render {rec['render_s'] * 1e3:.2f}); "
                    f"image8 {t_display * 1e3:.2f} ms" + (f"; bake stages (ms): {stages}" if stages else ""))


def table(records, meta):
    lines = [f"# Editor benchmark ({meta['device_kind']})", "", common.commit_line(meta), "",
             "A moved control → the new frame on the host (`Editor.set`, median; its bake and render share), "
             "and `Editor.image8` (the frame for display, tone-mapped on the device within the render) apart", ""]
    rows = [[r["backend"], f"{r['width']}x{r['height']}", r["edit"],
             f"2^{r['quality_facets_log2']}, K={r['quality_directions']}, J={r['quality_lobes']}"
             + (" (coarse)" if r["coarse"] else ""),
             f"{r['edit_s'] * 1e3:.2f}", f"{r['bake_s'] * 1e3:.2f}", f"{r['render_s'] * 1e3:.2f}",
             f"{r['display_s'] * 1e3:.2f}"] for r in records if r["part"] == "edits"]
    lines += common.markdown_table(["backend", "frame", "edit", "bake quality", "edit → frame ms", "bake ms",
                                    "render ms", "image8 ms"], rows)
    return "\n".join(lines) + "\n"


def plot(records, folder):
    recs = [r for r in records if r["part"] == "edits"]
    if not recs:
        return
    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    backends = list(dict.fromkeys(r["backend"] for r in recs))
    kinds = list(EDITS)
    width = 0.8 / len(backends)
    for b, name in enumerate(backends):
        ys = [next((r["edit_s"] * 1e3 for r in recs if r["backend"] == name and r["edit"] == k), 0) for k in kinds]
        ax.bar(np.arange(len(kinds)) + b * width, ys, width, label=name)
    ax.set_xticks(np.arange(len(kinds)) + width * (len(backends) - 1) / 2, kinds)
    ax.set_yscale("log")
    ax.set_ylabel("edit → new frame (ms)")
    ax.set_title(f"Editor: a moved control to a new {recs[0]['width']}x{recs[0]['height']} frame")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(os.path.join(folder, "editor.png"), dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", nargs="+", default=None, help="backend names (default: every usable backend here)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--size", default="640x480", help="the frame, WIDTHxHEIGHT")
    ap.add_argument("--edits", type=int, default=10, help="timed edits of each kind")
    args = ap.parse_args(argv)
    try:
        size = tuple(int(v) for v in args.size.lower().split("x"))
        assert len(size) == 2
    except (ValueError, AssertionError):
        ap.error(f"--size must be WIDTHxHEIGHT, got {args.size!r}")
    backends = common.backend_names(args.backends)
    out = common.Output(args.out, common.run_meta(
        backends=backends, device_kind=", ".join(sorted({wb.get_backend(b).device for b in backends}))))
    part_edits(backends, size, args.edits, out)
    out.finish(table)
    try:
        plot(out.records, args.out)
    except ImportError:  # a lent GPU machine may lack matplotlib: plot() can draw results.json elsewhere
        out.log("matplotlib is absent: no editor.png")
    out.log(f"wrote {args.out}/results.json, table.md")


if __name__ == "__main__":
    main()
