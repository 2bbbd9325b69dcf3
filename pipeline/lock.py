"""One writer per output folder: a lock file in the folder, held with flock for as long as a command writes.

    with folder_lock(folder, "fwl run"):    # FolderLockedError (exit 2) naming the holder when another has it
        ...

The file (LOCK, beside the manifest) names its holder: the command, the host, the pid and when it began. The
kernel releases a flock when its holder dies, even by SIGKILL, so a lock left by a dead holder on this host is
taken over, with a warning naming it. A holder on another host cannot be seen: its lock is refused, with how to
remove it if that holder is gone. A process that holds a folder's lock takes it again freely (fwl watch holds
its output's for its batches' runs); another thread of it is refused as another process would be. Readers
(fwl view) take no lock.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import fcntl
import json
import logging
import os
import socket
import threading
from pathlib import Path

from pipeline.layout import LOCK
from pipeline.outputs import OutputFolderError

LOG = logging.getLogger(__name__)
# (folder, thread) -> how many times that thread of this process took it (the outermost releases it); another
# thread (fwl view's jobs) opens the file anew, and flock refuses it as it would another process
_HELD: dict[tuple[str, int], int] = {}


class FolderLockedError(OutputFolderError):
    """Another command is writing the output folder: exit 2, naming it."""


def holder_record(command: str) -> dict:
    """What the lock file says of its holder."""
    return {"command": command, "host": socket.gethostname(), "pid": os.getpid(),
            "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def read_holder(path: Path) -> dict | None:
    """The holder a lock file names (None: no file, or nothing readable in it)."""
    try:
        holder = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return holder if isinstance(holder, dict) else None


def describe(holder: dict | None) -> str:
    if not holder:
        return "another process (it has not said which yet)"
    return (f"{holder.get('command', 'fwl')} (pid {holder.get('pid')} on {holder.get('host')}, since "
            f"{holder.get('started')})")


def is_alive(pid: int) -> bool:
    """Whether a process of this host has this pid (one of another user counts as alive)."""
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (TypeError, ValueError, OverflowError):
        return False
    return True


def _refuse(folder: Path, holder: dict | None, hint: str) -> FolderLockedError:
    return FolderLockedError(f"{folder}: is being written by {describe(holder)}: {hint}")


def _take(folder: Path, command: str) -> int:
    """The lock's descriptor, its file naming this process; FolderLockedError when another holds it."""
    path = folder / LOCK
    while True:
        fd, locked = os.open(path, os.O_RDWR | os.O_CREAT, 0o644), True
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            if err.errno != errno.ENOLCK:  # held; a filesystem without locks leaves the file's word alone
                os.close(fd)
                if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise _refuse(folder, read_holder(path), "wait for it to end, or choose another --output") \
                        from None
                raise
            locked = False
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)  # its holder removed it between our open and our flock: take the new one
    before = read_holder(path)
    if before and before.get("host") != socket.gethostname():
        os.close(fd)  # a flock may not reach across hosts: the holder's word stands
        raise _refuse(folder, before, f"wait for it to end; if it is gone, remove {path}")
    if before and before.get("pid") != os.getpid():
        if not locked and is_alive(before.get("pid")):
            os.close(fd)
            raise _refuse(folder, before, "wait for it to end, or choose another --output")
        LOG.warning("%s: taking over the lock of %s, which is gone", folder, describe(before))
    os.ftruncate(fd, 0)
    os.pwrite(fd, (json.dumps(holder_record(command)) + "\n").encode(), 0)
    return fd


@contextlib.contextmanager
def folder_lock(folder: str | Path, command: str):
    """Hold `folder`'s lock (made, with the folder, if need be) for the block; released, its file removed, after.
    FolderLockedError names the holder when another process has it; OutputFolderError when `folder` is a file."""
    folder = Path(folder).resolve()
    key = (str(folder), threading.get_ident())
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield folder
        finally:
            _HELD[key] -= 1
        return
    if folder.exists() and not folder.is_dir():
        raise OutputFolderError(f"{folder}: exists and is not a folder; choose another --output")
    made = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    try:
        fd = _take(folder, command)
    except BaseException:
        if made:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    _HELD[key] = 1
    try:
        yield folder
    finally:
        del _HELD[key]
        with contextlib.suppress(OSError):
            (folder / LOCK).unlink()  # before the flock goes: a waiting writer then takes a new file
        os.close(fd)
        if made and not any(folder.iterdir()):  # a command refused before writing leaves no folder behind
            with contextlib.suppress(OSError):
                folder.rmdir()
