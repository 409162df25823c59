"""bench_focus's micronavigation cases (issue 29): the re-navigated poses fused with the
echoes' increments as ``svss process --micronav`` fuses them
(:func:`svss_proc.micronav.renav.fuse_with_navigation`, settings of
``config/processing.toml`` ``[micronav]``), and how the motion estimates compare with
the simulated truth: per axis (north = along, east = across for the scenes' heading 0,
down) the rms error of the echoes', the navigation's and the fused increments of the
array's position (:func:`report`), and rms(error / sigma) of the first two; the interface echo's correlation quality (the
estimator's patch coherences). A kept recording's report is recomputed by
``python benchmarks/bench_focus.py --work WORK --micronav-report VARIANT``."""

from __future__ import annotations

import math
import time

import numpy as np

from svss_daq.config import ProcessingConfig, config_path, load_with_text
from svss_daq.frames import body_to_ned
from svss_proc.micronav.renav import fuse_with_navigation, locked_steps


def micronav_config():
    """The ``[micronav]`` table of ``config/processing.toml``."""
    return load_with_text(ProcessingConfig, config_path("processing.toml")).value.micronav


def fused_poses(pings, renav_poses, hardware, processing, nav_cfg):
    """(fused poses, the result, seconds)."""
    t0 = time.perf_counter()
    res = fuse_with_navigation(pings, renav_poses, hardware.value, processing.value,
                               nav_cfg, micronav_config())
    return res.poses, res, time.perf_counter() - t0


def _rms(a) -> list:
    a = np.asarray(a)
    if a.size == 0:
        return [math.nan] * 3
    return [float(v) for v in np.sqrt(np.nanmean(a ** 2, axis=0))]


def array_points(poses, array_m) -> np.ndarray:
    """The array's reference point (lever arm ``array_m``) of each pose, NED (n, 3)."""
    a = np.asarray(array_m, dtype=np.float64)
    return np.array([np.asarray(p.ned) + body_to_ned(p.roll_rad, p.pitch_rad,
                                                      p.heading_rad) @ a for p in poses])


def report(res, renav_poses, truths, array_m) -> dict:
    """What bench_focus records of a micronavigation: counts, coherence, errors against
    the truth (module docstring), over every step and over the steps without bottom
    lock (the navigation's sigma the held velocity's).

    The increments compared are the array's (its reference point at ``array_m``, each
    pose set with its own attitude), what the imaging places: the body origin's carry
    the attitude's noise times the lever arms (HDT 0.17 deg over the DVL's 2.2 m: 6.5 mm
    across), which moves the array by the lever arm from the DVL head only (0.8 m). The
    echoes' increment of the array is the estimator's body-origin displacement plus the
    array's lever arm turned by the two poses' attitudes it was given (the
    re-navigation's)."""
    true_inc = np.diff(array_points(truths, array_m), axis=0)
    nav_inc = np.diff(array_points(renav_poses, array_m), axis=0)
    fus_inc = np.diff(array_points(res.poses, array_m), axis=0)
    mic, mcov = res.echoes.increments()
    lever = np.diff(array_points(renav_poses, array_m)
                    - np.array([p.ned for p in renav_poses]), axis=0)
    mic = mic + lever
    msig = np.sqrt(np.einsum("kii->ki", mcov))
    ok = np.all(np.isfinite(mic), axis=1)
    gap = ~locked_steps(renav_poses)
    coh = np.array([e.coherence for e in res.echoes.estimates
                    if e is not None and e.refused is None])
    nadir_all = np.array([e.coherence[0] for e in res.echoes.estimates
                          if e is not None and np.isfinite(e.coherence[0])])

    def errors(mask):
        e_mic = (mic - true_inc)[ok & mask]
        e_nav = (nav_inc - true_inc)[mask]
        return {"steps": int(mask.sum()), "echo_steps": int((ok & mask).sum()),
                "echo_rms_error_mm": [v * 1e3 for v in _rms(e_mic)],
                "echo_mean_error_mm": [float(v) * 1e3 for v in e_mic.mean(axis=0)]
                if e_mic.size else [math.nan] * 3,
                "echo_median_sigma_mm": [float(v) * 1e3 for v in np.median(
                    msig[ok & mask], axis=0)] if e_mic.size else [math.nan] * 3,
                "echo_rms_error_over_sigma": _rms(e_mic / msig[ok & mask]),
                "nav_rms_error_mm": [v * 1e3 for v in _rms(e_nav)],
                "nav_sigma_mm": [float(v) * 1e3 for v in np.median(
                    res.nav_sigma_m[mask], axis=0)] if mask.any() else [math.nan] * 3,
                "nav_rms_error_over_sigma": _rms(e_nav / res.nav_sigma_m[mask]),
                "fused_rms_error_mm": [v * 1e3 for v in _rms((fus_inc - true_inc)[mask])]}

    return {**res.summary(), "description": res.description,
            "nadir_coherence_median": float(np.median(coh[:, 0])) if coh.size else None,
            "nadir_coherence_min": float(np.min(coh[:, 0])) if coh.size else None,
            "nadir_coherence_median_all_pairs": float(np.median(nadir_all))
            if nadir_all.size else None,
            "patch_coherence_median": float(np.median(coh)) if coh.size else None,
            "all_steps": errors(np.ones(len(true_inc), dtype=bool)),
            "steps_without_bottom_lock": errors(gap) if gap.any() else None}


def print_report(name: str, r: dict) -> None:
    print(f"{name}: {r['description']}")
    print(f"  interface echo coherence (nadir patch, accepted pairs): median "
          f"{r['nadir_coherence_median']}, min {r['nadir_coherence_min']}; all patches' "
          f"median {r['patch_coherence_median']}")
    for key in ("all_steps", "steps_without_bottom_lock"):
        e = r.get(key)
        if not e:
            continue
        f = lambda v: " / ".join(f"{x:6.2f}" for x in v)          # noqa: E731
        print(f"  {key} ({e['steps']} steps, {e['echo_steps']} from the echoes), "
              "north / east / down:")
        print(f"    echoes  rms error {f(e['echo_rms_error_mm'])} mm, mean "
              f"{f(e['echo_mean_error_mm'])} mm, median sigma "
              f"{f(e['echo_median_sigma_mm'])} mm, rms(err/sigma) "
              f"{f(e['echo_rms_error_over_sigma'])}")
        print(f"    renav   rms error {f(e['nav_rms_error_mm'])} mm, sigma "
              f"{f(e['nav_sigma_mm'])} mm, rms(err/sigma) {f(e['nav_rms_error_over_sigma'])}")
        print(f"    fused   rms error {f(e['fused_rms_error_mm'])} mm")
