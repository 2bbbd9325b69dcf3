"""The CRS of an input as every output writes it (fwcore.io.formats.input_crs): --crs, else what the file says."""

import struct

import laspy
import numpy as np
import pyproj
import pytest

from fwcore.io.crs import GIVEN, crs_projjson, parse_crs, unnamed_wkt_from_geokeys
from fwcore.io.formats import input_crs


def _las(path, keys: tuple[int, ...] | None = None, crs: pyproj.CRS | None = None):
    """A small LAS file (no waveforms: the CRS is in the header alone) with GeoTIFF keys (id, value pairs) or a
    WKT record."""
    header = laspy.LasHeader(point_format=6 if crs else 1, version="1.4" if crs else "1.2")
    if keys:
        pairs = [keys[i:i + 2] for i in range(0, len(keys), 2)]
        words = [1, 1, 0, len(pairs)] + [w for k, v in pairs for w in (k, 0, 1, v)]
        header.vlrs.append(laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag",
                                     struct.pack(f"<{len(words)}H", *words)))
    if crs:
        header.add_crs(crs)
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([1.0, 2.0]), np.array([3.0, 4.0]), np.array([5.0, 6.0])
    las.write(path)
    return path


def test_keys_that_name_an_epsg_code_give_its_crs(tmp_path):
    found = input_crs(_las(tmp_path / "a.las", (1024, 1, 3072, 32632)))
    assert found.named and pyproj.CRS.from_wkt(found.wkt).to_epsg() == 32632 and "EPSG:32632" in found.source


def test_keys_with_only_a_unit_give_an_unnamed_crs_in_that_unit(tmp_path, leica_dir):
    leica = input_crs(leica_dir / "leica_a.las")  # projected, metres, no code: the shared sample
    crs = pyproj.CRS.from_wkt(leica.wkt)
    assert not leica.named and crs.is_engineering and crs.to_epsg() is None
    assert [a.unit_name for a in crs.axis_info] == ["metre"] * 3 and [a.direction for a in crs.axis_info] == [
        "east", "north", "up"]
    feet = pyproj.CRS.from_wkt(input_crs(_las(tmp_path / "ft.las", (1024, 1, 3072, 32767, 3076, 9002))).wkt)
    assert feet.axis_info[0].unit_name == "foot" and feet.axis_info[0].unit_conversion_factor == 0.3048
    assert unnamed_wkt_from_geokeys({1024: 1}) is None  # projected, but in no known unit: unknown, not invented
    assert unnamed_wkt_from_geokeys({1024: 2, 2052: 9001}) is None  # geographic without a code is no local CRS
    assert input_crs(_las(tmp_path / "none.las")).wkt is None


def test_a_wkt_record_is_taken_as_it_is(tmp_path):
    found = input_crs(_las(tmp_path / "w.las", crs=pyproj.CRS.from_epsg(32633)))
    assert found.named and found.source == "WKT record" and pyproj.CRS.from_wkt(found.wkt).to_epsg() == 32633


def test_an_earth_centred_pulsewaves_file(pulsewaves_dir):
    found = input_crs(pulsewaves_dir / "riegl_example3.pls")
    assert found.named and pyproj.CRS.from_wkt(found.wkt).to_epsg() == 4978


@pytest.mark.parametrize("given", ["EPSG:25832", "25832", "epsg:25832", pyproj.CRS.from_epsg(25832).to_wkt(),
                                   pyproj.CRS.from_epsg(25832).to_json()])
def test_crs_overrides_what_the_file_says_in_every_form_pyproj_reads(tmp_path, given):
    path = _las(tmp_path / "a.las", crs=pyproj.CRS.from_epsg(32633))  # named wrongly
    found = input_crs(path, given)
    assert found.source == GIVEN and found.named
    assert pyproj.CRS.from_wkt(found.wkt).to_epsg() == 25832 and found.wkt.startswith('PROJCS["ETRS89 / UTM zone 32N"')
    assert pyproj.CRS.from_json(crs_projjson(found.wkt)).to_epsg() == 25832


@pytest.mark.parametrize("given", ["EPSG:99999999", "utm 32", "{\"type\": \"nothing\"}"])
def test_a_crs_pyproj_cannot_read_is_refused_naming_the_option(given):
    with pytest.raises(ValueError, match="--crs .* is not a coordinate reference system"):
        parse_crs(given)


def test_horizontal_metres_turns_a_metre_into_the_axis_unit():
    from fwcore.io.crs import horizontal_metres

    assert horizontal_metres(None) == 1.0
    assert horizontal_metres(pyproj.CRS.from_epsg(32633).to_wkt()) == 1.0
    assert horizontal_metres(pyproj.CRS.from_epsg(4979).to_wkt()) == pytest.approx(111_195.0, rel=1e-4)
    assert horizontal_metres(pyproj.CRS.from_epsg(2249).to_wkt()) == pytest.approx(0.3048006, rel=1e-6)  # US ft
