"""Roofs: single, flat echoes above the ground; crowns are neither."""

import numpy as np

from fwcore.terrain.buildings import building_echoes


def test_a_flat_roof_of_single_echoes_is_a_building_and_a_crown_is_not():
    rng = np.random.default_rng(0)
    rx, ry = rng.uniform(0, 10, 400), rng.uniform(0, 10, 400)
    roof_z = 108.0 + rng.normal(0, 0.03, 400)
    cx, cy = rng.uniform(20, 30, 400), rng.uniform(0, 10, 400)
    crown_z = 115.0 + 3 * np.cos((cx - 25) / 3) + rng.normal(0, 0.5, 400)
    x, y, z = np.concatenate([rx, cx]), np.concatenate([ry, cy]), np.concatenate([roof_z, crown_z])
    height = z - 100.0
    single = np.concatenate([np.ones(400, bool), rng.random(400) < 0.3])
    found = building_echoes(x, y, z, height, single)
    assert found[:400].mean() > 0.95
    assert not found[400:].any()
