"""Coverage: which pings and channels reached each voxel. Checked against the imaging
kernel's own count of the channel updates it made, and against a brute-force evaluation
of the beam cones and the receive window for every voxel and channel; stored in the
tile file and read back; older tiles without it still read."""

from __future__ import annotations

import itertools
import math

import h5py
import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, loaded_from_text
from svss_daq.geometry import array_geometry
from svss_proc.imaging.coverage import aperture_corners
from svss_proc.imaging.imager import TileImager
from svss_proc.tiles import read_tile, read_tile_header, write_tile

N_PINGS = 24


def small_processing(demo_processing):
    """The demo processing on 1 m x 0.6 m x 0.4 m tiles, straight rays at the water's
    speed (the brute-force count's; the points are in a water-like medium)."""
    text = (demo_processing.text.replace("length_m = 3.0", "length_m = 1.0")
            .replace("width_m = 1.2", "width_m = 0.6").replace("depth_m = 1.0", "depth_m = 0.4")
            .replace('delays = "table"', 'delays = "straight"'))
    assert text != demo_processing.text
    return loaded_from_text(ProcessingConfig, text, "small-processing")


@pytest.fixture(scope="module")
def pings(hardware):
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    scene = load_scene(config_path("scenes/demo.toml"))
    return list(itertools.islice(iter(EnvironmentSource(hardware, scene)), N_PINGS))


@pytest.fixture(scope="module")
def imaged(pings, hardware, demo_processing):
    proc = small_processing(demo_processing)
    imager = TileImager(hardware, proc.value)
    tiles = []
    for p in pings:
        tiles += imager.add(p)
    return tiles + imager.finish(), proc


def test_coverage_counts_the_kernels_channel_updates(imaged):
    """Every channel update the kernel made is counted, and no other: per tile the sum of
    the ping-channel pairs equals the kernel's update count; a voxel has image energy
    exactly where a ping reached it."""
    tiles, _ = imaged
    assert len(tiles) >= 3
    for t in tiles:
        c = t.coverage
        assert c.channels.sum(dtype=np.int64) == t.updates > 0
        np.testing.assert_array_equal(c.pings > 0, np.abs(t.image) > 0)
        assert c.pings.max() <= len(t.pings)
        assert np.all(c.channels <= c.pings.astype(np.int64) * c.n_channels)


def brute_force(tile, placed, geometry, window, cw):
    """Pings (0/1) and channels reaching each voxel of ``tile`` for one ping: every
    voxel and every channel tested (straight rays, water speed)."""
    g = tile.grid
    v = np.stack(np.meshgrid(g.along, g.cross, g.depth, indexing="ij"), axis=-1)
    tx, rx, b = placed.tx, placed.rx, placed.bore
    d1 = v - tx
    r1 = np.linalg.norm(d1, axis=-1)
    in_tx = d1 @ b >= r1 * math.cos(geometry.projector_half_angle)
    n = np.zeros(g.shape, dtype=np.int64)
    for e in rx:
        d2 = v - e
        r2 = np.linalg.norm(d2, axis=-1)
        t = (r1 + r2) / cw
        n += (in_tx & (d2 @ b >= r2 * math.cos(geometry.receiver_half_angle))
              & (t >= window[0]) & (t <= window[1]))
    return (n > 0).astype(np.int64), n


def test_coverage_of_one_ping_equals_a_brute_force_count(pings, hardware, demo_processing):
    from svss_daq.geometry import place_array
    from svss_proc.imaging.coverage import Coverage
    from svss_proc.imaging.grid import tile_grid
    from svss_proc.imaging.schedule import line_from_ping, ping_frame
    from svss_proc.tiles import Tile
    proc = small_processing(demo_processing).value
    geo = array_geometry(hardware.value)
    line = line_from_ping(pings[0], proc)
    checked = 0
    for p in pings[6:24:6]:
        placed = place_array(geo, p.nav, p.projector, ping_frame(line, p.nav, proc))
        k = int(np.floor(placed.tx[0] / proc.tile.length_m))
        tile = Tile(tile_grid(proc.tile, k), line, None, None,
                    coverage=Coverage.new(tile_grid(proc.tile, k).shape, geo.receivers))
        window = (2.9e-3, 3.2e-3)            # 4.35-4.8 m two-way: cuts the tile at both ends
        tile.coverage.add(tile.grid, 0, tile.grid.along.size, placed, geo, window,
                          proc.imaging, p.nav)
        want_p, want_c = brute_force(tile, placed, geo, window,
                                     proc.imaging.water_sound_speed_m_s)
        got_p, got_c = tile.coverage.pings, tile.coverage.channels.astype(np.int64)
        # the window's ends are compared in float: allow the odd voxel on its edge
        assert np.mean(got_p != want_p) < 1e-3
        assert np.abs(got_c - want_c).sum() <= 1e-3 * want_c.sum() + 2
        assert 0 < want_p.sum() < want_p.size          # the cone and window cut the tile
        checked += int(want_p.sum())
    assert checked > 5_000


def test_aperture_corners_hold_every_receiver(hardware):
    rx = array_geometry(hardware.value).receivers
    corners = aperture_corners(rx)
    assert 3 <= corners.size < rx.shape[0]
    # every receiver is a convex combination of the corners: no direction in the array
    # plane finds a receiver beyond the corners' extreme
    for ang in np.linspace(0, 2 * np.pi, 73):
        u = np.array([math.cos(ang), math.sin(ang)])
        assert (rx[:, :2] @ u).max() <= (rx[corners, :2] @ u).max() + 1e-12


def test_coverage_round_trips_and_old_tiles_still_read(imaged, hardware, tmp_path):
    tiles, proc = imaged
    t = max(tiles, key=lambda t: t.updates)
    path = write_tile(tmp_path / "tile_0001.h5", t, hardware, proc)
    got = read_tile(path)
    np.testing.assert_array_equal(got["coverage_pings"], t.coverage.pings)
    np.testing.assert_array_equal(got["coverage_channels"], t.coverage.channels)
    h = read_tile_header(path)
    np.testing.assert_array_equal(h["coverage_full_pings"], t.coverage.pings.max(axis=(0, 1)))
    assert h["attrs"]["projector_height_m"] == pytest.approx(t.coverage.mean_height_m)
    # a tile written before coverage existed: no coverage datasets, no error
    with h5py.File(path, "a") as f:
        for k in ("coverage_pings", "coverage_channels", "coverage_full_pings"):
            del f[k]
    old = read_tile(path)
    assert "coverage_pings" not in old
    np.testing.assert_array_equal(old["image"], t.image)


def test_next_tiles_planes_handed_back_are_complete_and_aperture_fraction(imaged):
    """Products without seams (docs/products.md, Seams): a tile is handed back with the
    next tile's first planes only when they are complete, so they equal that tile's
    final planes exactly; and the aperture fraction is 1 where the projector track
    spans a voxel's whole aperture, and falls towards the track's ends."""
    from svss_proc.imaging.coverage import aperture_fraction
    from svss_proc.imaging.imager import seam_planes
    tiles, proc = imaged
    n = seam_planes(proc.value)
    assert n == 30
    by_index = {t.grid.index: t for t in tiles}
    given = 0
    for t in tiles:
        nxt = by_index.get(t.grid.index + 1)
        if t.after is None or nxt is None:
            continue
        mag, ch = t.after
        np.testing.assert_array_equal(mag, np.abs(nxt.image[:n]).astype(np.float32))
        np.testing.assert_array_equal(ch, nxt.coverage.channels[:n])
        given += 1
    assert given >= 2
    c = tiles[len(tiles) // 2].coverage
    along = np.linspace(c.tx_along_min_m - 2.0, c.tx_along_max_m + 2.0, 201)
    f = aperture_fraction(along, np.array([0.0, 0.5]), (c.tx_along_min_m, c.tx_along_max_m),
                          2.0, math.tan(math.radians(25.0)))
    reach = 2.0 * math.tan(math.radians(25.0))
    inner = (along - reach >= c.tx_along_min_m) & (along + reach <= c.tx_along_max_m)
    np.testing.assert_allclose(f[inner, 0], 1.0)
    assert np.all(np.diff(f[along <= c.tx_along_min_m, 0]) >= 0)
    assert f[0, 0] == 0.0 and f[-1, 0] == 0.0
