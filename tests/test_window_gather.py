"""The window gather against numpy indexing, on each of its paths: the one this machine
compiles (AVX-512 here), and in subprocesses an AVX2-only target (numba's CPU name and
features; no AVX-512 instruction may appear) and the lane-by-lane loads."""

import os
import subprocess
import sys
from pathlib import Path

import numba as nb
import numpy as np
import pytest

from svss_proc.imaging.window_gather import (AVX2_TARGET, HALF, HALF_WINDOW, LANES, PATH,
                                             PATH_VARIABLE, WINDOW, choose_path,
                                             window_gather_1, window_gather_2,
                                             window_gather_4)

ROOT = Path(__file__).resolve().parents[1]

GATHERS = {1: window_gather_1, 2: window_gather_2, 4: window_gather_4}
N = 200


def _runner(gather):
    @nb.njit
    def run(re, im, ch, idx, dst, stride, offs):
        flags = np.zeros(offs.size, dtype=np.int64)
        for i in range(offs.size):
            flags[i] = gather(re, im, ch, idx, offs[i], dst, offs[i], stride)
        return flags
    return run


def _chunks():
    """(name, 16 indices, fits the window) cases."""
    ramp = np.arange(LANES)
    return [
        ("ramp, spread 30", 100 + 2 * ramp, True),
        ("spread 31", 50 + np.r_[ramp[:-1], 31], True),
        ("spread 32", 50 + np.r_[ramp[:-1], 32], False),
        ("constant", np.full(LANES, 7), True),
        ("decreasing", 40 - ramp, False),             # lane 0 is not the smallest index
        ("window ends at the row end", N - WINDOW + ramp, True),
        ("window past the row end", N - WINDOW + 1 + ramp, False),
        ("last sample", np.full(LANES, N - 1), False),
        ("first sample", np.zeros(LANES, dtype=int), True),
        ("scattered", np.array([3, 190, 17, 88, 5, 0, 199, 42, 42, 7, 150, 66, 1, 2, 3, 4]),
         False),
    ]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("taps", [1, 2, 4])
def test_window_gather_matches_indexing(taps, dtype):
    rng = np.random.default_rng(taps)
    re = rng.standard_normal((taps, 3, N)).astype(dtype)
    im = rng.standard_normal((taps, 3, N)).astype(dtype)
    cases = _chunks()
    idx = np.concatenate([np.asarray(c[1]) for c in cases]).astype(np.uint32)
    offs = np.arange(len(cases), dtype=np.int64) * LANES
    stride = idx.size + 5                              # rows of dst with a gap between them
    dst = np.full(2 * taps * stride, np.nan, dtype=dtype)
    flags = _runner(GATHERS[taps])(re, im, 1, idx, dst, stride, offs)
    rows = dst.reshape(2 * taps, stride)
    np.testing.assert_array_equal(rows[:taps, :idx.size], re[:, 1, idx])
    np.testing.assert_array_equal(rows[taps:, :idx.size], im[:, 1, idx])
    assert np.isnan(rows[:, idx.size:]).all()          # nothing written past the lanes
    expected = [int(dtype == np.float32 and _fits(PATH, np.asarray(c[1]), N))
                for c in cases]
    assert flags.tolist() == expected, (PATH, [c[0] for c in cases])
    if PATH == "avx512":           # the premise: the cases' own window verdicts
        assert expected[:len(cases)] == [int(dtype == np.float32 and c[2]) for c in cases]


def _fits(path: str, idx: np.ndarray, n: int) -> bool:
    """Whether ``path`` serves these 16 indices from its windows (the reference)."""
    if path == "avx512":
        return bool(np.all((idx - idx[0] >= 0) & (idx - idx[0] < WINDOW))
                    and idx[0] + WINDOW <= n)
    if path == "avx2":
        return all(bool(np.all((h - h[0] >= 0) & (h - h[0] < HALF_WINDOW))
                        and h[0] + HALF_WINDOW <= n) for h in (idx[:HALF], idx[HALF:]))
    return False


def test_avx2_cases_take_both_verdicts():
    """The premise for the AVX2 path: the cases fit its 16-sample halves and miss them."""
    verdicts = {_fits("avx2", np.asarray(c[1]), N) for c in _chunks()}
    assert verdicts == {True, False}


@pytest.mark.parametrize("env", [AVX2_TARGET, pytest.param(
    {PATH_VARIABLE: "loads"}, marks=pytest.mark.extended)], ids=["avx2 target", "loads"])
def test_window_gather_on_the_other_paths(env, tmp_path):
    """This module's gather test in a process that compiles another path (its own numba
    cache: the cache does not know the path). (The lane loads run in this process too,
    for every case outside the window; forcing them everywhere is an extended check.)"""
    full = {**os.environ, **env, "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
            "PYTHONPATH": os.pathsep.join([str(ROOT)] + [p for p in [
                os.environ.get("PYTHONPATH")] if p])}
    code = ("import sys, pytest; from svss_proc.imaging.window_gather import PATH; "
            "print('PATH', PATH); sys.exit(pytest.main(['-q', '-p', 'no:cacheprovider', "
            "'-n', '0', '-k', 'matches_indexing', sys.argv[1]]))")
    res = subprocess.run([sys.executable, "-c", code, __file__], cwd=ROOT, env=full,
                         capture_output=True, text=True, timeout=600)
    want = "avx2" if "NUMBA_CPU_NAME" in env else env[PATH_VARIABLE]
    assert f"PATH {want}" in res.stdout, res.stdout[-2000:] + res.stderr[-2000:]
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]
    assert "6 passed" in res.stdout, res.stdout[-2000:]


def test_path_choice():
    assert choose_path(frozenset({"avx2", "avx512f"}), None) == "avx512"
    assert choose_path(frozenset({"avx2", "fma"}), "auto") == "avx2"
    assert choose_path(frozenset({"sse4.2"}), None) == "loads"
    assert choose_path(frozenset({"avx2", "avx512f"}), "avx2") == "avx2"
    with pytest.raises(ValueError, match=PATH_VARIABLE + ".*lacks it"):
        choose_path(frozenset({"avx2"}), "avx512")
    with pytest.raises(ValueError, match="expected auto or one of"):
        choose_path(frozenset({"avx2"}), "sse")


def test_window_gather_rejects_mixed_precision():
    re = np.zeros((2, 1, 64), np.float32)
    with pytest.raises(nb.core.errors.TypingError):
        _runner(window_gather_2)(re, re, 0, np.zeros(16, np.uint32),
                                 np.zeros(64, np.float64), 16, np.zeros(1, np.int64))
