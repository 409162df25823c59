"""Target echoes in the simulated pings: the scene's targets as a contribution of
:class:`sim_device.environment_source.EnvironmentSource`.

For one ping and one target:

1. the projector's legs to the target centre (:mod:`.paths`: refracted if buried,
   direct and interface-reflected if proud); if no leg leaves the projector inside its
   beam (with an angular margin for the target's extent) the target costs nothing more;
2. the receivers' legs; every (projector leg, receiver leg) pair is an echo path with
   two-way delay tau, a frequency-independent factor (beam gains, spreading,
   transmission or reflection, water absorption), the coherent loss exp(-beta f^2) and
   the sediment attenuation exp(-gamma f); paths with a zero factor or outside the
   receive window are dropped;
3. the target's scattering amplitude f(freq; incident, scattered direction)
   (:mod:`.model`) on the band of the transmit pulse, for each remaining path only;
4. the echo spectrum  conj(p0 A f) exp(-beta f^2 - gamma f) e^{-j 2 pi f tau} S(f)  (the
   physics-convention factors conjugated for numpy's e^{+j omega t} synthesis; S the
   pulse spectrum), summed per channel and inverse transformed on the digitiser's grid
   (:meth:`sim_device.specular.SpectralSynthesiser.responses`).

Ringing (docs/targets_elastic.md §4): the echo spectrum is sampled on the FFT grid of a
:class:`~sim_device.specular.SpectralSynthesiser`, whose period bounds how long a response
may last before it wraps round into the window.  A sphere, a shell or a cylinder with a
form table keeps a grid a little longer than the pings' own and each path's response is
cut where the window can no longer see it (:mod:`.ringing`: tables cut on a fine grid,
shared by the paths; nothing wraps, by construction).  A disc (or a cylinder summed
exactly, step 0) gets a grid lengthened by its ring time t_ring, measured once on a fine
grid (where the energy still to come falls RING_DB below the total), and a response
that rings longer than the cap (``ring_max_s``; default the receive window plus the
pulse) is cut there with a short taper, path by path.

A scene without targets never builds this; a target outside every beam or window costs
two ray solves per ping.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import scipy.fft as sfft

from ..specular import SpectralSynthesiser
from ._series import DEFAULT_TOL
from .materials import Fluid, MaterialTable, load_materials
from .model import SceneTarget
from .paths import target_legs
from .ringing import RING_TAPER_S, CylinderRinging, ModalRinging, cut_window, tail_samples
from .shells import VACUUM

log = logging.getLogger(__name__)

#: defaults of the scene's [target_model] table (docs/targets.md, benchmark figures)
DEFAULT_FREQ_STEP_HZ = 5.0
DEFAULT_BISTATIC = "kell"
#: material name of a rigid, fixed target (no entry in the materials table)
RIGID = "rigid"
#: a target's ring time: when the energy still to come is this far below the total, dB
RING_DB = 60.0


def build_targets(scene, media, materials: MaterialTable | None = None,
                  source: str = "<scene>") -> list[SceneTarget]:
    """The scene's targets with their materials and host media; an unknown material
    raises a :class:`ValueError` naming ``targets[k].material``."""
    materials = materials if materials is not None else load_materials()
    tm = scene.target_model
    tol = tm.truncation_tol if tm is not None else DEFAULT_TOL
    step = tm.freq_step_hz if tm is not None else DEFAULT_FREQ_STEP_HZ
    rule = tm.bistatic if tm is not None else DEFAULT_BISTATIC
    lossy = tm is None or tm.material_loss is None or tm.material_loss
    out = []
    for k, cfg in enumerate(scene.targets):
        try:
            material = None if cfg.material == RIGID else materials.material(cfg.material)
        except Exception as exc:
            raise ValueError(f"{source}: key 'targets[{k}].material': {exc}") from None
        if material is not None and not lossy:
            material = material.lossless()
        fill = VACUUM
        if cfg.kind == "shell":
            if material is None or material.is_fluid:
                raise ValueError(f"{source}: key 'targets[{k}].material': a shell needs an "
                                 f"elastic solid, got {cfg.material!r}")
            if cfg.fill is not None and cfg.fill != VACUUM:
                try:
                    fill = materials.fluid(cfg.fill)
                except Exception as exc:
                    raise ValueError(f"{source}: key 'targets[{k}].fill': {exc}") from None
        med = 0 if cfg.depth_m < 0.0 else int(
            np.searchsorted(media.z_top[1:], cfg.depth_m, side="right"))
        host = Fluid("water" if med == 0 else f"medium {med}", float(media.rho[med]),
                     float(media.c[med]))
        out.append(SceneTarget(cfg, material, host, med, tol=tol, freq_step_hz=step,
                               bistatic=rule, index=k, fill=fill))
    return out


def ring_time(target: SceneTarget, spec, cap_s: float,
              pulse: np.ndarray) -> tuple[float, bool]:
    """(t_ring, cut): how long (s, from the start of the pulse at the centre's delay) the
    target's brightest monostatic echo of ``pulse`` (the digitised transmit pulse) lasts
    until the energy still to come is RING_DB below the total, at most ``cap_s``;
    ``cut`` when it rings longer than ``cap_s``."""
    fs = spec.fs
    pre = _advance(target, fs)
    n_e = sfft.next_fast_len(int(math.ceil(2.0 * cap_s * fs)) + 2 * pre + spec.n_pulse)
    f_e = np.arange(1, n_e // 2 + 1) * fs / n_e
    s_e = sfft.rfft(pulse, n_e)[1:]
    keep = np.abs(s_e) > 1e-6 * np.abs(s_e).max()
    k_in, k_out = target.reference_directions()
    x = np.zeros(n_e // 2 + 1, dtype=complex)
    x[1:][keep] = np.conj(target.amplitude(f_e[keep], k_in, k_out)[0]) * s_e[keep]
    e = sfft.irfft(x, n_e) ** 2
    total = float(e.sum())
    if not total > 0:
        return 0.0, False
    after = np.cumsum(e[:n_e - pre][::-1])[::-1]          # energy from sample i on
    thr = total * 10.0 ** (-RING_DB / 10.0)
    i_cap = min(int(math.ceil(cap_s * fs)), after.size - 1)
    if after[i_cap] > thr:
        return cap_s, True
    return float(np.argmax(after <= thr)) / fs, False


def _advance(target: SceneTarget, fs: float) -> int:
    """Samples by which a target's echo may precede its centre's delay (front face),
    with a margin."""
    return int(math.ceil((2.0 * target.extent / target.host.sound_speed + 2e-4) * fs)) + 4


def _cut_window(n_fft: int, fs: float, pre: int, t_cut: float) -> np.ndarray:
    """1 from -pre samples to t_cut, a raised-cosine taper over RING_TAPER_S, 0 after
    (circular time: the last ``pre`` samples are the negative times)."""
    t = np.arange(n_fft) / fs
    t[n_fft - pre:] -= n_fft / fs
    return cut_window(t, t_cut)


class TargetEchoes:
    """Callable ``(source, i, geometry) -> pressure (channels, samples) uPa`` adding the
    echoes of ``targets`` to the pings of ``source``."""

    def __init__(self, source, targets: list[SceneTarget], ring_max_s: float | None = None):
        self.targets = targets
        spec = source.spectral
        self.t_lo, self.t_hi = spec.t_lo, spec.t_hi
        fs = spec.fs
        #: the cap of a target's ringing (s)
        self.ring_cap = (float(ring_max_s) if ring_max_s is not None
                         else (spec.n + spec.n_pulse) / fs)
        self._synths: dict[int, SpectralSynthesiser] = {}
        #: per target, made when it is first in view: (synthesiser, bins, freq, cut
        #: window or None, t_ring)
        self.grids: list = [None] * len(targets)
        #: per target: its :mod:`.ringing` cut responses (None: a disc, a cylinder
        #: without table)
        self.ringing: list = [None] * len(targets)

    def _synth(self, source, tail: int) -> SpectralSynthesiser:
        spec = source.spectral
        syn = self._synths.get(tail)
        if syn is None:
            syn = self._synths[tail] = SpectralSynthesiser(
                source.pulses.pulse_real, source.pulses.pad, spec.fs, spec.n,
                spec.t0 + spec.lead / spec.fs, tail_samples=tail)
        return syn

    def grid(self, source, k: int):
        """The synthesis grid of target k (made once, when it is first seen)."""
        if self.grids[k] is not None:
            return self.grids[k]
        spec = source.spectral
        fs = spec.fs
        target = self.targets[k]
        pre = _advance(target, fs)
        pulse = source.pulses.pulse_real
        if target.kind in ("sphere", "shell") or target._form is not None:
            syn = self._synth(source, tail_samples(target, fs, pre))
            bins = syn.band()
            f_max = float(syn.f[bins].max())
            if target._form is None:
                # the longest cut: the window and pulse (at most the cap), and its taper
                keep = int(math.ceil((min(self.ring_cap, (spec.n + spec.n_pulse + 1) / fs)
                                      + RING_TAPER_S + 2.5e-4) * fs)) + 2
                ring = ModalRinging(target, pulse, fs, f_max, pre, keep, syn.n_fft, bins,
                                    self.ring_cap)
                fold_db = 10 * math.log10(max(ring.fold, 1e-300))
                t_ring = ring.t_ring
                note = (f"; fine grid {1e3 * ring.fine_s:.0f} ms, {fold_db:.0f} dB in its "
                        "last quarter")
            else:
                ring = CylinderRinging(target, f_max)
                t_ring, _ = ring_time(target, spec, self.ring_cap, pulse)
                note = ""
            self.ringing[k] = ring
            self.grids[k] = (syn, bins, syn.f[bins], None, t_ring)
            log.info("target %d (%s): rings %.2f ms%s; synthesis period %.2f ms, each "
                     "path cut where the window ends", target.index, target.kind,
                     1e3 * t_ring, note, 1e3 * syn.n_fft / fs)
            return self.grids[k]
        t_ring, cut = ring_time(target, spec, self.ring_cap, pulse)
        tail = int(math.ceil((t_ring + (RING_TAPER_S if cut else 0.0)) * fs)) + pre
        syn = self._synth(source, tail)
        bins = syn.band()
        win = _cut_window(syn.n_fft, fs, pre, t_ring) if cut else None
        self.grids[k] = (syn, bins, syn.f[bins], win, t_ring)
        log.info("target %d (%s): rings %.2f ms%s; synthesis period %.2f ms",
                 target.index, target.kind, 1e3 * t_ring, " (cut)" if cut else "",
                 1e3 * syn.n_fft / fs)
        return self.grids[k]

    def paths(self, source, g, target: SceneTarget):
        """Echo paths of ``target`` on the ping with geometry ``g``: (channel, tau,
        factor, beta, gamma, k_in, k_out) over kept paths, or None when no projector
        leg sees the target."""
        media = source.media
        bore = np.asarray(g.bore, dtype=np.float64)
        und = getattr(source, "undulation", None)
        rows = und.rows if und is not None else None
        tx_legs = target_legs(g.tx[None, :], target.position, target.medium, media, False,
                              rows)
        dist = float(np.linalg.norm(target.position - g.tx))
        margin = math.asin(min(1.0, target.extent / max(dist, 1e-9)))
        seen = [leg for leg in tx_legs
                if math.acos(max(-1.0, min(1.0, float(leg.look[0] @ bore)))) - margin
                <= source.tx_beam.edge]
        if not seen:
            return None
        rx_legs = target_legs(g.rx, target.position, target.medium, media, True, rows)
        parts = []
        for a in seen:
            g_tx = float(source.tx_beam(np.array([a.look[0] @ bore]))[0])
            if g_tx == 0.0:
                continue
            for b in rx_legs:
                amp = g_tx * a.factor[0] * source.rx_beam(b.look @ bore) * b.factor
                tau = a.time[0] + b.time
                keep = (amp != 0) & (tau > self.t_lo) & (tau < self.t_hi)
                if not np.any(keep):
                    continue
                ch = np.flatnonzero(keep)
                parts.append((ch, tau[ch], amp[ch], a.beta[0] + b.beta[ch],
                              a.gamma[0] + b.gamma[ch],
                              np.broadcast_to(a.arrive[0], (ch.size, 3)), -b.arrive[ch]))
        if not parts:
            return None
        return tuple(np.concatenate(x) for x in zip(*parts))

    def __call__(self, source, i: int, g) -> np.ndarray:
        t0 = time.perf_counter()
        n_ch = g.rx.shape[0]
        out = np.zeros((n_ch, source.spectral.n))
        in_view = 0
        rows = 0
        for k, target in enumerate(self.targets):
            p = self.paths(source, g, target)
            if p is None:
                continue
            syn, bins, f, win, _ = self.grid(source, k)
            ch, tau, amp, beta, gamma, k_in, k_out = p
            in_view += 1
            rows += ch.size
            ring = self.ringing[k]
            if ring is not None:
                # each path cut where the window ends (at most at the cap)
                keep = np.minimum(syn.t0 + (syn.lead + syn.n + syn.pad) / syn.fs - tau,
                                  self.ring_cap)
                form = (ring.form(k_in, k_out, keep) if target._form is None
                        else ring.form(f, k_in, k_out, keep))
            else:
                form = np.conj(target.amplitude(f, k_in, k_out))          # (M, F)
            if win is not None:                 # cut the ringing past the cap
                x = np.zeros((form.shape[0], syn.spectrum.size), dtype=complex)
                x[:, bins] = form
                form = sfft.rfft(sfft.irfft(x, syn.n_fft, axis=-1) * win, axis=-1)[:, bins]
            resp = (np.conj(amp)[:, None] * form
                    * np.exp(-beta[:, None] * f * f - gamma[:, None] * f))
            out += syn.responses(n_ch, ch, tau, resp, bins, source.p0)
        source.last_stats.update(targets_in_view=in_view, target_paths=rows,
                                 target_s=time.perf_counter() - t0)
        return out
