import h5py
import pyproj
import pytest

from fwcore.io.errors import WaveformFileError
from fwcore.io.hdf5 import hdf5_file, holds, wgs84_3d_wkt


def test_opening_names_the_file_and_what_it_should_be(tmp_path):
    with pytest.raises(FileNotFoundError, match="gone.h5: no such GEDI granule"):
        with hdf5_file(tmp_path / "gone.h5", "GEDI granule"):
            pass
    text = tmp_path / "notes.h5"
    text.write_text("not HDF5")
    with pytest.raises(WaveformFileError, match="notes.h5: not a readable HDF5 file"):
        with hdf5_file(text, "LVIS file"):
            pass


def test_a_layout_is_told_by_its_groups(tmp_path):
    path = tmp_path / "g.h5"
    with h5py.File(path, "w") as f:
        f["BEAM0000/rxwaveform"] = [1.0]
    assert holds(path, lambda f: "BEAM0000" in f) and not holds(path, lambda f: "RXWAVE" in f)
    assert not holds(tmp_path / "missing.h5", lambda f: True)
    assert pyproj.CRS.from_wkt(wgs84_3d_wkt()).to_epsg() == 4979
