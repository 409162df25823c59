"""The ping: one transmission and the 80 channels it was received on."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

#: quality flags of a navigation snapshot (bit mask)
NAV_GPS_FIX = 1          # position from a GNSS fix at or near this time
NAV_DEAD_RECKONED = 2    # position propagated by DVL dead reckoning
NAV_BOTTOM_LOCK = 4      # altitude from DVL bottom track
NAV_SIMULATED = 8        # produced by the simulator (truth)
NAV_HEADING_FROM_COURSE = 16   # heading is the GPS course over ground (no HDT in time)
NAV_NO_HEADING = 32      # no heading at all (heading 0 used, lever arms unreliable)
NAV_HEADING_FROM_COMPASS = 64  # heading is the DVL's magnetic compass (no HDT or course in time)
NAV_HELD = 128           # past the last navigation record: the pose is extrapolated (held)
NAV_CLOCK_RETIMED = 256  # an instrument's clock disagreed with the ping clock: its records
                         # were placed on the ping clock by their receive times
NAV_SMOOTHED = 512       # from the smoother over the whole recording (re-navigation);
                         # without it a live pose (causal fixed-lag smoother)
NAV_FUSED = 1024         # position from the DVL/GPS Kalman fusion (not GPS interpolation)
NAV_DVL_VELOCITY = 2048  # the DVL's bottom-track velocity carried the track here (a valid
                         # velocity within dvl_max_gap_s); NAV_BOTTOM_LOCK alone is the
                         # altitude, which ranges give without a velocity


@dataclass(frozen=True)
class NavSnapshot:
    """Pose of the body origin at a ping's transmit time.

    Positions in the survey frame (local NED, m); velocity NED (m/s); attitude (rad,
    ZYX Euler: heading from north, pitch nose-up positive, roll starboard-down positive);
    altitude of the body origin above the water-sediment interface (m); geodetic
    position (deg, NaN when unknown); ``quality``: NAV_* bit flags.
    """
    time_ns: int
    north_m: float
    east_m: float
    down_m: float
    vel_north_m_s: float
    vel_east_m_s: float
    vel_down_m_s: float
    roll_rad: float
    pitch_rad: float
    heading_rad: float
    altitude_m: float
    latitude_deg: float = float("nan")
    longitude_deg: float = float("nan")
    quality: int = 0

    @property
    def ned(self) -> np.ndarray:
        return np.array([self.north_m, self.east_m, self.down_m])

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "NavSnapshot":
        names = [f.name for f in dataclasses.fields(cls)]
        missing = [n for n in names if n not in d]
        if missing:
            raise ValueError(f"navigation snapshot: missing field '{missing[0]}'")
        unknown = sorted(set(d) - set(names))
        if unknown:
            raise ValueError(f"navigation snapshot: unknown field '{unknown[0]}'")
        out = {}
        for f in dataclasses.fields(cls):
            v = d[f.name]
            want = int if f.type in ("int", int) else float
            ok = not isinstance(v, bool) and isinstance(
                v, int if want is int else (int, float))
            if ok and want is int:
                ok = -2**63 <= v < 2**63                  # fits the int64 of the raw file
            elif ok and isinstance(v, int):
                ok = abs(v) <= 2**1023                    # converts to a float
            if not ok:
                shown = repr(v) if len(repr(v)) <= 80 else repr(v)[:60] + "..."
                raise ValueError(f"navigation snapshot: field '{f.name}' expected "
                                 f"{want.__name__}{' (int64)' if want is int else ''}, "
                                 f"got {shown}")
            out[f.name] = want(v)
        return cls(**out)


NAV_FIELDS = tuple(f.name for f in dataclasses.fields(NavSnapshot))


@dataclass(frozen=True)
class SampleAxis:
    """A uniform time axis: sample n at ``start_s + n * step_s`` (s after transmit)."""
    start_s: float
    step_s: float
    n: int

    def times(self) -> np.ndarray:
        """The sample times, s (float64)."""
        return self.start_s + self.step_s * np.arange(self.n)

    @property
    def end_s(self) -> float:
        """Time just past the last sample, s."""
        return self.start_s + self.step_s * self.n

    def shifted(self, by_s: float) -> "SampleAxis":
        """The same samples, every time moved by ``by_s``."""
        return SampleAxis(self.start_s + by_s, self.step_s, self.n)


@dataclass(frozen=True, eq=False)
class Ping:
    """One ping.

    ``samples``: (n_channels, n_samples) int32 ADC codes (24-bit in int32), real passband;
    the first sample is taken ``window_start_ns`` after the transmit time.
    ``config_id``: identity of the hardware configuration the ping was acquired with.
    """
    sequence: int
    projector: int
    transmit_time_ns: int
    sample_rate_hz: float
    window_start_ns: int
    samples: np.ndarray
    nav: NavSnapshot
    config_id: str = ""
    #: what is wrong with a ping read back damaged (its samples failed their checksum:
    #: zeros in their place); None for a sound ping. Every gate refuses a damaged ping
    #: (:func:`svss_daq.ping_gate.ping_problem`)
    damage: str | None = None

    def __post_init__(self):
        if self.samples.ndim != 2:
            raise ValueError(f"ping {self.sequence}: samples must be (channels, samples), "
                             f"got shape {self.samples.shape}")

    @property
    def sample_axis(self) -> SampleAxis:
        """When each sample was taken, s after transmit: ``window_start + n / fs``. The
        acoustic arrival time of a sample is this minus the digitiser's group delay
        (:func:`svss_daq.assembly.acoustic_axis`)."""
        return SampleAxis(self.window_start_ns * 1e-9, 1.0 / self.sample_rate_hz,
                          self.samples.shape[1])

    @property
    def n_channels(self) -> int:
        return self.samples.shape[0]

    @property
    def n_samples(self) -> int:
        return self.samples.shape[1]
