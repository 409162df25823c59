"""PNG quicklooks: maximum intensity projections of a tile, axes in metres."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .grid import TileGrid  # noqa: E402


def db(x: np.ndarray, floor_db: float = -300.0) -> np.ndarray:
    """20 log10 |x| with a floor for zeros (no log of zero)."""
    mag = np.abs(x)
    out = np.full(mag.shape, floor_db, dtype=np.float64)
    pos = mag > 0
    out[pos] = 20.0 * np.log10(mag[pos])
    return np.maximum(out, floor_db)


def mip_png(path: str | Path, image: np.ndarray, grid: TileGrid, title: str,
            dynamic_range_db: float = 40.0) -> Path:
    """Write the three maximum intensity projections of |image| (dB re its peak)."""
    mag = np.abs(image)
    peak = mag.max()
    rel = db(mag / peak) if peak > 0 else np.full(mag.shape, -dynamic_range_db)
    a, c, d = grid.along, grid.cross, grid.depth
    half = grid.voxel_m / 2 if np.isfinite(grid.voxel_m) else 0.0
    ext = {"a": (a[0] - half, a[-1] + half), "c": (c[0] - half, c[-1] + half),
           "d": (d[0] - half, d[-1] + half)}
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), constrained_layout=True,
                             height_ratios=[c.size, d.size, d.size])
    panels = [
        (rel.max(axis=2).T, ext["a"], ext["c"], "along-track (m)", "cross-track (m)",
         "depth MIP (top view)"),
        (rel.max(axis=1).T, ext["a"], ext["d"], "along-track (m)", "depth (m)",
         "cross-track MIP (side view)"),
        (rel.max(axis=0).T, ext["c"], ext["d"], "cross-track (m)", "depth (m)",
         "along-track MIP (end view)"),
    ]
    for ax, (img, xe, ye, xl, yl, name) in zip(axes, panels):
        im = ax.imshow(img, origin="upper" if yl.startswith("depth") else "lower",
                       extent=(xe[0], xe[1], ye[1], ye[0]) if yl.startswith("depth")
                       else (xe[0], xe[1], ye[0], ye[1]),
                       vmin=-dynamic_range_db, vmax=0.0, cmap="viridis", aspect="equal",
                       interpolation="nearest")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(name, fontsize=9)
        fig.colorbar(im, ax=ax, label="dB re tile peak", shrink=0.9)
    fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
