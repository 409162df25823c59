"""A gap in the digitiser's ping numbers, over a real loopback TCP link to the digitiser
emulator: one item carrying the gap's range reaches the daemon (never one placeholder
per missing number: the gap's length comes from the wire), no real ping is dropped for
it, and the daemon counts every missing number."""

from __future__ import annotations

import queue
import sys
import time

import numpy as np
import pytest

from sim_device.devices import DigitiserEmulator
from svss_daq.acquire_config import load_acquire
from svss_daq.config import config_path
from svss_daq.daemon import AcquisitionDaemon
from svss_daq.drivers.digitiser import DigitiserClient
from svss_daq.protocols import digitiser as dg

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="loopback TCP as on the boat's Linux host")
WAIT_S = 30.0
GAP = 1005                       # more than the driver's queue (devices.toml: 1000)


def _samples(n):
    return np.random.default_rng(n).integers(-2**23, 2**23, (80, 1500)).astype(np.int32)


def test_a_gap_of_1005_pings_is_one_item_and_loses_no_real_ping(tmp_path):
    """Issue 27 item 5: the 1005 missing numbers were 1000 placeholders (one per number,
    capped), which filled the driver's 1000-item queue: the next complete pings were
    dropped ("ping queue full") and never_delivered said 1000."""
    numbers = [0, 1, 2] + [3 + GAP, 4 + GAP]
    with DigitiserEmulator(None, ping_interval_s=None, channels_per_frame=16) as emu:
        cl = DigitiserClient("127.0.0.1", emu.port, connect_timeout_s=2.0,
                             reply_timeout_s=2.0, ping_timeout_s=1.0,
                             queue_pings=1000).open(wait_connected_s=WAIT_S)
        try:
            cl.start()
            t0 = time.time_ns()
            for k, n in enumerate(numbers):
                tx = t0 + k * 100_000_000
                assert emu.trigger(n, tx, tx + 1_000_000, _samples(n))
                deadline = time.monotonic() + WAIT_S      # sent before the next
                while emu.pings_sent <= k:
                    assert time.monotonic() < deadline, "the emulator did not send"
                    time.sleep(0.01)
            deadline = time.monotonic() + WAIT_S
            while cl.decoder.assembler.complete < len(numbers):   # all reassembled
                assert time.monotonic() < deadline, cl.decoder.assembler.complete
                time.sleep(0.01)
        finally:
            cl.close()
    items = []
    while True:
        try:
            items.append(cl.ping_queue.get_nowait())
        except queue.Empty:
            break
    complete = [i.ping_number for i in items if isinstance(i, dg.CompletePing)]
    assert complete == numbers
    assert cl.dropped == 0
    [gap] = [i for i in items if isinstance(i, dg.IncompletePing)]
    assert (gap.ping_number, gap.last_ping_number, gap.n_pings, gap.frames_received) == \
        (3, 2 + GAP, GAP, 0)
    for i in items:
        if isinstance(i, dg.CompletePing):
            np.testing.assert_array_equal(i.samples, _samples(i.ping_number))
    # the daemon counts what the driver delivered (its configuration untouched: nothing
    # is opened until it starts)
    daemon = AcquisitionDaemon(load_acquire(config_path("acquire.toml"), out_dir=tmp_path))
    for i in items:
        daemon.pipeline.take(i)
    assert daemon.counters.never_delivered == GAP
    assert daemon.counters.delivered == len(numbers) and daemon.counters.incomplete == 0
