"""The stream worker (``svss worker``): pings from the ZeroMQ stream, with catch-up from
the recording, into tile files, run by run. See docs/worker.md.

- :class:`~svss_proc.run_worker.Worker` (in :mod:`svss_proc.run_worker`, with
  ``svss process``'s :func:`~svss_proc.run_worker.process_raw`) images one run's pings
  into one folder, with its journal and manifest; this module feeds one per run from
  the stream.
- :class:`StreamWorker` and :func:`serve`: ``svss worker``. Pings from the best-effort
  stream go through a reorder buffer keyed by sequence; gaps are fetched from the
  catch-up service (:mod:`svss_daq.ping_service`) or, without one, skipped after a
  bounded wait; each run's tiles go to ``OUT/RUN_ID/``; the worker stays up across runs.
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import os
import re
import secrets
import socket
import time
from pathlib import Path

import zmq

from svss_daq import messages
from svss_daq.config import (HardwareConfig, Loaded, ProcessingConfig, SubscriberConfig,
                             WorkerConfig, from_dict, omitted_default)
from svss_daq.endpoints import check_endpoint
from svss_daq.ping import Ping
from svss_daq.ping_service import (MAX_PINGS_PER_REPLY, PROGRESS_INTERVAL_S, PingFetcher,
                                   RunInfo, ServiceError)
from svss_daq.progress import Progress
from svss_daq.signals import raise_if_stopped, stop_once
from svss_daq.subscriber import subscribe

from .imaging.imager import PingAccumulator, imaging_method
from .folder_lock import FolderLock
from .preflight import preflight
from .products_process import ProductsProcess
from .run_folder import MANIFEST, atomic_json, prepare_output_dir, read_journal, run_folder_name
from .run_worker import MAX_LISTED_GAPS, Worker
from .stream_run import _Run, memory_state  # noqa: F401  (memory_state: svss_proc.worker's)

log = logging.getLogger(__name__)

#: at a run's end, how long pings the recording has not flushed yet are waited for, s
END_WAIT_S = 10.0
#: how often the catch-up service is asked again about a run it did not announce, s
UNANNOUNCED_RECHECK_S = 1.0
#: daq.toml's [subscriber] gap_wait_s, reorder_pings and max_sequence_jump where a caller gives none: the loader's defaults for the omitted keys
GAP_WAIT_S = omitted_default(SubscriberConfig, "gap_wait_s")
REORDER_PINGS = omitted_default(SubscriberConfig, "reorder_pings")
MAX_SEQUENCE_JUMP = omitted_default(SubscriberConfig, "max_sequence_jump")


# --------------------------------------------------------------------------- stream


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
                 max_listed_gaps: int = MAX_LISTED_GAPS, behind: WorkerConfig | None = None,
                 timings: str | Path | None = None):
        preflight(processing.value, processing.source)     # before anything is written
        #: what this worker does when behind the sonar (daq.toml [worker])
        self.policy = behind if behind is not None else from_dict(
            WorkerConfig, {}, "[worker] defaults")
        self.behind = False
        #: the products process the runs' workers share (``[worker] products``; None:
        #: inline), started at the first tile
        p = self.policy
        self.offload = (ProductsProcess(hardware, processing, threads=p.products_threads,
                                        nice=p.products_nice)
                        if p.products == "process" else None)
        #: ``--timings FILE``: per run, the stage times, every ping's lag and every
        #: tile's times, rewritten at each run's end (benchmarks/bench_live.py)
        self.timings_path = None if timings is None else Path(timings)
        self.timings: dict[str, dict] = {}
        self.progress_interval_s = progress_interval_s
        self.max_listed_gaps = max_listed_gaps
        #: this worker's id in its progress messages to the catch-up service
        self.client_id = re.sub(r"[^A-Za-z0-9._:-]", "_", (
            f"{socket.gethostname()[:32]}-{os.getpid()}-{secrets.token_hex(4)}"))[:64]
        self.ends_refused = 0            # end markers the catch-up service contradicted
        #: run id -> its raw-run files as the catch-up service names them; the reason
        #: this worker fell back to reading them (None: it did not)
        self._run_files: dict[str, tuple[str, ...]] = {}
        self.fell_back: str | None = None
        #: pings naming a run the catch-up service does not announce (refused: they
        #: never open a run, never interrupt one), by run id
        self.foreign_refused: dict[str, int] = {}
        self._unannounced_at: dict[str, float] = {}   # run id -> when the service said no
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
        worker = self._configured(Worker(self.hardware, self.processing, folder,
                                         run_id=run_id, resume=True,
                                         max_listed_gaps=self.max_listed_gaps, live=True))
        start = worker.resume_sequence if worker.resume_sequence is not None else first
        run = _Run(run_id, worker, start)
        self._say(run)                     # the service knows at once this worker needs it
        log.info("run %s: imaging into %s from ping %s", run_id, folder, start)
        return run

    def _runs(self) -> list[RunInfo] | None:
        try:
            runs = self.fetcher.runs()
        except (TimeoutError, ServiceError, OSError) as exc:
            self.fetch_errors += 1
            log.error("%s", exc)
            if self._fall_back(exc):
                return self._runs()
            return None
        for info in runs:
            if info.files:
                self._run_files[info.run_id] = info.files
        return runs

    def _fall_back(self, exc: Exception) -> bool:
        """The catch-up service did not answer: where this machine holds the runs'
        raw-run files the service named, catch up from them from now on
        (:class:`~svss_daq.recording_fetcher.RecordingFetcher`), saying so once.
        Whether it fell back."""
        from svss_daq.recording_fetcher import RecordingFetcher
        if isinstance(self.fetcher, RecordingFetcher) or isinstance(exc, ServiceError) \
                and "busy" in str(exc):
            return False
        folders = {Path(f).parent for files in self._run_files.values() for f in files
                   if Path(f).is_file()}
        if not folders:
            return False
        gone = self.fetcher
        self.fetcher = RecordingFetcher(folders, timeout_s=min(gone.timeout_s, 1.0))
        self.fell_back = str(exc)
        log.error("catch-up service %s gone (%s): catching up from %s from now on",
                  gone.endpoint, exc, self.fetcher.endpoint)
        try:
            gone.close()
        except Exception:                    # a socket already gone: nothing to close
            pass
        return True

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
        return _Run(None, self._configured(Worker(
            self.hardware, self.processing, folder, max_listed_gaps=self.max_listed_gaps,
            live=True)),
            seq)

    def _configured(self, worker: Worker) -> Worker:
        worker.max_deferred = self.policy.max_deferred_tiles
        worker.offload = self.offload
        worker.max_in_flight = self.policy.products_in_flight
        if self.timings_path is not None:
            worker.lag.timeline = []
        return worker

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

    def _announced(self, run_id: str, seq: int) -> bool:
        """Whether a stream ping naming run ``run_id`` (not the one being imaged) may
        open it: the catch-up service knows the run (the daemon is recording or has
        recorded it). A run it does not know is refused and counted, its ping
        dropped: a foreign ping on the stream must not move the worker off its run or
        image into a folder of its naming. The service is asked again about an unknown
        run at most once a second. With no service to ask, or none answering while no
        run is being imaged, the stream is followed as it says (nothing can be checked;
        a run being imaged is not left for one the service cannot vouch for)."""
        if self.fetcher is None:
            return True
        now = time.monotonic()
        asked = self._unannounced_at.get(run_id)
        if asked is None or now - asked >= UNANNOUNCED_RECHECK_S:
            info, answered = self._run_info(run_id)
            if info is not None:
                self._unannounced_at.pop(run_id, None)
                return True
            if not answered and self.run is None:
                return True
            self._unannounced_at[run_id] = now
        n = self.foreign_refused.get(run_id, 0) + 1
        self.foreign_refused[run_id] = n
        if n == 1 or n % 100 == 0:
            log.warning("ping %d of run %r refused: the catch-up service does not announce "
                        "that run (%d of its ping(s) refused); the worker stays on %s",
                        seq, run_id, n,
                        f"run {self.run.run_id}" if self.run is not None and
                        self.run.run_id else "no run")
        return False

    def on_ping(self, ping: Ping, run_id: str | None = None) -> None:
        """A ping from the stream; ``run_id``: the run its header names (None: a
        publisher that does not say, its run is then found from the catch-up service or
        its end marker)."""
        seq = ping.sequence
        if run_id is not None and (self.run is None or self.run.run_id != run_id):
            if not self._announced(run_id, seq):
                return
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
            if self.fetcher.progress(self.client_id, r.run_id, r.next_seq, done,
                                     memory_state(r.worker, now)):
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
        w = r.worker
        self._judge(w, ping, w.lag.feed(ping.transmit_time_ns, ping.sequence))
        w.add(ping)
        if not self.behind:
            w.complete_deferred()         # one tile's full products at most per ping

    def _judge(self, w: Worker, ping: Ping, lag: float) -> None:
        """Behind the sonar, or caught up again (daq.toml [worker]): the alarm
        worker.behind raised or cleared (logged, and in the run's manifest), and the
        degrading policy applied to the tiles completed from now on."""
        p = self.policy
        if not self.behind and lag > p.behind_s:
            self.behind = True
            w.behind_episodes += 1
            log.warning("alarm worker.behind raised: ping %d reached the imager %.1f s "
                        "behind the sonar (worker.behind_s %g); %s", ping.sequence, lag,
                        p.behind_s, "every ping is still imaged; tiles get their quick "
                        "look now and their full products once caught up"
                        if p.when_behind == "quicklook_first" else
                        "full products as ever (worker.when_behind full_products)")
        elif self.behind and lag <= p.caught_up_s:
            self.behind = False
            log.warning("alarm worker.behind cleared: ping %d reached the imager %.1f s "
                        "behind the sonar (worker.caught_up_s %g); %d tile(s) wait for "
                        "their full products", ping.sequence, lag, p.caught_up_s,
                        len(w.deferred))
        w.defer_products = self.behind and p.when_behind == "quicklook_first"

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
            log.error("run %s: catch-up of %d..%d failed: %s", r.run_id, first, last, exc)
            if self._fall_back(exc):             # asked again at once, of the recording
                r.retry_at = 0.0
            else:
                r.service_failed = True
                r.retry_at = time.monotonic() + self.fetcher.timeout_s
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
        if r is not None and r.worker is not None and not r.buffer:
            if self.behind and r.worker.deferred:
                # nothing came for a poll: the stream is drained, caught up
                self.behind = False
                r.worker.defer_products = False
                log.warning("alarm worker.behind cleared: the stream is drained; %d "
                            "tile(s) wait for their full products", len(r.worker.deferred))
            if not self.behind:
                r.worker.complete_deferred()
            if r.worker.in_flight:
                r.worker.collect()
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
        if self.offload is not None:
            self.offload.close_if_idle()      # a new one for the next run's first tile
        if finished and r.run_id is not None:
            self.ended.add(r.run_id)
        summary = w.summary(complete)
        self.finished[w.out.name] = summary
        self._write_timings(w)
        log.info("run %s: %d tile(s) in %s (%s)", r.run_id, sum(p.suffix == ".h5"
                 for p in files), w.out, "complete" if complete else
                 f"incomplete: {w.incomplete_reason}")
        self.write_manifest(complete=True)

    def _write_timings(self, w: Worker) -> None:
        if self.timings_path is None:
            return
        self.timings[w.out.name] = {
            "run_id": w.run_id, "pings": w.imager.n_pings,
            "ping_interval_s": self.ping_interval_s,
            "stage_times": w.clock.totals(), "fetch_s": round(self.fetch_time_s, 4),
            "behind": {"max_lag_s": round(w.lag.max_lag_s, 3),
                       "episodes": w.behind_episodes,
                       "products_deferred": list(w.deferred_tiles)},
            "tiles": w.tile_times,
            "pings_fed": [list(t) for t in (w.lag.timeline or [])]}
        atomic_json(self.timings_path, {"schema": "svss.worker_timings", "version": 1,
                                        "runs": self.timings})

    def stop(self) -> None:
        """Stopped by a signal: write the open run's tiles (journal: redone on resume)
        and the manifest, marked incomplete."""
        r = self.run
        if r is not None and r.worker is not None:
            log.warning("stopped: writing %d open tile(s)", len(r.worker.imager.active))
            self._say(r, done=True)
            self._finish_run(r, finished=False)
        self.write_manifest(complete=False)

    def close(self) -> None:
        """End the products process (its tiles were written with their runs)."""
        if self.offload is not None:
            self.offload.close()

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
            "foreign_pings_refused": dict(sorted(self.foreign_refused.items())),
            "runs": {name: {"run_id": s["run_id"], "complete": s["complete"],
                            "incomplete": s["incomplete"], "pings": s["pings"],
                            "skipped_pings": s["skipped_pings"], "skipped": s["skipped"],
                            "missing_pings": s.get("missing_pings", 0),
                            "gaps": s.get("gaps", []),
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
          max_listed_gaps: int = MAX_LISTED_GAPS, behind: WorkerConfig | None = None,
          timings: str | Path | None = None) -> list[Path]:
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
    sock = sw = None
    guards = contextlib.ExitStack()
    try:
        guards.enter_context(stop_once("writing the open tiles and the manifest"))
        guards.enter_context(FolderLock(out_dir))     # before anything is written there
        sw = StreamWorker(out_dir, hardware, processing, fetcher=fetcher, force=force,
                          gap_wait_s=gap_wait_s, reorder_pings=reorder_pings,
                          max_sequence_jump=max_sequence_jump,
                          progress_interval_s=progress_interval_s,
                          max_listed_gaps=max_listed_gaps, behind=behind, timings=timings)
        sock = subscribe(endpoint, receive_hwm, curve=curve)
        # the imaging kernel compiled once subscribed (a daemon waiting for its subscriber
        # starts the sonar; the pings queue meanwhile) and before the worker speaks to the
        # service: a first run's compile at the first ping left it silent past the
        # daemon's service.worker_silence_s. (Before subscribing, the daemon's 10 s wait
        # for a subscriber ran out during it on a cold cache.)
        PingAccumulator(hardware, processing.value,
                        method=imaging_method(processing.value, live=True)).warm_up()
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
        if sw is not None:
            sw.close()
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
