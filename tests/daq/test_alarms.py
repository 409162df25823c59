"""The alarm checks on status snapshots (pure functions) and the tracker's raise, clear
and hysteresis; the [alarms] thresholds' defaults and errors; the status text."""

from __future__ import annotations

import copy

import pytest

from svss_daq.acquire_config import AcquireConfig, alarms_section
from svss_daq.alarms import CRITICAL, NAMES, WARNING, AlarmLimits, AlarmTracker, evaluate
from svss_daq.config import ConfigError, config_path, loads
from svss_daq.recent import RecentChange
from svss_daq.status import format_status

LIM = AlarmLimits(ping_interval_s=0.2, no_ping_intervals=5, min_rate_fraction=0.8,
                  rate_window_s=10, disk_min_free_mib=4096, disk_min_time_left_s=1800,
                  gps_fix_max_age_s=2.0, gps_max_sigma_m=5.0, dead_reckoning_max_s=60,
                  device_silent_s=3.0, worker_max_backlog_s=20, recent_s=10)

#: a healthy snapshot: recording at the schedule's rate, GPS and DVL good, room on disk
GOOD = {
    "state": "recording", "recording_s": 60.0, "ping_rate_hz": 5.0,
    "last_ping_age_s": 0.1,
    "recent": {"lost": {"never_delivered": 0, "incomplete": 0}, "stream_dropped": 0},
    "recorder": {"free_mib": 100000.0, "fill_mib_s": 2.4, "time_left_s": 41000.0,
                 "stopped": None},
    "devices": {"sequencer": {"connected": True, "silent_s": 0.1},
                "digitiser": {"connected": True},
                "dvl": {"connected": True, "silent_s": 0.2},
                "gps": {"connected": True, "silent_s": 0.3}},
    "navigation": {"mode": "gps", "solution": {
        "mode": "gps", "gps_fix_age_s": 0.4, "dvl_age_s": 0.1, "heading_source": "hdt",
        "bottom_lock": True, "gps_sigma_m": 0.05, "gps_gate": "accepting",
        "clock_offset_s": {"gps": 0.01}, "clock_retimed": [], "gps_rejected_sigma": 0}},
    "workers": [{"client": "w1", "run_id": "r", "next": 100, "done": False,
                 "backlog_pings": 2, "backlog_s": 0.4, "open_tiles": 3,
                 "max_open_tiles": 12, "memory_bound_age_s": None}],
}


def snap(**changes) -> dict:
    """GOOD with dotted keys replaced: snap(**{"navigation.solution.mode": "none"})."""
    s = copy.deepcopy(GOOD)
    for key, value in changes.items():
        *path, last = key.split(".")
        d = s
        for k in path:
            d = d[k]
        d[last] = value
    return s


def test_a_healthy_snapshot_raises_nothing():
    assert evaluate(GOOD, LIM) == {}


@pytest.mark.parametrize("changes, name, severity, says", [
    ({"last_ping_age_s": 1.1}, "pings.stopped", CRITICAL, "no ping for 1.1 s"),
    ({"ping_rate_hz": 3.9}, "pings.rate_low", WARNING, "3.90 pings/s"),
    ({"recent.lost": {"never_delivered": 3, "incomplete": 1}}, "pings.lost", WARNING,
     "4 ping(s) lost"),
    ({"recent.stream_dropped": 7}, "stream.dropped", WARNING, "7 ping(s) dropped"),
    ({"recorder.free_mib": 4000.0}, "disk.low", WARNING, "4000 MiB free"),
    ({"recorder.time_left_s": 600.0}, "disk.low", CRITICAL, "10.0 min left"),
    ({"navigation.solution.mode": "none", "navigation.solution.gps_fix_age_s": 9.0},
     "navigation.no_position", CRITICAL,
     "no position"),
    ({"navigation.solution.mode": "dead_reckoning",
      "navigation.solution.gps_fix_age_s": 5.0}, "navigation.no_gps_fix", WARNING,
     "dead reckoning on the DVL"),
    ({"navigation.solution.mode": "dead_reckoning",
      "navigation.solution.gps_fix_age_s": 61.0}, "navigation.dead_reckoning", WARNING,
     "dead reckoning for 61 s"),
    ({"navigation.solution.heading_source": "none"}, "navigation.no_heading", WARNING,
     "no heading"),
    ({"navigation.solution.bottom_lock": False}, "navigation.no_bottom_lock", WARNING,
     "no DVL bottom lock"),
    ({"navigation.solution.clock_retimed": ["gps"],
      "navigation.solution.clock_offset_s": {"gps": 18.0}}, "navigation.clock_offset",
     WARNING, "gps clock +18.000 s"),
    ({"navigation.solution.gps_sigma_m": 7.5}, "navigation.sigma_high", WARNING,
     "7.50 m above"),
    ({"devices.gps.silent_s": 3.5}, "gps.silent", WARNING, "nothing from the gps for 3.5"),
    ({"devices.dvl.connected": False}, "dvl.silent", CRITICAL, "dvl disconnected"),
    ({"workers": [{**GOOD["workers"][0], "backlog_pings": 150, "backlog_s": 30.0}]},
     "worker.behind", WARNING, "w1 150 ping(s) (30.0 s) behind"),
    ({"workers": [{**GOOD["workers"][0], "memory_bound_age_s": 2.0,
                   "open_tiles": 12}]}, "worker.memory_bound", WARNING, "12 of 12 tiles"),
    ({"workers": [{**GOOD["workers"][0], "silent": True, "heard_s": 45.0}]},
     "worker.silent", CRITICAL, "lacking pings of this run (the daemon keeps serving"),
    ({"workers": [{**GOOD["workers"][0], "silent": True, "heard_s": 45.0,
                   "done": True, "backlog_pings": 0, "backlog_s": 0.0}]},
     "worker.silent", WARNING, "w1 on run r at ping 100, silent for 45 s"),
    # a lead before the first ping: the rate window counts from the first ping
    ({"ping_rate_hz": 3.0, "recording_s": 60.0, "pinging_s": 12.0}, "pings.rate_low",
     WARNING, "3.00 pings/s"),
])
def test_each_condition_raises_its_named_alarm_and_only_that(changes, name, severity,
                                                              says):
    found = evaluate(snap(**changes), LIM)
    assert name in NAMES or name.endswith(".silent")
    # dead reckoning too long is also no GPS fix
    also = {"navigation.no_gps_fix"} if name == "navigation.dead_reckoning" else set()
    assert set(found) == {name} | also, found
    assert found[name].severity == severity
    assert says in found[name].message, found[name].message


@pytest.mark.parametrize("changes", [
    {"last_ping_age_s": 0.99},                      # 4.95 intervals: not yet
    {"ping_rate_hz": 4.0},                          # exactly 80 % of 5/s
    {"ping_rate_hz": 1.0, "recording_s": 9.0},      # the rate window is not full yet
    {"recorder.free_mib": 4096.0},
    {"navigation.solution.gps_fix_age_s": 2.0},     # the navigation's own limit
    {"navigation.solution.gps_sigma_m": 5.0},
    {"devices.gps.silent_s": 3.0},
    {"workers": [{**GOOD["workers"][0], "backlog_s": 20.0}]},
    {"workers": [{**GOOD["workers"][0], "memory_bound_age_s": 10.5}]},   # long ago
    {"ping_rate_hz": 0.0, "recording_s": 60.0, "pinging_s": None,       # the lead: no
     "last_ping_age_s": None},                                           # ping due yet
    {"ping_rate_hz": 1.0, "recording_s": 60.0, "pinging_s": 9.0},       # window not full
])
def test_thresholds_are_exclusive_bounds(changes):
    assert evaluate(snap(**changes), LIM) == {}


def test_ping_and_device_alarms_only_while_recording():
    s = snap(state="stopped", last_ping_age_s=100.0, ping_rate_hz=0.0,
             **{"devices.gps.silent_s": 50.0, "navigation.solution.mode": "none"})
    assert evaluate(s, LIM) == {}
    # a stopped sonar is not also a low rate; a dead reckoning without a GPS configured
    # is no GPS alarm
    s = snap(last_ping_age_s=5.0, ping_rate_hz=0.0)
    assert set(evaluate(s, LIM)) == {"pings.stopped"}
    s = snap(**{"navigation.solution.mode": "dead_reckoning",
                "navigation.solution.gps_fix_age_s": None})
    del s["devices"]["gps"]
    assert evaluate(s, LIM) == {}


def test_tracker_raises_once_clears_after_the_hysteresis_and_settles():
    tr = AlarmTracker(clear_after_s=3.0)
    stopped = evaluate(snap(last_ping_age_s=2.0), LIM)
    assert [(w, a.name) for w, a in tr.update(stopped, 100.0)] == [
        ("raised", "pings.stopped")]
    assert tr.update(stopped, 101.0) == []                      # raised once
    assert tr.update({}, 102.0) == []                           # gone, not cleared yet
    [row] = tr.listing(102.5)
    assert row["name"] == "pings.stopped" and row["clearing"] and row["age_s"] == 2.5
    assert tr.update(stopped, 103.0) == []                      # back: still the same one
    assert tr.update({}, 104.0) == [] and tr.update({}, 106.9) == []
    assert [(w, a.name) for w, a in tr.update({}, 107.0)] == [("cleared", "pings.stopped")]
    assert tr.listing(107.0) == []
    # the message follows the condition; settle clears at once; critical listed first
    tr.update({**evaluate(snap(last_ping_age_s=2.0), LIM),
               **evaluate(snap(**{"devices.gps.silent_s": 9.0}), LIM)}, 200.0)
    assert [r["name"] for r in tr.listing(200.0)] == ["pings.stopped", "gps.silent"]
    tr.update(evaluate(snap(last_ping_age_s=4.0), LIM), 201.0)
    assert "no ping for 4.0 s" in tr.listing(201.0)[0]["message"]
    assert sorted(a.name for _, a in tr.update({}, 201.5, settle=True)) == [
        "gps.silent", "pings.stopped"]


def test_recent_change_over_a_sliding_window():
    r = RecentChange(10.0)
    assert r.change() == ({}, 0.0)
    r.add(0.0, {"lost": 0})
    r.add(5.0, {"lost": 2})
    assert r.change() == ({"lost": 2}, 5.0)
    r.add(12.0, {"lost": 2})             # the baseline: the last sample at or before 2
    assert r.change() == ({"lost": 2}, 12.0)
    r.add(30.0, {"lost": 3})
    assert r.change() == ({"lost": 1}, 18.0)


def test_alarm_thresholds_default_in_the_schema_and_errors_name_file_and_key():
    text = config_path("acquire.toml").read_text()
    cfg = loads(AcquireConfig, text, "acquire.toml")
    a = alarms_section(cfg)
    assert a.no_ping_intervals == 5.0 and a.clear_after_s == 3.0
    # no [alarms] table at all: the same defaults
    bare = text[:text.index("[alarms]")]
    assert alarms_section(loads(AcquireConfig, bare, "bare.toml")) == a
    changed = loads(AcquireConfig, text + "disk_min_free_mib = 100\n", "x.toml")
    assert alarms_section(changed).disk_min_free_mib == 100.0
    with pytest.raises(ConfigError, match=r"x\.toml: key 'alarms\.device_silent_s'.*below"):
        loads(AcquireConfig, text + "device_silent_s = 0\n", "x.toml")
    with pytest.raises(ConfigError, match=r"x\.toml: unknown key 'alarms\.no_ping'"):
        loads(AcquireConfig, text + "no_ping = 3\n", "x.toml")


def test_status_text_alarms_first_utc_times_position_and_sources():
    s = snap(last_ping_age_s=2.0)
    tr = AlarmTracker(3.0)
    tr.update(evaluate(s, LIM), 0.0)
    s = {"alarms": tr.listing(1.0), "run_id": "r", "time_utc": "2026-11-27T03:00:00Z",
         **s, "events": [{"time_utc": "2026-11-27T02:59:59.123Z", "kind": "alarm.raised",
                          "detail": "pings.stopped: no ping"}],
         "recorder": {**s["recorder"], "file": "/runs/r_0000.h5", "closed": True,
                      "segment": 0}}
    s["navigation"]["pose"] = {
        "time_utc": "2026-11-23T05:00:00.000Z", "age_s": 0.4, "latitude_deg": 57.5,
        "longitude_deg": -11.25, "north_m": 1.0, "east_m": 2.0, "speed_m_s": 1.5,
        "heading_deg": 45.0, "altitude_m": 4.2, "position_source": "gps",
        "speed_source": "dvl", "heading_source": "hdt", "altitude_source": "dvl"}
    lines = format_status(s).splitlines()
    assert lines[0] == "ALARMS (1):" and "CRITICAL pings.stopped" in lines[1]
    text = "\n".join(lines)
    assert "57.500000N 11.250000W (gps)" in text and "1.50 m/s (dvl)" in text
    assert "heading 45.0 deg (hdt)" in text and "altitude 4.20 m (dvl)" in text
    assert "/runs/r_0000.h5 (segment 0, closed)" in text
    assert "event 2026-11-27T02:59:59.123Z: alarm.raised" in text
