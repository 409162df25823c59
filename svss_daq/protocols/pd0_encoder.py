"""Teledyne RDI PD0 ensembles: encoding, the mirror of :mod:`svss_daq.protocols.pd0`.

Builds a bottom-track ensemble as a Workhorse Navigator sends it with water profiling
off: header, fixed leader (59 bytes), variable leader (65 bytes, Y2K clock) and bottom
track (85 bytes, range MSBs included), then the checksum (sum of the bytes modulo
65536). Layout and scaling after the "Workhorse Commands and Output Data Format"
manual, as decoded by :func:`svss_daq.protocols.pd0.decode_ensemble`.

Inputs in SI units (m, m/s, rad, deg C); resolutions on the wire: time 10 ms, heading,
pitch and roll 0.01 deg, velocity 1 mm/s, range 1 cm, sound speed 1 m/s, depth 0.1 m,
temperature 0.01 deg C. Bottom-track velocity is RDI's: the velocity of the *bottom*
relative to the instrument, in the ensemble's coordinate system (beam 1-4 or X/Y/Z/error
for ship, E/N/U/error for earth); NaN is sent as the bad value -32768. Bottom-track
ranges are RDI's: the *vertical* range per beam, the range along the beam times the
cosine of the beam angle, not corrected for pitch and roll (the manual's bottom-track
range field); a NaN or non-positive range is sent as 0 ("no bottom"). Pressure (daPa on
the wire) may be sent as RDI's missing value 0xFFFFFFFF.

Beam coordinates (``coordinate_system="beam"``, EX bits 3-4 = 00): the four values are
the beams' radial velocities, positive toward the transducer (RDI). The beam pattern
(convex or concave, configuration bit 3), heading alignment (EA) and heading bias (EB)
are written as set; the heading given is sent as it is (an instrument with EB set has
already added it).
The five-beam layout (Sentinel V class, ``vertical_beam``) sets configuration bit 12
and adds the vertical beam's range (ID 0x4100: evaluation and RSSI amplitude, uint32
range in mm, status); a Sentinel V (firmware 47.x or 66.x) sends its 307.2 kHz as the
300 kHz class code.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Optional, Sequence

from svss_daq.protocols.pd0 import (BAD_VELOCITY, ID_BEAM5_RANGE, ID_BOTTOM_TRACK,
                                  ID_FIXED_LEADER, ID_VARIABLE_LEADER, MISSING_U32,
                                  SENTINEL_V_FIRMWARE, ensemble_checksum)

__all__ = ["Pd0Setup", "encode_ensemble", "FIXED_LEADER_BYTES", "VARIABLE_LEADER_BYTES",
           "BOTTOM_TRACK_BYTES"]

FIXED_LEADER_BYTES = 59
VARIABLE_LEADER_BYTES = 65
BOTTOM_TRACK_BYTES = 87  # firmware 51.41 as recorded (85 in older manuals)

_FREQ_CODE = {75e3: 0, 150e3: 1, 300e3: 2, 600e3: 3, 1200e3: 4, 2400e3: 5}
_BEAM_CODE = {15.0: 0, 20.0: 1, 30.0: 2}
_CS_CODE = {"beam": 0, "instrument": 1, "ship": 2, "earth": 3}


@dataclass(frozen=True)
class Pd0Setup:
    """The instrument's configuration, written to every fixed leader."""
    frequency_hz: float = 600e3  #: system frequency, Hz (75 k ... 2.4 M)
    beam_angle_deg: float = 30.0  #: Janus beam angle, deg (15, 20 or 30)
    coordinate_system: str = "ship"  #: beam, instrument, ship or earth (EX)
    serial_number: int = 0
    bt_pings_per_ensemble: int = 1
    bt_max_error_velocity_m_s: float = 1.0
    firmware: tuple[int, int] = (51, 41)
    n_cells: int = 0  #: no water profile (WP0)
    cell_size_m: float = 1.0
    blank_m: float = 0.88
    beam_pattern: str = "convex"  #: convex or concave (configuration bit 3)
    vertical_beam: bool = False  #: five-beam layout (bit 12) with the 0x4100 range
    heading_alignment_deg: float = 0.0  #: EA: beam 3 azimuth from the bow, deg
    #: EB: heading bias (magnetic declination) the instrument adds to its heading, deg
    heading_bias_deg: float = 0.0

    def frequency_code(self) -> int:
        if self.firmware[0] in SENTINEL_V_FIRMWARE and self.frequency_hz == 307.2e3:
            return 2
        return _FREQ_CODE[self.frequency_hz]

    def check(self) -> None:
        """Raise ValueError naming the first field outside what PD0 can express."""
        if self.beam_pattern not in ("convex", "concave"):
            raise ValueError(f"PD0 setup beam_pattern: expected 'convex' or 'concave', "
                             f"found {self.beam_pattern!r}")
        if not -179.99 <= self.heading_alignment_deg <= 180.0:
            raise ValueError(f"PD0 setup heading_alignment_deg: expected -179.99 .. 180, "
                             f"found {self.heading_alignment_deg!r}")
        if not -179.99 <= self.heading_bias_deg <= 180.0:
            raise ValueError(f"PD0 setup heading_bias_deg: expected -179.99 .. 180, "
                             f"found {self.heading_bias_deg!r}")
        if self.frequency_hz not in _FREQ_CODE and not (
                self.firmware[0] in SENTINEL_V_FIRMWARE and self.frequency_hz == 307.2e3):
            raise ValueError(f"PD0 setup frequency_hz: expected one of "
                             f"{sorted(_FREQ_CODE)}, found {self.frequency_hz!r}")
        if self.beam_angle_deg not in _BEAM_CODE:
            raise ValueError(f"PD0 setup beam_angle_deg: expected one of "
                             f"{sorted(_BEAM_CODE)}, found {self.beam_angle_deg!r}")
        if self.coordinate_system not in _CS_CODE:
            raise ValueError(f"PD0 setup coordinate_system: expected one of "
                             f"{tuple(_CS_CODE)}, found {self.coordinate_system!r}")
        if not 0 <= self.serial_number < 2**32:
            raise ValueError(f"PD0 setup serial_number: expected 0..2**32-1, found "
                             f"{self.serial_number!r}")


def _u(name: str, value: float, scale: float, lo: int, hi: int) -> int:
    """``value / scale`` rounded to an integer in [lo, hi], else ValueError naming it."""
    if not math.isfinite(value):
        raise ValueError(f"PD0 {name}: expected a finite number, found {value!r}")
    n = int(round(value / scale))
    if not lo <= n <= hi:
        raise ValueError(f"PD0 {name}: expected {lo * scale:g} .. {hi * scale:g}, found "
                         f"{value!r}")
    return n


def _fixed_leader(s: Pd0Setup) -> bytes:
    cfg = (s.frequency_code() | (0x08 if s.beam_pattern == "convex" else 0)
           | 0x40                                            # transducer attached
           | (_BEAM_CODE[s.beam_angle_deg] << 8) | 0x4000    # down-looking 4-beam Janus
           | (0x1000 if s.vertical_beam else 0))             # fifth (vertical) beam
    ex = (_CS_CODE[s.coordinate_system] << 3) | 0x07          # tilts, 3-beam, bin mapping
    body = struct.pack(
        "<HBBHBBBBHHHBBBBHBBBBhhBBHHBBBBH",
        ID_FIXED_LEADER, s.firmware[0], s.firmware[1], cfg, 0, 0x35, 4, s.n_cells,
        1, _u("cell_size_m", s.cell_size_m, 0.01, 1, 65535),
        _u("blank_m", s.blank_m, 0.01, 0, 65535), 1, 64, 5, 0,
        _u("bt_max_error_velocity_m_s", s.bt_max_error_velocity_m_s, 0.001, 0, 65535),
        0, 0, 20, ex, int(round(s.heading_alignment_deg * 100)),
        int(round(s.heading_bias_deg * 100)), 0x7D, 0x3D, 0, 0, 1, 5,
        50, 0, 0)
    body += bytes(8)                                     # CPU board serial
    body += struct.pack("<HBB", 0, 255, 0)               # bandwidth, power, spare
    body += struct.pack("<IB", s.serial_number, int(s.beam_angle_deg))
    assert len(body) == FIXED_LEADER_BYTES
    return body


def _variable_leader(number: int, time_ns: int, heading_rad: float, pitch_rad: float,
                     roll_rad: float, sound_speed_m_s: float, depth_m: float,
                     salinity_ppt: float, temperature_c: float,
                     pressure_pa: Optional[float]) -> bytes:
    if not 0 <= number < 2**24:
        raise ValueError(f"PD0 ensemble_number: expected 0 .. 2**24-1, found {number!r}")
    hund = int(round(time_ns / 1e7))  # 10 ms clock
    dt = datetime.fromtimestamp(hund // 100, tz=timezone.utc)
    if not 2000 <= dt.year <= 2069:
        raise ValueError(f"PD0 time_ns: expected a time in 2000..2069, found {dt.isoformat()}")
    hs = hund % 100
    hdg = math.degrees(heading_rad) % 360.0
    hdg_n = int(round(hdg * 100)) % 36000
    deg = math.degrees
    body = struct.pack(
        "<HHBBBBBBBBHHHHhhHh", ID_VARIABLE_LEADER, number & 0xFFFF, dt.year % 100, dt.month,
        dt.day, dt.hour, dt.minute, dt.second, hs, number >> 16, 0,
        _u("sound_speed_m_s", sound_speed_m_s, 1.0, 1400, 1600),
        _u("depth_m", depth_m, 0.1, 0, 65535), hdg_n,
        _u("pitch_rad", deg(pitch_rad), 0.01, -2000, 2000),
        _u("roll_rad", deg(roll_rad), 0.01, -2000, 2000),
        _u("salinity_ppt", salinity_ppt, 1.0, 0, 40),
        _u("temperature_c", temperature_c, 0.01, -500, 4000))
    body += bytes(3)                              # min pre-ping wait
    body += bytes(3)                              # heading/pitch/roll std
    body += bytes(8)                              # ADC
    body += bytes(4) + bytes(2)                   # error status, spare
    pres = MISSING_U32 if pressure_pa is None else \
        _u("pressure_pa", pressure_pa, 10.0, 0, MISSING_U32 - 1)
    body += struct.pack("<IIB", pres, 0, 0)       # pressure, variance (daPa), spare
    body += struct.pack("<8B", dt.year // 100, dt.year % 100, dt.month, dt.day, dt.hour,
                        dt.minute, dt.second, hs)
    assert len(body) == VARIABLE_LEADER_BYTES
    return body


def _bottom_track(s: Pd0Setup, velocity_m_s: Sequence[float], range_m: Sequence[float],
                  ) -> bytes:
    if len(velocity_m_s) != 4 or len(range_m) != 4:
        raise ValueError(f"PD0 bottom track: expected 4 velocities and 4 ranges, found "
                         f"{len(velocity_m_s)} and {len(range_m)}")
    vel = [BAD_VELOCITY if not math.isfinite(v) else
           _u(f"bottom-track velocity {k + 1}", v, 0.001, -32767, 32767)
           for k, v in enumerate(velocity_m_s)]
    rng = [0 if not (math.isfinite(r) and r > 0) else
           _u(f"bottom-track range {k + 1}", r, 0.01, 1, 2**24 - 1)
           for k, r in enumerate(range_m)]
    good = [r > 0 for r in rng]
    valid_v = all(v != BAD_VELOCITY for v in vel)
    body = struct.pack("<HHHBBBBH", ID_BOTTOM_TRACK, s.bt_pings_per_ensemble, 0, 220, 30, 0, 5,
                       _u("bt_max_error_velocity_m_s", s.bt_max_error_velocity_m_s, 0.001,
                          0, 65535))
    body += bytes(4)
    body += struct.pack("<4H", *(r & 0xFFFF for r in rng))
    body += struct.pack("<4h", *vel)
    body += bytes(200 if g else 0 for g in good)          # correlation
    body += bytes(80 if g else 0 for g in good)           # evaluation amplitude
    body += bytes(100 if (g and valid_v) else 0 for g in good)  # percent good
    body += struct.pack("<HHH", 20, 0, 0)                 # reference layer (min, near, far)
    body += struct.pack("<4h", *[BAD_VELOCITY] * 4)       # reference-layer velocity
    body += bytes(12)                                     # ref corr, intensity, percent good
    body += struct.pack("<H", 10000)                      # max tracking depth, dm
    body += bytes(150 if g else 30 for g in good)         # RSSI amplitude
    body += bytes([1])                                    # gain
    body += bytes((r >> 16) & 0xFF for r in rng)          # range MSBs
    body += bytes(6)                                      # reserved
    assert len(body) == BOTTOM_TRACK_BYTES
    return body


def _vertical_range(range_m: Optional[float]) -> bytes:
    mm = 0 if range_m is None or not (math.isfinite(range_m) and range_m > 0) else \
        _u("vertical_range_m", range_m, 0.001, 1, 2**32 - 1)
    return struct.pack("<HBBIB", ID_BEAM5_RANGE, 80 if mm else 0, 150 if mm else 30, mm, 0)


def encode_ensemble(setup: Pd0Setup, *, ensemble_number: int, time_ns: int,
                    heading_rad: float, pitch_rad: float, roll_rad: float,
                    bt_velocity_m_s: Sequence[float], bt_range_m: Sequence[float],
                    sound_speed_m_s: float = 1500.0, depth_m: float = 0.0,
                    salinity_ppt: float = 35.0, temperature_c: float = 10.0,
                    pressure_pa: Optional[float] = 0.0,
                    vertical_range_m: Optional[float] = None,
                    extra_blocks: Sequence[bytes] = ()) -> bytes:
    """One PD0 ensemble (header, fixed and variable leader, bottom track, checksum).

    ``time_ns``: ns since the Unix epoch UTC (sent to 10 ms); ``bt_velocity_m_s``: 4
    components, RDI's bottom velocity in ``setup.coordinate_system`` (NaN: bad);
    ``bt_range_m``: RDI's bottom-track range of beams 1-4, m (NaN: no bottom): the
    vertical range, range along the beam x cos(beam angle), not corrected for pitch and
    roll; ``vertical_range_m``: the vertical beam's range along its axis, m (five-beam
    setups; None or NaN: no bottom); ``pressure_pa``: Pa (None: RDI's missing value);
    ``extra_blocks``: further data types (each starting with its uint16 ID), appended
    as sent. Raises ValueError naming a field that PD0 cannot carry."""
    setup.check()
    parts = [_fixed_leader(setup),
             _variable_leader(ensemble_number, int(time_ns), heading_rad, pitch_rad, roll_rad,
                              sound_speed_m_s, depth_m, salinity_ppt, temperature_c,
                              pressure_pa),
             _bottom_track(setup, list(bt_velocity_m_s), list(bt_range_m))]
    if setup.vertical_beam:
        parts.append(_vertical_range(vertical_range_m))
    parts += [bytes(b) for b in extra_blocks]
    header_len = 6 + 2 * len(parts)
    offsets, off = [], header_len
    for p in parts:
        offsets.append(off)
        off += len(p)
    n_bytes = off
    header = struct.pack(f"<2sHBB{len(parts)}H", b"\x7f\x7f", n_bytes, 0, len(parts), *offsets)
    data = header + b"".join(parts)
    return data + struct.pack("<H", ensemble_checksum(data))
