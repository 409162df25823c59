"""Fixtures of the tile-worker tests: a short simulated run recorded to a raw file, a
small processing configuration (2 m tiles) and its `svss process` tiles."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load_with_text
from svss_proc.tiles import read_tile

ROOT = Path(__file__).resolve().parents[2]
N_PINGS = 90                       # 9 s at 10 pings/s


def small_processing_text() -> str:
    text = Path(config_path("processing-demo.toml")).read_text()
    new = (text.replace("length_m = 3.0", "length_m = 2.0")
           .replace("width_m = 1.2", "width_m = 0.4").replace("depth_m = 1.0", "depth_m = 0.3"))
    assert new != text
    return new


@pytest.fixture(scope="session")
def small_proc_path(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("config") / "small-processing.toml"
    p.write_text(small_processing_text())
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


@pytest.fixture(scope="session")
def raw_run(tmp_path_factory) -> Path:
    return simulate(tmp_path_factory.mktemp("raw") / "line1.h5")


@pytest.fixture(scope="session")
def processed(raw_run, small_proc, tmp_path_factory) -> Path:
    """`svss process` of the raw run (in process: the same function)."""
    from svss_proc.worker import process_raw
    out = tmp_path_factory.mktemp("processed")
    process_raw(raw_run, out, small_proc)
    return out


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
