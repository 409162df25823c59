"""The seabed's interface as one surface of the tile frame: level, a tilted plane
(:mod:`sim_device.bed_plane`), and either undulating about it
(:mod:`sim_device.bed_undulation`). What needs only where the bed is, not how sound
crosses it, asks this: the platform's altitude, the DVL's beams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .bed_plane import BedPlane
from .bed_undulation import Undulation, ray_hit

_LEVEL = BedPlane.from_slopes(0.0, 0.0)


@dataclass(frozen=True)
class BedSurface:
    """The interface of a scene's tile frame (z down from the interface's level at the
    first ping): ``plane`` (None: level) and ``undulation`` about it (None: none)."""
    plane: BedPlane | None = None
    undulation: Undulation | None = None

    def _bed(self) -> BedPlane:
        return self.plane if self.plane is not None else _LEVEL

    def hit(self, origin, direction) -> float:
        """Distance (m) from the tile-frame point ``origin`` (above the bed) along the
        unit ``direction`` to the bed; NaN where the ray never meets it."""
        bed = self._bed()
        o = bed.to_bed(np.asarray(origin, dtype=np.float64))
        d = bed.vector_to_bed(np.asarray(direction, dtype=np.float64))
        if self.undulation is None:
            return float(-o[2] / d[2]) if d[2] > 0.0 else math.nan
        und = self.undulation
        step = min(0.05 * und.shortest_wavelength, 0.1 * max(und.amplitude_bound, 1e-3))
        return float(ray_hit(o[0], o[1], o[2], d[0], d[1], d[2], und.rows,
                             und.amplitude_bound, step))

    def vertical_height(self, p) -> float:
        """Vertical height (m) of the tile-frame point ``p`` above the bed below it."""
        return self.hit(p, (0.0, 0.0, 1.0))


def ned_beam_ranges(surface: BedSurface, line):
    """A function (head, directions) -> slant ranges (m) from the survey-frame point
    ``head`` (north, east, down) along unit ``directions`` (n, 3) to the bed (NaN: no
    hit), for the tile frame of ``line`` (a :class:`~svss_daq.frames.TrackLine`)."""
    def ranges(head: np.ndarray, directions: np.ndarray) -> np.ndarray:
        origin = line.ned_to_tile(np.asarray(head, dtype=np.float64))
        turned = np.asarray(directions, dtype=np.float64) @ line.rotation_from_ned().T
        return np.array([surface.hit(origin, d) for d in turned])
    return ranges
