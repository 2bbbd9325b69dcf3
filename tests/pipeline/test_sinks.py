"""Sinks: assembled point clouds independent of the range size, MCAP time stamps and schema, the run's options
and its terminal output."""

import json
import subprocess
import sys

import laspy
import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.cli import main
from pipeline.run import run
from pipeline.sinks import WAVEFORM_FIELDS, decode_waveforms, stamp_ns, waveforms_schema

FAST = DecompositionConfig(optimizer="lm", lm_iterations=5)


# A single range has nothing to spread over workers: it runs in process (a pool of worker processes costs
# about 4 s a run). The runs of many ranges keep the default pool, whose parts end in any order.
IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]


@pytest.fixture(scope="module")
def two_range_sizes(tmp_path_factory, leica_dir):
    out = tmp_path_factory.mktemp("ranges")
    source = [str(leica_dir / "leica_a.las")]
    run(source, out / "one", FAST, ("las", "mcap"), points_per_range=5000, beam_args=IN_PROCESS, watch=False)
    run(source, out / "many", FAST, ("las", "mcap"), points_per_range=250, watch=False)
    run(source, out / "laz-one", FAST, ("las",), points_per_range=5000, laz=True, beam_args=IN_PROCESS,
        watch=False)
    run(source, out / "laz-many", FAST, ("las",), points_per_range=250, laz=True, watch=False)
    return out


def test_the_assembled_las_does_not_depend_on_the_range_size(two_range_sizes):
    one = (two_range_sizes / "one" / "las" / "leica_a.las").read_bytes()
    many = (two_range_sizes / "many" / "las" / "leica_a.las").read_bytes()
    assert len(one) > 50_000 and one == many
    assert json.loads((two_range_sizes / "many" / "run.json").read_text())["ranges"] == 5


def test_the_assembled_laz_does_not_depend_on_the_range_size(two_range_sizes):
    one = (two_range_sizes / "laz-one" / "las" / "leica_a.laz").read_bytes()
    assert one == (two_range_sizes / "laz-many" / "las" / "leica_a.laz").read_bytes()
    las = laspy.read(two_range_sizes / "laz-one" / "las" / "leica_a.laz")
    plain = laspy.read(two_range_sizes / "one" / "las" / "leica_a.las")
    assert las.points.array.tobytes() == plain.points.array.tobytes()  # bytes: NaN (no radiometry) is not == NaN


def test_the_assembled_las_keeps_header_crs_and_extra_bytes(two_range_sizes, leica_dir):
    las = laspy.read(two_range_sizes / "many" / "las" / "leica_a.las")
    source = laspy.read(leica_dir / "leica_a.las")
    assert np.allclose(las.header.scales, source.header.scales) and np.allclose(las.header.offsets,
                                                                                  source.header.offsets)
    projection = [v for v in las.header.vlrs if v.user_id.rstrip("\0") == "LASF_Projection"]
    assert projection and any(v.user_id.rstrip("\0") == "LASF_Projection" for v in source.header.vlrs)
    assert {"amplitude", "echo_width", "alpha"} <= set(las.point_format.extra_dimension_names)
    # the header's counts and bounds are those of the points, whatever the parts were
    assert las.header.point_count == len(las.points)
    np.testing.assert_allclose(las.header.mins, [las.x.min(), las.y.min(), las.z.min()])
    counts = np.bincount(las.return_number, minlength=16)[1:]
    np.testing.assert_array_equal(las.header.number_of_points_by_return, counts[:15])
    # points in file order: pulse by pulse, returns in order within each
    gps = np.asarray(las.gps_time)
    assert (np.diff(las.return_number)[np.diff(gps) == 0] == 1).all()


def test_mcap_of_many_ranges_has_every_pulse_once_in_order(two_range_sizes):
    from mcap.reader import make_reader
    ids = {}
    for name in ("one", "many"):
        with open(two_range_sizes / name / "mcap" / "leica_a.mcap", "rb") as f:
            reader = make_reader(f)
            channels = reader.get_summary().channels
            ids[name] = [int(p) for _, c, m in reader.iter_messages(topics=["/waveform"])
                         for p in decode_waveforms(m.data)["pulse_id"]]
        assert "week" in next(c for c in channels.values() if c.topic == "/waveform").metadata["log_time"]
    assert len(ids["one"]) == 924 and ids["one"] == ids["many"]


def test_gps_time_stamps():
    # 2020-01-01T00:00:00Z is GPS second 1,261,872,018 (18 leap seconds since 1980): adjusted 261,872,018
    assert stamp_ns(261_872_018.0, adjusted_standard=True) == 1_577_836_800 * 10**9
    # 2010-01-01T00:00:00Z: 15 leap seconds
    assert stamp_ns(1_262_304_000 - 315_964_800 + 15 - 1e9, adjusted_standard=True) == 1_262_304_000 * 10**9
    assert stamp_ns(345_600.25, adjusted_standard=False) == 345_600_250_000_000


def test_waveform_schema_is_a_protobuf_any_reader_decodes():
    from google.protobuf import descriptor_pb2

    files = descriptor_pb2.FileDescriptorSet.FromString(waveforms_schema()).file
    fields = {f.name: f for f in files[0].message_type[0].field}
    assert files[0].package == "fwlidar" and files[0].message_type[0].name == "Waveforms"
    assert [f.number for f in fields.values()] == list(range(1, len(WAVEFORM_FIELDS) + 2))
    assert fields["raw"].type == descriptor_pb2.FieldDescriptorProto.TYPE_FLOAT
    assert fields["reject_reasons"].type == descriptor_pb2.FieldDescriptorProto.TYPE_STRING


def _views() -> dict[str, np.ndarray]:
    """Three pulses' MCAP views (pipeline.stages.waveform_views' arrays), by hand."""
    return {"pulse_id": np.array([5, -7, 9]), "gps_time": np.array([1.5, 2.25, 3.0]),
            "sample_spacing_ps": np.array([1000.0, 1000.0, 500.0]), "sample_offsets": np.array([0, 3, 5, 9]),
            "raw": np.arange(9, dtype=np.float32), "model": np.linspace(0, 1, 9).astype(np.float32),
            "echo_offsets": np.array([0, 2, 2, 3]), "echo_time_ps": np.array([100.0, 2000.5, 7.0]),
            "echo_amplitude": np.array([3.0, 4.0, 5.0]), "echo_fwhm_ps": np.array([4000.0, 4100.0, 4200.0]),
            "echo_reject": np.array([0, 2, 0], dtype=np.int8)}


def test_waveform_messages_round_trip_the_ranges_arrays():
    from fwcore.engine.filter import REJECT_REASONS
    from pipeline.sinks import _waveforms_message

    views = _views()
    got = decode_waveforms(_waveforms_message(views, 1, 3))  # the last two pulses: offsets from 0 again
    np.testing.assert_array_equal(got["pulse_id"], [-7, 9])
    np.testing.assert_array_equal(got["sample_offsets"], [0, 2, 6])
    np.testing.assert_array_equal(got["raw"], [3, 4, 5, 6, 7, 8])
    np.testing.assert_array_equal(got["echo_offsets"], [0, 0, 1])
    np.testing.assert_array_equal(got["echo_time_ps"], [7.0])
    np.testing.assert_array_equal(got["echo_reject"], [0])
    assert got["reject_reasons"] == list(REJECT_REASONS)


def test_a_range_part_is_written_in_lz4_and_its_assembled_file_in_zstd(tmp_path):
    # zstd once, in the file a user opens: the part is read once, by the assembly, and removed
    from mcap.reader import make_reader
    from pipeline.sinks import assemble_mcap, write_mcap

    cloud = {"pulse_id": np.array([5, 5, 9]), "gps_time": np.array([1.5, 1.5, 3.0]), "x": np.array([10.0, 10.5, 11.0]),
             "y": np.array([20.0, 20.0, 21.0]), "z": np.array([5.0, 3.0, 1.0]), "amplitude": np.array([3.0, 4.0, 5.0]),
             "echo_width": np.array([4.0, 4.1, 4.2]), "return_number": np.array([1, 2, 1])}
    part = write_mcap(tmp_path / "part.mcap", cloud, _views(), adjusted_standard=False)
    whole = assemble_mcap([part], tmp_path / "whole.mcap", adjusted_standard=False)

    def compressions_and_messages(path):
        with open(path, "rb") as f:
            reader = make_reader(f)
            return ({c.compression for c in reader.get_summary().chunk_indexes},
                    [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()])

    (part_kinds, part_messages), (whole_kinds, whole_messages) = map(compressions_and_messages, (part, whole))
    assert part_kinds == {"lz4"} and whole_kinds == {"zstd"}
    assert [t for t, _, _ in whole_messages] == ["/echoes", "/waveform"] and whole_messages == part_messages
    np.testing.assert_array_equal(decode_waveforms(whole_messages[1][2])["pulse_id"], [5, -7, 9])


def test_a_part_holds_dictionaries_only_for_the_columns_whose_values_repeat(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    from pipeline.sinks import dictionary_columns, write_part

    n = 500
    table = pa.table({"reason": ["weak", ""] * (n // 2), "pulse_id": np.repeat(np.arange(n // 5), 5),
                      "x": np.random.default_rng(3).normal(size=n),
                      "rh": pa.array([[0.5, 1.25]] * n, pa.list_(pa.float32()))})
    assert dictionary_columns(table.schema) == ["reason", "pulse_id", "rh.list.element"]
    path = write_part(table, tmp_path, "part")
    meta = pq.ParquetFile(path).metadata.row_group(0)
    dictionary = {meta.column(i).path_in_schema: meta.column(i).has_dictionary_page for i in range(meta.num_columns)}
    assert dictionary == {"reason": True, "pulse_id": True, "x": False, "rh.list.element": True}
    assert pq.read_table(path).equals(table)


def test_a_mistyped_option_fails_with_its_name(tmp_path, capsys):
    assert main(["run", "--generatoins", "5", "--output", str(tmp_path / "out")]) == 2
    assert "unknown option --generatoins (did you mean --generations?)" in capsys.readouterr().err
    assert main(["run", "--direct_num_wrkers=2", "--output", str(tmp_path / "out")]) == 2
    assert "did you mean --direct_num_workers?" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_impossible_value_is_refused_not_replaced(tmp_path, capsys):
    assert main(["run", "--system-pulse-fwhm-ps", "0", "--output", str(tmp_path / "out")]) == 2
    assert "system pulse FWHM must be positive" in capsys.readouterr().err


def test_the_default_output_of_a_run_is_a_handful_of_lines(tmp_path):
    out = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "--output", str(tmp_path / "out"),
                          "--limit", "100", "--optimizer", "none"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = (out.stdout + out.stderr).splitlines()
    assert lines[0].startswith("fwl run: 1 file(s), 100 pulses in 1 ranges")
    assert "DirectRunner, in this process" in lines[0]  # a small run starts no worker processes
    assert len(lines) <= 5, lines  # start, no radiometry, the unnamed CRS, counts, time
    assert any(p.name == "driver.log" for p in (tmp_path / "out" / "logs").iterdir())
    driver = (tmp_path / "out" / "logs" / "driver.log").read_text()
    assert "Prism" not in driver  # the DirectRunner did not try to download another engine


def test_a_file_whose_parts_hold_no_point_is_assembled_with_no_min_or_max(tmp_path, leica_dir):
    """Every pulse of a file rejected: its parts are point clouds without points, and each Extra Bytes column,
    float or integer, has no value to bound (an integer one cannot say NaN: its min/max are marked irrelevant)."""
    from fwcore.io.writer import write_point_cloud
    from pipeline.sinks import assemble_las

    empty = {k: np.zeros(0) for k in ("x", "y", "z", "gps_time", "return_number", "number_of_returns", "intensity",
                                      "scan_angle", "scan_direction_flag", "edge_of_flight_line", "point_source_id",
                                      "user_data")}
    parts = [write_point_cloud(tmp_path / f"part{i}.las", leica_dir / "leica_a.las", empty) for i in range(2)]
    path = assemble_las(parts, tmp_path / "file.las")
    las = laspy.read(path)
    assert len(las.points) == 0
    structs = {s.format_name(): s for s in las.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs}
    assert structs["radiometry"].min is None and structs["radiometry"].max is None
    assert np.isnan(structs["amplitude"].min).all() and np.isnan(structs["amplitude"].max).all()


def test_the_parts_are_read_ahead_in_order_and_a_reading_error_reaches_the_writer():
    import threading

    from pipeline.sinks import _read_ahead

    assert list(_read_ahead(iter(range(10_000)), depth=8)) == list(range(10_000))

    def broken():
        yield 1
        raise OSError("a part cannot be read")

    with pytest.raises(OSError, match="cannot be read"):
        list(_read_ahead(broken()))
    before = threading.active_count()
    ahead = _read_ahead(iter(range(10_000)), depth=2)
    assert next(ahead) == 0
    ahead.close()  # the writer failed: the reading thread ends too
    assert threading.active_count() == before
