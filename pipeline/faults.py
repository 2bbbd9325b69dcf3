"""Faults of the machine, told apart from faults of the data.

A full disk, a read-only folder, a lost mount, an I/O error or a process out of memory say nothing about the
pulses: they stop the range (and the run) without a Rejection, so that rejected/ holds only what is wrong with
the data, and a resumed run redoes every range they stopped.

    machine_fault(err, doing, path, where) -> MachineFault | None   an OSError or MemoryError, typed
    raised_as_fault(doing, path, where)                             a with-block that raises them typed
    faults_in(err, output)                                          the distinct faults behind a failed run
    RunStopped                                                      what `fwl run` raises: exit 5, one line each

A MachineFault is carried by its one-line message alone: Beam's worker processes hand the driver an error's
text, not the error, and Beam rebuilds an error from its first argument when it adds the step's name.
"""

from __future__ import annotations

import contextlib
import errno
import re
from pathlib import Path

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
    import os

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
    distinct: dict[str, MachineFault] = {}
    for fault in found:
        distinct.setdefault(fault.code, fault)
    return list(distinct.values())


class RunStopped(Exception):
    """A run stopped by faults of the machine (MachineFault): nothing rejected for them, the ranges that finished
    kept for --resume."""

    def __init__(self, faults: list[MachineFault], output: str | Path):
        self.faults, self.output = faults, str(output)
        super().__init__("; ".join(f.said() for f in faults))

    def lines(self, resume: str) -> list[str]:
        """One line per cause: what, which file, the remedy, and how to go on (`resume`: the command)."""
        return [f"{f.said()}: {f.remedy()}, then {resume}" for f in self.faults]
