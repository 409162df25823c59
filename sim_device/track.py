"""The simulated platform track: the true pose of every ping (nominal straight line plus
optional sinusoidal motion; the navigation reports this truth)."""

from __future__ import annotations

from datetime import datetime

import numpy as np

from svss_daq.config import HardwareConfig
from svss_daq.frames import TrackLine
from svss_daq.ping import NAV_SIMULATED, NavSnapshot

from .scene import TrackConfig


def parse_utc_ns(text: str) -> int:
    """ISO 8601 UTC time ('2026-11-22T12:00:00Z') to int64 ns since the Unix epoch."""
    try:
        dt = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"track.start_time_utc: {text!r} is not an ISO 8601 time") from None
    if dt.utcoffset() is None:
        raise ValueError(f"track.start_time_utc: {text!r} has no time zone; expected UTC ('Z')")
    seconds = int(dt.timestamp())
    return seconds * 1_000_000_000 + dt.microsecond * 1000


def truth_line(track: TrackConfig) -> TrackLine:
    """The scene's own tile frame: first ping's body origin, track heading, nominal bottom."""
    return TrackLine((track.start_ne_m[0], track.start_ne_m[1]),
                     np.deg2rad(track.heading_deg), track.body_down_m + track.altitude_m)


def motion_phases(seed: int) -> np.ndarray:
    """Phases (rad) of heave, sway, roll, pitch and yaw, drawn from the scene seed."""
    return np.random.default_rng([seed, 0x6D6F74]).uniform(0.0, 2.0 * np.pi, 5)


def motion_at(track: TrackConfig, seed: int, t_s: float) -> dict[str, float]:
    """Platform motion about the nominal track at time ``t_s`` (s from the first ping):
    heave (m, down), sway (m, starboard), roll, pitch, yaw (rad) and the heave and sway
    rates (m/s). All zero without ``track.motion``."""
    m = track.motion
    if m is None:
        return dict(heave=0.0, sway=0.0, roll=0.0, pitch=0.0, yaw=0.0, heave_rate=0.0,
                    sway_rate=0.0)
    ph = motion_phases(seed)
    amps = (m.heave_m, m.sway_m, np.deg2rad(m.roll_deg), np.deg2rad(m.pitch_deg),
            np.deg2rad(m.yaw_deg))
    periods = (m.heave_period_s, m.sway_period_s, m.roll_period_s, m.pitch_period_s,
               m.yaw_period_s)
    w = [2.0 * np.pi / p for p in periods]
    val = [a * np.sin(wk * t_s + p) for a, wk, p in zip(amps, w, ph)]
    rate = [a * wk * np.cos(wk * t_s + p) for a, wk, p in zip(amps, w, ph)]
    return dict(heave=float(val[0]), sway=float(val[1]), roll=float(val[2]),
                pitch=float(val[3]), yaw=float(val[4]), heave_rate=float(rate[0]),
                sway_rate=float(rate[1]))


def pose_at(track: TrackConfig, t_s: float, seed: int = 0) -> NavSnapshot:
    """True pose at ``t_s`` seconds after the track's start time: a straight track at
    constant speed, plus the scene's platform motion if any (its phases drawn from
    ``seed``, the scene seed). Defined for any time, between pings too (the simulated
    navigation instruments sample it)."""
    h = np.deg2rad(track.heading_deg)
    s = t_s * track.speed_m_s
    t_ns = parse_utc_ns(track.start_time_utc) + int(round(t_s * 1e9))
    mo = motion_at(track, seed, t_s)
    sway = mo["sway"]
    return NavSnapshot(
        time_ns=t_ns,
        north_m=track.start_ne_m[0] + s * np.cos(h) - sway * np.sin(h),
        east_m=track.start_ne_m[1] + s * np.sin(h) + sway * np.cos(h),
        down_m=track.body_down_m + mo["heave"],
        vel_north_m_s=track.speed_m_s * np.cos(h) - mo["sway_rate"] * np.sin(h),
        vel_east_m_s=track.speed_m_s * np.sin(h) + mo["sway_rate"] * np.cos(h),
        vel_down_m_s=mo["heave_rate"], roll_rad=mo["roll"], pitch_rad=mo["pitch"],
        heading_rad=float(h + mo["yaw"]), altitude_m=track.altitude_m - mo["heave"],
        quality=NAV_SIMULATED)


def ping_pose(track: TrackConfig, hw: HardwareConfig, i: int, seed: int = 0) -> NavSnapshot:
    """True pose of ping ``i`` (pings every ``sequencer.ping_interval_s`` from the
    track's start time): :func:`pose_at` at its transmit time."""
    return pose_at(track, i * hw.sequencer.ping_interval_s, seed)
