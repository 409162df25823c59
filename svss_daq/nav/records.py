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
    """One DVL ensemble: the head's velocity over ground in the body frame (m/s, NaN: no
    bottom lock or no bottom track in the ensemble), the ranges along beams 1-4 (m, NaN
    where no bottom; slant ranges: RDI sends vertical ones, converted with the beam
    angle), roll and pitch (rad), the vertical beam's range along its axis (m, NaN:
    none) and the compass heading of the body x axis (rad, the instrument's heading less
    its heading alignment, declination applied; NaN: none). The head geometry it was
    made with: ``beam_angle_rad`` (the fixed leader's, else the configured one; NaN:
    unknown, the caller's configured angle applies), ``beam_alignment_rad`` (EA: beam
    3's azimuth clockwise from the body x axis) and ``beams_convex`` (beam pattern).
    An ensemble without bottom track still gives a sample: its attitude and heading."""
    time_ns: int
    velocity_body_m_s: tuple[float, float, float]
    ranges_m: tuple[float, float, float, float]
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    vertical_range_m: float = float("nan")
    heading_rad: float = float("nan")
    beam_angle_rad: float = float("nan")
    beam_alignment_rad: float = 0.0
    beams_convex: bool = True

    @property
    def bottom_lock(self) -> bool:
        return bool(np.all(np.isfinite(self.velocity_body_m_s)))
