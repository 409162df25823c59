"""Writing a finished tile's files: the HDF5 tile and its quicklook PNG."""

from __future__ import annotations

import logging
from pathlib import Path

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig

from .imager import Tile
from .quicklook import mip_png
from .tiles import tile_name, write_tile

log = logging.getLogger(__name__)


def save_tile(tile: Tile, out_dir: str | Path, hardware: Loaded[HardwareConfig],
              processing: Loaded[ProcessingConfig]) -> list[Path]:
    """Write ``tile_NNNN.h5`` and ``tile_NNNN_mip.png`` into ``out_dir``; return paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = tile_name(tile.grid.index)
    h5 = write_tile(out / f"{name}.h5", tile, hardware, processing)
    png = mip_png(out / f"{name}_mip.png", tile.image, tile.grid,
                  f"SVSS {name}: {len(tile.pings)} pings, along-track "
                  f"{tile.grid.along[0]:.2f}-{tile.grid.along[-1]:.2f} m")
    log.info("wrote %s (%d pings, %.2e voxel-channel updates) and %s", h5, len(tile.pings),
             tile.updates, png.name)
    return [h5, png]
