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
import math
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
    """End of a run: no more pings will follow on this stream. ``n_pings``: the pings
    recorded; ``last``: the run's last sequence (None: not said), so that a subscriber
    that cannot ask the recording still knows what it lacks."""
    run_id: str
    n_pings: int
    last: int | None = None


def encode_ping(ping: Ping, run_id: str | None = None) -> list:
    """Frames for one ping: topic, JSON header, the sample buffer (no copy). ``run_id``:
    the run the ping belongs to (header field ``run_id``; a ping stream carries it so
    that a subscriber never has to infer a ping's run from its sequence number)."""
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
    if run_id is not None:
        header["run_id"] = str(run_id)
    return [TOPIC_PING, json.dumps(header).encode(), samples.data]


def encode_end(end: RunEnd) -> list:
    header = {"schema": "svss.end", "version": SCHEMA_VERSION, "run_id": end.run_id,
              "n_pings": int(end.n_pings)}
    if end.last is not None:
        header["last"] = int(end.last)
    return [TOPIC_END, json.dumps(header).encode()]


_INT64 = (-2**63, 2**63 - 1)
_MAX_HEADER_BYTES = 65536       # a ping header is about 700 bytes
_MAX_SHAPE = (65535, 2**31 - 1)  # channels, samples per channel


def _buffer(frames: list, i: int, schema: str) -> memoryview:
    frame = frames[i]
    try:
        buf = frame.buffer if isinstance(frame, zmq.Frame) else memoryview(frame)
    except TypeError:
        raise MessageError(f"{schema} message: frame {i} is a {type(frame).__name__}, "
                           "not a buffer") from None
    if not buf.c_contiguous:
        raise MessageError(f"{schema} message: frame {i} is not a contiguous buffer")
    return buf.cast("B") if buf.format != "B" or buf.ndim != 1 else buf


def _header(frames: list, expect_schema: str) -> dict:
    raw = _buffer(frames, 1, expect_schema)
    if raw.nbytes > _MAX_HEADER_BYTES:
        raise MessageError(f"{expect_schema} message: header frame holds {raw.nbytes} "
                           f"bytes; expected at most {_MAX_HEADER_BYTES}")
    try:
        header = json.loads(bytes(raw).decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise MessageError(f"{expect_schema} message: frame 1 is not a UTF-8 JSON header "
                           f"({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(header, dict):
        raise MessageError(f"{expect_schema} message: header must be a JSON object, got "
                           f"{type(header).__name__}")
    if header.get("schema") != expect_schema:
        raise MessageError(f"{expect_schema} message: header field 'schema' is "
                           f"{_show(header.get('schema'))}, expected {expect_schema!r}")
    version = header.get("version")
    if not (type(version) is int and version == SCHEMA_VERSION):
        raise MessageError(f"{expect_schema} message: header field 'version' is "
                           f"{_show(version)}; this software reads version "
                           f"{SCHEMA_VERSION}")
    return header


def _show(v) -> str:
    """repr of a header value, shortened for an error message."""
    r = repr(v)
    return r if len(r) <= 80 else r[:60] + f"... ({len(r)} characters)"


def _field(header: dict, name: str, kind: type, schema: str = "svss.ping", *,
           lo: int = _INT64[0], positive: bool = False):
    """``header[name]`` checked to be a ``kind``: int, an integer (not a bool) in
    ``lo``..2**63-1; float, a finite number (> 0 if ``positive``), returned as a float;
    str, list or dict. MessageError naming the field and what was expected otherwise."""
    if name not in header:
        raise MessageError(f"{schema} message: header lacks field '{name}'")
    v = header[name]
    number = isinstance(v, (int, float)) and not isinstance(v, bool)
    if kind is int:
        ok = number and isinstance(v, int) and lo <= v <= _INT64[1]
        expected = f"an integer in {lo}..{_INT64[1]}"
    elif kind is float:
        try:
            ok = number and math.isfinite(v) and (v > 0 or not positive)
        except OverflowError:           # an integer too large for a float
            ok = False
        expected = "a finite number" + (" > 0" if positive else "")
    else:
        ok = isinstance(v, kind)
        expected = {str: "a string", list: "a JSON array", dict: "a JSON object"}[kind]
    if not ok:
        raise MessageError(f"{schema} message: header field '{name}' expected "
                           f"{kind.__name__} ({expected}), got {_show(v)}")
    return float(v) if kind is float else v


def decode(frames: list) -> Ping | RunEnd:
    """Decode a received multipart message into a :class:`Ping` or :class:`RunEnd`, or
    raise :class:`MessageError` naming the frame or field at fault
    (:func:`decode_tagged` without the ping's run id)."""
    return decode_tagged(frames)[0]


def decode_tagged(frames: list) -> tuple[Ping | RunEnd, str | None]:
    """:func:`decode`, and the run id a ping's header names (header field ``run_id``,
    optional: None when absent; a RunEnd's is its own).

    Every header field is type- and range-checked and the sample frame's size compared
    with the header's shape before the samples are touched; sample arrays are read-only
    views of the received buffer (no copy, nothing allocated for them).
    """
    if not isinstance(frames, (list, tuple)):
        raise MessageError(f"message is a {type(frames).__name__}; expected a list of "
                           "frames")
    if len(frames) < 2:
        raise MessageError(f"message has {len(frames)} frame(s); expected topic and header")
    topic = _buffer(frames, 0, "svss")          # compared in place, never copied
    if topic == TOPIC_END:
        if len(frames) != 2:
            raise MessageError(f"svss.end message has {len(frames)} frames; expected 2 "
                               "(topic, header)")
        h = _header(frames, "svss.end")
        end = RunEnd(_field(h, "run_id", str, "svss.end"),
                     _field(h, "n_pings", int, "svss.end", lo=0),
                     _field(h, "last", int, "svss.end", lo=0) if "last" in h else None)
        return end, end.run_id
    if topic != TOPIC_PING:
        raise MessageError(f"message topic {bytes(topic[:40])!r}; expected "
                           f"{TOPIC_PING!r} or {TOPIC_END!r}")
    if len(frames) != 3:
        raise MessageError(f"svss.ping message has {len(frames)} frames; expected 3 "
                           "(topic, header, samples)")
    h = _header(frames, "svss.ping")
    dtype = _field(h, "dtype", str)
    if dtype != _SAMPLE_DTYPE:
        raise MessageError(f"svss.ping message: header field 'dtype' is {_show(dtype)}; "
                           f"expected {_SAMPLE_DTYPE!r}")
    shape = _field(h, "shape", list)
    if len(shape) != 2 or not all(type(s) is int and 1 <= s <= m
                                  for s, m in zip(shape, _MAX_SHAPE)):
        raise MessageError(f"svss.ping message: header field 'shape' is {_show(shape)}; "
                           "expected [n_channels, n_samples] of integers in "
                           f"1..{_MAX_SHAPE[0]} and 1..{_MAX_SHAPE[1]}")
    fields = {
        "sequence": _field(h, "sequence", int, lo=0),
        "projector": _field(h, "projector", int),
        "transmit_time_ns": _field(h, "transmit_time_ns", int),
        "sample_rate_hz": _field(h, "sample_rate_hz", float, positive=True),
        "window_start_ns": _field(h, "window_start_ns", int),
        "config_id": _field(h, "config_id", str)}
    try:
        nav = NavSnapshot.from_dict(_field(h, "nav", dict))
    except ValueError as exc:
        raise MessageError(f"svss.ping message: header field 'nav': {exc}") from None
    buf = _buffer(frames, 2, "svss.ping")
    expected = shape[0] * shape[1] * 4
    if buf.nbytes != expected:
        raise MessageError(f"svss.ping message: sample frame holds {buf.nbytes} bytes; "
                           f"header shape {shape} of int32 needs {expected}")
    samples = np.frombuffer(buf, dtype=_SAMPLE_DTYPE).reshape(shape)
    run_id = _field(h, "run_id", str) if "run_id" in h else None
    return Ping(samples=samples, nav=nav, **fields), run_id


def send(socket: zmq.Socket, msg: Ping | RunEnd, flags: int = 0,
         run_id: str | None = None) -> None:
    """Send a ping (zero-copy sample buffer; ``run_id``: the run it belongs to) or an
    end-of-run marker; ``flags`` as for ``send_multipart`` (``zmq.NOBLOCK``: raise
    ``zmq.Again`` instead of waiting)."""
    if isinstance(msg, Ping):
        socket.send_multipart(encode_ping(msg, run_id), flags, copy=False)
    else:
        socket.send_multipart(encode_end(msg), flags)


def recv(socket: zmq.Socket) -> Ping | RunEnd:
    """Receive and decode one message (zero-copy)."""
    return decode(socket.recv_multipart(copy=False))


def recv_tagged(socket: zmq.Socket) -> tuple[Ping | RunEnd, str | None]:
    """Receive and decode one message (zero-copy) with its run id
    (:func:`decode_tagged`)."""
    return decode_tagged(socket.recv_multipart(copy=False))
