"""The window gather against numpy indexing, on both of its paths."""

import numba as nb
import numpy as np
import pytest

from svss_proc.imaging.window_gather import (HAS_AVX512, LANES, WINDOW, window_gather_1,
                                     window_gather_2, window_gather_4)

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
    fast = dtype == np.float32 and HAS_AVX512
    expected = [int(fits and fast) for _, _, fits in cases]
    assert flags.tolist() == expected, [c[0] for c in cases]


def test_window_gather_rejects_mixed_precision():
    re = np.zeros((2, 1, 64), np.float32)
    with pytest.raises(nb.core.errors.TypingError):
        _runner(window_gather_2)(re, re, 0, np.zeros(16, np.uint32),
                                 np.zeros(64, np.float64), 16, np.zeros(1, np.int64))
