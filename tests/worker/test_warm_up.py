"""The worker compiles its imaging kernel before it subscribes (PingAccumulator.warm_up,
called by svss_proc.worker.serve): on a first run, a compile at the first ping left the
worker silent past the daemon's service.worker_silence_s, and the daemon closed its
catch-up service before the worker could confirm the run's end. The warm-up must build
the very specialisation the first real ping needs, or it compiles nothing useful."""

from __future__ import annotations

import dataclasses

import pytest

from svss_daq.config import ProcessingConfig, config_path, load
from svss_proc.imaging import cpu_kernel


@pytest.mark.parametrize("delays", ["table", "straight"])
def test_warm_up_builds_what_the_first_ping_needs(hardware, delays):
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_proc.imaging.imager import TileImager
    proc = load(ProcessingConfig, config_path("processing-demo.toml"))
    proc = dataclasses.replace(proc, imaging=dataclasses.replace(proc.imaging, delays=delays))
    imager = TileImager(hardware, proc)
    calls = []
    run = imager.accumulator.kernel

    def recording(out, kd, array, d, **kw):
        calls.append((kd.interp, d.code, kw["gating"], kd.halvings))
        return run(out, kd, array, d, **kw)
    imager.accumulator.kernel = recording
    imager.accumulator.warm_up()
    key = calls[0]
    kernel = cpu_kernel.kernel_for(*key)
    warmed = list(kernel.signatures)
    ping = EnvironmentSource(hardware, load_scene(config_path("scenes/demo.toml"))).ping(40)
    imager.add(ping)
    assert len(calls) >= 2 and set(calls) == {key}      # the same kernel ...
    assert kernel.signatures == warmed                   # ... and no new specialisation


def test_depth_table_is_the_table_at_the_voxel_depths_depth_fastest():
    """kernel_args.depth_table: each offset row of the refraction table interpolated at
    the voxel depths (against numpy's interp), C order with depth fastest (neighbouring
    GPU threads read neighbouring addresses; numpy's fancy indexing gave Fortran order,
    and a second kernel specialisation)."""
    import numpy as np

    from svss_proc.imaging.delays import build_table
    from svss_proc.imaging.kernel_args import depth_table
    table = build_table(2.0, 3.0, -0.05, 1.05, 0.01, 1500.0, 1767.0)
    depth = np.linspace(0.0, 1.0, 51).astype(np.float32)
    tz, ez, _ = depth_table(table, depth)
    assert tz.shape == (table.time.shape[0], depth.size) and tz.dtype == np.float32
    assert tz.flags.c_contiguous and ez.flags.c_contiguous
    z = table.z0 + table.dz * np.arange(table.time.shape[1])
    for i in (0, 57, table.time.shape[0] - 1):
        np.testing.assert_allclose(tz[i], np.interp(depth.astype(np.float64), z,
                                                    table.time[i]), rtol=1e-6)
        np.testing.assert_allclose(ez[i], np.interp(depth.astype(np.float64), z,
                                                    table.eta[i]), rtol=1e-5)
    assert depth_table(table, depth)[0] is tz          # kept: the GPU uploads it once
