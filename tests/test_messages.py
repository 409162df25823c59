"""Ping messages over real ZeroMQ sockets."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zmq

from svss_daq import messages
from svss_daq.messages import MessageError, RunEnd
from svss_daq.ping import NavSnapshot, Ping
from svss_daq.publisher import PingPublisher


def make_ping(seq: int = 7, nch: int = 80, ns: int = 1500) -> Ping:
    rng = np.random.default_rng(seq)
    samples = rng.integers(-2**23, 2**23, size=(nch, ns), dtype=np.int32)
    nav = NavSnapshot(time_ns=1_700_000_000_123_456_789 + seq, north_m=1.5, east_m=-2.25,
                      down_m=0.1, vel_north_m_s=1.0, vel_east_m_s=0.01, vel_down_m_s=0.0,
                      roll_rad=0.01, pitch_rad=-0.02, heading_rad=3.1, altitude_m=2.0,
                      latitude_deg=40.9, longitude_deg=-77.9, quality=5)
    return Ping(sequence=seq, projector=seq % 6, transmit_time_ns=nav.time_ns,
                sample_rate_hz=125e3, window_start_ns=1_000_000, samples=samples, nav=nav,
                config_id="abcdef0123456789")


def assert_same(a: Ping, b: Ping) -> None:
    assert (a.sequence, a.projector, a.transmit_time_ns, a.sample_rate_hz,
            a.window_start_ns, a.config_id) == (b.sequence, b.projector, b.transmit_time_ns,
                                                b.sample_rate_hz, b.window_start_ns,
                                                b.config_id)
    assert a.nav == b.nav
    np.testing.assert_array_equal(a.samples, b.samples)


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    c.term()


def test_round_trip_push_pull_zero_copy(ctx):
    push, pull = ctx.socket(zmq.PUSH), ctx.socket(zmq.PULL)
    port = pull.bind_to_random_port("tcp://127.0.0.1")
    push.connect(f"tcp://127.0.0.1:{port}")
    sent = [make_ping(i) for i in range(5)]
    for p in sent:
        messages.send(push, p)
    messages.send(push, RunEnd("run-1", 5))
    got = [messages.recv(pull) for _ in range(6)]
    for a, b in zip(sent, got):
        assert_same(a, b)
        assert not b.samples.flags.owndata          # a view of the received frame
    assert got[-1] == RunEnd("run-1", 5)
    push.close(0), pull.close(0)


def test_publisher_waits_for_subscriber_and_delivers_all(ctx):
    pub = PingPublisher("tcp://127.0.0.1:*", 100, ctx=ctx)
    sub = ctx.socket(zmq.SUB)
    sub.connect(pub.endpoint)
    sub.setsockopt(zmq.SUBSCRIBE, b"svss.")
    pub.wait_for_subscribers(timeout_s=10)
    sent = [make_ping(i, nch=8, ns=64) for i in range(50)]
    for p in sent:
        pub.publish(p)
    pub.publish(RunEnd("r", 50))
    assert sub.poll(10000)
    got = []
    while True:
        m = messages.recv(sub)
        if isinstance(m, RunEnd):
            break
        got.append(m)
    assert [p.sequence for p in got] == list(range(50))
    assert_same(sent[-1], got[-1])
    sub.close(0)
    pub.close(0)


def test_publisher_times_out_without_subscriber(ctx):
    pub = PingPublisher("tcp://127.0.0.1:*", 100, ctx=ctx)
    with pytest.raises(TimeoutError, match="no subscriber"):
        pub.wait_for_subscribers(timeout_s=0.3)
    pub.close(0)


def _frames(p: Ping) -> list[bytes]:
    return [bytes(f) for f in messages.encode_ping(p)]


def _with_header(frames, **changes):
    h = json.loads(frames[1])
    for k, v in changes.items():
        if v is None:
            h.pop(k)
        else:
            h[k] = v
    return [frames[0], json.dumps(h).encode(), *frames[2:]]


def test_malformed_messages_raise_clear_errors():
    f = _frames(make_ping(1, nch=4, ns=16))
    cases = [
        ([f[0]], "1 frame"),
        ([b"other", f[1], f[2]], "topic"),
        ([f[0], f[1]], "2 frames"),
        ([f[0], b"\xff\xfe not json", f[2]], "not a UTF-8 JSON header"),
        ([f[0], b"[1, 2]", f[2]], "JSON object"),
        (_with_header(f, version=99), "'version' is 99"),
        (_with_header(f, schema="svss.other"), "'schema'"),
        (_with_header(f, dtype="<f8"), "'dtype'"),
        (_with_header(f, shape=[4, 17]), "needs 272"),
        (_with_header(f, shape=[4]), "'shape'"),
        (_with_header(f, sequence="7"), "'sequence' expected int"),
        (_with_header(f, transmit_time_ns=None), "lacks field 'transmit_time_ns'"),
        ([f[0], f[1], f[2][:-4]], "holds 252 bytes"),
    ]
    nav_missing = _with_header(f)
    h = json.loads(nav_missing[1])
    del h["nav"]["altitude_m"]
    cases.append(([f[0], json.dumps(h).encode(), f[2]], "missing field 'altitude_m'"))
    for frames, text in cases:
        with pytest.raises(MessageError, match=text.replace("(", r"\(")):
            messages.decode(frames)
    # and a good one still decodes
    assert messages.decode(f).sequence == 1
