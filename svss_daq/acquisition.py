"""The acquisition loop: record every ping, then publish it.

Recording comes first so that a slow or absent subscriber never costs a recorded ping.
"""

from __future__ import annotations

import logging
from typing import Iterable

from .messages import RunEnd
from .ping import Ping
from .progress import Progress
from .publisher import PingPublisher
from .rawfile import RawRunWriter

log = logging.getLogger(__name__)


def acquire(pings: Iterable[Ping], recorder: RawRunWriter | None,
            publisher: PingPublisher | None, run_id: str, total: int | None = None) -> int:
    """Record and publish every ping of ``pings``; end with a run-end message.

    Returns the number of pings handled.
    """
    progress = Progress("acquisition", total, log)
    n, last = 0, None
    for ping in pings:
        last = ping.sequence if last is None else max(last, ping.sequence)
        if recorder is not None:
            recorder.append(ping)
        if publisher is not None:
            publisher.publish(ping, run_id=run_id)
        n += 1
        progress.update()
    if recorder is not None:
        recorder.flush()
    if publisher is not None:
        publisher.publish(RunEnd(run_id, n, last))
    return n
