"""svss batch on a LocalCluster of two worker processes on loopback: the tiles of a
two-run survey equal `svss process`'s voxel for voxel, also when a worker process is
killed mid-run; a rerun skips finished tiles and redoes a half-written one; the survey
index lists every tile as its file says; bad raw files are named."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_daq.rawfile import RawFileError
from svss_proc.batch.plan import plan_run
from svss_proc.batch.run import STATE, run_batch
from svss_proc.batch.task import image_tile
from svss_proc.survey_index import INDEX_NAME
from svss_proc.tiles import read_detections, read_tile_header
from tests.batch.conftest import assert_same_products, seam_attrs
from tests.worker.conftest import assert_same_tiles

pytest.importorskip("distributed")

RUNS = ("lineA", "lineB")
#: the delays the batch's processing (processing-demo.toml's) names
DEMO_DELAYS = load(ProcessingConfig, config_path("processing-demo.toml")).imaging.delays


class KillOnce:
    """The tile task, except that the first task of run ``run_id`` kills its own worker
    process (SIGKILL) once, before imaging: the marker file records the pid."""

    def __init__(self, marker: Path, run_id: str):
        self.marker, self.run_id = str(marker), run_id

    def __call__(self, plan, out, processing, kernel_threads, **kw):
        if plan.run_id == self.run_id:
            try:
                fd = os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                pass
            else:
                os.write(fd, f"{os.getpid()} {plan.index}".encode())
                os.close(fd)
                os.kill(os.getpid(), signal.SIGKILL)
        return image_tile(plan, out, processing, kernel_threads, **kw)


@pytest.fixture(scope="module")
def batch(survey, coarse_proc, client, tmp_path_factory) -> dict:
    """The survey batched (run B's segments given out of order), one worker killed."""
    d = tmp_path_factory.mktemp("batch")
    marker = d / "killed"
    out = d / "out"
    files = [survey["A"], *reversed(survey["B_segments"])]
    summary = run_batch(files, out, coarse_proc, client=client, kernel_threads=1,
                        task=KillOnce(marker, "lineB"))
    return {"out": out, "summary": summary, "marker": marker}


@pytest.mark.slow
def test_tiles_equal_svss_process_voxel_for_voxel(batch, reference):
    """Images and products, these across the seams (products.background.across_seams,
    the default): each tile's products take the neighbouring tiles' planes and the
    previous tile's contacts, as svss process's do."""
    # the tasks' kernels ran on one thread each (as svss batch's on 2 cores), svss
    # process's on every core: the tiles must not depend on it
    assert {r["kernel_threads"] for r in batch["summary"]["results"]} == {1}
    seams = 0
    for run in RUNS:
        assert_same_tiles(reference[run], batch["out"] / run)
        seams += assert_same_products(reference[run], batch["out"] / run)
        for ref in sorted(reference[run].glob("tile_*.h5")):
            got = batch["out"] / run / ref.name
            a, b = read_detections(ref)[0], read_detections(got)[0]
            assert a.dtype == b.dtype, ref.name
            for name in a.dtype.names:                # NaN where a field is undefined
                np.testing.assert_array_equal(a[name], b[name], err_msg=ref.name)
            assert got.with_name(ref.stem + "_mip.png").is_file()
        # the run products, as the streaming worker writes them at a run's end; the
        # contacts name the batch's run (run B's reference is its whole file, whose run
        # id is its stem)
        got, want = (p.read_text().splitlines() for p in (
            batch["out"] / run / "contacts.csv", reference[run] / "contacts.csv"))
        assert len(got) == len(want) > 1 and got[0] == want[0]
        col = got[0].split(",").index("run_id")
        ref_id = {"lineA": "lineA", "lineB": "lineB-whole"}[run]
        for g, w in zip(got[1:], want[1:]):
            g, w = g.split(","), w.split(",")
            assert (g[col], w[col]) == (run, ref_id)
            assert g[:col] + g[col + 1:] == w[:col] + w[col + 1:]
        assert (batch["out"] / run / "mosaic.h5").is_file()
    # every seam inside a run, both ways (8: the runs' 6 tiles have 4 seams)
    n_seams = sum(len(list(reference[run].glob("tile_*.h5"))) - 1 for run in RUNS)
    assert seams == 2 * n_seams == 8


def test_killed_worker_leaves_no_missing_tile(batch, reference):
    pid, index = map(int, batch["marker"].read_text().split())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)                               # that worker process is gone
    s = batch["summary"]
    n_ref = sum(len(list(reference[r].glob("tile_*.h5"))) for r in RUNS)
    assert (s["tiles"], s["imaged"], s["failed"], s["skipped"]) == (n_ref, n_ref, 0, 0)
    made = [r for r in s["results"] if (r["run_id"], r["index"]) == ("lineB", index)]
    assert len(made) == 1 and made[0]["pid"] != pid and not made[0]["skipped"]
    assert (batch["out"] / "lineB" / f"tile_{index:04d}.h5").is_file()
    assert not [p for p in batch["out"].rglob("*") if ".partial" in p.name]


def test_survey_index_lists_every_tile(batch, reference):
    import pandas as pd
    import xarray as xr
    out = batch["out"]
    df = pd.read_csv(out / INDEX_NAME)
    tiles = sorted(out.glob("*/tile_*.h5"))
    assert sorted(df["file"]) == sorted(str(p.relative_to(out)) for p in tiles)
    assert set(df["run_id"]) == set(RUNS)
    for row in df.itertuples():
        h = read_tile_header(out / row.file)
        v = float(h["attrs"]["voxel_m"])
        assert row.tile_index == int(h["attrs"]["tile_index"])
        assert row.n_pings == h["ping_sequence"].size
        assert (row.first_ping, row.last_ping) == (h["ping_sequence"].min(),
                                                   h["ping_sequence"].max())
        assert row.n_detections == len(read_detections(out / row.file)[0])
        assert row.along_min_m == pytest.approx(h["along"][0] - v / 2)
        assert row.along_max_m == pytest.approx(h["along"][-1] + v / 2)
        assert row.depth_max_m == pytest.approx(h["depth"][-1] + v / 2)
        assert row.line_heading_deg == pytest.approx(
            np.degrees(h["attrs"]["line_heading_rad"]))
        assert row.processing_config_id == h["attrs"]["processing_config_id"]
        assert row.voxel_m == 0.05 and row.delays == DEMO_DELAYS
    assert df["n_detections"].sum() == batch["summary"]["detections"]
    # runs have their own tile frames (run B starts 8 pings later)
    assert df.groupby("run_id")["line_origin_north_m"].nunique().eq(1).all()
    assert df["line_origin_north_m"].nunique() == 2
    ds = xr.Dataset.from_dataframe(df.set_index(["run_id", "tile_index"]))
    assert int(ds["n_pings"].sum()) == df["n_pings"].sum()
    # svss process writes the same index for its folder
    for run in RUNS:
        ref = pd.read_csv(reference[run] / INDEX_NAME)
        mine = df[df["run_id"] == run].reset_index(drop=True)
        cols = ["tile_index", "n_pings", "n_detections", "along_min_m",
                "line_origin_east_m", "processing_config_id"]
        pd.testing.assert_frame_equal(ref[cols], mine[cols])


@pytest.mark.slow
def test_rerun_skips_finished_tiles_and_redoes_a_half_written_one(batch, reference, survey,
                                                                  coarse_proc, cluster,
                                                                  tmp_path, capsys):
    """Through the command line, on the running cluster's scheduler (--scheduler)."""
    from svss.cli import main
    out = tmp_path / "out"
    shutil.copytree(batch["out"], out)
    redo = sorted((out / "lineA").glob("tile_*.h5"))[1]
    redo.unlink()
    redo.with_name(redo.stem + "_mip.png").unlink()
    half = redo.with_name(f".{redo.stem}.partial-0badf00d.h5")
    half.write_bytes(b"\x89HDF\r\n\x1a\n half-written")
    before = {p: p.stat().st_mtime_ns for p in out.rglob("tile_*.h5")}
    files = [str(survey["A"]), *map(str, survey["B_segments"])]
    assert main(["batch", *files, "--out", str(out), "--processing", coarse_proc.source,
                 "--scheduler", cluster.scheduler_address]) == 0
    n = len(before) + 1
    assert f"{n} tile(s) of 2 run(s) (1 imaged, {n - 1} already done)" in \
        capsys.readouterr().out
    assert not half.exists() and redo.is_file()
    assert {p: p.stat().st_mtime_ns for p in before} == before      # not rewritten
    for run in RUNS:
        assert_same_tiles(reference[run], out / run)
        # the tile redone took its neighbours' seam planes and the previous tile's
        # contacts from their files
        assert_same_products(reference[run], out / run)
    assert seam_attrs(redo)["seam_planes_before"] > 0 and \
        seam_attrs(redo)["seam_planes_after"] > 0
    assert "svss.batch_state" in (out / STATE).read_text()


def test_a_batch_over_some_runs_keeps_the_others_in_the_index(batch, survey, coarse_proc,
                                                               client, tmp_path):
    """A rerun over run A alone (issue 27, item 10): the survey index and the batch
    state still hold run B (they were rewritten to run A's tiles only)."""
    import pandas as pd
    out = tmp_path / "out"
    shutil.copytree(batch["out"], out)
    before = pd.read_csv(out / INDEX_NAME)
    s = run_batch([survey["A"]], out, coarse_proc, client=client, kernel_threads=1)
    assert (s["runs"], s["imaged"], s["index_runs"]) == (1, 0, 2)
    after = pd.read_csv(out / INDEX_NAME)
    pd.testing.assert_frame_equal(before, after)
    state = json.loads((out / STATE).read_text())
    assert set(state["runs"]) == set(RUNS) and state["complete"]
    assert state["runs"]["lineB"]["tiles"] == int((before["run_id"] == "lineB").sum())


def test_segments_plan_as_the_whole_run(survey, coarse_proc):
    whole = plan_run("w", "w", [survey["B_whole"]], coarse_proc)
    segs = plan_run("s", "s", survey["B_segments"], coarse_proc)
    assert [t.index for t in whole.tiles] == [t.index for t in segs.tiles]
    assert [t.sequences for t in whole.tiles] == [t.sequences for t in segs.tiles]
    assert whole.tiles[0].line == segs.tiles[0].line
    # a tile spanning the segment boundary reads from both files
    assert any(len({r[0] for r in t.ranges}) == 2 for t in segs.tiles)


def test_missing_or_corrupt_raw_file_is_named(survey, coarse_proc, tmp_path):
    missing = tmp_path / "nothere.h5"
    with pytest.raises(RawFileError, match=str(missing)):
        run_batch([survey["A"], missing], tmp_path / "o1", coarse_proc, workers=1)
    bad = tmp_path / "truncated.h5"
    data = survey["A"].read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(RawFileError, match=str(bad)):
        run_batch([bad], tmp_path / "o2", coarse_proc, workers=1)


def test_two_runs_of_one_name_are_refused(survey, coarse_proc, tmp_path):
    """Files of two days, both 'lineB-whole.h5' without run ids: not merged into one run."""
    a, b = tmp_path / "day1", tmp_path / "day2"
    a.mkdir(), b.mkdir()
    for d in (a, b):
        shutil.copy(survey["B_whole"], d)
    with pytest.raises(ValueError, match=r"day2/lineB-whole.h5 and .*day1/lineB-whole.h5: "
                                         r"both segment 0 of run 'lineB-whole'"):
        run_batch([a / "lineB-whole.h5", b / "lineB-whole.h5"], tmp_path / "o",
                  coarse_proc, workers=1)


def test_folder_of_other_settings_is_refused(survey, coarse_proc, tmp_path):
    """Its tiles would be taken as done: refused, named, unless --force."""
    out = tmp_path / "o"
    out.mkdir()
    (out / STATE).write_text(json.dumps({"processing_config_id": "0123abcd", "runs": {
        "lineA": {"folder": "lineA"}}}))
    (out / "lineA").mkdir()
    (out / "lineA" / "tile_0001.h5").write_bytes(b"old")
    with pytest.raises(FileExistsError, match=f"{out}.*0123abcd.*--force"):
        run_batch([survey["A"]], out, coarse_proc, workers=1)
    assert (out / "lineA" / "tile_0001.h5").read_bytes() == b"old"


def test_cli_names_the_extra_without_dask(survey, tmp_path, monkeypatch, caplog):
    from svss.cli import main
    monkeypatch.setitem(sys.modules, "distributed", None)      # as if not installed
    assert main(["batch", str(survey["A"]), "--out", str(tmp_path / "o")]) == 2
    assert "svss[distributed]" in caplog.text and "dask" in caplog.text
    assert not (tmp_path / "o").exists()


def test_reach_without_beam_gating_is_the_conditioned_window(survey, coarse_proc):
    """Without gating a ping reaches as far as its conditioned echoes: the plan's end of
    that window (no samples read) is the conditioner's on the real samples."""
    from svss_daq.rawfile import RawRunReader
    from svss_daq.waveform import make_waveform
    from svss_proc.batch.plan import TilePlanner
    from svss_proc.conditioning import Conditioner
    with RawRunReader(survey["A"]) as r:
        planner = TilePlanner(r.hardware, coarse_proc.value, coarse_proc.source, "test")
        hw, c = r.hardware.value, coarse_proc.value.conditioning
        cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), c.decimation,
                           c.upsample)
        for i in (0, len(r) - 1):
            p = r.ping(i)
            assert planner.schedule.echo_end_s(p) == cond.ping(p).axis.end_s


def _segments_with_records(whole: Path, out_dir: Path, run_id: str, split: int):
    """``whole`` as two segment files as the daemon writes them: pings split at
    ``split``, each instrument record (NMEA, PD0, ping clock) in the segment open when it
    was received (before the second segment's first ping: the first)."""
    from svss_daq.rawfile import NAV_CONFIG_ATTR, RawRunReader, RawRunWriter
    paths = []
    with RawRunReader(whole) as r:
        cut = r.nav(split).time_ns
        for seg, (a, b) in enumerate(((0, split), (split, len(r)))):
            first = (lambda t: t < cut) if seg == 0 else (lambda t: t >= cut)
            p = out_dir / f"{run_id}_{seg:03d}.h5"
            with RawRunWriter(p, r.hardware, run_attrs={
                    "run_id": run_id, "segment": seg,
                    NAV_CONFIG_ATTR: r.navigation_config}) as w:
                for i in range(a, b):
                    w.append(r.ping(i))
                for t, s in r.nmea():
                    if first(t):
                        w.append_nmea(t, s)
                for t, e in r.pd0():
                    if first(t):
                        w.append_pd0(t, e)
                for rx, tx in r.ping_clock():
                    if first(rx):
                        w.append_clock_reference(rx, tx)
            paths.append(p)
    return paths


@pytest.mark.slow
def test_runs_with_instrument_records_are_renavigated_and_say_so(client, coarse_proc,
                                                                   hardware, tmp_path):
    """A run the daemon recorded with its instrument records: batch re-navigates it
    (every segment's records together), images with those poses, equal voxel for voxel
    to svss process, and says which poses in the batch state and the tiles."""
    from svss_daq.nav.renavigate import renavigation
    from tests.test_renavigate import write_instrumented_run
    whole = write_instrumented_run(tmp_path / "inst.h5", hardware, 30)
    segs = _segments_with_records(whole, tmp_path, "inst", 12)
    renav = renavigation(whole)
    # the plan of the segments poses every ping as the whole run's re-navigation
    seg_plan, whole_plan = (plan_run("inst", "inst", p, coarse_proc) for p in
                            (segs, [whole]))
    assert seg_plan.poses == whole_plan.poses == renav.description
    by_seq = dict(zip(range(30), renav.poses))
    for a, b in zip(seg_plan.tiles, whole_plan.tiles):
        assert a.sequences == b.sequences and a.poses == b.poses
        assert list(a.poses) == [by_seq[s] for s in a.sequences]
    out = tmp_path / "out"
    run_batch(segs, out, coarse_proc, client=client, kernel_threads=1)
    state = json.loads((out / STATE).read_text())
    assert state["runs"]["inst"]["poses"] == renav.description
    from svss_proc.run_worker import process_raw
    ref = tmp_path / "ref"
    process_raw(whole, ref, coarse_proc)
    assert_same_tiles(ref, out / "inst")
    for t in sorted((out / "inst").glob("tile_*.h5")):
        h = read_tile_header(t)
        assert h["poses"] == renav.description
        assert h["attrs"]["line_origin_north_m"] == pytest.approx(renav.poses[0].north_m)
    # --no-renavigate: the recorded poses (7 m off north in this recording), as planned
    live = plan_run("inst", "inst", segs, coarse_proc, renavigate=False)
    assert live.poses == "recorded live poses"
    assert all(t.poses is None and t.pose_source == live.poses for t in live.tiles)


def test_renavigate_is_refused_for_a_run_without_records(survey, coarse_proc, tmp_path):
    from svss_daq.nav.renavigate import RenavigationError
    with pytest.raises(RenavigationError, match=r"cannot re-navigate: .*lineA\.h5: records "
                       "no NMEA sentence and no PD0 ensemble"):
        run_batch([survey["A"]], tmp_path / "o", coarse_proc, workers=1, renavigate=True)
    assert not list((tmp_path / "o").glob("*/tile_*.h5"))
