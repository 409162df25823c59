#!/usr/bin/env python
"""Focus of the image with the navigation the chain measures (issue 26, docs/navigation.md,
"Focus").

A synthetic aperture focuses only when the array's motion between pings is known to a
fraction of a wavelength. For each scene (the demo, and a copy of it with platform
motion) and each set of navigation instruments (``config/sim-device.toml``, a GPS at RTK
accuracy, the DVL with twice its noise), the real chain records a run: ``svss
sim-device`` (the simulated sonar, DVL and GPS on their real protocols, its own process)
-> ``svss acquire`` (the daemon, its own process, recording raw-run files). The recorded
pings are then imaged as ``svss process`` images them (:class:`TileImager` of the run's
hardware and the processing configuration, pings through the :class:`PingGate`) three
times, with the same samples and three sets of poses:

* ``true``: the simulator's own poses (:func:`sim_device.track.ping_pose` of each
  recorded ping's track ping, from its transmit time; these are the poses ``svss
  simulate`` writes, whose samples are identical);
* ``live``: the poses the daemon recorded (its navigation, live);
* ``renav``: :func:`svss_daq.nav.renavigate.renavigate` of the run (the re-navigation
  from the recorded instrument records), when that module is importable ("n/a" if not).

Per point target of the scene, around the peak of the 2 cm tile image nearest to the
point, the image is sampled again with the same kernel and the same per-ping geometry
(the imager's conditioner, array placement, delay tables and kernel) on fine grids: a
cube of +-3 cm at 3 mm, then +-3 mm at 0.75 mm around its maximum, and three lines
through the peak (+-20 cm at 2 mm) for the -3 dB widths. Reported per point: the peak
level against the true-pose image's peak of the same point (dB), the -3 dB widths
(along, cross, depth), and the peak's position error against the scene's truth: along
and cross in the scene's track frame (from the image's tile frame through its track
line to the survey frame) and depth below the interface; relative positions between the
points (largest pairwise error, horizontal and depth) and absolute ones. The fine
sampler is checked against the tile: at a voxel centre it gives the tile's value.

Usage::

    python benchmarks/bench_focus.py --quick --out benchmarks/results/bench_focus.json
    python benchmarks/bench_focus.py --variants --out benchmarks/results/bench_focus.json

``--quick``: the demo scene, default instruments; without ``--variants`` both scenes
with the default instruments; ``--variants`` adds the RTK GPS and the twice- and
five-times-noisier DVL (``--variants rtk`` one of them); ``--scenes demo`` one scene;
``--autofocus`` adds the poses ``af``: the re-navigated poses after the autofocus on the
re-navigated image's isolated responses (:mod:`svss_proc.micronav.autofocus`), e.g.

    python benchmarks/bench_focus.py --quick --variants dvl_noise_x5 --autofocus

``--micronav-report VARIANT --work WORK``: the micronavigation report
(``focus_micronav``) of a kept sand recording, recomputed (no chain run).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_device.device_process import load_sim_device_config  # noqa: E402
from sim_device.scene import load_scene  # noqa: E402
from sim_device.track import parse_utc_ns, ping_pose, truth_line  # noqa: E402
from svss_daq.config import (ProcessingConfig, config_path, load_with_text)  # noqa: E402
from svss_daq.ping_gate import PingGate, PingRejected  # noqa: E402
from svss_daq.rawfile import RawRunReader  # noqa: E402
from svss_proc.imaging.imager import TileImager  # noqa: E402
from svss_proc.micronav.autofocus import _Sampler  # noqa: E402
from svss.demo import stop_process  # noqa: E402

log = logging.getLogger("bench_focus")

DEMO_SCENE = ROOT / "config/scenes/demo.toml"
DEFAULT_PROCESSING = ROOT / "config/processing-demo.toml"     # what svss demo images with
DEFAULT_SIM = ROOT / "config/sim-device.toml"

#: platform motion of the "motion" scene: issue 26's amplitudes; periods of a 9 m
#: pontoon boat in a short chop (roll and pitch 4-5 s, heave 5 s, sway and yaw slower)
MOTION = {"heave_m": 0.03, "heave_period_s": 5.0, "sway_m": 0.05, "sway_period_s": 7.0,
          "roll_deg": 1.0, "roll_period_s": 4.0, "pitch_deg": 1.0, "pitch_period_s": 4.5,
          "yaw_deg": 0.5, "yaw_period_s": 8.0}

#: instrument variants: {section: {key: value or ("x", factor)}} applied to sim-device.toml
VARIANTS = {
    "default": {},
    # RTK fixed: ~2 cm horizontal, 3 cm vertical; GGA fix quality 4 (RTK fixed integer)
    "rtk": {"gps": {"position_sigma_m": 0.02, "height_sigma_m": 0.03, "fix_quality": 4}},
    "dvl_noise_x2": {"dvl": {"velocity_sigma_m_s": ("x", 2.0), "range_sigma_m": ("x", 2.0)}},
    "dvl_noise_x5": {"dvl": {"velocity_sigma_m_s": ("x", 5.0), "range_sigma_m": ("x", 5.0)}},
    # issue 29: no bottom lock for 10 s (5-15 s of the track: the sand scene's points lie
    # under its middle); a 0.5 % velocity scale error and a 1 deg mounting misalignment
    "dvl_dropout": {"dvl": {"dropout_start_s": 5.0, "dropout_s": 10.0}},
    "dvl_scale_misalign": {"dvl": {"velocity_scale_error": 0.005, "misalignment_deg": 1.0}},
}
#: --micronav: the re-navigation told the noise of the DVL the variant has (the fusion
#: weighs the DVL's increments by the navigation's dvl_velocity_sigma_m_s): factors of
#: the recorded navigation configuration's keys
VARIANT_NAVIGATION = {"dvl_noise_x2": {"dvl_velocity_sigma_m_s": 2.0, "dvl_range_sigma_m": 2.0},
                      "dvl_noise_x5": {"dvl_velocity_sigma_m_s": 5.0, "dvl_range_sigma_m": 5.0}}
#: ``af``: the re-navigated poses (the live ones without re-navigation) after the
#: autofocus on the image's isolated responses (svss_proc.micronav.autofocus; --autofocus)
POSES = ("true", "live", "renav", "af", "fused", "fused_af")

#: issue 29's sand scene (--scenes sand): the seed's sand (interface, volume, specular
#: return, noise) without its cylinder, with the motion above and three points in the
#: sand (-20 dB, as the demo's) under the middle of the DVL dropout of ``dvl_dropout``
SAND_SCENE = ROOT / "config/scenes/seed_cylinder_sand.toml"
SAND_PINGS = 200
SAND_POINTS = ((12.5, 0.0, 0.30), (13.3, 0.32, 0.45), (14.1, -0.40, 0.60))
#: sand: only the pings whose array is within this of the points (along) are imaged, m
SAND_IMAGE_MARGIN_M = 2.5
#: sand: the sediment's sound speed for the imaging's refraction (the seed's medium sand)
SAND_SEDIMENT_SPEED_M_S = 1767.0

#: fine sampling around each peak (m): coarse-to-fine cubes and the width lines
CUBE1_HALF, CUBE1_STEP = 0.030, 0.003
CUBE2_HALF, CUBE2_STEP = 0.003, 0.00075
LINE_HALF, LINE_STEP = 0.20, 0.002
#: search around each point's expected position in the 2 cm image (along/cross, depth), m
SEARCH_WIDE = (0.35, 0.20)
SEARCH_NARROW = (0.12, 0.10)

STARTUP_S = 180.0


# --------------------------------------------------------------------------- inputs


def _set_key(text: str, section: str, key: str, value) -> str:
    """``key = value`` of ``[section]`` in TOML text replaced (comments kept); a factor
    ``("x", f)`` multiplies the present value."""
    lines = text.splitlines(keepends=True)
    sect = None
    for i, line in enumerate(lines):
        m = re.match(r"\s*\[([^\]]+)\]\s*(#.*)?$", line)
        if m:
            sect = m.group(1).strip()
            continue
        m = re.match(rf"(\s*{re.escape(key)}\s*=\s*)([^#\n]*?)(\s*(#.*)?\n?)$", line)
        if sect == section and m:
            if isinstance(value, tuple):
                value = float(m.group(2)) * value[1]
            lines[i] = f"{m.group(1)}{value!r}{m.group(3)}"
            return "".join(lines)
    raise KeyError(f"{section}.{key} not found in the sim-device configuration")


def write_variant(name: str, base: Path, folder: Path) -> Path:
    text = base.read_text()
    for section, keys in VARIANTS[name].items():
        for key, value in keys.items():
            text = _set_key(text, section, key, value)
    path = folder / f"sim-device-{name}.toml"
    path.write_text(text)
    load_sim_device_config(path)                 # validated before any process starts
    return path


def _write_with_motion(text: str, path: Path) -> Path:
    """The scene ``text`` with the platform motion (MOTION) added, written to ``path``
    and validated."""
    text = text.rstrip("\n") + "\n\n# bench_focus: platform motion (issue 26)\n[track.motion]\n"
    path.write_text(text + "".join(f"{k} = {v!r}\n" for k, v in MOTION.items()))
    load_scene(path)
    return path


def write_motion_scene(base: Path, folder: Path) -> Path:
    text = base.read_text().replace('name = "demo-points"', 'name = "demo-points-motion"')
    return _write_with_motion(text, folder / "demo-motion.toml")


def write_sand_scene(folder: Path) -> Path:
    """The sand scene (SAND_*): the seed's, its cylinder taken out, the points and the
    motion added, SAND_PINGS pings."""
    text = SAND_SCENE.read_text()
    text = text[:text.index("# The cylinder")]
    text = re.sub(r'name = "seed-cylinder-sand"', 'name = "sand-points-motion"', text)
    text = re.sub(r"n_pings = \d+", f"n_pings = {SAND_PINGS}", text)
    text += "\n# bench_focus (issue 29): points in the sand\n" + "".join(
        f"[[points]]\nalong_m = {a!r}\ncross_m = {c!r}\ndepth_m = {d!r}\n"
        "target_strength_db = -20.0\n\n" for a, c, d in SAND_POINTS)
    return _write_with_motion(text, folder / "sand-motion.toml")


def sand_processing(base: Path, folder: Path):
    """``base`` with the sand's sediment speed and the refraction tables."""
    text = base.read_text()
    text = re.sub(r"sediment_sound_speed_m_s = [0-9.]+",
                  f"sediment_sound_speed_m_s = {SAND_SEDIMENT_SPEED_M_S!r}", text)
    text = re.sub(r'delays = "\w+"', 'delays = "table"', text)
    path = folder / "processing-sand.toml"
    path.write_text(text)
    return load_with_text(ProcessingConfig, path)


def presynthesised(scene_path: Path, folder: Path, hardware: Path) -> Path:
    """The scene's pings synthesised once (``svss simulate``) for ``svss sim-device
    --from-run``: the sand scene costs more than a ping interval a ping on 2 cores, and
    the device drops a ping whose samples are late. Kept in ``folder`` for reruns."""
    out = folder / f"{scene_path.stem}-simulated.h5"
    if not out.exists():
        t0 = time.perf_counter()
        subprocess.run(_svss("simulate", "--scene", str(scene_path), "--hardware",
                             str(hardware), "--out", str(out)), check=True, cwd=ROOT,
                       env=_env(), stdout=subprocess.DEVNULL)
        log.info("%s synthesised in %.0f s", out, time.perf_counter() - t0)
    return out


# --------------------------------------------------------------------------- the chain


def _svss(*args: str) -> list[str]:
    return [sys.executable, "-m", "svss", *args]


def _env() -> dict:
    """The chain's processes run this tree's packages (the one the benchmark imports),
    whatever the installed ones are."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get(
        "PYTHONPATH", "").split(os.pathsep) if p])
    return env


def record(scene_path: Path, sim_config: Path, folder: Path, hardware: Path,
           lead_s: float, from_run: Path | None = None) -> dict:
    """``svss sim-device`` -> ``svss acquire`` into ``folder``; the recording's files and
    what the device said."""
    folder.mkdir(parents=True, exist_ok=True)
    devices, logs = folder / "devices.toml", folder / "logs"
    logs.mkdir(exist_ok=True)
    n_pings = load_scene(scene_path).track.n_pings
    sim = None
    t0 = time.perf_counter()
    try:
        with open(logs / "sim-device.log", "wb") as err:
            sim = subprocess.Popen(
                _svss("sim-device", "--scene", str(scene_path), "--hardware", str(hardware),
                      "--sim-config", str(sim_config), "--devices-out", str(devices),
                      "--lead", str(lead_s),
                      *(("--from-run", str(from_run)) if from_run else ())),
                stdout=subprocess.DEVNULL, stderr=err,
                cwd=ROOT, env=_env())
        deadline = time.monotonic() + STARTUP_S
        while not devices.exists():
            if sim.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("svss sim-device did not start; its log ends:\n"
                                   + (logs / "sim-device.log").read_text()[-2000:])
            time.sleep(0.05)
        with open(logs / "acquire.log", "wb") as err:
            rc = subprocess.run(
                _svss("acquire", "--hardware", str(hardware), "--devices", str(devices),
                      "--out", str(folder / "runs"), "--run-id", "focus", "--pings",
                      str(n_pings), "--ephemeral-ports"),
                stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT, env=_env(),
                timeout=STARTUP_S + lead_s + 10 * n_pings).returncode
        if rc != 0:
            raise RuntimeError(f"svss acquire failed with exit code {rc}; see "
                               f"{logs / 'acquire.log'}")
    finally:
        stop_process(sim)
    sim_log = (logs / "sim-device.log").read_text(errors="replace")
    first = re.search(r"first ping is track ping (\d+)", sim_log)
    late = re.search(r"'late': (\d+)", sim_log)
    files = sorted((folder / "runs").glob("focus_*.h5"))
    if not files:
        raise RuntimeError(f"no recording in {folder / 'runs'}")
    return {"files": files, "first_track_ping": int(first.group(1)) if first else None,
            "device_late_pings": int(late.group(1)) if late else None,
            "chain_wall_s": time.perf_counter() - t0}


# --------------------------------------------------------------------------- poses


def true_poses(pings, scene, hw) -> list:
    """The simulator's pose of each recorded ping: its track ping from its transmit time
    (the sequencer's grid: track start + k x interval)."""
    t0 = parse_utc_ns(scene.track.start_time_utc)
    interval_ns = hw.value.sequencer.ping_interval_s * 1e9
    out = []
    for p in pings:
        k = (p.transmit_time_ns - t0) / interval_ns
        if abs(k - round(k)) > 1e-3:
            raise RuntimeError(f"ping {p.sequence}: transmit time {p.transmit_time_ns} is "
                               f"not on the track's ping grid (k = {k:.4f})")
        out.append(ping_pose(scene.track, hw.value, int(round(k)), scene.scene.seed))
    return out


def renav_poses(files: list[Path], pings, nav_cfg=None) -> tuple[list | None, str, object]:
    """The re-navigation's poses of ``pings`` (:func:`svss_daq.nav.renavigate.renavigate`
    of the run's segments: one pose per recorded ping, in order), what they are and the
    navigation configuration; None and why when it is unavailable or the run cannot be
    re-navigated."""
    cfg = None
    try:
        from svss_daq.nav import renavigate as rn
    except ImportError as exc:
        return None, f"svss_daq.nav.renavigate not importable ({exc})", None
    try:
        if hasattr(rn, "renavigation"):
            r = rn.renavigation([str(f) for f in files], nav_cfg)
            poses, why, cfg = r.poses, r.description, getattr(r, "config", None)
        else:
            poses, why = rn.renavigate([str(f) for f in files]), "renavigate"
    except ValueError as exc:                    # RenavigationError: the reason
        log.warning("re-navigation unavailable: %s", exc)
        return None, f"re-navigation failed: {exc}", None
    seqs = []
    for f in files:
        with RawRunReader(f) as run:
            seqs += [int(s) for s in run.ping_table()["ping_sequence"]]
    if len(poses) != len(seqs):
        raise RuntimeError(f"renavigate gave {len(poses)} poses for {len(seqs)} pings")
    by_seq = dict(zip(seqs, poses))
    return [by_seq[p.sequence] for p in pings], why, cfg


# --------------------------------------------------------------------------- imaging


class Focus:
    """Images one run's pings with one set of poses: the tiles as ``svss process``
    makes them, then fine samples with the same kernel and per-ping geometry."""

    def __init__(self, hardware, processing, pings, navs, label: str):
        self.imager = TileImager(hardware, processing.value, source=processing.source)
        self.proc = processing.value
        gate = PingGate(hardware, name=f"bench {label}")
        self.pings, self.tiles = [], []
        t0 = time.perf_counter()
        for p, nav in zip(pings, navs):
            posed = dataclasses.replace(p, nav=nav)
            if not gate.admit(posed):
                continue
            try:
                self.tiles += self.imager.add(posed)
            except PingRejected as exc:
                gate.refuse(exc)
                continue
            self.pings.append(posed)
        self.tiles += self.imager.finish()
        self.refused = dict(gate.refused)
        self.n_refused = gate.n_refused
        self.line = self.imager.line
        self.tile_s = time.perf_counter() - t0
        self._sampler = _Sampler(self.imager.accumulator, self.proc, self.line)

    # -- the 2 cm image
    def voxel_peak(self, centre, half) -> tuple[np.ndarray, float]:
        """Largest |voxel| of the tiles within +-half (along/cross, depth) of ``centre``
        (tile frame): its voxel centre and magnitude."""
        best, where = -1.0, None
        for t in self.tiles:
            g = t.grid
            ia = np.flatnonzero(np.abs(g.along - centre[0]) <= half[0])
            ic = np.flatnonzero(np.abs(g.cross - centre[1]) <= half[0])
            idp = np.flatnonzero(np.abs(g.depth - centre[2]) <= half[1])
            if not (ia.size and ic.size and idp.size):
                continue
            sub = np.abs(t.image[ia[0]:ia[-1] + 1, ic[0]:ic[-1] + 1, idp[0]:idp[-1] + 1])
            k = np.unravel_index(int(np.argmax(sub)), sub.shape)
            if sub[k] > best:
                best = float(sub[k])
                where = np.array([g.along[ia[0] + k[0]], g.cross[ic[0] + k[1]],
                                  g.depth[idp[0] + k[2]]])
        if where is None:
            raise RuntimeError(f"no tile holds the search box around {centre}")
        return where, best

    # -- fine sampling with the imager's kernel
    def sample(self, along, cross, depth) -> np.ndarray:
        """The image at the grid ``along x cross x depth`` (tile frame), complex: the
        pings the tiles took, each as :meth:`TileImager.add` images it (the autofocus's
        sampler, :class:`svss_proc.micronav.autofocus._Sampler`)."""
        return self._sampler.grid(self.pings, along, cross, depth)

    def _cube(self, c, half, step):
        n = int(round(half / step))
        ax = [c[i] + step * np.arange(-n, n + 1) for i in range(3)]
        mag = np.abs(self.sample(*ax))
        k = np.unravel_index(int(np.argmax(mag)), mag.shape)
        edge = any(j in (0, 2 * n) for j in k)
        return np.array([ax[i][k[i]] for i in range(3)]), float(mag[k]), mag, n, edge

    def fine_peak(self, voxel_centre, voxel_level) -> dict:
        c = np.array(voxel_centre, dtype=np.float64)
        check = None
        for _ in range(4):                     # re-centred while the maximum is on an edge
            c1, _, mag, n, edge = self._cube(c, CUBE1_HALF, CUBE1_STEP)
            if check is None:                  # the cube's centre is the tile's voxel
                check = abs(mag[n, n, n] - voxel_level) / max(voxel_level, 1e-30)
            if not edge:
                break
            c = c1
        c2, level, _, _, _ = self._cube(c1, CUBE2_HALF, CUBE2_STEP)
        widths = []
        for axis in range(3):
            offs = LINE_STEP * np.arange(-int(LINE_HALF / LINE_STEP),
                                         int(LINE_HALF / LINE_STEP) + 1)
            ax = [np.array([c2[i]]) for i in range(3)]
            ax[axis] = c2[axis] + offs
            prof = np.abs(self.sample(*ax)).reshape(-1)
            widths.append(width_3db(offs, prof, level))
        return {"position": c2, "level": level, "widths": widths, "kernel_check": check,
                "edge": bool(edge)}


def width_3db(x: np.ndarray, prof: np.ndarray, peak: float) -> float:
    """Width between the -3 dB crossings either side of the profile's centre (linear
    interpolation of the power); NaN where the profile does not fall that far."""
    p = (prof / peak) ** 2
    mid = int(np.argmin(np.abs(x)))
    half = 0.5
    right = np.flatnonzero(p[mid:] < half)
    left = np.flatnonzero(p[:mid + 1][::-1] < half)
    if not right.size or not left.size:
        return float("nan")
    ir = mid + int(right[0])
    il = mid - int(left[0])
    xr = x[ir - 1] + (x[ir] - x[ir - 1]) * (p[ir - 1] - half) / (p[ir - 1] - p[ir])
    xl = x[il + 1] + (x[il] - x[il + 1]) * (p[il + 1] - half) / (p[il + 1] - p[il])
    return float(xr - xl)


# --------------------------------------------------------------------------- measuring


def measure(focus: Focus, scene, true_peaks: list[dict] | None) -> dict:
    """Per point: the fine peak, level against the true-pose peak (``true_peaks``; None:
    these are the true-pose peaks), widths, position errors (scene track frame: along,
    cross; depth below the interface)."""
    truth = truth_line(scene.track)
    ch, sh = math.cos(truth.heading), math.sin(truth.heading)
    pts = []
    expected = []
    for pt in scene.points:
        ned = truth.tile_to_ned(np.array([pt.along_m, pt.cross_m, pt.depth_m]))
        e = focus.line.ned_to_tile(ned)
        expected.append(np.array([e[0], e[1], pt.depth_m]))
    # wide search, then around the expected positions moved by the median offset
    wide = [focus.voxel_peak(e, SEARCH_WIDE)[0] for e in expected]
    offset = np.median(np.array(wide) - np.array(expected), axis=0)
    for i, (pt, e) in enumerate(zip(scene.points, expected)):
        vox, vlevel = focus.voxel_peak(e + offset, SEARCH_NARROW)
        fp = focus.fine_peak(vox, vlevel)
        ned = focus.line.tile_to_ned(fp["position"])
        dn, de = ned[0] - truth.origin_ne[0], ned[1] - truth.origin_ne[1]
        along, cross = dn * ch + de * sh, -dn * sh + de * ch
        err = [along - pt.along_m, cross - pt.cross_m, fp["position"][2] - pt.depth_m]
        pts.append({
            "point": i, "truth_along_cross_depth_m": [pt.along_m, pt.cross_m, pt.depth_m],
            "peak_along_cross_depth_m": [float(along), float(cross),
                                         float(fp["position"][2])],
            "error_along_cross_depth_m": [float(v) for v in err],
            "peak": fp["level"], "voxel_peak": vlevel,
            "width_along_cross_depth_m": fp["widths"],
            "kernel_check_rel": fp["kernel_check"], "peak_on_search_edge": fp["edge"]})
    for p, ref in zip(pts, true_peaks or pts):
        p["level_db"] = 20 * math.log10(p["peak"] / ref["peak"])
        p["voxel_level_db"] = 20 * math.log10(p["voxel_peak"] / ref["voxel_peak"])
    return {"points": pts, "summary": summarise(pts), "pings_imaged": len(focus.pings),
            "pings_refused": focus.n_refused, "refused": focus.refused,
            "tile_imaging_s": focus.tile_s,
            "line": {"origin_ne": list(focus.line.origin_ne),
                     "heading_deg": math.degrees(focus.line.heading),
                     "interface_down": focus.line.interface_down}}


def summarise(pts: list[dict]) -> dict:
    err = np.array([p["error_along_cross_depth_m"] for p in pts])
    n = len(pts)
    rel_h, rel_d = 0.0, 0.0
    for i in range(n):
        for j in range(i + 1, n):
            d = err[i] - err[j]
            rel_h = max(rel_h, float(math.hypot(d[0], d[1])))
            rel_d = max(rel_d, float(abs(d[2])))
    lv = [p["level_db"] for p in pts if p["level_db"] is not None]
    vlv = [p["voxel_level_db"] for p in pts if p["voxel_level_db"] is not None]
    w = np.array([p["width_along_cross_depth_m"] for p in pts])
    return {"mean_level_db": float(np.mean(lv)) if lv else None,
            "worst_level_db": float(np.min(lv)) if lv else None,
            "mean_voxel_level_db": float(np.mean(vlv)) if vlv else None,
            "mean_width_along_cross_depth_m": [float(v) for v in np.nanmean(w, axis=0)],
            "max_rel_horizontal_m": rel_h, "max_rel_depth_m": rel_d,
            "max_abs_horizontal_m": float(np.max(np.hypot(err[:, 0], err[:, 1]))),
            "max_abs_depth_m": float(np.max(np.abs(err[:, 2]))),
            "mean_error_along_cross_depth_m": [float(v) for v in err.mean(axis=0)],
            "max_kernel_check_rel": float(max(p["kernel_check_rel"] for p in pts))}


#: issue 26's "Done when" with the default instruments: mean and worst peak level (dB)
#: per navigation, relative position errors (m), absolute horizontal error in units of
#: the GPS's stated 1-sigma per axis
DONE_WHEN = {"renav": {"mean_level_db": -1.0, "worst_level_db": -2.0},
             "live": {"mean_level_db": -2.0}}
DONE_REL_HORIZONTAL_M, DONE_REL_DEPTH_M = 0.03, 0.01
DONE_ABS_SIGMAS = 2.0


def criteria(kind: str, s: dict, gps_sigma_m: float) -> dict:
    """Issue 26's "Done when" checks of one image: each value, its limit, passed."""
    out = {k: {"value": s[k], "limit": lim, "ok": s[k] >= lim}
           for k, lim in DONE_WHEN.get(kind, {}).items()}
    out["max_rel_horizontal_m"] = {"value": s["max_rel_horizontal_m"],
                                   "limit": DONE_REL_HORIZONTAL_M,
                                   "ok": s["max_rel_horizontal_m"] <= DONE_REL_HORIZONTAL_M}
    out["max_rel_depth_m"] = {"value": s["max_rel_depth_m"], "limit": DONE_REL_DEPTH_M,
                              "ok": s["max_rel_depth_m"] <= DONE_REL_DEPTH_M}
    lim = DONE_ABS_SIGMAS * gps_sigma_m
    out["max_abs_horizontal_m"] = {"value": s["max_abs_horizontal_m"], "limit": lim,
                                   "ok": s["max_abs_horizontal_m"] <= lim}
    return out


def nav_errors(navs, truths) -> dict:
    """RMS and largest pose-field errors of ``navs`` against the true poses (body origin:
    along/cross in the track frame, down, altitude; attitude in mrad)."""
    out = {}
    h = truths[0].heading_rad if truths else 0.0
    ch, sh = math.cos(h), math.sin(h)
    fields = {
        "along_m": lambda n, t: (n.north_m - t.north_m) * ch + (n.east_m - t.east_m) * sh,
        "cross_m": lambda n, t: -(n.north_m - t.north_m) * sh + (n.east_m - t.east_m) * ch,
        "down_m": lambda n, t: n.down_m - t.down_m,
        "altitude_m": lambda n, t: n.altitude_m - t.altitude_m,
        "bottom_down_m": lambda n, t: (n.down_m + n.altitude_m) - (t.down_m + t.altitude_m),
        "roll_mrad": lambda n, t: 1e3 * (n.roll_rad - t.roll_rad),
        "pitch_mrad": lambda n, t: 1e3 * (n.pitch_rad - t.pitch_rad),
        "heading_mrad": lambda n, t: 1e3 * math.remainder(n.heading_rad - t.heading_rad,
                                                          2 * math.pi)}
    for name, f in fields.items():
        e = np.array([f(n, t) for n, t in zip(navs, truths)], dtype=np.float64)
        d = np.diff(e)
        out[name] = {"mean": float(np.nanmean(e)), "std": float(np.nanstd(e)),
                     "ping_to_ping_rms": float(np.sqrt(np.nanmean(d ** 2))) if d.size
                     else None}
    flags: dict[str, int] = {}
    for n in navs:
        flags[str(n.quality)] = flags.get(str(n.quality), 0) + 1
    out["quality_flags"] = flags
    return out


# --------------------------------------------------------------------------- one case


def run_case(scene_name: str, scene_path: Path, variant: str, sim_config: Path,
             work: Path, args, processing) -> dict:
    scene = load_scene(scene_path)
    from_run = (presynthesised(scene_path, work, Path(args.hardware))
                if scene_name == "sand" else None)
    log.info("case %s / %s: recording (sim-device%s -> acquire)", scene_name, variant,
             " --from-run" if from_run else "")
    rec = record(scene_path, sim_config, work / f"{scene_name}-{variant}",
                 Path(args.hardware), args.lead, from_run)
    pings = []
    hardware = None
    for f in rec["files"]:
        with RawRunReader(f) as run:
            hardware = run.hardware
            pings += list(run)
    pings.sort(key=lambda p: p.sequence)
    navs = {"true": true_poses(pings, scene, hardware), "live": [p.nav for p in pings]}
    renav, why, nav_cfg = renav_poses(rec["files"], pings)
    told = VARIANT_NAVIGATION.get(variant) if args.micronav else None
    if renav is not None and told and nav_cfg is not None:
        nav_cfg = dataclasses.replace(nav_cfg, **{k: getattr(nav_cfg, k) * f
                                                  for k, f in told.items()})
        renav, why, nav_cfg = renav_poses(rec["files"], pings, nav_cfg)
        why += f" (navigation told the DVL's noise: {told})"
    if renav is not None:
        # the re-navigation gives no altitude without bottom lock (the ping gate refuses
        # those pings); the fused poses take the bottom depth interpolated across, and
        # so do the DVL-only ones here, so that both image the same pings
        from svss_proc.micronav.renav import with_interpolated_bottom
        navs["renav"], filled = with_interpolated_bottom(renav)
        renav = navs["renav"]
    case = {"scene": scene_name, "variant": variant, "pings_recorded": len(pings),
            "first_track_ping": rec["first_track_ping"],
            "device_late_pings": rec["device_late_pings"],
            "chain_wall_s": rec["chain_wall_s"], "renav_source": why, "poses": {},
            "renav_altitude_filled": filled if renav is not None else 0}
    if args.micronav and renav is not None:
        import focus_micronav as fm
        navs["fused"], res, sec = fm.fused_poses(pings, renav, hardware, processing, nav_cfg)
        case["micronav"] = fm.report(res, renav, navs["true"],
                                     hardware.value.lever_arms.array_m)
        case["micronav"]["seconds"] = sec
        fm.print_report(f"{scene_name} / {variant}", case["micronav"])
    # the pings imaged: all, or (sand) those whose array reaches the points
    imaged = list(range(len(pings)))
    if scene_name == "sand":
        ahead = hardware.value.lever_arms.array_m[0]
        lo = min(p.along_m for p in scene.points) - SAND_IMAGE_MARGIN_M
        hi = max(p.along_m for p in scene.points) + SAND_IMAGE_MARGIN_M
        line = truth_line(scene.track)
        imaged = [i for i, t in enumerate(navs["true"])
                  if lo <= line.ned_to_tile(np.array(t.ned))[0] + ahead <= hi]
    case["pings_imaged_indices"] = [imaged[0], imaged[-1]] if imaged else None
    sub = [pings[i] for i in imaged]
    kinds = [k for k in POSES if not (k == "live" and args.skip_live)]
    gps = load_sim_device_config(sim_config).gps
    true_peaks = None
    focused = {}
    for kind in kinds:
        if kind in ("af", "fused_af") and args.autofocus:
            base = {"af": "renav" if "renav" in focused else "live",
                    "fused_af": "fused"}[kind]
            if base in focused:
                poses, case[f"autofocus_{base}"] = autofocused_poses(
                    focused[base], processing, sub, [navs[base][i] for i in imaged])
                navs[kind] = list(navs[base])
                for i, nv in zip(imaged, poses):
                    navs[kind][i] = nv
        if kind not in navs:
            case["poses"][kind] = None
            continue
        t0 = time.perf_counter()
        focus = focused[kind] = Focus(hardware, processing, sub,
                                      [navs[kind][i] for i in imaged],
                                      f"{scene_name}/{variant}/{kind}")
        res = measure(focus, scene, true_peaks)
        if kind == "true":
            true_peaks = res["points"]
        res["nav_errors"] = nav_errors(navs[kind], navs["true"])
        if kind != "true":
            res["criteria"] = criteria("live" if kind == "live" else "renav",
                                       res["summary"], gps.position_sigma_m)
        res["wall_s"] = time.perf_counter() - t0
        case["poses"][kind] = res
        s = res["summary"]
        log.info("%s / %s / %s: mean %.2f dB, worst %.2f dB (%d pings, %d refused, %.0f s)",
                 scene_name, variant, kind, s["mean_level_db"], s["worst_level_db"],
                 res["pings_imaged"], res["pings_refused"], res["wall_s"])
    return case


def autofocused_poses(focus: Focus, processing, pings, navs) -> tuple[list, dict]:
    """``navs`` after the autofocus of ``focus``'s image on its isolated responses
    (:func:`svss_proc.micronav.autofocus.autofocus_image`, settings of the processing's
    ``[autofocus]``; the pings ``focus`` refused keep theirs), and what it reported."""
    from svss_proc.micronav.autofocus import autofocus_image
    t0 = time.perf_counter()
    res, pick = autofocus_image(focus.imager.accumulator, processing.value, focus.line,
                                focus.pings, focus.tiles)
    by_seq = {p.sequence: p.nav for p in res.pings}
    out = [by_seq.get(p.sequence, n) for p, n in zip(pings, navs)]
    db = lambda a, b: (20 * np.log10(np.maximum(a, 1e-300) / np.maximum(b, 1e-300))  # noqa: E731
                       ).tolist()
    info = {"points": pick.points.tolist(), "contrast_db": pick.contrast_db.tolist(),
            "isolation_db": pick.isolation_db.tolist(), "maxima_examined": pick.examined,
            "rejected": pick.rejected, "kept": res.kept, "reason": res.reason,
            "gain_db": res.gain_db.tolist(),
            "holdout_gain_db": db(res.holdout_after, res.holdout_before),
            "sharpness_before": res.sharpness_before, "sharpness_after": res.sharpness_after,
            "cross_rms_m": float(np.sqrt(np.mean(res.cross_m ** 2))),
            "down_rms_m": float(np.sqrt(np.mean(res.down_m ** 2))),
            "seconds": time.perf_counter() - t0}
    log.info("autofocus: %s (%s), gains %s dB, %.0f s", "kept" if res.kept else "refused",
             res.reason, np.round(res.gain_db, 2).tolist(), info["seconds"])
    return out, info


# --------------------------------------------------------------------------- report


def machine_info() -> dict:
    info = {"python": platform.python_version(), "machine": platform.machine(),
            "cores": os.cpu_count(),
            "cores_available": len(os.sched_getaffinity(0))
            if hasattr(os, "sched_getaffinity") else os.cpu_count()}
    try:
        text = Path("/proc/cpuinfo").read_text()
        model = re.search(r"model name\s*:\s*(.*)", text)
        flags = set(re.search(r"flags\s*:\s*(.*)", text).group(1).split())
        info["cpu"] = model.group(1).strip() if model else platform.processor()
        info["isa"] = [f for f in ("avx512f", "avx512bw", "avx512vl", "avx2", "fma", "avx",
                                   "sse4_2") if f in flags]
    except (OSError, AttributeError):
        info["cpu"] = platform.processor()
    try:
        import llvmlite.binding as llvm
        import numba
        info["numba"] = numba.__version__
        info["llvm_host_cpu"] = llvm.get_host_cpu_name()
        info["numba_threads"] = numba.get_num_threads()
    except Exception:                            # informative only
        pass
    return info


def git_info(declared: str | None) -> dict:
    """This tree's revision and its modified tracked files; ``declared``: the revision a
    tree outside git was exported from (``git archive REV``)."""
    def git(*a):
        r = subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True)
        return r.stdout.strip() if r.returncode == 0 else None
    rev = git("rev-parse", "HEAD")
    if rev is None:
        return {"revision": declared, "tree": f"{ROOT} (not a git checkout: exported from "
                f"{declared or 'an unknown revision'})"}
    dirty = git("status", "--porcelain", "--untracked-files=no")
    return {"revision": rev, "modified_tracked_files": dirty.splitlines() if dirty else []}


def _f(v, fmt="{:6.2f}", na="   n/a"):
    return na if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def print_tables(cases: list[dict]) -> None:
    print()
    print("Focus per case and poses: peak level against the true-pose image (fine-sampled; "
          "at 2 cm voxels in brackets), mean -3 dB widths, position errors (mm)")
    print(f"{'scene':8} {'variant':13} {'poses':5} {'mean dB':>7} {'worst dB':>8} "
          f"{'(voxel)':>7} {'w_al':>5} {'w_cr':>5} {'w_dp':>5} {'rel_h':>6} {'rel_d':>6} "
          f"{'abs_h':>6} {'abs_d':>6} {'refused':>7}")
    for c in cases:
        for kind in POSES:
            r = c["poses"].get(kind)
            if r is None:
                print(f"{c['scene']:8} {c['variant']:13} {kind:5} {'n/a':>7}")
                continue
            s = r["summary"]
            w = s["mean_width_along_cross_depth_m"]
            print(f"{c['scene']:8} {c['variant']:13} {kind:5} {_f(s['mean_level_db'], '{:7.2f}')}"
                  f" {_f(s['worst_level_db'], '{:8.2f}')} {_f(s['mean_voxel_level_db'], '{:7.2f}')}"
                  f" {w[0] * 1e3:5.0f} {w[1] * 1e3:5.0f} {w[2] * 1e3:5.0f}"
                  f" {s['max_rel_horizontal_m'] * 1e3:6.1f} {s['max_rel_depth_m'] * 1e3:6.1f}"
                  f" {s['max_abs_horizontal_m'] * 1e3:6.1f} {s['max_abs_depth_m'] * 1e3:6.1f}"
                  f" {r['pings_refused']:7d}")
    print()
    print("Per point: level (dB) against the true-pose peak, live / renav / af")
    for c in cases:
        row = []
        for i in range(len(c["poses"]["true"]["points"])):
            parts = []
            for kind in ("live", "renav", "af"):
                r = c["poses"].get(kind)
                parts.append("n/a" if r is None else f"{r['points'][i]['level_db']:.1f}")
            row.append(f"p{i} {'/'.join(parts)}")
        print(f"{c['scene']:8} {c['variant']:13} " + "  ".join(row))
    for c in cases:
        m = c.get("motion_true_vs_level_true_db")
        if m:
            print(f"\nmotion imaged with true poses against the level track's true-pose "
                  f"image ({c['variant']}): mean {m['mean']:+.2f} dB")
    print()
    print("Issue 26 'Done when' (renav: mean >= -1 dB, worst >= -2 dB; live: mean >= -2 dB;"
          f" relative <= {DONE_REL_HORIZONTAL_M * 1e3:.0f} mm horizontal, "
          f"<= {DONE_REL_DEPTH_M * 1e3:.0f} mm depth; absolute horizontal <= "
          f"{DONE_ABS_SIGMAS:g} x the GPS sigma)")
    for c in cases:
        for kind in ("live", "renav"):
            r = c["poses"].get(kind)
            if r is None:
                continue
            failed = [k for k, v in r["criteria"].items() if not v["ok"]]
            print(f"{c['scene']:8} {c['variant']:13} {kind:5} "
                  + ("pass" if not failed else "FAIL: " + ", ".join(failed)))
    print()
    print("Pose errors against the true poses (mm; std over the run / rms ping-to-ping "
          "change): along, cross, altitude (the imaged height)")
    for c in cases:
        for kind in ("live", "renav", "af"):
            r = c["poses"].get(kind)
            if r is None:
                continue
            e = r["nav_errors"]
            print(f"{c['scene']:8} {c['variant']:13} {kind:5} " + "  ".join(
                f"{k[:-2]} {e[k]['std'] * 1e3:5.1f}/{e[k]['ping_to_ping_rms'] * 1e3:4.1f}"
                for k in ("along_m", "cross_m", "altitude_m")))


def print_micronav_table(cases: list[dict]) -> None:
    """Issue 29: peak level against the true poses, DVL-only (renav) beside fused, with
    and without the autofocus; the motion estimates against the truth."""
    print()
    print("Issue 29: peak level against the true-pose image, mean / worst (dB)")
    print(f"{'scene':6} {'variant':19} {'renav':>14} {'fused':>14} {'renav+af':>14} "
          f"{'fused+af':>14}")
    for c in cases:
        cells = []
        for kind in ("renav", "fused", "af", "fused_af"):
            r = c["poses"].get(kind)
            cells.append("n/a" if r is None else
                         f"{r['summary']['mean_level_db']:.2f} / "
                         f"{r['summary']['worst_level_db']:.2f}")
        print(f"{c['scene']:6} {c['variant']:19} " + " ".join(f"{x:>14}" for x in cells))
    print()
    print("Motion estimates against the truth, every step (mm; north / east / down): "
          "echoes rms error [rms(err/sigma)], renav rms error [rms(err/sigma)], fused rms "
          "error; nadir coherence (median)")
    for c in cases:
        m = c.get("micronav")
        if not m:
            continue
        e = m["all_steps"]
        f = lambda v: "/".join(f"{x:.2f}" for x in v)            # noqa: E731
        coh = m["nadir_coherence_median"]
        print(f"{c['scene']:6} {c['variant']:19} {m['from_echoes']}/{m['pairs']} "
              f"echo {f(e['echo_rms_error_mm'])} [{f(e['echo_rms_error_over_sigma'])}] "
              f"renav {f(e['nav_rms_error_mm'])} [{f(e['nav_rms_error_over_sigma'])}] "
              f"fused {f(e['fused_rms_error_mm'])}; coh "
              + ("n/a (no pair accepted)" if coh is None else f"{coh:.2f}"))


def micronav_report(work: Path, variant: str, out: str | None = None) -> dict:
    """Recompute the micronavigation report of a kept sand recording (``--work WORK`` of
    an earlier run with ``--scenes sand --micronav``; ``variant``: its instruments) for
    the array's reference point, print it and save it to ``out`` (JSON) where given."""
    import focus_micronav as fm
    from svss_proc.micronav.renav import with_interpolated_bottom
    files = sorted((work / f"sand-{variant}" / "runs").glob("focus_*.h5"))
    if not files:
        raise SystemExit(f"{work / f'sand-{variant}' / 'runs'}: no focus_*.h5 recordings")
    pings = []
    for f in files:
        with RawRunReader(f) as r:
            hw = r.hardware
            pings += list(r)
    pings.sort(key=lambda p: p.sequence)
    truth = true_poses(pings, load_scene(work / "sand-motion.toml"), hw)
    renav, _, cfg = renav_poses(files, pings)
    renav, _ = with_interpolated_bottom(renav)
    proc = sand_processing(DEFAULT_PROCESSING, work)
    _, res, sec = fm.fused_poses(pings, renav, hw, proc, cfg)
    report = fm.report(res, renav, truth, hw.value.lever_arms.array_m)
    report["seconds"] = sec
    fm.print_report(variant, report)
    if out:
        Path(out).write_text(json.dumps(report, indent=1))
    return report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="JSON results file")
    ap.add_argument("--quick", action="store_true",
                    help="the demo scene only (with --variants: those instruments too)")
    ap.add_argument("--variants", nargs="?", const="all", default=None,
                    help="instrument variants besides the default: all (bare --variants), "
                    f"or a comma list of {', '.join(v for v in VARIANTS if v != 'default')}")
    ap.add_argument("--scenes", default=None,
                    help="comma list of demo, motion, sand (default demo, motion; demo "
                    "with --quick). sand: the seed's sand with points and motion "
                    "(SAND_*), pre-synthesised and streamed with sim-device --from-run, "
                    "imaged with the sand's sediment speed and refraction tables")
    ap.add_argument("--autofocus", action="store_true",
                    help="also image with the autofocused poses (af: the re-navigated "
                    "ones, focused on the image's isolated responses)")
    ap.add_argument("--micronav", action="store_true",
                    help="also image with the re-navigated poses fused with the echoes' "
                    "increments (fused; with --autofocus also fused_af) and report the "
                    "motion estimates against the truth (issue 29)")
    ap.add_argument("--skip-default", action="store_true",
                    help="leave the default instruments out (run only --variants)")
    ap.add_argument("--skip-live", action="store_true",
                    help="do not image with the live poses (saves an image per case)")
    ap.add_argument("--processing", default=str(DEFAULT_PROCESSING),
                    help="processing TOML (default: config/processing-demo.toml, the demo's)")
    ap.add_argument("--hardware", default=str(config_path("hardware.toml")))
    ap.add_argument("--sim-config", default=str(DEFAULT_SIM),
                    help="base simulated-device TOML the variants modify")
    ap.add_argument("--lead", type=float, default=12.0,
                    help="sim-device --lead (s; as svss demo)")
    ap.add_argument("--work", help="keep the recordings here (default: a temporary folder)")
    ap.add_argument("--threads", type=int, default=None,
                    help="numba threads of the imaging (default: numba's, one per core)")
    ap.add_argument("--source-revision", help="for a tree outside git (git archive REV): "
                    "the revision it is, recorded in the results")
    ap.add_argument("--micronav-report", metavar="VARIANT",
                    help="only recompute the micronavigation report of the sand recording "
                    "kept in --work for VARIANT (default: its instruments), saved to --out")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    if args.micronav_report:
        if not args.work:
            ap.error("--micronav-report needs --work (the folder of the kept recordings)")
        micronav_report(Path(args.work), args.micronav_report, args.out)
        return 0
    if args.threads:
        import numba
        numba.set_num_threads(args.threads)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
                        datefmt="%H:%M:%S")
    log.setLevel(logging.INFO)
    variants = ["default"]
    if args.variants:
        extra = list(VARIANTS)[1:] if args.variants == "all" else args.variants.split(",")
        for v in extra:
            if v not in VARIANTS:
                ap.error(f"--variants: unknown variant {v!r} (known: {', '.join(VARIANTS)})")
        variants += [v for v in extra if v != "default"]
    if args.skip_default and len(variants) > 1:
        variants.remove("default")
    t_start = time.perf_counter()
    processing = load_with_text(ProcessingConfig, args.processing)
    tmp = tempfile.TemporaryDirectory(prefix="bench-focus-") if not args.work else None
    work = Path(args.work or tmp.name).resolve()
    work.mkdir(parents=True, exist_ok=True)
    names = (args.scenes or ("demo" if args.quick else "demo,motion")).split(",")
    if set(names) - {"demo", "motion", "sand"}:
        ap.error(f"--scenes: unknown {sorted(set(names) - {'demo', 'motion', 'sand'})}")
    scenes = {}
    if "demo" in names:
        scenes["demo"] = DEMO_SCENE
    if "motion" in names:
        scenes["motion"] = write_motion_scene(DEMO_SCENE, work)
    if "sand" in names:
        scenes["sand"] = write_sand_scene(work)
        sand_proc = sand_processing(Path(args.processing), work)
    cases = []
    try:
        for variant in variants:
            sim = write_variant(variant, Path(args.sim_config), work)
            for name, path in scenes.items():
                cases.append(run_case(name, path, variant, sim, work, args,
                                      sand_proc if name == "sand" else processing))
    finally:
        if tmp is not None:
            tmp.cleanup()
    # motion imaged with true poses, against the level scene's true-pose image
    for c in cases:
        if c["scene"] == "motion":
            ref = next((d for d in cases if d["scene"] == "demo"
                        and d["variant"] == c["variant"]), None)
            if ref is not None:
                lv = [20 * math.log10(a["peak"] / b["peak"]) for a, b in
                      zip(c["poses"]["true"]["points"], ref["poses"]["true"]["points"])]
                c["motion_true_vs_level_true_db"] = {"per_point": lv,
                                                     "mean": float(np.mean(lv))}
    result = {"command": " ".join([os.path.basename(sys.executable)] + sys.argv),
              "git": git_info(args.source_revision), "machine": machine_info(),
              "processing": str(Path(args.processing).resolve().relative_to(ROOT))
              if Path(args.processing).resolve().is_relative_to(ROOT) else args.processing,
              "motion": MOTION if not args.quick else None,
              "variants": {v: VARIANTS[v] for v in variants},
              "fine_sampling_m": {"cube1": [CUBE1_HALF, CUBE1_STEP],
                                  "cube2": [CUBE2_HALF, CUBE2_STEP],
                                  "lines": [LINE_HALF, LINE_STEP]},
              "cases": cases, "wall_s": time.perf_counter() - t_start}
    # the results saved before they are printed: a table's formatting never loses a run
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=1, default=_json_default))
    print_tables(cases)
    if args.micronav:
        print_micronav_table(cases)
    print(f"\nwall time {result['wall_s']:.0f} s")
    if args.out:
        print(f"wrote {args.out}")
    return 0


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o).__name__)


if __name__ == "__main__":
    sys.exit(main())
