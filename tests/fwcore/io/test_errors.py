"""The io errors in one module, the file kinds read once from a file's first bytes, and messages that name the
file, the problem and the command that reads it."""

import pytest

from fwcore.io import formats, neon, pulsewaves
from fwcore.io.errors import InputFileError, PacketError, WaveformCsvError, WaveformFileError, WdzError
from fwcore.io.formats import (FOREIGN_BINARY, LAS, NEON_CSV, PULSEWAVES, WAVES_FILE, WDP_FILE, format_of, kind_of,
                               plan_point_ranges)
from fwcore.io.las import open_waveform_file


def test_every_io_error_is_a_value_error_of_one_family():
    assert all(issubclass(e, InputFileError) and issubclass(e, ValueError)
               for e in (WaveformFileError, WaveformCsvError, PacketError, WdzError))
    assert issubclass(WdzError, PacketError)  # a packet that cannot be decoded rejects its pulse, as any other


def test_the_pulsewaves_signatures_are_the_reader_s_own():
    assert pulsewaves.PULSE_SIGNATURE is formats.PULSE_SIGNATURE == b"PulseWavesPulse\0"
    assert pulsewaves.WAVES_SIGNATURE is formats.WAVES_SIGNATURE == b"PulseWavesWaves\0"


def test_the_shared_files_are_known_by_their_first_bytes(leica_dir, neon_dir, pulsewaves_dir):
    pls = pulsewaves_dir / "geolas_example1.pls"
    assert (kind_of(leica_dir / "leica_a.las").format, kind_of(pls).format,
            kind_of(neon_dir / "return_waveforms.csv").format) == (LAS, PULSEWAVES, NEON_CSV)
    assert kind_of(neon_dir / "return_waveforms.csv").words == "a NEON-layout waveform CSV"
    assert kind_of(pls.with_suffix(".wvs")) is WAVES_FILE and WAVES_FILE.beside
    assert kind_of(leica_dir / "leica_a.wdp") is WDP_FILE
    assert kind_of(neon_dir / "geolocation.csv").words == "a text file (CSV)"


def test_a_format_is_found_with_one_read_of_the_file(neon_dir, monkeypatch):
    opened = []

    def counting_open(path, *args, **kwargs):
        opened.append(path)
        return open(path, *args, **kwargs)

    monkeypatch.setattr(formats, "open", counting_open, raising=False)
    assert format_of(neon_dir / "return_waveforms.csv") is NEON_CSV
    assert len(opened) == 1


def test_a_pls_is_pulsewaves_by_its_name_and_random_bytes_are_foreign(tmp_path):
    (tmp_path / "empty.pls").write_bytes(b"")
    (tmp_path / "noise.bin").write_bytes(bytes(range(256)))
    assert format_of(tmp_path / "empty.pls") is PULSEWAVES
    assert kind_of(tmp_path / "noise.bin") is FOREIGN_BINARY and format_of(tmp_path / "noise.bin") is LAS


def test_a_file_of_another_format_is_named_with_the_command_that_reads_it(leica_dir, neon_dir):
    csv = neon_dir / "return_waveforms.csv"
    with pytest.raises(WaveformFileError) as err:
        open_waveform_file(csv)
    assert str(err.value) == (f"{csv} is a NEON-layout waveform CSV, not a LAS/LAZ or PulseWaves file "
                              "(fwl decompose-csv reads it)")
    with pytest.raises(WaveformFileError) as err:
        plan_point_ranges(csv)
    assert str(err.value) == (f"{csv} is a NEON-layout waveform CSV, not a flight line of full waveforms: give it "
                              "to fwl decompose-csv")
    las = leica_dir / "leica_a.las"
    with pytest.raises(WaveformCsvError) as err:
        neon.read_neon_csv(las)
    assert str(err.value) == (f"{las} is a LAS/LAZ file, not a NEON-layout waveform CSV (waveform_id, n_samples, "
                              "s0, ...) (fwl run reads it)")
    wdp = leica_dir / "leica_a.wdp"
    with pytest.raises(WaveformFileError, match=r"leica_a\.wdp is a LAS waveform packet file .*\(give the file "
                                                r"beside it\)"):
        open_waveform_file(wdp)


def test_a_csv_error_names_the_file_and_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("waveform_id,n_samples,s0,s1\n1,2,3,4\n2,2,x,5\n")
    with pytest.raises(WaveformCsvError, match=r"bad\.csv:3: unreadable value"):
        neon.read_neon_csv(bad)
