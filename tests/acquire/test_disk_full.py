"""A stop on a full disk (issue 27, item 6): the stream, the recording and the summary
agree. Real processes (``svss sim-device`` -> ``svss acquire``), real HDF5, a real full
disk: a per-file size limit (``RLIMIT_FSIZE``: ``EFBIG``) and, where a tmpfs can be
mounted, a small filesystem (``ENOSPC``)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.rawfile import RawRunReader, summary_path
from svss_daq.recorder import RunRecorder, reserve_path

from .conftest import CONFIG, acquire_toml, limit_file_size
from .test_daemon import Collector

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")

#: bytes of a ping in the file (80 channels x 1500 samples of int32)
PING_BYTES = 80 * 1500 * 4


def _mounted_tmpfs(where, size_bytes: int) -> bool:
    where.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_bytes}", "tmpfs",
                          str(where)], capture_output=True, text=True)
    return res.returncode == 0


@pytest.mark.parametrize("full", ["EFBIG", "ENOSPC"])
@pytest.mark.slow
def test_full_disk_stream_recording_and_summary_agree(rig, tmp_path, full):
    """The hostile tester's run: 139 pings recorded, published and imaged, 130 in the
    file, no summary. Here the daemon flushes every 10th ping, as it did then."""
    daq = tmp_path / "daq.toml"
    daq.write_text((CONFIG / "daq.toml").read_text().replace(
        "flush_every_pings = 1\n", "flush_every_pings = 10\n"))
    assert "flush_every_pings = 10\n" in daq.read_text()
    runs = tmp_path / "runs"
    limit = 24 * PING_BYTES                      # a disk full after ~20 pings
    preexec = None
    if full == "EFBIG":
        preexec = limit_file_size(limit)
    elif not _mounted_tmpfs(runs, limit):
        pytest.skip("cannot mount a tmpfs here (needs root): the ENOSPC case is left out")
    try:
        cfg = acquire_toml(tmp_path, run={"daq": str(daq)})
        dev = rig.device("--time-scale", "2")
        acq = rig.acquire(dev, "--pings", "200", "--wait-subscribers", "1", config=cfg,
                          preexec_fn=preexec)
        sub = Collector(acq.endpoints["publisher"])
        sub.start()
        rc = acq.wait(180)
        sub.join(20)
        sub.close()
        logs = acq.logs()
        assert rc == 3, logs[-3000:]
        assert ("File too large" if full == "EFBIG" else "No space left") in logs
        [f] = acq.files()
        with RawRunReader(f) as run:
            in_file = [p.sequence for p in run]
            summary = run.summary
        # the stream carried exactly the pings the file holds, and said so at its end
        assert 5 <= len(in_file) <= 30, len(in_file)
        assert sub.seqs == in_file, (len(sub.seqs), len(in_file))
        assert sub.end is not None and sub.end.n_pings == len(in_file)
        # the segment has its summary (beside it: the file could not take it), in
        # agreement with both
        assert summary is not None, logs[-3000:]
        assert summary_path(f).is_file()
        c = summary["counters"]
        assert c["recorded"] == c["published"] == len(in_file)
        assert c["publish_dropped"] == 0 and c["not_recorded"] >= 1
        assert c["delivered"] == c["recorded"] + c["not_recorded"] + c["duplicates"]
        assert summary["failure"] and str(f) in summary["failure"]
        assert not reserve_path(runs, "run1").exists()
        # svss inspect shows the summary
        out = subprocess.run([sys.executable, "-m", "svss", "inspect", str(f)],
                             capture_output=True, text=True, cwd=CONFIG.parent, timeout=120)
        assert out.returncode == 0, out.stderr[-2000:]
    finally:
        if full == "ENOSPC":
            subprocess.run(["umount", "-l", str(runs)], capture_output=True)


def test_the_catch_up_view_holds_flushed_pings_only(tmp_path):
    """What the catch-up service serves of the run being recorded (and what it says of
    it) is what is on disk: a ping waiting for its flush is not recorded yet."""
    from tests.hostile.conftest import ping_for
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    rec = RunRecorder(tmp_path, "r", hw, flush_every_pings=10, flush_interval_s=3600,
                      max_file_bytes=2**40, max_file_s=1e6, reserve_bytes=4096)
    assert reserve_path(tmp_path, "r").stat().st_size == 4096
    for i in range(5):
        rec.append(ping_for(hw, i))
    assert rec.n_recorded == 5 and rec.n_flushed == 0
    assert rec.info()["n_pings"] == 0 and rec.info()["last"] == -1
    assert rec.recorded(0, 100) == []
    rec.flush()
    assert rec.n_flushed == 5 and rec.recorded(0, 100) == [0, 1, 2, 3, 4]
    assert rec.info()["first"] == 0 and rec.info()["last"] == 4
    for i in range(5, 17):                # the 10th after the flush flushes by itself
        rec.append(ping_for(hw, i))
    assert rec.n_flushed == 15 and rec.info()["last"] == 14
    assert rec.recorded(10, 100) == list(range(10, 15))
    rec.close({"counters": {"recorded": 17}})
    assert rec.n_flushed == 17 and not reserve_path(tmp_path, "r").exists()
    with RawRunReader(tmp_path / "r_000.h5") as r:
        assert len(r) == 17 and r.summary == {"counters": {"recorded": 17}}
