"""The incremental PD0 stream parser: :class:`Pd0StreamParser` is fed bytes as they
arrive (:class:`~svss_daq.protocols.framing.ByteStream` keeps them), finds ensembles
and resynchronises on garbage, skips Sentinel V vendor blocks, never raises and holds
bounded memory; :class:`Pd0StreamStats` counts what it did. The protocol is described
in :mod:`svss_daq.protocols.pd0`, its public face.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from typing import Optional

from .framing import ByteStream
from .pd0_ensemble import (DECODED_IDS, HEADER_ID, KNOWN_UNDECODED_IDS, MAX_ENSEMBLE_BYTES,
                           VENDOR_BLOCK_ID, NeedMore, Pd0DecodeError, Pd0Ensemble,
                           decode_ensemble, ensemble_checksum, parse_header)

__all__ = ["Pd0StreamStats", "Pd0StreamParser"]

logger = logging.getLogger("svss_daq.protocols.pd0")   # the protocol's one logger



@dataclass
class Pd0StreamStats:
    """Counters of a :class:`Pd0StreamParser` (bytes are stream bytes)."""

    bytes_fed: int = 0
    ensembles: int = 0
    bytes_discarded: int = 0
    discard_runs: int = 0  #: contiguous discarded stretches (one warning each)
    bad_headers: int = 0
    bad_checksums: int = 0
    decode_errors: int = 0  #: checksum right but contents inconsistent
    internal_errors: int = 0  #: decoder bugs caught to keep the stream alive (should stay 0)
    vendor_blocks: int = 0  #: 0x7F79 blocks between ensembles, skipped quietly
    vendor_block_bytes: int = 0  #: their bytes (not in bytes_discarded)
    known_types_skipped: int = 0  #: data types of KNOWN_UNDECODED_IDS met in ensembles
    unknown_types: int = 0  #: data types neither decoded nor in KNOWN_UNDECODED_IDS


class Pd0StreamParser:
    """Incremental PD0 parser: ``for ens in parser.feed(chunk): ...``.

    It searches for ``0x7F7F``, checks the header, waits for the byte count, checks
    the checksum and decodes. On a bad header, a bad checksum or undecodable
    contents it skips one byte and searches again. If the candidate at the front
    cannot complete yet but a later header already yields a whole checksum-valid
    ensemble, the front candidate is taken to be garbage (so a false header cannot
    hold good data back). Each discarded stretch is counted and logged once
    (warning) with its stream byte offset and reason. Sentinel V vendor blocks
    (``0x7F79`` + uint16 count, count + 2 bytes, followed by a header or closed by a
    matching checksum, holding no valid ensemble) are skipped quietly and counted, as
    are known but undecoded data types; :meth:`flush` logs one summary line of them.

    It never raises on any input, does work linear in the bytes fed, and keeps at
    most :data:`MAX_ENSEMBLE_BYTES` plus the last chunk between calls. Call
    :meth:`flush` at the end of a stream to decode what a false header was holding
    back and to log the final discards.
    """

    def __init__(self) -> None:
        self.stats = Pd0StreamStats()
        # the bytes not yet framed, and the stream offset of the first
        self._stream = ByteStream("PD0", logger, self.stats)
        self._discard_start: Optional[int] = None
        self._discard_len = 0
        self._discard_reasons: set = set()
        self._la_scanned = 0  # stream offset from which later headers are still unseen
        self._la_pending: list = []  # [stream offset, stream offset it needs to reach]
        self._skipped_ids: set = set()  # known undecoded data-type IDs seen

    @property
    def buffered(self) -> int:
        """Bytes held waiting for more data."""
        return len(self._stream)

    def feed(self, data) -> list:
        """Add bytes; return the ensembles (:class:`Pd0Ensemble`) they complete, in order."""
        if self._stream.feed(data) is None:
            return []
        return self._run(final=False)

    def flush(self) -> list:
        """End of stream: return what can still be decoded and discard the rest."""
        out = self._run(final=True)
        self._drop_all("end of stream")
        st = self.stats
        if st.vendor_blocks or st.known_types_skipped:
            logger.info("PD0 stream: skipped quietly %d vendor block(s) 0x7F79 (%d bytes) and "
                        "%d known but undecoded data type(s)%s", st.vendor_blocks,
                        st.vendor_block_bytes, st.known_types_skipped,
                        " (IDs " + ", ".join(f"0x{i:04X}" for i in sorted(self._skipped_ids)) + ")"
                        if self._skipped_ids else "")
        return out

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after a reconnection); counters are kept."""
        self._drop_all("reset")

    # -- internals -------------------------------------------------------------

    def _drop_all(self, reason: str) -> None:
        if self._stream.buf:
            self._discard(0, len(self._stream.buf), reason)
            self._stream.clear()
        self._la_pending = []
        self._la_scanned = self._stream.base
        self._log_discard()

    def _discard(self, pos: int, n: int, reason: str) -> None:
        if n <= 0:
            return
        start = self._stream.base + pos
        if self._discard_start is not None and self._discard_start + self._discard_len != start:
            self._log_discard()
        if self._discard_start is None:
            self._discard_start = start
            self.stats.discard_runs += 1
        self._discard_len += n
        self._discard_reasons.add(reason)
        self.stats.bytes_discarded += n

    def _log_discard(self) -> None:
        if self._discard_start is not None:
            logger.warning(
                "PD0 stream: discarded %d bytes at stream offset %d (%s)",
                self._discard_len, self._discard_start, "; ".join(sorted(self._discard_reasons)),
            )
        self._discard_start = None
        self._discard_len = 0
        self._discard_reasons = set()

    def _judge(self, pos: int, end: int):
        """The candidate at ``pos``: a :class:`Pd0Ensemble`, an int (the buffer end it
        needs) or ``(reason, error)`` if it is not an ensemble."""
        buf, base = self._stream.buf, self._stream.base
        try:
            n_bytes, _ = parse_header(buf, pos, end, base)
        except NeedMore as e:
            return e.need_end
        except Pd0DecodeError as e:
            return ("bad header", e)
        if end - pos < n_bytes + 2:
            return pos + n_bytes + 2
        (stored,) = struct.unpack_from("<H", buf, pos + n_bytes)
        if ensemble_checksum(buf, pos, n_bytes) != stored:
            return ("bad checksum", None)
        try:
            return decode_ensemble(buf, pos, verify_checksum=False, base_offset=base)
        except Pd0DecodeError as e:
            return ("undecodable", e)
        except Exception:  # a decoder bug must not stop acquisition
            logger.exception("PD0 stream: internal decoder error at stream offset %d", base + pos)
            return ("internal error", None)

    def _lookahead(self, pos: int, end: int) -> Optional[tuple]:
        """The first header after ``pos`` that already gives a valid ensemble.

        Headers already judged invalid are not looked at again and incomplete ones
        only once their bytes are in, so the total work stays linear.
        """
        base = self._stream.base
        front = base + pos
        pending = [p for p in self._la_pending if p[0] > front]
        self._la_pending = pending
        for item in pending:
            if base + end < item[1]:
                continue
            r = self._judge(item[0] - base, end)
            if isinstance(r, Pd0Ensemble):
                return item[0] - base, r
            item[1] = base + r if isinstance(r, int) else -1  # -1: invalid, dropped below
        self._la_pending = [p for p in pending if p[1] >= 0]
        k = max(self._la_scanned - base, pos + 1)
        while True:
            j = self._stream.buf.find(HEADER_ID, k, end)
            if j < 0:
                break
            r = self._judge(j, end)
            if isinstance(r, Pd0Ensemble):
                self._la_scanned = base + j + 1
                return j, r
            if isinstance(r, int):
                self._la_pending.append([base + j, base + r])
            k = j + 1
        self._la_scanned = base + max(end - 1, pos + 1)
        return None

    def _count(self, reason: str) -> None:
        if reason == "bad header":
            self.stats.bad_headers += 1
        elif reason == "bad checksum":
            self.stats.bad_checksums += 1
        elif reason == "undecodable":
            self.stats.decode_errors += 1
        else:
            self.stats.internal_errors += 1

    def _accept(self, out: list, ens: Pd0Ensemble) -> None:
        self._log_discard()
        out.append(ens)
        self.stats.ensembles += 1
        for i in ens.data_type_ids:
            if i in KNOWN_UNDECODED_IDS:
                self.stats.known_types_skipped += 1
                self._skipped_ids.add(i)
            elif i not in DECODED_IDS:
                self.stats.unknown_types += 1

    def _take_later(self, out: list, pos: int, end: int, reason: str) -> Optional[int]:
        """The candidate at ``pos`` cannot complete yet: where a later header already
        gives a valid ensemble, the candidate was garbage (discarded for ``reason``) and
        that ensemble is taken; the position after it, or None (wait for more bytes)."""
        found = self._lookahead(pos, end)
        if found is None:
            return None
        j, ens = found
        self._discard(pos, j - pos, reason)
        self._accept(out, ens)
        return j + ens.n_bytes

    def _vendor_block(self, pos: int, end: int, final: bool):
        """The 0x7F79 candidate at ``pos``: its size (bytes to skip), None (needs more
        bytes) or False (not a vendor block)."""
        buf = self._stream.buf
        if end - pos < 4:
            return False if final else None
        (count,) = struct.unpack_from("<H", buf, pos + 2)
        if count < 4:
            return False
        size = count + 2
        if end - pos < size:
            return False if final else None
        if self._lookahead(pos, pos + size) is not None:  # it would swallow an ensemble
            return False
        if struct.unpack_from("<H", buf, pos + count)[0] == ensemble_checksum(buf, pos, count):
            return size
        if end - pos < size + 2:
            return (size if end - pos == size else False) if final else None
        nxt = bytes(buf[pos + size:pos + size + 2])
        return size if nxt in (HEADER_ID, VENDOR_BLOCK_ID) else False

    def _run(self, final: bool) -> list:
        buf = self._stream.buf
        end = len(buf)
        pos = 0
        out: list = []
        nxt_h = nxt_v = -2  # next header / vendor block (-1: none); kept while ahead of pos
        while pos < end:
            if nxt_h != -1 and nxt_h < pos:
                nxt_h = buf.find(HEADER_ID, pos)
            if nxt_v != -1 and nxt_v < pos:
                nxt_v = buf.find(VENDOR_BLOCK_ID, pos)
            i = nxt_h
            v = nxt_v if nxt_v >= 0 and (i < 0 or nxt_v < i) else -1
            if v >= 0:
                if v > pos:
                    self._discard(pos, v - pos, "no header")
                    pos = v
                size = self._vendor_block(pos, end, final)
                if size:
                    self._log_discard()
                    self.stats.vendor_blocks += 1
                    self.stats.vendor_block_bytes += size
                    pos += size
                    continue
                if size is None:  # incomplete: is it garbage holding good data back?
                    after = self._take_later(out, pos, end, "vendor block never completed")
                    if after is None:
                        break
                    pos = after
                    continue
                self._discard(pos, 1, "no header")
                pos += 1
                continue
            if i < 0:
                keep = 1 if (buf[end - 1] == 0x7F and not final) else 0
                self._discard(pos, end - pos - keep, "no header")
                pos = end - keep
                break
            if i > pos:
                self._discard(pos, i - pos, "no header")
                pos = i
            r = self._judge(pos, end)
            if isinstance(r, Pd0Ensemble):
                self._accept(out, r)
                pos += r.n_bytes
                continue
            if isinstance(r, int):  # incomplete: is it garbage holding good data back?
                after = self._take_later(out, pos, end, "ensemble never completed")
                if after is None:
                    if final:
                        self._discard(pos, end - pos, "ensemble never completed")
                        pos = end
                    break
                pos = after
                continue
            reason, err = r
            self._count(reason)
            if err is not None:
                logger.debug("PD0 stream: %s", err)
            self._discard(pos, 1, reason)
            pos += 1
        self._stream.consume(pos)
        return out
