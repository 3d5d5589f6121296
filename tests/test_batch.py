"""Batch jobs (warp_biscale.batch, batch_jobs, batch_report): job files become the right tasks, every bad
job file is a one-line error at its file:line before any work, and a run — on a real two-process Dask
LocalCluster, on a running scheduler, or here — writes every output (materials that load, PNGs that read,
a CSV row per task, a contact sheet whose thumbnails exist), records a task that raises (after one retry)
while the rest finish, runs a killed worker's task elsewhere, resumes without redoing finished tasks and
keeps them through Ctrl-C.

Everything is tiny (facets 1024, K = 4, J = 2, 64 × 48 renders with a constant environment) so the file
runs in about a minute on a 2-core CPU; most of that is each fresh worker process's first task (importing
Warp, the renderer's per-process tables and lighting), which a batch pays once per worker.
"""

import argparse
import csv
import json
import os
import shutil
import signal
import textwrap

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import batch, batch_jobs
from warp_biscale.batch_jobs import load_jobs, loads_jobs
from warp_biscale.device import cpu_threads, usable_cores
from warp_biscale.tomlschema import SceneError

try:
    import distributed
except ImportError:  # the job files, reports and in-process runs are tested without Dask all the same
    distributed = None
needs_dask = pytest.mark.skipif(distributed is None, reason="Dask (distributed) is not installed")

EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "examples")

ISSUE_JOB = """\
[bake]
method = "sg"
lobes = 4
facets = 4096
directions = 6
[[tile]]
family = "pyramid"
height = [0.2, 0.4, 0.6]      # a list is a sweep axis
[[tile]]
family = "grooves"
depth = [0.3, 0.5]
[[material]]
brdf = "blinnphong:exponent=128"   # the CLI's --brdf syntax
"""

SCENE = """\
# a sphere (the material slot) on a floor, a constant sky and one point light: a real render, cheap
[render]
width = 64
height = 48
ssdf_resolution = 8
ssdf_terms = 4
env_lobes = 4

[camera]
eye = [0.0, 1.2, 3.5]
target = [0.0, -0.2, 0.0]
fov = 40.0

[environment]
type = "constant"
radiance = 0.4
height = 8
width = 16

[[light]]
type = "point"
position = [2.0, 3.0, 2.0]
intensity = 15.0
radius = 0.1

[[object]]
mesh = "sphere"
subdivisions = 2
material = "tile"

[[object]]
mesh = "plane"
size = 6.0
height = -1.0
divisions = 2
material = "floor"

[material.tile]
type = "lambert"

[material.floor]
type = "lambert"
albedo = 0.4
"""

# 6 tasks: two pyramid heights and one groove, each in a glossy and a matte material
JOB = """\
[bake]
lobes = 2
facets = 1024
directions = 4
normal_res = 16

[compute]
compare = true

[truth]
facets = 2048

[[tile]]
family = "pyramid"
height = [0.3, 0.5]

[[tile]]
family = "grooves"
depth = 0.4

[[material]]
brdf = "blinnphong:exponent=64,ks=0.5,kd=0.2,normalization=energy"

[[material]]
type = "lambert"
albedo = [0.6, 0.5, 0.4]

[[scene]]
path = "scene.toml"
slot = "tile"
name = "tiny"
shadow_samples = 2
"""


def write(folder, name, text):
    path = os.path.join(folder, name)
    with open(path, "w") as fh:
        fh.write(textwrap.dedent(text))
    return path


@pytest.fixture(scope="module")
def job_dir(tmp_path_factory):
    d = str(tmp_path_factory.mktemp("batch"))
    write(d, "scene.toml", SCENE)
    write(d, "jobs.toml", JOB)
    return d


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def check_outputs(out, res):
    """Every done task's files exist and read back; the CSV has a row per task; the contact sheet names every
    thumbnail, which exists, and fetches nothing from elsewhere."""
    rows = {r["task"]: r for r in read_csv(res.csv)}
    assert set(rows) == {t.hash for t in res.tasks}
    with open(res.html, encoding="utf-8") as fh:
        page = fh.read()
    assert "http://" not in page and "https://" not in page and "<script src" not in page
    for t in res.tasks:
        row, rec = rows[t.hash], res.records.get(t.hash)
        if rec is None or rec["status"] != "done":
            continue
        folder = os.path.join(out, "tasks", t.hash)
        mat = wb.load(os.path.join(folder, "material.wbm"))
        assert isinstance(mat, wb.EffectiveBRDF) and mat.directions == 4
        gt = wb.load(os.path.join(folder, "truth.npz"))
        assert isinstance(gt, wb.GroundTruth) and gt.facets == 2048
        img = wb.read_image(os.path.join(out, row["image:tiny"]))
        assert img.shape == (48, 64, 3) and np.isfinite(img).all() and img.max() > 0
        thumb = rec["outputs"]["thumbnails"]["tiny"]
        assert f"tasks/{t.hash}/{thumb}" in page and os.path.isfile(os.path.join(folder, thumb))
        assert row["status"] == "done" and float(row["bake_s"]) > 0 and np.isfinite(float(row["psnr"]))
        assert float(row["peak_rss_mb"]) > 0 and int(row["wbm_bytes"]) > 0
        assert row["wbm"] == f"tasks/{t.hash}/material.wbm"
        assert rec["hash"] == t.hash and rec["timings"]["bake"] > 0


# ------------------------------------------------------------------------------------------------ job files


def test_issue_example_parses_into_five_tasks():
    with pytest.warns(wb.EnergyWarning, match=r"^jobs\.toml:13: \[\[material\]\] #1 BlinnPhong"):  # located, said once
        jobs = loads_jobs(ISSUE_JOB, path="jobs.toml")
    assert len(jobs.tasks) == 5
    labels = [t.label for t in jobs.tasks]
    assert labels[:3] == [f"pyramid(height={h}) × blinnphong:exponent=128" for h in ("0.2", "0.4", "0.6")]
    assert labels[3:] == [f"grooves(depth={d}) × blinnphong:exponent=128" for d in ("0.3", "0.5")]
    assert len({t.hash for t in jobs.tasks}) == 5 and len({t.tile_key for t in jobs.tasks}) == 5
    for t in jobs.tasks:
        assert t.bake == {**t.bake, "method": "sg", "lobes": 4, "facets": 4096, "directions": 6}
        assert t.truth is None and t.scenes == [] and t.materials[0]["exponent"] == 128.0
    # the same inputs give the same hashes (what a rerun resumes by), wherever the file is; another setting,
    # or another material, gives others
    quiet = ISSUE_JOB.replace("128", "128,normalization=energy")  # (no EnergyWarning)
    one, two = loads_jobs(quiet, path="jobs.toml"), loads_jobs(quiet, path="elsewhere/other.toml")
    assert [t.hash for t in one.tasks] == [t.hash for t in two.tasks]
    assert not {t.hash for t in one.tasks} & {t.hash for t in jobs.tasks}
    other = loads_jobs(quiet.replace("lobes = 4", "lobes = 5"), path="jobs.toml")
    assert not {t.hash for t in other.tasks} & {t.hash for t in one.tasks}
    assert [t.tile_key for t in other.tasks] == [t.tile_key for t in one.tasks]


def test_example_job_file_parses():
    jobs = load_jobs(os.path.join(EXAMPLES, "jobs", "sweep.toml"))
    assert len(jobs.tasks) == 5
    assert [s["slot"] for s in jobs.scenes] == ["demo_tile"] and jobs.tasks[0].scenes[0]["width"] == 128
    assert all(t.truth is not None and t.compare for t in jobs.tasks)
    # At least one lobe per distinct facet normal of its pyramids (four sides and the base): with lobes = 4 they
    # scored 20-22 dB against their truths where the grooves scored 66 dB (lobes = 8: 65-68 dB for all five).
    normals = len(np.unique(np.round(wb.geometry.pyramid().face_normals, 6), axis=0))
    assert normals == 5 and all(t.bake["lobes"] >= normals for t in jobs.tasks)


def test_sweep_syntax():
    text = """\
    [bake]
    lobes = [2, 3]
    facets = 1024
    directions = 4
    [[tile]]
    family = "pyramid"
    name = "p"
    height = { from = 0.1, to = 0.5, steps = 3 }
    sides = [3, 4, 5]
    zip = true
    [[tile]]
    family = "rods"
    name = "r"
    length = { from = 0.2, to = 0.8, step = 0.3 }
    color = [1.0, 0.5, 0.2]          # a vector key: one value, not a sweep
    [[material]]
    type = "cooktorrance"
    roughness = { from = 0.05, to = 0.2, steps = 2, log = true }
    ks = [[0.5, 0.5, 0.5], [0.9, 0.8, 0.2]]
    tiles = ["p"]
    [[material]]
    brdf = "lambert:albedo=0.5"
    """
    jobs = loads_jobs(textwrap.dedent(text), path="jobs.toml")
    pyramids = [t for t in jobs.tasks if t.tile["family"] == "pyramid"]
    rods = [t for t in jobs.tasks if t.tile["family"] == "rods"]
    # pyramids: 3 zipped tiles x (4 cook-torrance + 1 lambert) x 2 lobe counts; rods: 3 tiles x 1 x 2
    assert len(pyramids) == 3 * 5 * 2 and len(rods) == 3 * 1 * 2
    assert sorted({(t.tile["params"]["height"], t.tile["params"]["sides"]) for t in pyramids}) == [
        (0.1, 3), (0.3, 4), (0.5, 5)]
    assert sorted({t.tile["params"]["length"] for t in rods}) == [0.2, 0.5, 0.8]
    assert all(t.tile["params"]["color"] == [1.0, 0.5, 0.2] for t in rods)
    rough = sorted({t.materials[0]["roughness"] for t in pyramids if t.materials[0]["type"] == "CookTorrance"})
    assert np.allclose(rough, [0.05, 0.2])
    assert {t.bake["lobes"] for t in jobs.tasks} == {2, 3}
    assert "[lobes=2]" in jobs.tasks[0].label


def test_file_tiles_and_a_job_given_as_a_dict(tmp_path, monkeypatch):
    """Mesh and height-field tiles: read from files relative to the job, hashed by their bytes (an edited file
    is a new task), and run (here, no Dask); a job given as Python data is read the same way."""
    from PIL import Image

    tile = wb.geometry.pyramid(height=0.4)
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in tile.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in tile.faces]
    (tmp_path / "tile.obj").write_text("\n".join(lines) + "\n")
    yy, xx = np.mgrid[0:16, 0:16]
    bumps = (127.5 + 127.5 * np.sin(2 * np.pi * xx / 16) * np.sin(2 * np.pi * yy / 16)).astype(np.uint8)
    Image.fromarray(bumps).save(tmp_path / "bumps.png")
    doc = {"bake": {"lobes": 2, "facets": 1024, "directions": 4, "normal_res": 16},
           "compute": {"compare": True}, "truth": {"facets": 2048},
           "tile": [{"mesh": str(tmp_path / "tile.obj"), "period": [1.0, 1.0]},
                    {"heightfield": "bumps.png", "scale": [0.1, 0.2]}],
           "material": [{"brdf": "ward:alpha=0.3,ks=0.3,kd=0.5", "name": "satin"}]}
    jobs = batch.jobs_from_dict(doc, base_dir=str(tmp_path))
    assert [t.label for t in jobs.tasks] == ["tile.obj × satin: ward:alpha=0.3,ks=0.3,kd=0.5",
                                             "bumps.png(scale=0.1) × satin: ward:alpha=0.3,ks=0.3,kd=0.5",
                                             "bumps.png(scale=0.2) × satin: ward:alpha=0.3,ks=0.3,kd=0.5"]
    monkeypatch.chdir(tmp_path)  # (the dict's relative paths: against the working directory)
    res = batch.run(doc, str(tmp_path / "out"), progress=False)
    assert (res.done, res.failed) == (3, 0) and [t.hash for t in res.tasks] == [t.hash for t in jobs.tasks]
    for t in jobs.tasks:
        rec = res.records[t.hash]
        assert rec["metrics"]["psnr"] > 10 and os.path.isfile(os.path.join(res.output, "tasks", t.hash, "truth.npz"))
    Image.fromarray(255 - bumps).save(tmp_path / "bumps.png")  # an edited image: new tasks for it alone
    again = batch.jobs_from_dict(doc, base_dir=str(tmp_path))
    assert again.tasks[0].hash == jobs.tasks[0].hash and again.tasks[1].hash != jobs.tasks[1].hash
    with pytest.raises(SceneError, match=r"^<jobs>: \[\[tile\]\] #1 no such image file: nope.png"):
        batch.jobs_from_dict({**doc, "tile": [{"heightfield": "nope.png"}]}, base_dir=str(tmp_path))


def test_asg_method_and_an_anisotropic_material(tmp_path):
    """[bake] method = "asg" (Xu 2013) sweeps beside "sg" and "auto", and takes an anisotropic small-scale BRDF
    (which the SG bake refuses: that task fails with its one-line reason, the rest finish; "auto" bakes it by ASG);
    the ASG materials are saved, judged against their ground truth and their live lobes are counted."""
    doc = {"bake": {"method": ["sg", "asg", "auto"], "lobes": 8, "facets": 1024, "directions": 4, "normal_res": 16},
           "compute": {"compare": True}, "truth": {"facets": 2048},
           "tile": [{"family": "pyramid"}],
           "material": [{"brdf": "ward:alpha_x=0.1,alpha_y=0.4,kd=0.1"}]}
    res = batch.run(doc, str(tmp_path / "out"), progress=False)
    assert (res.done, res.failed) == (2, 1)
    failed = [r for r in res.records.values() if r["status"] == "failed"]
    assert len(failed) == 1 and "bake it with method='asg'" in failed[0]["error"] and "\n" not in failed[0]["error"]
    for done in (r for r in res.records.values() if r["status"] == "done"):
        mat = wb.load(os.path.join(res.output, "tasks", done["hash"], "material.wbm"))
        assert isinstance(mat, wb.ASGBRDF) and mat.materials[0].anisotropic
        assert done["metrics"]["psnr"] > 30 and done["bake_info"]["lobes_live"] == len(mat.weight)
        assert ("method_choice" in mat.info) == (done["task"]["bake"]["method"] == "auto")
        assert done["bake_info"]["method"] == "asg"
    with open(os.path.join(res.output, "results.csv"), newline="") as fh:
        used = {row["method"]: row["method_used"] for row in csv.DictReader(fh)}
    assert used == {"sg": "", "asg": "asg", "auto": "asg"}  # (the sg task failed: it made no material)


def test_a_merl_table_as_a_jobs_brdf(tmp_path):
    """A MERL file as a job's brdf (the CLI's --brdf syntax takes one): the task records its path and SHA-256, the
    worker reads it and bakes it as `wb.bake` does (the same tables), and a file edited after the job was read is
    that task's one-line failure, not a bake of other data."""
    table = wb.MeasuredBRDF.from_brdf(wb.CookTorrance(0.8, 0.25, kd=0.2))
    table.save(tmp_path / "ct.binary")
    doc = {"bake": {"lobes": 2, "facets": 1024, "directions": 4, "normal_res": 16},
           "tile": [{"family": "pyramid"}], "material": [{"brdf": str(tmp_path / "ct.binary")}]}
    res = batch.run(doc, str(tmp_path / "out"), progress=False)
    assert (res.done, res.failed) == (1, 0)
    (record,) = res.records.values()
    assert record["task"]["materials"][0]["sha256"] == batch_jobs.file_sha256(tmp_path / "ct.binary")
    mat = wb.load(os.path.join(res.output, "tasks", record["hash"], "material.wbm"))
    want = wb.bake(wb.geometry.pyramid(), wb.MeasuredBRDF.load(tmp_path / "ct.binary"), lobes=2, facets=1024,
                   directions=4, normal_res=16, backend=record["task"]["bake"]["backend"])
    np.testing.assert_array_equal(mat.table(), want.table())
    task = dict(record["task"], materials=[dict(record["task"]["materials"][0], sha256="0" * 64)])
    with pytest.raises(ValueError, match=r"the MERL file .*ct.binary changed since the job was read"):
        batch.execute(task)


BASE = """\
[bake]
lobes = 2
facets = 1024
directions = 4
[[tile]]
family = "pyramid"
height = [0.2, 0.4]
[[material]]
brdf = "lambert:albedo=0.5"
"""


@pytest.mark.parametrize("case, edit, bad_line, words", [
    ("unknown top-level key", lambda t: "colour = 1\n" + t, "colour", ["unknown table or key 'colour'"]),
    ("unknown bake key", lambda t: t.replace("lobes = 2", "lobse = 2"), "lobse", ["unknown key 'lobse'"]),
    ("unknown tile key", lambda t: t.replace("height =", "heigth ="), "heigth", ["unknown key 'heigth'", "pyramid"]),
    ("empty list", lambda t: t.replace("[0.2, 0.4]", "[]"), "height", ["empty"]),
    ("empty range", lambda t: t.replace("[0.2, 0.4]", "{ from = 0.2, to = 0.6, steps = 0 }"), "height", ["empty"]),
    ("huge range", lambda t: t.replace("[0.2, 0.4]", "{ from = 0.2, to = 0.6, steps = 1000000000000 }"), "height",
     ["the range makes 1000000000000 values (more than 100000)"]),
    ("empty step range", lambda t: t.replace("[0.2, 0.4]", "{ from = 0.6, to = 0.2, step = 0.1 }"), "height",
     ["is empty"]),
    ("bad parameter value", lambda t: t.replace("[0.2, 0.4]", "[0.2, -0.4]"), "height", ["height", "-0.4"]),
    ("unknown family", lambda t: t.replace('"pyramid"', '"pyramids"'), "family", ["unknown tile family"]),
    ("bad brdf", lambda t: t.replace("albedo=0.5", "albedo=x"), "brdf", ["albedo"]),
    ("bad bake setting", lambda t: t.replace("directions = 4", "directions = [4, 40]"), "directions", ["[2, 32]"]),
    ("scene without the slot", lambda t: t + '[[scene]]\npath = "scene.toml"\nslot = "gold"\n', "slot",
     ["no [material.gold]", "scene.toml"]),
    ("scene not using the slot", lambda t: t + '[[scene]]\npath = "unused.toml"\nslot = "spare"\n', "slot",
     ["no [[object]]", "'spare'"]),
    ("missing scene file", lambda t: t + '[[scene]]\npath = "nope.toml"\nslot = "tile"\n', "path",
     ["no such scene file"]),
    ("bad scene file", lambda t: t + '[[scene]]\npath = "bad.toml"\nslot = "tile"\n', "path",
     ["bad.toml:12:", "fov"]),
    ("unwritable output folder", lambda t: 'output = "a_file/results"\n' + t, "output", ["cannot be written"]),
    ("TOML syntax", lambda t: t.replace("lobes = 2", "lobes = = 2"), "lobes", ["invalid TOML"]),
    ("material for an unknown tile", lambda t: t + 'tiles = ["nope"]\n', "tiles", ["no [[tile]] has name"]),
    ("render without a scene", lambda t: t + "[compute]\nrender = true\n", "render", ["[[scene]]"]),
    ("bad block_rays", lambda t: t + '[[scene]]\npath = "scene.toml"\nslot = "tile"\nblock_rays = "yes"\n',
     "block_rays", ["block_rays", "true, false or a block side 1, 2 or 4"]),
])
def test_bad_job_files_are_one_line_errors_at_file_line(tmp_path, case, edit, bad_line, words):
    write(tmp_path, "scene.toml", SCENE)
    write(tmp_path, "unused.toml", SCENE + "\n[material.spare]\ntype = \"lambert\"\n")
    write(tmp_path, "bad.toml", SCENE.replace("fov = 40.0", "fov = 'wide'"))
    write(tmp_path, "a_file", "not a folder\n")
    text = edit(BASE)
    path = write(tmp_path, "jobs.toml", text)
    with pytest.raises(SceneError) as info:
        load_jobs(path)
    msg = str(info.value)
    line = next(i for i, s in enumerate(text.splitlines(), 1) if s.lstrip().startswith(bad_line))
    assert msg.startswith(f"jobs.toml:{line}:"), (case, msg)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, (case, msg)
    # the command line refuses it before any work, with nothing written
    args = _parser().parse_args(["batch", path, "-o", str(tmp_path / "out"), "-q"])
    with pytest.raises(ValueError):
        args.func(args)
    assert not (tmp_path / "out").exists()


def test_a_scene_chooses_block_rays_and_its_renders_follow(tmp_path):
    """[[scene]] block_rays (true/false or a block side; absent: the renderer's default, shared in 2×2 blocks from
    320×240 up) goes into the task's scene and its hash only where it is set, and reaches the render: at 320×240
    the default's image is block_rays = true's, bit for bit, and not block_rays = false's nor 4's (4×4 blocks)."""
    write(tmp_path, "scene.toml", SCENE)
    scene = '[[scene]]\npath = "scene.toml"\nslot = "tile"\nwidth = 320\nheight = 240\n'
    texts = {None: BASE + scene, True: BASE + scene + "block_rays = true\n",
             False: BASE + scene + "block_rays = false\n", 4: BASE + scene + "block_rays = 4\n"}
    jobs = {k: load_jobs(write(tmp_path, f"jobs-{k}.toml", t.replace("[0.2, 0.4]", "0.3"))) for k, t in texts.items()}
    for k, j in jobs.items():
        assert [t.scenes[0]["block_rays"] for t in j.tasks] == [k]
    assert len({j.tasks[0].hash for j in jobs.values()}) == 4
    images = {}
    for k, j in jobs.items():
        res = batch.run(j, str(tmp_path / f"out-{k}"), progress=False)
        record = next(iter(res.records.values()))
        assert res.done == 1, record
        images[k] = wb.images.read_image(os.path.join(res.output, "tasks", record["hash"], "render-scene.png"))
    assert np.array_equal(images[None], images[True])
    assert np.abs(images[None] - images[False]).max() > 1e-3
    assert np.abs(images[None] - images[4]).max() > 1e-3
    # A [[scene]] without the key takes the scene file's own [render] block_rays (and its other ray settings).
    write(tmp_path, "own.toml", SCENE.replace("env_lobes = 4\n", "env_lobes = 4\nblock_rays = false\n"))
    own = load_jobs(write(tmp_path, "jobs-own.toml", texts[None].replace("[0.2, 0.4]", "0.3").replace(
        'path = "scene.toml"', 'path = "own.toml"')))
    assert own.tasks[0].scenes[0]["block_rays"] is False
    res = batch.run(own, str(tmp_path / "out-own"), progress=False)
    record = next(iter(res.records.values()))
    assert res.done == 1, record
    image = wb.images.read_image(os.path.join(res.output, "tasks", record["hash"], "render-own.png"))
    assert np.array_equal(image, images[False])


def test_assign_workers_keeps_tiles_together_and_balances():
    jobs = loads_jobs(BASE.replace("[0.2, 0.4]", "[0.1, 0.2, 0.3]") + '[[material]]\nbrdf = "ward:alpha=0.2"\n'
                      '[[material]]\nbrdf = "cooktorrance:roughness=0.3"\n', path="jobs.toml")
    assert len(jobs.tasks) == 9  # 3 tiles x 3 materials
    where = batch.assign_workers(jobs.tasks, ["a", "b", "c"])
    for key in {t.tile_key for t in jobs.tasks}:
        assert len({where[t.hash] for t in jobs.tasks if t.tile_key == key}) == 1
    where = batch.assign_workers(jobs.tasks, ["a", "b"])
    assert sorted(list(where.values()).count(w) for w in "ab") == [4, 5]
    keys = {t.tile_key for t in jobs.tasks}
    assert sum(len({where[t.hash] for t in jobs.tasks if t.tile_key == k}) for k in keys) == 4  # one tile split


# ------------------------------------------------------------------------------------------------ runs


@pytest.fixture(scope="module")
def cluster_run(job_dir, tmp_path_factory):
    if distributed is None:
        pytest.skip("Dask (distributed) is not installed")
    """The 6-task job on a fresh 2-process LocalCluster (workers=2, each pinned to its own cores), with a hook
    that makes one task raise every time and kills the worker running another on its first attempt."""
    marks = str(tmp_path_factory.mktemp("marks"))
    jobs = load_jobs(os.path.join(job_dir, "jobs.toml"))
    lambert = [t.materials[0]["type"] == "Lambert" for t in jobs.tasks]
    failing = next(t for t, m in zip(jobs.tasks, lambert) if t.tile["family"] == "grooves" and m)
    killed = next(t for t, m in zip(jobs.tasks, lambert) if t.tile["params"].get("height") == 0.5 and not m)

    def hook(task, failing=failing.hash, killed=killed.hash, marks=marks):
        with open(os.path.join(marks, "starts"), "a") as fh:
            fh.write(f"{os.getpid()}\n")
        if task["hash"] == failing:
            with open(os.path.join(marks, "attempts"), "a") as fh:
                fh.write(f"{os.getpid()}\n")
            raise RuntimeError("boom: this task always fails")
        if task["hash"] == killed and not os.path.exists(os.path.join(marks, "killed")):
            with open(os.path.join(marks, "killed"), "w") as fh:
                fh.write(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGKILL)  # the worker process dies mid-run; its nanny starts another

    out = os.path.join(job_dir, "results")
    res = batch.run(jobs, out, workers=2, hook=hook, progress=False, dashboard=False, pin=True)
    return {"res": res, "out": out, "jobs": jobs, "failing": failing, "killed": killed, "marks": marks}


def test_cluster_run_writes_every_output(cluster_run):
    res, out = cluster_run["res"], cluster_run["out"]
    assert (res.ran, res.done, res.failed, res.skipped) == (6, 5, 1, 0)
    check_outputs(out, res)
    with open(os.path.join(cluster_run["marks"], "starts")) as fh:
        assert len(set(fh.read().split())) >= 2  # both worker processes ran tasks
    recs = [r for r in res.records.values() if r["status"] == "done"]
    # a worker process lives across tasks: a later task on it finds its scene (lighting, SSDF) ready
    assert any(r["worker"]["task_index"] >= 2 and r["caches"]["scene tiny"] for r in recs)
    if hasattr(os, "sched_getaffinity") and len(os.sched_getaffinity(0)) >= 2:  # each worker on its own cores
        share = len(os.sched_getaffinity(0)) // 2
        cores = {r["worker"]["pid"]: tuple(r["worker"]["cores"]) for r in recs}
        assert all(len(c) == share for c in cores.values())
        # a pinned worker splits its CPU work over its own cores (its affinity), not over the machine's
        assert {r["worker"]["cpu_threads"] for r in recs} == {share}
        by_pid = list(cores.values())
        assert all(set(a).isdisjoint(b) or a == b for a in by_pid for b in by_pid)
    with open(os.path.join(out, "job.toml")) as fh:
        assert fh.read() == textwrap.dedent(JOB)


def test_gpu_cluster_gives_each_worker_its_own_gpu(job_dir, tmp_path):
    """gpus=2: one worker process per GPU, worker i seeing GPU i alone (CUDA_VISIBLE_DEVICES). On this CPU
    machine the tasks run on the job's CPU backend, and each records the GPU its worker was given."""
    if distributed is None:
        pytest.skip("Dask (distributed) is not installed")
    jobs = load_jobs(os.path.join(job_dir, "jobs.toml"))
    starts = str(tmp_path / "starts")

    def hook(task, starts=starts):
        with open(starts, "a") as fh:
            fh.write(f"{os.getpid()} {os.environ.get('CUDA_VISIBLE_DEVICES')}\n")

    res = batch.run(jobs, str(tmp_path / "results"), gpus=2, hook=hook, progress=False, dashboard=False)
    assert (res.done, res.failed) == (len(jobs.tasks), 0)
    with open(starts) as fh:
        seen = dict(line.split() for line in fh.read().splitlines())
    assert set(seen.values()) == {"0", "1"} and len(set(seen)) == 2  # both GPUs, a process each
    assert {r["worker"]["gpus"] for r in res.records.values()} <= {"0", "1"}
    with pytest.raises(ValueError, match="one of workers"):
        batch.run(jobs, str(tmp_path / "other"), gpus=2, workers=2)


def test_cluster_run_records_a_failing_task_after_one_retry(cluster_run):
    res, failing, marks = cluster_run["res"], cluster_run["failing"], cluster_run["marks"]
    rec = res.records[failing.hash]
    assert rec["status"] == "failed" and rec["error"] == "RuntimeError: boom: this task always fails"
    with open(os.path.join(marks, "attempts")) as fh:
        assert len(fh.read().split()) == 2  # tried, then retried once (Dask retries=1)
    folder = os.path.join(cluster_run["out"], "tasks", failing.hash)
    assert os.path.isfile(os.path.join(folder, "error.json"))
    assert not os.path.exists(os.path.join(folder, "task.json"))  # no done marker: a rerun tries it again
    with open(os.path.join(folder, "error.json")) as fh:
        assert "boom" in json.load(fh)["traceback"]
    row = next(r for r in read_csv(res.csv) if r["task"] == failing.hash)
    assert row["status"] == "failed" and "boom" in row["error"]


def test_cluster_run_finishes_a_killed_workers_task_elsewhere(cluster_run):
    res, killed, marks = cluster_run["res"], cluster_run["killed"], cluster_run["marks"]
    with open(os.path.join(marks, "killed")) as fh:
        dead_pid = int(fh.read())
    rec = res.records[killed.hash]
    assert rec["status"] == "done" and rec["worker"]["pid"] != dead_pid


@needs_dask
def test_a_task_that_kills_its_worker_every_time_ends_the_batch_anyway(tmp_path):
    """A task that kills the worker process running it on every attempt (a crash in native code) is recorded as
    failed (Dask's KilledWorker) and the batch ends. Before, it waited for ever: Dask keeps a task whose worker
    restriction names a departed worker waiting for it even where others are allowed, and the nanny restarts a
    killed worker at a new address (batch._resend_stranded). A task queued on the dying worker with it may fail
    too; the other tasks finish."""
    write(str(tmp_path), "jobs.toml", BASE.replace("height = [0.2, 0.4]", "height = [0.2, 0.4, 0.6]"))
    jobs = load_jobs(str(tmp_path / "jobs.toml"))
    assert len(jobs.tasks) == 3
    victim = jobs.tasks[0].hash

    def hook(task, victim=victim):
        if task["hash"] == victim:
            os.kill(os.getpid(), signal.SIGKILL)

    res = batch.run(jobs, str(tmp_path / "results"), workers=2, hook=hook, progress=False, dashboard=False)
    assert res.records[victim]["status"] == "failed" and "KilledWorker" in res.records[victim]["error"]
    assert sum(r["status"] == "done" for r in res.records.values()) >= 1
    assert set(res.records) == {t.hash for t in jobs.tasks}


@needs_dask
def test_rerun_resumes_on_a_running_scheduler(cluster_run, tmp_path):
    """A copy of the results run again, submitted to a running scheduler (a LocalCluster of one worker process):
    only the failed task runs; a third run runs nothing. Removing one output reruns that task alone. (Its worker
    was a thread of this process once: in one CI run on CPython 3.11.7, numpy's header parse below then failed with
    "AST constructor recursion depth mismatch", CPython's error when threads build ASTs at once.)"""
    out = str(tmp_path / "results")
    shutil.copytree(cluster_run["out"], out)
    jobs = cluster_run["jobs"]
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        res = batch.run(jobs, out, scheduler=lc.scheduler_address, progress=False)
    assert (res.ran, res.done, res.failed, res.skipped) == (1, 1, 0, 5)
    assert set(res.records) == {t.hash for t in jobs.tasks}
    check_outputs(out, res)
    failing = os.path.join(out, "tasks", cluster_run["failing"].hash)
    assert os.path.isfile(os.path.join(failing, "task.json"))
    assert not os.path.exists(os.path.join(failing, "error.json"))
    again = batch.run(jobs, out, progress=False)  # here, no Dask
    assert (again.ran, again.skipped) == (0, 6)
    os.remove(os.path.join(out, "tasks", jobs.tasks[0].hash, "render-tiny.png"))
    third = batch.run(jobs, out, progress=False)
    assert (third.ran, third.done, third.skipped) == (1, 1, 5)
    check_outputs(out, third)


def test_ctrl_c_keeps_finished_tasks_and_the_rerun_resumes(job_dir, tmp_path):
    jobs = load_jobs(os.path.join(job_dir, "jobs.toml"))
    order = [t.hash for t in batch._order(jobs.tasks)]  # the order in which they run here
    stop_at = order[2]

    def hook(task):
        if task["hash"] == stop_at:
            raise KeyboardInterrupt

    out = str(tmp_path / "results")
    with pytest.raises(KeyboardInterrupt):
        batch.run(jobs, out, hook=hook, progress=False)
    done = [h for h in order if os.path.isfile(os.path.join(out, "tasks", h, "task.json"))]
    assert done == order[:2]
    rows = read_csv(os.path.join(out, "results.csv"))  # the report is written on the way out
    assert sorted(r["status"] for r in rows) == ["done"] * 2 + ["pending"] * 4
    res = batch.run(jobs, out, progress=False)
    assert (res.ran, res.done, res.skipped) == (4, 4, 2)
    check_outputs(out, res)
    # an output cut since it was written is made again, with its task; the others stay skipped
    rec = res.records[order[0]]
    name = rec["outputs"]["material"]
    path = os.path.join(out, "tasks", order[0], name)
    whole = open(path, "rb").read()
    with open(path, "wb") as fh:
        fh.write(whole[:len(whole) // 2])
    res = batch.run(jobs, out, progress=False)
    assert (res.ran, res.done, res.skipped) == (1, 1, 5)
    with open(tmp_path / "first.wbm", "wb") as fh:
        fh.write(whole)
    np.testing.assert_array_equal(wb.load(path).table(), wb.load(tmp_path / "first.wbm").table())  # made again


def test_a_folder_that_is_not_a_batchs_results_is_refused_before_any_task(job_dir, tmp_path):
    """A run writes results.csv, index.html and job.toml into its folder: a folder holding the user's own files is
    refused in one line naming it and a file, before any task runs and with nothing written; an earlier run's
    results (its tasks/ of task folders) are reused, as a rerun does, and an empty folder is filled."""
    jobs = load_jobs(os.path.join(job_dir, "jobs.toml"))
    calls = []
    own = tmp_path / "own"
    own.mkdir()
    (own / "index.html").write_text("my page")
    (own / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match=r"^output folder '.*own' holds 'index.html' and 1 more and is not an "
                                         r"earlier batch's results \(no tasks/ folder of task folders\); give a new "
                                         r"or empty folder$"):
        batch.run(jobs, str(own), hook=calls.append, progress=False)
    # a folder of the user's own called tasks/ is not a batch's either
    (own / "tasks").mkdir()
    (own / "tasks" / "todo.md").write_text("mine")
    with pytest.raises(ValueError, match="holds 'index.html'"):
        batch.run(jobs, str(own), hook=calls.append, progress=False)
    assert calls == [] and sorted(os.listdir(own)) == ["index.html", "notes.txt", "tasks"]
    assert (own / "index.html").read_text() == "my page" and os.listdir(own / "tasks") == ["todo.md"]
    # the command line says so before it reads the job file
    args = _parser().parse_args(["batch", os.path.join(job_dir, "jobs.toml"), "-o", str(own), "-q"])
    with pytest.raises(ValueError, match=r"^-o: output folder '.*own' holds 'index.html'"):
        args.func(args)
    assert (own / "index.html").read_text() == "my page"
    # what a run leaves, a run stopped before its first task (an empty tasks/) and an empty folder: accepted
    done = tmp_path / "done"
    os.makedirs(done / "tasks" / jobs.tasks[0].hash)
    (done / "tasks" / ".DS_Store").write_text("a file browser's")
    for name in ("results.csv", "index.html", "job.toml"):
        (done / name).write_text("an earlier run's")
    (tmp_path / "stopped" / "tasks").mkdir(parents=True)
    (tmp_path / "stopped" / "job.toml").write_text("an earlier run's")
    (tmp_path / "empty").mkdir()
    for folder in ("done", "stopped", "empty", "missing"):
        batch.check_results_folder(str(tmp_path / folder))


def test_a_task_that_raises_here_is_retried_recorded_and_the_rest_finish(job_dir, tmp_path):
    jobs = load_jobs(os.path.join(job_dir, "jobs.toml"))
    bad = jobs.tasks[1].hash
    calls = []

    def hook(task):
        calls.append(task["hash"])
        if task["hash"] == bad:
            raise ValueError("bad tile, on purpose")

    res = batch.run(jobs, str(tmp_path / "r"), hook=hook, progress=False)
    assert (res.done, res.failed) == (5, 1) and calls.count(bad) == 2
    assert res.records[bad]["error"] == "ValueError: bad tile, on purpose" and res.records[bad]["attempts"] == 2
    check_outputs(str(tmp_path / "r"), res)


def _parser():
    p = argparse.ArgumentParser(prog="warp-biscale")
    batch.add_parser(p.add_subparsers(dest="command", required=True))
    return p


def test_command_line(job_dir, tmp_path, capsys):
    job = write(str(tmp_path), "jobs.toml", JOB.replace('path = "scene.toml"', f'path = "{job_dir}/scene.toml"')
                .replace("height = [0.3, 0.5]", "height = 0.3").replace("depth = 0.4", "depth = [0.4, 0.6]"))
    args = _parser().parse_args(["batch", job, "--dry-run"])
    assert args.func(args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == "6 task(s)" and len(lines) == 7
    out = str(tmp_path / "cli-results")
    args = _parser().parse_args(["batch", job, "-o", out, "--workers", "0"])
    assert args.func(args) == 0
    captured = capsys.readouterr()
    assert "results.csv" in captured.out and "[6/6] 6 done, 0 failed" in captured.err
    assert len(read_csv(os.path.join(out, "results.csv"))) == 6
    for clash in (["--workers", "2", "--scheduler", "tcp://localhost:1"], ["--gpus", "2", "--workers", "2"]):
        with pytest.raises(ValueError, match="give one of --workers"):
            args = _parser().parse_args(["batch", job, *clash])
            args.func(args)
    if distributed is not None:  # a malformed scheduler address: said before any work, the report left alone
        before = open(os.path.join(out, "results.csv")).read()
        with pytest.raises(ValueError, match=r"^--scheduler 'notanaddress': missing port number"):
            args = _parser().parse_args(["batch", job, "-o", out, "--scheduler", "notanaddress", "--no-resume"])
            args.func(args)
        assert open(os.path.join(out, "results.csv")).read() == before
    # a backend this machine cannot run, for a run here or on its own workers: said before any task (not a
    # failure of each task, tried twice)
    if not any(b["name"].startswith("warp:cuda") and b["usable"] for b in wb.backends()):
        cuda_job = tmp_path / "cuda.toml"
        cuda_job.write_text(open(job).read().replace("[bake]\n", '[bake]\nbackend = "warp:cuda"\n', 1))
        with pytest.raises(ValueError, match=r"cuda.toml: \[bake\] backend 'warp:cuda' cannot run here"):
            args = _parser().parse_args(["batch", str(cuda_job), "-o", str(tmp_path / "cuda-out")])
            args.func(args)
        assert not os.path.exists(tmp_path / "cuda-out")


def test_a_run_whose_cluster_never_starts_leaves_the_last_report(job_dir, tmp_path, monkeypatch):
    """A run that fails before any task ran (no cluster reached) keeps the last results.csv, whose finished tasks it
    would otherwise list as pending; a run that ran tasks writes its report."""
    jobs = load_jobs(os.path.join(job_dir, "jobs.toml"))
    out = str(tmp_path / "results")
    batch.run(jobs, out, progress=False)
    before = open(os.path.join(out, "results.csv")).read()

    def unreachable(*args, **kwargs):
        raise OSError("Timed out trying to connect to tcp://127.0.0.1:1")

    monkeypatch.setattr(batch, "_have", lambda name: True)
    monkeypatch.setattr(batch, "_run_dask", unreachable)
    with pytest.raises(OSError, match="Timed out"):
        batch.run(jobs, out, workers=2, resume=False, progress=False)
    assert open(os.path.join(out, "results.csv")).read() == before


def test_cpu_threads_follow_the_variable_else_the_affinity(monkeypatch):
    """A CPU backend's threads: $WARP_BISCALE_CPU_THREADS, else the cores this process may run on; Warp CPU splits
    its launches over that many; a bad value is one line, refused before any backend is made (not passed over by
    "auto" for the next backend)."""
    monkeypatch.delenv("WARP_BISCALE_CPU_THREADS", raising=False)
    assert cpu_threads() == usable_cores() >= 1
    if hasattr(os, "sched_getaffinity"):
        assert usable_cores() == len(os.sched_getaffinity(0))
    monkeypatch.setenv("WARP_BISCALE_CPU_THREADS", " 3 ")
    assert cpu_threads() == 3
    from warp_biscale.warp_backend import WarpBackend

    assert WarpBackend("cpu")._slices == 3  # (a new backend: get_backend keeps the one made first)
    for bad in ("0", "-2", "two", "1.5", "+3", "²", "99999"):
        monkeypatch.setenv("WARP_BISCALE_CPU_THREADS", bad)
        with pytest.raises(ValueError, match="WARP_BISCALE_CPU_THREADS must be an integer from 1 to 1024"):
            wb.get_backend("auto")
