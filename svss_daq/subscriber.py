"""The subscriber side of the ping stream: a bounded SUB socket on a checked endpoint."""

from __future__ import annotations

import zmq

from .endpoints import check_endpoint
from .config import CurveConfig
from .security import secure_client

TOPIC_PREFIX = b"svss."


def subscribe(endpoint: str, receive_hwm: int, ctx: zmq.Context | None = None,
              curve: CurveConfig | None = None) -> zmq.Socket:
    """A SUB socket connected to the ping publisher at ``endpoint`` (checked by
    :func:`~svss_daq.endpoints.check_endpoint`), subscribed to every SVSS topic.

    At most ``receive_hwm`` (>= 1) messages wait in the socket; beyond that ZeroMQ stops
    reading from the connection and the publisher's queue fills instead, where drops are
    counted (:class:`~svss_daq.publisher.PingPublisher`). A subscriber sees drops only as
    gaps in the ping sequence numbers.

    With ``curve`` enabled the socket is a CURVE client with this client's key pair and
    the publisher's public key (:func:`~svss_daq.security.secure_client`); key-file
    errors raise :class:`~svss_daq.config.ConfigError`.
    """
    check_endpoint(endpoint, bind=False)
    if isinstance(receive_hwm, bool) or not isinstance(receive_hwm, int) or receive_hwm < 1:
        raise ValueError(f"receive_hwm: expected an integer >= 1 (messages), got "
                         f"{receive_hwm!r}")
    ctx = ctx or zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    try:
        sock.setsockopt(zmq.RCVHWM, receive_hwm)
        sock.setsockopt(zmq.LINGER, 0)
        secure_client(sock, curve)
        sock.connect(endpoint)
        sock.setsockopt(zmq.SUBSCRIBE, TOPIC_PREFIX)
    except ValueError:
        sock.close(linger=0)
        raise
    except zmq.ZMQError as exc:
        sock.close(linger=0)
        raise OSError(f"cannot connect a ping subscriber to {endpoint}: {exc}") from None
    return sock
