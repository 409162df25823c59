"""Tile schedule: from poses alone, which tiles -- and which along-track slices of them --
each ping reaches, and when tiles open and close.

The schedule is the one place that decides what is imaged where; it reads no sample.
:class:`~svss_proc.imaging.imager.TileImager` (the worker and ``svss process``) feeds it
pings and images what it says; ``svss batch`` plans a run with it alone
(:mod:`svss_proc.batch.plan`) and a batch task then images one planned tile with the
same schedule, its frame fixed and the run's other tiles marked written.

For each ping, in order (:meth:`TileSchedule.step`): the tile frame (the first admitted
ping's, or fixed), the array placed in it, the track guard
(:class:`~svss_proc.imaging.pose_check.TrackGuard`), the ping's along-track reach (the
projector cone down to the tile's bottom with beam gating, else the echo window's
one-way range), the tiles it reaches (at most ``limits.memory_gib`` allows, else the
ping is refused), tiles closed early to make room (farthest first), each reached tile's
slice of along-track voxel planes, and the tiles complete after it.

Tile completion (docs/worker.md): a tile is complete when ``tile.close_after_pings``
consecutive pings (default :data:`CLOSE_AFTER_PINGS`) have not reached it, whichever way
the platform moves (forward, reversing, turning away); a stopped platform keeps the
tiles it reaches open. :meth:`TileSchedule.finish` closes the rest at run end.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from svss_daq.config import (HardwareConfig, Loaded, ProcessingConfig, TileConfig,
                             omitted_default)
from svss_daq.frames import TrackLine
from svss_daq.geometry import PlacedArray, array_geometry, cone_reach, place_array
from svss_daq.ping import Ping
from svss_daq.ping_gate import PingRejected
from svss_daq.waveform import make_waveform

from ..conditioning import Conditioner
from ..preflight import preflight
from .grid import tile_grid, tile_index
from .pose_check import TrackGuard
from .surface import InterfaceShape, level_offset

log = logging.getLogger(__name__)

#: consecutive pings that must stay clear of a tile before it is complete, when the
#: processing configuration's ``tile.close_after_pings`` is omitted (the schema's default,
#: which the loader fills in; this serves configurations built in code)
CLOSE_AFTER_PINGS = omitted_default(TileConfig, "close_after_pings")


def along_reach(tx_tile: np.ndarray, bore: np.ndarray, half_angle: float,
                max_depth: float) -> float:
    """Largest horizontal distance from the projector at which a voxel no deeper than
    ``max_depth`` (tile frame) can lie inside the projector cone, m."""
    return cone_reach(max_depth - float(tx_tile[2]), float(bore[2]), half_angle)


def gated_reach(tx_tile: np.ndarray, bore: np.ndarray, half_angle: float,
                proc: ProcessingConfig) -> float:
    """:func:`along_reach` to the bottom of the tiles of ``proc``; on a sloping
    interface to the bottom where the plane lies deepest within twice that reach."""
    tcfg = proc.tile
    deepest = tcfg.top_m + tcfg.depth_m
    reach = along_reach(tx_tile, bore, half_angle, deepest)
    shape = InterfaceShape.of(proc.imaging)
    if shape.level:
        return reach
    a = float(tx_tile[0]) + np.array([-2.0, 2.0, -2.0, 2.0]) * reach
    c = np.array([-0.5, -0.5, 0.5, 0.5]) * tcfg.width_m
    return along_reach(tx_tile, bore, half_angle,
                       deepest + max(float(shape.depth(a, c).max()), 0.0))


def line_from_ping(ping: Ping, proc: ProcessingConfig) -> TrackLine:
    """The tile frame, from the processing configuration and (if so configured) the
    first ping's pose."""
    return line_from_pose(ping.nav, proc)


def line_from_pose(nav, proc: ProcessingConfig) -> TrackLine:
    """:func:`line_from_ping` from the first ping's pose ``nav`` alone."""
    im = proc.imaging
    if im.track_line == "fixed":
        origin, heading = tuple(im.line_origin_ne_m), math.radians(im.line_heading_deg)
    else:
        origin, heading = (nav.north_m, nav.east_m), nav.heading_rad
    if im.interface == "fixed":
        return TrackLine(origin, heading, im.interface_down_m)
    line = TrackLine(origin, heading, nav.down_m + nav.altitude_m)
    return dataclasses.replace(line, interface_down=line.interface_down - level_offset(
        InterfaceShape.of(im), line, nav.north_m, nav.east_m))


def ping_frame(frame: TrackLine, nav, proc: ProcessingConfig) -> TrackLine:
    """The frame one ping is placed in: the tile frame, except that with
    ``imaging.interface = "altitude"`` the interface lies at this ping's measured
    altitude below the body (DVL bottom track), so that the array's height above the
    seabed is the DVL's rather than the GPS height's (decimetres of noise); on a sloping
    interface (``imaging.interface_slope_deg``) the frame's level is the plane's zero,
    placed so that the plane passes through the bed the ping measured under its body
    (:func:`~svss_proc.imaging.surface.level_offset`). Without an altitude (lost bottom
    lock) the tile frame's interface is used."""
    if proc.imaging.interface != "altitude":
        return frame
    interface = nav.down_m + nav.altitude_m
    if not math.isfinite(interface):
        return frame
    shape = InterfaceShape.of(proc.imaging)
    return dataclasses.replace(frame, interface_down=interface - level_offset(
        shape, frame, nav.north_m, nav.east_m))


@dataclass(frozen=True)
class Slice:
    """Along-track voxel planes ``ia0 <= i < ia1`` of tile ``tile``."""
    tile: int
    ia0: int
    ia1: int


@dataclass(frozen=True)
class PingStep:
    """What the schedule decided for one ping: image ``slices`` (in tile order) with the
    array ``placed``; ``reached``: the tiles it reaches (open after it, a tile with no
    slice included); ``closed_early``: tiles closed to make room, before it is imaged;
    ``closed``: tiles complete after it."""
    sequence: int
    placed: PlacedArray
    reach_m: float
    reached: tuple[int, ...]
    slices: tuple[Slice, ...]
    closed_early: tuple[int, ...]
    closed: tuple[int, ...]


class _Trusted:
    """The track guard of a schedule whose poses were judged elsewhere (a batch task:
    the plan judged every pose against the whole run's track)."""
    reanchored = 0

    def check(self, sequence, nav, tx_tile):
        return None

    def commit(self, fix) -> None:
        pass


class TileSchedule:
    """Tile bookkeeping on poses only. :meth:`step` one ping at a time, in time order;
    :meth:`finish` at the run's end."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: ProcessingConfig, *,
                 source: str = "processing configuration"):
        self.max_open_tiles = preflight(processing, source)
        #: when (monotonic) the memory bound was last reached: a tile closed early, or a
        #: ping refused for reaching more tiles than fit (None: never)
        self.memory_bound_at: float | None = None
        self.hardware = hardware
        self.proc = processing
        self.geometry = array_geometry(hardware.value)
        self._track: TrackGuard | _Trusted = TrackGuard(processing.ping_gate)
        hold = processing.tile.close_after_pings
        self.close_after = CLOSE_AFTER_PINGS if hold is None else hold
        self._conditioner: Conditioner | None = None
        self._line: TrackLine | None = None
        # open tiles: index -> sequence of the ping that opened it
        self._opened_by: dict[int, int] = {}
        # per open tile: consecutive pings since one last reached it
        self._clear: dict[int, int] = {}
        # tiles closed (written), never opened again
        self._done: set[int] = set()
        self._n_pings = 0
        self._late_pings = 0

    # -- read-only views --------------------------------------------------------------------

    @property
    def line(self) -> TrackLine | None:
        """The tile frame (None until the first ping is admitted or :meth:`fix_frame`)."""
        return self._line

    @property
    def done(self) -> frozenset[int]:
        """Tiles closed (written, or marked so), never opened again."""
        return frozenset(self._done)

    @property
    def track(self) -> TrackGuard | _Trusted:
        """The track guard (``reanchored``: times the track followed a true move)."""
        return self._track

    @property
    def n_pings(self) -> int:
        """Pings scheduled."""
        return self._n_pings

    @property
    def late_pings(self) -> int:
        """Pings that reached only tiles already written (not imaged)."""
        return self._late_pings

    # -- set-up for resumes, batch tasks and single-tile imaging --------------------------

    def fix_frame(self, line: TrackLine) -> None:
        """Use ``line`` as the tile frame (a resumed run's, a batch plan's)."""
        self._line = line

    def mark_done(self, tiles: Iterable[int]) -> None:
        """Treat ``tiles`` as written: no ping opens them again."""
        self._done.update(int(k) for k in tiles)

    def trust_poses(self) -> None:
        """Skip the track guard: the poses were judged against the whole run already."""
        self._track = _Trusted()

    @property
    def open_tiles(self) -> list[int]:
        return sorted(self._opened_by)

    def resume_sequence(self) -> int | None:
        """The first sequence of the earliest still-open tile (None: no tile open):
        imaging again from there rebuilds every open tile exactly."""
        return min(self._opened_by.values()) if self._opened_by else None

    # -- one ping ---------------------------------------------------------------------------

    def echo_end_s(self, ping: Ping) -> float:
        """End of the ping's conditioned (arrival-time) axis, s, from its header."""
        if self._conditioner is None:
            hw, c = self.hardware.value, self.proc.conditioning
            self._conditioner = Conditioner(hw.digitiser, make_waveform(hw.waveform),
                                            c.decimation, c.upsample)
        return self._conditioner.output_axis(ping.sample_axis).end_s

    def step(self, ping: Ping, echo_end_s: float | None = None) -> PingStep:
        """Schedule one ping (``echo_end_s``: its conditioned axis's end, when known;
        else from its header). Raises :class:`~svss_daq.ping_gate.PingRejected`,
        changing nothing, for an implausible pose (the track guard) or a ping that would
        reach more tiles than fit in ``limits.memory_gib``."""
        proc, tcfg, geo = self.proc, self.proc.tile, self.geometry
        line = self._line or line_from_ping(ping, proc)
        placed = place_array(geo, ping.nav, ping.projector, ping_frame(line, ping.nav, proc))
        tx = placed.tx
        fix = self._track.check(ping.sequence, ping.nav, tx)
        if proc.imaging.beam_gating:
            reach = gated_reach(tx, placed.bore, geo.projector_half_angle, proc)
        else:
            end = self.echo_end_s(ping) if echo_end_s is None else echo_end_s
            reach = end * proc.imaging.water_sound_speed_m_s / 2
        lo, hi = tx[0] - reach, tx[0] + reach
        k_lo, k_hi = tile_index(tcfg, lo), tile_index(tcfg, hi)
        limit = self.max_open_tiles
        if k_hi - k_lo + 1 > limit:
            self.memory_bound_at = time.monotonic()
            raise PingRejected(ping.sequence, f"reaches {k_hi - k_lo + 1} tiles (along-track "
                               f"{lo:.1f} to {hi:.1f} m), more than the {limit} that fit "
                               "in limits.memory_gib")
        if self._line is None:
            self._line = line
            log.info("tile frame: origin N %.2f E %.2f m, heading %.1f deg, interface %.2f m",
                     *line.origin_ne, math.degrees(line.heading), line.interface_down)
        self._track.commit(fix)
        reached = [k for k in range(k_lo, k_hi + 1) if k not in self._done]
        if not reached:
            self._late_pings += 1
            log.warning("ping %d reaches only tiles already written (%d..%d); not imaged",
                        ping.sequence, k_lo, k_hi)
        early = self._make_room([k for k in reached if k not in self._opened_by], reached) \
            if reached else []
        v = tcfg.voxel_m
        slices = []
        for k in reached:
            if k not in self._opened_by:
                self._opened_by[k] = ping.sequence
                self._clear[k] = 0
            a = tile_grid(tcfg, k).along
            ia0 = int(np.clip(np.floor((lo - a[0]) / v), 0, a.size))
            ia1 = int(np.clip(np.ceil((hi - a[0]) / v) + 1, 0, a.size))
            if ia1 > ia0:
                slices.append(Slice(k, ia0, ia1))
        self._n_pings += 1
        # a tile is complete once close_after consecutive pings have stayed clear of it
        # (in either direction); one this ping reaches stays open
        finished = []
        for k in self._opened_by:
            if k_lo <= k <= k_hi:
                self._clear[k] = 0
            else:
                self._clear[k] += 1
                if self._clear[k] >= self.close_after:
                    finished.append(k)
        for k in sorted(finished):
            self._close(k)
        return PingStep(ping.sequence, placed, reach, tuple(reached), tuple(slices),
                        tuple(early), tuple(sorted(finished)))

    def _make_room(self, new: list[int], reached: list[int]) -> list[int]:
        """Close open tiles this ping does not reach, farthest first, until the ``new``
        ones fit within the tiles ``limits.memory_gib`` allows; return those closed."""
        limit = self.max_open_tiles
        closed = []
        spare = sorted((k for k in self._opened_by if k not in reached),
                       key=lambda k: -min(abs(k - r) for r in reached))
        while len(self._opened_by) + len(new) > limit and spare:
            k = spare.pop(0)
            log.warning("closing tile %d early: %d tiles open, %d fit in limits.memory_gib",
                        k, len(self._opened_by) + len(new), limit)
            self._close(k)
            closed.append(k)
        if closed:
            self.memory_bound_at = time.monotonic()
        return closed

    def _close(self, k: int) -> None:
        self._done.add(k)
        self._clear.pop(k, None)
        self._opened_by.pop(k, None)

    def finish(self) -> list[int]:
        """Close every open tile (the run's end); their indices, in order."""
        rest = sorted(self._opened_by)
        for k in rest:
            self._close(k)
        return rest


__all__ = ["CLOSE_AFTER_PINGS", "PingStep", "Slice", "TileSchedule", "along_reach",
           "line_from_ping", "ping_frame"]
