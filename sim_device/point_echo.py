"""First echo source: point scatterers in a homogeneous, lossless medium.

For every projector-receiver pair the echo of scatterer k is

    p(t) = p0 * 10^(TS_k/20) / (r1 r2) * s(t - tau_k),    tau_k = (r1 + r2) / c,

with p0 the source level as a pressure at 1 m, r1 and r2 the projector-to-scatterer and
scatterer-to-receiver ranges, and s the transmit pulse evaluated exactly at the
fractional delay. Elements only see scatterers inside their beam cones (hard cones). The
digitiser samples p at t_n - g (g its group delay) and adds white electronic noise
seeded per ping, so any ping can be made alone and is the same whatever the order.
"""

from __future__ import annotations

import numpy as np

from svss_daq.config import HardwareConfig, Loaded
from svss_daq.frames import body_to_ned
from svss_daq.geometry import array_geometry
from svss_daq.ping import Ping
from svss_daq.scaling import counts_per_upa, quantise
from svss_daq.waveform import make_waveform

from .scene import SceneConfig
from .track import ping_pose, truth_line


class PointEchoSource:
    """Synthesises the pings of a scene of point scatterers, one at a time."""

    def __init__(self, hardware: Loaded[HardwareConfig], scene: SceneConfig):
        self.hardware = hardware
        self.hw = hw = hardware.value
        self.scene = scene
        self.geometry = array_geometry(hw)
        self.waveform = make_waveform(hw.waveform)
        self.line = truth_line(scene.track)
        pts = np.array([[p.along_m, p.cross_m, p.depth_m] for p in scene.points],
                       dtype=np.float64).reshape(-1, 3)
        self.targets_ned = self.line.tile_to_ned(pts)
        self.target_amplitude = 10.0 ** (np.array([p.target_strength_db for p in scene.points])
                                         / 20.0)
        self.p0_upa = 10.0 ** (hw.waveform.source_level_db / 20.0)

    @property
    def n_pings(self) -> int:
        return self.scene.track.n_pings

    def pressure(self, i: int) -> np.ndarray:
        """Noise-free acoustic pressure (uPa) at every hydrophone for ping ``i``,
        sampled on the digitiser's grid: (n_channels, n_samples) float64."""
        hw, geo = self.hw, self.geometry
        dig = hw.digitiser
        nav = ping_pose(self.scene.track, hw, i)
        rot = body_to_ned(nav.roll_rad, nav.pitch_rad, nav.heading_rad)
        proj = hw.sequencer.projector_order[i % len(hw.sequencer.projector_order)]
        tx = nav.ned + rot @ geo.projectors[proj]
        rx = nav.ned + geo.receivers @ rot.T
        bore = rot @ geo.boresight
        c = self.scene.medium.sound_speed_m_s
        fs = dig.sample_rate_hz
        t = dig.window_start_s - dig.group_delay_s + np.arange(dig.window_samples) / fs
        out = np.zeros((geo.n_channels, dig.window_samples))
        n_pulse = int(np.ceil(self.waveform.duration_s * fs)) + 2
        for tgt, amp in zip(self.targets_ned, self.target_amplitude):
            d1 = tgt - tx
            r1 = np.linalg.norm(d1)
            if d1 @ bore < r1 * np.cos(geo.projector_half_angle):
                continue
            d2 = tgt - rx                                    # receiver -> target
            r2 = np.linalg.norm(d2, axis=1)
            seen = d2 @ bore >= r2 * np.cos(geo.receiver_half_angle)
            tau = (r1 + r2) / c
            a = self.p0_upa * amp / (r1 * r2)
            for ch in np.flatnonzero(seen):
                n0 = max(int(np.floor((tau[ch] - t[0]) * fs)), 0)
                n1 = min(n0 + n_pulse, t.size)
                if n0 >= n1:
                    continue
                out[ch, n0:n1] += a[ch] * self.waveform.real(t[n0:n1] - tau[ch])
        return out

    def ping(self, i: int) -> Ping:
        """Ping ``i``: quantised samples with electronic noise, and its true pose."""
        hw = self.hw
        dig = hw.digitiser
        p = self.pressure(i)
        rng = np.random.default_rng([self.scene.scene.seed, i])
        noise = self.scene.noise.electronic_rms_counts
        if noise > 0:
            p = p + rng.normal(0.0, noise / counts_per_upa(dig), p.shape)
        codes, _ = quantise(p, dig)
        nav = ping_pose(self.scene.track, hw, i)
        proj = hw.sequencer.projector_order[i % len(hw.sequencer.projector_order)]
        return Ping(sequence=i, projector=proj, transmit_time_ns=nav.time_ns,
                    sample_rate_hz=dig.sample_rate_hz,
                    window_start_ns=int(round(dig.window_start_s * 1e9)), samples=codes,
                    nav=nav, config_id=self.hardware.id)

    def __iter__(self):
        for i in range(self.n_pings):
            yield self.ping(i)
