"""The bridge between the formats and the engine: pulses -> waveforms (seeds, signal windows), echoes -> points."""

import dataclasses

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io.las import read_las_pulses
from fwcore.io.records import PointRange
from fwcore.pulses import UNCLASSIFIED, decomposed_echoes, echo_positions, echo_times_ps, pulse_waveforms, signal_windows
from fwcore.rng import pulse_seeds


@pytest.fixture(scope="module")
def leica(leica_dir):
    return read_las_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 40))


def test_waveforms_are_seeded_from_the_pulse_not_the_file(leica):
    waveforms = pulse_waveforms(leica, 7)
    assert waveforms.samples is leica.samples and waveforms.valid.all() and waveforms.noise_floor is None
    np.testing.assert_array_equal(waveforms.seeds, pulse_seeds(7, leica.pulse_id, np.zeros(len(leica), np.int16)))
    np.testing.assert_array_equal(waveforms.sample_spacing_ps, 2000.0)
    assert not np.array_equal(pulse_waveforms(leica, 8).seeds, waveforms.seeds)


def test_a_recorded_noise_keeps_only_the_signal_s_window(leica):
    samples = np.full(256, 10.0)
    samples[120:131] = 110.0  # a box of 100 over noise mean 10, sigma 1
    one = dataclasses.replace(leica, samples=samples, sample_offsets=np.array([0, 256]), pulse_id=leica.pulse_id[:1],
                              noise_mean=np.array([10.0]), noise_sd=np.array([1.0]))
    valid = signal_windows(one)
    # smoothed with the sigma-4 kernel, the box adds more than 3 (3 sigmas) from 7 samples before it (5.1% of
    # the kernel's weight lies 7-12 samples out, 3.0% at 8-12) to 7 after: 113..137, then 40 samples each side
    assert np.flatnonzero(valid).tolist() == list(range(73, 178))
    flat = dataclasses.replace(one, samples=np.full(256, 10.0))
    assert signal_windows(flat).all()  # a waveform that never rises keeps all its samples


def test_echoes_become_points_at_their_times(leica):
    pulse = nominal_pulse(2000.0)
    result = decompose_batch(pulse_waveforms(leica, 0), DecompositionConfig(), pulse)
    times = echo_times_ps(leica, result, 150.0)
    np.testing.assert_allclose(times, result.position * 2000.0 + 150.0)
    owner = result.echo_waveform
    xyz = echo_positions(leica, result, 150.0)
    np.testing.assert_allclose(xyz, leica.anchor[owner] + (leica.anchor_location_ps[owner] - times)[:, None]
                               * leica.direction[owner])
    columns = decomposed_echoes(leica, result)
    kept = result.reject == 0
    assert columns["x"].size == kept.sum() > len(leica)
    for pulse_row in np.unique(owner[kept]):  # return numbers 1..n in time order within each pulse
        mine = leica.pulse_id[pulse_row] == columns["pulse_id"]
        assert columns["return_number"][mine].tolist() == list(range(1, mine.sum() + 1))
        assert (columns["number_of_returns"][mine] == mine.sum()).all()
    np.testing.assert_array_equal(columns["intensity"], np.round(result.amplitude[kept] * 256))  # 8 -> 16 bits
    assert (columns["classification"] == UNCLASSIFIED).all()
