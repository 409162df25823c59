"""NMEA 0183 GPS/heading sentences: typed records and an incremental line parser.

Decoded sentence types (any two-character talker ID: GP, GN, GL, GA, BD, HE, HC,
II, IN, ...): GGA, RMC, VTG, HDT, ZDA, GLL, ROT and GST. Field splitting is done by
``pynmea2``; framing, the checksum policy and unit conversion are done here.

Units: geodetic latitude/longitude in decimal **degrees** (WGS 84 as delivered,
north and east positive; the one exception to the project's radians rule, because
they are coordinates, not angles used in computation); heights in m; speeds in
m/s (1 knot = 1852/3600 m/s); courses, headings and magnetic variation in
radians (true north, clockwise; variation east positive); rate of turn in rad/s.
An empty field decodes to ``None``.

Time: every timed record carries ``time_of_day_ns`` (ns since UTC midnight) and
``time_ns`` (int ns since the Unix epoch, UTC) when a date is known, else
``None``. RMC and ZDA carry their own date. For GGA, GLL (and others with only a
time of day) the stream parser takes the date of the latest RMC/ZDA and sets
``date_from_stream`` (a time of day more than 12 h before/after that reference is
taken to be on the next/previous day). Two-digit RMC years are 2000-2079 for 00-79
and 1980-1999 for 80-99.

Checksum policy (:class:`ChecksumPolicy`):

``"require"``
    a sentence must end in ``*hh`` and the checksum (XOR of the characters
    between ``$`` and ``*``) must match; anything else is rejected.
``"verify_if_present"``
    a sentence without ``*hh`` is accepted; one with it must match.
"""

from __future__ import annotations

import calendar
import enum
import logging
import math
import re
import time
from dataclasses import dataclass
from typing import Optional, Union

import pynmea2

from .framing import ByteStream

__all__ = [
    "ChecksumPolicy",
    "NmeaError",
    "NmeaRecord",
    "GgaFix",
    "RmcFix",
    "VtgVelocity",
    "HdtHeading",
    "ZdaTime",
    "GllPosition",
    "RotRate",
    "GstStatistics",
    "NmeaStreamStats",
    "NmeaStreamParser",
    "parse_sentence",
    "nmea_checksum",
    "KNOT_MPS",
    "SUPPORTED_TYPES",
]

logger = logging.getLogger(__name__)

KNOT_MPS = 1852.0 / 3600.0
_DEG = math.pi / 180.0
_DAY_NS = 86_400 * 1_000_000_000
_HALF_DAY_NS = _DAY_NS // 2


class ChecksumPolicy(str, enum.Enum):
    """What to do with the ``*hh`` checksum (see the module docstring)."""

    REQUIRE = "require"
    VERIFY_IF_PRESENT = "verify_if_present"


class NmeaError(ValueError):
    """A rejected sentence: names the field, what was expected and what was found."""

    def __init__(self, field: str, expected: str, found: str, sentence: str = "") -> None:
        self.field = field
        self.expected = expected
        self.found = found
        self.sentence = sentence
        super().__init__(f"NMEA {field}: expected {expected}, found {found}"
                         + (f" in {sentence[:90]!r}" if sentence else ""))


# -- records -------------------------------------------------------------------


@dataclass(frozen=True)
class NmeaRecord:
    """Base of all records."""

    talker: str  #: e.g. "GP", "GN", "HE"
    sentence_type: str  #: e.g. "GGA"


@dataclass(frozen=True)
class _Timed(NmeaRecord):
    time_of_day_ns: Optional[int]  #: ns since UTC midnight
    time_ns: Optional[int]  #: ns since Unix epoch UTC, None when no date is known
    date_from_stream: bool  #: date taken from an earlier RMC/ZDA, not this sentence

    @property
    def has_date(self) -> bool:
        return self.time_ns is not None


@dataclass(frozen=True)
class GgaFix(_Timed):
    """GGA: position fix. ``fix_quality``: 0 invalid, 1 GPS, 2 DGPS, 3 PPS, 4 RTK
    fixed, 5 RTK float, 6 dead reckoning, 7 manual, 8 simulation."""

    latitude_deg: Optional[float]
    longitude_deg: Optional[float]
    fix_quality: int
    satellites: Optional[int]
    hdop: Optional[float]
    altitude_msl_m: Optional[float]  #: antenna height above mean sea level (geoid)
    geoid_separation_m: Optional[float]  #: ellipsoid height = altitude_msl_m + this
    dgps_age_s: Optional[float]
    dgps_station: Optional[str]

    @property
    def has_fix(self) -> bool:
        return self.fix_quality > 0 and self.latitude_deg is not None


@dataclass(frozen=True)
class RmcFix(_Timed):
    """RMC: recommended minimum data (position, speed and course over ground, date)."""

    valid: bool  #: status 'A'
    latitude_deg: Optional[float]
    longitude_deg: Optional[float]
    speed_mps: Optional[float]
    course_rad: Optional[float]  #: true course over ground
    magnetic_variation_rad: Optional[float]  #: east positive
    mode: Optional[str]  #: FAA mode indicator (A, D, E, N, ...) if sent


@dataclass(frozen=True)
class GllPosition(_Timed):
    """GLL: geographic position."""

    valid: bool
    latitude_deg: Optional[float]
    longitude_deg: Optional[float]
    mode: Optional[str]


@dataclass(frozen=True)
class ZdaTime(_Timed):
    """ZDA: UTC date and time."""

    local_zone_offset_s: Optional[int]  #: local zone hours/minutes as seconds


@dataclass(frozen=True)
class VtgVelocity(NmeaRecord):
    """VTG: course and speed over ground (no time in the sentence)."""

    course_true_rad: Optional[float]
    course_magnetic_rad: Optional[float]
    speed_mps: Optional[float]
    mode: Optional[str]


@dataclass(frozen=True)
class HdtHeading(NmeaRecord):
    """HDT: true heading (from a gyro or GNSS compass)."""

    heading_rad: Optional[float]


@dataclass(frozen=True)
class RotRate(NmeaRecord):
    """ROT: rate of turn, positive turning to starboard."""

    rate_rad_s: Optional[float]
    valid: bool


@dataclass(frozen=True)
class GstStatistics(_Timed):
    """GST: GNSS pseudorange error statistics of the fix at ``time_of_day_ns`` (m):
    RMS of the range inputs, 1-sigma of the error ellipse's semi-major and semi-minor
    axes and of latitude, longitude and altitude; ``orientation_rad`` of the
    semi-major axis from true north."""

    rms_m: Optional[float]
    sigma_major_m: Optional[float]
    sigma_minor_m: Optional[float]
    orientation_rad: Optional[float]
    sigma_latitude_m: Optional[float]
    sigma_longitude_m: Optional[float]
    sigma_altitude_m: Optional[float]


# -- field conversion ------------------------------------------------------------

_NUM_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)$")
_TIME_RE = re.compile(r"^(\d{2})(\d{2})(\d{2})(?:\.(\d{1,9}))?$")
_LATLON_RE = re.compile(r"^(\d{1,3})(\d{2}(?:\.\d*)?)$")
_HEX2_RE = re.compile(r"^[0-9A-Fa-f]{2}$")
_ADDRESS_RE = re.compile(r"^[A-Z0-9]{5}$")


def nmea_checksum(body: str) -> int:
    """XOR of the characters of ``body`` (the text between ``$`` and ``*``)."""
    cs = 0
    for ch in body.encode("ascii", "replace"):
        cs ^= ch
    return cs


class _Fields:
    """Access to a pynmea2 sentence's fields with strict conversions."""

    def __init__(self, msg, sentence: str) -> None:
        self.msg = msg
        self.sentence = sentence
        self.type = msg.sentence_type

    def raw(self, name: str) -> str:
        """The field's text as sent ('' when empty or absent)."""
        i = self.msg.name_to_idx[name]
        data = self.msg.data
        return data[i].strip() if i < len(data) else ""

    def err(self, name: str, expected: str, found: str) -> NmeaError:
        return NmeaError(f"{self.type} {name}", expected, repr(found), self.sentence)

    def float(self, name: str) -> Optional[float]:
        v = self.raw(name)
        if v == "":
            return None
        if not _NUM_RE.match(v):
            raise self.err(name, "a decimal number", v)
        return float(v)

    def int(self, name: str) -> Optional[int]:
        v = self.raw(name)
        if v == "":
            return None
        if not v.isdigit():
            raise self.err(name, "an unsigned integer", v)
        return int(v)

    def char(self, name: str, allowed: str) -> Optional[str]:
        v = self.raw(name)
        if v == "":
            return None
        if len(v) != 1 or v.upper() not in allowed:
            raise self.err(name, f"one of {', '.join(allowed)}", v)
        return v.upper()

    def time_of_day(self, name: str = "timestamp") -> Optional[int]:
        v = self.raw(name)
        if v == "":
            return None
        m = _TIME_RE.match(v)
        if not m:
            raise self.err(name, "hhmmss[.sss]", v)
        hh, mm, ss = int(m.group(1)), int(m.group(2)), int(m.group(3))
        if hh > 23 or mm > 59 or ss > 60:
            raise self.err(name, "a valid time of day", v)
        frac = m.group(4) or ""
        return ((hh * 60 + mm) * 60 + ss) * 1_000_000_000 + int(frac.ljust(9, "0") or 0)

    def angle(self, name: str) -> Optional[float]:
        v = self.float(name)
        return None if v is None else v * _DEG

    def latlon(self, name: str, dir_name: str, is_lat: bool) -> Optional[float]:
        v, d = self.raw(name), self.raw(dir_name).upper()
        if v == "" and d == "":
            return None
        hemis = "NS" if is_lat else "EW"
        if d not in tuple(hemis):
            raise self.err(dir_name, f"{hemis[0]} or {hemis[1]}", d)
        m = _LATLON_RE.match(v)
        if not m:
            raise self.err(name, "[d]ddmm.mmmm", v)
        deg = int(m.group(1))
        minutes = float(m.group(2))
        limit = 90 if is_lat else 180
        if minutes >= 60.0 or deg + minutes / 60.0 > limit:
            raise self.err(name, f"at most {limit} degrees with minutes < 60", v)
        val = deg + minutes / 60.0
        return -val if d in "SW" else val


def _epoch_ns(year: int, month: int, day: int, tod_ns: int) -> int:
    return calendar.timegm((year, month, day, 0, 0, 0)) * 1_000_000_000 + tod_ns


def _check_date(f: _Fields, name: str, text: str, year: int, month: int, day: int) -> None:
    if not (1 <= month <= 12 and 1 <= day <= calendar.monthrange(year, month)[1]):
        raise f.err(name, "a valid calendar date", text)


def _infer(tod: Optional[int], ref: Optional[tuple]) -> Optional[int]:
    """Epoch ns for a time of day, given (epoch_ns, time_of_day_ns) of a dated sentence."""
    if tod is None or ref is None:
        return None
    ref_ns, ref_tod = ref
    t = ref_ns - ref_tod + tod
    if t - ref_ns > _HALF_DAY_NS:
        t -= _DAY_NS
    elif ref_ns - t > _HALF_DAY_NS:
        t += _DAY_NS
    return t


def _talker(f: _Fields) -> tuple:
    return f.msg.talker, f.type


def _gga(f: _Fields, ref) -> GgaFix:
    tod = f.time_of_day()
    t_ns = _infer(tod, ref)
    qual = f.int("gps_qual")
    return GgaFix(
        *_talker(f), time_of_day_ns=tod, time_ns=t_ns, date_from_stream=t_ns is not None,
        latitude_deg=f.latlon("lat", "lat_dir", True),
        longitude_deg=f.latlon("lon", "lon_dir", False),
        fix_quality=0 if qual is None else qual,
        satellites=f.int("num_sats"),
        hdop=f.float("horizontal_dil"),
        altitude_msl_m=f.float("altitude"),
        geoid_separation_m=f.float("geo_sep"),
        dgps_age_s=f.float("age_gps_data"),
        dgps_station=f.raw("ref_station_id") or None,
    )


def _rmc(f: _Fields, ref) -> RmcFix:
    tod = f.time_of_day()
    date = f.raw("datestamp")
    t_ns, from_stream = None, False
    if date:
        if not (len(date) == 6 and date.isdigit()):
            raise f.err("datestamp", "ddmmyy", date)
        d, m, yy = int(date[:2]), int(date[2:4]), int(date[4:])
        y = 2000 + yy if yy < 80 else 1900 + yy
        _check_date(f, "datestamp", date, y, m, d)
        if tod is not None:
            t_ns = _epoch_ns(y, m, d, tod)
    else:
        t_ns = _infer(tod, ref)
        from_stream = t_ns is not None
    var = f.angle("mag_variation")
    mode = f.raw("mode_indicator") or None
    if var is None and mode is None and f.raw("mag_var_dir"):
        # Some receivers (e.g. Saab R4) send the mode letter right after an empty
        # variation, leaving out the variation direction.
        mode = f.raw("mag_var_dir")
    elif var is not None and f.char("mag_var_dir", "EW") == "W":
        var = -var
    speed = f.float("spd_over_grnd")
    return RmcFix(
        *_talker(f), time_of_day_ns=tod, time_ns=t_ns, date_from_stream=from_stream,
        valid=f.raw("status").upper() == "A",
        latitude_deg=f.latlon("lat", "lat_dir", True),
        longitude_deg=f.latlon("lon", "lon_dir", False),
        speed_mps=None if speed is None else speed * KNOT_MPS,
        course_rad=f.angle("true_course"),
        magnetic_variation_rad=var,
        mode=mode,
    )


def _gll(f: _Fields, ref) -> GllPosition:
    tod = f.time_of_day()
    t_ns = _infer(tod, ref)
    return GllPosition(
        *_talker(f), time_of_day_ns=tod, time_ns=t_ns, date_from_stream=t_ns is not None,
        valid=f.raw("status").upper() == "A",
        latitude_deg=f.latlon("lat", "lat_dir", True),
        longitude_deg=f.latlon("lon", "lon_dir", False),
        mode=f.raw("faa_mode") or None,
    )


def _zda(f: _Fields, ref) -> ZdaTime:
    tod = f.time_of_day()
    day, month, year = f.int("day"), f.int("month"), f.int("year")
    t_ns = None
    if day is not None and month is not None and year is not None:
        text = f"{day:02d}/{month:02d}/{year}"
        if year < 1980 or year > 2200:
            raise f.err("year", "a four-digit year", str(year))
        _check_date(f, "date", text, year, month, day)
        if tod is not None:
            t_ns = _epoch_ns(year, month, day, tod)
    zh, zm = f.raw("local_zone") or "0", f.raw("local_zone_minutes") or "0"
    if not re.match(r"^[+-]?\d{1,2}$", zh) or not re.match(r"^\d{1,2}$", zm):
        raise f.err("local_zone", "zone hours -13..13 and minutes 0..59", f"{zh},{zm}")
    sign = -1 if zh.startswith("-") else 1
    zone = sign * (abs(int(zh)) * 3600 + int(zm) * 60)
    return ZdaTime(*_talker(f), time_of_day_ns=tod, time_ns=t_ns, date_from_stream=False,
                   local_zone_offset_s=zone)


def _vtg(f: _Fields, ref) -> VtgVelocity:
    # Old receivers omit the unit letters: course true, course magnetic, knots, km/h.
    if f.raw("true_track_sym") not in ("T", ""):
        data = list(f.msg.data) + [""] * 4
        legacy = pynmea2.VTG(f.msg.talker, "VTG", [data[0], "T", data[1], "M", data[2], "N", data[3], "K"])
        f = _Fields(legacy, f.sentence)
    kts, kmh = f.float("spd_over_grnd_kts"), f.float("spd_over_grnd_kmph")
    speed = kts * KNOT_MPS if kts is not None else (None if kmh is None else kmh / 3.6)
    return VtgVelocity(
        *_talker(f),
        course_true_rad=f.angle("true_track"),
        course_magnetic_rad=f.angle("mag_track"),
        speed_mps=speed,
        mode=f.raw("faa_mode") or None,
    )


def _hdt(f: _Fields, ref) -> HdtHeading:
    return HdtHeading(*_talker(f), heading_rad=f.angle("heading"))


def _rot(f: _Fields, ref) -> RotRate:
    rate = f.float("rate_of_turn")  # degrees per minute
    return RotRate(*_talker(f), rate_rad_s=None if rate is None else rate * _DEG / 60.0,
                   valid=f.raw("status").upper() == "A")


def _gst(f: _Fields, ref) -> GstStatistics:
    tod = f.time_of_day()
    t_ns = _infer(tod, ref)

    def sigma(name: str) -> Optional[float]:
        v = f.float(name)
        if v is not None and v < 0:
            raise f.err(name, "a standard deviation >= 0 m", str(v))
        return v

    return GstStatistics(
        *_talker(f), time_of_day_ns=tod, time_ns=t_ns, date_from_stream=t_ns is not None,
        rms_m=sigma("rms"), sigma_major_m=sigma("std_dev_major"),
        sigma_minor_m=sigma("std_dev_minor"), orientation_rad=f.angle("orientation"),
        sigma_latitude_m=sigma("std_dev_latitude"),
        sigma_longitude_m=sigma("std_dev_longitude"),
        sigma_altitude_m=sigma("std_dev_altitude"),
    )


_DECODERS: dict = {"GGA": _gga, "RMC": _rmc, "GLL": _gll, "ZDA": _zda, "VTG": _vtg, "HDT": _hdt,
                   "ROT": _rot, "GST": _gst}

#: Sentence types this module decodes.
SUPPORTED_TYPES = tuple(sorted(_DECODERS))


class _Ignored(Exception):
    """Internal: a well-formed sentence of a type this module does not decode."""


def _decode(sentence: str, policy: ChecksumPolicy, ref: Optional[tuple]) -> NmeaRecord:
    if not sentence.startswith("$"):
        if sentence.startswith("!"):
            raise _Ignored("encapsulated (AIS) sentence")
        raise NmeaError("start", "'$'", repr(sentence[:1]), sentence)
    star = sentence.find("*")
    if star >= 0:
        body, cs = sentence[1:star], sentence[star + 1:]
        if not _HEX2_RE.match(cs):
            raise NmeaError("checksum", "two hex digits after '*'", repr(cs), sentence)
        want = nmea_checksum(body)
        if int(cs, 16) != want:
            raise NmeaError("checksum", f"{want:02X} (XOR of the characters between '$' and '*')",
                            cs.upper(), sentence)
    else:
        if policy is ChecksumPolicy.REQUIRE:
            raise NmeaError("checksum", "'*hh' at the end (policy 'require')", "none", sentence)
        body = sentence[1:]
    address = body.split(",", 1)[0]
    if address.startswith("P"):
        raise _Ignored("proprietary sentence")
    if not _ADDRESS_RE.match(address):
        raise NmeaError("address", "talker ID and sentence type, e.g. 'GPGGA'", repr(address), sentence)
    decoder = _DECODERS.get(address[2:])
    if decoder is None:
        raise _Ignored(f"unsupported sentence type {address[2:]}")
    try:
        msg = pynmea2.parse(sentence, check=False)
    except pynmea2.ParseError as e:
        raise NmeaError("sentence", "NMEA 0183 syntax", str(e.args[0][0] if e.args else e), sentence) from None
    return decoder(_Fields(msg, sentence), ref)


def _coerce_policy(policy) -> ChecksumPolicy:
    try:
        return ChecksumPolicy(policy)
    except ValueError:
        raise ValueError(f"checksum policy must be one of {[p.value for p in ChecksumPolicy]}, "
                         f"not {policy!r}") from None


def parse_sentence(
    sentence: Union[str, bytes],
    checksum_policy: Union[ChecksumPolicy, str] = ChecksumPolicy.REQUIRE,
    *,
    reference: Optional[tuple] = None,
) -> Optional[NmeaRecord]:
    """Decode one sentence (surrounding whitespace allowed).

    Returns a record, or ``None`` for a well-formed sentence of a type not decoded
    here (AIS ``!``, proprietary ``$P...``, other types). Raises :class:`NmeaError`
    for a rejected one. ``reference`` = (time_ns, time_of_day_ns) of a dated
    sentence, used to date sentences that carry only a time of day.
    """
    policy = _coerce_policy(checksum_policy)
    if isinstance(sentence, (bytes, bytearray)):
        try:
            sentence = bytes(sentence).decode("ascii")
        except UnicodeDecodeError:
            raise NmeaError("characters", "ASCII", "non-ASCII bytes") from None
    s = sentence.strip()
    if any(not (" " <= c <= "~") for c in s):
        raise NmeaError("characters", "printable ASCII", "control or non-ASCII characters", s)
    try:
        return _decode(s, policy, reference)
    except _Ignored:
        return None


# -- stream parser -------------------------------------------------------------------


@dataclass
class NmeaStreamStats:
    """Counters of a :class:`NmeaStreamParser`."""

    bytes_fed: int = 0
    lines: int = 0  #: non-empty lines examined (over-long ones are only counted in rejected_overlong)
    records: int = 0
    rejected_checksum: int = 0
    rejected_malformed: int = 0
    rejected_non_ascii: int = 0
    rejected_overlong: int = 0
    ignored_ais: int = 0
    ignored_unsupported: int = 0
    bytes_discarded: int = 0  #: junk before a '$' and dropped over-long data
    internal_errors: int = 0  #: decoder bugs caught to keep the stream alive (should stay 0)

    @property
    def rejected(self) -> int:
        return self.rejected_checksum + self.rejected_malformed + self.rejected_non_ascii + self.rejected_overlong


_PRINTABLE_RE = re.compile(rb"^[\x20-\x7e]*$")


class NmeaStreamParser:
    """Incremental NMEA 0183 parser: ``for rec in parser.feed(chunk): ...``.

    Lines end at ``\\n`` (a trailing ``\\r`` is dropped). A sentence starts at the
    last ``$`` or ``!`` of its line, so junk glued in front of it (a lost line end,
    line noise) is dropped and the sentence kept. Lines with non-printable or
    non-ASCII characters, bad checksums (per ``checksum_policy``), malformed fields
    or longer than ``max_line_length`` are rejected and counted; AIS (``!``) and
    unsupported or proprietary sentences are ignored with a debug log. Incomplete
    data longer than ``max_line_length`` is cut back to its last ``$``/``!`` (or
    dropped), so memory stays bounded. It never raises on any input.
    """

    def __init__(
        self,
        checksum_policy: Union[ChecksumPolicy, str] = ChecksumPolicy.REQUIRE,
        *,
        max_line_length: int = 256,
        infer_dates: bool = True,
        warn_interval_s: float = 10.0,
    ) -> None:
        self.checksum_policy = _coerce_policy(checksum_policy)
        if max_line_length < 11:
            raise ValueError("max_line_length must be at least 11 characters")
        self.max_line_length = int(max_line_length)
        self.infer_dates = infer_dates
        self.warn_interval_s = warn_interval_s
        self.stats = NmeaStreamStats()
        self._stream = ByteStream("NMEA", logger, self.stats)  # the line not yet ended
        self._ref: Optional[tuple] = None  # (epoch ns, time of day ns) of the last dated sentence
        self._last_warn = -math.inf
        self._unwarned = 0
        self._cut = False  # the buffered line already lost its start as over-long

    @property
    def buffered(self) -> int:
        return len(self._stream)

    def feed(self, data) -> list:
        """Add bytes; return the records of the sentences they complete, in order."""
        if self._stream.feed(data) is None:
            return []
        out: list = []
        for line in self._stream.lines():
            self._line(line, out, self._cut)
            self._cut = False
        buf = self._stream.buf
        if len(buf) > self.max_line_length:
            p = max(buf.rfind(b"$"), buf.rfind(b"!"))
            keep = len(buf) - p if p >= 0 and len(buf) - p <= self.max_line_length else 0
            dropped = len(buf) - keep
            self.stats.bytes_discarded += dropped
            if not self._cut:  # count each over-long line once
                self.stats.rejected_overlong += 1
                self._reject("over-long line", f"dropped {dropped} bytes without a line end")
            self._cut = True
            self._stream.consume(dropped)
        return out

    def flush(self) -> list:
        """End of stream: parse a last line that lacks its line end."""
        out: list = []
        if self._stream.buf:
            line = bytes(self._stream.buf)
            self._stream.clear()
            self._line(line, out, self._cut)
        self._cut = False
        return out

    # -- internals -------------------------------------------------------------

    def _reject(self, reason: str, detail: str) -> None:
        logger.debug("NMEA stream: rejected (%s): %s", reason, detail)
        self._unwarned += 1
        now = time.monotonic()
        if now - self._last_warn >= self.warn_interval_s:
            logger.warning("NMEA stream: %d line(s) rejected since last report, latest: %s: %s",
                           self._unwarned, reason, detail)
            self._last_warn = now
            self._unwarned = 0

    def _line(self, raw: bytes, out: list, continued: bool = False) -> None:
        raw = raw.strip()
        if not raw:
            return
        st = self.stats
        p = max(raw.rfind(b"$"), raw.rfind(b"!"))
        if continued and p < 0:  # the rest of an over-long line, already counted
            st.bytes_discarded += len(raw)
            return
        st.lines += 1
        if p < 0:
            st.rejected_malformed += 1
            st.bytes_discarded += len(raw)
            self._reject("no sentence start", repr(raw[:40]))
            return
        if p > 0:
            st.bytes_discarded += p
            logger.debug("NMEA stream: dropped %d junk bytes before a sentence", p)
            raw = raw[p:]
        if len(raw) > self.max_line_length:
            st.rejected_overlong += 1
            st.bytes_discarded += len(raw)
            self._reject("over-long line", f"{len(raw)} characters")
            return
        if not _PRINTABLE_RE.match(raw):
            st.rejected_non_ascii += 1
            self._reject("non-printable or non-ASCII characters", repr(raw[:40]))
            return
        sentence = raw.decode("ascii")
        try:
            rec = _decode(sentence, self.checksum_policy, self._ref if self.infer_dates else None)
        except _Ignored as why:
            if sentence.startswith("!"):
                st.ignored_ais += 1
            else:
                st.ignored_unsupported += 1
            logger.debug("NMEA stream: ignored %s: %s", why, sentence[:40])
            return
        except NmeaError as e:
            if e.field == "checksum":
                st.rejected_checksum += 1
            else:
                st.rejected_malformed += 1
            self._reject(e.field, str(e))
            return
        except Exception:  # a decoder bug must not stop acquisition
            st.internal_errors += 1
            logger.exception("NMEA stream: internal error decoding %r", sentence)
            return
        if isinstance(rec, (RmcFix, ZdaTime)) and rec.time_ns is not None and not rec.date_from_stream:
            self._ref = (rec.time_ns, rec.time_of_day_ns)
        st.records += 1
        out.append(rec)
