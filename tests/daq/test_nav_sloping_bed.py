"""The navigation's down axis over a bed that slopes (svss_daq.nav.fusion, "down"): the
bed's depth and gradient under the head are states, measured by each DVL beam's
footprint, so a boat running over a slope follows the bed by its slope and keeps its own
depth where the GPS heights put it. Flat-bed navigation let the bed's depth change by
only 2 mm/s and moved the head instead: over a river's bank its body depth wandered by
metres.

Encoder-made ensembles: the simulated DVL (sim_device.devices.dvl) writes PD0 ranges to
a tilted plane along each beam, the project's parser reads them back; the real one:
RDI's Workhorse bottom-track recording in ``../shared/data``."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

from sim_device.devices.clock import SimClock
from sim_device.devices.dvl import DvlEmulator
from sim_device.devices.gps import antenna_ned
from sim_device.devices.instruments_config import load_instruments
from svss_daq.config import DevicesConfig, HardwareConfig, config_path, load
from svss_daq.nav.geodesy import ned_to_geodetic
from svss_daq.nav.records import GpsFix
from svss_daq.navigation import compute_poses, dvl_sample_from_pd0
from svss_daq.ping import NavSnapshot
from svss_daq.protocols.pd0 import Pd0StreamParser, decode_ensemble
from tests.conftest import SHARED_DATA

START_NS = 1_800_000_000 * 10 ** 9
SPEED_M_S, HEADING_DEG = 1.5, 20.0
#: the bed: down = K0 + KN north + KE east (about 6 deg deepening ahead and 5 to port)
K0, KN, KE = 4.0, 0.10, -0.09
BODY_DOWN_M = 0.0                 # the boat on the water: the GPS heights hold it there
ORIGIN = (45.0, 7.0, 0.0)


def _truth(t_ns: int) -> NavSnapshot:
    t = (t_ns - START_NS) * 1e-9
    h = math.radians(HEADING_DEG)
    v = SPEED_M_S * np.array([math.cos(h), math.sin(h)])
    n, e = v * t
    return NavSnapshot(t_ns, float(n), float(e), BODY_DOWN_M, float(v[0]), float(v[1]), 0.0,
                       0.0, 0.0, h, float(K0 + KN * n + KE * e - BODY_DOWN_M), math.nan,
                       math.nan, 0)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Two minutes at 5 Hz over the slope (the bed deepens 2.6 m), the DVL's realistic
    noise, RTK fixes of the antenna once a second."""
    inst = load_instruments(config_path("sim-device.toml"))
    hw = load(HardwareConfig, config_path("hardware.toml"))
    dvl = DvlEmulator(inst.dvl, hw.lever_arms, SimClock(START_NS), _truth,
                      tmp_path_factory.mktemp("dvl"), bed=(K0, KN, KE))
    try:
        samples = [dvl_sample_from_pd0(decode_ensemble(dvl._emit("ensemble", t, t)))
                   for t in START_NS + np.arange(600) * 200_000_000]
    finally:
        dvl.close()
    fixes = []
    for t in START_NS + np.arange(120) * 1_000_000_000:
        lat, lon, h = ned_to_geodetic(antenna_ned(_truth(int(t)), hw.lever_arms.gps_antenna_m),
                                      ORIGIN)
        fixes.append(GpsFix(int(t), float(lat), float(lon), float(h), 4, 0.02))
    cfg = dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                              origin_latitude_deg=ORIGIN[0], origin_longitude_deg=ORIGIN[1],
                              origin_height_m=ORIGIN[2])
    times = [int(t) for t in START_NS + 100_000_000 + np.arange(1190) * 100_000_000]
    return samples, fixes, cfg, hw, times


@pytest.mark.parametrize("causal", [True, False], ids=["live", "smoothed"])
def test_a_boat_over_a_slope_keeps_its_depth_and_its_altitude(run, causal):
    samples, fixes, cfg, hw, times = run
    state: dict = {}
    poses = compute_poses(times, fixes, [], samples, cfg, hw.lever_arms, causal=causal,
                          state_out=state)
    truth = [_truth(t) for t in times]
    settled = np.array(times) > START_NS + 10 * 10 ** 9      # after the first 10 s
    down = np.array([p.down_m for p in poses])[settled]
    alt = np.array([p.altitude_m for p in poses])[settled]
    alt_true = np.array([p.altitude_m for p in truth])[settled]
    bed_change = alt_true.max() - alt_true.min()
    assert bed_change > 2.0                                 # the bed fell away by metres
    # the body stays on the water (GPS heights sigma 0.6 m; the DVL carries the rest)
    assert np.sqrt(np.mean((down - BODY_DOWN_M) ** 2)) < 0.05, down
    assert np.max(np.abs(down - BODY_DOWN_M)) < 0.15
    # the altitude under the body, not under the head 2.2 m ahead of it: to a few cm
    err = alt - alt_true
    assert np.sqrt(np.mean(err ** 2)) < 0.03 and np.max(np.abs(err)) < 0.08, err
    # the gradient the beams measure is the bed's (filter: at the last sample)
    grad = state["d"][0][-1, 2:4]
    np.testing.assert_allclose(grad, [KN, KE], atol=0.01)


def test_a_flat_bed_model_could_not_have_followed_it(run):
    """The same run with the gradient held at zero (its prior and random walk nil): the
    bed's depth can then change only by its 2 mm/s random walk, and the head's depth
    absorbs the rest: what the navigation did before the bed's slope was a state."""
    samples, fixes, cfg, hw, times = run
    from svss_daq.nav import fusion
    flat = dataclasses.replace(cfg, bottom_slope_sigma_per_m=0.0)
    saved = fusion._GRADIENT_VAR
    fusion._GRADIENT_VAR = 0.0
    try:
        poses = compute_poses(times, fixes, [], samples, flat, hw.lever_arms, causal=True)
    finally:
        fusion._GRADIENT_VAR = saved
    down = np.array([p.down_m for p in poses])
    assert np.max(np.abs(down - BODY_DOWN_M)) > 0.5


DVL = SHARED_DATA / "dvl_pd0" / "RDI_withBT.000"


def test_a_real_river_bank_is_followed_by_its_slope(hardware):
    """RDI's Workhorse recording: beam 2 (starboard) reads 2-3 m more than beam 1 all
    along (a bed falling away to starboard by some 24 deg). Put on the water surface by
    GPS heights along its own dead-reckoned track, the body's depth stays near the
    antenna's lever arm below it (2.5 m): the bed is taken afresh when the bottom comes
    back after 8 minutes without it (held across the gap, the bed pulled the head 4 m
    off); the gradient is the one the beams show."""
    if not DVL.exists():
        pytest.skip(f"real recordings not found: {DVL.parent}")
    samples = [s for s in (dvl_sample_from_pd0(e)
                           for e in Pd0StreamParser().feed(DVL.read_bytes())) if s is not None]
    lock = np.array([np.all(np.isfinite(s.velocity_body_m_s)) for s in samples])
    cfg = dataclasses.replace(load(DevicesConfig, config_path("devices.toml")).navigation,
                              origin_latitude_deg=0.0, origin_longitude_deg=0.0,
                              origin_height_m=0.0)
    arms = hardware.value.lever_arms
    times = [s.time_ns for s in samples]
    track = compute_poses(times, [], [], samples, cfg, arms)
    fixes, last = [], None
    for p in track:
        if (last is None or p.time_ns - last >= 10 ** 9) and math.isfinite(p.north_m):
            lat, lon, _ = ned_to_geodetic(np.array([p.north_m, p.east_m, 0.0]), (0, 0, 0))
            fixes.append(GpsFix(p.time_ns, float(lat), float(lon), 0.0, 4, 0.02))
            last = p.time_ns
    want = -arms.gps_antenna_m[2]                 # the body 2.5 m below the antenna
    state: dict = {}
    live = compute_poses(times, fixes, [], samples, cfg, arms, causal=True, state_out=state)
    down = np.array([p.down_m for p in live])[lock]
    # flat, with the bed held over the 8-minute loss of bottom before ensemble 860:
    # 0.34 m rms and 4.0 m above it at worst
    assert np.sqrt(np.mean((down - want) ** 2)) < 0.15
    assert down.min() > want - 1.2
    # the bed's gradient: its magnitude as the beams show it, 0.4-0.5 (22-27 deg)
    g = np.hypot(*state["d"][0][lock, 2:4].T)
    assert 0.38 < np.median(g) < 0.52


def test_a_beam_off_the_bed_is_left_out(run):
    """One ensemble whose port beam met something a quarter of the way to the bed (a
    fish): its four footprints lie on no plane (the port one 2 m off the others'), so
    its ranges are left out and the altitude about it is the bed's; taken in, it moves
    the bed. Three beams with one steeper than ``bottom_max_slope_deg`` likewise."""
    from svss_daq.nav import fusion
    samples, fixes, cfg, hw, times = run
    k = 300
    r = np.array(samples[k].ranges_m, dtype=float)
    r[0] *= 0.25
    hit = list(samples)
    hit[k] = dataclasses.replace(samples[k], ranges_m=tuple(r))
    t_k = samples[k].time_ns
    near = [t for t in times if abs(t - t_k) <= 400_000_000]
    truth = np.array([_truth(t).altitude_m for t in near])
    three = list(hit)
    three[k] = dataclasses.replace(samples[k], ranges_m=tuple(np.where(np.arange(4) == 1,
                                                                       np.nan, r)))
    from svss_daq.nav.dvl_geometry import level_footprints
    taken_in = functools.partial(level_footprints.__wrapped__, off_plane_fraction=10.0)
    for sel, footprints, worst in ((hit, level_footprints, 0.03), (hit, taken_in, None),
                                   (three, level_footprints, 0.03)):
        fusion.level_footprints = footprints
        try:
            alt = np.array([p.altitude_m for p in compute_poses(
                near, fixes, [], sel, cfg, hw.lever_arms, causal=True)])
        finally:
            fusion.level_footprints = level_footprints
        err = np.max(np.abs(alt - truth))
        if worst is not None:
            assert err < worst, err
        else:                                      # taken in, the fish moves the bed
            assert err > 0.1, err
