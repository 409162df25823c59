"""A digitiser fault that drops or corrupts frames for many pings logs a few lines, not
one a frame (a 1005-ping gap logged 5025 lines); the counters keep every frame."""

from __future__ import annotations

import logging

import numpy as np

from sim_device.devices.digitiser import FAULT_LOG_EVERY, FAULT_LOG_FIRST, DigitiserEmulator, _frames


def test_a_long_frame_drop_logs_a_few_lines_and_counts_every_frame(caplog):
    em = DigitiserEmulator(lambda n: np.zeros((80, 1500), dtype=np.int32),
                           channels_per_frame=16)
    try:
        with caplog.at_level(logging.INFO, logger="sim_device.devices.digitiser"):
            em.drop_next(-1, 1005)                 # every frame of the next 1005 pings
            for _ in range(1100):
                em._ping_bytes()
            em.corrupt_next(1, 250)                # frame 1 of the next 250
            for _ in range(300):
                em._ping_bytes()
    finally:
        em.close()
    assert em.frames_dropped == 1005 * 5           # 80 channels, 16 a frame
    lines = [r.getMessage() for r in caplog.records]
    drops = [m for m in lines if "dropped (fault" in m]
    assert len(drops) == FAULT_LOG_FIRST + 1005 // FAULT_LOG_EVERY
    assert "frame(s) 0-4 dropped (fault; 1 ping(s), 5 frame(s) dropped so far)" in drops[0]
    assert drops[-1].endswith("(fault; 1000 ping(s), 5000 frame(s) dropped so far)")
    assert em.frames_corrupted == 250
    assert len([m for m in lines if "corrupted (fault" in m]) == FAULT_LOG_FIRST + 2
    assert _frames([0, 1, 2, 4, 6, 7]) == "0-2, 4, 6-7"
