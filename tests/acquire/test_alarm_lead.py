"""Alarms that know when pings are due, through real processes: ``svss sim-device``
holding its first ping for a lead (as the demo starts it), ``svss acquire`` and ``svss
status --follow``. Until the first ping, pings.stopped, pings.rate_low and
sequencer.silent wait for ``[alarms] first_ping_s`` after the start (the status says
when the first ping is due): none cries wolf in a 4 s lead; a sonar that has not
started by then raises pings.stopped all the same."""

from __future__ import annotations

import sys

import pytest

from .conftest import CONFIG, acquire_toml
from .test_alarms_live import Follower, free_port

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")

QUIET = ("pings.stopped", "pings.rate_low", "sequencer.silent")


def _start(rig, tmp_path, lead_s: float, attempt: int = 0, **alarms):
    """A device holding its first ping ``lead_s`` after it is ready, an acquisition
    publishing its status on a free port, and a follower of that status."""
    port = free_port()
    endpoint = f"tcp://127.0.0.1:{port}"
    work = tmp_path / f"attempt{attempt}"
    work.mkdir()
    daq = work / "daq.toml"
    daq.write_text((CONFIG / "daq.toml").read_text()
                   .replace('"tcp://127.0.0.1:5556"', '"tcp://127.0.0.1:*"')
                   .replace('"tcp://127.0.0.1:5557"', '"tcp://127.0.0.1:*"'))
    follower = Follower(endpoint)
    dev = rig.device("--lead", str(lead_s), name=f"dev{attempt}")
    config = acquire_toml(work, alarms={"device_silent_s": 1.0, **alarms},
                          run={"daq": str(daq)}, status={"endpoint": endpoint})
    acq = rig.acquire(dev, "--duration", "600", ephemeral=False, config=config,
                      run_id=f"run{attempt}")
    return follower, (acq, dev)


@pytest.mark.slow
def test_no_alarm_cries_wolf_in_the_lead_before_the_first_ping(rig, tmp_path):
    # the lead runs from the device's start, so a loaded machine that is slow to start
    # the acquisition eats into it: then the same run again with twice the lead, until
    # the acquisition's statuses cover at least a second of the lead
    for attempt, lead_s in enumerate((4.0, 8.0, 16.0, 32.0)):
        follower, procs = _start(rig, tmp_path, lead_s, attempt)
        try:
            before = []
            s = follower.until(lambda s: (before.append(s) or True)
                               and s["counters"]["delivered"] > 0, "the first ping")
            # whatever the lead left, no alarm on pings cried wolf in it
            assert not set(QUIET) & follower.seen, sorted(follower.seen)
            assert s["pinging_s"] is not None and s["first_ping_due_s"] is None
            waiting = [b for b in before if b["state"] == "recording"
                       and b["counters"]["delivered"] == 0]
            assert all(b["first_ping_due_s"] is not None and b["last_ping_age_s"] is None
                       for b in waiting)
        finally:
            follower.stop()
            for p in procs:
                p.stop()
        # the lead was seen: a second and more of statuses before the first ping (at 5
        # a second), each saying when the first ping is due
        if len(waiting) >= 5:
            return
    pytest.fail(f"with a {lead_s} s lead the acquisition still started too late to "
                f"see it ({len(waiting)} statuses before the first ping)")


@pytest.mark.slow
def test_a_sonar_that_does_not_start_in_time_raises_pings_stopped(rig, tmp_path):
    follower, _ = _start(rig, tmp_path, 20.0, first_ping_s=1.0)
    try:
        s = follower.until(lambda s: "pings.stopped" in {a["name"] for a in s["alarms"]},
                           "pings.stopped before the first ping")
        assert s["counters"]["delivered"] == 0
        alarm = [a for a in s["alarms"] if a["name"] == "pings.stopped"][0]
        assert alarm["severity"] == "critical" and "no ping for" in alarm["message"]
    finally:
        follower.stop()
