"""Teledyne RDI PD0 binary ensembles: pure decoding and an incremental stream parser.

Layout of one ensemble (all integers little-endian), after the Teledyne RDI
"Workhorse Commands and Output Data Format" manual:

* header: ``0x7F 0x7F``, uint16 byte count (header to last data byte, checksum
  excluded), a spare byte, the number of data types ``n`` and ``n`` uint16 offsets
  (from the first header byte) to each data type;
* data types, each starting with a uint16 ID: fixed leader ``0x0000``, variable
  leader ``0x0080``, velocity ``0x0100``, correlation ``0x0200``, echo intensity
  ``0x0300``, percent good ``0x0400``, bottom track ``0x0600``, and for five-beam
  instruments (Sentinel V class) the vertical beam's velocity profile ``0x0A00`` and
  range ``0x4100``; other IDs are listed in ``data_type_ids`` and skipped (those in
  :data:`KNOWN_UNDECODED_IDS` are counted by the stream parser, without a warning);
* a uint16 checksum: the sum of every byte of the ensemble modulo 65536.

Decoded values are in SI units: m, m/s, s, Pa, radians (angles); temperature in
degrees Celsius. Times are int64 nanoseconds since the Unix epoch (UTC). Bad-value
markers (velocity -32768) and "no bottom found" (bottom-track range 0) become NaN, the
missing pressure 0xFFFFFFFF None (a pressure field from 0x80000000 up is a small
negative reading wrapped: ``signed_pressure_dapa``). Bottom-track ranges are RDI's vertical ranges (beam
range x cos(beam angle), not corrected for pitch and roll), as sent.
Array fields are read-only numpy arrays. Raw counts (correlation, echo intensity,
percent good) stay as uint8 arrays.

:func:`decode_ensemble` decodes one ensemble from bytes and raises
Between ensembles a Sentinel V may send vendor blocks that start ``0x7F 0x79`` with a
uint16 byte count (block = count + 2 bytes, as dolfyn reads them): the stream parser
skips them quietly and counts them (:class:`Pd0StreamStats`), logging one summary line
on :meth:`Pd0StreamParser.flush`.

System frequency: the fixed leader's configuration bits 0-2 give the Workhorse
frequency class (75 kHz ... 2.4 MHz, ``frequency_class_hz``). A Sentinel V (CPU
firmware 47.x or 66.x) sends the 300 kHz class code for its 307.2 kHz transducer, so
``system_frequency_hz`` reports 307.2 kHz there; the five-beam layout is flagged by bit
12 of the configuration word (dolfyn's ``beam5``) or a beam count of 5.

:func:`decode_ensemble` decodes one ensemble from bytes and raises
:class:`Pd0DecodeError` on anything malformed. :class:`Pd0StreamParser` is fed bytes
as they arrive, resynchronises on garbage, never raises and holds bounded memory.

This module is the protocol's public face: the records and their decoding are in
:mod:`svss_daq.protocols.pd0_ensemble`, the stream parser in
:mod:`svss_daq.protocols.pd0_stream`.
"""

from __future__ import annotations

from .pd0_ensemble import (BAD_VELOCITY, HEADER_ID, ID_BEAM5_RANGE, ID_BEAM5_VELOCITY,
                          ID_BOTTOM_TRACK, ID_CORRELATION, ID_ECHO_INTENSITY,
                          ID_FIXED_LEADER, ID_PERCENT_GOOD, ID_VARIABLE_LEADER,
                          ID_VELOCITY, KNOWN_UNDECODED_IDS, MAX_ENSEMBLE_BYTES,
                          MISSING_U32, SENTINEL_V_FIRMWARE, VENDOR_BLOCK_ID,
                          BottomTrack, FixedLeader, Pd0DecodeError, Pd0Ensemble,
                          VariableLeader, VerticalBeam, decode_ensemble,
                          ensemble_checksum, signed_pressure_dapa)
from .pd0_stream import Pd0StreamParser, Pd0StreamStats

__all__ = [
    "HEADER_ID",
    "BAD_VELOCITY",
    "MISSING_U32",
    "MAX_ENSEMBLE_BYTES",
    "Pd0DecodeError",
    "FixedLeader",
    "VariableLeader",
    "BottomTrack",
    "VerticalBeam",
    "Pd0Ensemble",
    "KNOWN_UNDECODED_IDS",
    "VENDOR_BLOCK_ID",
    "Pd0StreamStats",
    "Pd0StreamParser",
    "decode_ensemble",
    "ensemble_checksum",
]
