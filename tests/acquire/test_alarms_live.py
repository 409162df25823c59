"""Alarms raised and cleared through real processes: ``svss sim-device`` with a faults
file (the sonar stops delivering pings, a GPS outage, a DVL dropout), ``svss acquire``, a tile worker
that falls behind and reaches its memory bound (its progress messages to the real
catch-up service), a disk floor above the free space; and ``svss status --follow``
started before any daemon, through one run's end and the next run's start."""

from __future__ import annotations

import json
import queue
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from svss_daq.ping_service import PingFetcher
from svss_daq.rawfile import RawRunReader
from svss_daq.status import format_status

from .conftest import CONFIG, ROOT, acquire_toml

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")

# simulated seconds after the sequencer's START (10 pings/s): the sonar delivers no
# ping for 2 s, the GPS loses its fix for 3 s, the DVL drops out for 2.5 s
FAULTS = """
[[fault]]
at_s = 2.0
kind = "digitiser.drop_frames"
frame = -1
pings = 20

[[fault]]
at_s = 6.0
kind = "gps.outage"
seconds = 3.0

[[fault]]
at_s = 11.0
kind = "dvl.vanish"
seconds = 2.5
"""
DEADLINE_S = 90.0        # a loaded machine; each wait below ends as soon as it is met


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Follower:
    """``svss status --follow --json`` as a process; its status lines in a queue."""

    def __init__(self, endpoint: str):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "svss", "status", "--follow", "--json", "--connect",
             endpoint, "--timeout", "1"], stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL, cwd=ROOT, text=True)
        self.lines: queue.Queue = queue.Queue()
        self.seen: set[str] = set()        # every alarm name any status listed
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            s = json.loads(line)
            self.seen |= {a["name"] for a in s["alarms"]}
            self.lines.put(s)

    def until(self, pred, what: str, timeout_s: float = DEADLINE_S) -> dict:
        """The first status (from now) for which ``pred`` holds."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                s = self.lines.get(timeout=0.5)
            except queue.Empty:
                assert self.proc.poll() is None, "svss status --follow exited"
                continue
            if pred(s):
                return s
        raise AssertionError(f"svss status --follow: no status with {what} within "
                             f"{timeout_s} s")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(10)


def alarmed(*names):
    return lambda s: set(names) <= {a["name"] for a in s["alarms"]}


def not_alarmed(*names):
    return lambda s: s["state"] == "recording" and not (
        set(names) & {a["name"] for a in s["alarms"]})


def test_alarms_raise_and_clear_through_real_processes_and_follow_survives_runs(
        rig, tmp_path):
    port = free_port()
    endpoint = f"tcp://127.0.0.1:{port}"
    daq = tmp_path / "daq.toml"         # publisher and service on free ports
    daq.write_text((CONFIG / "daq.toml").read_text()
                   .replace('"tcp://127.0.0.1:5556"', '"tcp://127.0.0.1:*"')
                   .replace('"tcp://127.0.0.1:5557"', '"tcp://127.0.0.1:*"'))
    alarms = {"recent_s": 2.0, "clear_after_s": 0.5, "worker_max_backlog_s": 1.0,
              "device_silent_s": 1.0,
              "disk_min_free_mib": 0.0, "disk_min_time_left_s": 0.0}
    common = {"run": {"daq": str(daq)}, "status": {"endpoint": endpoint},
              "catch_up": {"linger_s": 0.0}}
    follower = Follower(endpoint)          # before any daemon is up
    try:
        faults = tmp_path / "faults.toml"
        faults.write_text(FAULTS)
        dev = rig.device("--faults", str(faults))
        acq = rig.acquire(dev, "--duration", "120", ephemeral=False,
                          config=acquire_toml(tmp_path, alarms=alarms, **common))
        follower.until(lambda s: s["run_id"] == "run1" and s["state"] == "recording",
                       "run1 recording")
        # a worker that stays at the run's first ping, at its memory bound: its
        # progress messages to the daemon's catch-up service, every 0.3 s
        s = follower.until(lambda s: s["counters"]["recorded"] > 0, "a ping recorded")
        fetcher = PingFetcher(acq.endpoints["service"], timeout_s=10)
        [run] = [r for r in fetcher.runs() if r.run_id == "run1"]
        worker = {"done": False, "extras": {"open_tiles": 4, "max_open_tiles": 4,
                                            "memory_bound_age_s": 0.0}}
        stop = threading.Event()

        def slow_worker():
            while not stop.wait(0.3):
                fetcher.progress("slow-worker", "run1", run.first, worker["done"],
                                 worker["extras"])

        talker = threading.Thread(target=slow_worker, daemon=True)
        talker.start()
        # the sonar stops (no ping for 5 ping intervals), then pings again
        s = follower.until(alarmed("pings.stopped"), "pings.stopped")
        assert [a for a in s["alarms"] if a["name"] == "pings.stopped"][0][
            "severity"] == "critical"
        s = follower.until(alarmed("worker.behind", "worker.memory_bound"),
                           "the slow worker's alarms")
        [w] = s["workers"]
        assert w["client"] == "slow-worker" and w["backlog_pings"] > 10
        follower.until(not_alarmed("pings.stopped"), "pings.stopped cleared")
        # the GPS outage: dead reckoning on the DVL carries the position
        s = follower.until(alarmed("navigation.no_gps_fix"), "navigation.no_gps_fix")
        assert s["navigation"]["solution"]["mode"] == "dead_reckoning"
        text = format_status(s)               # what an operator reads: alarms first
        assert text.startswith("ALARMS (") and "navigation.no_gps_fix" in text
        assert "now dead_reckoning" in text, text
        (tmp_path / "status.txt").write_text(text)
        worker.update(done=True, extras={"open_tiles": 2, "max_open_tiles": 4,
                                         "memory_bound_age_s": 30.0})
        follower.until(not_alarmed("navigation.no_gps_fix", "worker.behind",
                                   "worker.memory_bound"), "the alarms cleared")
        # pings posed on GPS again (their poses lag the solution): the GPS fix age on
        # the devices' own clock (not the host's), the position and its sources
        s = follower.until(lambda s: s["navigation"]["pose"]["position_source"] == "gps"
                           and s["navigation"]["solution"]["mode"] == "gps",
                           "a ping posed on GPS after the outage")
        sol, pose = s["navigation"]["solution"], s["navigation"]["pose"]
        assert 0 <= sol["gps_fix_age_s"] < 5 and 0 <= pose["age_s"] < 10
        assert -90 <= pose["latitude_deg"] <= 90 and -180 <= pose["longitude_deg"] <= 360
        assert pose["altitude_source"] == "dvl" and pose["speed_m_s"] is not None
        stop.set()
        talker.join()
        # the DVL drops out: silent, no bottom lock; both clear when it is back
        dvl = ("dvl.silent", "navigation.no_bottom_lock")
        follower.until(lambda s: set(dvl) <= follower.seen and not_alarmed(*dvl)(s),
                       "the DVL dropout's alarms raised and cleared")
        fetcher.close()
        acq.stop()
        # the run's last status: its file named, closed (not "recording: None")
        s = follower.until(lambda s: s["state"] in ("stopped", "failed"), "run1 stopped")
        assert s["run_id"] == "run1" and s["recorder"]["closed"]
        assert s["recorder"]["file"].endswith("run1_000.h5")
        assert follower.proc.poll() is None          # the run ended: still following
        [f] = acq.files()
        with RawRunReader(f) as rr:
            events = rr.events()
        trail = [(k, d.split(":")[0]) for _, k, d in events if k.startswith("alarm.")]
        for name in ("pings.stopped", "pings.lost", "worker.behind", "worker.memory_bound",
                     "navigation.no_gps_fix", *dvl):
            assert ("alarm.raised", name) in trail and ("alarm.cleared", name) in trail, (
                name, trail)
            assert trail.index(("alarm.raised", name)) < trail.index(
                ("alarm.cleared", name))
        # the next run, its disk floor above the free space: followed, alarmed
        alarms["disk_min_free_mib"] = 1e9
        tmp2 = tmp_path / "second"
        tmp2.mkdir()
        rig.acquire(dev, "--duration", "60", ephemeral=False, run_id="run2",
                    config=acquire_toml(tmp2, alarms=alarms, **common))
        s = follower.until(lambda s: s["run_id"] == "run2" and alarmed("disk.low")(s),
                           "run2's disk.low")
        assert "MiB free (alarm below 1e+09 MiB)" in [
            a for a in s["alarms"] if a["name"] == "disk.low"][0]["message"]
    finally:
        follower.stop()
