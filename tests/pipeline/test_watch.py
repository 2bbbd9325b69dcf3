"""`fwl watch`: each flight line processed once it is complete, once, also across restarts; a replaced one again."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.cli import main
from pipeline.faults import MachineFault, RunStopped
from pipeline.outputs import input_identity, read_run
from pipeline.watch import FolderWatch, due, snapshot, watch

RUN = ["--preset", "fast", "--formats", "parquet,las", "--direct_num_workers=1", "--direct_running_mode=in_memory"]


def fwl_watch(folder, output, *extra):
    return subprocess.Popen([sys.executable, "-m", "pipeline.cli", "watch", str(folder), "--output", str(output),
                             "--poll", "0.5", *RUN, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def wait_for(condition, seconds=180):
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.2)


def done_inputs(output):
    try:
        return [(i["name"], i["counts"]["pulses_read"]) for i in json.loads((output / "run.json").read_text())["inputs"]]
    except (OSError, ValueError):
        return []


# ---------------------------------------------------------------- complete, steady, due

def test_an_input_is_ready_once_its_packets_are_there_and_nothing_grows(tmp_path, leica_dir):
    watcher = FolderWatch(tmp_path)
    shutil.copy(leica_dir / "leica_a.las", tmp_path / "a.las")  # its header says: packets in a.wdp
    assert snapshot(tmp_path / "a.las") is None
    assert watcher.ready() == {} and watcher.ready() == {}
    data = (leica_dir / "leica_a.wdp").read_bytes()
    (tmp_path / "a.wdp").write_bytes(data[:1000])  # arriving
    assert watcher.ready() == {}
    (tmp_path / "a.wdp").write_bytes(data)
    assert watcher.ready() == {}  # grew since the last look
    ready = watcher.ready()
    assert list(ready) == [str(tmp_path / "a.las")] and ready[str(tmp_path / "a.las")]["a.wdp"]["size"] == len(data)
    (tmp_path / "notes.txt").write_text("not an input")
    assert list(watcher.ready()) == [str(tmp_path / "a.las")]
    # a flight line linked into the folder is known by its target, as fwl run records it
    elsewhere = tmp_path / "store"
    elsewhere.mkdir()
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", elsewhere / f"b{suffix}")
    (tmp_path / "b.las").symlink_to(elsewhere / "b.las")
    watcher.ready()
    assert sorted(watcher.ready()) == sorted([str(elsewhere / "b.las"), str(tmp_path / "a.las")])


def test_due_are_the_ready_inputs_the_output_lacks_or_holds_another_version_of(tmp_path, leica_copy):
    path = str(leica_copy)
    ready = {path: input_identity(path)}
    out = tmp_path / "out"
    assert due(ready, out) == [path]  # no output folder yet
    out.mkdir()
    (out / "fwl-output.json").write_text(json.dumps({"settings": {}, "inputs": [
        {"path": path, "name": "leica_a.las", "stem": "leica_a", "identity": ready[path], "done": False}]}))
    assert due(ready, out) == [path]  # begun, not finished
    (out / "fwl-output.json").write_text(json.dumps({"settings": {}, "inputs": [
        {"path": path, "name": "leica_a.las", "stem": "leica_a", "identity": ready[path], "done": True}]}))
    assert due(ready, out) == []
    assert due({path: {"leica_a.las": {"size": 1, "sha256": "0"}}}, out) == [path]  # replaced


# ---------------------------------------------------------------- the command

def test_watch_processes_a_file_once_complete_once_across_restarts_and_again_when_replaced(tmp_path, leica_dir):
    land, out = tmp_path / "land", tmp_path / "out"
    land.mkdir()
    watcher = fwl_watch(land, out)
    try:
        shutil.copy(leica_dir / "leica_a.las", land / "leica_a.las")
        time.sleep(2.5)  # five polls: the .las alone is not complete
        assert not (out / "run.json").exists()
        shutil.copy(leica_dir / "leica_a.wdp", land / "leica_a.wdp")
        wait_for(lambda: done_inputs(out) == [("leica_a.las", 924)])
        first = (out / "las" / "leica_a.las").stat().st_mtime_ns
        watcher.send_signal(signal.SIGINT)
        stdout, stderr = watcher.communicate(timeout=60)
    finally:
        watcher.kill()
    assert watcher.returncode == 0, stderr
    assert stdout.count("new or replaced file(s): leica_a.las") == 1 and "fwl watch: stopped" in stdout

    # a restart finds the file done: nothing runs
    again = fwl_watch(land, out, "--once")
    stdout, stderr = again.communicate(timeout=120)
    assert again.returncode == 0, stderr
    assert "new or replaced" not in stdout
    assert (out / "las" / "leica_a.las").stat().st_mtime_ns == first

    # a re-delivered flight line under the same name replaces the outputs of the first
    assert main(["simulate", "--pulses", "60", "--seed", "3", "--output", str(land / "leica_a.las"),
                 "--overwrite"]) == 0  # over the Leica file: fwl simulate writes over no file of another unless told
    (land / "leica_a.truth.parquet").unlink()
    (land / "second.las").write_bytes(b"LASF" + bytes(300))  # damaged: rejected with its reason, not retried
    replaced = fwl_watch(land, out, "--once")
    stdout, stderr = replaced.communicate(timeout=180)
    assert replaced.returncode == 0, stderr
    assert "new or replaced file(s): leica_a.las, second.las" in stdout
    summary = read_run(out)
    assert [(i["name"], i["counts"]["pulses_read"], i["counts"]["files_rejected"]) for i in summary["inputs"]] == \
        [("leica_a.las", 60, 0), ("second.las", 0, 1)]
    assert sorted(p.name for p in (out / "pulses").iterdir()) == ["leica_a-000000000000.parquet"]
    # the rejected input counts as done: a restart does not try it again
    last = fwl_watch(land, out, "--once")
    stdout, _ = last.communicate(timeout=120)
    assert "new or replaced" not in stdout


def test_watch_refuses_an_output_made_with_other_settings_before_it_waits(tmp_path, leica_dir, capsys):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--limit", "20", *RUN]) == 0
    (tmp_path / "land").mkdir()
    assert main(["watch", str(tmp_path / "land"), "--output", str(out), "--once", "--optimizer", "none",
                 "--limit", "20", *RUN]) == 2
    assert "holds outputs made with other settings" in capsys.readouterr().err
    assert main(["watch", str(tmp_path / "nowhere"), "--output", str(out), "--once", *RUN]) == 2
    assert "no such folder to watch" in capsys.readouterr().err
    assert main(["watch", str(tmp_path / "land"), "--output", str(out), "--poll", "0", *RUN]) == 2
    assert "--poll must be" in capsys.readouterr().err


def test_a_replaced_inputs_outputs_go_and_no_other_inputs(tmp_path):
    from pipeline.outputs import remove_input_outputs
    files = ["echoes/x-000000000000.parquet", "pulses/x-000000000000.parquet", "rejected/x.parquet", "las/x.las",
             "mcap/x.mcap", "parts/plans/x.json", "parts/x-000000000400.las.tmp",
             "las/x.las.las", "echoes/x.las-000000000000.parquet", "las/xy.las", "logs/x.log"]
    for f in files:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text("")
    gone = remove_input_outputs(tmp_path, "x")
    assert sorted(p.relative_to(tmp_path).as_posix() for p in gone) == sorted(files[:7])
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()) == \
        sorted(files[7:])


# ---------------------------------------------------------------- Ctrl-C

# when the terminal's Ctrl-C comes: as the batch claims the folder (plan job), after its first range (the ranges'
# job), once its 11 ranges are done (the files' job), and while idle after it
CTRL_C_AT = {"claimed": lambda out: (out / "fwl-output.json").is_file(),
             "first range": lambda out: any((out / "parts").glob("*.json")) if (out / "parts").is_dir() else False,
             "ranges done": lambda out: len(list((out / "parts").glob("*.json"))) >= 11
             if (out / "parts").is_dir() else False,
             "idle": lambda out: (out / "run.json").is_file()}


IN_PROCESS, POOL = ["--direct_num_workers=1", "--direct_running_mode=in_memory"], []


# in process, a range's step is interrupted in this process's main thread, where Beam wraps the KeyboardInterrupt
# in a RuntimeError: the watch took it for a failed batch and went on (every time, at "first range")
@pytest.mark.parametrize("at, runner", [("claimed", IN_PROCESS), ("first range", IN_PROCESS), ("first range", POOL),
                                        ("ranges done", POOL), ("idle", IN_PROCESS)])
def test_ctrl_c_stops_the_watch_within_seconds_at_any_moment(tmp_path, leica_dir, at, runner):
    land, out = tmp_path / "land", tmp_path / "out"
    land.mkdir()
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", land / f"leica_a{suffix}")
    watcher = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "watch", str(land), "--output", str(out),
                                "--poll", "0.2", "--preset", "fast", "--formats", "parquet,las",
                                "--points-per-range", "100", *runner], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, start_new_session=True)
    try:
        # the batch may finish, and clear parts/, between two looks: then the Ctrl-C comes while idle
        wait_for(lambda: CTRL_C_AT[at](out) or (out / "run.json").is_file() or watcher.poll() is not None,
                 seconds=240)
        os.killpg(watcher.pid, signal.SIGINT)  # to the process group, as a terminal sends it
        sent = time.monotonic()
        stdout, stderr = watcher.communicate(timeout=30)
        seconds = time.monotonic() - sent
    finally:
        if watcher.poll() is None:
            os.killpg(watcher.pid, signal.SIGKILL)
    assert seconds < 10, seconds
    assert "did not finish" not in stdout and "Traceback" not in stderr, stderr
    finished = (out / "run.json").is_file()  # the batch may end before the signal lands
    assert watcher.returncode == (0 if finished else 130), (at, stdout, stderr)
    if at in ("claimed", "idle"):  # the batch had seconds to go, or none
        assert finished == (at == "idle")
    said = "fwl watch: stopped" in stdout if finished else "interrupted while processing leica_a.las" in stderr
    assert said, (stdout, stderr)


def test_a_batch_stopped_by_the_machine_is_said_in_one_line_and_the_watch_goes_on(tmp_path, leica_copy):
    out, said = tmp_path / "out", []
    fault = MachineFault.of("ENOSPC", "No space left on device", "writing", out / "echoes" / "a.parquet", "a.las")

    def full(paths):
        raise RunStopped([fault], out)

    assert watch(leica_copy.parent, out, DecompositionConfig(), {}, full, poll=0.05, once=True, say=said.append) == 0
    assert said[1:] == ["fwl watch: 1 new or replaced file(s): leica_a.las",
                        f"fwl watch: stopped: {fault.said()}: free space on the disk of {out / 'echoes'}, then the "
                        f"watch tries the batch again at its next poll"]
