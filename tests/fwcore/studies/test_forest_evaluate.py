"""Comparing maps with the truth: grids that meet, blocks, errors by hand."""

import numpy as np

from fwcore.studies.forest_evaluate import Raster, block_mean, canopy_accuracy, ground_scores, on_grid, rmse


def test_a_map_meets_the_truth_where_its_cells_centres_fall():
    truth = Raster(np.arange(20.0).reshape(4, 5), -1.0, 3.0, 1.0)  # x -1..4, y -1..3
    coarse = Raster(np.zeros((2, 2)), 0.0, 2.0, 2.0)  # x 0..4, y -2..2: the second row half outside
    np.testing.assert_array_equal(on_grid(truth, coarse)[0], [truth.values[2, 2], truth.values[2, 4]])
    assert np.isnan(on_grid(truth, coarse)[1]).all()
    # the mean over whole blocks: the first block holds rows 1-2, columns 1-2
    blocks = block_mean(truth, coarse)
    assert blocks[0, 0] == np.mean(truth.values[1:3, 1:3]) and np.isnan(blocks[1, 0])


def test_errors_by_hand():
    assert rmse(np.array([3.0, -4.0, np.nan])) == np.sqrt(12.5)
    s = ground_scores(np.array([1, 1, 0, 0, 1], bool), np.array([1, 0, 1, 0, 1], bool))
    assert (s["precision"], s["recall"]) == (2 / 3, 2 / 3) and s["f1"] == 2 / 3
    truth_gap = Raster(np.full((2, 2), 0.25), 0.0, 2.0, 1.0)
    truth_pai = Raster(np.full((2, 2), 2.0), 0.0, 2.0, 1.0)
    crowns = Raster(np.ones((2, 2)), 0.0, 2.0, 1.0)
    cover, pai = Raster(np.array([[0.7]]), 0.0, 2.0, 2.0), Raster(np.array([[2.2]]), 0.0, 2.0, 2.0)
    a = canopy_accuracy(cover, pai, truth_gap, truth_pai, crowns, np.ones((1, 1), bool))
    assert np.isclose(a["cover_median_abs_error"], 0.05) and np.isclose(a["cover_vs_crowns_median_abs_error"], 0.3)
    assert np.isclose(a["pai_median_relative_error"], 0.1)
    assert np.isclose(a["pai_effective_median_relative_error"], abs(2.2 + np.log(0.25) / 0.5) / (-np.log(0.25) / 0.5))
    assert np.isclose(a["pai_effective_median_bias"], (2.2 + np.log(0.25) / 0.5) / (-np.log(0.25) / 0.5))  # -0.21
