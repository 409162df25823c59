"""Scene files: the environment, the platform track and the targets a simulation shows.

The schema is declared here with :func:`svss_daq.config.spec`; the values live in
``config/scenes/*.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from svss_daq.config import load, spec


@dataclass(frozen=True)
class SceneInfo:
    name: str = spec("scene name")
    description: str = spec("what the scene shows")
    seed: int = spec("random seed", lo=0, hi=2**63 - 1)


@dataclass(frozen=True)
class MediumConfig:
    sound_speed_m_s: float = spec("sound speed of the homogeneous medium, m/s", lo=1000, hi=2500)
    density_kg_m3: float = spec("density, kg/m^3", lo=500, hi=5000)


@dataclass(frozen=True)
class TrackConfig:
    start_time_utc: str = spec("time of the first ping, ISO 8601 UTC")
    start_ne_m: tuple[float, float] = spec("first ping's body origin (north, east), m", length=2)
    heading_deg: float = spec("track heading, deg from north", lo=-360, hi=360)
    speed_m_s: float = spec("platform speed over ground, m/s", lo=0.0, hi=20)
    altitude_m: float = spec("body origin height above the water-sediment interface, m",
                             lo=0.1, hi=100)
    body_down_m: float = spec("body origin depth below the sea surface, m", lo=-10, hi=100)
    n_pings: int = spec("number of pings", lo=1, hi=10**7)


@dataclass(frozen=True)
class PointTarget:
    along_m: float = spec("along-track position from the first ping, m", lo=-1e4, hi=1e4)
    cross_m: float = spec("cross-track position, starboard positive, m", lo=-1e3, hi=1e3)
    depth_m: float = spec("depth below the water-sediment interface, m", lo=-100, hi=100)
    target_strength_db: float = spec("target strength, dB re 1 m^2", lo=-120, hi=40)


@dataclass(frozen=True)
class NoiseConfig:
    electronic_rms_counts: float = spec("white electronic noise per channel, ADC counts rms",
                                        lo=0.0, hi=1e7)


@dataclass(frozen=True)
class SceneConfig:
    scene: SceneInfo = spec("identity")
    medium: MediumConfig = spec("propagation medium")
    track: TrackConfig = spec("platform track")
    noise: NoiseConfig = spec("noise")
    points: tuple[PointTarget, ...] = spec("point scatterers", min_length=0)



def load_scene(path: str | Path) -> SceneConfig:
    """Read and validate a scene file."""
    return load(SceneConfig, path)
