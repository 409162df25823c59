"""The stream worker stopped twice and shared (issue 27, item 9), as real processes
(``svss replay`` serving a raw run on loopback, ``svss worker``): a SIGTERM that follows
the SIGINT -- a parent forwarding the signal the terminal sent to both -- no longer
interrupts the writing of the open tiles and the manifest; a second worker on the same
output folder is refused, naming the folder and the first one's pid."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from svss_proc.folder_lock import LOCK_NAME, FolderInUse, FolderLock

from .conftest import ROOT

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux")

STARTUP_S = 120.0


def _svss(*args, log: Path, **kw) -> subprocess.Popen:
    with open(log, "wb") as err:
        return subprocess.Popen([sys.executable, "-m", "svss", *map(str, args)], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=err, text=True, **kw)


def _wait(pred, what: str, proc: subprocess.Popen, log: Path, timeout_s=STARTUP_S):
    deadline = time.monotonic() + timeout_s
    while not pred():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s} s (rc {proc.poll()}):\n"
                                 + log.read_text(errors="replace")[-3000:])
        time.sleep(0.05)


def replay_endpoints(replay: subprocess.Popen, log: Path) -> tuple[str, str]:
    """The publisher and catch-up service endpoints ``svss replay`` prints on start."""
    pub = service = None
    deadline = time.monotonic() + STARTUP_S
    while (pub is None or service is None) and time.monotonic() < deadline:
        line = replay.stdout.readline()
        if not line:
            break
        if line.startswith("replaying"):
            pub = line.rsplit(" on ", 1)[1].strip()
        elif line.startswith("catch-up service on"):
            service = line.rsplit(" on ", 1)[1].strip()
    assert pub and service, log.read_text()[-3000:]
    return pub, service


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


@pytest.mark.slow
def test_second_signal_does_not_interrupt_the_flush_and_one_worker_per_folder(
        raw_run, small_proc_path, tmp_path):
    replay = _svss("replay", raw_run, "--endpoint", "tcp://127.0.0.1:*", "--service",
                   "tcp://127.0.0.1:*", "--realtime", "--linger", "120", "--wait", "120",
                   log=tmp_path / "replay.log")
    procs = [replay]
    try:
        pub, service = replay_endpoints(replay, tmp_path / "replay.log")
        out = tmp_path / "tiles"
        args = ("worker", "--connect", pub, "--service", service, "--out", out,
                "--processing", small_proc_path, "--idle-timeout", "120")
        a_log = tmp_path / "worker-a.log"
        a = _svss(*args, log=a_log)
        procs.append(a)
        _wait(lambda: (out / LOCK_NAME).is_file() and str(a.pid) in
              (out / LOCK_NAME).read_text(), "worker A's lock", a, a_log)
        # a second worker on the folder: refused at once, naming the folder and the pid
        b = subprocess.run([sys.executable, "-m", "svss", *map(str, args)], cwd=ROOT,
                           capture_output=True, text=True, timeout=STARTUP_S)
        assert b.returncode == 2, (b.returncode, b.stderr[-2000:])
        assert f"{out}: in use by another svss worker pid {a.pid}" in b.stderr, b.stderr
        # worker A images: its tile frame is in its journal, tiles are open
        journal = out / "line1" / "worker_state.json"
        _wait(journal.is_file, "worker A imaging", a, a_log)
        a.send_signal(signal.SIGINT)
        a.send_signal(signal.SIGTERM)            # the parent's, right after the terminal's
        assert a.wait(120) == 130, a_log.read_text()[-3000:]
        logs = a_log.read_text(errors="replace")
        assert "Traceback" not in logs, logs[-3000:]
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["complete"] is False and manifest["runs"]["line1"]["tiles"] >= 1
        tiles = sorted((out / "line1").glob("tile_*.h5"))
        assert len(tiles) == manifest["runs"]["line1"]["tiles"]
        assert json.loads((out / "line1" / "manifest.json").read_text())["complete"] is False
        assert "SIGTERM while stopping: finishing first" in logs, logs[-3000:]
        # the lock went with the worker: the folder is free again
        with FolderLock(out):
            with pytest.raises(FolderInUse, match=f"pid {__import__('os').getpid()}"):
                FolderLock(out)
    finally:
        for p in reversed(procs):
            _stop(p)
