"""Normalisation options: the background (3-D sliding median) by the exact method
against the histogram median at several bin widths, on a tile.

The tile is synthetic, as ``benchmarks/bench_background.py``'s: correlated Rayleigh
speckle falling 20 dB/m with depth, a bright layer at 60 % of the depth (+25 dB), a
few 35 dB targets and the first 5 % along-track unimaged (zeros); full: the processing
configuration's tile (750 x 100 x 100 voxels at 2 cm), quick: 160 x 40 x 40 voxels (time
extrapolated per voxel). Kernel, boundary and zeros as ``[products.background]``.
Errors of each background against the exact one, |20 log10(b / b_exact)| over the
voxels with a positive exact background: ``max_db`` (the row's error) and ``mean_db``.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
from scipy import ndimage

from svss_daq.config import ProcessingConfig
from svss_proc.imaging.grid import n_voxels
from svss_proc.products.background import kernel_voxels, median_background

log = logging.getLogger(__name__)


def synthetic_tile(shape: tuple[int, int, int], voxel_m: float, seed: int = 0) -> np.ndarray:
    """Magnitude (float32) of a synthetic tile (module docstring)."""
    rng = np.random.default_rng(seed)
    re = ndimage.uniform_filter(rng.standard_normal(shape, dtype=np.float32), 3)
    im = ndimage.uniform_filter(rng.standard_normal(shape, dtype=np.float32), 3)
    mag = np.hypot(re, im)
    depth = (np.arange(shape[2]) + 0.5) * voxel_m
    mag *= (10 ** (-depth)).astype(np.float32)[None, None, :]          # 20 dB/m
    k = int(0.6 * shape[2])
    mag[:, :, max(k - 1, 0):k + 2] *= 10 ** (25 / 20)
    for f in (0.2, 0.4, 0.6, 0.8):
        a, c, d = int(f * shape[0]), int(f * shape[1]), int((1 - f) * shape[2])
        mag[max(a - 2, 0):a + 3, max(c - 2, 0):c + 3, max(d - 2, 0):d + 3] *= 10 ** (35 / 20)
    mag[: max(1, shape[0] // 20)] = 0.0
    return mag.astype(np.float32)


def _error(b, exact) -> dict:
    pos = (exact > 0) & np.isfinite(exact)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.abs(20 * np.log10(b[pos].astype(np.float64) / exact[pos]))
    e[~np.isfinite(e)] = np.inf
    return {"max_db": float(e.max()) if e.size else 0.0,
            "mean_db": float(e.mean()) if e.size else 0.0}


def run(proc: ProcessingConfig, quick: bool) -> list[dict]:
    cfg = proc.products.background
    t = proc.tile
    v = t.voxel_m
    full_shape = (n_voxels(t.length_m, v), n_voxels(t.width_m, v), n_voxels(t.depth_m, v))
    shape = (160, 40, 40) if quick else full_shape
    mag = synthetic_tile(shape, v)
    kernel = kernel_voxels(cfg.kernel_m, v)
    ratio = math.prod(full_shape) / mag.size
    small = np.ascontiguousarray(mag[: min(16, shape[0]), :8, :8])
    bins = (0.25, 1.0) if quick else (0.1, 0.25, 0.5, 1.0, 2.0)
    rows = [("reference", "exact", ("exact", cfg.histogram_bin_db)),
            ("default", f"{cfg.method}" + (f" {cfg.histogram_bin_db:g} dB"
                                           if cfg.method == "histogram" else ""),
             (cfg.method, cfg.histogram_bin_db))]
    rows += [("method", f"histogram {b:g} dB", ("histogram", b)) for b in bins
             if not (cfg.method == "histogram" and b == cfg.histogram_bin_db)]
    if cfg.method != "histogram":
        rows.append(("method", f"histogram {cfg.histogram_bin_db:g} dB",
                     ("histogram", cfg.histogram_bin_db)))
    out, exact = [], None
    for opt, val, (method, bin_db) in rows:
        median_background(small, kernel, method, bin_db, cfg.boundary, cfg.ignore_zeros)
        t0 = time.perf_counter()
        b = median_background(mag, kernel, method, bin_db, cfg.boundary, cfg.ignore_zeros)
        el = time.perf_counter() - t0
        if opt == "reference":
            exact = b
        err = _error(b, exact)
        out.append({"area": "normalisation", "option": opt, "value": val,
                    "setting": {"method": method, "histogram_bin_db": bin_db},
                    "is_reference": opt == "reference", "is_default": opt == "default",
                    "time_s": el, "tile_s": el * ratio, "error": err["max_db"],
                    "error_name": "largest background difference (dB)",
                    "metrics": {**err, "voxels": int(mag.size),
                                "kernel_voxels": list(kernel)}})
        log.info("normalisation %s: %.2f s, max %.3f dB", val, el, err["max_db"])
    return out
