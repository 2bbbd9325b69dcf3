from __future__ import annotations

import math

import numpy as np
import pytest

from fwcore.engine.model import (echo_energy, equivalent_gaussian_sigma, fwhm, generalized_gaussian, half_width,
                                 sigma_from_equivalent, sigma_to_time_unit, table_reach, table_value, waveform_model)
from fwcore.instrument.shape import echo_shape


def test_alpha_sqrt2_is_an_ordinary_gaussian():
    t = np.linspace(-20, 20, 401)
    expected = 3.0 * np.exp(-(t - 1.5) ** 2 / (2 * 4.0 ** 2))
    np.testing.assert_allclose(generalized_gaussian(t, 3.0, 1.5, 4.0, math.sqrt(2)), expected, rtol=1e-12)


@pytest.mark.parametrize("alpha", [1.0, 1.2, math.sqrt(2), 1.8, 2.2])
def test_half_width_is_where_the_echo_halves(alpha):
    sigma = 3.7
    h = half_width(sigma, alpha)
    assert generalized_gaussian(h, 1.0, 0.0, sigma, alpha) == pytest.approx(0.5, rel=1e-12)
    assert fwhm(sigma, alpha) == pytest.approx(2 * h)


@pytest.mark.parametrize("alpha", [1.2, math.sqrt(2), 2.2])
def test_energy_is_the_area_under_the_echo(alpha):
    t = np.linspace(-400, 400, 800001)
    y = generalized_gaussian(t, 2.5, 0.0, 3.0, alpha)
    numeric = np.sum(y) * (t[1] - t[0])
    assert echo_energy(2.5, 3.0, alpha) == pytest.approx(numeric, rel=1e-6)
    if alpha == math.sqrt(2):
        assert echo_energy(2.5, 3.0, alpha) == pytest.approx(2.5 * 3.0 * math.sqrt(2 * math.pi))


@pytest.mark.parametrize("alpha", [1.1, 1.6, 2.4])
def test_equivalent_sigma_round_trips(alpha):
    s = equivalent_gaussian_sigma(5.0, alpha)
    assert sigma_from_equivalent(s, alpha) == pytest.approx(5.0)
    assert fwhm(5.0, alpha) == pytest.approx(2.0 * math.sqrt(2 * math.log(2)) * s)


def test_sigma_in_picoseconds_gives_the_same_echo():
    alpha, sigma_samples, spacing = 1.7, 2.3, 2000.0
    t_samples = np.linspace(-10, 10, 41)
    sigma_ps = sigma_to_time_unit(sigma_samples, alpha, spacing)
    np.testing.assert_allclose(generalized_gaussian(t_samples * spacing, 1.0, 0.0, sigma_ps, alpha),
                               generalized_gaussian(t_samples, 1.0, 0.0, sigma_samples, alpha), rtol=1e-12)


def test_waveform_model_sums_echoes():
    t = np.arange(50.0)
    y = waveform_model(t, 10.0, [1.0, 2.0], [10.0, 30.0], [2.0, 3.0], [1.4, 1.6])
    expected = 10.0 + generalized_gaussian(t, 1.0, 10.0, 2.0, 1.4) + generalized_gaussian(t, 2.0, 30.0, 3.0, 1.6)
    np.testing.assert_allclose(y, expected)


@pytest.mark.parametrize("factor", [1.01, 1.37, 2.2, 3.9])  # between rows: both rows weigh
def test_a_tabulated_echo_is_zero_outside_its_reach_and_not_just_inside(leica_response, factor):
    shape = echo_shape(leica_response, 2000.0, 4.0)
    s = shape.s_min * factor
    before, after = table_reach(shape, s)
    t = np.arange(-before - 3.0, after + 3.0, 1.0 / 128.0)
    values = np.array([table_value(shape, 1.0, 0.0, s, x) for x in t])
    assert not values[(t < -before) | (t > after)].any()
    inside = (t > -before + 2 * shape.step) & (t < after - 2 * shape.step)
    assert values[inside][:8].any() and values[inside][-8:].any()
