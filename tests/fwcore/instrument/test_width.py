"""The pulse's width where nothing records it: single pulses, isolated echoes, a CSV's outgoing pulses, a file."""

import numpy as np
import pytest

from fwcore.instrument.width import (csv_pulse_fwhm_ps, estimate_pulse_fwhm, median_pulse_fwhm, recorded_pulse_fwhm_ps,
                                     single_echo_fwhm)
from fwcore.io import PointRange, read_pulses
from fwcore.io.neon import read_neon_csv

T = np.arange(60.0)
DATA = "examples/data/"


def gaussian(sigma: float, centre: float = 30.3) -> np.ndarray:
    return 10.0 + 100.0 * np.exp(-0.5 * ((T - centre) / sigma) ** 2)


def test_median_pulse_fwhm_of_single_pulses():
    # FWHM 2.3548 sigma: 4.71 and 7.06 samples, sampled (the half-height crossings interpolate linearly)
    assert median_pulse_fwhm([gaussian(2.0), gaussian(3.0)]) == pytest.approx(5.9390, abs=1e-4)
    with pytest.raises(ValueError, match="no usable waveform"):
        median_pulse_fwhm([np.full(20, 5.0)])


def test_single_echo_fwhm_takes_one_isolated_echo_and_nothing_else():
    valid = np.ones(T.size, dtype=bool)
    assert single_echo_fwhm(gaussian(3.0), valid) == pytest.approx(6.812, abs=1e-3)  # 7.06, the smoothing removed
    two = gaussian(3.0) + 60.0 * np.exp(-0.5 * ((T - 45.0) / 3.0) ** 2)
    assert single_echo_fwhm(two, valid) is None
    with pytest.raises(ValueError, match="isolated strong echo"):
        estimate_pulse_fwhm([two] * 6)
    assert estimate_pulse_fwhm([gaussian(3.0)] * 6).fwhm_samples == pytest.approx(6.812, abs=1e-3)


def test_csv_and_file_widths(neon_dir, leica_dir):
    assert csv_pulse_fwhm_ps(read_neon_csv(neon_dir / "outgoing_pulses.csv")) == pytest.approx(15155.56, abs=0.01)
    head = read_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 1125))
    assert recorded_pulse_fwhm_ps(head) == (10980.0, "single returns")  # Leica records no outgoing pulse


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
