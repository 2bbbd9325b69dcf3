"""The joint Cramer-Rao bound of echo times on a simulated flight, against closed forms and hand-computed Fisher
information, and the recall and range RMSE an unbiased estimator at the bound would reach."""

import numpy as np
import pytest

from fwcore.studies.bound import echo_time_bounds_ps, expected_match
from fwcore.studies.evaluate import range_crlb_cm
from fwcore.studies.simulate import SensorConfig


@pytest.mark.parametrize("amplitude, time_ps", [(60.0, 40_000.0), (15.0, 61_300.0)])
def test_a_lone_gaussian_echo_s_bound_is_the_closed_form(amplitude, time_ps):
    """One Gaussian echo (A, sigma) on white noise of variance v sampled every D: its time's Fisher information is
    sum (A (t - u) / sigma^2 g)^2 / v ~ A^2 sqrt(pi) / (2 v D sigma), so sigma_t = sqrt(2 v D sigma / (A^2 sqrt(pi)));
    the time of a symmetric echo does not trade against its amplitude, width or the background, so the joint bound
    is that one. At 1.7 samples a sigma the sum is the integral to 1e-5."""
    sensor = SensorConfig(noise_sigma=1.5, shot_noise=0.0, samples_per_packet=120)
    sigma, v, spacing = 1_700.0, 1.5 ** 2 + 1.0 / 12.0, sensor.sample_spacing_ps
    bound = echo_time_bounds_ps([1], [time_ps], [amplitude], [sigma], [np.sqrt(2.0)], sensor)[0]
    assert spacing == 1000.0
    assert bound == pytest.approx(np.sqrt(2 * v * spacing * sigma / (amplitude ** 2 * np.sqrt(np.pi))), rel=1e-4)


def test_only_the_wanted_pulses_are_bounded():
    sensor = SensorConfig(noise_sigma=1.5, shot_noise=0.0, samples_per_packet=120)
    bounds = echo_time_bounds_ps([1, 2, 2], [40_000.0, 30_000.0, 60_000.0], [20.0, 20.0, 20.0], [1_700.0] * 3,
                                 [np.sqrt(2.0)] * 3, sensor, wanted=np.array([False, True, False]))
    assert np.isnan(bounds[0]) and np.isfinite(bounds[1:]).all()  # a wanted echo's pulse is bounded whole


def test_the_joint_bound_of_a_lone_echo_is_the_single_echo_crlb_with_its_nuisances():
    """A lone Gaussian echo: its time's joint bound is at least the single-echo CRLB (which knows the amplitude and
    width), and close to it (a symmetric echo's time is nearly uncorrelated with its amplitude and width)."""
    sensor = SensorConfig(noise_sigma=1.5, shot_noise=0.0, samples_per_packet=120)
    alpha = np.sqrt(2.0)
    for amplitude in (15.0, 60.0):
        bound = echo_time_bounds_ps([1], [40_000.0], [amplitude], [1_700.0], [alpha], sensor)[0]
        alone = range_crlb_cm(np.array([amplitude]), np.array([1_700.0]), np.array([alpha]), sensor)[0] / (
            0.0299792458 / 2)
        assert alone <= bound < 1.1 * alone


def test_the_joint_bound_grows_as_two_echoes_close_in_and_gives_the_recall_an_ideal_engine_reaches():
    sensor = SensorConfig(noise_sigma=1.5, shot_noise=0.0, samples_per_packet=120)
    alpha = np.sqrt(2.0)
    fwhm = 1_700.0 * 2.3548
    bounds = []
    for gap in (0.8, 1.2, 3.0):  # in FWHM
        b = echo_time_bounds_ps([1, 1], [40_000.0, 40_000.0 + gap * fwhm], [20.0, 20.0], [1_700.0] * 2,
                                [alpha] * 2, sensor)
        assert b[0] == pytest.approx(b[1], rel=1e-3)  # a symmetric pair
        bounds.append(b[0])
    assert bounds[0] > bounds[1] > bounds[2]
    # an estimator at the bound lands within the window erf(window / (sigma sqrt 2)) of the time
    ideal = expected_match(np.array([500.0, 1000.0, np.inf]), 1000.0, 1.0)
    assert ideal.true_echoes == 3
    assert ideal.recall == pytest.approx((0.954499736 + 0.682689492 + 0.0) / 3, rel=1e-6)
    # of those that land: a normal truncated at 2 and at 1 sigma keeps 0.774 and 0.291 of its variance
    assert ideal.range_rmse_cm ** 2 == pytest.approx((0.954499736 * 500.0 ** 2 * 0.77395
                                                      + 0.682689492 * 1000.0 ** 2 * 0.29113) / 1.637189228, rel=1e-3)


def test_the_widths_known_bound_is_the_information_without_the_widths_computed_by_hand():
    """Two Gaussian echoes 1.2 W apart: with their widths given, the bound of each time is the inverse of the Fisher
    information of (A1, t1, A2, t2, background) from the closed-form derivatives, and below the joint bound."""
    sensor = SensorConfig(noise_sigma=1.5, shot_noise=0.0, samples_per_packet=120)
    sigma, amplitude = 1_700.0, np.array([20.0, 12.0])
    times = np.array([40_000.0, 40_000.0 + 1.2 * 2.3548 * sigma])
    known = echo_time_bounds_ps([1, 1], times, amplitude, [sigma] * 2, [np.sqrt(2.0)] * 2, sensor, widths_known=True)
    joint = echo_time_bounds_ps([1, 1], times, amplitude, [sigma] * 2, [np.sqrt(2.0)] * 2, sensor)
    t = np.arange(120) * 1000.0
    columns = []
    for a, u in zip(amplitude, times):
        g = np.exp(-(t - u) ** 2 / (2 * sigma ** 2))
        columns += [g, a * g * (t - u) / sigma ** 2]
    jacobian = np.column_stack(columns + [np.ones(t.size)])
    covariance = np.linalg.inv(jacobian.T @ jacobian / (1.5 ** 2 + 1.0 / 12.0))
    assert known == pytest.approx(np.sqrt(np.diag(covariance)[[1, 3]]), rel=1e-3)
    assert np.all(known < 0.9 * joint)
