"""A tile's products made in a second process, beside the live imaging
(docs/keeping_up.md, "Products beside the imaging").

A live worker hands each completed tile to :class:`ProductsProcess`: a child process
(``spawn``: no numba or OpenMP state is inherited) that runs the same
:func:`~svss_proc.products.chain.save_tile` the worker runs inline, one tile at a time,
in the order handed (the seams need the previous tile's products: the child keeps each
run's :class:`~svss_proc.products.chain.Seams`). The imaging goes on meanwhile; on a
2-core machine the two share the cores, and the products' serial parts (HDF5, PNG, the
chain's single-threaded steps) no longer hold the pings back.

Nothing handed over is lost: the worker keeps each tile until the child says it is
written, and a child that dies (killed, out of memory) is reported; the worker then
makes the products of every tile it had handed over itself, inline, and goes on inline.
The child ignores SIGINT and SIGTERM (the worker's own stop writes the open tiles through
it) and leaves when told, or when the worker is gone (killed, also half-way through
handing a tile over: the jobs pipe ends). A worker that exits without closing it (an
exception on its way out) tells it at exit, before multiprocessing's own exit handler
would wait for ever on a child that ignores its SIGTERM while the worker, still alive,
holds the jobs pipe open; a child that has not left by then is killed.

The child's time comes back with each tile (the chain's stages, and the whole job as
``products.process``), so the manifest's ``stage_times`` keep the products' figures.
"""

from __future__ import annotations

import atexit
import dataclasses
import logging
import multiprocessing
import os
import pickle
import queue
import signal
import time
import weakref
from pathlib import Path

log = logging.getLogger(__name__)

#: the child's whole job per tile, CPU and wall (manifest ``stage_times``)
PROCESS_STAGE = "products.process"
#: at the worker's exit, how long a products process not closed may take to write the
#: tiles handed to it before it is killed, s
EXIT_WAIT_S = 60.0

#: products processes started and not closed (closed at exit: :func:`_close_at_exit`)
_OPEN: "weakref.WeakSet[ProductsProcess]" = weakref.WeakSet()
_exit_hook = False


def _close_at_exit() -> None:
    """Close every products process still open: registered after multiprocessing's own
    exit handler (at the first start), so it runs before it."""
    for pp in list(_OPEN):
        log.warning("exiting with the products process (pid %s) open: closing it",
                    None if pp._proc is None else pp._proc.pid)
        try:
            pp.close(timeout_s=EXIT_WAIT_S)
        except Exception:                 # the next one is closed all the same
            log.exception("closing the products process failed")


class ProductsProcessGone(RuntimeError):
    """The products process died before it wrote the tiles handed to it."""


@dataclasses.dataclass(frozen=True)
class Written:
    """What the child says of one job: the files written (``error`` None), or why none
    were; the chain's stage times (:meth:`~svss_proc.live_clock.StageClock.totals`),
    and the job's CPU and wall seconds in the child."""
    job: int
    paths: list[Path] | None
    error: str | None
    stages: dict
    cpu_s: float
    wall_s: float


class ProductsProcess:
    """The child process and its two queues. ``threads``: numba threads in the child (1:
    the imaging keeps both cores of a 2-core machine when it needs them); ``nice``: the
    child's niceness above the worker's (the imaging, which must keep up with the pings,
    goes first; the products take the cores' idle time). Started at the first
    :meth:`submit`, so a worker that completes no tile pays nothing."""

    def __init__(self, hardware, processing, threads: int = 1, nice: int = 0):
        self.hardware, self.processing = hardware, processing
        self.threads = int(threads)
        self.nice = int(nice)
        self._ctx = multiprocessing.get_context("spawn")
        self._proc = None
        self._jobs = None
        self._results = None
        self._next = 0
        self._done: dict[int, Written] = {}
        self._pending: set[int] = set()
        #: why the child is gone (None: alive or not started)
        self.gone: str | None = None

    # ------------------------------------------------------------------ parent side
    def _start(self) -> None:
        global _exit_hook
        self._jobs = self._ctx.Queue()
        self._results = self._ctx.Queue()
        self._proc = self._ctx.Process(
            target=serve, name="svss-products", daemon=True,
            args=(self._jobs, self._results, self.hardware, self.processing,
                  self.threads, _log_setup(), self.nice))
        self._proc.start()
        _OPEN.add(self)
        if not _exit_hook:                  # after multiprocessing's (LIFO: before it)
            atexit.register(_close_at_exit)
            _exit_hook = True
        log.info("products process started (pid %d, %d numba thread(s), nice +%d)",
                 self._proc.pid, self.threads, self.nice)

    @property
    def alive(self) -> bool:
        """The child can take tiles (not started yet counts as able)."""
        return self.gone is None and (self._proc is None or self._proc.is_alive())

    def submit(self, out: str | Path, tile) -> int:
        """Hand ``tile`` (finished, host memory) over to be written into ``out``; the
        job's number. The tile is pickled here (a tile that cannot be raises here, not
        on the queue's thread, where it would be lost); the pipe write happens on the
        queue's own thread."""
        if self.gone is not None:
            raise ProductsProcessGone(self.gone)
        payload = pickle.dumps(tile.to_host(), protocol=pickle.HIGHEST_PROTOCOL)
        if self._proc is None:
            self._start()
        job = self._next
        self._next += 1
        self._jobs.put(("tile", job, str(out), payload))
        self._pending.add(job)
        return job

    def end_run(self, out: str | Path) -> None:
        """The run in ``out`` has no more tiles: the child forgets its seams."""
        if self._proc is not None and self.alive:
            self._jobs.put(("end", str(out)))

    def _take(self, r: Written) -> None:
        self._pending.discard(r.job)
        self._done[r.job] = r

    def _pump(self, timeout: float | None = None) -> None:
        """Collect what the child has said; wait up to ``timeout`` s for one answer."""
        if self._results is None:
            return
        try:
            self._take(self._results.get(timeout=timeout) if timeout
                       else self._results.get_nowait())
            while True:
                self._take(self._results.get_nowait())
        except queue.Empty:
            pass

    def result(self, job: int) -> Written | None:
        """Job ``job``'s outcome if the child has given it (once), else None; raises
        :class:`ProductsProcessGone` when the child died without giving it."""
        self._pump()
        if job in self._done:
            return self._done.pop(job)
        if job not in self._pending:
            raise KeyError(f"products job {job}: not handed over, or already taken")
        self._check_alive()
        return None

    def wait(self, job: int) -> Written:
        """Block until job ``job`` is done; :class:`ProductsProcessGone` when the child
        dies first."""
        while True:
            r = self.result(job)
            if r is not None:
                return r
            self._pump(timeout=0.2)
            if job in self._done:
                return self._done.pop(job)

    def _check_alive(self) -> None:
        if self.gone is not None:
            raise ProductsProcessGone(self.gone)
        if self._proc is not None and not self._proc.is_alive():
            self._pump()          # what it said before it went
            code = self._proc.exitcode
            self.gone = f"the products process (pid {self._proc.pid}) exited with {code}"
            log.error("%s; %d tile(s) handed to it are made here instead", self.gone,
                      len(self._pending))
            raise ProductsProcessGone(self.gone)

    def close_if_idle(self) -> bool:
        """:meth:`close` when every tile handed over has been taken back (a run's end:
        an idle child holds memory; the next tile starts a new one)."""
        self._pump()
        if self._pending or self._done:
            return False
        self.close()
        return True

    def close(self, timeout_s: float = 60.0) -> None:
        """Tell the child to leave once its tiles are written; wait for it. A later
        :meth:`submit` starts a new child."""
        if self._proc is None:
            return
        if self._proc.is_alive():
            try:
                self._jobs.put(None)
            except (OSError, ValueError):
                pass
            self._proc.join(timeout_s)
            if self._proc.is_alive():       # it ignores SIGTERM: killed
                log.error("the products process did not leave within %.0f s: killed",
                          timeout_s)
                self._proc.kill()
                self._proc.join(5.0)
        _OPEN.discard(self)
        for q in (self._jobs, self._results):
            q.close()
            q.cancel_join_thread()
        self._proc = self._jobs = self._results = None
        self._pending.clear()
        self._done.clear()
        self.gone = None


# --------------------------------------------------------------------------- the child
def _log_setup() -> tuple:
    """The worker's logging level, and its first handler's format and date format, for
    the child's lines to read as the worker's."""
    root = logging.getLogger()
    fmt = next((h.formatter for h in root.handlers if h.formatter is not None), None)
    return (root.getEffectiveLevel(), None if fmt is None else fmt._fmt,
            None if fmt is None else fmt.datefmt)


def serve(jobs, results, hardware, processing, threads: int, log_setup: tuple,
          nice: int = 0) -> None:
    """The child's loop: ``("tile", job, out, tile)`` written by
    :func:`~svss_proc.products.chain.save_tile` with the run's seams, its outcome put on
    ``results``; ``("end", out)`` forgets a run's seams; None (or the worker gone) ends
    it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if nice > 0:
        os.nice(nice)
    level, fmt, datefmt = log_setup
    logging.basicConfig(level=level, format=fmt or "%(asctime)s %(levelname)s %(name)s: "
                        "%(message)s", datefmt=datefmt)
    import numba

    from .live_clock import StageClock
    from .products.chain import Seams, save_tile
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    seams: dict[str, Seams] = {}
    # the child never puts a job: it lets go of the jobs pipe's write end, so that a
    # worker killed (even half-way through handing a tile over) ends the pipe and a
    # read here ends with EOFError rather than waiting for the rest for ever
    jobs._writer.close()
    while True:
        try:
            msg = jobs.get()
        except (EOFError, OSError):          # the worker is gone
            return
        if msg is None:
            return
        if msg[0] == "end":
            seams.pop(msg[1], None)
            continue
        _, job, out, payload = msg
        clock = StageClock()
        c0, w0 = time.process_time(), time.perf_counter()
        tile = pickle.loads(payload)
        del payload
        try:
            paths, error = save_tile(tile, out, hardware, processing,
                                     seams.setdefault(out, Seams()), clock=clock), None
        except Exception as exc:             # said to the worker, which decides
            log.exception("%s: tile %d: products failed", out, tile.grid.index)
            paths, error = None, f"{type(exc).__name__}: {exc}"
        results.put(Written(job, paths, error, clock.totals(),
                            time.process_time() - c0, time.perf_counter() - w0))
