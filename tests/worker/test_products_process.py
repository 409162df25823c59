"""The full products in a second process beside the imaging (daq.toml ``[worker] products
= "process"``; svss_proc/products_process.py): the same tile files as inline, every
tile written even when the process is killed, the journal counting handed-over tiles as
not written. Real spawned processes, real HDF5."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text
from svss_daq.rawfile import RawRunReader
from svss_proc.products_process import PROCESS_STAGE, ProductsProcess
from svss_proc.run_folder import JOURNAL
from svss_proc.run_worker import Worker
from svss_proc.tiles import read_tile_header

from .conftest import ROOT, small_processing_text


@pytest.fixture(scope="module")
def hw_loaded():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


@pytest.fixture(scope="module")
def proc_products(tmp_path_factory):
    """The small tiles of the worker tests with the demo's products on (background,
    detections, quick look)."""
    p = tmp_path_factory.mktemp("config") / "small-products.toml"
    p.write_text(small_processing_text())
    return load_with_text(ProcessingConfig, p)


@pytest.fixture(scope="module")
def pings(raw_run):
    with RawRunReader(raw_run) as r:
        return list(r)


def _datasets(path) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()])
                     if isinstance(obj, h5py.Dataset) else None)
    return out


def _run(hw, proc, out, pings, offload=None, run_id=None):
    w = Worker(hw, proc, out, run_id=run_id, live=True)
    w.offload = offload
    for p in pings:
        w.add(p)
    return w, w.finish()


def test_the_products_process_writes_what_inline_writes(hw_loaded, proc_products, pings,
                                                        tmp_path):
    _, inline = _run(hw_loaded, proc_products, tmp_path / "inline", pings)
    pp = ProductsProcess(hw_loaded, proc_products, threads=1, nice=5)
    try:
        w, side = _run(hw_loaded, proc_products, tmp_path / "process", pings, pp)
        # it has made tiles, so it has lowered its priority: the imaging goes first
        assert (os.getpriority(os.PRIO_PROCESS, pp._proc.pid)
                == min(os.getpriority(os.PRIO_PROCESS, 0) + 5, 19))
    finally:
        pp.close()
    names = sorted(p.name for p in inline)
    assert sorted(p.name for p in side) == names
    tiles = [n for n in names if n.endswith(".h5")]
    assert len(tiles) >= 3                      # several tiles: the seams passed on
    for name in tiles:
        a, b = _datasets(tmp_path / "inline" / name), _datasets(tmp_path / "process" / name)
        assert sorted(a) == sorted(b)
        assert {"background", "drc", "detections/peak_db", "image"} <= set(a)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name}: {k}")
    # the child's time came back: one job per tile, and the chain's stages
    st = w.clock.totals()
    assert st[PROCESS_STAGE]["calls"] == len(tiles)
    assert st["products.chain"]["calls"] == len(tiles)
    man = json.loads((tmp_path / "process" / "manifest.json").read_text())
    assert sorted(man["files"]) == names


def test_a_killed_products_process_loses_no_tile(hw_loaded, proc_products, pings, tmp_path,
                                                 caplog):
    out = tmp_path / "run"
    pp = ProductsProcess(hw_loaded, proc_products, threads=1)
    w = Worker(hw_loaded, proc_products, out, run_id="line1", live=True)
    w.offload = pp
    w.max_in_flight = 100               # keep what is handed over in flight
    try:
        it = iter(pings)
        for p in it:                    # until a tile is handed over
            w.add(p)
            if w.in_flight:
                break
        assert w.in_flight, "no tile was completed"
        job, tile, _ = w.in_flight[0]
        journal = json.loads((out / JOURNAL).read_text())
        # handed over, not written: not in the journal's written tiles, resumed from
        assert tile.grid.index not in journal["written"]
        assert journal["resume_sequence"] <= tile.pings[0]
        os.kill(pp._proc.pid, signal.SIGKILL)
        pp._proc.join(60)                # the condition, not a time
        assert not pp._proc.is_alive()
        with caplog.at_level("ERROR"):
            for p in it:
                w.add(p)
            files = w.finish()
    finally:
        pp.close()
    assert w.offload is None and not w.in_flight
    assert "products process" in caplog.text and "made here instead" in caplog.text
    tiles = sorted(p for p in files if p.suffix == ".h5")
    assert len(tiles) >= 3
    for t in tiles:
        read_tile_header(t)                 # a whole, readable tile file
    journal = json.loads((out / JOURNAL).read_text())
    assert journal["complete"]
    assert sorted(journal["written"]) == sorted(
        int(t.stem.split("_")[1]) for t in tiles)


def _running(pid: int) -> bool:
    """``pid`` exists and is not a zombie (an orphan's parent may not reap it at once)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def worker_script(tmp_path: Path, then: str) -> Path:
    """A worker script: it starts a products process, prints its pid, then runs the
    lines ``then``."""
    script = tmp_path / "worker.py"
    script.write_text(
        "import sys, time\n"
        "from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, "
        "load_with_text\n"
        "from svss_proc.products_process import ProductsProcess\n"
        "if __name__ == '__main__':\n"
        "    pp = ProductsProcess(load_with_text(HardwareConfig, config_path('hardware.toml')),"
        " load_with_text(ProcessingConfig, config_path('processing.toml')))\n"
        "    pp._start()\n"
        "    print(pp._proc.pid, flush=True)\n" + then)
    return script


def test_the_products_process_leaves_when_its_worker_is_killed(tmp_path):
    """A worker killed with SIGKILL cannot tell its products process to leave: the
    process sees it gone and leaves by itself, rather than living on as an orphan."""
    script = worker_script(tmp_path, "    time.sleep(3600)\n")
    worker = subprocess.Popen([sys.executable, str(script)], cwd=ROOT,
                              stdout=subprocess.PIPE, text=True)
    try:
        child = int(worker.stdout.readline())
        assert _running(child)
    finally:
        worker.kill()
        worker.wait()
    deadline = time.monotonic() + 60           # the condition, with a generous bound
    while _running(child) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _running(child), f"products process {child} outlived its killed worker"


def test_a_worker_leaving_without_closing_it_exits_and_takes_it_along(tmp_path):
    """A worker on its way out without closing its products process (an exception in
    its run): multiprocessing's exit handler would wait for ever on a child that
    ignores its SIGTERM while the worker, still alive, holds the jobs pipe open. The
    worker exits, and the child with it."""
    script = worker_script(
        tmp_path,
        # once the child ignores SIGTERM (earlier, multiprocessing's SIGTERM ends it)
        "    deadline = time.monotonic() + 60\n"
        "    while time.monotonic() < deadline:\n"
        "        st = open(f'/proc/{pp._proc.pid}/status').read()\n"
        "        ign = int(st.split('SigIgn:')[1].split()[0], 16)\n"
        "        if ign & (1 << 14):\n"
        "            break\n"
        "        time.sleep(0.05)\n"
        "    raise SystemExit('leaving without pp.close()')\n")
    res = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 1 and "leaving without" in res.stderr, res.stderr[-2000:]
    assert "closing it" in res.stderr
    child = int(res.stdout.split()[0])
    deadline = time.monotonic() + 30
    while _running(child) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _running(child), f"products process {child} outlived its worker"
