"""Which multipath combinations a scene synthesises: a (projector legs, receiver legs)
combination is kept when its nadir sonar-equation level lies within
``drop_below_noise_db`` of the noise in the pulse's band (the direct path always)."""

from __future__ import annotations

import logging
import math

import numpy as np

from svss_daq.decibels import power_to_db

from .acoustics import Sediment, sigma_interface, sigma_volume
from .environment import Environment
from .multipath import image_depth, leg_image, leg_pairs

log = logging.getLogger(__name__)


def nadir_sigma(fidelity, env: Environment, top: Sediment | None, fc: float) -> float:
    """Interface plus volume backscatter near normal incidence (linear), for the
    path-level estimate."""
    if fidelity is None or not env.has_seabed:
        return 0.0
    th = math.radians(85.0)
    cw = env.water_sound_speed
    if fidelity.interface_model == "constant":
        s_int = 10.0 ** (fidelity.interface_strength_db / 10.0)
    elif top is not None:
        rho, nu, d = top.ratios(env.water_density, cw)
        s_int = float(sigma_interface(th, fc, rho, nu, d, top.spectral_strength,
                                      top.spectral_exponent, cw))
    else:
        s_int = 0.0
    s_vol = 0.0
    if top is not None:
        rho, nu, d = top.ratios(env.water_density, cw)
        s_vol = float(sigma_volume(th, rho, nu, d, top.sigma2()))
    return (s_int if fidelity.interface else 0.0) + (s_vol if fidelity.volume else 0.0)


def path_geometry(a: int, b: int, tx_z: float, rx_z: float, depth: float,
                  env: Environment, r_bottom: float, back_lobe: float,
                  pulse_s: float) -> tuple[float, float, float, float]:
    """Leg pair (``a`` transmit, ``b`` receive image legs) at nadir: the heights of the
    two image sources above the interface (m), the amplitude factor of their surface and
    bottom reflections (``r_bottom`` = |R| at normal incidence) and back lobes, and the
    area of the annulus one pulse insonifies (m^2)."""
    la, lb = leg_image(a), leg_image(b)
    h_t = -float(image_depth(a, tx_z, depth))
    h_r = -float(image_depth(b, rx_z, depth))
    lobes = (1.0 if a % 2 == 0 else back_lobe) * (1.0 if b % 2 == 0 else back_lobe)
    refl = (abs(env.surface_reflection) ** (la.n_surface + lb.n_surface)
            * r_bottom ** (la.n_bottom + lb.n_bottom))
    area = math.pi * 0.5 * (h_t + h_r) * env.water_sound_speed * pulse_s
    return h_t, h_r, lobes * refl, area


def choose_paths(*, order: int, m_max: int, tx_z: float, rx_z: float,
                 water_depth: float | None, sigma: float, target_strength: float,
                 p0: float, pulse_s: float, env: Environment, r_bottom: float,
                 back_lobe: float, noise_power: float,
                 drop_db: float) -> tuple[np.ndarray, dict]:
    """allowed[m_tx, m_rx] and the nadir level (dB re uPa^2) of each combination.

    ``tx_z``/``rx_z``: projector and mean receiver depth in the tile frame (m, negative
    above the interface); ``sigma``: nadir backscatter (linear); ``target_strength``:
    the strongest scene point (linear, m^2); ``pulse_s``: pulse length; ``r_bottom``:
    |R| of the interface at normal incidence; ``back_lobe``: the transducers' back-lobe
    amplitude."""
    n = m_max + 1
    allowed = np.zeros((n, n), dtype=np.bool_)
    pairs = leg_pairs(order, m_max) or [(0, 0)]
    depth = water_depth if water_depth is not None else 0.0
    levels = {}
    noise_db = float(power_to_db(noise_power))
    for (a, b) in pairs:
        h_t, h_r, amp, area = path_geometry(a, b, tx_z, rx_z, depth, env, r_bottom,
                                            back_lobe, pulse_s)
        ms = (0.5 * p0 ** 2 * amp ** 2 * (sigma * area + target_strength)
              / (h_t * h_r) ** 2)
        level = float(power_to_db(ms))
        levels[(a, b)] = level
        keep = (a, b) == (0, 0) or noise_power <= 0 or level >= noise_db - drop_db
        allowed[a, b] = keep
        if not keep:
            log.info("multipath legs (%d, %d) dropped: nadir level %.1f dB re uPa^2, "
                     "noise %.1f dB", a, b, level, noise_db)
    return allowed, levels
