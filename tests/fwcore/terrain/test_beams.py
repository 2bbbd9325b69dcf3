"""Where a pulse's gap belongs: its beam at its leaves' (or the canopy's) mean interception height, by
hand-computed geometry."""

import numpy as np
import pytest

from fwcore.terrain.beams import beam_positions, pulse_interception_heights, range_normalised


def test_a_slanted_beam_is_placed_where_it_crosses_the_height_and_a_lone_echo_borrows_its_neighbour_s():
    # pulse 1: ground at (0, 0, 100), a leaf 10 m up and 2 m across (a beam 11.3 degrees off nadir)
    # pulse 2: one ground echo 3 m away, on terrain 1 m higher: the same direction, from its own end
    pulse = np.array([1, 1, 2])
    x, y, z = np.array([0.0, 2.0, 3.0]), np.array([0.0, 0.0, 1.0]), np.array([100.0, 110.0, 101.0])
    height = np.array([0.0, 10.0, 0.0])
    bx, by = beam_positions(pulse, x, y, z, height, at=5.0)
    np.testing.assert_allclose(bx, [1.0, 1.0, 4.0])
    np.testing.assert_allclose(by, [0.0, 0.0, 1.0])
    # no height to place them at, or no pulse with two echoes a metre apart: where they lie
    for at, zz in ((np.nan, z), (5.0, np.array([100.0, 100.5, 101.0]))):
        bx, by = beam_positions(pulse, x, y, zz, height, at=at)
        np.testing.assert_array_equal(bx, x)


def test_each_pulse_s_own_leaves_give_its_height_and_a_gap_s_pulse_its_neighbours():
    # pulse 7 ends at (0, 0): leaves 10 m up (energy 1) and 20 m up (3), an unusable echo (NaN energy), its ground;
    # pulse 5 ends at (1, 0): one leaf 6 m up that stopped the beam; pulse 9 ends at (30, 0): a leaf 2 m up;
    # pulse 3 ends at (0.5, 1): its ground only (a gap), nearest to pulses 7 and 5
    pulse = np.array([7, 7, 7, 7, 5, 9, 9, 3])
    x = np.array([2.0, 4.0, 6.0, 0.0, 1.0, 30.0, 30.0, 0.5])
    y = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    height = np.array([10.0, 20.0, 30.0, 0.0, 6.0, 2.0, 0.0, 0.0])
    z = 100.0 + height
    energy = np.array([1.0, 3.0, np.nan, 5.0, 2.0, 1.0, 1.0, 4.0])
    veg = np.array([True, True, True, False, True, True, False, False])
    own = [17.5, 17.5, 17.5, 17.5, 6.0, 2.0, 2.0]
    np.testing.assert_allclose(pulse_interception_heights(pulse, x, y, z, height, energy, veg, neighbours=2),
                               own + [(17.5 + 6.0) / 2])
    np.testing.assert_allclose(pulse_interception_heights(pulse, x, y, z, height, energy, veg, neighbours=8),
                               own + [(17.5 + 6.0 + 2.0) / 3])  # no more than there are
    # no pulse with leaves: no height
    assert np.isnan(pulse_interception_heights(pulse, x, y, z, height, energy, np.zeros(8, bool))).all()
    assert pulse_interception_heights(pulse[:0], x[:0], y[:0], z[:0], height[:0], energy[:0], veg[:0]).shape == (0,)


def test_each_pulse_is_placed_at_its_own_height():
    # pulse 1: ground at (0, 0, 100), a leaf 10 m up and 2 m across: at its leaf's height, x 2 (the leaf itself);
    # pulse 2: one ground echo at (3, 1, 101) with pulse 1's direction, 2.5 m up: x 3.5;
    # pulse 3: a leaf 4 m up and 1 m across from its ground at (10, 0, 99), no height: where its echoes lie
    pulse = np.array([1, 1, 2, 3, 3])
    x, y = np.array([0.0, 2.0, 3.0, 10.0, 11.0]), np.array([0.0, 0.0, 1.0, 0.0, 0.0])
    z = np.array([100.0, 110.0, 101.0, 99.0, 103.0])
    height = np.array([0.0, 10.0, 0.0, 0.0, 4.0])
    at = np.array([10.0, 10.0, 2.5, np.nan, np.nan])
    bx, by = beam_positions(pulse, x, y, z, height, at)
    np.testing.assert_allclose(bx, [2.0, 2.0, 3.5, 10.0, 11.0])
    np.testing.assert_allclose(by, [0.0, 0.0, 1.0, 0.0, 0.0])
    # one height per echo the same as one for all
    same = beam_positions(pulse[:3], x[:3], y[:3], z[:3], height[:3], np.full(3, 5.0))
    np.testing.assert_allclose(same[0], beam_positions(pulse[:3], x[:3], y[:3], z[:3], height[:3], 5.0)[0])


def test_energies_on_one_scale_by_the_square_of_their_range():
    np.testing.assert_allclose(range_normalised(np.array([2.0, 1.0]), np.array([500.0, 480.0])),
                               [2.0 * 500 ** 2, 480.0 ** 2])
    np.testing.assert_array_equal(range_normalised(np.array([2.0, 1.0]), np.array([500.0, np.nan])), [2.0, 1.0])
