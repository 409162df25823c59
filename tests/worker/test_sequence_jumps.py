"""Sequence numbers from the wire never set how much work the tile worker does: a ping
implausibly far ahead of its run is refused and counted (not taken as the run's new
frontier), and a range the recording lacks is skipped in one step with one log line,
however long. Real loopback sockets (publisher, catch-up service), real raw files, the
real worker (`serve`) in a thread; its tiles must equal `svss process`'s of the same
recording."""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time

import pytest
import zmq

from svss_daq import messages
from svss_daq.catchup_stores import RawRunStore, ReplayStore
from svss_daq.ping_service import PingService
from svss_daq.publisher import PingPublisher
from svss_daq.rawfile import RawRunWriter
from svss_proc.run_folder import MANIFEST
from svss_proc.run_worker import process_raw
from svss_proc.worker import serve

from .conftest import N_SHORT, assert_same_tiles

N = N_SHORT
RUN = "line1"                    # the run of `run30`
HOLE = 10**6                     # sequences the recording of `holed` lacks after ping 14


class _Lines(logging.Handler):
    """Counts the worker's log records and keeps the first few (a test that fails may
    see a million)."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.n = 0
        self.kept: list[str] = []

    def emit(self, record):
        self.n += 1
        if len(self.kept) < 200:
            self.kept.append(record.getMessage())

    def seen(self, *words: str) -> bool:
        return any(w in m for m in list(self.kept) for w in words)


@pytest.fixture
def lines():
    h = _Lines()
    # the stream worker's records and those of the run worker it feeds
    loggers = [logging.getLogger(n) for n in ("svss_proc.worker", "svss_proc.run_worker")]
    for logger in loggers:
        logger.addHandler(h)
    yield h
    for logger in loggers:
        logger.removeHandler(h)


def _write(path, hardware, pings, run_id):
    with RawRunWriter(path, hardware, run_attrs={"run_id": run_id, "segment": 0}) as w:
        for p in pings:
            w.append(p)
    return path


@pytest.fixture(scope="module")
def first30(first_pings):
    return first_pings


@pytest.fixture(scope="module")
def run30(short_run, short_processed):
    """The raw run's first 30 pings as run RUN, and its `svss process` tiles."""
    return short_run, short_processed


@pytest.fixture(scope="module")
def holed(hardware, first30, small_proc, tmp_path_factory):
    """Run "holed": the same 30 pings, numbered 0..14 then HOLE+15..HOLE+29 (a digitiser
    whose numbering jumped a million: none of those sequences was ever recorded)."""
    d = tmp_path_factory.mktemp("holed")
    pings = [p if p.sequence < 15 else dataclasses.replace(p, sequence=p.sequence + HOLE)
             for p in first30]
    path = _write(d / "holed.h5", hardware, pings, "holed")
    process_raw(path, d / "ref", small_proc)
    return path, d / "ref", pings


def hostile(ping, sequence):
    """A copy of ``ping`` 50 ms later (a valid ping for the gate) numbered ``sequence``."""
    t = ping.transmit_time_ns + 50_000_000
    return dataclasses.replace(ping, sequence=sequence, transmit_time_ns=t,
                               nav=dataclasses.replace(ping.nav, time_ns=t))


def _wait_for(pred, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


class _Chain:
    """A catch-up service over ``path`` (as a replay presents it), a publisher and the
    worker in a thread."""

    def __init__(self, path, out, hardware, processing):
        self.ctx = zmq.Context()
        self.store = RawRunStore([path])
        self.replay = ReplayStore(self.store)
        self.svc = PingService("tcp://127.0.0.1:*", self.replay, ctx=self.ctx)
        self.pub = PingPublisher("tcp://127.0.0.1:*", 1000, ctx=self.ctx)
        self.result: dict = {}

        def target():
            try:
                self.result["files"] = serve(
                    self.pub.endpoint, out, hardware, processing, 120, receive_hwm=1000,
                    service=self.svc.endpoint, runs=1, gap_wait_s=0.3)
            except BaseException as exc:              # reported by the test
                self.result["error"] = exc
        self.thread = threading.Thread(target=target)
        self.thread.start()
        self.pub.wait_for_subscribers(timeout_s=60)

    def finish(self, run_id, n):
        self.replay.end(run_id)
        self.pub.publish(messages.RunEnd(run_id, n))
        self.thread.join(timeout=300)

    def close(self):
        self.pub.close()
        self.svc.close()
        self.store.close()
        self.ctx.term()
        assert not self.thread.is_alive() and "error" not in self.result, \
            self.result.get("error")


def test_a_ping_1e10_ahead_is_refused_not_the_new_frontier(run30, first30, hardware,
                                                          small_proc, tmp_path, lines):
    """Issue 27 item 4: a ping 1e10 ahead mid-run and a pause. It was taken as the run's
    frontier: the worker skipped to it (the fetch of 1e10 sequences refused), dropped
    the 15 real pings after it as duplicates and wrote complete with 16 of 30 pings,
    skipped_pings 9,999,999,985."""
    path, ref = run30
    out = tmp_path / "w"
    chain = _Chain(path, out, hardware, small_proc)
    try:
        chain.replay.begin(RUN)
        for p in first30[:15]:
            chain.pub.publish(p)
        chain.pub.publish(hostile(first30[14], 10**10))
        # the pause: until the worker has judged the hostile ping (refused it, or
        # skipped to it after gap_wait_s)
        _wait_for(lambda: lines.seen("refused", "skipped"), 60, "the hostile ping judged")
        for p in first30[15:]:
            chain.pub.publish(p)
        chain.finish(RUN, N)
    finally:
        chain.close()
    m = json.loads((out / MANIFEST).read_text())
    assert m["complete"] and m["pings"] == N, m
    assert m["skipped_pings"] == 0 and m["duplicate_pings"] == 0
    assert m["implausible_sequences"] == 1
    assert_same_tiles(ref, out / RUN)


def test_a_hostile_ping_after_the_run_ended_costs_one_line(run30, first30, hardware,
                                                          small_proc, tmp_path, lines):
    """Issue 27 item 3: a ping 1e6 ahead after the run's last ping was recorded (the
    recording ended at 29). The worker asked the service for the million sequences
    before it, expanded the answer into a million integers, logged each one (92 MB)
    and imaged the hostile ping."""
    path, ref = run30
    out = tmp_path / "w"
    chain = _Chain(path, out, hardware, small_proc)
    t0 = time.monotonic()
    try:
        chain.replay.begin(RUN)
        for p in first30:
            chain.pub.publish(p)
        chain.replay.end(RUN)
        chain.pub.publish(hostile(first30[-1], N - 1 + HOLE))
        chain.finish(RUN, N)
    finally:
        chain.close()
    assert lines.n < 200, (lines.n, lines.kept[-5:])
    m = json.loads((out / MANIFEST).read_text())
    assert m["complete"] and m["pings"] == N, m
    assert m["missing_in_recording"] == 0 and m["skipped_pings"] == 0
    assert m["implausible_sequences"] == 1
    assert any(f"ping {N - 1 + HOLE} refused" in k for k in lines.kept)
    assert_same_tiles(ref, out / RUN)
    assert time.monotonic() - t0 < 120


def test_a_million_sequences_missing_from_the_recording_skip_in_one_step(
        holed, hardware, small_proc, tmp_path, lines):
    """A recording whose numbering jumps a million (every ping of it real): the pings
    past the jump are far ahead of the run's expected sequence, but the recording holds
    them, so they are imaged; the million sequences it lacks are one range, skipped at
    once with one line (they were expanded into a million integers, a million lines)."""
    path, ref, pings = holed
    out = tmp_path / "w"
    chain = _Chain(path, out, hardware, small_proc)
    t0 = time.monotonic()
    try:
        chain.replay.begin("holed")
        for p in pings:
            chain.pub.publish(p)
        chain.finish("holed", N)
    finally:
        chain.close()
    assert lines.n < 200, (lines.n, lines.kept[-5:])
    m = json.loads((out / MANIFEST).read_text())
    assert m["complete"] and m["pings"] == N, m
    assert m["missing_in_recording"] == HOLE and m["skipped_pings"] == 0
    assert m["implausible_sequences"] == 0
    assert sum("not in the recording" in k for k in lines.kept) == 1
    assert_same_tiles(ref, out / "holed")
    assert time.monotonic() - t0 < 120
