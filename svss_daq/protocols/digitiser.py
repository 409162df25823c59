"""Digitiser TCP protocol: binary frames, pure encode/decode, an incremental frame parser
that resynchronises on the sync word, and reassembly of whole pings from frames.

Every frame is a 60-byte little-endian header followed by a payload. The header carries
a sync word, the protocol version, the frame type, the ping number, two int64 ns
timestamps, the ping's channel count, the block of channels in this frame, the samples
per channel, the sample format, the frame's index within the ping, the payload length,
the payload's CRC-32 and the header's own CRC-32. A ping may span several frames (e.g.
one per block of channels). Control frames (commands and replies) use the same header
with a 16-byte payload. The specification is in ``docs/protocols.md``.
"""

from __future__ import annotations

import logging
import struct
import zlib
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

__all__ = [
    "MAGIC", "VERSION", "HEADER", "HEADER_SIZE", "FrameType", "SampleFormat", "CommandCode",
    "ReplyStatus", "DigitiserProtocolError", "FrameHeader", "DataFrame", "CommandFrame",
    "ReplyFrame", "CorruptFrame", "encode_data_frames", "encode_command", "encode_reply",
    "decode_header", "decode_frame", "FrameStreamParser", "FrameReassembler", "CompletePing",
    "IncompletePing", "DigitiserStreamDecoder",
]

logger = logging.getLogger(__name__)

MAGIC = b"SVDG"
VERSION = 1
#: magic, version, type, flags, ping, transmit ns, first-sample ns, n_channels,
#: channel_first, channel_count, sample_format, reserved, n_samples, frame_index,
#: frame_count, payload_length, payload_crc32, header_crc32
HEADER = struct.Struct("<4sBBHQqqHHHBBIHHIII")
HEADER_SIZE = HEADER.size  # 60
CONTROL = struct.Struct("<IHhd")  # request id, command code, status, value
MAX_CHANNELS = 4096
MAX_SAMPLES = 10_000_000
DEFAULT_MAX_PAYLOAD = 64 << 20


class FrameType:
    DATA = 1
    COMMAND = 2
    REPLY = 3


class SampleFormat:
    """Sample encodings: code -> numpy dtype (all little-endian)."""
    INT32_24BIT = 1  #: 24-bit two's-complement ADC codes sign-extended into int32
    INT16 = 2
    DTYPES = {1: np.dtype("<i4"), 2: np.dtype("<i2")}


class CommandCode:
    START = 1
    STOP = 2
    SET_GAIN = 3   #: value: analogue gain, dB
    STATUS = 4     #: reply value: pings sent since START
    NAMES = {1: "START", 2: "STOP", 3: "SET_GAIN", 4: "STATUS"}


class ReplyStatus:
    OK = 0
    UNKNOWN_COMMAND = -1
    BAD_VALUE = -2
    WRONG_STATE = -3
    NAMES = {0: "ok", -1: "unknown command", -2: "bad value", -3: "wrong state"}


class DigitiserProtocolError(ValueError):
    """A frame that does not follow the protocol; names the byte offset and field."""

    def __init__(self, offset: int, field: str, expected: str, found: str) -> None:
        self.offset, self.field, self.expected, self.found = offset, field, expected, found
        super().__init__(f"digitiser frame error at byte offset {offset}: {field}: "
                         f"expected {expected}, found {found}")


@dataclass(frozen=True)
class FrameHeader:
    frame_type: int
    ping_number: int
    transmit_time_ns: int       #: transmit (trigger) time of the ping, ns since epoch UTC
    first_sample_time_ns: int   #: time of the ping's first sample, ns since epoch UTC
    n_channels: int             #: channels in the whole ping
    channel_first: int          #: first channel carried by this frame
    channel_count: int          #: channels carried by this frame
    sample_format: int
    n_samples: int              #: samples per channel
    frame_index: int
    frame_count: int            #: frames making up the ping
    payload_length: int
    payload_crc32: int
    flags: int = 0


@dataclass(frozen=True)
class DataFrame:
    header: FrameHeader
    samples: np.ndarray  #: int32 (channel_count, n_samples)
    offset: int = 0      #: stream byte offset of the frame


@dataclass(frozen=True)
class CommandFrame:
    request_id: int
    command: int
    value: float
    offset: int = 0


@dataclass(frozen=True)
class ReplyFrame:
    request_id: int
    command: int
    status: int
    value: float
    offset: int = 0


@dataclass(frozen=True)
class CorruptFrame:
    """A frame with a valid header whose payload failed its CRC or could not be used."""
    header: FrameHeader
    offset: int
    reason: str


Frame = Union[DataFrame, CommandFrame, ReplyFrame]


# ------------------------------------------------------------------------ encoding


def _pack_header(h: FrameHeader) -> bytes:
    raw = HEADER.pack(MAGIC, VERSION, h.frame_type, h.flags, h.ping_number, h.transmit_time_ns,
                      h.first_sample_time_ns, h.n_channels, h.channel_first, h.channel_count,
                      h.sample_format, 0, h.n_samples, h.frame_index, h.frame_count,
                      h.payload_length, h.payload_crc32, 0)
    return raw[:-4] + struct.pack("<I", zlib.crc32(raw[:-4]))


def encode_data_frames(ping_number: int, transmit_time_ns: int, first_sample_time_ns: int,
                       samples: np.ndarray, channels_per_frame: int,
                       sample_format: int = SampleFormat.INT32_24BIT) -> list[bytes]:
    """A ping's samples (channels x samples, integer) as frames of ``channels_per_frame``
    channels each (the last may be shorter)."""
    samples = np.asarray(samples)
    if samples.ndim != 2:
        raise ValueError(f"digitiser: samples must be (channels, samples), got {samples.shape}")
    nch, ns = samples.shape
    if not 1 <= nch <= MAX_CHANNELS or not 1 <= ns <= MAX_SAMPLES:
        raise ValueError(f"digitiser: {nch} channels x {ns} samples outside "
                         f"[1, {MAX_CHANNELS}] x [1, {MAX_SAMPLES}]")
    dt = SampleFormat.DTYPES[sample_format]
    info = np.iinfo(dt) if sample_format != SampleFormat.INT32_24BIT else None
    lo, hi = (-(1 << 23), (1 << 23) - 1) if info is None else (info.min, info.max)
    if samples.size and (samples.min() < lo or samples.max() > hi):
        raise ValueError(f"digitiser: samples outside [{lo}, {hi}] for sample format {sample_format}")
    cpf = max(1, int(channels_per_frame))
    count = -(-nch // cpf)
    if count > 65535:
        raise ValueError(f"digitiser: {count} frames per ping exceeds 65535")
    out = []
    for k in range(count):
        c0 = k * cpf
        block = np.ascontiguousarray(samples[c0:c0 + cpf], dtype=dt).tobytes()
        h = FrameHeader(FrameType.DATA, ping_number, transmit_time_ns, first_sample_time_ns, nch,
                        c0, min(cpf, nch - c0), sample_format, ns, k, count, len(block),
                        zlib.crc32(block))
        out.append(_pack_header(h) + block)
    return out


def _control(ftype: int, payload: bytes) -> bytes:
    h = FrameHeader(ftype, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, len(payload), zlib.crc32(payload))
    return _pack_header(h) + payload


def encode_command(request_id: int, command: int, value: float = 0.0) -> bytes:
    return _control(FrameType.COMMAND, CONTROL.pack(request_id, command, 0, value))


def encode_reply(request_id: int, command: int, status: int, value: float = 0.0) -> bytes:
    return _control(FrameType.REPLY, CONTROL.pack(request_id, command, status, value))


# ------------------------------------------------------------------------ decoding


def decode_header(data: bytes, offset: int = 0, *, max_payload: int = DEFAULT_MAX_PAYLOAD,
                  base_offset: int = 0) -> FrameHeader:
    """Check and decode the header at ``data[offset:]``; errors name the byte offset
    (``base_offset + offset`` + the field's position) and the field."""
    o = base_offset + offset

    def err(pos: int, fld: str, exp: str, found: str) -> DigitiserProtocolError:
        return DigitiserProtocolError(o + pos, fld, exp, found)

    if len(data) - offset < HEADER_SIZE:
        raise err(0, "header", f"{HEADER_SIZE} bytes", f"{max(0, len(data) - offset)} bytes")
    (magic, ver, ftype, flags, ping, tx, t0, nch, c0, cc, fmt, _res, ns, fi, fc, plen, pcrc,
     hcrc) = HEADER.unpack_from(data, offset)
    if magic != MAGIC:
        raise err(0, "magic", repr(MAGIC), repr(magic))
    crc = zlib.crc32(bytes(data[offset:offset + HEADER_SIZE - 4]))
    if crc != hcrc:
        raise err(56, "header_crc32", f"0x{crc:08X} (CRC-32 of header bytes 0-55)", f"0x{hcrc:08X}")
    if ver != VERSION:
        raise err(4, "version", str(VERSION), str(ver))
    if ftype not in (FrameType.DATA, FrameType.COMMAND, FrameType.REPLY):
        raise err(5, "frame_type", "1 (data), 2 (command) or 3 (reply)", str(ftype))
    if plen > max_payload:
        raise err(48, "payload_length", f"at most {max_payload}", str(plen))
    if ftype == FrameType.DATA:
        if fmt not in SampleFormat.DTYPES:
            raise err(38, "sample_format", f"one of {sorted(SampleFormat.DTYPES)}", str(fmt))
        if not 1 <= nch <= MAX_CHANNELS:
            raise err(32, "n_channels", f"1..{MAX_CHANNELS}", str(nch))
        if cc < 1 or c0 + cc > nch:
            raise err(34, "channel_first/channel_count", f"a block inside 0..{nch - 1}",
                      f"{c0}+{cc}")
        if not 1 <= ns <= MAX_SAMPLES:
            raise err(40, "n_samples", f"1..{MAX_SAMPLES}", str(ns))
        if fc < 1 or fi >= fc:
            raise err(44, "frame_index/frame_count", "index < count, count >= 1", f"{fi}/{fc}")
        want = cc * ns * SampleFormat.DTYPES[fmt].itemsize
        if plen != want:
            raise err(48, "payload_length", f"{want} (channel_count x n_samples x sample size)",
                      str(plen))
    elif plen != CONTROL.size:
        raise err(48, "payload_length", f"{CONTROL.size} for a control frame", str(plen))
    return FrameHeader(ftype, ping, tx, t0, nch, c0, cc, fmt, ns, fi, fc, plen, pcrc, flags)


def _payload_to_frame(h: FrameHeader, payload: bytes, offset: int) -> Frame:
    if h.frame_type == FrameType.DATA:
        a = np.frombuffer(payload, dtype=SampleFormat.DTYPES[h.sample_format])
        return DataFrame(h, a.astype(np.int32).reshape(h.channel_count, h.n_samples), offset)
    rid, cmd, status, value = CONTROL.unpack(payload)
    if h.frame_type == FrameType.COMMAND:
        return CommandFrame(rid, cmd, value, offset)
    return ReplyFrame(rid, cmd, status, value, offset)


def decode_frame(data: bytes, offset: int = 0, *, max_payload: int = DEFAULT_MAX_PAYLOAD,
                 base_offset: int = 0) -> tuple[Frame, int]:
    """Decode one whole frame at ``data[offset:]``; returns (frame, bytes used)."""
    h = decode_header(data, offset, max_payload=max_payload, base_offset=base_offset)
    end = offset + HEADER_SIZE + h.payload_length
    if len(data) < end:
        raise DigitiserProtocolError(base_offset + offset + HEADER_SIZE, "payload",
                                     f"{h.payload_length} bytes",
                                     f"{len(data) - offset - HEADER_SIZE} bytes")
    payload = bytes(data[offset + HEADER_SIZE:end])
    crc = zlib.crc32(payload)
    if crc != h.payload_crc32:
        raise DigitiserProtocolError(base_offset + offset + HEADER_SIZE, "payload_crc32",
                                     f"0x{h.payload_crc32:08X} (from the header)", f"0x{crc:08X}")
    return _payload_to_frame(h, payload, base_offset + offset), HEADER_SIZE + h.payload_length


# ------------------------------------------------------------------- frame stream


@dataclass
class FrameStreamStats:
    bytes_fed: int = 0
    frames: int = 0
    bad_headers: int = 0       #: sync words whose header failed its checks
    corrupt_payloads: int = 0  #: valid headers whose payload failed its CRC
    bytes_discarded: int = 0
    last_error: str = ""


class FrameStreamParser:
    """Split a byte stream into frames; never raises on any input.

    Searches for the sync word, checks the header (its CRC first) as soon as its 60 bytes
    are in, skips one byte and searches again on a bad header, waits for the payload and
    checks its CRC. A frame whose payload fails is reported as :class:`CorruptFrame` and
    the search resumes right after its header, so that a truncated frame cannot swallow
    the frame after it. Memory: one frame plus the last chunk.
    """

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self.max_payload = max_payload
        self._buf = bytearray()
        self._pos = 0          # read position in _buf
        self._base = 0         # stream offset of _buf[0]
        self._header: Optional[FrameHeader] = None  # validated header at _pos
        self.stats = FrameStreamStats()

    def reset(self) -> None:
        self._base += len(self._buf)
        self._buf.clear()
        self._pos = 0
        self._header = None

    def feed(self, data: bytes) -> list[Union[Frame, CorruptFrame]]:
        self.stats.bytes_fed += len(data)
        self._buf += data
        out: list[Union[Frame, CorruptFrame]] = []
        buf = self._buf
        while True:
            if self._header is None:
                i = buf.find(MAGIC, self._pos)
                if i < 0:
                    keep = max(self._pos, len(buf) - (len(MAGIC) - 1))
                    self._discard_to(keep)
                    break
                self._discard_to(i)
                if len(buf) - self._pos < HEADER_SIZE:
                    break
                try:
                    self._header = decode_header(buf, self._pos, max_payload=self.max_payload,
                                                 base_offset=self._base)
                except DigitiserProtocolError as e:
                    self.stats.bad_headers += 1
                    self.stats.last_error = str(e)
                    logger.debug("digitiser stream: %s", e)
                    self._discard_to(self._pos + 1)
                    continue
            h = self._header
            end = self._pos + HEADER_SIZE + h.payload_length
            if len(buf) < end:
                break
            off = self._base + self._pos
            payload = bytes(buf[self._pos + HEADER_SIZE:end])
            self._header = None
            if zlib.crc32(payload) != h.payload_crc32:
                self.stats.corrupt_payloads += 1
                msg = (f"digitiser frame error at byte offset {off + HEADER_SIZE}: payload_crc32: "
                       f"expected 0x{h.payload_crc32:08X}, found 0x{zlib.crc32(payload):08X}")
                self.stats.last_error = msg
                logger.warning("%s (ping %d, frame %d/%d)", msg, h.ping_number, h.frame_index,
                               h.frame_count)
                out.append(CorruptFrame(h, off, "payload CRC-32 mismatch"))
                # resume the search right after the header: if the frame was truncated,
                # its "payload" holds the start of the next frame
                self.stats.bytes_discarded += HEADER_SIZE
                self._pos += HEADER_SIZE
            else:
                out.append(_payload_to_frame(h, payload, off))
                self.stats.frames += 1
                self._pos = end
        if self._pos > 65536 or self._pos == len(buf):
            del buf[:self._pos]
            self._base += self._pos
            self._pos = 0
        return out

    def _discard_to(self, i: int) -> None:
        if i > self._pos:
            self.stats.bytes_discarded += i - self._pos
            self._pos = i


# ------------------------------------------------------------------- reassembly


@dataclass(frozen=True)
class CompletePing:
    ping_number: int
    transmit_time_ns: int
    first_sample_time_ns: int
    samples: np.ndarray  #: int32 (n_channels, n_samples)


@dataclass(frozen=True)
class IncompletePing:
    """A ping that could not be completed: frames missing, corrupt or inconsistent.
    ``missing_frames``: indices never received (empty when not known); ``reason`` says why.

    Ping numbers skipped entirely (no frame at all) are one item for the whole gap:
    ``frames_received`` 0, ``ping_number`` the first missing and ``last_ping_number``
    the last (:attr:`n_pings` of them), however long the gap."""
    ping_number: int
    frames_received: int
    frame_count: int
    missing_frames: tuple[int, ...]
    reason: str
    last_ping_number: Optional[int] = None

    @property
    def n_pings(self) -> int:
        """How many ping numbers this item stands for (1 unless a gap)."""
        last = self.ping_number if self.last_ping_number is None else self.last_ping_number
        return last - self.ping_number + 1


@dataclass
class _Open:
    first: FrameHeader
    samples: np.ndarray
    have: set = field(default_factory=set)
    corrupt: int = 0
    problem: str = ""


class FrameReassembler:
    """Reassemble pings from data frames.

    The frames of a ping are sent together (in any order among themselves) before the
    next ping's. A frame of another ping closes the open one: complete if every frame
    arrived intact, else reported as :class:`IncompletePing`. Ping numbers skipped
    entirely are reported as one incomplete ping with no frames carrying the gap's range
    (never one item per missing number: a gap's length comes from the wire).
    ``flush()`` closes the open ping (end of stream, or no frame for a while).
    """

    def __init__(self) -> None:
        self._open: Optional[_Open] = None
        self._last_closed: Optional[int] = None
        self.complete = 0
        self.incomplete = 0
        self.skipped = 0      # ping numbers with no frame at all

    @property
    def open_ping(self) -> Optional[int]:
        return None if self._open is None else self._open.first.ping_number

    def add(self, frame: Union[DataFrame, CorruptFrame]) -> list[Union[CompletePing, IncompletePing]]:
        h = frame.header
        out: list[Union[CompletePing, IncompletePing]] = []
        if self._open is not None and self._open.first.ping_number != h.ping_number:
            out += self.flush()
        if self._open is None:
            if self._last_closed is not None and h.ping_number <= self._last_closed:
                # a late frame of a closed ping, or the device restarted its numbering
                if self._last_closed - h.ping_number < 2:
                    logger.warning("digitiser: frame of already closed ping %d ignored", h.ping_number)
                    return out
                logger.info("digitiser: ping numbering restarted at %d (after %d)",
                            h.ping_number, self._last_closed)
                self._last_closed = None
            if self._last_closed is not None and h.ping_number > self._last_closed + 1:
                gap = h.ping_number - self._last_closed - 1
                logger.warning("digitiser: %d ping(s) missing before ping %d", gap, h.ping_number)
                out.append(IncompletePing(self._last_closed + 1, 0, 0, (), "no frame received",
                                          last_ping_number=h.ping_number - 1))
                self.skipped += gap
            self._open = _Open(h, np.zeros((h.n_channels, h.n_samples), np.int32))
        o = self._open
        f0 = o.first
        if (h.n_channels, h.n_samples, h.frame_count, h.transmit_time_ns) != (
                f0.n_channels, f0.n_samples, f0.frame_count, f0.transmit_time_ns):
            o.problem = (f"frame {h.frame_index} disagrees with frame {f0.frame_index} on "
                         f"channels/samples/frame count/transmit time")
            return out
        if isinstance(frame, CorruptFrame):
            o.corrupt += 1
            return out
        if h.frame_index in o.have:
            o.problem = f"frame {h.frame_index} received twice"
            return out
        o.have.add(h.frame_index)
        o.samples[h.channel_first:h.channel_first + h.channel_count] = frame.samples
        if len(o.have) == f0.frame_count and not o.problem and not o.corrupt:
            out += self.flush()
        return out

    def flush(self) -> list[Union[CompletePing, IncompletePing]]:
        o, self._open = self._open, None
        if o is None:
            return []
        f0 = o.first
        self._last_closed = f0.ping_number
        if len(o.have) == f0.frame_count and not o.problem and not o.corrupt:
            self.complete += 1
            return [CompletePing(f0.ping_number, f0.transmit_time_ns, f0.first_sample_time_ns,
                                 o.samples)]
        missing = tuple(sorted(set(range(f0.frame_count)) - o.have))
        reasons = []
        if missing:
            reasons.append(f"{len(missing)} frame(s) missing")
        if o.corrupt:
            reasons.append(f"{o.corrupt} corrupt frame(s)")
        if o.problem:
            reasons.append(o.problem)
        self.incomplete += 1
        logger.warning("digitiser: ping %d incomplete: %s", f0.ping_number, "; ".join(reasons))
        return [IncompletePing(f0.ping_number, len(o.have), f0.frame_count, missing,
                               "; ".join(reasons))]

    def reset(self) -> None:
        self._open = None
        self._last_closed = None


class DigitiserStreamDecoder:
    """Bytes in, pings and control frames out: :class:`FrameStreamParser` feeding a
    :class:`FrameReassembler`. Never raises on any input."""

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self.frames = FrameStreamParser(max_payload)
        self.assembler = FrameReassembler()

    def feed(self, data: bytes) -> list:
        out: list = []
        for fr in self.frames.feed(data):
            if isinstance(fr, (DataFrame, CorruptFrame)):
                if isinstance(fr, CorruptFrame) and fr.header.frame_type != FrameType.DATA:
                    continue
                out += self.assembler.add(fr)
            else:
                out.append(fr)
        return out

    def flush(self) -> list:
        return self.assembler.flush()

    def reset(self) -> list:
        """Start a new stream (after a reconnection): the open ping is reported."""
        out = self.assembler.flush()
        self.frames.reset()
        return out
