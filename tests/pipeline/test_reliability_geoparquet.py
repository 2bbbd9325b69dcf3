"""The echo table is GeoParquet 1.1 (points, WKB, the input's CRS as PROJJSON); rejected/ is always there."""

import json
import shutil

import duckdb
import geopandas
import laspy
import numpy as np
import pyarrow.parquet as pq
import pyproj
import pytest

from pipeline.cli import main
from pipeline.tables import wkb_points

QUICK = ["--preset", "fast", "--limit", "30", "--points-per-range", "300", "--direct_num_workers=1",
         "--direct_running_mode=in_memory", "--formats", "parquet"]


@pytest.fixture(scope="module")
def utm_run(tmp_path_factory, leica_dir):
    """The Leica sample with its CRS said to be WGS 84 / UTM 32N (EPSG:32632), and its run."""
    data = tmp_path_factory.mktemp("utm")
    las = laspy.read(leica_dir / "leica_a.las")
    las.header.add_crs(pyproj.CRS.from_epsg(32632))
    las.write(data / "utm.las")
    shutil.copy(leica_dir / "leica_a.wdp", data / "utm.wdp")
    out = data / "out"
    assert main(["run", str(data / "utm.las"), "--output", str(out)] + QUICK) == 0
    return out


def test_echo_parts_carry_geoparquet_metadata_with_the_inputs_crs(utm_run):
    for part in sorted((utm_run / "echoes").glob("*.parquet")):
        geo = json.loads(pq.read_schema(part).metadata[b"geo"])
        assert geo["version"] == "1.1.0" and geo["primary_column"] == "geometry"
        column = geo["columns"]["geometry"]
        assert column["encoding"] == "WKB" and column["geometry_types"] == ["Point Z"]
        assert pyproj.CRS.from_json_dict(column["crs"]).to_epsg() == 32632
        table = pq.read_table(part, columns=["x", "y", "z"]).to_pandas()
        assert column["bbox"] == [table.x.min(), table.y.min(), table.z.min(),
                                  table.x.max(), table.y.max(), table.z.max()]


def test_geopandas_opens_the_echo_table_as_points(utm_run):
    frame = geopandas.read_parquet(utm_run / "echoes")
    assert len(frame) > 30 and frame.crs.to_epsg() == 32632
    assert (frame.geometry.geom_type == "Point").all() and frame.geometry.has_z.all()
    np.testing.assert_array_equal(frame.geometry.x, frame.x)
    np.testing.assert_array_equal(frame.geometry.y, frame.y)
    np.testing.assert_array_equal(frame.geometry.z, frame.z)
    assert {"x", "y", "z", "kept", "fwhm_ps"} <= set(frame.columns)


def test_the_pulse_table_is_geoparquet_a_point_per_pulse_at_its_anchor(utm_run):
    from fwcore.io import read_pulses

    frame = geopandas.read_parquet(utm_run / "pulses")
    assert len(frame) == 30 and frame.crs.to_epsg() == 32632 and frame.geometry.has_z.all()
    pulses = read_pulses(utm_run.parent / "utm.las")
    anchor = dict(zip(pulses.pulse_id.tolist(), pulses.anchor.tolist()))
    np.testing.assert_array_equal(np.stack([frame.geometry.x, frame.geometry.y, frame.geometry.z], axis=1),
                                  [anchor[p] for p in frame.pulse_id])
    for part in sorted((utm_run / "pulses").glob("*.parquet")):
        column = json.loads(pq.read_schema(part).metadata[b"geo"])["columns"]["geometry"]
        points = geopandas.read_parquet(part).geometry
        assert column["bbox"] == [points.x.min(), points.y.min(), points.z.min(),
                                  points.x.max(), points.y.max(), points.z.max()]


def test_an_input_without_a_crs_says_unknown_not_crs84(tmp_path, leica_dir):
    las = laspy.read(leica_dir / "leica_a.las")
    las.header.vlrs = [v for v in las.header.vlrs if v.record_id != 34735]  # no GeoTIFF keys: nothing said
    las.write(tmp_path / "bare.las")
    shutil.copy(leica_dir / "leica_a.wdp", tmp_path / "bare.wdp")
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "bare.las"), "--output", str(out)] + QUICK) == 0
    part = sorted((out / "echoes").glob("*.parquet"))[0]
    assert json.loads(pq.read_schema(part).metadata[b"geo"])["columns"]["geometry"]["crs"] is None
    assert geopandas.read_parquet(part).crs is None


def test_crs_names_the_crs_of_every_output(tmp_path, leica_dir, capfd):
    from mcap.reader import make_reader

    out = tmp_path / "out"
    args = ["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--crs", "EPSG:25832"]
    assert main(args + QUICK[:-1] + ["parquet,las,mcap"]) == 0
    said = [line for line in capfd.readouterr().out.splitlines() if "CRS" in line]
    assert said == ["fwl run: CRS EPSG:25832 (ETRS89 / UTM zone 32N) assigned by --crs to 1 input(s), whatever "
                    "they say"]
    las = laspy.read(out / "las" / "leica_a.las")
    assert las.header.global_encoding.wkt and las.header.parse_crs().to_epsg() == 25832
    assert geopandas.read_parquet(out / "echoes").crs.to_epsg() == 25832
    assert geopandas.read_parquet(out / "pulses").crs.to_epsg() == 25832
    with open(out / "mcap" / "leica_a.mcap", "rb") as f:
        reader = make_reader(f)
        wkt = {m.name: m.metadata["wkt"] for m in reader.iter_metadata()}["crs"]
        channels = {c.topic: c.metadata for c in reader.get_summary().channels.values()}
    assert pyproj.CRS.from_wkt(wkt).to_epsg() == 25832 and channels["/echoes"]["crs"] == wkt
    summary = json.loads((out / "run.json").read_text())
    assert summary["crs"] == "EPSG:25832" and summary["inputs"][0]["crs"]["source"] == "--crs"


def test_keys_with_only_a_unit_give_an_unnamed_crs_said_once(tmp_path, leica_dir, capfd):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out)] + QUICK[:-1] + ["parquet,las"]) == 0
    said = [line for line in capfd.readouterr().out.splitlines() if "CRS" in line]
    assert said == ["fwl run: leica_a.las name(s) no CRS, only its unit: written as unnamed projected CRS (metre); "
                    "give --crs (an EPSG code, WKT or PROJJSON) to name it"]
    las = laspy.read(out / "las" / "leica_a.las")
    crs = las.header.parse_crs()
    assert las.header.global_encoding.wkt and crs.is_engineering and crs.axis_info[0].unit_name == "metre"
    assert geopandas.read_parquet(out / "echoes").crs == crs


def test_a_crs_pyproj_cannot_read_is_a_usage_error_before_anything_is_written(tmp_path, leica_dir, capfd):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--crs", "EPSG:12"] + QUICK) == 2
    assert "--crs 'EPSG:12' is not a coordinate reference system" in capfd.readouterr().err
    assert not out.exists()


def test_rejected_is_written_without_rows_when_nothing_is_rejected(utm_run):
    assert [p.name for p in (utm_run / "rejected").iterdir()] == ["utm.parquet"]
    (count,), = duckdb.sql(f"SELECT count(*) FROM read_parquet('{utm_run}/rejected/*.parquet')").fetchall()
    assert count == 0
    assert pq.read_schema(utm_run / "rejected" / "utm.parquet").names == ["source_file", "pulse_id", "stage", "reason"]


def test_wkb_points_are_iso_point_z_and_null_where_not_finite():
    from shapely import wkb
    points = wkb_points(np.array([1.5, np.nan]), np.array([2.0, 0.0]), np.array([3.25, 0.0]))
    first = wkb.loads(points[0].as_py())
    assert (first.x, first.y, first.z) == (1.5, 2.0, 3.25) and points[1].as_py() is None


def test_the_echo_table_has_a_bbox_covering_that_geopandas_and_duckdb_filter_on(utm_run):
    from fwcore.spatial import hilbert_key, square_bounds

    for part in sorted((utm_run / "echoes").glob("*.parquet")):
        column = json.loads(pq.read_schema(part).metadata[b"geo"])["columns"]["geometry"]
        assert column["covering"] == {"bbox": {f: ["bbox", f] for f in ("xmin", "ymin", "xmax", "ymax")}}
        table = pq.read_table(part, columns=["x", "y", "bbox"]).to_pandas()
        bbox = table.bbox.apply(lambda b: (b["xmin"], b["ymin"], b["xmax"], b["ymax"])).tolist()
        assert bbox == list(zip(table.x, table.y, table.x, table.y))
        x, y = table.x.to_numpy(), table.y.to_numpy()
        key = hilbert_key(x, y, square_bounds((x.min(), y.min(), x.max(), y.max())))
        assert (np.diff(key.astype(np.int64)) >= 0).all()  # each part's rows in Hilbert order
    every = geopandas.read_parquet(utm_run / "echoes")
    x0, x1 = np.quantile(every.x, [0.3, 0.7])
    y0, y1 = np.quantile(every.y, [0.3, 0.7])
    inside = every[every.x.between(x0, x1) & every.y.between(y0, y1)]
    found = geopandas.read_parquet(utm_run / "echoes", bbox=(x0, y0, x1, y1))
    assert 0 < len(found) < len(every) and found.crs.to_epsg() == 32632
    key = ["pulse_id", "echo_index"]
    assert found.sort_values(key)[key].values.tolist() == inside.sort_values(key)[key].values.tolist()
    (count,), = duckdb.sql(f"SELECT count(*) FROM read_parquet('{utm_run}/echoes/*.parquet') WHERE bbox.xmin <= {x1} "
                           f"AND bbox.xmax >= {x0} AND bbox.ymin <= {y1} AND bbox.ymax >= {y0}").fetchall()
    assert count == len(inside)
