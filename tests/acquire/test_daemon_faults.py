"""Device faults injected into the simulated device (``--faults``) while ``svss
acquire`` runs: each is flagged, counted, recorded in the raw file's events and shown in
the status stream, and acquisition goes on."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from svss_daq.ping import NAV_BOTTOM_LOCK, NAV_DEAD_RECKONED, NAV_GPS_FIX
from svss_daq.rawfile import RawRunReader
from svss_daq.status import read_status

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")

# simulated seconds after the sequencer's START (time scale 1)
FAULTS = """
seed = 3

[[fault]]
at_s = 1.0
kind = "digitiser.reset"

[[fault]]
at_s = 2.0
kind = "digitiser.garbage"
length = 300

[[fault]]
at_s = 2.5
kind = "sequencer.vanish"
seconds = 0.6

[[fault]]
at_s = 3.5
kind = "dvl.garbage"
length = 80

[[fault]]
at_s = 3.6
kind = "gps.garbage"
text = "$GPGGA,garbage*00\\r\\n\\u0000"

[[fault]]
at_s = 4.0
kind = "gps.outage"
seconds = 4.0

[[fault]]
at_s = 8.5
kind = "dvl.bottom_lock_loss"
seconds = 3.0

[[fault]]
at_s = 12.0
kind = "gps.vanish"
seconds = 0.5
"""

EXPECTED_EVENTS = ("digitiser.disconnected", "digitiser.reconnected", "digitiser.garbage",
                   "sequencer.vanished", "sequencer.returned", "dvl.garbage", "gps.garbage",
                   "navigation.gps_outage", "navigation.gps_back",
                   "navigation.bottom_lock_lost", "navigation.bottom_lock_back",
                   "gps.vanished", "gps.returned")


@pytest.mark.slow
def test_every_injected_fault_is_flagged_counted_and_survived(rig, tmp_path):
    faults = tmp_path / "faults.toml"
    faults.write_text(FAULTS)
    dev = rig.device("--faults", str(faults))
    acq = rig.acquire(dev, "--duration", "15")
    last = None
    while acq.proc.poll() is None:
        try:
            last = read_status(acq.endpoints["status"], timeout_s=2)
        except TimeoutError:         # a loaded machine, or no status after the run:
            continue                 # the last one read stays, until the daemon exits
    assert acq.wait(60) == 0, acq.logs()[-4000:]
    [f] = acq.files()
    with RawRunReader(f) as run:
        events = run.events()
        summary = run.summary
        table = run.nav_table()
        seqs = run.ping_table()["ping_sequence"]
    kinds = {k for _, k, _ in events}
    missing = [k for k in EXPECTED_EVENTS if k not in kinds]
    assert not missing, (missing, sorted(kinds), acq.logs()[-3000:])
    # counted in the closing summary and shown in the status stream
    assert all(summary["events"].get(k, 0) >= 1 for k in EXPECTED_EVENTS)
    assert last is not None and last["n_events"] >= len(EXPECTED_EVENTS) - 2
    assert last["devices"]["digitiser"]["reconnects"] >= 1
    # acquisition went on: pings before and after every fault, none twice
    assert len(seqs) >= 70 and len(set(seqs.tolist())) == len(seqs)
    t = (table["time1"] - table["time1"][0]) * 1e-9
    assert t[-1] > 13.0
    q = table["quality"]
    # the GPS outage: poses carried by DVL dead reckoning, flagged, position kept
    dr = (q & NAV_DEAD_RECKONED) != 0
    assert dr.any() and not (q[dr] & NAV_GPS_FIX).any()
    assert np.isfinite(table["north_m"][dr]).all()
    assert summary["navigation"]["dead_reckoned"] == int(dr.sum())
    # loss of bottom lock: pings without it, altitude unknown
    nolock = (q & NAV_BOTTOM_LOCK) == 0
    assert nolock.any() and np.isnan(table["altitude_m"][nolock]).all()
    assert (q & NAV_BOTTOM_LOCK).sum() > len(q) // 2
