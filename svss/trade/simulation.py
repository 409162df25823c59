"""Simulation options: seconds per simulated tile against the error they make in the
image.

Every row simulates the workload's pings with one fidelity option of the scene changed
(through the scene's own tables: ``[scattering] scatterers_per_resolution_cell`` and
``volume_below_noise_db``, ``[surface] multipath_order``, ``[target_model]
truncation_tol`` and ``freq_step_hz``; the scene file gives the defaults) and images
them with one fixed setting (linear, float32, table delays at the top sediment's
speed). Measures, on the background (voxels more than ``target_radius`` from the
target) and the target:

* ``level_db``: mean background intensity, dB re the reference's;
* ``contrast_db``: speckle contrast 10 log10 <I^2>/<I>^2 of the intensity normalised
  by its mean at each depth (fully developed speckle: 10 log10 2 = 3.0 dB), re the
  reference's; also the scintillation index <I^2>/<I>^2 - 1 and the Kolmogorov-Smirnov
  distance of the normalised intensity to the exponential law;
* ``excess_db``: the target's excess (brightest voxel near it over the mean background
  at its depth +-10 cm), re the reference's.

The row's error is the largest of the three differences (dB). Different scatterer
densities draw different seabeds, so their differences hold a statistical part: the
``other seed`` row (same fidelity as the reference, another seabed) shows its size.
Time: median seconds per ping (noise and quantisation included) x 150 pings per tile.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import SceneConfig, TargetModelConfig
from sim_device.targets import DEFAULT_TOL
from sim_device.targets.echo import DEFAULT_BISTATIC, DEFAULT_FREQ_STEP_HZ
from svss_daq.config import HardwareConfig, Loaded, ProcessingConfig

from .imaging import image
from .workloads import TILE_PINGS, Workload

log = logging.getLogger(__name__)

KEYS = ("per_cell", "order", "below_noise", "tol", "step")


def scene_defaults(scene: SceneConfig) -> dict:
    """The scene file's fidelity options (absent tables take the simulator's defaults)."""
    sc, surf, tm = scene.scattering, scene.surface, scene.target_model
    return {"per_cell": sc.scatterers_per_resolution_cell if sc else None,
            "order": surf.multipath_order if surf else 0,
            "below_noise": sc.volume_below_noise_db if sc else None,
            "tol": tm.truncation_tol if tm else DEFAULT_TOL,
            "step": tm.freq_step_hz if tm else DEFAULT_FREQ_STEP_HZ}


def with_options(scene: SceneConfig, s: dict, seed: int | None = None) -> SceneConfig:
    """``scene`` with the fidelity options ``s`` (keys of :data:`KEYS`)."""
    out = scene
    if scene.scattering is not None:
        out = dataclasses.replace(out, scattering=dataclasses.replace(
            scene.scattering, scatterers_per_resolution_cell=s["per_cell"],
            volume_below_noise_db=s["below_noise"]))
    if scene.surface is not None:
        out = dataclasses.replace(out, surface=dataclasses.replace(
            scene.surface, multipath_order=s["order"]))
    tm = scene.target_model or TargetModelConfig(DEFAULT_TOL, DEFAULT_FREQ_STEP_HZ,
                                                 DEFAULT_BISTATIC)
    out = dataclasses.replace(out, target_model=dataclasses.replace(
        tm, truncation_tol=s["tol"], freq_step_hz=s["step"]))
    if seed is not None:
        out = dataclasses.replace(out, scene=dataclasses.replace(out.scene, seed=seed))
    return out


def variants(default: dict, quick: bool) -> tuple[dict, list[tuple[str, str, dict]]]:
    """The highest-fidelity setting and the rows (option, value, setting)."""
    pc = default["per_cell"]
    # quick: the cylinder's form table at the simulator's finest default step (5 Hz,
    # within 3e-4 dB of the exact series in the full run, docs/trade.md) instead of the
    # exact series, which costs 3 to 5 times more per ping on every reference-based row
    ref = {"per_cell": max(4.0, 2 * pc) if pc else 4.0, "order": max(default["order"], 2),
           "below_noise": None, "tol": min(default["tol"], 1e-12),
           "step": DEFAULT_FREQ_STEP_HZ if quick else 0.0}
    rows = [("reference", "highest fidelity", ref), ("default", "scene file", default)]
    if quick:
        cells, orders, cuts, tols, steps = (1.0, 0.02), (0,), (0.0,), (1e-3,), (500.0,)
    else:
        cells = (2.0, 1.0, 0.5)
        orders, cuts, tols, steps = (1, 0), (10.0, 0.0), (1e-4,), (5.0, 500.0)
    for v in cells:
        rows.append(("per_cell", f"{v:g}", dict(ref, per_cell=v)))
    for v in orders:
        rows.append(("order", str(v), dict(ref, order=v)))
    for v in cuts:
        rows.append(("below_noise", f"{v:g} dB", dict(ref, below_noise=v)))
    for v in tols:
        rows.append(("tol", f"{v:g}", dict(ref, tol=v)))
    for v in steps:
        rows.append(("step", f"{v:g} Hz", dict(ref, step=v)))
    return ref, rows


def image_statistics(img: np.ndarray, grid, target, radius: float) -> dict:
    """Background level, speckle and target excess of one image (module docstring)."""
    inten = np.abs(img) ** 2
    a, c, d = np.meshgrid(grid.along, grid.cross, grid.depth, indexing="ij")
    near = ((a - target[0]) ** 2 + (c - target[1]) ** 2 + (d - target[2]) ** 2
            <= radius ** 2) if target is not None else np.zeros(inten.shape, bool)
    bg = (~near) & (inten > 0)
    level = float(np.mean(inten[bg]))
    # normalise by the mean background intensity at each depth
    prof = np.array([inten[:, :, k][bg[:, :, k]].mean() if bg[:, :, k].any() else np.nan
                     for k in range(inten.shape[2])])
    x = (inten / prof[None, None, :])[bg & np.isfinite(prof)[None, None, :]]
    x = x / x.mean()
    m2 = float(np.mean(x * x))
    xs = np.sort(x)
    n = xs.size
    cdf = 1.0 - np.exp(-xs)
    ks = float(max(np.max(np.arange(1, n + 1) / n - cdf), np.max(cdf - np.arange(n) / n)))
    out = {"level_db": 10 * math.log10(level), "contrast_db": 10 * math.log10(m2),
           "scintillation": m2 - 1.0, "ks_exponential": ks}
    if target is not None and near.any():
        band = bg & (np.abs(d - target[2]) <= 0.1)
        ref_level = float(np.mean(inten[band])) if band.any() else level
        out["excess_db"] = 10 * math.log10(float(inten[near].max()) / ref_level)
    return out


def run(hw: Loaded[HardwareConfig], proc: ProcessingConfig, workload: Workload,
        c_sed: float, quick: bool) -> list[dict]:
    default = scene_defaults(workload.scene)
    ref_s, rows = variants(default, quick)
    if not quick:
        rows.append(("other seed", "reference, another seabed", dict(ref_s)))
    im = dataclasses.replace(proc.imaging, interpolation="linear", precision="float32",
                             delays="table", sediment_sound_speed_m_s=c_sed, device="cpu")
    p_img = dataclasses.replace(proc, tile=workload.tile, imaging=im)
    radius = 3 * workload.tile.voxel_m + (0.05 if quick else 0.25)
    out, ref_stats, warm = [], None, False
    for opt, val, s in rows:
        seed = workload.scene.scene.seed + 1 if opt == "other seed" else None
        src = EnvironmentSource(hw, with_options(workload.scene, s, seed))
        if not warm:                  # numba kernels compile (or load) outside the timings
            src.ping(max(workload.first - 1, 0))
            warm = True
        times, pings = [], []
        for i in workload.pings:
            t0 = time.perf_counter()
            pings.append(src.ping(i))
            times.append(time.perf_counter() - t0)
        img, grid, *_ = image(hw, p_img, pings, workload.tile_index)
        st = image_statistics(img, grid, workload.target, radius)
        if opt == "reference":
            ref_stats = st
        diff = {"level_db": st["level_db"] - ref_stats["level_db"],
                "contrast_db": st["contrast_db"] - ref_stats["contrast_db"],
                "excess_db": st.get("excess_db", math.nan) - ref_stats.get("excess_db",
                                                                          math.nan)}
        err = max(abs(v) for v in diff.values() if math.isfinite(v))
        per_ping = float(np.median(times))
        out.append({"area": "simulation", "option": opt, "value": val, "setting": s,
                    "is_reference": opt == "reference", "is_default": opt == "default",
                    "is_floor": opt == "other seed", "time_s": float(sum(times)),
                    "s_per_ping": per_ping, "tile_s": per_ping * TILE_PINGS,
                    "error": float(err), "error_name": "largest image-domain difference "
                    "(level, speckle contrast, target excess; dB)",
                    "metrics": {**st, **{f"d_{k}": v for k, v in diff.items()}}})
        log.info("simulation %s=%s: %.2f s/ping, error %.2f dB", opt, val, per_ping, err)
    return out
