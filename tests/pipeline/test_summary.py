"""run.json's counts read back from the tables written: pulses, echoes kept and spurious, and each rejected row told
apart as a file, a pulse or a problem; the status and the exit code each status means."""

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.summary import EXIT_CODES, count_outputs, status_of, whole_file_reasons


def _write(folder, name, columns):
    folder.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table(columns), folder / name)


@pytest.fixture
def written(tmp_path):
    """Two inputs' tables in two parts each, as ranges write them: a.las fully decomposed, b.las with two pulses
    rejected and a range that failed whole; c.las rejected as a file."""
    _write(tmp_path / "pulses", "a-0.parquet", {"source_file": ["a.las"] * 3})
    _write(tmp_path / "pulses", "a-1.parquet", {"source_file": ["a.las"] * 2})
    _write(tmp_path / "pulses", "b-0.parquet", {"source_file": ["b.las"]})
    _write(tmp_path / "echoes", "a-0.parquet", {"source_file": ["a.las"] * 4, "kept": [True, True, False, True]})
    _write(tmp_path / "echoes", "b-0.parquet", {"source_file": ["b.las"] * 2, "kept": [False, False]})
    _write(tmp_path / "rejected", "b-0.parquet", {"source_file": ["b.las"] * 3, "stage": ["read", "decompose", "write"],
                                                  "pulse_id": [7, 9, -1]})
    _write(tmp_path / "rejected", "c.parquet", {"source_file": ["c.las"], "stage": ["open"], "pulse_id": [-1],
                                                "reason": ["not a LAS file: bad signature"]})
    _write(tmp_path / "rejected", "a.parquet", {"source_file": pa.array([], pa.string()),
                                                "stage": pa.array([], pa.string()), "pulse_id": pa.array([], pa.int64())})
    return tmp_path


def test_counts_add_up_per_input_and_in_total(written):
    totals, per_input = count_outputs(written, ["a.las", "b.las", "c.las"])
    assert per_input["a.las"] == {"pulses_read": 5, "pulses_decomposed": 5, "pulses_rejected": 0, "files_rejected": 0,
                                  "problems": 0, "echoes_kept": 3, "echoes_spurious": 1}
    assert per_input["b.las"] == {"pulses_read": 3, "pulses_decomposed": 1, "pulses_rejected": 2, "files_rejected": 0,
                                  "problems": 1, "echoes_kept": 0, "echoes_spurious": 2}
    assert per_input["c.las"] == {"pulses_read": 0, "pulses_decomposed": 0, "pulses_rejected": 0, "files_rejected": 1,
                                  "problems": 0, "echoes_kept": 0, "echoes_spurious": 0}
    assert totals == {"pulses_read": 8, "pulses_decomposed": 6, "pulses_rejected": 2, "files_rejected": 1,
                      "problems": 1, "echoes_kept": 3, "echoes_spurious": 3}
    entries = [{"name": n, "stem": n[0]} for n in ("a.las", "b.las", "c.las")]
    assert whole_file_reasons(written, entries, per_input) == {"c.las": "not a LAS file: bad signature"}


def test_the_status_and_its_exit_code():
    clean = {"pulses_rejected": 0, "files_rejected": 0, "problems": 0, "pulses_decomposed": 5}
    assert status_of(clean) == "complete"
    assert status_of({**clean, "problems": 1}) == "partial"  # a range that failed whole: not complete
    assert status_of({**clean, "files_rejected": 1, "pulses_decomposed": 0}) == "failed"
    assert EXIT_CODES == {"complete": 0, "partial": 3, "failed": 4}


def test_a_run_without_tables_counts_what_its_ranges_decomposed_and_kept(tmp_path, leica_dir):
    """An MCAP-only (or LAS-only) run writes no pulses/ nor echoes/: its counts come from its ranges' marks, and
    are those of the same run with the tables."""
    from fwcore.engine.config import DecompositionConfig
    from pipeline.run import run

    las = str(leica_dir / "leica_a.las")
    # two ranges of 300 points: the marks of both are summed
    tables = run([las], tmp_path / "tables", DecompositionConfig(), ("parquet",), 400, 300, watch=False)
    for formats in (("mcap",), ("las",)):
        alone = run([las], tmp_path / formats[0], DecompositionConfig(), formats, 400, 300, watch=False)
        assert alone["counts"] == tables["counts"]
        assert alone["counts"]["pulses_read"] == 400 and alone["counts"]["echoes_kept"] > 400
        assert alone["inputs"][0]["counts"] == tables["inputs"][0]["counts"]
