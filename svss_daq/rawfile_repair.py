"""The repair of a raw-run file whose writer died (a daemon killed mid-run): its
HDF5 open-for-writing flags cleared as ``h5clear -s --increment`` does, with HDF5's
superblock checksum (:func:`lookup3`) recomputed, and a summary saying it was
interrupted stored in it, or beside it where it cannot be closed so
(:func:`close_interrupted`). Every flushed ping stays as it was.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from .rawfile_layout import RawFileError
from .rawfile_writer import write_summary, write_summary_beside
from .untrusted_hdf5 import hdf5_superblock

log = logging.getLogger("svss_daq.rawfile")     # one logger for the raw file's modules


def _rot32(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 ``hashlittle`` of ``data``: the checksum HDF5 stores at the
    end of a version 2 or 3 superblock (``H5_checksum_lookup3``)."""
    m = 0xFFFFFFFF
    n = len(data)
    abc = [(0xDEADBEEF + n + initval) & m] * 3
    padded = data + bytes(-n % 12)
    words = [int.from_bytes(padded[i:i + 4], "little") for i in range(0, len(padded), 4)]

    def step(x, y, z, k):            # x -= z; x ^= rot(z, k); z += y
        abc[x] = ((abc[x] - abc[z]) & m) ^ _rot32(abc[z], k)
        abc[z] = (abc[z] + abc[y]) & m

    def final(x, y, k):              # x ^= y; x -= rot(y, k)
        abc[x] = ((abc[x] ^ abc[y]) - _rot32(abc[y], k)) & m

    k = 0
    while n - 4 * k > 12:
        abc = [(v + w) & m for v, w in zip(abc, words[k:k + 3])]
        for x, y, z, r in ((0, 1, 2, 4), (1, 2, 0, 6), (2, 0, 1, 8), (0, 1, 2, 16),
                           (1, 2, 0, 19), (2, 0, 1, 4)):
            step(x, y, z, r)
        k += 3
    if n - 4 * k == 0:
        return abc[2]
    abc = [(v + w) & m for v, w in zip(abc, words[k:k + 3])]
    for x, y, r in ((2, 1, 14), (0, 2, 11), (1, 0, 25), (2, 1, 16), (0, 2, 4), (1, 0, 14),
                    (2, 1, 24)):
        final(x, y, r)
    return abc[2]


def _clear_open_flags(path: Path) -> None:
    """What ``h5clear -s --increment`` does to a file whose writer died: the superblock's
    file consistency flags cleared (open for writing, SWMR writing) and its end-of-file
    address raised to the file's size (so that nothing HDF5 allocates next lands on
    bytes the dead writer left), the superblock's checksum recomputed. Version 2 and 3
    superblocks only (what :class:`RawRunWriter` writes); :class:`RawFileError`
    otherwise."""
    sb = hdf5_superblock(path, RawFileError)
    if sb["version"] not in (2, 3):
        raise RawFileError(f"{path}: HDF5 superblock version {sb['version']}; only "
                           "versions 2 and 3 can be closed here")
    off = sb["offset"]
    with open(path, "r+b") as fh:
        fh.seek(off)
        head = bytearray(fh.read(48))
        n_off = head[9]
        end = 12 + 4 * n_off               # signature .. root object header address
        if n_off != 8 or len(head) < end + 4:
            raise RawFileError(f"{path}: HDF5 superblock with {n_off}-byte addresses; "
                               "only 8-byte addresses can be closed here")
        stored = int.from_bytes(head[end:end + 4], "little")
        if lookup3(bytes(head[:end])) != stored:
            raise RawFileError(f"{path}: HDF5 superblock checksum does not match; the "
                               "file is left as it is")
        eoa_at = 12 + 2 * n_off
        base = int.from_bytes(head[12:12 + n_off], "little")
        eoa = int.from_bytes(head[eoa_at:eoa_at + n_off], "little")
        head[11] = 0
        head[eoa_at:eoa_at + n_off] = max(eoa, sb["size"] - base).to_bytes(n_off, "little")
        head[end:end + 4] = lookup3(bytes(head[:end])).to_bytes(4, "little")
        fh.seek(off)
        fh.write(head[:end + 4])
        fh.flush()
        os.fsync(fh.fileno())


def close_interrupted(path: str | Path, summary: dict) -> str:
    """Close the segment ``path`` of a writer that died (a daemon killed mid-run) and
    mark it: its open-for-writing flags cleared (:func:`_clear_open_flags`; every
    flushed ping stays as it was) and ``summary`` (saying it was interrupted) stored as
    its ``acquisition_summary``. A file that cannot be closed so is left untouched and
    gets the summary beside it (:func:`write_summary_beside`). Returns ``"closed"`` or
    ``"beside"``; :class:`RawFileError` when neither could be written."""
    path = Path(path)
    try:
        if hdf5_superblock(path, RawFileError)["flags"] & 1:
            _clear_open_flags(path)
        write_summary(path, summary)
        return "closed"
    except (RawFileError, OSError) as exc:
        log.warning("%s: not closed (%s); its summary goes beside it", path, exc)
    write_summary_beside(path, summary)
    return "beside"
