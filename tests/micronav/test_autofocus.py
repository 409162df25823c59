"""Autofocus on prominent points (svss_proc.micronav.autofocus): on the demo scene's
simulated pings (80 channels, the real geometry, the demo processing), poses spoiled by
a cross-track step and a vertical drift with a random walk (a noisy DVL) lose several dB
at the scene's points; the autofocus brings them back to within a fraction of a dB of
the true poses' image, with the imaging kernel as the judge. The guard and the choice of
points are checked on their own."""

from __future__ import annotations

import numpy as np
import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.micronav.autofocus import (_Sampler, accept, accept_holdout, autofocus,
                                          autofocus_settings, bright_points,
                                          image_sharpness, isolated_points, peak_levels,
                                          shifted)


@pytest.fixture(scope="module")
def scene_run(hardware):
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from sim_device.track import truth_line
    from svss_proc.imaging.imager import TileImager
    proc = load(ProcessingConfig, config_path("processing-demo.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    src = EnvironmentSource(hardware, scene)
    pings = [src.ping(i) for i in range(0, 60)]      # the array passes the first 3 points
    imager = TileImager(hardware, proc)
    imager.add(pings[0])                             # fixes the tile frame
    line = imager.line
    truth = truth_line(scene.track)
    points = np.array([[*line.ned_to_tile(truth.tile_to_ned(np.array(
        [p.along_m, p.cross_m, p.depth_m])))[:2], p.depth_m] for p in scene.points[:3]])
    return proc, imager.accumulator, line, pings, points


@pytest.mark.slow
def test_autofocus_recovers_the_focus_a_noisy_track_lost(scene_run):
    proc, acc, line, pings, points = scene_run
    k = np.arange(len(pings))
    rng = np.random.default_rng(1)
    err_y = np.where(k >= len(pings) // 2, 0.012, 0.0) + 0.003 * np.sin(k / 7)   # m
    err_z = 0.02 * k / len(pings) + np.cumsum(rng.normal(0, 0.004, len(pings)))
    spoiled = [shifted(p, line, float(y), float(z)) for p, y, z in zip(pings, err_y, err_z)]
    # levels are the responses' peaks (within peak_search_m of each point), as the
    # autofocus judges them: against the true poses' peaks
    ref = peak_levels(_Sampler(acc, proc, line), pings, points, autofocus_settings(proc))[1]
    res = autofocus(acc, proc, line, spoiled, points)
    before = 20 * np.log10(res.before / ref)
    after = 20 * np.log10(res.after / ref)
    # the premise: the spoiled track defocuses every point, by dB
    assert np.all(before < -1.0) and before.mean() < -2.5, before
    assert res.kept and res.reason == "sharper"
    print("levels against the true poses' peaks (dB): before", np.round(before, 2),
          "after", np.round(after, 2))
    assert np.all(after > -1.0) and after.mean() > -0.5, (before, after)
    # the corrected pings are the spoiled ones moved by the corrections reported
    for p, q, y, z in zip(spoiled, res.pings, res.cross_m, res.down_m):
        assert q.samples is p.samples
        assert q.nav.down_m - p.nav.down_m == pytest.approx(z, abs=1e-12)
        assert q.nav.altitude_m - p.nav.altitude_m == pytest.approx(-z, abs=1e-12)
        assert np.hypot(q.nav.north_m - p.nav.north_m,
                        q.nav.east_m - p.nav.east_m) == pytest.approx(abs(y), abs=1e-12)


def test_autofocus_says_why_it_does_nothing(scene_run):
    proc, acc, line, pings, points = scene_run
    res = autofocus(acc, proc, line, pings, np.zeros((0, 3)))
    assert not res.kept and res.reason == "no point to focus on"
    assert res.pings == pings and not res.cross_m.any()
    far = points + np.array([40.0, 0.0, 0.0])                 # no ping reaches it
    res = autofocus(acc, proc, line, pings, far)
    assert not res.kept and "fewer than 3 pings" in res.reason


def test_the_guard_keeps_only_what_sharpens_every_point():
    before = np.array([1.0, 2.0, 3.0])
    assert accept(before, before * 1.1, 0.05) == (True, "sharper")
    kept, why = accept(before, np.array([2.0, 3.0, 2.8]), 0.05)   # one point fell 7 %
    assert not kept and "0.933" in why
    kept, why = accept(before, np.array([0.99, 1.99, 2.99]), 0.05)
    assert not kept and "did not grow" in why


class _Grid:
    def __init__(self, n, voxel=0.01):
        self.along, self.cross, self.depth = (voxel * np.arange(m) for m in n)


class _Tile:
    def __init__(self, image, voxel=0.01):
        self.image = image
        self.grid = _Grid(image.shape, voxel)


def test_bright_points_takes_strong_isolated_responses():
    rng = np.random.default_rng(3)
    img = (rng.normal(size=(80, 40, 30)) + 1j * rng.normal(size=(80, 40, 30))) * 0.1
    img[10, 5, 5] = 300.0            # strong
    img[11, 5, 5] = 250.0            # its neighbour: not a second point
    img[60, 30, 20] = 120.0          # strong, far
    img[40, 20, 10] = 2.0            # 26 dB over the median: not bright enough
    pts = bright_points([_Tile(img)], 5, min_separation_m=0.2, min_contrast_db=30.0)
    np.testing.assert_allclose(pts, [[0.10, 0.05, 0.05], [0.60, 0.30, 0.20]])
    assert bright_points([_Tile(img)], 1).shape == (1, 3)


def test_the_held_out_points_guard():
    before = np.array([1.0, 2.0])
    assert accept_holdout(before, before * 1.01, 0.02) == (True, "sharper")
    kept, why = accept_holdout(before, np.array([0.97, 2.1]), 0.02)
    assert not kept and "held-out point's peak fell to 0.970" in why
    kept, why = accept_holdout(before, np.array([0.99, 1.99]), 0.02)
    assert not kept and "held-out points' peak power fell" in why
    assert accept_holdout(np.zeros(0), np.zeros(0), 0.02)[0]


def _seabed(rng, shape=(150, 60, 50)):
    """A 2 cm tile of a seabed: volume speckle below an interface 40 dB brighter
    (depth 0-4 cm), brighter than any buried response."""
    img = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * 0.1
    img[:, :, :3] *= 100.0
    return img


def test_isolated_points_takes_only_responses_that_stand_out_of_a_seabed():
    settings = autofocus_settings()
    rng = np.random.default_rng(4)
    img = _seabed(rng)
    img[40, 30, 20] = 7.0        # a buried point: 36 dB over the speckle's median
    img[100, 20, 30] = 6.0       # another ...
    img[101, 21, 30] = 5.0       # ... its own lobe (inside the core): still isolated
    img[75, 45, 40] = 0.8        # 18 dB over the median: not enough contrast
    img[120, 10, 25] = 6.0       # bright, but a neighbour as bright 12 cm away
    img[126, 10, 25] = 5.5
    pick = isolated_points([_Tile(img, 0.02)], settings)
    assert pick.refused is None
    np.testing.assert_allclose(pick.points, [[0.80, 0.60, 0.40], [2.00, 0.40, 0.60]])
    assert np.all(pick.contrast_db > 30) and np.all(pick.isolation_db > 6)
    assert pick.rejected["a neighbour as bright"] >= 2 and pick.rejected["low contrast"] > 0
    # the brightest voxels, as bright_points takes them, are the interface's
    assert np.all(bright_points([_Tile(img, 0.02)], 6, min_contrast_db=0.0)[:, 2] < 0.06)


def test_isolated_points_refuses_a_seabed_without_isolated_responses():
    settings = autofocus_settings()
    pick = isolated_points([_Tile(_seabed(np.random.default_rng(5)), 0.02)], settings)
    assert len(pick.points) == 0
    assert pick.refused.startswith("no isolated response: of 400 local maxima 0.1 m or "
                                   "more below the interface")
    assert "over the background" in pick.refused and "over its neighbours" in pick.refused


def test_image_sharpness():
    # a response's energy over 27 voxels, then gathered into one: 27 times sharper;
    # voxels no ping reached (zero) do not count
    spread = np.zeros((10, 10, 10), dtype=np.complex64)
    spread[3:6, 3:6, 3:6] = 1.0
    spread[0, 0, 0] = 0.1
    focused = np.zeros_like(spread)
    focused[4, 4, 4] = np.sqrt(27.0)
    focused[0, 0, 0] = 0.1
    focused[3, 3, 3] = 1e-6
    assert image_sharpness(spread) == pytest.approx((27 + 1e-4) / 28)
    assert image_sharpness(focused) == pytest.approx((27 ** 2 + 1e-4 + 1e-24) / 3)
    assert image_sharpness(np.zeros(10)) == 0.0
