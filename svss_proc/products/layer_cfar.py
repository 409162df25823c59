"""A detection threshold per depth layer, from the layer's own statistics: a constant
false-alarm rate per volume (docs/detections.md, "Layer thresholds").

One threshold for the whole tile assumes every layer's normalised level has the tail of
fully developed speckle (Rayleigh magnitude: a voxel of normalised intensity
x = 10^(L/10) exceeds X with probability 2^-X). Some layers do not: the interface's own
layer (a sheet of strong discrete facets), a bright multiple's sheet near a tile's
bottom, sparse volume scatterers. Their tails are heavier, and a 17 dB threshold that is
1e-15 per voxel in speckle crosses hundreds of voxels there (the seed's sand line: 86 of
104 contacts at 1.8-2.0 m, 9 on the interface).

Per depth plane of a tile, over the voxels allowed to detect, the tail of x is fitted
with a Weibull survival function

    P(X > x) = exp(-(x / lam)^k)

through two of its quantiles (the levels exceeded by ``p_a`` and ``p_b`` of the layer,
10 % and 1 %: a target's few voxels do not move them). Speckle gives k = 1 and
lam = 1 / ln 2 exactly (the exponential intensity); heavier tails give k < 1. The
layer's threshold is where that tail falls to the per-voxel false-alarm probability
``pfa`` (the configured false alarms per m^3 times a voxel's volume):

    X_T = lam (ln(1 / pfa))^(1 / k),  T = 10 log10 X_T dB,

and a voxel detects at max(T, the configured threshold): a speckle layer keeps the
configured threshold (its T is 14.8 dB for 1e-4 per m^3 in 2 cm voxels), a heavy-tailed
one is raised above its own clutter. A contact's expected false alarms are the layer's
voxels times P(X > its level), from the same fit.

Clutter fills a layer along the whole track; a target's sidelobes fill only the few
metres its pings' footprint spans (the demo's points in water, 36-46 dB over the noise,
spread sidelobes over more than 1 % of their layers and, fitted over the whole tile,
raised their own layers' thresholds to 40-90 dB, above them). So:

- the along-track stretch within a projector footprint's reach of any voxel
  ``GUARD_DB`` or more over the configured threshold (a strong response, whose
  sidelobes those are) is left out of every layer's fit, as a CFAR's guard cells are;
- each layer is fitted in along-track blocks of ``BLOCK_M`` and its threshold is the
  median of the blocks': what the guard misses moves one or two blocks, clutter all.

- the ``GUARD_REGIONS`` strongest regions over the configured threshold (the objects a
  dense field holds: one every 2 m in the Sayers-like field, each spreading over more
  than 1 % of its block's top layer) are left out with ``GUARD_MARGIN_M`` about them:
  clutter crosses the threshold in many more regions than that and still shows in the
  fit (the seed's sand line: 104).

A layer with no block left keeps the configured threshold. Clutter that itself reaches
``GUARD_DB`` over the threshold guards itself out of the fit: this handles tails up to
that level (the seed's sand: 25.8 dB at most, 8.8 dB over the 17 dB threshold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the quantiles the tail is fitted through: levels exceeded by these fractions
P_A, P_B = 0.1, 0.01
#: fewer voxels in a block of a layer than this: no fit there
MIN_LAYER_VOXELS = 1000
#: the along-track blocks each layer is fitted in, m
BLOCK_M = 3.0
#: a voxel this far over the configured threshold is a strong response: the stretch
#: its sidelobes may reach is left out of the fits, dB
GUARD_DB = 10.0
#: the strongest regions over the threshold left out of the fits, per tile
GUARD_REGIONS = 10
#: and how far about each region's voxels, m
GUARD_MARGIN_M = 0.3


@dataclass(frozen=True)
class LayerTails:
    """Per depth plane: the Weibull tail's scale ``lam`` and shape ``k`` of the
    normalised intensity (NaN: no fit), the voxels fitted ``n`` and the threshold
    ``threshold_db`` (dB re background: max of the configured one and the tail's)."""
    lam: np.ndarray
    k: np.ndarray
    n: np.ndarray
    threshold_db: np.ndarray

    def expected(self, iz: int, level_db: float) -> float:
        """Expected voxels of layer ``iz`` at or above ``level_db``: from the layer's
        fitted tail, or where it has none (too few voxels left out of the guards) from
        speckle's (k = 1, lam = 1 / ln 2), which its threshold, the configured one, then
        assumes."""
        lam, k = float(self.lam[iz]), float(self.k[iz])
        if not (math.isfinite(lam) and math.isfinite(k)):
            lam, k = 1.0 / math.log(2.0), 1.0
        x = 10.0 ** (level_db / 10.0)
        return float(self.n[iz]) * math.exp(-((x / lam) ** k))


def weibull_tail(x: np.ndarray, p_a: float = P_A, p_b: float = P_B
                 ) -> tuple[float, float]:
    """(lam, k) of the Weibull survival exp(-(x/lam)^k) through the levels of ``x``
    exceeded by the fractions ``p_a`` > ``p_b``; (NaN, NaN) where they do not rise."""
    xa, xb = np.quantile(np.asarray(x, dtype=np.float64), [1.0 - p_a, 1.0 - p_b])
    if not (xa > 0.0 and xb > xa):
        return float("nan"), float("nan")
    k = math.log(math.log(1.0 / p_b) / math.log(1.0 / p_a)) / math.log(xb / xa)
    lam = xb / math.log(1.0 / p_b) ** (1.0 / k)
    return lam, k


def guarded_along(level_db: np.ndarray, detectable: np.ndarray | None, floor_db: float,
                  reach_m: float, voxel_m: float) -> np.ndarray:
    """Along-track indices (a mask over axis 0) within ``reach_m`` of a voxel at least
    ``GUARD_DB`` over ``floor_db`` (among the ``detectable`` ones)."""
    strong = np.asarray(level_db >= floor_db + GUARD_DB)
    if detectable is not None:
        strong &= detectable
    rows = strong.any(axis=(1, 2))
    if not rows.any():
        return rows
    from scipy.ndimage import maximum_filter1d
    half = int(math.ceil(reach_m / voxel_m))
    return maximum_filter1d(rows.astype(np.uint8), size=2 * half + 1, mode="constant") > 0


def guarded_regions(level_db: np.ndarray, detectable: np.ndarray | None,
                    floor_db: float, voxel_m: float) -> np.ndarray:
    """A mask of the voxels within ``GUARD_MARGIN_M`` of the ``GUARD_REGIONS`` strongest
    26-connected regions at or over ``floor_db`` (among the ``detectable`` voxels)."""
    from scipy import ndimage
    over = np.asarray(level_db >= floor_db)
    if detectable is not None:
        over &= detectable
    out = np.zeros(level_db.shape, dtype=bool)
    if not over.any():
        return out
    labels, n = ndimage.label(over, structure=np.ones((3, 3, 3), dtype=bool))
    peaks = ndimage.maximum(level_db[over], labels[over], np.arange(1, n + 1))
    strongest = np.arange(1, n + 1)[np.argsort(-np.asarray(peaks))[:GUARD_REGIONS]]
    half = max(1, int(round(GUARD_MARGIN_M / voxel_m)))
    for box, lab in zip(ndimage.find_objects(labels), range(1, n + 1)):
        if lab in strongest and box is not None:
            out[tuple(slice(max(0, b.start - half), b.stop + half) for b in box)] = True
    return out


def layer_tails(level_db: np.ndarray, detectable: np.ndarray | None, pfa: float,
                floor_db: float, voxel_m: float, guard: np.ndarray | None = None,
                exclude: np.ndarray | None = None) -> LayerTails:
    """The tails and thresholds of each depth plane (last axis) of ``level_db``
    (normalised level, dB re background, along x cross x depth; NaN never counts) over
    the ``detectable`` voxels (None: all) outside the ``guard``ed along-track indices
    (:func:`guarded_along`; None: none) and the ``exclude``d voxels
    (:func:`guarded_regions`; None: none), fitted per along-track block (``voxel_m``:
    the voxel's size, m) and the median block's taken; ``pfa``: false-alarm
    probability per voxel; ``floor_db``: the configured threshold, the least any layer
    gets."""
    if not 0.0 < pfa < 1.0:
        raise ValueError(f"per-voxel false-alarm probability {pfa!r}: expected 0 < pfa < 1")
    na, nz = level_db.shape[0], level_db.shape[-1]
    per_block = max(1, int(round(BLOCK_M / voxel_m)))
    n_blocks = max(1, na // per_block)
    edges = np.linspace(0, na, n_blocks + 1).round().astype(int)
    lam, k = np.full(nz, np.nan), np.full(nz, np.nan)
    n = np.zeros(nz, dtype=np.int64)
    thr = np.full(nz, float(floor_db))
    log_inv_pfa = math.log(1.0 / pfa)
    for iz in range(nz):
        plane = level_db[..., iz]
        ok = np.isfinite(plane)
        if detectable is not None:
            ok &= detectable[..., iz]
        n[iz] = int(ok.sum())
        if guard is not None:
            ok &= ~guard[:, None]
        if exclude is not None:
            ok &= ~exclude[..., iz]
        fits = []
        for a, b in zip(edges[:-1], edges[1:]):
            sel = ok[a:b]
            if sel.sum() < MIN_LAYER_VOXELS:
                continue
            lb, kb = weibull_tail(10.0 ** (plane[a:b][sel] / 10.0))
            if math.isfinite(lb):
                fits.append((10.0 * math.log10(lb * log_inv_pfa ** (1.0 / kb)), lb, kb))
        if not fits:
            continue
        fits.sort()
        t_db, lam[iz], k[iz] = fits[(len(fits) - 1) // 2]
        thr[iz] = max(float(floor_db), t_db)
    return LayerTails(lam, k, n, thr)
