"""A late ping of the simulated device's worker pool (issue 27, item 10): its synthesis,
dropped when the sequencer moves past it, is counted late by the device without a
`CancelledError` traceback logged at ERROR (one per late ping under load)."""

from __future__ import annotations

import logging
import threading
import time

from sim_device.ping_sources import PoolSynthesis
from svss_daq.config import HardwareConfig, config_path, load_with_text

#: pings synthesised ahead: the last is queued behind the others (each tens of ms), so
#: that it is still waiting for a worker when the next ping drops it
AHEAD = 30


def test_a_dropped_synthesis_is_a_late_ping_not_an_error(caplog):
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    interval = round(hw.value.sequencer.ping_interval_s * 1e9)
    src = PoolSynthesis(hw, config_path("scenes/demo.toml"), workers=1, lookahead=AHEAD)
    try:
        src.start(0, interval)
        src.want(0)                              # pings 0..AHEAD in flight
        fut = src._futures[AHEAD]
        got: list = []
        waiter = threading.Thread(target=lambda: got.append(src.get(AHEAD, 60.0)))
        with caplog.at_level(logging.DEBUG, logger="sim_device"):
            waiter.start()
            deadline = time.monotonic() + 30       # the sender waits on the ping's result
            while not fut._condition._waiters and time.monotonic() < deadline:
                time.sleep(0.001)
            assert fut._condition._waiters, "the waiter never waited"
            src.want(AHEAD + 1)                      # the sequencer's next ping drops it
            waiter.join(60)
        assert fut.cancelled(), "the worker took the ping before it was dropped"
        assert got == [None]                         # late: the device counts it so
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text
        assert "Traceback" not in caplog.text and "CancelledError" not in caplog.text
    finally:
        src.close()
