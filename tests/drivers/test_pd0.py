"""PD0 decoder and stream parser: real Workhorse files against dolfyn's decodings,
targeted field checks, error reports, and property-based fuzzing of the stream."""

from __future__ import annotations

import functools
import logging
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svss_daq.protocols.pd0 import (
    MAX_ENSEMBLE_BYTES,
    Pd0DecodeError,
    Pd0Ensemble,
    Pd0StreamParser,
    decode_ensemble,
    ensemble_checksum,
)

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "dvl_pd0"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data folder missing: {DATA}")

h5py = pytest.importorskip("h5py")

# Deterministic by default so CI cannot flake; SVSS_FUZZ_EXAMPLES=5000 fuzzes deeper with fresh seeds.
_DEEP = int(os.environ.get("SVSS_FUZZ_EXAMPLES", "0"))
FUZZ = settings(max_examples=_DEEP or 100, deadline=2000, derandomize=not _DEEP, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@functools.lru_cache(maxsize=None)
def raw_file(name: str) -> bytes:
    return (DATA / name).read_bytes()


def split_ensembles(raw: bytes) -> list:
    """Cut a contiguous PD0 file at its byte counts (independent of the parser)."""
    out, pos = [], 0
    while pos + 4 <= len(raw):
        assert raw[pos:pos + 2] == b"\x7f\x7f"
        n = int.from_bytes(raw[pos + 2:pos + 4], "little") + 2
        if pos + n > len(raw):
            break
        out.append(raw[pos:pos + n])
        pos += n
    return out


@functools.lru_cache(maxsize=None)
def fuzz_pool() -> tuple:
    """Real ensembles used as intact material in the fuzz tests."""
    return tuple(split_ensembles(raw_file("RDI_withBT.000"))[:30] + split_ensembles(raw_file("RDI_test01.000"))[:8])


def key(e: Pd0Ensemble) -> tuple:
    return (e.fixed.serial_number, e.ensemble_number, e.time_ns)


@functools.lru_cache(maxsize=None)
def pool_keys() -> tuple:
    return tuple(key(decode_ensemble(b)) for b in fuzz_pool())


def assert_matches_float32(mine, ref, atol=1e-6, what=""):
    """|mine - ref| <= atol, allowing one float32 ulp because dolfyn stores float32."""
    mine = np.asarray(mine, dtype=np.float64)
    ref32 = np.asarray(ref, dtype=np.float32)
    ref = ref32.astype(np.float64)
    assert mine.shape == ref.shape, what
    assert np.array_equal(np.isnan(mine), np.isnan(ref)), f"{what}: NaN pattern differs"
    tol = atol + np.spacing(np.abs(ref32)).astype(np.float64)
    ok = np.isnan(ref) | (np.abs(mine - ref) <= tol)
    assert ok.all(), f"{what}: max diff {np.nanmax(np.abs(mine - ref))}"


def check_against_dolfyn(ens: list, nc: Path, n: int) -> None:
    ens = ens[:n]
    with h5py.File(nc, "r") as f:
        assert len(ens) == f["time"].shape[0] == n
        attrs = f.attrs
        fx = ens[0].fixed
        assert f["time"].attrs["units"] == b"seconds since 1970-01-01" or \
            f["time"].attrs["units"] == "seconds since 1970-01-01"
        # Configuration (fixed leader) against dolfyn's attributes.
        assert fx.n_cells == int(attrs["n_cells"][0]) and fx.n_beams == int(attrs["n_beams"][0])
        assert fx.cell_size_m == pytest.approx(float(attrs["cell_size"][0]), abs=1e-6)
        assert fx.blank_m == pytest.approx(float(attrs["blank_dist"][0]), abs=1e-9)
        assert fx.transmit_pulse_length_m == pytest.approx(float(attrs["transmit_pulse_m"][0]), abs=1e-9)
        assert fx.transmit_lag_m == pytest.approx(float(attrs["transmit_lag_m"][0]), abs=1e-9)
        assert fx.serial_number == int(attrs["serialnum"][0])
        assert fx.system_frequency_hz == 1e3 * int(attrs["carrier_freq"][0])
        assert fx.beam_angle_rad == pytest.approx(np.deg2rad(int(attrs["beam_angle"][0])))
        assert fx.orientation == attrs["orientation"].decode()
        assert fx.beam_pattern == attrs["beam_pattern"].decode()
        assert fx.coordinate_system == attrs["coord_sys"].decode()
        assert fx.heading_bias_rad == pytest.approx(np.deg2rad(float(attrs["magnetic_var_deg"][0])))
        assert f"{fx.firmware_version}.{fx.firmware_revision}" == f"{float(attrs['firmware_ver'][0]):.2f}"
        assert_matches_float32(fx.cell_distances_m, f["range"][:], what="range")

        # Per-ensemble scalars.
        t = np.array([e.time_ns for e in ens], dtype=np.int64)
        assert t.dtype == np.int64
        assert np.abs(t / 1e9 - f["time"][:]).max() <= 1e-6, "time"
        assert [e.ensemble_number for e in ens] == list(f["number"][:])
        for name, attr in (("heading", "heading_rad"), ("pitch", "pitch_rad"), ("roll", "roll_rad")):
            mine = np.array([getattr(e, attr) for e in ens])
            ref = np.deg2rad(f[name][:].astype(np.float64))
            assert np.abs(mine - ref).max() <= 1e-6, name
        assert_matches_float32([e.sound_speed_mps for e in ens], f["c_sound"][:], what="c_sound")
        assert_matches_float32([e.depth_m for e in ens], f["depth"][:], what="depth")
        assert_matches_float32([e.variable.temperature_degc for e in ens], f["temp"][:], what="temp")
        assert_matches_float32([e.variable.salinity_ppt for e in ens], f["salinity"][:], what="salinity")
        # dolfyn: pressure in dbar (1 dbar = 1e4 Pa)
        assert_matches_float32([e.variable.pressure_pa / 1e4 for e in ens], f["pressure"][:], what="pressure")

        # Water profile: dolfyn is (beam/dir, cell, time); ours (cell, beam) per ensemble.
        vel = np.stack([e.velocity_mps for e in ens], axis=-1).transpose(1, 0, 2)
        assert_matches_float32(vel, f["vel"][:], what="vel")
        for name, attr in (("corr", "correlation"), ("amp", "echo_intensity"), ("prcnt_gd", "percent_good")):
            arr = np.stack([getattr(e, attr) for e in ens], axis=-1).transpose(1, 0, 2)
            np.testing.assert_array_equal(arr, f[name][:], err_msg=name)

        if "vel_bt" in f:
            bt = [e.bottom_track for e in ens]
            # dolfyn keeps RDI's bad marker (-32.768 m/s) and range 0 (no bottom); ours are NaN.
            ref_v = f["vel_bt"][:].astype(np.float64)
            ref_v[f["vel_bt"][:] == np.float32(-32.768)] = np.nan
            assert_matches_float32(np.stack([b.velocity_mps for b in bt], axis=-1), ref_v, what="vel_bt")
            ref_r = f["dist_bt"][:].astype(np.float64)
            ref_r[ref_r == 0] = np.nan
            assert_matches_float32(np.stack([b.range_m for b in bt], axis=-1), ref_r, what="dist_bt")
            for name, attr in (("corr_bt", "correlation"), ("amp_bt", "amplitude"), ("prcnt_gd_bt", "percent_good")):
                np.testing.assert_array_equal(np.stack([getattr(b, attr) for b in bt], axis=-1), f[name][:],
                                              err_msg=name)


@needs_data
def test_test01_matches_dolfyn():
    raw = raw_file("RDI_test01.000")
    direct = [decode_ensemble(b) for b in split_ensembles(raw)]
    parser = Pd0StreamParser()
    streamed = parser.feed(raw) + parser.flush()
    assert [key(e) for e in streamed] == [key(e) for e in direct]
    assert len(direct) == 22
    assert all(e.bottom_track is None for e in direct)
    check_against_dolfyn(direct, DATA / "RDI_test01.nc", 22)
    # 772 trailing bytes are the start of a 23rd ensemble cut off by the file's end.
    assert parser.stats.bytes_discarded == len(raw) - sum(e.n_bytes for e in direct) == 772
    assert parser.stats.bad_checksums == 0


@needs_data
def test_withbt_first_100_match_dolfyn():
    parser = Pd0StreamParser()
    ens = parser.feed(raw_file("RDI_withBT.000")[:120_000])
    assert len(ens) >= 100
    assert all(e.bottom_track is not None for e in ens)
    check_against_dolfyn(ens, DATA / "RDI_withBT.nc", 100)


@needs_data
def test_withbt_whole_file_in_odd_chunks():
    raw = raw_file("RDI_withBT.000")
    parser = Pd0StreamParser()
    ens = []
    sizes = [1, 7, 580, 2, 4093, 581, 63]
    pos = k = 0
    while pos < len(raw):
        n = sizes[k % len(sizes)]
        ens += parser.feed(raw[pos:pos + n])
        assert parser.buffered <= MAX_ENSEMBLE_BYTES
        pos += n
        k += 1
    ens += parser.flush()
    assert [e.ensemble_number for e in ens] == list(range(1, 1722))
    t = np.array([e.time_ns for e in ens])
    assert (np.diff(t) > 0).all()
    assert parser.stats.bytes_discarded == 99 and parser.stats.bad_checksums == 0
    # Later ensembles have bottom lock: ranges within the 0.9-22 m water of this record.
    rng = np.array([e.bottom_track.range_m for e in ens])
    vel = np.array([e.bottom_track.velocity_mps for e in ens])
    assert np.isfinite(rng).sum() > 3000 and np.isfinite(vel).sum() > 3000
    assert np.nanmin(rng) > 0.5 and np.nanmax(rng) < 25.0
    assert np.nanmax(np.abs(vel)) < 3.0
    # pressure near the surface: 30 ensembles send fields just under 2^32 (read unsigned,
    # 4.29e10 Pa); they are readings of -7 to -153 daPa between neighbours of 0.1-0.3 dbar
    pres = np.array([np.nan if e.variable.pressure_pa is None else e.variable.pressure_pa
                     for e in ens])
    negative = pres < 0
    assert negative.sum() == 30 and np.nanmax(pres) < 1e5
    assert -2000.0 <= pres[negative].min() and pres[negative].max() < 0   # -7 to -153 daPa
    near = np.concatenate([pres[np.flatnonzero(negative) - 1], pres[np.flatnonzero(negative) + 1]])
    assert np.nanmedian(np.abs(near)) < 5e3               # their neighbours: under 0.5 dbar


def _bt_offset(ens_bytes: bytes) -> int:
    n_types = ens_bytes[5]
    offs = struct.unpack_from(f"<{n_types}H", ens_bytes, 6)
    for o in offs:
        if struct.unpack_from("<H", ens_bytes, o)[0] == 0x0600:
            return o
    raise AssertionError("no bottom track")


def _fix_checksum(b: bytearray) -> bytearray:
    n = struct.unpack_from("<H", b, 2)[0]
    struct.pack_into("<H", b, n, ensemble_checksum(bytes(b), 0, n))
    return b


@needs_data
def test_bottom_track_and_velocity_scaling_on_patched_ensemble():
    b = bytearray(split_ensembles(raw_file("RDI_withBT.000"))[0])
    bt = _bt_offset(bytes(b))
    struct.pack_into("<4H", b, bt + 16, 100, 65535, 0, 1234)  # range LSB, cm
    struct.pack_into("<4h", b, bt + 24, -32768, 1500, -1, 32767)  # velocity, mm/s
    struct.pack_into("<4B", b, bt + 77, 0, 1, 0, 2)  # range MSB, x 65536 cm
    # Water velocity, cell 1: beam values at the velocity data type.
    vel_off = struct.unpack_from("<H", b, 6 + 2 * 2)[0]
    assert struct.unpack_from("<H", b, vel_off)[0] == 0x0100
    struct.pack_into("<4h", b, vel_off + 2, 123, -32768, -4567, 0)
    e = decode_ensemble(bytes(_fix_checksum(b)))
    np.testing.assert_allclose(e.bottom_track.range_m, [1.0, (65535 + 65536) * 0.01, np.nan, (1234 + 2 * 65536) * 0.01],
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(e.bottom_track.velocity_mps, [np.nan, 1.5, -0.001, 32.767], rtol=0, atol=1e-12)
    np.testing.assert_allclose(e.velocity_mps[0], [0.123, np.nan, -4.567, 0.0], rtol=0, atol=1e-12)
    assert e.bottom_track.range_raw_cm.tolist() == [100, 131071, 0, 132306]
    with pytest.raises(ValueError):
        e.velocity_mps[0, 0] = 1.0  # arrays are read-only


@needs_data
def test_decode_errors_name_offset_field_expected_found():
    good = split_ensembles(raw_file("RDI_withBT.000"))[0]
    n = struct.unpack_from("<H", good, 2)[0]

    bad = bytearray(good)
    bad[n] ^= 0x01
    with pytest.raises(Pd0DecodeError) as ei:
        decode_ensemble(bytes(bad), base_offset=1000)
    e = ei.value
    assert (e.offset, e.field) == (1000 + n, "checksum")
    assert f"0x{ensemble_checksum(good, 0, n):04X}" in e.expected and e.found != e.expected
    assert f"byte offset {1000 + n}" in str(e) and "checksum" in str(e)

    with pytest.raises(Pd0DecodeError) as ei:
        decode_ensemble(b"\x00\x00" + good[2:])
    assert (ei.value.offset, ei.value.field, ei.value.expected, ei.value.found) == (0, "header ID", "0x7F7F", "0x0000")

    with pytest.raises(Pd0DecodeError) as ei:
        decode_ensemble(b"xx" + good[:-5], 2)
    assert ei.value.field == "ensemble length" and ei.value.offset == 2
    assert str(len(good)) in ei.value.expected and str(len(good) - 5) in ei.value.found

    bad = bytearray(good)
    struct.pack_into("<H", bad, 6 + 2 * 2, 3)  # third offset points back into the header
    with pytest.raises(Pd0DecodeError) as ei:
        decode_ensemble(bytes(_fix_checksum(bad)))
    assert ei.value.field == "offset of data type 3" and ei.value.offset == 10 and ei.value.found == "3"

    bad = bytearray(good)
    fixed_off = struct.unpack_from("<H", bad, 6)[0]
    bad[fixed_off + 9] = 200  # claim 200 cells: the velocity data type is too short for it
    with pytest.raises(Pd0DecodeError) as ei:
        decode_ensemble(bytes(_fix_checksum(bad)))
    assert ei.value.field == "velocity data length" and "200 cells" in ei.value.expected

    with pytest.raises(Pd0DecodeError) as ei:
        decode_ensemble(b"\x7f\x7f\x10")
    assert ei.value.field == "ensemble header"


@needs_data
def test_stream_discards_are_counted_and_logged_with_offsets(caplog):
    ens = split_ensembles(raw_file("RDI_withBT.000"))[:3]
    corrupted = bytearray(ens[1])
    corrupted[200] ^= 0xFF
    junk = b"garbage\x7f!"
    stream = junk + ens[0] + bytes(corrupted) + ens[2]
    parser = Pd0StreamParser()
    with caplog.at_level(logging.WARNING, logger="svss_daq.protocols.pd0"):
        out = parser.feed(stream) + parser.flush()
    assert [e.ensemble_number for e in out] == [1, 3]
    assert parser.stats.bad_checksums >= 1
    assert parser.stats.bytes_discarded == len(junk) + len(corrupted)
    msgs = [r.getMessage() for r in caplog.records]
    assert any(f"discarded {len(junk)} bytes at stream offset 0" in m for m in msgs), msgs
    off = len(junk) + len(ens[0])
    assert any(f"discarded {len(corrupted)} bytes at stream offset {off}" in m and "bad checksum" in m
               for m in msgs), msgs


@needs_data
def test_false_header_does_not_hold_back_good_ensembles():
    ens = split_ensembles(raw_file("RDI_withBT.000"))[:2]
    # A real ensemble's first 100 bytes with its byte count changed to 60000: the
    # header passes every check that can be made before 60000 bytes have arrived.
    forged = bytearray(ens[0][:100])
    struct.pack_into("<H", forged, 2, 60000)
    parser = Pd0StreamParser()
    out = parser.feed(bytes(forged) + ens[0] + ens[1])
    assert [e.ensemble_number for e in out] == [1, 2]  # without waiting for 60000 bytes
    assert parser.buffered == 0
    assert parser.stats.bytes_discarded == 100


def test_random_garbage_keeps_memory_bounded():
    rng = np.random.default_rng(1)
    parser = Pd0StreamParser()
    for _ in range(60):
        chunk = rng.integers(0, 256, size=4096, dtype=np.uint8)
        chunk[rng.integers(0, 4095, size=40)] = 0x7F  # many header-like bytes
        assert parser.feed(chunk.tobytes()) == []
        assert parser.buffered <= MAX_ENSEMBLE_BYTES
    assert parser.flush() == [] and parser.buffered == 0
    assert parser.stats.bytes_discarded == 60 * 4096 and parser.stats.internal_errors == 0


def test_feed_rejects_non_bytes_without_raising():
    parser = Pd0StreamParser()
    assert parser.feed("not bytes") == [] and parser.feed(5) == []  # type: ignore[arg-type]


# -- property-based fuzzing ------------------------------------------------------

def _feed_chunked(parser: Pd0StreamParser, data: bytes, sizes: list) -> list:
    out, pos, k = [], 0, 0
    while pos < len(data):
        n = sizes[k % len(sizes)]
        out += parser.feed(data[pos:pos + n])
        assert parser.buffered <= MAX_ENSEMBLE_BYTES + n
        pos += n
        k += 1
    return out + parser.flush()


chunk_sizes = st.lists(st.integers(1, 1500), min_size=1, max_size=8)
header_soup = st.lists(st.one_of(st.binary(max_size=40), st.sampled_from([b"\x7f\x7f", b"\x7f", b"\x7f\x7f\x45\x02\x00\x07"])),
                       max_size=30).map(b"".join)


@needs_data
@FUZZ
@given(data=st.one_of(st.binary(max_size=3000), header_soup), sizes=chunk_sizes)
def test_fuzz_random_bytes_never_raise(data, sizes):
    parser = Pd0StreamParser()
    out = _feed_chunked(parser, data, sizes)
    # Random bytes cannot carry a valid ensemble (in practice); nothing may leak through.
    assert all(isinstance(e, Pd0Ensemble) for e in out)
    assert parser.buffered == 0 and parser.stats.internal_errors == 0


@st.composite
def garbage(draw):
    pool = fuzz_pool()
    src = pool[draw(st.integers(0, len(pool) - 1))]
    kind = draw(st.sampled_from(["random", "truncated", "flipped", "inserted", "soup", "forged"]))
    if kind == "random":
        return draw(st.binary(min_size=1, max_size=700))
    if kind == "soup":
        return draw(header_soup) or b"\x7f"
    if kind == "forged":  # a real header whose byte count lies
        b = bytearray(src[:draw(st.integers(81, len(src) - 1))])
        struct.pack_into("<H", b, 2, draw(st.integers(len(src) - 1, 0xFFFF)))
        return bytes(b)
    if kind == "truncated":
        return src[:draw(st.integers(1, len(src) - 1))]
    if kind == "flipped":  # one byte changed: the checksum always catches it
        b = bytearray(src)
        i = draw(st.integers(0, len(b) - 1))
        b[i] ^= draw(st.integers(1, 255))
        return bytes(b)
    i = draw(st.integers(0, len(src)))  # bytes inserted into a real ensemble
    return src[:i] + draw(st.binary(min_size=1, max_size=50)) + src[i:]


segments = st.lists(st.one_of(st.integers(0, 37).map(lambda i: ("ok", i)), garbage().map(lambda g: ("junk", g))),
                    min_size=1, max_size=12)


def _is_subsequence(small: list, big: list) -> bool:
    it = iter(big)
    return all(any(x == y for y in it) for x in small)


@needs_data
@FUZZ
@given(segs=segments, sizes=chunk_sizes)
def test_fuzz_recovers_every_intact_ensemble_after_garbage(segs, sizes):
    pool, keys = fuzz_pool(), pool_keys()
    stream = b"".join(pool[x] if kind == "ok" else x for kind, x in segs)
    parser = Pd0StreamParser()
    decoded = _feed_chunked(parser, stream, sizes)
    out = [key(e) for e in decoded]
    intact = [keys[x] for kind, x in segs if kind == "ok"]
    assert _is_subsequence(intact, out), (intact, out)
    # Anything else decoded must be a real ensemble that the garbage happened to contain.
    assert set(out) <= set(keys)
    assert parser.buffered == 0 and parser.stats.internal_errors == 0
    # Every byte is accounted for: decoded or discarded.
    assert parser.stats.bytes_discarded + sum(e.n_bytes for e in decoded) == len(stream)


@needs_data
@FUZZ
@given(idx=st.lists(st.integers(0, 37), min_size=1, max_size=8), cut=st.floats(0, 1), sizes=chunk_sizes)
def test_fuzz_truncated_stream_yields_exactly_the_complete_ensembles(idx, cut, sizes):
    pool, keys = fuzz_pool(), pool_keys()
    stream = b"".join(pool[i] for i in idx)
    k = int(cut * len(stream))
    ends = np.cumsum([len(pool[i]) for i in idx])
    expected = [keys[i] for i, e in zip(idx, ends) if e <= k]
    parser = Pd0StreamParser()
    out = [key(e) for e in _feed_chunked(parser, stream[:k], sizes)]
    assert out == expected
    assert parser.stats.bytes_discarded == k - sum(len(pool[i]) for i, e in zip(idx, ends) if e <= k)


@needs_data
@FUZZ
@given(junk=garbage(), start=st.integers(0, 3), check=st.booleans())
def test_fuzz_direct_decode_raises_only_pd0_decode_error(junk, start, check):
    # Without the checksum check, corrupted contents reach every field decoder.
    try:
        e = decode_ensemble(junk, min(start, len(junk)), verify_checksum=check)
    except Pd0DecodeError as err:
        assert err.field and err.expected and err.found is not None and err.offset >= 0
    else:
        assert isinstance(e, Pd0Ensemble) and e.n_bytes <= len(junk)
