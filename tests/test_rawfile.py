"""Raw-run files: round trip, NMEA, bad files, and a writer killed with SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest

from svss_daq.rawfile import (FORMAT, RawFileError, RawRunReader, RawRunWriter,
                              svss_format)
from tests.test_messages import assert_same, make_ping


def _ping_for(hardware, i):
    p = make_ping(i)
    return type(p)(sequence=p.sequence, projector=p.projector,
                   transmit_time_ns=p.transmit_time_ns, sample_rate_hz=p.sample_rate_hz,
                   window_start_ns=p.window_start_ns, samples=p.samples, nav=p.nav,
                   config_id=hardware.id)


def test_round_trip(tmp_path, hardware):
    path = tmp_path / "run.h5"
    sent = [_ping_for(hardware, i) for i in range(12)]
    with RawRunWriter(path, hardware, flush_every_pings=5, environment={"sound_speed": 1480.0},
                      run_attrs={"scene_name": "t"}) as w:
        for p in sent:
            w.append(p)
        w.append_nmea(123, "$GPGGA,120000.00,4052.0,N,07752.0,W,1,08,0.9,10.0,M,,,,*47\r\n")
    with RawRunReader(path) as r:
        assert r.clean and len(r) == 12
        assert r.hardware.id == hardware.id and r.hardware.value == hardware.value
        for a, b in zip(sent, r):
            assert_same(a, b)
        assert r.nmea() == [(123, "$GPGGA,120000.00,4052.0,N,07752.0,W,1,08,0.9,10.0,M,,,,*47")]
        assert r.environment["sound_speed"] == 1480.0
    with h5py.File(path, "r") as f:        # SONAR-netCDF4-like layout
        assert f["Sonar/Beam_group1/backscatter_r"].shape == (12, 80, 1500)
        assert f["Sonar/Beam_group1/backscatter_r"].chunks == (1, 80, 1500)
        for g in ("Platform", "Platform/NMEA", "Environment", "Provenance", "Vendor_specific"):
            assert g in f


def test_reader_tables_and_provenance(tmp_path, hardware):
    """The whole-run tables a summary reads: per-ping records, navigation, shape and
    provenance, equal to what the pings read one by one carry."""
    path = tmp_path / "run.h5"
    sent = [_ping_for(hardware, i) for i in range(7)]
    with RawRunWriter(path, hardware) as w:
        for p in sent:
            w.append(p)
    with RawRunReader(path) as r:
        assert r.shape == sent[0].samples.shape == (80, 1500)
        table = r.ping_table()
        assert set(table) == {"ping_time", "ping_sequence", "transmit_projector",
                              "window_start_ns"}
        np.testing.assert_array_equal(table["ping_sequence"], [p.sequence for p in sent])
        np.testing.assert_array_equal(table["ping_time"], [p.transmit_time_ns for p in sent])
        np.testing.assert_array_equal(table["transmit_projector"], [p.projector for p in sent])
        np.testing.assert_array_equal(table["window_start_ns"],
                                      [p.window_start_ns for p in sent])
        nav = r.nav_table()
        np.testing.assert_array_equal(nav["time1"], [p.nav.time_ns for p in sent])
        for name in ("north_m", "east_m", "heading_rad", "altitude_m", "quality"):
            np.testing.assert_array_equal(nav[name], [getattr(p.nav, name) for p in sent])
        # the tables are copies: changing one does not change what the reader returns
        table["ping_sequence"][:] = -1
        assert r.ping(0).sequence == sent[0].sequence
        with h5py.File(path, "r") as f:
            assert r.provenance == dict(f["Provenance"].attrs) and r.provenance


def test_svss_format_names_the_kind_of_file(tmp_path, hardware):
    run = tmp_path / "run.h5"
    with RawRunWriter(run, hardware) as w:
        w.append(_ping_for(hardware, 0))
    assert svss_format(run) == FORMAT
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["svss_format"] = np.bytes_(b"SVSS tile")
    assert svss_format(other) == "SVSS tile"
    bare = tmp_path / "bare.h5"
    h5py.File(bare, "w").close()
    assert svss_format(bare) is None
    with pytest.raises(RawFileError, match="missing.h5: no such file"):
        svss_format(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all" * 10)
    with pytest.raises(RawFileError, match="junk.h5: not a readable HDF5 file"):
        svss_format(junk)


def test_writer_rejects_wrong_shape_and_config(tmp_path, hardware):
    with RawRunWriter(tmp_path / "r.h5", hardware) as w:
        with pytest.raises(ValueError, match=r"shape \(80, 10\)"):
            w.append(make_ping(1, nch=80, ns=10))
        with pytest.raises(ValueError, match="hardware config abcdef0123456789"):
            w.append(make_ping(1))


def test_reader_errors_name_the_file(tmp_path):
    with pytest.raises(RawFileError, match="no such file"):
        RawRunReader(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all" * 10)
    with pytest.raises(RawFileError, match="junk.h5: not a readable HDF5 file"):
        RawRunReader(junk)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["svss_format"] = "something-else"
    with pytest.raises(RawFileError, match="other.h5: root attribute 'svss_format'"):
        RawRunReader(other)


WRITER = textwrap.dedent("""
    import sys
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    from svss_daq.rawfile import RawRunWriter
    from tests.test_rawfile import _ping_for
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    w = RawRunWriter(sys.argv[1], hw, flush_every_pings=4, flush_interval_s=1e9)
    i = 0
    while True:
        w.append(_ping_for(hw, i))
        i += 1
        if w.n_flushed == i:
            print("flushed", i, flush=True)
""")


def test_sigkill_keeps_everything_up_to_last_flush(tmp_path, hardware):
    path = tmp_path / "killed.h5"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE,
                            text=True, cwd=root, env={**os.environ, "PYTHONPATH": root})
    flushed = 0
    deadline = time.monotonic() + 60
    while flushed < 40 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        flushed = int(line.split()[1])
    proc.send_signal(signal.SIGKILL)          # mid-run, no chance to close the file
    proc.wait(timeout=10)
    assert flushed >= 40, "writer did not get going"
    assert svss_format(path) == FORMAT       # also a file its writer left open
    with RawRunReader(path) as r:
        assert not r.clean
        assert len(r) >= flushed              # nothing flushed is lost
        for i in range(len(r)):               # and everything read back is intact
            assert_same(_ping_for(hardware, i), r.ping(i))


def _ensembles(n):
    from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble
    return [encode_ensemble(Pd0Setup(), ensemble_number=k + 1,
                            time_ns=1_790_000_000_000_000_000 + k * 200_000_000,
                            heading_rad=0.5, pitch_rad=0.01, roll_rad=-0.02,
                            bt_velocity_m_s=[0.0, -1.0, 0.0, 0.0], bt_range_m=[2.0 + k] * 4)
            for k in range(n)]


def test_instrument_records_round_trip(tmp_path, hardware):
    """The PD0 ensembles (exact bytes, receive times), the ping-clock events and the
    navigation configuration a run keeps for re-navigation, read back as written, also
    across the records' chunks; and the writer's layout."""
    from svss_daq.protocols.pd0 import decode_ensemble
    from svss_daq.rawfile import NAV_CONFIG_ATTR, PD0_CHUNK
    path = tmp_path / "run.h5"
    ens = _ensembles(3)
    big = [bytes(range(256)) * 300] * 5             # 76800 bytes each: across chunks
    nav_text = "dvl_min_beams = 3\ngps_max_sigma_m = 2.0\n"
    with RawRunWriter(path, hardware, run_attrs={NAV_CONFIG_ATTR: nav_text}) as w:
        w.append(_ping_for(hardware, 0))
        for k, b in enumerate(ens + big):
            w.append_pd0(1000 + k, b)
        w.append_clock_reference(77, 70)
        w.append_clock_reference(88, 80)
        with pytest.raises(ValueError, match="empty PD0 ensemble"):
            w.append_pd0(5, b"")
    assert sum(map(len, big)) > 5 * PD0_CHUNK
    with RawRunReader(path) as r:
        assert r.keeps_pd0 and r.n_pd0 == 8
        assert r.pd0() == [(1000 + k, b) for k, b in enumerate(ens + big)]
        assert [decode_ensemble(b).bottom_track.range_m[0] for _, b in r.pd0()[:3]] == \
            pytest.approx([2.0, 3.0, 4.0])
        assert r.ping_clock() == [(77, 70), (88, 80)]
        assert r.navigation_config == nav_text
    with h5py.File(path, "r") as f:
        g = f["Platform/PD0"]
        assert g["stream"].dtype == np.uint8 and g["time"].dtype == np.int64
        assert list(g["offset"][:4]) == [0, len(ens[0]), len(ens[0]) + len(ens[1]),
                                         sum(map(len, ens))]


def test_files_without_the_instrument_records_still_open(tmp_path, hardware):
    """Files written before the PD0 ensembles and the ping clock were kept (their groups
    absent) open and read as before, with none."""
    path = tmp_path / "old.h5"
    sent = [_ping_for(hardware, i) for i in range(3)]
    with RawRunWriter(path, hardware) as w:
        for p in sent:
            w.append(p)
        w.append_nmea(5, "$GPHDT,12.5,T*03")
    with h5py.File(path, "a") as f:
        del f["Platform/PD0"], f["Platform/ping_clock"]
    with RawRunReader(path) as r:
        assert not r.keeps_pd0 and r.n_pd0 == 0 and r.pd0() == []
        assert r.ping_clock() == [] and r.navigation_config is None
        assert r.nmea() == [(5, "$GPHDT,12.5,T*03")]
        for a, b in zip(sent, r):
            assert_same(a, b)


def test_pd0_records_outside_the_stream_are_cut_with_a_warning(tmp_path, hardware, caplog):
    path = tmp_path / "run.h5"
    ens = _ensembles(4)
    with RawRunWriter(path, hardware) as w:
        w.append(_ping_for(hardware, 0))
        for k, b in enumerate(ens):
            w.append_pd0(k, b)
    with h5py.File(path, "a") as f:                # a damaged index: entry 2 past the end
        f["Platform/PD0/offset"][2] = 10**6
    with caplog.at_level("WARNING"), RawRunReader(path) as r:
        assert r.pd0() == [(0, ens[0]), (1, ens[1])]
    assert "PD0 ensemble 2 of 4 at byte 1000000" in caplog.text
    with h5py.File(path, "a") as f:                # a stream of the wrong type
        del f["Platform/PD0/stream"]
        f["Platform/PD0"].create_dataset("stream", data=np.zeros(4, np.float32))
    with pytest.raises(RawFileError, match="'/Platform/PD0/stream' has dtype float32"):
        RawRunReader(path)
