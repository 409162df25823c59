"""The live navigator over runs longer than its history window, and the fusion where
an instrument falls back: no true heading, a GPS outage without bottom lock, an
RMC-only receiver. Each case once went wrong by metres while flagged good."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from svss_daq import navigation as nav
from svss_daq.ping import (NAV_DEAD_RECKONED, NAV_GPS_FIX, NAV_HEADING_FROM_COURSE, NAV_HELD,
                           NAV_NO_HEADING)
from tests.daq.test_navigation import LEVER, ORIGIN, T0, cfg, make_sensors, truth  # noqa: F401

HISTORY_S = 60.0          # as config/acquire.toml [navigation] history_s


def _straight(duration_s: float, gps_until_s: float, height: bool = True):
    """1 m/s due north, level; DVL at 5 Hz with compass, GPS (antenna lever arm) at 5 Hz
    until ``gps_until_s``."""
    td = np.arange(0.0, duration_s, 0.2)
    dvl = [nav.DvlSample(T0 + int(round(t * 1e9)), (1.0, 0.0, 0.0), (2.0,) * 4, 0.0, 0.0,
                         heading_rad=0.0) for t in td]
    fixes = []
    for t in np.arange(0.0, gps_until_s, 0.2):
        ant = np.array([t, 0.0, 0.0]) + np.asarray(LEVER.gps_antenna_m)
        lat, lon, h = nav.ned_to_geodetic(ant, ORIGIN)
        fixes.append(nav.GpsFix(T0 + int(round(t * 1e9)), float(lat), float(lon),
                                float(h) if height else math.nan, 1, 0.3))
    return dvl, fixes


def _live(navr, dvl, fixes, times_s, lag_s=1.0):
    out, i, j = [], 0, 0
    for tp in times_s:
        limit = T0 + int((tp + lag_s) * 1e9)
        while i < len(dvl) and dvl[i].time_ns <= limit:
            navr.add_dvl(dvl[i])
            i += 1
        while j < len(fixes) and fixes[j].time_ns <= limit:
            navr.add_fix(fixes[j])
            j += 1
        out.append(navr.poses([T0 + int(round(tp * 1e9))])[0])
    return out


@pytest.mark.parametrize("gps_until_s, configured", [(0.0, True), (30.0, False)],
                         ids=["configured-origin-no-gps", "gps-lost-after-30s"])
def test_live_dead_reckoning_outlives_the_history_window(cfg, gps_until_s, configured):
    """Three history windows without a fix: the live poses keep dead reckoning from
    where the track was (the window's dropped records are carried as the filter's
    state), instead of restarting at the survey origin (72 m off after 185 s)."""
    c = cfg
    if configured:
        c = dataclasses.replace(cfg, origin_latitude_deg=ORIGIN[0],
                                origin_longitude_deg=ORIGIN[1], origin_height_m=ORIGIN[2])
    dvl, fixes = _straight(200.0, gps_until_s)
    navr = nav.Navigator(c, LEVER, history_s=HISTORY_S)
    if not configured:
        navr.origin = ORIGIN
    times = np.arange(5.0, 196.0, 1.0)
    poses = _live(navr, dvl, fixes, times)
    err = np.array([p.north_m for p in poses]) - times
    late = times > gps_until_s + HISTORY_S + 5
    assert late.sum() > 60
    assert np.max(np.abs(err)) < 0.05
    assert all(p.quality & NAV_DEAD_RECKONED and not p.quality & NAV_GPS_FIX
               for p, is_late in zip(poses, late) if is_late)


def test_live_latitude_and_longitude_are_the_poses_own(cfg):
    dvl, fixes = _straight(40.0, 40.0)
    navr = nav.Navigator(cfg, LEVER, history_s=HISTORY_S)
    poses = _live(navr, dvl, fixes, np.arange(3.0, 35.0, 0.5))
    origin = navr.survey_origin()
    for p in poses:
        lat, lon, _ = nav.ned_to_geodetic(np.array([p.north_m, p.east_m, p.down_m]), origin)
        assert abs(lat - p.latitude_deg) * 111e3 < 1e-3
        assert abs(lon - p.longitude_deg) * 111e3 * math.cos(math.radians(lat)) < 1e-3


def test_rmc_only_receiver_keeps_one_survey_plane(cfg):
    """No fix carries a height: the origin's latitude and longitude are the first fix's
    for the whole run (a window's first fix moved it: 36 m after 140 s)."""
    dvl, fixes = _straight(150.0, 150.0, height=False)
    navr = nav.Navigator(cfg, LEVER, history_s=HISTORY_S)
    times = np.arange(5.0, 145.0, 2.0)
    poses = _live(navr, dvl, fixes, times)
    first = np.asarray(LEVER.gps_antenna_m)[0]          # the origin is the first antenna fix
    err = np.array([p.north_m for p in poses]) - (times - first)
    assert np.max(np.abs(err)) < 0.05


def test_no_true_heading_does_not_carry_the_track(cfg):
    """16 s without HDT or compass inside a 120 s track: the DVL's velocities there are
    not turned with a made-up heading, so poses elsewhere stay right (they were 5-8 m
    off, flagged good); the poses inside are flagged."""
    fixes, heads, dvl = make_sensors(duration_s=120.0, dvl_hz=5.0, dvl_sigma=0.003, seed=2)
    gap = (52.0, 68.0)
    heads = [h for h in heads if not gap[0] * 1e9 <= h.time_ns - T0 <= gap[1] * 1e9]
    t = np.arange(5.0, 115.0, 0.5) + 0.013
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                              cfg, LEVER, ORIGIN)
    p, *_ = truth(t)
    err = np.hypot(*(np.array([[s.north_m, s.east_m] for s in poses]) - p[:, :2]).T)
    flagged = np.array([bool(s.quality & NAV_NO_HEADING) for s in poses])
    assert flagged.any() and np.max(err[~flagged]) < 0.1


def test_course_over_ground_does_not_carry_the_track(cfg):
    """20 s with only a course over ground 20 deg off the heading (a crabbing boat):
    unflagged poses stay right (they were 1.5-2.2 m off)."""
    fixes, heads, dvl = make_sensors(duration_s=120.0, dvl_hz=5.0, dvl_sigma=0.003, seed=2)
    gap = (50.0, 70.0)
    crab = [dataclasses.replace(h, heading_rad=h.heading_rad + math.radians(20.0),
                                from_course=True)
            for h in heads if gap[0] * 1e9 <= h.time_ns - T0 <= gap[1] * 1e9]
    heads = [h for h in heads if not gap[0] * 1e9 <= h.time_ns - T0 <= gap[1] * 1e9] + crab
    t = np.arange(5.0, 115.0, 0.5) + 0.013
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                              cfg, LEVER, ORIGIN)
    p, *_ = truth(t)
    err = np.hypot(*(np.array([[s.north_m, s.east_m] for s in poses]) - p[:, :2]).T)
    flagged = np.array([bool(s.quality & NAV_HEADING_FROM_COURSE) for s in poses])
    assert flagged.any() and np.max(err[~flagged]) < 0.1


def test_gps_interpolated_across_an_outage_without_lock_is_flagged_held(cfg):
    """A GPS outage and lost bottom lock together: the positions across the gap are an
    interpolation between fixes, flagged held (they carried no flag at all)."""
    fixes, heads, dvl = make_sensors(duration_s=100.0, dvl_hz=5.0, dvl_sigma=0.003,
                                     outage=(40.0, 60.0), seed=3)
    nan3 = (math.nan,) * 3
    dvl = [dataclasses.replace(d, velocity_body_m_s=nan3)
           if 40e9 <= d.time_ns - T0 <= 60e9 else d for d in dvl]
    t = np.array([38.0, 42.0, 50.0, 58.0, 62.0])
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                              cfg, LEVER, ORIGIN)
    held = [bool(p.quality & NAV_HELD) for p in poses]
    assert held == [False, True, True, True, False]
