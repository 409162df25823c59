"""The one byte-stream buffer of the instrument stream parsers (PD0, NMEA, the
sequencer's sentences and the daemon's NMEA record tap)."""

from __future__ import annotations

import logging

import numpy as np

from svss_daq.protocols.framing import ByteStream
from svss_daq.protocols.nmea import NmeaStreamStats


def test_feed_takes_any_bytes_like_object_and_refuses_the_rest(caplog):
    s = ByteStream("TEST")
    assert s.feed(b"ab") == 2 and s.feed(bytearray(b"c")) == 1
    assert s.feed(memoryview(b"de")) == 2 and s.feed(np.frombuffer(b"fg", np.uint8)) == 2
    assert s.feed(np.array([1], dtype="<u2")) == 2          # its bytes, cast
    with caplog.at_level(logging.WARNING, logger="svss_daq.protocols.framing"):
        assert s.feed("text") is None and s.feed(5) is None
    assert bytes(s.buf) == b"abcdefg\x01\x00" and len(s) == 9
    assert [r.getMessage() for r in caplog.records] == [
        "TEST stream: ignored a feed of non-bytes type str",
        "TEST stream: ignored a feed of non-bytes type int"]


def test_the_protocols_logger_says_it_and_its_counters_count():
    log = logging.getLogger("svss_daq.protocols.test")
    stats = NmeaStreamStats()
    s = ByteStream("X", log, stats)
    assert s.log is log
    s.feed(b"abc")
    s.feed(None)
    s.feed(bytearray(4))
    assert stats.bytes_fed == 7


def test_consume_moves_the_stream_offset_and_survives_a_lingering_export():
    s = ByteStream("TEST")
    s.feed(b"0123456789")
    s.consume(3)
    assert bytes(s.buf) == b"3456789" and s.base == 3
    view = memoryview(s.buf)               # a decoder's view still alive
    s.consume(2)                           # the buffer cannot shrink in place: copied
    assert bytes(s.buf) == b"56789" and s.base == 5
    assert bytes(view[:2]) == b"34"
    s.consume(0)
    s.consume(-1)
    assert s.base == 5
    assert s.keep_last(3) == 2 and bytes(s.buf) == b"789" and s.base == 7
    assert s.keep_last(10) == 0
    assert s.clear() == 3 and s.base == 10 and len(s) == 0 and s.clear() == 0


def test_lines_are_taken_whole_and_the_rest_waits():
    s = ByteStream("TEST")
    s.feed(b"$A*00\r\n\n$B")
    assert s.lines() == [b"$A*00\r", b""]
    assert bytes(s.buf) == b"$B" and s.base == 8
    assert s.lines() == []
    s.feed(b"C\n")
    assert s.lines() == [b"$BC"] and len(s) == 0 and s.base == 12
