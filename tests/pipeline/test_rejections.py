"""The dead letter's way out: a range's Rejections sorted into rejected/<stem>-<range>.parquet, a file's into
rejected/<stem>.parquet, and an input nothing of which was rejected given an empty table of the same schema."""

from types import SimpleNamespace

import pyarrow.parquet as pq

from pipeline.records import Rejection
from pipeline.rejections import write_empty_rejected, write_file_rejection, write_rejections
from pipeline.tables import REJECTED_SCHEMA


def test_a_range_s_rejections_go_to_its_own_file_ordered_by_pulse_then_stage(tmp_path):
    task = SimpleNamespace(source=SimpleNamespace(stem="x"), start=600)
    rows = [Rejection("x.las", "x", 600, 612, "write", "disk"), Rejection("x.las", "x", 600, 601, "read", "lost"),
            Rejection("x.las", "x", 600, 612, "decompose", "no echo")]
    path = write_rejections(tmp_path, task, rows)
    assert path == tmp_path / "rejected" / "x-000000000600.parquet"
    written = pq.read_table(path)
    assert written.schema.equals(REJECTED_SCHEMA, check_metadata=False)
    assert [(r["pulse_id"], r["stage"], r["reason"]) for r in written.to_pylist()] == [
        (601, "read", "lost"), (612, "decompose", "no echo"), (612, "write", "disk")]


def test_a_file_rejected_whole_and_the_empty_tables_of_the_others(tmp_path):
    path = write_file_rejection(tmp_path, Rejection("a.las", "a", -1, -1, "open", "not a LAS file"))
    assert path == tmp_path / "rejected" / "a.parquet"
    assert pq.read_table(path).to_pylist() == [{"source_file": "a.las", "pulse_id": -1, "stage": "open",
                                                "reason": "not a LAS file"}]
    write_rejections(tmp_path, SimpleNamespace(source=SimpleNamespace(stem="b"), start=0),
                     [Rejection("b.las", "b", 0, 3, "read", "lost")])
    write_empty_rejected(tmp_path, ["a", "b", "c"])  # a and b have theirs; c gets an empty one
    assert sorted(p.name for p in (tmp_path / "rejected").iterdir()) == ["a.parquet", "b-000000000000.parquet",
                                                                         "c.parquet"]
    empty = pq.read_table(tmp_path / "rejected" / "c.parquet")
    assert empty.num_rows == 0 and empty.schema.names == REJECTED_SCHEMA.names
    assert pq.read_table(tmp_path / "rejected" / "a.parquet").num_rows == 1  # not replaced by an empty one
