"""What a run may do to its output folder, how it names its outputs, its exit codes and run.json."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pyarrow.dataset as ds
import pytest

from pipeline.cli import main
from pipeline.layout import MANIFEST
from pipeline.outputs import (IncompleteRunError, InputNames, OutputFolderError, expand_inputs, is_complete, read_run,
                              take_output_folder)
from pipeline.summary import EXIT_INTERRUPTED, EXIT_NOTHING_DONE, EXIT_OK, EXIT_PARTIAL, EXIT_USAGE

QUICK = ["--preset", "fast", "--limit", "20", "--points-per-range", "300", "--direct_num_workers=1",
         "--direct_running_mode=in_memory"]


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def rows(folder, table):
    return ds.dataset(str(folder / table), format="parquet").to_table().to_pandas()


@pytest.fixture
def copies(tmp_path, leica_dir):
    """leica_a.las + .wdp copied under flightA/ and flightB/."""
    for flight in ("flightA", "flightB"):
        (tmp_path / flight).mkdir()
        for suffix in (".las", ".wdp"):
            shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / flight / f"leica_a{suffix}")
    return tmp_path


# ---------------------------------------------------------------- the folder is the user's unless ours

def test_a_folder_holding_the_input_is_refused_and_left_as_it_was(copies, monkeypatch, capsys):
    # the report: mkdir -p d/las && cp leica_a.* d/las/ && cd d && fwl run las/leica_a.las --output .
    d = copies / "d"
    shutil.copytree(copies / "flightA", d / "las")
    before = snapshot(d)
    monkeypatch.chdir(d)
    assert main(["run", "las/leica_a.las", "--output", "."] + QUICK) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "not an fwl run output folder" in err and "las/leica_a.las" in err
    assert snapshot(d) == before


def test_a_bad_input_is_reported_before_the_folder_is_touched(tmp_path, leica_dir, capsys):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out)] + QUICK) == EXIT_OK
    before = snapshot(out)
    assert main(["run", str(tmp_path / "missing.las"), "--output", str(out)] + QUICK) == EXIT_USAGE
    assert "missing.las: no file matches this input" in capsys.readouterr().err
    assert snapshot(out) == before and is_complete(out)


def test_a_rerun_replaces_its_own_outputs_and_refuses_foreign_files(tmp_path, leica_dir, copies, capsys):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out)] + QUICK) == EXIT_OK
    summary = read_run(out)
    assert (out / MANIFEST).is_file() and "las/leica_a.las" in summary["files"]
    for foreign in (out / "notes.txt", out / "las" / "mine.las", out / "extra" / "x"):
        foreign.parent.mkdir(exist_ok=True)
        foreign.write_text("the user's")
        before = snapshot(out)
        assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out)] + QUICK) == EXIT_USAGE
        assert "did not write" in capsys.readouterr().err and foreign.name in str(snapshot(out))
        assert snapshot(out) == before
        shutil.rmtree(foreign.parent) if foreign.parent.name == "extra" else foreign.unlink()
    # another input: the earlier outputs go, the new ones come
    (copies / "flightA" / "leica_a.las").rename(copies / "flightA" / "other.las")
    (copies / "flightA" / "leica_a.wdp").rename(copies / "flightA" / "other.wdp")
    assert main(["run", str(copies / "flightA" / "other.las"), "--output", str(out)] + QUICK) == EXIT_OK
    assert sorted(p.name for p in (out / "las").iterdir()) == ["other.las"]
    assert set(rows(out, "pulses").source_file) == {"other.las"}


def test_an_earlier_output_as_input_is_refused(tmp_path, leica_dir, capsys):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--formats", "las"] + QUICK) == 0
    assert main(["run", str(out / "las" / "leica_a.las"), "--output", str(out)] + QUICK) == EXIT_USAGE
    assert "is an output of the earlier run" in capsys.readouterr().err
    assert is_complete(out)


def test_an_interrupted_folder_reads_incomplete_and_a_rerun_completes_it(tmp_path, leica_dir, capsys):
    out = tmp_path / "out"
    args = ["run", str(leica_dir / "leica_a.las"), "--output", str(out)] + QUICK
    assert main(args) == EXIT_OK
    complete = snapshot(out)
    # what an interruption leaves: no run.json, some parts missing, a half-written part
    (out / "run.json").unlink()
    for p in sorted((out / "echoes").iterdir())[1:]:
        p.unlink()
    (out / "pulses" / "leica_a-000000000000.parquet.tmp").write_bytes(b"PAR1 half")
    assert not is_complete(out)
    with pytest.raises(IncompleteRunError, match="did not finish"):
        read_run(out)
    assert main(["evaluate", str(out), "--truth", str(tmp_path / "t.parquet")]) == EXIT_USAGE
    assert "incomplete, no run.json" in capsys.readouterr().err
    assert main(args) == EXIT_OK
    again = snapshot(out)
    assert set(again) == set(complete)
    assert all(again[k] == complete[k] for k in again if k.endswith(".parquet") or k.endswith(".las"))


def test_take_output_folder_claims_new_and_empty_folders_only(tmp_path):
    names = InputNames.of(["/data/a.las"])
    take_output_folder(tmp_path / "new", names, ["/data/a.las"])
    assert json.loads((tmp_path / "new" / MANIFEST).read_text())["inputs"][0]["stem"] == "a"
    (tmp_path / "empty").mkdir()
    take_output_folder(tmp_path / "empty", names, ["/data/a.las"])
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputFolderError, match="not a folder"):
        take_output_folder(tmp_path / "file", names, ["/data/a.las"])
    (tmp_path / "hasdir" / "las").mkdir(parents=True)
    with pytest.raises(OutputFolderError, match="not an fwl run output folder"):
        take_output_folder(tmp_path / "hasdir", names, ["/data/a.las"])


# ---------------------------------------------------------------- names

def test_input_names_are_unique_and_deterministic():
    names = InputNames.of(["/d/flightA/leica_a.las", "/d/flightB/leica_a.las", "/d/x.las", "/d/x.laz", "/d/y.las"])
    assert [names.name(p) for p in sorted(names.names)] == [
        "flightA/leica_a.las", "flightB/leica_a.las", "x.las", "x.laz", "y.las"]
    assert [names.stem(names.name(p)) for p in sorted(names.names)] == [
        "flightA__leica_a", "flightB__leica_a", "x.las", "x.laz", "y"]
    assert InputNames.of(["/d/x.laz", "/d/x.las"]) == InputNames.of(["/d/x.las", "/d/x.laz"])
    deep = InputNames.of(["/a/f/g.las", "/b/f/g.las"])
    assert sorted(deep.names.values()) == ["a/f/g.las", "b/f/g.las"]


def test_a_folder_input_expands_to_its_las_and_laz_files(leica_dir, tmp_path):
    assert [p.rsplit("/", 1)[-1] for p in expand_inputs([str(leica_dir)])] == ["leica_a.las", "leica_a.laz"]
    assert expand_inputs([str(leica_dir / "leica_a.las"), str(leica_dir / "*.las")]) == \
        [str((leica_dir / "leica_a.las").resolve())]
    with pytest.raises(FileNotFoundError, match="a folder that holds no .las, .laz, .pls or GEDI/LVIS L1B .h5 file"):
        expand_inputs([str(tmp_path)])


def test_same_file_names_in_two_folders_keep_their_own_outputs(copies, leica_dir):
    out = copies / "out"
    alone = copies / "alone"
    assert main(["run", str(copies / "flightA" / "leica_a.las"), "--output", str(alone)] + QUICK) == EXIT_OK
    assert main(["run", str(copies / "flight*" / "leica_a.las"), "--output", str(out)] + QUICK) == EXIT_OK
    summary = read_run(out)
    assert [(i["name"], i["output_stem"], i["counts"]["pulses_read"]) for i in summary["inputs"]] == [
        ("flightA/leica_a.las", "flightA__leica_a", 20), ("flightB/leica_a.las", "flightB__leica_a", 20)]
    assert summary["counts"]["pulses_read"] == 40
    assert sorted(p.name for p in (out / "las").iterdir()) == ["flightA__leica_a.las", "flightB__leica_a.las"]
    assert sorted(p.name for p in (out / "mcap").iterdir()) == ["flightA__leica_a.mcap", "flightB__leica_a.mcap"]
    echoes = rows(out, "echoes")
    a = echoes[echoes.source_file == "flightA/leica_a.las"].drop(columns="source_file").reset_index(drop=True)
    b = echoes[echoes.source_file == "flightB/leica_a.las"].drop(columns="source_file").reset_index(drop=True)
    single = rows(alone, "echoes").drop(columns="source_file").reset_index(drop=True)
    assert a.equals(single) and b.equals(single)
    assert (out / "las" / "flightA__leica_a.las").read_bytes() == (alone / "las" / "leica_a.las").read_bytes()


def test_las_beside_laz_in_a_folder_input(leica_dir, tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir), "--output", str(out), "--formats", "parquet,las"] + QUICK) == EXIT_OK
    summary = read_run(out)
    assert [(i["name"], i["output_stem"]) for i in summary["inputs"]] == [("leica_a.las", "leica_a.las"),
                                                                          ("leica_a.laz", "leica_a.laz")]
    assert sorted(p.name for p in (out / "las").iterdir()) == ["leica_a.las.las", "leica_a.laz.las"]
    assert all(i["counts"]["pulses_decomposed"] == 20 for i in summary["inputs"])


# ---------------------------------------------------------------- exit codes and counts

def test_exit_codes_and_counts_tell_the_truth(tmp_path, leica_dir):
    data = tmp_path / "data"
    data.mkdir()
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", data / f"cut{suffix}")
    wdp = (data / "cut.wdp").read_bytes()
    (data / "cut.wdp").write_bytes(wdp[: len(wdp) // 3])
    (data / "junk.las").write_bytes(b"not a las file at all")
    assert main(["run", str(data / "junk.las"), "--output", str(tmp_path / "none")] + QUICK) == EXIT_NOTHING_DONE
    assert read_run(tmp_path / "none")["status"] == "failed"
    out = tmp_path / "some"
    args = ["--optimizer", "none", "--points-per-range", "300", "--direct_num_workers=1",
            "--direct_running_mode=in_memory"]
    assert main(["run", str(data), "--output", str(out)] + args) == EXIT_PARTIAL
    summary = read_run(out)
    c = summary["counts"]
    assert summary["status"] == "partial" and summary["exit_code"] == EXIT_PARTIAL
    assert c["files_rejected"] == 1 and c["pulses_rejected"] > 0
    assert c["pulses_read"] == 924 == c["pulses_decomposed"] + c["pulses_rejected"]
    for key in ("pulses_read", "pulses_decomposed", "pulses_rejected", "files_rejected", "echoes_kept"):
        assert summary["metrics"][key] == c[key], key
    per_input = {i["name"]: i["counts"] for i in summary["inputs"]}
    assert per_input["junk.las"]["files_rejected"] == 1 and per_input["cut.las"]["pulses_rejected"] == c["pulses_rejected"]


def test_bad_option_values_are_clear_errors(capsys):
    for flag, value in (("--points-per-range", "0"), ("--points-per-range", "-5"), ("--limit", "0")):
        with pytest.raises(SystemExit) as stop:
            main(["run", "--output", "unused", flag, value])
        assert stop.value.code == EXIT_USAGE
        err = capsys.readouterr().err
        assert f"argument {flag}: must be >= 1" in err and "Traceback" not in err


def test_run_version_prints_the_version_and_runs_nothing(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(["run", "--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.startswith("fwl 0.")
    assert not any(tmp_path.iterdir())


def test_ctrl_c_stops_cleanly_and_a_rerun_completes_the_folder(tmp_path, leica_dir):
    out = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "run", str(leica_dir / "leica_a.las"),
                            "--output", str(out), "--points-per-range", "100"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 240
    while not list((out / "echoes").glob("*.parquet")) and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    assert run.poll() is None, "the run ended before it could be interrupted"
    os.killpg(run.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole process group
    stdout, stderr = run.communicate(timeout=120)
    assert run.returncode == EXIT_INTERRUPTED
    assert stderr.strip().splitlines() == [f"fwl run: interrupted; {out} holds an incomplete run (no run.json): "
                                           f"rerun the same command with --resume to complete it"], stderr
    assert not list(out.rglob("*.tmp")) and not is_complete(out)
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--optimizer", "none",
                 "--direct_num_workers=1", "--direct_running_mode=in_memory"]) == EXIT_OK
    summary = read_run(out)
    assert summary["counts"]["pulses_decomposed"] == 924 and summary["config"]["optimizer"] == "none"
    assert len(rows(out, "pulses")) == 924 and not (out / "parts").exists()
