"""The daemon's device supervisor on its own (svss_daq/daemon_devices.py): the
simulated sequencer on a real pseudo-terminal, the simulated digitiser on loopback TCP,
a GPS and a DVL writing on pseudo-terminals; opened from the devices configuration,
watched (faults become run events), their records tapped into a real raw-run segment,
reported, stopped and closed; no pipeline, no daemon."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import threading
import time
import tty

import numpy as np
import pytest

from sim_device.devices import DigitiserEmulator, SequencerEmulator
from svss_daq.assembly import PingAssembler
from svss_daq.daemon_devices import DeviceSupervisor
from svss_daq.daemon_nav import NavigationMonitor, unknown_pose
from svss_daq.daemon_run import RunState
from svss_daq.drivers.sequencer import SequencerDriver
from svss_daq.protocols import nmea_encoder as ne
from svss_daq.protocols.digitiser import CompletePing
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
from svss_daq.rawfile import EVENT_KIND_LEN, RawRunReader
from svss_daq.recorder import RunRecorder

from tests.drivers.test_serial_link import wait_until

from .conftest import local_setup

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")
WAIT_S = 10.0


def _samples(n):
    return np.full((80, 1500), n, np.int32)


class Instruments(threading.Thread):
    """A GPS and a DVL on pseudo-terminals, each record stamped now, every 0.1 s until
    stopped; what each wrote is kept."""

    def __init__(self):
        super().__init__(daemon=True)
        self.fds = {}
        for name in ("gps", "dvl"):
            master, slave = os.openpty()
            tty.setraw(slave)
            self.fds[name] = (master, slave, os.ttyname(slave))
        self.sentences: list[str] = []
        self.ensembles: list[bytes] = []
        self.halt = threading.Event()
        self.junk = threading.Event()

    def port(self, name: str) -> str:
        return self.fds[name][2]

    def run(self):
        setup = Pd0Setup(coordinate_system="ship", beam_angle_deg=30.0)
        k = 0
        while not self.halt.wait(0.1):
            t = time.time_ns()
            lines = [ne.gga("GP", t, 41.524, -70.671, 2, 12, 0.9, 0.0, 0.0),
                     ne.rmc("GP", t, True, 41.524, -70.671, 0.0, 0.5),
                     ne.hdt("GP", 0.5)]
            data = b"".join(lines)
            if self.junk.is_set():
                self.junk.clear()
                data = b"\x00\xffjunk\n" + data
            os.write(self.fds["gps"][0], data)
            self.sentences += [b.decode().strip() for b in lines]
            k += 1
            ens = encode_ensemble(setup, ensemble_number=k, time_ns=t, heading_rad=0.5,
                                  pitch_rad=0.0, roll_rad=0.0,
                                  bt_velocity_m_s=[0.0, -1.0, 0.0, 0.0],
                                  bt_range_m=[2.0] * 4)
            os.write(self.fds["dvl"][0], ens)
            self.ensembles.append(ens)

    def close(self):
        self.halt.set()
        self.join(2.0)
        for master, slave, _ in self.fds.values():
            for fd in (master, slave):
                try:
                    os.close(fd)
                except OSError:
                    pass


@pytest.fixture
def rig(tmp_path):
    seq = SequencerEmulator(link_path=tmp_path / "seq").start()
    dig = DigitiserEmulator(_samples, ping_interval_s=0.1).start()
    inst = Instruments()
    inst.start()
    setup = local_setup(tmp_path, links=True, pairing={"start_timeout_s": WAIT_S})
    d = setup.devices
    devices = dataclasses.replace(
        d, sequencer=dataclasses.replace(d.sequencer, port=seq.port),
        digitiser=dataclasses.replace(d.digitiser, host="127.0.0.1", port=dig.port,
                                      reconnect_initial_s=0.05, reconnect_max_s=0.2),
        gps=dataclasses.replace(d.gps, port=inst.port("gps")),
        dvl=dataclasses.replace(d.dvl, port=inst.port("dvl")))
    setup = dataclasses.replace(setup, devices=devices)
    run = RunState("devices")
    run.recorder = RunRecorder(setup.out_dir, run.run_id, setup.hardware,
                               flush_every_pings=1, flush_interval_s=1.0,
                               max_file_bytes=2**30, max_file_s=600.0, reserve_bytes=0)
    transmits: list = []
    sup = DeviceSupervisor(setup, run, NavigationMonitor(setup, run),
                           on_transmit=transmits.append)
    try:
        yield setup, run, sup, seq, dig, inst, transmits
    finally:
        sup.close()
        if not run.recorder.ended:
            run.recorder.close()
        inst.close()
        dig.close()
        seq.close()


def test_devices_are_opened_watched_tapped_reported_and_stopped(rig):
    setup, run, sup, seq, dig, inst, transmits = rig
    hw = setup.hardware.value
    # a sequencer left pinging (its daemon killed mid-run) is stopped before it is set
    left = SequencerDriver(seq.port, reply_timeout_s=0.5, retries=1).open(timeout_s=WAIT_S)
    left.configure(hw)
    left.arm()
    left.start()
    left.close()
    sup.open()
    run.recording(first_ping_s=5.0)
    assert [k for _, k, _ in run.events] == ["sequencer.was_running"]
    assert seq.state == "RUNNING" and seq.schedule == tuple(hw.sequencer.projector_order)
    # the schedule's pings: transmit records handed on, the digitiser's pings queued
    assert wait_until(lambda: len(transmits) >= 3)
    ping = sup.digitiser.ping_queue.get(timeout=WAIT_S)
    assert isinstance(ping, CompletePing)
    assert sup.nav.has_data("gps") and sup.nav.has_data("dvl")
    # the recording's segment opens with its first ping; the tapped records follow
    dig_cfg = hw.digitiser
    run.recorder.append(PingAssembler(setup.hardware).build(
        0, hw.sequencer.projector_order[0], ping.transmit_time_ns,
        round(dig_cfg.window_start_s * 1e9), ping.samples,
        unknown_pose(ping.transmit_time_ns)))
    sup.watch()
    # faults: garbage on the digitiser's stream and the GPS line, the digitiser's
    # connection reset, the sequencer's port gone and back
    dig.inject_garbage(b"\x00SVDG" + bytes(200))
    inst.junk.set()
    assert wait_until(lambda: sup.digitiser.decoder.frames.stats.bytes_discarded > 0
                 and not inst.junk.is_set())
    dig.reset_connection()
    assert wait_until(lambda: sup.digitiser.connects >= 2)
    seq.vanish(0.3)
    assert wait_until(lambda: sup.sequencer.link.stats.connects >= 2)
    time.sleep(0.3)                              # the GPS junk's line read
    sup.watch()
    kinds = [k for _, k, _ in run.events]
    for kind in ("digitiser.garbage", "gps.garbage", "digitiser.disconnected",
                 "digitiser.reconnected", "sequencer.vanished", "sequencer.returned"):
        assert kind in kinds, kinds
    status = sup.status(time.monotonic())
    assert set(status) == {"sequencer", "digitiser", "dvl", "gps"}
    assert status["digitiser"]["reconnects"] >= 1 and status["sequencer"]["reopens"] >= 1
    assert status["gps"]["records"] > 0 and status["gps"]["garbage_bytes"] > 0
    assert all(status[k]["connected"] for k in status)
    assert all(0 <= status[k]["silent_s"] < 5 for k in ("sequencer", "dvl", "gps"))
    sup.stop_pinging()
    assert seq.state == "IDLE"
    sup.stop_digitiser()
    sup.watch()
    sup.close()
    run.recorder.close()
    with RawRunReader(run.recorder.segments[0]) as r:
        nmea, pd0, clock = r.nmea(), r.pd0(), r.ping_clock()
        events = [k for _, k, _ in r.events()]
    # every record written is the instrument's, as sent
    assert nmea and {s for _, s in nmea} <= set(inst.sentences)
    got = [b for _, b in pd0]                   # (from the first the link read whole)
    assert got and got == inst.ensembles[inst.ensembles.index(got[0]):][:len(got)]
    assert len(clock) == len(transmits) and [tx for _, tx in clock] == [
        ev.transmit_time_ns for ev in transmits]
    # the events too, those before the segment opened held for it
    assert events == [k[:EVENT_KIND_LEN] for _, k, _ in run.events]
    assert run.counters.records_dropped == 0


def test_without_navigation_links_only_the_sonar_is_opened(rig, tmp_path, caplog):
    setup, run, sup, seq, dig, inst, transmits = rig
    bare = dataclasses.replace(setup, devices=dataclasses.replace(setup.devices, gps=None,
                                                                  dvl=None))
    sup = DeviceSupervisor(bare, run, NavigationMonitor(bare, run))
    try:
        sup.open()
        assert "no DVL or GPS link configured" in caplog.text
        assert sup.gps_link is None and sup.dvl_link is None
        assert wait_until(lambda: sup.transmits >= 2)
        assert set(sup.status(time.monotonic())) == {"sequencer", "digitiser"}
        assert math.isnan(sup.nav.poses([time.time_ns()])[0].north_m)
    finally:
        sup.stop_pinging()
        sup.close()
