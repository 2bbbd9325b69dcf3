"""The C allocator's freed memory kept for the length of a task, in a worker told to hand it back at once.

A Dask worker's nanny starts it with MALLOC_TRIM_THRESHOLD_=65536 (distributed's `pre-spawn-environ`), so that
glibc returns freed memory to the system eagerly. Set by the environment, that also turns off glibc's sliding
mmap threshold: every array above 128 KiB is then mapped and unmapped anew, its pages faulted in on each use.
A tile's or a range's numpy work faulted 11x the pages and took 13% more CPU (`fwl classify` on a million
echoes: 0.79 million page faults in its tasks against 0.07 million). While a task runs, `kept_memory` gives the
allocator glibc's own sliding limits at their top (arrays up to 32 MiB from the heap, 64 MiB of free heap kept);
when the last task running in the process ends, the worker's own settings come back, and the heap is trimmed
at the next free. A process not told to trim (the DirectRunner's workers, the driver) is left as it is.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import os
import threading
from collections.abc import Iterator

TRIM_ENV = "MALLOC_TRIM_THRESHOLD_"
MMAP_ENV = "MALLOC_MMAP_THRESHOLD_"
M_TRIM_THRESHOLD = -1  # mallopt's parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_DEFAULT = 128 << 10  # glibc's mmap threshold where the environment fixed it
TASK_MMAP_THRESHOLD = 32 << 20  # the top of glibc's sliding mmap threshold (64-bit)
TASK_TRIM_THRESHOLD = 2 * TASK_MMAP_THRESHOLD  # glibc's sliding rule: twice the mmap threshold

_LOCK = threading.Lock()
_RUNNING = [0]  # tasks inside kept_memory in this process: the worker's settings come back with the last


@contextlib.contextmanager
def kept_memory() -> Iterator[None]:
    """Within it, freed memory is kept for reuse, where the environment told this process's glibc to trim
    eagerly (see the module); elsewhere nothing changes."""
    libc = _libc() if os.environ.get(TRIM_ENV) is not None else None
    if libc is None:
        yield
        return
    with _LOCK:
        if _RUNNING[0] == 0:
            libc.mallopt(M_MMAP_THRESHOLD, TASK_MMAP_THRESHOLD)
            libc.mallopt(M_TRIM_THRESHOLD, TASK_TRIM_THRESHOLD)
        _RUNNING[0] += 1
    try:
        yield
    finally:
        with _LOCK:
            _RUNNING[0] -= 1
            if _RUNNING[0] == 0:
                libc.mallopt(M_TRIM_THRESHOLD, _env_bytes(TRIM_ENV, 0))
                libc.mallopt(M_MMAP_THRESHOLD, _env_bytes(MMAP_ENV, MMAP_DEFAULT))


def _env_bytes(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:  # glibc reads a malformed value as none given
        return default


@functools.lru_cache(maxsize=1)
def _libc():
    """glibc's mallopt, or None (another C library: nothing to keep)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return libc
