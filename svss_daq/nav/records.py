"""The navigation's instrument records: GPS fixes, headings and DVL samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


