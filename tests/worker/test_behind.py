"""A worker behind the sonar (issue 32), as real processes: ``svss replay --realtime``
serving a raw run on loopback with its catch-up service, ``svss worker`` with products,
and a subscriber of this test timing the stream. The worker is stopped (SIGSTOP) while
the line goes on and continued once the stream has moved 6 s past it: it must say so
(the alarm worker.behind, in its log and its run's manifest) and degrade by daq.toml's
``[worker]`` policy -- tiles completed while behind get their quick look first and their
full products later -- and never drop a ping: every recorded ping imaged, every tile
written with its full products in the end, the run complete. Waits are on conditions
(the journal, the stream's sequence, the process's exit), never fixed sleeps."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import pytest
import zmq

from svss_daq import messages
from svss_daq.config import ConfigError, DaqConfig, config_path, load, worker_section
from svss_daq.subscriber import subscribe

from .conftest import N_PINGS, ROOT, small_processing_text
from .test_stop_and_lock import _stop as stop_process
from .test_stop_and_lock import _wait as wait_running
from .test_stop_and_lock import replay_endpoints

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux")

STARTUP_S = 300.0
#: the stream has moved this many pings past the stopped worker when it is continued:
#: 6 s, far beyond behind_s below
STOPPED_PINGS = 60


def _config_dir(tmp_path: Path, worker_table: str) -> Path:
    d = tmp_path / "config"
    shutil.copytree(Path(config_path("daq.toml")).parent, d)
    text = (d / "daq.toml").read_text()
    head, sep, tail = text.partition("\n[worker]")
    assert sep, "config/daq.toml has a [worker] table"
    rest = tail.split("\n[", 1)
    (d / "daq.toml").write_text(head + "\n" + worker_table
                                + ("\n[" + rest[1] if len(rest) > 1 else ""))
    return d


def _svss(*args, log: Path, config_dir: Path) -> subprocess.Popen:
    with open(log, "wb") as err:
        return subprocess.Popen([sys.executable, "-m", "svss", "--config-dir",
                                 str(config_dir), *map(str, args)], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=err, text=True)


def _wait(pred, what: str, proc: subprocess.Popen, log: Path, timeout_s=STARTUP_S):
    return wait_running(pred, what, proc, log, timeout_s)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)          # a stopped process hears SIGTERM then
    stop_process(proc)


def test_worker_config_is_checked(tmp_path):
    """daq.toml's [worker]: defaults where omitted, bad values refused naming the file
    and the key."""
    assert worker_section(load(DaqConfig, config_path("daq.toml"))).when_behind == \
        "quicklook_first"
    d = _config_dir(tmp_path, "[worker]\nbehind_s = 3.0\n")
    w = worker_section(load(DaqConfig, d / "daq.toml"))
    assert (w.behind_s, w.caught_up_s, w.when_behind, w.max_deferred_tiles) == \
        (3.0, 5.0, "quicklook_first", 4)
    bad = _config_dir(tmp_path / "bad", '[worker]\nwhen_behind = "drop_pings"\n')
    with pytest.raises(ConfigError, match=r"daq\.toml.*worker\.when_behind"):
        load(DaqConfig, bad / "daq.toml")


@pytest.mark.slow
def test_behind_worker_degrades_to_quick_looks_first_and_drops_no_ping(raw_run, tmp_path):
    cfg = _config_dir(tmp_path, "[worker]\nbehind_s = 1.0\ncaught_up_s = 0.5\n"
                      'when_behind = "quicklook_first"\nmax_deferred_tiles = 20\n')
    proc = tmp_path / "processing.toml"
    proc.write_text(small_processing_text())            # 2 m tiles, with products
    replay = _svss("replay", raw_run, "--endpoint", "tcp://127.0.0.1:*", "--service",
                   "tcp://127.0.0.1:*", "--realtime", "--subscribers", "2", "--linger",
                   "300", "--wait", "300", log=tmp_path / "replay.log", config_dir=cfg)
    procs = [replay]
    mon = None
    try:
        pub, service = replay_endpoints(replay, tmp_path / "replay.log")

        def stream_at(seq: int) -> bool:
            while mon.poll(0):
                msg = messages.recv(mon)
                if isinstance(msg, messages.RunEnd):
                    seen["end"] = True
                else:
                    seen["last"] = max(seen["last"], msg.sequence)
            return seen["last"] >= seq or seen["end"]

        out, timings = tmp_path / "tiles", tmp_path / "timings.json"
        w_log = tmp_path / "worker.log"
        worker = _svss("worker", "--connect", pub, "--service", service, "--out", out,
                       "--processing", proc, "--runs", "1", "--idle-timeout", "120",
                       "--timings", timings, log=w_log, config_dir=cfg)
        procs.append(worker)
        # the replay starts once this test's subscriber joins the worker's: after the
        # worker's warm-up (a first run compiles for minutes on a loaded machine)
        _wait(lambda: "worker: waiting for pings" in w_log.read_text(errors="replace"),
              "the worker's warm-up", worker, w_log)
        mon = subscribe(pub, 10000, zmq.Context.instance())
        seen = {"last": -1, "end": False}
        journal = out / "line1" / "worker_state.json"
        _wait(journal.is_file, "the worker imaging", worker, w_log)
        worker.send_signal(signal.SIGSTOP)
        stopped_at = seen["last"]
        _wait(lambda: stream_at(stopped_at + STOPPED_PINGS), "the stream moving on",
              replay, tmp_path / "replay.log")
        assert not seen["end"], "the line ended before the worker was continued"
        worker.send_signal(signal.SIGCONT)
        assert worker.wait(STARTUP_S * 3) == 0, w_log.read_text()[-3000:]
        logs = w_log.read_text(errors="replace")
        assert "Traceback" not in logs, logs[-3000:]
        # it said so
        assert re.search(r"alarm worker\.behind raised: ping \d+ reached the imager "
                         r"[\d.]+ s behind the sonar", logs), logs[-3000:]
        run = json.loads((out / "line1" / "manifest.json").read_text())
        assert run["behind"]["episodes"] >= 1 and run["behind"]["max_lag_s"] > 1.0, run
        deferred = run["behind"]["products_deferred"]
        assert deferred, run["behind"]
        # never a ping dropped: every recorded ping imaged, the run complete
        assert run["complete"] is True and run["pings"] == N_PINGS, run
        assert run["skipped_pings"] == 0 and not run["skipped"]
        tiles = sorted((out / "line1").glob("tile_*.h5"))
        assert len(tiles) == len([f for f in run["files"] if f.endswith(".h5")])
        imaged = set()
        for t in tiles:
            with h5py.File(t, "r") as f:
                # every tile, the deferred ones included, has its full products
                assert "detections" in f and "background" in f, (t, list(f))
                imaged |= {int(s) for s in f["ping_sequence"][()]}
        assert imaged == set(range(N_PINGS))
        t = json.loads(timings.read_text())["runs"]["line1"]
        assert t["pings"] == N_PINGS
        by_tile = {e["tile"]: e for e in t["tiles"]}
        assert sorted(by_tile) == sorted(int(p.stem.split("_")[1]) for p in tiles)
        for k in deferred:
            e = by_tile[k]
            # quick look first, full products later
            assert e["quicklook_unix_s"] is not None and e["written_unix_s"] is not None
            assert e["quicklook_unix_s"] < e["written_unix_s"], e
        for k, e in by_tile.items():
            if k not in deferred:
                assert e["quicklook_unix_s"] is None, e
        # the stages were timed: every ping conditioned, imaged, covered and scheduled
        st = run["stage_times"]
        assert st["scheduling"]["calls"] == N_PINGS
        assert st["conditioning"]["calls"] >= 1 and st["imaging"]["calls"] >= N_PINGS
        assert st["coverage"]["calls"] == st["imaging"]["calls"]
        assert st["quicklook"]["calls"] == len(deferred)
        assert st["products"]["calls"] == len(tiles)
        assert os.path.getsize(timings) > 0
    finally:
        if mon is not None:
            mon.close(linger=0)
        for p in reversed(procs):
            _stop(p)


def test_waiting_tiles_are_bounded_and_not_written_in_the_journal(raw_run, tmp_path):
    """In one process (the policy's bookkeeping): with products deferred, a completed
    tile gets its quick look and no tile file; the journal does not list it as written
    and resumes at or before its first ping (a crash rebuilds it); beyond
    ``max_deferred`` waiting tiles the oldest gets its full products at once; at the
    run's end every tile has them."""
    from svss_daq.config import ProcessingConfig, load_with_text
    from svss_daq.rawfile import RawRunReader
    from svss_proc.run_worker import Worker
    proc_path = tmp_path / "processing.toml"
    proc_path.write_text(small_processing_text())
    proc = load_with_text(ProcessingConfig, proc_path)
    out = tmp_path / "line1"
    seen = []
    with RawRunReader(raw_run) as run:
        w = Worker(run.hardware, proc, out, run_id="line1")
        w.defer_products, w.max_deferred = True, 2
        for p in run:
            w.add(p)
            if w.deferred:
                waiting = [t.grid.index for t, _ in w.deferred]
                j = json.loads((out / "worker_state.json").read_text())
                for t, _ in w.deferred:
                    assert not (out / f"tile_{t.grid.index:04d}.h5").exists()
                    assert (out / f"tile_{t.grid.index:04d}_mip.png").exists()
                    assert t.grid.index not in j["written"], j
                    assert j["resume_sequence"] <= t.pings[0], j
                assert len(waiting) <= 2
                seen.append(tuple(waiting))
        n_done_mid = len(list(out.glob("tile_*.h5")))
        w.finish()
    assert any(len(s) == 2 for s in seen), seen       # the bound was reached ...
    assert n_done_mid >= 1                            # ... and the oldest finished
    tiles = sorted(out.glob("tile_*.h5"))
    # the tiles completed mid-run waited; those the run's end closed did not
    assert w.deferred_tiles and set(w.deferred_tiles) < {int(p.stem.split("_")[1])
                                                         for p in tiles}
    for t in tiles:
        with h5py.File(t, "r") as f:
            assert "detections" in f
    assert json.loads((out / "worker_state.json").read_text())["complete"] is True
