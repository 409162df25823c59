"""Stopping on a signal without being interrupted while stopping.

``svss`` commands turn SIGINT and SIGTERM into :class:`KeyboardInterrupt` and then write
what they hold (tiles, manifests, recordings). A second signal -- Ctrl-C pressed twice, or
a parent that forwards SIGTERM to a child the terminal's Ctrl-C reached already -- would
interrupt that writing half-way: :func:`stop_once` makes the first signal stop the block
and every later one wait (logged) until the writing is done. SIGKILL still stops at once.

A signal handler's exception lands wherever the main thread happens to be, and Python
swallows it there when that is a weakref callback or a ``__del__`` ("Exception ignored
in ..."): the command would then run on as if never signalled (a daemon went on recording
for 20 s after SIGTERM). Every handler here therefore also records the request
(:func:`note_stop`), and long loops call :func:`raise_if_stopped` each round.

Some writing must not be cut at all: a KeyboardInterrupt that lands inside HDF5 comes out
of h5py as an HDF5 error (a segment being created is then "failed", a ping half-appended
leaves the recorder's bookkeeping behind the file). Within :func:`deferred_stop` a stop
signal is only noted; it is raised when the block ends.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
from collections.abc import Iterator

log = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_requested: str | None = None        # "signal SIGTERM" once a stop signal came
_deferring = 0                       # depth of deferred_stop blocks (main thread)
_deferred: str | None = None         # a stop signal that came inside one


def note_stop(signum: int) -> str:
    """Record that signal ``signum`` asked the command to stop; returns the reason
    (``"signal SIGTERM"``) for the :class:`KeyboardInterrupt`."""
    global _requested
    reason = f"signal {signal.Signals(signum).name}"
    _requested = _requested or reason
    return reason


def clear_stop() -> None:
    """Forget an earlier stop request (a command starting in a process that ran one)."""
    global _requested, _deferred
    _requested = _deferred = None


def stop_requested() -> str | None:
    """The reason of the stop signal received, or None."""
    return _requested


def raise_if_stopped() -> None:
    """Raise :class:`KeyboardInterrupt` if a stop signal came (its own exception may
    have been swallowed where it landed)."""
    if _requested is not None:
        raise KeyboardInterrupt(_requested)


def stop_cause(exc: BaseException) -> KeyboardInterrupt | None:
    """The stop signal's :class:`KeyboardInterrupt` behind ``exc``, if a stop was
    requested and ``exc`` was raised because of it: a signal that lands inside a C
    extension's callback (numba unpickling a cached kernel) comes out as that
    extension's ``SystemError``, caused by the KeyboardInterrupt. None otherwise."""
    if _requested is None:
        return None
    seen = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def quiet_unraisable(unraisable) -> None:
    """``sys.unraisablehook``: a stop signal's KeyboardInterrupt that Python swallowed
    (it landed in a finaliser) is noted in one line, not printed as a traceback (the
    loops raise it again); anything else goes to Python's own hook."""
    if (isinstance(unraisable.exc_value, KeyboardInterrupt)
            and _requested is not None):
        log.debug("%s landed in %r; the command's loop stops on it", _requested,
                  unraisable.object)
        return
    sys.__unraisablehook__(unraisable)


def _interrupt(signum: int) -> None:
    """Stop the main thread for signal ``signum``: KeyboardInterrupt now, or at the end
    of the :func:`deferred_stop` block it is in."""
    global _deferred
    reason = note_stop(signum)
    if _deferring:
        _deferred = _deferred or reason
        log.debug("%s inside a write that must not be cut: stopping after it", reason)
        return
    raise KeyboardInterrupt(reason)


def stop_handler(signum, frame) -> None:
    """The handler ``svss`` commands install for SIGINT and SIGTERM."""
    _interrupt(signum)


@contextlib.contextmanager
def deferred_stop() -> Iterator[None]:
    """Within the block a stop signal (from :func:`stop_handler` or :func:`stop_once`'s
    first) is noted, not raised; the :class:`KeyboardInterrupt` comes when the block ends
    (unless it ends with its own exception, which goes on: the request stays noted for
    :func:`raise_if_stopped`). Blocks nest; only the main thread receives signals, so
    elsewhere this does nothing. Keep the block short: it delays the stop."""
    global _deferring, _deferred
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _deferring += 1
    try:
        yield
    except BaseException:
        _deferring -= 1
        if not _deferring:
            _deferred = None                # noted in _requested; this exception goes on
        raise
    _deferring -= 1
    if not _deferring and _deferred is not None:
        reason, _deferred = _deferred, None
        raise KeyboardInterrupt(reason)


@contextlib.contextmanager
def stop_once(what: str) -> Iterator[None]:
    """Within the block, the first SIGINT or SIGTERM raises :class:`KeyboardInterrupt`;
    every later one is logged (``what``: what the command is then finishing) and
    otherwise ignored, until the block ends (the previous handlers are then restored).
    Outside the main thread (where Python cannot set handlers) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def later(signum, frame):
        log.warning("%s while stopping: finishing first (%s); SIGKILL stops at once and "
                    "loses it", signal.Signals(signum).name, what)

    def first(signum, frame):
        for s in STOP_SIGNALS:
            signal.signal(s, later)
        _interrupt(signum)

    old = {s: signal.signal(s, first) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


__all__ = ["STOP_SIGNALS", "clear_stop", "deferred_stop", "note_stop", "quiet_unraisable", "stop_cause", "raise_if_stopped",
           "stop_handler",
           "stop_once", "stop_requested"]
