"""The simulated device's echo source: seabed scattering (PoSSM), coherent returns,
multipath, ambient and electronic noise, and the scene's point scatterers.

:class:`EnvironmentSource` has the interface of the Foundation's point-scatterer source
(``n_pings``, ``ping(i)``, ``pressure(i)``, iteration); every ping is made on its own
from the scene and its index, so any subset of pings, in any order, gives the same
samples. Per ping:

1. the true pose (:mod:`sim_device.track`) gives the projector, the 80 receivers and the
   boresight in the scene's tile frame (z down from the interface);
2. image legs of the projector and receivers for multipath (:mod:`sim_device.multipath`)
   and which (m_tx, m_rx) combinations are kept (level against noise, decided once);
3. the cells the projector's cone (and its images') can reach are filled with
   scatterers (:mod:`sim_device.possm`); with the scene's points they go through the two
   synthesis passes (:mod:`sim_device.synthesis`);
4. coherent returns of the interface and deeper boundaries (:mod:`sim_device.specular`);
5. the scene's targets (:mod:`sim_device.targets.echo`), through
   ``EnvironmentSource.contributions`` (callables of the source, the ping index and its
   geometry returning pressure). A scene without targets never pays for target
   scattering;
6. noise (:mod:`sim_device.noise`) and quantisation to int32 ADC codes.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from svss_daq.config import HardwareConfig, Loaded
from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.ping import Ping
from svss_daq.scaling import counts_per_upa, quantise
from svss_daq.waveform import make_waveform

from . import possm
from .acoustics import Sediment, sigma_interface, sigma_volume
from .beams import beam_table, interface_sigma_table, reflection_tables
from .environment import Environment, build_environment
from .multipath import (coherent_paths, image_depth, leg_image, leg_pairs,
                        max_leg_reflections)
from .noise import band_power, knudsen_noise
from .refraction import two_medium_table
from .scene import SceneConfig
from .specular import (PathSet, SpectralSynthesiser, boundary_paths, interface_paths,
                       merge, select)
from .targets.echo import TargetEchoes, build_targets
from .synthesis import MED_INTERFACE, PulseSynthesiser, accumulate, transmit_legs
from .track import ping_pose, truth_line

log = logging.getLogger(__name__)


@dataclass
class PingGeometry:
    """One ping's geometry in the tile frame (m): projector (3,), receivers (n, 3),
    boresight (3,), projector index, pose."""
    tx: np.ndarray
    rx: np.ndarray
    bore: np.ndarray
    projector: int
    nav: object


@dataclass
class Scatterers:
    """Scatterers of one ping (tile frame): positions (m), medium (-1: interface),
    strength (complex, uPa at 1 m per unit incident pressure times the source level)."""
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    med: np.ndarray
    amp: np.ndarray

    @property
    def size(self) -> int:
        return self.x.size

    def take(self, keep: np.ndarray) -> "Scatterers":
        return Scatterers(self.x[keep], self.y[keep], self.z[keep], self.med[keep],
                          self.amp[keep])

    @staticmethod
    def concat(parts: list["Scatterers"]) -> "Scatterers":
        return Scatterers(*(np.concatenate([getattr(p, f) for p in parts])
                            for f in ("x", "y", "z", "med", "amp")))


def _empty_scatterers() -> Scatterers:
    z = np.zeros(0)
    return Scatterers(z, z, z, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=complex))


class EnvironmentSource:
    """Synthesises the pings of a scene: seabed, surface, noise and point scatterers."""

    def __init__(self, hardware: Loaded[HardwareConfig], scene: SceneConfig,
                 sediments: dict[str, Sediment] | None = None):
        self.hardware = hardware
        self.hw = hw = hardware.value
        self.scene = scene
        self.seed = scene.scene.seed
        self.geometry = array_geometry(hw)
        self.waveform = make_waveform(hw.waveform)
        self.line = truth_line(scene.track)
        self.env: Environment = build_environment(scene, sediments)
        self.fc = fc = self.waveform.center_hz
        self.media = media = self.env.media(fc)
        self.p0 = 10.0 ** (hw.waveform.source_level_db / 20.0)
        dig = hw.digitiser
        self.fs = dig.sample_rate_hz
        t_first = dig.window_start_s - dig.group_delay_s
        self.pulses = PulseSynthesiser(self.waveform, self.fs, dig.window_samples, t_first)
        self.spectral = SpectralSynthesiser(self.pulses.pulse_real, self.pulses.pad, self.fs,
                                            dig.window_samples, t_first)
        sc = scene.scattering
        self.fidelity = sc
        self.precision = sc.precision if sc is not None else "float64"
        # transducers
        tr = scene.transducers
        pattern, taper, back = ("cone", 0.0, None) if tr is None else (
            tr.pattern, math.radians(tr.taper_deg), tr.back_lobe_db)
        cw = self.env.water_sound_speed
        self.tx_beam = beam_table(self.geometry.projector_half_angle, pattern, taper, back,
                                  fc, cw)
        self.rx_beam = beam_table(self.geometry.receiver_half_angle, pattern, taper, back,
                                  fc, cw)
        # seabed tables
        top = self.env.layers[0].sediment if self.env.has_seabed else None
        self.top_sediment = top
        self.r_top, self.r_bot = reflection_tables(top, fc, self.env.water_density, cw)
        self.sig = interface_sigma_table(
            top, fc, self.env.water_density, cw,
            sc.interface_model if sc is not None else "apl_uw",
            sc.interface_strength_db if sc is not None else None)
        # the two-medium refraction table; precision "exact" gives a table of ones, which
        # sends every refracted leg to Brent's method
        self.table = (two_medium_table(cw, media.c[1])
                      if media.n > 1 and self.precision != "exact" else np.ones((2, 2)))
        self.sigma_v = np.array([0.0] + [ly.sediment.volume_scattering_coefficient(fc)
                                         for ly in self.env.layers])
        # multipath
        surf = scene.surface
        self.order = surf.multipath_order if surf is not None else 0
        self.drop_db = surf.drop_below_noise_db if surf is not None else math.inf
        self.m_max = max_leg_reflections(self.order, self.env.has_surface,
                                         self.env.has_seabed)
        self.water_depth = self.env.water_depth if self.env.has_surface else None
        self.sequences = coherent_paths(self.order if self.env.has_surface else 0,
                                        self.env.has_surface)
        # noise
        nz = scene.noise
        self.counts_per_upa = counts_per_upa(dig)
        electronic_upa = nz.electronic_rms_counts / self.counts_per_upa
        f_lo = min(hw.waveform.f_start_hz, hw.waveform.f_stop_hz)
        f_hi = max(hw.waveform.f_start_hz, hw.waveform.f_stop_hz)
        self.noise_power = band_power(nz.sea_state, nz.ambient_band_hz, f_lo, f_hi,
                                      electronic_upa, self.fs)
        # the scene's point scatterers
        pts = scene.points
        if pts:
            atd = np.array([[p.along_m, p.cross_m, p.depth_m] for p in pts], dtype=np.float64)
            med = np.array([self.env.medium_at(p.depth_m) for p in pts], dtype=np.int64)
            amp = self.p0 * 10.0 ** (np.array([p.target_strength_db for p in pts]) / 20.0)
            self.points = Scatterers(atd[:, 0].copy(), atd[:, 1].copy(), atd[:, 2].copy(),
                                     med, amp.astype(complex))
        else:
            self.points = _empty_scatterers()
        self.allowed = self._choose_paths()
        #: extra pressure contributions: callables f(source, i, geometry) ->
        #: (n_channels, n_samples) uPa, added by pressure(i); the scene's targets are one
        self.contributions: list = []
        self.targets = build_targets(scene, media, source=f"scene {scene.scene.name!r}")
        if self.targets:
            self.contributions.append(TargetEchoes(self, self.targets))
        self.last_stats: dict = {}

    def with_seed(self, seed: int) -> "EnvironmentSource":
        """The same source for another seabed and noise (another seed), sharing every
        table: a cheap way to draw Monte-Carlo realisations."""
        other = copy.copy(self)
        other.seed = int(seed)
        other.scene = dataclasses.replace(self.scene, scene=dataclasses.replace(
            self.scene.scene, seed=int(seed)))
        other.last_stats = {}
        return other

    # ------------------------------------------------------------------ geometry
    @property
    def n_pings(self) -> int:
        return self.scene.track.n_pings

    def frame(self, i: int) -> PingGeometry:
        """Projector, receivers and boresight of ping ``i`` in the tile frame."""
        hw, geo = self.hw, self.geometry
        nav = ping_pose(self.scene.track, hw, i, self.seed)
        rot = body_to_ned(nav.roll_rad, nav.pitch_rad, nav.heading_rad)
        proj = hw.sequencer.projector_order[i % len(hw.sequencer.projector_order)]
        tx = self.line.ned_to_tile(nav.ned + rot @ geo.projectors[proj])
        rx = self.line.ned_to_tile(nav.ned + geo.receivers @ rot.T)
        bore = self.line.rotation_from_ned() @ (rot @ geo.boresight)
        return PingGeometry(tx, rx, bore, proj, nav)

    def _images(self, pos: np.ndarray) -> np.ndarray:
        """Element-image rows (..., m_max + 1, 6) for element positions (..., 3)."""
        depth = self.water_depth if self.water_depth is not None else 0.0
        rows = []
        for m in range(self.m_max + 1):
            li = leg_image(m)
            h = -image_depth(m, pos[..., 2], depth)
            one = np.ones_like(h)
            f_surf = self.env.surface_reflection ** li.n_surface
            rows.append(np.stack([pos[..., 0], pos[..., 1], h, li.direction * one,
                                  f_surf * one, li.n_bottom * one], axis=-1))
        return np.ascontiguousarray(np.stack(rows, axis=-2))

    # --------------------------------------------------------------- path choice
    def _choose_paths(self) -> np.ndarray:
        """allowed[m_tx, m_rx]: multipath combinations synthesised. A combination is
        dropped when its nadir sonar-equation level (pulse-limited area, interface and
        volume backscatter near normal incidence, or the strongest scene point; its
        reflections and lobe levels) lies more than ``drop_below_noise_db`` below the
        noise in the pulse's band."""
        n = self.m_max + 1
        allowed = np.zeros((n, n), dtype=np.bool_)
        pairs = leg_pairs(self.order, self.m_max)
        if not pairs:
            pairs = [(0, 0)]
        g = self.frame(0)
        depth = self.water_depth if self.water_depth is not None else 0.0
        sigma = self._nadir_sigma()
        ts = float(np.max(np.abs(self.points.amp)) / self.p0) ** 2 if self.points.size else 0.0
        t_p = self.waveform.duration_s
        c0 = self.env.water_sound_speed
        r_b = abs(self.r_bot[0]) if self.env.has_seabed else 0.0
        back = (10.0 ** (self.scene.transducers.back_lobe_db / 20.0)
                if self.scene.transducers is not None
                and self.scene.transducers.back_lobe_db is not None else 0.0)
        self.path_levels_db = {}
        for (a, b) in pairs:
            la, lb = leg_image(a), leg_image(b)
            h_t = -float(image_depth(a, g.tx[2], depth))
            h_r = -float(image_depth(b, float(np.mean(g.rx[:, 2])), depth))
            lobes = (1.0 if a % 2 == 0 else back) * (1.0 if b % 2 == 0 else back)
            refl = (abs(self.env.surface_reflection) ** (la.n_surface + lb.n_surface)
                    * r_b ** (la.n_bottom + lb.n_bottom))
            area = math.pi * 0.5 * (h_t + h_r) * c0 * t_p
            ms = (0.5 * self.p0 ** 2 * (lobes * refl) ** 2 * (sigma * area + ts)
                  / (h_t * h_r) ** 2)
            level = 10.0 * math.log10(ms) if ms > 0 else -math.inf
            self.path_levels_db[(a, b)] = level
            keep = (a, b) == (0, 0) or self.noise_power <= 0 or (
                level >= 10.0 * math.log10(self.noise_power) - self.drop_db)
            allowed[a, b] = keep
            if not keep:
                log.info("multipath legs (%d, %d) dropped: nadir level %.1f dB re uPa^2, "
                         "noise %.1f dB", a, b, level, 10 * math.log10(self.noise_power))
        return allowed

    def _nadir_sigma(self) -> float:
        """Interface plus volume backscatter near normal incidence (linear), for the
        path-level estimate."""
        sc = self.fidelity
        if sc is None:
            return 0.0
        if not self.env.has_seabed:
            return 0.0
        th = math.radians(85.0)
        if sc.interface_model == "constant":
            s_int = 10.0 ** (sc.interface_strength_db / 10.0)
        elif self.top_sediment is not None:
            rho, nu, d = self.top_sediment.ratios(self.env.water_density,
                                                  self.env.water_sound_speed)
            s_int = float(sigma_interface(th, self.fc, rho, nu, d,
                                          self.top_sediment.spectral_strength,
                                          self.top_sediment.spectral_exponent,
                                          self.env.water_sound_speed))
        else:
            s_int = 0.0
        s_vol = 0.0
        if self.top_sediment is not None:
            rho, nu, d = self.top_sediment.ratios(self.env.water_density,
                                                  self.env.water_sound_speed)
            s_vol = float(sigma_volume(th, rho, nu, d, self.top_sediment.sigma2()))
        return (s_int if sc.interface else 0.0) + (s_vol if sc.volume else 0.0)

    # --------------------------------------------------------------- scatterers
    def _tx_reach(self, g: PingGeometry):
        """Horizontal reach (m) of the projector's cones at a depth, all images."""
        tilt = math.acos(max(-1.0, min(1.0, abs(float(g.bore[2])))))
        angle = self.tx_beam.edge + tilt
        used = np.flatnonzero(self.allowed.any(axis=1))
        depth = self.water_depth if self.water_depth is not None else 0.0
        h = max(-float(image_depth(int(m), g.tx[2], depth)) for m in used)
        limit = float(self.media.c.max()) * self.pulses.t_hi
        c, z_top = self.media.c, self.media.z_top
        return lambda z: possm.cone_reach(np.asarray(z), h, angle, c, z_top, limit)

    def _depth_limit(self, g: PingGeometry) -> float:
        """Deepest volume scatterer: the scene's cut-off, or where even the vertical
        two-way path leaves the receive window."""
        zmax = self.fidelity.volume_max_depth_m
        c, z_top = self.media.c, self.media.z_top
        h_t = -g.tx[2]
        h_r = float(np.min(-g.rx[:, 2]))
        z = np.linspace(0.0, zmax, 2001)
        t = (h_t + h_r) / c[0] + np.zeros_like(z)
        for i in range(1, c.size):
            bot = z_top[i + 1] if i + 1 < c.size else np.inf
            t += 2.0 * (np.clip(z, z_top[i], bot) - z_top[i]) / c[i]
        inside = z[t < self.pulses.t_hi]
        return float(inside[-1]) if inside.size else 0.0

    def scatterers(self, i: int, g: PingGeometry | None = None) -> Scatterers:
        """The seabed scatterers the projector can reach on ping ``i`` (before the beam
        and window tests of the kernels), plus the scene's points."""
        g = g if g is not None else self.frame(i)
        sc = self.fidelity
        parts = [self.points] if self.points.size else []
        if sc is None or not self.env.has_seabed:
            return Scatterers.concat(parts) if parts else _empty_scatterers()
        reach = self._tx_reach(g)
        cell = sc.cell_m
        if sc.interface:
            cells = possm.interface_cells(g.tx[0], g.tx[1], float(reach(0.0)[0]), cell)
            n_per = possm.scatterers_per_cell(sc.interface_density_per_m2, cell * cell)
            s = self._generate(cells, possm.KIND_INTERFACE, n_per, cell)
            s.amp *= self.p0 * math.sqrt(cell * cell / n_per)
            s.med[:] = MED_INTERFACE
            parts.append(s)
        if sc.volume:
            zmax = self._depth_limit(g)
            cells = possm.volume_cells(g.tx[0], g.tx[1], lambda z: reach(z)[0], zmax, cell)
            n_per = possm.scatterers_per_cell(sc.volume_density_per_m3, cell ** 3)
            s = self._generate(cells, possm.KIND_VOLUME, n_per, cell)
            s = s.take(s.z <= zmax)
            s.med = np.searchsorted(self.media.z_top[1:], s.z, side="right").astype(np.int64)
            s.amp *= self.p0 * np.sqrt(self.sigma_v[s.med] * cell ** 3 / n_per)
            parts.append(s)
        return Scatterers.concat(parts) if parts else _empty_scatterers()

    def _generate(self, cells: np.ndarray, kind: int, n_per: int, cell: float) -> Scatterers:
        n = cells.shape[0] * n_per
        x, y, z = np.empty(n), np.empty(n), np.empty(n)
        xi = np.empty(n, dtype=np.complex128)
        if n:
            possm.generate_cells(cells, kind, n_per, cell, cell, self.seed, x, y, z, xi)
        return Scatterers(x, y, z, np.zeros(n, dtype=np.int64), xi)

    # ---------------------------------------------------------------- synthesis
    def scattered(self, i: int, g: PingGeometry | None = None) -> np.ndarray:
        """Pressure (uPa) of the point scatterers (seabed and scene points) on ping i."""
        t0 = time.perf_counter()
        g = g if g is not None else self.frame(i)
        s = self.scatterers(i, g)
        n_gen = s.size
        n_ch = g.rx.shape[0]
        if s.size == 0:
            self.last_stats.update(generated=0, in_view=0, echoes=0)
            return np.zeros((n_ch, self.pulses.n))
        # ping-local coordinates (the projector's horizontal position as origin)
        ox, oy = float(g.tx[0]), float(g.tx[1])
        tx = g.tx - [ox, oy, 0.0]
        rx = g.rx - [ox, oy, 0.0]
        f = np.float32 if self.precision == "float32" else np.float64
        cf = np.complex64 if self.precision == "float32" else np.complex128
        img_t = self._images(tx[None, :])[0].astype(f)
        img_r = self._images(rx).astype(f)
        sx, sy, sz = (s.x - ox).astype(f), (s.y - oy).astype(f), s.z.astype(f)
        amp = s.amp.astype(cf)
        m = self.media
        args_env = (m.c, m.rho, m.delta, m.alpha, m.z_top, self.table, self.r_top,
                    self.r_bot)
        bore = np.ascontiguousarray(g.bore, dtype=np.float64)
        tb = self.tx_beam
        t1 = time.perf_counter()
        tau_t = np.empty((s.size, img_t.shape[0]), dtype=f)
        amp_t = np.empty((s.size, img_t.shape[0]), dtype=cf)
        transmit_legs(sx, sy, sz, s.med, amp, img_t, *args_env, bore, tb.front, tb.back,
                      tb.lo_front, tb.lo_back, self.sig, tau_t, amp_t)
        seen = np.any(amp_t != 0, axis=1)
        idx = np.flatnonzero(seen)
        t2 = time.perf_counter()
        rb = self.rx_beam
        buf = self.pulses.buffer(n_ch).astype(cf)
        counts = accumulate(sx[idx], sy[idx], sz[idx], s.med[idx], tau_t[idx], amp_t[idx],
                            img_r, self.allowed, *args_env, bore, rb.front, rb.back,
                            rb.lo_front, rb.lo_back, self.sig, self.fc, self.pulses.t_lo,
                            self.pulses.t_hi, self.pulses.t_buf0, self.fs, buf)
        t3 = time.perf_counter()
        out = self.pulses.to_passband(buf.astype(np.complex128))
        self.last_stats.update(generated=n_gen, in_view=int(idx.size),
                               echoes=int(counts.sum()), generate_s=t1 - t0,
                               transmit_s=t2 - t1, receive_s=t3 - t2,
                               scattered_s=time.perf_counter() - t0)
        return out

    def coherent_paths(self, i: int, g: PingGeometry | None = None) -> PathSet:
        """The coherent (specular) paths of ping ``i`` that are synthesised."""
        g = g if g is not None else self.frame(i)
        m = self.media
        top = self.top_sediment
        rho, nu, d = top.ratios(self.env.water_density, self.env.water_sound_speed)
        paths = interface_paths(g.tx, g.rx, g.bore, m, self.water_depth,
                                self.env.surface_reflection, self.sequences, self.tx_beam,
                                self.rx_beam, rho, nu, d)
        if m.n > 2:
            pairs = [(a, b) for a, b in leg_pairs(self.order, self.m_max)]
            paths = merge(paths, boundary_paths(g.tx, g.rx, g.bore, m, self.water_depth,
                                                self.env.surface_reflection, pairs,
                                                self.tx_beam, self.rx_beam))
        if self.noise_power > 0 and paths.tau.shape[1]:
            peak = 0.5 * (self.p0 * paths.level_at(self.fc).max(axis=0)) ** 2
            floor = self.noise_power * 10.0 ** (-self.drop_db / 10.0)
            keep = (paths.order == 0) | (peak >= floor)
            paths = select(paths, keep)
        return paths

    def specular(self, i: int, g: PingGeometry | None = None) -> np.ndarray:
        """Pressure (uPa) of the coherent returns on ping ``i``."""
        g = g if g is not None else self.frame(i)
        sc = self.fidelity
        if sc is None or not sc.specular or not self.env.has_seabed:
            return np.zeros((g.rx.shape[0], self.pulses.n))
        paths = self.coherent_paths(i, g)
        self.last_stats["coherent_paths"] = paths.tau.shape[1]
        return self.spectral(paths, self.p0)

    def pressure(self, i: int) -> np.ndarray:
        """Noise-free acoustic pressure (uPa) at every hydrophone on ping ``i``, sampled
        on the digitiser's grid: (n_channels, n_samples) float64."""
        g = self.frame(i)
        self.last_stats = {"ping": i}
        out = self.scattered(i, g) + self.specular(i, g)
        for extra in self.contributions:
            out = out + extra(self, i, g)
        return out

    def noise(self, i: int) -> np.ndarray:
        """Ambient and electronic noise (uPa) of ping ``i``."""
        dig = self.hw.digitiser
        shape = (self.geometry.n_channels, dig.window_samples)
        out = np.zeros(shape)
        nz = self.scene.noise
        if nz.sea_state is not None:
            rng = np.random.default_rng([self.seed, i, 1])
            out += knudsen_noise(rng, shape[0], shape[1], self.fs, nz.sea_state,
                                 nz.ambient_band_hz)
        if nz.electronic_rms_counts > 0:
            rng = np.random.default_rng([self.seed, i])
            out += rng.normal(0.0, nz.electronic_rms_counts / self.counts_per_upa, shape)
        return out

    def ping(self, i: int) -> Ping:
        """Ping ``i``: quantised samples with noise, and its true pose."""
        hw = self.hw
        dig = hw.digitiser
        p = self.pressure(i) + self.noise(i)
        codes, clipped = quantise(p, dig)
        if clipped:
            log.warning("ping %d: %d samples clipped at full scale", i, clipped)
        g_nav = ping_pose(self.scene.track, hw, i, self.seed)
        proj = hw.sequencer.projector_order[i % len(hw.sequencer.projector_order)]
        return Ping(sequence=i, projector=proj, transmit_time_ns=g_nav.time_ns,
                    sample_rate_hz=dig.sample_rate_hz,
                    window_start_ns=int(round(dig.window_start_s * 1e9)), samples=codes,
                    nav=g_nav, config_id=self.hardware.id)

    def __iter__(self):
        for i in range(self.n_pings):
            yield self.ping(i)
