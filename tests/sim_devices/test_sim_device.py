"""``svss sim-device`` as a real process: the acquisition drivers, built from the devices
configuration it prints, drive its sequencer over a real pseudo-terminal and receive its
digitiser's pings over real loopback TCP; the samples are the physics', bit for bit."""

from __future__ import annotations

import functools
import signal
import sys
import time

import numpy as np
import pytest
import serial

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import load_scene
from sim_device.track import parse_utc_ns
from svss_daq.config import DevicesConfig, loads
from svss_daq.drivers.digitiser import DigitiserClient
from svss_daq.drivers.sequencer import SequencerDriver, SequencerError
from svss_daq.protocols import digitiser as dg
from svss_daq.protocols import sequencer as sq

from .conftest import DEMO, wait_for

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")
WAIT_S = 5.0
N_PINGS = 12


def _sentence(body: str) -> bytes:
    c = functools.reduce(lambda a, b: a ^ b, body.encode(), 0)
    return f"${body}*{c:02X}\r\n".encode()


def test_drivers_receive_the_physics_bit_for_bit(sim_device_factory, hardware):
    dev = sim_device_factory("--no-navigation")
    assert loads(DevicesConfig, (dev.stdout.read_text()), "stdout") == dev.devices
    assert dev.devices.digitiser.host == "127.0.0.1" and dev.devices.dvl is None
    hw = hardware.value
    scene = load_scene(DEMO)
    t_track = parse_utc_ns(scene.track.start_time_utc)
    interval_ns = round(hw.sequencer.ping_interval_s * 1e9)

    seq = SequencerDriver.from_config(dev.devices.sequencer).open()
    dig = DigitiserClient.from_config(dev.devices.digitiser).open(wait_connected_s=WAIT_S)
    try:
        seq.configure(hardware.value)
        assert seq.status().state == "IDLE"
        seq.arm()
        assert dig.set_gain(6.0) == 6.0
        dig.start()
        seq.start()
        pings = []
        while len(pings) < N_PINGS:
            pings.append(dig.ping_queue.get(timeout=WAIT_S))
        # every transmission up to the last ping delivered (on a loaded machine the
        # device may drop a ping whose samples were not ready in time: it says so)
        events = [seq.ping_queue.get(timeout=WAIT_S)
                  for _ in range(max(N_PINGS, pings[-1].ping_number + 1))]
        st = seq.status()
        seq.stop()
        dig.stop()
    finally:
        dig.close()
        seq.close()
    assert st.state == "RUNNING" and st.pings_sent >= N_PINGS
    assert [e.sequence for e in events] == list(range(len(events))) \
        and seq.missed_pings == 0
    # transmissions on the track's ping grid, on the simulated clock; the projector cycle
    # locked to it
    k = [(e.transmit_time_ns - t_track) / interval_ns for e in events]
    assert all(x == int(x) for x in k) and np.all(np.diff(k) == 1), k
    assert [e.projector for e in events] == [hw.sequencer.projector_order[int(x) % 6]
                                             for x in k]
    assert all(isinstance(p, dg.CompletePing) for p in pings), pings
    numbers = [p.ping_number for p in pings]
    assert numbers == sorted(set(numbers)), numbers
    # a ping missing only where the device dropped it late, logged (the first ten)
    for n in sorted(set(range(numbers[-1])) - set(numbers)):
        assert f"ping {n} (track ping" in dev.logs(), (n, numbers, dev.logs()[-2000:])
    by_seq = {e.sequence: e for e in events}
    src = EnvironmentSource(hardware, scene)
    for p in pings:
        e = by_seq[p.ping_number]
        assert p.transmit_time_ns == e.transmit_time_ns
        assert p.first_sample_time_ns == e.transmit_time_ns + round(
            hw.digitiser.window_start_s * 1e9)
        i = (e.transmit_time_ns - t_track) // interval_ns
        truth = src.ping(i)
        assert truth.transmit_time_ns == e.transmit_time_ns and truth.projector == e.projector
        assert p.samples.dtype == np.int32 and np.array_equal(p.samples, truth.samples), i
    assert dev.stop() == 130


def test_bad_commands_get_naks_and_garbage_never_kills_it(sim_device_factory, hardware):
    dev = sim_device_factory("--no-navigation", name="garbage")
    port = serial.Serial(dev.devices.sequencer.port, 115200, timeout=0.05)
    parser = sq.SequencerStreamParser()
    got: list = []

    def ask(raw: bytes, n: int = 1) -> list:
        port.write(raw)
        start = len(got)
        deadline = time.monotonic() + WAIT_S
        while len(got) < start + n and time.monotonic() < deadline:
            got.extend(m for m in parser.feed(port.read(4096)) if not isinstance(m, sq.PingEvent))
        return got[start:]

    try:
        assert ask(_sentence("SEQ,FOO,5")) == [sq.Nak(0, "?", 2, "unknown command FOO")]
        assert ask(_sentence("SEQ,PRI,6,100")[:-6] + b"00\r\n") == [
            sq.Nak(0, "?", 1, "unreadable sentence")]                      # bad checksum
        assert ask(sq.encode(sq.SetInterval(60007, 20_000_000_000)))[0].code == 3  # out of range
        assert ask(sq.encode(sq.Arm(60008)))[0].code == 5                       # not configured
        assert ask(sq.encode(sq.Start(60009)))[0].code == 4                 # wrong state
        assert ask(sq.encode(sq.Ack(60010, "PRI")))[0].code == 2               # not a command
        rng = np.random.default_rng(1)
        for _ in range(20):  # random bytes, '$' storms, overlong lines, NULs
            port.write(rng.integers(0, 256, 500, dtype=np.uint8).tobytes())
            port.write(b"$" * 300 + b"$SEQ," + b"A" * 400 + b"\r\n\x00\xff")
        time.sleep(0.2)
        port.reset_input_buffer()
        parser = sq.SequencerStreamParser()
        st = ask(sq.encode(sq.StatusRequest(60011)))
        assert st == [sq.Status(60011, "IDLE", 0, 0, 0)], st
        assert dev.proc.poll() is None
    finally:
        port.close()
    # the drivers still get on with it
    seq = SequencerDriver.from_config(dev.devices.sequencer).open()
    try:
        seq.configure(hardware.value)
        with pytest.raises(SequencerError, match="code 3"):
            seq.set_interval(20.0)
        seq.arm()
        seq.start()
        assert seq.ping_queue.get(timeout=WAIT_S).sequence == 0
        with pytest.raises(SequencerError, match="code 4"):
            seq.set_interval(0.2)
    finally:
        seq.close()
    assert dev.proc.poll() is None, dev.logs()
    assert "Traceback" not in dev.logs()


def test_sigterm_stops_it_promptly_with_130(sim_device_factory):
    dev = sim_device_factory(name="term")
    assert dev.devices.dvl is not None and dev.devices.gps is not None
    # a digitiser client connected and streaming, a driver on the sequencer
    seq = SequencerDriver.from_config(dev.devices.sequencer).open()
    dig = DigitiserClient.from_config(dev.devices.digitiser).open(wait_connected_s=WAIT_S)
    try:
        dig.start()
        t0 = time.monotonic()
        dev.proc.send_signal(signal.SIGTERM)
        rc = dev.proc.wait(10)
        took = time.monotonic() - t0
        assert wait_for(lambda: not dig.connected, WAIT_S)
    finally:
        dig.close()
        seq.close()
    assert rc == 130 and took < 3.0, (rc, took, dev.logs())
    assert "stopped by signal SIGTERM" in dev.logs()
    run_dir = dev.devices.sequencer.port.rsplit("/", 1)[0]
    assert wait_for(lambda: not __import__("os").path.exists(run_dir), 1.0)


def test_from_run_streams_a_presynthesised_run(sim_device_factory, hardware, tmp_path):
    """``--from-run``: track ping k is the run's ping k; the run is `svss simulate`'s."""
    from svss_daq.rawfile import RawRunReader, RawRunWriter

    scene = load_scene(DEMO)
    src = EnvironmentSource(hardware, scene)
    run = tmp_path / "run.h5"
    # the first seconds of the track are enough: the device starts pinging near its start
    with RawRunWriter(run, hardware) as rec:
        for i in range(scene.track.n_pings):
            rec.append(src.ping(i))
    dev = sim_device_factory("--no-navigation", "--from-run", str(run), name="fromrun")
    seq = SequencerDriver.from_config(dev.devices.sequencer).open()
    dig = DigitiserClient.from_config(dev.devices.digitiser).open(wait_connected_s=WAIT_S)
    try:
        seq.configure(hardware.value)
        seq.arm()
        dig.start()
        seq.start()
        events = {e.sequence: e for e in (seq.ping_queue.get(timeout=WAIT_S) for _ in range(5))}
        pings = [dig.ping_queue.get(timeout=WAIT_S) for _ in range(5)]
    finally:
        dig.close()
        seq.close()
    t_track = parse_utc_ns(scene.track.start_time_utc)
    with RawRunReader(run) as r:
        for p in pings:
            assert isinstance(p, dg.CompletePing)
            i = (events[p.ping_number].transmit_time_ns - t_track) // 100_000_000
            assert np.array_equal(p.samples, r.ping(i).samples)
    assert "streamed from the pre-synthesised run" in dev.logs()


def test_worker_processes_give_the_same_samples_and_stop_promptly(sim_device_factory,
                                                                   hardware):
    """``--workers 2``: pings synthesised ahead in spawned processes, bit for bit the
    in-process physics; SIGTERM ends the workers too."""
    dev = sim_device_factory("--no-navigation", "--workers", "2", name="workers")
    scene = load_scene(DEMO)
    t_track = parse_utc_ns(scene.track.start_time_utc)
    seq = SequencerDriver.from_config(dev.devices.sequencer).open()
    dig = DigitiserClient.from_config(dev.devices.digitiser).open(wait_connected_s=WAIT_S)
    try:
        seq.configure(hardware.value)
        seq.arm()
        dig.start()
        seq.start()
        events = {e.sequence: e for e in (seq.ping_queue.get(timeout=WAIT_S) for _ in range(6))}
        pings = [dig.ping_queue.get(timeout=WAIT_S) for _ in range(6)]
        t0 = time.monotonic()
        rc = dev.stop()
        took = time.monotonic() - t0
    finally:
        dig.close()
        seq.close()
    src = EnvironmentSource(hardware, scene)
    for p in pings:
        assert isinstance(p, dg.CompletePing)
        i = (events[p.ping_number].transmit_time_ns - t_track) // 100_000_000
        assert np.array_equal(p.samples, src.ping(i).samples), i
    logs = dev.logs()
    assert "2 worker process(es)" in logs and "'late': 0" in logs, logs
    assert rc == 130 and took < 3.0, (rc, took)
