"""Each contact's features (svss_proc/products/contact_features.py; issue 51): the tail
below the object (extent, decay, late-to-specular) against synthetic images whose tail
and background are known, and the resonance lines of ringing echoes against the decaying
sinusoids they are made of."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from svss_daq.config import FeaturesConfig
from svss_proc.products import detect
from svss_proc.products.contact_features import (LATE_UPPER_BOUND, NO_ASPECT, NO_TAIL,
                                                 SHORT_FIT, TAIL_CUT, contact_features,
                                                 flags_text, point_fraction,
                                                 resonance_lines)

VOXEL = 0.02
CFG = FeaturesConfig(enabled=True, footprint_min_m=(0.06, 0.06),
                     footprint_max_m=(0.3, 0.3), peak_window_m=0.06, tail_window_m=0.5,
                     background_within_db=3.0, below_run_m=0.06, reference_boxes=4,
                     reference_gap_m=0.2, min_fit_points=4, profile_m=1.0,
                     aspect_window_m=0.6, point_aspect_deg=None)
#: Rayleigh magnitude of unit-variance components: its median
MEDIAN = math.sqrt(2.0 * math.log(2.0))


def axes(shape):
    return tuple(np.arange(n) * VOXEL for n in shape)


def scene(rng, shape=(120, 30, 100), at=(1.2, 0.3, 0.4), peak_db=40.0, tail_db=None,
          tail_start_db=22.0):
    """The normalised level (dB re the speckle's median, known) of complex speckle with
    a point at ``at`` (a 3 x 3 x 3 voxel blob ``peak_db`` over the median) and, below
    it from 0.06 m, a tail ``tail_start_db`` over the speckle's mean intensity falling
    by ``tail_db`` dB per metre of depth over the 3 x 3 columns of the point (random
    phases); returns the level and the detection row."""
    img = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    a, c, z = axes(shape)
    ia, ic, iz = (int(round(p / VOXEL)) for p in at)
    img[ia - 1:ia + 2, ic - 1:ic + 2, iz - 1:iz + 2] += MEDIAN * 10 ** (peak_db / 20)
    if tail_db is not None:
        d = z - z[iz]
        below = d > 0.06 + 1e-9
        mean_i = 2.0                     # the speckle's mean intensity
        amp = np.sqrt(mean_i * 10 ** ((tail_start_db - tail_db * (d - 0.06)) / 10))
        ph = np.exp(2j * np.pi * rng.random((3, 3, shape[2])))
        img[ia - 1:ia + 2, ic - 1:ic + 2, below] += (amp[None, None, :] * ph)[:, :, below]
    level = 20 * np.log10(np.abs(img) / MEDIAN)
    row = np.zeros(1, dtype=detect.DTYPE)
    row["along_m"], row["cross_m"], row["depth_m"] = a[ia], c[ic], z[iz]
    row["extent_along_m"] = row["extent_cross_m"] = row["extent_depth_m"] = 0.04
    return level.astype(np.float32), row


def test_decay_rate_recovered_within_its_stated_uncertainty():
    """A point with a tail falling 30 dB/m over speckle: over 40 independent images the
    fitted decay's error over its stated standard error has mean ~0 and spread ~1, and
    95 % of them lie within 2 standard errors."""
    z, ext = [], []
    for seed in range(40):
        level, row = scene(np.random.default_rng(seed), tail_db=30.0)
        f = contact_features(level, axes(level.shape), row, CFG)
        c = f.columns
        assert c["feature_flags"][0] & (NO_TAIL | SHORT_FIT | TAIL_CUT) == 0
        z.append((c["tail_decay_db_per_m"][0] - 30.0) / c["tail_decay_err_db_per_m"][0])
        ext.append(c["tail_extent_m"][0])
    # the extent: the profile (tail plus background over the background) falls to 3 dB
    # where the tail is as strong as the background: 0.06 m + 22/30 m = 0.79 m (the
    # background's fluctuation holds it up a little: the run must stay under 3 dB)
    assert abs(np.median(ext) - (0.06 + 22.0 / 30.0)) < 0.06
    assert np.all(np.abs(np.array(ext) - (0.06 + 22.0 / 30.0)) < 0.25)
    z = np.array(z)
    assert abs(z.mean()) < 0.5
    assert 0.6 < z.std() < 1.5
    assert np.mean(np.abs(z) < 2.0) >= 0.85


def test_stated_uncertainty_against_the_spread_over_images():
    """The decay's standard error agrees with the spread of the decay over images."""
    d, e = [], []
    for seed in range(40):
        level, row = scene(np.random.default_rng(100 + seed), tail_db=50.0,
                           tail_start_db=25.0)
        c = contact_features(level, axes(level.shape), row, CFG).columns
        d.append(c["tail_decay_db_per_m"][0])
        e.append(c["tail_decay_err_db_per_m"][0])
    assert abs(np.mean(d) - 50.0) < 3 * np.std(d) / math.sqrt(len(d)) + 1.0
    assert 0.6 < np.std(d) / np.sqrt(np.mean(np.square(e))) < 1.6


def test_a_point_without_a_tail():
    """No tail: extent within the peak window, no decay, late-to-specular very low
    (mostly an upper bound from the background's fluctuation: the late energy is the
    background's, under twice its spread but for chance)."""
    bounds = 0
    for seed in range(10):
        level, row = scene(np.random.default_rng(seed))
        c = contact_features(level, axes(level.shape), row, CFG).columns
        assert c["tail_extent_m"][0] <= CFG.peak_window_m + 1e-6
        assert np.isnan(c["tail_decay_db_per_m"][0])
        assert c["feature_flags"][0] & NO_TAIL
        bounds += bool(c["feature_flags"][0] & LATE_UPPER_BOUND)
        assert c["late_to_specular_db"][0] < -25.0
    assert bounds >= 7


def test_late_to_specular_against_the_energies_put_in():
    """A tail of known energy: the ratio equals the tail's energy over the point's
    within its stated uncertainty (three of them)."""
    rng = np.random.default_rng(7)
    level, row = scene(rng, tail_db=30.0)
    c = contact_features(level, axes(level.shape), row, CFG).columns
    # expected: per depth, the footprint's mean intensity (re the median) over the
    # background's mean intensity (1 / ln 2), summed over the windows
    mean_bg = 1.0 / math.log(2.0)
    d = np.arange(1, 26 + 1) * VOXEL           # the tail window: 0.06 < d <= 0.56
    d = d[(d > 0.06 + 1e-9) & (d <= 0.56 + 1e-9)]
    late = np.sum(10 ** ((22.0 - 30.0 * (d - 0.06)) / 10))     # re the mean intensity
    # peak window: the blob's layers at d = 0 (9 of 9 voxels) plus d = 0.02 (9 of 9):
    # amplitude MEDIAN * 100 over the median: intensity 1e4 re the median
    spec = 2 * 1e4 / mean_bg
    expect = 10 * math.log10(late / spec)
    err = c["late_to_specular_err_db"][0]
    assert np.isfinite(err) and err > 0
    assert abs(c["late_to_specular_db"][0] - expect) < 3 * err + 0.3


def test_no_contacts_no_features():
    level = np.full((40, 10, 30), -300.0, dtype=np.float32)
    f = contact_features(level, axes(level.shape), detect.empty(), CFG)
    assert all(v.size == 0 for v in f.columns.values())
    assert f.profiles.shape[0] == 0


def test_a_contact_on_a_tile_of_no_data():
    """Every voxel missing: NaN features with their reasons, no error."""
    level = np.full((40, 10, 30), -300.0, dtype=np.float32)
    row = np.zeros(1, dtype=detect.DTYPE)
    row["along_m"], row["cross_m"], row["depth_m"] = 0.4, 0.1, 0.2
    c = contact_features(level, axes(level.shape), row, CFG).columns
    assert np.isnan(c["tail_decay_db_per_m"][0])
    assert np.isnan(c["late_to_specular_db"][0])
    assert c["feature_flags"][0] > 0


def test_a_tail_cut_by_the_tiles_bottom_is_flagged_not_wrong():
    """A contact 0.2 m above the bottom with a long tail: the extent and the late energy
    are NaN (cut), flagged; the decay, where fitted, holds the truth within its
    uncertainty."""
    rng = np.random.default_rng(3)
    level, row = scene(rng, at=(1.2, 0.3, 1.78), tail_db=10.0)
    c = contact_features(level, axes(level.shape), row, CFG).columns
    flags = int(c["feature_flags"][0])
    assert flags & TAIL_CUT and "tail cut" in flags_text(flags)
    assert np.isnan(c["tail_extent_m"][0])
    assert np.isnan(c["late_to_specular_db"][0])
    d, e = c["tail_decay_db_per_m"][0], c["tail_decay_err_db_per_m"][0]
    assert np.isnan(d) or abs(d - 10.0) < 3 * e


def test_neighbouring_contacts_are_not_taken_for_background():
    """A second bright contact where a reference footprint would lie is left out of the
    references: the first contact's profile is not pulled down by it."""
    rng = np.random.default_rng(11)
    level, row = scene(rng, tail_db=30.0)
    alone = contact_features(level, axes(level.shape), row, CFG).columns
    # a second point with a bright tail 0.3 m ahead (where the first reference lies)
    level2, row2 = scene(np.random.default_rng(12), at=(1.5, 0.3, 0.4), tail_db=5.0,
                         tail_start_db=30.0)
    both = level.copy()
    both[28:33] = level2[28:33]
    rows = np.concatenate([row, row2])
    c = contact_features(both, axes(level.shape), rows, CFG).columns
    assert abs(c["tail_decay_db_per_m"][0] - alone["tail_decay_db_per_m"][0]) < \
        2 * alone["tail_decay_err_db_per_m"][0]


# --------------------------------------------------------------- resonance lines


def ringing(rng, fs, n, lines, pings, noise=0.0, real=False):
    t = np.arange(n) / fs
    out = []
    for _ in range(pings):
        s = np.zeros(n, dtype=complex)
        for f, w, a in lines:        # w: full width at half power = decay rate / pi
            ph = rng.random() * 2 * np.pi
            s += a * np.exp(-np.pi * w * t + 1j * (2 * np.pi * f * t + ph))
        if real:
            s = s.real
        s = s + noise * (rng.standard_normal(n) + (0 if real else 1j * rng.standard_normal(n)))
        out.append(s)
    return np.array(out)


def test_a_decaying_sinusoid_line_and_width_recovered():
    """A line at 4.2 kHz (baseband) decaying over 2 ms (width 1/(pi 2 ms) = 159 Hz),
    noise-free: frequency and width exact."""
    fs = 62500.0
    w = 1.0 / (np.pi * 2e-3)
    x = ringing(np.random.default_rng(0), fs, 400, [(4200.0, w, 1.0)], 1)
    r = resonance_lines(x, fs, max_lines=2, f_offset_hz=27500.0)
    assert r.frequency_hz.size == 1
    assert r.frequency_hz[0] == pytest.approx(31700.0, abs=1e-6)
    assert r.width_hz[0] == pytest.approx(w, rel=1e-6)


def test_two_lines_in_noise_over_pings_within_their_uncertainty():
    """Two lines (real samples, so each at +f and -f) over 12 noisy pings: both recovered
    within 4 jackknife standard errors (and 2 % of their width)."""
    fs = 125000.0
    truth = [(24800.0, 300.0, 1.0), (31000.0, 120.0, 0.6)]
    x = ringing(np.random.default_rng(5), fs, 400, truth, 12, noise=0.05, real=True)
    r = resonance_lines(x, fs, max_lines=2)
    assert r.frequency_hz.size == 2
    for (f, w, _), fm, wm, fe, we in zip(truth, r.frequency_hz, r.width_hz,
                                         r.frequency_err_hz, r.width_err_hz):
        assert np.isfinite(fe) and np.isfinite(we)
        assert abs(fm - f) < 4 * fe + 0.02 * w
        assert abs(wm - w) < 4 * we + 0.02 * w


def test_silence_has_no_lines():
    r = resonance_lines(np.zeros((3, 100)), 1000.0)
    assert r.frequency_hz.size == 0


# ------------------------------------------------------------ aspect over the aperture

K_W = 2 * np.pi * 27500.0 / 1500.0          # rad/m: the band's centre in water


def aperture_image(rng, centre_deg, spread_deg, shape=(100, 15, 40), at=(1.0, 0.14, 0.4)):
    """A complex image whose contact columns (its 3 x 7 footprint x peak window) hold a
    response with a Gaussian angular spectrum along-track: look angles theta with
    sin(theta) about sin(centre) with deviation sin(spread), random phases, summed on a
    fine k_x grid (k_x = 2 k sin theta); over weak speckle."""
    img = 1e-3 * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    a, c, z = axes(shape)
    ia, ic, iz = (int(round(p / VOXEL)) for p in at)
    s0, ss = math.sin(math.radians(centre_deg)), math.sin(math.radians(spread_deg))
    sgrid = np.linspace(s0 - 5 * ss, s0 + 5 * ss, 801)
    amp = np.exp(-0.25 * ((sgrid - s0) / ss) ** 2)          # power: exp(-0.5 (..)^2)
    x = a - a[ia]
    for j in range(ic - 1, ic + 2):
        for k in range(iz - 3, iz + 4):
            ph = np.exp(2j * np.pi * rng.random(sgrid.size))
            img[:, j, k] += np.exp(1j * 2 * K_W * np.outer(x, sgrid)) @ (amp * ph) / 30
    row = np.zeros(1, dtype=detect.DTYPE)
    row["along_m"], row["cross_m"], row["depth_m"] = a[ia], c[ic], z[iz]
    row["extent_along_m"] = row["extent_cross_m"] = row["extent_depth_m"] = 0.04
    return img, row


ASPECT_CFG = dataclasses.replace(CFG, aspect_window_m=0.6)


@pytest.mark.parametrize("centre,spread", [(5.0, 2.0), (-8.0, 10.0), (0.0, 4.0)])
def test_aspect_over_the_aperture_against_the_angular_spectrum_put_in(centre, spread):
    """The look angles' mean and rms spread equal the Gaussian's put in, the spread
    widened by the Hann window's own (variance 4 pi^2 / (3 T^2) in k_x, T the window's
    length: 1.46 deg at 0.62 m), within 3 standard errors (and 0.3 deg)."""
    img, row = aperture_image(np.random.default_rng(int(10 * spread)), centre, spread)
    level = 20 * np.log10(np.abs(img) / 1e-3)
    f = contact_features(level.astype(np.float32), axes(img.shape), row, ASPECT_CFG,
                         img, K_W).columns
    t_win = 31 * VOXEL
    sig_win = math.degrees(2 * np.pi / (math.sqrt(3) * t_win) / (2 * K_W))
    # the spread of theta for a small spread of sin(theta) about sin(centre)
    sig = math.degrees(math.sin(math.radians(spread)) / math.cos(math.radians(centre)))
    want = math.hypot(sig, sig_win)
    err = f["aspect_width_err_deg"][0]
    assert np.isfinite(err) and err > 0
    assert abs(f["aspect_width_deg"][0] - want) < 3 * err + 0.3, \
        (f["aspect_width_deg"][0], want, err)
    assert abs(f["aspect_centre_deg"][0] - centre) < 0.5 + 0.1 * spread


def test_no_aspect_without_a_complex_image():
    level, row = scene(np.random.default_rng(0))
    cfg = dataclasses.replace(CFG, point_aspect_deg=(11.0, 5.0))
    c = contact_features(level, axes(level.shape), row, cfg).columns
    assert c["feature_flags"][0] & NO_ASPECT and np.isnan(c["aspect_width_deg"][0])
    assert np.isnan(c["aspect_point_fraction"][0])


def test_point_fraction_is_the_broader_direction_whatever_the_heading():
    """A cylinder's widths swap with its heading (narrow along-track when its axis lies
    along the track, narrow across when across); the fraction is the same either way, a
    sphere's is 1, a flat face's the larger of its two small ratios."""
    ref = (11.0, 5.0)
    along_axis = point_fraction((2.75, 5.0), (0.1, 0.2), ref)     # axis along-track
    across_axis = point_fraction((11.0, 1.25), (0.3, 0.1), ref)   # axis across-track
    assert along_axis == pytest.approx((1.0, 0.04)) and across_axis == pytest.approx((1.0, 0.3 / 11))
    assert point_fraction((11.0, 5.0), (0.1, 0.1), ref)[0] == pytest.approx(1.0)
    assert point_fraction((3.3, 2.5), (0.1, 0.1), ref) == pytest.approx((0.5, 0.02))
    assert all(np.isnan(point_fraction((3.0, float("nan")), (0.1, 0.1), ref)))
    assert all(np.isnan(point_fraction((3.0, 2.0), (0.1, 0.1), None)))


def test_point_fraction_of_a_synthetic_response_from_the_image():
    """From the image, through contact_features: a response spread 6 deg along-track
    over weak speckle, referenced to a point's 12 deg along and 5 deg across (the
    shipped references' scale): the fraction is the larger of the two measured widths
    over their references, with that ratio's error."""
    img, row = aperture_image(np.random.default_rng(3), 0.0, 6.0, shape=(100, 40, 40),
                              at=(1.0, 0.4, 0.4))
    level = 20 * np.log10(np.abs(img) / 1e-3)
    cfg = dataclasses.replace(ASPECT_CFG, point_aspect_deg=(12.0, 5.0))
    f = contact_features(level.astype(np.float32), axes(img.shape), row, cfg, img,
                         K_W).columns
    along = f["aspect_width_deg"][0] / 12.0
    across = f["aspect_cross_width_deg"][0] / 5.0
    assert np.isfinite(along) and np.isfinite(across) and abs(along - across) > 0.05
    broader, err = ((along, f["aspect_width_err_deg"][0] / 12.0) if along > across
                    else (across, f["aspect_cross_width_err_deg"][0] / 5.0))
    assert f["aspect_point_fraction"][0] == pytest.approx(broader, rel=1e-5)
    assert f["aspect_point_fraction_err"][0] == pytest.approx(err, rel=1e-5)
    assert 0.3 < along < 0.8, (along, across)    # the 6 deg put in, widened by the window
