"""RIEGL-style LAS 1.4: a hundred descriptors, most of them empty, the points using two."""

import logging

import laspy
import numpy as np

from fwcore.io import open_waveform_file, plan_point_ranges, read_pulses
from fwcore.io.writer import write_waveform_las


def test_empty_descriptors_do_not_stop_the_file(tmp_path, leica_dir, caplog):
    leica = read_pulses(leica_dir / "leica_a.las")
    bits = np.where(np.arange(len(leica)) % 2 == 0, 16, 8)
    empty = [i for i in range(1, 101) if i not in (3, 40)]
    path = write_waveform_las(tmp_path / "riegl.las", leica, "las14-wdp", bits, empty_descriptors=empty)
    header = laspy.open(path).header
    assert (header.version.minor, header.point_format.id) == (4, 9)
    wf = open_waveform_file(path)
    assert len(wf.descriptors) == 100
    assert sorted(i for i, d in wf.descriptors.items() if d.problem is None) == [3, 40]
    assert wf.descriptors[7].problem == "waveform descriptor 7 has 0 samples at 0.0 ps spacing"
    pulses = read_pulses(path)
    assert len(pulses) == 924 and not pulses.rejected
    np.testing.assert_array_equal(pulses.samples, leica.samples)
    assert set(pulses.descriptor_index.tolist()) == {3, 40}

    # points that point at an empty descriptor: only those pulses are rejected, with the reason
    las = laspy.read(path)
    las.wavepacket_index[np.asarray(las.wavepacket_offset) == las.wavepacket_offset[0]] = 7
    las.write(path)
    with caplog.at_level(logging.WARNING, logger="fwl"):
        ranges = plan_point_ranges(path, 300)
    # once per used unusable descriptor, one line for the unused ones; never per pulse
    assert caplog.text.count("waveform descriptor 7 has 0 samples") == 1
    assert "97 unusable waveform descriptors are not used by any point (1-2, 4-6, 8-39, 41-100)" in caplog.text
    batches = [read_pulses(r) for r in ranges]
    rejected = [r for b in batches for r in b.rejected]
    assert sum(len(b) for b in batches) == 923
    assert [reason for _, reason in rejected] == ["riegl.las: waveform descriptor 7 has 0 samples at 0.0 ps spacing"]
    assert rejected[0][0] == leica.pulse_id[0]
