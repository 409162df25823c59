"""The run as its tiles hold it, for the run products (:mod:`.run_products`,
:mod:`.run_mosaic`) and the live view: each tile's header and plan views
(:class:`TileView`), the survey origin, the tiles' configurations, and the run's
id, ping track and its circumstances (:mod:`.circumstances`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from svss_daq.config import (
    ConfigError,
    HardwareConfig,
    ImagingConfig,
    ProcessingConfig,
    ProductsConfig,
    loads,
)
from svss_daq.frames import TrackLine
from svss_daq.geometry import array_geometry
from svss_daq.navigation import geodetic_to_ned, ned_to_geodetic
from svss_daq.untrusted_hdf5 import run_id_attr

from ..tiles import finished_tile_paths, read_tile_views, tile_line
from .circumstances import PingTrack, Stretch, ping_track, stretches

log = logging.getLogger(__name__)


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
    its tiles (:func:`run_pings`), once each, in time order; empty arrays when no tile
    keeps its pings' track (tiles written before it was kept)."""
    p = run_pings(views)
    order = np.argsort(p.time_ns, kind="stable")
    return p.time_ns[order].astype(np.int64), p.north_m[order], p.east_m[order]


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
