"""A sloping seabed in the simulator: a buried point's echo arrives at the two-way time of
Fermat's path through the tilted plane, found here by minimising the travel time over
the crossing point in the scene's tile frame (independently of the simulator's bed
frame); the recorded altitude is the body's vertical height above the plane; element
images are mirrored in the horizontal sea surface and in the tilted bed.

The echo's delay is read from the phase of its correlation with the band-limited echo
at the reference delay: exp(-j 2 pi f_c delta) for an echo delta late, so that a few
nanoseconds show. The level bed is checked the same way, so that the method itself is
tested against a known answer."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.signal import hilbert

from sim_device.bed_plane import BedPlane, leg_image_position
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import PointTarget, load_scene
from svss_daq.config import config_path
from svss_daq.waveform import make_waveform
from tests.sim.test_synthesis import band_limited_echo, elements_written_out

SLOPE = (3.0, 5.0)           # deg along, across: the bench's sloping sand


def scene_with(slope, point):
    sc = load_scene(config_path("scenes/seabed_sand.toml"))
    return dataclasses.replace(
        sc, points=(point,), targets=(), surface=None,
        noise=dataclasses.replace(sc.noise, electronic_rms_counts=0.0),
        scattering=dataclasses.replace(sc.scattering, interface=False, volume=False,
                                       specular=False),
        # nearly lossless: a lossy sediment's complex transmission coefficients add a phase
        # (about 50 ns at the carrier here) that is not a travel time
        seabed=dataclasses.replace(sc.seabed, slope_deg=slope, layers=tuple(
            dataclasses.replace(layer, loss_parameter=1e-6) for layer in sc.seabed.layers)))


def fermat_time(e, q, ga, gc, cw, cs):
    """Least travel time (s) from e (water) to q (sediment, tile frame) through the plane
    z = ga x + gc y, over the crossing point, to 1e-13 s."""
    def t(xy):
        p = np.array([xy[0], xy[1], ga * xy[0] + gc * xy[1]])
        return np.linalg.norm(p - e) / cw + np.linalg.norm(q - p) / cs
    s = (ga * e[0] + gc * e[1] - e[2]) / ((ga * e[0] + gc * e[1] - e[2])
                                          + (q[2] - ga * q[0] - gc * q[1]))
    x0 = e[:2] + s * (q[:2] - e[:2])                # where the straight line crosses
    res = minimize(t, x0, method="Nelder-Mead",
                   options={"xatol": 1e-10, "fatol": 1e-16, "maxiter": 20000})
    return float(res.fun)


def measured_delays(hardware, sc, i, chans):
    """Each channel's echo delay, s, from the phase of its correlation with the
    band-limited echo at that channel's reference delay ``chans[ch]``."""
    hw = hardware.value
    src = EnvironmentSource(hardware, sc)
    p = src.pressure(i)
    wf = make_waveform(hw.waveform)
    dig = hw.digitiser
    fs = dig.sample_rate_hz
    t = dig.window_start_s - dig.group_delay_s + np.arange(dig.window_samples) / fs
    out = {}
    for ch, tau in chans.items():
        ref = hilbert(band_limited_echo(wf, t, tau, fs))
        c = np.sum(p[ch] * np.conj(ref))
        # the echo is there, and the reference lies on its main lobe (a quarter period
        # out would halve |c| against the echo's own energy)
        assert abs(c) > 0.9 * np.sqrt(np.sum(p[ch] ** 2) * np.sum(np.abs(ref) ** 2) / 2)
        out[ch] = tau - np.angle(c) / (2 * math.pi * wf.center_hz)
    return src, out


@pytest.mark.parametrize("slope", [None, SLOPE], ids=["level", "sloping"])
def test_buried_point_echo_arrives_at_the_fermat_time_through_the_plane(hardware, slope):
    hw = hardware.value
    i = 60
    probe = scene_with(slope, PointTarget(along_m=0, cross_m=0, depth_m=1,
                                          target_strength_db=-10.0))
    tx, rx, _ = elements_written_out(hw, probe, i)
    pt = PointTarget(along_m=float(tx[0]) + 0.3, cross_m=float(tx[1]) + 0.25,
                     depth_m=0.6, target_strength_db=-10.0)   # near the projector's nadir
    sc = scene_with(slope, pt)
    ga, gc = (math.tan(math.radians(a)) for a in (slope or (0.0, 0.0)))
    q = np.array([pt.along_m, pt.cross_m, ga * pt.along_m + gc * pt.cross_m + pt.depth_m])
    cw, cs = 1500.0, 1767.0            # the scene's water; medium_sand (config/sediments.toml)
    t_tx = fermat_time(tx, q, ga, gc, cw, cs)
    chans = {ch: t_tx + fermat_time(rx[ch], q, ga, gc, cw, cs) for ch in range(0, 80, 9)}
    src, got = measured_delays(hardware, sc, i, chans)
    assert math.isclose(float(np.real(src.media.c[1])), cs, rel_tol=1e-9)
    err = np.array([got[ch] - chans[ch] for ch in chans])
    assert np.abs(err).max() < 5e-10, err         # 0.5 ns: 0.75 mm of water path
    if slope is not None:                          # the slope moved the echo by far more
        flat = {ch: fermat_time(tx, q - [0, 0, q[2] - pt.depth_m], 0, 0, cw, cs)
                + fermat_time(rx[ch], q - [0, 0, q[2] - pt.depth_m], 0, 0, cw, cs)
                for ch in chans}
        assert min(abs(chans[ch] - flat[ch]) for ch in chans) > 1e-5


def test_altitude_is_the_vertical_height_above_the_plane(hardware):
    hw = hardware.value
    sc = scene_with(SLOPE, PointTarget(along_m=5, cross_m=0, depth_m=0.5,
                                       target_strength_db=-20))
    src = EnvironmentSource(hardware, sc)
    ga, gc = (math.tan(math.radians(a)) for a in SLOPE)
    for i in (0, 50, 120):
        nav = src.pose(i)
        h = math.radians(sc.track.heading_deg)
        dn = nav.north_m - sc.track.start_ne_m[0]
        de = nav.east_m - sc.track.start_ne_m[1]
        a, c = dn * math.cos(h) + de * math.sin(h), -dn * math.sin(h) + de * math.cos(h)
        bed_down = sc.track.body_down_m + sc.track.altitude_m + ga * a + gc * c
        assert nav.altitude_m == pytest.approx(bed_down - nav.down_m, abs=1e-9)


def test_bed_reaching_the_platform_is_refused_naming_the_key(hardware):
    sc = scene_with((-30.0, 0.0), PointTarget(along_m=5, cross_m=0, depth_m=0.5,
                                              target_strength_db=-20))
    src = EnvironmentSource(hardware, dataclasses.replace(
        sc, track=dataclasses.replace(sc.track, n_pings=130)))
    with pytest.raises(ValueError, match="seabed.slope_deg"):
        src.pose(129)


def test_element_images_mirror_in_the_surface_and_the_tilted_bed():
    plane = BedPlane.from_slopes(*SLOPE)
    depth = 2.5
    e_tile = np.array([0.4, -0.3, -2.1])           # an element 2.1 m above the level
    e = plane.to_bed(e_tile)
    # one reflection: the surface, horizontal in the tile frame at z = -depth
    want = plane.to_bed(e_tile * [1, 1, -1] + [0, 0, -2 * depth])
    assert np.allclose(leg_image_position(1, e, plane, depth), want, atol=1e-12)
    # two: the bed (bed-frame z = 0), then the surface
    b = e * [1, 1, -1]
    b_tile = b @ plane.rot                         # back to the tile frame
    want2 = plane.to_bed(b_tile * [1, 1, -1] + [0, 0, -2 * depth])
    assert np.allclose(leg_image_position(2, e, plane, depth), want2, atol=1e-12)
    # a level bed gives the one-dimensional images of sim_device.multipath
    flat = BedPlane.from_slopes(0.0, 0.0)
    for m, z in ((1, -2 * depth + 2.1), (2, -2 * depth - 2.1), (3, -4 * depth + 2.1)):
        assert leg_image_position(m, e_tile, flat, depth)[2] == pytest.approx(z)
