"""The acquisition daemon's recorder: one run in rotating raw-run segment files.

Segment ``k`` of run ``R`` is ``<out_dir>/R_<kkk>.h5``, a complete raw-run file (root
attributes ``run_id``, ``segment``) readable while written (SWMR), opened with its first
ping. A new segment starts
when the current one exceeds ``max_file_bytes`` or ``max_file_s``. Pings are appended in
the order they are assembled; the recorder keeps the index sequence -> (segment, row)
so that the catch-up service (:mod:`svss_daq.ping_service`) can read any recorded ping
back while the run goes on. Free disk space is checked after every flush: below
``min_free_bytes`` recording stops with :class:`RecordingStopped` (and a write that
fails for a full disk stops it the same way), leaving every flushed ping readable.

A ping counts as recorded once it is flushed (:attr:`RunRecorder.n_flushed`: the
recorded pings are a prefix of those appended); the catch-up service's view
(:meth:`RunRecorder.info`, :meth:`RunRecorder.recorded`) holds those only, and the
daemon publishes a ping only once it is recorded, so that a write that fails (a full
disk) leaves the stream, the recording and the run's summary in agreement. A reserve
file (``.<run id>.reserve``, ``reserve_bytes``) holds disk space from the start of the
run to its close: released before the summaries are written, it leaves them room on a
full disk. A segment whose file cannot take its summary (its writer stopped on a failed
write) gets it beside it, ``<segment>.summary.json``
(:func:`~svss_daq.rawfile.summary_path`), where :class:`~svss_daq.rawfile.RawRunReader`
reads it.
"""

from __future__ import annotations

import bisect
import contextlib
import errno
import fcntl
import glob
import logging
import os
import re
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from .config import HardwareConfig, Loaded
from .ping import Ping
from .rawfile import (RawFileError, RawRunReader, RawRunWriter, close_interrupted,
                      hdf5_superblock, summary_path, write_summary, write_summary_beside)
from .signals import deferred_stop

log = logging.getLogger(__name__)

#: disk space a run holds in reserve for its closing summaries, MiB (acquire.toml
#: ``disk.reserve_mib`` when given)
RESERVE_MIB = 1.0


class RecordingStopped(RuntimeError):
    """Recording cannot go on (disk full or below the floor); the message says why."""


def segment_path(out_dir: Path, run_id: str, segment: int) -> Path:
    return out_dir / f"{run_id}_{segment:03d}.h5"


def reserve_path(out_dir: Path, run_id: str) -> Path:
    """The file holding a run's disk reserve while it records."""
    return out_dir / f".{run_id}.reserve"


def lock_path(out_dir: Path, run_id: str) -> Path:
    """The file a recording daemon holds locked (``flock``) while it records run
    ``run_id``: the kernel releases the lock when the daemon dies, however it dies, so a
    lock file that can be taken is that of a run whose daemon stopped without closing
    it."""
    return out_dir / f".{run_id}.lock"


_SEGMENT = re.compile(r"(?P<run>.+)_(?P<segment>\d{3,})\.h5")
_LOCK = re.compile(r"\.(?P<run>.+)\.lock")


def run_segments(out_dir: Path, run_id: str) -> list[Path]:
    """The segment files of run ``run_id`` in ``out_dir`` (``<run id>_<kkk>.h5``), in
    segment order."""
    found = []
    for p in Path(out_dir).glob(f"{glob.escape(run_id)}_*.h5"):
        m = _SEGMENT.fullmatch(p.name)
        if m and m["run"] == run_id:
            found.append((int(m["segment"]), p))
    return [p for _, p in sorted(found)]


def _try_lock(path: Path) -> int | None:
    """An open descriptor of ``path`` (created if absent) holding its exclusive lock, or
    None when another process holds it."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    except BaseException:
        os.close(fd)
        raise
    return fd


def take_run_lock(out_dir: Path, run_id: str) -> int:
    """Lock run ``run_id`` in ``out_dir`` for recording (:func:`lock_path`, the daemon's
    pid written in it); the descriptor holding the lock. FileExistsError when a live
    daemon records that run, or when the run is recorded there already (a restarted
    daemon records a new run)."""
    path = lock_path(out_dir, run_id)
    existed = path.exists()
    fd = _try_lock(path)
    if fd is None:
        try:
            who = path.read_text().strip()
        except OSError:
            who = "?"
        raise FileExistsError(f"{out_dir}: run {run_id} is being recorded by another "
                              f"daemon (pid {who or '?'}; {path} is locked)")
    old = run_segments(out_dir, run_id)
    if old:
        if not existed:
            path.unlink(missing_ok=True)
        os.close(fd)
        raise FileExistsError(f"{out_dir}: run {run_id} is recorded there already "
                              f"({', '.join(p.name for p in old[:3])}"
                              f"{', ...' if len(old) > 3 else ''}); a restarted daemon "
                              "records a new run: give another --run-id (or none)")
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    return fd


def free_run_id(out_dir: Path, run_id: str, tries: int = 1000) -> str:
    """``run_id``, or ``run_id-2``, ``-3``, ... when a run of that id is already in
    ``out_dir`` (segments or a lock file): a daemon restarted within the second of its
    predecessor's start gets a run of its own."""
    out_dir = Path(out_dir)
    for k in range(1, tries + 1):
        rid = run_id if k == 1 else f"{run_id}-{k}"
        if not run_segments(out_dir, rid) and not lock_path(out_dir, rid).exists():
            return rid
    raise FileExistsError(f"{out_dir}: runs {run_id} to {run_id}-{tries} exist already")


def _has_summary(reader: RawRunReader) -> bool:
    return "acquisition_summary" in reader.attrs or summary_path(reader.path).is_file()


def close_interrupted_runs(out_dir: str | Path, by_run: str) -> dict[str, dict]:
    """Close and mark the runs in ``out_dir`` whose recording daemon stopped without
    closing them (killed, crashed, the machine lost power): a run whose lock file
    (:func:`lock_path`) nobody holds, or whose segment is still flagged open for
    writing without a lock file (a daemon from before lock files). Each of its
    segments without a summary is closed (:func:`~svss_daq.rawfile.close_interrupted`:
    every flushed ping kept as it was) and gets a summary that says the run was
    interrupted (``interrupted``: true, the pings it holds, ``closed_by``:
    ``by_run``, the run of the daemon that found it); its lock and reserve files are
    removed. Runs of a live daemon (their lock held) are left alone; a daemon calls
    this before it takes its own run's lock (so that a run id given again after its
    daemon was killed is closed, then refused as recorded already). Returns {run id:
    its summary} of the runs closed."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        return {}
    candidates: set[str] = set()
    for p in out_dir.iterdir():
        m = _LOCK.fullmatch(p.name)
        if m:
            candidates.add(m["run"])
            continue
        m = _SEGMENT.fullmatch(p.name)
        if m and not lock_path(out_dir, m["run"]).exists():
            try:
                if hdf5_superblock(p)["flags"] & 1:
                    candidates.add(m["run"])
            except RawFileError as exc:
                log.warning("%s", exc)
    closed = {}
    for run_id in sorted(candidates):
        fd = _try_lock(lock_path(out_dir, run_id))
        if fd is None:
            log.info("%s: run %s is being recorded by a live daemon; left as it is",
                     out_dir, run_id)
            continue
        try:
            summary = _close_run(out_dir, run_id, by_run)
            if summary is not None:
                closed[run_id] = summary
            reserve_path(out_dir, run_id).unlink(missing_ok=True)
            lock_path(out_dir, run_id).unlink(missing_ok=True)
        finally:
            os.close(fd)
    return closed


def _close_run(out_dir: Path, run_id: str, by_run: str) -> dict | None:
    """Close and mark the segments of the interrupted run ``run_id`` (those without a
    summary); its summary, or None when every segment had one."""
    segs = run_segments(out_dir, run_id)
    n_pings, todo = 0, []
    for p in segs:
        try:
            with RawRunReader(p) as r:
                n_pings += len(r)
                if not _has_summary(r):
                    todo.append(p)
        except RawFileError as exc:
            log.error("run %s: %s; that segment is left as it is", run_id, exc)
    if not todo:
        return None
    summary = {
        "run_id": run_id, "interrupted": True,
        "why": "the daemon recording this run stopped without closing it (killed, "
               "crashed or the power lost); every ping flushed before is kept",
        "counters": {"recorded": n_pings}, "segments": [p.name for p in segs],
        "closed_by": by_run,
        "closed_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    for p in todo:
        try:
            how = close_interrupted(p, summary)
        except RawFileError as exc:
            log.error("run %s: %s", run_id, exc)
            continue
        log.warning("%s: run %s was interrupted (its daemon stopped without closing "
                    "it); %s, marked interrupted (%d pings in the run)", p, run_id,
                    "closed" if how == "closed" else "its summary beside it", n_pings)
    return summary


class RunRecorder:
    """Records run ``run_id`` into ``out_dir``; thread-safe (one lock)."""

    def __init__(self, out_dir: str | Path, run_id: str, hardware: Loaded[HardwareConfig],
                 *, flush_every_pings: int, flush_interval_s: float, max_file_bytes: float,
                 max_file_s: float, min_free_bytes: float = 0.0,
                 reserve_bytes: float = RESERVE_MIB * 2**20,
                 environment: dict | None = None, run_attrs: dict | None = None):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.run_id, self.hardware = run_id, hardware
        self.flush_every, self.flush_interval = flush_every_pings, flush_interval_s
        self.max_bytes, self.max_s = max_file_bytes, max_file_s
        self.min_free = min_free_bytes
        self.environment, self.run_attrs = environment or {}, dict(run_attrs or {})
        self.lock = threading.RLock()
        self.segments: list[Path] = []
        self._seg_first: list[int] = []          # index of each segment's first ping
        self.sequences: list[int] = []           # every recorded sequence, in order
        self._sorted = True                      # ... and ascending
        self._where: dict[int, tuple[int, int]] = {}   # sequence -> (segment, row)
        self._readers: dict[int, RawRunReader] = {}
        self.writer: RawRunWriter | None = None
        self._held: list = []
        self.stopped: str | None = None
        self.ended = False
        self._durable = 0                        # pings flushed: a prefix of `sequences`
        self._dmin = self._dmax = -1             # ... their lowest and highest sequence
        self._failed_segments: set[int] = set()  # segments whose writer stopped failing
        # the run's lock, held until close (a run recorded here already is refused)
        self._lock_fd: int | None = take_run_lock(self.out_dir, run_id)
        try:
            self.free_bytes = self._free()
            self._check_free()
            self._reserve = reserve_path(self.out_dir, run_id)
            self._hold_reserve(int(reserve_bytes))
        except BaseException:
            self._release_lock()
            raise
        # the first segment opens with the first ping: a run that never pinged (devices
        # that did not open) leaves no file

    # -- writing -----------------------------------------------------------------------

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """The recorder's lock, and a stop signal deferred until the write is whole (one
        landing inside HDF5 would fail the segment, or leave a ping in the file that the
        bookkeeping does not count)."""
        with deferred_stop(), self.lock:
            yield

    def _free(self) -> int:
        return shutil.disk_usage(self.out_dir).free

    def _hold_reserve(self, n: int) -> None:
        """Take ``n`` bytes of disk for the run's closing summaries (released at
        :meth:`close`); a disk that cannot give them stops recording now."""
        if n <= 0:
            return
        try:
            fd = os.open(self._reserve, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                try:
                    os.posix_fallocate(fd, 0, n)
                except OSError as exc:            # a filesystem without fallocate
                    if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                        raise
                    os.write(fd, bytes(n))
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            self._reserve.unlink(missing_ok=True)
            raise self._stop(f"{self._reserve}: cannot hold {n / 2**20:.2f} MiB in reserve "
                             f"for the run's summary (disk.reserve_mib): "
                             f"{os.strerror(exc.errno) if exc.errno else exc}") from None

    def _release_reserve(self) -> None:
        self._reserve.unlink(missing_ok=True)

    def _release_lock(self) -> None:
        """The run is closed: its lock file goes (a daemon that dies before this leaves
        it, unlocked: :func:`close_interrupted_runs` then knows the run was
        interrupted)."""
        if self._lock_fd is not None:
            lock_path(self.out_dir, self.run_id).unlink(missing_ok=True)
            os.close(self._lock_fd)
            self._lock_fd = None

    def _durable_upto(self, n: int) -> None:
        """The first ``n`` pings appended are on disk."""
        if n <= self._durable:
            return
        new = self.sequences[self._durable:n]
        self._dmin = min(new) if self._dmin < 0 else min(self._dmin, min(new))
        self._dmax = max(self._dmax, max(new))
        self._durable = n

    def _writer_failed(self, w: RawRunWriter, exc: RawFileError) -> RecordingStopped:
        """A write of the current segment failed: what it had flushed stays recorded."""
        self._failed_segments.add(len(self.segments) - 1)
        self._durable_upto(self._seg_first[-1] + w.n_flushed)
        return self._stop(str(exc))

    def _check_free(self) -> None:
        if self.free_bytes < self.min_free:
            raise self._stop(f"{self.out_dir}: {self.free_bytes / 2**20:.0f} MiB free, below "
                             f"the floor of {self.min_free / 2**20:.0f} MiB (disk."
                             "min_free_mib)")

    def _stop(self, why: str) -> RecordingStopped:
        self.stopped = why
        log.error("recording stopped: %s; %d pings of run %s are on disk", why,
                  self.n_flushed, self.run_id)
        return RecordingStopped(why)

    def _open_segment(self) -> None:
        k = len(self.segments)
        path = segment_path(self.out_dir, self.run_id, k)
        attrs = {**self.run_attrs, "run_id": self.run_id, "segment": k}
        try:
            self.writer = RawRunWriter(path, self.hardware,
                                       flush_every_pings=self.flush_every,
                                       flush_interval_s=self.flush_interval,
                                       environment=self.environment, run_attrs=attrs)
        except RawFileError as exc:
            raise self._stop(str(exc)) from None
        self.segments.append(path)
        self._seg_first.append(len(self.sequences))
        self._opened = time.monotonic()
        self._base_bytes = path.stat().st_size
        held, self._held = self._held, []
        for method, args in held:       # events, NMEA, PD0, ping clock between segments
            self._side(method, *args)
        dig = self.hardware.value.digitiser
        self._ping_bytes = 4 * dig.n_channels * dig.window_samples + 256
        log.info("recording run %s segment %d to %s", self.run_id, k, path)

    def _rotate_if_due(self) -> None:
        """A new segment once the next ping would take this one past ``max_file_bytes``
        (size estimated from what was appended: the file grows at flushes) or it is
        older than ``max_file_s``."""
        w = self.writer
        if w.n_pings == 0:
            return
        size = self._base_bytes + w.n_pings * self._ping_bytes
        if size + self._ping_bytes > self.max_bytes or \
                time.monotonic() - self._opened >= self.max_s:
            self._close_segment()               # the next one opens with the next ping

    def _close_segment(self) -> None:
        w, self.writer = self.writer, None
        try:
            w.close()
        except RawFileError as exc:
            raise self._writer_failed(w, exc) from None
        self._durable_upto(len(self.sequences))

    @property
    def n_recorded(self) -> int:
        """Pings appended (recorded once flushed: :attr:`n_flushed`)."""
        return len(self.sequences)

    @property
    def n_flushed(self) -> int:
        """Pings of the run known to be on disk: the first ``n_flushed`` appended."""
        return self._durable

    def append(self, ping: Ping) -> None:
        """Record one ping (raises :class:`RecordingStopped` when recording cannot go
        on; every flushed ping stays readable)."""
        with self._writing():
            if self.stopped:
                raise RecordingStopped(self.stopped)
            if self.writer is None:
                self._open_segment()
            w = self.writer
            flushed = w.n_flushed
            try:
                w.append(ping)
            except RawFileError as exc:
                raise self._writer_failed(w, exc) from None
            seg = len(self.segments) - 1
            if self.sequences and ping.sequence <= self.sequences[-1]:
                self._sorted = False
            self._where[ping.sequence] = (seg, w.n_pings - 1)
            self.sequences.append(ping.sequence)
            self._durable_upto(self._seg_first[-1] + w.n_flushed)
            if w.n_flushed != flushed:          # a flush happened: check the disk
                self.free_bytes = self._free()
                self._check_free()
                # the file's real overhead (metadata, chunk indexes) so far
                self._base_bytes = max(self._base_bytes, w.path.stat().st_size
                                       - w.n_flushed * self._ping_bytes)
            self._rotate_if_due()

    def append_event(self, time_ns: int, kind: str, detail: str) -> None:
        """Record a device event (held for the next segment between two)."""
        self._side("append_event", time_ns, kind, detail)

    def append_nmea(self, time_ns: int, sentence: str) -> None:
        """Record a raw NMEA sentence (held for the next segment between two)."""
        self._side("append_nmea", time_ns, sentence)

    def append_pd0(self, time_ns: int, ensemble: bytes) -> None:
        """Record a PD0 ensemble as received (held for the next segment between two)."""
        self._side("append_pd0", time_ns, ensemble)

    def append_clock_reference(self, receive_ns: int, transmit_ns: int) -> None:
        """Record a ping-clock event (held for the next segment between two)."""
        self._side("append_clock_reference", receive_ns, transmit_ns)

    def _side(self, method: str, *args) -> None:
        with self._writing():
            if self.stopped or self.ended:
                return
            if self.writer is None:
                self._held.append((method, args))
                return
            try:
                getattr(self.writer, method)(*args)
            except RawFileError as exc:
                raise self._writer_failed(self.writer, exc) from None

    def flush(self) -> None:
        """Flush the open segment (what was appended is then recorded)."""
        with self._writing():
            if self.writer is not None and not self.stopped:
                w = self.writer
                try:
                    w.flush()
                except RawFileError as exc:
                    raise self._writer_failed(w, exc) from None
                self._durable_upto(self._seg_first[-1] + w.n_flushed)
                self.free_bytes = self._free()

    def close_files(self) -> None:
        """Close the current segment (flushing it): every ping appended is then
        recorded, unless a write fails (then :attr:`stopped` says why). Idempotent."""
        with self._writing():
            self.ended = True
            if self.writer is not None:
                w, self.writer = self.writer, None
                try:
                    w.close()
                except RawFileError as exc:
                    self._writer_failed(w, exc)
                else:
                    if len(self.segments) - 1 not in self._failed_segments:
                        self._durable_upto(len(self.sequences))
            for r in self._readers.values():
                r.close()
            self._readers.clear()

    def close(self, summary: dict | None = None) -> None:
        """Close the current segment; store ``summary`` in every segment of the run (in
        the file; beside it, ``<segment>.summary.json``, for a segment whose writer
        stopped on a failed write or whose file cannot take it); release the reserve and
        the run's lock."""
        with self._writing():
            self.close_files()
            self._release_reserve()              # room for the summaries on a full disk
            if summary is not None:
                for k, path in enumerate(self.segments):
                    if not path.exists():
                        continue
                    try:
                        if k in self._failed_segments:
                            raise RawFileError(f"{path}: its writer stopped on a failed "
                                               "write; the file is left as it was")
                        write_summary(path, summary)
                        continue
                    except RawFileError as exc:
                        why = exc
                    try:
                        side = write_summary_beside(path, summary)
                        log.warning("the acquisition summary of %s is in %s (%s)", path,
                                    side, why)
                    except RawFileError as exc:
                        log.error("%s; %s", why, exc)
            self._release_lock()

    # -- reading back (the catch-up service's store) -----------------------------------

    def info(self) -> dict:
        """The run as recorded so far (flushed pings only)."""
        with self.lock:
            return {"run_id": self.run_id, "first": self._dmin, "last": self._dmax,
                    "n_pings": self._durable, "ended": self.ended}

    def recorded(self, first: int, last: int) -> list[int]:
        """Recorded (flushed) sequences within [first, last], ascending."""
        with self.lock:
            n = self._durable
            if self._sorted:
                s = self.sequences
                return s[bisect.bisect_left(s, first, 0, n):bisect.bisect_right(s, last, 0, n)]
            s = sorted(self.sequences[:n])
            return s[bisect.bisect_left(s, first):bisect.bisect_right(s, last)]

    def read(self, sequence: int) -> Ping | None:
        """The recorded ping ``sequence`` (None when it was never recorded)."""
        with self.lock:
            where = self._where.get(sequence)
            if where is None:
                return None
            seg, row = where
            if seg == len(self.segments) - 1 and self.writer is not None:
                return self.writer.read_ping(row)
            if seg not in self._readers:
                self._readers[seg] = RawRunReader(self.segments[seg])
            return self._readers[seg].ping(row)
