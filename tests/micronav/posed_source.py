"""A simulated sonar whose true poses are the scene's track plus offsets chosen per ping
(steps and ramps of sway, surge and heave), for the micronavigation tests: the echoes
are synthesised by the project's simulator from those poses, and the offsets are the
truth the estimators are checked against."""

from __future__ import annotations

import dataclasses

import numpy as np

from sim_device.environment_source import EnvironmentSource, PingGeometry
from svss_daq.scaling import quantise
from sim_device.track import ping_pose
from svss_daq.geometry import place_array
from svss_daq.ping import Ping


class PosedSource(EnvironmentSource):
    """``offsets(i)`` -> (surge, sway, heave) m added to ping i's track pose (along the
    heading, starboard, down); the altitude falls by the heave (the seabed stays)."""

    def __init__(self, hardware, scene, offsets):
        self.offsets = offsets          # before the base class places ping 0
        super().__init__(hardware, scene)

    def true_pose(self, i: int):
        nav = ping_pose(self.scene.track, self.hw, i, self.seed)
        surge, sway, heave = self.offsets(i)
        h = nav.heading_rad
        return dataclasses.replace(
            nav, north_m=nav.north_m + surge * np.cos(h) - sway * np.sin(h),
            east_m=nav.east_m + surge * np.sin(h) + sway * np.cos(h),
            down_m=nav.down_m + heave, altitude_m=nav.altitude_m - heave)

    def frame(self, i: int) -> PingGeometry:
        nav = self.true_pose(i)
        placed = place_array(self.geometry, nav, self.assembler.projector_of(i), self.line)
        return PingGeometry(placed.tx, placed.rx, placed.bore, placed.projector, nav)

    def ping(self, i: int) -> Ping:
        p = self.pressure(i) + self.noise(i)
        codes, _ = quantise(p, self.hw.digitiser)
        return self.assembler.from_simulation(i, codes, self.true_pose(i))


def interface_sand_scene():
    """The seed's sand scene without its target, volume and multipath: the interface's
    echo is what the micronavigation estimator uses; the rest costs synthesis time."""
    from sim_device.scene import load_scene
    from svss_daq.config import config_path
    scene = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    return dataclasses.replace(
        scene, targets=(), scattering=dataclasses.replace(scene.scattering, volume=False),
        surface=dataclasses.replace(scene.surface, multipath_order=0))

