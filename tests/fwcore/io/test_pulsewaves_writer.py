"""GEDI and LVIS waveforms written as PulseWaves read back as the same waveforms, at the same places."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fwcore.io import read_pulses
from fwcore.io.pulsewaves import open_pulsewaves
from fwcore.io.pulsewaves_writer import write_pulsewaves

DATA = Path(__file__).resolve().parents[3] / "examples" / "data"
LVIS = DATA / "lvis" / "LVIS_Mondah_level1b.SPLIT.8.h5"
GEDI = DATA / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"


def _positions(batch, t_ps: float) -> np.ndarray:
    """Each pulse's sample at time t_ps after its first (fwcore.io.records.PulseBatch's geometry)."""
    return batch.anchor + (batch.anchor_location_ps - t_ps)[:, None] * batch.direction


@pytest.mark.parametrize("source, rounded", [(LVIS, False), (GEDI, True)])
def test_a_written_file_reads_back_the_same_waveforms_times_and_places(tmp_path, source, rounded):
    pulses = read_pulses(source)
    written = read_pulses(write_pulsewaves(tmp_path / "copy.pls", pulses, round_samples=rounded))
    assert len(written) == len(pulses)
    np.testing.assert_array_equal(written.sample_offsets, pulses.sample_offsets)
    np.testing.assert_array_equal(written.samples, np.round(pulses.samples) if rounded else pulses.samples)
    np.testing.assert_allclose(written.sample_spacing_ps, pulses.sample_spacing_ps, rtol=1e-7)  # float32 units
    np.testing.assert_allclose(written.gps_time, pulses.gps_time, atol=1e-6)
    for t_ps in (0.0, 500_000.0):  # the first sample and half a microsecond down the beam
        error = np.abs(_positions(written, t_ps) - _positions(pulses, t_ps)).max(axis=0)
        assert error[0] < 1e-7 and error[1] < 1e-7  # degrees: the 1e-7 quantum
        assert error[2] < 1e-3  # metres: the 1e-3 quantum


def test_one_descriptor_a_sample_spacing_with_16_bit_samples(tmp_path):
    pulses = read_pulses(LVIS)
    opened = open_pulsewaves(write_pulsewaves(tmp_path / "copy.pls", pulses))
    assert len(opened.descriptors) == np.unique(pulses.sample_spacing_ps).size
    (sampling,) = opened.descriptors[1].samplings
    assert (sampling.type, sampling.bits_per_sample, sampling.number_of_segments) == (2, 16, 1)
    assert opened.header.n_pulses == len(pulses) and not opened.problems


def test_8_bit_samples_and_what_cannot_be_written(tmp_path):
    pulses = read_pulses(LVIS)
    small = dataclasses.replace(pulses, samples=np.clip(pulses.samples - pulses.samples.min(), 0, 255))
    written = read_pulses(write_pulsewaves(tmp_path / "eight.pls", small, bits=8))
    np.testing.assert_array_equal(written.samples, small.samples)
    assert set(written.bits_per_sample) == {8}
    with pytest.raises(ValueError, match="not whole 8-bit values"):
        write_pulsewaves(tmp_path / "too_big.pls", pulses, bits=8)
    with pytest.raises(ValueError, match="round_samples"):
        write_pulsewaves(tmp_path / "fractions.pls", read_pulses(GEDI))
