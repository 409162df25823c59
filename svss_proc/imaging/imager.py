"""Tile imager: conditions pings, backprojects them into every tile they reach, and
hands back tiles once the pings' reach has stayed clear of them for a while.

Tile completion (docs/worker.md): a tile is complete when ``tile.close_after_pings``
consecutive pings (default :data:`CLOSE_AFTER_PINGS`) have not reached it, whichever
way the platform moves (forward, reversing, turning away); a stopped platform keeps the
tiles it reaches open. :meth:`TileImager.finish` closes the rest at run end, and the
memory bound (``limits.memory_gib``) closes the farthest tile early.

The imager knows only the hardware configuration, the processing configuration and the
pings; never the truth of a scene.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.frames import TrackLine
from svss_daq.geometry import array_geometry, place_array
from svss_daq.ping import Ping
from svss_daq.ping_gate import PingRejected, ping_problem
from svss_daq.waveform import make_waveform

from ..conditioning import Conditioner
from ..preflight import preflight
from ..tiles import Tile
from .coverage import Coverage
from .cpu_kernel import run_ping
from .delays import TravelTimeTable, build_table
from .grid import tile_grid, tile_index
from .kernel_args import DelayModel, prepare
from .pose_check import TrackGuard, check_pose_flags

log = logging.getLogger(__name__)

#: consecutive pings that must stay clear of a tile before it is complete, when the
#: processing configuration's ``tile.close_after_pings`` is omitted
CLOSE_AFTER_PINGS = 20
#: refraction tables are cached per 1 / TABLE_KEYS_PER_M of array height (1 cm)
TABLE_KEYS_PER_M = 100


def receive_apodisation(receivers_body: np.ndarray, kind: str) -> np.ndarray | None:
    """Per-channel weights over the receive aperture (None for no weighting)."""
    if kind == "none":
        return None
    w = np.ones(receivers_body.shape[0])
    for axis in (0, 1):
        p = receivers_body[:, axis]
        span = np.ptp(p)
        if span > 0:
            pitch = np.min(np.diff(np.unique(np.round(p, 9))))
            x = (p - p.min() + pitch) / (span + 2 * pitch)       # in (0, 1)
            w *= np.sin(np.pi * x) ** 2
    return w / w.mean()


def along_reach(tx_tile: np.ndarray, bore: np.ndarray, half_angle: float,
                max_depth: float) -> float:
    """Largest horizontal distance from the projector at which a voxel no deeper than
    ``max_depth`` (tile frame) can lie inside the projector cone, m."""
    tilt = math.acos(max(-1.0, min(1.0, float(bore[2]))))
    cone = min(half_angle + tilt, math.radians(89.0))
    return max(0.0, (max_depth - float(tx_tile[2]))) * math.tan(cone)


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


def ping_frame(frame: TrackLine, nav, proc: ProcessingConfig) -> TrackLine:
    """The frame one ping is placed in: the tile frame, except that with
    ``imaging.interface = "altitude"`` the interface lies at this ping's measured
    altitude below the body (DVL bottom track), so that the array's height above the
    seabed is the DVL's rather than the GPS height's (decimetres of noise). Without an
    altitude (lost bottom lock) the tile frame's interface is used."""
    if proc.imaging.interface != "altitude":
        return frame
    interface = nav.down_m + nav.altitude_m
    if not math.isfinite(interface):
        return frame
    return dataclasses.replace(frame, interface_down=interface)


class TileImager:
    """Streaming imager. Feed pings in time order with :meth:`add`; it returns the tiles
    that are complete. :meth:`finish` returns the rest."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: ProcessingConfig, *,
                 source: str = "processing configuration"):
        self.max_open_tiles = preflight(processing, source)
        self.hardware = hardware
        hw = hardware.value
        self.proc = processing
        self.track = TrackGuard(processing.ping_gate)
        self.late_pings = 0
        self.geometry = array_geometry(hw)
        cond = processing.conditioning
        self.conditioner = Conditioner(hw.digitiser, make_waveform(hw.waveform),
                                       cond.decimation, cond.upsample)
        self.dtype = np.float32 if processing.imaging.precision == "float32" else np.float64
        self.apod = receive_apodisation(self.geometry.receivers, processing.imaging.apodisation)
        self._tables: dict[int, TravelTimeTable] = {}
        if processing.imaging.device == "cuda":
            from . import gpu_kernel            # numba-cuda only when asked for
            self._run, self._zeros = gpu_kernel.run_ping_gpu, gpu_kernel.device_zeros
        else:
            self._run, self._zeros = run_ping, np.zeros
        self.line: TrackLine | None = None
        self.active: dict[int, Tile] = {}
        hold = processing.tile.close_after_pings
        self.close_after = CLOSE_AFTER_PINGS if hold is None else hold
        #: per open tile: consecutive pings since one last reached it
        self.clear: dict[int, int] = {}
        #: per open tile: the sequence of the ping that opened it
        self.opened_by: dict[int, int] = {}
        self.done: set[int] = set()
        self.n_pings = 0
        self.updates = 0

    def resume_sequence(self) -> int | None:
        """The first sequence of the earliest still-open tile (None: no tile open):
        imaging again from there rebuilds every open tile exactly."""
        return min(self.opened_by.values()) if self.opened_by else None

    def _tile(self, k: int, sequence: int) -> Tile:
        if k not in self.active:
            self.opened_by[k] = sequence
            self.clear[k] = 0
            grid = tile_grid(self.proc.tile, k)
            self.active[k] = Tile(grid, self.line, self._zeros(grid.shape, dtype=self.dtype),
                                  self._zeros(grid.shape, dtype=self.dtype),
                                  coverage=Coverage.new(grid.shape, self.geometry.receivers))
        return self.active[k]

    def add(self, ping: Ping) -> list[Tile]:
        """Image one ping into the tiles it reaches; return tiles now complete.

        Raises :class:`~svss_daq.ping_gate.PingRejected`, changing nothing, for a pose
        its navigation's flags keep from imaging
        (:func:`~svss_proc.imaging.pose_check.pose_flags_problem`), a ping the gate's
        :func:`~svss_daq.ping_gate.ping_problem` refuses, an implausible pose
        (:mod:`~svss_proc.imaging.pose_check`) or one that would reach more than
        the tiles that fit in ``limits.memory_gib``. (A stream's
        :class:`~svss_daq.ping_gate.PingGate` also keeps time order and counts.)"""
        check_pose_flags(ping, self.proc.ping_gate)
        reason = ping_problem(ping, self.hardware)
        if reason is not None:
            raise PingRejected(getattr(ping, "sequence", "?"), reason)
        line = self.line or line_from_ping(ping, self.proc)
        geo, tcfg = self.geometry, self.proc.tile
        placed = place_array(geo, ping.nav, ping.projector,
                             ping_frame(line, ping.nav, self.proc))
        tx, rx, bore = placed.tx, placed.rx, placed.bore
        fix = self.track.check(ping.sequence, ping.nav, tx)
        im = self.proc.imaging
        gating = im.beam_gating
        # which tiles can this ping reach?
        max_depth = tcfg.top_m + tcfg.depth_m
        cond = None
        if gating:
            reach = along_reach(tx, bore, geo.projector_half_angle, max_depth)
        else:
            cond = self.conditioner.ping(ping)
            reach = cond.axis.end_s * im.water_sound_speed_m_s / 2
        lo, hi = tx[0] - reach, tx[0] + reach
        k_lo, k_hi = tile_index(tcfg, lo), tile_index(tcfg, hi)
        limit = self.max_open_tiles
        if k_hi - k_lo + 1 > limit:
            raise PingRejected(ping.sequence, f"reaches {k_hi - k_lo + 1} tiles (along-track "
                               f"{lo:.1f} to {hi:.1f} m), more than the {limit} that fit "
                               "in limits.memory_gib")
        if self.line is None:
            self.line = line
            log.info("tile frame: origin N %.2f E %.2f m, heading %.1f deg, interface %.2f m",
                     *line.origin_ne, math.degrees(line.heading), line.interface_down)
        self.track.commit(fix)
        reached = [k for k in range(k_lo, k_hi + 1) if k not in self.done]
        if not reached:
            self.late_pings += 1
            log.warning("ping %d reaches only tiles already written (%d..%d); not imaged",
                        ping.sequence, k_lo, k_hi)
        closed = (self._make_room([k for k in reached if k not in self.active], reached)
                  if reached else [])
        cond = cond or self.conditioner.ping(ping)
        delays = DelayModel(im.delays, im.water_sound_speed_m_s, im.sediment_sound_speed_m_s,
                            self._table(tx, rx, reach) if im.delays == "table" else None)
        kd = None
        for k in reached:
            tile = self._tile(k, ping.sequence)
            a = tile.grid.along
            v = tcfg.voxel_m
            ia0 = int(np.clip(np.floor((lo - a[0]) / v), 0, a.size))
            ia1 = int(np.clip(np.ceil((hi - a[0]) / v) + 1, 0, a.size))
            if ia1 <= ia0:
                continue
            kd = kd or prepare(cond, im.interpolation, self.dtype)
            n = self._run(tile.re, tile.im, kd, tx, rx, a, tile.grid.cross, tile.grid.depth,
                          ia0, ia1, bore=bore, cos_tx=math.cos(geo.projector_half_angle),
                          cos_rx=math.cos(geo.receiver_half_angle), delays=delays,
                          gating=gating, apod=self.apod)
            # which voxels this ping reached (geometry only; the image is not touched)
            window = (cond.axis.start_s, cond.axis.end_s - cond.axis.step_s)
            tile.coverage.add(tile.grid, ia0, ia1, placed, geo, window, im, ping.nav)
            tile.pings.append(ping.sequence)
            tile.updates += int(n)
            self.updates += int(n)
        self.n_pings += 1
        # a tile is complete once close_after consecutive pings have stayed clear of it
        # (in either direction); one this ping reaches stays open
        finished = []
        for k in self.active:
            if k_lo <= k <= k_hi:
                self.clear[k] = 0
            else:
                self.clear[k] += 1
                if self.clear[k] >= self.close_after:
                    finished.append(k)
        return closed + [self._close(k) for k in sorted(finished)]

    def _make_room(self, new: list[int], reached: list[int]) -> list[Tile]:
        """Close open tiles this ping does not reach, farthest first, until the ``new``
        ones fit within the tiles ``limits.memory_gib`` allows; return those closed."""
        limit = self.max_open_tiles
        closed = []
        spare = sorted((k for k in self.active if k not in reached),
                       key=lambda k: -min(abs(k - r) for r in reached))
        while len(self.active) + len(new) > limit and spare:
            k = spare.pop(0)
            log.warning("closing tile %d early: %d tiles open, %d fit in limits.memory_gib",
                        k, len(self.active) + len(new), limit)
            closed.append(self._close(k))
        return closed

    def _table(self, tx: np.ndarray, rx: np.ndarray, reach: float) -> TravelTimeTable:
        """Refraction table for this ping's mean element height (cached per cm: the
        kernel corrects each element's height to first order, T(h) = T(h_ref) +
        (h - h_ref) eta, and the second-order remainder over 5 mm, ~(5 mm)^2 / (2 x 2 m),
        is 1e-4 of a wavelength; per mm, real navigation's altitude needed a new table
        almost every ping). A cached
        table that is too short for this ping is rebuilt longer: its nodes (k x step) and
        their times do not depend on the extent, so every ping sees the same times
        whichever pings came before it (a batch task images a subset of a run's pings
        and must give the same tile as the whole run)."""
        im, tcfg = self.proc.imaging, self.proc.tile
        h = float(-np.mean(np.concatenate([rx[:, 2], tx[2:3]])))
        key = int(round(h * TABLE_KEYS_PER_M))
        span = float(np.ptp(rx[:, 0]) + np.ptp(rx[:, 1]) + abs(rx[:, :2] - tx[:2]).max())
        rho_max = reach + tcfg.width_m + span
        cached = self._tables.get(key)
        if cached is None or cached.rho_max < rho_max:
            self._tables[key] = build_table(
                key / TABLE_KEYS_PER_M, rho_max, tcfg.top_m - im.table_step_m,
                tcfg.top_m + tcfg.depth_m + im.table_step_m, im.table_step_m,
                im.water_sound_speed_m_s, im.sediment_sound_speed_m_s)
        return self._tables[key]

    def _close(self, k: int) -> Tile:
        self.done.add(k)
        self.clear.pop(k, None)
        self.opened_by.pop(k, None)
        return self.active.pop(k).to_host()

    def finish(self) -> list[Tile]:
        """Return every tile still being formed."""
        return [self._close(k) for k in sorted(self.active)]
