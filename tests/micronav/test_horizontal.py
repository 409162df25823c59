"""Surge, sway and heave between pings from their common phase centres focused on the
seabed (svss_proc/micronav/horizontal.py), on pings the simulator synthesises from known
poses: the seed's sand scene without its target (interface, volume, specular return,
noise), the configured projector order 0..5 at 1 m/s (no phase centres within lambda/4:
docs/phase_centres.md), and a sway step, a heave step and a ramp of all three injected
into the true poses. The estimator is given the straight track's poses (a navigation that
saw none of the motion) and must find the injected increments; across the projector
sequence's wrap (5 -> 0) it must refuse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_device.scene import load_scene
from sim_device.track import ping_pose
from svss_daq.config import HardwareConfig, config_path, load_with_text
from svss_daq.frames import body_to_ned
from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner
from svss_proc.micronav.horizontal import estimate_displacement, phase_gradient

from ..computed_once import computed_once
from .posed_source import PosedSource

SWAY_STEP = (14, 0.025)            # from ping 14 on, 25 mm to starboard
HEAVE_STEP = (16, 0.006)           # from ping 16 on, 6 mm down
RAMP = (17, np.array([0.003, 0.004, -0.002]))   # from ping 17: surge, sway, heave per ping
PINGS = range(12, 22)              # projectors 0 1 2 3 4 5 0 1 2 3


def offsets(i: int) -> np.ndarray:
    """The injected motion of ping i about the straight track: surge, sway, heave, m."""
    o = np.zeros(3)
    if i >= SWAY_STEP[0]:
        o[1] += SWAY_STEP[1]
    if i >= HEAVE_STEP[0]:
        o[2] += HEAVE_STEP[1]
    if i >= RAMP[0]:
        o += RAMP[1] * (i - RAMP[0])
    return o


@pytest.fixture(scope="module")
def estimates(tmp_path_factory):
    return computed_once(tmp_path_factory, "test_horizontal-estimates", _estimates)


def _estimates():
    import dataclasses
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    hw = loaded.value
    assert list(hw.sequencer.projector_order) == [0, 1, 2, 3, 4, 5]
    scene = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    scene = dataclasses.replace(scene, targets=())
    src = PosedSource(loaded, scene, offsets)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 2)
    data = {}
    for i in PINGS:
        p = src.ping(i)
        data[i] = (p, cond.ping(p))
    out = {}
    for i in list(PINGS)[:-1]:
        (pa, ca), (pb, cb) = data[i], data[i + 1]
        # the navigation: the straight track, none of the injected motion
        na, nb = (ping_pose(scene.track, hw, k, src.seed) for k in (i, i + 1))
        est = estimate_displacement(
            ca.data, cb.data, ca.t0_s, ca.dt_s, src.geometry, pa.projector, pb.projector,
            body_to_ned(na.roll_rad, na.pitch_rad, na.heading_rad), na.ned,
            body_to_ned(nb.roll_rad, nb.pitch_rad, nb.heading_rad), nb.ned,
            na.down_m + na.altitude_m, scene.medium.sound_speed_m_s, hw.waveform.center_hz)
        # heading 0: north is along the track, east is starboard
        out[i] = (pa.projector, pb.projector, est, offsets(i + 1) - offsets(i))
    return out


def _table(estimates):
    for i, (pa, pb, est, true) in estimates.items():
        if est.refused:
            print(f"{i}->{i + 1} ({pa}->{pb}) refused: {est.refused}")
        else:
            print(f"{i}->{i + 1} ({pa}->{pb}) true {np.round(true * 1e3, 1)} est "
                  f"{np.round(est.correction_m * 1e3, 1)} sigma "
                  f"{np.round(est.sigma_m * 1e3, 1)} mm, coherence "
                  f"{np.round(est.coherence, 2)}")


@pytest.mark.slow
def test_refuses_across_the_sequence_wrap_and_nowhere_else(estimates):
    _table(estimates)
    for i, (pa, pb, est, _) in estimates.items():
        if (pa, pb) == (5, 0):
            assert est.refused is not None and "do not overlap" in est.refused
            assert "projector 5 then 0" in est.refused
            assert np.isnan(est.displacement_m).all()
        else:
            assert est.refused is None, est.refused
            assert est.n_pairs >= 30


def test_increments_match_the_injected_motion_within_their_error(estimates):
    err, sig = [], []
    for i, (_, _, est, true) in estimates.items():
        if est.refused:
            continue
        e = est.correction_m - true
        err.append(e)
        sig.append(est.sigma_m)
        # each within 3.5 of its own sigma; horizontally within 12 mm, vertically 1.5 mm
        assert np.all(np.abs(e) <= 3.5 * est.sigma_m), (i, e, est.sigma_m)
        assert np.all(np.abs(e[:2]) < 0.012) and abs(e[2]) < 0.0015, (i, e)
    err, sig = np.array(err), np.array(sig)
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    print("rms error (surge, sway, heave) mm", np.round(rms * 1e3, 2), "median sigma",
          np.round(np.median(sig, axis=0) * 1e3, 2))
    # the reported errors are neither far too small nor far too large
    ratio = rms / np.median(sig, axis=0)
    assert np.all(ratio < 2.0) and np.all(ratio > 0.3), ratio


def test_the_steps_are_found(estimates):
    # sway: the step pair's increment, against the truth and against zero (no step)
    est = estimates[SWAY_STEP[0] - 1][2]
    assert abs(est.correction_m[1] - SWAY_STEP[1]) < 3.0 * est.sigma_m[1]
    assert est.correction_m[1] > 3.0 * est.sigma_m[1]
    assert abs(est.correction_m[1] - SWAY_STEP[1]) < 0.010
    # heave: the step pair against the truth and the pairs before it
    step = estimates[HEAVE_STEP[0] - 1][2].correction_m[2]
    still = [estimates[i][2].correction_m[2] for i in (12, 13, 14)]
    assert abs(step - HEAVE_STEP[1]) < 0.0015
    assert min(step - s for s in still) > 0.004


def test_the_ramp_is_found(estimates):
    ramp = [estimates[i][2] for i in range(RAMP[0], max(PINGS))
            if estimates[i][2].refused is None]
    assert len(ramp) == 3
    mean = np.mean([e.correction_m for e in ramp], axis=0)
    # three increments: surge and sway to 6 mm, heave to 1 mm, heave's sign and size
    assert np.all(np.abs(mean[:2] - RAMP[1][:2]) < 0.006), mean
    assert abs(mean[2] - RAMP[1][2]) < 0.001, mean


def test_phase_gradient_recovers_a_plane_wave_across_the_aperture():
    rng = np.random.default_rng(3)
    centres = np.stack(np.meshgrid(np.arange(6) * 0.0455, np.arange(8) * 0.0455,
                                   indexing="ij"), axis=-1).reshape(-1, 2)
    g = np.array([12.0, -7.5])                      # rad/m
    common = rng.normal(size=40) + 1j * rng.normal(size=40)
    contrib = np.exp(1j * centres @ g)[:, None] * common[None, :]
    np.testing.assert_allclose(phase_gradient(contrib, centres, 0.07), g, atol=1e-9)
    # an unrelated pattern gives no false slope beyond the noise
    noise = rng.normal(size=contrib.shape) + 1j * rng.normal(size=contrib.shape)
    est = phase_gradient(contrib + 0.1 * noise, centres, 0.07)
    assert np.all(np.abs(est - g) < 1.0)
    assert math.isfinite(est[0])


def test_focus_points_brings_a_point_echo_into_phase_only_at_the_point():
    """Independent synthesis: each channel hears a point at P0 after its exact bistatic
    delay, with the baseband phase exp(-j 2 pi f_c tau) of svss_daq.conventions and a
    Gaussian envelope; focused at P0 the channels add in phase (|v| = n_ch, arg v = 0 to
    the interpolation's error); 1 cm away along the line of sight they do not."""
    from svss_daq.conventions import echo_phase
    from svss_proc.micronav.horizontal import focus_points
    fc, c, dt = 27500.0, 1500.0, 1.6e-5
    rng = np.random.default_rng(11)
    tx = np.array([0.52, -0.11, 0.0])
    rx = np.column_stack([rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.5, 0.5, 20),
                          np.zeros(20)])
    p0 = np.array([0.4, 0.3, 2.0])
    tau = (np.linalg.norm(p0 - tx) + np.linalg.norm(p0 - rx, axis=1)) / c
    t = dt * np.arange(400)
    env = np.exp(-0.5 * ((t[None, :] - tau[:, None]) / 40e-6) ** 2)
    bb = env * echo_phase(tau, fc)[:, None]
    v = focus_points(bb, 0.0, dt, fc, c, tx, rx, p0[None, :])[0]
    assert abs(v) > 0.97 * len(rx) and abs(np.angle(v)) < 1e-3
    # a point 1 cm farther along the look: every path 2 cm longer, lambda/2.7 of phase
    u = (p0 - 0.5 * (tx + rx.mean(axis=0)))
    u /= np.linalg.norm(u)
    v1 = focus_points(bb, 0.0, dt, fc, c, tx, rx, (p0 + 0.01 * u)[None, :])[0]
    want = 2 * math.pi * fc * 0.02 / c
    assert abs(math.remainder(np.angle(v1) - want, 2 * math.pi)) < 0.1


def _demo_pair(i: int, **options):
    """The estimate between the demo scene's pings i and i + 1 (six points in water, no
    seabed), posed by the simulator's straight track (the truth: no correction)."""
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    hw = loaded.value
    from sim_device.environment_source import EnvironmentSource
    src = EnvironmentSource(loaded, load_scene(config_path("scenes/demo.toml")))
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 2)
    pa, pb = src.ping(i), src.ping(i + 1)
    ca, cb = cond.ping(pa), cond.ping(pb)
    na, nb = pa.nav, pb.nav
    return estimate_displacement(
        ca.data, cb.data, ca.t0_s, ca.dt_s, src.geometry, pa.projector, pb.projector,
        body_to_ned(na.roll_rad, na.pitch_rad, na.heading_rad), na.ned,
        body_to_ned(nb.roll_rad, nb.pitch_rad, nb.heading_rad), nb.ned,
        na.down_m + na.altitude_m, 1500.0, hw.waveform.center_hz, **options)


def test_refuses_without_a_seabed():
    """The demo scene: six points in water, no seabed. The patches still cohere 0.3-0.8
    on noise and the points' echoes (and gave increments 15-30 mm wrong, the truth being
    the straight track's), so the estimator must refuse on the nadir patch."""
    est = _demo_pair(42)
    assert est.refused is not None and "no coherent seabed return" in est.refused, est
    assert np.isnan(est.correction_m).all()


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_refuses_a_point_echo_below_nadir(kernel):
    """The demo scene's first point (on the track, 0.30 m below the nominal bottom) under
    the array at pings 24-33: its echo coheres at 0.94-0.98 over the nadir patch, and
    without the layer test those pairs gave increments 20-27 mm wrong across with a stated
    sigma of 3-6 mm (the fusion then focused the demo scene worse than the navigation
    alone). The nadir return grows with depth there: it is no seabed."""
    est = _demo_pair(25, kernel=kernel)
    assert est.refused is not None and "no seabed layer under the array" in est.refused, est
    assert "strongest +0.20 m from the navigation's seabed" in est.refused, est.refused
    assert np.isnan(est.correction_m).all()


def test_seabed_layer_wants_an_interface_at_the_seabed_depth():
    """The layer test on profiles of the nadir patch's power (offsets from the
    navigation's seabed, down positive): an interface's return (peaked at the seabed, the
    water 20-60 dB below: the simulated sand's), also 5 cm off; the same 10 cm further
    down than the tolerance; a point below nadir whose return grows with depth; noise."""
    from svss_proc.micronav.horizontal import LAYER_TOLERANCE_M, layer_offsets, seabed_layer
    d = layer_offsets()
    assert d[0] == pytest.approx(-0.2) and d[-1] == pytest.approx(0.2) and 0.0 in d
    sand = 10.0 ** (-np.minimum(np.abs(d) * 200.0, 60.0 * (d < 0) + 20.0 * (d >= 0)) / 10.0)
    assert seabed_layer(d, sand) is None
    assert seabed_layer(d, np.roll(sand, 1)) is None                # the seabed 5 cm deeper
    deep = np.roll(sand, 3)                                          # 15 cm deeper
    why = seabed_layer(d, deep)
    assert why and why.startswith("no seabed layer") and "+0.15 m" in why, why
    assert seabed_layer(d, deep, tolerance_m=0.15) is None
    point = 10.0 ** (np.clip(d, 0.0, None) * 200.0 / 10.0)           # +40 dB at 0.2 m
    assert "strongest +0.20 m" in seabed_layer(d, point)
    rng = np.random.default_rng(3)
    noise = rng.uniform(0.5, 1.5, d.size)
    noise[np.argmin(np.abs(d))] = 4.0                                # 6-9 dB over the rest
    assert noise.argmax() == np.argmin(np.abs(d))
    why = seabed_layer(d, noise)
    assert why and "dB over the water" in why and "(10 dB needed)" in why, why
    assert seabed_layer(d, noise, contrast_db=0.0) is None
    assert LAYER_TOLERANCE_M == pytest.approx(0.10)
