"""The survey index: one CSV file per output folder (``survey_index.csv``) listing every
tile with its run, extent, pings, processing settings and detection count, read from
the tile files themselves. ``pandas.read_csv`` reads it as it is, and
``xarray.Dataset.from_dataframe`` makes a dataset of it (docs/batch.md lists the
columns).
"""

from __future__ import annotations

import csv
import logging
import math
import os
from pathlib import Path

from svss_daq.config import ProcessingConfig, loads

from .tiles import TILE_GLOB, is_temporary, read_tile_header, temporary_path

log = logging.getLogger(__name__)

INDEX_NAME = "survey_index.csv"

#: the columns, in order (units in the names: m, deg, m/s)
COLUMNS = (
    "run_id", "tile_index", "file",
    "along_min_m", "along_max_m", "cross_min_m", "cross_max_m", "depth_min_m",
    "depth_max_m", "voxel_m",
    "line_origin_north_m", "line_origin_east_m", "line_heading_deg", "interface_down_m",
    "n_pings", "first_ping", "last_ping", "n_detections",
    "processing_config_id", "hardware_config_id",
    "water_sound_speed_m_s", "sediment_sound_speed_m_s", "delays", "interpolation",
    "precision", "beam_gating", "close_after_pings",
)


def _settings(text: str | None, cache: dict) -> dict:
    """Key processing settings from a tile's processing configuration text."""
    if text is None:
        return {}
    if text not in cache:
        im = loads(ProcessingConfig, text, "tile provenance")
        cache[text] = {
            "water_sound_speed_m_s": im.imaging.water_sound_speed_m_s,
            "sediment_sound_speed_m_s": im.imaging.sediment_sound_speed_m_s,
            "delays": im.imaging.delays, "interpolation": im.imaging.interpolation,
            "precision": im.imaging.precision, "beam_gating": im.imaging.beam_gating,
            "close_after_pings": im.tile.close_after_pings}
    return cache[text]


def tile_row(path: Path, run_id: str, folder: Path, cache: dict | None = None) -> dict:
    """One index row for the tile file ``path`` (``file`` relative to ``folder``)."""
    h = read_tile_header(path)
    a = h["attrs"]
    v = float(a["voxel_m"])
    seq = h["ping_sequence"]
    row = {
        "run_id": run_id, "tile_index": int(a["tile_index"]),
        "file": os.path.relpath(path, folder),
        "voxel_m": v,
        "line_origin_north_m": float(a["line_origin_north_m"]),
        "line_origin_east_m": float(a["line_origin_east_m"]),
        "line_heading_deg": math.degrees(float(a["line_heading_rad"])),
        "interface_down_m": float(a["interface_down_m"]),
        "n_pings": int(seq.size),
        "first_ping": int(seq.min()) if seq.size else "",
        "last_ping": int(seq.max()) if seq.size else "",
        "n_detections": len(h["detections"]),
        "processing_config_id": str(a.get("processing_config_id", "")),
        "hardware_config_id": str(a.get("hardware_config_id", "")),
    }
    for d in ("along", "cross", "depth"):          # voxel edges, m
        row[f"{d}_min_m"] = float(h[d].min()) - v / 2
        row[f"{d}_max_m"] = float(h[d].max()) + v / 2
    row.update(_settings(h.get("processing_config_toml"), {} if cache is None else cache))
    return row


def find_tiles(folder: Path) -> list[tuple[str, Path]]:
    """(run, tile file) of the finished tiles in ``folder`` (the run: the folder's
    name) and in its sub-folders (the run: the sub-folder's name)."""
    folder = Path(folder)
    out = [(folder.name, p) for p in sorted(folder.glob(TILE_GLOB))]
    for d in sorted(p for p in folder.iterdir() if p.is_dir()):
        out += [(d.name, p) for p in sorted(d.glob(TILE_GLOB))]
    return [(r, p) for r, p in out if not is_temporary(p)]


def write_survey_index(folder: str | Path, tiles: list[tuple[str, Path]] | None = None
                       ) -> tuple[Path, list[dict]]:
    """Write ``folder/survey_index.csv`` (atomically) for ``tiles`` ((run id, tile
    file) pairs; default: :func:`find_tiles`); rows sorted by run and tile index.
    Returns the path and the rows."""
    folder = Path(folder)
    tiles = find_tiles(folder) if tiles is None else tiles
    cache: dict = {}
    rows = sorted((tile_row(Path(p), r, folder, cache) for r, p in tiles),
                  key=lambda row: (row["run_id"], row["tile_index"]))
    path = folder / INDEX_NAME
    tmp = temporary_path(path)          # unique: two writers never share it
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, restval="")
        w.writeheader()
        w.writerows(rows)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    log.info("wrote %s (%d tiles)", path, len(rows))
    return path, rows
