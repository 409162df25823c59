"""The acquisition daemon's status stream: JSON messages on a ZeroMQ PUB socket.

A message is two frames: the topic ``b"svss.status"`` and a UTF-8 JSON object with
``schema`` ``"svss.status"``, ``version``, ``time_utc``, ``run_id``, ``state``
(``starting``, ``recording``, ``stopping``, ``stopped``, ``failed``), ``ping_rate_hz``,
``counters`` (pings delivered, recorded, published, dropped, ...), ``recorder`` (file,
segment, pings on disk, free disk space), ``devices`` (one object per device: connected,
reconnects, garbage, ...), ``navigation`` (mode, flags of the last ping's pose, counts)
and ``events`` (the latest device events). ``svss status`` prints one. Never pickle.
See docs/acquisition.md.
"""

from __future__ import annotations

import json
import logging
import time

import zmq

from .endpoints import check_endpoint

log = logging.getLogger(__name__)

TOPIC = b"svss.status"
SCHEMA = "svss.status"
VERSION = 1


class StatusPublisher:
    """Binds ``endpoint`` and publishes status objects (never blocks: a full queue drops
    the message, the next one replaces it anyway)."""

    def __init__(self, endpoint: str, ctx: zmq.Context | None = None, *, curve=None):
        check_endpoint(endpoint, bind=True)
        self.sock = (ctx or zmq.Context.instance()).socket(zmq.PUB)
        self.sock.setsockopt(zmq.SNDHWM, 10)
        self.sock.setsockopt(zmq.LINGER, 0)
        if curve is not None:
            from .security import secure_server
            secure_server(self.sock, curve)
        try:
            self.sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.sock.close(linger=0)
            raise OSError(f"cannot bind the status stream to {endpoint}: {exc}") from None
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.sent = 0

    def publish(self, status: dict) -> None:
        msg = {"schema": SCHEMA, "version": VERSION, **status}
        try:
            self.sock.send_multipart([TOPIC, json.dumps(msg).encode()], zmq.NOBLOCK)
            self.sent += 1
        except zmq.Again:
            pass

    def close(self) -> None:
        self.sock.close(linger=0)


def decode_status(frames: list[bytes]) -> dict:
    """A status object from its frames; ValueError naming what is wrong."""
    if len(frames) != 2 or frames[0] != TOPIC:
        raise ValueError(f"status message: expected 2 frames with topic {TOPIC!r}, got "
                         f"{len(frames)} frame(s)")
    try:
        msg = json.loads(bytes(frames[1]).decode())
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"status message: header is not UTF-8 JSON ({exc})") from None
    if not isinstance(msg, dict) or msg.get("schema") != SCHEMA:
        raise ValueError(f"status message: expected schema {SCHEMA!r}")
    if msg.get("version") != VERSION:
        raise ValueError(f"status message: version {msg.get('version')!r}; this software "
                         f"reads version {VERSION}")
    return msg


def read_status(endpoint: str, timeout_s: float = 5.0, ctx: zmq.Context | None = None,
                *, curve=None) -> dict:
    """The next status message from the daemon at ``endpoint`` (TimeoutError naming the
    endpoint when none arrives within ``timeout_s``)."""
    check_endpoint(endpoint, bind=False)
    sock = (ctx or zmq.Context.instance()).socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        if curve is not None:
            from .security import secure_client
            secure_client(sock, curve)
        sock.connect(endpoint)
        sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not sock.poll(int(left * 1000)):
                raise TimeoutError(f"no status message from {endpoint} within "
                                   f"{timeout_s:g} s (is svss acquire running?)")
            try:
                return decode_status(sock.recv_multipart())
            except ValueError as exc:
                log.warning("%s: %s", endpoint, exc)
    finally:
        sock.close(linger=0)


def format_status(s: dict) -> str:
    """A few lines for an operator."""
    c, r, nav = s.get("counters", {}), s.get("recorder", {}), s.get("navigation", {})
    lines = [f"run {s.get('run_id')}  state {s.get('state')}  {s.get('time_utc')}  "
             f"uptime {s.get('uptime_s', 0):.0f} s",
             f"pings: {s.get('ping_rate_hz', 0):.2f}/s  delivered {c.get('delivered', 0)}  "
             f"recorded {c.get('recorded', 0)}  published {c.get('published', 0)}  "
             f"dropped (stream) {c.get('publish_dropped', 0)}  incomplete "
             f"{c.get('incomplete', 0)}  transmit records missing "
             f"{c.get('transmit_missing', 0)}",
             f"recording: {r.get('file')} (segment {r.get('segment')}), "
             f"{r.get('flushed', 0)} pings on disk, "
             f"{r.get('free_mib', float('nan')):.0f} MiB free"
             + (f"  STOPPED: {r['stopped']}" if r.get("stopped") else ""),
             f"navigation: {nav.get('mode')}  dead-reckoned pings "
             f"{nav.get('dead_reckoned', 0)}  without bottom lock "
             f"{nav.get('no_bottom_lock', 0)}  held {nav.get('held', 0)}"]
    sol = nav.get("solution") or {}
    if sol.get("clock_retimed") or sol.get("gps_gate") not in (None, "accepting"):
        off = sol.get("clock_offset_s", {})
        lines.append("  " + "  ".join(
            [f"clock offset {n} {off.get(n, float('nan')):+.3f} s (re-timed)"
             for n in sol.get("clock_retimed", [])]
            + ([f"GPS fixes rejected ({sol['gps_gate']}): {sol.get('gps_rejected', 0)}, "
                f"by sigma {sol.get('gps_rejected_sigma', 0)}"]
               if sol.get("gps_gate") not in (None, "accepting") else [])))
    for name, d in s.get("devices", {}).items():
        state = "connected" if d.get("connected") else "DISCONNECTED"
        extra = ", ".join(f"{k} {v}" for k, v in d.items() if k != "connected" and v)
        lines.append(f"  {name:<10} {state}" + (f"  ({extra})" if extra else ""))
    for t, kind, detail in s.get("events", [])[-5:]:
        lines.append(f"  event {t}: {kind}: {detail}")
    return "\n".join(lines)
