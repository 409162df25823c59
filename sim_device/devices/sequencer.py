"""Transmit-sequencer emulator on a pseudo-terminal.

Answers the sequencer protocol (:mod:`svss_daq.protocols.sequencer`) on the master side
of ``os.openpty``; a driver opens :attr:`SequencerEmulator.port` (the slave's path).
When started it emits a PING event every interval, projectors cycled in the schedule's
order, stamped with the host clock (``time.time_ns()``).
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
import tty
from typing import Optional

from svss_daq.protocols import sequencer as proto

__all__ = ["SequencerEmulator"]

logger = logging.getLogger(__name__)
E = proto.ErrorCode


class SequencerEmulator:
    """A sequencer on a pty. ``mute = True`` makes it ignore commands (to test
    timeouts); ``drop_replies`` > 0 ignores that many commands (to test retries)."""

    def __init__(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        tty.setraw(self._master)
        self.port = os.ttyname(self._slave)
        self.parser = proto.SequencerStreamParser()
        self.state = "IDLE"
        self.schedule: Optional[tuple[int, ...]] = None
        self.waveform: Optional[proto.SetWaveform] = None
        self.interval_ns: Optional[int] = None
        self.window: Optional[tuple[int, int]] = None
        self.next_sequence = 0
        self.pings_sent = 0
        self.mute = False
        self.drop_replies = 0
        self.commands: list = []  #: every command received, in order
        self._last: dict[int, bytes] = {}  # mid -> reply, for repeated ids
        self._next_ping_ns = 0
        self._stop = threading.Event()
        self._wlock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="sequencer-emulator", daemon=True)

    def start(self) -> "SequencerEmulator":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "SequencerEmulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def write(self, data: bytes) -> None:
        """Write raw bytes to the driver (e.g. garbage)."""
        with self._wlock:
            os.write(self._master, data)

    def _send(self, msg: proto.Message) -> bytes:
        b = proto.encode(msg)
        self.write(b)
        return b

    def _reply(self, cmd: proto.Command) -> proto.Message:
        name = cmd.TYPE
        if isinstance(cmd, proto.StatusRequest):
            return proto.Status(cmd.mid, self.state, self.next_sequence, self.pings_sent, 0)
        if isinstance(cmd, proto.Stop):
            self.state = "IDLE"
            return proto.Ack(cmd.mid, name)
        if isinstance(cmd, proto.Arm):
            missing = [n for n, v in (("SCHED", self.schedule), ("WAVE", self.waveform),
                                      ("PRI", self.interval_ns), ("RXWIN", self.window)) if v is None]
            if missing:
                return proto.Nak(cmd.mid, name, E.NOT_CONFIGURED, "missing " + " ".join(missing))
            if self.state != "IDLE":
                return proto.Nak(cmd.mid, name, E.WRONG_STATE, f"state {self.state}")
            self.state = "ARMED"
            return proto.Ack(cmd.mid, name)
        if isinstance(cmd, proto.Start):
            if self.state != "ARMED":
                return proto.Nak(cmd.mid, name, E.WRONG_STATE, f"state {self.state} not ARMED")
            self.state = "RUNNING"
            self.next_sequence = 0
            self._next_ping_ns = time.monotonic_ns()
            return proto.Ack(cmd.mid, name)
        if self.state != "IDLE":
            return proto.Nak(cmd.mid, name, E.WRONG_STATE, f"state {self.state}: STOP first")
        if isinstance(cmd, proto.SetSchedule):
            self.schedule = cmd.projectors
        elif isinstance(cmd, proto.SetWaveform):
            if cmd.kind != "lfm" or not (0 < cmd.f_start_hz < 1e6 and 0 < cmd.f_stop_hz < 1e6) \
                    or cmd.duration_ns > 100_000_000:
                return proto.Nak(cmd.mid, name, E.BAD_ARGUMENT, "waveform out of range")
            self.waveform = cmd
        elif isinstance(cmd, proto.SetInterval):
            if not 1_000_000 <= cmd.interval_ns <= 10_000_000_000:
                return proto.Nak(cmd.mid, name, E.BAD_ARGUMENT, "interval outside 1 ms..10 s")
            self.interval_ns = cmd.interval_ns
        elif isinstance(cmd, proto.SetReceiveWindow):
            if self.interval_ns is not None and cmd.start_ns + cmd.length_ns > self.interval_ns:
                return proto.Nak(cmd.mid, name, E.BAD_ARGUMENT, "window longer than the interval")
            self.window = (cmd.start_ns, cmd.length_ns)
        return proto.Ack(cmd.mid, name)

    def _handle(self, msg: proto.Message) -> None:
        if not isinstance(msg, tuple(proto.COMMAND_TYPES.values())):
            self._send(proto.Nak(0, msg.TYPE, E.UNKNOWN_COMMAND, "not a host command"))
            return
        if self.mute:
            return
        if self.drop_replies > 0:
            self.drop_replies -= 1
            self.commands.append(msg)
            return
        if msg.mid in self._last:  # a re-sent command: answer again, do not execute twice
            self.write(self._last[msg.mid])
            return
        self.commands.append(msg)
        reply = self._send(self._reply(msg))
        self._last = {msg.mid: reply, **dict(list(self._last.items())[:15])}

    def _run(self) -> None:
        while not self._stop.is_set():
            wait = 0.05
            if self.state == "RUNNING":
                wait = max(0.0, (self._next_ping_ns - time.monotonic_ns()) / 1e9)
            try:
                r, _, _ = select.select([self._master], [], [], min(wait, 0.05))
            except (OSError, ValueError):
                break
            if r:
                try:
                    data = os.read(self._master, 4096)
                except OSError:  # no reader on the slave side for now
                    time.sleep(0.01)
                    data = b""
                rejected = self.parser.stats.rejected
                for msg in self.parser.feed(data):
                    self._handle(msg)
                if self.parser.stats.rejected > rejected and not self.mute:
                    self._send(proto.Nak(0, "?", E.BAD_CHECKSUM, "unreadable sentence"))
            if self.state == "RUNNING" and time.monotonic_ns() >= self._next_ping_ns:
                sched = self.schedule or (0,)
                seq = self.next_sequence
                try:
                    self._send(proto.PingEvent(seq, sched[seq % len(sched)], time.time_ns()))
                except OSError:
                    pass
                self.next_sequence += 1
                self.pings_sent += 1
                self._next_ping_ns += self.interval_ns or 100_000_000
