"""Terrain interpolation: exact on planes (triangulation and bilinear), nearest outside the ground's hull."""

import numpy as np

from fwcore.terrain.dtm import bilinear, interpolate, thin


def test_a_plane_is_interpolated_exactly_inside_and_held_outside():
    rng = np.random.default_rng(0)
    gx, gy = rng.uniform(0, 10, 200), rng.uniform(0, 10, 200)
    plane = lambda x, y: 3.0 + 0.2 * x - 0.1 * y  # noqa: E731
    qx, qy = rng.uniform(2, 8, 50), rng.uniform(2, 8, 50)
    np.testing.assert_allclose(interpolate(gx, gy, plane(gx, gy), qx, qy), plane(qx, qy), atol=1e-9)
    far = interpolate(gx, gy, plane(gx, gy), np.array([100.0]), np.array([5.0]), thin_cell=None)
    nearest = np.argmin((gx - 100) ** 2 + (gy - 5) ** 2)
    assert far[0] == plane(gx, gy)[nearest]
    assert np.isnan(interpolate(np.zeros(0), np.zeros(0), np.zeros(0), qx, qy)).all()


def test_bilinear_between_cell_centres_and_the_edge_beyond_them():
    # centres at x 0.5, 1.5, 2.5 and y 1.5 (north row), 0.5: values a plane 2x + 10y
    raster = np.array([[2 * 0.5 + 15, 2 * 1.5 + 15, 2 * 2.5 + 15], [2 * 0.5 + 5, 2 * 1.5 + 5, 2 * 2.5 + 5]])
    x, y = np.array([1.0, 2.2, 0.5]), np.array([1.0, 0.7, 1.5])
    np.testing.assert_allclose(bilinear(raster, 0.0, 2.0, 1.0, x, y), 2 * x + 10 * y)
    assert bilinear(raster, 0.0, 2.0, 1.0, np.array([-5.0]), np.array([1.5]))[0] == raster[0, 0]


def test_thinning_keeps_one_mean_point_a_cell():
    gx, gy, gz = np.array([0.1, 0.3, 1.5, 0.2]), np.array([0.1, 0.5, 0.5, 1.7]), np.array([1.0, 3.0, 5.0, 7.0])
    tx, ty, tz = thin(gx, gy, gz, 1.0)
    order = np.argsort(tz)
    np.testing.assert_allclose(np.c_[tx, ty, tz][order], [[0.2, 0.3, 2.0], [1.5, 0.5, 5.0], [0.2, 1.7, 7.0]])
