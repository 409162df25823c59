"""A costly fixture value computed once per test session, not once per xdist worker.

Tests are handed to the workers as they free up (``--dist worksteal``), so the tests of
one module can land on both workers and a module- or session-scoped fixture is then
computed on each (test_horizontal's 10 simulated sand pings: 10 CPU-s a time). With
:func:`computed_once` the first worker to need the value computes it under a lock and
pickles it into the session's temporary folder, which the workers share; the others wait
for the lock and load it. Without xdist it just computes."""

from __future__ import annotations

import fcntl
import os
import pickle
from typing import Callable, TypeVar

T = TypeVar("T")


def computed_once(tmp_path_factory, name: str, compute: Callable[[], T]) -> T:
    """``compute()``, shared by the session's workers under ``name`` (unique per
    fixture: the module's and the fixture's name)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return compute()
    # a worker's base folder is SESSION/popen-gwN: SESSION is this run's, shared
    session = tmp_path_factory.getbasetemp().parent
    path = session / f"computed-once-{name}.pickle"
    with open(session / f"computed-once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if path.exists():
                with open(path, "rb") as f:
                    return pickle.load(f)
            value = compute()
            tmp = path.with_suffix(".partial")
            with open(tmp, "wb") as f:
                pickle.dump(value, f)
            os.replace(tmp, path)
            return value
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
