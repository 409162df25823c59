"""One batch task: image one planned tile from its raw files and save it, in whatever
process runs it (a Dask worker, or this one).

The task opens the tile's raw files itself and reads only the pings of its ranges
(:meth:`svss_daq.rawfile.RawRunReader.ping`, one by one). It images them with the
streaming worker's :class:`~svss_proc.imaging.imager.TileImager`, set to the run's tile
frame and with the run's other tiles closed, so that only this tile is formed, and
saves it with :func:`~svss_proc.products.chain.save_tile` (products, quicklook, the
atomic ``tile_NNNN.h5`` rename as commit point). A tile whose ``.h5`` is already
there is not imaged again (resume, or a task rerun after its worker died).

With products across the seams (``products.background.across_seams``, the default) a
tile is imaged by one task (``save=False``: :class:`Formed`, kept in the worker's
memory) and saved by another, :func:`save_formed`, with what ``svss process`` gives
its products across the seams: the next tile's first planes (:func:`head_planes`,
:func:`prefix_head`) and the previous tile's last planes and contacts (the previous
save's :class:`Saved`, or :func:`before_from_file`); :mod:`.run` builds that graph.

A ping the imager refuses for its samples (the one check the plan cannot make: ADC codes
out of range, a corrupted ping) is skipped; the task then raises :class:`PingsRefused`
naming every such ping of its tile, without saving it: the batch plans the run again
without them, as ``svss process`` images it (:mod:`.run`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numba
import numpy as np

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.ping_gate import PingRejected
from svss_daq.rawfile import RawFileError, RawRunReader

from ..seabed.speed import applied
from ..imaging.imager import TileImager, seam_planes
from ..products.chain import Before, Seams, save_tile
from ..tiles import Tile, read_detections, read_tile_header, tile_file_paths, tile_line
from .plan import PlanMismatch, TilePlan

log = logging.getLogger(__name__)


class PingsRefused(RuntimeError):
    """Pings of a tile refused for their samples: ``pings`` lists (raw file, index in
    it, sequence, reason). Deterministic: the plan must leave them out."""

    def __init__(self, pings: list[tuple[str, int, int, str]], where: str = ""):
        self.pings = [tuple(p) for p in pings]
        self.where = where
        first = self.pings[0]
        super().__init__(f"{where}{len(self.pings)} ping(s) refused for their samples, "
                         f"e.g. {first[0]}: ping {first[1]} (sequence {first[2]}): "
                         f"{first[3]}")

    def __reduce__(self):                 # across processes (Dask) with its pings
        return (PingsRefused, (self.pings, self.where))


def tile_paths(out: Path, plan: TilePlan) -> tuple[Path, Path]:
    """(tile .h5, quicklook .png) of ``plan`` under the batch output folder ``out``."""
    return tile_file_paths(Path(out) / plan.folder, plan.index)


def _result(plan: TilePlan, h5: Path, detections: int, t0: float, skipped: bool,
            threads: int | None = None) -> dict:
    """A tile's summary; ``threads``: the numba threads its imaging ran with (None: this
    thread's setting, where the tile was imaged in this call)."""
    return {"key": plan.key, "run_id": plan.run_id, "folder": plan.folder,
            "index": plan.index, "pings": plan.n_pings, "detections": int(detections),
            "compute_s": time.perf_counter() - t0, "skipped": skipped, "file": str(h5),
            "pid": os.getpid(),
            "kernel_threads": numba.get_num_threads() if threads is None else threads}


def image_tile(plan: TilePlan, out: str, processing: Loaded[ProcessingConfig],
               kernel_threads: int | None = None, save: bool = True):
    """Image and save one tile; a summary (``pings``, ``detections``, ``compute_s``,
    ``skipped`` when its committed file was already there, ``pid``, ``kernel_threads``).
    ``kernel_threads``: numba threads for this task's kernels (at most the process's
    ``NUMBA_NUM_THREADS``; None: the process's setting). ``save`` False (products
    without seams, :func:`save_formed`): the tile imaged, not saved (:class:`Formed`;
    None when its committed file is already there)."""
    t0 = time.perf_counter()
    if kernel_threads is not None:          # per calling thread; launched threads stay
        numba.set_num_threads(max(1, min(kernel_threads, numba.config.NUMBA_NUM_THREADS)))
    h5, _ = tile_paths(Path(out), plan)
    if h5.is_file():
        if not save:
            return None
        return _result(plan, h5, len(read_tile_header(h5)["detections"]), t0, True)
    tile, hardware = _form(plan, processing)
    if not save:
        return Formed(tile, hardware, time.perf_counter() - t0, numba.get_num_threads())
    save_tile(tile, h5.parent, hardware, processing)
    return _saved(plan, h5, t0)


def _saved(plan: TilePlan, h5: Path, t0: float, before_s: float = 0.0,
           threads: int | None = None) -> dict:
    dets = len(read_tile_header(h5)["detections"])
    log.info("%s: tile %d of run %s, %d pings, %d detections, %.2f s", h5, plan.index,
             plan.run_id, plan.n_pings, dets, time.perf_counter() - t0 + before_s)
    out = _result(plan, h5, dets, t0, False, threads)
    out["compute_s"] += before_s
    return out


def _form(plan: TilePlan, processing: Loaded[ProcessingConfig]):
    """(the tile imaged from the plan's pings, the raw files' hardware configuration)."""
    readers: dict[str, RawRunReader] = {}
    try:
        for path, _, _ in plan.ranges:
            if path not in readers:
                readers[path] = RawRunReader(path)
        hardware = next(iter(readers.values())).hardware
        for r in readers.values():
            if r.hardware.id != plan.hardware_id:
                raise RawFileError(f"{r.path}: hardware configuration {r.hardware.id}, the "
                                   f"plan was made with {plan.hardware_id} (file changed?)")
        proc = applied(processing.value, plan.seabed)   # the run's sediment-speed stage
        imager = TileImager(hardware, proc, source=processing.source)
        # the run's frame; its other tiles written (only this one is formed); the poses
        # judged against the whole run's track by the plan (a tile's pings alone are not
        # that track)
        imager.schedule.fix_frame(plan.track_line())
        imager.schedule.mark_done(plan.others)
        imager.schedule.trust_poses()
        k = 0
        refused: list[tuple[str, int, int, str]] = []
        for path, start, stop in plan.ranges:
            r = readers[path]
            for i in range(start, stop):
                ping = r.ping(i)
                if plan.poses is not None:       # re-navigated: the plan's pose
                    ping = dataclasses.replace(ping, nav=plan.poses[k])
                k += 1
                try:
                    early = imager.add(ping)
                except PingRejected as exc:      # its samples: the plan did not see them
                    log.warning("%s: ping %d (sequence %d) refused imaging tile %d of run "
                                "%s: %s", path, i, ping.sequence, plan.index, plan.run_id,
                                exc.reason)
                    refused.append((path, i, ping.sequence, exc.reason))
                    continue
                if early:
                    raise PlanMismatch(f"{path}: tile(s) {[t.grid.index for t in early]} "
                                       f"closed early imaging tile {plan.index}")
    finally:
        for r in readers.values():
            r.close()
    if refused:
        raise PingsRefused(refused, f"run {plan.run_id} tile {plan.index}: ")
    tiles = {t.grid.index: t for t in imager.finish()}
    tile = tiles.get(plan.index)
    got = tuple(tile.pings) if tile is not None else ()
    if got != plan.sequences:
        raise PlanMismatch(f"run {plan.run_id} tile {plan.index}: imaged pings "
                           f"{got[:5]}... ({len(got)}), the plan has {plan.sequences[:5]}... "
                           f"({len(plan.sequences)})")
    tile.poses, tile.run_id, tile.seabed = plan.pose_source, plan.run_id, plan.seabed
    return tile, hardware


@dataclass
class Formed:
    """A tile imaged by a task and not saved yet (products without seams): it waits in
    the worker's memory for its neighbours' seam planes. ``compute_s``: the imaging's
    time; ``kernel_threads``: the numba threads it ran with (the save runs in another
    task, on whichever worker thread)."""
    tile: Tile
    hardware: Loaded[HardwareConfig]
    compute_s: float
    kernel_threads: int = 0


@dataclass
class Saved:
    """What :func:`save_formed` returns: the tile's summary (:func:`image_tile`'s) and
    what the next tile's products take from it (:class:`Before`)."""
    result: dict
    before: Before | None


def head_planes(formed: Formed | None, plan: TilePlan, out: str, n: int):
    """The first ``n`` along-track planes of tile ``plan`` (magnitude, ping-channel
    pairs), as the streaming imager hands them back with the tile before it
    (``Tile.after``): from the tile just imaged, or from its committed file
    (``formed`` None)."""
    if formed is not None:
        t = formed.tile
        return (np.abs(t.image[:n]).astype(np.float32),
                None if t.coverage is None else t.coverage.channels[:n].copy())
    h5, _ = tile_paths(Path(out), plan)
    with h5py.File(h5, "r") as f:
        return (np.abs(f["image"][:n]).astype(np.float32, copy=False),
                f["coverage_channels"][:n] if "coverage_channels" in f else None)


def prefix_head(plan: TilePlan, pings: int, processing: Loaded[ProcessingConfig], n: int,
                kernel_threads: int | None = None):
    """The first ``n`` planes of tile ``plan`` imaged with its first ``pings`` pings
    only: what the streaming imager handed back with the tile before it when later
    pings of this tile reached those planes again (a turn; rare)."""
    if kernel_threads is not None:
        numba.set_num_threads(max(1, min(kernel_threads, numba.config.NUMBA_NUM_THREADS)))
    tile, hardware = _form(prefix_plan(plan, pings), processing)
    return head_planes(Formed(tile, hardware, 0.0), plan, "", n)


def prefix_plan(plan: TilePlan, pings: int) -> TilePlan:
    """``plan`` cut to its first ``pings`` pings."""
    ranges, left = [], pings
    for path, a, b in plan.ranges:
        if left <= 0:
            break
        take = min(b - a, left)
        ranges.append((path, a, a + take))
        left -= take
    return dataclasses.replace(
        plan, ranges=tuple(ranges), sequences=plan.sequences[:pings],
        poses=None if plan.poses is None else plan.poses[:pings])


def before_from_file(plan: TilePlan, out: str, n: int) -> Before:
    """What the tile after ``plan``'s takes from its committed file: its last ``n``
    planes and its contacts, as :class:`~svss_proc.products.chain.Seams` remembers
    them when it is saved."""
    h5, _ = tile_paths(Path(out), plan)
    with h5py.File(h5, "r") as f:
        mag = np.abs(f["image"][-n:]).astype(np.float32, copy=False)
        ch = f["coverage_channels"][-n:] if "coverage_channels" in f else None
        line = tile_line(dict(f.attrs))
    d, _ = read_detections(h5)
    return Before(plan.index, line, mag, ch,
                  np.stack([d["along_m"], d["cross_m"], d["depth_m"]], axis=1).astype(
                      np.float64),
                  np.asarray(d["peak_db"], dtype=np.float64))


def save_formed(formed: Formed | None, plan: TilePlan, out: str,
                processing: Loaded[ProcessingConfig], before=None, after=None,
                kernel_threads: int | None = None) -> Saved:
    """Save a tile imaged by :func:`image_tile` (``save=False``) with its products
    across the seams, as ``svss process`` saves it: ``before``, the previous tile's
    :class:`Saved` (or :class:`Before`; None: none), ``after``, the next tile's first
    planes (:func:`head_planes`; None: none). A tile committed meanwhile (``formed``
    None: a task run again) is not written again. ``kernel_threads``: numba threads of
    the products' kernels, as :func:`image_tile`'s."""
    if kernel_threads is not None:
        numba.set_num_threads(max(1, min(kernel_threads, numba.config.NUMBA_NUM_THREADS)))
    t0 = time.perf_counter()
    h5, _ = tile_paths(Path(out), plan)
    n = seam_planes(processing.value)
    if formed is None or h5.is_file():
        return Saved(_result(plan, h5, len(read_tile_header(h5)["detections"]), t0, True),
                     before_from_file(plan, out, n))
    seams = Seams()
    seams.last = before.before if isinstance(before, Saved) else before
    tile = formed.tile
    tile.after = after
    save_tile(tile, h5.parent, formed.hardware, processing, seams)
    return Saved(_saved(plan, h5, t0, formed.compute_s, formed.kernel_threads or None),
                 seams.last)


def result_of(saved: Saved) -> dict:
    """The summary of a :class:`Saved` tile (collected by the batch)."""
    return saved.result
