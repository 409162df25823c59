"""``svss acquire``: the boat-side acquisition daemon.

It starts the drivers from the devices configuration (sequencer on its serial port,
digitiser on TCP, DVL and GPS on their serial ports), commands the ping schedule, and
for every ping the digitiser delivers:

1. pairs it with the sequencer's transmit record of the same sequence (waiting up to
   ``pairing.transmit_wait_s``; without one -- a vanished sequencer link -- the
   digitiser's transmit time and the projector cycle's phase stand in, counted);
2. poses it from the navigation solution at its transmit time (GPS, DVL dead reckoning,
   flagged per ping);
3. records it (:class:`~svss_daq.recorder.RunRecorder`: rotating SWMR raw-run files);
4. publishes it on the best-effort ping stream (:class:`~svss_daq.publisher.PingPublisher`,
   never blocking) once it is recorded, i.e. flushed (``daq.toml [recorder]``; held at
   most ``flush_interval_s``), so that the catch-up service
   (:class:`~svss_daq.ping_service.PingService`, the reliable path) can always serve
   what a subscriber missed, and a write that fails (a full disk) leaves the stream,
   the recording and the summary in agreement: a ping lost with the failed write is
   neither recorded nor published (counted, ``not_recorded``).

Device faults are logged, counted, written to the raw file's ``events`` and shown in
the status stream (:mod:`svss_daq.status`); none stops the run. Recording that cannot
go on (disk full, below the free-space floor) stops the run cleanly with every flushed
ping readable. SIGINT/SIGTERM (KeyboardInterrupt) stop the sequencer, drain the pings
still in flight, flush and close everything and end the run (RunEnd on the stream).
See docs/acquisition.md.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
import time
from dataclasses import dataclass, field

from . import messages
from .acquire_config import DEFAULT_LIMITS, AcquireSetup, alarms_section
from .alarms import AlarmLimits, AlarmTracker, evaluate
from .assembly import AssemblyError, PingAssembler
from .drivers.digitiser import DigitiserClient
from .protocols.nmea import NmeaStreamParser
from .protocols.pd0 import Pd0Ensemble, Pd0StreamParser
from .drivers.sequencer import SequencerDriver
from .drivers.serial_link import SerialLink
from .nav.clocks import describe_offset
from .navigation import Navigator
from .ping import (NAV_BOTTOM_LOCK, NAV_CLOCK_RETIMED, NAV_DEAD_RECKONED, NAV_GPS_FIX,
                   NAV_HELD, NavSnapshot)
from .protocols import digitiser as dg
from .protocols.sequencer import PingEvent
from .publisher import PingPublisher, publisher_end_timeout_s
from .nav.renavigate import navigation_config_text
from .rawfile import NAV_CONFIG_ATTR
from .recorder import (RESERVE_MIB, RecordingStopped, RunRecorder,
                       close_interrupted_runs, free_run_id)
from .recent import RecentChange
from .signals import deferred_stop, raise_if_stopped
from .status import StatusPublisher, pose_summary, utc_text

log = logging.getLogger(__name__)

NAN = float("nan")
#: events kept for the status stream
RECENT_EVENTS = 20


def utc_now_ns() -> int:
    return time.time_ns()


def run_id_now(name: str) -> str:
    return f"{name}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}"


@dataclass
class Counters:
    """What the daemon counted (the status stream's ``counters``)."""
    delivered: int = 0          # complete pings from the digitiser
    incomplete: int = 0         # pings the digitiser closed with channels missing
    never_delivered: int = 0    # ping numbers the digitiser skipped (no frame at all)
    recorded: int = 0           # pings on disk (flushed)
    not_recorded: int = 0       # assembled, lost with a failed write or after recording
                                # stopped (a full disk): neither recorded nor published
    published: int = 0
    publish_dropped: int = 0    # refused by a full subscriber queue (best-effort stream)
    transmit_missing: int = 0   # no sequencer record: assembled from the digitiser's
    duplicates: int = 0         # a sequence delivered twice (the second is not recorded)
    assembly_errors: int = 0
    pose_errors: int = 0        # no navigation solution at all (pose left NaN)
    # past the bounds of acquire.toml [limits] (docs/acquisition.md, "Limits")
    pending_full: int = 0       # pings posed before their wait ended: too many waiting
    transmit_unclaimed: int = 0  # transmit records dropped: too many waiting for a ping
    records_dropped: int = 0    # NMEA / PD0 / clock records dropped before being written

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class NavTally:
    mode: str = "none"
    dead_reckoned: int = 0
    no_gps_fix: int = 0
    no_bottom_lock: int = 0
    last_quality: int = 0
    outage: bool = False
    lock_lost: bool = False
    held: int = 0               # pings posed on the last navigation sample held (NAV_HELD)
    clock_retimed: int = 0      # pings posed on re-timed instrument clocks
    holding: bool = False
    last_held_ns: int = 0


@dataclass
class _Watch:
    """Last seen value of a driver counter, to turn increases into events."""
    values: dict = field(default_factory=dict)

    def delta(self, key: str, value: int) -> int:
        old = self.values.get(key, value)
        self.values[key] = value
        return value - old


class _RecordQueue:
    """Records waiting to be written (appended by a reader thread, taken by the loop):
    at most ``limit``; past it the oldest is dropped and counted (:attr:`dropped`)."""

    def __init__(self, limit: int):
        self.limit = limit
        self.items: collections.deque = collections.deque()
        self.dropped = 0

    def append(self, item) -> None:
        if len(self.items) >= self.limit:
            try:
                self.items.popleft()
                self.dropped += 1
            except IndexError:              # taken meanwhile by the loop
                pass
        self.items.append(item)

    def popleft(self):
        return self.items.popleft()

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self):
        return iter(list(self.items))


class _NmeaTap:
    """The GPS link's parser: decodes with :class:`NmeaStreamParser` and keeps each raw
    sentence (receive time, text) for the recording."""

    def __init__(self, parser: NmeaStreamParser, keep: int):
        self.parser = parser
        self.stats = parser.stats
        self.raw = _RecordQueue(keep)
        self._buf = bytearray()

    def feed(self, data: bytes):
        self._buf += data
        *lines, rest = bytes(self._buf).split(b"\n")
        self._buf = bytearray(rest[-512:])
        now = utc_now_ns()
        for line in lines:
            text = line.strip(b"\r\x00 ")
            # from the last sentence start, as the parser reads it (junk glued in front
            # of a sentence is dropped there too)
            start = max(text.rfind(b"$"), text.rfind(b"!"))
            if start >= 0:
                self.raw.append((now, text[start:].decode("ascii", "replace")))
        return self.parser.feed(data)


class _Pd0Tap(Pd0StreamParser):
    """The DVL link's parser: :class:`Pd0StreamParser` that also keeps the bytes of
    every ensemble it decodes (header to checksum, exactly the bytes that decoded) with
    their receive time, for the recording (re-navigation, :mod:`svss_daq.nav.renavigate`).
    The ensembles are taken where the parser judges a candidate whole and valid
    (``_judge``); the one it then accepts is matched by identity."""

    def __init__(self, keep: int):
        super().__init__()
        self.raw = _RecordQueue(keep)
        self._judged: dict[int, bytes] = {}

    def _judge(self, pos: int, end: int):
        r = super()._judge(pos, end)
        if isinstance(r, Pd0Ensemble):
            self._judged[id(r)] = bytes(self._buf[pos:pos + r.n_bytes])
        return r

    def _take(self, out: list) -> list:
        now = utc_now_ns()
        for ens in out:
            raw = self._judged.get(id(ens))
            if raw is None:           # cannot happen while _judge decodes every ensemble
                log.error("PD0 tap: ensemble %d decoded without its bytes; not recorded",
                          ens.variable.ensemble_number)
                continue
            self.raw.append((now, raw))
        self._judged.clear()
        return out

    def feed(self, data) -> list:
        return self._take(super().feed(data))

    def flush(self) -> list:
        return self._take(super().flush())


class AcquisitionDaemon:
    """One run of acquisition (a survey line) with the configuration ``setup``.

    ``endpoints`` replaces the configured ones (keys ``publisher``, ``service``,
    ``status``; ``tcp://127.0.0.1:*`` picks a free port); the bound ones are in
    :attr:`endpoints` after :meth:`start`."""

    def __init__(self, setup: AcquireSetup, *, run_id: str | None = None,
                 endpoints: dict[str, str] | None = None, curve=None):
        self.setup = setup
        acq = setup.acquire
        self.hardware = setup.hardware
        # a run of its own: a daemon restarted within its predecessor's second gets
        # NAME-...-2 (an explicit run id recorded there already is refused at bind)
        self.run_id = run_id or free_run_id(setup.out_dir, run_id_now(acq.run.name))
        self.assembler = PingAssembler(setup.hardware)
        want = {"publisher": setup.daq.publisher.endpoint,
                "status": acq.status.endpoint}
        service_cfg = getattr(setup.daq, "service", None)
        if service_cfg is not None:
            want["service"] = service_cfg.endpoint
        want.update(endpoints or {})
        self._want_endpoints = want
        self.endpoints: dict[str, str] = {}
        self.curve = curve if curve is not None else getattr(setup.daq, "security", None)
        self.counters = Counters()
        self.nav_tally = NavTally()
        self.events: collections.deque = collections.deque(maxlen=RECENT_EVENTS)
        self.n_events = 0
        self.event_counts: collections.Counter = collections.Counter()
        self.state = "starting"
        self._stop_done = False          # stop() ran to its end (then it does nothing)
        self.failure: str | None = None
        self._watch = _Watch()
        self._tx: dict[int, PingEvent] = {}
        self._tx_lock = threading.Lock()
        self._phase: int | None = None     # projector cycle: order index - sequence
        self._nav_lock = threading.Lock()
        self._times: collections.deque = collections.deque()
        self._last_seq: int | None = None
        self.limits = acq.limits or DEFAULT_LIMITS
        # the latest ping numbers (duplicate_window of them), to refuse a duplicate
        self._seen: set[int] = set()
        self._seen_order: collections.deque = collections.deque()
        self._pending: collections.deque = collections.deque()   # (arrival, CompletePing)
        # pings appended to the recording, published once flushed: (index in the run,
        # Ping, monotonic time appended); at most a flush's worth (daq.toml [recorder])
        self._unflushed: collections.deque = collections.deque()
        self.recorder: RunRecorder | None = None
        self.publisher: PingPublisher | None = None
        self.status_pub: StatusPublisher | None = None
        self.service = None
        self.sequencer: SequencerDriver | None = None
        self.digitiser: DigitiserClient | None = None
        self.dvl_link: SerialLink | None = None
        self.gps_link: SerialLink | None = None
        self.dvl_parser: Pd0StreamParser | None = None
        self.gps_tap: _NmeaTap | None = None
        self.navigator = Navigator(setup.devices.navigation, setup.hardware.value.lever_arms,
                                   history_s=acq.navigation.history_s)
        self._t_start = time.monotonic()
        self._requests_seen = 0
        self._last_request = -float("inf")     # monotonic time of the last catch-up request
        self._next_status = 0.0
        # alarms (svss_daq.alarms): thresholds, the active ones, and what the status
        # snapshot needs for them
        self.alarm_limits = AlarmLimits.from_setup(setup)
        self.alarms = AlarmTracker(alarms_section(acq).clear_after_s)
        self._recent = RecentChange(self.alarm_limits.recent_s)     # drops
        self._disk = RecentChange(acq.status.rate_window_s)         # free space
        self._recording_at: float | None = None     # monotonic: state became recording
        #: monotonic: when the first ping is due at the latest ([alarms] first_ping_s
        #: after recording began); the alarms on pings count from then until one comes
        self._pings_due_at: float | None = None
        self._first_ping_at: float | None = None    # monotonic: the first ping delivered
        self._last_ping_at: float | None = None     # monotonic: the last ping delivered
        self._last_recorded_seq: int | None = None
        self._last_pose: NavSnapshot | None = None   # the last ping's pose
        self._transmits = 0                          # transmit records received
        self._heard: dict[str, tuple[int, float]] = {}   # device: (records, when changed)

    # -- events --------------------------------------------------------------------------

    def event(self, kind: str, detail: str, level: int = logging.WARNING) -> None:
        """Log, count, keep for the status stream and record one device event."""
        t = utc_now_ns()
        self.n_events += 1
        self.event_counts[kind] += 1
        self.events.append((t, kind, detail))
        log.log(level, "%s: %s", kind, detail)
        if self.recorder is not None and not self.recorder.stopped:
            try:
                self.recorder.append_event(t, kind, detail)
            except RecordingStopped:
                pass

    # -- start ---------------------------------------------------------------------------

    def bind(self) -> dict[str, str]:
        """Open the recording and bind the endpoints; return them (before any ping)."""
        s, acq = self.setup, self.setup.acquire
        daq = s.daq
        if self.recorder is not None:
            return self.endpoints
        # runs in the folder whose daemon died mid-run (killed, crashed): closed and
        # marked interrupted before this run takes its lock and the catch-up service
        # lists them (as ended)
        interrupted = close_interrupted_runs(s.out_dir, self.run_id)
        self.recorder = RunRecorder(
            s.out_dir, self.run_id, s.hardware,
            flush_every_pings=daq.recorder.flush_every_pings,
            flush_interval_s=daq.recorder.flush_interval_s,
            max_file_bytes=acq.rotation.max_file_mib * 2**20,
            max_file_s=acq.rotation.max_file_s,
            min_free_bytes=acq.disk.min_free_mib * 2**20,
            reserve_bytes=(RESERVE_MIB if acq.disk.reserve_mib is None
                           else acq.disk.reserve_mib) * 2**20,
            run_attrs={"acquisition_config": str(s.path),
                       NAV_CONFIG_ATTR: navigation_config_text(s.devices.navigation)})
        for rid, summ in interrupted.items():        # (events: in this run's file too)
            self.event("recording.interrupted_run", f"run {rid} in {s.out_dir} was left "
                       "open by a daemon that stopped without closing it: closed and "
                       f"marked interrupted ({summ['counters']['recorded']} pings kept)")
        self.publisher = PingPublisher(self._want_endpoints["publisher"],
                                       daq.publisher.send_hwm, curve=self.curve,
                                       end_timeout_s=publisher_end_timeout_s(daq))
        self.endpoints["publisher"] = self.publisher.endpoint
        self.status_pub = StatusPublisher(self._want_endpoints["status"], curve=self.curve)
        self.endpoints["status"] = self.status_pub.endpoint
        if "service" in self._want_endpoints:
            self._start_service(self._want_endpoints["service"])
        return dict(self.endpoints)

    def start(self, wait_subscribers: int = 0) -> AcquisitionDaemon:
        """Bind (if not yet), open the devices and start pinging; with
        ``wait_subscribers``, first wait (up to ``pairing.start_timeout_s``) for that many
        subscribers to the ping stream."""
        self.bind()
        from .nav.kalman import warm_up
        warm_up()                    # the navigation filter compiled before the sonar pings
        if wait_subscribers:
            self.publisher.wait_for_subscribers(
                wait_subscribers, self.setup.acquire.pairing.start_timeout_s)
        self._open_devices()
        self.state = "recording"
        self._recording_at = time.monotonic()
        self._pings_due_at = self._recording_at + alarms_section(
            self.setup.acquire).first_ping_s
        self._publish_status(force=True)
        return self

    def _start_service(self, endpoint: str) -> None:
        from .ping_service import PingService, service_options
        from .catchup_stores import RecordingStore
        store = RecordingStore(self.recorder)
        cfg = self.setup.daq.service
        self.service = PingService(endpoint, store, curve=self.curve,
                                   **service_options(cfg))
        self.endpoints["service"] = self.service.endpoint

    def _open_devices(self) -> None:
        dev, hw = self.setup.devices, self.hardware.value
        wait = self.setup.acquire.pairing.start_timeout_s
        if dev.gps is not None:
            self.gps_tap = _NmeaTap(NmeaStreamParser(), self.limits.records_waiting)
            self.gps_link = SerialLink(dev.gps.port, self.gps_tap, baudrate=dev.gps.baudrate,
                                       on_record=self._on_nmea, name="gps",
                                       reconnect_max_s=1.0).start()
        if dev.dvl is not None:
            # keeps each ensemble's bytes for the recording
            self.dvl_parser = _Pd0Tap(self.limits.records_waiting)
            self.dvl_link = SerialLink(dev.dvl.port, self.dvl_parser,
                                       baudrate=dev.dvl.baudrate, on_record=self._on_pd0,
                                       name="dvl", reconnect_max_s=1.0).start()
        if dev.gps is None and dev.dvl is None:
            log.warning("no DVL or GPS link configured: pings are recorded without a pose")
        # the ping-clock events as received, for the recording (re-navigation judges the
        # instrument clocks against the ping clock as the live navigation does)
        self._clock_tap = _RecordQueue(self.limits.records_waiting)
        self.sequencer = SequencerDriver.from_config(dev.sequencer,
                                                     on_ping=self._transmit_tapped,
                                                     reconnect_max_s=0.5)
        self.sequencer.open(timeout_s=wait)
        self.digitiser = DigitiserClient.from_config(dev.digitiser)
        self.digitiser.open(wait_connected_s=wait)
        # the first pings need a pose: wait for the navigation to have data
        # (any DVL ensemble counts, with bottom track or without: the link is alive)
        for name, link, have in (("GPS fix", dev.gps, lambda: self.navigator.fixes),
                                 ("DVL ensemble", dev.dvl,
                                  lambda: self.navigator.counts["dvl_ensembles"])):
            if link is not None and not self._wait(have, wait):
                log.warning("no %s within %.0f s: pinging without it", name, wait)
        # a sequencer still pinging (a daemon killed mid-run never stopped it) refuses to
        # be configured: stop it first, and say so
        state = self.sequencer.status()
        if state.state != "IDLE":
            self.event("sequencer.was_running", f"the sequencer was {state.state} at start "
                       f"(next ping {state.next_sequence}; a daemon stopped without "
                       "stopping it?): stopped before it is configured")
            self.sequencer.stop()
        self.sequencer.configure(hw)
        self.sequencer.arm()
        self.digitiser.start()
        self.sequencer.start()
        log.info("run %s: pinging every %.3f s, schedule %s", self.run_id,
                 hw.sequencer.ping_interval_s, list(hw.sequencer.projector_order))

    def _transmit_tapped(self, ev: PingEvent) -> None:
        """A transmit record: kept with its receive time for the recording, then
        handled (:meth:`_on_transmit`)."""
        self._clock_tap.append((utc_now_ns(), ev.transmit_time_ns))
        self._on_transmit(ev)

    @staticmethod
    def _wait(pred, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > deadline:
                return False
            time.sleep(0.02)
        return True

    # -- reader-thread callbacks -----------------------------------------------------------

    def _on_transmit(self, ev: PingEvent) -> None:
        now = utc_now_ns()
        self._transmits += 1
        with self._tx_lock:
            self._tx[ev.sequence] = ev
        with self._nav_lock:        # the ping clock as the host sees it (instrument clocks)
            self.navigator.add_reference(now, ev.transmit_time_ns)

    def _on_nmea(self, record) -> None:
        """Each sentence to the navigation as it arrives, with its receive time: GST is
        paired with its fix by time of day there, HDT timed on the receiver's clock, and
        the receiver's clock judged against the ping clock."""
        now = utc_now_ns()
        with self._nav_lock:
            self.navigator.add_nmea([(now, record)])

    def _on_pd0(self, ensemble) -> None:
        now = utc_now_ns()
        with self._nav_lock:
            self.navigator.add_pd0(ensemble, receive_ns=now)

    # -- the acquisition loop ------------------------------------------------------------

    def run(self, max_pings: int | None = None, duration_s: float | None = None) -> int:
        """Acquire until ``max_pings`` pings were delivered, ``duration_s`` passed, the
        recording stopped or SIGINT/SIGTERM (KeyboardInterrupt, re-raised after
        :meth:`stop`). Returns the number of pings recorded."""
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            while self.recorder.stopped is None:
                if max_pings is not None and self.counters.delivered >= max_pings:
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    break
                raise_if_stopped()          # its own KeyboardInterrupt may have been lost
                self.step(0.05)
        except KeyboardInterrupt:
            self.stop()
            raise
        self.stop()
        return self.counters.recorded

    def step(self, timeout_s: float) -> None:
        """Handle what the digitiser delivered within ``timeout_s``; watch the devices;
        publish the status when due."""
        try:
            item = self.digitiser.ping_queue.get(timeout=timeout_s)
        except queue.Empty:
            item = None
        with deferred_stop():       # no ping taken off the queue and dropped by a stop
            while item is not None:
                self._take(item)
                if len(self._pending) > self.limits.pending_pings:
                    self._assemble_due(final=False)
                try:
                    item = self.digitiser.ping_queue.get_nowait()
                except queue.Empty:
                    item = None
            self._assemble_due(final=False)
        self._flush_due()
        self._watch_devices()
        self._nav_notices()
        self._note_requests()
        self._publish_status()

    def _flush_due(self) -> None:
        """Flush the recording when a ping has waited ``flush_interval_s`` for it (no
        ping came to flush it), then publish what it made recorded."""
        if self._unflushed and time.monotonic() - self._unflushed[0][2] >= \
                self.setup.daq.recorder.flush_interval_s:
            with deferred_stop():
                try:
                    self.recorder.flush()
                except RecordingStopped as exc:
                    self._recording_failed(exc)
                self._publish_recorded()

    def _recording_failed(self, exc: RecordingStopped) -> None:
        if self.failure is None:
            log.error("recording stopped: %s", exc)
        self.failure = self.failure or str(exc)
        self.state = "failed"

    def _publish_recorded(self) -> None:
        """Publish the pings the recording holds now (flushed), in order."""
        n = self.recorder.n_flushed
        with deferred_stop():       # no ping taken off the list and left unpublished
            while self._unflushed and self._unflushed[0][0] < n:
                _, ping, _ = self._unflushed.popleft()
                self.counters.recorded += 1
                self._last_recorded_seq = ping.sequence
                self._times.append(time.monotonic())
                if self.publisher.publish(ping, run_id=self.run_id):
                    self.counters.published += 1
                else:
                    self.counters.publish_dropped += 1

    def _note_requests(self) -> None:
        # replies sent whole: a client that does not read keeps nothing up
        if self.service is not None and self.service.replies != self._requests_seen:
            self._requests_seen = self.service.replies
            self._last_request = time.monotonic()

    def _take(self, item) -> None:
        if isinstance(item, dg.IncompletePing):
            if item.frames_received == 0:       # never sent: a gap in the ping numbers
                self.counters.never_delivered += item.n_pings     # one item per gap
                return
            self.counters.incomplete += 1
            self.event("digitiser.incomplete_ping",
                       f"ping {item.ping_number}: {item.frames_received} of "
                       f"{item.frame_count} frames ({item.reason}); not recorded")
            return
        if not isinstance(item, dg.CompletePing):
            return
        self.counters.delivered += 1
        self._last_ping_at = time.monotonic()
        if self._first_ping_at is None:
            self._first_ping_at = self._last_ping_at
        self._pending.append((time.monotonic(), item))

    def _assemble_due(self, final: bool) -> None:
        """Assemble pending pings whose transmit record is there (or waited for long
        enough), in delivery order."""
        now = time.monotonic()
        ready: list = []
        pairing = self.setup.acquire.pairing
        nav_wait = self.setup.acquire.navigation.wait_s
        # the fixed-lag smoother: a ping waits for the records fixed_lag_s past it
        lag_ns = int(self.setup.devices.navigation.fixed_lag_s * 1e9)
        while self._pending:
            arrived, data = self._pending[0]
            with self._tx_lock:
                have_tx = data.ping_number in self._tx
            if not final and ((not have_tx and now < arrived + pairing.transmit_wait_s)
                              or (now < arrived + nav_wait and not self._nav_caught_up(
                                  data.transmit_time_ns + lag_ns))):
                if len(self._pending) <= self.limits.pending_pings:
                    break
                # too many waiting (acquire.toml limits.pending_pings): posed now
                self.counters.pending_full += 1
                if str(self.counters.pending_full).rstrip("0") == "1":
                    self.event("daemon.pending_full", f"ping {data.ping_number} posed "
                               f"before its wait ended: {len(self._pending)} pings were "
                               f"waiting (limits.pending_pings "
                               f"{self.limits.pending_pings}); "
                               f"{self.counters.pending_full} in all (an event at every "
                               "power of 10)")
            with self._tx_lock:
                ev = self._tx.pop(data.ping_number, None)
            self._pending.popleft()
            ready.append((data, ev))
        self._handle_all(ready)
        with self._tx_lock:        # transmit records nobody will claim
            excess = len(self._tx) - self.limits.transmit_records
            if excess > 0:
                for k in sorted(self._tx)[:excess]:
                    del self._tx[k]
                self.counters.transmit_unclaimed += excess

    def _handle_all(self, ready: list) -> None:
        """Pose the pings of ``ready`` ((CompletePing, PingEvent or None) pairs) in one
        navigation solution, then assemble, record and publish each."""
        if not ready:
            return
        navs = self._poses([d.transmit_time_ns for d, _ in ready])
        for (data, ev), nav in zip(ready, navs):
            self._handle(data, ev, nav)

    def _handle(self, data: dg.CompletePing, ev: PingEvent | None,
                nav: NavSnapshot | None = None) -> None:
        seq = data.ping_number
        if seq in self._seen:
            self.counters.duplicates += 1
            self.event("digitiser.duplicate_ping", f"ping {seq} delivered again; the "
                       "first one is kept")
            return
        order = self.assembler.projector_order
        if ev is not None:
            self._phase = (order.index(ev.projector) - seq) % len(order) \
                if ev.projector in order else self._phase
        else:
            self.counters.transmit_missing += 1
            self.event("sequencer.transmit_record_missing",
                       f"ping {seq}: no PING record from the sequencer; transmit time from "
                       "the digitiser, projector from the schedule's phase")
        nav = nav if nav is not None else self._poses([data.transmit_time_ns])[0]
        try:
            if ev is not None:
                ping = self.assembler.from_instrument(data, ev, nav)
            else:
                projector = order[(seq + (self._phase or 0)) % len(order)]
                ping = self.assembler.build(seq, projector, data.transmit_time_ns,
                                            data.first_sample_time_ns - data.transmit_time_ns,
                                            data.samples, nav)
        except AssemblyError as exc:
            self.counters.assembly_errors += 1
            self.event("assembly.error", str(exc), logging.ERROR)
            return
        self._seen.add(seq)
        self._seen_order.append(seq)
        while len(self._seen_order) > self.limits.duplicate_window:
            self._seen.discard(self._seen_order.popleft())
        if self._last_seq is not None and seq > self._last_seq + 1:
            self.event("digitiser.pings_missing", f"{seq - self._last_seq - 1} ping(s) "
                       f"before {seq} never delivered")
        self._last_seq = seq if self._last_seq is None else max(seq, self._last_seq)
        self._tally_nav(nav)
        with deferred_stop():       # a stop signal after the file and the counts agree
            index = self.recorder.n_recorded
            try:
                self.recorder.append(ping)
            except RecordingStopped as exc:
                self._recording_failed(exc)
            if self.recorder.n_recorded > index:     # appended: published once flushed
                self._unflushed.append((index, ping, time.monotonic()))
            else:
                self.counters.not_recorded += 1
            self._publish_recorded()

    def _nav_caught_up(self, t_ns: int) -> bool:
        """Whether every navigation link has data at or after ``t_ns`` (a pose between
        samples, not extrapolated past the last one)."""
        nav, dev = self.navigator, self.setup.devices
        with self._nav_lock:
            for name, link in (("dvl", dev.dvl), ("gps", dev.gps)):
                latest = nav.latest_ns(name)     # on the ping clock (re-timed clocks too)
                if link is not None and not (latest is not None and latest >= t_ns):
                    return False
        return True

    def _poses(self, times_ns: list[int]) -> list[NavSnapshot]:
        if self.setup.devices.gps is None and self.setup.devices.dvl is None:
            return [_unknown_pose(t) for t in times_ns]
        try:
            with self._nav_lock:
                return self.navigator.poses(times_ns)
        except (ValueError, IndexError) as exc:
            before = self.counters.pose_errors
            self.counters.pose_errors += len(times_ns)
            if before == 0 or before // 100 != self.counters.pose_errors // 100:
                self.event("navigation.no_solution", f"no pose for {len(times_ns)} "
                           f"ping(s) ({exc}); recorded without one; "
                           f"{self.counters.pose_errors} in all")
            return [_unknown_pose(t) for t in times_ns]

    def _tally_nav(self, nav: NavSnapshot) -> None:
        t, q = self.nav_tally, nav.quality
        t.last_quality = q
        self._last_pose = nav
        gps, dr, lock = bool(q & NAV_GPS_FIX), bool(q & NAV_DEAD_RECKONED), bool(q & NAV_BOTTOM_LOCK)
        held = bool(q & NAV_HELD)
        t.mode = ("gps" if gps else "dead_reckoning" if dr else "held" if held else "none")
        if not gps:
            t.no_gps_fix += 1
        if dr:
            t.dead_reckoned += 1
        if held:
            t.held += 1
            t.last_held_ns = nav.time_ns
        if q & NAV_CLOCK_RETIMED:
            t.clock_retimed += 1
        if not lock and self.setup.devices.dvl is not None:
            t.no_bottom_lock += 1
        if not gps and not t.outage and self.setup.devices.gps is not None:
            t.outage = True
            self.event("navigation.gps_outage", "no GPS fix at the ping's time: " + (
                "dead reckoning on the DVL carries the pose" if dr else
                "the last navigation sample is held" if held else "no position"))
        elif gps and t.outage:
            t.outage = False
            self.event("navigation.gps_back", "GPS fixes again", logging.INFO)
        if held and not t.holding:
            t.holding = True
            self.event("navigation.held", "pings posed on the last navigation sample held "
                       "(flag NAV_HELD): no newer DVL or GPS record within acquire "
                       "navigation.wait_s of the ping (an instrument slower than that, or "
                       "silent)")
        elif not held and t.holding and (nav.time_ns - t.last_held_ns) * 1e-9 \
                > self.setup.devices.navigation.held_clear_s:
            t.holding = False
            self.event("navigation.held_end", "pings posed on current navigation again "
                       f"(none held for navigation.held_clear_s); {t.held} held in all",
                       logging.INFO)
        if self.setup.devices.dvl is not None:
            if not lock and not t.lock_lost:
                t.lock_lost = True
                self.event("navigation.bottom_lock_lost", self._why_no_lock(nav.time_ns))
            elif lock and t.lock_lost:
                t.lock_lost = False
                self.event("navigation.bottom_lock_back", "DVL bottom track again",
                           logging.INFO)

    def _why_no_lock(self, t_ns: int) -> str:
        """Why a ping has no bottom lock: no DVL ensemble near it (silent, slow, or its
        clock elsewhere), or ensembles without bottom track."""
        with self._nav_lock:       # (once per loss: a scan of the samples kept is cheap)
            nearest = min((d.time_ns - t_ns for d in self.navigator.dvl), key=abs,
                          default=None)
        gap_s = self.setup.devices.navigation.dvl_max_gap_s
        if nearest is None:
            n = self.navigator.counts["dvl_ensembles"]
            return ("no DVL ensemble yet" if n == 0 else
                    f"no DVL ensemble near the ping ({n} received, none within the "
                    "navigation's history of it: the DVL's clock elsewhere?)") + \
                ": altitude unknown, no dead reckoning"
        if abs(nearest) * 1e-9 > gap_s:
            return (f"no DVL ensemble within navigation.dvl_max_gap_s {gap_s:g} s of the "
                    f"ping (the nearest {describe_offset(nearest * 1e-9)} from it: the DVL "
                    "slow or silent, or its clock elsewhere): altitude unknown, no dead "
                    "reckoning")
        return "no DVL bottom track: altitude unknown, no dead reckoning"

    def _nav_notices(self) -> None:
        """The navigation's notices (instrument clocks, the GPS sigma gate) as events
        (the navigation logged them already)."""
        with self._nav_lock:
            notices = self.navigator.take_notices()
        for kind, detail, _level in notices:
            self.event(kind, detail, logging.DEBUG)

    # -- device watch ----------------------------------------------------------------------

    def _watch_devices(self) -> None:
        w = self._watch
        dig = self.digitiser
        if dig is not None:
            if w.delta("dig.disconnects", dig.disconnects) > 0:
                self.event("digitiser.disconnected", f"link to {dig.host}:{dig.port} lost "
                           f"({dig.last_error}); reconnecting")
            if w.delta("dig.connects", dig.connects) > 0 and dig.connects > 1:
                self.event("digitiser.reconnected", f"{dig.host}:{dig.port} connected "
                           "again; streaming restarted", logging.INFO)
            n = w.delta("dig.dropped", dig.dropped)
            if n > 0:
                self.event("digitiser.queue_full", f"{n} ping(s) dropped: the driver's "
                           f"queue (devices.toml digitiser.queue_pings) was full; "
                           f"{dig.dropped} in all")
            st = dig.decoder.frames.stats
            bad = w.delta("dig.bad", st.bad_headers + st.corrupt_payloads)
            junk = w.delta("dig.discarded", st.bytes_discarded)
            if bad > 0 or junk > 0:
                self.event("digitiser.garbage", f"{junk} byte(s) discarded, {bad} bad frame "
                           f"header(s) or corrupt payload(s); {st.bytes_discarded} bytes "
                           "discarded in all")
        for name, link, parser in (("sequencer", self.sequencer and self.sequencer.link,
                                    self.sequencer and self.sequencer.parser),
                                   ("dvl", self.dvl_link, self.dvl_parser),
                                   ("gps", self.gps_link, self.gps_tap)):
            if link is None:
                continue
            if w.delta(f"{name}.disconnects", link.stats.disconnects) > 0:
                self.event(f"{name}.vanished", f"serial port {link.port} lost; reopening")
            if w.delta(f"{name}.connects", link.stats.connects) > 0 and link.stats.connects > 1:
                self.event(f"{name}.returned", f"serial port {link.port} open again",
                           logging.INFO)
            discarded = getattr(getattr(parser, "stats", None), "bytes_discarded", 0)
            n = w.delta(f"{name}.discarded", discarded)
            if n > 0:
                self.event(f"{name}.garbage", f"{n} byte(s) of garbage skipped on "
                           f"{link.port}")
        if self.sequencer is not None:
            n = w.delta("seq.missed", self.sequencer.missed_pings)
            if n > 0:
                self.event("sequencer.events_missing", f"{n} PING record(s) lost on the "
                           "sequencer link")
        if self.gps_link is not None and self.recorder and not self.recorder.stopped:
            while self.gps_tap.raw:
                t, text = self.gps_tap.raw.popleft()
                try:
                    self.recorder.append_nmea(t, text)
                except RecordingStopped:
                    break
        if self.dvl_link is not None and self.recorder and not self.recorder.stopped:
            while self.dvl_parser.raw:
                t, raw = self.dvl_parser.raw.popleft()
                try:
                    self.recorder.append_pd0(t, raw)
                except RecordingStopped:
                    break
        tap = getattr(self, "_clock_tap", None)
        if tap is not None and self.recorder and not self.recorder.stopped:
            while tap:
                rx, tx = tap.popleft()
                try:
                    self.recorder.append_clock_reference(rx, tx)
                except RecordingStopped:
                    break
        queues = [q for q in (getattr(self.gps_tap, "raw", None),
                              getattr(self.dvl_parser, "raw", None), tap)
                  if isinstance(q, _RecordQueue)]
        dropped = sum(q.dropped for q in queues)
        old, self.counters.records_dropped = self.counters.records_dropped, dropped
        if dropped > old and (old == 0 or len(str(dropped)) > len(str(old))):
            self.event("daemon.records_dropped", f"{dropped} navigation / clock record(s) "
                       f"dropped unwritten: more than limits.records_waiting "
                       f"{self.limits.records_waiting} waited (an event at every power of "
                       "10)")

    # -- status --------------------------------------------------------------------------

    def ping_rate(self) -> float:
        window = self.setup.acquire.status.rate_window_s
        now = time.monotonic()
        while self._times and now - self._times[0] > window:
            self._times.popleft()
        if len(self._times) < 2:
            return 0.0
        return (len(self._times) - 1) / max(self._times[-1] - self._times[0], 1e-9)

    def status(self) -> dict:
        """The status snapshot (the status stream's message, less its alarms: see
        :meth:`_publish_status`). Ages are seconds; times UTC text."""
        c = self.counters
        rec = self.recorder
        now = time.monotonic()
        devices = {}
        if self.sequencer is not None:
            ls = self.sequencer.link.stats
            devices["sequencer"] = {"connected": self.sequencer.link.connected,
                                    "reopens": max(ls.connects - 1, 0),
                                    "events_missing": self.sequencer.missed_pings,
                                    "garbage_bytes":
                                        self.sequencer.parser.stats.bytes_discarded,
                                    "silent_s": self._silent("sequencer", self._transmits,
                                                             now, self._pings_due_at)}
        if self.digitiser is not None:
            d = self.digitiser
            devices["digitiser"] = {"connected": d.connected,
                                    "reconnects": max(d.connects - 1, 0),
                                    "bad_frames": d.decoder.frames.stats.bad_headers
                                    + d.decoder.frames.stats.corrupt_payloads,
                                    "garbage_bytes": d.decoder.frames.stats.bytes_discarded}
        for name, link, parser in (("dvl", self.dvl_link, self.dvl_parser),
                                   ("gps", self.gps_link, self.gps_tap)):
            if link is not None:
                devices[name] = {"connected": link.connected,
                                 "reopens": max(link.stats.connects - 1, 0),
                                 "records": link.stats.records,
                                 "garbage_bytes": parser.stats.bytes_discarded,
                                 "silent_s": self._silent(name, link.stats.records, now)}
        t = self.nav_tally
        nav = {"mode": t.mode, "last_quality": t.last_quality,
               "dead_reckoned": t.dead_reckoned, "no_gps_fix": t.no_gps_fix,
               "no_bottom_lock": t.no_bottom_lock, "held": t.held,
               "clock_retimed": t.clock_retimed, "pose_errors": c.pose_errors}
        # "now" on the ping clock: the navigation's records are on it (a device whose
        # clock is not the host's, as the simulated one, is judged on its own time)
        # (unknown before the first transmit record: no solution is judged then)
        with self._nav_lock:
            ping_now = self.navigator.ping_clock.ping_time(utc_now_ns())
        if self._last_pose is not None:
            nav["pose"] = pose_summary(self._last_pose, ping_now)
        quality = getattr(self.navigator, "quality", None)
        if callable(quality) and ping_now is not None:
            try:
                with self._nav_lock:
                    nav["solution"] = quality(ping_now)
            except Exception as exc:             # status must never stop acquisition
                log.debug("navigation quality: %s", exc)
        interval = self.hardware.value.sequencer.ping_interval_s
        recording_s = None if self._recording_at is None else now - self._recording_at
        # before the first ping, its age counts from when pings are due (none before)
        last_ping = self._last_ping_at if self._last_ping_at is not None \
            else self._pings_due_at
        if last_ping is not None and now < last_ping:
            last_ping = None
        due_in = (None if self._first_ping_at is not None or self._pings_due_at is None
                  else max(self._pings_due_at - now, 0.0))
        # recent drops (alarms pings.lost, stream.dropped)
        dig_dropped = self.digitiser.dropped if self.digitiser is not None else 0
        self._recent.add(now, {"never_delivered": c.never_delivered,
                               "incomplete": c.incomplete, "not_recorded": c.not_recorded,
                               "driver_queue_full": dig_dropped,
                               "stream_dropped": c.publish_dropped})
        change, _ = self._recent.change()
        stream_dropped = int(change.pop("stream_dropped", 0))
        file = None
        if rec is not None:
            file = rec.writer.path if rec.writer else (rec.segments[-1] if rec.segments
                                                       else None)
        free_mib = rec.free_bytes / 2**20 if rec else NAN
        disk = self._disk_rate(now, free_mib)
        return {
            "time_utc": utc_text(utc_now_ns()),
            "run_id": self.run_id, "state": self.state,
            "uptime_s": round(now - self._t_start, 3),
            "recording_s": None if recording_s is None else round(recording_s, 3),
            # since the first ping (the ping rate's window counts from it), and the
            # seconds until pings are due at the latest before it
            "pinging_s": None if self._first_ping_at is None
            else round(now - self._first_ping_at, 3),
            "first_ping_due_s": None if due_in is None else round(due_in, 3),
            "ping_rate_hz": round(self.ping_rate(), 3),
            "schedule_rate_hz": round(1.0 / interval, 3), "ping_interval_s": interval,
            "last_ping_age_s": None if last_ping is None else round(now - last_ping, 3),
            "last_sequence": self._last_recorded_seq,
            "counters": c.as_dict(), "endpoints": dict(self.endpoints),
            "subscribers": self.publisher.subscriptions if self.publisher else 0,
            "recent": {"window_s": self.alarm_limits.recent_s,
                       "lost": {k: int(v) for k, v in change.items()},
                       "stream_dropped": stream_dropped},
            "recorder": {"file": None if file is None else str(file),
                         "closed": bool(rec is not None and rec.writer is None
                                        and rec.ended),
                         "segment": len(rec.segments) - 1 if rec else None,
                         "recorded": rec.n_recorded if rec else 0,
                         "flushed": rec.n_flushed if rec else 0,
                         "free_mib": free_mib, **disk,
                         "stopped": rec.stopped if rec else None},
            "devices": devices, "navigation": nav, "workers": self._workers(interval),
            "n_events": self.n_events,
            "events": [{"time_utc": utc_text(te), "kind": k, "detail": d}
                       for te, k, d in self.events],
            "event_counts": dict(self.event_counts),
            "failure": self.failure,
        }

    def _silent(self, name: str, records: int, now: float,
                due: float | None = None) -> float | None:
        """Seconds since device ``name``'s count of records last changed (since
        recording began when it never did, or since ``due`` when it has nothing to say
        before then: the sequencer before its first ping); None before recording or
        before ``due``."""
        old = self._heard.get(name)
        if old is None or old[0] != records:
            self._heard[name] = (records, now)
        if self._recording_at is None:
            return None
        since = max(self._heard[name][1], self._recording_at)
        if due is not None and records == 0:
            if now < due:
                return None
            since = max(since, due)
        return round(now - since, 3)

    def _disk_rate(self, now: float, free_mib: float) -> dict:
        """How fast the disk fills (over status.rate_window_s) and the time left at
        that rate before recording stops (disk.min_free_mib)."""
        if not free_mib == free_mib:                      # NaN: no recorder
            return {"fill_mib_s": None, "time_left_s": None}
        self._disk.add(now, {"free": free_mib})
        change, dt = self._disk.change()
        if dt <= 0:
            return {"fill_mib_s": None, "time_left_s": None}
        rate = -change["free"] / dt
        room = free_mib - self.setup.acquire.disk.min_free_mib
        left = max(room, 0.0) / rate if rate > 1e-6 else None
        return {"fill_mib_s": round(rate, 4),
                "time_left_s": None if left is None else round(left, 1)}

    def _workers(self, interval: float) -> list[dict]:
        """The tile workers the catch-up service hears from, with their backlog on this
        run (pings recorded that they still lack, and those pings' time)."""
        if self.service is None:
            return []
        out = []
        for w in self.service.workers():
            backlog = None
            if w["run_id"] == self.run_id:
                last = self._last_recorded_seq
                backlog = 0 if w["done"] or last is None else max(last + 1 - w["next"], 0)
            out.append({**w, "backlog_pings": backlog,
                        "backlog_s": None if backlog is None else round(backlog * interval,
                                                                        3)})
        return out

    def _publish_status(self, force: bool = False, settle: bool = False) -> None:
        """Publish the status when due (``force``: now), its alarms first, after
        evaluating them (:mod:`svss_daq.alarms`); every alarm raised or cleared is an
        event (``alarm.raised`` / ``alarm.cleared``). ``settle``: alarms whose
        condition is gone clear at once (the run ended)."""
        now = time.monotonic()
        if not force and now < self._next_status:
            return
        self._next_status = now + self.setup.acquire.status.interval_s
        status = self.status()
        for what, alarm in self.alarms.update(evaluate(status, self.alarm_limits), now,
                                              settle=settle):
            if what == "raised":
                self.event("alarm.raised", f"{alarm.name}: {alarm.message}")
            else:
                self.event("alarm.cleared", f"{alarm.name}: the condition has gone (last "
                           f"said: {alarm.message})", logging.INFO)
        status["n_events"] = self.n_events
        if self.status_pub is not None:
            self.status_pub.publish({"alarms": self.alarms.listing(now), **status})


    # -- stop ----------------------------------------------------------------------------

    def stop(self) -> None:
        """Stop pinging, drain pings in flight, flush and close everything, end the
        run. Safe to call twice: a second call after a finished one does nothing (the
        first may have ended "failed", e.g. a stop signal inside a segment's creation)."""
        if self._stop_done:
            return
        failed = self.state == "failed"
        self.state = "stopping"
        try:
            if self.sequencer is not None:
                self.sequencer.stop()
        except Exception as exc:                 # a vanished device must not lose the run
            self.event("sequencer.stop_failed", str(exc))
        if not failed and self.digitiser is not None:
            drain = time.monotonic() + self.setup.acquire.pairing.drain_s
            while time.monotonic() < drain and not (self.recorder and self.recorder.stopped):
                try:
                    self._take(self.digitiser.ping_queue.get(timeout=0.05))
                except queue.Empty:
                    pass
                except KeyboardInterrupt:
                    break
            self._assemble_due(final=True)
        try:
            if self.digitiser is not None:
                self.digitiser.stop()
        except Exception as exc:
            self.event("digitiser.stop_failed", str(exc))
        self._watch_devices()
        self._nav_notices()
        # the alarms of a run being recorded clear with its end (in its events)
        self._publish_status(force=True, settle=True)
        if self.recorder is not None:
            # the last pings are recorded (or lost with a failed write) before the
            # summary counts them; what is recorded is published before the end marker
            self.recorder.close_files()
            if self.recorder.stopped:
                self.failure = self.failure or self.recorder.stopped
            if self.publisher is not None:
                self._publish_recorded()
            # delivered, never recorded: lost with a failed write, or waiting for their
            # pose when recording stopped
            self.counters.not_recorded += len(self._unflushed) + len(self._pending)
            self._unflushed.clear()
            self._pending.clear()
        summary = self.summary()
        if self.recorder is not None:
            self.recorder.close(summary)
        self.state = "failed" if (failed or self.failure) else "stopped"
        self._publish_status(force=True)
        for obj in (self.digitiser, self.sequencer, self.dvl_link, self.gps_link):
            if obj is None:
                continue
            try:
                obj.close() if hasattr(obj, "close") else obj.stop()
            except Exception as exc:
                log.warning("closing %s: %s", obj, exc)
        if self.publisher is not None:
            last = self.recorder.info()["last"] if self.recorder is not None else -1
            self.publisher.publish(messages.RunEnd(self.run_id, self.counters.recorded,
                                                   last if last >= 0 else None))
            self.publisher.close()
        if self.service is not None:
            self._linger()
            self.service.close()
        if self.status_pub is not None:
            self.status_pub.close()
        self._stop_done = True
        log.info("run %s: %d pings delivered, %d recorded in %d file(s), %d published, "
                 "%d dropped on the stream, %d device event(s)", self.run_id,
                 self.counters.delivered, self.counters.recorded,
                 len(self.recorder.segments) if self.recorder else 0,
                 self.counters.published, self.counters.publish_dropped, self.n_events)

    def _linger(self) -> None:
        """Keep the catch-up service up after the run while workers still need it: while
        a worker that tells the service its progress (svss.progress) still lacks pings
        of this run (:meth:`~svss_daq.ping_service.PingService.waiting`; a worker not
        heard from for ``service.worker_silence_s`` is forgotten), and until no reply
        was sent whole for ``catch_up.linger_s`` (a worker that does not say its
        progress); never longer than ``catch_up.max_linger_s``. SIGINT/SIGTERM end it."""
        cfg = self.setup.acquire.catch_up
        self._note_requests()
        end = time.monotonic() + cfg.max_linger_s
        seen, quiet_since = self.service.replies, self._last_request
        logged, said = False, None
        try:
            while True:
                now = time.monotonic()
                waiting = self.service.waiting(self.run_id)
                if now >= end:
                    if waiting:
                        log.warning("run %s: catch-up service closed after catch_up."
                                    "max_linger_s (%.0f s) while %d worker(s) still "
                                    "lacked pings (%s)", self.run_id,
                                    cfg.max_linger_s, len(waiting),
                                    "; ".join(sorted(waiting.values())))
                    break
                if not waiting and now >= quiet_since + cfg.linger_s:
                    break
                if waiting and set(waiting) != said:
                    said = set(waiting)
                    log.info("run %s ended; the catch-up service stays up while %d "
                             "worker(s) still lack pings (%s; at most catch_up."
                             "max_linger_s %.0f s)", self.run_id, len(waiting),
                             "; ".join(sorted(waiting.values())), cfg.max_linger_s)
                time.sleep(0.1)
                self._publish_status()      # the workers' backlog, while they catch up
                if self.service.replies != seen:
                    seen, quiet_since = self.service.replies, time.monotonic()
                    if not logged and cfg.linger_s > 0:
                        log.info("run %s ended; serving catch-up requests until none "
                                 "comes for %.0f s", self.run_id, cfg.linger_s)
                        logged = True
        except KeyboardInterrupt:
            pass

    def summary(self) -> dict:
        return {"run_id": self.run_id, "counters": self.counters.as_dict(),
                "navigation": {k: v for k, v in self.nav_tally.__dict__.items()
                               if k not in ("outage", "lock_lost", "holding",
                                            "last_held_ns")},
                "n_events": self.n_events, "events": dict(self.event_counts),
                "failure": self.failure,
                "segments": [p.name for p in self.recorder.segments] if self.recorder else []}


def _unknown_pose(t_ns: int) -> NavSnapshot:
    return NavSnapshot(t_ns, NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN)


__all__ = ["AcquisitionDaemon", "Counters", "run_id_now"]
