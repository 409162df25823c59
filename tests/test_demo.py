"""End to end: `svss demo` (sim-device -> acquire -> ZeroMQ -> worker, separate processes,
the real drivers and the navigation from the simulated DVL and GPS) puts the built-in
scene's point targets, buried in silt under its interface and volume echoes, where they
are; its contacts are exactly those targets; and `svss process` on the recorded run gives
the same tiles."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from sim_device.scene import load_scene
from svss_daq.config import ProcessingConfig, config_path, load
from svss_daq.frames import TrackLine
from svss_daq.rawfile import RawRunReader
from svss_proc.imaging.grid import tile_index
from svss.demo import DEMO_SCENE
from svss.score import score_tiles
from svss_proc.tiles import read_tile

pytestmark = pytest.mark.slow

#: the worker writes each run's tiles into a folder named by the run id
RUN = "demo"
#: where the targets may be found, in the tile frame the worker took from the first
#: ping's measured pose: a voxel and a half in depth (each ping at its DVL altitude); the
#: navigation's drift relative to that first pose along and across (GPS 0.3 m smoothed
#: over 5 s with DVL dead reckoning: up to 0.17 m seen in two runs)
TOL_DEPTH_M = 0.03
TOL_HORIZONTAL_M = 0.25
#: the interface's own echo: this deep below it, m
INTERFACE_LAYER_M = 0.1


def svss(*args, cwd=None):
    res = subprocess.run([sys.executable, "-m", "svss", *args], capture_output=True,
                         text=True, timeout=900, cwd=cwd)
    assert res.returncode == 0, res.stderr[-3000:]
    return res


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    res = svss("demo", "--out", str(out))
    return out, res.stdout


def test_demo_writes_run_tiles_and_pngs(demo):
    out, stdout = demo
    listed = [Path(line.strip()) for line in stdout.splitlines() if line.startswith("  ")]
    raw = out / "runs" / f"{RUN}_000.h5"
    assert raw in listed
    tiles = [p for p in listed if p.suffix == ".h5" and p.name.startswith("tile_")]
    pngs = [p for p in listed if p.suffix == ".png"]
    assert len(tiles) >= 2 and len([p for p in pngs if p.name.startswith("tile_")]) == len(tiles)
    # the run's products: contacts with latitude and longitude, the mosaic, and (the
    # pings carry geodetic positions) the map products
    assert {"contacts.csv", "contacts.geojson", "mosaic.png", "mosaic.h5", "mosaic.tif",
            "contacts.gpkg"} <= {p.name for p in listed}
    for p in listed:
        assert p.is_file() and p.stat().st_size > 0
    for p in pngs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = matplotlib.image.imread(p)
        assert img.ndim == 3 and img.std() > 0.01
    scene = load_scene(config_path(DEMO_SCENE))
    with RawRunReader(raw) as run:
        # svss acquire --pings N records the pings delivered beside the N-th too (a loaded
        # daemon takes several per step: 91 of the 90-ping scene once, in a loaded suite)
        assert run.clean and len(run) >= scene.track.n_pings
        assert run.summary["counters"]["recorded"] == len(run)
        seq = run.ping_table()["ping_sequence"]
        c = run.summary["counters"]
        lost = c["never_delivered"] + c["not_recorded"] + c["assembly_errors"]
    # every sequence in order; a gap only where a ping was lost and the daemon's summary
    # counts it (the simulated sonar, loaded, once never delivered ping 29)
    assert seq[0] == 0 and np.all(np.diff(seq) >= 1)
    assert int(seq[-1]) + 1 - len(seq) == lost, c


def expected_in_tile(pt, scene, attrs) -> np.ndarray:
    """Where a scene point lies in a tile's frame: the scene places it along and across
    the true track from its first ping; the tile frame is the one the worker took from
    the first ping's *measured* pose (stored in the tile). Depth is below the interface,
    where each ping is placed at its DVL altitude."""
    tr = scene.track
    h = np.deg2rad(tr.heading_deg)
    north = tr.start_ne_m[0] + pt.along_m * np.cos(h) - pt.cross_m * np.sin(h)
    east = tr.start_ne_m[1] + pt.along_m * np.sin(h) + pt.cross_m * np.cos(h)
    line = TrackLine((float(attrs["line_origin_north_m"]), float(attrs["line_origin_east_m"])),
                     float(attrs["line_heading_rad"]), float(attrs["interface_down_m"]))
    along, cross, _ = line.ned_to_tile(np.array([north, east, 0.0]))
    return np.array([along, cross, pt.depth_m])


def test_targets_at_true_positions(demo):
    out, _ = demo
    scene = load_scene(config_path(DEMO_SCENE))
    tile_cfg = load(ProcessingConfig, config_path("processing-demo.toml")).tile
    tiles, truth = {}, {}
    # the tile frame starts at the first recorded ping's measured pose, not at the scene's
    # along-track zero (a loaded daemon may record its first ping later): a target's tile
    # is the one holding it in that frame, as the worker's grid says
    attrs = read_tile(sorted((out / "tiles" / RUN).glob("tile_*.h5"))[0])["attrs"]
    for pt in scene.points:
        want = expected_in_tile(pt, scene, attrs)
        k = tile_index(tile_cfg, float(want[0]))
        t = tiles.setdefault(k, read_tile(out / "tiles" / RUN / f"tile_{k:04d}.h5"))
        assert np.allclose(expected_in_tile(pt, scene, t["attrs"]), want)   # one frame
        truth.setdefault(k, []).append(want)
        mag = np.abs(t["image"])
        box = [np.flatnonzero(np.abs(ax - x) <= 0.3)
               for ax, x in zip((t["along"], t["cross"], t["depth"]), want)]
        sub = mag[np.ix_(*box)]
        i, j, m = np.unravel_index(sub.argmax(), sub.shape)
        peak = np.array([t["along"][box[0][i]], t["cross"][box[1][j]], t["depth"][box[2][m]]])
        err = np.abs(peak - want)
        assert np.all(err <= [TOL_HORIZONTAL_M, TOL_HORIZONTAL_M, TOL_DEPTH_M]), (pt, peak, want)
        # a real peak: well above the tile's median level
        assert 20 * np.log10(sub.max() / np.median(mag[mag > 0])) > 25
    # and the brightest voxel of each tile in the sediment (under the interface's own
    # layer, whose echo is brighter than the points) is one of the targets
    for k, t in tiles.items():
        below = t["depth"] > INTERFACE_LAYER_M
        mag = np.abs(t["image"])[:, :, below]
        i, j, m = np.unravel_index(mag.argmax(), mag.shape)
        peak = np.array([t["along"][i], t["cross"][j], t["depth"][below][m]])
        near = np.all(np.abs(np.array(truth[k]) - peak)
                      <= [TOL_HORIZONTAL_M, TOL_HORIZONTAL_M, TOL_DEPTH_M], axis=1)
        assert near.any(), (k, peak)


def test_the_contacts_are_exactly_the_targets(demo):
    """The run's contacts (what a crew gets) against the scene: every point detected,
    nothing else: no contact from the interface, the volume or the run's ends."""
    out, _ = demo
    r = score_tiles(out / "tiles" / RUN, config_path(DEMO_SCENE))
    s = r["summary"]
    assert s["truth"] == 6 and s["hits"] == 6, r["truth"]
    assert s["false_alarms"] == 0 and s["duplicates"] == 0, r["detections"]


# extended: the worker's tiles equal svss process's voxel for voxel in the default run
# through the real daemon (tests/acquire/test_daemon_restart.py, test_chain.py)
@pytest.mark.extended
def test_process_recorded_run_gives_the_same_tiles(demo, tmp_path):
    """``svss process`` through the command's function in this process (its kernels
    compiled once for the session; the real command runs in tests/test_renavigate.py)."""
    from svss.cli import main
    out, _ = demo
    # with the poses recorded live (svss process re-navigates by default: other poses)
    assert main(["process", str(out / "runs" / f"{RUN}_000.h5"), "--out", str(tmp_path),
                 "--processing", str(config_path("processing-demo.toml")),
                 "--no-renavigate"]) == 0
    live = sorted((out / "tiles" / RUN).glob("tile_*.h5"))
    again = sorted(tmp_path.glob("tile_*.h5"))
    assert [p.name for p in live] == [p.name for p in again]
    for a, b in zip(live, again):
        ta, tb = read_tile(a), read_tile(b)
        np.testing.assert_array_equal(ta["ping_sequence"], tb["ping_sequence"])
        np.testing.assert_allclose(tb["image"], ta["image"], rtol=0,
                                   atol=1e-5 * np.abs(ta["image"]).max())
