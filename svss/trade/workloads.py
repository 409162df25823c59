"""The workloads ``svss trade`` measures on: simulated pings over one sub-tile.

Full (the reference workloads of DESIGN.md, cut to a sub-tile so that every option can
be run in one sitting): the seed's buried aluminium cylinder in medium sand
(``config/scenes/seed_cylinder_sand.toml``), the pings that reach a sub-tile 0.6 m
long around the cylinder, full tile width and depth; per-tile figures are extrapolated
to the reference tile (15 m x 2 m x 2 m, 150 pings). Quick: the demo's point scatterers
(``scenes/demo.toml``) for imaging and a sand scene cut to 10 cm of volume for the
simulation, a few pings and a small sub-tile.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sim_device.environment import build_environment
from sim_device.scene import SceneConfig, load_scene
from svss_daq.config import (
    HardwareConfig,
    Loaded,
    ProcessingConfig,
    TileConfig,
    config_path,
)
from svss_daq.geometry import cone_reach

#: the reference tile of DESIGN.md: 15 m at 1 m/s and 10 pings/s
TILE_PINGS = 150


@dataclass(frozen=True)
class Workload:
    """Pings ``first .. first + n - 1`` (every ``stride``-th) of ``scene``, imaged into
    tile ``tile_index`` of ``tile`` (a sub-tile); ``target`` the tile-frame position (m)
    of the scene's first target or brightest point (None: none)."""
    name: str
    scene: SceneConfig
    first: int
    n: int
    stride: int
    tile: TileConfig
    tile_index: int
    target: tuple[float, float, float] | None

    @property
    def pings(self) -> list[int]:
        return list(range(self.first, self.first + self.n * self.stride, self.stride))


def sediment_speed(scene: SceneConfig) -> float | None:
    """Sound speed of the scene's top sediment (m/s; None without a seabed)."""
    env = build_environment(scene)
    return env.layers[0].sediment.sound_speed if env.layers else None


def ping_spacing(scene: SceneConfig, hw: HardwareConfig) -> float:
    """Along-track distance between pings (m)."""
    return scene.track.speed_m_s * hw.sequencer.ping_interval_s


def _reach(hw: HardwareConfig, tile: TileConfig, altitude: float) -> float:
    """Largest along-track distance from the projector at which it insonifies the tile."""
    return cone_reach(altitude + tile.top_m + tile.depth_m, 1.0,      # boresight down
                      math.radians(hw.beams.projector_half_angle_deg))


def around(scene: SceneConfig, hw: Loaded[HardwareConfig], tile: TileConfig,
           centre_along: float, name: str, stride: int = 1,
           target: tuple[float, float, float] | None = None) -> Workload:
    """The pings that reach a sub-tile of ``tile``'s width and depth, ``tile.length_m``
    long and holding along-track ``centre_along`` (m from the first ping's body origin),
    imaged in the frame of the first of them."""
    h = hw.value
    step = ping_spacing(scene, h)
    array_ahead = h.lever_arms.array_m[0] + float(np.mean(
        [p[0] for p in h.projectors.positions_m]))
    altitude = scene.track.altitude_m - h.lever_arms.array_m[2]
    reach = _reach(h, tile, altitude)
    lo = centre_along - 0.5 * tile.length_m - reach - array_ahead
    hi = centre_along + 0.5 * tile.length_m + reach - array_ahead
    first = max(0, math.floor(lo / step))
    last = min(scene.track.n_pings - 1, math.ceil(hi / step))
    # the tile frame starts at the first imaged ping: positions move back by its offset
    shift = first * step
    index = math.floor((centre_along - shift) / tile.length_m)
    tgt = None if target is None else (target[0] - shift, target[1], target[2])
    n = (last - first) // stride + 1
    return Workload(name, scene, first, n, stride, tile, index, tgt)


def imaging_workload(hw: Loaded[HardwareConfig], proc: ProcessingConfig,
                     quick: bool) -> Workload:
    """Pings for the imaging options (module docstring)."""
    if quick:
        sc = load_scene(config_path("scenes/demo.toml"))
        p = sc.points[0]
        tile = dataclasses.replace(proc.tile, length_m=0.32, width_m=0.32, depth_m=0.48,
                                   voxel_m=0.04)
        return around(sc, hw, tile, p.along_m, "demo points (quick)", stride=3,
                      target=(p.along_m, p.cross_m, p.depth_m))
    return _sand(hw, proc, "seed cylinder in sand", length=0.6, stride=1)


def simulation_workload(hw: Loaded[HardwareConfig], proc: ProcessingConfig,
                        quick: bool) -> Workload:
    """Pings for the simulation options: the sand scene (quick: 10 cm of volume, a
    small cylinder 12 cm deep, 2 pings 0.4 m apart, a 24 cm sub-tile at 4 cm)."""
    if quick:
        sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
        t = sc.targets[0]
        sc = dataclasses.replace(sc, scattering=dataclasses.replace(
            sc.scattering, volume_max_depth_m=0.1), targets=(dataclasses.replace(
                t, depth_m=0.12, radius_m=0.03, length_m=0.1),))
        tile = dataclasses.replace(proc.tile, length_m=0.24, width_m=0.48, depth_m=0.24,
                                   voxel_m=0.04)
        w = around(sc, hw, tile, t.along_m, "sand, 10 cm of volume (quick)", stride=4,
                   target=(t.along_m, t.cross_m, 0.12))
        mid = w.first + (w.n // 2) * w.stride
        return dataclasses.replace(w, first=mid - w.stride, n=2)
    return _sand(hw, proc, "seed cylinder in sand", length=0.4, stride=3, depth=1.6)


def _sand(hw, proc, name, length, stride, depth=None) -> Workload:
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    t = sc.targets[0]
    tile = dataclasses.replace(proc.tile, length_m=length,
                               depth_m=proc.tile.depth_m if depth is None else depth)
    return around(sc, hw, tile, t.along_m, name, stride=stride,
                  target=(t.along_m, t.cross_m, t.depth_m))


def extrapolation(tile: TileConfig, full: TileConfig) -> float:
    """Volume ratio of a full tile to the sub-tile ``tile``."""
    return (full.length_m / tile.length_m) * (full.width_m / tile.width_m) * (
        full.depth_m / tile.depth_m)
