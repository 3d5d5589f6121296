"""The batch contact sheet (index.html in a results folder) opened in a real headless browser: Debian's
chromium driven by Playwright, from file:// as a person opens it, with no server. A real batch run (bake,
ground truth, compare and two renders per task, one task made to fail) gives rows with a PSNR, a time and
thumbnails; the browser then shows that every thumbnail loads, that sorting by error (PSNR, max relative
error) and by time reorders the rows into the order of the values in results.csv, that the failed task
shows as failed, and that the page fetches nothing from outside the results folder.

Playwright's own browser download is not used (CI and this machine cannot reach it): the browser is
Debian's `chromium` (`.ci/run` installs it), or the one WARP_BISCALE_CHROMIUM names. Without it the tests
skip with the reason, except where WARP_BISCALE_REQUIRE_BROWSER=1 (CI sets it): then they fail, so a CI
run without a browser cannot pass by skipping them.
"""

import csv
import os
import shutil
from urllib.parse import unquote, urlparse

import pytest

from warp_biscale import batch
from warp_biscale.batch_jobs import load_jobs

from test_batch import SCENE, write  # the tiny scene (64 x 48, a sphere in the material's slot) and its writer

REQUIRED = os.environ.get("WARP_BISCALE_REQUIRE_BROWSER", "") not in ("", "0")

# 5 tasks: three pyramid heights and two grooves, one glossy material, so the PSNRs differ; bake, ground
# truth and renders as small as tests/test_batch.py's (the run takes a few seconds on a 2-core CPU).
# Two scenes, so that a row has more than one thumbnail.
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
height = [0.2, 0.4, 0.6]

[[tile]]
family = "grooves"
depth = [0.3, 0.5]

[[material]]
brdf = "blinnphong:exponent=64,ks=0.5,kd=0.2,normalization=energy"

[[scene]]
path = "scene.toml"
slot = "tile"
name = "tiny"
shadow_samples = 2

[[scene]]
path = "scene.toml"
slot = "tile"
name = "wide"
width = 96
height = 48
shadow_samples = 2
"""

FAILING = 1  # the task (in the job's order) that raises: in the middle, so sorting has to move its row


def _unavailable(reason):
    if REQUIRED:
        pytest.fail(f"WARP_BISCALE_REQUIRE_BROWSER is set, but {reason}", pytrace=False)
    pytest.skip(reason)


@pytest.fixture(scope="module")
def browser():
    """Headless chromium, for the whole file (it starts in about a second)."""
    try:
        from playwright.sync_api import Error, sync_playwright
    except ImportError as exc:
        _unavailable(f"Playwright is not installed ({exc}; pip install '.[test]')")
    exe = os.environ.get("WARP_BISCALE_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not exe:
        _unavailable("no chromium found (apt-get install chromium, or set WARP_BISCALE_CHROMIUM to a Chromium)")
    with sync_playwright() as pw:
        try:
            # --no-sandbox: Chromium's sandbox refuses to run as root, which CI is. --disable-dev-shm-usage: a
            # container's /dev/shm is often 64 MB, too small for Chromium's shared memory.
            b = pw.chromium.launch(executable_path=exe, headless=True,
                                   args=["--no-sandbox", "--disable-dev-shm-usage"])
        except Error as exc:
            _unavailable(f"chromium ({exe}) did not start: {str(exc).strip().splitlines()[0]}")
        yield b
        b.close()


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A real batch run, here (no Dask: the sheet is the same either way), into a fresh results folder."""
    d = str(tmp_path_factory.mktemp("sheet"))
    write(d, "scene.toml", SCENE)
    write(d, "jobs.toml", JOB)
    jobs = load_jobs(os.path.join(d, "jobs.toml"))
    failing = jobs.tasks[FAILING].hash

    def hook(task):  # batch.run's own test hook: the task raises a real exception, on each attempt
        if task["hash"] == failing:
            raise RuntimeError("boom: this task always fails")

    out = os.path.join(d, "results")
    res = batch.run(jobs, out, hook=hook, progress=False)
    assert (res.done, res.failed) == (len(jobs.tasks) - 1, 1)
    with open(res.csv, newline="") as fh:
        table = {r["task"]: r for r in csv.DictReader(fh)}
    return {"res": res, "out": os.path.realpath(out), "csv": table, "failing": failing}


def _inside(url, folder):
    """The file a file:// URL names, if it is inside `folder`, else None."""
    u = urlparse(url)
    if u.scheme != "file" or u.netloc not in ("", "localhost"):
        return None
    path = os.path.realpath(unquote(u.path))
    return path if path.startswith(folder + os.sep) else None


def _task(row):
    """A row's task hash, from its link to the task's folder ("tasks/<hash>/")."""
    return row["task"].removeprefix("tasks/").rstrip("/")


class Sheet:
    """index.html open in a fresh page, with every request it makes and every script error recorded."""

    def __init__(self, browser, results):
        self.results, self.out = results, results["out"]
        self.page = browser.new_page()
        self.requests, self.failed, self.errors = [], [], []
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.on("requestfailed", lambda r: self.failed.append(f"{r.url}: {r.failure}"))
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.goto("file://" + os.path.join(self.out, "index.html"))

    def rows(self):
        """The table's rows as shown, in order: each {column (its head's data-c): (text, sort value)}, with
        "task" the full hash (from the task cell's link) and "imgs" the number of <img> in the row."""
        return self.page.evaluate("""() => {
            const t = document.getElementById('t');
            const cols = Array.from(t.tHead.rows[0].cells, c => c.getAttribute('data-c'));
            return Array.from(t.tBodies[0].rows, tr => {
                const row = {cls: tr.className, imgs: tr.querySelectorAll('img').length};
                cols.forEach((c, i) => {
                    const cell = tr.cells[i];
                    row[c] = c === 'task' ? cell.querySelector('a').getAttribute('href')
                                          : [cell.textContent, cell.getAttribute('data-v')];
                });
                return row;
            });
        }""")

    def order(self):
        return [_task(r) for r in self.rows()]

    def check_requests(self):
        """Everything the page fetched: file:// inside the results folder, there, and nothing failed."""
        assert self.requests, "no request recorded"
        outside = [u for u in self.requests if _inside(u, self.out) is None]
        assert not outside, f"fetched from outside {self.out}: {outside}"
        assert all(os.path.isfile(_inside(u, self.out)) for u in self.requests)
        assert not self.failed and not self.errors, (self.failed, self.errors)


@pytest.fixture
def sheet(browser, results):
    s = Sheet(browser, results)
    yield s
    s.page.close()


def test_every_thumbnail_loads_and_nothing_comes_from_outside(sheet, results):
    table, out = results["csv"], results["out"]
    renders = {t: [v for k, v in r.items() if k.startswith("image:") and v] for t, r in table.items()}
    n_renders = sum(len(v) for v in renders.values())
    assert n_renders == 2 * results["res"].done  # two scenes per done task, none for the failed one
    imgs = sheet.page.locator("img")
    assert imgs.count() == n_renders
    # the thumbnails are loading='lazy' (a sheet of thousands loads what is shown): bring each into view,
    # as a person scrolling does, then wait until every one has loaded or failed
    for i in range(imgs.count()):
        imgs.nth(i).scroll_into_view_if_needed()
    sheet.page.wait_for_function("Array.from(document.images).every(im => im.complete)", timeout=15_000)
    state = sheet.page.evaluate("""Array.from(document.images, im => ({src: im.src, complete: im.complete,
        w: im.naturalWidth, h: im.naturalHeight, link: im.closest('a') && im.closest('a').href}))""")
    for im in state:
        assert im["complete"] and im["w"] > 0 and im["h"] > 0, im  # decoded: a broken image has width 0
        thumb = _inside(im["src"], out)
        assert thumb is not None and os.path.basename(thumb).startswith("thumb-"), im
        full = _inside(im["link"], out)  # the thumbnail opens its full render, one of its row's in the CSV
        assert full is not None and os.path.relpath(full, out) in renders[os.path.basename(os.path.dirname(full))]
    # the recorder saw every thumbnail fetched (so an empty list below would not be a blind spot) ...
    assert {_inside(im["src"], out) for im in state} <= {_inside(u, out) for u in sheet.requests}
    sheet.check_requests()
    # ... and every other link on the page (results.csv, each task's folder) stays inside the folder too
    for url in sheet.page.evaluate("Array.from(document.querySelectorAll('[href],[src]'), e => e.href || e.src)"):
        path = _inside(url, out)
        assert path is not None and os.path.exists(path), url


def _sorted_as_csv(sheet, results, column, direction):
    """The rows are in the order of `column`'s values in results.csv (`direction`, tasks without a value
    last), and the page shows the CSV's value in each row."""
    table = results["csv"]
    rows = sheet.rows()
    order = [_task(r) for r in rows]
    assert sorted(order) == sorted(table)  # every task, once
    for task, r in zip(order, rows):
        assert r[column][0] == table[task][column], (column, task)
    values = [float(table[t][column]) for t in order if table[t][column] != ""]
    assert len(values) == results["res"].done
    assert values == sorted(values, reverse=(direction == "desc")), (column, direction, values)
    assert all(table[t][column] == "" for t in order[len(values):])  # empties (the failed task) last
    return order


@pytest.mark.parametrize("column", ["psnr", "max_rel_error", "total_s", "bake_s"])
def test_clicking_a_column_head_sorts_by_it_both_ways(sheet, results, column):
    """Error (PSNR, max relative error) and time: the first click sorts ascending, the second descending."""
    before = sheet.order()
    head = sheet.page.locator(f"#t thead th[data-c='{column}']")
    head.click()
    up = _sorted_as_csv(sheet, results, column, "asc")
    assert head.get_attribute("data-dir") == "asc" and head.inner_text().endswith("\u25b2")
    head.click()
    down = _sorted_as_csv(sheet, results, column, "desc")
    assert head.get_attribute("data-dir") == "desc" and head.inner_text().endswith("\u25bc")
    # the rows moved: the two clicks give opposite orders of the done tasks (the failed one last in both),
    # at most one of which is the order the page opened in
    done = results["res"].done
    assert up != down and (before != up or before != down)
    if len({results["csv"][t][column] for t in up[:done]}) == done:  # (equal values keep their order both ways)
        assert up[:done] == down[:done][::-1]
    sheet.check_requests()


@pytest.mark.parametrize("button, column, direction", [
    ("worst PSNR first", "psnr", "asc"), ("slowest first", "total_s", "desc"),
    ("slowest bake first", "bake_s", "desc")])
def test_sort_buttons(sheet, results, button, column, direction):
    sheet.page.get_by_role("button", name=button).click()
    _sorted_as_csv(sheet, results, column, direction)
    sheet.check_requests()


def test_a_failed_task_shows_as_failed(sheet, results):
    failing, res = results["failing"], results["res"]
    rows = {_task(r): r for r in sheet.rows()}
    bad = rows[failing]
    assert bad["cls"] == "failed" and bad["status"][0] == "failed" and bad["imgs"] == 0
    assert bad["error"][0] == res.records[failing]["error"] == "RuntimeError: boom: this task always fails"
    assert bad["psnr"][0] == "" and bad["total_s"][0] == ""
    assert all(r["cls"] == "done" and r["error"][0] == "" and r["imgs"] == 2 for t, r in rows.items() if t != failing)
    summary = sheet.page.locator("body > p").first.inner_text()
    assert f"{len(rows)} task(s): {res.done} done, 1 failed" in summary
    assert sheet.order()[0] != failing  # (so the button below has something to do)
    sheet.page.get_by_role("button", name="failed first").click()
    assert sheet.order()[0] == failing
    sheet.check_requests()
