import numpy as np
import pytest

from fwcore.io import geolocate, open_waveform_file, plan_point_ranges, read_pulses


def test_leica_facts(leica_dir):
    wf = open_waveform_file(leica_dir / "leica_a.las")
    assert wf.version == "1.3" and wf.point_format == 4 and wf.point_count == 1125
    (d,) = wf.descriptors.values()
    assert (d.index, d.bits_per_sample, d.n_samples, d.sample_spacing_ps) == (1, 8, 256, 2000.0)
    assert d.gain == pytest.approx(0.0172906, rel=1e-5) and d.offset == 0.0
    pulses = read_pulses(leica_dir / "leica_a.las")
    assert len(pulses) == 924 and pulses.return_offsets[-1] == 1125
    assert pulses.packet_offset[0] == 92  # after the header LAStools writes
    assert np.unique(pulses.pulse_id).size == 924
    assert (np.diff(pulses.sample_offsets) == 256).all()


def test_las_wdp_and_laz_wdz_give_identical_pulses(leica_dir):
    a = read_pulses(leica_dir / "leica_a.las")
    b = read_pulses(leica_dir / "leica_a.laz")
    assert open_waveform_file(leica_dir / "leica_a.laz").packets.compressed
    assert not a.rejected and not b.rejected
    np.testing.assert_array_equal(a.samples, b.samples)
    np.testing.assert_array_equal(a.gps_time, b.gps_time)
    np.testing.assert_array_equal(a.return_xyz, b.return_xyz)
    np.testing.assert_array_equal(a.return_offsets, b.return_offsets)


def test_system_returns_of_a_pulse_land_on_each_other(leica_dir):
    p = read_pulses(leica_dir / "leica_a.las")
    counts = np.diff(p.return_offsets)
    multi = np.flatnonzero(counts > 1)
    assert multi.size > 100
    worst = 0.0
    for i in multi:
        lo, hi = p.return_offsets[i], p.return_offsets[i + 1]
        m = hi - lo
        xyz = geolocate(np.repeat(p.anchor[i:i + 1], m, 0), np.full(m, p.anchor_location_ps[i]),
                        np.repeat(p.direction[i:i + 1], m, 0), p.return_location_ps[lo:hi])
        worst = max(worst, np.abs(xyz - p.return_xyz[lo:hi]).max())
    # coordinates are stored in millimetres: two roundings and float32 x_t give at most ~1 mm
    assert worst < 1.5e-3


@pytest.mark.parametrize("points_per_range", [1, 97, 400, 5000])
def test_ranges_cover_every_pulse_exactly_once(leica_dir, points_per_range):
    path = leica_dir / "leica_a.las"
    everything = read_pulses(path)
    ranges = plan_point_ranges(path, points_per_range)
    parts = [read_pulses(r) for r in ranges]
    ids = np.concatenate([p.pulse_id for p in parts])
    assert ids.size == 924 and np.unique(ids).size == 924
    # a pulse read in a range has all its returns and the same samples
    by_id = {int(pid): i for i, pid in enumerate(everything.pulse_id)}
    for part in parts:
        for j, pid in enumerate(part.pulse_id):
            i = by_id[int(pid)]
            np.testing.assert_array_equal(part.pulse_samples(j), everything.pulse_samples(i))
            assert part.return_offsets[j + 1] - part.return_offsets[j] == \
                everything.return_offsets[i + 1] - everything.return_offsets[i]


def test_pulse_whose_points_lie_far_apart_is_read_once(tmp_path, leica_dir):
    import laspy
    las = laspy.read(leica_dir / "leica_a.las")
    offsets = np.asarray(las.wavepacket_offset)
    multi = np.flatnonzero(np.asarray(las.return_number) == 2)[0]
    # move the second return of a pulse to the end of the file
    order = np.concatenate([np.delete(np.arange(len(las.points)), multi), [multi]])
    las.points = las.points[order]
    path = tmp_path / "far.las"
    las.write(path)
    (tmp_path / "far.wdp").write_bytes((leica_dir / "leica_a.wdp").read_bytes())
    ranges = plan_point_ranges(path, 100)
    assert sum(len(r.extra_points) for r in ranges) >= 1
    parts = [read_pulses(r) for r in ranges]
    ids = np.concatenate([p.pulse_id for p in parts])
    assert ids.size == 924 and np.unique(ids).size == 924
    owner = next(p for p in parts if offsets[multi] in p.packet_offset)
    j = int(np.flatnonzero(owner.packet_offset == offsets[multi])[0])
    assert owner.return_offsets[j + 1] - owner.return_offsets[j] == las.number_of_returns[-1]


@pytest.mark.parametrize("point_format,version", [(5, "1.3"), (10, "1.4")])
def test_colour_formats_carry_rgb_and_nir(tmp_path, leica_dir, point_format, version):
    import laspy
    las = laspy.convert(laspy.read(leica_dir / "leica_a.las"), point_format_id=point_format, file_version=version)
    las.red[:] = np.arange(len(las.points)) % 65536
    if point_format == 10:
        las.nir[:] = 7
    path = tmp_path / "colour.las"
    las.write(path)
    (tmp_path / "colour.wdp").write_bytes((leica_dir / "leica_a.wdp").read_bytes())
    pulses = read_pulses(path)
    reference = read_pulses(leica_dir / "leica_a.las")
    np.testing.assert_array_equal(pulses.samples, reference.samples)
    assert pulses.rgb is not None and pulses.rgb.shape == (924, 3)
    assert (pulses.nir == 7).all() if point_format == 10 else pulses.nir is None


def test_las13_internal_packets(tmp_path, leica_dir):
    """LAS 1.3 internal storage: the header's 'start of waveform data packet record' points at the
    record (its 60-byte header first), and offsets count from there."""
    import struct
    import laspy
    las = laspy.read(leica_dir / "leica_a.las")
    wdp = (leica_dir / "leica_a.wdp").read_bytes()  # a record header + LAStools header + packets
    path = tmp_path / "internal13.las"
    las.header.global_encoding.waveform_data_packets_external = False
    las.header.global_encoding.waveform_data_packets_internal = True
    las.write(path)
    start = path.stat().st_size
    with open(path, "r+b") as f:
        f.seek(0, 2)
        f.write(wdp)
        f.seek(227)
        f.write(struct.pack("<Q", start))
    wf = open_waveform_file(path)
    assert wf.packets.path == path and wf.packets.record_start == start
    np.testing.assert_array_equal(read_pulses(path).samples, read_pulses(leica_dir / "leica_a.las").samples)
