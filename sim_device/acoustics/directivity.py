"""Transducer directivity, as linear amplitude gains (1 on axis).

* Circular piston in a rigid baffle (far field): b(θ) = 2 J1(x)/x, x = k a sinθ, with θ the
  angle off the acoustic axis (rad), k = 2πf/c, a the piston radius. The sign is kept
  (side lobes alternate); |b| is the magnitude. Half power (|b| = 1/√2, −3.01 dB) at
  x = 1.6163, exactly −3.00 dB at x = 1.6129; first null at x = 3.8317 (first zero of J1).
* Cone gate: 1 inside a cone of given half-angle, 0 outside, with an optional raised-cosine
  taper of given width centred on the edge (gain ½ at the half-angle; width 0 gives the
  hard edge with the boundary itself inside).

Angles in radians, frequency Hz, speeds m/s, lengths m. dB helpers: :mod:`svss_daq.decibels`
(20 log10 for these amplitude gains).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq
from scipy.special import j1, jn_zeros

__all__ = [
    "piston_directivity",
    "piston_x_at_gain",
    "piston_radius_for_half_angle",
    "piston_first_null",
    "cone_gate",
]


def _piston_of_x(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-6
    safe = np.where(small, 1.0, x)
    return np.where(small, 1.0 - x * x / 8.0, 2.0 * j1(safe) / safe)


def piston_directivity(off_axis_angle: ArrayLike, frequency: ArrayLike, radius: ArrayLike,
                       sound_speed: ArrayLike) -> np.ndarray:
    """Far-field amplitude gain 2 J1(x)/x, x = k a sinθ, of a baffled circular piston.

    off_axis_angle θ (rad from the axis); frequency Hz; radius a (m); sound_speed m/s.
    Returns the signed real gain (1 on axis).
    """
    k = 2.0 * np.pi * np.asarray(frequency, dtype=float) / np.asarray(sound_speed, dtype=float)
    x = k * np.asarray(radius, dtype=float) * np.sin(np.asarray(off_axis_angle, dtype=float))
    return _piston_of_x(x)


@lru_cache(maxsize=32)
def piston_x_at_gain(gain: float = 2.0 ** -0.5) -> float:
    """The x = k a sinθ of the main lobe where 2 J1(x)/x falls to `gain` (0 < gain < 1)."""
    if not 0.0 < gain < 1.0:
        raise ValueError("gain must lie in (0, 1)")
    first_null = float(jn_zeros(1, 1)[0])
    return float(brentq(lambda x: float(_piston_of_x(x)) - gain, 1e-9, first_null,
                        xtol=1e-14, rtol=1e-15))


def piston_first_null(frequency: ArrayLike, radius: ArrayLike,
                      sound_speed: ArrayLike) -> np.ndarray:
    """Off-axis angle (rad) of the first null, sinθ = 3.8317/(k a); NaN if k a < 3.8317."""
    k = 2.0 * np.pi * np.asarray(frequency, dtype=float) / np.asarray(sound_speed, dtype=float)
    s = float(jn_zeros(1, 1)[0]) / (k * np.asarray(radius, dtype=float))
    with np.errstate(invalid="ignore"):
        return np.where(s <= 1.0, np.arcsin(np.minimum(s, 1.0)), np.nan)


def piston_radius_for_half_angle(half_angle: ArrayLike, frequency: ArrayLike,
                                 sound_speed: ArrayLike, level_db: float = -3.0) -> np.ndarray:
    """Piston radius (m) whose one-way gain is `level_db` (default −3 dB) at `half_angle`.

    a = x_g / (k sin θ_h), x_g from :func:`piston_x_at_gain`. half_angle rad (0, π/2];
    frequency Hz; sound_speed m/s.
    """
    th = np.asarray(half_angle, dtype=float)
    if np.any(~((th > 0) & (th <= np.pi / 2))):
        raise ValueError("half_angle must lie in (0, pi/2] rad")
    x = piston_x_at_gain(10.0 ** (level_db / 20.0))
    k = 2.0 * np.pi * np.asarray(frequency, dtype=float) / np.asarray(sound_speed, dtype=float)
    return x / (k * np.sin(th))


def cone_gate(off_axis_angle: ArrayLike, half_angle: ArrayLike,
              taper_width: ArrayLike = 0.0) -> np.ndarray:
    """Amplitude gate of a cone: 1 inside, 0 outside, raised-cosine taper across the edge.

    g = 1 for θ ≤ θ_h − w/2, 0 for θ ≥ θ_h + w/2, ½[1 + cos(π(θ − θ_h + w/2)/w)] between;
    w = 0 gives a hard edge (θ ≤ θ_h → 1). off_axis_angle θ, half_angle θ_h, taper_width w
    all in rad.
    """
    th = np.abs(np.asarray(off_axis_angle, dtype=float))
    h = np.asarray(half_angle, dtype=float)
    w = np.asarray(taper_width, dtype=float)
    if np.any(w < 0):
        raise ValueError("taper_width must be >= 0")
    hard = np.where(th <= h, 1.0, 0.0)
    safe_w = np.where(w > 0, w, 1.0)
    u = np.clip((th - h + 0.5 * w) / safe_w, 0.0, 1.0)
    soft = 0.5 * (1.0 + np.cos(np.pi * u))
    return np.where(w > 0, soft, hard)
