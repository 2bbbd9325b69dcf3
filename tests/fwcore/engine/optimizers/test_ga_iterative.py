"""The patent's iterative GA: its peak search and ranges, the echo it adds, its r2 stop."""

from __future__ import annotations

import math

import numpy as np

from fwcore.engine.decompose import decompose_waveform
from fwcore.engine.model import waveform_model
from fwcore.engine.optimizers.ga_iterative import patent_peak_ranges
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
