"""The acquisition daemon's ping pipeline: take, pair, assemble, record, publish.

:class:`PingPipeline` takes what the digitiser delivers (complete pings; incomplete ones
and gaps in the ping numbers are counted and said), and for each complete ping:

1. pairs it with the sequencer's transmit record of the same sequence (waiting up to
   ``pairing.transmit_wait_s``; without one -- a vanished sequencer link -- the
   digitiser's transmit time and the projector cycle's phase stand in, counted), and
   waits up to ``navigation.wait_s`` for the navigation to reach past it (the fixed-lag
   smoother's ``fixed_lag_s``);
2. poses the pings ready together in one navigation solution
   (:class:`~svss_daq.daemon_nav.NavigationMonitor`);
3. assembles it (:class:`~svss_daq.assembly.PingAssembler`), refusing a duplicate;
4. records it (the run's :class:`~svss_daq.recorder.RunRecorder`) and publishes it on
   the best-effort stream once it is flushed (held at most ``flush_interval_s``), so
   that a write that fails leaves the stream, the recording and the counts in
   agreement.

Every queue is bounded by acquire.toml ``[limits]``: pings waiting past
``pending_pings`` are posed at once, transmit records past ``transmit_records``
dropped, both counted and said at every power of 10.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
import time

from .acquire_config import limits_section
from .assembly import AssemblyError, PingAssembler
from .daemon_nav import NavigationMonitor
from .daemon_run import RunState, power_of_ten
from .ping import NavSnapshot
from .protocols import digitiser as dg
from .protocols.sequencer import PingEvent
from .recorder import RecordingStopped
from .signals import deferred_stop


class PingPipeline:
    """The pings of run ``run`` (its recorder and publisher, bound before the first
    ping) with the configuration ``setup``, posed by ``nav``."""

    def __init__(self, setup, run: RunState, nav: NavigationMonitor):
        self.setup = setup
        self.run = run
        self.nav = nav
        self.assembler = PingAssembler(setup.hardware)
        self.limits = limits_section(setup.acquire)
        self._tx: dict[int, PingEvent] = {}
        self._tx_lock = threading.Lock()
        self._phase: int | None = None     # projector cycle: order index - sequence
        # the latest ping numbers (duplicate_window of them), to refuse a duplicate
        self._seen: set[int] = set()
        self._seen_order: collections.deque = collections.deque()
        self._last_seq: int | None = None
        self._pending: collections.deque = collections.deque()   # (arrival, CompletePing)
        # pings appended to the recording, published once flushed: (index in the run,
        # Ping, monotonic time appended); at most a flush's worth (daq.toml [recorder])
        self._unflushed: collections.deque = collections.deque()
        self._times: collections.deque = collections.deque()     # pings recorded, when

    # -- in ------------------------------------------------------------------------------

    def on_transmit(self, ev: PingEvent) -> None:
        """A transmit record from the sequencer (its reader thread)."""
        with self._tx_lock:
            self._tx[ev.sequence] = ev

    def take(self, item) -> None:
        """One item from the digitiser: a complete ping waits for its transmit record
        and navigation; an incomplete one, or a gap, is counted (and said)."""
        c = self.run.counters
        if isinstance(item, dg.IncompletePing):
            if item.frames_received == 0:       # never sent: a gap in the ping numbers
                c.never_delivered += item.n_pings     # one item per gap
                return
            c.incomplete += 1
            self.run.event("digitiser.incomplete_ping",
                           f"ping {item.ping_number}: {item.frames_received} of "
                           f"{item.frame_count} frames ({item.reason}); not recorded")
            return
        if not isinstance(item, dg.CompletePing):
            return
        self.run.ping_delivered()
        self._pending.append((time.monotonic(), item))

    def take_from(self, pings: queue.Queue, timeout_s: float) -> None:
        """Take what the digitiser's queue ``pings`` holds within ``timeout_s`` and
        handle every ping that is ready."""
        try:
            item = pings.get(timeout=timeout_s)
        except queue.Empty:
            item = None
        with deferred_stop():       # no ping taken off the queue and dropped by a stop
            while item is not None:
                self.take(item)
                if len(self._pending) > self.limits.pending_pings:
                    self.assemble_due(final=False)
                try:
                    item = pings.get_nowait()
                except queue.Empty:
                    item = None
            self.assemble_due(final=False)

    @property
    def waiting(self) -> int:
        """Pings delivered and waiting for their transmit record or navigation."""
        return len(self._pending)

    # -- pair, pose, assemble ------------------------------------------------------------

    def assemble_due(self, final: bool) -> None:
        """Assemble pending pings whose transmit record is there (or waited for long
        enough), in delivery order; ``final``: all of them, waiting no more."""
        now = time.monotonic()
        ready: list = []
        c = self.run.counters
        pairing = self.setup.acquire.pairing
        nav_wait = self.setup.acquire.navigation.wait_s
        # the fixed-lag smoother: a ping waits for the records fixed_lag_s past it
        lag_ns = int(self.setup.devices.navigation.fixed_lag_s * 1e9)
        while self._pending:
            arrived, data = self._pending[0]
            with self._tx_lock:
                have_tx = data.ping_number in self._tx
            if not final and ((not have_tx and now < arrived + pairing.transmit_wait_s)
                              or (now < arrived + nav_wait and not self.nav.caught_up(
                                  data.transmit_time_ns + lag_ns))):
                if len(self._pending) <= self.limits.pending_pings:
                    break
                # too many waiting (acquire.toml limits.pending_pings): posed now
                c.pending_full += 1
                if power_of_ten(c.pending_full):
                    self.run.event("daemon.pending_full", f"ping {data.ping_number} posed "
                                   f"before its wait ended: {len(self._pending)} pings "
                                   f"were waiting (limits.pending_pings "
                                   f"{self.limits.pending_pings}); "
                                   f"{c.pending_full} in all (an event at every "
                                   "power of 10)")
            with self._tx_lock:
                ev = self._tx.pop(data.ping_number, None)
            self._pending.popleft()
            ready.append((data, ev))
        self.handle_all(ready)
        with self._tx_lock:        # transmit records nobody will claim
            excess = len(self._tx) - self.limits.transmit_records
            if excess > 0:
                for k in sorted(self._tx)[:excess]:
                    del self._tx[k]
                c.transmit_unclaimed += excess

    def handle_all(self, ready: list) -> None:
        """Pose the pings of ``ready`` ((CompletePing, PingEvent or None) pairs) in one
        navigation solution, then assemble, record and publish each."""
        if not ready:
            return
        navs = self.nav.poses([d.transmit_time_ns for d, _ in ready])
        for (data, ev), nav in zip(ready, navs):
            self.handle(data, ev, nav)

    def handle(self, data: dg.CompletePing, ev: PingEvent | None,
               nav: NavSnapshot | None = None) -> None:
        """Assemble, record and publish one ping with its transmit record ``ev`` (None:
        missing) and pose ``nav`` (None: posed here)."""
        seq = data.ping_number
        run, c = self.run, self.run.counters
        if seq in self._seen:
            c.duplicates += 1
            run.event("digitiser.duplicate_ping", f"ping {seq} delivered again; the "
                      "first one is kept")
            return
        order = self.assembler.projector_order
        if ev is not None:
            self._phase = (order.index(ev.projector) - seq) % len(order) \
                if ev.projector in order else self._phase
        else:
            c.transmit_missing += 1
            run.event("sequencer.transmit_record_missing",
                      f"ping {seq}: no PING record from the sequencer; transmit time from "
                      "the digitiser, projector from the schedule's phase")
        nav = nav if nav is not None else self.nav.poses([data.transmit_time_ns])[0]
        try:
            if ev is not None:
                ping = self.assembler.from_instrument(data, ev, nav)
            else:
                projector = order[(seq + (self._phase or 0)) % len(order)]
                ping = self.assembler.build(seq, projector, data.transmit_time_ns,
                                            data.first_sample_time_ns - data.transmit_time_ns,
                                            data.samples, nav)
        except AssemblyError as exc:
            c.assembly_errors += 1
            run.event("assembly.error", str(exc), logging.ERROR)
            return
        self._seen.add(seq)
        self._seen_order.append(seq)
        while len(self._seen_order) > self.limits.duplicate_window:
            self._seen.discard(self._seen_order.popleft())
        if self._last_seq is not None and seq > self._last_seq + 1:
            run.event("digitiser.pings_missing", f"{seq - self._last_seq - 1} ping(s) "
                      f"before {seq} never delivered")
        self._last_seq = seq if self._last_seq is None else max(seq, self._last_seq)
        self.nav.count(nav)
        with deferred_stop():       # a stop signal after the file and the counts agree
            rec = run.recorder
            index = rec.n_recorded
            try:
                rec.append(ping)
            except RecordingStopped as exc:
                run.recording_failed(exc)
            if rec.n_recorded > index:     # appended: published once flushed
                self._unflushed.append((index, ping, time.monotonic()))
            else:
                c.not_recorded += 1
            self.publish_recorded()

    # -- record, publish -----------------------------------------------------------------

    def flush_due(self) -> None:
        """Flush the recording when a ping has waited ``flush_interval_s`` for it (no
        ping came to flush it), then publish what it made recorded."""
        if self._unflushed and time.monotonic() - self._unflushed[0][2] >= \
                self.setup.daq.recorder.flush_interval_s:
            with deferred_stop():
                try:
                    self.run.recorder.flush()
                except RecordingStopped as exc:
                    self.run.recording_failed(exc)
                self.publish_recorded()

    def publish_recorded(self) -> None:
        """Publish the pings the recording holds now (flushed), in order."""
        run, c = self.run, self.run.counters
        n = run.recorder.n_flushed
        with deferred_stop():       # no ping taken off the list and left unpublished
            while self._unflushed and self._unflushed[0][0] < n:
                _, ping, _ = self._unflushed.popleft()
                c.recorded += 1
                run.last_recorded_seq = ping.sequence
                self._times.append(time.monotonic())
                if run.publisher.publish(ping, run_id=run.run_id):
                    c.published += 1
                else:
                    c.publish_dropped += 1

    def lose_unrecorded(self) -> None:
        """At the run's end, after the recording's files closed: pings delivered and
        never recorded (lost with a failed write, or waiting for their pose when
        recording stopped) are counted ``not_recorded``."""
        self.run.counters.not_recorded += len(self._unflushed) + len(self._pending)
        self._unflushed.clear()
        self._pending.clear()

    def ping_rate(self) -> float:
        """Pings recorded a second over the last ``status.rate_window_s``."""
        window = self.setup.acquire.status.rate_window_s
        now = time.monotonic()
        while self._times and now - self._times[0] > window:
            self._times.popleft()
        if len(self._times) < 2:
            return 0.0
        return (len(self._times) - 1) / max(self._times[-1] - self._times[0], 1e-9)
