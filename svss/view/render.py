"""The survey map of ``svss view``, drawn server-side with matplotlib as a PNG: the tiles'
plan-view MIPs placed in north/east (survey frame) by their track lines, the tile
outlines, the track (the tiles' pings and the live poses of the status stream), the
boat's last position and heading, the run's contacts, and a latitude/longitude grid
drawn as contours of the geodetic coordinates over the north/east plane (exact in the
survey frame, whatever its size)."""

from __future__ import annotations

import io
import math

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from svss_daq.navigation import ned_to_geodetic  # noqa: E402
from svss_proc.products.drc import compress  # noqa: E402
from svss_proc.products.quicklook import CMAP  # noqa: E402
from svss_proc.products.run_products import (TileView, _configs,  # noqa: E402
                                             tile_corners_ne)

#: the map's size, inches at DPI
SIZE_IN = (7.5, 6.5)
DPI = 100
#: lat/lon grid spacings to choose from, degrees (1'', 2'', 5'', ... 1 deg)
_STEPS_DEG = [s / 3600 for s in (0.1, 0.2, 0.5, 1, 2, 5, 10, 15, 30, 60, 120, 300, 600,
                                 900, 1800, 3600)]


def _step(span_deg: float, lines: int = 4) -> float:
    for s in _STEPS_DEG:
        if span_deg / s <= lines:
            return s
    return _STEPS_DEG[-1]


def dms(v: float, pos: str, neg: str) -> str:
    """``v`` degrees as D°MM'SS.S'' with its hemisphere letter."""
    h = pos if v >= 0 else neg
    s = abs(v) * 3600
    d, s = divmod(s, 3600)
    m, s = divmod(s, 60)
    return f"{int(d)}°{int(m):02d}'{s:04.1f}\"{h}"


def _tile_plan(v: TileView) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(north, east) of a tile's plan-view cell corners and its compressed depth MIP
    (0..1), or None for a tile without products."""
    mip = v.data.get("mip_depth")
    if mip is None:
        return None
    pcfg = _configs(v)[0]
    a, c, vox = v.data["along"], v.data["cross"], v.voxel_m
    ea = np.concatenate([a - vox / 2, a[-1:] + vox / 2])
    ec = np.concatenate([c - vox / 2, c[-1:] + vox / 2])
    A, C = np.meshgrid(ea, ec, indexing="ij")
    ned = v.line.tile_to_ned(np.stack([A.ravel(), C.ravel(), np.zeros(A.size)], axis=1))
    north, east = ned[:, 0].reshape(A.shape), ned[:, 1].reshape(A.shape)
    if pcfg is not None:
        d = pcfg.drc
        shown = compress(mip, d.floor_db, d.knee_db, d.ceiling_db)
    else:
        lo, hi = np.nanpercentile(mip, [5, 99.9]) if np.isfinite(mip).any() else (0, 1)
        shown = np.clip((mip - lo) / max(hi - lo, 1e-9), 0, 1)
    return north, east, shown


def survey_map_png(views: list[TileView], contacts: list[dict], track_ne: np.ndarray,
                   pose: dict | None, origin: tuple[float, float, float] | None,
                   title: str) -> tuple[bytes, list[dict]]:
    """The map as PNG bytes, and each tile's outline in the image's pixels (x right, y
    down: ``{"name", "points": [[x, y], ...]}``) for the page to open a tile clicked on
    it. ``track_ne``: (n, 2) north, east of the live poses; ``pose``: the status's
    ``navigation.pose`` (the boat's position and heading), or None."""
    fig = Figure(figsize=SIZE_IN, dpi=DPI)
    ax = fig.add_axes((0.12, 0.1, 0.78, 0.8))
    ax.set_facecolor("#e8eef2")
    pts = []                                      # every north/east shown, for the limits
    outlines = []
    for v in views:
        plan = _tile_plan(v)
        if plan is not None:
            n, e, shown = plan
            ax.pcolormesh(e, n, shown, cmap=CMAP, vmin=0.0, vmax=1.0, shading="flat",
                          rasterized=True)
        corners = tile_corners_ne(v)
        ring = np.vstack([corners, corners[:1]])
        ax.plot(ring[:, 1], ring[:, 0], color="#1f4e79", lw=0.8)
        centre = corners.mean(axis=0)
        ax.annotate(v.path.stem.removeprefix("tile_"), (centre[1], centre[0]),
                    color="#1f4e79", fontsize=7, ha="center", va="center",
                    xytext=(0, 0), textcoords="offset points",
                    bbox={"boxstyle": "round,pad=0.1", "fc": "white", "alpha": 0.6,
                          "lw": 0})
        pts.append(corners)
        outlines.append((v.path.stem, corners))
        if "ping_north_m" in v.data:
            tn, te = v.data["ping_north_m"], v.data["ping_east_m"]
            ok = np.isfinite(tn) & np.isfinite(te)
            if ok.any():
                ax.plot(te[ok], tn[ok], ".", color="#555555", ms=1.5)
                pts.append(np.stack([tn[ok], te[ok]], axis=1))
    if len(track_ne):
        ax.plot(track_ne[:, 1], track_ne[:, 0], "-", color="#2a7d2e", lw=1.2,
                label="track (live)")
        pts.append(track_ne)
    if pose and pose.get("north_m") is not None and pose.get("east_m") is not None:
        pn, pe = pose["north_m"], pose["east_m"]
        ax.plot([pe], [pn], "o", color="#2a7d2e", ms=6, label="boat")
        hdg = pose.get("heading_deg")
        if hdg is not None:
            r = math.radians(hdg)
            ax.annotate("", (pe + math.sin(r), pn + math.cos(r)), (pe, pn),
                        arrowprops={"arrowstyle": "->", "color": "#2a7d2e", "lw": 1.5})
        pts.append(np.array([[pn, pe]]))
    if contacts:
        cn = np.array([c["north_m"] for c in contacts], dtype=float)
        ce = np.array([c["east_m"] for c in contacts], dtype=float)
        ax.scatter(ce, cn, s=70, facecolors="none", edgecolors="cyan", linewidths=1.4,
                   label="contacts")
        for c, n_, e_ in zip(contacts, cn, ce):
            ax.annotate(str(c["contact"]), (e_, n_), xytext=(6, 5),
                        textcoords="offset points", color="#006d6d", fontsize=8,
                        weight="bold", bbox={"boxstyle": "round,pad=0.1", "fc": "white",
                                             "alpha": 0.8, "lw": 0})
        pts.append(np.stack([cn, ce], axis=1))
    if pts:
        allp = np.vstack([p for p in pts if len(p)])
        allp = allp[np.all(np.isfinite(allp), axis=1)]
    else:
        allp = np.zeros((0, 2))
    if len(allp):
        (n0, e0), (n1, e1) = allp.min(axis=0), allp.max(axis=0)
        pad = max(2.0, 0.08 * max(n1 - n0, e1 - e0))
        half = 0.5 * max(n1 - n0, e1 - e0) + pad
        cn_, ce_ = 0.5 * (n0 + n1), 0.5 * (e0 + e1)
        ax.set_xlim(ce_ - half, ce_ + half)
        ax.set_ylim(cn_ - half, cn_ + half)
    else:
        ax.set_xlim(-10, 10)
        ax.set_ylim(-10, 10)
        ax.text(0.5, 0.5, "no tiles and no position yet", transform=ax.transAxes,
                ha="center", va="center", color="#555555")
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("east (m, survey frame)")
    ax.set_ylabel("north (m, survey frame)")
    if origin is not None:
        _latlon_grid(ax, origin)
    else:
        ax.grid(True, color="white", lw=0.6)
    ax.set_title(title, fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="lower right", fontsize=7, framealpha=0.7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    # pixels of the tile outlines in the saved image (y from the top)
    height = fig.get_figheight() * DPI
    regions = []
    for name, corners in outlines:
        xy = ax.transData.transform(np.stack([corners[:, 1], corners[:, 0]], axis=1))
        regions.append({"name": name, "points": [[round(float(x), 1),
                                                  round(float(height - y), 1)]
                                                 for x, y in xy]})
    return buf.getvalue(), regions


def _latlon_grid(ax, origin: tuple[float, float, float]) -> None:
    """Latitude and longitude lines over the axes: contours of the geodetic coordinates
    of a north/east lattice about ``origin``, labelled in degrees, minutes, seconds."""
    (e0, e1), (n0, n1) = ax.get_xlim(), ax.get_ylim()
    E, N = np.meshgrid(np.linspace(e0, e1, 60), np.linspace(n0, n1, 60))
    lat, lon, _ = ned_to_geodetic(np.stack([N, E, np.zeros_like(N)], axis=-1), origin)
    for field, pos, neg in ((lat, "N", "S"), (lon, "E", "W")):
        lo, hi = float(field.min()), float(field.max())
        step = _step(hi - lo)
        levels = np.arange(math.ceil(lo / step), math.floor(hi / step) + 1) * step
        if not len(levels):
            continue
        cs = ax.contour(E, N, field, levels=levels, colors="#7a8a99", linewidths=0.6,
                        linestyles="dashed")
        ax.clabel(cs, fmt=lambda v, p=pos, q=neg: dms(v, p, q), fontsize=6, inline=True)
