"""Imaging a region of a simulated scene with the exact sediment sound speed.

A :class:`Region` is a box in the scene's track frame (along from the track's start,
cross starboard, depth below the interface). Each region gets its own
:class:`~svss_proc.imaging.imager.TileImager` whose processing is the project's
``processing.toml`` with, by :func:`dataclasses.replace`: the track line fixed on the
scene's track with its origin moved so that tile 0 is exactly the region; tiles of the
region's size; the refraction-table delays (``imaging.delays = "table"``) with
``sediment_sound_speed_m_s`` the scene's top sediment speed (the seed: "perfect knowledge
of the sediment sound speed"); no products (they are computed here, on the region). The
same pings feed every region, so one simulation serves several measures.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from sim_device.environment_source import EnvironmentSource
from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.imaging.imager import TileImager

log = logging.getLogger(__name__)

#: tiles either side of the region marked as written (not imaged)
NEIGHBOURS = 64


@dataclass(frozen=True)
class Region:
    """A box to image (m, the scene's track frame): ``along`` = (start, end), cross-track
    half-width ``half_width``, depth ``top``..``bottom`` below the interface, voxel edge
    ``voxel``."""
    along: tuple[float, float]
    half_width: float
    top: float
    bottom: float
    voxel: float = 0.02


@dataclass
class Volume:
    """An imaged region: the complex image (along x cross x depth, uPa), its voxel-centre
    axes (m, the scene's track frame), the voxel edge (m) and the pings imaged."""
    image: np.ndarray
    along: np.ndarray
    cross: np.ndarray
    depth: np.ndarray
    voxel: float
    pings: list

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.along, self.cross, self.depth


def region_processing(src: EnvironmentSource, region: Region) -> ProcessingConfig:
    """The processing configuration that images ``region`` of ``src``'s scene as tile 0
    (see the module docstring)."""
    proc = load(ProcessingConfig, config_path("processing.toml"))
    tr = src.scene.track
    h = math.radians(tr.heading_deg)
    a0 = region.along[0]
    origin = (tr.start_ne_m[0] + a0 * math.cos(h), tr.start_ne_m[1] + a0 * math.sin(h))
    return dataclasses.replace(
        proc, products=None,
        tile=dataclasses.replace(
            proc.tile, length_m=region.along[1] - region.along[0],
            width_m=2 * region.half_width, depth_m=region.bottom - region.top,
            top_m=region.top, voxel_m=region.voxel, close_after_pings=100000),
        imaging=dataclasses.replace(
            proc.imaging, track_line="fixed", line_origin_ne_m=origin,
            line_heading_deg=tr.heading_deg, delays="table",
            water_sound_speed_m_s=float(src.media.c[0]),
            sediment_sound_speed_m_s=float(src.media.c[1])))


def image_regions(src: EnvironmentSource, pings, regions: dict[str, Region],
                  label: str = "") -> tuple[dict[str, Volume], dict]:
    """Simulate ``pings`` of ``src`` (noise included) and image each of ``regions``;
    returns the volumes by name and timings (s: simulation, imaging)."""
    imagers = {name: TileImager(src.hardware, region_processing(src, r))
               for name, r in regions.items()}
    for im in imagers.values():
        # only tile 0 (the region) is wanted: the imager leaves tiles it has already
        # written alone, so the neighbours a ping's cone also reaches are marked so
        # (halves the imaging: a cone reaches ~3 m either side at 3 m depth)
        im.schedule.mark_done(k for k in range(-NEIGHBOURS, NEIGHBOURS + 1) if k != 0)
    found: dict[str, object] = {}
    t_sim = t_img = 0.0
    pings = list(pings)
    t_log = time.perf_counter()
    for n, i in enumerate(pings):
        t0 = time.perf_counter()
        ping = src.ping(i)
        t1 = time.perf_counter()
        t_sim += t1 - t0
        for name, im in imagers.items():
            for tile in im.add(ping):
                if tile.grid.index == 0:
                    found[name] = tile
        t_img += time.perf_counter() - t1
        if time.perf_counter() - t_log > 20 or n == len(pings) - 1:
            t_log = time.perf_counter()
            log.info("%s: ping %d (%d of %d), %.1f s simulating, %.1f s imaging", label, i,
                     n + 1, len(pings), t_sim, t_img)
    out = {}
    for name, im in imagers.items():
        for tile in im.finish():
            if tile.grid.index == 0:
                found[name] = tile
        if name not in found:
            raise ValueError(f"{label}: no ping reached region {name!r} {regions[name]}")
        tile, r = found[name], regions[name]
        g = tile.grid
        out[name] = Volume(np.asarray(tile.image), g.along + r.along[0], g.cross.copy(),
                           g.depth.copy(), r.voxel, list(tile.pings))
    return out, {"simulation_s": t_sim, "imaging_s": t_img, "pings": len(pings)}
