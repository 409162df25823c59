#!/usr/bin/env python
"""Why targets in medium sand are missed: each target's brightest level over its
background against the brightest level of the sand's own clutter, per voxel and averaged
over boxes of voxels (a detector that integrates over a contact's extent), on the
classifier's sand fields (issue 51; docs/classification.md, "Detection in sand").

The fields (``classify_train_4``, ``classify_train_6``, ``classify_test2_sand``,
``classify_test_sand``) are simulated and processed as benchmarks/fit_classifier.py and
bench_classify.py do (shipped configuration, the sediment's speed estimated; reused
from ``--cache``). Per box (along x across x depth voxels of 2 cm) the normalised power
(|image| / background)^2 is averaged over the box; a target's level is the maximum
within 0.35 m of its true position, the clutter's the maximum of each tile over voxels
0.05-1.0 m below the interface, imaged by at least half the full coverage and more than
0.8 m (plan) from every target. Then the detection threshold's floor
(``[products.detection] threshold_db``) lowered to each of ``THRESHOLDS_DB``: the fields
processed again with it and their run contacts scored (:func:`svss.score.score_tiles`):
targets detected and false alarms.

The whole curve: the fields, and the held-out and seen silt fields beside them,
processed once more with the floor at ``LOW_FLOOR_DB`` and each depth layer's clutter
rate raised to ``LOW_LAYER_RATE`` (so that no layer's own threshold stands above the
floor), then every floor from there to 17.5 dB applied to their run contacts and those
over it scored: per sediment, the targets detected, the false alarms, how many of those
the contacts' call (the run's, with the pings) says man-made, and the false alarms per
100 m of track. Without ``--out`` the curve is left out.

    python benchmarks/bench_sand_detection.py --cache /tmp/bench_classify --out benchmarks/results/bench_sand_detection.json
"""

from __future__ import annotations

import hashlib
import json
import logging
import sys
import tomllib
from pathlib import Path

import h5py
import numpy as np
from scipy.ndimage import uniform_filter

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_false_alarms import line_args  # noqa: E402
from bench_isa import machine_isa  # noqa: E402
from fit_classifier import PROCESSING, _replace_keys, processed  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from svss_daq.config import HardwareConfig, config_path, load  # noqa: E402
from svss.score import score_tiles  # noqa: E402

log = logging.getLogger("bench_sand_detection")

FIELDS = (("classify_train_4", "shipped"), ("classify_train_6", "shipped"),
          ("classify_test2_sand", "estimate"), ("classify_test_sand", "estimate"))
BOXES = ((1, 1, 1), (3, 3, 1), (3, 3, 3), (5, 5, 3), (7, 7, 3))
TARGET_RADIUS_M, CLEAR_M = 0.35, 0.8
DEPTHS_M = (0.05, 1.0)
#: detection floors tried besides the shipped one, dB
THRESHOLDS_DB = (14.0,)
#: the curve: floor and per-layer clutter rate (per m^3) of its one processing, the
#: floors applied to its contacts, and the fields per sediment
LOW_FLOOR_DB, LOW_LAYER_RATE = 12.0, 1.0
CURVE_FLOORS_DB = tuple(np.arange(12.0, 17.51, 0.5))
CURVE_FIELDS = (("sand", ("classify_train_4", "classify_train_6", "classify_test2_sand",
                          "classify_test_sand")),
                ("silt", ("classify_test2_silt", "classify_test_silt")))


def floor_processing(threshold_db: float, cache: Path) -> Path:
    """The shipped processing with ``[products.detection] threshold_db`` set."""
    out = cache / f"processing-threshold-{threshold_db:g}.toml"
    out.write_text(_replace_keys(PROCESSING.read_text(), "products.detection",
                                 {"threshold_db": f"{threshold_db:.1f}"}, PROCESSING))
    return out


def at_threshold(cache: Path, threshold_db: float | None) -> dict:
    """Targets detected and false alarms of the sand fields' run contacts with the
    shipped floor (None) or ``threshold_db``."""
    out = {"threshold_db": threshold_db, "fields": {}}
    for name, tag in FIELDS:
        if threshold_db is None:
            tiles = processed(name, cache, PROCESSING, tag, False)
        else:
            tiles = processed(name, cache, floor_processing(threshold_db, cache),
                              f"{tag}-floor{threshold_db:g}", False)
        s = score_tiles(tiles, ROOT / "config" / "scenes" / f"{name}.toml")["summary"]
        out["fields"][name] = {"targets": s["truth"], "detected": s["hits"],
                               "false_alarms": s["false_alarms"]}
    f = out["fields"].values()
    out.update(targets=sum(v["targets"] for v in f), detected=sum(v["detected"] for v in f),
               false_alarms=sum(v["false_alarms"] for v in f))
    log.info("floor %s dB: %d of %d targets detected, %d false alarm(s)",
             "shipped" if threshold_db is None else f"{threshold_db:g}", out["detected"],
             out["targets"], out["false_alarms"])
    return out


def low_processing(cache: Path) -> Path:
    """The shipped processing with the floor at LOW_FLOOR_DB and the layers' clutter
    rate at LOW_LAYER_RATE."""
    out = cache / f"processing-low-{LOW_FLOOR_DB:g}.toml"
    out.write_text(_replace_keys(PROCESSING.read_text(), "products.detection",
                                 {"threshold_db": f"{LOW_FLOOR_DB:.1f}",
                                  "layer_false_alarms_per_m3": f"{LOW_LAYER_RATE:g}"},
                                 PROCESSING))
    return out


def floor_curve(tiles: dict[str, Path], track_m: dict[str, float]) -> list[dict]:
    """Per floor of CURVE_FLOORS_DB, the fields' run contacts of the low processing
    (name: tiles folder) at or over it scored again (``score_tiles`` with
    ``min_excess_db``, so that a target whose nearest contact falls under the floor
    can still be found by another): the targets detected, the false alarms, those
    called man-made, and the false alarms per 100 m of the fields' ``track_m``."""
    rows = []
    length = sum(track_m[n] for n in tiles)
    for floor in CURVE_FLOORS_DB:
        det = tot = fa = fa_manmade = 0
        for name, folder in tiles.items():
            rep = score_tiles(folder, ROOT / "config" / "scenes" / f"{name}.toml",
                              min_excess_db=float(floor))
            tot += rep["summary"]["truth"]
            det += rep["summary"]["hits"]
            alarms = [d for d in rep["detections"] if d.get("status") == "false alarm"]
            fa += len(alarms)
            fa_manmade += sum(int(d.get("class", -2)) == 1 for d in alarms)
        rows.append({"floor_db": round(float(floor), 2), "targets": int(tot),
                     "detected": int(det), "false_alarms": fa,
                     "false_alarms_called_manmade": fa_manmade,
                     "false_alarms_per_100m": round(100.0 * fa / length, 1)})
    return rows


def curves(cache: Path) -> dict:
    """floor_curve per sediment of CURVE_FIELDS, each field processed once with
    low_processing (cached under a tag of that file's contents)."""
    proc = low_processing(cache)
    tag = f"low{LOW_FLOOR_DB:g}-{hashlib.sha256(proc.read_bytes()).hexdigest()[:8]}"
    interval = load(HardwareConfig, config_path("hardware.toml")).sequencer.ping_interval_s
    out = {"low_floor_db": LOW_FLOOR_DB, "low_layer_rate_per_m3": LOW_LAYER_RATE}
    for sediment, names in CURVE_FIELDS:
        folders, track_m = {}, {}
        for name in names:
            folders[name] = processed(name, cache, proc, tag, False)
            track = load_scene(ROOT / "config" / "scenes" / f"{name}.toml").track
            track_m[name] = track.n_pings * track.speed_m_s * interval
        out[sediment] = {"fields": list(names), "track_m": round(sum(track_m.values()), 1),
                         "rows": floor_curve(folders, track_m)}
        for r in out[sediment]["rows"]:
            log.info("%s, floor %.1f dB: %d of %d detected, %d false alarms (%d called "
                     "man-made; %.1f per 100 m)", sediment, r["floor_db"], r["detected"],
                     r["targets"], r["false_alarms"], r["false_alarms_called_manmade"],
                     r["false_alarms_per_100m"])
    return out


def tile_levels(path: Path, targets: np.ndarray, box) -> tuple[list[float], float | None]:
    """(each target's maximum level inside this tile, dB, for the targets it holds; the
    clutter's maximum, dB, or None) of one tile, the power averaged over ``box``."""
    with h5py.File(path, "r") as f:
        a, c, d = (f[k][:] for k in ("along", "cross", "depth"))
        img = np.abs(f["image"][:])
        bg = f["background"][:]
        cov = f["coverage_pings"][:]
        full = f["coverage_full_pings"][:]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = (img / bg) ** 2
    p[~np.isfinite(p)] = 0.0
    level = 10.0 * np.log10(np.maximum(uniform_filter(p.astype(np.float32), size=box,
                                                      mode="nearest"), 1e-12))
    ok = ((cov >= 0.5 * full[None, None, :])
          & (d[None, None, :] >= DEPTHS_M[0]) & (d[None, None, :] <= DEPTHS_M[1]))
    near = np.zeros(level.shape[:2], dtype=bool)
    found = []
    for t in targets:
        ia = np.flatnonzero(np.abs(a - t[0]) <= TARGET_RADIUS_M)
        ic = np.flatnonzero(np.abs(c - t[1]) <= TARGET_RADIUS_M)
        iz = np.flatnonzero(np.abs(d - t[2]) <= TARGET_RADIUS_M)
        if ia.size and ic.size and iz.size:
            found.append(float(level[ia[0]:ia[-1] + 1, ic[0]:ic[-1] + 1,
                                     iz[0]:iz[-1] + 1].max()))
        near |= ((np.abs(a - t[0]) <= CLEAR_M)[:, None]
                 & (np.abs(c - t[1]) <= CLEAR_M)[None, :])
    mask = ok & ~near[:, :, None]
    return found, (float(level[mask].max()) if mask.any() else None)


def main() -> None:
    args = line_args(__doc__)
    rows = []
    for box in BOXES:
        targets_db, clutter_db = [], []
        for name, tag in FIELDS:
            tiles = processed(name, args.cache, PROCESSING, tag, False)
            scene = tomllib.loads((ROOT / "config" / "scenes" / f"{name}.toml").read_text())
            truth = np.array([[t["along_m"], t["cross_m"], t["depth_m"]]
                              for t in scene["targets"]])
            best: dict[int, float] = {}
            for path in sorted(tiles.glob("tile_*.h5")):
                found, clutter = tile_levels(path, truth, box)
                if clutter is not None:
                    clutter_db.append(clutter)
                # a target in two tiles: its brighter tile
                held = [i for i, t in enumerate(truth) if _in_tile(path, t)]
                for i, v in zip(held, found):
                    best[i] = max(best.get(i, -np.inf), v)
            targets_db += list(best.values())
        t = np.sort(targets_db)
        row = {"box_voxels": list(box), "targets_db_sorted": [round(float(v), 2) for v in t],
               "clutter_tile_max_db": [round(v, 2) for v in sorted(clutter_db)],
               "weakest_targets_db": [round(float(v), 2) for v in t[:5]],
               "clutter_max_db": round(max(clutter_db), 2) if clutter_db else None,
               "targets_over_clutter_median": int(np.sum(t > np.median(clutter_db)))
               if clutter_db else None}
        rows.append(row)
        log.info("box %s: weakest targets %s dB; clutter per tile %s dB (%d of %d targets "
                 "over the tiles' median clutter maximum)", box, row["weakest_targets_db"],
                 row["clutter_tile_max_db"], row["targets_over_clutter_median"], t.size)
    floors = [at_threshold(args.cache, None)] + [at_threshold(args.cache, t)
                                                  for t in THRESHOLDS_DB]
    if args.out:
        args.out.write_text(json.dumps({"machine": machine_isa(),
                                        "command": " ".join(["python"] + sys.argv),
                                        "fields": [f for f, _ in FIELDS], "rows": rows,
                                        "floors": floors, "curve": curves(args.cache)},
                                       indent=1))


def _in_tile(path: Path, t) -> bool:
    """Whether the tile's box holds the target's position within TARGET_RADIUS_M."""
    with h5py.File(path, "r") as f:
        return all(np.any(np.abs(f[k][:] - x) <= TARGET_RADIUS_M)
                   for k, x in zip(("along", "cross", "depth"), t))


if __name__ == "__main__":
    main()
