#!/usr/bin/env python
"""Benchmark the coverage count (``svss_proc.imaging.coverage``) against the imaging it
sits beside: the demo scene's pings imaged into default tiles (``config/processing.toml``:
15 m x 2 m x 2 m at 2 cm), timing every ``TileImager.add`` and, inside it, every
``Coverage.add``.

Usage::

    python benchmarks/bench_coverage.py --out benchmarks/results/bench_coverage.json

Prints and writes (JSON, with the machine's load) the median time per ping of the whole
``add`` and of the coverage, and the coverage's share of the imaging time.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_device.environment_source import EnvironmentSource  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path,  # noqa: E402
                             load, load_with_text)
from svss_proc.imaging import coverage as coverage_mod  # noqa: E402
from svss_proc.imaging.imager import TileImager  # noqa: E402

log = logging.getLogger("bench_coverage")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="JSON file for the results")
    ap.add_argument("--pings", type=int, default=40, help="pings timed (after 5 warm-up)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    pings = list(itertools.islice(iter(EnvironmentSource(hw, scene)), 20, 25 + args.pings))
    load_start = os.getloadavg()
    imager = TileImager(hw, proc)
    for p in pings[:5]:                     # compile (or load the cache), open the tiles
        imager.add(p)
    spent: list[float] = []
    original = coverage_mod.Coverage.add

    def timed(self, *a, **kw):
        t0 = time.perf_counter()
        original(self, *a, **kw)
        spent.append(time.perf_counter() - t0)

    coverage_mod.Coverage.add = timed
    per_ping, cov_per_ping = [], []
    try:
        for p in pings[5:]:
            n0 = len(spent)
            t0 = time.perf_counter()
            imager.add(p)
            per_ping.append(time.perf_counter() - t0)
            cov_per_ping.append(sum(spent[n0:]))
    finally:
        coverage_mod.Coverage.add = original
    res = {"pings": len(per_ping), "add_median_s": float(np.median(per_ping)),
           "coverage_median_s": float(np.median(cov_per_ping)),
           "coverage_share": float(np.sum(cov_per_ping) / np.sum(per_ping)),
           "cpus": os.cpu_count(), "load_average_start": load_start[0],
           "load_average_end": os.getloadavg()[0],
           "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    print(f"per ping: imaging {res['add_median_s'] * 1e3:.0f} ms, of which coverage "
          f"{res['coverage_median_s'] * 1e3:.1f} ms ({100 * res['coverage_share']:.1f} %); "
          f"load average {load_start[0]:.1f} -> {res['load_average_end']:.1f} on "
          f"{os.cpu_count()} CPUs")
    Path(args.out).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
