"""Fault injection from a file: validation naming the file and key, and a real
``svss sim-device`` run whose faults the drivers detect, report and survive."""

from __future__ import annotations

import queue
import sys
import time

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.faults import KINDS, load_faults, parse_faults
from sim_device.scene import load_scene
from sim_device.track import parse_utc_ns
from svss_daq.config import ConfigError
from svss_daq.drivers.digitiser import DigitiserClient
from svss_daq.drivers.sequencer import SequencerDriver, SequencerTimeout
from svss_daq.protocols import digitiser as dg

from .conftest import DEMO

WAIT_S = 5.0

FAULTS = """
seed = 7

[[fault]]
at_s = 0.45
kind = "digitiser.drop_frames"
frame = 2

[[fault]]
at_s = 0.85
kind = "digitiser.corrupt_frames"
frame = 4

[[fault]]
at_s = 1.25
kind = "digitiser.reset"

[[fault]]
at_s = 1.75
kind = "sequencer.garbage"
length = 300

[[fault]]
at_s = 1.85
kind = "digitiser.garbage"
length = 400

[[fault]]
at_s = 2.05
kind = "sequencer.vanish"
seconds = 0.5

[[fault]]
at_s = 3.25
kind = "clock.step"
step_s = 0.25

[[fault]]
at_s = 0.2
after = "track"
kind = "gps.outage"
seconds = 1.0

[[fault]]
at_s = 0.3
after = "track"
kind = "dvl.bottom_lock_loss"
seconds = 1.0

[[fault]]
at_s = 0.5
kind = "dvl.garbage"
text = "$GARBAGE"
"""


# ------------------------------------------------------------------ the file


def test_faults_file_parses_sorted_with_defaults(tmp_path):
    f = tmp_path / "faults.toml"
    f.write_text(FAULTS)
    faults, seed = load_faults(f)
    assert seed == 7 and len(faults) == 10
    assert [x.after for x in faults[:2]] == ["track", "track"]  # track-relative first
    assert [x.at_s for x in faults[2:]] == sorted(x.at_s for x in faults[2:])
    drop = next(x for x in faults if x.kind == "digitiser.drop_frames")
    assert drop.params == {"frame": 2, "pings": 1} and drop.after == "start"
    assert set(KINDS) >= {x.kind for x in faults}


@pytest.mark.parametrize("body, key, expected", [
    ('[[fault]]\nat_s = 1\nkind = "digitiser.explode"', "fault[0].kind", "one of"),
    ('[[fault]]\nat_s = -1\nkind = "digitiser.reset"', "fault[0].at_s", ">= 0"),
    ('[[fault]]\nkind = "digitiser.reset"', "fault[0].at_s", "got nothing"),
    ('[[fault]]\nat_s = 1\nafter = "lunch"\nkind = "digitiser.reset"', "fault[0].after",
     "'start'"),
    ('[[fault]]\nat_s = 1\nkind = "gps.outage"', "fault[0].seconds", "number of seconds"),
    ('[[fault]]\nat_s = 1\nkind = "gps.outage"\nseconds = "long"', "fault[0].seconds",
     "got 'long'"),
    ('[[fault]]\nat_s = 1\nkind = "clock.step"\nstep_s = 0', "fault[0].step_s", "non-zero"),
    ('[[fault]]\nat_s = 1\nkind = "digitiser.reset"\nframe = 2', "fault[0].frame",
     "unknown key"),
    ('[[fault]]\nat_s = 1\nkind = "digitiser.reset"\n[[fault]]\nat_s = 2\n'
     'kind = "sequencer.garbage"\nlength = 0', "fault[1].length", "1..1048576"),
    ('faults = 3', "faults", "unknown key"),
])
def test_faults_file_errors_name_the_file_and_key(tmp_path, body, key, expected):
    f = tmp_path / "bad.toml"
    f.write_text(body)
    with pytest.raises(ConfigError) as e:
        load_faults(f)
    msg = str(e.value)
    assert str(f) in msg and f"'{key}'" in msg and expected in msg, msg


def test_faults_file_not_toml_names_the_file(tmp_path):
    f = tmp_path / "x.toml"
    f.write_text("[[fault]\n")
    with pytest.raises(ConfigError, match=f"{f}: not valid TOML"):
        load_faults(f)
    assert parse_faults({}, "none") == ([], 0)


# ------------------------------------------------------------------ a real run


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs pseudo-terminals")
def test_drivers_detect_report_and_survive_every_fault(sim_device_factory, hardware,
                                                       tmp_path):
    faults = tmp_path / "faults.toml"
    faults.write_text(FAULTS)
    dev = sim_device_factory("--faults", str(faults), name="faults")
    hw = hardware.value
    scene = load_scene(DEMO)
    t_track = parse_utc_ns(scene.track.start_time_utc)
    interval = round(hw.sequencer.ping_interval_s * 1e9)
    seq = SequencerDriver.from_config(dev.devices.sequencer).open()
    dig = DigitiserClient.from_config(dev.devices.digitiser).open(wait_connected_s=WAIT_S)
    events, items = [], []
    try:
        seq.configure(hw)
        seq.arm()
        dig.start()
        seq.start()
        t_end = time.monotonic() + 4.2
        while time.monotonic() < t_end:
            while not seq.ping_queue.empty():
                events.append(seq.ping_queue.get())
            try:
                items.append(dig.ping_queue.get(timeout=0.05))
            except queue.Empty:
                continue
        # the sequencer answers after garbage and its vanishing (the link's reconnection
        # backs off up to reconnect_max_s, so on a loaded machine give it time)
        assert seq.link.wait_connected(15.0)
        for attempt in range(5):
            try:
                st = seq.status()
                break
            except SequencerTimeout:
                if attempt == 4:
                    raise
        seq.stop()
        while not seq.ping_queue.empty():
            events.append(seq.ping_queue.get())
    finally:
        dig.close()
        seq.close()
    logs = dev.logs()
    assert logs.count("fired at simulated t") == 10, logs
    assert st.state == "RUNNING"

    complete = [p for p in items if isinstance(p, dg.CompletePing)]
    incomplete = [p for p in items if isinstance(p, dg.IncompletePing)]
    # dropped frame: reported missing; corrupt frame: reported corrupt
    assert any(p.missing_frames == (2,) and p.frame_count == 5 for p in incomplete), incomplete
    assert any("corrupt" in p.reason for p in incomplete), incomplete
    # connection reset: detected, reconnected, streaming restarted by the driver
    assert dig.disconnects == 1 and dig.connects == 2
    last_reset = max(p.ping_number for p in complete)
    assert last_reset > 30  # pings kept coming after the reset (about ping 13)
    # garbage on the TCP stream: skipped, counted
    assert dig.decoder.frames.stats.bytes_discarded >= 400
    # every ping number at most once, in order, and every complete ping intact
    numbers = [p.ping_number for p in items]
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    src = EnvironmentSource(hardware, scene)
    step = 250_000_000
    stepped = 0
    for p in complete:
        rel = p.transmit_time_ns - t_track
        if rel % interval:          # after the clock step
            rel -= step
            stepped += 1
        k = rel // interval
        assert rel % interval == 0
        assert np.array_equal(p.samples, src.ping(k).samples), k
    assert stepped >= 5
    # the sequencer: garbage skipped and counted; the vanished port reopened, the pings
    # lost meanwhile counted as a gap; the clock step seen in the transmit times
    assert seq.parser.stats.bytes_discarded >= 250
    seqs = [e.sequence for e in events]
    assert seqs == sorted(seqs) and seq.missed_pings == (seqs[-1] + 1 - len(seqs)) >= 3
    dt = np.diff([e.transmit_time_ns for e in events]) - interval * np.diff(seqs)
    assert sorted(set(dt.tolist())) == [0, step]
    # the sequencer's and the digitiser's stamps agree ping by ping
    by_seq = {e.sequence: e for e in events}
    assert all(p.transmit_time_ns == by_seq[p.ping_number].transmit_time_ns
               for p in complete if p.ping_number in by_seq)
    assert "Traceback" not in logs
