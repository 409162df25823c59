"""One ``svss trade`` run: the workloads, the three areas, the fronts and the files."""

from __future__ import annotations

import logging
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path

from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig

from . import imaging, normalisation, report, simulation
from .workloads import imaging_workload, sediment_speed, simulation_workload

log = logging.getLogger(__name__)

AREAS = ("imaging", "simulation", "normalisation")


@dataclass
class TradeResult:
    """Rows per area (dicts: option, value, setting, time_s, tile_s, error, metrics,
    is_default, is_reference, on_front) and the run's conclusions."""
    machine: str
    budget_s: float
    quick: bool
    areas: dict[str, list[dict]] = field(default_factory=dict)
    workloads: dict[str, str] = field(default_factory=dict)
    defaults_on_front: dict[str, bool] = field(default_factory=dict)
    recommendation: dict = field(default_factory=dict)
    summary: list[str] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)


def cuda_available() -> bool:
    try:
        from numba import cuda
        return bool(cuda.is_available())
    except (ImportError, RuntimeError, OSError):   # numba-cuda missing or no driver
        return False


def machine() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    import numba
    return (f"{platform.node()}: {platform.processor() or platform.machine()}, "
            f"{os.cpu_count()} CPUs, {numba.get_num_threads()} numba threads, "
            f"load average {load:.2f} at the start, CUDA "
            f"{'available' if cuda_available() else 'not available'}")


def run_trade(hw: Loaded[HardwareConfig], proc: ProcessingConfig, out: Path, *,
              quick: bool = False, budget_s: float = 15.0,
              areas: tuple[str, ...] = AREAS) -> TradeResult:
    """Measure ``areas`` and write the table and plots to ``out``."""
    res = TradeResult(machine(), budget_s, quick)
    # the imager is restricted to one sub-tile (imaging.only_tile): its schedule's notes
    # on pings that reach only the other tiles are expected here
    for name in ("svss_proc.imaging.imager", "svss_proc.imaging.schedule"):
        logging.getLogger(name).setLevel(logging.ERROR)
    if "imaging" in areas:
        w = imaging_workload(hw, proc, quick)
        c_sed = sediment_speed(w.scene) or proc.imaging.water_sound_speed_m_s
        res.workloads["imaging"] = (f"{w.name}: pings {w.first}..{w.pings[-1]} "
                                    f"({w.n}), sub-tile {w.tile.length_m:g} x "
                                    f"{w.tile.width_m:g} x {w.tile.depth_m:g} m")
        from sim_device.environment_source import EnvironmentSource
        src = EnvironmentSource(hw, w.scene)
        log.info("simulating %d pings for the imaging options", w.n)
        pings = [src.ping(i) for i in w.pings]
        res.areas["imaging"] = imaging.run(hw, proc, w, pings, c_sed, quick,
                                           cuda_available())
    if "simulation" in areas:
        w = simulation_workload(hw, proc, quick)
        c_sed = sediment_speed(w.scene) or proc.imaging.water_sound_speed_m_s
        res.workloads["simulation"] = (f"{w.name}: pings {w.first}..{w.pings[-1]} "
                                       f"every {w.stride} ({w.n}), sub-tile "
                                       f"{w.tile.length_m:g} x {w.tile.width_m:g} x "
                                       f"{w.tile.depth_m:g} m")
        res.areas["simulation"] = simulation.run(hw, proc, w, c_sed, quick)
    if "normalisation" in areas:
        res.workloads["normalisation"] = "synthetic tile" + (" (160 x 40 x 40)" if quick
                                                             else " (full size)")
        res.areas["normalisation"] = normalisation.run(proc, quick)
    conclude(res)
    res.files = report.write(res, Path(out))
    return res


def conclude(res: TradeResult) -> None:
    """Fronts, the defaults' place on them and the recommendations."""
    for area, rows in res.areas.items():
        report.mark_front(rows)
        d = next(r for r in rows if r["is_default"])
        res.defaults_on_front[area] = d["on_front"]
        if d["on_front"]:
            res.summary.append(f"{area}: the default ({d['value']}) is on the Pareto front")
        else:
            by = [f"{o['option']} = {o['value']}" for o in rows
                  if o is not d and report.dominates(o, d, area)]
            res.summary.append(f"{area}: the default ({d['value']}) is NOT on the Pareto "
                               f"front: dominated by {', '.join(by)}")
        rec = report.recommend(rows, res.budget_s)
        res.recommendation[area] = None if rec is None else {
            "option": rec["option"], "value": rec["value"], "setting": rec["setting"],
            "tile_s": rec["tile_s"], "error": rec["error"]}
        res.summary.append(f"{area}: for {res.budget_s:g} s per tile, "
                           f"{report.describe(rec)}" + ("" if rec is None else
                           f" ({rec['tile_s']:.3g} s per tile, error {rec['error']:.3g})"))
    if "imaging" in res.areas and "normalisation" in res.areas:
        pair = report.recommend_chain(res.areas["imaging"], res.areas["normalisation"],
                                      res.budget_s)
        if pair is None:
            res.summary.append(f"processing chain: no imaging and normalisation pair fits "
                               f"{res.budget_s:g} s per tile")
        else:
            a, b = pair
            res.recommendation["processing"] = {"imaging": a["setting"],
                                                "normalisation": b["setting"],
                                                "tile_s": a["tile_s"] + b["tile_s"]}
            res.summary.append(
                f"processing chain (imaging + normalisation) for {res.budget_s:g} s per "
                f"tile: imaging {report.describe(a)} with normalisation "
                f"{report.describe(b)}: {a['tile_s'] + b['tile_s']:.3g} s per tile")


def print_table(res: TradeResult) -> None:
    """The table on standard output (the command's result)."""
    for area, rows in res.areas.items():
        print(f"\n== {area}: {res.workloads.get(area, '')}")
        print(f"   error: {rows[0]['error_name']}")
        print(f"{'option':14s} {'value':28s} {'time s':>8s} {'s/tile':>9s} {'error':>10s}"
              "  front")
        for r in rows:
            tag = "*" if r["is_default"] else "R" if r["is_reference"] else " "
            print(f"{tag}{r['option']:13s} {str(r['value'])[:28]:28s} {r['time_s']:8.3f} "
                  f"{r['tile_s']:9.3g} {r['error']:10.3g}  {'yes' if r['on_front'] else ''}")
    print(f"\n{res.machine}\n(* default, R reference)")
    for s in res.summary:
        print(s)
    for p in res.files:
        print(f"wrote {p}")
