"""Stopping on a signal without being interrupted while stopping.

``svss`` commands turn SIGINT and SIGTERM into :class:`KeyboardInterrupt` and then write
what they hold (tiles, manifests, recordings). A second signal -- Ctrl-C pressed twice, or
a parent that forwards SIGTERM to a child the terminal's Ctrl-C reached already -- would
interrupt that writing half-way: :func:`stop_once` makes the first signal stop the block
and every later one wait (logged) until the writing is done. SIGKILL still stops at once.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Iterator

log = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


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
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    old = {s: signal.signal(s, first) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


__all__ = ["STOP_SIGNALS", "stop_once"]
