"""The truth rasters of a forest: one crown's cover and PAI by hand, and the files beside a flight."""

import math

import numpy as np

from fwcore.studies.forest import ForestConfig, draw_forest
from fwcore.studies.forest_trace import TreeIndex
from fwcore.studies.forest_truth import (TRUTH_RASTERS, forest_truth, read_truth_raster, truth_raster_path,
                                         write_forest_flight)
from fwcore.studies.simulate import SensorConfig


def test_one_crown_s_cover_and_pai_are_its_projection_and_its_leaf_area():
    """One ellipsoid of uniform density (no shell, no gradient), radius 4 m, half depth 3 m, density 0.5 on flat
    ground: cover is its disc, PAI at its centre 0.5 x 6 m, and its total leaf area 0.5 x 4/3 pi r^2 a."""
    f = ForestConfig(slope=(0.0, 0.0), break_slope=0.0, ditch_depth_m=0.0, buildings=0)
    drawn = draw_forest((0.0, 0.0, 20.0, 20.0), f, 0)
    tree = np.array([[10.0, 10.0, 130.0, 3.0, 4.0, 0.5, 1.0, 0.5]])
    drawn = type(drawn)(f, (0.0, 0.0, 20.0, 20.0), tree, np.zeros((0, 5)), (0.0, 0.0), TreeIndex.of(tree, 0.0))
    truth = forest_truth(drawn, 1.0, 8)
    assert math.isclose(truth.cover.sum(), math.pi * 16, rel_tol=0.03)
    assert math.isclose(truth.pai.sum(), 0.5 * 4 / 3 * math.pi * 16 * 3, rel_tol=0.03)
    row, col = int(truth.north - 10.5), int(10.5 - truth.west)
    assert math.isclose(truth.pai[row, col], 0.5 * 6.0, rel_tol=0.05)
    # the top: terrain 120 (flat, a gentle roll aside) + 133 - 120; the ground's z beneath at the centre
    assert abs(truth.chm[row, col] - (133.0 - truth.dtm[row, col])) < 0.2
    assert truth.chm[0, 0] == 0 and truth.cover[0, 0] == 0 and truth.pgap[0, 0] == 1.0
    assert math.isclose(truth.pgap[row, col], math.exp(-0.5 * truth.pai[row, col]), rel_tol=0.05)


def test_the_flight_and_its_truth_rasters(tmp_path):
    out = tmp_path / "forest.las"
    flight, rasters = write_forest_flight(out, 3000, SensorConfig(samples_per_packet=360),
                                          __import__("fwcore.studies.forest", fromlist=["x"]).FOREST_SCENE,
                                          ForestConfig(), 2)
    assert [p.name for p in rasters] == [truth_raster_path(out, n).name for n in TRUTH_RASTERS]
    assert flight.n_pulses == 3000 and flight.truth.exists()
    dtm, (west, north, cell) = read_truth_raster(out, "dtm")
    assert cell == 1.0 and np.isfinite(dtm).all() and 100 < dtm.mean() < 140
    cover, _ = read_truth_raster(out, "cover")
    assert 0 < cover.mean() < 1
