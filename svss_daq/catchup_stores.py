"""The catch-up service's ping stores: where a :class:`~svss_daq.ping_service.PingService`
finds recorded pings.

:class:`RawRunStore` serves raw-run files (read through
:class:`~svss_daq.rawfile.RawRunReader`, runs spanning several segment files, files
still being written read again when they change); :class:`ReplayStore` shows one the
way a replay publishes it; :class:`RecordingStore` serves an acquisition daemon's
recording: the run being recorded, read back from its
:class:`~svss_daq.recorder.RunRecorder`, and the earlier runs in the same folder. Each
is a :class:`~svss_daq.ping_service.PingStore`.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Iterable

import numpy as np

from .ping import Ping
from .ping_service import RunInfo
from .rawfile import RawFileError, RawRunReader, summary_path

if TYPE_CHECKING:
    from .recorder import RunRecorder

log = logging.getLogger(__name__)


@dataclass
class _Segment:
    path: Path
    run_id: str
    segment: int
    reader: RawRunReader
    mtime_ns: int
    index: dict[int, int]           # sequence -> ping index in this file

    @property
    def clean(self) -> bool:
        return bool(self.reader.clean)


def _summarised(s: _Segment) -> bool:
    return "acquisition_summary" in s.reader.attrs or summary_path(s.path).is_file()


class RawRunStore:
    """Recorded raw-run files (:class:`~svss_daq.rawfile.RawRunReader`) as a
    :class:`~svss_daq.ping_service.PingStore`.

    A run's id is the file's root attribute ``run_id`` and its segment number the root
    attribute ``segment`` (the acquisition daemon writes both; when absent the id is the
    file's stem and the segment 0); a run may span several segment files. A run has ended
    when all its segment files were closed by their writer (and, when any segment carries
    the root attribute ``run_ended``, one of them says true). A file still being written
    is read again, when asked about sequences past what was read, once it has changed on
    disk. An unreadable file raises :class:`~svss_daq.rawfile.RawFileError` here, or
    with ``skip_unreadable`` is left out (logged) and the others served."""

    def __init__(self, paths: Iterable[str | Path], skip_unreadable: bool = False):
        self._lock = threading.RLock()
        self._segments: list[_Segment] = []
        for p in paths:
            try:
                self._segments.append(self._open(Path(p)))
            except RawFileError as exc:
                if not skip_unreadable:
                    raise
                log.warning("catch-up: not served: %s", exc)
        if not self._segments:
            raise ValueError("RawRunStore: no raw-run files given")
        order = {}
        for s in self._segments:          # runs in the order of their first file given
            order.setdefault(s.run_id, len(order))
        self._segments.sort(key=lambda s: (order[s.run_id], s.segment))

    @staticmethod
    def _open(path: Path, reader: RawRunReader | None = None) -> _Segment:
        mtime = path.stat().st_mtime_ns
        r = reader or RawRunReader(path)
        seqs = r.ping_table()["ping_sequence"]
        return _Segment(path, r.run_id, r.segment, r, mtime,
                        {int(s): i for i, s in enumerate(seqs)})

    def _refresh(self, run_id: str) -> None:
        """Read again the segments of ``run_id`` still being written that changed."""
        for k, s in enumerate(self._segments):
            if s.run_id != run_id or s.clean:
                continue
            try:
                mtime = s.path.stat().st_mtime_ns
            except OSError:
                continue
            if mtime == s.mtime_ns:
                continue
            # close first: HDF5 would hand a second open in this process (and the
            # reader's forked child) the file as it was first read
            s.reader.close()
            try:
                new = self._open(s.path)
            except (RawFileError, OSError) as exc:
                s.mtime_ns = -1                   # read it again at the next request
                raise RawFileError(f"{s.path}: could not read it again ({exc})") from None
            self._segments[k] = new

    def _of(self, run_id: str) -> list[_Segment]:
        segs = [s for s in self._segments if s.run_id == run_id]
        if not segs:
            raise KeyError(run_id)
        return segs

    def run_ids(self) -> list[str]:
        out: list[str] = []
        for s in self._segments:
            if s.run_id not in out:
                out.append(s.run_id)
        return out

    def paths(self, run_id: str) -> list[Path]:
        return [s.path for s in self._of(run_id)]

    def info(self, run_id: str, refresh: bool = True) -> RunInfo:
        with self._lock:
            if refresh:
                self._refresh(run_id)
            segs = self._of(run_id)
            seqs = [q for s in segs for q in s.index]
            flags = [bool(np.asarray(s.reader.attrs["run_ended"]).reshape(()))
                     for s in segs if "run_ended" in s.reader.attrs]
            # a segment with its run's summary (in it, or beside it when its writer
            # stopped on a failed write) is closed: a daemon closed the run, or found it
            # interrupted and marked it so (svss_daq.recorder.close_interrupted_runs)
            ended = all(s.clean or _summarised(s) for s in segs) \
                and (not flags or any(flags))
            return RunInfo(run_id, min(seqs) if seqs else 0, max(seqs) if seqs else -1,
                           len(seqs), ended,
                           tuple(str(s.path.resolve()) for s in segs))

    def runs(self) -> list[RunInfo]:
        return [self.info(r) for r in self.run_ids()]

    def sequences(self, run_id: str, first: int, last: int) -> list[int]:
        with self._lock:
            segs = self._of(run_id)
            if any(last > max(s.index, default=-1) for s in segs if not s.clean):
                self._refresh(run_id)
                segs = self._of(run_id)
            return sorted({q for s in segs for q in s.index if first <= q <= last})

    def read(self, run_id: str, sequence: int) -> Ping | None:
        with self._lock:
            for s in self._of(run_id):
                i = s.index.get(sequence)
                if i is not None:
                    p = s.reader.ping(i)
                    if p.damage:            # not served, as a ping never recorded is not
                        log.error("catch-up: not served: %s", p.damage)
                        return None
                    return p
        return None

    def close(self) -> None:
        with self._lock:
            for s in self._segments:
                s.reader.close()

    def __enter__(self) -> RawRunStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ReplayStore:
    """A :class:`RawRunStore` presented as a replay publishes it, like an acquisition
    daemon's recording: a run is listed once :meth:`begin` is called (before its first
    ping is published) and has ended once :meth:`end` is (after its end marker)."""

    def __init__(self, store: RawRunStore):
        self.store = store
        self._begun: list[str] = []
        self._ended: set[str] = set()
        self._lock = threading.Lock()

    def begin(self, run_id: str) -> None:
        with self._lock:
            if run_id not in self._begun:
                self._begun.append(run_id)

    def end(self, run_id: str) -> None:
        with self._lock:
            self._ended.add(run_id)

    def _visible(self, run_id: str) -> None:
        with self._lock:
            if run_id not in self._begun:
                raise KeyError(run_id)

    def runs(self) -> list[RunInfo]:
        with self._lock:
            begun, ended = list(self._begun), set(self._ended)
        out = []
        for r in begun:
            i = self.store.info(r)
            out.append(RunInfo(i.run_id, i.first, i.last, i.n_pings, r in ended, i.files))
        return out

    def sequences(self, run_id: str, first: int, last: int) -> list[int]:
        self._visible(run_id)
        return self.store.sequences(run_id, first, last)

    def read(self, run_id: str, sequence: int) -> Ping | None:
        self._visible(run_id)
        return self.store.read(run_id, sequence)


class RecordingStore:
    """The catch-up service's view of a recording daemon: the run being recorded (read
    back from :class:`RunRecorder`) and the runs recorded earlier in the same folder
    (raw-run files, :class:`RawRunStore`)."""

    def __init__(self, recorder: RunRecorder):
        self.recorder = recorder
        earlier = sorted(p for p in recorder.out_dir.glob("*.h5")
                         if p not in recorder.segments and not p.name.startswith(
                             recorder.run_id + "_"))
        self.earlier = None
        if earlier:
            try:                              # a damaged old file is left out
                self.earlier = RawRunStore(earlier, skip_unreadable=True)
            except Exception as exc:          # and must not stop a run
                log.warning("catch-up: earlier runs in %s not served (%s)",
                            recorder.out_dir, exc)

    def runs(self) -> list[RunInfo]:
        out = list(self.earlier.runs()) if self.earlier else []
        out.append(RunInfo(**self.recorder.info(), files=tuple(
            str(Path(p).resolve()) for p in self.recorder.segments)))
        return out

    def sequences(self, run_id: str, first: int, last: int) -> list[int]:
        if run_id == self.recorder.run_id:
            return self.recorder.recorded(first, last)
        return self.earlier.sequences(run_id, first, last) if self.earlier else []

    def read(self, run_id: str, sequence: int) -> Ping | None:
        if run_id == self.recorder.run_id:
            return self.recorder.read(sequence)
        return self.earlier.read(run_id, sequence) if self.earlier else None
