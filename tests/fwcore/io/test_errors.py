"""The io errors in one module, and messages that name the file, the problem and the command that reads it (what
a file is, from its first bytes: tests/fwcore/io/test_formats.py)."""

import pytest

from fwcore.io import formats, neon, pulsewaves
from fwcore.io.errors import (ForeignCsvError, ForeignFileError, ForeignWaveformFileError, InputFileError, PacketError,
                              WaveformCsvError, WaveformFileError, WdzError)
from fwcore.io.formats import LAS, NEON_CSV, plan_point_ranges
from fwcore.io.las import open_waveform_file


def test_every_io_error_is_a_value_error_of_one_family():
    assert all(issubclass(e, InputFileError) and issubclass(e, ValueError)
               for e in (WaveformFileError, WaveformCsvError, PacketError, WdzError, ForeignFileError))
    assert issubclass(ForeignWaveformFileError, WaveformFileError) and issubclass(ForeignCsvError, WaveformCsvError)
    assert issubclass(WdzError, PacketError)  # a packet that cannot be decoded rejects its pulse, as any other


def test_the_pulsewaves_signatures_are_the_reader_s_own():
    assert pulsewaves.PULSE_SIGNATURE is formats.PULSE_SIGNATURE == b"PulseWavesPulse\0"
    assert pulsewaves.WAVES_SIGNATURE is formats.WAVES_SIGNATURE == b"PulseWavesWaves\0"


def test_a_file_of_another_format_is_named_with_the_command_that_reads_it(leica_dir, neon_dir):
    csv = neon_dir / "return_waveforms.csv"
    with pytest.raises(WaveformFileError) as err:
        LAS.open(csv)
    assert str(err.value) == (f"{csv} is a NEON-layout waveform CSV, not a LAS/LAZ or PulseWaves file "
                              "(fwl decompose-csv reads it)")
    with pytest.raises(WaveformFileError) as err:
        plan_point_ranges(csv)
    assert str(err.value) == (f"{csv} is a NEON-layout waveform CSV, not a flight line of full waveforms: give it "
                              "to fwl decompose-csv")
    las = leica_dir / "leica_a.las"
    with pytest.raises(WaveformCsvError) as err:
        NEON_CSV.open(las)
    assert str(err.value) == (f"{las} is a LAS/LAZ file, not a NEON-layout waveform CSV (waveform_id, n_samples, "
                              "s0, ...) (fwl run reads it)")
    wdp = leica_dir / "leica_a.wdp"
    with pytest.raises(WaveformFileError, match=r"leica_a\.wdp is a LAS waveform packet file .*\(give the file "
                                                r"beside it\)"):
        LAS.open(wdp)


def test_a_reader_given_another_kind_of_file_says_what_it_wanted_without_the_table(leica_dir, neon_dir, tmp_path):
    # the readers do not know the other kinds (fwcore.io.formats does): they raise a ForeignFileError of their own
    csv, las = neon_dir / "return_waveforms.csv", leica_dir / "leica_a.las"
    with pytest.raises(ForeignWaveformFileError) as err:
        open_waveform_file(csv)
    assert err.value.path == csv and err.value.wanted == "a LAS/LAZ or PulseWaves file"
    assert str(err.value).startswith(f"{csv}: not a readable LAS/LAZ file (")
    with pytest.raises(ForeignCsvError) as err:
        neon.read_neon_csv(las)
    assert str(err.value) == f"{las}: not a NEON waveform CSV (expected header waveform_id, n_samples, s0, ...)"
    damaged = tmp_path / "damaged.las"
    damaged.write_bytes(las.read_bytes()[:100])  # LAS's first bytes, a header cut short: LAS, damaged
    with pytest.raises(WaveformFileError, match="damaged.las: not a readable LAS/LAZ file") as err:
        open_waveform_file(damaged)
    assert not isinstance(err.value, ForeignFileError)
    noise = tmp_path / "noise.bin"
    noise.write_bytes(bytes(range(256)))
    with pytest.raises(ForeignWaveformFileError, match=r"noise\.bin: not a readable LAS/LAZ file: a binary file of "
                                                       r"no format fwl reads \("):
        LAS.open(noise)
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(ForeignCsvError, match=r"other\.csv: not a NEON waveform CSV \(expected header"):
        NEON_CSV.open(other)  # a text file of another layout: the reader's own message


def test_a_csv_error_names_the_file_and_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("waveform_id,n_samples,s0,s1\n1,2,3,4\n2,2,x,5\n")
    with pytest.raises(WaveformCsvError, match=r"bad\.csv:3: unreadable value"):
        neon.read_neon_csv(bad)
