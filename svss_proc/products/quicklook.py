"""PNG quicklooks of a tile, axes in metres.

:func:`products_png`: the three maximum intensity projections (top, side and end views)
and depth slices of the background-normalised, compressed volume, with the detections
marked, a colour bar in dB re background and the tile's identity.
:func:`mip_png`: the three projections of ``|image|`` in dB re the tile's peak, for tiles
processed without products.
"""

from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.cm import ScalarMappable  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402

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


def products_png(path: str | Path, mips: dict[str, np.ndarray], level: np.ndarray,
                 gain_db: np.ndarray, detections: np.ndarray, grid: TileGrid,
                 voxel_m: float, cfg: ProductsConfig, title: str, identity: str) -> Path:
    """Quicklook of a tile's products.

    ``mips``: the projections of level + gain (dB re background, keys of
    :data:`svss_proc.tiles.MIPS`); ``level``: normalised level (dB re background, along x
    cross x depth) and ``gain_db`` the display gain per depth, for the depth slices at
    ``cfg.quicklook.depth_slices_m``; ``detections``: contacts to mark; ``title`` and
    ``identity``: the tile's name and provenance lines.
    """
    d = cfg.drc

    def comp(x):
        return compress(x, d.floor_db, d.knee_db, d.ceiling_db)

    a, c, z = grid.along, grid.cross, grid.depth
    ea, ec, ed = _edges(a, voxel_m), _edges(c, voxel_m), _edges(z, voxel_m)
    la, lc, ld = ea[1] - ea[0], ec[1] - ec[0], ed[1] - ed[0]
    slices = []
    for depth in cfg.quicklook.depth_slices_m:
        if ed[0] <= depth <= ed[1]:
            k = int(np.argmin(np.abs(z - depth)))
            slices.append((k, comp(level[:, :, k] + gain_db[k])))
    heights = [lc, ld] + [lc] * len(slices)
    right = max(lc, 0.3 * la)
    scale = min(12.0 / (la + right), 11.0 / sum(heights))  # inches per metre
    fig = plt.figure(figsize=(max(scale * (la + right) + 2.0, 9.0),
                              scale * sum(heights) + 2.0), constrained_layout=True)
    gs = fig.add_gridspec(len(heights), 2, width_ratios=[la, right], height_ratios=heights)
    kw = {"cmap": CMAP, "vmin": 0.0, "vmax": 1.0}
    ax = fig.add_subplot(gs[0, 0])
    _show(ax, comp(mips["mip_depth"]), ea, ec, "along-track (m)", "cross-track (m)",
          "MIP over depth (top view)", depth_down=False, **kw)
    _mark(ax, detections["along_m"], detections["cross_m"])
    ax = fig.add_subplot(gs[1, 0])
    _show(ax, comp(mips["mip_cross"]), ea, ed, "along-track (m)", "depth (m)",
          "MIP over cross-track (side view)", depth_down=True, **kw)
    _mark(ax, detections["along_m"], detections["depth_m"])
    for row, (k, img) in enumerate(slices, start=2):
        ax = fig.add_subplot(gs[row, 0])
        _show(ax, img, ea, ec, "along-track (m)", "cross-track (m)",
              f"depth slice at {z[k]:.2f} m", depth_down=False, **kw)
        near = np.flatnonzero(np.abs(detections["depth_m"] - z[k]) <= max(voxel_m, 0.05))
        _mark(ax, detections["along_m"][near], detections["cross_m"][near], near)
    ax = fig.add_subplot(gs[0:2, 1]) if len(heights) > 1 else fig.add_subplot(gs[0, 1])
    _show(ax, comp(mips["mip_along"]), ec, ed, "cross-track (m)", "depth (m)",
          "MIP over along-track (end view)", depth_down=True, **kw)
    _mark(ax, detections["cross_m"], detections["depth_m"])
    levels = [lv for lv in (d.floor_db, 0.0, 10.0, d.knee_db, d.knee_db + 10.0,
                            d.ceiling_db, d.ceiling_db + 20.0) if lv >= d.floor_db]
    levels = sorted(set(levels))
    cb = fig.colorbar(ScalarMappable(Normalize(0.0, 1.0), CMAP), ax=ax, location="bottom",
                      shrink=0.9)
    cb.set_ticks(comp(np.asarray(levels)))
    cb.set_ticklabels([f"{lv:g}" for lv in levels])
    gain = cfg.depth_gain
    label = "normalised level (compressed scale)\ndB re background"
    if gain.db_per_m:
        label += f"\n+ display gain {gain.db_per_m:g} dB/m below {gain.start_m:g} m"
    cb.set_label(label, fontsize=8)
    cb.ax.tick_params(labelsize=7)
    if len(heights) > 2:
        tax = fig.add_subplot(gs[2:, 1])
        tax.axis("off")
        tax.text(0.0, 1.0, _detection_lines(detections), va="top", ha="left",
                 family="monospace", fontsize=7, transform=tax.transAxes)
    fig.suptitle(f"{title}; {len(detections)} detection(s) at "
                 f"{cfg.detection.threshold_db:g} dB re background\n{identity}", fontsize=8)
    path = Path(path)
    fig.savefig(path, dpi=cfg.quicklook.dpi)
    plt.close(fig)
    return path


def _detection_lines(detections: np.ndarray, n_max: int = 20) -> str:
    """The strongest detections as text lines (position m, excess dB)."""
    lines = ["#   along   cross  depth  excess"]
    for i, row in enumerate(detections[:n_max]):
        lines.append(f"{i:<2d} {row['along_m']:7.2f} {row['cross_m']:6.2f} "
                     f"{row['depth_m']:6.2f} {row['excess_db']:5.1f} dB")
    if len(detections) > n_max:
        lines.append(f"... {len(detections) - n_max} more")
    if len(detections) == 0:
        lines.append("(no detections)")
    return "\n".join(lines)


def _mark(ax, x: np.ndarray, y: np.ndarray, numbers=None) -> None:
    """Mark detections with open circles numbered as in the detection table."""
    if len(x) == 0:
        return
    ax.scatter(x, y, s=60, facecolors="none", edgecolors="cyan", linewidths=0.8)
    numbers = range(len(x)) if numbers is None else numbers
    for i, xi, yi in zip(numbers, x, y):
        ax.annotate(str(i), (xi, yi), xytext=(3, 3), textcoords="offset points",
                    color="cyan", fontsize=6)
