"""The pose of the body origin at given times from every instrument record: the DVL's
velocities and attitude carry the ping-to-ping geometry, GPS and the DVL's altitude only
bound its slow drift (``docs/navigation.md``, "Fusion").

Three independent two-state Kalman filters (:mod:`svss_daq.nav.kalman`) run on the grid
of DVL sample times, one per NED axis of the DVL head's position:

* north and east: (head position, DVL velocity bias); the DVL velocity rotated to NED
  (roll and pitch from the DVL, heading from the heading sources) is the process, the
  trapezoid of consecutive samples its displacement, noise ``dvl_velocity_sigma_m_s``
  per sample; the bias is first-order Gauss-Markov (``dvl_velocity_bias_sigma_m_s``,
  ``dvl_bias_correlation_s``). GPS fixes are measurements of the antenna, moved to the
  head through the lever arms and to the grid point before them with the DVL's
  velocity; noise per axis GST sigma / sqrt(2), else ``gps_sigma_m``.
* down: (head depth, the bed's depth under the head, the bed's gradient north and east):
  the bed a plane about the head that the head moves over. Process: the DVL's vertical
  velocity for the head; for the bed's depth, the gradient times the head's horizontal
  displacement plus a random walk (``bottom_depth_rate_sigma_m_s``); for the gradient,
  a random walk per metre travelled (``bottom_slope_sigma_per_m``); where ranges return
  after more than ``dvl_max_gap_s`` without any, a new bed (depth and gradient free).
  Measurements: each beam's footprint below the head, bed depth minus head depth plus
  the gradient times the footprint's horizontal offset (noise ``dvl_range_sigma_m``;
  a sample whose footprints lie on no plausible plane is left out:
  :func:`~.dvl_geometry.plausible_bed`); with fewer than ``dvl_min_beams`` ranges the
  vertical beam's height; the GPS height where a fix has one (``gps_height_sigma_m``).
  The body's altitude is the bed's plane at the body, not at the head.

Without bottom lock the last velocity is held with ``dvl_gap_velocity_sigma_m_s`` of
uncertainty, so the GPS takes over. The RTS smoother gives each pose every record before
and after it (a recorded run, or the live navigator's history, which the acquisition
waits to reach ``fixed_lag_s`` past a ping); ``causal=True`` gives the filter alone.
Without a DVL, positions are interpolated between fixes.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_DVL_VELOCITY,
                           NAV_FUSED, NAV_GPS_FIX,
                           NAV_HEADING_FROM_COMPASS, NAV_HEADING_FROM_COURSE, NAV_HELD,
                           NAV_NO_HEADING, NavSnapshot)

from .dvl_geometry import _sample_altitude, level_footprints
from .geodesy import geodetic_to_ned, ned_to_geodetic
from .headings import _headings, _nearest_age, _rotations
from .kalman import filter_smooth, filter_smooth_n
from .records import DvlSample, GpsFix, HeadingSample

__all__ = ["attitude_poses", "compute_poses", "survey_origin", "prior_at"]

#: prior variance of a position the first measurement fixes, m^2 (100 m: any GPS wins)
_UNKNOWN_VAR_M2 = 1e4
#: prior variance of the body's depth without GPS heights (body at the origin's height), m^2
_NO_HEIGHT_VAR_M2 = 1.0
#: prior variance of the bed's gradient (per axis; 0.3: a slope of 17 deg), 1
_GRADIENT_VAR = 0.09
#: the lever arm's rate of turn is taken over +-0.5 s of attitude
ATTITUDE_RATE_HALF_WINDOW_S = 0.5
#: heading flags of _headings without a true heading: 1 course over ground, 2 none
_NO_TRUE_HEADING = (1, 2)
_HEADING_FLAG = {0: 0, 1: NAV_HEADING_FROM_COURSE, 2: NAV_NO_HEADING, 3: NAV_HEADING_FROM_COMPASS}


def prior_at(state: Optional[dict], time_ns: int) -> Optional[dict]:
    """The filter's state at the DVL sample of ``time_ns`` from a previous call's
    ``state_out`` (None where it has no sample at exactly that time)."""
    if not state or "time_ns" not in state:
        return None
    times = state["time_ns"]
    k = int(np.searchsorted(times, time_ns))
    if k >= times.size or int(times[k]) != int(time_ns):
        return None
    return {"time_ns": int(time_ns), **{ax: (state[ax][0][k].copy(), state[ax][1][k].copy())
                                        for ax in ("n", "e", "d")}}


def survey_origin(cfg, fixes: Sequence[GpsFix]) -> Optional[tuple[float, float, float]]:
    """The survey origin (lat deg, lon deg, h m): configured, else the first fix with a
    height (an RMC carries none), else the first fix at height 0; None without either."""
    if cfg.origin_latitude_deg is not None and cfg.origin_longitude_deg is not None:
        return (cfg.origin_latitude_deg, cfg.origin_longitude_deg, cfg.origin_height_m or 0.0)
    if not fixes:
        return None
    first = sorted(fixes, key=lambda f: f.time_ns)
    with_h = [f for f in first if math.isfinite(f.height_m)]
    f = with_h[0] if with_h else first[0]
    return (f.latitude_deg, f.longitude_deg, f.height_m if with_h else 0.0)


def _grid_model(td, v_ned, ok, cfg):
    """Per step of the DVL grid: the displacement (K-1, 3) the velocities integrate to,
    its variance, whether the DVL carried it, and the velocity to use at each grid
    point (the last good one held where a sample has none; (K, 3))."""
    k_n = td.size
    v_use = v_ned.copy()
    last = None
    first_ok = np.flatnonzero(ok)
    for k in range(k_n):
        if ok[k]:
            last = v_ned[k]
        else:
            v_use[k] = last if last is not None else (
                v_ned[first_ok[0]] if first_ok.size else np.zeros(3))
    dt = np.diff(td)
    both = ok[:-1] & ok[1:] & (dt <= cfg.dvl_max_gap_s)
    one = (ok[:-1] ^ ok[1:]) & (dt <= cfg.dvl_max_gap_s)
    carried = both | one
    disp = np.where(both[:, None], 0.5 * (v_use[:-1] + v_use[1:]) * dt[:, None],
                    np.where(ok[:-1, None], v_use[:-1], v_use[1:]) * dt[:, None])
    held = ~carried
    disp[held] = v_use[:-1][held] * dt[held, None]
    sig_v = cfg.dvl_velocity_sigma_m_s
    var = np.where(both, sig_v ** 2 * dt ** 2, 2.0 * sig_v ** 2 * dt ** 2)
    var = np.where(held, cfg.dvl_gap_velocity_sigma_m_s ** 2 * dt ** 2, var)
    return disp, var, carried, v_use


def _partial(t_m, td, v_use):
    """Grid point before each time ``t_m`` (clipped to the grid) and the displacement
    (.., 3) from it to ``t_m`` with the velocity linear between grid points."""
    k = np.clip(np.searchsorted(td, t_m, side="right") - 1, 0, td.size - 1)
    tau = t_m - td[k]
    k1 = np.minimum(k + 1, td.size - 1)
    span = td[k1] - td[k]
    slope = np.where((span > 0)[:, None], (v_use[k1] - v_use[k]) / np.where(span > 0, span, 1.0)[:, None], 0.0)
    inside = (tau >= 0) & (tau <= span)
    disp = v_use[k] * tau[:, None] + np.where(inside[:, None], 0.5 * slope * (tau ** 2)[:, None], 0.0)
    return k, tau, disp


def _attitude_of(dvl: Sequence[DvlSample], headings: Sequence[HeadingSample], cfg,
                 t0: int):
    """``attitude(t)`` for times ``t`` (s after ``t0`` ns): (roll, pitch, heading,
    heading flag) arrays; roll and pitch from the DVL's sensors (0 without a DVL),
    heading from the heading sources (HDT, the DVL compass, the course)."""
    td = (np.array([d.time_ns for d in dvl], dtype=np.int64) - t0).astype(np.float64) * 1e-9
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
    return attitude


def attitude_poses(times_ns, headings: Sequence[HeadingSample], dvl: Sequence[DvlSample],
                   cfg, flags: int = 0) -> list[NavSnapshot]:
    """Poses without a position (no survey origin, no GPS fix to take one from): NaN
    position, velocity and altitude, the attitude and heading the instruments give, and
    their heading flag (so a pose says its heading came from the compass, or that there
    is none)."""
    t_ns = np.asarray(times_ns, dtype=np.int64).reshape(-1)
    if t_ns.size == 0:
        return []
    dvl = sorted(dvl, key=lambda d: d.time_ns)
    t0 = int(t_ns.min())
    r, p, h, hflag = _attitude_of(dvl, headings, cfg, t0)(
        (t_ns - t0).astype(np.float64) * 1e-9)
    nan = math.nan
    return [NavSnapshot(int(t), nan, nan, nan, nan, nan, nan, float(ri), float(pi),
                        float(hi), nan, quality=_HEADING_FLAG[int(f)] | flags)
            for t, ri, pi, hi, f in zip(t_ns, r, p, h, hflag)]


def compute_poses(times_ns, fixes: Sequence[GpsFix], headings: Sequence[HeadingSample],
                  dvl: Sequence[DvlSample], cfg, lever_arms,
                  origin: Optional[tuple[float, float, float]] = None, *,
                  causal: bool = False, flags: int = 0, prior: Optional[dict] = None,
                  state_out: Optional[dict] = None) -> list[NavSnapshot]:
    """The pose of the body origin at each of ``times_ns``.

    ``cfg``: :class:`~svss_daq.config.NavigationConfig`; ``lever_arms``:
    :class:`~svss_daq.config.LeverArms`; ``origin`` (lat deg, lon deg, h m) overrides the
    survey origin (:func:`survey_origin`). ``causal``: the Kalman filter's estimate (the
    records before each time only, as a live system without lag) instead of the RTS
    smoother's; ``flags``: quality bits added to every pose (e.g. NAV_SMOOTHED).

    A sliding window (the live navigator) carries what it dropped in ``prior``: the
    filter's state at the first DVL sample before that sample's measurements, as
    ``state_out`` of the previous call gave it (``state_out``, a dict, receives the
    filter's predicted state and covariance per axis at every DVL sample: keys
    ``time_ns``, ``n``, ``e``, ``d``; see :func:`prior_at`). Without a dropped record
    the prior is the previous call's own, so a window that did not move poses alike.
    """
    t_ns = np.asarray(times_ns, dtype=np.int64).reshape(-1)
    if t_ns.size == 0:
        return []
    fixes = sorted(fixes, key=lambda f: f.time_ns)
    dvl = sorted(dvl, key=lambda d: d.time_ns)
    t0 = int(t_ns.min())  # times relative to this, s (float64 keeps ns resolution)
    sec = lambda a: (np.asarray(a, dtype=np.int64) - t0).astype(np.float64) * 1e-9  # noqa: E731
    t = sec(t_ns)
    configured = cfg.origin_latitude_deg is not None and cfg.origin_longitude_deg is not None
    if origin is None:
        origin = survey_origin(cfg, fixes)
    if origin is None:
        raise ValueError("navigation: no survey origin configured "
                         "(navigation.origin_latitude_deg) and no GPS fix to take it from")
    r_gps = np.asarray(lever_arms.gps_antenna_m, dtype=np.float64)
    r_dvl = np.asarray(lever_arms.dvl_m, dtype=np.float64)
    beam = math.radians(cfg.dvl_beam_angle_deg)

    # attitude: roll and pitch from the DVL's sensors, heading from the heading sources
    td = sec([d.time_ns for d in dvl]) if dvl else np.zeros(0)
    attitude = _attitude_of(dvl, headings, cfg, t0)

    # GPS: antenna positions at the fixes, their noise
    tf = sec([f.time_ns for f in fixes]) if fixes else np.zeros(0)
    has_h = np.array([math.isfinite(f.height_m) for f in fixes], dtype=bool)
    if fixes:
        hgt = np.array([f.height_m if math.isfinite(f.height_m) else origin[2] for f in fixes])
        ant = geodetic_to_ned(np.array([f.latitude_deg for f in fixes]),
                              np.array([f.longitude_deg for f in fixes]), hgt, origin)
        att_f = attitude(tf)
        rot_f = _rotations(*att_f[:3])
        sig = np.array([f.sigma_m / math.sqrt(2.0) if math.isfinite(f.sigma_m) and f.sigma_m > 0
                        else cfg.gps_sigma_m for f in fixes])
        # without a true heading the lever arm to the antenna is unknown in azimuth
        arm = float(np.hypot(*(r_gps - r_dvl)[:2]))
        sig = np.where(np.isin(att_f[3], _NO_TRUE_HEADING), np.hypot(sig, arm), sig)
    else:
        ant, rot_f, sig = np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0)

    n = t.size
    r, p, h, hflag = attitude(t)
    rot_t = _rotations(r, p, h)
    near_fix = _nearest_age(tf, t) <= cfg.gps_fix_max_age_s
    if td.size:
        pos, vel, alt, dr, held = _fused(t, td, dvl, attitude, tf, ant, rot_f, sig, has_h,
                                         rot_t, r_gps, r_dvl, beam, cfg, configured, causal,
                                         prior, state_out)
    else:
        pos, vel, alt, dr = (np.full((n, 3), np.nan), np.full((n, 3), np.nan),
                             np.full(n, np.nan), np.zeros(n, dtype=bool))
        held = np.zeros(n, dtype=bool)
    # GPS alone where the DVL grid does not reach (no DVL, or beyond it by more than a gap)
    gps_only = ~np.all(np.isfinite(pos), axis=1) & (tf.size > 0)
    if gps_only.any():
        pos_f = ant - np.einsum("kij,j->ki", rot_f, r_gps)
        pos[gps_only] = np.stack([np.interp(t[gps_only], tf, pos_f[:, j]) for j in range(3)], -1)
        held[gps_only] = ((t[gps_only] > tf[-1]) | (t[gps_only] < tf[0])
                          | ~near_fix[gps_only])   # interpolated across an outage
        if tf.size >= 2:
            vf = np.stack([np.gradient(pos_f[:, j], tf) for j in range(3)], -1)
            vel[gps_only] = np.stack([np.interp(t[gps_only], tf, vf[:, j]) for j in range(3)], -1)
    fused = ~gps_only & np.all(np.isfinite(pos), axis=1)

    lat, lon, _ = ned_to_geodetic(pos, origin)
    out = []
    for k in range(n):
        q = flags
        if np.all(np.isfinite(pos[k])):
            if near_fix[k]:
                q |= NAV_GPS_FIX
            elif dr[k]:
                q |= NAV_DEAD_RECKONED
            if held[k]:
                q |= NAV_HELD
            if fused[k]:
                q |= NAV_FUSED
                if dr[k]:
                    q |= NAV_DVL_VELOCITY
        if np.isfinite(alt[k]):
            q |= NAV_BOTTOM_LOCK
        q |= _HEADING_FLAG[int(hflag[k])]
        out.append(NavSnapshot(int(t_ns[k]), float(pos[k, 0]), float(pos[k, 1]), float(pos[k, 2]),
                               float(vel[k, 0]), float(vel[k, 1]), float(vel[k, 2]),
                               float(r[k]), float(p[k]), float(h[k]), float(alt[k]),
                               float(lat[k]), float(lon[k]), q))
    return out


def _down_states(dvl, heading_d, head_h, disp, var, td, m_gps, z_gps, r_gps_var, prior,
                 beam, cfg, causal, state_out):
    """The down axis's states (K, 4): head depth, bed depth under the head, the bed's
    gradient north and east (module docstring), smoothed or (``causal``) filtered;
    ``heading_d``: the heading at each sample (rad), ``td``: the samples' times (s)."""
    k_n = len(dvl)
    steps, rows, zs, rs = [m_gps], [np.tile([1.0, 0.0, 0.0, 0.0], (m_gps.size, 1))], \
        [z_gps], [r_gps_var]
    r_beam = cfg.dvl_range_sigma_m ** 2
    seen = np.zeros(k_n, dtype=bool)          # samples whose ranges measured the bed
    for k, d in enumerate(dvl):
        level = level_footprints(d, beam, cfg.dvl_min_beams, cfg.bottom_max_slope_deg,
                                 cfg.dvl_range_sigma_m)
        if level is None:
            if math.isfinite(head_h[k]):                  # the vertical beam, under the head
                seen[k] = True
                steps.append(np.array([k]))
                rows.append(np.array([[-1.0, 1.0, 0.0, 0.0]]))
                zs.append(np.array([head_h[k]]))
                rs.append(np.array([r_beam]))
            continue
        if not len(level):                                # a beam off the bed: left out
            continue
        ch, sh = math.cos(heading_d[k]), math.sin(heading_d[k])
        north = ch * level[:, 0] - sh * level[:, 1]       # footprints about the head, NED
        east = sh * level[:, 0] + ch * level[:, 1]
        steps.append(np.full(len(level), k))
        rows.append(np.stack([-np.ones(len(level)), np.ones(len(level)), north, east], -1))
        zs.append(level[:, 2])
        rs.append(np.full(len(level), r_beam))
        seen[k] = True
    dt = np.diff(td)
    f = np.tile(np.eye(4), (k_n - 1, 1, 1))
    f[:, 1, 2], f[:, 1, 3] = disp[:, 0], disp[:, 1]
    q = np.zeros((k_n - 1, 4, 4))
    q[:, 0, 0] = var
    travelled = np.hypot(disp[:, 0], disp[:, 1])
    q[:, 1, 1] = cfg.bottom_depth_rate_sigma_m_s ** 2 * dt
    q[:, 2, 2] = q[:, 3, 3] = cfg.bottom_slope_sigma_per_m ** 2 * travelled
    # ranges again after more than a gap without: the bed under the boat is a new bed,
    # its depth and gradient free (a stale bed held the head's depth against the GPS
    # heights: 4 m off after RDI's recording lost the bottom for 8 minutes)
    last = np.maximum.accumulate(np.where(seen, np.arange(k_n), -1))
    before = np.concatenate([[-1], last[:-1]])
    stale = seen[1:] & ((before[1:] < 0)
                        | (td[1:] - td[np.maximum(before[1:], 0)] > cfg.dvl_max_gap_s))
    q[stale, 1, 1] = _UNKNOWN_VAR_M2
    q[stale, 2, 2] = q[stale, 3, 3] = _GRADIENT_VAR
    u = np.zeros((k_n - 1, 4))
    u[:, 0] = disp[:, 2]
    xs, _, xf, pf = filter_smooth_n(prior[0], prior[1], u, f, q,
                                    (np.concatenate(steps).astype(np.int64),
                                     np.concatenate(rows), np.concatenate(zs),
                                     np.concatenate(rs)),
                                    smooth=not causal, predicted=True)
    if state_out is not None:
        state_out["d"] = (xf, pf)
    return xs


def _fused(t, td, dvl, attitude, tf, ant, rot_f, sig, has_h, rot_t, r_gps, r_dvl, beam, cfg,
           configured: bool, causal: bool, prior: Optional[dict], state_out: Optional[dict]):
    """Positions, velocities, altitudes and the dead-reckoned and held masks at times t
    from the Kalman fusion on the DVL grid (module docstring)."""
    k_n = td.size
    vb = np.array([d.velocity_body_m_s for d in dvl], dtype=np.float64)
    att_d = attitude(td)
    rot_d = _rotations(*att_d[:3])
    v_ned = np.einsum("kij,kj->ki", rot_d, vb)
    # a velocity carries the track only with a true heading to turn it (HDT, compass)
    ok = np.all(np.isfinite(v_ned), axis=1) & ~np.isin(att_d[3], _NO_TRUE_HEADING)
    head_h = np.array([_sample_altitude(d, beam, (0.0, 0.0, 0.0), cfg.dvl_min_beams) for d in dvl])
    disp, var, carried, v_use = _grid_model(td, v_ned, ok, cfg)
    dt = np.diff(td)
    lever_d = np.einsum("kij,j->ki", rot_d, r_dvl)          # head - body origin at the grid

    # GPS: the head's position at each fix, moved back to the grid point before it
    in_reach = (tf >= td[0] - cfg.dvl_max_gap_s) & (tf <= td[-1] + cfg.dvl_max_gap_s)
    head_f = ant - np.einsum("kij,j->ki", rot_f, r_gps - r_dvl)
    kf, tau, part = _partial(tf, td, v_use)
    z_f = head_f - part
    r_extra = (cfg.dvl_velocity_sigma_m_s * tau) ** 2
    use = in_reach

    # priors at the first grid point
    have_fix = bool(use.any())
    if have_fix:
        j0 = int(np.flatnonzero(use)[0])
        x_ne = z_f[j0, :2] - disp[:kf[j0], :2].sum(axis=0)
        p_ne = _UNKNOWN_VAR_M2
    else:  # dead reckoning from the configured origin: the body there at the first sample
        x_ne = lever_d[0, :2]
        p_ne = 0.0 if configured else _UNKNOWN_VAR_M2
    use_h = use & has_h
    if use_h.any():
        j0 = int(np.flatnonzero(use_h)[0])
        x_d, p_d = z_f[j0, 2] - disp[:kf[j0], 2].sum(), _UNKNOWN_VAR_M2
    else:
        x_d, p_d = lever_d[0, 2], _NO_HEIGHT_VAR_M2
    good_h = np.flatnonzero(np.isfinite(head_h))
    z_b0 = x_d + (head_h[good_h[0]] if good_h.size else 0.0)
    priors = {"n": (np.array([x_ne[0], 0.0]), np.diag([p_ne, cfg.dvl_velocity_bias_sigma_m_s ** 2])),
              "e": (np.array([x_ne[1], 0.0]), np.diag([p_ne, cfg.dvl_velocity_bias_sigma_m_s ** 2])),
              "d": (np.array([x_d, z_b0, 0.0, 0.0]),
                    np.diag([p_d, _UNKNOWN_VAR_M2, _GRADIENT_VAR, _GRADIENT_VAR]))}
    td_ns = np.array([d.time_ns for d in dvl], dtype=np.int64)
    if prior is not None and int(prior["time_ns"]) == int(td_ns[0]):
        # what a window dropped: the state before its first sample's measurements, from
        # every earlier record (fixes before that sample are in it already)
        priors = {ax: prior[ax] for ax in ("n", "e", "d")}
        use = use & (tf >= td[0])
        use_h = use & has_h

    # north and east: (head position, velocity bias)
    a = np.exp(-dt / cfg.dvl_bias_correlation_s)
    sb2 = cfg.dvl_velocity_bias_sigma_m_s ** 2
    f01 = np.where(carried, dt, 0.0)
    qc = sb2 * (1.0 - a * a)
    states = []
    for ax, name in ((0, "n"), (1, "e")):
        m = (kf[use], np.ones(use.sum()), np.zeros(use.sum()), z_f[use, ax],
             sig[use] ** 2 + r_extra[use])
        xs, _, xf, pf = filter_smooth(*priors[name], disp[:, ax], f01, a, var, qc, m,
                                      smooth=not causal, predicted=True)
        states.append(xs)
        if state_out is not None:
            state_out[name] = (xf, pf)
    # down: (head depth, bed depth under the head, bed gradient north, east)
    alt_ok = np.isfinite(head_h)
    xs_d = _down_states(dvl, att_d[2], head_h, disp, var, td, kf[use_h],
                        z_f[use_h, 2], cfg.gps_height_sigma_m ** 2 + r_extra[use_h],
                        priors["d"], beam, cfg, causal, state_out)
    if state_out is not None:
        state_out["time_ns"] = td_ns
    head = np.stack([states[0][:, 0], states[1][:, 0], xs_d[:, 0]], -1)
    bias = np.stack([states[0][:, 1], states[1][:, 1], np.zeros(k_n)], -1)
    bottom = xs_d[:, 1]
    grad = xs_d[:, 2:4]

    # the head at each time t: the grid states and the DVL's displacement between them
    k, tau, part = _partial(t, td, v_use)
    k1 = np.minimum(k + 1, k_n - 1)
    span = np.where(k1 > k, td[k1] - td[k], 1.0)
    frac = np.clip(np.where(k1 > k, tau / span, 0.0), 0.0, 1.0)
    # what the states add to the DVL's own displacement over the step (the smoother's
    # correction), spread linearly over it
    drift = head[k1] - head[k] - (0.5 * (v_use[k] + v_use[k1]) + bias[k]) * span[:, None]
    beyond = (t > td[-1]) | (t < td[0])
    h_t = head[k] + part + bias[k] * tau[:, None] + np.where(beyond[:, None], 0.0,
                                                             frac[:, None] * drift)
    pos = h_t - np.einsum("kij,j->ki", rot_t, r_dvl)
    # the body origin's velocity: the head's less the rate of the rotated lever arm
    eps = ATTITUDE_RATE_HALF_WINDOW_S
    rate = (np.einsum("kij,j->ki", _rotations(*attitude(t + eps)[:3]), r_dvl)
            - np.einsum("kij,j->ki", _rotations(*attitude(t - eps)[:3]), r_dvl)) / (2 * eps)
    vel = v_use[k] + bias[k] - rate
    # the bed under the body origin: the plane about the head, at the body's offset
    b_t = np.interp(t, td, bottom)
    to_body = -np.einsum("kij,j->ki", rot_t, r_dvl)[:, :2]
    b_t = b_t + np.interp(t, td, grad[:, 0]) * to_body[:, 0] \
        + np.interp(t, td, grad[:, 1]) * to_body[:, 1]
    near_alt = _nearest_age(td[alt_ok], t) <= cfg.dvl_max_gap_s
    alt = np.where(near_alt, b_t - pos[:, 2], np.nan)
    near_lock = _nearest_age(td[ok], t) <= cfg.dvl_max_gap_s
    near_fix = _nearest_age(tf, t) <= cfg.gps_fix_max_age_s
    far = (t > td[-1] + cfg.dvl_max_gap_s) | (t < td[0] - cfg.dvl_max_gap_s)
    # held: past the last DVL sample (extrapolated), before the first one without a fix
    # near, or with neither bottom lock nor a fix near (the velocity held)
    held = (t > td[-1]) | ((t < td[0]) & ~near_fix) | (~near_lock & ~near_fix)
    if tf.size:  # no bottom lock within a gap: GPS interpolation where fixes reach
        covered = (far | ~near_lock) & (t >= tf[0] - cfg.gps_fix_max_age_s) \
            & (t <= tf[-1] + cfg.gps_fix_max_age_s)
        pos[covered] = np.nan
    return pos, vel, alt, near_lock & ~beyond, held
