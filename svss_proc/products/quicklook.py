"""PNG quicklooks of a tile, axes in metres.

:func:`products_png`: the three maximum intensity projections (top, side and end views)
and depth slices of the background-normalised, compressed volume, with the detections
marked, a colour bar in dB re background and the tile's identity.
:func:`mip_png`: the three projections of ``|image|`` in dB re the tile's peak, for tiles
processed without products.

Both are drawn by :mod:`svss_proc.products.raster` straight into pixels, not by
matplotlib (which took ten times as long, see there); matplotlib provides the colour
maps and the fonts. The run's mosaic (:mod:`.run_products`) is drawn the same way.
"""

from __future__ import annotations

import functools
import logging
import math
from pathlib import Path

import numpy as np
from matplotlib import colormaps

from svss_daq.config import ProductsConfig
from svss_daq.decibels import amplitude_to_db_floored

from .classify import NOT_CLASSIFIED, class_text
from .contact_features import LATE_UPPER_BOUND
from .drc import compress
from .raster import Canvas, View, rgb8, save_rgb_palette_png
from ..imaging.grid import TileGrid

log = logging.getLogger(__name__)

CMAP = "magma"
#: the colour map of the quick looks without products (dB re the tile's peak)
MIP_CMAP = "viridis"


def _edges(axis: np.ndarray, voxel_m: float) -> tuple[float, float]:
    half = voxel_m / 2 if np.isfinite(voxel_m) else 0.0
    return float(axis[0] - half), float(axis[-1] + half)


#: colour of voxels no ping imaged (RGBA): distinct from every colour of the map
NO_DATA_RGBA = (0.62, 0.66, 0.70, 1.0)
#: panel heights, inches: a 2 m axis of a 15 m tile gets at least MIN_PANEL_IN
MIN_PANEL_IN, MAX_PANEL_IN = 2.4, 3.0
#: figure width, inches: about one inch per metre of tile, within these bounds
MIN_WIDTH_IN, MAX_WIDTH_IN = 7.0, 16.0
#: the products quick look's fixed layout, inches: margins left (the y axis's label and
#: tick labels) and right, the title block on top, above each view its title, below it
#: its x axis (tick labels and label), the bottom row's height, and the colour bar's gap
#: from the end view, width and room for its tick labels and label
LEFT_IN, RIGHT_IN, SUPTITLE_IN = 0.9, 0.3, 0.55
TITLE_IN, XLABEL_IN, BOTTOM_VIEW_IN = 0.25, 0.45, 3.0
COLORBAR_GAP_IN, COLORBAR_W_IN, COLORBAR_LABELS_IN = 0.6, 0.25, 1.9
#: zlib level of the PNGs: 3 wrote a default tile's quick look in a sixth of the time of
#: PIL's ``optimize`` (level 9) for 4 % more bytes (issue 32)
PNG_COMPRESS_LEVEL = 3
#: the contacts' circles: diameter (points; matplotlib's scatter of 60 square points) and
#: colour, also their numbers'
MARKER_PT, MARKER_RGB = 60 ** 0.5, (0.0, 1.0, 1.0)
DEPTH_LABEL = "depth below seabed (m)"
CROSS_LABEL = "cross-track (m), starboard +"


def view_rgba(display: np.ndarray, imaged: np.ndarray | None, floor_db: float,
              knee_db: float, ceiling_db: float) -> np.ndarray:
    """RGBA image (x index first, like ``display``) of a view in dB: compressed
    (:func:`~svss_proc.products.drc.compress`) through the colour map, and
    :data:`NO_DATA_RGBA` where ``imaged`` is False (no ping reached the voxels) or the
    value is NaN; low signal stays at the dark end of the map."""
    u = compress(display, floor_db, knee_db, ceiling_db)
    rgba = colormaps[CMAP](np.nan_to_num(u, nan=0.0))
    missing = np.isnan(display) if imaged is None else (~imaged | np.isnan(display))
    rgba[missing] = NO_DATA_RGBA
    return rgba


def choose_labels(xy_px: np.ndarray, max_labels: int, min_sep_px: float = 16.0) -> list[int]:
    """Which contacts (rows of ``xy_px``: display positions, strongest first) get a
    number on a view: strongest first, at most ``max_labels``, none closer than
    ``min_sep_px`` to a label already placed (the others are listed, not labelled)."""
    chosen: list[int] = []
    for i, p in enumerate(np.asarray(xy_px, dtype=np.float64).reshape(-1, 2)):
        if len(chosen) >= max_labels:
            break
        if all(np.hypot(*(p - xy_px[j])) >= min_sep_px for j in chosen):
            chosen.append(i)
    return chosen


def _panel_height(extent_m: float, along_m: float, width_in: float) -> tuple[float, float]:
    """Height (in) of a full-width panel showing ``extent_m`` against ``along_m`` and
    its vertical exaggeration (1: equal scales)."""
    natural = extent_m * width_in / along_m
    h = min(max(natural, MIN_PANEL_IN), MAX_PANEL_IN)
    return h, h / natural


def _draw(canvas: Canvas, box, rgba, xe, ye, xlabel, ylabel, title, depth_down) -> View:
    """A view: the image with its axes in metres, their labels and its title."""
    v = canvas.view(box, rgba, xe, ye, depth_down)
    canvas.x_axis(v, xlabel)
    canvas.y_axis(v, ylabel)
    canvas.title(v, title)
    return v


def _sides(canvas: Canvas, v: View, horizontal: bool) -> None:
    """Mark port and starboard on a view whose cross-track axis is vertical (top view,
    depth slices; starboard up) or horizontal (end view; starboard right)."""
    if horizontal:
        canvas.label_box(v.at(0.99, 0.02), "STBD \u2192", 7, "rd")
        canvas.label_box(v.at(0.01, 0.02), "\u2190 PORT", 7, "ld")
    else:
        canvas.label_box(v.at(0.005, 0.97), "STBD", 7, "la")
        canvas.label_box(v.at(0.005, 0.03), "PORT", 7, "ld")


def products_png(path: str | Path, mips: dict[str, np.ndarray], level: np.ndarray,
                 gain_db: np.ndarray, detections: np.ndarray, grid: TileGrid,
                 voxel_m: float, cfg: ProductsConfig, title: str, identity: str,
                 coverage: np.ndarray | None = None,
                 profiles: np.ndarray | None = None, profile_step_m: float = float("nan")
                 ) -> Path:
    """Quicklook of a tile's products.

    Full-width views stacked (top view, side view, depth slices at
    ``cfg.quicklook.depth_slices_m``), each at least :data:`MIN_PANEL_IN` high (the
    vertical exaggeration is given in its title when the scales differ), then the end
    view, the colour bar and the contact list. ``mips``: the projections of level +
    gain (dB re background, keys of :data:`svss_proc.tiles.MIPS`); ``level``:
    normalised level (dB re background, along x cross x depth) and ``gain_db`` the
    display gain per depth; ``detections``: contacts, strongest first: the strongest
    ``quicklook.max_labels`` that do not overlap are numbered on the views, every one
    is circled and the list gives the first 25; ``coverage``: pings per voxel (voxels
    no ping reached are drawn in :data:`NO_DATA_RGBA`; None: all imaged); ``title``
    and ``identity``: the tile's name and provenance lines; ``profiles``: each
    contact's tail profile (dB re background from its peak down in steps of
    ``profile_step_m``, :mod:`.contact_features`): the strongest are drawn beside the
    list (:data:`TAIL_PANELS` at most, as the width allows) and the list gives each
    contact's tail features.
    """
    d = cfg.drc
    max_labels = cfg.quicklook.max_labels
    a, c, z = grid.along, grid.cross, grid.depth
    ea, ec, ed = _edges(a, voxel_m), _edges(c, voxel_m), _edges(z, voxel_m)
    la, lc, ld = ea[1] - ea[0], ec[1] - ec[0], ed[1] - ed[0]
    hit = None if coverage is None else coverage > 0

    def rgba(x, imaged):
        return view_rgba(x, imaged, d.floor_db, d.knee_db, d.ceiling_db)

    panels = [(rgba(mips["mip_depth"], None if hit is None else hit.any(axis=2)), ec, lc,
               CROSS_LABEL, "top view: maximum over depth", False, ("along_m", "cross_m"),
               None),
              (rgba(mips["mip_cross"], None if hit is None else hit.any(axis=1)), ed, ld,
               DEPTH_LABEL, "side view: maximum over cross-track", True,
               ("along_m", "depth_m"), None)]
    for depth in cfg.quicklook.depth_slices_m:
        if ed[0] <= depth <= ed[1]:
            k = int(np.argmin(np.abs(z - depth)))
            near = np.abs(detections["depth_m"] - z[k]) <= max(voxel_m, 0.05)
            panels.append((rgba(level[:, :, k] + gain_db[k],
                                None if hit is None else hit[:, :, k]), ec, lc, CROSS_LABEL,
                           f"depth slice {z[k]:.2f} m below seabed", False,
                           ("along_m", "cross_m"), near))
    width = float(np.clip(la + 1.6, MIN_WIDTH_IN, MAX_WIDTH_IN))
    axes_w = width - LEFT_IN - RIGHT_IN
    heights = [_panel_height(p[2], la, axes_w) for p in panels]
    bottom_h = BOTTOM_VIEW_IN
    slot = TITLE_IN + XLABEL_IN             # a panel's title above, its x axis below
    height = SUPTITLE_IN + sum(h for h, _ in heights) + len(panels) * slot + slot + bottom_h
    tails = profiles is not None and len(profiles) > 0 and np.isfinite(profile_step_m)
    if tails:                       # a row of tail profiles under the bottom row
        height += TAIL_ROW_IN
    # the layout is fixed here, in inches; the views are placed in its pixels
    canvas = Canvas(width, height, cfg.quicklook.dpi)
    n_det = len(detections)
    order = np.arange(n_det)
    drawn = []
    top = SUPTITLE_IN
    for (img, ye, _, ylabel, name, down, keys, sel), (h, exag) in zip(panels, heights):
        box = canvas.box(LEFT_IN, top + TITLE_IN, axes_w, h)
        top += h + slot
        if abs(exag - 1.0) > 0.05:
            name += f" (vertical scale \u00d7{exag:.1f})"
        v = _draw(canvas, box, img, ea, ye, "along-track (m)", ylabel, name, down)
        if not down:
            _sides(canvas, v, horizontal=False)
        drawn.append((v, order if sel is None else order[sel], keys))
    # the bottom row: the end view (true scale), the colour bar, the contact list
    end_w = min(bottom_h * lc / ld, 0.4 * axes_w) if ld > 0 else bottom_h
    end_h = min(bottom_h, end_w * ld / lc) if lc > 0 else bottom_h
    v = canvas.view(canvas.box(LEFT_IN, top + TITLE_IN, end_w, end_h),
                    rgba(mips["mip_along"], None if hit is None else hit.any(axis=0)), ec,
                    ed, True)
    canvas.x_axis(v, CROSS_LABEL, max_ticks=5)
    canvas.y_axis(v, DEPTH_LABEL)
    canvas.title(v, "end view: maximum over along-track")
    _sides(canvas, v, horizontal=True)
    drawn.append((v, order, ("cross_m", "depth_m")))
    cbar_left = LEFT_IN + end_w + COLORBAR_GAP_IN
    levels = sorted({lv for lv in (d.floor_db, 0.0, 10.0, d.knee_db, d.knee_db + 10.0,
                                   d.ceiling_db, d.ceiling_db + 20.0) if lv >= d.floor_db})
    gain = cfg.depth_gain
    label = "normalised level, dB re background\n(compressed scale; grey: no ping)"
    if gain.db_per_m:
        label += f"\n+ display gain {gain.db_per_m:g} dB/m below {gain.start_m:g} m"
    canvas.colour_bar(canvas.box(cbar_left, top + TITLE_IN, COLORBAR_W_IN, bottom_h),
                      _lut(CMAP), compress(np.asarray(levels), d.floor_db, d.knee_db,
                                           d.ceiling_db), [f"{lv:g}" for lv in levels],
                      label)
    text_left = cbar_left + COLORBAR_W_IN + COLORBAR_LABELS_IN
    canvas.text((text_left * canvas.dpi, (top + TITLE_IN) * canvas.dpi),
                _detection_lines(detections, 25), 7, "la", "mono")
    if tails:
        _tail_panels(canvas, LEFT_IN, top + TITLE_IN + bottom_h + XLABEL_IN,
                     width - RIGHT_IN, TAIL_ROW_IN, detections, profiles, profile_step_m,
                     cfg)
    canvas.text((canvas.width / 2, 0.08 * canvas.dpi),
                f"{title}\n{n_det} detection(s) at {cfg.detection.threshold_db:g} dB re "
                f"background (numbered: the strongest {max_labels} on each view)\n"
                f"{identity}", 8, "ma", align="center")
    for v, idx, keys in drawn:
        _mark(canvas, v, detections, idx, keys, max_labels)
    path = Path(path)
    canvas.save_palette_png(path, _palette(), PNG_COMPRESS_LEVEL)
    return path


def mip_png(path: str | Path, image: np.ndarray, grid: TileGrid, title: str,
            dynamic_range_db: float = 40.0, dpi: int = 90) -> Path:
    """Write the three maximum intensity projections of |image| (dB re its peak), each
    at true scale, stacked, with a colour bar."""
    mag = np.abs(image)
    peak = mag.max()
    rel = (amplitude_to_db_floored(mag / peak, -300.0) if peak > 0
           else np.full(mag.shape, -dynamic_range_db))
    v = grid.voxel_m
    ea, ec, ed = _edges(grid.along, v), _edges(grid.cross, v), _edges(grid.depth, v)
    la, lc, ld = (e[1] - e[0] for e in (ea, ec, ed))
    width = float(np.clip(la + 1.6, MIN_WIDTH_IN, MAX_WIDTH_IN)) + COLORBAR_LABELS_IN
    axes_w = width - LEFT_IN - RIGHT_IN - COLORBAR_GAP_IN - COLORBAR_W_IN \
        - COLORBAR_LABELS_IN
    panels = [(rel.max(axis=2), ea, ec, "along-track (m)", CROSS_LABEL,
               "depth MIP (top view)", False),
              (rel.max(axis=1), ea, ed, "along-track (m)", DEPTH_LABEL,
               "cross-track MIP (side view)", True),
              (rel.max(axis=0), ec, ed, CROSS_LABEL, DEPTH_LABEL,
               "along-track MIP (end view)", True)]
    sizes = []
    for _, xe, ye, *_rest in panels:
        w = axes_w
        h = w * (ye[1] - ye[0]) / (xe[1] - xe[0])
        if h > MAX_PANEL_IN:                # true scale: narrower rather than taller
            w, h = w * MAX_PANEL_IN / h, MAX_PANEL_IN
        sizes.append((w, max(h, 0.2)))
    slot = TITLE_IN + XLABEL_IN
    height = SUPTITLE_IN + sum(h for _, h in sizes) + len(panels) * slot
    canvas = Canvas(width, height, dpi)
    lut = _lut(MIP_CMAP)
    top = SUPTITLE_IN
    for (img, xe, ye, xl, yl, name, down), (w, h) in zip(panels, sizes):
        u = np.clip((img + dynamic_range_db) / dynamic_range_db, 0.0, 1.0)
        rgba = lut[np.round(u * (len(lut) - 1)).astype(np.int64)]
        _draw(canvas, canvas.box(LEFT_IN, top + TITLE_IN, w, h), rgba, xe, ye, xl, yl,
              name, down)
        ticks = np.arange(0.0, 1.0001, 10.0 / dynamic_range_db) if dynamic_range_db > 0 \
            else np.array([0.0])
        canvas.colour_bar(canvas.box(LEFT_IN + w + COLORBAR_GAP_IN, top + TITLE_IN,
                                     COLORBAR_W_IN, h), lut, ticks,
                          [f"{dynamic_range_db * (t - 1):g}" for t in ticks],
                          "dB re tile peak")
        top += h + slot
    canvas.text((canvas.width / 2, 0.12 * canvas.dpi), title, 10, "ma", align="center")
    path = Path(path)
    canvas.save_palette_png(path, _palette(MIP_CMAP), PNG_COMPRESS_LEVEL)
    return path


@functools.lru_cache(maxsize=4)
def _lut(name: str) -> np.ndarray:
    """The colour map ``name`` at 256 levels, RGBA floats."""
    return colormaps[name](np.linspace(0.0, 1.0, 256))


@functools.lru_cache(maxsize=2)
def _palette(cmap: str = CMAP) -> tuple[int, ...]:
    """The 256 colours of a quicklook: the colour map ``cmap`` at 224 levels, greys,
    white, black, the marker cyan and the no-data colour (made once)."""
    cols = [tuple(c) for c in colormaps[cmap](np.linspace(0.0, 1.0, 224))[:, :3]]
    cols += [(g, g, g) for g in np.linspace(0.0, 1.0, 24)]
    cols += [(0.0, 1.0, 1.0), (0.0, 0.75, 0.75), (0.5, 1.0, 1.0), NO_DATA_RGBA[:3],
             (0.15, 0.15, 0.15), (0.6, 0.6, 0.6), (0.3, 0.3, 0.3), (0.9, 0.9, 0.9)]
    return tuple(int(round(255 * v)) for c in cols[:256] for v in c)


#: the row of tail profiles under the bottom row: its height, at most this many panels,
#: each this wide and this far apart (inches)
TAIL_ROW_IN, TAIL_PANELS, TAIL_PANEL_IN, TAIL_GAP_IN = 2.6, 8, 1.1, 0.55


def _tail_panels(canvas, left_in: float, top_in: float, right_in: float, h_in: float,
                 detections: np.ndarray, profiles: np.ndarray, step_m: float,
                 cfg: ProductsConfig) -> None:
    """The tail profiles of the strongest contacts (numbered as the list), one small
    panel each from ``left_in`` while they fit before ``right_in``: level (dB re
    background) against apparent depth below the peak, the features'
    background_within_db marked (grey), the decay (dB/m) and the tail's extent
    above."""
    fc = cfg.features
    n = int(min(len(profiles), TAIL_PANELS,
                max(0, (right_in - left_in + TAIL_GAP_IN) // (TAIL_PANEL_IN + TAIL_GAP_IN))))
    depth = np.arange(profiles.shape[1]) * step_m
    hi = float(np.nanmax(profiles[:n])) if n and np.isfinite(profiles[:n]).any() else 30.0
    xe = (-5.0, max(10.0, 10.0 * math.ceil(hi / 10.0)))
    ye = (0.0, float(depth[-1]) if depth.size > 1 else 1.0)
    grey = rgb8((0.6, 0.6, 0.6))
    for i in range(n):
        x0 = left_in + i * (TAIL_PANEL_IN + TAIL_GAP_IN)
        box = canvas.box(x0, top_in + 0.45, TAIL_PANEL_IN, h_in - 0.95)
        v = canvas.view(box, np.ones((1, 1, 3)), xe, ye, True)
        canvas.x_axis(v, "dB re background", max_ticks=3)
        if i == 0:
            canvas.y_axis(v, "below peak (m)")
        if fc is not None:
            x = v.to_px([fc.background_within_db] * 2, list(ye))
            canvas.draw.line([tuple(p) for p in x], fill=grey)
        ok = np.isfinite(profiles[i])
        pts = v.to_px(np.clip(profiles[i][ok], *xe), depth[ok])
        if len(pts) > 1:
            canvas.draw.line([tuple(p) for p in pts], fill=rgb8((0.0, 0.45, 0.7)), width=2)
        row = detections[i]
        decay = row["tail_decay_db_per_m"]
        ext = row["tail_extent_m"]
        canvas.text((v.x0, v.y0 - canvas.px(2)),
                    f"#{i} " + (f"{decay:.0f}\u00b1{row['tail_decay_err_db_per_m']:.0f} dB/m"
                                if np.isfinite(decay) else "no decay")
                    + "\n" + (f"tail {ext:.2f} m" if np.isfinite(ext) else "tail cut"),
                    7, "ld")


def _detection_lines(detections: np.ndarray, n_max: int = 20) -> str:
    """The strongest detections as text lines: number, position (m; depth below the
    seabed), excess (dB re background), largest extent (m) and, where measured, the
    tail's extent (m), decay (dB/m), late-to-specular ratio (dB; '<' an upper bound) and
    the rms spread of the look angles over the aperture (deg; docs/contact_features.md);
    where classified, its class and p_manmade (:mod:`.classify`)."""
    feats = "tail_extent_m" in (detections.dtype.names or ()) and len(detections) \
        and np.any(detections["feature_flags"] >= 0)
    lines = ["#    along  cross  depth  excess   size", "      (m)    (m)    (m)    (dB)    (m)"]
    classed = "class" in (detections.dtype.names or ()) and len(detections) \
        and np.any(detections["class"] != NOT_CLASSIFIED)
    if feats:
        lines[0] += "   tail  decay    L/S aspect"
        lines[1] += "    (m) (dB/m)   (dB)  (deg)"
    if classed:
        lines[0] += "  class      p"
        lines[1] += "         (man-made)"
    for i, row in enumerate(detections[:n_max]):
        size = max(row["extent_along_m"], row["extent_cross_m"], row["extent_depth_m"])
        lines.append(f"{i:<3d}{row['along_m']:6.2f} {row['cross_m']:6.2f} "
                     f"{row['depth_m']:6.2f} {row['excess_db']:6.1f} {size:6.2f}"
                     + (_feature_text(row) if feats else "")
                     + (_class_text(row) if classed else ""))
    if len(detections) > n_max:
        lines.append(f"... {len(detections) - n_max} more (in the tile file)")
    if len(detections) == 0:
        lines.append("(no detections)")
    return "\n".join(lines)


def _feature_text(row) -> str:
    """A contact's features for the list: tail extent, decay, late-to-specular, aspect."""
    def num(v, w, d):
        return f"{v:{w}.{d}f}" if np.isfinite(v) else " " * (w - 1) + "-"
    ls = row["late_to_specular_db"]
    bound = "<" if row["feature_flags"] >= 0 and row["feature_flags"] & LATE_UPPER_BOUND \
        and np.isfinite(ls) else " "
    return (f" {num(row['tail_extent_m'], 6, 2)} {num(row['tail_decay_db_per_m'], 6, 0)} "
            f"{bound}{num(ls, 5, 1)} {num(row['aspect_width_deg'], 6, 1)}")


def _class_text(row) -> str:
    """A contact's class and p_manmade for the list (:mod:`.classify`)."""
    p = row["p_manmade"]
    return f"  {class_text(row['class']):<9} " + (f"{p:4.2f}" if np.isfinite(p) else "   -")


def _mark(canvas: Canvas, v: View, detections: np.ndarray, idx: np.ndarray,
          keys: tuple[str, str], max_labels: int) -> list[int]:
    """Circle the contacts ``idx`` (rows of ``detections``, strongest first) on a view
    and number those :func:`choose_labels` picks; returns the numbered rows."""
    if len(idx) == 0:
        return []
    px = v.to_px(detections[keys[0]][idx], detections[keys[1]][idx])
    canvas.circles(px, MARKER_PT, MARKER_RGB, 0.8, v)
    chosen = choose_labels(px, max_labels)
    off = canvas.px(4.0)
    for j in chosen:
        canvas.text((px[j, 0] + off, px[j, 1] - off), str(int(idx[j])), 7, "ls", "bold",
                    rgb8(MARKER_RGB))
    return [int(idx[j]) for j in chosen]
