"""Faults of the machine told apart from faults of the data, and carried by their one-line message."""

import errno
import os

import pytest

from pipeline.faults import (MACHINE_ERRNOS, MEMORY, READING, WRITING, MachineFault, RunStopped, clear_faults,
                             faults_in, machine_fault, note_fault, noted_faults, output_fault, raised_as_fault)


@pytest.mark.parametrize("number", sorted(MACHINE_ERRNOS))
def test_every_machine_errno_is_a_fault_reading_or_writing(number):
    err = OSError(number, os.strerror(number))
    for doing in (READING, WRITING):
        fault = machine_fault(err, doing, "/out/echoes/a-000000000000.parquet", "a.las points 0-400")
        assert (fault.code, fault.strerror, fault.doing, fault.path, fault.where) == \
            (errno.errorcode[number], os.strerror(number), doing, "/out/echoes/a-000000000000.parquet",
             "a.las points 0-400")


def test_a_missing_file_is_the_machines_only_when_writing_and_data_errors_never():
    gone = FileNotFoundError(errno.ENOENT, "No such file or directory")
    assert machine_fault(gone, WRITING, "/lost/mount/x.las").code == "ENOENT"
    assert machine_fault(gone, READING, "/in/gone.wdp") is None  # an input's packet file gone: its data's fault
    assert machine_fault(ValueError("x scale 0"), READING, "/in/a.las") is None
    assert machine_fault(OSError("no errno"), WRITING, "/out") is None
    assert machine_fault(NotADirectoryError(errno.ENOTDIR, "Not a directory"), WRITING, "/out") is None
    memory = machine_fault(MemoryError(), READING, "/in/a.las", "a.las points 0-400")
    assert (memory.code, memory.strerror) == (MEMORY, "out of memory")
    assert "fewer --direct_num_workers" in memory.remedy()


def test_the_file_an_oserror_names_is_the_one_said():
    err = PermissionError(errno.EACCES, "Permission denied", "/out/pulses/a.parquet.tmp")
    fault = machine_fault(err, WRITING, "/out", "a.las points 0-400")
    assert fault.said() == "Permission denied (EACCES) writing /out/pulses/a.parquet.tmp (a.las points 0-400)"
    assert fault.remedy() == "give this user write (or read) permission on /out/pulses"


def test_the_message_alone_carries_the_fault_through_beams_rebuilt_error():
    fault = MachineFault.of("ENOSPC", "No space left on device", WRITING, "/out/parts/a; b.mcap", "a.las points 0-1125")
    # Beam adds the step's name by building the same type from the first argument (runners/common.py)
    rebuilt = type(fault)(fault.args[0] + " [while running 'DecomposeFlight/RangeStages']", *fault.args[1:])
    assert (rebuilt.code, rebuilt.path, rebuilt.where) == ("ENOSPC", "/out/parts/a, b.mcap", "a.las points 0-1125")
    assert rebuilt.said() == fault.said() == \
        "No space left on device (ENOSPC) writing /out/parts/a, b.mcap (a.las points 0-1125)"
    assert "\n" not in str(fault) and len(str(fault)) < 200
    with pytest.raises(ValueError, match="not a machine fault"):
        MachineFault("disk full")


def test_faults_are_found_in_a_workers_error_text_and_in_the_drivers_own_errors():
    fault = MachineFault.of("ENOSPC", "No space left on device", WRITING, "/out/echoes/a.parquet", "a.las points 0-5")
    other = MachineFault.of("EIO", "Input/output error", READING, "/in/b.las", "b.las points 0-5")
    # a worker process's error reaches the driver as text in Beam's RuntimeError, twice said, among other lines
    text = (f"Pipeline failed in state FAILED: Traceback (most recent call last):\n  ...\nOSError: [Errno 28] No "
            f"space left on device\n\npipeline.faults.MachineFault: {fault} [while running 'RangeStages']\n"
            f"{fault}\n{other}")
    found = faults_in(RuntimeError(text), "/out")
    assert [f.said() for f in found] == [fault.said(), other.said()]  # one per cause
    try:
        try:
            raise OSError(errno.EDQUOT, "Disk quota exceeded")
        except OSError as err:
            raise RuntimeError("summarising failed") from err
    except RuntimeError as err:
        assert [(f.code, f.path, f.where) for f in faults_in(err, "/out")] == [("EDQUOT", "/out", "the driver")]
    assert faults_in(ValueError("bad option"), "/out") == []


def test_raised_as_fault_retypes_the_machines_errors_only():
    with pytest.raises(MachineFault) as caught:
        with raised_as_fault(WRITING, "/out/parts/a.json", "a.las points 0-5"):
            raise OSError(errno.EROFS, "Read-only file system")
    assert caught.value.code == "EROFS" and isinstance(caught.value.__cause__, OSError)
    assert caught.value.remedy() == "mount /out/parts writable, or choose another --output"
    with pytest.raises(ValueError):
        with raised_as_fault(WRITING, "/out"):
            raise ValueError("a damaged packet")


def test_a_stopped_run_says_one_line_per_cause_with_the_remedy_and_the_resume():
    faults = [MachineFault.of("ENOSPC", "No space left on device", WRITING, "/out/echoes/a.parquet", "a.las points 0-5")]
    stopped = RunStopped(faults, "/out")
    assert stopped.lines("fwl run a.las --output /out --resume") == [
        "No space left on device (ENOSPC) writing /out/echoes/a.parquet (a.las points 0-5): free space on the disk "
        "of /out/echoes, then fwl run a.las --output /out --resume"]
    assert str(stopped) == faults[0].said()


def test_a_fault_noted_where_the_output_takes_nothing_is_found_in_the_temporary_folder(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "parts").write_text("a file where parts/ should be: the output takes no note")
    fault = MachineFault.of("ENOSPC", "No space left on device", "writing", out / "echoes" / "a.parquet", "a.las")
    note_fault(out, "a-000000000000", fault)
    assert [f.said() for f in noted_faults(out)] == [fault.said()]
    clear_faults(out)
    assert noted_faults(out) == []


def test_ranges_ended_without_a_word_are_a_full_disk_only_when_it_is_full(tmp_path):
    lost = output_fault(tmp_path, 3)
    assert (lost.code, lost.where) == ("ELOST", "3 ranges") and "out-of-memory killer" in lost.remedy()
