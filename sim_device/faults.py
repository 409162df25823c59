"""Fault injection for the simulated device, from a TOML file.

The file is a list of ``[[fault]]`` tables, each::

    [[fault]]
    at_s = 2.5              # simulated seconds (true time, not the stepped devices' clock)
    after = "start"         # "start": the sequencer's first START; "track": the track start
    kind = "digitiser.drop_frames"
    frame = 2               # kind-specific keys, below

Kinds and their keys (``seconds``: simulated seconds):

=========================== =============================================================
``digitiser.drop_frames``    ``frame`` (index, -1 = all; default -1), ``pings`` (default 1)
``digitiser.corrupt_frames`` ``frame`` (default 0), ``pings`` (default 1)
``digitiser.reset``          the client's TCP connection is reset
``digitiser.garbage``        ``length`` random bytes (default 256) before the next frame
``sequencer.garbage``        ``length`` random bytes (default 64) or ``text`` on the line
``sequencer.vanish``         ``seconds``: the pty and its symlink disappear, then return
``dvl.garbage``, ``gps.garbage``   as ``sequencer.garbage``
``dvl.vanish``, ``gps.vanish``     ``seconds``
``dvl.bottom_lock_loss``     ``seconds`` without bottom track
``gps.outage``               ``seconds`` without fix or heading
``clock.step``               ``step_s`` (signed): the devices' clock jumps
=========================== =============================================================

Random garbage is drawn from ``seed`` (a top-level key, default 0) and the fault's
position, so a file always injects the same bytes. Errors name the file and the key.
:class:`FaultScheduler` fires each fault at its time on the device's SimClock and logs
it with the simulated time.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from svss_daq.config import ConfigError, read_toml

__all__ = ["Fault", "FaultScheduler", "load_faults", "parse_faults", "KINDS"]

log = logging.getLogger(__name__)

# kind -> {key: (type, default or REQUIRED, check, what is expected)}
REQUIRED = object()
_SECONDS = {"seconds": (float, REQUIRED, lambda v: 0 < v <= 3600, "a number of seconds in (0, 3600]")}
_GARBAGE = {"length": (int, 64, lambda v: 1 <= v <= 1 << 20, "an integer 1..1048576"),
            "text": (str, None, lambda v: len(v) > 0, "a non-empty string")}
KINDS: dict[str, dict[str, tuple]] = {
    "digitiser.drop_frames": {"frame": (int, -1, lambda v: -1 <= v < 4096, "an integer -1..4095"),
                              "pings": (int, 1, lambda v: 1 <= v <= 10**6, "an integer >= 1")},
    "digitiser.corrupt_frames": {"frame": (int, 0, lambda v: 0 <= v < 4096, "an integer 0..4095"),
                                 "pings": (int, 1, lambda v: 1 <= v <= 10**6, "an integer >= 1")},
    "digitiser.reset": {},
    "digitiser.garbage": {"length": (int, 256, lambda v: 1 <= v <= 1 << 20,
                                     "an integer 1..1048576")},
    "sequencer.garbage": _GARBAGE,
    "sequencer.vanish": _SECONDS,
    "dvl.garbage": _GARBAGE,
    "dvl.vanish": _SECONDS,
    "dvl.bottom_lock_loss": _SECONDS,
    "gps.garbage": _GARBAGE,
    "gps.vanish": _SECONDS,
    "gps.outage": _SECONDS,
    "clock.step": {"step_s": (float, REQUIRED, lambda v: v != 0 and abs(v) <= 86400,
                              "a non-zero number of seconds, |step| <= 86400")},
}
_COMMON = {"at_s", "after", "kind"}


@dataclass(frozen=True)
class Fault:
    """One fault: ``at_s`` simulated seconds after ``after`` ("start" or "track")."""
    index: int
    kind: str
    at_s: float
    after: str
    params: dict = field(default_factory=dict)

    @property
    def device(self) -> str:
        return self.kind.split(".", 1)[0]

    def describe(self) -> str:
        extra = ", ".join(f"{k}={v!r}" for k, v in self.params.items() if v is not None)
        return f"fault[{self.index}] {self.kind}" + (f" ({extra})" if extra else "")


def parse_faults(data: dict, source: str) -> tuple[list[Fault], int]:
    """Validate a parsed faults file; returns (faults sorted by time, seed)."""
    unknown = sorted(set(data) - {"fault", "seed"})
    if unknown:
        raise ConfigError(f"{source}: unknown key '{unknown[0]}' at the top level; expected "
                          "'fault' (an array of tables) and optionally 'seed'")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{source}: key 'seed': got {seed!r}; expected an integer >= 0")
    items = data.get("fault", [])
    if not isinstance(items, list) or not all(isinstance(t, dict) for t in items):
        raise ConfigError(f"{source}: key 'fault': expected an array of tables ([[fault]])")
    out = []
    for i, t in enumerate(items):
        where = f"fault[{i}]"

        def bad(key: str, expected: str) -> ConfigError:
            found = repr(t[key]) if key in t else "nothing"
            return ConfigError(f"{source}: key '{where}.{key}': got {found}; expected {expected}")

        kind = t.get("kind")
        if kind not in KINDS:
            raise bad("kind", "one of " + ", ".join(sorted(KINDS)))
        at = t.get("at_s")
        if isinstance(at, bool) or not isinstance(at, (int, float)) or not 0 <= at <= 10**6:
            raise bad("at_s", "a number of simulated seconds >= 0")
        after = t.get("after", "start")
        if after not in ("start", "track"):
            raise bad("after", "'start' (the sequencer's first START) or 'track' (the "
                      "track start time)")
        keys = KINDS[kind]
        extra = sorted(set(t) - _COMMON - set(keys))
        if extra:
            raise ConfigError(f"{source}: unknown key '{where}.{extra[0]}' for kind {kind!r}; "
                              f"expected {sorted(_COMMON | set(keys))}")
        params: dict[str, Any] = {}
        for key, (tp, default, check, expected) in keys.items():
            if key not in t:
                if default is REQUIRED:
                    raise bad(key, expected)
                params[key] = default
                continue
            v = t[key]
            if tp is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if isinstance(v, bool) or not isinstance(v, tp) or not check(v):
                raise bad(key, expected)
            params[key] = v
        out.append(Fault(i, kind, float(at), after, params))
    return sorted(out, key=lambda f: (f.after != "track", f.at_s, f.index)), seed


def load_faults(path: str | Path) -> tuple[list[Fault], int]:
    """Read and validate a faults TOML file (errors name the file and key)."""
    return parse_faults(read_toml(path), str(path))


class FaultScheduler:
    """Fires faults at their simulated times on ``clock`` against ``targets``:
    ``{"sequencer": ..., "digitiser": ..., "dvl": ..., "gps": ..., "clock": ...}``.

    ``start_true_ns()`` returns the true simulated time of the sequencer's first START
    (None before it); faults ``after = "start"`` wait for it. A fault whose device is
    missing is logged and skipped. ``fired`` lists (fault, simulated time ns)."""

    def __init__(self, faults: list[Fault], clock, targets: dict[str, Any],
                 start_true_ns: Callable[[], Optional[int]], seed: int = 0) -> None:
        self.faults = list(faults)
        self.clock = clock
        self.targets = targets
        self.start_true_ns = start_true_ns
        self.seed = seed
        self.fired: list[tuple[Fault, int]] = []
        self.skipped: list[Fault] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-faults", daemon=True)

    def start(self) -> "FaultScheduler":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def _due_ns(self, f: Fault) -> Optional[int]:
        base = self.clock.start_ns if f.after == "track" else self.start_true_ns()
        return None if base is None else base + int(round(f.at_s * 1e9))

    def _run(self) -> None:
        pending = list(self.faults)
        while pending and not self._stop.is_set():
            due = [(self._due_ns(f), f) for f in pending]
            known = [(t, f) for t, f in due if t is not None]
            if not known:  # every remaining fault waits for START
                self._stop.wait(0.02)
                continue
            t, f = min(known, key=lambda x: (x[0], x[1].index))
            # wake at most every 20 ms host time: START may make an earlier fault due
            if self.clock.host_delay_s(t) > 0.02 and any(d is None for d, _ in due):
                self._stop.wait(0.02)
                continue
            if not self.clock.sleep_until(t, self._stop):
                return
            pending.remove(f)
            self._fire(f)

    def _garbage(self, f: Fault) -> bytes:
        if f.params.get("text"):
            return f.params["text"].encode("ascii", "replace")
        rng = np.random.default_rng([self.seed, f.index])
        return rng.integers(0, 256, f.params["length"], dtype=np.uint8).tobytes()

    def _fire(self, f: Fault) -> None:
        dev = self.targets.get(f.device)
        sim_s = (self.clock.true_ns() - self.clock.start_ns) * 1e-9
        if dev is None:
            log.warning("%s at simulated t = track + %.3f s skipped: no %s in this device",
                        f.describe(), sim_s, f.device)
            self.skipped.append(f)
            return
        log.warning("%s fired at simulated t = track + %.3f s", f.describe(), sim_s)
        action = f.kind.split(".", 1)[1]
        p = f.params
        try:
            if action == "drop_frames":
                dev.drop_next(p["frame"], p["pings"])
            elif action == "corrupt_frames":
                dev.corrupt_next(p["frame"], p["pings"])
            elif action == "reset":
                dev.reset_connection()
            elif action == "garbage":
                dev.inject_garbage(self._garbage(f))
            elif action == "vanish":
                # the navigation devices' vanish blocks for its duration: not this thread
                seconds = p["seconds"]
                if f.device == "sequencer":
                    dev.vanish(seconds / self.clock.time_scale)
                else:
                    threading.Thread(target=dev.vanish, args=(seconds,), daemon=True,
                                     name=f"vanish-{f.device}").start()
            elif action == "bottom_lock_loss":
                dev.lose_bottom_lock(p["seconds"])
            elif action == "outage":
                dev.outage(p["seconds"])
            elif action == "step":
                dev.step(int(round(p["step_s"] * 1e9)))
        except Exception:
            log.exception("%s failed", f.describe())
            return
        self.fired.append((f, self.clock.true_ns()))
