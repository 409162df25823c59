"""Tile files: HDF5 with named dimensions and coordinate variables (netCDF4-style
dimension scales, so ``xarray.open_dataset(path, engine="h5netcdf")`` opens them), the
complex image, the image products (background, compressed volume,
maximum intensity projections, detections) and provenance. See docs/formats.md.

Files are written under a temporary name (:func:`temporary_path`) in the same folder and
renamed into place only when complete, so a tile file with its final name is always
whole. Files are untrusted when read: the readers check the format, the version and the
layout (groups, datasets, shapes, dtypes, attributes) and raise :class:`TileFileError`
naming the file and the path.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import time
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from svss_daq import __version__
from svss_daq import ping as _ping
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.frames import TrackLine
from svss_daq.rawfile import TIME_UNITS
from svss_daq.untrusted_hdf5 import (H5_ERRORS, abandon, cause, dataset, format_version,
                                     group, hdf5_superblock, in_child, shown)

from .products import detect
from .products.circumstances import tile_counts
from .imaging.tile import Tile  # noqa: F401  (the tile files' Tile: formed by the imager)

if TYPE_CHECKING:
    from .imaging.coverage import Coverage
    from .products.tile_products import Products

log = logging.getLogger(__name__)

TILE_FORMAT = "svss-tile"
TILE_FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
DIMS = ("along", "cross", "depth")
#: maximum intensity projections: name -> (axis projected over, remaining dimensions)
MIPS = {"mip_depth": (2, ("along", "cross")), "mip_cross": (1, ("along", "depth")),
        "mip_along": (0, ("cross", "depth"))}
DRC_SCALE = np.float32(1.0 / 255.0)
#: the coverage counts (smooth: neighbours mostly equal) and the 2-D projections are
#: gzip-compressed (the counts about tenfold); the volumes of floats (speckle: the complex
#: image, the background) and the 8-bit display volume are not: gzip level 1 took 3.1 of
#: the 3.3 CPU s of a default tile's file to save 18 % of their bytes (issue 32,
#: docs/formats.md), so they are stored plain, in chunks of whole along-track planes
#: compressed volumes; like the plain ones (:func:`_plain`) each chunk carries HDF5's
#: Fletcher-32 checksum, so that a tile damaged on disk is refused, naming the dataset
_GZIP = {"compression": "gzip", "compression_opts": 1, "shuffle": True, "fletcher32": True}
#: bytes of a plain volume's chunk, at most (whole along-track planes, at least one)
PLAIN_CHUNK_BYTES = 1 << 21
#: marks a file being written: ``.NAME.partial-XXXX.SUFFIX``; readers ignore such names
PARTIAL = ".partial-"
#: per ping of the tile (absent in tiles written before they were kept): dtype kinds
TRACK = {"ping_time": "i", "ping_north_m": "f", "ping_east_m": "f", "ping_nav_flags": "iu"}
#: the navigation's NAV_* flags (:mod:`svss_daq.ping`) as CF ``flag_masks`` and
#: ``flag_meanings`` of ``ping_nav_flags``
NAV_FLAG_NAMES = ("gps_fix", "dead_reckoned", "bottom_lock", "simulated",
                  "heading_from_course", "no_heading", "heading_from_compass", "held",
                  "clock_retimed", "smoothed", "fused", "dvl_velocity")
#: root attributes every tile has (and the scorer and the summary need)
REQUIRED_ATTRS = ("tile_index", "line_origin_north_m", "line_origin_east_m",
                  "line_heading_rad", "interface_down_m", "voxel_m")


#: the names of a tile's files (:func:`tile_name`, :func:`tile_file_paths`): the one place
#: they are spelled
TILE_PREFIX = "tile_"
TILE_SUFFIX = ".h5"
QUICKLOOK_SUFFIX = "_mip.png"
TILE_GLOB = f"{TILE_PREFIX}*{TILE_SUFFIX}"
#: name prefixes of a tile's files, finished or being written (:func:`temporary_path`)
TILE_FILE_PREFIXES = (TILE_PREFIX, f".{TILE_PREFIX}")
_TILE_FILE = re.compile(rf"{TILE_PREFIX}(-?\d+){re.escape(TILE_SUFFIX)}")


class TileFileError(ValueError):
    """A tile file that cannot be read (or written) as such."""


def temporary_path(path: str | Path) -> Path:
    """A unique temporary name beside ``path`` (same folder, so that a rename is atomic;
    same suffix, so that writers choosing a format by it still do):
    ``.NAME.partial-XXXXXXXX.SUFFIX``."""
    path = Path(path)
    return path.with_name(f".{path.stem}{PARTIAL}{secrets.token_hex(4)}{path.suffix}")


def is_temporary(path: str | Path) -> bool:
    """Whether ``path`` is a file still being written (:func:`temporary_path`)."""
    name = Path(path).name
    return name.startswith(".") and PARTIAL in name


def tile_line(attrs: dict) -> TrackLine:
    """The tile frame (track line) stored in a tile's root attributes."""
    return TrackLine((float(attrs["line_origin_north_m"]), float(attrs["line_origin_east_m"])),
                     float(attrs["line_heading_rad"]), float(attrs["interface_down_m"]))


def tile_name(index: int) -> str:
    """The stem of tile ``index``'s files: ``tile_NNNN``."""
    return f"{TILE_PREFIX}{index:04d}"


def tile_file_paths(folder: str | Path, index: int) -> tuple[Path, Path]:
    """(tile file, quicklook) of tile ``index`` in ``folder``: ``tile_NNNN.h5`` and
    ``tile_NNNN_mip.png``."""
    name = tile_name(index)
    folder = Path(folder)
    return folder / f"{name}{TILE_SUFFIX}", folder / f"{name}{QUICKLOOK_SUFFIX}"


def finished_tile_paths(folder: str | Path) -> list[Path]:
    """The finished tile files of ``folder`` (``tile_*.h5``; files being written, which
    :func:`temporary_path` names, excluded), sorted."""
    return sorted(p for p in Path(folder).glob(TILE_GLOB) if not is_temporary(p))


def finished_tiles_by_index(folder: str | Path) -> dict[int, Path]:
    """The finished tile files of ``folder`` by the tile index their names carry (files
    whose names carry none are left out)."""
    out = {}
    for p in Path(folder).glob(TILE_GLOB):
        m = _TILE_FILE.fullmatch(p.name)
        if m:
            out[int(m.group(1))] = p
    return out


def _plain(shape: tuple[int, ...], itemsize: int) -> dict:
    """Dataset options of a volume stored without compression: chunks of whole
    along-track planes, at most :data:`PLAIN_CHUNK_BYTES` (a reader of the first or last
    planes, such as the seams' neighbour, reads few chunks)."""
    plane = int(np.prod(shape[1:], dtype=np.int64)) * itemsize
    n = max(1, min(int(shape[0]), PLAIN_CHUNK_BYTES // max(plane, 1)))
    return ({"chunks": (n,) + tuple(int(v) for v in shape[1:]), "fletcher32": True}
            if all(shape) else {})


def _attach(ds: h5py.Dataset, f: h5py.Group, dims: tuple[str, ...]) -> None:
    for i, d in enumerate(dims):
        ds.dims[i].attach_scale(f[d])


def write_tile(path: str | Path, tile: Tile, hardware: Loaded[HardwareConfig],
               processing: Loaded[ProcessingConfig],
               products: "Products | None" = None) -> Path:
    """Write one tile (and its products, if given) to ``path`` (HDF5): under a temporary
    name first, renamed to ``path`` only when complete. On failure (a full disk) the
    temporary file is removed and :class:`TileFileError` names the file and the cause."""
    path = Path(path)
    tmp = temporary_path(path)
    f = None
    # every dataset stays open until the file is flushed: a dataset closed with data it
    # cannot write (a full disk) fails in h5py's finaliser, unseen, and HDF5 then crashes
    # closing it again
    kept: list[h5py.Dataset] = []

    def keep(ds: h5py.Dataset) -> h5py.Dataset:
        kept.append(ds)
        return ds

    try:
        f = h5py.File(tmp, "w")
        _write(f, tile, hardware, processing, products, keep)
        f.flush()
        kept.clear()
        f.close()
        os.replace(tmp, path)
    except H5_ERRORS as exc:
        if f is not None:
            abandon(f)
        kept.clear()
        tmp.unlink(missing_ok=True)
        why = " ".join(str(exc).split())
        raise TileFileError(f"{path}: writing tile {tile_name(tile.grid.index)} failed "
                            f"({why}); no file written") from None
    except BaseException:
        if f is not None:
            abandon(f)
        kept.clear()
        tmp.unlink(missing_ok=True)
        raise
    return path


def _write(f: h5py.File, tile: Tile, hardware: Loaded[HardwareConfig],
           processing: Loaded[ProcessingConfig], products: "Products | None", keep) -> None:
    """Write the tile into ``f``; every dataset created goes through ``keep``."""
    g = tile.grid
    f.attrs.update({
        "svss_format": TILE_FORMAT, "svss_format_version": TILE_FORMAT_VERSION,
        "Conventions": "CF-1.8",
        "title": f"SVSS image {tile_name(g.index)}", "tile_index": g.index,
        "line_origin_north_m": tile.line.origin_ne[0],
        "line_origin_east_m": tile.line.origin_ne[1],
        "line_heading_rad": tile.line.heading,
        "interface_down_m": tile.line.interface_down,
        "voxel_m": processing.value.tile.voxel_m,
        "voxel_channel_updates": tile.updates,
        "n_pings": len(tile.pings),
        "software_name": "svss", "software_version": __version__,
        "creation_time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "hardware_config_id": hardware.id, "processing_config_id": processing.id,
        "has_products": products is not None,
    })
    axes = {"along": (g.along, "along-track distance from the line origin"),
            "cross": (g.cross, "cross-track distance, starboard positive"),
            "depth": (g.depth, "depth below the water-sediment interface")}
    for name, (values, long_name) in axes.items():
        ds = keep(f.create_dataset(name, data=values))
        ds.attrs.update({"units": "m", "long_name": long_name})
        ds.make_scale(name)
    if g.surface is not None:           # a sloping interface: depths are below it
        ds = keep(f.create_dataset("interface_depth", data=np.asarray(g.surface)))
        ds.attrs.update({"units": "m", "long_name": "the interface's depth below "
                         "interface_down_m at each voxel column (the level under the "
                         "first ping; each voxel's depth is below its column's)"})
        _attach(ds, f, ("along", "cross"))
    pings = keep(f.create_dataset("ping_sequence",
                                  data=np.asarray(tile.pings, dtype=np.int64)))
    pings.attrs.update({"long_name": "sequence numbers of the pings that went into the tile",
                        "units": "1"})
    pings.make_scale("ping_sequence")
    if tile.run_id:
        f.attrs["run_id"] = tile.run_id
    flags = None
    if tile.track and len(tile.track) == len(tile.pings):
        track = np.asarray([row[:3] for row in tile.track], dtype=np.float64)
        if all(len(row) > 3 for row in tile.track):
            flags = np.asarray([int(row[3]) for row in tile.track], dtype=np.uint32)
        for name, data, units, long_name in (
                ("ping_time", np.asarray([row[0] for row in tile.track], dtype=np.int64),
                 TIME_UNITS, "transmit time of the ping (UTC)"),
                ("ping_north_m", track[:, 1], "m", "body origin north at the ping (survey "
                                                   "frame)"),
                ("ping_east_m", track[:, 2], "m", "body origin east at the ping (survey "
                                                  "frame)")):
            ds = keep(f.create_dataset(name, data=data))
            ds.attrs.update({"units": units, "long_name": long_name})
            if units == TIME_UNITS:
                ds.attrs.update({"standard_name": "time", "calendar": "standard"})
            _attach(ds, f, ("ping_sequence",))
        if flags is not None:
            ds = keep(f.create_dataset("ping_nav_flags", data=flags))
            ds.attrs.update({
                "units": "1", "long_name": "the navigation's quality flags of the ping's "
                "pose (NAV_* bits of svss_daq.ping)",
                "flag_masks": np.array([getattr(_ping, f"NAV_{n.upper()}")
                                        for n in NAV_FLAG_NAMES], dtype=np.uint32),
                "flag_meanings": " ".join(NAV_FLAG_NAMES)})
            _attach(ds, f, ("ping_sequence",))
    # what happened among the tile's pings (docs/run_products.md, "Circumstances")
    f.attrs.update(tile_counts(tile.pings, flags))
    # the magnitude is not stored: it is |image| (read_tile computes it), and was 30 MB
    # of a default tile written twice
    image = keep(f.create_dataset("image", data=tile.image,
                                  **_plain(tile.image.shape, tile.image.itemsize)))
    image.attrs.update({"long_name": "complex backprojected image (coherent sum of "
                                     "matched-filter outputs)", "units": "uPa"})
    _attach(image, f, DIMS)
    if tile.coverage is not None:
        _write_coverage(f, tile.coverage, keep)
    if products is not None:
        _write_products(f, products, keep)
    prov = f.create_group("provenance")
    keep(prov.create_dataset("hardware_config_toml", data=hardware.text))
    keep(prov.create_dataset("processing_config_toml", data=processing.text))
    prov.attrs.update({"software_name": "svss", "software_version": __version__,
                       "hardware_config_source": hardware.source,
                       "processing_config_source": processing.source})
    if tile.poses:
        prov.attrs["poses"] = tile.poses
    prov.attrs["imaging_method"] = tile.method
    if tile.seabed:
        _write_seabed(prov, tile.seabed)


def _write_seabed(prov: h5py.Group, seabed: dict) -> None:
    """The sediment speed a tile was imaged with, its source and uncertainty
    (``/provenance/seabed`` attributes; the responses, the layers and the interface's
    slope and relief as JSON texts)."""
    g = prov.create_group("seabed")
    for k in ("status", "reason"):
        g.attrs[k] = str(seabed.get(k) or "")
    for k in ("sediment_sound_speed_m_s", "sigma_m_s", "configured_m_s", "reduced_chi2"):
        v = seabed.get(k)
        g.attrs[k] = np.nan if v is None else float(v)
    g.attrs["disagrees"] = bool(seabed.get("disagrees", False))
    g.attrs["responses_json"] = json.dumps(seabed.get("responses", []))
    g.attrs["layers_json"] = json.dumps(seabed.get("layers", []))
    g.attrs["tiles_json"] = json.dumps({"tiles": seabed.get("tiles", []),
                                        "tiles_disagree": seabed.get("tiles_disagree")})
    # the interface's slope and relief as estimated (the relief's nodes themselves are
    # the manifest's; the tile holds its columns' depths, ``interface_depth``)
    g.attrs["interface_json"] = json.dumps({k: v for k, v in seabed.items()
                                            if k.startswith("interface_") and k not in (
                                                "interface_relief_m",
                                                "interface_relief_origin_m",
                                                "interface_relief_step_m")})


def _write_coverage(f: h5py.File, c: Coverage, keep) -> None:
    """The coverage volumes (docs/products.md) and the tile's geometry summary."""
    for name, data, long_name in (
            ("coverage_pings", c.pings, ("pings that reached the voxel (projector cone, "
                                         "a receiver cone and the receive window)")),
            ("coverage_channels", c.channels, "ping-channel pairs that reached the voxel")):
        ds = keep(f.create_dataset(name, data=data.astype(np.uint16), chunks=True, **_GZIP))
        ds.attrs.update({"long_name": long_name, "units": "1", "saturates_at": 65535})
        _attach(ds, f, DIMS)
    full = keep(f.create_dataset("coverage_full_pings",
                                 data=c.pings.max(axis=(0, 1)).astype(np.uint16)))
    full.attrs.update({"long_name": "full coverage per depth: the most pings any voxel of "
                                    "the depth layer got", "units": "1"})
    _attach(full, f, ("depth",))
    f.attrs["coverage_n_channels"] = c.n_channels
    f.attrs["projector_height_m"] = c.mean_height_m
    if c.geodetic_ref is not None:
        f.attrs["geodetic_ref"] = np.asarray(c.geodetic_ref, dtype=np.float64)


def _write_products(f: h5py.File, p: "Products", keep) -> None:
    f.attrs["n_detections"] = len(p.detections)
    f.attrs["products_timing_s"] = json.dumps({k: round(v, 4) for k, v in p.timings.items()})
    common = {"background_method": p.method, "background_kernel_voxels": p.kernel_voxels,
              "background_kernel_m": p.kernel_m, "background_boundary": p.boundary,
              "background_max_error_db": p.max_error_db}
    if p.background is not None:
        data = np.asarray(p.background, dtype=np.float32)
        bg = keep(f.create_dataset("background", data=data,
                                   **_plain(data.shape, data.itemsize)))
        bg.attrs.update({"long_name": "background: 3-D median of the magnitude",
                         "units": "uPa", "ignore_zeros": p.ignore_zeros,
                         "normalisation_floor_upa": p.floor_upa, **common})
        _attach(bg, f, DIMS)
    if p.drc is not None:
        q = np.round(np.clip(p.drc, 0.0, 1.0) * 255.0).astype(np.uint8)
        drc = keep(f.create_dataset("drc", data=q, **_plain(q.shape, q.itemsize)))
        drc.attrs.update({"long_name": "dynamic-range-compressed normalised level, 0..1",
                          "units": "1", "scale_factor": DRC_SCALE,
                          "add_offset": np.float32(0.0), **p.drc_attrs})
        _attach(drc, f, DIMS)
    gain = keep(f.create_dataset("depth_gain_db", data=p.gain_db.astype(np.float32)))
    gain.attrs.update({"long_name": "display gain added to the normalised level",
                       "units": "dB"})
    _attach(gain, f, ("depth",))
    for name, (axis, dims) in MIPS.items():
        ds = keep(f.create_dataset(name, data=p.mips[name].astype(np.float32), **_GZIP))
        ds.attrs.update({"long_name": f"maximum intensity projection over {DIMS[axis]} "
                                      f"of the normalised level plus display gain",
                         "units": "dB re background", **common})
        _attach(ds, f, dims)
    grp = f.create_group("detections")
    n = len(p.detections)
    idx = keep(grp.create_dataset("detection", data=np.arange(n, dtype=np.int64)))
    idx.attrs["long_name"] = "contact number, strongest first"
    idx.make_scale("detection")
    for name, _, units, long_name in detect.FIELDS:
        ds = keep(grp.create_dataset(name, data=p.detections[name]))
        ds.attrs.update({"units": units, "long_name": long_name})
        ds.dims[0].attach_scale(idx)
    grp.attrs.update({k: v for k, v in p.detection_attrs.items()})
    if p.tail_profiles is not None:     # each contact's tail (docs/contact_features.md)
        ds = keep(grp.create_dataset("tail_profile_db",
                                     data=np.asarray(p.tail_profiles, dtype=np.float32)))
        ds.attrs.update({"units": "dB re background", "step_m": p.tail_profile_step_m,
                         "long_name": "mean normalised intensity over the contact's "
                                      "footprint over that of reference footprints beside "
                                      "it, from the peak's depth down in steps of step_m "
                                      "(NaN: below the tile)"})
        ds.dims[0].attach_scale(idx)


def _text(v) -> str:
    return v.decode(errors="replace") if isinstance(v, bytes) else str(v)


def _open_tile(path: Path) -> h5py.File:
    """Open a tile file for reading, checking that it is whole (its superblock), its
    format and its version."""
    if not path.is_file():
        raise TileFileError(f"{path}: no such file")
    sb = hdf5_superblock(path, TileFileError)
    if sb["flags"] & 1:
        raise TileFileError(f"{path}: not closed by its writer (a half-written tile)")
    try:
        f = h5py.File(path, "r")
    except H5_ERRORS as exc:
        raise TileFileError(f"{path}: not a readable HDF5 file ({cause(exc)})") from None
    try:
        fmt = f.attrs.get("svss_format")
        if fmt is None or _text(fmt) != TILE_FORMAT:
            raise TileFileError(f"{path}: root attribute 'svss_format' is "
                                f"{None if fmt is None else _text(fmt)!r}; expected "
                                f"{TILE_FORMAT!r}")
        format_version(f.attrs.get("svss_format_version"), path, READABLE_VERSIONS,
                       TileFileError)
    except BaseException as exc:
        f.close()
        if isinstance(exc, H5_ERRORS) and not isinstance(exc, TileFileError):
            raise TileFileError(f"{path}: cannot read its root attributes "
                                f"({cause(exc)})") from None
        raise
    return f


def _read(path: str | Path, body):
    """Open the tile at ``path`` and return ``body(f, path)``; any failure to read it
    becomes a :class:`TileFileError` naming the file. The read runs in a child process
    (:func:`svss_daq.untrusted_hdf5.in_child`), so that a damaged file that would hang or
    crash HDF5 is refused instead."""
    path = Path(path)
    return in_child(path, lambda: _read_now(path, body), TileFileError)


def _read_now(path: Path, body):
    with _open_tile(path) as f:
        try:
            return body(f, path)
        except TileFileError:
            raise
        except H5_ERRORS as exc:
            raise TileFileError(f"{path}: cannot read the tile ({cause(exc)})") from None


def _volume(f: h5py.File, name: str, path: Path, shape: tuple[int, ...], kinds: str,
            dims: tuple[str, ...] = DIMS) -> h5py.Dataset:
    ds = dataset(f, name, path, len(shape), kinds, TileFileError,
                 what=f"{' x '.join(dims)}")
    if ds.shape != shape:
        raise TileFileError(f"{path}: dataset '/{name}' has shape {ds.shape}; expected "
                            f"{shape} ({' x '.join(dims)} of the tile's axes)")
    return ds


def _data(ds: h5py.Dataset, path: Path) -> np.ndarray:
    """All of ``ds``; a chunk failing its checksum is a :class:`TileFileError` naming
    the file and the dataset."""
    try:
        return ds[()]
    except H5_ERRORS as exc:
        if "filter" in str(exc) and ds.fletcher32:
            raise TileFileError(f"{path}: dataset '{ds.name}' fails its Fletcher-32 "
                                "checksum (changed on disk since it was written)") from None
        raise


def verify_tile(path: str | Path) -> list[str]:
    """Every checksummed dataset of the tile at ``path`` read against its checksums:
    what is damaged (each naming file and dataset; empty: none). Raises
    :class:`TileFileError` for a tile written without checksums."""
    path = Path(path)

    def body(f, path):
        found, damaged = [], []

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and obj.fletcher32:
                found.append(obj.name)
                try:
                    _data(obj, path)
                except TileFileError as exc:
                    damaged.append(str(exc))
        f.visititems(visit)
        if not found:
            raise TileFileError(f"{path}: written without checksums (before they were "
                                "written): it cannot be verified")
        return damaged
    return _read(path, body)


def _header(f: h5py.File, path: Path) -> dict:
    out = {k: dataset(f, k, path, 1, "f", TileFileError, what="voxel centres, m")[()]
           for k in DIMS}
    out["ping_sequence"] = dataset(f, "ping_sequence", path, 1, "iu", TileFileError)[()]
    n_pings = out["ping_sequence"].shape
    for k, kinds in TRACK.items():          # absent in tiles written before they were kept
        if k in f:
            ds = dataset(f, k, path, 1, kinds, TileFileError)
            if ds.shape != n_pings:
                raise TileFileError(f"{path}: dataset '/{k}' has shape {ds.shape}; "
                                    f"expected {n_pings} like '/ping_sequence'")
            out[k] = ds[()]
    attrs = dict(f.attrs)
    for k in REQUIRED_ATTRS:
        v = attrs.get(k)
        if v is None:
            raise TileFileError(f"{path}: root attribute '{k}' missing")
        if np.ndim(v) != 0 or not isinstance(np.asarray(v).item(), (int, float)) \
                or isinstance(np.asarray(v).item(), bool):
            raise TileFileError(f"{path}: root attribute '{k}' is {shown(v)}; expected a "
                                "number")
    out["attrs"] = attrs
    has_products = bool(np.asarray(attrs.get("has_products", False)).any())
    if has_products and "detections" not in f:
        raise TileFileError(f"{path}: group '/detections' missing; expected it in a tile "
                            "with products (root attribute has_products is true)")
    out["detections"] = _read_detections(f, path)
    prof = f.get("detections/tail_profile_db")
    if isinstance(prof, h5py.Dataset) and prof.ndim == 2 and prof.dtype.kind == "f" \
            and prof.shape[0] == len(out["detections"]) and prof.shape[1] <= 100_000:
        out["tail_profile_db"] = prof[()]
        out["tail_profile_step_m"] = float(prof.attrs.get("step_m", np.nan))
    out["products"] = [k for k in ("background", "drc", *MIPS, "detections") if k in f]
    if "coverage_full_pings" in f:
        out["coverage_full_pings"] = _volume(f, "coverage_full_pings", path,
                                             (out["depth"].size,), "u", ("depth",))[()]
    if "background" in f:
        out["background_attrs"] = {k: v for k, v in f["background"].attrs.items()
                                   if k != "DIMENSION_LIST"}
    for k in ("hardware_config_toml", "processing_config_toml"):
        if f"provenance/{k}" in f:
            out[k] = _text(dataset(f, f"provenance/{k}", path, 0, "SOU", TileFileError)[()])
    prov = f.get("provenance")
    out["poses"] = (_text(prov.attrs.get("poses")) if isinstance(prov, h5py.Group)
                    else None)
    out["seabed"] = _read_seabed(prov)
    # tiles written before the live method existed were made by the exact method
    out["imaging_method"] = (_text(prov.attrs.get("imaging_method", "exact"))
                             if isinstance(prov, h5py.Group) else None)
    return out


def _read_seabed(prov) -> dict | None:
    """``/provenance/seabed`` as written by :func:`_write_seabed` (None: a tile written
    before it was kept)."""
    g = prov.get("seabed") if isinstance(prov, h5py.Group) else None
    if not isinstance(g, h5py.Group):
        return None
    out = {}
    for k in ("status", "reason"):
        out[k] = _text(g.attrs.get(k, ""))
    for k in ("sediment_sound_speed_m_s", "sigma_m_s", "configured_m_s", "reduced_chi2"):
        v = float(g.attrs.get(k, np.nan))
        out[k] = None if not np.isfinite(v) else v
    out["disagrees"] = bool(g.attrs.get("disagrees", False))
    for key, default in (("responses", "[]"), ("layers", "[]")):
        try:
            out[key] = json.loads(_text(g.attrs.get(f"{key}_json", default)))
        except ValueError:
            out[key] = json.loads(default)
    for key in ("interface_json", "tiles_json"):
        try:
            out.update(json.loads(_text(g.attrs.get(key, "{}"))))
        except ValueError:
            pass
    return out


def read_tile_header(path: str | Path) -> dict:
    """Everything of a tile file but its volumes: the axes (``along``, ``cross``,
    ``depth``), ``ping_sequence``, ``attrs``, ``detections`` (empty when the tile has
    no ``/detections`` group: see ``products``), the names of the ``products`` it holds,
    ``background_attrs``, the configuration texts, ``poses`` (what the pings were posed
    with; None in tiles written before it was kept) and, for tiles with coverage,
    ``coverage_full_pings`` (per depth)."""
    return _read(path, _header)


def _full(f: h5py.File, path: Path) -> dict:
    out = _header(f, path)
    shape = tuple(out[d].size for d in DIMS)
    out["image"] = _data(_volume(f, "image", path, shape, "cfV"), path)
    if out["image"].dtype.kind == "V":      # an HDF5 compound (r, i) h5py did not map
        raise TileFileError(f"{path}: dataset '/image' has dtype {out['image'].dtype}; "
                            "expected complex64")
    out["magnitude"] = (_data(_volume(f, "magnitude", path, shape, "f"), path)
                        if "magnitude" in f else np.abs(out["image"]))
    for k in ("coverage_pings", "coverage_channels"):
        if k in f:
            out[k] = _data(_volume(f, k, path, shape, "u"), path)
    if "background" in f:
        out["background"] = _data(_volume(f, "background", path, shape, "f"), path)
    if "depth_gain_db" in f:
        out["depth_gain_db"] = _volume(f, "depth_gain_db", path, shape[2:], "f",
                                       ("depth",))[()]
    for k, (axis, dims) in MIPS.items():
        if k in f:
            out[k] = _data(_volume(f, k, path, tuple(n for i, n in enumerate(shape)
                                                     if i != axis), "f", dims), path)
    if "drc" in f:
        ds = _volume(f, "drc", path, shape, "u")
        scale = ds.attrs.get("scale_factor")
        if scale is None or np.ndim(scale) != 0:
            raise TileFileError(f"{path}: attribute '/drc' scale_factor is {shown(scale)}; "
                                "expected a number")
        out["drc"] = _data(ds, path).astype(np.float32) * np.float32(scale)
    return out


def _views(f: h5py.File, path: Path) -> dict:
    out = _header(f, path)
    shape = tuple(out[d].size for d in DIMS)
    for k, (axis, dims) in MIPS.items():
        if k in f:
            out[k] = _data(_volume(f, k, path, tuple(n for i, n in enumerate(shape)
                                                     if i != axis), "f", dims), path)
    if "coverage_pings" in f:
        out["coverage_plan"] = _data(_volume(f, "coverage_pings", path, shape, "u"),
                                     path).max(axis=2)
    return out


def read_tile_views(path: str | Path) -> dict:
    """:func:`read_tile_header` plus the MIPs the tile has and, for tiles with coverage,
    ``coverage_plan``: the most pings any voxel of each (along, cross) column got (0:
    a column no ping imaged). For run-level products, without the volumes."""
    return _read(path, _views)


def read_tile(path: str | Path) -> dict:
    """Read a tile file into plain arrays: :func:`read_tile_header` plus image,
    magnitude (|image|; stored in the file only by tiles written before issue 32) and,
    when the file has them, background, drc (decoded to 0..1),
    depth_gain_db, the MIPs (``mip_depth``, ``mip_cross``, ``mip_along``) and the
    coverage (``coverage_pings``, ``coverage_channels``; tiles written before coverage
    existed have none)."""
    return _read(path, _full)


def _read_detections(f: h5py.File, path: Path) -> np.ndarray:
    if "detections" not in f:
        return detect.empty()
    g = group(f, "detections", path, TileFileError)
    n = dataset(g, "detection", path, 1, "iu", TileFileError,
                what="contact numbers").shape[0]
    out = np.zeros(n, dtype=detect.DTYPE)
    for name in detect.DTYPE.names:
        if name in detect.OPTIONAL_FIELDS and name not in g:     # an older tile
            out[name] = detect.OPTIONAL_FIELDS[name]
            continue
        ds = dataset(g, name, path, 1, "iuf", TileFileError, what=f"{n} values")
        if ds.shape != (n,):
            raise TileFileError(f"{path}: dataset '/detections/{name}' has shape "
                                f"{ds.shape}; expected ({n},) like '/detections/detection'")
        out[name] = ds[()]
    return out


def read_detections(path: str | Path) -> tuple[np.ndarray, dict]:
    """The detection table of a tile file and the tile's root attributes. A tile
    without a ``/detections`` group (processed without products) is an error."""
    h = read_tile_header(path)
    if "detections" not in h["products"]:
        raise TileFileError(f"{path}: group '/detections' missing (the tile was processed "
                            "without [products]); it has no detections to read")
    return h["detections"], h["attrs"]
