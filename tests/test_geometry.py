"""Array geometry against the seed paper's description of the SVSS array, the element
positions written out from the documented layout and the rotation in closed form
(tests/references.py)."""

from __future__ import annotations

import numpy as np

from svss_daq.frames import TrackLine, body_to_ned
from svss_daq.geometry import array_geometry, section_positions
from tests.references import body_to_ned_written_out, receivers_written_out

LEVER_ARRAY = np.array([3.0, 0.0, 0.5])      # config/hardware.toml [lever_arms] array_m


def test_eighty_channels_at_9_1_cm(hardware):
    geo = array_geometry(hardware.value)
    rx = geo.receivers
    assert rx.shape == (80, 3)
    assert len(np.unique(np.round(rx, 6), axis=0)) == 80
    d = np.linalg.norm(rx[:, None, :] - rx[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    np.testing.assert_allclose(d.min(axis=1), 0.091, atol=1e-12)   # every element's neighbour


def test_4x12_section_with_4x8_forward_centred(hardware):
    aft, fwd = section_positions(hardware.value.receive_array)
    assert aft.shape == (48, 3) and fwd.shape == (32, 3)
    # 4 rows along-track x 12 columns cross-track, and 4 x 8
    assert len(np.unique(np.round(aft[:, 0], 6))) == 4 and len(np.unique(np.round(aft[:, 1], 6))) == 12
    assert len(np.unique(np.round(fwd[:, 0], 6))) == 4 and len(np.unique(np.round(fwd[:, 1], 6))) == 8
    # forward of the aft section, contiguous at the same pitch, centred cross-track
    assert fwd[:, 0].min() > aft[:, 0].max()
    np.testing.assert_allclose(fwd[:, 0].min() - aft[:, 0].max(), 0.091, atol=1e-12)
    np.testing.assert_allclose(fwd[:, 1].mean(), aft[:, 1].mean(), atol=1e-12)
    # about 73 cm along-track by 1.1 m cross-track (element count x pitch)
    rx = np.concatenate([aft, fwd])
    along = np.ptp(rx[:, 0]) + 0.091
    cross = np.ptp(rx[:, 1]) + 0.091
    assert abs(along - 0.73) < 0.01 and abs(cross - 1.1) < 0.01


def test_modules_are_eight_channel_blocks(hardware):
    rx = array_geometry(hardware.value).receivers
    for m in range(10):
        block = rx[8 * m: 8 * m + 8]
        assert len(np.unique(np.round(block[:, 0], 6))) == 4
        assert len(np.unique(np.round(block[:, 1], 6))) == 2
        np.testing.assert_allclose(np.ptp(block[:, 0]), 3 * 0.091, atol=1e-12)
        np.testing.assert_allclose(np.ptp(block[:, 1]), 0.091, atol=1e-12)


def test_six_projectors_forward_22_9_cm_apart(hardware):
    geo = array_geometry(hardware.value)
    tx = geo.projectors
    assert tx.shape == (6, 3)
    assert tx[:, 0].min() > geo.receivers[:, 0].max()
    np.testing.assert_allclose(np.diff(np.sort(tx[:, 1])), 0.229, atol=1e-12)
    np.testing.assert_allclose(tx[:, 1].mean(), geo.receivers[:, 1].mean(), atol=1e-12)
    np.testing.assert_allclose(geo.boresight, [0, 0, 1])


def test_elements_at_the_documented_positions(hardware):
    geo = array_geometry(hardware.value)
    np.testing.assert_allclose(geo.receivers, receivers_written_out() + LEVER_ARRAY,
                               rtol=0, atol=1e-12)
    # a few channels spelled out (array frame): the first module's aft-port corner, its
    # starboard neighbour, the next row forward, the second module's first, the aft
    # section's last (forward-starboard corner) and the forward section's first
    for ch, pos in [(0, (-0.3185, -0.5005, 0.0)), (1, (-0.3185, -0.4095, 0.0)),
                    (2, (-0.2275, -0.5005, 0.0)), (8, (-0.3185, -0.3185, 0.0)),
                    (47, (-0.0455, 0.5005, 0.0)), (48, (0.0455, -0.3185, 0.0)),
                    (79, (0.3185, 0.3185, 0.0))]:
        np.testing.assert_allclose(geo.receivers[ch], np.array(pos) + LEVER_ARRAY, atol=1e-12)
    ys = (-0.5725, -0.3435, -0.1145, 0.1145, 0.3435, 0.5725)
    np.testing.assert_allclose(geo.projectors,
                               np.array([(0.5185, y, 0.0) for y in ys]) + LEVER_ARRAY, atol=1e-12)


def test_body_to_ned_is_the_closed_form_rotation():
    rng = np.random.default_rng(4)
    for roll, pitch, heading in rng.uniform(-np.pi, np.pi, (50, 3)) * [1, 0.5, 1]:
        r = body_to_ned(roll, pitch, heading)
        np.testing.assert_allclose(r, body_to_ned_written_out(roll, pitch, heading),
                                   rtol=0, atol=1e-15)
    # known vectors: heading east, pitched 90 degrees nose-up: forward points up and
    # starboard still south; heading south, rolled 90 degrees starboard-down: starboard
    # points down and the body's down points to port, which is east
    r = body_to_ned(0.0, np.pi / 2, np.pi / 2)
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(r @ [0, 1, 0], [-1, 0, 0], atol=1e-15)
    r = body_to_ned(np.pi / 2, 0.0, np.pi)
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 1, 0], atol=1e-15)


def test_frames_round_trip_and_orientation():
    r = body_to_ned(0.0, 0.0, np.pi / 2)              # heading east
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)   # forward -> east
    np.testing.assert_allclose(r @ [0, 1, 0], [-1, 0, 0], atol=1e-15)  # starboard -> south
    c10, s10 = np.cos(np.deg2rad(10)), np.sin(np.deg2rad(10))
    r = body_to_ned(0.0, np.deg2rad(10), 0.0)          # nose up: forward points up (z < 0)
    np.testing.assert_allclose(r @ [1, 0, 0], [c10, 0, -s10], atol=1e-15)
    r = body_to_ned(np.deg2rad(10), 0.0, 0.0)          # starboard down
    np.testing.assert_allclose(r @ [0, 1, 0], [0, c10, s10], atol=1e-15)
    line = TrackLine((10.0, -5.0), np.deg2rad(30), 3.0)
    p = np.random.default_rng(1).normal(size=(20, 3)) * 50
    np.testing.assert_allclose(line.tile_to_ned(line.ned_to_tile(p)), p, atol=1e-12)
    # along-track axis points along the heading, cross-track to starboard
    np.testing.assert_allclose(line.ned_to_tile([10 + np.cos(np.deg2rad(30)),
                                                 -5 + np.sin(np.deg2rad(30)), 3.0]),
                               [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(line.rotation_from_ned() @ [-np.sin(np.deg2rad(30)),
                                                           np.cos(np.deg2rad(30)), 0],
                               [0, 1, 0], atol=1e-12)
