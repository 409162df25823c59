"""Measures of the reproduction (pure functions of arrays; no simulation, no files).

**Depth profile** (:func:`depth_profile`): the mean intensity |image|^2 over the voxels of
each depth layer in a column under the track (the cross-track half-width and along-track
span chosen by the caller), leaving out a sphere about the target; in dB re its maximum.

**Multipath features** (:func:`multipath_features`, the rule of docs/reproduce.md): the
features of a profile are its local maxima deeper than ``min_depth`` (clear of the
interface's own return) whose prominence -- the height above the higher of the two
lowest points reached on the way to a higher maximum (or the profile's end) on either
side -- is at least ``min_prominence_db`` (3 dB). Of the two most prominent features,
the shallower is the first-order multipath, the deeper the second-order. Each feature's depth is its **peak**, refined by
a parabola (in dB) through the maximum and its two neighbours; its **onset** is where
the profile, coming from above, first rises to within ``onset_db`` (3 dB) of the peak
(linear interpolation between voxels).

**Excess** (:func:`target_excess`): as the products define a contact's excess (docs/
products.md): the level L = 20 log10(|image| / B) at the target's peak voxel, B the 3-D
median background (the products' kernel, method and boundary), the peak being the
largest |image| within ``radius`` of the target's true centre. Beside it,
:func:`surround_excess`: the same peak over the median |image| at its depth away from
the target (which the products' window cannot guarantee for a long target lying along
the track's axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svss_proc.products.background import kernel_voxels, median_background
from svss_proc.products.drc import level_db, normalise


def depth_profile(image: np.ndarray, axes, half_width: float,
                  along: tuple[float, float] | None = None,
                  exclude_along: tuple[float, float] | None = None) -> np.ndarray:
    """Mean intensity per depth layer (|image|^2, uPa^2; NaN where a layer has no voxel)
    over |cross| <= ``half_width`` and ``along`` (m; None: all), leaving out the columns
    whose along-track position lies within ``exclude_along`` = (centre, half-length) (m;
    a target and its own multipath echoes, which lie below it) and voxels no ping
    reached (exact zeros)."""
    a, c, _d = (np.asarray(x, dtype=np.float64) for x in axes)
    inten = np.abs(np.asarray(image, dtype=np.complex128)) ** 2
    cols = np.abs(c) <= half_width
    rows = np.ones(a.size, bool)
    if along is not None:
        rows &= (a >= along[0]) & (a <= along[1])
    if exclude_along is not None:
        rows &= np.abs(a - exclude_along[0]) > exclude_along[1]
    sel = rows[:, None, None] & cols[None, :, None] & (inten > 0)
    num = np.where(sel, inten, 0.0).sum(axis=(0, 1))
    cnt = sel.sum(axis=(0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, num / np.maximum(cnt, 1), np.nan)


def to_db(profile: np.ndarray) -> np.ndarray:
    """10 log10 of an intensity profile re its largest finite value (dB)."""
    p = np.asarray(profile, dtype=np.float64)
    top = np.nanmax(p)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 10 * np.log10(p / top)


@dataclass(frozen=True)
class Feature:
    """A profile feature: peak depth (m, parabola-refined), onset depth (m), peak level
    (dB, as the profile) and prominence (dB)."""
    depth: float
    onset: float
    level_db: float
    prominence_db: float


def prominences(db: np.ndarray, peaks: np.ndarray) -> np.ndarray:
    """Topographic prominence (dB) of each index in ``peaks`` of ``db`` (see the module
    docstring); NaN samples end a side."""
    out = np.empty(len(peaks))
    n = db.size
    for k, i in enumerate(peaks):
        bases = []
        for step in (-1, 1):
            j, low = i + step, db[i]
            while 0 <= j < n and np.isfinite(db[j]) and db[j] <= db[i]:
                low = min(low, db[j])
                j += step
            bases.append(low)
        out[k] = db[i] - max(bases)
    return out


def refine_peak(x: np.ndarray, y: np.ndarray, i: int) -> float:
    """Position of the vertex of the parabola through samples i-1, i, i+1 (evenly
    spaced ``x``); x[i] at either end or where it is not a maximum."""
    if i <= 0 or i >= len(y) - 1 or not np.all(np.isfinite(y[i - 1:i + 2])):
        return float(x[i])
    y0, y1, y2 = y[i - 1], y[i], y[i + 1]
    den = y0 - 2 * y1 + y2
    if den >= 0:
        return float(x[i])
    off = 0.5 * (y0 - y2) / den
    return float(x[i] + np.clip(off, -0.5, 0.5) * (x[i + 1] - x[i]))


def onset(x: np.ndarray, db: np.ndarray, i: int, drop_db: float) -> float:
    """Shallowest depth above peak ``i`` from which the profile stays within
    ``drop_db`` of the peak down to it: going up from the peak, the first crossing of
    peak - drop_db, interpolated linearly; x[0] if never crossed."""
    level = db[i] - drop_db
    j = i
    while j > 0 and np.isfinite(db[j - 1]) and db[j - 1] >= level:
        j -= 1
    if j == 0 or not np.isfinite(db[j - 1]):
        return float(x[j])
    f = (level - db[j - 1]) / (db[j] - db[j - 1])
    return float(x[j - 1] + f * (x[j] - x[j - 1]))


def find_features(depth: np.ndarray, db: np.ndarray, min_depth: float,
                  min_prominence_db: float, onset_db: float = 3.0) -> list[Feature]:
    """Every feature of the profile ``db`` (dB) over ``depth`` (m, increasing) by the
    rule of the module docstring, shallowest first."""
    depth = np.asarray(depth, dtype=np.float64)
    db = np.asarray(db, dtype=np.float64)
    inner = np.arange(1, db.size - 1)
    is_max = (np.isfinite(db[inner]) & (db[inner] > db[inner - 1])
              & (db[inner] >= db[inner + 1]) & (depth[inner] > min_depth))
    peaks = inner[is_max]
    prom = prominences(db, peaks)
    out = []
    for i, p in zip(peaks, prom):
        if p >= min_prominence_db:
            out.append(Feature(refine_peak(depth, db, int(i)), onset(depth, db, int(i), onset_db),
                               float(db[i]), float(p)))
    return out


def multipath_features(depth: np.ndarray, db: np.ndarray, min_depth: float = 0.2,
                       min_prominence_db: float = 3.0, onset_db: float = 3.0
                       ) -> tuple[Feature | None, Feature | None, list[Feature]]:
    """(first-order, second-order, all features) of a depth profile: of the two most
    prominent features, the shallower and the deeper (the second None when there is
    one feature only, both None when there is none)."""
    feats = find_features(depth, db, min_depth, min_prominence_db, onset_db)
    top = sorted(sorted(feats, key=lambda f: -f.prominence_db)[:2], key=lambda f: f.depth)
    first = top[0] if top else None
    second = top[1] if len(top) > 1 else None
    return first, second, feats


def multipath_depth_expected(extra_path_m: float, water_speed: float,
                             sediment_speed: float) -> float:
    """The path arithmetic (PHYSICS.md section 8): a path ``extra_path_m`` longer than
    the direct bottom return maps, at nadir, to the sediment depth
    extra / c_w * c_sed / 2 (m)."""
    return extra_path_m / water_speed * sediment_speed / 2.0


@dataclass(frozen=True)
class Excess:
    """A target's excess: ``excess_db`` (L at the peak, dB re the median background),
    the peak position (along, cross, depth; m), its magnitude and background (uPa)."""
    excess_db: float
    peak: tuple[float, float, float]
    peak_upa: float
    background_upa: float


def background(mag: np.ndarray, voxel_m: float, kernel_m=(1.2, 0.2, 0.1),
               method: str = "histogram", bin_db: float = 0.05,
               boundary: str = "reflect") -> np.ndarray:
    """The products' 3-D median background of ``mag`` (docs/products.md), voxels no ping
    reached left out."""
    return median_background(np.ascontiguousarray(mag, dtype=np.float32),
                             kernel_voxels(tuple(kernel_m), voxel_m), method, bin_db,
                             boundary, ignore_zeros=True)


def _peak_near(mag: np.ndarray, axes, centre: tuple[float, float, float],
               radius: float):
    """The voxel axes (float64) and the index (i, j, k) of the largest ``mag`` within
    ``radius`` (m) of ``centre``; ValueError where no imaged voxel is that near."""
    a, c, d = (np.asarray(x, dtype=np.float64) for x in axes)
    r2 = ((a[:, None, None] - centre[0]) ** 2 + (c[None, :, None] - centre[1]) ** 2
          + (d[None, None, :] - centre[2]) ** 2)
    near = np.where(r2 <= radius ** 2, mag, -1.0)
    if near.max() <= 0:
        raise ValueError(f"no imaged voxel within {radius} m of the target at {centre}")
    return (a, c, d), np.unravel_index(int(np.argmax(near)), mag.shape)


def target_excess(image: np.ndarray, axes, voxel_m: float, centre: tuple[float, float, float],
                  radius: float = 0.3, kernel_m=(1.2, 0.2, 0.1), method: str = "histogram",
                  bin_db: float = 0.05, boundary: str = "reflect",
                  floor_db: float = -60.0) -> Excess:
    """The target's excess (see the module docstring): ``image`` complex or magnitude
    (along x cross x depth), ``axes`` its voxel centres (m), ``centre`` the target's true
    centre (m), ``radius`` (m) the search radius of its peak."""
    mag = np.abs(np.asarray(image)).astype(np.float32)
    bg = background(mag, voxel_m, kernel_m, method, bin_db, boundary)
    level = level_db(normalise(mag, bg, floor_db))
    (a, c, d), (i, j, k) = _peak_near(mag, axes, centre, radius)
    return Excess(float(level[i, j, k]), (float(a[i]), float(c[j]), float(d[k])),
                  float(mag[i, j, k]), float(bg[i, j, k]))


def surround_excess(image: np.ndarray, axes, centre: tuple[float, float, float],
                    radius: float = 0.3, keep_out: float = 0.6,
                    band: float = 0.05) -> Excess:
    """The target's excess over its surroundings (dB): the peak |image| within
    ``radius`` (m) of ``centre`` over the median |image| of the voxels in the depth band
    ``band`` (m) either side of the peak's depth whose horizontal distance from the
    target's centre exceeds ``keep_out`` (m). Unlike :func:`target_excess`, the
    background cannot hold the target itself (the products' 1.2 m x 0.2 m x 0.1 m median
    window is half filled by a 61 cm cylinder lying along the track)."""
    mag = np.abs(np.asarray(image)).astype(np.float64)
    (a, c, d), (i, j, k) = _peak_near(mag, axes, centre, radius)
    h2 = (a[:, None] - centre[0]) ** 2 + (c[None, :] - centre[1]) ** 2
    ring = (h2 > keep_out ** 2)[:, :, None] & (np.abs(d - d[k]) <= band + 1e-9)[None, None, :]
    vals = mag[ring & (mag > 0)]
    if vals.size == 0:
        raise ValueError(f"no imaged voxel farther than {keep_out} m from the target")
    bg = float(np.median(vals))
    return Excess(float(20 * np.log10(mag[i, j, k] / bg)),
                  (float(a[i]), float(c[j]), float(d[k])), float(mag[i, j, k]), bg)
