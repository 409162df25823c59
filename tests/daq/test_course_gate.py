"""The RMC course as a heading only where the receiver moves along it: a receiver
standing still reports speed noise above the 0.3 m/s threshold (0.16-0.39 m/s) with a
course that turns at random; its course must not become the platform's heading. The
RMC sentences are written out here (NMEA 0183: time, status, position, speed in knots,
course in degrees true, date), parsed by the project's stream parser."""

from __future__ import annotations

import math

import numpy as np

from svss_daq.navigation import samples_from_nmea
from svss_daq.protocols.nmea import NmeaStreamParser

LAT0, LON0 = 50.2131, -8.1146


def nmea_checksum(body: str) -> int:
    """NMEA 0183: the XOR of every character between '$' and '*'."""
    x = 0
    for ch in body.encode("ascii"):
        x ^= ch
    return x
KNOT = 1852.0 / 3600.0


def _rmc(t_s: float, north_m: float, east_m: float, speed_m_s: float, course_deg: float):
    lat = LAT0 + math.degrees(north_m / 6_371_000.0)
    lon = LON0 + math.degrees(east_m / (6_371_000.0 * math.cos(math.radians(LAT0))))
    hh, rem = divmod(12 * 3600 + t_s, 3600)
    mm, ss = divmod(rem, 60)
    la, lo = abs(lat), abs(lon)
    body = (f"GPRMC,{int(hh):02d}{int(mm):02d}{ss:05.2f},A,"
            f"{int(la):02d}{(la - int(la)) * 60:09.6f},{'N' if lat >= 0 else 'S'},"
            f"{int(lo):03d}{(lo - int(lo)) * 60:09.6f},{'E' if lon >= 0 else 'W'},"
            f"{speed_m_s / KNOT:.2f},{course_deg % 360:.1f},041226,,,A")
    return f"${body}*{nmea_checksum(body):02X}\r\n"


def _headings(lines):
    parser = NmeaStreamParser()
    recs = [(10**18 + i * 10**9, r) for i, line in enumerate(lines)
            for r in parser.feed(line.encode())]
    _, heads = samples_from_nmea(recs, 0.3)
    return [h for h in heads if h.from_course]


def test_a_receiver_standing_still_gives_no_course_heading():
    rng = np.random.default_rng(48)
    lines = [_rmc(k, *rng.normal(0.0, 0.3, 2), rng.uniform(0.16, 0.39),
                  rng.uniform(0, 360)) for k in range(120)]
    speeds = [float(line.split(",")[7]) * KNOT for line in lines]
    assert sum(v > 0.3 for v in speeds) > 40          # the old gate let these through
    assert _headings(lines) == []


def test_a_moving_receiver_gives_its_course():
    rng = np.random.default_rng(49)
    course = 40.0
    lines = []
    for k in range(120):
        d = 1.0 * k + rng.normal(0.0, 0.3)
        n, e = d * math.cos(math.radians(course)), d * math.sin(math.radians(course))
        lines.append(_rmc(k, n + rng.normal(0, 0.3), e + rng.normal(0, 0.3),
                          1.0 + rng.normal(0, 0.1), course + rng.normal(0, 2.0)))
    heads = _headings(lines)
    assert len(heads) >= 110                          # all but the first baseline's
    err = [(math.degrees(h.heading_rad) - course + 180) % 360 - 180 for h in heads]
    assert max(abs(e) for e in err) < 8.0
