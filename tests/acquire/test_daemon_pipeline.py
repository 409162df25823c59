"""The daemon's ping pipeline on its own (svss_daq/daemon_pipeline.py): what the
digitiser and the sequencer deliver, taken, paired, assembled, recorded in real raw-run
segments and published on a real ZeroMQ stream once flushed, with its bounds; no
devices, no daemon."""

from __future__ import annotations

import math
import queue
import time

import numpy as np
import pytest

from svss_daq import messages
from svss_daq.daemon_nav import NavigationMonitor
from svss_daq.daemon_pipeline import PingPipeline
from svss_daq.daemon_run import RunState
from svss_daq.protocols.digitiser import CompletePing, IncompletePing
from svss_daq.protocols.sequencer import PingEvent
from svss_daq.publisher import PingPublisher
from svss_daq.rawfile import EVENT_KIND_LEN, RawRunReader
from svss_daq.recorder import RunRecorder
from svss_daq.subscriber import subscribe

from .conftest import local_setup

LIMITS = {"pending_pings": 3, "transmit_records": 2, "duplicate_window": 1000,
          "records_waiting": 100}


@pytest.fixture
def parts(tmp_path):
    """A pipeline over a real recorder (flushed every 100 pings or 1.5 s) and a real
    publisher with one subscriber; no navigation links (poses unknown)."""
    setup = local_setup(tmp_path, limits=LIMITS,
                        recorder={"flush_every_pings": 100, "flush_interval_s": 1.5})
    run = RunState("pipe")
    rec = setup.daq.recorder
    run.recorder = RunRecorder(setup.out_dir, run.run_id, setup.hardware,
                               flush_every_pings=rec.flush_every_pings,
                               flush_interval_s=rec.flush_interval_s,
                               max_file_bytes=2**30, max_file_s=600.0, reserve_bytes=0)
    run.publisher = PingPublisher("tcp://127.0.0.1:*", 1000)
    sub = subscribe(run.publisher.endpoint, 1000)
    run.publisher.wait_for_subscribers(1, 10.0)
    pipeline = PingPipeline(setup, run, NavigationMonitor(setup, run))
    yield setup, run, pipeline, sub
    sub.close()
    run.publisher.close(linger_s=0.1)
    if not run.recorder.ended:
        run.recorder.close()


def _ping(hw, i: int, t0: int) -> CompletePing:
    dig = hw.digitiser
    t = t0 + i * 100_000_000
    samples = np.full((dig.n_channels, dig.window_samples), i + 1, np.int32)
    return CompletePing(i, t, t + round(dig.window_start_s * 1e9), samples)


def _received(sub, n: int) -> list:
    out = []
    while len(out) < n and sub.poll(5000):
        out.append(messages.recv(sub))
    return out


def test_pings_are_paired_assembled_recorded_and_published_once_flushed(parts):
    setup, run, pipeline, sub = parts
    hw = setup.hardware.value
    order = hw.sequencer.projector_order
    t0 = time.time_ns()
    for i in (0, 1, 2, 4):                       # ping 3's transmit record is lost
        pipeline.on_transmit(PingEvent(i, order[i % len(order)], t0 + i * 100_000_000))
    q: queue.Queue = queue.Queue()
    for i in range(5):
        q.put(_ping(hw, i, t0))
    q.put(IncompletePing(5, 0, 0, (), "never sent", last_ping_number=7))    # a gap
    q.put(IncompletePing(8, 3, 5, (1, 2), "frames missing"))
    pipeline.take_from(q, 1.0)
    # 0-2 paired at once; 3 waits for its transmit record, 4 behind it
    c = run.counters
    assert c.delivered == 5 and c.never_delivered == 3 and c.incomplete == 1
    assert pipeline.waiting == 2 and run.recorder.n_recorded == 3
    assert c.recorded == c.published == 0           # appended, not yet flushed
    time.sleep(setup.acquire.pairing.transmit_wait_s)
    pipeline.assemble_due(final=False)              # 3 waited long enough
    assert pipeline.waiting == 0 and c.transmit_missing == 1
    pipeline.flush_due()
    assert c.recorded == 0                          # flushed only when a ping waited for it
    time.sleep(setup.daq.recorder.flush_interval_s)
    pipeline.flush_due()
    assert c.recorded == c.published == 5 and run.last_recorded_seq == 4
    pipeline.take(_ping(hw, 1, t0))                 # delivered again
    pipeline.assemble_due(final=True)
    assert c.duplicates == 1 and c.delivered == 6 and run.recorder.n_recorded == 5
    got = _received(sub, 5)
    assert [p.sequence for p in got] == [0, 1, 2, 3, 4]
    # the projector of the ping without its record continues the schedule's phase
    assert [p.projector for p in got] == [order[i % len(order)] for i in range(5)]
    assert all(int(p.samples[0, 0]) == p.sequence + 1 for p in got)
    assert all(math.isnan(p.nav.north_m) for p in got)          # no navigation links
    kinds = [k for _, k, _ in run.events]
    assert kinds == ["digitiser.incomplete_ping", "sequencer.transmit_record_missing",
                     "digitiser.duplicate_ping"]
    assert pipeline.ping_rate() > 0
    run.recorder.close()
    [path] = run.recorder.segments
    with RawRunReader(path) as r:
        table = r.ping_table()
        assert table["ping_sequence"].tolist() == [0, 1, 2, 3, 4]
        assert table["ping_time"].tolist() == [t0 + i * 100_000_000 for i in range(5)]
        assert [k for _, k, _ in r.events()] == [k[:EVENT_KIND_LEN] for k in kinds]


def test_bounds_pose_waiting_pings_and_drop_unclaimed_records(parts):
    setup, run, pipeline, sub = parts
    hw = setup.hardware.value
    order = hw.sequencer.projector_order
    t0 = time.time_ns()
    for i in range(100, 105):                   # records of pings that never come
        pipeline.on_transmit(PingEvent(i, order[0], t0))
    for i in range(5):                          # pings whose records never come
        pipeline.take(_ping(hw, i, t0))
    pipeline.assemble_due(final=False)
    c = run.counters
    # past limits.pending_pings (3) the oldest are posed at once: an event at 1, 10, ...
    assert pipeline.waiting == LIMITS["pending_pings"] and c.pending_full == 2
    assert c.transmit_unclaimed == 5 - LIMITS["transmit_records"]
    assert [k for _, k, _ in run.events].count("daemon.pending_full") == 1
    pipeline.assemble_due(final=True)
    run.recorder.close_files()
    pipeline.publish_recorded()
    pipeline.lose_unrecorded()
    assert c.recorded == c.published == 5 and c.not_recorded == 0
    assert c.transmit_missing == 5


def test_a_ping_lost_with_a_stopped_recording_is_neither_recorded_nor_published(parts):
    setup, run, pipeline, sub = parts
    hw = setup.hardware.value
    order = hw.sequencer.projector_order
    run.recorder.close()
    # every ping flushed at once, and the disk below its floor at the first flush
    run.recorder = RunRecorder(setup.out_dir, "pipe2", setup.hardware, flush_every_pings=1,
                               flush_interval_s=1.0, max_file_bytes=2**30, max_file_s=600.0,
                               reserve_bytes=0)
    run.recorder.min_free = float("inf")        # (checked after each flush)
    t0 = time.time_ns()
    for i in range(2):
        pipeline.on_transmit(PingEvent(i, order[i], t0 + i * 100_000_000))
        pipeline.take(_ping(hw, i, t0))
        pipeline.assemble_due(final=False)
    c = run.counters
    # the first is on disk (recording stopped after its flush), the second lost
    assert c.recorded == c.published == 1 and c.not_recorded == 1
    assert run.state == "failed" and "min_free_mib" in run.failure
    assert [p.sequence for p in _received(sub, 1)] == [0]
