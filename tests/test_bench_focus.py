"""benchmarks/bench_focus.py's measuring pieces: the -3 dB width, the variant and motion
files it writes for the chain, and the relative/absolute position summary."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_focus",
                                                  ROOT / "benchmarks/bench_focus.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_focus"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("offset", [0.0, 0.0013, -0.0041])
def test_width_of_a_gaussian_profile(bench, offset):
    """A Gaussian amplitude exp(-x^2 / (2 s^2)) is -3 dB (half power) at
    x = s sqrt(ln 2): the width is 2 s sqrt(ln 2), whichever sample the peak falls near."""
    s = 0.02
    x = 0.002 * np.arange(-100, 101)
    prof = np.exp(-((x - offset) ** 2) / (2 * s * s))
    w = bench.width_3db(x, prof, float(prof.max()))
    assert w == pytest.approx(2 * s * math.sqrt(math.log(2)), rel=2e-3)


def test_width_is_nan_when_the_profile_stays_above_half_power(bench):
    x = np.linspace(-0.1, 0.1, 101)
    prof = np.exp(-(x ** 2) / (2 * 1.0 ** 2))                 # far wider than the line
    assert math.isnan(bench.width_3db(x, prof, float(prof.max())))


def test_variants_change_only_their_keys_and_validate(bench, tmp_path):
    base = ROOT / "config/sim-device.toml"
    rtk = bench.write_variant("rtk", base, tmp_path)
    dvl = bench.write_variant("dvl_noise_x2", base, tmp_path)
    from sim_device.device_process import load_sim_device_config
    b, r, d = (load_sim_device_config(p) for p in (base, rtk, dvl))
    assert (r.gps.position_sigma_m, r.gps.height_sigma_m, r.gps.fix_quality) == (0.02, 0.03, 4)
    assert r.dvl == b.dvl and r.sonar == b.sonar
    assert d.dvl.velocity_sigma_m_s == pytest.approx(2 * b.dvl.velocity_sigma_m_s)
    assert d.dvl.range_sigma_m == pytest.approx(2 * b.dvl.range_sigma_m)
    assert d.gps == b.gps
    # a key only another section has is not taken from there
    with pytest.raises(KeyError, match="gps.range_sigma_m"):
        bench._set_key(base.read_text(), "gps", "range_sigma_m", 1.0)


def test_motion_scene_is_the_demo_with_motion(bench, tmp_path):
    from sim_device.scene import load_scene
    demo = load_scene(ROOT / "config/scenes/demo.toml")
    moving = load_scene(bench.write_motion_scene(ROOT / "config/scenes/demo.toml", tmp_path))
    assert moving.points == demo.points
    assert moving.track.motion.heave_m == 0.03 and moving.track.motion.roll_deg == 1.0
    assert moving.track.motion.yaw_deg == 0.5
    assert demo.track.motion is None


def test_summary_relative_errors_ignore_a_common_offset(bench):
    """A shift shared by every point (e.g. the GPS's absolute error) is an absolute error,
    not a relative one; one point off by 3 cm along makes a 3 cm relative error."""
    def pts(errors):
        return [{"error_along_cross_depth_m": e, "level_db": 0.0, "voxel_level_db": 0.0,
                 "width_along_cross_depth_m": [0.03, 0.08, 0.06], "kernel_check_rel": 0.0}
                for e in errors]
    s = bench.summarise(pts([[0.2, -0.1, 0.01]] * 4))
    assert s["max_rel_horizontal_m"] == pytest.approx(0.0, abs=1e-12)
    assert s["max_rel_depth_m"] == pytest.approx(0.0, abs=1e-12)
    assert s["max_abs_horizontal_m"] == pytest.approx(math.hypot(0.2, 0.1))
    assert s["max_abs_depth_m"] == pytest.approx(0.01)
    s = bench.summarise(pts([[0.0, 0.0, 0.0]] * 3 + [[0.03, 0.0, -0.004]]))
    assert s["max_rel_horizontal_m"] == pytest.approx(0.03)
    assert s["max_rel_depth_m"] == pytest.approx(0.004)
