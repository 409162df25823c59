"""Instrument clocks against the ping clock.

Every instrument stamps its records with its own clock (the DVL's real-time clock, the
GPS receiver's UTC from its date and time of day); pings are posed on the ping clock
(the sequencer's and digitiser's transmit times). The host sees both through the times
it receives records at: :class:`PingClock` learns the ping clock on the host's receive
clock from ping-clock events (the sequencer's transmit records, which leave the
sequencer at transmit), and :class:`InstrumentClock` keeps, for one instrument, the
offsets (receive time on the ping clock - instrument time) of its latest records. When
every record of the latest ``clock_window_s`` (and at least ``clock_records`` records)
lies beyond ``clock_max_offset_s`` on the same side, the instrument's clock is wrong (a
DVL real-time clock never set, a GPS date a week rollover off, GPS time instead of UTC);
its records are then re-timed onto the ping clock by the median of those offsets, frozen,
so that the spacing of the instrument's own clock is kept.

Receive times are only ever late: transport, and the host itself (a thread waiting
for the interpreter, a compile, a loaded machine) delays them, and a stalled reader
then takes a burst of old records at once. So the ping clock is the upper envelope of
its events (the least delayed one rules) and a clock is judged wrong only when even
its least delayed record of the window is off: a stall shorter than the window cannot
make a right clock look wrong.
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
    (``ping_ns``, received at ``receive_ns``); :meth:`ping_time` is the ping-clock time
    at a receive time: the upper envelope of the kept events (each extended at the
    rate), the rate the median over pairs of events at least ``RATE_MIN_SPAN_S``
    apart (1 without such pairs). None before the first event."""

    def __init__(self) -> None:
        self.events: collections.deque = collections.deque(maxlen=REFERENCES_KEPT)
        self.rate = 1.0
        self._c_ns = 0.0     # envelope: ping = p_last + c + rate * (receive - r_last)

    def add(self, receive_ns: int, ping_ns: int) -> None:
        self.events.append((int(receive_ns), int(ping_ns)))
        ev = self.events
        span = RATE_MIN_SPAN_S * 1e9
        slopes = []
        j = 0
        for i in range(len(ev)):
            while j < len(ev) and ev[j][0] - ev[i][0] < span:
                j += 1
            if j == len(ev):
                break
            if ev[j][1] > ev[i][1]:
                slopes.append((ev[j][1] - ev[i][1]) / (ev[j][0] - ev[i][0]))
        self.rate = statistics.median(slopes) if slopes else 1.0
        r1, p1 = ev[-1]
        self._c_ns = max((p - p1) - self.rate * (r - r1) for r, p in ev)

    def ping_time(self, receive_ns: int) -> Optional[int]:
        if not self.events:
            return None
        r1, p1 = self.events[-1]
        return p1 + int(round(self._c_ns + self.rate * (int(receive_ns) - r1)))


class InstrumentClock:
    """One instrument's clock against the ping clock.

    :meth:`observe` one record: its ``offset_ns`` (ping-clock receive time - instrument
    time), its ``instrument_ns`` and a ``mark`` (what the caller needs to find the
    records stored since). The window holds the records of the latest ``window_ns``
    of instrument time (at least ``n_records``); a jump of the instrument's time by more
    than ``window_ns`` starts it afresh. Once it spans ``window_ns`` with ``n_records``
    records, :attr:`offset_ns` is their median and the clock is judged:
    :attr:`applied_ns` (added to the instrument's times) stays while some record of the
    window lies within ``max_offset_ns`` of it; when every one lies beyond, on the same
    side, it becomes the median (0 if the median is within ``max_offset_ns`` of the
    ping clock), and :meth:`observe` returns ``(old, new, since)``: ``since`` the mark
    of the window's first record (None: every record so far, the clock never having
    been seen right)."""

    def __init__(self, name: str, max_offset_ns: int, n_records: int,
                 window_ns: int) -> None:
        self.name = name
        self.max_offset_ns = int(max_offset_ns)
        self.n_records = max(1, int(n_records))
        self.window_ns = int(window_ns)
        self.window: collections.deque = collections.deque()   # (instrument, offset, mark)
        self.offset_ns: Optional[int] = None
        self.applied_ns = 0
        self.seen_right = False
        self._start_ns: Optional[int] = None     # instrument time the window's stretch began

    def observe(self, offset_ns: int, instrument_ns: int, mark) -> Optional[tuple]:
        t = int(instrument_ns)
        w = self.window
        if w and abs(t - w[-1][0]) > self.window_ns:       # the clock jumped (or a gap)
            w.clear()
        if not w:
            self._start_ns = t
        w.append((t, int(offset_ns), mark))
        while len(w) > self.n_records and w[0][0] < t - self.window_ns:
            w.popleft()
        if len(w) < self.n_records or t - self._start_ns < self.window_ns:
            return None
        offs = [o for _, o, _ in w]
        med = int(statistics.median(offs))
        self.offset_ns = med
        lo, hi = min(offs) - self.applied_ns, max(offs) - self.applied_ns
        if lo <= self.max_offset_ns and hi >= -self.max_offset_ns:
            if self.applied_ns == 0:
                self.seen_right = True
            return None
        old = self.applied_ns
        self.applied_ns = med if abs(med) > self.max_offset_ns else 0
        since = w[0][2] if (self.seen_right or old != 0) else None
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
