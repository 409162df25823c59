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
2. in each voxel column fully covered, the echo's depth is picked as the slope's
   columns are (:func:`.slope.pick_echo`: the first rise half-way in dB from the water's
   level to the column's brightest, up to its peak, refined by a parabola), and a column
   whose echo stands less than ``ECHO_CONTRAST_DB`` over the water above it has none;
3. the picks are gathered on the relief's nodes (``NODE_M`` apart along and across the
   track line): each node's depth is the median of the picks within half a node of it,
   its uncertainty 1.4826 median absolute deviation / sqrt(n); nodes with fewer than
   ``MIN_PICKS`` take their nearest neighbour's depth;
4. the relief is kept where it stands out of its own uncertainty: the nodes' spread
   (standard deviation about their mean) more than ``MIN_RELIEF_SIGMAS`` times the
   median node uncertainty and more than ``MIN_RELIEF_M``. A level, rough bed's picks
   scatter by speckle alone, and it stays a plane.

The relief is what the picks say about the plane, up to one constant: the first ping's
frame puts its level at the bed under its body, and the tiles' frames (each ping at its
own altitude, :func:`~svss_proc.imaging.surface.level_offset`) subtract the relief
under the body again, so that constant cancels.
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

from .slope import ECHO_CONTRAST_DB, WATER_CLEARANCE_M, image_slab, pick_echo

log = logging.getLogger(__name__)

__all__ = ["ReliefEstimate", "estimate_relief", "with_relief"]

#: node spacing of the relief, along and across the track line, m
NODE_M = 0.25
#: picks a node needs for a depth of its own
MIN_PICKS = 5
#: the relief is kept where the nodes' spread exceeds this many median uncertainties ...
MIN_RELIEF_SIGMAS = 3.0
#: ... and this depth, m
MIN_RELIEF_M = 0.01


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
    configured where it kept none)."""
    nodes = summary.get("interface_relief_m")
    if not nodes:
        return processing
    return dataclasses.replace(processing, imaging=dataclasses.replace(
        processing.imaging,
        interface_relief_m=tuple(tuple(float(v) for v in row) for row in nodes),
        interface_relief_origin_m=tuple(float(v) for v in
                                        summary["interface_relief_origin_m"]),
        interface_relief_step_m=tuple(float(v) for v in summary["interface_relief_step_m"])))


def _picks(tiles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along, cross, depth) of every fully covered column's interface echo."""
    along, cross, depth = [], [], []
    for t in tiles:
        re = np.asarray(t.re, dtype=np.float64)
        im = np.asarray(t.im, dtype=np.float64)
        pw = re * re + im * im
        cov = np.asarray(t.coverage.pings)
        full = cov.min(axis=2)
        z = np.asarray(t.grid.depth)
        water = z < -WATER_CLEARANCE_M
        if np.count_nonzero(water) < 3:
            continue
        ok = full >= 0.5 * max(int(full.max()), 1)
        for ia, ic in zip(*np.nonzero(ok)):
            echo = pick_echo(pw[ia, ic], z, water, ECHO_CONTRAST_DB)
            if echo is not None:
                along.append(float(t.grid.along[ia]))
                cross.append(float(t.grid.cross[ic]))
                depth.append(echo[0])
    return np.asarray(along), np.asarray(cross), np.asarray(depth)


def relief_nodes(along: np.ndarray, cross: np.ndarray, depth: np.ndarray,
                 node_m: float = NODE_M) -> ReliefEstimate:
    """The picks (along, cross, depth) gathered on nodes ``node_m`` apart (module docs,
    steps 3 and 4)."""
    if along.size < MIN_PICKS:
        return ReliefEstimate(None, (0.0, 0.0), (node_m, node_m), math.nan, math.nan, 0,
                              f"kept: {along.size} interface echoes picked")
    a0 = math.floor(along.min() / node_m) * node_m
    c0 = math.floor(cross.min() / node_m) * node_m
    ia = np.rint((along - a0) / node_m).astype(np.int64)
    ic = np.rint((cross - c0) / node_m).astype(np.int64)
    na, nc = int(ia.max()) + 1, int(ic.max()) + 1
    nodes = np.full((na, nc), np.nan)
    sigma = np.full((na, nc), np.nan)
    order = np.lexsort((ic, ia))
    key = ia[order] * nc + ic[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    ends = np.r_[starts[1:], key.size]
    for s, e in zip(starts, ends):
        if e - s < MIN_PICKS:
            continue
        d = depth[order[s:e]]
        med = float(np.median(d))
        k = int(key[s])
        nodes[k // nc, k % nc] = med
        sigma[k // nc, k % nc] = 1.4826 * float(np.median(np.abs(d - med))) / math.sqrt(e - s)
    picked = np.isfinite(nodes)
    n_picked = int(picked.sum())
    if n_picked < 4:
        return ReliefEstimate(None, (a0, c0), (node_m, node_m), math.nan, math.nan,
                              n_picked, f"kept: {n_picked} nodes with {MIN_PICKS} picks")
    # nodes without picks of their own: their nearest picked neighbour's depth
    pa, pc = np.nonzero(picked)
    for i, j in zip(*np.nonzero(~picked)):
        k = int(np.argmin((pa - i) ** 2 + (pc - j) ** 2))
        nodes[i, j] = nodes[pa[k], pc[k]]
    spread = float(np.std(nodes[picked]))
    sig = float(np.median(sigma[picked]))
    src = (f"interface echo, {along.size} columns on {n_picked} nodes of "
           f"{node_m:.2f} m")
    if spread <= max(MIN_RELIEF_SIGMAS * sig, MIN_RELIEF_M):
        return ReliefEstimate(None, (a0, c0), (node_m, node_m), spread, sig, n_picked,
                              src + ": within its uncertainty, a plane")
    return ReliefEstimate(nodes, (a0, c0), (node_m, node_m), spread, sig, n_picked, src)


def estimate_relief(pings: Sequence[Ping], hardware, processing: ProcessingConfig
                    ) -> ReliefEstimate:
    """The interface's relief about the plane of ``processing`` under a run's ``pings``
    (in order, posed as they are to be imaged) with ``hardware`` (Loaded)."""
    im = processing.imaging
    steady = dataclasses.replace(processing, imaging=dataclasses.replace(
        im, interface="navigation" if im.interface == "altitude" else im.interface,
        interface_relief_m=None))
    along, cross, depth = _picks(image_slab(pings, hardware, steady))
    est = relief_nodes(along, cross, depth)
    log.info("%s", est.description)
    return est
