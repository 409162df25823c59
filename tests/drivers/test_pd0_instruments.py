"""PD0 as other RDI instruments send it: beam coordinates, the five-beam (Sentinel V)
layout, 0x7F79 vendor blocks between ensembles and known but undecoded data types."""

from __future__ import annotations

import logging
import math
import struct

import numpy as np
import pytest

from svss_daq.protocols import pd0
from svss_daq.protocols.pd0_encoder import Pd0Setup, encode_ensemble

T0 = 1_700_000_000_000_000_000


def ens(setup, k=0, vel=(0.1, -0.2, 0.3, 0.0), rng=(2.0, 2.1, 2.2, 2.3), **kw):
    return encode_ensemble(setup, ensemble_number=k, time_ns=T0 + k * 125_000_000,
                           heading_rad=0.5, pitch_rad=0.01, roll_rad=-0.02,
                           bt_velocity_m_s=vel, bt_range_m=rng, **kw)


@pytest.mark.parametrize("pattern", ["convex", "concave"])
@pytest.mark.parametrize("angle", [20.0, 30.0])
def test_beam_coordinates_pattern_and_alignment_round_trip(pattern, angle):
    s = Pd0Setup(coordinate_system="beam", beam_pattern=pattern, beam_angle_deg=angle,
                 heading_alignment_deg=-45.0)
    e = pd0.decode_ensemble(ens(s, vel=(0.123, -0.456, 0.789, -0.012)))
    assert e.fixed.coordinate_system == "beam"
    assert e.fixed.coord_transform & 0x18 == 0          # EX bits 3-4: beam
    assert e.fixed.beam_pattern == pattern
    assert e.fixed.beam_angle_rad == pytest.approx(math.radians(angle))
    assert e.fixed.heading_alignment_rad == pytest.approx(math.radians(-45.0))
    assert e.fixed.tilts_used and e.fixed.three_beam_allowed
    assert np.allclose(e.bottom_track.velocity_mps, (0.123, -0.456, 0.789, -0.012))
    assert e.fixed.n_beams == 4 and not e.fixed.vertical_beam and e.vertical_beam is None


def test_five_beam_sentinel_v_frequency_and_vertical_range():
    s = Pd0Setup(firmware=(47, 19), frequency_hz=307.2e3, vertical_beam=True,
                 beam_angle_deg=20.0)
    e = pd0.decode_ensemble(ens(s, vertical_range_m=1.987))
    f = e.fixed
    assert f.sentinel_v and f.vertical_beam
    assert f.n_beams == 5 and f.janus_beams == 4
    assert f.system_config & 0x7 == 2                    # the 300 kHz class code
    assert f.frequency_class_hz == 300e3
    assert f.system_frequency_hz == 307.2e3              # the true frequency
    assert e.vertical_beam is not None
    assert e.vertical_beam.range_m == pytest.approx(1.987)
    assert pd0.ID_BEAM5_RANGE in e.data_type_ids
    no_bottom = pd0.decode_ensemble(ens(s, vertical_range_m=None))
    assert math.isnan(no_bottom.vertical_beam.range_m)
    # a Workhorse of the same class code stays 300 kHz
    w = pd0.decode_ensemble(ens(Pd0Setup(frequency_hz=300e3))).fixed
    assert w.system_frequency_hz == 300e3 and not w.sentinel_v and w.n_beams == 4
    with pytest.raises(ValueError, match="frequency_hz"):
        Pd0Setup(frequency_hz=307.2e3).check()          # not a Sentinel V firmware


def test_five_beam_profiles_with_four_janus_columns_and_beam5_velocity():
    s = Pd0Setup(firmware=(47, 19), frequency_hz=307.2e3, vertical_beam=True)
    n_cells = 3
    # a water profile of the 4 Janus beams (0x0100) and the vertical beam (0x0A00)
    vel4 = struct.pack("<H", 0x0100) + struct.pack(f"<{4 * n_cells}h", *range(12))
    vel5 = struct.pack("<H", 0x0A00) + struct.pack(f"<{n_cells}h", 10, -32768, -20)
    raw = encode_ensemble(Pd0Setup(firmware=s.firmware, frequency_hz=s.frequency_hz,
                                   vertical_beam=True, n_cells=n_cells),
                          ensemble_number=1, time_ns=T0, heading_rad=0, pitch_rad=0, roll_rad=0,
                          bt_velocity_m_s=(0, 0, 0, 0), bt_range_m=(1, 1, 1, 1),
                          vertical_range_m=1.0, extra_blocks=[vel4, vel5])
    e = pd0.decode_ensemble(raw)
    assert e.velocity_mps.shape == (n_cells, 4)
    assert e.velocity_mps[2, 3] == pytest.approx(0.011)
    assert np.allclose(e.beam5_velocity_mps, [0.010, np.nan, -0.020], equal_nan=True)


def vendor_block(payload: bytes, checksum: bool = True) -> bytes:
    body = b"\x7f\x79" + struct.pack("<H", 4 + len(payload)) + payload
    tail = struct.pack("<H", pd0.ensemble_checksum(body)) if checksum else b"\xaa\x55"
    return body + tail


def test_vendor_blocks_are_skipped_quietly_and_summarised(caplog):
    s = Pd0Setup()
    ensembles = [ens(s, k) for k in range(6)]
    blocks = [vendor_block(bytes(range(k, k + 37))) for k in range(5)]
    blocks[2] = vendor_block(b"\x7f\x7f\x00" * 5, checksum=False)  # closed by the next header
    stream = b"".join(e + b for e, b in zip(ensembles, blocks)) + ensembles[-1]
    p = pd0.Pd0StreamParser()
    got = []
    with caplog.at_level(logging.INFO, logger="svss_daq.protocols.pd0"):
        for i in range(0, len(stream), 29):
            got += p.feed(stream[i:i + 29])
        got += p.flush()
    assert [g.ensemble_number for g in got] == list(range(6))
    assert p.stats.vendor_blocks == 5
    assert p.stats.vendor_block_bytes == sum(len(b) for b in blocks)
    assert p.stats.bytes_discarded == 0 and p.stats.discard_runs == 0
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    summary = [r.getMessage() for r in caplog.records if "0x7F79" in r.getMessage()]
    assert len(summary) == 1 and "5 vendor block" in summary[0]


def test_false_vendor_header_does_not_swallow_ensembles():
    s = Pd0Setup()
    a, b, c = ens(s, 1), ens(s, 2), ens(s, 3)
    # garbage claiming a block that covers ensemble b and ends where c begins
    fake = b"\x7f\x79" + struct.pack("<H", 4 + 3 + len(b) - 2) + b"xyz"
    stream = a + fake + b + c
    p = pd0.Pd0StreamParser()
    got = p.feed(stream) + p.flush()
    assert [g.ensemble_number for g in got] == [1, 2, 3]
    assert p.stats.vendor_blocks == 0 and p.stats.bytes_discarded == len(fake)


def test_known_undecoded_data_types_are_counted_without_warnings(caplog):
    s = Pd0Setup()
    adc = struct.pack("<H", 0x7001) + bytes(12)          # ADC data (dolfyn: known, skipped)
    attitude = struct.pack("<H", 0x5902) + bytes(103)    # ping attitude
    mystery = struct.pack("<H", 0x6A6A) + bytes(4)       # not known to anyone
    p = pd0.Pd0StreamParser()
    with caplog.at_level(logging.INFO, logger="svss_daq.protocols.pd0"):
        got = p.feed(b"".join(ens(s, k, extra_blocks=[adc, attitude, mystery]) for k in range(4)))
        got += p.flush()
    assert len(got) == 4 and 0x7001 in got[0].data_type_ids
    assert p.stats.known_types_skipped == 8 and p.stats.unknown_types == 4
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    lines = [r.getMessage() for r in caplog.records if "known but undecoded" in r.getMessage()]
    assert len(lines) == 1 and "0x5902" in lines[0] and "0x7001" in lines[0]
