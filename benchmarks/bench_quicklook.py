#!/usr/bin/env python
"""CPU time of a default 15 m tile's PNGs as the worker writes them: the products
quicklook (``products_png``: six views, 39 contacts, the contact list) and the quick
look without products (``mip_png``), drawn by the raster plotter
(svss_proc/products/raster.py). The tile's products are made up (speckle-like levels,
the first 1.5 m unimaged), as tests/products/test_quicklook.py's; the drawing does not
depend on the values. Each is drawn ``--repeat`` times after one warm-up; the fastest
and the median CPU seconds are reported with the machine's instruction set and load.

    python benchmarks/bench_quicklook.py [--repeat 5] --out benchmarks/results/bench_quicklook.json
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

log = logging.getLogger("bench_quicklook")


def default_tile():
    from svss_daq.config import ProcessingConfig, config_path, load
    from svss_proc.imaging.grid import tile_grid
    from svss_proc.products import detect
    from svss_proc.tiles import MIPS
    proc = load(ProcessingConfig, config_path("processing.toml"))
    grid = tile_grid(proc.tile, 0)
    rng = np.random.default_rng(3)
    level = rng.normal(0.0, 5.0, grid.shape).astype(np.float32)
    coverage = np.full(grid.shape, 20, dtype=np.uint16)
    coverage[:75] = 0
    level[:75] = -300.0
    gain = np.zeros(grid.shape[2], dtype=np.float32)
    mips = {k: level.max(axis=axis) for k, (axis, _) in MIPS.items()}
    det = np.zeros(39, dtype=detect.DTYPE)
    det["along_m"] = rng.uniform(2.0, 14.0, 39)
    det["cross_m"] = rng.uniform(-0.9, 0.9, 39)
    det["depth_m"] = rng.uniform(0.05, 1.9, 39)
    det["excess_db"] = np.sort(rng.uniform(14.0, 40.0, 39))[::-1]
    image = (rng.normal(size=grid.shape) + 1j * rng.normal(size=grid.shape)).astype(
        np.complex64)
    return proc, grid, level, gain, mips, det, coverage, image


def _cpu(fn, repeat: int) -> dict:
    fn()                                                  # warm-up: fonts, palette
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return {"cpu_s_min": round(min(times), 4), "cpu_s_median": round(float(np.median(times)), 4),
            "repeat": repeat}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from bench_isa import machine_isa
    from svss_proc.products.quicklook import mip_png, products_png
    proc, grid, level, gain, mips, det, coverage, image = default_tile()
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        png = Path(tmp) / "q.png"
        results = {
            "products_png": _cpu(lambda: products_png(
                png, mips, level, gain, det, grid, 0.02, proc.products,
                "SVSS tile_0000 (along 0-15 m, 150 pings)", "bench", coverage=coverage),
                args.repeat),
            "mip_png": _cpu(lambda: mip_png(png, image, grid, "SVSS tile_0000 (quick look)"),
                            args.repeat)}
    out = {"command": "python benchmarks/bench_quicklook.py " + " ".join(argv or sys.argv[1:]),
           "machine": machine_isa(), "load_before": load0, "load_after": os.getloadavg(),
           "tile_shape": list(grid.shape), "results": results}
    for name, r in results.items():
        log.info("%-13s %.3f CPU s fastest, %.3f median of %d", name, r["cpu_s_min"],
                 r["cpu_s_median"], r["repeat"])
    if args.out:
        args.out.write_text(json.dumps(out, indent=1) + "\n")
        log.info("wrote %s", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
