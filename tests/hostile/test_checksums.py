"""Recordings that cannot be silently wrong: every ping's samples and every tile volume
carry HDF5's Fletcher-32 checksum. A raw run with 4 KiB inside one ping's samples
overwritten on disk by other in-range samples (what a bad sector or a stray write
leaves) names the damaged ping (file, ping, dataset) on reading; ``svss process``
refuses it and images the rest; the catch-up service does not serve it; replay's gate
refuses it; ``svss inspect --verify`` finds it; a damaged tile is refused naming its
dataset; files written before checksums read on, saying they cannot be verified."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from svss_daq.catchup_stores import RawRunStore
from svss_daq.ping_gate import PingGate
from svss_daq.rawfile import BEAM, RawRunReader
from svss_proc.tiles import TileFileError, read_tile, verify_tile, write_tile
from tests.hostile.conftest import ROOT, small_tile, write_run

DAMAGED = 20
N_PINGS = 40


def svss(*args, timeout=600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "svss", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, env=env)


def overwrite(path: Path, dataset: str, chunk: int, nbytes: int = 4096,
              with_chunk: int | None = None) -> None:
    """Overwrite ``nbytes`` in the middle of chunk ``chunk`` (in storage order) of
    ``dataset`` with the bytes at the same place of chunk ``with_chunk`` (None: from the
    chunk's own start): other in-range values of the same kind, as a stray write or a
    remapped sector leaves them. No check of the values can see it."""
    with h5py.File(path, "r") as f:
        ds = f[dataset]
        info = ds.id.get_chunk_info(chunk)
        src = ds.id.get_chunk_info(with_chunk) if with_chunk is not None else None
    mid = info.size // 2
    with open(path, "rb") as fh:
        fh.seek(src.byte_offset + mid if src is not None else info.byte_offset)
        data = fh.read(nbytes)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + mid)
        fh.write(data)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """The demo scene's first 40 pings, as ``svss simulate`` records them."""
    d = tmp_path_factory.mktemp("checksums")
    scene = (ROOT / "config/scenes/demo.toml").read_text()
    scene = re.sub(r"(?m)^n_pings = \d+", f"n_pings = {N_PINGS}", scene)
    (d / "scene.toml").write_text(scene)
    r = svss("simulate", "--scene", d / "scene.toml", "--out", d / "run.h5")
    assert r.returncode == 0, r.stderr
    return d / "run.h5"


@pytest.fixture(scope="module")
def damaged(recorded, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("damaged") / "run.h5"
    path.write_bytes(recorded.read_bytes())
    overwrite(path, f"{BEAM}/backscatter_r", DAMAGED, with_chunk=DAMAGED - 1)
    return path


def test_a_damaged_ping_is_named_and_the_rest_reads(damaged, recorded):
    with RawRunReader(damaged) as r, RawRunReader(recorded) as clean:
        assert r.verifiable and len(r) == N_PINGS
        for i in range(N_PINGS):
            p = r.ping(i)
            if i == DAMAGED:
                assert p.damage is not None and not p.samples.any()
                for part in (str(damaged), f"ping {DAMAGED} (sequence {p.sequence})",
                             f"'/{BEAM}/backscatter_r'", "Fletcher-32"):
                    assert part in p.damage
            else:
                assert p.damage is None
                assert np.array_equal(p.samples, clean.ping(i).samples)
        found = r.verify()
        assert len(found) == 1 and f"ping {DAMAGED} " in found[0]
        assert clean.verify() == []
        # every gate refuses it (replay's among them), saying why
        gate = PingGate(r.hardware, name="test")
        assert not gate.admit(r.ping(DAMAGED)) and gate.admit(r.ping(0))
        assert any(k.startswith("damaged on disk") for k in gate.refused)


def test_the_catch_up_service_does_not_serve_a_damaged_ping(damaged):
    with RawRunStore([damaged]) as store:
        run = store.run_ids()[0]
        seqs = store.sequences(run, 0, 10 ** 9)
        assert len(seqs) == N_PINGS
        served = {q for q in seqs if store.read(run, q) is not None}
        assert len(served) == N_PINGS - 1


def test_inspect_verify_names_the_damage_and_old_files_say_they_cannot(damaged, recorded,
                                                                       tmp_path):
    bad = svss("inspect", "--verify", damaged)
    assert bad.returncode == 1 and f"ping {DAMAGED} " in bad.stdout, bad.stdout + bad.stderr
    assert "backscatter_r" in bad.stdout
    good = svss("inspect", "--verify", recorded)
    assert good.returncode == 0 and "no damage" in good.stdout
    # a run recorded before checksums: the same samples without the filter
    old = tmp_path / "old.h5"
    old.write_bytes(recorded.read_bytes())
    with h5py.File(old, "r+") as f:
        ds = f[f"{BEAM}/backscatter_r"]
        data, attrs = ds[()], dict(ds.attrs)
        dims = [d[0] for d in ds.dims if len(d)]
        del f[f"{BEAM}/backscatter_r"]
        new = f[BEAM].create_dataset("backscatter_r", data=data, maxshape=(None,) +
                                     data.shape[1:], chunks=(1,) + data.shape[1:])
        for k, v in attrs.items():
            if k not in ("DIMENSION_LIST",):
                new.attrs[k] = v
        for i, d in enumerate(dims):
            new.dims[i].attach_scale(d)
    unverified = svss("inspect", "--verify", old)
    assert unverified.returncode == 3 and "cannot be verified" in unverified.stdout
    with RawRunReader(old) as r:
        assert not r.verifiable and r.ping(DAMAGED).damage is None
    summary = svss("inspect", old)
    assert summary.returncode == 0 and "cannot be verified" in summary.stdout


@pytest.mark.slow
def test_process_refuses_the_damaged_ping_and_images_the_rest(damaged, recorded, tmp_path):
    out = {}
    for name, run in (("damaged", damaged), ("clean", recorded)):
        r = svss("process", run, "--out", tmp_path / name, "--processing",
                 ROOT / "config/processing-demo.toml", "--sediment-speed", "configured",
                 "--no-renavigate")
        assert r.returncode == 0, r.stderr[-3000:]
        out[name] = (json.loads((tmp_path / name / "manifest.json").read_text()), r.stderr)
    man, log = out["damaged"]
    assert man["pings"] == N_PINGS - 1 and out["clean"][0]["pings"] == N_PINGS
    assert man["refused"] == {"damaged on disk": 1}
    assert f"ping {DAMAGED} (sequence" in log and "Fletcher-32" in log
    # svss batch: the task refuses it, the run is planned again without it
    r = svss("batch", damaged, "--out", tmp_path / "batch", "--processing",
             ROOT / "config/processing-demo.toml", "--workers", 1, "--sediment-speed",
             "configured", "--no-renavigate")
    assert r.returncode == 0, r.stderr[-3000:]
    state = json.loads((tmp_path / "batch" / "batch_state.json").read_text())["runs"]
    (run,) = state.values()
    assert run["refused"] == {"damaged on disk": 1}
    assert [(e["index"], "Fletcher-32" in e["reason"]) for e in run["excluded_pings"]] \
        == [(DAMAGED, True)]


def test_a_damaged_tile_is_refused_naming_the_dataset(hardware, small_proc, tmp_path):
    path = write_tile(tmp_path / "tile_0001.h5", small_tile(small_proc), hardware,
                      small_proc)
    assert verify_tile(path) == [] and read_tile(path)["image"].size
    with h5py.File(path, "r") as f:
        n = f["image"].id.get_num_chunks()
    overwrite(path, "image", n // 2, nbytes=256)
    with pytest.raises(TileFileError, match=r"tile_0001.h5: dataset '/image' fails its "
                                            r"Fletcher-32 checksum"):
        read_tile(path)
    assert any("'/image'" in d for d in verify_tile(path))
