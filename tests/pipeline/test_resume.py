"""`fwl run --resume`: a run killed midway goes on where it stopped and ends as an uninterrupted run would."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from pipeline.cli import main
from pipeline.layout import MANIFEST, plan_path
from pipeline.outputs import differences, input_identity, is_complete, read_run
from pipeline.plan import FilePlan
from pipeline.summary import EXIT_OK, EXIT_USAGE

# 19 ranges of the Leica sample's 1125 points: a kill lands among them
ARGS = ["--preset", "fast", "--points-per-range", "60", "--formats", "parquet,las"]
IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def outputs(folder):
    """What a run leaves for its user: the tables' parts, the point cloud, rejected rows (not logs nor run.json)."""
    return {k: v for k, v in snapshot(folder).items() if k.split("/")[0] in ("echoes", "pulses", "rejected", "las")}


def test_a_killed_run_resumes_to_the_uninterrupted_runs_outputs(tmp_path, leica_copy):
    killed, clean = tmp_path / "killed", tmp_path / "clean"
    run = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "run", str(leica_copy), "--output", str(killed),
                            *ARGS], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 240
    while not list((killed / "parts").glob("*.json")) and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert run.poll() is None, "the run ended before it could be killed"
    os.killpg(run.pid, signal.SIGKILL)  # no handler runs: what a lost machine or the OOM killer leaves
    run.wait(timeout=60)
    assert not is_complete(killed)
    plan = FilePlan.from_json(json.loads(plan_path(killed, "leica_a").read_text()))
    marked = {p.stem for p in (killed / "parts").glob("*.json")}
    unmarked = [r.start for r in plan.ranges if f"leica_a-{r.start:012d}" not in marked]
    assert 0 < len(marked) and unmarked
    # what a worker killed while writing leaves: parts of a range that never reached its mark, one half-written
    half = f"leica_a-{unmarked[-1]:012d}"
    (killed / "parts" / f"{half}.las").write_bytes(b"LASF" + bytes(20))
    (killed / "echoes").mkdir(exist_ok=True)
    (killed / "echoes" / f"{half}.parquet").write_bytes(b"PAR1 half")
    (killed / "pulses").mkdir(exist_ok=True)
    (killed / "pulses" / f"{half}.parquet.tmp").write_bytes(b"PAR1")

    assert main(["run", str(leica_copy), "--output", str(killed), "--resume", *ARGS, *IN_PROCESS]) == EXIT_OK
    assert main(["run", str(leica_copy), "--output", str(clean), *ARGS, *IN_PROCESS]) == EXIT_OK
    resumed = read_run(killed)
    assert resumed["taken"] == "resumed" and resumed["ranges"] == len(plan.ranges) == 19
    assert resumed["ranges_reused"] == len(plan.ranges) - len(unmarked) == len(marked)
    assert resumed["counts"] == read_run(clean)["counts"]
    assert resumed["counts"]["pulses_read"] == 924
    # its rate counts the pulses of the ranges it ran, not those it reused
    assert 0 < resumed["pulses_processed"] < 924 == read_run(clean)["pulses_processed"]
    assert resumed["pulses_per_second"] == pytest.approx(resumed["pulses_processed"] / resumed["seconds"], rel=1e-3)
    # the same rows in the same part files, and the same point cloud, byte for byte
    assert outputs(killed) == outputs(clean)
    assert not (killed / "parts").exists()


def test_resume_refuses_other_settings_or_changed_inputs_and_touches_nothing(tmp_path, leica_copy, capsys):
    out = tmp_path / "out"
    quick = ["--limit", "40", *ARGS, *IN_PROCESS]
    assert main(["run", str(leica_copy), "--output", str(out), *quick]) == EXIT_OK
    (out / "run.json").unlink()  # as an interrupted run's folder reads
    before = snapshot(out)
    capsys.readouterr()

    assert main(["run", str(leica_copy), "--output", str(out), "--resume", "--optimizer", "none",
                 *quick]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "cannot resume: the settings differ" in err and "config.optimizer: 'lm' -> 'none'" in err
    assert main(["run", str(leica_copy), "--output", str(out), "--resume", *quick, "--limit", "41"]) == EXIT_USAGE
    assert "limit: 40 -> 41" in capsys.readouterr().err
    # what is given of the file's pulse instead of measuring it is a setting too
    assert main(["run", str(leica_copy), "--output", str(out), "--resume", "--shape-tolerance", "0.02",
                 *quick]) == EXIT_USAGE
    assert "overrides.shape_tolerance: None -> 0.02" in capsys.readouterr().err

    packets = leica_copy.with_suffix(".wdp")
    data = bytearray(packets.read_bytes())
    data[-1] ^= 0xFF  # the last packet's last sample: the same size, other data
    packets.write_bytes(bytes(data))
    assert main(["run", str(leica_copy), "--output", str(out), "--resume", *quick]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert f"{leica_copy}: changed since the interrupted run" in err and "leica_a.wdp.sha256" in err

    other = tmp_path / "other.las"
    shutil.copy(leica_copy, other)
    assert main(["run", str(other), "--output", str(out), "--resume", *quick]) == EXIT_USAGE
    assert f"not given now: {leica_copy}" in capsys.readouterr().err
    assert snapshot(out) == before


def test_resume_of_a_new_folder_runs_and_of_a_finished_run_does_nothing(tmp_path, leica_dir, capsys):
    out = tmp_path / "out"
    quick = [str(leica_dir / "leica_a.las"), "--output", str(out), "--limit", "40", *ARGS, *IN_PROCESS]
    assert main(["run", *quick, "--resume"]) == EXIT_OK
    assert "nothing to resume: a new run" in capsys.readouterr().out
    assert read_run(out)["counts"]["pulses_decomposed"] == 40
    before = snapshot(out)
    assert main(["run", *quick, "--resume"]) == EXIT_OK
    assert "already complete: nothing to do" in capsys.readouterr().out
    assert snapshot(out) == before


def test_a_folder_from_before_fingerprints_cannot_be_resumed(tmp_path, leica_dir, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST).write_text(json.dumps({"written_by": "fwl run", "inputs": [
        {"path": str(leica_dir / "leica_a.las"), "name": "leica_a.las", "stem": "leica_a"}]}))
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--resume", *ARGS]) == EXIT_USAGE
    assert "did not fingerprint its runs" in capsys.readouterr().err


def test_an_inputs_identity_is_its_bytes_not_its_times(leica_copy):
    first = input_identity(str(leica_copy))
    assert sorted(first) == ["leica_a.las", "leica_a.wdp"] and first["leica_a.wdp"]["size"] == 236636
    os.utime(leica_copy, (0, 0))  # touched, or copied without its times: the same data
    assert input_identity(str(leica_copy)) == first
    data = bytearray(leica_copy.read_bytes())
    data[300] ^= 0xFF  # one byte in the header's records: the same size, other data
    leica_copy.write_bytes(bytes(data))
    now = input_identity(str(leica_copy))
    assert now["leica_a.las"]["sha256"] != first["leica_a.las"]["sha256"]
    assert differences(first, now) == \
        [f"leica_a.las.sha256: {first['leica_a.las']['sha256']!r} -> {now['leica_a.las']['sha256']!r}"]
