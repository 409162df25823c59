"""Run-level products of a folder of tiles: the run's contact list (CSV and GeoJSON, with
latitude and longitude) and a mosaic of the tiles' plan-view MIPs (PNG and HDF5); with a
survey origin, the map products in its UTM zone (:mod:`.georef`: the mosaic as a
GeoTIFF, the contacts as a GeoPackage layer).

Each contact names its run (the tiles' ``run_id``), its tile and the UTC time of the
closest pass (:func:`closest_pass` on the run's ping track, :func:`run_track`); values
are rounded to their meaningful precision (:data:`CONTACT_FIELDS`).

Contacts (docs/products.md "Run products"). Each tile's detections are placed in the
survey frame through the tile's line, then into the run frame (the first tile's line),
and filtered across tiles, which a tile alone cannot do:

1. coverage: a contact whose peak voxel was imaged by fewer pings than
   ``min_coverage_fraction`` of the run's full coverage at its depth (the most pings any
   voxel of that depth got in any tile) is dropped (a tile at the start or end of a run
   measures its fraction against itself only);
2. one object: contacts of neighbouring tiles within ``merge_m`` (per axis) are one
   (the same object seen in two tiles), strongest peak first;
3. sidelobes: a contact ``sidelobe_db`` weaker (peak magnitude) than a stronger one
   within its sidelobe region (:func:`svss_proc.products.detect.is_sidelobe`), whichever
   tile each is in, is dropped.

Circumstances (:mod:`.circumstances`): the run's pings (every tile's, with the
navigation flags its tiles kept) placed where the array was, give the run's stretches of
missing pings, dead-reckoned and held poses; each contact counts those among the pings
that could see it (:func:`contact_circumstances`), the map draws them along the array's
track, the GeoJSON carries them as LineStrings and ``mosaic.h5`` as a table.

Latitude and longitude: survey NED to geodetic through
:func:`svss_daq.navigation.ned_to_geodetic` about the survey origin: the one given, or
else the one recovered from a ping's geodetic position recorded in a tile
(``geodetic_ref``); without either they are empty (CSV) or the feature has a null
geometry (GeoJSON). GeoJSON follows RFC 7946: WGS-84, [longitude, latitude].

Pure geometry (:func:`filter_contacts`, :func:`survey_origin`, :func:`mosaic_grid`) is
kept apart from the file handling (:func:`write_run_products`).
"""

from __future__ import annotations

import csv
import functools
import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from matplotlib import colormaps
from PIL import Image, ImageDraw

from svss_daq.config import (
    ConfigError,
    HardwareConfig,
    ImagingConfig,
    ProcessingConfig,
    ProductsConfig,
    loads,
)
from svss_daq.frames import TrackLine
from svss_daq.geometry import array_geometry, cone_radius
from svss_daq.navigation import geodetic_to_ned, ned_to_geodetic
from svss_daq.rawfile import TIME_UNITS
from svss_daq.untrusted_hdf5 import run_id_attr

from ..tiles import (TileFileError, finished_tile_paths, read_tile_views,
                     temporary_path, tile_line)
from .chain import coverage_settings, footprint_for
from .circumstances import (FALLBACK_REACH_M, KINDS, LABELS, PingTrack, Stretch,
                            circumstances_text, counts_near, is_partial, ping_track,
                            stretches)
from .detect import Footprint, is_later_echo, sidelobe_filter
from .drc import compress
from .georef import (CONTACTS_GPKG, MOSAIC_TIF, SurveyProjection, utm_grid,
                     write_contacts_gpkg, write_mosaic_geotiff, write_stretches_gpkg)
from .quicklook import CMAP, MARKER_RGB, NO_DATA_RGBA, PNG_COMPRESS_LEVEL, choose_labels
from .raster import Canvas, font, rgb8

log = logging.getLogger(__name__)

CONTACTS_CSV = "contacts.csv"
CONTACTS_GEOJSON = "contacts.geojson"
MOSAIC_PNG = "mosaic.png"
MOSAIC_H5 = "mosaic.h5"
#: most cells along either side of the mosaic grid (coarser cells beyond)
MAX_MOSAIC_CELLS = 4000

#: contact columns: (name, units, meaning, decimals written: None not a float). The
#: decimals are the meaningful precision: 1e-7 deg (1 cm) for latitude and longitude,
#: 1 mm for positions and sizes (the detections' sub-voxel peaks on 2 cm voxels),
#: 0.01 dB, 0.001 of coverage; the tiles' float32 values carry no more.
CONTACT_FIELDS = (
    ("contact", "1", "contact number in the run, strongest excess first", None),
    ("run_id", "", "the run (survey line) the contact was found in (empty: not known)",
     None),
    ("tile", "", "tile file the contact was detected in", None),
    ("time_utc", "", ("UTC time of the closest pass: when the body origin was "
                      "horizontally closest to the peak, on the run's ping track (ISO "
                      "8601, ms; empty: tiles written before their pings' track was "
                      "kept)"), None),
    ("latitude_deg", "deg", "WGS-84 latitude of the peak (empty: no geodetic origin)", 7),
    ("longitude_deg", "deg", "WGS-84 longitude of the peak", 7),
    ("depth_below_seabed_m", "m", "depth of the peak below the water-sediment interface",
     3),
    ("size_along_m", "m", "along-track extent above the threshold", 3),
    ("size_cross_m", "m", "cross-track extent above the threshold", 3),
    ("size_depth_m", "m", "depth extent above the threshold", 3),
    ("excess_db", "dB", ("signal excess: the level at the peak over the local background "
                         "(3-D median of the image magnitude), dB"), 2),
    ("threshold_db", "dB", ("the detection threshold at the peak's depth: the configured "
                            "one, or that depth layer's own from its clutter's tail "
                            "(layer_false_alarms_per_m3), dB re background"), 2),
    ("expected_false_alarms", "1", ("voxels of the peak's depth layer in its tile expected "
                                    "at the contact's level or above from that layer's "
                                    "clutter (its fitted tail; three significant digits; "
                                    "empty: no fit): the contact's local false-alarm "
                                    "estimate"), None),
    ("north_m", "m", "survey-frame north of the peak", 3),
    ("east_m", "m", "survey-frame east of the peak", 3),
    ("along_m", "m", "along-track position in the run frame (the first tile's line)", 3),
    ("cross_m", "m", "cross-track position in the run frame, starboard positive", 3),
    ("closest_pass_m", "m", ("horizontal distance from the body origin to the peak at the "
                             "closest pass"), 3),
    ("coverage_fraction", "1", ("pings that imaged the peak over the run's full coverage "
                                "at its depth"), 3),
    ("pings_missing", "1", ("missing pings (sequence gaps) among the pings that could see "
                            "the contact: placed on the track of their gap, within the "
                            "projector cone's horizontal reach of it"), None),
    ("poses_dead_reckoned", "1", ("dead-reckoned poses (no GPS fix: NAV_DEAD_RECKONED) "
                                  "among the pings that could see it"), None),
    ("poses_held", "1", "held poses (NAV_HELD) among the pings that could see it", None),
    ("circumstances", "", ("what happened around the contact in words, empty when "
                           "nothing did: e.g. 'gap 8 pings; dead-reckoned 30 poses; held "
                           "2 poses; partial coverage' (coverage_fraction under 0.75)"),
     None),
    ("tile_row", "1", "row of the tile's detection table", None),
    ("n_tiles", "1", "tiles whose detections were merged into the contact", None),
)
_DECIMALS = {name: d for name, _, _, d in CONTACT_FIELDS}


def _rounded(name: str, value):
    """A contact column's value at its meaningful precision (NaN stays NaN)."""
    d = _DECIMALS.get(name)
    if d is None or not isinstance(value, float) or not math.isfinite(value):
        return value
    return round(value, d)


@dataclass
class TileView:
    """What the run products need of one tile: its file, header (:func:`read_tile_header`
    keys), MIPs and coverage plan."""
    path: Path
    data: dict

    @property
    def line(self) -> TrackLine:
        return tile_line(self.data["attrs"])

    @property
    def voxel_m(self) -> float:
        return float(self.data["attrs"]["voxel_m"])


def load_views(tiles_dir: str | Path) -> list[TileView]:
    """Every tile of ``tiles_dir`` (:func:`read_tile_views`)."""
    return [TileView(p, read_tile_views(p)) for p in finished_tile_paths(tiles_dir)]


# ----------------------------------------------------------------------- geometry


def survey_origin(ref: tuple[float, float, float, float, float],
                  iterations: int = 6) -> tuple[float, float, float]:
    """The survey origin (lat deg, lon deg, ellipsoidal height m) of a frame in which a
    point at (``ref`` lat, lon) has survey NED (``ref`` north, east, down): the origin
    whose :func:`~svss_daq.navigation.geodetic_to_ned` gives the point that NED. The
    point's height is taken as ``-down`` (origin height 0: heights move latitude and
    longitude by far less than a millimetre)."""
    lat, lon, n, e, d = (float(v) for v in ref)
    point = (lat, lon, -d)
    ned = np.array([n, e, d])
    lat0, lon0, h0 = ned_to_geodetic(-ned, point)          # first guess
    origin = (float(lat0), float(lon0), float(h0))
    for _ in range(iterations):
        err = geodetic_to_ned(*point, origin) - ned
        lat0, lon0, h0 = ned_to_geodetic(err, origin)
        origin = (float(lat0), float(lon0), float(h0))
    return origin


def _depth_index(depth_axis: np.ndarray, z: float) -> int:
    return int(np.clip(np.argmin(np.abs(depth_axis - z)), 0, depth_axis.size - 1))


def filter_contacts(rows: list[dict], full_pings: np.ndarray | None, depth_axis: np.ndarray,
                    min_fraction: float, merge_m, sidelobe_db: float, sidelobe_m: float,
                    footprint: Footprint | None, later_echo_m=None) -> list[dict]:
    """The run's contacts from the tiles' detections (``rows``: dicts with ``run_m``
    (along, cross, depth in the run frame), ``peak_db``, ``coverage_pings``, extents,
    ...): coverage against the run's full coverage per depth ``full_pings`` (None:
    none known), merge across tiles, sidelobes across tiles (module docstring).
    Returns the kept rows (``n_tiles`` and ``coverage_fraction`` set), strongest
    excess first."""
    kept = []
    for r in rows:
        if full_pings is not None and r["coverage_pings"] > 0:
            ref = float(full_pings[_depth_index(depth_axis, r["depth_m"])])
            r["coverage_fraction"] = r["coverage_pings"] / ref if ref > 0 else 0.0
            if r["coverage_fraction"] < min_fraction:
                continue
        else:
            r["coverage_fraction"] = float("nan")
        kept.append(r)
    kept.sort(key=lambda r: -r["peak_db"])
    merge = np.asarray(merge_m, dtype=np.float64)
    merged: list[dict] = []
    for r in kept:
        for m in merged:
            if r["tile"] != m["tile"] and np.all(np.abs(r["run_m"] - m["run_m"]) <= merge):
                m["lo"] = np.minimum(m["lo"], r["run_m"] - r["half"])
                m["hi"] = np.maximum(m["hi"], r["run_m"] + r["half"])
                m["n_tiles"] += 1
                break
        else:
            r["n_tiles"] = 1
            r["lo"], r["hi"] = r["run_m"] - r["half"], r["run_m"] + r["half"]
            merged.append(r)
    if not merged:
        return []
    keep = sidelobe_filter(np.array([m["run_m"] for m in merged]),
                           np.array([m["peak_db"] for m in merged]), sidelobe_db,
                           sidelobe_m, footprint)
    out: list[dict] = []
    for r in (m for m, k in zip(merged, keep) if k):      # strongest peak first
        for m in out:
            if is_later_echo(r["run_m"], m["run_m"], later_echo_m):
                m["lo"] = np.minimum(m["lo"], r["lo"])
                m["hi"] = np.maximum(m["hi"], r["hi"])
                break
        else:
            out.append(r)
    out.sort(key=lambda r: -r["excess_db"])
    return out


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


# ----------------------------------------------------------------------- settings


def _configs(view: TileView) -> tuple[ProductsConfig | None, HardwareConfig | None,
                                       ImagingConfig | None]:
    out = []
    for key, cls in (("processing_config_toml", ProcessingConfig),
                     ("hardware_config_toml", HardwareConfig)):
        text = view.data.get(key)
        try:
            out.append(None if text is None else loads(cls, text, f"{view.path}:/provenance/{key}"))
        except ConfigError as exc:
            log.warning("%s", exc)
            out.append(None)
    proc, hw = out
    return ((None if proc is None else proc.products), hw,
            (None if proc is None else proc.imaging))


# ----------------------------------------------------------------------- contacts


def run_of_views(views: list[TileView]) -> str:
    """The run the tiles belong to: their root attribute ``run_id`` ("" when none has
    one: tiles written before it was kept); the first tile's when they differ (logged)."""
    ids = []
    for v in views:
        rid = run_id_attr(v.data["attrs"])
        if isinstance(rid, str) and rid and rid not in ids:
            ids.append(rid)
    if len(ids) > 1:
        log.warning("tiles of %d runs in one folder (%s); the contacts name the first",
                    len(ids), ", ".join(ids))
    return ids[0] if ids else ""


def utc_text(time_ns: int) -> str:
    """ISO 8601 UTC of a time in ns since the Unix epoch, to the nearest millisecond."""
    t = np.datetime64(int(time_ns) + 500_000, "ns").astype("datetime64[ms]")
    return f"{np.datetime_as_string(t, unit='ms')}Z"


def run_track(views: list[TileView]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The run's track: (transmit time ns, body origin north m, east m) of every ping of
    its tiles, once each, in time order; empty arrays when no tile keeps its pings'
    track (tiles written before it was kept)."""
    seq, t, n, e = [], [], [], []
    for v in views:
        d = v.data
        if all(k in d for k in ("ping_time", "ping_north_m", "ping_east_m")):
            seq.append(d["ping_sequence"])
            t.append(d["ping_time"])
            n.append(d["ping_north_m"])
            e.append(d["ping_east_m"])
    if not seq:
        return (np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    t, n, e = np.concatenate(t), np.concatenate(n), np.concatenate(e)
    _, first = np.unique(np.concatenate(seq), return_index=True)
    keep = first[np.argsort(t[first], kind="stable")]
    ok = np.isfinite(n[keep]) & np.isfinite(e[keep])
    keep = keep[ok]
    return t[keep].astype(np.int64), n[keep], e[keep]


def closest_pass(track: tuple[np.ndarray, np.ndarray, np.ndarray], ned: np.ndarray
                 ) -> tuple[str, float]:
    """(UTC time, horizontal distance m) of the closest pass of the body origin to the
    point ``ned`` (survey frame): the nearest point of the run's ``track``
    (:func:`run_track`) taken as straight between successive pings, its time
    interpolated between theirs. ("", NaN) without a track."""
    t, n, e = track
    if t.size == 0:
        return "", float("nan")
    if t.size == 1:
        return utc_text(int(t[0])), float(np.hypot(n[0] - ned[0], e[0] - ned[1]))
    a = np.stack([n[:-1], e[:-1]], axis=1)
    seg = np.stack([np.diff(n), np.diff(e)], axis=1)
    p = np.asarray(ned[:2], dtype=np.float64)
    length2 = np.einsum("ij,ij->i", seg, seg)
    u = np.clip(np.einsum("ij,ij->i", p - a, seg) / np.where(length2 > 0, length2, 1.0),
                0.0, 1.0)
    dist = np.hypot(*(a + u[:, None] * seg - p).T)
    k = int(np.argmin(dist))
    when = int(t[k]) + int(round(float(u[k]) * float(t[k + 1] - t[k])))
    return utc_text(when), float(dist[k])


def run_pings(views: list[TileView]) -> PingTrack:
    """Every ping of the run's tiles once, in sequence order (:func:`.circumstances.
    ping_track`): its time, body origin north and east and its navigation flags where
    its tile kept them (``ping_nav_flags``); empty when no tile keeps its pings' track."""
    seq, t, n, e, q = [], [], [], [], []
    for v in views:
        d = v.data
        if all(k in d for k in ("ping_time", "ping_north_m", "ping_east_m")):
            seq.append(d["ping_sequence"])
            t.append(d["ping_time"])
            n.append(d["ping_north_m"])
            e.append(d["ping_east_m"])
            f = d.get("ping_nav_flags")
            q.append(np.array([None] * d["ping_sequence"].size if f is None
                              else [int(x) for x in f], dtype=object))
    if not seq:
        return ping_track([], [], [], [])
    return ping_track(*(np.concatenate(a) for a in (seq, t, n, e, q)))


#: pings either side of a ping whose positions give the track's course there
COURSE_PINGS = 5
#: less travel than this (m) over those pings gives no course (the line's heading is
#: taken)
COURSE_MIN_M = 0.05


def array_offset_m(hw: HardwareConfig | None) -> np.ndarray:
    """The projectors' mean position forward and starboard of the body origin (body
    frame, m; zero without a usable hardware configuration)."""
    if hw is None:
        return np.zeros(2)
    try:
        return np.asarray(array_geometry(hw).projectors[:, :2].mean(axis=0),
                          dtype=np.float64)
    except ValueError as exc:
        log.warning("the array's place on the track not known (%s): the body origin's "
                    "track is taken", exc)
        return np.zeros(2)


def array_track(pings: PingTrack, offset_m: np.ndarray, heading_rad: float) -> PingTrack:
    """The pings placed where the array was: the body origin moved by ``offset_m``
    (forward, starboard; :func:`array_offset_m`) turned to the track's course at each
    ping (from the body origins of the :data:`COURSE_PINGS` pings either side;
    ``heading_rad``, the run line's heading, where they moved less than
    :data:`COURSE_MIN_M`). The tiles keep no heading: a crab angle is not followed."""
    if not len(pings) or not np.any(offset_m):
        return pings
    k = np.arange(len(pings))
    lo = np.maximum(k - COURSE_PINGS, 0)
    hi = np.minimum(k + COURSE_PINGS, len(pings) - 1)
    dn = pings.north_m[hi] - pings.north_m[lo]
    de = pings.east_m[hi] - pings.east_m[lo]
    course = np.where(np.hypot(dn, de) >= COURSE_MIN_M, np.arctan2(de, dn), heading_rad)
    ch, sh = np.cos(course), np.sin(course)
    return pings.moved(offset_m[0] * ch - offset_m[1] * sh,
                       offset_m[0] * sh + offset_m[1] * ch)


def run_circumstances(views: list[TileView], hw: HardwareConfig | None = None
                      ) -> tuple[PingTrack, list[Stretch]]:
    """The run's pings placed where the array was (:func:`run_pings`,
    :func:`array_track`; ``hw``: the hardware configuration, default the first tile's)
    and its stretches of missing pings, dead-reckoned and held poses
    (:func:`.circumstances.stretches`)."""
    if not views:
        return ping_track([], [], [], []), []
    if hw is None:
        _, hw, _ = _configs(views[0])
    track = array_track(run_pings(views), array_offset_m(hw), views[0].line.heading)
    return track, stretches(track)


def contact_circumstances(track: PingTrack, ned, depth_m: float, coverage_fraction: float,
                          footprint: Footprint | None) -> dict:
    """A contact's circumstance columns: what happened among the pings that could see
    it (those placed on ``track`` within the projector cone's horizontal reach of the
    peak at ``depth_m``: ``(h + z) tan(half-angle)`` of ``footprint``, else
    :data:`.circumstances.FALLBACK_REACH_M`) and its ``circumstances`` text (with
    "partial coverage" where ``coverage_fraction`` is under
    :data:`.circumstances.PARTIAL_COVERAGE_BELOW`)."""
    reach = (cone_radius(footprint.height_m + max(float(depth_m), 0.0),
                         footprint.tan_half_angle)
             if footprint is not None else FALLBACK_REACH_M)
    counts = counts_near(track, float(ned[0]), float(ned[1]), reach)
    return {**counts,
            "circumstances": circumstances_text(counts, is_partial(coverage_fraction))}


def run_contacts(views: list[TileView],
                 origin: tuple[float, float, float] | None = None) -> tuple[list[dict], dict]:
    """The run's contacts (dicts with the :data:`CONTACT_FIELDS`) from its tiles, and a
    summary (settings, origin, counts)."""
    if not views:
        return [], {"tiles": 0}
    pcfg, hw, imaging = _configs(views[0])
    if pcfg is None:
        raise TileFileError(f"{views[0].path}: no [products] in its processing "
                            "configuration: the tiles have no detections")
    _, min_fraction, use_footprint = coverage_settings(pcfg)
    dc = pcfg.detection
    run_line = views[0].line
    depth_axis = views[0].data["depth"]
    fulls = [v.data["coverage_full_pings"] for v in views
             if "coverage_full_pings" in v.data
             and v.data["coverage_full_pings"].shape == depth_axis.shape]
    full = np.max(fulls, axis=0) if fulls else None
    heights = [float(v.data["attrs"]["projector_height_m"]) for v in views
               if np.isfinite(float(v.data["attrs"].get("projector_height_m", np.nan)))]
    footprint = reach = None
    if heights and hw is not None and imaging is not None:
        reach = footprint_for(float(np.mean(heights)), hw, imaging)
        footprint = reach if use_footprint else None
    rows = []
    for v in views:
        table = v.data["detections"]
        if not len(table):
            continue
        xyz = np.stack([table["along_m"], table["cross_m"], table["depth_m"]], axis=1)
        ned = v.line.tile_to_ned(xyz)
        run = run_line.ned_to_tile(ned)
        run[:, 2] = xyz[:, 2]                     # depth below the seabed as imaged
        for i, row in enumerate(table):
            half = 0.5 * np.array([row["extent_along_m"], row["extent_cross_m"],
                                   row["extent_depth_m"]], dtype=np.float64)
            rows.append({"tile": v.path.name, "tile_row": i, "run_m": run[i],
                         "ned": ned[i], "half": half, "depth_m": float(xyz[i, 2]),
                         "peak_db": float(row["peak_db"]),
                         "excess_db": float(row["excess_db"]),
                         "threshold_db": _optional(table, row, "threshold_db"),
                         "false_alarms": _optional(table, row, "false_alarms"),
                         "coverage_pings": int(row["coverage_pings"])})
    n_tile_detections = len(rows)
    kept = filter_contacts(rows, full, depth_axis, min_fraction, dc.merge_m, dc.sidelobe_db,
                           dc.sidelobe_m, footprint, dc.later_echo_m)
    if origin is None:
        refs = [v.data["attrs"]["geodetic_ref"] for v in views
                if "geodetic_ref" in v.data["attrs"]]
        origin = survey_origin(refs[0]) if refs else None
    run_id = run_of_views(views)
    track = run_track(views)
    pings, stretched = run_circumstances(views, hw)
    out = []
    for k, r in enumerate(kept):
        lat = lon = float("nan")
        if origin is not None:
            la, lo, _ = ned_to_geodetic(r["ned"], origin)
            lat, lon = float(la), float(lo)
        size = r["hi"] - r["lo"]
        when, dist = closest_pass(track, r["ned"])
        c = {"contact": k, "run_id": run_id, "tile": r["tile"], "time_utc": when,
             "latitude_deg": lat, "longitude_deg": lon,
             "depth_below_seabed_m": r["depth_m"], "size_along_m": float(size[0]),
             "size_cross_m": float(size[1]), "size_depth_m": float(size[2]),
             "excess_db": r["excess_db"], "threshold_db": r["threshold_db"],
             "expected_false_alarms": r["false_alarms"],
             "north_m": float(r["ned"][0]), "east_m": float(r["ned"][1]),
             "along_m": float(r["run_m"][0]), "cross_m": float(r["run_m"][1]),
             "closest_pass_m": dist,
             "coverage_fraction": float(r["coverage_fraction"]),
             **contact_circumstances(pings, r["ned"], r["depth_m"],
                                     float(r["coverage_fraction"]), reach),
             "tile_row": r["tile_row"], "n_tiles": r["n_tiles"]}
        out.append({name: _rounded(name, c[name]) for name, *_ in CONTACT_FIELDS})
    summary = {"tiles": len(views), "tile_detections": n_tile_detections,
               "run_id": run_id,
               "contacts": len(out), "origin": None if origin is None else list(origin),
               "min_coverage_fraction": min_fraction,
               "run_full_coverage_pings": None if full is None else int(full.max()),
               "sidelobe_db": dc.sidelobe_db,
               "footprint": None if footprint is None else
               {"height_m": footprint.height_m, "tan_half_angle": footprint.tan_half_angle},
               "stretches": {k: sum(1 for x in stretched if x.kind == k) for k in KINDS},
               "array_track": pings, "stretch_list": stretched}
    return out, summary


def _optional(table: np.ndarray, row, name: str) -> float:
    """A detection's optional column (NaN where an older tile has none or wrote -1: not
    known)."""
    if name not in (table.dtype.names or ()):
        return float("nan")
    v = float(row[name])
    return v if v >= 0.0 else float("nan")


def _csv_value(name: str, v) -> str:
    if isinstance(v, float):
        if not math.isfinite(v):
            return ""
        d = _DECIMALS.get(name)
        return f"{v:.3g}" if d is None else f"{v:.{d}f}"
    return str(v)


def write_contacts_csv(path: Path, contacts: list[dict]) -> Path:
    """One row per contact, :data:`CONTACT_FIELDS` columns, each at its precision (NaN
    written empty)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([name for name, *_ in CONTACT_FIELDS])
        for c in contacts:
            w.writerow([_csv_value(k, c[k]) for k, *_ in CONTACT_FIELDS])
    return path


def stretch_geojson(k: int, st: Stretch, origin) -> dict:
    """A stretch as an RFC 7946 LineString feature along the array's track ([longitude,
    latitude] about the survey ``origin``; null geometry without one), id
    ``stretch-K``, properties ``kind`` (:data:`.circumstances.KINDS`), ``label``,
    ``first_sequence``, ``last_sequence``, ``pings``, ``start_utc``, ``end_utc``."""
    geometry = None
    if origin is not None and np.all(np.isfinite(np.asarray(origin, dtype=float)[:2])):
        ned = np.stack([st.north_m, st.east_m, np.zeros(st.north_m.size)], axis=1)
        lat, lon, _ = ned_to_geodetic(ned, tuple(origin))
        geometry = {"type": "LineString",
                    "coordinates": [[_rounded("longitude_deg", float(b)),
                                     _rounded("latitude_deg", float(a))]
                                    for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon))]}
    return {"type": "Feature", "id": f"stretch-{k}", "geometry": geometry,
            "properties": {"kind": st.kind, "label": LABELS[st.kind],
                           "first_sequence": st.first_sequence,
                           "last_sequence": st.last_sequence, "pings": st.pings,
                           "start_utc": utc_text(st.start_ns),
                           "end_utc": utc_text(st.end_ns)}}


def contacts_geojson(contacts: list[dict], summary: dict) -> dict:
    """RFC 7946 FeatureCollection: a Point [longitude, latitude] per contact (null
    geometry without a geodetic origin), the other columns as properties and ``kind``
    "contact"; after them the run's stretches (``summary["stretch_list"]``) as
    LineStrings (:func:`stretch_geojson`)."""
    feats = []
    for c in contacts:
        ok = math.isfinite(c["latitude_deg"]) and math.isfinite(c["longitude_deg"])
        props = {"kind": "contact",
                 **{k: (None if isinstance(c[k], float) and not math.isfinite(c[k])
                        else _rounded(k, c[k]))
                    for k, *_ in CONTACT_FIELDS if k not in ("latitude_deg", "longitude_deg")}}
        feats.append({"type": "Feature", "id": c["contact"],
                      "geometry": ({"type": "Point",
                                    "coordinates": [_rounded("longitude_deg",
                                                             c["longitude_deg"]),
                                                    _rounded("latitude_deg",
                                                             c["latitude_deg"])]}
                                   if ok else None),
                      "properties": props})
    feats += [stretch_geojson(k, st, summary.get("origin"))
              for k, st in enumerate(summary.get("stretch_list", ()))]
    return {"type": "FeatureCollection", "features": feats,
            "svss_run": {k: summary.get(k) for k in ("run_id", "tiles", "tile_detections",
                                                     "contacts", "origin", "stretches")}}


# ----------------------------------------------------------------------- mosaic


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
                            "held poses (docs/products.md, Circumstances)")
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


# ----------------------------------------------------------------------- the entry


def write_run_products(tiles_dir: str | Path, out_dir: str | Path | None = None,
                       origin: tuple[float, float, float] | None = None) -> list[Path]:
    """Write the run products of the tiles in ``tiles_dir`` into ``out_dir`` (default:
    the same folder): ``contacts.csv``, ``contacts.geojson``, ``mosaic.png`` and
    ``mosaic.h5``, and with a survey origin the map products ``mosaic.tif`` (GeoTIFF)
    and ``contacts.gpkg`` (GeoPackage), in the survey's UTM zone. ``origin``: survey origin (lat deg, lon deg, height m) when the
    tiles carry no geodetic reference. Returns the files written (none when the
    folder has no tiles with products)."""
    tiles_dir = Path(tiles_dir)
    out = Path(out_dir) if out_dir is not None else tiles_dir
    views = load_views(tiles_dir)
    if not views:
        log.warning("%s: no tiles; no run products", tiles_dir)
        return []
    pcfg, _, _ = _configs(views[0])
    if pcfg is None:
        log.warning("%s: tiles without products; no run products", tiles_dir)
        return []
    out.mkdir(parents=True, exist_ok=True)
    contacts, summary = run_contacts(views, origin)
    origin = summary["origin"]
    track, found = summary["array_track"], summary["stretch_list"]
    m = run_mosaic(views)
    title = (f"SVSS run mosaic: {len(views)} tile(s) from {tiles_dir.name}, "
             f"{len(contacts)} contact(s) (from {summary['tile_detections']} tile "
             f"detections); cell {m['cell_m'] * 100:.0f} cm")
    geojson = json.dumps(contacts_geojson(contacts, summary), indent=1)
    writers = {CONTACTS_CSV: lambda p: write_contacts_csv(p, contacts),
               CONTACTS_GEOJSON: lambda p: p.write_text(geojson),
               MOSAIC_H5: lambda p: write_mosaic_h5(p, m, origin, track, found),
               MOSAIC_PNG: lambda p: write_mosaic_png(p, m, contacts, pcfg, title,
                                                      pcfg.quicklook.max_labels, track,
                                                      found, run_swath(views))}
    projection = None
    if origin is not None:                 # the map products (docs/products.md)
        try:
            projection = SurveyProjection(tuple(origin))
        except ValueError as exc:
            log.warning("%s: no %s or %s: %s", tiles_dir, MOSAIC_TIF, CONTACTS_GPKG, exc)
    if projection is not None:
        um = utm_mosaic(views, projection)
        what = (f"{title}; run {summary['run_id'] or 'unknown'}; plan-view MIP in dB re "
                f"background, WGS 84 / UTM (EPSG:{projection.epsg})")
        writers[MOSAIC_TIF] = lambda p: write_mosaic_geotiff(p, um, projection.epsg, what)
        writers[CONTACTS_GPKG] = lambda p: write_stretches_gpkg(write_contacts_gpkg(
            p, contacts, [k for k, *_ in CONTACT_FIELDS], projection),
            [{**stretch_geojson(0, st, None)["properties"], "north_m": st.north_m,
              "east_m": st.east_m} for st in found], projection)
    elif origin is None:
        log.info("%s: no survey origin (no ping with a geodetic position, no --origin): "
                 "no %s or %s", tiles_dir, MOSAIC_TIF, CONTACTS_GPKG)
    files = []
    for name, write in writers.items():
        final = out / name
        tmp = temporary_path(final)          # whole files only, under their final names
        try:
            write(tmp)
            os.replace(tmp, final)
        finally:
            tmp.unlink(missing_ok=True)
        files.append(final)
    log.info("%s: %d contact(s) from %d tile detection(s) in %d tile(s); wrote %s",
             out, len(contacts), summary["tile_detections"], len(views),
             ", ".join(p.name for p in files))
    return files


def run_products_at_end(tiles_dir: str | Path) -> list[Path]:
    """:func:`write_run_products` for the worker at a run's end: a failure is logged
    (naming the folder), never raised, so that it cannot cost the run's tiles."""
    try:
        return write_run_products(tiles_dir)
    except Exception:
        log.exception("%s: writing the run products failed (rewrite them with "
                      "'svss products %s')", tiles_dir, tiles_dir)
        return []


__all__ = [
    "CONTACTS_GPKG",
    "CONTACT_FIELDS",
    "MOSAIC_TIF",
    "closest_pass",
    "contact_circumstances",
    "filter_contacts",
    "run_circumstances",
    "run_contacts",
    "run_mosaic",
    "run_pings",
    "run_products_at_end",
    "utm_mosaic",
    "survey_origin",
    "write_run_products",
]
