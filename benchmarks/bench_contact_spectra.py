#!/usr/bin/env python
"""Resonance lines from the pings (docs/contact_features.md, "Resonance lines from the
pings") on a shell and a rock buried alike: config/scenes/shell_slab_silt.toml and
shell_slab_sand.toml (a TNT-filled steel shell, 15.2 cm, 8 mm wall, and a granite slab
30 cm across, 8 cm thick, flat, both centres 20 cm deep), simulated once into
``--cache`` and processed by ``svss process`` with the shipped configuration.

For each target's contact: the columns ``svss process`` wrote (the shipped window,
``[products.spectra]``), and the same measured from the recorded pings with the window
starting later (``--late-start``: the slab's own response is over by then, a ringing
shell's not); for a shell, the peaks of its monostatic form function in the band from
the simulator's modal series (the line should sit at one); and the same at empty points
of the seabed (no target within a metre), the background's own figures. The cost, side
by side: ``svss process`` with the shipped configuration and with ``[products.spectra]``
left out, and the spectra step's own time from its log line.

    python benchmarks/bench_contact_spectra.py --cache /tmp/bench_spectra --out benchmarks/results/bench_contact_spectra.json
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_false_alarms import _run, simulated_line  # noqa: E402
from bench_isa import machine_isa  # noqa: E402

log = logging.getLogger("bench_contact_spectra")

SCENES = ("shell_slab_silt", "shell_slab_sand")
#: points of the seabed with no target within a metre (along, cross, depth), m, where
#: the array passes (its receivers 2.7 m ahead of the body: 2.7-10.6 m along)
EMPTY = ((3.5, 0.0, 0.2), (6.75, 0.0, 0.2), (6.75, 0.5, 0.3), (9.5, 0.0, 0.2))
COLUMNS = ("late_over_background_db", "resonance_hz", "resonance_err_hz",
           "resonance_width_hz", "resonance_width_err_hz", "resonance_pings")


def shell_peaks(target) -> list[float]:
    """Local maxima of a shell's |f(pi)| in 20-35 kHz (the simulator's modal series in
    its host), Hz."""
    from sim_device.targets.shells import shell_backscatter
    f = np.arange(19000.0, 36000.0, 25.0)
    a = np.abs(shell_backscatter(f, target.radius, target.thickness, target.host,
                                 target.material, target.fill))
    k = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])) + 1
    return [float(x) for x in f[k] if 20000.0 <= x <= 35000.0]


def remeasured(raw: Path, tiles: Path, points: list[tuple], start_s: float) -> list[dict]:
    """The spectra columns at ``points`` (run frame) from the recorded pings, the window
    starting ``start_s`` after the arrival, with the processing the tiles were made
    with (their provenance)."""
    from svss_daq.config import ProcessingConfig, loads
    from svss_daq.rawfile import RawRunReader
    from svss_proc.products.run_spectra import run_spectra
    from svss_proc.products.run_views import load_views
    views = load_views(tiles)
    proc = loads(ProcessingConfig, views[0].data["processing_config_toml"],
                 f"{views[0].path}:/provenance/processing_config_toml")
    cfg = dataclasses.replace(proc.products.spectra, start_s=start_s,
                              min_over_background_db=-100.0)      # every line shown
    contacts = [{"along_m": a, "cross_m": c, "depth_below_seabed_m": d} for a, c, d in points]
    with RawRunReader(raw) as run:
        return run_spectra(iter(run), run.hardware, proc, cfg, contacts, views[0].line)


def without_spectra(cache: Path) -> Path:
    """The shipped processing with its ``[products.spectra]`` table left out."""
    text = (ROOT / "config" / "processing.toml").read_text()
    start = text.index("[products.spectra]")
    end = text.find("\n[", start + 1)
    out = cache / "processing-no-spectra.toml"
    out.write_text(text[:start] + (text[end + 1:] if end >= 0 else ""))
    return out


def step_seconds(log_path: Path) -> float | None:
    """The spectra step's time from ``svss process``'s log ("resonance lines of ... in
    X s")."""
    for line in log_path.read_text().splitlines():
        if "resonance lines of" in line and line.rstrip().endswith(" s"):
            return float(line.rstrip()[:-2].rsplit(" in ", 1)[1])
    return None


def one_scene(name: str, cache: Path, late_start: float) -> dict:
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    raw = simulated_line(name, cache)
    tiles = cache / f"{name}-tiles"
    took = _run([sys.executable, "-m", "svss", "process", str(raw), "--out", str(tiles),
                 "--force"], cache / f"{name}.process.log")
    took_off = _run([sys.executable, "-m", "svss", "process", str(raw), "--out",
                     str(cache / f"{name}-tiles-off"), "--force", "--processing",
                     str(without_spectra(cache))], cache / f"{name}.process-off.log")
    scene = load_scene(ROOT / "config" / "scenes" / f"{name}.toml")
    targets = EnvironmentSource(load_with_text(HardwareConfig, config_path("hardware.toml")),
                                scene).targets
    with open(tiles / "contacts.csv") as fh:
        contacts = list(csv.DictReader(fh))
    rows, points = [], []
    for t in targets:
        near = min(contacts, key=lambda c: math.hypot(float(c["along_m"]) - t.cfg.along_m,
                                                      float(c["cross_m"]) - t.cfg.cross_m),
                   default=None)
        d = None if near is None else math.hypot(float(near["along_m"]) - t.cfg.along_m,
                                                 float(near["cross_m"]) - t.cfg.cross_m)
        row = {"target": t.cfg.description, "kind": t.kind, "truth_m": list(t.position)}
        if d is None or d > 0.5:
            row["status"] = "missed"
        else:
            row["status"] = "detected"
            row["contact_m"] = [float(near[k]) for k in ("along_m", "cross_m",
                                                         "depth_below_seabed_m")]
            row["shipped"] = {k: float(near[k]) if near[k] != "" else None for k in COLUMNS}
            points.append(tuple(row["contact_m"]))
        if t.kind == "shell":
            row["model_peaks_hz"] = shell_peaks(t)
        rows.append(row)
    late = remeasured(raw, tiles, points + list(EMPTY), late_start)
    # the empty points in the shipped window (every line shown: no threshold)
    shipped_empty = remeasured(raw, tiles, list(EMPTY), _shipped_start())
    k = 0
    for row in rows:
        if row["status"] == "detected":
            row["late_window"] = late[k]
            k += 1
    empty = [{"at_m": list(p), "shipped": s, "late_window": lt}
             for p, s, lt in zip(EMPTY, shipped_empty, late[k:])]
    return {"scene": name, "process_s": round(took, 1),
            "process_without_spectra_s": round(took_off, 1),
            "spectra_step_s": step_seconds(cache / f"{name}.process.log"),
            "targets": rows, "empty": empty}


def _shipped_start() -> float:
    from svss_daq.config import ProcessingConfig, config_path, load
    return load(ProcessingConfig, config_path("processing.toml")).products.spectra.start_s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--late-start", type=float, default=5e-4,
                    help="the later window's start after the arrival, s (default 5e-4)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s",
                        datefmt="%H:%M:%S")
    args.cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    out = {"machine": machine_isa(), "command": " ".join(["python"] + sys.argv),
           "late_start_s": args.late_start,
           "scenes": [one_scene(n, args.cache, args.late_start) for n in SCENES],
           "wall_s": None}
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    for s in out["scenes"]:
        log.info("%s: svss process %.1f s, without the spectra %.1f s (ratio %.3f); the "
                 "step %s s", s["scene"], s["process_s"], s["process_without_spectra_s"],
                 s["process_s"] / s["process_without_spectra_s"], s["spectra_step_s"])
        for r in s["targets"] + s["empty"]:
            what = r.get("kind", f"empty {r.get('at_m')}")
            sh, lt = r.get("shipped"), r.get("late_window")
            log.info("%s %s: shipped %s; late %s", s["scene"], what,
                     None if sh is None else {k: sh[k] for k in COLUMNS[:4]},
                     None if lt is None else {k: lt[k] for k in COLUMNS[:2]})
    text = json.dumps(out, indent=1, default=float)
    if args.out:
        args.out.write_text(text + "\n")
    else:
        print(text)


if __name__ == "__main__":
    main()
