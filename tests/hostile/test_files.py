"""Files are untrusted, writers fail cleanly (issue 13): truncated and damaged raw runs
and tiles are refused quickly with errors naming the file and the path; a full disk
stops the writers with a clear error, keeps what was flushed and leaves no tile under
its final name; no silent overwrite; ``svss score`` does not mix runs; fuzzed files give
data or the reader's own error, never another exception, never a hang.

Everything here runs the real writers, readers and HDF5 on real files."""

from __future__ import annotations

import faulthandler
import json
import logging
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from svss.score import score_tiles
from svss.summary import summarise
from svss_daq import untrusted_hdf5
from svss_daq.rawfile import RawFileError, RawRunReader, RawRunWriter
from svss_proc.products.chain import save_tile
from svss_proc.tiles import (
    TileFileError,
    is_temporary,
    read_detections,
    read_tile,
    read_tile_header,
    write_tile,
)
from tests.test_messages import assert_same

from .conftest import (FUZZ_EXAMPLES, ROOT, copy, fuzz_settings, ping_for, small_tile,
                       svss_calls, write_run)

HANG_GUARD_S = 20.0      # generous: only to tell a hang from a refusal, not a speed test
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def run_py(code: str, *args, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code), *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=ENV,
                          check=False)


# a writer killed with SIGKILL after flushing argv[2] pings and appending up to argv[3]
KILLED = """
    import os, signal, sys
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    from svss_daq.rawfile import RawRunWriter
    from tests.hostile.conftest import ping_for
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    w = RawRunWriter(sys.argv[1], hw, flush_every_pings=10**6, flush_interval_s=1e9)
    flushed, appended = int(sys.argv[2]), int(sys.argv[3])
    for i in range(flushed):
        w.append(ping_for(hw, i))
    w.flush()
    for i in range(flushed, appended):
        w.append(ping_for(hw, i))
    os.kill(os.getpid(), signal.SIGKILL)
"""


def killed_run(path: Path, flushed: int, appended: int) -> Path:
    res = run_py(KILLED, path, flushed, appended)
    assert res.returncode == -signal.SIGKILL, res.stderr[-2000:]
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory, hardware):
    """A clean run and one whose writer was killed right after its last flush (4 pings
    each)."""
    d = tmp_path_factory.mktemp("runs")
    return {"clean": write_run(d / "clean.h5", hardware, n_pings=4),
            "killed": killed_run(d / "killed.h5", 4, 4)}


@pytest.fixture(scope="module")
def tile_path(tmp_path_factory, hardware, small_proc):
    """A small tile with products (one detection) written by save_tile."""
    d = tmp_path_factory.mktemp("tile")
    h5, _ = save_tile(small_tile(small_proc), d, hardware, small_proc)
    assert len(read_tile(h5)["detections"]) == 1
    return h5


# ---------------------------------------------------------------- truncated raw runs

TRUNCATED = [(kind, fraction) for fraction in (0.0005, 0.01, 0.3, 0.6)
             for kind in ("clean", "killed")]


@pytest.fixture(scope="module")
def truncated(runs, tmp_path_factory):
    """Each case of :data:`TRUNCATED`: the file cut short and ``svss inspect``'s result
    on it (one process inspects them all)."""
    d = tmp_path_factory.mktemp("truncated")
    paths = {}
    for kind, fraction in TRUNCATED:
        data = runs[kind].read_bytes()
        paths[kind, fraction] = path = d / f"cut_{kind}_{fraction}.h5"
        path.write_bytes(data[: int(len(data) * fraction)])
    results = svss_calls(*(("inspect", paths[case]) for case in TRUNCATED))
    return {case: (paths[case], res) for case, res in zip(TRUNCATED, results)}


@pytest.mark.parametrize("kind", ["clean", "killed"])
@pytest.mark.parametrize("fraction", [0.0005, 0.01, 0.3, 0.6])
def test_truncated_raw_run_is_refused_naming_the_file(runs, truncated, kind, fraction):
    data = runs[kind].read_bytes()
    path, res = truncated[kind, fraction]
    t0 = time.monotonic()
    with pytest.raises(RawFileError, match=re.escape(str(path))) as err:
        RawRunReader(path)
    assert time.monotonic() - t0 < HANG_GUARD_S
    if kind == "clean":      # the superblock's end of file against the file's size
        assert f"truncated: {path.stat().st_size} bytes on disk" in str(err.value)
        assert f"records {len(data)} bytes" in str(err.value)
    assert res.returncode == 2 and str(path) in res.stderr, res.stderr[-2000:]
    assert "Traceback" not in res.stderr and res.elapsed < HANG_GUARD_S


@pytest.mark.parametrize("size", [0, 7, 9, 47])
def test_file_shorter_than_a_superblock_is_refused(runs, size, tmp_path):
    """Found by fuzzing: a superblock cut short must not index past its end."""
    path = tmp_path / "stub.h5"
    path.write_bytes(runs["clean"].read_bytes()[:size])
    with pytest.raises(RawFileError, match=re.escape(str(path))):
        RawRunReader(path)
    with pytest.raises(TileFileError, match=re.escape(str(path))):
        read_tile(path)


def test_killed_writer_reads_back_exactly_its_flushed_pings(tmp_path, hardware):
    """Pings appended after the last flush are never presented (the pings_flushed count
    bounds the reader), even where HDF5 already extended the datasets."""
    path = killed_run(tmp_path / "k.h5", 3, 7)
    with RawRunReader(path) as r:
        assert not r.clean and len(r) == 3
        for i, p in enumerate(r):
            assert_same(ping_for(hardware, i), p)
    with h5py.File(path, "r", libver="latest", swmr=True) as f:
        assert f["Sonar/Beam_group1/pings_flushed"][0] == 3


# ------------------------------------------------------ missing or malformed structure

def _damaged(src: Path, dst: Path, edit) -> Path:
    copy(src, dst)
    with h5py.File(dst, "a") as f:
        edit(f)
    return dst


def _delete(name):
    def edit(f):
        del f[name]
    return edit


def _del_attr(obj, name):
    def edit(f):
        del f[obj].attrs[name]
    return edit


def _replace(name, data):
    def edit(f):
        if name in f:       # (a tile's magnitude: only tiles written before issue 32)
            del f[name]
        f[name] = data
    return edit


B = "Sonar/Beam_group1"
RAW_DAMAGE = {
    # what is done: (edit, text the error must contain)
    "no beam group": (_delete("Sonar"), "group '/Sonar/Beam_group1' missing"),
    "no samples": (_delete(f"{B}/backscatter_r"), f"dataset '/{B}/backscatter_r' missing"),
    "no ping_time": (_delete(f"{B}/ping_time"), f"dataset '/{B}/ping_time' missing"),
    "no ping_sequence": (_delete(f"{B}/ping_sequence"),
                         f"dataset '/{B}/ping_sequence' missing"),
    "no transmit_projector": (_delete(f"{B}/transmit_projector"),
                              f"dataset '/{B}/transmit_projector' missing"),
    "no window_start_ns": (_delete(f"{B}/window_start_ns"),
                           f"dataset '/{B}/window_start_ns' missing"),
    "no platform": (_delete("Platform"), "group '/Platform' missing"),
    "no time1": (_delete("Platform/time1"), "dataset '/Platform/time1' missing"),
    "no north_m": (_delete("Platform/north_m"), "dataset '/Platform/north_m' missing"),
    "no quality": (_delete("Platform/quality"), "dataset '/Platform/quality' missing"),
    "no NMEA": (_delete("Platform/NMEA"), "group '/Platform/NMEA' missing"),
    "no NMEA text": (_delete("Platform/NMEA/sentence"),
                     "dataset '/Platform/NMEA/sentence' missing"),
    "no environment": (_delete("Environment"), "group '/Environment' missing"),
    "no hardware text": (_delete("Vendor_specific/hardware_config_toml"),
                         "dataset '/Vendor_specific/hardware_config_toml' missing"),
    "no format": (_del_attr("/", "svss_format"), "root attribute 'svss_format' is None"),
    "no version": (_del_attr("/", "svss_format_version"),
                   "root attribute 'svss_format_version' missing"),
    "version 3": (lambda f: f.attrs.__setitem__("svss_format_version", 3),
                  "svss_format_version 3; this software reads version(s) [1, 2]"),
    "version 1.5": (lambda f: f.attrs.__setitem__("svss_format_version", 1.5),
                    "root attribute 'svss_format_version' is 1.5; expected an integer"),
    "no sample rate": (_del_attr(B, "sample_rate_hz"),
                       f"attribute '/{B}' sample_rate_hz is None"),
    "channels": (_replace(f"{B}/backscatter_r", np.zeros((4, 79, 1500), "<i4")),
                 ("has shape (4, 79, 1500); the stored hardware configuration records 80 "
                  "channels x 1500 samples")),
    "samples 2-D": (_replace(f"{B}/backscatter_r", np.zeros((4, 80), "<i4")),
                    f"dataset '/{B}/backscatter_r' has shape (4, 80); expected 3"),
    "samples int16": (_replace(f"{B}/backscatter_r", np.zeros((4, 80, 1500), "<i2")),
                      "has dtype int16; expected int32"),
    "per-ping 2-D": (_replace(f"{B}/ping_time", np.zeros((4, 2), "<i8")),
                     f"dataset '/{B}/ping_time' has shape (4, 2); expected 1"),
    "per-ping float": (_replace(f"{B}/ping_sequence", np.zeros(4)),
                       f"dataset '/{B}/ping_sequence' has dtype float64; expected kind"),
    "nav text": (_replace("Platform/north_m", np.array([b"a"] * 4)),
                 "dataset '/Platform/north_m' has dtype |S1"),
    "group for dataset": (lambda f: (f.__delitem__("Platform/east_m"),
                                     f.create_group("Platform/east_m")),
                          "'/Platform/east_m' is a Group; expected a dataset"),
    "flushed count": (_replace(f"{B}/pings_flushed", np.array([1, 2])),
                      f"dataset '/{B}/pings_flushed' holds"),
    "bad hardware text": (_replace("Vendor_specific/hardware_config_toml", "[[[nonsense"),
                          ":/Vendor_specific/hardware_config_toml"),
}


@pytest.mark.parametrize("case", RAW_DAMAGE)
def test_damaged_raw_run_names_the_file_and_path(runs, case, tmp_path):
    edit, expected = RAW_DAMAGE[case]
    path = _damaged(runs["clean"], tmp_path / "damaged.h5", edit)
    with pytest.raises(RawFileError) as err:
        RawRunReader(path)
    assert str(path) in str(err.value) and expected in str(err.value), str(err.value)


TILE_DAMAGE = {
    "no along": (_delete("along"), "dataset '/along' missing"),
    "no depth": (_delete("depth"), "dataset '/depth' missing"),
    "no pings": (_delete("ping_sequence"), "dataset '/ping_sequence' missing"),
    "track length": (lambda f: f.create_dataset(
        "ping_time", data=np.zeros(f["ping_sequence"].shape[0] + 2, np.int64)),
        "dataset '/ping_time' has shape"),
    "track text": (lambda f: f.create_dataset("ping_north_m", data=np.array([b"x"])),
                   "dataset '/ping_north_m' has dtype"),
    "no image": (_delete("image"), "dataset '/image' missing"),
    "no detections": (_delete("detections"),
                      "group '/detections' missing; expected it in a tile with products"),
    "no excess": (_delete("detections/excess_db"),
                  "dataset '/detections/excess_db' missing"),
    "no tile_index": (_del_attr("/", "tile_index"), "root attribute 'tile_index' missing"),
    "no heading": (_del_attr("/", "line_heading_rad"),
                   "root attribute 'line_heading_rad' missing"),
    "text voxel": (lambda f: f.attrs.__setitem__("voxel_m", "big"),
                   "root attribute 'voxel_m' is 'big'; expected a number"),
    "no format": (_del_attr("/", "svss_format"), "root attribute 'svss_format' is None"),
    "no version": (_del_attr("/", "svss_format_version"),
                   "root attribute 'svss_format_version' missing"),
    "image shape": (_replace("image", np.zeros((20, 15, 9), np.complex64)),
                    "dataset '/image' has shape (20, 15, 9); expected (20, 15, 10)"),
    "image 2-D": (_replace("magnitude", np.zeros((20, 15), np.float32)),
                  "dataset '/magnitude' has shape (20, 15); expected 3"),
    "mip shape": (_replace("mip_cross", np.zeros((20, 15), np.float32)),
                  "dataset '/mip_cross' has shape (20, 15); expected (20, 10)"),
    "detections length": (_replace("detections/peak_db", np.zeros(3, np.float32)),
                          "dataset '/detections/peak_db' has shape (3,); expected (1,)"),
    "axis text": (_replace("cross", np.array([b"x"] * 15)), "dataset '/cross' has dtype"),
    "drc scale": (_del_attr("drc", "scale_factor"), "attribute '/drc' scale_factor is None"),
}


@pytest.mark.parametrize("case", TILE_DAMAGE)
def test_damaged_tile_names_the_file_and_path(tile_path, case, tmp_path):
    edit, expected = TILE_DAMAGE[case]
    path = _damaged(tile_path, tmp_path / "tile_0001.h5", edit)
    with pytest.raises(TileFileError) as err:
        read_tile(path)
    assert str(path) in str(err.value) and expected in str(err.value), str(err.value)


def test_truncated_tile_is_refused(tile_path, tmp_path):
    data = tile_path.read_bytes()
    for fraction in (0.0005, 0.01, 0.3, 0.6, 0.99):
        path = tmp_path / f"tile_{fraction}.h5"
        path.write_bytes(data[: int(len(data) * fraction)])
        for read in (read_tile, read_tile_header, read_detections):
            with pytest.raises(TileFileError, match=re.escape(str(path))):
                read(path)


# ------------------------------------------------------------------ format versions

VERSIONS = [3, 999, 2.5, "2", -1, True]


@pytest.fixture(scope="module")
def versioned(tile_path, tmp_path_factory):
    """For each version of :data:`VERSIONS`: a folder holding the tile marked with it,
    and ``svss inspect``'s and ``svss score``'s results on them (one process runs them
    all)."""
    scene = ROOT / "config" / "scenes" / "demo.toml"
    paths, calls = [], []
    for i, version in enumerate(VERSIONS):
        out = tmp_path_factory.mktemp(f"version{i}") / "tiles"
        out.mkdir()
        path = _damaged(tile_path, out / "tile_0001.h5",
                        lambda f, v=version: f.attrs.__setitem__("svss_format_version", v))
        paths.append(path)
        calls += [("inspect", path), ("score", out, "--scene", scene)]
    results = svss_calls(*calls)
    return {repr(v): (path, results[2 * i], results[2 * i + 1])
            for i, (v, path) in enumerate(zip(VERSIONS, paths))}


@pytest.mark.parametrize("version", VERSIONS)
def test_unknown_tile_version_refused_by_readers_inspect_and_score(versioned, version):
    path, inspected, scored = versioned[repr(version)]
    for read in (read_tile, read_tile_header, read_detections):
        with pytest.raises(TileFileError, match=re.escape(str(path)) + ".*svss_format_version"):
            read(path)
    for res in (inspected, scored):
        assert res.returncode == 2 and str(path) in res.stderr, res.stderr[-2000:]
        assert "svss_format_version" in res.stderr and "Traceback" not in res.stderr


def test_tile_without_detections_refused_by_score_naming_it(tile_path, hardware, small_proc,
                                                            tmp_path):
    scene = ROOT / "config" / "scenes" / "demo.toml"
    # a tile processed without [products]: readable, but nothing to score
    bare = tmp_path / "bare"
    text = small_proc.text.split("\n[products]")[0]
    from svss_daq.config import ProcessingConfig, loaded_from_text
    no_products = loaded_from_text(ProcessingConfig, text, "no-products")
    h5, _ = save_tile(small_tile(no_products), bare, hardware, no_products)
    assert "detections" not in read_tile_header(h5)["products"]
    with pytest.raises(TileFileError, match=re.escape(str(h5)) + ": group '/detections'"):
        read_detections(h5)
    # a tile with products whose detections group was removed: refused everywhere
    gone = tmp_path / "gone"
    gone.mkdir()
    path = _damaged(tile_path, gone / "tile_0001.h5", _delete("detections"))
    bare_scored, inspected, gone_scored = svss_calls(
        ("score", bare, "--scene", scene), ("inspect", path), ("score", gone, "--scene", scene))
    assert bare_scored.returncode == 2, bare_scored.stderr[-2000:]
    assert f"{h5}: group '/detections' missing" in bare_scored.stderr
    for res in (inspected, gone_scored):
        assert res.returncode == 2, res.stderr[-2000:]
        assert f"{path}: group '/detections' missing" in res.stderr


# ------------------------------------------------------------------------ full disk

FULL_RAW = """
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # writes past the limit: EFBIG
    limit = int(sys.argv[2])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    from svss_daq.rawfile import RawFileError, RawRunWriter
    from tests.hostile.conftest import ping_for
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    try:
        with RawRunWriter(sys.argv[1], hw, flush_every_pings=3) as w:
            for i in range(1000):
                w.append(ping_for(hw, i))
    except RawFileError as exc:
        print(exc, file=sys.stderr)
        sys.exit(3)
"""


@pytest.mark.parametrize("limit", [700_000, 3_000_000])
def test_full_disk_stops_the_raw_writer_keeping_what_was_flushed(tmp_path, hardware, limit):
    path = tmp_path / "full.h5"
    res = run_py(FULL_RAW, path, limit)
    assert res.returncode == 3, (res.returncode, res.stderr[-3000:])   # not -11 / 139
    m = re.search(r"(\d+) pings are safely on disk", res.stderr)
    assert m and f"{path}: flushing pings" in res.stderr and "File too large" in res.stderr, \
        res.stderr[-3000:]
    flushed = int(m.group(1))
    assert flushed == (limit // (80 * 1500 * 4)) // 3 * 3 or flushed > 0
    with RawRunReader(path) as r:
        assert len(r) == flushed
        for i, p in enumerate(r):
            assert np.any(p.samples != 0)
            assert_same(ping_for(hardware, i), p)


def test_full_disk_before_the_first_ping(tmp_path):
    path = tmp_path / "full.h5"
    res = run_py(FULL_RAW, path, 2000)
    assert res.returncode == 3, (res.returncode, res.stderr[-3000:])
    assert f"{path}: writing the run's header failed" in res.stderr
    assert "no file written" in res.stderr and not path.exists()


def test_full_disk_in_svss_simulate(tmp_path):
    """The command the hostile tester ran: a clear error, exit status 2, no crash; the
    file reads back with the flushed pings and no zeros."""
    path = tmp_path / "run.h5"
    res = run_py("""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (10_000_000, 10_000_000))
        from svss.cli import main
        sys.exit(main(sys.argv[1:]))
    """, "simulate", "--scene", ROOT / "config" / "scenes" / "demo.toml", "--out", path)
    assert res.returncode == 2, (res.returncode, res.stderr[-3000:])
    m = re.search(r"(\d+) pings are safely on disk", res.stderr)
    assert m and str(path) in res.stderr and "Traceback" not in res.stderr
    with RawRunReader(path) as r:
        assert len(r) == int(m.group(1)) > 0
        assert all(np.any(p.samples != 0) for p in r)


# save_tile into argv[1]/LIMIT for each limit of argv[2:], files limited to LIMIT bytes
# (the soft limit, raised again after each): what each raised, as JSON
FULL_TILE = """
    import json, resource, signal, sys
    from pathlib import Path
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path,
                                 load_with_text)
    from svss_proc.products.chain import save_tile
    from svss_proc.tiles import TileFileError
    from tests.hostile.conftest import small_processing, small_tile
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = small_processing(load_with_text(ProcessingConfig,
                                           config_path("processing-demo.toml")))
    tile = small_tile(proc)
    _, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    errors = {}
    for limit in map(int, sys.argv[2:]):
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
        try:
            save_tile(tile, Path(sys.argv[1]) / str(limit), hw, proc)
            errors[limit] = None
        except TileFileError as exc:
            errors[limit] = str(exc)
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))
    print(json.dumps(errors))
"""
FULL_TILE_CASES = [(90_000, "tile_0001.h5"),         # after the PNG
                   (20_000, "tile_0001_mip.png")]    # at the PNG


@pytest.fixture(scope="module")
def full_tile(tmp_path_factory):
    """The folder each limit of :data:`FULL_TILE_CASES` wrote into and the error
    save_tile raised (one process writes them all)."""
    base = tmp_path_factory.mktemp("full-tile")
    res = run_py(FULL_TILE, base, *(limit for limit, _ in FULL_TILE_CASES))
    assert res.returncode == 0, (res.returncode, res.stderr[-3000:])
    errors = json.loads(res.stdout)
    return {limit: (base / str(limit), errors[str(limit)]) for limit, _ in FULL_TILE_CASES}


@pytest.mark.parametrize("limit, fails", FULL_TILE_CASES)
def test_full_disk_leaves_no_tile_under_its_final_name(full_tile, tile_path, limit, fails):
    assert tile_path.stat().st_size > limit
    out, error = full_tile[limit]
    assert error is not None, "save_tile wrote the tile"
    assert f"{out / fails}: writing" in error and "no file written" in error, error
    assert sorted(p.name for p in out.iterdir()) == []     # no final name, no temporary


def test_temporary_files_are_ignored_and_refused(tile_path, tmp_path):
    out = tmp_path / "tiles"
    out.mkdir()
    copy(tile_path, out / "tile_0001.h5")
    tmp = copy(tile_path, out / ".tile_0002.partial-0123abcd.h5")
    assert is_temporary(tmp) and not is_temporary(out / "tile_0001.h5")
    with pytest.raises(TileFileError, match=re.escape(str(tmp)) + ": a temporary file"):
        summarise(tmp)
    report = score_tiles(out, ROOT / "config" / "scenes" / "demo.toml", radius_m=0.3)
    assert report["tiles"] == ["tile_0001.h5"]


def test_write_tile_replaces_only_when_complete(tile_path, hardware, small_proc, tmp_path):
    """An earlier tile of the same name stays whole until the new one is complete."""
    path = copy(tile_path, tmp_path / "tile_0001.h5")
    before = path.read_bytes()
    tile = small_tile(small_proc, seed=9)
    tile.pings = "not pings"           # fails while writing
    with pytest.raises((TileFileError, ValueError, TypeError)):
        write_tile(path, tile, hardware, small_proc)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["tile_0001.h5"]


# ----------------------------------------------------------------------- overwrite

def test_existing_raw_run_is_not_overwritten(runs, hardware, tmp_path):
    path = copy(runs["clean"], tmp_path / "run.h5")
    before = path.read_bytes()
    with pytest.raises(RawFileError, match=re.escape(str(path)) + ": already exists.*--force"):
        RawRunWriter(path, hardware)
    assert path.read_bytes() == before
    with RawRunWriter(path, hardware, overwrite=True) as w:
        w.append(ping_for(hardware, 7))
    with RawRunReader(path) as r:
        assert len(r) == 1 and r.ping(0).sequence == ping_for(hardware, 7).sequence


# ------------------------------------------------------------- score and stale tiles

def test_score_uses_the_manifest_and_names_stale_tiles(tile_path, hardware, small_proc,
                                                      tmp_path, caplog):
    scene = ROOT / "config" / "scenes" / "demo.toml"
    out = tmp_path / "tiles"
    out.mkdir()
    copy(tile_path, out / "tile_0001.h5")
    save_tile(small_tile(small_proc, index=2), out, hardware, small_proc)   # stale
    with caplog.at_level(logging.WARNING, logger="svss.score"):
        report = score_tiles(out, scene, radius_m=0.3)
    assert report["tiles"] == ["tile_0001.h5", "tile_0002.h5"]
    assert "no manifest.json; scoring all 2" in caplog.text
    (out / "manifest.json").write_text(json.dumps(
        {"pings": 6, "files": ["tile_0001.h5", "tile_0001_mip.png"]}))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="svss.score"):
        report = score_tiles(out, scene, radius_m=0.3)
    assert report["tiles"] == ["tile_0001.h5"]
    assert "tile_0002.h5 not listed in manifest.json" in caplog.text
    assert report["summary"]["detections"] == 1
    (out / "manifest.json").write_text(json.dumps({"files": ["tile_0003.h5"]}))
    with pytest.raises(FileNotFoundError, match="lists tile_0003.h5"):
        score_tiles(out, scene, radius_m=0.3)
    (out / "manifest.json").write_text("{not json")
    with pytest.raises(ValueError, match=re.escape(str(out / "manifest.json"))):
        score_tiles(out, scene, radius_m=0.3)


# ------------------------------------------------------------------------- fuzzing

def _raw_data_spans(path: Path) -> list[tuple[int, int]]:
    """Byte ranges of a run's sample chunks (the bulk of the file, where a mutation
    only changes codes)."""
    with h5py.File(path, "r", libver="latest", swmr=True) as f:
        ds = f["Sonar/Beam_group1/backscatter_r"]
        spans = []
        for i in range(ds.id.get_num_chunks()):
            info = ds.id.get_chunk_info(i)
            spans.append((info.byte_offset, info.byte_offset + info.size))
    return sorted(spans)


def _structure_offsets(size: int, data_spans) -> np.ndarray:
    """Offsets outside the sample chunks: superblock, object headers, indices, small
    datasets."""
    mask = np.ones(size, dtype=bool)
    for a, b in data_spans:
        mask[a:b] = False
    return np.flatnonzero(mask)


def _mutate(data: bytes, draw, offsets: np.ndarray) -> bytes:
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "overwrite", "zero", "truncate"]))
        if draw(st.booleans()):          # mostly the file's structure, sometimes anywhere
            at = int(offsets[draw(st.integers(0, offsets.size - 1))])
        else:
            at = draw(st.integers(0, max(len(buf) - 1, 0)))
        if kind == "truncate":
            del buf[at:]
        elif kind == "flip" and at < len(buf):
            buf[at] ^= 1 << draw(st.integers(0, 7))
        elif kind == "overwrite":
            new = draw(st.binary(min_size=1, max_size=64))
            buf[at:at + len(new)] = new
        elif kind == "zero":
            n = draw(st.integers(1, 4096))
            buf[at:at + n] = bytes(min(n, max(len(buf) - at, 0)))
    return bytes(buf)


@pytest.fixture(scope="module")
def fuzz_runs(tmp_path_factory, hardware):
    """Small runs to mutate (clean and killed), 2 pings each, and their structure
    offsets."""
    d = tmp_path_factory.mktemp("fuzz")
    out = {}
    for kind, path in (("clean", write_run(d / "clean.h5", hardware, n_pings=2)),
                       ("killed", killed_run(d / "killed.h5", 2, 3))):
        data = path.read_bytes()
        out[kind] = (data, _structure_offsets(len(data), _raw_data_spans(path)))
    return out


@pytest.fixture
def quick_refusal(monkeypatch):
    """A damaged file that keeps HDF5 busy is refused after 2 s (not 10) while fuzzing."""
    monkeypatch.setattr(untrusted_hdf5, "PROBE_TIMEOUT_S", 2.0)


def _bounded(fn):
    """Run ``fn`` with a hang guard: a hang inside HDF5 (where Python cannot interrupt
    it) dumps the stacks and ends the test process instead of blocking the suite."""
    faulthandler.dump_traceback_later(120, exit=True)
    t0 = time.monotonic()
    try:
        return fn()
    finally:
        faulthandler.cancel_dump_traceback_later()
        assert time.monotonic() - t0 < HANG_GUARD_S


@pytest.mark.parametrize("kind", ["clean", "killed"])
@fuzz_settings()
@given(data=st.data())
@pytest.mark.slow
def test_fuzzed_raw_run_gives_data_or_raw_file_error(fuzz_runs, kind, tmp_path,
                                                       quick_refusal, data):
    template, offsets = fuzz_runs[kind]
    path = tmp_path / "fuzzed.h5"
    path.write_bytes(_mutate(template, data.draw, offsets))

    def read():
        try:
            with RawRunReader(path) as r:
                r.ping_table(), r.nav_table(), r.nmea(), r.provenance
                assert len(r) <= 3
                for p in r:
                    assert p.samples.shape == (80, 1500)
        except RawFileError as exc:
            assert str(path) in str(exc)
    _bounded(read)


@pytest.fixture(scope="module")
def fuzz_tile(tile_path):
    data = tile_path.read_bytes()
    with h5py.File(tile_path, "r") as f:
        spans = []
        for name in ("image", "background", "drc"):
            ds = f[name]
            for i in range(ds.id.get_num_chunks()):
                info = ds.id.get_chunk_info(i)
                spans.append((info.byte_offset, info.byte_offset + info.size))
    return data, _structure_offsets(len(data), spans)


@fuzz_settings(max_examples=max(1, FUZZ_EXAMPLES // 2))   # a tile read costs 2x a raw run's
@given(data=st.data())
@pytest.mark.slow
def test_fuzzed_tile_gives_data_or_tile_file_error(fuzz_tile, tmp_path, quick_refusal,
                                                    data):
    template, offsets = fuzz_tile
    path = tmp_path / "tile_0001.h5"
    path.write_bytes(_mutate(template, data.draw, offsets))

    def read():
        for fn in (read_tile, read_detections):
            try:
                fn(path)
            except TileFileError as exc:
                assert str(path) in str(exc)
    _bounded(read)
