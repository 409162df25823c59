"""A raw run with one per-ping dataset shortened (issue 27, item 7): ``svss inspect`` and
``svss process`` read it as a 3-ping run, exit 0, no warning. Now a clear error naming
the file and the dataset."""

from __future__ import annotations

import h5py
import pytest

from svss_daq.rawfile import FLUSHED, RawFileError, RawRunReader

from .conftest import svss_calls, write_run


def _shorten(path, name: str, n: int, drop_count: bool = False):
    with h5py.File(path, "a") as f:
        f[name].resize(n, axis=0)
        if drop_count:
            del f[FLUSHED]
    return path


@pytest.mark.parametrize("name", ["Platform/north_m", "Sonar/Beam_group1/ping_sequence",
                                  "Sonar/Beam_group1/backscatter_r"])
@pytest.mark.parametrize("drop_count", [False, True], ids=["counted", "older-file"])
def test_a_shortened_dataset_is_a_damaged_file(tmp_path, hardware, name, drop_count):
    path = _shorten(write_run(tmp_path / "run.h5", hardware, n_pings=12), name, 3,
                    drop_count)
    with pytest.raises(RawFileError) as err:
        RawRunReader(path)
    msg = str(err.value)
    assert str(path) in msg and f"dataset '/{name}' has 3 entries" in msg and \
        "damaged" in msg, msg


def test_inspect_and_process_refuse_the_shortened_run(tmp_path, hardware):
    """The hostile tester's reproduction: north_m 3 of the run's entries."""
    path = _shorten(write_run(tmp_path / "run.h5", hardware, n_pings=12),
                    "Platform/north_m", 3)
    calls = (("inspect", path), ("process", path, "--out", tmp_path / "tiles",
                                 "--no-renavigate"))
    for args, res in zip(calls, svss_calls(*calls, timeout=180)):
        assert res.returncode == 2, (args[0], res.returncode, res.stderr[-2000:])
        assert f"{path}: damaged: dataset '/Platform/north_m' has 3 entries" in res.stderr, \
            res.stderr[-2000:]
        assert "Traceback" not in res.stderr


def test_a_longer_dataset_in_a_closed_file_is_damaged_too(tmp_path, hardware):
    path = write_run(tmp_path / "run.h5", hardware, n_pings=6)
    with h5py.File(path, "a") as f:
        f["Platform/east_m"].resize(9, axis=0)
    with pytest.raises(RawFileError, match=r"dataset '/Platform/east_m' has 9 entries, "
                                           r"the run was closed with 6 pings"):
        RawRunReader(path)


def test_a_killed_writer_is_still_read_to_its_last_flush(tmp_path, hardware):
    """Datasets longer than the flushed count (pings appended after the last flush of a
    writer that died) are what SWMR leaves: read, not refused."""
    from .test_files import killed_run
    path = killed_run(tmp_path / "killed.h5", flushed=4, appended=7)
    with RawRunReader(path) as r:
        assert len(r) == 4 and not r.clean and r.truncated == 0
