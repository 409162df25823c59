"""The daemon's navigation monitor on its own (svss_daq/daemon_nav.py): a real
Navigator fed as the device readers feed it (NMEA records and PD0 ensembles made by the
project's encoders, received now), ping poses from it, the tally of their flags and its
events, the navigation's notices as run events, the status and the summary; no devices,
no daemon."""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np
import pytest

from svss_daq.daemon_nav import NavigationMonitor, NavTally
from svss_daq.daemon_run import RunState
from svss_daq.nav.geodesy import ned_to_geodetic
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX, NAV_HELD,
                           NavSnapshot)
from svss_daq.protocols import nmea_encoder as ne
from svss_daq.protocols.nmea import NmeaStreamParser
from svss_daq.protocols.pd0 import decode_ensemble
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble

from .conftest import local_setup

ORIGIN = (41.5240, -70.6710, 0.0)
HEADING = math.radians(30.0)
SPEED = 1.0
STEP_NS = 200_000_000            # GPS and DVL at 5 Hz


def _feed(nav: NavigationMonitor, t0: int, n: int, dvl_clock_s: float = 0.0,
          gps: bool = True) -> None:
    """``n`` epochs of GPS (GGA, RMC, HDT: the antenna on a straight line from the
    origin at 1 m/s; unless not ``gps``) and DVL bottom track up to ``t0``, received
    now."""
    parser = NmeaStreamParser()
    setup = Pd0Setup(coordinate_system="ship", beam_angle_deg=30.0)
    for k in range(n):
        t = t0 - (n - 1 - k) * STEP_NS
        s = k * STEP_NS * 1e-9 * SPEED
        ned = np.array([math.cos(HEADING) * s, math.sin(HEADING) * s, 0.0])
        lat, lon, h = (float(v) for v in ned_to_geodetic(ned, ORIGIN))
        for rec in parser.feed(ne.gga("GP", t, lat, lon, 2, 12, 0.9, h, 0.0)
                               + ne.rmc("GP", t, True, lat, lon, SPEED, HEADING)
                               + ne.hdt("GP", HEADING)) if gps else ():
            nav.on_nmea(rec)
        nav.on_pd0(decode_ensemble(encode_ensemble(
            setup, ensemble_number=k + 1, time_ns=t + int(dvl_clock_s * 1e9),
            heading_rad=HEADING, pitch_rad=0.0, roll_rad=0.0,
            bt_velocity_m_s=[0.0, -SPEED, 0.0, 0.0], bt_range_m=[2.0] * 4)))


@pytest.fixture
def monitor(tmp_path):
    setup = local_setup(tmp_path, links=True)
    run = RunState("nav")
    return setup, run, NavigationMonitor(setup, run)


def test_pings_are_posed_from_the_records_as_they_arrive(monitor):
    setup, run, nav = monitor
    assert not nav.has_data("gps") and not nav.has_data("dvl")
    t0 = time.time_ns()
    nav.add_reference(t0, t0)                   # the sequencer's clock is the host's
    assert not nav.caught_up(t0 - 10**9)        # no record yet: a ping waits
    _feed(nav, t0, 6)
    assert nav.has_data("gps") and nav.has_data("dvl")
    solution = nav.status()["solution"]          # the solution now
    assert solution["gps_fixes"] == 6 and solution["dvl_ensembles"] == 6
    assert solution["heading_source"] == "hdt" and solution["bottom_lock"]
    assert nav.caught_up(t0 - 500_000_000) and not nav.caught_up(t0 + 10**9)
    times = [t0 - 600_000_000, t0 - 400_000_000]
    poses = nav.poses(times)
    assert [p.time_ns for p in poses] == times
    for p in poses:
        assert p.quality & NAV_GPS_FIX and p.quality & NAV_BOTTOM_LOCK
        assert p.heading_rad == pytest.approx(HEADING, abs=1e-6)
        assert np.isfinite([p.north_m, p.east_m, p.altitude_m]).all()
    assert poses[1].north_m - poses[0].north_m == pytest.approx(
        0.2 * SPEED * math.cos(HEADING), abs=0.02)
    for p in poses:
        nav.count(p)
    assert run.counters.pose_errors == 0 and not run.events
    status = nav.status()
    assert status["mode"] == "gps" and status["no_gps_fix"] == 0
    assert status["pose"]["latitude_deg"] == pytest.approx(poses[1].latitude_deg)
    assert nav.summary() == {"mode": "gps", "dead_reckoned": 0, "no_gps_fix": 0,
                             "no_bottom_lock": 0, "last_quality": poses[1].quality,
                             "held": 0, "clock_retimed": 0}
    assert set(NavTally.STATE).isdisjoint(nav.summary())


def test_the_tally_says_when_the_navigation_changes(monitor, caplog):
    setup, run, nav = monitor
    caplog.set_level(logging.INFO, logger="svss_daq.daemon")
    t0 = time.time_ns()
    nav.add_reference(t0, t0)
    _feed(nav, t0, 3)
    good = NavSnapshot(t0, 1.0, 2.0, 3.0, 0, 0, 0, 0, 0, HEADING, 2.0,
                       quality=NAV_GPS_FIX | NAV_BOTTOM_LOCK)
    clear = setup.devices.navigation.held_clear_s
    seq = [good,
           dataclasses.replace(good, quality=NAV_DEAD_RECKONED | NAV_BOTTOM_LOCK),
           dataclasses.replace(good, quality=NAV_GPS_FIX),                 # lock lost
           dataclasses.replace(good, quality=NAV_HELD | NAV_BOTTOM_LOCK),
           dataclasses.replace(good, time_ns=t0 + int((clear + 1) * 1e9))]
    for p in seq:
        nav.count(p)
    kinds = [k for _, k, _ in run.events]
    assert kinds == ["navigation.gps_outage",
                     "navigation.gps_back", "navigation.bottom_lock_lost",
                     "navigation.gps_outage", "navigation.held",
                     "navigation.bottom_lock_back",
                     "navigation.gps_back", "navigation.held_end"]
    lost = [d for _, k, d in run.events if k == "navigation.bottom_lock_lost"]
    assert lost == ["no DVL bottom track: altitude unknown, no dead reckoning"]
    t = nav.tally
    assert (t.dead_reckoned, t.no_gps_fix, t.no_bottom_lock, t.held) == (1, 2, 1, 1)
    assert t.mode == "gps" and nav.status()["held"] == 1
    # every event is in the log too, under the daemon's name
    assert sum(r.name == "svss_daq.daemon" and r.getMessage().startswith("navigation.")
               for r in caplog.records) == len(kinds)


def test_the_navigations_notices_become_run_events(monitor):
    setup, run, nav = monitor
    t0 = time.time_ns()
    nav.add_reference(t0, t0)
    window = setup.devices.navigation.clock_window_s
    # the DVL's records of the last window and more, all received now, its clock an
    # hour behind
    _feed(nav, t0, int(window / (STEP_NS * 1e-9)) + 10, dvl_clock_s=-3600.0, gps=False)
    nav.notices()
    [(_, kind, detail)] = list(run.events)
    assert kind == "navigation.clock_offset" and "dvl clock -1.00 h" in detail
    nav.notices()                               # taken once
    assert run.n_events == 1
    pose = nav.poses([t0 - 10**9])[0]
    nav.count(pose)
    assert nav.tally.clock_retimed == 1


def test_without_navigation_links_pings_are_posed_unknown(tmp_path):
    setup = local_setup(tmp_path)
    run = RunState("bare")
    nav = NavigationMonitor(setup, run)
    t0 = time.time_ns()
    assert nav.caught_up(t0)                    # nothing to wait for
    poses = nav.poses([t0, t0 + 1])
    assert [p.time_ns for p in poses] == [t0, t0 + 1]
    assert all(math.isnan(p.north_m) and math.isnan(p.heading_rad) for p in poses)
    nav.count(poses[0])
    # no GPS and no DVL configured: neither an outage nor a lost lock to say
    assert not run.events and nav.tally.mode == "none"
    assert nav.tally.no_bottom_lock == 0
