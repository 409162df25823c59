"""The tile grid: voxel centres in the tile frame (along, cross, depth), m."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svss_daq.config import TileConfig


@dataclass(frozen=True)
class TileGrid:
    """Voxel-centre axes of tile ``index``: along-track covers
    [index * length, (index + 1) * length), cross-track is centred on the line, depth
    starts at ``top`` below the interface (of each column: ``surface``)."""
    index: int
    along: np.ndarray
    cross: np.ndarray
    depth: np.ndarray
    #: (n_along, n_cross) the interface's depth at each column below the frame's level,
    #: m (None: level; :mod:`svss_proc.imaging.surface`)
    surface: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.along.size, self.cross.size, self.depth.size)

    @property
    def voxel_m(self) -> float:
        return float(self.along[1] - self.along[0]) if self.along.size > 1 else float("nan")


def n_voxels(extent_m: float, voxel_m: float) -> int:
    """Voxels along an axis (rounded to the nearest whole voxel)."""
    return max(1, int(math.floor(extent_m / voxel_m + 0.5)))


def tile_grid(cfg: TileConfig, index: int, shape=None) -> TileGrid:
    """Grid of tile ``index`` for the tile configuration ``cfg``, over an interface of
    ``shape`` (an :class:`~svss_proc.imaging.surface.InterfaceShape`; None: level)."""
    v = cfg.voxel_m
    na, nc, nd = (n_voxels(cfg.length_m, v), n_voxels(cfg.width_m, v),
                  n_voxels(cfg.depth_m, v))
    along = index * cfg.length_m + (np.arange(na) + 0.5) * v
    cross = -0.5 * nc * v + (np.arange(nc) + 0.5) * v
    depth = cfg.top_m + (np.arange(nd) + 0.5) * v
    return TileGrid(index, along, cross, depth,
                    None if shape is None else shape.grid(along, cross))


def tile_index(cfg: TileConfig, along_m: float) -> int:
    """Index of the tile holding along-track position ``along_m``: k with
    k * length <= along_m < (k + 1) * length in floating point (the quotient alone can
    round across a tile edge, e.g. -5e-324 / 2 = -0.0 gave tile 0)."""
    length = cfg.length_m
    k = math.floor(along_m / length)
    if k * length > along_m:
        k -= 1
    elif (k + 1) * length <= along_m:
        k += 1
    return int(k)


def kernel_voxels(kernel_m: tuple[float, float, float], voxel_m: float
                  ) -> tuple[int, int, int]:
    """A window's extent (along, cross, depth), m, as odd voxel counts (the background's
    median kernel; the seam planes a tile hands back): each extent is
    rounded to whole voxels and an even count is raised by one (1.2 m, 0.2 m, 0.1 m at
    2 cm voxels: 61 x 11 x 5)."""
    if voxel_m <= 0:
        raise ValueError(f"voxel size must be positive, got {voxel_m} m")
    out = []
    for ext in kernel_m:
        if ext < 0:
            raise ValueError(f"kernel extents must be non-negative, got {kernel_m} m")
        n = max(1, int(math.floor(ext / voxel_m + 0.5)))
        out.append(n if n % 2 else n + 1)
    return tuple(out)
