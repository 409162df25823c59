"""The water-sediment interface as a surface under the tile: its depth at each voxel
column, below the level the array's heights are measured from.

A tile's voxel depths are below the interface *of their own column* (a buried object's
depth is what a crew digs), so on a sloping bed the grid follows the seabed. The kernels
refract each leg at the column's interface taken as level about the column (the depth
``surf[ia, ic]`` of :class:`~svss_proc.imaging.kernel_args.VoxelGeometry`): exact on a
level bed, and on a slope an approximation whose cost in depth and peak level
``benchmarks/bench_seabed.py`` measures against a simulator that refracts at the tilted
plane itself.

The shape is a plane through the tile frame's origin, ``[imaging] interface_slope_deg``
(along the track line, across it to starboard; positive where the bed deepens):

    s(a, c) = a tan(slope_along) + c tan(slope_across).

With ``[imaging] interface_relief_m`` the surface undulates about that plane: the
relief's depth below the plane at the nodes of a grid along and across the track line
(``interface_relief_origin_m``, ``interface_relief_step_m``), bilinear between them and
the edge's value beyond.

A ping's frame puts its interface level where its own altitude says the bed is, under
its body (:func:`level_offset`), so each ping's array is placed against the bed it
measured and the shape supplies the rest of the tile.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


#: the relief grids as arrays, by the identity of the configuration's tuple (hashing a
#: long line's thousands of nodes on every call would cost more than the look-up)
_ARRAYS: dict[int, tuple[tuple, np.ndarray]] = {}


def _relief_array(relief: tuple) -> np.ndarray:
    hit = _ARRAYS.get(id(relief))
    if hit is not None and hit[0] is relief:
        return hit[1]
    if len(_ARRAYS) >= 8:
        _ARRAYS.pop(next(iter(_ARRAYS)))
    arr = np.asarray(relief, dtype=np.float64)
    _ARRAYS[id(relief)] = (relief, arr)
    return arr


def bilinear(nodes: np.ndarray, origin, step, along, cross) -> np.ndarray:
    """``nodes`` (n_along, n_cross), the first at ``origin`` (along, cross) and spaced
    ``step``, interpolated bilinearly at (along, cross) (the edge's value beyond)."""
    a = np.clip((np.asarray(along, dtype=np.float64) - origin[0]) / step[0], 0.0,
                nodes.shape[0] - 1)
    c = np.clip((np.asarray(cross, dtype=np.float64) - origin[1]) / step[1], 0.0,
                nodes.shape[1] - 1)
    i = np.minimum(a.astype(np.int64), max(nodes.shape[0] - 2, 0))
    j = np.minimum(c.astype(np.int64), max(nodes.shape[1] - 2, 0))
    fa = a - i if nodes.shape[0] > 1 else np.zeros_like(a)
    fc = c - j if nodes.shape[1] > 1 else np.zeros_like(c)
    i1 = np.minimum(i + 1, nodes.shape[0] - 1)
    j1 = np.minimum(j + 1, nodes.shape[1] - 1)
    return ((1 - fa) * ((1 - fc) * nodes[i, j] + fc * nodes[i, j1])
            + fa * ((1 - fc) * nodes[i1, j] + fc * nodes[i1, j1]))


@dataclass(frozen=True)
class InterfaceShape:
    """The interface's depth below the tile frame's level, as a function of along-track
    ``a`` and cross-track ``c`` (tile frame, m): a plane of gradients ``grad_along``
    and ``grad_across`` (m of depth per m; the tangents of the slopes), and the
    ``relief`` below it (rows along, columns across; None: none) at nodes from
    ``relief_origin`` spaced ``relief_step`` (along, cross; m)."""
    grad_along: float = 0.0
    grad_across: float = 0.0
    relief: tuple | None = None
    relief_origin: tuple[float, float] = (0.0, 0.0)
    relief_step: tuple[float, float] = (0.25, 0.25)

    @classmethod
    def of(cls, imaging) -> "InterfaceShape":
        """From a processing configuration's ``[imaging]``."""
        slope = imaging.interface_slope_deg or (0.0, 0.0)
        relief = getattr(imaging, "interface_relief_m", None)
        return cls(math.tan(math.radians(slope[0])), math.tan(math.radians(slope[1])),
                   relief,
                   tuple(imaging.interface_relief_origin_m or (0.0, 0.0)),
                   tuple(imaging.interface_relief_step_m or (0.25, 0.25)))

    @property
    def level(self) -> bool:
        return self.grad_along == 0.0 and self.grad_across == 0.0 and self.relief is None

    @property
    def slope_deg(self) -> tuple[float, float]:
        return (math.degrees(math.atan(self.grad_along)),
                math.degrees(math.atan(self.grad_across)))

    def depth(self, along, cross):
        """The interface's depth (m) below the frame's level at (along, cross)."""
        plane = (self.grad_along * np.asarray(along, dtype=np.float64)
                 + self.grad_across * np.asarray(cross, dtype=np.float64))
        if self.relief is None:
            return plane
        return plane + bilinear(_relief_array(self.relief), self.relief_origin,
                                self.relief_step, along, cross)

    def grid(self, along: np.ndarray, cross: np.ndarray) -> np.ndarray | None:
        """The depth at every voxel column of axes ``along`` x ``cross`` (float64,
        (n_along, n_cross)); None on a level bed (the kernels' flat default)."""
        if self.level:
            return None
        return np.ascontiguousarray(self.depth(np.asarray(along)[:, None],
                                               np.asarray(cross)[None, :]))


def level_offset(shape: InterfaceShape, frame, north_m: float, east_m: float) -> float:
    """How far the interface under a body at (north, east) lies below the tile frame's
    level of ``frame`` (a :class:`~svss_daq.frames.TrackLine`), m: subtracted from the
    depth of the bed the ping measured there, it gives the level its frame puts the
    shape's zero at."""
    if shape.level:
        return 0.0
    along, cross, _ = frame.ned_to_tile(np.array([north_m, east_m, 0.0]))
    return float(shape.depth(along, cross))
