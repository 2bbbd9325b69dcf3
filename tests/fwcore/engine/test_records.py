"""The engine's records: a batch's fitted model at every sample, in one kernel call, against each waveform's
own NumPy model (Decomposition.model: waveform_model, tabulated_model)."""

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.records import fitted_model, model_samples
from fwcore.engine.waveform_width import waveform_widths
from fwcore.instrument.measure import file_system_pulse
from fwcore.io import input_summary, read_pulses
from fwcore.pulses import pulse_waveforms


@pytest.mark.parametrize("model", ["generalized", "system"])
def test_model_samples_is_each_waveforms_own_model(leica_dir, model):
    path = str(leica_dir / "leica_a.las")
    config = DecompositionConfig(model=model, generations=5)
    pulses = read_pulses(path)
    result = decompose_batch(pulse_waveforms(pulses, 0), config, file_system_pulse(path, input_summary(path).records,
                                                                                   config), threads=1)
    offsets = pulses.sample_offsets
    expected = np.zeros(int(offsets[-1]), np.float32)
    for i in np.flatnonzero(result.status == 0):
        expected[offsets[i]:offsets[i + 1]] = result.waveform(int(i)).model(np.arange(offsets[i + 1] - offsets[i]))
    assert (result.shapes is not None) == (model == "system") and np.abs(expected).max() > 50
    np.testing.assert_allclose(model_samples(result, offsets), expected, rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize("model", ["generalized", "system"])
def test_fitted_model_given_to_the_widths_gives_their_own(leica_dir, model):
    """A range computes the model once (pipeline.stages.geolocate_range): the echoes' widths measured against it
    are those waveform_widths measures on its own, to the bit, and model_samples is its float32."""
    path = str(leica_dir / "leica_a.las")
    config = DecompositionConfig(model=model, generations=5)
    pulses = read_pulses(path)
    result = decompose_batch(pulse_waveforms(pulses, 0), config, file_system_pulse(path, input_summary(path).records,
                                                                                   config), threads=1)
    model_64 = fitted_model(result, pulses.sample_offsets)
    own = waveform_widths(pulses.samples, pulses.sample_offsets, result)
    given = waveform_widths(pulses.samples, pulses.sample_offsets, result, model_64)
    assert model_64.dtype == np.float64 and np.isfinite(own).sum() > 100
    np.testing.assert_array_equal(given, own)
    np.testing.assert_array_equal(model_samples(result, pulses.sample_offsets), model_64.astype(np.float32))
