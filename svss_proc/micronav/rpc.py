"""Vertical motion between two pings from their redundant phase centres
(docs/phase_centres.md, "Vertical increments").

Channel i of ping a and channel j of ping b whose phase centres coincide horizontally
(:func:`~svss_proc.micronav.phase_centres.pair_phase_centres`) hear the seabed's first
return, the interface within ``max_angle`` of straight below, along the same paths but
for two things: the bistatic excess of each pair (known from the geometry) and the
vertical displacement dz of the phase centre from ping a to ping b (down positive). With
the excess E = |s_h|^2 / (4 h) at the phase centre's height h (s_h the horizontal part
of receiver minus projector; the array near level) and eps = (E_b - E_a) / c, the
baseband samples (:mod:`svss_daq.conventions`: an echo at delay tau has phase
exp(-j 2 pi f_c tau)) give

    C = sum_t bb_a(t) conj(bb_b(t + eps)),    arg C - 2 pi f_c eps = 4 pi f_c dz cos(theta) / c

over the window from the return at nadir to ``max_angle`` (cos(theta) the window's
energy-weighted mean of h / R). The phase is unambiguous for |dz| < lambda / 4 (13.6 mm at
27.5 kHz): a pair is taken between pings close enough for that. Its standard deviation
from the coherence gamma over N independent samples is sqrt((1 - gamma^2) / (2 N
gamma^2)) (the Cramer-Rao bound of a phase estimate). A weighted plane through the pairs'
dz at their phase centres' (x, y) gives the array's heave, roll and pitch increments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svss_daq.geometry import ArrayGeometry

from .phase_centres import PhaseCentrePairs, phase_centres

__all__ = ["PairDisplacements", "VerticalIncrement", "excess_delay_s", "first_return_window",
           "fit_vertical_increment", "pair_vertical_displacements", "shifted_samples"]


@dataclass(frozen=True)
class PairDisplacements:
    """Per pair: ``dz_m`` the phase centre's vertical displacement from ping a to ping b
    (down positive), ``sigma_m`` its standard deviation, ``coherence`` (0..1), ``xy_m``
    (n, 2) the phase centre in ping a's body frame, ``channel_a``, ``channel_b``."""
    dz_m: np.ndarray
    sigma_m: np.ndarray
    coherence: np.ndarray
    xy_m: np.ndarray
    channel_a: np.ndarray
    channel_b: np.ndarray


@dataclass(frozen=True)
class VerticalIncrement:
    """The array's motion from ping a to ping b: ``heave_m`` at the body origin (down
    positive), ``roll_rad`` (starboard down positive), ``pitch_rad`` (nose up positive),
    their standard deviations ``sigma`` (3,), the pairs used and the rms of the pairs
    about the plane, m."""
    heave_m: float
    roll_rad: float
    pitch_rad: float
    sigma: np.ndarray
    n_pairs: int
    rms_residual_m: float


def shifted_samples(bb: np.ndarray, t0: float, dt: float, times: np.ndarray) -> np.ndarray:
    """Complex baseband samples (channels, n) at ``times`` (channels, m), linearly
    interpolated (baseband varies slowly: the band is a few samples wide); 0 outside."""
    u = (times - t0) / dt
    i = np.floor(u).astype(np.int64)
    w = u - i
    n = bb.shape[1]
    ok = (i >= 0) & (i + 1 < n)
    i = np.clip(i, 0, n - 2)
    rows = np.arange(bb.shape[0])[:, None]
    out = bb[rows, i] * (1.0 - w) + bb[rows, i + 1] * w
    return np.where(ok, out, 0.0)


def first_return_window(t0_s: float, dt_s: float, n_samples: int, height_m: float,
                        sound_speed_m_s: float, max_angle_rad: float) -> tuple[int, int]:
    """Sample indices [k0, k1) of the seabed's first return from straight below to
    ``max_angle_rad`` off nadir: arrival times 2 h / c to 2 h / (c cos(max_angle)) on the
    axis t_k = t0 + k dt. Every scatterer heard in this window, on the interface or in
    the volume below it, lies within ``max_angle_rad`` of nadir (a flat interface): the
    window bounds the spatial frequencies of the echo across the array, 2 k sin(angle)."""
    if not height_m > 0:
        raise ValueError(f"height {height_m!r} m above the interface: expected > 0")
    if not 0 < max_angle_rad < math.pi / 2:
        raise ValueError(f"max_angle {max_angle_rad!r} rad: expected in (0, pi/2)")
    c, h = float(sound_speed_m_s), float(height_m)
    t_lo, t_hi = 2.0 * h / c, 2.0 * h / (c * math.cos(max_angle_rad))
    k0 = max(int(math.floor((t_lo - t0_s) / dt_s)), 0)
    k1 = min(int(math.ceil((t_hi - t0_s) / dt_s)) + 1, n_samples)
    if k1 - k0 < 2:
        raise ValueError(f"the interface's first return ({t_lo * 1e3:.3f}-{t_hi * 1e3:.3f} "
                         "ms) is outside the samples")
    return k0, k1


def excess_delay_s(separation_a: np.ndarray, separation_b: np.ndarray, times_s: np.ndarray,
                   height_m: float, sound_speed_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The difference of two pairs' bistatic excess delays over the interface's first
    return, eps (n_pairs, n_times) s, and cos(theta) (n_times,). A sample at time t
    hears the ring of the interface at cos(theta) = 2 h / (c t) (h the phase centres'
    height); the excess |s_perp|^2 / (4 R) there, averaged over the ring's azimuths, is
    |s_h|^2 (1 - sin^2(theta) / 2) cos(theta) / (4 h), so

        eps = (|s_h,b|^2 - |s_h,a|^2) (1 - sin^2(theta) / 2) cos(theta) / (4 h c)."""
    c, h = float(sound_speed_m_s), float(height_m)
    t = np.asarray(times_s, dtype=np.float64)
    cos_t = np.clip(2.0 * h / (c * np.maximum(t, 2.0 * h / c)), 0.0, 1.0)
    ring = (1.0 - 0.5 * (1.0 - cos_t ** 2)) * cos_t / (4.0 * h)
    s2a = np.sum(np.asarray(separation_a)[:, :2] ** 2, axis=1)
    s2b = np.sum(np.asarray(separation_b)[:, :2] ** 2, axis=1)
    return (s2b - s2a)[:, None] * ring[None, :] / c, cos_t


def pair_vertical_displacements(bb_a: np.ndarray, bb_b: np.ndarray, t0_s: float, dt_s: float,
                                geometry: ArrayGeometry, projector_a: int, projector_b: int,
                                pairs: PhaseCentrePairs, height_m: float,
                                sound_speed_m_s: float, center_hz: float,
                                max_angle_rad: float) -> PairDisplacements:
    """Each pair's vertical displacement from the interface's first return (module
    docstring). ``bb_a``, ``bb_b``: the two pings' conditioned complex baseband
    (channels, n) on one sample axis (``t0_s``, ``dt_s``: arrival time after transmit);
    ``height_m``: the phase centres' height above the interface at ping a (> 0)."""
    if not height_m > 0:
        raise ValueError(f"height {height_m!r} m above the interface: expected > 0")
    if not 0 < max_angle_rad < math.pi / 2:
        raise ValueError(f"max_angle {max_angle_rad!r} rad: expected in (0, pi/2)")
    c, h = float(sound_speed_m_s), float(height_m)
    ia, ib = pairs.channel_a, pairs.channel_b
    empty = np.zeros(0)
    if len(pairs) == 0:
        return PairDisplacements(empty, empty, empty, np.zeros((0, 2)), ia, ib)
    k0, k1 = first_return_window(t0_s, dt_s, bb_a.shape[1], h, c, max_angle_rad)
    t = t0_s + dt_s * np.arange(k0, k1)
    eps, cos_t = excess_delay_s(pairs.separation_a, pairs.separation_b, t, h, c)
    a = bb_a[ia, k0:k1]
    b = shifted_samples(bb_b[ib], t0_s, dt_s, t[None, :] + eps)
    prod = a * np.conj(b) * np.exp(-2j * math.pi * center_hz * eps)
    cross = prod.sum(axis=1)
    pa, pb = np.sum(np.abs(a) ** 2, axis=1), np.sum(np.abs(b) ** 2, axis=1)
    gamma = np.abs(cross) / np.sqrt(np.maximum(pa * pb, 1e-300))
    gamma = np.clip(gamma, 1e-6, 1.0 - 1e-12)
    w = np.abs(prod)
    cos_bar = np.sum(w * cos_t[None, :], axis=1) / np.maximum(w.sum(axis=1), 1e-300)
    phase = np.angle(cross)
    scale = c / (4.0 * math.pi * center_hz * cos_bar)
    # independent samples: the compressed pulse is about one over the bandwidth long,
    # which the decimated grid samples about once
    n_ind = max(k1 - k0, 1)
    sigma_phase = np.sqrt((1.0 - gamma ** 2) / (2.0 * n_ind * gamma ** 2))
    pc = phase_centres(geometry, projector_a)[ia]
    # the phase centre moving down (dz > 0) shortens the path: b's echo comes earlier
    return PairDisplacements(-phase * scale, sigma_phase * scale, gamma, pc[:, :2].copy(),
                             ia, ib)


def fit_vertical_increment(d: PairDisplacements, min_coherence: float = 0.5,
                           origin_xy=(0.0, 0.0)) -> VerticalIncrement | None:
    """The plane dz = heave - pitch x + roll y (x forward, y starboard, from
    ``origin_xy``, body frame) through the pairs of coherence >= ``min_coherence``,
    weighted by 1 / sigma^2; None with fewer than 3 such pairs."""
    use = d.coherence >= min_coherence
    if use.sum() < 3:
        return None
    x = d.xy_m[use, 0] - origin_xy[0]
    y = d.xy_m[use, 1] - origin_xy[1]
    a = np.column_stack([np.ones_like(x), -x, y])
    w = 1.0 / np.maximum(d.sigma_m[use], 1e-9) ** 2
    aw = a * w[:, None]
    cov = np.linalg.pinv(a.T @ aw)
    p = cov @ (aw.T @ d.dz_m[use])
    res = d.dz_m[use] - a @ p
    # the pairs scatter about the plane more than their phase noise says (the interface's
    # speckle and the excess model, ~1-2 mm per pair on the simulated sand): the
    # covariance is scaled by the reduced chi-square where that exceeds 1
    n = int(use.sum())
    if n > 3:
        cov = cov * max(1.0, float(np.sum(w * res ** 2)) / (n - 3))
    sig = np.sqrt(np.diag(cov))
    return VerticalIncrement(float(p[0]), float(p[2]), float(p[1]),
                             np.array([sig[0], sig[2], sig[1]]), n,
                             float(np.sqrt(np.mean(res ** 2))))
