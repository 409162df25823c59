"""Named alarms of the acquisition: pure checks of a status snapshot, and a tracker that
turns what the checks find into raise and clear events.

:func:`evaluate` reads one status snapshot (the object the daemon publishes on its
status stream, :mod:`svss_daq.status`) against :class:`AlarmLimits` and returns the
alarms whose condition holds now, by name; it keeps no state (a snapshot carries the
ages, rates and recent counts the checks need). :class:`AlarmTracker` keeps the active
alarms: an alarm is raised the first time its condition is found and cleared once the
condition has been absent for ``clear_after_s`` (hysteresis: a condition that flickers
raises one alarm, not a stream of them). The daemon (:mod:`svss_daq.daemon`) puts the
active alarms first in its status and writes every raise and clear to the run's events
(``alarm.raised`` / ``alarm.cleared``, the detail starting with the alarm's name).

The alarms, their meaning and what they ask of the operator: docs/operator.md.
Thresholds: ``acquire.toml [alarms]`` (:class:`~svss_daq.acquire_config.AlarmsSection`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

CRITICAL = "critical"
WARNING = "warning"
#: every alarm name :func:`evaluate` can return ("<device>.silent" for each device)
NAMES = ("pings.stopped", "pings.rate_low", "pings.lost", "stream.dropped", "disk.low",
         "navigation.no_position", "navigation.no_gps_fix", "navigation.dead_reckoning",
         "navigation.no_heading", "navigation.no_bottom_lock", "navigation.clock_offset",
         "navigation.sigma_high", "sequencer.silent", "digitiser.silent", "dvl.silent",
         "gps.silent", "worker.behind", "worker.silent", "worker.memory_bound")


@dataclass(frozen=True)
class Alarm:
    """One alarm: its name (``NAMES``), severity (``critical`` or ``warning``) and what
    is wrong, with the numbers."""
    name: str
    severity: str
    message: str


@dataclass(frozen=True)
class AlarmLimits:
    """The thresholds the checks read: ``acquire.toml [alarms]`` and the few settings of
    the other configurations they compare against."""
    ping_interval_s: float            # hardware sequencer.ping_interval_s
    no_ping_intervals: float          # alarms.no_ping_intervals
    min_rate_fraction: float          # alarms.min_rate_fraction
    rate_window_s: float              # status.rate_window_s
    disk_min_free_mib: float          # alarms.disk_min_free_mib
    disk_min_time_left_s: float       # alarms.disk_min_time_left_s
    gps_fix_max_age_s: float          # devices navigation.gps_fix_max_age_s
    gps_max_sigma_m: float            # devices navigation.gps_max_sigma_m
    dead_reckoning_max_s: float       # alarms.dead_reckoning_max_s
    device_silent_s: float            # alarms.device_silent_s
    worker_max_backlog_s: float       # alarms.worker_max_backlog_s
    recent_s: float                   # alarms.recent_s

    @classmethod
    def from_setup(cls, setup) -> AlarmLimits:
        """From an :class:`~svss_daq.acquire_config.AcquireSetup`."""
        from .acquire_config import alarms_section
        a, acq, nav = alarms_section(setup.acquire), setup.acquire, setup.devices.navigation
        return cls(ping_interval_s=setup.hardware.value.sequencer.ping_interval_s,
                   no_ping_intervals=a.no_ping_intervals,
                   min_rate_fraction=a.min_rate_fraction,
                   rate_window_s=acq.status.rate_window_s,
                   disk_min_free_mib=a.disk_min_free_mib,
                   disk_min_time_left_s=a.disk_min_time_left_s,
                   gps_fix_max_age_s=nav.gps_fix_max_age_s,
                   gps_max_sigma_m=nav.gps_max_sigma_m,
                   dead_reckoning_max_s=a.dead_reckoning_max_s,
                   device_silent_s=a.device_silent_s,
                   worker_max_backlog_s=a.worker_max_backlog_s, recent_s=a.recent_s)


def _num(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) \
        and math.isfinite(v) else None


def _ago(age) -> str:
    a = _num(age)
    return "never" if a is None else f"{a:.1f} s ago"


# --------------------------------------------------------------------------- checks


def check_pings(s: dict, lim: AlarmLimits) -> list[Alarm]:
    """While recording: no ping for ``no_ping_intervals`` ping intervals (before the
    first ping: counted from when pings are due, ``first_ping_s`` after the start); the
    rate below ``min_rate_fraction`` of the schedule (once a whole rate window was
    pinged);
    pings lost, or dropped on the stream, within ``recent_s``."""
    out = []
    if s.get("state") != "recording":
        return out
    interval = lim.ping_interval_s
    age = _num(s.get("last_ping_age_s"))
    if age is not None and age > lim.no_ping_intervals * interval:
        out.append(Alarm("pings.stopped", CRITICAL, (
            f"no ping for {age:.1f} s ({age / interval:.0f} ping intervals of "
            f"{interval:g} s; alarm after {lim.no_ping_intervals:g})")))
    else:
        rate, want = _num(s.get("ping_rate_hz")) or 0.0, 1.0 / interval
        # a whole rate window of pinging (a status without ``pinging_s``, from an older
        # daemon: of recording)
        pinging = _num(s.get("pinging_s")) if "pinging_s" in s else _num(s.get("recording_s"))
        if (pinging or 0.0) >= lim.rate_window_s and rate < lim.min_rate_fraction * want:
            out.append(Alarm("pings.rate_low", WARNING, (
                f"{rate:.2f} pings/s over the last {lim.rate_window_s:g} s, below "
                f"{lim.min_rate_fraction:.0%} of the schedule's {want:.2f}/s")))
    recent = s.get("recent") or {}
    lost = {k: v for k, v in (recent.get("lost") or {}).items() if v}
    if lost:
        out.append(Alarm("pings.lost", WARNING, (
            f"{sum(lost.values())} ping(s) lost in the last {lim.recent_s:g} s (" +
            ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sorted(lost.items()))
            + ")")))
    n = recent.get("stream_dropped") or 0
    if n:
        out.append(Alarm("stream.dropped", WARNING, (
            f"{n} ping(s) dropped on the live stream in the last {lim.recent_s:g} s: a "
            "subscriber does not keep up (they are recorded; a worker fetches them from "
            "the catch-up service)")))
    return out


def check_disk(s: dict, lim: AlarmLimits) -> list[Alarm]:
    """Free space below ``disk_min_free_mib``, or less than ``disk_min_time_left_s``
    left at the current rate before recording stops (critical then, and when recording
    stopped)."""
    r = s.get("recorder") or {}
    free = _num(r.get("free_mib"))
    if free is None:
        return []
    left = _num(r.get("time_left_s"))
    short = left is not None and left < lim.disk_min_time_left_s
    if not (free < lim.disk_min_free_mib or short or r.get("stopped")):
        return []
    rate = _num(r.get("fill_mib_s"))
    msg = f"{free:.0f} MiB free (alarm below {lim.disk_min_free_mib:g} MiB)"
    if left is not None:
        msg += f"; {left / 60:.1f} min left at {rate or 0:.2f} MiB/s before recording stops"
    elif rate is not None and rate <= 0:
        msg += "; not filling now"
    if r.get("stopped"):
        msg += f"; recording STOPPED: {r['stopped']}"
    return [Alarm("disk.low", CRITICAL if short or r.get("stopped") else WARNING, msg)]


def check_navigation(s: dict, lim: AlarmLimits) -> list[Alarm]:
    """The navigation solution now (``navigation.solution``): no position, no GPS fix,
    dead reckoning for longer than ``dead_reckoning_max_s``, no heading, no bottom lock,
    instrument clocks off the ping clock, GPS sigma above the limit."""
    nav = s.get("navigation") or {}
    sol = nav.get("solution")
    devices = s.get("devices") or {}
    has_gps, has_dvl = "gps" in devices, "dvl" in devices
    if not isinstance(sol, dict) or not (has_gps or has_dvl) \
            or s.get("state") != "recording":
        return []
    out = []
    mode = sol.get("mode")
    fix_age, dvl_age = _num(sol.get("gps_fix_age_s")), _num(sol.get("dvl_age_s"))
    no_fix = has_gps and (fix_age is None or fix_age > lim.gps_fix_max_age_s)
    if mode == "none":
        out.append(Alarm("navigation.no_position", CRITICAL, (
            f"no position: last GPS fix {_ago(fix_age)}, no dead reckoning (DVL "
            f"{'bottom lock lost' if has_dvl else 'not configured'}); pings are posed "
            "on held navigation or without a position")))
    elif no_fix:
        out.append(Alarm("navigation.no_gps_fix", WARNING, (
            f"no GPS fix: last {_ago(fix_age)} (navigation.gps_fix_max_age_s "
            f"{lim.gps_fix_max_age_s:g} s)" + (
                "; the receiver reports no fix" if sol.get("gps_gate") == "no_fix" else "")
            + ("; dead reckoning on the DVL carries the position"
               if mode == "dead_reckoning" else ""))))
    if mode == "dead_reckoning" and has_gps and (
            fix_age is None or fix_age > lim.dead_reckoning_max_s):
        out.append(Alarm("navigation.dead_reckoning", WARNING, (
            f"dead reckoning for {'the whole run' if fix_age is None else f'{fix_age:.0f} s'}"
            f" (alarm after {lim.dead_reckoning_max_s:g} s): the position drifts")))
    if sol.get("heading_source") == "none":
        out.append(Alarm("navigation.no_heading", WARNING, (
            "no heading: no HDT, DVL compass or GPS course within "
            "navigation.heading_max_age_s; lever arms and the tile frame are unreliable")))
    if has_dvl and not sol.get("bottom_lock"):
        out.append(Alarm("navigation.no_bottom_lock", WARNING, (
            f"no DVL bottom lock (last DVL sample {_ago(dvl_age)}): altitude unknown, no "
            "dead reckoning")))
    retimed = sol.get("clock_retimed") or []
    if retimed:
        off = sol.get("clock_offset_s") or {}
        out.append(Alarm("navigation.clock_offset", WARNING, "; ".join(
            f"{n} clock {(_num(off.get(n)) or float('nan')):+.3f} s off the ping clock"
            for n in retimed) + ": its records are re-timed by their receive times"))
    sigma = _num(sol.get("gps_sigma_m"))
    if sol.get("gps_gate") == "sigma" or (sigma is not None and sigma > lim.gps_max_sigma_m):
        out.append(Alarm("navigation.sigma_high", WARNING, (
            f"GPS sigma {'unknown' if sigma is None else f'{sigma:.2f} m'} above "
            f"navigation.gps_max_sigma_m {lim.gps_max_sigma_m:g} m: fixes rejected "
            f"({sol.get('gps_rejected_sigma', 0)} by sigma so far)")))
    return out


def check_devices(s: dict, lim: AlarmLimits) -> list[Alarm]:
    """While recording: a device disconnected, or (``silent_s`` in its status) silent
    for longer than ``device_silent_s``."""
    if s.get("state") != "recording":
        return []
    out = []
    for name, d in sorted((s.get("devices") or {}).items()):
        if not isinstance(d, dict):
            continue
        silent = _num(d.get("silent_s"))
        if not d.get("connected"):
            out.append(Alarm(f"{name}.silent", CRITICAL,
                             f"{name} disconnected; reconnecting"))
        elif silent is not None and silent > lim.device_silent_s:
            out.append(Alarm(f"{name}.silent", WARNING, (
                f"nothing from the {name} for {silent:.1f} s (alarm after "
                f"{lim.device_silent_s:g} s)")))
    return out


def check_workers(s: dict, lim: AlarmLimits) -> list[Alarm]:
    """The tile workers that tell the catch-up service their progress: one silent (not
    heard for the service's ``worker_silence_s``; critical while it lacks pings of the
    run); one more than ``worker_max_backlog_s`` behind the recording; one that reached
    its memory bound within ``recent_s``."""
    behind, bound, silent, stuck = [], [], [], []
    for w in s.get("workers") or []:
        if w.get("silent"):
            what = (f"{w.get('client')} on run {w.get('run_id')} at ping {w.get('next')}, "
                    f"silent for {_num(w.get('heard_s')) or 0:.0f} s")
            lacks = not w.get("done") and (w.get("backlog_pings") or 0) > 0
            (stuck if lacks else silent).append(what)
        lag = _num(w.get("backlog_s"))
        if lag is not None and lag > lim.worker_max_backlog_s:
            behind.append(f"{w.get('client')} {w.get('backlog_pings')} ping(s) "
                          f"({lag:.1f} s) behind on run {w.get('run_id')}")
        age = _num(w.get("memory_bound_age_s"))
        if age is not None and age <= lim.recent_s:
            bound.append(f"{w.get('client')} ({w.get('open_tiles')} of "
                         f"{w.get('max_open_tiles')} tiles open, bound reached "
                         f"{age:.1f} s ago)")
    out = []
    if stuck or silent:
        parts = (["lacking pings of this run (the daemon keeps serving them after it, "
                  "up to catch_up.max_linger_s): " + "; ".join(stuck)] if stuck else [])
        parts += silent
        out.append(Alarm("worker.silent", CRITICAL if stuck else WARNING,
                         "worker(s) silent (stopped or hung: no progress for "
                         "service.worker_silence_s): " + "; ".join(parts)))
    if behind:
        out.append(Alarm("worker.behind", WARNING, "worker(s) behind the recording "
                         f"(alarm beyond {lim.worker_max_backlog_s:g} s): "
                         + "; ".join(behind)))
    if bound:
        out.append(Alarm("worker.memory_bound", WARNING, "worker(s) at their memory "
                         "bound (processing limits.memory_gib): tiles closed early or "
                         "pings refused: " + "; ".join(bound)))
    return out


CHECKS = (check_pings, check_disk, check_navigation, check_devices, check_workers)


def evaluate(status: dict, limits: AlarmLimits) -> dict[str, Alarm]:
    """Every alarm whose condition holds in ``status``, by name."""
    return {a.name: a for check in CHECKS for a in check(status, limits)}


# --------------------------------------------------------------------------- tracker


@dataclass
class Active:
    """An active alarm: the latest finding, when it was raised (monotonic and UTC) and
    since when its condition has been absent (None: present)."""
    alarm: Alarm
    since: float
    since_utc: str
    absent_since: float | None = None


@dataclass
class AlarmTracker:
    """The active alarms. :meth:`update` with what :func:`evaluate` found returns the
    events: ``("raised", alarm)`` for a new one, ``("cleared", alarm)`` for one whose
    condition has been absent for ``clear_after_s`` (at once with ``settle``: the run
    ended). An alarm found again updates its message and severity."""
    clear_after_s: float
    active: dict[str, Active] = field(default_factory=dict)

    def update(self, found: dict[str, Alarm], now_s: float, *, settle: bool = False
               ) -> list[tuple[str, Alarm]]:
        events = []
        for name, alarm in found.items():
            a = self.active.get(name)
            if a is None:
                self.active[name] = Active(alarm, now_s, time.strftime(
                    "%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
                events.append(("raised", alarm))
            else:
                a.alarm, a.absent_since = alarm, None
        for name in [n for n in self.active if n not in found]:
            a = self.active[name]
            if a.absent_since is None:
                a.absent_since = now_s
            if settle or now_s - a.absent_since >= self.clear_after_s:
                del self.active[name]
                events.append(("cleared", a.alarm))
        return events

    def listing(self, now_s: float) -> list[dict]:
        """The active alarms for the status stream: critical first, then oldest first."""
        order = sorted(self.active.values(),
                       key=lambda a: (a.alarm.severity != CRITICAL, a.since, a.alarm.name))
        return [{"name": a.alarm.name, "severity": a.alarm.severity,
                 "message": a.alarm.message, "since_utc": a.since_utc,
                 "age_s": round(now_s - a.since, 1),
                 "clearing": a.absent_since is not None} for a in order]


__all__ = ["Alarm", "AlarmLimits", "AlarmTracker", "CRITICAL", "NAMES", "WARNING",
           "evaluate"]
