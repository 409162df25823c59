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

The daemon is a loop over parts that share the run (:mod:`svss_daq.daemon_run`: its
state, timeline, counters and events), each tested on its own: the ping pipeline
(:mod:`svss_daq.daemon_pipeline`: take, pair, assemble, record, publish), the device
supervisor (:mod:`svss_daq.daemon_devices`: open, watch, tap records, stop), the
navigation monitor (:mod:`svss_daq.daemon_nav`: poses, the tally and its events) and
the status reporter (:mod:`svss_daq.daemon_status`: the snapshot, the disk, alarms).
Here: binding the recording and the endpoints, the loop, and the run's end.
"""

from __future__ import annotations

import logging
import queue
import time

from . import messages
from .acquire_config import AcquireSetup, alarms_section, limits_section
from .daemon_devices import DeviceSupervisor, NmeaTap, Pd0Tap, RecordQueue
from .daemon_nav import NavigationMonitor, NavTally
from .daemon_pipeline import PingPipeline
from .daemon_run import RECENT_EVENTS, Counters, RunState, run_id_now, utc_now_ns
from .daemon_status import StatusReporter
from .nav.renavigate import navigation_config_text
from .publisher import PingPublisher, publisher_end_timeout_s
from .rawfile import NAV_CONFIG_ATTR
from .recorder import RESERVE_MIB, RunRecorder, close_interrupted_runs, free_run_id
from .signals import raise_if_stopped
from .status import StatusPublisher

log = logging.getLogger(__name__)

# the record taps under their former names (tests, re-navigation)
_RecordQueue, _NmeaTap, _Pd0Tap = RecordQueue, NmeaTap, Pd0Tap


class AcquisitionDaemon:
    """One run of acquisition (a survey line) with the configuration ``setup``: a loop
    over its parts, which share the run's :class:`~svss_daq.daemon_run.RunState`
    (:attr:`run_state`): the ping pipeline (:attr:`pipeline`), the device supervisor
    (:attr:`devices`), the navigation monitor (:attr:`nav`) and the status reporter
    (:attr:`reporter`).

    ``endpoints`` replaces the configured ones (keys ``publisher``, ``service``,
    ``status``; ``tcp://127.0.0.1:*`` picks a free port); the bound ones are in
    :attr:`endpoints` after :meth:`start`."""

    def __init__(self, setup: AcquireSetup, *, run_id: str | None = None,
                 endpoints: dict[str, str] | None = None, curve=None):
        self.setup = setup
        acq = setup.acquire
        self.hardware = setup.hardware
        self.limits = limits_section(acq)
        # a run of its own: a daemon restarted within its predecessor's second gets
        # NAME-...-2 (an explicit run id recorded there already is refused at bind)
        self.run_id = run_id or free_run_id(setup.out_dir, run_id_now(acq.run.name))
        want = {"publisher": setup.daq.publisher.endpoint,
                "status": acq.status.endpoint}
        service_cfg = getattr(setup.daq, "service", None)
        if service_cfg is not None:
            want["service"] = service_cfg.endpoint
        want.update(endpoints or {})
        self._want_endpoints = want
        self.curve = curve if curve is not None else getattr(setup.daq, "security", None)
        self.run_state = RunState(self.run_id, RECENT_EVENTS)
        self.nav = NavigationMonitor(setup, self.run_state)
        self.pipeline = PingPipeline(setup, self.run_state, self.nav)
        self.devices = DeviceSupervisor(setup, self.run_state, self.nav,
                                        on_transmit=self.pipeline.on_transmit)
        self.reporter = StatusReporter(setup, self.run_state, self.pipeline, self.devices,
                                       self.nav)
        self._stop_done = False          # stop() ran to its end (then it does nothing)
        self._requests_seen = 0
        self._last_request = -float("inf")     # monotonic time of the last catch-up request

    # -- the run's state, as its parts keep it -------------------------------------------

    @property
    def state(self) -> str:
        return self.run_state.state

    @state.setter
    def state(self, value: str) -> None:
        self.run_state.state = value

    @property
    def failure(self) -> str | None:
        return self.run_state.failure

    @failure.setter
    def failure(self, value: str | None) -> None:
        self.run_state.failure = value

    counters = property(lambda self: self.run_state.counters,
                        doc="the run's :class:`Counters`")
    events = property(lambda self: self.run_state.events,
                      doc="the latest events: (UTC ns, kind, detail)")
    n_events = property(lambda self: self.run_state.n_events)
    event_counts = property(lambda self: self.run_state.event_counts)
    endpoints = property(lambda self: self.run_state.endpoints,
                         doc="the bound endpoints (after :meth:`bind`)")
    recorder = property(lambda self: self.run_state.recorder)
    publisher = property(lambda self: self.run_state.publisher)
    service = property(lambda self: self.run_state.service)
    status_pub = property(lambda self: self.reporter.publisher)
    navigator = property(lambda self: self.nav.navigator)
    nav_tally = property(lambda self: self.nav.tally)
    sequencer = property(lambda self: self.devices.sequencer)
    digitiser = property(lambda self: self.devices.digitiser)

    def event(self, kind: str, detail: str, level: int = logging.WARNING) -> None:
        """Log, count, keep for the status stream and record one device event."""
        self.run_state.event(kind, detail, level)

    # -- start ---------------------------------------------------------------------------

    def bind(self) -> dict[str, str]:
        """Open the recording and bind the endpoints; return them (before any ping)."""
        s, acq = self.setup, self.setup.acquire
        daq, run = s.daq, self.run_state
        if run.recorder is not None:
            return self.endpoints
        # runs in the folder whose daemon died mid-run (killed, crashed): closed and
        # marked interrupted before this run takes its lock and the catch-up service
        # lists them (as ended)
        interrupted = close_interrupted_runs(s.out_dir, self.run_id)
        run.recorder = RunRecorder(
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
        run.publisher = PingPublisher(self._want_endpoints["publisher"],
                                      daq.publisher.send_hwm, curve=self.curve,
                                      end_timeout_s=publisher_end_timeout_s(daq))
        run.endpoints["publisher"] = run.publisher.endpoint
        self.reporter.publisher = StatusPublisher(self._want_endpoints["status"],
                                                  curve=self.curve)
        run.endpoints["status"] = self.reporter.publisher.endpoint
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
        self.devices.open()
        self.run_state.recording(alarms_section(self.setup.acquire).first_ping_s)
        self.reporter.publish(force=True)
        return self

    def _start_service(self, endpoint: str) -> None:
        from .ping_service import PingService, service_options
        from .catchup_stores import RecordingStore
        store = RecordingStore(self.recorder)
        cfg = self.setup.daq.service
        self.run_state.service = PingService(endpoint, store, curve=self.curve,
                                       **service_options(cfg))
        self.endpoints["service"] = self.service.endpoint

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
        self.pipeline.take_from(self.digitiser.ping_queue, timeout_s)
        self.pipeline.flush_due()
        self.devices.watch()
        self.nav.notices()
        self._note_requests()
        self.reporter.publish()

    def _note_requests(self) -> None:
        # replies sent whole: a client that does not read keeps nothing up
        if self.service is not None and self.service.replies != self._requests_seen:
            self._requests_seen = self.service.replies
            self._last_request = time.monotonic()

    def status(self) -> dict:
        """The status snapshot (the status stream's message, less its alarms)."""
        return self.reporter.status()

    # -- stop ----------------------------------------------------------------------------

    def stop(self) -> None:
        """Stop pinging, drain pings in flight, flush and close everything, end the
        run. Safe to call twice: a second call after a finished one does nothing (the
        first may have ended "failed", e.g. a stop signal inside a segment's creation)."""
        if self._stop_done:
            return
        run, pipeline = self.run_state, self.pipeline
        failed = run.state == "failed"
        run.state = "stopping"
        self.devices.stop_pinging()
        if not failed and self.digitiser is not None:
            drain = time.monotonic() + self.setup.acquire.pairing.drain_s
            while time.monotonic() < drain and not (self.recorder and self.recorder.stopped):
                try:
                    pipeline.take(self.digitiser.ping_queue.get(timeout=0.05))
                except queue.Empty:
                    pass
                except KeyboardInterrupt:
                    break
            pipeline.assemble_due(final=True)
        self.devices.stop_digitiser()
        self.devices.watch()
        self.nav.notices()
        # the alarms of a run being recorded clear with its end (in its events)
        self.reporter.publish(force=True, settle=True)
        if self.recorder is not None:
            # the last pings are recorded (or lost with a failed write) before the
            # summary counts them; what is recorded is published before the end marker
            self.recorder.close_files()
            if self.recorder.stopped:
                run.failure = run.failure or self.recorder.stopped
            if self.publisher is not None:
                pipeline.publish_recorded()
            pipeline.lose_unrecorded()
        summary = self.summary()
        if self.recorder is not None:
            self.recorder.close(summary)
        run.state = "failed" if (failed or run.failure) else "stopped"
        self.reporter.publish(force=True)
        self.devices.close()
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
                self.reporter.publish()     # the workers' backlog, while they catch up
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
                "navigation": self.nav.summary(),
                "n_events": self.n_events, "events": dict(self.event_counts),
                "failure": self.failure,
                "segments": [p.name for p in self.recorder.segments] if self.recorder else []}


__all__ = ["AcquisitionDaemon", "Counters", "NavTally", "run_id_now", "utc_now_ns"]
