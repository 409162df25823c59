"""The acquisition daemon's status stream: JSON messages on a ZeroMQ PUB socket.

A message is two frames: the topic ``b"svss.status"`` and a UTF-8 JSON object with
``schema`` ``"svss.status"``, ``version``, ``alarms`` (the active named alarms, critical
first: name, severity, message, since_utc, age_s; :mod:`svss_daq.alarms`), ``time_utc``,
``run_id``, ``state`` (``starting``, ``recording``, ``stopping``, ``stopped``,
``failed``), ``ping_rate_hz`` and ``schedule_rate_hz``, ``last_ping_age_s`` (before
the first ping: since pings were due, ``first_ping_due_s`` until then), ``pinging_s``,
``counters`` (pings delivered, recorded, published, dropped, ...), ``recent`` (pings
lost and dropped on the stream lately), ``recorder`` (file, segment, pings on disk, free
disk space, fill rate and time left), ``devices`` (one object per device: connected,
reconnects, garbage, seconds silent, ...), ``navigation`` (``mode`` and flags of the
last ping's pose, ``pose``: its position, speed, heading, altitude and their sources;
``solution``: the navigation now, judged on the ping clock; counts), ``workers`` (the
tile workers heard by the catch-up service, with their backlog) and ``events`` (the
latest events, times UTC). Times are UTC text, ages seconds. ``svss status`` prints
one (:func:`format_status`). Never pickle. See docs/acquisition.md and docs/operator.md.
"""

from __future__ import annotations

import json
import logging
import math
import time

import zmq

from .endpoints import check_endpoint
from .ping import (NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX, NAV_HEADING_FROM_COMPASS,
                   NAV_HEADING_FROM_COURSE, NAV_HELD, NAV_NO_HEADING)

log = logging.getLogger(__name__)

TOPIC = b"svss.status"
SCHEMA = "svss.status"
VERSION = 1
#: at close, how long the last status may wait to reach subscribers, ms
CLOSE_LINGER_MS = 200


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
        # a moment for the last status (the run's end) to reach its subscribers
        self.sock.close(linger=CLOSE_LINGER_MS)


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


def utc_text(t_ns: int | None) -> str | None:
    """``t_ns`` (ns since the Unix epoch) as UTC text to the millisecond."""
    if t_ns is None:
        return None
    s, ns = divmod(int(t_ns), 10**9)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(s)) + f".{ns // 10**6:03d}Z"


def _finite(v: float, digits: int) -> float | None:
    return round(float(v), digits) if math.isfinite(v) else None


def pose_summary(nav, now_ns: int | None) -> dict:
    """The operator's view of a ping's pose (a :class:`~svss_daq.ping.NavSnapshot`):
    time (UTC on the ping clock) and age at ``now_ns`` (same clock; None: unknown),
    latitude and longitude, survey-frame position, speed and course over ground,
    heading, altitude above the bottom, and where each came from (its quality flags): position ``gps``,
    ``dead_reckoning``, ``held`` or ``none``; heading ``hdt``, ``dvl_compass``,
    ``gps_course`` or ``none``; speed ``dvl`` (bottom track) or ``gps``; altitude
    ``dvl`` (bottom lock) or ``none``. Unknown numbers are null."""
    q = nav.quality
    held = " (held)" if q & NAV_HELD else ""
    position = ("gps" if q & NAV_GPS_FIX else "dead_reckoning" if q & NAV_DEAD_RECKONED
                else "held" if q & NAV_HELD else "none")
    heading = ("none" if q & NAV_NO_HEADING or not math.isfinite(nav.heading_rad) else
               "gps_course" if q & NAV_HEADING_FROM_COURSE else
               "dvl_compass" if q & NAV_HEADING_FROM_COMPASS else "hdt")
    vn, ve = nav.vel_north_m_s, nav.vel_east_m_s
    speed = math.hypot(vn, ve)
    return {"time_utc": utc_text(nav.time_ns),
            "age_s": None if now_ns is None else round((int(now_ns) - int(nav.time_ns))
                                                       * 1e-9, 3),
            "latitude_deg": _finite(nav.latitude_deg, 8),
            "longitude_deg": _finite(nav.longitude_deg, 8),
            "north_m": _finite(nav.north_m, 3), "east_m": _finite(nav.east_m, 3),
            "down_m": _finite(nav.down_m, 3),
            "speed_m_s": _finite(speed, 3),
            "course_deg": _finite(math.degrees(math.atan2(ve, vn)) % 360, 1)
            if speed > 0.05 else None,
            "heading_deg": _finite(math.degrees(nav.heading_rad) % 360, 1),
            "altitude_m": _finite(nav.altitude_m, 3),
            "position_source": position + (held if position != "held" else ""),
            "speed_source": ("dvl" if q & NAV_BOTTOM_LOCK else
                             "gps" if q & NAV_GPS_FIX else "none") + held,
            "heading_source": heading + held,
            "altitude_source": "dvl" if q & NAV_BOTTOM_LOCK and
            math.isfinite(nav.altitude_m) else "none"}


class StatusSubscriber:
    """A subscription to the status stream at ``endpoint``, kept across daemons: ZeroMQ
    connects when a daemon binds the endpoint and again after one went away, so the
    next status of the next run comes on the same subscription. :meth:`next` waits
    for one message."""

    def __init__(self, endpoint: str, ctx: zmq.Context | None = None, *, curve=None):
        check_endpoint(endpoint, bind=False)
        self.endpoint = endpoint
        self.sock = (ctx or zmq.Context.instance()).socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        try:
            if curve is not None:
                from .security import secure_client
                secure_client(self.sock, curve)
            self.sock.setsockopt(zmq.RECONNECT_IVL, 100)
            self.sock.setsockopt(zmq.RECONNECT_IVL_MAX, 1000)
            self.sock.connect(endpoint)
            self.sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
        except BaseException:
            self.sock.close(linger=0)
            raise

    def next(self, timeout_s: float) -> dict | None:
        """The next status message, or None when none came within ``timeout_s``
        (malformed ones are logged and skipped)."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not self.sock.poll(int(left * 1000)):
                return None
            try:
                return decode_status(self.sock.recv_multipart())
            except ValueError as exc:
                log.warning("%s: %s", self.endpoint, exc)

    def close(self) -> None:
        self.sock.close(linger=0)

    def __enter__(self) -> StatusSubscriber:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_status(endpoint: str, timeout_s: float = 5.0, ctx: zmq.Context | None = None,
                *, curve=None) -> dict:
    """The next status message from the daemon at ``endpoint`` (TimeoutError naming the
    endpoint when none arrives within ``timeout_s``)."""
    with StatusSubscriber(endpoint, ctx, curve=curve) as sub:
        s = sub.next(timeout_s)
    if s is None:
        raise TimeoutError(f"no status message from {endpoint} within "
                           f"{timeout_s:g} s (is svss acquire running?)")
    return s


def _n(v, fmt: str, unit: str = "", none: str = "?") -> str:
    return none if not isinstance(v, (int, float)) or isinstance(v, bool) \
        or not math.isfinite(v) else format(v, fmt) + unit


def _latlon(lat, lon) -> str:
    if lat is None or lon is None:
        return "position unknown"
    return (f"{abs(lat):.6f}{'N' if lat >= 0 else 'S'} "
            f"{abs(lon):.6f}{'E' if lon >= 0 else 'W'}")


def format_alarms(s: dict) -> list[str]:
    """The alarm lines of a status (the first lines of :func:`format_status`)."""
    alarms = s.get("alarms") or []
    if not alarms:
        return ["alarms: none"]
    lines = [f"ALARMS ({len(alarms)}):"]
    for a in alarms:
        sev = "CRITICAL" if a.get("severity") == "critical" else "warning"
        lines.append(f"  {sev:<8} {a.get('name')}  since {a.get('since_utc')} "
                     f"({_n(a.get('age_s'), '.0f', ' s')}"
                     + (", clearing" if a.get("clearing") else "")
                     + f"): {a.get('message')}")
    return lines


def format_status(s: dict) -> str:
    """Lines for an operator: the alarms first, then the run, pings, position,
    navigation, recording, devices, workers and the latest events."""
    c, r, nav = s.get("counters", {}), s.get("recorder", {}), s.get("navigation", {})
    lines = format_alarms(s)
    lines.append(f"run {s.get('run_id')}  state {s.get('state')}  at {s.get('time_utc')}"
                 f"  up {_n(s.get('uptime_s'), '.0f', ' s')}")
    age, due = s.get("last_ping_age_s"), s.get("first_ping_due_s")
    if s.get("pinging_s") is not None or "pinging_s" not in s:     # (an older daemon)
        last = _n(age, ".1f", " s ago", "none yet")
    elif age is None:
        last = "none yet" + ("" if due is None else f", due within {due:.1f} s")
    else:
        last = f"none yet, due {age:.1f} s ago"

    lines.append(f"pings: {_n(s.get('ping_rate_hz'), '.2f', '/s')} (schedule "
                 f"{_n(s.get('schedule_rate_hz'), '.2f', '/s')}), last "
                 f"{last}  delivered "
                 f"{c.get('delivered', 0)}  recorded {c.get('recorded', 0)}  published "
                 f"{c.get('published', 0)}  dropped (stream) {c.get('publish_dropped', 0)}"
                 f"  never delivered {c.get('never_delivered', 0)}  incomplete "
                 f"{c.get('incomplete', 0)}  transmit records missing "
                 f"{c.get('transmit_missing', 0)}")
    p = nav.get("pose")
    if p:
        lines.append(
            f"position: {_latlon(p.get('latitude_deg'), p.get('longitude_deg'))} "
            f"({p.get('position_source')})  N {_n(p.get('north_m'), '.1f')} E "
            f"{_n(p.get('east_m'), '.1f')} m  speed {_n(p.get('speed_m_s'), '.2f', ' m/s')}"
            f" ({p.get('speed_source')})  heading {_n(p.get('heading_deg'), '.1f', ' deg')}"
            f" ({p.get('heading_source')})  altitude "
            f"{_n(p.get('altitude_m'), '.2f', ' m')} ({p.get('altitude_source')})  "
            f"pose of the ping at {p.get('time_utc')} ({_n(p.get('age_s'), '.1f', ' s')} "
            "old)")
    else:
        lines.append("position: no ping posed yet")
    sol = nav.get("solution") or {}
    nav_line = (f"navigation: last ping {nav.get('mode')}, now {sol.get('mode', '?')}  "
                f"GPS fix {_n(sol.get('gps_fix_age_s'), '.1f', ' s ago', 'never')}"
                f" (sigma {_n(sol.get('gps_sigma_m'), '.2f', ' m', 'n/a')}, "
                f"{sol.get('gps_gate', '?')})  DVL "
                f"{_n(sol.get('dvl_age_s'), '.1f', ' s ago', 'never')}"
                f" ({'bottom lock' if sol.get('bottom_lock') else 'no bottom lock'})  "
                f"heading from {sol.get('heading_source', '?')}") if sol else \
        f"navigation: last ping {nav.get('mode')}"
    lines.append(nav_line + f"  dead-reckoned pings {nav.get('dead_reckoned', 0)}  held "
                 f"{nav.get('held', 0)}")
    if sol.get("clock_retimed"):
        off = sol.get("clock_offset_s", {})
        lines.append("  " + "  ".join(f"clock offset {n} {_n(off.get(n), '+.3f', ' s')}"
                                      " (re-timed)" for n in sol["clock_retimed"]))
    where = r.get("file") or "(no file yet)"
    lines.append(f"recording: {where} (segment {r.get('segment')}"
                 + (", closed" if r.get("closed") else "") + f"), {r.get('flushed', 0)} "
                 f"pings on disk, {_n(r.get('free_mib'), '.0f', ' MiB')} free"
                 + (f", filling {_n(r.get('fill_mib_s'), '.2f', ' MiB/s')}, "
                    f"{_n(r.get('time_left_s') / 60, '.0f', ' min')} left"
                    if isinstance(r.get("time_left_s"), (int, float)) else "")
                 + (f"  STOPPED: {r['stopped']}" if r.get("stopped") else ""))
    for name, d in s.get("devices", {}).items():
        state = "connected" if d.get("connected") else "DISCONNECTED"
        extra = ", ".join(f"{k} {v}" for k, v in d.items()
                          if k not in ("connected", "silent_s") and v)
        lines.append(f"  {name:<10} {state}"
                     + (f", last heard {_n(d.get('silent_s'), '.1f', ' s ago')}"
                        if d.get("silent_s") is not None else "")
                     + (f"  ({extra})" if extra else ""))
    for w in s.get("workers", []):
        lines.append(f"  worker {w.get('client')}: run {w.get('run_id')} at ping "
                     f"{w.get('next')}" + ("" if w.get("backlog_pings") is None else
                                           f", {w['backlog_pings']} ping(s) "
                                           f"({_n(w.get('backlog_s'), '.1f', ' s')}) behind")
                     + (f", {w.get('open_tiles')} of {w.get('max_open_tiles')} tiles open"
                        if w.get("open_tiles") is not None else "")
                     + (f", imaging {w['imaging_method']}" if w.get("imaging_method") else "")
                     + (f", SILENT for {_n(w.get('heard_s'), '.0f', ' s')}"
                        if w.get("silent") else ""))
    for e in s.get("events", [])[-5:]:
        if isinstance(e, dict):
            lines.append(f"  event {e.get('time_utc')}: {e.get('kind')}: {e.get('detail')}")
    return "\n".join(lines)
