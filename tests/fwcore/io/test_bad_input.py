"""Each kind of bad input gets an error that names the file and the problem."""

import shutil
import struct

import laspy
import pytest

from fwcore.io import WaveformFileError, open_waveform_file, read_pulses


def test_missing_wdp(leica_copy):
    leica_copy.with_suffix(".wdp").unlink()
    with pytest.raises(FileNotFoundError, match=r"leica_a\.las.*leica_a\.wdp.*missing"):
        open_waveform_file(leica_copy)


def test_upper_case_wdp_is_accepted(leica_copy):
    leica_copy.with_suffix(".wdp").rename(leica_copy.with_suffix(".WDP"))
    assert len(read_pulses(leica_copy)) == 924


def test_truncated_wdp_rejects_only_the_pulses_it_lost(leica_copy):
    wdp = leica_copy.with_suffix(".wdp")
    data = wdp.read_bytes()
    wdp.write_bytes(data[: len(data) // 2])
    pulses = read_pulses(leica_copy)
    assert len(pulses) + len(pulses.rejected) == 924
    assert 400 < len(pulses.rejected) < 520
    assert all("beyond the end of leica_a.wdp" in reason for _, reason in pulses.rejected)


def test_truncated_wdz_rejects_pulses_with_a_reason(tmp_path, leica_dir):
    shutil.copy(leica_dir / "leica_a.laz", tmp_path / "leica_a.laz")
    data = (leica_dir / "leica_a.wdz").read_bytes()
    (tmp_path / "leica_a.wdz").write_bytes(data[: len(data) // 2])
    pulses = read_pulses(tmp_path / "leica_a.laz")
    assert len(pulses) + len(pulses.rejected) == 924 and len(pulses.rejected) > 400


def test_descriptor_index_without_descriptor(leica_copy):
    las = laspy.read(leica_copy)
    las.wavepacket_index[:3] = 7
    las.write(leica_copy)
    pulses = read_pulses(leica_copy)
    assert len(pulses) + len(pulses.rejected) == 924
    assert any("descriptor index 7 has no waveform packet descriptor" in r for _, r in pulses.rejected)


def test_unknown_compression_type(leica_copy):
    las = laspy.read(leica_copy)
    vlr = next(v for v in las.header.vlrs if v.record_id == 100)
    data = bytearray(vlr.record_data_bytes())
    data[1] = 3
    las.header.vlrs.remove(vlr)
    las.header.vlrs.append(laspy.VLR("LASF_Spec", 100, "Waveform Packet Descriptor", bytes(data)))
    las.write(leica_copy)
    # an unusable descriptor does not stop the file: each pulse pointing at it is rejected with the reason
    pulses = read_pulses(leica_copy)
    assert len(pulses) == 0 and len(pulses.rejected) == 924
    assert {r for _, r in pulses.rejected} == {"leica_a.las: waveform descriptor 1 has unknown compression type 3 "
                                               "(only 0, uncompressed, is defined)"}


def test_point_format_without_waveforms(tmp_path, leica_dir):
    las = laspy.convert(laspy.read(leica_dir / "leica_a.las"), point_format_id=1)
    las.write(tmp_path / "plain.las")
    with pytest.raises(WaveformFileError, match=r"plain\.las: point format 1 has no waveform packets"):
        open_waveform_file(tmp_path / "plain.las")


def test_corrupt_header(tmp_path, leica_dir):
    data = bytearray((leica_dir / "leica_a.las").read_bytes())
    data[0:4] = b"JUNK"  # not the LASF signature
    (tmp_path / "bad.las").write_bytes(bytes(data))
    with pytest.raises(WaveformFileError, match=r"bad\.las: not a readable LAS/LAZ file"):
        open_waveform_file(tmp_path / "bad.las")


def test_empty_file(tmp_path):
    (tmp_path / "empty.las").write_bytes(b"")
    with pytest.raises(WaveformFileError, match=r"empty\.las: empty file"):
        open_waveform_file(tmp_path / "empty.las")


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.las: no such file"):
        open_waveform_file(tmp_path / "nope.las")


def test_internal_packet_record_outside_the_file(tmp_path, leica_dir):
    data = bytearray((leica_dir / "leica_a.las").read_bytes())
    struct.pack_into("<H", data, 6, 2)  # global encoding: internal packets
    struct.pack_into("<Q", data, 227, len(data) + 1000)
    (tmp_path / "internal.las").write_bytes(bytes(data))
    with pytest.raises(WaveformFileError, match=r"internal\.las: internal waveform packets announced at byte"):
        open_waveform_file(tmp_path / "internal.las")
