"""The patent's iterative GA: its peak search and ranges, the echo it adds, its r2 stop; against the naive references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fwcore.engine.decompose import decompose_waveform
from fwcore.engine.model import waveform_model
from fwcore.engine.estimate import MIN_SIGMA
from fwcore.engine.optimizers.ga_iterative import ga_iterative, patent_peak_ranges, patent_peaks
from fwcore.engine.optimizers.local import fit_levenberg_marquardt
from tests.fwcore import naive
from tests.fwcore.engine.optimizers.test_local import NOISY_T, assert_same_optimum
from tests.fwcore.engine.test_decompose import CONFIG, PULSE, PULSE_SIGMA, SPACING, SQ2, synthetic


def test_patent_peaks_and_search_ranges():
    t = np.arange(100.0)
    y = waveform_model(t, 10.0, [100.0, 60.0], [30.0, 60.0], [3.0, 3.0], [math.sqrt(2)] * 2)
    r = patent_peak_ranges(y, 0.0)
    assert r.peak.tolist() == [30, 60]
    np.testing.assert_allclose(r.position_range, [[25, 35], [55, 65]])
    np.testing.assert_allclose(r.amplitude_range[:, 1], [100.0, 60.0], atol=0.01)
    # two inflection points at +-3: upper sigma = 3 * (p2 - p1) / 2 = 9
    np.testing.assert_allclose(r.sigma_range[:, 1], [9.0, 9.0], atol=0.5)


def test_the_patent_method_adds_the_echo_its_peak_search_missed():
    # a shoulder 2.2 sigma after a strong echo is no local maximum within +-5 bins: the peak
    # search finds one echo, R^2 stays below the threshold, and added echoes take the shoulder
    position = [60.0, 60.0 + 2.2 * PULSE_SIGMA]
    y = synthetic([150.0, 90.0], position, [PULSE_SIGMA] * 2, [SQ2] * 2, noise=1.0, seed=11)
    config = CONFIG.replace(optimizer="ga-iterative", ga_iterative_r2=0.999, noise_threshold=6.0,
                            noise_estimator="residual", min_noise_sigma=1.0)  # the patent's own estimate
    single = decompose_waveform(y, SPACING, seed=3, config=config.replace(ga_iterative_r2=0.5), pulse=PULSE)
    r = decompose_waveform(y, SPACING, seed=3, config=config, pulse=PULSE)
    assert single.n_echoes_initial == r.n_echoes_initial == 1
    assert single.amplitude.size == 1 and r.amplitude.size > 1
    assert np.abs(r.position - position[1]).min() < 1.0
    assert r.r2 > single.r2
    np.testing.assert_array_equal(r.alpha, SQ2)


def test_the_patent_method_stops_at_its_r2_threshold():
    y = synthetic([150.0], [60.0], [PULSE_SIGMA], [SQ2], noise=1.0, seed=12)
    r = decompose_waveform(y, SPACING, seed=3, config=CONFIG.replace(optimizer="ga-iterative"), pulse=PULSE)
    assert r.amplitude.size == 1 and r.r2 >= CONFIG.ga_iterative_r2


# ---------------------------------------------------------------- against the naive references (tests/fwcore/naive)
# The GA is stochastic, so what is compared is what is not: its peak search, and where its result leads. A
# stochastic fit on a 16-bit grid is no optimum; the engine's LM from it must reach the optimum SciPy reaches
# from the truth.

GAUSSIAN_TRUTH = {  # b, (A, u, sigma) per Gaussian echo
    1: [8.0, 120.0, 50.0, 3.0],
    2: [8.0, 120.0, 40.0, 3.0, 70.0, 60.0, 4.0],
    3: [8.0, 120.0, 30.0, 2.5, 80.0, 50.0, 3.5, 40.0, 80.0, 3.0],
}
VALID = np.ones(NOISY_T.size, bool)
LAST = float(NOISY_T.size - 1)


def gaussian_case(truth, noise: float, smoothing: float, seed: int):
    """(the truth in the engine's layout, the noisy waveform, its smoothing) on NOISY_T."""
    x = naive.gaussian_individual(np.array(truth))
    y = naive.model_of_individual(x, NOISY_T) + np.random.default_rng(seed).normal(0, noise, NOISY_T.size)
    return x, y, naive.gaussian_smooth(y, smoothing)


def gaussian_bounds(n: int):
    lower = np.r_[0.0, np.tile([0.0, 0.0, 0.5, SQ2], n)]
    return lower, np.r_[30.0, np.tile([300.0, LAST, 10.0, SQ2], n)]


def by_position(x):
    """x with its echoes in order of position (a refit may swap two)."""
    echoes = x[1:].reshape(-1, 4)
    return np.r_[x[0], echoes[np.argsort(echoes[:, 1])].ravel()]


@pytest.mark.parametrize("n", [1, 2, 3])
def test_patent_peaks_match_the_naive_peak_search(n):
    _, _, smoothed = gaussian_case(GAUSSIAN_TRUTH[n], 2.0, 1.5, n)
    ranges = np.zeros((8, 7))
    count = patent_peaks(smoothed, VALID, 8.0, 12.0, 8, 0.0, LAST, ranges)
    expected = naive.patent_peaks(smoothed, 8.0, 12.0, 0.0, LAST)
    assert count == len(expected) == n
    for (peak, a_hi, u_lo, u_hi, s_hi), found in zip(expected, ranges):
        np.testing.assert_allclose(found[[6, 1, 2, 3, 5]], [peak, a_hi, u_lo, u_hi, s_hi], rtol=1e-12)
        assert found[0] == 0.0 and found[4] == MIN_SIGMA


@pytest.mark.parametrize("n", [1, 2, 3])
def test_the_ga_result_refined_reaches_the_naive_optimum(n):
    truth, y, smoothed = gaussian_case(GAUSSIAN_TRUTH[n], 2.0, 1.5, n)
    found, n_echoes, n_peaks, _ = ga_iterative(VALID, smoothed, 8.0, 2.0, 6.0, 8, 0.0, LAST, NOISY_T, smoothed, y,
                                               0.9, 60, 1000, np.uint64(7))
    assert n_echoes == n_peaks == n
    lower, upper = gaussian_bounds(n)
    # the GA's own fit (of the smoothed samples) is no better than their optimum, and within 2x of it
    _, smoothed_cost = naive.least_squares_fit(truth, NOISY_T, smoothed, lower, upper)
    ga_cost = np.sum((naive.model_of_individual(found, NOISY_T) - smoothed) ** 2)
    assert smoothed_cost * (1 - 1e-12) <= ga_cost <= 2.0 * smoothed_cost
    reference, reference_cost = naive.least_squares_fit(truth, NOISY_T, y, lower, upper)
    x, cost, _ = fit_levenberg_marquardt(found, n, NOISY_T, y, lower, upper)
    assert_same_optimum(by_position(x), cost, by_position(reference), reference_cost, lower, upper)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_echo_the_ga_adds_is_the_one_the_naive_search_missed(seed):
    # a shoulder 2.2 sigma after a strong echo: the patent's peak search (naive and ours) finds one echo; the
    # added echo lies within 10 bins of the largest residual of the naive one-echo optimum, and the pair refined
    # by LM is SciPy's two-echo optimum
    truth, y, smoothed = gaussian_case([8.0, 150.0, 50.0, 3.0, 90.0, 56.6, 3.0], 1.0, 1.0, 11)
    ((peak, height, _, _, s_hi),) = naive.patent_peaks(smoothed, 8.0, 6.0, 0.0, LAST)
    lower, upper = gaussian_bounds(1)
    one, _ = naive.least_squares_fit([8.0, height, peak, s_hi / 3, SQ2], NOISY_T, smoothed, lower, upper)
    centre = NOISY_T[np.argmax(smoothed - naive.model_of_individual(one, NOISY_T))]
    found, n_echoes, n_peaks, _ = ga_iterative(VALID, smoothed, 8.0, 1.0, 6.0, 2, 0.0, LAST, NOISY_T, smoothed, y,
                                               0.999, 60, 1000, np.uint64(seed))
    assert (n_echoes, n_peaks) == (2, 1)
    assert abs(found[6] - centre) <= 10.0
    lower, upper = gaussian_bounds(2)
    reference, reference_cost = naive.least_squares_fit(truth, NOISY_T, y, lower, upper)
    x, cost, _ = fit_levenberg_marquardt(found, 2, NOISY_T, y, lower, upper)
    assert_same_optimum(by_position(x), cost, by_position(reference), reference_cost, lower, upper)
