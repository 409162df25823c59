"""Instrument clocks against the ping clock.

Every instrument stamps its records with its own clock (the DVL's real-time clock, the
GPS receiver's UTC from its date and time of day); pings are posed on the ping clock
(the sequencer's and digitiser's transmit times). The host sees both through the times
it receives records at: :class:`PingClock` learns the ping clock on the host's receive
clock from ping-clock events (the sequencer's transmit records, which leave the
sequencer at transmit), and :class:`InstrumentClock` keeps, for one instrument, the
median over its latest records of (receive time on the ping clock - instrument time).
When that offset exceeds ``navigation.clock_max_offset_s`` the instrument's clock is
wrong (a DVL real-time clock never set, a GPS date a week rollover off, GPS time
instead of UTC); its records are then re-timed onto the ping clock by that one frozen
offset, so that the spacing of the instrument's own clock is kept.
"""

from __future__ import annotations

import collections
import statistics
from typing import Optional

#: The ping clock's rate against the receive clock is measured over ping-clock events at
#: least this far apart (s of the receive clock); below, the rates are taken as equal.
#: (They are equal on the boat; a simulated device running faster than the host is
#: not.) Short spans would let the host's receive jitter (ms) tilt the rate.
RATE_MIN_SPAN_S = 1.0
#: Ping-clock events kept: at 10 pings/s, 6 s of them.
REFERENCES_KEPT = 64


class PingClock:
    """The ping clock read on the receive clock: :meth:`add` a ping-clock event
    (``ping_ns``, received at ``receive_ns``); :meth:`ping_time` is the ping-clock
    time at a receive time, from the latest event and the rate between the oldest
    and latest kept (None before the first event)."""

    def __init__(self) -> None:
        self.events: collections.deque = collections.deque(maxlen=REFERENCES_KEPT)

    def add(self, receive_ns: int, ping_ns: int) -> None:
        self.events.append((int(receive_ns), int(ping_ns)))

    def ping_time(self, receive_ns: int) -> Optional[int]:
        if not self.events:
            return None
        r1, p1 = self.events[-1]
        r0, p0 = self.events[0]
        rate = 1.0
        if r1 - r0 >= RATE_MIN_SPAN_S * 1e9 and p1 > p0:
            rate = (p1 - p0) / (r1 - r0)
        return p1 + int(round((int(receive_ns) - r1) * rate))


class InstrumentClock:
    """One instrument's clock against the ping clock.

    :meth:`observe` one record's offset (ping-clock receive time - instrument time, ns)
    with a ``mark`` (what the caller needs to find the records stored since); once
    ``n_records`` offsets are in, their median is :attr:`offset_ns`. :attr:`applied_ns`
    is added to the instrument's times: 0 while the median is within ``max_offset_ns``
    of the ping clock; when the median departs from the applied offset by more than
    that, the applied offset becomes the median (0 if the median is back within
    ``max_offset_ns``), and :meth:`observe` returns ``(old, new, since)``: ``since`` the
    mark of the first record to move (None: every record so far, the clock never
    having been seen right)."""

    def __init__(self, name: str, max_offset_ns: int, n_records: int) -> None:
        self.name = name
        self.max_offset_ns = int(max_offset_ns)
        self.window: collections.deque = collections.deque(maxlen=max(1, int(n_records)))
        self.offset_ns: Optional[int] = None
        self.applied_ns = 0
        self.seen_right = False

    def observe(self, offset_ns: int, mark) -> Optional[tuple]:
        self.window.append((int(offset_ns), mark))
        if len(self.window) < self.window.maxlen:
            return None
        med = int(statistics.median(o for o, _ in self.window))
        self.offset_ns = med
        if abs(med - self.applied_ns) <= self.max_offset_ns:
            if self.applied_ns == 0:
                self.seen_right = True
            return None
        old = self.applied_ns
        self.applied_ns = med if abs(med) > self.max_offset_ns else 0
        since = None
        if self.seen_right or old != 0:
            # the records from the first of the latest run that agrees with the median
            since = self.window[-1][1]
            for o, m in reversed(self.window):
                if abs(o - med) > self.max_offset_ns:
                    break
                since = m
        if self.applied_ns == 0:
            self.seen_right = True
        return old, self.applied_ns, since

    @property
    def retimed(self) -> bool:
        return self.applied_ns != 0


def describe_offset(offset_s: float) -> str:
    """An offset in the unit an operator reads: s, h, days or years."""
    a = abs(offset_s)
    sign = "+" if offset_s >= 0 else "-"
    if a < 600:
        return f"{sign}{a:.3f} s"
    if a < 2 * 86400:
        return f"{sign}{a / 3600:.2f} h"
    if a < 2 * 365.25 * 86400:
        return f"{sign}{a / 86400:.1f} days"
    return f"{sign}{a / (365.25 * 86400):.2f} years"
