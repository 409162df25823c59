"""The acquisition daemon's queues are bounded by acquire.toml's ``[limits]``
(docs/acquisition.md, "Limits"): past a bound it counts, says so (an event at every
power of 10) and goes on, losing no ping. ``svss sim-device`` and ``svss acquire`` as
real processes."""

from __future__ import annotations

import sys

import pytest

from svss_daq.rawfile import RawRunReader

from .conftest import acquire_toml

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")

# the DVL's port vanishes for 3 s: pings wait for navigation up to wait_s (5 s), many
# more than pending_pings at once
FAULTS = """
[[fault]]
at_s = 1.0
kind = "dvl.vanish"
seconds = 3.0
"""
PENDING = 3


@pytest.mark.slow
def test_pings_waiting_for_navigation_past_the_bound_are_posed_at_once(rig, tmp_path):
    faults = tmp_path / "faults.toml"
    faults.write_text(FAULTS)
    cfg = acquire_toml(tmp_path, navigation={"wait_s": 5.0})
    cfg.write_text(cfg.read_text() + f"[limits]\npending_pings = {PENDING}\n"
                   "transmit_records = 1000\nduplicate_window = 1000\n"
                   "records_waiting = 10000\n")
    dev = rig.device("--faults", str(faults))
    acq = rig.acquire(dev, "--pings", "60", config=cfg)
    assert acq.wait(120) == 0, acq.logs()[-3000:]
    [f] = acq.files()
    with RawRunReader(f) as run:
        summary = run.summary
        events = run.events()
        n = len(run)
    c = summary["counters"]
    assert c["pending_full"] >= 10, c                  # counted
    kinds = [k for _, k, _ in events]
    # said at the 1st, 10th, 100th... only
    assert 1 <= kinds.count("daemon.pending_full") <= len(str(c["pending_full"])), kinds
    # none lost: every delivered ping recorded
    assert c["delivered"] >= 60 and c["recorded"] == c["delivered"] == n
    assert "limits.pending_pings 3" in acq.logs()
