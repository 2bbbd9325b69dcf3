"""One output rule for every command that writes: nothing that is not its own earlier output is written over
(exit 2, every byte unchanged) unless --overwrite; an output named with another format's suffix is refused."""

import json

import pyarrow.parquet as pq
import pytest

from pipeline.cli import main
from pipeline.layout import MANIFEST

NOTES = b"flight notes: the user's own file\n"
SIMULATE = ["simulate", "--pulses", "30", "--seed", "1"]


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory, neon_dir):
    lines = (neon_dir / "return_waveforms.csv").read_text().splitlines()
    path = tmp_path_factory.mktemp("csv") / "small.csv"
    path.write_text("\n".join(lines[:13]) + "\n")
    return path


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def users_files(folder, names):
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_bytes(NOTES)
    return snapshot(folder)


def refused(argv, folder, capsys, named):
    """The command exits 2, says why naming the path, and leaves every byte of `folder` as it was."""
    before = snapshot(folder)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert named in err and "fwl: error:" in err
    assert snapshot(folder) == before
    return err


@pytest.mark.parametrize("name", ["echoes.parquet", "echoes.waveforms.parquet"])
def test_decompose_csv_refuses_a_users_file(tmp_path, small_csv, capsys, name):
    users_files(tmp_path, [name])
    err = refused(["decompose-csv", str(small_csv), "--output", str(tmp_path / "echoes.parquet")], tmp_path, capsys,
                  str(tmp_path / name))
    assert "--overwrite" in err


def test_decompose_csv_refuses_a_suffix_that_is_not_parquet(tmp_path, small_csv, capsys):
    users_files(tmp_path, ["notes.txt"])
    err = refused(["decompose-csv", str(small_csv), "--output", str(tmp_path / "notes.txt")], tmp_path, capsys,
                  "notes.txt")
    assert "ends .parquet, not .txt" in err


def test_decompose_csv_replaces_its_own_output_and_a_users_with_overwrite(tmp_path, small_csv, capsys):
    out = tmp_path / "echoes.parquet"
    argv = ["decompose-csv", str(small_csv), "--output", str(out), "--optimizer", "none"]
    assert main(argv) == 0
    first = snapshot(tmp_path)
    assert main(argv) == 0  # its own earlier output: replaced, the same bytes
    assert snapshot(tmp_path) == first
    (tmp_path / "echoes.waveforms.parquet").write_bytes(NOTES)
    assert main(argv) == 2
    assert main(argv + ["--overwrite"]) == 0
    assert pq.read_table(tmp_path / "echoes.waveforms.parquet").num_rows == 12


@pytest.mark.parametrize("name", ["mine.las", "mine.trajectory.csv", "mine.truth.parquet", "mine.wdp"])
def test_simulate_refuses_a_users_file(tmp_path, capsys, name):
    users_files(tmp_path, [name])
    refused(SIMULATE + ["--output", str(tmp_path / "mine.las")], tmp_path, capsys, str(tmp_path / name))


def test_simulate_refuses_a_suffix_that_is_not_las(tmp_path, capsys):
    users_files(tmp_path, ["x.csv"])
    err = refused(SIMULATE + ["--output", str(tmp_path / "x.csv")], tmp_path, capsys, "x.csv")
    assert "ends .las or .laz, not .csv" in err


def test_simulate_replaces_its_own_flight_and_a_users_with_overwrite(tmp_path, capsys):
    argv = SIMULATE + ["--output", str(tmp_path / "sim.las")]
    assert main(argv) == 0
    first = snapshot(tmp_path)
    assert main(argv) == 0
    assert snapshot(tmp_path) == first
    (tmp_path / "sim.truth.parquet").write_bytes(NOTES)  # the mark gone: the flight is no longer ours
    assert main(argv) == 2 and (tmp_path / "sim.truth.parquet").read_bytes() == NOTES
    assert main(argv + ["--overwrite"]) == 0 and snapshot(tmp_path) == first


def test_compare_refuses_a_folder_of_the_users(tmp_path, small_csv, capsys):
    users_files(tmp_path / "out", ["compare.csv"])
    refused(["compare", str(small_csv), "--output", str(tmp_path / "out"), "--optimizers", "lm"], tmp_path, capsys,
            "compare.csv")


def test_compare_refuses_a_run_folder_and_writes_into_its_own(tmp_path, small_csv, capsys):
    run_folder = tmp_path / "run"
    run_folder.mkdir()
    (run_folder / MANIFEST).write_text(json.dumps({"written_by": "fwl run", "inputs": []}))
    refused(["compare", str(small_csv), "--output", str(run_folder), "--optimizers", "lm"], tmp_path, capsys,
            MANIFEST)
    out = tmp_path / "out"
    argv = ["compare", str(small_csv), "--output", str(out), "--optimizers", "lm", "--limit", "3"]
    assert main(argv) == 0
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["written_by"] == "fwl compare" and "compare.csv" in manifest["files"]
    assert main(argv) == 0  # its own earlier output
    (out / "mine.txt").write_bytes(NOTES)
    assert main(argv) == 2
    assert main(argv + ["--overwrite"]) == 0 and (out / "mine.txt").read_bytes() == NOTES


@pytest.mark.parametrize("name, said", [("table.txt", "ends .md or .csv, not .txt"),
                                        ("table.md", "not an earlier output of fwl evaluate"),
                                        ("table.csv", "not an earlier output of fwl evaluate")])
def test_evaluate_refuses_a_users_table_and_a_suffix_it_does_not_write(tmp_path, capsys, name, said):
    run_folder = tmp_path / "run"  # refused before the run is read any further than its run.json
    run_folder.mkdir()
    (run_folder / "run.json").write_text("{}")
    users_files(tmp_path, [name])
    err = refused(["evaluate", str(run_folder), "--truth", str(tmp_path / "t.truth.parquet"), "--output",
                   str(tmp_path / name)], tmp_path, capsys, name)
    assert said in err
