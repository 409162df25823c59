"""A run's image at chosen points or small grids, made exactly as the tiles make it (the
imager's accumulator: its conditioner, geometry, refraction tables and kernel), for the
stages that probe an image without forming tiles: the autofocus
(:mod:`svss_proc.micronav.autofocus`) and the sediment-speed scan
(:mod:`svss_proc.seabed`)."""

from __future__ import annotations

import numpy as np

from svss_daq.frames import TrackLine
from svss_daq.geometry import place_array
from svss_daq.ping import Ping

from .kernel_args import ImageSlice, VoxelAxes, prepare
from .schedule import gated_reach, ping_frame
from .surface import InterfaceShape


class PointSampler:
    """Each ping's contribution at single points, with an imager's accumulator (its
    conditioner, geometry, tables and kernel), in the tile frame ``line``. ``prepared``:
    a cache of the pings' conditioned samples and tap planes to share with other samplers
    of the same conditioning, interpolation and precision (those of other sediment
    speeds: the sediment-speed scan conditions each ping once)."""

    def __init__(self, accumulator, processing, line: TrackLine,
                 prepared: dict | None = None):
        self.acc = accumulator
        self.proc = processing
        self.line = line
        self._kd: dict = {} if prepared is None else prepared

    def _prepared(self, p: Ping):
        """(conditioned, kernel data) of ping ``p``, once."""
        key = id(p.samples)
        if key not in self._kd:
            cond = self.acc.condition(p)
            self._kd[key] = (cond, prepare(cond, self.proc.imaging.interpolation,
                                           self.acc.dtype))
        return self._kd[key]

    def placed(self, p: Ping):
        """Ping ``p``'s array placed in the tile frame, and its along-track reach (m) as
        the tiles' schedule has it (:meth:`~svss_proc.imaging.schedule.TileSchedule.step`):
        the projector's beam to the tile's bottom with ``beam_gating``, else the echo
        window's range."""
        geo = self.acc.geometry
        placed = place_array(geo, p.nav, p.projector, ping_frame(self.line, p.nav, self.proc))
        im = self.proc.imaging
        if im.beam_gating:
            reach = gated_reach(placed.tx, placed.bore, geo.projector_half_angle, self.proc)
        else:
            reach = self._prepared(p)[0].axis.end_s * im.water_sound_speed_m_s / 2
        return placed, reach

    def reach(self, p: Ping) -> tuple[float, float]:
        """The projector's along-track position and reach (m) of ping ``p``."""
        placed, reach = self.placed(p)
        return float(placed.tx[0]), reach

    def _axes(self, along, cross, depth) -> VoxelAxes:
        """Voxel axes over the configured interface (depths below each column's)."""
        return VoxelAxes(along, cross, depth,
                         InterfaceShape.of(self.proc.imaging).grid(along, cross))

    def value(self, p: Ping, point: np.ndarray) -> complex:
        """Ping ``p``'s contribution at ``point`` (tile frame: along, cross, depth)."""
        im, acc = self.proc.imaging, self.acc
        placed, reach = self.placed(p)
        kd = self._prepared(p)[1]
        re_ = np.zeros((1, 1, 1), dtype=acc.dtype)
        im_ = np.zeros_like(re_)
        array, delays = acc.ping_inputs(placed.tx, placed.rx, placed.bore, reach)
        axes = self._axes(*(np.array([float(v)]) for v in point))
        acc.kernel(ImageSlice(re_, im_, axes, 0, 1), kd, array, delays,
                   gating=im.beam_gating)
        return complex(float(re_[0, 0, 0]), float(im_[0, 0, 0]))

    def grid(self, pings: list, along, cross, depth) -> np.ndarray:
        """The image of ``pings`` at the grid ``along x cross x depth`` (tile frame),
        complex, as the tiles image it."""
        im, acc = self.proc.imaging, self.acc
        along, cross, depth = (np.ascontiguousarray(x, dtype=np.float64)
                               for x in (along, cross, depth))
        re_ = np.zeros((along.size, cross.size, depth.size), dtype=acc.dtype)
        im_ = np.zeros_like(re_)
        axes = self._axes(along, cross, depth)
        # the schedule's slices take the voxels less than one voxel beyond the reach
        v = self.proc.tile.voxel_m
        for p in pings:
            if p.damage:                        # damaged on disk: refused, not imaged
                continue
            placed, reach = self.placed(p)
            ia = np.flatnonzero((along > placed.tx[0] - reach - v)
                                & (along < placed.tx[0] + reach + v))
            if not ia.size:
                continue
            kd = self._prepared(p)[1]
            array, delays = acc.ping_inputs(placed.tx, placed.rx, placed.bore, reach)
            acc.kernel(ImageSlice(re_, im_, axes, int(ia[0]), int(ia[-1]) + 1), kd, array,
                       delays, gating=im.beam_gating)
        return re_.astype(np.float64) + 1j * im_.astype(np.float64)
