"""Sequencer and digitiser codecs: round trips, errors naming offset and field, stream
resynchronisation, and Hypothesis fuzzing of every parser (never raises, never hangs,
finds the next valid message)."""

from __future__ import annotations

import os
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from svss_daq.protocols import digitiser as dg
from svss_daq.protocols import sequencer as sq

FUZZ = settings(max_examples=int(os.environ.get("SVSS_FUZZ_EXAMPLES", "150")), deadline=None,
                suppress_health_check=[HealthCheck.too_slow], derandomize="SVSS_FUZZ_EXAMPLES" not in os.environ)

SEQ_MESSAGES = [
    sq.SetSchedule(1, (0, 1, 2, 3, 4, 5)), sq.SetWaveform(2, "lfm", 35000.0, 20000.0, 255000),
    sq.SetInterval(3, 100_000_000), sq.SetReceiveWindow(4, 0, 12_000_000), sq.Arm(5),
    sq.Start(6), sq.Stop(7), sq.StatusRequest(65535), sq.Ack(9, "START"),
    sq.Nak(0, "?", 1, "bad checksum"), sq.Status(11, "RUNNING", 42, 42, 0),
    sq.PingEvent(2**40, 5, 1_700_000_000_123_456_789), sq.PingEvent(0, 0, -5),
]


# ------------------------------------------------------------------- sequencer codec


@pytest.mark.parametrize("msg", SEQ_MESSAGES, ids=lambda m: m.TYPE)
def test_sequencer_round_trip(msg):
    b = sq.encode(msg)
    assert b.startswith(b"$SEQ," + msg.TYPE.encode() + b",") and b.endswith(b"\r\n")
    assert sq.decode_sentence(b) == msg


def test_sequencer_checksum_is_xor_of_body():
    b = sq.encode(sq.Arm(12))
    body = b[1:b.index(b"*")]
    x = 0
    for c in body:
        x ^= c
    assert b[-4:-2] == b"%02X" % x


@pytest.mark.parametrize("line, offset, field", [
    (b"$SEQ,ARM,5*00", 11, "checksum"),
    (b"SEQ,ARM,5*00", 0, "start"),
    (b"$SEQ,ARM,5", 10, "checksum"),
])
def test_sequencer_errors_name_offset_and_field(line, offset, field):
    with pytest.raises(sq.SequencerProtocolError) as e:
        sq.decode_sentence(line)
    assert e.value.offset == offset and e.value.field == field
    assert f"byte offset {offset}" in str(e.value)


def _with_checksum(body: bytes) -> bytes:
    return b"$" + body + b"*%02X" % sq.checksum(body)


@pytest.mark.parametrize("body, offset, field", [
    (b"SEQ,PRI,7,abc", 11, "PRI.interval_ns"),
    (b"SEQ,PRI,7", 10, "PRI.interval_ns"),
    (b"SEQ,FOO,7", 5, "type"),
    (b"SEQ,ARM,0", 9, "ARM.mid"),
    (b"SEQ,STAT,3,SLEEPING,0,0,0", 12, "STAT.state"),
    (b"SEQ,ARM,3,9", 11, "ARM"),
    (b"SEQ,SCHED,3,1,64", 15, "SCHED.projectors"),
    (b"SEQ,WAVE,2,lfm,nan,20000,1", 16, "WAVE.f_start_hz"),
])
def test_sequencer_field_errors(body, offset, field):
    with pytest.raises(sq.SequencerProtocolError) as e:
        sq.decode_sentence(_with_checksum(body))
    assert (e.value.offset, e.value.field) == (offset, field), str(e.value)


def test_sequencer_encode_rejects_bad_values():
    with pytest.raises(ValueError, match="mid"):
        sq.encode(sq.Arm(0))
    with pytest.raises(ValueError, match="text"):
        sq.encode(sq.Nak(1, "ARM", 3, "a,b"))
    with pytest.raises(ValueError, match="non-finite"):
        sq.encode(sq.SetWaveform(1, "lfm", float("inf"), 1.0, 1))


def test_sequencer_stream_resynchronises():
    good = [sq.encode(m) for m in SEQ_MESSAGES]
    stream = (b"\x00\xffnoise$SEQ,ARM,1*00\r\n" + good[0] + b"$SEQ,PI" + good[1]
              + b"x" * 500 + b"\n" + good[2])
    p = sq.SequencerStreamParser()
    out = []
    for i in range(0, len(stream), 7):
        out += p.feed(stream[i:i + 7])
    assert out == SEQ_MESSAGES[:3]
    assert p.stats.rejected >= 1 and p.stats.bytes_discarded > 500


@FUZZ
@given(st.lists(st.one_of(st.binary(max_size=80), st.sampled_from([sq.encode(m) for m in SEQ_MESSAGES])),
                max_size=12), st.integers(1, 64), st.data())
def test_sequencer_stream_fuzz(parts, chunk, data):
    """Random bytes mixed with valid sentences, optionally corrupted or truncated: never
    raises; a valid sentence preceded by a line end (or nothing) is always recovered."""
    stream = b"".join(parts)
    if stream and data.draw(st.booleans()):
        i = data.draw(st.integers(0, len(stream) - 1))
        stream = stream[:i] + bytes([stream[i] ^ data.draw(st.integers(1, 255))]) + stream[i + 1:]
    if data.draw(st.booleans()):
        stream = stream[:data.draw(st.integers(0, len(stream)))]
    p = sq.SequencerStreamParser()
    out = []
    for i in range(0, len(stream), chunk):
        out += p.feed(stream[i:i + chunk])
    marker = sq.PingEvent(999, 3, 123456789)
    out_after = p.feed(b"\n" + sq.encode(marker))
    assert out_after[-1:] == [marker]
    for m in out:
        assert sq.decode_sentence(sq.encode(m)) == m


@FUZZ
@given(st.binary(max_size=250))
def test_sequencer_decode_fuzz(b):
    try:
        sq.decode_sentence(b)
    except sq.SequencerProtocolError as e:
        assert 0 <= e.offset <= sq.MAX_SENTENCE


# ------------------------------------------------------------------- digitiser codec


def _ping(n=80, s=150, seed=0):
    return np.random.default_rng(seed).integers(-2**23, 2**23, (n, s)).astype(np.int32)


def test_digitiser_frames_round_trip_bit_exact():
    a = _ping()
    frames = dg.encode_data_frames(17, 1_700_000_000_000_000_000, 1_700_000_000_000_304_000, a, 16)
    assert len(frames) == 5 and all(len(f) == dg.HEADER_SIZE + 16 * 150 * 4 for f in frames)
    fr, used = dg.decode_frame(frames[2])
    assert used == len(frames[2]) and fr.header.channel_first == 32 and fr.header.frame_index == 2
    np.testing.assert_array_equal(fr.samples, a[32:48])
    out = dg.DigitiserStreamDecoder().feed(b"".join(frames))
    assert len(out) == 1 and isinstance(out[0], dg.CompletePing)
    p = out[0]
    assert (p.ping_number, p.transmit_time_ns, p.first_sample_time_ns) == (
        17, 1_700_000_000_000_000_000, 1_700_000_000_000_304_000)
    assert p.samples.dtype == np.int32 and np.array_equal(p.samples, a)


def test_digitiser_int16_format_and_control_frames():
    a = np.arange(-300, 300, dtype=np.int32).reshape(4, 150)
    fr, _ = dg.decode_frame(dg.encode_data_frames(1, 0, 0, a, 4, dg.SampleFormat.INT16)[0])
    assert fr.samples.dtype == np.int32 and np.array_equal(fr.samples, a)
    c, _ = dg.decode_frame(dg.encode_command(9, dg.CommandCode.SET_GAIN, 12.5))
    assert c == dg.CommandFrame(9, 3, 12.5, 0)
    r, _ = dg.decode_frame(dg.encode_reply(9, 3, dg.ReplyStatus.BAD_VALUE, 6.0))
    assert r == dg.ReplyFrame(9, 3, -2, 6.0, 0)
    with pytest.raises(ValueError, match="outside"):
        dg.encode_data_frames(1, 0, 0, np.full((1, 4), 2**23, np.int32), 1)


def _reheader(frame: bytes, pos: int, new: bytes) -> bytes:
    """Patch header bytes and fix the header CRC (so that the field check is reached)."""
    b = bytearray(frame)
    b[pos:pos + len(new)] = new
    b[56:60] = zlib.crc32(bytes(b[:56])).to_bytes(4, "little")
    return bytes(b)


def test_digitiser_errors_name_offset_and_field():
    f = dg.encode_data_frames(3, 0, 0, _ping(8, 10), 8)[0]
    cases = [
        (b"XXXX" + f[4:], 0, "magic"),
        (f[:20] + bytes([f[20] ^ 1]) + f[21:], 56, "header_crc32"),
        (_reheader(f, 4, b"\x02"), 4, "version"),
        (_reheader(f, 38, b"\x07"), 38, "sample_format"),
        (_reheader(f, 48, (5).to_bytes(4, "little")), 48, "payload_length"),
        (_reheader(f, 44, (3).to_bytes(2, "little")), 44, "frame_index/frame_count"),
        (f[:-1] + bytes([f[-1] ^ 0x10]), 60, "payload_crc32"),
        (f[:40], 0, "header"),
    ]
    for data, off, field in cases:
        with pytest.raises(dg.DigitiserProtocolError) as e:
            dg.decode_frame(b"ab" + data, 2, base_offset=100)
        assert (e.value.offset, e.value.field) == (102 + off, field), str(e.value)


def test_assembler_reports_missing_corrupt_and_skipped_pings():
    a = _ping(80, 20)
    fr = {n: dg.encode_data_frames(n, n, n, a, 16) for n in range(6)}
    bad = bytearray(fr[3][1])
    bad[-5] ^= 0xFF
    stream = (b"".join(fr[0]) + b"".join(fr[1][:2] + fr[1][3:])  # ping 1: frame 2 dropped
              + b"garbage\x00SVDG" * 3 + b"".join(fr[2])           # garbage, then ping 2
              + b"".join([fr[3][0], bytes(bad)] + fr[3][2:])       # ping 3: frame 1 corrupt
              + b"".join(fr[5]))                                   # ping 4 missing altogether
    d = dg.DigitiserStreamDecoder()
    out = d.feed(stream) + d.flush()
    kinds = [(type(o).__name__, o.ping_number) for o in out]
    assert kinds == [("CompletePing", 0), ("IncompletePing", 1), ("CompletePing", 2),
                     ("IncompletePing", 3), ("IncompletePing", 4), ("CompletePing", 5)]
    assert out[1].missing_frames == (2,) and out[1].frames_received == 4
    assert "corrupt" in out[3].reason and out[4].frames_received == 0
    assert all(np.array_equal(o.samples, a) for o in out if isinstance(o, dg.CompletePing))
    assert d.frames.stats.corrupt_payloads == 1 and d.frames.stats.bad_headers == 3


@FUZZ
@given(st.lists(st.one_of(st.binary(max_size=120), st.sampled_from(["ping", "cmd", "magic"])),
                max_size=10), st.integers(1, 300), st.data())
def test_digitiser_stream_fuzz(parts, chunk, data):
    """Random bytes, fake sync words, valid frames, bit flips and truncation: never
    raises, every delivered ping is bit-exact, and a valid ping sent afterwards arrives."""
    a = _ping(6, 8, seed=1)
    pieces = []
    for k, p in enumerate(parts):
        if p == "ping":
            pieces += dg.encode_data_frames(k, 0, 0, a, 2)
        elif p == "cmd":
            pieces.append(dg.encode_command(k, 1))
        elif p == "magic":
            pieces.append(dg.MAGIC + bytes(20))
        else:
            pieces.append(p)
    stream = b"".join(pieces)
    if stream and data.draw(st.booleans()):
        i = data.draw(st.integers(0, len(stream) - 1))
        stream = stream[:i] + bytes([stream[i] ^ data.draw(st.integers(1, 255))]) + stream[i + 1:]
    if data.draw(st.booleans()):
        stream = stream[:data.draw(st.integers(0, len(stream)))]
    d = dg.DigitiserStreamDecoder(max_payload=4096)
    out = []
    for i in range(0, len(stream), chunk):
        out += d.feed(stream[i:i + chunk])
    out += d.feed(b"".join(dg.encode_data_frames(10_000, 5, 5, a, 3)))
    out += d.flush()
    complete = [o for o in out if isinstance(o, dg.CompletePing)]
    assert complete and complete[-1].ping_number == 10_000
    assert all(np.array_equal(c.samples, a) for c in complete)


@FUZZ
@given(st.binary(min_size=0, max_size=200))
def test_digitiser_decode_frame_fuzz(b):
    for data in (b, dg.MAGIC + b):
        try:
            dg.decode_frame(data)
        except dg.DigitiserProtocolError as e:
            assert 0 <= e.offset <= len(data) + dg.HEADER_SIZE
