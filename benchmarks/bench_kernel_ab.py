"""Imaging A/B: two revisions' whole imaging path (TileImager: conditioning, delays, tap
planes, kernel), side by side in one process.

    python benchmarks/bench_kernel_ab.py --base REV [--this REV] [--reps 8] [--out ab.json]

Runs from any directory. Each git revision's ``svss_daq`` and ``svss_proc`` are taken out
with ``git archive`` and imported under renamed packages (``svss_daq_base``,
``svss_proc_base``; ``--this REV``: ``svss_daq_this``, ``svss_proc_this``): absolute
imports of the two packages are rewritten, relative ones kept. Module layout and kernel
signatures may therefore differ freely between the sides; only the imager's public face
is used: ``TileImager(hardware, processing)`` (from ``imaging.imager`` or ``imager``,
whichever the revision has), ``add(ping)``, ``updates`` and ``active[k].re/im/pings``.
Without ``--this`` the second side is the working tree as imported here.

Both sides read this checkout's ``config/hardware.toml`` and ``config/processing.toml``,
each with its own revision's loader and config classes. Where a revision's loader
rejects this checkout's file (a key renamed since), that side reads its own revision's
file instead; the log and the JSON say so and list what differs between the two files
(renamed keys with equal values, or changed values). Every setting of SETTINGS is put
into ``processing.imaging`` with ``dataclasses.replace``.

The pings are simulated once by this checkout's ``EnvironmentSource`` (the demo scene of
``bench_imaging.py``) and handed to both sides as they are (the base imager only reads
their attributes). The timed ping is found once, on this side's imager: the first ping
after the warm-up ping that, like the pings before and after it, reaches exactly one
tile, so that its projector cone lies inside that tile with at least one ping's advance
to spare on either end (the DESIGN.md reference workload). Per setting both imagers get
the warm-up ping (it fixes the tile frame), then the timed ping is added to each,
interleaved (the order alternates), ``--reps`` + 1 times; rep 0 compiles and builds
tables, the best of the others is kept, so that the ratio holds while the host's speed
drifts. Printed per setting: updates/s of each side (from the imagers' ``updates``
counters), the ratio base time / this time, the update counts of the timed ping (must
be equal) and the largest difference between the two sides' tiles, each tile divided
by the number of pings added to it, relative to the base's peak.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import io
import json
import logging
import pathlib
import re
import subprocess
import sys
import tarfile
import tempfile
import time
import tomllib

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
for _p in (str(ROOT), str(HERE)):              # the project and bench_imaging, from anywhere
    if _p not in sys.path:
        sys.path.insert(0, _p)

from bench_imaging import scene_for

from sim_device.environment_source import EnvironmentSource
from svss_daq import config as this_config

log = logging.getLogger("bench_kernel_ab")

PACKAGES = ("svss_daq", "svss_proc")
IMAGER_MODULES = ("imaging.imager", "imager")  # where TileImager has lived
CONFIG_DIR = ROOT / "config"
SETTINGS = [("straight", "linear", "float32"), ("straight", "nearest", "float32"),
            ("straight", "cubic", "float32"), ("table", "linear", "float32"),
            ("straight", "linear", "float64")]
FIRST_PING, LAST_PING = 150, 200               # warm-up ping; the timed ping lies between


def git(*args: str) -> bytes:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True,
                          capture_output=True).stdout


# --- a revision's packages under renamed names ---------------------------------------

_PKGS = "|".join(PACKAGES)
_IMPORT = re.compile(r"^(?P<head>[ \t]*(?:from|import)[ \t]+)(?P<pkg>" + _PKGS
                     + r")(?=[.\s]|$)", re.MULTILINE)
_DYNAMIC = re.compile(r"(?P<head>import_module\(\s*[\"'])(?P<pkg>" + _PKGS + r")(?=[.\"'])")


def renamed_source(src: str, suffix: str, where: str) -> str:
    """``src`` with every absolute import of svss_daq / svss_proc (statements and
    ``import_module("...")``) going to ``<package>_<suffix>``; relative imports stay.
    Raises if the parsed result still imports one of the original packages."""
    out = _IMPORT.sub(lambda m: f"{m['head']}{m['pkg']}_{suffix}", src)
    out = _DYNAMIC.sub(lambda m: f"{m['head']}{m['pkg']}_{suffix}", out)
    for node in ast.walk(ast.parse(out, where)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [node.module or ""]
        else:
            continue
        left = [n for n in names if n.split(".")[0] in PACKAGES]
        if left:
            raise RuntimeError(f"{where}:{node.lineno}: import of {left[0]} not renamed")
    return out


def extract_renamed(sha: str, suffix: str, top: pathlib.Path) -> None:
    """``sha``'s svss_daq and svss_proc written under ``top`` as
    svss_daq_<suffix> and svss_proc_<suffix>."""
    raw = top / "_archive"
    raw.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(git("archive", sha, *PACKAGES))) as tar:
        if hasattr(tarfile, "data_filter"):
            tar.extractall(raw, filter="data")
        else:
            tar.extractall(raw)
    for pkg in PACKAGES:
        for f in sorted((raw / pkg).rglob("*.py")):
            rel = f.relative_to(raw / pkg)
            dest = top / f"{pkg}_{suffix}" / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(renamed_source(f.read_text(), suffix, f"{sha[:10]}:{pkg}/{rel}"))


def imager_class(pkg: str) -> type:
    """``pkg``'s TileImager, from the first of IMAGER_MODULES that exists."""
    for mod in IMAGER_MODULES:
        name = f"{pkg}.{mod}"
        try:
            return importlib.import_module(name).TileImager
        except ModuleNotFoundError as exc:
            # only the module itself (or its parent package) missing means "not here";
            # anything else is a real import error inside it
            if not exc.name or not (name + ".").startswith(exc.name + "."):
                raise
    raise RuntimeError(f"no TileImager in {pkg} (looked in {', '.join(IMAGER_MODULES)})")


# --- configuration -------------------------------------------------------------------

def flat(d: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flat(v, key + "."))
        else:
            out[key] = v
    return out


def config_changes(ours: str, theirs: str) -> list[str]:
    """What differs from this checkout's config text ``ours`` to a revision's
    ``theirs``: keys renamed within a section with the value kept, changed values,
    keys only on one side."""
    a, b = flat(tomllib.loads(ours)), flat(tomllib.loads(theirs))
    changes = [f"{k}: {a[k]!r} -> {b[k]!r}" for k in sorted(a.keys() & b.keys())
               if a[k] != b[k]]
    only_a, only_b = sorted(a.keys() - b.keys()), sorted(b.keys() - a.keys())
    for kb in list(only_b):
        section = kb.rpartition(".")[0]
        match = [ka for ka in only_a
                 if ka.rpartition(".")[0] == section and a[ka] == b[kb]]
        if len(match) == 1:
            changes.append(f"renamed {match[0]} -> {kb} (value {b[kb]!r} kept)")
            only_a.remove(match[0])
            only_b.remove(kb)
    changes += [f"only here: {k} = {a[k]!r}" for k in only_a]
    changes += [f"only in the revision: {k} = {b[k]!r}" for k in only_b]
    return changes


def read_configs(config, label: str, sha: str | None, dest: pathlib.Path):
    """(Loaded hardware config, processing config, provenance) read with one side's
    ``config`` module: this checkout's files, or where that side's loader rejects one
    (and the side is a git revision ``sha``) that revision's own file."""
    dest.mkdir(parents=True, exist_ok=True)
    values, provenance = {}, {}
    for name, cls, load in (("hardware.toml", config.HardwareConfig, config.load_with_text),
                            ("processing.toml", config.ProcessingConfig, config.load)):
        ours = (CONFIG_DIR / name).read_text()
        (dest / name).write_text(ours)
        try:
            values[name] = load(cls, dest / name)
            provenance[name] = {"file": "this checkout's"}
            continue
        except Exception as exc:               # any refusal by that side's loader
            if sha is None:
                raise
            reason = f"{type(exc).__name__}: {exc}"
        theirs = git("show", f"{sha}:config/{name}").decode()
        (dest / name).write_text(theirs)
        values[name] = load(cls, dest / name)
        changes = config_changes(ours, theirs)
        renames_only = all(c.startswith("renamed ") for c in changes)
        (log.info if renames_only else log.warning)(
            "%s: this checkout's %s refused (%s); read %s's own, which differs by: %s",
            label, name, reason, sha[:10], "; ".join(changes) or "nothing")
        provenance[name] = {"file": f"{sha[:10]}'s own", "refused": reason,
                            "changes": changes, "same_values": renames_only}
    return values["hardware.toml"], values["processing.toml"], provenance


# --- the two sides -------------------------------------------------------------------

@dataclasses.dataclass
class Side:
    """One revision's imaging path: its TileImager and its configuration."""
    label: str
    rev: str                                   # "REV (sha)" or "working tree"
    imager_cls: type
    hardware: object                           # that side's Loaded[HardwareConfig]
    processing: object                         # that side's ProcessingConfig
    config: dict                               # where each config file came from
    daq: str = "svss_daq"                      # that side's svss_daq package name

    def imager(self, delays: str, interpolation: str, precision: str):
        p = self.processing
        im = dataclasses.replace(p.imaging, delays=delays, interpolation=interpolation,
                                 precision=precision)
        return self.imager_cls(self.hardware, dataclasses.replace(p, imaging=im))

    def adapt(self, ping):
        """The ping as this side accepts it: rebuilt from this side's own ``Ping`` and
        ``NavSnapshot`` classes (its ping gate checks the types, and the renamed
        packages' classes differ from this checkout's), and, if it names a hardware
        config other than this side's (only when the side had to read its own
        revision's hardware file), without the id."""
        mod = importlib.import_module(f"{self.daq}.ping")
        ping = _as_class(ping, mod)
        if ping.config_id and ping.config_id != self.hardware.id:
            return dataclasses.replace(ping, config_id="")
        return ping


def _as_class(obj, mod):
    """``obj`` (a dataclass) rebuilt as ``mod``'s class of the same name, field by field
    (nested dataclasses too); returned as it is where ``mod`` has no such class."""
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        return obj
    cls = getattr(mod, type(obj).__name__, None)
    if cls is None or cls is type(obj):
        return obj
    return cls(**{f.name: _as_class(getattr(obj, f.name), mod)
                  for f in dataclasses.fields(cls) if f.init and hasattr(obj, f.name)})


def side_at(rev: str, label: str, workdir: pathlib.Path) -> Side:
    """Revision ``rev`` imported as svss_daq_<label> and svss_proc_<label>."""
    sha = git("rev-parse", "--verify", f"{rev}^{{commit}}").decode().strip()
    top = workdir / label
    extract_renamed(sha, label, top)
    sys.path.insert(0, str(top))
    importlib.invalidate_caches()
    daq, proc = f"svss_daq_{label}", f"svss_proc_{label}"
    for pkg in (daq, proc):
        where = pathlib.Path(importlib.import_module(pkg).__file__).resolve()
        if not where.is_relative_to(top.resolve()):
            raise RuntimeError(f"{pkg} imported from {where}, not from {top}")
    config = importlib.import_module(f"{daq}.config")
    hw, pc, prov = read_configs(config, label, sha, top / "config")
    log.info("%s: %s (%s), packages under %s", label, rev, sha[:10], top)
    return Side(label, f"{rev} ({sha[:10]})", imager_class(proc), hw, pc, prov, daq)


def side_here(label: str, workdir: pathlib.Path) -> Side:
    """The working tree as imported here."""
    for pkg in PACKAGES:
        where = pathlib.Path(importlib.import_module(pkg).__file__).resolve()
        if not where.is_relative_to(ROOT):
            raise RuntimeError(f"{pkg} imported from {where}, not from {ROOT}")
    hw, pc, prov = read_configs(this_config, label, None, workdir / label / "config")
    log.info("%s: working tree %s", label, ROOT)
    return Side(label, "working tree", imager_class("svss_proc"), hw, pc, prov)


# --- pings and measurement -----------------------------------------------------------

class Pings:
    """This checkout's simulated pings of the demo scene, each simulated once."""

    def __init__(self):
        c = this_config
        hardware = c.load_with_text(c.HardwareConfig, CONFIG_DIR / "hardware.toml")
        self.source = EnvironmentSource(hardware, scene_for(340))
        self._cache: dict[int, object] = {}

    def __getitem__(self, i: int):
        if i not in self._cache:
            t = time.perf_counter()
            self._cache[i] = self.source.ping(i)
            log.debug("simulated ping %d (%.2f s)", i, time.perf_counter() - t)
        return self._cache[i]


def touched_tiles(imager, ping) -> tuple[int, ...]:
    return tuple(sorted(k for k, t in imager.active.items() if ping.sequence in t.pings))


def mid_tile_ping(side: Side, pings: Pings, setting) -> int:
    """The first ping after FIRST_PING that reaches exactly one tile, as do the pings
    just before and after it (so its reach is inside the tile by a ping's advance)."""
    imager = side.imager(*setting)
    seen: list[tuple[int, tuple[int, ...], int]] = []       # (ping, tiles, updates)
    for i in range(FIRST_PING, LAST_PING + 1):
        ping = side.adapt(pings[i])
        before = imager.updates
        imager.add(ping)
        seen.append((i, touched_tiles(imager, ping), imager.updates - before))
        log.info("ping %d: tiles %s, %d updates", *seen[-1])
        if len(seen) >= 3:
            (_, prev, _), (mid, tiles, n), (_, nxt, _) = seen[-3:]
            if len(tiles) == 1 and prev == tiles == nxt and n > 0:
                return mid
    raise RuntimeError(f"no ping in {FIRST_PING + 1}..{LAST_PING - 1} reaches one tile "
                       f"only, with its neighbours")


def image_diff(a, b) -> float:
    """Largest |b - a| over the two imagers' tiles, each tile divided by the number of
    pings added to it, relative to a's peak."""
    if set(a.active) != set(b.active):
        raise RuntimeError(f"tiles differ: {sorted(a.active)} / {sorted(b.active)}")
    peak = diff = 0.0
    for k in sorted(a.active):
        ta, tb = a.active[k], b.active[k]
        if list(ta.pings) != list(tb.pings):
            raise RuntimeError(f"tile {k}: pings differ: {ta.pings} / {tb.pings}")
        n = max(1, len(ta.pings))
        za = (np.asarray(ta.re, np.float64) + 1j * np.asarray(ta.im, np.float64)) / n
        zb = (np.asarray(tb.re, np.float64) + 1j * np.asarray(tb.im, np.float64)) / n
        peak = max(peak, float(np.abs(za).max()))
        diff = max(diff, float(np.abs(zb - za).max()))
    return diff / peak if peak > 0 else float("nan")


def measure(sides: dict[str, Side], pings: Pings, setting, timed: int, reps: int) -> dict:
    order = list(sides)                        # ["base", "this"]
    imagers = {s: sides[s].imager(*setting) for s in order}
    warm = {s: sides[s].adapt(pings[FIRST_PING]) for s in order}
    ping = {s: sides[s].adapt(pings[timed]) for s in order}
    for s in order:
        imagers[s].add(warm[s])
    best = {s: float("inf") for s in order}
    counts: dict[str, set[int]] = {s: set() for s in order}
    for rep in range(reps + 1):                # rep 0 compiles and builds tables
        for s in (order if rep % 2 == 0 else order[::-1]):
            im = imagers[s]
            u0 = im.updates
            t0 = time.perf_counter()
            im.add(ping[s])
            elapsed = time.perf_counter() - t0
            counts[s].add(im.updates - u0)
            if rep:
                best[s] = min(best[s], elapsed)
        log.info("%s rep %d: %s", "/".join(setting), rep,
                 ", ".join(f"{s} {elapsed_or_dash(best[s])}" for s in order))
    for s in order:
        if len(counts[s]) != 1:
            raise RuntimeError(f"{s}: update count varies between reps: {sorted(counts[s])}")
    n = {s: counts[s].pop() for s in order}
    delays, interp, precision = setting
    return {"delays": delays, "interpolation": interp, "precision": precision,
            "updates": [n["base"], n["this"]],
            "base_seconds": best["base"], "this_seconds": best["this"],
            "base_updates_per_s": n["base"] / best["base"],
            "this_updates_per_s": n["this"] / best["this"],
            "ratio": best["base"] / best["this"],
            "max_rel_diff": image_diff(imagers["base"], imagers["this"])}


def elapsed_or_dash(t: float) -> str:
    return f"{t:.3f} s" if t < float("inf") else "-"


def print_row(row: dict) -> None:
    print(f"{row['delays']:8s} {row['interpolation']:7s} {row['precision']:7s}  "
          f"base {row['base_updates_per_s']:.3e}/s  this {row['this_updates_per_s']:.3e}/s  "
          f"ratio {row['ratio']:.2f}  updates {row['updates'][0]} / {row['updates'][1]}  "
          f"diff {row['max_rel_diff']:.1e}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision to compare against")
    ap.add_argument("--this", help="git revision to compare (default: the working tree)")
    ap.add_argument("--reps", type=int, default=8,
                    help="timed repetitions per setting, the best is kept (default 8)")
    ap.add_argument("--out", help="JSON file for the figures")
    args = ap.parse_args(argv)
    if args.reps < 1:
        ap.error("--reps must be at least 1")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("numba").setLevel(logging.WARNING)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_kernel_ab_") as tmp:
        work = pathlib.Path(tmp)
        sides = {"base": side_at(args.base, "base", work),
                 "this": (side_at(args.this, "this", work) if args.this
                          else side_here("this", work))}
        pings = Pings()
        timed = mid_tile_ping(sides["this"], pings, SETTINGS[0])
        log.info("warm-up ping %d, timed ping %d", FIRST_PING, timed)
        for setting in SETTINGS:
            row = measure(sides, pings, setting, timed, args.reps)
            rows.append(row)
            print_row(row)
            if row["updates"][0] != row["updates"][1]:
                log.warning("%s: update counts differ: %s", "/".join(setting), row["updates"])
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"command": " ".join([pathlib.Path(sys.executable).name] + sys.argv),
                       "base": sides["base"].rev, "this": sides["this"].rev,
                       "config": {s.label: s.config for s in sides.values()},
                       "reps": args.reps, "warmup_ping": FIRST_PING, "timed_ping": timed,
                       "rows": rows}, fh, indent=2)
        log.info("figures in %s", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
