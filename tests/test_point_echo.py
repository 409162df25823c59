"""The first echo source: delays, spherical spreading, waveform, noise seeding."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_device.point_echo import PointEchoSource
from sim_device.scene import PointTarget, load_scene
from sim_device.track import ping_pose, truth_line
from svss_daq.config import config_path
from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import make_waveform


@pytest.fixture(scope="module")
def scene():
    return load_scene(config_path("scenes/demo.toml"))


def one_target_scene(scene, target, noise=0.0):
    return dataclasses.replace(scene, points=(target,),
                               noise=dataclasses.replace(scene.noise,
                                                         electronic_rms_counts=noise))


def test_single_echo_delay_and_level(hardware, scene):
    hw = hardware.value
    tgt = PointTarget(along_m=4.0, cross_m=0.2, depth_m=0.5, target_strength_db=-15.0)
    sc = one_target_scene(scene, tgt)
    src = PointEchoSource(hardware, sc)
    i = 10
    p = src.pressure(i)
    # independent geometry, written out here
    nav = ping_pose(sc.track, hw, i)
    geo = array_geometry(hw)
    rot = body_to_ned(0, 0, nav.heading_rad)
    proj = hw.sequencer.projector_order[i % 6]
    tx = nav.ned + rot @ geo.projectors[proj]
    rx = nav.ned + geo.receivers @ rot.T
    xt = truth_line(sc.track).tile_to_ned([4.0, 0.2, 0.5])
    r1 = np.linalg.norm(xt - tx)
    r2 = np.linalg.norm(xt - rx, axis=1)
    c = sc.medium.sound_speed_m_s
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    wf = make_waveform(hw.waveform)
    dig = hw.digitiser
    t = dig.window_start_s - dig.group_delay_s + np.arange(dig.window_samples) / dig.sample_rate_hz
    checked = 0
    for ch in range(80):
        expect = p0 * 10 ** (-15 / 20) / (r1 * r2[ch]) * wf.real(t - (r1 + r2[ch]) / c)
        if np.abs(expect).max() > 0 and np.any(p[ch]):
            np.testing.assert_allclose(p[ch], expect, rtol=1e-9, atol=1e-9 * np.abs(expect).max())
            checked += 1
    assert checked > 40    # most channels see the target


def test_outside_beams_is_silent(hardware, scene):
    far = PointTarget(along_m=30.0, cross_m=0.0, depth_m=0.5, target_strength_db=0.0)
    src = PointEchoSource(hardware, one_target_scene(scene, far))
    assert not np.any(src.pressure(0))


def test_same_seed_same_samples_any_order(hardware, scene):
    src = PointEchoSource(hardware, scene)
    a = [src.ping(i).samples for i in (3, 1, 2)]
    b = [PointEchoSource(hardware, scene).ping(i).samples for i in (1, 2, 3)]
    np.testing.assert_array_equal(a[0], b[2])
    np.testing.assert_array_equal(a[1], b[0])
    assert not np.array_equal(a[1], a[2])          # different pings, different noise
    other = dataclasses.replace(scene, scene=dataclasses.replace(scene.scene, seed=1))
    assert not np.array_equal(PointEchoSource(hardware, other).ping(1).samples, a[1])


def test_noise_level_and_quantisation(hardware, scene):
    far = PointTarget(along_m=300.0, cross_m=0.0, depth_m=0.5, target_strength_db=0.0)
    src = PointEchoSource(hardware, one_target_scene(scene, far, noise=50.0))
    ping = src.ping(0)
    assert ping.samples.dtype == np.int32 and ping.samples.shape == (80, 1500)
    assert abs(ping.samples.std() - 50.0) < 1.0
    assert ping.config_id == hardware.id
    assert counts_per_upa(hardware.value.digitiser) > 0
