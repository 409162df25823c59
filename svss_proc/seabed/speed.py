"""The sediment's sound speed of a run, from its own echoes (docs/seabed.md).

As migration velocity analysis does in seismics: the speed that focuses the buried
responses best is the speed they were buried in. Per run:

1. the run's pings, posed as they are to be imaged, are imaged on a coarse grid
   (``[seabed] search_voxel_m``, no products) with the configured speed;
2. its isolated responses at least ``min_depth_m`` below the interface are picked
   (:func:`~svss_proc.micronav.autofocus.isolated_points`, with the contrast and
   isolation of ``[seabed]``): speckle and the interface's own echo are not isolated;
3. about each, a small box (``box_m``) is imaged exactly as the tiles image it
   (:class:`~svss_proc.imaging.sampler.PointSampler`) at each trial speed of a coarse
   scan over ``speed_range_m_s`` and of a fine scan about its best, the box's depth
   following the speed (a response keeps its vertical travel time: it sits deeper in a
   faster sediment); the focus sum |I|^4 (:mod:`.focus`) peaks at the response's speed;
4. the responses' speeds are combined by their uncertainties (:func:`.focus.combine`).

Where no response qualifies (nothing below the interface stands out of its background:
an empty sediment, a sediment without objects) the speed is not constrained and the
configured ``imaging.sediment_sound_speed_m_s`` is kept, saying so. Configured layers
(``imaging.sediment_layers``, a core sample) are kept; the half-space below them is
scanned. The estimate, its uncertainty and each response's speed go into the manifest
(``seabed``) and the tiles (:class:`SpeedEstimate`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from svss_daq.config import ProcessingConfig
from svss_daq.ping import Ping
from svss_daq.ping_gate import PingRejected

from ..imaging.delays import SpeedProfile
from ..imaging.imager import PingAccumulator, TileImager
from ..imaging.sampler import PointSampler
from .focus import (combine, curve_peak, depth_at_time, focus_measure, point_sigma,
                    vertical_time)

log = logging.getLogger(__name__)

__all__ = ["SpeedEstimate", "configured_speed", "estimate_speed", "speed_wanted",
           "with_speed"]

#: points of the fine scan either side of the coarse scan's best
FINE_HALF_STEPS = 4


@dataclass(frozen=True)
class SpeedEstimate:
    """What the scan found for a run: ``status`` 'estimated' (``speed_m_s`` from the
    echoes, ``sigma_m_s`` its standard deviation), 'unconstrained' (nothing to focus on:
    the configured speed kept) or 'configured' (not asked for); ``responses``: per
    response its tile-frame position (m, at the configured speed), its best speed and
    its uncertainty (m/s), its contrast (dB)."""
    status: str
    speed_m_s: float
    configured_m_s: float
    reason: str
    sigma_m_s: float | None = None
    chi2: float | None = None
    disagree_sigmas: float = 3.0
    responses: list = field(default_factory=list)

    @property
    def disagrees(self) -> bool:
        """The configured speed lies more than ``disagree_sigmas`` standard deviations
        from the estimate."""
        return (self.status == "estimated" and self.sigma_m_s is not None and
                abs(self.configured_m_s - self.speed_m_s)
                > self.disagree_sigmas * self.sigma_m_s)

    @property
    def description(self) -> str:
        """For the logs and the tiles' provenance."""
        if self.status == "estimated":
            text = (f"sediment speed {self.speed_m_s:.0f} +/- {self.sigma_m_s:.0f} m/s from "
                    f"{len(self.responses)} buried response(s)")
            if self.disagrees:
                text += (f"; the configured {self.configured_m_s:.0f} m/s disagrees "
                         f"({abs(self.configured_m_s - self.speed_m_s) / self.sigma_m_s:.1f}"
                         f" sigma)")
            return text
        if self.status == "unconstrained":
            return (f"sediment speed not constrained by the echoes ({self.reason}); the "
                    f"configured {self.configured_m_s:.0f} m/s kept")
        return f"sediment speed {self.configured_m_s:.0f} m/s as configured"

    def summary(self) -> dict:
        """JSON-ready (the manifest's and the tiles' ``seabed``)."""
        r = lambda v, n: None if v is None or not math.isfinite(v) else round(float(v), n)  # noqa: E731
        return {"status": self.status, "sediment_sound_speed_m_s": r(self.speed_m_s, 1),
                "sigma_m_s": r(self.sigma_m_s, 1), "configured_m_s": r(self.configured_m_s, 1),
                "disagrees": self.disagrees, "reduced_chi2": r(self.chi2, 2),
                "reason": self.reason, "responses": [
                    {"along_m": r(p["position"][0], 3), "cross_m": r(p["position"][1], 3),
                     "depth_m": r(p["position"][2], 3), "speed_m_s": r(p["speed"], 1),
                     "sigma_m_s": r(p["sigma"], 1), "contrast_db": r(p["contrast_db"], 1)}
                    for p in self.responses]}


def configured_speed(processing: ProcessingConfig) -> SpeedEstimate:
    """The configured speed, not scanned (the live worker's; ``--sediment-speed
    configured``)."""
    c = float(processing.imaging.sediment_sound_speed_m_s)
    return SpeedEstimate("configured", c, c, "as configured")


def speed_wanted(processing: ProcessingConfig, flag: str | None = None) -> bool:
    """The scan on: ``flag`` ('estimate' / 'configured', a command line's), else the
    processing configuration's ``[seabed] speed`` (no table: off)."""
    if flag is not None:
        return flag == "estimate"
    return processing.seabed is not None and processing.seabed.speed == "estimate"


def with_speed(processing: ProcessingConfig, speed_m_s: float) -> ProcessingConfig:
    """``processing`` imaging with half-space sediment speed ``speed_m_s`` (its layers,
    if any, kept)."""
    return dataclasses.replace(processing, imaging=dataclasses.replace(
        processing.imaging, sediment_sound_speed_m_s=float(speed_m_s)))


def _pick_settings(processing: ProcessingConfig):
    """The autofocus's response picker set to ``[seabed]``'s thresholds."""
    from ..micronav.autofocus import autofocus_settings
    sb = processing.seabed
    return dataclasses.replace(
        autofocus_settings(processing), points=sb.points,
        interface_clearance_m=sb.min_depth_m, min_contrast_db=sb.min_contrast_db,
        min_isolation_db=sb.min_isolation_db)


def _search_image(pings: Sequence[Ping], hardware, processing: ProcessingConfig):
    """The run imaged on the coarse search grid: (tiles, the tile frame, the indices of
    the pings imaged)."""
    sb = processing.seabed
    coarse = dataclasses.replace(
        processing, products=None,
        tile=dataclasses.replace(processing.tile, voxel_m=sb.search_voxel_m))
    imager = TileImager(hardware, coarse)
    tiles, used = [], []
    for i in range(len(pings)):
        try:
            tiles += imager.add(pings[i])
        except PingRejected as exc:
            log.debug("seabed scan: %s", exc)
            continue
        used.append(i)
    tiles += imager.finish()
    return tiles, imager.line, used


class _Scanner:
    """Boxes about responses imaged at trial speeds, each speed's tables built once."""

    def __init__(self, hardware, processing: ProcessingConfig, line, pings: Sequence[Ping],
                 used: list[int]):
        self.hw = hardware
        self.proc = processing
        self.line = line
        self.pings = pings
        #: the conditioned pings of the response being scanned (shared by the speeds)
        self.prepared: dict = {}
        self._samplers: dict[float, PointSampler] = {}
        self.base = SpeedProfile.of(processing.imaging)
        ref = self._sampler(processing.imaging.sediment_sound_speed_m_s)
        self.reach = []                     # (index, projector along, reach)
        for i in used:
            x0, reach = ref.reach(pings[i])
            self.reach.append((i, x0, reach))
        self._near: list[Ping] = []

    def _sampler(self, c: float) -> PointSampler:
        c = round(float(c), 6)
        s = self._samplers.get(c)
        if s is None:
            proc = with_speed(self.proc, c)
            s = PointSampler(PingAccumulator(self.hw, proc), proc, self.line, self.prepared)
            self._samplers[c] = s
        return s

    def depth_for(self, depth0: float, c: float) -> float:
        """Where a response imaged at ``depth0`` with the picking image's speed lies with
        half-space speed ``c``: the same vertical travel time."""
        tops = np.asarray(self.base.tops)
        t = vertical_time(depth0, tops, np.asarray(self.base.speeds))
        return depth_at_time(t, tops, np.asarray(self.base.speeds[:-1] + (c,)))

    def focus(self, position: np.ndarray, c: float) -> float:
        """The focus measure of the box about ``position`` (configured-speed image) at
        half-space speed ``c``."""
        sb = self.proc.seabed
        step = sb.box_step_m
        ax = [np.arange(-h, h + 0.5 * step, step) for h in sb.box_m]
        # the box's depths keep their vertical travel times: a response's main lobe
        # spans more depth in a faster sediment, and a box of fixed depths would hold
        # more of it (F grew with c: +18 m/s in sand)
        z = np.array([self.depth_for(float(position[2]) + dz, c) for dz in ax[2]])
        box = self._sampler(c).grid(self._near, position[0] + ax[0], position[1] + ax[1],
                                    np.maximum(z, 1e-3))
        return focus_measure(box)

    def scan(self, position: np.ndarray, contrast_db: float) -> tuple[float, float]:
        """(speed, uncertainty) of one response: a coarse scan, then a fine one about
        its best."""
        sb = self.proc.seabed
        lo, hi = sb.speed_range_m_s
        self.prepared.clear()               # one response's pings held at a time
        self._near = [self.pings[i] for i, x0, reach in self.reach
                      if abs(position[0] - x0) <= reach + sb.box_m[0]]
        speeds = list(np.arange(lo, hi + 0.5 * sb.coarse_step_m_s, sb.coarse_step_m_s))
        values = [self.focus(position, c) for c in speeds]
        best, _ = curve_peak(np.array(speeds), np.array(values))
        fine = best + sb.fine_step_m_s * np.arange(-FINE_HALF_STEPS, FINE_HALF_STEPS + 1)
        for c in fine:
            if lo <= c <= hi:
                speeds.append(float(c))
                values.append(self.focus(position, float(c)))
        s, v = np.array(speeds), np.array(values)
        keep = np.abs(s - best) <= FINE_HALF_STEPS * sb.fine_step_m_s + 1e-9
        if keep.sum() >= 3:
            s, v = s[keep], v[keep]
        c, curv = curve_peak(s, v)
        if not (lo < c < hi):
            return c, math.inf                     # at an end of the scan: no peak
        return c, point_sigma(curv, contrast_db, sb.fine_step_m_s / math.sqrt(12.0))


def estimate_speed(pings: Sequence[Ping], hardware, processing: ProcessingConfig
                   ) -> SpeedEstimate:
    """The sediment speed of a run's ``pings`` (in order, posed as they are to be
    imaged; any sequence: each is read when needed, e.g. :class:`.stage.RunPings` from
    the raw files) with ``hardware`` (its :class:`~svss_daq.config.Loaded` configuration) and
    ``processing`` (its ``[seabed]`` the settings; module docstring)."""
    sb = processing.seabed
    configured = float(processing.imaging.sediment_sound_speed_m_s)
    if sb is None:
        return SpeedEstimate("configured", configured, configured, "no [seabed] table")
    out = None
    pick_speed = configured
    for round_ in range(sb.rounds):
        found = _one_round(pings, hardware, with_speed(processing, pick_speed), configured)
        if found.status != "estimated":
            return out if out is not None else found
        out = found
        if round_ + 1 < sb.rounds and abs(found.speed_m_s - pick_speed) <= sb.fine_step_m_s:
            break                           # picked at the estimate already
        pick_speed = found.speed_m_s
    return out


def _one_round(pings: Sequence[Ping], hardware, processing: ProcessingConfig,
               configured: float) -> SpeedEstimate:
    """Pick the responses on an image made with ``processing``'s speed and scan them."""
    sb = processing.seabed
    tiles, line, used = _search_image(pings, hardware, processing)
    if line is None or not tiles:
        return SpeedEstimate("unconstrained", configured, configured, "no ping imaged",
                             disagree_sigmas=sb.disagree_sigmas)
    pick = _pick_isolated(tiles, processing)
    log.info("seabed scan at %.0f m/s: %d isolated buried response(s) of %d local maxima "
             "examined (%s)", processing.imaging.sediment_sound_speed_m_s, len(pick.points),
             pick.examined, ", ".join(f"{k}: {v}" for k, v in pick.rejected.items()))
    if len(pick.points) < sb.min_points:
        reason = pick.refused or (f"{len(pick.points)} isolated buried response(s), "
                                  f"{sb.min_points} needed")
        return SpeedEstimate("unconstrained", configured, configured, reason,
                             disagree_sigmas=sb.disagree_sigmas)
    scanner = _Scanner(hardware, processing, line, pings, used)
    responses = []
    for pos, con in zip(pick.points, pick.contrast_db):
        c, sig = scanner.scan(pos, float(con))
        responses.append({"position": [float(v) for v in pos], "speed": c, "sigma": sig,
                          "contrast_db": float(con)})
        log.info("seabed scan: response at %.2f m along, %.2f m across, %.2f m deep: "
                 "%.0f +/- %.0f m/s", pos[0], pos[1], pos[2], c, sig)
    speed, sigma, chi2 = combine(np.array([r["speed"] for r in responses]),
                                 np.array([r["sigma"] for r in responses]))
    if not math.isfinite(speed):
        return SpeedEstimate("unconstrained", configured, configured,
                             "no response's focus peaked inside the scanned speeds "
                             f"{list(sb.speed_range_m_s)} m/s",
                             disagree_sigmas=sb.disagree_sigmas, responses=responses)
    return SpeedEstimate("estimated", speed, configured, "focus of buried responses",
                         sigma, chi2, sb.disagree_sigmas, responses)


def _pick_isolated(tiles, processing):
    from ..micronav.autofocus import isolated_points
    return isolated_points(tiles, _pick_settings(processing))
