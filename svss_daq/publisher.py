"""Ping publication over ZeroMQ (XPUB, so the publisher can see its subscribers)."""

from __future__ import annotations

import logging
import time

import zmq

from . import messages
from .ping import Ping

log = logging.getLogger(__name__)


class PingPublisher:
    """Binds ``endpoint`` (``tcp://127.0.0.1:*`` picks a free port) and publishes
    :mod:`~svss_daq.messages`. ``send_hwm`` = 0 never drops pings for a slow subscriber."""

    def __init__(self, endpoint: str, send_hwm: int = 0, ctx: zmq.Context | None = None):
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.XPUB)
        self.sock.setsockopt(zmq.SNDHWM, send_hwm)
        try:
            self.sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.sock.close(linger=0)
            raise OSError(f"cannot bind ping publisher to {endpoint}: {exc}") from None
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.subscriptions = 0
        log.info("publishing pings on %s", self.endpoint)

    def _drain_subscriptions(self, timeout_ms: int) -> None:
        if self.sock.poll(timeout_ms, zmq.POLLIN):
            while True:
                try:
                    event = self.sock.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                if event[:1] == b"\x01":
                    self.subscriptions += 1
                    log.info("subscriber joined (%r)", event[1:])
                elif event[:1] == b"\x00":
                    self.subscriptions -= 1

    def wait_for_subscribers(self, n: int = 1, timeout_s: float = 30.0) -> None:
        """Block until ``n`` subscriptions have arrived (ZeroMQ drops messages published
        before a subscriber's subscription reaches the publisher)."""
        deadline = time.monotonic() + timeout_s
        while self.subscriptions < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no subscriber on {self.endpoint} after {timeout_s:.0f} s")
            self._drain_subscriptions(int(min(left, 0.2) * 1000))

    def publish(self, msg: Ping | messages.RunEnd) -> None:
        self._drain_subscriptions(0)
        messages.send(self.sock, msg)

    def close(self, linger_s: float = 10.0) -> None:
        """Close, giving queued messages up to ``linger_s`` to leave."""
        self.sock.close(linger=int(linger_s * 1000))

    def __enter__(self) -> "PingPublisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
