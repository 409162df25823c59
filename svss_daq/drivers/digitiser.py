"""Digitiser driver: TCP client that reassembles pings and sends control commands.

A background thread connects (``connect_timeout_s``), reads, feeds a
:class:`~svss_daq.protocols.digitiser.DigitiserStreamDecoder` and delivers
:class:`~svss_daq.protocols.digitiser.CompletePing` (int32 channels x samples, ping
number, timestamps) and :class:`~svss_daq.protocols.digitiser.IncompletePing` to a
callback and/or queue. When the socket goes away it reconnects with exponential backoff
and, if acquisition had been started, sends START again. A ping with no new frame for
``ping_timeout_s`` is closed and reported incomplete.
"""

from __future__ import annotations

import itertools
import logging
import queue as queue_mod
import socket
import threading
import time
from typing import Any, Callable, Optional

from svss_daq.protocols import digitiser as proto

__all__ = ["DigitiserClient", "DigitiserError", "DigitiserTimeout", "DigitiserNotConnected"]

logger = logging.getLogger(__name__)


class DigitiserError(RuntimeError):
    """The digitiser rejected a command; ``status`` is the reply's status code."""

    def __init__(self, message: str, status: int) -> None:
        self.status = status
        super().__init__(message)


class DigitiserTimeout(TimeoutError):
    """No reply to a command in time."""


class DigitiserNotConnected(ConnectionError):
    """Not connected to the digitiser."""


class DigitiserClient:
    """TCP client of the digitiser at ``host:port``.

    ``on_ping(item)`` (reader thread) and/or ``ping_queue`` receive CompletePing and
    IncompletePing objects (a gap in the ping numbers is one IncompletePing carrying its
    range). ``stats``-like counters: ``connects``, ``disconnects``, ``dropped`` (items
    the queue, at most ``queue_pings`` long, had no room for: logged at the 1st, 10th,
    100th...).
    """

    def __init__(self, host: str, port: int, *, connect_timeout_s: float = 2.0,
                 reply_timeout_s: float = 1.0, reconnect_initial_s: float = 0.1,
                 reconnect_max_s: float = 5.0, ping_timeout_s: float = 0.5,
                 max_payload_bytes: int = proto.DEFAULT_MAX_PAYLOAD,
                 queue_pings: int = 1000,
                 on_ping: Optional[Callable[[Any], None]] = None,
                 ping_queue: Optional[queue_mod.Queue] = None) -> None:
        self.host, self.port = host, port
        self.connect_timeout_s = connect_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self.reconnect_initial_s = reconnect_initial_s
        self.reconnect_max_s = reconnect_max_s
        self.ping_timeout_s = ping_timeout_s
        self.on_ping = on_ping
        self.ping_queue = ping_queue if ping_queue is not None else \
            queue_mod.Queue(maxsize=queue_pings)
        self.decoder = proto.DigitiserStreamDecoder(max_payload_bytes)
        self.connects = 0
        self.disconnects = 0
        self.dropped = 0
        self.last_error: Optional[BaseException] = None
        self._sock: Optional[socket.socket] = None
        self._send_lock = threading.Lock()
        self._cmd_lock = threading.Lock()
        self._replies: queue_mod.Queue = queue_mod.Queue()
        self._ids = itertools.cycle(range(1, 1 << 31))
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._acquiring = False
        self._gain_db: Optional[float] = None

    @classmethod
    def from_config(cls, cfg, **kw: Any) -> "DigitiserClient":
        """From a :class:`~svss_daq.config.DigitiserLinkConfig`."""
        return cls(cfg.host, cfg.port, connect_timeout_s=cfg.connect_timeout_s,
                   reply_timeout_s=cfg.reply_timeout_s,
                   reconnect_initial_s=cfg.reconnect_initial_s,
                   reconnect_max_s=cfg.reconnect_max_s, ping_timeout_s=cfg.ping_timeout_s,
                   max_payload_bytes=cfg.max_payload_bytes, queue_pings=cfg.queue_pings,
                   **kw)

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def wait_connected(self, timeout_s: float) -> bool:
        return self._connected.wait(timeout_s)

    # -- life cycle ------------------------------------------------------------------

    def open(self, wait_connected_s: Optional[float] = None) -> "DigitiserClient":
        """Start the reader thread; with a wait, raise DigitiserNotConnected if not
        connected in time (naming the address and the last error)."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"digitiser:{self.host}:{self.port}",
                                        daemon=True)
        self._thread.start()
        if wait_connected_s is not None and not self.wait_connected(wait_connected_s):
            self.close()
            raise DigitiserNotConnected(f"digitiser {self.host}:{self.port} not connected within "
                                        f"{wait_connected_s:g} s: {self.last_error}")
        return self

    def close(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        self._drop_socket()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
        self._thread = None

    def __enter__(self) -> "DigitiserClient":
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- commands --------------------------------------------------------------------

    def command(self, code: int, value: float = 0.0) -> proto.ReplyFrame:
        """Send a command and wait ``reply_timeout_s`` for its reply."""
        name = proto.CommandCode.NAMES.get(code, str(code))
        with self._cmd_lock:
            rid = next(self._ids)
            with self._send_lock:
                s = self._sock
                if s is None:
                    raise DigitiserNotConnected(f"{name}: digitiser {self.host}:{self.port} is "
                                                f"not connected ({self.last_error})")
                try:
                    s.sendall(proto.encode_command(rid, code, value))
                except OSError as e:
                    raise DigitiserNotConnected(f"{name}: send to {self.host}:{self.port} "
                                                f"failed: {e}") from e
            deadline = time.monotonic() + self.reply_timeout_s
            while True:
                left = deadline - time.monotonic()
                try:
                    r = self._replies.get(timeout=max(left, 0)) if left > 0 else None
                except queue_mod.Empty:
                    r = None
                if r is None:
                    raise DigitiserTimeout(f"no reply to {name} (request {rid}) from "
                                           f"{self.host}:{self.port} within "
                                           f"{self.reply_timeout_s:g} s")
                if r.request_id == rid:
                    break
                logger.debug("digitiser: stale reply %r ignored", r)
        if r.status != proto.ReplyStatus.OK:
            why = proto.ReplyStatus.NAMES.get(r.status, "unknown status")
            raise DigitiserError(f"digitiser rejected {name} (request {rid}): status "
                                 f"{r.status} ({why})", r.status)
        return r

    def start(self) -> None:
        """Start streaming; after a reconnection the driver starts it again."""
        self.command(proto.CommandCode.START)
        self._acquiring = True

    def stop(self) -> None:
        self._acquiring = False
        self.command(proto.CommandCode.STOP)

    def set_gain(self, gain_db: float) -> float:
        """Set the analogue gain, dB; returns the gain the digitiser applied."""
        r = self.command(proto.CommandCode.SET_GAIN, float(gain_db))
        self._gain_db = r.value
        return r.value

    def status(self) -> int:
        """Pings sent since START."""
        return int(self.command(proto.CommandCode.STATUS).value)

    # -- reader thread ---------------------------------------------------------------

    def _drop_socket(self) -> None:
        with self._send_lock:
            s, self._sock = self._sock, None
        self._connected.clear()
        if s is not None:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def _deliver(self, items: list) -> None:
        for it in items:
            if isinstance(it, proto.ReplyFrame):
                self._replies.put(it)
                continue
            if isinstance(it, proto.CommandFrame):
                logger.warning("digitiser: unexpected command frame from the device: %r", it)
                continue
            if self.on_ping is not None:
                try:
                    self.on_ping(it)
                except Exception:
                    logger.exception("digitiser: ping callback failed")
            try:
                self.ping_queue.put_nowait(it)
            except queue_mod.Full:
                self.dropped += 1
                if str(self.dropped).rstrip("0") == "1":
                    logger.warning("digitiser: ping queue full (%d items), ping %d dropped "
                                   "(%d in all; logged at every power of 10)",
                                   self.ping_queue.maxsize, it.ping_number, self.dropped)

    def _resume(self) -> None:
        """After a reconnection: restore gain and streaming (in a helper thread, since
        replies arrive through the reader thread)."""
        def go() -> None:
            try:
                if self._gain_db is not None:
                    self.set_gain(self._gain_db)
                self.command(proto.CommandCode.START)
                logger.info("digitiser: streaming restarted after reconnection")
            except Exception as e:
                logger.warning("digitiser: could not restart streaming after reconnection: %s", e)
        threading.Thread(target=go, name="digitiser-resume", daemon=True).start()

    def _run(self) -> None:
        delay = self.reconnect_initial_s
        while not self._stop.is_set():
            try:
                s = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
            except OSError as e:
                self.last_error = e
                logger.debug("digitiser: connect to %s:%d failed (%s); retry in %.2g s",
                             self.host, self.port, e, delay)
                self._stop.wait(delay)
                delay = min(delay * 2, self.reconnect_max_s)
                continue
            s.settimeout(0.05)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._send_lock:
                self._sock = s
            self.connects += 1
            self.last_error = None
            self._connected.set()
            delay = self.reconnect_initial_s
            logger.info("digitiser: connected to %s:%d", self.host, self.port)
            if self._acquiring:
                self._resume()
            last_frame = time.monotonic()
            while not self._stop.is_set():
                try:
                    data = s.recv(1 << 20)
                except socket.timeout:
                    data = None
                except OSError as e:
                    self.last_error = e
                    data = b""
                if data == b"":
                    if not self._stop.is_set():
                        self.disconnects += 1
                        logger.warning("digitiser: connection to %s:%d lost (%s); reconnecting",
                                       self.host, self.port, self.last_error or "closed by peer")
                    break
                now = time.monotonic()
                if data:
                    last_frame = now
                    self._deliver(self.decoder.feed(data))
                elif self.decoder.assembler.open_ping is not None and \
                        now - last_frame > self.ping_timeout_s:
                    self._deliver(self.decoder.flush())
            self._drop_socket()
            self._deliver(self.decoder.reset())
            if not self._stop.is_set():
                self._stop.wait(delay)
