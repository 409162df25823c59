"""When the streaming imager hands a run's tiles back, and with which of the next tile's
first planes: bookkeeping on the schedule's steps alone (no image), shared by
:class:`~svss_proc.imaging.imager.TileImager` (which hands back the tiles themselves)
and the batch plan (:mod:`svss_proc.batch.plan`, which must know the same order without
imaging).

A complete tile is held until the next tile's first ``planes`` along-track planes are
complete (each reached, then ``close_after`` consecutive pings clear of it: the rule that
completes a tile) or ``close_after`` pings have passed; at the run's end every plane is
complete. A tile closed early (the memory bound) is handed back at once without them.
The planes let a tile's products see across its seam as in one seamless volume
(products without seams; ``planes`` 0: none).
"""

from __future__ import annotations

import numpy as np

from .schedule import PingStep

#: what goes back with a tile: (next tile, the pings imaged into it then), or None
After = "tuple[int, int] | None"


class Handback:
    """The hand-back of one run's tiles. ``planes``: the next tile's planes a tile waits
    for; ``close_after``: the schedule's clear pings that complete a plane;
    ``n_along``: a tile's along-track planes. :meth:`step` and :meth:`finish` return the
    tiles handed back then, in order, each with its :data:`After`. With ``record``
    (the batch plan): ``order``, every hand-back of the run in order, and ``touch``, per
    tile the first plane each of its pings reached, for :meth:`seams`."""

    def __init__(self, planes: int, close_after: int, n_along: int, record: bool = True):
        self.planes, self.close_after, self.n_along = planes, close_after, n_along
        self.record = record
        self.active: dict[int, np.ndarray] = {}     # open tile -> last ping per plane
        self.held: dict[int, int] = {}              # complete tile -> pings then
        self.imaged: dict[int, int] = {}            # tile -> pings imaged into it
        self.touch: dict[int, list[int]] = {}
        self.order: list[tuple[int, tuple[int, int] | None]] = []

    def _next(self, k: int, n_pings: int, final: bool):
        """(after, wait): tile ``k + 1`` and its pings so far when its first planes are
        complete, else None; ``wait``: they may still come (it is open)."""
        n, nxt = self.planes, k + 1
        if n < 1 or not (nxt in self.held or nxt in self.active) or self.n_along < n:
            return None, False
        if not final and nxt not in self.held:
            last = self.active[nxt][:n]
            if np.any(last == 0) or np.any(n_pings - last < self.close_after):
                return None, True
        return (nxt, self.imaged.get(nxt, 0)), False

    def _hand_back(self, k: int, after=None) -> tuple[int, tuple[int, int] | None]:
        self.held.pop(k, None)
        self.active.pop(k, None)
        if self.record:
            self.order.append((k, after))
        else:
            self.imaged.pop(k, None)
        return k, after

    def close_early(self, step: PingStep) -> list[tuple[int, None]]:
        """The tiles ``step`` closed early (the memory bound), handed back at once: the
        imager frees them before it opens the tiles the ping reaches."""
        return [self._hand_back(k) for k in step.closed_early]

    def step(self, step: PingStep, n_pings: int, early: bool = True
             ) -> list[tuple[int, tuple[int, int] | None]]:
        """Follow one scheduled ping (``n_pings``: the schedule's count after it); with
        ``early`` its tiles closed early first (:meth:`close_early`; False: done
        already)."""
        out = self.close_early(step) if early else []
        for k in step.reached:
            if k not in self.active:
                self.active[k] = np.zeros(self.n_along, dtype=np.int64)
        for sl in step.slices:
            self.active[sl.tile][sl.ia0:sl.ia1] = n_pings
            self.imaged[sl.tile] = self.imaged.get(sl.tile, 0) + 1
            if self.record:
                self.touch.setdefault(sl.tile, []).append(sl.ia0)
        for k in step.closed:
            self.active.pop(k, None)
            self.held[k] = n_pings
        ready = []
        for k in sorted(self.held):
            after, wait = self._next(k, n_pings, final=False)
            if not wait or n_pings - self.held[k] >= self.close_after:
                ready.append((k, after))
        return out + [self._hand_back(k, after) for k, after in ready]

    def finish(self, n_pings: int) -> list[tuple[int, tuple[int, int] | None]]:
        """The run has ended: every tile still open or held, with its next planes."""
        keys = sorted(set(self.active) | set(self.held))
        after = {k: self._next(k, n_pings, final=True)[0] for k in keys}
        return [self._hand_back(k, after[k]) for k in keys]

    def seams(self) -> dict[int, tuple[int, bool, int | None, bool]]:
        """Per tile (``record`` on): (hand-back order, whether the tile before it was
        handed back just before, the next tile's pings imaged when it was handed back
        (None: no planes), whether those planes were final then: no later ping of the
        next tile reached them)."""
        out = {}
        prev = None
        for i, (k, after) in enumerate(self.order):
            final = after is None or all(a >= self.planes
                                         for a in self.touch.get(after[0], ())[after[1]:])
            out[k] = (i, prev == k - 1 and self.planes > 0,
                      None if after is None else after[1], final)
            prev = k
        return out
