"""Resonance lines from the pings (svss_proc/products/contact_spectra.py): each channel
focused on a buried contact at its refracted two-way time, the pings' series into the
matrix pencil. Synthetic pings on the real 80-channel array, 300 m along the track,
the contact 30 cm deep in sand: the echoes are placed at the times of
tests/references.refracted_time (an independent Fermat minimisation), the ringing's
frequency and width put in are read back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from svss_daq.config import HardwareConfig, config_path, load
from svss_daq.conventions import baseband_carrier
from svss_daq.geometry import array_geometry
from svss_proc.imaging.imager import receive_apodisation
from svss_proc.products.contact_spectra import (EchoCollector, Focus, contact_lines,
                                                focused_echo, two_way_times)
from tests.references import layered_time, refracted_time

CW, CS = 1480.0, 1650.0                     # water; medium sand
FC, BAND = 27500.0, (20000.0, 35000.0)
DT = 1 / 62500.0                            # the shipped conditioning's rate
T0, NT = 1.5e-3, 1200                       # the record: 1.5 to 20.7 ms after transmit
HEIGHT = 2.0                                # array above the interface, m
POINT = np.array([301.3, 0.4, 0.30])        # along, cross, depth below the interface


@pytest.fixture(scope="module")
def geo():
    return array_geometry(load(HardwareConfig, config_path("hardware.toml")))


def placed(geo, along):
    """The array level, its receivers' centre at ``along`` (tile frame), the first
    projector transmitting."""
    off = np.array([along, 0.0, -HEIGHT]) - geo.receivers.mean(axis=0)
    return geo.projectors[0] + off, geo.receivers + off, np.array([0.0, 0.0, 1.0])


def focus(geo, start=2e-4, length=2.5e-3):
    return Focus(CW, CS, FC, math.cos(geo.projector_half_angle),
                 math.cos(geo.receiver_half_angle),
                 receive_apodisation(geo.receivers, "hann"), start, length)


def ringing_ping(rng, tx, rx, f_hz, width_hz, snr=30.0, amp=None):
    """Each channel's complex baseband: a specular pulse at the reference two-way time
    and a line at ``f_hz`` decaying at pi * ``width_hz`` from it, a random amplitude and
    phase for the ping, complex noise ``snr`` times under the line's start."""
    t = T0 + DT * np.arange(NT)
    if amp is None:
        amp = rng.uniform(0.5, 1.5) * np.exp(2j * np.pi * rng.random())
    out = np.empty((rx.shape[0], NT), dtype=np.complex128)
    t_tx = refracted_time(tx, POINT, CW, CS)
    for ch, r in enumerate(rx):
        tau = t_tx + refracted_time(r, POINT, CW, CS)
        s = t - tau
        late = np.where(s >= 0, np.exp((2j * np.pi * f_hz - np.pi * width_hz) * s), 0.0)
        spec = 5 * np.exp(-0.5 * (s / 3e-5) ** 2) * np.exp(2j * np.pi * FC * s)
        out[ch] = amp * (late + spec) * baseband_carrier(t, FC)
    noise = (rng.standard_normal(out.shape) + 1j * rng.standard_normal(out.shape))
    return out + noise * abs(amp) / (snr * math.sqrt(2))


def test_two_way_times_are_the_references_fermat_times(geo):
    tx, rx, _ = placed(geo, 300.0)
    got = two_way_times(tx, rx, POINT, CW, CS)
    t_tx = refracted_time(tx, POINT, CW, CS)
    want = np.array([t_tx + refracted_time(r, POINT, CW, CS) for r in rx])
    assert np.max(np.abs(got - want)) < 1e-10


def test_layered_two_way_times_are_fermat_times_under_a_lower_bed(geo):
    """Silt 0.2 m over sand, the bed 7 cm below the frame's level at the contact: the
    times through the layers (the imaging's ray) against an independent least-time
    minimisation over both crossing points, every eighth receiver."""
    tx, rx, _ = placed(geo, 300.0)
    rx = rx[::8]
    tops, speeds, surface = np.array([0.0, 0.2]), np.array([1476.0, 1767.0]), 0.07
    got = two_way_times(tx, rx, POINT, CW, CS, surface, tops, speeds)

    def ref(e):
        rho = math.hypot(POINT[0] - e[0], POINT[1] - e[1])
        return layered_time(rho, [surface - e[2], 0.2, POINT[2] - 0.2],
                            [CW, 1476.0, 1767.0])
    want = np.array([ref(tx) + ref(r) for r in rx])
    assert np.max(np.abs(got - want)) < 1e-10               # measured 1e-18


def test_the_focused_series_is_the_response_put_in(geo):
    """Focused on the contact the channels add in phase: the series is the line put in
    (its level at the window's start, its decay and its phase advance per sample);
    focused 25 cm beside it (across-track) they do not."""
    rng = np.random.default_rng(1)
    tx, rx, bore = placed(geo, 300.6)
    f_r, w = 26000.0, 300.0
    b = ringing_ping(rng, tx, rx, f_r, w, snr=1e6)
    fo = focus(geo)
    e = focused_echo(b, T0, DT, tx, rx, bore, POINT, fo)
    n = np.arange(e.size)
    amp = abs(e[0]) / math.exp(-math.pi * w * fo.start_s)
    model = np.exp((2j * np.pi * (f_r - FC) - math.pi * w) * DT * n)
    ratio = e / (e[0] * model)               # 1 throughout, but for interpolation error
    assert np.max(np.abs(ratio - 1)) < 0.03, np.max(np.abs(ratio - 1))
    assert 0.5 < amp < 1.5                   # the ping's amplitude, not 80 times it
    beside = focused_echo(b, T0, DT, tx, rx, bore, POINT + [0.0, -0.25, 0.0], fo)
    assert np.mean(np.abs(beside)) < 0.2 * np.mean(np.abs(e))


def test_a_bed_lower_under_the_contact_is_focused_as_the_imaging_takes_it(geo):
    """The interface under the contact lies 7 cm below the frame's level (a sloping or
    rough bed): the echoes are at the reference times with every element 7 cm higher
    over it. Given the bed's depth, the collector's series is the response put in from
    its true start (level and phase, within 3 %); taken level, the series starts some
    40 microseconds off, its phase wrong by a third of a radian or more."""
    rng = np.random.default_rng(11)
    tx, rx, bore = placed(geo, 300.8)
    drop = np.array([0.0, 0.0, 0.07])
    f_r, w, amp = 26000.0, 300.0, 0.8 * np.exp(0.3j)
    b = ringing_ping(rng, tx - drop, rx - drop, f_r, w, snr=1e6, amp=amp)
    fo = focus(geo)
    on = EchoCollector(POINT[None, :], fo, surface=lambda a, c: 0.07)
    off = EchoCollector(POINT[None, :], fo)
    for col in (on, off):
        col.add(b, T0, DT, tx, rx, bore)
    t = fo.start_s + DT * np.arange(on.echoes[0][0].size)
    want = amp * np.exp((2j * np.pi * (f_r - FC) - math.pi * w) * t)
    assert np.max(np.abs(on.echoes[0][0] / want - 1)) < 0.03
    assert np.min(np.abs(off.echoes[0][0] / want - 1)) > 0.3


def test_outside_the_projector_cone_or_the_record_nothing(geo):
    fo = focus(geo)
    b = np.zeros((geo.receivers.shape[0], NT), dtype=np.complex128)
    tx, rx, bore = placed(geo, 300.0 - 3.0)                   # 3.3 m behind: out of the cone
    assert focused_echo(b, T0, DT, tx, rx, bore, POINT, fo) is None
    tx, rx, bore = placed(geo, 301.0)
    short = b[:, :200]                                         # ends before the echo
    assert focused_echo(short, T0, DT, tx, rx, bore, POINT, fo) is None


@pytest.mark.parametrize("f_r,w", [(24000.0, 150.0), (31500.0, 600.0)])
def test_lines_read_back_from_the_pings_over_the_aperture(geo, f_r, w):
    """Pings every 0.1 m over the aperture, the collector keeping those whose cone
    holds the contact: the strongest line in the band is the one put in, within three
    jackknife errors (and 1 % of the frequency, 20 % of the width)."""
    rng = np.random.default_rng(int(f_r))
    col = EchoCollector(POINT[None, :], focus(geo))
    for along in np.arange(299.0, 303.6, 0.1):
        tx, rx, bore = placed(geo, along)
        which = col.wants(tx, bore)
        if which.size:
            col.add(ringing_ping(rng, tx, rx, f_r, w), T0, DT, tx, rx, bore, which)
    n = len(col.echoes[0])
    # the first projector's cone (25 deg half angle, 0.9 m across from the contact):
    # about 1.2 m of track of the 4.6 m fed
    assert 6 <= n <= 15, n
    got = contact_lines(col.echoes[0], DT, FC, BAND, references=col.references[0],
                        min_over_background_db=3.0)
    assert got["resonance_pings"] == n
    # its references 0.6 m along-track either side hold only the noise and the line
    # defocused: the late response stands well over them
    assert len(col.references[0]) >= 3 and got["late_over_background_db"] > 10.0, got
    fe, we = got["resonance_err_hz"], got["resonance_width_err_hz"]
    assert np.isfinite(fe) and np.isfinite(we)
    assert abs(got["resonance_hz"] - f_r) < 3 * fe + 0.01 * f_r, got
    assert abs(got["resonance_width_hz"] - w) < 3 * we + 0.2 * w, got


def test_the_background_alone_gives_no_line(geo):
    """Pings of noise alone: the pencil still finds poles in a band-limited series, but
    the point stands no higher than its references (0 dB, within the scatter of 2 x 10
    pings' power) and no line is reported."""
    rng = np.random.default_rng(7)
    col = EchoCollector(POINT[None, :], focus(geo))
    for along in np.arange(299.0, 303.6, 0.1):
        tx, rx, bore = placed(geo, along)
        which = col.wants(tx, bore)
        if which.size:
            col.add(rng.standard_normal((80, NT)) + 1j * rng.standard_normal((80, NT)),
                    T0, DT, tx, rx, bore, which)
    got = contact_lines(col.echoes[0], DT, FC, BAND, references=col.references[0],
                        min_over_background_db=3.0)
    assert abs(got["late_over_background_db"]) < 1.5, got
    assert math.isnan(got["resonance_hz"]) and math.isnan(got["resonance_width_hz"])
    assert not math.isnan(contact_lines(col.echoes[0], DT, FC, BAND)["resonance_hz"])


def test_noise_alone_or_too_few_pings_give_no_line(geo):
    rng = np.random.default_rng(5)
    tx, rx, bore = placed(geo, 301.0)
    fo = focus(geo)
    noise = [focused_echo(rng.standard_normal((80, NT)) + 1j * rng.standard_normal((80, NT)),
                          T0, DT, tx, rx, bore, POINT, fo) for _ in range(2)]
    few = contact_lines(noise, DT, FC, BAND, min_pings=3)
    assert few["resonance_pings"] == 2 and math.isnan(few["resonance_hz"])
