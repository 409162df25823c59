"""The tile worker on the reliable path: real processes, real loopback sockets, real
files. Its tiles must equal `svss process`'s of the same raw run, voxel for voxel, when
the stream drops pings (fetched from the recording), when the worker is SIGKILLed mid-run
and restarted, and across two runs."""

from __future__ import annotations

import json
import shutil
import signal
import threading
import time

import pytest
import zmq

from svss_daq import messages
from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.catchup_stores import RawRunStore, ReplayStore
from svss_daq.ping_service import PingService
from svss_daq.publisher import PingPublisher
from svss_daq.rawfile import RawRunReader
from svss_proc.run_folder import JOURNAL, MANIFEST
from svss_proc.worker import serve

from .conftest import N_SHORT, assert_same_tiles, svss, write_pings

DROPPED = {0, 1, 5, 6, 7, 20} | set(range(44, 52)) | {89}


@pytest.fixture(scope="module")
def hw():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


def _serve_in_thread(result, *args, **kw):
    def target():
        try:
            result["files"] = serve(*args, **kw)
        except BaseException as exc:          # reported by the test
            result["error"] = exc
    t = threading.Thread(target=target)
    t.start()
    return t


@pytest.mark.slow
def test_dropped_pings_are_fetched_from_the_recording(raw_run, processed, hw, small_proc,
                                                      tmp_path):
    out = tmp_path / "w"
    result = {}
    ctx = zmq.Context()
    with RawRunStore([raw_run]) as store, \
            PingService("tcp://127.0.0.1:*", ReplayStore(store), ctx=ctx) as svc, \
            PingPublisher("tcp://127.0.0.1:*", 1000, ctx=ctx) as pub, \
            RawRunReader(raw_run) as run:
        t = _serve_in_thread(result, pub.endpoint, out, hw, small_proc, 60,
                             receive_hwm=1000, service=svc.endpoint, runs=1,
                             gap_wait_s=600.0)
        pub.wait_for_subscribers(timeout_s=60)
        svc.store.begin("line1")
        for p in run:
            if p.sequence not in DROPPED:
                pub.publish(p)
            if p.sequence == 30:
                pub.publish(p)                       # a duplicate
        svc.store.end("line1")
        pub.publish(messages.RunEnd("line1", len(run)))
        t.join(timeout=300)
    ctx.term()
    assert not t.is_alive() and "error" not in result, result.get("error")
    assert_same_tiles(processed, out / "line1")
    m = json.loads((out / MANIFEST).read_text())
    assert m["complete"] and m["fetched_pings"] == len(DROPPED)
    assert m["duplicate_pings"] == 1 and m["skipped_pings"] == 0
    assert m["missing_in_recording"] == 0 and m["pings"] == 90
    assert m["files"] and all(f.startswith("line1/") for f in m["files"])
    j = json.loads((out / "line1" / JOURNAL).read_text())
    assert j["complete"] and j["run_id"] == "line1"


def test_without_a_service_gaps_are_skipped_after_a_bounded_wait(short_run, hw, small_proc,
                                                                 tmp_path):
    out = tmp_path / "w"
    result = {}
    ctx = zmq.Context()
    with PingPublisher("tcp://127.0.0.1:*", 1000, ctx=ctx) as pub, \
            RawRunReader(short_run) as run:
        t = _serve_in_thread(result, pub.endpoint, out, hw, small_proc, 60,
                             receive_hwm=1000, runs=1, gap_wait_s=0.3)
        pub.wait_for_subscribers(timeout_s=60)
        for p in run:
            if p.sequence not in {5, 6, 7, 20}:
                pub.publish(p)
            if p.sequence == 25:
                time.sleep(1.0)                   # the gap at 20 waits, then is skipped
        pub.publish(messages.RunEnd("line1", len(run)))
        t.join(timeout=300)
    ctx.term()
    assert not t.is_alive() and "error" not in result, result.get("error")
    m = json.loads((out / MANIFEST).read_text())
    # pings skipped: the run is not complete, and its manifest says which
    assert m["skipped_pings"] == 4 and m["pings"] == N_SHORT - 4 and not m["complete"]
    assert m["runs"]["line1"]["skipped"] == [[5, 7], [20, 20]]
    assert not m["runs"]["line1"]["complete"] and m["runs"]["line1"]["incomplete"]
    # the folder is named by the run's end marker
    assert json.loads((out / "line1" / MANIFEST).read_text())["run_id"] == "line1"
    assert not json.loads((out / "line1" / JOURNAL).read_text())["complete"]


def _wait_for(pred, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def _journal_written(folder) -> bool:
    try:
        return bool(json.loads((folder / JOURNAL).read_text()).get("written"))
    except (OSError, ValueError):
        return False


def _replay(*runs, realtime=True, linger=120):
    proc = svss("replay", *map(str, runs), "--endpoint", "tcp://127.0.0.1:*", "--service",
                "tcp://127.0.0.1:*", "--linger", str(linger), "--wait", "120",
                *(["--realtime"] if realtime else []))
    pub = proc.stdout.readline().split(" on ")[-1].strip()
    service = proc.stdout.readline().split(" on ")[-1].strip()
    assert pub.startswith("tcp://") and service.startswith("tcp://"), (pub, service)
    return proc, pub, service


def _stop(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except Exception:
            proc.kill()
            proc.wait()


# extended: tests/acquire/test_chain.py's SIGKILL mid-run resume makes the check through the
# real daemon in the default run
@pytest.mark.extended
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_stopped_worker_resumes_with_every_tile_once(sig, raw_run, processed,
                                                     small_proc_path, tmp_path):
    """SIGKILL: the tiles written stay, the open ones are imaged again from the resume
    point. SIGTERM: the open tiles are written (marked in the journal as written only
    because of the stop) and redone on resume."""
    out = tmp_path / "w"
    replay, pub, service = _replay(raw_run)
    worker_args = ("worker", "--connect", pub, "--service", service, "--out", str(out),
                   "--processing", str(small_proc_path), "--runs", "1",
                   "--idle-timeout", "120")
    try:
        w1 = svss(*worker_args)
        try:
            # the journal is updated just after a tile's rename: wait for both, so
            # that the stop falls after a tile the journal knows (a stop between the
            # two is the resume of test_chain's SIGKILL at any moment)
            _wait_for(lambda: _journal_written(out / "line1"), 120, "the first tile")
            w1.send_signal(sig)
            w1.wait(timeout=30)
        finally:
            if w1.poll() is None:
                w1.kill()
        assert w1.returncode == (-signal.SIGKILL if sig == signal.SIGKILL else 130)
        journal = json.loads((out / "line1" / JOURNAL).read_text())
        assert not journal["complete"] and journal["written"]
        first = [f"tile_{k:04d}.h5" for k in journal["written"]]
        if sig == signal.SIGTERM:
            assert json.loads((out / MANIFEST).read_text())["complete"] is False
        # debris of a killed writer: a temporary tile file
        (out / "line1" / ".tile_0007.partial-deadbeef.h5").write_bytes(b"half")
        w2 = svss(*worker_args)
        try:
            rc = w2.wait(timeout=240)
        finally:
            if w2.poll() is None:
                w2.kill()
        err = w2.stderr.read()
        assert rc == 0, err[-3000:]
        assert "resuming run line1" in err
    finally:
        _stop(replay)
    assert_same_tiles(processed, out / "line1")
    assert set(first) <= {p.name for p in (out / "line1").glob("tile_*.h5")}
    m = json.loads((out / "line1" / MANIFEST).read_text())
    assert m["complete"] and m["resumed"] == 1
    assert sorted(f for f in m["files"] if f.endswith(".h5")) == \
        sorted(p.name for p in processed.glob("tile_*.h5"))
    assert json.loads((out / "line1" / JOURNAL).read_text())["complete"]


def test_worker_stays_up_across_two_runs(short_run, short_processed, hw, small_proc,
                                        tmp_path):
    # two short runs (3 m each): staying up from one run to the next is the point
    second = tmp_path / "line2.h5"
    shutil.copyfile(short_run, second)
    out = tmp_path / "w"
    replay, pub, service = _replay(short_run, second, realtime=False)
    result = {}
    try:
        t = _serve_in_thread(result, pub, out, hw, small_proc, 120, receive_hwm=1000,
                             service=service, runs=2)
        t.join(timeout=300)
    finally:
        _stop(replay)
    assert not t.is_alive() and "error" not in result, result.get("error")
    for run in ("line1", "line2"):
        assert_same_tiles(short_processed, out / run)
    m = json.loads((out / MANIFEST).read_text())
    assert m["complete"] and set(m["runs"]) == {"line1", "line2"}
    assert m["pings"] == 2 * N_SHORT and all(r["complete"] for r in m["runs"].values())


def test_sequences_the_recording_lacks_are_skipped_and_counted(first_pings, hw, small_proc,
                                                                tmp_path):
    """A recording with holes (pings the daemon never got): the service says they are
    missing, the worker skips them at once (no wait) and its tiles equal `svss
    process`'s of the same file."""
    from svss_proc.run_worker import process_raw

    raw = write_pings(tmp_path / "holes.h5",
                      [p for p in first_pings if p.sequence not in {10, 11, 25}])
    process_raw(raw, tmp_path / "ref", small_proc)
    out = tmp_path / "w"
    result = {}
    ctx = zmq.Context()
    with RawRunStore([raw]) as store, \
            PingService("tcp://127.0.0.1:*", ReplayStore(store), ctx=ctx) as svc, \
            PingPublisher("tcp://127.0.0.1:*", 1000, ctx=ctx) as pub, \
            RawRunReader(raw) as run:
        t = _serve_in_thread(result, pub.endpoint, out, hw, small_proc, 60,
                             receive_hwm=1000, service=svc.endpoint, runs=1,
                             gap_wait_s=600.0)
        pub.wait_for_subscribers(timeout_s=60)
        svc.store.begin("holes")
        for p in run:
            if p.sequence != 20:                      # and one dropped on the stream
                pub.publish(p)
        svc.store.end("holes")
        pub.publish(messages.RunEnd("holes", len(run)))
        t.join(timeout=300)
    ctx.term()
    assert not t.is_alive() and "error" not in result, result.get("error")
    assert_same_tiles(tmp_path / "ref", out / "holes")
    m = json.loads((out / MANIFEST).read_text())
    assert m["missing_in_recording"] == 3 and m["fetched_pings"] == 1
    assert m["skipped_pings"] == 0 and m["pings"] == N_SHORT - 3
