#!/usr/bin/env python
"""Contacts against the truth on the seed's lines, the Sayers-like field and the demo,
with the shipped processing: one detection threshold for every layer against a threshold
per depth layer from its own clutter (``[products.detection] layer_false_alarms_per_m3``,
docs/detections.md "Layer thresholds"), side by side in one run.

Each scene is simulated once into ``--cache`` (``svss simulate``), then processed with
``svss process`` twice: the shipped configuration (``config/processing.toml``; the demo's
``config/processing-demo.toml``) and the same with ``layer_false_alarms_per_m3`` left
out. The run's contacts are scored against the scene's truth (:func:`svss.score.score_tiles`,
the run-level contacts an operator gets): targets detected and missed, false alarms in
all and per 100 m of track, by depth band, and, as the tile MIPs and the run's mosaic
(its PNG and GeoTIFF) show them, the brightest pixel outside every target's core (0.3 m
beyond its half-extent) against the faintest detected target.

    python benchmarks/bench_false_alarms.py --cache /tmp/bench_false_alarms --out benchmarks/results/bench_false_alarms.json
"""

from __future__ import annotations

import argparse
import glob
import json
import logging
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_isa import machine_isa  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from sim_device.track import truth_line  # noqa: E402
from svss.score import half_extent, scene_truth, score_tiles  # noqa: E402

log = logging.getLogger("bench_false_alarms")

#: (scene, processing configuration)
LINES = (("seed_cylinder_sand", "processing.toml"), ("seed_cylinder_silt", "processing.toml"),
         ("sayers_field", "processing.toml"), ("demo_seabed", "processing-demo.toml"))
#: depth bands of the false alarms, m below the interface
BANDS = ((-10.0, 0.1, "interface (< 0.1 m)"), (0.1, 1.5, "0.1-1.5 m"),
         (1.5, 10.0, "deeper (> 1.5 m)"))


def _run(cmd: list[str], log_path: Path) -> float:
    t = time.perf_counter()
    with open(log_path, "w") as fh:
        r = subprocess.run(cmd, cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed (rc {r.returncode}); see {log_path}")
    return time.perf_counter() - t


def simulated_line(name: str, cache: Path) -> Path:
    """The run of config/scenes/NAME.toml, simulated once into ``cache`` (``svss
    simulate``, its log beside it) and reused."""
    raw = cache / f"{name}.h5"
    if not raw.exists():
        log.info("%s: simulating", name)
        _run([sys.executable, "-m", "svss", "simulate", "--scene",
              str(ROOT / "config" / "scenes" / f"{name}.toml"), "--out", str(raw)],
             cache / f"{name}.simulate.log")
    return raw


def one_threshold(config: str, cache: Path) -> Path:
    """``config`` without ``layer_false_alarms_per_m3``: one threshold for all layers."""
    text = (ROOT / "config" / config).read_text()
    out = cache / f"one-threshold-{config}"
    out.write_text("\n".join(line for line in text.splitlines()
                             if not line.startswith("layer_false_alarms_per_m3")) + "\n")
    return out


def core_m(target: dict) -> float:
    """How far about a target's centre its own response reaches horizontally: 0.3 m
    beyond its largest half-extent (a cylinder's half length, a sphere's radius)."""
    return 0.3 + half_extent(target)


def shown_levels(tiles_dir: Path, scene, detected: list[int]) -> tuple[float, float]:
    """(the brightest depth-MIP pixel outside every target's core (:func:`core_m`),
    the faintest of the ``detected`` targets' brightest MIP pixels within its core),
    dB as the products show them (the normalised level plus the display gain), over the
    run's tiles."""
    truth = scene_truth(scene)
    ned = truth_line(scene.track).tile_to_ned(
        np.array([t["scene_m"] for t in truth], dtype=np.float64).reshape(-1, 3))
    from svss_proc import tiles
    outside, at = -np.inf, np.full(len(truth), -np.inf)
    for path in sorted(glob.glob(str(tiles_dir / "tile_*.h5"))):
        header = tiles.read_tile_header(path)
        t_tile = tiles.tile_line(header["attrs"]).ned_to_tile(ned)
        with h5py.File(path, "r") as f:
            mip = f["mip_depth"][:]
        a, c = np.meshgrid(header["along"], header["cross"], indexing="ij")
        far = np.ones(mip.shape, dtype=bool)
        for k, p in enumerate(t_tile):
            near = np.hypot(a - p[0], c - p[1]) <= core_m(truth[k])
            far &= ~near
            if near.any():
                at[k] = max(at[k], float(np.max(mip[near])))
        if far.any():
            outside = max(outside, float(np.max(mip[far])))
    faintest = min((at[k] for k in detected), default=float("nan"))
    return outside, faintest


def mosaic_levels(tiles_dir: Path, scene, detected: list[int]) -> tuple[float, float]:
    """As :func:`shown_levels`, on the run's mosaic (``mosaic.h5``'s plan-view MIP in the
    survey frame, which the mosaic PNG and GeoTIFF show)."""
    truth = scene_truth(scene)
    ned = truth_line(scene.track).tile_to_ned(
        np.array([t["scene_m"] for t in truth], dtype=np.float64).reshape(-1, 3))
    with h5py.File(tiles_dir / "mosaic.h5", "r") as f:
        mip, north, east = f["mip_db"][:], f["north"][:], f["east"][:]
    n, e = np.meshgrid(north, east, indexing="ij")
    far = np.isfinite(mip)
    at = np.full(len(truth), -np.inf)
    for k, p in enumerate(ned):
        near = np.hypot(n - p[0], e - p[1]) <= core_m(truth[k])
        far &= ~near
        if (near & np.isfinite(mip)).any():
            at[k] = float(np.nanmax(np.where(near, mip, np.nan)))
    outside = float(np.max(mip[far])) if far.any() else -np.inf
    return outside, min((at[k] for k in detected), default=float("nan"))


def line_args(doc: str) -> argparse.Namespace:
    """The command line of a benchmark over LINES (``--cache`` of the simulated runs,
    made here; ``--out``; ``--only`` scene names), ``doc``'s first paragraph its
    description; logging set up."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--only", nargs="*", default=None, help="scene names to run")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s",
                        datefmt="%H:%M:%S")
    args.cache.mkdir(parents=True, exist_ok=True)
    return args


def main() -> None:
    args = line_args(__doc__)
    svss = [sys.executable, "-m", "svss"]
    rows = []
    for name, config in LINES:
        if args.only and name not in args.only:
            continue
        scene_path = ROOT / "config" / "scenes" / f"{name}.toml"
        scene = load_scene(scene_path)
        raw = simulated_line(name, args.cache)
        track_m = scene.track.n_pings * scene.track.speed_m_s / 10.0
        for variant, cfg in (("one threshold", one_threshold(config, args.cache)),
                             ("per layer (shipped)", ROOT / "config" / config)):
            out = args.cache / f"{name}-{'layer' if 'layer' in variant else 'one'}"
            secs = _run(svss + ["process", str(raw), "--out", str(out), "--processing",
                                str(cfg), "--force"], args.cache / f"{out.name}.log")
            r = score_tiles(out, scene_path)
            s = r["summary"]
            fa = [d for d in r["detections"] if d.get("status") == "false alarm"]
            bands = {label: sum(lo <= d["depth_m"] < hi for d in fa) for lo, hi, label in BANDS}
            hits = [t["excess_db"] for t in r["truth"] if t["status"] == "detected"]
            hit = [k for k, t in enumerate(r["truth"]) if t["status"] == "detected"]
            outside, faintest = shown_levels(out, scene, hit)
            m_outside, m_faintest = mosaic_levels(out, scene, hit)
            row = {"scene": name, "variant": variant, "track_m": track_m,
                   "targets": s["truth"], "detected": s["hits"], "missed": s["misses"],
                   "false_alarms": s["false_alarms"],
                   "false_alarms_per_100m": 100.0 * s["false_alarms"] / track_m,
                   "false_alarms_by_depth": bands,
                   "weakest_detected_excess_db": min(hits) if hits else None,
                   "faintest_detected_shown_db": faintest,
                   "brightest_outside_targets_shown_db": outside,
                   "mosaic_faintest_detected_db": m_faintest,
                   "mosaic_brightest_outside_targets_db": m_outside,
                   "process_s": secs}
            rows.append(row)
            log.info("%-20s %-20s targets %d detected %d false alarms %d (%.1f per 100 m; "
                     "%s); shown: faintest detected target %.1f dB, brightest pixel "
                     "outside targets %.1f dB (mosaic: %.1f, %.1f dB) (%.0f s)", name,
                     variant, row["targets"], row["detected"], row["false_alarms"],
                     row["false_alarms_per_100m"], bands, faintest, outside, m_faintest,
                     m_outside, secs)
    if args.out:
        args.out.write_text(json.dumps({"machine": machine_isa(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
