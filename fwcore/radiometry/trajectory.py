"""The platform's trajectory and GPS time systems: a trajectory read from a CSV (in the input's coordinates) or an
SBET (WGS 84, put in the input's CRS with pyproj), its positions at the pulses' GPS times, and the check that it
covers an input's times and stands where its pulses came from. GPS times are week seconds or adjusted standard
time (GPS - 1e9, LAS's global encoding bit 0); a trajectory is matched to a file's system where that needs no
week number.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np

from fwcore.radiometry.errors import RadiometryError

WEEK_S = 604800.0
ADJUSTED_OFFSET_S = 1e9  # adjusted standard GPS time = GPS seconds - 1e9 (LAS global encoding bit 0)
SBET_FIELDS = ("gps_time", "latitude", "longitude", "height", "x_velocity", "y_velocity", "z_velocity", "roll",
               "pitch", "heading", "wander", "x_acceleration", "y_acceleration", "z_acceleration",
               "x_angular_rate", "y_angular_rate", "z_angular_rate")
SBET_RECORD = np.dtype([(f, "<f8") for f in SBET_FIELDS])  # 17 little-endian doubles, angles in radians
MAX_GEOMETRY_ANGLE_DEG = 3.0  # sensor-to-return against the beam: a trajectory in another CRS is far off this


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """The platform's positions at increasing GPS times, in the inputs' CRS (the scanner's optical centre: no
    lever arm is applied)."""

    path: str
    gps_time: np.ndarray
    xyz: np.ndarray  # (n, 3)
    time_system: str  # week (GPS seconds of the week) | adjusted (adjusted standard GPS time)

    def positions(self, gps_time: np.ndarray, file_time_system: str) -> np.ndarray:
        """Positions at the pulses' times (linear between knots); NaN outside the trajectory."""
        t = to_time_system(np.asarray(gps_time, dtype=float), file_time_system, self.time_system)
        out = np.empty((t.size, 3))
        for k in range(3):
            out[:, k] = np.interp(t, self.gps_time, self.xyz[:, k], left=np.nan, right=np.nan)
        return out

    def covers(self, gps_time: np.ndarray, file_time_system: str) -> bool:
        t = to_time_system(np.asarray(gps_time, dtype=float), file_time_system, self.time_system)
        return bool(t.size == 0 or (t.min() >= self.gps_time[0] and t.max() <= self.gps_time[-1]))


def time_system_of(times: np.ndarray) -> str:
    """GPS week seconds lie in [0, 604800]; adjusted standard times (GPS - 1e9) are outside it since 2011-09."""
    return "week" if times.size and times.min() >= 0.0 and times.max() <= WEEK_S else "adjusted"


def to_time_system(t: np.ndarray, source: str, target: str) -> np.ndarray:
    """Times from one GPS time system to another where that needs no week number: adjusted -> week
    ((t + 1e9) mod 604800); week -> adjusted needs the week, and raises."""
    if source == target:
        return t
    if source == "adjusted" and target == "week":
        return np.mod(t + ADJUSTED_OFFSET_S, WEEK_S)
    raise RadiometryError(f"GPS times in {source} seconds cannot be converted to {target} seconds without the GPS "
                          "week")


def read_trajectory_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A CSV with a header naming gps_time (or time), x, y, z: times and positions in the file's CRS."""
    path = Path(path)
    try:
        with path.open() as f:
            header = [h.strip().lower() for h in f.readline().split(",")]
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError, UnicodeDecodeError) as err:
        raise RadiometryError(f"{path}: not a trajectory CSV ({err}); it needs a header gps_time,x,y,z and a row "
                              "per time") from None
    time_column = "gps_time" if "gps_time" in header else "time" if "time" in header else None
    if time_column is None or not {"x", "y", "z"} <= set(header) or data.shape[1] != len(header):
        raise RadiometryError(f"{path}: the header must name gps_time, x, y and z (it names {', '.join(header)})")
    columns = [header.index(c) for c in (time_column, "x", "y", "z")]
    return data[:, columns[0]], data[:, columns[1:]]


def read_sbet(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """An SBET (17 little-endian doubles a record: time, latitude, longitude (radians), ellipsoidal height, ...):
    times and (longitude deg, latitude deg, height m)."""
    path = Path(path)
    size = path.stat().st_size
    if size == 0 or size % SBET_RECORD.itemsize:
        raise RadiometryError(f"{path}: {size} bytes is not a whole number of SBET records ({SBET_RECORD.itemsize} "
                              "bytes each: 17 doubles); give a .csv with gps_time,x,y,z for other layouts")
    records = np.memmap(path, dtype=SBET_RECORD, mode="r")
    lat, lon = np.asarray(records["latitude"]), np.asarray(records["longitude"])
    if not (np.all(np.abs(lat) <= math.pi / 2) and np.all(np.abs(lon) <= 2 * math.pi)):
        raise RadiometryError(f"{path}: latitudes and longitudes are not radians: not an SBET")
    geographic = np.stack([np.degrees(lon), np.degrees(lat), np.asarray(records["height"])], axis=1)
    return np.array(records["gps_time"]), geographic


def load_trajectory(path: str | Path, crs_wkt: str | None, source: str = "") -> Trajectory:
    """A trajectory file in the CRS of an input (`crs_wkt`, named by `source` in errors): a CSV as it is, an SBET
    (WGS 84 ellipsoidal) transformed with pyproj. Checks that times increase and values are finite."""
    path = Path(path)
    if not path.is_file():
        raise RadiometryError(f"--trajectory {path}: no such file")
    if path.suffix.lower() in (".csv", ".txt"):
        gps_time, xyz = read_trajectory_csv(path)
    else:
        gps_time, geographic = read_sbet(path)
        if not crs_wkt:
            raise RadiometryError(f"{source}: names no coordinate reference system, so the SBET {path.name} "
                                  "(WGS 84) cannot be put in its coordinates: give the trajectory as a CSV "
                                  "gps_time,x,y,z in the file's coordinates")
        xyz = _geographic_to_crs(geographic, crs_wkt, path, source)
    if gps_time.size < 2 or not np.all(np.isfinite(gps_time)) or not np.all(np.isfinite(xyz)):
        raise RadiometryError(f"{path}: a trajectory needs at least two rows of finite times and positions")
    if np.any(np.diff(gps_time) <= 0):
        row = int(np.flatnonzero(np.diff(gps_time) <= 0)[0]) + 1
        raise RadiometryError(f"{path}: times do not increase at data row {row + 1} (counting from 1: {float(gps_time[row - 1])!r} then "
                              f"{float(gps_time[row])!r})")
    system = time_system_of(gps_time)
    if system == "adjusted" and gps_time.min() > ADJUSTED_OFFSET_S:  # standard GPS seconds: LAS adjusts them
        gps_time = gps_time - ADJUSTED_OFFSET_S
    return Trajectory(str(path), gps_time, np.ascontiguousarray(xyz, dtype=float), system)


def _geographic_to_crs(geographic: np.ndarray, crs_wkt: str, path: Path, source: str) -> np.ndarray:
    """WGS 84 (ellipsoidal heights) to the file's CRS. A CRS with a vertical datum whose geoid model pyproj does
    not have (offline: no grids) would keep ellipsoidal heights, tens of metres off: refused."""
    import pyproj
    from pyproj.exceptions import ProjError

    try:
        target = pyproj.CRS.from_wkt(crs_wkt)
        transformer = pyproj.Transformer.from_crs(pyproj.CRS.from_epsg(4979), target, always_xy=True)
    except ProjError as err:
        raise RadiometryError(f"{source}: its CRS cannot take the SBET {path.name} ({err}): give the trajectory as "
                              "a CSV gps_time,x,y,z in the file's coordinates") from None
    if len(target.sub_crs_list) > 1 and "ballpark" in transformer.description.lower():
        raise RadiometryError(f"{source}: its heights are in a vertical datum ({target.sub_crs_list[1].name}) that "
                              f"the SBET {path.name}'s ellipsoidal heights cannot be converted to here (no geoid "
                              "model): give the trajectory as a CSV gps_time,x,y,z in the file's coordinates")
    x, y, z = transformer.transform(geographic[:, 0], geographic[:, 1], geographic[:, 2])
    return np.stack([x, y, z], axis=1)


def file_stamp(path: str | Path) -> tuple[int, int]:
    """Size and modification time: a cache keyed on them loads a file anew once it changes (fwl watch lives long)."""
    stat = Path(path).stat()
    return stat.st_size, stat.st_mtime_ns


@functools.lru_cache(maxsize=8)
def _cached_trajectory(path: str, crs_wkt: str | None, stamp: tuple[int, int]) -> Trajectory:
    return load_trajectory(path, crs_wkt, "an input")


def cached_trajectory(path: str, crs_wkt: str | None) -> Trajectory:
    """One load per process, CRS and version of the file: a worker places many ranges against one trajectory."""
    return _cached_trajectory(path, crs_wkt, file_stamp(path))


def check_trajectory(trajectory: Trajectory, source: str, file_time_system: str, gps_time: np.ndarray,
                     points: np.ndarray, beam: np.ndarray) -> None:
    """Before any decomposition: the trajectory covers the input's times and stands where its pulses came from.

    `gps_time` spans the input; `points` (m, 3) are returns of pulses at the first m times, `beam` their unit
    directions away from the scanner. Raises RadiometryError naming the file and how to fix the call."""
    name = Path(trajectory.path).name
    try:
        times = to_time_system(gps_time, file_time_system, trajectory.time_system)
    except RadiometryError:
        raise RadiometryError(f"{source}: its GPS times are in week seconds and the trajectory {name}'s in adjusted "
                              f"standard time, which cannot be converted back without the GPS week: give the "
                              "trajectory in GPS week seconds") from None
    if trajectory.time_system != file_time_system and np.ptp(times) > np.ptp(gps_time) + 1e-6:
        raise RadiometryError(f"{source}: its adjusted standard GPS times cross a GPS week boundary, so they cannot "
                              f"be matched to the trajectory {name}'s week seconds: split the file at the boundary "
                              "or give the trajectory in adjusted standard time")
    if not trajectory.covers(gps_time, file_time_system):
        said = {"week": "GPS week seconds", "adjusted": "adjusted standard GPS time"}
        raise RadiometryError(
            f"{source}: its pulses' GPS times {times.min():.3f}..{times.max():.3f} ({said[trajectory.time_system]}"
            f"{', converted from ' + said[file_time_system] if file_time_system != trajectory.time_system else ''}) "
            f"are not all within the trajectory {name}'s {trajectory.gps_time[0]:.3f}..{trajectory.gps_time[-1]:.3f}:"
            " give the trajectory of this flight line (and check that both are in the same GPS time system)")
    if not len(points):
        return
    sensor = trajectory.positions(gps_time[:len(points)], file_time_system)
    toward = points - sensor
    distance = np.linalg.norm(toward, axis=1)
    cosine = np.einsum("ij,ij->i", toward, beam) / np.maximum(distance, 1e-12)
    angle = np.degrees(np.arccos(np.clip(np.median(cosine), -1.0, 1.0)))
    if not (1.0 < np.median(distance) < 100_000.0 and angle < MAX_GEOMETRY_ANGLE_DEG):
        raise RadiometryError(
            f"{source}: the trajectory {name} does not stand where the pulses came from in the file's coordinates "
            f"(median distance to the returns {np.median(distance):.1f}, {angle:.1f} deg off the beam): give the "
            "trajectory in the file's coordinate reference system")
