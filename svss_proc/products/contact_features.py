"""Features of each contact that speak to what it is made of (issue 51;
docs/contact_features.md).

An elastic object rings: its internal paths and resonances arrive after its specular
echo, and the image puts them below it, a response that decays with apparent depth and
reaches far beyond the object's size (the seed's man-made targets); a rock's thickness
resonances die within a few cycles. Measured here, from the normalised level of a tile
(dB re the local background, along x cross x depth, :mod:`.chain`) and its contacts:

* the **tail profile**: the mean normalised intensity over the contact's footprint (its
  along- and cross-track extent about its peak, within configured bounds) at each depth
  below its peak, over the same mean in reference footprints beside it along-track at
  the same depths (the local background's own mean: 0 dB where there is only
  background), :func:`tail_profile`;
* the tail's **extent**: the depth below the peak from which the profile stays within
  ``background_within_db`` of the background for ``below_run_m``; NaN where the tile's
  bottom comes first (flag :data:`TAIL_CUT`);
* the **decay rate**: a least-squares line through the background-subtracted profile
  (10 log10(I/B - 1), dB) from the end of the peak window to the extent, dB per metre of
  apparent depth (positive: decaying), with its standard error from the residuals
  (inflated for their depth correlation, an AR(1) factor);
* the **aspect over the aperture**: the look angles (along-track) the contact's
  response came from, from the complex image's along-track spectrum about it
  (:func:`aspect_spread`: their mean and rms spread; a flat face answers only near its
  normal, a point or a sphere over the whole aperture); and their rms spread
  across-track, the same on the image with its along- and cross-track axes swapped
  (the receive array's aperture: a cylinder lying along the track answers over it, a
  flat face again only near its normal); the per-ping levels would give the same with
  the ping-to-ping variation;
* the **late-to-specular ratio**: the background-subtracted energy in the tail window
  below the object over that in its peak window (dB), its uncertainty from the spread of
  the same energies in the reference footprints (the background's fluctuation); where
  the late energy is under twice that spread, the value is that upper bound
  (:data:`LATE_UPPER_BOUND`).

The spectrum of the returns (resonance lines and their widths) needs the pings: the
echo windows at the object's range, which the tile does not keep.
:func:`resonance_lines` measures it on any array of echo samples (a multi-snapshot
matrix pencil: each line's frequency, width and amplitude, uncertainties from a
jackknife over the snapshots); :mod:`.contact_spectra` focuses the recorded pings on
each run contact and calls it (``svss process``).

Pure functions of arrays: no files, no configuration loading. ``cfg`` is a
:class:`svss_daq.config.FeaturesConfig` (``[products.features]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: flag bits of ``feature_flags`` (0: every feature measured; -1: not measured)
TAIL_CUT = 1            # the tile's bottom within the tail window or before the extent
NO_TAIL = 2             # the profile falls to the background within the peak window
LATE_UPPER_BOUND = 4    # late energy under twice its uncertainty: an upper bound
NO_REFERENCE = 8        # fewer than 2 reference footprints: background from the layer
SHORT_FIT = 16          # fewer than min_fit_points for the decay
NO_ASPECT = 32          # no complex image, no wavenumber, or the window leaves the tile
FLAG_TEXT = {TAIL_CUT: "tail cut by the tile's bottom", NO_TAIL: "no tail",
             LATE_UPPER_BOUND: "late energy an upper bound",
             NO_REFERENCE: "no reference beside it (background from its layer)",
             SHORT_FIT: "tail too short to fit", NO_ASPECT: "aspect not measured"}

#: detection-table columns of the features: (name, dtype, units, meaning), as
#: :data:`svss_proc.products.detect.FIELDS`
FEATURE_FIELDS = (
    ("tail_extent_m", "f4", "m", ("apparent depth below the peak down to where the tail "
                                  "profile falls to within background_within_db of the "
                                  "local background (NaN: cut by the tile's bottom, or "
                                  "not measured)")),
    ("tail_decay_db_per_m", "f4", "dB/m", ("decay of the tail below the object (least "
                                           "squares on the background-subtracted profile; "
                                           "positive: decaying; NaN: no tail to fit)")),
    ("tail_decay_err_db_per_m", "f4", "dB/m", "standard error of tail_decay_db_per_m"),
    ("late_to_specular_db", "f4", "dB", ("background-subtracted energy in the tail window "
                                         "below the object over that in its peak window "
                                         "(an upper bound where flagged)")),
    ("late_to_specular_err_db", "f4", "dB", ("uncertainty of late_to_specular_db from the "
                                             "local background's fluctuation (NaN for an "
                                             "upper bound)")),
    ("aspect_centre_deg", "f4", "deg", ("power-weighted mean look angle along-track of "
                                        "the contact's response over the aperture (in "
                                        "water; NaN: not measured)")),
    ("aspect_width_deg", "f4", "deg", ("rms spread of that look angle: narrow for a "
                                       "specular face, the aperture's for a point")),
    ("aspect_width_err_deg", "f4", "deg", "standard error of aspect_width_deg (jackknife)"),
    ("aspect_cross_width_deg", "f4", "deg", ("rms spread of the look angle across-track "
                                             "(the cross-track spectrum, as "
                                             "aspect_width_deg along; NaN: not measured)")),
    ("aspect_cross_width_err_deg", "f4", "deg", ("standard error of aspect_cross_width_deg "
                                                 "(jackknife)")),
    ("aspect_point_fraction", "f4", "1", ("the broader of the two look-angle spreads "
                                          "as a fraction of a point scatterer's "
                                          "(point_aspect_deg, along and across): near 1 "
                                          "for a sphere and along a cylinder's axis, well "
                                          "below for a face seen only about its normal "
                                          "both ways; NaN: an aspect not measured")),
    ("aspect_point_fraction_err", "f4", "1", ("standard error of aspect_point_fraction "
                                              "(the broader spread's, over its reference)")),
    ("feature_flags", "i4", "1", ("bits: 1 tail cut by the tile's bottom, 2 no tail, 4 "
                                  "late-to-specular an upper bound, 8 no reference "
                                  "footprint beside it, 16 tail too short to fit, 32 "
                                  "aspect not measured; -1: features not measured")),
)
FEATURE_NAMES = tuple(name for name, *_ in FEATURE_FIELDS)
#: fill values of the feature columns (a tile written before them, or without
#: ``[products.features]``)
FEATURE_FILL = {"tail_extent_m": np.nan, "tail_decay_db_per_m": np.nan,
                "tail_decay_err_db_per_m": np.nan, "late_to_specular_db": np.nan,
                "late_to_specular_err_db": np.nan, "aspect_centre_deg": np.nan,
                "aspect_width_deg": np.nan, "aspect_width_err_deg": np.nan,
                "aspect_cross_width_deg": np.nan, "aspect_cross_width_err_deg": np.nan,
                "aspect_point_fraction": np.nan, "aspect_point_fraction_err": np.nan,
                "feature_flags": -1}
#: levels at or below this (dB re background) are voxels no ping reached (drc.MIN_DB)
_MISSING_DB = -299.0


def flags_text(flags: int) -> str:
    """``feature_flags`` in words ('' for 0; 'not measured' for -1)."""
    if flags < 0:
        return "features not measured"
    return "; ".join(t for bit, t in FLAG_TEXT.items() if flags & bit)


@dataclass(frozen=True)
class TailProfile:
    """One contact's profile below its peak: ``depth_m`` (apparent depth below the peak
    of each voxel layer, from the peak's layer down), ``level_db`` (the footprint's mean
    normalised intensity over the reference footprints', dB: 0 at the background),
    ``intensity`` and ``reference`` (those means, re the median background), ``ref_sd``
    (the reference footprints' spread of their own mean at each depth, same units),
    ``refs`` (reference footprint means, (n_refs, depths)) and ``flags``."""
    depth_m: np.ndarray
    level_db: np.ndarray
    intensity: np.ndarray
    reference: np.ndarray
    refs: np.ndarray
    flags: int


def _box(axis: np.ndarray, centre: float, half: float) -> tuple[int, int]:
    """Voxel index range [lo, hi) of ``axis`` within ``half`` of ``centre`` (at least the
    nearest voxel)."""
    k = int(np.argmin(np.abs(axis - centre)))
    lo = int(np.searchsorted(axis, centre - half - 1e-9, side="left"))
    hi = int(np.searchsorted(axis, centre + half + 1e-9, side="right"))
    return min(lo, k), max(hi, k + 1)


def _power(level: np.ndarray) -> np.ndarray:
    """Normalised intensity 10^(L/10) of a level in dB (NaN where missing)."""
    lv = np.asarray(level, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(lv > _MISSING_DB, 10.0 ** (lv / 10.0), np.nan)


def _box_mean(level: np.ndarray, a: tuple[int, int], c: tuple[int, int], k0: int
              ) -> np.ndarray:
    """Mean normalised intensity of ``level`` (dB; NaN or -300: missing) over along
    ``a`` x cross ``c`` at each depth from ``k0`` down (NaN where the box holds no
    data)."""
    block = _power(level[a[0]:a[1], c[0]:c[1], k0:])
    n = np.sum(np.isfinite(block), axis=(0, 1))
    s = np.nansum(block, axis=(0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def footprint_half(row, cfg) -> tuple[float, float]:
    """Half the along- and cross-track size of a contact's footprint (m): half its extent
    above the threshold, within half of ``footprint_min_m`` and ``footprint_max_m``."""
    ext = (float(row["extent_along_m"]), float(row["extent_cross_m"]))
    return tuple(float(np.clip(0.5 * e, 0.5 * lo, 0.5 * hi)) for e, lo, hi in
                 zip(ext, cfg.footprint_min_m, cfg.footprint_max_m))


def layer_means(level: np.ndarray) -> np.ndarray:
    """The mean normalised intensity of each depth layer of ``level`` (NaN: none)."""
    p = _power(level).reshape(-1, level.shape[2])
    n = np.sum(np.isfinite(p), axis=0)
    return np.where(n > 0, np.nansum(p, axis=0) / np.maximum(n, 1), np.nan)


def tail_profile(level: np.ndarray, axes, row, cfg, others: np.ndarray | None = None,
                 layers: dict | None = None) -> TailProfile:
    """The tail profile of the contact ``row`` (a detection: ``along_m``, ``cross_m``,
    ``depth_m``, extents) in ``level`` (normalised level, dB re background; NaN or
    -300 dB where missing) on ``axes`` (voxel centres, m). Reference footprints: the same footprint
    shifted along-track, ``reference_gap_m`` beyond it and then side by side, up to
    ``reference_boxes`` on each side, inside the tile and clear (by the gap) of every
    contact in ``others`` ((n, 2) along, cross, with their half sizes (n, 2) as columns
    2-3). Fewer than 2: the mean of the depth layer instead (flag
    :data:`NO_REFERENCE`; :func:`layer_means`, kept in ``layers`` under "means" for
    the tile's other contacts)."""
    a, c, z = (np.asarray(x, dtype=np.float64) for x in axes)
    ha, hc = footprint_half(row, cfg)
    pa, pc, pz = float(row["along_m"]), float(row["cross_m"]), float(row["depth_m"])
    k0 = int(np.argmin(np.abs(z - pz)))
    ia, ic = _box(a, pa, ha), _box(c, pc, hc)
    inten = _box_mean(level, ia, ic, k0)
    gap = float(cfg.reference_gap_m)
    step = 2.0 * ha + (a[1] - a[0] if a.size > 1 else 0.0)
    refs = []
    for sign in (-1.0, 1.0):
        for j in range(int(cfg.reference_boxes)):
            ca = pa + sign * (2.0 * ha + gap + j * step)
            if ca - ha < a[0] - 1e-9 or ca + ha > a[-1] + 1e-9:
                break
            if others is not None and len(others) and np.any(
                    (np.abs(others[:, 0] - ca) <= ha + others[:, 2] + gap)
                    & (np.abs(others[:, 1] - pc) <= hc + others[:, 3] + gap)):
                continue
            m = _box_mean(level, _box(a, ca, ha), ic, k0)
            if np.isfinite(m).any():
                refs.append(m)
    flags = 0
    if len(refs) >= 2:
        refs = np.array(refs)
        with np.errstate(invalid="ignore"):
            reference = np.nanmean(refs, axis=0)
    else:
        flags |= NO_REFERENCE
        layers = {} if layers is None else layers
        if "means" not in layers:
            layers["means"] = layer_means(level)
        reference = layers["means"][k0:]
        refs = np.zeros((0, inten.size))
    with np.errstate(invalid="ignore", divide="ignore"):
        level = 10.0 * np.log10(inten / reference)
    return TailProfile(z[k0:] - z[k0], level, inten, reference, refs, flags)


def _fit_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of y on x and its standard error, from the residuals,
    inflated by sqrt((1 + r) / (1 - r)) for their lag-1 correlation r (clipped to
    [0, 0.9]): neighbouring depth voxels share a resolution cell."""
    xm = x - x.mean()
    sxx = float(np.sum(xm * xm))
    slope = float(np.sum(xm * (y - y.mean())) / sxx)
    res = y - y.mean() - slope * xm
    n = x.size
    s2 = float(np.sum(res * res)) / max(n - 2, 1)
    r = float(np.sum(res[1:] * res[:-1]) / np.sum(res * res)) if np.any(res) else 0.0
    r = min(max(r, 0.0), 0.9)
    return slope, math.sqrt(s2 / sxx * (1.0 + r) / (1.0 - r))


@dataclass(frozen=True)
class TailFeatures:
    """The features of one contact (:data:`FEATURE_FIELDS`) and its profile."""
    extent_m: float
    decay_db_per_m: float
    decay_err_db_per_m: float
    late_to_specular_db: float
    late_to_specular_err_db: float
    flags: int
    profile: TailProfile

    def as_row(self) -> dict:
        return {"tail_extent_m": self.extent_m, "tail_decay_db_per_m": self.decay_db_per_m,
                "tail_decay_err_db_per_m": self.decay_err_db_per_m,
                "late_to_specular_db": self.late_to_specular_db,
                "late_to_specular_err_db": self.late_to_specular_err_db,
                "feature_flags": self.flags}


def tail_features(p: TailProfile, cfg) -> TailFeatures:
    """Extent, decay and late-to-specular ratio (module docstring) of a profile."""
    flags = p.flags
    d = p.depth_m
    dz = float(d[1] - d[0]) if d.size > 1 else 0.0
    x = float(cfg.background_within_db)
    run = max(1, int(math.ceil(float(cfg.below_run_m) / dz - 1e-9))) if dz > 0 else 1
    low = ~(p.level_db >= x)                     # NaN (no data) counts as background
    end = None                                   # first layer of the run within X dB
    for k in range(1, d.size - run + 1):
        if low[k:k + run].all():
            end = k
            break
    extent = float("nan") if end is None else float(d[end])
    if end is None:
        flags |= TAIL_CUT
    peak_w, tail_w = float(cfg.peak_window_m), float(cfg.tail_window_m)
    in_peak = d <= peak_w + 1e-9
    in_tail = (d > peak_w + 1e-9) & (d <= peak_w + tail_w + 1e-9)
    if d.size == 0 or d[-1] < peak_w + tail_w - 0.5 * dz:
        flags |= TAIL_CUT                        # the tail window passes the bottom
    with np.errstate(invalid="ignore", divide="ignore"):
        excess = p.intensity / p.reference - 1.0
    # the decay: from the end of the peak window to the extent (or the bottom)
    stop = d.size if end is None else end
    sel = in_tail.copy()
    sel[stop:] = False
    sel &= np.isfinite(excess) & (excess > 0)
    decay = err = float("nan")
    if end is not None and extent <= peak_w + 1e-9:
        flags |= NO_TAIL
    elif sel.sum() < max(int(cfg.min_fit_points), 3):
        flags |= SHORT_FIT
    else:
        slope, se = _fit_slope(d[sel], 10.0 * np.log10(excess[sel]))
        decay, err = -slope, se
    # late-to-specular: background-subtracted energies (re the median background, x dz)
    late = spec = sd_late = sd_spec = float("nan")
    if not flags & TAIL_CUT:
        ref = p.reference
        spec = float(np.nansum((p.intensity - ref)[in_peak])) * dz
        late = float(np.nansum((p.intensity - ref)[in_tail])) * dz
        if p.refs.shape[0] >= 2:
            sd_spec = float(np.std(np.nansum((p.refs - ref)[:, in_peak], axis=1), ddof=1)) * dz
            sd_late = float(np.std(np.nansum((p.refs - ref)[:, in_tail], axis=1), ddof=1)) * dz
    ratio = ratio_err = float("nan")
    if math.isfinite(spec) and spec > 0:
        if math.isfinite(sd_late) and late < 2.0 * sd_late:
            flags |= LATE_UPPER_BOUND
            ratio = 10.0 * math.log10(2.0 * sd_late / spec) if sd_late > 0 else float("nan")
        elif late > 0:
            ratio = 10.0 * math.log10(late / spec)
            if math.isfinite(sd_late):
                ratio_err = 10.0 / math.log(10.0) * math.hypot(sd_late / late, sd_spec / spec)
    return TailFeatures(extent, decay, err, ratio, ratio_err, flags, p)


@dataclass(frozen=True)
class ContactFeatures:
    """The features of a tile's contacts: ``columns`` (name -> (n,) array, the
    :data:`FEATURE_FIELDS`), ``profiles`` ((n, m) tail profiles, dB re background, NaN
    past the tile's bottom) at ``step_m`` from each peak down."""
    columns: dict
    profiles: np.ndarray
    step_m: float


def aspect_spread(image: np.ndarray, axes, row, cfg, wavenumber_rad_m: float,
                  background: np.ndarray | None = None
                  ) -> tuple[float, float, float]:
    """How the contact ``row`` responds over the synthetic aperture, from the complex
    ``image`` alone: its along-track spectrum. A voxel's along-track wavenumber k_x is
    2 k sin(theta), theta the look angle along-track (in water: the interface keeps
    k_x), k = ``wavenumber_rad_m`` (2 pi f_c / c_w). Over ``aspect_window_m`` along
    about the peak (Hann taper), for every column of the footprint (cross) and of the
    peak window (depth, above and below the peak), the power spectrum in k_x is summed
    (less the mean spectrum of the same patch in ``background`` noise columns when
    given: (columns, samples) complex); the look angle's power-weighted mean (deg), its
    rms spread (deg) and that spread's jackknife standard error over the columns.
    NaN where the window leaves the tile or no power remains."""
    a, c, z = (np.asarray(x, dtype=np.float64) for x in axes)
    nan3 = (float("nan"),) * 3
    if a.size < 4 or not np.iscomplexobj(image) or not wavenumber_rad_m > 0:
        return nan3
    dx = float(a[1] - a[0])
    half = int(round(0.5 * float(cfg.aspect_window_m) / dx))
    i0 = int(np.argmin(np.abs(a - float(row["along_m"]))))
    if half < 2 or i0 - half < 0 or i0 + half + 1 > a.size:
        return nan3
    ic = _box(c, float(row["cross_m"]), footprint_half(row, cfg)[1])
    iz = _box(z, float(row["depth_m"]), float(cfg.peak_window_m))
    patch = np.asarray(image[i0 - half:i0 + half + 1, ic[0]:ic[1], iz[0]:iz[1]])
    cols = patch.reshape(patch.shape[0], -1).T                   # (columns, samples)
    taper = np.hanning(cols.shape[1])
    spec = np.abs(np.fft.fft(cols * taper, axis=1)) ** 2
    if background is not None and len(background):
        spec = spec - np.mean(np.abs(np.fft.fft(background * taper, axis=1)) ** 2, axis=0)
    k = 2.0 * np.pi * np.fft.fftfreq(cols.shape[1], dx)
    s = np.clip(k / (2.0 * wavenumber_rad_m), -1.0, 1.0)
    theta = np.degrees(np.arcsin(s))

    def moments(p):
        p = np.clip(p, 0.0, None)
        w = float(p.sum())
        if not w > 0:
            return float("nan"), float("nan")
        m = float(np.sum(p * theta) / w)
        return m, math.sqrt(float(np.sum(p * (theta - m) ** 2) / w))

    centre, width = moments(spec.sum(axis=0))
    n = spec.shape[0]
    err = float("nan")
    if n >= 3 and math.isfinite(width):
        tot = spec.sum(axis=0)
        jack = np.array([moments(tot - spec[j])[1] for j in range(n)])
        err = math.sqrt((n - 1) / n * float(np.nansum((jack - np.nanmean(jack)) ** 2)))
    return centre, width, err


def _aspect_background(image: np.ndarray, axes, row, cfg) -> np.ndarray | None:
    """The columns of :func:`aspect_spread`'s patch shifted along-track by its length
    plus ``reference_gap_m``, on both sides where inside the tile: the background's own
    spectrum (None where neither fits)."""
    a, c, z = (np.asarray(x, dtype=np.float64) for x in axes)
    if a.size < 4 or not np.iscomplexobj(image):
        return None
    dx = float(a[1] - a[0])
    half = int(round(0.5 * float(cfg.aspect_window_m) / dx))
    shift = 2 * half + 1 + int(round(float(cfg.reference_gap_m) / dx))
    i0 = int(np.argmin(np.abs(a - float(row["along_m"]))))
    ic = _box(c, float(row["cross_m"]), footprint_half(row, cfg)[1])
    iz = _box(z, float(row["depth_m"]), float(cfg.peak_window_m))
    out = []
    for i in (i0 - shift, i0 + shift):
        if half >= 2 and i - half >= 0 and i + half + 1 <= a.size:
            p = np.asarray(image[i - half:i + half + 1, ic[0]:ic[1], iz[0]:iz[1]])
            out.append(p.reshape(p.shape[0], -1).T)
    return np.concatenate(out) if out else None


def _swapped(row) -> np.ndarray:
    """A detection row with its along- and cross-track position and extent swapped (the
    across-track aspect is :func:`aspect_spread` on the image with those axes swapped)."""
    out = np.zeros(1, dtype=row.dtype)      # a copy: a table's row is a view into it
    out[0] = row
    for a, b in (("along_m", "cross_m"), ("extent_along_m", "extent_cross_m")):
        out[a], out[b] = row[b], row[a]
    return out[0]


def point_fraction(widths, errors, point_deg) -> tuple[float, float]:
    """(fraction, its standard error): the broader of the look-angle spreads
    ``widths`` (along, across; deg) each over a point scatterer's ``point_deg`` (along,
    across), and that one's error over its reference. A sphere is a point both ways
    (about 1); a cylinder is one along its axis (about 1 whatever its heading, where
    either width alone follows the heading); a flat face returns only about its
    normal, both ways (well below 1). NaN where either width or ``point_deg`` is
    missing."""
    if point_deg is None:
        return float("nan"), float("nan")
    r = [float(w) / float(p) for w, p in zip(widths, point_deg)]
    if not all(math.isfinite(x) for x in r):
        return float("nan"), float("nan")
    j = int(np.argmax(r))
    return r[j], float(errors[j]) / float(point_deg[j])


def contact_features(level: np.ndarray, axes, detections: np.ndarray, cfg,
                     image: np.ndarray | None = None,
                     wavenumber_rad_m: float | None = None) -> ContactFeatures:
    """The features of every contact of ``detections`` (a detection table) in the
    normalised ``level`` (dB re background, along x cross x depth; NaN or -300 dB:
    missing) on ``axes`` (voxel centres, m); with the complex ``image`` and the
    wavenumber of the band's centre in water (rad/m) also the aspect over the aperture
    (:func:`aspect_spread`; else flag :data:`NO_ASPECT`). The stored profiles run
    ``profile_m`` below each peak."""
    z = np.asarray(axes[2], dtype=np.float64)
    step = float(z[1] - z[0]) if z.size > 1 else 0.0
    m = int(round(float(cfg.profile_m) / step)) + 1 if step > 0 else 1
    n = len(detections)
    cols = {name: np.full(n, FEATURE_FILL[name], dtype=dt)
            for name, dt, *_ in FEATURE_FIELDS}
    profiles = np.full((n, m), np.nan, dtype=np.float32)
    if n == 0:
        return ContactFeatures(cols, profiles, step)
    others = np.array([[r["along_m"], r["cross_m"], *footprint_half(r, cfg)]
                       for r in detections], dtype=np.float64)
    layers: dict = {}
    for i, row in enumerate(detections):
        prof = tail_profile(level, axes, row, cfg, np.delete(others, i, axis=0), layers)
        f = tail_features(prof, cfg)
        for k, v in f.as_row().items():
            cols[k][i] = v
        asp = (float("nan"),) * 3
        if image is not None and wavenumber_rad_m:
            asp = aspect_spread(image, axes, row, cfg, wavenumber_rad_m,
                                _aspect_background(image, axes, row, cfg))
        if np.isfinite(asp[1]):
            cols["aspect_centre_deg"][i], cols["aspect_width_deg"][i], \
                cols["aspect_width_err_deg"][i] = asp
        else:
            cols["feature_flags"][i] |= NO_ASPECT
        if image is not None and wavenumber_rad_m:      # across-track: axes swapped
            across = _swapped(row)
            img_t = np.transpose(image, (1, 0, 2))
            axes_t = (axes[1], axes[0], axes[2])
            asp = aspect_spread(img_t, axes_t, across, cfg, wavenumber_rad_m,
                                _aspect_background(img_t, axes_t, across, cfg))
            cols["aspect_cross_width_deg"][i], cols["aspect_cross_width_err_deg"][i] = \
                asp[1], asp[2]
        cols["aspect_point_fraction"][i], cols["aspect_point_fraction_err"][i] = \
            point_fraction((cols["aspect_width_deg"][i], cols["aspect_cross_width_deg"][i]),
                           (cols["aspect_width_err_deg"][i],
                            cols["aspect_cross_width_err_deg"][i]),
                           getattr(cfg, "point_aspect_deg", None))
        k = min(m, prof.level_db.size)
        profiles[i, :k] = prof.level_db[:k]
    return ContactFeatures(cols, profiles, step)


def with_features(detections: np.ndarray, features: ContactFeatures) -> np.ndarray:
    """A copy of ``detections`` with the feature columns set."""
    out = detections.copy()
    for k, v in features.columns.items():
        out[k] = v
    return out


# ----------------------------------------------------------------- resonance lines


@dataclass(frozen=True)
class ResonanceLines:
    """Lines of a ringing response, strongest first: ``frequency_hz``, ``width_hz``
    (full width at half power of each line's Lorentzian: decay rate / pi),
    ``amplitude`` (at the window's first sample), and the jackknife standard errors
    ``frequency_err_hz``, ``width_err_hz`` over the snapshots (NaN with one)."""
    frequency_hz: np.ndarray
    width_hz: np.ndarray
    amplitude: np.ndarray
    frequency_err_hz: np.ndarray
    width_err_hz: np.ndarray


#: the matrix pencil's default length: a third of the window, at most this
MAX_PENCIL = 100


def _gram(x: np.ndarray, pencil: int) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors of H^H H, H the snapshots' Hankel
    matrices (rows: windows of ``pencil + 1`` samples) stacked: the squared singular
    values and right singular vectors of H, at the cost of a (pencil + 1)^2 matrix."""
    hank = np.concatenate([np.lib.stride_tricks.sliding_window_view(s, pencil + 1)
                           for s in x])
    return np.linalg.eigh(hank.conj().T @ hank)


def _pencil(x: np.ndarray, fs: float, order: int, pencil: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matrix pencil of snapshots ``x`` (snapshots, samples; complex): the ``order``
    poles' frequencies (Hz), widths (Hz) and amplitudes (mean magnitude over the
    snapshots)."""
    n = x.shape[1]
    _, vecs = _gram(x, pencil)
    # the signal subspace of the Hankel matrices' rows (conjugated right singular
    # vectors): (L + 1, order)
    v = np.conj(vecs[:, ::-1][:, :order])
    v1, v2 = v[:-1], v[1:]
    poles = np.linalg.eigvals(np.linalg.pinv(v1) @ v2)
    poles = poles[np.abs(poles) > 1e-12]
    freq = np.angle(poles) * fs / (2.0 * np.pi)
    width = -np.log(np.abs(poles)) * fs / np.pi
    vander = poles[None, :] ** np.arange(n)[:, None]
    amps = np.linalg.lstsq(vander, x.T, rcond=None)[0]      # (order, snapshots)
    return freq, width, np.mean(np.abs(amps), axis=1)


def resonance_lines(echoes: np.ndarray, fs: float, max_lines: int = 4,
                    rel_threshold: float = 1e-2, f_offset_hz: float = 0.0,
                    pencil: int | None = None) -> ResonanceLines:
    """The resonance lines of ringing echoes: ``echoes`` (snapshots x samples, or one
    window of samples), each a window of the response at the object's range after its
    specular echo (e.g. per ping: the matched-filtered samples from the end of the
    specular to the end of the ringing), sampled at ``fs`` (Hz); complex baseband
    (frequencies then re its centre: ``f_offset_hz`` added) or real (each line then
    appears at +f and -f: the positive one is kept). A multi-snapshot matrix pencil:
    the snapshots' Hankel matrices (windows of ``pencil`` + 1 samples; default a third
    of the window, at most :data:`MAX_PENCIL`) stacked, the signal subspace of the
    singular values
    above ``rel_threshold`` of the largest (at most ``2 max_lines``), its poles
    z = exp((-pi w + 2 pi i f) / fs) give each line's frequency f and width w (full
    width at half power); lines are sorted by amplitude. The uncertainty of f and w is a
    jackknife over the snapshots (each left out in turn)."""
    x = np.atleast_2d(np.asarray(echoes))
    real = not np.iscomplexobj(x)
    x = x.astype(np.complex128)
    n = x.shape[1]
    L = int(pencil) if pencil else max(2, min(n // 3, MAX_PENCIL))
    sv = np.sqrt(np.maximum(_gram(x, L)[0][::-1], 0.0))
    cap = 2 * max_lines if real else max_lines
    order = int(min(cap, np.sum(sv > rel_threshold * sv[0]))) if sv.size and sv[0] > 0 else 0
    empty = np.zeros(0)
    if order == 0:
        return ResonanceLines(empty, empty, empty, empty, empty)

    def lines(xs):
        f, w, a = _pencil(xs, fs, order, L)
        keep = (f > 0) if real else np.ones(f.size, dtype=bool)
        f, w, a = f[keep], w[keep], a[keep]
        o = np.argsort(-a)[:max_lines]
        return f[o] + f_offset_hz, w[o], a[o]

    f, w, a = lines(x)
    fe = we = np.full(f.size, np.nan)
    s = x.shape[0]
    if s >= 3:
        jf, jw = [], []
        for i in range(s):
            fi, wi, _ = lines(np.delete(x, i, axis=0))
            # each line of the whole matched to the nearest of the leave-one-out set
            idx = [int(np.argmin(np.abs(fi - ff))) if fi.size else -1 for ff in f]
            jf.append([fi[j] if j >= 0 else np.nan for j in idx])
            jw.append([wi[j] if j >= 0 else np.nan for j in idx])
        jf, jw = np.array(jf), np.array(jw)
        fe = np.sqrt((s - 1) / s * np.nansum((jf - np.nanmean(jf, 0)) ** 2, axis=0))
        we = np.sqrt((s - 1) / s * np.nansum((jw - np.nanmean(jw, 0)) ** 2, axis=0))
    return ResonanceLines(f, w, a, fe, we)
