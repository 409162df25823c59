"""The bytes of an instrument stream between reads: the one buffer of the stream parsers.

A serial or TCP read hands a parser any number of bytes: part of a record, several, or
garbage between them. :class:`ByteStream` keeps what was received and not yet framed,
with the stream offset of its first byte (so that a discard or an error names where in
the stream it was), takes any bytes-like object (anything else is refused with a
warning, never an exception: a parser must not stop acquisition), and drops the front
once it is framed or discarded. How records are found in it (a sync word, a sentence
start, resynchronisation after garbage) stays with each protocol: the PD0 parser
(:mod:`svss_daq.protocols.pd0`) searches its headers in :attr:`ByteStream.buf`, the
NMEA parser (:mod:`svss_daq.protocols.nmea`) and the daemon's record tap take its
lines (:meth:`ByteStream.lines`).
"""

from __future__ import annotations

import logging

logger = logging.getLogger(__name__)

__all__ = ["ByteStream"]


class ByteStream:
    """The bytes received and not yet framed (:attr:`buf`), and the stream offset of
    ``buf[0]`` (:attr:`base`). ``name`` names the stream in the warnings it logs on
    ``log`` (the protocol's logger; this module's by default); the bytes it takes are
    counted in ``stats.bytes_fed`` (a parser's counters) where ``stats`` is given."""

    __slots__ = ("name", "buf", "base", "log", "stats")

    def __init__(self, name: str, log: logging.Logger | None = None,
                 stats=None) -> None:
        self.name = name
        self.buf = bytearray()
        self.base = 0
        self.log = log or logger
        self.stats = stats

    def __len__(self) -> int:
        return len(self.buf)

    def feed(self, data) -> int | None:
        """Append ``data`` (any bytes-like object); the number of bytes added, or None
        (nothing added, a warning logged) when it is not bytes-like."""
        try:
            view = memoryview(data).cast("B")
        except TypeError:
            self.log.warning("%s stream: ignored a feed of non-bytes type %s", self.name,
                           type(data).__name__)
            return None
        self.buf += view
        if self.stats is not None:
            self.stats.bytes_fed += len(view)
        return len(view)

    def consume(self, n: int) -> None:
        """Drop the first ``n`` bytes (framed or discarded); the offset moves on."""
        if n <= 0:
            return
        try:
            del self.buf[:n]
        except BufferError:  # a lingering export; copy instead
            self.buf = bytearray(self.buf[n:])
        self.base += n

    def clear(self) -> int:
        """Drop every byte held; how many there were."""
        n = len(self.buf)
        if n:
            self.base += n
            self.buf = bytearray()
        return n

    def keep_last(self, n: int) -> int:
        """Keep at most the last ``n`` bytes; how many were dropped."""
        drop = len(self.buf) - n
        if drop <= 0:
            return 0
        self.consume(drop)
        return drop

    def lines(self) -> list[bytes]:
        """The complete lines held (each up to its ``\\n``, without it), consumed; what
        follows the last line end stays."""
        buf = self.buf
        out = []
        start = 0
        while True:
            nl = buf.find(b"\n", start)
            if nl < 0:
                break
            out.append(bytes(buf[start:nl]))
            start = nl + 1
        self.consume(start)
        return out
