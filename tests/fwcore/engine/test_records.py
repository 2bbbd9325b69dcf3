"""The engine's records: a batch's fitted model at every sample, in one kernel call, against each waveform's
own NumPy model (Decomposition.model: waveform_model, tabulated_model)."""

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.records import model_samples
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
