"""The command line as a user runs it: a real subprocess, a real PNG read back."""

import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import warp_biscale as wb


def _console_script():
    import shutil

    exe = shutil.which("warp-biscale", path=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    assert exe, "the warp-biscale console script is not installed next to this Python"
    return exe


def run_cli(*args):
    """The installed console script, run from a scratch directory (never the source checkout)."""
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        return subprocess.run([_console_script(), *args], capture_output=True, text=True, cwd=scratch,
                              timeout=600)


def test_truth_builtin_tile_writes_plot_and_table(tmp_path):
    out = tmp_path / "plot.png"
    npz = tmp_path / "gt.npz"
    r = run_cli("truth", "vgroove", "--facets", "4096", "--directions", "6", "--backend", "warp:cpu",
                "--brdf", "blinnphong:exponent=64,ks=0.8,kd=0.1", "-o", str(out), "--save", str(npz))
    assert r.returncode == 0, r.stderr
    assert "θi \\ θo" in r.stdout and "directional albedo" in r.stdout
    assert "effective BRDF" in r.stderr  # progress lines
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape[0] > 300 and img.shape[1] > 600
    assert img.std() > 10  # a real plot, not a blank canvas
    gt = wb.load(npz)
    assert gt.directions == 6 and gt.facets == 4096 and gt.tile.startswith("grooves(v")


def test_truth_mesh_file(tmp_path):
    import trimesh
    from conftest import random_heightfield

    tile = random_heightfield(n=4)
    trimesh.Trimesh(tile.vertices, tile.faces, process=False).export(tmp_path / "hf.obj")
    r = run_cli("truth", str(tmp_path / "hf.obj"), "--facets", "1024", "--directions", "4",
                "--backend", "warp:cpu", "-q", "-o", str(tmp_path / "p.png"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "p.png").exists()


@pytest.mark.parametrize("args, message", [
    (["truth", "no_such_tile"], "neither a mesh file nor a built-in tile"),
    (["truth", "flat", "--brdf", "glass"], "unknown BRDF 'glass'"),
    (["truth", "flat", "--brdf", "ward:alpha=-1"], "Ward.alpha must be a finite number > 0"),
    (["truth", "flat", "--facets", "0"], "facets must be an integer"),
    (["truth", "flat", "--backend", "metal"], "unknown backend"),
])
def test_truth_errors_are_clear(tmp_path, args, message):
    r = run_cli(*args, "-o", str(tmp_path / "x.png"))
    assert r.returncode != 0
    assert message in r.stderr
    assert not (tmp_path / "x.png").exists()


def test_backends_command_lists_warp_cpu():
    r = run_cli("backends")
    assert r.returncode == 0
    assert "warp:cpu" in r.stdout


def test_help_lists_commands():
    r = run_cli("--help")
    assert r.returncode == 0 and "truth" in r.stdout and "backends" in r.stdout


def test_bake_writes_a_material_file_that_loads(tmp_path):
    out = tmp_path / "m.wbm"
    r = run_cli("bake", "vgroove", "--facets", "4096", "--directions", "6", "--backend", "warp:cpu",
                "--brdf", "cooktorrance:roughness=0.2,ks=0.9,kd=0.1", "--lobes", "auto", "--truth", "8192",
                "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "lobes (NDF fit error" in r.stdout and "PSNR" in r.stdout and "MiB per material" in r.stdout
    assert "amplitudes" in r.stderr  # progress lines
    mat = wb.load(out)
    assert isinstance(mat, wb.EffectiveBRDF) and mat.directions == 6 and len(mat.lobes) == 2
    assert mat.materials == [wb.CookTorrance(0.9, 0.2, kd=0.1)]


def test_bake_bad_input_is_named(tmp_path):
    r = run_cli("bake", "pyramid", "--lobes", "lots", "-o", str(tmp_path / "m.wbm"))
    assert r.returncode == 2 and "--lobes must be an integer or 'auto'" in r.stderr
    r = run_cli("bake", "pyramid", "--brdf", "phong:exponent=-1", "-o", str(tmp_path / "m.wbm"))
    assert r.returncode == 2 and "exponent" in r.stderr
    assert not (tmp_path / "m.wbm").exists()
