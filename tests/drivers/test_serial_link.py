"""SerialLink over real pseudo-terminals: decoding, odd chunking, garbage,
reconnection after the device vanishes, open timeouts and a clean stop.
Every wait is bounded."""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
import tty
from contextlib import contextmanager
from pathlib import Path

import pytest

from svss_daq.protocols.nmea import HdtHeading, NmeaStreamParser, nmea_checksum
from svss_daq.protocols.pd0 import Pd0Ensemble, Pd0StreamParser
from svss_daq.drivers.serial_link import SerialLink, SerialOpenTimeout, open_port

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux pseudo-terminals")

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data folder missing: {DATA}")

WAIT_S = 5.0  # upper bound on any wait; tests normally finish far sooner
DEG = 3.141592653589793 / 180


@contextmanager
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(slave)  # raw from the start: no echo, no CR/LF translation
    try:
        yield master, slave, os.ttyname(slave)
    finally:
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass


def write_chunks(fd: int, data: bytes, sizes=(1, 3, 17, 64, 5, 250)) -> None:
    pos = k = 0
    while pos < len(data):
        n = sizes[k % len(sizes)]
        os.write(fd, data[pos:pos + n])
        pos += n
        k += 1


def drain(q: queue.Queue, n: int, timeout_s: float = WAIT_S) -> list:
    out, deadline = [], time.monotonic() + timeout_s
    while len(out) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            out.append(q.get(timeout=left))
        except queue.Empty:
            break
    return out


def wait_until(pred, timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def hdt(deg: float) -> bytes:
    body = f"GPHDT,{deg:.2f},T"
    return f"${body}*{nmea_checksum(body):02X}\r\n".encode()


@needs_data
def test_pd0_over_pty_in_odd_chunks_with_garbage():
    raw = (DATA / "dvl_pd0" / "RDI_withBT.000").read_bytes()
    ens = [raw[i * 581:(i + 1) * 581] for i in range(6)]  # this file's ensembles are 581 bytes
    stream = b"\x7f\x7fnoise" + ens[0] + ens[1] + b"\x00" * 33 + ens[2][:200] + ens[3] + b"\x7f" + ens[4] + ens[5]
    q: queue.Queue = queue.Queue()
    with pty_pair() as (master, _, path):
        link = SerialLink(path, Pd0StreamParser(), baudrate=115200, queue=q)
        link.start(wait_connected_s=WAIT_S)
        try:
            write_chunks(master, stream)
            got = drain(q, 5)
        finally:
            link.stop()
    assert all(isinstance(e, Pd0Ensemble) for e in got)
    assert [e.ensemble_number for e in got] == [1, 2, 4, 5, 6]
    assert link.stats.bytes_read == len(stream) and not link.running
    assert link.parser.stats.bytes_discarded == 7 + 33 + 200 + 1


@needs_data
def test_nmea_over_pty_to_callback_with_timestamps():
    lines = [ln for ln in (DATA / "gps_nmea" / "hemi.log").read_bytes().splitlines(keepends=True)
             if ln.startswith(b"$")][-40:]
    stream = b"\xff\xfe garbage \r\n".join(lines[:20]) + b"$GPGGA,broken\r\n" + b"".join(lines[20:])
    got: list = []
    done = threading.Event()

    def on_record(item):
        got.append(item)
        if len(got) == 40:
            done.set()

    expected = NmeaStreamParser().feed(b"".join(lines))
    with pty_pair() as (master, _, path):
        link = SerialLink(path, NmeaStreamParser(), baudrate=4800, on_record=on_record, timestamp=True)
        link.start(wait_connected_s=WAIT_S)
        t0 = time.time_ns()
        try:
            write_chunks(master, stream, sizes=(7, 1, 90, 13))
            assert done.wait(WAIT_S)
        finally:
            link.stop()
        t1 = time.time_ns()
    assert [rec for _, rec in got] == expected
    assert all(t0 <= ts <= t1 for ts, _ in got)
    assert link.parser.stats.rejected == 1 + 19  # the broken GGA and the 19 junk lines


def test_reconnects_when_the_device_vanishes(tmp_path):
    port = tmp_path / "gps"  # the configured port is a symlink, re-pointed to a new device
    q: queue.Queue = queue.Queue()
    with pty_pair() as (m1, s1, path1):
        os.symlink(path1, port)
        link = SerialLink(str(port), NmeaStreamParser(), queue=q, reconnect_initial_s=0.02, reconnect_max_s=0.1)
        link.start(wait_connected_s=WAIT_S)
        try:
            assert link.device == os.path.realpath(path1)
            os.write(m1, hdt(10.0))
            first = drain(q, 1)
            with pty_pair() as (m2, _, path2):  # opened while the first exists: a different device
                assert path2 != path1
                os.close(m1)
                os.close(s1)  # the first device is gone
                assert wait_until(lambda: link.stats.disconnects >= 1)
                tmp_link = tmp_path / "gps.new"
                os.symlink(path2, tmp_link)
                os.replace(tmp_link, port)
                assert wait_until(lambda: link.connected and link.device == os.path.realpath(path2))
                os.write(m2, hdt(20.0))
                second = drain(q, 1)
                link.stop()  # before the second device goes away
        finally:
            link.stop()
    assert len(first) == 1 and first[0].heading_rad == pytest.approx(10.0 * DEG)
    assert len(second) == 1 and isinstance(second[0], HdtHeading)
    assert second[0].heading_rad == pytest.approx(20.0 * DEG)
    assert link.stats.connects >= 2 and link.stats.disconnects >= 1
    assert link.stats.records == 2 and not link.running and not link.connected


def test_open_timeouts_name_the_port(tmp_path):
    missing = str(tmp_path / "no-such-tty")
    t0 = time.monotonic()
    with pytest.raises(SerialOpenTimeout) as ei:
        open_port(missing, timeout_s=0.3)
    assert time.monotonic() - t0 < 2.0
    assert ei.value.port == missing and missing in str(ei.value) and ei.value.last_error is not None
    link = SerialLink(missing, NmeaStreamParser(), queue=queue.Queue(), reconnect_initial_s=0.05)
    with pytest.raises(SerialOpenTimeout, match="no-such-tty"):
        link.start(wait_connected_s=0.3)
    assert not link.running and link.stats.open_failures >= 1
    with pty_pair() as (_, _, path):  # invalid settings fail at once, naming the port
        with pytest.raises(ValueError):
            open_port(path, baudrate=-5, timeout_s=5.0)
        bad = SerialLink(path, NmeaStreamParser(), baudrate=-5, queue=queue.Queue())
        with pytest.raises(SerialOpenTimeout, match=path):
            bad.start(wait_connected_s=0.3)
        assert isinstance(bad.last_open_error, ValueError) and not bad.running


def test_open_port_opens_a_pty():
    with pty_pair() as (master, _, path):
        ser = open_port(path, 9600, timeout_s=1.0, read_timeout_s=1.0)
        try:
            os.write(master, b"abc")
            assert ser.read(3) == b"abc"
        finally:
            ser.close()


def test_stop_is_prompt_and_errors_in_parser_or_callback_do_not_kill_the_reader():
    class Touchy(NmeaStreamParser):  # a parser with a bug on one input
        def feed(self, data):
            if b"BOOM" in data:
                raise RuntimeError("parser bug")
            return super().feed(data)

    delivered: list = []

    def on_record(rec):
        delivered.append(rec)
        if len(delivered) == 1:
            raise ValueError("callback bug")

    q: queue.Queue = queue.Queue(maxsize=1)
    with pty_pair() as (master, _, path):
        link = SerialLink(path, Touchy(), on_record=on_record, queue=q)
        link.start(wait_connected_s=WAIT_S)
        try:
            os.write(master, hdt(1.0))
            assert wait_until(lambda: len(delivered) == 1)
            os.write(master, b"BOOM\r\n")
            assert wait_until(lambda: link.stats.parser_errors == 1)
            os.write(master, hdt(2.0) + hdt(3.0))
            assert wait_until(lambda: len(delivered) == 3)
        finally:
            t0 = time.monotonic()
            link.stop()
            stop_s = time.monotonic() - t0
    assert stop_s < 1.0 and not link.running
    assert link.stats.callback_errors == 1 and link.stats.records == 3
    assert link.stats.records_dropped == 2  # queue of 1, nobody reading
    link.stop()  # stopping twice is harmless
    with pytest.raises(ValueError):
        SerialLink("/dev/null", NmeaStreamParser())  # nowhere to deliver
