"""One writer per output folder: the lock names its holder, refuses a second writer, takes over a dead one's."""

import json
import logging
import os
import socket
import subprocess
import sys
import threading
import time

import pytest

from pipeline.layout import LOCK
from pipeline.lock import FolderLockedError, folder_lock, is_alive, read_holder

HOLD = ("import sys, time; from pipeline.lock import folder_lock\n"
        "with folder_lock(sys.argv[1], 'fwl run'):\n"
        "    print('held', flush=True); sys.stdin.read()\n")


def _holder(folder):
    """Another process that holds `folder`'s lock until its stdin closes."""
    process = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline() == "held\n"
    return process


def test_the_lock_names_its_holder_while_held_and_goes_with_it(tmp_path):
    folder = tmp_path / "out"
    with folder_lock(folder, "fwl grid") as held:
        assert held == folder.resolve()
        holder = json.loads((folder / LOCK).read_text())
        assert (holder["command"], holder["host"], holder["pid"]) == ("fwl grid", socket.gethostname(), os.getpid())
        assert holder["started"].endswith("+00:00")
        with folder_lock(folder, "fwl run"):  # this process again (fwl watch's batches): no second file
            assert read_holder(folder / LOCK)["command"] == "fwl grid"
        assert (folder / LOCK).exists()
        (folder / "run.json").write_text("{}")
    assert sorted(p.name for p in folder.iterdir()) == ["run.json"]
    with folder_lock(tmp_path / "refused", "fwl run"):
        pass
    assert not (tmp_path / "refused").exists()  # a command that wrote nothing leaves no folder behind


def test_a_second_writer_is_refused_naming_the_holder_until_it_ends(tmp_path):
    folder = tmp_path / "out"
    process = _holder(folder)
    try:
        began = time.monotonic()
        with pytest.raises(FolderLockedError) as refused:
            with folder_lock(folder, "fwl compact"):
                pass
        assert time.monotonic() - began < 1.0
        assert f"is being written by fwl run (pid {process.pid} on {socket.gethostname()}, since " in \
            str(refused.value)
        assert "wait for it to end, or choose another --output" in str(refused.value)
    finally:
        process.communicate("")
    with folder_lock(folder, "fwl compact"):  # released with its holder's end
        assert read_holder(folder / LOCK)["pid"] == os.getpid()


def test_a_lock_whose_holder_died_is_taken_over_with_a_warning(tmp_path, caplog):
    folder = tmp_path / "out"
    process = _holder(folder)
    process.kill()  # SIGKILL: no clean-up; its file stays, naming it, and the kernel drops its flock
    process.wait()
    assert not is_alive(process.pid) and read_holder(folder / LOCK)["pid"] == process.pid
    with caplog.at_level(logging.WARNING, logger="pipeline.lock"):
        with folder_lock(folder, "fwl run"):
            assert read_holder(folder / LOCK)["pid"] == os.getpid()
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and said[0].startswith(f"{folder.resolve()}: taking over the lock of fwl run "
                                                 f"(pid {process.pid} on {socket.gethostname()}, since ")
    assert said[0].endswith("), which is gone")


def test_a_holder_on_another_host_is_refused_with_how_to_clear_it(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / LOCK).write_text(json.dumps({"command": "fwl watch", "host": "elsewhere", "pid": 4242,
                                           "started": "2026-01-01T00:00:00+00:00"}))
    with pytest.raises(FolderLockedError, match=rf"fwl watch \(pid 4242 on elsewhere, since 2026-01-01T00:00:00"
                                                rf"\+00:00\): wait for it to end; if it is gone, remove .*{LOCK}"):
        with folder_lock(folder, "fwl run"):
            pass
    assert read_holder(folder / LOCK)["host"] == "elsewhere"  # its word stands


def test_another_thread_of_the_holder_is_refused_as_another_process_is(tmp_path):
    refused = []

    def second():
        try:
            with folder_lock(tmp_path / "out", "fwl run"):
                pass
        except FolderLockedError as err:
            refused.append(str(err))

    with folder_lock(tmp_path / "out", "fwl run"):
        thread = threading.Thread(target=second)
        thread.start()
        thread.join()
    assert len(refused) == 1 and f"(pid {os.getpid()} on " in refused[0]


def test_a_file_where_the_folder_should_be_is_refused(tmp_path):
    (tmp_path / "out").write_text("x")
    with pytest.raises(ValueError, match="exists and is not a folder"):
        with folder_lock(tmp_path / "out", "fwl run"):
            pass
