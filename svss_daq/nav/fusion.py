"""The pose of the body origin at given times from every instrument record."""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE, NAV_NO_HEADING,
                           NavSnapshot)

from .dvl_geometry import _sample_altitude
from .geodesy import geodetic_to_ned, ned_to_geodetic
from .headings import _headings, _nearest_age, _rotations, _smooth, _fix_weights, wrap_angle
from .records import DvlSample, GpsFix, HeadingSample

YAW_RATE_HALF_WINDOW_S = 0.5

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
        yaw_rate = wrap_angle(h_b - h_a) / (2 * eps)
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


