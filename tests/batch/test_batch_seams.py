"""Products without seams in svss batch, on the plan alone (no imaging): the plan
follows the streaming imager's hand-back of tiles (which tile is saved after which,
and with which of the next tile's first planes), and a tile's plan cut to its first
pings. The batch's tiles against svss process's, products included, are in
test_batch.py (test_tiles_equal_svss_process_voxel_for_voxel)."""

from __future__ import annotations

from types import SimpleNamespace as NS

from svss_proc.batch.plan import Handback, TilePlan
from svss_proc.batch.task import prefix_plan
from svss_proc.imaging.schedule import Slice

PLANES, CLOSE, ALONG = 3, 2, 10


def step(reached=(), slices=(), closed=(), early=()):
    return NS(reached=tuple(reached), slices=tuple(Slice(*s) for s in slices),
              closed=tuple(closed), closed_early=tuple(early))


def run(steps) -> Handback:
    h = Handback(PLANES, CLOSE, ALONG)
    for i, s in enumerate(steps, 1):
        h.step(s, i)
    h.finish(len(steps))
    return h


def test_a_tile_waits_for_the_next_tiles_first_planes():
    h = run([step([0], [(0, 0, 10)]),
             step([0, 1], [(0, 5, 10), (1, 0, 4)]),    # tile 1's first planes reached
             step([1], [(1, 2, 8)]),
             step([1], [(1, 5, 10)]),                  # planes 0, 1 two pings clear
             step([1], [(1, 6, 10)], closed=[0]),      # tile 0 complete, plane 2 too:
             step([1], [(1, 6, 10)]),                  # handed back at once
             step([1, 2], [(1, 8, 10), (2, 0, 3)])])
    # tile 0 with tile 1's first planes after its first 4 pings (complete: the later
    # pings start at plane 6); tile 1 at the end with tile 2's planes
    assert h.order == [(0, (1, 4)), (1, (2, 1)), (2, None)]
    s = h.seams()
    assert s[0] == (0, False, 4, True) and s[1] == (1, True, 1, True)
    assert s[2] == (2, True, None, True)


def test_the_hold_ends_after_close_after_pings_without_the_planes():
    h = run([step([0, 1], [(0, 0, 10), (1, 0, 1)], closed=[]),
             step([1], [(1, 0, 3)], closed=[0]),        # held at 2
             step([1], [(1, 0, 3)]),                     # planes still reached
             step([1], [(1, 0, 3)]),                     # 2 pings: handed back without
             step([1], [(1, 5, 9)])])
    assert h.order[0] == (0, None)
    assert h.seams()[0] == (0, False, None, True)


def test_planes_reached_again_after_the_hand_back_are_not_final():
    h = run([step([0, 1], [(0, 0, 10), (1, 0, 3)]),
             step([0, 1], [(0, 8, 10), (1, 4, 9)]),
             step([1], [(1, 5, 9)], closed=[0]),        # tile 1's planes 0..2: 2 clear
             step([1], [(1, 1, 4)])])                    # a turn: reached again
    assert h.order[0] == (0, (1, 3))
    assert h.seams()[0] == (0, False, 3, False)


def test_a_tile_closed_early_goes_without_the_next_tiles_planes():
    h = run([step([0, 1], [(0, 0, 10), (1, 0, 5)]),
             step([1, 2], [(1, 0, 5), (2, 0, 5)], early=[0])])
    assert h.order[0] == (0, None)
    assert h.seams()[1][1]          # tile 0 then tile 1: the planes go on


def test_prefix_plan_cuts_ranges_across_segment_files():
    p = TilePlan("r", "r", 4, (("a.h5", 5, 8), ("b.h5", 0, 4)), tuple(range(7)),
                 (0, 9), (0.0, 0.0, 0.0, 0.0), "hw")
    q = prefix_plan(p, 5)
    assert q.ranges == (("a.h5", 5, 8), ("b.h5", 0, 2)) and q.sequences == (0, 1, 2, 3, 4)
    assert prefix_plan(p, 2).ranges == (("a.h5", 5, 7),)
    assert prefix_plan(p, 7) == p
