"""Digitiser emulator: a TCP server on loopback speaking :mod:`svss_daq.protocols.digitiser`.

Serves one client at a time. START streams pings every ``ping_interval_s``, each split
into frames of ``channels_per_frame`` channels; samples come from any callable
``ping_samples(ping_number) -> int32 array (channels x samples)``. Test hooks:
:meth:`drop_frame`, :meth:`corrupt_frame` and :meth:`inject_garbage`.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from typing import Callable, Optional

import numpy as np

from svss_daq.protocols import digitiser as proto

__all__ = ["DigitiserEmulator"]

logger = logging.getLogger(__name__)
C, S = proto.CommandCode, proto.ReplyStatus


class DigitiserEmulator:
    """TCP digitiser on ``127.0.0.1:port`` (``port=0``: an ephemeral port, see
    :attr:`port`). Ping numbers continue across clients and start at ``first_ping``."""

    def __init__(self, ping_samples: Callable[[int], np.ndarray], *, port: int = 0,
                 ping_interval_s: float = 0.1, channels_per_frame: int = 16,
                 first_ping: int = 0, host: str = "127.0.0.1") -> None:
        self.ping_samples = ping_samples
        self.ping_interval_s = ping_interval_s
        self.channels_per_frame = channels_per_frame
        self.gain_db = 0.0
        self.streaming = False
        self.next_ping = first_ping
        self.pings_sent = 0
        self.sent: dict[int, tuple[int, np.ndarray]] = {}  #: ping -> (transmit ns, samples), last 64
        self._drop: set[tuple[int, int]] = set()
        self._corrupt: set[tuple[int, int]] = set()
        self._garbage: list[bytes] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind((host, port))
        self._server.listen(1)
        self._server.settimeout(0.05)
        self.host, self.port = self._server.getsockname()[:2]
        self._client: Optional[socket.socket] = None
        self._thread = threading.Thread(target=self._run, name="digitiser-emulator", daemon=True)

    def start(self) -> "DigitiserEmulator":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop serving; the client's connection is closed (it sees the device go away)."""
        self._stop.set()
        self._thread.join(2.0)
        for s in (self._client, self._server):
            if s is not None:
                try:
                    s.close()
                except OSError:
                    pass

    def __enter__(self) -> "DigitiserEmulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def drop_frame(self, ping: int, frame_index: int) -> None:
        """Do not send this frame."""
        self._drop.add((ping, frame_index))

    def corrupt_frame(self, ping: int, frame_index: int) -> None:
        """Flip a payload byte of this frame after its CRC was computed."""
        self._corrupt.add((ping, frame_index))

    def inject_garbage(self, data: bytes) -> None:
        """Send these bytes before the next frame."""
        with self._lock:
            self._garbage.append(bytes(data))

    # -- server thread ---------------------------------------------------------------

    def _handle_command(self, c: proto.CommandFrame) -> bytes:
        if c.command == C.START:
            if not self.streaming:
                self.streaming = True
                self._next_t = time.monotonic()
            return proto.encode_reply(c.request_id, c.command, S.OK)
        if c.command == C.STOP:
            self.streaming = False
            return proto.encode_reply(c.request_id, c.command, S.OK)
        if c.command == C.SET_GAIN:
            if not -20.0 <= c.value <= 60.0:
                return proto.encode_reply(c.request_id, c.command, S.BAD_VALUE, self.gain_db)
            self.gain_db = round(c.value * 2) / 2  # 0.5 dB steps
            return proto.encode_reply(c.request_id, c.command, S.OK, self.gain_db)
        if c.command == C.STATUS:
            return proto.encode_reply(c.request_id, c.command, S.OK, float(self.pings_sent))
        return proto.encode_reply(c.request_id, c.command, S.UNKNOWN_COMMAND)

    def _ping_bytes(self) -> bytes:
        n = self.next_ping
        self.next_ping += 1
        samples = np.asarray(self.ping_samples(n), dtype=np.int32)
        tx = time.time_ns()
        self.sent[n] = (tx, samples)
        self.sent.pop(n - 64, None)
        frames = proto.encode_data_frames(n, tx, tx, samples, self.channels_per_frame)
        out = bytearray()
        for k, fr in enumerate(frames):
            with self._lock:
                garbage, self._garbage = self._garbage, []
            for g in garbage:
                out += g
            if (n, k) in self._drop:
                continue
            if (n, k) in self._corrupt:
                fr = bytearray(fr)
                fr[proto.HEADER_SIZE + 3] ^= 0x5A
                fr = bytes(fr)
            out += fr
        self.pings_sent += 1
        return bytes(out)

    def _serve(self, cl: socket.socket) -> None:
        dec = proto.FrameStreamParser(max_payload=1024)
        cl.settimeout(0.01)
        while not self._stop.is_set():
            try:
                data = cl.recv(65536)
                if data == b"":
                    return
            except socket.timeout:
                data = b""
            for fr in dec.feed(data):
                if isinstance(fr, proto.CommandFrame):
                    cl.sendall(self._handle_command(fr))
            if self.streaming and time.monotonic() >= self._next_t:
                self._next_t += self.ping_interval_s
                cl.settimeout(2.0)
                cl.sendall(self._ping_bytes())
                cl.settimeout(0.01)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                cl, _ = self._server.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            self._client = cl
            self.streaming = False  # a new client starts streaming with START
            try:
                self._serve(cl)
            except OSError as e:
                logger.info("digitiser emulator: client gone (%s)", e)
            finally:
                try:
                    cl.close()
                except OSError:
                    pass
                self._client = None
