"""``svss inspect`` on a raw run and on a tile, and ``svss score`` against a scene, run as
real commands on files written by the project's own writers (a test's further runs of
the same command, other options, through the command's function in process)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import h5py
import numpy as np
import pytest

from svss_daq.frames import TrackLine
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.rawfile import RawRunWriter
from svss_proc.imaging.grid import tile_grid
from svss_proc.products.chain import compute_products
from svss_proc.tiles import read_tile, write_tile

from . import VOXEL, make_tile, plant, rayleigh_median, speckle


def svss(*args, ok=True):
    res = subprocess.run([sys.executable, "-m", "svss", *args], capture_output=True,
                         text=True, timeout=120)
    if ok:
        assert res.returncode == 0, res.stderr[-3000:]
    return res


def svss_here(capsys, *args) -> str:
    """The command's function in this process (a test's further run of a command it has
    already run for real): its standard output."""
    from svss.cli import main
    capsys.readouterr()
    assert main([str(a) for a in args]) == 0
    return capsys.readouterr().out


HEADING = math.radians(30.0)


def write_raw_run(path, hardware):
    """Six pings (sequence 10..16, one missing), projectors 0, 1, 2 in turn, 0.1 m apart
    along a 30 deg heading; returns the first ping's samples."""
    dig = hardware.value.digitiser
    rng = np.random.default_rng(31)
    t0 = 1_790_000_000_000_000_000
    first = None
    with RawRunWriter(path, hardware, flush_every_pings=2,
                      environment={"sound_speed_indicative": 1490.0},
                      run_attrs={"scene_name": "inspect-test"}) as w:
        for i, seq in enumerate([10, 11, 12, 14, 15, 16]):
            s = 0.1 * i
            nav = NavSnapshot(time_ns=t0 + i * 100_000_000, north_m=100 + s * math.cos(HEADING),
                              east_m=200 + s * math.sin(HEADING), down_m=0.0,
                              vel_north_m_s=math.cos(HEADING), vel_east_m_s=math.sin(HEADING),
                              vel_down_m_s=0.0, roll_rad=0.0, pitch_rad=0.0,
                              heading_rad=HEADING, altitude_m=2.5, quality=12)
            samples = rng.integers(-3000, 3000, (dig.n_channels, dig.window_samples),
                                   dtype=np.int32)
            samples[5, 100] = 2 ** 21
            first = samples if first is None else first
            w.append(Ping(sequence=seq, projector=i % 3, transmit_time_ns=nav.time_ns,
                          sample_rate_hz=dig.sample_rate_hz, window_start_ns=1_000_000,
                          samples=samples, nav=nav, config_id=hardware.id))
        w.append_nmea(t0, "$GPGGA,120000.00,4052.0,N,07752.0,W,1,08,0.9,10.0,M,,,,*47")
        w.append_nmea(t0 + 1, "$GPVTG,30.0,T,,M,1.94,N,3.6,K,A*2C")
    return first


def test_inspect_raw_run(tmp_path, hardware, capsys):
    path = tmp_path / "run.h5"
    first = write_raw_run(path, hardware)
    s = json.loads(svss("inspect", str(path), "--json").stdout)
    assert s["kind"] == "raw" and s["clean"]
    assert s["run_attrs"]["scene_name"] == "inspect-test"
    assert s["hardware"]["config_id"] == hardware.id
    assert s["hardware"]["channels"] == hardware.value.digitiser.n_channels
    assert s["pings"] == {"n": 6, "first_sequence": 10, "last_sequence": 16,
                          "sequence_gaps": 1, "projectors": {"0": 2, "1": 2, "2": 2}}
    assert s["time"]["duration_s"] == pytest.approx(0.5)
    assert s["time"]["median_interval_s"] == pytest.approx(0.1)
    nav = s["navigation"]
    assert nav["track_length_m"] == pytest.approx(0.5)
    assert nav["mean_speed_m_s"] == pytest.approx(1.0)
    assert nav["heading_deg"] == pytest.approx([30.0, 30.0])
    # instrument records for re-navigation: NMEA only (a run without a DVL link)
    assert s["nmea_sentences"] == 2 and s["pd0_ensembles"] == 0
    assert s["ping_clock_events"] == 0 and s["renavigation_problem"] is None
    assert nav["quality_flags"] == [12]
    assert s["environment"] == {"sound_speed_indicative": 1490.0}
    assert s["nmea_sentences"] == 2
    fp = s["first_ping_samples"]
    assert fp["peak_counts"] == 2 ** 21
    assert fp["rms_counts"] == pytest.approx(np.sqrt(np.mean(first.astype(float) ** 2)))
    text = svss_here(capsys, "inspect", path)
    assert "SVSS raw run" in text and "6 (sequence 10 .. 16, 1 gap(s))" in text
    assert "PD0        0 ensemble(s), 0 ping-clock event(s); re-navigation: possible" in text


def test_inspect_tile(tmp_path, hardware, demo_processing, capsys):
    grid = tile_grid(demo_processing.value.tile, 3)
    img = speckle(grid.shape, np.random.default_rng(32))
    axes = (grid.along, grid.cross, grid.depth)
    plant(img, axes, (grid.along[75], grid.cross[30], grid.depth[20]), 1000.0)
    tile = make_tile(grid, TrackLine((1.0, 2.0), HEADING, 3.5), img, pings=range(50, 80),
                     updates=999)
    prods = compute_products(img, axes, VOXEL, demo_processing.value.products)
    path = write_tile(tmp_path / "tile_0003.h5", tile, hardware, demo_processing, prods)
    s = json.loads(svss("inspect", str(path), "--json").stdout)
    assert s["kind"] == "tile" and s["tile_index"] == 3 and s["shape"] == [150, 60, 50]
    assert s["pings"] == {"n": 30, "first": 50, "last": 79}
    assert s["axes"]["along"]["first_m"] == pytest.approx(grid.along[0])
    assert s["image"]["peak_at_m"] == pytest.approx([grid.along[75], grid.cross[30],
                                                     grid.depth[20]])
    assert s["image"]["peak_db_re_upa"] == pytest.approx(20 * np.log10(np.abs(img).max()),
                                                         abs=1e-3)
    assert s["line"]["heading_deg"] == pytest.approx(30.0)
    assert s["background"]["kernel_voxels"] == [61, 11, 5]
    assert s["provenance"]["processing_config_id"] == demo_processing.id
    det = read_tile(path)["detections"]
    assert len(s["detections"]) == len(det) == 1
    assert s["detections"][0]["along_m"] == pytest.approx(det["along_m"][0])
    text = svss_here(capsys, "inspect", path)
    assert "SVSS tile 3" in text and "detections 1" in text


def test_inspect_rejects_other_files(tmp_path):
    other = tmp_path / "x.h5"
    other.write_bytes(b"not hdf5")
    res = svss("inspect", str(other), ok=False)
    assert res.returncode == 2 and "x.h5" in res.stderr


SCENE = """
[scene]
name = "score-test"
description = "points for scoring"
seed = 1

[medium]
sound_speed_m_s = 1500.0
density_kg_m3 = 1000.0

[track]
start_time_utc = "2026-11-22T12:00:00Z"
start_ne_m = [100.0, 200.0]
heading_deg = 30.0
speed_m_s = 1.0
altitude_m = 2.5
body_down_m = 0.5
n_pings = 10

[noise]
electronic_rms_counts = 1.0
"""


def test_score_against_scene_truth(tmp_path, hardware, demo_processing, capsys):
    # scene frame: along from the first ping's body origin; the tiles here are imaged
    # on a line starting 0.5 m further along the track, so tile along = scene along - 0.5
    points = [(1.0, 0.1, 0.3, True), (2.2, -0.3, 0.6, True), (4.0, 0.2, 0.5, False),
              (50.0, 0.0, 0.5, False)]
    text = SCENE + "".join(f"\n[[points]]\nalong_m = {a}\ncross_m = {c}\ndepth_m = {d}\n"
                           f"target_strength_db = -20.0\n" for a, c, d, _ in points)
    scene = tmp_path / "scene.toml"
    scene.write_text(text)
    shift = 0.5
    line = TrackLine((100.0 + shift * math.cos(HEADING), 200.0 + shift * math.sin(HEADING)),
                     HEADING, 0.5 + 2.5)
    planted = [(a - shift, c, d) for a, c, d, p in points if p] + [(5.0 - shift, 0.0, 0.4)]
    out = tmp_path / "tiles"
    out.mkdir()
    rng = np.random.default_rng(33)
    for k in (0, 1):
        grid = tile_grid(demo_processing.value.tile, k)
        axes = (grid.along, grid.cross, grid.depth)
        img = speckle(grid.shape, rng)
        for pos in planted:
            plant(img, axes, pos, rayleigh_median(1.0) * 10 ** (30 / 20))
        prods = compute_products(img, axes, VOXEL, demo_processing.value.products)
        write_tile(out / f"tile_{k:04d}.h5", make_tile(grid, line, img, range(5)), hardware,
                   demo_processing, prods)
    report_path = tmp_path / "score.json"
    res = svss("score", str(out), "--scene", str(scene), "--out", str(report_path))
    r = json.loads(report_path.read_text())
    assert r["match_radius_m"] == demo_processing.value.products.detection.match_radius_m
    expected = {"truth": 3, "detections": 3, "hits": 2, "misses": 1, "false_alarms": 1,
                "duplicates": 0, "probability_of_detection": pytest.approx(2 / 3),
                "outside": 1, "level": "run"}
    assert {k: r["summary"][k] for k in expected} == expected
    # false alarms per tile and per square metre of the tiles' plan area
    t = demo_processing.value.tile
    area = 2 * t.length_m * t.width_m
    assert r["summary"]["plan_area_m2"] == pytest.approx(area)
    assert r["summary"]["false_alarms_per_m2"] == pytest.approx(1 / area)
    assert r["summary"]["false_alarms_per_tile"] == pytest.approx(0.5)
    assert sum(r["summary"]["false_alarms_by_tile"].values()) == 1
    status = [t["status"] for t in r["truth"]]
    assert status == ["detected", "detected", "missed", "outside"]
    for t in r["truth"][:2]:
        assert t["distance_m"] <= 0.5 * VOXEL * math.sqrt(3)
    assert "Pd = 0.67" in res.stdout and "false alarm" in res.stdout
    # a radius from the command line: 1.1 m lets the extra contact 1.03 m from the
    # third target detect it
    svss_here(capsys, "score", out, "--scene", scene, "--radius", "1.1", "--out", report_path)
    r = json.loads(report_path.read_text())
    assert r["match_radius_m"] == 1.1
    assert (r["summary"]["hits"], r["summary"]["misses"], r["summary"]["false_alarms"]) == \
        (3, 0, 0)


def test_score_names_the_tile_and_key_of_a_bad_stored_configuration(tmp_path, hardware,
                                                                    demo_processing, capsys):
    """The match radius comes from the tile's stored processing configuration, read by the
    configuration loader: a bad value is refused naming the file, the dataset and the key;
    a radius given on the command line is used without reading it."""
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + "\n[[points]]\nalong_m = 1.0\ncross_m = 0.0\ndepth_m = 0.5\n"
                     "target_strength_db = -20.0\n")
    grid = tile_grid(demo_processing.value.tile, 0)
    img = speckle(grid.shape, np.random.default_rng(34))
    prods = compute_products(img, (grid.along, grid.cross, grid.depth), VOXEL,
                             demo_processing.value.products)
    out = tmp_path / "tiles"
    out.mkdir()
    path = write_tile(out / "tile_0000.h5", make_tile(grid, TrackLine((100.0, 200.0), HEADING,
                                                                      3.0), img, range(5)),
                      hardware, demo_processing, prods)
    bad = demo_processing.text.replace("match_radius_m = 0.3", 'match_radius_m = "far"')
    assert bad != demo_processing.text
    with h5py.File(path, "a") as f:
        del f["provenance/processing_config_toml"]
        f["provenance/processing_config_toml"] = bad
    res = svss("score", str(out), "--scene", str(scene), ok=False)
    assert res.returncode == 2
    assert ("tile_0000.h5:/provenance/processing_config_toml: key "
            "'products.detection.match_radius_m'") in res.stderr and "--radius" in res.stderr
    assert "Pd = " in svss_here(capsys, "score", out, "--scene", scene, "--radius", "0.5")
