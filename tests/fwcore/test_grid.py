"""Map grids: cells aligned on multiples of the cell size, per-cell statistics independent of batching, energy
profiles in height bins above each cell's lowest echo."""

import math

import numpy as np
import pytest

from fwcore.grid import CellStatistics, Grid, HeightProfile


def test_the_grid_is_aligned_on_the_cell_size_and_covers_its_edges():
    grid = Grid.covering(10.3, 20.1, 13.9, 24.0, 2.0)
    assert (grid.west, grid.north, grid.width, grid.height) == (10.0, 26.0, 2, 3)  # 24.0 on an edge: one more row
    assert grid.transform() == (2.0, 0.0, 10.0, 0.0, -2.0, 26.0)
    # row 0 is the north: (10.3, 24.0) in row 1 (24-26 is row 0), (13.9, 20.1) in the last row, last column
    np.testing.assert_array_equal(grid.index([10.3, 13.9, 9.9, 11.0], [24.0, 20.1, 21.0, 26.5]), [2, 5, -1, -1])
    with pytest.raises(ValueError, match="cell size"):
        Grid.covering(0, 0, 1, 1, 0.0)


def test_the_statistics_of_a_cell_and_their_independence_of_batches():
    grid = Grid.covering(0, 0, 3.9, 1.9, 2.0)  # 2 x 1 cells
    x = np.array([0.5, 1.5, 1.0, 3.0, 3.5])
    y = np.array([0.5, 1.5, 1.0, 1.0, 0.2])
    z = np.array([10.0, 12.5, 11.0, 5.0, 7.0])
    amplitude = np.array([10.0, 20.0, 30.0, 40.0, np.nan])
    whole = CellStatistics(grid, ("amplitude",))
    whole.add(x, y, z, amplitude=amplitude)
    batched = CellStatistics(grid, ("amplitude",))
    for part in (slice(0, 2), slice(2, 3), slice(3, 5)):
        batched.add(x[part], y[part], z[part], amplitude=amplitude[part])
    for stats in (whole, batched):
        np.testing.assert_array_equal(stats.count, [3, 2])
        highest, lowest = stats.heights()
        np.testing.assert_array_equal(highest, [12.5, 7.0])
        np.testing.assert_array_equal(lowest, [10.0, 5.0])
        np.testing.assert_allclose(stats.mean("amplitude"), [20.0, 40.0])  # the NaN left out
    empty = CellStatistics(Grid.covering(0, 0, 9, 1, 2.0))
    assert np.isnan(empty.heights()[0]).all()


def test_the_profile_bins_energy_by_height_above_the_cells_lowest_echo():
    grid = Grid.covering(0, 0, 3.9, 1.9, 2.0)
    lowest = np.array([100.0, 5.0])
    bins = HeightProfile.bins_for(np.array([112.5, 7.0]), lowest, 5.0)
    assert bins == 3  # 12.5 m above: bins 0-5, 5-10, 10 and more
    profile = HeightProfile(grid, lowest, 5.0, bins)
    profile.add(np.array([0.5, 1.5, 1.0, 3.0, 3.5]), np.full(5, 1.0), np.array([100.0, 112.5, 104.99, 5.0, 7.0]),
                np.array([1.0, 2.0, 4.0, 8.0, np.nan]))
    np.testing.assert_array_equal(profile.sums, [[5.0, 0.0, 2.0], [8.0, 0.0, 0.0]])
    assert profile.edges() == [(0.0, 5.0), (5.0, 10.0), (10.0, math.inf)]


def test_echoes_added_by_their_cell_add_as_by_their_coordinates():
    rng = np.random.default_rng(8)
    grid = Grid.covering(0, 0, 9.9, 5.9, 1.0)
    x, y, z = rng.uniform(0, 10, 500), rng.uniform(0, 6, 500), rng.normal(50, 10, 500)
    value = np.where(rng.random(500) < 0.1, np.nan, rng.uniform(0, 1, 500))
    by_xy, by_cell = CellStatistics(grid, ("v",)), CellStatistics(grid, ("v",))
    by_xy.add(x, y, z, v=value)
    by_cell.add_cells(grid.index(x, y), z, v=value)
    for name in ("count", "highest", "lowest"):
        assert getattr(by_xy, name).tobytes() == getattr(by_cell, name).tobytes()
    assert by_xy.sums["v"].tobytes() == by_cell.sums["v"].tobytes() and (by_cell.counts["v"] > 0).sum() > 50
    lowest = by_xy.heights()[1]
    profile_xy, profile_cell = HeightProfile(grid, lowest, 2.0, 30), HeightProfile(grid, lowest, 2.0, 30)
    profile_xy.add(x, y, z, value)
    profile_cell.add_cells(grid.index(x, y), z, value)
    assert profile_xy.sums.tobytes() == profile_cell.sums.tobytes() and profile_cell.sums.sum() > 0
