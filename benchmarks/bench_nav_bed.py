"""The navigation's down axis over a real bed: the bed as a plane about the head (its
depth and gradient as states, docs/navigation.md "Fusion") against a flat bed (the
gradient held at zero), side by side in one run, live (the filter) and smoothed.

Two runs: RDI's Workhorse bottom-track recording (``../shared/data/dvl_pd0/RDI_withBT.000``,
a bank falling to starboard, the bottom lost for minutes mid-run), put on the water by
GPS heights of 0 m along its own dead-reckoned track (the body then 2.5 m below the
antenna); and two minutes of the simulated DVL's PD0 over a bed 6 deg deepening ahead
and 5 deg across, with RTK fixes. Figures: the body's depth error (rms, worst) and, on
the simulated run, the altitude's.

    python benchmarks/bench_nav_bed.py --out benchmarks/results/bench_nav_bed.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import platform
import tempfile
from pathlib import Path

import numpy as np

from sim_device.devices.clock import SimClock
from sim_device.devices.dvl import DvlEmulator
from sim_device.devices.gps import antenna_ned
from sim_device.devices.instruments_config import load_instruments
from svss_daq.config import DevicesConfig, HardwareConfig, config_path, load
from svss_daq.nav import fusion
from svss_daq.nav.geodesy import ned_to_geodetic
from svss_daq.nav.records import GpsFix
from svss_daq.navigation import compute_poses, dvl_sample_from_pd0
from svss_daq.ping import NavSnapshot
from svss_daq.protocols.pd0 import Pd0StreamParser, decode_ensemble

log = logging.getLogger("bench_nav_bed")
ROOT = Path(__file__).resolve().parents[1]
RECORDING = ROOT.parent / "shared" / "data" / "dvl_pd0" / "RDI_withBT.000"
START_NS = 1_800_000_000 * 10 ** 9
K0, KN, KE, SPEED, HEADING = 4.0, 0.10, -0.09, 1.5, math.radians(20.0)


def _truth(t_ns: int) -> NavSnapshot:
    t = (t_ns - START_NS) * 1e-9
    n, e = SPEED * t * math.cos(HEADING), SPEED * t * math.sin(HEADING)
    return NavSnapshot(t_ns, n, e, 0.0, SPEED * math.cos(HEADING), SPEED * math.sin(HEADING),
                       0.0, 0.0, 0.0, HEADING, K0 + KN * n + KE * e, math.nan, math.nan, 0)


def _fixes_on(track, every_ns=10 ** 9, origin=(0.0, 0.0, 0.0), height=None):
    out, last = [], None
    for p in track:
        if (last is None or p.time_ns - last >= every_ns) and math.isfinite(p.north_m):
            lat, lon, h = ned_to_geodetic(np.array([p.north_m, p.east_m, p.down_m]), origin)
            out.append(GpsFix(p.time_ns, float(lat), float(lon),
                              float(h) if height is None else height, 4, 0.02))
            last = p.time_ns
    return out


def _poses(times, fixes, samples, cfg, arms, causal, flat):
    saved = fusion._GRADIENT_VAR
    if flat:
        fusion._GRADIENT_VAR = 0.0
        cfg = dataclasses.replace(cfg, bottom_slope_sigma_per_m=0.0)
    try:
        return compute_poses(times, fixes, [], samples, cfg, arms, causal=causal)
    finally:
        fusion._GRADIENT_VAR = saved


def river(cfg, arms):
    samples = [s for s in (dvl_sample_from_pd0(e)
                           for e in Pd0StreamParser().feed(RECORDING.read_bytes()))
               if s is not None]
    lock = np.array([np.all(np.isfinite(s.velocity_body_m_s)) for s in samples])
    cfg = dataclasses.replace(cfg, origin_latitude_deg=0.0, origin_longitude_deg=0.0,
                              origin_height_m=0.0)
    times = [s.time_ns for s in samples]
    track = [dataclasses.replace(p, down_m=0.0) for p in
             compute_poses(times, [], [], samples, cfg, arms)]
    fixes = _fixes_on(track, height=0.0)
    want = -arms.gps_antenna_m[2]
    rows = []
    for flat in (True, False):
        for causal in (True, False):
            down = np.array([p.down_m for p in _poses(times, fixes, samples, cfg, arms,
                                                      causal, flat)])[lock] - want
            alt = np.array([p.altitude_m for p in _poses(times, fixes, samples, cfg, arms,
                                                         causal, flat)])[lock]
            rows.append({"run": "RDI_withBT", "bed": "flat" if flat else "plane",
                         "live": causal, "down_rms_m": float(np.sqrt(np.mean(down ** 2))),
                         "down_worst_m": float(np.max(np.abs(down))),
                         "mean_altitude_m": float(np.nanmean(alt))})
    return rows


def sloping(cfg, arms):
    inst = load_instruments(config_path("sim-device.toml"))
    with tempfile.TemporaryDirectory() as tmp:
        dvl = DvlEmulator(inst.dvl, arms, SimClock(START_NS), _truth, tmp, bed=(K0, KN, KE))
        try:
            samples = [dvl_sample_from_pd0(decode_ensemble(dvl._emit("ensemble", t, t)))
                       for t in START_NS + np.arange(600) * 200_000_000]
        finally:
            dvl.close()
    origin = (45.0, 7.0, 0.0)
    fixes = []
    for t in START_NS + np.arange(120) * 1_000_000_000:
        lat, lon, h = ned_to_geodetic(antenna_ned(_truth(int(t)), arms.gps_antenna_m), origin)
        fixes.append(GpsFix(int(t), float(lat), float(lon), float(h), 4, 0.02))
    cfg = dataclasses.replace(cfg, origin_latitude_deg=origin[0],
                              origin_longitude_deg=origin[1], origin_height_m=origin[2])
    times = [int(t) for t in START_NS + 10 ** 10 + np.arange(1000) * 100_000_000]
    truth = np.array([_truth(t).altitude_m for t in times])
    rows = []
    for flat in (True, False):
        for causal in (True, False):
            poses = _poses(times, fixes, samples, cfg, arms, causal, flat)
            down = np.array([p.down_m for p in poses])
            err = np.array([p.altitude_m for p in poses]) - truth
            rows.append({"run": "simulated 6/5 deg", "bed": "flat" if flat else "plane",
                         "live": causal, "down_rms_m": float(np.sqrt(np.mean(down ** 2))),
                         "down_worst_m": float(np.max(np.abs(down))),
                         "altitude_rms_m": float(np.sqrt(np.mean(err ** 2))),
                         "altitude_worst_m": float(np.max(np.abs(err)))})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    cfg = load(DevicesConfig, config_path("devices.toml")).navigation
    arms = load(HardwareConfig, config_path("hardware.toml")).lever_arms
    rows = sloping(cfg, arms) + (river(cfg, arms) if RECORDING.exists() else [])
    for r in rows:
        log.info("%-18s %-5s %-8s %s", r["run"], r["bed"], "live" if r["live"] else "smoothed",
                 "  ".join(f"{k} {v:.3f}" for k, v in r.items()
                           if isinstance(v, float)))
    if args.out:
        args.out.write_text(json.dumps({"machine": platform.processor() or platform.machine(),
                                        "settings": {k: getattr(cfg, k) for k in (
                                            "bottom_slope_sigma_per_m",
                                            "bottom_depth_rate_sigma_m_s",
                                            "bottom_max_slope_deg")},
                                        "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
