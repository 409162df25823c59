"""Micronavigation in the tile worker (svss_proc/micronav/live.py), through a real `svss
process` run (the same Worker class `svss worker` feeds from the stream).

- Over a seabed: pings the project's simulator synthesises from poses with an injected
  sway step and heave step (tests/micronav/posed_source.py), recorded with the straight
  track's poses (a navigation that saw none of the motion) and without DVL bottom lock
  (the navigation's step sigma is then the DVL gap's, and the echoes carry the steps).
  The tiles `svss process` writes must be those of the same pings imaged, with the stage
  off, at the poses an independent forward Kalman filter (written here, on x rather than
  on the correction) makes of the estimator's increments; and they must differ from the
  navigation's. The manifest counts the pairs and the refusals by reason.
- Without a seabed (the demo scene): every step refused ("no coherent seabed return"
  or "no seabed layer";
  the projector sequence's wrap 5 -> 0: "the phase centres do not overlap"), and the
  tiles equal, voxel for voxel, those made with the stage off.
"""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim_device.scene import load_scene
from sim_device.track import ping_pose
from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load_with_text,
                             loaded_from_text)
from svss_daq.frames import body_to_ned
from svss_daq.ping import NAV_FUSED, NAV_GPS_FIX
from svss_proc.conditioning import Conditioner
from svss_daq.nav.renavigate import current_navigation_config
from svss_proc.micronav.horizontal import estimate_displacement
from svss_proc.micronav.renav import array_lever_m, attitude_increment_sigma
from svss_proc.run_worker import Worker
from svss_proc.tiles import read_tile

from .posed_source import PosedSource, interface_sand_scene

ROOT = Path(__file__).resolve().parents[2]
PINGS = range(12, 16)              # projectors 0 1 2 3


def stage_table(enabled: bool) -> str:
    """config/processing.toml's ``[micronav]`` table with ``live`` as ``enabled`` says."""
    text = Path(config_path("processing.toml")).read_text()
    table = text[text.index("\n[micronav]"):].split("\n[", 2)
    table = "\n[" + table[1]
    new = re.sub(r"(?m)^live = \w+", f"live = {str(enabled).lower()}", table)
    assert new.count("live = ") == 1, "processing.toml: no [micronav] live line"
    return new


def offsets(i: int) -> np.ndarray:
    """Injected motion about the straight track (surge, sway, heave), m."""
    return np.array([0.0, 0.02 if i >= 14 else 0.0, 0.005 if i >= 15 else 0.0])


def processing_text(enabled: bool, length_m: float, top_m: float, depth_m: float) -> str:
    """processing-demo.toml with a small tile, no products, and the stage on or off."""
    text = Path(config_path("processing-demo.toml")).read_text()
    head = text.partition("\n[products]")[0]
    new = (head.replace("length_m = 3.0", f"length_m = {length_m}")
           .replace("width_m = 1.2", "width_m = 0.6")
           .replace("depth_m = 1.0", f"depth_m = {depth_m}")
           .replace("top_m = 0.0", f"top_m = {top_m}").replace("voxel_m = 0.02", "voxel_m = 0.03")
           # straight delays: images from equal poses compare to float32's rounding (the
           # table's times are keyed per cm of height, and poses equal to a nanometre may
           # fall either side of a key, whose tables agree to 1e-4 of a wavelength)
           .replace('delays = "table"', 'delays = "straight"'))
    assert new != head
    return new + "\n" + stage_table(enabled)


def process(run: Path, out: Path, proc_text: str) -> dict:
    """`svss process` in its own process; the run's manifest."""
    cfg = out.parent / f"{out.name}.toml"
    cfg.write_text(proc_text)
    r = subprocess.run([sys.executable, "-m", "svss", "process", str(run), "--out", str(out),
                        "--processing", str(cfg)], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads((out / "manifest.json").read_text())


def images(folder: Path) -> dict:
    return {p.name: read_tile(p)["image"] for p in sorted(folder.glob("tile_*.h5"))}


def image_in_process(pings, proc_text: str, out: Path) -> tuple[dict, dict]:
    """The tiles and the manifest of ``pings`` imaged by a :class:`Worker` here."""
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = loaded_from_text(ProcessingConfig, proc_text, "in-process")
    w = Worker(hw, proc, out)
    w.run(iter(pings))
    return images(out), json.loads((out / "manifest.json").read_text())


def write_run(path: Path, pings) -> Path:
    from svss_daq.rawfile import RawRunWriter
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    with RawRunWriter(path, hw) as rec:
        for p in pings:
            rec.append(p)
    return path


@pytest.fixture(scope="module")
def sand_run(tmp_path_factory):
    """The recorded pings (straight-track poses, no bottom lock), their true offsets and
    the run file. The seed's sand scene without its target, volume and multipath (the
    interface's echo is what the estimator uses; the rest costs synthesis time)."""
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    hw = loaded.value
    scene = interface_sand_scene()
    src = PosedSource(loaded, scene, offsets)
    pings = []
    for i in PINGS:
        p = src.ping(i)
        nav = ping_pose(scene.track, hw, i, src.seed)
        pings.append(dataclasses.replace(p, nav=dataclasses.replace(
            nav, quality=NAV_FUSED | NAV_GPS_FIX)))
    path = write_run(tmp_path_factory.mktemp("sand") / "sand.h5", pings)
    return pings, path


def expected_poses(pings) -> list:
    """The forward fusion, written independently: a Kalman filter on the positions x_k
    (random walk with the fused step, observed as the navigation's p_k with the anchor's
    sigma), the steps from :func:`estimate_displacement`."""
    loaded = load_with_text(HardwareConfig, config_path("hardware.toml"))
    hw = loaded.value
    from svss_daq.geometry import array_geometry
    from svss_daq.waveform import make_waveform
    geo = array_geometry(hw)
    cond = Conditioner(hw.digitiser, make_waveform(hw.waveform), 2, 1)
    cs = [cond.ping(p) for p in pings]
    nav_cfg = current_navigation_config()
    assert nav_cfg.dvl_gap_velocity_sigma_m_s == 0.3
    s2 = 0.3 ** 2
    x, cov = pings[0].nav.ned.copy(), np.eye(3) * s2
    out = [pings[0]]
    for (pa, ca), (pb, cb) in zip(zip(pings, cs), zip(pings[1:], cs[1:])):
        na, nb = pa.nav, pb.nav
        n_inc = nb.ned - na.ned
        # the held velocity's sigma (no bottom lock) over the step, and the attitude's
        # noise turning the lever arm to the array (the re-navigation's sigma)
        n_cov = np.diag(np.hypot(0.3 * 0.1, attitude_increment_sigma(
            [na, nb], nav_cfg, array_lever_m(hw.lever_arms))[0]) ** 2)
        est = estimate_displacement(
            ca.data, cb.data, ca.t0_s, ca.dt_s, geo, pa.projector, pb.projector,
            body_to_ned(na.roll_rad, na.pitch_rad, na.heading_rad), na.ned,
            body_to_ned(nb.roll_rad, nb.pitch_rad, nb.heading_rad), nb.ned,
            na.down_m + na.altitude_m, 1500.0, hw.waveform.center_hz)
        if est.refused:
            step, f_cov = n_inc, n_cov
        else:
            info = np.linalg.inv(n_cov) + np.linalg.inv(est.cov_m2)
            f_cov = np.linalg.inv(info)
            step = f_cov @ (np.linalg.solve(n_cov, n_inc)
                            + np.linalg.solve(est.cov_m2, est.displacement_m))
        x, cov = x + step, cov + f_cov
        gain = cov @ np.linalg.inv(cov + np.eye(3) * s2)
        x = x + gain @ (nb.ned - x)
        cov = (np.eye(3) - gain) @ cov
        d = x - nb.ned
        out.append(dataclasses.replace(pb, nav=dataclasses.replace(
            nb, north_m=float(x[0]), east_m=float(x[1]), down_m=float(x[2]),
            altitude_m=nb.altitude_m - float(d[2]))))
    return out


@pytest.mark.slow
def test_the_worker_images_each_ping_at_its_fused_pose(sand_run, tmp_path):
    pings, run = sand_run
    # small tiles about the interface
    on, off = (processing_text(e, 2.0, -0.1, 0.4) for e in (True, False))
    manifest = process(run, tmp_path / "on", on)
    mn = manifest["micronav"]
    print(json.dumps(mn))
    assert mn["pairs"] == len(PINGS) - 1
    assert mn["estimated"] == len(PINGS) - 1
    assert mn["refused"] == {"no previous ping": 1}
    got = images(tmp_path / "on")
    assert got
    want_pings = expected_poses(pings)
    want = image_in_process(want_pings, off, tmp_path / "want")[0]
    nav = image_in_process(pings, off, tmp_path / "nav")[0]
    assert got.keys() == want.keys() == nav.keys()
    for name in got:
        scale = np.abs(want[name]).max()
        np.testing.assert_allclose(got[name], want[name], atol=1e-5 * scale, rtol=0)
        # the fused poses moved the image: it is not the navigation's
        assert np.abs(got[name] - nav[name]).max() > 0.01 * scale
    # the fused poses moved toward the truth: the injected 20 mm sway and 5 mm heave,
    # carried from the steps they happened in (less the anchor's pull this early in a
    # run: the gain is about 1 / (k + 1) at the run's k-th ping), against the
    # navigation's zero
    last = np.array([want_pings[-1].nav.north_m, want_pings[-1].nav.east_m,
                     want_pings[-1].nav.down_m]) - pings[-1].nav.ned
    print("last ping's fused correction (m)", last)
    assert 0.004 < last[1] < 0.02 and 0.001 < last[2] < 0.006, last


def test_without_a_seabed_every_step_is_refused_and_the_image_unchanged(tmp_path):
    """The demo scene (points in water): the stage refuses at the nadir patch and the
    tiles are those of the stage off, voxel for voxel (the same Worker as above, here in
    this process: the stage's path through a process is the test above)."""
    import itertools

    from sim_device.environment_source import EnvironmentSource
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    n = 8
    pings = list(itertools.islice(iter(EnvironmentSource(hw, scene)), n))
    a, on = image_in_process(pings, processing_text(True, 3.0, 0.0, 1.0), tmp_path / "on")
    b, off = image_in_process(pings, processing_text(False, 3.0, 0.0, 1.0), tmp_path / "off")
    assert off["micronav"] is None
    mn = on["micronav"]
    wraps = sum(1 for i in range(1, n) if i % 6 == 0)       # 5 -> 0: no overlap
    assert mn["pairs"] == n - 1 and mn["estimated"] == 0
    # no seabed: refused at the nadir patch's coherence, or where a point's echo or
    # noise coheres there, by the layer test (horizontal.seabed_layer)
    refused = dict(mn["refused"])
    no_seabed = (refused.pop("no coherent seabed return under the array", 0)
                 + refused.pop("no seabed layer under the array", 0))
    assert refused == {"no previous ping": 1, "the phase centres do not overlap": wraps}
    assert no_seabed == n - 1 - wraps, mn["refused"]
    assert mn["max_correction_m"] == [0.0, 0.0, 0.0]
    assert a and a.keys() == b.keys()
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])



def test_a_resumed_stage_fuses_on_as_the_uninterrupted_one(sand_run, tmp_path):
    """The journal carries the fusion's state at the resume point: a worker resumed from
    it poses the pings from there as the uninterrupted one did, to the last bit (without
    it the fusion starts afresh there, and the poses differ). The stage alone, on the
    sand pings above (the imaging's part of a resume is tests/worker's)."""
    pings, _ = sand_run
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    proc = loaded_from_text(ProcessingConfig, processing_text(True, 2.0, -0.1, 0.4), "on")

    def stage(out, **kw):
        return Worker(hw, proc, tmp_path / out, run_id="r", **kw)

    whole = stage("whole").micronav
    want = [whole.pose(p).nav for p in pings]
    # a worker stopped after the third ping, its journal's resume point the third
    first = stage("resumed")
    for p in pings[:3]:
        first.micronav.pose(p)
    first._write_journal(resume=pings[2].sequence)
    saved = json.loads((tmp_path / "resumed" / "worker_state.json").read_text())["micronav"]
    assert saved["sequence"] == pings[2].sequence and abs(saved["correction_m"][1]) > 1e-3
    again = stage("resumed", resume=True).micronav
    got = [again.pose(p).nav for p in pings[2:]]
    assert got == want[2:]
    assert again.summary() == whole.summary()
    fresh = stage("fresh").micronav
    assert [fresh.pose(p).nav for p in pings[2:]] != want[2:]
