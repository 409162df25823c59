"""Map products of a run: the mosaic as a GeoTIFF and the contacts as a GeoPackage
layer, both in the survey's UTM zone (docs/run_products.md "Map products").

Libraries, not hand-written geodesy or file formats: pyproj (PROJ) for the projection
between WGS-84 latitude/longitude and UTM; rasterio (GDAL, shipped in its wheels) writes
the GeoTIFF with its CRS and geotransform; pyogrio (GDAL's vector drivers, shipped in its
wheels) writes the GeoPackage. What any GDAL-based tool (QGIS, gdalinfo, ogr2ogr) reads
is then what GDAL wrote.

The survey frame is the local north-east-down tangent plane at the survey origin
(:mod:`svss_daq.nav.geodesy`, exact WGS-84); UTM grid north differs from true north by
the meridian convergence (about 1 degree at 1.7 degrees of longitude from the zone's
central meridian) and UTM distances by the scale factor (0.9996 on the central
meridian). The mosaic is therefore resampled onto a UTM-aligned grid: each UTM cell
centre goes to latitude/longitude (pyproj), to the survey frame (the navigation's
geodesy), to its tile's voxel column (nearest), never by rotating or scaling the
survey-frame mosaic.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from svss_daq.navigation import geodetic_to_ned, ned_to_geodetic

log = logging.getLogger(__name__)

MOSAIC_TIF = "mosaic.tif"
CONTACTS_GPKG = "contacts.gpkg"
#: the contacts layer's name in the GeoPackage, and the stretches' (LineStrings)
CONTACTS_LAYER = "contacts"
STRETCHES_LAYER = "stretches"


def utm_epsg(lat_deg: float, lon_deg: float) -> int:
    """The EPSG code of the WGS-84 UTM zone of a point (the standard 6-degree zones,
    north 326zz, south 327zz; the Norway and Svalbard exceptions are not applied)."""
    if not (math.isfinite(lat_deg) and math.isfinite(lon_deg)) or abs(lat_deg) > 84.0:
        raise ValueError(f"no UTM zone for latitude {lat_deg}, longitude {lon_deg} "
                         "(UTM covers 80 S to 84 N)")
    zone = int(math.floor((lon_deg + 180.0) / 6.0)) % 60 + 1
    return (32600 if lat_deg >= 0.0 else 32700) + zone


@dataclass
class SurveyProjection:
    """Survey frame (north, east about ``origin``: lat deg, lon deg, height m) to and
    from the survey's UTM zone."""
    origin: tuple[float, float, float]

    def __post_init__(self):
        from pyproj import CRS, Transformer
        self.epsg = utm_epsg(self.origin[0], self.origin[1])
        self.crs = CRS.from_epsg(self.epsg)
        self._fwd = Transformer.from_crs(CRS.from_epsg(4326), self.crs, always_xy=True)
        self._inv = Transformer.from_crs(self.crs, CRS.from_epsg(4326), always_xy=True)

    def ne_to_latlon(self, north, east) -> tuple[np.ndarray, np.ndarray]:
        """Survey north, east (m, on the tangent plane) to WGS-84 latitude, longitude."""
        north = np.asarray(north, dtype=np.float64)
        ned = np.stack([north, np.asarray(east, dtype=np.float64), np.zeros_like(north)],
                       axis=-1)
        lat, lon, _ = ned_to_geodetic(ned, self.origin)
        return lat, lon

    def ne_to_utm(self, north, east) -> tuple[np.ndarray, np.ndarray]:
        """Survey north, east (m) to UTM easting, northing (m)."""
        lat, lon = self.ne_to_latlon(north, east)
        x, y = self._fwd.transform(lon, lat)
        return np.asarray(x), np.asarray(y)

    def utm_to_ne(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """UTM easting, northing (m; at the origin's ellipsoidal height) to survey north,
        east (m)."""
        lon, lat = self._inv.transform(np.asarray(x, dtype=np.float64),
                                       np.asarray(y, dtype=np.float64))
        ned = geodetic_to_ned(np.asarray(lat), np.asarray(lon),
                              np.full(np.shape(lat), self.origin[2]), self.origin)
        return ned[..., 0], ned[..., 1]


def utm_grid(corners_utm: np.ndarray, cell_m: float, max_cells: int
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """A UTM-aligned grid over the points ``corners_utm`` (..., 2: easting, northing):
    its edges on multiples of the cell (coarsened so that neither side has more than
    ``max_cells``). Returns (easting of the column centres, west to east; northing of
    the row centres, north to south; cell)."""
    x0, y0 = corners_utm[:, 0].min(), corners_utm[:, 1].min()
    x1, y1 = corners_utm[:, 0].max(), corners_utm[:, 1].max()
    cell = max(cell_m, (x1 - x0) / max_cells, (y1 - y0) / max_cells)
    left, right = math.floor(x0 / cell) * cell, math.ceil(x1 / cell) * cell
    bottom, top = math.floor(y0 / cell) * cell, math.ceil(y1 / cell) * cell
    nx, ny = max(1, round((right - left) / cell)), max(1, round((top - bottom) / cell))
    x = left + (np.arange(nx) + 0.5) * cell
    y = top - (np.arange(ny) + 0.5) * cell
    return x, y, cell


def write_mosaic_geotiff(path: Path, m: dict, epsg: int, description: str) -> Path:
    """One float32 band ``mip_db`` (rows north to south, NaN: no data) on the UTM grid
    of ``m`` (``x``, ``y`` cell centres, ``cell_m``), CRS EPSG ``epsg``."""
    import rasterio
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    cell = m["cell_m"]
    data = np.asarray(m["mip_db"], dtype=np.float32)
    # north up: the top-left corner, cell wide, cell high downwards
    transform = Affine(cell, 0.0, m["x"][0] - cell / 2, 0.0, -cell, m["y"][0] + cell / 2)
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1],
                       height=data.shape[0], count=1, dtype="float32",
                       crs=CRS.from_epsg(epsg), transform=transform, nodata=np.nan,
                       compress="deflate", tiled=data.shape[0] >= 256
                       and data.shape[1] >= 256) as dst:
        dst.write(data, 1)
        dst.set_band_description(1, "plan-view MIP, dB re background")
        dst.update_tags(1, units="dB re background")
        dst.update_tags(TIFFTAG_IMAGEDESCRIPTION=description, TIFFTAG_SOFTWARE="svss")
    return path


#: GeoPackage field types of the contact columns that are not floats
_INT_FIELDS = ("contact", "tile_row", "n_tiles", "pings_missing", "poses_dead_reckoned",
               "poses_held", "feature_flags")
_TEXT_FIELDS = ("run_id", "tile", "time_utc", "circumstances", "feature_notes",
                "class", "class_from")


def write_contacts_gpkg(path: Path, contacts: list[dict], fields: list[str],
                        projection: SurveyProjection) -> Path:
    """The contacts as the point layer ``contacts`` (UTM, the mosaic's CRS) of a
    GeoPackage, every column of ``fields`` (NaN: null) as an attribute."""
    x, y = projection.ne_to_utm([c["north_m"] for c in contacts],
                                [c["east_m"] for c in contacts])
    geometry = np.array([struct.pack("<BIdd", 1, 1, float(a), float(b))   # WKB Point
                         for a, b in zip(np.atleast_1d(x), np.atleast_1d(y))], dtype=object)
    data = []
    for k in fields:
        if k in _INT_FIELDS:
            data.append(np.array([int(c[k]) for c in contacts], dtype=np.int64))
        elif k in _TEXT_FIELDS:
            data.append(np.array([str(c[k]) for c in contacts], dtype=object))
        else:
            data.append(np.array([c[k] for c in contacts], dtype=np.float64))
    _quiet_write(path, geometry, data, list(fields), layer=CONTACTS_LAYER,
                 driver="GPKG", geometry_type="Point", crs=f"EPSG:{projection.epsg}")
    return path


def _quiet_write(path: Path, geometry, data, fields, **kw) -> None:
    """``pyogrio.raw.write``, without GDAL's "Created N records" (logged at INFO by
    pyogrio: this module says what it wrote)."""
    import pyogrio.raw

    io_log = logging.getLogger("pyogrio._io")
    level = io_log.level
    io_log.setLevel(max(level, logging.WARNING))
    try:
        pyogrio.raw.write(str(path), geometry, data, fields, **kw)
    finally:
        io_log.setLevel(level)


def write_stretches_gpkg(path: Path, rows: list[dict], projection: SurveyProjection) -> Path:
    """The run's stretches as the LineString layer ``stretches`` (UTM, the mosaic's CRS)
    added to the GeoPackage at ``path``: ``rows`` of ``north_m``, ``east_m`` (the line's
    positions, survey frame) and the attributes ``kind``, ``label``,
    ``first_sequence``, ``last_sequence``, ``pings``, ``start_utc``, ``end_utc``.
    Nothing is added without rows."""
    if not rows:
        return path
    geometry = []
    for r in rows:
        x, y = projection.ne_to_utm(r["north_m"], r["east_m"])
        x, y = np.atleast_1d(x), np.atleast_1d(y)
        geometry.append(struct.pack("<BII", 1, 2, x.size)              # WKB LineString
                        + np.column_stack([x, y]).astype("<f8").tobytes())
    fields = ["kind", "label", "first_sequence", "last_sequence", "pings", "start_utc",
              "end_utc"]
    data = [np.array([r[k] for r in rows], dtype=np.int64 if k in (
        "first_sequence", "last_sequence", "pings") else object) for k in fields]
    _quiet_write(path, np.array(geometry, dtype=object), data, fields,
                 layer=STRETCHES_LAYER, driver="GPKG", geometry_type="LineString",
                 crs=f"EPSG:{projection.epsg}", append=True)
    return path


__all__ = ["CONTACTS_GPKG", "MOSAIC_TIF", "STRETCHES_LAYER", "SurveyProjection", "utm_epsg",
           "utm_grid", "write_contacts_gpkg", "write_mosaic_geotiff", "write_stretches_gpkg"]
