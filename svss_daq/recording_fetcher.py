"""A worker's catch-up from the recording itself, when its catch-up service is gone.

The daemon's catch-up service names each run's raw-run files (``RunInfo.files``, as its
machine names them). A worker on that machine whose service no longer answers (the
daemon exited at the run's end, or was killed) reads what it lacks from those files
instead: :class:`RecordingFetcher` has the client side of
:class:`~svss_daq.ping_service.PingFetcher` that a worker uses (``runs``,
``fetch_once``, ``progress``, ``timeout_s``, ``endpoint``), over a
:class:`~svss_daq.catchup_stores.RawRunStore` of every raw-run file in the folders
those files are in (a run's later segments too). A run read this way has ended when its
files say so (closed by their writer, or summarised).
"""

from __future__ import annotations

import logging
from pathlib import Path

from .catchup_stores import RawRunStore
from .ping_service import MAX_PINGS_PER_REPLY, Fetched, RunInfo, ServiceError, _absent

log = logging.getLogger(__name__)


class RecordingFetcher:
    """Catch-up from the raw-run files in ``folders``."""

    takes_progress = False

    def __init__(self, folders, timeout_s: float = 1.0,
                 max_pings: int = MAX_PINGS_PER_REPLY):
        self.folders = sorted({Path(f) for f in folders})
        self.timeout_s = float(timeout_s)
        self.max_pings = int(max_pings)
        self.endpoint = "the recording in " + ", ".join(str(f) for f in self.folders)
        self._store: RawRunStore | None = None
        self._paths: list[Path] = []
        self._refused: set[Path] = set()

    def _files(self) -> list[Path]:
        return sorted(p for d in self.folders for p in d.glob("*.h5")
                      if not p.name.startswith("."))

    def store(self) -> RawRunStore:
        """The raw-run files of the folders (new ones taken in as they appear; a file
        that does not open as a raw run is left out, logged once)."""
        files = self._files()
        if self._store is None or set(files) - set(self._paths):
            if self._store is not None:
                self._store.close()
            good = []
            for f in files:
                try:
                    RawRunStore([f]).close()
                    good.append(f)
                except Exception as exc:            # not a raw run, or damaged
                    if f not in self._refused:
                        self._refused.add(f)
                        log.warning("catch-up from the recording: %s left out (%s)", f, exc)
            self._store = RawRunStore(good)
            self._paths = files
        return self._store

    def runs(self) -> list[RunInfo]:
        try:
            return self.store().runs()
        except Exception as exc:
            raise ServiceError(f"{self.endpoint}: {exc}") from None

    def fetch_once(self, run_id: str, first: int, last: int) -> Fetched:
        """What the recording holds of [first, last] of ``run_id`` (at most
        ``max_pings`` pings; ``next``: where to go on), as the service answers it."""
        try:
            return self._fetch(run_id, first, last)
        except Exception as exc:
            raise ServiceError(f"{self.endpoint}: {exc}") from None

    def _fetch(self, run_id: str, first: int, last: int) -> Fetched:
        st = self.store()
        present = st.sequences(run_id, first, last)
        nxt = None
        if len(present) > self.max_pings:
            nxt = present[self.max_pings]
            present = present[:self.max_pings]
            last = nxt - 1
        pings = [p for p in (st.read(run_id, q) for q in present) if p is not None]
        served = [p.sequence for p in pings]
        return Fetched(pings, _absent(first, last, served), nxt, False)

    def progress(self, *args, **kwargs) -> bool:
        return False                    # no daemon to tell

    def close(self) -> None:
        if self._store is not None:
            self._store.close()
            self._store = None
