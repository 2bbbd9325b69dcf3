"""An echo's width measured on the waveform (RIEGL's 'Pulse width'): the half-maximum crossings of the samples
less the background and the other echoes, against hand-computed widths."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import spearmanr

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.model import table_peak_offset, table_value, waveform_model
from fwcore.engine.records import WaveformBatch, fitted_model
from fwcore.engine.waveform_width import waveform_widths
from fwcore.instrument.measure import file_system_pulse
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import input_summary, read_pulses
from fwcore.pulses import pulse_waveforms

SPACING = 1000.0
FWHM_PER_SIGMA = 2 * math.sqrt(2 * math.log(2))
SQ2 = math.sqrt(2)
PULSE = nominal_pulse(3.0 * FWHM_PER_SIGMA * SPACING)


def _widths(waveforms: list[np.ndarray]):
    batch = WaveformBatch.from_waveforms(waveforms, SPACING, list(range(len(waveforms))))
    result = decompose_batch(batch, DecompositionConfig(), PULSE, threads=1)
    return result, waveform_widths(batch.samples, batch.offsets, result)


def _half_max_width(signal: np.ndarray) -> float:
    """By hand: the crossings of half the highest sample, linear between samples."""
    k = int(np.argmax(signal))
    half = signal[k] / 2
    right = k + np.flatnonzero(signal[k:] < half)[0]
    left = np.flatnonzero(signal[:k] < half)[-1]
    x_right = right - 1 + (signal[right - 1] - half) / (signal[right - 1] - signal[right])
    x_left = left + (half - signal[left]) / (signal[left + 1] - signal[left])
    return x_right - x_left


def test_one_echo_reads_its_own_half_maximum_width_off_the_samples():
    t = np.arange(120, dtype=float)
    rng = np.random.default_rng(2)
    waveforms = [waveform_model(t, 20.0, np.array([300.0]), np.array([50.3]), np.array([s]), np.array([SQ2]))
                 + rng.normal(0, 1.0, t.size) for s in (3.0, 3.6, 4.4)]
    result, widths = _widths(waveforms)
    assert (np.diff(result.echo_offsets) == 1).all()
    for i, w in enumerate(waveforms):  # one echo: its samples less the fitted background, measured by hand
        assert math.isclose(widths[i], _half_max_width(w - result.background[i]), rel_tol=1e-9)
    # noise-free widths 7.06, 8.48, 10.36 samples; linear between samples reads a Gaussian's a little wide
    np.testing.assert_allclose(widths, np.array([3.0, 3.6, 4.4]) * FWHM_PER_SIGMA, rtol=0.03)


def test_the_other_echo_is_taken_off_before_measuring():
    """Two echoes 1.27 FWHM apart: on the raw samples the valley between them stays over the first one's half
    maximum (the two would read as one wide echo); each measured alone reads its own width."""
    t = np.arange(140, dtype=float)
    clean = waveform_model(t, 10.0, np.array([400.0, 250.0]), np.array([50.0, 59.0]), np.array([3.0, 3.0]),
                           np.array([SQ2, SQ2]))
    assert (clean[50:59] - 10.0).min() > 200.0
    result, widths = _widths([clean])
    assert np.diff(result.echo_offsets)[0] == 2
    np.testing.assert_allclose(widths, 3.0 * FWHM_PER_SIGMA, rtol=0.03)


def test_an_echo_cut_by_the_record_end_has_no_width():
    t = np.arange(60, dtype=float)
    cut = waveform_model(t, 5.0, np.array([300.0]), np.array([57.5]), np.array([3.0]), np.array([SQ2]))
    _, widths = _widths([cut])
    assert widths.size == 1 and np.isnan(widths[0])


def test_widths_rank_with_the_true_widths_at_a_digitizer_s_noise():
    """Single echoes of widths 1-1.6x the pulse at SNR 30-300: the measured widths rank as the true ones."""
    rng = np.random.default_rng(5)
    t = np.arange(100, dtype=float)
    sigma = rng.uniform(3.0, 4.8, 200)
    amplitude = rng.uniform(90.0, 900.0, 200)
    waveforms = [waveform_model(t, 30.0, np.array([a]), np.array([40.0 + rng.uniform(0, 1)]), np.array([s]),
                                np.array([SQ2])) + rng.normal(0, 3.0, t.size) for a, s in zip(amplitude, sigma)]
    result, widths = _widths(waveforms)
    one = np.diff(result.echo_offsets) == 1
    assert one.mean() > 0.95
    first = result.echo_offsets[:-1][one]
    assert spearmanr(sigma[one], widths[first]).statistic > 0.95


def _widths_every_sample(samples, offsets, result, model, shape=None, pulses=None):
    """The widths as measured before the kernel read only the samples it walks: each echo alone over every sample,
    its peak and crossings found on that array (the slow reference); `shape` a tabulated response's, for the
    first `pulses` waveforms."""
    out = np.full(result.amplitude.size, np.nan)
    for i in np.flatnonzero(result.status[:pulses] == 0):
        lo, hi = offsets[i], offsets[i + 1]
        n = hi - lo
        for e in range(result.echo_offsets[i], result.echo_offsets[i + 1]):
            a, u, s, alpha = result.amplitude[e], result.position[e], result.sigma[e], result.alpha[e]
            if shape is None:
                own = np.array([a * math.exp(-abs(float(k) - u) ** (alpha * alpha) / (2.0 * s * s))
                                for k in range(n)])
                peak = u
            else:
                own = np.array([0.0 + table_value(shape, a, u, s, float(k)) for k in range(n)])
                peak = u + table_peak_offset(shape, s)
            signal = samples[lo:hi] - (model[lo:hi] - own)
            k = min(max(int(round(peak)), 0), n - 1)
            for j in (k - 1, k + 1):
                if 0 <= j < n and signal[j] > signal[k]:
                    k = j
            if signal[k] <= 0.0:
                continue
            half = 0.5 * signal[k]
            ends = []
            for step in (1, -1):
                j = k
                while 0 <= j + step < n and signal[j + step] >= half:
                    j += step
                ends.append(math.nan if not 0 <= j + step < n else
                            j + step * (signal[j] - half) / (signal[j] - signal[j + step]))
            out[e] = ends[0] - ends[1]
    return out


def test_widths_read_only_the_samples_they_walk_to_the_bit():
    """Long records of 4-7 overlapping echoes (generalized Gaussians of alpha 1-2, the noise of a digitizer): the
    kernel evaluates each echo alone where its peak and crossings read it, and gives the widths of the echo alone
    over every sample, to the bit."""
    rng = np.random.default_rng(9)
    t = np.arange(1024, dtype=float)
    waveforms = []
    for _ in range(6):
        k = rng.integers(4, 8)
        waveforms.append(waveform_model(t, 40.0, rng.uniform(15, 200, k), np.sort(rng.uniform(300, 700, k)),
                                        rng.uniform(2.5, 5.0, k), rng.uniform(1.0, 2.0, k))
                         + rng.normal(0, 2.0, t.size))
    batch = WaveformBatch.from_waveforms(waveforms, SPACING, list(range(len(waveforms))))
    result = decompose_batch(batch, DecompositionConfig(), PULSE, threads=1)
    model = fitted_model(result, batch.offsets)
    widths = waveform_widths(batch.samples, batch.offsets, result, model)
    assert result.amplitude.size > 20 and np.isfinite(widths).sum() > 20
    np.testing.assert_array_equal(widths, _widths_every_sample(batch.samples, batch.offsets, result, model))


def test_a_tabulated_echo_s_widths_read_only_the_samples_they_walk_to_the_bit(leica_dir):
    """The system response's echoes on the Leica file: the widths of each echo alone over every sample, to the bit."""
    path = str(leica_dir / "leica_a.las")
    config = DecompositionConfig(model="system", generations=5)
    pulses = read_pulses(path)
    result = decompose_batch(pulse_waveforms(pulses, 0), config, file_system_pulse(path, input_summary(path).records,
                                                                                   config), threads=1)
    (shape,) = result.shapes.values()
    model = fitted_model(result, pulses.sample_offsets)
    widths = waveform_widths(pulses.samples, pulses.sample_offsets, result, model)
    first = int(result.echo_offsets[150])
    expected = _widths_every_sample(pulses.samples, pulses.sample_offsets, result, model, shape, 150)
    assert np.isfinite(widths[:first]).sum() > 100
    np.testing.assert_array_equal(widths[:first], expected[:first])
