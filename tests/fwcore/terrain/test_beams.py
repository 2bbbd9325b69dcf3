"""Where a pulse's gap belongs: its beam at the canopy's mean interception height, by hand-computed geometry."""

import numpy as np
import pytest

from fwcore.terrain.beams import beam_positions, interception_height, range_normalised


def test_the_interception_height_is_the_vegetation_energy_s_mean():
    height = np.array([0.0, 10.0, 20.0, 30.0])
    energy = np.array([5.0, 1.0, 3.0, np.nan])
    veg = np.array([False, True, True, True])
    assert interception_height(height, energy, veg) == pytest.approx((10 * 1 + 20 * 3) / 4)
    assert np.isnan(interception_height(height, energy, np.zeros(4, bool)))


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


def test_energies_on_one_scale_by_the_square_of_their_range():
    np.testing.assert_allclose(range_normalised(np.array([2.0, 1.0]), np.array([500.0, 480.0])),
                               [2.0 * 500 ** 2, 480.0 ** 2])
    np.testing.assert_array_equal(range_normalised(np.array([2.0, 1.0]), np.array([500.0, np.nan])), [2.0, 1.0])
