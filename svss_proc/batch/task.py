"""One batch task: image one planned tile from its raw files and save it, in whatever
process runs it (a Dask worker, or this one).

The task opens the tile's raw files itself and reads only the pings of its ranges
(:meth:`svss_daq.rawfile.RawRunReader.ping`, one by one). It images them with the
streaming worker's :class:`~svss_proc.imaging.imager.TileImager`, set to the run's tile
frame and with the run's other tiles closed, so that only this tile is formed, and
saves it with :func:`~svss_proc.products.chain.save_tile` (products, quicklook, the
atomic ``tile_NNNN.h5`` rename as commit point). A tile whose ``.h5`` is already
there is not imaged again (resume, or a task rerun after its worker died).

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
from pathlib import Path

import numba

from svss_daq.config import Loaded, ProcessingConfig
from svss_daq.ping_gate import PingRejected
from svss_daq.rawfile import RawFileError, RawRunReader

from ..imaging.imager import TileImager
from ..products.chain import save_tile
from ..tiles import read_tile_header, tile_file_paths
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


def _result(plan: TilePlan, h5: Path, detections: int, t0: float, skipped: bool) -> dict:
    return {"key": plan.key, "run_id": plan.run_id, "folder": plan.folder,
            "index": plan.index, "pings": plan.n_pings, "detections": int(detections),
            "compute_s": time.perf_counter() - t0, "skipped": skipped, "file": str(h5),
            "pid": os.getpid(), "kernel_threads": numba.get_num_threads()}


def image_tile(plan: TilePlan, out: str, processing: Loaded[ProcessingConfig],
               kernel_threads: int | None = None) -> dict:
    """Image and save one tile; a summary (``pings``, ``detections``, ``compute_s``,
    ``skipped`` when its committed file was already there, ``pid``, ``kernel_threads``).
    ``kernel_threads``: numba threads for this task's kernels (at most the process's
    ``NUMBA_NUM_THREADS``; None: the process's setting)."""
    t0 = time.perf_counter()
    if kernel_threads is not None:          # per calling thread; launched threads stay
        numba.set_num_threads(max(1, min(kernel_threads, numba.config.NUMBA_NUM_THREADS)))
    h5, _ = tile_paths(Path(out), plan)
    if h5.is_file():
        return _result(plan, h5, len(read_tile_header(h5)["detections"]), t0, True)
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
        imager = TileImager(hardware, processing.value, source=processing.source)
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
    tile.poses, tile.run_id = plan.pose_source, plan.run_id
    save_tile(tile, h5.parent, hardware, processing)
    dets = len(read_tile_header(h5)["detections"])
    log.info("%s: tile %d of run %s, %d pings, %d detections, %.2f s", h5, plan.index,
             plan.run_id, len(got), dets, time.perf_counter() - t0)
    return _result(plan, h5, dets, t0, False)
