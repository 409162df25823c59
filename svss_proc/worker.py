"""The processing worker: pings in (a raw run, or the ZeroMQ stream with catch-up from
the recording), tile files out. See docs/worker.md.

- :class:`Worker` images one run's pings, fed in sequence order, into one folder: tiles
  are written atomically (the .h5 rename is the commit point) and, for a run with an id,
  a journal (``worker_state.json``) records the tile frame, the written tiles and the
  resume point after each tile, so that a killed worker resumes with no missing and no
  duplicated tile.
- :func:`process_raw`: ``svss process RUN.h5 --out DIR`` (tiles directly in DIR).
- :class:`StreamWorker` and :func:`serve`: ``svss worker``. Pings from the best-effort
  stream go through a reorder buffer keyed by sequence; gaps are fetched from the
  catch-up service (:mod:`svss_daq.ping_service`) or, without one, skipped after a
  bounded wait; each run's tiles go to ``OUT/RUN_ID/``; the worker stays up across runs.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import logging
import os
import re
import secrets
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import zmq

from svss_daq import messages
from svss_daq.config import (HardwareConfig, Loaded, ProcessingConfig, SubscriberConfig,
                             omitted_default)
from svss_daq.endpoints import check_endpoint
from svss_daq.frames import TrackLine
from svss_daq import ping as _ping
from svss_daq.nav.renavigate import RenavigationError, records_problem, renavigation
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.ping_gate import PingGate, PingRejected
from svss_daq.ping_service import (MAX_PINGS_PER_REPLY, PROGRESS_INTERVAL_S, PingFetcher,
                                   RunInfo, ServiceError)
from svss_daq.progress import Progress
from svss_daq.rawfile import RawRunReader, run_of
from svss_daq.signals import raise_if_stopped, stop_once
from svss_daq.subscriber import subscribe

from .folder_lock import FolderLock
from .imaging.imager import TileImager
from .imaging.pose_check import check_pose_flags
from .preflight import preflight
from .products.chain import save_tile
from .products.run_products import run_products_at_end
from .survey_index import write_survey_index
from .run_folder import (JOURNAL, JOURNAL_SCHEMA, JOURNAL_VERSION, MANIFEST, atomic_json,
                         prepare_output_dir, read_journal, run_folder_name)
from .tiles import finished_tiles_by_index, tile_file_paths

log = logging.getLogger(__name__)

#: at a run's end, how long pings the recording has not flushed yet are waited for, s
END_WAIT_S = 10.0
#: the navigation's pose flags counted over the imaged pings (manifest ``pose_flags``)
POSE_FLAG_NAMES = tuple((getattr(_ping, f"NAV_{n.upper()}"), n) for n in (
    "gps_fix", "dead_reckoned", "bottom_lock", "simulated", "heading_from_course",
    "heading_from_compass", "held", "clock_retimed", "smoothed", "fused"))
#: what a run's pings were posed with, when nothing else is said (manifest ``poses``)
LIVE_POSES = "recorded live poses"
#: daq.toml's [subscriber] gap_wait_s, reorder_pings, max_sequence_jump and
#: max_listed_gaps where a caller gives none: the loader's defaults for the omitted keys
GAP_WAIT_S = omitted_default(SubscriberConfig, "gap_wait_s")
REORDER_PINGS = omitted_default(SubscriberConfig, "reorder_pings")
MAX_SEQUENCE_JUMP = omitted_default(SubscriberConfig, "max_sequence_jump")
MAX_LISTED_GAPS = omitted_default(SubscriberConfig, "max_listed_gaps")


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
                 max_listed_gaps: int = MAX_LISTED_GAPS):
        self.hardware, self.processing = hardware, processing
        #: ranges [first, last] of the run's pings skipped (never imaged: lost on the
        #: stream and not fetched), the first ``max_listed_gaps``; the rest counted
        self.skipped_ranges: list[list[int]] = []
        self.skipped_unlisted = 0            # pings in ranges beyond the listed ones
        self.max_listed_gaps = max_listed_gaps
        #: why the run is incomplete though it was finished (manifest ``incomplete``)
        self.incomplete_reason: str | None = None
        #: what the pings are posed with (tile provenance and manifest ``poses``)
        self.poses = poses
        #: imaged pings per navigation flag (:data:`POSE_FLAG_NAMES`)
        self.pose_flags: dict[str, int] = {}
        self.out = Path(out_dir)
        self.run_id = run_id
        self.imager = TileImager(hardware, processing.value, source=processing.source)
        prepare_output_dir(self.out, force, resume=resume)
        self.gate = PingGate(hardware, name="worker")
        self.written: list[Path] = []
        self.last_sequence: int | None = None
        self.gaps = 0
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
        atomic_json(self.out / JOURNAL, {
            "schema": JOURNAL_SCHEMA, "version": JOURNAL_VERSION, "run_id": self.run_id,
            "complete": complete,
            "line": None if line is None else {
                "origin_ne": list(line.origin_ne), "heading": line.heading,
                "interface_down": line.interface_down},
            "written": sorted(self.imager.done - set(stopped_open)),
            "stopped_open": sorted(stopped_open),
            "resume_sequence": resume, "last_sequence": self.last_sequence,
            "resumed": self.resumed, "skipped": self.skipped_ranges,
            "skipped_unlisted": self.skipped_unlisted,
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
                log.warning("ping sequence jumps from %d to %d: %d ping(s) missing",
                            self.last_sequence, seq, seq - self.last_sequence - 1)
        if type(seq) is int and (self.last_sequence is None or seq > self.last_sequence):
            self.last_sequence = seq
        for tile in tiles:
            tile.poses = self.poses
            self.written += save_tile(tile, self.out, self.hardware, self.processing)
        if tiles or (self.imager.line is not None and not self._journal_line):
            self._journal_line = True
            self._write_journal()
        return ok

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
        open_tiles = sorted(self.imager.active)
        resume = self.imager.resume_sequence()
        if not complete:
            self._write_journal(stopped_open=open_tiles)    # intent first
        for tile in self.imager.finish():
            tile.poses = self.poses
            self.written += save_tile(tile, self.out, self.hardware, self.processing)
        refused = dict(self.gate.refused)
        if self.gate.n_refused or self.imaging_errors or self.imager.late_pings:
            log.warning("%d ping(s) refused %s, %d failed in imaging, %d reached only "
                        "tiles already written", self.gate.n_refused, refused,
                        self.imaging_errors, self.imager.late_pings)
        self._write_journal(complete=complete, stopped_open=() if complete else open_tiles,
                            resume=resume)
        atomic_json(self.out / MANIFEST, self.summary(complete))
        run_products_at_end(self.out)     # contacts and mosaic of the run (docs/products.md)
        return self.written

    def summary(self, complete: bool) -> dict:
        return {
            "complete": complete, "run_id": self.run_id, "pings": self.imager.n_pings,
            "poses": self.poses, "pose_flags": dict(sorted(self.pose_flags.items())),
            "pings_refused": self.gate.n_refused, "refused": dict(self.gate.refused),
            "imaging_errors": self.imaging_errors, "late_pings": self.imager.late_pings,
            "malformed_messages": self.malformed_messages,
            "track_reanchored": self.imager.track.reanchored,
            "sequence_gaps": self.gaps, "voxel_channel_updates": self.imager.updates,
            "resumed": self.resumed, "incomplete": self.incomplete_reason,
            "skipped_pings": self.skipped_pings, "skipped": self.skipped_ranges,
            "skipped_unlisted": self.skipped_unlisted,
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


def run_poses(readers: list[RawRunReader], renavigate: bool | None
              ) -> tuple[list[NavSnapshot] | None, str]:
    """The poses a recorded run (its segment readers, in order) is imaged with: (one
    pose per ping, or None for the poses recorded with the pings; what they are, for
    the logs, the tile provenance and the manifest). ``renavigate``: True re-navigates
    from the run's instrument records (:mod:`svss_daq.nav.renavigate`) and raises
    :class:`~svss_daq.nav.renavigate.RenavigationError` naming the file when it has
    none; False keeps the recorded poses; None (the default) re-navigates where the
    records exist and keeps the recorded poses otherwise (logged)."""
    where = str(readers[0].path)
    if renavigate is False:
        log.info("%s: imaged with its %s (re-navigation not asked for)", where, LIVE_POSES)
        return None, LIVE_POSES
    problem = records_problem(readers)
    if problem is not None:
        if renavigate:
            raise RenavigationError(f"cannot re-navigate: {problem}")
        log.info("%s: imaged with its %s (not re-navigated: %s)", where, LIVE_POSES,
                 problem)
        return None, LIVE_POSES
    try:
        renav = renavigation(readers)
    except RenavigationError as exc:
        if renavigate:
            raise
        log.warning("%s; imaged with its %s", exc, LIVE_POSES)
        return None, LIVE_POSES
    log.info("%s: imaged with poses %s", where, renav.description)
    return renav.poses, renav.description


def process_raw(path: str | Path, out_dir: str | Path,
                processing: Loaded[ProcessingConfig], *, force: bool = False,
                renavigate: bool | None = None) -> list[Path]:
    """Image a recorded raw run with the hardware configuration it was recorded with,
    into ``out_dir`` directly (the same tiles as the worker's ``OUT/RUN_ID/``), and
    the folder's survey index (``survey_index.csv``, :mod:`.survey_index`). The pings
    are posed as :func:`run_poses` decides (``renavigate``); the manifest's and the
    tiles' ``poses`` say with what."""
    with RawRunReader(path) as run:
        poses, what = run_poses([run], renavigate)
        worker = Worker(run.hardware, processing, out_dir, force=force, poses=what)
        pings = iter(run) if poses is None else (
            dataclasses.replace(p, nav=nav) for p, nav in zip(run, poses, strict=True))
        files = worker.run(pings, total=len(run))
    run_id, _ = run_of(Path(path))          # as svss batch names it in its index
    write_survey_index(out_dir, [(run_id, p) for p in files if p.suffix == ".h5"])
    return files


# --------------------------------------------------------------------------- stream


@dataclass
class _Run:
    """A run the stream worker is imaging: its folder's worker, the next sequence to
    feed and the reorder buffer."""
    run_id: str | None                  # None: not known yet (no service, before RunEnd)
    worker: Worker | None               # None: a run already finished here (ignored)
    next_seq: int | None
    buffer: dict[int, Ping] = field(default_factory=dict)
    #: pings fed to the worker in this session (all of a run's: nothing to fetch at its end)
    fed: int = 0
    gap_since: float | None = None
    retry_at: float = 0.0
    service_failed: bool = False        # the last catch-up of this run failed
    #: when ``next_seq`` last moved (monotonic): how far ahead a ping may plausibly be
    progress_at: float = field(default_factory=time.monotonic)
    #: the run's last sequence the recording held when last asked, and when (monotonic)
    recorded_last: int | None = None
    recorded_at: float = -float("inf")
    #: when this worker last told the service its progress in the run (monotonic)
    said_at: float = -float("inf")
    #: why the run's end could not be confirmed (the run is then not complete)
    end_unconfirmed: str | None = None
    #: when the stream last brought a ping of the run (monotonic)
    heard_at: float = field(default_factory=time.monotonic)
    #: when the service is next asked about the run while the stream is quiet
    ask_at: float = 0.0


class StreamWorker:
    """Feeds pings from the stream, run by run, to a :class:`Worker` per run folder,
    strictly in sequence order.

    ``fetcher``: the catch-up service's client (None: no service; gaps are skipped after
    ``gap_wait_s``). With a service the worker learns each run's id and first sequence
    from the service (the run being recorded), images every recorded ping from the run's
    first one (or from the journal's resume point), and fetches every gap."""

    def __init__(self, out: str | Path, hardware: Loaded[HardwareConfig],
                 processing: Loaded[ProcessingConfig], *, fetcher: PingFetcher | None = None,
                 gap_wait_s: float = GAP_WAIT_S, reorder_pings: int = REORDER_PINGS,
                 max_sequence_jump: int = MAX_SEQUENCE_JUMP, force: bool = False,
                 progress_interval_s: float = PROGRESS_INTERVAL_S,
                 max_listed_gaps: int = MAX_LISTED_GAPS):
        preflight(processing.value, processing.source)     # before anything is written
        self.progress_interval_s = progress_interval_s
        self.max_listed_gaps = max_listed_gaps
        #: this worker's id in its progress messages to the catch-up service
        self.client_id = re.sub(r"[^A-Za-z0-9._:-]", "_", (
            f"{socket.gethostname()[:32]}-{os.getpid()}-{secrets.token_hex(4)}"))[:64]
        self.ends_refused = 0            # end markers the catch-up service contradicted
        self.out = Path(out)
        self.hardware, self.processing = hardware, processing
        self.fetcher = fetcher
        self.gap_wait_s, self.reorder_pings = gap_wait_s, reorder_pings
        self.max_sequence_jump = max_sequence_jump
        self.ping_interval_s = hardware.value.sequencer.ping_interval_s
        prepare_output_dir(self.out, force, resume=True)
        self.run: _Run | None = None
        self.finished: dict[str, dict] = {}        # run folder -> summary (this session)
        self.ended: set[str] = set()     # runs ended (end marker or caught up whole)
        self.malformed_messages = 0
        self.duplicates = 0
        self.skipped = 0                 # sequences skipped after a gap wait
        self.missing = 0                 # sequences the recording does not hold
        self.fetched = 0
        self.overflow = 0
        self.implausible = 0             # pings refused: sequence implausibly far ahead
        self.fetch_errors = 0
        self.fetch_time_s = 0.0

    # ------------------------------------------------------------------ runs
    def _folder(self, run_id: str) -> Path:
        return self.out / run_folder_name(run_id)

    def _done_here(self, run_id: str) -> bool:
        d = self._folder(run_id)
        try:
            j = read_journal(d)
        except ValueError:
            return False
        if j is not None:
            return bool(j.get("complete"))
        try:
            return bool(json.loads((d / MANIFEST).read_text()).get("complete"))
        except (OSError, ValueError, AttributeError):
            return False

    def _open(self, run_id: str, first: int | None) -> _Run:
        """Start (or resume) imaging run ``run_id`` known to the service."""
        if self._done_here(run_id):
            log.info("run %s: already imaged in %s; its pings are ignored", run_id,
                     self._folder(run_id))
            return _Run(run_id, None, None)
        folder = self._folder(run_id)
        worker = Worker(self.hardware, self.processing, folder, run_id=run_id, resume=True,
                        max_listed_gaps=self.max_listed_gaps)
        start = worker.resume_sequence if worker.resume_sequence is not None else first
        run = _Run(run_id, worker, start)
        self._say(run)                     # the service knows at once this worker needs it
        log.info("run %s: imaging into %s from ping %s", run_id, folder, start)
        return run

    def _runs(self) -> list[RunInfo] | None:
        try:
            return self.fetcher.runs()
        except (TimeoutError, ServiceError, OSError) as exc:
            self.fetch_errors += 1
            log.error("%s", exc)
            return None

    def _attribute(self, seq: int) -> _Run:
        """The run a stream ping with sequence ``seq`` belongs to, when none is open."""
        if self.fetcher is not None:
            runs = self._runs() or []
            live = [r for r in runs if not r.ended and r.first <= seq]
            known = [r for r in runs if r.first <= seq <= r.last]
            pick = (live or known or [None])[-1]
            if pick is not None:
                return self._open(pick.run_id, pick.first)
            log.warning("ping %d: no run of the catch-up service holds it; imaging it as "
                        "a run without an id until its end marker", seq)
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        folder = self.out / f"unnamed-{stamp}-{seq}"
        log.info("a run begins at ping %d: imaging into %s until its end marker names it",
                 seq, folder)
        return _Run(None, Worker(self.hardware, self.processing, folder,
                                 max_listed_gaps=self.max_listed_gaps), seq)

    def resume_unfinished(self) -> None:
        """At start: finish (or continue) the runs whose journal says incomplete."""
        pending = []
        for d in sorted(p for p in self.out.iterdir() if p.is_dir()):
            try:
                j = read_journal(d)
            except ValueError as exc:
                log.error("%s", exc)
                continue
            if j is not None and not j.get("complete") and isinstance(j.get("run_id"), str):
                pending.append(j["run_id"])
        if not pending:
            return
        if self.fetcher is None:
            log.warning("run(s) %s unfinished in %s: restart with --service to finish "
                        "them", ", ".join(pending), self.out)
            return
        runs = {r.run_id: r for r in (self._runs() or [])}
        for run_id in pending:
            info = runs.get(run_id)
            if info is None:
                log.warning("run %s unfinished in %s, unknown to the catch-up service: "
                            "left as it is", run_id, self.out)
                continue
            if info.ended:
                self._catch_up_whole(info)
            elif self.run is None:
                self.run = self._open(run_id, info.first)

    def _catch_up_whole(self, info: RunInfo) -> None:
        """Image an ended run from the recording (from its resume point) and finish it."""
        r = self._open(info.run_id, info.first)
        if r.worker is None:
            return
        prev, self.run = self.run, r
        try:
            self._catch_up(r, r.next_seq, info.last)
            if r.next_seq <= info.last:           # the service failed part-way
                r.buffer.clear()
                self._skip_to(r, info.last + 1, "the catch-up service did not give them")
            self._finish_run(r, finished=True)
        finally:
            self.run = prev

    # ------------------------------------------------------------------ pings
    def _run_info(self, run_id: str) -> tuple[RunInfo | None, bool]:
        """What the catch-up service says of run ``run_id`` (None: it does not know the
        run, or did not answer) and whether it answered."""
        runs = self._runs()
        if runs is None:
            return None, False
        return {i.run_id: i for i in runs}.get(run_id), True

    def _open_tagged(self, run_id: str, seq: int) -> _Run:
        """The run a stream ping names (its header's run id) begins here, at ping
        ``seq``: imaged from its first recorded ping (or the journal's resume point)."""
        first = seq
        if self.fetcher is not None:
            info, answered = self._run_info(run_id)
            if info is not None:
                first = min(info.first, seq)
            elif answered:
                log.warning("run %s: unknown to the catch-up service; imaged from ping %d "
                            "(the stream's), nothing before it fetched", run_id, seq)
        return self._open(run_id, first)

    def _leave(self, r: _Run, new_run: str) -> None:
        """The stream carries pings of run ``new_run`` before run ``r``'s end marker (a
        daemon restarted after a crash; the marker lost): ``r`` is finished from the
        recording when the service says it has ended; otherwise its open tiles are
        written and it is left incomplete (a restarted worker resumes it). Its pings
        never go to another run's tiles."""
        if r.worker is None:
            return
        log.warning("run %s: the stream carries pings of run %s before this run's end "
                    "marker", r.run_id or "(unnamed)", new_run)
        info = None
        if self.fetcher is not None and r.run_id is not None:
            info = self._run_info(r.run_id)[0]
        if info is not None and info.ended:
            self._fetch_rest(r, info)
            self._finish_run(r, finished=True)
            return
        r.end_unconfirmed = (f"the stream moved on to run {new_run} before this run's "
                             "end marker" + ("" if info is None else "; the catch-up "
                                             "service says it is still being recorded"))
        self._finish_run(r, finished=False)

    def on_ping(self, ping: Ping, run_id: str | None = None) -> None:
        """A ping from the stream; ``run_id``: the run its header names (None: a
        publisher that does not say, its run is then found from the catch-up service or
        its end marker)."""
        seq = ping.sequence
        if run_id is not None and (self.run is None or self.run.run_id != run_id):
            if self.run is not None:
                self._leave(self.run, run_id)
            self.run = self._open_tagged(run_id, seq)
        elif self.run is None:
            self.run = self._attribute(seq)
        r = self.run
        if r.worker is None:                      # a run finished here earlier
            return
        if seq < r.next_seq or seq in r.buffer:
            self.duplicates += 1
            log.debug("ping %d: duplicate or already imaged; dropped", seq)
            return
        if not self._plausible(r, seq):
            return
        if len(r.buffer) >= self.reorder_pings:
            if self.fetcher is not None and seq > max(r.buffer):
                self.overflow += 1                # fetched from the recording later
                return
            self._skip_gap(r, "the reorder buffer is full")
        r.buffer[seq] = ping
        r.heard_at = time.monotonic()
        self._say(r)                  # (before imaging: a run's first ping says so at once)
        self.drain()

    def _say(self, r: _Run | None, done: bool = False) -> None:
        """Tell the catch-up service where this worker is in run ``r`` (the first
        sequence it lacks; ``done``: it needs nothing more of the run), at most every
        ``progress_interval_s`` unless ``done``: the daemon keeps its service up after the
        run while this worker lacks pings."""
        if self.fetcher is None or r is None or r.run_id is None or r.next_seq is None:
            return
        now = time.monotonic()
        if done or now - r.said_at >= self.progress_interval_s:
            if self.fetcher.progress(self.client_id, r.run_id, r.next_seq, done):
                r.said_at = now

    def _plausible(self, r: _Run, seq: int) -> bool:
        """Whether ``seq`` may be a ping of run ``r``: at most ``max_sequence_jump``
        past the run's expected sequence plus the pings the sequencer sent since that
        last moved, or held by the recording (asked of the catch-up service at most
        every POLL_SLICE_S; a ping is recorded before it is published). Past that it is
        refused, counted (manifest ``implausible_sequences``) and logged (the 1st, 10th,
        100th...): taken as the run's new frontier it would skip, or ask the service
        for, everything before it."""
        now = time.monotonic()
        allowed = self.max_sequence_jump + int((now - r.progress_at) / self.ping_interval_s)
        if seq - r.next_seq <= allowed or (r.recorded_last is not None
                                           and seq <= r.recorded_last):
            return True
        if self.fetcher is not None and r.run_id is not None \
                and now - r.recorded_at >= POLL_SLICE_S:
            r.recorded_at = now
            info = {i.run_id: i for i in (self._runs() or [])}.get(r.run_id)
            if info is not None:
                r.recorded_last = info.last
                if seq <= info.last:
                    return True
        self.implausible += 1
        if str(self.implausible).rstrip("0") == "1":
            log.warning("run %s: ping %d refused: %d ahead of the expected sequence %d "
                        "(subscriber.max_sequence_jump %d plus the pings of the %.1f s "
                        "since it moved)%s (%d refused in all; logged at every power of "
                        "10)", r.run_id or "(unnamed)", seq, seq - r.next_seq, r.next_seq,
                        self.max_sequence_jump, now - r.progress_at,
                        "" if r.recorded_last is None else
                        f" and past the recording's last ping {r.recorded_last}",
                        self.implausible)
        return False

    def _feed(self, r: _Run, ping: Ping) -> None:
        r.buffer.pop(ping.sequence, None)
        r.next_seq = ping.sequence + 1
        r.gap_since = None
        r.progress_at = time.monotonic()
        r.fed += 1
        r.worker.add(ping)

    def _skip_gap(self, r: _Run, why: str) -> None:
        self._skip_to(r, min(r.buffer), why)

    def _skip_to(self, r: _Run, nxt: int, why: str) -> None:
        """Pings ``r.next_seq``..``nxt - 1`` will not be imaged: counted, logged and
        listed in the run's journal and manifest (the run is then not complete)."""
        n = nxt - r.next_seq
        if n <= 0:
            return
        self.skipped += n
        r.worker.skip(r.next_seq, nxt - 1)
        log.warning("run %s: ping(s) %d..%d skipped (%s)", r.run_id or "(unnamed)",
                    r.next_seq, nxt - 1, why)
        r.next_seq = nxt
        r.gap_since = None
        r.progress_at = time.monotonic()

    def drain(self, final: bool = False) -> None:
        """Feed the buffered pings that are next in sequence; fill or skip gaps."""
        r = self.run
        if r is None or r.worker is None:
            return
        while True:
            while r.next_seq in r.buffer:
                self._feed(r, r.buffer[r.next_seq])
            if not r.buffer:
                return
            now = time.monotonic()
            if r.gap_since is None:
                r.gap_since = now
            if self.fetcher is not None and r.run_id is not None and now >= r.retry_at:
                before = r.next_seq
                self._catch_up(r, r.next_seq, min(r.buffer) - 1)
                if r.next_seq > before:
                    continue
                # asked again soon; after a service that did not answer, only once as
                # long again has passed (a gone service takes at most half the time)
                r.retry_at = time.monotonic() + (self.fetcher.timeout_s if
                                                 r.service_failed else 0.25)
            waited = now - r.gap_since
            if final or waited >= self.gap_wait_s and (
                    self.fetcher is None or r.run_id is None or r.service_failed):
                self._skip_gap(r, "end of run" if final else
                               f"not received within {self.gap_wait_s:g} s")
                continue
            return

    def _catch_up(self, r: _Run, first: int, last: int) -> None:
        """Fetch [first, last] of run ``r`` from the recording and feed it in order
        (with what the buffer holds); sequences the recording lacks are skipped and
        counted. Stops early at what is not recorded yet, or on a service error."""
        if first is None or last < first:
            return
        t0 = time.perf_counter()
        n = 0
        r.service_failed = False
        try:
            while r.next_seq <= last:
                self._say(r)
                got = self.fetcher.fetch_once(r.run_id, r.next_seq, last)
                by_seq = {p.sequence: p for p in got.pings}
                missing = collections.deque(got.missing)    # ranges, ascending
                upto = last if got.next is None else got.next - 1
                while r.next_seq <= upto:
                    q = r.next_seq
                    while missing and missing[0][1] < q:
                        missing.popleft()
                    p = by_seq.get(q)
                    p = r.buffer.get(q) if p is None else p
                    if p is not None:
                        n += q in by_seq
                        self._feed(r, p)
                    elif missing and missing[0][0] <= q:
                        # a range the recording lacks: skipped in one step (up to a
                        # ping the stream brought inside it), one log line
                        end = min(missing[0][1], upto)
                        end = min((s - 1 for s in r.buffer if q < s <= end), default=end)
                        self.missing += end - q + 1
                        log.warning("run %s: ping(s) %d..%d (%d) not in the recording; "
                                    "skipped", r.run_id, q, end, end - q + 1)
                        r.next_seq = end + 1
                        r.progress_at = time.monotonic()
                    else:                     # neither: should not happen; ask again
                        break
                if got.next is None or got.pending or r.next_seq < (got.next or 0):
                    break
        except (TimeoutError, ServiceError, OSError) as exc:
            self.fetch_errors += 1
            r.service_failed = True
            r.retry_at = time.monotonic() + self.fetcher.timeout_s
            log.error("run %s: catch-up of %d..%d failed: %s", r.run_id, first, last, exc)
        finally:
            self.fetched += n
            self.fetch_time_s += time.perf_counter() - t0
            if n:
                log.info("run %s: %d ping(s) fetched from the recording (%d..%d)",
                         r.run_id, n, first, r.next_seq - 1)

    @property
    def runs_ended(self) -> int:
        return len(self.ended)

    def on_end(self, end: messages.RunEnd) -> None:
        """A run's end marker: with a catch-up service, believed only once the service
        says the run has ended (a marker of a run still being recorded -- spoofed, or
        astray -- is refused, counted and logged, and the run goes on); then what is
        left of the run is fetched and its tiles finished. A run whose end the service
        could not confirm (it did not answer, or does not know the run) is finished
        but not complete."""
        r = self.run
        info, unconfirmed = None, None
        if self.fetcher is not None:
            info, answered = self._run_info(end.run_id)
            if not answered:                        # asked once more: a loaded machine
                info, answered = self._run_info(end.run_id)
            current = r is not None and r.run_id in (end.run_id, None)
            if (info is not None and not info.ended) or (info is None and answered
                                                         and not current):
                self.ends_refused += 1
                log.warning("end marker of run %s (%d pings) refused: the catch-up "
                            "service %s (%d end marker(s) refused in all)", end.run_id,
                            end.n_pings, "knows no such run" if info is None else
                            f"says it is still being recorded ({info.n_pings} pings so "
                            "far)", self.ends_refused)
                return
            if info is None:
                unconfirmed = (f"its end marker (which counts {end.n_pings} pings) "
                               "could not be confirmed: the catch-up service " +
                               ("does not know the run" if answered else "did not answer"))
        self.ended.add(end.run_id)
        if r is not None and r.run_id is None:          # named by its end marker
            self.drain(final=True)
            folder = self._folder(end.run_id)
            if folder.exists():
                log.error("run %s: %s exists already; its tiles stay in %s", end.run_id,
                          folder, r.worker.out)
            else:
                r.worker.out.rename(folder)
                r.worker.written = [folder / p.name for p in r.worker.written]
                r.worker.out = folder
            r.worker.run_id = end.run_id
            r.end_unconfirmed = unconfirmed
            self._skip_tail(r, end)
            self._finish_run(r, finished=True)
            self.run = None
            return
        if r is not None and r.run_id == end.run_id:
            if r.worker is not None:
                r.end_unconfirmed = unconfirmed
                if info is not None:
                    self._fetch_rest(r, info)
                else:
                    self.drain(final=True)
                    self._skip_tail(r, end)
                self._finish_run(r, finished=True)
            self.run = None
            return
        if r is not None:
            log.warning("end marker of run %s while imaging run %s", end.run_id, r.run_id)
        if info is not None and not self._done_here(end.run_id):
            log.info("run %s ended; imaging what this worker missed of it from the "
                     "recording", end.run_id)
            self._catch_up_whole(info)
            return
        log.info("end of run %s (%d pings)", end.run_id, end.n_pings)

    def _skip_tail(self, r: _Run, end: messages.RunEnd) -> None:
        """A run ended that the recording cannot be asked about: the pings between the
        last one fed and the run's last (the end marker's ``last``) were never imaged."""
        if end.last is not None and r.next_seq is not None and r.next_seq <= end.last:
            self._skip_to(r, end.last + 1, "after the last ping received; the end marker "
                          "says the run's last is %d" % end.last)

    def _fetch_rest(self, r: _Run, info: RunInfo) -> None:
        """Fetch what run ``r`` lacks up to the last ping the service says it recorded
        (waiting up to END_WAIT_S for what is not flushed yet) and feed what is
        buffered; what the service could not give is skipped: listed, and the run not
        complete."""
        last = info.last
        if r.next_seq <= last:
            deadline = time.monotonic() + END_WAIT_S
            self._catch_up(r, r.next_seq, last)
            while (r.next_seq <= last and not r.service_failed
                   and time.monotonic() < deadline):      # not flushed yet
                time.sleep(POLL_SLICE_S)
                self._catch_up(r, r.next_seq, last)
        self.drain(final=True)
        if r.next_seq <= last:
            self._skip_to(r, last + 1, "the catch-up service did not give them")

    def tick(self) -> None:
        """Between messages: retry or skip gaps whose time has come; tell the service
        where this worker is; when the stream has brought nothing of the open run for
        ``gap_wait_s``, ask the service about it (the stream drops pings, and end
        markers, a slow worker did not take): what it recorded since is fetched, and a
        run it says has ended is finished."""
        self.drain()
        r = self.run
        self._say(r)
        now = time.monotonic()
        if (self.fetcher is None or r is None or r.worker is None or r.run_id is None
                or r.buffer or now - r.heard_at < self.gap_wait_s or now < r.ask_at):
            return
        info, answered = self._run_info(r.run_id)
        r.ask_at = time.monotonic() + (self.gap_wait_s if answered
                                       else self.fetcher.timeout_s)
        if info is None:
            return
        if info.ended:
            log.warning("run %s: ended, says the catch-up service (its end marker has "
                        "not reached this worker); finishing it from the recording",
                        r.run_id)
            self._fetch_rest(r, info)
            self._finish_run(r, finished=True)
            self.run = None
        elif info.last >= r.next_seq:
            self._catch_up(r, r.next_seq, info.last)

    def _finish_run(self, r: _Run, finished: bool) -> None:
        """Write run ``r``'s open tiles and its manifest. ``finished``: the run ended
        (False: this worker stopped, or left the run before its end). The run is
        complete only when finished with every recorded ping imaged (none skipped) and,
        with a service, its end confirmed; the manifest says why not."""
        w = r.worker
        why = []
        if w.skipped_pings:
            why.append(f"{w.skipped_pings} ping(s) not imaged: lost on the stream and "
                       "not fetched from the recording" + (
                           "" if self.fetcher is not None else " (no catch-up service)"))
        if r.end_unconfirmed:
            why.append(r.end_unconfirmed)
        if not finished and not r.end_unconfirmed:
            why.append("stopped before the run's end")
        w.incomplete_reason = "; ".join(why) or None
        complete = finished and not why
        if finished:
            self._say(r, done=True)             # the service is not needed any more
        files = w.finish(complete=complete)
        if finished and r.run_id is not None:
            self.ended.add(r.run_id)
        summary = w.summary(complete)
        self.finished[w.out.name] = summary
        log.info("run %s: %d tile(s) in %s (%s)", r.run_id, sum(p.suffix == ".h5"
                 for p in files), w.out, "complete" if complete else
                 f"incomplete: {w.incomplete_reason}")
        self.write_manifest(complete=True)

    def stop(self) -> None:
        """Stopped by a signal: write the open run's tiles (journal: redone on resume)
        and the manifest, marked incomplete."""
        r = self.run
        if r is not None and r.worker is not None:
            log.warning("stopped: writing %d open tile(s)", len(r.worker.imager.active))
            self._say(r, done=True)
            self._finish_run(r, finished=False)
        self.write_manifest(complete=False)

    def write_manifest(self, complete: bool) -> None:
        """``OUT/manifest.json``: this session's runs, their counts and files."""
        runs = self.finished
        tot = {k: sum(s[k] for s in runs.values()) for k in (
            "pings", "pings_refused", "imaging_errors", "late_pings", "sequence_gaps",
            "voxel_channel_updates")}
        refused: dict[str, int] = {}
        for s in runs.values():
            for k, v in s["refused"].items():
                refused[k] = refused.get(k, 0) + v
        # complete: the session ended normally and every run in it is complete
        complete = complete and all(s["complete"] for s in runs.values())
        atomic_json(self.out / MANIFEST, {
            "complete": complete, **tot, "refused": refused,
            "malformed_messages": self.malformed_messages,
            "duplicate_pings": self.duplicates, "skipped_pings": self.skipped,
            "missing_in_recording": self.missing, "fetched_pings": self.fetched,
            "fetch_errors": self.fetch_errors, "dropped_reorder_full": self.overflow,
            "implausible_sequences": self.implausible,
            "end_markers_refused": self.ends_refused,
            "runs": {name: {"run_id": s["run_id"], "complete": s["complete"],
                            "incomplete": s["incomplete"], "pings": s["pings"],
                            "skipped_pings": s["skipped_pings"], "skipped": s["skipped"],
                            "tiles": sum(f.endswith(".h5") for f in s["files"])}
                     for name, s in runs.items()},
            "files": [f"{name}/{f}" for name, s in runs.items() for f in s["files"]]})

    def files(self) -> list[Path]:
        return [self.out / name / f for name, s in self.finished.items()
                for f in s["files"]]


#: longest wait in one poll, s (signals are handled between polls)
POLL_SLICE_S = 0.2


def serve(endpoint: str, out_dir: str | Path, hardware: Loaded[HardwareConfig],
          processing: Loaded[ProcessingConfig], idle_timeout_s: float | None = None, *,
          receive_hwm: int = 500, force: bool = False, service: str | None = None,
          service_timeout_s: float = 10.0, curve=None, runs: int | None = None,
          gap_wait_s: float = GAP_WAIT_S, reorder_pings: int = REORDER_PINGS,
          max_sequence_jump: int = MAX_SEQUENCE_JUMP,
          max_pings_per_reply: int = MAX_PINGS_PER_REPLY,
          progress_interval_s: float = PROGRESS_INTERVAL_S,
          max_listed_gaps: int = MAX_LISTED_GAPS) -> list[Path]:
    """Receive pings from ``endpoint`` and image them run by run into ``out_dir/RUN_ID/``
    until ``runs`` end-of-run messages (None: no limit) or ``idle_timeout_s`` without a
    message. ``service``: the catch-up service's endpoint (gaps are fetched from the
    recording; a journal lets a killed worker resume). Returns the files written. SIGINT
    (KeyboardInterrupt, also while idle) writes the open tiles and the manifest, marked
    incomplete, and re-raises; a later SIGINT or SIGTERM does not interrupt that
    (:func:`~svss_daq.signals.stop_once`). A folder another worker writes is refused
    (:class:`~.folder_lock.FolderInUse`, naming its pid)."""
    check_endpoint(endpoint, bind=False)            # before anything is written
    if service is not None:
        check_endpoint(service, bind=False)
    preflight(processing.value, processing.source)  # before the folder is made and locked
    fetcher = (PingFetcher(service, curve=curve, timeout_s=service_timeout_s,
                           max_pings_per_reply=max_pings_per_reply)
               if service is not None else None)
    sock = None
    guards = contextlib.ExitStack()
    try:
        guards.enter_context(stop_once("writing the open tiles and the manifest"))
        guards.enter_context(FolderLock(out_dir))     # before anything is written there
        sw = StreamWorker(out_dir, hardware, processing, fetcher=fetcher, force=force,
                          gap_wait_s=gap_wait_s, reorder_pings=reorder_pings,
                          max_sequence_jump=max_sequence_jump,
                          progress_interval_s=progress_interval_s,
                          max_listed_gaps=max_listed_gaps)
        sock = subscribe(endpoint, receive_hwm, curve=curve)
        log.info("worker: waiting for pings from %s%s", endpoint,
                 f" (catch-up service {service})" if service else "")
        try:
            sw.resume_unfinished()
            _loop(sw, sock, endpoint, idle_timeout_s, runs)
        except KeyboardInterrupt:
            sw.stop()
            raise
        sw.write_manifest(complete=True)
        return sw.files()
    finally:
        if sock is not None:
            sock.close(linger=0)
        if fetcher is not None:
            fetcher.close()
        guards.close()


def _loop(sw: StreamWorker, sock: zmq.Socket, endpoint: str, idle_timeout_s: float | None,
          runs: int | None) -> None:
    progress = Progress("imaging", None, log)
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    heard = time.monotonic()         # the last message (wall time: a tick may wait)
    while runs is None or sw.runs_ended < runs:
        raise_if_stopped()              # its own KeyboardInterrupt may have been lost
        if not poller.poll(int(POLL_SLICE_S * 1000)):
            sw.tick()
            if idle_timeout_s is not None and time.monotonic() - heard >= idle_timeout_s:
                log.warning("no message from %s for %.1f s: finishing", endpoint,
                            idle_timeout_s)
                if sw.run is not None and sw.run.worker is not None:
                    sw.drain(final=True)
                    sw._finish_run(sw.run, finished=sw.run.run_id is None)
                    sw.run = None
                break
            continue
        heard = time.monotonic()
        try:
            msg, run_id = messages.recv_tagged(sock)
        except messages.MessageError as exc:
            sw.malformed_messages += 1
            log.error("dropped a malformed message: %s", exc)
            continue
        if isinstance(msg, messages.RunEnd):
            log.info("end of run %s after %d pings", msg.run_id, msg.n_pings)
            sw.on_end(msg)
            continue
        sw.on_ping(msg, run_id)
        progress.update()
