"""ZeroMQ encoding of pings and run markers.

A message is a multipart frame list: ``[topic, header, *buffers]``.
- topic: ``b"svss.ping"`` or ``b"svss.end"``;
- header: UTF-8 JSON with ``schema`` (``"svss.ping"`` / ``"svss.end"``) and ``version``;
- buffers: for a ping, one raw C-ordered little-endian int32 buffer of shape
  (n_channels, n_samples), sent and received without copying.
Never pickle. See docs/formats.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import zmq

from .ping import NavSnapshot, Ping

SCHEMA_VERSION = 1
TOPIC_PING = b"svss.ping"
TOPIC_END = b"svss.end"
_SAMPLE_DTYPE = "<i4"


class MessageError(ValueError):
    """A message that cannot be decoded."""


@dataclass(frozen=True)
class RunEnd:
    """End of a run: no more pings will follow on this stream."""
    run_id: str
    n_pings: int


def encode_ping(ping: Ping) -> list:
    """Frames for one ping: topic, JSON header, the sample buffer (no copy)."""
    samples = ping.samples
    if samples.dtype != np.dtype(_SAMPLE_DTYPE) or not samples.flags.c_contiguous:
        samples = np.ascontiguousarray(samples, dtype=_SAMPLE_DTYPE)
    header = {
        "schema": "svss.ping", "version": SCHEMA_VERSION,
        "sequence": int(ping.sequence), "projector": int(ping.projector),
        "transmit_time_ns": int(ping.transmit_time_ns),
        "sample_rate_hz": float(ping.sample_rate_hz),
        "window_start_ns": int(ping.window_start_ns),
        "dtype": _SAMPLE_DTYPE, "shape": list(samples.shape),
        "config_id": ping.config_id,
        "nav": ping.nav.to_dict(),
    }
    return [TOPIC_PING, json.dumps(header).encode(), samples.data]


def encode_end(end: RunEnd) -> list:
    header = {"schema": "svss.end", "version": SCHEMA_VERSION, "run_id": end.run_id,
              "n_pings": int(end.n_pings)}
    return [TOPIC_END, json.dumps(header).encode()]


def _buffer(frame) -> memoryview:
    return frame.buffer if isinstance(frame, zmq.Frame) else memoryview(frame)


def _header(frames: list, expect_schema: str) -> dict:
    try:
        header = json.loads(bytes(_buffer(frames[1])).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MessageError(f"{expect_schema} message: frame 1 is not a UTF-8 JSON header "
                           f"({exc})") from None
    if not isinstance(header, dict):
        raise MessageError(f"{expect_schema} message: header must be a JSON object")
    if header.get("schema") != expect_schema:
        raise MessageError(f"{expect_schema} message: header field 'schema' is "
                           f"{header.get('schema')!r}, expected {expect_schema!r}")
    if header.get("version") != SCHEMA_VERSION:
        raise MessageError(f"{expect_schema} message: header field 'version' is "
                           f"{header.get('version')!r}; this software reads version "
                           f"{SCHEMA_VERSION}")
    return header


def _field(header: dict, name: str, kind: type):
    if name not in header:
        raise MessageError(f"svss.ping message: header lacks field '{name}'")
    v = header[name]
    ok = isinstance(v, kind) and not isinstance(v, bool)
    if kind is float:
        ok = isinstance(v, (int, float)) and not isinstance(v, bool)
    if not ok:
        raise MessageError(f"svss.ping message: header field '{name}' expected "
                           f"{kind.__name__}, got {v!r}")
    return v


def decode(frames: list) -> Ping | RunEnd:
    """Decode a received multipart message into a :class:`Ping` or :class:`RunEnd`.

    Sample arrays are read-only views of the received buffer (no copy).
    """
    if len(frames) < 2:
        raise MessageError(f"message has {len(frames)} frame(s); expected topic and header")
    topic = bytes(_buffer(frames[0]))
    if topic == TOPIC_END:
        h = _header(frames, "svss.end")
        return RunEnd(str(h.get("run_id", "")), int(h.get("n_pings", -1)))
    if topic != TOPIC_PING:
        raise MessageError(f"message topic {topic[:40]!r}; expected {TOPIC_PING!r} or "
                           f"{TOPIC_END!r}")
    if len(frames) != 3:
        raise MessageError(f"svss.ping message has {len(frames)} frames; expected 3 "
                           "(topic, header, samples)")
    h = _header(frames, "svss.ping")
    dtype = _field(h, "dtype", str)
    if dtype != _SAMPLE_DTYPE:
        raise MessageError(f"svss.ping message: header field 'dtype' is {dtype!r}; "
                           f"expected {_SAMPLE_DTYPE!r}")
    shape = _field(h, "shape", list)
    if len(shape) != 2 or not all(isinstance(s, int) and s > 0 for s in shape):
        raise MessageError(f"svss.ping message: header field 'shape' is {shape!r}; "
                           "expected [n_channels, n_samples] of positive integers")
    buf = _buffer(frames[2])
    expected = shape[0] * shape[1] * 4
    if buf.nbytes != expected:
        raise MessageError(f"svss.ping message: sample frame holds {buf.nbytes} bytes; "
                           f"header shape {shape} of int32 needs {expected}")
    try:
        nav = NavSnapshot.from_dict(_field(h, "nav", dict))
    except ValueError as exc:
        raise MessageError(f"svss.ping message: {exc}") from None
    samples = np.frombuffer(buf, dtype=_SAMPLE_DTYPE).reshape(shape)
    return Ping(
        sequence=_field(h, "sequence", int), projector=_field(h, "projector", int),
        transmit_time_ns=_field(h, "transmit_time_ns", int),
        sample_rate_hz=float(_field(h, "sample_rate_hz", float)),
        window_start_ns=_field(h, "window_start_ns", int), samples=samples, nav=nav,
        config_id=str(h.get("config_id", "")))


def send(socket: zmq.Socket, msg: Ping | RunEnd) -> None:
    """Send a ping (zero-copy sample buffer) or an end-of-run marker."""
    if isinstance(msg, Ping):
        socket.send_multipart(encode_ping(msg), copy=False)
    else:
        socket.send_multipart(encode_end(msg))


def recv(socket: zmq.Socket) -> Ping | RunEnd:
    """Receive and decode one message (zero-copy)."""
    return decode(socket.recv_multipart(copy=False))
