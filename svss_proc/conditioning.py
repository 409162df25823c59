"""Signal conditioning: matched filtering, basebanding and decimation in one FFT pass.

Optional band-limited upsampling (zero-padding the kept band) refines the output grid
for interpolation. Input: real ADC codes (channels x samples) whose sample n holds the acoustic pressure at
t_n = window_start + n / fs - group_delay after transmit. Output: complex baseband
matched-filter output in uPa (the peak magnitude of an echo A s(t - tau) is A), on the
time axis t_m = t_first + m * D / (U fs) (D decimation, U upsampling), following :mod:`svss_daq.conventions`:
y(t) = analytic correlation(t) * exp(-j 2 pi f_c t).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from svss_daq.config import Digitiser
from svss_daq.conventions import baseband_carrier
from svss_daq.scaling import counts_per_upa
from svss_daq.waveform import Waveform


@dataclass(frozen=True)
class Conditioned:
    """Complex baseband matched-filter output of one ping.

    ``data``: (channels, n) complex64 in uPa; sample m is the echo delay
    ``t0_s + m * dt_s`` after transmit.
    """
    data: np.ndarray
    t0_s: float
    dt_s: float
    center_hz: float


class Conditioner:
    """Matched filter + baseband + decimation for one hardware configuration."""

    def __init__(self, dig: Digitiser, waveform: Waveform, decimation: int, upsample: int = 1):
        self.fs = dig.sample_rate_hz
        self.n_in = dig.window_samples
        self.decimation = d = int(decimation)
        self.upsample = up = int(upsample)
        self.group_delay_s = dig.group_delay_s
        self.fc = waveform.center_hz
        replica = waveform.replica(self.fs)
        n = sfft.next_fast_len(self.n_in + replica.size)
        n = d * sfft.next_fast_len(-(-n // d))          # a multiple of the decimation
        self.n_fft = n
        m = n // d                                      # band kept around the carrier
        self.m_out = m * up                               # inverse FFT length
        self.n_out = -(-self.n_in // d) * up
        energy = float(replica @ replica)
        # matched filter, analytic (x2 on positive frequencies), scaled to uPa
        spec = np.conj(sfft.rfft(replica, n)) * (2.0 / energy / counts_per_upa(dig))
        k0 = int(round(self.fc * n / self.fs))
        self.f_shift = k0 * self.fs / n
        k = k0 + np.arange(-(m // 2), m - m // 2)
        keep = (k > 0) & (k < n // 2 + 1)
        self.bins = k[keep]                               # rfft bins kept
        self.slots = np.mod(k[keep] - k0, self.m_out)     # their place in the short ifft
        self.filter = (spec[self.bins] * (self.m_out / n)).astype(np.complex128)

    def __call__(self, codes: np.ndarray, window_start_s: float) -> Conditioned:
        x = sfft.rfft(np.asarray(codes, dtype=np.float64), self.n_fft, axis=-1)
        z = np.zeros((x.shape[0], self.m_out), dtype=np.complex128)
        z[:, self.slots] = x[:, self.bins] * self.filter
        y = sfft.ifft(z, axis=-1)[:, : self.n_out]
        t_first = window_start_s - self.group_delay_s
        dt = self.decimation / (self.fs * self.upsample)
        tm = t_first + np.arange(self.n_out) * dt
        # z holds a(t) exp(-j 2 pi f_shift (t - t_first)); bring it to the convention
        fix = baseband_carrier(tm, self.fc) * np.exp(2j * np.pi * self.f_shift * (tm - t_first))
        return Conditioned((y * fix).astype(np.complex64), t_first, dt, self.fc)
