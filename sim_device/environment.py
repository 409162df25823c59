"""The resolved environment of a scene: water, sea surface and sediment layers.

Pure data built from a :class:`~sim_device.scene.SceneConfig` and the sediment table;
the kernels receive it as flat arrays (:meth:`Environment.media`). Geometry is in the
scene's tile frame: z is the depth below the water-sediment interface (down positive),
the sea surface lies at z = -water_depth.

Media are numbered 0 (water) .. L (deepest sediment layer); boundary k (1 <= k <= L)
separates medium k-1 (above) from medium k and lies at depth ``z_top[k]``
(``z_top[1] = 0``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .acoustics import (Sediment, coppens_sound_speed, francois_garrison_absorption,
                        load_sediments, loss_parameter_from_attenuation,
                        sediment_attenuation_np_per_m)
from .scene import SceneConfig

log = logging.getLogger(__name__)

#: Np per dB for amplitudes (1 dB = ln(10)/20 Np).
NP_PER_DB = math.log(10.0) / 20.0


@dataclass(frozen=True)
class Layer:
    """A sediment layer from ``top_m`` to ``bottom_m`` (m below the interface; inf for
    the half-space)."""
    sediment: Sediment
    top_m: float
    bottom_m: float


@dataclass(frozen=True)
class Media:
    """Per-medium arrays for the kernels at one frequency (index 0 = water).

    c (m/s), rho (kg/m^3), delta (loss parameter), alpha (amplitude attenuation, Np/m),
    z_top (depth of each medium's top boundary, m; z_top[0] = -inf, z_top[1] = 0),
    rough (rms roughness of each medium's top boundary, m; rough[0] = 0).
    """
    c: np.ndarray
    rho: np.ndarray
    delta: np.ndarray
    alpha: np.ndarray
    z_top: np.ndarray
    rough: np.ndarray

    @property
    def n(self) -> int:
        return self.c.size


@dataclass(frozen=True)
class Environment:
    """Water, surface and seabed of a scene (SI units)."""
    water_sound_speed: float
    water_density: float
    water_depth: float | None            # m; None: no surface boundary known
    surface_reflection: float            # pressure reflection coefficient; 0: no surface
    layers: tuple[Layer, ...]
    absorption_model: str                # "none", "fixed" or "francois_garrison"
    absorption_db_m: float               # for "fixed"
    temperature_c: float | None
    salinity_ppt: float | None
    ph: float

    @property
    def has_seabed(self) -> bool:
        return bool(self.layers)

    @property
    def has_surface(self) -> bool:
        return self.surface_reflection != 0.0 and self.water_depth is not None

    def water_absorption_np_per_m(self, frequency: float) -> float:
        """Amplitude absorption of the water at ``frequency`` (Hz), Np/m."""
        if self.absorption_model == "fixed":
            return self.absorption_db_m * NP_PER_DB
        if self.absorption_model == "francois_garrison":
            depth = self.water_depth or 0.0
            db = francois_garrison_absorption(frequency, self.temperature_c,
                                              self.salinity_ppt, depth, self.ph)
            return float(db) * NP_PER_DB
        return 0.0

    def media(self, frequency: float) -> Media:
        """The media as kernel arrays at ``frequency`` (Hz)."""
        c = [self.water_sound_speed] + [ly.sediment.sound_speed for ly in self.layers]
        rho = [self.water_density] + [ly.sediment.density for ly in self.layers]
        delta = [0.0] + [ly.sediment.loss_parameter for ly in self.layers]
        alpha = [self.water_absorption_np_per_m(frequency)] + [
            float(sediment_attenuation_np_per_m(frequency, ly.sediment.sound_speed,
                                                ly.sediment.loss_parameter))
            for ly in self.layers]
        z_top = [-np.inf] + [ly.top_m for ly in self.layers]
        rough = [0.0] + [ly.sediment.rms_roughness for ly in self.layers]
        f = lambda v: np.ascontiguousarray(v, dtype=np.float64)  # noqa: E731
        return Media(f(c), f(rho), f(delta), f(alpha), f(z_top), f(rough))

    def medium_at(self, depth: float) -> int:
        """Index of the medium holding depth ``depth`` (m below the interface)."""
        if not self.layers or depth < 0.0:
            return 0
        for k, ly in enumerate(self.layers):
            if depth < ly.bottom_m:
                return k + 1
        return len(self.layers)


_OVERRIDES = {
    "density_kg_m3": "density", "sound_speed_m_s": "sound_speed",
    "loss_parameter": "loss_parameter", "spectral_strength_si": "spectral_strength",
    "spectral_exponent": "spectral_exponent", "volume_strength_db_m": "volume_strength_db",
    "rms_roughness_m": "rms_roughness",
}


def water_sound_speed(scene: SceneConfig) -> float:
    """The scene's water sound speed: given, or Coppens (1981) from T and S (m/s)."""
    m = scene.medium
    if m.sound_speed_m_s is not None:
        return m.sound_speed_m_s
    depth = m.depth_m or 0.0
    return float(coppens_sound_speed(m.temperature_c, m.salinity_ppt, 0.5 * depth))


def build_environment(scene: SceneConfig,
                      sediments: dict[str, Sediment] | None = None) -> Environment:
    """Resolve a scene's environment; sediments by name from ``config/sediments.toml``
    (or the table given), with the layer's overrides applied."""
    m = scene.medium
    layers: list[Layer] = []
    if scene.seabed is not None:
        table = sediments if sediments is not None else load_sediments()
        top = 0.0
        for k, spec_ in enumerate(scene.seabed.layers):
            if spec_.sediment not in table:
                raise ValueError(f"scene {scene.scene.name!r}: seabed.layers[{k}].sediment: "
                                 f"unknown sediment {spec_.sediment!r}; known: "
                                 f"{sorted(table)}")
            sed = table[spec_.sediment]
            changes = {}
            for key, attr in _OVERRIDES.items():
                v = getattr(spec_, key)
                if v is not None:
                    changes[attr] = v
            if "volume_strength_db" in changes:
                changes["sigma2_value"] = None
                if sed.reference_frequency is None:
                    raise ValueError(f"scene {scene.scene.name!r}: seabed.layers[{k}]: "
                                     f"sediment {sed.name!r} has no reference frequency "
                                     "for a volume strength override")
            if spec_.attenuation_db_m is not None:
                if sed.reference_frequency is None:
                    raise ValueError(f"scene {scene.scene.name!r}: seabed.layers[{k}]: "
                                     f"sediment {sed.name!r} has no reference frequency "
                                     "for an attenuation override")
                c_sed = changes.get("sound_speed", sed.sound_speed)
                changes["loss_parameter"] = float(loss_parameter_from_attenuation(
                    spec_.attenuation_db_m, sed.reference_frequency, c_sed))
                changes["quoted_attenuation_db_per_m"] = spec_.attenuation_db_m
            if changes:
                sed = sed.replace(**changes)
            bottom = top + spec_.thickness_m if spec_.thickness_m is not None else np.inf
            layers.append(Layer(sed, top, bottom))
            top = bottom
    surf = scene.surface
    r_surface = surf.reflection_coefficient if surf is not None and surf.kind == "flat" else 0.0
    return Environment(
        water_sound_speed=water_sound_speed(scene), water_density=m.density_kg_m3,
        water_depth=m.depth_m, surface_reflection=r_surface, layers=tuple(layers),
        absorption_model=m.absorption or "none", absorption_db_m=m.absorption_db_m or 0.0,
        temperature_c=m.temperature_c, salinity_ppt=m.salinity_ppt,
        ph=m.ph if m.ph is not None else 8.0)
