"""Reading HDF5 files that may be damaged or hostile, for every SVSS file kind.

HDF5 hangs on some damaged structures and crashes on others, in C code nothing
in-process can interrupt. The pieces here let a reader (raw runs in
:mod:`svss_daq.rawfile`, tiles in :mod:`svss_proc.tiles`) refuse such a file with its
own error instead: the superblock checked before HDF5 sees the file
(:func:`hdf5_superblock`), the structure read in a forked child with a time limit
(:func:`in_child`), SWMR opens with bounded metadata retries (:func:`open_swmr`),
typed checks of datasets, groups and the format version that name the file and the
path, attribute text and exception causes made printable (:func:`text`,
:func:`cause`, :func:`shown`), and closing a file after a failed write
(:func:`abandon`). Each function that refuses a file raises the ``error`` class its
caller passes (:class:`UnreadableFileError` by default).
"""

from __future__ import annotations

import ctypes
import faulthandler
import functools
import logging
import os
import pickle
import re
import select
import signal
import time
from pathlib import Path

import h5py
import numpy as np

log = logging.getLogger(__name__)


class UnreadableFileError(ValueError):
    """A file refused by these functions when the caller names no error class of its
    own (raw runs pass :class:`~svss_daq.rawfile.RawFileError`, tiles theirs)."""

#: metadata read attempts of a SWMR reader; HDF5 sleeps 2**k ns before attempt k, and
#: its default of 100 makes a damaged file hang "forever"; 20 bounds it to ~1 ms
SWMR_READ_ATTEMPTS = 20
#: exceptions h5py raises on corrupt or unwritable files
H5_ERRORS = (OSError, KeyError, ValueError, RuntimeError, TypeError, IndexError,
             AttributeError, OverflowError)


_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def hdf5_superblock(path: str | Path,
                    error: type[Exception] = UnreadableFileError) -> dict:
    """The HDF5 superblock of ``path``: ``offset``, ``version``, ``flags`` (file
    consistency flags: bit 0 open for writing, bit 2 SWMR writing), ``eof`` (the
    absolute end-of-file address it records, None when undefined) and the file's
    ``size``. Raises ``error`` naming the file when it has no superblock, or when it was
    closed cleanly and is shorter than the address it records (a truncated file). A file
    still flagged open for writing may be shorter: a writer that died in a failed write
    leaves that; its reader checks that what it reads lies in the file."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            offset = 0
            while True:       # the superblock is at 0, 512, 1024, 2048, ...
                fh.seek(offset)
                head = fh.read(64)
                if head[:8] == _SIGNATURE:
                    break
                offset = 512 if offset == 0 else 2 * offset
                if offset + 8 > size:
                    raise error(f"{path}: not a readable HDF5 file (no HDF5 superblock "
                                f"signature in its {size} bytes)")
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(head) < 48:
        raise error(f"{path}: truncated: {size} bytes, too short for the HDF5 superblock "
                    f"at byte {offset}")
    version = head[8]
    if version in (0, 1):           # addresses after fixed fields, flags 4 bytes
        n_off = head[13]
        flags = int.from_bytes(head[20:24], "little")
        start = 24 if version == 0 else 28
    elif version in (2, 3):
        n_off = head[9]
        flags = head[11]
        start = 12
    else:
        raise error(f"{path}: HDF5 superblock at byte {offset} has version {version}; "
                    "expected 0 to 3")
    if n_off not in (2, 4, 8, 16) or len(head) < start + 3 * n_off:
        raise error(f"{path}: HDF5 superblock at byte {offset} is damaged "
                    f"(size of offsets {n_off})")
    addr = [int.from_bytes(head[start + k * n_off: start + (k + 1) * n_off], "little")
            for k in range(3)]
    undefined = (1 << (8 * n_off)) - 1
    base, eof = addr[0], addr[2]    # v0/v1: base, free space, eof; v2/v3: base, ext, eof
    eof = None if eof == undefined else base + eof
    if eof is not None and size < eof and not flags & 1:
        raise error(f"{path}: truncated: {size} bytes on disk, its HDF5 superblock records "
                    f"{eof} bytes")
    return {"offset": offset, "version": version, "flags": flags, "eof": eof, "size": size}


@functools.lru_cache(maxsize=1)
def _set_read_attempts():
    """``H5Pset_metadata_read_attempts`` of the HDF5 library h5py runs on (h5py does not
    expose it), or None where it cannot be found."""
    try:
        h5py.h5p.create(h5py.h5p.FILE_ACCESS)       # make sure the library is loaded
        with open("/proc/self/maps") as fh:
            libs = sorted(set(re.findall(r"\S*/libhdf5[-.][^/\s]*\.so[^/\s]*", fh.read())))
        for lib in libs:
            fn = getattr(ctypes.CDLL(lib), "H5Pset_metadata_read_attempts", None)
            if fn is not None:
                fn.argtypes, fn.restype = [ctypes.c_int64, ctypes.c_uint], ctypes.c_int
                return fn
    except (OSError, ValueError):
        pass
    log.debug("H5Pset_metadata_read_attempts not found: SWMR reads retry HDF5's default")
    return None


def open_swmr(path: Path) -> h5py.File:
    """Open ``path`` as a SWMR reader with bounded metadata read attempts."""
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
    fapl.set_fclose_degree(h5py.h5f.CLOSE_STRONG)
    setter = _set_read_attempts()
    if setter is not None and setter(fapl.id, SWMR_READ_ATTEMPTS) < 0:
        log.debug("H5Pset_metadata_read_attempts failed")
    fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ,
                        fapl=fapl)
    return h5py.File(fid)


def abandon(f: h5py.File) -> None:
    """Close an HDF5 file after a failed write without writing anything more to it.

    HDF5 retries the failed writes when the file (or a dataset) is closed, fails again,
    and a later close of the half-closed dataset (at garbage collection or interpreter
    exit) crashes the process (HDF5 2.0, H5D_close). Pointing the file's descriptor at
    ``/dev/null`` first lets the close complete; the file on disk keeps what reached
    it before the failure."""
    name = "?"
    try:
        if not f.id.valid:
            return
        name = f.filename
        fd = f.id.get_vfd_handle()
        null = os.open(os.devnull, os.O_RDWR)
        try:
            os.dup2(null, fd)
        finally:
            os.close(null)
        f.close()
    except H5_ERRORS as exc:
        log.error("closing %s after a failed write: %s", name, cause(exc))


#: seconds HDF5 may take reading a file's structure before the file is refused
PROBE_TIMEOUT_S = 10.0
_in_probe = False


def in_child(path: Path, read, error: type[Exception] = UnreadableFileError,
             timeout_s: float | None = None):
    """``read()`` (reading a file through HDF5) run in a forked child process: its
    result (pickled back), or the exception it raised; ``error`` naming the file if it
    does not finish within ``timeout_s`` (default :data:`PROBE_TIMEOUT_S`) or crashes
    the process. HDF5 loops forever on some damaged structures (a global heap
    collection with an empty free-space object, for one) and crashes on others, in C
    code that nothing in-process can interrupt: the child takes the risk, and the
    caller does not read those structures itself. Runs ``read()`` in-process where
    ``os.fork`` is missing (or inside a child already)."""
    global _in_probe
    if _in_probe or not hasattr(os, "fork"):
        return read()
    timeout_s = PROBE_TIMEOUT_S if timeout_s is None else timeout_s
    rfd, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:                                    # child: read, send, leave at once
        try:
            os.close(rfd)
            _in_probe = True
            logging.disable(logging.CRITICAL)
            faulthandler.disable()              # a crash here is reported by the parent
            try:
                out = (True, read())
            except BaseException as exc:            # noqa: BLE001 - the parent raises it
                out = (False, exc)
            try:
                data = pickle.dumps(out)
            except Exception as exc:                # noqa: BLE001
                data = pickle.dumps((False, error(f"{path}: what was read cannot be passed "
                                                  f"on ({cause(exc)})")))
            view = memoryview(data)
            while view:
                view = view[os.write(wfd, view):]
        finally:
            os._exit(0)
    os.close(wfd)
    chunks, deadline = [], time.monotonic() + timeout_s
    try:
        while True:
            left = deadline - time.monotonic()
            ready = select.select([rfd], [], [], max(left, 0))[0] if left > 0 else []
            if not ready:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                raise error(f"{path}: HDF5 did not finish reading it within {timeout_s:g} s "
                            "(a damaged file)")
            chunk = os.read(rfd, 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(rfd)
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status) or not chunks:
        raise error(f"{path}: HDF5 crashed reading it (a damaged file; exit status "
                    f"{status})")
    ok, value = pickle.loads(b"".join(chunks))
    if not ok:
        raise value
    return value




def cause(exc: Exception) -> str:
    """An exception's message on one line (its type's name when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def shown(v) -> str:
    """``repr`` of a value read from a file, without numpy's wrappers."""
    if isinstance(v, np.ndarray):
        v = v.tolist()
    elif isinstance(v, np.generic):
        v = v.item()
    return repr(v)


def text(v) -> str | None:
    """An attribute read from a file as text (bytes decoded, a 0-d array unwrapped);
    None when it is not text."""
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray) and v.shape == ():
        return text(v[()])
    return v if isinstance(v, str) else None


def run_id_attr(attrs) -> str | None:
    """The run a file's root attributes ``attrs`` name (``run_id``, written by the
    acquisition daemon into raw runs and by the worker into tiles) as text; None when
    they name none (absent, empty, or not text)."""
    return text(attrs.get("run_id")) or None


def format_version(value, path: Path, readable: tuple[int, ...],
                   error: type[Exception] = UnreadableFileError) -> int:
    """The ``svss_format_version`` root attribute ``value`` checked: an integer scalar
    in ``readable``; otherwise ``error`` naming the file."""
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.reshape(())[()]
    if value is None:
        raise error(f"{path}: root attribute 'svss_format_version' missing; expected one "
                    f"of {list(readable)}")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise error(f"{path}: root attribute 'svss_format_version' is {shown(value)}; expected "
                    f"an integer, one of {list(readable)}")
    if int(value) not in readable:
        raise error(f"{path}: svss_format_version {int(value)}; this software reads "
                    f"version(s) {list(readable)}")
    return int(value)


def dataset(f: h5py.Group, name: str, path: Path, ndim: int, kinds: str,
            error: type[Exception] = UnreadableFileError, what: str = "") -> h5py.Dataset:
    """``f[name]`` checked to be a dataset of ``ndim`` dimensions whose dtype kind is in
    ``kinds`` (numpy kind letters: ``i`` integer, ``f`` float, ``S`` bytes, ...);
    otherwise ``error`` naming the file and the path."""
    full = f"{f.name.rstrip('/')}/{name}"
    obj = f.get(name)
    if obj is None:
        raise error(f"{path}: dataset '{full}' missing; expected {what or 'it'}")
    if not isinstance(obj, h5py.Dataset):
        raise error(f"{path}: '{full}' is a {type(obj).__name__}; expected a dataset")
    if obj.ndim != ndim:
        raise error(f"{path}: dataset '{full}' has shape {obj.shape}; expected {ndim} "
                    "dimension(s)")
    if obj.dtype.kind not in kinds:
        raise error(f"{path}: dataset '{full}' has dtype {obj.dtype}; expected kind "
                    f"{' or '.join(repr(k) for k in kinds)}")
    return obj


def group(f: h5py.Group, name: str, path: Path,
          error: type[Exception] = UnreadableFileError) -> h5py.Group:
    """``f[name]`` checked to be a group; otherwise ``error`` naming the file and path."""
    full = f"{f.name.rstrip('/')}/{name}"
    obj = f.get(name)
    if obj is None:
        raise error(f"{path}: group '{full}' missing")
    if not isinstance(obj, h5py.Group):
        raise error(f"{path}: '{full}' is a {type(obj).__name__}; expected a group")
    return obj
