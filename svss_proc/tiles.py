"""Tile files: HDF5 with named dimensions and coordinate variables (netCDF4-style
dimension scales, so xarray opens them), the complex image, its magnitude, and
provenance. See docs/formats.md.
"""

from __future__ import annotations

import time
from pathlib import Path

import h5py
import numpy as np

from svss_daq import __version__
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig

from .imager import Tile

TILE_FORMAT = "svss-tile"
TILE_FORMAT_VERSION = 1
DIMS = ("along", "cross", "depth")


def tile_name(index: int) -> str:
    return f"tile_{index:04d}"


def write_tile(path: str | Path, tile: Tile, hardware: Loaded[HardwareConfig],
               processing: Loaded[ProcessingConfig]) -> Path:
    """Write one tile to ``path`` (HDF5)."""
    path = Path(path)
    g = tile.grid
    with h5py.File(path, "w") as f:
        f.attrs.update({
            "svss_format": TILE_FORMAT, "svss_format_version": TILE_FORMAT_VERSION,
            "title": f"SVSS image {tile_name(g.index)}", "tile_index": g.index,
            "line_origin_north_m": tile.line.origin_ne[0],
            "line_origin_east_m": tile.line.origin_ne[1],
            "line_heading_rad": tile.line.heading,
            "interface_down_m": tile.line.interface_down,
            "voxel_m": processing.value.tile.voxel_m,
            "voxel_channel_updates": tile.updates,
            "software_name": "svss", "software_version": __version__,
            "creation_time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "hardware_config_id": hardware.id, "processing_config_id": processing.id,
        })
        axes = {"along": (g.along, "along-track distance from the line origin"),
                "cross": (g.cross, "cross-track distance, starboard positive"),
                "depth": (g.depth, "depth below the water-sediment interface")}
        for name, (values, long_name) in axes.items():
            ds = f.create_dataset(name, data=values)
            ds.attrs.update({"units": "m", "long_name": long_name})
            ds.make_scale(name)
        image = f.create_dataset("image", data=tile.image, chunks=True,
                                 compression="gzip", compression_opts=1, shuffle=True)
        image.attrs.update({"long_name": "complex backprojected image (coherent sum of "
                                         "matched-filter outputs)", "units": "uPa"})
        mag = f.create_dataset("magnitude", data=np.abs(tile.image).astype(np.float32),
                               chunks=True, compression="gzip", compression_opts=1,
                               shuffle=True)
        mag.attrs.update({"long_name": "image magnitude", "units": "uPa"})
        for ds in (image, mag):
            for i, d in enumerate(DIMS):
                ds.dims[i].attach_scale(f[d])
        pings = f.create_dataset("ping_sequence", data=np.asarray(tile.pings, dtype=np.int64))
        pings.attrs["long_name"] = "sequence numbers of the pings that went into the tile"
        prov = f.create_group("provenance")
        prov.create_dataset("hardware_config_toml", data=hardware.text)
        prov.create_dataset("processing_config_toml", data=processing.text)
    return path


def read_tile(path: str | Path) -> dict:
    """Read a tile file into plain arrays: image, magnitude, along, cross, depth, attrs."""
    path = Path(path)
    with h5py.File(path, "r") as f:
        if f.attrs.get("svss_format") != TILE_FORMAT:
            raise ValueError(f"{path}: root attribute 'svss_format' is "
                             f"{f.attrs.get('svss_format')!r}; expected {TILE_FORMAT!r}")
        out = {k: f[k][()] for k in ("image", "magnitude", *DIMS, "ping_sequence")}
        out["attrs"] = dict(f.attrs)
    return out
