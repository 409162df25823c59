"""Heading at any time from the heading sources, and the angle and time helpers the
fusion shares."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .records import HeadingSample

# --------------------------------------------------------------------------- fusion


def wrap_angle(a):
    """Angles (rad) wrapped into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _nearest_age(t_src: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distance (same units) from each t to the nearest t_src (inf if none)."""
    if t_src.size == 0:
        return np.full(t.shape, np.inf)
    i = np.clip(np.searchsorted(t_src, t), 1, t_src.size) - 1
    j = np.clip(i + 1, 0, t_src.size - 1)
    return np.minimum(np.abs(t - t_src[i]), np.abs(t - t_src[j]))


def _interp_angle(t_src, a_src, t):
    if t_src.size == 0:
        return np.full(t.shape, np.nan)
    return wrap_angle(np.interp(t, t_src, np.unwrap(a_src)))


def _headings(t: np.ndarray, heads: Sequence[HeadingSample], max_age_s: float, t0_ns: int,
              compass: Sequence = ()):
    """Heading (rad) at times t (s after ``t0_ns``) and a flag: 0 HDT, 1 course, 2 none,
    3 DVL compass (``compass``: DvlSample with a finite ``heading_rad``). True-heading
    sensors first: HDT within ``max_age_s``, else the DVL compass within ``max_age_s``,
    and only where neither is the course over ground (``from_course`` samples, already
    limited to speeds above ``course_min_speed_m_s``), flagged; none: 0."""
    sec = lambda a: (np.asarray(a, dtype=np.int64) - t0_ns).astype(np.float64) * 1e-9  # noqa: E731
    th = sec([h.time_ns for h in heads if not h.from_course])
    ah = np.array([h.heading_rad for h in heads if not h.from_course], dtype=np.float64)
    tc = sec([h.time_ns for h in heads if h.from_course])
    ac = np.array([h.heading_rad for h in heads if h.from_course], dtype=np.float64)
    tm = sec([d.time_ns for d in compass])
    am = np.array([d.heading_rad for d in compass], dtype=np.float64)
    oh, oc, om = np.argsort(th), np.argsort(tc), np.argsort(tm)
    th, ah, tc, ac, tm, am = th[oh], ah[oh], tc[oc], ac[oc], tm[om], am[om]
    use_h = _nearest_age(th, t) <= max_age_s
    use_m = ~use_h & (_nearest_age(tm, t) <= max_age_s)
    use_c = ~use_h & ~use_m & (_nearest_age(tc, t) <= max_age_s)
    out = np.zeros(t.shape)
    for use, ts, a in ((use_h, th, ah), (use_m, tm, am), (use_c, tc, ac)):
        if use.any():
            out = np.where(use, _interp_angle(ts, a, t), out)
    flag = np.where(use_h, 0, np.where(use_m, 3, np.where(use_c, 1, 2)))
    return out, flag


def _rotations(roll, pitch, heading) -> np.ndarray:
    """:func:`~svss_daq.frames.body_to_ned` of each (roll, pitch, heading), (n, 3, 3)."""
    r, p, h = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (roll, pitch, heading))
    cr, sr, cp, sp, ch, sh = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(h), np.sin(h)
    out = np.empty((r.size, 3, 3))
    out[:, 0, 0] = ch * cp
    out[:, 0, 1] = ch * sp * sr - sh * cr
    out[:, 0, 2] = ch * sp * cr + sh * sr
    out[:, 1, 0] = sh * cp
    out[:, 1, 1] = sh * sp * sr + ch * cr
    out[:, 1, 2] = sh * sp * cr - ch * sr
    out[:, 2, 0] = -sp
    out[:, 2, 1] = cp * sr
    out[:, 2, 2] = cp * cr
    return out
