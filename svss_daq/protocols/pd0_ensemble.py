"""A Teledyne RDI PD0 ensemble: its records (:class:`Pd0Ensemble` and its leaders,
bottom track and vertical beam) and their decoding from bytes (:func:`decode_ensemble`,
:class:`Pd0DecodeError` on anything malformed). The layout, units and conventions are
described in :mod:`svss_daq.protocols.pd0`, the protocol's public face; the incremental
stream parser is in :mod:`svss_daq.protocols.pd0_stream`.
"""

from __future__ import annotations

import calendar
import logging
import math
import struct
from dataclasses import dataclass
from typing import Optional

import numpy as np

__all__ = [
    "HEADER_ID",
    "BAD_VELOCITY",
    "MISSING_U32",
    "signed_pressure_dapa",
    "MAX_ENSEMBLE_BYTES",
    "ID_FIXED_LEADER",
    "ID_VARIABLE_LEADER",
    "ID_VELOCITY",
    "ID_CORRELATION",
    "ID_ECHO_INTENSITY",
    "ID_PERCENT_GOOD",
    "ID_BOTTOM_TRACK",
    "ID_BEAM5_VELOCITY",
    "ID_BEAM5_RANGE",
    "VENDOR_BLOCK_ID",
    "KNOWN_UNDECODED_IDS",
    "SENTINEL_V_FIRMWARE",
    "Pd0DecodeError",
    "FixedLeader",
    "VariableLeader",
    "BottomTrack",
    "VerticalBeam",
    "Pd0Ensemble",
    "ensemble_checksum",
    "decode_ensemble",
    "DECODED_IDS",
    "NeedMore",
    "parse_header",
]

logger = logging.getLogger("svss_daq.protocols.pd0")   # the protocol's one logger

HEADER_ID = b"\x7f\x7f"
#: Velocity value RDI uses for "no data".
BAD_VELOCITY = -32768
#: A uint32 field of all ones: RDI's missing value (variable leader pressure and its
#: variance; 4.29e9 daPa would be 4.3e6 dbar).
MISSING_U32 = 0xFFFFFFFF


def signed_pressure_dapa(raw: int) -> int:
    """The variable leader's pressure (decapascals re one atmosphere) from its uint32
    field. RDI's output-format documentation gives the field as unsigned (0 to
    4,294,967,295 daPa), but a Workhorse at the surface sends readings just under
    2^32: read as unsigned they are 4.29e10 Pa, more than any ocean by four orders of
    magnitude (RDI_withBT.000: 30 of 1721 ensembles, between neighbours of 0.1-0.3 dbar),
    and as two's complement -7 to -153 daPa, the sensor's offset from one atmosphere at
    the surface. So a field from 2^31 up (over 21,000 km of water) is that negative
    reading; 0xFFFFFFFF stays RDI's missing value (the caller's test, before this)."""
    return raw - (1 << 32) if raw >= (1 << 31) else raw
#: Largest possible ensemble on the wire: 16-bit byte count plus the checksum.
MAX_ENSEMBLE_BYTES = 0xFFFF + 2

ID_FIXED_LEADER = 0x0000
ID_VARIABLE_LEADER = 0x0080
ID_VELOCITY = 0x0100
ID_CORRELATION = 0x0200
ID_ECHO_INTENSITY = 0x0300
ID_PERCENT_GOOD = 0x0400
ID_BOTTOM_TRACK = 0x0600
ID_BEAM5_VELOCITY = 0x0A00
ID_BEAM5_RANGE = 0x4100
#: First two bytes of a Sentinel V vendor block sent between ensembles.
VENDOR_BLOCK_ID = b"\x7f\x79"

#: Data-type IDs of RDI instruments that are known (listed by dolfyn's reader) but not
#: decoded here: skipped without a warning and counted by the stream parser.
KNOWN_UNDECODED_IDS = {
    0x0001: "2nd profile fixed leader", 0x0010: "surface layer fixed leader",
    0x0081: "2nd profile variable leader", 0x0101: "2nd profile velocity",
    0x0103: "waves first leader", 0x0110: "surface layer velocity",
    0x0201: "2nd profile correlation", 0x0203: "waves data", 0x020C: "ambient sound profile",
    0x0210: "surface layer correlation", 0x0301: "2nd profile amplitude",
    0x0302: "beam 5 sum of squared velocities", 0x0303: "waves last leader",
    0x0310: "surface layer amplitude", 0x0401: "2nd profile percent good",
    0x0403: "waves HPR data", 0x0410: "surface layer percent good", 0x0500: "profile status",
    0x0501: "2nd profile status", 0x0510: "surface layer status", 0x0701: "number of pings",
    0x0702: "sum of squared velocities", 0x0703: "sum of velocities",
    0x0B00: "beam 5 correlation", 0x0C00: "beam 5 amplitude", 0x0D00: "beam 5 percent good",
    0x0BB8: "Ocean Surveyor fixed attitude", 0x0F01: "beam 5 leader", 0x2000: "VmDas navigation",
    0x2013: "navigation parameters", 0x2022: "WinRiver II NMEA", 0x2100: "WinRiver DBT",
    0x2101: "WinRiver GGA", 0x2102: "WinRiver VTG", 0x2103: "WinRiver GSA",
    0x2104: "WinRiver HDT", 0x3000: "fixed attitude", 0x30D0: "variable attitude",
    0x30D8: "variable attitude", 0x3200: "transformation matrix",
    0x4400: "firmware status", 0x4401: "auto mode setup",
    0x5803: "high-resolution bottom-track velocity", 0x5804: "bottom-track range",
    0x5901: "ISM (IMU) data", 0x5902: "ping attitude", 0x7001: "ADC data",
}

_HEADER_FIXED_BYTES = 6
_MIN_FIXED_LEADER = 42  # through the transmit lag distance (bytes 40-41)
_MIN_VARIABLE_LEADER = 28  # through the temperature (bytes 26-27)
_MIN_BOTTOM_TRACK = 44  # through the bottom-track percent good (bytes 40-43)
_BT_RANGE_MSB_END = 81  # bytes 77-80: range MSBs, newer firmware only

_DEG = math.pi / 180.0
_SYSTEM_FREQUENCY_HZ = {0: 75e3, 1: 150e3, 2: 300e3, 3: 600e3, 4: 1200e3, 5: 2400e3}
#: CPU firmware major versions of the Sentinel V class (dolfyn's model table).
SENTINEL_V_FIRMWARE = (47, 66)
#: Sentinel V true transducer frequency by configuration code, where it differs.
_SENTINEL_V_FREQUENCY_HZ = {2: 307.2e3}
_CFG_BEAM5 = 0x1000  # system configuration bit 12: a fifth (vertical) beam
_BEAM_ANGLE_DEG = {0: 15.0, 1: 20.0, 2: 30.0}
_COORDINATE_SYSTEMS = ("beam", "instrument", "ship", "earth")


class Pd0DecodeError(ValueError):
    """A malformed PD0 ensemble.

    Attributes: ``offset`` (byte offset of the offending field, in the caller's
    buffer or stream), ``field``, ``expected``, ``found``.
    """

    def __init__(self, offset: int, field: str, expected: str, found: str) -> None:
        self.offset = offset
        self.field = field
        self.expected = expected
        self.found = found
        super().__init__(
            f"PD0 decode error at byte offset {offset}: {field}: "
            f"expected {expected}, found {found}"
        )


@dataclass(frozen=True)
class FixedLeader:
    """Instrument configuration (fixed leader, ID 0x0000)."""

    firmware_version: int
    firmware_revision: int
    system_config: int  #: raw configuration word
    system_frequency_hz: Optional[float]  #: None if the code is unknown
    beam_pattern: str  #: "convex" or "concave"
    orientation: str  #: "up" or "down" (transducer facing)
    simulated: bool  #: real/sim flag set
    lag_length: int
    n_beams: int
    n_cells: int
    pings_per_ensemble: int
    cell_size_m: float
    blank_m: float
    profiling_mode: int
    low_corr_threshold: int  #: counts
    n_code_reps: int
    percent_good_min: int  #: %
    error_velocity_max_mps: float
    time_between_ping_groups_s: float
    coord_transform: int  #: raw EX byte
    coordinate_system: str  #: "beam", "instrument", "ship" or "earth"
    heading_alignment_rad: float
    heading_bias_rad: float  #: magnetic variation applied by the instrument (EB)
    sensor_source: int  #: raw EZ byte
    sensors_available: int
    bin1_distance_m: float  #: vertical distance to the centre of cell 1
    transmit_pulse_length_m: float
    ref_layer_start_cell: int
    ref_layer_end_cell: int
    false_target_threshold: int
    transmit_lag_m: float
    cpu_board_serial: Optional[str]  #: hex string, None on older firmware
    bandwidth: Optional[int]
    power_level: Optional[int]
    serial_number: Optional[int]
    beam_angle_rad: Optional[float]
    frequency_class_hz: Optional[float] = None  #: Workhorse table value of bits 0-2
    vertical_beam: bool = False  #: a fifth, vertical beam (Sentinel V class)
    sentinel_v: bool = False  #: firmware of the Sentinel V class

    @property
    def janus_beams(self) -> int:
        """Slanted (Janus) beams: ``n_beams`` less the vertical beam."""
        return self.n_beams - 1 if self.vertical_beam else self.n_beams

    @property
    def tilts_used(self) -> bool:
        """EX bit 2: the instrument applied its tilts in the transformation."""
        return bool(self.coord_transform & 0x04)

    @property
    def three_beam_allowed(self) -> bool:
        """EX bit 1: 3-beam solutions allowed when one beam is bad."""
        return bool(self.coord_transform & 0x02)

    @property
    def cell_distances_m(self) -> np.ndarray:
        """Vertical distance from the transducer to each cell centre (m)."""
        return self.bin1_distance_m + self.cell_size_m * np.arange(self.n_cells)


@dataclass(frozen=True)
class VariableLeader:
    """Per-ensemble state (variable leader, ID 0x0080)."""

    ensemble_number: int  #: including the MSB byte
    time_ns: Optional[int]  #: RTC, ns since Unix epoch UTC; None if the RTC is invalid
    rtc: tuple  #: raw (year, month, day, hour, minute, second, hundredths) as used
    bit_result: int
    sound_speed_mps: float
    depth_m: float  #: depth of transducer (ED)
    heading_rad: float
    pitch_rad: float  #: as reported (tilt 1)
    roll_rad: float  #: as reported (tilt 2)
    salinity_ppt: float
    temperature_degc: float
    min_preping_wait_s: float
    heading_std_rad: Optional[float]
    pitch_std_rad: Optional[float]
    roll_std_rad: Optional[float]
    adc: Optional[tuple]  #: raw ADC channels 0-7
    error_status: Optional[int]
    pressure_pa: Optional[float]  #: None: not sent, or RDI's missing value 0xFFFFFFFF
    pressure_variance_pa: Optional[float]  #: None: not sent, or 0xFFFFFFFF


@dataclass(frozen=True, eq=False)
class BottomTrack:
    """Bottom-track data (ID 0x0600); per-beam arrays have 4 entries."""

    pings_per_ensemble: int
    delay_before_reacquire: int
    corr_mag_min: int
    eval_amp_min: int
    percent_good_min: int
    mode: int
    error_velocity_max_mps: float
    #: RDI's range per beam (m), NaN where no bottom was found: the *vertical* range,
    #: the range along the beam times the cosine of the beam angle, not corrected for
    #: pitch and roll ("Workhorse Commands and Output Data Format", bottom-track range)
    range_m: np.ndarray
    velocity_mps: np.ndarray  #: in the ensemble's coordinate system, NaN where bad
    correlation: np.ndarray  #: uint8 counts
    amplitude: np.ndarray  #: uint8 evaluation amplitude counts
    percent_good: np.ndarray  #: uint8 %
    range_raw_cm: np.ndarray  #: uint32 raw range (LSB + 65536 * MSB), cm
    velocity_raw: np.ndarray  #: int16 raw velocity, mm/s (-32768 = bad)


@dataclass(frozen=True)
class VerticalBeam:
    """Vertical (fifth) beam range, ID 0x4100 (Sentinel V class)."""

    range_m: float  #: range to the bottom (or surface) along the vertical beam, NaN if 0
    eval_amplitude: int  #: counts
    rssi_amplitude: int  #: counts
    status: int  #: raw status bits


@dataclass(frozen=True, eq=False)
class Pd0Ensemble:
    """One decoded PD0 ensemble. Profile arrays are shaped (n_cells, n_beams)."""

    fixed: FixedLeader
    variable: VariableLeader
    velocity_mps: Optional[np.ndarray]  #: float64 m/s, NaN where bad
    correlation: Optional[np.ndarray]  #: uint8 counts
    echo_intensity: Optional[np.ndarray]  #: uint8 counts (about 0.45 dB/count)
    percent_good: Optional[np.ndarray]  #: uint8 %
    bottom_track: Optional[BottomTrack]
    data_type_ids: tuple  #: every data-type ID present, in order
    n_bytes: int  #: ensemble length on the wire, checksum included
    vertical_beam: Optional[VerticalBeam] = None  #: ID 0x4100, five-beam instruments
    beam5_velocity_mps: Optional[np.ndarray] = None  #: (n_cells,) ID 0x0A00, NaN where bad

    @property
    def time_ns(self) -> Optional[int]:
        """Ensemble time, ns since Unix epoch UTC (None if the RTC is invalid)."""
        return self.variable.time_ns

    @property
    def ensemble_number(self) -> int:
        return self.variable.ensemble_number

    @property
    def heading_rad(self) -> float:
        return self.variable.heading_rad

    @property
    def pitch_rad(self) -> float:
        return self.variable.pitch_rad

    @property
    def roll_rad(self) -> float:
        return self.variable.roll_rad

    @property
    def sound_speed_mps(self) -> float:
        return self.variable.sound_speed_mps

    @property
    def depth_m(self) -> float:
        return self.variable.depth_m


def ensemble_checksum(data: bytes, start: int = 0, n_bytes: Optional[int] = None) -> int:
    """Sum of ``data[start:start+n_bytes]`` modulo 65536 (the PD0 checksum)."""
    end = len(data) if n_bytes is None else start + n_bytes
    return int(np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start).sum()) & 0xFFFF


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class NeedMore(Exception):
    """The header cannot be judged until ``buf`` extends to ``need_end`` (the stream
    parser waits for those bytes)."""

    def __init__(self, need_end: int) -> None:
        super().__init__(need_end)
        self.need_end = need_end


def parse_header(buf, start: int, end: int, base: int) -> tuple:
    """Validate the header at ``buf[start:end]``; return (n_bytes, offsets).

    Raises :class:`Pd0DecodeError` for an impossible header and :class:`NeedMore`
    when ``end`` cuts it short. ``base`` is added to reported offsets.
    """
    avail = end - start
    if avail < 2:
        raise NeedMore(start + 2)
    if buf[start] != 0x7F or buf[start + 1] != 0x7F:
        raise Pd0DecodeError(
            base + start, "header ID", "0x7F7F", f"0x{buf[start]:02X}{buf[start + 1]:02X}"
        )
    if avail < _HEADER_FIXED_BYTES:
        raise NeedMore(start + _HEADER_FIXED_BYTES)
    n_bytes = buf[start + 2] | (buf[start + 3] << 8)
    n_types = buf[start + 5]
    if n_types < 2:
        raise Pd0DecodeError(
            base + start + 5, "number of data types", ">= 2 (fixed and variable leader)", str(n_types)
        )
    header_len = _HEADER_FIXED_BYTES + 2 * n_types
    if n_bytes < header_len + 2 * n_types:
        raise Pd0DecodeError(
            base + start + 2,
            "ensemble byte count",
            f">= {header_len + 2 * n_types} for {n_types} data types",
            str(n_bytes),
        )
    if avail < header_len:
        raise NeedMore(start + header_len)
    offsets = struct.unpack_from(f"<{n_types}H", buf, start + _HEADER_FIXED_BYTES)
    if offsets[0] != header_len:
        raise Pd0DecodeError(
            base + start + _HEADER_FIXED_BYTES,
            "offset of data type 1",
            f"{header_len} (end of header)",
            str(offsets[0]),
        )
    for k in range(1, n_types):
        if not offsets[k - 1] + 2 <= offsets[k] <= n_bytes - 2:
            raise Pd0DecodeError(
                base + start + _HEADER_FIXED_BYTES + 2 * k,
                f"offset of data type {k + 1}",
                f"in [{offsets[k - 1] + 2}, {n_bytes - 2}]",
                str(offsets[k]),
            )
    # The first two data types are always the fixed and the variable leader.
    for k, want in ((0, ID_FIXED_LEADER), (1, ID_VARIABLE_LEADER)):
        p = start + offsets[k]
        if p + 2 > end:
            raise NeedMore(p + 2)
        got = buf[p] | (buf[p + 1] << 8)
        if got != want:
            raise Pd0DecodeError(base + p, f"ID of data type {k + 1}", f"0x{want:04X}", f"0x{got:04X}")
    return n_bytes, offsets


def _rtc_ns(year: int, month: int, day: int, hour: int, minute: int, second: int, hundredths: int) -> Optional[int]:
    if not (1 <= month <= 12 and 0 <= hour < 24 and 0 <= minute < 60 and 0 <= second < 60 and 0 <= hundredths < 100):
        return None
    if not 1 <= day <= calendar.monthrange(year, month)[1]:
        return None
    return (calendar.timegm((year, month, day, hour, minute, second)) * 1_000_000_000
            + hundredths * 10_000_000)


def _decode_fixed(buf, p: int, length: int, base: int) -> FixedLeader:
    if length < _MIN_FIXED_LEADER:
        raise Pd0DecodeError(base + p, "fixed leader length", f">= {_MIN_FIXED_LEADER} bytes", f"{length} bytes")
    (fw_ver, fw_rev, cfg, sim, lag, n_beams, n_cells, pings, cell_cm, blank_cm, prof_mode,
     corr_thr, code_reps, pg_min, err_vel_mm, tpp_min, tpp_sec, tpp_hun, ex, ea, eb, ez,
     sensors_avail, bin1_cm, pulse_cm, ref_start, ref_end, wa, _spare, lag_cm) = struct.unpack_from(
        "<BBHBBBBHHHBBBBHBBBBhhBBHHBBBBH", buf, p + 2
    )
    if n_beams < 1:
        raise Pd0DecodeError(base + p + 8, "fixed leader number of beams", ">= 1", str(n_beams))
    freq_code = cfg & 0x7
    cpu_serial = bandwidth = power = serial = None
    beam_angle_deg: Optional[float] = _BEAM_ANGLE_DEG.get((cfg >> 8) & 0x3)
    if length >= 50:
        cpu_serial = bytes(buf[p + 42:p + 50]).hex()
    if length >= 53:
        bandwidth, power = struct.unpack_from("<HB", buf, p + 50)
    if length >= 58:
        (serial,) = struct.unpack_from("<I", buf, p + 54)
    if length >= 59 and buf[p + 58] != 0:
        beam_angle_deg = float(buf[p + 58])
    sentinel_v = fw_ver in SENTINEL_V_FIRMWARE
    vertical = bool(cfg & _CFG_BEAM5) or n_beams == 5
    total_beams = n_beams + 1 if (cfg & _CFG_BEAM5 and n_beams != 5) else n_beams
    freq_class = _SYSTEM_FREQUENCY_HZ.get(freq_code)
    freq = _SENTINEL_V_FREQUENCY_HZ.get(freq_code, freq_class) if sentinel_v else freq_class
    return FixedLeader(
        firmware_version=fw_ver,
        firmware_revision=fw_rev,
        system_config=cfg,
        system_frequency_hz=freq,
        beam_pattern="convex" if cfg & 0x8 else "concave",
        orientation="up" if cfg & 0x80 else "down",
        simulated=bool(sim),
        lag_length=lag,
        n_beams=total_beams,
        n_cells=n_cells,
        pings_per_ensemble=pings,
        cell_size_m=cell_cm * 0.01,
        blank_m=blank_cm * 0.01,
        profiling_mode=prof_mode,
        low_corr_threshold=corr_thr,
        n_code_reps=code_reps,
        percent_good_min=pg_min,
        error_velocity_max_mps=err_vel_mm * 0.001,
        time_between_ping_groups_s=tpp_min * 60.0 + tpp_sec + tpp_hun * 0.01,
        coord_transform=ex,
        coordinate_system=_COORDINATE_SYSTEMS[(ex >> 3) & 0x3],
        heading_alignment_rad=ea * 0.01 * _DEG,
        heading_bias_rad=eb * 0.01 * _DEG,
        sensor_source=ez,
        sensors_available=sensors_avail,
        bin1_distance_m=bin1_cm * 0.01,
        transmit_pulse_length_m=pulse_cm * 0.01,
        ref_layer_start_cell=ref_start,
        ref_layer_end_cell=ref_end,
        false_target_threshold=wa,
        transmit_lag_m=lag_cm * 0.01,
        cpu_board_serial=cpu_serial,
        bandwidth=bandwidth,
        power_level=power,
        serial_number=serial,
        beam_angle_rad=None if beam_angle_deg is None else beam_angle_deg * _DEG,
        frequency_class_hz=freq_class,
        vertical_beam=vertical,
        sentinel_v=sentinel_v,
    )


def _decode_variable(buf, p: int, length: int, base: int) -> VariableLeader:
    if length < _MIN_VARIABLE_LEADER:
        raise Pd0DecodeError(
            base + p, "variable leader length", f">= {_MIN_VARIABLE_LEADER} bytes", f"{length} bytes"
        )
    (ens, yy, mo, dd, hh, mi, ss, hs, ens_msb, bit, c, depth_dm, hdg, pitch, roll, sal,
     temp) = struct.unpack_from("<HBBBBBBBBHHHHhhHh", buf, p + 2)
    rtc = (yy + (2000 if yy < 70 else 1900), mo, dd, hh, mi, ss, hs)
    time_ns = _rtc_ns(*rtc)
    if length >= 65:
        # Y2K-compliant clock (century, year, month, day, hour, minute, second, hundredths).
        y2k = struct.unpack_from("<8B", buf, p + 57)
        if 19 <= y2k[0] <= 21:
            rtc2 = (y2k[0] * 100 + y2k[1],) + tuple(y2k[2:])
            t2 = _rtc_ns(*rtc2)
            if t2 is not None:
                rtc, time_ns = rtc2, t2
    if time_ns is None:
        logger.warning("PD0 ensemble %d: invalid real-time clock %s", ens + (ens_msb << 16), rtc)
    mpt = hdg_std = pitch_std = roll_std = adc = err_status = pres = pres_var = None
    if length >= 31:
        m, s, h = struct.unpack_from("<BBB", buf, p + 28)
        mpt = m * 60.0 + s + h * 0.01
    if length >= 34:
        hs_, ps_, rs_ = struct.unpack_from("<BBB", buf, p + 31)
        hdg_std, pitch_std, roll_std = hs_ * _DEG, ps_ * 0.1 * _DEG, rs_ * 0.1 * _DEG
    if length >= 42:
        adc = tuple(struct.unpack_from("<8B", buf, p + 34))
    if length >= 46:
        (err_status,) = struct.unpack_from("<I", buf, p + 42)
    if length >= 56:
        pr, prv = struct.unpack_from("<II", buf, p + 48)
        # decapascal -> Pa; 0xFFFFFFFF is RDI's "no pressure sensor / no data"
        pres = None if pr == MISSING_U32 else signed_pressure_dapa(pr) * 10.0
        pres_var = None if prv == MISSING_U32 else prv * 10.0
    return VariableLeader(
        ensemble_number=ens + (ens_msb << 16),
        time_ns=time_ns,
        rtc=rtc,
        bit_result=bit,
        sound_speed_mps=float(c),
        depth_m=depth_dm * 0.1,
        heading_rad=hdg * 0.01 * _DEG,
        pitch_rad=pitch * 0.01 * _DEG,
        roll_rad=roll * 0.01 * _DEG,
        salinity_ppt=float(sal),
        temperature_degc=temp * 0.01,
        min_preping_wait_s=float("nan") if mpt is None else mpt,
        heading_std_rad=hdg_std,
        pitch_std_rad=pitch_std,
        roll_std_rad=roll_std,
        adc=adc,
        error_status=err_status,
        pressure_pa=pres,
        pressure_variance_pa=pres_var,
    )


def _profile(buf, p: int, length: int, base: int, name: str, dtype: str, fixed: FixedLeader) -> np.ndarray:
    """A (n_cells, beams) profile; with a vertical beam, the Janus beams only when the
    data type holds just those (the fifth beam then comes in its own data types)."""
    itemsize = np.dtype(dtype).itemsize
    n_beams = fixed.n_beams
    if fixed.vertical_beam and length < 2 + itemsize * fixed.n_cells * n_beams:
        n_beams = fixed.janus_beams
    need = 2 + itemsize * fixed.n_cells * n_beams
    if length < need:
        raise Pd0DecodeError(
            base + p,
            f"{name} data length",
            f">= {need} bytes for {fixed.n_cells} cells x {n_beams} beams",
            f"{length} bytes",
        )
    a = np.frombuffer(buf, dtype=dtype, count=fixed.n_cells * n_beams, offset=p + 2)
    return a.reshape(fixed.n_cells, n_beams)


def _decode_vertical_range(buf, p: int, length: int, base: int) -> VerticalBeam:
    if length < 9:
        raise Pd0DecodeError(base + p, "vertical beam range (0x4100) length", ">= 9 bytes", f"{length} bytes")
    ev, rssi, rng_mm, status = struct.unpack_from("<BBIB", buf, p + 2)
    return VerticalBeam(range_m=float("nan") if rng_mm == 0 else rng_mm * 0.001,
                        eval_amplitude=ev, rssi_amplitude=rssi, status=status)


def _decode_beam5_velocity(buf, p: int, length: int, base: int, fixed: FixedLeader) -> np.ndarray:
    need = 2 + 2 * fixed.n_cells
    if length < need:
        raise Pd0DecodeError(base + p, "beam 5 velocity (0x0A00) length",
                             f">= {need} bytes for {fixed.n_cells} cells", f"{length} bytes")
    raw = np.frombuffer(buf, dtype="<i2", count=fixed.n_cells, offset=p + 2)
    return _readonly(_velocity_si(raw))


def _velocity_si(raw: np.ndarray) -> np.ndarray:
    v = raw.astype(np.float64) * 0.001
    v[raw == BAD_VELOCITY] = np.nan
    return v


def _decode_bottom_track(buf, p: int, length: int, base: int) -> BottomTrack:
    if length < _MIN_BOTTOM_TRACK:
        raise Pd0DecodeError(base + p, "bottom track length", f">= {_MIN_BOTTOM_TRACK} bytes", f"{length} bytes")
    pings, delay, corr_min, amp_min, pg_min, mode, err_max = struct.unpack_from("<HHBBBBH", buf, p + 2)
    rng = np.frombuffer(buf, dtype="<u2", count=4, offset=p + 16).astype(np.uint32)
    if length >= _BT_RANGE_MSB_END:
        rng = rng + (np.frombuffer(buf, dtype=np.uint8, count=4, offset=p + 77).astype(np.uint32) << 16)
    vel_raw = np.frombuffer(buf, dtype="<i2", count=4, offset=p + 24).astype(np.int16)
    range_m = rng.astype(np.float64) * 0.01
    range_m[rng == 0] = np.nan
    return BottomTrack(
        pings_per_ensemble=pings,
        delay_before_reacquire=delay,
        corr_mag_min=corr_min,
        eval_amp_min=amp_min,
        percent_good_min=pg_min,
        mode=mode,
        error_velocity_max_mps=err_max * 0.001,
        range_m=_readonly(range_m),
        velocity_mps=_readonly(_velocity_si(vel_raw)),
        correlation=_readonly(np.frombuffer(buf, dtype=np.uint8, count=4, offset=p + 32).copy()),
        amplitude=_readonly(np.frombuffer(buf, dtype=np.uint8, count=4, offset=p + 36).copy()),
        percent_good=_readonly(np.frombuffer(buf, dtype=np.uint8, count=4, offset=p + 40).copy()),
        range_raw_cm=_readonly(rng),
        velocity_raw=_readonly(vel_raw),
    )


def decode_ensemble(
    data, start: int = 0, *, verify_checksum: bool = True, base_offset: int = 0
) -> Pd0Ensemble:
    """Decode the PD0 ensemble that begins at ``data[start]``.

    ``data`` (bytes-like) must hold the whole ensemble and its 2-byte checksum;
    bytes after it are ignored. Raises :class:`Pd0DecodeError` naming the byte
    offset (``base_offset`` + index into ``data``), the field, what was expected and
    what was found.
    """
    buf = data if isinstance(data, (bytes, bytearray)) else bytes(data)
    end = len(buf)
    if start < 0 or start > end:
        raise Pd0DecodeError(base_offset + start, "start", f"in [0, {end}]", str(start))
    try:
        n_bytes, offsets = parse_header(buf, start, end, base_offset)
    except NeedMore:
        raise Pd0DecodeError(
            base_offset + start, "ensemble header", "a complete header", f"{end - start} bytes"
        ) from None
    if end - start < n_bytes + 2:
        raise Pd0DecodeError(
            base_offset + start,
            "ensemble length",
            f"{n_bytes + 2} bytes (byte count {n_bytes} + 2-byte checksum)",
            f"{end - start} bytes",
        )
    if verify_checksum:
        (stored,) = struct.unpack_from("<H", buf, start + n_bytes)
        computed = ensemble_checksum(buf, start, n_bytes)
        if stored != computed:
            raise Pd0DecodeError(
                base_offset + start + n_bytes, "checksum", f"0x{computed:04X} (sum of bytes mod 65536)",
                f"0x{stored:04X}",
            )
    ends = list(offsets[1:]) + [n_bytes]
    ids = []
    fixed = variable = velocity = corr = echo = pg = bt = vbeam = v5 = None
    for off, nxt in zip(offsets, ends):
        p = start + off
        length = nxt - off
        (type_id,) = struct.unpack_from("<H", buf, p)
        ids.append(type_id)
        if type_id == ID_FIXED_LEADER:
            fixed = _decode_fixed(buf, p, length, base_offset)
        elif type_id == ID_VARIABLE_LEADER:
            variable = _decode_variable(buf, p, length, base_offset)
        elif type_id in (ID_VELOCITY, ID_CORRELATION, ID_ECHO_INTENSITY, ID_PERCENT_GOOD):
            if fixed is None:
                raise Pd0DecodeError(base_offset + p, f"data type 0x{type_id:04X}", "after the fixed leader", "before it")
            if type_id == ID_VELOCITY:
                velocity = _readonly(_velocity_si(_profile(buf, p, length, base_offset, "velocity", "<i2", fixed)))
            else:
                name = {ID_CORRELATION: "correlation", ID_ECHO_INTENSITY: "echo intensity",
                        ID_PERCENT_GOOD: "percent good"}[type_id]
                arr = _readonly(_profile(buf, p, length, base_offset, name, "u1", fixed).copy())
                if type_id == ID_CORRELATION:
                    corr = arr
                elif type_id == ID_ECHO_INTENSITY:
                    echo = arr
                else:
                    pg = arr
        elif type_id == ID_BOTTOM_TRACK:
            bt = _decode_bottom_track(buf, p, length, base_offset)
        elif type_id == ID_BEAM5_RANGE:
            vbeam = _decode_vertical_range(buf, p, length, base_offset)
        elif type_id == ID_BEAM5_VELOCITY:
            if fixed is None:
                raise Pd0DecodeError(base_offset + p, f"data type 0x{type_id:04X}", "after the fixed leader", "before it")
            v5 = _decode_beam5_velocity(buf, p, length, base_offset, fixed)
    assert fixed is not None and variable is not None  # guaranteed by parse_header
    return Pd0Ensemble(
        fixed=fixed,
        variable=variable,
        velocity_mps=velocity,
        correlation=corr,
        echo_intensity=echo,
        percent_good=pg,
        bottom_track=bt,
        data_type_ids=tuple(ids),
        n_bytes=n_bytes + 2,
        vertical_beam=vbeam,
        beam5_velocity_mps=v5,
    )


#: the data types :func:`decode_ensemble` decodes
DECODED_IDS = frozenset((ID_FIXED_LEADER, ID_VARIABLE_LEADER, ID_VELOCITY, ID_CORRELATION,
                         ID_ECHO_INTENSITY, ID_PERCENT_GOOD, ID_BOTTOM_TRACK,
                         ID_BEAM5_VELOCITY, ID_BEAM5_RANGE))
