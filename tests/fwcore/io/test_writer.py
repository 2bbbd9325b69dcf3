import laspy
import numpy as np
import pyproj
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.io import read_pulses
from fwcore.io.las import open_waveform_file, plan_las_ranges, read_las_pulses
from fwcore.io.writer import WaveformLasWriter, point_cloud_template, write_point_cloud, write_waveform_las
from fwcore.pulses import decomposed_echoes, pulse_waveforms
from fwcore.instrument.measure import file_system_pulse
from fwcore.instrument.pulse import nominal_pulse


@pytest.fixture(scope="module")
def leica(leica_dir):
    return read_pulses(leica_dir / "leica_a.las")


@pytest.fixture(scope="module")
def leica_result(leica, leica_dir):
    """The sample decomposed once for the point-cloud tests, on its system pulse measured as `fwl run` measures
    it (the default 4 ns pulse, a third of Leica's, makes every waveform a slow many-echo fit: 18 s, not 1)."""
    pulse = file_system_pulse(leica_dir / "leica_a.las", len(leica.return_number), DecompositionConfig())
    config = DecompositionConfig(generations=10)
    return decompose_batch(pulse_waveforms(leica, 0), config, nominal_pulse(pulse.fwhm_ps, pulse.shape_tolerance))


def test_las13_wdp_round_trip(tmp_path, leica):
    path = write_waveform_las(tmp_path / "a.las", leica, "las13-wdp", 8)
    assert (tmp_path / "a.wdp").exists()
    back = read_pulses(path)
    np.testing.assert_array_equal(back.samples, leica.samples)
    np.testing.assert_allclose(back.return_xyz, leica.return_xyz, atol=5e-4)
    np.testing.assert_array_equal(back.gps_time, leica.gps_time)
    las = laspy.read(path)
    assert las.header.version.minor == 3 and las.header.point_format.id == 4 and len(las.points) == 1125
    # the sample is clipped to a plot: 16 pulses hold fewer returns than they had, and a rewrite says so too
    np.testing.assert_array_equal(back.number_of_returns, leica.number_of_returns)
    assert (np.asarray(las.return_number) <= np.asarray(las.number_of_returns)).all()


def test_las14_internal_packets_with_several_descriptors_round_trip(tmp_path, leica):
    bits = np.where(np.arange(len(leica)) % 3 == 0, 16, 8)
    path = write_waveform_las(tmp_path / "b.las", leica, "las14-internal", bits)
    las = laspy.read(path)
    assert las.header.version.minor == 4 and las.header.point_format.id == 9
    assert las.header.global_encoding.waveform_data_packets_internal
    back = read_pulses(path)
    assert sorted(set(back.descriptor_index.tolist())) == [1, 2]
    assert set(back.bits_per_sample.tolist()) == {8, 16}
    np.testing.assert_array_equal(back.samples, leica.samples)
    np.testing.assert_array_equal(back.return_number, leica.return_number)
    np.testing.assert_array_equal(back.return_location_ps, leica.return_location_ps.astype(np.float32))


def test_planned_ranges_of_las14_internal_packets_read_without_the_evlrs(tmp_path, leica):
    # LAS 1.4 keeps the packets in an EVLR: a range reads its points and packets without loading it
    path = write_waveform_las(tmp_path / "c.las", leica, "las14-internal", 8)
    whole = read_pulses(path)
    parts = [read_las_pulses(r) for r in plan_las_ranges(path, 500)]
    ids = np.concatenate([p.pulse_id for p in parts])
    assert len(parts) == 3 and sorted(ids.tolist()) == sorted(whole.pulse_id.tolist())
    assert sum(float(p.samples.sum()) for p in parts) == float(whole.samples.sum())
    unread, read = open_waveform_file(path, read_evlrs=False), open_waveform_file(path)
    assert unread == read  # every field: the EVLRs add nothing a range reads


def _tiny_las(path, scale, n):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, scale)
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(n, dtype=float), np.zeros(n), np.zeros(n)
    las.write(path)


def test_the_point_cloud_template_is_read_once_per_version_of_its_file(tmp_path):
    path = tmp_path / "t.las"
    _tiny_las(path, 0.01, 3)
    first = point_cloud_template(path)
    first["wkt"] = "changed by a caller"
    again = point_cloud_template(path)
    assert again["wkt"] != "changed by a caller" and list(again["scales"]) == [0.01] * 3
    _tiny_las(path, 0.001, 4)  # the file rewritten: its new header, not the one read before
    assert list(point_cloud_template(path)["scales"]) == [0.001] * 3


def test_decomposed_point_cloud(tmp_path, leica, leica_dir, leica_result):
    pulses, result = leica, leica_result
    echoes = decomposed_echoes(pulses, result)
    path = write_point_cloud(tmp_path / "cloud.laz", leica_dir / "leica_a.las", echoes)
    las = laspy.read(path)
    assert las.header.version.minor == 4 and las.header.point_format.id == 6
    assert len(las.points) == (result.reject == 0).sum()
    assert {"amplitude", "echo_width", "alpha", "echo_energy", "fit_error"} <= set(
        las.point_format.extra_dimension_names)
    assert "sigma" not in las.point_format.extra_dimension_names
    # FWHM in ps: 2 ns sampling
    np.testing.assert_allclose(np.asarray(las.echo_width), result.fwhm[result.reject == 0] * 2000.0, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(las.classification), 1)  # unclassified: what the echoes are
    assert las.header.system_identifier.rstrip("\0") == "ALSXX"
    np.testing.assert_allclose(las.x, echoes["x"], atol=5e-4)
    np.testing.assert_allclose(np.asarray(las.amplitude), echoes["amplitude"], rtol=1e-6)
    # return numbers run 1..n in time order within each pulse
    returns, totals = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    assert (returns >= 1).all() and (returns <= totals).all()
    # the sample's GeoTIFF keys say "projected, metres" and name no CRS: an unnamed CRS in metres, as WKT with
    # the WKT bit (formats 6-10 carry no GeoTIFF keys)
    crs = las.header.parse_crs()
    assert las.header.global_encoding.wkt and crs.is_engineering and crs.to_epsg() is None
    assert {a.unit_name for a in crs.axis_info} == {"metre"}
    assert not any(isinstance(v, laspy.vlrs.known.GeoKeyDirectoryVlr) for v in las.header.vlrs)
    assert las.header.scales.tolist() == [0.001, 0.001, 0.001]


def test_point_cloud_crs_is_ogc_wkt_from_the_inputs_geotiff_keys(tmp_path, leica, leica_dir, leica_result):
    import struct

    las = laspy.read(leica_dir / "leica_a.las")
    keys = struct.pack("<16H", 1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32632)
    las.header.vlrs = [v for v in las.header.vlrs if v.record_id != 34735]
    las.header.vlrs.append(laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", keys))
    template = tmp_path / "utm32.las"
    las.write(template)
    path = write_point_cloud(tmp_path / "cloud.las", template, decomposed_echoes(leica, leica_result))
    back = laspy.read(path)
    assert back.header.global_encoding.wkt
    wkt = [v for v in back.header.vlrs if v.record_id == 2112]
    assert len(wkt) == 1 and "WGS 84 / UTM zone 32N" in wkt[0].string
    assert back.header.parse_crs().to_epsg() == 32632
    assert not any(v.record_id == 34735 for v in back.header.vlrs)  # formats 6-10 carry WKT, not GeoTIFF keys
    given = write_point_cloud(tmp_path / "given.las", template, decomposed_echoes(leica, leica_result),
                              crs_wkt=pyproj.CRS.from_epsg(25832).to_wkt("WKT1_GDAL"))  # --crs: not the keys
    assert laspy.read(given).header.parse_crs().to_epsg() == 25832


@pytest.mark.parametrize("layout, mixed", [("las13-wdp", False), ("las14-wdp", True), ("las14-internal", True)])
def test_written_batch_by_batch_the_file_is_the_same_bytes(tmp_path, leica_dir, leica, layout, mixed):
    ranges = plan_las_ranges(leica_dir / "leica_a.las", 400)
    assert len(ranges) == 3
    batches = [read_pulses(r) for r in ranges]

    def bits(n, first):  # every third pulse at 16 bits: two descriptors, both in the first batch
        return np.where((first + np.arange(n)) % 3 == 0, 16, 8) if mixed else 8

    whole = write_waveform_las(tmp_path / "whole.las", leica, layout, bits(len(leica), 0))
    with WaveformLasWriter(tmp_path / "parts.las", layout) as writer:
        first = 0
        for batch in batches:
            writer.write(batch, bits(len(batch), first))
            first += len(batch)
    assert whole.read_bytes() == (tmp_path / "parts.las").read_bytes()
    if layout != "las14-internal":
        assert (tmp_path / "whole.wdp").read_bytes() == (tmp_path / "parts.wdp").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["whole.las", "parts.las"] + (["whole.wdp", "parts.wdp"] if layout != "las14-internal" else []))


def test_a_later_batch_with_a_new_descriptor_is_refused_and_the_partial_file_removed(tmp_path, leica_dir):
    first, second = (read_pulses(r) for r in plan_las_ranges(leica_dir / "leica_a.las", 400)[:2])
    with pytest.raises(ValueError, match="kind the first batch did not"):
        with WaveformLasWriter(tmp_path / "x.las", "las14-internal") as writer:
            writer.write(first, 8)
            writer.write(second, 16)
    assert list(tmp_path.iterdir()) == []


def test_every_echo_is_unclassified_whatever_its_pulses_points_were(leica, leica_result):
    """One rule for every sensor (RIEGL and simulated points carry 0, Leica's 1, a classified file 2 or 5):
    LAS class 1, unclassified, for the echoes the decomposition made."""
    import dataclasses

    for given in (None, 0, 2):
        classes = None if given is None else np.full(len(leica.classification), given, np.uint8)
        echoes = decomposed_echoes(dataclasses.replace(leica, classification=classes), leica_result)
        assert echoes["classification"].size == (leica_result.reject == 0).sum()
        np.testing.assert_array_equal(echoes["classification"], 1)
