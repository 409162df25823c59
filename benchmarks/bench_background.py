#!/usr/bin/env python
"""Benchmark the 3-D median background on a full tile (750 x 100 x 100 voxels, along x
cross x depth: the seed's 15 m x 2 m x 2 m at 2 cm) with the seed's kernel
(1.2 m x 0.2 m x 0.1 m: 61 x 11 x 5 voxels).

Side by side in one run:

- ``histogram``: the approximation (``svss_proc.products.background.median_histogram``) on the
  full tile, and the whole normalisation (background, division, level in dB);
- ``histogram, per-line kernel``: the same median with the kernel that slides one line's
  window at a time (the only one before issue 32; now kept for many sparse levels),
  alternated with the grouped kernel ``--repeat`` times, and checked equal to it;
- ``exact``: the exact median (``median_exact``) on the full tile, the reference for
  the approximation's error;
- ``scipy``: ``scipy.ndimage.median_filter`` on a sub-volume (it takes minutes on the
  full tile), timed and extrapolated per voxel to the full tile (``--scipy-full`` runs
  it on the whole tile instead), compared with ``median_exact`` on the same voxels.

Errors are in dB, ``|20 log10(b / b_exact)|`` over the voxels with a positive exact
background. The synthetic tile: speckle correlated over about 3 voxels, a 20 dB/m fall
with depth, a strong layer at 1.2 m (+25 dB, like a silt/clay boundary), a few targets,
and the first 0.8 m along-track unimaged (zeros). Settings (boundary, bin width,
``ignore_zeros``) come from ``config/processing.toml``.

Usage::

    python benchmarks/bench_background.py --out bench_background.json [--scipy-full]

Prints the table and writes it, with the machine's load, to ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402

from benchmarks.bench_isa import machine_isa  # noqa: E402
from svss_daq.config import ProcessingConfig, config_path, load  # noqa: E402
from svss_proc.products.background import kernel_voxels, median_exact, median_histogram  # noqa: E402
from svss_proc.products.drc import level_db, normalise  # noqa: E402

log = logging.getLogger("bench_background")

SHAPE = (750, 100, 100)
VOXEL = 0.02


def synthetic_tile(seed: int = 0) -> np.ndarray:
    """Magnitude (float32, uPa-like units) of a synthetic full tile."""
    rng = np.random.default_rng(seed)
    re = rng.standard_normal(SHAPE, dtype=np.float32)
    im = rng.standard_normal(SHAPE, dtype=np.float32)
    re = ndimage.uniform_filter(re, 3)
    im = ndimage.uniform_filter(im, 3)
    mag = np.hypot(re, im)
    depth = (np.arange(SHAPE[2]) + 0.5) * VOXEL
    mag *= (10 ** (-20.0 * depth / 20)).astype(np.float32)[None, None, :]
    layer = int(round(1.2 / VOXEL))
    mag[:, :, layer - 1:layer + 2] *= 10 ** (25 / 20)
    for a, c, d in ((150, 50, 30), (300, 20, 55), (450, 70, 70), (600, 40, 40)):
        mag[a - 2:a + 3, c - 2:c + 3, d - 2:d + 3] *= 10 ** (35 / 20)
    mag[:40] = 0.0
    return mag.astype(np.float32)


def histogram_per_line(mag: np.ndarray, kernel, bin_db: float, boundary: str,
                       ignore_zeros: bool) -> np.ndarray:
    """``median_histogram`` through the per-line kernel (``_sliding_median_levels``)
    instead of the grouped one: the same quantisation, padding and table."""
    from svss_proc.products import background as bg
    flat = np.ascontiguousarray(mag).reshape(-1)
    lo, hi = bg._positive_db_range(flat)
    n_bins = 0 if lo > hi else int(np.floor((hi - lo) / bin_db + 0.5)) + 1
    lo = lo if n_bins else 0.0
    levels = bg._quantise_db(flat, bool(ignore_zeros), lo, float(bin_db), max(n_bins, 1),
                             np.empty(flat.size, dtype=np.int32)).reshape(mag.shape)
    padded = np.ascontiguousarray(bg._pad(levels, kernel, boundary), dtype=np.int32)
    med = np.empty(mag.shape, dtype=np.int32)
    bg._sliding_median_levels(padded, *kernel, max(n_bins + 1, 1), n_bins + 1 > 4096,
                              np.zeros(1, dtype=np.uint16), numba.get_num_threads(), med)
    table = np.concatenate([[0.0], 10.0 ** ((lo + np.arange(n_bins) * bin_db) / 20.0),
                            [np.nan]])
    return table.astype(np.float32)[med]


def timed(fn, *args, **kw):
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0


def error_db(approx: np.ndarray, exact: np.ndarray) -> dict:
    pos = (exact > 0) & np.isfinite(exact)
    if not pos.any():
        return {"median_abs_db": None, "p99_abs_db": None, "max_abs_db": None}
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.abs(20 * np.log10(approx[pos].astype(np.float64) / exact[pos]))
    e[~np.isfinite(e)] = np.inf
    return {"median_abs_db": float(np.median(e)), "p99_abs_db": float(np.percentile(e, 99)),
            "max_abs_db": float(e.max())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="JSON file for the table")
    ap.add_argument("--scipy-full", action="store_true",
                    help="run scipy's median_filter on the whole tile (minutes)")
    ap.add_argument("--sub", default="150,40,30",
                    help="sub-volume for scipy, voxels along,cross,depth (default 150,40,30)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of the approximation")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")

    cfg = load(ProcessingConfig, config_path("processing.toml")).products.background
    kernel = kernel_voxels(cfg.kernel_m, VOXEL)
    load_start = os.getloadavg()
    log.info("kernel %s voxels, %d numba threads, %d CPUs, load average %.2f", kernel,
             numba.get_num_threads(), os.cpu_count(), load_start[0])
    mag = synthetic_tile()
    n_full = mag.size
    # compile (or load from the cache) outside the timings
    small = mag[40:110, :20, :20]
    median_histogram(small, kernel, cfg.histogram_bin_db, cfg.boundary, cfg.ignore_zeros)
    median_exact(small, kernel, cfg.boundary, cfg.ignore_zeros)
    histogram_per_line(small, kernel, cfg.histogram_bin_db, cfg.boundary, cfg.ignore_zeros)

    rows = []
    t_hist, t_line, cpu_hist, cpu_line = [], [], [], []
    for _ in range(max(args.repeat, 1)):          # alternated: the same minutes of load
        c0 = time.process_time()
        approx, t = timed(median_histogram, mag, kernel, cfg.histogram_bin_db, cfg.boundary,
                          cfg.ignore_zeros)
        cpu_hist.append(time.process_time() - c0)
        t_hist.append(t)
        c0 = time.process_time()
        per_line, t = timed(histogram_per_line, mag, kernel, cfg.histogram_bin_db,
                            cfg.boundary, cfg.ignore_zeros)
        cpu_line.append(time.process_time() - c0)
        t_line.append(t)
    grouped_equals_per_line = bool(np.array_equal(approx, per_line, equal_nan=True))
    t_norm = []
    for _ in range(max(args.repeat, 1)):
        t0 = time.perf_counter()
        b = median_histogram(mag, kernel, cfg.histogram_bin_db, cfg.boundary,
                             cfg.ignore_zeros)
        level_db(normalise(mag, b, cfg.floor_db))
        t_norm.append(time.perf_counter() - t0)
    exact, t_exact = timed(median_exact, mag, kernel, cfg.boundary, cfg.ignore_zeros)
    err = error_db(approx, exact)
    rows.append({"method": f"histogram ({cfg.histogram_bin_db} dB bins)", "voxels": n_full,
                 "time_s": min(t_hist), "times_s": t_hist, "cpu_s": min(cpu_hist),
                 "full_tile_s": min(t_hist), "full_tile": "measured", "reference": "exact",
                 **err, "bound_db": cfg.histogram_bin_db / 2})
    rows.append({"method": "histogram, per-line kernel", "voxels": n_full,
                 "time_s": min(t_line), "times_s": t_line, "cpu_s": min(cpu_line),
                 "full_tile_s": min(t_line),
                 "full_tile": "measured; equal to grouped: " + str(grouped_equals_per_line),
                 "reference": "exact", **error_db(per_line, exact),
                 "bound_db": cfg.histogram_bin_db / 2})
    rows.append({"method": "histogram + normalisation", "voxels": n_full,
                 "time_s": min(t_norm), "times_s": t_norm, "full_tile_s": min(t_norm),
                 "full_tile": "measured", "reference": "exact", **err,
                 "bound_db": cfg.histogram_bin_db / 2})
    rows.append({"method": "exact", "voxels": n_full, "time_s": t_exact,
                 "full_tile_s": t_exact, "full_tile": "measured", "reference": "-",
                 "median_abs_db": 0.0, "p99_abs_db": 0.0, "max_abs_db": 0.0})

    if args.scipy_full:
        sub = (slice(None),) * 3
    else:
        na, nc, nd = (int(v) for v in args.sub.split(","))
        a0, c0, d0 = 300, 30, 35   # inside the imaged part, across the bright layer
        sub = (slice(a0, a0 + na), slice(c0, c0 + nc), slice(d0, d0 + nd))
    vol = np.ascontiguousarray(mag[sub])
    mode = cfg.boundary if cfg.boundary != "truncate" else "reflect"  # scipy has no truncate
    ref, t_scipy = timed(ndimage.median_filter, vol, size=kernel, mode=mode)
    ours, t_ours_sub = timed(median_exact, vol, kernel, mode)
    approx_sub = median_histogram(vol, kernel, cfg.histogram_bin_db, mode)
    full = t_scipy * n_full / vol.size
    rows.append({"method": "scipy.ndimage.median_filter", "voxels": int(vol.size),
                 "time_s": t_scipy, "full_tile_s": full,
                 "full_tile": "measured" if args.scipy_full else
                 f"extrapolated per voxel from {'x'.join(map(str, vol.shape))}",
                 "reference": "-", "median_abs_db": 0.0, "p99_abs_db": 0.0,
                 "max_abs_db": 0.0})
    sub_check = {"shape": list(vol.shape), "exact_equals_scipy": bool(np.array_equal(ours, ref)),
                 "exact_time_s": t_ours_sub,
                 "histogram_vs_scipy": error_db(approx_sub, ref)}
    load_end = os.getloadavg()

    print(f"\nBackground median, kernel {kernel[0]}x{kernel[1]}x{kernel[2]} voxels, full tile "
          f"{SHAPE[0]}x{SHAPE[1]}x{SHAPE[2]}, {numba.get_num_threads()} threads; load "
          f"average {load_start[0]:.2f} -> {load_end[0]:.2f} on {os.cpu_count()} CPUs")
    head = f"{'method':<32}{'voxels':>10}{'time s':>9}{'tile s':>9}  {'median|e| dB':>12}" \
           f"{'p99 dB':>8}{'max dB':>8}  full-tile time"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['method']:<32}{r['voxels']:>10d}{r['time_s']:>9.2f}{r['full_tile_s']:>9.1f}"
              f"  {r['median_abs_db']:>12.4f}{r['p99_abs_db']:>8.4f}{r['max_abs_db']:>8.4f}"
              f"  {r['full_tile']}")
    print(f"grouped kernel / per-line kernel, wall: {min(t_hist) / min(t_line):.2f}, CPU: "
          f"{min(cpu_hist) / min(cpu_line):.2f} (fastest of {len(t_hist)} each, "
          f"alternated); equal: {grouped_equals_per_line}")
    print(f"sub-volume {sub_check['shape']}: exact == scipy: {sub_check['exact_equals_scipy']}"
          f" (exact {sub_check['exact_time_s']:.2f} s vs scipy {t_scipy:.2f} s); histogram vs"
          f" scipy max {sub_check['histogram_vs_scipy']['max_abs_db']:.4f} dB")
    report = {"shape": SHAPE, "kernel_voxels": kernel, "kernel_m": cfg.kernel_m,
              "boundary": cfg.boundary, "ignore_zeros": cfg.ignore_zeros,
              "histogram_bin_db": cfg.histogram_bin_db, "numba_threads":
              numba.get_num_threads(), "cpu_count": os.cpu_count(),
              "load_average_start": load_start, "load_average_end": load_end,
              "rows": rows, "sub_volume_check": sub_check,
              "grouped_equals_per_line": grouped_equals_per_line,
              "grouped_over_per_line_wall": min(t_hist) / min(t_line),
              "command": " ".join(["python", "benchmarks/bench_background.py"] + sys.argv[1:]),
              "machine": machine_isa()}
    Path(args.out).write_text(json.dumps(report, indent=2))
    log.info("wrote %s", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
