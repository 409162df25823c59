"""Navigation: the pose of the body origin at any time (e.g. every ping's transmit time).

Inputs are GPS fixes (geodetic, of the antenna; only real fixes: GGA quality 0
"invalid" and 6 "estimated", RMC status V or mode E/N are rejected and counted; an
optional GST horizontal sigma), headings (NMEA HDT, or RMC course over ground, or the
DVL's compass, as flagged fallbacks), and DVL samples (bottom-track velocity of the DVL
head in the body frame, slant ranges of the four Janus beams and of a vertical beam,
roll, pitch and compass heading). Output: :class:`svss_daq.ping.NavSnapshot` per
requested time; :meth:`Navigator.quality` summarises the solution's state.

Method (``docs/navigation.md``):

* Geodetic to survey NED: exact WGS-84 (geodetic -> ECEF -> rotation into the local
  north-east-down tangent plane at the survey origin); no flat-earth approximation.
* Lever arms (``config/hardware.toml`` ``lever_arms``): body origin = antenna position
  minus R(roll, pitch, heading) @ r_gps; DVL velocity at the body origin = velocity at
  the head minus omega x r_dvl with omega = (0, 0, heading rate) (roll and pitch rates
  neglected).
* Dead reckoning: the DVL velocity rotated to NED is integrated (trapezoid) over runs of
  DVL samples no further apart than ``dvl_max_gap_s``. The offset GPS minus dead
  reckoning at each fix is smoothed over ``gps_smoothing_s`` and interpolated linearly in
  time (held beyond the first and last fix): the track has the shape of the DVL and the
  absolute position of the GPS, and runs on the DVL alone through a GPS outage. Where
  fixes carry a GST sigma the smoother weights them by 1/sigma^2; fixes whose sigma
  exceeds ``gps_max_sigma_m`` are rejected. Without DVL, positions are interpolated
  linearly between fixes.
* DVL coordinates: PD0 bottom track in ``beam`` coordinates goes beam -> instrument by
  Teledyne RDI's "ADCP Coordinate Transformation" formulas (:func:`beam_to_instrument`,
  with a 3-beam solution when one beam is bad and ``dvl_min_beams`` is 3), then
  instrument -> ship with the heading alignment EA (and the 180 deg roll of an
  up-looking head); ``instrument`` the same without the first step; ``ship`` and
  ``earth`` as sent.
* Altitude above the bottom: mean over valid beams of range x (vertical component of
  the beam direction rotated by roll and pitch), plus the DVL head's depth below the body
  origin. Janus beams at ``dvl_beam_angle_deg`` from the vertical, RDI's layout for a
  down-looking convex head with beam 3 on the bow: 3 forward, 4 aft, 2 starboard, 1
  port (:func:`rdi_beam_vectors`; concave swaps the pairs). With fewer than
  ``dvl_min_beams`` slanted ranges, a vertical (fifth) beam's range is used.

Angles in radians, distances m, times int ns since the Unix epoch UTC.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from typing import Iterable, Optional, Sequence

import numpy as np

from svss_daq.frames import body_to_ned
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE, NAV_NO_HEADING,
                           NavSnapshot)

__all__ = [
    "WGS84_A", "WGS84_F", "NAV_HEADING_FROM_COURSE", "NAV_HEADING_FROM_COMPASS",
    "NAV_NO_HEADING", "GpsFix", "HeadingSample", "DvlSample", "geodetic_to_ecef",
    "ecef_to_geodetic", "ned_rotation", "geodetic_to_ned", "ned_to_geodetic",
    "rdi_beam_vectors", "janus_beam_vectors", "beam_to_instrument", "three_beam_fill",
    "instrument_to_ship", "altitude_from_ranges", "gst_sigma_m", "dvl_sample_from_pd0",
    "samples_from_nmea", "compute_poses", "Navigator",
]

logger = logging.getLogger(__name__)

WGS84_A = 6378137.0                 #: semi-major axis, m
WGS84_F = 1.0 / 298.257223563       #: flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

#: extra quality bits beside those of svss_daq.ping

#: the yaw rate for the DVL lever-arm term is the heading change over +-0.5 s
YAW_RATE_HALF_WINDOW_S = 0.5


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class GpsFix:
    """Antenna position: geodetic degrees, ellipsoidal height m (NaN: unknown, taken as
    the origin's height), GGA fix quality code."""
    time_ns: int
    latitude_deg: float
    longitude_deg: float
    height_m: float = float("nan")
    fix_quality: int = 1
    sigma_m: float = float("nan")  #: horizontal 1-sigma from GST (DRMS), m; NaN: not sent


@dataclass(frozen=True)
class HeadingSample:
    """Heading of the body x axis from true north, rad; ``from_course`` when it is a
    course over ground standing in for a heading."""
    time_ns: int
    heading_rad: float
    from_course: bool = False


@dataclass(frozen=True)
class DvlSample:
    """DVL head velocity over ground in the body frame (m/s, NaN: no bottom lock),
    slant ranges of beams 1-4 (m, NaN where no bottom), roll and pitch (rad), the
    vertical beam's range (m, NaN: none) and the compass heading of the body x axis
    (rad, the instrument's heading less its heading alignment; NaN: none)."""
    time_ns: int
    velocity_body_m_s: tuple[float, float, float]
    ranges_m: tuple[float, float, float, float]
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    vertical_range_m: float = float("nan")
    heading_rad: float = float("nan")

    @property
    def bottom_lock(self) -> bool:
        return bool(np.all(np.isfinite(self.velocity_body_m_s)))


# --------------------------------------------------------------------------- geodesy


def geodetic_to_ecef(lat_deg, lon_deg, h_m) -> np.ndarray:
    """WGS-84 geodetic (deg, deg, m) to ECEF (..., 3), m."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    h = np.asarray(h_m, dtype=np.float64)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - WGS84_E2) + h) * np.sin(lat)], axis=-1)


def ecef_to_geodetic(xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (..., 3) m to WGS-84 (lat deg, lon deg, h m); fixed-point iteration on
    latitude, converged to < 1e-12 rad within 6 steps near the surface."""
    xyz = np.asarray(xyz, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(8):
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        h = _height(p, z, lat, n)
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.degrees(lat), np.degrees(lon), _height(p, z, lat, n)


def _height(p, z, lat, n):
    """Height above the ellipsoid, p cos(lat) + z sin(lat) - n (1 - e2 sin^2 lat): valid
    at the poles too (p / cos(lat) - n was 0/0 there: NaN on the polar axis)."""
    s = np.sin(lat)
    return p * np.cos(lat) + z * s - n * (1.0 - WGS84_E2 * s * s)


def ned_rotation(lat0_deg: float, lon0_deg: float) -> np.ndarray:
    """Matrix whose rows are the north, east and down unit vectors (ECEF) at the origin."""
    la, lo = math.radians(lat0_deg), math.radians(lon0_deg)
    sl, cl, so, co = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def geodetic_to_ned(lat_deg, lon_deg, h_m, origin: tuple[float, float, float]) -> np.ndarray:
    """Geodetic (deg, deg, m) to survey NED (..., 3) m about ``origin`` (lat, lon, h)."""
    d = geodetic_to_ecef(lat_deg, lon_deg, h_m) - geodetic_to_ecef(*origin)
    return d @ ned_rotation(origin[0], origin[1]).T


def ned_to_geodetic(ned, origin: tuple[float, float, float]):
    """Survey NED (..., 3) m to geodetic (lat deg, lon deg, h m)."""
    xyz = np.asarray(ned, dtype=np.float64) @ ned_rotation(origin[0], origin[1]) \
        + geodetic_to_ecef(*origin)
    return ecef_to_geodetic(xyz)


# --------------------------------------------------------------------------- DVL


def rdi_beam_vectors(beam_angle_rad: float, convex: bool = True) -> np.ndarray:
    """Outward unit vectors (4, 3) of beams 1-4 in RDI's instrument frame (X, Y, Z; Z
    along the head's axis away from the beams, Y toward beam 3), each ``beam_angle_rad``
    from the axis: the geometry for which :func:`beam_to_instrument` is exact when a beam
    velocity is the velocity's component toward the transducer, b_i = -v . u_i.
    Convex: beam 2 at +X, 1 at -X, 3 at +Y, 4 at -Y; concave swaps each pair."""
    s, c = math.sin(beam_angle_rad), math.cos(beam_angle_rad)
    k = 1.0 if convex else -1.0
    return np.array([[-k * s, 0.0, -c], [k * s, 0.0, -c], [0.0, k * s, -c], [0.0, -k * s, -c]])


def janus_beam_vectors(beam_angle_rad: float, convex: bool = True) -> np.ndarray:
    """Unit vectors (4, 3) of beams 1-4 in the body frame for a down-looking DVL with
    beam 3 forward (instrument X starboard, Y forward, Z up; :func:`rdi_beam_vectors`):
    convex 1 port, 2 starboard, 3 forward, 4 aft, each ``beam_angle_rad`` from the
    vertical."""
    u = rdi_beam_vectors(beam_angle_rad, convex)
    return np.stack([u[:, 1], u[:, 0], -u[:, 2]], axis=-1)


def beam_to_instrument(beam_m_s, beam_angle_rad: float, convex: bool = True) -> np.ndarray:
    """RDI beam velocities (4,) m/s, positive toward the transducer, to instrument
    (X, Y, Z, error) m/s (Teledyne RDI, "ADCP Coordinate Transformation"):
    X = c a (b1 - b2), Y = c a (b4 - b3), Z = b (b1 + b2 + b3 + b4),
    e = d (b1 + b2 - b3 - b4), a = 1/(2 sin theta), b = 1/(4 cos theta), d = a/sqrt(2),
    c = +1 convex, -1 concave. NaN in any beam gives NaN (see :func:`three_beam_fill`)."""
    b1, b2, b3, b4 = (float(x) for x in beam_m_s)
    a = 1.0 / (2.0 * math.sin(beam_angle_rad))
    bb = 1.0 / (4.0 * math.cos(beam_angle_rad))
    c = 1.0 if convex else -1.0
    d = a / math.sqrt(2.0)
    return np.array([c * a * (b1 - b2), c * a * (b4 - b3), bb * (b1 + b2 + b3 + b4),
                     d * (b1 + b2 - b3 - b4)])


def three_beam_fill(beam_m_s) -> np.ndarray:
    """Beam velocities (4,) with one bad (NaN) beam replaced by the value that makes the
    error velocity zero (RDI's 3-beam solution): b1 + b2 = b3 + b4. Unchanged with no
    bad beam; all NaN with more than one."""
    b = np.array(beam_m_s, dtype=np.float64)[:4]
    bad = ~np.isfinite(b)
    if not bad.any():
        return b
    if bad.sum() > 1:
        return np.full(4, np.nan)
    k = int(np.flatnonzero(bad)[0])
    pair, other = ((0, 1), (2, 3)) if k < 2 else ((2, 3), (0, 1))
    mate = pair[1] if k == pair[0] else pair[0]
    b[k] = b[other[0]] + b[other[1]] - b[mate]
    return b


def instrument_to_ship(xyz, heading_alignment_rad: float, up_looking: bool = False
                       ) -> np.ndarray:
    """Instrument (X, Y, Z) to ship (X starboard, Y forward, Z up) coordinates: for an
    up-looking head first a 180 deg roll (X, Z negated, RDI), then the heading alignment
    EA (beam 3's azimuth clockwise from the bow): X' = cos EA X + sin EA Y,
    Y' = -sin EA X + cos EA Y. Tilts are not applied (the navigation applies roll and
    pitch to ship coordinates itself)."""
    x, y, z = (float(v) for v in xyz[:3])
    if up_looking:
        x, z = -x, -z
    ce, se = math.cos(heading_alignment_rad), math.sin(heading_alignment_rad)
    return np.array([ce * x + se * y, -se * x + ce * y, z])


def altitude_from_ranges(ranges_m, roll_rad: float, pitch_rad: float, beam_angle_rad: float,
                         dvl_lever_m, min_beams: int = 3,
                         vertical_range_m: float = float("nan")) -> float:
    """Height of the body origin above a flat bottom from DVL slant ranges, m; with fewer
    than ``min_beams`` valid ranges from the vertical beam's range (its axis along body
    z), else NaN. Heading does not matter."""
    r = np.asarray(ranges_m, dtype=np.float64)
    ok = np.isfinite(r) & (r > 0)
    rot = body_to_ned(roll_rad, pitch_rad, 0.0)
    if ok.sum() >= min_beams:
        vert = (janus_beam_vectors(beam_angle_rad) @ rot.T)[:, 2]
        below_head = float(np.mean(r[ok] * vert[ok]))
    elif math.isfinite(vertical_range_m) and vertical_range_m > 0:
        below_head = vertical_range_m * float(rot[2, 2])
    else:
        return float("nan")
    return below_head + float((rot @ np.asarray(dvl_lever_m, dtype=np.float64))[2])


@functools.lru_cache(maxsize=8192)
def _sample_altitude(d: "DvlSample", beam_angle_rad: float, dvl_lever_m: tuple,
                     min_beams: int) -> float:
    """:func:`altitude_from_ranges` of one DVL sample, computed once (a navigator poses
    each ping from the same history of samples)."""
    return altitude_from_ranges(d.ranges_m, d.roll_rad, d.pitch_rad, beam_angle_rad,
                                dvl_lever_m, min_beams, d.vertical_range_m)


def dvl_sample_from_pd0(ens, min_beams: int = 3,
                        beam_angle_rad: Optional[float] = None) -> Optional[DvlSample]:
    """A :class:`DvlSample` from a decoded PD0 ensemble (``svss_daq.drivers.pd0``).

    Bottom-track velocity is RDI's velocity of the bottom relative to the instrument,
    so the head's velocity is its negative. Coordinate systems: ``beam`` (to instrument
    with the fixed leader's beam angle, else ``beam_angle_rad``, and beam pattern; one
    bad beam is filled by :func:`three_beam_fill` when ``min_beams`` <= 3, else the
    velocity is bad), ``instrument`` (to ship with the heading alignment and
    orientation), ``ship`` (X starboard, Y forward, Z up, mapped to body x = Y, y = X,
    z = -Z) and ``earth`` (east, north, up: rotated back into the body frame with the
    ensemble's heading, pitch and roll). Returns None without a time or bottom track.
    """
    bt = ens.bottom_track
    t = ens.variable.time_ns
    if bt is None or t is None:
        return None
    fx = ens.fixed
    roll, pitch = float(ens.variable.roll_rad), float(ens.variable.pitch_rad)
    cs = fx.coordinate_system
    if cs in ("beam", "instrument"):
        if cs == "beam":
            angle = fx.beam_angle_rad if fx.beam_angle_rad is not None else beam_angle_rad
            if angle is None:
                raise ValueError(f"PD0 ensemble {ens.variable.ensemble_number}: beam "
                                 "coordinates without a beam angle (fixed leader system "
                                 "configuration bits 8-9 'other', no beam angle byte)")
            b = np.asarray(bt.velocity_mps[:4], dtype=np.float64)
            if min_beams <= 3:
                b = three_beam_fill(b)
            xyz = beam_to_instrument(b, angle, fx.beam_pattern == "convex")[:3]
        else:
            xyz = np.asarray(bt.velocity_mps[:3], dtype=np.float64)
        v = -instrument_to_ship(xyz, fx.heading_alignment_rad, fx.orientation == "up")
        body = np.array([v[1], v[0], -v[2]])
    elif cs == "ship":
        v = -np.asarray(bt.velocity_mps[:3], dtype=np.float64)
        body = np.array([v[1], v[0], -v[2]])
    else:  # earth
        v = -np.asarray(bt.velocity_mps[:3], dtype=np.float64)
        ned = np.array([v[1], v[0], -v[2]])
        body = body_to_ned(roll, pitch, float(ens.variable.heading_rad)).T @ ned
    rng = np.full(4, np.nan)
    rr = np.asarray(bt.range_m, dtype=np.float64)[:4]
    rng[:len(rr)] = rr
    vb = getattr(ens, "vertical_beam", None)
    vr = float(vb.range_m) if vb is not None else float("nan")
    hdg = float(_wrap(float(ens.variable.heading_rad) - fx.heading_alignment_rad))
    return DvlSample(int(t), tuple(float(x) for x in body), tuple(float(x) for x in rng),
                     roll, pitch, vr, hdg)


def gst_sigma_m(rec) -> float:
    """Horizontal 1-sigma (DRMS, m) of a GST record: sqrt(sigma_lat^2 + sigma_lon^2),
    else from the error ellipse's semi-axes; NaN when neither is sent."""
    a, b = rec.sigma_latitude_m, rec.sigma_longitude_m
    if a is None or b is None:
        a, b = rec.sigma_major_m, rec.sigma_minor_m
    if a is None or b is None:
        return float("nan")
    return math.hypot(a, b)


#: GGA fix qualities that are not a GNSS fix: 0 invalid, 6 estimated (dead reckoning)
GGA_NOT_A_FIX = (0, 6)
#: RMC/GLL mode letters that are not a GNSS fix: E estimated, N not valid
RMC_MODE_NOT_A_FIX = ("E", "N")


def samples_from_nmea(records: Iterable, course_min_speed_m_s: float = 0.3,
                      max_sigma_m: float = math.inf, counts: Optional[dict] = None
                      ) -> tuple[list[GpsFix], list[HeadingSample]]:
    """GPS fixes (GGA with a real fix and a date; else RMC with status A) and headings
    (HDT; RMC course above ``course_min_speed_m_s`` as a fallback) from NMEA records of
    ``svss_daq.drivers.nmea``. A GST with the fix's time of day gives the fix its sigma
    (:func:`gst_sigma_m`); a fix with sigma above ``max_sigma_m`` is rejected, as are
    GGA quality 0 or 6 and RMC status V or mode E/N: each counted in
    ``counts["gps_rejected"]`` (when a dict is given). Records without ``time_ns`` are
    skipped (HDT has no time of its own: give ``(host_time_ns, record)`` pairs)."""
    from svss_daq.drivers import nmea
    fixes, heads = [], []
    gga_times = set()
    pending_rmc = []
    sigma_by_tod: dict = {}
    recs = list(records)
    for rec in recs:
        r = rec[1] if isinstance(rec, tuple) else rec
        if isinstance(r, nmea.GstStatistics) and r.time_of_day_ns is not None:
            sigma_by_tod[r.time_of_day_ns] = gst_sigma_m(r)
    rejected = 0
    for rec in recs:
        t_host = None
        if isinstance(rec, tuple):
            t_host, rec = rec
        if isinstance(rec, nmea.HdtHeading):
            if rec.heading_rad is not None and t_host is not None:
                heads.append(HeadingSample(int(t_host), float(rec.heading_rad)))
            continue
        t = getattr(rec, "time_ns", None)
        if t is None:
            continue
        if isinstance(rec, nmea.GgaFix):
            if rec.latitude_deg is None or rec.longitude_deg is None:
                if rec.fix_quality not in GGA_NOT_A_FIX:
                    continue
            sigma = sigma_by_tod.get(rec.time_of_day_ns, float("nan"))
            gga_times.add(t)  # an RMC of the same time does not stand in for a rejected GGA
            if rec.fix_quality in GGA_NOT_A_FIX or sigma > max_sigma_m:
                rejected += 1
                continue
            h = float("nan")
            if rec.altitude_msl_m is not None:
                h = rec.altitude_msl_m + (rec.geoid_separation_m or 0.0)
            fixes.append(GpsFix(t, rec.latitude_deg, rec.longitude_deg, h, rec.fix_quality,
                                sigma))
        elif isinstance(rec, nmea.RmcFix):
            if rec.valid and (rec.mode or "A").upper() not in RMC_MODE_NOT_A_FIX:
                pending_rmc.append(rec)
            else:
                rejected += 1
    for rec in pending_rmc:
        if rec.time_ns not in gga_times and rec.latitude_deg is not None and rec.longitude_deg is not None:
            sigma = sigma_by_tod.get(rec.time_of_day_ns, float("nan"))
            if sigma > max_sigma_m:
                rejected += 1
            else:
                fixes.append(GpsFix(rec.time_ns, rec.latitude_deg, rec.longitude_deg,
                                    float("nan"), 1, sigma))
        if rec.course_rad is not None and (rec.speed_mps or 0.0) > course_min_speed_m_s:
            heads.append(HeadingSample(rec.time_ns, float(rec.course_rad), from_course=True))
    fixes.sort(key=lambda f: f.time_ns)
    heads.sort(key=lambda h: h.time_ns)
    if counts is not None:
        counts["gps_rejected"] = counts.get("gps_rejected", 0) + rejected
    return fixes, heads


# --------------------------------------------------------------------------- fusion


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _nearest_age(t_src: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distance (same units) from each t to the nearest t_src (inf if none)."""
    if t_src.size == 0:
        return np.full(t.shape, np.inf)
    i = np.clip(np.searchsorted(t_src, t), 1, t_src.size) - 1
    j = np.clip(i + 1, 0, t_src.size - 1)
    return np.minimum(np.abs(t - t_src[i]), np.abs(t - t_src[j]))


def _interp_angle(t_src, a_src, t):
    if t_src.size == 0:
        return np.full(t.shape, np.nan)
    return _wrap(np.interp(t, t_src, np.unwrap(a_src)))


def _headings(t: np.ndarray, heads: Sequence[HeadingSample], max_age_s: float, t0_ns: int,
              compass: Sequence = ()):
    """Heading (rad) at times t (s after ``t0_ns``) and a flag: 0 HDT, 1 course, 2 none,
    3 DVL compass (``compass``: DvlSample with a finite ``heading_rad``)."""
    sec = lambda a: (np.asarray(a, dtype=np.int64) - t0_ns).astype(np.float64) * 1e-9  # noqa: E731
    th = sec([h.time_ns for h in heads if not h.from_course])
    ah = np.array([h.heading_rad for h in heads if not h.from_course], dtype=np.float64)
    tc = sec([h.time_ns for h in heads if h.from_course])
    ac = np.array([h.heading_rad for h in heads if h.from_course], dtype=np.float64)
    tm = sec([d.time_ns for d in compass])
    am = np.array([d.heading_rad for d in compass], dtype=np.float64)
    oh, oc, om = np.argsort(th), np.argsort(tc), np.argsort(tm)
    th, ah, tc, ac, tm, am = th[oh], ah[oh], tc[oc], ac[oc], tm[om], am[om]
    use_h = _nearest_age(th, t) <= max_age_s
    use_c = ~use_h & (_nearest_age(tc, t) <= max_age_s)
    use_m = ~use_h & ~use_c & (_nearest_age(tm, t) <= max_age_s)
    out = np.where(use_h, _interp_angle(th, ah, t), _interp_angle(tc, ac, t))
    if use_m.any():
        out = np.where(use_m, _interp_angle(tm, am, t), out)
    flag = np.where(use_h, 0, np.where(use_c, 1, np.where(use_m, 3, 2)))
    return np.where(flag == 2, 0.0, out), flag


def _rotations(roll, pitch, heading) -> np.ndarray:
    """:func:`~svss_daq.frames.body_to_ned` of each (roll, pitch, heading), (n, 3, 3)."""
    r, p, h = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (roll, pitch, heading))
    cr, sr, cp, sp, ch, sh = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(h), np.sin(h)
    out = np.empty((r.size, 3, 3))
    out[:, 0, 0] = ch * cp
    out[:, 0, 1] = ch * sp * sr - sh * cr
    out[:, 0, 2] = ch * sp * cr + sh * sr
    out[:, 1, 0] = sh * cp
    out[:, 1, 1] = sh * sp * sr + ch * cr
    out[:, 1, 2] = sh * sp * cr - ch * sr
    out[:, 2, 0] = -sp
    out[:, 2, 1] = cp * sr
    out[:, 2, 2] = cp * cr
    return out


def _smooth(t: np.ndarray, x: np.ndarray, window_s: float,
            weights: Optional[np.ndarray] = None) -> np.ndarray:
    """Moving (weighted) mean of rows of x over |t_i - t_k| <= window/2."""
    if window_s <= 0 or t.size < 2:
        return x
    w = np.ones(t.size) if weights is None else np.asarray(weights, dtype=np.float64)
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x * w[:, None], axis=0)])
    cw = np.concatenate([[0.0], np.cumsum(w)])
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return (c[hi] - c[lo]) / (cw[hi] - cw[lo])[:, None]


def _fix_weights(fixes: Sequence[GpsFix]) -> Optional[np.ndarray]:
    """1/sigma^2 per fix where GST sigmas are known (fixes without one take the median
    sigma); None (equal weights) when no fix has one."""
    sig = np.array([f.sigma_m for f in fixes], dtype=np.float64)
    known = np.isfinite(sig) & (sig > 0)
    if not known.any():
        return None
    sig = np.where(known, sig, np.median(sig[known]))
    return 1.0 / sig ** 2


def compute_poses(times_ns, fixes: Sequence[GpsFix], headings: Sequence[HeadingSample],
                  dvl: Sequence[DvlSample], cfg, lever_arms,
                  origin: Optional[tuple[float, float, float]] = None) -> list[NavSnapshot]:
    """The pose of the body origin at each of ``times_ns``.

    ``cfg``: :class:`~svss_daq.config.NavigationConfig`; ``lever_arms``:
    :class:`~svss_daq.config.LeverArms`; ``origin`` (lat deg, lon deg, h m) overrides the
    configured survey origin (default: configured, else the first fix).
    """
    t_ns = np.asarray(times_ns, dtype=np.int64).reshape(-1)
    if t_ns.size == 0:
        return []
    fixes = sorted(fixes, key=lambda f: f.time_ns)
    dvl = sorted(dvl, key=lambda d: d.time_ns)
    t0 = int(t_ns.min())  # times relative to this, s (float64 keeps ns resolution)
    sec = lambda a: (np.asarray(a, dtype=np.int64) - t0).astype(np.float64) * 1e-9  # noqa: E731
    t = sec(t_ns)
    if origin is None and cfg.origin_latitude_deg is not None and cfg.origin_longitude_deg is not None:
        origin = (cfg.origin_latitude_deg, cfg.origin_longitude_deg, cfg.origin_height_m or 0.0)
    if origin is None:
        if not fixes:
            raise ValueError("navigation: no survey origin configured "
                             "(navigation.origin_latitude_deg) and no GPS fix to take it from")
        f = fixes[0]
        origin = (f.latitude_deg, f.longitude_deg, 0.0 if math.isnan(f.height_m) else f.height_m)
    r_gps = np.asarray(lever_arms.gps_antenna_m, dtype=np.float64)
    r_dvl = np.asarray(lever_arms.dvl_m, dtype=np.float64)
    beam = math.radians(cfg.dvl_beam_angle_deg)

    # attitude: roll and pitch from the DVL's sensors, heading from HDT / course
    td = sec([d.time_ns for d in dvl]) if dvl else np.zeros(0)
    roll_d = np.array([d.roll_rad for d in dvl], dtype=np.float64)
    pitch_d = np.array([d.pitch_rad for d in dvl], dtype=np.float64)
    compass = [d for d in dvl if math.isfinite(d.heading_rad)]

    def attitude(tt):
        if td.size:
            r, p = np.interp(tt, td, roll_d), np.interp(tt, td, pitch_d)
        else:
            r = p = np.zeros_like(tt)
        h, hflag = _headings(tt, headings, cfg.heading_max_age_s, t0, compass)
        return r, p, h, hflag

    # GPS: body-origin positions at the fixes
    tf = sec([f.time_ns for f in fixes]) if fixes else np.zeros(0)
    if fixes:
        hgt = np.array([origin[2] if math.isnan(f.height_m) else f.height_m for f in fixes])
        ant = geodetic_to_ned(np.array([f.latitude_deg for f in fixes]),
                              np.array([f.longitude_deg for f in fixes]), hgt, origin)
        rf, pf, hf, _ = attitude(tf)
        pos_f = ant - _rotations(rf, pf, hf) @ r_gps
    else:
        pos_f = np.zeros((0, 3))
    w_f = _fix_weights(fixes)

    # DVL: body-origin NED velocity and altitude at the DVL samples
    n = t.size
    pos = np.full((n, 3), np.nan)
    vel = np.full((n, 3), np.nan)
    dr = np.zeros(n, dtype=bool)
    if td.size:
        vb = np.array([d.velocity_body_m_s for d in dvl], dtype=np.float64)
        rd, pd, hd, _ = attitude(td)
        eps = YAW_RATE_HALF_WINDOW_S
        _, _, h_a, _ = attitude(td - eps)
        _, _, h_b, _ = attitude(td + eps)
        yaw_rate = _wrap(h_b - h_a) / (2 * eps)
        omega_x_r = np.stack([-yaw_rate * r_dvl[1], yaw_rate * r_dvl[0], np.zeros_like(td)], -1)
        rot_d = _rotations(rd, pd, hd)
        v_ned = np.einsum("kij,kj->ki", rot_d, vb - omega_x_r)
        lever = tuple(float(v) for v in r_dvl)
        alt_d = np.array([_sample_altitude(d, beam, lever, cfg.dvl_min_beams) for d in dvl])
        ok = np.all(np.isfinite(v_ned), axis=1)
        idx = np.flatnonzero(ok)
        # runs of valid samples no further apart than dvl_max_gap_s
        breaks = np.flatnonzero(np.diff(td[idx]) > cfg.dvl_max_gap_s) + 1
        for run in np.split(idx, breaks):
            if run.size < 2:
                continue
            ts, vs = td[run], v_ned[run]
            dpos = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (vs[1:] + vs[:-1])
                                                          * np.diff(ts)[:, None], axis=0)])
            inside = (t >= ts[0]) & (t <= ts[-1])
            fk = (tf >= ts[0] - cfg.gps_fix_max_age_s) & (tf <= ts[-1] + cfg.gps_fix_max_age_s)
            if not inside.any() or not fk.any():
                continue
            tfk = tf[fk]
            d_at_f = np.stack([np.interp(tfk, ts, dpos[:, j]) for j in range(3)], -1)
            off = _smooth(tfk, pos_f[fk] - d_at_f, cfg.gps_smoothing_s,
                          None if w_f is None else w_f[fk])
            ti = t[inside]
            pos[inside] = np.stack([np.interp(ti, ts, dpos[:, j]) + np.interp(ti, tfk, off[:, j])
                                    for j in range(3)], -1)
            vel[inside] = np.stack([np.interp(ti, ts, vs[:, j]) for j in range(3)], -1)
            dr[inside] = True
        near_d = _nearest_age(td[np.isfinite(alt_d)], t) <= cfg.dvl_max_gap_s
        good = np.isfinite(alt_d)
        alt = np.where(near_d, np.interp(t, td[good], alt_d[good]) if good.any() else np.nan, np.nan)
    else:
        alt = np.full(n, np.nan)

    # GPS only where dead reckoning did not reach
    gps_only = ~dr & (tf.size > 0)
    if gps_only.any():
        pos[gps_only] = np.stack([np.interp(t[gps_only], tf, pos_f[:, j]) for j in range(3)], -1)
        if tf.size >= 2:
            vf = np.stack([np.gradient(pos_f[:, j], tf) for j in range(3)], -1)
            vel[gps_only] = np.stack([np.interp(t[gps_only], tf, vf[:, j]) for j in range(3)], -1)

    r, p, h, hflag = attitude(t)
    near_fix = _nearest_age(tf, t) <= cfg.gps_fix_max_age_s
    lat, lon, _ = ned_to_geodetic(pos, origin)
    out = []
    for k in range(n):
        q = 0
        if np.all(np.isfinite(pos[k])):
            if near_fix[k]:
                q |= NAV_GPS_FIX
            elif dr[k]:
                q |= NAV_DEAD_RECKONED
        if np.isfinite(alt[k]):
            q |= NAV_BOTTOM_LOCK
        q |= {0: 0, 1: NAV_HEADING_FROM_COURSE, 2: NAV_NO_HEADING,
              3: NAV_HEADING_FROM_COMPASS}[int(hflag[k])]
        out.append(NavSnapshot(int(t_ns[k]), float(pos[k, 0]), float(pos[k, 1]), float(pos[k, 2]),
                               float(vel[k, 0]), float(vel[k, 1]), float(vel[k, 2]),
                               float(r[k]), float(p[k]), float(h[k]), float(alt[k]),
                               float(lat[k]), float(lon[k]), q))
    return out


class Navigator:
    """Collects GPS, heading and DVL samples and poses pings from them.

    ``add_nmea`` takes records (or ``(host_time_ns, record)`` pairs) from
    ``svss_daq.drivers.nmea``; ``add_pd0`` PD0 ensembles. ``poses(times_ns)`` calls
    :func:`compute_poses` on everything collected (kept for ``history_s``);
    ``quality(now_ns)`` summarises the state for a status stream.
    """

    def __init__(self, cfg, lever_arms, history_s: float = 600.0) -> None:
        self.cfg, self.lever_arms, self.history_ns = cfg, lever_arms, int(history_s * 1e9)
        self.fixes: list[GpsFix] = []
        self.headings: list[HeadingSample] = []
        self.dvl: list[DvlSample] = []
        self.origin: Optional[tuple[float, float, float]] = None
        self.counts = {"gps_fixes": 0, "gps_rejected": 0, "dvl_samples": 0, "dvl_no_lock": 0}
        self._last_fix: Optional[GpsFix] = None
        self._last_dvl: Optional[DvlSample] = None
        self._last_lock_ns: Optional[int] = None
        self._last_hdt_ns: Optional[int] = None
        self._last_course_ns: Optional[int] = None
        self._last_compass_ns: Optional[int] = None

    def add_fix(self, f: GpsFix) -> None:
        if self.origin is None and self.cfg.origin_latitude_deg is None:
            self.origin = (f.latitude_deg, f.longitude_deg, 0.0 if math.isnan(f.height_m) else f.height_m)
            logger.info("navigation: survey origin set to the first fix %.8f, %.8f",
                        f.latitude_deg, f.longitude_deg)
        self.fixes.append(f)
        self.counts["gps_fixes"] += 1
        if self._last_fix is None or f.time_ns >= self._last_fix.time_ns:
            self._last_fix = f

    def add_nmea(self, records: Iterable) -> None:
        fixes, heads = samples_from_nmea(records, self.cfg.course_min_speed_m_s,
                                         self.cfg.gps_max_sigma_m, self.counts)
        for f in fixes:
            self.add_fix(f)
        for h in heads:
            if h.from_course:
                self._last_course_ns = max(self._last_course_ns or h.time_ns, h.time_ns)
            else:
                self._last_hdt_ns = max(self._last_hdt_ns or h.time_ns, h.time_ns)
        self.headings += heads

    def add_pd0(self, ensemble) -> None:
        d = dvl_sample_from_pd0(ensemble, self.cfg.dvl_min_beams,
                                math.radians(self.cfg.dvl_beam_angle_deg))
        if d is not None:
            self.add_dvl(d)

    def add_dvl(self, d: DvlSample) -> None:
        self.dvl.append(d)
        self.counts["dvl_samples"] += 1
        if self._last_dvl is None or d.time_ns >= self._last_dvl.time_ns:
            self._last_dvl = d
        if d.bottom_lock:
            self._last_lock_ns = max(self._last_lock_ns or d.time_ns, d.time_ns)
        else:
            self.counts["dvl_no_lock"] += 1
        if math.isfinite(d.heading_rad):
            self._last_compass_ns = max(self._last_compass_ns or d.time_ns, d.time_ns)

    def prune(self, before_ns: int) -> None:
        self.fixes = [f for f in self.fixes if f.time_ns >= before_ns]
        self.headings = [h for h in self.headings if h.time_ns >= before_ns]
        self.dvl = [d for d in self.dvl if d.time_ns >= before_ns]

    def poses(self, times_ns) -> list[NavSnapshot]:
        times = np.asarray(times_ns, dtype=np.int64).reshape(-1)
        if times.size:
            self.prune(int(times.min()) - self.history_ns)
        return compute_poses(times, self.fixes, self.headings, self.dvl, self.cfg,
                             self.lever_arms, self.origin)

    def quality(self, now_ns: int) -> dict:
        """JSON-serialisable state at ``now_ns`` (O(1)): ``mode`` ("gps" within
        ``gps_fix_max_age_s`` of the last fix, "dead_reckoning" with bottom lock within
        ``dvl_max_gap_s`` and a survey origin, else "none"), ``gps_fix_age_s``,
        ``dvl_age_s`` (s, null: never), ``heading_source`` ("hdt", "course",
        "dvl_compass" or "none", each within ``heading_max_age_s``), ``bottom_lock``,
        ``gps_sigma_m`` (GST sigma of the last fix, null: not sent) and the counters
        ``gps_fixes``, ``gps_rejected``, ``dvl_samples``, ``dvl_no_lock``."""
        cfg = self.cfg

        def age(t):
            return None if t is None else (int(now_ns) - int(t)) * 1e-9

        fix_age = age(None if self._last_fix is None else self._last_fix.time_ns)
        dvl_age = age(None if self._last_dvl is None else self._last_dvl.time_ns)
        lock_age = age(self._last_lock_ns)
        bottom_lock = (self._last_dvl is not None and self._last_dvl.bottom_lock
                       and dvl_age is not None and abs(dvl_age) <= cfg.dvl_max_gap_s)
        has_origin = self.origin is not None or cfg.origin_latitude_deg is not None
        if fix_age is not None and abs(fix_age) <= cfg.gps_fix_max_age_s:
            mode = "gps"
        elif lock_age is not None and abs(lock_age) <= cfg.dvl_max_gap_s and has_origin:
            mode = "dead_reckoning"
        else:
            mode = "none"
        heading = "none"
        for name, t in (("hdt", self._last_hdt_ns), ("course", self._last_course_ns),
                        ("dvl_compass", self._last_compass_ns)):
            a = age(t)
            if a is not None and abs(a) <= cfg.heading_max_age_s:
                heading = name
                break
        sigma = None
        if self._last_fix is not None and math.isfinite(self._last_fix.sigma_m):
            sigma = float(self._last_fix.sigma_m)
        return {"mode": mode, "gps_fix_age_s": fix_age, "dvl_age_s": dvl_age,
                "heading_source": heading, "bottom_lock": bool(bottom_lock),
                "gps_sigma_m": sigma, **{k: int(v) for k, v in self.counts.items()}}
