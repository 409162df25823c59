"""PD0 and NMEA encoders: round trip through the project's parsers, and byte layout
against real recordings (../shared/data), so the encoders cannot drift from the
instruments."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from svss_daq.protocols import nmea, pd0
from svss_daq.protocols import nmea_encoder as ne
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.navigation import dvl_sample_from_pd0

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
DEG = math.pi / 180


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real recordings not found: {path.parent}")
    return path


# ------------------------------------------------------------------------------ PD0


@pytest.mark.parametrize("cs", ["ship", "earth"])
def test_pd0_round_trip(cs):
    rng = np.random.default_rng(3)
    setup = Pd0Setup(frequency_hz=1200e3, beam_angle_deg=20.0, coordinate_system=cs,
                     serial_number=4_000_000_001)
    for k in range(50):
        t = 1_795_000_000_000_000_000 + int(rng.integers(0, 10**12)) * 1000
        hdg, pitch, roll = rng.uniform(-4, 4), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)
        vel = rng.uniform(-5, 5, 4)
        rng_m = rng.uniform(0.5, 1000, 4)
        if k % 5 == 0:
            vel[:] = np.nan
            rng_m[k % 4] = np.nan
        data = encode_ensemble(setup, ensemble_number=70_000 + k, time_ns=t, heading_rad=hdg,
                               pitch_rad=pitch, roll_rad=roll, bt_velocity_m_s=vel,
                               bt_range_m=rng_m, sound_speed_m_s=1487.4, depth_m=3.27,
                               salinity_ppt=34.6, temperature_c=11.234)
        e = pd0.decode_ensemble(data)  # checksum verified
        assert e.n_bytes == len(data)
        assert e.ensemble_number == 70_000 + k
        assert abs(e.time_ns - t) <= 5_000_000  # 10 ms clock
        assert math.remainder(e.heading_rad - hdg, 2 * math.pi) == pytest.approx(0, abs=0.005 * DEG)
        assert e.pitch_rad == pytest.approx(pitch, abs=0.005 * DEG)
        assert e.roll_rad == pytest.approx(roll, abs=0.005 * DEG)
        assert e.sound_speed_mps == 1487.0 and e.depth_m == pytest.approx(3.3)
        assert e.variable.temperature_degc == pytest.approx(11.23)
        f = e.fixed
        assert (f.coordinate_system, f.system_frequency_hz, f.serial_number) == (cs, 1200e3, 4_000_000_001)
        assert f.beam_angle_rad == pytest.approx(20 * DEG) and f.orientation == "down"
        bt = e.bottom_track
        np.testing.assert_allclose(bt.velocity_mps, vel, atol=0.0005)
        np.testing.assert_array_equal(np.isnan(bt.velocity_mps), np.isnan(vel))
        np.testing.assert_allclose(bt.range_m, rng_m, atol=0.005)
        np.testing.assert_array_equal(np.isnan(bt.range_m), np.isnan(rng_m))


def test_pd0_velocity_reaches_navigation_as_the_head_velocity():
    """Ship and earth coordinates both give navigation the same body velocity."""
    from svss_daq.frames import body_to_ned
    v_body = np.array([1.2, -0.3, 0.05])
    r, p, h = 0.05, -0.02, 2.0
    ned = body_to_ned(r, p, h) @ v_body
    got = []
    for cs, bt in (("ship", [-v_body[1], -v_body[0], v_body[2], 0.0]),
                   ("earth", [-ned[1], -ned[0], ned[2], 0.0])):
        e = pd0.decode_ensemble(encode_ensemble(
            Pd0Setup(coordinate_system=cs), ensemble_number=1, time_ns=1_795_000_000 * 10**9,
            heading_rad=h, pitch_rad=p, roll_rad=r, bt_velocity_m_s=bt, bt_range_m=[5] * 4))
        got.append(dvl_sample_from_pd0(e).velocity_body_m_s)
    np.testing.assert_allclose(got[0], v_body, atol=0.0006)
    np.testing.assert_allclose(got[1], v_body, atol=0.002)  # plus attitude quantisation


def test_pd0_errors_name_the_field():
    args = dict(ensemble_number=1, time_ns=1_795_000_000 * 10**9, heading_rad=0.0,
                pitch_rad=0.0, roll_rad=0.0, bt_velocity_m_s=[0] * 4, bt_range_m=[1] * 4)
    with pytest.raises(ValueError, match="sound_speed_m_s"):
        encode_ensemble(Pd0Setup(), **{**args, "sound_speed_m_s": 900.0})
    with pytest.raises(ValueError, match="bottom-track velocity 2"):
        encode_ensemble(Pd0Setup(), **{**args, "bt_velocity_m_s": [0, 40.0, 0, 0]})
    with pytest.raises(ValueError, match="frequency_hz"):
        encode_ensemble(Pd0Setup(frequency_hz=500e3), **args)


def test_pd0_layout_matches_a_real_workhorse():
    """Same header shape, fixed/variable leader and bottom-track lengths and the same
    configuration fields as a Workhorse with bottom tracking (RDI_withBT.000)."""
    real = _need(DATA / "dvl_pd0" / "RDI_withBT.000").read_bytes()
    n_real, nt_real = struct.unpack_from("<HxB", real, 2)
    off_real = struct.unpack_from(f"<{nt_real}H", real, 6)
    ids_real = [struct.unpack_from("<H", real, o)[0] for o in off_real]
    len_real = dict(zip(ids_real, np.diff(list(off_real) + [n_real])))
    ours = encode_ensemble(Pd0Setup(coordinate_system="earth"), ensemble_number=1,
                           time_ns=1_795_000_000 * 10**9, heading_rad=0.0, pitch_rad=0.0,
                           roll_rad=0.0, bt_velocity_m_s=[0] * 4, bt_range_m=[1] * 4)
    n, nt = struct.unpack_from("<HxB", ours, 2)
    off = struct.unpack_from(f"<{nt}H", ours, 6)
    ids = [struct.unpack_from("<H", ours, o)[0] for o in off]
    lens = dict(zip(ids, np.diff(list(off) + [n])))
    assert ids == [0x0000, 0x0080, 0x0600]  # bottom track only (WP0)
    assert set(ids) <= set(ids_real)
    for i in ids:
        assert lens[i] == len_real[i], f"data type 0x{i:04X}: {lens[i]} bytes, real {len_real[i]}"
    assert off[0] == 6 + 2 * nt and len(ours) == n + 2
    a, b = pd0.decode_ensemble(real), pd0.decode_ensemble(ours)
    assert (b.fixed.n_beams, b.fixed.beam_pattern, b.fixed.orientation, b.fixed.coordinate_system) \
        == (a.fixed.n_beams, a.fixed.beam_pattern, a.fixed.orientation, a.fixed.coordinate_system)
    assert a.variable.rtc[0] >= 2000 and b.variable.rtc[0] >= 2000  # both carry the Y2K clock


# ----------------------------------------------------------------------------- NMEA


def _parse(b: bytes):
    assert b.endswith(b"\r\n")
    return nmea.parse_sentence(b.decode("ascii").strip())


def test_nmea_round_trip():
    rng = np.random.default_rng(5)
    p = nmea.NmeaStreamParser()
    for _ in range(200):
        t = 1_795_000_000_000_000_000 + int(rng.integers(0, 10**14)) * 100
        lat, lon = rng.uniform(-89.9, 89.9), rng.uniform(-179.9, 179.9)
        spd, crs, hdg = rng.uniform(0, 15), rng.uniform(-7, 7), rng.uniform(-7, 7)
        alt, sep = rng.uniform(-50, 500), rng.uniform(-100, 100)
        q = int(rng.choice([1, 2, 4, 5]))
        g = _parse(ne.gga("GN", t, lat, lon, q, 11, 0.8, alt, sep))
        assert g.latitude_deg == pytest.approx(lat, abs=1e-9) and g.longitude_deg == pytest.approx(lon, abs=1e-9)
        assert (g.fix_quality, g.satellites, g.hdop) == (q, 11, 0.8)
        assert g.altitude_msl_m == pytest.approx(alt, abs=5e-4) and g.geoid_separation_m == pytest.approx(sep, abs=5e-4)
        r = _parse(ne.rmc("GN", t, True, lat, lon, spd, crs, "D"))
        assert r.valid and r.mode == "D" and abs(r.time_ns - t) <= 5_000_000
        assert r.latitude_deg == pytest.approx(lat, abs=1e-9) and r.speed_mps == pytest.approx(spd, abs=3e-4)
        assert math.remainder(r.course_rad - crs, 2 * math.pi) == pytest.approx(0, abs=0.005 * DEG)
        v = _parse(ne.vtg("GN", crs, spd, "D"))
        assert v.speed_mps == pytest.approx(spd, abs=3e-4)
        assert math.remainder(v.course_true_rad - crs, 2 * math.pi) == pytest.approx(0, abs=0.005 * DEG)
        h = _parse(ne.hdt("HE", hdg))
        assert h.talker == "HE" and math.remainder(h.heading_rad - hdg, 2 * math.pi) == pytest.approx(0, abs=0.005 * DEG)
        z = _parse(ne.zda("GN", t))
        assert abs(z.time_ns - t) <= 5_000_000
        # the stream parser dates GGA from the ZDA before it
        recs = p.feed(ne.zda("GN", t) + ne.gga("GN", t, lat, lon, q))
        assert recs[1].time_ns == recs[0].time_ns


def test_nmea_no_fix_sentences_parse_as_no_fix():
    t = 1_795_000_000 * 10**9
    g = _parse(ne.gga("GP", t, None, None, 0))
    assert g.fix_quality == 0 and not g.has_fix and g.latitude_deg is None
    r = _parse(ne.rmc("GP", t, False, None, None, None, None))
    assert not r.valid and r.mode == "N" and r.time_ns == t
    assert _parse(ne.hdt("GP", None)).heading_rad is None
    assert _parse(ne.vtg("GP", None, None, "N")).speed_mps is None


def test_nmea_edges_and_errors():
    # rounding never writes 60 minutes, and carries into the degrees
    assert ne.format_latlon(41.99999999999, True) == ("4200.0000000", "N")
    assert ne.format_latlon(-0.5, False) == ("00030.0000000", "W")
    assert ne.format_time(86_399_996 * 10**6) == "000000.00"  # rounds into the next day
    with pytest.raises(ValueError, match="latitude"):
        ne.gga("GP", 0, 91.0, 0.0, 1)
    with pytest.raises(ValueError, match="fix_quality"):
        ne.gga("GP", 0, 1.0, 0.0, 9)
    with pytest.raises(ValueError, match="speed"):
        ne.vtg("GP", 0.0, -1.0)


def _real_lines(name: str) -> list[str]:
    text = _need(DATA / "gps_nmea" / name).read_text(errors="replace")
    return [ln.strip() for ln in text.splitlines() if ln.startswith("$")]


@pytest.mark.parametrize("kind", ["GGA", "RMC", "VTG", "HDT", "ZDA"])
def test_nmea_layout_matches_real_receivers(kind):
    """Field count and the width of the time/position fields as real receivers send them
    (Hemisphere for GGA, VTG, HDT, ZDA; Saab R4 for RMC)."""
    lines = [ln for ln in _real_lines("hemi.log") + _real_lines("saab-r4.log")
             if ln[3:6] == kind and ln.split(",")[1 if kind != "HDT" else 0]]
    if kind == "GGA":
        lines = [ln for ln in lines if ln.split(",")[2]]
    assert lines, f"no real {kind} with data"
    real = lines[0].split("*")[0].split(",")
    t = 1_795_000_000_120_000_000
    ours_b = {"GGA": ne.gga("GP", t, 42.36, -71.03, 1, 9, 0.9, 10.8, -33.3),
              "RMC": ne.rmc("GP", t, True, 50.2, -8.1, 0.25, 0.05),
              "VTG": ne.vtg("GP", 0.05, 0.25),
              "HDT": ne.hdt("GP", 0.07),
              "ZDA": ne.zda("GP", t)}[kind]
    ours = ours_b.decode().strip().split("*")[0].split(",")
    # the Saab R4 leaves out RMC's variation direction (docs/drivers.md); NMEA 2.3 has it
    quirk = 1 if kind == "RMC" and real[-2] == "" and real[-1] in "ADN" else 0
    assert len(ours) == len(real) + quirk, f"{kind}: {ours} vs real {real}"
    assert nmea.parse_sentence(lines[0]) is not None
    if kind in ("GGA", "RMC", "ZDA"):
        assert len(ours[1].split(".")[0]) == len(real[1].split(".")[0]) == 6  # hhmmss
    if kind == "GGA":
        for k in (2, 4):  # ddmm / dddmm before the point, same decimals as Hemisphere
            assert [len(x) for x in ours[k].split(".")] == [len(x) for x in real[k].split(".")]
