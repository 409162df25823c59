"""The simulated device's echo source: seabed scattering (PoSSM), coherent returns,
multipath, ambient and electronic noise, and the scene's point scatterers.

:class:`EnvironmentSource` has the interface of the Foundation's point-scatterer source
(``n_pings``, ``ping(i)``, ``pressure(i)``, iteration); every ping is made on its own
from the scene and its index, so any subset of pings, in any order, gives the same
samples. Per ping:

1. the true pose (:mod:`sim_device.track`) places the array in the scene's tile frame
   (z down from the interface) through :func:`svss_daq.geometry.place_array`;
2. image legs of the projector and receivers for multipath (:mod:`sim_device.multipath`)
   and which (m_tx, m_rx) combinations are kept (:mod:`sim_device.path_choice`, decided
   once);
3. the cells the projector's cone (and its images') can reach are filled with
   scatterers (:mod:`sim_device.scatterers`); with the scene's points they go through
   the two synthesis passes (:mod:`sim_device.synthesis`);
4. coherent returns of the interface and deeper boundaries (:mod:`sim_device.specular`);
5. the scene's targets (:mod:`sim_device.targets.echo`), through
   ``EnvironmentSource.contributions`` (callables of the source, the ping index and its
   geometry returning pressure). A scene without targets never pays for target
   scattering;
6. noise (:mod:`sim_device.receiver_noise`), quantisation to int32 ADC codes, and the
   ping built by :class:`svss_daq.assembly.PingAssembler` on the digitiser's axis.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import time
from dataclasses import dataclass

import numba
import numpy as np

from svss_daq.assembly import PingAssembler, acoustic_axis
from svss_daq.config import HardwareConfig, Loaded
from svss_daq.geometry import array_geometry, place_array
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.scaling import quantise
from svss_daq.waveform import make_waveform

from .acoustics import Sediment
from .bed_plane import BedPlane, leg_image_position
from .bed_surface import BedSurface
from .bed_undulation import Undulation
from .beams import beam_table, interface_sigma_table, reflection_tables
from .environment import Environment, build_environment
from .fidelity import densities, resolution_cell, volume_depth_limits
from .layered_rays import two_medium_table
from .multipath import coherent_paths, image_depth, leg_image, leg_pairs, max_leg_reflections
from .path_choice import choose_paths, nadir_sigma
from .receiver_noise import ReceiverNoise
from .scatterers import Scatterers, SeabedScatterers, scene_points
from .scene import SceneConfig
from .specular import (PathSet, SpectralSynthesiser, boundary_paths, interface_paths,
                       merge, select)
from .specular_curved import curved_interface_paths
from .pulse import PulseSynthesiser
from .synthesis import (SERIAL_BELOW, Medium, Pass2, Paths, Points, TransmitLegs, accumulate,
                        accumulate_fast, accumulate_fast_serial, beam_of, transmit_legs)
from .synthesis_curved import curved_accumulate, curved_transmit_legs
from .targets.echo import TargetEchoes, build_targets
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
    nav: NavSnapshot


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
        slope = scene.seabed.slope_deg if scene.seabed is not None else None
        #: a sloping bed (sim_device.bed_plane): geometry goes into its frame; None: level
        self.bed = (BedPlane.from_slopes(*slope)
                    if slope is not None and any(slope) else None)
        terms = scene.seabed.undulation if scene.seabed is not None else ()
        #: the interface undulating about its plane (sim_device.bed_undulation, bed
        #: frame); None: the plane itself
        self.undulation = (Undulation.from_terms(
            [(t.amplitude_m, t.wavelength_m, t.direction_deg, t.phase_deg) for t in terms])
            if terms else None)
        #: where the bed is (altitudes)
        self.surface = BedSurface(self.bed, self.undulation)
        self.env: Environment = build_environment(scene, sediments)
        self.fc = fc = self.waveform.center_hz
        self.media = media = self.env.media(fc)
        self.p0 = 10.0 ** (hw.waveform.source_level_db / 20.0)
        dig = hw.digitiser
        self.assembler = PingAssembler(hardware)
        arrival = acoustic_axis(self.assembler.sample_axis, dig)     # what sample n holds
        self.fs = dig.sample_rate_hz
        self.pulses = PulseSynthesiser(self.waveform, self.fs, arrival.n, arrival.start_s)
        self.spectral = SpectralSynthesiser(self.pulses.pulse_real, self.pulses.pad, self.fs,
                                            arrival.n, arrival.start_s)
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
        # multipath
        surf = scene.surface
        self.order = surf.multipath_order if surf is not None else 0
        self.drop_db = surf.drop_below_noise_db if surf is not None else math.inf
        self.m_max = max_leg_reflections(self.order, self.env.has_surface,
                                         self.env.has_seabed)
        self.water_depth = self.env.water_depth if self.env.has_surface else None
        self.sequences = coherent_paths(self.order if self.env.has_surface else 0,
                                        self.env.has_surface)
        self.receiver_noise = ReceiverNoise(scene.noise, hw.waveform, dig)
        self.noise_power = self.receiver_noise.power
        self.points = scene_points(scene, self.env, self.p0, self.bed, self.undulation)
        self.synthesis = (sc.synthesis if sc is not None and sc.synthesis is not None
                          else "fast")
        #: pass 2 on the GPU ([scattering] device = "cuda", sim_device.synthesis_gpu)
        self.gpu = None
        if sc is not None and sc.device == "cuda":
            if self.synthesis == "reference":
                raise ValueError(f"scene {scene.scene.name!r}: scattering.device = 'cuda' "
                                 "needs scattering.synthesis = 'fast'")
            from .synthesis_gpu import GpuAccumulator
            self.gpu = GpuAccumulator(f"scene {scene.scene.name!r}: scattering.device")
        self.resolution = self._resolution_cell()
        dens = None
        if sc is not None and sc.scatterers_per_resolution_cell is not None:
            dens = densities(self.resolution, sc.scatterers_per_resolution_cell)
            log.info("scatterer densities from %.3g per resolution cell (%.3f x %.3f x "
                     "%.3f m): %.0f /m^2, %.0f /m^3", sc.scatterers_per_resolution_cell,
                     self.resolution.along, self.resolution.across,
                     self.resolution.depth_sediment, *dens)
        self.seabed = SeabedScatterers(scene, self.env, fc, self.p0, self.tx_beam.edge,
                                       self.pulses.t_hi, self.water_depth, dens)
        self.allowed = self._choose_paths()
        #: zmax[m_tx, m_rx]: deepest scatterer each path synthesises (the level cut-off)
        self.zmax = self._volume_limits()
        if self.synthesis == "reference" and np.isfinite(self.zmax).any():
            raise ValueError(f"scene {scene.scene.name!r}: scattering.volume_below_noise_db "
                             "needs scattering.synthesis = 'fast' (the reference kernel has "
                             "no per-path depth limits)")
        kept = self.zmax[self.allowed]
        self.seabed.z_cut = float(kept.max()) if kept.size else math.inf
        #: extra pressure contributions: callables f(source, i, geometry) ->
        #: (n_channels, n_samples) uPa, added by pressure(i); the scene's targets are one
        self.contributions: list = []
        self.targets = build_targets(scene, media, source=f"scene {scene.scene.name!r}")
        if self.bed is not None:
            for t in self.targets:
                t.position = self.bed.buried(*t.position)
                t.axis = self.bed.vector_to_bed(t.axis)
        if self.undulation is not None:
            for t in self.targets:
                t.position = np.array(t.position, dtype=np.float64)
                t.position[2] += float(self.undulation.height(*t.position[:2]))
        if self.targets:
            tm = scene.target_model
            self.contributions.append(TargetEchoes(
                self, self.targets, tm.ring_max_s if tm is not None else None))
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

    def pose(self, i: int) -> NavSnapshot:
        """The true pose of ping ``i``; over a sloping or undulating bed its altitude is
        the body's vertical height above the bed below it."""
        nav = ping_pose(self.scene.track, self.hw, i, self.seed)
        if self.bed is None and self.undulation is None:
            return nav
        body = self.line.ned_to_tile(np.array([nav.north_m, nav.east_m, nav.down_m]))
        altitude = self.surface.vertical_height(body)
        if not altitude > 0.0:
            key = "seabed.undulation" if self.undulation is not None else "seabed.slope_deg"
            raise ValueError(f"scene {self.scene.scene.name!r}: key '{key}': "
                             f"the bed reaches the platform at ping {i} (altitude "
                             f"{altitude:.2f} m)")
        return dataclasses.replace(nav, altitude_m=altitude)

    def frame(self, i: int) -> PingGeometry:
        """Projector, receivers and boresight of ping ``i`` in the tile frame (the bed
        frame over a sloping bed: :mod:`sim_device.bed_plane`)."""
        nav = self.pose(i)
        placed = place_array(self.geometry, nav, self.assembler.projector_of(i), self.line)
        if self.bed is None:
            return PingGeometry(placed.tx, placed.rx, placed.bore, placed.projector, nav)
        b = self.bed
        return PingGeometry(b.to_bed(placed.tx), b.to_bed(placed.rx),
                            b.vector_to_bed(placed.bore), placed.projector, nav)

    def _images(self, pos: np.ndarray,
                origin_xy: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Element-image rows (..., m_max + 1, 6) for element positions (..., 3) of the
        ping's frame, x and y made relative to ``origin_xy``."""
        depth = self.water_depth if self.water_depth is not None else 0.0
        rows = []
        for m in range(self.m_max + 1):
            li = leg_image(m)
            if self.bed is None:
                p = np.array(pos, dtype=np.float64)
                p[..., 2] = image_depth(m, pos[..., 2], depth)
            else:
                p = leg_image_position(m, pos, self.bed, depth)
            one = np.ones(p.shape[:-1])
            f_surf = self.env.surface_reflection ** li.n_surface
            rows.append(np.stack([p[..., 0] - origin_xy[0], p[..., 1] - origin_xy[1],
                                  -p[..., 2], li.direction * one, f_surf * one,
                                  li.n_bottom * one], axis=-1))
        return np.ascontiguousarray(np.stack(rows, axis=-2))

    # --------------------------------------------------------------- path choice
    def _choose_paths(self) -> np.ndarray:
        """allowed[m_tx, m_rx]: the multipath combinations synthesised
        (:func:`sim_device.path_choice.choose_paths`, at the first ping's geometry)."""
        g = self.frame(0)
        ts = float(np.max(np.abs(self.points.amp)) / self.p0) ** 2 if self.points.size else 0.0
        tr = self.scene.transducers
        back = (10.0 ** (tr.back_lobe_db / 20.0)
                if tr is not None and tr.back_lobe_db is not None else 0.0)
        allowed, self.path_levels_db = choose_paths(
            order=self.order, m_max=self.m_max, tx_z=float(g.tx[2]),
            rx_z=float(np.mean(g.rx[:, 2])), water_depth=self.water_depth,
            sigma=nadir_sigma(self.fidelity, self.env, self.top_sediment, self.fc),
            target_strength=ts, p0=self.p0, pulse_s=self.waveform.duration_s, env=self.env,
            r_bottom=abs(self.r_bot[0]) if self.env.has_seabed else 0.0, back_lobe=back,
            noise_power=self.noise_power, drop_db=self.drop_db)
        return allowed

    def _resolution_cell(self):
        """One ping's resolution cell at nadir (:func:`sim_device.fidelity.resolution_cell`)."""
        wf = self.hw.waveform
        g = self.frame(0)
        altitude = max(-float(np.mean(g.rx[:, 2])), 1e-3)
        c1 = self.media.c[1] if self.media.n > 1 else self.media.c[0]
        band = max(abs(wf.f_stop_hz - wf.f_start_hz), 1.0 / wf.duration_s)
        return resolution_cell(self.geometry.receivers, self.hw.receive_array.pitch_m,
                               band, self.fc, altitude,
                               self.env.water_sound_speed, float(c1))

    def _volume_limits(self) -> np.ndarray:
        """zmax[m_tx, m_rx] of :func:`sim_device.fidelity.volume_depth_limits` (at the
        first ping's geometry)."""
        sc = self.fidelity
        below = sc.volume_below_noise_db if sc is not None else None
        if below is None or not self.env.has_seabed or not sc.volume:
            return np.full(self.allowed.shape, np.inf)
        g = self.frame(0)
        tr = self.scene.transducers
        back = (10.0 ** (tr.back_lobe_db / 20.0)
                if tr is not None and tr.back_lobe_db is not None else 0.0)
        zmax, self.volume_levels_db = volume_depth_limits(
            allowed=self.allowed, tx_z=float(g.tx[2]), rx_z=float(np.mean(g.rx[:, 2])),
            water_depth=self.water_depth, env=self.env, media=self.media, fc=self.fc,
            p0=self.p0, pulse_s=self.waveform.duration_s, r_bottom=complex(self.r_bot[0]),
            back_lobe=back, noise_power=self.noise_power, below_noise_db=below,
            z_max=sc.volume_max_depth_m)
        return zmax

    # --------------------------------------------------------------- scatterers
    def scatterers(self, i: int, g: PingGeometry | None = None) -> Scatterers:
        """The seabed scatterers the projector can reach on ping ``i`` (before the beam
        and window tests of the kernels), plus the scene's points."""
        g = g if g is not None else self.frame(i)
        used = np.flatnonzero(self.allowed.any(axis=1))
        seabed = self.seabed.generate(g.tx, g.rx, g.bore, used, self.seed)
        if self.undulation is not None and seabed.size:
            # the interface and the volume below it follow the surface
            seabed.z = seabed.z + self.undulation.height(seabed.x, seabed.y)
        parts = [p for p in (self.points, seabed) if p.size]
        return Scatterers.concat(parts)

    # ---------------------------------------------------------------- synthesis
    def medium_bundle(self) -> Medium:
        """The synthesis kernels' :class:`~sim_device.synthesis_args.Medium`: the media at
        the carrier, the two-medium ray table, the interface's reflection tables and
        sigma^(1/4)."""
        m = self.media
        return Medium(m.c, m.rho, m.delta, m.alpha, m.z_top, self.table, self.r_top,
                      self.r_bot, self.sig)

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
        curved = self.undulation is not None
        f = np.float32 if self.precision == "float32" and not curved else np.float64
        cf = np.complex64 if self.precision == "float32" and not curved else np.complex128
        img_t = self._images(g.tx[None, :], (ox, oy))[0].astype(f)
        img_r = self._images(g.rx, (ox, oy)).astype(f)
        sx, sy, sz = (s.x - ox).astype(f), (s.y - oy).astype(f), s.z.astype(f)
        amp = s.amp.astype(cf)
        medium = self.medium_bundle()
        if curved:
            # the surface's rows in the ping-local frame, in the ray table's place
            medium = medium._replace(tab=self.undulation.shifted(ox, oy))
        t1 = time.perf_counter()
        pts = Points(sx, sy, sz, s.med)
        legs = TransmitLegs(np.empty((s.size, img_t.shape[0]), dtype=f),
                            np.empty((s.size, img_t.shape[0]), dtype=cf))
        if curved:
            curved_transmit_legs(pts, amp, img_t, medium, beam_of(self.tx_beam, g.bore), legs)
        else:
            transmit_legs(pts, amp, img_t, medium, beam_of(self.tx_beam, g.bore), legs,
                          fast=self.synthesis != "reference")
        seen = np.any(legs.amp != 0, axis=1)
        idx = np.flatnonzero(seen)
        t2 = time.perf_counter()
        # the deepest scatterer per path, finite: the fast kernels are compiled with
        # fastmath (no infinities); with the reference every limit is infinite (a finite
        # one is refused above), so it keeps every path to any depth
        zlim = np.minimum(self.zmax, np.finfo(np.float64).max)
        p2 = Pass2(Points(*(a[idx] for a in pts)), TransmitLegs(*(a[idx] for a in legs)),
                   Paths(img_r, self.allowed, zlim), medium, beam_of(self.rx_beam, g.bore),
                   self.pulses.window())
        if curved:
            buf = self.pulses.buffer(n_ch).astype(cf)
            counts = curved_accumulate(p2, buf)
        elif self.synthesis == "reference":
            buf = self.pulses.buffer(n_ch).astype(cf)
            counts = accumulate(p2, buf)
        elif self.gpu is not None:
            buf, counts = self.gpu(p2, self.pulses.n_buf)
        elif idx.size < SERIAL_BELOW:
            buf, counts = accumulate_fast_serial(p2, self.pulses.n_buf)
        else:
            buf, counts = accumulate_fast(p2, self.pulses.n_buf, 2 * numba.get_num_threads())
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
        if self.undulation is not None:
            # every stationary point of the curved interface (bed-frame rows: g is in
            # the bed frame, not ping-local)
            paths = curved_interface_paths(g.tx, g.rx, g.bore, m, self.water_depth,
                                           self.env.surface_reflection, self.sequences,
                                           self.tx_beam, self.rx_beam, rho, nu, d,
                                           self.undulation.rows, self.fc)
        else:
            paths = interface_paths(g.tx, g.rx, g.bore, m, self.water_depth,
                                    self.env.surface_reflection, self.sequences,
                                    self.tx_beam, self.rx_beam, rho, nu, d)
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
        return self.receiver_noise.series(self.seed, i, self.geometry.n_channels)

    def ping(self, i: int) -> Ping:
        """Ping ``i``: quantised samples with noise, and its true pose."""
        p = self.pressure(i) + self.noise(i)
        codes, clipped = quantise(p, self.hw.digitiser)
        if clipped:
            log.warning("ping %d: %d samples clipped at full scale", i, clipped)
        return self.assembler.from_simulation(i, codes, self.pose(i))

    def __iter__(self):
        for i in range(self.n_pings):
            yield self.ping(i)
