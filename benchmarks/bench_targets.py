#!/usr/bin/env python
"""Benchmark the target form functions of ``sim_device.targets``.

1. Cost per evaluation of each target type over the SVSS band (20–35 kHz).
2. Series truncation tolerance × frequency sampling against error and time: each
   (tol, n_freq) pair evaluates the band on n_freq points (nested in the reference
   grid); ``series_rel_err`` is the largest relative error at those points against a
   tol = 1e-13 reference, ``band_rel_err`` the largest error, relative to the band's
   peak |f|, after cubic-spline interpolation of the complex form function onto the
   fine grid (series and sampling errors together), ``band_rms_rel_err`` the RMS of
   that error relative to the RMS |f| (an energy measure), ``max_ts_err_db`` the
   largest TS error on the fine grid.
3. Error of the monostatic-equivalent (bisector) rule for spheres over the SVSS
   geometry (bistatic angle up to 29°).

Usage::

    python benchmarks/bench_targets.py --out bench_targets.json [--quick]

Prints the tables and writes them to ``--out`` (JSON, or CSV if the name ends .csv).
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_device.targets import (disc_backscatter, finite_cylinder_backscatter,  # noqa: E402
                                load_materials, sphere_backscatter,
                                sphere_bisector_error, sphere_scattering_amplitude)

log = logging.getLogger("bench_targets")

F_LO, F_HI = 20e3, 35e3


def _time(fn, min_time: float, max_repeat: int = 200) -> tuple[float, float]:
    """(minimum, median) wall time (s) of ``fn()`` over repeats lasting about
    ``min_time`` s (the minimum is the figure least disturbed by other jobs)."""
    fn()  # warm up
    times: list[float] = []
    t_end = time.perf_counter() + min_time
    while (time.perf_counter() < t_end or len(times) < 3) and len(times) < max_repeat:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.min(times)), float(np.median(times))


def cost_table(n_freq: int, min_time: float) -> list[dict]:
    mat = load_materials()
    w = mat.fluid("water_nominal")
    al, iron = mat.material("aluminium"), mat.material("cast_iron")
    wc, granite = mat.material("tungsten_carbide"), mat.material("granite")
    f = np.linspace(F_LO, F_HI, n_freq)
    aspects = np.linspace(0, np.pi, 181)
    thetas = np.pi - np.radians(np.linspace(0, 29, 48))
    cases = [
        ("rigid sphere (shot put, a=5.1 cm)", 1,
         lambda: sphere_backscatter(f, 0.051, w)),
        ("elastic sphere, cast iron (a=5.1 cm)", 1,
         lambda: sphere_backscatter(f, 0.051, w, iron)),
        ("elastic sphere, WC (a=19.05 mm)", 1,
         lambda: sphere_backscatter(f, 0.01905, w, wc)),
        ("elastic sphere bistatic, 48 angles", 48,
         lambda: sphere_scattering_amplitude(f, 0.051, w, iron, theta=thetas)),
        ("rigid cylinder 61 cm, broadside", 1,
         lambda: finite_cylinder_backscatter(f, 0.076, 0.61, w)),
        ("elastic Al cylinder 61 cm, broadside", 1,
         lambda: finite_cylinder_backscatter(f, 0.076, 0.61, w, al)),
        ("elastic Al cylinder 61 cm, 181 aspects", 181,
         lambda: finite_cylinder_backscatter(f, 0.076, 0.61, w, al, aspect=aspects)),
        ("Kirchhoff disc (granite, a=10 cm), 181 tilts", 181,
         lambda: disc_backscatter(f, 0.10, w, granite, tilt=aspects - np.pi / 2)),
    ]
    rows = []
    for name, n_ang, fn in cases:
        t, t_med = _time(fn, min_time)
        rows.append(dict(target=name, n_freq=n_freq, n_angles=n_ang, ms_per_call=t * 1e3,
                         ms_median=t_med * 1e3,
                         us_per_freq_angle=t * 1e6 / (n_freq * n_ang)))
        log.info("timed %s: %.3f ms", name, t * 1e3)
    return rows


def tolerance_sampling_table(tols, n_freqs, min_time: float, n_ref: int) -> list[dict]:
    mat = load_materials()
    w = mat.fluid("water_nominal")
    targets = [
        ("elastic sphere, cast iron a=5.1 cm",
         lambda f, tol: sphere_backscatter(f, 0.051, w, mat.material("cast_iron"), tol=tol)),
        ("elastic Al cylinder 61 cm broadside",
         lambda f, tol: finite_cylinder_backscatter(f, 0.076, 0.61, w,
                                                    mat.material("aluminium"), tol=tol)),
    ]
    f_ref = np.linspace(F_LO, F_HI, n_ref)
    rows = []
    for name, fn in targets:
        ref = fn(f_ref, 1e-13)
        scale = np.max(np.abs(ref))
        ts_ref = 20 * np.log10(np.abs(ref))
        for tol in tols:
            for nf in n_freqs:
                step = (n_ref - 1) // (nf - 1)
                if step * (nf - 1) != n_ref - 1:
                    raise ValueError(f"n_freq {nf} does not nest in the {n_ref}-point grid")
                f = f_ref[::step]
                vals = fn(f, tol)
                series_err = np.max(np.abs(vals - ref[::step]) / np.abs(ref[::step]))
                interp = CubicSpline(f, vals.real)(f_ref) + 1j * CubicSpline(f, vals.imag)(f_ref)
                err = np.max(np.abs(interp - ref)) / scale
                rms = np.sqrt(np.mean(np.abs(interp - ref) ** 2) / np.mean(np.abs(ref) ** 2))
                with np.errstate(divide="ignore"):
                    ts_err = np.max(np.abs(20 * np.log10(np.abs(interp)) - ts_ref))
                t, _ = _time(lambda: fn(f, tol), min_time / 4)
                rows.append(dict(target=name, tol=tol, n_freq=nf,
                                 series_rel_err=float(series_err),
                                 band_rel_err=float(err), band_rms_rel_err=float(rms),
                                 max_ts_err_db=float(ts_err),
                                 ms_per_call=t * 1e3))
    return rows


def bistatic_table(n_freq: int) -> list[dict]:
    mat = load_materials()
    w = mat.fluid("water_nominal")
    f = np.linspace(F_LO, F_HI, n_freq)
    betas_deg = np.array([2.0, 5.0, 10.0, 15.0, 20.0, 29.0])
    targets = [("rigid sphere a=1 cm", 0.01, None),
               ("WC sphere a=19.05 mm", 0.01905, mat.material("tungsten_carbide")),
               ("rigid shot put a=5.1 cm", 0.051, None),
               ("cast-iron shot put a=5.1 cm", 0.051, mat.material("cast_iron"))]
    rows = []
    for name, a, m in targets:
        for method in ("bisector", "kell"):
            ts, rel = sphere_bisector_error(f, a, w, m, np.radians(betas_deg), method)
            exact = np.abs(sphere_scattering_amplitude(f, a, w, m,
                                                       theta=np.pi - np.radians(betas_deg)))
            approx = exact * 10 ** (ts / 20)
            band_db = 10 * np.log10(np.mean(approx**2, axis=0) / np.mean(exact**2, axis=0))
            for i, b in enumerate(betas_deg):
                rows.append(dict(target=name, method=method, beta_deg=float(b),
                                 max_abs_ts_err_db=float(np.max(np.abs(ts[:, i]))),
                                 band_avg_ts_err_db=float(band_db[i]),
                                 max_rel_complex_err=float(np.max(rel[:, i]))))
    return rows


def _print(title: str, rows: list[dict]) -> None:
    print(f"\n## {title}")
    if not rows:
        return
    keys = list(rows[0])
    fmt = []
    for k in keys:
        v = rows[0][k]
        fmt.append("{:>10.3g}" if isinstance(v, float) else "{:>10}")
    print(" | ".join(f"{k}" for k in keys))
    for r in rows:
        print(" | ".join(f.format(r[k]).strip() if not isinstance(r[k], str) else r[k]
                         for f, k in zip(fmt, keys)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output file (.json or .csv)")
    p.add_argument("--n-freq", type=int, default=256, help="band points for the cost table")
    p.add_argument("--min-time", type=float, default=1.0,
                   help="seconds of repeats per timing (minimum and median reported)")
    p.add_argument("--quick", action="store_true", help="small tables (smoke run)")
    p.add_argument("-v", "--verbose", action="store_true")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if args.quick:
        tols, nfs, n_ref, min_time = [1e-3, 1e-10], [65, 257], 1025, 0.1
    else:
        tols = [1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12]
        nfs = [33, 65, 129, 257, 513, 1025]
        n_ref, min_time = 8193, args.min_time
    info = dict(python=sys.version.split()[0], numpy=np.__version__,
                cpu_count=os.cpu_count(), band_hz=[F_LO, F_HI])
    cost = cost_table(args.n_freq, min_time)
    _print(f"Cost per evaluation, {args.n_freq} frequencies over 20-35 kHz", cost)
    tolsamp = tolerance_sampling_table(tols, nfs, min_time, n_ref)
    _print(f"Tolerance x frequency sampling (reference: tol 1e-13 on {n_ref} points)",
           tolsamp)
    bist = bistatic_table(128 if args.quick else 256)
    _print("Bisector rule error for spheres over 20-35 kHz", bist)
    out = Path(args.out)
    tables = dict(cost=cost, tolerance_sampling=tolsamp, bistatic=bist)
    if out.suffix.lower() == ".csv":
        with open(out, "w", newline="") as fh:
            for name, rows in tables.items():
                fh.write(f"# {name}\n")
                wr = csv.DictWriter(fh, fieldnames=list(rows[0]))
                wr.writeheader()
                wr.writerows(rows)
    else:
        out.write_text(json.dumps(dict(info=info, **tables), indent=1))
    print(f"\nwritten {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
