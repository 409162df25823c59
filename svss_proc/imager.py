"""Tile imager: conditions pings, backprojects them into every tile they reach, and
hands back tiles once the platform has moved past them.

The imager knows only the hardware configuration, the processing configuration and the
pings; never the truth of a scene.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.frames import TrackLine, body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.ping import Ping
from svss_daq.waveform import make_waveform

from .backprojection import along_reach, backproject_ping, prepare
from .conditioning import Conditioner
from .grid import TileGrid, tile_grid, tile_index

log = logging.getLogger(__name__)


@dataclass
class Tile:
    """A tile being formed or finished: the complex image and what went into it."""
    grid: TileGrid
    line: TrackLine
    image: np.ndarray
    pings: list[int] = field(default_factory=list)
    updates: int = 0


def line_from_ping(ping: Ping, proc: ProcessingConfig) -> TrackLine:
    """The tile frame, from the processing configuration and (if so configured) the
    first ping's pose."""
    im = proc.imaging
    nav = ping.nav
    if im.track_line == "fixed":
        origin, heading = tuple(im.line_origin_ne_m), math.radians(im.line_heading_deg)
    else:
        origin, heading = (nav.north_m, nav.east_m), nav.heading_rad
    interface = (im.interface_down_m if im.interface == "fixed"
                 else nav.down_m + nav.altitude_m)
    return TrackLine(origin, heading, interface)


class TileImager:
    """Streaming imager. Feed pings in time order with :meth:`add`; it returns the tiles
    that are complete. :meth:`finish` returns the rest."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: ProcessingConfig):
        self.hardware = hardware
        hw = hardware.value
        self.proc = processing
        self.geometry = array_geometry(hw)
        self.conditioner = Conditioner(hw.digitiser, make_waveform(hw.waveform),
                                       processing.conditioning.decimation)
        self.line: TrackLine | None = None
        self.active: dict[int, Tile] = {}
        self.done: set[int] = set()
        self.n_pings = 0
        self.updates = 0

    def _tile(self, k: int) -> Tile:
        if k not in self.active:
            grid = tile_grid(self.proc.tile, k)
            self.active[k] = Tile(grid, self.line, np.zeros(grid.shape, dtype=np.complex64))
        return self.active[k]

    def add(self, ping: Ping) -> list[Tile]:
        """Image one ping into the tiles it reaches; return tiles now complete."""
        if ping.config_id and ping.config_id != self.hardware.id:
            raise ValueError(f"ping {ping.sequence}: acquired with hardware config "
                             f"{ping.config_id}, imager configured with {self.hardware.id}")
        if self.line is None:
            self.line = line_from_ping(ping, self.proc)
            log.info("tile frame: origin N %.2f E %.2f m, heading %.1f deg, interface %.2f m",
                     *self.line.origin_ne, math.degrees(self.line.heading),
                     self.line.interface_down)
        geo, line, tcfg = self.geometry, self.line, self.proc.tile
        nav = ping.nav
        rot = line.rotation_from_ned() @ body_to_ned(nav.roll_rad, nav.pitch_rad,
                                                      nav.heading_rad)
        origin = line.ned_to_tile(nav.ned)
        tx = origin + rot @ geo.projectors[ping.projector]
        rx = origin + geo.receivers @ rot.T
        bore = rot @ geo.boresight
        cond = self.conditioner(ping.samples, ping.window_start_ns * 1e-9)
        c = self.proc.imaging.sound_speed_m_s
        gating = self.proc.imaging.beam_gating
        # which tiles can this ping reach?
        max_depth = tcfg.top_m + tcfg.depth_m
        if gating:
            reach = along_reach(tx, bore, geo.projector_half_angle, max_depth)
        else:
            reach = (cond.t0_s + cond.dt_s * cond.data.shape[1]) * c / 2
        lo, hi = tx[0] - reach, tx[0] + reach
        cos_tx, cos_rx = math.cos(geo.projector_half_angle), math.cos(geo.receiver_half_angle)
        kd = None
        for k in range(tile_index(tcfg, lo), tile_index(tcfg, hi) + 1):
            if k in self.done:
                continue
            tile = self._tile(k)
            a = tile.grid.along
            v = tcfg.voxel_m
            ia0 = int(np.clip(np.floor((lo - a[0]) / v), 0, a.size))
            ia1 = int(np.clip(np.ceil((hi - a[0]) / v) + 1, 0, a.size))
            if ia1 <= ia0:
                continue
            kd = kd or prepare(cond)
            n = backproject_ping(tile.image, kd.d, kd.f, kd.t0, kd.dt, kd.theta, kd.halvings,
                                 c, tx, rx, bore, cos_tx, cos_rx, a, tile.grid.cross,
                                 tile.grid.depth, ia0, ia1, gating)
            tile.pings.append(ping.sequence)
            tile.updates += int(n)
            self.updates += int(n)
        self.n_pings += 1
        # tiles wholly behind this ping's reach are complete (platform moves forward)
        finished = [k for k in self.active if (k + 1) * tcfg.length_m < lo]
        return [self._close(k) for k in sorted(finished)]

    def _close(self, k: int) -> Tile:
        self.done.add(k)
        return self.active.pop(k)

    def finish(self) -> list[Tile]:
        """Return every tile still being formed."""
        return [self._close(k) for k in sorted(self.active)]
