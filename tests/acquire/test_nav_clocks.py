"""``svss acquire`` with a DVL whose clock is years off the ping clock, and the
navigation tallies of the daemon.

The DVL is a real one: Teledyne RDI ensembles from ../shared/data replayed byte for byte
on a pseudo-terminal at the instrument's own pace -- first a Workhorse that sends no
bottom track at all (RDI_test01.000, its clock in 2011) while the daemon starts, then a
Workhorse with bottom lock (RDI_withBT.000 from ensemble 860, its clock in May 2017) --
beside ``svss sim-device``'s sequencer, digitiser and GPS, whose clock (the ping clock,
the scene's time) runs twice as fast as the host's."""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time
import types

import numpy as np
import pytest

from sim_device.devices.serial_device import SerialDevice
from svss_daq.acquire_config import load_acquire
from svss_daq.config import DevicesConfig, load
from svss_daq.daemon import AcquisitionDaemon
from svss_daq.protocols.pd0 import Pd0StreamParser, decode_ensemble
from svss_daq.ping import (NAV_BOTTOM_LOCK, NAV_CLOCK_RETIMED, NAV_GPS_FIX, NAV_HELD,
                           NavSnapshot)
from svss_daq.rawfile import RawRunReader
from svss_daq.status import format_status, read_status
from tests.conftest import SHARED_DATA

from .conftest import acquire_toml

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux pseudo-terminals")

NO_BT = SHARED_DATA / "dvl_pd0" / "RDI_test01.000"
WITH_BT = SHARED_DATA / "dvl_pd0" / "RDI_withBT.000"
LOCKED_FROM = 860          # RDI_withBT.000: bottom lock from this ensemble to the end
TIME_SCALE = 2.0
YEAR_S = 365.25 * 86400
STOP_AFTER_RETIMED = 30    # re-timed pings in the status before the run is stopped


def ensemble_bytes(path) -> list[tuple[int, bytes]]:
    """(instrument time ns, the ensemble's bytes) of every ensemble in a PD0 file, cut
    at the header's byte count (+ 2 checksum bytes) and checked by decoding each."""
    data = path.read_bytes()
    pos = data.index(b"\x7f\x7f")
    out = []
    while pos + 4 <= len(data):
        n = int.from_bytes(data[pos + 2:pos + 4], "little") + 2
        if pos + n > len(data):
            break
        ens = decode_ensemble(data[pos:pos + n])
        out.append((ens.variable.time_ns, data[pos:pos + n]))
        pos += n
    assert len(out) == len(Pd0StreamParser().feed(data))
    return out


class Replay(threading.Thread):
    """Writes ensembles on a pty at the instrument's pace (its own spacing over the time
    scale): ``first`` over and over until :attr:`switch` is set, then ``then``."""

    def __init__(self, dev: SerialDevice, first, then):
        super().__init__(daemon=True)
        self.dev, self.first, self.then = dev, first, then
        self.switch, self.stop_flag = threading.Event(), threading.Event()
        self.sent_second = 0

    def _play(self, ensembles, until) -> None:
        for (t, raw), (t_next, _) in zip(ensembles, ensembles[1:] + ensembles[-1:]):
            if self.stop_flag.is_set() or until():
                return
            self.dev.write(raw)
            if ensembles is self.then:
                self.sent_second += 1
            time.sleep(max(t_next - t, 0) * 1e-9 / TIME_SCALE or 0.25)

    def run(self) -> None:
        while not self.switch.is_set() and not self.stop_flag.is_set():
            self._play(self.first, self.switch.is_set)
        self._play(self.then, lambda: False)


@pytest.mark.slow
def test_dvl_clock_years_off_is_named_retimed_and_posed(rig, tmp_path):
    for f in (NO_BT, WITH_BT):
        if not f.exists():
            pytest.skip(f"real recordings not found: {f.parent}")
    no_bt = ensemble_bytes(NO_BT)
    locked = ensemble_bytes(WITH_BT)[LOCKED_FROM:]
    dev = rig.device("--time-scale", str(TIME_SCALE))
    (tmp_path / "replay").mkdir()
    dvl = SerialDevice(tmp_path / "replay", "dvl").start()
    text = dev.out.read_text()
    start = text.index("[dvl]")
    end = text.index("\n[", start + 1)
    devices = tmp_path / "devices-real-dvl.toml"
    devices.write_text(text[:start] + f'[dvl]\nport = "{dvl.port}"\nbaudrate = 115200\n'
                       + text[end:])
    replay = Replay(dvl, no_bt, locked)
    replay.start()
    try:
        # run until the status shows enough re-timed pings (a condition, not a time: a
        # loaded machine pings slower); the duration only bounds a run that never gets there
        acq = rig.acquire(types.SimpleNamespace(out=devices), "--duration", "300")
        # the pings start (the DVL's ensembles without bottom track count as a DVL
        # there): from then on the DVL with bottom lock
        deadline = time.monotonic() + 60
        while "pinging every" not in acq.logs() and time.monotonic() < deadline:
            if acq.proc.poll() is not None:
                break
            time.sleep(0.02)
        replay.switch.set()
        last, stopped = None, False
        while acq.proc.poll() is None:
            try:
                last = read_status(acq.endpoints["status"], timeout_s=2)
            except TimeoutError:     # a loaded machine, or no status after the run:
                continue             # the last one read stays, until the daemon exits
            if not stopped and last["navigation"]["clock_retimed"] >= STOP_AFTER_RETIMED \
                    and replay.sent_second >= 8:
                acq.proc.send_signal(signal.SIGTERM)    # flushed, closed, summarised
                stopped = True
        assert stopped, acq.logs()[-4000:]
        assert acq.wait(60) == 130, acq.logs()[-4000:]
    finally:
        replay.stop_flag.set()
        replay.join(5)
        dvl.close()
    logs = acq.logs()
    assert "pinging every" in logs and "no DVL ensemble within" not in logs, logs[-3000:]
    assert replay.sent_second >= 8
    [f] = acq.files()
    with RawRunReader(f) as run:
        events = run.events()
        summary = run.summary
        table = run.nav_table()
    clock = [d for _, k, d in events if k == "navigation.clock_offset"]
    assert clock and all(d.startswith("dvl clock -") for d in clock), clock
    assert clock[-1].startswith("dvl clock -9.5") and "years" in clock[-1], clock
    # in the status stream: the DVL named and re-timed, the simulated GPS (on the ping
    # clock at twice the host's pace) measured close and left alone
    sol = last["navigation"]["solution"]
    assert sol["clock_retimed"] == ["dvl"], sol
    assert -9.6 < sol["clock_offset_s"]["dvl"] / YEAR_S < -9.4
    # the GPS's offset is its transport latency on the ping clock: 0.2-0.5 s quiet, 1.8 s
    # with two CPU hogs beside the suite (host delays doubled by the time scale of 2);
    # within the limit the navigation judges clocks by, so it is measured, not re-timed
    limit = load(DevicesConfig, devices).navigation.clock_max_offset_s
    assert abs(sol["clock_offset_s"]["gps"]) < limit
    assert "navigation.clock_offset" in last["event_counts"]
    assert "clock offset" in format_status(last) and "dvl" in format_status(last)
    # the poses: the re-timed DVL gives bottom lock and altitude, flagged re-timed
    q = table["quality"]
    retimed = (q & NAV_CLOCK_RETIMED) != 0
    assert retimed.sum() >= 20 and summary["navigation"]["clock_retimed"] == int(retimed.sum())
    lock = retimed & ((q & NAV_BOTTOM_LOCK) != 0)
    assert lock.sum() > retimed.sum() // 2
    assert np.isfinite(table["altitude_m"][lock]).all()
    assert 5.0 < np.median(table["altitude_m"][lock]) < 15.0     # ranges of 8-11 m
    assert np.isfinite(table["north_m"]).all() and (q & NAV_GPS_FIX).sum() > len(q) // 2


def test_held_poses_are_counted_reported_and_evented(tmp_path):
    """Pings posed on the last navigation sample held (a DVL slower than the wait):
    counted in the tallies, the status and the run's summary, one event when it starts
    and one when it stops."""
    daemon = AcquisitionDaemon(load_acquire(acquire_toml(tmp_path)))
    t0 = 1_800_000_000 * 10**9

    def pose(k, q):
        return NavSnapshot(t0 + k * 10**8, 1.0, 2.0, 3.0, 0, 0, 0, 0, 0, 0, 5.0, quality=q)

    base = NAV_GPS_FIX | NAV_BOTTOM_LOCK
    clear = int(daemon.setup.devices.navigation.held_clear_s * 10)    # pings at 10 Hz
    # held pings with a few current ones between (a slow DVL): one event, not one each
    qs = [base] * 3 + ([NAV_HELD | NAV_BOTTOM_LOCK] * 2 + [base] * 3) * 2
    qs += [base] * (clear + 1) + [base | NAV_HELD] * 2
    for k, q in enumerate(qs):
        daemon.nav.count(pose(k, q))
    kinds = [k for _, k, _ in daemon.events]
    assert kinds.count("navigation.held") == 2 and kinds.count("navigation.held_end") == 1
    assert kinds.index("navigation.held") < kinds.index("navigation.held_end")
    nav = daemon.status()["navigation"]
    assert nav["held"] == 6 and nav["mode"] == "gps"
    assert daemon.nav_tally.held == 6 and daemon.summary()["navigation"]["held"] == 6
    assert "holding" not in daemon.summary()["navigation"]
    assert "held 6" in format_status(daemon.status())
    daemon.nav.count(pose(20, NAV_HELD))
    assert daemon.status()["navigation"]["mode"] == "held"


def test_bottom_lock_lost_names_the_reason(tmp_path, caplog):
    """'no DVL bottom track' only where the DVL sent ensembles without it near the ping;
    a DVL whose samples are nowhere near the ping (silent, slow, its clock elsewhere)
    is said so."""
    from svss_daq.nav.records import DvlSample
    caplog.set_level(logging.INFO)
    daemon = AcquisitionDaemon(load_acquire(acquire_toml(tmp_path)))
    t0 = 1_800_000_000 * 10**9
    far = t0 - int(9.5 * YEAR_S * 1e9)
    daemon.navigator.add_dvl(DvlSample(far, (1.0, 0.0, 0.0), (5.0,) * 4))
    daemon.nav.count(NavSnapshot(t0, 1, 2, 3, 0, 0, 0, 0, 0, 0, float("nan"),
                                 quality=NAV_GPS_FIX))
    [(_, kind, detail)] = [e for e in daemon.events if e[1] == "navigation.bottom_lock_lost"]
    assert "no DVL ensemble within" in detail and "-9.50 years" in detail
    daemon.nav.count(NavSnapshot(t0 + 10**8, 1, 2, 3, 0, 0, 0, 0, 0, 0, 5.0,
                                 quality=NAV_GPS_FIX | NAV_BOTTOM_LOCK))
    daemon.navigator.add_dvl(DvlSample(t0 + 2 * 10**8, (np.nan,) * 3, (np.nan,) * 4))
    daemon.nav.count(NavSnapshot(t0 + 2 * 10**8, 1, 2, 3, 0, 0, 0, 0, 0, 0, float("nan"),
                                 quality=NAV_GPS_FIX))
    lost = [d for _, k, d in daemon.events if k == "navigation.bottom_lock_lost"]
    assert lost[-1].startswith("no DVL bottom track")
