"""Scatterer generation per cell: determinism whatever the order, the statistics of the
weights and positions, and the cone reach that decides which cells are made."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_device import possm


def make(cells, kind=possm.KIND_VOLUME, n_per=50, cell=0.25, seed=99):
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    n = cells.shape[0] * n_per
    x, y, z = np.empty(n), np.empty(n), np.empty(n)
    xi = np.empty(n, dtype=complex)
    possm.generate_cells(cells, kind, n_per, cell, cell, seed, x, y, z, xi)
    return x, y, z, xi


def test_a_cell_is_the_same_whatever_else_is_generated():
    a = make([[3, -2, 1], [-7, 4, 0]])
    b = make([[10, 10, 10], [-7, 4, 0], [3, -2, 1]])
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u[:50], v[100:150])     # cell (3, -2, 1)
        np.testing.assert_array_equal(u[50:100], v[50:100])   # cell (-7, 4, 0)
    # another seed, another kind, another cell: other numbers
    c = make([[3, -2, 1]], seed=100)
    d = make([[3, -2, 1]], kind=possm.KIND_INTERFACE)
    e = make([[3, -2, 2]])
    for other in (c, d, e):
        assert not np.any(np.isclose(other[0][:50], a[0][:50], rtol=0, atol=1e-15))


def test_positions_fill_their_cells_uniformly():
    x, y, z, _ = make([[-3, 5, 2]], n_per=20000, cell=0.25)
    for v, lo in ((x, -0.75), (y, 1.25), (z, 0.5)):
        assert v.min() >= lo and v.max() < lo + 0.25
        counts, _ = np.histogram(v, bins=10, range=(lo, lo + 0.25))
        # chi-square with 9 dof: 99.9 % quantile 27.9
        assert np.sum((counts - 2000.0) ** 2 / 2000.0) < 27.9
    _, _, zi, _ = make([[0, 0, 0]], kind=possm.KIND_INTERFACE)
    assert np.all(zi == 0.0)


def test_weights_are_circular_complex_gaussian():
    _, _, _, xi = make([[i, j, 0] for i in range(-10, 10) for j in range(-10, 10)], n_per=100)
    n = xi.size
    assert np.mean(np.abs(xi) ** 2) == pytest.approx(1.0, abs=4 / math.sqrt(n))
    assert abs(np.mean(xi)) < 4 / math.sqrt(n)
    assert abs(np.mean(xi * xi)) < 4 / math.sqrt(n)          # circular: E xi^2 = 0
    # |xi|^2 is exponential with mean 1: P(|xi|^2 > 2) = e^-2
    assert np.mean(np.abs(xi) ** 2 > 2.0) == pytest.approx(math.exp(-2), abs=0.01)
    # real part Gaussian with variance 1/2: fourth moment 3/4
    assert np.mean(xi.real ** 4) == pytest.approx(0.75, rel=0.05)


def test_scatterers_per_cell():
    assert possm.scatterers_per_cell(1000.0, 0.25 ** 2) == 62
    assert possm.scatterers_per_cell(1e-3, 0.01) == 1          # never an empty cell


def test_cells_cover_the_disc():
    rng = np.random.default_rng(1)
    cx, cy, r, cell = 0.37, -1.21, 1.3, 0.25
    cells = {tuple(c) for c in possm.cells_in_disc(cx, cy, r, cell)}
    ang = rng.uniform(0, 2 * np.pi, 5000)
    rad = r * np.sqrt(rng.uniform(0, 1, 5000))
    for px, py in zip(cx + rad * np.cos(ang), cy + rad * np.sin(ang)):
        assert (math.floor(px / cell), math.floor(py / cell)) in cells
    # and no cell lies wholly outside
    for i, j in cells:
        dx = max(i * cell - cx, cx - (i + 1) * cell, 0.0)
        dy = max(j * cell - cy, cy - (j + 1) * cell, 0.0)
        assert dx * dx + dy * dy <= r * r
    assert possm.cells_in_disc(0, 0, -1.0, 0.25).shape == (0, 2)


def test_cone_reach_follows_snell():
    c = np.array([1500.0, 1767.0, 1476.0])
    z_top = np.array([-np.inf, 0.0, 1.0])
    a = math.radians(25.0)
    r = possm.cone_reach(np.array([-0.5, 0.0, 0.5, 2.0]), 2.0, a, c, z_top, 100.0)
    s1 = math.sin(a) * 1767 / 1500
    s2 = math.sin(a) * 1476 / 1500
    t1, t2 = s1 / math.sqrt(1 - s1 ** 2), s2 / math.sqrt(1 - s2 ** 2)
    expect = [2 * math.tan(a), 2 * math.tan(a), 2 * math.tan(a) + 0.5 * t1,
              2 * math.tan(a) + t1 + t2]
    np.testing.assert_allclose(r, expect, rtol=1e-12)
    # beyond the critical angle no ray enters: the reach is the given limit
    wide = possm.cone_reach(np.array([0.5]), 2.0, math.radians(70), c, z_top, 42.0)
    assert wide[0] == 42.0
    # homogeneous medium: straight rays below the nominal interface
    h = possm.cone_reach(np.array([1.0]), 2.0, a, c[:1], z_top[:1], 100.0)
    assert h[0] == pytest.approx(3.0 * math.tan(a))


def test_volume_cells_follow_the_reach():
    cells = possm.volume_cells(0.0, 0.0, lambda z: 0.3 + z, 0.6, 0.25)
    assert set(cells[:, 2]) == {0, 1, 2}
    for l in (0, 1, 2):
        ij = cells[cells[:, 2] == l][:, :2]
        ref = possm.cells_in_disc(0.0, 0.0, 0.3 + min((l + 1) * 0.25, 0.6), 0.25)
        assert {tuple(v) for v in ij} == {tuple(v) for v in ref}
    assert possm.volume_cells(0, 0, lambda z: 1.0, 0.0, 0.25).shape == (0, 3)
