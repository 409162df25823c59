"""Micronavigation against the simulated truth, and fused with a modelled DVL
(issue 29; docs/phase_centres.md "Current figures").

The seed's sand scene without its target (interface, volume, specular return, noise),
with bench_focus's platform motion (heave 3 cm / 5 s, sway 5 cm / 7 s, roll 1 deg / 4 s,
pitch 1 deg / 4.5 s, yaw 0.5 deg / 8 s), the configured projector order at 1 m/s. For
each consecutive pair of pings, :func:`svss_proc.micronav.horizontal.estimate_displacement`
is given the straight track's poses for position (a navigation that saw none of the
motion) and the true attitude, and its increments are compared with the true ones: rms
error per axis, the median of its sigma and rms(error / sigma), refusals, seconds per
pair.

Then a modelled DVL's increments (not the real chain: white errors per ping of
velocity sigma x ping interval, 3 mm/s as configured; five times that; a dropout whose
velocity is held from the stretch's start; a 0.5 % scale error along and a 1 deg
mounting misalignment) are fused with the echoes' (:func:`svss_proc.micronav.fusion.
fuse_increments`) and the positions' error within 25-ping apertures (rms about the
aperture's mean, the focusing's measure: lambda/8 = 7 mm) is reported with and without
the echoes. ``--image`` adds three points in the sand and images the pings with each
case's DVL and fused positions as bench_focus does: peak level against the true-pose
image. A modelled DVL, not the chain's: not bench_focus's cases.

    python benchmarks/bench_micronav.py --pings 60 --out benchmarks/results/bench_micronav.json
    python benchmarks/bench_micronav.py --pings 60 --image --out benchmarks/results/bench_micronav_image.json
    python benchmarks/bench_micronav.py --pings 30 --compare --out benchmarks/results/bench_micronav_kernels.json

``--compare`` times the numpy reference of the estimator against the numba kernel the
worker uses (:mod:`svss_proc.micronav.patch_focus`) on every pair, alternating which
goes first, and reports CPU (process) and wall seconds per pair, their ratio and the
largest difference of the estimates, with the machine's instruction set and the load
average before and after.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_device.environment_source import EnvironmentSource  # noqa: E402
from sim_device.scene import MotionConfig, PointTarget, load_scene  # noqa: E402
from sim_device.track import ping_pose  # noqa: E402
from svss_daq.config import HardwareConfig, config_path, load_with_text  # noqa: E402
from svss_daq.frames import body_to_ned  # noqa: E402
from svss_daq.waveform import make_waveform  # noqa: E402
from svss_proc.conditioning import Conditioner  # noqa: E402
from svss_proc.micronav.fusion import fuse_increments, increment_covariance  # noqa: E402
from benchmarks.bench_isa import machine_isa  # noqa: E402
from svss_proc.micronav.horizontal import TapCache, estimate_displacement  # noqa: E402

MOTION = dict(heave_m=0.03, heave_period_s=5.0, sway_m=0.05, sway_period_s=7.0,
              roll_deg=1.0, roll_period_s=4.0, pitch_deg=1.0, pitch_period_s=4.5,
              yaw_deg=0.5, yaw_period_s=8.0)
APERTURE = 25
DVL_SIGMA_M_S = 0.003


#: --image: three point scatterers in the sand under the stretch of pings 20-79 (the array
#: is 3 m ahead of the body origin), as the demo's (-20 dB), m
POINTS = ((7.0, 0.0, 0.30), (7.8, 0.32, 0.45), (8.6, -0.40, 0.60))


def scenes(with_points: bool):
    """The sand scene with the motion (and the points), and its straight track."""
    scene = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    points = tuple(PointTarget(along_m=a, cross_m=c, depth_m=d, target_strength_db=-20.0)
                   for a, c, d in POINTS) if with_points else ()
    straight = dataclasses.replace(scene, targets=(), points=points)
    return dataclasses.replace(straight, track=dataclasses.replace(
        straight.track, motion=MotionConfig(**MOTION))), straight


def estimates(n_pings: int, first: int, options: dict, with_points: bool = False,
              compare: bool = False):
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    taps = TapCache()
    hw = loaded.value
    scene, straight = scenes(with_points)
    src = EnvironmentSource(loaded, scene)
    pings = []
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 2)
    rows, prev = [], None
    synth_s = 0.0
    for i in range(first, first + n_pings):
        t0 = time.perf_counter()
        p = src.ping(i)
        synth_s += time.perf_counter() - t0
        cur = (p, cond.ping(p))
        pings.append(p)
        if prev is not None:
            (pa, ca), (pb, cb) = prev, cur
            ta, tb = pa.nav, pb.nav                     # the truth
            sa, sb = (ping_pose(straight.track, hw, k, src.seed) for k in (i - 1, i))
            ra = body_to_ned(ta.roll_rad, ta.pitch_rad, ta.heading_rad)
            rb = body_to_ned(tb.roll_rad, tb.pitch_rad, tb.heading_rad)
            args = (ca.data, cb.data, ca.t0_s, ca.dt_s, src.geometry, pa.projector,
                    pb.projector, ra, sa.ned, rb, sb.ned, ta.down_m + ta.altitude_m,
                    scene.medium.sound_speed_m_s, hw.waveform.center_hz)
            timed = {}
            if not rows:                 # the kernels loaded from numba's cache, untimed
                estimate_displacement(*args, **options)
            # --compare: the numpy reference and the numba kernel on the same pair, in
            # alternating order (the machine's load falls on both alike); the live
            # stage's cache of taps (one per ping, shared by its two pairs) for numba
            kernels = ("numpy", "numba") if compare else ("numba",)
            for kernel in (kernels if i % 2 else kernels[::-1]):
                extra = {"taps": taps} if kernel == "numba" else {}
                c0, t0 = time.process_time(), time.perf_counter()
                est = estimate_displacement(*args, **options, kernel=kernel, **extra)
                timed[kernel] = (est, time.process_time() - c0, time.perf_counter() - t0)
            est, cpu, sec = timed["numba"]
            row = {"ping": i - 1, "projectors": [pa.projector, pb.projector],
                   "true_m": (tb.ned - ta.ned).tolist(),
                   "est_m": est.displacement_m.tolist(),
                   "sigma_m": est.sigma_m.tolist(),
                   "cov_m2": est.cov_m2.tolist(), "refused": est.refused,
                   "coherence": est.coherence.tolist(), "seconds": sec, "cpu_s": cpu}
            if compare:
                old, ocpu, osec = timed["numpy"]
                row["numpy"] = {"seconds": osec, "cpu_s": ocpu, "refused": old.refused,
                                "est_m": old.displacement_m.tolist(),
                                "sigma_m": old.sigma_m.tolist()}
            rows.append(row)
        prev = cur
    return rows, synth_s / n_pings, hw.sequencer.ping_interval_s, pings, loaded, scene


def dvl_cases(true_inc: np.ndarray, interval_s: float, rng) -> dict:
    """Modelled DVL increments (north = along, the track's heading is 0) and their
    stated covariance per case."""
    n = true_inc.shape[0]
    s = DVL_SIGMA_M_S * interval_s
    noise = rng.normal(size=true_inc.shape)
    out = {}
    out["default"] = (true_inc + s * noise, [s] * 3)
    out["dvl_noise_x5"] = (true_inc + 5 * s * noise, [5 * s] * 3)
    held = np.repeat(true_inc[:1] + s * noise[:1], n, axis=0)
    out["dropout"] = (held, [0.3 * interval_s] * 3)     # dvl_gap_velocity_sigma_m_s
    turn = math.radians(1.0)
    rot = np.array([[math.cos(turn), -math.sin(turn), 0.0],
                    [math.sin(turn), math.cos(turn), 0.0], [0.0, 0.0, 1.0]])
    out["scale_0.5%_misalign_1deg"] = ((true_inc * [1.005, 1.0, 1.0]) @ rot.T + s * noise,
                                       [s] * 3)
    return out


def aperture_error(inc_err: np.ndarray) -> float:
    """Largest rms (3-D) within any APERTURE-ping window of the position error the
    increments' errors accumulate, about the window's mean, m."""
    pos = np.vstack([np.zeros(3), np.cumsum(inc_err, axis=0)])
    worst = 0.0
    for k in range(0, max(1, pos.shape[0] - APERTURE + 1)):
        w = pos[k:k + APERTURE]
        worst = max(worst, float(np.sqrt(np.mean(np.sum((w - w.mean(axis=0)) ** 2, axis=1)))))
    return worst


def image_cases(pings, hardware, scene, positions) -> dict:
    """Each case's DVL and fused poses (true attitude; positions from the first ping's
    true position plus the increments; the altitude keeps the true bottom) imaged as
    bench_focus images (its Focus and measure, processing-demo with the sand's sound
    speed and refraction tables): levels at the points against the true-pose image."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_focus as bf
    from svss_daq.config import ProcessingConfig
    text = (ROOT / "config/processing-demo.toml").read_text()
    text = text.replace("sediment_sound_speed_m_s = 1500.0", "sediment_sound_speed_m_s = 1767.0")
    text = text.replace('delays = "straight"', 'delays = "table"')
    tmp = Path(tempfile.mkdtemp(prefix="bench_micronav_")) / "processing-sand.toml"
    tmp.write_text(text)
    processing = load_with_text(ProcessingConfig, tmp)
    truth = [p.nav for p in pings]
    t_ned = np.array([n.ned for n in truth])
    bottom = np.array([n.down_m + n.altitude_m for n in truth])

    def posed(pos):
        pos = pos + t_ned[0]
        return [dataclasses.replace(n, north_m=float(q[0]), east_m=float(q[1]),
                                    down_m=float(q[2]), altitude_m=float(b - q[2]))
                for n, q, b in zip(truth, pos, bottom)]

    out = {}
    t0 = time.perf_counter()
    ref = bf.measure(bf.Focus(hardware, processing, pings, truth, "true"), scene, None)
    out["true"] = {"points": ref["points"], "pings_imaged": ref["pings_imaged"],
                   "seconds": time.perf_counter() - t0}
    print("peak level against the true poses (dB): mean / worst / per point")
    for name, (nav, fused) in positions.items():
        for kind, pos in (("dvl", nav), ("fused", fused)):
            t0 = time.perf_counter()
            res = bf.measure(bf.Focus(hardware, processing, pings, posed(pos),
                                      f"{name}/{kind}"), scene, ref["points"])
            lv = [p["level_db"] for p in res["points"]]
            out[f"{name}/{kind}"] = {"levels_db": lv, "mean_db": float(np.mean(lv)),
                                     "worst_db": float(np.min(lv)),
                                     "pings_imaged": res["pings_imaged"],
                                     "seconds": time.perf_counter() - t0}
            print(f"  {name:26s} {kind:5s} {np.mean(lv):6.2f} / {np.min(lv):6.2f} / "
                  f"{np.round(lv, 2).tolist()}  ({res['pings_imaged']} pings)")
    return out


def compare_kernels(rows: list) -> dict:
    """--compare: per pair estimated by both, the numpy reference's and the numba
    kernel's CPU and wall seconds (medians, and of the sums the ratio) and the largest
    differences of their estimates; refusals must agree."""
    both = [r for r in rows if r["refused"] is None]
    agree = all((r["refused"] is None) == (r["numpy"]["refused"] is None) for r in rows)
    d = np.array([np.subtract(r["est_m"], r["numpy"]["est_m"]) for r in both])
    sr = np.array([np.divide(r["sigma_m"], r["numpy"]["sigma_m"]) - 1.0 for r in both])
    med = lambda k, old: float(np.median([(r["numpy"] if old else r)[k] for r in both]))  # noqa: E731
    tot = lambda k, old: float(sum((r["numpy"] if old else r)[k] for r in both))  # noqa: E731
    out = {"pairs": len(both), "refusals_agree": agree,
           "numpy_cpu_s_per_pair": med("cpu_s", True), "numba_cpu_s_per_pair": med("cpu_s", False),
           "numpy_wall_s_per_pair": med("seconds", True),
           "numba_wall_s_per_pair": med("seconds", False),
           "cpu_ratio": tot("cpu_s", True) / tot("cpu_s", False),
           "wall_ratio": tot("seconds", True) / tot("seconds", False),
           "max_abs_displacement_difference_m": float(np.abs(d).max()) if both else None,
           "max_relative_sigma_difference": float(np.abs(sr).max()) if both else None}
    print(f"kernels over {out['pairs']} pairs (medians per pair; ratio of the sums):")
    print(f"  numpy reference  CPU {out['numpy_cpu_s_per_pair'] * 1e3:7.1f} ms   wall "
          f"{out['numpy_wall_s_per_pair'] * 1e3:7.1f} ms")
    print(f"  numba kernel     CPU {out['numba_cpu_s_per_pair'] * 1e3:7.1f} ms   wall "
          f"{out['numba_wall_s_per_pair'] * 1e3:7.1f} ms")
    print(f"  ratio            CPU {out['cpu_ratio']:7.2f}x     wall {out['wall_ratio']:7.2f}x")
    print(f"  estimates: largest difference {out['max_abs_displacement_difference_m']:.2e} m, "
          f"sigma {out['max_relative_sigma_difference']:.2e} relative; refusals agree: {agree}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pings", type=int, default=60)
    ap.add_argument("--first", type=int, default=20)
    ap.add_argument("--out", default=None)
    ap.add_argument("--gradient", default="none", choices=("none", "offset", "full"),
                    help="displacement_pass's gradient option (the alternatives measured)")
    ap.add_argument("--translations", type=int, default=2)
    ap.add_argument("--passes", type=int, default=2)
    ap.add_argument("--compare", action="store_true",
                    help="also run the numpy reference on every pair: CPU and wall time "
                         "per pair of both, their ratio and the largest difference of the "
                         "estimates")
    ap.add_argument("--image", action="store_true",
                    help="add three points to the scene and image it with the true, DVL "
                         "and fused poses of each case: peak loss against the true poses")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    load_before = os.getloadavg()
    rows, synth_s, interval, pings, hardware, scene = estimates(
        args.pings, args.first, dict(gradient=args.gradient, translations=args.translations,
                                     passes=args.passes), args.image, args.compare)
    load_after = os.getloadavg()
    ok = [r for r in rows if r["refused"] is None]
    true = np.array([r["true_m"] for r in rows])
    est = np.array([r["est_m"] for r in rows])
    sig = np.array([r["sigma_m"] for r in rows])
    good = np.array([r["refused"] is None for r in rows])
    err = (est - true)[good]
    summary = {
        "pairs": len(rows), "refused": int((~good).sum()),
        "refusals": sorted({r["refused"].split(":")[0] for r in rows if r["refused"]}),
        "rms_error_mm": (np.sqrt(np.mean(err ** 2, axis=0)) * 1e3).tolist(),
        "mean_error_mm": (err.mean(axis=0) * 1e3).tolist(),
        "median_sigma_mm": (np.median(sig[good], axis=0) * 1e3).tolist(),
        "rms_error_over_sigma": np.sqrt(np.mean((err / sig[good]) ** 2, axis=0)).tolist(),
        "true_increment_rms_about_mean_mm": (true.std(axis=0) * 1e3).tolist(),
        "seconds_per_pair_median": float(np.median([r["seconds"] for r in ok])),
        "cpu_seconds_per_pair_median": float(np.median([r["cpu_s"] for r in ok])),
        "synthesis_seconds_per_ping": synth_s}
    print(f"{len(rows)} ping pairs, {summary['refused']} refused "
          f"({'; '.join(summary['refusals'])})")
    print("axes north(along) / east(across) / down")
    for k in ("rms_error_mm", "mean_error_mm", "median_sigma_mm", "rms_error_over_sigma",
              "true_increment_rms_about_mean_mm"):
        print(f"  {k:34s} " + " / ".join(f"{v:6.2f}" for v in summary[k]))
    print(f"  seconds per pair (median, this machine) {summary['seconds_per_pair_median']:.3f}"
          f" wall, {summary['cpu_seconds_per_pair_median']:.3f} CPU")
    speed = compare_kernels(rows) if args.compare else None
    if speed is not None:
        summary["kernels"] = speed
    rng = np.random.default_rng(29)
    mic = np.where(good[:, None], est, np.nan)
    mcov = np.array([np.array(r["cov_m2"]) if r["refused"] is None else np.eye(3)
                     for r in rows])
    fusion = {}
    positions = {}
    print(f"worst {APERTURE}-ping aperture rms position error (mm): DVL alone / fused")
    for name, (inc, s) in dvl_cases(true, interval, rng).items():
        nav = np.vstack([np.zeros(3), np.cumsum(inc, axis=0)])
        ncov = np.array([increment_covariance(s)] * len(rows))
        x, _ = fuse_increments(nav, ncov, mic, mcov)
        positions[name] = (nav, x)
        e_nav = np.diff(nav, axis=0) - true
        e_fus = np.diff(x, axis=0) - true
        fusion[name] = {
            "dvl_step_rms_mm": (np.sqrt(np.mean(e_nav ** 2, axis=0)) * 1e3).tolist(),
            "fused_step_rms_mm": (np.sqrt(np.mean(e_fus ** 2, axis=0)) * 1e3).tolist(),
            "dvl_aperture_mm": aperture_error(e_nav) * 1e3,
            "fused_aperture_mm": aperture_error(e_fus) * 1e3}
        f = fusion[name]
        print(f"  {name:26s} {f['dvl_aperture_mm']:7.2f} / {f['fused_aperture_mm']:7.2f}   "
              f"(steps rms DVL {np.round(f['dvl_step_rms_mm'], 2)}, fused "
              f"{np.round(f['fused_step_rms_mm'], 2)})")
    images = image_cases(pings, hardware, scene, positions) if args.image else None
    out = {"command": " ".join(["python"] + [os.path.relpath(sys.argv[0], ROOT)]
                               + sys.argv[1:]),
           "machine": machine_isa(), "load_before": load_before, "load_after": load_after,
           "summary": summary, "fusion": fusion, "images": images, "pairs": rows,
           "args": vars(args), "wall_s": time.perf_counter() - t0}
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
