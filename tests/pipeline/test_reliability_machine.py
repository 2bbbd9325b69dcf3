"""Faults of the machine are not faults of the data: a full disk stops the run (exit 5) with one line naming it,
rejects nothing, and a resume finishes it as a clean run would; a second writer of a folder is refused."""

import errno
import os
import subprocess
import sys
import time

import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

import pipeline.stages
from pipeline.cli import main
from pipeline.layout import LOCK
from pipeline.lock import read_holder
from pipeline.outputs import is_complete, read_run
from pipeline.summary import EXIT_MACHINE, EXIT_OK, EXIT_USAGE

# 4 ranges of the Leica sample, decomposed in this process (a small run under the default runner)
ARGS = ["--preset", "fast", "--points-per-range", "300"]


def outputs(folder):
    """What a run leaves for its user, byte for byte: tables, point cloud, MCAP, rejected rows."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.relative_to(folder).parts[0] in ("echoes", "pulses", "rejected", "las", "mcap")}


def rejected_rows(folder) -> int:
    return sum(pq.read_metadata(f).num_rows for f in (folder / "rejected").glob("*.parquet"))


def kept_echoes(folder):
    echoes = ds.dataset(str(folder / "echoes")).to_table()
    return echoes.filter(pc.field("kept")).sort_by([("pulse_id", "ascending"), ("echo_index", "ascending")])


def test_a_full_disk_stops_the_run_without_a_rejection_and_resume_finishes_it(tmp_path, leica_copy, monkeypatch,
                                                                              capsys):
    out, clean = tmp_path / "out", tmp_path / "clean"
    real, written = pipeline.stages.write_mcap, []

    def fills_up(path, *args, **kwargs):  # the disk is full from the third range's MCAP part on
        if len(written) >= 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        written.append(path)
        return real(path, *args, **kwargs)

    monkeypatch.setattr("pipeline.stages.write_mcap", fills_up)
    command = ["run", str(leica_copy), "--output", str(out), *ARGS]
    assert main(command) == EXIT_MACHINE
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "No space left" in line]
    assert len(said) == 1 and said[0].startswith(f"fwl run: stopped: No space left on device (ENOSPC) writing {out}/"
                                                 f"parts/leica_a-0000000006")
    assert said[0].endswith(f"free space on the disk of {out / 'parts'}, then fwl run {leica_copy} --output {out} "
                            f"--preset fast --points-per-range 300 --resume")
    assert "2 of 4 ranges finished and are kept; no pulse was rejected for this (exit code 5)" in err
    assert not is_complete(out) and rejected_rows(out) == 0 and not (out / LOCK).exists()
    assert len(list((out / "parts").glob("*.json"))) == 2  # the two finished ranges' marks

    monkeypatch.undo()  # space freed
    assert main([*command, "--resume"]) == EXIT_OK
    assert main(["run", str(leica_copy), "--output", str(clean), *ARGS]) == EXIT_OK
    resumed = read_run(out)
    assert (resumed["taken"], resumed["ranges_reused"], resumed["counts"]) == \
        ("resumed", 2, read_run(clean)["counts"])
    assert resumed["counts"]["pulses_rejected"] == 0
    assert outputs(out) == outputs(clean)  # byte for byte


@pytest.fixture
def small_disk(tmp_path):
    """A 600 KiB filesystem (a tmpfs, which root may mount on every machine this project runs its CI on)."""
    assert os.geteuid() == 0, "mounting a 600 KiB filesystem needs root (CI runs as root, as .ci/run's apt-get does)"
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(disk)], capture_output=True,
                             text=True)
    assert mounted.returncode == 0, f"cannot mount a tmpfs here: {mounted.stderr.strip()}"
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_real_600_kib_disk_fills_and_grown_the_run_resumes_to_a_clean_runs_echoes(tmp_path, leica_copy, small_disk):
    out = small_disk / "out"
    command = [sys.executable, "-m", "pipeline.cli", "run", str(leica_copy), "--output", str(out)]
    # the default options; 2 worker processes (a fault crosses from them to the driver)
    workers = ["--points-per-range", "300", "--direct_num_workers=2", "--direct_running_mode=multi_processing"]
    full = subprocess.run(command + workers, capture_output=True, text=True, timeout=600)
    assert full.returncode not in (0, 3) and full.returncode == EXIT_MACHINE, full.stderr
    assert "fwl run: stopped: No space left on device (ENOSPC) writing" in full.stderr
    assert "Traceback" not in full.stderr and rejected_rows(out) == 0
    subprocess.run(["mount", "-o", "remount,size=20m", str(small_disk)], check=True)
    resumed = subprocess.run(command + workers + ["--resume"], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == EXIT_OK, resumed.stderr
    assert main(["run", str(leica_copy), "--output", str(tmp_path / "clean"), "--points-per-range", "300"]) == EXIT_OK
    assert kept_echoes(out).equals(kept_echoes(tmp_path / "clean"))
    assert read_run(out)["counts"] == read_run(tmp_path / "clean")["counts"]


def test_a_second_writer_is_refused_within_seconds_and_the_first_completes(tmp_path, leica_copy, capsys):
    out = tmp_path / "out"
    first = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "run", str(leica_copy), "--output", str(out),
                              *ARGS], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (read_holder(out / LOCK) or {}).get("pid") and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert first.poll() is None, "the first run ended before a second could start"
    for command in (["run", str(leica_copy), "--output", str(out), *ARGS], ["compact", str(out)],
                    ["grid", str(out), "--cell", "1"]):
        began = time.monotonic()
        assert main(command) == EXIT_USAGE
        assert time.monotonic() - began < 5
        err = capsys.readouterr().err
        assert f"{out}: is being written by fwl run (pid {first.pid} on " in err, err
    stdout, stderr = first.communicate(timeout=300)
    assert first.returncode == EXIT_OK, stderr
    assert read_run(out)["counts"]["pulses_decomposed"] == 924 and not (out / LOCK).exists()
