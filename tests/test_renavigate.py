"""Re-navigation (svss_daq/nav/renavigate.py): the instrument records a run keeps (the
daemon's taps: each PD0 ensemble's exact bytes, each NMEA sentence as the parser reads
it), decoded again and fed to the navigation as the daemon feeds it, give the poses of
the truth the records were made from; ``svss process`` images with them and says so.

The records are made by the project's encoders (svss_daq/protocols/nmea_encoder.py,
pd0_encoder.py: written from NMEA 0183 and RDI's output-format manual) from a known
track; the daemon-made recording is tested in tests/acquire/test_renavigation.py."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

import h5py
import numpy as np
import pytest

from svss_daq.config import (ConfigError, DevicesConfig, ProcessingConfig, config_path,
                             load, load_with_text)
from svss_daq.daemon import _NmeaTap, _Pd0Tap
from svss_daq.protocols import nmea_encoder as ne
from svss_daq.protocols.nmea import NmeaStreamParser
from svss_daq.protocols.pd0 import Pd0StreamParser, decode_ensemble
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.frames import body_to_ned
from svss_daq.nav.geodesy import ned_to_geodetic
from svss_daq.nav.renavigate import (RenavigationError, navigation_config_from_text,
                                     navigation_config_text, records_problem, renavigate,
                                     renavigation)
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_CLOCK_RETIMED, NAV_GPS_FIX, NAV_SMOOTHED,
                           NavSnapshot, Ping)
from svss_daq.rawfile import NAV_CONFIG_ATTR, RawRunReader, RawRunWriter
from svss_proc.run_worker import process_raw

ROOT = Path(__file__).resolve().parents[1]
T0 = int(datetime(2026, 5, 1, 12, 0, 0, tzinfo=timezone.utc).timestamp()) * 10**9
ORIGIN = (41.5240, -70.6710, 0.0)
HEADING = math.radians(30.0)
SPEED = 1.0                  # m/s along HEADING
ALTITUDE = 2.5               # body origin above the bottom, m
GPS_SIGMA = 0.3              # m per axis (as config/sim-device.toml)
DVL_SIGMA = 0.003            # m/s per component
PING_S = 0.1
BIAS_N = 7.0                 # the recorded (live) poses' error, m north


def nav_config():
    """The project's navigation configuration with the survey origin of the track."""
    cfg = load(DevicesConfig, config_path("devices.toml")).navigation
    return dataclasses.replace(cfg, origin_latitude_deg=ORIGIN[0],
                               origin_longitude_deg=ORIGIN[1], origin_height_m=ORIGIN[2])


def truth(t_ns: int) -> NavSnapshot:
    s = (t_ns - T0) * 1e-9
    vn, ve = SPEED * math.cos(HEADING), SPEED * math.sin(HEADING)
    return NavSnapshot(int(t_ns), 10.0 + vn * s, 20.0 + ve * s, 0.0, vn, ve, 0.0, 0.0, 0.0,
                       HEADING, ALTITUDE)


def instrument_records(hardware, seconds: float, seed: int = 5, dvl_clock_s: float = 0.0):
    """(NMEA sentences, PD0 ensembles) as the links deliver them, each (receive time ns,
    data) from the truth: GGA, RMC and HDT at 5 Hz (30 ms latency), ZDA at 1 Hz, PD0
    bottom track in ship coordinates at 5 Hz (50 ms latency; the DVL's clock
    ``dvl_clock_s`` off), with the instruments' noise."""
    rng = np.random.default_rng(seed)
    lever = hardware.value.lever_arms
    rot = body_to_ned(0.0, 0.0, HEADING)
    nmea, pd0 = [], []
    setup = Pd0Setup(coordinate_system="ship", beam_angle_deg=30.0)
    n = int(seconds / 0.2)
    for k in range(n):
        t = T0 + k * 200_000_000
        p = truth(t)
        ant = p.ned + rot @ np.asarray(lever.gps_antenna_m)
        ant[:2] += rng.normal(0.0, GPS_SIGMA, 2)
        lat, lon, h = (float(v) for v in ned_to_geodetic(ant, ORIGIN))
        rx = t + 30_000_000
        lines = [ne.gga("GP", t, lat, lon, 2, 12, 0.9, h, 0.0),
                 ne.rmc("GP", t, True, lat, lon, SPEED, HEADING),
                 ne.hdt("GP", HEADING)]
        if k % 5 == 0:
            lines.append(ne.zda("GP", t))
        nmea += [(rx, b.decode("ascii").strip()) for b in lines]
        # the DVL: the bottom's velocity relative to the head, ship axes (X stbd, Y fwd,
        # Z up); RDI's range per beam is the vertical range (level head: its height)
        tp = t + 100_000_000
        q = truth(tp)
        v_body = rot.T @ np.array([q.vel_north_m_s, q.vel_east_m_s, 0.0])
        v_body = v_body + rng.normal(0.0, DVL_SIGMA, 3)
        head_height = ALTITUDE - lever.dvl_m[2]
        ens = encode_ensemble(setup, ensemble_number=k + 1,
                              time_ns=tp + int(dvl_clock_s * 1e9), heading_rad=HEADING,
                              pitch_rad=0.0, roll_rad=0.0,
                              bt_velocity_m_s=[-v_body[1], -v_body[0], v_body[2], 0.0],
                              bt_range_m=[head_height] * 4)
        pd0.append((tp + 50_000_000, ens))
    return nmea, pd0


def write_instrumented_run(path: Path, hardware, n_pings: int = 30, *,
                           nmea=True, pd0=True, config=True, keep_pd0=True,
                           dvl_clock_s: float = 0.0) -> Path:
    """A raw run as the daemon writes it: pings posed ``BIAS_N`` m north of the truth
    (the live poses), their transmit records received 2 ms after transmit (the ping
    clock), the instrument records of the truth (2 s before the first ping to 2 s
    after the last) and the navigation configuration."""
    dig = hardware.value.digitiser
    first = T0 + 2 * 10**9
    records = instrument_records(hardware, (n_pings * PING_S) + 4.0,
                                 dvl_clock_s=dvl_clock_s)
    attrs = {NAV_CONFIG_ATTR: navigation_config_text(nav_config())} if config else {}
    zeros = np.zeros((dig.n_channels, dig.window_samples), np.int32)
    with RawRunWriter(path, hardware, run_attrs=attrs) as w:
        for i in range(n_pings):
            t = first + int(i * PING_S * 1e9)
            live = dataclasses.replace(truth(t), north_m=truth(t).north_m + BIAS_N,
                                       quality=NAV_GPS_FIX | NAV_BOTTOM_LOCK)
            w.append(Ping(i, hardware.value.sequencer.projector_order[
                i % len(hardware.value.sequencer.projector_order)], t,
                dig.sample_rate_hz, round(dig.window_start_s * 1e9), zeros, live,
                hardware.id))
            w.append_clock_reference(t + 2_000_000, t)
        if nmea:
            for t, s in records[0]:
                w.append_nmea(t, s)
        if pd0:
            for t, b in records[1]:
                w.append_pd0(t, b)
    if not keep_pd0:
        with h5py.File(path, "a") as f:
            del f["Platform/PD0"]
    return path


@pytest.fixture(scope="module")
def instrumented(tmp_path_factory, hardware) -> Path:
    return write_instrumented_run(tmp_path_factory.mktemp("renav") / "run.h5", hardware)


# ------------------------------------------------------------------ the daemon's taps


def _stream(parts):
    return b"".join(parts)


def test_pd0_tap_keeps_exactly_the_bytes_of_every_ensemble_that_decoded():
    setup = Pd0Setup(coordinate_system="ship")
    ens = [encode_ensemble(setup, ensemble_number=k, time_ns=T0 + k * 10**8,
                           heading_rad=0.1 * k, pitch_rad=0.0, roll_rad=0.0,
                           bt_velocity_m_s=[0.1, -1.0, 0.0, 0.0], bt_range_m=[3.0] * 4)
           for k in range(1, 5)]
    corrupt = bytearray(ens[2])
    corrupt[40] ^= 0xFF                                  # checksum now wrong
    # garbage, a false header claiming a long ensemble, a corrupt one between good ones
    stream = _stream([b"\x00junk\x7f", ens[0], b"\x7f\x7f\xff\x00garbage", ens[1],
                      bytes(corrupt), ens[3], b"\x7f"])
    rng = np.random.default_rng(3)
    tap, plain = _Pd0Tap(keep=100000), Pd0StreamParser()
    got, want = [], []
    pos = 0
    while pos < len(stream):
        n = int(rng.integers(1, 90))
        got += tap.feed(stream[pos:pos + n])
        want += plain.feed(stream[pos:pos + n])
        pos += n
    got += tap.flush()
    want += plain.flush()
    # the tap decodes what the parser decodes, and keeps those ensembles' bytes exactly
    assert [e.ensemble_number for e in got] == [e.ensemble_number for e in want] == [1, 2, 4]
    assert [raw for _, raw in tap.raw] == [ens[0], ens[1], ens[3]]
    assert all(decode_ensemble(raw).ensemble_number == e.ensemble_number
               for (_, raw), e in zip(tap.raw, got))


def test_nmea_tap_keeps_each_sentence_as_the_parser_reads_it():
    tap = _NmeaTap(NmeaStreamParser(), keep=100000)
    gga = ne.gga("GP", T0, 41.5, -70.6, 1, 8, 1.0, 5.0, -28.0).decode().strip()
    hdt = ne.hdt("GP", 0.2).decode().strip()
    # junk glued in front of a sentence (a lost line end): the parser drops it, and so
    # does the tap
    recs = tap.feed(b"\x00\x13noise" + gga.encode() + b"\r\n$GP" + hdt.encode() + b"\r\n")
    assert [t for _, t in tap.raw] == [gga, hdt]
    assert len(recs) == 2


# ------------------------------------------------------------------ records and config


def test_navigation_configuration_text_round_trip_and_schema_growth(caplog):
    cfg = nav_config()
    text = navigation_config_text(cfg)
    assert navigation_config_from_text(text, "rec") == cfg
    # a run recorded before a key existed: the key from config/devices.toml, logged
    lines = [ln for ln in text.splitlines() if not ln.startswith("fixed_lag_s")]
    with caplog.at_level(logging.WARNING):
        old = navigation_config_from_text("\n".join(lines) + "\nretired_key = 1\n", "old")
    assert old == cfg
    assert "fixed_lag_s" in caplog.text and "retired_key" in caplog.text
    with pytest.raises(ConfigError, match="bad: .*dvl_min_beams"):
        navigation_config_from_text(text.replace("dvl_min_beams = 3", "dvl_min_beams = 9"),
                                    "bad")


def test_runs_without_instrument_records_are_refused_with_the_reason(tmp_path, hardware,
                                                                     instrumented):
    bare = write_instrumented_run(tmp_path / "bare.h5", hardware, 3, nmea=False, pd0=False)
    with pytest.raises(RenavigationError, match="bare.h5: records no NMEA sentence and no "
                       "PD0 ensemble"):
        renavigate(bare)
    old = write_instrumented_run(tmp_path / "old.h5", hardware, 3, keep_pd0=False)
    with RawRunReader(old) as r:      # a file written before the PD0 ensembles were kept
        assert not r.keeps_pd0 and r.pd0() == [] and len(r) == 3 and r.n_nmea > 0
        assert "written before the DVL's PD0 ensembles were recorded" in records_problem(r)
    with RawRunReader(instrumented) as r:
        assert records_problem(r) is None


# ------------------------------------------------------------------ the poses


def test_renavigation_recovers_the_track_the_records_were_made_from(instrumented):
    with RawRunReader(instrumented) as r:
        recorded = [r.nav(i) for i in range(len(r))]
        renav = renavigation(r)
    assert renav.n_nmea > 0 and renav.n_pd0 > 0 and renav.n_bad_pd0 == 0
    assert renav.config_source.endswith(f"/{NAV_CONFIG_ATTR}")
    assert renav.description.startswith(f"re-navigated from {renav.n_nmea} NMEA sentences "
                                        f"and {renav.n_pd0} PD0 ensembles")
    assert len(renav.poses) == len(recorded)
    err = [math.hypot(p.north_m - truth(p.time_ns).north_m,
                      p.east_m - truth(p.time_ns).east_m) for p in renav.poses]
    live = [math.hypot(p.north_m - truth(p.time_ns).north_m,
                       p.east_m - truth(p.time_ns).east_m) for p in recorded]
    assert [p.time_ns for p in renav.poses] == [p.time_ns for p in recorded]
    assert max(err) < 3 * GPS_SIGMA and min(live) > BIAS_N - 0.01, (max(err), min(live))
    assert all(abs(p.heading_rad - HEADING) < math.radians(1.0) for p in renav.poses)
    assert all(p.quality & NAV_GPS_FIX and p.quality & NAV_BOTTOM_LOCK
               and p.quality & NAV_SMOOTHED and not p.quality & NAV_CLOCK_RETIMED
               for p in renav.poses)
    # the same poses again: the records alone decide them
    again = renavigate(instrumented)
    assert [(p.north_m, p.east_m, p.heading_rad) for p in again] == \
        [(p.north_m, p.east_m, p.heading_rad) for p in renav.poses]


def test_instrument_clocks_are_judged_against_the_recorded_ping_clock(tmp_path, hardware):
    """A DVL whose clock is 3 years off: the recorded transmit records give the ping
    clock, the DVL's records are re-timed onto it as live, and the poses say so."""
    n = 150       # 15 s: a clock is judged over navigation.clock_window_s (10 s) of records
    run = write_instrumented_run(tmp_path / "clock.h5", hardware, n,
                                 dvl_clock_s=3 * 365 * 86400.0)
    with RawRunReader(run) as r:
        assert len(r.ping_clock()) == n and r.ping_clock()[0][1] == r.nav(0).time_ns
        poses = renavigate(r)
    assert all(p.quality & NAV_CLOCK_RETIMED and p.quality & NAV_BOTTOM_LOCK
               for p in poses)
    err = max(math.hypot(p.north_m - truth(p.time_ns).north_m,
                         p.east_m - truth(p.time_ns).east_m) for p in poses)
    assert err < 3 * GPS_SIGMA


def test_a_recorded_configuration_today_refuses_is_a_renavigation_error(tmp_path, hardware):
    run = write_instrumented_run(tmp_path / "cfg.h5", hardware, 3)
    with h5py.File(run, "a") as f:
        f.attrs[NAV_CONFIG_ATTR] = f.attrs[NAV_CONFIG_ATTR].replace("dvl_min_beams = 3",
                                                                    "dvl_min_beams = 9")
    with pytest.raises(RenavigationError, match="cfg.h5:/navigation_config_toml: key "
                       "'dvl_min_beams'"):
        renavigate(run)
    # svss process then images with the recorded poses (by default), logged
    from svss_proc.run_worker import run_poses
    with RawRunReader(run) as r:
        assert run_poses([r], None) == (None, "recorded live poses")
        with pytest.raises(RenavigationError):
            run_poses([r], True)


def test_a_given_configuration_replaces_the_recorded_one(instrumented):
    shifted = dataclasses.replace(nav_config(), origin_latitude_deg=ORIGIN[0] + 1e-4)
    base = renavigate(instrumented)
    moved = renavigation(instrumented, shifted)
    assert moved.config_source == "given"
    # the survey origin 1e-4 deg (11.1 m) north: every position 11.1 m further south
    dn = [a.north_m - b.north_m for a, b in zip(moved.poses, base)]
    assert np.allclose(dn, -11.1, atol=0.2), dn[:3]


# ------------------------------------------------------------------ svss process


def small_processing(tmp_path: Path) -> Path:
    """The worker tests' small tiles, without products (the poses are what is tested)."""
    from tests.worker.conftest import small_processing_text
    p = tmp_path / "small-processing.toml"
    p.write_text(small_processing_text().split("\n[products]")[0] + "\n")
    return p


def svss(*args):
    return subprocess.run([sys.executable, "-m", "svss", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=600)


@pytest.mark.slow
def test_svss_process_images_with_the_renavigated_poses_and_says_so(tmp_path, instrumented,
                                                                    hardware):
    from svss_proc.tiles import read_tile_header
    proc = small_processing(tmp_path)
    res = svss("process", str(instrumented), "--out", str(tmp_path / "renav"),
               "--processing", str(proc))
    assert res.returncode == 0, res.stderr[-3000:]
    with RawRunReader(instrumented) as r:
        what = f"re-navigated from {r.n_nmea} NMEA sentences and {r.n_pd0} PD0 ensembles"
        first_live = r.nav(0)
    assert what in res.stderr
    manifest = json.loads((tmp_path / "renav" / "manifest.json").read_text())
    assert manifest["poses"].startswith(what) and manifest["pings"] == 30
    tiles = sorted((tmp_path / "renav").glob("tile_*.h5"))
    assert tiles
    first = renavigate(instrumented)[0]
    for t in tiles:
        h = read_tile_header(t)
        assert h["poses"] == manifest["poses"]
        # the tile frame is the first ping's pose: the re-navigated one, not the live one
        assert h["attrs"]["line_origin_north_m"] == pytest.approx(first.north_m)
        assert abs(h["attrs"]["line_origin_north_m"] - first_live.north_m) > BIAS_N - 1
    # --no-renavigate: the recorded live poses (the same function, in this process)
    process_raw(instrumented, tmp_path / "live", load_with_text(ProcessingConfig, proc),
                renavigate=False)
    manifest = json.loads((tmp_path / "live" / "manifest.json").read_text())
    assert manifest["poses"] == "recorded live poses"
    h = read_tile_header(sorted((tmp_path / "live").glob("tile_*.h5"))[0])
    assert h["poses"] == "recorded live poses"
    assert h["attrs"]["line_origin_north_m"] == pytest.approx(first_live.north_m)


def test_renavigate_is_refused_for_a_run_without_records(tmp_path, hardware, caplog):
    """The command's function in this process (the test above runs the real command)."""
    from svss.cli import main
    bare = write_instrumented_run(tmp_path / "sim.h5", hardware, 3, nmea=False, pd0=False)
    assert main(["process", str(bare), "--out", str(tmp_path / "o"), "--renavigate"]) == 2
    assert "cannot re-navigate: " in caplog.text and "sim.h5: records no NMEA" in caplog.text
    assert not (tmp_path / "o").exists()           # refused before anything is written
    # by default such a run images with its recorded poses, and says so
    process_raw(bare, tmp_path / "d",
                load_with_text(ProcessingConfig, small_processing(tmp_path)))
    assert json.loads((tmp_path / "d" / "manifest.json").read_text())["poses"] == \
        "recorded live poses"
