"""Micronavigation inside the re-navigation (svss_proc/micronav/renav.py through
svss_proc.run_worker.run_poses, as svss process and svss batch call it) on a short
recorded run: three pings of the seed's sand scene (projectors 5 0 1) whose true poses
have a sway step and a heave step that the navigation instruments did not see (their
records follow the straight track), written as the daemon writes a run (pings, the ping
clock, NMEA sentences and PD0 ensembles made by the project's encoders, the navigation
configuration). The navigation configuration states a DVL noise of ``STATED_DVL_SIGMA``
(a poor bottom: 10 mm a ping step), so the echoes' 2-3 mm weigh more. The re-navigated
increments miss the steps; fused with the echoes' increments they find them, the
5 -> 0 pair is refused for its reason, and the poses' description says so. (With the
configured 3 mm/s, 0.3 mm a step, the DVL's increments would weigh 70 times the
echoes': tests/micronav/test_fusion.py.)"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from sim_device.scene import load_scene
from sim_device.track import parse_utc_ns, pose_at
from svss_daq.config import (ConfigError, DevicesConfig, HardwareConfig, ProcessingConfig,
                             config_path, load, load_with_text)
from svss_daq.frames import body_to_ned
from svss_daq.nav.geodesy import ned_to_geodetic
from svss_daq.nav.renavigate import RenavigationError, navigation_config_text
from svss_daq.protocols import nmea_encoder as ne
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.rawfile import NAV_CONFIG_ATTR, RawRunReader, RawRunWriter
from svss_proc.run_worker import run_poses

from .posed_source import PosedSource

ORIGIN = (41.5240, -70.6710, 0.0)
PINGS = range(17, 20)                 # projectors 5 0 1
SWAY = (19, 0.020)                    # from ping 19 on, 20 mm to starboard (east) ...
HEAVE = (19, 0.005)                   # ... and 5 mm down
GPS_SIGMA, DVL_SIGMA = 0.3, 0.003
STATED_DVL_SIGMA = 0.1                # m/s, the recorded navigation configuration's
#: the acceleration prior left out (0.1 m a second difference): a step is no boat's motion
NO_ACCELERATION_PRIOR = 10.0


def offsets(i: int) -> np.ndarray:
    o = np.zeros(3)
    if i >= SWAY[0]:
        o[1] += SWAY[1]
    if i >= HEAVE[0]:
        o[2] += HEAVE[1]
    return o


def _records(track, hardware, seed_track, t0_ns, t1_ns, rng):
    """NMEA (GGA, RMC, HDT 5 Hz, ZDA 1 Hz) and PD0 (bottom track, ship coordinates,
    5 Hz) of the straight track, as the links deliver them: (receive ns, data)."""
    lever = hardware.lever_arms
    nmea, pd0 = [], []
    setup = Pd0Setup(coordinate_system="ship", beam_angle_deg=30.0)
    start = parse_utc_ns(track.start_time_utc)
    for k, t in enumerate(range(t0_ns, t1_ns, 200_000_000)):
        p = pose_at(track, (t - start) * 1e-9, seed_track)
        rot = body_to_ned(p.roll_rad, p.pitch_rad, p.heading_rad)
        ant = p.ned + rot @ np.asarray(lever.gps_antenna_m)
        ant[:2] += rng.normal(0.0, GPS_SIGMA, 2)
        lat, lon, h = (float(v) for v in ned_to_geodetic(ant, ORIGIN))
        lines = [ne.gga("GP", t, lat, lon, 2, 12, 0.9, h, 0.0),
                 ne.rmc("GP", t, True, lat, lon, 1.0, p.heading_rad),
                 ne.hdt("GP", p.heading_rad)]
        if k % 5 == 0:
            lines.append(ne.zda("GP", t))
        nmea += [(t + 30_000_000, b.decode("ascii").strip()) for b in lines]
        v_body = rot.T @ np.array([p.vel_north_m_s, p.vel_east_m_s, p.vel_down_m_s])
        v_body = v_body + rng.normal(0.0, DVL_SIGMA, 3)
        head_height = p.altitude_m - lever.dvl_m[2]    # RDI's range: vertical
        ens = encode_ensemble(setup, ensemble_number=k + 1, time_ns=t,
                              heading_rad=p.heading_rad, pitch_rad=p.pitch_rad,
                              roll_rad=p.roll_rad,
                              bt_velocity_m_s=[-v_body[1], -v_body[0], v_body[2], 0.0],
                              bt_range_m=[head_height] * 4)
        pd0.append((t + 50_000_000, ens))
    return nmea, pd0


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The run's path and the true poses of its pings."""
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    hw = loaded.value
    scene = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    scene = dataclasses.replace(scene, targets=())
    src = PosedSource(loaded, scene, offsets)
    pings = [src.ping(i) for i in PINGS]
    nav = dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                              origin_latitude_deg=ORIGIN[0], origin_longitude_deg=ORIGIN[1],
                              origin_height_m=ORIGIN[2],
                              dvl_velocity_sigma_m_s=STATED_DVL_SIGMA)
    first, last = pings[0].transmit_time_ns, pings[-1].transmit_time_ns
    nmea, pd0 = _records(scene.track, hw, scene.scene.seed, first - 3 * 10**9,
                         last + 3 * 10**9, np.random.default_rng(11))
    path = tmp_path_factory.mktemp("renav_micronav") / "run.h5"
    with RawRunWriter(path, loaded, run_attrs={NAV_CONFIG_ATTR:
                                               navigation_config_text(nav)}) as w:
        for p in pings:
            w.append(p)
            w.append_clock_reference(p.transmit_time_ns + 2_000_000, p.transmit_time_ns)
        for t, s in nmea:
            w.append_nmea(t, s)
        for t, b in pd0:
            w.append_pd0(t, b)
    return path, [p.nav for p in pings]


def _processing(enabled: bool):
    p = load_with_text(ProcessingConfig, config_path("processing.toml")).value
    return dataclasses.replace(p, micronav=dataclasses.replace(
        p.micronav, enabled=enabled, acceleration_sigma_m_s2=NO_ACCELERATION_PRIOR))


def test_the_fused_poses_find_the_steps_the_navigation_missed(recorded):
    path, truth = recorded
    true_inc = np.diff([n.ned for n in truth], axis=0)
    with RawRunReader(path) as run:
        plain, what_plain = run_poses([run], True, None, _processing(False))
        fused, what = run_poses([run], True, None, _processing(True))
    nav_err = np.diff([n.ned for n in plain], axis=0) - true_inc
    fus_err = np.diff([n.ned for n in fused], axis=0) - true_inc
    print("navigation step errors (mm)", np.round(nav_err * 1e3, 1).tolist())
    print("fused step errors (mm)", np.round(fus_err * 1e3, 1).tolist())
    print(what)
    # the navigation misses both steps (its DVL saw the straight track)
    assert abs(nav_err[1, 1]) > 0.8 * SWAY[1]
    assert abs(nav_err[1, 2]) > 0.8 * HEAVE[1]
    # fused, the echoes' increments carry them: sway within 6 mm, heave within 1.5 mm
    # (the estimator's sigma on this scene: about 2-3 mm across, 0.3-0.5 mm down)
    assert abs(fus_err[1, 1]) < 6e-3
    assert abs(fus_err[1, 2]) < 1.5e-3
    # the 5 -> 0 pair has no common phase centres; its step stays the navigation's
    np.testing.assert_allclose(fus_err[0], nav_err[0], atol=1e-3)
    assert "fused with 1 of 2 ping-to-ping increments from the echoes" in what
    assert "1 the phase centres do not overlap" in what
    assert what.startswith(what_plain)
    # attitude and the measured bottom depth are kept
    for a, b in zip(plain, fused):
        assert (a.roll_rad, a.pitch_rad, a.heading_rad) == (b.roll_rad, b.pitch_rad,
                                                            b.heading_rad)
        assert math.isclose(a.down_m + a.altitude_m, b.down_m + b.altitude_m, abs_tol=1e-9)


def test_micronavigation_needs_its_settings_and_the_re_navigation(recorded):
    path, _ = recorded
    demo = load_with_text(ProcessingConfig, config_path("processing-demo.toml")).value
    assert demo.micronav is None
    with RawRunReader(path) as run:
        # --micronav with a configuration without the table: the shipped settings
        # (it failed, "no [micronav] table")
        _, what = run_poses([run], True, True, demo)
        assert "echoes" in what
        with pytest.raises(RenavigationError, match="--no-renavigate"):
            run_poses([run], False, True, _processing(True))
        # the configuration's switch off and no flag: the re-navigated poses alone
        _, what = run_poses([run], True, None, _processing(False))
        assert "echoes" not in what


def test_the_micronav_table_is_checked_naming_file_and_key(tmp_path):
    text = Path(config_path("processing.toml")).read_text()
    bad = tmp_path / "processing.toml"
    bad.write_text(text.replace("acceleration_sigma_m_s2 = 0.2", "acceleration_sigma_m_s2 = -1"))
    with pytest.raises(ConfigError, match=rf"{bad}.*acceleration_sigma_m_s2"):
        load_with_text(ProcessingConfig, bad)


@pytest.mark.extended
def test_svss_process_and_batch_fuse_with_micronav_and_say_so(tmp_path, recorded):
    """The commands, in their own processes: the manifest (and each tile's provenance)
    says how many increments came from the echoes and why the others were refused."""
    import json
    import subprocess
    import sys

    from svss_proc.tiles import read_tile_header
    from tests.worker.conftest import small_processing_text
    path, _ = recorded
    text = Path(config_path("processing.toml")).read_text()
    table = text[text.index("[micronav]"):]
    table = table.replace("acceleration_sigma_m_s2 = 0.2",
                          f"acceleration_sigma_m_s2 = {NO_ACCELERATION_PRIOR!r}")
    proc = tmp_path / "processing.toml"
    proc.write_text(small_processing_text().split("\n[products]")[0] + "\n" + table)
    root = Path(__file__).resolve().parents[2]

    def svss(*args):
        return subprocess.run([sys.executable, "-m", "svss", *args], capture_output=True,
                              text=True, cwd=root, timeout=600)

    want = "fused with 1 of 2 ping-to-ping increments from the echoes"
    res = svss("process", str(path), "--out", str(tmp_path / "p"), "--processing",
               str(proc), "--micronav")
    assert res.returncode == 0, res.stderr[-3000:]
    manifest = json.loads((tmp_path / "p" / "manifest.json").read_text())
    assert want in manifest["poses"] and "1 the phase centres do not overlap" in \
        manifest["poses"]
    for t in sorted((tmp_path / "p").glob("tile_*.h5")):
        assert read_tile_header(t)["poses"] == manifest["poses"]
    # without the flag the configuration's switch (off) decides
    res = svss("process", str(path), "--out", str(tmp_path / "q"), "--processing", str(proc))
    assert res.returncode == 0, res.stderr[-3000:]
    assert "echoes" not in json.loads((tmp_path / "q" / "manifest.json").read_text())["poses"]
    pytest.importorskip("distributed")
    res = svss("batch", str(path), "--out", str(tmp_path / "b"), "--processing", str(proc),
               "--workers", "1", "--micronav")
    assert res.returncode == 0, res.stderr[-3000:]
    state = json.loads((tmp_path / "b" / "batch_state.json").read_text())
    assert want in json.dumps(state)
