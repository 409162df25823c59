"""Sequencer and digitiser drivers against the simulated device ends over a real
pseudo-terminal and a real loopback TCP socket. Every wait is bounded."""

from __future__ import annotations

import queue
import sys
import time

import numpy as np
import pytest

from sim_device.devices import DigitiserEmulator, SequencerEmulator
from svss_daq.drivers.digitiser import DigitiserClient, DigitiserError
from svss_daq.drivers.sequencer import SequencerDriver, SequencerError, SequencerTimeout
from svss_daq.protocols import digitiser as dg
from svss_daq.protocols import sequencer as sq

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")
WAIT_S = 5.0


def _get(q: queue.Queue, timeout_s: float = WAIT_S):
    return q.get(timeout=timeout_s)


# ------------------------------------------------------------------------ sequencer


@pytest.fixture
def seq_pair():
    emu = SequencerEmulator().start()
    drv = SequencerDriver(emu.port, reply_timeout_s=0.3, retries=1)
    drv.open(timeout_s=WAIT_S)
    try:
        yield emu, drv
    finally:
        drv.close()
        emu.close()


def test_sequencer_configure_arm_start_events_stop(seq_pair, hardware):
    emu, drv = seq_pair
    hw = hardware.value
    drv.configure(hw)
    assert emu.schedule == tuple(hw.sequencer.projector_order)
    assert emu.interval_ns == 100_000_000 and emu.window == (0, 12_000_000)
    assert emu.waveform.duration_ns == 255_000 and emu.waveform.f_start_hz == 35000.0
    assert drv.status().state == "IDLE"
    drv.set_interval(0.02)  # faster pings keep the test short
    drv.arm()
    t_start = time.time_ns()
    drv.start()
    events = [_get(drv.ping_queue) for _ in range(8)]
    st = drv.status()
    drv.stop()
    assert st.state == "RUNNING" and st.pings_sent >= 8
    assert [e.sequence for e in events] == list(range(8))
    assert [e.projector for e in events] == [hw.sequencer.projector_order[i % 6] for i in range(8)]
    tx = np.array([e.transmit_time_ns for e in events])
    assert tx[0] >= t_start and np.all(np.diff(tx) > 0)
    assert abs(np.median(np.diff(tx)) - 20_000_000) < 5_000_000  # 20 ms cadence
    assert drv.status().state == "IDLE" and drv.missed_pings == 0


def test_sequencer_error_reply_and_timeout(seq_pair):
    emu, drv = seq_pair
    with pytest.raises(SequencerError, match=r"ARM .*code 5 \(not configured\).*missing SCHED") as e:
        drv.arm()
    assert e.value.code == sq.ErrorCode.NOT_CONFIGURED
    with pytest.raises(SequencerError, match="START.*code 4"):
        drv.start()
    with pytest.raises(SequencerError, match="code 3"):
        drv.set_interval(20.0)
    emu.mute = True
    t0 = time.monotonic()
    with pytest.raises(SequencerTimeout, match=r"no reply to STOP .*within 0.3 s after 2 attempt"):
        drv.stop()
    assert 0.5 < time.monotonic() - t0 < 2.0
    emu.mute = False
    assert drv.status().state == "IDLE"


def test_sequencer_retry_same_id_executes_once(seq_pair):
    emu, drv = seq_pair
    emu.drop_replies = 1  # the first PRI is lost: the driver re-sends the same id
    drv.set_interval(0.05)
    pri = [c for c in emu.commands if isinstance(c, sq.SetInterval)]
    assert len(pri) == 2 and pri[0].mid == pri[1].mid and emu.interval_ns == 50_000_000


def test_sequencer_garbage_on_the_line_is_skipped(seq_pair):
    emu, drv = seq_pair
    emu.write(b"\x00\xff$SEQ,PING,1,2,3*00\r\nnoise")
    emu.write(sq.encode(sq.PingEvent(7, 2, 123)))
    ev = _get(drv.ping_queue)
    assert ev == sq.PingEvent(7, 2, 123) and drv.parser.stats.rejected >= 1


# ------------------------------------------------------------------------ digitiser


def _samples(n):
    rng = np.random.default_rng(n)
    return rng.integers(-2**23, 2**23, (80, 1500)).astype(np.int32)


def _client(port, **kw):
    return DigitiserClient("127.0.0.1", port, connect_timeout_s=1.0, reply_timeout_s=1.0,
                           reconnect_initial_s=0.05, reconnect_max_s=0.2, ping_timeout_s=0.3, **kw)


def _next_of(q, kind, timeout_s=WAIT_S):
    deadline = time.monotonic() + timeout_s
    while True:
        item = q.get(timeout=max(0.01, deadline - time.monotonic()))
        if isinstance(item, kind):
            return item


def test_digitiser_pings_bit_exact_gain_and_drop():
    with DigitiserEmulator(_samples, ping_interval_s=0.03, channels_per_frame=16) as emu:
        cl = _client(emu.port).open(wait_connected_s=WAIT_S)
        try:
            assert cl.set_gain(12.3) == 12.5  # the device applies 0.5 dB steps
            with pytest.raises(DigitiserError, match="SET_GAIN.*bad value"):
                cl.set_gain(99.0)
            emu.drop_frame(3, 2)
            emu.corrupt_frame(5, 4)
            cl.start()
            got = [_get(cl.ping_queue) for _ in range(7)]
            cl.stop()
            assert cl.status() >= 7
        finally:
            cl.close()
    kinds = [(type(g).__name__, g.ping_number) for g in got]
    assert kinds == [("CompletePing", 0), ("CompletePing", 1), ("CompletePing", 2),
                     ("IncompletePing", 3), ("CompletePing", 4), ("IncompletePing", 5),
                     ("CompletePing", 6)]
    assert got[3].missing_frames == (2,) and got[3].frame_count == 5
    assert "corrupt" in got[5].reason
    for g in got:
        if isinstance(g, dg.CompletePing):
            tx, s = emu.sent[g.ping_number]
            assert g.transmit_time_ns == tx and g.samples.dtype == np.int32
            assert g.samples.shape == (80, 1500) and np.array_equal(g.samples, s)


def test_digitiser_garbage_resync_and_reconnect_after_restart():
    emu = DigitiserEmulator(_samples, ping_interval_s=0.03).start()
    port = emu.port
    cl = _client(port).open(wait_connected_s=WAIT_S)
    try:
        cl.start()
        _next_of(cl.ping_queue, dg.CompletePing)
        emu.inject_garbage(b"\x00SVDG" + bytes(range(256)) * 3 + b"SVDG")
        # garbage lands in front of the next frame; the pings after it arrive intact
        p = _next_of(cl.ping_queue, dg.CompletePing)
        while cl.decoder.frames.stats.bytes_discarded == 0:
            p = _next_of(cl.ping_queue, dg.CompletePing)
        assert cl.decoder.frames.stats.bytes_discarded >= 768
        p = _next_of(cl.ping_queue, dg.CompletePing)
        assert np.array_equal(p.samples, _samples(p.ping_number))
        last = p.ping_number
        emu.close()  # the device goes away ...
        deadline = time.monotonic() + WAIT_S
        while cl.connected and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not cl.connected and cl.disconnects == 1
        emu = DigitiserEmulator(_samples, port=port, ping_interval_s=0.03,
                                first_ping=last + 100).start()  # ... and comes back
        assert cl.wait_connected(WAIT_S) and cl.connects == 2
        p = _next_of(cl.ping_queue, dg.CompletePing)  # streaming restarted by the driver
        assert p.ping_number >= last + 100 and np.array_equal(p.samples, _samples(p.ping_number))
    finally:
        cl.close()
        emu.close()


# ------------------------------------------------------------------------ from devices.toml


def test_drivers_from_the_devices_config_reach_the_devices(hardware):
    """``from_config`` (how the acquisition side builds its drivers from
    config/devices.toml) hands every link setting over: distinctive values, then a
    command round trip with each emulator."""
    import dataclasses

    from svss_daq.config import DevicesConfig, config_path, load

    devices = load(DevicesConfig, config_path("devices.toml"))
    with SequencerEmulator() as emu:
        cfg = dataclasses.replace(devices.sequencer, port=emu.port, baudrate=57600,
                                  reply_timeout_s=0.37, retries=3, open_timeout_s=WAIT_S + 0.25)
        drv = SequencerDriver.from_config(cfg).open()
        try:
            assert (drv.port, drv.link.baudrate, drv.reply_timeout_s, drv.retries,
                    drv.open_timeout_s) == (emu.port, 57600, 0.37, 3, WAIT_S + 0.25)
            drv.configure(hardware.value)
            assert emu.schedule == tuple(hardware.value.sequencer.projector_order)
        finally:
            drv.close()
    with DigitiserEmulator(_samples, ping_interval_s=0.03) as emu:
        cfg = dataclasses.replace(devices.digitiser, host="127.0.0.1", port=emu.port,
                                  connect_timeout_s=1.1, reply_timeout_s=0.9,
                                  reconnect_initial_s=0.07, reconnect_max_s=0.3,
                                  ping_timeout_s=0.4, max_payload_bytes=1 << 20)
        cl = DigitiserClient.from_config(cfg).open(wait_connected_s=WAIT_S)
        try:
            assert (cl.host, cl.port, cl.connect_timeout_s, cl.reply_timeout_s,
                    cl.reconnect_initial_s, cl.reconnect_max_s, cl.ping_timeout_s) == (
                "127.0.0.1", emu.port, 1.1, 0.9, 0.07, 0.3, 0.4)
            assert cl.decoder.frames.max_payload == 1 << 20
            assert cl.set_gain(12.3) == 12.5
        finally:
            cl.close()
