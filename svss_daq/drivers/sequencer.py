"""Transmit-sequencer driver: commands with replies over a serial port, ping events out.

Built on :class:`~svss_daq.drivers.serial_link.SerialLink` (background reader,
reconnection with backoff) and the pure codec :mod:`svss_daq.protocols.sequencer`.
Each command gets a message id; the driver waits ``reply_timeout_s`` for the reply with
that id and re-sends the same sentence (same id: the sequencer answers a repeated id
with its earlier reply and does not execute it twice) up to ``retries`` times.
"""

from __future__ import annotations

import itertools
import random
import time
import logging
import queue as queue_mod
import threading
from typing import Any, Callable, Optional

from svss_daq.drivers.serial_link import SerialLink
from svss_daq.protocols import sequencer as proto

__all__ = ["SequencerDriver", "SequencerError", "SequencerTimeout", "SequencerNotConnected"]

logger = logging.getLogger(__name__)


class SequencerError(RuntimeError):
    """The sequencer rejected a command (NAK) or answered with something unexpected."""

    def __init__(self, message: str, code: Optional[int] = None) -> None:
        self.code = code
        super().__init__(message)


class SequencerTimeout(TimeoutError):
    """No reply to a command within the timeout after every retry."""


class SequencerNotConnected(ConnectionError):
    """The serial port is not open."""


class _Link(SerialLink):
    """SerialLink that can also write to the open port."""

    def write(self, data: bytes) -> None:
        with self._lock:
            ser = self._ser
            if ser is None:
                raise SequencerNotConnected(f"{self.port} is not open")
            try:
                ser.write(data)
                ser.flush()
            except Exception as e:  # SerialException / OSError on a vanished device
                raise SequencerNotConnected(f"write to {self.port} failed: {e}") from e


class SequencerDriver:
    """Drive the transmit sequencer on ``port``.

    Ping events (:class:`~svss_daq.protocols.sequencer.PingEvent`) go to ``on_ping``
    (called in the reader thread) or, without one, to ``ping_queue`` (at most
    ``queue_records`` events; beyond, an event is dropped, counted in ``dropped`` and
    logged at the 1st, 10th, 100th...); both when both are given. Commands block until the
    reply arrives and raise :class:`SequencerError` (NAK, naming the code and text) or
    :class:`SequencerTimeout` (naming the command, id, port and what was expected).
    """

    def __init__(self, port: str, *, baudrate: int = 115200, reply_timeout_s: float = 0.5,
                 retries: int = 2, on_ping: Optional[Callable[[proto.PingEvent], None]] = None,
                 ping_queue: Optional[queue_mod.Queue] = None, read_timeout_s: float = 0.02,
                 reconnect_initial_s: float = 0.05, reconnect_max_s: float = 2.0,
                 open_timeout_s: float = 5.0, queue_records: int = 1000) -> None:
        self.port = port
        self.open_timeout_s = open_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self.retries = retries
        self.on_ping = on_ping
        # with a callback and no queue given, nothing is queued (a queue nobody reads
        # filled up after its 100000th event and then warned at every ping)
        self.ping_queue: Optional[queue_mod.Queue] = ping_queue if ping_queue is not None \
            else None if on_ping is not None else queue_mod.Queue(maxsize=queue_records)
        self.dropped = 0
        # ids start at a random point: the device answers a repeated id from its cache
        # of recent replies without executing it (a host retry), so a new session that
        # began at 1 again would have its first commands taken for the last session's
        first = random.randrange(proto.MAX_MID)
        self._mids = itertools.cycle([*range(first + 1, proto.MAX_MID + 1),
                                      *range(1, first + 1)])
        self._cmd_lock = threading.Lock()
        self._replies: queue_mod.Queue = queue_mod.Queue()
        self._last_sequence: Optional[int] = None
        self.missed_pings = 0
        self.parser = proto.SequencerStreamParser()
        self.link = _Link(port, self.parser, baudrate=baudrate, on_record=self._on_message,
                          read_timeout_s=read_timeout_s, reconnect_initial_s=reconnect_initial_s,
                          reconnect_max_s=reconnect_max_s, name=f"sequencer:{port}")

    @classmethod
    def from_config(cls, cfg, **kw: Any) -> "SequencerDriver":
        """From a :class:`~svss_daq.config.SequencerLinkConfig`."""
        return cls(cfg.port, baudrate=cfg.baudrate, reply_timeout_s=cfg.reply_timeout_s,
                   retries=cfg.retries, open_timeout_s=cfg.open_timeout_s,
                   queue_records=cfg.queue_records, **kw)

    # -- life cycle ------------------------------------------------------------------

    def open(self, timeout_s: Optional[float] = None) -> "SequencerDriver":
        """Start the link; wait up to ``timeout_s`` (default ``open_timeout_s``) for the port."""
        self.link.start(wait_connected_s=self.open_timeout_s if timeout_s is None else timeout_s)
        return self

    def close(self) -> None:
        self.link.stop()

    def __enter__(self) -> "SequencerDriver":
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- reader thread ---------------------------------------------------------------

    def _on_message(self, msg: proto.Message) -> None:
        if isinstance(msg, proto.PingEvent):
            if self._last_sequence is not None and msg.sequence > self._last_sequence + 1:
                n = msg.sequence - self._last_sequence - 1
                self.missed_pings += n
                logger.warning("sequencer: %d ping event(s) missing before sequence %d", n,
                               msg.sequence)
            self._last_sequence = msg.sequence
            if self.on_ping is not None:
                self.on_ping(msg)
            if self.ping_queue is None:
                return
            try:
                self.ping_queue.put_nowait(msg)
            except queue_mod.Full:
                self.dropped += 1
                if str(self.dropped).rstrip("0") == "1":
                    logger.warning("sequencer: ping queue full (%d events), event %d dropped "
                                   "(%d in all; logged at every power of 10)",
                                   self.ping_queue.maxsize, msg.sequence, self.dropped)
        elif isinstance(msg, (proto.Ack, proto.Nak, proto.Status)):
            self._replies.put(msg)
        else:
            logger.warning("sequencer: unexpected host command from the device: %r", msg)

    # -- commands --------------------------------------------------------------------

    def command(self, make: Callable[[int], proto.Command]) -> proto.Message:
        """Send ``make(mid)``; return its ACK or STAT reply. Raises on NAK or timeout."""
        with self._cmd_lock:
            mid = next(self._mids)
            cmd = make(mid)
            sentence = proto.encode(cmd)
            expected = "STAT" if isinstance(cmd, proto.StatusRequest) else "ACK"
            while not self._replies.empty():  # stale replies of timed-out commands
                logger.debug("sequencer: dropping stale reply %r", self._replies.get_nowait())
            attempts = self.retries + 1
            for attempt in range(1, attempts + 1):
                if attempt > 1:
                    logger.warning("sequencer: no reply to %s (mid %d) within %g s; re-sending "
                                   "(attempt %d of %d)", cmd.TYPE, mid, self.reply_timeout_s,
                                   attempt, attempts)
                try:
                    self.link.write(sentence)
                except SequencerNotConnected as e:
                    logger.warning("sequencer: %s", e)
                    self._replies_wait(self.reply_timeout_s, mid)  # let the link reconnect
                    continue
                reply = self._replies_wait(self.reply_timeout_s, mid)
                if reply is None:
                    continue
                if isinstance(reply, proto.Nak):
                    name = proto.ErrorCode.NAMES.get(reply.code, "unknown code")
                    raise SequencerError(f"sequencer rejected {cmd.TYPE} (mid {mid}): NAK code "
                                         f"{reply.code} ({name}): {reply.text}", reply.code)
                if reply.TYPE != expected or (isinstance(reply, proto.Ack) and reply.command != cmd.TYPE):
                    raise SequencerError(f"sequencer answered {cmd.TYPE} (mid {mid}) with "
                                         f"{reply!r}; expected {expected} for {cmd.TYPE}")
                return reply
            raise SequencerTimeout(
                f"no reply to {cmd.TYPE} (mid {mid}) from {self.port} within "
                f"{self.reply_timeout_s:g} s after {attempts} attempt(s); expected "
                f"$SEQ,{expected},{mid},...")

    def _replies_wait(self, timeout_s: float, mid: int) -> Optional[proto.Message]:

        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            try:
                r = self._replies.get(timeout=left)
            except queue_mod.Empty:
                return None
            # a NAK for an unreadable sentence carries mid 0: it answers our sentence
            if r.mid == mid or (isinstance(r, proto.Nak) and r.mid == 0):
                return r
            logger.debug("sequencer: reply for another message id ignored: %r", r)

    def set_schedule(self, projectors) -> None:
        """Projector indices fired in turn, one per ping."""
        self.command(lambda m: proto.SetSchedule(m, tuple(int(p) for p in projectors)))

    def set_waveform(self, f_start_hz: float, f_stop_hz: float, duration_s: float,
                     kind: str = "lfm") -> None:
        self.command(lambda m: proto.SetWaveform(m, kind, float(f_start_hz), float(f_stop_hz),
                                                 int(round(duration_s * 1e9))))

    def set_interval(self, interval_s: float) -> None:
        self.command(lambda m: proto.SetInterval(m, int(round(interval_s * 1e9))))

    def set_receive_window(self, start_s: float, length_s: float) -> None:
        self.command(lambda m: proto.SetReceiveWindow(m, int(round(start_s * 1e9)),
                                                      int(round(length_s * 1e9))))

    def configure(self, hardware) -> None:
        """Schedule, waveform, interval and receive window from a HardwareConfig."""
        seq, wf, dg = hardware.sequencer, hardware.waveform, hardware.digitiser
        self.set_schedule(seq.projector_order)
        self.set_waveform(wf.f_start_hz, wf.f_stop_hz, wf.duration_s, wf.kind)
        self.set_interval(seq.ping_interval_s)
        self.set_receive_window(dg.window_start_s, dg.window_samples / dg.sample_rate_hz)

    def arm(self) -> None:
        self.command(proto.Arm)

    def start(self) -> None:
        self._last_sequence = None
        self.command(proto.Start)

    def stop(self) -> None:
        self.command(proto.Stop)

    def status(self) -> proto.Status:
        return self.command(proto.StatusRequest)  # type: ignore[return-value]
