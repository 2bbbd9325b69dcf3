"""HDF5 granules (GEDI L1B, LVIS L1B): opened with errors that name the file, their layouts told apart, their CRS
(WGS84 longitude, latitude and ellipsoid height: EPSG:4979)."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Callable, Iterator

from fwcore.io.errors import WaveformFileError


@contextlib.contextmanager
def hdf5_file(path: str | Path, what: str) -> Iterator:
    """The file opened read-only with h5py; a missing file is a FileNotFoundError naming `what` it should be, an
    unreadable one a WaveformFileError naming the file."""
    import h5py

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such {what}")
    try:
        with h5py.File(path, "r") as f:
            yield f
    except OSError as err:
        raise WaveformFileError(f"{path}: not a readable HDF5 file ({err})") from None


def holds(path: str | Path, layout: Callable) -> bool:
    """Whether the file opens as HDF5 and `layout(file)` says it is of that layout (False for anything else)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return bool(layout(f))
    except (OSError, ValueError):
        return False


def wgs84_3d_wkt() -> str:
    import pyproj

    return pyproj.CRS.from_epsg(4979).to_wkt()
