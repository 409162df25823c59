"""Tile edges, empty scenes and empty tiles: the grid at its boundaries (positions on a
tile edge, far along the track, voxel counts at half-voxel extents), a scene with
nothing in it through the simulator and the imager, and the background of tiles that
are empty, constant or smaller than the median kernel."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from svss_daq.config import TileConfig
from svss_proc.imaging.grid import n_voxels, tile_grid, tile_index
from svss_proc.products.background import median_exact, median_histogram

from ._sweep import sweep

lengths = st.one_of(st.floats(0.1, 100.0), st.sampled_from([0.1, 0.3, 1.5, 15.0]))
voxels = st.sampled_from([0.003, 0.01, 0.02, 0.04, 0.1])


def cfg(length, voxel, width=1.0, depth=1.0):
    return TileConfig(length_m=length, width_m=width, depth_m=depth, top_m=0.0,
                      voxel_m=voxel, close_after_pings=None)


@sweep(100)
@given(lengths, st.one_of(st.integers(-10**5, 10**5).map(float),
                          st.floats(-1e5, 1e5)), st.sampled_from([0.0, 1e-12, -1e-12]))
def test_tile_index_agrees_with_the_tile_bounds_on_every_edge(length, along, jitter):
    """The tile tile_index names holds the position, also on its edges: k * L <= x <
    (k + 1) * L in the same floating arithmetic (x = k * L exactly included).
    Regression: floor(x / L) alone put x = -5e-324 in tile 0 (the quotient rounds to -0)."""
    c = cfg(length, 0.02)
    for x in (along + jitter, along * length, math.nextafter(along * length, -math.inf)):
        k = tile_index(c, x)
        assert k * length <= x < (k + 1) * length, (x, k)


@sweep(60)
@given(lengths, voxels, st.integers(-1000, 1000))
def test_tile_grid_voxels_lie_inside_their_tile(length, voxel, index):
    c = cfg(length, voxel, width=2 * voxel * 3 + voxel, depth=voxel)
    g = tile_grid(c, index)
    assert g.shape[0] == n_voxels(length, voxel) >= 1
    lo, hi = index * length, (index + 1) * length
    # voxel centres within the tile, up to half a voxel of rounding in the count
    assert g.along[0] >= lo - 1e-9 * (1 + abs(lo)) and g.along[0] - lo <= voxel
    assert g.along[-1] <= hi + 0.5 * voxel + 1e-9 * (1 + abs(hi))
    assert np.all(np.diff(g.along) > 0)
    assert abs(g.cross.mean()) <= 1e-12 and g.depth[0] == pytest.approx(0.5 * voxel)
    assert g.shape[2] == 1 and (g.shape[0] == 1) == math.isnan(g.voxel_m)


@sweep(40)
@given(st.integers(0, 10**6), voxels)
def test_voxel_count_at_half_voxel_extents(n, voxel):
    """extent = (n + 1/2) voxels rounds to n + 1 (or n when rounding lands below); never
    0, never off by more than one."""
    extent = (n + 0.5) * voxel
    k = n_voxels(extent, voxel)
    assert k >= 1 and abs(k - extent / voxel) <= 0.5 + 1e-6


@pytest.fixture(scope="module")
def empty_source(hardware):
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import config_path
    sc = load_scene(config_path("scenes/demo.toml"))
    sc = dataclasses.replace(sc, points=(), track=dataclasses.replace(sc.track, n_pings=40))
    return EnvironmentSource(hardware, sc)


def test_empty_scene_gives_silence_and_an_empty_image(hardware, empty_source, demo_processing):
    """No scatterer, no seabed, no target: the pressure is zero, the pings carry only
    noise, and the imager makes a finite tile with no peak above the noise."""
    from svss_proc.imaging.imager import TileImager
    src = empty_source
    p = src.pressure(5)
    assert p.shape[0] == hardware.value.digitiser.n_channels and np.all(p == 0.0)
    base = demo_processing.value
    proc = dataclasses.replace(base, tile=dataclasses.replace(base.tile, voxel_m=0.1))
    imager = TileImager(hardware, proc)
    tiles = []
    for i in range(0, 40, 2):
        tiles += imager.add(src.ping(i))
    tiles += imager.finish()
    assert tiles
    for t in tiles:
        power = t.re.astype(np.float64) ** 2 + t.im.astype(np.float64) ** 2
        assert np.all(np.isfinite(power))
        reached = power[power > 0]
        # noise only: speckle, whose largest voxel over ~1e4 is ~ln(1e4) = 9 times the
        # mean (a point target stands 20 dB and more above it)
        assert reached.size and reached.max() < 40 * reached.mean()


@pytest.mark.parametrize("fn", [median_exact, lambda m, k, **kw: median_histogram(
    m, k, 0.05, **kw)], ids=["exact", "histogram"])
def test_background_of_empty_constant_and_tiny_tiles(fn):
    kernel = (5, 3, 3)
    zeros = np.zeros((4, 2, 1), dtype=np.float32)           # smaller than the kernel
    b = fn(zeros, kernel, ignore_zeros=True)
    assert b.shape == zeros.shape and np.all(np.isnan(b))    # nothing to take a median of
    b = fn(zeros, kernel, ignore_zeros=False)
    assert np.all(b == 0.0)
    const = np.full((7, 3, 2), 3.5e-20, dtype=np.float32)   # tiny but positive
    b = fn(const, kernel)
    np.testing.assert_allclose(b, 3.5e-20, rtol=0.006, atol=0)   # histogram: 0.025 dB
    one = np.zeros((1, 1, 1))
    one[0, 0, 0] = 1e300
    assert fn(one, kernel)[0, 0, 0] == pytest.approx(1e300, rel=0.006)
