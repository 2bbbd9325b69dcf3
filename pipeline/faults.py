"""Faults of the machine, told apart from faults of the data.

A full disk, a read-only folder, a lost mount, an I/O error or a process out of memory say nothing about the
pulses: they stop the range (and the run) without a Rejection, so that rejected/ holds only what is wrong with
the data, and a resumed run redoes every range they stopped.

    machine_fault(err, doing, path, where) -> MachineFault | None   an OSError or MemoryError, typed
    raised_as_fault(doing, path, where)                             a with-block that raises them typed
    note_fault(output, name, fault) / noted_faults(output)         a worker's fault, told to the driver
    faults_in(err, output)                                          the distinct faults behind a failed run
    RunStopped                                                      what `fwl run` raises: exit 5, one line each

A MachineFault is carried by its one-line message alone. A worker does not fail its job with it (the
DirectRunner's worker processes could hang on a failed bundle, 1 run in 3 on a full disk): it leaves the range
without its mark and notes the fault in a file beside the marks, or, when the output cannot take even that (a
full disk), in this machine's temporary folder; the driver finds the ranges without a mark and reads the notes.
A fault the driver meets itself (or a job that failed) is found in the error and its text.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import tempfile
from pathlib import Path

from pipeline.layout import FAULT_SUFFIX, PARTS

# errors of the machine whatever the file: no space or quota, no permission, a read-only or lost filesystem,
# an I/O error, no memory, too many open files, a file larger than the filesystem takes
MACHINE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.EIO,
                            errno.ESTALE, errno.ENOTCONN, errno.ENODEV, errno.ENXIO, errno.ENOMEM, errno.ENFILE,
                            errno.EMFILE, errno.EFBIG})
MEMORY = "MemoryError"
READING, WRITING = "reading", "writing"

# what the user does about each cause; {folder} is the folder of the file
REMEDIES = {
    "ENOSPC": "free space on the disk of {folder}", "EDQUOT": "free space or raise the disk quota of {folder}",
    "EFBIG": "write to a filesystem that takes larger files",
    "EACCES": "give this user write (or read) permission on {folder}", "EPERM": "give this user permission on {folder}",
    "EROFS": "mount {folder} writable, or choose another --output",
    "EIO": "check the disk or network mount that holds {folder}", "ESTALE": "remount the network share of {folder}",
    "ENOTCONN": "remount the filesystem of {folder}", "ENODEV": "mount again the disk of {folder}",
    "ENXIO": "mount again the disk of {folder}", "ENOENT": "mount again the disk that holds {folder}",
    "ENOMEM": "give the workers more memory (fewer --direct_num_workers, smaller --points-per-range)",
    MEMORY: "give the workers more memory (fewer --direct_num_workers, smaller --points-per-range)",
    "EMFILE": "raise the open-file limit (ulimit -n)", "ENFILE": "raise the system's open-file limit",
    "ELOST": "see the workers' logs in logs/ (a worker killed by the out-of-memory killer: give it more memory)",
}

_MESSAGE = re.compile(r"machine fault (?P<code>[A-Za-z]+): (?P<strerror>[^;\n]*); (?P<doing>reading|writing): "
                      r"(?P<path>[^;\n]*); range: (?P<where>[^;\n]*?);")


class MachineFault(Exception):
    """An error of the machine, not of the data: its code (ENOSPC, ..., MemoryError), what the system said,
    whether the file was being read or written, the file, and the range (or step) at work."""

    def __init__(self, message: str):
        super().__init__(message)
        found = _MESSAGE.search(message)
        if found is None:
            raise ValueError(f"not a machine fault's message: {message[:200]}")
        self.code, self.strerror, self.doing = found["code"], found["strerror"], found["doing"]
        self.path, self.where = found["path"], found["where"]

    @classmethod
    def of(cls, code: str, strerror: str, doing: str, path: str | Path, where: str) -> "MachineFault":
        clean = [str(v).replace(";", ",").replace("\n", " ") for v in (strerror, path, where)]
        return cls(f"machine fault {code}: {clean[0]}; {doing}: {clean[1]}; range: {clean[2]};")

    def said(self) -> str:
        """The fault for a person, in one line: the cause, the file and the range."""
        where = f" ({self.where})" if self.where else ""
        return f"{self.strerror} ({self.code}) {self.doing} {self.path}{where}"

    def remedy(self) -> str:
        path = Path(self.path)
        folder = path if path.suffix == "" else path.parent
        return REMEDIES.get(self.code, "fix the machine's fault").format(folder=folder)


def machine_fault(err: BaseException, doing: str, path: str | Path, where: str = "") -> MachineFault | None:
    """`err` as a MachineFault when it is one (None for a fault of the data): a MemoryError, an OSError of
    MACHINE_ERRNOS, or, when writing, a folder that went missing (ENOENT: a lost mount, a removed output)."""
    if isinstance(err, MachineFault):
        return err
    if isinstance(err, MemoryError):
        return MachineFault.of(MEMORY, "out of memory", doing, path, where)
    if not isinstance(err, OSError) or err.errno is None:
        return None
    if err.errno not in MACHINE_ERRNOS and not (err.errno == errno.ENOENT and doing == WRITING):
        return None
    return MachineFault.of(errno.errorcode.get(err.errno, str(err.errno)), os.strerror(err.errno), doing,
                           err.filename or path, where)


@contextlib.contextmanager
def raised_as_fault(doing: str, path: str | Path, where: str = ""):
    """Within the block, a machine's error is raised as a MachineFault (from it); any other error as it is."""
    try:
        yield
    except Exception as err:  # noqa: BLE001  only the machine's are retyped; the rest go on unchanged
        fault = machine_fault(err, doing, path, where)
        if fault is None or fault is err:
            raise
        raise fault from err


def _elsewhere(output: str | Path) -> Path:
    """Where a worker notes a fault the output cannot take (a full disk): this machine's temporary folder."""
    key = hashlib.sha256(str(Path(output).resolve()).encode()).hexdigest()[:16]
    return Path(tempfile.gettempdir()) / "fwl-faults" / key


def note_fault(output: str | Path, name: str, fault: MachineFault) -> None:
    """The fault of the range (or input) `name`, for the driver: beside the marks, else in the temporary folder;
    a note that neither takes is lost (the driver then finds the range without its mark all the same)."""
    text = str(fault)
    for folder in (Path(output) / PARTS, _elsewhere(output)):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / f"{name}{FAULT_SUFFIX}").write_text(text)
            return
        except OSError:
            continue


def noted_faults(output: str | Path) -> list[MachineFault]:
    """The faults workers noted for this output (both places), one per cause."""
    found = []
    for folder in (Path(output) / PARTS, _elsewhere(output)):
        for path in sorted(folder.glob(f"*{FAULT_SUFFIX}")) if folder.is_dir() else []:
            try:
                found += [MachineFault(m.group(0)) for m in _MESSAGE.finditer(path.read_text())]
            except OSError:
                continue
    return _one_per_cause(found)


def clear_faults(output: str | Path) -> None:
    """The notes of an earlier attempt, gone before a job (a fault that stays is noted again)."""
    for folder in (Path(output) / PARTS, _elsewhere(output)):
        for path in folder.glob(f"*{FAULT_SUFFIX}") if folder.is_dir() else []:
            with contextlib.suppress(OSError):
                path.unlink()
    with contextlib.suppress(OSError):
        _elsewhere(output).rmdir()


def output_fault(output: str | Path, unfinished: int) -> MachineFault:
    """What the driver can say of ranges that ended without their mark and without a note: a full disk if the
    output's has no space left, else a worker lost (killed, out of memory)."""
    try:
        stats = os.statvfs(output)
        full = stats.f_bavail * stats.f_frsize < (1 << 20)
    except OSError:
        full = False
    if full:
        return MachineFault.of("ENOSPC", os.strerror(errno.ENOSPC), WRITING, output, f"{unfinished} ranges")
    return MachineFault.of("ELOST", "ended without a word (a worker killed, or out of memory?)", WRITING, output,
                           f"{unfinished} ranges")


def _one_per_cause(faults: list[MachineFault]) -> list[MachineFault]:
    distinct: dict[str, MachineFault] = {}
    for fault in faults:
        distinct.setdefault(fault.code, fault)
    return list(distinct.values())


def faults_in(err: BaseException, output: str | Path) -> list[MachineFault]:
    """The distinct machine faults behind `err` (one per code, the first said), from the error and its chain
    and from their text (a worker's fault reaches the driver as text inside Beam's error); [] when none."""
    found: list[MachineFault] = []
    seen: set[int] = set()
    e: BaseException | None = err
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        direct = machine_fault(e, WRITING, output, "the driver")
        found += [direct] if direct is not None and not isinstance(e, MachineFault) else []
        for text in (str(e), *(str(a) for a in getattr(e, "args", ())[1:] if isinstance(a, str))):
            for m in _MESSAGE.finditer(text):
                found.append(MachineFault(m.group(0)))
        e = e.__cause__ or e.__context__
    return _one_per_cause(found)


class RunStopped(Exception):
    """A run stopped by faults of the machine (MachineFault): nothing rejected for them, the ranges that finished
    kept for --resume."""

    def __init__(self, faults: list[MachineFault], output: str | Path, finished: int | None = None,
                 ranges: int | None = None):
        self.faults, self.output = faults, str(output)
        self.finished, self.ranges = finished, ranges  # the ranges that ended, of all: the first are kept
        super().__init__("; ".join(f.said() for f in faults))

    def lines(self, resume: str) -> list[str]:
        """One line per cause: what, which file, the remedy, and how to go on (`resume`: the command)."""
        return [f"{f.said()}: {f.remedy()}, then {resume}" for f in self.faults]
