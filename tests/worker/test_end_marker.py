"""A run's end marker is believed only once the catch-up service says the run has
ended: an end marker put on the stream mid-run (spoofed, or astray) is refused, counted
and logged, and the run goes on to its real end with every ping imaged. The worker is a
real ``svss worker`` process; the stream and the service are this test's, on loopback,
serving a simulated raw run as it is published."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time

import pytest
import zmq

from svss_daq import messages
from svss_daq.catchup_stores import RawRunStore, ReplayStore
from svss_daq.ping_service import PingService
from svss_daq.publisher import PingPublisher
from svss_daq.rawfile import RawRunReader

from .conftest import N_SHORT, ROOT, assert_same_tiles

DEADLINE_S = 240.0


def wait_for(pred, what: str, timeout_s: float = DEADLINE_S):
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.05)


@contextlib.contextmanager
def streamed_worker(short_run, small_proc_path, tmp_path):
    """A real ``svss worker --runs 1`` on this test's stream and catch-up service (on
    loopback) serving ``short_run`` as it is published: yields (publisher, service,
    the run's pings, the worker process, its log file, its output folder); the worker
    is killed if it has not exited by the end."""
    out, log = tmp_path / "w", tmp_path / "worker.log"
    ctx = zmq.Context()
    with RawRunStore([short_run]) as store, \
            PingService("tcp://127.0.0.1:*", ReplayStore(store), ctx=ctx) as svc, \
            PingPublisher("tcp://127.0.0.1:*", 1000, ctx=ctx) as pub, \
            RawRunReader(short_run) as run, open(log, "wb") as err:
        worker = subprocess.Popen(
            [sys.executable, "-m", "svss", "worker", "--connect", pub.endpoint,
             "--service", svc.endpoint, "--out", str(out), "--processing",
             str(small_proc_path), "--runs", "1", "--idle-timeout", "120"],
            stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)
        try:
            pub.wait_for_subscribers(timeout_s=60)
            svc.store.begin("line1")
            yield pub, svc, list(run), worker, log, out
        finally:
            if worker.poll() is None:
                worker.kill()
    ctx.term()


@pytest.mark.slow
def test_end_marker_mid_run_is_refused_and_the_run_goes_on(short_run, short_processed,
                                                           small_proc_path, tmp_path):
    with streamed_worker(short_run, small_proc_path, tmp_path) as (pub, svc, pings,
                                                                   worker, log, out):
        for p in pings[:15]:
            pub.publish(p)
        # mid-run, while the recording goes on: an end marker counting 15 pings
        pub.publish(messages.RunEnd("line1", 15))
        wait_for(lambda: worker.poll() is not None
                 or "end marker of run line1 (15 pings) refused" in log.read_text(),
                 "the worker to take the end marker")
        for p in pings[15:]:
            pub.publish(p)
        svc.store.end("line1")
        pub.publish(messages.RunEnd("line1", len(pings)))
        assert worker.wait(DEADLINE_S) == 0, log.read_text()[-3000:]
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] and m["pings"] == len(pings) == N_SHORT, m
    assert m["end_markers_refused"] == 1, m
    assert m["runs"]["line1"]["complete"] and m["skipped_pings"] == 0
    assert_same_tiles(short_processed, out / "line1")
