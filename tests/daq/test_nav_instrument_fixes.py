"""Navigation as real RDI instruments and GNSS receivers send their data (issue 26,
"correct on real instruments"): RDI's bottom-track ranges are vertical ranges and the
beam angle is the fixed leader's; true-heading sensors (HDT, then the DVL compass with
its alignment and declination) come before the course over ground; ensembles without
bottom track keep their attitude and heading; RDI's missing pressure is missing.

Real bytes (``../shared/data/dvl_pd0``) where they hold the case, else ensembles made by
:mod:`svss_daq.protocols.pd0_encoder` to RDI's formulas, with the beam geometry written
out here (not the module's)."""

from __future__ import annotations

import dataclasses
import logging
import math
import struct

import numpy as np
import pytest

from svss_daq import navigation as nav
from svss_daq.config import DevicesConfig, LeverArms, config_path, load
from svss_daq.protocols import nmea, pd0
from svss_daq.protocols import nmea_encoder as enc
from svss_daq.protocols.pd0 import Pd0StreamParser, ensemble_checksum
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.nav import pd0_samples
from svss_daq.nav.dvl_geometry import _sample_altitude, head_height_m
from svss_daq.nav.headings import _headings
from svss_daq.ping import NAV_BOTTOM_LOCK, NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE
from tests.conftest import SHARED_DATA
from tests.references import body_to_ned_written_out

DATA = SHARED_DATA / "dvl_pd0"
T0 = 1_700_000_000_000_000_000
ORIGIN = (44.0012, -87.9876, 150.0)
DEG = math.pi / 180
LEVER = LeverArms(array_m=(3.0, 0.0, 0.5), gps_antenna_m=(1.0, 0.3, -2.5),
                  dvl_m=(2.2, -0.2, 0.5))


def nav_cfg(**kw):
    return dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                               **kw)


@pytest.fixture(autouse=True)
def fresh_warnings():
    """Each test sees the once-per-disagreement warnings afresh."""
    pd0_samples._warned.clear()
    yield
    pd0_samples._warned.clear()


def real(name: str) -> list:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"real recordings not found: {DATA}")
    return parse_all(path.read_bytes())


def parse_all(raw: bytes) -> list:
    p = Pd0StreamParser()
    return p.feed(raw) + p.flush()


def beams_written_out(angle_deg, alignment_deg=0.0, convex=True):
    """Down-looking Janus beams 1-4 as unit vectors in the body frame (x fwd, y stbd, z
    down): RDI's convex layout with beam 3 on the bow is 1 port, 2 starboard, 3 forward,
    4 aft, each ``angle_deg`` from the head's axis; the heading alignment EA turns beam 3
    ``alignment_deg`` clockwise (toward starboard); a concave head crosses each pair."""
    s, c = math.sin(angle_deg * DEG), math.cos(angle_deg * DEG)
    az3 = alignment_deg * DEG + (0.0 if convex else math.pi)
    azimuths = (az3 - math.pi / 2, az3 + math.pi / 2, az3, az3 + math.pi)
    return np.array([[s * math.cos(a), s * math.sin(a), c] for a in azimuths])


def rdi_ranges(height_m, roll, pitch, angle_deg, alignment_deg=0.0, convex=True):
    """What RDI sends for a head ``height_m`` above a flat bottom: per beam the range along
    the beam (height / its down component after roll and pitch) times cos(beam angle)."""
    down = (beams_written_out(angle_deg, alignment_deg, convex)
            @ body_to_ned_written_out(roll, pitch, 0.0).T)[:, 2]
    return height_m / down * math.cos(angle_deg * DEG)


# ------------------------------------------------------------ 1. vertical bottom-track ranges


def test_five_beam_dvl_altitude_is_its_vertical_beam_range(caplog):
    """A five-beam DVL (Sentinel V layout) with a 20 deg fixed leader, the navigation
    configured for 30 deg: RDI's bottom-track ranges average to the vertical beam's range
    (the ratio the issue measured on a real five-beam recording: 0.974), and the head
    height from the four slanted beams equals the height from the vertical beam's range
    (the issue's figure for the old code: 0.844 of it)."""
    cfg = nav_cfg(dvl_beam_angle_deg=30.0)
    setup = Pd0Setup(firmware=(47, 19), frequency_hz=307.2e3, vertical_beam=True,
                     beam_angle_deg=20.0, serial_number=24680)
    height = 7.3
    ratios, ok = [], 0
    caplog.set_level(logging.WARNING, logger="svss_daq.nav.pd0_samples")
    for k, (roll_deg, pitch_deg) in enumerate([(0, 0), (3, -2), (-4, 5), (6, 1.5)]):
        roll, pitch = roll_deg * DEG, pitch_deg * DEG
        vert_beam = height / (math.cos(roll) * math.cos(pitch))  # along the head's axis
        raw = encode_ensemble(setup, ensemble_number=k + 1, time_ns=T0 + k * 10**8,
                              heading_rad=0.3, pitch_rad=pitch, roll_rad=roll,
                              bt_velocity_m_s=(0, 0, 0, 0),
                              bt_range_m=rdi_ranges(height, roll, pitch, 20.0),
                              vertical_range_m=vert_beam)
        e = pd0.decode_ensemble(raw)
        assert e.fixed.beam_angle_rad == pytest.approx(20 * DEG)
        ratios.append(np.mean(e.bottom_track.range_m) / e.vertical_beam.range_m)
        d = nav.dvl_sample_from_pd0(e, cfg.dvl_min_beams, cfg.dvl_beam_angle_deg * DEG)
        assert d.beam_angle_rad == pytest.approx(20 * DEG)
        h = head_height_m(d, cfg.dvl_min_beams)
        # 1 cm on the wire per range: within a centimetre of the truth
        assert h == pytest.approx(height, abs=0.01)
        assert h / (e.vertical_beam.range_m * math.cos(roll) * math.cos(pitch)) == \
            pytest.approx(1.0, abs=0.002)
        # the fusion's call (the configured 30 deg passed, the sample's own angle used)
        alt = _sample_altitude(d, cfg.dvl_beam_angle_deg * DEG, tuple(LEVER.dvl_m), 3)
        lever_down = (body_to_ned_written_out(roll, pitch, 0.0) @ np.array(LEVER.dvl_m))[2]
        assert alt == pytest.approx(height + lever_down, abs=0.01)
        # without slanted ranges: the vertical beam alone, times cos(roll) cos(pitch)
        bare = dataclasses.replace(d, ranges_m=(math.nan,) * 4)
        assert head_height_m(bare) == pytest.approx(height, abs=1e-3)
        ok += 1
    assert ok == 4
    assert np.all(np.abs(np.array(ratios) - 1.0) < 0.02)   # "cos(tilt)-free": about 1
    # the beam angles disagree: one warning naming both, not one per ensemble
    msgs = [r.getMessage() for r in caplog.records if "beam angle" in r.getMessage()]
    assert len(msgs) == 1 and "20.00" in msgs[0] and "30.00" in msgs[0]


@pytest.mark.parametrize("convex", [True, False])
@pytest.mark.parametrize("align_deg", [0.0, 45.0])
def test_head_height_uses_the_fixed_leaders_head_geometry(convex, align_deg):
    """Tilted 4-beam heads of each pattern and heading alignment: the height comes back
    from RDI's vertical ranges (the old code, reading them as slant ranges at the
    configured 30 deg, gave 0.87 of it)."""
    roll, pitch, height = 5 * DEG, -3 * DEG, 11.0
    setup = Pd0Setup(beam_angle_deg=20.0, beam_pattern="convex" if convex else "concave",
                     heading_alignment_deg=align_deg)
    raw = encode_ensemble(setup, ensemble_number=1, time_ns=T0, heading_rad=0.0,
                          pitch_rad=pitch, roll_rad=roll, bt_velocity_m_s=(0, 0, 0, 0),
                          bt_range_m=rdi_ranges(height, roll, pitch, 20.0, align_deg, convex))
    d = nav.dvl_sample_from_pd0(pd0.decode_ensemble(raw), 3, 30 * DEG)
    assert head_height_m(d) == pytest.approx(height, abs=0.01)
    assert _sample_altitude(d, 30 * DEG, (0.0, 0.0, 0.0), 3) == pytest.approx(height, abs=0.01)
    # the slant ranges the sample holds are the ranges along the beams
    down = (beams_written_out(20.0, align_deg, convex)
            @ body_to_ned_written_out(roll, pitch, 0.0).T)[:, 2]
    np.testing.assert_allclose(d.ranges_m, height / down, atol=0.012)


def test_configured_beam_angle_only_where_the_fixed_leader_has_none(caplog):
    """A fixed leader with beam-angle code 'other' and no beam angle byte: the configured
    angle is used, without a warning; a sample made without any angle has no ranges and
    no height from them."""
    raw = bytearray(encode_ensemble(Pd0Setup(beam_angle_deg=20.0), ensemble_number=1,
                                    time_ns=T0, heading_rad=0.0, pitch_rad=0.0, roll_rad=0.0,
                                    bt_velocity_m_s=(0, 0, 0, 0),
                                    bt_range_m=rdi_ranges(4.0, 0.0, 0.0, 20.0)))
    fl = struct.unpack_from("<H", raw, 6)[0]             # offset of the fixed leader
    cfg_word = struct.unpack_from("<H", raw, fl + 4)[0]
    struct.pack_into("<H", raw, fl + 4, cfg_word | 0x0300)  # bits 8-9: other
    raw[fl + 58] = 0                                        # no beam angle byte
    n = struct.unpack_from("<H", raw, 2)[0]
    struct.pack_into("<H", raw, n, ensemble_checksum(bytes(raw), 0, n))
    e = pd0.decode_ensemble(bytes(raw))
    assert e.fixed.beam_angle_rad is None
    caplog.set_level(logging.WARNING, logger="svss_daq.nav.pd0_samples")
    d = nav.dvl_sample_from_pd0(e, 3, 20 * DEG)
    assert d.beam_angle_rad == pytest.approx(20 * DEG)
    assert head_height_m(d) == pytest.approx(4.0, abs=0.01)
    assert not [r for r in caplog.records if "beam angle" in r.getMessage()]
    d = nav.dvl_sample_from_pd0(e)
    assert np.all(np.isnan(d.ranges_m)) and math.isnan(head_height_m(d))


def _echo_peak_distance(e, beam):
    """Vertical distance (the fixed leader's cell distances are vertical) of the echo
    intensity's peak in one beam's water profile, interpolated by a parabola through the
    peak cell and its neighbours; None where there is no clear peak."""
    ei = e.echo_intensity[:, beam].astype(np.float64)
    k = int(np.argmax(ei))
    if k == 0 or k == ei.size - 1 or ei[k] - np.median(ei) < 5:
        return None
    y0, y1, y2 = ei[k - 1:k + 2]
    den = y0 - 2 * y1 + y2
    off = 0.5 * (y0 - y2) / den if den else 0.0
    return e.fixed.cell_distances_m[k] + off * e.fixed.cell_size_m


def test_real_bottom_track_ranges_are_vertical_and_give_the_height():
    """RDI_withBT.000 (Workhorse 600 kHz, 20 deg, with a water profile): the bottom's echo
    in each beam's profile lies at the cell whose *vertical* distance (RDI's bin mapping)
    equals the beam's bottom-track range (median ratio 0.986; slant ranges would give
    cos 20 deg = 0.940), so the ranges are vertical. The head's height from the
    bottom-track ranges then agrees with the height from the echo peaks alone (each peak
    taken along its beam, turned by the ensemble's roll and pitch); the old reading
    (slant ranges at the configured 30 deg) was 13 % low. dolfyn's ``dist_bt`` (first 100
    ensembles) has no bottom (0) anywhere: those samples have no ranges and no height."""
    import h5py
    ens = real("RDI_withBT.000")
    cfg = nav_cfg()
    assert cfg.dvl_beam_angle_deg == 30.0 and ens[0].fixed.beam_angle_rad == pytest.approx(20 * DEG)
    with h5py.File(DATA / "RDI_withBT.nc", "r") as f:
        dist_bt = f["dist_bt"][:]
    assert dist_bt.shape == (4, 100) and not dist_bt.any()
    for e in ens[:100]:
        d = nav.dvl_sample_from_pd0(e, cfg.dvl_min_beams, cfg.dvl_beam_angle_deg * DEG)
        assert np.all(np.isnan(d.ranges_m)) and math.isnan(head_height_m(d))
    cos20 = math.cos(20 * DEG)
    per_beam, new, old = [], [], []
    for e in ens:
        r = e.bottom_track.range_m
        peaks = [_echo_peak_distance(e, b) if np.isfinite(r[b]) else None for b in range(4)]
        per_beam += [p / r[b] for b, p in enumerate(peaks) if p is not None]
        if sum(p is not None for p in peaks) < 3:
            continue
        down = (beams_written_out(20.0) @ body_to_ned_written_out(
            e.roll_rad, e.pitch_rad, 0.0).T)[:, 2]
        echo_h = np.mean([p / cos20 * down[b] for b, p in enumerate(peaks) if p is not None])
        d = nav.dvl_sample_from_pd0(e, cfg.dvl_min_beams, cfg.dvl_beam_angle_deg * DEG)
        new.append(head_height_m(d, cfg.dvl_min_beams) / echo_h)
        old.append(_sample_altitude(d, cfg.dvl_beam_angle_deg * DEG, (0.0, 0.0, 0.0),
                                    cfg.dvl_min_beams) / echo_h)
    logging.getLogger(__name__).info(
        "RDI_withBT: echo peak / bottom-track range median %.3f over %d beams; head height "
        "/ echo height median %.3f over %d ensembles", np.median(per_beam), len(per_beam),
        np.median(new), len(new))
    assert len(per_beam) > 3000 and len(new) > 700
    assert abs(np.median(per_beam) - 1.0) < 0.03 < abs(np.median(per_beam) - cos20)
    assert np.median(new) == pytest.approx(1.0, abs=0.03)
    assert np.median(old) == pytest.approx(1.0, abs=0.03)   # the fusion's call, too


# ------------------------------------------------------------------- 2. heading priority


def _course_and_compass_navigator(cfg, hdt: bool, compass_deg=40.0, course_deg=113.0,
                                  speed=1.5, ea_deg=0.0, eb_deg=0.0, seconds=6):
    """GGA + RMC at 1 Hz (course ``course_deg`` at ``speed``), optionally HDT 10 deg, and
    a DVL at 4 Hz whose compass reads ``compass_deg``."""
    n = nav.Navigator(cfg, LEVER)
    p = nmea.NmeaStreamParser()
    for k in range(seconds):
        t = T0 + k * 10**9
        recs = []
        for line in (enc.gga("GP", t, ORIGIN[0], ORIGIN[1] + k * 1e-5, 1, 10, 0.8, 10.0, -30.0),
                     enc.rmc("GP", t, True, ORIGIN[0], ORIGIN[1] + k * 1e-5, speed,
                             course_deg * DEG)):
            recs += p.feed(line)
        if hdt:   # HDT has no time of its own: the epoch's, as the daemon batches it
            recs.append((t, nmea.parse_sentence(enc.hdt("GP", 10 * DEG))))
        n.add_nmea(recs)
    setup = Pd0Setup(heading_alignment_deg=ea_deg, heading_bias_deg=eb_deg)
    for k in range(4 * seconds):
        n.add_pd0(pd0.decode_ensemble(encode_ensemble(
            setup, ensemble_number=k + 1, time_ns=T0 + k * 250_000_000,
            heading_rad=compass_deg * DEG, pitch_rad=0.0, roll_rad=0.0,
            bt_velocity_m_s=(0, -speed, 0, 0), bt_range_m=(5, 5, 5, 5))))
    return n


def _deg(a):
    return math.degrees(a) % 360.0


def test_compass_comes_before_the_course_over_ground():
    """No HDT, a working compass and a course 73 deg off it (the issue's river crossing):
    the compass heading, flagged as the compass; HDT, when there, before both; the course
    only without either, flagged; below course_min_speed_m_s not even that."""
    cfg = nav_cfg(origin_latitude_deg=ORIGIN[0], origin_longitude_deg=ORIGIN[1],
                  origin_height_m=ORIGIN[2])
    times = T0 + np.arange(1, 5) * 10**9
    n = _course_and_compass_navigator(cfg, hdt=False)
    for q in n.poses(times):
        assert _deg(q.heading_rad) == pytest.approx(40.0, abs=0.02)
        assert q.quality & NAV_HEADING_FROM_COMPASS and not q.quality & NAV_HEADING_FROM_COURSE
    assert n.quality(int(times[-1]))["heading_source"] == "dvl_compass"

    n = _course_and_compass_navigator(cfg, hdt=True)
    for q in n.poses(times):
        assert _deg(q.heading_rad) == pytest.approx(10.0, abs=0.02)
        assert not q.quality & (NAV_HEADING_FROM_COMPASS | NAV_HEADING_FROM_COURSE)
    assert n.quality(int(times[-1]))["heading_source"] == "hdt"

    # the course is a heading once the receiver has moved along it for 5 s
    n = _course_and_compass_navigator(cfg, hdt=False, seconds=12)
    n.dvl = [dataclasses.replace(d, heading_rad=math.nan) for d in n.dvl]  # no compass
    for q in n.poses(T0 + np.arange(7, 11) * 10**9):
        assert _deg(q.heading_rad) == pytest.approx(113.0, abs=0.02)
        assert q.quality & NAV_HEADING_FROM_COURSE

    # the unit that orders them, on its own
    t = np.array([0.0, 1.0])
    hdt_s = [nav.HeadingSample(T0, 0.1), nav.HeadingSample(T0 + 10**9, 0.1)]
    course = [nav.HeadingSample(T0, 2.0, True), nav.HeadingSample(T0 + 10**9, 2.0, True)]
    comp = [nav.DvlSample(T0, (0, 0, 0), (5,) * 4, heading_rad=1.0),
            nav.DvlSample(T0 + 10**9, (0, 0, 0), (5,) * 4, heading_rad=1.0)]
    h, flag = _headings(t, course, 2.0, T0, comp)
    assert np.allclose(h, 1.0) and np.all(flag == 3)
    h, flag = _headings(t, course + hdt_s, 2.0, T0, comp)
    assert np.allclose(h, 0.1) and np.all(flag == 0)
    h, flag = _headings(t, course, 2.0, T0, ())
    assert np.allclose(h, 2.0) and np.all(flag == 1)


def test_compass_alignment_and_declination(caplog):
    """The compass heading is the instrument's less its alignment EA; the configured
    magnetic declination is added where the instrument's EB is 0, not where EB is set
    (its heading already includes it), with one warning where both are set and differ."""
    times = T0 + np.arange(1, 5) * 10**9
    base = dict(origin_latitude_deg=ORIGIN[0], origin_longitude_deg=ORIGIN[1],
                origin_height_m=ORIGIN[2])
    n = _course_and_compass_navigator(nav_cfg(magnetic_declination_deg=-7.5, **base),
                                      hdt=False, compass_deg=40.0, ea_deg=12.0)
    for q in n.poses(times):
        assert _deg(q.heading_rad) == pytest.approx(40.0 - 12.0 - 7.5, abs=0.02)
    caplog.set_level(logging.WARNING, logger="svss_daq.nav.pd0_samples")
    n = _course_and_compass_navigator(nav_cfg(magnetic_declination_deg=-7.5, **base),
                                      hdt=False, compass_deg=40.0, eb_deg=3.0)
    for q in n.poses(times):
        assert _deg(q.heading_rad) == pytest.approx(40.0, abs=0.02)
    msgs = [r.getMessage() for r in caplog.records if "heading bias" in r.getMessage()]
    assert len(msgs) == 1 and "3.00" in msgs[0] and "-7.50" in msgs[0]


def test_real_compass_with_eb_takes_no_second_declination(caplog):
    """RDI_test01.000 was recorded with EB = 17 deg (dolfyn: magnetic_var_deg 17, heading
    already including it): the samples' headings are dolfyn's whatever declination is
    configured; a configured one that differs is warned about once."""
    import h5py
    ens = real("RDI_test01.000")
    assert ens[0].fixed.heading_bias_rad == pytest.approx(17 * DEG)
    with h5py.File(DATA / "RDI_test01.nc", "r") as f:
        ref = f["heading"][:].astype(np.float64)
    caplog.set_level(logging.WARNING, logger="svss_daq.nav.pd0_samples")
    for decl in (0.0, 17.0, 10.0):
        got = [_deg(nav.dvl_sample_from_pd0(e, 3, 30 * DEG, decl * DEG).heading_rad) for e in ens]
        np.testing.assert_allclose(got, ref, atol=1e-4)
    msgs = [r.getMessage() for r in caplog.records if "heading bias" in r.getMessage()]
    assert len(msgs) == 1 and "10.00" in msgs[0]


# ------------------------------------------------------- 5. ensembles without bottom track


def test_real_ensembles_without_bottom_track_keep_attitude_and_heading():
    """RDI_test01.000 has no bottom track in any ensemble: each gives a sample with its
    time, dolfyn's heading, pitch and roll, and NaN velocity and ranges (no bottom lock);
    the navigator holds them, says the compass gives the heading, and poses carry the
    attitude, flagged compass, without bottom lock."""
    import h5py
    ens = real("RDI_test01.000")
    assert len(ens) == 22 and all(e.bottom_track is None for e in ens)
    with h5py.File(DATA / "RDI_test01.nc", "r") as f:
        ref = {k: f[k][:].astype(np.float64) for k in ("heading", "pitch", "roll", "time")}
    samples = [nav.dvl_sample_from_pd0(e, 3, 30 * DEG) for e in ens]
    assert all(s is not None for s in samples)
    np.testing.assert_allclose([s.time_ns * 1e-9 for s in samples], ref["time"], atol=1e-6)
    np.testing.assert_allclose([_deg(s.heading_rad) for s in samples], ref["heading"], atol=1e-4)
    np.testing.assert_allclose([math.degrees(s.pitch_rad) for s in samples], ref["pitch"],
                               atol=1e-4)
    np.testing.assert_allclose([math.degrees(s.roll_rad) for s in samples], ref["roll"],
                               atol=1e-4)
    for s in samples:
        assert not s.bottom_lock and np.all(np.isnan(s.velocity_body_m_s))
        assert np.all(np.isnan(s.ranges_m)) and math.isnan(head_height_m(s))

    cfg = nav_cfg(origin_latitude_deg=ORIGIN[0], origin_longitude_deg=ORIGIN[1],
                  origin_height_m=ORIGIN[2])
    n = nav.Navigator(cfg, LEVER)
    for e in ens:
        n.add_pd0(e)
    assert len(n.dvl) == 22 and n.counts["dvl_no_lock"] == 22
    q = n.quality(ens[-1].time_ns)
    assert q["heading_source"] == "dvl_compass" and q["bottom_lock"] is False
    assert q["dvl_age_s"] == pytest.approx(0.0)
    times = [e.time_ns for e in ens[2:-2]]
    for t, p, e in zip(times, n.poses(times), ens[2:-2]):
        assert p.roll_rad == pytest.approx(e.roll_rad, abs=1e-9)
        assert p.pitch_rad == pytest.approx(e.pitch_rad, abs=1e-9)
        assert _deg(p.heading_rad) == pytest.approx(_deg(e.heading_rad), abs=1e-6)
        assert p.quality & NAV_HEADING_FROM_COMPASS and not p.quality & NAV_BOTTOM_LOCK
        assert math.isnan(p.altitude_m)


def _patched(ens_bytes: bytes, patch) -> bytes:
    """An ensemble with its variable leader changed by ``patch(buf, offset)`` and its
    checksum made right again."""
    b = bytearray(ens_bytes)
    var = struct.unpack_from("<H", b, 8)[0]            # the second data type's offset
    assert struct.unpack_from("<H", b, var)[0] == 0x0080
    patch(b, var)
    n = struct.unpack_from("<H", b, 2)[0]
    struct.pack_into("<H", b, n, ensemble_checksum(bytes(b), 0, n))
    return bytes(b)


def _first_real_ensemble(name: str) -> bytes:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"real recordings not found: {DATA}")
    raw = path.read_bytes()
    return raw[:struct.unpack_from("<H", raw, 2)[0] + 2]


def test_an_ensemble_without_a_valid_time_still_gives_no_sample():
    """A real ensemble whose clocks (RTC and Y2K clock) say month 13: no time, no sample
    (the daemon counts those)."""
    def month_13(b, v):
        b[v + 5] = 13       # RTC month
        b[v + 59] = 13      # Y2K clock month
    e = pd0.decode_ensemble(_patched(_first_real_ensemble("RDI_test01.000"), month_13))
    assert e.time_ns is None
    assert nav.dvl_sample_from_pd0(e, 3, 30 * DEG) is None


# ----------------------------------------------------------------- 8a. missing pressure


def test_missing_pressure_decodes_as_missing():
    """0xFFFFFFFF daPa (4.3e6 dbar) is RDI's missing value: None, on a real ensemble
    patched so and on encoder-made ones; real pressures are kept (215.47 dbar, dolfyn)."""
    raw = _first_real_ensemble("RDI_test01.000")
    assert pd0.decode_ensemble(raw).variable.pressure_pa / 1e4 == pytest.approx(215.47)

    def missing(b, v):
        struct.pack_into("<II", b, v + 48, 0xFFFFFFFF, 0xFFFFFFFF)
    e = pd0.decode_ensemble(_patched(raw, missing))
    assert e.variable.pressure_pa is None and e.variable.pressure_variance_pa is None
    args = dict(ensemble_number=1, time_ns=T0, heading_rad=0.0, pitch_rad=0.0, roll_rad=0.0,
                bt_velocity_m_s=(0, 0, 0, 0), bt_range_m=(5, 5, 5, 5))
    assert pd0.decode_ensemble(encode_ensemble(Pd0Setup(), pressure_pa=None, **args)
                               ).variable.pressure_pa is None
    assert pd0.decode_ensemble(encode_ensemble(Pd0Setup(), pressure_pa=2.1547e6, **args)
                               ).variable.pressure_pa == pytest.approx(2.1547e6)


@pytest.mark.parametrize("alignment_deg", [0.0, 45.0, -30.0])
def test_earth_coordinates_and_the_compass_agree_on_the_body_axes(alignment_deg):
    """A head mounted with beam 3 ``alignment_deg`` off the bow (EA), the bow due north,
    moving 1 m/s forward: in earth coordinates the instrument sends the bottom moving
    south; turned back into the body frame it must be 1 m/s along body x whatever EA is,
    and the compass's body heading 0 (the earth branch once used the instrument's
    heading, EA off the body axes)."""
    setup = Pd0Setup(coordinate_system="earth", heading_alignment_deg=alignment_deg)
    raw = encode_ensemble(setup, ensemble_number=1, time_ns=1_780_000_000_000_000_000,
                          heading_rad=math.radians(alignment_deg), pitch_rad=0.0,
                          roll_rad=0.0, bt_velocity_m_s=[0.0, -1.0, 0.0, 0.0],
                          bt_range_m=[2.0] * 4)
    d = nav.dvl_sample_from_pd0(pd0.decode_ensemble(raw))
    assert d.velocity_body_m_s == pytest.approx((1.0, 0.0, 0.0), abs=2e-3)
    assert nav.wrap_angle(d.heading_rad) == pytest.approx(0.0, abs=1e-3)
