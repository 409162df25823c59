"""Hostile ZeroMQ traffic: bounded queues with counted drops, and a decoder that turns any
frame list into a well-typed Ping or RunEnd or a MessageError (real sockets on loopback)."""

from __future__ import annotations

import json
import logging
import math
import os
import re
import threading
import time
import tracemalloc

import pytest
import zmq
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from svss_daq import messages
from svss_daq.messages import TOPIC_END, TOPIC_PING, MessageError, RunEnd
from svss_daq.ping import NAV_FIELDS, NavSnapshot, Ping
from svss_daq.publisher import PingPublisher
from svss_daq.subscriber import subscribe
from tests.test_messages import make_ping

MAX_EXAMPLES = int(os.environ.get("SVSS_FUZZ_EXAMPLES", "200"))


#: reader threads of the running test, stopped before its context is destroyed
_READERS: list[tuple[threading.Thread, threading.Event]] = []


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    # a reader still polling its socket when the context closes it deadlocks the
    # context's term (a loaded machine: the reader's join timed out): stop them first
    for t, stop in _READERS:
        stop.set()
        t.join(10)
    _READERS.clear()
    c.destroy(linger=0)      # closes what a failed test left open


def _reader(sock: zmq.Socket, got: list, quiet_s: float = 20.0) -> threading.Thread:
    """Read pings into ``got`` until the end-of-run marker (appended last), ``quiet_s``
    without a message, or the test's end."""
    stop = threading.Event()

    def run():
        heard = time.monotonic()
        while not stop.is_set() and time.monotonic() - heard < quiet_s:
            if not sock.poll(100):
                continue
            m = messages.recv(sock)
            got.append(m)
            heard = time.monotonic()
            if isinstance(m, RunEnd):
                return
    t = threading.Thread(target=run, daemon=True)
    _READERS.append((t, stop))
    t.start()
    return t


# ------------------------------------------------------------ bounded queues, drops


def test_full_queue_drops_and_counts_without_blocking(ctx, caplog):
    pub = PingPublisher("tcp://127.0.0.1:*", 4, ctx=ctx, drop_log_interval_s=3600)
    sub = subscribe(pub.endpoint, 4, ctx=ctx)
    pub.wait_for_subscribers(timeout_s=10)
    pings = [make_ping(i, nch=8, ns=4096) for i in range(1000)]   # 128 kB each
    slowest = 0.0
    sent = []                                  # sequences that publish() accepted
    with caplog.at_level(logging.WARNING, logger="svss_daq.publisher"):
        t0 = time.monotonic()
        for p in pings:                        # nobody reads: the queues fill
            t = time.monotonic()
            if pub.publish(p):
                sent.append(p.sequence)
            slowest = max(slowest, time.monotonic() - t)
        elapsed = time.monotonic() - t0
    assert elapsed < 5.0 and slowest < 0.5, (elapsed, slowest)
    assert 0 < pub.dropped < len(pings)
    assert len(sent) == pub.published and pub.published + pub.dropped == len(pings)
    # the first drop is logged at once with its sequence number, later ones rate-limited
    [rec] = [r for r in caplog.records if "dropped" in r.getMessage()]
    first = next(i for i in range(len(pings)) if i not in sent)
    assert f"dropped 1 ping(s), sequence {first}..{first}" in rec.getMessage()
    got = []
    reader = _reader(sub, got)                 # the subscriber finally reads
    assert pub.publish(RunEnd("r", len(pings)))     # the marker waits for room
    reader.join(30)
    assert got[-1] == RunEnd("r", len(pings))
    seqs = [m.sequence for m in got[:-1]]
    assert seqs == sent                        # every accepted ping, in order
    assert len(seqs) + pub.dropped == len(pings)
    sub.close(0)
    pub.close(0)


def test_one_slow_subscriber_makes_all_miss_the_same_pings(ctx):
    """XPUB_NODROP refuses a message when any subscriber's queue is full: nobody blocks,
    every subscriber sees the same gaps (documented in docs/formats.md)."""
    pub = PingPublisher("tcp://127.0.0.1:*", 4, ctx=ctx)
    slow, fast = subscribe(pub.endpoint, 4, ctx=ctx), subscribe(pub.endpoint, 4, ctx=ctx)
    pub.wait_for_subscribers(2, timeout_s=10)
    got_fast, got_slow = [], []
    fast_reader = _reader(fast, got_fast)
    n = 600
    t0 = time.monotonic()
    for i in range(n):
        pub.publish(make_ping(i, nch=8, ns=4096))
    assert time.monotonic() - t0 < 5.0
    assert pub.dropped > 0
    slow_reader = _reader(slow, got_slow)
    assert pub.publish(RunEnd("r", n))
    fast_reader.join(30), slow_reader.join(30)
    seq_fast = [m.sequence for m in got_fast[:-1]]
    assert seq_fast == [m.sequence for m in got_slow[:-1]]
    assert len(seq_fast) + pub.dropped == n
    for s in (slow, fast):
        s.close(0)
    pub.close(0)


def test_end_marker_gives_up_after_its_timeout(ctx, caplog):
    pub = PingPublisher("tcp://127.0.0.1:*", 2, ctx=ctx, end_timeout_s=0.3)
    sub = subscribe(pub.endpoint, 2, ctx=ctx)
    pub.wait_for_subscribers(timeout_s=10)
    ping = make_ping(1, nch=8, ns=4096)
    t0 = last_accepted = time.monotonic()
    while time.monotonic() - last_accepted < 0.5:   # until the queue and the kernel's
        assert time.monotonic() - t0 < 10           # socket buffers stay full
        if pub.publish(ping):
            last_accepted = time.monotonic()
    assert pub.dropped > 0
    i = pub.published
    t0 = time.monotonic()
    with caplog.at_level(logging.ERROR, logger="svss_daq.publisher"):
        assert not pub.publish(RunEnd("r-full", i))
    assert 0.3 <= time.monotonic() - t0 < 2.0
    assert "end-of-run marker of run 'r-full' not sent" in caplog.text
    sub.close(0)
    pub.close(0)


# ------------------------------------------------------- hostile headers on the wire

_GOOD_END = {"schema": "svss.end", "version": 1, "run_id": "r", "n_pings": 7}


@pytest.fixture
def wire(ctx):
    """A publisher and a bounded subscriber joined on loopback: send raw frames, recv."""
    pub = PingPublisher("tcp://127.0.0.1:*", 100, ctx=ctx)
    sub = subscribe(pub.endpoint, 100, ctx=ctx)
    pub.wait_for_subscribers(timeout_s=10)

    def roundtrip(frames):
        pub.sock.send_multipart(frames)
        assert sub.poll(10000)
        return messages.recv(sub)
    yield roundtrip
    sub.close(0)
    pub.close(0)


def _end(**changes) -> list[bytes]:
    h = {**_GOOD_END, **changes}
    return [TOPIC_END, json.dumps(h).encode()]


@pytest.mark.parametrize("n_pings", ["7", 7.5, None, True, False, 10**30, 2**63, -1, [],
                                     {}, float("nan"), float("inf")])
def test_end_with_bad_n_pings_raises_naming_the_field(wire, n_pings):
    with pytest.raises(MessageError, match=r"svss.end message: header field 'n_pings' "
                       r"expected int \(an integer in 0..9223372036854775807\), got "):
        wire(_end(n_pings=n_pings))
    assert wire(_end()) == RunEnd("r", 7)      # the socket is still fine


@pytest.mark.parametrize("run_id", [7, None, True, [], {}])
def test_end_with_bad_run_id_raises_naming_the_field(wire, run_id):
    with pytest.raises(MessageError, match="header field 'run_id' expected str"):
        wire(_end(run_id=run_id))


def test_end_missing_fields_and_extra_frames(wire):
    for name in ("run_id", "n_pings"):
        h = dict(_GOOD_END)
        del h[name]
        with pytest.raises(MessageError, match=f"svss.end message: header lacks field "
                           f"'{name}'"):
            wire([TOPIC_END, json.dumps(h).encode()])
    with pytest.raises(MessageError, match="svss.end message has 3 frames; expected 2"):
        wire(_end() + [b"x"])
    with pytest.raises(MessageError, match="'version' is True"):
        wire(_end(version=True))


def _ping_frames(**changes) -> list[bytes]:
    frames = [bytes(f) for f in messages.encode_ping(make_ping(3, nch=4, ns=16))]
    h = json.loads(frames[1])
    for k, v in changes.items():
        if k.startswith("nav."):
            h["nav"][k[4:]] = v
        else:
            h[k] = v
    return [frames[0], json.dumps(h).encode(), frames[2]]


@pytest.mark.parametrize("field, value, text", [
    ("sequence", -1, "'sequence' expected int (an integer in 0.."),
    ("sequence", 2**63, "'sequence' expected int"),
    ("sequence", 1.0, "'sequence' expected int"),
    ("projector", True, "'projector' expected int"),
    ("transmit_time_ns", "1", "'transmit_time_ns' expected int"),
    ("window_start_ns", -2**63 - 1, "'window_start_ns' expected int"),
    ("sample_rate_hz", float("nan"), "'sample_rate_hz' expected float (a finite number > 0"),
    ("sample_rate_hz", float("inf"), "'sample_rate_hz' expected float"),
    ("sample_rate_hz", 10**400, "'sample_rate_hz' expected float"),
    ("sample_rate_hz", 0, "'sample_rate_hz' expected float"),
    ("sample_rate_hz", "125e3", "'sample_rate_hz' expected float"),
    ("config_id", 7, "'config_id' expected str"),
    ("config_id", None, "'config_id' expected str"),
    ("nav", [], "'nav' expected dict"),
    ("nav.north_m", "1", "'nav': navigation snapshot: field 'north_m' expected float"),
    ("nav.roll_rad", True, "field 'roll_rad' expected float"),
    ("nav.altitude_m", None, "field 'altitude_m' expected float"),
    ("nav.down_m", 10**400, "field 'down_m' expected float"),
    ("nav.time_ns", 2**63, "field 'time_ns' expected int (int64)"),
    ("nav.quality", 1.0, "field 'quality' expected int"),
    ("nav.extra", 1.0, "unknown field 'extra'"),
    ("dtype", "<i8", "'dtype' is '<i8'"),
    ("shape", [4, 16, 1], "'shape' is [4, 16, 1]"),
    ("shape", [4.0, 16], "'shape'"),
    ("shape", [True, 64], "'shape'"),
    ("shape", [0, 16], "'shape'"),
    ("shape", [65536, 1], "'shape'"),
    ("shape", [1, 2**31], "'shape'"),
    ("shape", [10**30, 10**30], "'shape'"),
    ("shape", [4, 15], "sample frame holds 256 bytes; header shape [4, 15] of int32 needs "
     "240"),
])
def test_ping_with_bad_field_raises_naming_it(wire, field, value, text):
    frames = _ping_frames(**{field: value})
    with pytest.raises(MessageError) as exc:
        wire(frames)
    assert text in str(exc.value)
    assert isinstance(wire(_ping_frames()), Ping)


@pytest.mark.parametrize("header, text", [
    (b"[" * 60000, "not a UTF-8 JSON header (RecursionError"),
    (b'{"n": ' + b"9" * 5000 + b"}", "not a UTF-8 JSON header (ValueError"),
    (b" " * 70000, "header frame holds 70000 bytes; expected at most 65536"),
    (b"NaN", "header must be a JSON object, got float"),
])
def test_hostile_header_frames(wire, header, text):
    with pytest.raises(MessageError) as exc:
        wire([TOPIC_PING, header, b""])
    assert text in str(exc.value)


def test_absurd_shape_allocates_nothing():
    """The byte count is checked before any array exists: a header asking for 2**46
    samples over a 16-byte frame costs nothing."""
    frames = _ping_frames(shape=[65535, 2**31 - 1])
    frames[2] = b"\0" * 16
    big_topic = [b"x" * (64 << 20), frames[1], frames[2]]
    tracemalloc.start()
    try:
        for f, text in ((frames, "holds 16 bytes"), (big_topic, "message topic")):
            tracemalloc.reset_peak()
            with pytest.raises(MessageError, match=text):
                messages.decode(f)
            assert tracemalloc.get_traced_memory()[1] < 256 << 10
    finally:
        tracemalloc.stop()


# --------------------------------------------------------------------------- fuzzing

_SPECIAL_NUMBERS = [0, -1, 1, 2**31, 2**63 - 1, 2**63, -2**63 - 1, 10**30, 10**400,
                    -10**400, 1e308, -0.0, float("nan"), float("inf"), float("-inf")]
_json_scalars = (st.none() | st.booleans() | st.integers() | st.floats()
                 | st.sampled_from(_SPECIAL_NUMBERS) | st.text(max_size=12))
_json_values = st.recursive(
    _json_scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8),
                                                                       c, max_size=4),
    max_leaves=8)


def _good(topic: bytes, nch: int, ns: int) -> tuple[dict, bytes]:
    if topic == TOPIC_END:
        return dict(_GOOD_END), b""
    frames = messages.encode_ping(make_ping(5, nch=nch, ns=ns))
    return json.loads(frames[1]), bytes(frames[2])


@st.composite
def _frame_lists(draw) -> list[bytes]:
    """Mostly a valid ping or end message with a few header fields replaced by random JSON
    values or removed; sometimes a random topic, header, sample frame or frame count."""
    rare = st.integers(0, 9).map(lambda n: n == 0)      # true one time in ten
    topic = (draw(st.binary(max_size=16)) if draw(rare) else
             draw(st.sampled_from([TOPIC_PING] * 12 + [TOPIC_END] * 5
                                  + [b"svss.", b"svss.ping\0", b""])))
    nch, ns = draw(st.integers(1, 4)), draw(st.integers(1, 8))
    header, samples = _good(topic if topic == TOPIC_END else TOPIC_PING, nch, ns)
    keys = sorted(header) * 2 + ["extra"] + (
        [f"nav.{n}" for n in NAV_FIELDS] if topic != TOPIC_END else [])
    for key in draw(st.lists(st.sampled_from(keys), max_size=3)):   # perturb the header
        target, name = ((header["nav"], key[4:]) if key.startswith("nav.")
                        and isinstance(header.get("nav"), dict) else (header, key))
        if draw(rare):
            target.pop(name, None)
        else:
            target[name] = draw(_json_values)
    head = (draw(st.binary(max_size=64)) if draw(rare) else
            json.dumps(draw(_json_values)).encode() if draw(rare) else
            json.dumps(header).encode())
    shape = header.get("shape")
    fitted = (shape[0] * shape[1] * 4 if isinstance(shape, list) and len(shape) == 2
              and all(type(s) is int and 0 <= s < 64 for s in shape) else 0)
    body = (draw(st.binary(max_size=64)) if draw(rare) else
            draw(st.sampled_from([samples, samples, b"\0" * fitted, samples[:-1]])))
    frames = [topic, head] if topic == TOPIC_END else [topic, head, body]
    if draw(rare):                              # a frame too few or too many
        frames = frames[:-1] if draw(st.booleans()) else frames + [body]
    return frames


def _well_typed(p: Ping) -> bool:
    ints = (p.sequence, p.projector, p.transmit_time_ns, p.window_start_ns, p.nav.time_ns,
            p.nav.quality)
    floats = [getattr(p.nav, n) for n in NAV_FIELDS if n not in ("time_ns", "quality")]
    return (all(type(v) is int and -2**63 <= v < 2**63 for v in ints) and p.sequence >= 0
            and type(p.sample_rate_hz) is float and math.isfinite(p.sample_rate_hz)
            and p.sample_rate_hz > 0 and all(type(v) is float for v in floats)
            and type(p.config_id) is str and isinstance(p.nav, NavSnapshot))


@settings(max_examples=MAX_EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(_frame_lists())
def test_decode_never_raises_anything_but_message_error(frames):
    tracemalloc.start()
    try:
        try:
            out = messages.decode(frames)
        except MessageError as exc:
            out = None
            what = (re.search(r"field '(\w+)'", str(exc))
                    or re.search(r"(topic|sample frame|frames?|header)", str(exc)))
            event(f"MessageError: {what and what[1]}")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20          # headers are < 1 kB here; samples are views
    if out is not None:
        event(type(out).__name__)
    if isinstance(out, Ping):
        assert frames[0] == TOPIC_PING and len(frames) == 3
        assert out.samples.nbytes == len(frames[2]) and not out.samples.flags.owndata
        assert out.samples.shape == tuple(json.loads(frames[1])["shape"])
        assert _well_typed(out)
    elif out is not None:
        assert isinstance(out, RunEnd) and frames[0] == TOPIC_END
        assert type(out.run_id) is str and type(out.n_pings) is int and out.n_pings >= 0
