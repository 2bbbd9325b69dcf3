"""Damaged LAS inputs (issue 12, reader side): every promised point is read or reported, nothing invented."""

import shutil
import struct

import laspy
import numpy as np
import pytest

from fwcore.io import WaveformFileError, open_waveform_file, plan_point_ranges, read_pulses

POINT_COUNT_AT = 107  # LAS 1.3 header: legacy number of point records (u32)


def _set_point_count(path, n):
    with open(path, "r+b") as f:
        f.seek(POINT_COUNT_AT)
        f.write(struct.pack("<I", n))


def test_cut_inside_the_point_records_says_how_many_are_present(leica_copy):
    header = laspy.open(leica_copy).header
    cut = header.offset_to_point_data + 1000 * header.point_format.size + 20  # mid-record
    leica_copy.write_bytes(leica_copy.read_bytes()[:cut])
    ranges = plan_point_ranges(leica_copy, 400)
    batches = [read_pulses(r) for r in ranges]
    problems = [reason for b in batches for pid, reason in b.rejected if pid == -1]
    assert problems == [f"{leica_copy}: truncated: 1000 of 1125 point records present"]
    read = sum(b.return_offsets[-1] for b in batches)
    # every present point is read (a pulse whose other returns were cut keeps the ones that remain)
    assert read == 1000


def test_header_count_too_high_is_reported(leica_copy):
    _set_point_count(leica_copy, 5000)
    pulses = read_pulses(leica_copy)
    assert len(pulses) == 924
    reports = [r for p, r in pulses.rejected if p == -1]
    assert reports == [f"{leica_copy}: truncated: 1125 of 5000 point records present"]


def test_header_count_too_low_still_reads_every_record(leica_copy, caplog):
    _set_point_count(leica_copy, 1000)
    pulses = read_pulses(leica_copy)
    assert len(pulses) == 924 and pulses.return_offsets[-1] == 1125
    assert "promises 1000 point records but the file holds 1125" in caplog.text


def test_zero_scale_is_a_file_error(leica_copy):
    with open(leica_copy, "r+b") as f:
        f.seek(131)  # x scale factor
        f.write(struct.pack("<d", 0.0))
    with pytest.raises(WaveformFileError, match=r"leica_a\.las: the header's x scale 0\.0"):
        open_waveform_file(leica_copy)


def test_non_finite_offset_is_a_file_error(leica_copy):
    with open(leica_copy, "r+b") as f:
        f.seek(155 + 8)  # y offset
        f.write(struct.pack("<d", float("nan")))
    with pytest.raises(WaveformFileError, match=r"leica_a\.las: the header's y scale .* offset nan"):
        open_waveform_file(leica_copy)


def test_non_finite_beam_direction_rejects_the_pulse(leica_copy):
    las = laspy.read(leica_copy)
    first = np.flatnonzero(np.asarray(las.wavepacket_offset) == las.wavepacket_offset[0])
    las.x_t[first] = np.inf
    las.z_t[5] = np.nan
    las.write(leica_copy)
    pulses = read_pulses(leica_copy)
    assert len(pulses) + len(pulses.rejected) == 924 and len(pulses.rejected) == 2
    assert all("leica_a.las: non-finite x_t/y_t/z_t" in r for _, r in pulses.rejected)
    assert np.isfinite(pulses.direction).all()


def test_non_finite_gain_rejects_its_pulses_not_the_file(leica_copy):
    las = laspy.read(leica_copy)
    vlr = next(v for v in las.header.vlrs if v.record_id == 100)
    data = bytearray(vlr.record_data_bytes())
    data[10:18] = struct.pack("<d", float("inf"))  # digitizer gain
    las.header.vlrs.remove(vlr)
    las.header.vlrs.append(laspy.VLR("LASF_Spec", 100, "Waveform Packet Descriptor", bytes(data)))
    las.write(leica_copy)
    pulses = read_pulses(leica_copy)
    assert len(pulses) == 0 and len(pulses.rejected) == 924
    assert "non-finite digitizer gain (inf)" in pulses.rejected[0][1]


def test_wdp_whose_header_says_compressed_is_not_decoded(leica_copy):
    wdp = leica_copy.with_suffix(".wdp")
    data = bytearray(wdp.read_bytes())
    data[60 + 24 + 2 + 2] = 1  # the LAStools header's first descriptor: compressed
    wdp.write_bytes(bytes(data))
    pulses = read_pulses(leica_copy)
    assert len(pulses) == 0 and len(pulses.rejected) == 924
    assert "says uncompressed but its packet file holds LAStools-compressed packets" in pulses.rejected[0][1]


def test_empty_wdp_is_a_file_error(leica_copy):
    leica_copy.with_suffix(".wdp").write_bytes(b"")
    with pytest.raises(WaveformFileError, match=r"leica_a\.las: its waveform packet file leica_a\.wdp is empty"):
        plan_point_ranges(leica_copy)


@pytest.mark.parametrize("keep", [0.3, 0.7])
def test_truncated_laz_is_a_clear_error(tmp_path, leica_dir, keep):
    data = (leica_dir / "leica_a.laz").read_bytes()
    (tmp_path / "cut.laz").write_bytes(data[:int(len(data) * keep)])
    shutil.copy(leica_dir / "leica_a.wdz", tmp_path / "cut.wdz")
    with pytest.raises(WaveformFileError, match=r"cut\.laz"):
        for r in plan_point_ranges(tmp_path / "cut.laz", 400):
            read_pulses(r)


def test_corrupt_laz_points_are_a_clear_error(tmp_path, leica_dir):
    data = bytearray((leica_dir / "leica_a.laz").read_bytes())
    header = laspy.open(leica_dir / "leica_a.laz").header
    rng = np.random.default_rng(4)
    at = rng.integers(header.offset_to_point_data + 16, len(data) - 16, 400)
    data_array = np.frombuffer(bytes(data), np.uint8).copy()
    data_array[at] ^= 0xFF
    (tmp_path / "flip.laz").write_bytes(data_array.tobytes())
    shutil.copy(leica_dir / "leica_a.wdz", tmp_path / "flip.wdz")
    try:
        batches = [read_pulses(r) for r in plan_point_ranges(tmp_path / "flip.laz", 400)]
    except WaveformFileError as err:
        assert "flip.laz" in str(err)
    else:  # decodable garbage: whatever was read has finite geometry, the rest has reasons
        for b in batches:
            assert np.isfinite(b.anchor).all() and np.isfinite(b.direction).all()


def test_points_without_a_packet_are_reported(leica_copy):
    las = laspy.read(leica_copy)
    alone = np.flatnonzero(np.asarray(las.number_of_returns) == 1)[:4]
    las.wavepacket_index[alone] = 0
    las.write(leica_copy)
    batches = [read_pulses(r) for r in plan_point_ranges(leica_copy, 400)]
    assert sum(len(b) for b in batches) == 920
    reports = [r for b in batches for p, r in b.rejected if p == -1]
    assert sum(int(r.split(": ")[1].split()[0]) for r in reports) == 4
    assert all("point at no waveform packet" in r for r in reports)
