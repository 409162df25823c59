"""svss batch with faults in its input (issue 27, items 7 and 10): a corrupted ping no
longer fails the tiles it lies in (the run is planned again without it, as svss process
images it), a failure says whether a rerun can help, and a batch over some runs of a
survey keeps the others in the survey index and the state."""

from __future__ import annotations

import errno
import json
import shutil

import h5py
import pandas as pd
import pytest

from svss_daq.rawfile import RawFileError
from svss_proc.batch.run import STATE, BatchError, run_batch
from svss_proc.batch.task import image_tile
from svss_proc.survey_index import INDEX_NAME
from svss_proc.tiles import read_tile_header
from tests.batch.conftest import assert_same_products
from tests.worker.conftest import assert_same_tiles

pytest.importorskip("distributed")

#: the ping of run A whose samples are corrupted: it lies in two of its three tiles
BAD = 15


@pytest.fixture(scope="module")
def corrupted(survey, coarse_proc, tmp_path_factory) -> dict:
    """Run A with ping 15's samples beyond the 24-bit ADC range (a corrupted ping: the
    file is otherwise whole), and svss process's tiles of it."""
    from svss_proc.run_worker import process_raw
    d = tmp_path_factory.mktemp("corrupted")
    path = d / "lineA.h5"
    shutil.copy(survey["A"], path)
    with h5py.File(path, "a") as f:
        f["Sonar/Beam_group1/backscatter_r"][BAD, 0, :10] = 1 << 27
    ref = d / "process"
    process_raw(path, ref, coarse_proc)
    manifest = json.loads((ref / "manifest.json").read_text())
    assert manifest["pings_refused"] == 1, manifest
    return {"path": path, "ref": ref, "manifest": manifest}


@pytest.mark.slow
def test_a_corrupted_ping_is_refused_as_svss_process_refuses_it(corrupted, survey,
                                                                coarse_proc, client,
                                                                tmp_path):
    """The hostile tester's run: 2 of 3 tiles failed, "a rerun makes the rest". Here
    also the survey's other run is batched first into the same folder: a batch over a
    subset of the runs keeps it in the index and the state."""
    out = tmp_path / "out"
    run_batch(survey["B_segments"], out, coarse_proc, client=client, kernel_threads=1)
    s = run_batch([corrupted["path"]], out, coarse_proc, client=client, kernel_threads=1)
    assert s["failed"] == 0 and s["excluded_pings"] == 1
    assert s["imaged"] == len(list(corrupted["ref"].glob("tile_*.h5")))
    assert_same_tiles(corrupted["ref"], out / "lineA")
    assert_same_products(corrupted["ref"], out / "lineA") > 0     # across the seams
    state = json.loads((out / STATE).read_text())
    a = state["runs"]["lineA"]
    assert a["refused"] == corrupted["manifest"]["refused"]
    assert [(e["file"], e["index"]) for e in a["excluded_pings"]] == \
        [(str(corrupted["path"]), BAD)]
    assert "ADC range" in a["excluded_pings"][0]["reason"]
    # item 10: the survey index and the state still hold run B
    assert set(state["runs"]) == {"lineA", "lineB"} and state["complete"]
    df = pd.read_csv(out / INDEX_NAME)
    assert set(df["run_id"]) == {"lineA", "lineB"}
    assert sorted(df["file"]) == sorted(str(p.relative_to(out))
                                        for p in out.glob("*/tile_*.h5"))
    for tile in (out / "lineA").glob("tile_*.h5"):      # (process refused it too)
        assert BAD not in read_tile_header(tile)["ping_sequence"]
    # a rerun knows the refused ping from the state: nothing to image, nothing fails
    again = run_batch([corrupted["path"]], out, coarse_proc, client=client,
                      kernel_threads=1)
    assert (again["imaged"], again["failed"], again["excluded_pings"]) == (0, 0, 1)
    assert set(pd.read_csv(out / INDEX_NAME)["run_id"]) == {"lineA", "lineB"}


class FailTiles:
    """The tile task, except that tile ``damaged`` of run ``run_id`` meets a damaged
    file and tile ``full`` a full disk."""

    def __init__(self, run_id: str, damaged: int, full: int):
        self.run_id, self.damaged, self.full = run_id, damaged, full

    def __call__(self, plan, out, processing, kernel_threads, **kw):
        if plan.run_id == self.run_id and plan.index == self.damaged:
            raise RawFileError(f"{plan.ranges[0][0]}: damaged: a test's damaged file")
        if plan.run_id == self.run_id and plan.index == self.full:
            raise OSError(errno.ENOSPC, "No space left on device")
        return image_tile(plan, out, processing, kernel_threads, **kw)


def test_failures_say_whether_a_rerun_can_make_the_tile(survey, coarse_proc, client,
                                                       tmp_path):
    out = tmp_path / "out"
    from svss_proc.batch.plan import plan_run
    first, second = [t.index for t in plan_run("lineA", "lineA", [survey["A"]],
                                                coarse_proc).tiles][:2]
    with pytest.raises(BatchError) as err:
        run_batch([survey["A"]], out, coarse_proc, client=client, kernel_threads=1,
                  task=FailTiles("lineA", first, second))
    msg = str(err.value)
    assert "a rerun makes the rest" not in msg
    fixed, again = msg.split("fail the same way on every rerun", 1)[1].split(
        "a rerun, once it is fixed", 1)
    assert f"tile {first} " in fixed and "damaged" in fixed and f"tile {second} " not in fixed
    assert f"tile {second} " in again and "No space left" in again
    assert not json.loads((out / STATE).read_text())["complete"]


def test_a_refused_ping_is_no_compute_failed_error_in_the_workers_logs(client):
    """Dask logs a "Compute Failed" error with a traceback for every task that raises;
    a tile finding a ping refused raises PingsRefused so that the batch plans the run
    again, which is no failure: the batch's filter, installed in the workers, drops
    that error and only that one (a batch of the corrupted run logged one per tile)."""
    import logging

    from svss_proc.batch.run import ExpectedFailureFilter, _quiet_expected_failures
    from svss_proc.batch.task import PingsRefused

    def record(exc: BaseException) -> logging.LogRecord:
        return logging.LogRecord(
            "distributed.worker", logging.ERROR, __file__, 1,
            "Compute Failed\nKey:       %s\nState:     %s\nTask:  %s\nException: %r\n"
            "Traceback: %r\n", ("tile-lineA-0", "executing", "<Task ...>", repr(exc),
                                "  File ..."), None)

    refused = PingsRefused([("a.h5", 3, 3, "ADC range")], "run lineA tile 0: ")
    f = ExpectedFailureFilter()
    assert not f.filter(record(refused))
    assert f.filter(record(OSError(28, "No space left on device")))
    assert f.filter(logging.LogRecord("distributed.worker", logging.INFO, __file__, 1,
                                      "Starting Worker plugin %s", ("x",), None))
    # installed in the session's real worker processes, once each however often asked
    _quiet_expected_failures(client)
    _quiet_expected_failures(client)
    counts = client.run(lambda: sum(isinstance(x, ExpectedFailureFilter) for x in
                                    logging.getLogger("distributed.worker").filters))
    assert counts and set(counts.values()) == {1}, counts
