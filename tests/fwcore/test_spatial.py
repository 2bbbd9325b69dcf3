"""The Hilbert key: a walk through every cell, one step to a neighbour at a time; points without a position last."""

import numpy as np
import pytest

from fwcore.spatial import NO_POSITION, finite_bounds, hilbert_key, spatial_order, square_bounds


def _reference_key(n: int, x: int, y: int) -> int:
    """The textbook xy -> d of a Hilbert curve of side n, one point at a time."""
    d, s = 0, n // 2
    while s > 0:
        rx, ry = int(x & s > 0), int(y & s > 0)
        d += s * s * ((3 * rx) ^ ry)
        if ry == 0:
            if rx == 1:
                x, y = n - 1 - x, n - 1 - y
            x, y = y, x
        s //= 2
    return d


@pytest.mark.parametrize("order", [1, 3, 5])
def test_the_key_visits_every_cell_once_stepping_to_a_neighbour(order):
    n = 1 << order
    cx, cy = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n)))
    key = hilbert_key(cx + 0.5, cy + 0.5, (0.0, 0.0, float(n), float(n)), order)
    assert sorted(key.tolist()) == list(range(n * n))
    walk = np.argsort(key)
    steps = np.abs(np.diff(cx[walk])) + np.abs(np.diff(cy[walk]))
    assert (steps == 1).all()
    assert key.tolist() == [_reference_key(n, int(a), int(b)) for a, b in zip(cx, cy)]


def test_points_outside_are_clamped_and_points_without_a_position_go_last():
    x = np.array([-5.0, 0.0, 10.0, 20.0, np.nan, 3.0])
    y = np.array([-5.0, 0.0, 10.0, 20.0, 1.0, np.inf])
    key = hilbert_key(x, y, (0.0, 0.0, 10.0, 10.0), order=4)
    assert key[0] == key[1] == 0 and key[2] == key[3]
    assert key[4] == key[5] == NO_POSITION
    assert spatial_order(x, y).tolist()[-2:] == [4, 5]


def test_spatial_order_keeps_a_cells_points_in_their_order_and_handles_no_extent():
    x, y = np.full(5, 2.0), np.full(5, 3.0)
    assert spatial_order(x, y).tolist() == [0, 1, 2, 3, 4]
    assert finite_bounds(np.array([np.nan]), np.array([1.0])) is None
    assert spatial_order(np.array([np.nan, np.nan]), np.array([0.0, 1.0])).tolist() == [0, 1]


def test_an_order_out_of_range_is_refused():
    with pytest.raises(ValueError, match="order"):
        hilbert_key(np.zeros(1), np.zeros(1), (0, 0, 1, 1), order=32)


def test_a_strip_is_ordered_along_its_length_over_the_square_on_it():
    assert square_bounds((10.0, -200.0, 12.0, 200.0)) == (10.0, -200.0, 410.0, 200.0)
    rng = np.random.default_rng(1)
    x, y = rng.uniform(10, 12, 4000), rng.uniform(-200, 200, 4000)  # a range's strip of a flight line
    thirds = np.array_split(spatial_order(x, y), 3)  # three row groups: each a third of the strip's length
    assert all(np.ptp(y[t]) < 200 for t in thirds)
    assert max(np.ptp(y[t]) for t in np.array_split(spatial_order(x, y, (10.0, -200.0, 12.0, 200.0)), 3)) >= 200
