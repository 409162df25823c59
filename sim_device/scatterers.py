"""Point scatterers of one ping: the scene's points and the PoSSM seabed cells that the
projector's cone (and its multipath images) can reach.

Scatterers are generated per ping from the scene seed and the cell indices
(:mod:`sim_device.possm`), so any ping, in any order, sees the same seabed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import possm
from .environment import Environment
from .multipath import image_depth
from .scene import SceneConfig
from .synthesis_args import MED_INTERFACE


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
        if not parts:
            return empty_scatterers()
        return Scatterers(*(np.concatenate([getattr(p, f) for p in parts])
                            for f in ("x", "y", "z", "med", "amp")))


def empty_scatterers() -> Scatterers:
    z = np.zeros(0)
    return Scatterers(z, z, z, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=complex))


def scene_points(scene: SceneConfig, env: Environment, p0: float,
                 bed=None, undulation=None) -> Scatterers:
    """The scene's point scatterers, strength p0 * 10^(TS/20); over a sloping ``bed``
    (a :class:`~sim_device.bed_plane.BedPlane`) in its frame, each ``depth_m``
    vertically below the interface above it; with an ``undulation``
    (:class:`~sim_device.bed_undulation.Undulation`) below the undulating surface."""
    pts = scene.points
    if not pts:
        return empty_scatterers()
    atd = np.array([[p.along_m, p.cross_m, p.depth_m] for p in pts], dtype=np.float64)
    if bed is not None:
        atd = bed.buried(atd[:, 0], atd[:, 1], atd[:, 2])
    med = np.array([env.medium_at(float(z)) for z in atd[:, 2]], dtype=np.int64)
    if undulation is not None:
        atd[:, 2] += undulation.height(atd[:, 0], atd[:, 1])
    amp = p0 * 10.0 ** (np.array([p.target_strength_db for p in pts]) / 20.0)
    return Scatterers(atd[:, 0].copy(), atd[:, 1].copy(), atd[:, 2].copy(), med,
                      amp.astype(complex))


class SeabedScatterers:
    """PoSSM interface and volume scatterers inside a ping's reach.

    ``beam_edge``: the projector beam's edge angle (rad); ``t_hi``: the latest two-way
    time that can reach the receive window (s); ``water_depth``: surface to interface
    (m, None without a surface) for the multipath images; ``p0``: source level (uPa at
    1 m)."""

    def __init__(self, scene: SceneConfig, env: Environment, fc: float, p0: float,
                 beam_edge: float, t_hi: float, water_depth: float | None,
                 densities: tuple[float, float] | None = None):
        self.fidelity = scene.scattering
        sc = self.fidelity
        #: (interface per m^2, volume per m^3): the scene's, or ``densities`` (the
        #: resolution-cell option of :mod:`sim_device.fidelity`)
        self.densities = (densities if densities is not None else
                          (sc.interface_density_per_m2, sc.volume_density_per_m3)
                          if sc is not None else (0.0, 0.0))
        #: deepest volume scatterer generated (m; the level cut-off, if any)
        self.z_cut = math.inf
        self.env = env
        self.media = env.media(fc)
        self.p0 = p0
        self.beam_edge = beam_edge
        self.t_hi = t_hi
        self.water_depth = water_depth
        self.sigma_v = np.array([0.0] + [ly.sediment.volume_scattering_coefficient(fc)
                                         for ly in env.layers])

    def reach(self, tx: np.ndarray, bore: np.ndarray, image_orders: np.ndarray):
        """Horizontal reach (m) of the projector's cones at a depth, over the projector
        images ``image_orders`` that are synthesised."""
        tilt = math.acos(max(-1.0, min(1.0, abs(float(bore[2])))))
        angle = self.beam_edge + tilt
        depth = self.water_depth if self.water_depth is not None else 0.0
        h = max(-float(image_depth(int(m), tx[2], depth)) for m in image_orders)
        limit = float(self.media.c.max()) * self.t_hi
        c, z_top = self.media.c, self.media.z_top
        return lambda z: possm.cone_reach(np.asarray(z), h, angle, c, z_top, limit)

    def depth_limit(self, tx: np.ndarray, rx: np.ndarray) -> float:
        """Deepest volume scatterer: the scene's cut-off, or where even the vertical
        two-way path leaves the receive window."""
        zmax = min(self.fidelity.volume_max_depth_m, self.z_cut)
        c, z_top = self.media.c, self.media.z_top
        h_t = -tx[2]
        h_r = float(np.min(-rx[:, 2]))
        z = np.linspace(0.0, zmax, 2001)
        t = (h_t + h_r) / c[0] + np.zeros_like(z)
        for i in range(1, c.size):
            bot = z_top[i + 1] if i + 1 < c.size else np.inf
            t += 2.0 * (np.clip(z, z_top[i], bot) - z_top[i]) / c[i]
        inside = z[t < self.t_hi]
        return float(inside[-1]) if inside.size else 0.0

    def generate(self, tx: np.ndarray, rx: np.ndarray, bore: np.ndarray,
                 image_orders: np.ndarray, seed: int) -> Scatterers:
        """The seabed scatterers the projector can reach (before the beam and window
        tests of the synthesis kernels)."""
        sc = self.fidelity
        if sc is None or not self.env.has_seabed:
            return empty_scatterers()
        reach = self.reach(tx, bore, image_orders)
        cell = sc.cell_m
        parts = []
        if sc.interface:
            cells = possm.interface_cells(tx[0], tx[1], float(reach(0.0)[0]), cell)
            n_per = possm.scatterers_per_cell(self.densities[0], cell * cell)
            s = self._cells(cells, possm.KIND_INTERFACE, n_per, cell, seed)
            s.amp *= self.p0 * math.sqrt(cell * cell / n_per)
            s.med[:] = MED_INTERFACE
            parts.append(s)
        if sc.volume:
            zmax = self.depth_limit(tx, rx)
            cells = possm.volume_cells(tx[0], tx[1], lambda z: reach(z)[0], zmax, cell)
            n_per = possm.scatterers_per_cell(self.densities[1], cell ** 3)
            s = self._cells(cells, possm.KIND_VOLUME, n_per, cell, seed)
            s = s.take(s.z <= zmax)
            s.med = np.searchsorted(self.media.z_top[1:], s.z, side="right").astype(np.int64)
            s.amp *= self.p0 * np.sqrt(self.sigma_v[s.med] * cell ** 3 / n_per)
            parts.append(s)
        return Scatterers.concat(parts)

    @staticmethod
    def _cells(cells: np.ndarray, kind: int, n_per: int, cell: float,
               seed: int) -> Scatterers:
        n = cells.shape[0] * n_per
        x, y, z = np.empty(n), np.empty(n), np.empty(n)
        xi = np.empty(n, dtype=np.complex128)
        if n:
            possm.generate_cells(cells, kind, n_per, cell, cell, seed, x, y, z, xi)
        return Scatterers(x, y, z, np.zeros(n, dtype=np.int64), xi)
