"""A file's pulse measured: the one NEON CSV path, and the head of a file read once."""

import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.measure import MODEL_PULSES, _head_records, read_csv_input
from fwcore.instrument.pulse import PulseOverrides
from fwcore.io import PointRange, read_pulses


def test_read_csv_input_measures_on_every_waveform_and_batches_the_first(neon_dir):
    csv = read_csv_input(neon_dir / "return_waveforms.csv", DecompositionConfig(model="generalized"),
                         outgoing=neon_dir / "outgoing_pulses.csv", limit=5)
    assert len(csv.batch) == 5 and csv.waveform_id.tolist() == [1, 3, 5, 7, 9]
    assert len(csv.waveforms.waveform_id) == 250
    assert csv.pulse.fwhm_ps == pytest.approx(15155.56, abs=0.01)
    assert csv.pulse.fwhm_source == "median of the outgoing pulses"
    given = read_csv_input(neon_dir / "return_waveforms.csv", DecompositionConfig(model="generalized"),
                           PulseOverrides(fwhm_ps=12000.0, shape_tolerance=0.02))
    assert (given.pulse.fwhm_ps, given.pulse.fwhm_source, given.pulse.shape_tolerance) == (12000.0, "configured",
                                                                                          0.02)
    assert len(given.batch) == 250


def test_the_auto_choice_takes_the_pulses_of_the_first_records_from_the_head(leica_dir):
    path = str(leica_dir / "leica_a.las")
    head = read_pulses(PointRange(path, 0, 1125))
    alone = read_pulses(PointRange(path, 0, MODEL_PULSES))  # what reading the first records again would give
    waveforms = _head_records(head, MODEL_PULSES, 7)
    assert len(waveforms) == len(alone) == 179  # LAS records are points: 200 points hold 179 pulses
    assert (waveforms.samples == alone.samples).all() and (waveforms.offsets == alone.sample_offsets).all()
