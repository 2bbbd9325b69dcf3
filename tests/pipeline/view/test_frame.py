"""The map's frames against PROJ: a geographic run (GEDI's EPSG:4979) in east and north metres about its centre
agrees with PROJ's topocentric conversion over a GEDI granule's extent; the frame's SQL is its arithmetic; a grid
of degrees is placed where the frame draws its cells."""

import duckdb
import numpy as np
import pyproj
import pytest

from pipeline.view import frame as frames
from pipeline.view import grids

# the shared GEDI granule's echoes span 0.030 degrees of longitude and 0.030 of latitude about this centre
LON0, LAT0, HALF = -44.125131, -13.735071, 0.015


def _points():
    """A 21 x 21 lattice over the granule's extent, corners included (where the planes part most)."""
    steps = np.linspace(-HALF, HALF, 21)
    lon, lat = (v.ravel() for v in np.meshgrid(LON0 + steps, LAT0 + steps))
    return lon, lat, np.random.default_rng(57).uniform(770.0, 810.0, lon.size)


def test_a_geographic_run_is_drawn_in_metres_as_proj_places_them():
    lon, lat, h = _points()
    view = frames.of_crs(pyproj.CRS.from_epsg(4979), {"x": [LON0 - HALF, LON0 + HALF], "y": [LAT0 - HALF, LAT0 + HALF],
                                                      "z": [770.0, 810.0]})
    east, north, up = view.apply(lon, lat, h)
    # PROJ: the geodetic points to earth-centred, then east/north/up about the centre on the ground
    to_ecef = pyproj.Transformer.from_crs(4979, 4978, always_xy=True)
    x0, y0, z0 = to_ecef.transform(LON0, LAT0, 0.0)
    enu = pyproj.Transformer.from_pipeline(f"+proj=topocentric +X_0={x0!r} +Y_0={y0!r} +Z_0={z0!r} +ellps=WGS84")
    e, n, _ = enu.transform(*to_ecef.transform(lon, lat, np.zeros_like(h)))  # where the ground's ellipsoid is
    # 0.12 m at the corners of 3.3 km (the meridians converge, the equirectangular map keeps them parallel): what a
    # map to pick shots from shows; a point 800 m up would lie 800 m / 6,378 km x 1.5 km = 0.19 m further out in
    # PROJ's plane, an echo's map place does not
    apart = np.hypot(east - e, north - n)
    assert apart.max() < 0.15 and np.median(apart) < 0.05
    assert np.abs(east).max() > 1500  # metres, not 0.015 degrees
    assert np.array_equal(up, h)  # heights as they are: the ellipsoidal heights of the run's ground_z
    assert view.labels == ("east (m) from the run's centre", "north (m) from the run's centre", "height (m)")
    assert view.crs == "WGS 84 (EPSG:4979)"
    assert view.centre == "13.735071°S 44.125131°W"
    # a degree of latitude is 110.6 km at 13.7 degrees (the meridional arc), one of longitude 108.2 km
    _, sx, _, sy = view.xy_scale()
    geod = pyproj.Geod(ellps="WGS84")
    assert sy == pytest.approx(geod.inv(LON0, LAT0 - 0.5, LON0, LAT0 + 0.5)[2], rel=1e-5)
    assert sx == pytest.approx(geod.inv(LON0 - 0.0005, LAT0, LON0 + 0.0005, LAT0)[2] * 1000, rel=1e-6)


@pytest.mark.parametrize("epsg, bounds", [
    (4979, {"x": [-44.14, -44.11], "y": [-13.75, -13.72], "z": [770.0, 808.0]}),
    (4978, {"x": [4_100_000.0, 4_100_500.0], "y": [1_000_000.0, 1_000_300.0], "z": [4_700_000.0, 4_700_100.0]}),
    (25832, {"x": [500_000.0, 500_100.0], "y": [5_400_000.0, 5_400_100.0], "z": [0.0, 30.0]})])
def test_the_frames_sql_is_its_arithmetic(epsg, bounds):
    view = frames.of_crs(pyproj.CRS.from_epsg(epsg), bounds)
    rng = np.random.default_rng(epsg)
    xyz = [rng.uniform(lo, hi, 50) for lo, hi in (bounds["x"], bounds["y"], bounds["z"])]
    con = duckdb.connect()
    con.register("points", {"x": xyz[0], "y": xyz[1], "z": xyz[2]})
    fx, fy, fz = view.sql()
    got = con.execute(f"SELECT {fx}, {fy}, {fz} FROM points").fetchnumpy()
    for served, applied in zip(got.values(), view.apply(*xyz)):
        assert np.allclose(served, applied, rtol=0, atol=1e-6)
    assert view.planar == (epsg != 4978)  # the rotation of an earth-centred run mixes x, y and z


def test_a_grid_of_degrees_is_placed_where_the_map_draws_its_cells():
    view = frames.equirectangular("WGS 84", LON0, LAT0, 6378137.0, 298.257223563)
    _, sx, _, sy = view.xy_scale()
    layer = {"x0": LON0 + 0.0001, "dx": 0.0002, "west": LON0, "east": LON0 + 0.002,
             "y0": LAT0 - 0.0009, "dy": 0.0002, "north": LAT0, "south": LAT0 - 0.001, "shown_cell_m": 0.0002}
    placed = grids.in_frame(layer, view)
    assert placed["west"] == 0.0 and placed["north"] == 0.0
    assert placed["dx"] == pytest.approx(0.0002 * sx) and placed["dy"] == pytest.approx(0.0002 * sy)
    assert placed["x0"] == pytest.approx(0.0001 * sx) and placed["y0"] == pytest.approx(-0.0009 * sy)
    assert placed["dx"] == pytest.approx(21.6, abs=0.1) and placed["dy"] == pytest.approx(22.1, abs=0.1)  # metres
    box = (-100.0, 50.0, -30.0, 20.0)
    assert grids.crs_box(box, view) == pytest.approx((LON0 - 100 / sx, LON0 + 50 / sx, LAT0 - 30 / sy, LAT0 + 20 / sy))
    assert grids.cell_words(0.0002, view) == "0.0002° (21.6 × 22.1 m)"
    assert grids.cell_words(2.0, frames.Frame(("x", "y", "z"))) == "2 m"
