"""PNG quicklooks of a tile, axes in metres.

:func:`products_png`: the three maximum intensity projections (top, side and end views)
and depth slices of the background-normalised, compressed volume, with the detections
marked, a colour bar in dB re background and the tile's identity.
:func:`mip_png`: the three projections of ``|image|`` in dB re the tile's peak, for tiles
processed without products.
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.cm import ScalarMappable  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from svss_daq.config import ProductsConfig  # noqa: E402
from svss_daq.decibels import amplitude_to_db_floored  # noqa: E402

from .drc import compress  # noqa: E402
from ..imaging.grid import TileGrid  # noqa: E402

log = logging.getLogger(__name__)

CMAP = "magma"


def _edges(axis: np.ndarray, voxel_m: float) -> tuple[float, float]:
    half = voxel_m / 2 if np.isfinite(voxel_m) else 0.0
    return float(axis[0] - half), float(axis[-1] + half)


def _show(ax, img, xe, ye, xlabel, ylabel, title, cmap, vmin, vmax, depth_down):
    """Draw ``img`` (x index first) with axes in metres; depth increases downwards."""
    extent = (xe[0], xe[1], ye[1], ye[0]) if depth_down else (xe[0], xe[1], ye[0], ye[1])
    im = ax.imshow(img.T, origin="upper" if depth_down else "lower", extent=extent,
                   vmin=vmin, vmax=vmax, cmap=cmap, aspect="equal", interpolation="nearest")
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    return im


def mip_png(path: str | Path, image: np.ndarray, grid: TileGrid, title: str,
            dynamic_range_db: float = 40.0) -> Path:
    """Write the three maximum intensity projections of |image| (dB re its peak)."""
    mag = np.abs(image)
    peak = mag.max()
    rel = (amplitude_to_db_floored(mag / peak, -300.0) if peak > 0
           else np.full(mag.shape, -dynamic_range_db))
    v = grid.voxel_m
    ea, ec, ed = _edges(grid.along, v), _edges(grid.cross, v), _edges(grid.depth, v)
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), constrained_layout=True,
                             height_ratios=[grid.cross.size, grid.depth.size,
                                            grid.depth.size])
    panels = [(rel.max(axis=2), ea, ec, "along-track (m)", "cross-track (m)",
               "depth MIP (top view)", False),
              (rel.max(axis=1), ea, ed, "along-track (m)", "depth (m)",
               "cross-track MIP (side view)", True),
              (rel.max(axis=0), ec, ed, "cross-track (m)", "depth (m)",
               "along-track MIP (end view)", True)]
    for ax, (img, xe, ye, xl, yl, name, down) in zip(axes, panels):
        im = _show(ax, img, xe, ye, xl, yl, name, "viridis", -dynamic_range_db, 0.0, down)
        fig.colorbar(im, ax=ax, label="dB re tile peak", shrink=0.9)
    fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


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
DEPTH_LABEL = "depth below seabed (m)"
CROSS_LABEL = "cross-track (m), starboard +"


def view_rgba(display: np.ndarray, imaged: np.ndarray | None, floor_db: float,
              knee_db: float, ceiling_db: float) -> np.ndarray:
    """RGBA image (x index first, like ``display``) of a view in dB: compressed
    (:func:`~svss_proc.products.drc.compress`) through the colour map, and
    :data:`NO_DATA_RGBA` where ``imaged`` is False (no ping reached the voxels) or the
    value is NaN; low signal stays at the dark end of the map."""
    u = compress(display, floor_db, knee_db, ceiling_db)
    rgba = plt.get_cmap(CMAP)(np.nan_to_num(u, nan=0.0))
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


def _draw(ax, rgba, xe, ye, xlabel, ylabel, title, depth_down):
    extent = (xe[0], xe[1], ye[1], ye[0]) if depth_down else (xe[0], xe[1], ye[0], ye[1])
    ax.imshow(np.transpose(rgba, (1, 0, 2)), origin="upper" if depth_down else "lower",
              extent=extent, aspect="auto", interpolation="nearest")
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title(title, fontsize=9, loc="left")
    ax.tick_params(labelsize=7)


def _sides(ax, horizontal: bool) -> None:
    """Mark port and starboard on a view whose cross-track axis is vertical (top view,
    depth slices; starboard up) or horizontal (end view; starboard right)."""
    kw = {"transform": ax.transAxes, "fontsize": 7, "color": "white", "weight": "bold",
          "bbox": {"boxstyle": "round,pad=0.15", "fc": "0.15", "ec": "none", "alpha": 0.7}}
    if horizontal:
        ax.text(0.99, 0.02, "STBD →", ha="right", va="bottom", **kw)
        ax.text(0.01, 0.02, "← PORT", ha="left", va="bottom", **kw)
    else:
        ax.text(0.005, 0.97, "STBD", ha="left", va="top", **kw)
        ax.text(0.005, 0.03, "PORT", ha="left", va="bottom", **kw)


def products_png(path: str | Path, mips: dict[str, np.ndarray], level: np.ndarray,
                 gain_db: np.ndarray, detections: np.ndarray, grid: TileGrid,
                 voxel_m: float, cfg: ProductsConfig, title: str, identity: str,
                 coverage: np.ndarray | None = None) -> Path:
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
    and ``identity``: the tile's name and provenance lines.
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
    # the layout is fixed here, in inches (no layout engine: it drew the figure once
    # more to measure its texts, 40 % of the quick look's time); labels are placed in
    # its pixels, and saving draws the figure once
    fig = plt.figure(figsize=(width, height))
    fig.set_dpi(cfg.quicklook.dpi)

    def box(left_in, top_in, w_in, h_in):
        return [left_in / width, 1.0 - (top_in + h_in) / height, w_in / width, h_in / height]

    n_det = len(detections)
    order = np.arange(n_det)
    drawn = []
    top = SUPTITLE_IN
    for (img, ye, _, ylabel, name, down, keys, sel), (h, exag) in zip(panels, heights):
        ax = fig.add_axes(box(LEFT_IN, top + TITLE_IN, axes_w, h))
        top += h + slot
        if abs(exag - 1.0) > 0.05:
            name += f" (vertical scale ×{exag:.1f})"
        _draw(ax, img, ea, ye, "along-track (m)", ylabel, name, down)
        if not down:
            _sides(ax, horizontal=False)
        idx = order if sel is None else order[sel]
        drawn.append((ax, idx, keys))
    # the bottom row: the end view (true scale), the colour bar, the contact list
    end_w = min(bottom_h * lc / ld, 0.4 * axes_w) if ld > 0 else bottom_h
    end_h = min(bottom_h, end_w * ld / lc) if lc > 0 else bottom_h
    ax = fig.add_axes(box(LEFT_IN, top + TITLE_IN, end_w, end_h))
    _draw(ax, rgba(mips["mip_along"], None if hit is None else hit.any(axis=0)), ec, ed,
          CROSS_LABEL, DEPTH_LABEL, "end view: maximum over along-track", True)
    ax.set_aspect("equal")
    ax.apply_aspect()
    ax.xaxis.set_major_locator(MaxNLocator(5))
    _sides(ax, horizontal=True)
    drawn.append((ax, order, ("cross_m", "depth_m")))
    cbar_left = LEFT_IN + end_w + COLORBAR_GAP_IN
    cax = fig.add_axes(box(cbar_left, top + TITLE_IN, COLORBAR_W_IN, bottom_h))
    levels = sorted({lv for lv in (d.floor_db, 0.0, 10.0, d.knee_db, d.knee_db + 10.0,
                                   d.ceiling_db, d.ceiling_db + 20.0) if lv >= d.floor_db})
    cb = fig.colorbar(ScalarMappable(Normalize(0.0, 1.0), CMAP), cax=cax)
    cb.set_ticks(compress(np.asarray(levels), d.floor_db, d.knee_db, d.ceiling_db))
    cb.set_ticklabels([f"{lv:g}" for lv in levels])
    gain = cfg.depth_gain
    label = "normalised level, dB re background\n(compressed scale; grey: no ping)"
    if gain.db_per_m:
        label += f"\n+ display gain {gain.db_per_m:g} dB/m below {gain.start_m:g} m"
    cb.set_label(label, fontsize=8)
    cb.ax.tick_params(labelsize=7)
    text_left = cbar_left + COLORBAR_W_IN + COLORBAR_LABELS_IN
    fig.text(text_left / width, 1.0 - (top + TITLE_IN) / height,
             _detection_lines(detections, 25), va="top", ha="left", family="monospace",
             fontsize=7)
    fig.suptitle(f"{title}\n{n_det} detection(s) at {cfg.detection.threshold_db:g} dB re "
                 f"background (numbered: the strongest {max_labels} on each view)\n"
                 f"{identity}", fontsize=8, y=1.0 - 0.08 / height, va="top")
    for ax, idx, keys in drawn:
        _mark(ax, detections, idx, keys, max_labels)
    path = Path(path)
    save_png(fig, path, cfg.quicklook.dpi)
    plt.close(fig)
    return path


@functools.lru_cache(maxsize=1)
def _palette() -> tuple[int, ...]:
    """The 256 colours of a quicklook: the colour map at 224 levels, greys, white,
    black, the marker cyan and the no-data colour (made once)."""
    cols = [tuple(c) for c in plt.get_cmap(CMAP)(np.linspace(0.0, 1.0, 224))[:, :3]]
    cols += [(g, g, g) for g in np.linspace(0.0, 1.0, 24)]
    cols += [(0.0, 1.0, 1.0), (0.0, 0.75, 0.75), (0.5, 1.0, 1.0), NO_DATA_RGBA[:3],
             (0.15, 0.15, 0.15), (0.6, 0.6, 0.6), (0.3, 0.3, 0.3), (0.9, 0.9, 0.9)]
    return tuple(int(round(255 * v)) for c in cols[:256] for v in c)


def save_png(fig, path: Path, dpi: int) -> None:
    """Save ``fig`` as a palette PNG (:func:`_palette`: the colour map at 224 levels and
    the few other colours a quicklook uses; a third of the bytes of full colour), zlib
    level :data:`PNG_COMPRESS_LEVEL`."""
    from PIL import Image

    fig.set_dpi(dpi)
    fig.canvas.draw()                      # the pixels, no PNG encoding between
    rgba = np.asarray(fig.canvas.buffer_rgba())
    pal = Image.new("P", (1, 1))
    pal.putpalette(list(_palette()))
    Image.fromarray(rgba[..., :3], "RGB").quantize(palette=pal,
                                                   dither=Image.Dither.NONE).save(
        path, format="PNG", compress_level=PNG_COMPRESS_LEVEL)


def _detection_lines(detections: np.ndarray, n_max: int = 20) -> str:
    """The strongest detections as text lines: number, position (m; depth below the
    seabed), excess (dB re background), largest extent (m)."""
    lines = ["#    along  cross  depth  excess   size", "      (m)    (m)    (m)    (dB)    (m)"]
    for i, row in enumerate(detections[:n_max]):
        size = max(row["extent_along_m"], row["extent_cross_m"], row["extent_depth_m"])
        lines.append(f"{i:<3d}{row['along_m']:6.2f} {row['cross_m']:6.2f} "
                     f"{row['depth_m']:6.2f} {row['excess_db']:6.1f} {size:6.2f}")
    if len(detections) > n_max:
        lines.append(f"... {len(detections) - n_max} more (in the tile file)")
    if len(detections) == 0:
        lines.append("(no detections)")
    return "\n".join(lines)


def _mark(ax, detections: np.ndarray, idx: np.ndarray, keys: tuple[str, str],
          max_labels: int) -> list[int]:
    """Circle the contacts ``idx`` (rows of ``detections``, strongest first) on a view
    and number those :func:`choose_labels` picks; returns the numbered rows."""
    if len(idx) == 0:
        return []
    x, y = detections[keys[0]][idx], detections[keys[1]][idx]
    ax.scatter(x, y, s=60, facecolors="none", edgecolors="cyan", linewidths=0.8)
    px = ax.transData.transform(np.column_stack([x, y]))
    chosen = choose_labels(px, max_labels)
    for j in chosen:
        ax.annotate(str(int(idx[j])), (x[j], y[j]), xytext=(4, 4),
                    textcoords="offset points", color="cyan", fontsize=7, weight="bold")
    return [int(idx[j]) for j in chosen]
