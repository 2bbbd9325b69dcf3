"""A batch of pulses' metrics: each GEDI shot with the settings of the algorithm its L2A selected for it, and an
airborne file's with GEDI's settings scaled to its own pulse."""

import shutil

import h5py
import numpy as np

from fwcore.engine.config import DecompositionConfig, Optimizer
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import PointRange, read_pulses
from fwcore.io.gedi import l2a_algorithm_settings
from fwcore.metrics.pulses import batch_metrics, settings_for_pulse, take_waveforms, vertical_axis, zenith_cosine
from fwcore.metrics.waveform import MetricSettings, waveform_metrics
from fwcore.pulses import pulse_waveforms
from tests.fwcore.metrics.conftest import L1B, L2A


def test_each_shot_takes_its_selected_algorithms_settings(tmp_path):
    shutil.copy(L1B, tmp_path / L1B.name)
    l2a = tmp_path / L2A.name
    shutil.copy(L2A, l2a)
    with h5py.File(l2a, "r+") as f:  # L2A selects algorithm 2 for every other shot of the first beam
        selected = f["BEAM0001"]["selected_algorithm"]
        values = selected[:]
        values[::2] = 2
        selected[...] = values
    pulses = read_pulses(PointRange(str(tmp_path / L1B.name), 0, 16))
    assert pulses.metric_algorithm.tolist() == [2, 1] * 8
    config = DecompositionConfig(optimizer=Optimizer.LM)
    result = decompose_batch(pulse_waveforms(pulses, 1), config, nominal_pulse(), threads=1)
    _, settings = l2a_algorithm_settings(l2a)
    by_algorithm = {a: MetricSettings.from_dict(s) for a, s in settings.items()}
    mixed = batch_metrics(pulses, result, nominal_pulse(), by_algorithm[1], by_algorithm)
    first_z, drop = vertical_axis(pulses)
    for a, rows in ((2, np.arange(0, 16, 2)), (1, np.arange(1, 16, 2))):
        samples, offsets = take_waveforms(pulses.samples, pulses.sample_offsets, rows)
        alone = waveform_metrics(samples, offsets, pulses.noise_mean[rows], pulses.noise_sd[rows], first_z[rows],
                                 drop[rows], zenith_cosine(pulses)[rows], pulses.transmit_shape[rows], by_algorithm[a])
        assert np.array_equal(mixed.rh[rows], alone.rh, equal_nan=True)
        assert np.array_equal(mixed.ground_z[rows], alone.ground_z)
    # the algorithms differ where their settings do: the zcross smoothing of 3.5 moves some grounds
    plain = batch_metrics(pulses, result, nominal_pulse(), by_algorithm[1])
    assert not np.array_equal(plain.rh, mixed.rh)


def test_take_waveforms_keeps_each_waveforms_samples():
    samples, offsets = np.arange(10.0), np.array([0, 3, 3, 7, 10])
    taken, taken_offsets = take_waveforms(samples, offsets, np.array([3, 0, 2]))
    assert taken.tolist() == [7, 8, 9, 0, 1, 2, 3, 4, 5, 6] and taken_offsets.tolist() == [0, 3, 6, 10]


def test_an_airborne_pulse_is_smoothed_in_proportion_to_its_pulse():
    assert settings_for_pulse(4.3).smoothing_width == 6.5
    assert settings_for_pulse(2.0).smoothing_width_zcross == 2.0 * 6.5 / 4.3
