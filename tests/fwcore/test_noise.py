"""The noise model: robust white sigma against known truth, the baseline, and the pulse width."""

import math

import numpy as np
import pytest

from fwcore.engine.model import waveform_model
from fwcore.io.neon import read_neon_csv
from fwcore.instrument.width import csv_pulse_fwhm_ps, estimate_pulse_fwhm
from fwcore.engine.preprocess import estimate_noise, initial_echoes

DATA = "examples/data/"


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


def test_pulse_width_of_neon_from_its_returns_alone_is_near_the_outgoing_pulses():
    returns = read_neon_csv(DATA + "neon_harvard/return_waveforms.csv")
    outgoing = csv_pulse_fwhm_ps(read_neon_csv(DATA + "neon_harvard/outgoing_pulses.csv")) / 1000.0
    estimate = estimate_pulse_fwhm(returns.samples, returns.valid)
    assert estimate.n_waveforms >= 50
    # returns are the outgoing pulse through the receiver (impulse response 15.9 ns) and the target
    assert outgoing <= estimate.fwhm_samples <= 1.3 * outgoing


def test_pulse_width_needs_isolated_echoes():
    flat = [np.random.default_rng(i).normal(100, 2, 120) for i in range(10)]
    with pytest.raises(ValueError, match="isolated strong echo"):
        estimate_pulse_fwhm(flat)


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
