"""How `make test`'s two xdist workers share a cold session (tests/conftest.py's hooks call these).

- The engine's kernel (fwcore.engine.decompose, most of a cold session's compile time) compiles once, in a
  background process the controller starts before the workers: numba's cache then serves the workers, the Beam
  and `fwl` processes the tests start, and the Dask workers. Until it is done, a worker that is about to compile
  that kernel or start a Python process waits for it (a shared lock the background process holds), while tests
  that need neither run (other kernels, small, compile where they are needed); without the wait both workers
  and every process they start compiled the same kernel at once.
- Test files that share a session fixture are one unit of `--dist loadfile` (SHARED_SESSION): the fixture is
  then made on one worker, not on each.
"""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from xdist.scheduler import LoadFileScheduling

LOCK_ENV = "FWL_TEST_KERNELS_LOCK"
WARMED = "fwcore.engine.decompose"  # the module of the kernels the background process compiles
WARM_UP = ("from fwcore.engine.config import DecompositionConfig; from pipeline.stages import warm_up; "
           "warm_up(DecompositionConfig())")

# a prefix of the node ids -> the unit its files run in, with the session fixture they share
SHARED_SESSION = {
    "tests/pipeline/view/": "viewer runs",  # viewed, gedi_viewed, gridded (tests/pipeline/view/conftest.py)
    **{f"tests/pipeline/{name}.py": "forest run" for name in  # forest_run (tests/pipeline/conftest.py)
       ("test_forest_maps", "test_footprints", "test_tiled", "test_biomass_maps", "test_classify")},
}


class SharedSessionScheduling(LoadFileScheduling):
    """--dist loadfile, with the files of each SHARED_SESSION group one unit."""

    def _split_scope(self, nodeid: str) -> str:
        for prefix, group in SHARED_SESSION.items():
            if nodeid.startswith(prefix):
                return group
        return super()._split_scope(nodeid)


def start_kernels(rootdir: Path) -> subprocess.Popen:
    """The background compile (see the module), holding an exclusive lock on a file named in LOCK_ENV, which the
    workers inherit; the lock goes with the process."""
    fd, lock = tempfile.mkstemp(prefix="fwl-kernels-", suffix=".lock")
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        proc = subprocess.Popen([sys.executable, "-c", WARM_UP], cwd=rootdir, pass_fds=(fd,),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    finally:
        os.close(fd)  # the child's copy holds the lock
    os.environ[LOCK_ENV] = lock
    return proc


def stop_kernels(proc: subprocess.Popen) -> None:
    """End of the session: the background compile reaped (it ended long before, or the session was cut short)."""
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    os.unlink(os.environ.pop(LOCK_ENV))


_waited = False


def wait_for_kernels() -> None:
    """Block until the background compile has ended; at once outside a parallel session. A fixture that starts a
    process behind a deadline (the viewer's background job, behind an HTTP request's) waits here first, so the
    compile's minutes do not count against that deadline."""
    global _waited
    if not _waited and LOCK_ENV in os.environ:
        with open(os.environ[LOCK_ENV]) as f:
            fcntl.flock(f, fcntl.LOCK_SH)  # free once the background compile has ended, however it ended
        _waited = True


def _runs_python(args) -> bool:
    """Whether a command is this environment's Python or one of its scripts (fwl, dask): a process that may compile
    kernels. Others (ldconfig for ctypes, chromium, git) never wait."""
    program = Path(args if isinstance(args, (str, bytes, os.PathLike)) else args[0])
    program = Path(os.fsdecode(program))
    return program == Path(sys.executable) or program.parent == Path(sys.executable).parent


def wait_before_compiling_or_starting() -> None:
    """In a worker: compiling WARMED's kernels and starting a Python process (subprocess.Popen) wait for the
    background compile."""
    from numba.core.dispatcher import Dispatcher

    compile_ = Dispatcher.compile

    def compile_after_warm_up(self, sig):
        if self.py_func.__module__ == WARMED:  # other kernels are small: waiting would cost more than compiling
            wait_for_kernels()
        return compile_(self, sig)

    class PopenAfterWarmUp(subprocess.Popen):
        def __init__(self, args, *rest, **kwargs):
            if _runs_python(args):
                wait_for_kernels()
            super().__init__(args, *rest, **kwargs)

    Dispatcher.compile = compile_after_warm_up
    subprocess.Popen = PopenAfterWarmUp
