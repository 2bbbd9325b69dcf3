"""The noise model of a sample: the kernels against the NumPy references of sigma^2 + g s + (tolerance s)^2."""

import math

import numpy as np
import pytest

from fwcore.engine.noise_model import add_shot_noise, noise_variance
from fwcore.engine.model import analytic_shape
from tests.fwcore import naive


def _echo_waveform(seed: int):
    """A generalized-Gaussian echo over a background of 20 DN, with noise that grows with the signal."""
    rng = np.random.default_rng(seed)
    t = np.arange(80.0)
    x = np.array([20.0, 150.0, 40.3, 4.0, 1.7])
    clean = naive.model_of_individual(x, t)
    raw = clean + rng.normal(0.0, 1.0, t.size) * np.sqrt(1.0 + 0.5 * (clean - 20.0))
    return t, x, clean, raw


def test_noise_variance_matches_the_numpy_reference():
    t, _, clean, _ = _echo_waveform(1)
    valid = np.ones(t.size, bool)
    valid[::7] = False
    out = np.full(t.size, np.nan)
    noise_variance(clean, valid, 20.0, 1.3, 0.05, out)
    expected = naive.noise_variance(clean, valid, 20.0, 1.3, 0.05)
    np.testing.assert_allclose(out[:valid.sum()], expected, rtol=1e-15)
    assert np.isnan(out[valid.sum():]).all()  # only the valid samples are written, packed at the front
    assert expected.max() == pytest.approx(1.3 ** 2 + (0.05 * 150.0) ** 2, rel=1e-3)  # at the echo's peak


@pytest.mark.parametrize("seed", [2, 3])
def test_shot_noise_matches_the_numpy_reference(seed):
    t, x, clean, raw = _echo_waveform(seed)
    signal = clean - 20.0
    variance = naive.noise_variance(clean, np.ones(t.size, bool), 20.0, 1.0, 0.0)
    got = variance.copy()
    g = add_shot_noise(x, 1, t, analytic_shape(), raw, signal, got)
    expected_g, expected = naive.shot_noise(naive.model_of_individual(x, t), raw, signal, variance)
    assert g == pytest.approx(expected_g, rel=1e-12) and 0.2 < g < 1.0  # the 0.5 the noise was drawn with
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_shot_noise_is_zero_where_the_residuals_are_white():
    t, x, clean, _ = _echo_waveform(4)
    raw = clean + np.random.default_rng(4).normal(0.0, 1.0, t.size) * 0.5
    variance = np.ones(t.size)
    g = add_shot_noise(x, 1, t, analytic_shape(), raw, clean - 20.0, variance)
    assert g == 0.0 and (variance == 1.0).all()
    assert math.isclose(naive.shot_noise(clean, raw, clean - 20.0, np.ones(t.size))[0], 0.0)
