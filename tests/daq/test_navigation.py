"""Navigation against synthetic tracks with known truth.

The geodetic conversion is checked against an ECEF computation written here from the
WGS-84 definition (plain Python math, not the module's code); the track tests generate
GPS antenna fixes, HDT headings and DVL samples from a known body-origin trajectory,
with the body rotation written out in closed form (tests/references.py), not the
module's, so that a wrong rotation does not cancel between the truth and the solution."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq import navigation as nav
from svss_daq.config import DevicesConfig, LeverArms, config_path, load
from svss_daq.ping import NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX
from tests.references import body_to_ned_written_out

ORIGIN = (44.0012, -87.9876, 150.0)   # a lake survey (lat, lon deg, ellipsoidal height m)
T0 = 1_700_000_000_000_000_000
BOTTOM_DOWN = 4.0                     # flat bottom, survey frame, m
A, F = 6378137.0, 1 / 298.257223563


@pytest.fixture(scope="module")
def cfg():
    return load(DevicesConfig, config_path("devices.toml")).navigation


LEVER = LeverArms(array_m=(3.0, 0.0, 0.5), gps_antenna_m=(1.0, 0.3, -2.5), dvl_m=(2.2, -0.2, 0.5))


def ecef_ref(lat_deg, lon_deg, h):
    e2 = F * (2 - F)
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    n = A / math.sqrt(1 - e2 * math.sin(la) ** 2)
    return ((n + h) * math.cos(la) * math.cos(lo), (n + h) * math.cos(la) * math.sin(lo),
            (n * (1 - e2) + h) * math.sin(la))


def ned_ref(lat, lon, h, origin=ORIGIN):
    x, y, z = (a - b for a, b in zip(ecef_ref(lat, lon, h), ecef_ref(*origin)))
    la, lo = math.radians(origin[0]), math.radians(origin[1])
    n = -math.sin(la) * math.cos(lo) * x - math.sin(la) * math.sin(lo) * y + math.cos(la) * z
    e = -math.sin(lo) * x + math.cos(lo) * y
    d = -math.cos(la) * math.cos(lo) * x - math.cos(la) * math.sin(lo) * y - math.sin(la) * z
    return n, e, d


def geodetic_ref(n, e, d, origin=ORIGIN):
    """Inverse of ned_ref by Newton iteration on (lat, lon, h) (independent of the module)."""
    g = np.array([origin[0] + n / 111_000.0, origin[1] + e / 80_000.0, origin[2] - d])
    for _ in range(20):
        f0 = np.array(ned_ref(*g, origin)) - (n, e, d)
        jac = np.empty((3, 3))
        for i, step in enumerate((1e-7, 1e-7, 1e-3)):
            gg = g.copy()
            gg[i] += step
            jac[:, i] = (np.array(ned_ref(*gg, origin)) - (n, e, d) - f0) / step
        g = g - np.linalg.solve(jac, f0)
    return g


def test_geodetic_to_ned_matches_independent_wgs84():
    rng = np.random.default_rng(1)
    for _ in range(20):
        lat = ORIGIN[0] + rng.uniform(-0.05, 0.05)   # about +-5.5 km
        lon = ORIGIN[1] + rng.uniform(-0.05, 0.05)
        h = ORIGIN[2] + rng.uniform(-20, 20)
        got = nav.geodetic_to_ned(lat, lon, h, ORIGIN)
        assert np.allclose(got, ned_ref(lat, lon, h), atol=1e-6)  # exact: 1 um
        back = nav.ned_to_geodetic(got, ORIGIN)
        assert abs(back[0] - lat) < 1e-11 and abs(back[1] - lon) < 1e-11 and abs(back[2] - h) < 1e-6
    # 1 km east: the tangent plane lies below the ellipsoid by about r^2 / (2 R) = 7.8 cm
    lat, lon, h = geodetic_ref(0.0, 1000.0, 0.0)
    assert abs(h - ORIGIN[2] - 1000.0 ** 2 / (2 * 6.38e6)) < 5e-3


def test_altitude_from_janus_ranges():
    for angle in (20.0, 30.0):
        b = math.radians(angle)
        roll, pitch = math.radians(3), math.radians(-2)
        rot = body_to_ned_written_out(roll, pitch, 0.0)
        head_down = (rot @ np.array(LEVER.dvl_m))[2]
        u = nav.janus_beam_vectors(b) @ rot.T
        ranges = (2.0 - head_down) / u[:, 2]   # bottom 2 m below the body origin
        assert nav.altitude_from_ranges(ranges, roll, pitch, b, LEVER.dvl_m) == pytest.approx(2.0, abs=1e-9)
        ranges[1] = np.nan
        assert nav.altitude_from_ranges(ranges, roll, pitch, b, LEVER.dvl_m) == pytest.approx(2.0, abs=1e-9)
        ranges[2] = np.nan
        assert math.isnan(nav.altitude_from_ranges(ranges, roll, pitch, b, LEVER.dvl_m, 3))


# ------------------------------------------------------------------- synthetic track


def truth(t):
    """Body origin (N, E, D), roll, pitch, heading at times t (s): 40 s straight at 1 m/s,
    heading 30 deg, then a 0.05 rad/s turn (radius 20 m), small roll/pitch swell."""
    t = np.asarray(t, dtype=np.float64)
    h0, v, w, ts = math.radians(30), 1.0, 0.05, 40.0
    s = np.minimum(t, ts)
    n = s * v * math.cos(h0)
    e = s * v * math.sin(h0)
    tt = np.maximum(t - ts, 0.0)
    hd = h0 + w * tt
    n = n + (v / w) * (np.sin(hd) - math.sin(h0))
    e = e - (v / w) * (np.cos(hd) - math.cos(h0))
    d = 0.05 * np.sin(2 * np.pi * t / 7.0)
    roll = math.radians(2) * np.sin(2 * np.pi * t / 5.0)
    pitch = math.radians(1.5) * np.sin(2 * np.pi * t / 6.3)
    return np.stack([n, e, d], -1), roll, pitch, hd


def point_of(t, lever):
    p, r, q, h = truth(t)
    rot = np.array([body_to_ned_written_out(a, b, c) for a, b, c in zip(r, q, h)])
    return p + rot @ np.asarray(lever)


def make_sensors(duration_s=120.0, gps_hz=5.0, dvl_hz=8.0, gps_sigma=0.3, outage=None,
                 seed=0, dvl_sigma=0.01):
    rng = np.random.default_rng(seed)
    tg = np.arange(0.0, duration_s, 1 / gps_hz)
    if outage is not None:
        tg = tg[(tg < outage[0]) | (tg > outage[1])]
    ant = point_of(tg, LEVER.gps_antenna_m)
    ant[:, :2] += rng.normal(0, gps_sigma, (tg.size, 2))
    ant[:, 2] += rng.normal(0, 2 * gps_sigma, tg.size)
    fixes = []
    for t, (n, e, d) in zip(tg, ant):
        lat, lon, h = geodetic_ref(n, e, d)
        fixes.append(nav.GpsFix(T0 + int(round(t * 1e9)), lat, lon, h, 1))
    th = np.arange(0.0, duration_s, 1 / gps_hz)  # HDT keeps coming through a position outage
    _, _, _, hd = truth(th)
    heads = [nav.HeadingSample(T0 + int(round(t * 1e9)), float(nav.wrap_angle(h + rng.normal(0, 0.003))))
             for t, h in zip(th, hd)]
    td = np.arange(0.0, duration_s, 1 / dvl_hz)
    eps = 1e-4
    vq = (point_of(td + eps, LEVER.dvl_m) - point_of(td - eps, LEVER.dvl_m)) / (2 * eps)
    _, r, q, h = truth(td)
    head = point_of(td, LEVER.dvl_m)
    beams = nav.janus_beam_vectors(math.radians(30))
    dvl = []
    for k, t in enumerate(td):
        rot = body_to_ned_written_out(r[k], q[k], h[k])
        vb = rot.T @ vq[k] + rng.normal(0, dvl_sigma, 3)
        rng_m = (BOTTOM_DOWN - head[k, 2]) / (beams @ rot.T)[:, 2]
        dvl.append(nav.DvlSample(T0 + int(round(t * 1e9)), tuple(vb), tuple(rng_m), r[k], q[k]))
    return fixes, heads, dvl


def errors(poses, t):
    p, r, q, h = truth(t)
    got = np.array([[s.north_m, s.east_m, s.down_m] for s in poses])
    horiz = np.hypot(*(got[:, :2] - p[:, :2]).T)
    alt = np.array([s.altitude_m for s in poses]) - (BOTTOM_DOWN - p[:, 2])
    hdg = nav.wrap_angle(np.array([s.heading_rad for s in poses]) - h)
    return horiz, alt, hdg


def test_track_recovered_with_gps_and_dvl(cfg):
    fixes, heads, dvl = make_sensors()
    t = np.arange(5.0, 115.0, 0.1) + 0.013   # ping times, off the sensor grids
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl, cfg,
                              LEVER, ORIGIN)
    horiz, alt, hdg = errors(poses, t)
    rms = float(np.sqrt(np.mean(horiz ** 2)))
    print(f"GPS 5 Hz sigma 0.3 m + DVL 8 Hz: horizontal RMS {rms:.3f} m, max {horiz.max():.3f} m, "
          f"altitude max {np.abs(alt).max() * 1e3:.2f} mm, heading max {np.degrees(np.abs(hdg).max()):.2f} deg")
    assert rms < 0.12 and horiz.max() < 0.3          # GPS noise alone: 0.42 m RMS
    assert np.abs(alt).max() < 0.01
    assert np.degrees(np.abs(hdg).max()) < 1.0
    assert all(s.quality & NAV_GPS_FIX and s.quality & NAV_BOTTOM_LOCK for s in poses)
    v = np.array([[s.vel_north_m_s, s.vel_east_m_s] for s in poses])
    assert np.all(np.abs(np.hypot(*v.T) - 1.0) < 0.05)
    s = poses[100]
    lat, lon, _ = geodetic_ref(s.north_m, s.east_m, s.down_m)
    assert abs(s.latitude_deg - lat) < 1e-9 and abs(s.longitude_deg - lon) < 1e-9


def test_lever_arm_correction(cfg):
    """Noise-free GPS only (no DVL): the body origin is recovered where the antenna is
    1-2.7 m away from it; without the correction the error would be metres."""
    fixes, heads, dvl = make_sensors(gps_hz=5.0, gps_sigma=0.0, duration_s=60.0)
    nan3 = (math.nan,) * 3  # DVL without bottom lock: attitude only, no dead reckoning
    dvl = [nav.DvlSample(d.time_ns, nan3, d.ranges_m, d.roll_rad, d.pitch_rad) for d in dvl]
    tg = np.array([(f.time_ns - T0) * 1e-9 for f in fixes])[10:-10:7]
    poses = nav.compute_poses(T0 + np.round(tg * 1e9).astype(np.int64), fixes, heads, dvl, cfg,
                              LEVER, ORIGIN)
    p, *_ = truth(tg)
    got = np.array([[s.north_m, s.east_m, s.down_m] for s in poses])
    err = np.linalg.norm(got - p, axis=1)
    lever_effect = np.linalg.norm(point_of(tg, LEVER.gps_antenna_m) - p, axis=1)
    print(f"lever arm: error {err.max() * 1e3:.2f} mm vs {lever_effect.min():.2f} m uncorrected")
    assert err.max() < 0.02 and lever_effect.min() > 2.5  # heading noise 0.003 rad x 1 m


def test_dead_reckoning_through_gps_outage(cfg):
    fixes, heads, dvl = make_sensors(outage=(50.0, 80.0), seed=3)
    t = np.arange(45.0, 85.0, 0.1)
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads, dvl, cfg,
                              LEVER, ORIGIN)
    horiz, alt, _ = errors(poses, t)
    inside = (t > 51.6) & (t < 78.4)
    print(f"30 s GPS outage in a turn: max horizontal error {horiz[inside].max():.3f} m")
    assert horiz.max() < 0.3
    q = np.array([s.quality for s in poses])
    assert np.all(q[inside] & NAV_DEAD_RECKONED) and not np.any(q[inside] & NAV_GPS_FIX)
    assert np.all(q[~inside & ((t < 49) | (t > 81))] & NAV_GPS_FIX)
    # GPS lost for good at 80 s: dead reckoning on from the last fixes
    fixes2 = [f for f in fixes if (f.time_ns - T0) * 1e-9 < 80]
    poses2 = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes2, heads, dvl, cfg,
                               LEVER, ORIGIN)
    h2, *_ = errors(poses2, t)
    print(f"open-ended outage: error after 5 s of DVL only {h2[-1]:.3f} m")
    assert h2[-1] < 0.3 and poses2[-1].quality & NAV_DEAD_RECKONED


def test_course_fallback_is_flagged(cfg):
    fixes, heads, dvl = make_sensors(duration_s=30.0)
    course = [nav.HeadingSample(h.time_ns, h.heading_rad, from_course=True) for h in heads]
    t = np.array([10.0, 20.0])
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, course, dvl, cfg,
                              LEVER, ORIGIN)
    assert all(s.quality & nav.NAV_HEADING_FROM_COURSE for s in poses)
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, heads + course, dvl,
                              cfg, LEVER, ORIGIN)
    assert not any(s.quality & nav.NAV_HEADING_FROM_COURSE for s in poses)
    poses = nav.compute_poses(T0 + np.round(t * 1e9).astype(np.int64), fixes, [], dvl, cfg, LEVER)
    assert all(s.quality & nav.NAV_NO_HEADING for s in poses)
