"""Denoising, noise and baseline: the filter against the NumPy reference to the bit, the noise sigma against known
white noise (quantised or not, with held-out samples), the baseline against the repeated-median reference."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from fwcore.engine.estimate import initial_echoes
from fwcore.engine.model import waveform_model
from fwcore.engine.smoothing import estimate_noise, gaussian_smooth
from tests.fwcore import naive


def test_smoothing_matches_the_numpy_reference():
    y = np.random.default_rng(0).normal(100, 5, 200)
    np.testing.assert_allclose(gaussian_smooth(y, 2.5), naive.gaussian_smooth(y, 2.5), rtol=1e-12)


def test_smoothing_ignores_invalid_samples_in_a_gap():
    y = np.full(40, 50.0)
    valid = np.ones(40, bool)
    y[15:20], valid[15:20] = 0.0, False  # a zero gap must not pull neighbours down
    np.testing.assert_allclose(gaussian_smooth(y, 2.0, valid)[valid], 50.0)


def test_the_filter_sums_each_sample_in_order_to_the_bit():
    from fwcore.engine.smoothing import gaussian_weights, smoothed_sample, smoothed_value, weighted_sums

    rng = np.random.default_rng(8)
    for (n, sigma), gaps in itertools.product(((60, 1.9), (63, 1.9), (7, 3.0), (17, 2.0), (300, 0.8)), (True, False)):
        y = rng.normal(100, 5, n)
        valid = rng.random(n) > 0.2 if gaps else np.ones(n, bool)  # no gap: whole windows, four at a time
        weights = gaussian_weights(sigma)
        half = weights.size // 2
        sums, norms = np.empty(n), np.empty(n)
        weighted_sums(y, valid, weights, sums, norms)
        for i in range(n):  # one sample's sum, as a loop per sample adds it
            total = norm = 0.0
            for j in range(max(0, i - half), min(n, i + half + 1)):
                if valid[j]:
                    total += weights[j - i + half] * y[j]
                    norm += weights[j - i + half]
            assert sums[i] == total and norms[i] == norm
            assert smoothed_sample(y, valid, weights, i) == smoothed_value(total, norm, y[i])


def test_the_methods_noise_is_the_rms_of_raw_minus_smoothed():
    raw = np.array([1.0, 2.0, 4.0, 3.0, 2.0, 2.5])
    smoothed = gaussian_smooth(raw, 1.0)
    expected = math.sqrt(np.mean((raw - smoothed) ** 2))
    assert estimate_noise(raw, 1.0, robust=False) == pytest.approx(expected)


def _waveform(sigma, bits, with_signal, seed, n=400):
    t = np.arange(n, dtype=float)
    clean = np.full(n, 40.0)
    if with_signal:
        clean = waveform_model(t, 40.0, [180.0, 90.0, 60.0], [80.0, 150.0, 300.0], [3.0, 4.0, 3.0], [math.sqrt(2)] * 3)
    y = clean + np.random.default_rng(seed).normal(0.0, sigma, n)
    if bits:
        y = np.clip(np.round(y), 0, 2 ** bits - 1)
    return y


@pytest.mark.parametrize("bits", [8, 16, None])
@pytest.mark.parametrize("with_signal", [False, True])
def test_robust_noise_recovers_white_noise_sigma(bits, with_signal):
    # quantisation adds uniform noise of 1/sqrt(12) DN: the estimate measures what the samples hold
    sigma = 2.0
    expected = math.sqrt(sigma ** 2 + (1 / 12 if bits else 0.0))
    estimates = [estimate_noise(_waveform(sigma, bits, with_signal, seed), smoothing_sigma=0.75)
                 for seed in range(20)]
    assert np.mean(estimates) == pytest.approx(expected, rel=0.05)


def test_the_methods_formula_keeps_only_part_of_white_noise():
    # sqrt(mean((raw - smoothed)^2)) at light smoothing: about sqrt(1 - 2 w0 + sum w^2) of sigma
    sigma, s = 2.0, 0.75
    half = int(math.ceil(4 * s))
    w = np.exp(-0.5 * (np.arange(-half, half + 1) / s) ** 2)
    w /= w.sum()
    attenuation = math.sqrt(1 - 2 * w[half] + np.sum(w ** 2))
    formula = np.mean([estimate_noise(_waveform(sigma, None, False, seed), 0.75, robust=False) for seed in range(20)])
    assert formula == pytest.approx(sigma * attenuation, rel=0.05)
    assert formula < 0.7 * sigma


def test_quantised_flat_waveform_has_the_quantisation_floor():
    y = np.full(200, 13.0)  # an 8-bit digitizer whose analogue noise is below one count
    est = initial_echoes(y, 0.6, 2.0)
    assert est.noise_sigma == pytest.approx(1 / math.sqrt(12))
    assert est.n_echoes == 0


def test_baseline_is_the_background_not_the_undershoot_after_a_return():
    # a Leica-like return: strong echo, then an undershoot of 3 DN below a baseline of 13
    t = np.arange(256, dtype=float)
    y = waveform_model(t, 13.0, [90.0], [12.0], [2.3], [math.sqrt(2)])
    y[20:30] -= 3.0
    y = np.round(y + np.random.default_rng(1).normal(0, 0.5, 256))
    est = initial_echoes(y, 0.6, 2.3)
    assert est.background == pytest.approx(13.0, abs=0.3)
    assert est.n_echoes == 1  # the method's minimum (10) would turn the whole baseline into echoes
    method = initial_echoes(y, 0.6, 2.3, robust=False, min_noise_sigma=0.0)
    assert method.background < 11.0


def _every(n: int, k: int) -> np.ndarray:
    """A validity mask with every k-th sample held out (from sample 1), as
    fwcore.instrument.measure.held_out_errors makes."""
    valid = np.ones(n, bool)
    valid[1::k] = False
    return valid


def test_noise_of_a_quantised_waveform_survives_held_out_samples(leica_waveforms):
    # Leica's 8-bit baseline: next to a held-out sample the filter leans on one neighbour and leaves residuals
    # of a fraction of a count; read only where both neighbours are valid, the noise is the full waveform's
    ratios = []
    for y in leica_waveforms[:60]:
        y = np.asarray(y, dtype=float)
        plain = estimate_noise(y, 0.58)
        ratios.append(estimate_noise(y, 0.58, valid=_every(y.size, 5)) / plain)
    assert 0.9 < np.median(ratios) < 1.1
    assert min(ratios) > 0.5  # reading every sample, as before, fails both


def test_an_echo_is_measured_across_held_out_samples():
    # one Gaussian echo, sigma 3 samples, every 3rd sample held out, at six sub-sample phases: its width comes
    # from the denoised signal across the gaps, not from the fallback width (1 sample, as before)
    t = np.arange(120.0)
    widths, single = [], 0
    for centre in (60.0, 60.25, 60.5, 60.75, 61.0, 61.5):
        y = 10.0 + 100.0 * np.exp(-0.5 * ((t - centre) / 3.0) ** 2)
        est = initial_echoes(y, 0.6, fallback_sigma=1.0, valid=_every(y.size, 3), min_noise_sigma=2.0)
        widths.append(est.sigma[np.argmax(est.amplitude)])
        single += est.n_echoes == 1
    # a peak on a valid sample just before a held-out one (centre 60.0) leans the filter and reads 2 samples
    assert np.mean(widths) == pytest.approx(3.0, rel=0.1) and min(widths) > 1.9
    assert single >= 5


def test_selection_gives_the_median_of_the_smallest_k_to_the_bit():
    """The baseline's repeated medians: of the samples up to a level, which are the k smallest."""
    from fwcore.engine.smoothing import _median_of_smallest

    rng = np.random.default_rng(5)
    for m in (1, 2, 3, 4, 7, 60, 61, 200):
        for values in (rng.normal(0, 1, m), np.round(rng.normal(10, 3, m)), np.full(m, 4.0)):
            scratch = values.copy()
            for k in range(1, m + 1):  # one scratch through every selection, as the baseline uses it
                assert _median_of_smallest(scratch, m, k) == np.median(np.sort(values)[:k])
    # a long quantised record (a few distinct counts): each count's run is gathered in one pass
    values = np.round(rng.normal(40, 0.6, 20_000))
    scratch = values.copy()
    for k in (1, 2, 9_999, 10_000, 20_000):
        assert _median_of_smallest(scratch, values.size, k) == np.median(np.sort(values)[:k])


def test_selection_gives_the_median_and_its_absolute_deviation_to_the_bit():
    from fwcore.engine.smoothing import _median_in_place

    rng = np.random.default_rng(7)
    for m in (1, 2, 3, 4, 5, 8, 59, 60, 64, 65, 200):
        for values in (rng.normal(0, 1, m), np.round(rng.normal(10, 3, m)), np.full(m, 4.0),
                       np.sort(rng.normal(0, 1, m)), np.sort(rng.normal(0, 1, m))[::-1],
                       np.concatenate([rng.normal(0, 1, m - m // 4), rng.normal(40, 1, m // 4)])):
            scratch = np.concatenate([values, [np.inf]])  # a longer buffer: its first m
            centre = _median_in_place(scratch, m)
            assert centre == np.median(values)
            assert np.array_equal(np.sort(scratch[:m]), np.sort(values)) and scratch[m] == np.inf
            distances = np.abs(values - centre)
            assert _median_in_place(distances.copy(), m) == np.median(distances)


def test_baseline_matches_the_repeated_median_reference():
    from fwcore.engine.smoothing import _baseline

    rng = np.random.default_rng(6)
    for _ in range(50):
        y = np.round(waveform_model(np.arange(64.0), rng.uniform(5, 20), [rng.uniform(20, 300)], [rng.uniform(10, 50)],
                                    [rng.uniform(1.5, 4)], [math.sqrt(2)]) + rng.normal(0, 1.5, 64))
        valid = rng.random(64) > 0.1
        noise = 1.5
        values = y[valid]
        level = np.median(values)  # the median, repeatedly leaving out what lies 3 sigma above it
        for _ in range(8):
            new = np.median(values[values <= level + 3 * noise])
            if new == level:
                break
            level = new
        expected = np.mean(values[np.abs(values - level) <= 3 * noise])
        assert _baseline(y, valid, noise) == expected
