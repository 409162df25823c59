"""A sloping seabed: the water-sediment interface as a tilted plane, simulated exactly by
working in the bed's own frame.

The scene's tile frame has x along the track, y to starboard and z down from the
interface's level at the first ping (``track.body_down_m + track.altitude_m`` below the
surface). A bed sloping ``slope_deg = (along, across)`` (positive where it deepens ahead
and to starboard) lies at

    z = s(x, y) = x tan(along) + y tan(across).

Refraction, transmission, attenuation and scattering at and below a plane depend only on
positions relative to the plane (sediment layers lie parallel to it), so the simulator
rotates each ping's array, the scene's targets and the element images into the *bed
frame*, whose z is the distance below the plane along its normal n, and runs its
level-bed physics there unchanged: every direct path and seabed bounce is exact. The sea
surface stays horizontal in the tile frame; the element images of the scatterer legs are
mirrored in it exactly (:meth:`BedPlane.mirror_surface`), while the coherent
multiples by way of the surface (``specular`` paths with an S) treat it as parallel to
the bed at the water depth, and an image leg's beam is looked up as for a level bed.

A target's or point's ``depth_m`` is its vertical depth below the interface above it
(what a crew digs): tile-frame z = s(x, y) + depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BedPlane:
    """The plane z = ga x + gc y of the tile frame (``ga``, ``gc``: tangents of the
    along- and across-track slopes) and the rotation ``rot`` (3, 3) taking tile-frame
    vectors into the bed frame (rows: the plane's along-track direction, the in-plane
    direction normal to it, the downward normal)."""
    ga: float
    gc: float
    rot: np.ndarray

    @classmethod
    def from_slopes(cls, along_deg: float, across_deg: float) -> "BedPlane":
        ga, gc = math.tan(math.radians(along_deg)), math.tan(math.radians(across_deg))
        n = np.array([-ga, -gc, 1.0]) / math.sqrt(1.0 + ga * ga + gc * gc)
        u = np.array([1.0, 0.0, ga]) / math.sqrt(1.0 + ga * ga)
        v = np.cross(n, u)
        return cls(ga, gc, np.array([u, v, n]))

    @property
    def level(self) -> bool:
        return self.ga == 0.0 and self.gc == 0.0

    def depth(self, x, y):
        """The interface's tile-frame z under (x, y), m."""
        return self.ga * np.asarray(x, dtype=np.float64) + self.gc * np.asarray(y, dtype=np.float64)

    def to_bed(self, p: np.ndarray) -> np.ndarray:
        """Tile-frame positions (..., 3) in the bed frame."""
        return np.asarray(p, dtype=np.float64) @ self.rot.T

    def vector_to_bed(self, v: np.ndarray) -> np.ndarray:
        """Tile-frame directions (..., 3) in the bed frame (the same rotation: the frames
        share their origin)."""
        return self.to_bed(v)

    def buried(self, along, cross, depth) -> np.ndarray:
        """Bed-frame positions (..., 3) of points ``depth`` m vertically below the
        interface at (along, cross)."""
        a, c, d = (np.asarray(v, dtype=np.float64) for v in (along, cross, depth))
        return self.to_bed(np.stack([a, c, self.depth(a, c) + d], axis=-1))

    def vertical_height(self, p_tile: np.ndarray) -> np.ndarray:
        """Vertical height (m) of tile-frame points (..., 3) above the interface."""
        p = np.asarray(p_tile, dtype=np.float64)
        return self.depth(p[..., 0], p[..., 1]) - p[..., 2]

    def mirror_surface(self, p_bed: np.ndarray, water_depth: float) -> np.ndarray:
        """Bed-frame positions (..., 3) mirrored in the sea surface (tile-frame
        z = -water_depth, horizontal)."""
        p = np.asarray(p_bed, dtype=np.float64)
        down = self.rot[:, 2]                       # the tile's down in the bed frame
        return p - 2.0 * (p @ down + water_depth)[..., None] * down


def mirror_bed(p_bed: np.ndarray) -> np.ndarray:
    """Bed-frame positions (..., 3) mirrored in the interface (bed-frame z = 0)."""
    p = np.array(p_bed, dtype=np.float64)
    p[..., 2] = -p[..., 2]
    return p


def leg_image_position(m: int, p_bed: np.ndarray, plane: BedPlane,
                       water_depth: float) -> np.ndarray:
    """The image (bed frame) of elements at ``p_bed`` (..., 3) for a leg with ``m``
    reflections: leaving the scatterer up, the leg meets the surface and the seabed
    alternately (S, B, S, ...), so the image is M_S(M_B(M_S(...(p)))) with m mirrors
    (:mod:`sim_device.multipath`; there in one dimension, here in three)."""
    p = np.asarray(p_bed, dtype=np.float64)
    for k in reversed(range(m)):
        p = plane.mirror_surface(p, water_depth) if k % 2 == 0 else mirror_bed(p)
    return p


def ned_plane(plane: BedPlane, line) -> tuple[float, float, float]:
    """The bed as down = k0 + kn north + ke east in the survey frame (m), for a plane of
    the tile frame of ``line`` (a :class:`~svss_daq.frames.TrackLine`, whose
    ``interface_down`` is the plane's level at its origin)."""
    ch, sh = math.cos(line.heading), math.sin(line.heading)
    kn = plane.ga * ch - plane.gc * sh
    ke = plane.ga * sh + plane.gc * ch
    n0, e0 = line.origin_ne
    return (float(line.interface_down - kn * n0 - ke * e0), float(kn), float(ke))
