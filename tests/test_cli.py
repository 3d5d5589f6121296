"""The command line as a user runs it: a real subprocess, a real PNG read back."""

import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import warp_biscale as wb
from warp_biscale import cli


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


def run_cli_in_process(capsys, *args):
    """The command in this process (`cli.main`), for tests of a command's options and errors: → its return code,
    stdout and stderr as run_cli's result has them, the warnings it gave written to stderr as the console script
    writes them (after the rest). A subprocess costs ~1.5 s to start and ~5 s more to load the kernels; the
    console script itself runs as a subprocess in this file's other tests (the quiet, view, help, version and
    backends listing tests)."""
    import warnings
    from types import SimpleNamespace

    from warp_biscale import cli

    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            code = cli.main([str(a) for a in args])
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code
    out = capsys.readouterr()
    said = "".join(f"warning: {w.message}\n" for w in caught)
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err + said)


def test_truth_builtin_tile_writes_plot_and_table(tmp_path, capsys):
    out = tmp_path / "plot.png"
    npz = tmp_path / "gt.npz"
    r = run_cli_in_process(capsys, "truth", "vgroove", "--facets", "4096", "--directions", "6", "--backend", "warp:cpu",
                           "--brdf", "blinnphong:exponent=64,ks=0.8,kd=0.1", "-o", str(out), "--save", str(npz))
    assert r.returncode == 0, r.stderr
    assert "θi \\ θo" in r.stdout and "directional albedo" in r.stdout
    assert "effective BRDF" in r.stderr  # progress lines
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape[0] > 300 and img.shape[1] > 600
    assert img.std() > 10  # a real plot, not a blank canvas
    gt = wb.load(npz)
    assert gt.directions == 6 and gt.facets == 4096 and gt.tile.startswith("grooves(v")


def test_truth_mesh_file(tmp_path, capsys):
    import trimesh
    from conftest import random_heightfield

    tile = random_heightfield(n=4)
    trimesh.Trimesh(tile.vertices, tile.faces, process=False).export(tmp_path / "hf.obj")
    r = run_cli_in_process(capsys, "truth", str(tmp_path / "hf.obj"), "--facets", "1024", "--directions", "4",
                           "--backend", "warp:cpu", "-q", "-o", str(tmp_path / "p.png"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "p.png").exists()


@pytest.mark.parametrize("args, message", [
    (["truth", "no_such_tile"], "tile 'no_such_tile' is neither a mesh file"),
    (["truth", "flat", "--brdf", "glass"], "unknown BRDF 'glass'"),
    (["truth", "flat", "--brdf", "ward:alpha=-1"], "Ward.alpha must be a finite number > 0"),
    (["truth", "flat", "--facets", "0"], "facets must be an integer"),
    (["truth", "flat", "--backend", "metal"], "--backend: unknown backend 'metal'"),
    (["truth", "flat", "--seed", "-3"], "--seed must be an integer >= 0, got -3"),
    (["bake", "flat", "--seed", "-1"], "--seed must be an integer >= 0, got -1"),
    (["truth", "flat", "--brdf", "lambert:albedo=0.5,albedo=0.7"], "BRDF parameter 'albedo' is given twice"),
])
def test_truth_errors_are_clear(tmp_path, args, message, capsys):
    out = tmp_path / ("x.png" if args[0] == "truth" else "x.wbm")
    r = run_cli_in_process(capsys, *args, "-o", str(out))
    assert r.returncode == 2
    assert message in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not out.exists()


def test_truth_says_why_an_albedo_exceeds_the_small_scale_one(tmp_path, capsys):
    """With bounces the table's albedo carries the Monte Carlo paths' noise (docs/design.md §4.6), which a finer
    grid does not remove: the note under the table names it, not the grid's quadrature alone."""
    args = ["truth", "vgroove", "--facets", "1024", "--directions", "4", "--backend", "warp:cpu", "--brdf",
            "lambert:albedo=0.8", "-o", str(tmp_path / "p.png")]
    r = run_cli_in_process(capsys, *args, "--bounces", "2", "--paths", "64")
    assert r.returncode == 0, r.stderr
    note = next(line for line in r.stdout.splitlines() if line.startswith("directional albedo"))
    assert "Monte Carlo estimate from 64 paths" in note and "more --paths" in note, note
    r = run_cli_in_process(capsys, *args)
    assert r.returncode == 0, r.stderr
    note = next(line for line in r.stdout.splitlines() if line.startswith("directional albedo"))
    assert "quadrature error" in note and "Monte Carlo" not in note and "above 1" not in note, note


def test_backends_command_lists_warp_cpu(capsys):
    r = run_cli("backends")
    assert r.returncode == 0
    assert "warp:cpu" in r.stdout and "usable" in r.stdout and "auto picks" in r.stdout
    assert "Warp CUDA warning" not in r.stderr  # said once, in the listing, instead
    r = run_cli_in_process(capsys, "backends", "-q", "--require", "warp:cpu")
    assert r.returncode == 0 and r.stdout == "" and r.stderr == ""


def test_backends_require_refuses_an_unknown_kind(capsys, monkeypatch):
    """An unknown kind is a bad argument (2, naming the kinds there are), not a missing backend (1)."""
    for kind in ("metal", "warp:tpu"):
        r = run_cli_in_process(capsys, "backends", "-q", "--require", kind)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith(f"error: --require {kind!r}: the kinds are warp and opencl"), r.stderr
    # a known kind that no usable backend has: exit 1 (this machine stood for by one usable Warp CPU device)
    monkeypatch.setattr(cli, "backends", lambda: [{"name": "warp:cpu", "kind": "warp", "device": "CPU",
                                                    "type": "cpu", "usable": True, "reason": ""}])
    r = run_cli_in_process(capsys, "backends", "-q", "--require", "opencl:gpu")
    assert r.returncode == 1 and r.stderr == "error: no usable opencl:gpu backend here\n", r.stderr


def test_help_lists_commands():
    r = run_cli("--help")
    assert r.returncode == 0 and "truth" in r.stdout and "backends" in r.stdout


def test_bake_writes_a_material_file_that_loads(tmp_path, capsys):
    out = tmp_path / "m.wbm"
    r = run_cli_in_process(capsys, "bake", "vgroove", "--facets", "4096", "--directions", "6", "--backend", "warp:cpu",
                           "--brdf", "cooktorrance:roughness=0.2,ks=0.9,kd=0.1", "--lobes", "auto", "--truth", "8192",
                           "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "lobes (NDF fit error" in r.stdout and "PSNR" in r.stdout and "MiB per material" in r.stdout
    assert "amplitudes" in r.stderr  # progress lines
    mat = wb.load(out)
    assert isinstance(mat, wb.EffectiveBRDF) and mat.directions == 6 and len(mat.lobes) == 2
    assert mat.materials == [wb.CookTorrance(0.9, 0.2, kd=0.1)]


@pytest.mark.parametrize("method", ["asg", "matrix"])
def test_bake_other_methods(tmp_path, method, capsys):
    """`bake --method asg` (with --lobes auto) and `--method matrix` write material files of their kind."""
    out = tmp_path / "m.wbm"
    lobes = ["--lobes", "auto"] if method == "asg" else []
    r = run_cli_in_process(capsys, "bake", "vgroove", "--facets", "2048", "--directions", "4", "--backend", "warp:cpu",
                           "--method", method, *lobes, "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert ("2 ASG lobes (NDF fit error" in r.stdout) == (method == "asg") and "MiB per material" in r.stdout
    assert isinstance(wb.load(out), {"asg": wb.ASGBRDF, "matrix": wb.MatrixBRDF}[method])


def test_bake_method_auto_says_what_it_chose(tmp_path, capsys):
    """`bake --method auto` prints the method it kept with both PSNRs and writes that material; the file keeps the
    choice in its info."""
    out = tmp_path / "m.wbm"
    r = run_cli_in_process(capsys, "bake", "ugroove", "--facets", "2048", "--directions", "4", "--lobes", "2",
                           "--backend", "warp:cpu", "--brdf", "blinnphong:exponent=512,ks=1", "--method", "auto",
                           "-o", str(out))
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stdout.splitlines() if line.startswith("method auto: ")]
    assert len(said) == 1 and "SG " in said[0] and "ASG " in said[0] and " dB" in said[0]
    mat = wb.load(out)
    chosen = mat.info["method_choice"]["chosen"]
    assert said[0].startswith(f"method auto: {chosen.upper()} (") and getattr(mat, "method", None) == chosen


def test_bake_takes_a_merl_file(tmp_path, capsys):
    """`--brdf` takes a MERL table file as a small-scale BRDF (fitted by the bake, the fit recorded); a missing
    one is named in one line before any work."""
    table = tmp_path / "ct.binary"
    wb.MeasuredBRDF.from_brdf(wb.CookTorrance(0.6, 0.2, kd=0.2)).save(table)
    out = tmp_path / "m.wbm"
    r = run_cli_in_process(capsys, "bake", "pyramid", "--facets", "1024", "--directions", "4", "--lobes", "2",
                           "--backend", "warp:cpu", "--brdf", str(table), "-o", str(out))
    assert r.returncode == 0, r.stderr
    mat = wb.load(out)
    assert isinstance(mat.materials[0], wb.MeasuredBRDF) and "sg_fit" in mat.info
    assert cli.main(["bake", "pyramid", "--brdf", str(tmp_path / "none.binary"), "-o", str(tmp_path / "n.wbm")]) == 2
    err = capsys.readouterr().err
    assert "no such MERL BRDF file" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "n.wbm").exists()


def test_bake_bad_input_is_named(tmp_path, capsys):
    # (in-process, `cli.main`: the console script's own exit codes are checked by the tests above and below)
    for args, message in ((["--lobes", "lots"], "--lobes must be an integer or 'auto'"),
                          (["--brdf", "phong:exponent=-1"], "exponent"),
                          (["--method", "matrix", "--lobes", "4"], "--method matrix takes no --lobes")):
        assert cli.main(["bake", "pyramid", *args, "-o", str(tmp_path / "m.wbm")]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "m.wbm").exists()


# ------------------------------------------------------------------------------------------------ render, demo, view
# Tiny images: a 2-core CI runs the whole suite in minutes.

TINY_SCENE = """\
[render]
width = 32
height = 24
backend = "warp:cpu"

[camera]
eye = [0.0, 1.5, 4.0]
target = [0.0, 0.4, 0.0]
fov = 35

[environment]
type = "sky"
height = 16
width = 32
supersample = 1

[[light]]
type = "point"
position = [2.0, 3.0, 2.0]
intensity = 10.0

[[object]]
mesh = "sphere"
radius = 0.6
center = [0.0, 0.6, 0.0]
subdivisions = 2
material = "shiny"

[[object]]
mesh = "plane"
size = 4.0
divisions = 4
material = "floor"

[material.shiny]
type = "blinnphong"
kd = [0.5, 0.2, 0.1]
ks = 0.5
exponent = 100.0

[material.floor]
type = "lambert"
albedo = 0.5
"""


def _tiny_scene(tmp_path, text=TINY_SCENE):
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return p


def test_render_png_with_overrides(tmp_path, capsys):
    out = tmp_path / "out.png"
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path)), "-o", str(out), "--size", "40", "24",
                           "--exposure", "0.5")
    assert r.returncode == 0, r.stderr
    assert "stage times:" in r.stdout and "shade" in r.stdout
    assert f"wrote {out} (40×24 pixels, method sg, backend warp:cpu" in r.stdout
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (24, 40, 3)
    assert img.mean() > 20 and img.std() > 5  # lit, and not one flat colour


def test_render_exr_reads_back_linear(tmp_path):
    from warp_biscale.images import read_exr

    out = tmp_path / "out.exr"
    # (in-process, `cli.main`: test_quiet_means_quiet runs the console script's render)
    assert cli.main(["render", str(_tiny_scene(tmp_path)), "-o", str(out), "--size", "32", "16", "-q"]) == 0
    img = read_exr(out)
    assert img.shape == (16, 32, 3) and img.dtype == np.float32
    assert np.isfinite(img).all() and (img >= 0).all()
    assert img.mean() > 0.01 and img.std() > 0.005


def test_render_monte_carlo(tmp_path, capsys):
    out = tmp_path / "mc.png"
    # (in-process, `cli.main`: test_quiet_means_quiet runs the console script's render)
    assert cli.main(["render", str(_tiny_scene(tmp_path)), "-o", str(out), "--method", "mc", "--samples", "8",
                     "--size", "16", "12"]) == 0
    said = capsys.readouterr().out
    assert "method mc" in said and "Monte Carlo: 8 samples a pixel, standard error (RMS over the hit pixels) " in said
    assert np.asarray(Image.open(out)).shape == (12, 16, 3)


def test_render_refuses_an_exposure_for_a_file_of_radiance(tmp_path, capsys):
    """--exposure scales a PNG's tone mapping: for an EXR or HDR, which keep the radiance, it is refused in one line
    (it would do nothing), before the scene loads."""
    for name in ("x.exr", "x.hdr"):
        r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path)), "-o", str(tmp_path / name),
                               "--exposure", "1")
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and not (tmp_path / name).exists()
        assert r.stderr.startswith(f"error: --exposure scales a PNG's tone mapping; {tmp_path / name} (EXR/HDR)")


def test_render_bakes_a_bake_material(tmp_path, capsys):
    text = TINY_SCENE.replace('[material.shiny]\ntype = "blinnphong"\nkd = [0.5, 0.2, 0.1]\nks = 0.5\n'
                              'exponent = 100.0',
                              '[material.shiny]\ntype = "bake"\ntile = "vgroove"\nbrdf = "ward:alpha=0.2"\n'
                              'lobes = 2\ndirections = 4\nfacets = 512\nnormal_res = 16')
    out = tmp_path / "b.png"
    # (in-process, `cli.main`: test_quiet_means_quiet runs the console script's render)
    assert cli.main(["render", str(_tiny_scene(tmp_path, text)), "-o", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "baked material 'shiny': tile grooves(" in stdout and "512 facets, 2 lobes, K=4" in stdout
    assert out.exists()


@pytest.mark.parametrize("method, said", [("asg", "2 ASG lobes, K=4"), ("matrix", "512 facets, K=4")])
def test_render_says_what_an_asg_or_matrix_bake_made(tmp_path, capsys, method, said):
    """The bake summary of a scene's ASG or matrix material reads the bake's info, not `lobes` (SG lobes, which
    those materials refuse): the render goes on (the matrix method's by the lit-sphere renderer, which reads it)."""
    text = BAKED_SCENE.replace("normal_res = 16", f'normal_res = 16\nmethod = "{method}"')
    if method == "matrix":
        text = text.replace("lobes = 2\n", "")
    out = tmp_path / "b.png"
    extra = ["--method", "litsphere"] if method == "matrix" else []
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path, text)), "-o", str(out), *extra)
    assert r.returncode == 0, r.stderr
    assert "baked material 'shiny': tile grooves(" in r.stdout and said in r.stdout
    assert out.exists()


def test_render_refuses_a_matrix_bake_for_the_sg_renderer_before_baking(tmp_path, capsys, monkeypatch):
    """The SG renderer cannot shade a matrix bake: said in one line naming the material, before any bake (by the
    file's method, or by --method sg over a file that renders by the lit-sphere shader)."""
    from warp_biscale import scenefile

    def no_bake(*args, **kwargs):
        raise AssertionError("baked before the scene was checked")

    monkeypatch.setattr(scenefile, "bake", no_bake)
    text = BAKED_SCENE.replace("lobes = 2\n", "").replace("normal_res = 16", 'normal_res = 16\nmethod = "matrix"')
    out = tmp_path / "b.png"
    for extra in ([], ["--method", "sg"]):
        litsphere = text.replace("[render]\n", '[render]\nmethod = "litsphere"\n')
        scene = _tiny_scene(tmp_path, litsphere if extra else text)
        r = run_cli_in_process(capsys, "render", str(scene), "-o", str(out), *extra)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "[material.shiny] the SG renderer cannot shade a matrix bake" in r.stderr
        assert "render this scene by method 'litsphere'" in r.stderr and not out.exists()
        assert "'mc'" not in r.stderr  # (which refuses a glossy matrix bake too: not offered)
    # and the Monte Carlo reference, which samples the glossy small-scale BRDF (Ward here) by lobes it has not
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path, text)), "-o", str(tmp_path / "m.exr"),
                           "--method", "mc", "--samples", "8")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "[material.shiny] the Monte Carlo reference samples a glossy small-scale BRDF" in r.stderr


BAKED_SCENE = TINY_SCENE.replace('[material.shiny]\ntype = "blinnphong"\nkd = [0.5, 0.2, 0.1]\nks = 0.5\n'
                                 'exponent = 100.0',
                                 '[material.shiny]\ntype = "bake"\ntile = "vgroove"\nbrdf = "ward:alpha=0.2"\n'
                                 'lobes = 2\ndirections = 4\nfacets = 512\nnormal_res = 16')


@pytest.mark.parametrize("edit, args, message", [
    (None, ["--method", "mc", "--samples", "1"],
     "error: --samples must be at least 2 for the Monte Carlo reference (2 a sampling strategy), got 1"),
    (("height = 24\n", 'height = 24\nmethod = "mc"\nsamples = 1\n'), [],
     "scene.toml:5: [render] samples must be at least 2 for the Monte Carlo reference"),
    # the floor the file shows (its sky's 2 strategies and its light's, 2 samples each), before the bake
    (None, ["--method", "mc", "--samples", "4"],
     "error: --samples 4 is too few for the Monte Carlo reference of this scene: at least 6, 2 for each sampling "
     "strategy (its environment's 2 and its 1 light; a glossy material's BRDF adds 2)"),
    (("height = 24\n", 'height = 24\nmethod = "mc"\nsamples = 5\n'), [],
     "error: [render] samples = 5 is too few for the Monte Carlo reference of this scene: at least 6"),

    (None, ["--backend", "nope"], "error: --backend: unknown backend 'nope'"),
    (None, ["--truth-facets", "256"], "error: --truth-facets is for --method mc"),
    (("albedo = 0.5\n", 'albedo = 0.5\nkd_map = "kd.png"\n'), ["--method", "litsphere"],
     "error: the lit-sphere method (--method litsphere) cannot shade textured materials: material 'floor' has "
     "kd_map"),
])
def test_render_refuses_bad_options_before_baking(tmp_path, edit, args, message, capsys):
    """What an option needs of the scene is checked on the scene file before its materials are baked: one
    line, exit 2, no bake's progress."""
    text = BAKED_SCENE if edit is None else BAKED_SCENE.replace(*edit)
    assert edit is None or BAKED_SCENE.count(edit[0]) == 1
    Image.fromarray(np.full((4, 4, 3), 128, np.uint8)).save(tmp_path / "kd.png")
    out = tmp_path / "x.png"
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path, text)), "-o", str(out), *args)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert r.stdout == "" and not out.exists()


@pytest.mark.parametrize("edit, args, message", [
    (("fov = 35", "fvo = 35"), [], "scene.toml:9: [camera] unknown key 'fvo'"),
    (('material = "floor"', 'material = "flor"'), [], "[[object]] #2 material 'flor' is not defined"),
    (("exponent = 100.0", "exponent = -3"), [], "[material.shiny] BlinnPhong.exponent must be a finite number > 0"),
    (None, ["--samples", "4"], "--samples is for --method mc"),
    (("radius = 0.6", "radius = -0.8"), [], "scene.toml:24: [[object]] #1 Mesh.sphere radius must be > 0, got -0.8"),
    (("width = 32\n", "width = 32\nenv_lobes = 32\n"), [],
     "scene.toml:3: [render] env_lobes must be an integer in 1..16"),
    (("width = 32\n", "width = 32\nexposure = -99\n"), [], "scene.toml:3: [render] exposure -99 stops would turn"),
    (None, ["--size", "0"], "--size values must be integers in 1..16384, got 0"),
    (None, ["--size", "40", "30", "20"], "--size takes a width and an optional height"),
])
def test_render_errors_are_clear(tmp_path, edit, args, message, capsys):
    text = TINY_SCENE if edit is None else TINY_SCENE.replace(*edit)
    out = tmp_path / "x.png"
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path, text)), "-o", str(out), *args)
    assert r.returncode == 2
    assert message in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_render_refuses_unknown_extension_and_missing_file(tmp_path, capsys):
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path)), "-o", str(tmp_path / "x.jpg"))
    assert r.returncode != 0 and "must end in .png, .exr, .hdr" in r.stderr
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path)), "-o", str(tmp_path / ".png"))
    assert r.returncode == 2 and r.stderr.endswith(".png' has no name before its .png\n"), r.stderr
    r = run_cli_in_process(capsys, "render", str(tmp_path / "none.toml"))
    assert r.returncode != 0 and "no such scene file" in r.stderr


def test_demo_writes_a_png(tmp_path, capsys):
    out = tmp_path / "demo.png"
    r = run_cli_in_process(capsys, "demo", "--size", "48", "-o", str(out), "--backend", "warp:cpu")
    assert r.returncode == 0, r.stderr
    assert "baked material 'demo_tile': tile pyramid(" in r.stdout
    assert "demo done in" in r.stdout and str(out) in r.stdout
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (36, 48, 3)
    assert img.std() > 10 and len(np.unique(img.reshape(-1, 3), axis=0)) > 50


@pytest.mark.parametrize("args, message", [
    (["demo", "--backend", "nope"], "error: --backend: unknown backend 'nope'"),
    (["demo", "--size", "0"], "error: --size values must be integers in 1..16384, got 0"),
    # (the spec's energy warning comes with loading it: the size is refused before)
    (["ball", "blinnphong:exponent=50,ks=2", "--size", "0"], "error: --size must be an integer in 8..8192, got 0"),
    # (0 facets ran no truth and said nothing)
    (["bake", "pyramid", "--truth", "0"], "error: --truth facets must be an integer in [1, 67108864], got 0"),
    # (the SG renderer's ray options with --method litsphere, whose shader traces no such rays)
    (["render", "SCENE", "--method", "litsphere", "--occlusion-samples", "4"],
     "error: --occlusion-samples is for the SG renderer (--method sg); the lit-sphere shader traces no occlusion rays"),
    # (an anisotropic BRDF: ball has no method option, so the message points to `render`)
    (["ball", "ward:alpha_x=0.1,alpha_y=0.4"], "error: AnisotropicWard is anisotropic: a lit sphere, one value per "
                                               "normal, cannot hold it; show it on a scene's object with "
                                               "`warp-biscale render`"),
])
def test_bad_options_are_refused_before_loading_or_baking(tmp_path, args, message, capsys):
    out = tmp_path / "x.png"
    args = [str(_tiny_scene(tmp_path, BAKED_SCENE)) if a == "SCENE" else a for a in args]
    r = run_cli_in_process(capsys, *args, "-o", str(out))
    assert r.returncode == 2 and r.stderr.startswith(message) and r.stderr.count("\n") == 1, r.stderr
    assert r.stdout == "" and not out.exists()


@pytest.mark.parametrize("size, frame", [(["160", "120"], (160, 120)), (["160"], (160, 120)),
                                         (["160x120"], (160, 120)), ([], (640, 480))])
def test_edit_takes_size_as_the_other_commands_do(size, frame, capsys, monkeypatch):
    """`edit --size W [H]` as render, demo and view take it (and the WxH it took first); the editor itself is
    stood for by a stub, so no window opens."""
    from warp_biscale import editor_gui

    got = {}
    monkeypatch.setattr(editor_gui, "edit", lambda target, **kw: got.update(kw))
    args = ["--size", *size] if size else []
    assert cli.main(["edit", "pyramid", "--backend", "warp:cpu", *args]) == 0, capsys.readouterr().err
    assert got["size"] == frame


@pytest.mark.parametrize("size", [["8"], ["160", "120", "90"], ["160x"], ["big"]])
def test_edit_refuses_a_bad_size(size, capsys, monkeypatch):
    from warp_biscale import editor_gui

    monkeypatch.setattr(editor_gui, "edit", lambda target, **kw: pytest.fail("the editor was started"))
    assert cli.main(["edit", "pyramid", "--size", *size]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --size must be WIDTH [HEIGHT] (or WIDTHxHEIGHT), each in 16..8192 pixels") and \
        err.count("\n") == 1, err
    assert err.endswith(f"got {' '.join(size)!r}\n"), err  # (what was typed)


def test_edit_takes_its_target_after_size(capsys, monkeypatch):
    """`edit --size 640x480 pyramid` (the size before TARGET, as the command took it when --size was one WxH):
    --size's list of values swallows TARGET, which is taken back; no TARGET at all is one line."""
    from warp_biscale import editor_gui

    got = {}
    monkeypatch.setattr(editor_gui, "edit", lambda target, **kw: got.update(kw, target=target))
    assert cli.main(["edit", "--size", "320x240", "woven", "--backend", "warp:cpu"]) == 0, capsys.readouterr().err
    assert got == {**got, "target": "woven", "size": (320, 240)}
    assert cli.main(["edit", "--size", "320", "240", "rods", "--backend", "warp:cpu"]) == 0
    assert got["target"] == "rods" and got["size"] == (320, 240)
    assert cli.main(["edit", "--size", "320"]) == 2
    assert capsys.readouterr().err.startswith("error: edit needs a TARGET")


def test_view_screenshot_offscreen(tmp_path):
    out = tmp_path / "view.png"
    r = run_cli("view", str(_tiny_scene(tmp_path)), "--screenshot", str(out), "--size", "96", "48",
                "--render-scale", "0.5")
    assert r.returncode == 0, r.stderr
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (48, 96, 3) and img[:, :48].std() > 5 and img[:, 48:].std() > 5


def test_view_without_a_display_says_so(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([_console_script(), "view", str(_tiny_scene(tmp_path))], capture_output=True, text=True,
                       cwd=tmp_path, env=env, timeout=600)
    assert r.returncode == 1  # a failure of this machine, not of the input
    assert "no display" in r.stderr and "--screenshot" in r.stderr and "Traceback" not in r.stderr


def test_version_and_module_entry_point():
    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"warp-biscale {wb.__version__}"
    r = subprocess.run([sys.executable, "-m", "warp_biscale", "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f"warp-biscale {wb.__version__}"


def _unwritable_dir(tmp_path):
    """A folder in which this user can create no file: one without write permission, or for root (whom
    permissions do not stop) /proc, where no file can be created."""
    if os.geteuid() == 0:
        return "/proc"
    d = tmp_path / "locked"
    d.mkdir()
    d.chmod(0o500)
    return str(d)


# Every command that writes a file, with arguments that would otherwise compute for seconds.
WRITERS = {
    "render": lambda scene, out: ["render", scene, "-o", out],
    "demo": lambda scene, out: ["demo", "-o", out],
    "view": lambda scene, out: ["view", scene, "--screenshot", out],
    "bake": lambda scene, out: ["bake", "pyramid", "-o", out],
    "truth": lambda scene, out: ["truth", "pyramid", "-o", out],
    "truth --save": lambda scene, out: ["truth", "pyramid", "-o", os.path.join(os.path.dirname(scene), "p.png"),
                                        "--save", out],
}
GOOD_SUFFIX = {"render": ".png", "demo": ".png", "view": ".png", "bake": ".wbm", "truth": ".png",
               "truth --save": ".npz"}


@pytest.mark.parametrize("case", ["directory", "unwritable folder", "folder is a file", "unknown suffix"])
@pytest.mark.parametrize("command", list(WRITERS))
def test_unwritable_output_is_refused_before_any_work(tmp_path, command, case, capsys):
    scene = str(_tiny_scene(tmp_path))
    suffix = GOOD_SUFFIX[command]
    (tmp_path / "afile").write_text("x")
    out = {"directory": str(tmp_path),
           "unwritable folder": os.path.join(_unwritable_dir(tmp_path), "sub", "out" + suffix),
           "folder is a file": str(tmp_path / "afile" / ("out" + suffix)),
           "unknown suffix": str(tmp_path / "out.txt")}[case]
    r = run_cli_in_process(capsys, *WRITERS[command](scene, out))
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("error: ") and out in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert "done in" not in r.stderr and r.stdout == ""  # refused before the first stage


@pytest.mark.parametrize("exposure, message", [
    ("nan", "exposure must be a finite number of stops, got nan"),
    ("inf", "exposure must be a finite number of stops, got inf"),
    ("-40", "exposure -40 stops would turn the whole image black"),
    ("40", "exposure 40 stops would turn the whole image white"),
])
def test_bad_exposure_is_refused_before_rendering(tmp_path, exposure, message, capsys):
    out = tmp_path / "x.png"
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path)), "-o", str(out), f"--exposure={exposure}")
    assert r.returncode == 2 and message in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not out.exists()


def test_quiet_means_quiet(tmp_path):
    # (the tiny scene's Blinn–Phong reflects up to 2.4× what it receives: its EnergyWarning is not chatter, and
    # is said even with -q; this one is physical, 0.5 + 0.1 × 3.85 <= 1)
    physical = _tiny_scene(tmp_path, TINY_SCENE.replace("\nks = 0.5\n", "\nks = 0.1\n"))
    for args in (["render", str(physical), "-o", str(tmp_path / "r.png")],
                 ["bake", "vgroove", "--facets", "1024", "--directions", "4", "--lobes", "2", "--truth", "1024",
                  "-o", str(tmp_path / "m.wbm")],
                 ["truth", "vgroove", "--facets", "1024", "--directions", "4", "-o", str(tmp_path / "t.png")]):
        r = run_cli(*args, "--backend", "warp:cpu", "-q")
        assert r.returncode == 0 and r.stdout == "" and r.stderr == "", (args, r.stdout, r.stderr)


def test_ball_of_a_saved_lit_sphere_refuses_resolution_and_angles(tmp_path, capsys):
    """A saved lit-sphere folder is drawn as it was saved: --resolution or --angles, which only a material made
    into a lit sphere here takes, is refused in one line rather than silently ignored; without them it draws."""
    folder = tmp_path / "ls"
    wb.LitSphere.from_material(wb.Lambert(0.5), resolution=32, angles=[0, 60], backend="warp:cpu").save(folder)
    out = tmp_path / "b.png"
    r = run_cli_in_process(capsys, "ball", str(folder), "--resolution", "128", "-o", str(out), "--backend", "warp:cpu")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and not out.exists(), r.stderr
    assert f"error: --resolution: {folder} is a saved lit sphere, drawn at its own resolution (32) and angles (0, 60)" \
        in r.stderr
    r = run_cli_in_process(capsys, "ball", str(folder), "--size", "16", "-o", str(out), "--backend", "warp:cpu")
    assert r.returncode == 0 and out.exists(), r.stderr


@pytest.mark.parametrize("args, message", [
    (["view", "nosuch.toml"], "error: no such scene file: nosuch.toml"),
    (["view", "SCENE", "--render-scale", "2"], "error: --render-scale must be in (0, 1], got 2"),
    (["edit", "nosuchfamily"], "error: Editor target 'nosuchfamily' is neither a tile family"),
])
def test_view_and_edit_say_a_bad_argument_before_a_missing_display(tmp_path, args, message, capsys, monkeypatch):
    """Without a display, a bad argument is still a bad argument (exit 2, its own message), not "no display"."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    args = [str(_tiny_scene(tmp_path)) if a == "SCENE" else a for a in args]
    r = run_cli_in_process(capsys, *args)
    assert r.returncode == 2 and r.stderr.startswith(message) and r.stderr.count("\n") == 1, r.stderr


def test_mc_samples_floor_skips_a_black_environment(tmp_path, capsys):
    """A black environment is not sampled by the Monte Carlo reference, so the file's floor counts its light alone
    (2): --samples 2 passes it, and the reference itself then asks 4 of the shiny material (its BRDF and the light)."""
    text = TINY_SCENE.replace('type = "sky"\n', 'type = "constant"\nradiance = [0, 0, 0]\n')
    text = text.replace("supersample = 1\n", "")
    r = run_cli_in_process(capsys, "render", str(_tiny_scene(tmp_path, text)), "-o", str(tmp_path / "x.exr"),
                           "--method", "mc", "--samples", "2")
    assert r.returncode == 2 and "of this scene" not in r.stderr, r.stderr
    assert "samples=2 is too few for material" in r.stderr and "give at least 4" in r.stderr, r.stderr


def test_ctrl_c_during_a_warp_cpu_bake_exits_130_not_a_crash(tmp_path):
    """Warp CPU runs a launch as slices on a thread pool: a Ctrl-C left them running in native code while the
    interpreter freed their arrays (a segmentation fault, 4 times in 4 here). 2^20 facets at K = 24 keep the
    bake in its visibility stage for minutes, so the signal lands among the slices, after the kernels load; the
    running slices end within seconds (a slice holds at most warp_backend.LAUNCH_MAX_ITEMS items)."""
    import signal
    import time

    env = {**os.environ, "WARP_BISCALE_CPU_THREADS": "2"}
    p = subprocess.Popen([_console_script(), "bake", "heightfield", "--facets", str(2 ** 20), "--directions", "24",
                          "--backend", "warp:cpu", "-o", str(tmp_path / "h.wbm")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env)
    time.sleep(10)
    assert p.poll() is None, "the bake ended before the signal"
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 130, (p.returncode, err[-500:])
    assert err.strip().splitlines()[-1] == "interrupted"
    assert not (tmp_path / "h.wbm").exists()
