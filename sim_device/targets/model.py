"""A scene target as a scattering amplitude for given directions at the target.

:class:`SceneTarget` turns one ``[[targets]]`` entry of a scene (kind, material, size,
centre, orientation) into ``amplitude(freq, k_in, k_out)``: the complex far-field
amplitude f (m, physics convention exp(-i omega t), phase referenced to the centre) for
incident and scattered directions of travel at the target, in the host medium that
holds the centre (water, or a sediment treated as a fluid, as TIER does).

* sphere: the exact bistatic modal series f(theta), coefficients cached per frequency
  grid (they depend on frequency only);
* cylinder: the monostatic finite-cylinder model along the bisector of the directions
  to projector and receiver, at Kell's frequency f cos(beta/2) or at f
  (:mod:`.bistatic`); the infinite-cylinder form T is either summed for every projected
  frequency ("exact") or read from a table over projected frequency with a given step
  (linear interpolation of the complex values), built once per target;
* shell: the exact shell series (:mod:`.shells`), empty or filled, used like a sphere's;
* disc (flat rock): the bistatic Kirchhoff disc, its face a half-space or, with a
  thickness, an elastic plate (slab) in the host fluid.

Orientation (tile frame: x along-track, y starboard, z down): a cylinder's axis is
(cos t cos h, cos t sin h, sin t) for heading h from along-track and tilt t (positive
dips the +axis end downwards); a disc's normal is the upward vertical tilted by t
towards heading h: (sin t cos h, sin t sin h, -cos t).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from ._series import DEFAULT_TOL, complex_matmul, legendre_table
from .bistatic import angle_between, bistatic_from_directions
from .cylinders import _MIN_KA, cylinder_backscatter_at, infinite_cylinder_form
from .materials import ElasticMaterial, Fluid
from .rocks import disc_scattering_amplitude
from .shells import VACUUM, shell_modal_series
from .spheres import sphere_modal_series

KINDS = ("sphere", "cylinder", "disc", "shell")
#: a cut form table is read on a grid this many times finer than its step
CUT_FINER = 4


def _deg(x) -> float:
    return math.radians(float(x or 0.0))


class FormTable:
    """T(pi) of an infinite cylinder on a uniform grid of projected frequency (Hz),
    read by linear interpolation of the complex values; grows to cover requests."""

    def __init__(self, radius: float, host: Fluid, material, step_hz: float, tol: float):
        self.radius, self.host, self.material = radius, host, material
        self.step = float(step_hz)
        self.tol = tol
        self.f_min = _MIN_KA * host.sound_speed / (2.0 * math.pi * radius)
        self.f = np.zeros(0)
        self.t = np.zeros(0, dtype=complex)

    @property
    def pre(self) -> float:
        """Projected time (s) by which T's impulse response may precede the axis' echo."""
        return 2.0 * self.radius / self.host.sound_speed + 2e-4

    def _build(self, f_hi: float) -> None:
        n = int(math.ceil((f_hi - self.f_min) / self.step)) + 2
        n = sfft.next_fast_len(2 * (n - 1), real=True) // 2 + 1   # a fast cut FFT
        self.f = self.f_min + self.step * np.arange(n)
        self.t = infinite_cylinder_form(self.f, self.radius, self.host, self.material,
                                        tol=self.tol)

    def ensure(self, f_hi: float) -> None:
        """Cover projected frequencies up to ``f_hi`` (Hz)."""
        if self.f.size == 0 or f_hi > self.f[-1]:
            self._build(f_hi * 1.05)

    def cut(self, cut_s: float):
        """The table with its impulse response (over projected frequency, period 1/step)
        cut ``cut_s`` (s, projected time) after the axis' echo by a raised-cosine taper
        (:data:`.ringing.RING_TAPER_S`; the front tapered likewise before -pre), as a
        callable like the table; see
        :class:`.ringing.CylinderRinging`.  The grid starts at f_min ~ 0 and is treated
        as k * step (the shift f_min is a phase ramp of < 1e-6 rad over the cut)."""
        from .ringing import RING_TAPER_S, cut_window
        t = self.t
        n_t = 2 * (t.size - 1)
        fs = n_t * self.step
        h = sfft.irfft(np.conj(t), n_t)
        tt = np.arange(n_t) / fs
        tt[tt > n_t / fs - self.pre - RING_TAPER_S] -= n_t / fs
        # the cut response is short: its spectrum on a grid CUT_FINER times finer
        # (exact, by zero-padding in time) is read by linear interpolation with images
        # CUT_FINER^4 weaker in energy than on the table's own step
        hw = h * cut_window(tt, cut_s, t_front=-self.pre)
        neg = int(np.count_nonzero(tt < 0))
        z = np.zeros(CUT_FINER * n_t)
        z[:n_t - neg] = hw[:n_t - neg]
        z[z.size - neg:] = hw[n_t - neg:]
        tc = np.conj(sfft.rfft(z))[: CUT_FINER * (t.size - 1) + 1]
        f = self.f_min + (self.step / CUT_FINER) * np.arange(tc.size)
        return lambda fp: np.interp(fp, f, tc.real) + 1j * np.interp(fp, f, tc.imag)

    def __call__(self, f_proj: np.ndarray) -> np.ndarray:
        self.ensure(float(np.max(f_proj)))
        return np.interp(f_proj, self.f, self.t.real) + 1j * np.interp(f_proj, self.f,
                                                                       self.t.imag)


class SceneTarget:
    """One target of a scene (tile frame; see the module docstring).

    ``cfg``: a :class:`sim_device.scene.TargetConfig`; ``host``: the fluid holding the
    centre; ``medium``: its index (0 water); ``freq_step_hz``: cylinder form-table step
    (0: exact series); ``bistatic``: "kell" or "bisector"; ``fill``: a shell's fill
    (a :class:`Fluid` or "vacuum")."""

    def __init__(self, cfg, material: ElasticMaterial, host: Fluid, medium: int,
                 tol: float = DEFAULT_TOL, freq_step_hz: float = 0.0,
                 bistatic: str = "kell", index: int = 0, fill=VACUUM):
        if cfg.kind not in KINDS:
            raise ValueError(f"targets[{index}].kind: expected one of {KINDS}, "
                             f"got {cfg.kind!r}")
        self.cfg = cfg
        self.index = index
        self.kind = cfg.kind
        self.material = material
        self.host = host
        self.medium = int(medium)
        self.tol = float(tol)
        self.bistatic = bistatic
        self.radius = float(cfg.radius_m)
        self.length = float(cfg.length_m) if cfg.length_m is not None else 0.0
        thick = getattr(cfg, "thickness_m", None)
        self.thickness = float(thick) if thick is not None else None
        self.fill = fill
        self.position = np.array([cfg.along_m, cfg.cross_m, cfg.depth_m], dtype=np.float64)
        h, t = _deg(cfg.axis_heading_deg), _deg(cfg.axis_tilt_deg)
        if self.kind == "disc":
            self.axis = np.array([math.sin(t) * math.cos(h), math.sin(t) * math.sin(h),
                                  -math.cos(t)])
        else:
            self.axis = np.array([math.cos(t) * math.cos(h), math.cos(t) * math.sin(h),
                                  math.sin(t)])
        #: radius of a sphere holding the whole target (m)
        self.extent = math.hypot(self.radius, 0.5 * self.length)
        self._form = (FormTable(self.radius, host, material, freq_step_hz, self.tol)
                      if self.kind == "cylinder" and freq_step_hz > 0 else None)
        self._series_key = None
        self._series = None
        #: modal-series evaluations so far (frequencies x terms summed), for the stats
        self.evaluations = 0

    def series(self, freq: np.ndarray):
        """The modal series (a :class:`.spheres.SphereSeries`) of a sphere or shell."""
        if self.kind == "shell":
            return shell_modal_series(freq, self.radius, self.thickness, self.host,
                                      self.material, self.fill, tol=self.tol)
        return sphere_modal_series(freq, self.radius, self.host, self.material,
                                   tol=self.tol)

    def _sphere(self, freq: np.ndarray):
        key = freq.tobytes()
        if key != self._series_key:
            self._series = self.series(freq)
            self._series_key = key
        return self._series

    def _cylinder_geometry(self, k_in, k_out):
        geo = bistatic_from_directions(k_in, k_out)
        psi = angle_between(geo.bisector, self.axis)
        scale = np.cos(0.5 * geo.bistatic_angle) if self.bistatic == "kell" else 1.0
        return psi, np.broadcast_to(scale, psi.shape)

    def cylinder_scales(self, k_in: np.ndarray, k_out: np.ndarray):
        """(s, b) per path of a cylinder: projected frequency = s x frequency
        (s = scale sin psi), and the half-length (s) of the box the sinc of its length
        convolves with (scale L |cos psi| / c)."""
        psi, scale = self._cylinder_geometry(np.asarray(k_in, float).reshape(-1, 3),
                                             np.asarray(k_out, float).reshape(-1, 3))
        return (scale * np.abs(np.sin(psi)),
                scale * self.length * np.abs(np.cos(psi)) / self.host.sound_speed)

    def amplitude(self, freq: np.ndarray, k_in: np.ndarray, k_out: np.ndarray,
                  form=None) -> np.ndarray:
        """f (m, complex; shape (M, F)) at frequencies ``freq`` (F,) Hz for unit
        directions of travel ``k_in`` (M, 3) (towards the target) and ``k_out`` (M, 3)
        (away from it); ``form``: a cylinder's T(projected frequency), replacing its
        table (a cut one, :class:`.ringing.CylinderRinging`)."""
        freq = np.asarray(freq, dtype=np.float64)
        k_in = np.asarray(k_in, dtype=np.float64).reshape(-1, 3)
        k_out = np.asarray(k_out, dtype=np.float64).reshape(-1, 3)
        self.evaluations += freq.size * k_in.shape[0]
        if self.kind in ("sphere", "shell"):
            s = self._sphere(freq)
            mu = np.clip(np.sum(k_in * k_out, axis=1), -1.0, 1.0)     # cos(theta)
            p = legendre_table(s.coefficients.shape[1], mu)
            return ((-1j / s.k)[:, None] * complex_matmul(s.coefficients, p)).T
        if self.kind == "disc":
            return disc_scattering_amplitude(freq, self.radius, self.host, k_in, k_out,
                                             self.axis, self.material,
                                             thickness=self.thickness).T
        psi, scale = self._cylinder_geometry(k_in, k_out)
        f_eq = np.multiply.outer(scale, freq)
        return cylinder_backscatter_at(f_eq, psi[:, None], self.radius, self.length,
                                       self.host, self.material, tol=self.tol,
                                       form=self._form if form is None else form)

    def reference_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Incident and scattered directions (1, 3) of the target's brightest monostatic
        view: a disc at normal incidence, a cylinder at broadside (from above where the
        axis allows), a sphere or shell from above."""
        if self.kind == "disc":
            k_in = -self.axis
        elif self.kind == "cylinder":
            down = np.array([0.0, 0.0, 1.0])
            k_in = down - (down @ self.axis) * self.axis
            if np.linalg.norm(k_in) < 1e-6:               # vertical axis: from the side
                k_in = np.array([1.0, 0.0, 0.0])
            k_in = k_in / np.linalg.norm(k_in)
        else:
            k_in = np.array([0.0, 0.0, 1.0])
        return k_in[None, :], -k_in[None, :]
