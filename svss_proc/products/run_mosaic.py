"""The run's mosaic of the tiles' plan-view MIPs: the survey-frame grid and its
composite, the UTM one for the GeoTIFF (:mod:`.georef`), the HDF5 file (CF grid
mapping, the run's stretches and array track) and the PNG map (the contacts circled,
the stretches along the swath's edges, docs/run_products.md)."""

from __future__ import annotations

import functools
import json
import logging
import math
from pathlib import Path

import h5py
import numpy as np
from matplotlib import colormaps
from PIL import Image, ImageDraw

from svss_daq.config import ProductsConfig
from svss_daq.frames import TrackLine
from svss_daq.rawfile import TIME_UNITS

from .circumstances import KINDS, LABELS, PingTrack, Stretch
from .drc import compress
from .georef import SurveyProjection, utm_grid
from .quicklook import CMAP, MARKER_RGB, NO_DATA_RGBA, PNG_COMPRESS_LEVEL, choose_labels
from .raster import Canvas, font, rgb8
from .run_views import TileView


log = logging.getLogger(__name__)

MOSAIC_PNG = "mosaic.png"
MOSAIC_H5 = "mosaic.h5"
#: most cells along either side of the mosaic grid (coarser cells beyond)
MAX_MOSAIC_CELLS = 4000


def mosaic_grid(bounds_ne: tuple[float, float, float, float], cell_m: float,
                max_cells: int = MAX_MOSAIC_CELLS) -> tuple[np.ndarray, np.ndarray, float]:
    """Cell centres (north, east; m) of a north-east grid over ``bounds_ne`` (north min,
    north max, east min, east max) at ``cell_m``, coarsened so that neither side has
    more than ``max_cells`` cells. Returns (north, east, cell)."""
    n0, n1, e0, e1 = bounds_ne
    cell = max(cell_m, (n1 - n0) / max_cells, (e1 - e0) / max_cells)
    north = n0 + (np.arange(max(1, math.ceil((n1 - n0) / cell))) + 0.5) * cell
    east = e0 + (np.arange(max(1, math.ceil((e1 - e0) / cell))) + 0.5) * cell
    return north, east, cell


def place_plan(values: np.ndarray, along: np.ndarray, cross: np.ndarray, voxel_m: float,
               line: TrackLine, north: np.ndarray, east: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """A tile's plan view ``values`` (along x cross) sampled at the grid's cell centres
    (nearest voxel): (values, NaN outside the tile; inside the tile), each (north, east)."""
    nn, ee = np.meshgrid(north, east, indexing="ij")
    return place_plan_at(values, along, cross, voxel_m, line, nn, ee)


def place_plan_at(values: np.ndarray, along: np.ndarray, cross: np.ndarray,
                  voxel_m: float, line: TrackLine, nn: np.ndarray, ee: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`place_plan` at any cell centres: survey north ``nn``, east ``ee`` (same
    shape)."""
    atd = line.ned_to_tile(np.stack([nn, ee, np.zeros_like(nn)], axis=-1))
    ia = np.floor((atd[..., 0] - (along[0] - voxel_m / 2)) / voxel_m).astype(np.int64)
    ic = np.floor((atd[..., 1] - (cross[0] - voxel_m / 2)) / voxel_m).astype(np.int64)
    inside = (ia >= 0) & (ia < along.size) & (ic >= 0) & (ic < cross.size)
    out = np.full(nn.shape, np.nan, dtype=np.float32)
    out[inside] = values[ia[inside], ic[inside]]
    return out, inside


def tile_corners_ne(view: TileView) -> np.ndarray:
    """The four plan corners (north, east; m) of a tile."""
    a, c, v = view.data["along"], view.data["cross"], view.voxel_m
    atd = np.array([[a[0] - v / 2, c[0] - v / 2, 0.0], [a[-1] + v / 2, c[0] - v / 2, 0.0],
                    [a[-1] + v / 2, c[-1] + v / 2, 0.0], [a[0] - v / 2, c[-1] + v / 2, 0.0]])
    return view.line.tile_to_ned(atd)[:, :2]


def _plan(v: TileView) -> np.ndarray | None:
    """A tile's plan view for the mosaic: its ``mip_depth``, NaN where no ping reached
    the column (None: the tile has none)."""
    d = v.data
    plan = d.get("mip_depth")
    if plan is not None and "coverage_plan" in d:
        plan = np.where(d["coverage_plan"] > 0, plan, np.nan)
    return plan


def _composite(views: list[TileView], shape: tuple[int, int], box_of, ne_of) -> dict:
    """The tiles' plan views on one grid of ``shape``: each cell from the tile that
    shows the most there. ``box_of(view)``: the (row, column) slices of the cells the
    tile may cover; ``ne_of(rows, cols)``: survey north, east of those cells' centres."""
    mip = np.full(shape, np.nan, dtype=np.float32)
    which = np.full(shape, -1, dtype=np.int32)
    imaged = np.zeros(shape, dtype=bool)
    for k, v in enumerate(views):
        plan = _plan(v)
        if plan is None:
            continue
        box = box_of(v)
        nn, ee = ne_of(*box)
        placed, inside = place_plan_at(plan, v.data["along"], v.data["cross"], v.voxel_m,
                                       v.line, nn, ee)
        cur, who = mip[box], which[box]
        better = inside & ~np.isnan(placed) & ~(placed <= cur)     # NaN-aware maximum
        cur[better] = placed[better]
        who[inside & (who < 0)] = k
        who[better] = k
        imaged[box] |= ~np.isnan(placed)
    return {"mip_db": mip, "tile": which, "imaged": imaged,
            "tiles": [v.path.name for v in views]}


def run_swath(views: list[TileView]) -> tuple[TrackLine, float, float]:
    """The run's swath: the run line (the first tile's) and the tiles' cross-track
    extent on it (from, to; m, outer voxel edges)."""
    line = views[0].line
    lo, hi = math.inf, -math.inf
    for v in views:
        c = line.ned_to_tile(np.asarray(
            [[*ne, 0.0] for ne in tile_corners_ne(v)]))[:, 1]
        lo, hi = min(lo, float(c.min())), max(hi, float(c.max()))
    return line, lo, hi


def run_mosaic(views: list[TileView]) -> dict:
    """The plan-view MIPs (dB re background) of every tile on one north-east grid:
    ``north``, ``east`` (cell centres, m), ``mip_db`` (north x east, NaN where no tile
    or no ping), ``tile`` (index of the tile shown, -1 none), ``imaged`` (a ping reached
    the column), ``cell_m``."""
    corners = np.concatenate([tile_corners_ne(v) for v in views])
    cell = min(v.voxel_m for v in views)
    north, east, cell = mosaic_grid((corners[:, 0].min(), corners[:, 0].max(),
                                     corners[:, 1].min(), corners[:, 1].max()), cell)

    def box_of(v: TileView):               # only the cells of the tile's bounding box
        cn = tile_corners_ne(v)
        i0, i1 = np.searchsorted(north, [cn[:, 0].min() - cell, cn[:, 0].max() + cell])
        j0, j1 = np.searchsorted(east, [cn[:, 1].min() - cell, cn[:, 1].max() + cell])
        return slice(i0, i1), slice(j0, j1)

    def ne_of(rows: slice, cols: slice):
        return np.meshgrid(north[rows], east[cols], indexing="ij")

    out = _composite(views, (north.size, east.size), box_of, ne_of)
    out.update({"north": north, "east": east, "cell_m": cell})
    return out


def utm_mosaic(views: list[TileView], projection: SurveyProjection) -> dict:
    """:func:`run_mosaic` on a grid of the survey's UTM zone (``projection``): ``x``
    (easting of the column centres, west to east), ``y`` (northing of the row centres,
    north to south), ``mip_db``, ``tile``, ``imaged`` (row x column), ``cell_m``,
    ``epsg``. Each cell centre is taken to the survey frame through latitude and
    longitude (:mod:`.georef`)."""
    corners = np.concatenate([tile_corners_ne(v) for v in views])
    cx, cy = projection.ne_to_utm(corners[:, 0], corners[:, 1])
    x, y, cell = utm_grid(np.stack([cx, cy], axis=1), min(v.voxel_m for v in views),
                          MAX_MOSAIC_CELLS)

    def box_of(v: TileView):
        tx, ty = projection.ne_to_utm(*tile_corners_ne(v).T)
        j0 = int(np.clip(math.floor((tx.min() - x[0]) / cell) - 1, 0, x.size))
        j1 = int(np.clip(math.ceil((tx.max() - x[0]) / cell) + 2, 0, x.size))
        i0 = int(np.clip(math.floor((y[0] - ty.max()) / cell) - 1, 0, y.size))
        i1 = int(np.clip(math.ceil((y[0] - ty.min()) / cell) + 2, 0, y.size))
        return slice(i0, i1), slice(j0, j1)

    def ne_of(rows: slice, cols: slice):
        xx, yy = np.meshgrid(x[cols], y[rows])
        return projection.utm_to_ne(xx, yy)

    out = _composite(views, (y.size, x.size), box_of, ne_of)
    out.update({"x": x, "y": y, "cell_m": cell, "epsg": projection.epsg})
    return out


def survey_grid_mapping(origin) -> dict:
    """CF grid-mapping attributes of the survey frame's north/east plane about
    ``origin`` (lat deg, lon deg, h m): a plane tangent at the origin, north and east
    from it in metres, i.e. WGS 84 azimuthal equidistant about the origin (they differ
    by r^3 / R^2: 25 um at 1 km)."""
    from pyproj import CRS
    lat, lon = float(origin[0]), float(origin[1])
    crs = CRS.from_proj4(f"+proj=aeqd +lat_0={lat!r} +lon_0={lon!r} +x_0=0 +y_0=0 "
                         "+datum=WGS84 +units=m +no_defs")
    cf = crs.to_cf()
    cf["crs_wkt"] = crs.to_wkt()
    return cf


def _write_stretches_h5(f: h5py.File, track: PingTrack | None,
                        found: list[Stretch]) -> None:
    """The run's stretches as a table (group ``stretches``, dimension ``stretch``) and
    the array's track they lie on (group ``track``, dimension ``ping``)."""
    g = f.create_group("stretches")
    g.attrs["long_name"] = ("the run's stretches of missing pings, dead-reckoned and "
                            "held poses (docs/run_products.md, Circumstances)")
    idx = g.create_dataset("stretch", data=np.arange(len(found), dtype=np.int64))
    idx.attrs.update({"units": "1", "long_name": "stretch number"})
    idx.make_scale("stretch")
    text = h5py.string_dtype()
    cols = (("kind", np.array([x.kind for x in found], dtype=object), text, "",
             "missing, dead_reckoned or held"),
            ("first_sequence", [x.first_sequence for x in found], np.int64, "1",
             "first ping of the stretch (a gap's first missing ping)"),
            ("last_sequence", [x.last_sequence for x in found], np.int64, "1",
             "last ping of the stretch"),
            ("pings", [x.pings for x in found], np.int64, "1", "pings in the stretch"),
            ("start_time", [x.start_ns for x in found], np.int64, TIME_UNITS,
             "time of the stretch's first ping (UTC; a gap's interpolated)"),
            ("end_time", [x.end_ns for x in found], np.int64, TIME_UNITS,
             "time of the stretch's last ping"),
            ("start_north_m", [float(x.north_m[0]) for x in found], np.float64, "m",
             "north where the stretch's line starts (the array's track, survey frame)"),
            ("start_east_m", [float(x.east_m[0]) for x in found], np.float64, "m",
             "east where the stretch's line starts"),
            ("end_north_m", [float(x.north_m[-1]) for x in found], np.float64, "m",
             "north where the stretch's line ends"),
            ("end_east_m", [float(x.east_m[-1]) for x in found], np.float64, "m",
             "east where the stretch's line ends"))
    for name, data, dtype, units, long_name in cols:
        ds = g.create_dataset(name, data=np.asarray(data, dtype=dtype) if dtype is not text
                              else data, dtype=dtype, shape=(len(found),))
        ds.attrs.update({"units": units, "long_name": long_name})
        if units == TIME_UNITS:
            ds.attrs.update({"standard_name": "time", "calendar": "standard"})
        ds.dims[0].attach_scale(idx)
    if track is None:
        return
    t = f.create_group("track")
    t.attrs["long_name"] = ("the run's imaged pings where the array was (the projectors' "
                            "mean position)")
    seq = t.create_dataset("ping", data=track.sequence)
    seq.attrs.update({"units": "1", "long_name": "ping sequence number"})
    seq.make_scale("ping")
    for name, data, units, long_name in (
            ("time", track.time_ns, TIME_UNITS, "transmit time of the ping (UTC)"),
            ("north_m", track.north_m, "m", "the array's north (survey frame)"),
            ("east_m", track.east_m, "m", "the array's east (survey frame)"),
            ("nav_flags", track.flags, "1", "the navigation's NAV_* flags of the pose "
                                            "(0 where not known: see flags_known)"),
            ("flags_known", track.known.astype(np.uint8), "1",
             "the ping's tile kept its navigation flags")):
        ds = t.create_dataset(name, data=data)
        ds.attrs.update({"units": units, "long_name": long_name})
        if units == TIME_UNITS:
            ds.attrs.update({"standard_name": "time", "calendar": "standard"})
        ds.dims[0].attach_scale(seq)


def write_mosaic_h5(path: Path, m: dict, origin, track: PingTrack | None = None,
                    found: list[Stretch] = ()) -> Path:
    """The run mosaic on the survey frame's north/east grid; with a survey ``origin``
    its CF grid mapping (variable ``crs``, :func:`survey_grid_mapping`), so that a GIS
    or xarray places it (the GeoTIFF is the same mosaic on a UTM grid); the run's
    stretches ``found`` as a table and the array's ``track``
    (:func:`_write_stretches_h5`)."""
    with h5py.File(path, "w") as f:
        f.attrs.update({"title": "SVSS run mosaic: plan-view MIP of the tiles",
                        "cell_m": m["cell_m"], "tiles": json.dumps(m["tiles"]),
                        "survey_origin_lat_lon_h": (np.asarray(origin, dtype=np.float64)
                                                    if origin is not None else np.nan)})
        for name, units, std in (("north", "m", "projection_y_coordinate"),
                                 ("east", "m", "projection_x_coordinate")):
            ds = f.create_dataset(name, data=m[name])
            ds.attrs.update({"units": units, "standard_name": std,
                             "long_name": f"{name} of the survey origin (survey frame)"})
            ds.make_scale(name)
        mapping = None
        if origin is not None and np.all(np.isfinite(np.asarray(origin, dtype=float)[:2])):
            crs = f.create_dataset("crs", data=np.int32(0))
            for k, v in survey_grid_mapping(origin).items():
                crs.attrs[k] = v
            mapping = "crs"
        for name, units, long_name in (
                ("mip_db", "dB re background", ("maximum over depth and tiles of the "
                                                "normalised level plus display gain")),
                ("tile", "1", "index of the tile shown (-1: none)"),
                ("imaged", "1", "a ping reached the column")):
            ds = f.create_dataset(name, data=m[name].astype(np.uint8) if name == "imaged"
                                  else m[name], compression="gzip", compression_opts=1)
            ds.attrs.update({"units": units, "long_name": long_name})
            if mapping:
                ds.attrs["grid_mapping"] = mapping
            ds.dims[0].attach_scale(f["north"])
            ds.dims[1].attach_scale(f["east"])
        _write_stretches_h5(f, track, list(found))
    return path


#: the mosaic's layout, inches: left margin (the y axis), title block, bottom (the x
#: axis), the colour bar's gap, width and room for its labels
MOSAIC_LEFT_IN, MOSAIC_TOP_IN, MOSAIC_BOTTOM_IN = 0.95, 0.45, 0.6
MOSAIC_BAR_GAP_IN, MOSAIC_BAR_W_IN, MOSAIC_BAR_LABELS_IN = 0.3, 0.2, 1.1
#: the contacts' circles on the mosaic, points (diameter)
MOSAIC_MARKER_PT = 8.0
#: the map's colours (RGB) of the stretches and of the array's track, and their widths
#: (points); the legend's row height and its items' line length (inches)
STRETCH_RGB = {"missing": (0.1, 0.9, 0.1), "dead_reckoned": (0.25, 0.55, 1.0),
               "held": (1.0, 0.55, 0.0)}
TRACK_RGB = (0.9, 0.9, 0.9)
STRETCH_PT, TRACK_PT = 3.0, 0.75
LEGEND_ROW_IN, LEGEND_LINE_IN = 0.22, 0.3


@functools.lru_cache(maxsize=1)
def mosaic_palette() -> tuple[int, ...]:
    """The map's 256 colours: the colour map at 220 levels, greys, white, black, the
    marker cyan, the no-data colour and the few others the quicklooks use
    (:func:`.quicklook._palette`), and the stretches' colours (:data:`STRETCH_RGB`)."""
    cols = [tuple(c) for c in colormaps[CMAP](np.linspace(0.0, 1.0, 220))[:, :3]]
    cols += [(g, g, g) for g in np.linspace(0.0, 1.0, 24)]
    cols += [(0.0, 1.0, 1.0), (0.0, 0.75, 0.75), (0.5, 1.0, 1.0), NO_DATA_RGBA[:3],
             (0.15, 0.15, 0.15), (0.6, 0.6, 0.6), (0.3, 0.3, 0.3), TRACK_RGB]
    cols += [STRETCH_RGB[k] for k in KINDS]
    return tuple(int(round(255 * v)) for c in cols[:256] for v in c)


def _legend_items(found: list[Stretch]) -> list[tuple[tuple, str]]:
    """(colour, text) of the map's legend: the array's track, then each kind of
    stretch with the run's count of its pings."""
    items = [(TRACK_RGB, "array track")]
    for k in KINDS:
        n = sum(x.pings for x in found if x.kind == k)
        items.append((STRETCH_RGB[k], f"{LABELS[k]}: {n} ping{'' if n == 1 else 's'}"))
    return items


def _legend_rows(items, width_in: float, dpi: int, size_pt: float = 7.0) -> list[list]:
    """The legend's items in rows that fit ``width_in`` (each item: its line, a gap,
    its text, a gap)."""
    f = font("sans", size_pt * dpi / 72.0)
    rows: list[list] = [[]]
    used = 0.0
    for colour, text in items:
        w = LEGEND_LINE_IN + 0.08 + f.getlength(text) / dpi + 0.25
        if rows[-1] and used + w > width_in:
            rows.append([])
            used = 0.0
        rows[-1].append((colour, text, w))
        used += w
    return rows


def _on_edges(st: Stretch, swath, inset_m: float = 0.0
              ) -> list[tuple[np.ndarray, np.ndarray]]:
    """A stretch's line moved onto both edges of the swath (``swath``: the run line and
    the tiles' cross-track extent, m), ``inset_m`` inside them, so that it marks the
    stretch of the image without covering it; as it is without a swath."""
    if swath is None:
        return [(st.north_m, st.east_m)]
    line, lo, hi = swath
    atd = line.ned_to_tile(np.stack([st.north_m, st.east_m, np.zeros(st.north_m.size)],
                                    axis=1))
    out = []
    for c in (lo + inset_m, hi - inset_m):
        atd[:, 1] = c
        ne = line.tile_to_ned(atd)
        out.append((ne[:, 0], ne[:, 1]))
    return out


def _draw_track(canvas: Canvas, v, track: PingTrack, found: list[Stretch], swath) -> None:
    """The array's track and its stretches (on the swath's edges, :func:`_on_edges`) on
    the view ``v`` (clipped to it)."""
    layer = Image.new("RGBA", (v.w, v.h), (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)

    def line(north, east, colour, width_pt):
        if len(north) < 2:
            return
        xy = v.to_px(east, north) - np.array([v.x0, v.y0])
        draw.line([tuple(p) for p in xy.tolist()], fill=(*rgb8(colour), 255),
                  width=max(1, int(round(canvas.px(width_pt)))), joint="curve")
    # the track between successive imaged pings, not across a gap (the gap is drawn)
    cut = np.flatnonzero(np.diff(track.sequence) > 1) + 1
    for n, e in zip(np.split(track.north_m, cut), np.split(track.east_m, cut)):
        line(n, e, TRACK_RGB, TRACK_PT)
    # the stretches' lines just inside the swath's edges (half their width in metres)
    inset = 0.5 * canvas.px(STRETCH_PT) * (v.xe[1] - v.xe[0]) / max(v.w, 1)
    for st in found:
        for n, e in _on_edges(st, swath, inset):
            line(n, e, STRETCH_RGB[st.kind], STRETCH_PT)
    canvas.image.paste(layer, (v.x0, v.y0), layer)


def write_mosaic_png(path: Path, m: dict, contacts: list[dict], pcfg: ProductsConfig,
                     title: str, max_labels: int, track: PingTrack | None = None,
                     found: list[Stretch] = (), swath=None) -> Path:
    """The plan-view mosaic as a palette PNG, drawn as the tiles' quicklooks are
    (:mod:`svss_proc.products.raster`): north up, east right, at true scale (at most 9
    inches a side and 300 inches a metre), the numbered contacts circled, a colour
    bar in dB re background; with the run's pings (``track``, where the array was) the
    array's track, its stretches ``found`` in their colours (:data:`STRETCH_RGB`) along
    both edges of the ``swath`` (the run line, the tiles' cross-track extent from and
    to, m; None: on the track) and a legend under the map."""
    found = list(found)
    show_track = track is not None and len(track) > 0
    d = pcfg.drc
    img = compress(m["mip_db"], d.floor_db, d.knee_db, d.ceiling_db)
    img = np.where(np.isnan(m["mip_db"]), np.nan, img)
    cell = m["cell_m"]
    n, e = m["north"], m["east"]
    ee = (float(e[0] - cell / 2), float(e[-1] + cell / 2))
    ne = (float(n[0] - cell / 2), float(n[-1] + cell / 2))
    w, h = ee[1] - ee[0], ne[1] - ne[0]
    scale = min(9.0 / max(w, 1e-6), 9.0 / max(h, 1e-6), 300.0)
    view_w, view_h = w * scale, h * scale
    width_in = (MOSAIC_LEFT_IN + max(view_w, 3.5) + MOSAIC_BAR_GAP_IN + MOSAIC_BAR_W_IN
                + MOSAIC_BAR_LABELS_IN)
    rows = (_legend_rows(_legend_items(found), width_in - MOSAIC_LEFT_IN,
                         pcfg.quicklook.dpi) if show_track else [])
    canvas = Canvas(width_in, MOSAIC_TOP_IN + max(view_h, 2.0) + MOSAIC_BOTTOM_IN
                    + len(rows) * LEGEND_ROW_IN + (0.1 if rows else 0.0),
                    pcfg.quicklook.dpi)
    rgba = colormaps[CMAP](np.nan_to_num(img, nan=0.0))
    rgba[np.isnan(img) & (m["tile"] >= 0)] = (0.6, 0.6, 0.6, 1.0)    # in a tile, no ping
    rgba[m["tile"] < 0] = (1.0, 1.0, 1.0, 1.0)                        # outside every tile
    v = canvas.view(canvas.box(MOSAIC_LEFT_IN, MOSAIC_TOP_IN, view_w, view_h),
                    np.transpose(rgba, (1, 0, 2)), ee, ne, y_down=False)
    canvas.x_axis(v, "east (m, survey frame)")
    canvas.y_axis(v, "north (m, survey frame)")
    canvas.text((v.x0 + v.w / 2, v.y0 - canvas.px(4)), title, 9, "md")
    if show_track:
        _draw_track(canvas, v, track, found, swath)
        top = MOSAIC_TOP_IN + max(view_h, 2.0) + MOSAIC_BOTTOM_IN + 0.05
        for r, row in enumerate(rows):
            x = MOSAIC_LEFT_IN
            y = (top + (r + 0.5) * LEGEND_ROW_IN) * canvas.dpi
            for colour, text, item_w in row:
                x0, x1 = x * canvas.dpi, (x + LEGEND_LINE_IN) * canvas.dpi
                half = canvas.px(4.0)           # on a dark patch, as on the map
                canvas.draw.rectangle((x0, y - half, x1, y + half), fill=(38, 38, 38))
                canvas.draw.line((x0, y, x1, y), fill=rgb8(colour), width=max(1, int(round(
                    canvas.px(TRACK_PT if colour == TRACK_RGB else STRETCH_PT)))))
                canvas.text((x0 + (LEGEND_LINE_IN + 0.08) * canvas.dpi, y), text, 7, "lm")
                x += item_w
    xy = v.to_px([c["east_m"] for c in contacts], [c["north_m"] for c in contacts])
    chosen = choose_labels(xy, max_labels)
    canvas.circles(xy[chosen], MOSAIC_MARKER_PT, MARKER_RGB, 1.0, v)
    off = canvas.px(4.0)
    for i in chosen:
        canvas.text((xy[i, 0] + off, xy[i, 1] - off), str(contacts[i]["contact"]), 7, "ls",
                    fill=rgb8(MARKER_RGB))
    levels = [lv for lv in (d.floor_db, 0.0, 10.0, d.knee_db, d.ceiling_db) if lv >= d.floor_db]
    bar_h = 0.8 * max(view_h, 2.0)
    canvas.colour_bar(canvas.box(MOSAIC_LEFT_IN + view_w + MOSAIC_BAR_GAP_IN,
                                 MOSAIC_TOP_IN + (view_h - bar_h) / 2 if view_h > bar_h
                                 else MOSAIC_TOP_IN, MOSAIC_BAR_W_IN, bar_h),
                      colormaps[CMAP](np.linspace(0.0, 1.0, 256)),
                      compress(np.asarray(levels, dtype=np.float64), d.floor_db, d.knee_db,
                               d.ceiling_db), [f"{lv:g}" for lv in levels],
                      "plan-view MIP, dB re background\n(grey: no ping)")
    canvas.save_palette_png(path, mosaic_palette(), PNG_COMPRESS_LEVEL)
    return path
