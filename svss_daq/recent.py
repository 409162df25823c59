"""What changed in the last few seconds: cumulative values sampled over time, and their
change over a sliding window (the status stream's recent drops, the disk's fill rate)."""

from __future__ import annotations

import collections


class RecentChange:
    """Samples ``(time, {name: cumulative value})`` kept over ``window_s`` (plus the
    last one before it, the baseline). :meth:`change` is each value's change from the
    baseline to the latest sample and the time between them."""

    def __init__(self, window_s: float):
        self.window_s = float(window_s)
        self.samples: collections.deque = collections.deque()

    def add(self, now_s: float, values: dict[str, float]) -> None:
        self.samples.append((float(now_s), dict(values)))
        # keep one sample at or before the window's start: the baseline
        while len(self.samples) >= 2 and self.samples[1][0] <= now_s - self.window_s:
            self.samples.popleft()

    def change(self) -> tuple[dict[str, float], float]:
        """({name: latest - baseline}, seconds between them); ({}, 0) before two
        samples."""
        if len(self.samples) < 2:
            return {}, 0.0
        (t0, a), (t1, b) = self.samples[0], self.samples[-1]
        return {k: v - a.get(k, v) for k, v in b.items()}, t1 - t0


__all__ = ["RecentChange"]
