"""A simulated serial instrument on a pseudo-terminal reached through a stable path.

The pty's slave is published as a symlink ``<directory>/<name>`` -> ``/dev/pts/N``, so
the device can **vanish** (master closed, symlink removed: the reader's next read fails)
and **return** (a new pty, the symlink re-pointed atomically) under the same path, as a
USB serial adapter does behind a udev symlink. :class:`svss_daq.drivers.serial_link.SerialLink`
reopens the path and carries on.

While the device is gone, :meth:`SerialDevice.write` drops the bytes (counted): the
instrument keeps measuring, its output goes nowhere. Every fault is logged (warning)
with the simulated time of the device's clock and kept in :attr:`SerialDevice.faults`.
"""

from __future__ import annotations

import abc
import errno
import logging
import os
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from sim_device.devices.clock import SimClock

__all__ = ["SerialDevice", "SerialDeviceStats", "Fault", "open_raw_pty", "close_fds"]

logger = logging.getLogger(__name__)


def open_raw_pty() -> tuple[int, int]:
    """A new pty's (master, slave) descriptors, both raw; the master non-blocking, so
    that a full pty, or a reader that does not read, drops output rather than stalling
    the device."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    os.set_blocking(master, False)
    return master, slave


def close_fds(fds) -> None:
    """Close each of ``fds`` that is open (not None), errors ignored."""
    for fd in fds:
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass


@dataclass(frozen=True)
class Fault:
    """One injected fault: kind ('garbage', 'vanish', 'return', 'outage', ...), simulated
    time (ns, the devices' clock) and a description."""
    kind: str
    sim_time_ns: int
    detail: str


@dataclass
class SerialDeviceStats:
    bytes_written: int = 0
    writes_dropped: int = 0  #: writes lost while the device was gone or the pty was full
    bytes_dropped: int = 0
    garbage_bytes: int = 0
    vanishes: int = 0
    faults: list = field(default_factory=list)


class SerialDevice:
    """A device end on a pty whose slave is ``<directory>/<name>`` (:attr:`port`).

    ``clock`` stamps the fault log (simulated time) and scales :meth:`vanish`; without
    one the host clock is used."""

    def __init__(self, directory: str | os.PathLike, name: str,
                 clock: Optional[SimClock] = None) -> None:
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise ValueError(f"serial device {name!r}: directory {str(self.directory)!r} "
                             f"does not exist; expected a folder for the port symlink")
        if not name or "/" in name:
            raise ValueError(f"serial device name: expected a file name, found {name!r}")
        self.name = name
        self.clock = clock
        self.stats = SerialDeviceStats()
        self._master: Optional[int] = None
        self._slave: Optional[int] = None
        self._wlock = threading.Lock()

    # -- lifecycle ---------------------------------------------------------------

    @property
    def port(self) -> str:
        """The stable path a driver opens (a symlink to the current pty slave)."""
        return str(self.directory / self.name)

    @property
    def present(self) -> bool:
        """True while the device is there (started, not vanished, not closed)."""
        return self._master is not None

    def _sim_ns(self) -> int:
        return self.clock.now_ns() if self.clock is not None else time.time_ns()

    def _open_pty(self) -> None:
        master, slave = open_raw_pty()
        tmp = self.directory / f".{self.name}.new"
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)
        with self._wlock:
            self._master, self._slave = master, slave
        logger.info("%s: on %s -> %s", self.name, self.port, os.ttyname(slave))

    def _close_pty(self) -> None:
        with self._wlock:
            fds = (self._master, self._slave)
            self._master = self._slave = None
        close_fds(fds)
        try:
            os.unlink(self.port)
        except FileNotFoundError:
            pass

    def start(self) -> "SerialDevice":
        """Create the pty and publish :attr:`port`."""
        if self._master is None:
            self._open_pty()
        return self

    def close(self) -> None:
        """Close the pty and remove the symlink (idempotent)."""
        self._close_pty()

    def __enter__(self) -> "SerialDevice":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- output ------------------------------------------------------------------

    def write(self, data: bytes) -> bool:
        """Send ``data`` whole; False (counted in ``stats``) if the device is gone or the
        pty cannot take it now (nobody reading)."""
        with self._wlock:
            if self._master is None:
                self.stats.writes_dropped += 1
                self.stats.bytes_dropped += len(data)
                return False
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self._master, view)
                except OSError as e:
                    if e.errno not in (errno.EAGAIN, errno.EIO):
                        raise
                    self.stats.writes_dropped += 1
                    self.stats.bytes_dropped += len(view)
                    return False
                self.stats.bytes_written += n
                view = view[n:]
            return True

    # -- faults ------------------------------------------------------------------

    def _fault(self, kind: str, detail: str) -> Fault:
        f = Fault(kind, self._sim_ns(), detail)
        self.stats.faults.append(f)
        logger.warning("%s: fault %s at simulated time %.3f s: %s", self.name, kind,
                       f.sim_time_ns * 1e-9, detail)
        return f

    def inject_garbage(self, data: bytes) -> None:
        """Write ``data`` between two messages (line noise, a glitch)."""
        self._fault("garbage", f"{len(data)} bytes")
        self.stats.garbage_bytes += len(data)
        self.write(data)

    def vanish(self, seconds: float) -> None:
        """The device disappears for ``seconds`` of simulated time (host seconds without
        a clock), then returns on a new pty under the same :attr:`port`; blocks meanwhile."""
        if not seconds >= 0:
            raise ValueError(f"{self.name}: vanish seconds: expected >= 0, found {seconds!r}")
        self._fault("vanish", f"port {self.port} removed for {seconds:.3f} s")
        self.stats.vanishes += 1
        self._close_pty()
        scale = self.clock.time_scale if self.clock is not None else 1.0
        time.sleep(seconds / scale)
        self._open_pty()
        self._fault("return", f"port {self.port} back on {os.path.realpath(self.port)}")


class ScheduledSerialDevice(SerialDevice, abc.ABC):
    """A :class:`SerialDevice` with a thread that emits periodic outputs on a
    :class:`SimClock`.

    Each output stream has a period (s) and a latency (s): measurement ``k`` is taken at
    true simulated time ``start_ns + k * period`` and written ``latency`` later.
    Subclasses implement :meth:`_emit` (stream name, true measurement time ns, the
    devices' clock at that instant ns) returning the bytes to send."""

    def __init__(self, directory, name: str, clock: SimClock,
                 streams: dict[str, tuple[float, float]]) -> None:
        super().__init__(directory, name, clock)
        for s, (period, latency) in streams.items():
            if not period > 0 or not latency >= 0:
                raise ValueError(f"{name}: stream {s!r}: expected period > 0 and latency "
                                 f">= 0 s, found {period!r}, {latency!r}")
        self.streams = dict(streams)
        self.clock: SimClock = clock
        self.sent: dict[str, int] = {s: 0 for s in streams}  #: outputs emitted per stream
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    @abc.abstractmethod
    def _emit(self, stream: str, t_true_ns: int, t_clock_ns: int) -> bytes:
        """The bytes of one output of ``stream`` measured at true time ``t_true_ns``,
        stamped ``t_clock_ns`` on the devices' clock."""

    def start(self) -> "ScheduledSerialDevice":
        super().start()
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=f"sim-{self.name}",
                                            daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        super().close()

    def _run(self) -> None:
        t0 = self.clock.true_ns()
        # first measurement of each stream on a whole multiple of its period
        nxt = {}
        for s, (period, latency) in self.streams.items():
            p = int(round(period * 1e9))
            nxt[s] = (-(-t0 // p)) * p
        while not self._stop.is_set():
            s = min(nxt, key=lambda k: nxt[k] + int(self.streams[k][1] * 1e9))
            t_meas = nxt[s]
            if not self.clock.sleep_until(t_meas + int(self.streams[s][1] * 1e9), self._stop):
                break
            # the clock's steps so far, read at once (now_ns() - true_ns() read the host
            # clock twice: a thread held up between the reads stamped its output that
            # much early, 0.2 s at time scale 5 on a loaded machine)
            offset = self.clock.offset_ns
            try:
                data = self._emit(s, t_meas, t_meas + offset)
            except Exception:  # a bug must not silence the instrument for good
                logger.exception("%s: failed to build the %s output at %d ns", self.name, s,
                                 t_meas)
                data = b""
            if data:
                self.write(data)
            self.sent[s] += 1
            nxt[s] = t_meas + int(round(self.streams[s][0] * 1e9))
