"""Contacts in the background-normalised volume.

Detection (docs/detections.md): voxels whose normalised level (dB re background) reaches
``threshold_db`` and that enough pings imaged (``detectable``: the coverage rule) are
grouped into 26-connected regions; regions of fewer than ``min_voxels`` voxels are
dropped; each region's contact sits at its peak voxel, refined to sub-voxel precision by
a parabola through the peak and its two neighbours along each axis (in dB; at most half
a voxel); a region peaking on the bottom face, or on a top face in the water, is
dropped (its maximum is outside the volume). Contacts closer than ``merge_m`` (per
axis) to a stronger contact merge into it
(its extent grows to cover both). A contact whose peak *magnitude* is at least
``sidelobe_db`` below a stronger contact's, within that contact's sidelobe region
(:func:`is_sidelobe`: seen by one ping's projector cone together with it, or within
``sidelobe_m``), is taken for one of its imaging sidelobes (or its decaying elastic
tail) and dropped. The strongest ``max_per_tile`` are kept.

For speckle (Rayleigh-distributed magnitude) normalised by its median the probability
that a voxel reaches ``T`` dB is ``2 ** -(10 ** (T / 10))``: 1.7e-5 at 12 dB, 2.8e-8 at
14 dB, 3e-10 at 15 dB; multiply by a tile's 7.5 million voxels (fewer independent
resolution cells in a real image) for the expected false voxels per tile.

This module never sees the truth of a scene: scoring against ground truth is the
``svss score`` command's (:mod:`svss.score`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from svss_daq.decibels import amplitude_to_db
from svss_daq.geometry import cone_radius

from .classify import CLASS_FIELDS, CLASS_FILL
from .contact_features import FEATURE_FIELDS, FEATURE_FILL

log = logging.getLogger(__name__)

#: detection table columns: (name, dtype, units, meaning)
FIELDS = (
    ("along_m", "f8", "m", "along-track position of the peak (tile frame)"),
    ("cross_m", "f8", "m", "cross-track position of the peak, starboard positive"),
    ("depth_m", "f8", "m", "depth of the peak below the interface"),
    ("peak_db", "f4", "dB re 1 uPa", ("image magnitude at the peak voxel (uncalibrated: "
                                      "the coherent sum over pings and channels of "
                                      "matched-filter outputs; for comparing contacts "
                                      "within a run, not a target strength)")),
    ("background_db", "f4", "dB re 1 uPa", "background (median) at the peak voxel"),
    ("excess_db", "f4", "dB", "signal excess: normalised level at the peak, dB re "
                               "background"),
    ("extent_along_m", "f4", "m", "along-track extent of the voxels above threshold"),
    ("extent_cross_m", "f4", "m", "cross-track extent of the voxels above threshold"),
    ("extent_depth_m", "f4", "m", "depth extent of the voxels above threshold"),
    ("n_voxels", "i8", "1", "voxels above threshold"),
    ("coverage_pings", "i4", "1", "pings that imaged the peak voxel (0: not known)"),
    ("coverage_fraction", "f4", "1", ("coverage_pings as a fraction of the full coverage "
                                      "at that depth (-1: not known)")),
    ("threshold_db", "f4", "dB", ("the threshold at the peak's depth: the configured one, "
                                  "or its layer's where that layer's clutter is heavier "
                                  "(-1: not known)")),
    ("false_alarms", "f4", "1", ("voxels of the peak's depth layer in the tile expected "
                                 "at or above its level from the layer's own clutter "
                                 "(its fitted tail, or speckle's where it has none; -1: "
                                 "not known: one threshold for all layers)")),
)
#: each contact's features (:mod:`.contact_features`; not measured: their fill values)
FIELDS = FIELDS + FEATURE_FIELDS + CLASS_FIELDS    # and its class (:mod:`.classify`)
DTYPE = np.dtype([(name, dt) for name, dt, _, _ in FIELDS])
#: columns a tile written before they existed may lack, and their fill values
OPTIONAL_FIELDS = {"coverage_pings": 0, "coverage_fraction": -1.0,
                   "threshold_db": -1.0, "false_alarms": -1.0, **FEATURE_FILL,
                   **CLASS_FILL}


@dataclass(frozen=True)
class Footprint:
    """What bounds the imaging sidelobes of a point: the projector's height above the
    interface (m) and the tangent of its cone's half-angle. A ping puts the echo of a
    point onto every voxel at the same two-way range inside its projector cone, so a
    point's sidelobes lie within the horizontal distance over which one ping's cone
    holds both the point and the voxel: ``(2 h + z_point + z_voxel) tan(half-angle)``.
    And only at the same two-way range: a ping sees a point at depth z (m below the
    interface) at ranges from h + s z (nadir) to (h + s z) / cos(half-angle) (cone edge),
    ``s = depth_scale`` the water-equivalent range per metre of sediment (c_w / c_sed;
    straight rays), so two points whose range intervals are further apart than
    ``range_slack_m`` (half the transmitted pulse's length, c T / 2, m) cannot be each
    other's sidelobes: a target buried under a bright interface is not its sidelobe."""
    height_m: float
    tan_half_angle: float
    depth_scale: float = 1.0
    range_slack_m: float = 0.0

    def reach_m(self, z_a: float, z_b: float) -> float:
        return cone_radius(2.0 * self.height_m + max(z_a, 0.0) + max(z_b, 0.0),
                           self.tan_half_angle)

    def ranges_m(self, z: float) -> tuple[float, float]:
        """Nearest and furthest range (m, water-equivalent) at which one ping of this
        footprint's height sees a point at depth ``z`` inside its cone."""
        near = self.height_m + (z * self.depth_scale if z > 0.0 else z)
        return near, near * math.sqrt(1.0 + self.tan_half_angle ** 2)

    def may_share_range(self, z_a: float, z_b: float) -> bool:
        """Whether some ping can see points at depths ``z_a`` and ``z_b`` at one range
        (within ``range_slack_m``)."""
        a0, a1 = self.ranges_m(z_a)
        b0, b1 = self.ranges_m(z_b)
        return a0 <= b1 + self.range_slack_m and b0 <= a1 + self.range_slack_m


#: a contact claims later echoes only this far or more below the interface, m
LATER_ECHO_MIN_DEPTH_M = 0.1


def is_later_echo(weak_pos, strong_pos, later_echo_m) -> bool:
    """A weaker contact at ``weak_pos`` is a later echo of a stronger one at
    ``strong_pos`` (along, cross, depth; m): it lies under it, within
    ``later_echo_m`` (along, cross, depth below; None: never), and the stronger one is
    buried (``LATER_ECHO_MIN_DEPTH_M`` or more below the interface). An elastic object
    rings and its internal paths arrive late: its response extends below it, imaged as
    more objects deeper (the seed's "decaying return versus depth"); they are the same
    object. The interface's own bright patches claim nothing: a buried object under one
    would be lost in it (with one threshold on the seed's sand line, the buried cylinder
    was)."""
    if later_echo_m is None or float(strong_pos[2]) < LATER_ECHO_MIN_DEPTH_M:
        return False
    d = np.asarray(weak_pos, dtype=np.float64) - np.asarray(strong_pos, dtype=np.float64)
    return bool(abs(d[0]) <= later_echo_m[0] and abs(d[1]) <= later_echo_m[1]
                and 0.0 < d[2] <= later_echo_m[2])


def is_sidelobe(weak_pos, weak_peak_db: float, strong_pos, strong_peak_db: float,
                sidelobe_db: float, sidelobe_m: float,
                footprint: Footprint | None = None) -> bool:
    """Whether a contact at ``weak_pos`` (along, cross, depth; m) whose peak magnitude is
    ``weak_peak_db`` (dB re 1 uPa) can be an imaging sidelobe of a contact at
    ``strong_pos`` with ``strong_peak_db``: at least ``sidelobe_db`` weaker, and within
    ``sidelobe_m`` (Euclidean) or, with a ``footprint``, horizontally within the reach
    of one ping's projector cone; with a ``footprint``, never when no ping can see the
    two at one range (:meth:`Footprint.may_share_range`). Magnitudes, not excesses, are
    compared: a sidelobe's amplitude is a fraction of its source's whatever the
    backgrounds (the background under a strong target is raised by its own sidelobes, so
    its excess can be smaller than theirs)."""
    if strong_peak_db - weak_peak_db < sidelobe_db:
        return False
    w, s = np.asarray(weak_pos, dtype=np.float64), np.asarray(strong_pos, dtype=np.float64)
    if footprint is not None and not footprint.may_share_range(float(w[2]), float(s[2])):
        return False
    if float(np.linalg.norm(w - s)) <= sidelobe_m:
        return True
    if footprint is None:
        return False
    return bool(float(np.hypot(*(w[:2] - s[:2]))) <= footprint.reach_m(w[2], s[2]))


def sidelobe_zone(mag_db: np.ndarray, axes, sources_pos: np.ndarray,
                  sources_peak_db: np.ndarray, sidelobe_db: float, sidelobe_m: float,
                  footprint: Footprint | None = None) -> np.ndarray:
    """The voxels (a mask, the shape of ``mag_db``: |image| in dB re 1 uPa, along x
    cross x depth, on ``axes``) that :func:`is_sidelobe` would call an imaging sidelobe
    of one of the ``sources`` (positions (n, 3) in the same frame, peak magnitudes (n,)
    dB): at least ``sidelobe_db`` weaker than it, and within ``sidelobe_m`` of it or
    within one ping's footprint of it at a range some ping shares."""
    zone = np.zeros(mag_db.shape, dtype=bool)
    a, c, z = (np.asarray(ax, dtype=np.float64) for ax in axes)
    for pos, peak in zip(np.asarray(sources_pos, dtype=np.float64).reshape(-1, 3),
                         np.asarray(sources_peak_db, dtype=np.float64)):
        reach = share = None
        far = sidelobe_m
        if footprint is not None:
            reach = np.array([footprint.reach_m(float(zz), float(pos[2])) for zz in z])
            share = np.array([footprint.may_share_range(float(zz), float(pos[2]))
                              for zz in z])
            far = max(far, float(reach.max(initial=0.0)))
        # only the along-track planes the source's sidelobes can reach
        lo = int(np.searchsorted(a, pos[0] - far, side="left"))
        hi = int(np.searchsorted(a, pos[0] + far, side="right"))
        if hi <= lo:
            continue
        horiz = np.hypot(a[lo:hi, None] - pos[0], c[None, :] - pos[1])
        near = np.sqrt(horiz[:, :, None] ** 2 + (z[None, None, :] - pos[2]) ** 2) \
            <= sidelobe_m
        if footprint is not None:
            near = (near | (horiz[:, :, None] <= reach[None, None, :])) \
                & share[None, None, :]
        zone[lo:hi] |= near & (mag_db[lo:hi] <= peak - sidelobe_db)
    return zone


def empty() -> np.ndarray:
    """A detection table with no rows."""
    return np.zeros(0, dtype=DTYPE)


def sidelobe_filter(pos: np.ndarray, peak_db: np.ndarray, sidelobe_db: float,
                    sidelobe_m: float, footprint: Footprint | None = None) -> np.ndarray:
    """Which contacts survive sidelobe suppression: ``pos`` (n, 3) along, cross, depth
    (m, one frame), ``peak_db`` (n,) peak magnitudes (dB re 1 uPa). Strongest first, a
    contact is dropped when it :func:`is_sidelobe` of a stronger one kept. Returns a
    boolean mask (n,)."""
    order = np.argsort(-np.asarray(peak_db, dtype=np.float64), kind="stable")
    keep = np.zeros(len(order), dtype=bool)
    kept: list[int] = []
    for i in order:
        if not any(is_sidelobe(pos[i], peak_db[i], pos[k], peak_db[k], sidelobe_db,
                               sidelobe_m, footprint) for k in kept):
            kept.append(int(i))
            keep[i] = True
    return keep


def _refine(level: np.ndarray, idx: tuple[int, int, int], axis: int) -> float:
    """Sub-voxel offset (voxels, |offset| <= 0.5) of the peak along ``axis`` from a
    parabola through the peak and its neighbours; 0 at a face or without finite
    neighbours."""
    i = idx[axis]
    if i == 0 or i == level.shape[axis] - 1:
        return 0.0
    lo, hi = list(idx), list(idx)
    lo[axis], hi[axis] = i - 1, i + 1
    a, b, c = float(level[tuple(lo)]), float(level[idx]), float(level[tuple(hi)])
    den = a - 2.0 * b + c
    if not (np.isfinite(a) and np.isfinite(c)) or den >= 0:
        return 0.0
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))


@dataclass(frozen=True)
class Regions:
    """The labelled regions of a volume, from their voxels only: for labels 1 .. n
    (``labels``), ``counts`` (voxels), ``peak_value`` (the largest finite level; -inf
    when none is finite), ``peak`` (3, n: the voxel of that level, the first in C order
    where several share it) and the bounding box ``lo`` (3, n), ``hi`` (3, n;
    exclusive)."""
    labels: np.ndarray
    counts: np.ndarray
    peak_value: np.ndarray
    peak: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def _regions(labels: np.ndarray, level: np.ndarray) -> Regions:
    """:class:`Regions` of ``labels`` (ndimage.label's, 1 .. n consecutive) over
    ``level``. Only the labelled voxels are visited: a tile's regions are a few thousand
    of its 7.5 million voxels (``ndimage.maximum_position`` sorted all of them: 0.8 of a
    default tile's 1 s of detection, issue 32)."""
    flat = np.flatnonzero(labels)
    lab = labels.ravel()[flat]
    vals = level.ravel()[flat]
    vals = np.where(np.isfinite(vals), vals, -np.inf)
    n = int(lab.max()) if lab.size else 0
    # by label, then level (largest first), then position: each label's first entry is
    # its peak
    order = np.lexsort((flat, -vals, lab))
    lab, flat, vals = lab[order], flat[order], vals[order]
    starts = np.searchsorted(lab, np.arange(1, n + 1))
    coords = np.stack(np.unravel_index(flat, labels.shape))
    lo = np.minimum.reduceat(coords, starts, axis=1) if n else np.zeros((3, 0), np.intp)
    hi = np.maximum.reduceat(coords, starts, axis=1) + 1 if n else np.zeros((3, 0), np.intp)
    return Regions(np.arange(1, n + 1), np.diff(np.append(starts, lab.size)), vals[starts],
                   coords[:, starts], lo, hi)


#: the strongest responses outside the detectable voxels taken as sidelobe sources
HIDDEN_SOURCES = 20


def _hidden_sources(mask: np.ndarray, mag: np.ndarray, axes, min_voxels: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3), peak magnitudes dB re 1 uPa) of the :data:`HIDDEN_SOURCES`
    strongest regions of ``mask`` (at least ``min_voxels`` voxels), by peak magnitude."""
    if not mask.any():
        return np.zeros((0, 3)), np.zeros(0)
    labels, _ = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
    regions = _regions(labels, mag)     # labelled voxels only: their levels are finite
    big = regions.counts >= min_voxels
    peaks, values = regions.peak[:, big], regions.peak_value[big]
    order = np.argsort(-values)[:HIDDEN_SOURCES]
    pos = np.stack([np.asarray(axes[k], dtype=np.float64)[peaks[k, order]] for k in range(3)],
                   axis=1) if order.size else np.zeros((0, 3))
    db = np.array([amplitude_to_db(max(float(v), 1e-30)) for v in values[order]])
    return pos, db


def _absorb(into: dict, c: dict) -> None:
    """Contact candidate ``c`` made part of ``into``: its extent and voxels added."""
    into["lo"] = np.minimum(into["lo"], c["lo"])
    into["hi"] = np.maximum(into["hi"], c["hi"])
    into["n"] += c["n"]


def detect(level: np.ndarray, mag: np.ndarray, background: np.ndarray,
           axes: tuple[np.ndarray, np.ndarray, np.ndarray], threshold_db,
           min_voxels: int, merge_m: tuple[float, float, float],
           max_detections: int, sidelobe_db: float = np.inf,
           sidelobe_m: float = 0.0, *, detectable: np.ndarray | None = None,
           coverage_pings: np.ndarray | None = None,
           coverage_fraction: np.ndarray | None = None,
           footprint: Footprint | None = None, point_threshold_db: float | None = None,
           extended_min_m3: float | None = None,
           context: tuple[np.ndarray, np.ndarray] | None = None,
           tails=None, later_echo_m: tuple[float, float, float] | None = None
           ) -> np.ndarray:
    """Contacts of a tile.

    ``level``: normalised level, dB re background (along x cross x depth; NaN never
    detects); ``threshold_db``: a number, or one per depth (the layers' thresholds,
    :mod:`.layer_cfar`); ``tails``: the layers' fits (a
    :class:`~.layer_cfar.LayerTails`) that give each contact its expected false
    alarms (None: NaN); ``mag`` and ``background``: magnitude and background (uPa, same shape);
    ``axes``: voxel-centre coordinates (m) of the three axes; ``detectable``: voxels
    allowed to detect (None: all); ``coverage_pings``, ``coverage_fraction``: the
    coverage volumes, reported at each contact's peak; ``footprint``: sidelobe geometry
    (:func:`is_sidelobe`); ``point_threshold_db``: with it, a region (voxels at
    ``threshold_db`` or more) is a contact only when its peak reaches this level or
    its volume is at least ``extended_min_m3`` (m^3; an extended object);
    ``context``: contacts outside the tile (positions (n, 3) in the tile frame, m; peak
    magnitudes, dB re 1 uPa), e.g. the previous tile's: a contact that
    :func:`is_sidelobe` of one of them is dropped as well. Returns a table of
    :data:`DTYPE` rows, strongest excess first.
    """
    if level.shape != mag.shape or level.shape != background.shape:
        raise ValueError(f"shapes differ: level {level.shape}, magnitude {mag.shape}, "
                         f"background {background.shape}")
    thr = np.broadcast_to(np.asarray(threshold_db, dtype=np.float64), level.shape[2:])
    over = np.asarray(level >= thr[None, None, :])  # NaN compares False
    floor_db = float(thr.min()) if thr.size else float("inf")
    mask = over if detectable is None else over & detectable
    if not mask.any():
        return empty()
    labels, n = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
    regions = _regions(labels, level)
    counts = regions.counts
    keep = regions.labels[counts >= min_voxels]
    if keep.size == 0:
        return empty()
    voxel = [float(ax[1] - ax[0]) if ax.size > 1 else 0.0 for ax in axes]
    if detectable is not None and sidelobe_db < np.inf:
        # responses the coverage rule keeps from detecting (too few pings reached them:
        # beside a gap, at a run's end) still spread sidelobes into covered voxels:
        # they are sources, as the neighbouring tiles' contacts are
        hidden = _hidden_sources(over & ~detectable, mag, axes, min_voxels)
        if len(hidden[1]):
            context = hidden if context is None else (
                np.concatenate([np.asarray(context[0], dtype=np.float64).reshape(-1, 3),
                                hidden[0]]),
                np.concatenate([np.asarray(context[1], dtype=np.float64), hidden[1]]))
    if point_threshold_db is not None and point_threshold_db > floor_db:
        # a region is a contact when its peak reaches the point threshold, or when it
        # is an extended object: at least extended_min_m3 above the region threshold
        top = regions.peak_value[keep - 1]
        big = (counts[keep - 1] * float(np.prod(voxel)) >= extended_min_m3
               if extended_min_m3 is not None else np.zeros(keep.size, dtype=bool))
        keep = keep[(top >= point_threshold_db) | big]
        if keep.size == 0:
            return empty()
    cands = []
    # a peak on the bottom face, or on a top face lying in the water, is not a maximum
    # of the image: the object is outside the depth range (a deeper reflector, or a
    # multipath ghost above the seabed); a top face at the interface keeps its
    # contacts (objects resting on the seabed peak there)
    faces = {level.shape[2] - 1}
    if axes[2].size and axes[2][0] < 0.0:       # the top voxel's centre in the water
        faces.add(0)
    n_faces = 0
    for lab in keep:
        peak = tuple(int(p) for p in regions.peak[:, lab - 1])
        if peak[2] in faces and level.shape[2] > 2:
            n_faces += 1
            continue
        pos = [float(axes[k][peak[k]]) + _refine(level, peak, k) * voxel[k]
               for k in range(3)]
        cands.append({"pos": np.array(pos), "peak": peak, "excess": float(level[peak]),
                      "peak_db": float(amplitude_to_db(max(float(mag[peak]), 1e-30))),
                      "lo": regions.lo[:, lab - 1].copy(),
                      "hi": regions.hi[:, lab - 1].copy(), "n": int(counts[lab - 1])})
    # one object per merge box, then sidelobes: both strongest (peak magnitude) first
    cands.sort(key=lambda c: -c["peak_db"])
    merge = np.asarray(merge_m, dtype=np.float64)
    merged: list[dict] = []
    for c in cands:
        for k in merged:
            if np.all(np.abs(c["pos"] - k["pos"]) <= merge):
                _absorb(k, c)
                break
        else:
            merged.append(c)
    n_regions = keep.size
    not_sidelobe = sidelobe_filter(np.array([c["pos"] for c in merged]).reshape(-1, 3),
                                   np.array([c["peak_db"] for c in merged]), sidelobe_db,
                                   sidelobe_m, footprint)
    if context is not None and len(context[1]) and len(merged):
        for i, c in enumerate(merged):
            if not_sidelobe[i] and any(
                    is_sidelobe(c["pos"], c["peak_db"], p, q, sidelobe_db, sidelobe_m,
                                footprint)
                    for p, q in zip(np.asarray(context[0], dtype=np.float64).reshape(-1, 3),
                                    np.asarray(context[1], dtype=np.float64))):
                not_sidelobe[i] = False
    n_sidelobes = int((~not_sidelobe).sum())
    # later echoes, after the sidelobes: every contact, merged or not, has served as a
    # sidelobe source (an echo merged first would no longer explain its own sidelobes)
    kept = []
    for c in sorted((c for c, k in zip(merged, not_sidelobe) if k), key=lambda c: -c["peak_db"]):
        for k in kept:
            if is_later_echo(c["pos"], k["pos"], later_echo_m):
                _absorb(k, c)
                break
        else:
            kept.append(c)
    kept.sort(key=lambda c: -c["excess"])
    kept = kept[:max_detections]
    out = np.zeros(len(kept), dtype=DTYPE)
    for name, fill in {**FEATURE_FILL, **CLASS_FILL}.items():  # later (chain), if at all
        out[name] = fill
    for row, c in zip(out, kept):
        p = c["peak"]
        row["along_m"], row["cross_m"], row["depth_m"] = c["pos"]
        row["peak_db"] = amplitude_to_db(mag[p])
        row["background_db"] = amplitude_to_db(background[p])
        row["excess_db"] = c["excess"]
        ext = (c["hi"] - c["lo"]) * np.asarray(voxel)
        row["extent_along_m"], row["extent_cross_m"], row["extent_depth_m"] = ext
        row["n_voxels"] = c["n"]
        row["coverage_pings"] = 0 if coverage_pings is None else int(coverage_pings[p])
        row["coverage_fraction"] = (-1.0 if coverage_fraction is None
                                    else float(coverage_fraction[p]))
        row["threshold_db"] = float(thr[p[2]])
        expected = float("nan") if tails is None else tails.expected(p[2], float(level[p]))
        row["false_alarms"] = expected if math.isfinite(expected) else -1.0
    log.debug("%d regions above %.1f dB, %d of at least %d voxels, %d peaking on a depth "
              "face, %d sidelobes, %d contacts", n, floor_db, n_regions, min_voxels,
              n_faces, n_sidelobes, out.size)
    return out
