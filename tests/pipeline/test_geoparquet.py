"""The echo table's spatial index: rows in Hilbert order (neighbours on the ground, neighbours in the file, rows
without a position last), and the row groups a box query reads, judged by their bbox statistics alone."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.geoparquet import (RowGroup, bytes_touched, centre_box, extent_of, row_groups, spatially_sorted,
                                 touched)
from pipeline.tables import BBOX_COLUMN


def test_rows_are_sorted_so_that_neighbours_on_the_ground_are_neighbours_in_the_file():
    # two points in each corner of a 100 m square, interleaved, and one without a position
    x = [1.0, 99.0, 1.5, 99.5, 98.0, 2.0, 98.5, 2.5, np.nan]
    y = [1.0, 99.0, 98.0, 1.5, 98.5, 2.0, 1.0, 99.5, 5.0]
    table = pa.table({"x": x, "y": y, "row": list(range(9))})
    order = spatially_sorted(table).column("row").to_pylist()
    assert sorted(order) == list(range(9)) and order[-1] == 8  # every row once; no position: last
    corners = [(x[i] > 50, y[i] > 50) for i in order[:-1]]
    assert all(corners[k] == corners[k + 1] for k in (0, 2, 4, 6))  # each corner's pair side by side
    assert len(set(corners)) == 4


def _echo_file(path, boxes_per_group):
    """A Parquet file with a bbox column, one row group per list of boxes."""
    with pq.ParquetWriter(path, pa.schema([(BBOX_COLUMN, pa.struct([(f, pa.float64()) for f in
                                                                      ("xmin", "ymin", "xmax", "ymax")]))])) as w:
        for boxes in boxes_per_group:
            rows = [dict(zip(("xmin", "ymin", "xmax", "ymax"), b)) for b in boxes]
            w.write_table(pa.table({BBOX_COLUMN: rows}, schema=w.schema))
    return path


def test_a_box_query_reads_only_the_row_groups_whose_statistics_meet_it(tmp_path):
    path = _echo_file(tmp_path / "e.parquet", [[(0, 0, 1, 1), (9, 9, 10, 10)],  # group 0: (0, 0)-(10, 10)
                                               [(20, 0, 21, 1), (30, 5, 30, 5)]])  # group 1: (20, 0)-(30, 5)
    groups = row_groups([path])
    assert [(g.index, g.rows, g.box) for g in groups] == [(0, 2, (0, 0, 10, 10)), (1, 2, (20, 0, 30, 5))]
    assert [g.index for g in touched(groups, (11, 0, 19, 10))] == []  # the gap between them
    assert [g.index for g in touched(groups, (10, 5, 20, 6))] == [0, 1]  # touching both edges
    assert [g.index for g in touched(groups, (25, 6, 26, 7))] == []  # above group 1
    assert extent_of(groups) == (0, 0, 30, 10)
    assert bytes_touched([path], (0, 0, 1, 1)) == groups[0].bytes / (groups[0].bytes + groups[1].bytes)
    unknown = RowGroup("x", 0, 5, 100, None)  # no statistics: always read
    assert touched([unknown], (1e9, 1e9, 1e9, 1e9)) == [unknown]


def test_the_centre_box_is_a_share_of_the_extent_s_sides():
    assert centre_box((0.0, 0.0, 200.0, 100.0), 0.1) == (90.0, 45.0, 110.0, 55.0)
    assert centre_box((10.0, 20.0, 30.0, 60.0), 1.0) == (10.0, 20.0, 30.0, 60.0)
