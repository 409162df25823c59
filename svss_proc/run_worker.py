"""One run's pings into one folder of tiles, with the files that say how far it got.

- :class:`Worker` images one run's pings, fed in sequence order, into one folder: tiles
  are written atomically (the .h5 rename is the commit point) and, for a run with an id,
  a journal (``worker_state.json``) records the tile frame, the written tiles and the
  resume point after each tile, so that a killed worker resumes with no missing and no
  duplicated tile; at the end it writes the run's manifest and run products.
- :func:`run_poses`: what a recorded run is imaged with (re-navigated or live poses).
- :func:`process_raw`: ``svss process RUN.h5 --out DIR`` (tiles directly in DIR).

Nothing here speaks ZeroMQ: :mod:`svss_proc.worker` feeds a :class:`Worker` per run from
the stream (docs/worker.md).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time
from pathlib import Path
from typing import Iterable

from svss_daq import ping as _ping
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig, SubscriberConfig, \
    omitted_default
from svss_daq.frames import TrackLine
from svss_daq.nav.renavigate import RenavigationError, records_problem, renavigation
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.ping_gate import PingGate, PingRejected
from svss_daq.progress import Progress
from svss_daq.rawfile import RawRunReader, run_of

from .imaging.imager import TileImager, imaging_method
from .imaging.pose_check import check_pose_flags
from .live_clock import SonarLag, StageClock, instrument
from .micronav.live import live_stage
from .products.chain import Seams, save_quicklook, save_tile
from .products.run_products import run_products_at_end
from .products_process import PROCESS_STAGE, ProductsProcessGone
from .seabed.speed import configured_speed
from .run_folder import (JOURNAL, JOURNAL_SCHEMA, JOURNAL_VERSION, MANIFEST, atomic_json,
                         prepare_output_dir, read_journal)
from .survey_index import write_survey_index
from .tiles import TileFileError, finished_tiles_by_index, tile_file_paths

log = logging.getLogger(__name__)

#: daq.toml's [subscriber] max_listed_gaps where a caller gives none (the loader's
#: default for the omitted key)
MAX_LISTED_GAPS = omitted_default(SubscriberConfig, "max_listed_gaps")
#: the navigation's pose flags counted over the imaged pings (manifest ``pose_flags``)
POSE_FLAG_NAMES = tuple((getattr(_ping, f"NAV_{n.upper()}"), n) for n in (
    "gps_fix", "dead_reckoned", "bottom_lock", "simulated", "heading_from_course",
    "heading_from_compass", "held", "clock_retimed", "smoothed", "fused"))
#: what a run's pings were posed with, when nothing else is said (manifest ``poses``)
LIVE_POSES = "recorded live poses"


class Worker:
    """Images one run's pings, fed in sequence order, into tile files in ``out_dir``.

    Every ping passes the :class:`~svss_daq.ping_gate.PingGate` and the imager's pose
    checks first; a refused ping is logged, counted (``manifest.json``'s ``refused``) and
    skipped, and the run goes on. ``force`` replaces an earlier run's outputs in
    ``out_dir`` (otherwise refused).

    With a ``run_id`` the worker keeps a journal (``worker_state.json``, written
    atomically when the tile frame is set and after each tile): the tile frame, the
    written tiles and the resume point (the first sequence of the earliest still-open
    tile). ``resume``: continue from the journal in ``out_dir``; the tile files present
    are the truth for what is done, tiles written only because the worker was stopped
    are redone; feed the pings again from :attr:`resume_sequence`."""

    def __init__(self, hardware: Loaded[HardwareConfig], processing: Loaded[ProcessingConfig],
                 out_dir: str | Path, *, force: bool = False, run_id: str | None = None,
                 resume: bool = False, poses: str = LIVE_POSES,
                 max_listed_gaps: int = MAX_LISTED_GAPS, run_label: str | None = None,
                 live_poses: bool | None = None, live: bool = False):
        self.hardware, self.processing = hardware, processing
        #: the run products' resonance columns from the recorded pings
        #: (:func:`~svss_proc.products.run_products.write_run_products`'s ``spectra``;
        #: None: left empty, as live)
        self.contact_spectra = None
        #: ranges [first, last] of the run's pings skipped (never imaged: lost on the
        #: stream and not fetched), the first ``max_listed_gaps``; the rest counted
        self.skipped_ranges: list[list[int]] = []
        self.skipped_unlisted = 0            # pings in ranges beyond the listed ones
        self.max_listed_gaps = max_listed_gaps
        #: why the run is incomplete though it was finished (manifest ``incomplete``)
        self.incomplete_reason: str | None = None
        #: what the pings are posed with (tile provenance and manifest ``poses``)
        self.poses = poses
        #: what the autofocus stage did (manifest ``autofocus``; None: not a recorded
        #: run's processing, :func:`focus_poses`)
        self.autofocus: dict | None = None
        #: the sediment speed the tiles are imaged with and where it came from (manifest
        #: and tiles' ``seabed``; :mod:`svss_proc.seabed`): as configured unless a stage
        #: (:func:`svss_proc.seabed.stage.seabed_stage`) says otherwise
        self.seabed: dict = configured_speed(processing.value).summary()
        #: imaged pings per navigation flag (:data:`POSE_FLAG_NAMES`)
        self.pose_flags: dict[str, int] = {}
        self.out = Path(out_dir)
        self.run_id = run_id
        #: the run the tiles name (tile attribute ``run_id``, the contacts' ``run_id``):
        #: ``run_label``, else ``run_id`` ("" unknown); no journal without ``run_id``
        self.run_label = run_label or run_id or ""
        #: ``live``: the live worker's imaging method (``[imaging] live_method``), else
        #: ``method`` (:func:`~svss_proc.imaging.imager.imaging_method`)
        self.imager = TileImager(hardware, processing.value, source=processing.source,
                                 method=imaging_method(processing.value, live))
        #: CPU and wall time per stage (manifest ``stage_times``; docs/keeping_up.md)
        self.clock = StageClock()
        instrument(self.imager, self.clock)
        #: ``[micronav] live`` on the live poses: each ping imaged at its pose fused with
        #: the echoes' increment from the previous ping (None: off)
        #: ``live_poses``: the pings carry their live poses (None: ``poses`` says so)
        self.micronav = live_stage(hardware, processing.value, self.imager.accumulator,
                                   self.clock, poses == LIVE_POSES if live_poses is None
                                   else live_poses)
        #: how far behind the sonar the pings fed are (the stream worker judges it)
        self.lag = SonarLag()
        #: set by the stream worker while it is behind with ``when_behind =
        #: "quicklook_first"``: tiles completed get their quick look at once and their
        #: full products (and tile file) later (:meth:`complete_deferred`)
        self.defer_products = False
        #: tiles waiting for their full products at most; beyond, the oldest is finished
        self.max_deferred = 4
        #: tiles with only their quick look so far, in order (the seams need their
        #: products made in order)
        self.deferred: list = []
        #: every tile whose full products were deferred in this session (manifest)
        self.deferred_tiles: list[int] = []
        #: a :class:`~svss_proc.products_process.ProductsProcess` that makes the full
        #: products beside the imaging (the stream worker's, daq.toml ``[worker] products
        #: = "process"``); None: inline
        self.offload = None
        #: tiles handed to it and not yet written, in order: (job, tile, entry)
        self.in_flight: list = []
        #: tiles handed over at most; beyond, the worker waits for the oldest
        self.max_in_flight = 2
        #: times the worker fell behind in this run (manifest ``behind``)
        self.behind_episodes = 0
        #: per tile written: index, pings, quick look and tile file times (unix s)
        self.tile_times: list[dict] = []
        prepare_output_dir(self.out, force, resume=resume)
        self.gate = PingGate(hardware, name="worker")
        self.written: list[Path] = []
        self.seams = Seams()       # the previous tile, for products without seams
        self.last_sequence: int | None = None
        self.gaps = 0
        #: pings missing between imaged ones (sequence numbers never imaged) and the
        #: first ``max_listed_gaps`` gaps: first and last missing sequence, how many,
        #: and the distance the body moved across the gap (m; manifest ``gaps``)
        self.missing_in_sequence = 0
        self.gap_list: list[dict] = []
        self._last_ne: tuple[float, float] | None = None
        self.imaging_errors = 0
        self.malformed_messages = 0
        self.resume_sequence: int | None = None
        self.resumed = 0
        self._journal_line = False
        if resume:
            self._resume()

    # ------------------------------------------------------------------ journal
    def _resume(self) -> None:
        j = read_journal(self.out)
        if j is None:
            return
        path = self.out / JOURNAL
        if j.get("processing_config_id") != self.processing.id:
            raise ValueError(f"{path}: written with processing configuration "
                             f"{j.get('processing_config_id')}, not {self.processing.id} "
                             f"({self.processing.source}); resume with the same "
                             "configuration or pass --force")
        try:
            line = j.get("line")
            if line is not None:
                self.imager.schedule.fix_frame(
                    TrackLine(tuple(float(v) for v in line["origin_ne"]),
                              float(line["heading"]), float(line["interface_down"])))
                self._journal_line = True
            redo = {int(k) for k in j.get("stopped_open", [])}
            self.resume_sequence = j.get("resume_sequence")
            if self.resume_sequence is not None:
                self.resume_sequence = int(self.resume_sequence)
            self.resumed = int(j.get("resumed", 0)) + 1
            # pings skipped before the resume point stay skipped (their tiles are
            # written); those after it are fed again
            upto = self.resume_sequence if self.resume_sequence is not None else 0
            for a, b in j.get("skipped", [])[:self.max_listed_gaps]:
                if int(a) < upto:
                    self.skipped_ranges.append([int(a), min(int(b), upto - 1)])
            self.skipped_unlisted = int(j.get("skipped_unlisted", 0))
            if self.micronav is not None:
                self.micronav.resume(j.get("micronav"))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: malformed journal ({exc})") from None
        files = finished_tiles_by_index(self.out)
        for k in sorted(redo & set(files)):
            # written only because the worker was stopped: imaged again from the resume
            # point
            files.pop(k).unlink()
            tile_file_paths(self.out, k)[1].unlink(missing_ok=True)
        self.imager.schedule.mark_done(files)
        self.written = [p for k in sorted(files) for p in
                        (files[k], tile_file_paths(self.out, k)[1])]
        log.info("%s: resuming run %s from ping %s (%d tile(s) done%s)", self.out,
                 self.run_id, self.resume_sequence, len(files),
                 f", {len(redo)} redone" if redo else "")

    def _write_journal(self, complete: bool = False, stopped_open: Iterable[int] = (),
                       resume: int | None = None) -> None:
        if self.run_id is None:
            return
        line = self.imager.line
        resume = resume if resume is not None else self.imager.resume_sequence()
        if resume is None:
            resume = (self.last_sequence + 1 if self.last_sequence is not None
                      else self.resume_sequence)
        # a tile waiting for its full products (or being written by the products
        # process) has no tile file yet: not written, and rebuilt from its first ping
        # after a crash
        waiting = [t.pings[0] for t in self._waiting() if t.pings]
        if waiting:
            resume = min(waiting) if resume is None else min(resume, min(waiting))
        atomic_json(self.out / JOURNAL, {
            "schema": JOURNAL_SCHEMA, "version": JOURNAL_VERSION, "run_id": self.run_id,
            "complete": complete,
            "line": None if line is None else {
                "origin_ne": list(line.origin_ne), "heading": line.heading,
                "interface_down": line.interface_down},
            "written": sorted(self.imager.done - set(stopped_open)
                              - {t.grid.index for t in self._waiting()}),
            "stopped_open": sorted(stopped_open),
            "resume_sequence": resume, "last_sequence": self.last_sequence,
            "resumed": self.resumed, "skipped": self.skipped_ranges,
            "skipped_unlisted": self.skipped_unlisted,
            "micronav": None if self.micronav is None else self.micronav.journal(resume),
            "hardware_config_id": self.hardware.id,
            "processing_config_id": self.processing.id,
            "updated_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})

    # ------------------------------------------------------------------ imaging
    def add(self, ping: Ping) -> bool:
        """Gate and image one ping, writing the tiles it completes; False when refused.
        The pose's navigation flags are judged first
        (:func:`~svss_proc.imaging.pose_check.pose_flags_problem`: a pose without a
        position would otherwise be refused by the gate for its NaN alone)."""
        tiles = []
        ok = False
        try:
            check_pose_flags(ping, self.processing.value.ping_gate)
            flags_ok = True
        except PingRejected as exc:
            self.gate.refuse(exc)
            flags_ok = False
        if flags_ok and self.gate.admit(ping):
            try:
                with self.clock.stage("ping"):
                    if self.micronav is not None:
                        ping = self.micronav.pose(ping)
                    tiles = self.imager.add(ping)
                ok = True
            except PingRejected as exc:
                self.gate.refuse(exc)
            except Exception:                    # a defect must not lose the open tiles
                self.imaging_errors += 1
                log.exception("ping %d: imaging failed; ping skipped", ping.sequence)
        seq = getattr(ping, "sequence", None)
        if ok:
            self._tally_flags(ping.nav.quality)
            if self.last_sequence is not None and seq != self.last_sequence + 1:
                self.gaps += 1
                n_missing = seq - self.last_sequence - 1
                self.missing_in_sequence += max(n_missing, 0)
                ne = (float(ping.nav.north_m), float(ping.nav.east_m))
                moved = (math.hypot(ne[0] - self._last_ne[0], ne[1] - self._last_ne[1])
                         if self._last_ne is not None else None)
                if n_missing > 0 and len(self.gap_list) < self.max_listed_gaps:
                    self.gap_list.append({
                        "first": self.last_sequence + 1, "last": seq - 1,
                        "pings": n_missing,
                        "distance_m": None if moved is None or not math.isfinite(moved)
                        else round(moved, 3)})
                log.warning("ping sequence jumps from %d to %d: %d ping(s) missing%s",
                            self.last_sequence, seq, n_missing,
                            "" if moved is None or not math.isfinite(moved)
                            else f" over {moved:.1f} m of track")
            self._last_ne = (float(ping.nav.north_m), float(ping.nav.east_m))
        if type(seq) is int and (self.last_sequence is None or seq > self.last_sequence):
            self.last_sequence = seq
        for tile in tiles:
            self._save(tile)
        if self.in_flight:
            self.collect()
        if tiles or (self.imager.line is not None and not self._journal_line):
            self._journal_line = True
            self._write_journal()
        return ok

    def _save(self, tile) -> None:
        """Write a completed tile: with its full products, or (behind, or behind tiles
        still waiting: the seams need the products in tile order) its quick look only,
        the tile kept for :meth:`complete_deferred`."""
        tile.poses, tile.run_id, tile.seabed = self.poses, self.run_label, self.seabed
        entry = {"tile": tile.grid.index, "pings": len(tile.pings),
                 "first_ping": min(tile.pings) if tile.pings else None,
                 "last_ping": max(tile.pings) if tile.pings else None,
                 "quicklook_unix_s": None, "written_unix_s": None}
        self.tile_times.append(entry)
        if not (self.defer_products or self.deferred):
            self._save_full(tile, entry)
            return
        with self.clock.stage("quicklook"):
            save_quicklook(tile, self.out)
        entry["quicklook_unix_s"] = round(time.time(), 4)
        self.deferred.append((tile, entry))
        self.deferred_tiles.append(tile.grid.index)
        log.info("%s: tile %d: quick look written; its full products wait (%d tile(s) "
                 "waiting)", self.out, tile.grid.index, len(self.deferred))
        while len(self.deferred) > self.max_deferred:
            log.warning("%s: %d tiles wait for their full products (worker."
                        "max_deferred_tiles %d): finishing tile %d now", self.out,
                        len(self.deferred), self.max_deferred,
                        self.deferred[0][0].grid.index)
            self.complete_deferred()

    def _waiting(self) -> list:
        """The completed tiles without their tile file yet: deferred, or handed over."""
        return [t for t, _ in self.deferred] + [t for _, t, _ in self.in_flight]

    def _save_full(self, tile, entry: dict) -> None:
        if self.offload is not None:
            try:
                with self.clock.stage("products"):      # the hand-over
                    job = self.offload.submit(self.out, tile)
            except ProductsProcessGone:
                self._offload_gone()
            except Exception:                   # a defect: this tile is made here
                log.exception("%s: tile %d: not handed to the products process; made "
                              "here", self.out, tile.grid.index)
            else:
                self.in_flight.append((job, tile, entry))
                while len(self.in_flight) > self.max_in_flight:
                    self.collect(block=True)            # the products are behind: wait
                return
        with self.clock.stage("products"):
            self.written += save_tile(tile, self.out, self.hardware, self.processing,
                                      self.seams, clock=self.clock)
        entry["written_unix_s"] = round(time.time(), 4)

    def collect(self, block: bool = False, stage: str = "products_wait") -> int:
        """Take the tiles the products process has written, oldest first; ``block``:
        wait for the oldest (timed as ``stage``). How many were taken. A tile whose
        products failed there raises :class:`~svss_proc.tiles.TileFileError`, as inline;
        a products process gone has its tiles made here."""
        n = 0
        while self.in_flight:
            job, tile, entry = self.in_flight[0]
            try:
                if block and n == 0:
                    with self.clock.stage(stage):
                        r = self.offload.wait(job)
                else:
                    r = self.offload.result(job)
            except ProductsProcessGone:
                self._offload_gone()
                return n
            if r is None:
                break
            self.in_flight.pop(0)
            n += 1
            for k, v in r.stages.items():
                self.clock.add(k, math.nan if v["cpu_s"] is None else v["cpu_s"],
                               v["wall_s"], v["calls"])
            self.clock.add(PROCESS_STAGE, r.cpu_s, r.wall_s)
            if r.error is not None:
                raise TileFileError(f"{self.out}: tile {tile.grid.index}: products "
                                    f"process: {r.error}")
            self.written += r.paths
            entry["written_unix_s"] = round(time.time(), 4)
        if n:
            self._write_journal()
        return n

    def _offload_gone(self) -> None:
        """The products process died: every tile handed to it is made here, and the
        run goes on inline (the seams it kept are lost: the next tile is made without
        its predecessor's planes)."""
        pending, self.in_flight = self.in_flight, []
        self.offload = None
        self.seams = Seams()
        for _, tile, entry in pending:
            self._save_full(tile, entry)
        if pending:
            self._write_journal()

    def drain_products(self) -> None:
        """Wait until every tile handed to the products process is written (at the
        run's end: timed as ``products_drain``, apart from the waits while imaging)."""
        while self.in_flight:
            self.collect(block=True, stage="products_drain")
        if self.offload is not None:
            self.offload.end_run(self.out)

    def complete_deferred(self) -> bool:
        """Make the full products and the tile file of the oldest tile waiting for them
        (False: none waits)."""
        if not self.deferred:
            return False
        tile, entry = self.deferred.pop(0)
        self._save_full(tile, entry)
        self._write_journal()
        log.info("%s: tile %d: full products written (%d tile(s) still waiting)",
                 self.out, tile.grid.index, len(self.deferred))
        return True

    def skip(self, first: int, last: int) -> None:
        """Pings ``first``..``last`` of the run will never be imaged here (lost on the
        stream and not fetched): listed (the first ``max_listed_gaps`` ranges; beyond,
        counted) in the journal and the manifest, and the run is not complete."""
        if last < first:
            return
        if self.skipped_ranges and self.skipped_ranges[-1][1] + 1 == first:
            self.skipped_ranges[-1][1] = last
        elif len(self.skipped_ranges) < self.max_listed_gaps:
            self.skipped_ranges.append([first, last])
        else:
            self.skipped_unlisted += last - first + 1

    @property
    def skipped_pings(self) -> int:
        """Pings of the run skipped (:meth:`skip`)."""
        return sum(b - a + 1 for a, b in self.skipped_ranges) + self.skipped_unlisted

    def _tally_flags(self, quality: int) -> None:
        for bit, name in POSE_FLAG_NAMES:
            if quality & bit:
                self.pose_flags[name] = self.pose_flags.get(name, 0) + 1

    def finish(self, complete: bool = True) -> list[Path]:
        """Write every open tile and the manifest; ``complete`` False when stopped early
        (the journal then says the open tiles were written only because of the stop, and
        a resume redoes them)."""
        while self.complete_deferred():      # in tile order, before the open tiles
            pass
        self.defer_products = False
        open_tiles = sorted(self.imager.active)
        resume = self.imager.resume_sequence()
        if not complete:
            self._write_journal(stopped_open=open_tiles)    # intent first
        for tile in self.imager.finish():
            self._save(tile)
        self.drain_products()
        refused = dict(self.gate.refused)
        if self.gate.n_refused or self.imaging_errors or self.imager.late_pings:
            log.warning("%d ping(s) refused %s, %d failed in imaging, %d reached only "
                        "tiles already written", self.gate.n_refused, refused,
                        self.imaging_errors, self.imager.late_pings)
        self._write_journal(complete=complete, stopped_open=() if complete else open_tiles,
                            resume=resume)
        atomic_json(self.out / MANIFEST, self.summary(complete))
        with self.clock.stage("run_products"):
            # contacts and mosaic of the run (docs/products.md); the recorded pings read
            # again for the contacts' resonance lines only for a run imaged to its end
            run_products_at_end(self.out, self.contact_spectra if complete else None)
        return self.written

    def summary(self, complete: bool) -> dict:
        return {
            "complete": complete,
            # what is missing, where a reader looks first: pings the sonar's sequence
            # skipped between imaged pings (never recorded, or lost), with the track
            # they span; ``complete`` says the run was finished, not that it is whole
            "missing_pings": self.missing_in_sequence, "gaps": list(self.gap_list),
            "run_id": self.run_id, "pings": self.imager.n_pings,
            "imaging_method": self.imager.accumulator.method,
            "poses": self.poses, "pose_flags": dict(sorted(self.pose_flags.items())),
            "pings_refused": self.gate.n_refused, "refused": dict(self.gate.refused),
            "imaging_errors": self.imaging_errors, "late_pings": self.imager.late_pings,
            "malformed_messages": self.malformed_messages,
            "track_reanchored": self.imager.track.reanchored,
            "sequence_gaps": self.gaps, "voxel_channel_updates": self.imager.updates,
            "resumed": self.resumed, "incomplete": self.incomplete_reason,
            "skipped_pings": self.skipped_pings, "skipped": self.skipped_ranges,
            "skipped_unlisted": self.skipped_unlisted,
            "behind": {"max_lag_s": round(self.lag.max_lag_s, 3),
                       "episodes": self.behind_episodes,
                       "products_deferred": list(self.deferred_tiles)},
            "stage_times": self.clock.totals(),
            "micronav": None if self.micronav is None else self.micronav.summary(),
            "autofocus": self.autofocus, "seabed": self.seabed,
            "files": sorted({p.name for p in self.written})}

    def run(self, pings: Iterable[Ping], total: int | None = None) -> list[Path]:
        """Image every ping of ``pings``; on SIGINT (KeyboardInterrupt) write the open
        tiles and the manifest (marked incomplete) and re-raise."""
        progress = Progress("imaging", total, log)
        try:
            for ping in pings:
                self.add(ping)
                progress.update()
        except KeyboardInterrupt:
            self.stop()
            raise
        return self.finish()

    def stop(self) -> list[Path]:
        """Stopped early (a signal): write the open tiles and the manifest, marked
        incomplete."""
        log.warning("stopped: writing %d open tile(s)", len(self.imager.active))
        return self.finish(complete=False)


def shipped_micronav():
    """config/processing.toml's ``[micronav]`` (for a configuration without the
    table, e.g. config/processing-demo.toml, when ``--micronav`` asks for it)."""
    from svss_daq.config import ConfigError, config_path, load
    path = config_path("processing.toml")
    cfg = load(ProcessingConfig, path).micronav
    if cfg is None:
        raise ConfigError(f"{path}: no [micronav] table (micronavigation's settings)")
    return cfg


def run_poses(readers: list[RawRunReader], renavigate: bool | None,
              micronav: bool | None = False,
              processing: ProcessingConfig | None = None
              ) -> tuple[list[NavSnapshot] | None, str]:
    """The poses a recorded run (its segment readers, in order) is imaged with: (one
    pose per ping, or None for the poses recorded with the pings; what they are, for
    the logs, the tile provenance and the manifest). ``renavigate``: True re-navigates
    from the run's instrument records (:mod:`svss_daq.nav.renavigate`) and raises
    :class:`~svss_daq.nav.renavigate.RenavigationError` naming the file when it has
    none; False keeps the recorded poses; None (the default) re-navigates where the
    records exist and keeps the recorded poses otherwise (logged).

    ``micronav``: True fuses the re-navigated poses with the echoes' ping-to-ping
    increments (:mod:`svss_proc.micronav.renav`, settings of ``processing``'s
    ``[micronav]``, else config/processing.toml's; raises :class:`RenavigationError`
    where the run cannot be re-navigated); None does so where
    ``processing``'s ``[micronav] enabled`` says (logged where it cannot); False not."""
    where = str(readers[0].path)
    mcfg = processing.micronav if processing is not None else None
    fuse = bool(micronav) if micronav is not None else bool(mcfg and mcfg.enabled)
    if fuse and mcfg is None:              # asked for by the command line (--micronav)
        mcfg = shipped_micronav()
        log.info("%s: micronavigation with config/processing.toml's [micronav] settings "
                 "(the processing configuration has none)", where)
    if renavigate is False:
        if micronav:
            raise RenavigationError("micronavigation fuses the re-navigated poses: it "
                                    "cannot run with --no-renavigate")
        log.info("%s: imaged with its %s (re-navigation not asked for)", where, LIVE_POSES)
        return None, LIVE_POSES
    problem = records_problem(readers)
    if problem is not None:
        if renavigate or micronav:
            raise RenavigationError(f"cannot re-navigate: {problem}")
        log.info("%s: imaged with its %s (not re-navigated: %s)", where, LIVE_POSES,
                 problem)
        return None, LIVE_POSES
    try:
        renav = renavigation(readers)
    except RenavigationError as exc:
        if renavigate or micronav:
            raise
        log.warning("%s; imaged with its %s", exc, LIVE_POSES)
        return None, LIVE_POSES
    if not fuse:
        log.info("%s: imaged with poses %s", where, renav.description)
        return renav.poses, renav.description
    from .micronav.renav import fuse_with_navigation
    pings = (p for r in readers for p in r)
    res = fuse_with_navigation(pings, renav.poses, readers[0].hardware.value, processing,
                               renav.config, mcfg)
    what = f"{renav.description}, {res.description}"
    log.info("%s: imaged with poses %s", where, what)
    return res.poses, what


def focus_poses(readers: list[RawRunReader], poses: list[NavSnapshot] | None, what: str,
                autofocus: bool | None, processing: ProcessingConfig
                ) -> tuple[list[NavSnapshot] | None, str, dict]:
    """The poses of :func:`run_poses` (``poses``, ``what``) after the autofocus stage
    (:mod:`svss_proc.micronav.af_stage`) where ``autofocus`` (None: the processing
    configuration's ``[autofocus] enabled``) asks for it: (poses, what they are, the
    manifest's ``autofocus``)."""
    from .micronav.af_stage import OFF, autofocus_wanted, focus_run
    if not autofocus_wanted(autofocus, processing):
        return poses, what, dict(OFF)
    pings = (p for r in readers for p in r)
    if poses is not None:
        pings = (dataclasses.replace(p, nav=nav) for p, nav in zip(pings, poses, strict=True))
    navs, outcome = focus_run(pings, readers[0].hardware, processing)
    log.info("%s: %s", readers[0].path, outcome.description)
    # refused: the poses as they were (the recorded ones stay None: the worker's live
    # stage, if on, treats them as without the stage)
    return (navs if outcome.applied else poses), f"{what}, {outcome.description}", \
        outcome.summary()


def _contact_spectra(posed, hardware, processing, cfg, total, contacts, line) -> list[dict]:
    """The run products' ``spectra``: the recorded pings read again, as imaged."""
    from .products.run_spectra import run_spectra
    return run_spectra(posed(), hardware, processing, cfg, contacts, line, total)


def process_raw(path: str | Path, out_dir: str | Path,
                processing: Loaded[ProcessingConfig], *, force: bool = False,
                renavigate: bool | None = None, micronav: bool | None = None,
                autofocus: bool | None = None,
                sediment_speed: str | None = None) -> list[Path]:
    """Image a recorded raw run with the hardware configuration it was recorded with,
    into ``out_dir`` directly (the same tiles as the worker's ``OUT/RUN_ID/``), and
    the folder's survey index (``survey_index.csv``, :mod:`.survey_index`). The pings
    are posed as :func:`run_poses` decides (``renavigate``, ``micronav``), then corrected
    by the autofocus stage where ``autofocus`` (None: ``[autofocus] enabled``) asks
    (:func:`focus_poses`); the manifest's and the tiles' ``poses`` say with what, the
    manifest's ``autofocus`` what the autofocus did. The sediment speed is then
    estimated from the echoes where ``sediment_speed`` ('estimate' / 'configured'; None:
    ``[seabed] speed``) asks (:func:`~svss_proc.seabed.stage.seabed_stage`); the
    manifest's and the tiles' ``seabed`` say what the tiles were imaged with."""
    from .seabed.stage import seabed_stage
    with RawRunReader(path) as run:
        poses, what = run_poses([run], renavigate, micronav, processing.value)
        poses, what, focus = focus_poses([run], poses, what, autofocus, processing.value)
        used, seabed = seabed_stage([run], poses, processing, sediment_speed)
        worker = Worker(run.hardware, used, out_dir, force=force, poses=what,
                        run_label=run.run_id, live_poses=poses is None)
        worker.autofocus = focus
        worker.seabed = seabed.summary()

        def posed():
            return iter(run) if poses is None else (
                dataclasses.replace(p, nav=nav) for p, nav in zip(run, poses, strict=True))
        spectra = used.value.products.spectra if used.value.products else None
        if spectra is not None:
            worker.contact_spectra = functools.partial(_contact_spectra, posed, run.hardware,
                                                       used.value, spectra, len(run))
        files = worker.run(posed(), total=len(run))
    run_id, _ = run_of(Path(path))          # as svss batch names it in its index
    write_survey_index(out_dir, [(run_id, p) for p in files if p.suffix == ".h5"])
    return files
