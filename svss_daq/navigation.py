"""Navigation: the pose of the body origin at any time (e.g. every ping's transmit time).

Inputs are GPS fixes (geodetic, of the antenna), headings (NMEA HDT, or RMC course over
ground as a flagged fallback), and DVL samples (bottom-track velocity of the DVL head in
the body frame, slant ranges of the four Janus beams, roll and pitch). Output:
:class:`svss_daq.ping.NavSnapshot` per requested time.

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
  absolute position of the GPS, and runs on the DVL alone through a GPS outage.
  Without DVL, positions are interpolated linearly between fixes.
* Altitude above the bottom: mean over valid beams of range x (vertical component of
  the beam direction rotated by roll and pitch), plus the DVL head's depth below the body
  origin. Janus beams at ``dvl_beam_angle_deg`` from the vertical: beam 1 starboard,
  2 port, 3 forward, 4 aft (RDI convention with beam 3 on the bow).

Angles in radians, distances m, times int ns since the Unix epoch UTC.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Iterable, Optional, Sequence

import numpy as np

from svss_daq.frames import body_to_ned
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COURSE, NAV_NO_HEADING, NavSnapshot)

__all__ = [
    "WGS84_A", "WGS84_F", "NAV_HEADING_FROM_COURSE", "NAV_NO_HEADING", "GpsFix",
    "HeadingSample", "DvlSample", "geodetic_to_ecef", "ecef_to_geodetic", "ned_rotation",
    "geodetic_to_ned", "ned_to_geodetic", "janus_beam_vectors", "altitude_from_ranges",
    "dvl_sample_from_pd0", "samples_from_nmea", "compute_poses", "Navigator",
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
    slant ranges of beams 1-4 (m, NaN where no bottom), roll and pitch (rad)."""
    time_ns: int
    velocity_body_m_s: tuple[float, float, float]
    ranges_m: tuple[float, float, float, float]
    roll_rad: float = 0.0
    pitch_rad: float = 0.0


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
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    h = p / np.cos(lat) - n
    return np.degrees(lat), np.degrees(lon), h


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


def janus_beam_vectors(beam_angle_rad: float) -> np.ndarray:
    """Unit vectors (4, 3) of beams 1-4 in the body frame (down-looking DVL, beam 3 forward):
    1 starboard, 2 port, 3 forward, 4 aft, each ``beam_angle_rad`` from the vertical."""
    s, c = math.sin(beam_angle_rad), math.cos(beam_angle_rad)
    return np.array([[0.0, s, c], [0.0, -s, c], [s, 0.0, c], [-s, 0.0, c]])


def altitude_from_ranges(ranges_m, roll_rad: float, pitch_rad: float, beam_angle_rad: float,
                         dvl_lever_m, min_beams: int = 3) -> float:
    """Height of the body origin above a flat bottom from DVL slant ranges, m (NaN with
    fewer than ``min_beams`` valid ranges). Heading does not matter."""
    r = np.asarray(ranges_m, dtype=np.float64)
    ok = np.isfinite(r) & (r > 0)
    if ok.sum() < min_beams:
        return float("nan")
    rot = body_to_ned(roll_rad, pitch_rad, 0.0)
    vert = (janus_beam_vectors(beam_angle_rad) @ rot.T)[:, 2]
    below_head = float(np.mean(r[ok] * vert[ok]))
    return below_head + float((rot @ np.asarray(dvl_lever_m, dtype=np.float64))[2])


def dvl_sample_from_pd0(ens) -> Optional[DvlSample]:
    """A :class:`DvlSample` from a decoded PD0 ensemble (``svss_daq.drivers.pd0``).

    Bottom-track velocity is RDI's velocity of the bottom relative to the instrument,
    so the head's velocity is its negative. Supported coordinate systems: ``ship`` (X
    starboard, Y forward, Z up, mapped to body x = Y, y = X, z = -Z) and ``earth``
    (east, north, up: rotated back into the body frame with the ensemble's heading,
    pitch and roll). Returns None without a time or bottom track.
    """
    bt = ens.bottom_track
    t = ens.variable.time_ns
    if bt is None or t is None:
        return None
    roll, pitch = float(ens.variable.roll_rad), float(ens.variable.pitch_rad)
    v = -np.asarray(bt.velocity_mps[:3], dtype=np.float64)
    cs = ens.fixed.coordinate_system
    if cs == "ship":
        body = np.array([v[1], v[0], -v[2]])
    elif cs == "earth":
        ned = np.array([v[1], v[0], -v[2]])
        body = body_to_ned(roll, pitch, float(ens.variable.heading_rad)).T @ ned
    else:
        raise ValueError(f"PD0 ensemble {ens.variable.ensemble_number}: bottom-track "
                         f"coordinate system {cs!r}; expected 'ship' or 'earth'")
    rng = np.full(4, np.nan)
    rr = np.asarray(bt.range_m, dtype=np.float64)[:4]
    rng[:len(rr)] = rr
    return DvlSample(int(t), tuple(float(x) for x in body), tuple(float(x) for x in rng),
                     roll, pitch)


def samples_from_nmea(records: Iterable, course_min_speed_m_s: float = 0.3
                      ) -> tuple[list[GpsFix], list[HeadingSample]]:
    """GPS fixes (GGA with a valid fix and a date; else valid RMC) and headings (HDT; RMC
    course above ``course_min_speed_m_s`` as a fallback) from NMEA records of
    ``svss_daq.drivers.nmea``. Records without ``time_ns`` are skipped (HDT has no time
    of its own: give ``(host_time_ns, record)`` pairs to stamp it)."""
    from svss_daq.drivers import nmea
    fixes, heads = [], []
    gga_times = set()
    pending_rmc = []
    for rec in records:
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
            if rec.fix_quality > 0 and rec.latitude_deg is not None and rec.longitude_deg is not None:
                h = float("nan")
                if rec.altitude_msl_m is not None:
                    h = rec.altitude_msl_m + (rec.geoid_separation_m or 0.0)
                fixes.append(GpsFix(t, rec.latitude_deg, rec.longitude_deg, h, rec.fix_quality))
                gga_times.add(t)
        elif isinstance(rec, nmea.RmcFix) and rec.valid:
            pending_rmc.append(rec)
    for rec in pending_rmc:
        if rec.time_ns not in gga_times and rec.latitude_deg is not None and rec.longitude_deg is not None:
            fixes.append(GpsFix(rec.time_ns, rec.latitude_deg, rec.longitude_deg, float("nan"), 1))
        if rec.course_rad is not None and (rec.speed_mps or 0.0) > course_min_speed_m_s:
            heads.append(HeadingSample(rec.time_ns, float(rec.course_rad), from_course=True))
    fixes.sort(key=lambda f: f.time_ns)
    heads.sort(key=lambda h: h.time_ns)
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


def _headings(t: np.ndarray, heads: Sequence[HeadingSample], max_age_s: float, t0_ns: int):
    """Heading (rad) at times t (s after ``t0_ns``) and a flag: 0 HDT, 1 course, 2 none."""
    sec = lambda a: (np.asarray(a, dtype=np.int64) - t0_ns).astype(np.float64) * 1e-9  # noqa: E731
    th = sec([h.time_ns for h in heads if not h.from_course])
    ah = np.array([h.heading_rad for h in heads if not h.from_course], dtype=np.float64)
    tc = sec([h.time_ns for h in heads if h.from_course])
    ac = np.array([h.heading_rad for h in heads if h.from_course], dtype=np.float64)
    oh, oc = np.argsort(th), np.argsort(tc)
    th, ah, tc, ac = th[oh], ah[oh], tc[oc], ac[oc]
    use_h = _nearest_age(th, t) <= max_age_s
    use_c = ~use_h & (_nearest_age(tc, t) <= max_age_s)
    out = np.where(use_h, _interp_angle(th, ah, t), _interp_angle(tc, ac, t))
    flag = np.where(use_h, 0, np.where(use_c, 1, 2))
    return np.where(flag == 2, 0.0, out), flag


def _rotations(roll, pitch, heading) -> np.ndarray:
    return np.array([body_to_ned(r, p, h) for r, p, h in zip(roll, pitch, heading)]).reshape(-1, 3, 3)


def _smooth(t: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """Moving mean of rows of x over |t_i - t_k| <= window/2."""
    if window_s <= 0 or t.size < 2:
        return x
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


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

    def attitude(tt):
        if td.size:
            r, p = np.interp(tt, td, roll_d), np.interp(tt, td, pitch_d)
        else:
            r = p = np.zeros_like(tt)
        h, hflag = _headings(tt, headings, cfg.heading_max_age_s, t0)
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
        alt_d = np.array([altitude_from_ranges(d.ranges_m, d.roll_rad, d.pitch_rad, beam, r_dvl,
                                               cfg.dvl_min_beams) for d in dvl])
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
            off = _smooth(tfk, pos_f[fk] - d_at_f, cfg.gps_smoothing_s)
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
        q |= (NAV_HEADING_FROM_COURSE if hflag[k] == 1 else NAV_NO_HEADING if hflag[k] == 2 else 0)
        out.append(NavSnapshot(int(t_ns[k]), float(pos[k, 0]), float(pos[k, 1]), float(pos[k, 2]),
                               float(vel[k, 0]), float(vel[k, 1]), float(vel[k, 2]),
                               float(r[k]), float(p[k]), float(h[k]), float(alt[k]),
                               float(lat[k]), float(lon[k]), q))
    return out


class Navigator:
    """Collects GPS, heading and DVL samples and poses pings from them.

    ``add_nmea`` takes records (or ``(host_time_ns, record)`` pairs) from
    ``svss_daq.drivers.nmea``; ``add_pd0`` PD0 ensembles. ``poses(times_ns)`` calls
    :func:`compute_poses` on everything collected (kept for ``history_s``).
    """

    def __init__(self, cfg, lever_arms, history_s: float = 600.0) -> None:
        self.cfg, self.lever_arms, self.history_ns = cfg, lever_arms, int(history_s * 1e9)
        self.fixes: list[GpsFix] = []
        self.headings: list[HeadingSample] = []
        self.dvl: list[DvlSample] = []
        self.origin: Optional[tuple[float, float, float]] = None

    def add_fix(self, f: GpsFix) -> None:
        if self.origin is None and self.cfg.origin_latitude_deg is None:
            self.origin = (f.latitude_deg, f.longitude_deg, 0.0 if math.isnan(f.height_m) else f.height_m)
            logger.info("navigation: survey origin set to the first fix %.8f, %.8f",
                        f.latitude_deg, f.longitude_deg)
        self.fixes.append(f)

    def add_nmea(self, records: Iterable) -> None:
        fixes, heads = samples_from_nmea(records, self.cfg.course_min_speed_m_s)
        for f in fixes:
            self.add_fix(f)
        self.headings += heads

    def add_pd0(self, ensemble) -> None:
        d = dvl_sample_from_pd0(ensemble)
        if d is not None:
            self.dvl.append(d)

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
