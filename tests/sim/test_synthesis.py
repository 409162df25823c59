"""Echo synthesis: fractional-delay accumulation against an independent band-limited
echo, the pulse as the digitiser sees it, the phase rotation, the beam tables, a point
scatterer's exact echo (written out here) reproduced, and noise and quantisation.

The references place the array themselves, from the true pose, the documented array
layout and the rotation in closed form (tests/references.py) and the track's line, so
that a wrong placement in the simulator fails them."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.acoustics import piston_directivity, piston_radius_for_half_angle
from sim_device.beams import beam_table
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import MotionConfig, PointTarget, load_scene
from sim_device.track import ping_pose
from sim_device.synthesis import AA_PASS, AA_STOP, cis_cycles, digitised_pulse
from svss_daq.config import config_path
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner
from tests.references import body_to_ned_written_out, receivers_written_out


@pytest.fixture(scope="module")
def demo():
    return load_scene(config_path("scenes/demo.toml"))


def one_point(scene, target):
    return dataclasses.replace(scene, points=(target,), noise=dataclasses.replace(
        scene.noise, electronic_rms_counts=0.0))


def elements_written_out(hw, sc, i):
    """Projector, receivers (n, 3) and boresight of ping ``i`` in the scene's tile frame
    (along the track heading from the first ping's body origin, cross-track starboard,
    depth below the nominal bottom), placed here: the true pose of ping ``i``, the body
    rotation in closed form, the documented receiver layout, the configured projector
    positions and lever arm."""
    nav = ping_pose(sc.track, hw, i, sc.scene.seed)
    rot = body_to_ned_written_out(nav.roll_rad, nav.pitch_rad, nav.heading_rad)
    lever = np.asarray(hw.lever_arms.array_m, float)
    order = hw.sequencer.projector_order
    proj_body = np.asarray(hw.projectors.positions_m[order[i % len(order)]], float) + lever
    rx_body = receivers_written_out() + lever
    body_ned = np.array([nav.north_m, nav.east_m, nav.down_m])
    h = math.radians(sc.track.heading_deg)
    to_tile = np.array([[math.cos(h), math.sin(h), 0.0], [-math.sin(h), math.cos(h), 0.0],
                        [0.0, 0.0, 1.0]])
    origin = np.array([sc.track.start_ne_m[0], sc.track.start_ne_m[1],
                       sc.track.body_down_m + sc.track.altitude_m])
    tx = to_tile @ (body_ned + rot @ proj_body - origin)
    rx = (body_ned + rx_body @ rot.T - origin) @ to_tile.T
    bore = np.asarray(hw.beams.boresight, float)
    bore = to_tile @ rot @ (bore / np.linalg.norm(bore))
    return tx, rx, bore


def band_limited_echo(wf, t, tau, fs, os=32):
    """s(t - tau) through the simulated digitiser's anti-alias response, computed on a
    fine grid (written out here, independently of the synthesiser)."""
    n = 1 << int(math.ceil(math.log2((t[-1] - t[0] + 4e-3) * fs * os)))
    tf = t[0] - 1e-3 + np.arange(n) / (fs * os)
    spec = np.fft.rfft(wf.real(tf - tau))
    f = np.fft.rfftfreq(n, 1 / (fs * os))
    lo, hi = AA_PASS * fs, AA_STOP * fs
    taper = 0.5 * (1 + np.cos(np.pi * np.clip((f - lo) / (hi - lo), 0, 1)))
    h = np.where(f <= lo, 1.0, np.where(f >= hi, 0.0, taper))
    y = np.fft.irfft(spec * h, n)
    return np.interp(t, tf, y)


def test_point_echo_matches_an_independent_band_limited_echo(hardware, demo):
    hw = hardware.value
    tgt = PointTarget(along_m=4.0, cross_m=0.2, depth_m=0.5, target_strength_db=-15.0)
    sc = one_point(demo, tgt)
    src = EnvironmentSource(hardware, sc)
    i = 10
    p = src.pressure(i)
    tx, rx, _ = elements_written_out(hw, sc, i)
    wf = make_waveform(hw.waveform)
    dig = hw.digitiser
    fs = dig.sample_rate_hz
    t = dig.window_start_s - dig.group_delay_s + np.arange(dig.window_samples) / fs
    xt = np.array([4.0, 0.2, 0.5])
    r1 = np.linalg.norm(xt - tx)
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    checked = 0
    for ch in range(0, 80, 7):
        if not np.any(p[ch]):
            continue
        r2 = np.linalg.norm(xt - rx[ch])
        ref = p0 * 10 ** (-15 / 20) / (r1 * r2) * band_limited_echo(wf, t, (r1 + r2) / 1500, fs)
        err = np.sqrt(np.sum((p[ch] - ref) ** 2) / np.sum(ref ** 2))
        assert err < 2e-3, ch
        checked += 1
    assert checked >= 8


def exact_point_echo(hw, sc, i, target):
    """A point scatterer's echo with the exact (not band-limited) pulse, in a homogeneous
    lossless medium with hard beam cones: p0 10^(TS/20) / (r1 r2) s(t - (r1 + r2)/c),
    in the tile frame with the array placed by :func:`elements_written_out`."""
    tx, rx, bore = elements_written_out(hw, sc, i)
    xt = np.array([target.along_m, target.cross_m, target.depth_m])
    r1 = np.linalg.norm(xt - tx)
    r2 = np.linalg.norm(xt - rx, axis=1)
    c = sc.medium.sound_speed_m_s
    p0 = 10 ** (hw.waveform.source_level_db / 20)
    wf = make_waveform(hw.waveform)
    dig = hw.digitiser
    t = dig.window_start_s - dig.group_delay_s + np.arange(dig.window_samples) / dig.sample_rate_hz
    out = np.zeros((r2.size, t.size))
    if (xt - tx) @ bore < r1 * math.cos(math.radians(hw.beams.projector_half_angle_deg)):
        return out
    seen = (xt - rx) @ bore >= r2 * math.cos(math.radians(hw.beams.receiver_half_angle_deg))
    for ch in np.flatnonzero(seen):
        out[ch] = (p0 * 10 ** (target.target_strength_db / 20) / (r1 * r2[ch])
                   * wf.real(t - (r1 + r2[ch]) / c))
    return out


# a few degrees of roll, pitch and yaw and some heave and sway, so that the rotation of
# the array and its lever arm matter
ROCKING = MotionConfig(heave_m=0.05, heave_period_s=3.0, sway_m=0.04, sway_period_s=5.0,
                       roll_deg=4.0, roll_period_s=2.5, pitch_deg=3.0, pitch_period_s=3.5,
                       yaw_deg=3.0, yaw_period_s=7.0)


def test_frame_places_the_array_as_written_out(hardware, demo):
    # the placement every simulator test takes from EnvironmentSource.frame, checked
    # directly (the other tests of the simulator's physics start from it)
    hw = hardware.value
    sc = dataclasses.replace(demo, track=dataclasses.replace(demo.track, motion=ROCKING))
    src = EnvironmentSource(hardware, sc)
    for i in (0, 7, 20, 45):
        g = src.frame(i)
        tx, rx, bore = elements_written_out(hw, sc, i)
        np.testing.assert_allclose(g.tx, tx, rtol=0, atol=1e-12)
        np.testing.assert_allclose(g.rx, rx, rtol=0, atol=1e-12)
        np.testing.assert_allclose(g.bore, bore, rtol=0, atol=1e-12)
        assert g.projector == hw.sequencer.projector_order[i % 6]


@pytest.mark.parametrize("motion", [None, ROCKING], ids=["level", "rocking"])
def test_point_echo_images_like_the_exact_echo(hardware, demo, motion):
    # the matched-filter output (what the imager uses) is the exact echo's: the
    # digitiser's anti-alias filter only removes the pulse's out-of-band edges
    hw = hardware.value
    tgt = PointTarget(along_m=5.0, cross_m=-0.1, depth_m=0.3, target_strength_db=-20.0)
    sc = one_point(demo, tgt)
    sc = dataclasses.replace(sc, track=dataclasses.replace(sc.track, motion=motion))
    if motion is not None:
        nav = ping_pose(sc.track, hw, 20, sc.scene.seed)
        assert min(abs(nav.roll_rad), abs(nav.pitch_rad)) > math.radians(0.5)
    a = EnvironmentSource(hardware, sc).pressure(20)
    b = exact_point_echo(hw, sc, 20, tgt)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 1)
    cpu = counts_per_upa(hw.digitiser)
    ya, yb = cond(a * cpu).data, cond(b * cpu).data
    seen = np.abs(yb).max(axis=1) > 0
    assert seen.sum() > 40
    np.testing.assert_array_equal(np.abs(ya).max(axis=1) > 0, seen)
    k = np.argmax(np.abs(yb), axis=1)
    rows = np.flatnonzero(seen)
    assert np.all(np.abs(np.argmax(np.abs(ya[rows]), axis=1) - k[rows]) <= 1)
    ratio = ya[rows, k[rows]] / yb[rows, k[rows]]
    assert np.all(np.abs(20 * np.log10(np.abs(ratio))) < 0.05)
    assert np.all(np.abs(np.angle(ratio)) < math.radians(1.0))


def test_electronic_noise_level_and_quantisation(hardware, demo):
    far = PointTarget(along_m=300.0, cross_m=0.0, depth_m=0.5, target_strength_db=0.0)
    sc = dataclasses.replace(one_point(demo, far), noise=dataclasses.replace(
        demo.noise, electronic_rms_counts=50.0, sea_state=None))
    src = EnvironmentSource(hardware, sc)
    ping = src.ping(0)
    assert ping.samples.dtype == np.int32 and ping.samples.shape == (80, 1500)
    assert abs(ping.samples.std() - 50.0) < 1.0
    assert ping.config_id == hardware.id
    again = EnvironmentSource(hardware, sc).ping(0).samples
    np.testing.assert_array_equal(again, ping.samples)        # seeded by scene and ping
    assert not np.array_equal(src.ping(1).samples, ping.samples)


def test_outside_the_beams_is_silent(hardware, demo):
    far = PointTarget(along_m=30.0, cross_m=0.0, depth_m=0.5, target_strength_db=0.0)
    src = EnvironmentSource(hardware, one_point(demo, far))
    assert not np.any(src.pressure(0))
    assert src.last_stats["in_view"] == 0


def test_digitised_pulse_keeps_the_band():
    from svss_daq.config import HardwareConfig, load
    wf = make_waveform(load(HardwareConfig, config_path("hardware.toml")).waveform)
    fs = 125e3
    real, analytic, pad = digitised_pulse(wf, fs)
    assert np.allclose(analytic.real, real, atol=1e-12)
    # in-band spectrum equals the continuous pulse's (sampled finely and integrated)
    tj = (np.arange(real.size) - pad) / fs
    f = np.linspace(20e3, 35e3, 31)
    spec = np.exp(-2j * np.pi * np.outer(f, tj)) @ real / fs
    tf = np.arange(0, wf.duration_s, 1 / 8e6)
    ref = np.exp(-2j * np.pi * np.outer(f, tf)) @ wf.real(tf) / 8e6
    assert np.max(np.abs(spec - ref)) < 2e-3 * np.max(np.abs(ref))
    # analytic: negligible negative-frequency content (the filter tails are truncated)
    s = np.fft.fft(analytic, 4096)
    assert np.sum(np.abs(s[2049:]) ** 2) < 1e-6 * np.sum(np.abs(s) ** 2)


def test_cis_cycles():
    x = np.random.default_rng(0).uniform(-1e4, 1e4, 2000)
    x = np.concatenate([x, [0.0, 0.5, -0.5, 0.25, 1e-12]])
    c = np.array([cis_cycles(v) for v in x])
    assert np.max(np.abs(c[:, 0] - np.cos(2 * np.pi * x))) < 1e-10
    assert np.max(np.abs(c[:, 1] - np.sin(2 * np.pi * x))) < 1e-10


def test_beam_tables():
    h = math.radians(25)
    hard = beam_table(h, "cone", 0.0, None, 27500.0, 1500.0)
    assert hard.lo_front == math.cos(h) and hard.edge == h
    assert np.all(hard(np.array([math.cos(h), 0.95, 1.0])) == 1.0)
    assert hard(np.array([math.cos(h) - 1e-12]))[0] == 0.0
    assert np.all(hard(np.array([-1.0, -0.99, 0.0])) == 0.0)            # no back lobe
    pis = beam_table(h, "piston", 0.0, -20.0, 27500.0, 1500.0)
    assert pis(np.array([math.cos(h)]))[0] == pytest.approx(10 ** (-3 / 20), rel=1e-4)
    a = piston_radius_for_half_angle(h, 27500.0, 1500.0)
    th = math.radians(12.0)
    assert pis(np.array([math.cos(th)]))[0] == pytest.approx(
        float(piston_directivity(th, 27500.0, a, 1500.0)), rel=1e-5)
    # back lobe: the main lobe about -boresight, 20 dB down; nothing in between
    assert pis(np.array([-math.cos(th)]))[0] == pytest.approx(
        0.1 * float(piston_directivity(th, 27500.0, a, 1500.0)), rel=1e-5)
    assert pis(np.array([0.0, 0.5, -0.5]))[1] == 0.0
    tap = beam_table(h, "cone", math.radians(4), None, 27500.0, 1500.0)
    assert tap(np.array([math.cos(h)]))[0] == pytest.approx(0.5, abs=1e-3)
    assert tap(np.array([math.cos(h + math.radians(2.01))]))[0] == 0.0
    assert tap(np.array([math.cos(h - math.radians(2.01))]))[0] == pytest.approx(1.0)
