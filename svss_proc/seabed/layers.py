"""A layer boundary below the interface, from an image's level against depth.

Where a slower sediment lies over a faster, denser one (silt over sand or over clay),
the boundary returns a coherent echo and the volume below it scatters at its own level:
the median magnitude of each depth plane (over the voxels imaged) steps up there, then
decays with the lower layer's attenuation. A homogeneous sediment's median only decays.
The boundary is the depth where the median level stands most over the median of the
levels within a window about it, if by at least a threshold. The interface's own echo
by way of the sea surface also stands out, at the depth its extra path maps to; there
only a level brighter than the interface's is taken for a boundary.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter


def depth_profile_db(tiles: list) -> tuple[np.ndarray, np.ndarray]:
    """(depths m, level dB): each depth plane's median magnitude over the imaged voxels
    of all ``tiles`` (one grid depth axis; levels -inf where a plane has none)."""
    if not tiles:
        return np.zeros(0), np.zeros(0)
    depth = np.asarray(tiles[0].grid.depth, dtype=np.float64)
    planes = [[] for _ in depth]
    for t in tiles:
        mag = np.abs(np.asarray(t.image))
        for k in range(min(mag.shape[2], depth.size)):
            v = mag[:, :, k]
            v = v[v > 0]
            if v.size:
                planes[k].append(v)
    level = np.full(depth.size, -np.inf)
    for k, vs in enumerate(planes):
        if vs:
            level[k] = 20 * np.log10(max(float(np.median(np.concatenate(vs))), 1e-300))
    return depth, level


def boundary_in_profile(depth: np.ndarray, level_db: np.ndarray, min_depth_m: float,
                        window_m: float, min_db: float,
                        exclude: tuple[float, float] | None = None
                        ) -> tuple[float, float] | None:
    """(depth m, excess dB) of the strongest excess of ``level_db`` over its running
    median across ``window_m`` at or below ``min_depth_m`` (and a half window above the
    profile's last depth), if at least ``min_db``; else None. ``exclude``: (depth,
    half-width) m where the interface's echo by way of the sea surface appears: a level
    there is a boundary only if it is brighter than the interface's own (the levels
    above ``min_depth_m``): that echo is the interface's, weakened by the bounce and
    the longer path, and defocused. The excess is refined to a parabola's vertex
    through its neighbours."""
    depth = np.asarray(depth, dtype=np.float64)
    level = np.asarray(level_db, dtype=np.float64)
    ok = np.isfinite(level)
    if depth.size < 5 or ok.sum() < 5:
        return None
    step = float(np.median(np.diff(depth)))
    width = max(3, int(round(window_m / step)) | 1)
    filled = np.where(ok, level, np.min(level[ok]))
    excess = filled - median_filter(filled, size=width, mode="nearest")
    half = width // 2
    usable = ok & (depth >= min_depth_m) & (np.arange(depth.size) < depth.size - half)
    if exclude is not None:
        top = ok & (depth < min_depth_m)
        interface_db = float(np.max(level[top])) if top.any() else np.inf
        usable &= (np.abs(depth - exclude[0]) > exclude[1]) | (filled > interface_db)
    if not usable.any():
        return None
    i = int(np.flatnonzero(usable)[np.argmax(excess[usable])])
    if excess[i] < min_db:
        return None
    z = depth[i]
    if 0 < i < depth.size - 1:
        a, b, _ = np.polyfit([-step, 0.0, step], excess[i - 1:i + 2], 2)
        if a < 0:
            z += float(np.clip(-b / (2 * a), -step, step))
    return float(z), float(excess[i])


def find_boundary(tiles: list, min_depth_m: float, window_m: float, min_db: float,
                  exclude: tuple[float, float] | None = None
                  ) -> tuple[float, float] | None:
    """A layer boundary in ``tiles``' image (module docstring): (its depth in the image,
    m; its level over the levels about it, dB), or None; ``exclude`` as
    :func:`boundary_in_profile`'s."""
    depth, level = depth_profile_db(tiles)
    return boundary_in_profile(depth, level, min_depth_m, window_m, min_db, exclude)


def profile_peak(depth: np.ndarray, level_db: np.ndarray) -> float | None:
    """The depth (m) of the largest finite level inside the profile (not at either
    end), refined to a parabola's vertex through its neighbours; None: none inside."""
    got = profile_peak_level(depth, level_db)
    return None if got is None else got[0]


def profile_peak_level(depth: np.ndarray, level_db: np.ndarray
                       ) -> tuple[float, float] | None:
    """(depth m, level dB) of :func:`profile_peak`'s peak, the level the parabola's
    vertex's."""
    level = np.where(np.isfinite(level_db), level_db, -np.inf)
    if level.size < 3:
        return None
    i = int(np.argmax(level))
    if i == 0 or i == level.size - 1 or not np.all(np.isfinite(level[i - 1:i + 2])):
        return None
    step = float(depth[i + 1] - depth[i])
    a, b, c = np.polyfit([-step, 0.0, step], level[i - 1:i + 2], 2)
    dz = float(np.clip(-b / (2 * a), -step, step)) if a < 0 else 0.0
    return float(depth[i]) + dz, float(a * dz * dz + b * dz + c)
