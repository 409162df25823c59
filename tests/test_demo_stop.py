"""Ctrl-C on `svss demo` (issue 27, item 9): the terminal's SIGINT reaches the demo's
process group; the demo stops its processes once each, the worker first, and what it
says was flushed was: the worker's open tiles and manifest (incomplete), the recording
with its summary; no traceback, no process left running."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from svss_daq.rawfile import RawRunReader

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux")]

ROOT = Path(__file__).resolve().parents[1]
STARTUP_S = 300.0


def _running_under(folder: Path) -> list[str]:
    """Command lines of the processes that name ``folder`` (the demo's children)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
        except OSError:
            continue
        if str(folder) in cmd:
            out.append(f"{d.name}: {cmd}")
    return out


def test_ctrl_c_on_the_demo_flushes_what_it_says(tmp_path):
    out = tmp_path / "demo"
    err = tmp_path / "demo.err"
    with open(err, "wb") as fh:
        # --lead 3: the test stops the demo once it images, whichever ping comes first
        demo = subprocess.Popen([sys.executable, "-m", "svss", "demo", "--out", str(out),
                                 "--lead", "3"],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=fh,
                                start_new_session=True)        # its own process group
    try:
        journal = out / "tiles" / "demo" / "worker_state.json"
        deadline = time.monotonic() + STARTUP_S
        while not journal.is_file():                 # the worker images: tiles are open
            assert demo.poll() is None and time.monotonic() < deadline, \
                err.read_text(errors="replace")[-3000:]
            time.sleep(0.1)
        os.killpg(demo.pid, signal.SIGINT)           # Ctrl-C: the whole foreground group
        rc = demo.wait(600)
    finally:
        if demo.poll() is None:
            os.killpg(demo.pid, signal.SIGKILL)
    logs = err.read_text(errors="replace")
    assert rc == 130, logs[-3000:]
    assert "Traceback" not in logs, logs[-3000:]
    assert "what was done is flushed" in logs and "not cleanly" not in logs, logs[-3000:]
    # the stop's cause, not a file's state (it said "stopped by no acquisition summary:
    # not closed" of a recording closed with its summary)
    assert "svss demo stopped by signal SIGINT: the worker wrote" in logs \
        and "no acquisition summary" not in logs, \
        logs[-3000:]
    tiles = out / "tiles"
    top = json.loads((tiles / "manifest.json").read_text())
    run = json.loads((tiles / "demo" / "manifest.json").read_text())
    assert top["complete"] is False and run["complete"] is False
    written = sorted((tiles / "demo").glob("tile_*.h5"))
    assert written and len(written) == top["runs"]["demo"]["tiles"]
    [raw] = sorted((out / "runs").glob("demo_*.h5"))
    with RawRunReader(raw) as r:
        assert r.clean and r.summary is not None
        assert r.summary["counters"]["recorded"] == len(r) > 0
    assert not _running_under(out), _running_under(out)
