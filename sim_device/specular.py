"""Coherent (specular) returns of the seabed: the interface and deeper layer boundaries.

A few paths per channel, so each is synthesised exactly in the frequency domain, with
the frequency dependence of its coherent loss (Eckart 1953: R_coh = R exp(-2 k^2 h^2
sin^2 theta), PHYSICS.md section 3) and of the sediment attenuation (linear in f):

    P(f) = S(f) conj(A) exp(-beta f^2 - gamma f - j 2 pi f tau)

with S the spectrum of the transmit pulse, A the frequency-independent factor (source
level, beam gains, Rayleigh coefficients, spreading, water absorption; complex in the
physics convention exp(-i omega t), hence conjugated for numpy's FFT), beta the Eckart
exponent and gamma the sediment attenuation per Hz along the path.

* Interface: reflection sequences from :func:`sim_device.multipath.coherent_paths`;
  spherical spreading 1/L along the unfolded path.
* Boundary k >= 2 (between sediment layers k-1 and k): the ray crosses the water
  (projector and receiver legs, with their image heights for multipath) and every
  layer above twice; it takes T = (1 + R)(1 - R) at each boundary crossed, R_coh of
  boundary k, the layered-media spreading of :mod:`sim_device.layered_rays` and the
  attenuation of each layer. Reverberation between boundaries is not modelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from .acoustics import reflection_coefficient
from .beams import BeamTable
from .environment import Media
from .multipath import CoherentPath, image_depth, leg_image
from .layered_rays import ray_amplitude_terms, ray_tan, reflection


@dataclass
class PathSet:
    """Coherent paths of one ping: arrays (channels, paths)."""
    tau: np.ndarray         # s
    amp: np.ndarray         # complex, frequency-independent factor (without source level),
    #                         physics convention exp(-i omega t) as the Rayleigh coefficient
    beta: np.ndarray        # s^2: exp(-beta f^2)
    gamma: np.ndarray       # s:   exp(-gamma f)
    label: list[str]        # one per path
    order: np.ndarray       # reflections added to the path's direct form, per path

    def level_at(self, f: float) -> np.ndarray:
        """|factor| at frequency f (channels, paths)."""
        return np.abs(self.amp) * np.exp(-self.beta * f * f - self.gamma * f)


def _direction(dx, dy, rho, horiz, vert):
    """Unit direction with horizontal part ``horiz`` along (dx, dy) and vertical ``vert``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(rho > 0, dx / np.where(rho > 0, rho, 1.0), 0.0)
        uy = np.where(rho > 0, dy / np.where(rho > 0, rho, 1.0), 0.0)
    return np.stack([ux * horiz, uy * horiz, vert], axis=-1)


def interface_paths(tx: np.ndarray, rx: np.ndarray, bore: np.ndarray, media: Media,
                    water_depth: float | None, r_surface: float,
                    sequences: list[CoherentPath], tx_beam: BeamTable, rx_beam: BeamTable,
                    rho_ratio: float, nu: float, delta: float) -> PathSet:
    """Specular paths of the water-sediment interface (tile frame; tx (3,), rx (n, 3))."""
    c0 = media.c[0]
    k2 = 2.0 * (2.0 * math.pi / c0) ** 2 * media.rough[1] ** 2
    taus, amps, betas, labels = [], [], [], []
    dx = rx[:, 0] - tx[0]
    dy = rx[:, 1] - tx[1]
    rho = np.hypot(dx, dy)
    for seq in sequences:
        z_img = seq.image_depth(tx[2], water_depth if water_depth is not None else 0.0)
        dz = rx[:, 2] - z_img
        length = np.sqrt(rho * rho + dz * dz)
        sin_g = np.abs(dz) / length
        cos_g = rho / length
        g_tx = tx_beam(_direction(dx, dy, rho, cos_g, seq.departure * sin_g) @ bore)
        g_rx = rx_beam(_direction(-dx, -dy, rho, cos_g, seq.arrival * sin_g) @ bore)
        r = reflection_coefficient(np.arcsin(np.clip(sin_g, 0.0, 1.0)), rho_ratio, nu, delta)
        amp = (g_tx * g_rx * r_surface ** seq.n_surface * r ** seq.n_bottom / length
               * np.exp(-media.alpha[0] * length))
        taus.append(length / c0)
        amps.append(amp)
        betas.append(seq.n_bottom * k2 * sin_g ** 2)
        labels.append(f"interface {seq.sequence}")
    n = rx.shape[0]
    return PathSet(np.stack(taus, 1) if taus else np.zeros((n, 0)),
                   np.stack(amps, 1) if amps else np.zeros((n, 0), complex),
                   np.stack(betas, 1) if betas else np.zeros((n, 0)),
                   np.zeros((n, len(taus))), labels,
                   np.array([s.order for s in sequences], dtype=int))


def boundary_paths(tx: np.ndarray, rx: np.ndarray, bore: np.ndarray, media: Media,
                   water_depth: float | None, r_surface: float,
                   pairs: list[tuple[int, int]], tx_beam: BeamTable,
                   rx_beam: BeamTable) -> PathSet:
    """Specular paths of the deeper layer boundaries (k = 2 .. media.n - 1), each with the
    projector/receiver leg images of ``pairs`` (m_tx, m_rx)."""
    c = media.c
    n_ch = rx.shape[0]
    taus, amps, betas, gammas, labels, orders = [], [], [], [], [], []
    dx = rx[:, 0] - tx[0]
    dy = rx[:, 1] - tx[1]
    rho = np.hypot(dx, dy)
    depth = water_depth if water_depth is not None else 0.0
    k2_top = 2.0 * (2.0 * math.pi / c[0]) ** 2 * media.rough[1] ** 2
    for kb in range(2, media.n):
        thick = media.z_top[1:kb + 1]
        for (mt, mr) in pairs:
            lt, lr = leg_image(mt), leg_image(mr)
            h_t = -float(image_depth(mt, tx[2], depth))
            h_r = -image_depth(mr, rx[:, 2], depth)
            tau = np.empty(n_ch)
            amp = np.empty(n_ch, dtype=complex)
            beta = np.empty(n_ch)
            gamma = np.empty(n_ch)
            h = np.empty(kb)
            for ch in range(n_ch):
                h[0] = h_t + h_r[ch]
                h[1:] = 2.0 * np.diff(thick)
                t = ray_tan(rho[ch], h, c, kb)
                p, tau[ch], spread, cos0, _ = ray_amplitude_terms(
                    t, rho[ch], h, c, np.zeros(kb), kb, 0)
                sin0 = p * c[0]
                trans = 1.0 + 0j
                for j in range(1, kb):
                    rj = reflection(c[j - 1] * p, media.rho[j] / media.rho[j - 1],
                                    c[j] / c[j - 1], media.delta[j])
                    trans *= (1.0 + rj) * (1.0 - rj)
                rk = reflection(c[kb - 1] * p, media.rho[kb] / media.rho[kb - 1],
                                c[kb] / c[kb - 1], media.delta[kb])
                cos_k = math.sqrt(max(0.0, 1.0 - (c[kb - 1] * p) ** 2))   # sin(grazing)
                r_top = reflection(sin0, media.rho[1] / media.rho[0], c[1] / c[0],
                                   media.delta[1])
                n_b = lt.n_bottom + lr.n_bottom
                g_tx = tx_beam(np.array([dx[ch] / rho[ch] * sin0 if rho[ch] > 0 else 0.0,
                                         dy[ch] / rho[ch] * sin0 if rho[ch] > 0 else 0.0,
                                         lt.direction * cos0]) @ bore)
                g_rx = rx_beam(np.array([-dx[ch] / rho[ch] * sin0 if rho[ch] > 0 else 0.0,
                                         -dy[ch] / rho[ch] * sin0 if rho[ch] > 0 else 0.0,
                                         lr.direction * cos0]) @ bore)
                water_len = h[0] / cos0
                amp[ch] = (float(g_tx) * float(g_rx) * spread * trans * rk
                           * r_surface ** (lt.n_surface + lr.n_surface) * r_top ** n_b
                           * math.exp(-media.alpha[0] * water_len))
                beta[ch] = (2.0 * (2.0 * math.pi / c[kb - 1]) ** 2 * media.rough[kb] ** 2
                            * cos_k ** 2 + n_b * k2_top * cos0 ** 2)
                g = 0.0
                for j in range(1, kb):          # path length in layer j: h_j / cos(phi_j)
                    cos_j = math.sqrt(max(1e-300, 1.0 - (c[j] * p) ** 2))
                    g += 2.0 * math.pi * media.delta[j] / c[j] * h[j] / cos_j
                gamma[ch] = g
            taus.append(tau)
            amps.append(amp)
            betas.append(beta)
            gammas.append(gamma)
            labels.append(f"boundary {kb} legs ({mt},{mr})")
            orders.append(mt + mr)
    if not taus:
        z = np.zeros((n_ch, 0))
        return PathSet(z, z.astype(complex), z, z, [], np.zeros(0, dtype=int))
    return PathSet(np.stack(taus, 1), np.stack(amps, 1), np.stack(betas, 1),
                   np.stack(gammas, 1), labels, np.array(orders, dtype=int))


def merge(a: PathSet, b: PathSet) -> PathSet:
    """Both path sets as one."""
    return PathSet(np.concatenate([a.tau, b.tau], 1), np.concatenate([a.amp, b.amp], 1),
                   np.concatenate([a.beta, b.beta], 1), np.concatenate([a.gamma, b.gamma], 1),
                   a.label + b.label, np.concatenate([a.order, b.order]))


def select(paths: PathSet, keep: np.ndarray) -> PathSet:
    """The paths where ``keep`` (per path) is true."""
    return PathSet(paths.tau[:, keep], paths.amp[:, keep], paths.beta[:, keep],
                   paths.gamma[:, keep], [l for l, k in zip(paths.label, keep) if k],
                   paths.order[keep])


class SpectralSynthesiser:
    """Exact band-limited synthesis of a few delayed, filtered pulses per channel on the
    digitiser's grid t_n = t_first + n / fs."""

    def __init__(self, pulse_real: np.ndarray, pad: int, fs: float, n_samples: int,
                 t_first: float, tail_samples: int = 0):
        """``pulse_real``: the pulse on t_j = (j - pad) / fs (see
        :func:`sim_device.pulse.digitised_pulse`); ``tail_samples``: extra length of the
        FFT period so that responses longer than a pulse (ringing targets) end before
        they could wrap into the window (:mod:`sim_device.targets.echo`)."""
        self.fs = float(fs)
        self.n = int(n_samples)
        self.n_pulse = pulse_real.size
        self.pad = int(pad)
        self.lead = self.n_pulse + 4
        self.t0 = float(t_first) - self.lead / self.fs
        self.n_fft = sfft.next_fast_len(self.n + 2 * self.lead + int(tail_samples))
        self.spectrum = sfft.rfft(pulse_real, self.n_fft)
        self.f = np.arange(self.spectrum.size) * self.fs / self.n_fft
        self.t_lo = float(t_first) - (self.n_pulse - self.pad + 1) / self.fs
        self.t_hi = float(t_first) + (self.n + self.pad + 1) / self.fs

    def band(self, rel: float = 1e-6) -> np.ndarray:
        """Indices of the positive-frequency bins where the pulse spectrum exceeds
        ``rel`` times its peak (outside them a path's spectrum does not matter)."""
        mag = np.abs(self.spectrum)
        return np.flatnonzero((mag > rel * mag.max()) & (self.f > 0))

    def responses(self, n_channels: int, channel: np.ndarray, tau: np.ndarray,
                  resp: np.ndarray, bins: np.ndarray, scale: float) -> np.ndarray:
        """Pressure (n_channels, samples) of M echoes: echo m reaches channel
        ``channel[m]`` with delay ``tau[m]`` (s) and the frequency response ``resp[m]``
        (engineering convention e^{+j omega t}) on the bins ``bins``; times ``scale``."""
        y = np.zeros((n_channels, self.spectrum.size), dtype=np.complex128)
        ok = (tau > self.t_lo) & (tau < self.t_hi)
        if np.any(ok):
            fb = self.f[bins]
            echo = resp[ok] * np.exp(-2j * np.pi * fb * (tau[ok, None] - self.pad / self.fs
                                                         - self.t0))
            part = np.zeros((n_channels, bins.size), dtype=np.complex128)
            np.add.at(part, channel[ok], echo)
            y[:, bins] = part
        out = sfft.irfft(y * self.spectrum * scale, self.n_fft, axis=-1)
        return out[:, self.lead:self.lead + self.n]

    def __call__(self, paths: PathSet, scale: float) -> np.ndarray:
        """Pressure (channels, samples) of ``paths`` times ``scale`` (source level)."""
        n_ch = paths.tau.shape[0]
        y = np.zeros((n_ch, self.spectrum.size), dtype=np.complex128)
        f = self.f
        for j in range(paths.tau.shape[1]):
            tau = paths.tau[:, j]
            ok = (tau > self.t_lo) & (tau < self.t_hi) & (paths.amp[:, j] != 0)
            if not np.any(ok):
                continue
            expo = (-paths.beta[ok, j, None] * f * f - paths.gamma[ok, j, None] * f
                    - 2j * np.pi * f * (tau[ok, None] - self.pad / self.fs - self.t0))
            # conj: the factors are in the physics convention, the FFT's is e^{+j omega t}
            y[ok] += np.conj(paths.amp[ok, j, None]) * np.exp(expo)
        out = sfft.irfft(y * self.spectrum * scale, self.n_fft, axis=-1)
        return out[:, self.lead:self.lead + self.n]
