"""Conditioning on the GPU (svss_proc.imaging.gpu_conditioning): the conditioning as one
matrix is the CPU conditioner's FFT path (on the shipped digitiser and a real simulated
ping, and on other decimations and upsamplings), and the tap planes the device makes
from the codes are :func:`~svss_proc.imaging.kernel_args.prepare`'s of the CPU's
conditioning, for every interpolation and precision, at full-scale codes, silent
channels, a ping shorter than the window and channel groups cut short; the device ring
lends each ping one slot, refuses more holds than it has, and a refused ping (samples
at another rate) holds none. Under numba's CUDA
simulator on every machine, and on a real GPU where one is present."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from svss_daq.waveform import make_waveform
from svss_proc.conditioning import Conditioner
from tests.test_gpu_kernel import ROOT, requires_cuda, subprocess_env


def _ping_codes(hardware, scene_name="demo.toml"):
    """A simulated ping of the demo scene (the full array and window), its codes and
    axis."""
    from sim_device.environment_source import EnvironmentSource
    from sim_device.scene import load_scene
    from svss_daq.config import config_path
    scene = load_scene(config_path("scenes/" + scene_name))
    ping = EnvironmentSource(hardware, scene).ping(40)
    return ping.samples, ping.sample_axis


@pytest.mark.parametrize("decimation, upsample", [(2, 1), (1, 1), (4, 2)])
def test_the_conditioning_as_one_matrix_is_the_fft_path(hardware, decimation, upsample):
    hw = hardware.value
    c = Conditioner(hw.digitiser, make_waveform(hw.waveform), decimation, upsample)
    codes, axis = _ping_codes(hardware)
    assert codes.shape == (80, c.n_in)
    op = c.operator()
    assert op.shape == (c.n_in, c.n_out)
    ref = c(codes, axis).analytic
    peak = np.abs(ref).max()
    assert peak > 0
    # the operator acts on the codes as floats; the FFTs' rounding is ~1e-15 of the peak
    err = np.abs(codes.astype(np.float64) @ op - ref).max() / peak
    assert err < 1e-12, err


SCRIPT = textwrap.dedent("""
    import dataclasses, sys, numpy as np
    from svss_daq.config import HardwareConfig, config_path, load_with_text
    from svss_daq.ping import SampleAxis
    from svss_daq.waveform import make_waveform
    from svss_proc.conditioning import Conditioner
    from svss_proc.imaging.gpu_batch import PingBatcher
    from svss_proc.imaging.gpu_conditioning import DeviceConditioner
    from svss_proc.imaging.kernel_args import prepare
    hw = load_with_text(HardwareConfig, config_path("hardware.toml")).value
    n_in = int(sys.argv[2])
    dig = dataclasses.replace(hw.digitiser, window_samples=n_in, window_start_s=1.1e-3)
    cond = Conditioner(dig, make_waveform(hw.waveform), 2, 1)
    rng = np.random.default_rng(7)
    full = 2 ** (dig.bits - 1) - 1
    pings = []
    for nch, n, kind in ((11, n_in, "random"), (3, n_in, "full scale"),
                         (11, n_in - 17, "short")):
        codes = rng.integers(-full, full + 1, size=(nch, n)).astype(np.int32)
        if kind == "full scale":              # the rails, alternating, and a silent channel
            codes[0] = full * np.where(np.arange(n) % 2 == 0, 1, -1)
            codes[1] = -full
            codes[2] = 0
        pings.append((kind, codes))
    axis = SampleAxis(dig.window_start_s + 0.37e-3, 1.0 / dig.sample_rate_hz, n_in)
    out = {}
    for interp in ("nearest", "linear", "cubic"):
        for dtype in (np.float32, np.float64):
            dc = DeviceConditioner(cond, interp, dtype)
            batcher = PingBatcher(1)
            for kind, codes in pings:
                kd = batcher.device_planes(dc, codes, axis)
                ref = prepare(cond(codes, axis), interp, dtype)
                key = f"{interp}_{np.dtype(dtype).name}_{kind}"
                out[key] = np.stack([kd.planes.re.copy_to_host(),
                                     kd.planes.im.copy_to_host()])
                out[key + "_ref"] = np.stack([ref.planes.re, ref.planes.im])
                out[key + "_scalars"] = np.array(
                    [[kd.planes.t0, kd.planes.inv_dt, kd.planes.theta, kd.halvings,
                      kd.interp],
                     [ref.planes.t0, ref.planes.inv_dt, ref.planes.theta, ref.halvings,
                      ref.interp]], dtype=np.float64)
                batcher.release(kd)
    # the ring: one slot per held ping; more holds than slots are refused
    batcher = PingBatcher(1)
    dc = DeviceConditioner(cond, "linear", np.float32)
    held = [batcher.device_planes(dc, pings[1][1], axis)]
    cap = batcher._ring.capacity
    while len(held) < cap:
        held.append(batcher.device_planes(dc, pings[1][1], axis))
    try:
        batcher.device_planes(dc, pings[1][1], axis)
        out["refused"] = np.array("")
    except RuntimeError as e:
        out["refused"] = np.array(str(e))
    batcher.release(held.pop())
    batcher.release(batcher.device_planes(dc, pings[1][1], axis))   # a slot again
    out["made"] = np.array([batcher.planes_made, cap])
    # samples at another rate: refused, naming the rate
    try:
        batcher.device_planes(dc, pings[1][1], SampleAxis(0.0, 1e-5, n_in))
        out["rate"] = np.array("")
    except ValueError as e:
        out["rate"] = np.array(str(e))
    # nothing leaks: with every ping let go, no slot is held and none is named
    while held:
        batcher.release(held.pop())
    out["left"] = np.array([int(batcher._ring.refs.sum()), len(batcher._ring.of)])
    np.savez(sys.argv[1], **out)
""")


def _run(tmp_path, simulator: bool, n_in: int):
    out = tmp_path / "cond.npz"
    res = subprocess.run([sys.executable, "-c", SCRIPT, str(out), str(n_in)], cwd=ROOT,
                         env=subprocess_env(simulator), capture_output=True, text=True,
                         timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return np.load(out)


def _compare(r):
    for interp in ("nearest", "linear", "cubic"):
        for dtype, tol in (("float32", 1e-6), ("float64", 1e-12)):
            for kind in ("random", "full scale", "short"):
                key = f"{interp}_{dtype}_{kind}"
                got, ref = r[key], r[key + "_ref"]
                assert got.shape == ref.shape and got.dtype == ref.dtype, key
                peak = np.abs(ref).max()
                assert peak > 0, key
                err = np.abs(got - ref).max() / peak
                assert err < tol, (key, err)
                # the tap planes' zeros (where a tap reaches past the samples) are zeros
                np.testing.assert_array_equal(got[ref == 0], 0.0, err_msg=key)
                s = r[key + "_scalars"]
                np.testing.assert_array_equal(s[0], s[1], err_msg=key)
    assert "slots are held" in str(r["refused"])
    made, cap = r["made"]
    assert made == cap + 1
    assert "Hz" in str(r["rate"])
    # (a refused ping held its slot for good before: 50 such pings stopped a run)
    np.testing.assert_array_equal(r["left"], [0, 0])


@pytest.mark.slow
def test_device_tap_planes_under_the_simulator_are_the_cpus(tmp_path):
    _compare(_run(tmp_path, simulator=True, n_in=96))


@requires_cuda
def test_real_gpu_tap_planes_are_the_cpus(tmp_path):
    # the shipped window (1500 samples), as the imager conditions it
    _compare(_run(tmp_path, simulator=False, n_in=1500))


def test_the_device_takes_codes_no_longer_than_the_window(hardware):
    # (the operator covers the configured window: the imager conditions a longer ping on
    # the host, and the batcher refuses it before holding a slot)
    from svss_proc.imaging import gpu_conditioning
    hw = hardware.value
    dig = dataclasses.replace(hw.digitiser, window_samples=64)
    c = Conditioner(dig, make_waveform(hw.waveform), 2, 1)
    accepts = gpu_conditioning.DeviceConditioner.accepts
    probe = type("P", (), {"n_in": c.n_in})()
    assert accepts(probe, np.zeros((4, 64), np.int32))
    assert accepts(probe, np.zeros((4, 10), np.int32))
    assert not accepts(probe, np.zeros((4, 65), np.int32))
    assert not accepts(probe, np.zeros((4, 0), np.int32))
