#!/usr/bin/env python
"""Simulator A/B: a git revision's ``sim_device`` beside this checkout's, the same pings
of a seabed scene, interleaved, in one process.

    python benchmarks/bench_sim_ab.py --base REV [--scene seed_cylinder_sand]
        [--first 50] [--pings 150] [--setting scene|lean] [--out ab.json]

The base revision's ``sim_device`` is taken out with ``git archive`` and imported as
``sim_device_base`` (its absolute imports of ``sim_device`` rewritten; ``svss_daq`` is
this checkout's); its numba cache lives beside it in a folder named by the revision
(``$TMPDIR/svss_sim_ab_<sha>``), so the second run of a revision does not compile.
Each side builds its ``EnvironmentSource`` from its own ``load_scene`` of this checkout's
scene file, with ``bench_possm.with_fidelity`` (no targets: what ``bench_possm.py``
times) and, for ``--setting lean``, its fast profile. Both sides get one untimed ping
(compilation, tables), then for every ping ``pressure(i)`` of each side, the order
alternating from ping to ping; wall and process (all threads) seconds per ping. Printed
and saved: each side's median and total, the ratio base / this (median of the per-ping
ratios, and of the totals), the echoes, and how the samples compare: pings bit-identical,
the largest |difference| relative to the ping's peak, and the relative L2 difference.
The JSON records the load average before and after and the machine's instruction set
(``bench_isa.machine_isa``).
"""

from __future__ import annotations

import argparse
import importlib
import io
import json
import logging
import os
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
for _p in (str(ROOT), str(HERE)):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numba  # noqa: E402
from bench_isa import machine_isa  # noqa: E402
from bench_possm import FAST_PROFILE, with_fidelity  # noqa: E402

from svss_daq.config import HardwareConfig, config_path, load_with_text  # noqa: E402

log = logging.getLogger("bench_sim_ab")

#: EnvironmentSource.last_stats' stage times (s): scatterers generated, transmit legs,
#: receive legs and echoes (pass 2), the whole point-scatterer synthesis with the pulse
STAGES = ("generate_s", "transmit_s", "receive_s", "scattered_s")

_IMPORT = re.compile(r"^(?P<head>[ \t]*(?:from|import)[ \t]+)sim_device(?=[.\s]|$)",
                     re.MULTILINE)


def git(*args: str) -> bytes:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True,
                          capture_output=True).stdout


def base_package(rev: str) -> tuple[str, str]:
    """(module name, sha) of ``rev``'s sim_device extracted as ``sim_device_base``."""
    sha = git("rev-parse", rev).decode().strip()
    top = pathlib.Path(tempfile.gettempdir()) / f"svss_sim_ab_{sha[:12]}"
    pkg = top / "sim_device_base"
    if not (top / "complete").exists():
        raw = top / "_archive"
        raw.mkdir(parents=True, exist_ok=True)
        with tarfile.open(fileobj=io.BytesIO(git("archive", sha, "sim_device"))) as tar:
            tar.extractall(raw, filter="data")
        for f in sorted((raw / "sim_device").rglob("*.py")):
            dest = pkg / f.relative_to(raw / "sim_device")
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(_IMPORT.sub(lambda m: f"{m['head']}sim_device_base",
                                        f.read_text()))
        (top / "complete").write_text(sha)
    sys.path.insert(0, str(top))
    return "sim_device_base", sha


def source(pkg: str, hw, scene_name: str, setting: str):
    """``pkg``'s EnvironmentSource of the scene at ``setting``."""
    load_scene = importlib.import_module(f"{pkg}.scene").load_scene
    env = importlib.import_module(f"{pkg}.environment_source")
    opts = FAST_PROFILE if setting == "lean" else {}
    scene = with_fidelity(load_scene(config_path(f"scenes/{scene_name}.toml")), **opts)
    return env.EnvironmentSource(hw, scene)


def timed(src, i: int) -> tuple[np.ndarray, float, float]:
    c0, t0 = time.process_time(), time.perf_counter()
    p = src.pressure(i)
    return p, time.perf_counter() - t0, time.process_time() - c0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision of the base side")
    ap.add_argument("--scene", default="seed_cylinder_sand")
    ap.add_argument("--first", type=int, default=50, help="first timed ping")
    ap.add_argument("--pings", type=int, default=150, help="pings timed (a tile: 150)")
    ap.add_argument("--setting", default="scene", choices=("scene", "lean"))
    ap.add_argument("--threads", type=int, default=None, help="numba threads")
    ap.add_argument("--out", default=None, help="JSON file for the results")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("sim_device").setLevel(logging.ERROR)
    logging.getLogger("sim_device_base").setLevel(logging.ERROR)
    if args.threads:
        numba.set_num_threads(args.threads)
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    base_pkg, sha = base_package(args.base)
    sides = {"base": source(base_pkg, hw, args.scene, args.setting),
             "this": source("sim_device", hw, args.scene, args.setting)}
    load_before = os.getloadavg()
    for s in sides.values():                       # compile / load kernels, untimed
        s.pressure(args.first - 1)
    wall = {k: [] for k in sides}
    cpu = {k: [] for k in sides}
    echoes = {k: [] for k in sides}
    stages = {k: {s: [] for s in STAGES} for k in sides}
    same, peak_err, l2_err = 0, [], []
    names = list(sides)
    for n, i in enumerate(range(args.first, args.first + args.pings)):
        out = {}
        for k in (names if n % 2 == 0 else names[::-1]):
            out[k], w, c = timed(sides[k], i)
            wall[k].append(w)
            cpu[k].append(c)
            st = sides[k].last_stats
            echoes[k].append(st.get("echoes", 0))
            for name in STAGES:
                stages[k][name].append(st.get(name, 0.0))
        a, b = out["base"], out["this"]
        same += bool(np.array_equal(a, b))
        peak_err.append(float(np.max(np.abs(a - b)) / np.max(np.abs(a))))
        l2_err.append(float(np.linalg.norm(a - b) / np.linalg.norm(a)))
    load_after = os.getloadavg()
    res = {"base": sha, "this": "working tree", "scene": args.scene,
           "setting": args.setting, "pings": [args.first, args.first + args.pings - 1],
           "threads": numba.get_num_threads(), "machine": machine_isa(),
           "load_before": load_before, "load_after": load_after,
           "command": " ".join([os.path.basename(sys.argv[0])] + sys.argv[1:])}
    for k in names:
        res[k + "_side"] = {"s_per_ping_median": float(np.median(wall[k])),
                            "tile_s": float(np.sum(wall[k])),
                            "cpu_s_per_ping_median": float(np.median(cpu[k])),
                            "echoes_per_ping": float(np.mean(echoes[k])),
                            "stages_s_median": {s: float(np.median(v))
                                                for s, v in stages[k].items()}}
    print(f"{'stage (s, median)':20s} " + " ".join(f"{s:>11s}" for s in STAGES))
    for k in names:
        med = res[k + "_side"]["stages_s_median"]
        print(f"{k:20s} " + " ".join(f"{med[s]:11.4f}" for s in STAGES))
    ratios = np.array(wall["base"]) / np.array(wall["this"])
    res["ratio_median"] = float(np.median(ratios))
    res["ratio_total"] = float(np.sum(wall["base"]) / np.sum(wall["this"]))
    res["ratio_cpu_total"] = float(np.sum(cpu["base"]) / np.sum(cpu["this"]))
    res["samples"] = {"pings_bit_identical": same, "pings": args.pings,
                      "max_abs_diff_over_peak": max(peak_err),
                      "max_rel_l2": max(l2_err)}
    print(f"{args.scene} ({args.setting}), pings {args.first}-{args.first + args.pings - 1}, "
          f"{res['threads']} threads; load {load_before[0]:.2f} -> {load_after[0]:.2f}")
    print(f"{'side':6s} {'s/ping':>8s} {'tile s':>8s} {'CPU s/ping':>10s} {'echoes/ping':>12s}")
    for k in names:
        r = res[k + "_side"]
        print(f"{k:6s} {r['s_per_ping_median']:8.3f} {r['tile_s']:8.1f} "
              f"{r['cpu_s_per_ping_median']:10.3f} {r['echoes_per_ping']:12.0f}")
    print(f"base / this: x{res['ratio_median']:.2f} (median per ping), "
          f"x{res['ratio_total']:.2f} (totals), CPU x{res['ratio_cpu_total']:.2f}")
    s = res["samples"]
    print(f"samples: {s['pings_bit_identical']}/{s['pings']} pings bit-identical; largest "
          f"|diff|/peak {s['max_abs_diff_over_peak']:.2e}, relative L2 {s['max_rel_l2']:.2e}")
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps(res, indent=2))
        log.info("wrote %s", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
