"""A reusable serial-port reader: a background thread feeding a stream parser.

:class:`SerialLink` opens a port with pyserial, reads in a background thread with a
short read timeout, feeds the bytes to a parser (any object with
``feed(bytes) -> iterable of records``, e.g. :class:`~svss_daq.protocols.pd0.Pd0StreamParser`
or :class:`~svss_daq.protocols.nmea.NmeaStreamParser`) and hands each record to a
callback and/or puts it on a queue. When the port fails (read error, device
unplugged, pseudo-terminal closed) it logs it, closes the port and reopens the
same path with an exponential backoff until :meth:`SerialLink.stop` is called; the
parser keeps its state and resynchronises on its own.

Times are in seconds (float) for timeouts and backoff; the optional host receive
time stamped on records is int ns since the Unix epoch (``time.time_ns()``).
"""

from __future__ import annotations

import logging
import os
import queue as queue_mod
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Optional, Protocol

import serial

__all__ = ["SerialLink", "SerialLinkStats", "SerialOpenTimeout", "StreamParser", "open_port"]

logger = logging.getLogger(__name__)


class StreamParser(Protocol):
    """Anything that turns bytes into records."""

    def feed(self, data: bytes) -> Iterable[Any]: ...


class SerialOpenTimeout(TimeoutError):
    """The port could not be opened in time; ``port`` names it, ``last_error`` says why."""

    def __init__(self, port: str, timeout_s: float, last_error: Optional[BaseException]) -> None:
        self.port = port
        self.timeout_s = timeout_s
        self.last_error = last_error
        super().__init__(f"could not open serial port {port!r} within {timeout_s:g} s"
                         + (f": {last_error}" if last_error is not None else ""))


def _open_once(port: str, baudrate: int, read_timeout_s: float, serial_kwargs: dict) -> serial.Serial:
    return serial.Serial(port=port, baudrate=baudrate, timeout=read_timeout_s, **serial_kwargs)


def open_port(
    port: str,
    baudrate: int = 9600,
    *,
    timeout_s: float = 5.0,
    read_timeout_s: float = 0.1,
    retry_interval_s: float = 0.1,
    **serial_kwargs: Any,
) -> serial.Serial:
    """Open ``port``, retrying until ``timeout_s``; raise :class:`SerialOpenTimeout` naming it.

    Invalid settings (``ValueError`` from pyserial) are raised at once.
    """
    deadline = time.monotonic() + timeout_s
    last: Optional[BaseException] = None
    while True:
        try:
            return _open_once(port, baudrate, read_timeout_s, serial_kwargs)
        except (serial.SerialException, OSError) as e:
            last = e
        left = deadline - time.monotonic()
        if left <= 0:
            raise SerialOpenTimeout(port, timeout_s, last)
        time.sleep(min(retry_interval_s, left))


@dataclass
class SerialLinkStats:
    """Counters of a :class:`SerialLink` (updated by its thread)."""

    bytes_read: int = 0
    records: int = 0
    connects: int = 0  #: successful opens
    disconnects: int = 0  #: read failures that closed the port
    open_failures: int = 0
    records_dropped: int = 0  #: queue full
    parser_errors: int = 0
    callback_errors: int = 0


class SerialLink:
    """Read a serial port in a background thread and deliver parsed records.

    ``on_record(record)`` is called in the reader thread; ``queue`` (a
    ``queue.Queue``) receives records with ``put_nowait`` (a full queue drops the
    record, counted in ``stats.records_dropped``, so a slow consumer never stalls
    the port). With ``timestamp=True`` each record is delivered as
    ``(host_time_ns, record)``, the host time at which its last byte was read.

    Backoff between reopen attempts starts at ``reconnect_initial_s`` and doubles up
    to ``reconnect_max_s``. Extra keyword arguments go to ``serial.Serial``
    (bytesize, parity, stopbits, rtscts, ...).
    """

    def __init__(
        self,
        port: str,
        parser: StreamParser,
        *,
        baudrate: int = 9600,
        on_record: Optional[Callable[[Any], None]] = None,
        queue: Optional[queue_mod.Queue] = None,
        timestamp: bool = False,
        read_timeout_s: float = 0.05,
        read_size: int = 4096,
        reconnect_initial_s: float = 0.1,
        reconnect_max_s: float = 5.0,
        name: Optional[str] = None,
        **serial_kwargs: Any,
    ) -> None:
        if on_record is None and queue is None:
            raise ValueError("give on_record, queue or both")
        self.port = port
        self.parser = parser
        self.baudrate = baudrate
        self.on_record = on_record
        self.queue = queue
        self.timestamp = timestamp
        self.read_timeout_s = read_timeout_s
        self.read_size = read_size
        self.reconnect_initial_s = reconnect_initial_s
        self.reconnect_max_s = reconnect_max_s
        self.name = name or f"serial:{port}"
        self.serial_kwargs = serial_kwargs
        self.stats = SerialLinkStats()
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._ser: Optional[serial.Serial] = None
        self._lock = threading.Lock()
        self._last_open_error: Optional[BaseException] = None
        self._device: Optional[str] = None

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def last_open_error(self) -> Optional[BaseException]:
        """Why the latest attempt to open the port failed (None if it never failed)."""
        return self._last_open_error

    @property
    def device(self) -> Optional[str]:
        """The device the port path resolved to when last opened (symlinks followed)."""
        return self._device

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, *, wait_connected_s: Optional[float] = None) -> "SerialLink":
        """Start the reader thread.

        With ``wait_connected_s``, block until the port is open and raise
        :class:`SerialOpenTimeout` (naming the port; the link is stopped) if it is
        not open by then.
        """
        if self.running:
            raise RuntimeError(f"{self.name} is already running")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        if wait_connected_s is not None and not self.wait_connected(wait_connected_s):
            self.stop()
            raise SerialOpenTimeout(self.port, wait_connected_s, self._last_open_error)
        return self

    def wait_connected(self, timeout_s: float) -> bool:
        """True once the port is open (False after ``timeout_s``)."""
        return self._connected.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread and close the port; returns within about ``timeout_s``."""
        self._stop.set()
        with self._lock:
            ser = self._ser
        if ser is not None:
            try:
                ser.cancel_read()  # wakes a blocked read at once (POSIX)
            except Exception:
                pass
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
            if t.is_alive():
                logger.error("%s: reader thread did not stop within %g s", self.name, timeout_s)
        self._thread = None if t is None or not t.is_alive() else t

    def __enter__(self) -> "SerialLink":
        return self.start() if not self.running else self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # -- thread -------------------------------------------------------------------

    def _close(self) -> None:
        with self._lock:
            ser, self._ser = self._ser, None
        self._connected.clear()
        if ser is not None:
            try:
                ser.close()
            except Exception as e:  # closing a vanished device may fail
                logger.debug("%s: error closing port: %s", self.name, e)

    def _deliver(self, records: Iterable[Any], rx_ns: int) -> None:
        for rec in records:
            self.stats.records += 1
            item = (rx_ns, rec) if self.timestamp else rec
            if self.on_record is not None:
                try:
                    self.on_record(item)
                except Exception:
                    self.stats.callback_errors += 1
                    logger.exception("%s: record callback failed", self.name)
            if self.queue is not None:
                try:
                    self.queue.put_nowait(item)
                except queue_mod.Full:
                    self.stats.records_dropped += 1
                    if self.stats.records_dropped == 1 or self.stats.records_dropped % 100 == 0:
                        logger.warning("%s: queue full, %d record(s) dropped so far",
                                       self.name, self.stats.records_dropped)

    def _run(self) -> None:
        delay = self.reconnect_initial_s
        failures_logged = 0
        while not self._stop.is_set():
            if self._ser is None:
                try:
                    ser = _open_once(self.port, self.baudrate, self.read_timeout_s, self.serial_kwargs)
                except ValueError as e:  # invalid settings: retrying cannot help
                    self._last_open_error = e
                    self.stats.open_failures += 1
                    logger.error("%s: invalid serial settings for %s: %s; reader stopped", self.name, self.port, e)
                    break
                except (serial.SerialException, OSError) as e:
                    self._last_open_error = e
                    self.stats.open_failures += 1
                    log = logger.warning if failures_logged == 0 else logger.debug
                    log("%s: cannot open %s (%s); retrying in %.2g s", self.name, self.port, e, delay)
                    failures_logged += 1
                    self._stop.wait(delay)
                    delay = min(delay * 2.0, self.reconnect_max_s)
                    continue
                with self._lock:
                    self._ser = ser
                if self._stop.is_set():
                    break
                self._device = os.path.realpath(self.port)
                self.stats.connects += 1
                self._connected.set()
                logger.info("%s: opened %s (%s)", self.name, self.port, self._device)
                delay = self.reconnect_initial_s
                failures_logged = 0
            try:
                data = self._ser.read(1)
                if data:
                    n = self._ser.in_waiting
                    if n:
                        data += self._ser.read(min(n, self.read_size))
            except Exception as e:  # SerialException, OSError, or pyserial internals on a vanished fd
                if self._stop.is_set():
                    break
                self.stats.disconnects += 1
                logger.warning("%s: read from %s failed (%s); reconnecting", self.name, self.port, e)
                self._close()
                self._stop.wait(delay)
                continue
            if not data:
                continue
            rx_ns = time.time_ns()
            self.stats.bytes_read += len(data)
            try:
                records = list(self.parser.feed(data))
            except Exception:
                self.stats.parser_errors += 1
                logger.exception("%s: parser failed on %d bytes", self.name, len(data))
                continue
            self._deliver(records, rx_ns)
        self._close()
        logger.info("%s: stopped", self.name)
