"""The navigation's Kalman filter and RTS smoother against an independent solution, and
the fusion's ping-to-ping geometry against the accuracy a synthetic aperture needs.

A linear Gaussian model's RTS-smoothed states are its weighted least-squares states (the
prior, every process step and every measurement as one weighted equation each); the
filter's state at step k is the same solution with the measurements up to k only. Both
are computed here by a dense least-squares solve, independent of the recursions."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from svss_daq import navigation as nav
from svss_daq.nav.kalman import filter_smooth
from svss_daq.ping import NAV_DEAD_RECKONED, NAV_GPS_FIX, NAV_HELD
from svss_daq.frames import body_to_ned
from svss_daq.nav.dvl_geometry import head_height_m
from tests.daq.test_navigation import (LEVER, ORIGIN, T0, cfg, make_sensors,  # noqa: F401
                                       point_of, truth)


def _problem(rng, k_n=120, bias=True, meas_var=0.09):
    dt = rng.uniform(0.15, 0.25, k_n - 1)
    u = rng.normal(0.2, 0.05, k_n - 1)
    if bias:
        f01, f11 = dt, np.exp(-dt / 600.0)
        qc = 0.003 ** 2 * (1 - f11 ** 2)
        h1 = np.zeros(0)
    else:                                                # bottom depth: a random walk
        f01, f11 = np.zeros(k_n - 1), np.ones(k_n - 1)
        qc = 0.002 ** 2 * dt
    qp = (0.003 * dt) ** 2
    n_m = 150
    step = np.sort(rng.integers(0, k_n, n_m))
    h0 = np.ones(n_m) if bias else np.where(rng.random(n_m) < 0.5, 1.0, -1.0)
    h1 = np.zeros(n_m) if bias else np.where(h0 < 0, 1.0, 0.0)
    z = rng.normal(0.0, 1.0, n_m)
    r = np.full(n_m, meas_var) * rng.uniform(0.5, 2.0, n_m)
    x0, p0 = np.array([0.1, 0.0]), np.diag([4.0, 0.003 ** 2 if bias else 4.0])
    return x0, p0, u, f01, f11, qp, np.broadcast_to(qc, qp.shape).copy(), (step, h0, h1, z, r)


def _least_squares(x0, p0, u, f01, f11, qp, qc, meas, upto=None):
    """States (K, 2) minimising the weighted squares of the prior, the process and the
    measurements (those at steps <= ``upto`` only)."""
    k_n = u.size + 1
    step, h0, h1, z, r = meas
    rows, rhs = [], []

    def eq(coeffs, value, var):
        row = np.zeros(2 * k_n)
        for i, c in coeffs:
            row[i] = c
        w = 1.0 / math.sqrt(var)
        rows.append(row * w)
        rhs.append(value * w)

    eq([(0, 1.0)], x0[0], p0[0, 0])
    eq([(1, 1.0)], x0[1], p0[1, 1])
    for k in range(k_n - 1):
        eq([(2 * k + 2, 1.0), (2 * k, -1.0), (2 * k + 1, -f01[k])], u[k], qp[k])
        eq([(2 * k + 3, 1.0), (2 * k + 1, -f11[k])], 0.0, qc[k])
    for s, a, b, zz, rr in zip(step, h0, h1, z, r):
        if upto is None or s <= upto:
            eq([(2 * s, a), (2 * s + 1, b)], zz, rr)
    x, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return x.reshape(k_n, 2)


@pytest.mark.parametrize("bias", [True, False], ids=["velocity-bias", "bottom-depth"])
def test_smoother_is_the_least_squares_solution(bias):
    args = _problem(np.random.default_rng(7), bias=bias)
    xs, ps = filter_smooth(*args, smooth=True)
    ref = _least_squares(*args)
    assert np.max(np.abs(xs - ref)) < 1e-9 * max(1.0, np.max(np.abs(ref)))
    assert np.all(ps[:, 0, 0] > 0) and np.allclose(ps[:, 0, 1], ps[:, 1, 0])


def test_filter_uses_only_the_past():
    args = _problem(np.random.default_rng(11))
    xf, _ = filter_smooth(*args, smooth=False)
    for k in (0, 17, 60, 119):
        ref = _least_squares(*args, upto=k)
        assert np.max(np.abs(xf[k] - ref[k])) < 1e-9, k
    xs, _ = filter_smooth(*args, smooth=True)
    assert np.max(np.abs(xs[-1] - xf[-1])) < 1e-12        # at the end they agree


def test_rtk_noise_and_vague_prior_stay_stable():
    """Centimetre fixes on a 100 m prior (eight decades apart), 0.1 mm DVL noise: the
    recursions keep the covariance positive and agree with least squares."""
    args = list(_problem(np.random.default_rng(3), meas_var=1e-4))
    args[1] = np.diag([1e4, 0.003 ** 2])
    args[5] = (1e-4 * np.diff(np.arange(args[2].size + 1)) * 0.2) ** 2 + 1e-14
    xs, ps = filter_smooth(*args, smooth=True)
    ref = _least_squares(*args)
    assert np.all(np.isfinite(xs)) and np.all(ps[:, 0, 0] > 0)
    assert np.max(np.abs(xs[:, 0] - ref[:, 0])) < 1e-6


def _aperture_errors(poses, t, window_s=2.5):
    """Within each synthetic aperture (``window_s`` of pings): the rms spread of the
    horizontal error of the array's centre (placed with each pose's own attitude, as the
    imager places it) and of the altitude error about their means (a constant offset
    moves the image; the spread defocuses it), m."""
    p, *_ = truth(t)
    arm = np.asarray(LEVER.array_m)
    got = np.array([s.ned + body_to_ned(s.roll_rad, s.pitch_rad, s.heading_rad) @ arm
                    for s in poses])
    alt_err = np.array([s.altitude_m for s in poses]) - (4.0 - p[:, 2])
    err = got[:, :2] - point_of(t, LEVER.array_m)[:, :2]
    n = int(round(window_s / (t[1] - t[0])))
    horiz, vert = [], []
    for i in range(0, t.size - n, n // 2):
        e = err[i:i + n] - err[i:i + n].mean(axis=0)
        a = alt_err[i:i + n] - alt_err[i:i + n].mean()
        horiz.append(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))
        vert.append(np.sqrt(np.mean(a ** 2)))
    return np.array(horiz), np.array(vert)


def test_ping_to_ping_geometry_within_an_eighth_wavelength(cfg):
    """GPS at 5 Hz with 0.3 m of white noise, a DVL at the configured noise: within every
    2.5 s aperture the poses' horizontal and altitude errors vary by less than lambda/8
    (7 mm at 27.5 kHz). The GPS-minus-DR offset smoother varied by 20-38 mm."""
    fixes, heads, dvl = make_sensors(duration_s=120.0, dvl_hz=5.0, gps_sigma=0.3,
                                     dvl_sigma=cfg.dvl_velocity_sigma_m_s, seed=4)
    t = np.arange(5.0, 115.0, 0.1) + 0.013
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                              cfg, LEVER, ORIGIN)
    horiz, vert = _aperture_errors(poses, t)
    print(f"within 2.5 s: horizontal spread max {horiz.max() * 1e3:.1f} mm "
          f"(median {np.median(horiz) * 1e3:.1f}), altitude {vert.max() * 1e3:.1f} mm")
    assert horiz.max() < 0.007 and vert.max() < 0.007
    causal = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                               cfg, LEVER, ORIGIN, causal=True)
    h_c, v_c = _aperture_errors(causal, t)
    print(f"causal filter (for comparison, not used): horizontal {h_c.max() * 1e3:.1f} mm, "
          f"altitude {v_c.max() * 1e3:.1f} mm")


def test_dead_reckoning_from_a_configured_origin_without_gps(cfg):
    """No GPS at all, a configured survey origin: the DVL carries the track from it
    (the body origin there at the first DVL sample), flagged dead-reckoned."""
    _, heads, dvl = make_sensors(duration_s=30.0, dvl_hz=5.0, dvl_sigma=0.003, seed=2)
    p0, *_ = truth(np.array([(dvl[0].time_ns - T0) * 1e-9]))
    lat, lon, h = nav.ned_to_geodetic(p0[0], ORIGIN)
    c = dataclasses.replace(cfg, origin_latitude_deg=float(lat), origin_longitude_deg=float(lon),
                            origin_height_m=float(h))
    t = np.arange(1.0, 29.0, 0.5)
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), [], heads, dvl, c, LEVER)
    p, *_ = truth(t)
    rel = np.array([[s.north_m, s.east_m] for s in poses]) - (p[:, :2] - p0[0, :2])
    assert np.all(np.isfinite(rel)) and np.max(np.hypot(*rel.T)) < 0.05
    assert all(s.quality & NAV_DEAD_RECKONED and not s.quality & NAV_GPS_FIX
               for s in poses)



def _live_poses(cfg, t: np.ndarray) -> list:
    """Pings at times ``t`` (s) posed as the acquisition poses them: records arrive as
    time goes on, every ping is posed once the records reach ``fixed_lag_s`` past it,
    each from a new fusion of the last minute."""
    fixes, heads, dvl = make_sensors(duration_s=50.0, dvl_hz=5.0, gps_sigma=0.3,
                                     dvl_sigma=cfg.dvl_velocity_sigma_m_s, seed=4)
    navr = nav.Navigator(cfg, LEVER, history_s=60.0)
    navr.origin = ORIGIN
    streams = [(fixes, navr.add_fix), (dvl, navr.add_dvl),
               (heads, lambda h: navr.headings.append(h))]   # (prune replaces the list)
    at = [0, 0, 0]
    poses = []
    for tk in t:
        limit = T0 + int((tk + cfg.fixed_lag_s) * 1e9)
        for i, (records, add) in enumerate(streams):
            while at[i] < len(records) and records[at[i]].time_ns <= limit:
                add(records[at[i]])
                at[i] += 1
        poses.append(navr.poses([T0 + int(round(tk * 1e9))])[0])
    return poses


def test_live_navigator_keeps_the_aperture_geometry(cfg):
    """The acquisition's way: records arrive as time goes on, every ping is posed once
    the records reach ``fixed_lag_s`` past it, each from a new fusion of the last
    minute. Live poses stay within lambda/8 rms in every aperture (a fixed-lag solution
    alone moved by 7-18 mm between pings posed in different batches) and within the
    GPS's accuracy absolutely (following the solution over ``live_follow_s``; at 3 s
    instead of 60 s the chain drifts toward each new solution by 11 mm in an aperture)."""
    t = np.arange(5.0, 45.0, 0.1) + 0.013
    poses = _live_poses(cfg, t)
    horiz, vert = _aperture_errors(poses, t)
    p, *_ = truth(t)
    absolute = np.hypot(*(np.array([[s.north_m, s.east_m] for s in poses]) - p[:, :2]).T)
    print(f"live: aperture spread max {horiz.max() * 1e3:.1f} mm, altitude "
          f"{vert.max() * 1e3:.1f} mm; absolute max {absolute.max():.3f} m")
    assert horiz.max() < 0.007 and vert.max() < 0.007
    assert absolute.max() < 0.3


@pytest.mark.slow
def test_live_poses_keep_the_geometry_across_gaps_in_the_pings(cfg):
    """Pings dropped for 2.4 s and 6 s (a loaded simulator dropped them; the DVL and the
    GPS went on): apertures across the gaps keep the geometry the same pings have when
    no ping was dropped (the chain restarted after 2 s without pings and jumped: twice
    the spread here, 120 mm in a recorded run)."""
    every = np.arange(5.0, 40.0, 0.1) + 0.013
    kept = ((every < 15.0) | (every >= 17.4)) & ((every < 25.0) | (every >= 31.0))
    t = every[kept]
    gaps, _ = _aperture_errors(_live_poses(cfg, t), t)
    # the same pings' poses from a run that posed every ping: what the data allow over
    # apertures that now last 2.5 s plus the gap
    full, _ = _aperture_errors([p for p, k in zip(_live_poses(cfg, every), kept) if k], t)
    print(f"live across gaps: aperture spread max {gaps.max() * 1e3:.1f} mm; the same "
          f"pings posed without the gaps {full.max() * 1e3:.1f} mm")
    assert gaps.max() <= full.max() + 0.001


def test_pose_past_the_last_records_is_flagged_held(cfg):
    """A DVL slower than the acquisition's wait: a ping after the last DVL sample and
    the last fix is extrapolated with the last velocity and flagged NAV_HELD (it used
    to take the last sample's pose, flagged neither GPS nor dead-reckoned)."""
    fixes, heads, dvl = make_sensors(duration_s=20.0, dvl_hz=5.0, dvl_sigma=0.003, seed=1)
    t_end = (max(d.time_ns for d in dvl) - T0) * 1e-9
    t = np.array([t_end - 1.0, t_end + cfg.gps_fix_max_age_s + 0.5])
    before, after = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads,
                                      dvl, cfg, LEVER, ORIGIN)
    assert not before.quality & NAV_HELD and before.quality & NAV_GPS_FIX
    assert after.quality & NAV_HELD and not after.quality & (NAV_GPS_FIX | NAV_DEAD_RECKONED)
    p, *_ = truth(t)
    moved = math.hypot(after.north_m - before.north_m, after.east_m - before.east_m)
    assert moved == pytest.approx(math.hypot(*(p[1, :2] - p[0, :2])), abs=0.05)


def test_origin_height_from_a_fix_that_has_one(cfg):
    """A run whose first fixes are RMC (no height) and whose GGA say 170 m: the survey
    origin takes the first height, so the body's depth does not jump by 170 m."""
    fixes, heads, dvl = make_sensors(duration_s=20.0, dvl_hz=5.0, dvl_sigma=0.003, seed=1)
    fixes = [dataclasses.replace(f, height_m=math.nan) if k < 10 else f
             for k, f in enumerate(fixes)]
    t = np.arange(0.5, 19.5, 0.4)
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                              cfg, LEVER)
    down = np.array([s.down_m for s in poses])
    p, *_ = truth(t)
    offset = down - p[:, 2]            # the origin is the first GGA antenna, not ORIGIN
    assert np.max(np.abs(np.diff(down))) < 0.05 and np.ptp(offset) < 0.1


def test_altitude_noise_is_smoothed_by_the_dvl_vertical_velocity(cfg):
    """Beam ranges with the configured noise (2 cm per beam): each ensemble's own height
    varies by about 1 cm from ping to ping (what the imager placed pings with); the fused
    altitude varies within an aperture by a few millimetres."""
    fixes, heads, dvl = make_sensors(duration_s=60.0, dvl_hz=5.0,
                                     dvl_sigma=cfg.dvl_velocity_sigma_m_s, seed=8)
    rng = np.random.default_rng(9)
    dvl = [dataclasses.replace(d, ranges_m=tuple(np.asarray(d.ranges_m)
                                                 + rng.normal(0, cfg.dvl_range_sigma_m, 4)))
           for d in dvl]
    t = np.arange(5.0, 55.0, 0.1) + 0.013
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl,
                              cfg, LEVER, ORIGIN)
    _, vert = _aperture_errors(poses, t)
    raw = np.array([head_height_m(d, beam_angle_rad=math.radians(cfg.dvl_beam_angle_deg))
                    for d in dvl])
    raw_err = raw - (4.0 - point_of((np.array([d.time_ns for d in dvl]) - T0) * 1e-9,
                                    LEVER.dvl_m)[:, 2])
    print(f"altitude within apertures: fused {vert.max() * 1e3:.1f} mm rms (max), "
          f"one ensemble's own {np.std(raw_err) * 1e3:.1f} mm rms")
    assert np.std(raw_err) > 0.007 and vert.max() < 0.004


WARM_SCRIPT = """
import sys
import numpy as np
from numba.core import event
from svss_daq.nav.kalman import filter_smooth, warm_up
if sys.argv[1] == "warm":
    warm_up()
compiled = []
class Seen(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__name__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Seen())
k = 50                                    # a realistic call: 50 grid points, 3 fixes
filter_smooth(np.zeros(2), np.eye(2) * 4.0, np.full(k - 1, 0.1), np.full(k - 1, 0.1),
              np.ones(k - 1), np.full(k - 1, 1e-4), np.full(k - 1, 1e-4),
              ([0, 20, 49], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.1, 2.0, 5.0],
               [0.09, 0.09, 0.09]), smooth=False)
print("COMPILED", compiled)
"""


@pytest.mark.parametrize("warm", ["warm", pytest.param("cold", marks=pytest.mark.extended)])
@pytest.mark.slow
def test_warm_up_compiles_what_the_daemon_calls_before_the_sonar_starts(warm, tmp_path):
    """The daemon calls warm_up() before it starts the sonar (daemon.start): with an empty
    numba cache, the filter's first real call must then compile nothing (a compile there
    once held the first pings' navigation back 12 s); without the warm-up it does."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cold-cache"),
           "PYTHONPATH": os.pathsep.join([str(root)] + [p for p in [
               os.environ.get("PYTHONPATH")] if p])}
    res = subprocess.run([sys.executable, "-c", WARM_SCRIPT, warm], cwd=root, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("COMPILED")][0]
    assert ("_run" in line) == (warm == "cold"), line
