"""A pulse's identity comes from the pulse, not from the encoding: the same ids, seeds and echoes
from .las+.wdp, .laz+.wdz and our LAS 1.4 internal-packet rewrite of the Leica sample."""

import laspy
import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import pulse_identity, read_pulses
from fwcore.io.writer import write_waveform_las
from fwcore.pulses import echo_positions, pulse_waveforms


@pytest.fixture(scope="module")
def encodings(leica_dir, tmp_path_factory):
    las = read_pulses(leica_dir / "leica_a.las")
    header = laspy.open(leica_dir / "leica_a.las").header
    rewrite = write_waveform_las(tmp_path_factory.mktemp("rewrite") / "leica_a.las", las, "las14-internal",
                                 scales=header.scales, offsets=header.offsets)
    return {"las+wdp": las, "laz+wdz": read_pulses(leica_dir / "leica_a.laz"), "las14 internal": read_pulses(rewrite)}


def test_same_pulse_ids_whatever_the_encoding(encodings):
    a = encodings["las+wdp"]
    for name, b in encodings.items():
        np.testing.assert_array_equal(b.pulse_id, a.pulse_id, err_msg=name)
    # while the packet offsets, kept as their own column, differ
    assert not np.array_equal(encodings["laz+wdz"].packet_offset, a.packet_offset)


def test_identical_echoes_whatever_the_encoding(encodings):
    config, pulse = DecompositionConfig(generations=20), nominal_pulse(4000.0)
    tables = {}
    for name, pulses in encodings.items():
        n = 120
        sub = _head(pulses, n)
        result = decompose_batch(pulse_waveforms(sub, config.seed), config, pulse)
        tables[name] = np.column_stack([np.repeat(sub.pulse_id, np.diff(result.echo_offsets)), result.position,
                                        result.amplitude, result.alpha, result.reject,
                                        echo_positions(sub, result)])
    reference = tables.pop("las+wdp")
    for name, table in tables.items():
        np.testing.assert_array_equal(table, reference, err_msg=name)


def _head(pulses, n):
    import dataclasses
    s, r = pulses.sample_offsets[n], pulses.return_offsets[n]
    per_pulse = ("pulse_id", "packet_offset", "descriptor_index", "gps_time", "anchor", "anchor_location_ps",
                 "direction", "scan_angle", "point_source_id", "scan_direction_flag", "edge_of_flight_line",
                 "user_data", "sample_spacing_ps", "digitizer_gain", "digitizer_offset", "bits_per_sample",
                 "classification", "channel", "segment")
    return dataclasses.replace(
        pulses, **{f: getattr(pulses, f)[:n] for f in per_pulse}, samples=pulses.samples[:s],
        sample_offsets=pulses.sample_offsets[:n + 1], return_xyz=pulses.return_xyz[:r],
        return_number=pulses.return_number[:r], return_intensity=pulses.return_intensity[:r],
        return_location_ps=pulses.return_location_ps[:r], return_offsets=pulses.return_offsets[:n + 1],
        number_of_returns=pulses.number_of_returns[:r])


def test_repeated_time_and_anchor_are_told_apart_by_record_order():
    t = np.zeros(4)
    anchor = np.array([[1.0, 2.0, 3.0]] * 3 + [[1.0, 2.0, 3.001]])
    ids = pulse_identity(t, anchor)
    assert np.unique(ids).size == 4
    # the same records give the same ids; an id does not depend on what precedes it except equal keys
    np.testing.assert_array_equal(pulse_identity(t, anchor), ids)
    assert pulse_identity(t[3:], anchor[3:])[0] == ids[3]
