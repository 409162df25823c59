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

A scene without targets never builds this; a target outside every beam or window costs
two ray solves per ping.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from ._series import DEFAULT_TOL
from .materials import Fluid, MaterialTable, load_materials
from .model import SceneTarget
from .paths import target_legs

log = logging.getLogger(__name__)

#: defaults of the scene's [target_model] table (docs/targets.md, benchmark figures)
DEFAULT_FREQ_STEP_HZ = 5.0
DEFAULT_BISTATIC = "kell"
#: material name of a rigid, fixed target (no entry in the materials table)
RIGID = "rigid"


def build_targets(scene, media, materials: MaterialTable | None = None,
                  source: str = "<scene>") -> list[SceneTarget]:
    """The scene's targets with their materials and host media; an unknown material
    raises a :class:`ValueError` naming ``targets[k].material``."""
    materials = materials if materials is not None else load_materials()
    tm = scene.target_model
    tol = tm.truncation_tol if tm is not None else DEFAULT_TOL
    step = tm.freq_step_hz if tm is not None else DEFAULT_FREQ_STEP_HZ
    rule = tm.bistatic if tm is not None else DEFAULT_BISTATIC
    out = []
    for k, cfg in enumerate(scene.targets):
        try:
            material = None if cfg.material == RIGID else materials.material(cfg.material)
        except Exception as exc:
            raise ValueError(f"{source}: key 'targets[{k}].material': {exc}") from None
        med = 0 if cfg.depth_m < 0.0 else int(
            np.searchsorted(media.z_top[1:], cfg.depth_m, side="right"))
        host = Fluid("water" if med == 0 else f"medium {med}", float(media.rho[med]),
                     float(media.c[med]))
        out.append(SceneTarget(cfg, material, host, med, tol=tol, freq_step_hz=step,
                               bistatic=rule, index=k))
    return out


class TargetEchoes:
    """Callable ``(source, i, geometry) -> pressure (channels, samples) uPa`` adding the
    echoes of ``targets`` to the pings of ``source``."""

    def __init__(self, source, targets: list[SceneTarget]):
        self.targets = targets
        spec = source.spectral
        self.bins = spec.band()
        self.freq = spec.f[self.bins]
        self.t_lo, self.t_hi = spec.t_lo, spec.t_hi

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
        f = self.freq
        for target in self.targets:
            p = self.paths(source, g, target)
            if p is None:
                continue
            ch, tau, amp, beta, gamma, k_in, k_out = p
            in_view += 1
            rows += ch.size
            form = target.amplitude(f, k_in, k_out)                       # (M, F)
            resp = (np.conj(amp[:, None] * form)
                    * np.exp(-beta[:, None] * f * f - gamma[:, None] * f))
            out += source.spectral.responses(n_ch, ch, tau, resp, self.bins, source.p0)
        source.last_stats.update(targets_in_view=in_view, target_paths=rows,
                                 target_s=time.perf_counter() - t0)
        return out
