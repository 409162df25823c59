"""Imaging A/B: two revisions' whole imaging path (TileImager: conditioning, delays,
kernel), side by side in one process.

    python benchmarks/bench_kernel_ab.py --base REV [--this REV] [--reps 8] [--out ab.json]

Each revision's ``svss_daq`` and ``svss_proc`` are taken from git (``git archive``) and
imported under renamed packages (``svss_daq_base``, ``svss_proc_base``, ...; absolute
imports rewritten, relative ones kept), so that module layout and kernel signatures may
differ freely between the two; only the imager's public face is used: ``TileImager(hw,
proc)``, ``add(ping)``, ``updates`` and ``active[k].re/im/pings``. Without ``--this`` the
second side is the working tree as it is imported here. Each side reads its own
revision's ``config/hardware.toml`` and ``config/processing.toml`` with its own config
classes (keys may have been renamed) and varies ``processing.imaging`` by
``dataclasses.replace`` in every setting of SETTINGS.

The pings are simulated once by this checkout's ``EnvironmentSource`` (the demo scene of
``bench_imaging.py``). Per setting both imagers get the same warm-up ping (the first,
which fixes the tile frame); then one mid-tile ping (its projector cone wholly inside
one tile, the DESIGN.md reference workload) is added to each, interleaved, best of
``--reps`` (rep 0 compiles and builds tables), so that the ratio holds even when the
host's speed drifts. Prints updates/s of each (from the imagers' ``updates`` counters),
the ratio base time / this time, the update counts (must be equal) and the largest
image difference between the two sides' tiles relative to the peak.
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

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
for _p in (str(HERE), str(ROOT)):              # bench_imaging and the project, from anywhere
    if _p not in sys.path:
        sys.path.insert(0, _p)

from bench_imaging import scene_for                                   # noqa: E402
from sim_device.environment_source import EnvironmentSource           # noqa: E402
from svss_daq import config as this_config                            # noqa: E402

log = logging.getLogger("bench_kernel_ab")
PACKAGES = ("svss_daq", "svss_proc")
SETTINGS = [("straight", "linear", "float32"), ("straight", "nearest", "float32"),
            ("straight", "cubic", "float32"), ("table", "linear", "float32"),
            ("straight", "linear", "float64")]
FIRST_PING, LAST_PING = 150, 200               # warm-up ping and the mid-tile search range
IMAGER_MODULES = ("imaging.imager", "imager")  # where TileImager has lived


def git(*args: str) -> bytes:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True,
                          capture_output=True).stdout


def rename_imports(src: str, suffix: str, path: str) -> str:
    """``src`` with its absolute imports of svss_daq / svss_proc renamed (relative
    imports untouched); raises if an absolute import of them is left."""
    pat = re.compile(r"^(\s*(?:from|import)\s+)(%s)\b" % "|".join(PACKAGES), re.M)
    out = pat.sub(lambda m: f"{m[1]}{m[2]}_{suffix}", src)
    out = re.sub(r"(import_module\(\s*[\"'])(%s)\b" % "|".join(PACKAGES),
                 lambda m: f"{m[1]}{m[2]}_{suffix}", out)
    for node in ast.walk(ast.parse(out, path)):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                 [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                 else [])
        for n in names:
            if n.split(".")[0] in PACKAGES:
                raise RuntimeError(f"{path}:{node.lineno}: import of {n} not renamed")
    return out


@dataclasses.dataclass
class Side:
    """One revision's imaging path: its TileImager and its own configuration."""
    label: str
    rev: str                                   # git revision, or "working tree"
    imager_cls: type
    hardware: object                           # that side's Loaded[HardwareConfig]
    processing: object                         # that side's ProcessingConfig

    def imager(self, delays: str, interpolation: str, precision: str):
        p = self.processing
        im = dataclasses.replace(p.imaging, delays=delays, interpolation=interpolation,
                                 precision=precision)
        return self.imager_cls(self.hardware, dataclasses.replace(p, imaging=im))

    def adapt(self, ping):
        """The ping as this side accepts it: acquired with a hardware config whose id
        this side's (possibly renamed) hardware file does not have, it goes without id."""
        if ping.config_id and ping.config_id != self.hardware.id:
            return dataclasses.replace(ping, config_id="")
        return ping


def imager_class(pkg: str) -> type:
    for mod in IMAGER_MODULES:
        name = f"{pkg}.{mod}"
        try:
            return importlib.import_module(name).TileImager
        except ModuleNotFoundError as exc:
            if not exc.name or not (name + ".").startswith(exc.name + "."):
                raise                          # a real import error inside the module
    raise RuntimeError(f"no TileImager in {pkg} ({', '.join(IMAGER_MODULES)})")


def side_at(rev: str, label: str, workdir: pathlib.Path) -> Side:
    """``rev``'s svss_daq and svss_proc imported as svss_daq_<label>, svss_proc_<label>,
    with its config files."""
    sha = git("rev-parse", "--verify", f"{rev}^{{commit}}").decode().strip()
    top = workdir / label
    tmp = top / "_archive"
    tmp.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(git("archive", sha, *PACKAGES))) as tar:
        tar.extractall(tmp, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
    for pkg in PACKAGES:
        for f in sorted((tmp / pkg).rglob("*.py")):
            dest = top / f"{pkg}_{label}" / f.relative_to(tmp / pkg)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(rename_imports(f.read_text(), label, str(f.relative_to(tmp))))
    cfg = top / "config"
    cfg.mkdir()
    for name in ("hardware.toml", "processing.toml"):
        (cfg / name).write_bytes(git("show", f"{sha}:config/{name}"))
    sys.path.insert(0, str(top))
    importlib.invalidate_caches()
    daq, proc = f"svss_daq_{label}", f"svss_proc_{label}"
    config = importlib.import_module(f"{daq}.config")
    for pkg in (daq, proc):
        where = pathlib.Path(importlib.import_module(pkg).__file__).resolve()
        assert where.is_relative_to(top.resolve()), (pkg, where)
    log.info("%s: %s (%s) from %s", label, rev, sha[:10], top)
    return Side(label, f"{rev} ({sha[:10]})", imager_class(proc),
                config.load_with_text(config.HardwareConfig, cfg / "hardware.toml"),
                config.load(config.ProcessingConfig, cfg / "processing.toml"))


def side_here(label: str) -> Side:
    """The working tree as imported here, with this checkout's config/."""
    c, cfg = this_config, ROOT / "config"
    log.info("%s: working tree %s", label, ROOT)
    return Side(label, "working tree", imager_class("svss_proc"),
                c.load_with_text(c.HardwareConfig, cfg / "hardware.toml"),
                c.load(c.ProcessingConfig, cfg / "processing.toml"))


class Pings:
    """This checkout's simulated pings of the demo scene, each simulated once."""

    def __init__(self):
        c = this_config
        self.hardware = c.load_with_text(c.HardwareConfig, ROOT / "config" / "hardware.toml")
        self.source = EnvironmentSource(self.hardware, scene_for(340))
        self._cache: dict[int, object] = {}

    def __getitem__(self, i: int):
        if i not in self._cache:
            t = time.perf_counter()
            self._cache[i] = self.source.ping(i)
            log.info("simulated ping %d (%.1f s)", i, time.perf_counter() - t)
        return self._cache[i]


def mid_tile_ping(side: Side, pings: Pings, setting) -> int:
    """The first ping after the warm-up whose imaging touches exactly one tile (so its
    projector cone lies wholly inside it), as ``side`` images it."""
    imager = side.imager(*setting)
    imager.add(side.adapt(pings[FIRST_PING]))
    for i in range(FIRST_PING + 1, LAST_PING):
        ping = side.adapt(pings[i])
        before = imager.updates
        imager.add(ping)
        touched = [k for k, t in imager.active.items() if ping.sequence in t.pings]
        log.info("ping %d: tiles %s, %d updates", i, touched, imager.updates - before)
        if len(touched) == 1 and imager.updates > before:
            return i
    raise RuntimeError(f"no mid-tile ping in {FIRST_PING + 1}..{LAST_PING - 1}")


def image_diff(a, b) -> float:
    """Largest |b - a| over the tiles both imagers hold, relative to a's peak."""
    keys = sorted(set(a.active) & set(b.active))
    if not keys or set(a.active) != set(b.active):
        raise RuntimeError(f"tiles differ: {sorted(a.active)} / {sorted(b.active)}")
    peak = diff = 0.0
    for k in keys:
        ta, tb = a.active[k], b.active[k]
        za = np.asarray(ta.re, np.float64) + 1j * np.asarray(ta.im, np.float64)
        zb = np.asarray(tb.re, np.float64) + 1j * np.asarray(tb.im, np.float64)
        peak = max(peak, float(np.abs(za).max()))
        diff = max(diff, float(np.abs(zb - za).max()))
    return diff / peak


def measure(sides: dict[str, Side], pings: Pings, setting, mid: int, reps: int) -> dict:
    imagers = {name: s.imager(*setting) for name, s in sides.items()}
    warm = {name: s.adapt(pings[FIRST_PING]) for name, s in sides.items()}
    ping = {name: s.adapt(pings[mid]) for name, s in sides.items()}
    for name, im in imagers.items():
        im.add(warm[name])
    best: dict[str, float] = {}
    counts: dict[str, set[int]] = {name: set() for name in sides}
    order = list(sides)
    for rep in range(reps + 1):                # rep 0 compiles
        for name in (order if rep % 2 == 0 else order[::-1]):
            im = imagers[name]
            u0 = im.updates
            t = time.perf_counter()
            im.add(ping[name])
            el = time.perf_counter() - t
            counts[name].add(im.updates - u0)
            if rep:
                best[name] = min(best.get(name, el), el)
        log.info("%s rep %d: %s", "/".join(setting), rep,
                 ", ".join(f"{n} {best.get(n, float('nan')):.3f} s" for n in order))
    if any(len(c) != 1 for c in counts.values()):
        raise RuntimeError(f"update counts vary between reps: {counts}")
    n = {name: counts[name].pop() for name in order}
    delays, interp, precision = setting
    return {"delays": delays, "interpolation": interp, "precision": precision,
            "updates": [n["base"], n["this"]],
            "base_seconds": best["base"], "this_seconds": best["this"],
            "base_updates_per_s": n["base"] / best["base"],
            "this_updates_per_s": n["this"] / best["this"],
            "ratio": best["base"] / best["this"],
            "max_rel_diff": image_diff(imagers["base"], imagers["this"])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision to compare against")
    ap.add_argument("--this", help="git revision to compare (default: the working tree)")
    ap.add_argument("--reps", type=int, default=8, help="timed repetitions (best is kept)")
    ap.add_argument("--out", help="JSON file for the figures")
    args = ap.parse_args(argv)
    if args.reps < 1:
        ap.error("--reps must be at least 1")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_kernel_ab_") as tmp:
        work = pathlib.Path(tmp)
        sides = {"base": side_at(args.base, "base", work),
                 "this": side_at(args.this, "this", work) if args.this else side_here("this")}
        pings = Pings()
        mid = mid_tile_ping(sides["this"], pings, SETTINGS[0])
        log.info("warm-up ping %d, timed ping %d", FIRST_PING, mid)
        for setting in SETTINGS:
            row = measure(sides, pings, setting, mid, args.reps)
            rows.append(row)
            delays, interp, precision = setting
            print(f"{delays:8s} {interp:7s} {precision:7s}  base {row['base_updates_per_s']:.3e}"
                  f"/s  this {row['this_updates_per_s']:.3e}/s  ratio {row['ratio']:.2f}  "
                  f"updates {row['updates'][0]} / {row['updates'][1]}  "
                  f"diff {row['max_rel_diff']:.1e}", flush=True)
            if row["updates"][0] != row["updates"][1]:
                log.warning("update counts differ: %s", row["updates"])
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"command": " ".join([pathlib.Path(sys.executable).name] + sys.argv),
                       "base": sides["base"].rev, "this": sides["this"].rev,
                       "reps": args.reps, "warmup_ping": FIRST_PING, "timed_ping": mid,
                       "rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
