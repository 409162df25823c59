"""A tile worker's output folder: its run folders (named from the run id), the worker
journal a stopped run resumes from, the manifest, and the files an interrupted writer
left; everything of the worker that is files, not ZeroMQ."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
from pathlib import Path

from .tiles import TILE_FILE_PREFIXES, is_temporary

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"
JOURNAL = "worker_state.json"
JOURNAL_SCHEMA = "svss.worker_state"
JOURNAL_VERSION = 1


def atomic_json(path: Path, obj: dict) -> None:
    tmp = path.with_name(path.name + ".partial")
    with open(tmp, "w") as f:
        f.write(json.dumps(obj, indent=2))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _stale(p: Path) -> bool:
    return p.is_file() and (is_temporary(p) or p.name.endswith(".partial"))


def remove_temporaries(folder: Path) -> int:
    """Remove the temporary files a killed writer left in ``folder``; how many."""
    n = 0
    for p in folder.iterdir():
        if _stale(p):
            p.unlink(missing_ok=True)
            n += 1
    if n:
        log.warning("%s: removed %d temporary file(s) left by an interrupted writer", folder, n)
    return n


def _stream_manifest(path: Path) -> bool:
    """Whether ``path`` is the manifest of a stream worker's output folder."""
    try:
        m = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(m, dict) and isinstance(m.get("runs"), dict)


def _worker_folder(d: Path) -> bool:
    return d.is_dir() and ((d / MANIFEST).is_file() or (d / JOURNAL).is_file())


def prepare_output_dir(out: Path, force: bool = False, *, resume: bool = False) -> None:
    """Make ``out`` and remove stale temporary files in it (and in its run folders).
    Refuse a folder that holds tiles, a manifest or run folders of an earlier run unless
    ``force``, which removes them (outputs of two runs are never mixed), or ``resume``
    and it holds this worker's journal (``worker_state.json``, in it or in a run
    folder): then it is resumed."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    remove_temporaries(out)
    runs = sorted(d for d in out.iterdir() if _worker_folder(d))
    for d in runs:
        remove_temporaries(d)
    old = sorted(p for p in out.iterdir()
                 if p.is_file() and (p.name in (MANIFEST, JOURNAL)
                                     or p.name.startswith(TILE_FILE_PREFIXES)))
    if not old and not runs:
        return
    if resume and not force and ((out / JOURNAL).is_file()
                                 or any((d / JOURNAL).is_file() for d in runs)
                                 or _stream_manifest(out / MANIFEST)):
        log.info("%s: resuming (worker journal found)", out)
        return
    if not force:
        first = (old or runs)[0]
        raise FileExistsError(f"{out}: holds {len(old) + len(runs)} file(s) or run "
                              f"folder(s) of an earlier run (e.g. {first.name}); choose an "
                              "empty folder or pass --force to replace them")
    for p in old:
        p.unlink()
    for d in runs:
        shutil.rmtree(d)
    log.warning("%s: removed %d file(s) and %d run folder(s) of an earlier run (--force)",
                out, len(old), len(runs))


def read_journal(folder: Path) -> dict | None:
    """The worker journal of a run folder (None when there is none); ValueError naming
    the file when it is not one."""
    path = Path(folder) / JOURNAL
    if not path.is_file():
        return None
    try:
        j = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a worker journal ({exc})") from None
    if not isinstance(j, dict) or j.get("schema") != JOURNAL_SCHEMA \
            or j.get("version") != JOURNAL_VERSION:
        raise ValueError(f"{path}: not a worker journal (schema {JOURNAL_SCHEMA!r} version "
                         f"{JOURNAL_VERSION} expected)")
    return j


_SAFE_RUN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")


def run_folder_name(run_id: str) -> str:
    """A folder name for a run id from the wire: the id itself when it is a plain name
    (letters, digits, ``._-``, not starting with a dot, at most 100 characters),
    otherwise a cleaned form with a hash of the id."""
    if _SAFE_RUN.fullmatch(run_id):
        return run_id
    clean = re.sub(r"[^A-Za-z0-9._-]", "_", run_id)[:60].lstrip("._-") or "run"
    return f"{clean}-{hashlib.sha256(run_id.encode()).hexdigest()[:8]}"
