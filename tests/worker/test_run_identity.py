"""Pings carry their run's id on the stream and the worker keys runs by it: a stream that
moves on to another run without the first one's end marker (its daemon was killed and
restarted, its ping numbers from 0 again) never puts one run's pings into another's
tiles; the first run is finished from the recording once the service says it ended.
Real loopback sockets and files; the worker in a thread (``serve``)."""

from __future__ import annotations

import json
import shutil
import threading

import pytest
import zmq

from svss_daq import messages
from svss_daq.catchup_stores import RawRunStore, ReplayStore
from svss_daq.ping_service import PingService
from svss_daq.publisher import PingPublisher
from svss_daq.rawfile import RawRunReader
from svss_proc.worker import serve

from .conftest import assert_same_tiles


# a variant: tests/acquire/test_daemon_restart.py::test_killed_daemon_restarted_records_a_
# new_run_and_runs_never_mix makes the same check through the real chain (a run whose
# end marker is lost finished from its recording, the next run's ping numbers from 0
# again, both runs' tiles equal svss process's voxel for voxel)
@pytest.mark.extended
def test_a_run_without_its_end_marker_is_not_mixed_with_the_next(raw_run, processed, hardware,
                                                                small_proc, tmp_path):
    # the same recorded pings as two runs: the same sequence numbers in each
    other = tmp_path / "line2.h5"
    shutil.copyfile(raw_run, other)
    out, result = tmp_path / "w", {}
    ctx = zmq.Context()
    with RawRunStore([raw_run, other]) as store, \
            PingService("tcp://127.0.0.1:*", ReplayStore(store), ctx=ctx) as svc, \
            PingPublisher("tcp://127.0.0.1:*", 1000, ctx=ctx) as pub, \
            RawRunReader(raw_run) as run:

        def work():
            try:
                result["files"] = serve(pub.endpoint, out, hardware, small_proc, 120,
                                        receive_hwm=1000, service=svc.endpoint, runs=2,
                                        gap_wait_s=600.0)
            except BaseException as exc:          # reported below
                result["error"] = exc

        t = threading.Thread(target=work)
        t.start()
        pub.wait_for_subscribers(timeout_s=60)
        pings = list(run)
        svc.store.begin("line1")
        for p in pings[:40]:
            pub.publish(p, run_id="line1")
        svc.store.end("line1")                    # ... and its end marker is lost
        svc.store.begin("line2")
        for p in pings:
            pub.publish(p, run_id="line2")
        svc.store.end("line2")
        pub.publish(messages.RunEnd("line2", len(pings), pings[-1].sequence))
        t.join(timeout=600)
    ctx.term()
    assert not t.is_alive() and "error" not in result, result.get("error")
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] and m["runs"]["line1"]["complete"], m
    assert m["runs"]["line1"]["pings"] == m["runs"]["line2"]["pings"] == 90
    assert m["fetched_pings"] == 50 and m["duplicate_pings"] == 0 and m["skipped_pings"] == 0
    assert_same_tiles(processed, out / "line1")
    assert_same_tiles(processed, out / "line2")
