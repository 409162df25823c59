"""The autofocus as a stage of `svss process` (svss_proc/micronav/af_stage.py), through
the CLI's main function on real raw-run HDF5 files.

- The seed's sand (interface; no volume, for synthesis time) with three points buried
  0.30-0.60 m in it, the pings synthesised at the true poses and recorded with a
  navigation spoiled by a smooth cross-track and vertical wander (1 cm): with
  ``--autofocus`` the manifest says applied and the buried points' peaks in the tiles
  rise; with ``--no-autofocus`` they are those of the spoiled navigation.
- The same sand without the points: no isolated response, the manifest says refused and
  why, and the tiles are, voxel for voxel, those made without the stage.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from sim_device.scene import PointTarget
from sim_device.track import truth_line
from svss.cli import main
from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.rawfile import RawRunWriter
from svss_proc.micronav.autofocus import shifted
from svss_proc.tiles import read_tile

from ..computed_once import computed_once
from .posed_source import PosedSource, interface_sand_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_focus  # noqa: E402

#: along (from the first ping's body origin), cross, depth below the interface (m)
BURIED = ((5.0, 0.0, 0.30), (5.8, 0.32, 0.45), (6.6, -0.40, 0.60))
PINGS = range(0, 58)

pytestmark = pytest.mark.slow


def _wander(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The recorded navigation's error (cross-track, down), m: smooth, about 1 cm."""
    return (0.008 * np.sin(2 * math.pi * k / 30.0),
            0.006 * np.sin(2 * math.pi * k / 24.0 + 1.0))


def _record(path: Path, points: bool) -> Path:
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    sand = interface_sand_scene()
    scene = dataclasses.replace(sand, points=tuple(
        PointTarget(a, c, d, -20.0) for a, c, d in BURIED) if points else ())
    src = PosedSource(loaded, scene, lambda i: np.zeros(3))
    line = truth_line(scene.track)
    pings = [src.ping(i) for i in PINGS]
    ey, ez = _wander(np.arange(len(pings)))
    with RawRunWriter(path, loaded) as rec:
        for p, y, z in zip(pings, ey, ez):
            rec.append(shifted(p, line, float(y), float(z)))
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(the processing file, the run with the points, the run without, their folder):
    recorded once for the session's workers (the files stay in the first one's
    folder)."""
    def record():
        folder = tmp_path_factory.mktemp("af_stage")
        # the demo's tiles narrowed to the points (cross-track within 0.5 m, depth to
        # 0.8 m below the seabed): a third of the imaging, the same responses
        base = folder / "processing-narrow.toml"
        text = bench_focus.DEFAULT_PROCESSING.read_text()
        narrow = text.replace("width_m = 1.2", "width_m = 1.0").replace(
            "depth_m = 1.0", "depth_m = 0.8", 1)
        assert narrow.count("width_m = 1.0") == 1 and "depth_m = 0.8" in narrow
        base.write_text(narrow)
        proc = bench_focus.sand_processing(base, folder)
        assert proc.value.autofocus is None       # the settings: config/processing.toml's
        return (proc.source, _record(folder / "points.h5", True),
                _record(folder / "plain.h5", False), folder)
    return computed_once(tmp_path_factory, "test_autofocus_stage-runs", record)


def _process(run: Path, out: Path, processing: str, *flags: str) -> dict:
    assert main(["-q", "process", str(run), "--out", str(out), "--processing", processing,
                 "--no-renavigate", *flags]) == 0
    return json.loads((out / "manifest.json").read_text())


def _tiles(out: Path) -> list[dict]:
    return [read_tile(p) for p in sorted(out.glob("tile_*.h5"))]


def _peaks(tiles: list[dict]) -> np.ndarray:
    """Each buried point's peak: the largest magnitude of the tiles within 6 cm of it."""
    out = []
    for a, c, d in BURIED:
        best = 0.0
        for t in tiles:
            ia = np.flatnonzero(np.abs(t["along"] - a) <= 0.061)
            ic = np.flatnonzero(np.abs(t["cross"] - c) <= 0.061)
            iz = np.flatnonzero(np.abs(t["depth"] - d) <= 0.061)
            if ia.size and ic.size and iz.size:
                best = max(best, float(np.abs(t["image"][np.ix_(ia, ic, iz)]).max()))
        out.append(best)
    return np.array(out)


def test_autofocus_stage_raises_the_buried_points(runs, tmp_path):
    processing, run, _, _ = runs
    off = _process(run, tmp_path / "off", processing, "--no-autofocus")
    on = _process(run, tmp_path / "on", processing, "--autofocus")
    assert off["autofocus"] == {"enabled": False}
    af = on["autofocus"]
    print(af)
    assert af["enabled"] and af["applied"], af
    assert af["reason"] == "sharper" and af["points"] == 3
    assert af["gain_db_mean"] > 0
    assert af["corrections_rms_mm"]["cross"] > 0 and af["corrections_rms_mm"]["down"] > 1
    assert "autofocus applied on 3 points" in on["poses"]
    tiles_on, tiles_off = _tiles(tmp_path / "on"), _tiles(tmp_path / "off")
    assert all("autofocus applied" in t["poses"] for t in tiles_on)
    before, after = _peaks(tiles_off), _peaks(tiles_on)
    gain = 20 * np.log10(after / before)
    print("tile peaks, with over without the autofocus (dB):", np.round(gain, 2))
    assert np.all(gain > -0.1) and np.mean(gain) > 0.3, gain


def test_autofocus_stage_refuses_without_isolated_points(runs, tmp_path):
    processing, _, plain, _ = runs
    off = _process(plain, tmp_path / "off", processing)      # default: [autofocus] enabled
    on = _process(plain, tmp_path / "on", processing, "--autofocus")
    assert off["autofocus"] == {"enabled": False}
    af = on["autofocus"]
    assert af["enabled"] and not af["applied"], af
    assert re.match(r"no isolated response", af["reason"]), af
    assert af["points"] == 0 and af["corrections_rms_mm"] == {"cross": 0.0, "down": 0.0}
    assert "autofocus refused (no isolated response" in on["poses"]
    a, b = _tiles(tmp_path / "on"), _tiles(tmp_path / "off")
    assert len(a) == len(b) and a
    for x, y in zip(a, b):
        assert np.array_equal(x["image"], y["image"])
        assert "autofocus refused" in x["poses"]


@pytest.mark.extended
def test_svss_batch_autofocuses_as_svss_process(runs, tmp_path):
    """`svss batch --autofocus` (one local Dask worker): the run's state says applied as
    the manifest of `svss process --autofocus` does, and the tiles are the same."""
    processing, run, _, _ = runs
    manifest = _process(run, tmp_path / "process", processing, "--autofocus")
    assert main(["-q", "batch", str(run), "--out", str(tmp_path / "batch"), "--processing",
                 processing, "--no-renavigate", "--autofocus", "--workers", "1"]) == 0
    state = json.loads((tmp_path / "batch" / "batch_state.json").read_text())
    (entry,) = state["runs"].values()
    assert entry["autofocus"] == manifest["autofocus"] and entry["autofocus"]["applied"]
    assert entry["poses"] == manifest["poses"]
    got = {p.name: read_tile(p) for p in (tmp_path / "batch" / entry["folder"]).glob(
        "tile_*.h5")}
    want = {p.name: read_tile(p) for p in (tmp_path / "process").glob("tile_*.h5")}
    assert got.keys() == want.keys() and got
    for name in got:
        np.testing.assert_array_equal(got[name]["image"], want[name]["image"])
        assert "autofocus applied" in got[name]["poses"]
