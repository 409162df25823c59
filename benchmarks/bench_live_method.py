#!/usr/bin/env python
"""The live imaging method against the exact one on whole survey lines: image error,
each target's peak and -3 dB widths, and the run's contacts against the truth.

Each line (the seed's cylinder in sand and in silt, the Sayers-like field, the demo with
its seabed) is simulated once into ``--cache`` (``svss simulate``; the same recordings as
``bench_false_alarms.py``), then processed by ``svss process`` twice with the shipped
configuration (``config/processing.toml``; the demo's ``processing-demo.toml``): as
shipped (``[imaging] method = "exact"``) and with ``method = "factorised"`` (what the live
worker runs: docs/imaging.md "The live method"). Reported per line:

* the image error of the factorised tiles: 20 log10 of the rms difference over the rms
  exact image, over the voxels within 40 dB of each tile's peak (all tiles pooled), and
  the largest difference re the line's peak;
* per target of the scene's truth: its peak (the brightest voxel within its half-extent
  plus 10 cm of its true position, in every tile that holds it) under both methods, the
  change in dB, and the -3 dB widths (along, across, depth) through the exact peak;
* the run's contacts scored against the truth (:func:`svss.score.score_tiles`): detected,
  missed and false alarms under both; whether every exact detection is kept;
* ``svss process`` seconds (the same machine, one after the other).

    python benchmarks/bench_live_method.py --cache /tmp/bench_fa --out benchmarks/results/bench_live_method.json
"""

from __future__ import annotations

import json
import logging
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_false_alarms import LINES, line_args, simulated_line  # noqa: E402  (the same lines)
from bench_isa import machine_isa  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from svss.score import half_extent, score_tiles, tile_paths  # noqa: E402
from svss_proc.tiles import read_tile  # noqa: E402

log = logging.getLogger("bench_live_method")

def factorised_config(config: str, cache: Path) -> Path:
    """The configuration with ``[imaging] method = "factorised"``."""
    text = (ROOT / "config" / config).read_text()
    if re.search(r'^method = "exact"', text, flags=re.M):
        new = re.sub(r'^method = "exact"', 'method = "factorised"', text, count=1, flags=re.M)
    else:
        new = text.replace("\n[imaging]\n", '\n[imaging]\nmethod = "factorised"\n', 1)
    assert new != text, config
    out = cache / f"factorised-{config}"
    out.write_text(new)
    return out


def process(raw: Path, cfg: Path, out: Path, log_path: Path) -> float:
    t = time.perf_counter()
    with open(log_path, "w") as f:
        subprocess.run([sys.executable, "-m", "svss", "process", str(raw), "--out", str(out),
                        "--processing", str(cfg), "--force"], check=True, stdout=f,
                       stderr=subprocess.STDOUT, cwd=ROOT)
    return time.perf_counter() - t


def width(mag: np.ndarray, p: tuple, axis: int, voxel: float) -> float:
    """-3 dB width (m) of the response through voxel ``p`` along ``axis``."""
    idx = list(p)
    idx[axis] = slice(None)
    line = mag[tuple(idx)]
    half = line[p[axis]] / math.sqrt(2)
    lo = hi = p[axis]
    while lo > 0 and line[lo - 1] >= half:
        lo -= 1
    while hi < line.size - 1 and line[hi + 1] >= half:
        hi += 1
    left = lo - (line[lo] - half) / (line[lo] - line[lo - 1]) if lo > 0 else lo
    right = hi + (line[hi] - half) / (line[hi] - line[hi + 1]) if hi < line.size - 1 else hi
    return float((right - left) * voxel)


def compare(exact_dir: Path, fact_dir: Path, scored: dict) -> dict:
    """Image error and per-target peaks and widths of the factorised tiles."""
    num = den = 0.0
    worst = 0.0
    peak_all = 0.0
    targets = {}
    for pe in tile_paths(exact_dir):
        a = read_tile(pe)
        b = read_tile(fact_dir / pe.name)
        ia, ib = a["image"].astype(np.complex128), b["image"].astype(np.complex128)
        mag = np.abs(ia)
        lit = mag > mag.max() * 0.01
        num += float(np.sum(np.abs(ib - ia)[lit] ** 2))
        den += float(np.sum(mag[lit] ** 2))
        worst = max(worst, float(np.abs(ib - ia).max()))
        peak_all = max(peak_all, float(mag.max()))
        voxel = float(a["along"][1] - a["along"][0])
        grids = np.meshgrid(a["along"], a["cross"], a["depth"], indexing="ij")
        for k, t in enumerate(scored["truth"]):
            pos = t.get("tile_m", {}).get(pe.name)
            if pos is None:
                continue
            r = half_extent(t) + 0.1
            near = sum((g - x) ** 2 for g, x in zip(grids, pos)) <= r * r
            if not near.any():
                continue
            m = np.where(near, mag, 0.0)
            p = np.unravel_index(int(np.argmax(m)), m.shape)
            level_e, level_f = float(mag[p]), float(np.abs(ib).max(where=near, initial=0.0))
            best = targets.get(k)
            if best is None or level_e > best["exact"]:
                targets[k] = {"target": t.get("name", str(k)), "exact": level_e,
                              "factorised": level_f,
                              "change_db": 20 * math.log10(level_f / level_e),
                              "widths_m_exact": [width(mag, p, ax, voxel) for ax in range(3)],
                              "widths_m_factorised": [width(np.abs(ib), p, ax, voxel)
                                                      for ax in range(3)]}
    return {"image_error_db": 10 * math.log10(num / den),
            "largest_error_db": 20 * math.log10(worst / peak_all),
            "targets": [targets[k] for k in sorted(targets)]}


def main() -> None:
    args = line_args(__doc__)
    rows = []
    for name, config in LINES:
        if args.only and name not in args.only:
            continue
        scene_path = ROOT / "config" / "scenes" / f"{name}.toml"
        raw = simulated_line(name, args.cache)
        runs = {}
        for method, cfg in (("exact", ROOT / "config" / config),
                            ("factorised", factorised_config(config, args.cache))):
            out = args.cache / f"{name}-{method}"
            secs = process(raw, cfg, out, args.cache / f"{out.name}.log")
            r = score_tiles(out, scene_path)
            s = r["summary"]
            runs[method] = {"dir": out, "score": r, "process_s": secs,
                            "detected": s["hits"], "missed": s["misses"],
                            "false_alarms": s["false_alarms"],
                            "detected_targets": sorted(k for k, t in enumerate(r["truth"])
                                                       if t["status"] == "detected")}
            log.info("%s %s: %d detected, %d missed, %d false alarms (%.0f s)", name, method,
                     s["hits"], s["misses"], s["false_alarms"], secs)
        cmp = compare(runs["exact"]["dir"], runs["factorised"]["dir"], runs["exact"]["score"])
        kept = set(runs["exact"]["detected_targets"]) <= set(
            runs["factorised"]["detected_targets"])
        row = {"scene": name, "config": config,
               **{f"{m}_{k}": runs[m][k] for m in runs
                  for k in ("detected", "missed", "false_alarms", "process_s")},
               "every_detection_kept": kept, **cmp,
               "worst_target_change_db": min((t["change_db"] for t in cmp["targets"]),
                                             default=None),
               "scene_targets": len(load_scene(scene_path).points)
               + len(load_scene(scene_path).targets)}
        rows.append(row)
        log.info("%s: image error %.1f dB (largest %.1f dB); targets %s dB; detections kept: "
                 "%s", name, cmp["image_error_db"], cmp["largest_error_db"],
                 [round(t["change_db"], 2) for t in cmp["targets"]], kept)
    if args.out:
        args.out.write_text(json.dumps({
            "command": "python benchmarks/bench_live_method.py " + " ".join(sys.argv[1:]),
            "machine": machine_isa(), "rows": rows}, indent=1, default=str))


if __name__ == "__main__":
    main()
