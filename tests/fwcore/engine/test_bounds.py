"""The initial individual and its boxes: the kernel against the NumPy reference, analytic and tabulated."""

import numpy as np
import pytest

from fwcore.engine.bounds import parameter_bounds
from fwcore.instrument.response import named_response
from fwcore.engine.model import analytic_shape
from fwcore.instrument.shape import echo_shape
from tests.fwcore import naive

ECHOES = dict(amplitude=np.array([120.0, 35.0, 8.0]), position=np.array([1.2, 30.4, 58.7]),
              sigma=np.array([0.9, 3.1, 6.0]))


def _kernel_bounds(shape, gaussian, signal):
    n = 1 + 4 * ECHOES["amplitude"].size
    x0, lower, upper, local = (np.full(n, np.nan) for _ in range(4))
    parameter_bounds(10.0, 1.5, ECHOES["amplitude"], ECHOES["position"], ECHOES["sigma"], signal, 0.0, 59.0,
                     gaussian, 0.9, 2.6, shape, 2.0, x0, lower, upper, local)
    return x0, lower, upper, local


@pytest.mark.parametrize("gaussian", [False, True])
@pytest.mark.parametrize("tabulated", [False, True])
def test_bounds_match_the_numpy_reference(gaussian, tabulated):
    signal = 10.0 + np.random.default_rng(6).uniform(0.0, 150.0, 60)
    shape = echo_shape(named_response("riegl"), 1000.0) if tabulated else analytic_shape()
    widths = (shape.s_min, shape.s_min + shape.s_step * (shape.rows.shape[0] - 1)) if tabulated else None
    expected = naive.parameter_bounds(10.0, 1.5, ECHOES["amplitude"], ECHOES["position"], ECHOES["sigma"], signal,
                                      0.0, 59.0, gaussian, 0.9, 2.6, 2.0, widths)
    for got, want in zip(_kernel_bounds(shape, gaussian, signal), expected):
        np.testing.assert_array_equal(got, want)
    x0, lower, upper, _ = expected
    assert (lower <= x0).all() and (x0 <= upper).all()


def test_bounds_by_hand_for_one_echo():
    x0, lower, upper, local = naive.parameter_bounds(10.0, 1.5, [120.0], [30.4], [3.1], np.full(60, 210.0),
                                                     0.0, 59.0, False, 0.9, 2.6, 2.0)
    np.testing.assert_allclose(lower, [5.5, 0.0, 30.4 - 4.65, 0.775, 0.9])
    np.testing.assert_allclose(upper, [14.5, 184.5, 30.4 + 4.65, 9.3, 2.6])
    np.testing.assert_allclose(local, [14.5, 304.5, 30.4 + 4.65, 9.3, 2.6])  # 1.5 x the 200 DN at the echo
    np.testing.assert_allclose(x0, [10.0, 120.0, 30.4, 3.1, np.sqrt(2)])
