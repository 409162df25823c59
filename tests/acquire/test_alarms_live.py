"""Alarms raised and cleared through real processes: ``svss sim-device`` with a faults
file (the sonar stops delivering pings, a GPS outage, a DVL dropout), ``svss acquire``, a
real ``svss worker`` that falls behind (stopped with SIGSTOP, then let go on: it catches
up), a client of the catch-up service that says it is at its memory bound (a real worker
reaches it only with more tiles than a test's run makes), a disk floor between the free
space with and without a ballast file (the alarm raised, then cleared when the ballast
goes); and ``svss status --follow`` started before any daemon, through one run's end and
the next run's start."""

from __future__ import annotations

import json
import os
import queue
import shutil
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
from .test_worker_linger import fast_processing

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
        self.first: dict[str, dict] = {}   # alarm name: the first status that listed it
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            s = json.loads(line)
            for a in s["alarms"]:
                self.first.setdefault(a["name"], s)
            self.seen |= {a["name"] for a in s["alarms"]}
            self.lines.put(s)

    def until(self, pred, what: str, timeout_s: float = DEADLINE_S) -> dict:
        """The first status (from now) for which ``pred`` holds."""
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            try:
                s = self.lines.get(timeout=0.5)
            except queue.Empty:
                assert self.proc.poll() is None, "svss status --follow exited"
                continue
            if pred(s):
                return s
            last = s
        brief = None if last is None else {
            "state": last.get("state"), "run_id": last.get("run_id"),
            "counters": last.get("counters"), "alarms": [a["name"] for a in last["alarms"]],
            "solution": (last.get("navigation") or {}).get("solution")}
        raise AssertionError(f"svss status --follow: no status with {what} within "
                             f"{timeout_s} s; alarms seen {sorted(self.seen)}; the last "
                             f"status: {brief}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(10)


def alarmed(*names):
    return lambda s: set(names) <= {a["name"] for a in s["alarms"]}


def not_alarmed(*names):
    return lambda s: s["state"] == "recording" and not (
        set(names) & {a["name"] for a in s["alarms"]})


@pytest.mark.slow
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
    started: list[subprocess.Popen] = []
    try:
        faults = tmp_path / "faults.toml"
        faults.write_text(FAULTS)
        # the simulated clock at half the host's (5 pings/s): a real worker stopped
        # and let go on catches up beside two CPU-bound processes too
        dev = rig.device("--faults", str(faults), "--time-scale", "0.5")
        acq = rig.acquire(dev, "--duration", "600", ephemeral=False,
                          config=acquire_toml(tmp_path, alarms=alarms, **common))
        follower.until(lambda s: s["run_id"] == "run1" and s["state"] == "recording",
                       "run1 recording")
        # a real tile worker on the run (small tiles: it keeps up until it is stopped)
        s = follower.until(lambda s: s["counters"]["recorded"] > 0, "a ping recorded")
        with open(tmp_path / "worker.log", "wb") as err:
            real = subprocess.Popen(
                [sys.executable, "-m", "svss", "worker", "--connect",
                 acq.endpoints["publisher"], "--service", acq.endpoints["service"],
                 "--out", str(tmp_path / "tiles"), "--processing",
                 str(fast_processing(tmp_path)), "--runs", "1", "--idle-timeout", "120"],
                stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)
        started.append(real)
        # a client at its memory bound: its progress messages to the daemon's catch-up
        # service, every 0.3 s (it needs no more pings: it is not behind)
        fetcher = PingFetcher(acq.endpoints["service"], timeout_s=10)
        [run] = [r for r in fetcher.runs() if r.run_id == "run1"]
        worker = {"extras": {"open_tiles": 4, "max_open_tiles": 4,
                             "memory_bound_age_s": 0.0}}
        stop = threading.Event()

        def bound_worker():
            while not stop.wait(0.3):
                fetcher.progress("bound-worker", "run1", run.first, True, worker["extras"])

        talker = threading.Thread(target=bound_worker, daemon=True)
        talker.start()
        s = follower.until(alarmed("worker.memory_bound"), "worker.memory_bound")
        assert "bound-worker (4 of 4 tiles open" in [
            a for a in s["alarms"] if a["name"] == "worker.memory_bound"][0]["message"]
        worker.update(extras={"open_tiles": 2, "max_open_tiles": 4,
                              "memory_bound_age_s": 30.0})
        # the faults, raised and cleared in whatever order a loaded machine makes of
        # them (the simulated sonar falls behind its clock under load): the sonar stops
        # (no ping for 5 ping intervals), the GPS outage, the DVL dropout (silent, no
        # bottom lock); each clears when its condition ends
        faults = ("pings.stopped", "navigation.no_gps_fix", "dvl.silent",
                  "navigation.no_bottom_lock")
        follower.until(lambda s: set(faults) <= follower.seen
                       and not_alarmed(*faults, "worker.memory_bound")(s),
                       "the faults' alarms raised and cleared", timeout_s=3 * DEADLINE_S)
        s = follower.first["pings.stopped"]
        assert [a for a in s["alarms"] if a["name"] == "pings.stopped"][0][
            "severity"] == "critical"
        # in the GPS outage, dead reckoning on the DVL carries the position
        s = follower.first["navigation.no_gps_fix"]
        assert s["navigation"]["solution"]["mode"] == "dead_reckoning"
        text = format_status(s)               # what an operator reads: alarms first
        assert text.startswith("ALARMS (") and "navigation.no_gps_fix" in text
        assert "now dead_reckoning" in text, text
        (tmp_path / "status.txt").write_text(text)
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
        # the real worker, once it has told the service where it is in the run,
        # stopped: it falls behind the recording (more than 10 pings more than when it
        # stopped); let go on, it catches up (fetching what its subscription lost) and
        # the alarm clears
        mine = f"-{real.pid}-"

        def backlog(s):
            return max([w["backlog_pings"] for w in s["workers"] if mine in w["client"]
                        and w["backlog_pings"] is not None], default=None)

        s = follower.until(lambda s: backlog(s) is not None, "the worker's progress")
        real.send_signal(signal.SIGSTOP)
        at_stop = backlog(s)
        s = follower.until(lambda s: alarmed("worker.behind")(s)
                           and backlog(s) > at_stop + 10, "worker.behind")
        assert mine in [a for a in s["alarms"] if a["name"] == "worker.behind"][0]["message"]
        real.send_signal(signal.SIGCONT)
        follower.until(not_alarmed("worker.behind"), "worker.behind cleared",
                       timeout_s=2 * DEADLINE_S)
        assert real.poll() is None, (tmp_path / "worker.log").read_text()[-3000:]
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
        for name in ("pings.lost", "worker.behind", "worker.memory_bound", *faults):
            assert ("alarm.raised", name) in trail and ("alarm.cleared", name) in trail, (
                name, trail)
            assert trail.index(("alarm.raised", name)) < trail.index(
                ("alarm.cleared", name))
        # the next run, followed: its disk floor 1 GiB below the free space and a 2 GiB
        # ballast file beside its recording (other processes' files may come and go by
        # less than 1 GiB meanwhile): alarmed, then cleared when the ballast goes
        tmp2 = tmp_path / "second"
        tmp2.mkdir()
        mib = 1 << 20
        floor = shutil.disk_usage(tmp2).free / mib - 1024.0
        alarms["disk_min_free_mib"] = round(floor)
        ballast = tmp2 / "ballast"
        with open(ballast, "wb") as fh:
            os.posix_fallocate(fh.fileno(), 0, 2048 * mib)
        rig.acquire(dev, "--duration", "300", ephemeral=False, run_id="run2",
                    config=acquire_toml(tmp2, alarms=alarms, **common))
        s = follower.until(lambda s: s["run_id"] == "run2" and alarmed("disk.low")(s),
                           "run2's disk.low")
        assert f"MiB free (alarm below {round(floor):g} MiB)" in [
            a for a in s["alarms"] if a["name"] == "disk.low"][0]["message"]
        ballast.unlink()
        s = follower.until(lambda s: s["run_id"] == "run2" and not_alarmed("disk.low")(s),
                           "run2's disk.low cleared")
        assert s["recorder"]["free_mib"] > floor
    finally:
        follower.stop()
        for p in started:
            if p.poll() is None:
                p.send_signal(signal.SIGCONT)
                p.kill()
                p.wait(10)
