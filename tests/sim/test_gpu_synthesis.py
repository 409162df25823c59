"""Pass 2 on the GPU (:mod:`sim_device.synthesis_gpu`) against the CPU fast path
(:func:`sim_device.synthesis.accumulate_fast`) on the same scatterers: under numba's CUDA
simulator on every machine (a few hundred scatterers, 8 channels, in a subprocess because
the simulator must be chosen before numba.cuda is imported), compiled to PTX for a real
GPU where libNVVM is present, and on a real GPU (a sand-scene ping, 80 channels) where
one is present. Also the scene option ``[scattering] device``."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sim_device.scene import check_scene, load_scene
from svss_daq.config import ConfigError, config_path
from tests.test_gpu_kernel import subprocess_env

ROOT = Path(__file__).resolve().parents[2]
PING = 100
#: receive channels kept in the simulator cases (spread over the 80 of the array)
CHANNELS = np.arange(3, 80, 10)


def sand(**scattering):
    """The seed's sand scene, thinned, volume to 1.2 m, multipath to second order, no
    coherent returns or targets (as tests/sim/test_fast_synthesis.py)."""
    sc = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    opts = {"specular": False, "interface_density_per_m2": 100.0,
            "volume_density_per_m3": 400.0, "volume_max_depth_m": 1.2,
            "scatterers_per_resolution_cell": None, "volume_below_noise_db": None}
    opts.update(scattering)
    return dataclasses.replace(sc, scattering=dataclasses.replace(sc.scattering, **opts),
                               targets=())


def pass2_case(name: str, n_each: int = 60, hardware=None):
    """Inputs of pass 2 for one ping, as EnvironmentSource.scattered forms them, cut to
    ``n_each`` interface and ``n_each`` volume scatterers in view (all, for points in
    water) and the channels CHANNELS. Returns (pass 2's bundles, n_buf)."""
    from sim_device.environment_source import EnvironmentSource
    from sim_device.synthesis import (MED_INTERFACE, Pass2, Paths, Points, TransmitLegs,
                                      beam_of, transmit_legs)
    from svss_daq.config import HardwareConfig, load_with_text
    hw = (hardware if hardware is not None
          else load_with_text(HardwareConfig, config_path("hardware.toml")))
    if name == "water":
        demo = load_scene(config_path("scenes/demo.toml"))
        src = EnvironmentSource(hw, dataclasses.replace(demo, scattering=None))
        ping = 40
    else:
        src = EnvironmentSource(hw, sand(precision="exact") if name == "exact" else sand())
        ping = PING
    g = src.frame(ping)
    s = src.scatterers(ping, g)
    ox, oy = float(g.tx[0]), float(g.tx[1])
    img_t = src._images((g.tx - [ox, oy, 0.0])[None, :])[0]
    img_r = np.ascontiguousarray(src._images(g.rx - [ox, oy, 0.0])[CHANNELS])
    pts = Points(s.x - ox, s.y - oy, s.z, s.med)
    legs = TransmitLegs(np.empty((s.size, img_t.shape[0])),
                        np.empty((s.size, img_t.shape[0]), dtype=np.complex128))
    transmit_legs(pts, s.amp.astype(np.complex128), img_t, src.medium_bundle(),
                  beam_of(src.tx_beam, g.bore), legs)
    idx = np.flatnonzero(np.any(legs.amp != 0, axis=1))
    if name != "water":
        rng = np.random.default_rng(5)
        inter = idx[s.med[idx] == MED_INTERFACE]
        vol = idx[s.med[idx] >= 1]
        idx = np.sort(np.concatenate([rng.choice(inter, n_each, replace=False),
                                      rng.choice(vol, n_each, replace=False)]))
    zmax = np.minimum(src.zmax, np.finfo(np.float64).max)
    if zmax.shape[0] > 1 and zmax.shape[1] > 1:
        zmax[1, 0] = 0.4          # a level cut-off on one multipath path
    p2 = Pass2(Points(*(a[idx] for a in pts)), TransmitLegs(*(a[idx] for a in legs)),
               Paths(img_r, src.allowed, zmax), src.medium_bundle(),
               beam_of(src.rx_beam, g.bore), src.pulses.window())
    return p2, src.pulses.n_buf


SCRIPT = textwrap.dedent("""
    import sys, numpy as np
    from tests.sim.test_gpu_synthesis import N_EACH, pass2_case, wired_pair
    from sim_device.synthesis import accumulate_fast_serial
    from sim_device.synthesis_gpu import GpuAccumulator
    gpu = GpuAccumulator()
    out = {}
    for name in sys.argv[2:]:
        p2, n_buf = pass2_case(name, N_EACH[name])
        cpu, n_cpu = accumulate_fast_serial(p2, n_buf)
        dev, n_dev = gpu(p2, n_buf)
        out[name + "_cpu"], out[name + "_gpu"] = cpu, dev
        out[name + "_n"] = np.array([n_cpu.sum(), n_dev.sum()])
        out[name + "_med"] = p2.pts.med
    a, b = wired_pair()
    out["wired_gpu"], out["wired_cpu"] = a.scattered(40), b.scattered(40)
    out["wired_n"] = np.array([a.last_stats["echoes"], b.last_stats["echoes"]])
    out["wired_on"] = np.array([a.gpu is not None, b.gpu is None])
    np.savez(sys.argv[1], **out)
""")


def wired_pair():
    """EnvironmentSources of the demo's points in water (80 channels) with
    ``[scattering] device = "cuda"`` and without (no seabed scattering)."""
    from sim_device.environment_source import EnvironmentSource
    from svss_daq.config import HardwareConfig, load_with_text
    hw = load_with_text(HardwareConfig, config_path("hardware.toml"))
    demo = load_scene(config_path("scenes/demo.toml"))
    sc = dataclasses.replace(sand().scattering, interface=False, volume=False)
    return (EnvironmentSource(hw, dataclasses.replace(
                demo, scattering=dataclasses.replace(sc, device="cuda"))),
            EnvironmentSource(hw, dataclasses.replace(demo, scattering=sc)))

#: scatterers of each kind (interface, volume) per case: the simulator runs a Python
#: thread per (scatterer, channel), a few ms each. One accumulator runs the cases in this
#: order: its buffers grow (water to sand) and are reused (sand to exact)
N_EACH = {"water": 0, "sand": 60, "exact": 30}
CASES = tuple(N_EACH)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """The simulator runs (one subprocess for every case)."""
    out = tmp_path_factory.mktemp("gpu_sim") / "out.npz"
    # the project root prepended to PYTHONPATH, never replacing it: on the GPU machine
    # numpy, pyzmq and the rest live on PYTHONPATH (replacing it failed this fixture there)
    env = subprocess_env(True)
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(out), *CASES], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stderr[-4000:]
    return dict(np.load(out))


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("name", CASES)
@pytest.mark.slow
def test_simulated_gpu_equals_the_cpu_fast_path(simulated, name):
    """sand: interface and volume scatterers in a sediment, direct and multipath images,
    a level cut-off on one path; water: the demo's points in water; exact: every
    refracted leg by Brent's method (the table of ones)."""
    cpu, gpu = simulated[name + "_cpu"], simulated[name + "_gpu"]
    n_cpu, n_gpu = simulated[name + "_n"]
    assert cpu.shape == gpu.shape == (CHANNELS.size, cpu.shape[1])
    assert n_gpu == n_cpu > (20 if name == "water" else 200)      # the same echoes ...
    assert rel(gpu, cpu) < 1e-5                                   # ... to float32 rounding
    assert np.all(np.abs(cpu).max(axis=1) > 0)                    # every channel has echoes
    if name != "water":
        med = simulated[name + "_med"]
        assert (med == -1).sum() == (med >= 1).sum() == N_EACH[name]


def test_scene_option_runs_pass_2_on_the_gpu(simulated):
    """``[scattering] device = "cuda"`` through EnvironmentSource.scattered (simulator)."""
    assert simulated["wired_on"].all()
    n_gpu, n_cpu = simulated["wired_n"]
    assert n_gpu == n_cpu == 80 * 3                      # three points in view, 80 channels
    assert simulated["wired_gpu"].shape == simulated["wired_cpu"].shape
    assert rel(simulated["wired_gpu"], simulated["wired_cpu"]) < 1e-5


@pytest.mark.extended      # 7-9 s of libNVVM compile; the simulator tests above run the kernel
def test_kernel_compiles_for_a_real_gpu(monkeypatch):
    """The kernel the simulator ran, compiled to PTX for an H100 (sm_90): the simulator
    runs Python, so this is what shows that numba-cuda can compile it. Without a GPU,
    numba's device-function compilation asks the (absent) current device for its compute
    capability: that one query answers sm_90 here."""
    import types

    import numba.cuda.dispatcher as cuda_dispatcher
    from numba import cuda
    try:
        from numba.cuda.cudadrv import nvvm
        nvvm.NVVM()
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"libNVVM not available to numba ({e})")
    from sim_device import synthesis_gpu as sg
    if hasattr(cuda_dispatcher, "get_current_device") and not sg.cuda_available():
        monkeypatch.setattr(cuda_dispatcher, "get_current_device",
                            lambda: types.SimpleNamespace(compute_capability=(9, 0)))
    p2, _ = pass2_case("water")
    ptx, _ = cuda.compile_ptx(sg._receive_kernel.py_func, sg.kernel_signature(p2),
                              cc=(9, 0))
    assert ".entry" in ptx and "atom" in ptx


def test_device_option_checked():
    sc = sand(device="cuda")
    assert sc.scattering.device == "cuda"
    with pytest.raises(ConfigError, match=r"scattering\.device.*reference"):
        check_scene(sand(device="cuda", synthesis="reference"), "x.toml")
    from sim_device.synthesis_gpu import cuda_available
    if not cuda_available():
        with pytest.raises(ConfigError, match=r"x\.toml: key 'scattering\.device'.*no CUDA"):
            check_scene(sc, "x.toml")


def _real_gpu() -> bool:
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return False
    try:
        from sim_device.synthesis_gpu import cuda_available
    except ImportError:
        return False
    return cuda_available()


@pytest.mark.skipif(not _real_gpu(), reason="needs an NVIDIA GPU (numba-cuda); the "
                    "simulator tests above cover the kernel on every machine")
def test_real_gpu_sand_ping_equals_the_cpu_path(hardware):
    """A realistic sand-scene ping (the scene file's densities, 80 channels) through
    EnvironmentSource on the CPU and on the GPU."""
    from sim_device.environment_source import EnvironmentSource
    base = load_scene(config_path("scenes/seed_cylinder_sand.toml"))
    base = dataclasses.replace(base, targets=())
    cpu = EnvironmentSource(hardware, base)
    gpu = EnvironmentSource(hardware, dataclasses.replace(
        base, scattering=dataclasses.replace(base.scattering, device="cuda")))
    a = cpu.scattered(PING)
    b = gpu.scattered(PING)
    assert a.shape == b.shape == (80, a.shape[1])
    assert gpu.last_stats["echoes"] == cpu.last_stats["echoes"] > 1_000_000
    assert rel(b, a) < 1e-5
