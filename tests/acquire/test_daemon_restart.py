"""A daemon killed mid-run and restarted, through real processes (``svss sim-device`` ->
``svss acquire`` -> ``svss worker``): the restarted daemon records a new run, closes
the killed run's segment and marks it interrupted (every flushed ping kept), its
catch-up service lists that run as ended, and the restarted worker finishes the killed
run from the recording and images the new run into its own tiles: no run's pings in
another's tiles, even when the device was restarted too and the ping numbers begin
again at 0."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, load_with_text
from svss_daq.ping_service import PingFetcher
from svss_daq.rawfile import RawRunReader
from svss_proc.run_worker import process_raw
from tests.worker.conftest import assert_same_tiles

from .conftest import ROOT, acquire_toml
from .test_worker_linger import DEADLINE_S, fast_processing, journal_written, wait_for

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="needs Linux pseudo-terminals"), pytest.mark.slow]


def worker(tmp: Path, endpoints: dict, out: Path, processing: Path, name: str,
           runs: int) -> subprocess.Popen:
    log = open(tmp / f"{name}.log", "wb")
    return subprocess.Popen(
        [sys.executable, "-m", "svss", "worker", "--connect", endpoints["publisher"],
         "--service", endpoints["service"], "--out", str(out), "--processing",
         str(processing), "--runs", str(runs), "--idle-timeout", "600"],
        stdout=subprocess.DEVNULL, stderr=log, cwd=ROOT)


def recorded(endpoint: str, run_id: str) -> int:
    with PingFetcher(endpoint, timeout_s=5.0) as f:
        return sum(r.n_pings for r in f.runs() if r.run_id == run_id)


def test_killed_daemon_restarted_records_a_new_run_and_runs_never_mix(rig, tmp_path):
    cfg = acquire_toml(tmp_path, catch_up={"linger_s": 2.0, "max_linger_s": 600.0})
    processing = fast_processing(tmp_path)
    out = tmp_path / "tiles"
    dev = rig.device("--time-scale", "2", name="dev1")
    a = rig.acquire(dev, "--duration", "300", "--wait-subscribers", "1", run_id="runA",
                    config=cfg)
    wa = worker(tmp_path, a.endpoints, out, processing, "workerA", runs=1)
    try:
        wait_for(lambda: journal_written(out / "runA"), "worker A's first ping")
        wait_for(lambda: recorded(a.endpoints["service"], "runA") >= 20, "20 pings of A")
    finally:
        # the daemon and its worker die mid-run (the device too, below)
        for p in (a.proc, wa):
            p.send_signal(signal.SIGKILL)
            p.wait(20)
    [raw_a] = a.files()
    with RawRunReader(raw_a) as run:
        assert not run.clean and run.summary is None       # left open by the dead daemon
        kept = run.ping_table()["ping_sequence"].tolist()
        last_ping = run.ping(len(run) - 1)
    dev.stop()
    dev = rig.device("--time-scale", "2", name="dev2")      # ping numbers from 0 again
    b = rig.acquire(dev, "--pings", "20", "--wait-subscribers", "1", run_id="runB",
                    config=cfg)
    # the restarted daemon closed the killed run, marked it, and serves it as ended
    with PingFetcher(b.endpoints["service"], timeout_s=10.0) as f:
        runs = {r.run_id: r for r in f.runs()}
    assert runs["runA"].ended and runs["runA"].n_pings == len(kept), runs
    assert not runs["runB"].ended
    with RawRunReader(raw_a) as run:
        assert run.clean and run.summary["interrupted"] is True
        assert run.summary["counters"]["recorded"] == len(kept)
        assert run.summary["closed_by"] == "runB"
        assert run.ping_table()["ping_sequence"].tolist() == kept
        again = run.ping(len(run) - 1)
    np.testing.assert_array_equal(again.samples, last_ping.samples)
    assert again.nav == last_ping.nav
    # the restarted worker: the killed run finished from the recording, the new run
    # into its own folder (--runs 2: both)
    wb = worker(tmp_path, b.endpoints, out, processing, "workerB", runs=2)
    try:
        assert wb.wait(DEADLINE_S) == 0, (tmp_path / "workerB.log").read_text()[-3000:]
    finally:
        if wb.poll() is None:
            wb.kill()
    assert b.wait(DEADLINE_S) == 0, b.logs()[-3000:]
    assert "recording.interrupted_run: run runA" in b.logs()
    [raw_b] = b.files()
    with RawRunReader(raw_b) as run:
        n_b = len(run)
        assert run.summary["counters"]["recorded"] == n_b >= 20
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] and m["skipped_pings"] == 0, (
        m, (tmp_path / "workerB.log").read_text()[-3000:])
    assert m["runs"]["runA"]["complete"] and m["runs"]["runB"]["complete"], m["runs"]
    # every ping of the new run imaged in it (none dropped as the old run's duplicate;
    # the old run's are checked in its tiles below)
    assert m["runs"]["runB"]["pings"] == n_b
    # each run's tiles are those of `svss process` of its own recording, voxel for voxel
    # (the ping numbers of both begin at 0: a ping of one run in the other's tiles shows)
    load = load_with_text(ProcessingConfig, processing)
    for raw, name in ((raw_a, "runA"), (raw_b, "runB")):
        ref = tmp_path / f"process-{name}"
        process_raw(raw, ref, load, renavigate=False)
        assert_same_tiles(ref, out / name)


def test_daemon_restarted_on_a_device_left_pinging(rig, tmp_path):
    """The killed daemon never stopped the sequencer: the restarted one stops it before
    configuring it (says so) and records its run; a run id given again is refused (the
    killed run closed first)."""
    cfg = acquire_toml(tmp_path, catch_up={"linger_s": 0.0, "max_linger_s": 10.0})
    dev = rig.device("--time-scale", "2")
    a = rig.acquire(dev, "--duration", "300", run_id="runA", config=cfg)
    wait_for(lambda: recorded(a.endpoints["service"], "runA") >= 5, "5 pings of A")
    a.proc.send_signal(signal.SIGKILL)
    a.proc.wait(20)
    again = rig.acquire(dev, "--pings", "10", run_id="runA", config=cfg, wait=False)
    assert again.wait(60) == 2
    assert "run runA is recorded there already" in again.logs()
    with RawRunReader(a.files()[0]) as run:
        assert run.clean and run.summary["interrupted"] is True
    b = rig.acquire(dev, "--pings", "10", run_id="runB", config=cfg)
    assert b.wait(120) == 0, b.logs()[-3000:]
    assert "sequencer.was_running: the sequencer was RUNNING" in b.logs()
    with RawRunReader(b.files()[0]) as run:
        assert len(run) == run.summary["counters"]["recorded"] >= 10
