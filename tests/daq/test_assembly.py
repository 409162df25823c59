"""Instrument data to pings: the digitiser's complete ping (decoded from real protocol
bytes), the sequencer's transmit record and a pose make the same Ping, and the same tile,
as the simulator's; records that do not belong together are refused, naming the field;
the array is placed in the tile frame as written out by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim_device.environment_source import EnvironmentSource
from sim_device.scene import PointTarget, load_scene
from svss_daq.assembly import AssemblyError, PingAssembler, acoustic_axis
from svss_daq.config import config_path
from svss_daq.frames import TrackLine
from svss_daq.geometry import ArrayGeometry, array_geometry, place_array
from svss_daq.ping import NavSnapshot
from svss_daq.protocols import digitiser as dg
from svss_daq.protocols import sequencer as sq
from svss_proc.imaging.imager import TileImager


def _nav(**kw) -> NavSnapshot:
    base = dict(time_ns=1_700_000_000_000_000_000, north_m=0.0, east_m=0.0, down_m=0.0,
                vel_north_m_s=1.0, vel_east_m_s=0.0, vel_down_m_s=0.0, roll_rad=0.0,
                pitch_rad=0.0, heading_rad=0.0, altitude_m=2.5)
    return NavSnapshot(**{**base, **kw})


def _over_the_wire(ping, window_start_ns: int, projector: int):
    """The ping as the instruments report it: digitiser frames (16 channels each) through
    the stream decoder, and the sequencer's PING sentence through its parser."""
    frames = dg.encode_data_frames(ping.sequence, ping.transmit_time_ns,
                                   ping.transmit_time_ns + window_start_ns, ping.samples, 16)
    dec = dg.DigitiserStreamDecoder()
    out = []
    for f in frames:
        out += dec.feed(f[:25]) + dec.feed(f[25:])      # split mid-header on purpose
    (complete,) = [o for o in out if isinstance(o, dg.CompletePing)]
    parser = sq.SequencerStreamParser()
    (event,) = parser.feed(b"garbage\r\n" + sq.encode(
        sq.PingEvent(ping.sequence, projector, ping.transmit_time_ns)))
    return complete, event


@pytest.fixture(scope="module")
def point_source(hardware):
    sc = load_scene(config_path("scenes/demo.toml"))
    sc = dataclasses.replace(sc, points=(PointTarget(along_m=3.0, cross_m=0.1, depth_m=0.4,
                                                     target_strength_db=-10.0),))
    return EnvironmentSource(hardware, sc)


def test_instrument_records_make_the_simulators_ping(hardware, point_source):
    sim = point_source.ping(12)
    asm = PingAssembler(hardware)
    complete, event = _over_the_wire(sim, sim.window_start_ns, sim.projector)
    ping = asm.from_instrument(complete, event, sim.nav)
    assert (ping.sequence, ping.projector, ping.transmit_time_ns, ping.window_start_ns) == (
        sim.sequence, sim.projector, sim.transmit_time_ns, sim.window_start_ns)
    assert ping.samples.dtype == np.int32
    np.testing.assert_array_equal(ping.samples, sim.samples)
    assert ping.config_id == hardware.id
    # the time axis travels with the ping: sample n taken at window start + n / fs
    dig = hardware.value.digitiser
    ax = ping.sample_axis
    assert ax.n == dig.window_samples and ax.step_s == pytest.approx(1 / dig.sample_rate_hz)
    assert acoustic_axis(ax, dig).times()[10] == pytest.approx(
        dig.window_start_s + 10 / dig.sample_rate_hz - dig.group_delay_s, abs=1e-12)


def test_instrument_pings_image_like_simulated_ones(hardware, demo_processing, point_source):
    base = demo_processing.value
    proc = dataclasses.replace(base, products=None, tile=dataclasses.replace(
        base.tile, length_m=2.0, width_m=0.6, depth_m=0.6, top_m=0.1))
    asm = PingAssembler(hardware)
    direct, wired = TileImager(hardware, proc), TileImager(hardware, proc)
    tiles_a, tiles_b = [], []
    for i in range(0, 60, 2):
        sim = point_source.ping(i)
        complete, event = _over_the_wire(sim, sim.window_start_ns, sim.projector)
        tiles_a += direct.add(sim)
        tiles_b += wired.add(asm.from_instrument(complete, event, sim.nav))
    tiles_a += direct.finish()
    tiles_b += wired.finish()
    assert [t.grid.index for t in tiles_a] == [t.grid.index for t in tiles_b]
    assert max(np.abs(t.image).max() for t in tiles_a) > 0
    for a, b in zip(tiles_a, tiles_b):
        np.testing.assert_array_equal(a.image, b.image)


def test_records_that_do_not_belong_together_are_refused(hardware, point_source):
    sim = point_source.ping(3)
    asm = PingAssembler(hardware)
    complete, event = _over_the_wire(sim, sim.window_start_ns, sim.projector)
    with pytest.raises(AssemblyError, match="sequence"):
        asm.from_instrument(complete, dataclasses.replace(event, sequence=4), sim.nav)
    with pytest.raises(AssemblyError, match="transmit_time_ns"):
        asm.from_instrument(complete, dataclasses.replace(
            event, transmit_time_ns=event.transmit_time_ns + 1000), sim.nav)
    with pytest.raises(AssemblyError, match="projector 9"):
        asm.from_instrument(complete, dataclasses.replace(event, projector=9), sim.nav)
    with pytest.raises(AssemblyError, match=r"\(80, n\)"):
        asm.from_instrument(dataclasses.replace(complete, samples=complete.samples[:79]),
                            event, sim.nav)
    late = dataclasses.replace(complete, first_sample_time_ns=complete.transmit_time_ns - 1)
    with pytest.raises(AssemblyError, match="first_sample_time_ns"):
        asm.from_instrument(late, event, sim.nav)


def test_simulated_pings_follow_the_schedule(hardware):
    asm = PingAssembler(hardware)
    order = hardware.value.sequencer.projector_order
    codes = np.zeros((80, 16), dtype=np.int32)
    for i in (0, 1, len(order), 2 * len(order) + 3):
        p = asm.from_simulation(i, codes, _nav(time_ns=5_000 + i))
        assert p.projector == order[i % len(order)] and p.transmit_time_ns == 5_000 + i
    with pytest.raises(AssemblyError, match="integer"):
        asm.from_simulation(0, codes.astype(float), _nav())


def _one_element_array(element) -> ArrayGeometry:
    e = np.array([element], dtype=float)
    return ArrayGeometry(e, e.copy(), np.array([0.0, 0.0, 1.0]), 0.4, 0.9)


def test_place_array_against_hand_written_poses():
    # heading east, level: body forward is east, starboard is south, down is down
    geo = _one_element_array([0.3, 0.1, 0.2])
    nav = _nav(north_m=10.0, east_m=20.0, down_m=0.5, heading_rad=math.pi / 2)
    ned = place_array(geo, nav, 0)
    np.testing.assert_allclose(ned.tx, [10.0 - 0.1, 20.0 + 0.3, 0.7], atol=1e-12)
    line = TrackLine((10.0, 0.0), math.pi / 2, 3.0)         # along = east, cross = south
    tile = place_array(geo, nav, 0, line)
    np.testing.assert_allclose(tile.tx, [20.3, 0.1, 0.7 - 3.0], atol=1e-12)
    np.testing.assert_allclose(tile.rx[0], tile.tx, atol=1e-12)
    np.testing.assert_allclose(tile.bore, [0.0, 0.0, 1.0], atol=1e-12)
    # rolled 90 degrees starboard-down: starboard points down, down points to port
    geo = _one_element_array([0.0, 1.0, 0.0])
    rolled = place_array(geo, _nav(roll_rad=math.pi / 2), 0)
    np.testing.assert_allclose(rolled.tx, [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(rolled.bore, [0.0, -1.0, 0.0], atol=1e-12)
    # pitched 30 degrees nose-up: forward rises (down decreases)
    geo = _one_element_array([1.0, 0.0, 0.0])
    pitched = place_array(geo, _nav(pitch_rad=math.radians(30)), 0)
    np.testing.assert_allclose(pitched.tx, [math.cos(math.radians(30)), 0.0,
                                            -math.sin(math.radians(30))], atol=1e-12)


def test_place_array_refuses_a_missing_projector(hardware):
    geo = array_geometry(hardware.value)
    with pytest.raises(ValueError, match="projector 7"):
        place_array(geo, _nav(), 7)
