"""svss batch against svss process: one survey reprocessed by one process (``process_raw``
per run, the ``svss process`` path) and by LocalClusters of 1 and 2 worker processes
(``run_batch``), the tiles checked identical, the speed-ups and the scheduler's overhead
per tile.

    python benchmarks/bench_batch.py --out benchmarks/results/bench_batch.json \
        [--runs 2] [--pings 40] [--voxel 0.02] [--workers 1 2]

Survey: ``--runs`` runs of the demo scene's first ``--pings`` pings (run k starts k*8
pings later, so every run has its own tile frame), imaged with the demo processing
configuration on a narrow tile (3 m x 0.4 m x 0.3 m, ``--voxel`` m voxels), products
and quicklooks included. For each worker count a fresh LocalCluster is started (its
start timed apart), one batch is run cold (the workers import the code and load the
kernels from numba's cache) and one warm into another folder.

Figures (per worker count): ``batch_s`` the batch's wall time (planning, tasks, index);
``tasks_s`` the tasks' part (submit to last result); ``compute_s`` the sum of the
tasks' own times; ``overhead_per_tile_s`` = (tasks_s x workers - compute_s) / tiles, the
worker time per tile not spent in a task (scheduling, transfer, idle at the tail);
``speedup`` = single-process time / batch_s, with the single process (kernels warm)
timed just before the warm batch, and before the cluster for the cold one (the machine's
load drifts; the cold figure includes the workers' start-up). Each worker process gets
cores/workers numba threads; the single process uses all cores. On a 2-core machine 2 workers are the
most that can help: more workers need more cores or machines (docs/batch.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from svss_daq.config import ProcessingConfig, config_path, load_with_text
from svss_proc.batch.run import run_batch
from svss_proc.tiles import read_tile
from svss_proc.run_worker import process_raw

log = logging.getLogger("bench_batch")


def processing_text(voxel: float) -> str:
    text = Path(config_path("processing-demo.toml")).read_text()
    return (text.replace("width_m = 1.2", "width_m = 0.4").replace("depth_m = 1.0", "depth_m = 0.3")
            .replace("voxel_m = 0.02", f"voxel_m = {voxel}"))


def simulate(path: Path, n_pings: int, first: int, run_id: str) -> Path:
    import itertools

    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import HardwareConfig
    from svss_daq.rawfile import RawRunWriter
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    with RawRunWriter(path, hw, run_attrs={"run_id": run_id}) as rec:
        for p in itertools.islice(iter(EnvironmentSource(hw, scene)), first, first + n_pings):
            rec.append(p)
    return path


def same_tiles(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.glob("tile_*.h5"))
    if names != sorted(p.name for p in b.glob("tile_*.h5")):
        return False
    return all(np.array_equal(read_tile(a / n)["image"], read_tile(b / n)["image"])
               for n in names)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/bench_batch.json")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--pings", type=int, default=40)
    ap.add_argument("--voxel", type=float, default=0.02)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    log.setLevel(logging.INFO)
    import distributed

    work = Path(tempfile.mkdtemp(prefix="bench_batch-"))
    try:
        proc_path = work / "processing.toml"
        proc_path.write_text(processing_text(args.voxel))
        proc = load_with_text(ProcessingConfig, proc_path)
        runs = [simulate(work / f"line{k}.h5", args.pings, 8 * k, f"line{k}")
                for k in range(args.runs)]
        # warm this process's kernels (the workers' first batch is timed cold instead)
        process_raw(runs[0], work / "warm", proc)

        def single() -> float:
            """The survey by svss process, timed (each batch is compared with the one
            timed just before it: the machine's load drifts)."""
            t0 = time.perf_counter()
            for r in runs:
                process_raw(r, work / "single" / r.stem, proc, force=True)
            return time.perf_counter() - t0

        single_s = single()
        n_tiles = sum(len(list((work / "single" / r.stem).glob("tile_*.h5"))) for r in runs)
        log.info("single process: %d tiles in %.2f s", n_tiles, single_s)
        singles = [single_s]
        rows = []
        cores = os.cpu_count() or 1
        for n in args.workers:
            threads = max(1, cores // n)
            if n != args.workers[0]:
                single_s = single()
                singles.append(single_s)
            t0 = time.perf_counter()
            with distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                          host="127.0.0.1", dashboard_address=None
                                          ) as cluster, \
                    distributed.Client(cluster) as client:
                start_s = time.perf_counter() - t0
                row = {"workers": n, "numba_threads_per_worker": threads,
                       "cluster_start_s": round(start_s, 3)}
                for phase in ("cold", "warm"):
                    out = work / f"batch{n}-{phase}"
                    if phase == "warm":
                        single_s = single()
                        singles.append(single_s)
                    t0 = time.perf_counter()
                    s = run_batch(runs, out, proc, client=client, kernel_threads=threads)
                    batch_s = time.perf_counter() - t0
                    assert s["tiles"] == n_tiles and s["imaged"] == n_tiles, s
                    same = all(same_tiles(work / "single" / r.stem, out / r.stem)
                               for r in runs)
                    row[phase] = {
                        "batch_s": round(batch_s, 3), "plan_s": s["plan_s"],
                        "tasks_s": s["run_s"], "compute_s": s["compute_s"],
                        "overhead_per_tile_s": round((s["run_s"] * n - s["compute_s"])
                                                     / n_tiles, 4),
                        "single_process_s": round(single_s, 3),
                        "speedup": round(single_s / batch_s, 3),
                        "identical_to_svss_process": same}
                    log.info("%d worker(s) %s: %.2f s, speed-up %.2f, overhead %.3f s/tile, "
                             "identical %s", n, phase, batch_s, row[phase]["speedup"],
                             row[phase]["overhead_per_tile_s"], same)
                rows.append(row)
        result = {
            "benchmark": "bench_batch", "command": " ".join(sys.argv),
            "machine": {"cpu_count": cores, "platform": platform.platform(),
                        "python": platform.python_version(),
                        "load_average_at_end": os.getloadavg()},
            "survey": {"runs": args.runs, "pings_per_run": args.pings, "voxel_m": args.voxel,
                       "tiles": n_tiles, "tile_m": [3.0, 0.4, 0.3]},
            "single_process_s": [round(v, 3) for v in singles],
            "single_process_per_tile_s": round(min(singles) / n_tiles, 4),
            "local_cluster": rows,
            "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
        print(json.dumps(result, indent=2))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
