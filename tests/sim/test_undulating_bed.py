"""An undulating seabed in the simulator (sim_device.bed_undulation): buried echoes arrive
at the Fermat time through the curved surface, found here independently (a dense grid of
crossing points, then Nelder-Mead, in the tile frame); the recorded altitude and the
DVL's beams meet the curved surface where a ray written out here meets it; a surface of
zero amplitude gives the level bed's echoes to rounding; scenes the model cannot serve
are refused naming the key.

Echo delays are read as in tests/sim/test_sloping_bed.py, from the phase of the echo's
correlation with the band-limited echo at the reference delay."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq, minimize

from sim_device.bed_surface import BedSurface, ned_beam_ranges
from sim_device.bed_undulation import Undulation, crossing
from sim_device.environment_source import EnvironmentSource
from sim_device.scene import PointTarget, UndulationTerm, load_scene
from sim_device.synthesis import leg
from sim_device.synthesis_args import Beam, Medium
from sim_device.synthesis_curved import curved_leg_body
from sim_device.track import truth_line
from svss_daq.config import ConfigError, config_path
from tests.sim.test_sloping_bed import measured_delays
from tests.sim.test_synthesis import elements_written_out

#: the bench's undulating sand: 10 cm over 4 m along the track, 4 cm over 2.5 m across
TERMS = (UndulationTerm(amplitude_m=0.10, wavelength_m=4.0, direction_deg=0.0,
                        phase_deg=20.0),
         UndulationTerm(amplitude_m=0.04, wavelength_m=2.5, direction_deg=90.0,
                        phase_deg=60.0))
CW, CS = 1500.0, 1767.0        # the scene's water; medium_sand (config/sediments.toml)


def undulation(terms=TERMS) -> Undulation:
    return Undulation.from_terms([(t.amplitude_m, t.wavelength_m, t.direction_deg,
                                   t.phase_deg) for t in terms])


def height(terms, x, y):
    """The surface written out from the scene's terms (not through Undulation)."""
    return sum(t.amplitude_m * math.cos(2 * math.pi / t.wavelength_m
                                        * (x * math.cos(math.radians(t.direction_deg))
                                           + y * math.sin(math.radians(t.direction_deg)))
                                        + math.radians(t.phase_deg)) for t in terms)


def fermat_time(e, q, terms, cw, cs):
    """Least travel time (s) from e (water) to q (sediment) through the surface of
    ``terms``: the best of a 2 cm grid of crossing points, refined by Nelder-Mead."""
    def t(xy):
        p = np.array([xy[0], xy[1], height(terms, xy[0], xy[1])])
        return np.linalg.norm(p - e) / cw + np.linalg.norm(q - p) / cs
    xs = np.arange(min(e[0], q[0]) - 0.3, max(e[0], q[0]) + 0.3, 0.02)
    ys = np.arange(min(e[1], q[1]) - 0.3, max(e[1], q[1]) + 0.3, 0.02)
    best = min(((t((x, y)), x, y) for x in xs for y in ys))
    res = minimize(t, best[1:], method="Nelder-Mead",
                   options={"xatol": 1e-10, "fatol": 1e-16, "maxiter": 20000})
    return float(res.fun)


def scene_with(terms, point, sediment_loss=1e-6):
    sc = load_scene(config_path("scenes/seabed_sand.toml"))
    return dataclasses.replace(
        sc, points=(point,), targets=(), surface=None,
        noise=dataclasses.replace(sc.noise, electronic_rms_counts=0.0),
        scattering=dataclasses.replace(sc.scattering, interface=False, volume=False,
                                       specular=False),
        seabed=dataclasses.replace(sc.seabed, undulation=terms, layers=tuple(
            dataclasses.replace(layer, loss_parameter=sediment_loss)
            for layer in sc.seabed.layers)))


def test_crossing_is_the_global_least_time_through_the_surface():
    und = undulation()
    rng = np.random.default_rng(46)
    for cs in (1767.0, 1476.0):                    # a faster and a slower sediment
        for _ in range(12):
            e = np.array([rng.uniform(-3, 3), rng.uniform(-2, 2), -rng.uniform(1.0, 4.0)])
            q = np.array([rng.uniform(-3, 3), rng.uniform(-2, 2), 0.0])
            q[2] = height(TERMS, q[0], q[1]) + rng.uniform(0.05, 2.0)
            sx, sy, sz, ok = crossing(*e, *q, CW, cs, und.rows)
            assert ok
            assert sz == pytest.approx(height(TERMS, sx, sy), abs=1e-12)
            s = np.array([sx, sy, sz])
            got = np.linalg.norm(s - e) / CW + np.linalg.norm(q - s) / cs
            assert got == pytest.approx(fermat_time(e, q, TERMS, CW, cs), abs=2e-13)


def test_buried_point_echo_arrives_at_the_fermat_time_through_the_surface(hardware):
    hw = hardware.value
    i = 60
    probe = scene_with(TERMS, PointTarget(along_m=0, cross_m=0, depth_m=1,
                                          target_strength_db=-10.0))
    tx, rx, _ = elements_written_out(hw, probe, i)
    # near the projector's nadir, on a flank of the 4 m undulation (the surface there
    # tilts the ray by several degrees)
    pt = PointTarget(along_m=float(tx[0]) + 0.3, cross_m=float(tx[1]) + 0.25,
                     depth_m=0.6, target_strength_db=-10.0)
    sc = scene_with(TERMS, pt)
    q = np.array([pt.along_m, pt.cross_m, height(TERMS, pt.along_m, pt.cross_m) + 0.6])
    t_tx = fermat_time(tx, q, TERMS, CW, CS)
    chans = {ch: t_tx + fermat_time(rx[ch], q, TERMS, CW, CS) for ch in range(0, 80, 13)}
    src, got = measured_delays(hardware, sc, i, chans)
    err = np.array([got[ch] - chans[ch] for ch in chans])
    assert np.abs(err).max() < 5e-10, err          # 0.5 ns: 0.75 mm of water path
    # a level bed through the surface's height above the point would put it elsewhere
    # in time (the test can tell the curved surface from a plane)
    u_here = height(TERMS, pt.along_m, pt.cross_m)
    flat = {ch: fermat_time(tx - [0, 0, u_here], q - [0, 0, u_here], (), CW, CS)
            + fermat_time(rx[ch] - [0, 0, u_here], q - [0, 0, u_here], (), CW, CS)
            for ch in chans}
    assert max(abs(chans[ch] - flat[ch]) for ch in chans) > 2e-8


def test_zero_amplitude_surface_gives_the_level_legs():
    """The curved leg of a surface of zero amplitude equals the level leg for points in
    the water, on the interface and in the sediment, direct and surface-image legs."""
    und = Undulation(np.array([[0.0, 1.3, 0.4, 0.2]]))
    c = np.array([1500.0, 1767.0])
    rho = np.array([1000.0, 2000.0])
    delta = np.array([0.0, 0.01])
    alpha = np.array([1e-4, 2.0])
    z_top = np.array([-np.inf, 0.0])
    r_top = (np.linspace(0.1, 0.6, 101) * np.exp(0.2j)).astype(np.complex128)
    r_bot = r_top * 0.5
    bore = np.array([0.1, 0.05, 0.99])
    bore /= np.linalg.norm(bore)
    front = np.linspace(0.2, 1.0, 200)
    beam = Beam(bore, front, np.zeros(0), 0.3, 1.0)
    # a table of ones sends the level legs to Brent's method (scene precision "exact")
    medium = Medium(c, rho, delta, alpha, z_top, np.ones((2, 2)), r_top, r_bot, np.ones(11))
    hbuf, cbuf = np.empty(3), np.empty(2)
    for img in ((0.2, -0.1, 2.5, 1.0), (0.2, -0.1, 7.5, -1.0)):   # direct, surface image
        for x, y, z, med in ((0.9, 0.4, 0.7, 1), (-0.6, 0.3, 0.0, -1), (0.5, -0.8, -0.4, 0),
                             (0.05, 0.02, 1.9, 1)):
            for up in (False, True):
                want = leg(img[0], img[1], img[2], img[3], 1.0, 0, x, y, z, med, up, medium,
                           beam, hbuf, cbuf)
                got = curved_leg_body(img[0], img[1], img[2], img[3], 1.0, 0, x, y, z, med,
                                      up, c, rho, delta, alpha, z_top, und.rows, r_top,
                                      r_bot, bore, front, np.zeros(0), 0.3, 1.0, hbuf, cbuf)
                assert got[0] == pytest.approx(want[0], rel=1e-13, abs=1e-18)
                assert abs(got[1] - want[1]) <= 1e-9 * abs(want[1]) + 1e-300
                assert got[2] == pytest.approx(want[2], abs=1e-9)


def test_zero_amplitude_scene_gives_the_level_scenes_echoes(hardware):
    """A whole ping of points, interface and volume scatterers: the curved kernels over a
    surface of zero amplitude against the level reference kernels."""
    base = load_scene(config_path("scenes/seabed_sand.toml"))
    sc = dataclasses.replace(
        base, targets=(), surface=None,
        noise=dataclasses.replace(base.noise, electronic_rms_counts=0.0),
        scattering=dataclasses.replace(base.scattering, specular=False, synthesis="reference",
                                       precision="exact",
                                       volume_below_noise_db=None, cell_m=0.5,
                                       scatterers_per_resolution_cell=0.05))
    flat = EnvironmentSource(hardware, sc)
    zero = (UndulationTerm(amplitude_m=0.0, wavelength_m=4.0, direction_deg=10.0,
                           phase_deg=0.0),)
    curved = EnvironmentSource(hardware, dataclasses.replace(
        sc, seabed=dataclasses.replace(sc.seabed, undulation=zero)))
    a = flat.scattered(60)
    b = curved.scattered(60)
    assert flat.last_stats["echoes"] > 1000
    assert curved.last_stats["echoes"] == flat.last_stats["echoes"]
    assert np.max(np.abs(b - a)) <= 1e-9 * np.max(np.abs(a))


def test_altitude_and_dvl_beams_meet_the_curved_surface(hardware):
    sc = scene_with(TERMS, PointTarget(along_m=5, cross_m=0, depth_m=0.5,
                                       target_strength_db=-20))
    src = EnvironmentSource(hardware, sc)
    line = truth_line(sc.track)
    for i in (0, 37, 90):
        nav = src.pose(i)
        a, c, z = line.ned_to_tile(np.array([nav.north_m, nav.east_m, nav.down_m]))
        assert nav.altitude_m == pytest.approx(height(TERMS, a, c) - z, abs=1e-9)
    # four beams 30 deg off the vertical from a head 2.4 m above the level
    ranges = ned_beam_ranges(BedSurface(None, undulation()), line)
    head = line.tile_to_ned(np.array([3.1, -0.4, -2.4]))
    s30 = math.sin(math.radians(30.0))
    dirs_tile = np.array([[s30, 0, 1], [-s30, 0, 1], [0, s30, 1], [0, -s30, 1]])
    dirs_tile[:, 2] = math.cos(math.radians(30.0))
    dirs_ned = dirs_tile @ line.rotation_from_ned()       # tile -> NED
    got = ranges(head, dirs_ned)
    o = np.array([3.1, -0.4, -2.4])
    for d, r in zip(dirs_tile, got):
        f = lambda t: o[2] + t * d[2] - height(TERMS, o[0] + t * d[0], o[1] + t * d[1])  # noqa: E731
        ts = np.linspace(0.0, 4.0, 4001)
        k = int(np.argmax(np.array([f(t) for t in ts]) >= 0))   # the first crossing
        want = brentq(f, ts[k - 1], ts[k], xtol=1e-13)
        assert r == pytest.approx(want, abs=1e-9)
        assert abs(want - 2.4 / d[2]) > 1e-3                    # not the level's range


@pytest.mark.parametrize("change, key", [
    (lambda sc: dataclasses.replace(sc, seabed=dataclasses.replace(
        sc.seabed, layers=(dataclasses.replace(sc.seabed.layers[0], thickness_m=0.5),
                           sc.seabed.layers[0]))), "seabed.undulation"),
    (lambda sc: dataclasses.replace(sc, seabed=dataclasses.replace(sc.seabed, undulation=(
        UndulationTerm(amplitude_m=0.4, wavelength_m=2.0, direction_deg=0.0,
                       phase_deg=0.0),))), "seabed.undulation"),
    (lambda sc: dataclasses.replace(sc, surface=dataclasses.replace(
        load_scene(config_path("scenes/seabed_sand.toml")).surface, multipath_order=2)),
     "surface.multipath_order"),
])
def test_scenes_the_model_cannot_serve_are_refused_naming_the_key(tmp_path, change, key):
    from sim_device.scene import check_scene
    sc = change(scene_with(TERMS, PointTarget(along_m=5, cross_m=0, depth_m=0.5,
                                              target_strength_db=-20)))
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        check_scene(sc, "scene.toml")
