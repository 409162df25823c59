"""Coordinate frames: body (x fwd, y stbd, z down), survey (local north-east-down) and
tile (along-track, cross-track starboard positive, depth below the interface).

All angles in radians. One definition of each rotation, used by the simulator and the
imager alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def body_to_ned(roll: float, pitch: float, heading: float) -> np.ndarray:
    """Rotation matrix taking body-frame vectors to NED (ZYX Euler: heading, pitch, roll)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    ch, sh = np.cos(heading), np.sin(heading)
    rz = np.array([[ch, -sh, 0.0], [sh, ch, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class TrackLine:
    """The tile frame: a horizontal line in the survey frame plus the interface depth.

    ``origin_ne`` (m) and ``heading`` (rad from north) define along-track; cross-track is
    starboard of it; depth is measured down from ``interface_down`` (m, survey frame).
    """
    origin_ne: tuple[float, float]
    heading: float
    interface_down: float

    def ned_to_tile(self, ned: np.ndarray) -> np.ndarray:
        """Survey NED positions (..., 3) to tile (along, cross, depth), m."""
        ned = np.asarray(ned, dtype=np.float64)
        dn = ned[..., 0] - self.origin_ne[0]
        de = ned[..., 1] - self.origin_ne[1]
        ch, sh = np.cos(self.heading), np.sin(self.heading)
        return np.stack([dn * ch + de * sh, -dn * sh + de * ch,
                         ned[..., 2] - self.interface_down], axis=-1)

    def tile_to_ned(self, atd: np.ndarray) -> np.ndarray:
        """Tile (along, cross, depth) positions (..., 3) to survey NED, m."""
        atd = np.asarray(atd, dtype=np.float64)
        ch, sh = np.cos(self.heading), np.sin(self.heading)
        n = self.origin_ne[0] + atd[..., 0] * ch - atd[..., 1] * sh
        e = self.origin_ne[1] + atd[..., 0] * sh + atd[..., 1] * ch
        return np.stack([n, e, atd[..., 2] + self.interface_down], axis=-1)

    def rotation_from_ned(self) -> np.ndarray:
        """Matrix taking NED direction vectors to tile-frame direction vectors."""
        ch, sh = np.cos(self.heading), np.sin(self.heading)
        return np.array([[ch, sh, 0.0], [-sh, ch, 0.0], [0.0, 0.0, 1.0]])
