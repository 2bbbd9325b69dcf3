import shutil
from pathlib import Path

import numpy as np
import pytest

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
