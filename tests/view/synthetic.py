"""A tile as the worker writes it (``save_tile``: products, quicklook, the commit by
rename), from a synthetic image: speckle and a few point scatterers, on the demo
processing configuration's grid. Seconds, without simulating or imaging pings."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text
from svss_daq.frames import TrackLine
from svss_daq.navigation import ned_to_geodetic
from svss_proc.imaging.coverage import Coverage
from svss_proc.imaging.grid import tile_grid
from svss_proc.products.chain import save_tile
from svss_proc.tiles import Tile

#: config/sim-device.toml's survey origin (lat deg, lon deg, height m)
ORIGIN = (41.5240, -70.6710, 0.0)
HEADING_RAD = np.radians(30.0)
T0_NS = 1_795_000_000 * 10**9


def line() -> TrackLine:
    return TrackLine((10.0, 5.0), float(HEADING_RAD), 3.0)


def write_synthetic_tile(out: str | Path, index: int, run_id: str, seed: int = 0
                         ) -> list[Path]:
    """``out/tile_NNNN.h5`` and its quicklook, as ``svss worker`` writes them."""
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load_with_text(ProcessingConfig, config_path("processing-demo.toml"))
    grid = tile_grid(proc.value.tile, index)
    rng = np.random.default_rng(seed + index)
    shape = grid.shape
    img = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
    a, c, d = np.meshgrid(grid.along, grid.cross, grid.depth, indexing="ij")
    for pa, pc, pd in ((0.3, -0.2, 0.3), (0.7, 0.25, 0.55)):
        r2 = ((a - (grid.along[0] + pa * (grid.along[-1] - grid.along[0]))) ** 2
              + (c - pc) ** 2 + (d - pd) ** 2)
        img += (200.0 * np.exp(-r2 / (2 * 0.03 ** 2))).astype(np.complex64)
    tl = line()
    pings = list(range(index * 30, index * 30 + 30))
    along = grid.along[0] + np.linspace(0, grid.along[-1] - grid.along[0], len(pings))
    ned = tl.tile_to_ned(np.stack([along, np.zeros_like(along), np.full_like(along, -3.0)],
                                  axis=1))
    track = [(T0_NS + s * 10**8, float(n), float(e)) for s, (n, e, _) in zip(pings, ned)]
    lat, lon, _ = ned_to_geodetic(ned[0], ORIGIN)
    cov = Coverage(np.full(shape, 30, np.uint16), np.full(shape, 3000, np.uint16), 128,
                   np.zeros((4, 3)), height_sum_m=3.0 * len(pings), n_pings=len(pings),
                   geodetic_ref=(float(lat), float(lon), *map(float, ned[0])))
    from svss_proc.seabed.speed import SpeedEstimate
    seabed = SpeedEstimate("estimated", 1767.0, 1500.0, "focus of buried responses", 20.0,
                           0.5, 3.0, [{"position": [1.0, 0.0, 0.5], "speed": 1767.0,
                                       "sigma": 20.0, "contrast_db": 30.0}]).summary()
    tile = Tile(grid, tl, img.real.copy(), img.imag.copy(), pings=pings, updates=1,
                coverage=cov, poses="synthetic", run_id=run_id, track=track, seabed=seabed)
    return save_tile(tile, out, hw, proc)
