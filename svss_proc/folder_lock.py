"""One writer per output folder: an advisory lock (``flock``) on ``.svss-worker.lock`` in
the folder, held while a worker writes there. A second worker on the same folder is
refused with an error naming the folder and the holder's process id (two workers would
image the same pings twice and race on the same files). The kernel releases the lock
when its holder exits, also a holder killed with SIGKILL: a stale lock file never
blocks."""

from __future__ import annotations

import errno
import fcntl
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

LOCK_NAME = ".svss-worker.lock"
#: bytes of a lock file read for the holder's description
_MAX_LOCK_TEXT = 256


class FolderInUse(FileExistsError):
    """Another process holds the folder's lock; the message names it."""


class FolderLock:
    """Hold ``folder``'s lock (made if missing) until :meth:`release` (or the process
    ends). ``what``: the holder's name, written into the lock file with its pid."""

    def __init__(self, folder: str | Path, what: str = "svss worker"):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC,
                                       0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = self._holder()
            os.close(self._fd)
            self._fd = None
            if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
                raise FolderInUse(
                    f"{self.folder}: in use by another {holder} (lock {self.path}); two "
                    "workers must not write one folder: choose another --out, or stop "
                    "that one first") from None
            raise
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{what} pid {os.getpid()}\n".encode(), 0)
        log.debug("%s: locked (%s)", self.folder, self.path)

    def _holder(self) -> str:
        try:
            text = os.pread(self._fd, _MAX_LOCK_TEXT, 0).decode("utf-8", "replace").strip()
        except OSError:
            text = ""
        return text if text else "process (it wrote no pid yet)"

    def release(self) -> None:
        """Give the lock up (the file stays: removing it would race a new holder)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


__all__ = ["FolderInUse", "FolderLock", "LOCK_NAME"]
