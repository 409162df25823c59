"""Coherent returns: an empty scene (no sediment scattering, no noise) gives only the
specular returns, at the image-source delays, with Eckart's coherent level; a deeper
layer boundary returns at the refracted delay."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.acoustics import (cone_gate, eckart_factor, load_sediments,
                                  piston_directivity, piston_radius_for_half_angle,
                                  reflection_coefficient)
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import SedimentLayer, SeabedConfig, load_scene
from svss_daq.config import config_path
from svss_daq.scaling import counts_per_upa, quantise
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner

C_W = 1500.0
D = 2.5


def empty_scene(order=0, layers=None):
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    scat = dataclasses.replace(sc.scattering, interface=False, volume=False, specular=True)
    surf = dataclasses.replace(sc.surface, multipath_order=order) if order else None
    out = dataclasses.replace(sc, scattering=scat, surface=surf, targets=(), points=(),
                              noise=dataclasses.replace(sc.noise, electronic_rms_counts=0.0,
                                                        sea_state=None))
    if layers is not None:
        out = dataclasses.replace(out, seabed=SeabedConfig(layers=tuple(layers), slope_deg=None))
    return out


def layer(name, thickness=None, **overrides):
    """A seabed layer of the named sediment with the given overrides (others None)."""
    fields = {f.name: None for f in dataclasses.fields(SedimentLayer)}
    fields.update(sediment=name, thickness_m=thickness, **overrides)
    return SedimentLayer(**fields)


def gain(cos_off, half_deg):
    h = math.radians(half_deg)
    a = piston_radius_for_half_angle(h, 27500.0, C_W)
    th = np.arccos(np.clip(cos_off, -1, 1))
    return cone_gate(th, h, math.radians(2)) * piston_directivity(th, 27500.0, a, C_W)


def peak_time_and_level(y, t0, dt, near, half_width):
    """Sub-sample peak of |y| within ``half_width`` s of ``near``."""
    k0 = int(round((near - half_width - t0) / dt))
    k1 = int(round((near + half_width - t0) / dt))
    k = k0 + int(np.argmax(np.abs(y[k0:k1])))
    m = np.abs(y[k - 1:k + 2])
    frac = 0.5 * (m[0] - m[2]) / (m[0] - 2 * m[1] + m[2])
    return t0 + (k + frac) * dt, m[1] - 0.25 * (m[0] - m[2]) * frac


def test_empty_scene_gives_only_the_specular_returns(hardware):
    hw = hardware.value
    src = EnvironmentSource(hardware, empty_scene(order=2))
    i = 17
    g = src.frame(i)
    p = src.pressure(i)
    assert not np.any(src.scattered(i, g))                 # no scatterer at all
    np.testing.assert_array_equal(p, src.specular(i, g))
    np.testing.assert_array_equal(src.ping(i).samples, quantise(p, hw.digitiser)[0])
    # all the energy arrives at image-source delays: the projector's images for the
    # reflection sequences B, BS, SB, BSB, SBS (independent mirror construction)
    mirrors = {"S": lambda z: -2 * D - z, "B": lambda z: -z}
    fs = hw.digitiser.sample_rate_hz
    t = hw.digitiser.window_start_s - hw.digitiser.group_delay_s + np.arange(p.shape[1]) / fs
    for ch in (0, 40, 79):
        near = np.zeros(t.size, dtype=bool)
        for seq in ("B", "BS", "SB", "BSB", "SBS"):
            z = g.tx[2]
            for b in seq:
                z = mirrors[b](z)
            tau = math.dist([g.tx[0], g.tx[1], z], g.rx[ch]) / C_W
            near |= (t > tau - 5 / fs) & (t < tau + 3e-4)
        e = p[ch] ** 2
        assert e[~near].sum() < 1e-6 * e.sum()


def test_interface_specular_delay_and_eckart_level(hardware):
    hw = hardware.value
    src = EnvironmentSource(hardware, empty_scene())
    i = 3
    g = src.frame(i)
    p = src.pressure(i)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 1)
    y = cond(p * counts_per_upa(hw.digitiser))
    sand = load_sediments()["medium_sand"]
    rho, nu, d = sand.ratios(1000.0, C_W)
    wf = make_waveform(hw.waveform)
    # the pulse's spectrum on a fine grid, to weight the frequency-dependent Eckart loss
    ts = np.arange(0, wf.duration_s, 1 / 4e6)
    spec = np.abs(np.fft.rfft(wf.real(ts), 1 << 16)) ** 2
    f = np.fft.rfftfreq(1 << 16, 1 / 4e6)
    band = (f > 5e3) & (f < 60e3)
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    for ch in (5, 33, 70):
        img = np.array([g.tx[0], g.tx[1], -g.tx[2]])        # mirrored about the interface
        v = g.rx[ch] - img
        length = np.linalg.norm(v)
        theta = math.asin(abs(v[2]) / length)
        horiz = np.hypot(v[0], v[1])
        dep = np.array([v[0], v[1], abs(v[2])]) / length     # leaves the projector down
        arr = np.array([-v[0], -v[1], abs(v[2])]) / length   # back to the receiver: down
        gains = gain(dep @ g.bore, 25) * gain(arr @ g.bore, 50)
        r = abs(reflection_coefficient(theta, rho, nu, d))
        eck = eckart_factor(theta, f[band], sand.rms_roughness, C_W)
        weight = np.sum(spec[band] * eck) / np.sum(spec[band])   # matched-filter gain
        t_peak, level = peak_time_and_level(y.data[ch], y.t0_s, y.dt_s, length / C_W, 1e-4)
        assert t_peak == pytest.approx(length / C_W, abs=0.05 / 125e3)
        expect = p0 * gains * r * weight / length
        assert 20 * np.log10(level / expect) == pytest.approx(0.0, abs=0.2), ch
        assert horiz < 2.0


def test_deeper_layer_boundary_returns_at_the_refracted_delay(hardware):
    hw = hardware.value
    layers = [layer("very_fine_silt", 1.0), layer("medium_sand")]
    sc = empty_scene(layers=layers)
    src = EnvironmentSource(hardware, sc)
    i = 8
    g = src.frame(i)
    p = src.pressure(i)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 1)
    y = cond(p * counts_per_upa(hw.digitiser))
    silt = load_sediments()["very_fine_silt"]
    sand = load_sediments()["medium_sand"]
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    wf = make_waveform(hw.waveform)
    ts = np.arange(0, wf.duration_s, 1 / 4e6)
    spec = np.abs(np.fft.rfft(wf.real(ts), 1 << 16)) ** 2
    f = np.fft.rfftfreq(1 << 16, 1 / 4e6)
    band = (f > 5e3) & (f < 60e3)
    for ch in (10, 50):
        h_water = -g.tx[2] - g.rx[ch, 2]
        rho_h = math.hypot(*(g.rx[ch, :2] - g.tx[:2]))
        # least time through water (h_water) and 2 m of silt, by bisection on Snell's p
        lo, hi = 0.0, 1 / max(C_W, silt.sound_speed) * (1 - 1e-15)
        for _ in range(200):
            pp = 0.5 * (lo + hi)
            off = sum(h * pp * c / math.sqrt(1 - (pp * c) ** 2)
                      for h, c in ((h_water, C_W), (2.0, silt.sound_speed)))
            lo, hi = (pp, hi) if off < rho_h else (lo, pp)
        tau = pp * rho_h + sum(h * math.sqrt(1 / c ** 2 - pp ** 2)
                               for h, c in ((h_water, C_W), (2.0, silt.sound_speed)))
        t_peak, level = peak_time_and_level(y.data[ch], y.t0_s, y.dt_s, tau, 1e-4)
        # (the silt's attenuation, linear in f, skews the compressed pulse slightly, so
        # the parabolic peak is good to ~0.1 sample here)
        assert t_peak == pytest.approx(tau, abs=0.1 / 125e3)
        # level near normal incidence: T01 T10 R12 over the apparent range; the boundary's
        # Eckart loss (the sand's 1 cm roughness, seen from the silt) and 2 m of silt's
        # attenuation, both weighted over the pulse's band as a matched filter does
        r01 = reflection_coefficient(math.pi / 2, *silt.ratios(1000.0, C_W))
        r12 = (sand.density * sand.sound_speed - silt.density * silt.sound_speed) / (
            sand.density * sand.sound_speed + silt.density * silt.sound_speed)
        apparent = h_water + 2.0 * silt.sound_speed / C_W
        loss = (eckart_factor(math.pi / 2, f[band], sand.rms_roughness, silt.sound_speed)
                * 10 ** (-silt.attenuation_db_per_m(f[band]) * 2.0 / 20))
        weight = np.sum(spec[band] * loss) / np.sum(spec[band])
        expect = p0 * abs((1 - r01 ** 2) * r12) * weight / apparent
        assert 20 * np.log10(level / expect) == pytest.approx(0.0, abs=0.5), ch


def test_extremes_zero_roughness_and_very_high_attenuation(hardware):
    hw = hardware.value
    # zero roughness: the coherent return is the Rayleigh reflection itself (no Eckart)
    smooth = [layer("medium_sand", rms_roughness_m=0.0)]
    src = EnvironmentSource(hardware, empty_scene(layers=smooth))
    i = 3
    g = src.frame(i)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 1)
    y = cond(src.pressure(i) * counts_per_upa(hw.digitiser))
    sand = load_sediments()["medium_sand"]
    ch = 33
    img = np.array([g.tx[0], g.tx[1], -g.tx[2]])
    v = g.rx[ch] - img
    length = np.linalg.norm(v)
    dep = np.array([v[0], v[1], abs(v[2])]) / length
    arr = np.array([-v[0], -v[1], abs(v[2])]) / length
    r = abs(reflection_coefficient(math.asin(abs(v[2]) / length), *sand.ratios(1000.0, C_W)))
    expect = (10 ** (hw.waveform.source_level_db / 20) * gain(dep @ g.bore, 25)
              * gain(arr @ g.bore, 50) * r / length)
    _, level = peak_time_and_level(y.data[ch], y.t0_s, y.dt_s, length / C_W, 1e-4)
    assert 20 * np.log10(level / expect) == pytest.approx(0.0, abs=0.1)
    # very high attenuation (delta = 1, ~100 Np/m): nothing becomes infinite or NaN, and
    # the volume return shrinks as its penetration depth 1/(4 alpha) does (the volume
    # strength, in dB/m, is kept): by ~alpha ratio, 1/60, here
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    sc = dataclasses.replace(sc, targets=(), surface=None,
                             noise=dataclasses.replace(sc.noise, sea_state=None,
                                                       electronic_rms_counts=0.0))
    sc = dataclasses.replace(sc, scattering=dataclasses.replace(
        sc.scattering, interface=False, specular=False, volume_max_depth_m=0.5))
    lossy = dataclasses.replace(sc, seabed=SeabedConfig(layers=(
        layer("medium_sand", loss_parameter=1.0),), slope_deg=None))
    p_nominal = EnvironmentSource(hardware, sc).pressure(5)
    p_lossy = EnvironmentSource(hardware, lossy).pressure(5)
    assert np.all(np.isfinite(p_lossy)) and np.any(p_lossy)
    ratio_db = 10 * np.log10(np.sum(p_lossy ** 2) / np.sum(p_nominal ** 2))
    assert -24.0 < ratio_db < -12.0, ratio_db
