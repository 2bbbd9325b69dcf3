import math

import numpy as np
import pytest

from fwcore.instrument.shape import analytic_shape
from fwcore.engine.model import waveform_model
from fwcore.engine.optimizers.ga_iterative import patent_peak_ranges
from fwcore.engine.preprocess import estimate_noise, gaussian_smooth, initial_echoes
from tests.fwcore import naive


def test_smoothing_matches_the_numpy_reference():
    y = np.random.default_rng(0).normal(100, 5, 200)
    np.testing.assert_allclose(gaussian_smooth(y, 2.5), naive.gaussian_smooth(y, 2.5), rtol=1e-12)


def test_smoothing_ignores_invalid_samples_in_a_gap():
    y = np.full(40, 50.0)
    valid = np.ones(40, bool)
    y[15:20], valid[15:20] = 0.0, False  # a zero gap must not pull neighbours down
    np.testing.assert_allclose(gaussian_smooth(y, 2.0, valid)[valid], 50.0)


def test_the_methods_noise_is_the_rms_of_raw_minus_smoothed():
    raw = np.array([1.0, 2.0, 4.0, 3.0, 2.0, 2.5])
    smoothed = gaussian_smooth(raw, 1.0)
    expected = math.sqrt(np.mean((raw - smoothed) ** 2))
    assert estimate_noise(raw, 1.0, robust=False) == pytest.approx(expected)


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


def test_patent_peaks_and_search_ranges():
    t = np.arange(100.0)
    y = waveform_model(t, 10.0, [100.0, 60.0], [30.0, 60.0], [3.0, 3.0], [math.sqrt(2)] * 2)
    r = patent_peak_ranges(y, 0.0)
    assert r.peak.tolist() == [30, 60]
    np.testing.assert_allclose(r.position_range, [[25, 35], [55, 65]])
    np.testing.assert_allclose(r.amplitude_range[:, 1], [100.0, 60.0], atol=0.01)
    # two inflection points at +-3: upper sigma = 3 * (p2 - p1) / 2 = 9
    np.testing.assert_allclose(r.sigma_range[:, 1], [9.0, 9.0], atol=0.5)


def test_progressive_estimate_matches_the_naive_reference():
    from fwcore.engine.preprocess import _progressive_echoes

    t = np.arange(150.0)
    y = waveform_model(t, 12.0, [90.0, 40.0, 25.0], [30.0, 70.0, 110.0], [3.0, 4.0, 2.5], [math.sqrt(2)] * 3)
    y = y + np.random.default_rng(3).normal(0, 0.8, t.size)
    smoothed = gaussian_smooth(y, 0.8)
    threshold = np.full(t.size, 3.0)
    amplitude, position, sigma = np.zeros(12), np.zeros(12), np.zeros(12)
    n = _progressive_echoes(smoothed, np.ones(t.size, bool), 12.0, threshold, 12, 3.0, analytic_shape(), amplitude,
                            position, sigma)
    expected = naive.progressive_echoes(smoothed, 12.0, 3.0, 12, 3.0)
    assert n == len(expected) >= 3
    np.testing.assert_allclose(np.c_[amplitude[:n], position[:n], sigma[:n]], expected, rtol=1e-9)


def test_filter_matches_the_naive_reference():
    from fwcore.engine.filter import REJECT_REASONS, filter_echoes

    rng = np.random.default_rng(4)
    for _ in range(50):
        n = int(rng.integers(1, 8))
        position = np.sort(rng.uniform(-5, 105, n))
        amplitude, width = rng.uniform(0, 100, n), rng.uniform(1, 25, n)
        args = (0.0, 100.0, 8.0, 2.0, 4.0, 0.05, 1.0, 0.5, 3.0, float(rng.choice([1.0, 0.35, 0.6])))
        codes = filter_echoes(amplitude, position, width, *args[:3], noise_sigma=args[3], min_snr=args[4],
                              min_amplitude_ratio=args[5], min_separation_factor=args[6], min_width_factor=args[7],
                              max_width_factor=args[8], first_echo_ratio=args[9])
        assert [REJECT_REASONS[c] for c in codes] == naive.mark_spurious(amplitude, position, width, *args)


def test_of_a_close_pair_the_first_stays_when_it_is_strong_enough():
    from fwcore.engine.filter import REJECT_REASONS, filter_echoes

    # a shoulder at 40% of the stronger echo 5 samples later (pulse FWHM 8): one unresolved return
    amplitude, position, width = np.array([40.0, 100.0]), np.array([50.0, 55.0]), np.array([8.0, 8.0])

    def reasons(ratio):
        codes = filter_echoes(amplitude, position, width, 0.0, 100.0, 8.0, first_echo_ratio=ratio)
        return [REJECT_REASONS[c] for c in codes]

    assert reasons(1.0) == ["too_close", ""]  # the method's rule: the weaker goes
    assert reasons(0.35) == ["", "too_close"]  # the first surface
    assert reasons(0.5) == ["too_close", ""]  # below half of the later: a bump, not a surface
