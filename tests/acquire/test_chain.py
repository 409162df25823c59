"""The boat-side chain as separate processes: ``svss sim-device`` -> ``svss acquire`` ->
ZeroMQ (stream and catch-up service) -> ``svss worker``. Rotated recordings served across
segments; a worker SIGKILLed mid-run and restarted ends with every tile once, equal voxel
for voxel to ``svss process`` of the recording; counts reconcile from the device to the
worker."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, load_with_text
from svss_daq.ping_service import PingFetcher
from svss_daq.rawfile import RawRunReader
from svss_proc.tiles import read_tile
from svss_proc.run_worker import process_raw

from .conftest import CONFIG, ROOT, acquire_toml
from .test_daemon import device_stats

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="needs Linux pseudo-terminals"), pytest.mark.slow]
PROCESSING = CONFIG / "processing-demo.toml"


def coarse_processing(tmp: Path) -> Path:
    """The demo's processing on small tiles (2 x 0.4 x 0.3 m) at 4 cm voxels (a tile
    every 20 pings, a sixtieth of the demo tile's voxels): the resume logic, not the
    image, is under test here."""
    from tests.worker.conftest import small_processing_text
    path = tmp / "processing-coarse.toml"
    text = small_processing_text().replace("voxel_m = 0.02", "voxel_m = 0.04")
    assert "voxel_m = 0.04" in text
    path.write_text(text)
    return path


def test_rotated_segments_are_complete_and_served_across_files(rig, tmp_path):
    cfg = acquire_toml(tmp_path, rotation={"max_file_mib": 3.0},  # ~6 pings a segment
                       catch_up={"linger_s": 0.0})
    dev = rig.device("--time-scale", "2")
    acq = rig.acquire(dev, "--duration", "300", config=cfg)
    fetcher = PingFetcher(acq.endpoints["service"], timeout_s=10)
    deadline = time.monotonic() + 60
    while len(acq.files()) < 4 and time.monotonic() < deadline:
        time.sleep(0.2)
    # while the run goes on: pings from closed segments and the open one, by sequence
    [info] = [r for r in fetcher.runs() if r.run_id == "run1"]
    # three closed segments of at least 5 pings (3 MiB each) and the open one
    assert len(acq.files()) >= 4
    assert not info.ended and info.n_pings >= 15
    pings, missing = fetcher.fetch("run1", info.first, info.last)
    fetcher.close()
    got = [p.sequence for p in pings]
    assert len(got) == info.n_pings and got == sorted(got)
    # what is not served was never recorded (a ping the loaded device dropped)
    assert sorted(set(range(info.first, info.last + 1)) - set(got)) == \
        [q for a, b in missing for q in range(a, b + 1)]
    assert acq.stop() == 130                     # SIGTERM: flushed, closed, summarised
    files = acq.files()
    assert len(files) >= 4
    seqs, segments = [], []
    for f in files:
        with RawRunReader(f) as run:
            assert run.clean and run.attrs["run_id"] == "run1"
            segments.append(int(run.attrs["segment"]))
            assert f.stat().st_size <= 3.0 * 2**20 + 100_000      # plus its metadata
            seqs += run.ping_table()["ping_sequence"].tolist()
            summary = run.summary
    assert segments == list(range(len(files)))
    assert seqs == sorted(set(seqs)) and summary["counters"]["recorded"] == len(seqs)
    assert set(got) <= set(seqs) and not set(missing) & set(seqs)
    by_seq = {p.sequence: p for p in pings}
    with RawRunReader(files[0]) as run:
        first = run.ping(0)
    np.testing.assert_array_equal(by_seq[first.sequence].samples, first.samples)
    assert by_seq[first.sequence].nav == first.nav
    device_stats(dev)


def _worker(tmp: Path, endpoints: dict, out: Path) -> subprocess.Popen:
    log = open(tmp / "worker.log", "ab")
    return subprocess.Popen(
        [sys.executable, "-m", "svss", "worker", "--connect", endpoints["publisher"],
         "--service", endpoints["service"], "--out", str(out), "--processing",
         str(coarse_processing(tmp)), "--runs", "1", "--idle-timeout", "120"],
        stdout=subprocess.DEVNULL, stderr=log, cwd=ROOT)


@pytest.fixture(scope="module")
def warm_kernels(tmp_path_factory, hardware):
    """Compile (or load from numba's disk cache) the imaging and product kernels once,
    so that a worker process is not still compiling when the run it should image ends."""
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_proc.run_worker import Worker
    src = EnvironmentSource(hardware, load_scene(CONFIG / "scenes" / "demo.toml"))
    warm = tmp_path_factory.mktemp("warm")
    worker = Worker(hardware, load_with_text(ProcessingConfig, coarse_processing(warm)),
                    warm / "tiles")
    worker.run(src.ping(k) for k in range(30, 34))


def test_worker_killed_mid_run_resumes_every_tile_once(rig, tmp_path, warm_kernels):
    # a run of 8 s (6 tiles, the first written at its 36th ping); the daemon keeps its
    # catch-up service up while the restarted worker still fetches (catch_up.linger_s)
    cfg = acquire_toml(tmp_path, catch_up={"linger_s": 60.0, "max_linger_s": 300.0})
    dev = rig.device()
    acq = rig.acquire(dev, "--pings", "80", "--wait-subscribers", "1", config=cfg)
    out = tmp_path / "tiles"
    worker = _worker(tmp_path, acq.endpoints, out)
    run_dir = out / "run1"
    deadline = time.monotonic() + 120
    while not list(run_dir.glob("tile_*.h5")) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert list(run_dir.glob("tile_*.h5")), (tmp_path / "worker.log").read_text()[-3000:]
    worker.send_signal(signal.SIGKILL)           # mid-run: tiles open, pings in flight
    worker.wait(10)
    time.sleep(1.0)                              # pings go by meanwhile
    worker = _worker(tmp_path, acq.endpoints, out)
    try:
        assert worker.wait(240) == 0, (tmp_path / "worker.log").read_text()[-3000:]
    finally:
        if worker.poll() is None:
            worker.kill()
    # the worker has the whole run: the daemon, still serving catch-up, is stopped (a
    # signal during the linger ends it normally)
    assert acq.stop() in (0, 130), acq.logs()[-3000:]
    stats = device_stats(dev)
    [raw] = acq.files()
    with RawRunReader(raw) as run:
        n = len(run)
        summary = run.summary
    # device -> daemon -> file -> worker
    assert stats["pings_sent"] == summary["counters"]["delivered"] == n >= 80
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["complete"]
    # every tile once, equal voxel for voxel to svss process of the recording (with the
    # poses recorded live: by default svss process re-navigates); `svss process` here
    # in-process (its command line: tests/acquire/test_renavigation.py)
    again = tmp_path / "again"
    process_raw(raw, again, load_with_text(ProcessingConfig, coarse_processing(tmp_path)),
                renavigate=False)
    live = sorted(p.name for p in run_dir.glob("tile_*.h5"))
    ref = sorted(p.name for p in again.glob("tile_*.h5"))
    assert live == ref and len(live) >= 3
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".")]
    pings_in_tiles = set()
    for name in live:
        a, b = read_tile(run_dir / name), read_tile(again / name)
        np.testing.assert_array_equal(a["ping_sequence"], b["ping_sequence"])
        np.testing.assert_array_equal(a["image"], b["image"])
        pings_in_tiles |= set(a["ping_sequence"].tolist())
    with RawRunReader(raw) as run:
        assert pings_in_tiles == set(run.ping_table()["ping_sequence"].tolist())
