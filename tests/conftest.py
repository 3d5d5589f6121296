"""Shared fixtures: one test body runs on every backend present (Warp CPU, PoCL here and in CI;
CUDA and NVIDIA OpenCL on a GPU machine), and small tiles built by hand."""

import atexit
import os
import shutil
import tempfile

import numpy as np
import pytest
from hypothesis import settings

import warp_biscale as wb
import warp_biscale.reference  # noqa: F401  (the float64 oracle, wb.reference: tests and bench import it, the library never does)

# Property tests draw the same examples on every run (seeded by the test's name), so CI is reproducible;
# set HYPOTHESIS_PROFILE=explore locally to search for new counterexamples.
settings.register_profile("ci", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# What the library keeps between processes (the lighting table, SSDFs, matrix factors) goes to a folder of this
# session's own: a test never reads what an earlier run (of other code) left, and every SSDF a test needs is built
# by the kernels of this run at least once (subprocesses, the CLI's, inherit the folder).
os.environ["WARP_BISCALE_CACHE"] = tempfile.mkdtemp(prefix="warp-biscale-tests-")
atexit.register(shutil.rmtree, os.environ["WARP_BISCALE_CACHE"], ignore_errors=True)

BACKEND_ENTRIES = wb.backends()  # probed once for the whole session


def backend_params(entries):
    """One `backend` parameter per backend found here, usable or not, and per expected backend that is
    absent (Warp's CPU device, an OpenCL device): an unusable or absent one is an explicit skip that
    gives its reason, never a silent drop. A backend that is neither found nor expected on this kind of
    machine (Warp CUDA on a CPU-only one) is left out; `warp-biscale backends` says why."""
    params = []
    for b in entries:
        expected = b["name"] == "warp:cpu" or b["kind"] == "opencl"
        if b["usable"] or b["device"] is not None or expected:
            marks = () if b["usable"] else (pytest.mark.skip(reason=f"backend {b['name']} unusable: {b['reason']}"),)
            params.append(pytest.param(b["name"], marks=marks, id=b["name"]))
    return params


BACKEND_PARAMS = backend_params(BACKEND_ENTRIES)
BACKENDS = [b["name"] for b in BACKEND_ENTRIES if b["usable"]]  # the usable ones, for tests that compare them


@pytest.fixture(params=BACKEND_PARAMS, scope="session")
def backend(request):
    return wb.get_backend(request.param)


# CI sets WARP_BISCALE_REQUIRE_BACKENDS (e.g. "warp:cpu,opencl:cpu": kind:type pairs) so that a run in which
# a required backend is unusable, or ran no test, fails instead of passing on the others alone.
REQUIRED = [r.strip() for r in os.environ.get("WARP_BISCALE_REQUIRE_BACKENDS", "").split(",") if r.strip()]
_PASSED_ON = set()  # names of backends on which at least one test passed


def _matching(requirement):
    kind, _, kind_type = requirement.partition(":")
    return [b for b in BACKEND_ENTRIES if b["kind"] == kind and (not kind_type or b["type"] == kind_type)]


def pytest_configure(config):
    for requirement in REQUIRED:
        found = _matching(requirement)
        if not any(b["usable"] for b in found):
            why = "; ".join(f"{b['name']}: {b['reason']}" for b in found) or "none found"
            raise pytest.UsageError(f"required backend {requirement} is not usable here ({why})")


def pytest_runtest_logreport(report):
    if report.when == "call" and report.passed:
        for b in BACKEND_ENTRIES:
            if b["usable"] and any(f"{a}{b['name']}{z}" in report.nodeid for a in "[-" for z in "]-"):
                _PASSED_ON.add(b["name"])


def pytest_sessionfinish(session, exitstatus):
    if not REQUIRED or exitstatus != 0:
        return
    for requirement in REQUIRED:
        if not any(b["name"] in _PASSED_ON for b in _matching(requirement)):
            session.config.pluginmanager.get_plugin("terminalreporter").write_line(
                f"FAILED: no test ran on a required backend ({requirement})", red=True)
            session.exitstatus = pytest.ExitCode.TESTS_FAILED


def vgroove_tile(depth=0.5, width=1.0):
    """A V-groove along y, walls from z=0 at x=0 and x=w to z=-depth at x=w/2 (the closed form's tile)."""
    return wb.reference.vgroove_tile(depth, width)


def flat_tile(size=1.0, z=0.0):
    v = np.array([[0, 0, z], [size, 0, z], [size, size, z], [0, size, z]], float)
    return wb.SmallScale(v, np.array([[0, 1, 2], [0, 2, 3]]), name="flat")


def random_heightfield(n=8, amplitude=0.3, seed=1, materials=1):
    """A periodic height field of n×n cells (edges match), random heights, optional material ids."""
    rng = np.random.default_rng(seed)
    h = rng.random((n, n)) * amplitude
    xs = np.arange(n + 1) / n
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    z = h[np.arange(n + 1) % n][:, np.arange(n + 1) % n]
    verts = np.stack([gx.ravel(), gy.ravel(), z.ravel()], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    mats = rng.integers(0, materials, len(faces))
    colors = rng.random((len(faces), 3)) * 0.5 + 0.5
    return wb.SmallScale(verts, faces, material_ids=mats, colors=colors, name="heightfield")


@pytest.fixture
def vgroove():
    return vgroove_tile()


@pytest.fixture
def flat():
    return flat_tile()


@pytest.fixture(scope="session")
def heightfield():
    return random_heightfield()
