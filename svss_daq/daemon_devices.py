"""The acquisition daemon's device supervisor: the instruments of a run.

:class:`DeviceSupervisor` opens the devices of the devices configuration (the GPS and
the DVL on their serial ports, the sequencer on its serial port, the digitiser on TCP),
waits for the navigation's first data, stops a sequencer left pinging, configures and
starts the schedule; while the run is recorded it watches the drivers' counters and
turns their changes into run events (links lost and back, garbage skipped, pings
dropped by a full queue, transmit records lost), writes the records it taps (every NMEA
sentence, every PD0 ensemble's bytes, every transmit record's receive time: what
re-navigation needs, :mod:`svss_daq.nav.renavigate`) to the recording, and reports
each device's state for the status stream (connected, reopened, silent for how long).
At the run's end it stops pinging and closes the links. The record taps
(:class:`NmeaTap`, :class:`Pd0Tap`) and their bounded queue (:class:`RecordQueue`) are
here too.
"""

from __future__ import annotations

import collections
import logging
import time
from dataclasses import dataclass, field

from .acquire_config import limits_section
from .daemon_nav import NavigationMonitor
from .daemon_run import RunState, utc_now_ns
from .drivers.digitiser import DigitiserClient
from .drivers.sequencer import SequencerDriver
from .drivers.serial_link import SerialLink
from .protocols.framing import ByteStream
from .protocols.nmea import NmeaStreamParser
from .protocols.pd0 import Pd0Ensemble, Pd0StreamParser
from .protocols.sequencer import PingEvent
from .recorder import RecordingStopped

log = logging.getLogger("svss_daq.daemon")      # one logger for the daemon and its parts


class RecordQueue:
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


#: the end of an unfinished line a :class:`NmeaTap` keeps, bytes
NMEA_TAP_KEEP = 512


class NmeaTap:
    """The GPS link's parser: decodes with :class:`NmeaStreamParser` and keeps each raw
    sentence (receive time, text) for the recording."""

    def __init__(self, parser: NmeaStreamParser, keep: int):
        self.parser = parser
        self.stats = parser.stats
        self.raw = RecordQueue(keep)
        self._lines = ByteStream("NMEA tap", log)

    def feed(self, data):
        self._lines.feed(data)
        lines = self._lines.lines()
        self._lines.keep_last(NMEA_TAP_KEEP)
        now = utc_now_ns()
        for line in lines:
            text = line.strip(b"\r\x00 ")
            # from the last sentence start, as the parser reads it (junk glued in front
            # of a sentence is dropped there too)
            start = max(text.rfind(b"$"), text.rfind(b"!"))
            if start >= 0:
                self.raw.append((now, text[start:].decode("ascii", "replace")))
        return self.parser.feed(data)


class Pd0Tap(Pd0StreamParser):
    """The DVL link's parser: :class:`Pd0StreamParser` that also keeps the bytes of
    every ensemble it decodes (header to checksum, exactly the bytes that decoded) with
    their receive time, for the recording (re-navigation, :mod:`svss_daq.nav.renavigate`).
    The ensembles are taken where the parser judges a candidate whole and valid
    (``_judge``); the one it then accepts is matched by identity."""

    def __init__(self, keep: int):
        super().__init__()
        self.raw = RecordQueue(keep)
        self._judged: dict[int, bytes] = {}

    def _judge(self, pos: int, end: int):
        r = super()._judge(pos, end)
        if isinstance(r, Pd0Ensemble):
            self._judged[id(r)] = bytes(self._stream.buf[pos:pos + r.n_bytes])
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


@dataclass
class _Watch:
    """Last seen value of a driver counter, to turn increases into events."""
    values: dict = field(default_factory=dict)

    def delta(self, key: str, value: int) -> int:
        old = self.values.get(key, value)
        self.values[key] = value
        return value - old


def _wait(pred, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


class DeviceSupervisor:
    """The devices of run ``run`` with the configuration ``setup``; their navigation
    records go to ``nav``, the sequencer's transmit records to ``on_transmit`` (the
    ping pipeline) after ``nav``'s ping clock."""

    def __init__(self, setup, run: RunState, nav: NavigationMonitor, on_transmit=None):
        self.setup = setup
        self.run = run
        self.nav = nav
        self.on_transmit = on_transmit
        self.limits = limits_section(setup.acquire)
        self.sequencer: SequencerDriver | None = None
        self.digitiser: DigitiserClient | None = None
        self.dvl_link: SerialLink | None = None
        self.gps_link: SerialLink | None = None
        self.dvl_parser: Pd0Tap | None = None
        self.gps_tap: NmeaTap | None = None
        # the ping-clock events as received, for the recording (re-navigation judges the
        # instrument clocks against the ping clock as the live navigation does)
        self.clock_tap: RecordQueue | None = None
        self.transmits = 0                            # transmit records received
        self._watch = _Watch()
        self._heard: dict[str, tuple[int, float]] = {}   # device: (records, when changed)

    # -- start ---------------------------------------------------------------------------

    def open(self) -> None:
        """Open every configured device, wait for the navigation's first data (up to
        ``pairing.start_timeout_s``), then configure, arm and start the sonar."""
        dev, hw = self.setup.devices, self.setup.hardware.value
        keep = self.limits.records_waiting
        wait = self.setup.acquire.pairing.start_timeout_s
        if dev.gps is not None:
            self.gps_tap = NmeaTap(NmeaStreamParser(), keep)
            self.gps_link = SerialLink(dev.gps.port, self.gps_tap, baudrate=dev.gps.baudrate,
                                       on_record=self.nav.on_nmea, name="gps",
                                       reconnect_max_s=1.0).start()
        if dev.dvl is not None:
            # keeps each ensemble's bytes for the recording
            self.dvl_parser = Pd0Tap(keep)
            self.dvl_link = SerialLink(dev.dvl.port, self.dvl_parser,
                                       baudrate=dev.dvl.baudrate, on_record=self.nav.on_pd0,
                                       name="dvl", reconnect_max_s=1.0).start()
        if dev.gps is None and dev.dvl is None:
            log.warning("no DVL or GPS link configured: pings are recorded without a pose")
        self.clock_tap = RecordQueue(keep)
        self.sequencer = SequencerDriver.from_config(dev.sequencer,
                                                     on_ping=self._transmit,
                                                     reconnect_max_s=0.5)
        self.sequencer.open(timeout_s=wait)
        self.digitiser = DigitiserClient.from_config(dev.digitiser)
        self.digitiser.open(wait_connected_s=wait)
        # the first pings need a pose: wait for the navigation to have data
        for name, link, what in (("GPS fix", dev.gps, "gps"),
                                 ("DVL ensemble", dev.dvl, "dvl")):
            if link is not None and not _wait(lambda: self.nav.has_data(what), wait):
                log.warning("no %s within %.0f s: pinging without it", name, wait)
        # a sequencer still pinging (a daemon killed mid-run never stopped it) refuses to
        # be configured: stop it first, and say so
        state = self.sequencer.status()
        if state.state != "IDLE":
            self.run.event("sequencer.was_running", f"the sequencer was {state.state} at "
                           f"start (next ping {state.next_sequence}; a daemon stopped "
                           "without stopping it?): stopped before it is configured")
            self.sequencer.stop()
        self.sequencer.configure(hw)
        self.sequencer.arm()
        self.digitiser.start()
        self.sequencer.start()
        log.info("run %s: pinging every %.3f s, schedule %s", self.run.run_id,
                 hw.sequencer.ping_interval_s, list(hw.sequencer.projector_order))

    def _transmit(self, ev: PingEvent) -> None:
        """A transmit record (the sequencer's reader thread): kept with its receive
        time for the recording, the ping clock referenced, then handed on."""
        now = utc_now_ns()
        self.clock_tap.append((now, ev.transmit_time_ns))
        self.transmits += 1
        if self.on_transmit is not None:
            self.on_transmit(ev)
        self.nav.add_reference(now, ev.transmit_time_ns)

    # -- while recording -----------------------------------------------------------------

    def watch(self) -> None:
        """Turn the drivers' counters' changes into events; write the tapped records to
        the recording."""
        w, event = self._watch, self.run.event
        dig = self.digitiser
        if dig is not None:
            if w.delta("dig.disconnects", dig.disconnects) > 0:
                event("digitiser.disconnected", f"link to {dig.host}:{dig.port} lost "
                      f"({dig.last_error}); reconnecting")
            if w.delta("dig.connects", dig.connects) > 0 and dig.connects > 1:
                event("digitiser.reconnected", f"{dig.host}:{dig.port} connected "
                      "again; streaming restarted", logging.INFO)
            n = w.delta("dig.dropped", dig.dropped)
            if n > 0:
                event("digitiser.queue_full", f"{n} ping(s) dropped: the driver's "
                      f"queue (devices.toml digitiser.queue_pings) was full; "
                      f"{dig.dropped} in all")
            st = dig.decoder.frames.stats
            bad = w.delta("dig.bad", st.bad_headers + st.corrupt_payloads)
            junk = w.delta("dig.discarded", st.bytes_discarded)
            if bad > 0 or junk > 0:
                event("digitiser.garbage", f"{junk} byte(s) discarded, {bad} bad frame "
                      f"header(s) or corrupt payload(s); {st.bytes_discarded} bytes "
                      "discarded in all")
        for name, link, parser in self._serial():
            if w.delta(f"{name}.disconnects", link.stats.disconnects) > 0:
                event(f"{name}.vanished", f"serial port {link.port} lost; reopening")
            if w.delta(f"{name}.connects", link.stats.connects) > 0 and link.stats.connects > 1:
                event(f"{name}.returned", f"serial port {link.port} open again",
                      logging.INFO)
            discarded = getattr(getattr(parser, "stats", None), "bytes_discarded", 0)
            n = w.delta(f"{name}.discarded", discarded)
            if n > 0:
                event(f"{name}.garbage", f"{n} byte(s) of garbage skipped on {link.port}")
        if self.sequencer is not None:
            n = w.delta("seq.missed", self.sequencer.missed_pings)
            if n > 0:
                event("sequencer.events_missing", f"{n} PING record(s) lost on the "
                      "sequencer link")
        self.write_records()

    def _serial(self) -> list:
        """(name, link, parser) of each serial link opened."""
        seq = self.sequencer
        return [(name, link, parser) for name, link, parser in (
            ("sequencer", seq and seq.link, seq and seq.parser),
            ("dvl", self.dvl_link, self.dvl_parser),
            ("gps", self.gps_link, self.gps_tap)) if link is not None]

    def _taps(self) -> list:
        """(queue, the recorder's method that writes its records) of each record tap
        opened."""
        out = [(tap.raw, write) for tap, write in ((self.gps_tap, "append_nmea"),
                                                   (self.dvl_parser, "append_pd0"))
               if tap is not None]
        if self.clock_tap is not None:
            out.append((self.clock_tap, "append_clock_reference"))
        return out

    def write_records(self) -> None:
        """Write the tapped records (NMEA sentences, PD0 ensembles, transmit records)
        to the recording while it takes them; count what their queues dropped (an
        event at every power of 10)."""
        rec = self.run.recorder
        taps = self._taps()
        for q, write in taps:
            if not rec or rec.stopped:
                break
            while q:
                a, b = q.popleft()
                try:
                    getattr(rec, write)(a, b)
                except RecordingStopped:
                    break
        dropped = sum(q.dropped for q, _ in taps)
        c = self.run.counters
        old, c.records_dropped = c.records_dropped, dropped
        if dropped > old and (old == 0 or len(str(dropped)) > len(str(old))):
            self.run.event("daemon.records_dropped", f"{dropped} navigation / clock "
                           f"record(s) dropped unwritten: more than "
                           f"limits.records_waiting {self.limits.records_waiting} waited "
                           "(an event at every power of 10)")

    def silent(self, name: str, records: int, now: float,
               due: float | None = None) -> float | None:
        """Seconds since device ``name``'s count of records last changed (since
        recording began when it never did, or since ``due`` when it has nothing to say
        before then: the sequencer before its first ping); None before recording or
        before ``due``."""
        old = self._heard.get(name)
        if old is None or old[0] != records:
            self._heard[name] = (records, now)
        recording_at = self.run.recording_at
        if recording_at is None:
            return None
        since = max(self._heard[name][1], recording_at)
        if due is not None and records == 0:
            if now < due:
                return None
            since = max(since, due)
        return round(now - since, 3)

    def status(self, now: float) -> dict:
        """The status stream's ``devices`` at monotonic time ``now``."""
        devices = {}
        if self.sequencer is not None:
            ls = self.sequencer.link.stats
            devices["sequencer"] = {"connected": self.sequencer.link.connected,
                                    "reopens": max(ls.connects - 1, 0),
                                    "events_missing": self.sequencer.missed_pings,
                                    "garbage_bytes":
                                        self.sequencer.parser.stats.bytes_discarded,
                                    "silent_s": self.silent("sequencer", self.transmits,
                                                            now, self.run.pings_due_at)}
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
                                 "silent_s": self.silent(name, link.stats.records, now)}
        return devices

    @property
    def pings_dropped(self) -> int:
        """Pings the digitiser's driver dropped with its queue full."""
        return self.digitiser.dropped if self.digitiser is not None else 0

    # -- stop ----------------------------------------------------------------------------

    def stop_pinging(self) -> None:
        """Stop the sequencer (a vanished device is an event, not a lost run)."""
        self._stop(self.sequencer, "sequencer")

    def stop_digitiser(self) -> None:
        """Stop the digitiser's stream (a vanished device is an event)."""
        self._stop(self.digitiser, "digitiser")

    def _stop(self, driver, name: str) -> None:
        try:
            if driver is not None:
                driver.stop()
        except Exception as exc:
            self.run.event(f"{name}.stop_failed", str(exc))

    def close(self) -> None:
        """Close every driver and link."""
        for obj in (self.digitiser, self.sequencer, self.dvl_link, self.gps_link):
            if obj is None:
                continue
            try:
                obj.close() if hasattr(obj, "close") else obj.stop()
            except Exception as exc:
                log.warning("closing %s: %s", obj, exc)
