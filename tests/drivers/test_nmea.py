"""NMEA 0183 parser: real receiver logs against gpsd's decodings, field and unit
checks, the checksum policy, and property-based fuzzing of the line stream."""

from __future__ import annotations

import calendar
import json
import math
import os
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svss_daq.protocols.nmea import (
    KNOT_MPS,
    ChecksumPolicy,
    GgaFix,
    GllPosition,
    HdtHeading,
    NmeaError,
    NmeaStreamParser,
    RmcFix,
    RotRate,
    VtgVelocity,
    ZdaTime,
    nmea_checksum,
    parse_sentence,
)

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "gps_nmea"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data folder missing: {DATA}")

_DEEP = int(os.environ.get("SVSS_FUZZ_EXAMPLES", "0"))
FUZZ = settings(max_examples=_DEEP or 150, deadline=2000, derandomize=not _DEEP, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

DEG = math.pi / 180


def with_cs(body: str) -> str:
    return f"${body}*{nmea_checksum(body):02X}"


def decode_log(name: str, policy="require") -> tuple:
    parser = NmeaStreamParser(policy)
    recs = parser.feed((DATA / name).read_bytes()) + parser.flush()
    return recs, parser.stats


def gpsd_reports(name: str) -> list:
    """(the sentence line a report follows, the report) from gpsd's .chk file."""
    out, last = [], None
    for line in (DATA / name).read_text().splitlines():
        if line.startswith("{"):
            out.append((last, json.loads(line)))
        elif line.startswith(("$", "!")):
            last = line
    return out


def tod_ns(iso: str) -> int:
    hms = iso.split("T")[1].rstrip("Z")
    h, m, s = hms.split(":")
    sec, _, frac = s.partition(".")
    return ((int(h) * 60 + int(m)) * 60 + int(sec)) * 10**9 + int(frac.ljust(9, "0"))


def by_type_and_time(recs: list) -> dict:
    out = {}
    for r in recs:
        t = getattr(r, "time_of_day_ns", None)
        if t is not None:
            out.setdefault((r.sentence_type, t), r)
    return out


LATLON_TOL = 1e-9  # gpsd prints 9 decimals (about 0.1 mm)


@needs_data
def test_hemisphere_log_against_gpsd():
    recs, stats = decode_log("hemi.log")
    assert Counter(type(r).__name__ for r in recs) == {"GgaFix": 215, "HdtHeading": 215, "VtgVelocity": 215,
                                                       "ZdaTime": 108}
    assert stats.rejected == 2 == stats.rejected_malformed  # the two '#' comment lines
    index = by_type_and_time(recs)
    reports = gpsd_reports("hemi.log.chk")
    tpv = [(s, r) for s, r in reports if r["class"] == "TPV"]
    assert len(tpv) == 215 and all(s.startswith("$GPGGA") for s, _ in tpv)  # gpsd reports at each GGA
    n_pos = n_nofix = 0
    ggas = [r for r in recs if isinstance(r, GgaFix)]
    for (sentence, rep), gga in zip(tpv, ggas):  # one TPV per GGA, in order
        if gga.time_of_day_ns is not None:  # (for time-less GGAs gpsd uses the ZDA's time)
            assert gga.time_of_day_ns == tod_ns(rep["time"])
            assert index[("GGA", gga.time_of_day_ns)] is gga
        # gpsd: a fix needs quality > 0 and satellites in use > 0; altitude makes it 3-D.
        if gga.fix_quality > 0 and gga.satellites:
            assert rep["mode"] == (3 if gga.altitude_msl_m is not None else 2)
            assert abs(gga.latitude_deg - rep["lat"]) <= LATLON_TOL
            assert abs(gga.longitude_deg - rep["lon"]) <= LATLON_TOL
            assert gga.altitude_msl_m == pytest.approx(rep["altMSL"], abs=5e-4)
            assert gga.geoid_separation_m == pytest.approx(rep["geoidSep"], abs=5e-4)
            assert gga.altitude_msl_m + gga.geoid_separation_m == pytest.approx(rep["altHAE"], abs=1e-3)
            n_pos += 1
        else:
            assert rep["mode"] == 1 and "lat" not in rep
            n_nofix += 1
    assert (n_pos, n_nofix) == (6, 209)
    # gpsd's ATT reports carry the HDT headings.
    att = [r["heading"] for _, r in reports if r["class"] == "ATT"]
    hdt = [r.heading_rad for r in recs if isinstance(r, HdtHeading) and r.heading_rad is not None]
    assert len(att) == len(hdt) == 4
    assert max(abs(h - a * DEG) for h, a in zip(hdt, att)) <= 1e-9
    # Times: the ZDA's date is carried to the 21 GGAs that have a time of day.
    first_zda = next(r for r in recs if isinstance(r, ZdaTime))
    assert first_zda.time_ns == calendar.timegm((2018, 9, 7, 19, 39, 13)) * 10**9
    dated = [g for g in ggas if g.time_ns is not None]
    assert all(g.date_from_stream for g in dated) and len(dated) == 21
    assert dated[0].time_ns == calendar.timegm((2018, 9, 7, 19, 40, 50)) * 10**9
    assert all(g.time_ns % (86400 * 10**9) == g.time_of_day_ns for g in dated)


@needs_data
def test_saab_log_against_gpsd():
    recs, stats = decode_log("saab-r4.log")
    assert Counter(type(r).__name__ for r in recs) == {
        "GgaFix": 12, "RmcFix": 12, "VtgVelocity": 12, "ZdaTime": 12, "GllPosition": 12,
        "HdtHeading": 12, "RotRate": 12}
    assert stats.ignored_ais == 14  # !AIVDM and !AIVDO
    assert stats.ignored_unsupported == 24  # $PFEC (proprietary) and $GPDTM
    assert stats.rejected == 4  # the '#' comment lines
    index = by_type_and_time(recs)
    compared = Counter()
    for sentence, rep in gpsd_reports("saab-r4.log.chk"):
        if rep["class"] != "TPV":
            continue
        stype = sentence[3:6]
        rec = index[(stype, tod_ns(rep["time"]))]
        if "lat" in rep:
            assert abs(rec.latitude_deg - rep["lat"]) <= LATLON_TOL
            assert abs(rec.longitude_deg - rep["lon"]) <= LATLON_TOL
            assert rep["mode"] == 2 and rec.valid  # 2-D: no altitude in this receiver's output
            compared["position"] += 1
        if "speed" in rep:  # printed with 3 decimals
            assert abs(rec.speed_mps - rep["speed"]) <= 5e-4 + 1e-12
            compared["speed"] += 1
        if "track" in rep:  # printed with 4 decimals
            assert abs(rec.course_rad - rep["track"] * DEG) <= 5e-5 * DEG + 1e-12
            compared["track"] += 1
        if rep.get("status") == 2:  # DGPS
            assert (rec.mode == "D") if isinstance(rec, GllPosition) else (rec.fix_quality == 2)
            compared["dgps"] += 1
        if isinstance(rec, GgaFix):  # no satellite count: gpsd reports no fix
            assert rec.satellites is None and rep["mode"] == 1
    assert compared == {"position": 13, "speed": 12, "track": 12, "dgps": 2}
    # VTG and RMC of a cycle agree; the HEHDT gyro heading (no gpsd report) decodes too.
    vtg = [r for r in recs if isinstance(r, VtgVelocity)]
    rmc = [r for r in recs if isinstance(r, RmcFix)]
    assert all(abs(v.speed_mps - r.speed_mps) < 1e-12 and abs(v.course_true_rad - r.course_rad) < 1e-12
               for v, r in zip(vtg, rmc))
    hdt = [r for r in recs if isinstance(r, HdtHeading)]
    assert {h.talker for h in hdt} == {"HE"} and {round(h.heading_rad / DEG, 6) for h in hdt} == {4.0, 4.1}
    assert all(r.time_ns == calendar.timegm((2011, 6, 1, 0, 0, 0)) * 10**9 + r.time_of_day_ns for r in rmc)


def test_units_and_fields_of_each_sentence_type():
    rmc = parse_sentence(with_cs("GNRMC,235959.125,A,4916.45,S,12311.12,W,10.0,90.0,311299,3.1,W,D"))
    assert isinstance(rmc, RmcFix) and rmc.talker == "GN" and rmc.valid
    assert rmc.latitude_deg == pytest.approx(-(49 + 16.45 / 60), abs=1e-12)
    assert rmc.longitude_deg == pytest.approx(-(123 + 11.12 / 60), abs=1e-12)
    assert rmc.speed_mps == pytest.approx(10 * 1852 / 3600, abs=1e-12) and KNOT_MPS == 1852 / 3600
    assert rmc.course_rad == pytest.approx(math.pi / 2, abs=1e-15)
    assert rmc.magnetic_variation_rad == pytest.approx(-3.1 * DEG, abs=1e-15)
    assert rmc.time_of_day_ns == (23 * 3600 + 59 * 60 + 59) * 10**9 + 125_000_000
    assert rmc.time_ns == calendar.timegm((1999, 12, 31, 23, 59, 59)) * 10**9 + 125_000_000
    assert rmc.mode == "D" and not rmc.date_from_stream

    gga = parse_sentence(with_cs("GPGGA,123519.5,4807.038,N,01131.000,E,4,08,0.9,545.4,M,46.9,M,1.2,0031"))
    assert isinstance(gga, GgaFix) and gga.has_fix and gga.fix_quality == 4 and gga.satellites == 8
    assert (gga.hdop, gga.altitude_msl_m, gga.geoid_separation_m, gga.dgps_age_s, gga.dgps_station) == \
        (0.9, 545.4, 46.9, 1.2, "0031")
    assert gga.latitude_deg == pytest.approx(48 + 7.038 / 60, abs=1e-12) and gga.longitude_deg == pytest.approx(11 + 31 / 60, abs=1e-12)
    assert gga.time_ns is None and not gga.has_date and gga.time_of_day_ns == 45319_500_000_000

    nofix = parse_sentence("$GPGGA,,,,,,0,,,,M,,M,,*66")
    assert nofix.fix_quality == 0 and nofix.latitude_deg is None and not nofix.has_fix

    vtg = parse_sentence(with_cs("GPVTG,,T,,M,,N,36.0,K,A"))  # km/h only
    assert vtg.speed_mps == pytest.approx(10.0) and vtg.course_true_rad is None
    legacy = parse_sentence(with_cs("GPVTG,054.7,034.4,005.5,010.2"))
    assert legacy.course_true_rad == pytest.approx(54.7 * DEG) and legacy.course_magnetic_rad == pytest.approx(34.4 * DEG)
    assert legacy.speed_mps == pytest.approx(5.5 * KNOT_MPS)

    assert parse_sentence(with_cs("HEHDT,359.99,T")).heading_rad == pytest.approx(359.99 * DEG)
    assert parse_sentence(with_cs("GPHDT,,T")).heading_rad is None
    rot = parse_sentence(with_cs("HEROT,-60.0,A"))
    assert isinstance(rot, RotRate) and rot.rate_rad_s == pytest.approx(-DEG)

    zda = parse_sentence(with_cs("GPZDA,201530.00,04,07,2002,-05,30"))
    assert zda.time_ns == calendar.timegm((2002, 7, 4, 20, 15, 30)) * 10**9
    assert zda.local_zone_offset_s == -(5 * 3600 + 30 * 60)

    gll = parse_sentence(with_cs("GPGLL,3751.65,S,14507.36,E,225444,A,A"))
    assert isinstance(gll, GllPosition) and gll.valid and gll.latitude_deg == pytest.approx(-(37 + 51.65 / 60))
    assert gll.time_of_day_ns == (22 * 3600 + 54 * 60 + 44) * 10**9

    assert parse_sentence(with_cs("PFEC,GPatt,1")) is None  # proprietary: ignored
    assert parse_sentence(with_cs("GPGSV,1,1,00")) is None  # unsupported type: ignored
    assert parse_sentence("!AIVDM,1,1,,B,13aGhtw0R<OJf=6LgQ?Ad1FF05`L,0*24") is None


def test_dates_are_carried_across_midnight():
    p = NmeaStreamParser()
    lines = [with_cs("GPZDA,235959.00,31,12,2023,00,00"), with_cs("GPGGA,235959.50,,,,,0,,,,M,,M,,"),
             with_cs("GPGGA,000000.50,,,,,0,,,,M,,M,,"), with_cs("GPGLL,,,,,000001,V,N")]
    recs = p.feed(("\r\n".join(lines) + "\r\n").encode())
    midnight = calendar.timegm((2024, 1, 1, 0, 0, 0)) * 10**9
    assert [r.time_ns for r in recs] == [midnight - 10**9, midnight - 500_000_000, midnight + 500_000_000,
                                         midnight + 10**9]
    assert [r.date_from_stream for r in recs] == [False, True, True, True]
    q = NmeaStreamParser(infer_dates=False)
    assert q.feed(("\r\n".join(lines) + "\r\n").encode())[1].time_ns is None


def test_checksum_policy():
    good = with_cs("GPHDT,12.5,T")
    bare = "$GPHDT,12.5,T"
    wrong = good[:-2] + ("00" if good[-2:] != "00" else "01")
    assert parse_sentence(good, "require").heading_rad == pytest.approx(12.5 * DEG)
    assert parse_sentence("$GPHDT,28.5,T*0a", "require").heading_rad == pytest.approx(28.5 * DEG)  # lower-case hex
    with pytest.raises(NmeaError) as ei:
        parse_sentence(bare, ChecksumPolicy.REQUIRE)
    assert ei.value.field == "checksum" and ei.value.found == "none"
    assert parse_sentence(bare, "verify_if_present").heading_rad == pytest.approx(12.5 * DEG)
    for policy in ChecksumPolicy:
        with pytest.raises(NmeaError) as ei:
            parse_sentence(wrong, policy)
        assert ei.value.field == "checksum" and ei.value.expected.startswith(good[-2:])
    with pytest.raises(ValueError, match="checksum policy"):
        NmeaStreamParser("sometimes")

    stream = f"{good}\r\n{bare}\r\n{wrong}\r\n".encode()
    strict, lax = NmeaStreamParser("require"), NmeaStreamParser("verify_if_present")
    assert len(strict.feed(stream)) == 1 and strict.stats.rejected_checksum == 2
    assert len(lax.feed(stream)) == 2 and lax.stats.rejected_checksum == 1


@pytest.mark.parametrize("body, field", [
    ("GPGGA,123519,48x7.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,", "GGA lat"),
    ("GPGGA,123519,4807.038,Q,01131.000,E,1,08,0.9,545.4,M,46.9,M,,", "GGA lat_dir"),
    ("GPGGA,123519,4867.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,", "GGA lat"),
    ("GPGGA,253519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,", "GGA timestamp"),
    ("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,nan,M,46.9,M,,", "GGA altitude"),
    ("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,310299,003.1,W", "RMC datestamp"),
    ("GPZDA,201530.00,31,02,2002,00,00", "ZDA date"),
    ("GPHDT,north,T", "HDT heading"),
])
def test_malformed_fields_are_named(body, field):
    with pytest.raises(NmeaError) as ei:
        parse_sentence(with_cs(body))
    assert ei.value.field == field
    assert field in str(ei.value) and "expected" in str(ei.value)
    p = NmeaStreamParser()
    assert p.feed((with_cs(body) + "\r\n").encode()) == [] and p.stats.rejected_malformed == 1


def test_garbage_lines_are_dropped_and_memory_is_bounded():
    good = with_cs("GPHDT,1.0,T")
    p = NmeaStreamParser(max_line_length=82)
    data = (b"\x00\xffjunk" + good.encode() + b"\r\n"  # junk glued in front: sentence kept
            + b"$GPHDT,1.0,T\xe9*2B\r\n"  # non-ASCII inside: rejected
            + b"A" * 5000  # no line end for a long time: dropped, bounded
            + good.encode() + b"\n" + b"$" + b"9" * 300 + b"\r\n")  # over-long sentence line
    out = []
    for i in range(0, len(data), 97):
        out += p.feed(data[i:i + 97])
        assert p.buffered <= 82
    assert [r.heading_rad for r in out] == [pytest.approx(DEG)] * 2
    assert p.stats.rejected_non_ascii == 1 and p.stats.rejected_overlong == 2
    assert p.stats.rejected == 3 and p.stats.lines == 3  # an over-long line is counted only as such
    assert p.feed(object()) == []  # type: ignore[arg-type]


# -- property-based fuzzing ------------------------------------------------------------

def _log_lines() -> list:
    lines = []
    for name in ("hemi.log", "saab-r4.log"):
        lines += [ln for ln in (DATA / name).read_text().splitlines() if ln.startswith(("$", "!"))]
    return lines


LINES = _log_lines() if DATA.is_dir() else ["$GPHDT,,T*1B"]
NOISE_CHARS = st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters="$!*")


@st.composite
def nmea_garbage(draw):
    src = LINES[draw(st.integers(0, len(LINES) - 1))]
    kind = draw(st.sampled_from(["random", "truncated", "corrupted", "long"]))
    if kind == "random":
        return draw(st.binary(max_size=400))
    if kind == "long":
        return draw(st.binary(min_size=300, max_size=1200)) + b"\r\n"
    if kind == "truncated":  # checksum cut off or partly cut off
        return src[:draw(st.integers(1, max(1, src.find("*") + 2)))].encode() + b"\r\n"
    star = src.find("*")
    i = draw(st.integers(1, star - 1))
    c = draw(NOISE_CHARS.filter(lambda ch: ch != src[i]))
    return (src[:i] + c + src[i + 1:]).encode() + b"\r\n"


nmea_segments = st.lists(st.one_of(st.integers(0, len(LINES) - 1).map(lambda i: ("ok", i)),
                                   nmea_garbage().map(lambda g: ("junk", g))), min_size=1, max_size=25)
chunk_sizes = st.lists(st.integers(1, 300), min_size=1, max_size=6)


def _feed_chunked(parser, data: bytes, sizes: list) -> list:
    out, pos, k = [], 0, 0
    while pos < len(data):
        n = sizes[k % len(sizes)]
        out += parser.feed(data[pos:pos + n])
        assert parser.buffered <= parser.max_line_length
        pos += n
        k += 1
    return out + parser.flush()


@FUZZ
@given(data=st.binary(max_size=4000), sizes=chunk_sizes, policy=st.sampled_from(list(ChecksumPolicy)))
def test_fuzz_random_bytes_never_raise(data, sizes, policy):
    parser = NmeaStreamParser(policy)
    _feed_chunked(parser, data, sizes)
    assert parser.stats.internal_errors == 0 and parser.buffered == 0


@needs_data
@FUZZ
@given(segs=nmea_segments, sizes=chunk_sizes)
def test_fuzz_recovers_every_intact_sentence_after_garbage(segs, sizes):
    clean = "".join(LINES[x] + "\r\n" for kind, x in segs if kind == "ok").encode()
    expected = NmeaStreamParser().feed(clean)
    dirty = b"".join((LINES[x] + "\r\n").encode() if kind == "ok" else x for kind, x in segs)
    parser = NmeaStreamParser()
    got = _feed_chunked(parser, dirty, sizes)
    assert got == expected
    assert parser.stats.internal_errors == 0
