"""PulseWaves samples from five sensors: the facts of examples/data/pulsewaves/README.md."""

import struct

import numpy as np
import pytest

from fwcore.io import describe_file, plan_point_ranges, read_pulses
from fwcore.io.geolocate import geolocate
from fwcore.io.pulsewaves import WAVES_HEADER_BYTES, _layout, _walk_waves, open_pulsewaves
from fwcore.instrument.width import recorded_pulse_fwhm_ps

SAMPLES = {  # name: pulses, waveforms (one a pulse read), heights of the returning samples (README)
    "las13fwf_example1": (1000, 1000, (231.6, 277.0)),
    "geolas_example1": (1000, 790, (409.7, 455.7)),
    "lvis_example1": (1000, 1000, (-13.1, 119.1)),
    "optech_example1": (998, 998, (130.9, 152.6)),
    "riegl_example3": (16486, 16486, (334.9, 359.9)),
}
EARTH_CENTRED = {"optech_example1", "riegl_example3"}


def _positions(batch):
    n = np.diff(batch.sample_offsets)
    owner = np.repeat(np.arange(len(batch)), n)
    k = np.arange(n.sum()) - np.repeat(batch.sample_offsets[:-1], n)
    return geolocate(batch.anchor[owner], batch.anchor_location_ps[owner], batch.direction[owner],
                     k * batch.sample_spacing_ps[owner])


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_header_counts_times_and_tiling(pulsewaves_dir, name):
    pw = open_pulsewaves(pulsewaves_dir / f"{name}.pls")
    records = np.array(pw.records())
    assert pw.header.n_pulses == pw.point_count == records.size == SAMPLES[name][0]
    assert (records["T"].min(), records["T"].max()) == (pw.header.t_min, pw.header.t_max)
    # the waves of consecutive pulses tile the .wvs exactly from byte 60 to its end
    data = np.fromfile(pw.waves_path, np.uint8)
    layout = _layout(pw.descriptors)
    empty = np.zeros(0, np.int64)
    counts, ends = _walk_waves(data, records["offset"].astype(np.int64), records["descriptor"].astype(np.int64),
                               layout.first, layout.count, layout.extra, layout.bits_duration, layout.bits_segments,
                               layout.bits_samples, layout.n_segments, layout.n_samples, layout.sample_bytes, False,
                               empty, empty, empty, empty, empty, empty)
    assert (counts > 0).all()
    assert records["offset"][0] == WAVES_HEADER_BYTES and ends[-1] == data.size
    np.testing.assert_array_equal(ends[:-1], records["offset"][1:])


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_samples_lie_inside_the_header_bounds_at_the_known_heights(pulsewaves_dir, name):
    path = pulsewaves_dir / f"{name}.pls"
    pw = open_pulsewaves(path)
    batch = read_pulses(path)
    assert len(batch) == SAMPLES[name][1]
    assert len(batch) == np.unique(batch.pulse_id).size  # one waveform a pulse
    xyz = _positions(batch)
    assert np.isfinite(xyz).all()
    # within the coordinate quantisation and half a sampling unit along the beam
    half_unit = np.abs(batch.direction * batch.sample_spacing_ps[:, None]).max(axis=0) / 2
    slack = np.asarray(pw.header.scales) + half_unit
    assert (xyz.min(axis=0) >= np.asarray(pw.header.bounds_min) - slack).all()
    assert (xyz.max(axis=0) <= np.asarray(pw.header.bounds_max) + slack).all()
    if name in EARTH_CENTRED:
        import pyproj
        to_height = pyproj.Transformer.from_crs(4978, 4979, always_xy=True)
        height = to_height.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])[2]
        assert "EPSG:4978" in pw.crs_source
    else:
        height = xyz[:, 2]
    lo, hi = SAMPLES[name][2]
    assert height.min() == pytest.approx(lo, abs=0.1) and height.max() == pytest.approx(hi, abs=0.1)


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_first_pulse_matches_its_record(pulsewaves_dir, name):
    """An independent parse of the first record (struct, by the draft's table) against the batch."""
    pls = (pulsewaves_dir / f"{name}.pls").read_bytes()
    offset_to_pulses = struct.unpack_from("<q", pls, 176)[0]
    t_scale, t_offset = struct.unpack_from("<dd", pls, 224)
    scale, offset = np.array(struct.unpack_from("<3d", pls, 256)), np.array(struct.unpack_from("<3d", pls, 280))
    t, wave_offset, *xyz = struct.unpack_from("<qq6i2h", pls, offset_to_pulses)[:8]
    first_returning = struct.unpack_from("<h", pls, offset_to_pulses + 40)[0]
    anchor = np.array(xyz[:3]) * scale + offset
    batch = read_pulses(plan_point_ranges(pulsewaves_dir / f"{name}.pls", 50)[0])
    assert batch.packet_offset[0] == wave_offset
    assert batch.gps_time[0] == t * t_scale + t_offset
    np.testing.assert_allclose(batch.anchor[0], anchor)
    # first_returning_sample is the duration of the first returning segment (sampling units)
    unit_ps = 1000.0 * open_pulsewaves(pulsewaves_dir / f"{name}.pls").descriptors[
        int(batch.descriptor_index[0])].sample_units_ns
    assert -batch.anchor_location_ps[0] / unit_ps == pytest.approx(first_returning, abs=0.5)  # stored as a short


def test_geolas_mis_encoded_descriptor_is_rejected_not_decomposed(pulsewaves_dir):
    batch = read_pulses(pulsewaves_dir / "geolas_example1.pls")
    assert len(batch) == 790 and set(batch.descriptor_index.tolist()) == {1}
    assert len(batch.rejected) == 210
    assert all("do not match pulse descriptor 2 (mis-encoded" in reason for _, reason in batch.rejected)
    assert batch.samples.max() <= 255


def test_riegl_pulse_with_two_channels_is_one_waveform_of_the_unsaturated_channel(pulsewaves_dir):
    """The one pulse of descriptor 3 carries the low-power channel 1 (sensitive: it saturates at 255) and
    the high-power channel 0 over the same 80 ns: it is one waveform, channel 0's, as recorded."""
    path = pulsewaves_dir / "riegl_example3.pls"
    batch = read_pulses(path)
    (row,) = np.flatnonzero(batch.descriptor_index == 3)
    assert np.unique(batch.pulse_id).size == len(batch) == 16486
    assert batch.channel[row] == 0 and batch.segment[row] == 0
    high = batch.pulse_samples(row)
    assert high.size == 80 and high.max() == 76  # the high-power channel, unsaturated
    # the low-power channel of the same pulse, read straight from the waves: saturated (two samples at 255)
    waves = np.fromfile(open_pulsewaves(path).waves_path, np.uint8)
    at = int(batch.packet_offset[row])
    at += 1 + int(waves[at])  # reference sampling: an 8-bit count, then its samples
    low_n = int(waves[at + 4])  # low-power sampling: a 32-bit duration, an 8-bit count, then its samples
    low = waves[at + 5:at + 5 + low_n]
    assert low_n == 80 and (low == 255).sum() == 2
    assert set(np.diff(batch.sample_offsets).tolist()) <= {80, 160}


@pytest.mark.parametrize("name,scanner_ns", [("riegl_example3", 4.0), ("lvis_example1", 10.0),
                                             ("optech_example1", 10.0), ("geolas_example1", 10.0)])
def test_outgoing_waveform_gives_the_system_pulse_width(pulsewaves_dir, name, scanner_ns):
    batch = read_pulses(pulsewaves_dir / f"{name}.pls")
    assert batch.outgoing is not None and np.diff(batch.outgoing_offsets).min() > 0
    fwhm, source = recorded_pulse_fwhm_ps(batch)
    assert source == "outgoing waveforms"
    # measured on the recorded outgoing pulses; the scanner record's nominal width bounds it loosely
    assert 0.3 * scanner_ns * 1000 < fwhm < 3 * scanner_ns * 1000


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_describe_reads_headers_only(pulsewaves_dir, name):
    info = describe_file(pulsewaves_dir / f"{name}.pls")
    assert info["format"] == "PulseWaves" and info["pulses"] == SAMPLES[name][0]
    used = {d["index"]: d["pulses"] for d in info["descriptors"] if d["pulses"]}
    assert sum(used.values()) == SAMPLES[name][0]


def test_lookup_tables_turn_codes_into_linear_values(pulsewaves_dir):
    from fwcore.io.pulsewaves import LookupTable, linear_samples

    samples = np.array([0.0, 1.0, 2.0, 3.0, 5.0, 6.0, 1.0, 2.0, 7.0])
    offsets = np.array([0, 4, 6, 9])
    tables = {1: LookupTable(1, 0, 8, "volts", np.array([0.0, 0.5, 1.5, 3.5])),
              2: LookupTable(2, 0, 8, "amplitude [dB]", np.array([0.0, 10.0, 20.0]))}
    out = linear_samples(samples, offsets, np.array([1, 0, 2]), tables)
    np.testing.assert_array_equal(out[:6], [0.0, 0.5, 1.5, 3.5, 5.0, 6.0])  # a table; none: codes stay
    np.testing.assert_allclose(out[6:8], [10.0, 100.0])  # dB back to power
    assert np.isnan(out[8])  # a code the table does not hold
    assert samples[0] == 0.0 and samples[1] == 1.0  # the input is left as it was
    # the shared RIEGL file carries no table: its samples are its codes
    pw = open_pulsewaves(pulsewaves_dir / "riegl_example3.pls")
    assert pw.lookup_tables == {} and all(s.lookup_table == 0 for d in pw.descriptors.values() for s in d.samplings)


# sha256 over every waveform read (pulse id, channel, anchor location, spacing, samples): the hashes the reader
# gave before one waveform a pulse; riegl_example3's is the one it gave without its pulse's second channel
# (7128249950349058, channel 1: saturated), which it read as a waveform of its own until then
DECODED = {
    "geolas_example1": "5660cdd0135f6760930dce1c5a384fa3544fb0ff2646de3e47de78e921932745",
    "las13fwf_example1": "204a5d33a4152c80d5c3cd7550446237f08bf58a924e90d551dcfc924b10ae7d",
    "lvis_example1": "54ad2ccf76cba4d962686f4a2bb070270705cdf9cd7ffc4d38e07c2ba4498d0b",
    "optech_example1": "c8cbc1ccbfec881187059f9d373037f080893ad18a7ae590be7d2bfc5f4ba121",
    "riegl_example3": "3800f8b0c16f45c95fcecac6703418980080f62d895d43b967fdd0684818bad9",
}


def _decoded_hash(batch) -> str:
    import hashlib

    h = hashlib.sha256()
    for i in range(len(batch)):
        s = batch.pulse_samples(i)
        h.update(np.int64(batch.pulse_id[i]).tobytes() + np.int16(batch.channels()[i]).tobytes()
                 + np.float64(batch.anchor_location_ps[i]).tobytes() + np.float64(batch.sample_spacing_ps[i]).tobytes()
                 + np.int64(s.size).tobytes() + np.ascontiguousarray(s, np.float64).tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_every_shared_file_decodes_bit_for_bit_as_before(pulsewaves_dir, name):
    assert _decoded_hash(read_pulses(pulsewaves_dir / f"{name}.pls")) == DECODED[name]


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_pulses_planned_are_the_pulses_read(pulsewaves_dir, name):
    """Planned = read (waveforms + pulses rejected), range by range: a pulse with two returning channels
    or segments is one pulse (riegl_example3 read 16,487 of its 16,486 planned)."""
    ranges = plan_point_ranges(pulsewaves_dir / f"{name}.pls", 700)
    read = 0
    for r in ranges:
        batch = read_pulses(r)
        pulses_rejected = sum(1 for pulse_id, _ in batch.rejected if pulse_id >= 0)
        assert len(batch) + pulses_rejected == r.n_pulses == np.unique(batch.pulse_id).size + pulses_rejected
        read += len(batch) + pulses_rejected
    assert sum(r.n_pulses for r in ranges) == read == SAMPLES[name][0]


def test_a_range_of_riegl_example3_decomposes_or_rejects_every_pulse_it_planned(pulsewaves_dir, tmp_path):
    """The range that holds the pulse of two channels, through the run's stages without Beam: planned = read =
    decomposed + rejected (it read 501 of 500 before)."""
    from fwcore.engine.config import DecompositionConfig, Model
    from pipeline.plan import plan_file, planned_pulses
    from pipeline.stages import RangeSettings, run_range

    config = DecompositionConfig(model=Model.GAUSSIAN)
    path = pulsewaves_dir / "riegl_example3.pls"
    tasks = plan_file(str(path), path.name, path.stem, config, 500, None)
    assert sum(planned_pulses(t) for t in tasks) == 16486
    batch = read_pulses(path)
    start = int(np.flatnonzero(batch.descriptor_index == 3)[0])  # one waveform a pulse: its row is its record
    (task,) = [t for t in tasks if t.point_range.start <= start < t.point_range.stop]
    outcome = run_range(task, RangeSettings(str(tmp_path), config, frozenset({"parquet"})))
    assert outcome.pulses_read == planned_pulses(task) == 500
    assert outcome.pulses_decomposed + outcome.pulses_rejected == 500 and outcome.problems == 0
