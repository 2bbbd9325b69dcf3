"""Trajectories and GPS time systems: SBET and CSV files read (and refused, naming the file and the fix), an SBET
put in the input's CRS, positions at the pulses' times across time systems, and the check of a trajectory against
a file's pulses."""

import math
import os
import re
from pathlib import Path

import numpy as np
import pyproj
import pytest

from fwcore.radiometry.errors import RadiometryError
from fwcore.radiometry.trajectory import (SBET_RECORD, Trajectory, check_trajectory, load_trajectory, read_sbet,
                                          to_time_system)

DOWN = np.array([0.0, 0.0, -1.0])


def write_csv(path, text):
    path.write_text(text)
    return path


def write_sbet(path, gps_time, lat_rad, lon_rad, height):
    records = np.zeros(len(gps_time), dtype=SBET_RECORD)
    records["gps_time"], records["latitude"], records["longitude"], records["height"] = (
        gps_time, lat_rad, lon_rad, height)
    records.tofile(path)
    return path


# ---------------------------------------------------------------- SBET and CSV trajectories

def test_sbet_reads_times_and_degrees_and_height(tmp_path):
    path = write_sbet(tmp_path / "sbet.out", [10.0, 11.0], [math.radians(45.0), math.radians(-30.5)],
                      [math.radians(9.0), math.radians(-120.25)], [350.0, 410.5])
    times, geographic = read_sbet(path)
    np.testing.assert_array_equal(times, [10.0, 11.0])
    np.testing.assert_allclose(geographic, [[9.0, 45.0, 350.0], [-120.25, -30.5, 410.5]], rtol=1e-12)


def test_sbet_of_a_partial_record_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "broken_sbet.out"
    path.write_bytes(b"\0" * (136 * 2 + 5))
    with pytest.raises(RadiometryError, match="broken_sbet.out.*277 bytes"):
        read_sbet(path)
    empty = tmp_path / "empty.out"
    empty.write_bytes(b"")
    with pytest.raises(RadiometryError, match="empty.out"):
        read_sbet(empty)


def test_sbet_with_latitudes_in_degrees_is_refused(tmp_path):
    path = write_sbet(tmp_path / "degrees.out", [10.0, 11.0], [45.0, 45.1], [0.1, 0.1], [300.0, 300.0])
    with pytest.raises(RadiometryError, match="not radians"):
        read_sbet(path)


def test_csv_trajectory_loads_as_is_in_week_seconds(tmp_path):
    path = write_csv(tmp_path / "traj.csv", "gps_time,x,y,z\n100.0,1,2,3\n101.5,4,5,6\n103,7,8,9\n")
    trajectory = load_trajectory(path, None, "a.las")
    np.testing.assert_array_equal(trajectory.gps_time, [100.0, 101.5, 103.0])
    np.testing.assert_array_equal(trajectory.xyz, [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    assert trajectory.time_system == "week"


def test_csv_columns_are_found_by_header_name(tmp_path):
    path = write_csv(tmp_path / "traj.csv", "z, X ,time,y\n3,1,100,2\n6,4,101,5\n")
    trajectory = load_trajectory(path, None, "a.las")
    np.testing.assert_array_equal(trajectory.gps_time, [100.0, 101.0])
    np.testing.assert_array_equal(trajectory.xyz, [[1, 2, 3], [4, 5, 6]])


def test_csv_in_standard_gps_seconds_is_adjusted_by_1e9(tmp_path):
    path = write_csv(tmp_path / "traj.csv", "gps_time,x,y,z\n1300000000.25,0,0,0\n1300000001.5,1,1,1\n")
    trajectory = load_trajectory(path, None, "a.las")
    np.testing.assert_allclose(trajectory.gps_time, [300000000.25, 300000001.5], rtol=0, atol=1e-6)
    assert trajectory.time_system == "adjusted"


def test_csv_in_adjusted_standard_time_stays_as_is(tmp_path):
    path = write_csv(tmp_path / "traj.csv", "gps_time,x,y,z\n300000000.0,0,0,0\n300000001.0,1,1,1\n")
    trajectory = load_trajectory(path, None, "a.las")
    np.testing.assert_array_equal(trajectory.gps_time, [300000000.0, 300000001.0])
    assert trajectory.time_system == "adjusted"


def test_csv_without_z_is_refused_naming_its_header(tmp_path):
    path = write_csv(tmp_path / "traj.csv", "gps_time,x,y\n1,2,3\n2,3,4\n")
    with pytest.raises(RadiometryError, match="header.*gps_time, x, y"):
        load_trajectory(path, None, "a.las")


def test_csv_whose_times_do_not_increase_is_refused_naming_the_row(tmp_path):
    path = write_csv(tmp_path / "traj.csv", "gps_time,x,y,z\n100,0,0,0\n101,0,0,0\n102,0,0,0\n101.5,0,0,0\n")
    with pytest.raises(RadiometryError, match=r"do not increase at data row 4 \(counting from 1: 102\.0 then 101\.5\)"):
        load_trajectory(path, None, "a.las")
    repeated = write_csv(tmp_path / "repeated.csv", "gps_time,x,y,z\n100,0,0,0\n100,0,0,0\n")
    with pytest.raises(RadiometryError, match="data row 2 "):
        load_trajectory(repeated, None, "a.las")


def test_missing_trajectory_file_is_refused(tmp_path):
    with pytest.raises(RadiometryError, match="no such file"):
        load_trajectory(tmp_path / "nope.csv", None, "a.las")


def test_sbet_against_a_file_without_crs_is_refused(tmp_path):
    path = write_sbet(tmp_path / "sbet.out", [10.0, 11.0], [0.8, 0.8], [0.15, 0.15], [300.0, 300.0])
    with pytest.raises(RadiometryError, match="flight_7.las: names no coordinate reference system.*sbet.out"):
        load_trajectory(path, None, "flight_7.las")


def test_sbet_is_transformed_into_the_files_utm_crs(tmp_path):
    lat, lon, height = np.array([48.1, 48.1005, 48.101]), np.array([9.2, 9.2004, 9.2008]), np.array(
        [512.0, 515.5, 519.25])
    path = write_sbet(tmp_path / "sbet.out", [1000.0, 1001.0, 1002.0], np.radians(lat), np.radians(lon), height)
    trajectory = load_trajectory(path, pyproj.CRS.from_epsg(32632).to_wkt(), "a.las")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(trajectory.xyz[:, 0], x, rtol=0, atol=1e-6)
    np.testing.assert_allclose(trajectory.xyz[:, 1], y, rtol=0, atol=1e-6)
    np.testing.assert_allclose(trajectory.xyz[:, 2], height, rtol=0, atol=1e-6)
    assert 400_000 < x[0] < 600_000  # really UTM 32N
    np.testing.assert_array_equal(trajectory.gps_time, [1000.0, 1001.0, 1002.0])
    assert trajectory.time_system == "week"


def test_sbet_against_orthometric_heights_it_cannot_reach_is_refused(tmp_path):
    """UTM 33N + EGM96 heights with PROJ's database and no geoid grid (a PROJ_DATA of proj.db alone, the network
    off): pyproj would keep the ellipsoidal heights, tens of metres off, so the SBET is refused."""
    import shutil
    import subprocess
    import sys

    path = write_sbet(tmp_path / "sbet.out", [10.0, 11.0], [0.8, 0.8], [0.26, 0.26], [300.0, 300.0])
    bare = tmp_path / "proj"
    bare.mkdir()
    shutil.copy(Path(pyproj.datadir.get_data_dir()) / "proj.db", bare / "proj.db")
    code = ("import pyproj\nfrom fwcore.radiometry.errors import RadiometryError\n"
            "from fwcore.radiometry.trajectory import load_trajectory\n"
            f"wkt = pyproj.CRS.from_user_input('EPSG:32633+5773').to_wkt()\n"
            f"try:\n    load_trajectory({str(path)!r}, wkt, 'a.las')\nexcept RadiometryError as err:\n    print(err)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env={**os.environ, "PROJ_DATA": str(bare), "PROJ_LIB": str(bare), "PROJ_NETWORK": "OFF"})
    assert re.search(r"a.las: its heights are in a vertical datum .*EGM96.*give the trajectory as a CSV", done.stdout), \
        done.stdout + done.stderr


def test_sbet_against_an_unreadable_crs_is_refused(tmp_path):
    path = write_sbet(tmp_path / "sbet.out", [10.0, 11.0], [0.8, 0.8], [0.26, 0.26], [300.0, 300.0])
    with pytest.raises(RadiometryError, match="a.las: its CRS cannot take the SBET sbet.out"):
        load_trajectory(path, 'PROJCS["nonsense"]', "a.las")


# ---------------------------------------------------------------- positions and GPS time systems

def week_trajectory():
    return Trajectory("traj.csv", np.array([100.0, 110.0, 130.0]),
                      np.array([[0.0, 0.0, 500.0], [10.0, 20.0, 510.0], [50.0, 20.0, 490.0]]), "week")


def test_positions_are_the_knots_at_knots_and_linear_between():
    got = week_trajectory().positions(np.array([100.0, 110.0, 130.0, 105.0, 125.0]), "week")
    expected = [[0, 0, 500], [10, 20, 510], [50, 20, 490],
                [5, 10, 505],  # half way along the first segment
                [40, 20, 495]]  # three quarters along the second: 10 + 0.75*40, 510 - 0.75*20
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_positions_outside_the_trajectory_are_nan():
    got = week_trajectory().positions(np.array([99.9, 130.1, 120.0]), "week")
    assert np.isnan(got[:2]).all()
    np.testing.assert_allclose(got[2], [30.0, 20.0, 500.0])


def test_adjusted_file_times_are_read_as_week_seconds():
    w = 120.0  # week seconds: on the second segment, half way
    t = 2100 * 604800.0 + w - 1e9  # the same instant in adjusted standard time (week 2100)
    assert t > 0
    got = week_trajectory().positions(np.array([t, t - 15.0]), "adjusted")
    np.testing.assert_allclose(got, [[30.0, 20.0, 500.0], [5.0, 10.0, 505.0]], rtol=0, atol=1e-9)
    np.testing.assert_allclose(to_time_system(np.array([t]), "adjusted", "week"), [w], rtol=0, atol=1e-9)


def test_week_seconds_cannot_become_adjusted_time():
    with pytest.raises(RadiometryError, match="without the GPS week"):
        to_time_system(np.array([100.0]), "week", "adjusted")


# ---------------------------------------------------------------- checking a trajectory against a file

def line_trajectory():
    """A straight line at 500 m along x, 1 m/s, from t=1000 to 1100 (week seconds)."""
    return Trajectory("line.csv", np.array([1000.0, 1100.0]), np.array([[0.0, 0.0, 500.0], [100.0, 0.0, 500.0]]),
                      "week")


def test_check_passes_for_returns_straight_below_the_sensor():
    times = np.linspace(1010.0, 1090.0, 9)
    points = np.stack([times - 1000.0, np.zeros(9), np.zeros(9)], axis=1)
    check_trajectory(line_trajectory(), "a.las", "week", times, points, np.tile(DOWN, (9, 1)))


def test_check_refuses_times_outside_the_trajectory():
    times = np.array([1010.0, 1050.0, 1200.0])
    points = np.stack([times - 1000.0, np.zeros(3), np.zeros(3)], axis=1)
    with pytest.raises(RadiometryError, match="a.las.*not all within the trajectory line.csv"):
        check_trajectory(line_trajectory(), "a.las", "week", times, points, np.tile(DOWN, (3, 1)))


def test_check_refuses_a_trajectory_5_km_sideways():
    times = np.linspace(1010.0, 1090.0, 9)
    points = np.stack([times - 1000.0, np.full(9, 5000.0), np.zeros(9)], axis=1)
    with pytest.raises(RadiometryError, match="coordinate reference system"):
        check_trajectory(line_trajectory(), "a.las", "week", times, points, np.tile(DOWN, (9, 1)))


def test_check_refuses_a_week_file_against_an_adjusted_trajectory():
    adjusted = Trajectory("adj.csv", np.array([3e8, 3e8 + 100.0]), np.zeros((2, 3)), "adjusted")
    with pytest.raises(RadiometryError, match="week seconds"):
        check_trajectory(adjusted, "a.las", "week", np.array([10.0]), np.zeros((0, 3)), np.zeros((0, 3)))
