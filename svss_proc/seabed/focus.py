"""Pure functions of the sediment-speed scan: the focus of a response, the best speed of
a focus curve with its uncertainty, the depth a response moves to with the speed, and
the combination of several responses' speeds.

A buried response imaged with the wrong sediment speed is defocused: the channels' and
pings' echoes do not add in phase at any voxel. Its energy over a box that holds it is
nearly the same whatever the speed (Parseval over the aperture), but its concentration
is not: the focus measure F = sum |I|^4 over the box is largest at the speed that
brings every path into phase, and a grid's sampling of the peak (a voxel's position
against the main lobe) moves it far less than it moves the peak's magnitude.
"""

from __future__ import annotations

import math

import numpy as np


def focus_measure(box: np.ndarray) -> float:
    """sum |I|^4 over a complex image box (float64)."""
    a2 = np.abs(np.asarray(box, dtype=np.complex128)) ** 2
    return float(np.sum(a2 * a2))


def vertical_time(depth: float, tops: np.ndarray, speeds: np.ndarray) -> float:
    """One-way vertical travel time (s) from the interface down to ``depth`` (m) through
    layers from depths ``tops`` (``tops[0]`` = 0) at ``speeds`` (the last a half-space)."""
    t, z = 0.0, max(float(depth), 0.0)
    for k, c in enumerate(speeds):
        top = tops[k]
        bottom = tops[k + 1] if k + 1 < len(tops) else math.inf
        if z <= top:
            break
        t += (min(z, bottom) - top) / c
    return t


def depth_at_time(time_s: float, tops: np.ndarray, speeds: np.ndarray) -> float:
    """The depth (m) reached by one-way vertical time ``time_s`` (the inverse of
    :func:`vertical_time`)."""
    t = float(time_s)
    for k, c in enumerate(speeds):
        top = tops[k]
        bottom = tops[k + 1] if k + 1 < len(tops) else math.inf
        dt = (bottom - top) / c
        if t <= dt:
            return top + t * c
        t -= dt
    return float(tops[-1])                      # not reached: the last is a half-space


def curve_peak(speeds: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """The speed (m/s) where a focus curve peaks and the curvature of its natural log
    there (per (m/s)^2, < 0), by a parabola through the largest value and its
    neighbours. At either end of the scan: that end and a curvature of 0 (not a peak)."""
    s = np.asarray(speeds, dtype=np.float64)
    v = np.log(np.maximum(np.asarray(values, dtype=np.float64), 1e-300))
    order = np.argsort(s)
    s, v = s[order], v[order]
    i = int(np.argmax(v))
    if i == 0 or i == s.size - 1:
        return float(s[i]), 0.0
    a, b, _ = np.polyfit(s[i - 1:i + 2] - s[i], v[i - 1:i + 2], 2)
    if a >= 0:
        return float(s[i]), 0.0
    shift = float(np.clip(-b / (2 * a), s[i - 1] - s[i], s[i + 1] - s[i]))
    return float(s[i]) + shift, float(a)


def point_sigma(curvature: float, contrast_db: float, floor_m_s: float) -> float:
    """One response's speed uncertainty (m/s): the speed change that lowers its focus by
    as much as the background beside it can move it. A background ``contrast_db`` below
    the peak (amplitude ratio e) changes |I|^4 by up to about 4 e; on a parabola of
    curvature a in log F that is a speed change of sqrt(4 e / |a|). Never below
    ``floor_m_s`` (the scan's resolution); infinite without a peak (``curvature`` 0)."""
    if not curvature < 0:
        return math.inf
    e = 10.0 ** (-float(contrast_db) / 20.0)
    return max(math.sqrt(4.0 * e / -curvature), float(floor_m_s))


def combine(speeds: np.ndarray, sigmas: np.ndarray) -> tuple[float, float, float]:
    """Several responses' speeds (m/s) and uncertainties into one: (the inverse-variance
    weighted mean, its standard deviation, the reduced chi-square of the responses about
    it: well above 1 where they disagree by more than their uncertainties, as points
    above and below a layer boundary do). The standard deviation is the larger of the
    weighted mean's and the responses' own scatter over sqrt(n)."""
    c = np.asarray(speeds, dtype=np.float64)
    s = np.asarray(sigmas, dtype=np.float64)
    ok = np.isfinite(c) & np.isfinite(s) & (s > 0)
    c, s = c[ok], s[ok]
    if c.size == 0:
        return math.nan, math.inf, math.nan
    w = 1.0 / s ** 2
    mean = float(np.sum(w * c) / np.sum(w))
    sigma = float(1.0 / math.sqrt(np.sum(w)))
    if c.size < 2:
        return mean, sigma, math.nan
    chi2 = float(np.sum(w * (c - mean) ** 2) / (c.size - 1))
    sigma = max(sigma, float(np.std(c, ddof=1) / math.sqrt(c.size)))
    return mean, sigma, chi2
