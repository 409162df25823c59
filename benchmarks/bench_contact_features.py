#!/usr/bin/env python
"""Each contact's features (docs/contact_features.md) on simulated shells and rocks:
the tail below the object (extent, decay), late-to-specular ratio and aspect over the
aperture of every true target, as the products measure them.

Each scene is simulated once into ``--cache`` (``svss simulate``) and processed with
``svss process`` (``config/processing.toml``, or the scene's own configuration below);
the run's contacts are matched to the scene's targets (:func:`svss.score.score_tiles`)
and each target's features are those of its contact. A target that is no contact is
measured all the same, at its image's peak (the largest level within 0.15 m
horizontally and 0.15 m in depth of its centre, a 0.1 m footprint), and marked so.

    python benchmarks/bench_contact_features.py --cache /tmp/bench_contact_features --out benchmarks/results/bench_contact_features.json
"""

from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_false_alarms import _run, line_args, simulated_line  # noqa: E402
from bench_isa import machine_isa  # noqa: E402
from svss.score import score_tiles  # noqa: E402
from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load  # noqa: E402
from svss_proc.products import detect  # noqa: E402
from svss_proc.products.contact_features import (FEATURE_NAMES, contact_features,  # noqa: E402
                                                 flags_text)
from svss_proc.tiles import read_tile  # noqa: E402

log = logging.getLogger("bench_contact_features")

#: (scene, processing overrides: the sediment's speed where the echoes do not give it)
SCENES = (("shell_slab_silt", {}), ("shell_slab_sand", {"sand": True}),
          ("ordnance_field", {}))


def sand_processing(cache: Path) -> Path:
    """config/processing.toml imaging at medium sand's 1767 m/s, configured (the sand
    scene has no isolated buried point for the speed's estimate)."""
    text = (ROOT / "config" / "processing.toml").read_text()
    text = text.replace("sediment_sound_speed_m_s = 1500.0", "sediment_sound_speed_m_s = 1767.0")
    text = text.replace('speed = "estimate"', 'speed = "configured"')
    out = cache / "processing-sand.toml"
    out.write_text(text)
    return out


def at_peak(tiles_dir: Path, tile_m: dict, fcfg, k_w: float) -> dict | None:
    """The features of a target that is no contact, at its image's peak."""
    name, pos = next(iter(tile_m.items()))
    t = read_tile(tiles_dir / name)
    if "background" not in t:
        return None
    a, c, z = t["along"], t["cross"], t["depth"]
    with np.errstate(divide="ignore"):
        level = 20 * np.log10(np.maximum(np.abs(t["image"]), 1e-30)
                              / np.maximum(t["background"], 1e-30))
    ia = np.flatnonzero(np.abs(a - pos[0]) <= 0.15)
    ic = np.flatnonzero(np.abs(c - pos[1]) <= 0.15)
    iz = np.flatnonzero((np.abs(z - pos[2]) <= 0.15) & (z > -0.1))
    if not (ia.size and ic.size and iz.size):
        return None
    box = level[np.ix_(ia, ic, iz)]
    i, j, k = np.unravel_index(int(np.nanargmax(box)), box.shape)
    row = np.zeros(1, dtype=detect.DTYPE)
    row["along_m"], row["cross_m"], row["depth_m"] = a[ia[i]], c[ic[j]], z[iz[k]]
    row["extent_along_m"] = row["extent_cross_m"] = row["extent_depth_m"] = 0.1
    row["excess_db"] = box[i, j, k]
    cols = contact_features(level, (a, c, z), row, fcfg, t["image"], k_w).columns
    return {"excess_db": float(box[i, j, k]), "depth_m": float(z[iz[k]]),
            **{n: cols[n][0].item() for n in FEATURE_NAMES}}


def main() -> None:
    args = line_args(__doc__)
    svss = [sys.executable, "-m", "svss"]
    hw = load(HardwareConfig, config_path("hardware.toml"))
    rows = []
    for name, opts in SCENES:
        if args.only and name not in args.only:
            continue
        scene_path = ROOT / "config" / "scenes" / f"{name}.toml"
        raw = simulated_line(name, args.cache)
        cfg_path = sand_processing(args.cache) if opts.get("sand") \
            else ROOT / "config" / "processing.toml"
        out = args.cache / name
        secs = _run(svss + ["process", str(raw), "--out", str(out), "--processing",
                            str(cfg_path), "--force"], args.cache / f"{name}.log")
        pcfg = load(ProcessingConfig, cfg_path)
        k_w = 2 * math.pi * hw.waveform.center_hz / pcfg.imaging.water_sound_speed_m_s
        r = score_tiles(out, scene_path)
        for t in r["truth"]:
            desc = t["fields"].get("description") or t["fields"].get("kind", t["table"])
            row = {"scene": name, "target": desc, "truth_m": t["scene_m"],
                   "status": t["status"], "process_s": secs}
            if t["status"] == "detected":
                d = r["detections"][t["detection"]]
                row.update({"excess_db": d["excess_db"], "depth_m": d["depth_m"],
                            **{n: d[n] for n in FEATURE_NAMES}})
            elif "tile_m" in t:
                row["measured_at_peak"] = True
                row.update(at_peak(out, t["tile_m"], pcfg.products.features, k_w) or {})
            if "feature_flags" in row:
                row["feature_notes"] = flags_text(int(row["feature_flags"]))
            rows.append(row)
            log.info("%-16s %-62s %-9s excess %5.1f dB  tail %5.2f m  decay %6.1f +/- "
                     "%5.1f dB/m  late/spec %6.1f +/- %4.1f dB  aspect %5.1f +/- %4.1f deg "
                     "(centre %5.1f)  %s", name, desc[:62], t["status"],
                     row.get("excess_db", np.nan), row.get("tail_extent_m", np.nan),
                     row.get("tail_decay_db_per_m", np.nan),
                     row.get("tail_decay_err_db_per_m", np.nan),
                     row.get("late_to_specular_db", np.nan),
                     row.get("late_to_specular_err_db", np.nan),
                     row.get("aspect_width_deg", np.nan),
                     row.get("aspect_width_err_deg", np.nan),
                     row.get("aspect_centre_deg", np.nan), row.get("feature_notes", ""))
    if args.out:
        args.out.write_text(json.dumps({"machine": machine_isa(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
