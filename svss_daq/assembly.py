"""Instrument data to pings, once: every :class:`~svss_daq.ping.Ping` in the system is
built here, from the hardware (the digitiser's complete ping, the sequencer's transmit
record and the navigation solution) or from the simulator (samples and a true pose).

The sample time axis is the ping's (:attr:`Ping.sample_axis`); :func:`acoustic_axis`
turns it into the arrival times of the pressure the samples hold, for the conditioner
and the simulator alike.
"""

from __future__ import annotations

import numpy as np

from .config import Digitiser, HardwareConfig, Loaded
from .ping import NavSnapshot, Ping, SampleAxis
from .protocols.digitiser import CompletePing
from .protocols.sequencer import PingEvent


class AssemblyError(ValueError):
    """Instrument records that do not make one ping (the message names the field)."""


def acoustic_axis(axis: SampleAxis, digitiser: Digitiser) -> SampleAxis:
    """Arrival times of the pressure held by samples taken on ``axis``: each sample
    holds what reached the hydrophone one group delay before it was taken."""
    return axis.shifted(-digitiser.group_delay_s)


class PingAssembler:
    """Builds the pings of one hardware configuration."""

    def __init__(self, hardware: Loaded[HardwareConfig]):
        self.hardware = hardware
        hw = hardware.value
        self.digitiser = hw.digitiser
        self.projector_order = tuple(hw.sequencer.projector_order)
        self.n_projectors = len(hw.projectors.positions_m)
        self.window_start_ns = int(round(hw.digitiser.window_start_s * 1e9))

    @property
    def sample_axis(self) -> SampleAxis:
        """The configured sample axis of every ping (s after transmit)."""
        dig = self.digitiser
        return SampleAxis(self.window_start_ns * 1e-9, 1.0 / dig.sample_rate_hz,
                          dig.window_samples)

    def projector_of(self, sequence: int) -> int:
        """The projector the schedule fires on ping ``sequence``."""
        return self.projector_order[sequence % len(self.projector_order)]

    def build(self, sequence: int, projector: int, transmit_time_ns: int,
              window_start_ns: int, samples: np.ndarray, nav: NavSnapshot) -> Ping:
        """The one ping constructor: checks the samples against the configuration."""
        dig = self.digitiser
        where = f"ping {sequence}"
        samples = np.asarray(samples)
        if samples.ndim != 2 or samples.shape[0] != dig.n_channels:
            raise AssemblyError(f"{where}: samples have shape {samples.shape}, expected "
                                f"({dig.n_channels}, n) for the configured digitiser")
        if not np.issubdtype(samples.dtype, np.integer):
            raise AssemblyError(f"{where}: samples are {samples.dtype}, expected integer "
                                "ADC codes")
        if not 0 <= projector < self.n_projectors:
            raise AssemblyError(f"{where}: projector {projector}, expected "
                                f"0..{self.n_projectors - 1}")
        return Ping(sequence=int(sequence), projector=int(projector),
                    transmit_time_ns=int(transmit_time_ns),
                    sample_rate_hz=float(dig.sample_rate_hz),
                    window_start_ns=int(window_start_ns),
                    samples=samples.astype(np.int32, copy=False), nav=nav,
                    config_id=self.hardware.id)

    def from_instrument(self, data: CompletePing, transmit: PingEvent,
                        nav: NavSnapshot) -> Ping:
        """A recorded ping from the digitiser's complete ping, the sequencer's record of
        the same transmission and the navigation solution at its transmit time. The
        sequencer's transmit time and sequence are authoritative; the digitiser's must
        agree with them."""
        if data.ping_number != transmit.sequence:
            raise AssemblyError(f"digitiser ping {data.ping_number} paired with sequencer "
                                f"ping {transmit.sequence}: field 'sequence' differs")
        if data.transmit_time_ns != transmit.transmit_time_ns:
            raise AssemblyError(
                f"ping {transmit.sequence}: field 'transmit_time_ns' is "
                f"{data.transmit_time_ns} at the digitiser and {transmit.transmit_time_ns} "
                "at the sequencer")
        window_start = data.first_sample_time_ns - data.transmit_time_ns
        if window_start < 0:
            raise AssemblyError(f"ping {transmit.sequence}: field 'first_sample_time_ns' "
                                "is before the transmit time")
        return self.build(transmit.sequence, transmit.projector, transmit.transmit_time_ns,
                          window_start, data.samples, nav)

    def from_simulation(self, sequence: int, samples: np.ndarray, nav: NavSnapshot) -> Ping:
        """A simulated ping: transmitted at ``nav.time_ns`` on the scheduled projector,
        sampled on the configured window."""
        return self.build(sequence, self.projector_of(sequence), nav.time_ns,
                          self.window_start_ns, samples, nav)
