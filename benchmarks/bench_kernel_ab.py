"""CPU kernel A/B: this checkout's backprojection against an earlier revision's, side by side.

    python benchmarks/bench_kernel_ab.py --base REV [--reps 8] [--out ab.json]

Both kernels image the same reference-tile ping (DESIGN.md workload, mid-tile, full
projector cone inside the tile; captured from the imager) in each interpolation and
delay setting, interleaved in one process (best of ``--reps``), so that the ratio holds
even when the host's speed drifts. Prints updates/s of each, the ratio, the update
counts and the largest image difference relative to the peak.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import logging
import pathlib
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench_imaging import scene_for
from sim_device.point_echo import PointEchoSource
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,
                             load_with_text)
from svss_proc.imaging import cpu_kernel as backprojection
from svss_proc.imaging.imager import TileImager

log = logging.getLogger("bench_kernel_ab")
ROOT = pathlib.Path(__file__).resolve().parents[1]
SETTINGS = [("straight", "linear", "float32"), ("straight", "nearest", "float32"),
            ("straight", "cubic", "float32"), ("table", "linear", "float32"),
            ("straight", "linear", "float64")]


def module_at(rev: str, workdir: pathlib.Path):
    """svss_proc/backprojection.py as of ``rev``, importable next to the current one."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:svss_proc/backprojection.py"],
                         check=True, capture_output=True, text=True).stdout
    src = re.sub(r"^from \.(\w+) import", r"from svss_proc.\1 import", src, flags=re.M)
    path = workdir / f"backprojection_{re.sub(r'[^0-9A-Za-z]', '_', rev)}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod               # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def reference_call(hw, proc, delays: str):
    """(image shape, conditioned ping, run_ping arguments) of a mid-tile reference ping."""
    p = dataclasses.replace(proc, imaging=dataclasses.replace(proc.imaging, delays=delays))
    imager = TileImager(hw, p)
    calls = []
    imager._run = lambda re_, im_, kd, *a, **kw: calls.append((re_.shape, kd, a, kw)) or 0
    conds = []
    conditioner = imager.conditioner
    imager.conditioner = lambda *a: conds.append(conditioner(*a)) or conds[-1]
    src = PointEchoSource(hw, scene_for(340))
    for i in range(150, 200):
        n = len(calls)
        imager.add(src.ping(i))
        for shape, _, a, kw in calls[n:]:
            ia0, ia1 = a[-2], a[-1]
            if ia0 > 0 and ia1 < shape[0] and ia1 - ia0 > 150:
                return shape, conds[-1], a, kw
    raise RuntimeError("no mid-tile ping found")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision to compare against")
    ap.add_argument("--reps", type=int, default=8)
    ap.add_argument("--out", help="JSON file for the figures")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        kernels = {"base": module_at(args.base, pathlib.Path(tmp)), "this": backprojection}
        captured = {d: reference_call(hw, proc, d) for d in sorted({s[0] for s in SETTINGS})}
        for delays, interp, precision in SETTINGS:
            shape, cond, a, kw = captured[delays]
            ft = np.dtype(precision).type
            best, out = {}, {}
            for rep in range(args.reps + 1):          # rep 0 compiles
                for name, mod in kernels.items():
                    kd = mod.prepare(cond, interp, ft)
                    re_, im_ = np.zeros(shape, ft), np.zeros(shape, ft)
                    t = time.perf_counter()
                    n = mod.run_ping(re_, im_, kd, *a, **kw)
                    el = time.perf_counter() - t
                    if rep:
                        best[name] = min(best.get(name, el), el)
                    out[name] = (re_ + 1j * im_, n)
            ref = out["base"][0]
            row = {"delays": delays, "interpolation": interp, "precision": precision,
                   "updates": [out["base"][1], out["this"][1]],
                   "base_updates_per_s": out["base"][1] / best["base"],
                   "this_updates_per_s": out["this"][1] / best["this"],
                   "ratio": best["base"] / best["this"],
                   "max_rel_diff": float(np.abs(out["this"][0] - ref).max() / np.abs(ref).max())}
            rows.append(row)
            print(f"{delays:8s} {interp:7s} {precision:7s}  base {row['base_updates_per_s']:.3e}"
                  f"/s  this {row['this_updates_per_s']:.3e}/s  ratio {row['ratio']:.2f}  "
                  f"updates {row['updates'][0]} / {row['updates'][1]}  "
                  f"diff {row['max_rel_diff']:.1e}", flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"command": " ".join([pathlib.Path(sys.executable).name] + sys.argv),
                       "base": args.base, "reps": args.reps, "rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
