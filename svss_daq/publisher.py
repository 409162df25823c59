"""Ping publication over ZeroMQ (XPUB, so the publisher can see its subscribers).

Publishing never blocks acquisition: the socket's queue per subscriber is bounded
(``send_hwm``) and, with ``XPUB_NODROP``, a ping that does not fit is refused as a whole
(``zmq.Again`` on a non-blocking send) and counted in :attr:`PingPublisher.dropped`.
ZeroMQ refuses a message when *any* subscriber's queue is full, so with several
subscribers one slow subscriber makes every subscriber miss the same pings (all see the
same gaps); nobody blocks. See docs/formats.md.
"""

from __future__ import annotations

import logging
import time

import zmq

from . import messages
from .endpoints import check_endpoint
from .ping import Ping
from .config import CurveConfig
from .security import secure_server

log = logging.getLogger(__name__)


#: daq.toml publisher.end_timeout_s when omitted
END_TIMEOUT_S = 10.0


def publisher_end_timeout_s(daq) -> float:
    """daq.toml ``publisher.end_timeout_s`` (:data:`END_TIMEOUT_S` when omitted)."""
    t = daq.publisher.end_timeout_s
    return END_TIMEOUT_S if t is None else float(t)


class PingPublisher:
    """Binds ``endpoint`` (``tcp://127.0.0.1:*`` picks a free port) and publishes
    :mod:`~svss_daq.messages` with at most ``send_hwm`` (>= 1) messages queued per
    subscriber.

    A ping that finds a subscriber's queue full is dropped, counted (:attr:`dropped`) and
    logged (at most once per ``drop_log_interval_s``, with the sequence numbers); the
    end-of-run marker is retried for up to ``end_timeout_s`` instead.

    With ``curve`` enabled (the ``[security]`` table of daq.toml) the socket is a CURVE
    server: only subscribers whose public keys are authorized receive anything
    (:func:`~svss_daq.security.secure_server`, docs/security.md).
    """

    def __init__(self, endpoint: str, send_hwm: int, ctx: zmq.Context | None = None, *,
                 end_timeout_s: float = END_TIMEOUT_S, drop_log_interval_s: float = 5.0,
                 curve: CurveConfig | None = None):
        check_endpoint(endpoint, bind=True)
        if isinstance(send_hwm, bool) or not isinstance(send_hwm, int) or send_hwm < 1:
            raise ValueError(f"send_hwm: expected an integer >= 1 (messages), got "
                             f"{send_hwm!r}")
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.XPUB)
        self.sock.setsockopt(zmq.SNDHWM, send_hwm)
        self.sock.setsockopt(zmq.XPUB_NODROP, 1)    # full queue: zmq.Again, no silent drop
        self.sock.setsockopt(zmq.XPUB_VERBOSER, 1)  # every (un)subscription, to count them
        try:
            secure_server(self.sock, curve)
            self.sock.bind(endpoint)
        except ValueError:
            self.sock.close(linger=0)
            raise
        except zmq.ZMQError as exc:
            self.sock.close(linger=0)
            raise OSError(f"cannot bind ping publisher to {endpoint}: {exc}") from None
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.send_hwm = send_hwm
        self.end_timeout_s = end_timeout_s
        self.drop_log_interval_s = drop_log_interval_s
        self.subscriptions = 0
        self.published = 0          # pings handed to ZeroMQ
        self.dropped = 0            # pings refused because a subscriber's queue was full
        self._unreported = 0        # drops not logged yet, and their sequence range
        self._unreported_seq = (0, 0)
        self._last_drop_log = -float("inf")
        self._closed = False
        self.secured = bool(curve is not None and curve.enabled)
        log.info("publishing pings on %s (send_hwm %d%s)", self.endpoint, send_hwm,
                 ", CURVE" if self.secured else "")

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
                    log.info("subscriber left (%r)", event[1:])

    def wait_for_subscribers(self, n: int = 1, timeout_s: float = 30.0) -> None:
        """Block until ``n`` subscriptions have arrived (ZeroMQ drops messages published
        before a subscriber's subscription reaches the publisher)."""
        deadline = time.monotonic() + timeout_s
        while self.subscriptions < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no subscriber on {self.endpoint} after "
                                   f"{timeout_s:.0f} s")
            self._drain_subscriptions(int(min(left, 0.2) * 1000))

    def publish(self, msg: Ping | messages.RunEnd, run_id: str | None = None) -> bool:
        """Queue ``msg`` without blocking; return False if it was dropped. ``run_id``:
        the run a ping belongs to, in its header (subscribers key pings by it).

        A ping is dropped when a subscriber's queue is full; an end-of-run marker is
        retried for up to ``end_timeout_s`` first.
        """
        self._drain_subscriptions(0)
        if isinstance(msg, messages.RunEnd):
            return self._publish_end(msg)
        try:
            messages.send(self.sock, msg, zmq.NOBLOCK, run_id=run_id)
        except zmq.Again:
            self._count_drop(msg.sequence)
            return False
        self.published += 1
        return True

    def _count_drop(self, sequence: int) -> None:
        self.dropped += 1
        first = sequence if self._unreported == 0 else self._unreported_seq[0]
        self._unreported_seq = (first, sequence)
        self._unreported += 1
        if time.monotonic() - self._last_drop_log >= self.drop_log_interval_s:
            self._report_drops()

    def _report_drops(self) -> None:
        if self._unreported:
            first, last = self._unreported_seq
            log.warning("ping queue full (send_hwm %d, a subscriber is too slow): dropped "
                        "%d ping(s), sequence %d..%d; %d dropped in all", self.send_hwm,
                        self._unreported, first, last, self.dropped)
            self._unreported = 0
            self._last_drop_log = time.monotonic()

    def _publish_end(self, end: messages.RunEnd) -> bool:
        self._report_drops()
        deadline = time.monotonic() + self.end_timeout_s
        while True:
            try:
                messages.send(self.sock, end, zmq.NOBLOCK)
                return True
            except zmq.Again:
                if time.monotonic() >= deadline:
                    log.error("end-of-run marker of run %r not sent: a subscriber's queue "
                              "stayed full for %.1f s", end.run_id, self.end_timeout_s)
                    return False
            time.sleep(0.01)
            self._drain_subscriptions(0)

    def close(self, linger_s: float = 10.0) -> None:
        """Close, giving queued messages up to ``linger_s`` to leave."""
        if self._closed:
            return
        self._report_drops()
        if self.dropped:
            log.warning("publisher %s: %d ping(s) published, %d dropped", self.endpoint,
                        self.published, self.dropped)
        self.sock.close(linger=int(linger_s * 1000))
        self._closed = True

    def __enter__(self) -> PingPublisher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
