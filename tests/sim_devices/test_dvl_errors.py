"""The simulated DVL's error cases (config/sim-device.toml [dvl] velocity_scale_error,
misalignment_deg, dropout_start_s, dropout_s), as the project's PD0 parser reads the
ensembles the emulator writes: RDI's bottom-track velocity with no bottom lock is the
invalid value -32768 mm/s (ranges 0); a scale error multiplies the measured velocity;
a mounting misalignment turns it about the vertical (docs/sim_device.md)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.devices.clock import SimClock
from sim_device.devices.dvl import DvlEmulator
from sim_device.devices.instruments_config import load_instruments
from svss_daq.config import HardwareConfig, config_path, load
from svss_daq.frames import body_to_ned
from svss_daq.navigation import dvl_sample_from_pd0
from svss_daq.ping import NavSnapshot
from svss_daq.protocols.pd0 import decode_ensemble

START_NS = 1_800_000_000 * 10 ** 9
#: the true motion: NED velocity (m/s), heading (deg), depth of the bottom (m)
V_NED = np.array([0.8, 0.3, 0.05])
HEADING_DEG = 20.0
BOTTOM_M = 4.0


def _truth(t_ns: int) -> NavSnapshot:
    t = (t_ns - START_NS) * 1e-9
    p = V_NED * t
    return NavSnapshot(t_ns, float(p[0]), float(p[1]), float(p[2]), *map(float, V_NED),
                       0.0, 0.0, math.radians(HEADING_DEG), float(BOTTOM_M - p[2]),
                       math.nan, math.nan, 0)


def _ensembles(tmp_path, **errors):
    """Ensembles every 0.2 s over 0-14 s of the track, noise-free, with ``errors``:
    (time after the track start s, decoded ensemble, DvlSample)."""
    inst = load_instruments(config_path("sim-device.toml"))
    cfg = dataclasses.replace(inst.dvl, velocity_sigma_m_s=0.0, range_sigma_m=0.0,
                              heading_sigma_deg=0.0, tilt_sigma_deg=0.0, **errors)
    hw = load(HardwareConfig, config_path("hardware.toml"))
    dvl = DvlEmulator(cfg, hw.lever_arms, SimClock(START_NS), _truth, tmp_path)
    try:
        out = []
        for k in range(71):
            t_ns = START_NS + k * 200_000_000
            ens = decode_ensemble(dvl._emit("ensemble", t_ns, t_ns))
            out.append((k * 0.2, ens, dvl_sample_from_pd0(ens)))
        return out
    finally:
        dvl.close()


def _body_velocity() -> np.ndarray:
    """The head's true velocity in the body frame (no rotation: the lever arm adds none)."""
    return body_to_ned(0.0, 0.0, math.radians(HEADING_DEG)).T @ V_NED


def test_scale_error_and_misalignment_as_the_parser_reads_them(tmp_path):
    v = _body_velocity()
    exact = np.array([s.velocity_body_m_s for _, _, s in _ensembles(tmp_path)])
    # without errors: the true velocity to the PD0 resolution (1 mm/s)
    np.testing.assert_allclose(exact, np.broadcast_to(v, exact.shape), atol=0.6e-3)
    scale, alpha = 0.005, math.radians(1.0)
    got = np.array([s.velocity_body_m_s for _, _, s in _ensembles(
        tmp_path, velocity_scale_error=scale, misalignment_deg=1.0)])
    # the head turned alpha to starboard: forward v_f cos a + v_s sin a, starboard
    # -v_f sin a + v_s cos a, all times 1 + scale; vertical only scaled
    want = (1 + scale) * np.array([v[0] * math.cos(alpha) + v[1] * math.sin(alpha),
                                   -v[0] * math.sin(alpha) + v[1] * math.cos(alpha), v[2]])
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), atol=0.6e-3)
    # the errors are visible above the resolution: 4 mm/s along, 16 mm/s across
    assert np.all(np.abs(got[:, 0] - v[0]) > 3e-3)
    assert np.all(np.abs(got[:, 1] - v[1]) > 10e-3)


def test_a_configured_dropout_sends_no_bottom_lock_in_its_window(tmp_path):
    out = _ensembles(tmp_path, dropout_start_s=2.0, dropout_s=10.0)
    inside = [(t, e, s) for t, e, s in out if 2.0 <= t < 12.0 - 1e-9]
    outside = [(t, e, s) for t, e, s in out if not 2.0 <= t < 12.0 - 1e-9]
    assert len(inside) == 50 and len(outside) == 21
    for _, e, s in inside:
        assert np.all(e.bottom_track.velocity_raw == -32768)
        assert np.all(np.isnan(e.bottom_track.velocity_mps))
        assert np.all(np.isnan(e.bottom_track.range_m))
        assert np.all(np.isnan(s.velocity_body_m_s))
        assert math.isfinite(s.heading_rad)           # attitude still flows
    for _, e, s in outside:
        assert np.all(np.isfinite(s.velocity_body_m_s))
        assert np.all(np.isfinite(e.bottom_track.range_m))


@pytest.mark.parametrize("key, value", [("velocity_scale_error", 0.6),
                                        ("misalignment_deg", 200.0), ("dropout_s", -1.0)])
def test_error_settings_out_of_range_name_the_file_and_key(tmp_path, key, value):
    from svss_daq.config import ConfigError
    text = config_path("sim-device.toml").read_text()
    bad = tmp_path / "sim-device.toml"
    bad.write_text(text.replace(f"\n{key} = ", f"\n{key} = {value!r} #", 1))
    with pytest.raises(ConfigError, match=rf"{bad}.*{key}"):
        load_instruments(bad)


def test_ranges_over_a_sloping_bed_reach_the_plane_along_each_beam(tmp_path):
    """Over a bed down = k0 + kn north + ke east, beam k (RDI: 1 port, 2 starboard,
    3 forward, 4 aft, theta from the vertical) meets it after r = H / (cos theta - sin
    theta (kn u_n + ke u_e)) along the beam (H the head's height above the bed below
    it, u the beam's horizontal azimuth), reported as r cos theta: written out here for
    a level head at heading 20 deg."""
    inst = load_instruments(config_path("sim-device.toml"))
    cfg = dataclasses.replace(inst.dvl, velocity_sigma_m_s=0.0, range_sigma_m=0.0,
                              heading_sigma_deg=0.0, tilt_sigma_deg=0.0)
    hw = load(HardwareConfig, config_path("hardware.toml"))
    kn, ke = 0.05, -0.09                          # about 3 and 5 deg
    k0 = BOTTOM_M
    dvl = DvlEmulator(cfg, hw.lever_arms, SimClock(START_NS), _truth, tmp_path,
                      bed=(k0, kn, ke))
    try:
        theta = math.radians(cfg.beam_angle_deg)
        psi = math.radians(HEADING_DEG)
        lever = np.asarray(hw.lever_arms.dvl_m, float)
        rot = np.array([[math.cos(psi), -math.sin(psi), 0.0],
                        [math.sin(psi), math.cos(psi), 0.0], [0.0, 0.0, 1.0]])
        azimuth = {0: psi - math.pi / 2, 1: psi + math.pi / 2, 2: psi, 3: psi + math.pi}
        for k in (0, 20, 60):
            t_ns = START_NS + k * 200_000_000
            ens = decode_ensemble(dvl._emit("ensemble", t_ns, t_ns))
            pose = _truth(t_ns)
            head = np.array([pose.north_m, pose.east_m, pose.down_m]) + rot @ lever
            height = k0 + kn * head[0] + ke * head[1] - head[2]
            want = [height * math.cos(theta) / (math.cos(theta) - math.sin(theta) * (
                kn * math.cos(a) + ke * math.sin(a))) for a in
                (azimuth[b] for b in range(4))]
            np.testing.assert_allclose(ens.bottom_track.range_m, want, atol=0.006)
            # the slope shows: port and starboard differ by far more than the resolution
            assert abs(want[0] - want[1]) > 0.2
    finally:
        dvl.close()
