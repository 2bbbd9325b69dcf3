"""A run's echo table read for its maps: the files, the bounds from the row groups' statistics or from the rows,
the kept and placed echoes by batch, and the one CRS of the GeoParquet metadata."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pyproj
import pytest

from pipeline.echo_table import column_max, echo_bounds, echo_files, kept_batches, run_crs_wkt
from pipeline.tables import geo_metadata

X = np.array([5.0, -2.0, np.nan, 7.5, 3.0])
Y = np.array([1.0, 4.0, 2.0, np.nan, -6.0])
KEPT = [True, True, True, True, None]  # the last: kept unknown, not mapped


def _table(run, name: str, x, y, kept, crs: pyproj.CRS | None = None, statistics: bool = True):
    z = np.zeros(len(x))
    table = pa.table({"x": x, "y": y, "z": z, "kept": pa.array(kept, pa.bool_())})
    projjson = crs.to_json() if crs else None
    table = table.replace_schema_metadata(geo_metadata(np.asarray(x), np.asarray(y), z, projjson))
    (run / "echoes").mkdir(parents=True, exist_ok=True)
    pq.write_table(table, run / "echoes" / name, write_statistics=statistics)


def test_the_kept_placed_echoes_come_by_batch_and_the_bounds_agree(tmp_path):
    _table(tmp_path, "a.parquet", X, Y, KEPT)
    _table(tmp_path, "b.parquet", [10.0, 0.0], [20.0, -1.0], [False, True])
    files = echo_files(tmp_path)
    assert [f.name for f in files] == ["a.parquet", "b.parquet"]
    rows = list(kept_batches(files, ["x", "y"]))
    np.testing.assert_array_equal(np.concatenate([b["x"] for b in rows]), [5.0, -2.0, 0.0])  # NaN or null: out
    np.testing.assert_array_equal(np.concatenate([b["y"] for b in rows]), [1.0, 4.0, -1.0])
    # the statistics span every row, kept or not (a map's extent), NaN left out
    assert echo_bounds(files) == (-2.0, -6.0, 10.0, 20.0)


def test_bounds_without_statistics_are_read_from_the_kept_rows(tmp_path):
    _table(tmp_path, "a.parquet", X, Y, KEPT, statistics=False)
    assert echo_bounds(echo_files(tmp_path)) == (-2.0, 1.0, 5.0, 4.0)


def test_a_columns_largest_value_from_the_statistics_or_the_kept_rows(tmp_path):
    for statistics, folder in ((True, tmp_path / "stats"), (False, tmp_path / "read")):
        _table(folder, "a.parquet", X, Y, KEPT, statistics=statistics)
        _table(folder, "b.parquet", [10.0, 0.0], [20.0, -1.0], [False, True], statistics=statistics)
        for f in echo_files(folder):  # fwl classify's height: null where not kept and placed, NaN where unknown
            t = pq.read_table(f)
            kept = np.asarray(t.column("kept").fill_null(False)) & np.isfinite(t.column("x").to_numpy(False)) & \
                np.isfinite(t.column("y").to_numpy(False))
            h = np.array([3.0, np.nan, 9.0, 4.0, 2.0])[:t.num_rows] + (f.name == "b.parquet")
            pq.write_table(t.append_column("height", pa.array(h, mask=~kept)), f, write_statistics=statistics)
        assert column_max(echo_files(folder), "height", default=0.0) == 3.0  # b.parquet's 4.0 is not kept
    _table(tmp_path / "none", "a.parquet", [1.0], [1.0], [False])
    f = echo_files(tmp_path / "none")[0]
    pq.write_table(pq.read_table(f).append_column("height", pa.array([np.nan])), f)
    assert column_max([f], "height", default=0.0) == 0.0


def test_a_run_without_an_echo_table_is_refused(tmp_path):
    with pytest.raises(ValueError, match="the run has no echo table"):
        echo_files(tmp_path)


def test_the_runs_crs_is_its_inputs_one_crs(tmp_path):
    utm = pyproj.CRS.from_epsg(25832)
    _table(tmp_path / "one", "a.parquet", X, Y, KEPT, utm)
    _table(tmp_path / "one", "b.parquet", X, Y, KEPT)  # an input that names none
    assert pyproj.CRS.from_wkt(run_crs_wkt(echo_files(tmp_path / "one"))).to_epsg() == 25832
    _table(tmp_path / "two", "a.parquet", X, Y, KEPT, utm)
    _table(tmp_path / "two", "b.parquet", X, Y, KEPT, pyproj.CRS.from_epsg(32633))
    with pytest.raises(ValueError, match="2 different CRSs"):
        run_crs_wkt(echo_files(tmp_path / "two"))
