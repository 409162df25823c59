"""Transmit-sequencer emulator on a pseudo-terminal.

Answers the sequencer protocol (:mod:`svss_daq.protocols.sequencer`) on the master side
of ``os.openpty``; a driver opens :attr:`SequencerEmulator.port` (the slave's path, or
the stable symlink ``link_path`` when given). When started it emits a PING event every
interval, projectors cycled in the schedule's order.

Two time bases: without a clock, pings follow the host's monotonic clock from START and
are stamped ``time.time_ns()`` (the drivers' tests). With a
:class:`~sim_device.devices.clock.SimClock`, pings fall on the track's ping grid (true
simulated time ``clock.start_ns + k * interval``, the first grid point at or after
START), are stamped with the devices' clock at that instant (clock steps included), fire
projector ``schedule[k % len(schedule)]`` (the cycle locked to the grid, so that ping
``k``'s echoes are the scene's ping ``k``), and ``on_ping(event, k)`` hands the track
index ``k`` to whoever makes the echoes.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import select
import threading
import time
from pathlib import Path
from typing import Callable, Optional

from sim_device.devices.serial_device import close_fds, open_raw_pty
from svss_daq.protocols import sequencer as proto

__all__ = ["SequencerEmulator", "device_time_ns"]

logger = logging.getLogger(__name__)
E = proto.ErrorCode


def device_time_ns(clock, true_ns: int) -> int:
    """The devices' clock reading (steps included) at true simulated time ``true_ns``,
    ns (:attr:`SimClock.offset_ns`: the steps so far)."""
    return int(true_ns) + clock.offset_ns


class SequencerEmulator:
    """A sequencer on a pty. ``mute = True`` makes it ignore commands (to test
    timeouts); ``drop_replies`` > 0 ignores that many commands (to test retries).

    ``clock``: a SimClock (see the module docstring); ``on_ping(event, track_index)``
    and ``on_start(first_track_index, interval_ns)``: called from the emulator's thread
    (keep them short); ``link_path``: a symlink to the pty kept at a stable path, needed
    by :meth:`vanish`."""

    def __init__(self, *, clock=None,
                 on_ping: Optional[Callable[[proto.PingEvent, int], None]] = None,
                 on_start: Optional[Callable[[int, int], None]] = None,
                 link_path: Optional[str | os.PathLike] = None) -> None:
        self.clock = clock
        self.on_ping = on_ping
        self.on_start = on_start
        self.link_path = Path(link_path) if link_path is not None else None
        self._master: Optional[int] = None
        self._slave: Optional[int] = None
        self._open_pty()
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
        self.naks = 0             #: NAK replies sent (bad sentences and rejected commands)
        self.bytes_dropped = 0    #: bytes not written: nobody reading, or device vanished
        self.vanishes = 0
        self._last: dict[int, bytes] = {}  # mid -> reply, for repeated ids
        self._next_ping_ns = 0    # host monotonic (no clock) or true simulated (clock) ns
        self._next_k = 0          # track index of the next ping (clock)
        self._vanish_request: Optional[float] = None
        self._back_at: Optional[float] = None  # host monotonic s when a vanished port returns
        self._stop = threading.Event()
        self._wlock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="sequencer-emulator", daemon=True)

    # -- pty -------------------------------------------------------------------------

    def _open_pty(self) -> None:
        master, slave = open_raw_pty()
        self._master, self._slave = master, slave
        self.device = os.ttyname(slave)
        if self.link_path is not None:
            tmp = self.link_path.with_name(self.link_path.name + ".new")
            try:
                tmp.unlink()
            except FileNotFoundError:
                pass
            os.symlink(self.device, tmp)
            os.replace(tmp, self.link_path)
        self.port = str(self.link_path) if self.link_path is not None else self.device

    def _close_pty(self) -> None:
        with self._wlock:
            fds, self._master, self._slave = (self._master, self._slave), None, None
        close_fds(fds)

    # -- life cycle ------------------------------------------------------------------

    def start(self) -> "SequencerEmulator":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._close_pty()
        if self.link_path is not None:
            try:
                self.link_path.unlink()
            except FileNotFoundError:
                pass

    def __enter__(self) -> "SequencerEmulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- output and faults -----------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Write raw bytes to the driver; bytes that cannot go (device vanished, nobody
        reading and the pty buffer full) are dropped and counted."""
        with self._wlock:
            fd = self._master
            if fd is None:
                self.bytes_dropped += len(data)
                return
            try:
                n = os.write(fd, data)
            except BlockingIOError:
                n = 0
            except OSError as e:
                if e.errno not in (errno.EIO, errno.EBADF):
                    raise
                n = 0
            if n < len(data):
                self.bytes_dropped += len(data) - n

    def inject_garbage(self, data: bytes) -> None:
        """Send these bytes on the line (a fault)."""
        self.write(bytes(data))

    def vanish(self, seconds: float) -> None:
        """The port disappears for ``seconds`` host seconds (a USB adapter unplugged):
        the pty and the symlink go, the sequencer itself keeps its state and keeps
        transmitting (events meanwhile are lost); then a new pty appears at the same
        ``link_path``."""
        if self.link_path is None:
            raise ValueError("vanish needs a link_path: a driver finds a returning pty "
                             "only through a stable symlink")
        self._vanish_request = float(seconds)

    def _send(self, msg: proto.Message) -> bytes:
        b = proto.encode(msg)
        if isinstance(msg, proto.Nak):
            self.naks += 1
        self.write(b)
        return b

    # -- state machine ---------------------------------------------------------------

    def _start_pinging(self) -> None:
        self.state = "RUNNING"
        self.next_sequence = 0
        interval = self.interval_ns or 100_000_000
        if self.clock is None:
            self._next_ping_ns = time.monotonic_ns()
            return
        since = self.clock.true_ns() - self.clock.start_ns
        self._next_k = max(0, -(-since // interval))  # first grid point at or after now
        self._next_ping_ns = self.clock.start_ns + self._next_k * interval
        if self.on_start is not None:
            self.on_start(self._next_k, interval)

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
            self._start_pinging()
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

    @staticmethod
    def _nak_for(error: str) -> proto.Nak:
        """The NAK for a sentence the parser rejected (mid 0, command '?'): code 2 for an
        unknown sentence type, else 1 (unreadable: checksum, framing, fields)."""
        m = re.search(r"type: expected one of .*, found '([^']*)'", error)
        if m:
            name = re.sub(r"[^A-Za-z0-9_.-]", "_", m.group(1))[:16]
            return proto.Nak(0, "?", E.UNKNOWN_COMMAND, f"unknown command {name}")
        return proto.Nak(0, "?", E.BAD_CHECKSUM, "unreadable sentence")

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

    # -- thread ----------------------------------------------------------------------

    def _vanish_now(self, seconds: float) -> None:
        self._close_pty()
        try:
            self.link_path.unlink()
        except FileNotFoundError:
            pass
        self.vanishes += 1
        self._back_at = time.monotonic() + seconds
        logger.warning("sequencer: port %s vanished for %.3g s", self.link_path, seconds)

    def _ping_due_s(self) -> float:
        """Host seconds until the next ping is due (<= 0: now)."""
        if self.clock is None:
            return (self._next_ping_ns - time.monotonic_ns()) / 1e9
        return self.clock.host_delay_s(self._next_ping_ns)

    def _emit_ping(self) -> None:
        sched = self.schedule or (0,)
        seq = self.next_sequence
        interval = self.interval_ns or 100_000_000
        if self.clock is None:
            ev = proto.PingEvent(seq, sched[seq % len(sched)], time.time_ns())
        else:  # the projector cycle is locked to the track grid, as the echoes are
            ev = proto.PingEvent(seq, sched[self._next_k % len(sched)],
                                 device_time_ns(self.clock, self._next_ping_ns))
        self._send(ev)
        self.next_sequence += 1
        self.pings_sent += 1
        self._next_ping_ns += interval
        if self.clock is not None:
            k, self._next_k = self._next_k, self._next_k + 1
            if self.on_ping is not None:
                try:
                    self.on_ping(ev, k)
                except Exception:
                    logger.exception("sequencer: ping callback failed")

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._vanish_request is not None:
                seconds, self._vanish_request = self._vanish_request, None
                self._vanish_now(seconds)
            if self._back_at is not None and time.monotonic() >= self._back_at:
                self._back_at = None
                self._open_pty()
                logger.warning("sequencer: port %s is back (%s)", self.link_path, self.device)
            wait = 0.05
            if self.state == "RUNNING":
                wait = max(0.0, self._ping_due_s())
            master = self._master
            if master is None:
                time.sleep(min(wait, 0.01))
                r = []
            else:
                try:
                    r, _, _ = select.select([master], [], [], min(wait, 0.05))
                except (OSError, ValueError):
                    if self._stop.is_set():
                        break
                    r = []
            if r:
                try:
                    data = os.read(master, 4096)
                except OSError:  # no reader on the slave side for now
                    time.sleep(0.01)
                    data = b""
                rejected = self.parser.stats.rejected
                for msg in self.parser.feed(data):
                    self._handle(msg)
                new = self.parser.stats.rejected - rejected
                if new and not self.mute:
                    for err in self.parser.stats.errors[-min(new, 8):]:
                        self._send(self._nak_for(err))
            if self.state == "RUNNING" and self._ping_due_s() <= 0:
                self._emit_ping()
