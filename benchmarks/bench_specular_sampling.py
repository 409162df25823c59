#!/usr/bin/env python
"""How well the survey samples a long object's specular echo: the image peak of one
61 cm aluminium cylinder (15.2 cm diameter, centre 25 cm deep in medium sand, axis 150
deg from the track, 0.3 m off the track's centre line) at seven positions along the
track, through every phase of the projector cycle, at 1 m/s and at 0.5 m/s (10 pings/s,
the six projectors in turn).

A cylinder returns its body's echo only to projector-receiver pairs whose bisector lies
in the plane normal to its axis: over the aperture that is a narrow lobe (about
lambda / L wide). With one projector a ping, a projector repeats every 0.6 m of track at
1 m/s: where the cylinder lies relative to the projector cycle decides whether any pair
catches the lobe. The spread of its peak over positions (one cylinder per position,
the seabed silent so that only the target and the noise are in the image) measures the
effect; the sediment's speed is configured (known).

    python benchmarks/bench_specular_sampling.py --cache /tmp/bench_specular --out benchmarks/results/bench_specular_sampling.json
"""

from __future__ import annotations

import json
import logging
import re
import sys
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_classify import known_processing  # noqa: E402
from bench_false_alarms import _run, line_args  # noqa: E402
from bench_isa import machine_isa  # noqa: E402

log = logging.getLogger("bench_specular_sampling")

BASE = ROOT / "config" / "scenes" / "classify_test_sand.toml"
#: 2.3 m apart: 2.3 m is 0.5 m past a whole number of 0.6 m projector cycles (at 1 m/s),
#: so the positions step through every 0.1 m phase of the cycle (x mod 0.6: 0.2, 0.1,
#: 0.0, 0.5, 0.4, 0.3, 0.2): each projector's turn nearest the cylinder at least once
POSITIONS_M = (5.0, 7.3, 9.6, 11.9, 14.2, 16.5, 18.8)
CROSS_M, DEPTH_M, HEADING_DEG = -0.3, 0.25, 150.0
SPEEDS = {"1.0": (1.0, 200), "0.5": (0.5, 400)}      # m/s: (speed, pings over 20 m)


def scene_text(speed: float, pings: int) -> str:
    """The sand test field's settings with the seabed's scattering off, the given speed
    and pings, and one cylinder at each of :data:`POSITIONS_M`."""
    head = BASE.read_text().split("[[targets]]", 1)[0]
    for key, value in (("interface", "false"), ("volume", "false"),
                       ("speed_m_s", f"{speed}"), ("n_pings", f"{pings}")):
        head, n = re.subn(rf"(?m)^{key} = [^#\n]*", f"{key} = {value}", head, count=1)
        if n != 1:
            raise ValueError(f"{BASE}: no '{key}' line")
    body = "".join(
        f'\n[[targets]]\nkind = "cylinder"\nmaterial = "aluminium"\nalong_m = {x}\n'
        f"cross_m = {CROSS_M}\ndepth_m = {DEPTH_M}\nradius_m = 0.076\nlength_m = 0.61\n"
        f"axis_heading_deg = {HEADING_DEG}\naxis_tilt_deg = 0.0\n"
        f'description = "61 cm cylinder at {x} m"\n' for x in POSITIONS_M)
    return head + body


def peaks(tiles: Path) -> list[dict]:
    """The image's peak (dB re 1 count, and where) within 0.5 m of each cylinder."""
    out = []
    for x in POSITIONS_M:
        for t in sorted(tiles.glob("tile_*.h5")):
            with h5py.File(t, "r") as f:
                a, c, d = f["along"][:], f["cross"][:], f["depth"][:]
                if not a[0] <= x <= a[-1]:
                    continue
                ia = np.flatnonzero(np.abs(a - x) < 0.5)
                ic = np.flatnonzero(np.abs(c - CROSS_M) < 0.5)
                iz = np.flatnonzero(d > -0.15)
                img = np.abs(f["image"][ia[0]:ia[-1] + 1, ic[0]:ic[-1] + 1, iz[0]:])
            k = np.unravel_index(int(np.argmax(img)), img.shape)
            out.append({"along_m": x, "cycle_phase_m": round(x % 0.6, 3),
                        "peak_db": float(20 * np.log10(img.max())),
                        "at_m": [float(a[ia[0] + k[0]]), float(c[ic[0] + k[1]]),
                                 float(d[iz[0] + k[2]])]})
            break
    return out


def main() -> None:
    args = line_args(__doc__)
    proc = known_processing("classify_test_sand", args.cache)
    result = {"machine": machine_isa(), "command": " ".join(["python"] + sys.argv),
              "cylinder": {"length_m": 0.61, "radius_m": 0.076, "depth_m": DEPTH_M,
                           "cross_m": CROSS_M, "axis_heading_deg": HEADING_DEG},
              "speeds": {}}
    for name, (speed, pings) in SPEEDS.items():
        scene = args.cache / f"cylinders-{name}.toml"
        scene.write_text(scene_text(speed, pings))
        raw, tiles = args.cache / f"cylinders-{name}.h5", args.cache / f"cylinders-{name}"
        _run([sys.executable, "-m", "svss", "simulate", "--scene", str(scene), "--out",
              str(raw), "--force"], args.cache / f"cylinders-{name}.simulate.log")
        _run([sys.executable, "-m", "svss", "process", str(raw), "--out", str(tiles),
              "--processing", str(proc), "--force"], args.cache / f"cylinders-{name}.log")
        p = peaks(tiles)
        levels = [q["peak_db"] for q in p]
        spread = max(levels) - min(levels)
        result["speeds"][name] = {"speed_m_s": speed, "pings": pings, "peaks": p,
                                  "spread_db": spread}
        log.info("%s m/s: peaks %s dB; spread over positions %.1f dB", name,
                 ", ".join(f"{v:.1f}" for v in levels), spread)
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
