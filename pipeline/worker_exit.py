"""A DirectRunner worker process that ends at once when its harness is done.

Beam's DirectRunner (multi_processing) starts each worker as a subprocess and, at the job's end, waits for
each in turn to exit. A worker's interpreter then takes seconds to tear itself down (numba's and Beam's
modules, gRPC's threads): on the RIEGL-like line the ranges' job ended 4-8 s after its last range, its two
workers' exits one after the other. `leave_quickly_at_exit()` (called in a DoFn's setup) makes the worker's
exit, once its harness returned, an os._exit with the code it would have had, after its logs are flushed.
Nothing changes in any other process: the driver, Dask's workers, a job run in the driver's process.

The `fwl` command itself (pipeline.cli.entry) leaves the same way once its work is done and said: `leave_now`,
with the command's exit code. After `fwl run` on the RIEGL-like line its interpreter's teardown took 1.2 s.
"""

from __future__ import annotations

import atexit
import logging
import os
import sys

HARNESS_VARIABLE = "CONTROL_API_SERVICE_DESCRIPTOR"  # set by Beam's SubprocessSdkWorker for its worker only
_registered: list[bool] = []
_failed: list[bool] = []


def is_subprocess_worker() -> bool:
    """Whether this process is a DirectRunner worker Beam started as a subprocess (not the driver, nor Dask's)."""
    return bool(os.environ.get(HARNESS_VARIABLE)) and sys.argv[0].endswith("sdk_worker_main.py")


def _flush() -> None:
    for handler in logging.getLogger().handlers + logging.getLogger("fwl").handlers:
        handler.flush()
    sys.stdout.flush()
    sys.stderr.flush()


def _leave() -> None:
    _flush()
    os._exit(1 if _failed else 0)


def leave_now(code: int) -> None:
    """This process ends at once with `code`, its logs and output flushed, without the interpreter's teardown:
    for a command whose work is done (every file it wrote is closed)."""
    _flush()
    os._exit(code)


def leave_quickly_at_exit(force: bool = False) -> bool:
    """In a subprocess worker (or with `force`), exit without the interpreter's teardown once the harness
    returned: with 1 when an exception went uncaught, else 0. Registered once; whether it was."""
    if _registered:
        return True
    if not (force or is_subprocess_worker()):
        return False
    hook = sys.excepthook

    def noted(kind, value, traceback):  # the harness failed: the exit says so
        _failed.append(True)
        hook(kind, value, traceback)
    sys.excepthook = noted
    atexit.register(_leave)  # atexit runs its last registered first: before the others' teardown
    _registered.append(True)
    return True
