"""The sequencer driver's transmit-record queue over a real pseudo-terminal to the
sequencer emulator: with a callback (as the acquisition daemon takes them) nothing is
queued; without one the queue holds at most devices.toml's ``queue_records``, the rest
dropped, counted and logged once per power of 10."""

from __future__ import annotations

import logging
import sys
import time

import pytest

from sim_device.devices import SequencerEmulator
from svss_daq.config import DevicesConfig, config_path, load
from svss_daq.drivers.sequencer import SequencerDriver
from svss_daq.protocols import sequencer as sq

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")
WAIT_S = 10.0


def _send_events(emu, n):
    for k in range(n):
        emu.write(sq.encode(sq.PingEvent(k, k % 6, 1_000_000 * k)))


def _wait_for(pred, what):
    deadline = time.monotonic() + WAIT_S
    while not pred():
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def test_records_handed_to_a_callback_are_not_also_queued():
    """The daemon hands every record to a callback and never reads the queue: it grew
    to 100000 records (a survey's first 2.8 h at 10 pings/s), then every ping warned."""
    got = []
    emu = SequencerEmulator().start()
    cfg = load(DevicesConfig, config_path("devices.toml")).sequencer
    drv = SequencerDriver.from_config(
        type(cfg)(**{**cfg.__dict__, "port": emu.port}), on_ping=got.append)
    try:
        drv.open(timeout_s=WAIT_S)
        _send_events(emu, 50)
        _wait_for(lambda: len(got) == 50, "the records")
    finally:
        drv.close()
        emu.close()
    assert [e.sequence for e in got] == list(range(50))
    assert drv.ping_queue is None or drv.ping_queue.qsize() == 0


def test_a_full_queue_drops_counts_and_logs_at_powers_of_ten(caplog):
    emu = SequencerEmulator().start()
    drv = SequencerDriver(emu.port, queue_records=5)
    try:
        drv.open(timeout_s=WAIT_S)
        with caplog.at_level(logging.WARNING, "svss_daq.drivers.sequencer"):
            _send_events(emu, 16)
            _wait_for(lambda: drv.dropped == 11, "the drops")
    finally:
        drv.close()
        emu.close()
    assert [drv.ping_queue.get_nowait().sequence for _ in range(5)] == list(range(5))
    lines = [r.getMessage() for r in caplog.records if "queue full" in r.getMessage()]
    assert len(lines) == 2 and "(1 in all" in lines[0] and "(10 in all" in lines[1], lines
