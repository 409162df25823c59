"""Which checks a ping has passed, so that each check runs once per ping.

One ping meets several stages in one process: the worker's (or a plan's) gate, then
the imager, which must still refuse a ping handed to it directly (``svss process`` from
a file, a batch task, a test). Each stage asks for a check through :func:`once`: the
first asking runs it, and when it passes the ping is marked; a later stage asking the
same check of the same ping object trusts the mark instead of running it again (the
sample-range scan of :func:`svss_daq.ping_gate.ping_problem` runs once per ping).

A check is named by a hashable key that includes what it was made against (the
hardware configuration's id, the ``[ping_gate]`` limits), so a ping checked against
another configuration is checked afresh, and so is a copy (``dataclasses.replace``),
except for what :func:`carry` hands over: a re-posed ping
(:func:`svss_daq.ping_gate.reposed`) keeps its record's marks, and only its new pose is
checked. Only passes are remembered: a refused ping is refused
again, with the same reason, by whichever stage sees it. Marks are held weakly, by the
ping object's identity, and go with it. A ping is frozen; its samples are taken as they
were when checked.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Hashable

_PASSED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_LOCK = threading.Lock()


def passed(ping, check: Hashable) -> bool:
    """True when ``ping`` (this object) has passed ``check``."""
    try:
        with _LOCK:
            return check in _PASSED.get(ping, ())
    except TypeError:                      # not weakly referable, or an unhashable key
        return False


def mark_passed(ping, check: Hashable) -> None:
    """Record that ``ping`` passed ``check`` (nothing for an object that cannot be
    marked: it will be checked again)."""
    try:
        with _LOCK:
            marks = _PASSED.get(ping)
            _PASSED[ping] = frozenset({check}) if marks is None else marks | {check}
    except TypeError:
        pass


def once(ping, check: Hashable, problem: Callable[[], str | None]) -> str | None:
    """``problem()`` (why ``ping`` fails ``check``, None when it passes), unless
    ``ping`` has passed ``check`` already (then None without running it)."""
    if passed(ping, check):
        return None
    reason = problem()
    if reason is None:
        mark_passed(ping, check)
    return reason


def carry(src, dst, keep: Callable[[Hashable], bool]) -> None:
    """Mark ``dst`` with those of ``src``'s passed checks that ``keep`` accepts: a copy
    that changed nothing those checks read (a ping re-posed: its samples and record
    fields as they were) need not be checked for them again."""
    try:
        with _LOCK:
            marks = frozenset(k for k in _PASSED.get(src, ()) if keep(k))
            if marks:
                _PASSED[dst] = _PASSED.get(dst, frozenset()) | marks
    except TypeError:
        pass


__all__ = ["carry", "mark_passed", "once", "passed"]
