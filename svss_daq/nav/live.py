"""Live poses that keep the ping-to-ping geometry of one solution while following the
fusion's slow corrections (``docs/navigation.md``, "Live poses").

The acquisition poses pings in batches as records arrive, each batch from a new fusion
of the records so far; each new GPS fix moves the recent track a little (millimetres),
so consecutive pings posed in different batches would jitter by that much. Instead each
ping is placed relative to the previous ping by the displacement between the two in the
*current* solution, and the difference between the previous live pose and the current
solution is taken out over ``tau_s``:

    p_live(t_k) = p_live(t_k-1) + [p(t_k) - p(t_k-1)] + a (p(t_k-1) - p_live(t_k-1)),
    a = 1 - exp(-(t_k - t_k-1) / tau_s)

(p: the current solution), for north, east, down and the bottom's depth below the ping
(down + altitude); the altitude is the difference of the last two.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Sequence

from svss_daq.ping import NavSnapshot

__all__ = ["follow"]


def _step(live_before: float, now_before: float, now: float, a: float) -> float:
    return live_before + (now - now_before) + a * (now_before - live_before)


def follow(prev_live: Optional[NavSnapshot], prev_now: Optional[NavSnapshot],
           fused: Sequence[NavSnapshot], tau_s: float, max_gap_s: float) -> list[NavSnapshot]:
    """Live poses for ``fused`` (the current solution at increasing times, after
    ``prev_live``'s time). ``prev_now``: the current solution at ``prev_live``'s time.
    Without a previous pose, a gap over ``max_gap_s``, or a non-finite position, the
    solution's pose is taken as it is (and the chain restarts from it)."""
    out = []
    last_live, last_now = prev_live, prev_now
    for cur in fused:
        ok = (last_live is not None and last_now is not None
              and 0 < (cur.time_ns - last_live.time_ns) * 1e-9 <= max_gap_s
              and all(math.isfinite(v) for v in (cur.north_m, cur.east_m, cur.down_m,
                                                  last_live.north_m, last_now.north_m)))
        if not ok:
            out.append(cur)
        else:
            dt = (cur.time_ns - last_live.time_ns) * 1e-9
            a = 1.0 - math.exp(-dt / tau_s)
            new = {f: _step(getattr(last_live, f), getattr(last_now, f), getattr(cur, f), a)
                   for f in ("north_m", "east_m", "down_m")}
            if all(math.isfinite(p.altitude_m) for p in (cur, last_now, last_live)):
                bottom = _step(last_live.down_m + last_live.altitude_m,
                               last_now.down_m + last_now.altitude_m,
                               cur.down_m + cur.altitude_m, a)
                new["altitude_m"] = bottom - new["down_m"]
            out.append(dataclasses.replace(cur, **new))
        last_live, last_now = out[-1], cur
    return out
