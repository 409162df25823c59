"""Tile files: HDF5 with named dimensions and coordinate variables (netCDF4-style
dimension scales, so ``xarray.open_dataset(path, engine="h5netcdf")`` opens them), the
complex image, its magnitude, the image products (background, compressed volume,
maximum intensity projections, detections) and provenance. See docs/formats.md.
"""

from __future__ import annotations

import functools
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from svss_daq import __version__
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig
from svss_daq.frames import TrackLine

from .products import detect
from .imaging.grid import TileGrid

if TYPE_CHECKING:
    from .products.chain import Products

TILE_FORMAT = "svss-tile"
TILE_FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
DIMS = ("along", "cross", "depth")
#: maximum intensity projections: name -> (axis projected over, remaining dimensions)
MIPS = {"mip_depth": (2, ("along", "cross")), "mip_cross": (1, ("along", "depth")),
        "mip_along": (0, ("cross", "depth"))}
DRC_SCALE = np.float32(1.0 / 255.0)
_GZIP = {"compression": "gzip", "compression_opts": 1, "shuffle": True}


@dataclass
class Tile:
    """A tile being formed or finished: the image (real and imaginary planes in the
    kernel's precision while forming) and what went into it."""
    grid: TileGrid
    line: TrackLine
    re: np.ndarray
    im: np.ndarray
    pings: list[int] = field(default_factory=list)
    updates: int = 0

    @functools.cached_property
    def image(self) -> np.ndarray:
        """The complex image (along x cross x depth), complex64, uPa; built once, when
        the tile is finished."""
        out = np.empty(self.re.shape, dtype=np.complex64)
        out.real = self.re
        out.imag = self.im
        return out

    def to_host(self) -> "Tile":
        """Bring device-resident planes (GPU imaging) back to host memory."""
        if hasattr(self.re, "copy_to_host"):
            self.re, self.im = self.re.copy_to_host(), self.im.copy_to_host()
        return self


def tile_name(index: int) -> str:
    return f"tile_{index:04d}"


def _attach(ds: h5py.Dataset, f: h5py.Group, dims: tuple[str, ...]) -> None:
    for i, d in enumerate(dims):
        ds.dims[i].attach_scale(f[d])


def write_tile(path: str | Path, tile: Tile, hardware: Loaded[HardwareConfig],
               processing: Loaded[ProcessingConfig],
               products: "Products | None" = None) -> Path:
    """Write one tile (and its products, if given) to ``path`` (HDF5)."""
    path = Path(path)
    g = tile.grid
    with h5py.File(path, "w") as f:
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
            ds = f.create_dataset(name, data=values)
            ds.attrs.update({"units": "m", "long_name": long_name})
            ds.make_scale(name)
        pings = f.create_dataset("ping_sequence", data=np.asarray(tile.pings, dtype=np.int64))
        pings.attrs["long_name"] = "sequence numbers of the pings that went into the tile"
        pings.make_scale("ping_sequence")
        image = f.create_dataset("image", data=tile.image, chunks=True, **_GZIP)
        image.attrs.update({"long_name": "complex backprojected image (coherent sum of "
                                         "matched-filter outputs)", "units": "uPa"})
        mag = f.create_dataset("magnitude", data=np.abs(tile.image).astype(np.float32),
                               chunks=True, **_GZIP)
        mag.attrs.update({"long_name": "image magnitude", "units": "uPa"})
        _attach(image, f, DIMS)
        _attach(mag, f, DIMS)
        if products is not None:
            _write_products(f, products)
        prov = f.create_group("provenance")
        prov.create_dataset("hardware_config_toml", data=hardware.text)
        prov.create_dataset("processing_config_toml", data=processing.text)
        prov.attrs.update({"software_name": "svss", "software_version": __version__,
                           "hardware_config_source": hardware.source,
                           "processing_config_source": processing.source})
    return path


def _write_products(f: h5py.File, p: "Products") -> None:
    f.attrs["n_detections"] = len(p.detections)
    f.attrs["products_timing_s"] = json.dumps({k: round(v, 4) for k, v in p.timings.items()})
    common = {"background_method": p.method, "background_kernel_voxels": p.kernel_voxels,
              "background_kernel_m": p.kernel_m, "background_boundary": p.boundary,
              "background_max_error_db": p.max_error_db}
    if p.background is not None:
        bg = f.create_dataset("background", data=p.background.astype(np.float32),
                              chunks=True, **_GZIP)
        bg.attrs.update({"long_name": "background: 3-D median of the magnitude",
                         "units": "uPa", "ignore_zeros": p.ignore_zeros,
                         "normalisation_floor_upa": p.floor_upa, **common})
        _attach(bg, f, DIMS)
    if p.drc is not None:
        q = np.round(np.clip(p.drc, 0.0, 1.0) * 255.0).astype(np.uint8)
        drc = f.create_dataset("drc", data=q, chunks=True, **_GZIP)
        drc.attrs.update({"long_name": "dynamic-range-compressed normalised level, 0..1",
                          "units": "1", "scale_factor": DRC_SCALE,
                          "add_offset": np.float32(0.0), **p.drc_attrs})
        _attach(drc, f, DIMS)
    gain = f.create_dataset("depth_gain_db", data=p.gain_db.astype(np.float32))
    gain.attrs.update({"long_name": "display gain added to the normalised level",
                       "units": "dB"})
    _attach(gain, f, ("depth",))
    for name, (axis, dims) in MIPS.items():
        ds = f.create_dataset(name, data=p.mips[name].astype(np.float32), **_GZIP)
        ds.attrs.update({"long_name": f"maximum intensity projection over {DIMS[axis]} "
                                      f"of the normalised level plus display gain",
                         "units": "dB re background", **common})
        _attach(ds, f, dims)
    grp = f.create_group("detections")
    n = len(p.detections)
    idx = grp.create_dataset("detection", data=np.arange(n, dtype=np.int64))
    idx.attrs["long_name"] = "contact number, strongest first"
    idx.make_scale("detection")
    for name, _, units, long_name in detect.FIELDS:
        ds = grp.create_dataset(name, data=p.detections[name])
        ds.attrs.update({"units": units, "long_name": long_name})
        ds.dims[0].attach_scale(idx)
    grp.attrs.update({k: v for k, v in p.detection_attrs.items()})


def _text(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def _open_tile(path: Path) -> h5py.File:
    """Open a tile file for reading, checking its format and version."""
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: not a readable HDF5 file ({exc})") from None
    fmt = _text(f.attrs.get("svss_format", ""))
    if fmt != TILE_FORMAT:
        f.close()
        raise ValueError(f"{path}: root attribute 'svss_format' is {fmt!r}; expected "
                         f"{TILE_FORMAT!r}")
    version = int(f.attrs.get("svss_format_version", -1))
    if version not in READABLE_VERSIONS:
        f.close()
        raise ValueError(f"{path}: svss_format_version {version}; this software reads "
                         f"versions {READABLE_VERSIONS}")
    return f


def _header(f: h5py.File) -> dict:
    out = {k: f[k][()] for k in (*DIMS, "ping_sequence")}
    out["attrs"] = dict(f.attrs)
    out["detections"] = _read_detections(f)
    out["products"] = [k for k in ("background", "drc", *MIPS, "detections") if k in f]
    if "background" in f:
        out["background_attrs"] = {k: v for k, v in f["background"].attrs.items()
                                   if k != "DIMENSION_LIST"}
    for k in ("hardware_config_toml", "processing_config_toml"):
        if f"provenance/{k}" in f:
            out[k] = _text(f[f"provenance/{k}"][()])
    return out


def read_tile_header(path: str | Path) -> dict:
    """Everything of a tile file but its volumes: the axes (``along``, ``cross``,
    ``depth``), ``ping_sequence``, ``attrs``, ``detections``, the names of the
    ``products`` it holds, ``background_attrs`` and the configuration texts."""
    with _open_tile(Path(path)) as f:
        return _header(f)


def read_tile(path: str | Path) -> dict:
    """Read a tile file into plain arrays: :func:`read_tile_header` plus image,
    magnitude and, when the file has them, background, drc (decoded to 0..1),
    depth_gain_db and the MIPs (``mip_depth``, ``mip_cross``, ``mip_along``)."""
    with _open_tile(Path(path)) as f:
        out = _header(f)
        out["image"] = f["image"][()]
        out["magnitude"] = (f["magnitude"][()] if "magnitude" in f
                            else np.abs(out["image"]))
        for k in ("background", "depth_gain_db", *MIPS):
            if k in f:
                out[k] = f[k][()]
        if "drc" in f:
            ds = f["drc"]
            out["drc"] = ds[()].astype(np.float32) * np.float32(ds.attrs["scale_factor"])
    return out


def _read_detections(f: h5py.File) -> np.ndarray:
    if "detections" not in f:
        return detect.empty()
    g = f["detections"]
    n = g["detection"].shape[0]
    out = np.zeros(n, dtype=detect.DTYPE)
    for name in detect.DTYPE.names:
        out[name] = g[name][()]
    return out


def read_detections(path: str | Path) -> tuple[np.ndarray, dict]:
    """The detection table of a tile file and the tile's root attributes."""
    h = read_tile_header(path)
    return h["detections"], h["attrs"]
