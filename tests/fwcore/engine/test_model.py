from __future__ import annotations

import math

import numpy as np
import pytest

from fwcore.engine.model import (SQRT_2LN2, analytic_shape, batch_model, echo_energy, echo_span, echo_value,
                                 equivalent_gaussian_sigma, fwhm, generalized_gaussian, half_width, individual_model,
                                 sigma_from_equivalent, sigma_to_time_unit, table_reach, table_value,
                                 underflow_reach, waveform_model)
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


# (A, u, s, alpha): sharp and flat, narrow and wide, inside and at the record's ends (alpha 1: no sample underflows)
ECHOES = np.array([[120.0, 40.3, 2.1, 1.0], [35.0, 300.7, 3.4, 1.3], [8.0, 310.2, 1.5, 1.9], [60.0, 700.0, 6.0, 2.6],
                   [15.0, 1020.5, 2.5, 1.6], [0.0, 500.0, 3.0, 1.4]])


def test_individual_model_leaves_out_only_what_underflows():
    """Each echo evaluated within its underflow reach: the model of every sample, summed in the same order, to the
    bit; and the reach is where the echo's term is exactly 0, far inside the record for all but alpha 1."""
    times = np.flatnonzero(np.random.default_rng(3).random(1024) < 0.6).astype(np.float64)  # a signal window's gaps
    x = np.concatenate([[11.5], ECHOES.ravel()])
    got = np.empty(times.size)
    individual_model(x, len(ECHOES), times, analytic_shape(), got)
    expected = np.full(times.size, 11.5)
    for a, u, s, alpha in ECHOES:
        if a > 0.0:
            expected += np.array([echo_value(a, u, s, alpha, t) for t in times])
    np.testing.assert_array_equal(got, expected)
    reach = [underflow_reach(s * SQRT_2LN2, alpha * alpha) for _, _, s, alpha in ECHOES]
    assert reach[0] > 1024 and max(reach[2:5]) < 60
    for (a, u, s, alpha), r in zip(ECHOES[:5], reach):
        past = np.array([u - r - 0.01, u + r + 0.01])
        assert not any(echo_value(a, u, s, alpha, t) for t in past)
        assert echo_value(a, u, s, alpha, u + 0.5 * r) > 0.0 or alpha > 2.0


def test_individual_model_of_a_long_record_is_libm_s_to_a_few_ulp_and_the_centre_exact():
    """With a tail floor (GEDI, LVIS) the echoes take the vectorizable exp and log: each sample within a few ulp
    of echo_value's sum, the centre (t == u) exactly the amplitude, the reach the same."""
    times = np.flatnonzero(np.random.default_rng(3).random(1024) < 0.6).astype(np.float64)
    x = np.concatenate([[11.5], ECHOES.ravel()])
    exact, got = np.empty(times.size), np.empty(times.size)
    individual_model(x, len(ECHOES), times, analytic_shape(), exact)
    individual_model(x, len(ECHOES), times, analytic_shape()._replace(tail_floor=0.5), got)
    np.testing.assert_allclose(got, exact, rtol=1e-13, atol=0.0)
    assert not np.array_equal(got, exact)  # another exp and log: not libm's bits
    one = np.array([0.0, 5.0, 200.0, 2.0, 1.4])  # b, A, u, s, alpha
    centre = np.array([199.0, 200.0, 201.0])
    individual_model(one, 1, centre, analytic_shape()._replace(tail_floor=0.5), got[:3])
    assert got[1] == 5.0 and got[0] == got[2] == pytest.approx(echo_value(5.0, 200.0, 2.0, 1.4, 199.0), rel=1e-15)


def test_batch_model_is_every_sample_s_sum_to_the_bit(leica_response):
    """batch_model evaluates each echo over its span (echo_span) alone: the sum over every sample, to the bit,
    for Chauve's generalized Gaussians and for the tabulated response."""
    n = 1024
    offsets = np.array([0, n, 2 * n])
    a, u, s, alpha = (np.ascontiguousarray(np.tile(ECHOES[:, k], 2)) for k in range(4))
    sigma = np.sqrt((s * SQRT_2LN2) ** (alpha * alpha) / (2.0 * math.log(2.0)))  # Chauve's sigma of width s
    echo_offsets = np.array([0, len(ECHOES), 2 * len(ECHOES)])
    background = np.array([11.5, -2.0])
    got = np.zeros(2 * n)
    batch_model(np.array([0, 1]), offsets, echo_offsets, background, a, u, sigma, alpha, analytic_shape(), got)
    expected = np.repeat(background, n)
    t = np.arange(n, dtype=float)
    for e in range(2 * len(ECHOES)):
        w = e // len(ECHOES)
        term = np.array([a[e] * math.exp(-abs(x - u[e]) ** (alpha[e] * alpha[e]) / (2.0 * sigma[e] * sigma[e]))
                         for x in t])
        expected[w * n:(w + 1) * n] += term
        lo, hi = echo_span(analytic_shape(), u[e], sigma[e], alpha[e], n)
        assert not term[:lo].any() and not term[hi:].any()
    np.testing.assert_array_equal(got, expected)

    shape = echo_shape(leica_response, 2000.0, 4.0)
    widths = shape.s_min * np.tile([1.0, 1.37, 2.2, 3.9, 1.1, 1.5], 2)
    got = np.zeros(2 * n)
    batch_model(np.array([0, 1]), offsets, echo_offsets, background, a, u, widths, alpha, shape, got)
    expected = np.repeat(background, n)
    for e in range(2 * len(ECHOES)):
        w = e // len(ECHOES)
        expected[w * n:(w + 1) * n] += np.array([0.0 + table_value(shape, a[e], u[e], widths[e], x) for x in t])
        lo, hi = echo_span(shape, u[e], widths[e], alpha[e], n)
        assert hi - lo < 200
    np.testing.assert_array_equal(got, expected)
