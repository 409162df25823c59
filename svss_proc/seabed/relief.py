"""The interface's relief about its plane, from the interface's own echo (docs/seabed.md).

A bed undulates: sand waves, scour, tracks. The plane of :mod:`.slope` leaves that
relief out, and a buried object's depth below the interface above it, and its travel
times through that interface, are then wrong by as much. The relief is read off the
interface's echo, column by column:

1. the run is imaged in a slab about the plane (``±SLAB_HALF_M``, on the picking image's
   grid, ``[seabed] search_voxel_m``), every ping placed in the first ping's frame
   (``imaging.interface = "navigation"``): a ping placed at its own altitude would carry
   the relief under its body into the whole of its aperture and blur the echo it is to
   measure;
2. the image's power is averaged over ``SMOOTH_M`` along and across (incoherently: the
   interface's speckle, not its depth, varies from column to column); in each voxel
   column seen by at least ``FULL_APERTURE`` of the best covered column's pings, the
   echo is the first voxel from above within ``RISE_DB`` of the column's brightest below
   the water (the slab's top ``WATER_M``, above any relief of up to
   ``SLAB_HALF_M - WATER_M`` about the first ping's level), up to its peak, refined by a
   parabola in log power, where the brightest stands ``ECHO_CONTRAST_DB`` over the
   water's median (:func:`_first_rise`); depths within ``GHOST_BAND_M`` of the
   interface's echo by way of the sea surface are left out. First over
   ``COARSE_SMOOTH_M`` for a coarse surface (step 3, over twice the radius: robust to a
   buried response's cluster of picks), then each column again within
   ``PEAK_WINDOW_M`` of it;
3. the picks are gathered on the relief's nodes (``NODE_M`` apart along and across the
   track line): each node's depth is a robust local quadratic surface through the picks
   within ``RADIUS_M`` of it, evaluated at the node (iteratively reweighted least squares
   with Tukey's biweight, started from the ordinary least-squares surface: a pick drawn
   off by a bright facet's or a buried response's sidelobe weighs nothing), its
   uncertainty the fit's standard error there. A node with fewer than ``MIN_PICKS``
   picks, or whose picks lie mostly to one side of it (their centroid more than a third
   of the radius away: the quadratic would extrapolate), takes the navigation's bed
   depths (body depth plus altitude) where the body passed within a node of it (the
   array lies ahead of the body, and the frame is placed by the bed under the first
   ping's body), else its nearest picked neighbour's depth;
4. the relief is kept where it stands out of its own uncertainty: the nodes' spread
   (standard deviation about their mean) more than ``MIN_RELIEF_SIGMAS`` times the
   median node uncertainty and more than ``MIN_RELIEF_M``. A level, rough bed's picks
   scatter by speckle alone, and it stays a plane. And where the echo's relief agrees
   with the navigation's bed along the body's track (the two rms about their means
   within ``NAV_AGREE_FRACTION`` of the relief's spread): the echo's picks over a field
   of proud objects (the Sayers-like field: 9.4 cm rms) are the objects, not the bed.

The relief is what the picks say about the plane, up to one constant: the first ping's
frame puts its level at the bed under its body. The tiles are then imaged in that same
frame (``imaging.interface = "altitude"`` becomes ``"navigation"``: each ping at the
navigation's depth, not at its own altitude). A ping placed at its own altitude would
need the relief under its body to a millimetre: the echo's relief there, a few
millimetres off from node to node, moved the pings' heights by ±6 mm on the bench's
undulating sand and cost 1.2 dB of a shallow point's focus and 7 % of its speed. Placed
by the navigation, the pings carry the navigation's vertical errors instead (on a real
recording a few centimetres: docs/navigation.md), as the relief measured in that frame
does.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.ndimage import uniform_filter
from scipy.spatial import cKDTree

from svss_daq.config import ProcessingConfig
from svss_daq.ping import Ping

from ..imaging.schedule import line_from_pose
from ..imaging.surface import InterfaceShape, bilinear
from .slope import ECHO_CONTRAST_DB, image_slab

log = logging.getLogger(__name__)

__all__ = ["ReliefEstimate", "estimate_relief", "with_relief"]

#: half-thickness of the slab imaged about the plane, m: the relief (and the first ping's
#: level, the bed under its body) move the interface about the slab's middle, and each
#: column needs water above its echo
SLAB_HALF_M = 0.6
#: the slab's top this thick is the water the echo must stand out of, m
WATER_M = 0.15
#: the second picking's window about the coarse surface, m: more than the coarse
#: surface's error, less than the depth of a buried response under the interface
PEAK_WINDOW_M = 0.1
#: the echo's first rise: the first voxel within this of the column's brightest, dB
RISE_DB = 10.0
#: depths this close to the interface's echo by way of the sea surface are not picked, m
GHOST_BAND_M = 0.12
#: node spacing of the relief, along and across the track line, m
NODE_M = 0.25
#: a column is picked where its coverage through the slab is at least this share of the
#: best covered column's: a column seen by a small part of its aperture (at a run's ends,
#: the swath's edges) is blurred, and its echo's peak is not the surface's depth (at the
#: swath's edges, half covered, the picks still lie 2-3 cm deep: docs/seabed.md)
FULL_APERTURE = 0.5
#: the image's power is averaged over this span along and across before picking, m
SMOOTH_M = 0.2
#: ... and over this span for the coarse surface (a silt's volume speckle averages down
#: under it, the interface's sheet does not)
COARSE_SMOOTH_M = 0.6
#: picks a node needs for a depth of its own
MIN_PICKS = 12
#: the picks a node's surface is fitted to lie within this distance of it, m (a
#: quadratic over it is exact to a millimetre for a 10 cm undulation 4 m long)
RADIUS_M = 0.35
#: Tukey's biweight constant, in robust standard deviations of the residuals
BIWEIGHT_C = 4.685
#: the residuals' robust standard deviation is taken as at least this, m
MIN_SCALE_M = 0.004
#: the relief is kept where the nodes' spread exceeds this many median uncertainties ...
MIN_RELIEF_SIGMAS = 3.0
#: ... and this depth, m (the level silts' picks scatter by 0.8-0.9 cm rms, the sands'
#: by 0.1-0.2 cm)
MIN_RELIEF_M = 0.015
#: ... and where the echo's relief on the body's track is within this fraction of its
#: own spread of the navigation's bed there (both rms about their means), with at
#: least this many of the navigation's bed depths on picked nodes to tell
NAV_AGREE_FRACTION = 0.5
MIN_NAV_SAMPLES = 10


@dataclass(frozen=True)
class ReliefEstimate:
    """The relief's nodes (rows along, columns across; None: none kept), their first
    node (along, cross) and spacing, m; the nodes' spread and median uncertainty, m;
    how many nodes had picks of their own; why."""
    nodes: np.ndarray | None
    origin: tuple[float, float]
    step: tuple[float, float]
    spread_m: float
    sigma_m: float
    n_picked: int
    source: str

    def summary(self) -> dict:
        r = lambda v: None if v is None or not math.isfinite(v) else round(float(v), 4)  # noqa: E731
        out = {"interface_relief": self.nodes is not None,
               "interface_relief_rms_m": r(self.spread_m),
               "interface_relief_sigma_m": r(self.sigma_m),
               "interface_relief_nodes": int(self.n_picked),
               "interface_relief_from": self.source}
        if self.nodes is not None:
            out["interface_relief_range_m"] = [r(float(self.nodes.min())),
                                               r(float(self.nodes.max()))]
            out["interface_relief_m"] = [[round(float(v), 4) for v in row]
                                         for row in self.nodes]
            out["interface_relief_origin_m"] = [round(float(v), 4) for v in self.origin]
            out["interface_relief_step_m"] = [round(float(v), 4) for v in self.step]
        return out

    @property
    def description(self) -> str:
        kept = "kept" if self.nodes is not None else "not kept"
        return (f"interface relief {kept}: rms {self.spread_m * 100:.1f} cm against "
                f"{self.sigma_m * 100:.2f} cm a node ({self.source})")


def with_relief(processing: ProcessingConfig, summary: dict) -> ProcessingConfig:
    """``processing`` imaging over the relief of a :meth:`ReliefEstimate.summary` (as
    configured where it kept none), every ping in the frame the relief was measured in
    (module docs: ``imaging.interface = "altitude"`` becomes ``"navigation"``)."""
    nodes = summary.get("interface_relief_m")
    if not nodes:
        return processing
    im = processing.imaging
    return dataclasses.replace(processing, imaging=dataclasses.replace(
        im, interface="navigation" if im.interface == "altitude" else im.interface,
        interface_relief_m=tuple(tuple(float(v) for v in row) for row in nodes),
        interface_relief_origin_m=tuple(float(v) for v in
                                        summary["interface_relief_origin_m"]),
        interface_relief_step_m=tuple(float(v) for v in summary["interface_relief_step_m"])))


def _first_rise(col: np.ndarray, z: np.ndarray, window: np.ndarray, floor: float
                ) -> float | None:
    """The interface echo's depth in one column's power ``col`` within ``window`` (bool
    over ``z``): the first voxel from above within ``RISE_DB`` of the window's brightest,
    then up to its peak, refined by a parabola in log power. None where the brightest
    stands less than ``ECHO_CONTRAST_DB`` over ``floor`` (the water's level) or the peak
    lies at the window's edge. The first rise, not the brightest: a silt's volume below
    the interface is as bright as it; and within ``RISE_DB`` of the brightest, not
    half-way from the water: over deep, quiet water the sidelobes of a brighter facet
    nearby stand 40 dB over it, 15 dB under the interface."""
    idx = np.flatnonzero(window)
    if idx.size < 3:
        return None
    w = col[idx]
    top = float(w.max())
    if top < floor * 10 ** (ECHO_CONTRAST_DB / 10):
        return None
    j = int(np.argmax(w >= top * 10 ** (-RISE_DB / 10)))
    while j + 1 < w.size and w[j + 1] > w[j]:
        j += 1
    if j == 0 or j == w.size - 1:
        return None
    k = int(idx[j])
    lo, mid, hi = np.log(col[k - 1:k + 2])
    den = lo - 2 * mid + hi
    return float(z[k] + (0.5 * (lo - hi) / den if den < 0 else 0.0) * (z[1] - z[0]))


def _picks(tiles, guide: ReliefEstimate | None = None, ghost_m: float = math.nan
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along, cross, depth) of the interface echo in every column seen by enough of its
    aperture (:func:`_first_rise`): below the water (``guide`` None), or within
    ``PEAK_WINDOW_M`` of the ``guide``'s surface."""
    along, cross, depth = [], [], []
    for t in tiles:
        re = np.asarray(t.re, dtype=np.float64)
        im = np.asarray(t.im, dtype=np.float64)
        smooth = COARSE_SMOOTH_M if guide is None else SMOOTH_M
        n = max(1, int(round(smooth / t.grid.voxel_m)) // 2 * 2 + 1)
        pw = uniform_filter(re * re + im * im, size=(n, n, 1), mode="nearest")
        full = np.asarray(t.coverage.pings).min(axis=2)
        z = np.asarray(t.grid.depth)
        # the water: the slab's top WATER_M, above any relief the slab is made for
        water = z < z[0] + WATER_M
        if np.count_nonzero(water) < 3:
            continue
        # the interface's echo by way of the sea surface: a bright sheet, not the bed
        clear = ~(np.abs(z - ghost_m) <= GHOST_BAND_M)
        ok = full >= FULL_APERTURE * max(int(full.max()), 1)
        ia_ok, ic_ok = np.nonzero(ok)
        a_ok = np.asarray(t.grid.along)[ia_ok]
        c_ok = np.asarray(t.grid.cross)[ic_ok]
        centre = (None if guide is None else
                  bilinear(guide.nodes, guide.origin, guide.step, a_ok, c_ok))
        for k, (ia, ic) in enumerate(zip(ia_ok, ic_ok)):
            col = pw[ia, ic]
            floor = float(np.median(col[water]))
            if floor <= 0.0:
                continue
            window = clear & (~water if centre is None
                              else np.abs(z - centre[k]) <= PEAK_WINDOW_M)
            d = _first_rise(col, z, window, floor)
            if d is not None:
                along.append(float(a_ok[k]))
                cross.append(float(c_ok[k]))
                depth.append(d)
    return np.asarray(along), np.asarray(cross), np.asarray(depth)


def _local_surface(da: np.ndarray, dc: np.ndarray, z: np.ndarray
                   ) -> tuple[float, float] | None:
    """(depth at the origin, its standard error) of a quadratic surface through the picks
    at offsets (da, dc) of depths z: Tukey-biweight IRLS from the least-squares surface
    (module docs)."""
    x = np.column_stack([np.ones_like(da), da, dc, da * da, da * dc, dc * dc])
    try:                                # the start: every pick alike (a surface, not
        start = np.linalg.lstsq(x, z, rcond=None)[0]       # the median: on a 10 degree
    except np.linalg.LinAlgError:                          # flank that is 6 cm off at
        return None                                        # the radius)
    r = z - x @ start
    coef = None
    for _ in range(8):
        scale = max(1.4826 * float(np.median(np.abs(r))), MIN_SCALE_M)
        u = r / (BIWEIGHT_C * scale)
        w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        if np.count_nonzero(w) < x.shape[1] + 2:
            return None
        xw = x * w[:, None]
        try:
            new = np.linalg.solve(x.T @ xw, xw.T @ z)
        except np.linalg.LinAlgError:
            return None
        r = z - x @ new
        if coef is not None and abs(new[0] - coef[0]) < 1e-5:
            coef = new
            break
        coef = new
    kept = w > 0.0
    if not (z[kept].min() - MIN_SCALE_M <= coef[0] <= z[kept].max() + MIN_SCALE_M):
        return None             # outside the picks it weighs: an ill-posed surface
    w_sum = float(w.sum())
    normal = x.T @ (x * w[:, None])
    if np.linalg.cond(normal) > 1e12:
        return None
    cov = np.linalg.inv(normal)
    # the weighted residuals' variance, with the fit's degrees of freedom
    var = float((w * r * r).sum()) / max(w_sum - x.shape[1], 1.0)
    return float(coef[0]), float(math.sqrt(max(var * cov[0, 0] * w_sum / max(w_sum, 1.0), 0.0)))


def _surface_ghost_m(pings: Sequence[Ping], hardware) -> float:
    """Where the interface's echo by way of the sea surface (one bounce) appears below
    the interface in a water-speed image, m: the array's median depth below the surface
    (the survey frame's down 0; NaN without poses)."""
    pose = getattr(pings, "nav", None) or (lambda k: pings[k].nav)
    lever = float(hardware.value.lever_arms.array_m[2])
    downs = [pose(k).down_m for k in range(0, len(pings), max(1, len(pings) // 50))]
    downs = [d for d in downs if math.isfinite(d)]
    return float(np.median(downs)) + lever if downs else math.nan


def _bed_under_body(pings: Sequence[Ping], processing: ProcessingConfig) -> np.ndarray:
    """(along, cross, depth) of the bed under each ping's body as its navigation measured
    it (body depth plus altitude), in the slab's frame (the first ping's level, the
    plane of ``processing`` taken off): the relief where the body passes, which frames
    placed at each ping's own altitude need, and where the sonar, ahead of or beside
    the body, may not have looked."""
    pose = getattr(pings, "nav", None) or (lambda k: pings[k].nav)
    shape = InterfaceShape.of(processing.imaging)
    line = None
    out = []
    for k in range(len(pings)):
        nav = pose(k)
        bed = nav.down_m + nav.altitude_m
        if not math.isfinite(bed):
            continue
        if line is None:
            line = line_from_pose(nav, processing)
        a, c, _ = line.ned_to_tile(np.array([nav.north_m, nav.east_m, 0.0]))
        out.append((a, c, bed - line.interface_down - float(shape.depth(a, c))))
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def _nav_disagreement(nodes: np.ndarray, a0: float, c0: float, node_m: float,
                      bed: np.ndarray) -> float:
    """The rms (m, about their mean) of the echo's nodes less the navigation's bed depths
    ``bed`` (along, cross, depth) on the nodes nearest them that have picks of their own;
    0 where fewer than ``MIN_NAV_SAMPLES`` lie on such nodes."""
    if not bed.shape[0]:
        return 0.0
    i = np.rint((bed[:, 0] - a0) / node_m).astype(np.int64)
    j = np.rint((bed[:, 1] - c0) / node_m).astype(np.int64)
    ok = (i >= 0) & (i < nodes.shape[0]) & (j >= 0) & (j < nodes.shape[1])
    d = nodes[i[ok], j[ok]] - bed[ok, 2]
    d = d[np.isfinite(d)]
    if d.size < MIN_NAV_SAMPLES:
        return 0.0
    return float(np.std(d))


def relief_nodes(along: np.ndarray, cross: np.ndarray, depth: np.ndarray,
                 node_m: float = NODE_M, bed: np.ndarray | None = None,
                 radius_m: float = RADIUS_M, keep_all: bool = False) -> ReliefEstimate:
    """The picks (along, cross, depth) gathered on nodes ``node_m`` apart (module docs,
    steps 3 and 4); ``bed`` (n, 3): the navigation's bed under the body (along, cross,
    depth), for the nodes no echo reaches."""
    if along.size < MIN_PICKS:
        return ReliefEstimate(None, (0.0, 0.0), (node_m, node_m), math.nan, math.nan, 0,
                              f"kept: {along.size} interface echoes picked")
    bed = np.zeros((0, 3)) if bed is None else np.asarray(bed, dtype=np.float64)
    a_all = np.r_[along, bed[:, 0]]
    c_all = np.r_[cross, bed[:, 1]]
    a0 = math.floor(a_all.min() / node_m) * node_m
    c0 = math.floor(c_all.min() / node_m) * node_m
    na = int(round((a_all.max() - a0) / node_m)) + 1
    nc = int(round((c_all.max() - c0) / node_m)) + 1
    nodes = np.full((na, nc), np.nan)
    sigma = np.full((na, nc), np.nan)
    tree = cKDTree(np.column_stack([along, cross]))
    for i in range(na):
        for j in range(nc):
            a, c = a0 + i * node_m, c0 + j * node_m
            near = tree.query_ball_point((a, c), radius_m)
            if len(near) < MIN_PICKS:
                continue
            if math.hypot(float(np.mean(along[near])) - a,
                          float(np.mean(cross[near])) - c) > radius_m / 3:
                continue
            fit = _local_surface(along[near] - a, cross[near] - c, depth[near])
            if fit is not None:
                nodes[i, j], sigma[i, j] = fit
    picked = np.isfinite(nodes)
    n_picked = int(picked.sum())
    if n_picked < 4:
        return ReliefEstimate(None, (a0, c0), (node_m, node_m), math.nan, math.nan,
                              n_picked, f"kept: {n_picked} nodes with {MIN_PICKS} picks")
    # the echo's relief where the body passed against the navigation's bed there: two
    # views of the same bed (a proud object's or a bright patch's picks are not the bed)
    disagree = _nav_disagreement(nodes, a0, c0, node_m, bed)
    # nodes without picks of their own: the navigation's bed where the body passed
    # within a node of them (the median of its depths there), else their nearest
    # picked neighbour's depth
    pa, pc = np.nonzero(picked)
    bed_tree = cKDTree(bed[:, :2]) if bed.shape[0] else None
    n_bed = 0
    for i, j in zip(*np.nonzero(~picked)):
        if bed_tree is not None:
            near = bed_tree.query_ball_point((a0 + i * node_m, c0 + j * node_m), node_m)
            if near:
                nodes[i, j] = float(np.median(bed[near, 2]))
                n_bed += 1
                continue
        k = int(np.argmin((pa - i) ** 2 + (pc - j) ** 2))
        nodes[i, j] = nodes[pa[k], pc[k]]
    spread = float(np.std(nodes[picked]))
    sig = float(np.median(sigma[picked]))
    src = (f"interface echo, {along.size} columns on {n_picked} nodes of "
           f"{node_m:.2f} m" + (f"; the navigation's bed on {n_bed} more" if n_bed else ""))
    if not keep_all and spread <= max(MIN_RELIEF_SIGMAS * sig, MIN_RELIEF_M):
        return ReliefEstimate(None, (a0, c0), (node_m, node_m), spread, sig, n_picked,
                              src + ": within its uncertainty, a plane")
    if not keep_all and disagree > max(NAV_AGREE_FRACTION * spread, MIN_RELIEF_M):
        return ReliefEstimate(None, (a0, c0), (node_m, node_m), spread, sig, n_picked,
                              src + f": {100 * disagree:.1f} cm rms off the navigation's "
                              "bed where the body passed: not the bed, a plane kept")
    return ReliefEstimate(nodes, (a0, c0), (node_m, node_m), spread, sig, n_picked, src)


def estimate_relief(pings: Sequence[Ping], hardware, processing: ProcessingConfig
                    ) -> ReliefEstimate:
    """The interface's relief about the plane of ``processing`` under a run's ``pings``
    (in order, posed as they are to be imaged) with ``hardware`` (Loaded)."""
    im = processing.imaging
    steady = dataclasses.replace(processing, imaging=dataclasses.replace(
        im, interface="navigation" if im.interface == "altitude" else im.interface,
        interface_relief_m=None))
    tiles = image_slab(pings, hardware, steady, SLAB_HALF_M)
    bed = _bed_under_body(pings, steady)
    # a coarse surface through each column's brightest (robust to a buried response's
    # cluster of picks over twice the radius), then each column's brightest near it
    ghost = _surface_ghost_m(pings, hardware)
    coarse = relief_nodes(*_picks(tiles, ghost_m=ghost), bed=bed, radius_m=2 * RADIUS_M,
                          keep_all=True)
    if coarse.nodes is None:
        log.info("%s", coarse.description)
        return coarse
    est = relief_nodes(*_picks(tiles, coarse, ghost), bed=bed)
    log.info("%s", est.description)
    return est
