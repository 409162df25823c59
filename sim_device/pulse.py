"""The transmit pulse as the digitiser records it, and the last step of the synthesis:
baseband impulse buffers to passband pressure.

The synthesis kernels (:mod:`sim_device.synthesis`) add each echo's complex baseband
impulse A exp(-j 2 pi f_c tau) (the convention of :mod:`svss_daq.conventions`) at its
fractional delay into a baseband buffer; :meth:`PulseSynthesiser.to_passband` convolves
the buffer once with the sampled baseband pulse s_bb(t) = s_a(t) exp(-j 2 pi f_c t) and
remodulates. The baseband pulse occupies about +-B/2 around 0 Hz, far below the sample
rate, where cubic Lagrange interpolation is accurate to ~-90 dB; only the pulse's
out-of-band edges (the taper's pedestal) are band-limited, as a real digitiser's
anti-alias filter would (:func:`digitised_pulse`).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from svss_daq.conventions import baseband_carrier, remodulation
from svss_daq.waveform import Waveform

from .synthesis_args import Window, window

#: samples of margin on each side of the window kept in the baseband buffer
_MARGIN = 4


#: the simulated digitiser's anti-alias filter: raised-cosine low-pass from
#: AA_PASS * fs to AA_STOP * fs (an assumption; the hardware file gives none)
AA_PASS = 0.36
AA_STOP = 0.48
#: samples kept before the pulse's start and after its end for the filter's tails
AA_PAD = 24


def digitised_pulse(waveform: Waveform, fs: float, oversample: int = 16
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """The transmit pulse as the digitiser sees it: band-limited by its anti-alias
    filter, on the sample grid t_j = (j - AA_PAD) / fs.

    Returns (real pulse, analytic pulse, AA_PAD). Computed on a grid ``oversample``
    times finer, filtered in the frequency domain and sampled; the analytic pulse is
    the exact Hilbert pair (positive frequencies only).
    """
    n_pulse = int(math.ceil(waveform.duration_s * fs)) + 1
    n = n_pulse + 2 * AA_PAD
    n_fine = sfft.next_fast_len(n * oversample * 2)
    fs_fine = fs * oversample
    t = np.arange(n_fine) / fs_fine - AA_PAD / fs
    s = waveform.real(t)
    spec = sfft.fft(s)
    f = np.abs(sfft.fftfreq(n_fine, 1.0 / fs_fine))
    lo, hi = AA_PASS * fs, AA_STOP * fs
    h = np.where(f <= lo, 1.0, np.where(f >= hi, 0.0,
                                        0.5 * (1.0 + np.cos(np.pi * (f - lo) / (hi - lo)))))
    freq = sfft.fftfreq(n_fine, 1.0 / fs_fine)
    real = sfft.ifft(spec * h).real[::oversample][:n]
    analytic = sfft.ifft(spec * h * np.where(freq > 0, 2.0, np.where(freq == 0, 1.0, 0.0)))
    return real.copy(), analytic[::oversample][:n].copy(), AA_PAD


class PulseSynthesiser:
    """Turns baseband impulse buffers into digitiser-rate passband pressure.

    The digitiser's sample n holds the pressure at t_n = t_first + n / fs; the pulse
    kernel is :func:`digitised_pulse` in baseband, s_bb(t_j) = s_a(t_j) exp(-j 2 pi f_c t_j)
    on t_j = (j - pad) / fs.
    """

    def __init__(self, waveform: Waveform, fs: float, n_samples: int, t_first: float):
        self.fs = float(fs)
        self.fc = waveform.center_hz
        self.n = int(n_samples)
        self.t_first = float(t_first)
        real, analytic, pad = digitised_pulse(waveform, fs)
        n_pulse = real.size
        tp = (np.arange(n_pulse) - pad) / fs
        self.pulse_real = real
        self.pad = pad
        self.pulse_bb = analytic * baseband_carrier(tp, self.fc)
        self.n_pulse = n_pulse
        # buffer sample j <-> t_buf0 + j / fs; conv index m <-> t_buf0 + (m - pad) / fs
        self.offset = n_pulse + _MARGIN
        self.n_buf = self.n + n_pulse + 2 * _MARGIN
        self.t_buf0 = self.t_first - (self.offset - pad) / fs
        # echoes whose kernel support can reach the window
        self.t_lo = self.t_first - (n_pulse - pad + 2) / fs
        self.t_hi = self.t_first + (self.n + pad + 1) / fs
        self.n_fft = sfft.next_fast_len(self.n_buf + n_pulse - 1)
        self.pulse_fft = sfft.fft(self.pulse_bb, self.n_fft)
        t = self.t_first + np.arange(self.n) / fs
        self.remod = remodulation(t, self.fc)

    def window(self) -> Window:
        """The synthesis kernels' :class:`~sim_device.synthesis_args.Window` of this
        buffer: the carrier's echo phase, the delays kept, the buffer's time axis."""
        return window(self.fc, self.t_lo, self.t_hi, self.t_buf0, self.fs)

    def buffer(self, n_channels: int) -> np.ndarray:
        return np.zeros((n_channels, self.n_buf), dtype=np.complex128)

    def to_passband(self, buf: np.ndarray) -> np.ndarray:
        """Convolve with the baseband pulse, remodulate, take the real part (uPa)."""
        y = sfft.ifft(sfft.fft(buf, self.n_fft, axis=-1) * self.pulse_fft, axis=-1)
        return (y[:, self.offset:self.offset + self.n] * self.remod).real
