#!/usr/bin/env python
"""Buried objects at their depth and in focus without knowing the seabed: the sediment
speed estimated from the echoes against the shipped configuration and the truth.

Each scene of ``config/scenes/seabed_*.toml`` (sand, silt, silt over sand, silt over
stiff clay, sand sloping 3 deg along and 5 deg across: buried -20 dB points at 0.35-1.6 m and the seed's aluminium cylinder under an
11 m line, interface and volume scattering, the sea surface's multipath) is simulated
once into ``--cache`` as a raw run (as ``svss simulate`` records it), then:

* the sediment speed (and the interface's slope) is estimated from the run's echoes
  and navigation with the shipped
  ``config/processing.toml`` (:func:`svss_proc.seabed.stage.seabed_stage`, what
  ``svss process`` does);
* every target is imaged three ways, exactly as the tiles image it: (a) with the shipped
  configuration as it stands (1500 m/s, one half-space), (b) with the estimate, (c) with
  the scene's true layers, speeds and slope;
* per target: the depth of its peak (a point: against its depth; the cylinder: against
  its top) and its peak level against (c); per scene the estimated speeds against the
  truth.

A target is imaged on a 2 cm column about it (from 0.75 to 1.25 times the depth its
peak belongs at, and 5 cm more: a wrong speed moves it by up to about 20 %; 1 cm in
depth), then on a 5 mm grid about that column's peak; the peak's depth is refined by a
parabola.

    python benchmarks/bench_seabed.py --cache /tmp/bench_seabed --out benchmarks/results/bench_seabed.json
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_isa import machine_isa  # noqa: E402
from sim_device.environment_source import EnvironmentSource  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from svss_daq.config import (HardwareConfig, ProcessingConfig, SedimentLayerConfig,  # noqa: E402
                             config_path, load_with_text)
from svss_daq.rawfile import RawRunReader  # noqa: E402
from svss_proc.imaging.imager import PingAccumulator, TileImager  # noqa: E402
from svss_proc.imaging.sampler import PointSampler  # noqa: E402
from svss_proc.seabed.stage import RunPings, seabed_stage  # noqa: E402

log = logging.getLogger("bench_seabed")

SCENES = ("seabed_sand", "seabed_silt", "seabed_silt_over_sand", "seabed_silt_over_clay",
          "seabed_sand_sloping", "seabed_sand_undulating")

#: the true relief's nodes for the truth's image (c), m: fine enough that bilinear
#: interpolation between them is exact to a fraction of a millimetre
TRUE_RELIEF_STEP_M = 0.05


def recorded(scene: str, cache: Path) -> Path:
    """The scene's raw run, simulated once into ``cache`` by ``svss simulate``."""
    run = cache / f"{scene}.h5"
    if not run.is_file():
        cache.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "svss", "simulate", "--scene",
                        str(config_path(f"scenes/{scene}.toml")), "--out", str(run)],
                       check=True, cwd=ROOT)
        log.info("%s: simulated in %.0f s", scene, time.perf_counter() - t0)
    return run


def scene_relief(src: EnvironmentSource, line, along, cross) -> np.ndarray:
    """The scene's undulation (m, below its plane) at the nodes ``along`` x ``cross`` of
    the processing's tile frame ``line`` (a :class:`~svss_daq.frames.TrackLine`)."""
    a, c = np.meshgrid(along, cross, indexing="ij")
    ned = line.tile_to_ned(np.stack([a, c, np.zeros_like(a)], axis=-1))
    scene = src.line.ned_to_tile(ned)
    return src.undulation.height(scene[..., 0], scene[..., 1])


def true_processing(proc: ProcessingConfig, src: EnvironmentSource,
                    line=None) -> ProcessingConfig:
    """``proc`` imaging through the scene's own layers, speeds, slope and relief (in the
    processing's tile frame ``line``)."""
    import dataclasses
    speeds = [float(c) for c in np.real(src.media.c[1:])]
    layers = tuple(SedimentLayerConfig(thickness_m=float(layer.thickness_m),
                                       sound_speed_m_s=c)
                   for layer, c in zip(src.scene.seabed.layers[:-1], speeds[:-1]))
    slope = src.scene.seabed.slope_deg or (0.0, 0.0)
    relief = {}
    if src.undulation is not None:
        along = np.arange(-3.0, src.scene.track.n_pings * 0.1 + 3.0, TRUE_RELIEF_STEP_M)
        cross = np.arange(-4.0, 4.0 + 1e-9, TRUE_RELIEF_STEP_M)
        nodes = scene_relief(src, line, along, cross)
        relief = {"interface_relief_m": tuple(tuple(float(v) for v in row) for row in nodes),
                  "interface_relief_origin_m": (float(along[0]), float(cross[0])),
                  "interface_relief_step_m": (TRUE_RELIEF_STEP_M, TRUE_RELIEF_STEP_M)}
    return dataclasses.replace(proc, imaging=dataclasses.replace(
        proc.imaging, sediment_sound_speed_m_s=speeds[-1], sediment_layers=layers,
        delays="table", interface_slope_deg=tuple(float(v) for v in slope), **relief))


def relief_error(estimate: dict, src: EnvironmentSource, line) -> float | None:
    """The estimated relief's rms error (m) against the scene's at its nodes about the
    targets (within 1 m along of the first and last, 0.5 m across of the track), after
    their means are removed (the relief is known up to one constant: module docs of
    :mod:`svss_proc.seabed.relief`); None where none was estimated."""
    nodes = estimate.get("interface_relief_m")
    if not nodes or src.undulation is None:
        return None
    nodes = np.asarray(nodes)
    a0, c0 = estimate["interface_relief_origin_m"]
    da, dc = estimate["interface_relief_step_m"]
    ga = a0 + da * np.arange(nodes.shape[0])
    gc = c0 + dc * np.arange(nodes.shape[1])
    truth = scene_relief(src, line, ga, gc)
    along = [t["along"] for t in targets_of(src.scene)]
    near = (((ga >= min(along) - 1.0) & (ga <= max(along) + 1.0))[:, None]
            & (np.abs(gc) <= 0.5)[None, :])
    err = nodes[near] - truth[near]
    return float(np.sqrt(np.mean((err - err.mean()) ** 2)))


def targets_of(scene) -> list[dict]:
    """The scene's buried points and targets: name, position (tile frame), the depth a
    peak belongs at (a point's; a target's top)."""
    out = [{"name": f"point {i}", "kind": "point", "along": p.along_m, "cross": p.cross_m,
            "depth": p.depth_m, "expected": p.depth_m} for i, p in enumerate(scene.points)]
    for i, t in enumerate(scene.targets):
        out.append({"name": f"{t.kind} {i}", "kind": t.kind, "along": t.along_m,
                    "cross": t.cross_m, "depth": t.depth_m,
                    "expected": t.depth_m - t.radius_m})
    return out


def peak(sampler: PointSampler, pings, target: dict) -> tuple[float, float]:
    """(peak magnitude, its depth m) of a target's image (module docstring)."""
    a, c = target["along"], target["cross"]
    ax = np.arange(-0.1, 0.1 + 1e-9, 0.02)
    e = target["expected"]                   # a wrong speed moves it by up to ~20 %
    depth = np.arange(max(0.75 * e - 0.05, 0.1), 1.25 * e + 0.05 + 1e-9, 0.01)
    col = np.abs(sampler.grid(pings, a + ax, c + ax, depth))
    i, j, k = np.unravel_index(int(np.argmax(col)), col.shape)
    fine = np.arange(-0.02, 0.02 + 1e-9, 0.005)
    fz = depth[k] + np.arange(-0.03, 0.03 + 1e-9, 0.005)
    box = np.abs(sampler.grid(pings, a + ax[i] + fine, c + ax[j] + fine, fz))
    i, j, k = np.unravel_index(int(np.argmax(box)), box.shape)
    z = float(fz[k])
    if 0 < k < fz.size - 1:
        y = np.log(box[i, j, k - 1:k + 2])
        den = y[0] - 2 * y[1] + y[2]
        if den < 0:
            z += 0.005 * 0.5 * (y[0] - y[2]) / den
    return float(box[i, j, k]), z


def measure_scene(scene_name: str, cache: Path) -> dict:
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    shipped = load_with_text(ProcessingConfig, config_path("processing.toml"))
    scene = load_scene(config_path(f"scenes/{scene_name}.toml"))
    src = EnvironmentSource(hw, scene)
    run = recorded(scene_name, cache)
    out = {"scene": scene_name, "description": scene.scene.description}
    with RawRunReader(run) as reader:
        t0 = time.perf_counter()
        used, est = seabed_stage([reader], None, shipped, "estimate")
        out["estimate_s"] = round(time.perf_counter() - t0, 1)
        out["estimate"] = est.summary()
        pings = list(RunPings([reader]))
        imager = TileImager(hw, shipped.value)
        imager.add(pings[0])
        line = imager.line
        truth = true_processing(shipped.value, src, line)
        und = src.undulation
        out["truth"] = {"speeds_m_s": [float(c) for c in np.real(src.media.c[1:])],
                        "thicknesses_m": [lay.thickness_m for lay in scene.seabed.layers[:-1]],
                        "interface_slope_deg": list(scene.seabed.slope_deg or (0.0, 0.0)),
                        "interface_relief_rms_m": None if und is None else float(np.std(
                            np.asarray(truth.imaging.interface_relief_m)))}
        out["relief_error_rms_m"] = relief_error(out["estimate"], src, line)
        variants = {"shipped": shipped.value, "estimate": used.value, "truth": truth}
        prepared: dict = {}
        rows = []
        for t in targets_of(scene):
            row = {k: t[k] for k in ("name", "kind", "along", "cross", "depth", "expected")}
            for name, proc in variants.items():
                s = PointSampler(PingAccumulator(hw, proc), proc, line, prepared)
                near = [p for p in pings if abs(s.reach(p)[0] - t["along"]) <= s.reach(p)[1]]
                level, z = peak(s, near, t)
                row[name] = {"level": level, "depth_m": z,
                             "depth_error_m": z - t["expected"]}
            prepared.clear()
            for name in ("shipped", "estimate"):
                row[name]["level_db"] = 20 * math.log10(row[name]["level"]
                                                        / row["truth"]["level"])
            rows.append(row)
            log.info("%s %s (%.2f m): depth error shipped %+.3f estimate %+.3f truth %+.3f m; "
                     "level shipped %+.2f estimate %+.2f dB", scene_name, t["name"],
                     t["expected"], row["shipped"]["depth_error_m"],
                     row["estimate"]["depth_error_m"], row["truth"]["depth_error_m"],
                     row["shipped"]["level_db"], row["estimate"]["level_db"])
        out["targets"] = rows
    pts = [r for r in rows if r["kind"] == "point"]
    tol = [0.02 + 0.02 * r["expected"] for r in pts]
    out["verdict"] = {
        "depth_ok": all(abs(r["estimate"]["depth_error_m"]) <= t for r, t in zip(pts, tol)),
        "mean_loss_db": float(np.mean([-r["estimate"]["level_db"] for r in rows])),
        "worst_loss_db": float(np.max([-r["estimate"]["level_db"] for r in rows])),
        "speed_error_pct": 100 * (est.speed_m_s / out["truth"]["speeds_m_s"][-1] - 1),
        "slope_error_deg": [None if e is None else e - t for e, t in zip(
            out["estimate"].get("interface_slope_deg", [None, None]),
            out["truth"]["interface_slope_deg"])]}
    return out


def table(results: list[dict]) -> str:
    lines = []
    for r in results:
        e, tr = r["estimate"], r["truth"]
        lay = "".join(f"{x['thickness_m']:.2f} m at {x['speed_m_s']:.0f} +/- "
                      f"{x['sigma_m_s']:.0f} over " for x in e["layers"])
        true_lay = "".join(f"{d:.2f} m at {c:.0f} over " for d, c in
                           zip(tr["thicknesses_m"], tr["speeds_m_s"]))
        lines.append(f"{r['scene']}: estimated {lay}{e['sediment_sound_speed_m_s']} +/- "
                     f"{e['sigma_m_s']} m/s ({e['status']}; truth {true_lay}"
                     f"{tr['speeds_m_s'][-1]:.0f} m/s) in {r['estimate_s']} s")
        if e.get("interface_slope_deg") is not None:
            sl, sg = e["interface_slope_deg"], e["interface_slope_sigma_deg"]
            lines.append("  interface slope along {} across {} deg (truth {:+.1f}, {:+.1f})"
                         .format(*(f"{a:+.2f}" + (f" +/- {b:.2f}" if b is not None else "")
                                   for a, b in zip(sl, sg)), *tr["interface_slope_deg"]))
        if e.get("interface_relief") is not None:
            truth_rms = tr.get("interface_relief_rms_m")
            lines.append("  interface relief {}: rms {:.1f} cm (truth {}){}".format(
                "kept" if e["interface_relief"] else "not kept",
                100 * (e.get("interface_relief_rms_m") or 0.0),
                "none" if truth_rms is None else f"{100 * truth_rms:.1f} cm",
                "" if r.get("relief_error_rms_m") is None
                else f", error {100 * r['relief_error_rms_m']:.1f} cm rms"))
        lines.append("  target      depth   err shipped  err estimate  err truth  "
                     "level shipped  level estimate")
        for t in r["targets"]:
            lines.append(f"  {t['name']:<10} {t['expected']:6.2f}  "
                         f"{100 * t['shipped']['depth_error_m']:+8.1f} cm "
                         f"{100 * t['estimate']['depth_error_m']:+9.1f} cm "
                         f"{100 * t['truth']['depth_error_m']:+7.1f} cm "
                         f"{t['shipped']['level_db']:+10.2f} dB "
                         f"{t['estimate']['level_db']:+11.2f} dB")
        v = r["verdict"]
        lines.append(f"  depths within 2 cm + 2 %: {v['depth_ok']}; peak loss mean "
                     f"{v['mean_loss_db']:.2f} dB, worst {v['worst_loss_db']:.2f} dB; "
                     f"half-space speed error {v['speed_error_pct']:+.1f} %")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--cache", default="/tmp/bench_seabed", help="raw runs, simulated once")
    ap.add_argument("--out", default="bench_seabed.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    for name in ("numba", "sim_device", "svss_proc.imaging.schedule"):
        logging.getLogger(name).setLevel(logging.WARNING)
    results = [measure_scene(s, Path(args.cache)) for s in args.scenes.split(",")]
    doc = {"command": " ".join(["python", *sys.argv]), "machine": machine_isa(),
           "date": time.strftime("%Y-%m-%d"), "results": results}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1))
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
