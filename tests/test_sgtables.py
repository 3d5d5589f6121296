"""The renderer's half-space SG integrals (sg.cosine_fraction, sg.hemisphere_fraction, sg.visible_fraction)
and their table,
against independent brute-force quadrature over the sphere."""

import os

import numpy as np
import pytest

from warp_biscale import sg


def _brute(c, eta, n=1500):
    """Midpoint rule over the half-space ω·m ≥ 0 in polar coordinates about m (so the half-space edge is
    a grid edge and the integrand is smooth), lobe axis ξ with ξ·m = c; divided by the closed-form ∫G."""
    th = (np.arange(n) + 0.5) * (np.pi / 2) / n
    ph = (np.arange(4 * n) + 0.5) * (2 * np.pi) / (4 * n)
    t, p = np.meshgrid(th, ph, indexing="ij")
    w = np.sin(t) * (np.pi / 2 / n) * (2 * np.pi / (4 * n))
    xi = np.array([np.sqrt(1 - c * c), 0.0, c])
    g = np.exp(eta * (np.sin(t) * np.cos(p) * xi[0] + np.cos(t) * xi[2] - 1))
    total = sg.integral(eta)
    return (g * np.cos(t) * w).sum() / total, (g * w).sum() / total


@pytest.mark.parametrize("c,eta", [(0.3, 1e-4), (0.3, 1.0), (-0.5, 3.0), (0.1, 50.0), (0.9, 10.0), (0.0, 1.0),
                                   (1.0, 2.0), (-1.0, 2.0), (-0.05, 400.0)])
def test_fractions_match_brute_force_quadrature(c, eta):
    cos_b, hemi_b = _brute(c, eta)
    # The brute force's midpoint rule is good to ~1e-5 at these sharpnesses (φ-steps across the step edge).
    assert sg.cosine_fraction(c, eta) == pytest.approx(cos_b, abs=2e-5)
    assert sg.hemisphere_fraction(c, eta) == pytest.approx(hemi_b, abs=5e-5)


def _brute_lune(c, eta, n=1500):
    """Midpoint rule over the lobe's own hemisphere (polar angle about ξ up to π/2, a grid edge), the share
    of its mass with ω·m ≥ 0, ξ·m = c: Wang §5.3's lobe ∩ visibility hemisphere, independently of the
    y-substitution the library integrates in."""
    th = (np.arange(n) + 0.5) * (np.pi / 2) / n
    ph = (np.arange(4 * n) + 0.5) * (2 * np.pi) / (4 * n)
    t, p = np.meshgrid(th, ph, indexing="ij")
    w = np.sin(t) * np.exp(eta * (np.cos(t) - 1))
    m = np.array([np.sqrt(1 - c * c), 0.0, c])  # ξ = z
    visible = np.sin(t) * np.cos(p) * m[0] + np.cos(t) * m[2] >= 0
    return (w * visible).sum() / w.sum()


@pytest.mark.parametrize("c,eta", [(0.3, 1e-4), (-0.8, 1e-4), (0.3, 1.0), (-0.5, 3.0), (0.1, 50.0), (0.9, 10.0),
                                   (0.0, 1.0), (1.0, 2.0), (-1.0, 2.0), (-0.05, 400.0)])
def test_visible_fraction_matches_brute_force(c, eta):
    # The midpoint rule's staircase along the half-space edge is ~1e-4 of the mass at n = 1500.
    assert sg.visible_fraction(c, eta) == pytest.approx(_brute_lune(c, eta), abs=3e-4)


def test_visible_fraction_limits():
    """A uniform lobe sees the lune: (π/2 + θd)/π, so a broad lobe whose axis is occluded is shadowed (the
    half-space alone gives it 1/2 for any θd); a sharp lobe is the half-space's step; fully visible is 1."""
    theta = np.linspace(-np.pi / 2, np.pi / 2, 37)
    np.testing.assert_allclose(sg.visible_fraction(np.sin(theta), 1e-4), (np.pi / 2 + theta) / np.pi, atol=1e-4)
    c = np.linspace(-1, 1, 41)
    for eta in (1e-3, 1.0, 30.0, 1e4):
        np.testing.assert_allclose(sg.visible_fraction(1.0, eta), 1.0, atol=1e-9)
        assert np.all(np.diff(sg.visible_fraction(c, eta)) >= -1e-9)  # more visible, more light
    far = np.abs(c) > 0.1
    np.testing.assert_allclose(sg.visible_fraction(c[far], 1e4), sg.hemisphere_fraction(c[far], 1e4), atol=1e-6)


def test_fraction_limits_and_symmetry():
    c = np.linspace(-1, 1, 41)
    for eta in (1e-4, 0.5, 10.0, 1e3, 1e6):
        h = sg.hemisphere_fraction(c, eta)
        np.testing.assert_allclose(h + h[::-1], 1.0, atol=1e-9)  # complement: f(−c) = 1 − f(c)
        assert sg.hemisphere_fraction(0.0, eta) == pytest.approx(0.5, abs=1e-12)
        # more of the lobe above the horizon, more light (to the quadrature's 1e-6 near its kinks)
        assert np.all(np.diff(sg.cosine_fraction(c, eta)) >= -1e-6)
    # Sharp lobes: the cosine is constant over the lobe; broad (near-constant) lobes: the mean of (n·ω)⁺ is 1/4.
    np.testing.assert_allclose(sg.cosine_fraction(c[c > 0.2], 1e6), c[c > 0.2], atol=2e-6)
    np.testing.assert_allclose(sg.cosine_fraction(c, 1e-4), 0.25 + 0.25e-4 * c / 1.5, atol=1e-5)
    assert np.isfinite(sg.lighting_table()).all()


def test_table_lookup_error_bound():
    """The kernels read the fractions from a (log10 η, c) table. Measured bilinear error over 20000 random
    points: cosine fraction ≤ 5e-4 everywhere; visible fraction (the SSDF's, slot 1) ≤ 3e-3 for η ≤ 1e3, while
    for sharper lobes its step (width ~1/√η in c) is smeared over one column (2/256 in c, 0.45°), by design."""
    rng = np.random.default_rng(0)
    c = rng.uniform(-1, 1, 20000)
    eta = 10 ** rng.uniform(-4, 6, 20000)
    table = sg.lighting_table()
    err_cos = np.abs(sg.table_lookup(table, 0, c, eta) - sg.cosine_fraction(c, eta))
    err_hemi = np.abs(sg.table_lookup(table, 1, c, eta) - sg.visible_fraction(c, eta))
    assert err_cos.max() < 1e-3
    # Broad lobes' visible fraction goes as asin(c) near |c| = 1 (infinite slope): there, within the last
    # column, the bilinear error reaches 1e-2 (measured 9.9e-3); elsewhere 1.6e-3.
    assert err_hemi[(eta <= 1e3) & (np.abs(c) < 0.99)].max() < 3e-3
    assert err_hemi[eta <= 1e3].max() < 1.5e-2
    # Away from the step (|c| > 3 columns + 6/√η) the sharp lobes' fraction is exact to the table too.
    far = (eta > 1e3) & (np.abs(c) > 3 * 2 / 256 + 6 / np.sqrt(eta))
    assert err_hemi[far].max() < 1e-3


def test_lighting_table_kept_on_disk_between_processes(tmp_path, monkeypatch):
    """A fresh process reads the table from the cache folder instead of a second of quadrature; what it reads
    is the computed table bit for bit; a corrupt file or a folder that takes no file costs the quadrature
    again, never a wrong table."""
    monkeypatch.setenv("WARP_BISCALE_CACHE", str(tmp_path / "cache"))
    computed = sg._computed_table()

    def fresh():  # a new process's first call
        monkeypatch.setattr(sg, "_TABLE", None)
        return sg.lighting_table()

    path = sg.table_cache_path()
    assert os.path.dirname(path) == str(tmp_path / "cache")
    np.testing.assert_array_equal(fresh(), computed)  # computed, then written
    assert os.path.exists(path)
    np.testing.assert_array_equal(np.load(path), computed)

    def no_quadrature():
        raise AssertionError("the table was computed although a valid one was on disk")

    with monkeypatch.context() as m:
        m.setattr(sg, "_computed_table", no_quadrature)
        table = fresh()
    np.testing.assert_array_equal(table, computed)
    assert not table.flags.writeable
    for bad in (b"not a numpy file", np.zeros((2, 3), np.float32)):  # corrupt, then the wrong shape
        if isinstance(bad, bytes):
            with open(path, "wb") as fh:
                fh.write(bad)
        else:
            np.save(path, bad)
        np.testing.assert_array_equal(fresh(), computed)
        np.testing.assert_array_equal(np.load(path), computed)  # and put right on disk
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("WARP_BISCALE_CACHE", str(blocker / "cache"))  # a folder that cannot be made
    np.testing.assert_array_equal(fresh(), computed)
    monkeypatch.setattr(sg, "_TABLE", None)  # the next test's first call makes it again


def test_one_cache_folder_for_every_cached_constant(tmp_path, monkeypatch):
    """WARP_BISCALE_CACHE, else XDG_CACHE_HOME/warp_biscale, else ~/.cache/warp_biscale; the matrix factors'
    folder under it unless WARP_BISCALE_MATRIX_CACHE names its own."""
    from warp_biscale import io, matrix

    for name in ("WARP_BISCALE_CACHE", "XDG_CACHE_HOME", "WARP_BISCALE_MATRIX_CACHE"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert io.cache_folder() == str(tmp_path / "home" / ".cache" / "warp_biscale")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert io.cache_folder() == str(tmp_path / "xdg" / "warp_biscale")
    monkeypatch.setenv("WARP_BISCALE_CACHE", str(tmp_path / "mine"))
    assert io.cache_folder() == str(tmp_path / "mine")
    assert matrix.factors_cache_dir() == str(tmp_path / "mine" / "matrix")
    assert os.path.dirname(sg.table_cache_path()) == str(tmp_path / "mine")
    monkeypatch.setenv("WARP_BISCALE_MATRIX_CACHE", str(tmp_path / "factors"))
    assert matrix.factors_cache_dir() == str(tmp_path / "factors")


def test_tangents_follow_u_across_uv_seams():
    """A closed torus wraps its UVs: the faces across the seam must not turn the tangent (it would rotate an
    anisotropic effective BRDF there: streaks along the seam)."""
    import warp_biscale as wb
    from warp_biscale.scene import vertex_tangents

    m = wb.Mesh.torus(segments=(64, 32))
    t = vertex_tangents(m)
    u = np.arctan2(m.vertices[:, 2], m.vertices[:, 0])
    expected = np.stack([-np.sin(u), 0 * u, np.cos(u)], 1)  # ∂(ring)/∂u
    assert np.einsum("ij,ij->i", t, expected).min() > 0.99
    np.testing.assert_allclose(np.einsum("ij,ij->i", t, m.normals), 0, atol=1e-12)
