"""Each ping is checked once (issue 28): the instrument check (with its sample-range
scan) and the pose-flag check made at a gate are trusted by the imager for the same
ping object, while a ping handed to the imager unchecked, a copy, or a ping checked
against another configuration is checked afresh, and a refusal is repeated with its
reason. A re-posed ping (the live micronavigation's) keeps its record's check: its
samples are not scanned again, its new pose is checked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svss_daq import checked, ping_gate
from svss_daq.assembly import PingAssembler
from svss_daq.ping import NAV_GPS_FIX, NavSnapshot
from svss_daq.ping_gate import PingGate, PingRejected, checked_ping_problem
from svss_proc.imaging import pose_check


def _ping(hardware, sequence=3):
    dig = hardware.value.digitiser
    t = 1_700_000_000_000_000_000
    nav = NavSnapshot(time_ns=t, north_m=0.0, east_m=0.0, down_m=0.0, vel_north_m_s=1.0,
                      vel_east_m_s=0.0, vel_down_m_s=0.0, roll_rad=0.0, pitch_rad=0.0,
                      heading_rad=0.0, altitude_m=2.5, quality=NAV_GPS_FIX)
    samples = np.zeros((dig.n_channels, dig.window_samples), np.int32)
    return PingAssembler(hardware).from_simulation(sequence, samples, nav)


@pytest.fixture
def counted(monkeypatch):
    """Calls of the instrument check and of the pose-flag check."""
    calls = {"ping_problem": 0, "pose_flags": 0}
    real_ping, real_flags = ping_gate.record_problem, pose_check.pose_flags_problem

    def record_problem(*a, **kw):
        calls["ping_problem"] += 1
        return real_ping(*a, **kw)

    def pose_flags_problem(*a, **kw):
        calls["pose_flags"] += 1
        return real_flags(*a, **kw)
    monkeypatch.setattr(ping_gate, "record_problem", record_problem)
    monkeypatch.setattr(pose_check, "pose_flags_problem", pose_flags_problem)
    return calls


def test_a_gated_ping_is_not_checked_again(hardware, demo_processing, counted):
    ping = _ping(hardware)
    cfg = demo_processing.value.ping_gate
    pose_check.check_pose_flags(ping, cfg)             # the worker's order
    assert PingGate(hardware).admit(ping)
    assert counted == {"ping_problem": 1, "pose_flags": 1}
    pose_check.check_pose_flags(ping, cfg)             # the imager's, trusted
    assert checked_ping_problem(ping, hardware) is None
    assert counted == {"ping_problem": 1, "pose_flags": 1}
    # a second gate over the same ping still keeps its own time order
    gate = PingGate(hardware)
    assert gate.admit(ping) and not gate.admit(ping)
    assert counted["ping_problem"] == 1


def test_copies_other_configurations_and_refusals_are_checked_afresh(hardware, counted):
    ping = _ping(hardware)
    assert checked_ping_problem(ping, hardware) is None
    copy = dataclasses.replace(ping, sequence=4)
    assert checked_ping_problem(copy, hardware) is None
    assert counted["ping_problem"] == 2
    other = dataclasses.replace(hardware, text=hardware.text + "\n# another\n")
    assert checked_ping_problem(ping, other) is not None     # acquired with another id
    assert counted["ping_problem"] == 3
    bad = dataclasses.replace(ping, projector=99)
    reasons = [checked_ping_problem(bad, hardware) for _ in range(2)]
    assert reasons[0] == reasons[1] and "projector 99 outside" in reasons[0]
    assert counted["ping_problem"] == 5
    with pytest.raises(PingRejected, match="projector 99 outside"):
        PingGate(hardware).check(bad)


def test_objects_that_cannot_be_marked_are_checked_each_time():
    calls = []

    def problem():
        calls.append(1)
        return None
    assert checked.once((1, 2), "k", problem) is None
    assert checked.once((1, 2), "k", problem) is None       # a tuple has no weak ref
    assert len(calls) == 2


def test_a_reposed_ping_keeps_its_records_check_and_its_pose_is_checked(hardware, counted):
    """The live micronavigation moves a gated ping (svss_proc.micronav.live.fused): the
    copy is not scanned again (the imager trusts the gate's scan), but a pose out of
    bounds is still refused."""
    from svss_proc.micronav.live import fused
    ping = _ping(hardware)
    assert PingGate(hardware).admit(ping)
    moved = fused(ping, np.array([0.01, -0.02, 0.005]))
    assert moved is not ping and moved.nav.north_m == pytest.approx(0.01)
    assert checked_ping_problem(moved, hardware) is None
    assert counted["ping_problem"] == 1
    wild = fused(ping, np.array([0.0, 0.0, 5.0]))      # the altitude goes negative
    assert "altitude_m" in checked_ping_problem(wild, hardware)
    assert counted["ping_problem"] == 1
    # a copy that changed its record is checked afresh
    assert checked_ping_problem(dataclasses.replace(moved, projector=99), hardware) \
        is not None
    assert counted["ping_problem"] == 2
