"""A stop signal that lands while the recorder writes: a real recorder process takes a
SIGTERM every millisecond or so while it appends pings, each into a segment of its own
(every append creates an HDF5 file, the write most exposed to being cut). A signal that
lands inside an append stops it only once the ping is whole in the file and counted
(:func:`svss_daq.signals.deferred_stop`): no segment fails, the recorder's bookkeeping
and the files agree, and every segment reads back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from svss_daq.rawfile import RawRunReader

ROOT = Path(__file__).resolve().parents[2]
N_PINGS = 40

# The script hammers itself with SIGTERM while it appends pings to ``rec`` (made by
# ``setup``, which also names APPEND, the code object of the append under test). The
# handler acts on signals that land inside that append (the frame the signal
# interrupted, or one of its callers, is the append's); others (in the script's own loop)
# are ignored, so that the script sees each append's outcome by the count ``count``.
# ``finish`` closes and prints the JSON report.
HARNESS = """
import json, os, signal, sys, threading, time
from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.signals import stop_handler
from tests.hostile.conftest import ping_for
hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
SETUP

def in_append(frame):
    while frame is not None:
        if frame.f_code is APPEND:
            return True
        frame = frame.f_back
    return False

def handler(signum, frame):
    if in_append(frame):
        stop_handler(signum, frame)

pings = [ping_for(hw, i) for i in range(int(sys.argv[2]))]
done = threading.Event()
def hammer():
    while not done.is_set():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.001)
signal.signal(signal.SIGTERM, handler)
threading.Thread(target=hammer, daemon=True).start()
outcome = []
for ping in pings:
    n = COUNT
    try:
        rec.append(ping)
        outcome.append("whole")
    except KeyboardInterrupt:
        outcome.append("stopped after" if COUNT > n else "stopped before")
done.set()
time.sleep(0.05)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
FINISH
"""


def harness(setup: str, count: str, finish: str) -> str:
    return (HARNESS.replace("SETUP", setup.strip()).replace("COUNT", count)
            .replace("FINISH", finish.strip()))


RECORDER = harness("""
from svss_daq.recorder import RunRecorder
rec = RunRecorder(sys.argv[1], "line", hw, flush_every_pings=1, flush_interval_s=3600,
                  max_file_bytes=2**40, max_file_s=0.0)     # a new segment every ping
APPEND = RunRecorder.append.__code__
""", "rec.n_recorded", """
rec.close_files()
print(json.dumps({"outcome": outcome, "recorded": rec.n_recorded, "flushed": rec.n_flushed,
                  "stopped": rec.stopped, "sequences": rec.sequences,
                  "segments": [str(p) for p in rec.segments]}))
""")

# the same for RawRunWriter alone, as ``svss simulate`` writes: flushed every ping
WRITER = harness("""
from svss_daq.rawfile import RawRunWriter
rec = RawRunWriter(sys.argv[1] + "/run.h5", hw, flush_every_pings=1, flush_interval_s=3600)
APPEND = getattr(RawRunWriter.append, "__wrapped__", RawRunWriter.append).__code__
""", "rec.n_pings", """
recorded, flushed = rec.n_pings, rec.n_flushed
rec.close()
print(json.dumps({"outcome": outcome, "recorded": recorded, "flushed": flushed}))
""")


def test_stop_signals_inside_a_raw_writers_appends_leave_a_whole_file(tmp_path):
    """``svss simulate`` writes through RawRunWriter directly (under two CPU hogs it
    exited 1, not 130, on SIGTERM: the signal had landed inside HDF5)."""
    res = subprocess.run([sys.executable, "-c", WRITER, str(tmp_path), str(N_PINGS)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    outcome = out["outcome"]
    print({k: outcome.count(k) for k in set(outcome)})
    assert outcome.count("stopped after") >= N_PINGS // 2, outcome
    assert outcome.count("stopped before") <= 2, outcome
    expected = [i for i, o in enumerate(outcome) if o != "stopped before"]
    assert out["recorded"] == out["flushed"] == len(expected)
    with RawRunReader(tmp_path / "run.h5") as run:
        assert run.clean
        assert [run.ping(k).sequence for k in range(len(run))] == expected


@pytest.mark.slow
def test_stop_signals_inside_appends_fail_no_segment_and_leave_file_and_counts_agreeing(
        tmp_path):
    res = subprocess.run([sys.executable, "-c", RECORDER, str(tmp_path), str(N_PINGS)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    outcome = out["outcome"]
    print({k: outcome.count(k) for k in set(outcome)})
    assert out["stopped"] is None, out["stopped"]
    # the signals came, and nearly all landed inside the write and waited for its end
    # (one landing in the few bytecodes before the deferral begins stops the append
    # before the ping is handed over)
    assert outcome.count("stopped after") >= N_PINGS // 2, outcome
    assert outcome.count("stopped before") <= 2, outcome
    # the bookkeeping holds exactly the pings appended whole
    expected = [i for i, o in enumerate(outcome) if o != "stopped before"]
    assert out["sequences"] == expected
    assert out["recorded"] == out["flushed"] == len(expected)
    seen = []
    for path in out["segments"]:
        with RawRunReader(path) as run:
            assert run.clean
            seen += [run.ping(k).sequence for k in range(len(run))]
    assert seen == expected
