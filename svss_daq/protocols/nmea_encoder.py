"""NMEA 0183 sentences: encoding, the mirror of :mod:`svss_daq.protocols.nmea`.

GGA, RMC, VTG, HDT, ZDA and GST formatted like a survey-grade receiver (Hemisphere style):
time ``hhmmss.ss``, latitude ``ddmm.mmmmmmm``, longitude ``dddmm.mmmmmmm`` (1e-7 minute,
about 0.2 mm), altitude and geoid separation to 1 mm, speed to 0.001 kn, course and
heading to 0.01 deg, each sentence ``$<talker><type>,...*hh\\r\\n`` with the XOR checksum.

Inputs in the parser's units: degrees for latitude/longitude, radians for course and
heading, m/s for speed, m for heights, int ns since the Unix epoch (UTC) for times. A
``None`` position (or heading) gives the empty fields a receiver sends without a fix.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from typing import Optional

from svss_daq.protocols.nmea import KNOT_MPS, nmea_checksum

__all__ = ["sentence", "gga", "rmc", "vtg", "hdt", "zda", "gst", "format_time", "format_latlon"]

_MINUTE_DIGITS = 7


def sentence(body: str) -> bytes:
    """``$body*hh\\r\\n`` with the checksum of ``body`` (address and fields, no ``$``)."""
    if "$" in body or "*" in body or not body.isascii():
        raise ValueError(f"NMEA sentence body: expected ASCII without '$' or '*', found {body!r}")
    return f"${body}*{nmea_checksum(body):02X}\r\n".encode("ascii")


def _utc(time_ns: int) -> tuple[datetime, int]:
    """(UTC datetime of the whole second, hundredths) of ``time_ns`` rounded to 10 ms."""
    hund = int(round(int(time_ns) / 1e7))
    return datetime.fromtimestamp(hund // 100, tz=timezone.utc), hund % 100


def format_time(time_ns: int) -> str:
    """``hhmmss.ss`` (UTC, rounded to 10 ms)."""
    dt, hs = _utc(time_ns)
    return f"{dt.hour:02d}{dt.minute:02d}{dt.second:02d}.{hs:02d}"


def format_latlon(value_deg: Optional[float], is_lat: bool) -> tuple[str, str]:
    """(``[d]ddmm.mmmmmmm``, hemisphere letter), or two empty fields for None."""
    if value_deg is None:
        return "", ""
    limit = 90.0 if is_lat else 180.0
    if not (math.isfinite(value_deg) and abs(value_deg) <= limit):
        name = "latitude" if is_lat else "longitude"
        raise ValueError(f"NMEA {name}: expected a number in [-{limit:g}, {limit:g}] deg, "
                         f"found {value_deg!r}")
    hemi = ("N" if value_deg >= 0 else "S") if is_lat else ("E" if value_deg >= 0 else "W")
    scale = 10 ** _MINUTE_DIGITS
    units = int(round(abs(value_deg) * 60.0 * scale))  # whole 1e-7 minutes: no 60.0 minutes
    deg, rem = divmod(units, 60 * scale)
    minutes = f"{rem // scale:02d}.{rem % scale:0{_MINUTE_DIGITS}d}"
    return (f"{deg:02d}" if is_lat else f"{deg:03d}") + minutes, hemi


def _course_deg(angle_rad: Optional[float], name: str) -> str:
    if angle_rad is None:
        return ""
    if not math.isfinite(angle_rad):
        raise ValueError(f"NMEA {name}: expected a finite angle in rad, found {angle_rad!r}")
    d = round(math.degrees(angle_rad) % 360.0, 2)
    return f"{0.0 if d >= 360.0 else d:.2f}"


def _speed_kn(speed_m_s: Optional[float]) -> str:
    if speed_m_s is None:
        return ""
    if not (math.isfinite(speed_m_s) and speed_m_s >= 0):
        raise ValueError(f"NMEA speed: expected a finite speed >= 0 m/s, found {speed_m_s!r}")
    return f"{speed_m_s / KNOT_MPS:.3f}"


def gga(talker: str, time_ns: int, latitude_deg: Optional[float],
        longitude_deg: Optional[float], fix_quality: int, satellites: int = 0,
        hdop: Optional[float] = None, altitude_msl_m: Optional[float] = None,
        geoid_separation_m: Optional[float] = None) -> bytes:
    """GGA. Without a fix (``fix_quality`` 0) pass None positions: the fields are empty."""
    if not 0 <= fix_quality <= 8:
        raise ValueError(f"NMEA GGA fix_quality: expected 0..8, found {fix_quality!r}")
    lat, ns = format_latlon(latitude_deg, True)
    lon, ew = format_latlon(longitude_deg, False)
    f = lambda v, n: "" if v is None else f"{v:.{n}f}"  # noqa: E731
    return sentence(f"{talker}GGA,{format_time(time_ns)},{lat},{ns},{lon},{ew},{fix_quality},"
                    f"{satellites:02d},{f(hdop, 1)},{f(altitude_msl_m, 3)},M,"
                    f"{f(geoid_separation_m, 3)},M,,")


def rmc(talker: str, time_ns: int, valid: bool, latitude_deg: Optional[float],
        longitude_deg: Optional[float], speed_m_s: Optional[float],
        course_rad: Optional[float], mode: str = "A") -> bytes:
    """RMC (NMEA 2.3, with the mode letter; magnetic variation empty). ``valid``: status
    A, else V (and mode N)."""
    dt, _ = _utc(time_ns)
    lat, ns = format_latlon(latitude_deg, True)
    lon, ew = format_latlon(longitude_deg, False)
    return sentence(f"{talker}RMC,{format_time(time_ns)},{'A' if valid else 'V'},{lat},{ns},"
                    f"{lon},{ew},{_speed_kn(speed_m_s)},{_course_deg(course_rad, 'RMC course')},"
                    f"{dt.day:02d}{dt.month:02d}{dt.year % 100:02d},,,{mode if valid else 'N'}")


def vtg(talker: str, course_rad: Optional[float], speed_m_s: Optional[float],
        mode: str = "A") -> bytes:
    """VTG (NMEA 2.3): true course, empty magnetic course, knots and km/h, mode."""
    kmh = "" if speed_m_s is None else f"{speed_m_s * 3.6:.3f}"
    return sentence(f"{talker}VTG,{_course_deg(course_rad, 'VTG course')},T,,M,"
                    f"{_speed_kn(speed_m_s)},N,{kmh},K,{mode}")


def hdt(talker: str, heading_rad: Optional[float]) -> bytes:
    """HDT: true heading (empty without one)."""
    return sentence(f"{talker}HDT,{_course_deg(heading_rad, 'HDT heading')},T")


def zda(talker: str, time_ns: int) -> bytes:
    """ZDA: UTC time and date, local zone 00:00."""
    dt, _ = _utc(time_ns)
    return sentence(f"{talker}ZDA,{format_time(time_ns)},{dt.day:02d},{dt.month:02d},"
                    f"{dt.year:04d},00,00")


def gst(talker: str, time_ns: int, rms_m: Optional[float], sigma_major_m: Optional[float],
        sigma_minor_m: Optional[float], orientation_rad: Optional[float],
        sigma_latitude_m: Optional[float], sigma_longitude_m: Optional[float],
        sigma_altitude_m: Optional[float]) -> bytes:
    """GST: pseudorange error statistics of the fix at ``time_ns`` (sigmas in m, to 1 mm;
    orientation of the semi-major axis in rad from true north; None: empty field)."""
    def m(v: Optional[float], name: str) -> str:
        if v is None:
            return ""
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"NMEA GST {name}: expected a finite sigma >= 0 m, found {v!r}")
        return f"{v:.3f}"
    return sentence(f"{talker}GST,{format_time(time_ns)},{m(rms_m, 'rms')},"
                    f"{m(sigma_major_m, 'sigma_major')},{m(sigma_minor_m, 'sigma_minor')},"
                    f"{_course_deg(orientation_rad, 'GST orientation')},"
                    f"{m(sigma_latitude_m, 'sigma_latitude')},"
                    f"{m(sigma_longitude_m, 'sigma_longitude')},"
                    f"{m(sigma_altitude_m, 'sigma_altitude')}")
