"""The daemon's status reporter on its own (svss_daq/daemon_status.py): the disk's
fill rate and time left, and the status snapshot of a run composed from its real parts
(pipeline, navigation, devices not opened, a real recording), its alarms raised and
cleared as run events, published on a real status stream; no devices, no daemon."""

from __future__ import annotations

import time

import numpy as np
import pytest

from svss_daq.daemon_devices import DeviceSupervisor
from svss_daq.daemon_nav import NavigationMonitor
from svss_daq.daemon_pipeline import PingPipeline
from svss_daq.daemon_run import RunState
from svss_daq.daemon_status import DiskWatch, StatusReporter
from svss_daq.protocols.digitiser import CompletePing
from svss_daq.protocols.sequencer import PingEvent
from svss_daq.publisher import PingPublisher
from svss_daq.recorder import RunRecorder
from svss_daq.status import StatusPublisher, StatusSubscriber, format_status

from .conftest import local_setup


def test_the_disk_fill_rate_and_the_time_left():
    disk = DiskWatch(window_s=5.0, min_free_mib=100.0)
    assert disk.rate(10.0, float("nan")) == {"fill_mib_s": None, "time_left_s": None}
    assert disk.rate(10.0, 1000.0) == {"fill_mib_s": None, "time_left_s": None}
    assert disk.rate(11.0, 998.0) == {"fill_mib_s": 2.0, "time_left_s": 449.0}
    # over the window only: the fill of 10 s ago is forgotten
    assert disk.rate(20.0, 990.0)["fill_mib_s"] == pytest.approx(8.0 / 9.0, abs=1e-4)
    assert disk.rate(30.0, 990.0) == {"fill_mib_s": 0.0, "time_left_s": None}
    # below the floor: no time left
    disk = DiskWatch(window_s=5.0, min_free_mib=100.0)
    disk.rate(0.0, 60.0)
    assert disk.rate(1.0, 50.0) == {"fill_mib_s": 10.0, "time_left_s": 0.0}


@pytest.fixture
def reporter(tmp_path):
    setup = local_setup(tmp_path, status={"interval_s": 60.0},
                        alarms={"no_ping_intervals": 15.0})
    run = RunState("status")
    run.recorder = RunRecorder(setup.out_dir, run.run_id, setup.hardware,
                               flush_every_pings=1, flush_interval_s=1.0,
                               max_file_bytes=2**30, max_file_s=600.0, reserve_bytes=0)
    nav = NavigationMonitor(setup, run)
    pipeline = PingPipeline(setup, run, nav)
    rep = StatusReporter(setup, run, pipeline, DeviceSupervisor(setup, run, nav), nav)
    run.publisher = PingPublisher("tcp://127.0.0.1:*", 10)
    rep.publisher = StatusPublisher("tcp://127.0.0.1:*")
    sub = StatusSubscriber(rep.publisher.endpoint)
    yield setup, run, pipeline, rep, sub
    sub.close()
    rep.publisher.close()
    run.publisher.close(linger_s=0.1)
    run.recorder.close()


def _received(rep: StatusReporter, sub) -> dict:
    """The next status on the stream (forced out until the subscription has joined)."""
    for _ in range(50):
        s = sub.next(0.1)
        if s is not None:
            return s
        rep.publish(force=True)
    raise AssertionError("no status message")


def test_the_snapshot_of_a_run_its_alarms_and_the_stream(reporter):
    setup, run, pipeline, rep, sub = reporter
    s = rep.status()
    assert s["run_id"] == "status" and s["state"] == "starting"
    assert s["recording_s"] is None and s["first_ping_due_s"] is None
    assert s["last_ping_age_s"] is None and s["last_sequence"] is None
    assert s["devices"] == {} and s["workers"] == [] and s["subscribers"] == 0
    assert s["endpoints"] == {} and s["events"] == [] and s["failure"] is None
    assert s["navigation"]["mode"] == "none" and s["counters"]["delivered"] == 0
    assert s["recorder"]["recorded"] == 0 and s["recorder"]["free_mib"] > 0
    assert s["schedule_rate_hz"] == pytest.approx(1 / s["ping_interval_s"], abs=1e-3)
    # recording, and no ping in 15 ping intervals: pings.stopped
    run.recording(first_ping_s=0.0)
    interval = setup.hardware.value.sequencer.ping_interval_s
    time.sleep(16 * interval)
    first = _received(rep, sub)
    keys = list(first)                          # its alarms first
    assert keys.index("alarms") < keys.index("time_utc") and first["state"] == "recording"
    assert [a["name"] for a in first["alarms"]] == ["pings.stopped"]
    assert first["last_ping_age_s"] > 15 * interval
    assert [k for _, k, _ in run.events] == ["alarm.raised"]
    assert "pings.stopped" in run.events[-1][2]
    assert "ALARMS (1)" in format_status(first)
    # not due again for status.interval_s (60 s): nothing more on the stream
    rep.publish()
    assert sub.next(0.2) is None
    # a ping recorded: the condition is gone; at the run's end the alarm clears at once
    dig = setup.hardware.value.digitiser
    t = time.time_ns()
    samples = np.zeros((dig.n_channels, dig.window_samples), np.int32)
    pipeline.on_transmit(PingEvent(0, setup.hardware.value.sequencer.projector_order[0], t))
    pipeline.take(CompletePing(0, t, t + round(dig.window_start_s * 1e9), samples))
    pipeline.assemble_due(final=True)
    assert run.counters.recorded == 1
    rep.publish(force=True, settle=True)
    last = _received(rep, sub)
    assert last["alarms"] == [] and last["counters"]["recorded"] == 1
    assert last["last_sequence"] == 0 and last["last_ping_age_s"] < 15 * interval
    assert last["recorder"]["file"].endswith("status_000.h5")
    assert [k for _, k, _ in run.events] == ["alarm.raised", "alarm.cleared"]
    # the count includes what this status's alarms said (listed from the next one)
    assert last["n_events"] == 2 and [e["kind"] for e in last["events"]] == ["alarm.raised"]
