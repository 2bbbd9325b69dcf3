"""The initial estimate: echoes peeled off one by one, against the naive reference and hand-built waveforms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fwcore.engine.estimate import initial_echoes
from fwcore.engine.model import analytic_shape, tabulated_model, waveform_model
from fwcore.engine.smoothing import gaussian_smooth
from fwcore.instrument.response import named_response
from fwcore.instrument.shape import echo_shape
from tests.fwcore import naive


def test_inflection_points_give_sigma_of_a_clean_gaussian():
    t = np.arange(100.0)
    y = waveform_model(t, 10.0, [200.0], [47.3], [4.0], [math.sqrt(2)])
    est = initial_echoes(y, 0.0, fallback_sigma=2.0, robust=False, min_noise_sigma=0.0)
    # noise-free: the threshold is 0, so ripples of the residual follow the first (largest) echo
    assert est.position[0] == 47
    assert est.amplitude[0] == pytest.approx(200.0 * math.exp(-0.3**2 / 32), rel=1e-9)
    assert est.sigma[0] == pytest.approx(4.0, abs=0.15)
    assert est.background == pytest.approx(10.0)


def test_progressive_extraction_finds_a_shoulder_without_its_own_maximum():
    t = np.arange(120.0)
    # the second echo is a shoulder: the sum has a single local maximum
    y = waveform_model(t, 20.0, [300.0, 120.0], [40.0, 50.0], [4.0, 4.0], [math.sqrt(2)] * 2)
    y = y + np.random.default_rng(2).normal(0, 1.0, t.size)
    local_maxima = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] > y[2:]) & (y[1:-1] > 100)) + 1
    assert local_maxima.size == 1
    est = initial_echoes(y, 1.0, fallback_sigma=4.0)
    assert est.n_echoes >= 2
    assert np.any(np.abs(est.position - 50) <= 3)


def test_missing_inflection_point_at_the_edge_uses_the_other_side():
    t = np.arange(40.0)
    y = waveform_model(t, 5.0, [100.0], [1.0], [3.0], [math.sqrt(2)])  # left side cut off by the record start
    est = initial_echoes(y, 0.0, fallback_sigma=9.0)
    assert est.sigma[0] == pytest.approx(3.0, abs=0.3)


def test_progressive_estimate_matches_the_naive_reference():
    from fwcore.engine.estimate import _progressive_echoes

    t = np.arange(150.0)
    y = waveform_model(t, 12.0, [90.0, 40.0, 25.0], [30.0, 70.0, 110.0], [3.0, 4.0, 2.5], [math.sqrt(2)] * 3)
    y = y + np.random.default_rng(3).normal(0, 0.8, t.size)
    smoothed = gaussian_smooth(y, 0.8)
    threshold = np.full(t.size, 3.0)
    amplitude, position, sigma = np.zeros(12), np.zeros(12), np.zeros(12)
    for floor_ratio, at_least in ((0.0, 3), (0.35, 2)):
        n = _progressive_echoes(smoothed, np.ones(t.size, bool), 12.0, threshold, 12, 3.0, analytic_shape(),
                                amplitude, position, sigma, floor_ratio, 0.0)
        expected = naive.progressive_echoes(smoothed, 12.0, 3.0, 12, 3.0, floor_ratio)
        assert n == len(expected) >= at_least
        np.testing.assert_allclose(np.c_[amplitude[:n], position[:n], sigma[:n]], expected, rtol=1e-9)
    # the floor drops the weak echo at 110 (25 < 0.35 x 90, far from the others) but not the one at 70
    assert not np.any(np.abs(position[:n] - 110) < 5) and np.any(np.abs(position[:n] - 70) < 5)
    # a weak echo 2.4 FWHM after a strong one, in its return (the samples between stay above the threshold)
    y = waveform_model(t, 12.0, [150.0, 25.0], [30.0, 47.0], [3.0, 4.0], [math.sqrt(2)] * 2)
    smoothed = gaussian_smooth(y + np.random.default_rng(4).normal(0, 0.8, t.size), 0.8)
    n = _progressive_echoes(smoothed, np.ones(t.size, bool), 12.0, threshold, 12, 3.0, analytic_shape(), amplitude,
                            position, sigma, 0.35, 0.0)
    expected = naive.progressive_echoes(smoothed, 12.0, 3.0, 12, 3.0, 0.35)
    assert n == len(expected)
    np.testing.assert_allclose(np.c_[amplitude[:n], position[:n], sigma[:n]], expected, rtol=1e-9)
    assert np.any(np.abs(position[:n] - 47) < 2)


def test_the_residual_on_a_peeled_echos_flank_is_not_proposed():
    from fwcore.engine.estimate import _progressive_echoes

    t = np.arange(80.0)

    def peeled(second_amplitude, delay, flank_ratio):
        y = waveform_model(t, 12.0, [100.0, second_amplitude], [30.0, 30.0 + delay], [2.0, 2.0], [math.sqrt(2)] * 2)
        amplitude, position, sigma = np.zeros(12), np.zeros(12), np.zeros(12)
        n = _progressive_echoes(gaussian_smooth(y, 0.5), np.ones(t.size, bool), 12.0, np.full(t.size, 3.0), 12, 2.0,
                                analytic_shape(), amplitude, position, sigma, 0.05, flank_ratio)
        return amplitude[:n], position[:n]

    # two echoes 0.64 FWHM apart read as one broad return: peeled at 31, it leaves 5 counts at 30
    amplitude, position = peeled(50.0, 3.0, 0.0)
    assert amplitude.size == 2 and position[1] == pytest.approx(30.0) and amplitude[1] < 0.2 * amplitude[0]
    amplitude, position = peeled(50.0, 3.0, 0.2)
    assert amplitude.size == 1 and position[0] == pytest.approx(31.0)
    # a weak echo 1.5 FWHM behind a strong one is no flank
    amplitude, position = peeled(12.0, 7.0, 0.2)
    assert amplitude.size == 2 and position[1] == pytest.approx(37.0)


def test_a_return_a_target_widened_starts_as_wide_as_it_is():
    # a target widens both sides: the start takes the whole half-height width, so the rising edge is not
    # left over as an echo of its own
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0)
    t = np.arange(80.0)
    y = tabulated_model(t, 3.0, 150.0, 30.3, 1.5 * shape.s_min, shape)
    y = np.round(y + np.random.default_rng(4).normal(0, 0.5, t.size))
    est = initial_echoes(y, 0.4, shape.s_min, shape=shape)
    assert est.n_echoes == 1
    assert est.sigma[0] == pytest.approx(1.5 * shape.s_min, rel=0.1)


def test_a_neighbour_widens_one_side_and_the_start_takes_the_other():
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0)
    t = np.arange(80.0)
    y = tabulated_model(t, 3.0, [150.0, 90.0], [30.3, 35.8], [shape.s_min, shape.s_min], shape)
    y = np.round(y + np.random.default_rng(5).normal(0, 0.5, t.size))
    est = initial_echoes(y, 0.4, shape.s_min, shape=shape)
    assert est.n_echoes >= 2
    first = int(np.argmax(est.amplitude))
    assert est.sigma[first] < 1.2 * shape.s_min  # its whole half-height width would take in the neighbour
    assert np.sort(est.position[np.argsort(est.amplitude)[-2:]]) == pytest.approx([30.3, 35.8], abs=0.5)
