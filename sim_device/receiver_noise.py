"""Noise of the simulated receivers: ambient sea noise by sea state and electronic noise.

Ambient noise follows the Knudsen spectrum (as tabulated by Urick; PHYSICS.md section 7)
inside the receivers' band [f_low, f_high] and is independent from channel to channel
(omnidirectional noise at 9.1 cm spacing has a spatial coherence sin(kd)/kd of only
-0.08 at 27.5 kHz). It is drawn as white Gaussian noise shaped in the frequency domain:
a real series with one-sided spectral density N(f) has rfft coefficients of variance
N(f) fs n / 2. Electronic noise is white, in ADC counts rms.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from svss_daq.scaling import counts_per_upa

from .acoustics.ambient_noise import ambient_noise_spectrum_level, band_noise_power


def knudsen_noise(rng: np.random.Generator, n_channels: int, n_samples: int, fs: float,
                  sea_state: float, band: tuple[float, float]) -> np.ndarray:
    """Ambient noise (uPa), (n_channels, n_samples): Knudsen density inside ``band``
    (Hz), none outside."""
    n_fft = sfft.next_fast_len(n_samples)
    f = np.arange(n_fft // 2 + 1) * fs / n_fft
    inside = (f >= band[0]) & (f <= band[1]) & (f > 0)
    density = np.zeros(f.size)
    density[inside] = 10.0 ** (ambient_noise_spectrum_level(f[inside], sea_state) / 10.0)
    scale = np.sqrt(density * fs * n_fft / 2.0)
    spec = (rng.standard_normal((n_channels, f.size))
            + 1j * rng.standard_normal((n_channels, f.size))) * (scale / np.sqrt(2.0))
    spec[:, 0] = 0.0
    if n_fft % 2 == 0:
        spec[:, -1] = spec[:, -1].real * np.sqrt(2.0)
    return sfft.irfft(spec, n_fft, axis=-1)[:, :n_samples]


def band_power(sea_state: float | None, band: tuple[float, float] | None,
               f_low: float, f_high: float, electronic_upa_rms: float,
               fs: float) -> float:
    """Noise power (uPa^2) in [f_low, f_high]: Knudsen (where the receivers' band
    overlaps) plus the white electronic noise's share of it."""
    p = 0.0
    if sea_state is not None and band is not None:
        lo, hi = max(f_low, band[0]), min(f_high, band[1])
        if hi > lo:
            p += float(band_noise_power(lo, hi, sea_state))
    p += electronic_upa_rms ** 2 * (f_high - f_low) / (fs / 2.0)
    return p


class ReceiverNoise:
    """The noise of a scene's receivers on the digitiser's grid: ambient (Knudsen) and
    electronic, drawn per ping from the scene seed and the ping index."""

    def __init__(self, noise, waveform, digitiser):
        self.cfg = noise
        self.fs = digitiser.sample_rate_hz
        self.n_samples = digitiser.window_samples
        self.counts_per_upa = counts_per_upa(digitiser)
        self.electronic_upa = noise.electronic_rms_counts / self.counts_per_upa
        f_lo = min(waveform.f_start_hz, waveform.f_stop_hz)
        f_hi = max(waveform.f_start_hz, waveform.f_stop_hz)
        #: noise power in the pulse's band, uPa^2
        self.power = band_power(noise.sea_state, noise.ambient_band_hz, f_lo, f_hi,
                                self.electronic_upa, self.fs)

    def series(self, seed: int, i: int, n_channels: int) -> np.ndarray:
        """Noise (uPa) of ping ``i``, (n_channels, n_samples)."""
        shape = (n_channels, self.n_samples)
        out = np.zeros(shape)
        nz = self.cfg
        if nz.sea_state is not None:
            rng = np.random.default_rng([seed, i, 1])
            out += knudsen_noise(rng, shape[0], shape[1], self.fs, nz.sea_state,
                                 nz.ambient_band_hz)
        if nz.electronic_rms_counts > 0:
            rng = np.random.default_rng([seed, i])
            out += rng.normal(0.0, self.electronic_upa, shape)
        return out
