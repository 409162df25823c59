"""Transmit-sequencer serial protocol: pure encode/decode and an incremental stream parser.

Every message is one ASCII sentence ``$SEQ,<TYPE>,<field>,...*hh\\r\\n`` where ``hh`` is
the XOR of the bytes between ``$`` and ``*`` as two hexadecimal digits. Host commands
carry a message id ``mid`` (1..65535) that the reply repeats. Times are int64 ns;
frequencies Hz. The full specification is in ``docs/protocols.md``.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from typing import Union

from .framing import ByteStream

__all__ = [
    "SequencerProtocolError", "SetSchedule", "SetWaveform", "SetInterval",
    "SetReceiveWindow", "Arm", "Start", "Stop", "StatusRequest", "Ack", "Nak", "Status",
    "PingEvent", "Message", "Command", "encode", "decode_sentence", "checksum",
    "SequencerStreamParser", "ErrorCode", "STATES", "MAX_SENTENCE", "MAX_MID",
]

logger = logging.getLogger(__name__)

MAX_SENTENCE = 200  #: longest sentence including '$' and '\r\n', bytes
MAX_MID = 65535
MAX_PROJECTORS = 64
STATES = ("IDLE", "ARMED", "RUNNING", "FAULT")


class ErrorCode:
    """NAK error codes."""
    BAD_CHECKSUM = 1
    UNKNOWN_COMMAND = 2
    BAD_ARGUMENT = 3
    WRONG_STATE = 4
    NOT_CONFIGURED = 5
    HARDWARE_FAULT = 6
    NAMES = {1: "bad checksum", 2: "unknown command", 3: "bad argument",
             4: "wrong state", 5: "not configured", 6: "hardware fault"}


class SequencerProtocolError(ValueError):
    """A sentence that does not follow the protocol; names the byte offset and field."""

    def __init__(self, offset: int, field: str, expected: str, found: str) -> None:
        self.offset, self.field, self.expected, self.found = offset, field, expected, found
        super().__init__(f"sequencer sentence error at byte offset {offset}: {field}: "
                         f"expected {expected}, found {found}")


# ------------------------------------------------------------------------ messages


@dataclass(frozen=True)
class SetSchedule:
    """Projector indices fired in turn, one per ping, cycled."""
    mid: int
    projectors: tuple[int, ...]
    TYPE = "SCHED"


@dataclass(frozen=True)
class SetWaveform:
    """Linear FM pulse from ``f_start_hz`` to ``f_stop_hz`` lasting ``duration_ns``."""
    mid: int
    kind: str
    f_start_hz: float
    f_stop_hz: float
    duration_ns: int
    TYPE = "WAVE"


@dataclass(frozen=True)
class SetInterval:
    """Ping repetition interval, ns."""
    mid: int
    interval_ns: int
    TYPE = "PRI"


@dataclass(frozen=True)
class SetReceiveWindow:
    """Receive window: opens ``start_ns`` after transmit, lasts ``length_ns``."""
    mid: int
    start_ns: int
    length_ns: int
    TYPE = "RXWIN"


@dataclass(frozen=True)
class Arm:
    mid: int
    TYPE = "ARM"


@dataclass(frozen=True)
class Start:
    mid: int
    TYPE = "START"


@dataclass(frozen=True)
class Stop:
    mid: int
    TYPE = "STOP"


@dataclass(frozen=True)
class StatusRequest:
    mid: int
    TYPE = "STATUS"


@dataclass(frozen=True)
class Ack:
    """Command ``command`` (its TYPE word) with id ``mid`` accepted."""
    mid: int
    command: str
    TYPE = "ACK"


@dataclass(frozen=True)
class Nak:
    """Command rejected with an :class:`ErrorCode` and a short text."""
    mid: int
    command: str
    code: int
    text: str
    TYPE = "NAK"


@dataclass(frozen=True)
class Status:
    """Reply to STATUS: state, next ping sequence number, pings sent, fault code (0 ok)."""
    mid: int
    state: str
    next_sequence: int
    pings_sent: int
    fault: int
    TYPE = "STAT"


@dataclass(frozen=True)
class PingEvent:
    """Unsolicited: ping ``sequence`` transmitted on ``projector`` at ``transmit_time_ns``."""
    sequence: int
    projector: int
    transmit_time_ns: int
    TYPE = "PING"


Command = Union[SetSchedule, SetWaveform, SetInterval, SetReceiveWindow, Arm, Start, Stop,
                StatusRequest]
Message = Union[Command, Ack, Nak, Status, PingEvent]
COMMAND_TYPES = {c.TYPE: c for c in (SetSchedule, SetWaveform, SetInterval, SetReceiveWindow,
                                     Arm, Start, Stop, StatusRequest)}
REPLY_TYPES = {c.TYPE: c for c in (Ack, Nak, Status, PingEvent)}
ALL_TYPES = {**COMMAND_TYPES, **REPLY_TYPES}

_TEXT_OK = re.compile(r"^[\x20-\x7e]*$")
_INT_RE = re.compile(r"^-?[0-9]{1,19}$")
_FLOAT_RE = re.compile(r"^-?[0-9]+(\.[0-9]*)?([eE][-+]?[0-9]+)?$")
_I64 = (-(1 << 63), (1 << 63) - 1)


def checksum(body: bytes) -> int:
    """XOR of the bytes between '$' and '*'."""
    c = 0
    for b in body:
        c ^= b
    return c


# ------------------------------------------------------------------------ encoding


def _fmt_float(x: float) -> str:
    if not math.isfinite(x):
        raise ValueError(f"sequencer: non-finite number {x!r}")
    return repr(float(x))


def _check_int(name: str, v: int, lo: int, hi: int) -> str:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ValueError(f"sequencer: field {name} expected an integer in [{lo}, {hi}], got {v!r}")
    return str(v)


def _check_text(name: str, s: str) -> str:
    if not isinstance(s, str) or not _TEXT_OK.match(s) or any(c in s for c in "$*,"):
        raise ValueError(f"sequencer: field {name} expected printable ASCII without '$*,', got {s!r}")
    return s


def _fields_of(msg: Message) -> list[str]:
    m = msg
    if isinstance(m, PingEvent):
        return [_check_int("sequence", m.sequence, 0, _I64[1]),
                _check_int("projector", m.projector, 0, MAX_PROJECTORS - 1),
                _check_int("transmit_time_ns", m.transmit_time_ns, *_I64)]
    out = [_check_int("mid", m.mid, 0 if isinstance(m, Nak) else 1, MAX_MID)]
    if isinstance(m, SetSchedule):
        if not 1 <= len(m.projectors) <= MAX_PROJECTORS:
            raise ValueError(f"sequencer: field projectors expected 1..{MAX_PROJECTORS} "
                             f"entries, got {len(m.projectors)}")
        out += [_check_int("projectors", p, 0, MAX_PROJECTORS - 1) for p in m.projectors]
    elif isinstance(m, SetWaveform):
        out += [_check_text("kind", m.kind), _fmt_float(m.f_start_hz), _fmt_float(m.f_stop_hz),
                _check_int("duration_ns", m.duration_ns, 1, _I64[1])]
    elif isinstance(m, SetInterval):
        out.append(_check_int("interval_ns", m.interval_ns, 1, _I64[1]))
    elif isinstance(m, SetReceiveWindow):
        out += [_check_int("start_ns", m.start_ns, 0, _I64[1]),
                _check_int("length_ns", m.length_ns, 1, _I64[1])]
    elif isinstance(m, Ack):
        out.append(_check_text("command", m.command))
    elif isinstance(m, Nak):
        out += [_check_text("command", m.command), _check_int("code", m.code, 0, 999),
                _check_text("text", m.text)]
    elif isinstance(m, Status):
        if m.state not in STATES:
            raise ValueError(f"sequencer: field state expected one of {STATES}, got {m.state!r}")
        out += [m.state, _check_int("next_sequence", m.next_sequence, 0, _I64[1]),
                _check_int("pings_sent", m.pings_sent, 0, _I64[1]),
                _check_int("fault", m.fault, 0, 999)]
    elif not isinstance(m, (Arm, Start, Stop, StatusRequest)):
        raise TypeError(f"sequencer: not a protocol message: {m!r}")
    return out


def encode(msg: Message) -> bytes:
    """One sentence, ``$SEQ,TYPE,...*hh\\r\\n``, as ASCII bytes."""
    body = ",".join(["SEQ", msg.TYPE] + _fields_of(msg)).encode("ascii")
    if len(body) + 6 > MAX_SENTENCE:
        raise ValueError(f"sequencer: sentence of {len(body) + 6} bytes exceeds {MAX_SENTENCE}")
    return b"$" + body + b"*%02X\r\n" % checksum(body)


# ------------------------------------------------------------------------ decoding


class _Fields:
    """Field cursor that reports errors with the byte offset of the field."""

    def __init__(self, parts: list[str], offsets: list[int], kind: str) -> None:
        self.parts, self.offsets, self.kind, self.i = parts, offsets, kind, 0

    def _next(self, name: str, expected: str) -> tuple[str, int]:
        if self.i >= len(self.parts):
            end = self.offsets[-1] + len(self.parts[-1]) if self.parts else 0
            raise SequencerProtocolError(end, f"{self.kind}.{name}", expected, "end of sentence")
        s, off = self.parts[self.i], self.offsets[self.i]
        self.i += 1
        return s, off

    def int(self, name: str, lo: int, hi: int) -> int:
        s, off = self._next(name, f"an integer in [{lo}, {hi}]")
        if not _INT_RE.match(s) or not lo <= int(s) <= hi:
            raise SequencerProtocolError(off, f"{self.kind}.{name}",
                                         f"an integer in [{lo}, {hi}]", repr(s[:24]))
        return int(s)

    def float(self, name: str) -> float:
        s, off = self._next(name, "a finite decimal number")
        if not _FLOAT_RE.match(s) or len(s) > 40 or not math.isfinite(float(s)):
            raise SequencerProtocolError(off, f"{self.kind}.{name}", "a finite decimal number",
                                         repr(s[:24]))
        return float(s)

    def text(self, name: str, choices: tuple[str, ...] | None = None) -> str:
        s, off = self._next(name, "text")
        if choices is not None and s not in choices:
            raise SequencerProtocolError(off, f"{self.kind}.{name}", f"one of {list(choices)}",
                                         repr(s[:24]))
        return s

    def rest(self) -> list[tuple[str, int]]:
        out = list(zip(self.parts[self.i:], self.offsets[self.i:]))
        self.i = len(self.parts)
        return out

    def done(self) -> None:
        if self.i < len(self.parts):
            raise SequencerProtocolError(self.offsets[self.i], self.kind, "end of sentence",
                                         f"extra field {self.parts[self.i][:24]!r}")


def decode_sentence(line: bytes, base_offset: int = 0) -> Message:
    """Decode one sentence (with or without the trailing CR/LF).

    Raises :class:`SequencerProtocolError` naming the byte offset (from the sentence's
    '$', plus ``base_offset``) and the field.
    """
    line = bytes(line)
    if line.endswith(b"\n"):
        line = line[:-1]
    if line.endswith(b"\r"):
        line = line[:-1]
    b = base_offset

    def err(off: int, fld: str, exp: str, found: str) -> SequencerProtocolError:
        return SequencerProtocolError(b + off, fld, exp, found)

    if len(line) + 2 > MAX_SENTENCE:
        raise err(MAX_SENTENCE, "sentence", f"at most {MAX_SENTENCE} bytes", f"{len(line) + 2} bytes")
    if not line.startswith(b"$"):
        raise err(0, "start", "'$'", repr(line[:1]))
    for i, c in enumerate(line):
        if c < 0x20 or c > 0x7E:
            raise err(i, "sentence", "printable ASCII", f"byte 0x{c:02X}")
    star = line.rfind(b"*")
    if star < 0 or len(line) - star != 3:
        raise err(max(star, len(line)), "checksum", "'*hh' at the end of the sentence",
                  repr(line[-3:].decode("ascii")))
    body, hh = line[1:star], line[star + 1:]
    try:
        want = int(hh, 16)
    except ValueError:
        raise err(star + 1, "checksum", "two hexadecimal digits", repr(hh.decode("ascii"))) from None
    got = checksum(body)
    if want != got:
        raise err(star + 1, "checksum", f"{got:02X} (XOR of the bytes between '$' and '*')",
                  hh.decode("ascii"))
    text = body.decode("ascii")
    parts = text.split(",")
    offsets, pos = [], 1
    for p in parts:
        offsets.append(pos)
        pos += len(p) + 1
    for p, o in zip(parts, offsets):
        if "$" in p or "*" in p:
            raise err(o, "field", "no '$' or '*' inside a field", repr(p[:24]))
    if parts[0] != "SEQ":
        raise err(1, "address", "'SEQ'", repr(parts[0][:24]))
    if len(parts) < 2 or parts[1] not in ALL_TYPES:
        raise err(offsets[1] if len(parts) > 1 else len(line), "type",
                  f"one of {sorted(ALL_TYPES)}", repr(parts[1][:24]) if len(parts) > 1 else "nothing")
    kind = parts[1]
    f = _Fields(parts[2:], [b + o for o in offsets[2:]], kind)
    msg: Message
    if kind == "PING":
        msg = PingEvent(f.int("sequence", 0, _I64[1]), f.int("projector", 0, MAX_PROJECTORS - 1),
                        f.int("transmit_time_ns", *_I64))
    else:
        mid = f.int("mid", 0 if kind == "NAK" else 1, MAX_MID)
        if kind == "SCHED":
            items = f.rest()
            if not 1 <= len(items) <= MAX_PROJECTORS:
                raise err(len(line), "SCHED.projectors", f"1..{MAX_PROJECTORS} projector indices",
                          f"{len(items)}")
            proj = []
            for s, o in items:
                if not _INT_RE.match(s) or not 0 <= int(s) < MAX_PROJECTORS:
                    raise SequencerProtocolError(o, "SCHED.projectors",
                                                 f"an integer in [0, {MAX_PROJECTORS - 1}]", repr(s[:24]))
                proj.append(int(s))
            msg = SetSchedule(mid, tuple(proj))
        elif kind == "WAVE":
            msg = SetWaveform(mid, f.text("kind"), f.float("f_start_hz"), f.float("f_stop_hz"),
                              f.int("duration_ns", 1, _I64[1]))
        elif kind == "PRI":
            msg = SetInterval(mid, f.int("interval_ns", 1, _I64[1]))
        elif kind == "RXWIN":
            msg = SetReceiveWindow(mid, f.int("start_ns", 0, _I64[1]), f.int("length_ns", 1, _I64[1]))
        elif kind == "ACK":
            msg = Ack(mid, f.text("command"))
        elif kind == "NAK":
            msg = Nak(mid, f.text("command"), f.int("code", 0, 999), f.text("text"))
        elif kind == "STAT":
            msg = Status(mid, f.text("state", STATES), f.int("next_sequence", 0, _I64[1]),
                         f.int("pings_sent", 0, _I64[1]), f.int("fault", 0, 999))
        else:
            msg = COMMAND_TYPES[kind](mid)
    f.done()
    return msg


# ------------------------------------------------------------------- stream parser


@dataclass
class SequencerStreamStats:
    bytes_fed: int = 0
    messages: int = 0
    rejected: int = 0        #: sentences that failed to decode
    bytes_discarded: int = 0  #: bytes outside any sentence, or in rejected ones
    errors: list = field(default_factory=list)  #: the last few errors (at most 8)


class SequencerStreamParser:
    """Turn a byte stream into messages; never raises, resynchronises on the next '$'.

    A sentence starts at a '$' and ends at '\\n'. A '$' inside a pending sentence starts
    a new one (the earlier bytes are discarded); a sentence longer than
    :data:`MAX_SENTENCE` is dropped. Memory is bounded by one sentence.
    """

    def __init__(self) -> None:
        # the bytes not yet framed, and the stream offset of the first
        self._stream = ByteStream("sequencer", logger)
        self.stats = SequencerStreamStats()

    def _reject(self, n: int, e: Exception | str) -> None:
        self.stats.bytes_discarded += n
        if isinstance(e, Exception):
            self.stats.rejected += 1
            self.stats.errors = (self.stats.errors + [str(e)])[-8:]
            logger.debug("sequencer stream: %s", e)

    def feed(self, data: bytes) -> list[Message]:
        out: list[Message] = []
        self.stats.bytes_fed += len(data)
        for chunk_start in range(0, len(data), 4096):
            self._stream.buf += data[chunk_start:chunk_start + 4096]
            out += self._scan()
        return out

    def _scan(self) -> list[Message]:
        out: list[Message] = []
        buf = self._stream.buf
        while buf:
            d = buf.find(b"$")
            if d < 0:
                self._drop(len(buf), None)
                break
            if d > 0:
                self._drop(d, None)
            nl = buf.find(b"\n")
            nxt = buf.find(b"$", 1)
            if nxt >= 0 and (nl < 0 or nxt < nl):
                self._drop(nxt, "$ inside a sentence")
                continue
            if nl < 0:
                if len(buf) > MAX_SENTENCE:
                    self._drop(len(buf), SequencerProtocolError(
                        self._stream.base, "sentence", f"a line end within {MAX_SENTENCE} bytes",
                        f"{len(buf)} bytes without one"))
                break
            line = bytes(buf[:nl + 1])
            try:
                msg = decode_sentence(line, self._stream.base)
            except (SequencerProtocolError, ValueError) as e:
                self._drop(nl + 1, e)
                continue
            self._advance(nl + 1)
            self.stats.messages += 1
            out.append(msg)
        return out

    def _advance(self, n: int) -> None:
        self._stream.consume(n)

    def _drop(self, n: int, why: Exception | str | None) -> None:
        if why is not None:
            self._reject(n, why)
        else:
            self.stats.bytes_discarded += n
        self._advance(n)

    def reset(self) -> None:
        self._stream.clear()
