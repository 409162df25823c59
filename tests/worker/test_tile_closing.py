"""When a tile is complete: once ``tile.close_after_pings`` consecutive pings' reach has
stayed clear of it, whichever way the boat moves (forward, reversing, stopped), and at
run end. Pings from the ping assembler on poses chosen here; small tiles (2 m)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from svss_daq.assembly import PingAssembler
from svss_daq.config import HardwareConfig, ProcessingConfig, config_path, load_with_text, \
    loaded_from_text
from svss_daq.ping import NavSnapshot
from svss_proc.imaging.imager import TileImager
from svss_proc.imaging.schedule import CLOSE_AFTER_PINGS

from .conftest import small_processing_text

HEADING = math.radians(30.0)
DT_NS = 100_000_000                   # 10 pings/s


@pytest.fixture(scope="module")
def hw():
    return load_with_text(HardwareConfig, config_path("hardware.toml"))


def proc(hold: int | None = None):
    text = small_processing_text()
    if hold is None:
        text = text.replace("close_after_pings = 20", "")
    else:
        text = text.replace("close_after_pings = 20", f"close_after_pings = {hold}")
    return loaded_from_text(ProcessingConfig, text, "small-processing")


def pings(hw, along: list[float], reverse_from: int | None = None):
    """Pings at along-track positions ``along`` (m from the start, on a line heading
    30 deg), 0.1 s apart; from index ``reverse_from`` on the boat has turned round."""
    asm = PingAssembler(hw)
    dig = hw.value.digitiser
    rng = np.random.default_rng(1)
    samples = rng.integers(-1000, 1000, (dig.n_channels, dig.window_samples), dtype=np.int32)
    out = []
    t0 = 1_700_000_000_000_000_000
    for i, s in enumerate(along):
        h = HEADING + (math.pi if reverse_from is not None and i >= reverse_from else 0.0)
        v = 0.0 if i == 0 else (s - along[i - 1]) / (DT_NS * 1e-9)
        nav = NavSnapshot(time_ns=t0 + i * DT_NS, north_m=100 + s * math.cos(HEADING),
                          east_m=200 + s * math.sin(HEADING), down_m=0.5,
                          vel_north_m_s=v * math.cos(HEADING),
                          vel_east_m_s=v * math.sin(HEADING), vel_down_m_s=0.0,
                          roll_rad=0.0, pitch_rad=0.0, heading_rad=h, altitude_m=2.0,
                          quality=8)
        out.append(asm.from_simulation(i, samples, nav))
    return out


def image(hw, pings, processing):
    """Feed ``pings``; return {tile index: (ping index it closed at, its pings)}, the
    imager, and the tiles closed only at finish."""
    im = TileImager(hw, processing.value)
    closed = {}
    for i, p in enumerate(pings):
        for t in im.add(p):
            assert t.grid.index not in closed, f"tile {t.grid.index} closed twice"
            closed[t.grid.index] = (i, list(t.pings))
    at_end = {t.grid.index: (len(pings), list(t.pings)) for t in im.finish()}
    assert not set(at_end) & set(closed)
    return closed, at_end, im


def test_default_hold_when_omitted():
    """One definition: the schema's default, which the loader gives an omitted key and
    the schedule gives a configuration built in code without one."""
    assert CLOSE_AFTER_PINGS == 20
    assert proc().value.tile.close_after_pings == 20


def test_forward_tiles_close_in_order_after_the_hold(hw):
    track = [0.1 * i for i in range(80)]             # 8 m forward
    closed, at_end, im = image(hw, pings(hw, track), proc(20))
    order = sorted(closed, key=lambda k: closed[k][0])
    assert order == sorted(closed) and len(closed) >= 2
    for k, (i, seqs) in closed.items():
        # the hold: the last ping that reached the tile is exactly 20 pings before
        assert i - max(seqs) >= 20 - 1
    assert im.late_pings == 0
    # a longer hold closes the same tiles later, with the same pings
    closed40, at_end40, _ = image(hw, pings(hw, track), proc(40))
    every20 = {**closed, **at_end}
    every40 = {**closed40, **at_end40}
    assert every20.keys() == every40.keys()
    for k in every20:
        assert every20[k][1] == every40[k][1]
        if k in closed40:
            assert closed40[k][0] == closed[k][0] + 20


def test_stopped_boat_keeps_its_tiles_open(hw):
    track = [0.1 * i for i in range(30)] + [3.0] * 100 + [3.0 + 0.1 * i for i in range(1, 40)]
    closed, at_end, _ = image(hw, pings(hw, track), proc(20))
    everything = {**closed, **at_end}
    here = [k for k, (_, seqs) in everything.items() if 80 in seqs]   # under the stop
    assert here
    for k in here:
        i, seqs = everything[k]
        assert set(range(30, 130)) <= set(seqs)     # every stopped ping went in
        assert i >= 130                              # closed only after moving on


def test_reversing_boat(hw):
    fwd = [0.1 * i for i in range(60)]               # 0 -> 5.9 m
    back = [5.9 - 0.1 * i for i in range(1, 60)]     # backing up to 0 m
    closed, at_end, im = image(hw, pings(hw, fwd + back), proc(20))
    everything = {**closed, **at_end}
    # the tiles at the turn stay open while the boat turns and take both legs
    turn = [k for k, (_, seqs) in everything.items() if 59 in seqs]
    assert turn
    for k in turn:
        seqs = everything[k][1]
        assert min(seqs) < 60 <= max(seqs)
    # tiles the boat left on the way out closed, and pings reaching only them on the way
    # back are late (counted), never imaged into a tile already written
    first = min(everything)
    assert first in closed and closed[first][0] < 60
    assert im.late_pings > 0
    for k, (i, s) in closed.items():
        assert all(q < i for q in s)
    # tiles left behind on the way back close after the hold, before the run ends
    assert any(i >= 60 for i, _ in closed.values())


def test_the_memory_bound_reached_is_said_to_the_daemon(hw):
    """Tiles closed early for ``limits.memory_gib`` (and pings refused for it) mark the
    bound reached: the worker's progress messages carry it (alarm worker.memory_bound)."""
    from types import SimpleNamespace

    from svss_proc.preflight import GIB, plane_bytes, product_bytes
    from svss_proc.imaging.schedule import TileSchedule
    from svss_proc.worker import memory_state

    base = proc(100).value          # a long hold: tiles stay open behind the boat
    gib = (product_bytes(base) + 2.5 * plane_bytes(base)) / GIB     # room for 2 tiles
    p = dataclasses.replace(base, limits=dataclasses.replace(base.limits, memory_gib=gib))
    sched = TileSchedule(hw, p)
    assert sched.max_open_tiles == 2 and sched.memory_bound_at is None
    worker = SimpleNamespace(imager=SimpleNamespace(
        schedule=sched, active={}, accumulator=SimpleNamespace(method="factorised")))
    ps = pings(hw, [0.1 * i for i in range(40)])              # 4 m forward: 3 tiles
    for ping in ps[:5]:
        sched.step(ping)
    assert memory_state(worker, 0.0)["memory_bound_age_s"] is None
    early = [k for ping in ps[5:] for k in sched.step(ping).closed_early]
    assert early and sched.memory_bound_at is not None
    state = memory_state(worker, sched.memory_bound_at + 1.5)
    assert state == {"open_tiles": 0, "max_open_tiles": 2, "memory_bound_age_s": 1.5,
                     "imaging_method": "factorised"}
