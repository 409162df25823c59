"""The report's figures (PNG, matplotlib's Agg backend): the seed's three orthogonal
slices through the target peak, the depth profile with its multipath features, and the
test field's depth slice and cross-track MIP after normalisation and compression."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from .measures import Feature


def _edges(x: np.ndarray) -> tuple[float, float]:
    step = float(x[1] - x[0]) if x.size > 1 else 1.0
    return float(x[0] - step / 2), float(x[-1] + step / 2)


def _panel(ax, img, x, y, xlabel, ylabel, title, vmin, vmax, cmap="viridis",
           depth_down=True, aspect="equal"):
    x0, x1 = _edges(x)
    y0, y1 = _edges(y)
    h = ax.imshow(img.T, origin="upper" if depth_down else "lower", aspect=aspect,
                  extent=(x0, x1, y1, y0) if depth_down else (x0, x1, y0, y1),
                  vmin=vmin, vmax=vmax, cmap=cmap, interpolation="nearest")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    return h


def orthogonal_slices(path: str | Path, image: np.ndarray, axes, peak: tuple[float, float, float],
                      title: str, gain_db_per_m: float = 0.0, dynamic_range_db: float = 40.0,
                      dpi: int = 110) -> Path:
    """Three slices through ``peak`` (along, cross, depth; m) of ``image`` (along x cross x
    depth): along-track x depth at the peak's cross-track position, cross-track x depth at
    its along-track position, along x cross at its depth. Level: 20 log10 |image| re the
    volume's largest, plus ``gain_db_per_m`` x depth (the seed's display gain for sand);
    ``dynamic_range_db`` shown."""
    a, c, d = (np.asarray(v, dtype=np.float64) for v in axes)
    mag = np.abs(image).astype(np.float64)
    with np.errstate(divide="ignore"):
        db = 20 * np.log10(mag / mag.max()) + gain_db_per_m * np.maximum(d, 0.0)[None, None, :]
    i, j, k = (int(np.argmin(np.abs(v - p))) for v, p in zip((a, c, d), peak))
    shown = [db[:, j, :], db[i, :, :], db[:, :, k]]
    vmax = max(float(np.nanmax(np.where(np.isfinite(s), s, np.nan))) for s in shown)
    vmin = vmax - dynamic_range_db
    fig = plt.figure(figsize=(11, 6.8), layout="constrained")
    grid = fig.add_gridspec(2, 3, width_ratios=[a.size, c.size, 0.06 * a.size],
                            height_ratios=[d.size, c.size])
    ax1 = fig.add_subplot(grid[0, 0])
    _panel(ax1, db[:, j, :], a, d, "", "depth below the seabed (m)",
           f"along x depth at cross {c[j]:+.2f} m", vmin, vmax)
    ax2 = fig.add_subplot(grid[0, 1], sharey=ax1)
    _panel(ax2, db[i, :, :], c, d, "cross-track (m, starboard +)", "",
           f"cross x depth at along {a[i]:.2f} m", vmin, vmax)
    ax3 = fig.add_subplot(grid[1, 0], sharex=ax1)
    h = _panel(ax3, db[:, :, k], a, c, "along-track (m)", "cross-track (m)",
               f"along x cross at depth {d[k]:.2f} m", vmin, vmax)
    for ax in (ax1, ax2):
        ax.axhline(peak[2], color="w", lw=0.5, ls=":")
    cax = fig.add_subplot(grid[:, 2])
    fig.colorbar(h, cax=cax, label="dB re the volume's peak"
                 + (f" + {gain_db_per_m:g} dB/m gain" if gain_db_per_m else ""))
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)


def profile_figure(path: str | Path, depth: np.ndarray, profiles: dict[str, np.ndarray],
                   features: dict[str, list[Feature]], expected: dict[str, float],
                   title: str, dpi: int = 110) -> Path:
    """Depth profiles (dB) of the background under the track, their features (peak and
    onset marked) and the path arithmetic's depths (dashed)."""
    fig, ax = plt.subplots(figsize=(7, 5.5))
    for (name, db), colour in zip(profiles.items(), plt.cm.tab10.colors):
        ax.plot(db, depth, color=colour, lw=1, label=name)
        for f in features.get(name, []):
            ax.plot([f.level_db], [f.depth], "v", color=colour)
            ax.plot([f.level_db - 3], [f.onset], "_", color=colour, ms=12)
    for label, z in expected.items():
        ax.axhline(z, color="k", ls="--", lw=0.7)
        ax.text(ax.get_xlim()[0], z, f" {label}: {z:.3f} m", va="bottom", fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("mean intensity under the track (dB re its peak)")
    ax.set_ylabel("depth below the seabed (m)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)


def field_figure(path: str | Path, drc: np.ndarray, mip_cross_u: np.ndarray, axes,
                 depth_slice_m: float, targets: list[tuple[float, float, float, str]],
                 title: str, dpi: int = 110) -> Path:
    """The test field after normalisation and compression (display values 0..1): the
    depth slice nearest ``depth_slice_m`` (top) and the cross-track MIP (bottom, along x
    depth); ``targets`` (along, cross, depth, label) marked."""
    a, c, d = (np.asarray(v, dtype=np.float64) for v in axes)
    k = int(np.argmin(np.abs(d - depth_slice_m)))
    # metre scale would make an 18 m x 1.3 m view a strip: each panel is stretched
    # across (the axes are labelled in metres)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(13, 7), sharex=True, layout="constrained")
    h = _panel(ax1, drc[:, :, k], a, c, "", "cross-track (m, starboard +)",
               f"depth slice at {d[k]:.2f} m below the seabed (normalised, compressed)",
               0.0, 1.0, cmap="gray", depth_down=False, aspect="auto")
    _panel(ax2, mip_cross_u, a, d, "along-track (m)", "depth below the seabed (m)",
           "cross-track MIP (normalised, compressed; vertical scale stretched)", 0.0, 1.0,
           cmap="gray", aspect="auto")
    for (ta, tc, td, label) in targets:
        ax1.plot([ta], [tc], "o", mfc="none", mec="r", ms=12, mew=0.8)
        ax2.plot([ta], [td], "o", mfc="none", mec="r", ms=12, mew=0.8)
        ax2.text(ta, d[-1], label, color="r", fontsize=7, ha="center", va="bottom")
    fig.colorbar(h, ax=[ax1, ax2], label="display value (0: -10 dB, 1: +40 dB re background)")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)
