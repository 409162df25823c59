"""Imaging of point targets against theory: focus position, resolution, coherent gain,
refraction and float32 at long range. The echoes are synthesised here, independently of
the project's simulator and refraction solver (brute-force Fermat minimisation)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from svss_daq.config import ProcessingConfig, config_path, load
from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import make_waveform
from svss_proc.imaging.imager import TileImager
from tests.references import refracted_time

CW, SAND = 1500.0, 1767.0
ALTITUDE = 2.5          # body origin above the interface; the array is 0.5 m lower
P0 = 1e10               # uPa at 1 m


def synth_pings(hw, target, cs, n_pings, first=0, start_along=0.0):
    """Pings of one point target (tile frame: along, cross, depth below the interface) on
    a straight track along +x (heading north, line origin at the first ping)."""
    geo = array_geometry(hw.value)
    wf = make_waveform(hw.value.waveform)
    dig = hw.value.digitiser
    fs = dig.sample_rate_hz
    t = dig.window_start_s - dig.group_delay_s + np.arange(dig.window_samples) / fs
    cpu = counts_per_upa(dig)
    cos_tx, cos_rx = math.cos(geo.projector_half_angle), math.cos(geo.receiver_half_angle)
    pings, pairs = [], []
    order = hw.value.sequencer.projector_order
    for i in range(first, first + n_pings):
        s = start_along + i * hw.value.sequencer.ping_interval_s * 1.0
        nav = NavSnapshot(time_ns=10**18 + i * 10**8, north_m=s, east_m=0.0, down_m=0.0,
                          vel_north_m_s=1.0, vel_east_m_s=0.0, vel_down_m_s=0.0,
                          roll_rad=0.0, pitch_rad=0.0, heading_rad=0.0, altitude_m=ALTITUDE)
        rot = body_to_ned(0, 0, 0)
        # tile frame = NED shifted so that the interface is at depth 0
        origin = np.array([s, 0.0, -ALTITUDE])
        proj = order[i % len(order)]
        tx = origin + rot @ geo.projectors[proj]
        rx = origin + geo.receivers @ rot.T
        out = np.zeros((rx.shape[0], t.size))
        d1 = target - tx
        in_tx = d1[2] >= np.linalg.norm(d1) * cos_tx
        if in_tx:
            t1 = refracted_time(tx, target, CW, cs)
            r1 = np.linalg.norm(d1)
            for ch in range(rx.shape[0]):
                d2 = target - rx[ch]
                r2 = np.linalg.norm(d2)
                if d2[2] < r2 * cos_rx:
                    continue
                tau = t1 + refracted_time(rx[ch], target, CW, cs)
                a = P0 / (r1 * r2)
                out[ch] = a * wf.real(t - tau)
                if np.any(out[ch]):
                    pairs.append(a)
        pings.append(Ping(sequence=i, projector=proj, transmit_time_ns=nav.time_ns,
                          sample_rate_hz=fs, window_start_ns=0, samples=np.rint(out * cpu)
                          .astype(np.int32), nav=nav, config_id=hw.id))
    return pings, np.array(pairs)


def processing(voxel_m=0.01, width_m=0.2, depth_m=0.3, top_m=0.25, **imaging):
    proc = load(ProcessingConfig, config_path("processing.toml"))
    tile = dataclasses.replace(proc.tile, length_m=0.3, width_m=width_m, depth_m=depth_m,
                               top_m=top_m, voxel_m=voxel_m)
    im = dataclasses.replace(proc.imaging, **imaging)
    return dataclasses.replace(proc, tile=tile, imaging=im)


def image(hw, proc, pings):
    imager = TileImager(hw, proc)
    tiles = []
    for p in pings:
        tiles += imager.add(p)
    tiles += imager.finish()
    return max(tiles, key=lambda t: np.abs(t.image).max())


def peak(tile):
    """Peak position with parabolic sub-voxel refinement on each axis, m."""
    mag = np.abs(tile.image)
    idx = np.unravel_index(mag.argmax(), mag.shape)
    pos = []
    for ax, coords in enumerate((tile.grid.along, tile.grid.cross, tile.grid.depth)):
        i = idx[ax]
        sl = list(idx)
        if 0 < i < mag.shape[ax] - 1:
            vals = []
            for d in (-1, 0, 1):
                sl[ax] = i + d
                vals.append(mag[tuple(sl)])
            den = vals[0] - 2 * vals[1] + vals[2]
            frac = 0.5 * (vals[0] - vals[2]) / den if den != 0 else 0.0
        else:
            frac = 0.0
        pos.append(coords[i] + frac * (coords[1] - coords[0]))
    return np.array(pos), idx


def width_3db(profile, step):
    """-3 dB width (m) of a 1-D magnitude profile through its maximum."""
    p = profile / profile.max()
    i = p.argmax()
    thr = 10 ** (-3 / 20)
    lo = i
    while lo > 0 and p[lo - 1] >= thr:
        lo -= 1
    hi = i
    while hi < p.size - 1 and p[hi + 1] >= thr:
        hi += 1
    # linear interpolation of the crossings
    left = lo - (p[lo] - thr) / (p[lo] - p[lo - 1]) if lo > 0 else lo
    right = hi + (p[hi] - thr) / (p[hi] - p[hi + 1]) if hi < p.size - 1 else hi
    return (right - left) * step


# a point under the track, on a voxel centre mid-tile (4.655 m from the line origin)
TARGET_WATER = np.array([1.655, 0.005, 0.405])
N_PINGS = 32            # the array (3 m forward of the body origin) passes over it


@pytest.fixture(scope="module")
def water_pings(hardware):
    # the body origin moves 0.1 m per ping; the array is 3 m forward of it
    return synth_pings(hardware, TARGET_WATER, CW, N_PINGS, start_along=-3.0)


def test_point_focus_resolution_and_gain(hardware, water_pings):
    pings, pairs = water_pings
    proc = processing(delays="straight", interpolation="linear", precision="float64",
                      water_sound_speed_m_s=CW)
    # the line origin is the first ping's body origin (along -3.0 m): shift the truth
    tile = image(hardware, proc, pings)
    truth = TARGET_WATER + [3.0, 0.0, 0.0]
    pos, idx = peak(tile)
    assert np.all(np.abs(pos - truth) <= 0.5 * proc.tile.voxel_m), (pos, truth)
    mag = np.abs(tile.image)
    v = proc.tile.voxel_m
    wf = make_waveform(hardware.value.waveform)
    # depth: range resolution c / 2B times the taper's broadening, from the waveform itself
    fs = 4e6
    s = wf.analytic(np.arange(int(wf.duration_s * fs) + 1) / fs)
    ac = np.abs(np.correlate(s, s, mode="full"))
    t_width = width_3db(ac, 1 / fs)
    expect_depth = CW * t_width / 2
    assert abs(width_3db(mag[idx[0], idx[1], :], v) / expect_depth - 1) < 0.15
    assert 0.8 < expect_depth / (CW / (2 * wf.bandwidth_hz)) < 1.6
    # along-track: two-way synthetic aperture limited by the projector cone
    lam = CW / wf.center_hz
    theta = math.radians(hardware.value.beams.projector_half_angle_deg)
    expect_along = 0.886 * lam / (4 * math.sin(theta))
    assert abs(width_3db(mag[:, idx[1], idx[2]], v) / expect_along - 1) < 0.3
    # coherent gain: every projector-receiver pair adds its echo amplitude in phase
    assert abs(mag.max() / pairs.sum() - 1) < 0.05


@pytest.mark.parametrize("interp", ["nearest", "cubic"])
def test_other_interpolations_focus(hardware, water_pings, interp):
    pings, pairs = water_pings
    proc = processing(delays="straight", interpolation=interp, precision="float32",
                      water_sound_speed_m_s=CW)
    tile = image(hardware, proc, pings)
    pos, _ = peak(tile)
    assert np.all(np.abs(pos - (TARGET_WATER + [3.0, 0, 0])) <= 0.5 * proc.tile.voxel_m)
    assert np.abs(tile.image).max() / pairs.sum() > (0.85 if interp == "nearest" else 0.95)


@pytest.fixture(scope="module")
def sand_pings(hardware):
    return synth_pings(hardware, TARGET_WATER, SAND, N_PINGS, start_along=-3.0)


@pytest.mark.parametrize("delays", ["exact", "table"])
def test_buried_point_focuses_at_true_depth_with_refraction(hardware, sand_pings, delays):
    pings, pairs = sand_pings
    # the exact Fermat path per voxel and element is the slow reference: coarser voxels
    # in a smaller box round the target (5 cross x 10 deep: the peak's neighbours on
    # every axis; a focus displaced by more would peak on the box's edge and fail)
    box = dict(voxel_m=0.02, width_m=0.1, depth_m=0.2, top_m=0.3) if delays == "exact" \
        else dict(voxel_m=0.01)
    proc = processing(**box, delays=delays, interpolation="linear", precision="float32",
                      water_sound_speed_m_s=CW, sediment_sound_speed_m_s=SAND,
                      table_step_m=0.01)
    tile = image(hardware, proc, pings)
    pos, _ = peak(tile)
    truth = TARGET_WATER + [3.0, 0, 0]
    assert np.all(np.abs(pos - truth) <= 0.5 * proc.tile.voxel_m), (pos, truth)
    assert np.abs(tile.image).max() / pairs.sum() > 0.9


def test_straight_rays_displace_buried_point_as_predicted(hardware, sand_pings):
    pings, _ = sand_pings
    proc = processing(delays="straight", interpolation="linear", precision="float32",
                      water_sound_speed_m_s=CW)
    tile = image(hardware, proc, pings)
    pos, _ = peak(tile)
    truth = TARGET_WATER + [3.0, 0, 0]
    # prediction: the depth whose straight-ray delays at c_w best match the true
    # (refracted) delays over the projector-receiver pairs, least squares, near vertical
    geo = array_geometry(hardware.value)
    tx = np.array([truth[0], 0.0, -2.0]) + [geo.projectors[:, 0].mean() - 3.0, 0, 0]
    true_t = refracted_time(tx, truth, CW, SAND)
    z_pred = minimize_scalar(
        lambda z: (np.linalg.norm(truth - tx + [0, 0, z - truth[2]]) / CW - true_t) ** 2,
        bounds=(0.0, truth[2]), method="bounded").x
    assert abs(z_pred - truth[2] * CW / SAND) < 0.01          # the vertical-ray estimate
    assert abs(pos[2] - z_pred) <= 2 * proc.tile.voxel_m, (pos[2], z_pred)
    assert truth[2] - pos[2] > 5 * proc.tile.voxel_m             # clearly displaced upwards


def test_float32_far_from_the_line_origin_agrees_with_float64(hardware):
    """15 km along the line (tile index 50005 at 0.3 m tiles): geometry is made relative
    to the projector in float64 before the kernel runs in float32."""
    far = 15000.0
    pings, _ = synth_pings(hardware, TARGET_WATER + [far, 0, 0], CW, N_PINGS,
                           start_along=far - 3.0)
    images = {}
    for prec in ("float32", "float64"):
        proc = processing(delays="straight", interpolation="linear", precision=prec,
                          water_sound_speed_m_s=CW, track_line="fixed",
                          line_origin_ne_m=(0.0, 0.0), line_heading_deg=0.0)
        tile = image(hardware, proc, pings)
        assert tile.grid.index > 50000
        images[prec] = tile.image.astype(np.complex128)
        pos, _ = peak(tile)
        truth = TARGET_WATER + [far, 0, 0]          # the line origin is fixed at 0
        assert np.all(np.abs(pos - truth) <= 0.5 * proc.tile.voxel_m), (prec, pos, truth)
    ref = images["float64"]
    err = np.abs(images["float32"] - ref).max() / np.abs(ref).max()
    assert err < 1e-4, err


def test_refraction_table_covers_every_ping_whatever_came_first(hardware):
    """A table cached for a height is lengthened for a ping reaching further, with the
    same times at the nodes both hold: a batch task imaging a subset of a run's pings
    gets the times the whole run's imager used."""
    proc = processing(delays="table", sediment_sound_speed_m_s=SAND)
    imager = TileImager(hardware, proc)
    tx = np.array([0.0, 0.0, -2.0])
    rx = np.array([[0.1, -0.3, -2.0], [-0.2, 0.4, -2.0]])
    short = imager.accumulator.travel_table(tx, rx, 0.5)
    long = imager.accumulator.travel_table(tx, rx, 4.0)
    assert long.rho_max >= 4.0 + proc.tile.width_m
    n = short.time.shape[0]
    assert long.time.shape[0] > n
    np.testing.assert_array_equal(long.time[:n], short.time)
    np.testing.assert_array_equal(long.eta[:n], short.eta)
    assert imager.accumulator.travel_table(tx, rx, 1.0) is long          # long enough: kept
