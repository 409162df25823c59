"""The environment echo source behind the Foundation's interface: pings, seeding whatever
the order, a seabed fixed in space, scatterers only where the beams see them, cost that
follows the scatterers in view, platform motion, targets, and ``svss simulate``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import MotionConfig, load_scene
from svss_daq.config import config_path
from svss_daq.ping import NAV_SIMULATED
from svss_daq.rawfile import RawRunReader


@pytest.fixture(scope="module")
def sand():
    """The seed's sand scene at low fidelity (cheap): direct paths, shallow volume."""
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    return dataclasses.replace(
        sc, targets=(), surface=dataclasses.replace(sc.surface, multipath_order=0),
        scattering=dataclasses.replace(sc.scattering, interface_density_per_m2=300.0,
                                       volume_density_per_m3=500.0, volume_max_depth_m=0.3))


def test_pings_follow_the_interface(hardware, sand):
    src = EnvironmentSource(hardware, sand)
    hw = hardware.value
    assert src.n_pings == sand.track.n_pings
    p = src.ping(7)
    assert p.samples.dtype == np.int32 and p.samples.shape == (80, 1500)
    assert p.sequence == 7 and p.projector == hw.sequencer.projector_order[7 % 6]
    assert p.config_id == hardware.id and p.nav.quality & NAV_SIMULATED
    assert p.window_start_ns == round(hw.digitiser.window_start_s * 1e9)
    assert p.sample_rate_hz == hw.digitiser.sample_rate_hz
    assert np.abs(p.samples).max() < 2 ** 23
    assert src.pressure(7).shape == (80, 1500)


def test_same_seed_same_samples_whatever_the_order(hardware, sand):
    src = EnvironmentSource(hardware, sand)
    a = [src.ping(i).samples for i in (12, 10, 11)]
    b = [EnvironmentSource(hardware, sand).ping(i).samples for i in (10, 11, 12)]
    np.testing.assert_array_equal(a[0], b[2])
    np.testing.assert_array_equal(a[1], b[0])
    np.testing.assert_array_equal(a[2], b[1])
    other = src.with_seed(sand.scene.seed + 1)
    assert not np.array_equal(other.ping(10).samples, a[1])


def test_the_seabed_stays_where_it_is(hardware, sand):
    # two pings 1 m apart see overlapping seabed: the common scatterers are identical
    src = EnvironmentSource(hardware, sand)
    s1, s2 = src.scatterers(30), src.scatterers(40)
    key = lambda s: {(round(x, 12), round(y, 12), round(z, 12)): a
                     for x, y, z, a in zip(s.x, s.y, s.z, s.amp)}
    k1, k2 = key(s1), key(s2)
    common = set(k1) & set(k2)
    assert len(common) > 300
    assert all(k1[c] == k2[c] for c in common)
    # a scene twice as long (or longer) has the same seabed and cost per ping
    long = dataclasses.replace(sand, track=dataclasses.replace(sand.track, n_pings=20000))
    s3 = EnvironmentSource(hardware, long).scatterers(30)
    np.testing.assert_array_equal(s3.x, s1.x)
    np.testing.assert_array_equal(s3.amp, s1.amp)


def test_scatterers_only_where_the_projector_can_see(hardware, sand):
    src = EnvironmentSource(hardware, sand)
    i = 25
    g = src.frame(i)
    s = src.scatterers(i, g)
    # every generated cell touches the cone's reach; nothing is made far away
    reach0 = src.seabed.reach(g.tx, g.bore, np.flatnonzero(src.allowed.any(axis=1)))(0.0)[0]
    horiz = np.hypot(s.x - g.tx[0], s.y - g.tx[1])
    cell = sand.scattering.cell_m
    assert horiz.max() < reach0 + 2 * math.sqrt(2) * cell + 0.3 * 1.0
    src.pressure(i)
    st = src.last_stats
    assert 0 < st["in_view"] <= st["generated"]
    # the interface scatterers kept by the transmit pass are inside the projector's cone
    iface = s.med == -1
    d = np.stack([s.x[iface], s.y[iface], s.z[iface]], 1) - g.tx
    ang = np.arccos(d @ g.bore / np.linalg.norm(d, axis=1))
    inside = ang <= src.tx_beam.edge
    assert 0 < inside.sum() < iface.sum()          # the cells reach past the cone's edge
    # ... and the count in view matches the scatterers inside the edges (volume ones too)
    assert st["in_view"] >= inside.sum()


def test_a_scene_without_targets_pays_nothing_for_them(hardware, sand):
    with_target = dataclasses.replace(
        sand, targets=load_scene(config_path("scenes/seed_cylinder_sand.toml")).targets)
    src = EnvironmentSource(hardware, with_target)
    a = src.pressure(3)                       # the cylinder, 10 m ahead, is unseen
    assert src.last_stats["targets_in_view"] == 0
    bare = EnvironmentSource(hardware, sand)
    assert bare.contributions == [] and bare.targets == []
    np.testing.assert_array_equal(a, bare.pressure(3))


def test_exact_refraction_and_extra_contributions(hardware, sand):
    a = EnvironmentSource(hardware, sand).pressure(9)
    exact = dataclasses.replace(sand, scattering=dataclasses.replace(sand.scattering,
                                                                     precision="exact"))
    b = EnvironmentSource(hardware, exact).pressure(9)
    # the two-medium table against Brent's method for every refracted leg
    assert np.sqrt(np.sum((a - b) ** 2) / np.sum(b ** 2)) < 1e-5
    src = EnvironmentSource(hardware, sand)
    src.contributions.append(lambda s, i, g: np.full((g.rx.shape[0], s.pulses.n), float(i)))
    np.testing.assert_allclose(src.pressure(9), a + 9.0, rtol=0, atol=1e-6)


def test_platform_motion_moves_the_array(hardware, sand):
    motion = MotionConfig(heave_m=0.2, heave_period_s=5.0, sway_m=0.1, sway_period_s=7.0,
                          roll_deg=3.0, roll_period_s=4.0, pitch_deg=2.0, pitch_period_s=6.0,
                          yaw_deg=1.0, yaw_period_s=9.0)
    sc = dataclasses.replace(sand, track=dataclasses.replace(sand.track, motion=motion))
    still = EnvironmentSource(hardware, sand)
    moving = EnvironmentSource(hardware, sc)
    i = 13
    a, b = still.frame(i), moving.frame(i)
    assert b.nav.roll_rad != 0 and b.nav.pitch_rad != 0
    heave = b.nav.down_m - a.nav.down_m
    assert b.nav.altitude_m == pytest.approx(a.nav.altitude_m - heave)
    assert not np.allclose(a.rx, b.rx)
    assert math.degrees(math.acos(b.bore[2])) == pytest.approx(
        math.degrees(math.acos(math.cos(b.nav.roll_rad) * math.cos(b.nav.pitch_rad))), abs=1e-9)
    # the first (specular) arrival follows the array's true height
    only = dataclasses.replace(sc, scattering=dataclasses.replace(
        sc.scattering, interface=False, volume=False))
    p = EnvironmentSource(hardware, only).specular(i)
    fs = hardware.value.digitiser.sample_rate_hz
    t0 = hardware.value.digitiser.window_start_s - hardware.value.digitiser.group_delay_s
    first = t0 + np.argmax(np.abs(p).max(axis=0) > 0.01 * np.abs(p).max()) / fs
    shortest = min(np.linalg.norm(b.rx - b.tx * [1, 1, -1], axis=1)) / 1500.0
    assert first == pytest.approx(shortest, abs=6 / fs)


def test_svss_simulate_writes_the_run(tmp_path, hardware):
    from svss.cli import main
    text = config_path("scenes/demo.toml").read_text().replace("n_pings = 90", "n_pings = 4")
    scene = tmp_path / "tiny.toml"
    scene.write_text(text)
    out = tmp_path / "run.h5"
    assert main(["-q", "simulate", "--scene", str(scene), "--out", str(out)]) == 0
    with RawRunReader(out) as run:
        assert len(run) == 4
        pings = list(run)
    assert pings[2].sequence == 2
    expect = EnvironmentSource(hardware, load_scene(scene)).ping(2)
    np.testing.assert_array_equal(pings[2].samples, expect.samples)
