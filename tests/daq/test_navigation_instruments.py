"""Navigation from instruments as they send it: PD0 beam coordinates (against beam
velocities projected by hand), 3-beam solutions, the vertical beam, GPS fix validity,
GST weighting, the DVL compass through a GNSS loss, bottom-lock loss, and
Navigator.quality()."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from svss_daq import navigation as nav
from svss_daq.protocols import pd0
from svss_daq.protocols import nmea
from svss_daq.protocols import nmea_encoder as enc
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_NO_HEADING)
from tests.daq.test_navigation import (LEVER, ORIGIN, T0, cfg, errors,  # noqa: F401
                                       geodetic_ref, make_sensors, truth)


def beams_by_hand(v_bottom_instr, angle_deg, convex):
    """Radial velocities, positive toward the transducer, of a bottom velocity given in
    the instrument frame (X starboard, Y forward toward beam 3, Z up; beams pointing
    down): convex beam 1 points port-down, 2 starboard-down, 3 forward-down, 4 aft-down;
    concave heads cross the beams, so each pair points the other way."""
    s, c = math.sin(math.radians(angle_deg)), math.cos(math.radians(angle_deg))
    k = 1 if convex else -1
    u = {1: (-k * s, 0, -c), 2: (k * s, 0, -c), 3: (0, k * s, -c), 4: (0, -k * s, -c)}
    return [-float(np.dot(v_bottom_instr, u[i])) for i in (1, 2, 3, 4)]


@pytest.mark.parametrize("convex", [True, False])
@pytest.mark.parametrize("angle", [20.0, 30.0])
@pytest.mark.parametrize("align_deg", [0.0, 45.0])
def test_beam_coordinates_give_the_body_velocity(convex, angle, align_deg):
    v_body = np.array([1.23, -0.31, 0.07])              # head over ground: fwd, stbd, down
    v_ship = np.array([v_body[1], v_body[0], -v_body[2]])  # X stbd, Y fwd, Z up
    ea = math.radians(align_deg)                        # beam 3 at ea clockwise from the bow
    v_instr = np.array([math.cos(ea) * v_ship[0] - math.sin(ea) * v_ship[1],
                        math.sin(ea) * v_ship[0] + math.cos(ea) * v_ship[1], v_ship[2]])
    b = beams_by_hand(-v_instr, angle, convex)          # RDI reports the bottom's velocity
    setup = Pd0Setup(coordinate_system="beam", beam_angle_deg=angle,
                     beam_pattern="convex" if convex else "concave",
                     heading_alignment_deg=align_deg)
    raw = encode_ensemble(setup, ensemble_number=1, time_ns=T0, heading_rad=1.0,
                          pitch_rad=0.0, roll_rad=0.0, bt_velocity_m_s=b,
                          bt_range_m=(2, 2, 2, 2))
    ens = pd0.decode_ensemble(raw)
    d = nav.dvl_sample_from_pd0(ens)
    assert np.allclose(d.velocity_body_m_s, v_body, atol=3e-3)   # 1 mm/s on the wire
    assert d.heading_rad == pytest.approx(nav.wrap_angle(1.0 - ea), abs=1e-4)
    # the formulas themselves, unquantised, and a zero error velocity for Janus geometry
    x, y, z, e = nav.beam_to_instrument(beams_by_hand(v_instr, angle, convex),
                                        math.radians(angle), convex)
    assert np.allclose([x, y, z, e], [*v_instr, 0.0], atol=1e-12)


def test_three_beam_solution_and_min_beams():
    v_instr = np.array([0.4, 1.1, -0.05])
    b = beams_by_hand(-v_instr, 30.0, True)
    for bad in range(4):
        bb = list(b)
        bb[bad] = float("nan")
        assert np.allclose(nav.three_beam_fill(bb), b, atol=1e-12)
        raw = encode_ensemble(Pd0Setup(coordinate_system="beam"), ensemble_number=1,
                              time_ns=T0, heading_rad=0, pitch_rad=0, roll_rad=0,
                              bt_velocity_m_s=bb, bt_range_m=(2, 2, 2, 2))
        e = pd0.decode_ensemble(raw)
        v3 = nav.dvl_sample_from_pd0(e, min_beams=3).velocity_body_m_s
        assert np.allclose(v3, [v_instr[1], v_instr[0], -v_instr[2]], atol=3e-3)
        assert np.all(np.isnan(nav.dvl_sample_from_pd0(e, min_beams=4).velocity_body_m_s))
    two_bad = list(b)
    two_bad[0] = two_bad[3] = float("nan")
    assert np.all(np.isnan(nav.three_beam_fill(two_bad)))


def test_vertical_beam_gives_altitude_without_slanted_ranges(cfg):
    setup = Pd0Setup(firmware=(47, 19), frequency_hz=307.2e3, vertical_beam=True)
    raw = encode_ensemble(setup, ensemble_number=1, time_ns=T0, heading_rad=0,
                          pitch_rad=0, roll_rad=0, bt_velocity_m_s=(0, 0, 0, 0),
                          bt_range_m=(np.nan,) * 4, vertical_range_m=1.5)
    d = nav.dvl_sample_from_pd0(pd0.decode_ensemble(raw))
    assert d.vertical_range_m == pytest.approx(1.5)
    lever = (0.0, 0.0, 0.5)
    alt = nav.altitude_from_ranges(d.ranges_m, 0.0, 0.0, math.radians(30), lever, 3,
                                   d.vertical_range_m)
    assert alt == pytest.approx(2.0)
    roll = math.radians(4.0)   # tilted: the vertical beam's range times cos(roll)
    alt = nav.altitude_from_ranges(d.ranges_m, roll, 0.0, math.radians(30), (0, 0, 0), 3,
                                   d.vertical_range_m)
    assert alt == pytest.approx(1.5 * math.cos(roll))


def _records(lines):
    p = nmea.NmeaStreamParser()
    out = []
    for ln in lines:
        out += p.feed(ln)
    return out


def test_invalid_and_estimated_fixes_are_rejected_and_counted():
    t = T0
    lat, lon = ORIGIN[0], ORIGIN[1]
    lines = [enc.zda("GP", t),
             enc.gga("GP", t, lat, lon, 1, 9, 0.9, 10.0, -30.0),            # good
             enc.gga("GP", t + 10**8, None, None, 0),                        # invalid
             enc.gga("GP", t + 2 * 10**8, lat, lon, 6, 0, None, 10.0, -30.0),  # estimated
             enc.rmc("GP", t + 3 * 10**8, False, lat, lon, 1.0, 0.3),        # status V
             enc.rmc("GP", t + 4 * 10**8, True, lat, lon, 1.0, 0.3, mode="E"),  # estimated
             enc.rmc("GP", t + 5 * 10**8, True, lat, lon, 1.0, 0.3)]         # good
    recs = _records(lines)
    assert len(recs) == len(lines)                     # checksums right: all decoded
    counts = {}
    fixes, _ = nav.samples_from_nmea(recs, counts=counts)
    assert [f.time_ns for f in fixes] == [t, t + 5 * 10**8]
    assert counts["gps_rejected"] == 4
    navr = nav.Navigator(nav_cfg(), LEVER)
    navr.add_nmea(recs)
    assert navr.counts["gps_fixes"] == 2 and navr.counts["gps_rejected"] == 4


def nav_cfg(**kw):
    from svss_daq.config import DevicesConfig, config_path, load
    return dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation, **kw)


def test_gst_sigma_attached_and_large_sigma_rejected():
    t = T0
    lines = [enc.zda("GP", t)]
    for k, sig in enumerate((0.02, 0.5, 5.0)):
        tk = t + k * 200_000_000
        lines += [enc.gga("GP", tk, ORIGIN[0], ORIGIN[1], 4, 12, 0.7, 10.0, -30.0),
                  enc.gst("GP", tk, 0.3, sig * 1.2, sig * 0.8, 0.4, sig, sig, 2 * sig)]
    recs = _records(lines)
    g = [r for r in recs if isinstance(r, nmea.GstStatistics)]
    assert len(g) == 3 and g[1].sigma_latitude_m == 0.5 and g[1].sigma_altitude_m == 1.0
    assert g[1].orientation_rad == pytest.approx(0.4, abs=1e-4)
    counts = {}
    fixes, _ = nav.samples_from_nmea(recs, max_sigma_m=2.0, counts=counts)
    assert [f.sigma_m for f in fixes] == pytest.approx([0.02 * math.sqrt(2), 0.5 * math.sqrt(2)])
    assert counts["gps_rejected"] == 1
    with pytest.raises(nmea.NmeaError, match="GST std_dev_latitude"):
        nmea.parse_sentence(enc.sentence("GPGST,120000.00,0.3,1.0,0.5,10.0,-1.0,0.5,1.0"))


def test_large_sigma_fix_pulls_the_solution_less(cfg):
    fixes, heads, dvl = make_sensors(duration_s=90.0, gps_sigma=0.0, dvl_sigma=0.0)
    k = min(range(len(fixes)), key=lambda i: abs(fixes[i].time_ns - (T0 + 60 * 10**9)))
    t_k = fixes[k].time_ns

    def pull(sigma_out):
        return north_error(sigma_out, 3.0) - north_error(sigma_out, 0.0)

    def north_error(sigma_out, outlier_m):
        f = list(fixes)
        n, e, d = (float(x) for x in nav.geodetic_to_ned(f[k].latitude_deg, f[k].longitude_deg,
                                                         f[k].height_m, ORIGIN))
        lat, lon, h = geodetic_ref(n + outlier_m, e, d)  # an outlier to the north
        f = [dataclasses.replace(x, sigma_m=0.3) for x in f]
        f[k] = dataclasses.replace(f[k], latitude_deg=lat, longitude_deg=lon, height_m=h,
                                   sigma_m=sigma_out)
        pose = nav.compute_poses([t_k], f, heads, dvl, cfg, LEVER, ORIGIN)[0]
        p, _, _, _ = truth(np.array([(t_k - T0) * 1e-9]))
        return pose.north_m - p[0, 0]

    small, large = pull(0.3), pull(3.0)
    # the smoother weighs a fix by P / sigma^2 (P its own variance, a few cm^2 here):
    # the outlier moves the track a little, and a hundredth as much at ten times the sigma
    assert 0.001 < small < 0.1
    assert large == pytest.approx(small * (0.3 / 3.0) ** 2, rel=0.3)
    # without GST (no sigma at all): the present behaviour, an equal-weight mean
    f = [dataclasses.replace(x, sigma_m=float("nan")) for x in fixes]
    base = nav.compute_poses([t_k], f, heads, dvl, cfg, LEVER, ORIGIN)[0]
    p, _, _, _ = truth(np.array([(t_k - T0) * 1e-9]))
    assert abs(base.north_m - p[0, 0]) < 0.02


def test_gnss_loss_falls_back_to_the_dvl_compass(cfg):
    out = (40.0, 70.0)                                   # 30 s: GPS and HDT both lost
    fixes, heads, dvl = make_sensors(duration_s=90.0, outage=out, seed=3)
    heads = [h for h in heads if not out[0] * 1e9 <= h.time_ns - T0 <= out[1] * 1e9]
    _, _, _, hd = truth(np.array([(d.time_ns - T0) * 1e-9 for d in dvl]))
    rng = np.random.default_rng(5)
    dvl_c = [dataclasses.replace(d, heading_rad=float(nav.wrap_angle(h + rng.normal(0, 0.005))))
             for d, h in zip(dvl, hd)]
    t = np.arange(out[0] + 5.0, out[1] - 1.0, 1.0)
    times = T0 + (t * 1e9).astype(np.int64)
    poses = nav.compute_poses(times, fixes, heads, dvl_c, cfg, LEVER, ORIGIN)
    assert all(p.quality & NAV_DEAD_RECKONED and p.quality & NAV_HEADING_FROM_COMPASS
               and not p.quality & (NAV_NO_HEADING | NAV_GPS_FIX) for p in poses)
    horiz, _, hdg = errors(poses, t)
    assert np.max(np.abs(hdg)) < math.radians(1.0)
    assert np.max(horiz) < 0.6
    # without a compass the same poses have no heading (the earlier behaviour)
    bare = nav.compute_poses(times, fixes, heads, dvl, cfg, LEVER, ORIGIN)
    assert all(p.quality & NAV_NO_HEADING for p in bare)


def test_bottom_lock_loss_with_gps_keeps_gps_and_drops_altitude(cfg):
    fixes, heads, dvl = make_sensors(duration_s=90.0, seed=4)
    lost = (40.0, 55.0)
    dvl = [dataclasses.replace(d, velocity_body_m_s=(np.nan,) * 3, ranges_m=(np.nan,) * 4)
           if lost[0] * 1e9 <= d.time_ns - T0 <= lost[1] * 1e9 else d for d in dvl]
    t = np.arange(lost[0] + 2.0, lost[1] - 2.0, 0.5)
    poses = nav.compute_poses(T0 + (t * 1e9).astype(np.int64), fixes, heads, dvl, cfg, LEVER,
                              ORIGIN)
    assert all(p.quality & NAV_GPS_FIX and not p.quality & (NAV_BOTTOM_LOCK | NAV_DEAD_RECKONED)
               and math.isnan(p.altitude_m) for p in poses)
    horiz, _, _ = errors(poses, t)
    assert np.max(horiz) < 1.0


def test_quality_summary(cfg):
    n = nav.Navigator(nav_cfg(), LEVER)
    t = T0
    q = n.quality(t)
    assert q["mode"] == "none" and q["heading_source"] == "none" and q["gps_fix_age_s"] is None
    lines = [enc.zda("GP", t), enc.gga("GP", t, ORIGIN[0], ORIGIN[1], 4, 12, 0.7, 10.0, -30.0),
             enc.gst("GP", t, 0.3, 0.05, 0.03, 0.1, 0.03, 0.04, 0.08),
             enc.gga("GP", t + 2 * 10**8, None, None, 0)]
    n.add_nmea(_records(lines))
    n.add_nmea([(t, nmea.parse_sentence(enc.hdt("GP", 0.5)))])
    setup = Pd0Setup()
    for k in range(3):
        raw = encode_ensemble(setup, ensemble_number=k, time_ns=t + k * 125_000_000,
                              heading_rad=0.6, pitch_rad=0, roll_rad=0,
                              bt_velocity_m_s=(0, -1, 0, 0) if k < 2 else (np.nan,) * 4,
                              bt_range_m=(2, 2, 2, 2))
        n.add_pd0(pd0.decode_ensemble(raw))
    q = n.quality(t + 5 * 10**8)
    assert q == {"mode": "gps", "gps_fix_age_s": pytest.approx(0.5),
                 "dvl_age_s": pytest.approx(0.25), "heading_source": "hdt",
                 "bottom_lock": False, "gps_sigma_m": pytest.approx(0.05),
                 "gps_gate": "no_fix", "clock_offset_s": {}, "clock_retimed": [],
                 "gps_fixes": 1, "gps_rejected": 1, "gps_rejected_sigma": 0,
                 "gps_gst_missing": 0, "dvl_ensembles": 3, "dvl_samples": 3, "dvl_no_lock": 1}
    json.dumps(q, allow_nan=False)
    # GNSS and HDT gone, the DVL still locked: dead reckoning on the compass
    for k in range(40):
        n.add_pd0(pd0.decode_ensemble(encode_ensemble(
            setup, ensemble_number=10 + k, time_ns=t + (3 + k) * 125_000_000, heading_rad=0.6,
            pitch_rad=0, roll_rad=0, bt_velocity_m_s=(0, -1, 0, 0), bt_range_m=(2, 2, 2, 2))))
    q = n.quality(t + 42 * 125_000_000)
    assert q["mode"] == "dead_reckoning" and q["heading_source"] == "dvl_compass"
    assert q["bottom_lock"] is True and q["gps_fix_age_s"] == pytest.approx(5.25)
    json.dumps(q, allow_nan=False)
    q = n.quality(t + 60 * 10**9)
    assert q["mode"] == "none" and q["heading_source"] == "none"
