#!/usr/bin/env python
"""Would a factorised back-projection buy the live worker its margin? A measured answer.

Issue 32 asks whether a coarse-to-fine or factorised back-projection could cut the
imaging's work, with its error in the trade table. This benchmark tries the form that
suits one ping of this array. First, each ping is beamformed onto a coarse grid about
its array's centre O (stage 1: 80 channels a point). Then the grid is interpolated into
the voxels (stage 2: one look-up a voxel). The stage-1 grid's coordinates are:

* ``rho`` = (|p - projector| + |p - O|) / 2: surfaces of constant rho are the ellipsoids
  of constant reference delay, so a ping's thin echo shell lies along the grid;
* the direction cosines ``ux``, ``uy`` of p - O.

The grid holds the ping's image demodulated by the reference phase exp(j 2 pi f_c
2 rho / c). Its band is then set by the receive aperture's extent, not by the carrier:
|ux| and |uy| step at most lambda_min / (2 x the receivers' largest offset from O)
(Nyquist), and rho at c / (4 x the half bandwidth). ``q`` (angles) and ``qr`` (rho)
oversample those steps. Stage 2 interpolates trilinearly and remodulates.

The reference is the project's kernel (linear taps, float32, straight rays: the
prototype has no refraction table) on the same pings. Its error against the high-fidelity
imaging of `bench_imaging.py`'s options table is the default's -43 dB. Reported for each
(q, qr): the stage-1 voxel-channel updates against the direct kernel's, the tile image's
error (rms over the voxels within 40 dB of the peak, and the largest), and the level
change of the point responses. The prototype's kernels are plain numba (float64,
unoptimised), so its seconds are not a speed figure; the update counts are the work.
The pings are `bench_imaging.py`'s demo pings 100-239 (its point scatterers moved 12 m
along the track, the 80-channel array, the tile frame some 230 m from the survey
origin), imaged into their fullest tile.

    python benchmarks/bench_factorised.py --grids 2:2,3:3 --out benchmarks/results/bench_factorised.json
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections import Counter
from pathlib import Path

import numba as nb
import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_imaging import scene_for  # noqa: E402
from bench_isa import machine_isa  # noqa: E402
from sim_device.environment_source import EnvironmentSource  # noqa: E402
from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load, load_with_text  # noqa: E402
from svss_daq.conventions import REMODULATION_SIGN  # noqa: E402
from svss_proc.imaging.cpu_kernel import run_ping  # noqa: E402
from svss_proc.imaging.imager import TileImager  # noqa: E402
from svss_proc.imaging.kernel_args import LINEAR, SHIFT, DelayModel, ImageSlice  # noqa: E402

log = logging.getLogger("bench_factorised")


@nb.njit(parallel=True, fastmath=True)
def stage1(y, t0, inv_dt, sig, c, tx, rx, o, bore, cos_rx, grid_lo, step, out):
    """The ping's demodulated image at the grid (ux, uy, rho): out[jx, jy, ir]."""
    nux, nuy, nr = out.shape
    d0, d1, d2 = o[0] - tx[0], o[1] - tx[1], o[2] - tx[2]
    dd = d0 * d0 + d1 * d1 + d2 * d2
    nt = y.shape[1]
    for jx in nb.prange(nux):
        ux = grid_lo[0] + jx * step[0]
        for jy in range(nuy):
            uy = grid_lo[1] + jy * step[1]
            w = 1.0 - ux * ux - uy * uy
            if w <= 0.0:
                continue
            uz = math.sqrt(w)
            du = d0 * ux + d1 * uy + d2 * uz
            for ir in range(nr):
                rho = grid_lo[2] + ir * step[2]
                r = (4.0 * rho * rho - dd) / (2.0 * du + 4.0 * rho)   # |p - O| on the ellipsoid
                px, py, pz = o[0] + r * ux, o[1] + r * uy, o[2] + r * uz
                ex, ey, ez = px - tx[0], py - tx[1], pz - tx[2]
                r1 = math.sqrt(ex * ex + ey * ey + ez * ez)
                sr = 0.0
                si = 0.0
                for ch in range(rx.shape[0]):
                    fx, fy, fz = px - rx[ch, 0], py - rx[ch, 1], pz - rx[ch, 2]
                    r2 = math.sqrt(fx * fx + fy * fy + fz * fz)
                    if fx * bore[0] + fy * bore[1] + fz * bore[2] < r2 * cos_rx:
                        continue
                    tau = (r1 + r2) / c
                    u = (tau - t0) * inv_dt
                    if u < 0.0 or u > nt - 1.001:
                        continue
                    i0 = int(u)
                    f = u - i0
                    vr = (1.0 - f) * y[ch, i0].real + f * y[ch, i0 + 1].real
                    vi = (1.0 - f) * y[ch, i0].imag + f * y[ch, i0 + 1].imag
                    ph = sig * (tau - 2.0 * rho / c)
                    cr, ci = math.cos(ph), math.sin(ph)
                    sr += vr * cr - vi * ci
                    si += vr * ci + vi * cr
                out[jx, jy, ir] = complex(sr, si)


@nb.njit(parallel=True, fastmath=True)
def stage2(grid, sig, c, tx, o, bore, cos_tx, ax, cy, dz, ia0, ia1, grid_lo, step, img):
    """The grid interpolated (trilinear) into the voxels of the projector's cone and
    remodulated: img[ia - ia0, ic, iz] (a ping's slice)."""
    nux, nuy, nr = grid.shape
    for ka in nb.prange(ia1 - ia0):
        x = ax[ia0 + ka]
        for ic in range(cy.size):
            for iz in range(dz.size):
                ex, ey, ez = x - tx[0], cy[ic] - tx[1], dz[iz] - tx[2]
                r1 = math.sqrt(ex * ex + ey * ey + ez * ez)
                if ex * bore[0] + ey * bore[1] + ez * bore[2] < r1 * cos_tx:
                    continue
                gx, gy, gz = x - o[0], cy[ic] - o[1], dz[iz] - o[2]
                r = math.sqrt(gx * gx + gy * gy + gz * gz)
                rho = 0.5 * (r1 + r)
                fx = (gx / r - grid_lo[0]) / step[0]
                fy = (gy / r - grid_lo[1]) / step[1]
                fr = (rho - grid_lo[2]) / step[2]
                jx, jy, jr = int(fx), int(fy), int(fr)
                if (jx < 0 or jy < 0 or jr < 0 or jx >= nux - 1 or jy >= nuy - 1
                        or jr >= nr - 1):
                    continue
                a, b, e = fx - jx, fy - jy, fr - jr
                v = ((1 - a) * ((1 - b) * ((1 - e) * grid[jx, jy, jr] + e * grid[jx, jy, jr + 1])
                                + b * ((1 - e) * grid[jx, jy + 1, jr] + e * grid[jx, jy + 1, jr + 1]))
                     + a * ((1 - b) * ((1 - e) * grid[jx + 1, jy, jr] + e * grid[jx + 1, jy, jr + 1])
                            + b * ((1 - e) * grid[jx + 1, jy + 1, jr]
                                   + e * grid[jx + 1, jy + 1, jr + 1])))
                ph = sig * 2.0 * rho / c
                img[ka, ic, iz] = v * complex(math.cos(ph), math.sin(ph))


def baseband(kd, sig):
    """The ping's complex baseband samples from the kernel's linear tap planes (plane 0
    is the analytic signal times exp(-j theta (0 - shift)))."""
    p = kd.planes
    dt = 1.0 / float(p.inv_dt)
    a = (p.re[0].astype(np.float64) + 1j * p.im[0]) * np.exp(-1j * float(p.theta) * SHIFT[LINEAR])
    t = float(p.t0) + dt * np.arange(a.shape[1])
    return np.ascontiguousarray(a * np.exp(-1j * sig * t)), float(p.t0), dt


def factorised_ping(out, kd, array, q, qr, c, sig, f_max, half_band, img):
    """Add one ping into ``img`` (the tile, complex128) by the two stages; returns the
    stage-1 voxel-channel updates (grid points x channels)."""
    ax = out.axes
    tx, rx, bore = (np.asarray(v, dtype=np.float64) for v in (array.tx, array.rx, array.bore))
    o = rx.mean(axis=0)
    A, C, D = np.meshgrid(ax.along[out.ia0:out.ia1], ax.cross, ax.depth, indexing="ij")
    e = np.stack([A - tx[0], C - tx[1], D - tx[2]])
    r1 = np.sqrt((e ** 2).sum(0))
    inside = (e[0] * bore[0] + e[1] * bore[1] + e[2] * bore[2]) >= r1 * array.cos_tx
    if not inside.any():
        return 0
    g = np.stack([A - o[0], C - o[1], D - o[2]])
    r = np.sqrt((g ** 2).sum(0))
    coords = [g[0][inside] / r[inside], g[1][inside] / r[inside], 0.5 * (r1 + r)[inside]]
    lam_min = c / f_max
    step = np.array([lam_min / (2 * np.abs(rx[:, 0] - o[0]).max()) / q,
                     lam_min / (2 * np.abs(rx[:, 1] - o[1]).max()) / q,
                     c / (4 * half_band) / qr])
    lo = np.array([v.min() for v in coords]) - step
    shape = tuple(int((v.max() + s - l) / s) + 2 for v, s, l in zip(coords, step, lo))
    grid = np.zeros(shape, np.complex128)
    y, t0, dt = baseband(kd, sig)
    stage1(y, t0, 1.0 / dt, sig, c, tx, rx, o, bore, array.cos_rx, lo, step, grid)
    sl = np.zeros((out.ia1 - out.ia0, len(ax.cross), len(ax.depth)), np.complex128)
    stage2(grid, sig, c, tx, o, bore, array.cos_tx, ax.along, ax.cross, ax.depth, out.ia0,
           out.ia1, lo, step, sl)
    img[out.ia0:out.ia1] += sl
    return grid.size * rx.shape[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", default="2:2,3:3",
                    help="q:qr pairs: oversampling of the angle and rho steps over Nyquist")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    grids = [tuple(float(v) for v in p.split(":")) for p in args.grids.split(",")]
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = load(ProcessingConfig, config_path("processing.toml"))
    wf = hw.value.waveform
    f_max = max(wf.f_start_hz, wf.f_stop_hz)
    half_band = abs(wf.f_start_hz - wf.f_stop_hz) / 2
    c = proc.imaging.water_sound_speed_m_s
    sig = REMODULATION_SIGN * 2 * math.pi * wf.center_hz
    # the demo pings, imaged by the project's imager; its kernel calls are kept
    src = EnvironmentSource(hw, scene_for(340))
    imager = TileImager(hw, proc)
    calls = []
    kernel = imager.accumulator.kernel

    def keep(out, kd, array, delays, gating=True, **kw):
        calls.append((out, kd, array))
        return kernel(out, kd, array, delays, gating=gating, **kw)

    imager.accumulator.kernel = keep
    log.info("simulating and imaging 140 demo pings")
    for i in range(100, 240):
        imager.add(src.ping(i))
    fullest = Counter(id(o.re) for o, _, _ in calls).most_common(1)[0][0]
    mine = [cl for cl in calls if id(cl[0].re) == fullest]
    ax = mine[0][0].axes
    shape = (len(ax.along), len(ax.cross), len(ax.depth))
    ref = np.zeros(shape, np.complex128)
    n_direct = 0
    straight = DelayModel("straight", c, c)
    t = time.perf_counter()
    for out, kd, array in mine:
        re = np.zeros(shape, np.float32)
        im = np.zeros_like(re)
        n_direct += run_ping(ImageSlice(re, im, ax, out.ia0, out.ia1), kd, array, straight)
        ref += re + 1j * im
    t_direct = time.perf_counter() - t
    mag = np.abs(ref)
    peak = mag.max()
    lit = mag > peak * 10 ** (-40 / 20)
    peaks = np.argwhere((mag == ndimage.maximum_filter(mag, size=9)) & (mag > 0.1 * peak))
    log.info("tile %s from %d pings: %.3e direct updates (%.1f s)", shape, len(mine),
             n_direct, t_direct)
    rows = []
    for q, qr in grids:
        img = np.zeros(shape, np.complex128)
        t = time.perf_counter()
        n1 = sum(factorised_ping(out, kd, array, q, qr, c, sig, f_max, half_band, img)
                 for out, kd, array in mine)
        el = time.perf_counter() - t
        err = img - ref
        rms = np.sqrt(np.mean(np.abs(err[lit]) ** 2) / np.mean(mag[lit] ** 2))
        change = [float(20 * np.log10(abs(img[tuple(p)]) / mag[tuple(p)])) for p in peaks]
        row = {"q_angle": q, "q_rho": qr, "stage1_updates": int(n1),
               "direct_updates": int(n_direct), "fewer_updates": n_direct / n1,
               "tile_error_rms_db": float(20 * np.log10(rms)),
               "tile_error_max_db": float(20 * np.log10(np.abs(err).max() / peak)),
               "point_level_change_db": [round(v, 2) for v in change],
               "prototype_seconds": el}
        rows.append(row)
        log.info("q %.1f, qr %.1f: %.1fx fewer channel updates; tile error %.1f dB rms, "
                 "%.1f dB at most; %d points %.2f .. %.2f dB", q, qr, row["fewer_updates"],
                 row["tile_error_rms_db"], row["tile_error_max_db"], len(change),
                 min(change), max(change))
    result = {"command": "python benchmarks/bench_factorised.py " + " ".join(argv or sys.argv[1:]),
              "machine": machine_isa(), "tile_shape": list(shape), "tile_pings": len(mine),
              "direct_updates": int(n_direct), "direct_seconds": t_direct,
              "points": len(peaks), "rows": rows}
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        log.info("saved %s", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
