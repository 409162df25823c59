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

from svss_daq.config import ProcessingConfig, SedimentLayerConfig
from svss_daq.ping import Ping
from svss_daq.ping_gate import PingRejected

from ..imaging.delays import SpeedProfile
from ..imaging.imager import PingAccumulator, TileImager
from ..imaging.sampler import PointSampler
from .relief import with_relief
from .slope import with_slope
from .focus import (combine, curve_peak, depth_at_time, focus_measure, point_sigma,
                    vertical_time)

log = logging.getLogger(__name__)

__all__ = ["SpeedEstimate", "applied", "configured_speed", "estimate_speed", "speed_wanted",
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
    #: estimated layers above the half-space of ``speed_m_s``, top first: thickness,
    #: speed and its standard deviation, the boundary's level over its surroundings (dB)
    layers: tuple = ()
    #: the interface's slope and relief the run was scanned and is imaged over
    #: (:meth:`.slope.SlopeEstimate.summary`, :meth:`.relief.ReliefEstimate.summary`;
    #: None: as configured)
    slope: dict | None = None

    def apply(self, processing: ProcessingConfig) -> ProcessingConfig:
        """``processing`` imaging with this estimate (its layers over its half-space, as
        :meth:`summary` rounds them, so that a tile imaged from the summary alone, as
        ``svss batch``'s tasks image it, is the same); unchanged unless estimated."""
        return applied(processing, self.summary())

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
        text = self._speed_description
        if self.slope is not None and "interface_slope_deg" in self.slope:
            a, c = self.slope["interface_slope_deg"]
            text += f"; interface slope {a:+.2f} deg along, {c:+.2f} deg across"
        if self.slope is not None and self.slope.get("interface_relief"):
            text += (f"; interface relief rms {100 * self.slope['interface_relief_rms_m']:.1f}"
                     " cm")
        return text

    @property
    def _speed_description(self) -> str:
        if self.status == "estimated":
            text = (f"sediment speed {self.speed_m_s:.0f} +/- {self.sigma_m_s:.0f} m/s from "
                    f"{len(self.responses)} buried response(s)")
            for l_ in self.layers:
                text += (f" below {l_['thickness_m']:.2f} m at {l_['speed_m_s']:.0f} +/- "
                         f"{l_['sigma_m_s']:.0f} m/s")
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
                     "sigma_m_s": r(p["sigma"], 1), "contrast_db": r(p["contrast_db"], 1),
                     "layer": p.get("layer")}
                    for p in self.responses],
                "layers": [{k: r(v, 3) for k, v in l_.items()} for l_ in self.layers],
                **(self.slope or {})}


def applied(processing: ProcessingConfig, summary: dict | None) -> ProcessingConfig:
    """``processing`` imaging with the seabed of a :meth:`SpeedEstimate.summary`: its
    interface slope where it has one, its sediment where that was estimated (unchanged
    for None)."""
    if not summary:
        return processing
    slope = summary.get("interface_slope_deg")
    if slope is not None and None not in slope:
        processing = with_slope(processing, slope)
    processing = with_relief(processing, summary)
    if summary.get("status") != "estimated":
        return processing
    out = with_speed(processing, summary["sediment_sound_speed_m_s"])
    if summary.get("layers"):               # only the table refracts through layers
        out = dataclasses.replace(out, imaging=dataclasses.replace(
            out.imaging, delays="table", sediment_layers=tuple(
                SedimentLayerConfig(thickness_m=float(l_["thickness_m"]),
                                    sound_speed_m_s=float(l_["speed_m_s"]))
                for l_ in summary["layers"])))
    return out


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
    if any, kept); straight-ray delays, which know no sediment, become the refraction
    table's."""
    delays = "table" if processing.imaging.delays == "straight" else processing.imaging.delays
    return dataclasses.replace(processing, imaging=dataclasses.replace(
        processing.imaging, sediment_sound_speed_m_s=float(speed_m_s), delays=delays))


def _pick_settings(processing: ProcessingConfig):
    """The autofocus's response picker set to ``[seabed]``'s thresholds."""
    from ..micronav.autofocus import autofocus_settings
    sb = processing.seabed
    return dataclasses.replace(
        autofocus_settings(processing), points=sb.points,
        interface_clearance_m=sb.min_depth_m, min_contrast_db=sb.min_contrast_db,
        min_isolation_db=sb.min_isolation_db)


def _search_image(pings: Sequence[Ping], hardware, processing: ProcessingConfig):
    """The run imaged on the coarse search grid: (tiles, the tile frame, per ping imaged
    its index, projector along-track position and reach and projector depth (tile
    frame, m) as the scans' samplers place it). Each ping is read once here; the scans
    read only the pings about their response."""
    sb = processing.seabed
    coarse = dataclasses.replace(
        processing, products=None,
        tile=dataclasses.replace(processing.tile, voxel_m=sb.search_voxel_m))
    imager = TileImager(hardware, coarse, method="exact")   # estimation: the exact sum
    tiles, reach, placer = [], [], None
    for i in range(len(pings)):
        p = pings[i]
        try:
            tiles += imager.add(p)
        except PingRejected as exc:
            log.debug("seabed scan: %s", exc)
            continue
        if placer is None:                  # the frame is set by the first ping imaged
            placer = PointSampler(imager.accumulator, coarse, imager.line)
        placed, r = placer.placed(p)
        reach.append((i, float(placed.tx[0]), r, float(placed.tx[2])))
    tiles += imager.finish()
    return tiles, imager.line, reach


class _Scanner:
    """Boxes about responses imaged at trial speeds, each speed's tables built once."""

    def __init__(self, hardware, processing: ProcessingConfig, line, pings: Sequence[Ping],
                 reach: list[tuple[int, float, float, float]], base: SpeedProfile):
        self.hw = hardware
        #: the profile scanned: ``processing``'s layers over a half-space at trial speeds
        self.proc = processing
        self.line = line
        self.pings = pings
        #: the conditioned pings of the response being scanned (shared by the speeds)
        self.prepared: dict = {}
        self._samplers: dict[float, PointSampler] = {}
        #: the profile the responses were picked with (their depths are its)
        self.base = base
        self.scanned = SpeedProfile.of(processing.imaging)
        #: per ping imaged: (index, projector along, reach, projector depth), the
        #: picking image's (:func:`_search_image`)
        self.reach = reach
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
        """Where a response imaged at ``depth0`` with the picking image's profile lies in
        the scanned profile with half-space speed ``c``: the same vertical travel time."""
        t = vertical_time(depth0, np.asarray(self.base.tops), np.asarray(self.base.speeds))
        return depth_at_time(t, np.asarray(self.scanned.tops),
                             np.asarray(self.scanned.speeds[:-1] + (c,)))

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

    def scan(self, position: np.ndarray, contrast_db: float) -> dict:
        """One response: a coarse scan, then a fine one about its best; its ``speed``
        and ``sigma`` (m/s), the log of its focus at the best speed (``log_focus``)
        and the ``curve`` (speeds, focus values) scanned."""
        sb = self.proc.seabed
        lo, hi = sb.speed_range_m_s
        self.prepared.clear()               # one response's pings held at a time
        self._near = self._symmetric(float(position[0]))
        if not self._near:
            return {"speed": math.nan, "sigma": math.inf, "log_focus": -math.inf,
                    "curve": (np.zeros(0), np.zeros(0))}
        speeds = list(np.arange(lo, hi + 0.5 * sb.coarse_step_m_s, sb.coarse_step_m_s))
        values = [self.focus(position, c) for c in speeds]
        best, _ = curve_peak(np.array(speeds), np.array(values))
        fine = best + sb.fine_step_m_s * np.arange(-FINE_HALF_STEPS, FINE_HALF_STEPS + 1)
        for c in fine:
            if lo <= c <= hi:
                speeds.append(float(c))
                values.append(self.focus(position, float(c)))
        s, v = np.array(speeds), np.array(values)
        order = np.argsort(s)
        curve = (s[order], v[order])
        keep = np.abs(s - best) <= FINE_HALF_STEPS * sb.fine_step_m_s + 1e-9
        if keep.sum() >= 3:
            s, v = s[keep], v[keep]
        c, curv = curve_peak(s, v)
        log_focus = float(np.log(max(float(np.max(v)), 1e-300)))
        if not (lo < c < hi):                    # at an end of the scan: no peak
            return {"speed": c, "sigma": math.inf, "log_focus": log_focus, "curve": curve}
        return {"speed": c, "sigma": point_sigma(curv, contrast_db,
                                                 sb.fine_step_m_s / math.sqrt(12.0)),
                "log_focus": log_focus, "curve": curve}

    def boundary_depth(self, c: float, around_m: float) -> tuple[float, float] | None:
        """The depth of a layer boundary's echo in a fine image of the middle of the run
        made with a uniform sediment of speed ``c`` (half-space speed of this scanner's
        profile): the peak of the median level against depth (1 cm steps) within
        ``[seabed] boundary_window_m`` / 2 of ``around_m``; None: no peak inside. With
        the boundary's true top-layer speed the peak lies on the boundary; with another
        speed it lies where the boundary's vertical travel time puts it."""
        from .layers import profile_peak_level
        sb = self.proc.seabed
        x = np.array([x0 for _, x0, _, _ in self.reach])
        mid = float(np.median(x))
        near = [self.pings[i] for i, x0, reach, _ in self.reach if abs(mid - x0) <= reach]
        half = 0.5 * sb.boundary_window_m
        along = mid + np.arange(-0.7, 0.7 + 1e-9, 0.02)
        cross = np.arange(-0.3, 0.3 + 1e-9, 0.02)
        depth = np.arange(max(around_m - half, sb.min_depth_m), around_m + half + 1e-9, 0.01)
        self.prepared.clear()
        img = self._sampler(c).grid(near, along, cross, depth)
        self.prepared.clear()
        mag = np.abs(img).reshape(-1, depth.size)
        level = np.array([20 * np.log10(max(float(np.median(m[m > 0])), 1e-300))
                          if np.any(m > 0) else -np.inf for m in mag.T])
        return profile_peak_level(depth, level)

    def _symmetric(self, along: float) -> list[Ping]:
        """The pings that reach ``along``, on a synthetic aperture symmetric about it: a
        response near a run's end is seen from one side only, and a one-sided aperture
        couples its along-track position with the speed (a response 0.6 m inside a
        run's first pings' reach scanned +4 % fast). Empty: less than a quarter of the
        full aperture on its shorter side."""
        sb = self.proc.seabed
        x = [(i, x0, reach) for i, x0, reach, _ in self.reach
             if abs(along - x0) <= reach + sb.box_m[0]]
        if not x:
            return []
        half = min(along - min(x0 for _, x0, _ in x), max(x0 for _, x0, _ in x) - along)
        if half < 0.25 * float(np.median([r for _, _, r in x])):
            return []
        return [self.pings[i] for i, x0, _ in x if abs(along - x0) <= half + 1e-9]

    def surface_ghost_depth(self) -> float:
        """Where the interface's echo by way of the sea surface (one bounce) appears in
        the picking image, m below the interface: the projector's median depth below the
        surface (the survey frame's down 0) in water, as vertical one-way time."""
        d = float(self.line.interface_down) + float(np.median([z for *_, z in self.reach]))
        t = max(d, 0.0) / self.proc.imaging.water_sound_speed_m_s
        return depth_at_time(t, np.asarray(self.base.tops), np.asarray(self.base.speeds))


def estimate_speed(pings: Sequence[Ping], hardware, processing: ProcessingConfig
                   ) -> SpeedEstimate:
    """The sediment speed of a run's ``pings`` (in order, posed as they are to be
    imaged; any sequence: each is read when needed, e.g. :class:`.stage.RunPings` from
    the raw files) with ``hardware`` (its :class:`~svss_daq.config.Loaded`
    configuration) and ``processing`` (its ``[seabed]`` the settings; module
    docstring)."""
    sb = processing.seabed
    configured = float(processing.imaging.sediment_sound_speed_m_s)
    if sb is None:
        return SpeedEstimate("configured", configured, configured, "no [seabed] table")
    out, last = None, None
    pick_speed = configured
    for round_ in range(sb.rounds):
        found, seen = _one_round(pings, hardware, with_speed(processing, pick_speed),
                                 configured)
        if found.status != "estimated":
            if out is None:
                return found
            break
        out, last = found, seen
        if abs(found.speed_m_s - pick_speed) <= sb.fine_step_m_s:
            break                           # picked at the estimate already
        pick_speed = found.speed_m_s
    if sb.layers and not processing.imaging.sediment_layers and last is not None:
        layered = _layered(out, last, pings, hardware, processing)
        if layered is not None:
            return layered
    return out


@dataclass
class _Seen:
    """What a round saw: its picking image's tiles, frame, imaged pings' placement
    (:func:`_search_image`), processing and the responses it scanned."""
    tiles: list
    line: object
    reach: list
    processing: ProcessingConfig
    responses: list
    #: where the interface's surface-bounce echo appears in the picking image, m
    ghost_depth_m: float


def _responses(scanner: _Scanner, points, contrasts, quiet: bool = False) -> list[dict]:
    out = []
    for pos, con in zip(points, contrasts):
        r = scanner.scan(pos, float(con))
        r.update(position=[float(v) for v in pos], contrast_db=float(con))
        out.append(r)
        if not quiet:
            log.info("seabed scan: response at %.2f m along, %.2f m across, %.2f m deep: "
                     "%.0f +/- %.0f m/s", pos[0], pos[1], pos[2], r["speed"], r["sigma"])
    return out


def _one_round(pings: Sequence[Ping], hardware, processing: ProcessingConfig,
               configured: float) -> tuple[SpeedEstimate, _Seen | None]:
    """Pick the responses on an image made with ``processing``'s speed and scan them."""
    sb = processing.seabed
    tiles, line, reach = _search_image(pings, hardware, processing)
    if line is None or not tiles:
        return SpeedEstimate("unconstrained", configured, configured, "no ping imaged",
                             disagree_sigmas=sb.disagree_sigmas), None
    scanner = _Scanner(hardware, processing, line, pings, reach,
                       SpeedProfile.of(processing.imaging))
    ghost = scanner.surface_ghost_depth()
    pick, n_ghost = _pick_isolated(tiles, processing, ghost)
    log.info("seabed scan at %.0f m/s: %d isolated buried response(s) of %d local maxima "
             "examined (%s; %d voxels on the interface's surface echo at %.2f m left out)",
             processing.imaging.sediment_sound_speed_m_s, len(pick.points), pick.examined,
             ", ".join(f"{k}: {v}" for k, v in pick.rejected.items()), n_ghost, ghost)
    if len(pick.points) < sb.min_points:
        reason = pick.refused or (f"{len(pick.points)} isolated buried response(s), "
                                  f"{sb.min_points} needed")
        reason += (f"; the interface's echo by way of the surface at {ghost:.2f} m "
                   "not searched")
        return SpeedEstimate("unconstrained", configured, configured, reason,
                             disagree_sigmas=sb.disagree_sigmas), None
    responses = _responses(scanner, pick.points, pick.contrast_db)
    seen = _Seen(tiles, line, reach, processing, responses, ghost)
    speed, sigma, chi2 = combine(np.array([r["speed"] for r in responses]),
                                 np.array([r["sigma"] for r in responses]))
    if not math.isfinite(speed):
        return SpeedEstimate("unconstrained", configured, configured,
                             "no response's focus peaked inside the scanned speeds "
                             f"{list(sb.speed_range_m_s)} m/s",
                             disagree_sigmas=sb.disagree_sigmas, responses=responses), seen
    return SpeedEstimate("estimated", speed, configured, "focus of buried responses",
                         sigma, chi2, sb.disagree_sigmas, responses), seen


def _layered(uniform: SpeedEstimate, seen: _Seen, pings, hardware,
             processing: ProcessingConfig) -> SpeedEstimate | None:
    """A two-layer profile where the picking image shows a layer boundary below the
    interface (:func:`.layers.find_boundary`; the interface's surface-bounce echo told
    apart) with responses above and below it. For each trial top-layer speed c1 (about
    the responses-above estimate) the layer's thickness is where the boundary's echo
    peaks in a fine image made with c1 (:meth:`_Scanner.boundary_depth`), and the
    responses below are scanned for the half-space speed c2 through that layer; c1 is
    the trial that maximises the responses' summed log focus (those above at c1, from
    their one-speed scans; those below at their best c2). None: no such boundary, or
    nothing above or below it to focus on."""
    from .layers import find_boundary
    sb = processing.seabed
    base = SpeedProfile.of(seen.processing.imaging)
    boundary = find_boundary(seen.tiles, sb.min_depth_m, sb.boundary_window_m,
                             sb.boundary_min_db, exclude=(seen.ghost_depth_m, sb.box_m[2]))
    if boundary is None:
        return None
    z_b, level_db = boundary
    guard = sb.box_m[2]
    scanned = [r for r in seen.responses if math.isfinite(r["sigma"])]
    above = [r for r in scanned if r["position"][2] < z_b - guard]
    below = [r for r in scanned if r["position"][2] > z_b + guard]
    log.info("seabed scan: a layer boundary about %.2f m below the interface (%.1f dB over "
             "the levels about it; %d response(s) above it, %d below; the surface echo's "
             "at %.2f m)", z_b, level_db, len(above), len(below), seen.ghost_depth_m)
    if not above or not below:
        return None
    c1_0, s1_0, _ = combine(np.array([r["speed"] for r in above]),
                            np.array([r["sigma"] for r in above]))
    if not math.isfinite(c1_0):
        return None
    t_b = vertical_time(z_b, np.asarray(base.tops), np.asarray(base.speeds))
    lo, hi = sb.speed_range_m_s
    uniform_scan = _Scanner(hardware, seen.processing, seen.line, pings, seen.reach, base)

    def deep_at(c1: float) -> tuple[float, list[dict]] | None:
        got = uniform_scan.boundary_depth(c1, t_b * c1)
        if got is None or got[0] < processing.tile.voxel_m:
            return None
        thickness = got[0]
        log.info("seabed scan: boundary echo at %.0f m/s: %.3f m, %.2f dB", c1, *got)
        top = SedimentLayerConfig(thickness_m=float(thickness), sound_speed_m_s=float(c1))
        scan_proc = dataclasses.replace(seen.processing, imaging=dataclasses.replace(
            seen.processing.imaging, sediment_layers=(top,)))
        scanner = _Scanner(hardware, scan_proc, seen.line, pings, seen.reach, base)
        return thickness, _responses(scanner, [np.array(r["position"]) for r in below],
                                     [r["contrast_db"] for r in below], quiet=True)

    def total(c1: float, deep: list[dict]) -> float:
        j = sum(float(np.interp(c1, r["curve"][0], np.log(np.maximum(r["curve"][1],
                                                                       1e-300))))
                for r in above)
        return j + sum(r["log_focus"] for r in deep)

    step = sb.coarse_step_m_s
    trials: dict[float, tuple[float, float, list]] = {}
    for c1 in np.clip(c1_0 + step * np.arange(-2, 3), lo, hi):
        c1 = float(c1)
        if c1 not in trials:
            got = deep_at(c1)
            if got is not None:
                trials[c1] = (total(c1, got[1]), *got)
                log.info("seabed scan: top layer %.0f m/s, %.3f m thick: summed log focus "
                         "%.3f", c1, got[0], trials[c1][0])
    if len(trials) < 3:
        return None
    cs = np.array(sorted(trials))
    js = np.array([trials[c][0] for c in cs])
    c1, curv = curve_peak(cs, np.exp(js - js.max()))
    got = deep_at(c1)
    if got is None:
        return None
    thickness, deep = got
    c2, s2, chi2 = combine(np.array([r["speed"] for r in deep]),
                           np.array([r["sigma"] for r in deep]))
    if not math.isfinite(c2):
        return None
    noise = 4.0 * sum(10.0 ** (-r["contrast_db"] / 20.0) for r in above + below)
    s1 = (max(math.sqrt(noise / -curv), sb.fine_step_m_s / math.sqrt(12.0)) if curv < 0
          else s1_0)
    for r in above:
        r["layer"] = 0
    for r in deep:
        r["layer"] = 1
        log.info("seabed scan: response at %.2f m along, %.2f m across, %.2f m deep, below "
                 "the boundary: %.0f +/- %.0f m/s", *r["position"], r["speed"], r["sigma"])
    layers = ({"thickness_m": float(thickness), "speed_m_s": float(c1), "sigma_m_s": float(s1),
               "boundary_db": float(level_db)},)
    return SpeedEstimate("estimated", c2, uniform.configured_m_s,
                         "focus of buried responses above and below a layer boundary",
                         s2, chi2, sb.disagree_sigmas, above + deep, layers)


def _pick_isolated(tiles, processing, ghost_depth_m: float):
    """(the isolated responses to scan, how many local maxima lay on the interface's
    echo by way of the sea surface): that echo is a bright sheet at ``ghost_depth_m``
    whose speckle stands out of the levels above and below it (in the seed's sand every
    pick lay there and scanned 1800-2040 m/s) and crowds the brightest maxima; the
    depths within the box's depth of it are left out of the picking image."""
    from types import SimpleNamespace

    from ..micronav.autofocus import isolated_points
    sb = processing.seabed
    masked, n_ghost = [], 0
    for t in tiles:
        img = np.asarray(t.image)
        band = np.abs(np.asarray(t.grid.depth) - ghost_depth_m) <= sb.box_m[2]
        if band.any():
            img = img.copy()
            n_ghost += int(np.count_nonzero(img[:, :, band]))
            img[:, :, band] = 0
        masked.append(SimpleNamespace(image=img, grid=t.grid))
    return isolated_points(masked, _pick_settings(processing)), n_ghost
