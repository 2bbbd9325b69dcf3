"""The io records: a pulse's identity from what it is, and a PulseBatch's per-row views, on the Leica sample."""

import numpy as np

from fwcore.io.las import read_las_pulses
from fwcore.io.records import PointRange, _mix64, pulse_identity


def test_the_mix_is_splitmix64_s_finaliser():
    # SplitMix64 seeded with 0: its first output is 0xE220A8397B1DCDAF (Vigna's reference implementation)
    assert int(_mix64(np.zeros(1, np.uint64))[0]) == 0xE220A8397B1DCDAF


def test_identity_is_what_the_pulse_is_and_repeats_are_told_apart_by_order():
    gps = np.array([1.0, 1.0, 1.0, 2.0])
    anchor = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.004], [0.0, 0.0, 0.0]])
    ids = pulse_identity(gps, anchor)
    assert np.unique(ids).size == 4 and (ids >= 0).all() and (ids < 2 ** 53).all()
    # the same pulses in another order keep their ids (of two equal ones, the first in record order is the first)
    np.testing.assert_array_equal(pulse_identity(gps[::-1], anchor[::-1])[[2, 1, 0]], ids[[0, 2, 3]])
    assert pulse_identity(gps[:1], anchor[:1] + 0.00004)[0] == ids[0]  # anchors within half a quantum (0.1 mm)
    assert pulse_identity(gps[:1], anchor[:1], anchor[:1])[0] != ids[0]  # a target changes it


def test_a_batch_s_rows_and_returns(leica_dir):
    batch = read_las_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 1125))
    assert len(batch) == 924 and batch.sample_offsets[-1] == 924 * 256
    np.testing.assert_array_equal(batch.pulse_samples(3), batch.samples[768:1024])
    per_pulse = np.diff(batch.return_offsets)
    assert per_pulse.sum() == 1125 and batch.return_pulse().tolist() == np.repeat(np.arange(924), per_pulse).tolist()
    # the sample is clipped to a plot: 21 returns of 16 pulses lie outside it
    assert batch.omitted_returns().sum() == 21 and np.count_nonzero(batch.omitted_returns()) == 16
    assert batch.channels().tolist() == [0] * 924 and batch.segments().tolist() == [0] * 924
    assert batch.outgoing_samples(0).size == 0
