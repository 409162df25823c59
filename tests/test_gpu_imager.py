"""The tile imager on the GPU end to end (schedule, conditioning, device planes, the
update counts kept on the device and read once per tile) against the same imager on the
CPU: every tile's update count, the imager's total and the images, with the GPU's pings
batched per launch (``imaging.gpu_pings_per_launch``: a batch full before the tile is
handed back and the rest launched at hand-back). Under numba's CUDA
simulator on every machine (a small tile of 10 cm voxels; the simulator interprets each
thread), and on a real GPU where one is present."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.test_gpu_kernel import ROOT, requires_cuda, subprocess_env

SCRIPT = textwrap.dedent("""
    import dataclasses, json, sys, numpy as np
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import (HardwareConfig, Loaded, ProcessingConfig, config_path,
                                 load, load_with_text)
    from svss_proc.imaging.imager import TileImager
    opt = json.loads(sys.argv[2])
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    if opt["window"] is not None:             # a shorter receive window (the simulator)
        start, n = opt["window"]
        hw = Loaded(dataclasses.replace(hw.value, digitiser=dataclasses.replace(
            hw.value.digitiser, window_start_s=start, window_samples=n)), hw.text, hw.source)
    channels = None if opt["channels"] is None else np.arange(0, 80, opt["channels"])
    proc = load(ProcessingConfig, config_path("processing.toml"))
    scene = load_scene(config_path("scenes/demo.toml"))
    pt = scene.points[0]
    # 1 m tiles of 10 cm voxels; the pings whose projector passes within 0.5 m of the
    # first point, far enough from the origin that the float32 geometry is realistic
    proc = dataclasses.replace(proc, tile=dataclasses.replace(
        proc.tile, length_m=1.0, width_m=0.4, depth_m=0.4, top_m=0.1, voxel_m=0.1))
    src = EnvironmentSource(hw, scene)
    step = scene.track.speed_m_s * hw.value.sequencer.ping_interval_s
    first = int(round(pt.along_m / step))
    pings = [src.ping(i) for i in range(first - 1, first + 2)]
    out = {}
    runs = [("cpu", "host")] + [("cuda", v) for v in opt["stages"]]
    for device, stages in runs:
        for precision in opt["precisions"]:
            p = dataclasses.replace(proc, imaging=dataclasses.replace(
                proc.imaging, device=device, precision=precision,
                gpu_pings_per_launch=opt["per_launch"], gpu_conditioning=stages,
                gpu_coverage=stages))
            imager = TileImager(hw, p, channels=channels)
            tiles = []
            for ping in pings:
                tiles += imager.add(ping)
            tiles += imager.finish()
            key = f"{device}-{stages}_{precision}"
            out[key + "_total"] = np.array(imager.updates)
            out[key + "_index"] = np.array([t.grid.index for t in tiles])
            out[key + "_updates"] = np.array([t.updates for t in tiles])
            out[key + "_image"] = np.stack([t.image for t in tiles])
            out[key + "_pings"] = np.stack([t.coverage.pings for t in tiles])
            out[key + "_channels"] = np.stack([t.coverage.channels for t in tiles])
            out[key + "_shared"] = np.array(max(len(set(a.pings) & set(b.pings))
                                                for a, b in zip(tiles, tiles[1:])))
    np.savez(sys.argv[1], **out)
""")

#: the simulator's receive window (start s, samples): the test tile's echoes (2.8 to
#: about 4 ms) in 384 samples rather than 1500, and every tenth channel, so that the
#: device conditioning (a thread per output sample, interpreted) takes seconds
SIM_WINDOW = (0.002, 384)


def _run(tmp_path, simulator: bool, precisions: str, per_launch: int = 2,
         stages=("device",), window=None, channels=None):
    out = tmp_path / "imager.npz"
    opt = dict(precisions=precisions.split(","), per_launch=per_launch,
               stages=list(stages), window=window, channels=channels)
    res = subprocess.run([sys.executable, "-c", SCRIPT, str(out), json.dumps(opt)],
                         cwd=ROOT, env=subprocess_env(simulator), capture_output=True,
                         text=True, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return np.load(out)


def _compare(r, precisions, stages=("device",), coverage_exact=True):
    for prec, tol in (("float32", 1e-4), ("float64", 1e-9)):
        if prec not in precisions:
            continue
        cpu = f"cpu-host_{prec}"
        # the premise: several tiles, each with updates, the total their sum, and
        # voxels some pings reached with only some channels
        assert len(r[cpu + "_index"]) >= 2 and np.all(r[cpu + "_updates"] > 0)
        assert int(r[cpu + "_total"]) == int(r[cpu + "_updates"].sum())
        assert np.any(r[cpu + "_channels"] % r[cpu + "_channels"].max() != 0)
        assert int(r[cpu + "_shared"]) >= 1        # a ping reached two tiles
        for st in stages:
            gpu = f"cuda-{st}_{prec}"
            np.testing.assert_array_equal(r[gpu + "_index"], r[cpu + "_index"])
            # counted on the device, read when each tile was handed back
            np.testing.assert_array_equal(r[gpu + "_updates"], r[cpu + "_updates"])
            assert int(r[gpu + "_total"]) == int(r[cpu + "_total"])
            # coverage, counted on the device or on the host: the CPU's, exactly under
            # the simulator; on a GPU fused multiply-adds may round a voxel on a cone or
            # window edge the other way (one ping, its channels), at a few voxels
            for c in ("_pings", "_channels"):
                got, ref = r[gpu + c].astype(np.int64), r[cpu + c].astype(np.int64)
                if coverage_exact:
                    np.testing.assert_array_equal(got, ref, err_msg=gpu + c)
                else:
                    off = got != ref
                    assert off.mean() <= 1e-3, (gpu + c, off.sum())
                    step = 1 if c == "_pings" else int(ref.max())
                    assert np.abs(got - ref).max(initial=0) <= step, (gpu + c)
            ref = r[cpu + "_image"]
            np.testing.assert_allclose(r[gpu + "_image"], ref, rtol=0,
                                       atol=tol * np.abs(ref).max(), err_msg=prec + st)


@pytest.mark.slow
def test_gpu_imager_under_the_simulator_matches_the_cpu_imager(tmp_path):
    # float32 alone under the simulator (the precision whose device arithmetic
    # differs), the planes made on the host (the full window, every channel)
    _compare(_run(tmp_path, simulator=True, precisions="float32", stages=("host",)),
             "float32", stages=("host",))


@pytest.mark.slow
def test_gpu_conditioning_and_coverage_under_the_simulator_match_the_cpu(tmp_path):
    # the tap planes made on the device from the codes and the coverage counted there,
    # in both precisions, on a shorter window and every tenth channel
    _compare(_run(tmp_path, simulator=True, precisions="float32,float64",
                  window=SIM_WINDOW, channels=10), "float32,float64")


@requires_cuda
def test_real_gpu_imager_matches_the_cpu_imager(tmp_path):
    _compare(_run(tmp_path, simulator=False, precisions="float32,float64",
                  stages=("device", "host")), "float32,float64", stages=("device", "host"),
             coverage_exact=False)
