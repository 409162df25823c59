#!/usr/bin/env python
"""Benchmark the simulated device's environment synthesis (``sim_device``).

1. Throughput: pings per second for the demo, silt and sand scenes, 80 channels, at
   the scene file's fidelity, the fast accumulation and the reference kernel side by
   side in one run (``[scattering] synthesis``; ``--reference-pings`` pings of the
   reference, default 1), and the scenes under the fast profile (``--fast-profile``
   options: density per resolution cell and the volume's level cut-off); the time for a
   reference tile's worth of pings (15 m at 1 m/s and 10 pings/s: 150 pings), measured
   on ``--pings`` pings and extrapolated, or run in full with ``--full-tile``. The demo
   is timed through ``ping(i)`` (noise and quantisation included), the seabed scenes
   through ``pressure(i)``. CPU seconds (all threads) per echo are reported beside the
   wall time: the machine is shared, and CPU time is the steadier figure.
2. Cost follows the scatterers in view: the same ping of the sand scene in a scene
   twice as long (and ten times as long) costs the same.
3. Fidelity options (scatterer density, density per resolution cell, multipath order,
   volume depth cut-off, the volume's level cut-off, precision, the reference kernel):
   each row lowers one option from the highest-fidelity setting; time per ping against
   the error relative to that setting:
   * ``wave_err``: ||p - p_ref|| / ||p_ref|| over the noise-free samples (meaningful when
     the seabed is the same realisation: multipath, cut-off, precision);
   * ``energy_err_db``: 10 log10 of the ping energy (channels, pings, whole window)
     relative to the reference's;
   * ``profile_err_db``: rms over 0.2 ms bins of 10 log10(I / I_ref), I the mean square
     over channels and pings, in the bins where the reference is above the noise (a
     statistical measure, for the density rows; its floor is the ``other seed`` row; a
     missing late arrival, e.g. multipath, counts with its full dB deficit);
   * ``speckle``: scintillation index <I^2>/<I>^2 - 1 of the envelope (analytic signal)
     normalised by the mean profile, over channels, pings and the bins above the noise
     (Gaussian speckle: 1; the reference's value is printed with it);
   * ``at_target_db``: the background (mean square over channels and pings) in the
     0.2 ms about the buried cylinder's two-way delay (1 m deep, under the track)
     relative to the reference's: the change in the target's excess over its
     background is minus this.

Usage::

    python benchmarks/bench_possm.py --out benchmarks/results/bench_possm.json [--pings 3]
                                     [--fidelity-pings 2] [--quick] [--full-tile]
                                     [--threads N] [--only throughput,length,fidelity]
                                     [--scenes demo,seed_cylinder_silt,seed_cylinder_sand]
                                     [--reference-pings 1] [--fast-profile 2,20]

Prints the tables and writes them to ``--out`` (JSON). The first ping of each source
compiles or loads the numba kernels and is not timed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402

from bench_isa import machine_isa  # noqa: E402
from sim_device.environment_source import EnvironmentSource  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,  # noqa: E402
                             load_with_text)
from svss_proc.imaging.imager import TileImager  # noqa: E402

log = logging.getLogger("bench_possm")

TILE_PINGS = 150            # 15 m tile at 1 m/s and 10 pings/s (DESIGN.md)
#: the fast profile's options (--fast-profile): scatterers per resolution cell, the
#: volume's level cut-off below the noise (dB)
FAST_PROFILE = {"per_cell": 1.0, "below_noise": 0.0}
#: the settings of the scene files before issue 17 (explicit densities, no level
#: cut-off): the "former" rows
FORMER = {"per_cell": None, "below_noise": None}
FIRST_PING = 100            # pings well inside the track


KEEP = "scene"       # with_fidelity: keep the scene file's value (None: option off)


def with_fidelity(scene, density=1.0, order=None, cutoff=None, precision=None, seed=None,
                  synthesis=None, per_cell=KEEP, below_noise=KEEP):
    sc = scene.scattering
    if sc is None:
        return scene
    scat = dataclasses.replace(
        sc, interface_density_per_m2=sc.interface_density_per_m2 * density,
        volume_density_per_m3=sc.volume_density_per_m3 * density,
        volume_max_depth_m=sc.volume_max_depth_m if cutoff is None else cutoff,
        precision=sc.precision if precision is None else precision,
        synthesis=sc.synthesis if synthesis is None else synthesis,
        scatterers_per_resolution_cell=(sc.scatterers_per_resolution_cell
                                        if per_cell == KEEP else per_cell),
        volume_below_noise_db=(sc.volume_below_noise_db if below_noise == KEEP
                               else below_noise))
    surf = scene.surface if order is None else dataclasses.replace(scene.surface,
                                                                   multipath_order=order)
    out = dataclasses.replace(scene, scattering=scat, surface=surf, targets=())
    if seed is not None:
        out = dataclasses.replace(out, scene=dataclasses.replace(out.scene, seed=seed))
    return out


_warm: set = set()


def time_pings(src: EnvironmentSource, pings: list[int], keep: bool = False,
               whole: bool = False):
    """Wall time per ping (s) of ``src.pressure`` (``src.ping`` if ``whole``) over
    ``pings``, the pings' statistics (with ``cpu_s``: CPU seconds of all threads), and
    the pressures if ``keep``. The first source of each precision and kernel runs one
    untimed ping first (numba compiles or loads its kernels)."""
    key = (src.precision, src.synthesis, whole)
    if key not in _warm:
        src.ping(pings[0] - 1) if whole else src.pressure(pings[0] - 1)
        _warm.add(key)
    out, times, stats = [], [], []
    for i in pings:
        c0 = time.process_time()
        t0 = time.perf_counter()
        p = src.ping(i) if whole else src.pressure(i)
        times.append(time.perf_counter() - t0)
        stats.append(dict(src.last_stats, cpu_s=time.process_time() - c0))
        if keep:
            out.append(p)
    return np.array(times), stats, out


def throughput(hw, name: str, n: int, full_tile: bool, label: str = "scene file",
               **options) -> dict:
    scene = with_fidelity(load_scene(config_path(f"scenes/{name}.toml")), **options)
    src = EnvironmentSource(hw, scene)
    whole = src.scene.seabed is None
    first = 30 if whole else FIRST_PING
    if full_tile:                   # a whole tile's pings inside the track
        first = max(1, min(first, src.n_pings - TILE_PINGS))
    n_all = min(TILE_PINGS, src.n_pings - first) if full_tile else n
    pings = list(range(first, first + n_all))
    times, stats, _ = time_pings(src, pings, whole=whole)
    per_ping = float(np.median(times))
    echoes = float(np.mean([s.get("echoes", 0) for s in stats]))
    cpu = float(np.median([s["cpu_s"] for s in stats]))
    row = {
        "scene": name, "setting": label, "synthesis": src.synthesis,
        "timed": "ping" if whole else "pressure", "channels": src.geometry.n_channels,
        "multipath_order": src.order, "pings_timed": len(pings),
        "s_per_ping_median": per_ping, "s_per_ping_min": float(times.min()),
        "s_per_ping_mean": float(times.mean()), "first_ping": first,
        "pings_per_s": 1.0 / per_ping,
        "tile_s": float(times.sum()) if full_tile else per_ping * TILE_PINGS,
        "tile_measured": full_tile,
        "scatterers_generated": int(np.mean([s.get("generated", 0) for s in stats])),
        "scatterers_in_view": int(np.mean([s.get("in_view", 0) for s in stats])),
        "echoes_per_ping": int(echoes),
        "ns_per_echo": per_ping / max(echoes, 1.0) * 1e9,
        "cpu_s_per_ping": cpu,
        "cpu_ns_per_echo": cpu / max(echoes, 1.0) * 1e9,
        "receive_s": float(np.median([s.get("receive_s", 0.0) for s in stats])),
        "coherent_paths": int(stats[-1].get("coherent_paths", 0)),
        "options": {k: v for k, v in options.items()},
    }
    log.info("%s (%s, %s): %.3f s/ping", name, label, src.synthesis, per_ping)
    return row


def scene_length(hw, n: int) -> list[dict]:
    base = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    rows = []
    for factor in (1, 2, 10):
        sc = with_fidelity(base)
        sc = dataclasses.replace(sc, track=dataclasses.replace(
            sc.track, n_pings=sc.track.n_pings * factor))
        src = EnvironmentSource(hw, sc)
        times, stats, _ = time_pings(src, list(range(FIRST_PING, FIRST_PING + n)))
        rows.append({"track_pings": sc.track.n_pings,
                     "track_m": sc.track.n_pings * hw.value.sequencer.ping_interval_s
                     * sc.track.speed_m_s,
                     "s_per_ping_median": float(np.median(times)),
                     "s_per_ping_min": float(times.min()),
                     "scatterers_generated": int(stats[-1]["generated"]),
                     "echoes_per_ping": int(stats[-1]["echoes"])})
    return rows


def profile(ps: list[np.ndarray], nbin: int = 25) -> np.ndarray:
    """Mean square over channels and pings in bins of ``nbin`` samples."""
    p = np.stack(ps)
    n = p.shape[-1] // nbin * nbin
    return np.mean(p[..., :n] ** 2, axis=(0, 1)).reshape(-1, nbin).mean(axis=1)


def envelope_power(ps: list[np.ndarray]) -> np.ndarray:
    """|analytic signal|^2 of the pressures: (pings, channels, samples)."""
    p = np.stack(ps)
    spec = np.fft.fft(p, axis=-1)
    n = p.shape[-1]
    spec[..., n // 2 + 1:] = 0.0
    spec[..., 1:(n + 1) // 2] *= 2.0
    return np.abs(np.fft.ifft(spec, axis=-1)) ** 2


def speckle(ps: list[np.ndarray], above: np.ndarray, nbin: int = 25) -> float:
    """Scintillation index of the envelope normalised by its mean over channels and
    pings, over the samples of the bins marked ``above``."""
    e = envelope_power(ps)
    m = e.mean(axis=(0, 1))
    n = above.size * nbin
    keep = np.repeat(above, nbin)[:n] & (m[:n] > 0)
    x = e[..., :n][..., keep] / m[:n][keep]
    return float(np.mean(x ** 2) - 1.0)


def target_bin(src: EnvironmentSource, depth: float = 1.0, nbin: int = 25) -> int:
    """The profile bin of the nadir two-way delay of a point ``depth`` m below the
    interface (the seed's buried cylinder)."""
    g = src.frame(FIRST_PING)
    h = -float(g.tx[2])
    tau = 2.0 * h / src.media.c[0] + 2.0 * depth / src.media.c[1]
    return int((tau - src.pulses.t_first) * src.fs) // nbin


#: the highest fidelity both fidelity tables start from: twice the former scene files'
#: densities, multipath to second order, 3 m of volume, float64, no level cut-off
TOP = {"density": 2.0, "order": 2, "cutoff": 3.0, "precision": "float64", "per_cell": None,
       "below_noise": None}


def row_options(key: str, value) -> tuple[dict, str]:
    """The with_fidelity options and the label of a fidelity-table row: one option
    lowered from :data:`TOP`, the scene file's own setting ("default") or TOP on another
    seabed ("seed")."""
    if key == "default":
        return {}, "scene file (default)"
    if key == "seed":
        return dict(TOP, seed=value), "other seed (same fidelity)"
    return dict(TOP, **{key: value}), f"{key} = {value}"


def _only(variants: list, only_rows: str | None) -> list:
    """The ``(key, value)`` variants whose key ``only_rows`` (comma-separated) names;
    all of them without it."""
    return [v for v in variants if v[0] in only_rows.split(",")] if only_rows else variants


def fidelity(hw, n: int, quick: bool, only_rows: str | None = None
             ) -> tuple[dict, list[dict]]:
    """The fidelity table on ``n`` pings of the sand scene."""
    base = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    top = TOP
    pings = list(range(FIRST_PING, FIRST_PING + n))
    ref_src = EnvironmentSource(hw, with_fidelity(base, **top))
    t_ref, s_ref, p_ref = time_pings(ref_src, pings, keep=True)
    noise = ref_src.noise_power
    i_ref = profile(p_ref)
    above = i_ref > noise
    tb = target_bin(ref_src)
    si_ref = speckle(p_ref, above)
    reference = {"options": top, "s_per_ping": float(np.median(t_ref)),
                 "cpu_s_per_ping": float(np.median([x["cpu_s"] for x in s_ref])),
                 "echoes_per_ping": int(np.mean([s["echoes"] for s in s_ref])),
                 "bins_above_noise": int(above.sum()), "speckle": si_ref,
                 "target_bin": tb}
    variants = [("density", 1.0), ("density", 0.5), ("density", 0.25),
                ("per_cell", 4.0), ("per_cell", 2.0), ("per_cell", 1.0),
                ("order", 1), ("order", 0),
                ("cutoff", 2.5), ("cutoff", 1.5), ("cutoff", 1.0),
                ("below_noise", 20.0), ("below_noise", 10.0), ("below_noise", 0.0),
                ("precision", "exact"), ("precision", "float32"),
                ("synthesis", "reference"),
                ("default", None),
                ("seed", base.scene.seed + 1)]
    if quick:
        variants = [("per_cell", 2.0), ("order", 0), ("below_noise", 20.0),
                    ("precision", "float32"), ("default", None),
                    ("seed", base.scene.seed + 1)]
    variants = _only(variants, only_rows)
    rows = []
    for key, value in variants:
        opts, label = row_options(key, value)
        src = EnvironmentSource(hw, with_fidelity(base, **opts))
        t, s, p = time_pings(src, pings, keep=True)
        same_seabed = key in ("order", "cutoff", "precision", "below_noise", "synthesis")
        wave = (float(np.sqrt(sum(np.sum((a - b) ** 2) for a, b in zip(p, p_ref))
                              / sum(np.sum(b ** 2) for b in p_ref)))
                if same_seabed else None)
        i_opt = profile(p)
        ratio = i_opt[above] / i_ref[above]
        rows.append({"option": label, "s_per_ping": float(np.median(t)),
                     "cpu_s_per_ping": float(np.median([x["cpu_s"] for x in s])),
                     "speedup": float(np.median(t_ref) / np.median(t)),
                     "echoes_per_ping": int(np.mean([x["echoes"] for x in s])),
                     "wave_err": wave,
                     "energy_err_db": float(10 * np.log10(i_opt.sum() / i_ref.sum())),
                     "profile_err_db": float(np.sqrt(np.mean((10 * np.log10(
                         np.maximum(ratio, 1e-30))) ** 2))),
                     "speckle": speckle(p, above),
                     "at_target_db": float(10 * np.log10(i_opt[tb] / i_ref[tb]))})
        log.info("%s: %.2f s/ping", label, rows[-1]["s_per_ping"])
    return reference, rows


IMAGE_TILE_M = 3.0          # image-domain fidelity: tile 3 (9-12 m along) holds the target
IMAGE_PINGS = (70, 140)     # the pings whose beams reach that tile (7-14 m along)


def image_processing(src: EnvironmentSource):
    """Processing for the image-domain rows: 3 m tiles on the scene's own track line, the
    exact sediment sound speed (travel-time table), 2 cm voxels."""
    proc = load(ProcessingConfig, config_path("processing.toml"))
    tr = src.scene.track
    return dataclasses.replace(
        proc, products=None,
        tile=dataclasses.replace(proc.tile, length_m=IMAGE_TILE_M, close_after_pings=1000),
        imaging=dataclasses.replace(
            proc.imaging, track_line="fixed", line_origin_ne_m=tuple(tr.start_ne_m),
            line_heading_deg=tr.heading_deg, delays="table",
            water_sound_speed_m_s=float(src.media.c[0]),
            sediment_sound_speed_m_s=float(src.media.c[1])))


def image_tile(hw, src: EnvironmentSource, pings: range):
    """Simulate ``pings`` of ``src`` (noise included) and image them; returns (tile
    holding the target, simulation s/ping, simulation CPU s/ping)."""
    imager = TileImager(hw, image_processing(src))
    tiles, t_sim, c_sim = [], 0.0, 0.0
    for i in pings:
        c0, t0 = time.process_time(), time.perf_counter()
        ping = src.ping(i)
        t_sim += time.perf_counter() - t0
        c_sim += time.process_time() - c0
        tiles += imager.add(ping)
    tiles += imager.finish()
    k = int(src.scene.targets[0].along_m // IMAGE_TILE_M)
    tile = next(t for t in tiles if t.grid.index == k)
    return tile, t_sim / len(pings), c_sim / len(pings)


def image_measures(tile, target, depth_bin_m: float = 0.1, keep_out_m: float = 0.6) -> dict:
    """Image-domain measures of one tile: the background's mean level per depth bin
    (sediment, 0.2 m below the interface down to the tile's bottom, the cross-track
    margins and the target's surroundings left out), its speckle (scintillation index of
    the intensity normalised by its local mean: about 1 for Rayleigh speckle) and the
    target's excess (peak intensity within 0.3 m of the target over the background's
    median intensity at the target's depth, dB)."""
    g = tile.grid
    inten = np.abs(tile.image.astype(np.complex128)) ** 2
    a, c, d = np.meshgrid(g.along, g.cross, g.depth, indexing="ij")
    near = ((a - target.along_m) ** 2 + (c - target.cross_m) ** 2
            + (d - target.depth_m) ** 2) < keep_out_m ** 2
    bg = (~near) & (d > 0.2) & (np.abs(c) < 0.6) & (inten > 0)
    edges = np.arange(0.2, g.depth[-1] + depth_bin_m, depth_bin_m)
    which = np.digitize(d, edges) - 1
    prof = np.array([inten[bg & (which == j)].mean() if np.any(bg & (which == j))
                     else np.nan for j in range(edges.size - 1)])
    # speckle about the local mean level (0.3 m along, 0.2 m across, 0.1 m deep), so that
    # the beam pattern and the depth decay do not count as speckle
    v = g.voxel_m
    local = ndimage.uniform_filter(inten, size=(max(1, round(0.3 / v)), max(1, round(0.2 / v)),
                                                max(1, round(0.1 / v))), mode="nearest")
    norm = inten[bg] / local[bg]
    close = ((a - target.along_m) ** 2 + (c - target.cross_m) ** 2
             + (d - target.depth_m) ** 2) < 0.3 ** 2
    band = bg & (np.abs(d - target.depth_m) < 0.1)
    return {"profile": prof, "mean": float(inten[bg].mean()),
            "speckle": float(np.mean(norm ** 2) - 1.0),
            "excess_db": float(10 * np.log10(inten[close].max() / np.median(inten[band])))}


def image_fidelity(hw, quick: bool, only_rows: str | None = None
                   ) -> tuple[dict, list[dict]]:
    """The fidelity table in the image domain: the sand scene with its cylinder, 70
    pings imaged into the 3 m tile holding the target, one option lowered per row from
    the highest fidelity; errors relative to that setting's image."""
    base = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    top = TOP
    pings = range(*IMAGE_PINGS)

    def run(**opts):
        sc = with_fidelity(base, **opts)
        sc = dataclasses.replace(sc, targets=base.targets)
        src = EnvironmentSource(hw, sc)
        src.ping(pings[0] - 1)                  # compile / load kernels untimed
        tile, t, c = image_tile(hw, src, pings)
        return image_measures(tile, base.targets[0]), t, c, src

    m_ref, t_ref, c_ref, _ = run(**top)
    reference = {"options": top, "s_per_ping": t_ref, "cpu_s_per_ping": c_ref,
                 "speckle": m_ref["speckle"], "excess_db": m_ref["excess_db"],
                 "pings": len(pings), "tile_m": IMAGE_TILE_M}
    variants = [("per_cell", 4.0), ("per_cell", 2.0), ("per_cell", 1.0),
                ("per_cell", 0.5), ("order", 1), ("order", 0), ("below_noise", 0.0),
                ("default", None), ("seed", base.scene.seed + 1)]
    if quick:
        variants = [("per_cell", 2.0), ("per_cell", 1.0), ("default", None),
                    ("seed", base.scene.seed + 1)]
    variants = _only(variants, only_rows)
    rows = []
    for key, value in variants:
        opts, label = row_options(key, value)
        m, t, c, src = run(**opts)
        ok = np.isfinite(m["profile"]) & np.isfinite(m_ref["profile"])
        prof_db = 10 * np.log10(m["profile"][ok] / m_ref["profile"][ok])
        rows.append({"option": label, "s_per_ping": t, "cpu_s_per_ping": c,
                     "speedup": t_ref / t,
                     "mean_db": float(10 * np.log10(m["mean"] / m_ref["mean"])),
                     "profile_db": float(np.sqrt(np.mean(prof_db ** 2))),
                     "speckle": m["speckle"],
                     "speckle_err": m["speckle"] - m_ref["speckle"],
                     "excess_db": m["excess_db"],
                     "excess_err_db": m["excess_db"] - m_ref["excess_db"],
                     "per_cell": (src.fidelity.scatterers_per_resolution_cell
                                  if src.fidelity is not None else None)})
        log.info("%s: %.2f s/ping", label, t)
    return reference, rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="JSON file for the results")
    ap.add_argument("--pings", type=int, default=3, help="pings timed per throughput "
                    "measurement")
    ap.add_argument("--fidelity-pings", type=int, default=2,
                    help="pings per row of the fidelity table")
    ap.add_argument("--full-tile", action="store_true",
                    help="time a whole tile (150 pings) instead of extrapolating")
    ap.add_argument("--quick", action="store_true", help="fewer fidelity rows")
    ap.add_argument("--rows", default=None, help="only these fidelity rows (comma-"
                    "separated keys: density, per_cell, order, cutoff, below_noise, "
                    "precision, synthesis, default, seed)")
    ap.add_argument("--threads", type=int, default=None, help="numba threads")
    ap.add_argument("--hardware", default=None, help="hardware TOML")
    ap.add_argument("--only", default="throughput,length,fidelity",
                    help="comma-separated sections to run")
    ap.add_argument("--scenes", default="demo,seed_cylinder_silt,seed_cylinder_sand",
                    help="comma-separated scenes (config/scenes) for the throughput")
    ap.add_argument("--settings", default="former,scene,lean",
                    help="throughput rows: former (reference and fast kernels), scene "
                    "(the scene file), lean (--fast-profile)")
    ap.add_argument("--reference-pings", type=int, default=1,
                    help="pings of the reference kernel per scene (0: none)")
    ap.add_argument("--fast-profile", default=None,
                    help="per_cell,below_noise_db of the fast-profile rows (default "
                    f"{FAST_PROFILE['per_cell']},{FAST_PROFILE['below_noise']})")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("sim_device").setLevel(logging.ERROR)
    if args.threads:
        numba.set_num_threads(args.threads)
    if args.fast_profile:
        a, b = args.fast_profile.split(",")
        FAST_PROFILE.update(per_cell=float(a), below_noise=float(b))
    hw = load_with_text(HardwareConfig, args.hardware or config_path("hardware.toml"))
    result = {"machine": {"python": platform.python_version(), "numba": numba.__version__,
                          "threads": numba.get_num_threads(), "cpus": os.cpu_count(),
                          "load_avg": list(os.getloadavg()), **machine_isa()}}

    only = set(args.only.split(","))
    if "throughput" in only:
        throughput_section(hw, args, result)
    if "length" in only:
        length_section(hw, args, result)
    if "fidelity" in only:
        fidelity_section(hw, args, result)
    if "image" in only:
        image_section(hw, args, result)
    result["machine"]["load_avg_end"] = list(os.getloadavg())
    Path(args.out).write_text(json.dumps(result, indent=2))
    log.info("wrote %s", args.out)
    return 0


def throughput_section(hw, args, result) -> None:
    print("\n== throughput (80 channels): fast and reference kernels, fast profile ==")
    rows = []
    for name in args.scenes.split(","):
        if name == "demo":
            rows.append(throughput(hw, name, args.pings, args.full_tile))
            continue
        settings = args.settings.split(",")
        if args.reference_pings and "former" in settings:
            rows.append(throughput(hw, name, args.reference_pings, False, "former",
                                   synthesis="reference", **FORMER))
        if "former" in settings:
            rows.append(throughput(hw, name, args.pings, False, "former", **FORMER))
        if "scene" in settings:
            rows.append(throughput(hw, name, args.pings, args.full_tile))
        if "lean" in settings:
            rows.append(throughput(hw, name, args.pings, args.full_tile, "lean",
                                   **FAST_PROFILE))
    print(f"{'scene':20s} {'setting':12s} {'kernel':9s} {'s/ping':>7s} {'min':>7s} "
          f"{'pings/s':>7s} {'tile (s)':>9s} {'in view':>8s} {'echoes':>10s} "
          f"{'ns/echo':>7s} {'cpu ns/echo':>11s}")
    for r in rows:
        print(f"{r['scene']:20s} {r['setting']:12s} {r['synthesis']:9s} "
              f"{r['s_per_ping_median']:7.3f} {r['s_per_ping_min']:7.3f} "
              f"{r['pings_per_s']:7.2f} {r['tile_s']:9.1f} {r['scatterers_in_view']:8d} "
              f"{r['echoes_per_ping']:10d} {r['ns_per_echo']:7.1f} "
              f"{r['cpu_ns_per_echo']:11.1f}")
    for name in args.scenes.split(","):
        ref = [r for r in rows if r["scene"] == name and r["synthesis"] == "reference"]
        for r in rows:
            if ref and r["scene"] == name and r["synthesis"] == "fast":
                print(f"{name} {r['setting']} (fast) against former (reference): wall "
                      f"x{ref[0]['s_per_ping_median'] / r['s_per_ping_median']:.1f}, CPU "
                      f"x{ref[0]['cpu_s_per_ping'] / r['cpu_s_per_ping']:.1f}, CPU per echo "
                      f"x{ref[0]['cpu_ns_per_echo'] / r['cpu_ns_per_echo']:.1f}")
    result["throughput"] = rows


def length_section(hw, args, result) -> None:
    print("\n== cost per ping against the scene's length (sand) ==")
    rows = scene_length(hw, args.pings)
    print(f"{'track (m)':>9s} {'s/ping':>7s} {'min':>7s} {'generated':>10s} {'echoes':>10s}")
    for r in rows:
        print(f"{r['track_m']:9.0f} {r['s_per_ping_median']:7.2f} {r['s_per_ping_min']:7.2f} "
              f"{r['scatterers_generated']:10d} {r['echoes_per_ping']:10d}")
    result["scene_length"] = rows


def fidelity_section(hw, args, result) -> None:
    print("\n== fidelity options (sand): one option lowered from the highest fidelity ==")
    ref, rows = fidelity(hw, args.fidelity_pings, args.quick, args.rows)
    print(f"reference {ref['options']}: {ref['s_per_ping']:.2f} s/ping, "
          f"{ref['echoes_per_ping']} echoes/ping, {ref['bins_above_noise']} bins above "
          f"noise, speckle {ref['speckle']:.2f}")
    print(f"{'option':40s} {'s/ping':>7s} {'speedup':>7s} {'echoes':>10s} {'wave_err':>9s} "
          f"{'energy dB':>9s} {'profile dB':>10s} {'speckle':>7s} {'@target dB':>10s}")
    for r in rows:
        w = f"{r['wave_err']:9.2e}" if r["wave_err"] is not None else f"{'-':>9s}"
        print(f"{r['option']:40s} {r['s_per_ping']:7.2f} {r['speedup']:7.2f} "
              f"{r['echoes_per_ping']:10d} {w} {r['energy_err_db']:9.2f} "
              f"{r['profile_err_db']:10.2f} {r['speckle']:7.2f} {r['at_target_db']:10.2f}")
    result["fidelity_reference"] = ref
    result["fidelity"] = rows



def image_section(hw, args, result) -> None:
    print("\n== fidelity options in the image domain (sand, 3 m tile with the cylinder) ==")
    ref, rows = image_fidelity(hw, args.quick, args.rows)
    print(f"reference {ref['options']}: {ref['s_per_ping']:.2f} s/ping, speckle "
          f"{ref['speckle']:.2f}, target excess {ref['excess_db']:.1f} dB")
    print(f"{'option':32s} {'s/ping':>7s} {'speedup':>7s} {'mean dB':>7s} "
          f"{'prof dB':>7s} {'speckle':>7s} {'excess dB':>9s} {'d excess':>8s}")
    for r in rows:
        print(f"{r['option']:32s} {r['s_per_ping']:7.2f} {r['speedup']:7.2f} "
              f"{r['mean_db']:7.2f} {r['profile_db']:7.2f} {r['speckle']:7.2f} "
              f"{r['excess_db']:9.1f} {r['excess_err_db']:8.1f}")
    result["image_fidelity_reference"] = ref
    result["image_fidelity"] = rows


if __name__ == "__main__":
    sys.exit(main())
