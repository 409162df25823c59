"""Tile planning for batch reprocessing: which pings of which raw files go into which
tile, decided from the runs' ping and navigation tables alone (no sample is read).

The plan runs the streaming worker's gate (:class:`~svss_daq.ping_gate.PingGate`,
:func:`~svss_proc.imaging.pose_check.check_pose_flags`) and the same
:class:`~svss_proc.imaging.schedule.TileSchedule` that
:class:`~svss_proc.imaging.imager.TileImager` images with (tile frame, track guard,
reach, tile opening, early closing under ``limits.memory_gib``, closing after
``tile.close_after_pings`` clear pings), ping by ping, without imaging. Each tile's
plan is then the list of pings the streaming worker images into it, in order, as index
ranges of the run's segment files: a task images exactly those (and checks that the
imager took exactly those), so that its tile equals ``svss process``'s voxel for voxel.

The one check the plan cannot make without the samples is the ADC-code range of
:func:`~svss_daq.ping_gate.ping_problem`; a ping refused for it is found by the tasks
of its tiles (:class:`~.task.PingsRefused`), and the run is planned again with it
refused (``exclude``), as ``svss process`` refuses it, and counted in the run's
``refused`` (:mod:`.run`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.frames import TrackLine
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.ping_gate import PingGate, PingRejected
from svss_daq.rawfile import RawFileError, RawRunReader, run_of

from ..imaging.imager import seam_planes
from ..imaging.pose_check import check_pose_flags
from ..imaging.schedule import PingStep, TileSchedule
from ..imaging.grid import tile_grid
from ..imaging.handback import Handback
from ..run_worker import LIVE_POSES, focus_poses, run_poses
from ..seabed.stage import seabed_stage

log = logging.getLogger(__name__)


class PlanMismatch(RuntimeError):
    """A tile task's imager took other pings than the plan gave it."""


@dataclass(frozen=True)
class TilePlan:
    """One tile of one run: what a task needs (file paths and ping index ranges, never
    the pings themselves). ``ranges``: (raw file, first index, index past the last) in
    imaging order; ``sequences``: the pings the tile must hold, in order; ``span``: the
    run's first and last tile index (every other tile in it is closed in the task's
    imager, so that only this one is formed: no ping of the run reaches a tile outside
    it); ``line``: the run's tile frame (origin N, E m; heading rad; interface down
    m)."""
    run_id: str
    folder: str
    index: int
    ranges: tuple[tuple[str, int, int], ...]
    sequences: tuple[int, ...]
    span: tuple[int, int]
    line: tuple[float, float, float, float]
    hardware_id: str
    #: the pose of each ping of ``sequences`` when the run was re-navigated (None: the
    #: poses recorded with the pings)
    poses: tuple[NavSnapshot, ...] | None = None
    #: what the pings are posed with (tile provenance ``poses``)
    pose_source: str = LIVE_POSES
    #: the run's sediment-speed stage's summary (the tiles are imaged with its estimate,
    #: :func:`svss_proc.seabed.speed.applied`; tile provenance ``seabed``)
    seabed: dict | None = None
    #: products without seams (:class:`Handback`): where ``svss process`` hands the
    #: tile back among the run's tiles (0, 1, ...); whether the tile handed back just
    #: before it is tile ``index - 1`` (its last planes and contacts are then this
    #: tile's :class:`~svss_proc.products.chain.Before`); how many of tile
    #: ``index + 1``'s pings were imaged when this tile was handed back with its first
    #: planes (None: handed back without them); whether those planes are tile
    #: ``index + 1``'s final ones (no later ping of it reaches them)
    order: int = 0
    before: bool = False
    after_pings: int | None = None
    after_final: bool = True

    @property
    def key(self) -> str:
        """The task's name (unique in a survey)."""
        return f"tile-{self.folder}-{self.index}"

    @property
    def others(self) -> set[int]:
        """The run's tiles but this one."""
        return set(range(self.span[0], self.span[1] + 1)) - {self.index}

    @property
    def n_pings(self) -> int:
        return len(self.sequences)

    def track_line(self) -> TrackLine:
        n, e, heading, interface = self.line
        return TrackLine((n, e), heading, interface)


@dataclass
class RunPlan:
    """The tiles of one run (its segment files in order)."""
    run_id: str
    folder: str
    paths: list[Path]
    hardware_id: str
    n_pings: int
    tiles: list[TilePlan] = field(default_factory=list)
    refused: dict[str, int] = field(default_factory=dict)
    late_pings: int = 0
    #: what the pings are posed with
    poses: str = LIVE_POSES
    #: what the autofocus stage did (:func:`svss_proc.run_worker.focus_poses`)
    autofocus: dict = field(default_factory=lambda: {"enabled": False})
    #: the sediment speed the run is imaged with and where it came from
    #: (:func:`svss_proc.seabed.stage.seabed_stage`)
    seabed: dict | None = None


def _ranges(refs: list[tuple[int, int]], paths: list[Path]) -> tuple:
    """(segment, index) references, in order, as (path, start, stop) runs."""
    out: list[list] = []
    for seg, i in refs:
        if out and out[-1][0] == seg and out[-1][2] == i:
            out[-1][2] = i + 1
        else:
            out.append([seg, i, i + 1])
    return tuple((str(paths[s]), a, b) for s, a, b in out)


class TilePlanner:
    """A run's tiles planned on poses alone: the streaming worker's gate and its
    :class:`~svss_proc.imaging.schedule.TileSchedule` (see the module doc); ``tiles``:
    tile index -> [(ref, sequence)] of the pings imaged into it, in order."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: ProcessingConfig,
                 source: str, name: str):
        self.proc = processing
        self.schedule = TileSchedule(hardware, processing, source=source)
        self.gate = PingGate(hardware, name=name)
        self.tiles: dict[int, list] = {}
        #: the streaming imager's hand-back (products without seams)
        self.handback = Handback(seam_planes(processing), self.schedule.close_after,
                                 tile_grid(processing.tile, 0).shape[0])

    @property
    def line(self) -> TrackLine | None:
        return self.schedule.line

    @property
    def late_pings(self) -> int:
        return self.schedule.late_pings

    def add(self, ping: Ping, ref) -> None:
        """One ping (``ref``: where it lies, kept in the plan)."""
        try:
            check_pose_flags(ping, self.proc.ping_gate)     # as the worker, first
        except PingRejected as exc:
            self.gate.refuse(exc)
            return
        if not self.gate.admit(ping):
            return
        try:
            step = self.schedule.step(ping)
        except PingRejected as exc:
            self.gate.refuse(exc)
            return
        for k in step.reached:                  # a reached tile is made, pings or not
            self.tiles.setdefault(k, [])
        for sl in step.slices:
            self.tiles[sl.tile].append((ref, ping.sequence))
        self.handback.step(step, self.schedule.n_pings)


def _pose_ping(reader: RawRunReader, i: int, meta: dict, zeros: np.ndarray,
               nav: NavSnapshot | None = None) -> Ping:
    """Ping ``i`` of ``reader`` with its records and pose (``nav``, else the recorded
    one) but no samples (a read-only zero view of the right shape: nothing is read or
    allocated)."""
    return Ping(sequence=int(meta["ping_sequence"][i]),
                projector=int(meta["transmit_projector"][i]),
                transmit_time_ns=int(meta["ping_time"][i]),
                sample_rate_hz=reader.sample_rate_hz,
                window_start_ns=int(meta["window_start_ns"][i]),
                samples=zeros, nav=reader.nav(i) if nav is None else nav,
                config_id=reader.hardware.id)


def group_runs(paths: list[str | Path]) -> dict[str, list[Path]]:
    """Raw files grouped into runs, each run's segment files in segment order, runs in
    the order of their first file given; as the catch-up service groups them
    (:class:`svss_daq.catchup_stores.RawRunStore`). A missing or unreadable file raises
    :class:`~svss_daq.rawfile.RawFileError` naming it; two files claiming the same
    segment of one run (two runs of one name) a ValueError naming both."""
    if not paths:
        raise ValueError("svss batch: no raw-run files given")
    runs: dict[str, dict[int, Path]] = {}
    seen: set[Path] = set()
    for p in (Path(q).absolute() for q in paths):      # tasks may run elsewhere
        if not p.is_file():
            raise RawFileError(f"{p}: no such raw-run file")
        if p.resolve() in seen:
            raise ValueError(f"{p}: given twice")
        seen.add(p.resolve())
        run_id, seg = run_of(p)
        segs = runs.setdefault(run_id, {})
        if seg in segs:
            raise ValueError(f"{p} and {segs[seg]}: both segment {seg} of run {run_id!r} "
                             "(two runs of one name? batch them apart, or give them "
                             "distinct run_id attributes)")
        segs[seg] = p
    return {r: [segs[k] for k in sorted(segs)] for r, segs in runs.items()}


def plan_run(run_id: str, folder: str, paths: list[Path],
             processing: Loaded[ProcessingConfig], renavigate: bool | None = None,
             exclude: dict[tuple[str, int], str] | None = None,
             micronav: bool | None = None, autofocus: bool | None = None,
             sediment_speed: str | None = None) -> RunPlan:
    """Plan the tiles of one run (its segment files, in order) for ``processing``, its
    pings posed as :func:`svss_proc.run_worker.run_poses` decides (``renavigate``: the
    whole run, every segment's instrument records together; ``micronav``: fused with the
    echoes' increments, None as the processing configuration says; ``autofocus``: then
    corrected by the autofocus stage, :func:`~svss_proc.run_worker.focus_poses`;
    ``sediment_speed``: the sediment-speed stage,
    :func:`~svss_proc.seabed.stage.seabed_stage`). ``exclude``: pings found
    refused for their samples, (raw file, index) -> reason: refused here as the
    streaming worker's gate refuses them (counted in ``refused``)."""
    exclude = exclude or {}
    readers = []
    navs: dict[tuple[int, int], NavSnapshot] = {}
    try:
        for p in paths:
            readers.append(RawRunReader(p))
        hw = readers[0].hardware
        for r in readers[1:]:
            if r.hardware.id != hw.id:
                raise RawFileError(f"{r.path}: recorded with hardware configuration "
                                   f"{r.hardware.id}, the run's first segment "
                                   f"{readers[0].path} with {hw.id}; a run has one")
        planner = TilePlanner(hw, processing.value, processing.source,
                              name=f"batch plan of run {run_id}")
        poses, what = run_poses(readers, renavigate, micronav, processing.value)
        poses, what, focus = focus_poses(readers, poses, what, autofocus, processing.value)
        _, seabed = seabed_stage(readers, poses, processing, sediment_speed)
        dig = hw.value.digitiser
        zeros = np.broadcast_to(np.zeros((), np.int32), (dig.n_channels, dig.window_samples))
        n = 0
        for s, r in enumerate(readers):
            meta = r.ping_table()         # the reader checked the samples' shape
            for i in range(len(r)):
                nav = None if poses is None else poses[n + i]
                why = exclude.get((str(paths[s]), i))
                if why is not None:
                    planner.gate.refuse(PingRejected(int(meta["ping_sequence"][i]), why))
                    continue
                if nav is not None:
                    navs[(s, i)] = nav
                planner.add(_pose_ping(r, i, meta, zeros, nav), (s, i))
            n += len(r)
    finally:
        for r in readers:
            r.close()
    plan = RunPlan(run_id, folder, list(paths), hw.id, n,
                   refused=dict(planner.gate.refused), late_pings=planner.late_pings,
                   poses=what, autofocus=focus, seabed=seabed.summary())
    if planner.line is None:
        log.warning("run %s: no ping passed the checks; no tile", run_id)
        return plan
    ln = planner.line
    planner.handback.finish(planner.schedule.n_pings)
    seams = planner.handback.seams()
    line = (float(ln.origin_ne[0]), float(ln.origin_ne[1]), float(ln.heading),
            float(ln.interface_down))
    all_tiles = tuple(sorted(planner.tiles))
    for k in all_tiles:
        refs = planner.tiles[k]
        plan.tiles.append(TilePlan(
            run_id, folder, k, _ranges([r for r, _ in refs], paths),
            tuple(s for _, s in refs), (all_tiles[0], all_tiles[-1]), line, hw.id,
            poses=tuple(navs[r] for r, _ in refs) if navs else None, pose_source=what,
            seabed=plan.seabed,
            **dict(zip(("order", "before", "after_pings", "after_final"), seams[k]))))
    log.info("run %s: %d ping(s) in %d file(s) -> %d tile(s) (frame origin N %.2f E %.2f m, "
             "heading %.1f deg)", run_id, n, len(paths), len(plan.tiles), line[0], line[1],
             math.degrees(line[2]))
    return plan

