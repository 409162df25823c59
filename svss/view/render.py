"""The survey map of ``svss view``, drawn server-side with matplotlib as a PNG: the tiles'
plan-view MIPs placed in north/east (survey frame) by their track lines, the tile
outlines, the track (the tiles' pings and the live poses of the status stream), the
boat's last position and heading, the run's contacts, and a latitude/longitude grid
drawn as contours of the geodetic coordinates over the north/east plane (exact in the
survey frame, whatever its size)."""

from __future__ import annotations

import functools
import io
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from svss_daq.navigation import ned_to_geodetic  # noqa: E402
from svss_proc.products.drc import compress  # noqa: E402
from svss_proc.products.quicklook import CMAP  # noqa: E402
from svss_proc.products.run_products import (TileView, _configs,  # noqa: E402
                                             tile_corners_ne)

#: the map's size, inches at DPI
SIZE_IN = (7.5, 6.5)
DPI = 100
#: a tile narrower than this on the map is drawn without its number, pixels
LABEL_MIN_PX = 28
#: the map's axes in the figure (left, bottom, width, height), fractions
AXES = (0.12, 0.1, 0.78, 0.8)
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


def block_max(x: np.ndarray, k: int) -> np.ndarray:
    """``x`` (2-D) reduced by the maximum over ``k`` x ``k`` blocks (edge blocks
    partial): a MIP seen at a coarser scale keeps its peaks."""
    if k <= 1:
        return x
    na, nc = x.shape
    pad = np.full((-(-na // k) * k, -(-nc // k) * k), -np.inf, dtype=np.float32)
    pad[:na, :nc] = np.where(np.isfinite(x), x, -np.inf)
    out = pad.reshape(pad.shape[0] // k, k, pad.shape[1] // k, k).max(axis=(1, 3))
    return np.where(np.isfinite(out), out, np.nan)


def _edges(axis: np.ndarray, vox: float, k: int) -> np.ndarray:
    """Cell edges of ``axis`` (voxel centres) grouped ``k`` by ``k``."""
    e = np.concatenate([axis - vox / 2, axis[-1:] + vox / 2])
    idx = np.arange(0, axis.size, k)
    return np.concatenate([e[idx], e[-1:]])


@functools.lru_cache(maxsize=16)
def _drc(processing_toml: str | None) -> tuple[float, float, float] | None:
    """(floor, knee, ceiling) dB of the quicklooks' compression in a tile's processing
    configuration (the tiles of a run share it: read once), None without products."""
    pcfg = _configs(TileView(Path("tile"), {"processing_config_toml": processing_toml}))[0]
    return None if pcfg is None else (pcfg.drc.floor_db, pcfg.drc.knee_db,
                                      pcfg.drc.ceiling_db)


def _tile_plan(v: TileView, m_per_px: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(north, east) of a tile's plan-view cell corners and its compressed depth MIP
    (0..1), blocks of voxels merged (their maximum) where a voxel is smaller than half
    a pixel of the map (``m_per_px``); None for a tile without products."""
    mip = v.data.get("mip_depth")
    if mip is None:
        return None
    drc = _drc(v.data.get("processing_config_toml"))
    a, c, vox = v.data["along"], v.data["cross"], v.voxel_m
    k = max(1, int(0.5 * m_per_px / vox))
    mip = block_max(np.asarray(mip, dtype=np.float32), k)
    A, C = np.meshgrid(_edges(a, vox, k), _edges(c, vox, k), indexing="ij")
    ned = v.line.tile_to_ned(np.stack([A.ravel(), C.ravel(), np.zeros(A.size)], axis=1))
    north, east = ned[:, 0].reshape(A.shape), ned[:, 1].reshape(A.shape)
    if drc is not None:
        shown = compress(mip, *drc)
    else:
        lo, hi = np.nanpercentile(mip, [5, 99.9]) if np.isfinite(mip).any() else (0, 1)
        shown = np.clip((mip - lo) / max(hi - lo, 1e-9), 0, 1)
    return north, east, shown


def _limits(pts: list[np.ndarray]) -> tuple[float, float, float] | None:
    """(centre north, centre east, half side) of a square holding every point, with a
    margin; None without points."""
    pts = [p for p in pts if len(p)]
    if not pts:
        return None
    allp = np.vstack(pts)
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    if not len(allp):
        return None
    (n0, e0), (n1, e1) = allp.min(axis=0), allp.max(axis=0)
    span = max(n1 - n0, e1 - e0)
    return 0.5 * (n0 + n1), 0.5 * (e0 + e1), 0.5 * span + max(2.0, 0.08 * span)


def survey_map_png(views: list[TileView], contacts: list[dict], track_ne: np.ndarray,
                   pose: dict | None, origin: tuple[float, float, float] | None,
                   title: str) -> tuple[bytes, list[dict]]:
    """The map as PNG bytes, and each tile's outline in the image's pixels (x right, y
    down: ``{"name", "points": [[x, y], ...]}``) for the page to open a tile clicked on
    it. ``track_ne``: (n, 2) north, east of the live poses; ``pose``: the status's
    ``navigation.pose`` (the boat's position and heading), or None."""
    fig = Figure(figsize=SIZE_IN, dpi=DPI)
    ax = fig.add_axes(AXES)
    ax.set_facecolor("#e8eef2")
    # what is shown, north/east: the limits first (the tiles are drawn at their scale)
    corners = [tile_corners_ne(v) for v in views]
    tracks = []
    for v in views:
        if "ping_north_m" in v.data:
            tn, te = v.data["ping_north_m"], v.data["ping_east_m"]
            ok = np.isfinite(tn) & np.isfinite(te)
            tracks.append(np.stack([tn[ok], te[ok]], axis=1))
    boat = None
    if pose and isinstance(pose.get("north_m"), (int, float)) \
            and isinstance(pose.get("east_m"), (int, float)):
        boat = np.array([[pose["north_m"], pose["east_m"]]], dtype=float)
    cne = (np.array([[c["north_m"], c["east_m"]] for c in contacts], dtype=float)
           .reshape(-1, 2))
    lim = _limits([*corners, *tracks, track_ne.reshape(-1, 2), cne,
                   np.zeros((0, 2)) if boat is None else boat])
    if lim is None:
        cn, ce, half = 0.0, 0.0, 10.0
        ax.text(0.5, 0.5, "no tiles and no position yet", transform=ax.transAxes,
                ha="center", va="center", color="#555555")
    else:
        cn, ce, half = lim
    ax.set_xlim(ce - half, ce + half)
    ax.set_ylim(cn - half, cn + half)
    ax.set_aspect("equal", adjustable="box")
    m_per_px = 2 * half / (AXES[2] * SIZE_IN[0] * DPI)
    # every tile's cells in one collection of quadrilaterals, the outlines in another:
    # one artist each, however many tiles the run has
    quads, values = [], []
    for v in views:
        plan = _tile_plan(v, m_per_px)
        if plan is not None:
            n, e, shown = plan
            xy = np.stack([e, n], axis=-1)
            quads.append(np.stack([xy[:-1, :-1], xy[1:, :-1], xy[1:, 1:], xy[:-1, 1:]],
                                  axis=2).reshape(-1, 4, 2))
            values.append(np.asarray(shown, dtype=float).ravel())
    if quads:
        cells = PolyCollection(np.concatenate(quads), array=np.concatenate(values),
                               cmap=CMAP, edgecolors="none", antialiased=False)
        cells.set_clim(0.0, 1.0)
        ax.add_collection(cells, autolim=False)
    ax.add_collection(LineCollection(
        [np.vstack([c, c[:1]])[:, ::-1] for c in corners], colors="#1f4e79",
        linewidths=0.8), autolim=False)
    for v, corner in zip(views, corners):
        if np.ptp(corner, axis=0).min() < LABEL_MIN_PX * m_per_px:
            continue                      # too small on this map to carry its number
        centre = corner.mean(axis=0)
        ax.annotate(v.path.stem.removeprefix("tile_"), (centre[1], centre[0]),
                    color="#1f4e79", fontsize=7, ha="center", va="center",
                    bbox={"boxstyle": "round,pad=0.1", "fc": "white", "alpha": 0.6,
                          "lw": 0})
    if tracks:
        t = np.vstack(tracks)
        ax.plot(t[:, 1], t[:, 0], ".", color="#555555", ms=1.5)
    if len(track_ne):
        ax.plot(track_ne[:, 1], track_ne[:, 0], "-", color="#2a7d2e", lw=1.2,
                label="track (live)")
    if boat is not None:
        pn, pe = boat[0]
        ax.plot([pe], [pn], "o", color="#2a7d2e", ms=6, label="boat")
        hdg = pose.get("heading_deg")
        if isinstance(hdg, (int, float)):
            r, arrow = math.radians(hdg), 0.06 * half
            ax.annotate("", (pe + arrow * math.sin(r), pn + arrow * math.cos(r)), (pe, pn),
                        arrowprops={"arrowstyle": "->", "color": "#2a7d2e", "lw": 1.5})
    if len(cne):
        ax.scatter(cne[:, 1], cne[:, 0], s=70, facecolors="none", edgecolors="cyan",
                   linewidths=1.4, label="contacts")
        for c, (n_, e_) in zip(contacts, cne):
            ax.annotate(str(c["contact"]), (e_, n_), xytext=(6, 5),
                        textcoords="offset points", color="#006d6d", fontsize=8,
                        weight="bold", bbox={"boxstyle": "round,pad=0.1", "fc": "white",
                                             "alpha": 0.8, "lw": 0})
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
    for v, corner in zip(views, corners):
        xy = ax.transData.transform(np.stack([corner[:, 1], corner[:, 0]], axis=1))
        regions.append({"name": v.path.stem, "points": [[round(float(x), 1),
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
        ax.clabel(cs, fmt=lambda v, p=pos, q=neg: dms(v, p, q), fontsize=7, inline=True)
