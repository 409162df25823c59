"""Image products of a finished tile, and writing its files (HDF5 tile + PNG quicklook).

:func:`compute_products` runs the chain of docs/products.md on a tile's magnitude:
background (3-D median), normalisation, level in dB, display gain, dynamic range
compression, maximum intensity projections and detections.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from svss_daq.config import (HardwareConfig, ImagingConfig, Loaded, ProcessingConfig,
                             ProductsConfig)

from svss_daq.decibels import amplitude_to_db

from . import drc as drc_mod
from .background import greater_of_below, kernel_voxels, median_background
from .circumstances import circumstances_text, tile_counts
from .classify import with_class
from .contact_features import contact_features, with_features
from .detect import Footprint, detect, sidelobe_zone
from .layer_cfar import guarded_along, guarded_regions, layer_tails
from ..imaging.coverage import aperture_fraction, full_fraction
from .quicklook import mip_png, products_png
from .tile_products import Products
from ..tiles import (MIPS, Tile, TileFileError, temporary_path, tile_file_paths, tile_name,
                     write_tile)

log = logging.getLogger(__name__)

def _planes(planes, mag: np.ndarray, channels: np.ndarray | None, whiten: bool):
    """A neighbour's planes (magnitude, ping-channel pairs) when they fit this tile
    (same cross-track and depth axes; channels known where whitening needs them)."""
    if planes is None or planes[0].shape[1:] != mag.shape[1:] or not planes[0].shape[0]:
        return None
    m, c = planes
    if channels is not None and whiten and (c is None or c.shape != m.shape):
        return None
    return np.asarray(m, dtype=np.float32), c


def coverage_settings(cfg: ProductsConfig) -> tuple[bool, float, bool]:
    """(coverage_whitening, min_coverage_fraction, sidelobe_footprint) of ``cfg`` (the
    loader fills them where the file omits them)."""
    b, d = cfg.background, cfg.detection
    return b.coverage_whitening, d.min_coverage_fraction, d.sidelobe_footprint


def whitened_background(mag: np.ndarray, channels: np.ndarray | None, kernel, bcfg
                        ) -> np.ndarray:
    """The 3-D median background of ``mag``; with ``channels`` (ping-channel pairs per
    voxel) the median of ``mag / sqrt(channels)`` times ``sqrt(channels)``: noise summed
    over N independent channel samples grows as sqrt(N), so the background follows the
    coverage instead of being smeared across its edges by the kernel. Voxels no channel
    reached have background 0."""
    if channels is None:
        return median_background(mag, kernel, bcfg.method, bcfg.histogram_bin_db,
                                 bcfg.boundary, bcfg.ignore_zeros)
    w = np.sqrt(channels.astype(np.float32))
    with np.errstate(divide="ignore", invalid="ignore"):
        white = np.where(w > 0, mag / w, 0.0).astype(np.float32)
    bg = median_background(white, kernel, bcfg.method, bcfg.histogram_bin_db,
                           bcfg.boundary, bcfg.ignore_zeros)
    return (bg * w).astype(np.float32)


@dataclass(frozen=True)
class Before:
    """What a tile's products take from the tile before it on the same line (the
    previous along-track tile, finished first): its last along-track voxel planes
    (``magnitude``, ``channels``: ping-channel pairs, or None), enough for every
    background window of the tile's first planes to reach across the seam as it would
    in one seamless volume, and its contacts (``positions`` (n, 3) along, cross, depth,
    m, in the shared tile frame; ``peak_db``), stronger sources whose sidelobes reach
    into this tile (docs/products.md, *Seams*)."""
    index: int
    line: object
    magnitude: np.ndarray
    channels: np.ndarray | None
    positions: np.ndarray
    peak_db: np.ndarray


def _shown(level: np.ndarray, mag: np.ndarray, axes, sources: np.ndarray,
           before: "Before | None", dc, footprint: Footprint | None,
           layer_threshold_db: np.ndarray | None = None,
           detectable: np.ndarray | None = None) -> np.ndarray:
    """The level the display products show. A layer whose threshold was raised over
    ``threshold_db`` by its own clutter (``layer_threshold_db``, :mod:`.layer_cfar`) is
    shown lowered by as much: a voxel is shown over the threshold exactly where it
    could detect, and a bright layer's clutter (the seed's sand line: 28 dB in the MIPs,
    8 dB over its cylinder) no brighter than the threshold. A voxel that the detection
    would call an imaging sidelobe of a contact (this tile's, its neighbours' planes',
    the previous tile's: :func:`~.detect.sidelobe_zone`) is shown at most at the
    threshold: a strong target's sidelobes end sharply where no ping's footprint holds
    both it and them; there the median background falls to the noise and the edge stood
    up to 70 dB over it in the demo, brighter than any target, though the detection
    drops it. A voxel that may not detect (``detectable`` false: imaged by too few
    pings, or its aperture cut by the run's end) is shown as partial: at most at the
    threshold too (the seed's sand line past its last ping: 28 dB)."""
    if detectable is not None and not detectable.all():
        level = np.where(detectable, level, np.minimum(level, dc.threshold_db))
    if layer_threshold_db is not None:
        raised = np.maximum(np.asarray(layer_threshold_db) - dc.threshold_db, 0.0)
        if np.any(raised):
            level = level - raised[None, None, :].astype(level.dtype)
    pos = np.stack([sources["along_m"], sources["cross_m"], sources["depth_m"]], -1)
    peak = np.asarray(sources["peak_db"], dtype=np.float64)
    if before is not None and before.positions.size:
        pos = np.concatenate([pos, np.asarray(before.positions).reshape(-1, 3)])
        peak = np.concatenate([peak, np.asarray(before.peak_db, dtype=np.float64)])
    if not peak.size or not np.isfinite(dc.sidelobe_db):
        return level
    with np.errstate(divide="ignore"):
        mag_db = amplitude_to_db(np.maximum(mag, 1e-30))
    zone = sidelobe_zone(mag_db, axes, pos, peak, dc.sidelobe_db, dc.sidelobe_m, footprint)
    return np.where(zone, np.minimum(level, dc.threshold_db), level)


def compute_products(image: np.ndarray, axes: tuple[np.ndarray, np.ndarray, np.ndarray],
                     voxel_m: float, cfg: ProductsConfig, keep_volumes: bool = True,
                     coverage: tuple[np.ndarray, np.ndarray] | None = None,
                     footprint: Footprint | None = None,
                     aperture: np.ndarray | None = None,
                     before: Before | None = None,
                     after: tuple[np.ndarray, np.ndarray | None] | None = None,
                     wavenumber_rad_m: float | None = None) -> Products:
    """Products of one tile. ``image``: complex image or magnitude (along x cross x
    depth, uPa); ``axes``: voxel-centre coordinates (m); ``voxel_m``: voxel edge (m).
    ``keep_volumes``: return the background and compressed volumes (else None).
    ``coverage``: (pings, ping-channel pairs) per voxel (None: unknown; every voxel
    counts as fully imaged); ``footprint``: the sidelobe geometry (None: the
    ``sidelobe_m`` radius only); ``aperture``: the fraction of each voxel's synthetic
    aperture traversed (along x depth, :func:`~svss_proc.imaging.coverage.aperture_fraction`;
    None: unknown), voxels below ``min_coverage_fraction`` do not detect; ``before``:
    the previous tile's last planes and contacts (:class:`Before`; None: none known);
    ``after``: the next tile's first planes (magnitude, ping-channel pairs; None: not
    known); ``wavenumber_rad_m``: 2 pi f_c / c_w of the pings, for the contacts' aspect
    over the aperture (None: not measured; docs/contact_features.md)."""
    t = {}
    t0 = time.perf_counter()
    mag = np.abs(image).astype(np.float32, copy=False)
    bcfg = cfg.background
    whiten, min_fraction, use_footprint = coverage_settings(cfg)
    kernel = kernel_voxels(bcfg.kernel_m, voxel_m)
    pings, channels = coverage if coverage is not None else (None, None)
    # the neighbours' planes across the seams: every background window of this tile's
    # planes reaches across a seam as in one seamless volume (exact for kernel // 2
    # planes), and contacts peaking there are context (sources of sidelobes), never this
    # tile's
    lo_planes = _planes(before and (before.magnitude, before.channels), mag, channels, whiten)
    hi_planes = _planes(after, mag, channels, whiten)
    nb = 0 if lo_planes is None else lo_planes[0].shape[0]
    na = 0 if hi_planes is None else hi_planes[0].shape[0]
    mag_x = np.concatenate([p[0] for p in (lo_planes, (mag, channels), hi_planes)
                            if p is not None]) if nb or na else mag
    ch_x = None
    if channels is not None and whiten:
        ch_x = np.concatenate([p[1] for p in (lo_planes, (mag, channels), hi_planes)
                               if p is not None]) if nb or na else channels
    bg_x = greater_of_below(whitened_background(mag_x, ch_x, kernel, bcfg), axes[2],
                            kernel[2], bcfg.below_edge_from_m)
    core = slice(nb, nb + mag.shape[0])
    bg = bg_x[core]
    t1 = time.perf_counter()
    t["background"] = t1 - t0
    floor = drc_mod.background_floor(bg, bcfg.floor_db)
    # with the neighbours' planes divided by the same floor as this tile's (the tile's
    # own level is the core of it: normalise divides by that floor too)
    level_x = drc_mod.level_db(drc_mod.normalise(mag_x, bg_x, bcfg.floor_db, floor=floor))
    level = level_x[core]
    t2 = time.perf_counter()
    t["normalisation"] = t2 - t1
    t3 = t2
    dc = cfg.detection
    fraction = None if pings is None else full_fraction(pings)
    detectable = None if fraction is None else fraction >= min_fraction
    if aperture is not None:
        # a partly imaged edge (the run starts or ends within the voxel's aperture)
        # never detects, whatever the tile's own most-covered voxels got
        part = np.asarray(aperture)[:, None, :] >= min_fraction
        detectable = part if detectable is None else detectable & part
    axes_x, pings_x, fraction_x, detectable_x = axes, pings, fraction, detectable
    if nb or na:
        v = float(voxel_m)
        axes_x = (np.concatenate([axes[0][0] - v * np.arange(nb, 0, -1), axes[0],
                                  axes[0][-1] + v * np.arange(1, na + 1)]), axes[1], axes[2])

        def pad(x, fill):
            if x is None:
                return None
            out = np.full((nb + x.shape[0] + na,) + x.shape[1:], fill, dtype=x.dtype)
            out[core] = x
            return out
        pings_x, fraction_x = pad(pings, 0), pad(fraction, -1.0)
        detectable_x = pad(detectable if detectable is not None
                           else np.ones(mag.shape, dtype=bool), True)
    tails = None
    threshold = dc.threshold_db
    if dc.layer_false_alarms_per_m3 is not None:
        # each depth layer's threshold from its own clutter (this tile's voxels that
        # may detect): a constant false-alarm rate per volume
        # (strong responses' sidelobes are not clutter: the stretch a projector
        # footprint reaches about them is left out of the fits)
        depth_max = float(np.max(axes[2])) if axes[2].size else 0.0
        reach = (footprint.reach_m(depth_max, depth_max) if footprint is not None
                 else dc.sidelobe_m)
        guard = guarded_along(level, detectable, dc.threshold_db, reach, float(voxel_m))
        tails = layer_tails(level, detectable, dc.layer_false_alarms_per_m3
                            * float(voxel_m) ** 3, dc.threshold_db, float(voxel_m), guard,
                            guarded_regions(level, detectable, dc.threshold_db,
                                            float(voxel_m)))
        threshold = tails.threshold_db
    table = detect(level_x, mag_x, bg_x, axes_x, threshold, dc.min_voxels,
                   dc.merge_m, 1 << 30, dc.sidelobe_db, dc.sidelobe_m,
                   detectable=detectable_x,
                   context=None if before is None or not before.positions.size
                   else (before.positions, before.peak_db),
                   coverage_pings=pings_x, coverage_fraction=fraction_x,
                   footprint=footprint if use_footprint else None,
                   point_threshold_db=dc.point_threshold_db,
                   extended_min_m3=dc.extended_min_m3, tails=tails,
                   later_echo_m=dc.later_echo_m)
    sources = table             # with those peaking in the neighbours' planes
    if nb or na:        # contacts peaking in a neighbour's planes are that tile's
        half = 0.5 * float(voxel_m)
        table = table[(table["along_m"] >= axes[0][0] - half)
                      & (table["along_m"] < axes[0][-1] + half)]
    table = table[:dc.max_per_tile]
    t4 = time.perf_counter()
    t["detection"] = t4 - t3
    profiles, step = None, float("nan")
    fcfg = cfg.features
    if fcfg is not None and fcfg.enabled:     # each contact's tail below it
        feats = contact_features(level, axes, table, fcfg, image, wavenumber_rad_m)
        table, profiles, step = with_features(table, feats), feats.profiles, feats.step_m
        t5 = time.perf_counter()
        t["features"], t4 = t5 - t4, t5
        ccfg = cfg.classify
        if ccfg is not None and ccfg.enabled:     # man-made, natural or undecided
            table = with_class(table, ccfg)
    g = cfg.depth_gain
    gain = drc_mod.depth_gain_db(axes[2], g.db_per_m, g.start_m).astype(np.float32)
    display = _shown(level, mag, axes, sources, before, dc,
                     footprint if use_footprint else None,
                     None if tails is None else tails.threshold_db, detectable)
    display = display + gain[None, None, :] if np.any(gain) else display
    d = cfg.drc
    comp = drc_mod.compress(display, d.floor_db, d.knee_db, d.ceiling_db) if keep_volumes \
        else None
    # MIPs commute with the monotone compression: compress(mip) == mip(compress)
    mips = {name: np.fmax.reduce(display, axis=axis) for name, (axis, _) in MIPS.items()}
    t["compression_and_mips"] = time.perf_counter() - t4
    return Products(
        method=bcfg.method, kernel_m=tuple(bcfg.kernel_m), kernel_voxels=kernel,
        boundary=bcfg.boundary, ignore_zeros=bcfg.ignore_zeros,
        max_error_db=0.0 if bcfg.method == "exact" else bcfg.histogram_bin_db / 2,
        floor_upa=floor, background=bg if keep_volumes else None, level=level,
        gain_db=gain, drc=comp, mips=mips, detections=table,
        drc_attrs={"floor_db": d.floor_db, "knee_db": d.knee_db,
                   "ceiling_db": d.ceiling_db, "depth_gain_db_per_m": g.db_per_m,
                   "depth_gain_start_m": g.start_m},
        tail_profiles=profiles, tail_profile_step_m=step,
        detection_attrs={"threshold_db": dc.threshold_db, "min_voxels": dc.min_voxels,
                         "layer_false_alarms_per_m3": (np.nan if dc.layer_false_alarms_per_m3
                                                       is None
                                                       else dc.layer_false_alarms_per_m3),
                         "layer_threshold_db": (np.full(0, np.nan) if tails is None
                                                else tails.threshold_db),
                         "merge_m": np.asarray(dc.merge_m),
                         "sidelobe_db": dc.sidelobe_db, "sidelobe_m": dc.sidelobe_m,
                         "max_per_tile": dc.max_per_tile,
                         "min_coverage_fraction": min_fraction,
                         "point_threshold_db": (dc.threshold_db if dc.point_threshold_db
                                                is None else dc.point_threshold_db),
                         "extended_min_m3": (np.nan if dc.extended_min_m3 is None
                                             else dc.extended_min_m3),
                         "coverage_used": pings is not None,
                         "aperture_rule": aperture is not None,
                         "seam_planes_before": nb, "seam_planes_after": na,
                         "seam_context_contacts": (0 if before is None
                                                   else int(before.peak_db.size)),
                         "coverage_whitening": bool(whiten and channels is not None),
                         "sidelobe_footprint_height_m": (
                             np.nan if footprint is None or not use_footprint
                             else footprint.height_m),
                         "sidelobe_footprint_tan": (
                             np.nan if footprint is None or not use_footprint
                             else footprint.tan_half_angle)},
        timings=t)


def tile_title(name: str, tile: Tile) -> str:
    """One line naming a tile: index, along-track span, pings and what happened among
    them (:func:`~svss_proc.products.circumstances.tile_counts`: missing pings,
    dead-reckoned and held poses; nothing when none did)."""
    g = tile.grid
    pings = (f"pings {min(tile.pings)}-{max(tile.pings)} ({len(tile.pings)})"
             if tile.pings else "no pings")
    flags = ([row[3] for row in tile.track] if tile.track and len(tile.track)
             == len(tile.pings) and all(len(row) > 3 for row in tile.track) else None)
    said = circumstances_text(tile_counts(tile.pings, flags))
    return (f"SVSS {name}: along-track {g.along[0]:.2f}-{g.along[-1]:.2f} m, {pings}"
            + (f"; {said}" if said else ""))


def footprint_for(height_m: float, hardware: HardwareConfig,
                  imaging: ImagingConfig) -> Footprint:
    """The sidelobe geometry (:class:`~svss_proc.products.detect.Footprint`) of pings
    ``height_m`` above the interface: the projector's half-angle, the sediment's
    water-equivalent range scale c_w / c_sed of the imaging configuration and half the
    transmitted pulse's length (at c_w) as the range slack."""
    half = math.radians(hardware.beams.projector_half_angle_deg)
    c_w = imaging.water_sound_speed_m_s
    return Footprint(height_m, math.tan(half), c_w / imaging.sediment_sound_speed_m_s,
                     0.5 * c_w * hardware.waveform.duration_s)


def tile_footprint(tile: Tile, hardware: Loaded[HardwareConfig],
                   imaging: ImagingConfig) -> Footprint | None:
    """The sidelobe geometry of a tile: its pings' mean projector height
    (:func:`footprint_for`; None without coverage or pings)."""
    cov = tile.coverage
    if cov is None or not np.isfinite(cov.mean_height_m):
        return None
    return footprint_for(cov.mean_height_m, hardware.value, imaging)


class Seams:
    """What a run's tiles pass on along the line, for products without seams: the last
    tile saved, as the :class:`Before` of the next one (its index one higher, on the
    same line). The streaming worker keeps one per run; a batch task saving a tile sets
    ``last`` to the previous tile's (:mod:`svss_proc.batch.task`)."""

    def __init__(self) -> None:
        self.last: Before | None = None

    def before_for(self, tile: Tile) -> Before | None:
        b = self.last
        if b is None or b.index != tile.grid.index - 1 or b.line != tile.line:
            return None
        return b

    def remember(self, tile: Tile, prods: Products | None, planes: int) -> None:
        if prods is None or planes < 1:
            self.last = None
            return
        cov = tile.coverage
        d = prods.detections
        self.last = Before(
            tile.grid.index, tile.line,
            np.abs(tile.image[-planes:]).astype(np.float32),
            None if cov is None else cov.channels[-planes:].copy(),
            np.stack([d["along_m"], d["cross_m"], d["depth_m"]], axis=1).astype(np.float64),
            np.asarray(d["peak_db"], dtype=np.float64))


def tile_aperture(tile: Tile, footprint: Footprint | None) -> np.ndarray | None:
    """The fraction of each voxel's synthetic aperture the tile's pings traversed (along
    x depth; :func:`~svss_proc.imaging.coverage.aperture_fraction`), None without
    coverage or footprint."""
    cov = tile.coverage
    if cov is None or footprint is None or not np.isfinite(cov.tx_along_min_m):
        return None
    return aperture_fraction(tile.grid.along, tile.grid.depth,
                             (cov.tx_along_min_m, cov.tx_along_max_m), footprint.height_m,
                             footprint.tan_half_angle)


def save_quicklook(tile: Tile, out_dir: str | Path) -> Path:
    """The quick look of a tile whose full products wait (a worker behind the sonar,
    docs/worker.md): ``tile_NNNN_mip.png``, the maximum intensity projections of the
    image's magnitude (dB re the tile's peak), written under a temporary name and renamed
    into place. No tile file: :func:`save_tile` writes it, and the full quick look, later
    (a PNG without its .h5 belongs to a tile not yet committed)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png = tile_file_paths(out, tile.grid.index)[1]
    tmp = temporary_path(png)
    try:
        mip_png(tmp, tile.image, tile.grid,
                tile_title(tile_name(tile.grid.index), tile) + " (quick look: full "
                "products to follow)")
        os.replace(tmp, png)
    except OSError as exc:
        raise TileFileError(f"{png}: writing the quick look failed "
                            f"({exc.strerror or exc})") from None
    finally:
        tmp.unlink(missing_ok=True)
    log.info("wrote the quick look %s (%d pings; full products to follow)", png,
             len(tile.pings))
    return png


def save_tile(tile: Tile, out_dir: str | Path, hardware: Loaded[HardwareConfig],
              processing: Loaded[ProcessingConfig], seams: Seams | None = None,
              clock=None) -> list[Path]:
    """Compute the products (when the processing configuration has a ``[products]``
    table) and write ``tile_NNNN.h5`` and ``tile_NNNN_mip.png`` into ``out_dir``;
    return the paths. Both are written under temporary names and renamed into place
    only when both are complete, the .h5 last (the commit point); on failure no final
    .h5 is created and
    :class:`~svss_proc.tiles.TileFileError` names the file. ``seams``: the run's
    :class:`Seams` (the previous tile's last planes and contacts; this tile's are
    remembered for the next). ``clock``: a :class:`~svss_proc.live_clock.StageClock`
    that gets the products' parts (``products.chain``: the chain in all, CPU and wall;
    ``products.background`` etc.: its steps, wall time; ``products.quicklook_png`` and
    ``products.tile_file``, CPU and wall)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = tile_name(tile.grid.index)
    pcfg = processing.value.products
    voxel = processing.value.tile.voxel_m
    title = tile_title(name, tile)
    ident = (f"line origin N {tile.line.origin_ne[0]:.2f} E {tile.line.origin_ne[1]:.2f} m,"
             f" heading {np.degrees(tile.line.heading):.1f} deg\nconfigs: hardware "
             f"{hardware.id}, processing {processing.id}")
    h5, png = tile_file_paths(out, tile.grid.index)
    g = tile.grid
    prods = None
    if pcfg is not None:
        c_chain, w_chain = time.process_time(), time.perf_counter()
        cov = tile.coverage
        fp = tile_footprint(tile, hardware, processing.value.imaging)
        prods = compute_products(tile.image, (g.along, g.cross, g.depth), voxel, pcfg,
                                 keep_volumes=pcfg.store_volumes,
                                 coverage=None if cov is None else (cov.pings, cov.channels),
                                 footprint=fp, aperture=tile_aperture(tile, fp),
                                 before=(seams.before_for(tile) if seams is not None
                                         and pcfg.background.across_seams else None),
                                 after=tile.after if pcfg.background.across_seams else None,
                                 wavenumber_rad_m=2.0 * math.pi
                                 * hardware.value.waveform.center_hz
                                 / processing.value.imaging.water_sound_speed_m_s)
        if clock is not None:       # the chain's CPU in all, its steps' wall times
            clock.add("products.chain", time.process_time() - c_chain,
                      time.perf_counter() - w_chain)
            for k, v in prods.timings.items():
                clock.add(f"products.{k}", float("nan"), v)
    if seams is not None:
        seams.remember(tile, prods, 0 if pcfg is None
                       else kernel_voxels(pcfg.background.kernel_m, voxel)[0] // 2)
    tmp_png = temporary_path(png)
    c0, w0 = time.process_time(), time.perf_counter()
    try:
        try:
            if prods is None:
                mip_png(tmp_png, tile.image, tile.grid, title)
            else:
                products_png(tmp_png, prods.mips, prods.level, prods.gain_db,
                             prods.detections, g, voxel, pcfg, title, ident,
                             coverage=None if tile.coverage is None else tile.coverage.pings,
                             profiles=prods.tail_profiles,
                             profile_step_m=prods.tail_profile_step_m)
        except OSError as exc:
            raise TileFileError(f"{png}: writing the quicklook failed "
                                f"({exc.strerror or exc}); no file written") from None
        # the tile's .h5 rename is the commit point: the quicklook goes into place
        # first, so a tile_NNNN.h5 always has its PNG, and a PNG without its .h5 (a crash
        # in between) belongs to a tile that is redone (docs/worker.md)
        os.replace(tmp_png, png)
        c1, w1 = time.process_time(), time.perf_counter()
        try:
            write_tile(h5, tile, hardware, processing, prods)
        except BaseException:
            png.unlink(missing_ok=True)
            raise
        if clock is not None:
            clock.add("products.quicklook_png", c1 - c0, w1 - w0)
            clock.add("products.tile_file", time.process_time() - c1,
                      time.perf_counter() - w1)
    finally:
        tmp_png.unlink(missing_ok=True)
    if prods is None:
        log.info("wrote %s (%d pings, no products) and %s", h5, len(tile.pings), png.name)
    else:
        log.info("wrote %s (%d pings, %d detections; background %s %dx%dx%d in %.2f s) "
                 "and %s", h5, len(tile.pings), len(prods.detections), prods.method,
                 *prods.kernel_voxels, prods.timings["background"], png.name)
    return [h5, png]
