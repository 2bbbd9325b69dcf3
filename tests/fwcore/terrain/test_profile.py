"""Relative heights and the plant area volume density from energy by height above the terrain."""

import numpy as np

from fwcore.metrics.canopy import plant_area_index, gap_probability
from fwcore.terrain.profile import cover_and_pai, plant_area_density, relative_heights


def test_relative_heights_interpolate_within_a_bin():
    # bins of 1 m from -1 m: the ground's energy 4 in [-1, 0), the canopy's 4 in [10, 11) and 2 in [15, 16)
    sums = np.zeros((2, 20))
    sums[0, 0], sums[0, 11], sums[0, 16] = 4.0, 4.0, 2.0
    rh50 = relative_heights(sums, -1.0, 1.0, 50.0)
    rh98 = relative_heights(sums, -1.0, 1.0, 98.0)
    assert rh50[0] == 10.25  # 5 of 10: 1 into the bin at 10 m that holds 4
    assert np.isclose(rh98[0], 15.9)  # 9.8 of 10: 1.8 into the bin at 15 m that holds 2
    assert np.isnan(rh50[1])


def test_the_profile_of_plant_area_sums_to_the_cell_pai():
    canopy = np.array([[0.0, 1.0, 2.0, 3.0, 0.5]])  # energy per 2 m bin from the terrain up
    rv, rg = canopy.sum(axis=1), np.array([4.0])
    pavd = plant_area_density(canopy, rv, rg, 2.0)
    cover, pai = cover_and_pai(rv, rg)
    np.testing.assert_allclose(pavd.sum() * 2.0, pai)
    np.testing.assert_allclose(pai, plant_area_index(gap_probability(rv, rg), 1.0))
    np.testing.assert_allclose(cover, 1 - (1 - 6.5 / (6.5 + 1.5 * 4.0)))
    # the top bin holds the PAI of its own energy: -ln(1 - 0.5 / 12.5) / 0.5 over 2 m
    np.testing.assert_allclose(pavd[0, -1], -np.log(1 - 0.5 / 12.5) / 0.5 / 2.0)
    assert np.isnan(cover_and_pai(np.zeros(1), np.zeros(1))[0]).all()
