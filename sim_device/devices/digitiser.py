"""Digitiser emulator: a TCP server on loopback speaking :mod:`svss_daq.protocols.digitiser`.

Serves one client at a time; a ping is split into frames of ``channels_per_frame``
channels. Two ways to make pings, both only while the client has sent START:

* free-running (``ping_interval_s`` a number): a ping every interval, samples from the
  callable ``ping_samples(ping_number) -> int32 array (channels x samples)``, stamped
  ``time.time_ns()``;
* triggered (``ping_interval_s=None``): :meth:`trigger` hands over one ping (number,
  transmit time, samples), as the simulated device does for each of the sequencer's
  transmissions. A ping triggered while not streaming is not sent (counted).

Faults: :meth:`drop_frame`, :meth:`corrupt_frame` (by ping number), :meth:`drop_next`,
:meth:`corrupt_next` (the next pings sent), :meth:`inject_garbage` and
:meth:`reset_connection`.
"""

from __future__ import annotations

import collections
import logging
import socket
import struct
import threading
import time
from typing import Callable, Optional

import numpy as np

from svss_daq.protocols import digitiser as proto

__all__ = ["DigitiserEmulator"]

logger = logging.getLogger(__name__)
C, S = proto.CommandCode, proto.ReplyStatus


#: a fault's pings logged: the first few, then every n-th (a 1005-ping gap logged 5025
#: lines, one a frame)
FAULT_LOG_FIRST = 3
FAULT_LOG_EVERY = 100


def _frames(ks: list[int]) -> str:
    """Frame indices as ranges: [0, 1, 2, 4] -> '0-2, 4'."""
    parts, start = [], None
    for i, k in enumerate(ks):
        if start is None:
            start = k
        if i + 1 == len(ks) or ks[i + 1] != k + 1:
            parts.append(str(start) if start == k else f"{start}-{k}")
            start = None
    return ", ".join(parts)


class DigitiserEmulator:
    """TCP digitiser on ``127.0.0.1:port`` (``port=0``: an ephemeral port, see
    :attr:`port`). Free-running ping numbers continue across clients and start at
    ``first_ping``; ``ping_samples`` may be None in triggered mode."""

    def __init__(self, ping_samples: Optional[Callable[[int], np.ndarray]] = None, *,
                 port: int = 0, ping_interval_s: Optional[float] = 0.1,
                 channels_per_frame: int = 16, first_ping: int = 0,
                 host: str = "127.0.0.1", max_pending: int = 8) -> None:
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
        self._drop_next: list[list[int]] = []     # [frame index (-1: all), pings left]
        self._corrupt_next: list[list[int]] = []
        self._reset = False
        #: triggered pings waiting to be sent: (ping, transmit ns, first sample ns, samples)
        self._pending: collections.deque = collections.deque()
        self.max_pending = max_pending
        self.not_streaming = 0   #: triggered pings discarded: no client streaming
        self.overflowed = 0      #: triggered pings discarded: the client did not keep up
        self.frames_dropped = 0
        self.frames_corrupted = 0
        #: pings with frames dropped / corrupted by a fault (their log lines: the first
        #: FAULT_LOG_FIRST, then every FAULT_LOG_EVERY-th)
        self._fault_pings = {"dropped": 0, "corrupted": 0}
        self.resets = 0
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
        if self._thread.ident is not None:          # (never started: nothing to join)
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

    def drop_next(self, frame_index: int = -1, pings: int = 1) -> None:
        """Do not send frame ``frame_index`` (-1: every frame) of the next ``pings`` pings."""
        with self._lock:
            self._drop_next.append([int(frame_index), int(pings)])

    def corrupt_next(self, frame_index: int = 0, pings: int = 1) -> None:
        """Corrupt the payload of frame ``frame_index`` of the next ``pings`` pings."""
        with self._lock:
            self._corrupt_next.append([int(frame_index), int(pings)])

    def reset_connection(self) -> None:
        """Reset the client's TCP connection (RST, as a rebooting device would); the
        server keeps listening and the driver is expected to reconnect. Without a client
        there is nothing to reset (logged)."""
        if self._client is None:
            logger.warning("digitiser emulator: connection reset requested with no client")
            return
        self._reset = True

    def trigger(self, ping_number: int, transmit_time_ns: int, first_sample_time_ns: int,
                samples: np.ndarray) -> bool:
        """Queue one ping for sending (triggered mode); False if it was discarded
        because no client is streaming or ``max_pending`` pings are already queued."""
        if not (self.streaming and self._client is not None):
            self.not_streaming += 1
            return False
        with self._lock:
            if len(self._pending) >= self.max_pending:
                self.overflowed += 1
                logger.warning("digitiser emulator: client not keeping up, ping %d discarded",
                               ping_number)
                return False
            self._pending.append((int(ping_number), int(transmit_time_ns),
                                  int(first_sample_time_ns), np.asarray(samples, np.int32)))
        return True

    def _faults_for(self, rules: list[list[int]], frame_count: int) -> set[int]:
        """Frame indices hit by the next-ping rules (consumes one ping of each rule)."""
        hit: set[int] = set()
        for rule in rules:
            idx = rule[0]
            hit |= set(range(frame_count)) if idx < 0 else {idx % frame_count}
            rule[1] -= 1
        rules[:] = [r for r in rules if r[1] > 0]
        return hit

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

    def _ping_bytes(self, pending=None) -> bytes:
        if pending is None:  # free-running
            n = self.next_ping
            self.next_ping += 1
            samples = np.asarray(self.ping_samples(n), dtype=np.int32)
            tx = first = time.time_ns()
        else:
            n, tx, first, samples = pending
        self.sent[n] = (tx, samples)
        self.sent.pop(n - 64, None)
        frames = proto.encode_data_frames(n, tx, first, samples, self.channels_per_frame)
        with self._lock:
            drop = self._faults_for(self._drop_next, len(frames))
            corrupt = self._faults_for(self._corrupt_next, len(frames))
        out = bytearray()
        dropped, corrupted = [], []
        for k, fr in enumerate(frames):
            with self._lock:
                garbage, self._garbage = self._garbage, []
            for g in garbage:
                out += g
            if (n, k) in self._drop or k in drop:
                self.frames_dropped += 1
                dropped.append(k)
                continue
            if (n, k) in self._corrupt or k in corrupt:
                fr = bytearray(fr)
                fr[proto.HEADER_SIZE + 3] ^= 0x5A
                fr = bytes(fr)
                self.frames_corrupted += 1
                corrupted.append(k)
            out += fr
        for what, ks in (("dropped", dropped), ("corrupted", corrupted)):
            if ks:
                self._fault_pings[what] += 1
                m = self._fault_pings[what]
                if m <= FAULT_LOG_FIRST or m % FAULT_LOG_EVERY == 0:   # not a line a frame
                    logger.info("digitiser emulator: ping %d: frame(s) %s %s (fault; %d "
                                "ping(s), %d frame(s) %s so far)", n, _frames(ks), what, m,
                                self.frames_dropped if what == "dropped"
                                else self.frames_corrupted, what)
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
            if self._reset:
                self._reset = False
                self.resets += 1
                # SO_LINGER 0: close() sends RST, the client sees "connection reset"
                cl.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                logger.warning("digitiser emulator: connection reset (fault)")
                return
            if self.ping_interval_s is None:
                while self._pending:
                    with self._lock:
                        item = self._pending.popleft()
                    if self.streaming:
                        cl.settimeout(2.0)
                        cl.sendall(self._ping_bytes(item))
                        cl.settimeout(0.01)
            elif self.streaming and time.monotonic() >= self._next_t:
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
            self.streaming = False  # a new client starts streaming with START
            with self._lock:
                self._pending.clear()
            self._client = cl
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
