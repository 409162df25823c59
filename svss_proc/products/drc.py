"""Normalisation by the background, depth-varying gain and dynamic range compression.

The chain (docs/products.md), for a magnitude ``m`` (uPa) and its background ``b``
(uPa, :mod:`svss_proc.products.background`):

1. normalised amplitude ``r = m / max(b, b_floor)``, where ``b_floor`` is the tile's
   median background times ``10**(floor_db / 20)``: never a division by zero, and
   voxels whose window held no data (``b`` NaN) are divided by ``b_floor``;
2. normalised level ``L = 20 log10 r`` in dB re background (0 dB: the local median;
   zeros give ``-inf`` clipped to :data:`MIN_DB`, never ``log(0)``; NaN stays NaN);
3. an optional depth-varying gain ``g(z) = db_per_m * max(z - start_m, 0)`` dB added to
   ``L`` for display (detections use ``L`` without it);
4. dynamic range compression to display values in ``[0, 1]``: the logarithmic map of
   step 2, followed by a nonlinear intensity map that is linear in dB from ``floor_db``
   (0) to ``knee_db`` and above the knee bends smoothly (same slope at the knee) towards
   ``ceiling_db`` (1), which it approaches but never reaches::

       y = L                                     floor_db <= L <= knee_db
       y = knee + s (1 - exp(-(L - knee) / s))   L > knee_db,  s = ceiling_db - knee_db
       u = (y - floor_db) / (ceiling_db - floor_db)

   so the most extreme values (strong interface returns) are compressed while weak
   sub-bottom returns keep their dB scale. Below ``floor_db`` and NaN map to 0.
"""

from __future__ import annotations

import numpy as np

from svss_daq.decibels import amplitude_to_db_floored

#: lowest level reported, dB (what zeros map to)
MIN_DB = -300.0


def background_floor(background: np.ndarray, floor_db: float) -> float:
    """Smallest divisor: the median of the finite positive background times
    ``10**(floor_db / 20)`` (uPa); 1.0 when there is no positive background."""
    b = background[np.isfinite(background) & (background > 0)]
    if b.size == 0:
        return 1.0
    if b.size > 1_000_000:  # a strided sample estimates the median well enough
        b = b[:: b.size // 1_000_000]
    return float(np.median(b)) * 10.0 ** (floor_db / 20.0)


def normalise(mag: np.ndarray, background: np.ndarray, floor_db: float,
              floor: float | None = None) -> np.ndarray:
    """Normalised amplitude ``mag / max(background, floor)`` (float32, dimensionless;
    NaN where ``mag`` is NaN). See :func:`background_floor`; ``floor``: that of another
    background (a tile's, for its neighbours' planes across the seams)."""
    floor = np.float32(background_floor(background, floor_db) if floor is None else floor)
    bg = np.asarray(background, dtype=np.float32)
    denom = np.where(np.isfinite(bg) & (bg > floor), bg, floor)
    return (np.asarray(mag, dtype=np.float32) / denom).astype(np.float32)


def level_db(ratio: np.ndarray) -> np.ndarray:
    """``20 log10(ratio)`` (float32), at least :data:`MIN_DB` (no log of zero); NaN
    stays NaN."""
    level = amplitude_to_db_floored(np.asarray(ratio, dtype=np.float32), MIN_DB)
    return level.astype(np.float32, copy=False)  # NaN propagates through the floor


def depth_gain_db(depth_m: np.ndarray, db_per_m: float, start_m: float) -> np.ndarray:
    """Gain (dB) at each depth: ``db_per_m * max(depth - start_m, 0)``."""
    return db_per_m * np.maximum(np.asarray(depth_m, dtype=np.float64) - start_m, 0.0)


def _check(floor_db: float, knee_db: float, ceiling_db: float) -> None:
    if not floor_db < knee_db < ceiling_db:
        raise ValueError(f"compression needs floor < knee < ceiling, got {floor_db}, "
                         f"{knee_db}, {ceiling_db} dB")


def compress(level: np.ndarray, floor_db: float, knee_db: float,
             ceiling_db: float) -> np.ndarray:
    """Display value in [0, 1) (float32) of a level in dB (see the module docstring)."""
    _check(floor_db, knee_db, ceiling_db)
    y = np.array(level, dtype=np.float32)  # a copy; NaN and levels below the floor -> floor
    y[~(y >= floor_db)] = floor_db
    hi = y > knee_db
    s = ceiling_db - knee_db
    y[hi] = knee_db - s * np.expm1(-(y[hi].astype(np.float64) - knee_db) / s)
    y -= floor_db
    y /= ceiling_db - floor_db
    return np.clip(y, 0.0, 1.0, out=y)


def expand(u: np.ndarray, floor_db: float, knee_db: float, ceiling_db: float) -> np.ndarray:
    """Inverse of :func:`compress` for ``0 <= u < 1``: the level (dB) shown as ``u``
    (``floor_db`` for 0, ``inf`` for 1). Used to label colour bars."""
    _check(floor_db, knee_db, ceiling_db)
    u = np.asarray(u, dtype=np.float64)
    y = floor_db + u * (ceiling_db - floor_db)
    s = ceiling_db - knee_db
    with np.errstate(divide="ignore"):
        above = knee_db - s * np.log(np.maximum(1.0 - (y - knee_db) / s, 0.0))
    return np.where(y <= knee_db, y, above)
