"""Simulated device ends speaking this project's wire protocols, for tests and
hardware-in-the-loop runs: a transmit sequencer on a pseudo-terminal and a digitiser
TCP server on loopback. See ``docs/protocols.md``."""

from sim_device.devices.digitiser import DigitiserEmulator
from sim_device.devices.sequencer import SequencerEmulator

__all__ = ["DigitiserEmulator", "SequencerEmulator"]
