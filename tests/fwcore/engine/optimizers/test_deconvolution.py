"""The deconvolution methods (Gold, Richardson-Lucy): the kernels against NumPy references, overlapping echoes
recovered, noise alone gives none."""

from __future__ import annotations

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_waveform
from fwcore.engine.model import analytic_shape, tabulated_model
from fwcore.engine.optimizers.deconvolution import gold, response_kernel, richardson_lucy
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.response import named_response
from fwcore.instrument.shape import echo_shape
from tests.fwcore import naive


@pytest.mark.parametrize("method", ["gold", "richardson-lucy"])
def test_deconvolution_finds_two_overlapping_echoes(method):
    leica = named_response("leica")
    shape = echo_shape(leica, 2000.0)
    t = np.arange(120.0)
    y = tabulated_model(t, 12.0, [150.0, 90.0], [40.0, 46.5], [shape.s_min, shape.s_min], shape)
    y = np.round(y + np.random.default_rng(1).normal(0, 0.5, t.size))
    config = DecompositionConfig(model="system", optimizer=method, deconvolution_iterations=500)
    d = decompose_waveform(y, 2000.0, 0, config, pulse=nominal_pulse(leica.fwhm_ps, response=leica))
    strong = np.sort(d.position[np.argsort(d.amplitude)[-2:]])
    np.testing.assert_allclose(strong, [40.0, 46.5], atol=0.6)


@pytest.mark.parametrize("method", ["gold", "richardson-lucy"])
def test_deconvolution_of_noise_alone_finds_no_echo(method):
    y = 12.0 + np.random.default_rng(5).normal(0.0, 0.5, 100).round()
    d = decompose_waveform(y, 1000.0, 0, DecompositionConfig(optimizer=method), pulse=nominal_pulse(4000.0))
    assert d.amplitude.size == 0 and d.message == "no_echoes"


def _blurred_pair():
    """Two echoes 5 samples apart through a Gaussian of 2.5 samples, 10 DN of noise-free background removed."""
    kernel, centre = naive.gaussian_response_kernel(2.5)
    truth = np.zeros(90)
    truth[40], truth[45] = 300.0, 120.0
    return naive._convolve_same(truth, kernel, centre) + 0.01, kernel, centre


def test_the_response_kernel_of_a_gaussian_is_the_numpy_one():
    kernel, centre = response_kernel(analytic_shape(), 2.5)
    expected, expected_centre = naive.gaussian_response_kernel(2.5)
    assert centre == expected_centre == 10
    np.testing.assert_allclose(kernel, expected, rtol=1e-14)


@pytest.mark.parametrize("method", ["gold", "richardson-lucy"])
def test_deconvolution_matches_the_numpy_reference(method):
    signal, kernel, centre = _blurred_pair()
    kernel_method, reference = (gold, naive.gold) if method == "gold" else (richardson_lucy, naive.richardson_lucy)
    got = kernel_method(signal, kernel, centre, 300)
    expected = reference(signal, kernel, centre, 300)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)
    # and it deconvolves: the two spikes stand out of the profile, where the signal holds one blurred hump
    peaks = [int(np.argmax(got[:43])), 43 + int(np.argmax(got[43:]))]
    np.testing.assert_allclose(peaks, [40, 45], atol=1)  # Gold, slower, still leans the weak one outwards
    assert got[peaks[0]] > 2 * signal.max()
