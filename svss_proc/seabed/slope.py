"""The interface's slope of a run, from its own navigation and echoes (docs/seabed.md).

The tiles' voxel depths are below the interface of each column, modelled as a plane
(``[imaging] interface_slope_deg``, :mod:`svss_proc.imaging.surface`); each ping's frame
passes the plane through the bed its altitude measured under the body. Two views of the
same plane give its two slopes:

* **along the track**, from the navigation: each ping's bed depth below the survey
  frame's origin, its body depth plus its altitude, against its along-track position
  (a straight line by least squares). The sonar's image cannot see it: every ping
  places the bed at its own altitude, so a wrong along-track slope blurs the
  interface's echo about its true depth without moving it;
* **across the track**, from the interface's own echo: the run imaged in a thin slab
  about the interface (``±SLAB_HALF_M``, on the picking image's grid) with the
  along-track slope, the echo's peak depth in each cross-track column (the power summed
  along-track where the slab is fully covered; the echo is where the level first rises
  half-way in dB from the water's to the column's brightest, from above, then up to its
  peak, refined by
  a parabola: a silt's volume just below can be as bright as its interface, a buried
  response brighter; a column whose brightest stands less than ``ECHO_CONTRAST_DB``
  over the water above, or whose echo lies at the slab's edge, has none), and a
  straight line through them weighted by their power. The navigation cannot see this
  one: the track is one line.

Each slope comes with its standard deviation from the fit's residuals. Too short a run
(less than ``MIN_SPAN_M`` along-track, or of cross-track columns with an echo) keeps the
configured slope, saying so.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from svss_daq.config import ProcessingConfig
from svss_daq.ping import Ping
from svss_daq.ping_gate import PingRejected

from ..imaging.imager import TileImager
from ..imaging.schedule import line_from_pose

log = logging.getLogger(__name__)

__all__ = ["SlopeEstimate", "estimate_slope", "with_slope"]

#: half-thickness of the slab about the interface imaged for its echo, m
SLAB_HALF_M = 0.4
#: least along-track span of the navigation, and cross-track span of the echo's columns,
#: that a slope is fitted over, m
MIN_SPAN_M = 1.0
#: columns whose echo is this far below the brightest column's are left out, dB
COLUMN_FLOOR_DB = 10.0
#: a column's echo stands at least this far over the median of the water above it, dB
#: (power summed along-track), the water being the slab's depths above -WATER_CLEARANCE_M
ECHO_CONTRAST_DB = 10.0
WATER_CLEARANCE_M = 0.15


@dataclass(frozen=True)
class SlopeEstimate:
    """The interface's slope (along, across), deg, positive where it deepens ahead and to
    starboard; each with its standard deviation (None: not estimated) and where it
    came from."""
    slope_deg: tuple[float, float]
    sigma_deg: tuple[float | None, float | None]
    source: tuple[str, str]

    def summary(self) -> dict:
        r = lambda v: None if v is None or not math.isfinite(v) else round(float(v), 3)  # noqa: E731
        return {"interface_slope_deg": [r(v) for v in self.slope_deg],
                "interface_slope_sigma_deg": [r(v) for v in self.sigma_deg],
                "interface_slope_from": list(self.source)}

    @property
    def description(self) -> str:
        parts = []
        for name, s, sig, src in zip(("along", "across"), self.slope_deg, self.sigma_deg,
                                     self.source):
            parts.append(f"{name} {s:+.2f}" + (f" +/- {sig:.2f}" if sig is not None else "")
                         + f" deg ({src})")
        return "interface slope " + ", ".join(parts)


def with_slope(processing: ProcessingConfig, slope_deg) -> ProcessingConfig:
    """``processing`` imaging over an interface of ``slope_deg`` (along, across)."""
    return dataclasses.replace(processing, imaging=dataclasses.replace(
        processing.imaging, interface_slope_deg=(float(slope_deg[0]), float(slope_deg[1]))))


def _line_fit(x: np.ndarray, y: np.ndarray, w: np.ndarray | None = None
              ) -> tuple[float, float]:
    """(gradient, its standard deviation) of a weighted straight-line fit y ~ a + g x,
    the deviation from the residuals' scatter."""
    w = np.ones_like(x) if w is None else w
    sw = w.sum()
    xm = (w * x).sum() / sw
    ym = (w * y).sum() / sw
    sxx = (w * (x - xm) ** 2).sum()
    g = float((w * (x - xm) * (y - ym)).sum() / sxx)
    res = y - ym - g * (x - xm)
    n_eff = sw ** 2 / (w ** 2).sum()
    var = (w * res ** 2).sum() / sw * n_eff / max(n_eff - 2.0, 1.0)
    return g, float(math.sqrt(var * (w ** 2 * (x - xm) ** 2).sum()) / sxx)


def _along(pings: Sequence[Ping], processing: ProcessingConfig
           ) -> tuple[float, float | None, str]:
    """The along-track gradient of the navigation's bed depths, its deviation, source."""
    # the poses alone: a run read from its files (RunPings.nav) is not read whole here
    pose = getattr(pings, "nav", None) or (lambda k: pings[k].nav)
    line = None
    a, b = [], []
    for i in range(len(pings)):
        nav = pose(i)
        bed = nav.down_m + nav.altitude_m
        if not math.isfinite(bed):
            continue
        if line is None:
            line = line_from_pose(nav, processing)
        a.append(float(line.ned_to_tile(np.array([nav.north_m, nav.east_m, 0.0]))[0]))
        b.append(bed)
    a, b = np.asarray(a), np.asarray(b)
    if a.size < 3 or np.ptp(a) < MIN_SPAN_M:
        return 0.0, None, f"kept: {a.size} bed depths over {np.ptp(a) if a.size else 0:.1f} m"
    g, sig = _line_fit(a, b)
    return g, sig, f"navigation, {a.size} bed depths over {np.ptp(a):.1f} m"


def image_slab(pings: Sequence[Ping], hardware, processing: ProcessingConfig,
               half_m: float = SLAB_HALF_M):
    """The run imaged in the slab ``half_m`` about the interface on the picking image's
    grid."""
    sb = processing.seabed
    v = sb.search_voxel_m
    slab = dataclasses.replace(
        processing, products=None,
        tile=dataclasses.replace(processing.tile, voxel_m=v, top_m=-half_m,
                                 depth_m=2 * half_m))
    imager = TileImager(hardware, slab, method="exact")   # estimation: the exact sum
    tiles = []
    for i in range(len(pings)):
        try:
            tiles += imager.add(pings[i])
        except PingRejected as exc:
            log.debug("interface slope: %s", exc)
    return tiles + imager.finish()


def pick_echo(col: np.ndarray, z: np.ndarray, water: np.ndarray, contrast_db: float
              ) -> tuple[float, float] | None:
    """The interface echo's (depth m, power) in one column's power profile ``col`` over depths
    ``z`` (``water``: the depths above the interface), or None where the column's
    brightest stands less than ``contrast_db`` over the water's median, or its echo lies
    at the profile's edge. The interface is where the level first rises half-way (in
    dB) from the water's to the column's brightest (a silt's volume below it can be as
    bright, a buried response brighter): the first such depth from above, then up to
    its peak, refined by a parabola in log power."""
    top = col.max()
    floor = np.median(col[water])
    if top <= 0.0 or floor <= 0.0 or top < floor * 10 ** (contrast_db / 10):
        return None
    k = int(np.argmax(col >= math.sqrt(floor * top)))
    while k + 1 < col.size and col[k + 1] > col[k]:
        k += 1
    if k == 0 or k == col.size - 1:
        return None
    lo, mid, hi = np.log(col[k - 1:k + 2])
    den = lo - 2 * mid + hi
    frac = 0.5 * (lo - hi) / den if den < 0 else 0.0
    return float(z[k] + frac * (z[1] - z[0])), float(col[k])


def _across(tiles) -> tuple[float, float | None, str]:
    """The cross-track gradient of the interface echo's depth, its deviation, source."""
    cross, depth, power = [], [], []
    for t in tiles:
        re = np.asarray(t.re, dtype=np.float64)
        im = np.asarray(t.im, dtype=np.float64)
        pw = re * re + im * im
        cov = np.asarray(t.coverage.pings)
        full = cov.min(axis=2)                        # covered through the slab
        rows = full >= 0.5 * max(int(full.max()), 1)
        prof = np.where(rows[:, :, None], pw, 0.0).sum(axis=0)    # (cross, depth)
        z = np.asarray(t.grid.depth)
        water = z < -WATER_CLEARANCE_M
        if np.count_nonzero(water) < 3:
            continue
        for ic in range(prof.shape[0]):
            echo = pick_echo(prof[ic], z, water, ECHO_CONTRAST_DB)
            if echo is None:
                continue
            cross.append(float(t.grid.cross[ic]))
            depth.append(echo[0])
            power.append(echo[1])
    if not cross:
        return 0.0, None, "kept: no interface echo imaged"
    cross, depth, power = (np.asarray(x) for x in (cross, depth, power))
    keep = power >= power.max() * 10 ** (-COLUMN_FLOOR_DB / 10)
    cross, depth, power = cross[keep], depth[keep], power[keep]
    if cross.size < 3 or np.ptp(cross) < MIN_SPAN_M:
        return 0.0, None, (f"kept: the interface's echo in {cross.size} columns over "
                           f"{np.ptp(cross) if cross.size else 0:.1f} m")
    g, sig = _line_fit(cross, depth, power)
    return g, sig, f"interface echo, {cross.size} columns over {np.ptp(cross):.1f} m"


def estimate_slope(pings: Sequence[Ping], hardware, processing: ProcessingConfig
                   ) -> SlopeEstimate:
    """The interface's slope under a run's ``pings`` (in order, posed as they are to be
    imaged) with ``hardware`` (Loaded) and ``processing`` (its ``[seabed]`` grid)."""
    configured = processing.imaging.interface_slope_deg or (0.0, 0.0)
    g_a, s_a, src_a = _along(pings, processing)
    if s_a is None:
        g_a = math.tan(math.radians(configured[0]))
    tiles = image_slab(pings, hardware, with_slope(processing, (math.degrees(math.atan(g_a)),
                                                           0.0)))
    g_c, s_c, src_c = _across(tiles)
    if s_c is None:
        g_c = math.tan(math.radians(configured[1]))
    deg = lambda g: math.degrees(math.atan(g))          # noqa: E731
    dsig = lambda g, s: None if s is None else math.degrees(s / (1.0 + g * g))  # noqa: E731
    est = SlopeEstimate((deg(g_a), deg(g_c)), (dsig(g_a, s_a), dsig(g_c, s_c)),
                        (src_a, src_c))
    log.info("%s", est.description)
    return est
