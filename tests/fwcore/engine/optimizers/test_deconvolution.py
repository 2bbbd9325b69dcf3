"""The deconvolution methods (Gold, Richardson-Lucy): overlapping echoes recovered, noise alone gives none."""

from __future__ import annotations

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_waveform
from fwcore.engine.model import tabulated_model
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.response import named_response
from fwcore.instrument.shape import echo_shape


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
