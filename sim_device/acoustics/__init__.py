"""Pure, numpy-vectorised acoustics of the simulated device (SI units, angles in radians).

Modules: :mod:`.sediments` (sediment table and loader), :mod:`.attenuation` (sediment and
water attenuation, water sound speed), :mod:`.interface` (Rayleigh reflection,
transmission, Snell, Eckart), :mod:`.backscatter` (APL-UW TR 9407 bottom backscatter),
:mod:`.ambient_noise` (Knudsen ambient noise), :mod:`.directivity` (piston and cone
gains); decibels: :mod:`svss_daq.decibels`. Models, sources and validity:
``docs/acoustics.md``.
"""

from .attenuation import (ainslie_mccolm_absorption, coppens_sound_speed,
                          francois_garrison_absorption, loss_parameter_from_attenuation,
                          mackenzie_sound_speed, sediment_attenuation_db_per_m,
                          sediment_attenuation_np_per_m)
from .backscatter import (BackscatterComponents, bottom_backscatter, kirchhoff_parameters,
                          sigma2_from_volume_strength, sigma_composite, sigma_interface,
                          sigma_kirchhoff, sigma_perturbation, sigma_total, sigma_volume)
from .directivity import cone_gate, piston_directivity, piston_radius_for_half_angle
from .interface import (band_limited_rms_roughness, coherent_reflection_coefficient,
                        critical_angle, eckart_factor, reflection_coefficient,
                        snell_grazing_angle, transmission_coefficient, transmitted_angle)
from .ambient_noise import (ambient_noise_spectrum_level, band_noise_level, band_noise_rms_pressure,
                    white_noise_rms_per_sample)
from .sediments import Sediment, SedimentConfigError, load_sediments

__all__ = [
    "Sediment", "SedimentConfigError", "load_sediments",
    "sediment_attenuation_db_per_m", "sediment_attenuation_np_per_m",
    "loss_parameter_from_attenuation", "francois_garrison_absorption",
    "ainslie_mccolm_absorption", "mackenzie_sound_speed", "coppens_sound_speed",
    "reflection_coefficient", "transmission_coefficient", "critical_angle",
    "snell_grazing_angle", "transmitted_angle", "eckart_factor",
    "coherent_reflection_coefficient", "band_limited_rms_roughness",
    "kirchhoff_parameters", "sigma_kirchhoff", "sigma_perturbation", "sigma_composite",
    "sigma_interface", "sigma_volume", "sigma_total", "sigma2_from_volume_strength",
    "bottom_backscatter", "BackscatterComponents",
    "ambient_noise_spectrum_level", "band_noise_level", "band_noise_rms_pressure",
    "white_noise_rms_per_sample",
    "piston_directivity", "piston_radius_for_half_angle", "cone_gate",
]
