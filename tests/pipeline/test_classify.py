"""fwl classify on a simulated forest: ground echoes against the truth's (F1 >= 0.97), classes and heights in the
echo table, null where an echo was not kept; tiles small enough that the forest spans several."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from fwcore.studies.evaluate import match_echoes
from fwcore.studies.forest_evaluate import ground_scores
from fwcore.studies.truth import truth_path
from pipeline.classify import is_classified
from pipeline.cli import main


@pytest.fixture(scope="session")
def classified(forest_run):
    """The session's forest run classified (again, if fwl grid --classify did it first: the same classes)."""
    assert main(["classify", str(forest_run), "--tile", "60", "--overlap", "15"]) == 0
    assert is_classified(forest_run)
    return forest_run


def _echoes(run_dir):
    return pa.concat_tables([pq.read_table(f, columns=["pulse_id", "time_ps", "kept", "classification", "height"])
                             for f in sorted((run_dir / "echoes").glob("*.parquet"))])


def test_ground_echoes_against_the_truth(classified, forest_flight):
    e = _echoes(classified)
    kept = e.filter(e.column("kept"))
    truth = pq.read_table(truth_path(forest_flight), columns=["pulse_id", "time_ps", "surface"])
    ti, fi = match_echoes(truth.column("pulse_id").to_numpy(), truth.column("time_ps").to_numpy(),
                          kept.column("pulse_id").to_numpy(), kept.column("time_ps").to_numpy(), 1500.0)
    truth_ground = np.zeros(kept.num_rows, bool)
    truth_ground[fi] = np.asarray(truth.column("surface").to_pylist(), object)[ti] == "ground"
    code = kept.column("classification").to_numpy(zero_copy_only=False)
    scores = ground_scores(code == 2, truth_ground)
    assert scores["f1"] >= 0.97, scores
    height = kept.column("height").to_numpy(zero_copy_only=False)
    assert np.abs(np.median(height[code == 2])) < 0.05
    assert (height[code == 5] >= 5.0).all() and set(np.unique(code)) <= {1, 2, 3, 4, 5, 6}
    roof = np.zeros(kept.num_rows, bool)
    roof[fi] = np.asarray(truth.column("surface").to_pylist(), object)[ti] == "roof"
    if roof.sum() > 50:  # the flight's buildings: found, and nothing else called one
        assert (code[roof] == 6).mean() > 0.7 and roof[code == 6].mean() > 0.95


def test_a_run_before_fwl_classify_is_not_classified(tmp_path):
    from pipeline.echo_table import echo_files

    run = tmp_path / "run"
    (run / "echoes").mkdir(parents=True)
    table = pa.table({"kept": [True, False], "classification": pa.array([None, None], pa.uint8())})
    pq.write_table(table, run / "echoes" / "a.parquet")
    assert echo_files(run) and not is_classified(run)
    pq.write_table(pa.table({"kept": [True, False], "classification": pa.array([2, None], pa.uint8())}),
                    run / "echoes" / "a.parquet")
    assert is_classified(run)


def test_spurious_echoes_have_no_class_and_a_second_run_is_the_same(classified):
    e = _echoes(classified)
    spurious = e.filter(pa.compute.invert(e.column("kept")))
    assert spurious.column("classification").null_count == spurious.num_rows
    before = e.column("classification").to_numpy(zero_copy_only=False)
    assert main(["classify", str(classified), "--tile", "60", "--overlap", "15"]) == 0
    np.testing.assert_array_equal(_echoes(classified).column("classification").to_numpy(zero_copy_only=False),
                                  before)
