"""Hostile ZeroMQ endpoints: refused with a reason before any socket binds or connects."""

from __future__ import annotations

import logging

import pytest
import zmq

from svss_daq.endpoints import check_endpoint
from svss_daq.publisher import PingPublisher
from svss_daq.subscriber import subscribe


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    c.destroy(linger=0)      # closes what a failed test left open


BAD = [  # endpoint, text the error must contain (besides the endpoint)
    ("tcp://127.0.0.1:0", "port '0' is not an integer in 1..65535"),
    ("tcp://127.0.0.1:65536", "port '65536' is not an integer in 1..65535"),
    ("tcp://127.0.0.1:99999", "port '99999' is not an integer in 1..65535"),
    ("tcp://127.0.0.1:abc", "port 'abc' is not an integer"),
    ("tcp://127.0.0.1:-1", "port '-1' is not an integer"),
    ("tcp://127.0.0.1: 5556", "port ' 5556' is not an integer"),
    ("tcp://127.0.0.1:٥٥٥٦", "is not an integer"),            # non-ASCII digits
    ("tcp://127.0.0.1", "expected tcp://HOST:PORT"),             # missing port
    ("tcp://127.0.0.1:", "port '' is not an integer"),
    ("tcp://:5556", "expected tcp://HOST:PORT"),                 # missing host
    ("tcp://[::1:5556", "is not an address or host name"),
    ("tcp://[zz::1]:5556", "host '[zz::1]' is not an IPv6 address"),
    ("tcp://bad host:5556", "host 'bad host' is not an address or host name"),
    ("udp://127.0.0.1:5556", "unknown transport 'udp'"),
    ("abc", "unknown transport 'abc'"),
    ("", "unknown transport ''"),
    ("tcp://", "expected a non-empty tcp address"),
    ("ipc://", "expected a non-empty ipc address"),
    ("inproc:// x", "without surrounding spaces"),
]


@pytest.mark.parametrize("bind", [True, False])
@pytest.mark.parametrize("endpoint, text", BAD)
def test_bad_endpoint_raises_naming_it(endpoint, text, bind):
    with pytest.raises(ValueError) as exc:
        check_endpoint(endpoint, bind=bind)
    assert repr(endpoint) in str(exc.value) and text in str(exc.value)


@pytest.mark.parametrize("endpoint, text", [
    ("tcp://127.0.0.1:*", "port '*' (a free port) can only be bound"),
    ("tcp://*:5556", "host '*' (every interface) can only be bound"),
])
def test_wildcards_are_for_binding_only(endpoint, text):
    with pytest.raises(ValueError, match=repr(endpoint).replace("*", r"\*")) as exc:
        check_endpoint(endpoint, bind=False)
    assert text in str(exc.value)


def test_not_a_string():
    with pytest.raises(ValueError, match="expected a string, got int"):
        check_endpoint(5556, bind=True)


@pytest.mark.parametrize("endpoint", ["tcp://127.0.0.1:5556", "tcp://127.0.0.1:*",
                                      "tcp://127.1.2.3:1", "tcp://localhost:65535",
                                      "tcp://[::1]:5556", "ipc:///tmp/svss.sock",
                                      "inproc://pings"])
def test_good_loopback_endpoints_pass_without_warning(endpoint, caplog):
    with caplog.at_level(logging.WARNING, logger="svss_daq.endpoints"):
        assert check_endpoint(endpoint, bind=True) == endpoint
        if "*" not in endpoint:
            assert check_endpoint(endpoint, bind=False) == endpoint
    assert not caplog.records


@pytest.mark.parametrize("endpoint, text", [
    ("tcp://*:5556", "every network interface"),
    ("tcp://0.0.0.0:5556", "every network interface"),
    ("tcp://[::]:5556", "every network interface"),
    ("tcp://192.0.2.7:5556", "non-loopback address 192.0.2.7"),
    ("tcp://sonar.example:5556", "non-loopback address sonar.example"),
])
def test_non_loopback_bind_warns(endpoint, text, caplog):
    with caplog.at_level(logging.WARNING, logger="svss_daq.endpoints"):
        assert check_endpoint(endpoint, bind=True) == endpoint
    [rec] = caplog.records
    assert rec.levelno == logging.WARNING
    assert endpoint in rec.getMessage() and text in rec.getMessage()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="svss_daq.endpoints"):
        check_endpoint(endpoint.replace("*", "127.0.0.1"), bind=False)  # connecting: quiet
    assert not caplog.records


@pytest.mark.parametrize("endpoint", ["tcp://127.0.0.1:99999", "tcp://127.0.0.1:0",
                                      "tcp://127.0.0.1", "udp://127.0.0.1:5556"])
def test_publisher_and_subscriber_refuse_bad_endpoints(endpoint, ctx):
    with pytest.raises(ValueError, match=repr(endpoint)):
        PingPublisher(endpoint, 10, ctx=ctx)
    with pytest.raises(ValueError, match=repr(endpoint)):
        subscribe(endpoint, 10, ctx=ctx)


def test_star_port_binds_a_free_port_and_subscriber_connects(ctx):
    with PingPublisher("tcp://127.0.0.1:*", 10, ctx=ctx) as pub:
        host, port = pub.endpoint.rsplit(":", 1)
        assert host == "tcp://127.0.0.1" and 1 <= int(port) <= 65535
        sub = subscribe(pub.endpoint, 10, ctx=ctx)
        assert sub.getsockopt(zmq.RCVHWM) == 10
        pub.wait_for_subscribers(timeout_s=10)
        sub.close(0)
        pub.close(0)


@pytest.mark.parametrize("hwm", [0, -1, 1.5, True, "10"])
def test_high_water_marks_must_be_positive_integers(hwm, ctx):
    with pytest.raises(ValueError, match=f"send_hwm: expected an integer >= 1.*{hwm!r}"):
        PingPublisher("tcp://127.0.0.1:*", hwm, ctx=ctx)
    with pytest.raises(ValueError, match=f"receive_hwm: expected an integer >= 1.*{hwm!r}"):
        subscribe("tcp://127.0.0.1:5556", hwm, ctx=ctx)
