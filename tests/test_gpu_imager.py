"""The tile imager on the GPU end to end (schedule, conditioning, device planes, the
update counts kept on the device and read once per tile) against the same imager on the
CPU: every tile's update count, the imager's total and the images, with the GPU's pings
batched per launch (``imaging.gpu_pings_per_launch``: a batch full before the tile is
handed back and the rest launched at hand-back). Under numba's CUDA
simulator on every machine (a small tile of 10 cm voxels; the simulator interprets each
thread), and on a real GPU where one is present."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.test_gpu_kernel import ROOT, requires_cuda, subprocess_env

SCRIPT = textwrap.dedent("""
    import dataclasses, sys, numpy as np
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import (HardwareConfig, ProcessingConfig, config_path, load,
                                 load_with_text)
    from svss_proc.imaging.imager import TileImager
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
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
    for device in ("cpu", "cuda"):
        for precision in sys.argv[2].split(","):
            p = dataclasses.replace(proc, imaging=dataclasses.replace(
                proc.imaging, device=device, precision=precision,
                gpu_pings_per_launch=int(sys.argv[3])))
            imager = TileImager(hw, p)
            tiles = []
            for ping in pings:
                tiles += imager.add(ping)
            tiles += imager.finish()
            key = f"{device}_{precision}"
            out[key + "_total"] = np.array(imager.updates)
            out[key + "_index"] = np.array([t.grid.index for t in tiles])
            out[key + "_updates"] = np.array([t.updates for t in tiles])
            out[key + "_image"] = np.stack([t.image for t in tiles])
    np.savez(sys.argv[1], **out)
""")


def _run(tmp_path, simulator: bool, precisions: str, per_launch: int = 2):
    out = tmp_path / "imager.npz"
    res = subprocess.run([sys.executable, "-c", SCRIPT, str(out), precisions,
                          str(per_launch)], cwd=ROOT,
                         env=subprocess_env(simulator), capture_output=True, text=True,
                         timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return np.load(out)


def _compare(r, precisions):
    for prec, tol in (("float32", 1e-4), ("float64", 1e-9)):
        if prec not in precisions:
            continue
        cpu, gpu = f"cpu_{prec}", f"cuda_{prec}"
        # the premise: several tiles, each with updates, the total their sum
        assert len(r[cpu + "_index"]) >= 2 and np.all(r[cpu + "_updates"] > 0)
        assert int(r[cpu + "_total"]) == int(r[cpu + "_updates"].sum())
        np.testing.assert_array_equal(r[gpu + "_index"], r[cpu + "_index"])
        # counted on the device, read when each tile was handed back
        np.testing.assert_array_equal(r[gpu + "_updates"], r[cpu + "_updates"])
        assert int(r[gpu + "_total"]) == int(r[cpu + "_total"])
        ref = r[cpu + "_image"]
        np.testing.assert_allclose(r[gpu + "_image"], ref, rtol=0,
                                   atol=tol * np.abs(ref).max(), err_msg=prec)


@pytest.mark.slow
def test_gpu_imager_under_the_simulator_matches_the_cpu_imager(tmp_path):
    # float32 alone under the simulator (the precision whose device arithmetic differs)
    _compare(_run(tmp_path, simulator=True, precisions="float32"), "float32")


@requires_cuda
def test_real_gpu_imager_matches_the_cpu_imager(tmp_path):
    _compare(_run(tmp_path, simulator=False, precisions="float32,float64"),
             "float32,float64")

