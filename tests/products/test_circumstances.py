"""The circumstances of a run's pings (svss_proc.products.circumstances) on constructed
ping tables: stretches of missing pings, dead-reckoned and held poses; the counts among
the pings near a point against a brute force over every ping, the missing ones placed
one by one; the words; a tile's navigation flags through its file (and a tile without
them still read); the map's stretches in their colours."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import xarray as xr
from PIL import Image

from svss_daq.frames import TrackLine
from svss_daq.ping import NAV_DEAD_RECKONED, NAV_FUSED, NAV_GPS_FIX, NAV_HELD
from svss_proc.imaging.grid import tile_grid
from svss_proc.products.chain import tile_title
from svss_proc.products.circumstances import (KINDS, circumstances_text, counts_near,
                                              ping_track, stretches, tile_counts)
from svss_proc.products.raster import rgb8
from svss_proc.products.run_products import STRETCH_RGB, TRACK_RGB, write_mosaic_png
from svss_proc.tiles import read_tile_header, write_tile

from . import make_tile

T0 = 1_800_000_000_000_000_000
DT = 100_000_000                      # 10 pings a second
GOOD = NAV_GPS_FIX | NAV_FUSED
DR = NAV_DEAD_RECKONED | NAV_FUSED


def table(seqs, flags=None, step=(0.1, 0.0), start=(0.0, 0.0)):
    """Pings ``seqs`` on a straight track, ``step`` m (north, east) a ping."""
    s = np.asarray(seqs)
    return ping_track(s, T0 + DT * s, start[0] + step[0] * s, start[1] + step[1] * s,
                      flags)


def test_a_gap_is_one_missing_stretch_between_the_imaged_pings_around_it():
    seqs = [*range(0, 10), *range(15, 21)]
    t = table(seqs, [GOOD] * len(seqs))
    (gap,) = stretches(t)
    assert (gap.kind, gap.first_sequence, gap.last_sequence, gap.pings) == ("missing", 10,
                                                                            14, 5)
    assert (gap.start_ns, gap.end_ns) == (T0 + 10 * DT, T0 + 14 * DT)
    # its line runs between the imaged pings 9 and 15
    np.testing.assert_allclose(gap.north_m, [0.9, 1.5])
    assert tile_counts(seqs, [GOOD] * len(seqs)) == {
        "pings_missing": 5, "poses_dead_reckoned": 0, "poses_held": 0}


def test_pose_stretches_follow_the_flags_and_a_gap_ends_them():
    seqs = [*range(0, 10), *range(11, 20)]
    flags = {s: GOOD for s in seqs}
    for s in (3, 4, 5, 6, 8, 9, 11, 12):
        flags[s] = DR
    flags[15] = DR | NAV_HELD                  # dead-reckoned and held: counted as both
    flags[16] = NAV_HELD
    t = table(seqs, [flags[s] for s in seqs])
    found = stretches(t)
    got = [(x.kind, x.first_sequence, x.last_sequence, x.pings) for x in found]
    assert got == [("missing", 10, 10, 1), ("dead_reckoned", 3, 6, 4),
                   ("dead_reckoned", 8, 9, 2), ("dead_reckoned", 11, 12, 2),
                   ("dead_reckoned", 15, 15, 1), ("held", 15, 16, 2)]
    by = {(x.kind, x.first_sequence): x for x in found}
    # a line reaches halfway to the pings around it ...
    np.testing.assert_allclose(by["dead_reckoned", 3].north_m, [0.25, 0.3, 0.4, 0.5, 0.6,
                                                                0.65])
    # ... but not across a gap (ping 10 is missing)
    np.testing.assert_allclose(by["dead_reckoned", 8].north_m, [0.75, 0.8, 0.9])
    np.testing.assert_allclose(by["dead_reckoned", 11].north_m, [1.1, 1.2, 1.25])
    assert tile_counts(seqs, [flags[s] for s in seqs]) == {
        "pings_missing": 1, "poses_dead_reckoned": 9, "poses_held": 2}


def test_flags_not_known_make_no_pose_stretch():
    seqs = list(range(20))
    t = table(seqs)                                    # a tile written before the flags
    assert stretches(t) == []
    assert counts_near(t, 1.0, 0.0, 5.0) == {"pings_missing": 0,
                                             "poses_dead_reckoned": 0, "poses_held": 0}
    assert tile_counts(seqs) == {"pings_missing": 0}
    # a ping given twice (in two tiles) counts once; a ping without a position not at all
    t = ping_track([5, 3, 5, 4], [T0] * 4, [0.5, 0.3, 0.5, np.nan], [0.0] * 4,
                   [DR, GOOD, DR, DR])
    assert t.sequence.tolist() == [3, 5] and t.flags.tolist() == [GOOD, DR]


@pytest.mark.parametrize("step", [(0.1, 0.0), (0.05, 0.087), (-0.07, 0.07)])
def test_counts_near_a_point_equal_a_brute_force_over_every_ping(step):
    """The missing pings of each gap placed one by one on the straight line between the
    imaged pings around it (evenly by sequence), every ping's distance to the point
    tested: the counts must equal counts_near's for points and reaches all about."""
    rng = np.random.default_rng(7)
    missing = {*range(12, 20), *range(40, 41), *range(55, 80)}
    seqs = [s for s in range(120) if s not in missing]
    flags = {s: GOOD for s in seqs}
    for s in range(20, 35):
        flags[s] = DR
    for s in (35, 36, 90):
        flags[s] = NAV_HELD | DR
    # a wobbling track: the gaps' lines are straight between their imaged ends
    wobble = 0.03 * np.sin(np.arange(120) / 5.0)
    north = np.array([step[0] * s + wobble[s] for s in range(120)])
    east = np.array([step[1] * s - wobble[s] for s in range(120)])
    t = ping_track(seqs, [T0 + DT * s for s in seqs], north[seqs], east[seqs],
                   [flags[s] for s in seqs])
    # every ping's position: imaged ones where they are, missing ones on their gap's line
    pos = {s: (north[s], east[s]) for s in seqs}
    for a, b in zip(seqs[:-1], seqs[1:]):
        for k in range(a + 1, b):
            u = (k - a) / (b - a)
            pos[k] = (north[a] + u * (north[b] - north[a]), east[a] + u * (east[b] - east[a]))
    for _ in range(60):
        k = rng.integers(0, 120)
        p = (north[k] + rng.normal(0, 0.4), east[k] + rng.normal(0, 0.4))
        reach = float(rng.uniform(0.05, 3.0))
        near = [s for s in range(120) if np.hypot(pos[s][0] - p[0], pos[s][1] - p[1]) <= reach]
        want = {"pings_missing": sum(s in missing for s in near),
                "poses_dead_reckoned": sum(s not in missing
                                           and bool(flags[s] & NAV_DEAD_RECKONED)
                                           for s in near),
                "poses_held": sum(s not in missing and bool(flags[s] & NAV_HELD)
                                  for s in near)}
        assert counts_near(t, p[0], p[1], reach) == want, (p, reach)


def test_the_words():
    assert circumstances_text({"pings_missing": 0, "poses_dead_reckoned": 0,
                               "poses_held": 0}) == ""
    assert circumstances_text({"pings_missing": 8, "poses_dead_reckoned": 30,
                               "poses_held": 1}, partial_coverage=True) == \
        "gap 8 pings; dead-reckoned 30 poses; held 1 pose; partial coverage"
    assert circumstances_text({"pings_missing": 1}) == "gap 1 ping"


def test_a_tiles_navigation_flags_go_through_its_file_and_its_title(
        tmp_path, hardware, demo_processing):
    grid = tile_grid(demo_processing.value.tile, 0)
    line = TrackLine((0.0, 0.0), 0.0, 2.5)
    seqs = [*range(5, 12), *range(15, 30)]
    flags = [DR if 20 <= s < 25 else NAV_HELD if s == 29 else GOOD for s in seqs]
    tile = make_tile(grid, line, np.zeros(grid.shape, np.complex64), pings=seqs)
    tile.track = [(T0 + DT * s, 0.1 * s, 0.0, q) for s, q in zip(seqs, flags)]
    path = write_tile(tmp_path / "tile_0000.h5", tile, hardware, demo_processing, None)
    h = read_tile_header(path)
    assert h["ping_nav_flags"].dtype == np.uint32
    np.testing.assert_array_equal(h["ping_nav_flags"], flags)
    attrs = h["attrs"]
    assert (attrs["pings_missing"], attrs["poses_dead_reckoned"], attrs["poses_held"]) == \
        (3, 5, 1)
    with xr.open_dataset(path, engine="h5netcdf") as ds:       # CF flags, on the pings
        assert ds.ping_nav_flags.dims == ("ping_sequence",)
        meanings = ds.ping_nav_flags.attrs["flag_meanings"].split()
        masks = dict(zip(meanings, ds.ping_nav_flags.attrs["flag_masks"].tolist()))
        assert masks["dead_reckoned"] == NAV_DEAD_RECKONED and masks["held"] == NAV_HELD
    assert tile_title("tile_0000", tile).endswith(
        "; gap 3 pings; dead-reckoned 5 poses; held 1 pose")
    # a tile whose track has no flags (as written before they were kept) still reads
    tile.track = [row[:3] for row in tile.track]
    path = write_tile(tmp_path / "tile_0001.h5", tile, hardware, demo_processing, None)
    with h5py.File(path) as f:
        assert "ping_nav_flags" not in f and "poses_held" not in f.attrs
    h = read_tile_header(path)
    assert "ping_nav_flags" not in h and h["attrs"]["pings_missing"] == 3
    np.testing.assert_array_equal(h["ping_time"], [T0 + DT * s for s in seqs])


#: the map view's box in the test's PNG (write_mosaic_png's layout: 0.95 in left, 0.45 in
#: top; a 1 m x 2 m plan at 4.5 inches a metre), inches: left, top, width, height
VIEW_IN = (0.95, 0.45, 4.5, 9.0)


def _view_pixels(path, dpi: int) -> np.ndarray:
    """The map view of a mosaic PNG (RGB), a pixel inside its frame."""
    rgb = np.asarray(Image.open(path).convert("RGB"))
    x0, y0 = (int(round(v * dpi)) for v in VIEW_IN[:2])
    x1, y1 = (int(round((VIEW_IN[0] + VIEW_IN[2]) * dpi)),
              int(round((VIEW_IN[1] + VIEW_IN[3]) * dpi)))
    return rgb[y0 + 1:y1 - 1, x0 + 1:x1 - 1]


def _where(view: np.ndarray, colour) -> tuple[np.ndarray, np.ndarray]:
    return np.nonzero(np.all(view == rgb8(colour), axis=2))


def test_the_map_draws_the_track_and_each_stretch_in_its_colour(tmp_path,
                                                               demo_processing):
    """A plan view 1 m east x 2 m north, the track up its middle: each kind of stretch
    shows in its colour along both edges of the swath (not over the image), the track
    in its own; without stretches none of their colours, without pings no track."""
    cell = 0.02
    north = (np.arange(100) + 0.5) * cell
    east = (np.arange(50) + 0.5) * cell
    rng = np.random.default_rng(3)
    m = {"north": north, "east": east, "cell_m": cell,
         "mip_db": rng.normal(0.0, 3.0, (100, 50)).astype(np.float32),
         "tile": np.zeros((100, 50), np.int32)}
    seqs = [s for s in range(20) if s not in (8, 9, 10)]
    flags = [DR if 3 <= s <= 6 else NAV_HELD if s >= 16 else GOOD for s in seqs]
    t = table(seqs, flags, step=(0.1, 0.0), start=(0.0, 0.5))
    pcfg = demo_processing.value.products
    dpi = pcfg.quicklook.dpi
    swath = (TrackLine((0.0, 0.5), 0.0, 2.5), -0.5, 0.5)
    marked = write_mosaic_png(tmp_path / "marked.png", m, [], pcfg, "marked", 12, t,
                              stretches(t), swath)
    clean = write_mosaic_png(tmp_path / "clean.png", m, [], pcfg, "clean", 12,
                             table(range(20), [GOOD] * 20, start=(0.0, 0.5)), [], swath)
    bare = write_mosaic_png(tmp_path / "bare.png", m, [], pcfg, "bare", 12)
    view = _view_pixels(marked, dpi)
    width = view.shape[1]
    for kind in KINDS:
        ys, xs = _where(view, STRETCH_RGB[kind])
        assert xs.size > 20, kind
        # on both edges of the swath, none over its middle
        assert np.all((xs < 0.1 * width) | (xs > 0.9 * width)), kind
        assert (xs < 0.1 * width).any() and (xs > 0.9 * width).any(), kind
    # along the track where they happened (north up: rows from the top)
    rows = {k: _where(view, STRETCH_RGB[k])[0] for k in KINDS}
    assert rows["held"].max() < rows["missing"].min() < rows["missing"].max() \
        < rows["dead_reckoned"].min()
    ys, xs = _where(view, TRACK_RGB)
    assert xs.size > 20 and np.all(np.abs(xs - width / 2) < 0.05 * width)
    view = _view_pixels(clean, dpi)
    assert _where(view, TRACK_RGB)[0].size > 20
    assert not any(_where(view, STRETCH_RGB[k])[0].size for k in KINDS)
    # the legend names every kind (under the map) even where none happened
    assert Image.open(clean).size[1] > Image.open(bare).size[1]
    view = _view_pixels(bare, dpi)
    assert not any(_where(view, c)[0].size for c in (*STRETCH_RGB.values(), TRACK_RGB))
