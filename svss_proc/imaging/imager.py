"""Tile imager: a :class:`~.schedule.TileSchedule` (what to image where, from the poses)
and a :class:`PingAccumulator` (condition a ping once, run the imaging and coverage
kernels on the slices the schedule gives) over the tiles being formed; it hands back
tiles as the schedule closes them (docs/worker.md: tile completion).

The imager knows only the hardware configuration, the processing configuration and the
pings; never the truth of a scene.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.frames import TrackLine
from svss_daq.geometry import PlacedArray, array_geometry
from svss_daq.ping import Ping, SampleAxis
from svss_daq.ping_gate import PingRejected, checked_ping_problem
from svss_daq.waveform import make_waveform

from ..conditioning import Conditioned, Conditioner
from .coverage import Coverage
from .cpu_kernel import run_ping
from .delays import SpeedProfile, TravelTimeTable, build_table
from .factorised import Factorisation, add_ping
from .grid import kernel_voxels, tile_grid
from .handback import Handback
from .surface import InterfaceShape
from .tile import Tile
from .kernel_args import (DelayModel, ImageSlice, KernelData, PingArray, VoxelAxes,
                          prepare)
from .pose_check import check_pose_flags
from .schedule import PingStep, TileSchedule

log = logging.getLogger(__name__)

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


def imaging_method(processing: ProcessingConfig, live: bool = False) -> str:
    """The imaging method a setting runs: ``[imaging] live_method`` for the live worker,
    ``method`` otherwise; 'exact' on the GPU (the factorised second stage is a CPU
    kernel, and the GPU keeps up with the exact method)."""
    im = processing.imaging
    method = im.live_method if live else im.method
    return "exact" if im.device == "cuda" else method


class PingAccumulator:
    """Images pings into tiles: conditions a ping (:meth:`condition`), builds the kernel
    arguments once per ping and runs the imaging and coverage kernels on the slices a
    :class:`~.schedule.PingStep` gives (:meth:`image`). ``channels``: sum only these
    receive channels (None: all; ``svss trade``'s sub-arrays). ``method``: 'exact' or
    'factorised' (:mod:`.factorised`; None: ``[imaging] method``, see
    :func:`imaging_method`)."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: ProcessingConfig, *,
                 channels: np.ndarray | None = None, method: str | None = None):
        hw = hardware.value
        self._proc = processing
        im = processing.imaging
        #: the imaging method run ('exact' or 'factorised'), named in tiles and manifests
        self.method = method if method is not None else imaging_method(processing)
        if self.method not in ("exact", "factorised"):
            raise ValueError(f"imaging method {self.method!r}: expected 'exact' or "
                             "'factorised'")
        if self.method == "factorised" and im.device == "cuda":
            self.method = "exact"
        self._plan = Factorisation(*im.factorised_step_m, im.factorised_lobes)
        self._channels = None if channels is None else np.asarray(channels)
        geometry = array_geometry(hw)
        if self._channels is not None:
            geometry = dataclasses.replace(geometry,
                                           receivers=geometry.receivers[self._channels])
        self._geometry = geometry
        cond = processing.conditioning
        self._conditioner = Conditioner(hw.digitiser, make_waveform(hw.waveform),
                                        cond.decimation, cond.upsample)
        self._dtype = np.float32 if processing.imaging.precision == "float32" else np.float64
        self._apod = receive_apodisation(geometry.receivers, processing.imaging.apodisation)
        self._tables: dict[int, TravelTimeTable] = {}
        #: the sediment's layers and half-space speed the tables refract through
        self._profile = SpeedProfile.of(processing.imaging)
        #: on the GPU a tile's updates are counted on the device (``count=`` of the
        #: kernel's front door) and read when the tile is handed back or
        #: :attr:`updates` is read, so that no ping waits for its kernel to finish: the
        #: next ping's conditioning and the coverage run while it does
        self._device_counter = None
        #: on the GPU the pings of a tile are queued and imaged
        #: ``imaging.gpu_pings_per_launch`` at a time (:mod:`.gpu_batch`); the queue is
        #: launched before a tile's counts or planes are read (:meth:`settle`)
        self._batcher = None
        #: on the GPU with ``imaging.gpu_conditioning = "device"``, a ping's tap planes
        #: are made on the device from its codes (:mod:`.gpu_conditioning`)
        self._device_conditioner = None
        #: on the GPU with ``imaging.gpu_coverage = "device"``, coverage is counted there
        #: (:mod:`.gpu_coverage`; None: on the CPU)
        self._coverage_counter = None
        if processing.imaging.device == "cuda":
            from . import gpu_batch, gpu_kernel      # numba-cuda only when asked for
            self._batcher = gpu_batch.PingBatcher(processing.imaging.gpu_pings_per_launch)
            kernel, self._zeros = self._batcher.run_ping, gpu_kernel.device_zeros
            self._device_counter = gpu_kernel.device_counter
            if im.gpu_conditioning == "device":
                from .gpu_conditioning import DeviceConditioner
                self._device_conditioner = DeviceConditioner(
                    self._conditioner, im.interpolation, self._dtype)
            if im.gpu_coverage == "device":
                from .gpu_coverage import DeviceCounter
                self._coverage_counter = DeviceCounter(self._batcher.stream)
        else:
            kernel, self._zeros = run_ping, np.zeros
        #: the kernel's front door, ``kernel(out: ImageSlice, kd, array: PingArray,
        #: delays, gating=)`` (:func:`~.cpu_kernel.run_ping` or
        #: :func:`~.gpu_kernel.run_ping_gpu`); benchmarks and tests may wrap it
        self.kernel = kernel
        self._updates = 0
        self._pending: dict[int, tuple[Tile, object]] = {}   # id(tile): (tile, counter)

    # read-only views
    @property
    def geometry(self):
        """The array geometry imaged with (the channel subset's receivers)."""
        return self._geometry

    @property
    def channels(self) -> np.ndarray | None:
        """The receive channels summed (None: all)."""
        return self._channels

    @property
    def apod(self) -> np.ndarray | None:
        """Per-channel apodisation weights (None: uniform)."""
        return self._apod

    @property
    def dtype(self) -> type:
        """The kernel precision (numpy float32 or float64)."""
        return self._dtype

    @property
    def updates(self) -> int:
        """Voxel-channel updates made so far (on the GPU: waits for the kernels)."""
        self.settle()
        return self._updates

    def settle(self, tile: Tile | None = None) -> None:
        """Read the device-side update counts of ``tile`` (None: of every tile) into the
        tile's and this accumulator's totals, after launching the pings still queued
        for it; nothing to do on the CPU."""
        for key in ([id(tile)] if tile is not None else list(self._pending)):
            entry = self._pending.pop(key, None)
            if entry is not None:
                if self._batcher is not None:
                    self._batcher.flush(entry[0].re)
                n = int(entry[1].copy_to_host()[0])      # waits for the tile's kernels
                entry[0].updates += n
                self._updates += n

    def warm_up(self) -> None:
        """Compile this setting's imaging kernel (or load it from numba's cache) on a
        2 x 2 x 2 voxel problem, before pings come: a worker that compiles at its first ping
        is silent for tens of seconds on a first run (the daemon, not hearing from it
        for ``service.worker_silence_s``, once closed its catch-up service before the
        worker could confirm the run's end)."""
        im, geo = self._proc.imaging, self._geometry
        axis = self._conditioner.output_axis()
        cond = Conditioned(np.zeros((geo.receivers.shape[0], axis.n), dtype=np.complex128),
                           axis, self._conditioner.fc)
        kd = prepare(cond, im.interpolation, self._dtype)
        tx = np.array([0.0, 0.0, -2.0])
        array, delays = self.ping_inputs(tx, tx + geo.receivers - geo.projectors[0],
                                         np.array([0.0, 0.0, 1.0]), 1.0)
        out = ImageSlice(self._zeros((2, 2, 2), dtype=self._dtype),    # (not 1: a 1-voxel
                         self._zeros((2, 2, 2), dtype=self._dtype),    # axis is also F order)
                         VoxelAxes(np.zeros(2), np.zeros(2), np.array([0.4, 0.5])), 0, 2)
        self.image_slice(out, kd, array, delays, gating=im.beam_gating)
        if self._device_conditioner is not None:          # its kernel too
            self._batcher.release(self._batcher.device_planes(
                self._device_conditioner, np.zeros((geo.receivers.shape[0], 1), np.int32),
                None))
        if self._coverage_counter is not None:
            cov = Coverage.new((2, 2, 2), geo.receivers, self._zeros)
            cov.add(out.axes, 0, 2, PlacedArray(tx, array.rx, array.bore, 0), geo,
                    (axis.start_s, axis.end_s), im, None, counter=self._coverage_counter)

    def image_slice(self, out: ImageSlice, kd, array: PingArray, delays: DelayModel, *,
                    gating: bool) -> int:
        """One ping into one tile's slice by this accumulator's :attr:`method` (the
        kernel's front door, or the factorised method's two stages around it); returns
        the voxel-channel updates. The live clock times the worker's imaging here."""
        if self.method == "factorised":
            return add_ping(out, kd, array, delays, self._plan, self.kernel, gating=gating)
        return self.kernel(out, kd, array, delays, gating=gating)

    def ping_inputs(self, tx: np.ndarray, rx: np.ndarray, bore: np.ndarray,
                    reach: float) -> tuple[PingArray, DelayModel]:
        """The kernel's array and delay model for a ping placed with projector ``tx``,
        receivers ``rx`` (this accumulator's channels) and boresight ``bore`` (tile
        frame), reaching ``reach`` m along-track (the refraction table's extent)."""
        im, geo = self._proc.imaging, self._geometry
        delays = DelayModel(im.delays, im.water_sound_speed_m_s, im.sediment_sound_speed_m_s,
                            self.travel_table(tx, rx, reach) if im.delays == "table"
                            else None)
        return PingArray(tx, rx, bore, math.cos(geo.projector_half_angle),
                         math.cos(geo.receiver_half_angle), self._apod), delays

    def kernel_data(self, ping: Ping, cond: Conditioned | None = None
                    ) -> tuple[KernelData, SampleAxis, bool]:
        """The ping's kernel data and its samples' arrival-time axis, and whether the
        planes were made on the device (to be let go of after imaging:
        :meth:`~.gpu_batch.PingBatcher.release`). ``cond``: the ping conditioned
        already (None: conditioned here, on the device where so configured)."""
        dc = self._device_conditioner
        if cond is None and dc is not None and dc.accepts(ping.samples):
            codes = ping.samples if self._channels is None else ping.samples[self._channels]
            kd = self._batcher.device_planes(dc, codes, ping.sample_axis)
            return kd, self._conditioner.output_axis(ping.sample_axis), True
        cond = self.condition(ping) if cond is None else cond
        return prepare(cond, self._proc.imaging.interpolation, self._dtype), cond.axis, False

    def condition(self, ping: Ping) -> Conditioned:
        """The ping's analytic signal at its arrival times (its channels)."""
        c = self._conditioner.ping(ping)
        if self._channels is None:
            return c
        return Conditioned(c.analytic[self._channels], c.axis, c.center_hz)

    def new_tile(self, index: int, line: TrackLine) -> Tile:
        """An empty tile ``index`` in frame ``line``, its planes where the kernel runs."""
        grid = tile_grid(self._proc.tile, index, InterfaceShape.of(self._proc.imaging))
        return Tile(grid, line, self._zeros(grid.shape, dtype=self._dtype),
                    self._zeros(grid.shape, dtype=self._dtype),
                    coverage=Coverage.new(grid.shape, self._geometry.receivers,
                                          None if self._coverage_counter is None
                                          else self._zeros),
                    method=self.method)

    def image(self, ping: Ping, cond: Conditioned | None, step: PingStep,
              tiles: dict[int, Tile]) -> int:
        """Image ``ping`` (conditioned ``cond``; None: conditioned here,
        :meth:`kernel_data`) into the slices of ``step`` (tiles by index); returns the
        voxel-channel updates (0 on the GPU, where they are counted on the device:
        :meth:`settle`)."""
        if not step.slices:
            return 0
        im, geo = self._proc.imaging, self._geometry
        placed = step.placed
        if self._channels is not None:
            placed = dataclasses.replace(placed, rx=placed.rx[self._channels])
        array, delays = self.ping_inputs(placed.tx, placed.rx, placed.bore, step.reach_m)
        kd, axis, made = self.kernel_data(ping, cond)
        window = (axis.start_s, axis.end_s - axis.step_s)
        total = 0
        try:
            for s in step.slices:
                tile = tiles[s.tile]
                out = ImageSlice(tile.re, tile.im, tile.grid, s.ia0, s.ia1)
                if self._device_counter is not None:
                    entry = self._pending.get(id(tile))
                    if entry is None:
                        entry = self._pending[id(tile)] = (tile, self._device_counter())
                    self.kernel(out, kd, array, delays, gating=im.beam_gating,
                                count=entry[1])
                    n = 0
                else:
                    n = self.image_slice(out, kd, array, delays, gating=im.beam_gating)
                # which voxels this ping reached (geometry only; the image is not touched)
                tile.coverage.add(tile.grid, s.ia0, s.ia1, placed, geo, window, im,
                                  ping.nav, counter=self._coverage_counter)
                tile.pings.append(ping.sequence)
                tile.track.append((int(ping.transmit_time_ns), float(ping.nav.north_m),
                                   float(ping.nav.east_m), int(ping.nav.quality)))
                tile.updates += int(n)
                total += int(n)
        finally:
            if made:                   # its ring slot, held while it was imaged
                self._batcher.release(kd)
        self._updates += total
        return total

    def travel_table(self, tx: np.ndarray, rx: np.ndarray, reach: float) -> TravelTimeTable:
        """Refraction table for this ping's mean element height (cached per cm: the
        kernel corrects each element's height to first order, T(h) = T(h_ref) +
        (h - h_ref) eta, and the second-order remainder over 5 mm, ~(5 mm)^2 / (2 x 2 m),
        is 1e-4 of a wavelength; per mm, real navigation's altitude needed a new table
        almost every ping). A cached
        table that is too short for this ping is rebuilt longer: its nodes (k x step) and
        their times do not depend on the extent, so every ping sees the same times
        whichever pings came before it (a batch task images a subset of a run's pings
        and must give the same tile as the whole run)."""
        im, tcfg = self._proc.imaging, self._proc.tile
        h = float(-np.mean(np.concatenate([rx[:, 2], tx[2:3]])))
        key = int(round(h * TABLE_KEYS_PER_M))
        span = float(np.ptp(rx[:, 0]) + np.ptp(rx[:, 1]) + abs(rx[:, :2] - tx[:2]).max())
        rho_max = reach + tcfg.width_m + span
        cached = self._tables.get(key)
        if cached is None or cached.rho_max < rho_max:
            self._tables[key] = build_table(
                key / TABLE_KEYS_PER_M, rho_max, tcfg.top_m - im.table_step_m,
                tcfg.top_m + tcfg.depth_m + im.table_step_m, im.table_step_m,
                im.water_sound_speed_m_s, im.sediment_sound_speed_m_s, self._profile)
        return self._tables[key]


def seam_planes(processing: ProcessingConfig) -> int:
    """Along-track planes a tile's products need from the next tile for a background
    without seams: half the background kernel (0 without products)."""
    p = processing.products
    if p is None or not p.background.across_seams:
        return 0
    return kernel_voxels(p.background.kernel_m, processing.tile.voxel_m)[0] // 2


class TileImager:
    """Streaming imager: a :class:`~.schedule.TileSchedule` and a
    :class:`PingAccumulator` over the tiles being formed. Feed pings in time order with
    :meth:`add`; it returns the tiles that are complete. :meth:`finish` returns the
    rest. Set-up (a fixed frame, tiles already written, poses judged elsewhere) goes
    through :attr:`schedule`'s ``fix_frame``, ``mark_done`` and ``trust_poses``."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: ProcessingConfig, *,
                 source: str = "processing configuration",
                 channels: np.ndarray | None = None, method: str | None = None):
        self._hardware = hardware
        self._proc = processing
        #: what to image where, from the poses (set-up: ``fix_frame``, ``mark_done``,
        #: ``trust_poses``)
        self.schedule = TileSchedule(hardware, processing, source=source)
        #: conditions pings and runs the kernels (``condition``, ``kernel``)
        self.accumulator = PingAccumulator(hardware, processing, channels=channels,
                                           method=method)
        #: the tiles being formed or held (complete, until the next tile's first planes
        #: are: :mod:`.handback`), by index
        self._tiles: dict[int, Tile] = {}
        #: planes of the next tile handed back with a tile (products without seams: half
        #: the background kernel along-track; 0 without products)
        self._seam_planes = seam_planes(processing)
        self._handback = Handback(self._seam_planes, self.schedule.close_after,
                                  tile_grid(processing.tile, 0).shape[0], record=False)

    # read-only views of the tiles, the schedule and the accumulator
    @property
    def active(self) -> Mapping[int, Tile]:
        """The tiles being formed, by index (read-only); with them the tiles complete but
        held until the next tile's first planes are (not written yet)."""
        return MappingProxyType(dict(self._tiles))

    @property
    def line(self) -> TrackLine | None:
        """The tile frame (None until the first ping is admitted or a frame is fixed)."""
        return self.schedule.line

    @property
    def done(self) -> frozenset[int]:
        """The tiles closed and handed back (or marked written), never opened again."""
        return self.schedule.done - frozenset(self._handback.held)

    @property
    def n_pings(self) -> int:
        """Pings scheduled (admitted past the gate, the pose checks and the track)."""
        return self.schedule.n_pings

    @property
    def late_pings(self) -> int:
        """Pings that reached only tiles already written (not imaged)."""
        return self.schedule.late_pings

    @property
    def track(self):
        """The track guard, read-only by use: ``track.reanchored`` counts the times the
        track followed a true move."""
        return self.schedule.track

    @property
    def updates(self) -> int:
        """Voxel-channel updates made so far."""
        return self.accumulator.updates

    def resume_sequence(self) -> int | None:
        """The first sequence of the earliest still-open tile (None: no tile open):
        imaging again from there rebuilds every open tile exactly."""
        first = [self._tiles[k].pings[0] for k in self._handback.held
                 if self._tiles[k].pings]
        opened = self.schedule.resume_sequence()
        if opened is not None:
            first.append(opened)
        return min(first) if first else None

    def add(self, ping: Ping) -> list[Tile]:
        """Image one ping into the tiles it reaches; return tiles now complete.

        Raises :class:`~svss_daq.ping_gate.PingRejected`, changing nothing, for a pose
        its navigation's flags keep from imaging
        (:func:`~svss_proc.imaging.pose_check.pose_flags_problem`), a ping the gate's
        :func:`~svss_daq.ping_gate.ping_problem` refuses, an implausible pose
        (:mod:`~svss_proc.imaging.pose_check`) or one that would reach more than
        the tiles that fit in ``limits.memory_gib``. (A stream's
        :class:`~svss_daq.ping_gate.PingGate` also keeps time order and counts.)"""
        check_pose_flags(ping, self._proc.ping_gate)        # each once per ping: a gate
        reason = checked_ping_problem(ping, self._hardware)  # that passed it is trusted
        if reason is not None:
            raise PingRejected(getattr(ping, "sequence", "?"), reason)
        cond = None
        if not self._proc.imaging.beam_gating:      # the reach is the echo window's
            cond = self.accumulator.condition(ping)
        step = self.schedule.step(ping, None if cond is None else cond.axis.end_s)
        out = [self._hand_back(k, after) for k, after in self._handback.close_early(step)]
        for k in step.reached:
            if k not in self._tiles:
                self._tiles[k] = self.accumulator.new_tile(k, self.schedule.line)
        if step.slices:
            self.accumulator.image(ping, cond, step, self._tiles)
        return out + [self._hand_back(k, after) for k, after
                      in self._handback.step(step, self.schedule.n_pings, early=False)]

    def _next_planes(self, after) -> tuple[np.ndarray, np.ndarray | None] | None:
        """The first :attr:`_seam_planes` along-track planes (magnitude, ping-channel
        pairs) of the next tile the hand-back names (``after``: (its index, pings), or
        None: none go back)."""
        if after is None:
            return None
        n, nxt = self._seam_planes, self._tiles[after[0]]
        self.accumulator.settle(nxt)
        re, im = nxt.re[:n], nxt.im[:n]
        if hasattr(re, "copy_to_host"):
            re, im = re.copy_to_host(), im.copy_to_host()
        z = np.empty(re.shape, dtype=np.complex64)   # as Tile.image, so that the
        z.real, z.imag = re, im                       # magnitude is bit for bit the
        mag = np.abs(z).astype(np.float32)            # products' own (compute_products)
        ch = None
        if nxt.coverage is not None:
            ch = nxt.coverage.channels[:n]
            ch = ch.copy_to_host() if hasattr(ch, "copy_to_host") else ch.copy()
        return mag, ch

    def _hand_back(self, k: int, after=None) -> Tile:
        planes = self._next_planes(after)
        tile = self._tiles.pop(k)
        self.accumulator.settle(tile)
        tile.after = planes
        return tile.to_host()

    def finish(self) -> list[Tile]:
        """Return every tile still being formed."""
        self.schedule.finish()
        return [self._hand_back(k, after)
                for k, after in self._handback.finish(self.schedule.n_pings)]
