import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests import parallel

KERNELS = pytest.StashKey[subprocess.Popen]()
DATA = Path(__file__).resolve().parents[1] / "examples" / "data"


@pytest.fixture(scope="session")
def neon_dir() -> Path:
    return DATA / "neon_harvard"


@pytest.fixture(scope="session")
def leica_waveforms() -> np.ndarray:
    """The Leica sample's 924 distinct packets (8-bit, 256 samples), read straight from the .wdp
    by byte offset: an independent reader for the engine tests, not the project's LAS reader."""
    import laspy

    las = laspy.read(DATA / "leica_als" / "leica_a.las")
    offsets = np.unique(np.asarray(las.wavepacket_offset))
    raw = np.fromfile(DATA / "leica_als" / "leica_a.wdp", dtype=np.uint8)
    return np.stack([raw[o:o + 256] for o in offsets]).astype(np.float64)


@pytest.fixture(scope="session")
def leica_dir() -> Path:
    return DATA / "leica_als"


@pytest.fixture(scope="session")
def pulsewaves_dir() -> Path:
    return DATA / "pulsewaves"


@pytest.fixture
def leica_copy(tmp_path, leica_dir) -> Path:
    """The Leica sample's .las and .wdp copied into the test's folder: a file a test may damage or change."""
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / f"leica_a{suffix}")
    return tmp_path / "leica_a.las"


def _controller_of_workers(config) -> bool:
    return not hasattr(config, "workerinput") and bool(config.getoption("numprocesses", None))


def pytest_configure(config):
    """Under xdist (`make test`): the controller starts the kernels' one compile, the workers wait for it before
    compiling or starting a process (tests/parallel.py)."""
    if _controller_of_workers(config):
        config.stash[KERNELS] = parallel.start_kernels(config.rootpath)
    elif hasattr(config, "workerinput") and parallel.LOCK_ENV in os.environ:
        parallel.wait_before_compiling_or_starting()


def pytest_unconfigure(config):
    if KERNELS in config.stash:
        parallel.stop_kernels(config.stash[KERNELS])


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """--dist loadfile with the files that share a session fixture on one worker (tests/parallel.py)."""
    if config.getvalue("dist") == "loadfile":
        return parallel.SharedSessionScheduling(config, log)
    return None
