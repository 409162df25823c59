"""The seed's scenes (config/scenes/seed_cylinder_*.toml, sayers_field.toml), their
variants for the sensitivity study, the two arrays, and the pings a measure needs.

Variants are made with :func:`dataclasses.replace` on the loaded scene, never by editing
the files: the cylinder's axis (across or along the track), the seabed's roughness
spectrum (exponent gamma and strength w2 of W(K) = w2 K^-gamma, the only spectral
parameters the sediment table carries), the seed (seabed realisation) and the scatterer
density per resolution cell.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import SceneConfig, load_scene
from svss_daq.config import HardwareConfig, Loaded, config_path, load_with_text
from svss_daq.geometry import cone_reach

#: the arrays: the paper-era 4 x 8 array with five projectors (the seed's simulation)
#: and the 80-channel field array with six
ARRAYS = {"paper": "hardware-paper.toml", "80ch": "hardware.toml"}
#: the seed's two simulations and the test field
SCENES = {"sand": "scenes/seed_cylinder_sand.toml", "silt": "scenes/seed_cylinder_silt.toml",
          "field": "scenes/sayers_field.toml"}
#: cylinder axis headings re the track (deg): across (the scene files) and along
AXES = {"across": 90.0, "along": 0.0}


def load_hardware(array: str) -> Loaded[HardwareConfig]:
    """The hardware of ``array`` (a key of :data:`ARRAYS`)."""
    if array not in ARRAYS:
        raise ValueError(f"array {array!r}; expected one of {sorted(ARRAYS)}")
    return load_with_text(HardwareConfig, config_path(ARRAYS[array]))


@dataclass(frozen=True)
class Variant:
    """What the seed leaves unstated, and the realisation: cylinder ``axis`` (a key of
    :data:`AXES`), roughness ``gamma`` (None: the sediment table's) and ``w2_scale``
    (factor on the table's w2), scene ``seed`` (None: the file's), scatterers per
    resolution cell (None: the file's)."""
    axis: str = "across"
    gamma: float | None = None
    w2_scale: float = 1.0
    seed: int | None = None
    per_cell: float | None = None

    def label(self) -> str:
        parts = [f"axis {self.axis}"]
        if self.gamma is not None:
            parts.append(f"gamma {self.gamma:g}")
        if self.w2_scale != 1.0:
            parts.append(f"w2 x{self.w2_scale:g}")
        if self.seed is not None:
            parts.append(f"seed {self.seed}")
        return ", ".join(parts)


def seed_scene(name: str, variant: Variant = Variant()) -> SceneConfig:
    """The scene ``name`` (a key of :data:`SCENES`) with ``variant`` applied."""
    if name not in SCENES:
        raise ValueError(f"scene {name!r}; expected one of {sorted(SCENES)}")
    scene = load_scene(config_path(SCENES[name]))
    if name == "field":
        return scene if variant.seed is None else dataclasses.replace(
            scene, scene=dataclasses.replace(scene.scene, seed=variant.seed))
    if variant.axis not in AXES:
        raise ValueError(f"cylinder axis {variant.axis!r}; expected one of {sorted(AXES)}")
    targets = tuple(dataclasses.replace(t, axis_heading_deg=AXES[variant.axis])
                    if t.kind == "cylinder" else t for t in scene.targets)
    top = scene.seabed.layers[0]
    if variant.gamma is not None or variant.w2_scale != 1.0:
        from sim_device.acoustics import load_sediments  # the table the scene refers to
        sed = load_sediments()[top.sediment]
        gamma = sed.spectral_exponent if variant.gamma is None else variant.gamma
        w2 = sed.spectral_strength if top.spectral_strength_si is None \
            else top.spectral_strength_si
        if variant.gamma is not None:
            # keep the spectrum's level at K = 2k (the Bragg wavenumber of grazing
            # backscatter at the 27.5 kHz carrier in water, 230 rad/m): a change of gamma
            # then tilts the spectrum about the scale the sonar sees
            k_bragg = 2 * 2 * math.pi * 27500.0 / 1500.0
            w2 = w2 * k_bragg ** (gamma - sed.spectral_exponent)
        top = dataclasses.replace(top, spectral_exponent=gamma,
                                  spectral_strength_si=w2 * variant.w2_scale)
    layers = (top,) + tuple(scene.seabed.layers[1:])
    scat = scene.scattering
    if variant.per_cell is not None:
        scat = dataclasses.replace(scat, scatterers_per_resolution_cell=variant.per_cell)
    out = dataclasses.replace(scene, targets=targets, scattering=scat,
                              seabed=dataclasses.replace(scene.seabed, layers=layers))
    if variant.seed is not None:
        out = dataclasses.replace(out, scene=dataclasses.replace(out.scene, seed=variant.seed))
    return out


def source(array: str, name: str, variant: Variant = Variant()) -> EnvironmentSource:
    """The echo source of scene ``name`` with ``variant`` for ``array``."""
    return EnvironmentSource(load_hardware(array), seed_scene(name, variant))


def top_sediment_speed(src: EnvironmentSource) -> float:
    """The scene's top sediment sound speed (m/s): what the imager is given as exact."""
    return float(src.media.c[1])


def array_along(src: EnvironmentSource, i: int) -> float:
    """Along-track position (tile frame of the scene's track, m) of ping ``i``'s
    projector."""
    return float(src.frame(i).tx[0])


def pings_over(src: EnvironmentSource, lo_m: float, hi_m: float) -> range:
    """The pings whose projector lies within [lo_m, hi_m] along the track (m)."""
    a0 = array_along(src, 0)
    step = array_along(src, 1) - a0
    first = max(0, math.ceil((lo_m - a0) / step - 1e-9))
    last = min(src.n_pings - 1, math.floor((hi_m - a0) / step + 1e-9))
    return range(first, last + 1)


def reach_m(src: EnvironmentSource, depth_m: float) -> float:
    """Horizontal reach (m) of the projector's cone edge (half-angle plus the transducer
    taper) down to ``depth_m`` below the interface, refracted into the top sediment:
    the along-track half-aperture a voxel at that depth is imaged with."""
    hw = src.hw
    tr = src.scene.transducers
    half = math.radians(hw.beams.projector_half_angle_deg
                        + (tr.taper_deg if tr is not None else 0.0))
    height = -float(src.frame(0).tx[2])
    s = math.sin(half) * float(src.media.c[1]) / float(src.media.c[0])
    below = max(depth_m, 0.0) * s / math.sqrt(1 - s * s) if s < 1 else math.inf
    return cone_reach(height, 1.0, half) + below
