"""Fixtures of the tile-worker tests: a short simulated run recorded to a raw file (and
its first 30 pings as a run of their own), a small processing configuration (2 m tiles,
no products) and their `svss process` tiles."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load_with_text
from svss_proc.tiles import read_tile
from tests.computed_once import computed_once

ROOT = Path(__file__).resolve().parents[2]
N_PINGS = 90                       # 9 s at 10 pings/s
#: pings of :func:`short_run`: 3 m, so that no tile closes before the run ends
N_SHORT = 30


def small_processing_text() -> str:
    text = Path(config_path("processing-demo.toml")).read_text()
    new = (text.replace("length_m = 3.0", "length_m = 2.0")
           .replace("width_m = 1.2", "width_m = 0.4").replace("depth_m = 1.0", "depth_m = 0.3"))
    assert new != text
    return new


def stream_processing_text() -> str:
    """:func:`small_processing_text` without its ``[products]`` tables: what the worker
    tests compare with `svss process`'s tiles is each tile's pings and image (the
    products are the same code after either, tested in tests/products), and a tile's
    products quicklook costs more than imaging its pings."""
    head, sep, _ = small_processing_text().partition("\n[products]")
    assert sep
    return head + "\n"


@pytest.fixture(scope="session")
def small_proc_path(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("config") / "small-processing.toml"
    p.write_text(stream_processing_text())
    return p


@pytest.fixture(scope="session")
def small_proc(small_proc_path):
    return load_with_text(ProcessingConfig, small_proc_path)


def simulate(path: Path, n_pings: int = N_PINGS, run_attrs: dict | None = None,
             skip: frozenset = frozenset()) -> Path:
    """The demo scene's first ``n_pings`` pings recorded to ``path`` (sequences in
    ``skip`` left out: a recording with holes)."""
    import itertools

    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import HardwareConfig
    from svss_daq.rawfile import RawRunWriter
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    with RawRunWriter(path, hw, run_attrs=run_attrs or {}) as rec:
        for p in itertools.islice(iter(EnvironmentSource(hw, scene)), n_pings):
            if p.sequence not in skip:
                rec.append(p)
    return path


def write_pings(path: Path, pings, run_attrs: dict | None = None) -> Path:
    """``pings`` recorded to ``path`` (a clean raw run)."""
    from svss_daq.config import HardwareConfig
    from svss_daq.rawfile import RawRunWriter
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    with RawRunWriter(path, hw, run_attrs=run_attrs or {}) as rec:
        for p in pings:
            rec.append(p)
    return path


@pytest.fixture(scope="session")
def raw_run(tmp_path_factory) -> Path:
    return computed_once(tmp_path_factory, "worker-raw_run",
                         lambda: simulate(tmp_path_factory.mktemp("raw") / "line1.h5"))


@pytest.fixture(scope="session")
def short_run(tmp_path_factory) -> Path:
    """The demo scene's first :data:`N_SHORT` pings (those of :func:`raw_run`: the
    simulation is seeded) as run "line1": for the tests whose point needs no tile
    closed mid-run (a third of the imaging of :func:`raw_run`)."""
    return computed_once(tmp_path_factory, "worker-short_run", lambda: simulate(
        tmp_path_factory.mktemp("short") / "line1.h5", N_SHORT))


@pytest.fixture(scope="session")
def first_pings(short_run) -> list:
    """The pings of :func:`short_run`."""
    from svss_daq.rawfile import RawRunReader
    with RawRunReader(short_run) as r:
        return list(r)


@pytest.fixture(scope="session")
def processed(raw_run, small_proc, tmp_path_factory) -> Path:
    """`svss process` of the raw run (in process: the same function)."""
    from svss_proc.run_worker import process_raw

    def run():
        out = tmp_path_factory.mktemp("processed")
        process_raw(raw_run, out, small_proc)
        return out
    return computed_once(tmp_path_factory, "worker-processed", run)


@pytest.fixture(scope="session")
def short_processed(short_run, small_proc, tmp_path_factory) -> Path:
    """`svss process` of :func:`short_run` (in process: the same function)."""
    from svss_proc.run_worker import process_raw

    def run():
        out = tmp_path_factory.mktemp("short-processed")
        process_raw(short_run, out, small_proc)
        return out
    return computed_once(tmp_path_factory, "worker-short_processed", run)


def svss(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "svss", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def assert_same_tiles(ref: Path, got: Path) -> None:
    """Same tile files, each with the same pings and the same image, voxel for voxel."""
    want = sorted(p.name for p in ref.glob("tile_*.h5"))
    have = sorted(p.name for p in got.glob("tile_*.h5"))
    assert want and have == want, (want, have)
    for name in want:
        a, b = read_tile(ref / name), read_tile(got / name)
        np.testing.assert_array_equal(a["ping_sequence"], b["ping_sequence"])
        np.testing.assert_array_equal(a["image"], b["image"])
    assert not [p for p in got.iterdir() if ".partial" in p.name]
