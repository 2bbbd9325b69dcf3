"""The LAS/LAZ waveform reader on the bundled Leica sample: its header, its descriptor, a pulse's samples and its
returns, the ranges a file is planned in, LAZ as LAS."""

import laspy
import numpy as np

from fwcore.io.las import POINT_FORMATS, open_waveform_file, packet_keys, plan_las_ranges, read_las_pulses
from fwcore.io.records import PointRange


def test_the_header_and_descriptor_of_the_leica_sample(leica_dir):
    wf = open_waveform_file(leica_dir / "leica_a.las")
    assert (wf.version, wf.point_format, wf.point_count, wf.header_point_count) == ("1.3", 4, 1125, 1125)
    assert not wf.compressed and not wf.adjusted_standard_gps_time and wf.problems == ()
    assert wf.quirks is POINT_FORMATS[4] and wf.quirks.scan_angle_field == "scan_angle_rank"
    (descriptor,) = wf.descriptors.values()
    assert (descriptor.index, descriptor.bits_per_sample, descriptor.compression, descriptor.n_samples,
            descriptor.sample_spacing_ps) == (1, 8, 0, 256, 2000.0)
    assert descriptor.gain == np.float64(0.017290625721216202) and descriptor.offset == 0.0


def test_a_pulse_is_its_packet_s_bytes_and_its_points(leica_dir):
    batch = read_las_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 10))
    las = laspy.read(leica_dir / "leica_a.las")
    raw = np.fromfile(leica_dir / "leica_a.wdp", dtype=np.uint8)  # the packet file read by hand
    assert len(batch) == 10 and batch.packet_offset[:3].tolist() == [92, 348, 604]
    assert batch.sample_offsets[:3].tolist() == [0, 256, 512]
    for i in (0, 9):
        offset = batch.packet_offset[i]
        np.testing.assert_array_equal(batch.pulse_samples(i), raw[offset:offset + 256])
    assert batch.pulse_samples(0)[:12].tolist() == [13, 12, 13, 13, 14, 13, 13, 17, 42, 67, 87, 100]
    assert (batch.sample_spacing_ps[0], batch.bits_per_sample[0]) == (2000.0, 8)
    # the first pulses have one return each: the points of the file, in its order
    assert batch.return_offsets[:4].tolist() == [0, 1, 2, 3]
    np.testing.assert_allclose(batch.return_xyz[:3], np.column_stack([las.x, las.y, las.z])[:3])


def test_the_file_is_planned_in_ranges_that_keep_a_pulse_whole(leica_dir):
    ranges = plan_las_ranges(leica_dir / "leica_a.las", 500)
    assert [(r.start, r.stop, r.n_pulses) for r in ranges] == [(0, 500, 424), (500, 1000, 392), (1000, 1125, 108)]
    # the pulse cut by the range boundary at point 500 is read by the range before it, once
    assert ranges[0].extra_points == (500,) and ranges[1].foreign_points == (500,)
    las = laspy.read(leica_dir / "leica_a.las")
    assert sum(r.n_pulses for r in ranges) == np.unique(packet_keys(las.points)).size == 924


def test_laz_reads_as_its_las(leica_dir):
    las = read_las_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 50))
    laz = read_las_pulses(PointRange(str(leica_dir / "leica_a.laz"), 0, 50))
    assert open_waveform_file(leica_dir / "leica_a.laz").compressed
    np.testing.assert_array_equal(laz.samples, las.samples)
    np.testing.assert_array_equal(laz.pulse_id, las.pulse_id)
    np.testing.assert_array_equal(laz.return_xyz, las.return_xyz)
