"""The reliable path's end through real processes (``svss sim-device`` -> ``svss acquire``
-> ``svss worker``): a worker that tells the catch-up service its progress keeps the
daemon's service up after the run while it still lacks pings, and a worker that cannot
fetch what it lacks says so in its manifest (``complete: false``, the ranges skipped),
never ``complete: true`` with pings skipped.

The worker is stopped (SIGSTOP) mid-run: the daemon's ping queue to it is tiny
(``publisher.send_hwm = 2``), so the stream drops the pings it does not take, and its
last request to the service is long past when the run ends (``catch_up.linger_s`` 1 s).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from svss_daq.ping_service import PingFetcher, ServiceError
from svss_daq.rawfile import RawRunReader
from svss_proc.tiles import read_tile

from .conftest import CONFIG, ROOT, acquire_toml

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="needs Linux pseudo-terminals"), pytest.mark.slow]
DEADLINE_S = 600.0


def config_dir(tmp: Path, edits: dict[str, str],
               if_there: dict[str, str] | None = None) -> Path:
    """A copy of the project's configuration folder with ``edits`` (old -> new text)
    made to its daq.toml, and ``if_there`` where the old text is there."""
    d = tmp / "config"
    shutil.copytree(CONFIG, d)
    text = (d / "daq.toml").read_text()
    for old, new in edits.items():
        assert old in text, old
        text = text.replace(old, new)
    for old, new in (if_there or {}).items():
        text = text.replace(old, new)
    (d / "daq.toml").write_text(text)
    return d


def fast_processing(tmp: Path) -> Path:
    """The demo's processing on small tiles (2 x 0.3 x 0.2 m) at 4 cm voxels: the run's
    end, not the image, is under test."""
    from tests.worker.conftest import small_processing_text
    path = tmp / "processing-fast.toml"
    text = (small_processing_text().replace("voxel_m = 0.02", "voxel_m = 0.04")
            .replace("width_m = 0.4", "width_m = 0.3")
            .replace("depth_m = 0.3", "depth_m = 0.2"))
    assert "voxel_m = 0.04" in text and "width_m = 0.3" in text and "depth_m = 0.2" in text
    path.write_text(text)
    return path


def wait_for(pred, what: str, timeout_s: float = DEADLINE_S, step_s: float = 0.05):
    deadline = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(step_s)


def run_ended(endpoint: str) -> bool:
    """Whether the catch-up service at ``endpoint`` says run1 has ended (asked there,
    not of the file: a reader holding the file while the daemon closes it makes the
    daemon put the summary beside it)."""
    try:
        with PingFetcher(endpoint, timeout_s=2.0) as fetcher:
            return any(r.run_id == "run1" and r.ended for r in fetcher.runs())
    except (TimeoutError, ServiceError):
        return False


def journal_written(folder: Path) -> bool:
    try:
        return bool(json.loads((folder / "worker_state.json").read_text()).get("line"))
    except (OSError, ValueError):
        return False


def dead_endpoint() -> str:
    """A loopback endpoint nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


class StoppedWorker:
    """A daemon's run with a worker stopped (SIGSTOP) from its first tile frame until
    the run has ended and the daemon has decided whether to keep its service up.
    ``service``: the catch-up service the worker is given (default: the daemon's; with
    another, the worker goes on as soon as the run has ended, while the daemon still
    waits to send its end marker)."""

    def __init__(self, rig, tmp: Path, service: str | None = None, n_pings: int = 80,
                 request_timeout_s: float = 2.0, silence_s: float = 120.0,
                 max_linger_s: float = 600.0):
        self.cfg_dir = config_dir(tmp, {
            "send_hwm = 500": "send_hwm = 2",                 # a stopped worker loses pings
            "request_timeout_s = 10.0": f"request_timeout_s = {request_timeout_s}"},
            # stopped for the run and the daemon's 10 s wait to send its end marker (and
            # more on a loaded machine): not silent meanwhile (``silence_s``: the
            # service's worker_silence_s)
            {"worker_silence_s = 30.0": f"worker_silence_s = {silence_s}"})
        cfg = acquire_toml(tmp, run={"daq": str(self.cfg_dir / "daq.toml")},
                           catch_up={"linger_s": 1.0, "max_linger_s": max_linger_s})
        dev = rig.device("--time-scale", "2")
        self.acq = rig.acquire(dev, "--pings", str(n_pings), "--wait-subscribers", "1",
                               config=cfg)
        self.out = tmp / "tiles"
        self.log = tmp / "worker.log"
        with open(self.log, "wb") as err:
            self.worker = subprocess.Popen(
                [sys.executable, "-m", "svss", "worker", "--connect",
                 self.acq.endpoints["publisher"], "--service",
                 service or self.acq.endpoints["service"],
                 "--out", str(self.out), "--processing", str(fast_processing(tmp)),
                 "--runs", "1", "--idle-timeout", "600"],
                stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT,
                env={**os.environ, "SVSS_CONFIG_DIR": str(self.cfg_dir)})
        try:
            # stopped as soon as the run's first ping reached it (it has told the
            # service then; the run goes on for seconds)
            wait_for(lambda: "imaging into" in self.log.read_text(),
                     "the worker's first ping")
            if service is None:
                # ... and once the daemon's service has its progress (a message still in
                # the stopped worker's socket would never leave it: on a loaded machine
                # the daemon then knew no worker and left at the run's end)
                wait_for(lambda: "is imaging run run1" in self.acq.logs(),
                         "the worker's progress at the daemon")
            self.worker.send_signal(signal.SIGSTOP)
            # the run ends while the worker is stopped ...
            wait_for(lambda: self.acq.proc.poll() is not None
                     or run_ended(self.acq.endpoints["service"]), "the run's end")
            # ... and the daemon decides: it goes (its linger on requests is over) or it
            # stays up for the worker that lacks pings
            if service is None:
                wait_for(lambda: self.acq.proc.poll() is not None
                         or "stays up while 1 worker(s)" in self.acq.logs(),
                         "the daemon's decision after the run")
        except BaseException:
            self.close()
            raise

    def resume(self) -> dict:
        """Let the worker go on; its manifest once it has exited (rc 0)."""
        self.worker.send_signal(signal.SIGCONT)
        try:
            rc = self.worker.wait(DEADLINE_S)
        finally:
            self.close()
        assert rc == 0, self.log.read_text()[-3000:]
        return json.loads((self.out / "manifest.json").read_text())

    def close(self) -> None:
        if self.worker.poll() is None:
            self.worker.send_signal(signal.SIGCONT)
            self.worker.kill()
            self.worker.wait(10)


def recording(acq) -> tuple[list[int], dict]:
    """The run's recorded sequences and its summary."""
    [raw] = acq.files()
    with RawRunReader(raw) as run:
        return run.ping_table()["ping_sequence"].tolist(), run.summary


def test_daemon_stays_up_while_a_worker_lacks_pings(rig, tmp_path):
    run = StoppedWorker(rig, tmp_path)
    manifest = run.resume()
    assert run.acq.wait(DEADLINE_S) == 0, run.acq.logs()[-3000:]
    recorded, summary = recording(run.acq)
    # the stopped worker lost pings on the stream and fetched every one of them
    assert manifest["fetched_pings"] > 0, manifest
    assert manifest["fetch_errors"] == 0 and manifest["skipped_pings"] == 0, (
        manifest, run.log.read_text()[-3000:], run.acq.logs()[-2000:])
    assert manifest["complete"] and manifest["runs"]["run1"]["complete"], manifest
    assert manifest["pings"] == len(recorded) == summary["counters"]["recorded"]
    assert "stays up while 1 worker(s)" in run.acq.logs()
    imaged = set()
    for tile in (run.out / "run1").glob("tile_*.h5"):
        imaged |= set(read_tile(tile)["ping_sequence"].tolist())
    assert imaged == set(recorded)


def test_a_silent_worker_keeps_the_service_up_and_raises_its_alarm(rig, tmp_path):
    """The worker stopped (SIGSTOP) far longer than the service's worker_silence_s
    (1 s): it is silent, not forgotten: the alarm worker.silent is raised, critical (it
    lacks pings of the run), and stays raised; the daemon keeps its service up after
    the run for it; let go on, the worker fetches what it lacks and completes."""
    run = StoppedWorker(rig, tmp_path, silence_s=1.0)
    logs = run.acq.logs()
    assert "stays up while 1 worker(s)" in logs and "silent for" in logs
    raised = [ln for ln in logs.splitlines() if "alarm.raised" in ln and "worker.silent" in ln]
    assert raised and "lacking pings of this run" in raised[0], logs[-3000:]   # critical
    manifest = run.resume()
    assert run.acq.wait(DEADLINE_S) == 0, run.acq.logs()[-3000:]
    recorded, _ = recording(run.acq)
    assert manifest["complete"] and manifest["pings"] == len(recorded), manifest


def test_a_worker_whose_service_is_gone_falls_back_to_the_recording(rig, tmp_path):
    """The daemon waits for the stopped worker no longer than catch_up.max_linger_s
    (1 s here) and exits, its service gone with it. Let go on, the worker says the
    service is gone and catches up from the raw-run file the service named (on this
    machine): every recorded ping imaged, the run complete, the worker exits 0."""
    run = StoppedWorker(rig, tmp_path, max_linger_s=1.0)
    assert run.acq.wait(DEADLINE_S) == 0, run.acq.logs()[-3000:]     # gone, cleanly
    manifest = run.resume()
    recorded, _ = recording(run.acq)
    log = run.log.read_text()
    assert "gone" in log and "catching up from the recording in" in log, log[-3000:]
    assert manifest["complete"] and manifest["skipped_pings"] == 0, (manifest, log[-3000:])
    assert manifest["pings"] == len(recorded) and manifest["fetched_pings"] > 0
    imaged = set()
    for tile in (run.out / "run1").glob("tile_*.h5"):
        imaged |= set(read_tile(tile)["ping_sequence"].tolist())
    assert imaged == set(recorded)


def test_a_worker_that_cannot_fetch_says_so_in_its_manifest(rig, tmp_path):
    # the worker's catch-up service does not answer: it lost pings on the stream and
    # cannot fetch them
    # (its first ask of the service waits out the timeout while the run goes on)
    run = StoppedWorker(rig, tmp_path, service=dead_endpoint(), n_pings=120,
                        request_timeout_s=0.5)
    t0 = time.monotonic()
    manifest = run.resume()
    took = time.monotonic() - t0
    assert run.acq.wait(DEADLINE_S) == 0, run.acq.logs()[-3000:]
    recorded, _ = recording(run.acq)
    m = manifest["runs"]["run1"]
    assert manifest["pings"] < len(recorded)             # the stream lost some
    # not complete, and it says why and what (the ranges it never imaged)
    assert not manifest["complete"] and not m["complete"], manifest
    assert m["incomplete"] and manifest["fetch_errors"] > 0
    skipped = {q for a, b in m["skipped"] for q in range(a, b + 1)}
    assert skipped and m["skipped_pings"] == len(skipped)
    assert skipped <= set(range(min(recorded), max(recorded) + 1))
    # every recorded ping is imaged or listed as skipped
    imaged = set()
    for tile in (run.out / "run1").glob("tile_*.h5"):
        imaged |= set(read_tile(tile)["ping_sequence"].tolist())
    assert not imaged & skipped and set(recorded) <= imaged | skipped
    # a gone service is waited for a few request timeouts (0.5 s), not one per gap
    assert took < 60, took
