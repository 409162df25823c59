"""The catch-up service over real raw files and real loopback sockets: found and missing
sequences, capped replies, runs spanning segment files, malformed requests answered and
counted, timeouts naming the endpoint."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import zmq

from svss_daq import messages
from svss_daq.catchup_stores import RawRunStore, ReplayStore
from svss_daq.ping_service import PingFetcher, PingService, ServiceError
from svss_daq.rawfile import RawRunReader

from .conftest import simulate

HOLES = frozenset({3, 4, 9})


@pytest.fixture(scope="module")
def holed(tmp_path_factory):
    """A 12-ping run whose recording lacks sequences 3, 4 and 9."""
    return simulate(tmp_path_factory.mktemp("holed") / "holed.h5", 12, skip=HOLES)


@pytest.fixture(scope="module")
def segmented(tmp_path_factory):
    """One run (id "line-7") recorded in two segment files: pings 0-5 and 6-11."""
    d = tmp_path_factory.mktemp("segments")
    a = simulate(d / "a.h5", 6, run_attrs={"run_id": "line-7", "segment": 0})
    b = simulate(d / "b.h5", 12, run_attrs={"run_id": "line-7", "segment": 1},
                 skip=frozenset(range(6)))
    return [b, a]                            # given out of order on purpose


def test_fetch_found_missing_and_capped(holed):
    with RawRunStore([holed]) as store, \
            PingService("tcp://127.0.0.1:*", store, max_pings_per_reply=4) as svc, \
            PingFetcher(svc.endpoint, timeout_s=10) as f:
        (run,) = f.runs()
        assert (run.run_id, run.first, run.last, run.n_pings, run.ended) == \
            ("holed", 0, 11, 9, True)
        one = f.fetch_once("holed", 0, 11)            # capped at 4 pings
        assert [p.sequence for p in one.pings] == [0, 1, 2, 5]
        assert one.missing == [(3, 4)] and one.next == 6 and not one.pending
        pings, missing = f.fetch("holed", 0, 20)      # loops over capped replies
        assert [p.sequence for p in pings] == [q for q in range(12) if q not in HOLES]
        assert missing == [(3, 4), (9, 9), (12, 20)]   # past the end of an ended run
        with RawRunReader(holed) as r:                # the same pings, bit for bit
            rec = {p.sequence: p for p in r}
        for p in pings:
            np.testing.assert_array_equal(p.samples, rec[p.sequence].samples)
            assert json.dumps(p.nav.to_dict()) == json.dumps(rec[p.sequence].nav.to_dict())
            assert p.transmit_time_ns == rec[p.sequence].transmit_time_ns
        assert f.fetch("holed", 3, 4) == ([], [(3, 4)])
        assert svc.errors == 0 and svc.pings_served == 4 + 9


def test_a_damaged_file_is_left_out_and_the_others_served(holed, segmented, tmp_path):
    """(What a restarted daemon's catch-up service does with the runs recorded before it:
    one unreadable file among them cost it all of them.)"""
    bad = tmp_path / "bad_000.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 4000)
    from svss_daq.rawfile import RawFileError
    with pytest.raises(RawFileError, match="bad_000"):
        RawRunStore([holed, bad])
    with RawRunStore([holed, bad, *segmented], skip_unreadable=True) as store:
        assert [r.run_id for r in store.runs()] == ["holed", "line-7"]


def test_a_run_spanning_segment_files(segmented):
    with RawRunStore(segmented) as store, \
            PingService("tcp://127.0.0.1:*", store) as svc, \
            PingFetcher(svc.endpoint, timeout_s=10) as f:
        (run,) = f.runs()
        assert (run.run_id, run.first, run.last, run.n_pings) == ("line-7", 0, 11, 12)
        pings, missing = f.fetch("line-7", 4, 8)
        assert [p.sequence for p in pings] == [4, 5, 6, 7, 8] and missing == []


def test_replay_store_lists_runs_as_they_are_published(holed, segmented):
    with RawRunStore([holed, *segmented]) as store, \
            PingService("tcp://127.0.0.1:*", ReplayStore(store)) as svc, \
            PingFetcher(svc.endpoint, timeout_s=10) as f:
        replay = svc.store
        assert f.runs() == []
        replay.begin("holed")
        assert [(r.run_id, r.ended) for r in f.runs()] == [("holed", False)]
        replay.end("holed")
        replay.begin("line-7")
        assert [(r.run_id, r.ended) for r in f.runs()] == [("holed", True),
                                                           ("line-7", False)]
        with pytest.raises(ServiceError, match="unknown run 'nope'"):
            f.fetch("nope", 0, 1)


@pytest.mark.parametrize("frames, words", [
    ([b"{not json"], "not UTF-8 JSON"),
    ([b"[1, 2]"], "JSON object"),
    ([b'{"schema": "svss.fetch", "run_id": "holed", "first": -1, "last": 2}'],
     "'first' expected an integer"),
    ([b'{"schema": "svss.fetch", "run_id": "holed", "first": 5, "last": 2}'],
     "first <= last"),
    ([b'{"schema": "svss.fetch", "run_id": 7, "first": 0, "last": 2}'], "'run_id'"),
    ([b'{"schema": "svss.fetch", "run_id": "holed", "first": true, "last": 2}'],
     "'first'"),
    ([b'{"schema": "svss.pickle"}'], "'svss.fetch' or 'svss.runs'"),
    ([b'{"schema": "svss.runs", "version": 2}'], "version"),
    ([b"{}", b"{}"], "2 frames"),
    ([b"x" * 10000], "at most"),
])
def test_malformed_requests_are_answered_counted_and_survived(holed, frames, words):
    with RawRunStore([holed]) as store, \
            PingService("tcp://127.0.0.1:*", store) as svc, zmq.Context() as ctx:
        s = ctx.socket(zmq.DEALER)
        s.connect(svc.endpoint)
        s.send_multipart(frames)
        assert s.poll(10_000)
        reply = json.loads(s.recv())
        s.close(linger=0)
        assert reply["schema"] == "svss.error" and words in reply["error"], reply
        assert svc.errors == 1
        with PingFetcher(svc.endpoint, timeout_s=10) as f:   # still serving
            assert [p.sequence for p in f.fetch("holed", 0, 2)[0]] == [0, 1, 2]


def test_timeout_names_the_endpoint():
    with zmq.Context() as ctx:
        s = ctx.socket(zmq.ROUTER)                # bound, never answers
        port = s.bind_to_random_port("tcp://127.0.0.1")
        endpoint = f"tcp://127.0.0.1:{port}"
        t = time.monotonic()
        with PingFetcher(endpoint, timeout_s=0.3) as f:
            with pytest.raises(TimeoutError, match=endpoint):
                f.runs()
        assert time.monotonic() - t < 5
        s.close(linger=0)


def test_bad_endpoints_are_refused_before_binding(holed):
    with RawRunStore([holed]) as store:
        with pytest.raises(ValueError, match="99999"):
            PingService("tcp://127.0.0.1:99999", store)
    with pytest.raises(ValueError, match="99999"):
        PingFetcher("tcp://127.0.0.1:99999")


def test_fetch_rate_on_loopback(raw_run, capsys):
    """The figure for docs/catchup.md: pings per second one fetcher gets."""
    with RawRunStore([raw_run]) as store, \
            PingService("tcp://127.0.0.1:*", store) as svc, \
            PingFetcher(svc.endpoint, timeout_s=30) as f:
        t = time.perf_counter()
        pings, missing = f.fetch("line1", 0, 89)
        dt = time.perf_counter() - t
    assert len(pings) == 90 and not missing
    rate = 90 / dt
    mb = 90 * pings[0].samples.nbytes / dt / 1e6
    with capsys.disabled():
        print(f"\ncatch-up fetch on loopback: {rate:.0f} pings/s ({mb:.0f} MB/s)")
    assert messages.decode(messages.encode_ping(pings[0])).sequence == 0


WRITER = r"""
import itertools, sys, time
from pathlib import Path
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.rawfile import RawRunWriter
hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
pings = list(itertools.islice(iter(EnvironmentSource(hw, load_scene(
    config_path("scenes/demo.toml")))), 10))
go = Path(sys.argv[2])
with RawRunWriter(sys.argv[1], hw, flush_every_pings=1,
                  run_attrs={"run_id": "live", "segment": 0}) as w:
    for p in pings[:5]:
        w.append(p)
    w.flush()
    print("5", flush=True)
    while not go.exists():
        time.sleep(0.05)
    for p in pings[5:]:
        w.append(p)
    w.flush()
    print("10", flush=True)
    while go.read_text() != "close":
        time.sleep(0.05)
"""


def test_a_run_still_being_written_answers_pending_then_found(tmp_path):
    """A raw file still open for writing (another process, SWMR): the service says which
    pings are not recorded yet (pending, not missing) and serves them once flushed."""
    import subprocess
    import sys
    from .conftest import ROOT
    path, go = tmp_path / "live.h5", tmp_path / "go"
    w = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(go)], cwd=ROOT,
                         stdout=subprocess.PIPE, text=True)
    try:
        assert w.stdout.readline().strip() == "5"
        with RawRunStore([path]) as store, \
                PingService("tcp://127.0.0.1:*", store) as svc, \
                PingFetcher(svc.endpoint, timeout_s=30) as f:
            (run,) = f.runs()
            assert (run.run_id, run.last, run.ended) == ("live", 4, False)
            got = f.fetch_once("live", 3, 8)
            assert [p.sequence for p in got.pings] == [3, 4] and got.missing == []
            assert got.pending and got.next == 5
            go.write_text("more")
            assert w.stdout.readline().strip() == "10"
            deadline = time.monotonic() + 20
            while True:                       # the file's change is seen, then read again
                pings, missing = f.fetch("live", 3, 8)
                if len(pings) == 6 or time.monotonic() > deadline:
                    break
                time.sleep(0.1)
            assert [p.sequence for p in pings] == [3, 4, 5, 6, 7, 8] and missing == []
            assert not f.runs()[0].ended
    finally:
        go.write_text("close")
        w.wait(timeout=30)
    with RawRunStore([path]) as store:
        (run,) = store.runs()
        assert run.ended and run.n_pings == 10


def _until(cond, timeout_s=30.0):
    """Wait for ``cond()`` (the service reads progress messages on its own thread)."""
    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            raise AssertionError("condition not met in time")
        time.sleep(0.02)


def test_a_worker_says_its_imaging_method(holed):
    """A worker's progress message carries its imaging method (docs/live_method.md):
    the service lists it and `svss status` shows it; a word that is not a method is
    refused and counted, the worker's earlier state kept."""
    from svss_daq.status import format_status

    with RawRunStore([holed]) as store, \
            PingService("tcp://127.0.0.1:*", store) as svc, \
            PingFetcher(svc.endpoint, timeout_s=10) as f:
        f.runs()                                       # learns that it takes progress
        assert f.progress("w1", "holed", 5, False, {"open_tiles": 1,
                                                    "imaging_method": "factorised"})
        _until(lambda: svc.workers())
        [w] = svc.workers()
        assert w["imaging_method"] == "factorised" and w["open_tiles"] == 1
        assert f.progress("w1", "holed", 6, False, {"imaging_method": "fastest"})
        _until(lambda: svc.progress_refused == 1)
        [w] = svc.workers()
        assert w["next"] == 5 and w["imaging_method"] == "factorised"
        text = format_status({"workers": [dict(w, backlog_pings=0, backlog_s=0.0)]})
        assert "imaging factorised" in text
