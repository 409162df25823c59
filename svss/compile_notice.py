"""One line before numba compiles: the first run of a command compiles its kernels (tens of
seconds to a minute, silent otherwise); later runs load them from numba's on-disk cache.

numba raises a ``numba:compile`` event only when it actually compiles (a function loaded
from the cache raises none), so the line appears exactly when there is a wait to explain.
"""

from __future__ import annotations

import logging

log = logging.getLogger("svss")

MESSAGE = ("compiling kernels (first run only: numba caches them on disk, later runs "
           "start in seconds)")

_installed = False


def announce_compiling() -> None:
    """Log :data:`MESSAGE` once, at INFO, when this process first compiles a kernel."""
    global _installed
    if _installed:
        return
    from numba.core import event

    class _Once(event.Listener):
        said = False

        def on_start(self, ev) -> None:
            if not self.said:
                self.said = True
                log.info(MESSAGE)

        def on_end(self, ev) -> None:
            pass

    event.register("numba:compile", _Once())
    _installed = True


__all__ = ["MESSAGE", "announce_compiling"]
