"""ASPRS classes from ground, buildings and heights."""

import numpy as np

from fwcore.terrain.classes import asprs_classes


def test_classes_by_height_ground_and_buildings_first():
    height = np.array([0.0, 0.1, 0.5, 3.0, 12.0, 8.0, 0.05, np.nan])
    ground = np.array([True, False, False, False, False, False, False, False])
    building = np.array([False, False, False, False, False, True, False, False])
    np.testing.assert_array_equal(asprs_classes(height, ground, building), [2, 1, 3, 4, 5, 6, 1, 1])
    noise = np.zeros(8, bool)
    noise[1] = True
    assert asprs_classes(height, ground, building, noise)[1] == 7
