"""Multipath by image sources: image positions against explicit mirror constructions, the
seed's multipath depths, and arrival times and levels of synthesised paths against the
image-source geometry."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.multipath import (coherent_paths, image_depth, leg_image, leg_pairs,
                                  max_leg_reflections)
from sim_device.scene import (PointTarget, SurfaceConfig,
                              TransducerConfig, load_scene)
from svss_daq.config import config_path
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner

D = 2.5          # water depth (m)


@pytest.mark.parametrize("m", range(6))
def test_leg_images_are_successive_mirrors(m):
    seq = "".join("S" if k % 2 == 0 else "B" for k in range(m))  # S, B, S ... upwards
    z_e = -2.0
    li = leg_image(m)
    assert li.n_surface == seq.count("S") and li.n_bottom == seq.count("B")
    z_img = image_depth(m, z_e, D)
    # mirror the element in reverse order of the reflections met going up
    z = z_e
    for b in reversed(seq):
        z = -2 * D - z if b == "S" else -z
    assert z_img == pytest.approx(z)
    # main lobe (leaves downwards) for even m, back lobe for odd m
    assert li.direction == (1.0 if m % 2 == 0 else -1.0)


def test_seed_multipath_depths():
    # PHYSICS.md section 8: array 2 m above the interface in 2.5 m of water; first-order
    # multipath appears at 0.6 m and second-order at 2.9 m sediment depth in sand
    c_w, c_s = 1500.0, 1767.0
    z_e = -2.0
    direct = -image_depth(0, z_e, D)
    first = -image_depth(1, z_e, D) - direct          # one surface bounce: 2 x 0.5 m
    second = -image_depth(2, z_e, D) - direct         # surface then seabed: 5 m
    assert first == pytest.approx(1.0) and second == pytest.approx(5.0)
    assert first / c_w * c_s / 2 == pytest.approx(0.6, abs=0.02)
    assert second / c_w * c_s / 2 == pytest.approx(2.9, abs=0.05)


def test_path_enumeration():
    assert leg_pairs(0, 0) == [(0, 0)]
    assert leg_pairs(2, 2) == [(0, 0), (0, 1), (1, 0), (0, 2), (1, 1), (2, 0)]
    assert max_leg_reflections(3, has_surface=False, has_seabed=True) == 0
    assert max_leg_reflections(3, has_surface=True, has_seabed=False) == 1
    seqs = [p.sequence for p in coherent_paths(2, has_surface=True)]
    assert seqs == ["B", "BS", "SB", "BSB", "SBS"]
    assert [p.sequence for p in coherent_paths(5, has_surface=False)] == ["B"]
    p = coherent_paths(2, True)[3]                     # B S B
    assert (p.n_surface, p.n_bottom, p.order, p.departure, p.arrival) == (1, 2, 2, 1, 1)
    # image of the projector for B S B: mirrored by B, then S, then B
    assert p.image_depth(-2.0, D) == pytest.approx(-(-2 * D - 2.0))


@pytest.fixture(scope="module")
def point_scene():
    """A point just above the sand interface, no seabed scattering, a flat surface and
    back lobes so that surface-bounce legs reach the elements."""
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    scat = dataclasses.replace(sc.scattering, interface=False, volume=False, specular=False)
    return dataclasses.replace(
        sc, scattering=scat, targets=(),
        points=(PointTarget(along_m=6.0, cross_m=0.1, depth_m=-0.01, target_strength_db=-10.0),),
        surface=SurfaceConfig(kind="flat", reflection_coefficient=-1.0, multipath_order=2,
                              drop_below_noise_db=200.0),
        transducers=TransducerConfig(pattern="cone", taper_deg=0.0, back_lobe_db=-6.0),
        noise=dataclasses.replace(sc.noise, electronic_rms_counts=0.0, sea_state=None))


def test_multipath_arrival_times_and_levels(hardware, point_scene):
    src = EnvironmentSource(hardware, point_scene)
    hw = hardware.value
    i = 30
    g = src.frame(i)
    ch = 20
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 1)
    cpu = counts_per_upa(hw.digitiser)
    pt = np.array([src.points.x[0], src.points.y[0], src.points.z[0]])
    amp0 = None
    for (a, b) in leg_pairs(2, 2):
        src.allowed = np.zeros((3, 3), dtype=bool)
        src.allowed[a, b] = True
        p = src.pressure(i)[ch]
        t = cond(p[None, :] * cpu)
        y = t.data[0]

        # expected: straight unfolded legs from the element images (independent geometry):
        # reflections met going up from the point are S, B, S, ...; the element's image
        # is mirrored by the last reflection first
        def leg_len(pos, m):
            z = pos[2]
            for b in reversed("SBSBSB"[:m]):
                z = -2 * D - z if b == "S" else -z
            return math.dist([pos[0], pos[1], 0.0], [pt[0], pt[1], 0.0]), abs(z - pt[2])
        h1, v1 = leg_len(g.tx, a)
        h2, v2 = leg_len(g.rx[ch], b)
        r1, r2 = math.hypot(h1, v1), math.hypot(h2, v2)
        tau = (r1 + r2) / 1500.0
        k = np.argmax(np.abs(y))
        # sub-sample peak by parabolic interpolation of |y|
        m = np.abs(y[k - 1:k + 2])
        frac = 0.5 * (m[0] - m[2]) / (m[0] - 2 * m[1] + m[2])
        t_peak = t.t0_s + (k + frac) * t.dt_s
        assert t_peak == pytest.approx(tau, abs=0.1 / 125e3), (a, b)
        # level: spreading, |R_s| per surface bounce, |R_b| per seabed bounce, lobes
        back = 10 ** (-6 / 20)
        lobes = (back if a % 2 else 1.0) * (back if b % 2 else 1.0)
        rb = 1.0
        for m_, v, r in ((a, v1, r1), (b, v2, r2)):
            n_b = m_ // 2
            if n_b:
                q = math.sqrt(1 - (v / r) ** 2)     # cos(grazing) of the seabed bounce
                rb *= abs(np.interp(q, np.linspace(0, 1, src.r_bot.size), src.r_bot)) ** n_b
        expect = lobes * rb / (r1 * r2)
        if amp0 is None:
            amp0 = (np.abs(y).max(), expect)
        else:
            ratio_db = 20 * np.log10(np.abs(y).max() / amp0[0])
            assert ratio_db == pytest.approx(20 * np.log10(expect / amp0[1]), abs=0.1), (a, b)
