"""The NEON-layout waveform CSV reader: the bundled Harvard Forest files, trailing padding, gaps and bad values."""

import numpy as np
import pytest

from fwcore.io.errors import ForeignCsvError, WaveformCsvError
from fwcore.io.neon import read_neon_csv


def test_the_harvard_returns_and_outgoing_pulses(neon_dir):
    returns = read_neon_csv(neon_dir / "return_waveforms.csv")
    assert returns.waveform_id.size == 250 and returns.waveform_id[:4].tolist() == [1, 3, 5, 7]
    assert [s.size for s in returns.samples[:4]] == [80, 80, 80, 88]  # each its own n_samples
    assert returns.samples[0][:8].tolist() == [218, 219, 219, 220, 221, 222, 222, 223]
    assert returns.valid[0].all()
    outgoing = read_neon_csv(neon_dir / "outgoing_pulses.csv")
    assert outgoing.waveform_id.size == 250 and outgoing.samples[0].size == 60 and outgoing.samples[0].max() == 772


def test_padding_is_cut_and_gaps_stay_invalid(tmp_path):
    path = tmp_path / "w.csv"
    path.write_text("waveform_id,n_samples,s0,s1,s2,s3,s4,s5\n4,6,10,0,12,NA,0,0\n\n9,6,5,6,7,8,9,10\n")
    w = read_neon_csv(path)
    assert w.waveform_id.tolist() == [4, 9]
    np.testing.assert_array_equal(w.samples[0], [10, 0, 12])  # the trailing zeros and NA are padding
    assert w.valid[0].tolist() == [True, False, True]
    assert w.samples[1].tolist() == [5, 6, 7, 8, 9, 10] and w.valid[1].all()


def test_errors_name_the_file_and_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("waveform_id,n_samples,s0\n1,1,5\n2,1,five\n")
    with pytest.raises(WaveformCsvError, match=r"bad\.csv:3: unreadable value"):
        read_neon_csv(bad)
    other = tmp_path / "other.csv"
    other.write_text("x,y,z\n1,2,3\n")
    with pytest.raises(ForeignCsvError, match="not a NEON waveform CSV"):
        read_neon_csv(other)
    empty = tmp_path / "empty.csv"
    empty.write_text("waveform_id,n_samples,s0\n")
    with pytest.raises(WaveformCsvError, match="no waveforms"):
        read_neon_csv(empty)
