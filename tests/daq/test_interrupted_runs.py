"""Runs whose recording daemon died mid-run: a real recorder process SIGKILLed while it
writes leaves its segment flagged open for writing, without a summary; the next daemon
in the folder closes that segment (the superblock's flags cleared, as ``h5clear``
does), marks the run interrupted and keeps every flushed ping as it was. A run whose
recorder is alive (its lock held) is left alone; a run id recorded already is refused,
and a daemon restarted within the second gets a run id of its own."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from svss_daq.rawfile import RawRunReader, lookup3
from svss_daq.untrusted_hdf5 import hdf5_superblock
from svss_daq.recorder import (RunRecorder, close_interrupted_runs, free_run_id, lock_path,
                               reserve_path)

ROOT = Path(__file__).resolve().parents[2]

RECORDER = """
import sys, time
from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.recorder import RunRecorder
from tests.hostile.conftest import ping_for
hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
rec = RunRecorder(sys.argv[1], sys.argv[2], hw, flush_every_pings=4, flush_interval_s=3600,
                  max_file_bytes=2**40, max_file_s=1e6)
for i in range(int(sys.argv[3])):
    rec.append(ping_for(hw, i))
    rec.append_event(i, "test.ping", f"ping {i}")
print("written", flush=True)
while True:                      # recording on: killed here
    time.sleep(1)
"""


def recorder_process(out: Path, run_id: str, n_pings: int) -> subprocess.Popen:
    """A RunRecorder in its own process that has appended ``n_pings`` pings (flushed
    every 4th) and keeps the run open."""
    proc = subprocess.Popen([sys.executable, "-c", RECORDER, str(out), run_id,
                             str(n_pings)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "written"
    return proc


def test_lookup3_is_hdf5s_superblock_checksum(tmp_path):
    import h5py
    path = tmp_path / "x.h5"
    with h5py.File(path, "w", libver="latest") as f:
        f["x"] = np.arange(3)
    head = path.read_bytes()[:48]
    assert head[8] in (2, 3)                   # a version 2/3 superblock, 8-byte addresses
    assert lookup3(head[:44]) == int.from_bytes(head[44:48], "little")


def test_killed_recorder_run_is_closed_and_marked_with_its_flushed_pings(tmp_path):
    out = tmp_path / "runs"
    proc = recorder_process(out, "lineA", 10)          # 8 flushed, 2 not
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    seg = out / "lineA_000.h5"
    assert hdf5_superblock(seg)["flags"] & 1             # left open for writing
    assert lock_path(out, "lineA").exists() and reserve_path(out, "lineA").exists()
    with RawRunReader(seg) as run:
        assert not run.clean and run.summary is None
        before = [run.ping(i) for i in range(len(run))]
        events = run.events()
    assert len(before) == 8
    closed = close_interrupted_runs(out, "lineB")
    assert set(closed) == {"lineA"}
    assert closed["lineA"]["interrupted"] and closed["lineA"]["counters"]["recorded"] == 8
    assert not hdf5_superblock(seg)["flags"] & 1
    assert not lock_path(out, "lineA").exists() and not reserve_path(out, "lineA").exists()
    with RawRunReader(seg) as run:
        assert run.clean
        assert run.summary["interrupted"] is True and run.summary["closed_by"] == "lineB"
        after = [run.ping(i) for i in range(len(run))]
        assert run.events() == events
    assert [p.sequence for p in after] == [p.sequence for p in before]
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a.samples, b.samples)
        assert a.nav == b.nav and a.transmit_time_ns == b.transmit_time_ns
    assert close_interrupted_runs(out, "lineC") == {}      # done once


def test_a_live_recorders_run_is_left_alone(tmp_path):
    out = tmp_path / "runs"
    proc = recorder_process(out, "live", 6)
    try:
        seg = out / "live_000.h5"
        size, mtime = seg.stat().st_size, seg.stat().st_mtime_ns
        assert close_interrupted_runs(out, "other") == {}
        assert hdf5_superblock(seg)["flags"] & 1
        assert (seg.stat().st_size, seg.stat().st_mtime_ns) == (size, mtime)
        from svss_daq.config import HardwareConfig, config_path, load_with_text
        hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
        with pytest.raises(FileExistsError, match="being recorded by another daemon"):
            RunRecorder(out, "live", hw, flush_every_pings=1, flush_interval_s=1,
                        max_file_bytes=2**30, max_file_s=60)
    finally:
        proc.kill()
        proc.wait(10)
    assert set(close_interrupted_runs(out, "other")) == {"live"}


def test_a_recorded_run_id_is_refused_and_a_free_one_found(tmp_path, hardware):
    out = tmp_path / "runs"
    proc = recorder_process(out, "line-20260101T000000Z", 1)
    proc.kill()
    proc.wait(10)
    close_interrupted_runs(out, "x")
    with pytest.raises(FileExistsError, match="recorded there already"):
        RunRecorder(out, "line-20260101T000000Z", hardware, flush_every_pings=1,
                    flush_interval_s=1, max_file_bytes=2**30, max_file_s=60)
    assert not lock_path(out, "line-20260101T000000Z").exists()
    assert free_run_id(out, "line-20260101T000000Z") == "line-20260101T000000Z-2"
    assert free_run_id(out, "line-20260101T000001Z") == "line-20260101T000001Z"
    # a clean run's lock is released with its summary
    rec = RunRecorder(out, "ok", hardware, flush_every_pings=1, flush_interval_s=1,
                      max_file_bytes=2**30, max_file_s=60)
    assert lock_path(out, "ok").exists()
    rec.close({"run_id": "ok"})
    assert not lock_path(out, "ok").exists()
    assert close_interrupted_runs(out, "y") == {}



def test_a_ping_half_written_when_killed_is_left_out_of_the_closed_run(tmp_path):
    """Killed between growing its datasets for a ping and counting it flushed (seen
    under load: 21 entries, 20 flushed), the writer leaves a longer dataset than its
    count; closed as interrupted, the run reads its flushed pings (it was refused as
    damaged, and the restarted daemon served none of the earlier runs)."""
    import h5py
    out = tmp_path / "runs"
    proc = recorder_process(out, "lineA", 10)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    seg = out / "lineA_000.h5"
    close_interrupted_runs(out, "lineB")
    with h5py.File(seg, "a") as f:          # the half-written ping's entries
        for name in ("Sonar/Beam_group1/backscatter_r", "Platform/time1"):
            f[name].resize(f[name].shape[0] + 1, axis=0)
    with RawRunReader(seg) as run:
        assert run.clean and run.summary["interrupted"] is True
        assert len(run) == 8 and run.truncated == 1
        assert [run.ping(i).sequence for i in range(8)] == list(range(8))
    # a file closed by its own writer with such a mismatch is still damaged
    with h5py.File(seg, "a") as f:
        f.attrs["acquisition_summary"] = '{"interrupted": false}'
    from svss_daq.rawfile import RawFileError
    with pytest.raises(RawFileError, match="damaged"):
        RawRunReader(seg)
