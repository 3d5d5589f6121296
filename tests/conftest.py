"""Shared fixtures: one test body runs on every backend present (Warp CPU, PoCL here and in CI;
CUDA and NVIDIA OpenCL on a GPU machine), and small tiles built by hand."""

import os

import numpy as np
import pytest
from hypothesis import settings

import warp_biscale as wb

# Property tests draw the same examples on every run (seeded by the test's name), so CI is reproducible;
# set HYPOTHESIS_PROFILE=explore locally to search for new counterexamples.
settings.register_profile("ci", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def _present_backends():
    names = []
    for b in wb.backends():
        if b.get("error") or b["device"] is None:
            continue
        names.append(b["name"])
    return names


BACKENDS = _present_backends()


@pytest.fixture(params=BACKENDS, scope="session")
def backend(request):
    return wb.get_backend(request.param)


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
