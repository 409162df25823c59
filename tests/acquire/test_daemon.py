"""The acquisition daemon against the simulated device, as on the boat: ``svss
sim-device`` and ``svss acquire`` are real processes, the drivers talk over real
pseudo-terminals and loopback TCP, pings go to real HDF5 files and real ZeroMQ sockets."""

from __future__ import annotations

import ast
import json
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zmq

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from sim_device.track import parse_utc_ns, pose_at
from svss_daq import messages
from svss_daq.ping import NAV_GPS_FIX
from svss_daq.rawfile import RawRunReader
from svss_daq.status import read_status
from svss_daq.subscriber import subscribe

from .conftest import CONFIG, DEMO, ROOT, acquire_toml, limit_file_size

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")


class Collector(threading.Thread):
    """A ping subscriber in a thread: every sequence it received and the run end."""

    def __init__(self, endpoint: str, hwm: int = 1000, read: bool = True):
        super().__init__(daemon=True)
        self.sock = subscribe(endpoint, hwm, zmq.Context.instance())
        self.read, self.seqs, self.end = read, [], None
        self.stop_flag = threading.Event()

    def run(self):
        while not self.stop_flag.is_set() and self.end is None:
            if not self.read:
                time.sleep(0.05)
                continue
            if self.sock.poll(100):
                msg = messages.recv(self.sock)
                if isinstance(msg, messages.RunEnd):
                    self.end = msg
                else:
                    self.seqs.append(msg.sequence)

    def close(self):
        self.stop_flag.set()
        self.join(5)
        self.sock.close(linger=0)


def device_stats(dev) -> dict:
    """The simulated device's closing statistics (its last log line)."""
    assert dev.stop() == 130
    line = [x for x in dev.logs().splitlines() if "simulated device stopped:" in x][-1]
    return ast.literal_eval(line.split("simulated device stopped: ", 1)[1])


def recorded(files) -> tuple[list, dict]:
    pings, summary = [], None
    for f in files:
        with RawRunReader(f) as run:
            pings += list(run)
            summary = run.summary
    return pings, summary


@pytest.mark.slow
def test_twice_the_ping_rate_every_ping_recorded_and_counts_reconcile(rig, hardware):
    dev = rig.device("--time-scale", "2")
    acq = rig.acquire(dev, "--pings", "60", "--wait-subscribers", "1")
    sub = Collector(acq.endpoints["publisher"])
    sub.start()
    status = read_status(acq.endpoints["status"], timeout_s=20)
    assert status["run_id"] == "run1" and status["state"] in ("starting", "recording")
    # svss status, a real client process, reads the same stream
    out = subprocess.run([sys.executable, "-m", "svss", "status", "--connect",
                          acq.endpoints["status"], "--json", "--timeout", "20"],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["devices"]["digitiser"]["connected"] is True
    assert acq.wait(180) == 0, acq.logs()[-3000:]
    sub.join(20)
    sub.close()
    stats = device_stats(dev)
    pings, summary = recorded(acq.files())
    c = summary["counters"]
    seqs = [p.sequence for p in pings]
    # device -> daemon -> file -> subscriber
    assert stats["pings_sent"] == c["delivered"] == c["recorded"] == len(pings) >= 60
    assert sorted(sub.seqs) == seqs and sub.end.n_pings == len(pings)
    assert seqs == sorted(set(seqs)) and c["publish_dropped"] == 0
    assert c["transmit_missing"] == 0 and c["incomplete"] == 0
    # the physics, bit for bit, and the navigation near the truth
    scene = load_scene(DEMO)
    src = EnvironmentSource(hardware, scene)
    t0 = parse_utc_ns(scene.track.start_time_utc)
    interval = round(hardware.value.sequencer.ping_interval_s * 1e9)
    for p in pings[:: max(1, len(pings) // 6)]:
        k = (p.transmit_time_ns - t0) // interval
        truth = src.ping(k)
        assert np.array_equal(p.samples, truth.samples) and p.projector == truth.projector
        true_pose = pose_at(scene.track, (p.transmit_time_ns - t0) * 1e-9, scene.scene.seed)
        assert p.nav.quality & NAV_GPS_FIX
        err = np.hypot(p.nav.north_m - true_pose.north_m, p.nav.east_m - true_pose.east_m)
        assert err < 1.5, (k, err)


@pytest.mark.slow
def test_slow_subscriber_never_slows_acquisition(rig, tmp_path):
    daq = tmp_path / "daq.toml"
    text = (CONFIG / "daq.toml").read_text()
    daq.write_text(text.replace("send_hwm = 500", "send_hwm = 4")
                   # its end marker is not waited for 10 s: the subscriber never reads
                   .replace("end_timeout_s = 10.0", "end_timeout_s = 1.0"))
    assert "end_timeout_s = 10.0" in text
    cfg = acquire_toml(tmp_path, run={"daq": str(daq)})
    dev = rig.device("--time-scale", "2")
    acq = rig.acquire(dev, "--pings", "60", config=cfg)
    ctx = zmq.Context.instance()
    slow = ctx.socket(zmq.SUB)                       # connected, subscribed, never reads
    slow.setsockopt(zmq.RCVHWM, 1)
    slow.setsockopt(zmq.RCVBUF, 4096)
    slow.connect(acq.endpoints["publisher"])
    slow.setsockopt(zmq.SUBSCRIBE, b"")
    try:
        assert acq.wait(180) == 0, acq.logs()[-3000:]
    finally:
        slow.close(linger=0)
    stats = device_stats(dev)
    pings, summary = recorded(acq.files())
    c = summary["counters"]
    # every ping the device sent was recorded (the device may drop a late ping of its
    # own on a loaded machine: it then sends nothing for it)
    assert stats["pings_sent"] == c["delivered"] == len(pings) >= 60
    assert c["publish_dropped"] > 0 and c["published"] + c["publish_dropped"] == len(pings)
    assert "dropped" in acq.logs()
    assert "stayed full for 1.0 s" in acq.logs()      # daq.toml's end_timeout_s


@pytest.mark.slow
def test_sigkill_leaves_the_recording_readable_to_its_last_flush(rig):
    dev = rig.device()
    acq = rig.acquire(dev, "--duration", "120")
    deadline = time.monotonic() + 60
    flushed = 0
    while flushed < 25 and time.monotonic() < deadline:
        flushed = read_status(acq.endpoints["status"], timeout_s=10)["recorder"]["flushed"]
    acq.proc.send_signal(signal.SIGKILL)
    acq.proc.wait(10)
    [f] = acq.files()
    with RawRunReader(f) as run:
        assert not run.clean and len(run) >= flushed >= 25
        pings = list(run)
    seqs = [p.sequence for p in pings]
    assert seqs == sorted(seqs) and all(p.samples.any() for p in pings)
    assert run.summary is None                   # killed: no closing summary


@pytest.mark.slow
def test_full_disk_stops_recording_cleanly(rig):
    dev = rig.device()
    limit = 8 * 2**20                            # ~16 pings of 480 kB
    acq = rig.acquire(dev, "--pings", "200", preexec_fn=limit_file_size(limit))
    rc = acq.wait(120)
    logs = acq.logs()
    [f] = acq.files()
    assert rc == 3, logs[-3000:]
    assert str(f) in logs and "failed" in logs and "pings are safely on disk" in logs
    with RawRunReader(f) as run:
        n = len(run)
        assert 5 <= n <= 20
        pings = list(run)
    assert [p.sequence for p in pings] == sorted({p.sequence for p in pings})
    assert all(p.samples.any() for p in pings)


@pytest.mark.slow
def test_two_survey_lines_on_one_device(rig):
    """The daemon restarted for the next line (same device, same folder): both runs are
    recorded whole, each in its own files."""
    dev = rig.device("--time-scale", "2")
    first = rig.acquire(dev, "--pings", "20", run_id="lineA")
    assert first.wait(120) == 0, first.logs()[-3000:]
    second = rig.acquire(dev, "--pings", "20", run_id="lineB")
    assert second.wait(120) == 0, second.logs()[-3000:]
    for acq in (first, second):
        pings, summary = recorded(acq.files())
        assert len(pings) == summary["counters"]["recorded"] >= 20
        assert [p.sequence for p in pings] == sorted({p.sequence for p in pings})
    t_a = recorded(first.files())[0][-1].transmit_time_ns
    t_b = recorded(second.files())[0][0].transmit_time_ns
    assert t_b > t_a                             # the second line came after the first
