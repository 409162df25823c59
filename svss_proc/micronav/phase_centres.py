"""Redundant phase centres of the SVSS array: which transmit-receive pairs of two pings
look at the seabed from (nearly) the same point, and the bistatic path they must be
corrected by before their echoes are compared (docs/phase_centres.md).

A projector at ``t`` and a receiver at ``r`` hear a scatterer at range ``R`` from their
midpoint ``c = (t + r) / 2`` (the phase centre) after the path

    |P - t| + |P - r| = 2 R + |s_perp|^2 / (4 R) + O(|s|^4 / R^3),

``s = r - t`` and ``s_perp`` its part across the direction from ``c`` to the scatterer
(:func:`bistatic_excess_m`). Two pairs with the same phase centre therefore hear the same
seabed with the same delay once each is corrected by its own excess; pairs of two pings
whose phase centres coincide in the world (the platform's displacement between the pings
included) give the displacement by the delay between their echoes.

Everything here is in the body frame of the earlier ping (x forward, y starboard, z
down), m; rotations between the two pings are taken as small (they enter the estimator,
not the pairing). Pure functions of the array geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from svss_daq.geometry import ArrayGeometry

__all__ = ["PhaseCentrePairs", "bistatic_excess_m", "near_pairs", "overlap_table",
           "pair_phase_centres", "phase_centres"]


def phase_centres(geometry: ArrayGeometry, projector: int) -> np.ndarray:
    """(n_channels, 3): the midpoint of projector ``projector`` and each receiver, m."""
    return 0.5 * (geometry.projectors[projector] + geometry.receivers)


@nb.njit(cache=True)
def _near(pa, pb, tolerance_m, ia, ib):
    n = 0
    t2 = tolerance_m * tolerance_m
    for i in range(pa.shape[0]):
        for j in range(pb.shape[0]):
            dx = pb[j, 0] - pa[i, 0]
            dy = pb[j, 1] - pa[i, 1]
            if dx * dx + dy * dy <= t2:
                ia[n] = i
                ib[n] = j
                n += 1
    return n


def near_pairs(pa: np.ndarray, pb: np.ndarray, tolerance_m: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j), i ascending then j, of the points ``pa[i]`` and ``pb[j]`` ((n, 3)
    each) within ``tolerance_m`` of each other horizontally: ``np.nonzero(hypot(pb[j] -
    pa[i]) <= tolerance_m)`` without the (n_a, n_b, 3) differences (a numba loop)."""
    pa = np.ascontiguousarray(pa, dtype=np.float64)
    pb = np.ascontiguousarray(pb, dtype=np.float64)
    ia = np.empty(pa.shape[0] * pb.shape[0], dtype=np.int64)
    ib = np.empty_like(ia)
    n = _near(pa, pb, float(tolerance_m), ia, ib)
    return ia[:n], ib[:n]


def bistatic_excess_m(separation: np.ndarray, direction: np.ndarray,
                      range_m: np.ndarray | float) -> np.ndarray:
    """The path a bistatic pair travels beyond twice the range from its phase centre, to
    second order: |s_perp|^2 / (4 R), m. ``separation`` (..., 3): receiver minus
    projector; ``direction`` (..., 3): unit vector from the phase centre to the
    scatterer; ``range_m``: that distance (> 0). The next term is O(|s|^4 / R^3)."""
    s = np.asarray(separation, dtype=np.float64)
    u = np.asarray(direction, dtype=np.float64)
    along = np.sum(s * u, axis=-1)
    perp2 = np.sum(s * s, axis=-1) - along * along
    return perp2 / (4.0 * np.asarray(range_m, dtype=np.float64))


@dataclass(frozen=True)
class PhaseCentrePairs:
    """Channels of ping a and ping b (the later) whose phase centres coincide within
    the tolerance once b's are moved by the displacement: ``residual_m`` (n, 3) is
    b's phase centre + displacement - a's, m; ``separation_a``, ``separation_b`` (n, 3)
    each pair's receiver minus projector (for :func:`bistatic_excess_m`)."""
    channel_a: np.ndarray
    channel_b: np.ndarray
    residual_m: np.ndarray
    separation_a: np.ndarray
    separation_b: np.ndarray

    def __len__(self) -> int:
        return int(self.channel_a.size)


def pair_phase_centres(geometry: ArrayGeometry, projector_a: int, projector_b: int,
                       displacement_m, tolerance_m: float) -> PhaseCentrePairs:
    """The one-to-one pairs of channels (a, b) whose phase centres lie within
    ``tolerance_m`` horizontally of each other when ping b was transmitted with projector
    ``projector_b`` from ``displacement_m`` (3,) (ping b's body origin minus ping a's, in
    a's body frame) and ping a with ``projector_a``; nearest pairs first taken, each
    channel used once. Sorted by channel of a."""
    if not tolerance_m > 0:
        raise ValueError(f"tolerance {tolerance_m!r} m: expected a number > 0")
    d = np.asarray(displacement_m, dtype=np.float64).reshape(3)
    pa = phase_centres(geometry, projector_a)
    pb = phase_centres(geometry, projector_b) + d
    diff = pb[None, :, :] - pa[:, None, :]                # (a, b, 3)
    dist = np.hypot(diff[..., 0], diff[..., 1])
    cand = np.argwhere(dist <= tolerance_m)
    order = np.argsort(dist[cand[:, 0], cand[:, 1]], kind="stable")
    used_a, used_b, keep = set(), set(), []
    for i, j in cand[order]:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            keep.append((i, j))
    keep.sort()
    ia = np.array([k[0] for k in keep], dtype=np.int64)
    ib = np.array([k[1] for k in keep], dtype=np.int64)
    rx = geometry.receivers
    return PhaseCentrePairs(ia, ib, diff[ia, ib] if keep else np.zeros((0, 3)),
                            rx[ia] - geometry.projectors[projector_a],
                            rx[ib] - geometry.projectors[projector_b])


def overlap_table(geometry: ArrayGeometry, order, speed_m_s: float, interval_s: float,
                  lags, tolerance_m: float) -> list[dict]:
    """For each ping lag of ``lags`` and each position of the projector sequence
    ``order``: the number of phase-centre pairs within ``tolerance_m`` at a straight,
    steady ``speed_m_s`` along x, and their largest residual (m). A lag with no pair at
    some position of the sequence cannot give that step's motion."""
    order = list(order)
    out = []
    for lag in lags:
        d = np.array([speed_m_s * interval_s * lag, 0.0, 0.0])
        for k, pa in enumerate(order):
            pb = order[(k + lag) % len(order)]
            pairs = pair_phase_centres(geometry, pa, pb, d, tolerance_m)
            worst = float(np.hypot(*pairs.residual_m[:, :2].T).max()) if len(pairs) else None
            out.append({"lag": int(lag), "projector_a": int(pa), "projector_b": int(pb),
                        "pairs": len(pairs), "max_residual_m": worst})
    return out


def main(argv=None) -> int:
    """Print the pairs per ping lag over a range of speeds for the configured hardware
    (``python -m svss_proc.micronav.phase_centres [--order 0,2,4,5,3,1]``)."""
    import argparse

    from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load
    from svss_daq.geometry import array_geometry
    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--hardware", default=None, help="hardware TOML (default: the project's)")
    p.add_argument("--order", default=None, help="projector order (default: the sequencer's)")
    p.add_argument("--centre-hz", type=float, default=None,
                   help="frequency of the tolerance lambda/4 (default: the waveform's centre)")
    p.add_argument("--processing", default=None,
                   help="processing TOML whose imaging.water_sound_speed_m_s sets the "
                   "tolerance (default: the project's)")
    p.add_argument("--sound-speed", type=float, default=None,
                   help="water sound speed of the tolerance, m/s (default: the processing "
                   "configuration's imaging.water_sound_speed_m_s)")
    args = p.parse_args(argv)
    hw = load(HardwareConfig, args.hardware or config_path("hardware.toml"))
    sound_speed = (args.sound_speed if args.sound_speed is not None else load(
        ProcessingConfig, args.processing or config_path("processing.toml")
    ).imaging.water_sound_speed_m_s)
    geo = array_geometry(hw)
    order = ([int(k) for k in args.order.split(",")] if args.order
             else list(hw.sequencer.projector_order))
    tol = sound_speed / (args.centre_hz or hw.waveform.center_hz) / 4
    lags = (1, 2, 3, 4)
    print(f"projector order {order}, ping interval {hw.sequencer.ping_interval_s} s, "
          f"tolerance lambda/4 = {tol * 1e3:.1f} mm; pairs per sequence position")
    for speed in np.round(np.arange(0.3, 2.001, 0.05), 2):
        rows = overlap_table(geo, order, float(speed), hw.sequencer.ping_interval_s, lags,
                             tol)
        cells = []
        for lag in lags:
            n = [r["pairs"] for r in rows if r["lag"] == lag]
            cells.append(f"lag {lag}: {' '.join(f'{k:2d}' for k in n)}")
        print(f"{speed:4.2f} m/s  " + "   ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
