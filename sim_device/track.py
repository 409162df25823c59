"""The simulated platform track: the true pose of every ping."""

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


def ping_pose(track: TrackConfig, hw: HardwareConfig, i: int) -> NavSnapshot:
    """True pose of ping ``i`` on a straight, level track at constant speed."""
    dt = hw.sequencer.ping_interval_s
    h = np.deg2rad(track.heading_deg)
    s = i * dt * track.speed_m_s
    t_ns = parse_utc_ns(track.start_time_utc) + int(round(i * dt * 1e9))
    return NavSnapshot(
        time_ns=t_ns,
        north_m=track.start_ne_m[0] + s * np.cos(h), east_m=track.start_ne_m[1] + s * np.sin(h),
        down_m=track.body_down_m,
        vel_north_m_s=track.speed_m_s * np.cos(h), vel_east_m_s=track.speed_m_s * np.sin(h),
        vel_down_m_s=0.0, roll_rad=0.0, pitch_rad=0.0, heading_rad=float(h),
        altitude_m=track.altitude_m, quality=NAV_SIMULATED)
