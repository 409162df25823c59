"""Fixtures of the batch tests: a two-run survey (one run in one file, one in two
segment files), coarse processing (5 cm voxels, 3 m tiles), its `svss process` tiles, and a
LocalCluster of two worker processes on loopback shared by the session's batches; and
the comparison of two folders' tile products (across the seams included)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load_with_text
from svss_daq.rawfile import RawRunReader, RawRunWriter
from svss_proc.tiles import read_tile
from tests.computed_once import computed_once
from tests.worker.conftest import simulate

N_A = 30                      # pings of run A (3 s at 10 pings/s)
N_B = 34                      # run B: pings 8..33 (a later first ping: another frame)
SPLIT = 12                    # run B's first segment holds its first 12 pings


def coarse_processing_text() -> str:
    text = Path(config_path("processing-demo.toml")).read_text()
    new = (text.replace("width_m = 1.2", "width_m = 0.4").replace("depth_m = 1.0", "depth_m = 0.3")
           .replace("voxel_m = 0.02", "voxel_m = 0.05"))
    # products across the seams (the default), as svss process makes them
    assert new.count("0.05") > text.count("0.05") and "across_seams = false" not in new
    return new


@pytest.fixture(scope="session")
def coarse_proc(tmp_path_factory):
    p = tmp_path_factory.mktemp("batch-config") / "coarse-processing.toml"
    p.write_text(coarse_processing_text())
    return load_with_text(ProcessingConfig, p)


def split_run(whole: Path, out_dir: Path, run_id: str, split: int) -> list[Path]:
    """``whole``'s pings copied into two segment files ``RUN_000.h5``, ``RUN_001.h5``
    (root attributes run_id and segment, as the acquisition daemon writes them)."""
    paths = []
    with RawRunReader(whole) as r:
        for seg, (a, b) in enumerate(((0, split), (split, len(r)))):
            p = out_dir / f"{run_id}_{seg:03d}.h5"
            with RawRunWriter(p, r.hardware, run_attrs={"run_id": run_id,
                                                        "segment": seg}) as w:
                for i in range(a, b):
                    w.append(r.ping(i))
            paths.append(p)
    return paths


@pytest.fixture(scope="session")
def survey(tmp_path_factory) -> dict:
    """Run A (one file, run id 'lineA') and run B (whole, and as two segments of run
    'lineB'); made once for the session's workers."""
    def make():
        d = tmp_path_factory.mktemp("survey")
        a = simulate(d / "lineA.h5", N_A, run_attrs={"run_id": "lineA"})
        whole = simulate(d / "lineB-whole.h5", N_B, skip=frozenset(range(8)))
        return {"A": a, "B_whole": whole, "B_segments": split_run(whole, d, "lineB", SPLIT)}
    return computed_once(tmp_path_factory, "batch-survey", make)


@pytest.fixture(scope="session")
def reference(survey, coarse_proc, tmp_path_factory) -> dict:
    """`svss process` (in process: the same function) of run A and of run B whole."""
    from svss_proc.run_worker import process_raw

    def make():
        out = {}
        for run, key in (("lineA", "A"), ("lineB", "B_whole")):
            out[run] = tmp_path_factory.mktemp(f"process-{run}")
            process_raw(survey[key], out[run], coarse_proc)
        return out
    return computed_once(tmp_path_factory, "batch-reference", make)


@pytest.fixture(scope="session")
def cluster():
    """Two single-threaded worker processes and their scheduler, all on loopback, shared
    by the batch modules (a worker a test kills is restarted by its nanny)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as c:
        yield c


@pytest.fixture(scope="session")
def client(cluster):
    import distributed
    with distributed.Client(cluster) as c:
        yield c


PRODUCT_VOLUMES = ("background", "drc", "depth_gain_db", "mip_depth", "mip_cross",
                   "mip_along")


def seam_attrs(path: Path) -> dict:
    """The products' seam attributes of a tile file (docs/products.md, Seams)."""
    with h5py.File(path, "r") as f:
        a = f["detections"].attrs
        return {k: int(a[k]) for k in ("seam_planes_before", "seam_planes_after",
                                       "seam_context_contacts")}


def assert_same_products(ref: Path, got: Path) -> int:
    """The tiles' products equal, volume for volume, and so do what they took across the
    seams; returns the seams (a tile's planes from a neighbour) the tiles used."""
    seams = 0
    for p in sorted(ref.glob("tile_*.h5")):
        a, b = read_tile(p), read_tile(got / p.name)
        names = [k for k in PRODUCT_VOLUMES if k in a]
        assert "drc" in names and "mip_depth" in names, names
        for k in names:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{p.name} {k}")
        sa, sb = seam_attrs(p), seam_attrs(got / p.name)
        assert sa == sb, p.name
        seams += (sa["seam_planes_before"] > 0) + (sa["seam_planes_after"] > 0)
    return seams
